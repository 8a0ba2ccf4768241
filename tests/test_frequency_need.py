"""Frequency photons for the undecided pixels (docs/method.md "Frequency
photons for the undecided pixels").

Pass k traces photons_per_pass x frequency_fraction x k^-frequency_decay x
need frequency photons, need = photon_pass.frequency_need(state): the share of
the pixels that counted photons in the last pass and are not held, at least
FREQUENCY_NEED_FLOOR.  Asserted: the share exactly on hand-made states, the
chunks' n_freq it gives, its fall in a render of a shadow edge (measured),
the same image from the same seed and after a resume, and that the wrong
prediction of tests/test_holds.py::test_wrong_prediction_still_converges
(which converges, asserted there) runs at the floor.
"""
import numpy as np
import pytest

from core.render import Renderer
from core.settings import RenderSettings
from core.sppm.photon_pass import FREQUENCY_NEED_FLOOR, frequency_need
from core.sppm.state import PixelState

from test_holds import _shadow_edge_scene


def _state(M_last, held):
    st = PixelState.zeros(len(M_last))
    st.M_last[:], st.held[:] = M_last, held
    return st


def test_need_counts_the_active_pixels_not_held():
    """Of 5 pixels 4 counted photons, 1 of them held: 3/4; pixel 4 (no
    photon, held is False there anyway) is left out; a state without photons
    needs every frequency photon; all held: the floor."""
    st = _state([3.0, 1.0, 0.0, 2.0, 5.0], [True, False, False, False, False])
    assert frequency_need(st) == 0.75
    assert frequency_need(_state([0.0, 0.0], [False, False])) == 1.0
    assert frequency_need(_state([1.0, 2.0], [True, True])) == FREQUENCY_NEED_FLOOR


def _edge_renderer(seed=0, **over):
    scene, _ = _shadow_edge_scene(res=24)
    st = RenderSettings(integrator="PHOTON", photons_per_pass=20_000, photons_for_direct=True,
                        initial_radius_px=4.0, seed=seed, max_passes=100, **over)
    return Renderer(scene, st, log=lambda s: None)


def _schedule(r, passes):
    """(n_freq of every pass, need after every pass, image after the last)."""
    n_freq, need = [], []
    for _ in range(passes):
        n_freq.append(sum(f for _, f in r.photon_pass.chunks()))
        res = r.step()
        need.append(frequency_need(r.state))
    return n_freq, need, res.image


def test_need_falls_as_the_pixels_decide():
    """Shadow edge, 24x24, 20k photons per pass, seed 0 (measured): the share
    of undecided pixels falls from 1 before pass 1 to 0.545 after it and
    0.19-0.25 from pass 6 on (the pixels at the edge, where the counts
    reject the holds, and the dark ones that count too few photons); the
    chunks carry round(20,000 x 0.25 x k^-0.5 x need) frequency photons."""
    n_freq, need, _ = _schedule(_edge_renderer(), 8)
    assert n_freq[0] == 5000
    for k in range(2, 9):
        assert n_freq[k - 1] == int(round(20_000 * 0.25 * k ** -0.5 * need[k - 2]))
    assert 0.45 < need[0] < 0.65
    assert all(0.15 < v < 0.3 for v in need[5:])
    assert n_freq[7] < 0.3 * 5000 / np.sqrt(8)          # 364 of 1768


def test_same_seed_same_image_and_resume():
    """The schedule reads the state's bits only: the same seed gives the same
    image, and so does a render resumed from a checkpoint after pass 3."""
    _, need_a, img_a = _schedule(_edge_renderer(), 6)
    _, need_b, img_b = _schedule(_edge_renderer(), 6)
    assert need_a == need_b
    assert np.array_equal(img_a, img_b)
    r = _edge_renderer()
    _schedule(r, 3)
    d = r.state_dict()
    r2 = _edge_renderer()
    r2.load_state(d)
    _, need_c, img_c = _schedule(r2, 3)
    assert need_c == need_a[3:]
    assert np.array_equal(img_c, img_a)


def test_wrong_prediction_runs_at_the_floor():
    """tests/test_holds.py's forced 10 m prediction (holds unverified): every
    pixel with photons holds from pass 1, so its passes trace the floor's
    share of frequency photons; test_wrong_prediction_still_converges checks
    that render still converges."""
    r = _edge_renderer(verify_holds=False, cap_radius_at_edges=False, clip_kernel=False)
    r.radii.predicted = lambda rmin, rh: np.where(np.isfinite(rmin), 10.0, rmin)
    n_freq, need, _ = _schedule(r, 3)
    assert need == [FREQUENCY_NEED_FLOOR] * 3
    assert n_freq[1:] == [int(round(20_000 * 0.25 * k ** -0.5 * FREQUENCY_NEED_FLOOR))
                          for k in (2, 3)]
