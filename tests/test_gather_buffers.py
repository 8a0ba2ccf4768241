"""hashgrid.GatherBuffers: per-thread gather rows allocated once and reused by
every photon chunk, folded at the touched visible points only.

The reference is the per-chunk path the photon pass used before (a dense
GatherResult per chunk, added with numpy: ``acc.M += g.M``,
``acc.Phi += g.Phi_sum * (albedo / pi)``, ``acc.r_pred = minimum(...)``).
The fold sums the thread rows in the same order and scales with the same
float64 operations, so every sum is compared EXACTLY (no tolerance).
"""
import time
import types

import numpy as np
import pytest

from analytic_scenes import look_down_ortho, quad, translate
from core.render import Renderer
from core.scene.model import DIFFUSE, GLOSSY, Light, Lobe, Material, make_scene
from core.settings import RenderSettings
from core.sppm import hashgrid as hg
from test_hashgrid import _args, random_case

CHUNKS = 4


def per_chunk_trace_gather(self, pg, n, n_freq, rng, acc):
    """PhotonPass._trace_gather before hashgrid.GatherBuffers (the reference
    here and bench/bench_render.py --gather's "before"): one dense
    GatherResult per chunk, pixel-sized thread rows summed and added with numpy."""
    vp = pg.vp
    dep = self._trace(n, n_freq, rng)
    if dep is None:
        return
    t1 = time.perf_counter()
    g = hg.gather(pg.grid, dep["p"], dep["ng"], dep["wi"], dep["power"], dep["rpred"],
                  vp.p, vp.ng, pg.R2, vp.const, cos_ng=-1.0,
                  want_freq_pairs=pg.want_pairs and n_freq > 0, sectors=self.sectors)
    acc.M += g.M
    if acc.sectors is not None:
        acc.sectors += g.sectors
    acc.Phi += g.Phi_sum * (vp.albedo / np.pi)
    acc.r_pred = np.minimum(acc.r_pred, g.rpred_min if self.receivers is None
                            else np.where(vp.const, g.rpred_min, np.inf))
    self._add_pairs(vp, dep, g, acc)      # the pairs: the same code
    self.stage_seconds["gather"] += time.perf_counter() - t1


def _chunked(c, n_chunks):
    """The case's photons split into n_chunks consecutive chunks."""
    P = c["ph_pos"].shape[0]
    for k in range(n_chunks):
        s = slice(k * P // n_chunks, (k + 1) * P // n_chunks)
        yield {**c, **{key: c[key][s] for key in
                       ("ph_pos", "ph_ng", "ph_wi", "ph_power", "ph_rpred")}}


def _sums(K):
    return np.zeros(K), np.zeros((K, 3)), np.full(K, np.inf), np.zeros((K, hg.SECTOR_CELLS))


@pytest.mark.parametrize("parallel,masked,albedo_dtype,fold",
                         [(False, False, np.float64, "lists"), (True, True, np.float32, "lists"),
                          (True, False, np.float32, "sweep")])
def test_buffers_equal_the_per_chunk_path(parallel, masked, albedo_dtype, fold, monkeypatch):
    # float32 albedo: numpy divides it by pi in float32 (NEP 50), the fold too.
    # fold: the touched lists, or a sweep of every VP.
    monkeypatch.setattr(hg, "FOLD_SWEEP_FRACTION", 0 if fold == "lists" else 10 ** 9)
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
    # A gather left unfolded (an interrupted pass) is cleared, not carried.
    hg.gather(grid, *_args(c), parallel=parallel, buffers=buf)
    assert buf.M.any()
    buf.clear()
    assert not buf.M.any() and not buf.S.any() and np.all(buf.rmin == np.inf)
    for got, exp in ((M1, M0), (Phi1, Phi0), (r1, r0), (S1, S0)):
        assert np.array_equal(got, exp), np.abs(got - exp).max()
    # The case exercises what a fold adds: counts, Lambert flux, frequency
    # radii, sectors; each chunk touches a subset of the points only.
    assert M0.sum() > 4000 and np.isfinite(r0).sum() > 200 and (Phi0 > 0).any()
    assert all(0 < t < 2 * K for t in touched) and min(touched) < K


def _floor_scene(res=24):
    """A floor, half Lambert (Phi_sum), half Lambert + GGX (pairs, receivers),
    in an open box of Lambert walls (photons deposit after a bounce) under a
    square area light."""
    tris = quad((-0.75, 0, 0), (0.75, 0, 0), (0, 1.5, 0)) + \
        quad((0.75, 0, 0), (0.75, 0, 0), (0, 1.5, 0))
    for c, a, b in (((1.5, 0, 0.75), (0, 1.5, 0), (0, 0, 0.75)),
                    ((-1.5, 0, 0.75), (0, 0, 0.75), (0, 1.5, 0)),
                    ((0, 1.5, 0.75), (0, 0, 0.75), (1.5, 0, 0)),
                    ((0, -1.5, 0.75), (1.5, 0, 0), (0, 0, 0.75))):
        tris += quad(c, a, b)
    mats = [Material("matte", (Lobe(DIFFUSE, (0.7, 0.6, 0.5)),)),
            Material("glossy", (Lobe(DIFFUSE, (0.4, 0.4, 0.4)),
                                Lobe(GLOSSY, (0.5, 0.5, 0.5), roughness=0.4)))]
    light = Light("area", "AREA", (50.0, 50.0, 50.0), translate(0, 0, 1.0),
                  shape="SQUARE", size=1.0)
    return make_scene(tris, mats, [light], look_down_ortho(3.0, 2.0, res),
                      tri_mat=[0, 0, 1, 1] + [0] * 8)


@pytest.mark.parametrize("frequency", [True, False])
def test_render_equals_the_per_chunk_path(frequency):
    # Multi-chunk passes (3 chunks of 4000 photons, the last one smaller) through
    # the renderer: every sum of the pass (M, Phi, radius histograms, spectrum,
    # sector counts) is the same bits, so the images and AOVs are identical.
    st = RenderSettings(integrator="PHOTON", max_passes=2, time_limit=0.0, photons_per_pass=10_000, seed=3,
                        use_frequency=frequency, frequency_estimator="QUANTILE",
                        aov_spectrum=frequency, aov_photon_count=True, aov_radius=True)
    out = []
    for old in (False, True):
        r = Renderer(_floor_scene(), st, log=lambda s: None)
        pp = r.photon_pass
        pp.chunk = 4000
        assert len(pp.chunks()) == 3
        if old:
            pp._trace_gather = types.MethodType(per_chunk_trace_gather, pp)
        out.append((r.run(), pp.gather_buffers))
    (new, buf), (ref, _) = out
    assert buf is not None and buf.allocations == 1    # once per render
    assert buf.with_sectors == frequency               # verify_holds reads them
    np.testing.assert_array_equal(new.image, ref.image)
    assert new.aovs.keys() == ref.aovs.keys() and len(new.aovs) >= 2
    for k in new.aovs:
        np.testing.assert_array_equal(new.aovs[k], ref.aovs[k], err_msg=k)
    assert np.asarray(new.image).max() > 0


@pytest.mark.parametrize("K", [1500, 3 * 1024])
def test_vp_records_equal_the_columns(K, monkeypatch):
    # The compiled records (hashgrid._vp_records: numba's allocator, VP
    # ranges in threads from PARALLEL_MIN_VPS) are numpy's column copies.
    monkeypatch.setattr(hg, "PARALLEL_MIN_VPS", 2048)
    rng = np.random.default_rng(K)
    pos, ng = rng.normal(size=(K, 3)), rng.normal(size=(K, 3))
    R2, const = rng.uniform(0, 1e-3, K), rng.random(K) < 0.7
    pos[3, 1], R2[5] = np.nan, np.inf
    ref = np.empty((K, 8))
    ref[:, 0:3], ref[:, 3], ref[:, 4:7], ref[:, 7] = pos, R2, ng, const
    rec = hg._vp_records(pos, ng, R2, const)
    assert rec.dtype == np.float64 and rec.shape == (K, 8) and rec.flags.c_contiguous
    assert np.array_equal(rec, ref, equal_nan=True)


@pytest.mark.parametrize("n_chunks", [3, 5])
def test_merge_sort_in_runs_is_the_stable_sort(n_chunks):
    # The gather's merge sort of a large table's slots (runs sorted in the
    # threads, merged pairwise: hashgrid._merge_sorted_runs) gives the
    # one-run order, slots and rows bit for bit with any number of runs
    # (tests/test_photon_sort.py: 1 and 2 runs against numpy's stable sort).
    from test_photon_sort import _case, _sorted
    grid, ph = _case(20, 4000)
    assert grid.n_slots > hg.COUNT_SORT_SLOTS_PER_PHOTON * 4000
    one = _sorted(grid, ph, 1)
    for got, exp in zip(_sorted(grid, ph, n_chunks), one):
        assert got.dtype == exp.dtype and np.array_equal(got, exp, equal_nan=True)
    key = np.random.default_rng(n_chunks).integers(0, 40, 500)      # many ties
    runs = np.empty(500, np.int64)
    for c in range(n_chunks):
        hg._argsort_run(key, c * 500 // n_chunks, (c + 1) * 500 // n_chunks, runs)
    assert np.array_equal(hg._merge_sorted_runs(key, runs, n_chunks),
                          np.argsort(key, kind="stable"))
