"""The kept prediction as the precision mean of the passes' predictions
(update.mixture_prediction; docs/frequency.md "Mixture of predictions").

The pixel's light is the mixture of its photons' light: 1/r^2 = sum_i w_i /
r_i^2 (spectrum.layered_radius's rule), each term capped at 1/(beta R^2).
One sharp photon among smooth ones no longer releases a hold; a sharp share
above beta (5 %) still does.
"""
import numpy as np
import pytest

from core.frequency.spectrum import BETA
from core.settings import RenderSettings
from core.sppm.state import PixelState
from core.sppm.update import MIXTURE_WEIGHT, Radii, kept_prediction, mixture_prediction


def test_mixture_prediction_numbers():
    lam = MIXTURE_WEIGHT
    R2 = np.ones(6)
    r = mixture_prediction(np.array([2.0, np.inf, 0.5, 0.0, np.inf, 0.4]),
                           np.array([np.nan, 3.0, 3.0, 3.0, np.nan, np.inf]), R2)
    assert r[0] == 2.0                                  # first prediction: itself
    assert r[1] == 3.0                                  # none this pass: kept
    # One pass at 0.5 R after 3 R: 1/r^2 = 0.9/9 + 0.1 * 4 = 0.5 -> held (r > R).
    assert r[2] == pytest.approx(1.0 / np.sqrt((1 - lam) / 9.0 + lam * 4.0), rel=1e-12)
    assert r[2] > 1.4
    # A zero radius counts as its share's whole drop, 1/(beta R^2): no hold.
    assert r[3] == pytest.approx(1.0 / np.sqrt((1 - lam) / 9.0 + lam / BETA), rel=1e-12)
    assert r[3] < 0.71
    assert np.isnan(r[4])                               # never a prediction
    assert r[5] == pytest.approx(0.4, rel=1e-12)        # inf = none yet: the new one
    # The last-prediction rule releases pixel 2 (0.5 < R).
    assert kept_prediction(np.array([0.5]), np.array([3.0]))[0] == 0.5


def _held_fraction(mixture, passes=60, seed=3):
    """Fraction of pixel-passes held: 400 pixels of radius 1 m, one
    prediction per pass each, 3 m (smooth) with probability 0.9 and 0.5 m (a
    sharp outlier) with 0.1; uniform sector counts (the verified holds' test
    accepts)."""
    st = RenderSettings()
    radii = Radii(st, None, 1.0, True, None, 1, 400)
    radii.keep_mixture = mixture
    state = PixelState.zeros(400, sector_cells=radii.sector_cells)
    state.R2[:] = 1.0
    M, Phi = np.full(400, 100.0), np.ones((400, 3))
    S = np.full((400, radii.sector_cells), 100.0 / radii.sector_cells)
    rng = np.random.default_rng(seed)
    held = []
    for _ in range(passes):
        R = np.sqrt(state.R2)
        r_pred = np.where(rng.random(400) < 0.1, 0.5, 3.0) * R
        radii.update(state, M, Phi, r_pred, S)
        held.append(state.held.mean())
    return float(np.mean(held[10:]))


def test_outliers_keep_the_hold():
    """With the last prediction a pixel is released in every pass its
    prediction is the outlier (10 %); with the mixture (1/r^2 = 0.9/9 + 0.1*4
    = 0.5 on average) only where outliers cluster in recent passes (measured
    0.962 held)."""
    last, mix = _held_fraction(False), _held_fraction(True)
    assert last == pytest.approx(0.9, abs=0.02)         # binomial 1 sigma 0.002
    assert mix == pytest.approx(0.962, abs=0.02)
    # A sharp share well above beta still releases: predictions 0.2 R in 30 %.
    st = RenderSettings()
    radii = Radii(st, None, 1.0, True, None, 1, 1)
    radii.keep_mixture = True
    state = PixelState.zeros(1, sector_cells=radii.sector_cells)
    state.R2[:] = 1.0
    M, Phi = np.full(1, 100.0), np.ones((1, 3))
    S = np.full((1, radii.sector_cells), 100.0 / radii.sector_cells)
    for k in range(40):
        radii.update(state, M, Phi, np.array([0.2 if k % 10 < 3 else 3.0]) * np.sqrt(state.R2), S)
    assert not state.held[0]
