"""Radius rules (docs/method.md "Radius rules"): the gather's sector counts,
the chi-square uniformity test (CPPM, Lin et al. 2020), the MSE-optimal radius
(APPM, Kaplanyan & Dachsbacher 2013), and frequency holds verified by the
photons (verify_holds).

Scenes: a Lambert plane under a vertical sun whose left half is shadowed by a
black plate above the camera (closed form: rho E / pi for x > 0, 0 for x < 0:
uniform light and one sharp edge), the shadow-edge scene of
tests/test_holds.py with a deliberately wrong prediction, and the ring
caustic under a 1 m light (example_blends/ring_lambert.blend).
"""
import os

import numpy as np
import pytest

from core.render import Renderer
from core.scene.model import Light, make_scene
from core.settings import RenderSettings, SettingsError
from core.sppm import hashgrid as hg
from core.sppm.update import CHI2_ALPHA, appm_radius, chi2_rejects

from analytic_scenes import lambert, look_down_ortho, pixel_centres_ortho, quad, translate
from test_holds import _shadow_edge_scene

E_SUN = 3.0
RHO = 0.8


def _gather_cells(offsets_fn, seed, n_side=30, per_disc=80):
    """Sector counts of n_side^2 unit-spaced visible points (R = 0.5, normal
    +Z) under photons drawn by offsets_fn(rng, n) (offsets from the nearest
    point, in its disc), per_disc photons per disc on average."""
    rng = np.random.default_rng(seed)
    g = np.arange(n_side, dtype=float)
    X, Y = np.meshgrid(g, g)
    vp = np.c_[X.ravel(), Y.ravel(), np.zeros(X.size)]
    K = vp.shape[0]
    R = np.full(K, 0.5)
    n = rng.poisson(per_disc, K)
    owner = np.repeat(np.arange(K), n)
    ph = (vp[owner] + offsets_fn(rng, owner.size)).astype(np.float32)
    up = np.tile(np.float32([0, 0, 1]), (owner.size, 1))
    grid = hg.build_grid(vp, R, np.ones(K, bool))
    args = (grid, ph, up, up, np.ones((owner.size, 3)), np.full(owner.size, np.nan),
            vp, np.tile([0.0, 0, 1], (K, 1)), R * R, np.ones(K, bool))
    plain = hg.gather(*args)
    res = hg.gather(*args, sectors=True)
    # The sector output is additive: the other outputs are the same bits.
    assert np.array_equal(plain.M, res.M) and np.array_equal(plain.Phi_sum, res.Phi_sum)
    assert plain.sectors is None and np.array_equal(res.sectors.sum(axis=1), res.M)
    return res.sectors


def _disc(rng, n, half=False):
    r = 0.5 * np.sqrt(rng.random(n)) * (1 - 1e-9)
    a = rng.uniform(0, np.pi if half else 2 * np.pi, n)
    return np.c_[r * np.cos(a), r * np.sin(a), np.zeros(n)]


def _gradient(rng, n, k=1.6):
    """Offsets with density 1 + k x on the disc of radius 0.5."""
    out, got = [], 0
    while got < n:
        d = _disc(rng, 2 * n)
        d = d[rng.random(2 * n) < (1 + k * d[:, 0]) / (1 + k * 0.5)]
        out.append(d)
        got += len(d)
    return np.concatenate(out)[:n]


def test_chi2_sector_test_false_rejection_rate_and_power():
    """Uniform photons in 2700 discs (3 seeds, ~80 photons each) are rejected
    at the stated CHI2_ALPHA = 1%: measured 1.22% (uniformity, 7 dof) and
    1.26% (linear density, 5 dof); the binomial 1-sigma of the rate is
    0.19%, so the band below is 4 sigma.  A half-disc distribution (every
    photon on one side of a line through the centre) is rejected by the
    uniformity test in every disc (measured 100%).  A strong linear gradient
    (density 1 + 1.6 x, 200 photons per disc) is rejected by the uniformity
    test (91%) and accepted by the linear one at its false-rejection rate
    (1.2%): it does not bias the symmetric disc."""
    U = np.concatenate([_gather_cells(_disc, s) for s in range(3)])
    sigma = np.sqrt(CHI2_ALPHA * (1 - CHI2_ALPHA) / U.shape[0])
    for linear in (False, True):
        assert abs(chi2_rejects(U, linear).mean() - CHI2_ALPHA) < 4 * sigma
    half = chi2_rejects(_gather_cells(lambda rng, n: _disc(rng, n, half=True), 7))
    assert half.mean() > 0.99
    G = _gather_cells(_gradient, 11, per_disc=200)
    assert chi2_rejects(G).mean() > 0.85
    assert chi2_rejects(G, linear=True).mean() < CHI2_ALPHA + 4 * np.sqrt(
        CHI2_ALPHA * (1 - CHI2_ALPHA) / G.shape[0])
    # Too few photons (expected count < 5 per cell): the test cannot reject.
    assert not chi2_rejects(np.array([[20.0, 0, 0, 0, 0, 0, 0, 0]]))[0]


def test_appm_radius_formula():
    """r^6 = R^6 n / (8 D^2), D^2 = (n_out - n_in)^2 - n; inf without curvature."""
    S = np.array([[30.0, 30, 30, 30, 10, 10, 10, 10],     # peak: n_in 120, n_out 40
                  [20.0, 20, 20, 20, 20, 20, 20, 20]])    # uniform
    r = appm_radius(S, np.array([4.0, 4.0]))
    assert r[0] == pytest.approx(2.0 * (160 / (8 * (80.0 ** 2 - 160))) ** (1 / 6))
    assert np.isinf(r[1])


def _sun_edge_scene(res=24):
    """Plane z = 0 under a vertical sun of E_SUN W/m^2; a black plate at
    z = 4 (above the camera at z = 3) shadows x < 0."""
    tris = quad((0, 0, 0), (10, 0, 0), (0, 10, 0)) + quad((-5, 0, 4), (5, 0, 0), (0, 10, 0))
    sun = Light("sun", "SUN", (E_SUN,) * 3, np.eye(4))
    sc = make_scene(np.asarray(tris, np.float32), [lambert("floor", RHO), lambert("black", 0.0)],
                    [sun], look_down_ortho(3.0, 2.0, res))
    sc.tri_mat[2:] = 1
    return sc, lambda x, y: np.where(x > 0, RHO * E_SUN / np.pi, 0.0)


def _render(scene, Lfun, passes=(8, 64), **kw):
    X, Y = pixel_centres_ortho(scene)
    L = Lfun(X, Y)
    st = RenderSettings(integrator="PHOTON",
                        max_passes=max(passes), photons_per_pass=20_000, photons_for_direct=True,
                        initial_radius_px=4.0, cap_radius_at_edges=False, **kw)
    r = Renderer(scene, st, log=lambda s: None)
    out = {}
    for k in range(1, max(passes) + 1):
        img = r.step().image[..., :3].mean(axis=2)
        if k in passes:
            out[k] = (np.abs(img - L).mean() / L.mean(), np.sqrt(r.R2).reshape(L.shape).copy(),
                      img)
    return out, X, L


_PPM = {}


def _ppm_far_mean():
    """Plain PPM's mean over the lit region away from the edge (the rules must
    converge to the same value; it is 3.1% above rho E / pi at 64 passes, for
    every rule alike: a property of the sun photons, not of the radius)."""
    if not _PPM:
        out, X, _ = _render(*_sun_edge_scene(), use_frequency=False)
        _PPM["far"] = out[64][2][X > 0.6].mean()
    return _PPM["far"]


@pytest.mark.parametrize("rule", ["CPPM", "APPM"])
def test_per_pixel_rules_converge_and_shrink_at_the_edge(rule):
    """Sun-and-plate scene, 24x24, 20k photons/pass, 4 px initial radius,
    seed 0.  Measured relative L1 error 8 -> 64 passes: CPPM 0.193 -> 0.150,
    APPM 0.195 -> 0.140 (plain PPM 0.201 -> 0.136).  Lit region away from the
    edge (x > 0.6): mean within 0.7% (CPPM) / 0.6% (APPM) of PPM's, noise of
    each mean 0.45-0.6% (1 sigma), so 2% is > 2.5 sigma.  Radius ratio 64/8
    next to the edge on the lit side (0 < x < 0.3) against far from it:
    CPPM 0.83 / 0.90 (the hold rate: 0.89), APPM 0.83 / 0.86, PPM 0.72 /
    0.73 (the per-pixel rules keep the radius in the uniform light and shrink
    it faster at the edge)."""
    out, X, L = _render(*_sun_edge_scene(), radius_rule=rule, use_frequency=False)
    (e8, R8, _), (e64, R64, img) = out[8], out[64]
    assert e64 < e8 - 0.03
    far, edge = X > 0.6, (X > 0) & (X < 0.3)
    assert img[far].mean() == pytest.approx(_ppm_far_mean(), rel=0.02)
    ratio_edge = R64[edge].mean() / R8[edge].mean()
    ratio_far = R64[far].mean() / R8[far].mean()
    if rule == "CPPM":
        assert ratio_far > 0.87
        assert ratio_edge < ratio_far - 0.04
    else:
        assert ratio_edge < ratio_far - 0.015


def test_rules_need_frequency_off():
    with pytest.raises(SettingsError, match="radius_rule"):
        RenderSettings(integrator="PHOTON", radius_rule="CPPM").validate()
    RenderSettings(integrator="PHOTON", radius_rule="APPM", use_frequency=False).validate()


def _step_within_rates(r, hold):
    """One pass of ``r``; returns (image (H, W, 3), f, n, M, outside): f =
    R'^2/R^2 of the pixels that gathered with a radius, n their N before the
    pass, M their photons, and ``outside`` how many f lie outside
    [f_RELEASE_ALPHA, f_hold] (outside (0, GROW_MAX^2] in a pixel's first pass
    with photons, n = 0), f_a = (n + a M) / (n + M)."""
    from core.sppm.update import GROW_MAX, RELEASE_ALPHA
    N0, R20 = r.state.N.copy(), r.R2.copy()
    img = r.step().image[..., :3]
    M = r.state.M_last
    m = (M > 0) & (R20 > 0)
    f, n, Mm = r.R2[m] / R20[m], N0[m], M[m]
    lo = (n + RELEASE_ALPHA * Mm) / (n + Mm)
    hi = np.where(n > 0, (n + hold * Mm) / (n + Mm), GROW_MAX ** 2)
    outside = int(np.sum((f < lo * (1 - 1e-12)) | (f > hi * (1 + 1e-12))))
    return img, f, n, Mm, outside


def _edge_errors_and_radii(grow, hold_alpha_spectrum=None):
    """The forced 10 m prediction of tests/test_holds.py on the shadow edge,
    verified holds, 64 passes of 50k photons, seed 0, the default rules with
    radii.grow = grow (and radii.hold_alpha_spectrum, None: the default):
    (relative L1 error at passes 8 and 64, mean radius ratio 64/8 next to the
    edges on the lit side, far from them, the number of per-pass factors
    f = R'^2/R^2 outside [f_RELEASE_ALPHA, f_max(hold_alpha, spectrum rate)]
    (outside (0, GROW_MAX^2] in a pixel's first pass with photons), and the
    number above f_hold_alpha: holds that took the spectrum's slower rate)."""
    scene, Lfun = _shadow_edge_scene()
    X, Y = pixel_centres_ortho(scene)
    L = Lfun(X, Y)
    st = RenderSettings(integrator="PHOTON", max_passes=64, photons_per_pass=50_000, photons_for_direct=True,
                        initial_radius_px=4.0, cap_radius_at_edges=False, verify_holds=True,
                        # discs reach across the wall (with the clip the wall's leak is gone)
                        clip_kernel=False,
                        # frequency photons from pass 1: the growth of a pixel's first
                        # pass with photons, as these numbers were measured
                        frequency_start=1)
    r = Renderer(scene, st, log=lambda s: None)
    r.radii.predicted = lambda rmin, rh: np.where(np.isfinite(rmin), 10.0, rmin)
    r.radii.grow = grow
    if hold_alpha_spectrum is not None:
        r.radii.hold_alpha_spectrum = hold_alpha_spectrum
    hold = max(st.hold_alpha, r.radii.hold_alpha_spectrum)
    # The release itself is tested: holds kept past pass 4 although few hold
    # (core.sppm.update.HOLD_SHARE_MIN; with it, 0.135 at pass 64: the
    # released radii then shrink at alpha, not RELEASE_ALPHA).
    r.radii.hold_share_min = 0.0
    err, R, outside, slow = {}, {}, 0, 0
    for k in range(1, 65):
        img, f, n, Mm, out = _step_within_rates(r, hold)
        img = img.mean(axis=2)
        outside += out
        f_hold = (n + st.hold_alpha * Mm) / (n + Mm)
        slow += int(np.sum((n > 0) & (f > f_hold * (1 + 1e-12))))
        if k in (8, 64):
            err[k] = np.abs(img - L).mean() / L.mean()
            R[k] = np.sqrt(r.R2).reshape(L.shape).copy()
    edge = ((X > 0) & (X < 0.3)) | ((X < -0.5) & (X > -0.8))
    ratio_edge = R[64][edge].mean() / R[8][edge].mean()
    ratio_far = R[64][X > 0.6].mean() / R[8][X > 0.6].mean()
    return err[8], err[64], ratio_edge, ratio_far, outside, slow


def test_wrong_prediction_is_released_by_the_photons():
    """The forced 10 m prediction on the shadow edge, with verify_holds: the
    chi-square test releases the holds the photons contradict.  Default
    rules (docs/method.md "X as the default"): the first pass grows the
    radii whose counts can be tested and whose neighbours show no curvature
    (GROW_MAX, 2x), the wider discs see the edges and the point light's
    falloff and the linear test releases most holds at RELEASE_ALPHA.  The
    holds that stand with 5 photons per sector cell or more take the
    spectrum's slower rate (HOLD_ALPHA_SPECTRUM 0.95: the forced prediction
    is 10 m, so min(0.95, 1 - 0.1 (R / 10 m)^2) = 0.95), and still every
    pass's factor f = R'^2/R^2 lies in [f_RELEASE_ALPHA, f_0.95]: R -> 0
    (docs/method.md "Consistent holds").  Measured (seed 0, deterministic):
    relative L1 error 0.160 at pass 8 -> 0.108 at pass 64 (round 15's rule,
    hold_alpha_spectrum 0: 0.158 -> 0.106; plain PPM 0.146 -> 0.109: a wrong
    prediction costs, and the error still falls); radius ratio 64/8 next to
    the edges 0.72, far from them 0.69 (0.72 / 0.69); 9,884 of the 36,864
    pixel-passes shrank more slowly than f_hold_alpha, none outside the bounds.

    Given up under X: that the radii far from the edges (x > 0.6, a smooth
    falloff the linear test accepts at the initial radius) shrink more
    slowly than at the edges; the grown discs see the falloff's curvature
    there too.  It still holds without the growth (grow 1, the rest of the
    default): error 0.141 -> 0.099 (round 15's rule: 0.139 -> 0.098, on this
    scene the same bits as the rule before X), ratio 0.80 at the edges against
    0.86 far from them (0.80 / 0.86); 18,023 slower factors.  Noise of the
    error: +-0.002 (test_holds); margins >= 3.5 sigma."""
    from core.sppm.update import GROW_MAX, HOLD_ALPHA_SPECTRUM
    assert GROW_MAX == 2.0 and HOLD_ALPHA_SPECTRUM == 0.95
    e8, e64, ratio_edge, ratio_far, outside, slow = _edge_errors_and_radii(GROW_MAX)
    assert outside == 0 and slow > 1000     # the slower rate taken, within its bound
    assert e64 < e8 - 0.04
    assert e64 < 0.115
    assert ratio_edge < 0.75 and ratio_far < 0.75     # the grown radii come back
    e8, e64, ratio_edge, ratio_far, outside, slow = _edge_errors_and_radii(1.0)
    assert outside == 0 and slow > 1000
    assert e64 < e8 - 0.03
    assert e64 < 0.107
    assert ratio_edge < 0.86               # faster than the hold rates (0.90, 0.95)
    assert ratio_edge < ratio_far - 0.03


def test_a_hold_needs_counts_the_test_can_judge():
    """Below the chi-square test's minimum (CHI2_MIN_EXPECTED = 5 per cell)
    the low-count refusals of docs/method.md "Rings under a 1 m light" (set
    here: hold_min_expected 1 photon per sector cell on average,
    hold_max_top2 0.6 of the counts in the two fullest cells: a disc that
    photons reach on one side only) refuse a hold.  Smooth prediction
    (10 R): uniform counts hold from 1 per cell on; counts all in one
    quadrant's two cells do not while the test cannot judge.  Given up by
    default (X, docs/method.md "X as the default": HOLD_MIN_EXPECTED 0,
    HOLD_MAX_TOP2 2): every pixel holds, as CPPM retains a radius while its
    test cannot reject (the refusals kept the principled interior's dim
    pixels at PPM's rate; the kernel clip removed the ring's leak they were
    made for).  The compiled update and its numpy reference agree bit for
    bit."""
    from core.sppm import update as U
    from core.sppm.state import PixelState
    P = 400
    rng = np.random.default_rng(3)
    E = np.r_[rng.uniform(0.3, 0.95, 100), rng.uniform(1.05, 4.9, 200), rng.uniform(6.0, 40.0, 100)]
    assert U.HOLD_MIN_EXPECTED == 0.0 and U.HOLD_MAX_TOP2 > 1.0     # X: no refusal
    few = E < 1.0
    one_sided = np.zeros(P, bool)
    one_sided[200:300] = True
    shape = np.where(one_sided[:, None], np.r_[4.0, 0, 0, 0, 4.0, 0, 0, 0], 1.0)
    held = {}
    for rules in (True, False):
        for compiled in (True, False):
            st = PixelState.zeros(P, sector_cells=hg.SECTOR_CELLS)
            st.R2[:], st.N[:] = 1e-4, 8.0 * E
            st.sectors[:] = (E[:, None] - 0.25) * shape    # this pass adds 0.25 per cell
            radii = U.Radii(RenderSettings(integrator="PHOTON"), None, 10.0, True, None, 1, P)
            if rules:
                radii.hold_min_expected, radii.hold_max_top2 = 1.0, 0.6
            radii.compiled = compiled
            radii.update(st, np.full(P, 2.0), np.full((P, 3), 0.1), np.full(P, 0.1),
                         np.full((P, hg.SECTOR_CELLS), 0.25))
            held[rules, compiled] = (st.held.copy(), st.R2.copy())
        assert np.array_equal(held[rules, True][0], held[rules, False][0])
        assert np.array_equal(held[rules, True][1], held[rules, False][1])
    h = held[True, True][0]
    assert not h[few].any() and not h[one_sided].any() and h[~few & ~one_sided].all()
    assert held[False, True][0].all()


RING = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                    "example_blends", "ring_lambert.blend")


def _ring_32():
    """(scene, settings) of ring_lambert at 32x32, 16 passes of 50k photons."""
    bpy_helpers = pytest.importorskip("bpy_helpers")
    bpy = bpy_helpers.bpy()
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    bpy.ops.wm.open_mainfile(filepath=RING, load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = 25
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    base = settings_from_scene(sc).replace(integrator="PHOTON", max_passes=16, photons_per_pass=50_000)
    return scene, base


def test_caustic_line_holds_are_released():
    """The ring's caustic under a 1 m light (ring_lambert): on the 2%
    brightest pixels (the caustic lines) the spectrum alone holds many radii:
    its predicted radius there is 4.7x the PPM radius at 64x64 after 16
    passes (the prediction misses the lines; docs/method.md).  Verified by the
    photons most holds are released.  Measured at 32x32, 16 passes of 50k
    photons, seed 0, on the 20 brightest pixels: 35% held -> 15% (7 -> 3
    pixels; deterministic for the seed).  Since the interface operator
    (oblique incidence: the ring's curvature is sagittal, docs/frequency.md
    "Refraction and oblique incidence") the spectrum alone holds 10% there
    (2 pixels) and verification keeps those two.  Since the doubling
    schedule of the frequency photons (docs/method.md "Frequency photons in
    doubling passes") the same two pixels have the same predictions, but
    one of them sits on the knife edge of a hold (its kept prediction is
    its radius to 0.3 %: a prediction between the two rates sets R to it),
    held in the verified render and not in the other: 1 and 2 pixels.  So
    both renders are bounded (the rule before held 35 %), not compared
    pixel for pixel across two different radius histories."""
    scene, base = _ring_32()
    held = {}
    for verify in (False, True):
        r = Renderer(scene, base.replace(verify_holds=verify), log=lambda s: None)
        r.radii.hold_share_min = 0.0    # the holds themselves (tests/test_hold_share.py)
        for _ in range(16):
            img = r.step().image[..., :3].mean(axis=2).ravel()
        if not verify:
            caustic = np.argsort(img)[-max(1, img.size // 50):]
        held[verify] = r.state.held[caustic].mean()
    assert held[False] <= 0.15
    assert held[True] <= 0.15


def _ring_run(scene, st, radii=None, seed=0):
    """16 passes of ring_lambert at 32x32: (final radii, held, images at
    passes 4 / 8 / 16, the number of per-pass factors f = R'^2/R^2 outside
    [f_RELEASE_ALPHA, f_hold_alpha] (f_HOLD_ALPHA_SPECTRUM where that is
    larger; outside (0, GROW_MAX^2] in a pixel's first pass with photons))."""
    from core.sppm.update import HOLD_ALPHA_SPECTRUM
    # the slowest hold rate: hold_alpha, or the spectrum's bound (the default's,
    # or the run's own: 0 is off)
    hold = max(st.hold_alpha, (radii or {}).get("hold_alpha_spectrum", HOLD_ALPHA_SPECTRUM))
    r = Renderer(scene, st.replace(seed=seed), log=lambda s: None)
    # X's holds on the ring, kept past pass 4 although the ring holds ~10 %
    # of its pixels (by default it renders on as PPM: tests/test_hold_share.py)
    r.radii.hold_share_min = 0.0
    for k, v in (radii or {}).items():
        setattr(r.radii, k, v)
    imgs, outside = {}, 0
    for k in range(1, 17):
        img, _, _, _, out = _step_within_rates(r, hold)
        outside += out
        if k in (4, 8, 16):
            imgs[k] = np.asarray(img, np.float64)
    return np.sqrt(r.R2), r.state.held.copy(), imgs, outside


def test_ring_radii_stay_between_the_rates_and_the_error_falls():
    """ring_lambert (1 m light), 32x32, 16 passes of 50k photons, seed 0.
    The default rules (X, docs/method.md "X as the default", with the
    spectrum's hold rate HOLD_ALPHA_SPECTRUM = 0.95 gated at 5 photons per
    sector cell since round 16) retain a radius while its counts are too few
    for the test, as CPPM does; a retained radius the photons later
    contradict is released, but stays above PPM's.

    Given up under X: that released radii stay at PPM's (the low-count
    refusals of "Rings under a 1 m light" were made for the ring's leak
    through its wall, which the kernel clip now removes).  Measured
    (deterministic for the seed): pixels not held at the end with
    R > 1.1 R_PPM: 399 with the default, 398 with round 15's rule (no
    spectrum rate: "x15"), 421 with CPPM, 3 with the rule before X
    (spectrum holds only, no growth, the low-count refusals); geometric mean
    of R / R_PPM 1.10 (the default, x15 and CPPM), 1.004 with the rule before.

    What X keeps, asserted for the default and x15: (1) every pass's factor
    f = R'^2/R^2 of every pixel lies in [f_RELEASE_ALPHA, f_0.95] (x15:
    f_hold_alpha; a first pass may grow, at most GROW_MAX^2): the premise of
    "Consistent holds" / "Why it still converges" (0 factors outside, of each
    render); (2) the error against a PPM render of seed 100 (64 passes of
    200k photons, floor 1.5e-3) falls with the passes (relMSE 2.2e-2, 1.3e-2,
    8.4e-3 at passes 4, 8, 16) and stays PPM's within its noise: x15 / PPM at
    pass 16 is 1.020, 0.995, 1.021 for seeds 0, 1, 2 (CPPM 1.021, 0.996,
    1.022), so 1.06 is 3 sigma of that spread above the largest (seed 0: the
    default 8.4442e-3, 1.0205x PPM; x15 8.4439e-3; the spectrum rate ungated,
    HOLD_SPECTRUM_MIN_EXPECTED = 0: 8.4478e-3); (3) its large released radii
    are no more than CPPM's retention leaves (399 against 421); (4) with the
    rule before set the released radii stay at PPM's (at most 15 pixels, 3
    measured).
    The caustic lines themselves: tests/test_caustic_lines.py (predicted
    radius 0.03x PPM's)."""
    from fppm.tools.metrics import relmse
    scene, base = _ring_32()
    ref = Renderer(scene, base.replace(use_frequency=False, seed=100, photons_per_pass=200_000,
                                       max_passes=64), log=lambda s: None)
    for _ in range(64):
        img = ref.step().image[..., :3]
    ref = np.asarray(img, np.float64)
    runs = {"ppm": (base.replace(use_frequency=False), None), "fppm": (base, None),
            "cppm": (base.replace(use_frequency=False, radius_rule="CPPM"), None),
            "before": (base, dict(hold_uniform=False, grow=1.0, uniform_min_expected=5.0,
                                  hold_min_expected=1.0, hold_max_top2=0.6,
                                  hold_alpha_spectrum=0.0)),
            # round 15's default: no spectrum hold rate, hold_alpha for every hold
            # (docs/method.md "The gated spectrum rate as the default, round 16")
            "x15": (base, dict(hold_alpha_spectrum=0.0))}
    R, held, err = {}, {}, {}
    for k, (st, radii) in runs.items():
        R[k], held[k], imgs, outside = _ring_run(scene, st, radii)
        assert outside == 0, k
        err[k] = [relmse(imgs[p], ref) for p in (4, 8, 16)]
    for k in ("fppm", "x15"):
        e = err[k]
        assert e[1] < 0.75 * e[0] and e[2] < 0.75 * e[1], k
        assert e[2] < 1.06 * err["ppm"][2], k
    big = {k: int(np.sum(~held[k] & (R[k] > 1.1 * R["ppm"]))) for k in ("fppm", "cppm", "before")}
    assert big["fppm"] <= big["cppm"] and big["before"] <= 15


def test_sector_counts_are_checkpointed():
    """The sector counts are a PixelState field: saved, checked and loaded
    with the others (a resumed render continues the same test)."""
    from core.sppm.state import PixelState
    a = PixelState.zeros(6, sector_cells=hg.SECTOR_CELLS)
    a.sectors[:] = np.arange(6 * hg.SECTOR_CELLS).reshape(6, -1)
    d = a.state_dict()
    b = PixelState.zeros(6, sector_cells=hg.SECTOR_CELLS)
    assert b.check_state(d) is None
    b.load_state(d)
    assert np.array_equal(b.sectors, a.sectors)
    assert "sectors" in b.check_state({k: v for k, v in d.items() if k != "sectors"})
    d["sectors"][0, 0] = -1.0
    assert "negative" in b.check_state(d)
    assert PixelState.zeros(6).sectors is None      # no rule needs them: no field
