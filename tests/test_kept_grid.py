"""core.kept.KeptBuffer and hashgrid.build_grid(..., kept=): the grid's table
and entries reused from one build to the next, the same grid bit for bit, and
never while a grid built on them is still referenced."""
import numpy as np

from core.kept import KeptBuffer
from core.sppm import hashgrid as hg


def test_kept_buffer_reused_only_when_unreferenced():
    b = KeptBuffer()
    a = b.get(100, np.int32)
    del a
    a = b.get(90, np.int32)
    assert (b.reused, b.allocations) == (1, 1) and a.size == 90
    v = a[3:]
    del a
    a = b.get(90, np.int32)              # a view of the last one is alive
    assert (b.reused, b.allocations) == (1, 2)
    del a, v
    assert b.get(90 + 90 // 16, np.int32).size == 95 and b.reused == 2   # headroom
    assert b.get(10, np.int64).dtype == np.int64 and b.allocations == 3


def _grid_arrays(g):
    return (g.cell_start.copy(), g.vp_ids.copy(), g.n_slots, g.dense)


def test_kept_grid_equals_fresh_builds():
    rng = np.random.default_rng(1)
    kept = hg.KeptGrid()
    held = None
    for k, (K, layout) in enumerate([(4000, "hash"), (3000, "hash"), (5000, "dense"),
                                     (5000, "hash")]):
        pos = rng.uniform(0, 1, (K, 3))
        R = rng.uniform(0.01, 0.04, K)
        act = rng.random(K) < 0.9
        g = hg.build_grid(pos, R, act, layout=layout, kept=kept)
        fresh = hg.build_grid(pos, R, act, layout=layout)
        for x, y in zip(_grid_arrays(g), _grid_arrays(fresh)):
            assert np.array_equal(x, y)
        if k == 2:
            held, snap = g, _grid_arrays(g)      # kept alive through the next build
        del g, fresh
    for x, y in zip(_grid_arrays(held), snap):
        assert np.array_equal(x, y)
    # build 2 reused build 1's arrays (fewer VPs); build 4 did not reuse
    # build 3's (held)
    assert kept.cell_start.reused + kept.cell_start.allocations == 4
    assert kept.vp_ids.reused >= 1 and kept.cell_start.reused >= 1
    assert kept.vp_ids.allocations >= 2 and kept.cell_start.allocations >= 2


def _filled_buffers(K, seed):
    rng = np.random.default_rng(seed)
    b = hg.GatherBuffers(K, sectors=True, threads=2)
    hit = rng.random((2, K)) < 0.5
    b.M[...] = np.where(hit, rng.integers(1, 9, (2, K)), 0)
    b.Phi[...] = np.where(hit[..., None], rng.uniform(size=(2, K, 3)), 0.0)
    b.rmin[...] = np.where(hit, rng.uniform(size=(2, K)), np.inf)
    b.S[...] = np.where(hit[..., None], rng.integers(0, 5, (2, K, hg.SECTOR_CELLS)), 0)
    for t in range(2):
        v = np.flatnonzero(hit[t])
        b.touched[t, :v.size] = v
        b.n_touched[t] = v.size
    b.n_used = 2
    return b


def test_threaded_fold_sweep_equals_the_serial_one(monkeypatch):
    # GatherBuffers.fold's sweep by VP ranges in threads (from PARALLEL_MIN_VPS
    # VPs): the same sums, bit for bit, and the rows zeroed.
    K = 5000
    albedo = np.random.default_rng(2).uniform(0.05, 0.95, (K, 3)).astype(np.float32)
    out = []
    for min_vps in (10 ** 9, 1):
        monkeypatch.setattr(hg, "PARALLEL_MIN_VPS", min_vps)
        b = _filled_buffers(K, 5)
        M, Phi, r, S = np.zeros(K), np.full((K, 3), 0.25), np.full(K, 0.7), np.zeros((K, 8))
        b.fold(M, Phi, albedo, np.pi, r, None, S)
        assert not b.M.any() and not b.Phi.any() and np.all(b.rmin == np.inf)
        assert not b.S.any() and not b.n_touched.any()
        out.append((M, Phi, r, S))
    assert out[0][0].sum() > 0
    for x, y in zip(*out):
        assert np.array_equal(x, y)
