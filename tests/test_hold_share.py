"""The holds left out where they hold almost nothing (core.sppm.update,
HOLD_SHARE_PASS / HOLD_SHARE_MIN, Radii.leave_out_holds; docs/method.md
"Where FPPM's extras do not pay").

After pass 4 a photon-mapping render whose held pixels are fewer than 25 %
of those with a radius renders on as plain PPM.  The rings under a 1 m
light hold 10-12 % (their smooth floor is lit by the light's falloff, which
the verified holds' linear test rejects), every other example scene 47-99 %.
"""
import os

import numpy as np
import pytest

from core.render import Renderer
from core.sppm import update as U
from core.sppm.photon_pass import frequency_photons

HERE = os.path.dirname(os.path.abspath(__file__))
BLENDS = os.path.join(os.path.dirname(HERE), "example_blends")


def _scene(name, percent=25, photons=50_000, passes=16):
    bpy_helpers = pytest.importorskip("bpy_helpers")
    bpy = bpy_helpers.bpy()
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    bpy.ops.wm.open_mainfile(filepath=os.path.join(BLENDS, name + ".blend"), load_ui=False,
                             use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = percent
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    st = settings_from_scene(sc).replace(integrator="PHOTON", max_passes=passes,
                                         photons_per_pass=photons)
    return scene, st


def _render(scene, st, passes, share=None):
    r = Renderer(scene, st, log=lambda s: None)
    if share is not None:
        r.radii.hold_share_min = share
    imgs, held = [], []
    for _ in range(passes):
        imgs.append(np.asarray(r.step().image[..., :3], np.float64).copy())
        has = r.state.R2 > 0
        held.append(np.count_nonzero(r.state.held & has) / np.count_nonzero(has))
    return r, imgs, held


def test_ring_renders_on_as_ppm_after_pass_4():
    """ring_lambert at 32x32, 50k photons: the share held in pass 4 is
    below 25 %, so from pass 5 nothing is held, no frequency photon is traced
    (pass 8 would trace frequency_photons(8) of them), the plan says why, and
    passes 1-4 are the rule-off render's bits.  From pass 5 every radius
    shrinks at PPM's rate: each pixel's factor f = R'^2/R^2 is PPM's
    (N + alpha M)/(N + M) to rounding."""
    scene, st = _scene("ring_lambert")
    r, imgs, held = _render(scene, st, 8)
    off, imgs_off, held_off = _render(scene, st, 8, share=0.0)
    assert held[3] == held_off[3] < U.HOLD_SHARE_MIN
    assert r.radii.holds_left_out is not None and off.radii.holds_left_out is None
    assert any(s == "frequency holds" for s, _ in r.plan.left_out)
    assert any("Left out: frequency holds" in s for s in r.plan_lines())
    for k in range(4):
        assert np.array_equal(imgs[k], imgs_off[k]), k
    assert max(held[4:]) == 0.0 and min(held_off[4:]) > 0.0
    assert frequency_photons(st, 8, True) > 0
    assert r.photon_pass.chunks(8) == [(n, 0) for n, _ in off.photon_pass.chunks(8)]
    N0, R20 = r.state.N.copy(), r.state.R2.copy()
    r.step()
    M = r.state.M_last
    m = (M > 0) & (R20 > 0)
    f_ppm = (N0[m] + st.alpha * M[m]) / (N0[m] + M[m])
    assert np.allclose(r.state.R2[m] / R20[m], np.maximum(f_ppm, 0), rtol=1e-12)


def test_winning_scene_is_unchanged():
    """indirect_room at 32x32 holds 94-99 % of its pixels: the rule leaves it
    alone, its images are the rule-off render's bits through pass 6."""
    scene, st = _scene("indirect_room", photons=20_000, passes=6)
    r, imgs, held = _render(scene, st, 6)
    _, imgs_off, _ = _render(scene, st, 6, share=0.0)
    assert held[3] >= U.HOLD_SHARE_MIN and r.radii.holds_left_out is None
    for a, b in zip(imgs, imgs_off):
        assert np.array_equal(a, b)


def test_left_out_holds_survive_a_checkpoint():
    """A render resumed after the decision continues as plain PPM, bit for bit."""
    scene, st = _scene("ring_lambert", photons=20_000, passes=7)
    r, _, _ = _render(scene, st, 5)
    d = r.state_dict()
    assert "holds_left_out" in d
    again = Renderer(scene, st, log=lambda s: None)
    again.load_state(d)
    assert again.radii.holds_left_out == r.radii.holds_left_out
    assert not again.photon_pass.frequency
    for _ in range(2):
        a = np.asarray(r.step().image, np.float64)
        b = np.asarray(again.step().image, np.float64)
        assert np.array_equal(a, b)
