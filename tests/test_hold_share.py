"""The holds left out where they hold almost nothing (core.sppm.update,
HOLD_SHARE_PASS / HOLD_SHARE_MIN, Radii.leave_out_holds; docs/method.md
"Where FPPM's extras do not pay").

After pass 1 a photon-mapping render whose held pixels are fewer than 25 %
of those with a radius renders on as plain PPM, from PPM's state.  The rings under a 1 m
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


def _render(scene, st, passes, share=None, log=None):
    r = Renderer(scene, st, log=(lambda s: None) if log is None else log.append)
    if share is not None:
        r.radii.hold_share_min = share
    imgs, held = [], []
    for _ in range(passes):
        imgs.append(np.asarray(r.step().image[..., :3], np.float64).copy())
        has = r.state.R2 > 0
        held.append(np.count_nonzero(r.state.held & has) / np.count_nonzero(has))
    return r, imgs, held


def test_ring_renders_as_ppm():
    """ring_lambert at 32x32, 50k photons, the ring under its 1 m light
    alone (the file's dim world taken out: since the world's photons start
    where the triangles are, round 29, they reach the ring and lift the
    share to 27 %): the share held in pass
    HOLD_SHARE_PASS (1) is below 25 % (7.5 %), so the holds are left out; pass 1's
    factors are undone (R^2, N, tau scaled by alpha / f), which makes the
    state PPM's after its pass 1, and from then on the render is PPM's: the
    frequency photons are PPM's photons (docs/method.md "The frequency kernel
    on the indirect scenes"), so every image and radius equals a PPM render's
    of the same seed to rounding (relative 1e-9 asserted, over 6 passes).
    Nothing is held after the decision, no frequency photon is traced (pass 2
    would trace frequency_photons(2) of them), and the plan says why; the
    image of pass 1 is the rule-off render's to rounding (the estimate
    tau / R^2 does not change)."""
    assert U.HOLD_SHARE_PASS == 1
    scene, st = _scene("ring_lambert")
    scene.world_color = np.zeros(3)
    log = []
    r, imgs, held = _render(scene, st, 6, log=log)
    off, imgs_off, held_off = _render(scene, st, 1, share=0.0)
    ppm, imgs_ppm, _ = _render(scene, st.replace(use_frequency=False), 6)
    assert held_off[0] < U.HOLD_SHARE_MIN and held_off[0] > 0.0
    assert r.radii.holds_left_out is not None and off.radii.holds_left_out is None
    assert any(s == "frequency holds" for s, _ in r.plan.left_out)
    assert any("Left out: frequency holds" in s for s in r.plan_lines())
    # said when decided (Blender's info log: addon/engine.py _log), once
    assert [s for s in log if s.startswith("Left out: frequency holds")] == r.plan_lines()[-1:]
    assert np.allclose(imgs[0], imgs_off[0], rtol=1e-12, atol=0)
    assert max(held) == 0.0
    assert frequency_photons(st, 2, True) > 0
    assert r.photon_pass.chunks(2) == [(n, 0) for n, _ in off.photon_pass.chunks(2)]
    for a, b in zip(imgs, imgs_ppm):
        assert np.allclose(a, b, rtol=1e-9, atol=0)
    assert np.allclose(r.state.R2, ppm.state.R2, rtol=1e-9, atol=0)


def test_winning_scene_is_unchanged():
    """indirect_room at 32x32 holds most of its pixels in pass 1: the rule
    leaves it alone, its images are the rule-off render's bits through pass 6."""
    scene, st = _scene("indirect_room", photons=20_000, passes=6)
    r, imgs, held = _render(scene, st, 6)
    _, imgs_off, _ = _render(scene, st, 6, share=0.0)
    assert held[0] >= U.HOLD_SHARE_MIN and r.radii.holds_left_out is None
    for a, b in zip(imgs, imgs_off):
        assert np.array_equal(a, b)


def test_left_out_holds_survive_a_checkpoint():
    """A render resumed after the decision continues as plain PPM, bit for bit."""
    scene, st = _scene("ring_lambert", photons=20_000, passes=5)
    r, _, _ = _render(scene, st, 2)
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


def test_no_hold_through_glass():
    """glass_sphere at 32x32 (docs/method.md "The glass sphere at equal passes,
    round 17"): a pixel whose visible point is seen through the sphere never
    holds (HOLD_THROUGH_DELTA), while the rule before held most of them;
    the pixels seen directly hold as before.  COMBINED keeps its holds."""
    scene, st = _scene("glass_sphere", photons=20_000, passes=4)
    out, masks = {}, []
    for rule in (False, True):                  # the same seed: the same visible points
        r = Renderer(scene, st, log=lambda s: None)
        r.radii.hold_through_delta = rule
        held_through, held_direct = [], []
        for k in range(4):
            r.step()
            if not rule:
                masks.append(r.radii._through.copy())
                assert 20 < masks[k].sum() < 0.2 * masks[k].size
            through = masks[k]
            has = r.state.R2 > 0
            held_through.append(r.state.held[through & has].mean())
            held_direct.append(r.state.held[~through & has].mean())
        out[rule] = held_through, held_direct
    assert max(out[False][0]) == 0.0 and min(out[True][0]) > 0.3
    assert min(out[False][1]) > 0.5 and min(out[True][1]) > 0.5
    assert U.Radii(st.replace(integrator="COMBINED"), None, 10.0, True, None, 1, 1).hold_through_delta
