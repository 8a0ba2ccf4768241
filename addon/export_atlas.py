"""Materials baked into texture atlases at export (core/scene/atlas.py).

A material whose textures need more than an image read at its UVs - a
procedural texture (Noise, Voronoi, Checker, ...: core/scene/procedural.py),
converter nodes (Math, Map Range, Vector Math, ...), colour attributes,
Geometry position or normal, images read at different vectors - has every
texture it reads baked over its triangles: each texel of a triangle's block
holds what the material's node graph gives at that point of the triangle's
plane (core/scene/shader_graph.py, read from the nodes by
addon/export_graph.py).  The triangles' texture coordinates become the
atlas's, so every stage (camera pass, paths, photons, light tracing;
colours, alpha, roughness and metallic maps, emission, bump, normal maps)
reads the bake as it reads an image, per hit, compiled or not.

Its cost is resolution: a block's texels follow the finest detail of the
sources (``atlas.procedural_density``, ``atlas.image_density``) within a
budget of texels a material (``atlas.BUDGET``); docs/shading.md
"Procedural textures, node graphs and material atlases" gives the measured
error.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
from typing import NamedTuple

import numpy as np

from ..core.scene import atlas as AT
from ..core.scene import color_ops as CO
from ..core.scene import procedural as PR
from ..core.scene import shader_graph as SG
from ..core.scene.textures import REPEAT, sampler_of
from .export_graph import linked_parameter

#: Texels evaluated at once (memory of a procedural's temporaries).
CHUNK = 1 << 16
#: A bake's values are finite: NaN reads 0, larger magnitudes this.
LIMIT = 1e6
#: What a bake whose graph raises holds instead (the exporter's diffuse
#: grey, alpha 1), and the errors that make it so.
FAILED = (0.8, 0.8, 0.8, 1.0)
EVAL_ERRORS = (ArithmeticError, ValueError, KeyError, TypeError, IndexError)
#: Atlases kept between exports, by what they depend on
#: (:meth:`AtlasBaker._digest`): the viewport exports again after every
#: edit, and a scene whose atlas materials did not change bakes nothing.
#: The oldest go first beyond CACHE_SIZE atlases or CACHE_BYTES of images.
_CACHE: dict = {}
CACHE_SIZE = 8
CACHE_BYTES = 512 << 20


def _failure(err) -> str:
    """The note of a bake whose graph raised ``err``."""
    return f"its texture graph could not be evaluated ({type(err).__name__}: {err}): grey"


def procedural_params(node, follow, notes, skip=()) -> dict:
    """A procedural node's params (core/scene/procedural.py): its input
    sockets' values by name (a linked one at its own value, noted; a Value
    node's value) but the Vector and ``skip``, and its enum, boolean, int
    and float properties by identifier."""
    params = {}
    for sock in node.inputs:
        if sock.name == "Vector" or sock.name in skip:
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
        if prop.type in ('ENUM', 'BOOLEAN', 'INT', 'FLOAT') and not prop.is_readonly \
                and getattr(prop, "array_length", 0) == 0 \
                and prop.identifier not in _base_properties():
            params[prop.identifier] = getattr(node, prop.identifier)
    return params


@functools.cache
def _base_properties() -> frozenset:
    """The properties every shader node has (location, width, mute, ...):
    not a texture's parameters."""
    import bpy
    return frozenset(p.identifier for p in bpy.types.ShaderNode.bl_rna.properties)


def needs_atlas(nodes, graph_nodes) -> bool:
    """Whether any of the nodes (a material's, its groups' included) with a
    linked output is a procedural texture, one of ``graph_nodes`` or an
    Image Texture projected otherwise than flat, a Color Ramp whose
    Alpha is linked (the colour chains read a ramp's Color only), a UDIM
    image (its tiles chosen per point), the camera's texture coordinates,
    or a
    colour or Mix node whose factor a node feeds (the colour chains fold
    constant ones only)."""
    return any((nd.type in PR.KINDS or nd.type in graph_nodes
                or nd.type == 'TEX_IMAGE' and getattr(nd, "projection", 'FLAT') != 'FLAT')
               and any(o.is_linked for o in nd.outputs)
               or nd.type == 'VALTORGB' and nd.outputs['Alpha'].is_linked
               or nd.type == 'TEX_COORD' and any(nd.outputs[k].is_linked
                                                 for k in ('Camera', 'Window'))
               or nd.type == 'TEX_IMAGE' and nd.image is not None
               and nd.image.source == 'TILED' and any(o.is_linked for o in nd.outputs)
               or linked_parameter(nd) and any(o.is_linked for o in nd.outputs)
               for nd in nodes)


def chain_exprs(e, ops) -> list:
    """The expressions of a chain (e, ops): e and, depth first, every
    "mix_image" op's own."""
    out = [e]
    for op in ops:
        if op[0] == "mix_image":
            out += chain_exprs(op[3], op[4])
    return out


def uv_periodic(b, textures) -> bool:
    """Whether a bake's chain (its images in ``textures``) reads the surface
    only through images at the render UV, each read flat with Repeat: a
    function of the uv, periodic with period 1 in u and v, so that one bake
    over the unit square serves every triangle at its own uvs."""
    def ok(e):
        if isinstance(e, SG.Image):
            v = e.vector
            return (isinstance(v, SG.Attr) and v.key == ("UV", None)
                    and e.projection == "FLAT" and not e.tiles
                    and sampler_of(textures[e.texture]) >> 2 == REPEAT)
        if isinstance(e, (SG.Attr, SG.Proc)):
            return False
        return all(ok(a) for a in getattr(e, "args", ()))
    return all(ok(e) for e in chain_exprs(b.expr, b.ops))


class Bake(NamedTuple):
    """One texture of an atlas material: its index in the exporter's
    ``textures``, the chain (expression, colour ops after it), and whether
    a float input reads it (scalar: its value in the alpha channel)."""
    index: int
    expr: object
    ops: tuple
    scalar: bool


class AtlasBaker:
    """The atlas materials of one export: their bakes, their triangles
    (recorded object by object), then :meth:`bake` once the geometry is in."""

    def __init__(self, ex):
        self.ex = ex
        self.bakes: dict[int, list[Bake]] = {}      # material -> its bakes
        self.keys: dict[int, list] = {}             # material -> attribute keys read
        self.parts: dict[int, list] = {}    # material -> [(part, rows, attrs, key, world)]

    # -- materials -----------------------------------------------------------
    def texture(self, mb, expr, ops, scalar) -> int:
        """A placeholder texture for the chain (expr, ops) in ``mb``'s
        material, baked by :meth:`bake`."""
        idx = len(self.ex.textures)
        self.ex.textures.append(np.ones((1, 1, 4), np.float32))
        mb.bakes.append(Bake(idx, expr, tuple(ops), bool(scalar)))
        return idx

    def add_material(self, m: int, mb) -> None:
        """Registers material m's bakes: baked now over its images' own grid
        when every one is a function of the render UV through images read
        with Repeat (:func:`uv_periodic`: then it repeats with them and needs
        no atlas), else laid out over its triangles by :meth:`bake`."""
        if mb.bakes and all(uv_periodic(b, self.ex.textures) for b in mb.bakes):
            for b in mb.bakes:
                try:
                    self._bake_uv_space(b)
                except EVAL_ERRORS as err:
                    self.ex.textures[b.index] = np.array([[FAILED]], np.float32)
                    self._note(m, _failure(err))
            self._roughness_means(m, {b.index: float(self.ex.textures[b.index][..., 3].mean())
                                      for b in mb.bakes if self.ex.textures[b.index].shape[2] > 3})
            return
        if mb.bakes:
            self.bakes[m] = list(mb.bakes)
            keys = set()
            for b in mb.bakes:
                for e in chain_exprs(b.expr, b.ops):
                    keys |= SG.attributes(e)
            self.keys[m] = sorted(keys, key=repr)

    def _bake_uv_space(self, b: Bake) -> None:
        """The bake of a :func:`uv_periodic` chain over the unit uv square, on
        the grid of its largest image, enlarged as ``_Exporter.folded``
        enlarges one under nonlinear nodes; a lone image is its own texture."""
        from .export import UPSAMPLE_FACTOR, UPSAMPLE_MAX
        ex = self.ex
        e = b.expr
        if isinstance(e, SG.Image) and not b.ops and b.scalar == (e.output == "Alpha"):
            ex.textures[b.index] = ex.textures[e.texture]
            return
        shapes = [ex.textures[x.texture].shape[:2] for x in SG.walk(e)
                  if isinstance(x, SG.Image)] or [(1, 1)]
        H, W = max(h for h, _ in shapes), max(w for _, w in shapes)
        k = max(1, min(UPSAMPLE_MAX // max(H, W), UPSAMPLE_FACTOR))
        H, W = H * k, W * k
        v, u = np.divmod(np.arange(H * W), W)
        out = np.empty((H * W, 4), np.float32)
        for a in range(0, H * W, CHUNK):
            uv = np.stack([(u[a:a + CHUNK] + 0.5) / W, (v[a:a + CHUNK] + 0.5) / H,
                           np.zeros(len(u[a:a + CHUNK]))], 1)
            ctx = SG.EvalContext({("UV", None): uv}, ex.textures)
            out[a:a + CHUNK] = self._values(b, ctx, {}, len(uv))
            ex.poll()
        ex.textures[b.index] = out.reshape(H, W, 4)

    # -- geometry ----------------------------------------------------------
    def record(self, m: int, part: int, rows, attrs: dict, world, key) -> None:
        """Triangles rows of parts[part] with material m, their attributes
        {key: (k, 3, 3) float64 at the corners} and world corners (k, 3, 3);
        key: instances with the same key share their blocks (None: never)."""
        self.parts.setdefault(m, []).append((part, rows, attrs, key, world))

    # -- baking ------------------------------------------------------------
    def bake(self, parts) -> None:
        """Lay out, evaluate and store every atlas material's textures; the
        triangles' uvs in ``parts`` become the atlas's."""
        for m, entries in self.parts.items():
            self._bake_material(m, entries, parts)
            self.ex.poll()

    def _sizes(self, m: int, corners: dict) -> np.ndarray:
        """(T,) float64 texels a block side each triangle asks for: the
        largest over the material's textures and images of the extent of
        their vector at the corners times their density."""
        ex = self.ex
        T = len(next(iter(corners.values()))) if corners else 0
        flat = SG.EvalContext({k: v.reshape(-1, 3) for k, v in corners.items()}, ex.textures)
        memo: dict = {}
        ext = np.ones(T)
        for b in self.bakes[m]:
            for e in chain_exprs(b.expr, b.ops):
                for x in SG.walk(e):
                    if isinstance(x, SG.Proc):
                        d = AT.procedural_density(x.node_kind, dict(x.params))
                    elif isinstance(x, SG.Image):
                        d = AT.image_density(ex.textures[x.texture].shape)
                    else:
                        continue
                    v = SG.evaluate(x.vector, flat, memo)
                    v = np.asarray(v, np.float64).reshape(T, 3, -1)
                    ext = np.maximum(ext, AT.extent(v) * d)
        return ext

    def _bake_material(self, m: int, entries, parts) -> None:
        """Material m's atlas: its layout and bakes (or the cached ones of the
        same graph on the same triangles, :data:`_CACHE`), its triangles' uvs
        in ``parts`` (instances sharing blocks share uvs), its textures,
        notes and roughness means."""
        ex = self.ex
        firsts: dict = {}
        unique = []
        for e in entries:
            if e[3] is None or e[3] not in firsts:
                if e[3] is not None:
                    firsts[e[3]] = len(unique)
                unique.append(e)
        keys = self.keys[m]
        corners = {k: np.concatenate([e[2][k] for e in unique]) for k in keys}
        world = np.concatenate([e[4] for e in unique])
        digest = self._digest(m, corners, world)
        done = _CACHE.get(digest)
        if done is None:
            done = self._layout_and_bake(m, keys, corners, world)
            _CACHE[digest] = done

            def held():
                return sum(img.nbytes for entry in _CACHE.values() for img in entry[1])
            while len(_CACHE) > 1 and (len(_CACHE) > CACHE_SIZE or held() > CACHE_BYTES):
                _CACHE.pop(next(iter(_CACHE)))
        uv, images, means, notes = done
        at, starts = 0, []
        for part, rows, *_ in unique:
            starts.append(at)
            parts[part][2][rows] = uv[at:at + len(rows)]
            at += len(rows)
        for part, rows, _, key, _ in entries:
            if key is not None and unique[firsts[key]][0] != part:
                j = firsts[key]
                parts[part][2][rows] = uv[starts[j]:starts[j] + len(rows)]
        for b, img in zip(self.bakes[m], images):
            ex.textures[b.index] = img
        for note in notes:
            self._note(m, note)
        self._roughness_means(m, {b.index: v for b, v in zip(self.bakes[m], means)})

    def _digest(self, m: int, corners: dict, world) -> bytes:
        """What material m's atlas depends on: its bakes' graphs (their
        images' pixels included), the corners' attributes and positions."""
        h = hashlib.blake2b(digest_size=20)
        h.update(repr([(b.expr, b.ops, b.scalar) for b in self.bakes[m]]).encode())
        for b in self.bakes[m]:
            for e in chain_exprs(b.expr, b.ops):
                for x in SG.walk(e):
                    if isinstance(x, SG.Image):
                        for t in [x.texture] + [i for _, i in x.tiles]:
                            img = self.ex.textures[t]
                            h.update(repr((img.shape, sampler_of(img),
                                           type(img).__name__)).encode())
                            h.update(np.ascontiguousarray(img).data)
        for k in sorted(corners, key=repr):
            h.update(repr(k).encode())
            h.update(np.ascontiguousarray(corners[k]).data)
        h.update(np.ascontiguousarray(world).data)
        h.update(repr((AT.BUDGET, AT.HARD_CAP)).encode())
        return h.digest()

    def _layout_and_bake(self, m: int, keys, corners: dict, world) -> tuple:
        """(corner uvs (T, 3, 2), the bakes' images, their alpha means over
        the triangles, notes) of material m's atlas."""
        ex = self.ex
        notes = []
        # About a sixteenth of the budget spread evenly over the surface at
        # least: a graph may bend its attributes anywhere (a sine of the
        # position).  A block holds about 4 A d^2 texels for a triangle of
        # area A at d texels a unit (its square is twice the triangle, whose
        # longest edge is about 2 sqrt(A)).
        area = 0.5 * np.linalg.norm(np.cross(world[:, 1] - world[:, 0],
                                             world[:, 2] - world[:, 0]), axis=1)
        floor = np.sqrt(AT.BUDGET / 64 / max(float(area.sum()), 1e-12))
        if 9 * len(world) > AT.HARD_CAP:
            L, tx, uv = AT.flat(len(world))
            notes.append(f"{len(world):,} triangles: its textures one value a triangle "
                         f"(atlas budget)")
        else:
            asked = self._sizes(m, corners) if keys else np.ones(len(world))
            n = AT.block_sizes(np.maximum(asked, AT.extent(world) * floor), 1.0)
            # Within the budget, the finest blocks the sources ask for; if
            # not, say how much detail the bake keeps (texels a side, median).
            wanted = np.minimum(np.ceil(asked), AT.SIZES[-1])
            kept = float(np.median(np.minimum(n / np.maximum(wanted, 1.0), 1.0)))
            if kept < 0.95:
                notes.append(f"textures baked at {100 * kept:.0f} % of their detail "
                             f"(atlas budget)")
            L = AT.pack(n)
            uv = AT.corner_uvs(L)
            tx = AT.texels(L)
        bakes = self.bakes[m]
        images = [np.zeros((L.height, L.width, 4), np.float32) for _ in bakes]
        failed = set()
        for a in range(0, len(tx.tri), CHUNK):
            part = AT.Texels(*(x[a:a + CHUNK] for x in tx))
            ctx = SG.EvalContext({k: AT.at_texels(corners[k], part) for k in keys},
                                 ex.textures)
            memo: dict = {}
            for i, b in enumerate(bakes):
                if i in failed:
                    continue
                try:
                    images[i][part.iy, part.ix] = self._values(b, ctx, memo, len(part.tri))
                except EVAL_ERRORS as err:
                    failed.add(i)
                    images[i][:] = FAILED
                    notes.append(_failure(err))
            ex.poll()
        inside = (tx.s >= 0) & (tx.t >= 0) & (tx.s + tx.t <= 1)
        means = [float(img[tx.iy[inside], tx.ix[inside], 3].mean()) if inside.any() else 1.0
                 for img in images]
        return uv, images, means, notes


    def _note(self, m: int, note: str) -> None:
        """One more approximation of material m (once)."""
        mat = self.ex.materials[m]
        if note not in mat.approximations:
            self.ex.materials[m] = dataclasses.replace(
                mat, approximations=mat.approximations + (note,))

    @staticmethod
    def _values(b: Bake, ctx, memo, K: int) -> np.ndarray:
        """(K, 4) float32 the bake's texels at the chunk's points (finite:
        NaN as 0, magnitudes beyond LIMIT clipped)."""
        with np.errstate(all='ignore'):
            out = AtlasBaker._raw_values(b, ctx, memo, K)
        return np.clip(np.nan_to_num(out, nan=0.0), -LIMIT, LIMIT)

    @staticmethod
    def _raw_values(b: Bake, ctx, memo, K: int) -> np.ndarray:
        def rgb(e, ops):
            c = SG.evaluate(SG.as_vector(e, SG.COLOR), ctx, memo)
            c = np.broadcast_to(c, (K, 3))
            done = []
            for op in ops:
                if op[0] == "mix_image":
                    _, blend, t, other, oops, clamp = op
                    op = ("mix", blend, t, rgb(other, oops), "A", clamp)
                done.append(op)
            return CO.apply(tuple(done), c)
        out = np.ones((K, 4), np.float32)
        if b.scalar and not b.ops:
            out[:, 3] = np.clip(np.broadcast_to(
                SG.evaluate(SG.as_float(b.expr), ctx, memo), (K,)), 0.0, 1.0)
        elif b.scalar:
            out[:, 3] = np.clip(CO.gray(rgb(b.expr, b.ops)), 0.0, 1.0)
        else:
            out[:, :3] = rgb(b.expr, b.ops)
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
