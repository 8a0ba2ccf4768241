"""core.sppm.hashgrid._sort_photons: the gather's photon sort, both ways.

A counting sort over the table's slots (few slots a photon) and a merge sort
of the photons' slots (a large table: no (n_slots,) array per chunk) must
both give numpy's stable sort by slot of the photons inside the grid: the
same order, slots and copied rows, bit for bit, for 1 and 2 threads.
"""
import numpy as np
import pytest

from core.kept import KeptBuffers
from core.sppm import hashgrid as hg


def _case(log2_table, P, seed=3):
    rng = np.random.default_rng(seed)
    K = 3000
    vp = rng.uniform(0, 1, (K, 3))
    grid = hg.build_grid(vp, np.full(K, 0.03), np.ones(K, bool), log2_table=log2_table)
    # photons near the VPs (many share a slot) and some outside the grid
    ph_pos = (vp[rng.integers(0, K, P)] + rng.normal(scale=0.02, size=(P, 3))).astype(np.float32)
    ph_pos[::17] += 5.0
    ph_ng = rng.normal(size=(P, 3)).astype(np.float32)
    ph_wi = rng.normal(size=(P, 3)).astype(np.float32)
    power = rng.uniform(size=(P, 3))
    rpred = np.where(rng.random(P) < 0.3, rng.uniform(size=P), np.nan)
    return grid, (ph_pos, ph_ng, ph_wi, power, rpred)


def _sorted(grid, ph, n_chunks, kept=None):
    f = hg._sort_photons if n_chunks > 1 else hg._sort_photons_serial
    return hg._sorted_photons(f, ph, grid, n_chunks, kept)[:7]


@pytest.mark.parametrize("log2_table, P", [(12, 4000),      # counting sort: 1 slot a photon
                                           (20, 4000)])     # merge sort: 262 slots a photon
def test_photon_sort_is_the_stable_sort_by_slot(log2_table, P):
    grid, ph = _case(log2_table, P)
    counting = grid.n_slots <= hg.COUNT_SORT_SLOTS_PER_PHOTON * P
    assert counting == (log2_table == 12)
    ps = np.empty(P, np.int64)
    hg._photon_slots(0, P, ph[0], grid.origin, grid.inv_h, grid.lo, grid.hi, False,
                     1, 1, 1, 64 - grid.log2_table, grid.cell_start, ps)
    inside = np.flatnonzero(ps >= 0)
    exp = inside[np.argsort(ps[inside], kind="stable")]
    assert 0 < exp.size < P and np.unique(ps[inside]).size < exp.size   # shared slots
    kept = KeptBuffers()           # the gather's kept buffer, reused: the same rows
    for n_chunks, kb in ((1, None), (2, None), (2, kept), (1, kept)):
        order, slot, pos, ng, wi, power, rpred = _sorted(grid, ph, n_chunks, kb)
        assert np.array_equal(order, exp) and order.dtype == np.int32
        assert np.array_equal(slot, ps[exp])
        for got, src in zip((pos, ng, wi, power, rpred), ph):
            # float64 columns of one record a photon (float32 widened exactly)
            assert got.dtype == np.float64
            np.testing.assert_array_equal(got, src[exp].astype(np.float64))
