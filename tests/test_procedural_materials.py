"""Procedural textures in materials, baked into atlases at export
(addon/export_atlas.py, core/scene/atlas.py), rendered against Cycles.

The ports themselves are checked pixel by pixel against Cycles in
tests/test_procedural_noise.py, test_procedural_voronoi.py and
test_procedural_patterns.py; here, what the bake feeds: a colour, a
roughness map, a bump, a mix of an image read at its UVs with a procedural
read at its Generated coordinates, a float chain into a Mix Shader.  The
scenes and the bound are tests/test_shading_nodes.py's (a plane under a
sun, 2x the seed-to-seed noise plus 1 % of the mean), each with the
effect check: the texture moves the image by more than 3x that bound.
Then the atlas's own maths: an affine function is baked and read back to
float32 rounding; blocks never overlap; instances share their blocks.
"""
from __future__ import annotations

import numpy as np
import pytest

from core.scene import atlas as AT
from core.scene.textures import sample_texture


def test_an_affine_function_baked_reads_back_exactly():
    """Every bilinear lookup inside a triangle reads its own block only, and
    the texels hold the triangle's plane extended: an affine function of
    the point comes back to float32 rounding (measured 2.5e-6), and no
    texel belongs to two blocks."""
    rng = np.random.default_rng(1)
    T = 400
    P = rng.normal(size=(T, 3, 3))
    L = AT.pack(AT.block_sizes(AT.extent(P), 10.0))
    tx = AT.texels(L)
    owners = np.zeros((L.height, L.width), np.int64)
    np.add.at(owners, (tx.iy, tx.ix), 1)
    assert owners.max() == 1
    a = np.array([[0.3, -0.2, 0.5], [1.0, 0.1, -0.4], [0.2, 0.2, 0.2]])
    img = AT.image(L, tx, AT.at_texels(P, tx) @ a.T + 0.1)
    b = rng.dirichlet([1, 1, 1], size=T)
    uv = np.einsum('tk,tkd->td', b, AT.corner_uvs(L).astype(np.float64))
    got = sample_texture(img, uv)
    want = np.einsum('tk,tkd->td', b, P) @ a.T + 0.1
    assert np.abs(got - want).max() < 2e-5


def test_the_budget_caps_the_blocks():
    """Sizes follow extent x density, rounded up to atlas.SIZES, and the
    density drops until the texels fit the budget."""
    n = AT.block_sizes(np.array([0.1, 1.0, 10.0]), 10.0)
    assert list(n) == [1, 12, 128]
    ext = np.full(1000, 1.0)
    n = AT.block_sizes(ext, 1000.0, budget=100_000)
    assert np.sum((n + 2) ** 2) <= 100_000 and n[0] >= 6


#: (kind, output, params, bound on the bake's mean |error| over the mean
#: value): measured at the densities of atlas.procedural_density.
BAKES = [
    ("TEX_NOISE", "Color", {}, 0.005),          # measured 0.16 %
    ("TEX_NOISE", "Factor", {"Detail": 5.0}, 0.002),   # 0.06 %
    ("TEX_VORONOI", "Distance", {}, 0.002),     # 0.04 %
    ("TEX_VORONOI", "Color", {}, 0.015),        # 0.46 % (cell borders)
    ("TEX_CHECKER", "Color", {}, 0.04),         # 1.4 % (square borders)
    ("TEX_WAVE", "Color", {}, 0.03),            # 1.1 % (8 texels a period)
    ("TEX_MAGIC", "Color", {}, 0.008),          # 0.23 %
    ("TEX_BRICK", "Color", {}, 0.04),           # 1.3 % (mortar lines)
    ("TEX_GRADIENT", "Color", {"gradient_type": "SPHERICAL"}, 0.025),   # 0.8 %
]


@pytest.mark.parametrize("kind,output,params,bound", BAKES, ids=[f"{b[0]}-{b[1]}" for b in BAKES])
def test_a_bake_reads_back_its_procedural(kind, output, params, bound):
    """The bake at atlas.procedural_density (8 texels a feature of the finest
    detail, 4 for a Noise, 32 for sharp patterns) read back by the bilinear lookup at
    random points of 30 small triangles against the procedural evaluated
    there: the mean |error| over the mean value.  A smooth pattern's error
    is the bilinear's h^2 / 8 of its curvature; a sharp one's, the texel
    its edges blur over."""
    from core.scene import procedural as PR
    rng = np.random.default_rng(3)
    T = 30
    P = rng.uniform(0, 1, size=(T, 1, 3)) + rng.normal(scale=0.06, size=(T, 3, 3))
    L = AT.pack(AT.block_sizes(AT.extent(P) * AT.procedural_density(kind, params), 1.0))
    tx = AT.texels(L)
    img = AT.image(L, tx, PR.evaluate(kind, output, params, AT.at_texels(P, tx)))
    b = rng.dirichlet([1, 1, 1], size=20 * T)
    tri = np.tile(np.arange(T), 20)
    got = sample_texture(img, np.einsum('nk,nkd->nd', b, AT.corner_uvs(L)[tri].astype(float)))
    want = PR.evaluate(kind, output, params, np.einsum('nk,nkd->nd', b, P[tri]))
    assert np.abs(got - want).mean() / np.abs(want).mean() < bound


# ------------------------------------------------------------------ against Cycles

def _scene(build):
    import test_shading_nodes as TS
    return TS.plane_scene(build)


def _compare(sc, tmp_path, label):
    import test_shading_nodes as TS
    return TS.compare(sc, tmp_path, label)


def _check(err, noise, effect=None):
    import test_shading_nodes as TS
    TS._check(err, noise, effect)


def _effect(img, scene, replace):
    """Mean |img - the image with the baked textures replaced by ``replace``
    (C,) texels| over the mean: what the texture changes."""
    import dataclasses
    import test_shading_nodes as TS
    flat = [np.broadcast_to(np.asarray(replace, np.float32), (1, 1, 4)).copy()
            for _ in scene.textures]
    plain = TS._fppm(dataclasses.replace(scene, textures=flat), 1)
    return float(np.abs(plain - img).mean() / img.mean())


def _image_node(nodes, name="A", pixels=None):
    """An Image Texture node of tests/test_shading_nodes.py's colour pixels
    (or ``pixels``), an sRGB image ``name``."""
    import test_shading_nodes as TS
    im = nodes.new('ShaderNodeTexImage')
    im.image = TS._image(name, TS._color_pixels() if pixels is None else pixels,
                         non_color=False)
    return im


def _position_xyz(nodes, links):
    """A Separate XYZ of the Geometry node's Position."""
    geo = nodes.new('ShaderNodeNewGeometry')
    sep = nodes.new('ShaderNodeSeparateXYZ')
    links.new(geo.outputs['Position'], sep.inputs[0])
    return sep


def _mix(nodes, links, blend, factor, a, b):
    """A Mix (Color) node of sockets a and b; its Result socket."""
    mix = nodes.new('ShaderNodeMix')
    mix.data_type = 'RGBA'
    mix.blend_type = blend
    mix.inputs['Factor'].default_value = factor
    links.new(a, mix.inputs['A'])
    links.new(b, mix.inputs['B'])
    return mix.outputs['Result']


def _diffuse(nodes, links, surface):
    import test_shading_nodes as TS
    return TS.diffuse_with_normal(nodes, links, surface)


@pytest.mark.parametrize("output", ["Color", "Factor"])
def test_a_checker_colour_agrees_with_cycles(output, tmp_path):
    """Checker (Generated coordinates, the unlinked default) into a Diffuse
    Color.  Measured: 0.90x the seed-to-seed noise; a flat grey instead moves
    the image by 8x the bound."""
    pytest.importorskip("bpy")

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        ck = nodes.new('ShaderNodeTexChecker')
        ck.inputs['Scale'].default_value = 4.0
        ck.inputs['Color1'].default_value = (0.9, 0.6, 0.2, 1.0)
        ck.inputs['Color2'].default_value = (0.1, 0.2, 0.5, 1.0)
        links.new(ck.outputs[output], d.inputs['Color'])

    sc, _ = _scene(mat)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, f"checker {output}")
    assert lines[1] == "Approximated: nothing.", lines[1]
    assert len(scene.textures) == 1 and scene.textures[0].shape[0] > 100
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


def test_images_read_at_different_vectors_agree_with_cycles(tmp_path):
    """A Multiply of two images, one at the UV map, one at Object
    coordinates through a rotating Mapping: FPPM read both at the first's
    vector before atlases.  Measured: 0.85x the seed-to-seed noise; the
    second image at the first's vector (Cycles' render of it) is 24 % of
    the mean away, 6.7x the bound."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        a = _image_node(nodes)
        b = _image_node(nodes, "B", TS._color_pixels(4)[:, ::-1].copy())
        tc = nodes.new('ShaderNodeTexCoord')
        mp = nodes.new('ShaderNodeMapping')
        mp.inputs['Rotation'].default_value = (0.0, 0.0, 0.7)
        mp.inputs['Scale'].default_value = (1.7, 1.7, 1.0)
        links.new(tc.outputs['Object'], mp.inputs['Vector'])
        links.new(mp.outputs['Vector'], b.inputs['Vector'])
        links.new(_mix(nodes, links, 'MULTIPLY', 1.0, a.outputs['Color'], b.outputs['Color']),
                  d.inputs['Color'])

    sc, ob = _scene(mat)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "two vectors")
    assert lines[1] == "Approximated: nothing.", lines[1]
    # What FPPM rendered before: the second image at the first's vector.
    nt = ob.data.materials[0].node_tree
    b = next(nd for nd in nt.nodes if nd.type == 'TEX_IMAGE' and nd.image.name == "B")
    nt.links.remove(b.inputs['Vector'].links[0])
    old = TS._cycles(sc, 0, tmp_path / "old.exr")
    _check(err, noise, float(np.abs(old - ref).mean() / ref.mean()))


def _noise(nodes, links, scale=4.0, detail=2.0, vector=None):
    nz = nodes.new('ShaderNodeTexNoise')
    nz.inputs['Scale'].default_value = scale
    nz.inputs['Detail'].default_value = detail
    if vector is not None:
        links.new(vector, nz.inputs['Vector'])
    return nz


def _ramp(nodes, links, src, a, b, at=(0.3, 0.7)):
    """A Color Ramp from ``a`` to ``b`` (rgba) at positions ``at``, fed by ``src``."""
    cr = nodes.new('ShaderNodeValToRGB')
    cr.color_ramp.elements[0].position = at[0]
    cr.color_ramp.elements[0].color = a
    cr.color_ramp.elements[1].position = at[1]
    cr.color_ramp.elements[1].color = b
    links.new(src, cr.inputs['Fac'])
    return cr


def test_a_noise_roughness_map_agrees_with_cycles(tmp_path):
    """Noise (Object coordinates of a turned Empty, through a Mapping) ->
    Color Ramp -> a metal's Roughness, read per hit from the bake
    (core/materials/rough_maps.py).  Measured: 0.86x the seed-to-seed noise;
    the bake's mean roughness everywhere moves the image by 59 % of the
    mean, 7x the bound."""
    import bpy
    pytest.importorskip("bpy")

    def mat(nodes, links, surface):
        p = nodes.new('ShaderNodeBsdfPrincipled')
        p.inputs['Metallic'].default_value = 1.0
        p.inputs['Base Color'].default_value = (0.9, 0.8, 0.6, 1.0)
        links.new(p.outputs[0], surface)
        e = bpy.data.objects.new("Ref", None)
        e.location = (0.3, 0.1, 0.2)
        e.rotation_euler = (0.0, 0.0, 0.4)
        bpy.context.scene.collection.objects.link(e)
        tc = nodes.new('ShaderNodeTexCoord')
        tc.object = e
        mp = nodes.new('ShaderNodeMapping')
        mp.inputs['Rotation'].default_value = (0.2, 0.0, 0.5)
        links.new(tc.outputs['Object'], mp.inputs['Vector'])
        nz = _noise(nodes, links, 2.5, 1.0, mp.outputs['Vector'])
        cr = _ramp(nodes, links, nz.outputs['Factor'], (0.05, 0.05, 0.05, 1.0),
                   (0.8, 0.8, 0.8, 1.0))
        links.new(cr.outputs['Color'], p.inputs['Roughness'])

    import test_shading_nodes as TS
    sc, _ = TS.plane_scene(mat, sun_rotation=(0.35, 0.0, 0.0))
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "noise roughness")
    assert lines[1] == "Approximated: nothing.", lines[1]
    lobe = next(lb for m in scene.materials for lb in m.lobes if lb.roughness_texture >= 0)
    mean = scene.materials[0]
    import dataclasses
    flat = dataclasses.replace(scene, materials=[dataclasses.replace(
        mean, lobes=tuple(dataclasses.replace(lb, roughness_texture=-1) for lb in mean.lobes))])
    plain = TS._fppm(flat, 1)
    assert 0.1 < lobe.roughness < 0.7
    _check(err, noise, float(np.abs(plain - img).mean() / img.mean()))


def test_a_noise_bump_agrees_with_cycles(tmp_path):
    """Noise Factor (Generated coordinates) into a Bump's Height (distance
    0.3).  Measured: 0.87x the seed-to-seed noise; without the bump the
    image moves by 3.4x the bound."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        nz = _noise(nodes, links, 6.0, 1.0)
        bump = nodes.new('ShaderNodeBump')
        bump.inputs['Distance'].default_value = 0.3
        links.new(nz.outputs['Factor'], bump.inputs['Height'])
        links.new(bump.outputs['Normal'], d.inputs['Normal'])

    sc, _ = _scene(mat)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "noise bump")
    assert lines[1] == TS.PHOTON_NOTE, lines[1]
    plain = TS._fppm(TS._without_normals(scene), 1)
    _check(err, noise, float(np.abs(plain - img).mean() / img.mean()))


def test_a_noise_mixed_with_an_image_agrees_with_cycles(tmp_path):
    """An image at its UVs times a Noise Color at Generated coordinates
    (Overlay blend), into a Principled Base Color.  Measured: 0.84x the
    seed-to-seed noise; flat grey textures move the image by 12x the bound."""
    pytest.importorskip("bpy")

    def mat(nodes, links, surface):
        p = nodes.new('ShaderNodeBsdfPrincipled')
        links.new(p.outputs[0], surface)
        im = _image_node(nodes)
        nz = _noise(nodes, links, 5.0, 2.0)
        links.new(_mix(nodes, links, 'OVERLAY', 0.8, im.outputs['Color'], nz.outputs['Color']),
                  p.inputs['Base Color'])

    sc, _ = _scene(mat)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "noise x image")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


# ------------------------------------------------------------ node graphs per texel

def distorted_noise_roughness(nodes, links, p):
    """A metal Principled ``p`` whose Roughness is a Noise Factor through Map
    Range (smoothstep) and Math (multiply, clamped), the Noise's vector the
    Generated coordinates distorted by a second Noise's Color (also
    bench/bench_atlas.py's graph)."""
    p.inputs['Metallic'].default_value = 1.0
    warp = _noise(nodes, links, 3.0, 0.0)
    tc = nodes.new('ShaderNodeTexCoord')
    add = nodes.new('ShaderNodeVectorMath')
    add.operation = 'MULTIPLY_ADD'
    add.inputs[1].default_value = (0.3, 0.3, 0.3)
    links.new(warp.outputs['Color'], add.inputs[0])
    links.new(tc.outputs['Generated'], add.inputs[2])
    nz = _noise(nodes, links, 2.5, 1.0, add.outputs['Vector'])
    mr = nodes.new('ShaderNodeMapRange')
    mr.interpolation_type = 'SMOOTHSTEP'
    mr.inputs['From Min'].default_value = 0.35
    mr.inputs['From Max'].default_value = 0.65
    mr.inputs['To Min'].default_value = 0.05
    mr.inputs['To Max'].default_value = 0.9
    links.new(nz.outputs['Factor'], mr.inputs['Value'])
    mul = nodes.new('ShaderNodeMath')
    mul.operation = 'MULTIPLY'
    mul.use_clamp = True
    mul.inputs[1].default_value = 1.1
    links.new(mr.outputs['Result'], mul.inputs[0])
    links.new(mul.outputs['Value'], p.inputs['Roughness'])


def test_a_noise_through_map_range_and_math_agrees_with_cycles(tmp_path):
    """Noise Factor -> Map Range (smoothstep) -> Math (multiply, clamped)
    into a Principled Roughness, and the Noise's vector distorted by a
    Vector Math Add of a second noise's colour: the graph evaluated per
    texel (core/scene/shader_graph.py).  Measured: 0.82x the seed-to-seed
    noise; the graph's mean roughness everywhere moves the image by 20x the
    bound."""
    pytest.importorskip("bpy")
    import dataclasses

    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        p = nodes.new('ShaderNodeBsdfPrincipled')
        links.new(p.outputs[0], surface)
        distorted_noise_roughness(nodes, links, p)

    sc, _ = TS.plane_scene(mat, sun_rotation=(0.35, 0.0, 0.0))
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "noise map range")
    assert lines[1] == "Approximated: nothing.", lines[1]
    m = scene.materials[0]
    flat = dataclasses.replace(scene, materials=[dataclasses.replace(
        m, lobes=tuple(dataclasses.replace(lb, roughness_texture=-1) for lb in m.lobes))])
    plain = TS._fppm(flat, 1)
    _check(err, noise, float(np.abs(plain - img).mean() / img.mean()))


@pytest.mark.parametrize("domain", ["POINT", "CORNER"])
def test_colour_attributes_agree_with_cycles(domain, tmp_path):
    """A Color Attribute node (random colours on the vertices or the face
    corners of a subdivided plane) into a Diffuse Color: the corners' values
    interpolated over each triangle, as Cycles does.  Measured: 0.82x and
    0.83x the seed-to-seed noise; flat grey moves the image by 14x and 6.7x
    the bound."""
    pytest.importorskip("bpy")
    import bpy

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        ca = nodes.new('ShaderNodeVertexColor')
        ca.layer_name = "Paint"
        links.new(ca.outputs['Color'], d.inputs['Color'])

    sc, ob = _scene(mat)
    me = ob.data
    bpy.context.view_layer.objects.active = ob
    import bmesh
    bm = bmesh.new()
    bm.from_mesh(me)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=3, use_grid_fill=True)
    bm.to_mesh(me)
    bm.free()
    at = me.color_attributes.new("Paint", 'FLOAT_COLOR', domain)
    rng = np.random.default_rng(4)
    cols = rng.uniform(0.05, 0.95, size=(len(at.data), 4))
    cols[:, 3] = 1.0
    at.data.foreach_set("color", cols.ravel())
    me.update()
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, f"colour attribute {domain}")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


def test_position_through_math_agrees_with_cycles(tmp_path):
    """Geometry Position -> Separate XYZ -> Math (sine of 7 x + 3 y) -> Color
    Ramp into a Diffuse Color: world-space attributes per instance.
    Measured: 0.78x the seed-to-seed noise; flat grey moves the image by
    13x the bound."""
    pytest.importorskip("bpy")

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        sep = _position_xyz(nodes, links)
        ma = nodes.new('ShaderNodeMath')
        ma.operation = 'MULTIPLY_ADD'
        ma.inputs[1].default_value = 7.0
        links.new(sep.outputs['X'], ma.inputs[0])
        m2 = nodes.new('ShaderNodeMath')
        m2.operation = 'MULTIPLY'
        m2.inputs[1].default_value = 3.0
        links.new(sep.outputs['Y'], m2.inputs[0])
        links.new(m2.outputs[0], ma.inputs[2])
        sn = nodes.new('ShaderNodeMath')
        sn.operation = 'SINE'
        links.new(ma.outputs[0], sn.inputs[0])
        cr = _ramp(nodes, links, sn.outputs[0], (0.1, 0.3, 0.8, 1.0), (0.9, 0.7, 0.2, 1.0))
        cr.color_ramp.elements[0].position = 0.0
        links.new(cr.outputs['Color'], d.inputs['Color'])

    sc, _ = _scene(mat)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "position math")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


def test_an_image_through_math_is_baked_over_its_own_uvs(tmp_path):
    """An image at the render UV through Separate Color, Math (power) and
    Combine Color into a Diffuse Color: a function of the uv that repeats
    with the image, baked once over the image's grid (enlarged 8x for the
    nonlinear nodes), the triangles' uvs kept: no atlas, no resolution
    lost.  Measured: 0.84x the seed-to-seed noise; the image without the
    nodes moves the image by 8.9x the bound."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        im = _image_node(nodes)
        sep = nodes.new('ShaderNodeSeparateColor')
        links.new(im.outputs['Color'], sep.inputs[0])
        pw = nodes.new('ShaderNodeMath')
        pw.operation = 'POWER'
        pw.inputs[1].default_value = 3.0
        links.new(sep.outputs['Red'], pw.inputs[0])
        comb = nodes.new('ShaderNodeCombineColor')
        links.new(pw.outputs[0], comb.inputs['Red'])
        links.new(sep.outputs['Green'], comb.inputs['Green'])
        links.new(sep.outputs['Blue'], comb.inputs['Blue'])
        links.new(comb.outputs['Color'], d.inputs['Color'])

    sc, ob = _scene(mat)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "image math")
    assert lines[1] == "Approximated: nothing.", lines[1]
    assert scene.textures[-1].shape[:2] == (64, 64)
    assert np.allclose(scene.tri_uv.min(), 0.0) and np.allclose(scene.tri_uv.max(), 1.5)
    nt = ob.data.materials[0].node_tree
    im = next(nd for nd in nt.nodes if nd.type == 'TEX_IMAGE')
    d = next(nd for nd in nt.nodes if nd.type == 'BSDF_DIFFUSE')
    nt.links.new(im.outputs['Color'], d.inputs['Color'])
    plain = TS._cycles(sc, 0, tmp_path / "plain.exr")
    _check(err, noise, float(np.abs(plain - ref).mean() / ref.mean()))


def test_a_graph_that_raises_is_grey_with_a_note(monkeypatch):
    """A port raising while a bake evaluates (here Math, made to raise) costs
    that material its texture, not the render: the texture is the
    exporter's diffuse grey and the render log says why."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    from core.scene import node_math

    def boom(*args, **kwargs):
        raise ValueError("made to fail")
    monkeypatch.setattr(node_math, "math", boom)

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        sep = _position_xyz(nodes, links)
        sn = nodes.new('ShaderNodeMath')
        sn.operation = 'SINE'
        links.new(sep.outputs['X'], sn.inputs[0])
        links.new(sn.outputs[0], d.inputs['Color'])

    _scene(mat)
    scene, lines = TS._export()
    assert "its texture graph could not be evaluated (ValueError: made to fail): grey" \
        in lines[1], lines[1]
    assert np.all(scene.textures[-1][..., :3] == np.float32(0.8))


def test_object_info_agrees_with_cycles(tmp_path):
    """Object Info Random (through a Color Ramp) and Color into a Diffuse, on
    the plane, a copy of it sharing its mesh, and an instance of a
    collection holding it: one value an object, Random as Cycles syncs it
    (the instance's random_id, else a hash of the object's name).  Measured:
    0.8x the seed-to-seed noise."""
    pytest.importorskip("bpy")
    import bpy

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        oi = nodes.new('ShaderNodeObjectInfo')
        cr = _ramp(nodes, links, oi.outputs['Random'], (0.05, 0.2, 0.9, 1.0),
                   (0.95, 0.6, 0.1, 1.0), (0.0, 1.0))
        links.new(_mix(nodes, links, 'MULTIPLY', 1.0, cr.outputs['Color'],
                       oi.outputs['Color']), d.inputs['Color'])

    sc, ob = _scene(mat)
    ob.scale = (0.3, 0.3, 1.0)
    ob.location = (-0.4, 0.3, 0.0)
    ob.color = (0.9, 1.0, 0.8, 1.0)
    copy = ob.copy()
    copy.name = "Plane copy"
    copy.location = (0.35, 0.3, 0.0)
    copy.color = (1.0, 0.7, 1.0, 1.0)
    sc.collection.objects.link(copy)
    coll = bpy.data.collections.new("Tiles")
    coll.objects.link(ob.copy())
    inst = bpy.data.objects.new("Tiles instance", None)
    inst.instance_type = 'COLLECTION'
    inst.instance_collection = coll
    inst.location = (0.8, -0.7, 0.0)
    sc.collection.objects.link(inst)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "object info")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


def test_too_many_triangles_for_blocks_give_one_texel_a_triangle(monkeypatch):
    """Past atlas.HARD_CAP (here lowered to 1) each triangle of an atlas
    material gets one texel, its centroid's value, every corner reading it,
    and the render log says so."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    from core.scene import atlas
    monkeypatch.setattr(atlas, "HARD_CAP", 1)

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        links.new(_position_xyz(nodes, links).outputs['X'], d.inputs['Color'])

    _scene(mat)
    scene, lines = TS._export()
    assert "2 triangles: its textures one value a triangle (atlas budget)" in lines[1], lines[1]
    tex = scene.textures[-1]
    assert tex.shape[:2] == (1, 2)
    assert np.all(scene.tri_uv == scene.tri_uv[:, :1])
    centroid_x = scene.tri_p.astype(np.float64).mean(axis=1)[:, 0]
    assert np.allclose(np.sort(tex[0, :, 0]), np.sort(centroid_x), atol=1e-6)


def test_an_unchanged_atlas_is_not_baked_again(monkeypatch):
    """Exporting the same scene again (the viewport does after every edit)
    reuses the atlas: the same uvs and textures, no bake; a changed node
    value bakes anew."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    from fppm.addon import export_atlas

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        nz = _noise(nodes, links, 4.0, 1.0)
        links.new(nz.outputs['Color'], d.inputs['Color'])

    _, ob = _scene(mat)
    first, _ = TS._export()
    calls = []
    real = export_atlas.AtlasBaker._layout_and_bake

    def counted(self, *args):
        calls.append(1)
        return real(self, *args)
    monkeypatch.setattr(export_atlas.AtlasBaker, "_layout_and_bake", counted)
    again, _ = TS._export()
    assert not calls
    assert np.array_equal(first.tri_uv, again.tri_uv)
    assert np.array_equal(first.textures[-1], again.textures[-1])
    nz = next(nd for nd in ob.data.materials[0].node_tree.nodes if nd.type == 'TEX_NOISE')
    nz.inputs['Scale'].default_value = 5.0
    TS._export()
    assert len(calls) == 1


def test_a_procedurals_properties_are_its_params():
    """Every enum, boolean, int and float property of a procedural node is a
    param of its port (a Brick's offset, squash and their frequencies), and
    none of the properties every node has."""
    pytest.importorskip("bpy")
    import bpy

    from fppm.addon.export_atlas import procedural_params
    m = bpy.data.materials.new("Params")
    nd = m.node_tree.nodes.new('ShaderNodeTexBrick')
    nd.offset, nd.offset_frequency, nd.squash, nd.squash_frequency = 0.3, 3, 1.5, 4
    params = procedural_params(nd, lambda sock: (None, None, sock), [])
    assert {k: params[k] for k in ("offset", "offset_frequency", "squash",
                                   "squash_frequency")} == pytest.approx(
        {"offset": 0.3, "offset_frequency": 3, "squash": 1.5, "squash_frequency": 4})
    assert not {"width", "location", "mute", "select"} & set(params)
    assert params["Scale"] == 5.0 and "Vector" not in params
    bpy.data.materials.remove(m)


@pytest.mark.parametrize("projection", ["BOX", "SPHERE", "TUBE"])
def test_image_projections_agree_with_cycles(projection, tmp_path):
    """An Image Texture projected Box (blend 0.3, the plane tilted so that
    its normal mixes the three faces), Sphere or Tube, at Object coordinates
    through a Mapping: Cycles' svm_node_tex_image_box weights and
    map_to_sphere / map_to_tube (FPPM read the image flat before, noted)."""
    pytest.importorskip("bpy")

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        im = _image_node(nodes)
        im.projection = projection
        im.projection_blend = 0.3
        tc = nodes.new('ShaderNodeTexCoord')
        mp = nodes.new('ShaderNodeMapping')
        mp.inputs['Scale'].default_value = (0.6, 0.6, 0.6)
        mp.inputs['Location'].default_value = (0.5, 0.5, 0.5)
        mp.inputs['Rotation'].default_value = (0.7, 0.5, 0.0)   # z varies over the plane
        links.new(tc.outputs['Object'], mp.inputs['Vector'])
        links.new(mp.outputs['Vector'], im.inputs['Vector'])
        links.new(im.outputs['Color'], d.inputs['Color'])

    sc, ob = _scene(mat)
    ob.rotation_euler = (0.55, 0.4, 0.5)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, f"{projection} projection")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


@pytest.mark.parametrize("height", ["image", "noise", "scaled"])
def test_displacement_renders_as_cycles_bump(height, tmp_path):
    """A Displacement node (Scale 0.15, Midlevel 0.5) into the Material
    Output's Displacement, its Height an image or a Noise: Cycles renders it
    as a bump by default (Displacement method 'Bump Only'); FPPM ignored it
    before.  Measured: 0.82x / 0.89x the seed-to-seed noise; without the
    bump the image is 4.9x / 3.5x the bound away.  'scaled': the image on
    the plane scaled 3x (object-space displacement grows with the object:
    0.94x the noise; at the unscaled distance 2.7 % of the mean away, 90x
    the noise)."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        _diffuse(nodes, links, surface)
        out = next(nd for nd in nodes if nd.type == 'OUTPUT_MATERIAL')
        disp = nodes.new('ShaderNodeDisplacement')
        disp.inputs['Scale'].default_value = 0.15
        if height != "noise":
            src = _image_node(nodes, "H", TS.height_pixels()).outputs['Color']
        else:
            src = _noise(nodes, links, 6.0, 1.0).outputs['Factor']
            disp.inputs['Scale'].default_value = 0.3
        links.new(src, disp.inputs['Height'])
        links.new(disp.outputs['Displacement'], out.inputs['Displacement'])

    sc, ob = _scene(mat)
    if height == "scaled":
        ob.scale = (3.0, 3.0, 3.0)
        next(nd for nd in ob.data.materials[0].node_tree.nodes
             if nd.type == 'DISPLACEMENT').inputs['Scale'].default_value = 0.05
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, f"displacement {height}")
    assert lines[1] == TS.PHOTON_NOTE, lines[1]
    plain = TS._fppm(TS._without_normals(scene), 1)
    _check(err, noise, float(np.abs(plain - img).mean() / img.mean()))


def test_a_muted_node_passes_its_input_on():
    """A muted Math node in a texture graph passes its first input on (its
    internal link), as Cycles bypasses it: the bake equals the graph without
    it."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        sep = _position_xyz(nodes, links)
        ma = nodes.new('ShaderNodeMath')
        ma.operation = 'SINE'
        ma.mute = True
        links.new(sep.outputs['X'], ma.inputs[0])
        links.new(ma.outputs[0], d.inputs['Color'])

    _, ob = _scene(mat)
    muted, _ = TS._export()
    nt = ob.data.materials[0].node_tree
    ma = next(nd for nd in nt.nodes if nd.type == 'MATH')
    d = next(nd for nd in nt.nodes if nd.type == 'BSDF_DIFFUSE')
    nt.links.new(ma.inputs[0].links[0].from_socket, d.inputs['Color'])
    nt.nodes.remove(ma)
    direct, _ = TS._export()
    assert np.array_equal(muted.textures[-1], direct.textures[-1])


def _displaced_grid(method, space, smooth, height):
    """An 80 x 80 grid (4 m, scaled 1.5x along z: object space stretches the
    offsets) whose Diffuse material's Displacement node (Midlevel 0.5) reads
    a Wave (Scale 0.25) or a Noise texture (Scale 0.8), under a sun 60
    degrees from the zenith, seen at 60 degrees."""
    import math

    import bpy
    import bpy_helpers as H
    sc = H.empty_scene((48, 36))
    m = H.node_material("Disp", "BSDF_DIFFUSE", Color=(0.8, 0.8, 0.8, 1.0))
    m.displacement_method = method
    nt = m.node_tree
    out = next(n for n in nt.nodes if n.type == 'OUTPUT_MATERIAL')
    d = nt.nodes.new('ShaderNodeDisplacement')
    d.space = space
    d.inputs["Scale"].default_value = 0.25 if height == "wave" else 0.8
    t = nt.nodes.new('ShaderNodeTexWave' if height == "wave" else 'ShaderNodeTexNoise')
    t.inputs["Scale"].default_value = 1.5 if height == "wave" else 2.0
    nt.links.new(t.outputs["Fac"], d.inputs["Height"])
    nt.links.new(d.outputs[0], out.inputs["Displacement"])
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=80, y_subdivisions=80, size=4.0)
    ob = bpy.context.active_object
    ob.data.materials.append(m)
    ob.scale = (1.0, 1.0, 1.5)
    if smooth:
        bpy.ops.object.shade_smooth()
    sun = H.add_light(sc, "SUN", 3.0, (0, 0, 5))
    sun.rotation_euler = (math.radians(60), 0.0, math.radians(30))
    H.set_world(sc, (0.05, 0.05, 0.05))
    H.add_camera(sc, location=(0.0, -4.0, 2.5), rotation=(math.radians(60), 0.0, 0.0))
    return sc, m


@pytest.mark.parametrize("case", ["object-smooth-wave-PATH", "world-flat-noise-PATH"])
def test_true_displacement_agrees_with_cycles(case, tmp_path):
    """Displacement method 'Displacement Only' moves the grid's vertices
    (addon/export_displace.py; FPPM rendered a bump before, noted): a Wave
    in object space on smooth faces (the offsets along the normals taken to
    object space, the vertex normals recomputed), a Noise in world space on
    flat faces.  Two seeds a side under the project's bound; the image
    moves by more than 3x the bound against the undisplaced grid.
    Measured: 0.87x and 0.81x the seed noise; the undisplaced grid 43 % and
    16 % of the mean away."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    space, shading, height, integrator = case.split("-")
    sc, m = _displaced_grid('DISPLACEMENT', space.upper(), shading == "smooth", height)
    scene, lines = TS._export()
    assert "true displacement" not in " ".join(lines), lines
    err, noise, img, ref = TS.two_seeds(
        sc, scene, lambda s, seed: TS.render_integrator(s, integrator, seed, passes=8),
        tmp_path, 128)
    m.node_tree.links.remove(next(lk for lk in m.node_tree.links
                                  if lk.to_socket.name == "Displacement"))
    flat, _ = TS._export()
    plain = TS.render_integrator(flat, integrator, 1, passes=TS.EFFECT_PASSES)
    effect = float(np.abs(plain - img).mean() / img.mean())
    print(f"{case}: error {err:.4f}, noise {noise:.4f}, undisplaced {effect:.3f}")
    TS._check(err, noise, effect)


@pytest.mark.parametrize("case", ["BUMP-unscaled", "BUMP-stretched", "BOTH-stretched"])
def test_displacement_bump_is_cycles_on_stretched_objects(case, tmp_path):
    """The Wave grid of :func:`_displaced_grid` (object space) with its
    displacement rendered as a bump (Bump Only, or over the displaced
    vertices with Displacement and Bump), unscaled or stretched 1.5x along
    its normal.  Cycles' displacement bump sets the shading normal itself,
    so no bump shadowing darkens it, and the object's stretch a = |M^T n|
    along the normal scales the height once (and the object-space bump of
    Displacement and Bump once more): ``Scene.tri_bump_scale``.  Two seeds a
    side under the project's bound; stretched with Bump Only, the rule
    before (one distance, the cube root of the scale's determinant) is
    outside it.  Measured (docs/shading.md "Displacement"): 1.47x, 2.35x
    and 1.26x the seed noise; the rule before 5.3x."""
    pytest.importorskip("bpy")
    import dataclasses

    import test_shading_nodes as TS
    method, shape = case.split("-")
    sc, m = _displaced_grid(method, 'OBJECT', True, "wave")
    import bpy
    ob = bpy.data.objects["Grid"]
    if shape == "unscaled":
        ob.scale = (1.0, 1.0, 1.0)
    scene, lines = TS._export()
    a = np.linalg.norm(ob.scale[2])
    p = scene.tri_p.astype(np.float64)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    stretch = np.linalg.norm(n * np.array(ob.scale), axis=1)      # |M^T n|, M diagonal
    np.testing.assert_allclose(scene.tri_bump_scale,
                               stretch ** (2 if method == "BOTH" else 1), rtol=1e-5)

    def render(s, seed):
        return TS.render_integrator(s, "PATH", seed, passes=8)

    err, noise, img, ref = TS.two_seeds(sc, scene, render, tmp_path, 128)
    print(f"{case}: error {err:.4f}, noise {noise:.4f} ({err / noise:.2f}x)")
    TS._check(err, noise)
    if case == "BUMP-stretched":
        # (Displacement and Bump's own noise, 2.8 % of the mean, is as large
        # as the rule's change there: measured 6.6 % against a bound of 6.7 %.)
        before = dataclasses.replace(scene, tri_bump_scale=np.full_like(
            scene.tri_bump_scale, a ** (1.0 / 3.0)))
        old = float(np.abs(render(before, 1) - ref).mean() / ref.mean())
        print(f"{case}: the rule before {old:.4f} ({old / noise:.2f}x)")
        assert old > 2.0 * noise + 0.01, old


def test_converter_nodes_through_the_exporter_agree_with_cycles(tmp_path):
    """Geometry Position -> Vector Rotate (about Z) -> Separate X -> Float
    Curve -> Math -> Blackbody (1500 to 10500 K), scaled, into a Diffuse
    Color, multiplied by a Color Ramp's Alpha of its RGB to BW: every node
    new in the exporter's graph (addon/export_graph.py) in one material.
    Measured: mean |diff| 0.36 % of the mean, 0.86x the seed-to-seed
    noise; flat grey moves the image by over 3x the bound (asserted)."""
    pytest.importorskip("bpy")

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        geo = nodes.new('ShaderNodeNewGeometry')
        rot = nodes.new('ShaderNodeVectorRotate')
        rot.rotation_type = 'Z_AXIS'
        rot.inputs['Angle'].default_value = 0.7
        links.new(geo.outputs['Position'], rot.inputs['Vector'])
        sep = nodes.new('ShaderNodeSeparateXYZ')
        links.new(rot.outputs[0], sep.inputs[0])
        lin = nodes.new('ShaderNodeMath')
        lin.operation = 'MULTIPLY_ADD'
        lin.inputs[1].default_value, lin.inputs[2].default_value = 0.6, 0.5
        links.new(sep.outputs['X'], lin.inputs[0])
        fc = nodes.new('ShaderNodeFloatCurve')
        fc.mapping.curves[0].points.new(0.5, 0.15)
        fc.mapping.update()
        links.new(lin.outputs[0], fc.inputs['Value'])
        kelvin = nodes.new('ShaderNodeMath')
        kelvin.operation = 'MULTIPLY_ADD'
        kelvin.inputs[1].default_value, kelvin.inputs[2].default_value = 9000.0, 1500.0
        links.new(fc.outputs[0], kelvin.inputs[0])
        bb = nodes.new('ShaderNodeBlackbody')
        links.new(kelvin.outputs[0], bb.inputs[0])
        scale = nodes.new('ShaderNodeVectorMath')
        scale.operation = 'SCALE'
        scale.inputs['Scale'].default_value = 0.15
        links.new(bb.outputs[0], scale.inputs[0])
        bw = nodes.new('ShaderNodeRGBToBW')
        links.new(bb.outputs[0], bw.inputs[0])
        cr = nodes.new('ShaderNodeValToRGB')
        cr.color_ramp.elements[0].color = (1.0, 1.0, 1.0, 0.3)
        cr.color_ramp.elements[1].color = (1.0, 1.0, 1.0, 1.0)
        links.new(bw.outputs[0], cr.inputs['Fac'])
        links.new(_mix(nodes, links, 'MULTIPLY', 1.0, scale.outputs[0], cr.outputs['Alpha']),
                  d.inputs['Color'])

    sc, _ = _scene(mat)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "converter nodes")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


def _islands_mesh(bpy):
    """One mesh of five islands: icospheres of two subdivisions (their
    vertices' pointiness varies with their spacing on the sphere) and a
    bevelled box, each welded, side by side on the plane z = 0."""
    import bmesh
    bm = bmesh.new()
    for i, (x, y, r) in enumerate([(-0.5, -0.3, 0.3), (0.1, -0.35, 0.22), (0.5, 0.2, 0.18),
                                   (-0.35, 0.4, 0.2)]):
        bmesh.ops.create_icosphere(bm, subdivisions=1 + i % 2, radius=r,
                                   matrix=__import__("mathutils").Matrix.Translation((x, y, 0.0)))
    res = bmesh.ops.create_cube(bm, size=0.3,
                                matrix=__import__("mathutils").Matrix.Translation((0.2, 0.45, 0)))
    bmesh.ops.bevel(bm, geom=[e for e in bm.edges if e.verts[0] in res["verts"]],
                    offset=0.04, segments=2, affect='EDGES')
    me = bpy.data.meshes.new("Islands")
    bm.to_mesh(me)
    bm.free()
    return me


def test_pointiness_and_random_per_island_agree_with_cycles(tmp_path):
    """Geometry Pointiness (through a Color Ramp of 0.4 .. 0.7) times Random
    Per Island (through another) into a Diffuse Color on one mesh of five
    islands, seen from above (core/scene/mesh_attributes.py, computed from
    the mesh as Cycles' sync does).  Measured: mean |diff| 5.9 % of the
    mean, 0.86x the seed-to-seed noise (dark islands on black: a noisy
    image; tests/test_mesh_attributes.py checks the values themselves
    against Cycles' bake, to 5e-5); flat grey moves the image by over 3x
    the bound (asserted)."""
    pytest.importorskip("bpy")
    import bpy

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        geo = nodes.new('ShaderNodeNewGeometry')
        pr = _ramp(nodes, links, geo.outputs['Pointiness'], (0.05, 0.05, 0.05, 1.0),
                   (0.95, 0.95, 0.95, 1.0), (0.55, 0.7))
        ir = _ramp(nodes, links, geo.outputs['Random Per Island'], (0.9, 0.2, 0.1, 1.0),
                   (0.1, 0.5, 0.95, 1.0), (0.0, 1.0))
        links.new(_mix(nodes, links, 'MULTIPLY', 1.0, pr.outputs['Color'],
                       ir.outputs['Color']), d.inputs['Color'])

    sc, ob = _scene(mat)
    m = ob.data.materials[0]
    ob.data = _islands_mesh(bpy)
    ob.data.materials.append(m)
    ob.rotation_euler = (0.0, 0.0, 0.0)
    for poly in ob.data.polygons:
        poly.use_smooth = True
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "pointiness, islands")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


#: A UDIM image's tiles: number -> colour (1012 left out: Cycles' magenta).
UDIM_TILES = {1001: (0.8, 0.25, 0.1), 1002: (0.1, 0.7, 0.25), 1011: (0.2, 0.35, 0.9)}


def _save_png(path, colour):
    """A 4 x 4 PNG at ``path`` of one colour, a white texel in its corner."""
    import bpy
    im = bpy.data.images.new("saved", 4, 4)
    px = np.ones((4, 4, 4), np.float32)
    px[..., :3] = colour
    px[0, 0, :3] = 1.0
    im.pixels.foreach_set(px.ravel())
    im.filepath_raw = str(path)
    im.file_format = 'PNG'
    im.save()
    bpy.data.images.remove(im)


def udim_image(folder, token="<UDIM>"):
    """A file-based UDIM image of UDIM_TILES (4 x 4 PNGs in ``folder``, each
    tile's colour with a white texel in its corner), named with ``token``."""
    import bpy
    for n, c in UDIM_TILES.items():
        k = n - 1001
        name = str(n) if token == "<UDIM>" else f"u{k % 10 + 1}_v{k // 10 + 1}"
        _save_png(folder / f"tiles.{name}.png", c)
    first = "1001" if token == "<UDIM>" else "u1_v1"
    img = bpy.data.images.load(str(folder / f"tiles.{first}.png"))
    img.source = 'TILED'
    img.filepath = str(folder / f"tiles.{token}.png")
    img.reload()
    assert sorted(t.number for t in img.tiles) == sorted(UDIM_TILES)
    return img


@pytest.mark.parametrize("token", ["<UDIM>", "<UVTILE>"])
def test_a_udim_image_agrees_with_cycles(token, tmp_path):
    """A UDIM image (tiles 1001, 1002 and 1011 from PNG files, 1012 missing)
    into a Diffuse Color, the plane's uvs spanning 0 .. 1.5 in u and v: each
    tile over its own unit square, Cycles' magenta where there is no tile.
    Before, the first tile was read everywhere (Image.pixels holds it
    alone).  Measured: mean |diff| 1.8 % of the mean, 0.86x the
    seed-to-seed noise; the first tile everywhere (what FPPM read before)
    moves the image by 67 % of the mean, 13x the bound."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        tex = nodes.new('ShaderNodeTexImage')
        tex.interpolation = 'Closest'
        tex.image = udim_image(tmp_path, token)
        links.new(tex.outputs['Color'], d.inputs['Color'])

    sc, _ = _scene(mat)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, f"UDIM {token}")
    assert lines[1] == "Approximated: nothing.", lines[1]
    import bpy
    node = next(n for n in bpy.data.materials["Surf"].node_tree.nodes if n.type == 'TEX_IMAGE')
    first = "1001" if token == "<UDIM>" else "u1_v1"
    node.image = bpy.data.images.load(str(tmp_path / f"tiles.{first}.png"))
    plain, _ = TS._export()
    alone = TS._fppm(plain, 1)
    effect = float(np.abs(alone - img).mean() / img.mean())
    print(f"UDIM: the first tile everywhere moves the image by {effect:.3f} of the mean")
    _check(err, noise, effect)


def test_a_packed_udim_image_reads_as_its_files(tmp_path):
    """The UDIM image of the test above (tiles 1001, 1002, 1011; 1012
    missing) packed into the file and its tile files deleted: the export's
    textures equal, bit for bit, those read from the files (which agree
    with Cycles above), with no note.  Before, every tile of a packed image
    read magenta, with a note per tile."""
    pytest.importorskip("bpy")
    import os

    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        tex = nodes.new('ShaderNodeTexImage')
        tex.interpolation = 'Closest'
        tex.image = udim_image(tmp_path)
        links.new(tex.outputs['Color'], d.inputs['Color'])

    _scene(mat)
    files, lines = TS._export()
    assert lines[1] == "Approximated: nothing.", lines[1]
    import bpy
    img = next(n for n in bpy.data.materials["Surf"].node_tree.nodes
               if n.type == 'TEX_IMAGE').image
    img.pack()
    assert sorted(int(p.tile_number) for p in img.packed_files) == sorted(UDIM_TILES)
    for n in UDIM_TILES:
        os.remove(tmp_path / f"tiles.{n}.png")
    packed, lines = TS._export()
    assert lines[1] == "Approximated: nothing.", lines[1]
    assert len(packed.textures) == len(files.textures) >= len(UDIM_TILES)
    for a, b in zip(files.textures, packed.textures):
        np.testing.assert_array_equal(a, b)
    # Unpacked again (REMOVE) with its files gone: no data left, each tile
    # reads magenta with a note.
    img.unpack(method='REMOVE')
    _, lines = TS._export()
    assert "UDIM tile 1001 could not be read" in "\n".join(lines)


#: An image sequence's frames: file number -> colour.
SEQUENCE = {1: (0.8, 0.25, 0.1), 2: (0.1, 0.7, 0.25), 3: (0.2, 0.35, 0.9)}


@pytest.mark.parametrize("scene_frame, offset, cyclic", [(2, 0, False), (5, 1, True)])
def test_an_image_sequence_frame_agrees_with_cycles(scene_frame, offset, cyclic, tmp_path):
    """An image sequence (shot_0001.png .. shot_0003.png, one colour each,
    a white texel in a corner) into a Diffuse Color, rendered at scene
    frame 2 (its second file), and at frame 5 with Offset 1 and Cyclic (5
    wraps to 2, plus 1: the third).  Before, the texture was dropped with
    a note: ``Image.pixels`` of a sequence is empty.  Measured: mean |diff|
    1.2 % and 0.6 % of the mean, 0.84x and 0.85x the seed-to-seed noise;
    the first frame instead moves the image by 164 % and 134 % of the
    mean."""
    pytest.importorskip("bpy")
    import bpy

    import test_shading_nodes as TS
    for n, c in SEQUENCE.items():
        _save_png(tmp_path / f"shot_{n:04d}.png", c)

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        tex = nodes.new('ShaderNodeTexImage')
        tex.interpolation = 'Closest'
        tex.image = bpy.data.images.load(str(tmp_path / "shot_0001.png"))
        tex.image.source = 'SEQUENCE'
        iu = tex.image_user
        iu.frame_duration, iu.frame_start, iu.frame_offset = 3, 1, offset
        iu.use_cyclic = cyclic
        links.new(tex.outputs['Color'], d.inputs['Color'])

    sc, _ = _scene(mat)
    sc.frame_set(scene_frame)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, f"sequence at {scene_frame}")
    assert lines[1] == "Approximated: nothing.", lines[1]
    node = next(n for n in bpy.data.materials["Surf"].node_tree.nodes if n.type == 'TEX_IMAGE')
    node.image = bpy.data.images.load(str(tmp_path / "shot_0001.png"), check_existing=False)
    plain, _ = TS._export()
    effect = float(np.abs(TS._fppm(plain, 1) - img).mean() / img.mean())
    print(f"sequence: the first frame moves the image by {effect:.3f} of the mean")
    _check(err, noise, effect)


def test_sequence_frames_and_file_names():
    """Blender's frame of an image user (BKE_image_user_frame_get) and its
    file name: Frames 3 from Start Frame 1, clamped to 0 .. 3 or cyclic,
    then Offset; the last digits of the name replaced, zero-padded."""
    pytest.importorskip("bpy")
    from types import SimpleNamespace

    from fppm.addon.export_read import frame_path, sequence_frame
    iu = SimpleNamespace(frame_duration=3, frame_start=1, frame_offset=0, use_cyclic=False)
    assert [sequence_frame(iu, f) for f in (-1, 0, 1, 3, 4, 9)] == [0, 0, 1, 3, 3, 3]
    iu.use_cyclic, iu.frame_offset = True, 10
    assert [sequence_frame(iu, f) for f in (-1, 0, 1, 3, 4, 6)] == [12, 13, 11, 13, 11, 13]
    iu.frame_duration = 0
    assert sequence_frame(iu, 5) == 0
    assert frame_path("/a/b7/shot_0001.png", 12) == "/a/b7/shot_0012.png"
    assert frame_path("/a/v2.fire.001.exr", 1234) == "/a/v2.fire.1234.exr"
    assert frame_path("/a/plain.png", 3) == "/a/plain.png"


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_camera_coordinates_agree_with_cycles(kind, tmp_path):
    """Texture Coordinate Window (its x, y as red and green) and Camera
    (through a Checker), and the Camera Data node's View Z Depth (blue,
    through Map Range), View Distance (through Ping-Pong, a Mix factor) and
    View Vector (added, scaled), into a Diffuse Color; a camera
    tilted, shifted and lens-changed (or orthographic) over a 4:3 frame.
    Before, each cut the graph with a note.  Measured: mean |diff| 3.1 %
    and 1.6 % of the mean, 0.74x and 0.86x the seed-to-seed noise."""
    pytest.importorskip("bpy")
    import math

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        tc = nodes.new('ShaderNodeTexCoord')
        cd = nodes.new('ShaderNodeCameraData')
        win = nodes.new('ShaderNodeSeparateXYZ')
        links.new(tc.outputs['Window'], win.inputs[0])
        depth = nodes.new('ShaderNodeMapRange')
        depth.inputs['From Min'].default_value = 2.5
        depth.inputs['From Max'].default_value = 4.0
        links.new(cd.outputs['View Z Depth'], depth.inputs['Value'])
        rgb = nodes.new('ShaderNodeCombineXYZ')
        links.new(win.outputs['X'], rgb.inputs['X'])
        links.new(win.outputs['Y'], rgb.inputs['Y'])
        links.new(depth.outputs['Result'], rgb.inputs['Z'])
        ring = nodes.new('ShaderNodeMath')
        ring.operation = 'PINGPONG'
        ring.inputs[1].default_value = 0.25
        links.new(cd.outputs['View Distance'], ring.inputs[0])
        ch = nodes.new('ShaderNodeTexChecker')
        ch.inputs['Scale'].default_value = 3.0
        links.new(tc.outputs['Camera'], ch.inputs['Vector'])
        mix = nodes.new('ShaderNodeMix')
        mix.data_type, mix.blend_type = 'RGBA', 'MULTIPLY'
        links.new(ring.outputs[0], mix.inputs['Factor'])
        links.new(rgb.outputs[0], mix.inputs['A'])
        links.new(ch.outputs['Color'], mix.inputs['B'])
        tint = nodes.new('ShaderNodeVectorMath')
        tint.operation = 'MULTIPLY_ADD'
        tint.inputs[1].default_value = (0.2, 0.2, 0.2)
        links.new(cd.outputs['View Vector'], tint.inputs[0])
        links.new(mix.outputs['Result'], tint.inputs[2])
        absolute = nodes.new('ShaderNodeVectorMath')
        absolute.operation = 'ABSOLUTE'
        links.new(tint.outputs[0], absolute.inputs[0])
        links.new(absolute.outputs[0], d.inputs['Color'])

    sc, _ = _scene(mat)
    sc.render.resolution_x = 40
    sc.render.resolution_y = 30
    cam = sc.camera
    cam.data.type = kind
    cam.data.lens = 30.0
    cam.data.ortho_scale = 2.2
    cam.data.shift_x, cam.data.shift_y = 0.05, -0.08
    cam.location = (0.3, -1.6, 2.6)
    cam.rotation_euler = (math.radians(30.0), 0.0, math.radians(8.0))
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, f"camera coordinates {kind}")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


def test_vector_transform_agrees_with_cycles(tmp_path):
    """Vector Transform in five of its forms on a rotated, unevenly scaled
    plane under a tilted perspective camera: the world position to object
    space (its absolute value a colour), to camera space (its z through Map Range as
    a Mix factor), the object-space point as a vector to camera space, the
    world normal to object space and a constant normal from camera to
    world (added, absolute, into a Diffuse Color).  Before, the node cut
    the graph with a note.  Measured: mean |diff| 5.5 % of the mean, 0.84x
    the seed-to-seed noise (tests/test_converter_nodes.py checks the
    transforms' closed forms)."""
    pytest.importorskip("bpy")
    import math

    def vt(nodes, links, src, kind, a, b):
        n = nodes.new('ShaderNodeVectorTransform')
        n.vector_type, n.convert_from, n.convert_to = kind, a, b
        if isinstance(src, tuple):
            n.inputs[0].default_value = src
        else:
            links.new(src, n.inputs[0])
        return n.outputs[0]

    def vmath(nodes, links, op, a, b=None, scale=None):
        n = nodes.new('ShaderNodeVectorMath')
        n.operation = op
        links.new(a, n.inputs[0])
        if b is not None:
            links.new(b, n.inputs[1])
        if scale is not None:
            n.inputs['Scale'].default_value = scale
        return n.outputs[0]

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        geo = nodes.new('ShaderNodeNewGeometry')
        tc = nodes.new('ShaderNodeTexCoord')
        base = vmath(nodes, links, 'ABSOLUTE',
                     vt(nodes, links, geo.outputs['Position'], 'POINT', 'WORLD', 'OBJECT'))
        sep = nodes.new('ShaderNodeSeparateXYZ')
        links.new(vt(nodes, links, geo.outputs['Position'], 'POINT', 'WORLD', 'CAMERA'),
                  sep.inputs[0])
        mr = nodes.new('ShaderNodeMapRange')
        mr.inputs['From Min'].default_value, mr.inputs['From Max'].default_value = 2.5, 4.0
        links.new(sep.outputs['Z'], mr.inputs['Value'])
        mix = nodes.new('ShaderNodeMix')
        mix.data_type, mix.blend_type = 'RGBA', 'MIX'
        next(i for i in mix.inputs if i.identifier == 'B_Color').default_value = \
            (0.9, 0.5, 0.1, 1.0)
        links.new(mr.outputs['Result'], mix.inputs['Factor'])
        links.new(base, mix.inputs['A'])
        extra = vmath(nodes, links, 'ADD',
                      vt(nodes, links, tc.outputs['Object'], 'VECTOR', 'OBJECT', 'CAMERA'),
                      vt(nodes, links, geo.outputs['Normal'], 'NORMAL', 'WORLD', 'OBJECT'))
        extra = vmath(nodes, links, 'ADD', extra,
                      vt(nodes, links, (0.3, -0.5, 0.8), 'NORMAL', 'CAMERA', 'WORLD'))
        extra = vmath(nodes, links, 'SCALE', vmath(nodes, links, 'ABSOLUTE', extra),
                      scale=0.15)
        links.new(vmath(nodes, links, 'ADD', mix.outputs['Result'], extra), d.inputs['Color'])

    sc, ob = _scene(mat)
    ob.scale = (1.3, 0.7, 1.0)
    ob.rotation_euler = (0.1, -0.15, 0.6)
    cam = sc.camera
    cam.data.type = 'PERSP'
    cam.data.lens = 30.0
    cam.location = (0.3, -1.6, 2.6)
    cam.rotation_euler = (math.radians(30.0), 0.0, math.radians(8.0))
    import test_shading_nodes as TS
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, "vector transform")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


def test_object_and_view_layer_attributes_agree_with_cycles(tmp_path):
    """Attribute nodes of type Object and View Layer: a custom property on
    the object (a colour), one on its mesh only (an integer, found on the
    data), the RNA path ``color`` (the viewport display colour) and a
    missing name (zero), and a scene custom property through View Layer;
    the plane, a copy with other values, into a Diffuse Color.  Before,
    they cut the graph with a note.  Measured: mean |diff| 1.3 % of the
    mean, 0.71x the seed-to-seed noise; each attribute alone, on one plane,
    agrees to the digit."""
    pytest.importorskip("bpy")

    def attr(nodes, kind, name):
        a = nodes.new('ShaderNodeAttribute')
        a.attribute_type, a.attribute_name = kind, name
        return a

    def vmath(nodes, links, op, a, b):
        n = nodes.new('ShaderNodeVectorMath')
        n.operation = op
        links.new(a, n.inputs[0])
        links.new(b, n.inputs[1])
        return n.outputs[0]

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        tint = attr(nodes, 'OBJECT', 'tint').outputs['Color']
        level = attr(nodes, 'OBJECT', 'level').outputs['Fac']
        shown = attr(nodes, 'OBJECT', 'color').outputs['Vector']
        none = attr(nodes, 'OBJECT', 'no such property').outputs['Alpha']
        mood = attr(nodes, 'VIEW_LAYER', 'mood').outputs['Fac']
        scale = nodes.new('ShaderNodeMath')
        scale.operation = 'MULTIPLY_ADD'
        scale.inputs[1].default_value = 0.2
        links.new(level, scale.inputs[0])
        links.new(none, scale.inputs[2])
        c = vmath(nodes, links, 'SCALE', tint, tint)
        links.new(scale.outputs[0], c.node.inputs['Scale'])
        m = vmath(nodes, links, 'SCALE', shown, shown)
        links.new(mood, m.node.inputs['Scale'])
        links.new(vmath(nodes, links, 'ADD', c, m), d.inputs['Color'])

    sc, ob = _scene(mat)
    sc["mood"] = 0.4
    ob.scale = (0.35, 0.9, 1.0)
    ob.location = (-0.5, 0.0, 0.0)
    ob["tint"] = (0.2, 0.6, 0.9)
    ob.color = (0.9, 0.3, 0.2, 1.0)
    ob.data["level"] = 3
    copy = ob.copy()
    copy.data = ob.data.copy()
    copy.location = (0.5, 0.0, 0.0)
    copy["tint"] = (0.8, 0.7, 0.1)
    copy.color = (0.1, 0.9, 0.5, 1.0)
    copy.data["level"] = 1
    sc.collection.objects.link(copy)
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "object attributes")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))


def test_a_geometry_attributes_factor_agrees_with_cycles(tmp_path):
    """An Attribute node (type Geometry) reading a float attribute of the
    vertices through its Fac output (named Factor in Blender 5), through a
    Color Ramp into a Diffuse Color.  Before, the output's new name cut the
    graph.  Measured: mean |diff| 0.60 % of the mean, 0.87x the
    seed-to-seed noise."""
    pytest.importorskip("bpy")
    import bmesh
    import bpy

    def mat(nodes, links, surface):
        d = _diffuse(nodes, links, surface)
        a = nodes.new('ShaderNodeAttribute')
        a.attribute_name = "weight"
        cr = _ramp(nodes, links, a.outputs['Fac'], (0.1, 0.2, 0.8, 1.0), (0.9, 0.6, 0.1, 1.0),
                   (0.0, 1.0))
        links.new(cr.outputs['Color'], d.inputs['Color'])

    sc, ob = _scene(mat)
    bpy.context.view_layer.objects.active = ob
    bm = bmesh.new()
    bm.from_mesh(ob.data)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=3, use_grid_fill=True)
    bm.to_mesh(ob.data)
    bm.free()
    at = ob.data.attributes.new("weight", 'FLOAT', 'POINT')
    at.data.foreach_set("value", np.random.default_rng(5).uniform(0, 1, len(at.data)))
    ob.data.update()
    err, noise, img, ref, scene, lines = _compare(sc, tmp_path, "attribute factor")
    assert lines[1] == "Approximated: nothing.", lines[1]
    _check(err, noise, _effect(img, scene, (0.5, 0.5, 0.5, 1.0)))
