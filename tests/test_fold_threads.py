"""hashgrid.GatherBuffers.fold: a pixel-sized sweep by VP ranges in threads
gives the serial sweep's sums bit for bit."""
import numpy as np

from core.sppm import hashgrid as hg


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
