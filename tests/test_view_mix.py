"""Mix Shaders whose Fac depends on the view: a Fresnel node, a Layer
Weight's Fresnel or Facing output, also through converter and colour
nodes (a Color Ramp), sampled per lobe over mu = |w_o . n_s|
(``core.scene.model.Lobe.view``) and read per hit by every stage, against
Cycles.

A smooth sphere under a sun and a grey world, seen from every angle
between normal and grazing; FPPM and Cycles, two seeds a side, under
tests/test_shading_nodes.py's bound (2x the seed-to-seed noise plus 1 % of
the mean), and the factor's effect (the image the old reading gave, the
Fac's own value) above 3x that bound.  Then Cycles' formulas and the
lobes' factors themselves.
"""
from __future__ import annotations

import numpy as np
import pytest

from core.materials import build_material_table, lobe_colors
from core.scene import node_math as NM
from core.scene import nodes as N
from core.scene.model import DIFFUSE, GLOSSY, VIEW_SAMPLES, Material

RES = 40


def test_cycles_formulas():
    """fresnel_dielectric_cos at normal incidence is ((eta - 1) / (eta + 1))^2
    and 1 at grazing; Layer Weight's Fresnel of Blend b is the Fresnel of IOR
    1 / (1 - b); its Facing is 1 - mu^(2b) below b = 0.5, 1 - mu at 0.5,
    1 - mu^(0.5 / (1 - b)) above."""
    assert abs(NM.fresnel(1.0, 1.45) - (0.45 / 2.45) ** 2) < 1e-15
    assert NM.fresnel(0.0, 1.45) == 1.0 and NM.fresnel(0.3, 1.0) == 0.0
    mu = np.linspace(0.0, 1.0, 11)
    assert np.allclose(NM.layer_weight(mu, 0.3, "Fresnel"), NM.fresnel(mu, 1.0 / 0.7))
    assert np.allclose(NM.layer_weight(mu, 0.2, "Facing"), 1.0 - mu ** 0.4)
    assert np.allclose(NM.layer_weight(mu, 0.5, "Facing"), 1.0 - mu)
    assert np.allclose(NM.layer_weight(mu, 0.8, "Facing"), 1.0 - mu ** 2.5)


def test_each_lobe_carries_its_side_of_the_mix():
    """(1 - f) on A's lobes, f on B's, products under nested mixes, and the
    table's colours at mu interpolate them (to 1e-4 at 257 samples)."""
    mu = np.linspace(0.0, 1.0, VIEW_SAMPLES)
    f = NM.fresnel(mu, 1.45)
    a = (N.make_lobe(DIFFUSE, (0.8, 0.2, 0.1)),)
    b = (N.make_lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.2),)
    lobes, _ = N.mix_by_view(a, b, f)
    assert np.allclose(lobes[0].view, 1.0 - f) and np.allclose(lobes[1].view, f)
    g = NM.layer_weight(mu, 0.3, "Facing")
    nested, _ = N.mix_by_view(lobes, (N.make_lobe(DIFFUSE, (0.1, 0.1, 0.9)),), g)
    assert np.allclose(nested[0].view, (1.0 - f) * (1.0 - g))
    tab = build_material_table([Material("m", nested)], [])
    x = np.array([0.013, 0.37, 0.999])
    cols = lobe_colors(tab, np.zeros(3, np.int64), np.zeros((3, 2)), x)
    want = (1.0 - NM.fresnel(x, 1.45)) * (1.0 - NM.layer_weight(x, 0.3, "Facing"))
    assert np.allclose(cols[:, 0, 0] / 0.8, want, atol=1e-4)


def _scene(fac, roughness, glossy=(1.0, 1.0, 1.0), bump=False):
    """A smooth sphere (radius 0.6) seen from above, orthographic, under a
    tilted sun and a grey world; its material Mix(Diffuse red, Glossy, fac):
    "fresnel" (IOR 1.45), "layer_weight" (its Fresnel output, Blend 0.3),
    "facing" (Layer Weight Facing, Blend 0.35), "ramp" (a Fresnel through a
    Color Ramp from 0.05 to 0.6)."""
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=256, world_color=(0.5, 0.5, 0.5))
    m, nt, out = K._new_material("Varnish")
    d = nt.nodes.new('ShaderNodeBsdfDiffuse')
    d.inputs["Color"].default_value = (0.8, 0.2, 0.1, 1.0)
    g = nt.nodes.new('ShaderNodeBsdfGlossy')
    g.inputs["Color"].default_value = (*glossy, 1.0)
    g.inputs["Roughness"].default_value = roughness
    mix = nt.nodes.new('ShaderNodeMixShader')
    nt.links.new(d.outputs[0], mix.inputs[1])
    nt.links.new(g.outputs[0], mix.inputs[2])
    if fac in ("fresnel", "ramp"):
        f = nt.nodes.new('ShaderNodeFresnel')
        f.inputs["IOR"].default_value = 1.45
        src = f.outputs[0]
        if fac == "ramp":
            ramp = nt.nodes.new('ShaderNodeValToRGB')
            ramp.color_ramp.elements[0].position = 0.05
            ramp.color_ramp.elements[1].position = 0.6
            nt.links.new(src, ramp.inputs["Fac"])
            src = ramp.outputs["Color"]
    else:
        f = nt.nodes.new('ShaderNodeLayerWeight')
        f.inputs["Blend"].default_value = 0.3 if fac == "layer_weight" else 0.35
        src = f.outputs["Fresnel" if fac == "layer_weight" else "Facing"]
    nt.links.new(src, mix.inputs["Fac"])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    if bump:
        # One Bump on both shaders and the factor's node (Cycles: each reads
        # its own Normal input).
        b = TS._bump_node(nt.nodes, nt.links, distance=0.1)
        for nd in (d, g, f):
            nt.links.new(b, nd.inputs["Normal"])
    ob = TS.uv_sphere_object("Ball", m)
    ob.location = (0.0, 0.0, 0.0)
    TS.ortho_view(sc, sun_energy=2.0, sun_angle=0.1, sun_rotation=(0.6, 0.3, 0.0))
    return sc, mix


def _render(scene, integrator, seed):
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    # Photon mapping: one visible point a pixel a pass (Path Tracing: 8 paths).
    st = RenderSettings(integrator=integrator, max_passes=48 if integrator == "PHOTON" else 12,
                        camera_samples=8, seed=seed, photons_per_pass=20_000,
                        use_frequency=False, max_bounces=16)
    return Renderer(scene, st, log=lambda s: None).run().image[..., :3].astype(np.float64)


#: (fac, glossy roughness, integrator[, glossy colour[, one Bump on every node]])
CASES = [("fresnel", 0.0, "PATH"), ("fresnel", 0.0, "PHOTON"), ("fresnel", 0.5, "PATH"),
         ("fresnel", 0.8, "PATH"), ("fresnel", 0.3, "COMBINED"), ("layer_weight", 0.15, "PATH"),
         ("facing", 0.3, "PATH"), ("ramp", 0.2, "PATH"), ("fresnel", 0.2, "PATH", (0.9, 0.6, 0.2)),
         ("fresnel", 0.2, "PATH", (1.0, 1.0, 1.0), True)]


@pytest.mark.parametrize("case", CASES, ids=["-".join(map(str, c[:3]))
                                             + ("-bump" if len(c) > 4 else "-tint" if len(c) > 3
                                                else "") for c in CASES])
def test_a_view_mix_agrees_with_cycles(case, tmp_path):
    """Measured: docs/shading.md "View-dependent mixes: Fresnel and Layer
    Weight"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    fac, roughness, integrator = case[:3]
    sc, mix = _scene(fac, roughness, *case[3:])
    scene, lines = TS._export()
    assert not any("ignored" in ln or "read as its value" in ln for ln in lines), lines
    assert any(lb.view for lb in scene.materials[0].lobes)
    err, noise, img, ref = TS.two_seeds(sc, scene, lambda s, seed: _render(s, integrator, seed),
                                        tmp_path, 256,
                                        key=(__name__,) + tuple(case[:2]) + tuple(case[3:]))
    mean = ref.mean()
    # The old reading: the Fac's own value (0.5), a plain mix.
    for ln in mix.inputs["Fac"].links:
        mix.id_data.links.remove(ln)
    old, _ = TS._export()
    effect = np.abs(_render(old, integrator, 1) - ref).mean() / mean
    print(f"{case}: mean {img.mean():.4f} vs Cycles {mean:.4f}; |diff| {err:.4f}, "
          f"noise {noise:.4f} ({err / noise:.2f}x); Fac 0.5 {effect:.4f}")
    TS._check(err, noise, effect)
