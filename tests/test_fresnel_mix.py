"""A Mix Shader of a Diffuse and a Glossy BSDF by a Fresnel factor (a
Fresnel node, or a Layer Weight's Fresnel output), rendered as the
Principled BSDF's dielectric layer (core/scene/nodes.py ``fresnel_mix``),
against Cycles.

A smooth sphere under a sun and a grey world, seen from every angle
between normal and grazing; FPPM and Cycles, two seeds a side, under
tests/test_shading_nodes.py's bound (2x the seed-to-seed noise plus 1 % of
the mean), and the Fresnel factor's effect (the image the old reading gave,
the Fac's own value) above 3x that bound.  Then the lobes themselves.
"""
from __future__ import annotations

import numpy as np
import pytest

from core.scene import nodes as N
from core.scene.model import DIFFUSE, GLOSSY, Lobe

RES = 40


def test_the_lobes_are_the_principled_layer():
    """Diffuse A under Glossy B: B becomes a white GGX with the dielectric
    Fresnel of the IOR, weighted by its grey colour; A gets the layer of
    that IOR and B's roughness; other forms are refused."""
    a = (N.make_lobe(DIFFUSE, (0.8, 0.2, 0.1)),)
    b = (N.make_lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.2, multiscatter=True),)
    lobes, note = N.fresnel_mix(a, b, 1.45)
    spec, under = lobes
    assert spec.kind == GLOSSY and spec.fresnel == "DIELECTRIC" and spec.fresnel_ior == 1.45
    assert spec.color == (1.0, 1.0, 1.0) and abs(spec.weight - 0.9) < 1e-12
    assert spec.roughness == 0.2 and spec.multiscatter
    assert under.kind == DIFFUSE and under.color == (0.8, 0.2, 0.1)
    assert under.layer_ior == 1.45 and under.layer_roughness == 0.2 and under.layer_multiscatter
    assert abs(under.layer_f0 - ((1.45 - 1) / (1.45 + 1)) ** 2) < 1e-12
    assert note == ""                                        # roughness 0.2: no note
    rough = (N.make_lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.5),)
    assert "rough Glossy" in N.fresnel_mix(a, rough, 1.45)[1]
    tinted = (N.make_lobe(GLOSSY, (0.9, 0.5, 0.5)),)
    assert N.fresnel_mix(a, tinted, 1.45) is None            # a coloured glossy
    assert N.fresnel_mix(b, a, 1.45) is None                 # the glossy below
    assert N.fresnel_mix(a, b + b, 1.45) is None             # two glossy lobes
    assert N.fresnel_mix(a, b, 1.0) is None                  # no Fresnel at IOR 1
    assert isinstance(b[0], Lobe)


def _scene(fac, roughness):
    """A smooth sphere (radius 0.6) seen from above, orthographic, under a
    tilted sun and a grey world; its material Mix(Diffuse red, Glossy white,
    fac): "fresnel" (IOR 1.45), "layer_weight" (its Fresnel output, Blend
    0.3)."""
    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=256, world_color=(0.5, 0.5, 0.5))
    m, nt, out = K._new_material("Varnish")
    d = nt.nodes.new('ShaderNodeBsdfDiffuse')
    d.inputs["Color"].default_value = (0.8, 0.2, 0.1, 1.0)
    g = nt.nodes.new('ShaderNodeBsdfGlossy')
    g.inputs["Roughness"].default_value = roughness
    mix = nt.nodes.new('ShaderNodeMixShader')
    nt.links.new(d.outputs[0], mix.inputs[1])
    nt.links.new(g.outputs[0], mix.inputs[2])
    if fac == "fresnel":
        f = nt.nodes.new('ShaderNodeFresnel')
        f.inputs["IOR"].default_value = 1.45
        nt.links.new(f.outputs[0], mix.inputs["Fac"])
    else:
        f = nt.nodes.new('ShaderNodeLayerWeight')
        f.inputs["Blend"].default_value = 0.3
        nt.links.new(f.outputs["Fresnel"], mix.inputs["Fac"])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    ob = TS.uv_sphere_object("Ball", m)
    ob.location = (0.0, 0.0, 0.0)
    cam_d = bpy.data.cameras.new("Cam")
    cam_d.type = 'ORTHO'
    cam_d.ortho_scale = 1.4
    cam = bpy.data.objects.new("Cam", cam_d)
    cam.location = (0, 0, 3)
    K.link(cam)
    sc.camera = cam
    ld = bpy.data.lights.new("Sun", 'SUN')
    ld.energy = 2.0
    ld.angle = 0.1
    sun = bpy.data.objects.new("Sun", ld)
    sun.rotation_euler = (0.6, 0.3, 0.0)
    K.link(sun)
    return sc, mix


def _render(scene, integrator, seed):
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    # Photon mapping: one visible point a pixel a pass (Path Tracing: 8 paths).
    st = RenderSettings(integrator=integrator, max_passes=48 if integrator == "PHOTON" else 12,
                        camera_samples=8, seed=seed, photons_per_pass=20_000,
                        use_frequency=False, max_bounces=16)
    return Renderer(scene, st, log=lambda s: None).run().image[..., :3].astype(np.float64)


CASES = [("fresnel", 0.0, "PATH"), ("fresnel", 0.0, "PHOTON"), ("fresnel", 0.15, "PATH"),
         ("layer_weight", 0.15, "PATH"), ("fresnel", 0.3, "PATH")]


@pytest.mark.parametrize("fac,roughness,integrator", CASES,
                         ids=[f"{f}-{r}-{i}" for f, r, i in CASES])
def test_a_fresnel_mix_agrees_with_cycles(fac, roughness, integrator, tmp_path):
    """Measured: docs/shading.md "Fresnel and Layer Weight mixes"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc, mix = _scene(fac, roughness)
    scene, lines = TS._export()
    assert not any("ignored" in ln or "Fresnel mix" in ln for ln in lines), lines
    c1 = TS._cycles(sc, 0, tmp_path / "c0.exr", 256)
    c2 = TS._cycles(sc, 1, tmp_path / "c1.exr", 256)
    a1, a2 = _render(scene, integrator, 1), _render(scene, integrator, 2)
    ref, img = (c1 + c2) / 2, (a1 + a2) / 2
    mean = ref.mean()
    err = np.abs(img - ref).mean() / mean
    noise = (np.abs(a1 - a2).mean() + np.abs(c1 - c2).mean()) / 2 / mean
    # The old reading: the Fac's own value (0.5), a plain mix.
    for ln in mix.inputs["Fac"].links:
        mix.id_data.links.remove(ln)
    old, _ = TS._export()
    effect = np.abs(_render(old, integrator, 1) - ref).mean() / mean
    print(f"{fac} r={roughness} {integrator}: mean {img.mean():.4f} vs Cycles {mean:.4f}; "
          f"|diff| {err:.4f}, noise {noise:.4f} ({err / noise:.2f}x); Fac 0.5 {effect:.4f}")
    TS._check(err, noise, effect)


def test_a_fresnel_mix_over_a_rough_glossy_is_noted_and_near(tmp_path):
    """Roughness 0.8: Cycles weighs the Glossy by F at the shading normal
    and the Diffuse by 1 - F; the layer reflects F at each microfacet
    normal and leaves the Diffuse 1 - its albedo.  Measured: the image mean
    1.7 % below Cycles' (error 5x the seed noise of 0.45 %); noted in the
    log.  Bound: the mean within 3 %."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc, _ = _scene("fresnel", 0.8)
    scene, lines = TS._export()
    assert any("rough Glossy (roughness 0.8)" in ln for ln in lines), lines
    ref = TS._cycles(sc, 0, tmp_path / "c0.exr", 256)
    ratio = _render(scene, "PATH", 1).mean() / ref.mean()
    print(f"fresnel r=0.8 PATH: mean / Cycles' {ratio:.4f}")
    assert 0.97 < ratio < 1.0
