"""hashgrid._count_range tests the sorted photons by runs of one slot,
candidate by candidate, keeping a candidate's sums in registers over the run.

The reference is the count pass it replaced (``count_photon_by_photon``
below: each photon against each candidate of its slot, the sums read and
written at every accepted photon).  Phi receives the same powers in the same
order, rmin is a minimum, M and S are counts: every output is compared
EXACTLY, on ranges that cut slot runs (the threads' split), with sector
counts, packed clips (rule (5)), frequency photons and cells of more than 64
entries (no hit mask there), runs shorter than run_min (photon by photon)
and longer than 64 (cut), every run_min.  Only the order of the touched list may differ.
"""
import itertools
import math

import numpy as np
import pytest
from numba import njit

from core.sppm import hashgrid as hg
from test_hashgrid import _args, random_case


@njit(cache=True)
def count_photon_by_photon(q0, q1, slot, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                           vp_rec, vp_clip, cos_ng, cell_start, vp_ids,
                           M, Phi, rmin, hitmask, n_pair, n_freq, S, touched, n_touched):
    """hashgrid._count_range as it was before the runs (same arguments)."""
    one = np.uint64(1)
    with_sectors = S.shape[1] > 0
    track = touched.shape[0] > 0
    clipped = vp_clip.shape[0] > 0
    for p in range(q0, q1):
        s = slot[p]
        e0 = cell_start[s]
        e1 = cell_start[s + 1]
        x = np.float64(ph_pos[p, 0])
        y = np.float64(ph_pos[p, 1])
        z = np.float64(ph_pos[p, 2])
        r = ph_rpred[p]
        is_freq = not math.isnan(r)
        npair = 0
        nfreq = 0
        mask = np.uint64(0)
        for e in range(e0, e1):
            v = vp_ids[e]
            rx, ry, rz, r2, nvx, nvy, nvz, const = hg._vp_record(vp_rec, v)
            code = vp_clip[v] if clipped else hg.CLIP_CLEAR
            if not hg._accepts(rx, ry, rz, r2, nvx, nvy, nvz, code, x, y, z,
                               np.float64(ph_wi[p, 0]), np.float64(ph_wi[p, 1]),
                               np.float64(ph_wi[p, 2]), np.float64(ph_ng[p, 0]),
                               np.float64(ph_ng[p, 1]), np.float64(ph_ng[p, 2]), cos_ng):
                continue
            M[v] += 1
            if track and M[v] == 1:
                touched[n_touched[0]] = v
                n_touched[0] += 1
            if with_sectors:
                S[v, hg._sector_cell(rx, ry, rz, r2, nvx, nvy, nvz, x, y, z)] += 1
            if const != 0.0:
                Phi[v, 0] += ph_power[p, 0]
                Phi[v, 1] += ph_power[p, 1]
                Phi[v, 2] += ph_power[p, 2]
            else:
                npair += 1
            if is_freq:
                nfreq += 1
                if r < rmin[v]:
                    rmin[v] = r
            if e - e0 < 64:
                mask |= one << np.uint64(e - e0)
        hitmask[p] = mask
        n_pair[p] = npair
        n_freq[p] = nfreq


def _random_clips(rng, K, share):
    """(K,) uint64 packed clips: a share of the points clipped, each wedge's
    byte open (CLIP_OPEN) or a fraction of the radius."""
    b = rng.integers(0, 256, (K, hg.CLIP_WEDGES)).astype(np.uint64)
    b[rng.random((K, hg.CLIP_WEDGES)) < 0.5] = hg.CLIP_OPEN
    codes = np.zeros(K, np.uint64)
    for k in range(hg.CLIP_WEDGES):
        codes |= b[:, k] << np.uint64(8 * k)
    return np.where(rng.random(K) < share, codes, hg.CLIP_CLEAR)


def _run(kernel, args, K, n, splits, sectors, seeded_phi, run_min=None):
    M = np.zeros(K, np.int32)
    Phi = seeded_phi.copy()               # earlier chunks' sums: the adds start from them
    rmin = np.full(K, np.inf)
    S = np.zeros((K, hg.SECTOR_CELLS if sectors else 0), np.int32)
    touched = np.empty(K, np.int32)
    n_touched = np.zeros(1, np.int64)
    hitmask = np.full(n, 7, np.uint64)    # garbage: every row must be written
    n_pair = np.full(n, -1, np.int32)
    n_freq = np.full(n, -1, np.int32)
    for q0, q1 in zip(splits[:-1], splits[1:]):
        kernel(q0, q1, *args, M, Phi, rmin, hitmask, n_pair, n_freq, S, touched, n_touched,
               *(() if run_min is None else (run_min,)))
    return M, Phi, rmin, S, hitmask, n_pair, n_freq, touched[:n_touched[0]]


@pytest.mark.parametrize("seed,log2_table,sectors,clip_share", [
    (0, None, True, 0.3), (1, 3, True, 0.0), (2, None, False, 0.5), (3, 6, True, 1.0)])
def test_runs_equal_photon_by_photon(seed, log2_table, sectors, clip_share):
    c = random_case(seed, K=800, P=5000, radius_spread=30.0)
    kw = {} if log2_table is None else {"log2_table": log2_table}
    grid = hg.build_grid(c["vp_pos"], c["vp_R"], c["active"], **kw)
    P, K, ph, vp = hg._prepare(*_args(c))
    order, slot, pos, ng, wi, power, rpred, _, _, _ = hg._sorted_photons(
        hg._sort_photons_serial, ph, grid, 1)
    n = slot.shape[0]
    rng = np.random.default_rng(seed)
    clip = (np.zeros(0, np.uint64) if clip_share == 0.0
            else np.ascontiguousarray(_random_clips(rng, K, clip_share)))
    args = (slot, pos, ng, wi, power, rpred, hg._vp_records(*vp), clip, 0.2,
            grid.cell_start, grid.vp_ids)
    phi0 = rng.exponential(size=(K, 3))
    # one range, and ranges cut inside slot runs (as the threads' split does)
    # and every run by bit mask (run_min 1), the runs of COUNT_RUN_MIN or
    # more photons, none (65: runs are cut at 64)
    for splits, run_min in itertools.product(
            ([0, n], [0, n // 3, n // 3 + 1, 2 * n // 3, n]), (1, hg.COUNT_RUN_MIN, 65)):
        got = _run(hg._count_range, args, K, n, splits, sectors, phi0, run_min)
        ref = _run(count_photon_by_photon, args, K, n, splits, sectors, phi0)
        for name, a, b in zip(("M", "Phi", "rmin", "S", "hitmask", "n_pair", "n_freq"),
                              got[:7], ref[:7]):
            np.testing.assert_array_equal(a, b, err_msg=name)
        # the same points touched, each once
        assert sorted(got[7].tolist()) == sorted(ref[7].tolist())
        assert len(set(got[7].tolist())) == got[7].size
    # the case exercises what it claims: counts, pairs, frequency photons,
    # runs of a slot shorter than COUNT_RUN_MIN (photon by photon) and
    # longer (the bit mask; longer than 64 in the hash case: cut), and (hash
    # case) cells of more than 64 entries
    M, _, rmin, S = ref[:4]
    assert M.sum() > 1000 and ref[5].sum() > 200 and np.isfinite(rmin).sum() > 100
    runs = np.diff(np.flatnonzero(np.r_[True, np.diff(slot) != 0, True]))
    assert (runs >= hg.COUNT_RUN_MIN).sum() >= 8
    if log2_table is None:           # the hashed cases' 8 and 64 slots: long runs only
        assert (runs < hg.COUNT_RUN_MIN).sum() > 50
    if sectors:
        np.testing.assert_array_equal(S.sum(axis=1), M)
    if log2_table == 3:
        assert np.diff(grid.cell_start).max() > 64 and runs.max() > 64


def test_run_min_by_the_mean_run():
    """The bit masks only where a slot holds COUNT_RUN_MIN photons on average."""
    k = hg.COUNT_RUN_MIN
    assert hg._run_min(np.repeat(np.arange(10), k)) == k
    assert hg._run_min(np.repeat(np.arange(10), k - 1)) == 65
    assert hg._run_min(np.zeros(0, np.int64)) == 65
