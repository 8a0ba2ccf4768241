"""Shadow catchers (core/sppm/shadow_catcher.py) against Cycles.

A grey floor that is a shadow catcher under a red box floating over it, a
sun and a dim blue world, seen from above (tests/test_holdout.py's
scene).  Three ways Blender shows it: Film > Transparent (the Combined is
the matte, its alpha the catcher's shadow), the same with the Shadow
Catcher pass (the Combined the matte, the pass the shadow), and an opaque
film (the matte over the world, the world darkened by the shadow).  FPPM's
integrators and Cycles render each, two seeds a side; colour, alpha and
the pass are compared under tests/test_shading_nodes.py's bound (2x the
seed-to-seed noise + 1 % of the mean), and the catcher moves the image by
more than 3x that bound (the same export without it; the pass, which is 1
without a catcher, shows the shadow).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

RES = 40
PASS = "Shadow Catcher"


def _scene(case):
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16, world_color=(0.05, 0.08, 0.15))
    TS.floor_and_box()
    sc.objects["Floor"].is_shadow_catcher = True
    TS.ortho_view(sc, 2.2, sun_energy=3.0, sun_rotation=(0.6, 0.3, 0.0))
    sc.render.film_transparent = case != "opaque"
    sc.view_layers[0].cycles.use_pass_shadow_catcher = case == "pass"
    return sc


def _cycles(sc, seed, path):
    """Cycles' Combined RGBA and Shadow Catcher pass (ones without it)."""
    import bpy

    import bpy_helpers as H
    sc.render.engine = 'CYCLES'
    sc.cycles.samples, sc.cycles.seed, sc.cycles.use_animated_seed = 256, seed, False
    bpy.ops.render.render()
    d = H.save_multilayer(sc, path)
    rgba = d["ViewLayer.Combined"].astype(np.float64)
    s = d.get(f"ViewLayer.{PASS}")
    return rgba, (np.ones(rgba.shape[:2] + (3,)) if s is None else s.astype(np.float64))


def _render(scene, integrator, seed, passes=12, with_pass=False):
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    st = RenderSettings(integrator=integrator, max_passes=passes, camera_samples=8, seed=seed,
                        photons_per_pass=25_000, use_frequency=False, max_bounces=16)
    pr = Renderer(scene, st, log=lambda s: None, passes=(PASS,) if with_pass else ()).run()
    s = pr.aovs.get(PASS)
    return (pr.image.astype(np.float64),
            np.ones(pr.image.shape[:2] + (3,)) if s is None else s.astype(np.float64))


_REFS: dict = {}


def _reference(case, tmp_path):
    """(exported scene, its log, Cycles' two seeds) of a case, rendered once."""
    if case not in _REFS:
        import test_shading_nodes as TS
        sc = _scene(case)
        scene, lines = TS._export()
        _REFS[case] = (scene, lines, _cycles(sc, 0, tmp_path / "c0.exr"),
                       _cycles(sc, 1, tmp_path / "c1.exr"))
    return _REFS[case]


#: (case, integrator).  Combined renders Path Tracing's image under the sun
#: alone (tests/test_holdout.py): Path Tracing stands for it.
CASES = [("transparent", "PHOTON"), ("transparent", "PATH"), ("pass", "PHOTON"),
         ("opaque", "PHOTON")]


@pytest.mark.parametrize("case,integrator", CASES, ids=[f"{c}-{i}" for c, i in CASES])
def test_shadow_catcher_agrees_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Shadow catchers"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    scene, lines, c1, c2 = _reference(case, tmp_path)
    assert scene.tri_catcher is not None and scene.tri_catcher.sum() == 2
    assert any("shadow catcher" in ln for ln in lines), lines
    with_pass = case == "pass"
    a1 = _render(scene, integrator, 1, with_pass=with_pass)
    a2 = _render(scene, integrator, 2, with_pass=with_pass)
    without = _render(dataclasses.replace(scene, tri_catcher=None), integrator, 1,
                      passes=TS.EFFECT_PASSES)
    parts = [("colour", 0, slice(0, 3)), ("alpha", 0, slice(3, 4))]
    if case == "opaque":
        parts = parts[:1]
    if with_pass:
        parts.append(("pass", 1, slice(0, 3)))
    for name, i, ch in parts:
        ref = (c1[i][..., ch] + c2[i][..., ch]) / 2
        img = (a1[i][..., ch] + a2[i][..., ch]) / 2
        mean = ref.mean()
        err = np.abs(img - ref).mean() / mean
        noise = (np.abs(a1[i][..., ch] - a2[i][..., ch]).mean()
                 + np.abs(c1[i][..., ch] - c2[i][..., ch]).mean()) / 2 / mean
        effect = np.abs(without[i][..., ch] - ref).mean() / mean
        print(f"{case} {integrator} {name}: mean {img.mean():.4f} vs Cycles {mean:.4f}; "
              f"|diff| {err:.4f}, noise {noise:.4f} ({err / noise:.2f}x); without the "
              f"catcher {effect:.4f}")
        # The pass without a catcher is 1: it moves by the shadow's share
        # of the image; its shadow is checked to be there instead.
        TS._check(err, noise, effect if name != "pass" else None)
        if name == "pass":
            assert ref.mean(axis=2).min() < 0.5 and img.mean(axis=2).min() < 0.5
