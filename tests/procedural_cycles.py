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
"""
from __future__ import annotations

import numpy as np

from bpy_helpers import _ensure_nodes, add_plane, bpy, empty_scene, link, set_world

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


def mapped_points(res: int, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0),
                  scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(res, res, 3) float64 the Mapping node's Point output at the pixel
    centres, row 0 at the top (as ``read_exr`` gives Cycles' image)."""
    from mathutils import Euler
    c = (np.arange(res) + 0.5) / res * EXTENT - EXTENT / 2
    x, y = np.meshgrid(c, c[::-1])
    p = np.stack([x, y, np.zeros_like(x)], -1) * np.asarray(scale, np.float64)
    R = np.array(Euler(rotation, 'XYZ').to_matrix(), np.float64)
    return p @ R.T + np.asarray(location, np.float64)


def cycles_values(build, tmp_path, res: int = 64, location=(0.0, 0.0, 0.0),
                  rotation=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):
    """(values (res, res, 3) float64, points (res, res, 3) float64): what
    Cycles shows of ``build(nodes, links, vector_socket) -> output socket``
    at the pixel centres, and the texture-space point of each
    (:func:`mapped_points`)."""
    b = bpy()
    sc = empty_scene((res, res), engine='CYCLES')
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
    links.new(build(nodes, links, mp.outputs["Vector"]), em.inputs["Color"])
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
    build's inputs.  Each tile is picked by a Mix node of type VECTOR whose
    factor is exactly 0 or 1 (a (1 - t) + b t passes either side unchanged,
    as long as every build's output is finite at every pixel), so a float
    output shows as grey, a vector or colour as it is: any value, negative
    and large ones too (the EXR keeps float32)."""
    assert len(builds) <= tiles * tiles and res % tiles == 0
    half = tiles / 2

    def build(nodes, links, vector):
        exact_centres(nodes, links, vector, res)
        centres = vector.node.inputs["Vector"].links[0].from_socket

        def math(op, *args):
            nd = nodes.new("ShaderNodeMath")
            nd.operation = op
            for sock, a in zip(nd.inputs, args):
                if isinstance(a, (int, float)):
                    sock.default_value = a
                else:
                    links.new(a, sock)
            return nd.outputs[0]

        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(centres, sep.inputs[0])
        x, y = sep.outputs["X"], sep.outputs["Y"]
        u = math("FRACT", math("MULTIPLY", x, half))
        v = math("FRACT", math("MULTIPLY", y, half))
        col = math("FLOOR", math("MULTIPLY_ADD", x, half, half))
        row = math("FLOOR", math("MULTIPLY_ADD", y, -half, half))
        tile = math("MULTIPLY_ADD", row, float(tiles), col)
        out = centres
        for i, b in enumerate(builds):
            mix = nodes.new("ShaderNodeMix")
            mix.data_type = "VECTOR"
            mix.clamp_factor = False
            ins = {s.identifier: s for s in mix.inputs}
            links.new(math("COMPARE", tile, float(i), 0.25), ins["Factor_Float"])
            links.new(out, ins["A_Vector"])
            links.new(b(nodes, links, u, v), ins["B_Vector"])
            out = next(s for s in mix.outputs if s.identifier == "Result_Vector")
        return out

    img, pts = cycles_values(build, tmp_path, res=res)
    s = res // tiles
    result = []
    for i in range(len(builds)):
        r, c = divmod(i, tiles)
        sl = (slice(r * s, (r + 1) * s), slice(c * s, (c + 1) * s))
        p = pts[sl].reshape(-1, 3)
        u, v = p[:, 0] * half % 1.0, p[:, 1] * half % 1.0
        result.append((img[sl].reshape(-1, 3), u, v))
    return result
