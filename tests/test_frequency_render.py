"""Frequency photons as rendered: where radii are held, where they shrink.

The operators themselves are pinned against sampled light fields in
test_frequency_ops.py; here the whole pipeline (emission inits, transport,
occlusion grid, deposit radius, per-pixel min, held-radius update) is checked
on scenes whose answer is known qualitatively and, for the open plane,
quantitatively.
"""
import numpy as np
import pytest

from core.render import Renderer
from core.settings import RenderSettings

from analytic_scenes import pixel_centres_ortho, point_light_plane


def _render(scene, **kw):
    st = RenderSettings(**{"integrator": "PHOTON",
                           "max_passes": 16, "photons_per_pass": 50_000, "photons_for_direct": True,
                           "aov_held": True, "aov_predicted_radius": True, "aov_radius": True,
                           "aov_spectrum": True, **kw})
    r = Renderer(scene, st, log=lambda s: None)
    return r, r.run()


@pytest.mark.parametrize("estimator", ["MIN", "QUANTILE"])
def test_open_plane_radii_are_held(estimator, monkeypatch):
    """A point light over an open Lambert plane: the light field is smooth at
    the scale of a few pixels, so (nearly) every pixel's radius is held (the
    paper's claim), and the image stays within 2% of the closed form.  Held
    radii still shrink, at the hold rate (docs/method.md "Consistent holds").
    By default (rule set X, docs/method.md "X as the default") a pixel's
    first verified hold also grows its radius towards the prediction, at
    most GROW_MAX (2) times: measured mean radius 2.93 px (MIN) / 2.41 px
    (QUANTILE, whose bin edges predict lower), held 96.5 % / 93.4 % (some
    grown discs see the falloff's curvature and are released: given up,
    'every pixel held' of the rule before); image mean -0.7 % / -0.5 %.
    Without the growth, the hold rates alone: 1.82 px (MIN) / 1.80 px
    (QUANTILE) with the spectrum's rate 0.95 on the holds the counts can test
    (HOLD_ALPHA_SPECTRUM, the default since round 16; 1.67 px with hold_alpha
    0.9 alone, the rule before), held 99.3 % / 98.4 %."""
    from core.sppm import update as U
    scene, Lfun = point_light_plane(res=24)
    X, Y = pixel_centres_ortho(scene)
    # Held: the radius shrinks like PPM with the hold rate, from 2 px to
    # 2 prod_k sqrt((N + a M)/(N + M)) after 16 passes of equal M: 1.832 px
    # with the spectrum's a = 0.95 (where the counts reach 5 per sector cell
    # and r_pred > R), 1.665 px with hold_alpha = 0.9 (measured 1.68 under the
    # rule before: M varies per pass), not like plain PPM's 1.03 px; a
    # first-pass growth multiplies that by at most GROW_MAX.
    r, res = _render(scene, frequency_estimator=estimator)
    assert res.aovs["Held"][..., 0].mean() > 0.9
    assert 2.2 < res.aovs["FPPM Radius px"].mean() < U.GROW_MAX * 1.87
    img = res.image[..., :3].mean(axis=2)
    assert abs(img.mean() / Lfun(X, Y).mean() - 1) < 0.02
    monkeypatch.setattr(U, "GROW_MAX", 1.0)
    r, res = _render(scene, frequency_estimator=estimator)
    held = res.aovs["Held"][..., 0]
    assert held.mean() > 0.95
    assert 1.75 < res.aovs["FPPM Radius px"].mean() < 1.87    # most holds at 0.95
    # Predicted radius for a point light at h = 1 m: travel gives a = 0.467 d^2,
    # r_x = 0.3203 sqrt(a) = 0.22 d; 0.22-0.35 m over the view (d = 1..1.4 m,
    # divided by cos at the plane).  The quantile estimator reports a bin's
    # lower edge (bins are 1.8x wide in log space), hence the looser floor.
    rp = res.aovs["Predicted Radius"][..., 0]
    lo = 0.21 if estimator == "MIN" else 0.21 / 1.8
    assert np.median(rp) > lo and np.median(rp) < 0.6
    # The held radius is admissible: bias at most the 2.5% peak bias of a
    # 95%-of-peak radius (frequency.md), so the image mean stays within 2%.
    img = res.image[..., :3].mean(axis=2)
    assert abs(img.mean() / Lfun(X, Y).mean() - 1) < 0.02
    # Spectrum AOV: (a, b, c) of the limiting photon, positive semi-definite.
    s = res.aovs["Spectrum"].reshape(-1, 3).astype(np.float64)
    s = s[np.any(s != 0, axis=1)]
    assert s.shape[0] > 0.9 * img.size
    assert np.all(s[:, 0] >= 0) and np.all(s[:, 1] >= 0)
    assert np.all(s[:, 2] ** 2 <= s[:, 0] * s[:, 1] * (1 + 1e-6) + 1e-12)


def test_plain_ppm_never_holds():
    scene, _ = point_light_plane(res=16)
    r, res = _render(scene, use_frequency=False, max_passes=8)
    assert res.aovs["Held"].max() == 0
    # alpha = 0.7: R^2 shrinks by (N + 0.7 M)/(N + M) every pass with photons.
    assert res.aovs["FPPM Radius px"].mean() < 1.5


def test_coffee_cup_predicted_radius_smallest_at_the_caustic():
    """The seed paper's Figure 1: the ring's caustic is where radiance varies
    fastest, so frequency photons predict their smallest radii there."""
    bpy = pytest.importorskip("bpy")
    import os
    from fppm.addon.export import export_scene
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        "example_blends", "coffee_cup.blend")
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False, use_scripts=False)
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    scene.camera = type(scene.camera)(**{**scene.camera.__dict__, "resolution": (64, 64)})
    st = RenderSettings(integrator="PHOTON",
                        max_passes=8, photons_per_pass=100_000, aov_predicted_radius=True)
    r = Renderer(scene, st, log=lambda s: None)
    res = r.run()
    L_ind = r.tau.mean(axis=1) / (np.pi * np.where(r.R2 > 0, r.R2, np.inf) * r.photons_emitted)
    rp = res.aovs["Predicted Radius"][..., 0].ravel()
    has = rp > 0
    # The focus: the brightest 2% of the indirect (photon) radiance, i.e. the
    # cardioid's cusp.  (A wider cut also takes in the smooth, diverging
    # reflection off the ring's convex outside, correctly predicted large.)
    focus = has & (L_ind >= np.percentile(L_ind[has], 98))
    rest = has & ~focus
    assert focus.sum() >= 20 and rest.sum() > 500
    # Measured (seed 0, 64x64, 8 x 100k, occlusion applied at the blocker):
    # focus median 0.109 m, rest 0.498 m (4.6x).  Asserted: 3x.
    assert np.median(rp[focus]) * 3 < np.median(rp[rest])
