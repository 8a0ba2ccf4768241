"""Properties of the frequency model: random operator chains, the 95 % radius,
accumulation rules, the PPM radius update and a small bump simulation.

Hypothesis runs derandomized (fixed examples, CI is deterministic); numpy
draws use fixed seeds.  Tolerances on Monte Carlo numbers are stated where
they are asserted.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from core.frequency import spectrum as F
from core.sppm.update import ppm_radius_update

PROFILE = settings(derandomize=True, max_examples=200, deadline=None, database=None)


# ------------------------------------------------------------------ chains
OPS = ("travel", "occlude", "onto", "off", "brdf", "curvature", "mirror")
PAPER_OPS = ("travel", "occlude", "onto", "off", "brdf")      # the paper has no curvature


def apply_op(s, op, u, model, A_MAX=F.A_MAX_DEFAULT):
    """One operator with parameters drawn from u in [0, 1]^3 (per photon)."""
    u = np.asarray(u, float)
    if op == "travel":
        return F.travel(s, 0.05 + 3 * u[..., 0], model, A_MAX)
    if op == "occlude":
        return F.occlude(s, (0.01 + u[..., 0]) ** 2, model, A_MAX)      # (distance)^2
    if op == "onto":
        return F.onto_surface(s, 0.1 + 0.9 * u[..., 0], model, A_MAX)
    if op == "off":
        return F.off_surface(s, 0.1 + 0.9 * u[..., 0], model, A_MAX, cos_i=0.1 + 0.9 * u[..., 1])
    if op == "brdf":
        return F.brdf(s, F.lobe_variance("GGX", u[..., 0]), model, A_MAX)
    if op == "curvature":
        return F.curvature(s, 2 * u[..., 0] - 1, model, A_MAX)
    return F.mirror(s)


def run_chains(s, ops, kinds, params, model):
    """Apply, photon by photon, chain step k's operator ops[kinds[k, i]]."""
    out = np.array(s, float)
    for k in range(kinds.shape[0]):
        new = np.empty_like(out)
        with np.errstate(all="ignore"):
            for j, op in enumerate(ops):
                m = kinds[k] == j
                if m.any():
                    new[m] = apply_op(out[m], op, params[k][m], model)
        out = new
    return out


def test_random_chains_paper_invalid_fraction(record_property):
    """10-operator chains of the paper's five operators (uniformly drawn) from
    point and area lights: the PAPER model ends with a non-PSD or non-finite
    Q for 55 % of them, the CORRECTED model for none, also with curvature and
    mirrors.  frequency.md reports 74 %; the share depends on the operator mix
    (drawing travel and occlusion twice as often as the others gives 78 %)."""
    rng = np.random.default_rng(0)
    n, L = 2000, 10
    s0 = np.concatenate([F.light_init("POINT", n // 2), F.light_init("AREA", n - n // 2, size=0.3)])
    kinds = rng.integers(0, len(PAPER_OPS), (L, n))
    params = rng.uniform(0, 1, (L, n, 3))
    paper = run_chains(s0, PAPER_OPS, kinds, params, "PAPER")
    frac = 1.0 - F.is_psd(paper).mean()
    record_property("paper_invalid_fraction", float(frac))
    print(f"PAPER: {frac:.1%} of {n} random 10-operator chains end invalid")
    # measured 55.1 % with this seed; binomial sd 1.1 %: a +-6 sd band
    assert 0.48 < frac < 0.62
    cor = run_chains(s0, PAPER_OPS, kinds, params, "CORRECTED")
    assert F.is_psd(cor).all()
    kinds7 = rng.integers(0, len(OPS), (L, n))
    cor7 = run_chains(s0, OPS, kinds7, params, "CORRECTED")
    assert F.is_psd(cor7).all()


finite_or_extreme = st.one_of(
    st.floats(0.0, 1.0), st.floats(1e-12, 1e6),
    st.sampled_from([0.0, 1e-300, 1e-20, 1e20, np.inf, np.nan, -1.0]))
step = st.tuples(st.sampled_from(OPS), st.lists(finite_or_extreme, min_size=3, max_size=3))


@st.composite
def spectra(draw):
    a = draw(st.floats(0, 1e4))
    b = draw(st.floats(0, 1.0))
    rho = draw(st.floats(-1, 1))
    return [a, b, rho * math.sqrt(a * b)]


@PROFILE
@given(s=spectra(), chain=st.lists(step, min_size=1, max_size=12),
       D=st.sampled_from([1e-3, 1.0, 1e4]))
def test_corrected_chains_stay_finite_and_psd(s, chain, D):
    """Any chain, with extreme parameters (0, inf, NaN, negative, 1e20 and
    raw values instead of the [0, 1] mapping), keeps a finite PSD Q with
    a <= A_MAX and b <= 0.467."""
    A_MAX = D * D
    out = F.sanitize(np.array([s], float), A_MAX)      # as light_init would give
    with np.errstate(all="ignore"):
        for op, p in chain:
            v = np.array([p], float)
            if op == "travel":
                out = F.travel(out, v[:, 0] * D, A_MAX=A_MAX)
            elif op == "occlude":
                out = F.occlude(out, v[:, 0] * A_MAX, A_MAX=A_MAX)
            elif op == "onto":
                out = F.onto_surface(out, v[:, 0], A_MAX=A_MAX)
            elif op == "off":
                out = F.off_surface(out, v[:, 0], A_MAX=A_MAX)
            elif op == "brdf":
                out = F.brdf(out, v[:, 0], A_MAX=A_MAX)
            elif op == "curvature":
                out = F.curvature(out, v[:, 0] / D, A_MAX=A_MAX)
            else:
                out = F.mirror(out)
    assert F.is_psd(out).all(), out
    assert out[0, 0] <= A_MAX and out[0, 1] <= F.B_CAP
    r = F.predicted_radius(out, np.inf, D)
    assert np.isfinite(r).all() and (r >= 0).all()


@PROFILE
@given(st.lists(st.sampled_from([0.0, -1.0, 1e-300, 0.3, 7.0, 1e300, np.inf, -np.inf, np.nan]),
                min_size=3, max_size=3))
def test_sanitize_any_input(v):
    out = F.sanitize(np.array([v]), A_MAX=100.0)
    assert F.is_psd(out).all() and out[0, 0] <= 100.0 and out[0, 1] <= F.B_CAP


@PROFILE
@given(st.lists(spectra(), min_size=2, max_size=6))
def test_paper_per_coefficient_max_keeps_psd(rows):
    acc = np.full((1, 3), np.nan)
    for r in rows:
        acc = F.accumulate_spectrum_paper(acc, np.array([r]))
    assert F.is_psd(acc).all()


def test_per_coefficient_min_can_be_invalid():
    p1, p2 = np.array([1.0, 0.01, 0.0]), np.array([0.01, 1.0, -0.1])
    assert F.is_psd(np.stack([p1, p2])).all()
    assert not F.is_psd(np.minimum(p1, p2)[None])[0]        # (0.01, 0.01, -0.1)


# ------------------------------------------------------------------ radius
def test_rx_is_the_95_percent_of_peak_radius():
    """Sampled light field -> outgoing radiance at a receiver with lobe b_r:
    L(x) = int l(x, t) g_br(t) dt.  It stays >= 95 % of its peak exactly out
    to r_x = sqrt(2 beta a_eff), a_eff = a - c^2 / (b + b_r) (a for diffuse).
    Grid: 4001 x-samples over +-1.5 r_x (h = 7.5e-4 r_x) and a 2001-point
    theta quadrature: the crossing is located to ~1e-3 r_x."""
    Q = np.array([[0.02, 0.012], [0.012, 0.03]])
    Qi = np.linalg.inv(Q)
    t = np.linspace(-2.0, 2.0, 2001)
    for b_r in (0.01, 0.2, np.inf):
        r = F.predicted_radius(np.array([[Q[0, 0], Q[1, 1], Q[0, 1]]]), b_r, 1e9)[0]
        x = np.linspace(-1.5 * r, 1.5 * r, 4001)
        X, T = np.meshgrid(x, t, indexing="ij")
        l = np.exp(-0.5 * (Qi[0, 0] * X * X + 2 * Qi[0, 1] * X * T + Qi[1, 1] * T * T))
        g = np.ones_like(t) if np.isinf(b_r) else np.exp(-0.5 * t * t / b_r)
        Lx = (l * g).sum(axis=1)
        inside = np.abs(x) <= r * (1 - 2e-3)
        outside = np.abs(x) >= r * (1 + 2e-3)
        assert Lx[inside].min() >= 0.95 * Lx.max()
        assert Lx[outside].max() < 0.95 * Lx.max()
    assert math.sqrt(2 * F.BETA) == pytest.approx(0.3203, abs=1e-4)


def test_rtheta_is_the_95_percent_view_angle():
    """An angular Gaussian of variance b + b_r drops to 95 % at
    sqrt(2 beta (b + b_r)); a camera at distance z sees that angle across
    r_theta = z tan(angle)."""
    b, b_r, z = 0.05, 0.02, 3.0
    ang = np.linspace(0, 1, 100001)
    cross = ang[np.argmax(np.exp(-0.5 * ang ** 2 / (b + b_r)) < 0.95)]
    r = F.predicted_radius(np.array([[1e6, b, 0.0]]), b_r, z)[0]
    assert math.atan(r / z) == pytest.approx(cross, abs=2e-5)


def disc_bias(r2_over_2a):
    """Disc average / peak of a 2D Gaussian exp(-rho^2 / 2a) over a disc of
    radius r: (1 - exp(-u)) / u with u = r^2 / 2a."""
    return (1 - math.exp(-r2_over_2a)) / r2_over_2a - 1


def test_disc_estimate_bias_at_bump_peak():
    # r_x: u = beta -> (1 - 0.95) / beta - 1 = -2.52 %
    assert disc_bias(F.BETA) == pytest.approx(-0.0252, abs=1e-4)
    # Monte Carlo: uniform points in the disc, n = 400k; the sd of the mean of
    # exp(-rho^2/2a) (values in [0.95, 1]) is < 0.015 / sqrt(n) = 2.4e-5
    rng = np.random.default_rng(7)
    a = 0.3 ** 2
    r = F.predicted_radius(np.array([[a, 0.1, 0.0]]), np.inf, 1.0)[0]
    rho2 = r * r * rng.uniform(0, 1, 400_000)
    mc = np.exp(-rho2 / (2 * a)).mean() - 1
    assert mc == pytest.approx(-0.0252, abs=1e-4)
    # "95 % of the energy" radii: 1.96 sigma and 2.45 sigma -> -56 % / -68 %
    assert disc_bias(1.96 ** 2 / 2) == pytest.approx(-0.556, abs=2e-3)
    assert disc_bias(2.45 ** 2 / 2) == pytest.approx(-0.683, abs=2e-3)
    # the paper's r = pi sqrt(a) beta = 0.161 sigma: over-small, -0.65 %
    rp = F.predicted_radius(np.array([[a, 0.1, 0.0]]), np.inf, 1.0, model="PAPER")[0]
    assert rp / 0.3 == pytest.approx(math.pi * F.BETA)
    assert disc_bias(rp * rp / (2 * a)) == pytest.approx(-0.0065, abs=1e-4)


def test_paper_tan_radius_passes_half_pi():
    b = np.array([10.0, 50.0, 90.0, 94.9, 95.1, 100.0])
    s = np.stack([np.full_like(b, 1e8), b, np.zeros_like(b)], 1)
    r = F.predicted_radius(s, 0.0, 1.0, model="PAPER")
    assert np.all(np.diff(r[:4]) > 0) and r[3] > 1000          # grows to +inf ...
    assert r[4] < -1000 and r[5] == pytest.approx(-24.6, rel=0.01)   # ... then negative
    rc = F.predicted_radius(s, 0.0, 1.0)                        # b capped at 0.467
    assert np.all(rc > 0) and np.allclose(rc, rc[0])


def test_accumulation_min_vs_paper_max_at_caustic_peak():
    """Hitpoint at a caustic peak (a = sigma^2, sigma = 1 cm) next to broad
    light (a = 1): irradiance E = B + C exp(-rho^2 / 2 sigma^2), C = 1.86 B.
    The disc estimate with MIN keeps the caustic's 95 % radius (-2.5 % on the
    caustic share); MAX takes the broad light's radius and averages the
    caustic away (frequency.md: -65 % vs -2 %)."""
    sig, B, C = 0.01, 1.0, 1.86
    photons = np.array([[1.0, 0.2, 0.0], [sig * sig, 0.2, 0.0], [0.5, 0.1, 0.0]])
    r_new = F.predicted_radius(photons, np.inf, 5.0)
    r_min, r_max = np.inf, np.inf
    for r in r_new:
        r_min = F.accumulate(np.array([r_min]), np.array([r]))[0]
        r_max = F.accumulate(np.array([r_max]), np.array([r]), model="PAPER")[0]
    assert r_min == pytest.approx(math.sqrt(2 * F.BETA) * sig)
    assert r_max == pytest.approx(math.sqrt(2 * F.BETA))

    def bias(r):
        return C * disc_bias(r * r / (2 * sig * sig)) / (B + C)
    assert bias(r_min) == pytest.approx(-0.0164, abs=1e-3)     # -2.5 % x C/(B+C)
    assert bias(r_max) == pytest.approx(-0.65, abs=0.01)


# ------------------------------------------------------------------ PPM update
def test_ppm_without_frequency_shrinks_exactly():
    N = np.array([0.0, 10.0, 1e6])
    R2 = np.array([1.0, 0.04, 1e-6])
    tau = np.array([[0.0] * 3, [1.0, 2.0, 3.0], [5.0] * 3])
    M = np.array([4, 7, 3])
    Phi = np.ones((3, 3))
    for r_pred in (None, np.full(3, np.inf), np.full(3, np.nan), np.zeros(3)):
        N1, R21, tau1, held = ppm_radius_update(N, R2, tau, M, Phi, 0.7, r_pred)
        ratio = (N + 0.7 * M) / (N + M)
        assert np.array_equal(R21, R2 * ratio)
        assert np.array_equal(N1, N + 0.7 * M)
        np.testing.assert_allclose(tau1, (tau + Phi) * ratio[:, None], rtol=1e-15)
        assert not held.any()


def test_ppm_held_radius():
    N, R2, tau = np.array([10.0, 10.0, 10.0]), np.full(3, 0.04), np.ones((3, 3))
    M, Phi = np.array([5, 5, 0]), np.full((3, 3), 2.0)
    r_pred = np.array([0.5, 0.19, 0.5])     # >= R, between R_ppm and R, no photons
    N1, R21, tau1, held = ppm_radius_update(N, R2, tau, M, Phi, 0.7, r_pred)
    # held: f = 1 -> N + M, tau + Phi, R unchanged
    assert R21[0] == 0.04 and N1[0] == 15 and np.all(tau1[0] == 3.0) and held[0]
    # partial: R' = r_pred, f = (r/R)^2, N' = (N + M) f
    f = 0.19 ** 2 / 0.04
    assert R21[1] == pytest.approx(0.19 ** 2) and N1[1] == pytest.approx(15 * f)
    np.testing.assert_allclose(tau1[1], 3.0 * f)
    assert held[1] and f > (10 + 3.5) / 15
    # M = 0: nothing changes
    assert R21[2] == 0.04 and N1[2] == 10 and np.all(tau1[2] == 1.0) and not held[2]


@PROFILE
@given(N=st.floats(0, 1e9), R2=st.floats(1e-14, 1e4), tau=st.floats(0, 1e12),
       M=st.integers(0, 10 ** 6), phi=st.floats(0, 1e6), alpha=st.floats(0.05, 1.0),
       r=st.one_of(st.none(), st.floats(0, 1e3), st.sampled_from([np.inf, np.nan, -1.0])),
       floor=st.sampled_from([0.0, 1e-14, 1e-6]))
def test_ppm_update_properties(N, R2, tau, M, phi, alpha, r, floor):
    R2 = max(R2, floor)
    rp = None if r is None else np.array([r])
    N1, R21, tau1, held = ppm_radius_update(np.array([N]), np.array([R2]), np.full((1, 3), tau),
                                              np.array([M]), np.full((1, 3), phi), alpha, rp, floor)
    assert R21[0] <= R2 and R21[0] >= floor                       # never grows, floor
    assert np.isfinite(N1).all() and N1[0] >= N                   # (N + M) f >= N + alpha M
    assert np.isfinite(tau1).all() and (tau1 >= 0).all()
    if M == 0:
        assert N1[0] == N and R21[0] == R2 and tau1[0, 0] == tau
    if held[0]:
        assert R21[0] > R2 * (N + alpha * M) / (N + M) * (1 - 1e-12)


# ------------------------------------------------------------------ bump simulation
def bump_sim(r_pred, sigma, R0=0.035, rate=500.0, passes=1000, runs=64, alpha=0.7, seed=0):
    """Disc estimate at the peak of a 2D Gaussian bump E = exp(-rho^2/2 sigma^2).

    Each pass emits photons whose hits around the hitpoint follow E: the count
    inside radius R is Poisson(rate * 2 pi sigma^2 (1 - exp(-R^2/2 sigma^2))),
    each of unit power; L = tau / (pi R^2 passes rate).  Returns
    (relRMSE, mean relative bias, final radius) over ``runs`` runs.
    """
    rng = np.random.default_rng(seed)
    N, R2, tau = np.zeros(runs), np.full(runs, R0 * R0), np.zeros((runs, 3))
    rp = None if r_pred is None else np.full(runs, r_pred)
    for _ in range(passes):
        lam = rate * 2 * math.pi * sigma ** 2 * (1 - np.exp(-R2 / (2 * sigma ** 2)))
        M = rng.poisson(lam).astype(float)
        N, R2, tau, _ = ppm_radius_update(N, R2, tau, M, np.repeat(M[:, None], 3, 1), alpha, rp)
    L = tau[:, 0] / (math.pi * R2 * passes * rate)
    return math.sqrt(np.mean((L - 1) ** 2)), float(np.mean(L) - 1), float(np.sqrt(R2).mean())


def test_bump_simulation_held_radius_beats_plain_ppm(record_property):
    """64 runs x 1000 passes, smooth bump sigma = 0.1, R0 = 0.35 sigma.
    Measured: plain PPM relRMSE 5.6 %, held with the corrected r (0.32 sigma)
    3.8 %, with the paper's r (0.16 sigma) 4.7 %.  The relRMSE of 64 runs has
    a relative sd of ~1/sqrt(128) = 9 %, so 'corrected < 0.85 x plain' holds
    with > 3 sd margin.  The held estimate's bias sits at the -2.5 % peak
    level (sd of the mean 3.8 % / 8 = 0.5 %)."""
    sigma = 0.1
    plain = bump_sim(None, sigma)
    cor = bump_sim(math.sqrt(2 * F.BETA) * sigma, sigma)
    pap = bump_sim(math.pi * F.BETA * sigma, sigma)
    for k, v in (("plain", plain), ("corrected", cor), ("paper", pap)):
        record_property(f"bump_relRMSE_{k}", v[0])
    print(f"bump relRMSE: plain {plain[0]:.2%}, held corrected {cor[0]:.2%}, held paper {pap[0]:.2%}")
    assert cor[0] < 0.85 * plain[0]
    assert -0.045 < cor[1] < -0.01
    assert cor[2] == pytest.approx(math.sqrt(2 * F.BETA) * sigma)   # the radius was held
    # a sharp bump (sigma = 0.02): r_pred = 0.0064 is below the PPM radius
    # for all 1000 passes, so holding never triggers: identical to plain PPM
    assert bump_sim(math.sqrt(2 * F.BETA) * 0.02, 0.02) == bump_sim(None, 0.02)
