"""Cycles' own values of a procedural texture, pixel by pixel: the ground
truth of core/scene/procedural.py's ports.

A plane of side EXTENT at z = 0, its object space the world's, seen from
above by an orthographic camera that frames it exactly; its material an
Emission of strength 1 whose Color is the node under test, fed by the
plane's Object coordinates through a Mapping node.  One Cycles sample a
pixel through a 0.01-pixel Box filter reads the texture near the pixel
centre: at one offset for every pixel, (+4.9e-4, +4.9e-4) pixel (measured
with Linear Gradients), which :func:`exact_centres` removes by feeding the
Mapping the pixel centres themselves.

Many cases share one render as tiles (:func:`tiled_values`, for any graph
of nodes; :func:`mosaic`, for a texture node read at the texture-space
points of a Mapping), each pixel evaluating its own case only: a render of
its fresh scene costs 20 ms at 128 x 128 pixels and 0.1 s at 512 x 512
(the plain emission of a Math node), and a case's nodes add their own
pixels' cost.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bpy_helpers import _ensure_nodes, add_plane, bpy, link, set_world
from core.scene import procedural

EXTENT = 2.0

#: Blender node idnames of the procedural kinds (core/scene/procedural.py).
NODE_TYPES = {
    "TEX_CHECKER": "ShaderNodeTexChecker",
    "TEX_GRADIENT": "ShaderNodeTexGradient",
    "TEX_MAGIC": "ShaderNodeTexMagic",
    "TEX_BRICK": "ShaderNodeTexBrick",
    "TEX_VORONOI": "ShaderNodeTexVoronoi",
    "TEX_NOISE": "ShaderNodeTexNoise",
    "TEX_WHITE_NOISE": "ShaderNodeTexWhiteNoise",
    "TEX_WAVE": "ShaderNodeTexWave",
}


def add_node(nodes, kind: str, params: dict):
    """A node of ``kind`` with ``params`` (input sockets by name, properties by
    identifier) set, as procedural.evaluate reads them; properties first,
    since they decide which sockets a node shows."""
    nd = nodes.new(NODE_TYPES[kind])
    for key, value in params.items():
        if not any(s.name == key for s in nd.inputs):
            setattr(nd, key, value)
    for key, value in params.items():
        # by name over all sockets: inputs.get() skips the unavailable ones
        sock = next((s for s in nd.inputs if s.name == key), None)
        if sock is None:
            continue
        if sock.type == "RGBA":
            sock.default_value = (*value[:3], 1.0)
        else:
            sock.default_value = value
    return nd


def exact_centres(nodes, links, vec, res):
    """Route the Mapping's input (``vec`` is its output) through
    Snap(2/res) + (1/res, 1/res, 0): the Object coordinate of the pixel's
    centre, exact in float32, wherever the filter put the sample."""
    mp = vec.node
    obj = mp.inputs["Vector"].links[0].from_socket
    snap = nodes.new("ShaderNodeVectorMath")
    snap.operation = 'SNAP'
    snap.inputs[1].default_value = (2.0 / res,) * 3
    half = nodes.new("ShaderNodeVectorMath")
    half.operation = 'ADD'
    half.inputs[1].default_value = (1.0 / res, 1.0 / res, 0.0)
    links.new(obj, snap.inputs[0])
    links.new(snap.outputs[0], half.inputs[0])
    links.new(half.outputs[0], mp.inputs["Vector"])


def map_points(p, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0),
               scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(..., 3) float64 a Mapping node's Point output at points ``p``
    (..., 3), in float64 (Cycles rounds to float32)."""
    from mathutils import Euler
    R = np.array(Euler(rotation, 'XYZ').to_matrix(), np.float64)
    return (np.asarray(p, np.float64) * np.asarray(scale, np.float64)) @ R.T \
        + np.asarray(location, np.float64)


def mapped_points(res: int, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0),
                  scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(res, res, 3) float64 the Mapping node's Point output at the pixel
    centres, row 0 at the top (as ``read_exr`` gives Cycles' image)."""
    c = (np.arange(res) + 0.5) / res * EXTENT - EXTENT / 2
    x, y = np.meshgrid(c, c[::-1])
    return map_points(np.stack([x, y, np.zeros_like(x)], -1), location, rotation, scale)


def _empty_scene(res: int):
    """bpy_helpers.empty_scene for Cycles without its preferences' reset: a
    fresh file from the factory startup (``read_homefile``, 7 ms), not
    ``read_factory_settings`` (40 ms: it also resets the preferences and
    registers every add-on again), whose scene settings are the same."""
    b = bpy()
    b.ops.wm.read_homefile(use_empty=True, use_factory_startup=True, load_ui=False)
    sc = b.context.scene
    sc.render.resolution_x = sc.render.resolution_y = res
    sc.render.resolution_percentage = 100
    sc.render.engine = 'CYCLES'
    return sc


def cycles_values(build, tmp_path, res: int = 64, location=(0.0, 0.0, 0.0),
                  rotation=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):
    """(values (res, res, 3) float64, points (res, res, 3) float64): what
    Cycles shows of ``build(nodes, links, vector_socket) -> output socket``
    at the pixel centres, and the texture-space point of each
    (:func:`mapped_points`).  The output is shown as an Emission's Color,
    or is the surface shader itself when it is a shader socket."""
    b = bpy()
    sc = _empty_scene(res)
    set_world(sc, (0.0, 0.0, 0.0), 0.0)
    m = b.data.materials.new("Procedural")
    _ensure_nodes(m)
    nt = m.node_tree
    nodes, links = nt.nodes, nt.links
    for nd in list(nodes):
        if nd.type != 'OUTPUT_MATERIAL':
            nodes.remove(nd)
    out = next(nd for nd in nodes if nd.type == 'OUTPUT_MATERIAL')
    em = nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = 1.0
    links.new(em.outputs[0], out.inputs["Surface"])
    tc = nodes.new("ShaderNodeTexCoord")
    mp = nodes.new("ShaderNodeMapping")
    mp.inputs["Location"].default_value = location
    mp.inputs["Rotation"].default_value = rotation
    mp.inputs["Scale"].default_value = scale
    links.new(tc.outputs["Object"], mp.inputs["Vector"])
    shown = build(nodes, links, mp.outputs["Vector"])
    if shown.type == 'SHADER':          # the build's own closures
        nodes.remove(em)
        links.new(shown, out.inputs["Surface"])
    else:
        links.new(shown, em.inputs["Color"])
    add_plane(sc, size=EXTENT, material=m)
    cd = b.data.cameras.new("Camera")
    cd.type = 'ORTHO'
    cd.ortho_scale = EXTENT
    cam = link(b.data.objects.new("Camera", cd), sc)
    cam.location = (0.0, 0.0, 1.0)
    cam.rotation_euler = (0.0, 0.0, 0.0)
    sc.camera = cam
    cy = sc.cycles
    cy.samples = 1
    cy.use_denoising = False
    cy.use_adaptive_sampling = False
    cy.filter_width = 0.01
    cy.pixel_filter_type = 'BOX'
    cy.seed = 0
    sc.view_settings.view_transform = 'Standard'
    im = sc.render.image_settings
    im.file_format, im.color_depth, im.color_mode = 'OPEN_EXR', '32', 'RGBA'
    path = str(tmp_path / f"procedural_{res}.exr")
    sc.render.filepath = path
    sc.render.use_file_extension = False
    b.ops.render.render(write_still=True)
    from scenes.refs import read_exr
    img = read_exr(path)[..., :3].astype(np.float64)
    return img, mapped_points(res, location, rotation, scale)


def agreement(ours: np.ndarray, theirs: np.ndarray) -> tuple[float, float]:
    """(median, 99th percentile) of |ours - theirs| over the pixels' channels:
    the median sees a wrong formula, the percentile a wrong cell or seam
    (the 1 % of pixels left out are those a cell edge crosses within the
    0.005-pixel jitter)."""
    d = np.abs(np.asarray(ours, np.float64) - np.asarray(theirs, np.float64))
    return float(np.median(d)), float(np.percentile(d, 99))



def tiled_values(builds, tmp_path, res: int = 128, tiles: int = 8):
    """[(values (s*s, 3) float64, u (s*s,), v (s*s,))] per build: what Cycles
    shows of each ``build(nodes, links, u, v) -> output socket`` over its
    s x s tile (s = res / tiles) of one render, tiles row by row from the
    top left, with u, v (float64, as Cycles has them exactly in float32)
    the pixel's position within its tile, (k + 0.5) / s for k = 0 .. s - 1,
    u rightwards and v upwards: ``u``, ``v`` are Math node sockets giving
    them, from the exact pixel centres (:func:`exact_centres`), for the
    build's inputs (res and tiles powers of two keep them exact).

    Each build's output is the Color of an Emission of strength 1, and a
    binary tree of Mix Shader nodes picks the tile's Emission, its factors
    (the tile index against the split) exactly 0 or 1: Cycles' SVM jumps
    over a Mix Shader's branch of weight 0 (a linked factor compiles to
    NODE_JUMP_IF_ZERO / NODE_JUMP_IF_ONE), so a pixel evaluates its own
    tile's nodes and the nodes the builds share, no other build's: a case
    costs Cycles its tile's pixels, not the render's.  (A chain of Mix
    nodes evaluated every case at every pixel: Cycles took 2 s over 15 4D
    Voronoi cases, 13 of them Smooth F1, as 16 x 16 tiles of a 64 x 64
    render, and takes 0.2 s over all 54 as tiles of a 128 x 128 one.)  The
    weights are exactly 1, so a float output shows as grey, a vector or
    colour as it is: any value, negative and large ones too (the EXR keeps
    float32).  Tiles past the builds show black.

    Each row of tiles is a node group of its own, the material a tree of
    their Group nodes: bpy's node edits take time in proportion to the
    size of the tree edited (0.1 ms at 100 nodes, 0.8 ms at 400), so that
    one tree of 64 cases took longer to build than to render."""
    n = len(builds)
    assert 0 < n <= tiles * tiles and res % tiles == 0
    assert res & (res - 1) == 0 and tiles & (tiles - 1) == 0, "inexact u, v"
    half = tiles / 2

    def math(nodes, links, op, *args):
        nd = nodes.new("ShaderNodeMath")
        nd.operation = op
        for sock, a in zip(nd.inputs, args):
            if isinstance(a, (int, float)):
                sock.default_value = a
            else:
                links.new(a, sock)
        return nd.outputs[0]

    def pick(nodes, links, tile, leaf, lo, hi, first=lambda i: i):
        """The shader of leaves lo .. hi - 1 (``leaf(i)``, from tile
        ``first(i)`` on) by the tile index."""
        if hi - lo == 1:
            return leaf(lo)
        mid = (lo + hi) // 2
        mix = nodes.new("ShaderNodeMixShader")
        links.new(math(nodes, links, "GREATER_THAN", tile, first(mid) - 0.5), mix.inputs[0])
        links.new(pick(nodes, links, tile, leaf, lo, mid, first), mix.inputs[1])
        links.new(pick(nodes, links, tile, leaf, mid, hi, first), mix.inputs[2])
        return mix.outputs[0]

    def group(nodes, links, uvt, lo, hi):
        """A Group node showing tiles lo .. hi - 1 from a node tree of its own
        (fed u, v and the tile index), leaf n every tile past the builds."""
        ng = bpy().data.node_groups.new(f"Tiles {lo}", "ShaderNodeTree")
        for name in ("u", "v", "tile"):
            ng.interface.new_socket(name, in_out="INPUT", socket_type="NodeSocketFloat")
        ng.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
        gn, gl = ng.nodes, ng.links
        gin = gn.new("NodeGroupInput")
        u, v, tile = gin.outputs[0], gin.outputs[1], gin.outputs[2]

        def emission(i):
            em = gn.new("ShaderNodeEmission")
            em.inputs["Strength"].default_value = 1.0
            if i < n:
                gl.new(builds[i](gn, gl, u, v), em.inputs["Color"])
            else:
                em.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
            return em.outputs[0]

        gl.new(pick(gn, gl, tile, emission, lo, hi), gn.new("NodeGroupOutput").inputs[0])
        group = nodes.new("ShaderNodeGroup")
        group.node_tree = ng
        for value, sock in zip(uvt, group.inputs):
            links.new(value, sock)
        return group.outputs[0]

    def build(nodes, links, vector):
        exact_centres(nodes, links, vector, res)
        centres = vector.node.inputs["Vector"].links[0].from_socket
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(centres, sep.inputs[0])
        x, y = sep.outputs["X"], sep.outputs["Y"]
        u = math(nodes, links, "FRACT", math(nodes, links, "MULTIPLY", x, half))
        v = math(nodes, links, "FRACT", math(nodes, links, "MULTIPLY", y, half))
        col = math(nodes, links, "FLOOR", math(nodes, links, "MULTIPLY_ADD", x, half, half))
        row = math(nodes, links, "FLOOR", math(nodes, links, "MULTIPLY_ADD", y, -half, half))
        tile = math(nodes, links, "MULTIPLY_ADD", row, float(tiles), col)
        # leaves 0 .. n - 1 the builds, leaf n (if any) every tile past them,
        # by rows of ``tiles`` leaves in node groups
        leaves = n + 1 if n < tiles * tiles else n
        rows = range(0, leaves, tiles)
        return pick(nodes, links, tile, lambda r: group(
            nodes, links, (u, v, tile), rows[r], min(rows[r] + tiles, leaves)),
            0, len(rows), lambda r: rows[r])

    img, pts = cycles_values(build, tmp_path, res=res)
    s = res // tiles
    result = []
    for i in range(n):
        r, c = divmod(i, tiles)
        sl = (slice(r * s, (r + 1) * s), slice(c * s, (c + 1) * s))
        p = pts[sl].reshape(-1, 3)
        u, v = p[:, 0] * half % 1.0, p[:, 1] * half % 1.0
        result.append((img[sl].reshape(-1, 3), u, v))
    return result


class Case(NamedTuple):
    """A texture node for :func:`mosaic`: ``kind`` (NODE_TYPES) read at
    ``output``, its ``params`` (sockets by name, properties by identifier,
    as procedural.evaluate reads them); ``linked`` links inputs to a
    component ('X', 'Y', 'Z') of the texture-space point (ours gets that
    component as an (n,) array); ``snap`` > 0 feeds the node the point
    snapped to that grid (Vector Math Snap; a hash of float bits needs the
    very float32 point); the Mapping's ``location``, ``rotation``,
    ``scale``."""
    kind: str
    output: str
    params: dict
    linked: dict = {}
    snap: float = 0.0
    location: tuple = (0.0, 0.0, 0.0)
    rotation: tuple = (0.0, 0.0, 0.0)
    scale: tuple = (1.0, 1.0, 1.0)


def mosaic(cases, tmp_path, res: int = 128, tiles: int = 8):
    """[(ours, theirs) (s*s, 3) float64 per case]: our and Cycles' values of
    each :class:`Case` over its s x s tile (s = res / tiles) of
    :func:`tiled_values`' renders (tiles * tiles cases a render), at the
    texture-space points of the case's Mapping at the tile's pixel centres
    as a plane of its own: (2u - 1, 2v - 1, 0), the points of an s x s
    render of the whole plane (:func:`cycles_values`), exact in float32.
    Cases of the same Mapping and snap share those nodes."""
    per = tiles * tiles
    result = []
    for k in range(0, len(cases), per):
        chunk = cases[k:k + per]
        shared = {}

        def point(nodes, links, u, v, case):
            """The case's (snapped) texture-space point, and its Separate XYZ,
            shared in a node tree."""
            tree = nodes.id_data.as_pointer()
            key = (tree, case.location, case.rotation, case.scale, case.snap)
            if key not in shared:
                if tree not in shared:
                    q = nodes.new("ShaderNodeCombineXYZ")
                    for t, sock in zip((u, v), q.inputs):
                        m = nodes.new("ShaderNodeMath")
                        m.operation = "MULTIPLY_ADD"
                        links.new(t, m.inputs[0])
                        m.inputs[1].default_value = 2.0
                        m.inputs[2].default_value = -1.0
                        links.new(m.outputs[0], sock)
                    shared[tree] = q.outputs[0]
                mp = nodes.new("ShaderNodeMapping")
                mp.inputs["Location"].default_value = case.location
                mp.inputs["Rotation"].default_value = case.rotation
                mp.inputs["Scale"].default_value = case.scale
                links.new(shared[tree], mp.inputs["Vector"])
                vec = mp.outputs["Vector"]
                if case.snap:
                    sn = nodes.new("ShaderNodeVectorMath")
                    sn.operation = 'SNAP'
                    sn.inputs[1].default_value = (case.snap,) * 3
                    links.new(vec, sn.inputs[0])
                    vec = sn.outputs[0]
                sep = nodes.new("ShaderNodeSeparateXYZ")
                links.new(vec, sep.inputs[0])
                shared[key] = vec, sep
            return shared[key]

        def builder(case):
            def build(nodes, links, u, v):
                vec, sep = point(nodes, links, u, v, case)
                nd = add_node(nodes, case.kind, case.params)
                if nd.inputs.get("Vector") is not None:     # not 1D Voronoi's
                    links.new(vec, nd.inputs["Vector"])
                for name, comp in case.linked.items():
                    links.new(sep.outputs[comp], next(s for s in nd.inputs if s.name == name))
                return next(s for s in nd.outputs if s.name == case.output)
            return build

        shown = tiled_values([builder(c) for c in chunk], tmp_path, res, tiles)
        for case, (theirs, u, v) in zip(chunk, shown):
            q = np.stack([2.0 * u - 1.0, 2.0 * v - 1.0, np.zeros_like(u)], -1)
            p = map_points(q, case.location, case.rotation, case.scale)
            if case.snap:
                p = np.floor(p / case.snap) * case.snap
            ps = dict(case.params, **{name: p[:, "XYZ".index(comp)]
                                      for name, comp in case.linked.items()})
            result.append((procedural.evaluate(case.kind, case.output, ps, p), theirs))
    return result
