"""The Diffuse, Glossy and Transmission Color passes, the Environment,
Ambient Occlusion and UV passes against Cycles (core/sppm/color_passes.py,
core/materials/albedo.py).

One scene, 48x36: a Principled floor (Blender's default material: a
dielectric specular layer over the diffuse, Multiscatter GGX), a
Principled metal cube (F82 tint), a smooth glass sphere, a Glossy BSDF
cube, a card half Transparent in front of it, under an HDRI the camera
sees above the horizon, the world's AO distance 1 m.  The floor is a mesh without a UV map (its UV
pass is 0); the cube and sphere have Blender's primitive UVs.  FPPM
renders 8 passes, Cycles 128 samples, two seeds a side; each pass is
compared inside every object (Cycles' Object Index) under the project's
bound, 2x the seed-to-seed noise + 1 % of the mean
(tests/test_shading_nodes.py ``_check``).  Measured (README "Passes"): every
object's error 0.63-1.74x its seed noise.
"""
from __future__ import annotations

import numpy as np
import pytest

NAMES = ("Diffuse Color", "Glossy Color", "Transmission Color", "Environment",
         "Ambient Occlusion", "UV")
FLAGS = ("use_pass_diffuse_color", "use_pass_glossy_color", "use_pass_transmission_color",
         "use_pass_environment", "use_pass_ambient_occlusion", "use_pass_uv",
         "use_pass_object_index")
N_FPPM, N_CYCLES = 8, 128


def _scene():
    import bpy
    import bpy_helpers as H
    import test_environment as TE
    sc = H.empty_scene((48, 36))
    H.add_plane(sc, material=H.node_material("Floor", "BSDF_PRINCIPLED"), size=8.0).pass_index = 1
    metal = H.node_material("Metal", "BSDF_PRINCIPLED", **{"Base Color": (0.9, 0.6, 0.2, 1.0)},
                            Metallic=1.0, Roughness=0.3)
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(-0.9, 0.3, 0.4))
    ob = bpy.context.active_object
    ob.data.materials.append(metal)
    ob.pass_index = 2
    glass = H.node_material("Glass", "BSDF_GLASS", Color=(0.9, 0.95, 1.0, 1.0), Roughness=0.0,
                            IOR=1.45)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=(0.8, 0.0, 0.45), segments=24,
                                         ring_count=12)
    ob = bpy.context.active_object
    ob.data.materials.append(glass)
    ob.pass_index = 3
    bpy.ops.object.shade_smooth()
    gloss = H.node_material("Gloss", "BSDF_GLOSSY", Color=(0.2, 0.8, 0.3, 1.0), Roughness=0.2)
    H.add_cube(sc, name="G", size=0.7, location=(0.0, 1.6, 0.35), material=gloss).pass_index = 4
    card = H.node_material("Card", "BSDF_DIFFUSE", Color=(0.8, 0.1, 0.1, 1.0))
    nt = card.node_tree
    out = next(n for n in nt.nodes if n.type == 'OUTPUT_MATERIAL')
    d = next(n for n in nt.nodes if n.type == 'BSDF_DIFFUSE')
    t, mix = nt.nodes.new('ShaderNodeBsdfTransparent'), nt.nodes.new('ShaderNodeMixShader')
    mix.inputs["Fac"].default_value = 0.5
    nt.links.new(d.outputs[0], mix.inputs[1])
    nt.links.new(t.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    H.mesh_object(sc, "Card", [(-0.3, 0.9, 0.1), (0.3, 0.9, 0.1), (0.3, 0.9, 0.8),
                               (-0.3, 0.9, 0.8)], [(0, 1, 2, 3)], card).pass_index = 5
    H.add_light(sc, "POINT", 200.0, (1.0, -1.0, 3.0))
    TE.hdri_world(sc, TE.spiky_image())
    sc.world.light_settings.distance = 1.0     # the AO rays' reach (Blender's default: 10 m)
    H.add_camera(sc)
    vl = sc.view_layers[0]
    for k in FLAGS:
        setattr(vl, k, True)
    H.small_settings(sc, passes=N_FPPM, photons=2000, integrator="PHOTON")
    return sc


def _result(sc, path):
    import bpy_helpers as H
    return {k.split(".", 1)[1]: v for k, v in H.save_multilayer(sc, path).items()}


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    """{'f1', 'f2' (FPPM seeds 1, 2), 'c0', 'c1' (Cycles seeds 0, 1)}: the passes."""
    bpy = pytest.importorskip("bpy")
    import fppm.addon.engine as E
    tmp = tmp_path_factory.mktemp("color_passes")
    sc = _scene()
    out = {}
    for seed in (1, 2):
        sc.render.engine, sc.fppm.seed = 'FPPM', seed
        sess = E.RenderSession(log=lambda m: None)
        with E.session(sess):
            bpy.ops.render.render()
        assert sess.error is None, sess.error
        out[f"f{seed}"] = _result(sc, tmp / f"f{seed}.exr")
    sc.render.engine = 'CYCLES'
    sc.cycles.samples, sc.cycles.use_denoising, sc.cycles.device = N_CYCLES, False, 'CPU'
    sc.cycles.use_adaptive_sampling = False
    for seed in (0, 1):
        sc.cycles.seed = seed
        bpy.ops.render.render()
        out[f"c{seed}"] = _result(sc, tmp / f"c{seed}.exr")
    return out


@pytest.mark.parametrize("name", NAMES)
def test_pass_agrees_with_cycles_on_every_object(renders, name):
    import test_shading_nodes as TS
    f1, f2, c1, c2 = (renders[k][name] for k in ("f1", "f2", "c0", "c1"))
    f, c = (f1 + f2) / 2, (c1 + c2) / 2
    ob = renders["c0"]["Object Index"][..., 0]
    checked = 0
    for o in np.unique(ob):
        m = ob == o
        mean = c[m].mean()
        if mean < 0.01 * c.mean():
            # The pass is (nearly) 0 there: the floor's UV, the objects'
            # Environment (a few samples past a silhouette or the horizon).
            assert np.abs(f[m]).mean() < 0.02 * c.mean(), (name, o)
            continue
        err = np.abs(f - c)[m].mean() / mean
        noise = (np.abs(f1 - f2)[m].mean() + np.abs(c1 - c2)[m].mean()) / 2 / mean
        print(f"{name} object {int(o)}: {m.sum()} px, error {err:.4f}, noise {noise:.4f}")
        TS._check(err, noise)
        checked += 1
    assert checked >= 2


def test_values_cycles_defines(renders):
    from test_passes import _interior
    f, c = renders["f1"], renders["c0"]
    ob = c["Object Index"][..., 0]
    inside = _interior(c)          # no filter sample of the pixel sees another object
    floor, cube = inside & (ob == 1), inside & (ob == 2)
    assert floor.sum() > 200 and cube.sum() > 20
    # A mesh without a UV map writes (0, 0, 0); one with writes (u, v, 1)
    # (channels U, V, A: read_exr puts A first).
    for r in (f, c):
        assert np.all(r["UV"][floor] == 0.0)
        assert np.allclose(r["UV"][..., 0][cube], 1.0)
    # The Principled floor's diffuse colour is its base colour 0.8 less the
    # specular layer's albedo (about 0.71 here), its glossy colour the
    # layer's Fresnel estimate (about 0.11): both far from 0.8 and 1.
    d = f["Diffuse Color"][floor].mean()
    g = f["Glossy Color"][floor].mean()
    assert 0.6 < d < 0.78 and 0.05 < g < 0.2, (d, g)


def test_closure_albedos_of_lambert_and_smooth_glass():
    """Closed forms at normal incidence: a Lambert lobe's albedo is its
    colour; smooth glass (IOR 1.5) splits its colour into F0 = 0.04
    reflected and 0.96 transmitted."""
    from fppm.core.materials import build_material_table, lobe_colors
    from fppm.core.materials.albedo import closure_albedos
    from fppm.core.scene.model import DIFFUSE, GLASS, Lobe, Material
    mats = [Material("d", lobes=(Lobe(DIFFUSE, (0.5, 0.25, 0.1)),)),
            Material("g", lobes=(Lobe(GLASS, (1.0, 0.9, 0.8), roughness=0.0, ior=1.5),))]
    tab = build_material_table(mats, [])
    mat = np.array([0, 1])
    cols = lobe_colors(tab, mat, np.zeros((2, 2)), np.ones(2))
    a = closure_albedos(tab, mat, cols, np.ones(2), np.ones(2, bool))
    assert np.allclose(a[0, 0], (0.5, 0.25, 0.1)) and np.all(a[1:, 0] == 0.0)
    assert np.allclose(a[1, 1], 0.04 * np.array([1.0, 0.9, 0.8]), rtol=0.02)
    assert np.allclose(a[2, 1], 0.96 * np.array([1.0, 0.9, 0.8]), rtol=0.002)
    assert np.all(a[0, 1] == 0.0)
