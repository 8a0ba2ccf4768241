"""addon/export.py on scenes built in the test: counts, transforms, units, materials, bad input."""
import math
import os

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

from fppm.addon import export as E  # noqa: E402
from fppm.core.scene import model as S  # noqa: E402
from fppm.core.errors import SceneError  # noqa: E402


def export(log=None):
    lines = [] if log is None else log
    return E.export_scene(H.evaluated_depsgraph(), lines.append), lines


def base_scene():
    sc = H.empty_scene((32, 32))
    H.add_camera(sc)
    H.add_light(sc, "POINT", 100.0)
    return sc


# ---------------------------------------------------------------- geometry

def test_triangle_counts_with_modifiers_and_instances():
    sc = base_scene()
    H.add_plane(sc)                                        # 1 quad  -> 2
    H.add_cube(sc, "Cube")                                 # 6 quads -> 12
    sub = H.add_cube(sc, "Subdivided", location=(3, 0, 0.5))
    m = sub.modifiers.new("Sub", 'SUBSURF')
    m.levels, m.render_levels = 1, 2                       # viewport depsgraph: level 1
    arr = H.add_cube(sc, "Arrayed", location=(-3, 0, 0.5))
    arr.modifiers.new("Arr", 'ARRAY').count = 3            # 3 x 12
    # A collection instanced twice by empties.
    coll = bpy.data.collections.new("Props")
    src = H.add_cube(bpy.context.scene, "PropCube")
    sc.collection.objects.unlink(src)
    coll.objects.link(src)
    for i in range(2):
        e = bpy.data.objects.new(f"Inst{i}", None)
        e.instance_type = 'COLLECTION'
        e.instance_collection = coll
        e.location = (0, 3 + 2 * i, 0)
        sc.collection.objects.link(e)
    s, lines = export()
    # 2 + 12 + 6*4 quads*2 + 36 + 2*12
    assert s.n_triangles == 2 + 12 + 48 + 36 + 24
    assert s.tri_p.dtype == np.float32 and s.tri_n.dtype == np.float32
    assert s.tri_uv.shape == (s.n_triangles, 3, 2) and s.tri_mat.dtype == np.int32
    assert "2 instances" in lines[0] and f"{s.n_triangles:,} triangles" in lines[0]
    assert len(lines) == 2 and lines[1].startswith("Approximated:")


def test_geometry_nodes_instances():
    sc = base_scene()
    src = H.add_cube(sc, "Source")
    src.hide_viewport = True       # only its instances are in the scene
    src.hide_render = True
    host = H.add_plane(sc, "Host", size=0.1)
    ng = bpy.data.node_groups.new("Scatter", 'GeometryNodeTree')
    ng.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    ng.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    gout = ng.nodes.new('NodeGroupOutput')
    line = ng.nodes.new('GeometryNodeMeshLine')
    line.inputs['Count'].default_value = 5
    info = ng.nodes.new('GeometryNodeObjectInfo')
    info.inputs['Object'].default_value = src
    iop = ng.nodes.new('GeometryNodeInstanceOnPoints')
    ng.links.new(line.outputs['Mesh'], iop.inputs['Points'])
    ng.links.new(info.outputs['Geometry'], iop.inputs['Instance'])
    ng.links.new(iop.outputs['Instances'], gout.inputs['Geometry'])
    host.modifiers.new("GN", 'NODES').node_group = ng
    s, lines = export()
    assert s.n_triangles == 5 * 12
    assert "5 instances" in lines[0]
    # Mesh Line's default offset is 1 m along Z: instance k sits at z = k.
    zc = s.tri_p[:, :, 2].mean(axis=1)
    assert sorted(set(np.round(zc.reshape(5, 12).mean(axis=1), 4))) == [0, 1, 2, 3, 4]


def test_transform_normals_and_uvs():
    sc = base_scene()
    ob = H.add_plane(sc, size=2.0)
    ob.data.uv_layers.new(name="UVMap")
    ob.location = (1.0, 2.0, 3.0)
    ob.scale = (2.0, 1.0, 1.0)
    s, _ = export()
    p = s.tri_p.reshape(-1, 3)
    assert np.allclose(p.min(0), [-1, 1, 3]) and np.allclose(p.max(0), [3, 3, 3])
    assert np.allclose(s.tri_n.reshape(-1, 3), [0, 0, 1], atol=1e-6)
    # The default UVs of a quad map its corners to the unit square corners.
    uv = s.tri_uv.reshape(-1, 2)
    for q, t in zip(p, uv):
        assert np.allclose(t, [(q[0] + 1) / 4, (q[1] - 1) / 2], atol=1e-6)


def test_mirrored_object_keeps_winding_consistent():
    sc = base_scene()
    ob = H.add_cube(sc)
    ob.scale = (-1.0, 1.0, 1.0)
    s, _ = export()
    P = s.tri_p.astype(np.float64)
    ng = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    ns = s.tri_n.astype(np.float64).mean(axis=1)
    # Geometric and shading normals agree (outward) on every triangle.
    assert np.all(np.einsum("ij,ij->i", ng, ns) > 0)


def test_hidden_and_invisible_objects_are_skipped():
    sc = base_scene()
    H.add_plane(sc)
    H.add_cube(sc, "Hidden").hide_render = True
    inv = H.add_cube(sc, "Invisible", location=(2, 0, 0))
    for k in ("camera", "diffuse", "glossy", "transmission", "shadow"):
        setattr(inv, "visible_" + k, False)
    part = H.add_cube(sc, "Partly", location=(-2, 0, 0))
    part.visible_camera = False
    s, lines = export()
    assert s.n_triangles == 2 + 12
    # Camera visibility is honoured (tests/test_ray_visibility.py): no note;
    # the triangles carry the flags.
    assert lines[1] == "Approximated: nothing.", lines
    from core.accel import RAY_ALL, RAY_CAMERA
    assert sorted(np.unique(s.tri_visibility)) == [RAY_ALL & ~RAY_CAMERA, RAY_ALL]
    part.visible_glossy = False
    s, lines = export()
    assert "ray visibility of 1 object(s) (Partly): diffuse, and glossy" in lines[1]


def test_an_instance_takes_its_instancers_ray_visibility():
    """Cycles: "for instancers, visibility is inherited": a collection
    instance's triangles carry its object's flags and-ed with the instancing
    empty's, the collection's own object outside the scene unaffected."""
    from core.accel import RAY_ALL, RAY_CAMERA, RAY_SHADOW
    sc = base_scene()
    H.add_plane(sc)
    coll = bpy.data.collections.new("Props")
    src = H.add_cube(bpy.context.scene, "PropCube")
    sc.collection.objects.unlink(src)
    coll.objects.link(src)
    src.visible_shadow = False
    e = bpy.data.objects.new("Inst", None)
    e.instance_type = 'COLLECTION'
    e.instance_collection = coll
    e.location = (0, 3, 0)
    sc.collection.objects.link(e)
    e.visible_camera = False
    s, _ = export()
    assert s.n_triangles == 2 + 12
    assert list(s.tri_visibility[:2]) == [RAY_ALL] * 2
    assert set(s.tri_visibility[2:]) == {RAY_ALL & ~RAY_CAMERA & ~RAY_SHADOW}


def test_nan_vertices_are_dropped_and_counted():
    sc = base_scene()
    H.add_plane(sc)
    nan = float("nan")
    # One good triangle, one with a NaN corner, one with collinear corners.
    H.mesh_object(sc, "Broken", [(0, 0, 1), (1, 0, 1), (0, 1, 1), (nan, 0, 1), (2, 0, 1)],
                  [(0, 1, 2), (1, 3, 2), (0, 1, 4)])
    s, lines = export()
    warn = [ln for ln in lines if ln.startswith("Warning")]
    assert warn == ["Warning: dropped 2 of 5 triangles with NaN/infinite corners or zero area."]
    assert s.n_triangles == 3
    assert np.all(np.isfinite(s.tri_p))


# ---------------------------------------------------------------- lights, world, camera

def test_lights_in_cycles_units():
    sc = H.empty_scene((32, 32))
    H.add_camera(sc)
    H.add_plane(sc)
    H.add_light(sc, "POINT", 100.0, name="P", color=(1.0, 0.5, 0.25), exposure=1.0,
                shadow_soft_size=0.1)
    H.add_light(sc, "SPOT", 50.0, name="S", spot_size=math.radians(40), spot_blend=0.3)
    H.add_light(sc, "SUN", 3.0, name="Sun", angle=math.radians(2))
    a = H.add_light(sc, "AREA", 80.0, name="A", shape='RECTANGLE', size=2.0, size_y=0.5)
    a.scale = (1.0, 3.0, 1.0)
    a.hide_render = True   # hidden lights do not count
    H.add_light(sc, "AREA", 20.0, name="D", shape='DISK', size=1.0)
    s, lines = export()
    L = {lt.name: lt for lt in s.lights}
    assert sorted(L) == ["D", "P", "S", "Sun"]
    assert np.allclose(L["P"].strength, (200.0, 100.0, 50.0))  # colour x energy x 2^exposure
    assert L["P"].kind == "POINT" and L["P"].radius == pytest.approx(0.1)
    assert L["S"].spot_size == pytest.approx(math.radians(40)) and L["S"].spot_blend == pytest.approx(0.3)
    assert L["Sun"].strength == pytest.approx((3.0, 3.0, 3.0)) and L["Sun"].angle == pytest.approx(math.radians(2))
    assert L["D"].shape == "DISK" and L["D"].size == pytest.approx(1.0)
    assert np.allclose(L["D"].matrix_world[:3, 3], (0, 0, 3))
    assert "4 lights" in lines[0]


def test_area_light_without_normalize_scales_by_area():
    sc = base_scene()
    H.add_plane(sc)
    a = H.add_light(sc, "AREA", 10.0, name="A", shape='RECTANGLE', size=2.0, size_y=0.5)
    a.data.normalize = False
    a.scale = (1.0, 3.0, 1.0)
    s, _ = export()
    A = next(lt for lt in s.lights if lt.name == "A")
    # Cycles: L = c P / pi when not normalised = (c P A) / (pi A): strength x area (3 m^2).
    assert A.strength[0] == pytest.approx(10.0 * 2.0 * 0.5 * 3.0)


def test_world_colour_from_background_node():
    sc = base_scene()
    H.add_plane(sc)
    H.set_world(sc, (0.1, 0.2, 0.3), 2.0)
    s, _ = export()
    assert np.allclose(s.world_color, (0.2, 0.4, 0.6))


def test_camera_fields():
    sc = base_scene()
    H.add_plane(sc)
    r = sc.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = 64, 48, 50
    r.use_border = True
    r.border_min_x, r.border_min_y, r.border_max_x, r.border_max_y = 0.25, 0.0, 0.75, 0.5
    cam = sc.camera
    cam.scale = (2.0, 2.0, 2.0)           # ignored by Blender's projection
    cd = cam.data
    cd.lens, cd.sensor_fit, cd.sensor_width = 42.0, 'VERTICAL', 30.0
    cd.shift_x, cd.shift_y, cd.clip_start, cd.clip_end = 0.1, -0.2, 0.05, 50.0
    cd.dof.use_dof = True
    cd.dof.aperture_fstop = 2.8
    cd.dof.focus_distance = 3.5
    c = export()[0].camera
    assert c.resolution == (32, 24)
    assert c.border == (0.25, 0.0, 0.75, 0.5)
    assert (c.lens, c.sensor_fit, c.sensor_width) == (pytest.approx(42.0), "VERTICAL", pytest.approx(30.0))
    assert (c.shift_x, c.shift_y) == (pytest.approx(0.1), pytest.approx(-0.2))
    assert (c.clip_start, c.clip_end) == (pytest.approx(0.05), pytest.approx(50.0))
    # Cycles: aperture radius = lens [m] / (2 f-stop).
    assert c.aperture_radius == pytest.approx(0.042 / 5.6)
    assert c.focus_distance == pytest.approx(3.5)
    assert np.allclose(np.linalg.norm(c.matrix_world[:3, :3], axis=0), 1.0)
    assert np.allclose(c.matrix_world[:3, 3], (0, -4, 1))


# ---------------------------------------------------------------- materials

def test_materials_from_nodes():
    sc = base_scene()
    mats = {
        "Diffuse": H.node_material("Diffuse", "BSDF_DIFFUSE", Color=(0.5, 0.25, 0.125, 1)),
        "Glass": H.node_material("Glass", "BSDF_GLASS", IOR=1.5, Roughness=0.0),
        "Lamp": H.node_material("Lamp", "EMISSION", Color=(1, 0.5, 0.5, 1), Strength=4.0),
        "Gold": H.node_material("Gold", "BSDF_PRINCIPLED", Metallic=1.0, Roughness=0.3),
        # Sheen has no FPPM lobe: the one approximated material here.
        "Velvet": H.node_material("Velvet", "BSDF_PRINCIPLED", **{"Sheen Weight": 0.5}),
    }
    mix = H.node_material("Mix", "BSDF_DIFFUSE", Color=(0.8, 0.8, 0.8, 1))
    nt = mix.node_tree
    out = next(n for n in nt.nodes if n.type == 'OUTPUT_MATERIAL')
    gl = nt.nodes.new("ShaderNodeBsdfGlossy")
    gl.inputs["Roughness"].default_value = 0.0
    mx = nt.nodes.new("ShaderNodeMixShader")
    mx.inputs["Fac"].default_value = 0.25
    nt.links.new(next(n for n in nt.nodes if n.type == 'BSDF_DIFFUSE').outputs[0], mx.inputs[1])
    nt.links.new(gl.outputs[0], mx.inputs[2])
    nt.links.new(mx.outputs[0], out.inputs["Surface"])
    mats["Mix"] = mix
    for i, (name, m) in enumerate(mats.items()):
        H.add_cube(sc, name, location=(2 * i, 0, 0), material=m)
    s, lines = export()
    M = {m.name: m for m in s.materials}
    assert sorted(M) == sorted(mats)
    d = M["Diffuse"].lobes
    assert len(d) == 1 and d[0].kind == S.DIFFUSE and np.allclose(d[0].color, (0.5, 0.25, 0.125))
    g = M["Glass"].lobes
    assert len(g) == 1 and g[0].kind == S.GLASS and g[0].ior == pytest.approx(1.5)
    assert np.allclose(M["Lamp"].emission, (4.0, 2.0, 2.0))
    # Metallic 1 is exact (Cycles' F82-tint conductor, F0 = base colour, the
    # node's default Multiscatter GGX): one lobe, nothing noted.
    (gold,) = M["Gold"].lobes
    assert gold.kind == S.GLOSSY and gold.weight == pytest.approx(1.0)
    assert gold.color == pytest.approx((0.8, 0.8, 0.8)) and gold.roughness == pytest.approx(0.3)
    assert getattr(gold, "fresnel", "") == "F82" and getattr(gold, "multiscatter", False)
    assert tuple(getattr(gold, "f82_tint", (1.0, 1.0, 1.0))) == pytest.approx((1.0, 1.0, 1.0))
    assert M["Gold"].approximations == ()
    kinds = {lb.kind: lb for lb in M["Mix"].lobes}
    assert set(kinds) == {S.DIFFUSE, S.GLOSSY}
    # Mix fac 0.25: weight x colour = 0.75 x 0.8 diffuse, 0.25 x 0.8 glossy.
    wd = kinds[S.DIFFUSE].weight * np.array(kinds[S.DIFFUSE].color)
    wg = kinds[S.GLOSSY].weight * np.array(kinds[S.GLOSSY].color)
    assert np.allclose(wd, 0.6) and np.allclose(wg, 0.2)
    # Every triangle points at its object's material.
    assert np.bincount(s.tri_mat, minlength=len(s.materials)).tolist() == [12] * len(mats)
    # The approximations line names the material, node and what was approximated.
    assert "material 'Velvet': Principled BSDF: sheen (weight 0.5) ignored" in lines[1]
    assert "'Gold'" not in lines[1]


def _one_node_material(name, idname, distribution, **inputs):
    m = H.node_material(name, "BSDF_DIFFUSE")
    nt = m.node_tree
    nt.nodes.remove(next(n for n in nt.nodes if n.type == 'BSDF_DIFFUSE'))
    node = nt.nodes.new(idname)
    node.distribution = distribution
    for k, v in inputs.items():
        node.inputs[k].default_value = v
    nt.links.new(node.outputs[0], next(n for n in nt.nodes if n.type == 'OUTPUT_MATERIAL')
                 .inputs["Surface"])
    return m


def test_distribution_sets_multiscatter():
    from fppm.core.materials import build_material_table
    sc = base_scene()
    # name -> (node, distribution, inputs, kind, multiscatter expected)
    cases = {
        "GlossyMulti": ("ShaderNodeBsdfGlossy", 'MULTI_GGX', {"Roughness": 0.5}, S.GLOSSY, True),
        "GlossyGGX": ("ShaderNodeBsdfGlossy", 'GGX', {"Roughness": 0.5}, S.GLOSSY, False),
        "GlossyBeckmann": ("ShaderNodeBsdfGlossy", 'BECKMANN', {"Roughness": 0.5}, S.GLOSSY, False),
        "GlassMulti": ("ShaderNodeBsdfGlass", 'MULTI_GGX', {"Roughness": 0.4, "IOR": 1.33},
                       S.GLASS, True),
        "GlassGGX": ("ShaderNodeBsdfGlass", 'GGX', {"Roughness": 0.4, "IOR": 1.33}, S.GLASS, False),
        # Cycles' Refraction BSDF has no multiscatter variant.
        "Refraction": ("ShaderNodeBsdfRefraction", 'GGX', {"Roughness": 0.4, "IOR": 1.33},
                       S.REFRACTION, False),
        "MetalMulti": ("ShaderNodeBsdfPrincipled", 'MULTI_GGX', {"Metallic": 1.0, "Roughness": 0.5},
                       S.GLOSSY, True),
        "MetalGGX": ("ShaderNodeBsdfPrincipled", 'GGX', {"Metallic": 1.0, "Roughness": 0.5},
                     S.GLOSSY, False),
    }
    for i, (name, (idname, dist, inputs, _, _)) in enumerate(cases.items()):
        H.add_cube(sc, name, location=(2 * i, 0, 0),
                   material=_one_node_material(name, idname, dist, **inputs))
    s, lines = export()
    M = {m.name: m for m in s.materials}
    table = build_material_table(s.materials, s.textures)
    for name, (_, dist, inputs, kind, ms) in cases.items():
        (lobe,) = M[name].lobes
        assert lobe.kind == kind, name
        assert lobe.roughness == pytest.approx(inputs["Roughness"]), name
        if "IOR" in inputs:
            assert lobe.ior == pytest.approx(inputs["IOR"]), name
        assert bool(getattr(lobe, "multiscatter", False)) is ms, name
        # ... and core.materials reads it: the table's flag is what the BSDF uses.
        assert bool(table.multiscatter[s.materials.index(M[name]), 0]) is ms, name
    # Only the Beckmann glossy is approximated (rendered as GGX).
    assert "material 'GlossyBeckmann': Glossy BSDF: BECKMANN distribution rendered as GGX" \
        in lines[1]
    assert lines[1].count("distribution rendered as GGX") == 1


def test_unsupported_node_one_warning_and_grey():
    sc = base_scene()
    m = H.node_material("Skin", "SUBSURFACE_SCATTERING")
    H.add_cube(sc, material=m)
    H.add_plane(sc)                       # no material: the default grey
    s, lines = export()
    warn = [ln for ln in lines if ln.startswith("Warning")]
    assert len(warn) == 1 and "'Skin'" in warn[0] and "Subsurface Scattering" in warn[0]
    skin = next(x for x in s.materials if x.name == "Skin")
    assert skin.lobes == (S.Lobe(S.DIFFUSE, E.GREY),)
    assert any(x.name == "(no material)" for x in s.materials)


def test_image_texture_is_linearised():
    sc = base_scene()
    m = H.node_material("Tex", "BSDF_DIFFUSE")
    nt = m.node_tree
    img = bpy.data.images.new("checker", 4, 2, alpha=True)
    px = np.zeros((2, 4, 4), np.float32)
    px[..., 3] = 1.0
    px[0, :, 0] = 128 / 255          # bottom row: sRGB 128 red
    px[1, :, 1] = 1.0                # top row green
    img.pixels.foreach_set(px.ravel())
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = img
    diff = next(n for n in nt.nodes if n.type == 'BSDF_DIFFUSE')
    nt.links.new(tex.outputs["Color"], diff.inputs["Color"])
    H.add_cube(sc, material=m)
    s, _ = export()
    assert len(s.textures) == 1
    t = s.textures[0]
    assert t.shape == (2, 4, 4) and t.dtype == np.float32
    # Row 0 stays the bottom row; sRGB 128/255 decodes to 0.2158605.
    assert np.allclose(t[0, :, 0], 0.2158605, atol=2e-4)
    assert np.allclose(t[1, :, 1], 1.0)
    lobe = s.materials[0].lobes[0]
    assert lobe.color_texture == 0 and lobe.color == (1.0, 1.0, 1.0)


def test_image_texture_into_roughness_is_a_roughness_map():
    """A roughness map (Non-Color, half 0.2 and half 0.8) into the
    Principled Roughness and an image's alpha into a Glossy's: a scalar
    texture on the lobe (``Lobe.roughness_texture``, read per hit by the
    camera side, core.materials.rough_maps) and the map's mean as its
    roughness (0.2: the Rec.709 luminance of the colour, associated with
    alpha as Cycles' Color output gives it; 0.4: the alpha channel's mean),
    what the frequency model reads."""
    sc = base_scene()
    m = H.node_material("PBR", "BSDF_PRINCIPLED")
    nt = m.node_tree
    img = bpy.data.images.new("rough", 4, 2, alpha=True, float_buffer=True)
    img.colorspace_settings.name = 'Non-Color'
    px = np.ones((2, 4, 4), np.float32)
    px[0, :, :3], px[1, :, :3] = 0.2, 0.8
    px[..., 3] = np.array([0.1, 0.3, 0.5, 0.7], np.float32)       # alpha mean 0.4
    img.pixels.foreach_set(px.ravel())
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = img
    p = next(n for n in nt.nodes if n.type == 'BSDF_PRINCIPLED')
    p.inputs["Metallic"].default_value = 1.0
    nt.links.new(tex.outputs["Color"], p.inputs["Roughness"])
    g = H.node_material("Gloss", "BSDF_GLOSSY")
    gn = next(n for n in g.node_tree.nodes if n.type == 'BSDF_GLOSSY')
    t2 = g.node_tree.nodes.new("ShaderNodeTexImage")
    t2.image = img
    g.node_tree.links.new(t2.outputs["Alpha"], gn.inputs["Roughness"])
    H.add_cube(sc, "A", material=m)
    H.add_cube(sc, "B", location=(3, 0, 0), material=g)
    s, lines = export()
    M = {mm.name: mm for mm in s.materials}
    # The Color output of an image with alpha whose Alpha output is not
    # linked: the colour associated with alpha (Cycles), 0.2 a and 0.8 a.
    (metal,) = M["PBR"].lobes
    assert metal.roughness == pytest.approx(0.2, abs=1e-6)
    np.testing.assert_allclose(s.textures[metal.roughness_texture][..., 3],
                               px[..., 0] * px[..., 3], atol=1e-6)
    (gloss,) = M["Gloss"].lobes
    assert gloss.roughness == pytest.approx(0.4, abs=1e-6)
    np.testing.assert_allclose(s.textures[gloss.roughness_texture][..., 3], px[..., 3])
    assert "Roughness" not in " ".join(lines)       # nothing approximated


# ---------------------------------------------------------------- errors

def test_no_lights_message():
    sc = H.empty_scene()
    H.add_camera(sc)
    H.add_plane(sc)
    with pytest.raises(SceneError) as ei:
        export()
    assert str(ei.value) == "The scene has no lights: add a light, an emissive material or a world colour."


def test_emissive_material_or_world_counts_as_light():
    sc = H.empty_scene()
    H.add_camera(sc)
    H.add_plane(sc, material=H.node_material("L", "EMISSION", Strength=2.0))
    assert export()[0].n_triangles == 2
    sc2 = H.empty_scene()
    H.add_camera(sc2)
    H.add_plane(sc2)
    H.set_world(sc2, (0.5, 0.5, 0.5))
    assert export()[0].n_triangles == 2


def test_no_camera_and_nothing_visible():
    sc = H.empty_scene()
    H.add_light(sc)
    H.add_plane(sc)
    with pytest.raises(SceneError, match="no camera"):
        export()
    sc = H.empty_scene()
    H.add_light(sc)
    H.add_camera(sc)
    with pytest.raises(SceneError, match="Nothing is visible"):
        export()


def test_current_frame_is_exported():
    sc = base_scene()
    ob = H.add_cube(sc)
    ob.location = (0, 0, 0)
    ob.keyframe_insert("location", frame=1)
    ob.location = (0, 0, 5)
    ob.keyframe_insert("location", frame=11)
    zs = []
    for f in (1, 6, 11):
        sc.frame_set(f)
        zs.append(float(export()[0].tri_p[:, :, 2].mean()))
    assert zs[0] == pytest.approx(0.0, abs=1e-6) and zs[2] == pytest.approx(5.0, abs=1e-5)
    assert 0.0 < zs[1] < 5.0


# Counts derived from example_blends/make_examples.py (quad = 2 triangles,
# box = 12, uv_sphere = 2 * segments * (rings - 1), open_cylinder = 2 * segments).
EXAMPLES = {
    "cornell": (5 * 2 + 2 * 12, 1, {"Red", "Green", "White"}),
    "coffee_cup": (2 + 2 * 96, 1, {"Table", "Mirror"}),
    "glass_sphere": (2 + 2 + 2 * 32 * 15, 1, {"Floor", "Wall", "Glass"}),
    "point_caustic": (2 + 2 + 2 * 32 * 15 + 12, 1, {"Floor", "Wall", "Glass", "Clay"}),
    "indirect_room": (6 * 2 + 12 + 2 * 24 * 11 + 12, 1,
                      {"Plaster", "BlueWall", "Floor", "Oak", "Ceramic"}),
    "ring_lambert": (98, 1, {"Lambert", "Mirror"}),
    "ring_principled": (98, 1, {"Material", "Mirror"}),
    "principled_interior": (570, 1, {"Material"}),
}


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_example_scene_counts(name):
    path = os.path.join(H.ROOT, "example_blends", name + ".blend")
    if not os.path.exists(path):
        pytest.skip(f"{name}.blend not generated")
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False, use_scripts=False)
    H.ensure_registered()
    s, lines = export()
    tris, n_lights, mats = EXAMPLES[name]
    assert s.n_triangles == tris
    assert len(s.lights) == n_lights
    assert {m.name for m in s.materials} == mats
    # Only supported nodes are used in the examples: nothing approximated.
    assert lines[1] == "Approximated: nothing.", lines[1]
    assert not [ln for ln in lines if ln.startswith("Warning")]
    # FPPM traces as many bounces as the file's Cycles Light Paths allow:
    # at 8 against Cycles' 16, indirect_room rendered 2.8% darker than Cycles
    # (image mean 0.972; 0.998 at 16), a bias FPPM and PPM shared.
    sc = bpy.context.scene
    assert sc.fppm.max_bounces == sc.cycles.max_bounces == sc.cycles.diffuse_bounces
