"""Frequency operators pinned against SAMPLED light fields.

Every test builds a 2D (x, theta) light field l, applies the operation in the
PRIMAL domain (shear, visibility product, coordinate rescale, angular
convolution, bend, point reflection), samples it on a grid, FFTs it and fits
Q = [[a, c], [c, b]] from the power spectrum's second moments:
|L|^2 ~ exp(-W^T Q W) is a Gaussian in W of covariance (2Q)^-1, so
Q = inv(M_spec) / 2.  Independently Q is the covariance of l itself and twice
the covariance of |l|^2; the three fits must agree.  The operator's output is
then compared with the fit, never with the notes' formulas.

Tolerance.  The grid spans +-9 sigma of l with >= 3 cells per conditional
(narrowest) sigma, so by Poisson summation the Riemann sums of the primal and
spectral Gaussian moments are exact to ~exp(-2 pi^2 3^2) and the truncation
error is ~exp(-81/2); the theta convolution uses a 161-node trapezoid rule
over +-7 sd.  ``test_harness_self_check`` measures the harness on the
untransformed Gaussian: max relative error ~1e-9.  We assert 1e-6 of ||Q||
everywhere: 1000x the measured harness error, while the PAPER-vs-CORRECTED
differences asserted below are >= 1e-2 of ||Q||.
"""
import math

import numpy as np
import pytest

from core.frequency import spectrum as F

TOL = 1e-6   # relative to ||Q||; see module docstring


# ------------------------------------------------------------------ harness
def gaussian_field(Q, centre=(0.0, 0.0)):
    """l(x, t) = exp(-0.5 v^T Q^-1 v): a light field of covariance Q."""
    Qi = np.linalg.inv(np.asarray(Q, float))
    cx, ct = centre

    def f(x, t):
        dx, dt = x - cx, t - ct
        return np.exp(-0.5 * (Qi[0, 0] * dx * dx + 2 * Qi[0, 1] * dx * dt + Qi[1, 1] * dt * dt))
    return f


def shear(f, d):           # travel: l(x - d t, t)
    return lambda x, t: f(x - d * t, t)


def scale_x(f, s):         # l(s x, t): onto surface s = cos_i, off surface s = 1/cos_o
    return lambda x, t: f(s * x, t)


def visibility(f, a_o):    # occlusion: times exp(-x^2 / 2 a_o)
    return lambda x, t: f(x, t) * np.exp(-0.5 * x * x / a_o)


def bend(f, k):            # theta' = theta + k x  <=>  l'(x, t) = l(x, t - k x)
    return lambda x, t: f(x, t - k * x)


def flip(f):               # (x, t) -> (-x, -t)
    return lambda x, t: f(-x, -t)


def conv_theta(f, var, n=161):
    """Angular convolution with a normalised Gaussian lobe of variance var
    (trapezoid rule over +-7 sd; the integrand is smooth so it converges
    geometrically)."""
    u = np.linspace(-7, 7, n) * math.sqrt(var)
    w = np.exp(-0.5 * u * u / var)
    w /= w.sum()

    def g(x, t):
        acc = np.zeros(np.broadcast(x, t).shape)
        for uj, wj in zip(u, w):
            acc += wj * f(x, t - uj)
        return acc
    return g


def _grid_for(C, K=9.0, per_sigma=3.0, nmax=1024):
    C = np.asarray(C, float)
    det = max(C[0, 0] * C[1, 1] - C[0, 1] ** 2, 1e-300)
    axes = []
    for i in (0, 1):
        sd = math.sqrt(C[i, i])
        cond = math.sqrt(det / C[1 - i, 1 - i])          # narrowest cross-section
        n = int(min(nmax, max(128, math.ceil(2 * K * sd / (cond / per_sigma)))))
        n += n % 2
        axes.append((sd, n))
    return axes


def _sample(f, C, mean):
    (sx, nx), (st, nt) = _grid_for(C)
    x = mean[0] + np.linspace(-9 * sx, 9 * sx, nx, endpoint=False)
    t = mean[1] + np.linspace(-9 * st, 9 * st, nt, endpoint=False)
    X, T = np.meshgrid(x, t, indexing="ij")
    return x, t, X, T, f(X, T)


def _moments(w, X, T):
    w = w / w.sum()
    mx, mt = (w * X).sum(), (w * T).sum()
    dx, dt = X - mx, T - mt
    C = np.array([[(w * dx * dx).sum(), (w * dx * dt).sum()],
                  [(w * dx * dt).sum(), (w * dt * dt).sum()]])
    return C, (mx, mt)


def fit(f, guess, mean=(0.0, 0.0), iters=3):
    """Return (Q_spectral, Q_primal, Q_sq) of the field f.

    The grid is derived from the field itself: start from ``guess`` (a rough
    covariance) and re-grid on the measured primal covariance ``iters`` times.
    """
    C = np.asarray(guess, float)
    for _ in range(iters):
        x, t, X, T, l = _sample(f, C, mean)
        C, mean = _moments(l, X, T)
    x, t, X, T, l = _sample(f, C, mean)
    Q_primal, _ = _moments(l, X, T)
    Q_sq = 2.0 * _moments(l * l, X, T)[0]
    P = np.abs(np.fft.fft2(l)) ** 2
    wx = 2 * np.pi * np.fft.fftfreq(len(x), x[1] - x[0])
    wt = 2 * np.pi * np.fft.fftfreq(len(t), t[1] - t[0])
    WX, WT = np.meshgrid(wx, wt, indexing="ij")
    M = _moments(P, WX, WT)[0]
    Q_spec = np.linalg.inv(M) / 2.0
    return Q_spec, Q_primal, Q_sq


def Qmat(s):
    a, b, c = np.asarray(s, float).reshape(3)
    return np.array([[a, c], [c, b]])


def spec(Q):
    return np.array([[Q[0, 0], Q[1, 1], Q[0, 1]]])


def rel(Qa, Qb):
    return np.abs(Qa - Qb).max() / np.abs(Qb).max()


def sampled(f, guess):
    """The field's Q, after checking the three independent fits agree."""
    Qs, Qp, Qq = fit(f, guess)
    assert rel(Qp, Qs) < TOL and rel(Qq, Qs) < TOL, (Qs, Qp, Qq)
    return Qs


def random_Q(rng, rho_max=0.9):
    a = 10 ** rng.uniform(-2.5, -0.5)
    b = 10 ** rng.uniform(-2.5, -0.7)
    rho = rng.uniform(-rho_max, rho_max)
    return np.array([[a, rho * math.sqrt(a * b)], [rho * math.sqrt(a * b), b]])


# ------------------------------------------------------------------ tests
def test_harness_self_check():
    """The harness recovers a known Q (this measures the TOL budget), and the
    amplitude spectrum |L| gives Q/2 (frequency.md "Convention")."""
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(4):
        Q = random_Q(rng, rho_max=0.95)
        f = gaussian_field(Q, centre=(0.3, -0.1))
        Qs, Qp, Qq = fit(f, np.diag(np.diag(Q)) * 4, mean=(0.0, 0.0))
        worst = max(worst, rel(Qs, Q), rel(Qp, Q), rel(Qq, Q))
    assert worst < 1e-8
    # amplitude convention: |L| ~ exp(-W^T Q' W) with Q' = Q / 2
    Q = random_Q(rng)
    x, t, X, T, l = _sample(gaussian_field(Q), Q, (0.0, 0.0))
    A = np.abs(np.fft.fft2(l))
    WX, WT = np.meshgrid(2 * np.pi * np.fft.fftfreq(len(x), x[1] - x[0]),
                         2 * np.pi * np.fft.fftfreq(len(t), t[1] - t[0]), indexing="ij")
    Q_amp = np.linalg.inv(_moments(A, WX, WT)[0]) / 2.0
    assert rel(Q_amp, Q / 2) < 1e-8


@pytest.mark.parametrize("d", [1.5, -0.7])
def test_travel_matches_sampled_shear(d):
    """Travel in both directions: the shear l(x - d theta, theta)."""
    rng = np.random.default_rng(2)
    for _ in range(3):
        Q = random_Q(rng)
        Qs = sampled(shear(gaussian_field(Q), d), Q + np.diag([d * d * Q[1, 1], 0]))
        cor = Qmat(F.travel(spec(Q), d))
        pap = Qmat(F.travel(spec(Q), d, model="PAPER"))
        assert rel(cor, Qs) < TOL
        # the paper's opposite theta sign: off by 4 c d in a and 2 b d in c
        assert abs(pap[0, 0] - Qs[0, 0]) == pytest.approx(abs(4 * Q[0, 1] * d), rel=1e-4)
        assert rel(pap, Qs) > 1e-2


def test_focusing_beam_reaches_zero_at_focus():
    """A beam aimed at a focus 2 m ahead: theta = -x/2, so a(2) = 0 for the
    rank-1 beam; the paper's signs give 0.16 (frequency.md)."""
    beam = np.array([[0.04, 0.01, -0.02]])            # a = 0.2^2, theta = -x / 2
    assert F.travel(beam, 2.0)[0, 0] == pytest.approx(0.0, abs=1e-15)
    assert F.travel(beam, 2.0, model="PAPER")[0, 0] == pytest.approx(0.16, abs=1e-15)
    # sampled field needs a full-rank Q: add an angular spread delta = 0.0025
    # -> the focus has a = delta d^2 = 0.01 (paper: 0.17)
    Q = Qmat(beam) + np.diag([0.0, 0.0025])
    Qs = sampled(shear(gaussian_field(Q), 2.0), Q)
    assert Qs[0, 0] == pytest.approx(0.01, rel=TOL)
    assert F.travel(spec(Q), 2.0)[0, 0] == pytest.approx(Qs[0, 0], rel=TOL)
    assert F.travel(spec(Q), 2.0, model="PAPER")[0, 0] == pytest.approx(0.17, rel=1e-12)
    # and backwards from the focus the beam grows again symmetrically
    Qf = Qmat(F.travel(spec(Q), 2.0))
    Qb = sampled(shear(gaussian_field(Qf), -2.0), Qf)
    assert rel(Qb, Q) < TOL


@pytest.mark.parametrize("a_o", [0.002, 0.05])
def test_occlusion_with_c_matches_sampled_visibility(a_o):
    rng = np.random.default_rng(3)
    for _ in range(3):
        Q = random_Q(rng)
        Qs = sampled(visibility(gaussian_field(Q), a_o), Q)
        cor = F.occlude(spec(Q), a_o)
        pap = F.occlude(spec(Q), a_o, model="PAPER")
        assert rel(Qmat(cor), Qs) < TOL
        assert Qmat(pap)[0, 0] == pytest.approx(Qs[0, 0], rel=TOL)   # a is right
        if abs(Q[0, 1]) > 0.2 * math.sqrt(Q[0, 0] * Q[1, 1]):
            assert rel(Qmat(pap), Qs) > 1e-2                        # b, c are not
    # a correlated beam narrowly occluded: the paper's Q is not PSD, ours is
    Q = np.array([[0.04, 0.0171], [0.0171, 0.0081]])                # rho = 0.95
    pap = F.occlude(spec(Q), 0.001, model="PAPER")
    cor = F.occlude(spec(Q), 0.001)
    assert not F.is_psd(pap)[0] and F.is_psd(cor)[0]
    Qs = sampled(visibility(gaussian_field(Q), 0.001), np.diag([0.001, 0.0081]))
    assert rel(Qmat(cor), Qs) < TOL


def test_occlusion_without_c_paper_is_right():
    Q = np.diag([0.03, 0.02])
    Qs = sampled(visibility(gaussian_field(Q), 0.01), Q)
    for model in ("CORRECTED", "PAPER"):
        assert rel(Qmat(F.occlude(spec(Q), 0.01, model=model)), Qs) < TOL


@pytest.mark.parametrize("cos", [0.9, 0.35])
def test_onto_and_off_surface_match_sampled_rescale(cos):
    rng = np.random.default_rng(4)
    Q = random_Q(rng)
    # onto: u = x / cos, l_s(u, t) = l(u cos, t): the footprint grows
    Qs = sampled(scale_x(gaussian_field(Q), cos), Q)
    assert rel(Qmat(F.onto_surface(spec(Q), cos)), Qs) < TOL
    assert rel(Qmat(F.onto_surface(spec(Q), cos, model="PAPER")), Qs) > 1e-2
    # off: x = u cos_o, l_o(x, t) = l_s(x / cos_o, t)
    cos_o = 0.6
    Qo = sampled(scale_x(gaussian_field(Qs), 1.0 / cos_o), Qs)
    assert rel(Qmat(F.off_surface(spec(Qs), cos_o)), Qo) < TOL
    assert rel(Qmat(F.off_surface(spec(Qs), cos_o, model="PAPER", cos_i=cos)), Qo) > 1e-2
    # a disc kernel keeps the unstretched axis: identity
    assert np.allclose(F.onto_surface(spec(Q), cos, disc=True), spec(Q))


@pytest.mark.parametrize("b_lobe", [0.002, 0.05])
def test_brdf_matches_sampled_angular_convolution(b_lobe):
    rng = np.random.default_rng(5)
    Q = random_Q(rng)
    Qs = sampled(conv_theta(gaussian_field(Q), b_lobe), Q + np.diag([0, b_lobe]))
    assert rel(Qmat(F.brdf(spec(Q), b_lobe)), Qs) < TOL


@pytest.mark.parametrize("kappa", [0.8, -1.5])
def test_curvature_matches_sampled_bend(kappa):
    rng = np.random.default_rng(6)
    Q = random_Q(rng)
    k = 2 * kappa                                       # mirror: k = 2 kappa
    Qs = sampled(bend(gaussian_field(Q), k), Q)
    assert rel(Qmat(F.curvature(spec(Q), kappa)), Qs) < TOL
    assert rel(Qmat(F.curvature(spec(Q), kappa, model="PAPER")), Qs) > 1e-2   # missing


def test_flat_mirror_keeps_c():
    Q = np.array([[0.02, -0.006], [-0.006, 0.01]])
    Qs = sampled(flip(gaussian_field(Q, centre=(0.1, 0.05))), Q)
    assert rel(Qmat(F.mirror(spec(Q))), Qs) < TOL
    assert Qs[0, 1] < 0


def test_concave_mirror_focuses_collimated_beam():
    """Collimated beam (a = 0.01, tiny angular spread 1e-4) on a concave mirror
    of radius 2 (kappa = -1/2): focal length 1, the spot at d = 1 has
    a = b d^2 = 1e-4 (100x smaller)."""
    Q = np.diag([0.01, 1e-4])
    f = shear(bend(flip(gaussian_field(Q)), 2 * -0.5), 1.0)
    Qs = sampled(f, Q)
    s = F.travel(F.curvature(F.mirror(spec(Q)), -0.5), 1.0)
    assert rel(Qmat(s), Qs) < TOL
    assert s[0, 0] == pytest.approx(1e-4, rel=1e-9)


def test_operator_chain_matches_sampled_chain():
    """Emitter -> travel -> occlusion -> onto -> BRDF -> off -> curved mirror
    -> travel: the composition of operators equals the composed primal field."""
    Q = np.array([[0.01, 0.0], [0.0, 0.05]])
    f = gaussian_field(Q)
    s = spec(Q)
    f = shear(f, 0.8);            s = F.travel(s, 0.8)
    f = visibility(f, 0.02);      s = F.occlude(s, 0.02)
    f = scale_x(f, 0.7);          s = F.onto_surface(s, 0.7)
    f = conv_theta(f, 0.01);      s = F.brdf(s, 0.01)
    f = scale_x(f, 1 / 0.5);      s = F.off_surface(s, 0.5)
    f = bend(flip(f), 2 * 0.6);   s = F.curvature(F.mirror(s), 0.6)
    f = shear(f, 0.5);            s = F.travel(s, 0.5)
    Qs = sampled(f, Qmat(s) * 2 + np.diag([0.01, 0.01]))
    assert rel(Qmat(s), Qs) < TOL


def test_paper_model_exact_values():
    """The PAPER model is the seed's formulas verbatim."""
    s = np.array([[0.3, 0.2, 0.1]])
    np.testing.assert_allclose(F.travel(s, 2.0, model="PAPER"), [[0.7, 0.2, -0.3]], rtol=1e-14)
    np.testing.assert_allclose(F.occlude(s, 0.6, model="PAPER"), [[0.2, 0.2, 0.1]], rtol=1e-14)
    np.testing.assert_allclose(F.onto_surface(s, 0.5, model="PAPER"), [[0.075, 0.2, 0.05]], rtol=1e-14)
    np.testing.assert_allclose(F.off_surface(s, 0.9, model="PAPER", cos_i=0.5),
                               [[1.2, 0.2, 0.2]], rtol=1e-14)
    np.testing.assert_allclose(F.brdf(s, 0.05, model="PAPER"), [[0.3, 0.25, 0.1]], rtol=1e-14)
    np.testing.assert_allclose(F.curvature(s, 3.0, model="PAPER"), s)
    beta = -math.log(0.95)
    r = F.predicted_radius(np.array([[0.04, 0.01, 0.0]]), 0.0, 2.0, model="PAPER")
    r_x = math.pi * 0.2 * beta                          # 0.0322
    r_t = 2.0 * math.tan(math.pi * 0.1 * beta)          # 0.0323
    assert r[0] == pytest.approx(min(r_x, r_t), rel=1e-14)
    np.testing.assert_allclose(F.accumulate([np.inf, 0.2, 0.3], [0.1, 0.1, 0.5], model="PAPER"),
                               [0.1, 0.2, 0.5])
    np.testing.assert_allclose(
        F.accumulate_spectrum_paper([[np.nan] * 3, [0.1, 0.5, -0.2]], [[1, 2, 3], [0.3, 0.2, -0.1]]),
        [[1, 2, 3], [0.3, 0.5, -0.1]])



@pytest.mark.parametrize("model", ["CORRECTED", "PAPER"])
def test_radius_fold_key_minimum_is_the_models_fold(model):
    """A per-pixel minimum of the fold keys (what the gather computes),
    decoded, is the model's accumulate rule (min / max) bit for bit; an
    empty pixel (inf) stays inf."""
    rng = np.random.default_rng(12)
    r = rng.uniform(0, 1, (50, 7))
    r[3, 2] = 0.0
    m = np.min(F.radius_fold_key(r, model), axis=0)
    acc = np.full(7, np.inf)
    for row in r:
        acc = F.accumulate(acc, row, model)
    assert np.array_equal(F.radius_from_fold_key(m, model), acc)
    assert F.radius_from_fold_key(np.array([np.inf]), model)[0] == np.inf

def test_corrected_model_exact_values():
    s = np.array([[0.3, 0.2, 0.1]])
    np.testing.assert_allclose(F.travel(s, 2.0), [[1.5, 0.2, 0.5]], rtol=1e-14)
    # t = 0.9: a = 0.2, c = 0.1 * 0.6 / 0.9, b = 0.2 - 0.01 / 0.9
    np.testing.assert_allclose(F.occlude(s, 0.6), [[0.2, 0.2 - 0.01 / 0.9, 0.1 * 0.6 / 0.9]], rtol=1e-14)
    np.testing.assert_allclose(F.onto_surface(s, 0.5), [[1.2, 0.2, 0.2]], rtol=1e-14)
    np.testing.assert_allclose(F.off_surface(s, 0.5), [[0.075, 0.2, 0.05]], rtol=1e-14)
    # k = 2 kappa = 0.2: b = 0.2 + 2 k c + k^2 a, c = 0.1 + k a
    np.testing.assert_allclose(F.curvature(s, 0.1), [[0.3, 0.252, 0.16]], rtol=1e-14)
    # a strong bend would give b = 0.7 > 0.467: the whole Q is scaled by
    # 0.467 / 0.7 (clipping b alone moved the focus -c/b), so
    # b = 0.467, c = 0.4 * 0.667, a = 0.3 * 0.667 and -c/b stays 0.4 / 0.7
    out = F.curvature(s, 0.5)
    f = F.B_CAP / 0.7
    np.testing.assert_allclose(out, [[0.3 * f, F.B_CAP, 0.4 * f]], rtol=1e-12)
    assert -out[0, 2] / out[0, 1] == pytest.approx(-0.4 / 0.7)


def test_lobe_variances():
    # Phong: flatland second moment of cos^n, n = 20 -> 0.0476 (frequency.md)
    t = np.linspace(-np.pi / 2, np.pi / 2, 200001)
    for n in (5, 20, 100):
        w = np.cos(t) ** n
        assert F.lobe_variance("PHONG", n) == pytest.approx((t * t * w).sum() / w.sum(), rel=0.01)
    assert F.lobe_variance("PHONG", 20) == pytest.approx(0.0476, abs=1e-4)
    # diffuse: pi^2/4 - 2, the second moment of cos over (-pi/2, pi/2), and the cap
    w = np.cos(t)
    assert F.lobe_variance("DIFFUSE", 0.3) == pytest.approx((t * t * w).sum() / w.sum(), rel=1e-6)
    assert F.lobe_variance(0, 0.0) == pytest.approx(0.4674011, rel=1e-6)   # scene.DIFFUSE
    # GGX: the sampled flatland lobe D(theta_o / 2) stays >= 95 % of its peak
    # out to the same angle as the Gaussian of variance b: sqrt(2 beta b).
    # Measured ratio 1.0065-1.0078 for roughness 0.1-0.7 (the Gaussian is
    # slightly narrower = conservative); assert within [1, 1.01].
    th = np.linspace(0, 1.5, 1_500_001)
    for rough in (0.1, 0.3, 0.5, 0.7):
        al = rough ** 2
        h = th / 2
        D = al ** 2 / (np.pi * np.cos(h) ** 4 * (al ** 2 + np.tan(h) ** 2) ** 2)
        w95 = th[np.argmax(D < 0.95 * D[0])]
        b = F.lobe_variance("GGX", rough)
        assert 1.0 <= w95 / math.sqrt(2 * F.BETA * b) <= 1.01
    assert F.lobe_variance(1, 0.0) == 0.0                                   # mirror
    assert F.lobe_variance("GGX", 1.0) == pytest.approx(F.B_CAP)
    assert F.lobe_variance("TRANSPARENT", 0.5) == 0.0
    # per-photon arrays of core.scene.model lobe kinds
    from core.scene import model as S
    kinds = np.array([S.DIFFUSE, S.GLOSSY, S.GLASS, S.TRANSPARENT, S.GLOSSY])
    rough = np.array([0.5, 0.3, 0.0, 0.2, 1.0])
    np.testing.assert_allclose(F.lobe_variance(kinds, rough),
                               [F.B_DIFFUSE, F.lobe_variance("GGX", 0.3), 0.0, 0.0, F.B_CAP])


def test_light_inits_from_primal_variance():
    """An area light is a box in x: its primal variance is w^2/12 and stable
    with resolution, while the second moment of its sampled (sinc^2) power
    spectrum diverges with the grid resolution (frequency.md)."""
    w = 0.5
    s = F.light_init("AREA", 4, size=w, size_y=0.8)
    np.testing.assert_allclose(s, [[w * w / 12, F.B_DIFFUSE, 0.0]] * 4)
    spec_a, prim_a = [], []
    for n in (512, 4096):
        x = -2 + (np.arange(n) + 0.5) * (4 / n)          # cell centres: box = whole cells
        box = (np.abs(x) <= w / 2).astype(float)
        prim_a.append((box * x * x).sum() / box.sum())
        P = np.abs(np.fft.fft(box)) ** 2
        W = 2 * np.pi * np.fft.fftfreq(n, x[1] - x[0])
        spec_a.append(1 / (2 * (P * W * W).sum() / P.sum()))
    # primal: a discrete box of whole cells has variance (w^2 - h^2)/12,
    # i.e. w^2/12 within (h/w)^2 = 2.4e-4 at n = 512
    assert prim_a[0] == pytest.approx(w * w / 12, rel=3e-4)
    assert prim_a[1] == pytest.approx(w * w / 12, rel=1e-5)
    # spectral: the 'variance' keeps shrinking as the grid refines (sinc^2 tails)
    assert spec_a[1] < 0.3 * spec_a[0]
    assert F.light_init("POINT")[0].tolist() == [0.0, F.B_DIFFUSE, 0.0]
    sun = F.light_init("SUN", angle=0.02, A_MAX=100.0)[0]
    assert sun.tolist() == pytest.approx([100.0, 0.01 ** 2 / 3, 0.0])
    spot = F.light_init("SPOT", spot_size=0.5)[0]
    assert spot[1] == pytest.approx(0.25 ** 2 / 3)
