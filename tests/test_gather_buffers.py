"""hashgrid.GatherBuffers: per-thread gather rows allocated once and reused by
every photon chunk, folded at the touched visible points only.

The reference is the per-chunk path the photon pass used before (a dense
GatherResult per chunk, added with numpy: ``acc.M += g.M``,
``acc.Phi += g.Phi_sum * (albedo / pi)``, ``acc.r_pred = minimum(...)``).
The fold sums the thread rows in the same order and scales with the same
float64 operations, so every sum is compared EXACTLY (no tolerance).
"""
import numpy as np
import pytest

from core.sppm import hashgrid as hg
from test_hashgrid import _args, random_case

CHUNKS = 4


def _chunked(c, n_chunks):
    """The case's photons split into n_chunks consecutive chunks."""
    P = c["ph_pos"].shape[0]
    for k in range(n_chunks):
        s = slice(k * P // n_chunks, (k + 1) * P // n_chunks)
        yield {**c, **{key: c[key][s] for key in
                       ("ph_pos", "ph_ng", "ph_wi", "ph_power", "ph_rpred")}}


def _sums(K):
    return np.zeros(K), np.zeros((K, 3)), np.full(K, np.inf), np.zeros((K, hg.SECTOR_CELLS))


@pytest.mark.parametrize("parallel,masked,albedo_dtype", [(False, False, np.float64),
                                                          (True, True, np.float32)])
def test_buffers_equal_the_per_chunk_path(parallel, masked, albedo_dtype):
    # float32 albedo: numpy divides it by pi in float32 (NEP 50), the fold too.
    c = random_case(7, K=1500, P=12_000)
    K = c["vp_pos"].shape[0]
    grid = hg.build_grid(c["vp_pos"], c["vp_R"], c["active"])
    albedo = np.random.default_rng(1).uniform(0.05, 0.95, (K, 3)).astype(albedo_dtype)
    mask = c["vp_const"] if masked else None
    # Reference: one dense result per chunk, added as photon_pass did.
    M0, Phi0, r0, S0 = _sums(K)
    pairs0 = []
    for ch in _chunked(c, CHUNKS):
        g = hg.gather(grid, *_args(ch), want_freq_pairs=True, parallel=parallel, sectors=True)
        M0 += g.M
        S0 += g.sectors
        Phi0 += g.Phi_sum * (albedo / np.pi)
        r0 = np.minimum(r0, g.rpred_min if mask is None else np.where(mask, g.rpred_min, np.inf))
        pairs0.append((g.pair_vp, g.pair_ph, g.freq_pair_vp, g.freq_pair_ph))
    # Buffers: the same chunks, folded into the sums after each chunk.
    buf = hg.GatherBuffers(K, sectors=True, threads=2)
    rows = (buf.M, buf.Phi, buf.rmin, buf.S, buf.touched)
    M1, Phi1, r1, S1 = _sums(K)
    touched = []
    for k, ch in enumerate(_chunked(c, CHUNKS)):
        g = hg.gather(grid, *_args(ch), want_freq_pairs=True, parallel=parallel, buffers=buf)
        assert g.M is None and g.Phi_sum is None and g.sectors is None
        for a, b in zip((g.pair_vp, g.pair_ph, g.freq_pair_vp, g.freq_pair_ph), pairs0[k]):
            np.testing.assert_array_equal(a, b)
        touched.append(int(buf.n_touched.sum()))
        buf.fold(M1, Phi1, albedo, np.pi, r1, mask, S1)
        # Folded rows are zero again (rmin inf), ready for the next chunk.
        assert not buf.M.any() and not buf.Phi.any() and not buf.S.any()
        assert np.all(buf.rmin == np.inf) and not buf.n_touched.any()
    assert buf.allocations == 1
    assert all(a is b for a, b in zip(rows, (buf.M, buf.Phi, buf.rmin, buf.S, buf.touched)))
    for got, exp in ((M1, M0), (Phi1, Phi0), (r1, r0), (S1, S0)):
        assert np.array_equal(got, exp), np.abs(got - exp).max()
    # The case exercises what a fold adds: counts, Lambert flux, frequency
    # radii, sectors; each chunk touches a subset of the points only.
    assert M0.sum() > 4000 and np.isfinite(r0).sum() > 200 and (Phi0 > 0).any()
    assert all(0 < t < 2 * K for t in touched) and min(touched) < K
