"""Materials baked into texture atlases at export (core/scene/atlas.py).

A material that reads a procedural texture (Noise, Voronoi, Checker, ...:
core/scene/procedural.py) has every texture it reads baked over its
triangles: each texel of a triangle's block holds what the material's chain
gives at that point of the triangle's plane, each source read at its own
vector (a procedural at its Generated or Object coordinates, an image at its
UV map), the colour nodes between applied per texel.  The triangles' texture
coordinates become the atlas's, so every stage (camera pass, paths, photons,
light tracing; colours, alpha, roughness and metallic maps, emission, bump,
normal maps) reads the bake as it reads an image, per hit, compiled or not.

Its cost is resolution: a block's texels follow the finest detail of the
sources (``atlas.procedural_density``, ``atlas.image_density``) within a
budget of texels a material (``atlas.BUDGET``);
docs/shading.md "Procedural textures" gives the measured error against
Cycles.
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from ..core.scene import atlas as AT
from ..core.scene import color_ops as CO
from ..core.scene import procedural as PR
from ..core.scene.textures import sample_alpha, sample_texture

#: Cycles' colour of a missing image (magenta).
MISSING_IMAGE = (1.0, 0.0, 1.0)

#: Texels evaluated at once (memory of a procedural's temporaries).
CHUNK = 1 << 18


class Procedural:
    """One output of a procedural texture node, as a colour chain's source:
    the node's ``type``, ``name`` and ``inputs`` (its Vector) like an Image
    Texture node's, its ``output`` name and ``params``
    (:func:`procedural_params`)."""

    def __init__(self, node, output: str, params: dict):
        self.node = node
        self.type = node.type
        self.name = node.name
        self.inputs = node.inputs
        self.outputs = node.outputs
        self.output = output
        self.params = params
        self.image = None


def procedural_params(node, follow, notes) -> dict:
    """A procedural node's params (core/scene/procedural.py): its input
    sockets' values by name (a linked one at its own value, noted; a Value
    node's value) and its enum and boolean properties by identifier."""
    params = {}
    for sock in node.inputs:
        if sock.name == "Vector" or not sock.enabled and not hasattr(sock, "default_value"):
            continue
        src, _, vsock = follow(sock)
        v = getattr(vsock, "default_value", None)
        if src is not None and src.type == 'VALUE':
            v = src.outputs[0].default_value
        elif src is not None:
            notes.append(f"'{src.name}' into {node.name}.{sock.name}: its value used")
        if v is None:
            continue
        try:
            params[sock.name] = tuple(float(x) for x in tuple(v)[:3])
        except TypeError:
            params[sock.name] = float(v)
    for prop in node.bl_rna.properties:
        if prop.type in ('ENUM', 'BOOLEAN') and not prop.is_readonly \
                and prop.identifier not in _BASE_PROPERTIES:
            params[prop.identifier] = getattr(node, prop.identifier)
    return params


_BASE_PROPERTIES = {"select", "show_options", "show_preview", "hide", "mute",
                    "show_texture", "use_custom_color", "warning_propagation"}


def has_procedural(follow_nodes) -> bool:
    """Whether any of the nodes (a material's, its groups' included) is a
    procedural texture with a linked output."""
    return any(nd.type in PR.KINDS and any(o.is_linked for o in nd.outputs)
               for nd in follow_nodes)


def sources(node, ops) -> list:
    """The chain's sources: ``node`` and, depth first, every "mix_image"
    op's image or procedural."""
    out = [node]
    for op in ops:
        if op[0] == "mix_image":
            out += sources(op[3], op[4])
    return out


class Bake(NamedTuple):
    """One texture of an atlas material: its index in the exporter's
    ``textures``, the chain (source, ops), read as a float (scalar),
    ``prepared``: the index of the chain folded as an image (one image, no
    other source), else -1; ``keys``: the vector spec key of each of
    :func:`sources` (source, ops), in that order."""
    index: int
    source: object
    ops: tuple
    scalar: bool
    prepared: int
    keys: tuple


class AtlasBaker:
    """The atlas materials of one export: their bakes, their triangles
    (recorded object by object), then :meth:`bake` once the geometry is in."""

    def __init__(self, ex):
        self.ex = ex
        self.bakes: dict[int, list[Bake]] = {}      # material -> its bakes
        self.specs: dict[int, dict] = {}            # material -> {spec key: vector spec}
        self.parts: dict[int, list] = {}            # material -> [(part, rows, vectors, key)]

    # -- materials -----------------------------------------------------------
    def texture(self, mb, node, ops, scalar) -> int:
        """A placeholder texture for the chain (node, ops) in ``mb``'s
        material, baked by :meth:`bake`."""
        ex = self.ex
        srcs = sources(node, ops)
        prepared = -1
        if len(srcs) == 1 and not isinstance(node, Procedural):
            # One image: its chain folded into its texels, read at the texels'
            # vector (the exporter's own texture, alpha and all).
            prepared = ex.texture(node, mb, ops, scalar)
            if prepared < 0:
                return -1
        else:
            for s in srcs:
                if not isinstance(s, Procedural):
                    ex.color_texels(s, mb.notes)
        keys = []
        for s in srcs:
            spec = mb.vector(s, 'Generated' if isinstance(s, Procedural) else 'UV')
            keys.append(spec_key(spec))
            mb.bake_specs[keys[-1]] = spec
        idx = len(ex.textures)
        ex.textures.append(np.ones((1, 1, 4), np.float32))
        mb.bakes.append(Bake(idx, node, tuple(ops), bool(scalar), prepared, tuple(keys)))
        return idx

    def add_material(self, m: int, mb) -> None:
        if mb.bakes:
            self.bakes[m] = list(mb.bakes)
            self.specs[m] = dict(mb.bake_specs)

    # -- geometry ----------------------------------------------------------
    def record(self, m: int, part: int, rows, vectors: dict, key) -> None:
        """Triangles rows of parts[part] with material m, their texture
        vectors {spec key: (k, 3, 3) float64}; key: instances with the same
        key share their blocks (None: never)."""
        self.parts.setdefault(m, []).append((part, rows, vectors, key))

    # -- baking ------------------------------------------------------------
    def bake(self, parts) -> None:
        """Lay out, evaluate and store every atlas material's textures; the
        triangles' uvs in ``parts`` become the atlas's."""
        for m, entries in self.parts.items():
            self._bake_material(m, entries, parts)
            self.ex.poll()

    def _density(self, m: int) -> dict:
        """{spec key: texels a unit of that vector} over the material's
        sources."""
        ex = self.ex
        dens: dict = {}
        for b in self.bakes[m]:
            for s, key in zip(sources(b.source, b.ops), b.keys):
                if isinstance(s, Procedural):
                    d = AT.procedural_density(s.type, s.params)
                else:
                    img = ex.textures[b.prepared] if b.prepared >= 0 else \
                        ex.color_texels(s, [])
                    d = AT.image_density(img.shape if img is not None else (1, 1))
                dens[key] = max(dens.get(key, 0.0), d)
        return dens

    def _bake_material(self, m: int, entries, parts) -> None:
        ex = self.ex
        firsts: dict = {}
        unique = []
        for e in entries:
            if e[3] is None or e[3] not in firsts:
                if e[3] is not None:
                    firsts[e[3]] = len(unique)
                unique.append(e)
        keys = list(self.specs[m])
        vec = {k: np.concatenate([e[2][k] for e in unique]) for k in keys}
        dens = self._density(m)
        ext = np.max([AT.extent(vec[k]) * dens.get(k, 1.0) for k in keys], axis=0)
        n = AT.block_sizes(ext, 1.0)
        # Within the budget, the finest blocks the sources ask for; if not,
        # say how much detail the bake keeps (texels a side, as a median).
        wanted = np.minimum(np.ceil(ext), AT.SIZES[-1])
        kept = float(np.median(np.minimum(n / np.maximum(wanted, 1.0), 1.0)))
        if kept < 0.95:
            mat = ex.materials[m]
            ex.materials[m] = dataclasses.replace(mat, approximations=mat.approximations + (
                f"textures baked at {100 * kept:.0f} % of their detail (atlas budget)",))
        L = AT.pack(n)
        uv = AT.corner_uvs(L)
        at = 0
        starts = []
        for part, rows, _, _ in unique:
            starts.append(at)
            parts[part][2][rows] = uv[at:at + len(rows)]
            at += len(rows)
        for part, rows, _, key in entries:
            if key is not None and unique[firsts[key]][0] != part:
                j = firsts[key]
                parts[part][2][rows] = uv[starts[j]:starts[j] + len(rows)]
        tx = AT.texels(L)
        images = {b.index: np.zeros((L.height, L.width, 4), np.float32) for b in self.bakes[m]}
        inside = (tx.s >= 0) & (tx.t >= 0) & (tx.s + tx.t <= 1)
        for a in range(0, len(tx.tri), CHUNK):
            part = AT.Texels(*(x[a:a + CHUNK] for x in tx))
            at_vec = {k: AT.at_texels(vec[k], part) for k in keys}
            for b in self.bakes[m]:
                images[b.index][part.iy, part.ix] = self._values(m, b, at_vec)
            ex.poll()
        means = {}
        for b in self.bakes[m]:
            img = images[b.index]
            ex.textures[b.index] = img
            means[b.index] = float(img[tx.iy[inside], tx.ix[inside], 3].mean()) \
                if inside.any() else 1.0
        self._roughness_means(m, means)

    def _values(self, m: int, b: Bake, at_vec: dict) -> np.ndarray:
        """(K, 4) float32 the bake's texels at the chunk's points."""
        ex = self.ex
        if b.prepared >= 0:
            img = ex.textures[b.prepared]
            uv = at_vec[b.keys[0]][:, :2]
            out = np.empty((len(uv), 4), np.float32)
            out[:, :3] = sample_texture(img, uv)
            out[:, 3] = sample_alpha(img, uv)
            return out

        keys = iter(b.keys)     # sources() order: a source, then its ops' depth first

        def rgb(s, ops):
            p = at_vec[next(keys)]
            if isinstance(s, Procedural):
                c = PR.evaluate(s.type, s.output, s.params, p)
            else:
                img = ex.color_texels(s, [])
                c = sample_texture(img, p[:, :2]) if img is not None else \
                    np.broadcast_to(np.asarray(MISSING_IMAGE, np.float64), (len(p), 3))
            done = []
            for op in ops:
                if op[0] == "mix_image":
                    _, blend, t, other, oops, clamp = op
                    op = ("mix", blend, t, rgb(other, oops), "A", clamp)
                done.append(op)
            return CO.apply(tuple(done), c)
        c = rgb(b.source, b.ops)
        out = np.ones((len(c), 4), np.float32)
        if b.scalar:
            out[:, 3] = np.clip(CO.gray(c), 0.0, 1.0)
        else:
            out[:, :3] = c
        return out

    def _roughness_means(self, m: int, means: dict) -> None:
        """The lobes of material m whose roughness map is baked take the
        bake's mean over the triangles as their own roughness (what the
        frequency model reads, core.materials.rough_maps)."""
        ex = self.ex
        mat = ex.materials[m]
        lobes = tuple(dataclasses.replace(lb, roughness=means[lb.roughness_texture])
                      if lb.roughness_texture in means else lb for lb in mat.lobes)
        if lobes != mat.lobes:
            ex.materials[m] = dataclasses.replace(mat, lobes=lobes)



def spec_key(spec) -> tuple:
    """A hashable key of a vector spec (source, object, A (4, 4))."""
    src, ob, A = spec
    return (src, ob, tuple(np.round(np.asarray(A, np.float64), 9).ravel()))
