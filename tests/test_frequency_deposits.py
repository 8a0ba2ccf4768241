"""A frequency photon's first k counted deposits (``PhotonTracer.freq_deposits``,
``kernels.ChainParams.deposits``; docs/frequency.md "Fewer marched deposits").

With ``freq_deposits = k`` a frequency photon predicts a radius at its first
k deposits that are not gated as unreached, and is traced as a classic
photon after them (no march, no spectrum, r = NaN).  Specular bounces
deposit nothing, so they do not count: a caustic photon keeps its spectrum
through its delta chain to its first diffuse deposit.
"""
import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from test_photon_kernels import _tracer, cornell, glass_mirror  # noqa: E402


def _rows(dep, predicted=None):
    """Deposit rows (position, power, bounce[, radius key]) sorted; predicted
    True / False: only those with / without a radius; None: all, no radius."""
    k = np.ones(dep["rpred"].shape[0], bool)
    cols = [dep["p"], dep["power"], dep["bounce"][:, None].astype(np.float64)]
    if predicted is not None:
        k = ~np.isnan(dep["rpred"]) if predicted else np.isnan(dep["rpred"])
        cols.append(dep["rpred"][:, None])
    rows = np.concatenate([c[k] for c in cols], axis=1)
    return rows[np.lexsort(rows[:, ::-1].T)]


def _trace(tr, k, n, nf):
    tr.freq_deposits = k
    return tr.trace(n, nf, np.random.default_rng(17))


@pytest.mark.parametrize("nf", [5_000, 500])       # one batch; traced again (2.5 %)
def test_first_k_deposits_are_the_full_chains_first_k(nf):
    """Cornell box (Lambert walls: every hit after the first deposits, the
    light's segment deposits nothing): with k = 1 (2) the predicted deposits
    are exactly the full chain's at path vertex 1 (1 and 2), bit for bit, and
    every photon deposits what it deposits without spectra."""
    tr = _tracer(cornell(), use_frequency=True)
    n = 20_000
    full = _trace(tr, 0, n, nf)
    plain = _rows(_trace(tr, 0, n, 0))
    f = _rows(full, True)
    for k in (1, 2):
        dep = _trace(tr, k, n, nf)
        np.testing.assert_array_equal(_rows(dep), plain)      # the same photons
        want = f[f[:, 6] <= k]                                # vertices 1..k
        got = _rows(dep, True)
        np.testing.assert_array_equal(got, want)
        assert got.shape[0] <= k * nf
        # the classic deposits of the frequency photons carry no spectrum
        cl = np.isnan(dep["rpred"])
        assert not dep["spec"][cl].any()
    # vertex 1 holds about 0.8 of the frequency photons (the rest escape the
    # open box or are absorbed), vertex 2 fewer: k = 1 marches about a third
    # of the predicted deposits of the full chain here
    n1 = np.count_nonzero(f[:, 6] == 1)
    assert 0.6 * nf < n1 <= nf
    assert n1 < 0.6 * f.shape[0]


def test_specular_bounces_do_not_count():
    """Mirror and glass deposit nothing: with k = 1 the predicted deposits
    are the full chain's first deposit of each photon, some of them after a
    delta chain (path vertex > 1, the caustic deposits)."""
    tr = _tracer(glass_mirror(), use_frequency=True)
    n, nf = 20_000, 5_000
    full = _trace(tr, 0, n, nf)
    dep = _trace(tr, 1, n, nf)
    np.testing.assert_array_equal(_rows(dep), _rows(full))
    got, f = _rows(dep, True), _rows(full, True)
    assert got.shape[0] <= nf
    # each predicted deposit is one of the full chain's, bit for bit
    fs = {tuple(r) for r in f}
    assert all(tuple(r) in fs for r in got)
    after_delta = np.count_nonzero(got[:, 6] > 1)
    assert after_delta > 0.02 * got.shape[0]
    # every vertex-1 prediction of the full chain is a first deposit: all kept
    np.testing.assert_array_equal(got[got[:, 6] == 1], f[f[:, 6] == 1])
