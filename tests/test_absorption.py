"""Absorbing volumes (a Volume Absorption in a material's Volume), against Cycles.

Inside a closed surface whose material has a Volume Absorption of constant
Color c and Density rho, every ray keeps exp(-rho (1 - c) t) over a length
t (``core.scene.absorption``; Cycles' volume stack for volumes that do not
nest).  The cases render tests/test_shading_nodes.py's floor with a block
over it in FPPM's integrators and in Cycles, two seeds a side, under that
file's bound (2x the seed-to-seed noise plus 1 % of the mean), and check
that the absorption moves the image by more than 3x that bound (the same
export rendered without it).  "fog": the block has a Volume and no
Surface (its boundary lets every ray through; shadow rays cross it and are
attenuated); "glass": a Glass BSDF block, seen through from above.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.scene import absorption as A

RES = 40


def test_attenuate_takes_the_back_sides_of_absorbing_surfaces():
    """A hit on the back side (winding normal along the ray) of an
    absorbing material's triangle keeps exp(-sigma t |d|); its front side,
    another material and a miss keep everything."""
    from core.scene.model import Material
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 2, np.float32)   # normal +z
    sc = type("S", (), {})()
    sc.materials = [Material("a", absorption=(0.5, 1.0, 2.0)), Material("b")]
    sc.tri_mat, sc.tri_p = np.array([0, 1], np.int32), tri
    ab = A.of_scene(sc)
    assert ab is not None and A.of_scene(sc) is ab
    prim = np.array([0, 0, 1, -1])
    d = np.array([[0, 0, 2.0], [0, 0, -1.0], [0, 0, 1.0], [0, 0, 1.0]])
    t = np.array([0.5, 0.5, 0.5, np.inf])
    beta = np.ones((4, 3))
    A.attenuate(ab, prim, t, d, beta)
    np.testing.assert_allclose(beta[0], np.exp(-np.array([0.5, 1.0, 2.0]) * 1.0))
    np.testing.assert_array_equal(beta[1:], 1.0)
    sc2 = type("S", (), {})()
    sc2.materials, sc2.tri_mat, sc2.tri_p = [Material("b")], np.zeros(1, np.int32), tri[:1]
    assert A.of_scene(sc2) is None


def _scene(case):
    """The floor and box of tests/test_shading_nodes.py without the box,
    under its sun, a block 0.5 m high floating over the floor; "fog": a
    Volume Absorption (density 2) and no Surface; "glass": a Glass BSDF
    (IOR 1.45) with a Volume Absorption (density 6)."""
    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16)
    TS.floor_and_box()
    bpy.data.objects.remove(bpy.data.objects["Box"])
    # (The glass: a low sun, whose shadow of the block falls beside the
    # floor seen through it.)
    TS.ortho_view(sc, 2.2, sun_energy=3.0,
                  sun_rotation=(0.5, 0.3, 0.0) if case == "fog" else (1.0, 0.4, 0.0))
    K.set_world(sc, (0.05, 0.05, 0.05))
    mat, nt, out = K._new_material("Tinted")
    a = nt.nodes.new('ShaderNodeVolumeAbsorption')
    a.inputs["Color"].default_value = (0.2, 0.55, 0.9, 1.0)
    a.inputs["Density"].default_value = 2.0 if case == "fog" else 6.0
    nt.links.new(a.outputs[0], out.inputs["Volume"])
    if case == "glass":
        g = nt.nodes.new('ShaderNodeBsdfGlass')
        g.inputs["Roughness"].default_value = 0.0
        g.inputs["IOR"].default_value = 1.45
        nt.links.new(g.outputs[0], out.inputs["Surface"])
    K.box("Block", (1.2, 0.9, 0.5), mat, location=(0.1, -0.05, 0.15), rot_z_deg=20.0)
    return sc


def _clear(scene):
    return dataclasses.replace(scene, materials=[dataclasses.replace(m, absorption=())
                                                 for m in scene.materials])


#: (case, integrator).  Photon mapping and light tracing would show the sun
#: refracted through the glass, which Cycles cannot sample: the glass is
#: compared in Path Tracing.  (Light tracing's paths are the photons'.)
CASES = [("fog", "PHOTON"), ("fog", "PATH"), ("glass", "PATH")]


@pytest.mark.parametrize("case,integrator", CASES, ids=[f"{c}-{i}" for c, i in CASES])
def test_absorption_agrees_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Absorbing volumes"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = _scene(case)
    scene, lines = TS._export()
    assert any(m.absorption for m in scene.materials)
    assert not any("volume" in ln for ln in lines), lines
    TS.agrees_with_cycles(sc, scene, integrator, tmp_path, _clear(scene), case,
                          key=(__name__, case))


def test_a_volume_without_a_surface_lets_every_ray_through():
    """A Principled Volume with no Surface (a fog box FPPM does not render):
    exported as a white Transparent BSDF, so the box is not a black block,
    with the note; a textured Volume Absorption is ignored with it too."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    from core.scene.model import TRANSPARENT
    from scenes import bpy_kit as K
    sc = K.reset_scene((8, 8), samples=1)
    TS.ortho_view(sc, 2.0)
    fog, nt, out = K._new_material("Fog")
    nt.links.new(nt.nodes.new('ShaderNodeVolumePrincipled').outputs[0], out.inputs["Volume"])
    K.box("FogBox", (1.0, 1.0, 0.5), fog)
    tex, nt, out = K._new_material("Textured")
    a = nt.nodes.new('ShaderNodeVolumeAbsorption')
    nt.links.new(nt.nodes.new('ShaderNodeTexNoise').outputs[0], a.inputs["Density"])
    nt.links.new(a.outputs[0], out.inputs["Volume"])
    K.box("NoiseBox", (0.5, 0.5, 0.5), tex, location=(0.6, 0.6, 0))
    scene, lines = TS._export()
    for name in ("Fog", "Textured"):
        m = next(m for m in scene.materials if m.name == name)
        assert [(lb.kind, tuple(lb.color)) for lb in m.lobes] == [(TRANSPARENT, (1.0, 1.0, 1.0))]
        assert m.absorption == ()
    assert sum("volume ignored" in ln for ln in lines) >= 1, lines


def test_compiled_camera_pass_equals_numpy_with_absorption():
    """The glass block's scene: the compiled camera pass (through the
    glass, its chains' throughput attenuated) adds the same emission and
    finds the same visible points as the numpy reference, bit for bit, and
    the absorption darkens what is seen through the glass."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    from core.render import Renderer
    from core.settings import RenderSettings
    _scene("glass")
    scene, _ = TS._export()
    out = {}
    for name, sc in (("absorbing", scene), ("clear", _clear(scene))):
        cam = Renderer(sc, RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=100,
                                          seed=1), log=lambda _m: None).camera_pass
        for compiled in (False, True):
            cam.compiled = compiled
            vp, L = cam(np.random.default_rng(11))
            out[name, compiled] = (vp, L.copy())
    (vp_n, L_n), (vp_c, L_c) = out["absorbing", False], out["absorbing", True]
    assert np.array_equal(L_n, L_c)
    for f in ("valid", "p", "mat", "beta"):
        assert np.array_equal(getattr(vp_n, f), getattr(vp_c, f)), f
    assert vp_n.beta[vp_n.valid].sum() < 0.95 * out["clear", True][0].beta[vp_n.valid].sum()
