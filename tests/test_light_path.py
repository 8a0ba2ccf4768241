"""Light Path's Is Camera Ray and Is Shadow Ray in materials, against Cycles.

A Mix Shader whose Fac is Is Camera Ray shows camera rays (also through
Transparent BSDFs) one shader and every other ray another; Is Shadow Ray
does the same for shadow rays (``core.scene.ray_variants``).  The
glass-shadow trick (a Glass that shadow rays see as a white Transparent
BSDF) makes the object shadowless (``clear_shadows``).  Each case renders
tests/test_shading_nodes.py's floor and box in FPPM's integrators and in
Cycles, two seeds a side, under that file's bound (2x the seed-to-seed
noise plus 1 % of the mean), and checks that the Light Path moves the image
by more than 3x the bound (the same export with every ray seeing the
material itself).  Then the exporter's reading, the material split of
light linking with variants, and the compiled camera pass against its
numpy reference.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

RES = 40


def _scene(case):
    """"camera": the box red to camera rays, blue to every other ray (its
    light on the floor is blue); "card": an emitting card over the box that
    camera rays see as a Transparent BSDF (an unseen light); "glass": the
    box a Glass that shadow rays see as a white Transparent BSDF, under the
    sun alone; "tinted": the same with an orange Transparent BSDF."""
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16)
    box, nt, d, out = TS.floor_and_box()
    TS.ortho_view(sc, 2.2, sun_energy=0.0 if case == "card" else 3.0)
    K.set_world(sc, (0.0,) * 3 if case in ("glass", "tinted") else (0.05,) * 3)
    if case == "card":
        lamp = TS.lamp_over_box()
        nt = lamp.data.materials[0].node_tree
        out = next(n for n in nt.nodes if n.type == 'OUTPUT_MATERIAL')
        seen_by_others = next(n for n in nt.nodes if n.type == 'EMISSION')
        seen_by_rays = nt.nodes.new('ShaderNodeBsdfTransparent')
        output = "Is Camera Ray"
    elif case == "camera":
        seen_by_others = nt.nodes.new('ShaderNodeBsdfDiffuse')
        seen_by_others.inputs["Color"].default_value = (0.1, 0.2, 0.8, 1.0)
        seen_by_rays, output = d, "Is Camera Ray"
    else:
        seen_by_others = nt.nodes.new('ShaderNodeBsdfGlass')
        seen_by_others.inputs["Roughness"].default_value = 0.0
        seen_by_rays = nt.nodes.new('ShaderNodeBsdfTransparent')
        if case == "tinted":
            seen_by_rays.inputs["Color"].default_value = (0.9, 0.6, 0.3, 1.0)
        output = "Is Shadow Ray"
    mix = nt.nodes.new('ShaderNodeMixShader')
    nt.links.new(nt.nodes.new('ShaderNodeLightPath').outputs[output], mix.inputs["Fac"])
    nt.links.new(seen_by_others.outputs[0], mix.inputs[1])
    nt.links.new(seen_by_rays.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    return sc


def _as_itself(scene):
    """The scene with every ray seeing each material itself (no Light Path)."""
    return dataclasses.replace(scene, material_camera=None, material_shadow=None,
                               tri_visibility=None)


#: (case, integrator).  Combined leaves light tracing out of these scenes
#: (test_combined_leaves_light_tracing_out) and is Path Tracing's image
#: under a sun or a card alone; a tinted shadow material is
#: honoured by shadow rays alone (photons see the Glass): Path Tracing is
#: Cycles' there; light tracing sees no glass.
CASES = [("camera", "PHOTON"), ("camera", "PATH"), ("camera", "LIGHT"),
         ("card", "PHOTON"), ("card", "LIGHT"),
         ("glass", "PHOTON"), ("tinted", "PATH")]


@pytest.mark.parametrize("case,integrator", CASES, ids=[f"{c}-{i}" for c, i in CASES])
def test_light_path_agrees_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Light Path in materials"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = _scene(case)
    scene, lines = TS._export()
    if case in ("camera", "card"):
        assert scene.material_camera is not None and scene.material_shadow is None
    elif case == "glass":
        # Shadowless instead: the Shadow visibility of the box's triangles.
        assert scene.material_shadow is None and scene.tri_visibility is not None
    else:
        assert scene.material_shadow is not None
        assert any("Is Shadow Ray" in ln for ln in lines)
    err, noise, img, ref = TS.two_seeds(
        sc, scene, lambda s, seed: TS.render_integrator(s, integrator, seed), tmp_path, 256,
        key=(__name__, case))
    effect = (np.abs(TS.render_integrator(_as_itself(scene), integrator, 1,
                                          passes=TS.EFFECT_PASSES) - ref).mean() / ref.mean())
    print(f"{case} {integrator}: mean {img.mean():.4f} vs Cycles {ref.mean():.4f}; |diff| "
          f"{err:.4f}, noise {noise:.4f} ({err / noise:.2f}x); as itself {effect:.4f}")
    # Photon mapping renders the sun's caustic through the plain glass, most
    # of the light the trick lets through: no effect bound there.
    TS._check(err, noise, None if (case, integrator) == ("glass", "PHOTON") else effect)


def test_exporter_mixes_once_per_ray_kind():
    """A Light Path mix inside another mix: the outer mix of each ray kind's
    inner material; an output other than Is Camera / Shadow Ray is read as
    a diffuse ray's, with a note; the variants are the scene's last
    materials, each ray kind's row mapping to them."""
    bpy = pytest.importorskip("bpy")
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((8, 8), samples=1)
    TS.ortho_view(sc, 2.0)
    m, nt, out = K._new_material("Layered")
    red, blue, green = (nt.nodes.new('ShaderNodeBsdfDiffuse') for _ in range(3))
    red.inputs["Color"].default_value = (1, 0, 0, 1)
    blue.inputs["Color"].default_value = (0, 0, 1, 1)
    green.inputs["Color"].default_value = (0, 1, 0, 1)
    lp = nt.nodes.new('ShaderNodeLightPath')
    inner, outer = (nt.nodes.new('ShaderNodeMixShader') for _ in range(2))
    nt.links.new(lp.outputs["Is Camera Ray"], inner.inputs["Fac"])
    nt.links.new(blue.outputs[0], inner.inputs[1])
    nt.links.new(red.outputs[0], inner.inputs[2])
    outer.inputs["Fac"].default_value = 0.25
    nt.links.new(inner.outputs[0], outer.inputs[1])
    nt.links.new(green.outputs[0], outer.inputs[2])
    nt.links.new(outer.outputs[0], out.inputs["Surface"])
    K.plane("P", 1.0, m)
    m2, nt2, out2 = K._new_material("Glossy ray")
    lp2 = nt2.nodes.new('ShaderNodeLightPath')
    mix2 = nt2.nodes.new('ShaderNodeMixShader')
    nt2.links.new(lp2.outputs["Is Glossy Ray"], mix2.inputs["Fac"])
    nt2.links.new(nt2.nodes.new('ShaderNodeBsdfDiffuse').outputs[0], mix2.inputs[1])
    nt2.links.new(nt2.nodes.new('ShaderNodeEmission').outputs[0], mix2.inputs[2])
    nt2.links.new(mix2.outputs[0], out2.inputs["Surface"])
    K.plane("Q", 1.0, m2, location=(1.5, 0, 0))
    scene, lines = TS._export()
    names = [mt.name for mt in scene.materials]
    i = names.index("Layered")
    cam = scene.material_camera
    assert cam is not None and cam[i] != i and scene.materials[cam[i]].name == "Layered (camera)"
    def albedo(mt):
        return np.sum([lb.weight * np.asarray(lb.color) for lb in mt.lobes], axis=0)
    np.testing.assert_allclose(albedo(scene.materials[i]), [0.0, 0.25, 0.75], atol=1e-6)
    np.testing.assert_allclose(albedo(scene.materials[cam[i]]), [0.75, 0.25, 0.0], atol=1e-6)
    j = names.index("Glossy ray")
    assert cam[j] == j and not any(scene.materials[j].emission)   # a diffuse ray's: 0
    assert any("Light Path Is Glossy Ray read as a diffuse ray's" in ln for ln in lines)
    assert scene.material_pass_index.size == len(scene.materials)


def test_light_linking_copies_a_materials_variants():
    """A material split per receiver set keeps, per copy, a copy of its
    camera variant in the same set."""
    from core.scene import linking as LL
    from test_compiled_stages import SCENES
    scene = SCENES["room"](8)
    M = len(scene.materials)
    cam = np.arange(M + 1, dtype=np.int32)
    cam[0] = M
    scene = dataclasses.replace(scene, materials=list(scene.materials) + [scene.materials[1]],
                                material_camera=cam)
    rcv = (np.arange(scene.tri_mat.size) % 2).astype(np.uint8)
    out = LL.split_materials(scene, rcv, None)
    c = out.material_camera
    users = np.unique(out.tri_mat[scene.tri_mat == 0])
    assert users.size == 2
    variants = c[users]
    assert len(set(variants.tolist())) == 2 and all(v >= M for v in variants)
    for u, v in zip(users, variants):
        assert out.material_receiver[u] == out.material_receiver[v]
        assert out.materials[v] is scene.materials[M]
    assert c.size == len(out.materials) and all(c[v] == v for v in variants)


@pytest.mark.parametrize("blocked", [False, True])
def test_compiled_camera_pass_equals_numpy_with_camera_materials(blocked, monkeypatch):
    """Camera rays seeing one material as another (the metal scene's slab
    as the mirror, its metal as the slab): the compiled camera pass (one
    call, or blocks of 700 pixels) equals the numpy reference bit for bit,
    and differs from the plain scene's."""
    from core.render import Renderer
    from core.settings import RenderSettings
    from core.sppm import visible_points as VP
    from test_compiled_stages import SCENES
    if blocked:
        monkeypatch.setattr(VP, "CAMERA_BLOCK", 700)
    base = SCENES["metal"](40)
    cam = np.arange(len(base.materials), dtype=np.int32)
    cam[1], cam[0] = 3, 1
    out = {}
    for name, sc in (("variants", dataclasses.replace(base, material_camera=cam)),
                     ("plain", base)):
        r = Renderer(sc, RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=100,
                                        seed=1), log=lambda _m: None,
                     force_stages=("glossy chains",))
        c = r.camera_pass
        for compiled in (False, True):
            c.compiled = compiled
            vp, L = c(np.random.default_rng(11))
            out[name, compiled] = (vp, L.copy())
    (vp_n, L_n), (vp_c, L_c) = out["variants", False], out["variants", True]
    assert np.array_equal(L_n, L_c)
    for f in ("valid", "p", "mat", "colors", "beta"):
        assert np.array_equal(getattr(vp_n, f), getattr(vp_c, f)), f
    assert not np.array_equal(vp_c.mat, out["plain", True][0].mat)


def test_combined_leaves_light_tracing_out():
    """Camera rays or shadow rays that see a material as another: every
    light is the camera paths' in Combined (core.integrators.mis), and the
    plan says why."""
    from core.integrators.mis import NO_LT, light_classes
    from core.lights import build_light_table
    from test_compiled_stages import SCENES
    base = SCENES["room"](8)
    M = len(base.materials)
    assert (light_classes(build_light_table(base)) != NO_LT).any()
    for kind in ("camera", "shadow"):
        rows = np.arange(M, dtype=np.int32)
        rows[0] = 1
        t = build_light_table(dataclasses.replace(base, **{"material_" + kind: rows}))
        assert (light_classes(t) == NO_LT).all(), kind
