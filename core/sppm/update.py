"""Radius of each pixel's kernel: initialisation, the frequency estimators, the progressive update.

Initial radius (docs/method.md "Initial radius"): on the first pass that gives
a pixel a visible point, initial_radius_px pixel footprints at the point's
camera depth (the slope ignored), or initial_radius metres with radius_mode
WORLD; capped by the distance to the nearest surface boundary seen around the
pixel (core.sppm.edges, docs/method.md "Surface boundaries"); never below the
radius floor R_FLOOR_REL * D (docs/frequency.md stiff table: it keeps
1 / (pi R^2) finite).

Predicted radius of a pass (Belcour & Soler 2011; docs/frequency.md): MIN
keeps the smallest radius any gathered frequency photon predicts
(core.sppm.hashgrid); QUANTILE (the paper's future work) keeps a per-pixel
histogram of the predicted radii of every frequency photon gathered so far and
takes the lower edge of the bin holding the QUANTILE-th fraction, so that a
few outliers (false occlusions pinning r near 0) no longer set the radius.
With amortised frequency photons (frequency_decay > 0, fewer of them in
later passes) a pixel keeps its last prediction through the passes that
bring it none (:func:`kept_prediction`; docs/method.md "Amortised frequency
photons").

Progressive update: :func:`ppm_radius_update` (PPM radius reduction, slowed
to the hold rate hold_alpha where the predicted radius says the light is
smooth; docs/method.md "Consistent holds").  Every visible point may hold:
core.sppm.photon_pass predicts the radius for the visible point's own
receiver lobes (docs/frequency.md "At the hitpoint").

Radius rules (setting radius_rule, docs/method.md "Radius rules"): the
radius a pass asks ppm_radius_update to keep comes from the frequency
prediction (PPM with frequency photons), from the MSE-optimal radius of the
sector counts (APPM, :func:`appm_radius`) or from the chi-square uniformity
test of the sector counts (CPPM, :func:`chi2_rejects`); with verify_holds a
test of the same counts (for a linear density) also releases frequency holds
the photons contradict; the uniformity test adds holds where the spectrum
does not call the light smooth (HOLD_OR_UNIFORM), and a verified hold in a
pixel's first pass with photons grows the radius towards the spectrum's
prediction (GROW_MAX, :func:`grow_targets`; docs/method.md "Spectrum and
counts"; both on by default: "X as the default") unless the neighbouring
pixels' densities of the same pass curve at the grown scale
(GROW_CURVATURE_Z, :func:`grow_curvature_rejects`; "When the first hold
grows").  Every rule
but that one-off growth only chooses the per-pass factor between the PPM
rate alpha and the hold rate hold_alpha, so every rule converges by the
same argument (the growth, once and bounded, scales a bound by a constant).
Where pass 1 holds fewer than HOLD_SHARE_MIN of the pixels, the holds are
left out and pass 1's factors undone (:meth:`Radii.leave_out_holds`): the
render goes on as PPM's (docs/method.md "Where FPPM's extras do not pay").

The update (the PPM rule, the default: frequency holds, verified by the
sector counts; and the baselines' APPM and CPPM rules, RULE_CODES) runs as
one compiled kernel per pixel range (:func:`_ppm_update_range`, split over
the numba threads from PARALLEL_MIN pixels); the numpy functions below are
its reference.  It repeats their operations in their order:
numpy's sum of 8 sector counts is its pairwise tree, and the gradient
projection S @ _GRADIENT.T is written as OpenBLAS's dgemm kernel computes
it, a chain of fused multiply-adds; tests/test_compiled_pass_stages.py
checks the state is the same bits.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from ..scene.camera_kernels import fma

from ..frequency import spectrum as F
from . import edges
from . import hashgrid
from .hashgrid import SECTOR_CELLS, SECTOR_QUADRANTS

#: Smallest radius relative to the scene diameter D (docs/frequency.md stiff
#: table, "tiny radii").
R_FLOOR_REL = 1e-7
QUANTILE = 0.1
HIST_BINS = 24
#: Seed of the surface-boundary cap's camera pass (with the render's seed).
EDGE_PASS_STREAM = 0xED6E
#: Chi-square test of the sector counts (CPPM, Lin et al. 2020): false
#: rejection rate and its critical values, the 0.99 quantiles of chi2(7)
#: (uniformity: SECTOR_CELLS - 1 degrees of freedom) and of chi2(5) (the
#: verified holds' test, two fewer: the fitted linear gradient); statistics
#: tables.
CHI2_ALPHA = 0.01
CHI2_CRITICAL = 18.475
CHI2_CRITICAL_LINEAR = 15.086
#: The test needs an expected count of at least 5 per cell (Cochran 1952's
#: rule for Pearson's statistic); with fewer photons it cannot reject.
CHI2_MIN_EXPECTED = 5.0
#: A verified hold needs this expected count per sector cell.  0 (the
#: default, rule set X of docs/method.md "X as the default"): a hold the
#: test cannot yet judge stands; 1 (a photon per cell, the rule of "Rings
#: under a 1 m light") refused the early holds of the principled interior's
#: dim pixels, which then shrank at PPM's rate and never came back
#: ("The frequency kernel on the indirect scenes").
HOLD_MIN_EXPECTED = 0.0
#: PPM parameter of a pixel whose prediction the photons reject (its earlier
#: holds were wrong): it shrinks faster than PPM until the test accepts;
#: above 1/2, which keeps the variance condition (docs/method.md
#: "Consistent holds").
RELEASE_ALPHA = 0.55
#: The release rate also where no hold was predicted: wherever the sector
#: counts reject a linear density (or show a ramp steeper than
#: GRADIENT_MAX), the disc straddles light it cannot average without bias
#: (a caustic's edge, a shadow's), so it shrinks at RELEASE_ALPHA (0: only
#: where a prediction is rejected, the rule before round 34; docs/method.md
#: "Counts that reject shrink faster, round 34").
RELEASE_EVERYWHERE = True
#: Below CHI2_MIN_EXPECTED per cell (the test cannot judge), a hold is
#: refused where the two fullest of the 8 cells hold this share of the counts
#: or more (uniform: 1/4; above 1: off, the default, rule set X).  0.6 was
#: made for the ring's leak through its wall (docs/method.md "Rings under a
#: 1 m light"), which the kernel clip at walls now removes.
HOLD_MAX_TOP2 = 2.0
#: A verified hold is refused (as the linear test's rejection) where the
#: counts can be tested (CHI2_MIN_EXPECTED) and the linear density fitted to
#: them changes by more than GRADIENT_MAX of its mean from the disc's centre
#: to its edge (:func:`relative_gradient`).  A density that is linear over the
#: disc and never negative has gamma <= 1; near that bound the light falls
#: towards dark within about R / gamma, and a curvature on that scale biases
#: the disc by about gamma^2 / 8 of its mean, which 8 cells cannot resolve
#: (the edge of the glass sphere's caustic: gamma 0.83-0.93, the linear test
#: accepting).  0.75 (about 7 %); inf: off (the rule before round 33;
#: docs/method.md "Steep counts refuse a hold, round 33").
GRADIENT_MAX = 0.75
#: Hold also where CPPM's uniformity test of the sector counts accepts,
#: whatever the spectrum predicts (on by default, rule set X); from
#: UNIFORM_MIN_EXPECTED per sector cell, and 0 (the default) counts a disc
#: the test cannot yet judge as uniform, CPPM's retention while photons
#: accumulate.  The linear test still vetoes (docs/method.md "Spectrum and
#: counts", "X as the default").
HOLD_OR_UNIFORM = True
UNIFORM_MIN_EXPECTED = 0.0
#: In a pixel's first pass with photons, a verified hold grows the radius to
#: the spectrum's prediction, at most GROW_MAX times the initial radius and
#: never past the surface-boundary cap (docs/method.md "Spectrum and counts":
#: the counts of a disc cannot say that the light is smooth beyond it); only
#: where the counts can be tested and a grown disc pays for its gather
#: (GROW_MIN_EXPECTED per sector cell).  1: off; 2 (the default, rule set X).
GROW_MAX = 2.0
#: 10, twice the chi-square tests' CHI2_MIN_EXPECTED: the pixels of 5-10
#: photons per cell gained ~1-2 % of their own error from growing and paid a
#: larger gather in every pass after (docs/method.md "When the first hold
#: grows", "Grow only where the counts are full").
GROW_MIN_EXPECTED = 2.0 * CHI2_MIN_EXPECTED
#: The growth's test at the grown scale (docs/method.md "When the first hold
#: grows"): the counts of one disc cannot see beyond it, but the pixels
#: initial_radius_px away gathered their own discs in the same pass, at the
#: distance the grown disc reaches.  Their photon densities M / R^2 along the
#: image rows and columns give a second difference (zero for a linear
#: density, the verified holds' model); where it differs from zero by more
#: than GROW_CURVATURE_Z Poisson standard deviations on either axis the hold
#: stands but does not grow.  2.576: the two-sided normal quantile of the
#: chi-square tests' level CHI2_ALPHA; 0: off (every verified hold grows).
GROW_CURVATURE_Z = 2.576
#: Per-pixel hold rate from the spectrum (Knaus & Zwicker 2011: the bias of a
#: disc goes as (R / R_pred)^2 where the light is flat within R_pred): a verified
#: hold whose spectrum predicts r_pred > R shrinks with
#: alpha_h = min(HOLD_ALPHA_SPECTRUM, 1 - (1 - hold_alpha) (R / r_pred)^2), where
#: the counts can test the hold (HOLD_SPECTRUM_MIN_EXPECTED); at or below
#: hold_alpha (0: the rule before, bench 'fppm:hmax=0'): hold_alpha for every
#: hold.  Below 1, so that R_k -> 0 still, with R_k^2 <= C k^-(1 - 0.95)
#: (docs/method.md "Consistent holds", "The gated spectrum rate as the
#: default, round 16").
HOLD_ALPHA_SPECTRUM = 0.95
#: The spectrum's rate applies only where the counts can test the hold: an
#: expected count of at least this per sector cell (the state's counts and
#: this pass's, as the verified holds' test reads them); below it the linear
#: test cannot reject (CHI2_MIN_EXPECTED), so a wrongly predicted hold (the
#: ring's low-count caustic pixels) keeps hold_alpha (docs/method.md "A slower
#: hold where the counts can test it, round 15").  0: no gate.
HOLD_SPECTRUM_MIN_EXPECTED = CHI2_MIN_EXPECTED
#: The holds left out where they hold almost nothing (docs/method.md "Where
#: FPPM's extras do not pay"): after the update of pass HOLD_SHARE_PASS, a
#: photon-mapping render in which fewer than HOLD_SHARE_MIN of the pixels
#: with a radius hold renders on as plain PPM -- no frequency photons, no
#: sector counts, every radius at the alpha rate; after pass 1 from PPM's own
#: state (Radii.leave_out_holds).  Measured at 64x64 in pass 1: the rings
#: hold 10 % of their pixels, every other example scene 52-99 %.
#: HOLD_SHARE_MIN 0: never.
HOLD_SHARE_PASS = 1
HOLD_SHARE_MIN = 0.25
#: A visible point reached through a delta vertex (the floor seen through the
#: glass sphere, a surface seen in a mirror) holds: False (the default for
#: photon mapping) refuses its holds, so it shrinks at PPM's rate.  On the
#: glass sphere at 128x128 the holds of the pixels that see the caustic's
#: focus through the sphere carried most of FPPM's excess over PPM at equal
#: passes, with the counts' holds (CPPM's) as with the spectrum's
#: (docs/method.md "The glass sphere at equal passes, round 17").
#: COMBINED's merging, which gathers at those points only, keeps its holds.
HOLD_THROUGH_DELTA = False
#: With frequency_start S > 1 the pixels have photons (N > 0) before the
#: first prediction, so the growth of a pixel's first pass with photons
#: (GROW_MAX) would never run; True (the default; S = 1 never reads it): a
#: verified hold grows in pass S as it would in pass 1, from the radius it
#: has then (docs/method.md "A late start for the frequency photons, round
#: 18": 0.91x the error of S = 1 in the room at equal CPU with S = 2, and
#: bench_hold_alpha 'growS=0' the rule without).
GROW_AT_START = True
#: Pixels from which the compiled update splits over the numba threads.
PARALLEL_MIN = 1 << 16
#: The per-pixel radius rules the compiled update runs besides PPM's (code 0),
#: so that a baseline differs from FPPM only in its rule, not in numpy's
#: cost (docs/method.md "The baselines' update compiled, round 33").
RULE_CODES = {"CPPM": 1.0, "APPM": 2.0}


def _gradient_patterns() -> np.ndarray:
    """(2, SECTOR_CELLS) expected count pattern of a unit linear gradient
    along the tangent frame's u and w axes: each cell's centroid, the ring's
    radial centroid (2/3)(b^3 - a^3)/(b^2 - a^2) (R = 1, rings split at
    1/sqrt 2) times the quadrant's direction at 45 + 90 q degrees."""
    a2 = 1.0 / np.sqrt(2.0)
    rings = [(0.0, a2), (a2, 1.0)]
    rho = [2.0 / 3.0 * (b ** 3 - a ** 3) / (b ** 2 - a ** 2) for a, b in rings]
    th = np.radians(45.0 + 90.0 * np.arange(SECTOR_QUADRANTS))
    return np.array([np.concatenate([r * np.cos(th) for r in rho]),
                     np.concatenate([r * np.sin(th) for r in rho])])


_GRADIENT = _gradient_patterns()
#: |g|^2 of the two gradient patterns, as chi2_rejects computes them.
_GRADIENT_NORM2 = np.square(_GRADIENT).sum(axis=1)


def needs_sectors(settings, frequency: bool) -> bool:
    """The gather must count photons per sector cell: the APPM or CPPM rule,
    or frequency holds verified by the photons."""
    return settings.radius_rule != "PPM" or (frequency and settings.verify_holds)


def chi2_rejects(S: np.ndarray, linear: bool = False, critical=None) -> np.ndarray:
    """(P,) bool: Pearson's chi-square test rejects, at level CHI2_ALPHA, that
    the photons counted in the SECTOR_CELLS equal-area cells S (P,
    SECTOR_CELLS) are uniform over the disc (CPPM's hypothesis), or with
    linear=True that their density is linear (uniform plus a gradient, which
    leaves the symmetric disc estimate unbiased: the verified holds' test).
    False where the expected count per cell is below CHI2_MIN_EXPECTED;
    critical: another critical value (None: the level CHI2_ALPHA's).
        E = sum(S) / C,  X^2 = |S - E|^2 / E                  vs chi2(C - 1)
        linear: X^2 - sum_g (g.S)^2 / (|g|^2 E), g = the two gradient
        patterns (orthogonal to each other and to a constant)  vs chi2(C - 3)"""
    S = np.asarray(S, np.float64)
    E = S.sum(axis=1) / SECTOR_CELLS
    r2 = np.square(S - E[:, None]).sum(axis=1)
    crit = CHI2_CRITICAL
    if linear:
        proj = S @ _GRADIENT.T                                   # (P, 2)
        r2 = r2 - (np.square(proj) / np.square(_GRADIENT).sum(axis=1)).sum(axis=1)
        crit = CHI2_CRITICAL_LINEAR
    if critical is not None:
        crit = critical
    with np.errstate(divide="ignore", invalid="ignore"):
        X2 = r2 / E
    return (E >= CHI2_MIN_EXPECTED) & (X2 > crit)


def relative_gradient(S: np.ndarray) -> np.ndarray:
    """(P,) the linear density fitted to the sector counts S (P,
    SECTOR_CELLS), its gradient's size relative to the mean: the fitted
    density at the disc's edge along the gradient is (1 +- gamma) times the
    disc's mean (the gradient patterns' projections as chi2_rejects(linear=
    True) computes them; 0 where S sums to 0)."""
    S = np.asarray(S, np.float64)
    E = S.sum(axis=1) / SECTOR_CELLS
    b = (S @ _GRADIENT.T) / _GRADIENT_NORM2                # (P, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.sqrt(b[:, 0] * b[:, 0] + b[:, 1] * b[:, 1]) / E
    return np.where(E > 0, g, 0.0)


def appm_radius(S: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """(P,) radius [m] minimising the estimated MSE of the disc estimate
    (Kaplanyan & Dachsbacher 2013), from the sector counts S (P,
    SECTOR_CELLS) gathered with squared radii R2 (P,); inf where the
    Laplacian estimate is zero (any radius is as good: keep it).

    For density L + x.g + x'Hx/2 over the disc of radius R, the inner ring
    (|x| < R/sqrt 2) and the outer ring of equal area differ by
    n_out - n_in = pi lap(L) R^4 / 16 photons (n = n_in + n_out ~ pi R^2 L),
    so the relative Laplacian is lambda = 16 (n_out - n_in) / (n R^2).  The
    disc's bias is L lambda r^2 / 8 and its relative variance R^2 / (n r^2),
    so MSE(r) / L^2 = lambda^2 r^4 / 64 + R^2 / (n r^2) is least at
        r^6 = 32 R^2 / (n lambda^2) = R^6 n / (8 D^2),
    D^2 = (n_out - n_in)^2 - n: the square of the difference, less its
    Poisson variance (n), so that noise alone does not shrink the radius."""
    S = np.asarray(S, np.float64)
    n_in = S[:, :SECTOR_QUADRANTS].sum(axis=1)
    n_out = S[:, SECTOR_QUADRANTS:].sum(axis=1)
    n = n_in + n_out
    D2 = np.maximum(np.square(n_out - n_in) - n, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = n / (8.0 * D2)
    # libm's pow element by element, as the compiled rule (_rule_radius) calls
    # it: numpy's array power may run SIMD routines a last bit apart.
    root = np.array([math.pow(x, 1.0 / 6.0) if d > 0 else 0.0 for x, d in zip(q, D2)])
    r = np.sqrt(R2) * root
    return np.where(D2 > 0, r, np.inf)


class RadiusHistogram:
    """HIST_BINS bins of predicted radii, log-spaced from 1e-6 D to D
    (bin 0: below 1e-6 D, the last bin: up to and above D)."""

    def __init__(self, D: float):
        self.D = D

    def bin(self, r: np.ndarray) -> np.ndarray:
        """(K,) int64 bin of the radii |r| (K,) [m]."""
        lo, hi = 1e-6 * self.D, self.D
        x = (np.log(np.maximum(np.abs(r), 1e-300)) - np.log(lo)) / (np.log(hi) - np.log(lo))
        return np.clip((x * (HIST_BINS - 1)).astype(np.int64) + 1, 0, HIST_BINS - 1)

    def edge(self, b: np.ndarray) -> np.ndarray:
        """(K,) float64 lower edge [m] of bins b (K,) (0 for bin 0)."""
        lo, hi = 1e-6 * self.D, self.D
        e = np.exp(np.log(lo) + (b - 1) / (HIST_BINS - 1) * (np.log(hi) - np.log(lo)))
        return np.where(b <= 0, 0.0, e)

    def quantile(self, h: np.ndarray, r_fallback: np.ndarray) -> np.ndarray:
        """(P,) radius at the QUANTILE-th fraction of the counts h (P, HIST_BINS);
        r_fallback (P,) where a pixel has no count."""
        tot = h.sum(axis=1)
        cum = np.cumsum(h, axis=1)
        b = np.argmax(cum >= np.ceil(QUANTILE * np.maximum(tot, 1))[:, None], axis=1)
        return np.where(tot > 0, self.edge(b), r_fallback)


class Radii:
    """Radius policy of a render.

    settings: RenderSettings; camera: CameraModel (pixel footprint); D: scene
    diameter [m]; frequency: the plan traces frequency photons; camera_pass:
    core.sppm.visible_points.CameraPass (the boundary cap's pass through the
    pixel centres); H, W: the region's size.
    """

    def __init__(self, settings, camera, D: float, frequency: bool, camera_pass, H: int, W: int):
        self.settings, self.camera, self.frequency = settings, camera, frequency
        self.camera_pass, self.H, self.W = camera_pass, H, W
        self.floor = R_FLOOR_REL * float(D)     # a Python float: numpy keeps float32 radii
        self.floor_sq = radius_floor_sq(D)
        self.hist = RadiusHistogram(D)
        self.quantile = frequency and settings.frequency_estimator == "QUANTILE"
        self.sector_cells = SECTOR_CELLS if needs_sectors(settings, frequency) else 0
        # Amortised frequency photons (frequency_decay > 0): a pass without a
        # frequency photon at a pixel keeps the pixel's last prediction.
        self.keep_predictions = frequency and settings.frequency_decay > 0
        # kept_prediction's rule: False keeps the last prediction, True the
        # running minimum of every prediction (bench_hold_alpha compares them).
        self.keep_minimum = False
        self._edge_cap = None
        # The PPM rule's update in _ppm_update_range and the initial radii
        # in _initialise_range (False: the numpy references, the same state).
        self.compiled = True
        # Verified holds need this expected count per sector cell, and a
        # rejected prediction shrinks with this PPM parameter (never slower
        # than alpha); bench_hold_alpha 'fppm:power=0:release=0.7' is the
        # rule before (docs/method.md "Rings under a 1 m light").
        self.hold_min_expected = HOLD_MIN_EXPECTED
        # alpha = 1 is a fixed radius (no pixel shrinks): a release must not
        # shrink it either (tests/test_stiff_scenes: a point focus with a
        # fixed radius integrates to its flux).
        self.release_alpha = (settings.alpha if settings.alpha >= 1.0
                              else min(settings.alpha, RELEASE_ALPHA))
        self.hold_max_top2 = HOLD_MAX_TOP2
        self.gradient_max = GRADIENT_MAX
        self.release_everywhere = float(RELEASE_EVERYWHERE)
        # docs/method.md "Spectrum and counts" (bench_hold_alpha varies them).
        self.hold_uniform = HOLD_OR_UNIFORM
        self.grow = GROW_MAX
        self.grow_min_expected = GROW_MIN_EXPECTED
        self.grow_curvature_z = GROW_CURVATURE_Z
        self.grow_at_start = GROW_AT_START
        self.uniform_critical = CHI2_CRITICAL
        self.uniform_min_expected = UNIFORM_MIN_EXPECTED
        self.hold_alpha_spectrum = HOLD_ALPHA_SPECTRUM
        self.hold_spectrum_min_expected = HOLD_SPECTRUM_MIN_EXPECTED
        # leave_out_holds: the share of held pixels below which the holds are
        # left out after pass HOLD_SHARE_PASS (photon mapping with verified
        # frequency holds only: COMBINED's merging keeps its own rule), and
        # why they were (None: they were not).
        self.hold_share_min = (HOLD_SHARE_MIN if frequency and settings.integrator == "PHOTON"
                               and settings.verify_holds and settings.radius_rule == "PPM"
                               else 0.0)
        # Pass 1 whatever frequency_start S: with S > 1 its holds are the
        # counts' (the uniformity test, CPPM's) and hold the same share as
        # the spectrum's (the rings 11 %, the other examples 40-99 %), and
        # only after pass 1 can leave_out_holds make the state PPM's; decided
        # after pass S the rings kept pass 1's holds and pass S's growth
        # (docs/method.md "Round 19: the rings and the decision").
        self.hold_share_pass = HOLD_SHARE_PASS
        self.holds_left_out = None
        # HOLD_THROUGH_DELTA (photon mapping; bench 'fppm:through=1' holds
        # there as before round 17), and this pass's visible points reached
        # through a delta vertex (P,) bool (set by initialise; None: not asked).
        self.hold_through_delta = (HOLD_THROUGH_DELTA or settings.integrator != "PHOTON"
                                   or not frequency)     # PPM, CPPM: no hold to refuse
        self._through = None
        # The radii before the first update (leave_out_holds undoes pass 1's
        # holds: the state becomes PPM's), and the updates so far.
        self._R2_first = None
        self._updates = 0

    def initialise(self, state, vp, check_stop=lambda: None) -> None:
        """Set state.R2 of the pixels whose first visible point this is (R2 == 0)
        (``compiled``: in :func:`_initialise_range`, the same bits)."""
        st = self.settings
        if not self.hold_through_delta and vp.through_delta is not None:
            self._through = np.asarray(vp.through_delta) & np.asarray(vp.valid)
        if self.compiled:
            cap = np.zeros(0)
            if st.cap_radius_at_edges:
                if self._edge_cap is None and not np.any(vp.valid & (state.R2 == 0)):
                    return              # no new pixel: the cap's camera pass can wait
                cap = self.edge_cap(check_stop)
            P = state.R2.shape[0]
            args = (vp.valid, vp.depth, state.R2, cap, st.radius_mode == "WORLD",
                    float(st.initial_radius), float(st.initial_radius_px), float(self.camera.pix),
                    self.camera.cam.kind == "ORTHO", float(self.floor))
            # Mostly a scan for new pixels (none after the first pass in a
            # closed scene): threads from the grid build's threshold, not the
            # update's (a parallel region's hand-off cost ~10 ms of wall a
            # 256² pass on the loaded machine, the scan 0.2 ms).
            T = numba.get_num_threads()
            if P >= hashgrid.PARALLEL_MIN_VPS and T > 1:
                _initialise_parallel(T, *args)
            else:
                _initialise_range(0, P, *args)
            return
        new = vp.valid & (state.R2 == 0)
        if not np.any(new):
            return
        if st.radius_mode == "WORLD":
            r = np.full(int(new.sum()), st.initial_radius)
        else:
            r = st.initial_radius_px * self.camera.footprint(vp.depth[new])
        if st.cap_radius_at_edges:
            r = np.minimum(r, self.edge_cap(check_stop)[new])
        r = np.maximum(r, self.floor)
        state.R2[new] = r * r

    def leave_out_holds(self, state, k: int) -> "str | None":
        """After the update of pass k: leave the holds out when k is
        ``hold_share_pass`` (HOLD_SHARE_PASS) and fewer than ``hold_share_min`` of the pixels with
        a radius held in it (:meth:`drop_holds`); the reason, once, else None."""
        if self.holds_left_out is not None or self.hold_share_min <= 0 or k != self.hold_share_pass:
            return None
        has = state.R2 > 0
        share = float(np.count_nonzero(state.held & has)) / max(int(np.count_nonzero(has)), 1)
        if share >= self.hold_share_min:
            return None
        if k == 1 and self._R2_first is not None:
            # Pass 1 gathered every pixel with its initial radius, as PPM's
            # does, and N was 0: scaling R^2, N and tau by alpha / f (f =
            # R'^2 / R^2, the factor the rules chose) gives PPM's state after
            # its pass 1 (N = alpha M, tau = alpha Phi, R^2 = alpha R0^2;
            # "Consistent holds": any f keeps the estimate an average of the
            # passes' estimates), so the render goes on as PPM's, held or
            # grown radii and all.
            R0 = self._R2_first
            m = (state.M_last > 0) & (R0 > 0) & (state.R2 > 0)
            g = self.settings.alpha * R0[m] / state.R2[m]
            state.R2[m] *= g
            state.N[m] *= g
            state.tau[m] *= g[:, None]
            state.held[:] = False
        self._R2_first = None
        self.drop_holds(f"{100 * share:.0f} % of the pixels held after pass {k}, below "
                        f"{100 * self.hold_share_min:.0f} %: plain PPM"
                        + (" from its first pass on" if k == 1 else f" from pass {k + 1}"))
        return self.holds_left_out

    def drop_holds(self, why: str) -> None:
        """From the next update on, the PPM rule alone: no prediction kept, no
        sector counts read (the state keeps its array, unread, for checkpoints)."""
        self.holds_left_out = why
        self.frequency = False
        self.keep_predictions = False

    def edge_cap(self, check_stop=lambda: None) -> np.ndarray:
        """(P,) float64 cap on each pixel's initial radius [m] (inf = none):
        core.sppm.edges.boundary_cap of one camera pass through the pixel
        centres, computed once per render."""
        if self._edge_cap is None:
            st = self.settings
            vp, _ = self.camera_pass(np.random.default_rng([st.seed, EDGE_PASS_STREAM]),
                                     check_stop, centre=True)
            fp = self.camera.footprint(vp.depth)
            if st.radius_mode == "WORLD":
                r_px = st.initial_radius / np.maximum(fp[vp.valid], 1e-300)
                reach = edges.reach_for(float(r_px.max()) if r_px.size else 1.0)
            else:
                reach = edges.reach_for(st.initial_radius_px)
            self._edge_cap = edges.boundary_cap(vp.p, vp.ng, vp.wo, vp.valid, fp,
                                                self.H, self.W, reach)
        return self._edge_cap

    def predicted(self, r_pred_min: np.ndarray, r_hist) -> np.ndarray:
        """(P,) predicted radius of the pass [m] (inf = no frequency photon) from
        the gathered minimum r_pred_min (P,) and, for QUANTILE, the committed
        histogram r_hist (P, HIST_BINS).  The PAPER model predicts negative
        radii for converging light: their magnitude is the radius."""
        r_pred = r_pred_min
        r_pred = F.radius_from_fold_key(r_pred, self.settings.frequency_model)
        if self.quantile:
            r_pred = self.hist.quantile(r_hist, r_pred)
        return r_pred

    def grows_at(self, k) -> bool:
        """Whether pass k (1-based; None: unknown) grows the verified holds
        of pixels that already have photons: the first pass with frequency
        photons when it is not pass 1 (``grow_at_start``, GROW_AT_START)."""
        S = int(self.settings.frequency_start)
        return bool(self.grow_at_start) and S > 1 and k is not None and int(k) == S

    def update(self, state, M: np.ndarray, Phi: np.ndarray, r_pred: np.ndarray,
               sectors=None, k=None) -> None:
        """Progressive update of state (N, R2, tau, held, r_pred_last, M_last,
        sectors) with this pass's photons: M (P,) count, Phi (P, 3) flux,
        r_pred (P,) [m] predicted for each visible point's receiver lobes (any
        material), sectors (P, SECTOR_CELLS) this pass's sector counts (None
        unless :func:`needs_sectors`); k: the pass (1-based; None: unknown),
        for :meth:`grows_at`."""
        rule = self.settings.radius_rule
        any_n = self.grows_at(k)
        if (any_n and self._edge_cap is None and self.camera_pass is not None
                and self.settings.cap_radius_at_edges):
            # A render resumed after pass 1 has not made the growth's cap
            # yet (its own camera stream: the same cap as without the resume).
            self.edge_cap()
        self._updates += 1
        if self._updates == 1 and self.hold_share_min > 0 and self.hold_share_pass == 1:
            self._R2_first = state.R2.copy()
        if self.keep_predictions:
            r_pred = kept_prediction(r_pred, state.r_pred_last, self.keep_minimum)
        left_out = self.holds_left_out is not None
        grow_cap = self._edge_cap
        if (rule == "PPM" and self.grow > 1.0 and self.grow_curvature_z > 0 and not left_out
                and sectors is not None and state.sectors is not None):
            grow_cap = self.grow_cap(state, M, any_n)
        veto = (self._through if rule == "PPM" and not left_out and not self.hold_through_delta
                else None)
        if veto is not None and not veto.any():
            veto = None
        if self.compiled and (
                (rule == "PPM" and (left_out or (state.sectors is None) == (sectors is None)))
                or (rule in RULE_CODES and not left_out and state.sectors is not None
                    and sectors is not None)):
            self._update_compiled(state, M, Phi, r_pred, None if left_out else sectors, grow_cap,
                                  veto, any_n)
            return
        S = None
        if state.sectors is not None and sectors is not None and not left_out:
            S = state.sectors + sectors
        # APPM / CPPM keep a radius (r_pred = R: the hold rate) where the MSE
        # optimum is not smaller (no curvature seen) / the test accepts.
        keep = np.sqrt(np.where(state.R2 > 0, state.R2, np.nan))
        if rule == "APPM":
            r_pred = appm_radius(S, state.R2)
            r_pred = np.where(np.isinf(r_pred), keep, r_pred)
        elif rule == "CPPM":
            r_pred = np.where(chi2_rejects(S), np.nan, keep)
        elif not self.frequency:
            r_pred = np.full_like(r_pred, np.nan)
        else:
            r_pred = np.where(np.isinf(r_pred), np.nan, r_pred)
        r_hold = r_pred
        R2_grow = None
        if S is not None and rule == "PPM":
            E = S.sum(axis=1) / SECTOR_CELLS
            if self.hold_uniform:
                # Smooth by the spectrum or by the counts (CPPM's test).
                uniform = ~chi2_rejects(S, critical=self.uniform_critical) & (state.R2 > 0) \
                    & (E >= self.uniform_min_expected)
                r_hold = np.where(uniform, np.fmax(r_pred, keep), r_pred)
            if self.grow > 1.0:
                R2_grow = np.where(E >= self.grow_min_expected, grow_targets(
                    state.N, state.R2, r_pred, self.grow, grow_cap, any_n), 0.0)
            # Verified holds: the photons veto the prediction where they show
            # more than a linear gradient (the prediction itself is kept for
            # the Predicted Radius pass).
            rejected = chi2_rejects(S, linear=True) | (
                (E >= CHI2_MIN_EXPECTED) & (relative_gradient(S) > self.gradient_max))
            r_or = r_hold
            r_hold = np.where(rejected, np.nan, r_hold)
            # Too few photons for the test to reject: no agreement yet.
            r_hold = np.where(E < self.hold_min_expected, np.nan, r_hold)
            top2 = np.sort(S, axis=1)[:, -2:]
            one_sided = (E < CHI2_MIN_EXPECTED) & (top2[:, 0] + top2[:, 1]
                                                   >= self.hold_max_top2 * S.sum(axis=1))
            r_hold = np.where(one_sided, np.nan, r_hold)
        if veto is not None:
            r_hold = np.where(veto, np.nan, r_hold)                 # Radii.hold_through_delta
        m = M > 0
        R2_old = state.R2[m]
        alpha = self.settings.alpha
        hold_alpha = self.settings.hold_alpha
        if S is not None and rule == "PPM":
            alpha = np.where(rejected & (np.isfinite(r_or) | bool(self.release_everywhere)),
                             self.release_alpha, alpha)[m]
            if self.hold_alpha_spectrum > hold_alpha:
                hold_alpha = spectrum_hold_alpha(state.R2[m], r_pred[m], r_hold[m], hold_alpha,
                                                 self.hold_alpha_spectrum,
                                                 E[m] >= self.hold_spectrum_min_expected)
        N2, R2n, tau2, held = ppm_radius_update(state.N[m], state.R2[m], state.tau[m], M[m],
                                                  Phi[m], alpha, r_hold[m],
                                                  self.floor_sq, hold_alpha,
                                                  None if R2_grow is None else R2_grow[m])
        state.N[m], state.R2[m], state.tau[m] = N2, R2n, tau2
        if S is not None:
            # The counts shrink with the disc, as N does (N' = (N + M) f).
            f = np.where(R2_old > 0, R2n / np.where(R2_old > 0, R2_old, 1.0), 1.0)
            S[m] *= f[:, None]
            state.sectors[...] = S
        state.held[:] = False
        state.held[np.nonzero(m)[0]] = held
        state.r_pred_last = r_pred
        state.M_last = M

    def grow_cap(self, state, M: np.ndarray, any_n: bool = False):
        """The growth's cap [m] of this pass ((P,) or None: none): the
        surface-boundary cap, and 0 (no growth) where
        :func:`grow_curvature_rejects` sees curvature at the grown scale
        around a pixel in its first pass with photons (any_n: around every
        pixel with photons, :meth:`grows_at`); the edge cap itself where no
        pixel is (nothing to decide)."""
        first = ((state.N == 0.0) | any_n) & (M > 0) & (state.R2 > 0)
        if not np.any(first) or state.R2.shape[0] != self.H * self.W:
            return self._edge_cap
        step = max(1, int(round(self.settings.initial_radius_px)))
        veto = first & grow_curvature_rejects(M, state.R2, self.H, self.W, step,
                                              self.grow_curvature_z)
        cap = (np.full(state.R2.shape[0], np.inf) if self._edge_cap is None
               else np.array(self._edge_cap, np.float64))
        cap[veto] = 0.0
        return cap

    def _update_compiled(self, state, M, Phi, r_pred, sectors, grow_cap=None, veto=None,
                         any_n: bool = False) -> None:
        """:meth:`update` of the PPM, CPPM or APPM rule in ``_ppm_update_range`` (the same bits);
        veto (P,) bool: the pixels that do not hold (None: none); any_n: the
        growth whatever N (:meth:`grows_at`)."""
        P = M.shape[0]
        st = self.settings
        none = np.zeros((P, 0))
        a = UpdateArrays(state.N, state.R2, state.tau, state.held,
                         none if state.sectors is None or sectors is None else state.sectors,
                         np.ascontiguousarray(M, np.float64),
                         np.ascontiguousarray(Phi, np.float64),
                         np.ascontiguousarray(r_pred, np.float64),
                         none if sectors is None else np.ascontiguousarray(sectors, np.float64),
                         np.zeros(0, np.bool_) if veto is None
                         else np.ascontiguousarray(veto, np.bool_),
                         np.empty(P))
        prm = np.array([st.alpha, self.floor_sq, st.hold_alpha, self.hold_min_expected,
                        self.release_alpha, self.hold_max_top2, float(self.hold_uniform),
                        self.grow * self.grow if self.grow > 1.0 else 0.0,
                        self.grow_min_expected, self.uniform_critical,
                        self.uniform_min_expected, self.hold_alpha_spectrum,
                        self.hold_spectrum_min_expected, float(any_n),
                        RULE_CODES.get(st.radius_rule, 0.0), self.gradient_max,
                        self.release_everywhere])
        cap = grow_cap if grow_cap is not None else np.zeros(0)
        args = (a, prm, self.frequency, _GRADIENT, _GRADIENT_NORM2, cap)
        T = numba.get_num_threads()
        if P >= PARALLEL_MIN and T > 1:
            _ppm_update_parallel(T, *args)
        else:
            _ppm_update_range(0, P, *args)
        state.r_pred_last = a.r_pred_last
        state.M_last = M


def grow_targets(N, R2, r_pred, grow, cap=None, any_n=False):
    """(P,) squared radius [m^2] a verified hold grows to (0: none) in the
    pixel's first pass with photons (N == 0; any_n: whatever N,
    Radii.grows_at): the spectrum's prediction
    r_pred (P,) [m] (NaN: none), at most grow times the radius R2 (P,) and
    the surface-boundary cap (P,) [m] (None: no cap) (docs/method.md
    "Spectrum and counts")."""
    rr = np.maximum(np.where(np.isfinite(r_pred), r_pred, 0.0), 0.0)
    lim = grow * grow * R2
    if cap is not None:
        lim = np.minimum(lim, np.square(cap))
    return np.where(((N == 0.0) | any_n) & np.isfinite(r_pred), np.minimum(np.square(rr), lim), 0.0)


def grow_curvature_rejects(M, R2, H, W, step, z):
    """(P,) bool: the photon density of this pass curves at the grown scale
    around each pixel of an H x W image (P = H W, row-major): the densities
    rho = M / R^2 (M (P,) photons gathered in squared radii R2 (P,) [m^2]) of
    the pixels ``step`` rows or columns away give, along either axis,
        d = rho_- + rho_+ - 2 rho,  Var d = M_- / R_-^4 + M_+ / R_+^4 + 4 M / R^4
    (Poisson counts, a count of at least 1 for the variance), and the test
    rejects a linear density where |d| > z sqrt(Var d) on either axis.  An
    axis with a neighbour off the image or without a radius is not tested."""
    rho = np.where(R2 > 0, M / np.where(R2 > 0, R2, 1.0), np.nan).reshape(H, W)
    var = np.where(R2 > 0, np.maximum(M, 1.0) / np.where(R2 > 0, R2 * R2, 1.0),
                   np.nan).reshape(H, W)
    out = np.zeros((H, W), bool)
    for axis in (0, 1):
        n = rho.shape[axis]
        if n <= 2 * step:
            continue
        c = [slice(None)] * 2
        lo, mid, hi = list(c), list(c), list(c)
        lo[axis], mid[axis], hi[axis] = slice(0, n - 2 * step), slice(step, n - step), \
            slice(2 * step, n)
        lo, mid, hi = tuple(lo), tuple(mid), tuple(hi)
        d = rho[lo] + rho[hi] - 2.0 * rho[mid]
        v = var[lo] + var[hi] + 4.0 * var[mid]
        with np.errstate(invalid="ignore"):
            out[mid] |= np.abs(d) > z * np.sqrt(v)      # NaN (no radius): False
    return out.ravel()


def spectrum_hold_alpha(R2, r_spec, r_hold, hold_alpha, alpha_max, testable=True):
    """(K,) hold rate of each row (HOLD_ALPHA_SPECTRUM): where the hold stands
    (r_hold finite), the counts can test it (testable (K,) bool, or True:
    HOLD_SPECTRUM_MIN_EXPECTED) and the spectrum predicts r_spec > R,
    min(alpha_max, 1 - (1 - hold_alpha) R^2 / r_spec^2); hold_alpha elsewhere."""
    r = np.maximum(np.where(np.isfinite(r_spec), r_spec, 0.0), 0.0)
    slow = np.isfinite(r_hold) & (R2 > 0) & (r * r > R2) & testable
    q = R2 / np.where(slow, r * r, 1.0)
    return np.where(slow, np.minimum(alpha_max, 1.0 - (1.0 - hold_alpha) * q), hold_alpha)


def kept_prediction(r_pred: np.ndarray, r_last: np.ndarray, minimum: bool = False) -> np.ndarray:
    """(P,) the prediction a pass's update uses with amortised frequency
    photons (docs/method.md "Amortised frequency photons"): this pass's
    r_pred (P,) [m] where a frequency photon reached the pixel, else the
    pixel's last prediction r_last (P,) (PixelState.r_pred_last: a radius,
    NaN = none, inf = none yet).  The spectrum is a property of the light
    field at the pixel, not of the pass; whatever it is, the update only
    chooses f between f_alpha and f_hold_alpha, so convergence is unchanged.
    minimum=True: the running minimum of every prediction instead (NaN and
    inf count as none)."""
    if minimum:
        return np.fmin(r_pred, r_last)
    return np.where(np.isinf(r_pred), r_last, r_pred)


class UpdateArrays(NamedTuple):
    """The compiled PPM update's arrays (P pixels).  In place: N, R2 (P,),
    tau (P, 3), held (P,) bool, S (P, SECTOR_CELLS) the state's sector
    counts ((P, 0): none).  In: M (P,), Phi (P, 3), r_pred (P,) the
    predicted radius, sectors (P, SECTOR_CELLS) this pass's counts ((P, 0):
    none), veto (P,) bool the pixels that do not hold (Radii.hold_through_delta;
    (0,): none).  Out: r_pred_last (P,).  All float64 but held and veto."""
    N: np.ndarray
    R2: np.ndarray
    tau: np.ndarray
    held: np.ndarray
    S: np.ndarray
    M: np.ndarray
    Phi: np.ndarray
    r_pred: np.ndarray
    sectors: np.ndarray
    veto: np.ndarray
    r_pred_last: np.ndarray


@njit(cache=True, inline="always")
def _np_max(a, b):
    """np.maximum of two floats (NaN wins)."""
    return a if (a >= b or a != a) else b


@njit(cache=True, inline="always")
def _np_min(a, b):
    """np.minimum of two floats (NaN wins)."""
    return a if (a <= b or a != a) else b


@njit(cache=True, inline="always")
def _sum8(x):
    """numpy's sum of 8 float64 (its pairwise tree of 8 accumulators)."""
    return ((x[0] + x[1]) + (x[2] + x[3])) + ((x[4] + x[5]) + (x[6] + x[7]))


@njit(cache=True)
def _chi2_uniform_rejects(Si, tmp, crit):
    """chi2_rejects(S, critical=crit) of one pixel's counts Si
    (SECTOR_CELLS,); tmp: (SECTOR_CELLS,) scratch."""
    E = _sum8(Si) / SECTOR_CELLS
    for k in range(SECTOR_CELLS):
        d = Si[k] - E
        tmp[k] = d * d
    r2 = _sum8(tmp)
    if E == 0.0:
        return False
    return E >= CHI2_MIN_EXPECTED and r2 / E > crit


@njit(cache=True, inline="always")
def _projections(Si, grad):
    """The two gradient patterns' projections (p0, p1) of one pixel's counts
    Si, S @ grad.T as OpenBLAS's dgemm computes it (a chain of fused
    multiply-adds); read by the linear test and the relative gradient."""
    p0 = Si[0] * grad[0, 0]
    p1 = Si[0] * grad[1, 0]
    for k in range(1, SECTOR_CELLS):
        p0 = fma(Si[k], grad[0, k], p0)
        p1 = fma(Si[k], grad[1, k], p1)
    return p0, p1


@njit(cache=True)
def _chi2_linear_rejects(Si, E, p0, p1, gnorm2, tmp):
    """chi2_rejects(S, linear=True) of one pixel's counts Si (SECTOR_CELLS,),
    their mean E (_sum8(Si) / SECTOR_CELLS) and projections p0, p1
    (:func:`_projections`); tmp: (SECTOR_CELLS,) scratch."""
    for k in range(SECTOR_CELLS):
        d = Si[k] - E
        tmp[k] = d * d
    r2 = _sum8(tmp)
    r2 = r2 - (p0 * p0 / gnorm2[0] + p1 * p1 / gnorm2[1])
    if E == 0.0:
        return False                # X^2 is NaN or inf but E < CHI2_MIN_EXPECTED
    return E >= CHI2_MIN_EXPECTED and r2 / E > CHI2_CRITICAL_LINEAR


@njit(cache=True, inline="always")
def _relative_gradient(E, p0, p1, gnorm2):
    """relative_gradient of one pixel's counts from their mean E and
    projections p0, p1 (:func:`_projections`)."""
    b0, b1 = p0 / gnorm2[0], p1 / gnorm2[1]
    return math.sqrt(b0 * b0 + b1 * b1) / E if E > 0 else 0.0


@njit(cache=True)
def _rule_radius(Si, R2, rule, tmp):
    """The radius [m] CPPM (rule 1) or APPM (rule 2) keeps for one pixel's
    counts Si (SECTOR_CELLS,) at squared radius R2, as :meth:`Radii.update`'s
    numpy rules compute it (the same operations in their order): CPPM the
    radius itself where :func:`chi2_rejects` accepts uniform counts, else NaN
    (no hold); APPM :func:`appm_radius`, the radius itself where that is inf.
    NaN where R2 <= 0.  tmp: (SECTOR_CELLS,) scratch."""
    keep = math.sqrt(R2) if R2 > 0 else np.nan
    if rule == 1.0:
        return np.nan if _chi2_uniform_rejects(Si, tmp, CHI2_CRITICAL) else keep
    n_in = Si[0]
    for k in range(1, SECTOR_QUADRANTS):
        n_in += Si[k]
    n_out = Si[SECTOR_QUADRANTS]
    for k in range(SECTOR_QUADRANTS + 1, SECTOR_CELLS):
        n_out += Si[k]
    n = n_in + n_out
    d = n_out - n_in
    D2 = _np_max(d * d - n, 0.0)
    if D2 > 0:
        return math.sqrt(R2) * (n / (8.0 * D2)) ** (1.0 / 6.0)
    return keep


@njit(cache=True)
def _ppm_update_range(i0, i1, a, prm, frequency, grad, gnorm2, cap):
    """Radii.update for pixels i0..i1-1 (the PPM rule, or CPPM's or APPM's: prm[14]): the verified
    holds' chi-square test, then :func:`ppm_radius_update` (its operations
    and order), the sector counts scaled with N; prm = (alpha, R2_floor,
    hold_alpha, hold_min_expected: no hold below this expected count per
    sector cell, release_alpha: the PPM parameter of a pixel whose
    prediction the test rejects, hold_max_top2, hold_uniform (1.0: hold
    also where the uniformity test accepts), grow^2 (0: no growth;
    :func:`grow_targets`), grow_min_expected: no growth below this expected
    count per sector cell, the uniformity test's critical value, its
    minimum expected count per cell (below: no uniform hold), the spectrum's
    hold rate (HOLD_ALPHA_SPECTRUM; at or below hold_alpha: off) and its
    minimum expected count per cell (HOLD_SPECTRUM_MIN_EXPECTED), 1.0: the
    growth whatever N (Radii.grows_at), the radius rule (RULE_CODES: 0 PPM,
    1 CPPM, 2 APPM; CPPM and APPM read only alpha, hold_alpha and the
    counts: :func:`_rule_radius`), the steepest relative gradient a hold
    accepts (GRADIENT_MAX), 1.0: release_alpha wherever the counts reject,
    predicted or not (RELEASE_EVERYWHERE)); cap (P,) the
    growth's cap [m] (Radii.grow_cap: the surface boundary, 0 where the
    growth curves; (0,): none)."""
    alpha, floor_sq, hold_alpha = prm[0], prm[1], prm[2]
    rule = prm[14]
    with_S = a.S.shape[1] == SECTOR_CELLS
    E_cell = 0.0
    Si = np.empty(SECTOR_CELLS)
    tmp = np.empty(SECTOR_CELLS)
    for i in range(i0, i1):
        alpha = prm[0]
        r = a.r_pred[i]
        if not frequency or math.isinf(r):
            r = np.nan
        a.r_pred_last[i] = r
        r_spec = r
        if with_S:
            for k in range(SECTOR_CELLS):
                Si[k] = a.S[i, k] + a.sectors[i, k]
            E_cell = _sum8(Si) / SECTOR_CELLS
            if rule != 0.0:
                # CPPM / APPM: the rule's radius from the counts alone, no
                # spectrum, growth or verification (Radii.update's numpy rules).
                r = _rule_radius(Si, a.R2[i], rule, tmp)
                r_spec = np.nan
                a.r_pred_last[i] = r
            else:
                if (prm[6] != 0.0 and a.R2[i] > 0 and not _chi2_uniform_rejects(Si, tmp, prm[9])
                        and E_cell >= prm[10]):
                    Ri = math.sqrt(a.R2[i])
                    if r != r or r < Ri:
                        r = Ri                              # np.fmax(r, R)
                p0, p1 = _projections(Si, grad)
                if (_chi2_linear_rejects(Si, E_cell, p0, p1, gnorm2, tmp)
                        or (E_cell >= CHI2_MIN_EXPECTED
                            and _relative_gradient(E_cell, p0, p1, gnorm2) > prm[15])):
                    if np.isfinite(r) or prm[16] != 0.0:
                        alpha = prm[4]
                    r = np.nan
                else:
                    tot = _sum8(Si)
                    if tot / SECTOR_CELLS < prm[3]:
                        r = np.nan
                    elif tot / SECTOR_CELLS < CHI2_MIN_EXPECTED:
                        m1, m2 = -1.0, -1.0
                        for k in range(SECTOR_CELLS):
                            if Si[k] > m1:
                                m1, m2 = Si[k], m1
                            elif Si[k] > m2:
                                m2 = Si[k]
                        if m2 + m1 >= prm[5] * tot:
                            r = np.nan
        if a.veto.shape[0] > 0 and a.veto[i]:
            r = np.nan                                      # Radii.hold_through_delta
        held = False
        M = a.M[i]
        if M > 0:
            N, R2 = a.N[i], a.R2[i]
            p0, p1, p2 = a.Phi[i, 0], a.Phi[i, 1], a.Phi[i, 2]
            active = (np.isfinite(p0) and np.isfinite(p1) and np.isfinite(p2)
                      and p0 >= 0 and p1 >= 0 and p2 >= 0 and R2 > 0 and np.isfinite(R2))
            if active:
                f_ppm = (N + alpha * M) / (N + M)
                f = f_ppm
                freq = np.isfinite(r)
                f_lim = 0.0
                if freq:
                    rr = _np_max(r, 0.0)
                    f_lim = _np_min(rr * rr / R2, 1.0)
                ha = hold_alpha
                if (with_S and prm[11] > hold_alpha and freq and np.isfinite(r_spec)
                        and E_cell >= prm[12]):
                    rs = _np_max(r_spec, 0.0)               # spectrum_hold_alpha
                    if rs * rs > R2:
                        ha = _np_min(prm[11], 1.0 - (1.0 - hold_alpha) * (R2 / (rs * rs)))
                if hold_alpha < 1.0:
                    f_lim = _np_min(f_lim, (N + ha * M) / (N + M))
                held = freq and f_lim > f_ppm
                f = _np_max(f, f_lim)
                if (held and with_S and prm[7] > 0.0 and (N == 0.0 or prm[13] != 0.0)
                        and np.isfinite(r_spec)
                        and E_cell >= prm[8]):
                    rs = _np_max(r_spec, 0.0)
                    lim = prm[7] * R2
                    if cap.shape[0] > 0:
                        lim = _np_min(lim, cap[i] * cap[i])
                    g = _np_min(rs * rs, lim) / R2
                    if g > f:
                        f = g
                f = _np_max(f, _np_min(floor_sq / R2, 1.0))
                if f == f_ppm:
                    a.N[i] = N + alpha * M
                else:
                    a.N[i] = (N + M) * f
                R2n = R2 * f
                a.R2[i] = R2n
                for c in range(3):
                    a.tau[i, c] = (a.tau[i, c] + a.Phi[i, c]) * f
            else:
                R2n = R2
            if with_S:
                # The counts shrink with the disc, as N does (N' = (N + M) f).
                fs = R2n / R2 if R2 > 0 else 1.0
                for k in range(SECTOR_CELLS):
                    Si[k] *= fs
        a.held[i] = held
        if with_S:
            for k in range(SECTOR_CELLS):
                a.S[i, k] = Si[k]


@njit(cache=True, parallel=True)
def _ppm_update_parallel(n_chunks, a, prm, frequency, grad, gnorm2, cap):
    P = a.M.shape[0]
    for c in prange(n_chunks):
        _ppm_update_range(c * P // n_chunks, (c + 1) * P // n_chunks, a, prm, frequency, grad,
                          gnorm2, cap)


@njit(cache=True)
def _initialise_range(i0, i1, valid, depth, R2, cap, world, r_world, r_px, pix, ortho, floor):
    """Radii.initialise for pixels i0..i1-1: R2 (P,) float64 of the valid
    (P,) bool pixels with R2 == 0, from depth (P,) float32, the edge cap (P,)
    float64 ((0,): none), the floor [m].  numpy's dtypes, hence its bits: the
    footprint rule is float32 (camera.footprint of the float32 depth, times
    the Python float initial_radius_px, NEP 50) up to the cap's float64
    minimum, and stays float32 through the floor and the square without a
    cap; WORLD radii are float64."""
    with_cap = cap.shape[0] > 0
    pix32, r_px32, floor32 = np.float32(pix), np.float32(r_px), np.float32(floor)
    for i in range(i0, i1):
        if not valid[i] or R2[i] != 0.0:
            continue
        if world:
            r = r_world
        else:
            fp = pix32 if ortho else depth[i] * pix32       # CameraModel.footprint
            r32 = r_px32 * fp
            if not with_cap:
                r32 = _np_max(r32, floor32)
                R2[i] = r32 * r32
                continue
            r = np.float64(r32)
        if with_cap:
            r = _np_min(r, cap[i])
        r = _np_max(r, floor)
        R2[i] = r * r


@njit(cache=True, parallel=True)
def _initialise_parallel(n_chunks, valid, depth, R2, cap, world, r_world, r_px, pix, ortho,
                         floor):
    P = R2.shape[0]
    for c in prange(n_chunks):
        _initialise_range(c * P // n_chunks, (c + 1) * P // n_chunks, valid, depth, R2, cap,
                          world, r_world, r_px, pix, ortho, floor)


def radius_floor_sq(D):
    """R2_floor = (1e-7 D)^2 for a scene of diameter D [m] (stiff table "tiny radii")."""
    return (R_FLOOR_REL * float(D)) ** 2


def ppm_radius_update(N, R2, tau, M, Phi, alpha, r_pred=None, R2_floor=0.0, hold_alpha=1.0,
                      R2_grow=None):
    """Progressive radius update with a frequency-held radius.

    N: (K,) accumulated photon count; R2: (K,) squared radius [m^2];
    tau: (K, 3) accumulated flux; M: (K,) photons collected this pass;
    Phi: (K, 3) their flux; alpha: PPM parameter in (0, 1]; r_pred: (K,)
    predicted radius [m] or None (inf = no frequency photon, NaN = no hold);
    R2_floor: smallest R^2 (see :func:`radius_floor_sq`); hold_alpha: the
    PPM parameter of a held radius, in (0, 1] (or (K,) of them per row,
    :func:`spectrum_hold_alpha`): 1 holds it forever (the inconsistent rule
    of Belcour & Soler 2011), <= alpha never holds;
    R2_grow: (K,) squared radius [m^2] a held row grows to where it is
    larger than R^2 f (f > 1; :func:`grow_targets`), or None.
    Returns (N', R2', tau', held): (K,), (K,), (K, 3) float64 and (K,) bool.

    docs/frequency.md "PPM update" and docs/method.md "Consistent holds":
        f_a   = (N + a M) / (N + M)                 (Hachisuka 2008 with a)
        f     = max(f_alpha, min((r_pred/R)^2, f_hold_alpha))
                                                    (f_alpha when r_pred not finite)
        R'^2  = R^2 f,  N' = (N + M) f,  tau' = (tau + Phi) f
    so plain PPM gives N' = N + alpha M; a radius the prediction calls smooth
    shrinks like PPM with hold_alpha (no slower), which keeps the estimate
    consistent for hold_alpha < 1 (Knaus & Zwicker 2011); a prediction
    between the two rates sets R' = r_pred.
    R'^2 >= min(R^2, R2_floor): the floor never makes a radius grow.
    Rows with M <= 0, or with non-finite / negative Phi, are left unchanged.
    Everything is float64 (stiff table "float32 counters").
    """
    N = np.asarray(N, np.float64).copy()
    R2 = np.asarray(R2, np.float64).copy()
    tau = np.asarray(tau, np.float64).copy()
    M = np.asarray(M, np.float64)
    Phi = np.asarray(Phi, np.float64)
    active = (M > 0) & np.all(np.isfinite(Phi), axis=-1) & np.all(Phi >= 0, axis=-1) \
        & (R2 > 0) & np.isfinite(R2)
    Ma = np.where(active, M, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        f_ppm = np.where(active, (N + alpha * Ma) / (N + Ma), 1.0)
        f = f_ppm
        held = np.zeros(N.shape, bool)
        if r_pred is not None:
            r = np.asarray(r_pred, np.float64)
            freq = np.isfinite(r) & active
            r2 = np.square(np.maximum(np.where(freq, r, 0.0), 0.0))
            f_lim = np.where(freq, np.minimum(r2 / np.where(active, R2, 1.0), 1.0), 0.0)
            ha = np.asarray(hold_alpha, np.float64)
            if np.any(ha < 1.0):
                f_lim = np.minimum(f_lim, np.where(active, (N + ha * Ma) / (N + Ma), 1.0))
            held = freq & (f_lim > f_ppm)
            f = np.maximum(f, f_lim)
            if R2_grow is not None:
                g = np.asarray(R2_grow, np.float64) / np.where(active, R2, 1.0)
                f = np.where(held & (g > f), g, f)
        f_floor = np.minimum(np.asarray(R2_floor, np.float64) / np.where(active, R2, 1.0), 1.0)
        f = np.where(active, np.maximum(f, f_floor), 1.0)
    plain = active & (f == f_ppm)
    N1 = np.where(plain, N + alpha * Ma, np.where(active, (N + Ma) * f, N))
    R2_1 = np.where(active, R2 * f, R2)
    tau1 = np.where(active[..., None], (tau + np.where(active[..., None], Phi, 0.0)) * f[..., None], tau)
    return N1, R2_1, tau1, held
