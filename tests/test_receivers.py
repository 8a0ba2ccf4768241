"""Frequency kernels at every receiver (docs/frequency.md "Receivers").

A visible point of any material may hold its radius: the deposit keeps its
spectrum, and the gather's pairs recombine it with the point's receiver
lobes (core.frequency.kernels.Receivers).  Checked here: the receiver
variances, the layered radius against the sum of two Gaussian profiles, a
default Principled floor holding where a Lambert floor does, and the
Principled floor's image against its closed form.
"""
import numpy as np
import pytest

from core import materials as B
from core.frequency import spectrum as F
from core.render import Renderer
from core.scene import nodes as shading
from core.scene.model import DIFFUSE, GLOSSY, Lobe, Material
from core.settings import RenderSettings

from analytic_scenes import pixel_centres_ortho, point_light_plane


def _variance(lobes):
    mt = B.build_material_table([Material("m", tuple(lobes))], [])
    used = (mt.kind >= 0) & (mt.weight != 0)
    return F.receiver_variance(mt.kind, mt.roughness, used & ~mt.lobe_delta)[0]


def test_receiver_variance_of_common_materials():
    assert _variance([Lobe(DIFFUSE, (0.8,) * 3)]) == np.inf                    # Lambert
    assert _variance([Lobe(DIFFUSE, (0.8,) * 3, roughness=0.5)]) == np.inf     # Oren-Nayar
    # GGX alpha = r^2: b = alpha^2 / (1 - alpha^2) (docs/frequency.md "Lobe widths").
    assert _variance([Lobe(GLOSSY, (0.8,) * 3, roughness=0.3)]) == pytest.approx(0.0081 / 0.9919)
    # Blender's default Principled: diffuse + specular layer of roughness 0.5.
    lobes, _, _ = shading.principled_to_lobes()
    assert _variance(lobes) == pytest.approx(0.0625 / 0.9375)
    # A perfect mirror is no receiver (delta): inf, and the plan keeps no
    # visible point on it anyway.
    assert _variance([Lobe(GLOSSY, (0.8,) * 3, roughness=0.0)]) == np.inf


def test_layered_radius_keeps_the_sum_of_two_profiles_at_95_percent():
    """(1 - w) exp(-x^2/2A_s) + w exp(-x^2/2A_g) at x = layered_radius never
    drops below 0.95 (exp is convex: the second-order expansion overstates
    the drop, so the radius is conservative) and is exact at w = 0, 1 and
    A_g = A_s.  Computed: at most 0.9656 (w = 0.01, A_g = A_s/100) and
    0.9855 at A_g = A_s/1000, a 1/sqrt(w)-bounded loss of radius."""
    beta = F.BETA
    A_s = 1.0
    for A_g in (1.0, 0.1, 0.01):
        for w in (0.0, 0.05, 0.3, 0.7, 1.0):
            r = F.layered_radius([np.sqrt(2 * beta * A_s)], [np.sqrt(2 * beta * A_g)], [w])[0]
            v = (1 - w) * np.exp(-r * r / (2 * A_s)) + w * np.exp(-r * r / (2 * A_g))
            assert 0.95 - 1e-12 <= v <= (0.9525 if A_g >= 0.1 else 0.99), (A_g, w, v)
            if w in (0.0, 1.0) or A_g == 1.0:
                assert v == pytest.approx(0.95, abs=1e-12)
    # Limits, NaN share (conservative: all glossy), zero radius (no hold).
    assert F.layered_radius([0.3], [0.1], [0.0])[0] == pytest.approx(0.3)
    assert F.layered_radius([0.3], [0.1], [1.0])[0] == pytest.approx(0.1)
    assert F.layered_radius([0.3], [0.1], [np.nan])[0] == pytest.approx(0.1)
    assert F.layered_radius([0.3], [0.0], [0.2])[0] == 0.0


def _plane(material, **kw):
    scene, _ = point_light_plane(res=24)
    if material is not None:
        scene.materials = [material]
    st = RenderSettings(**{"integrator": "PHOTON",
                           "max_passes": 16, "photons_per_pass": 50_000, "photons_for_direct": True,
                           "aov_held": True, "aov_predicted_radius": True, **kw})
    r = Renderer(scene, st, log=lambda s: None)
    return scene, r, r.run()


def _principled():
    lobes, _, _ = shading.principled_to_lobes()       # Blender's defaults
    return Material("principled", tuple(lobes))


def test_principled_floor_holds_where_a_lambert_floor_does():
    """Point light 1 m over an open plane.  Measured (seed 0): held fraction
    1.00 for both; median predicted radius 0.32 m (Lambert) and 0.28 m
    (Principled: the specular layer's share tightens it near the highlight).
    Holding is decided per pixel against a 0.17 m radius, far from both."""
    _, rl, res_l = _plane(None)
    _, rp, res_p = _plane(_principled())
    assert rp.plan.frequency_photons
    hl, hp = res_l.aovs["Held"][..., 0].mean(), res_p.aovs["Held"][..., 0].mean()
    assert hl > 0.95 and hp > 0.95
    ml = np.median(res_l.aovs["Predicted Radius"][..., 0])
    mp = np.median(res_p.aovs["Predicted Radius"][..., 0])
    assert 0.7 * ml < mp <= ml * 1.001


def test_principled_floor_image_agrees_with_its_closed_form():
    """L = f(wo, wi) I cos / d^2 with f from core.materials (Cycles' Principled,
    checked against Cycles to 1e-3 in test_bsdf.py).  Measured (seed 0, 16 x
    50k photons): image mean 0.997 of the closed form (plain PPM 0.998);
    the 0.6 m centre square with the highlight 0.986 (PPM 0.988: the
    pixel filter and kernel both flatten the peak).  Seeds 0-3: mean 0.993
    to 1.000, centre 0.978 to 0.989, so the 2 % (the Lambert test's bound)
    and 3 % bounds leave >= 2 sigma of that scatter beyond the bias."""
    scene, r, res = _plane(_principled())
    X, Y = pixel_centres_ortho(scene)
    mt = B.build_material_table(scene.materials, [])
    K = X.size
    p = np.stack([X.ravel(), Y.ravel(), np.zeros(K)], 1)
    wi = np.array([0, 0, 1.0]) - p
    d2 = (wi ** 2).sum(1)
    wi /= np.sqrt(d2)[:, None]
    n = np.tile([0, 0, 1.0], (K, 1))
    mat = np.zeros(K, np.int64)
    f = B.eval_bsdf(mt, mat, B.lobe_colors(mt, mat, np.zeros((K, 2))), n, n, n, wi)
    L = (f * (100 / (4 * np.pi) * wi[:, 2] / d2)[:, None]).reshape(X.shape + (3,))
    img = res.image[..., :3].astype(np.float64)
    assert res.aovs["Held"].mean() > 0.95
    assert abs(img.mean() / L.mean() - 1) < 0.02
    c = (np.abs(X) < 0.3) & (np.abs(Y) < 0.3)
    assert abs(img[c].mean() / L[c].mean() - 1) < 0.03


def test_rough_glossy_floor_agrees_with_cycles_with_frequency_on():
    """t_glossy_floor (GGX alpha 0.16 floor, area light) with frequency photons
    on, checked with test_cycles_agreement's bounds: mean within 2 % and
    relMSE < 1.5 (noise of the two-seed mean + the reference's) + 2e-3.
    Measured: mean 0.9959 of Cycles, relMSE 6.09e-3 against a noise of
    4.66e-3 (bound 9.0e-3), the same as plain PPM (0.9959, 6.09e-3): 2 % of
    the pixels hold (the glossy receiver's r_theta is small), so the
    frequency kernel changes little here and breaks nothing."""
    pytest.importorskip("bpy")
    from test_cycles_agreement import BIAS_ALLOWANCE, export
    from scenes.refs import RELMSE_EPS, load_reference
    ref_img, meta = load_reference("t_glossy_floor")
    ref = ref_img[..., :3].astype(np.float64)
    scene = export("t_glossy_floor")
    imgs = [Renderer(scene, RenderSettings(integrator="PHOTON",
                                           max_passes=64, photons_per_pass=40_000, seed=seed),
                     log=lambda s: None).run().image[..., :3].astype(np.float64) for seed in (1, 2)]
    a1, a2 = imgs
    m = 0.5 * (a1 + a2)
    den = ref ** 2 + RELMSE_EPS
    noise = np.mean((a1 - a2) ** 2 / 4.0 / den) + float(meta["noise"]["relmse"])
    assert abs(m.mean() / ref.mean() - 1) < 0.02
    assert np.mean((m - ref) ** 2 / den) < 1.5 * noise + BIAS_ALLOWANCE


def test_oren_nayar_floor_predicts_exactly_the_lambert_radius():
    """An Oren-Nayar receiver is diffuse (b_r = inf, glossy share 0): on the
    open plane every photon deposit is a first hit, identical for both
    floors, so the predicted radii agree bit for bit although the Oren-Nayar
    points go through the pair path and the Lambert ones through the gather."""
    _, _, res_l = _plane(None, max_passes=4)
    _, r_on, res_on = _plane(Material("oren-nayar", (Lobe(DIFFUSE, (0.8,) * 3, roughness=0.5),)),
                             max_passes=4)
    assert not r_on.mtab.lambert_only[0]
    rl = res_l.aovs["Predicted Radius"]
    assert np.isfinite(rl).all() and np.median(rl) > 0.2
    assert np.array_equal(rl, res_on.aovs["Predicted Radius"])


def test_receiver_radii_only_in_chunks_with_frequency_photons():
    """The receivers' radii are looked for only in chunks with frequency
    photons (PhotonPass._add_pairs, docs/method.md "FPPM's pass against
    CPPM's, round 16"): a Principled plane (every visible point non-Lambert),
    16x16, 6 passes of 20,000 photons (one chunk each), no Predicted Radius
    AOV (the receivers' own branch).  Frequency photons are traced in passes
    1, 2 and 4 only, so the receivers see 3 chunks, all with pairs, where
    the rule before called them in all 6 (3 with no pair to look at); the
    radii, counts, flux, holds, kept predictions and image are the same bits."""
    def render(skip):
        scene, _ = point_light_plane(res=16)
        scene.materials = [_principled()]
        st = RenderSettings(integrator="PHOTON", max_passes=6, photons_per_pass=20_000,
                            photons_for_direct=True, frequency_start=1)   # passes 1, 2, 4
        r = Renderer(scene, st, log=lambda s: None)
        pp = r.photon_pass
        calls = []
        keys = pp.receivers.radius_keys

        def counted(vp, dep, pv, pp_, model="CORRECTED"):
            calls.append((r.pass_index + 1, pv.size))
            return keys(vp, dep, pv, pp_, model)
        pp.receivers.radius_keys = counted
        if not skip:                             # the rule before: every chunk
            add = pp._add_pairs
            pp._add_pairs = lambda vp, dep, g, acc, clip=None, n_freq=None: add(vp, dep, g, acc, clip)
        res = r.run()
        return r, res, calls

    r_new, res_new, calls_new = render(True)
    r_old, res_old, calls_old = render(False)
    assert [k for k, _ in calls_new] == [1, 2, 4]
    assert all(n > 0 for _, n in calls_new)
    assert [k for k, _ in calls_old] == [1, 2, 3, 4, 5, 6]
    assert [n for k, n in calls_old if k in (3, 5, 6)] == [0, 0, 0]
    for name in ("R2", "N", "tau", "held", "r_pred_last", "M_last"):
        np.testing.assert_array_equal(getattr(r_new.state, name), getattr(r_old.state, name))
    np.testing.assert_array_equal(res_new.image, res_old.image)
    # the receivers' predictions are what hold these pixels
    assert np.isfinite(r_new.state.r_pred_last).mean() > 0.9
    assert r_new.state.held.mean() > 0.5
