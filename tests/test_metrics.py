"""tools.metrics against hand-computed values on small arrays."""
import math

import numpy as np
import pytest

from tools import metrics as M


def img(*rgb_rows):
    """(H, W, 3) float64 from nested lists of RGB triples."""
    return np.array(rgb_rows, dtype=np.float64)


# x = (1, 2, 3), r = (1, 1, 1): differences (0, 1, 2).
X1 = img([[1.0, 2.0, 3.0]])
R1 = img([[1.0, 1.0, 1.0]])


def test_relmse_by_hand():
    # (0 + 1 + 4) / (1 + 0.01) / 3
    assert M.relmse(X1, R1) == pytest.approx(5 / 1.01 / 3, rel=1e-12)


def test_rmse_by_hand():
    assert M.rmse(X1, R1) == pytest.approx(math.sqrt(5 / 3), rel=1e-12)


def test_mean_relative_error_by_hand():
    # (0 + 1 + 2) / (1 + 0.1) / 3
    assert M.mean_relative_error(X1, R1) == pytest.approx(3 / 1.1 / 3, rel=1e-12)


def test_alpha_channel_ignored_and_eps_on_black():
    x = img([[0.1, 0.0, 0.0, 7.0]])
    r = img([[0.0, 0.0, 0.0, 1.0]])
    # black reference: (0.1^2 / 0.01 + 0 + 0) / 3 = 1/3
    assert M.relmse(x, r) == pytest.approx(1 / 3, rel=1e-12)
    assert M.mean_relative_error(x, r) == pytest.approx(0.1 / 0.1 / 3, rel=1e-12)


def test_masks_select_pixels_and_empty_mask_is_nan():
    x = img([[1.0, 2.0, 3.0], [5.0, 5.0, 5.0]])
    r = img([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    m = np.array([[True, False]])
    assert M.relmse(x, r, m) == pytest.approx(5 / 1.01 / 3, rel=1e-12)
    assert M.rmse(x, r, ~m) == pytest.approx(4.0, rel=1e-12)
    assert math.isnan(M.relmse(x, r, np.zeros((1, 2), bool)))
    e = M.error_metrics(x, r, {"caustic": m})
    assert set(e) == {f"{k}_{g}" for k in ("relmse", "rmse", "mre", "flip")
                      for g in ("all", "caustic")}
    assert e["relmse_all"] == pytest.approx((5 / 1.01 + 3 * 16 / 1.01) / 6, rel=1e-12)


def test_size_mismatch_raises():
    with pytest.raises(ValueError):
        M.relmse(np.zeros((2, 2, 3)), np.zeros((2, 3, 3)))


def test_reference_floor_by_hand():
    r = np.ones((2, 2, 3))
    v = np.full((2, 2, 3), 0.0202)
    assert M.reference_floor(r, v) == pytest.approx(0.02, rel=1e-12)


def test_bias_noise_by_hand():
    # Two renders 1 and 3 of a pixel whose reference is 1: mean 2, s^2 = 2
    # (ddof 1), w = 1/1.01.  noise = 2/1.01; raw (m - r)^2 w = 1/1.01;
    # bias2 = raw - noise/K = 0; per-seed relMSE = (0 + 4)/2/1.01 = 2/1.01.
    x = [np.full((1, 1, 3), 1.0), np.full((1, 1, 3), 3.0)]
    r = np.ones((1, 1, 3))
    d = M.bias_noise(x, r)
    assert d["noise"] == pytest.approx(2 / 1.01, rel=1e-12)
    assert d["bias2"] == pytest.approx(0.0, abs=1e-12)
    assert d["relmse_mean_image"] == pytest.approx(1 / 1.01, rel=1e-12)
    assert d["relmse_per_seed"] == pytest.approx(2 / 1.01, rel=1e-12)


def test_bias_noise_identity_and_recovery():
    # Exact identity: mean_k relMSE_k = raw + (K-1)/K noise = bias2 + noise.
    rng = np.random.default_rng(1)
    K, H, W = 8, 100, 100
    r = np.ones((H, W, 3))
    b, sd = 0.1, 0.2
    xs = r + b + sd * rng.normal(size=(K, H, W, 3))
    d = M.bias_noise(xs, r)
    assert d["relmse_per_seed"] == pytest.approx(d["bias2"] + d["noise"], rel=1e-12)
    # Recovery: noise -> sd^2/1.01 (relative std sqrt(2/((K-1) N)) = 0.3%,
    # N = 3e4); bias2 -> b^2/1.01, whose estimate has std
    # sqrt(4 b^2 s^2 + 2 s^4)/sqrt(N) with s^2 = sd^2/K: 9e-5, 1% of b^2.
    # Tolerances: 5 standard deviations.
    assert d["noise"] == pytest.approx(sd ** 2 / 1.01, rel=0.015)
    assert d["bias2"] == pytest.approx(b ** 2 / 1.01, rel=0.05)


def test_loglog_interp():
    t, e = [1.0, 10.0], [1.0, 0.01]
    # Straight line in log-log: slope -2, so e(sqrt 10) = 0.1.
    assert M.loglog_interp(math.sqrt(10), t, e) == pytest.approx(0.1, rel=1e-12)
    assert math.isnan(M.loglog_interp(0.5, t, e))
    assert M.loglog_interp(20.0, t, e) == 0.01


def test_gaussian_blur_keeps_constants_and_mass():
    a = np.full((9, 11), 3.0)
    assert np.allclose(M.gaussian_blur(a, 2.0), 3.0)
    d = np.zeros((41, 41))
    d[20, 20] = 1.0
    b = M.gaussian_blur(d, 2.0)
    assert b.sum() == pytest.approx(1.0, rel=1e-9)
    # Peak of a normalised 2-D Gaussian, sigma 2: 1 / (2 pi sigma^2) (sampled: +-2%).
    assert b[20, 20] == pytest.approx(1 / (2 * math.pi * 4), rel=0.02)


def test_region_masks_on_a_synthetic_caustic():
    ref = np.ones((32, 32, 3))
    ref[10:13, 10:13] = 20.0          # a 3x3 caustic on a flat background
    m = M.region_masks(ref)
    assert m["caustic"][10:13, 10:13].all() and m["caustic"].sum() == 9
    # Flat background (> 1 px from the spot) is smooth, the spot is not.
    far = np.ones((32, 32), bool)
    far[8:15, 8:15] = False
    assert m["smooth"][far].all() and not m["smooth"][10:13, 10:13].any()
    # A linear ramp of 1% per pixel is smooth everywhere, nothing caustic.
    ramp = np.repeat((1 + 0.01 * np.arange(32))[None, :, None], 32, 0).repeat(3, 2)
    mr = M.region_masks(ramp)
    assert mr["smooth"].all() and not mr["caustic"].any()


def test_indirect_from_cycles_passes():
    ref = np.ones((8, 8, 3))
    dd = np.ones((8, 8, 3))
    di = np.ones((8, 8, 3))
    dd[:, :4] = 0.1                   # left half: 0.1 direct, 1 indirect -> 91% indirect
    m = M.region_masks(ref, dd, di)
    assert m["indirect"][:, :4].all() and not m["indirect"][:, 4:].any()


def test_masks_from_image_channels():
    a = np.zeros((2, 2, 4))
    a[0, 0, 0] = 1.0
    a[0, 1, 1] = 0.9
    a[1, 1, 2] = 0.6
    m = M.masks_from_image(a)
    assert m["caustic"].sum() == 1 and m["caustic"][0, 0]
    assert m["smooth"].sum() == 1 and m["smooth"][0, 1]
    assert m["indirect"].sum() == 1 and m["indirect"][1, 1]


def test_flip_is_flip_evaluators_hdr_mean_and_masks_average_its_map():
    """M.flip = flip-evaluator's own HDR mean on a tiny pair; regions average the one map."""
    F = pytest.importorskip("flip_evaluator")
    rng = np.random.default_rng(1)
    r = rng.uniform(0.0, 2.0, (16, 12, 3))
    x = r * rng.uniform(0.7, 1.3, r.shape)
    _, mean, _ = F.evaluate(r.astype(np.float32), x.astype(np.float32), "HDR")
    # flip-evaluator averages in float32, tools.metrics in float64: 1e-6 apart.
    assert M.flip(x, r) == pytest.approx(mean, rel=1e-5)
    assert M.flip(r, r) == 0.0
    m = np.zeros((16, 12), bool)
    m[:5] = True
    fm = M.flip_map(x, r)
    e = M.error_metrics(x, r, {"smooth": m})
    assert e["flip_smooth"] == pytest.approx(fm[:5].mean(), rel=1e-12)
    assert e["flip_all"] == pytest.approx(mean, rel=1e-5)
    assert math.isnan(M.flip(x, r, np.zeros((16, 12), bool)))
    # Negative and NaN pixels (which FLIP's HDR mode rejects) count as black.
    y = x.copy()
    y[0, 0] = (-1.0, np.nan, 0.5)
    z = x.copy()
    z[0, 0] = (0.0, 0.0, 0.5)
    assert M.flip(y, r) == M.flip(z, r)

