"""The compiled per-pixel stages of a pass against their references.

What is asserted, and why the tolerances are zero:
- Camera rays (core.scene.camera_kernels ``_pinhole_range``) equal
  ``CameraModel.generate(..., compiled=False)`` bit for bit: the same
  operations in the same order, and the rotation written as the fused
  multiply-adds of OpenBLAS's dgemm kernel (every x86-64 with FMA).
  Perspective with shift and a non-square pixel aspect, orthographic, a
  filter of width 0; the one-thread and the split (PARALLEL_MIN) paths; the
  thin lens takes the numpy path in both.
- The grid build (core.sppm.hashgrid ``_active_extent``, ``_bbox_cells``,
  ``_insert_parallel``: each VP's slots by VP ranges, then a counting sort by
  slot ranges) gives the grid of the numpy extent and serial two-pass
  insertion it replaced (tests/oracle_grid.py) exactly (minima, maxima,
  the same per-VP arithmetic, integer counts: no rounding): a dense
  grid, hash tables small enough that most cells collide, a VP whose sphere
  covers more than ``_DEDUP_SCAN`` slots of a small table (the sort path of
  the deduplication), inactive and non-finite VPs, on one thread and split
  (PARALLEL_MIN_VPS, lowered for the test).
- The PPM rule's update (core.sppm.update ``_ppm_update_range``) leaves the
  numpy path's state bit for bit: the same operations in the same order,
  numpy's pairwise sum of the 8 sector counts and OpenBLAS's FMA chain for
  the gradient projection written out.  Rows with no photons, negative or
  NaN flux, no radius yet, infinite, NaN, negative and tiny predicted
  radii (the floor), sector counts that the linear test rejects and
  accepts; with and without frequency photons, sector counts and the hold
  rate; one thread and split (PARALLEL_MIN).
- The film's image, radius and radius in pixels (core.sppm.film
  ``_film_range``) equal ``Film(..., compiled=False)``'s bit for bit (the
  same operations in the same order; float32 rounding of the same float64):
  pixels without a radius, with an infinite sum (set to 0), a transparent
  film's alpha, perspective and orthographic footprints, every AOV of the
  state; one thread and split (PARALLEL_MIN).
- The glossy pairs' reflected flux summed at the touched points alone
  (photon_pass.REFLECTED_DENSE_FRACTION) gives the dense per-point sums'
  image bit for bit: each point's pairs are summed in the same order.
- The camera pass's Embree call split in two threads
  (visible_points.INTERSECT_SPLIT_MIN) gives the one-call visible points
  bit for bit (each ray's hit is its own).
"""
from __future__ import annotations


import numpy as np
import pytest

from core.scene import camera as C
from core.render import Renderer
from core.settings import RenderSettings
from core.sppm import visible_points as V
from core.warmup import warmup_scene

import oracle_grid
from core.sppm import film as Fm
from core.sppm import photon_pass as PP
from core.sppm import hashgrid as Hg
from core.sppm import update as U
from core.sppm.state import PixelState
from core.scene.camera import CameraModel, FilterSampler
from core.scene.model import Camera


def _camera(kind, W, H, aperture=0.0):
    M = np.array([[0.8, 0.0, 0.6, 0.3], [0.6, 0.0, -0.8, -1.9], [0.0, 1.0, 0.0, 0.5],
                  [0, 0, 0, 1]], float)
    return Camera(kind=kind, matrix_world=M, lens=35.0, sensor_width=36.0, resolution=(W, H),
                  clip_start=0.01, clip_end=100.0, shift_x=0.1, shift_y=-0.05,
                  pixel_aspect=(1.0, 1.3), ortho_scale=2.5, aperture_radius=aperture,
                  focus_distance=2.0)


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
@pytest.mark.parametrize("K", [1000, C.PARALLEL_MIN + 7])
@pytest.mark.parametrize("width", [1.5, 0.0])
def test_compiled_camera_rays_equal_numpy(kind, K, width):
    cm, fs = CameraModel(_camera(kind, 300, 250)), FilterSampler(width)
    rng = np.random.default_rng(K)
    px = rng.integers(0, 300, K)
    py = rng.integers(0, 250, K).astype(np.float64)
    u = rng.random((K, 4))
    a, dz_a = cm.generate(px, py, u[:, :2], u[:, 2:], fs, compiled=False)
    b, dz_b = cm.generate(px, py, u[:, :2], u[:, 2:], fs)
    for x, y in ((a.o, b.o), (a.d, b.d), (a.t_max, b.t_max), (dz_a, dz_b)):
        assert x.dtype == y.dtype and np.array_equal(x, y)
    assert np.ptp(b.d[:, 0]) > 0.1 or kind == "ORTHO"


def test_thin_lens_takes_the_numpy_path():
    cm, fs = CameraModel(_camera("PERSP", 64, 48, aperture=0.05)), FilterSampler(1.5)
    rng = np.random.default_rng(2)
    px, py, u = rng.integers(0, 64, 500), rng.integers(0, 48, 500), rng.random((500, 4))
    a, _ = cm.generate(px, py, u[:, :2], u[:, 2:], fs, compiled=False)
    b, _ = cm.generate(px, py, u[:, :2], u[:, 2:], fs)
    assert np.array_equal(a.o, b.o) and np.array_equal(a.d, b.d)
    assert np.ptp(a.o[:, 0]) > 0.01          # the lens spreads the origins


def _vps(K, seed):
    """K visible points on three faces of a unit box (the Cornell box's
    kind of distribution), radii around 1/sqrt(K), a few inactive or NaN."""
    rng = np.random.default_rng(seed)
    p = rng.random((K, 3))
    face = rng.integers(0, 3, K)
    p[np.arange(K), face] = 0.0
    R = rng.uniform(0.5, 1.5, K) / np.sqrt(K)
    active = rng.random(K) > 0.05
    p[:3] = np.nan
    R[3:6] = np.inf
    return p, R, active


@pytest.mark.parametrize("K,layout,log2_table", [
    (3000, "auto", None), (3000, "dense", None), (3000, "hash", None),
    (3000, "hash", 6), (9000, "auto", None), (9000, "hash", 9)])
def test_parallel_grid_build_equals_serial(K, layout, log2_table, monkeypatch):
    monkeypatch.setattr(Hg, "PARALLEL_MIN_VPS", 4096)    # 9000 VPs: split
    p, R, active = _vps(K, K)
    if log2_table == 9:
        R[10] = 40.0 / np.sqrt(K)         # > _DEDUP_SCAN of its cells share 512 slots
    a = oracle_grid.build_grid_reference(p, R, active, layout=layout, log2_table=log2_table)
    for parallel in (True, False):
        b = Hg.build_grid(p, R, active, layout=layout, log2_table=log2_table, parallel=parallel)
        for f in ("K", "n_active", "h", "inv_h", "dense", "log2_table"):
            assert getattr(a, f) == getattr(b, f), f
        for f in ("origin", "lo", "hi", "dims", "cell_start", "vp_ids", "R_ins"):
            x, y = getattr(a, f), getattr(b, f)
            assert x.dtype == y.dtype and np.array_equal(x, y), f
    assert a.n_entries > 5 * a.n_active
    if log2_table == 9:
        big = np.flatnonzero(a.vp_ids == 10).size
        assert Hg._DEDUP_SCAN < big <= 512


@pytest.mark.parametrize("threads", [3, 4, 5])
def test_grid_build_with_more_threads_than_sort_groups(threads, monkeypatch):
    """More threads than the counting sort's SORT_GROUPS entry ranges: each
    range is split by slots too; the grid is still the oracle's, bit for bit
    (the thread count is the build's chunk count: any number runs on the
    machine's threads)."""
    monkeypatch.setattr(Hg, "PARALLEL_MIN_VPS", 4096)
    monkeypatch.setattr(Hg.numba, "get_num_threads", lambda: threads)
    p, R, active = _vps(9000, threads)
    R[10] = 40.0 / np.sqrt(9000)
    for layout, log2_table in (("auto", None), ("hash", 9)):
        a = oracle_grid.build_grid_reference(p, R, active, layout=layout, log2_table=log2_table)
        b = Hg.build_grid(p, R, active, layout=layout, log2_table=log2_table)
        for f in ("cell_start", "vp_ids", "R_ins"):
            x, y = getattr(a, f), getattr(b, f)
            assert x.dtype == y.dtype and np.array_equal(x, y), f
        assert a.n_entries > 5 * a.n_active


def _update_case(P, seed, sectors):
    """A state after some passes and one pass's photons, P pixels."""
    rng = np.random.default_rng(seed)
    st = PixelState.zeros(P, sector_cells=Hg.SECTOR_CELLS if sectors else 0)
    st.R2[:] = rng.uniform(1e-6, 1e-4, P) * (rng.random(P) > 0.05)
    st.N[:] = rng.uniform(0, 500, P)
    st.tau[:] = rng.uniform(0, 2, (P, 3))
    M = rng.poisson(40, P).astype(float) * (rng.random(P) > 0.1)
    Phi = rng.uniform(0, 0.1, (P, 3)) * M[:, None]
    Phi[rng.random(P) < 0.02, 1] = -1e-3
    Phi[rng.random(P) < 0.02, 2] = np.nan
    r_pred = np.sqrt(st.R2) * rng.uniform(0.3, 1.5, P)
    pick = rng.random(P)
    r_pred[pick < 0.2] = np.inf
    r_pred[(pick > 0.2) & (pick < 0.25)] = np.nan
    r_pred[(pick > 0.25) & (pick < 0.3)] *= -1.0
    r_pred[(pick > 0.3) & (pick < 0.35)] = 1e-12           # below the floor
    S_pass = None
    if sectors:
        st.sectors[:] = rng.poisson(30, (P, Hg.SECTOR_CELLS)) * rng.uniform(0.2, 1, (P, 1))
        ramp = np.r_[np.linspace(0.2, 1.8, 4), np.linspace(0.0, 2.0, 4)]
        steep = rng.random(P) < 0.3                     # more than a gradient: rejected
        st.sectors[steep] *= ramp
        S_pass = rng.multinomial(1, np.full(Hg.SECTOR_CELLS, 1 / Hg.SECTOR_CELLS),
                                 (P, 40)).sum(axis=1).astype(float)
        S_pass *= (M / 40.0)[:, None]
    return st, M, Phi, r_pred, S_pass


@pytest.mark.parametrize("P", [3000, U.PARALLEL_MIN + 3])
@pytest.mark.parametrize("frequency,sectors,hold_alpha,knobs", [
    (True, True, 0.9, None), (True, False, 0.9, None), (True, True, 1.0, None),
    (False, False, 0.9, None),
    # the spectrum's hold rate, growth at low counts (docs/method.md "What the spectrum adds
    # over the counts")
    (True, True, 0.9, dict(hold_alpha_spectrum=0.97, grow_min_expected=0.0)),
    # the spectrum's rate gated by the counts (docs/method.md "A slower hold where the counts
    # can test it, round 15"): a gate inside the case's 11-35 per cell takes both branches
    (True, True, 0.9, dict(hold_alpha_spectrum=0.97, hold_spectrum_min_expected=20.0)),
    # no hold where the visible point was reached through a delta vertex (docs/method.md
    # "The glass sphere at equal passes, round 17"): the compiled update's veto array
    (True, True, 0.9, dict(hold_through_delta=False, through=0.3)),
    # the veto beside the growth's cap: pixels in their first pass with photons (they grow),
    # half of them with a finite surface-boundary cap; vetoed pixels with and without a cap
    (True, True, 0.9, dict(hold_through_delta=False, through=0.3, first=0.5, edge_cap=0.5)),
    # frequency_start 4's pass 4: verified holds grow whatever N (Radii.grows_at,
    # docs/method.md "A late start for the frequency photons, round 18")
    (True, True, 0.9, dict(late=4)),
    # the late start's growth beside the glass veto
    (True, True, 0.9, dict(late=4, hold_through_delta=False, through=0.3)),
    # verified holds refused where the counts' fitted gradient is steep
    (True, True, 0.9, dict(gradient_max=0.3))])
def test_compiled_ppm_update_equals_numpy(P, frequency, sectors, hold_alpha, knobs):
    settings = RenderSettings(integrator="PHOTON", hold_alpha=hold_alpha, verify_holds=sectors)
    radii = U.Radii(settings, None, 10.0, frequency, None, 1, P)
    radii.floor_sq = 1e-9                                # reached by the tiny predictions
    ref, M, Phi, r_pred, S_pass = _update_case(P, P, sectors)
    rng = np.random.default_rng(P + 1)
    cap, k_pass = None, None
    for k, v in (knobs or {}).items():
        if k == "through":          # that share of the pixels seen through glass
            radii._through = rng.random(P) < v
        elif k == "late":           # pass v = frequency_start v, growth at the start
            radii.settings = settings.replace(frequency_start=v)
            radii.grow_at_start, k_pass = True, v
        elif k == "first":          # that share of the pixels in their first pass with photons
            ref.N[rng.random(P) < v] = 0.0
        elif k == "edge_cap":       # that share with a cap [m] of 0.9-1.4 R (inf: none)
            cap = np.where(rng.random(P) < v, np.sqrt(ref.R2) * rng.uniform(0.9, 1.4, P), np.inf)
            radii._edge_cap = cap
        else:
            setattr(radii, k, v)
    new = PixelState(**{k: v.copy() for k, v in ref.state_dict().items()})
    N_before, R2_before = ref.N.copy(), ref.R2.copy()
    radii.compiled = False
    radii.update(ref, M, Phi, r_pred, S_pass, k=k_pass)
    radii.compiled = True
    radii.update(new, M, Phi, r_pred, S_pass, k=k_pass)
    for f in ("N", "R2", "tau", "held", "r_pred_last", "M_last", "sectors"):
        x, y = getattr(ref, f), getattr(new, f)
        if x is None:
            assert y is None
            continue
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), f
    if frequency:              # both branches taken (X's uniform counts add holds: 0.62)
        assert 0.05 < ref.held.mean() < 0.8
    if radii._through is not None:
        assert not ref.held[radii._through].any() and ref.held[~radii._through].mean() > 0.3
    if k_pass is not None:     # grown radii, every pixel having had photons (N > 0)
        assert radii.grows_at(k_pass) and not radii.grows_at(k_pass + 1)
        assert (ref.R2 > 1.2 * R2_before).mean() > 0.03
    if cap is not None:         # the cap binds a growth; vetoed pixels with and without a cap
        first = (M > 0) & (R2_before > 0) & (N_before == 0.0)
        grown = first & ref.held & (ref.R2 > R2_before)
        assert np.sum(grown & np.isinf(cap)) > 10
        assert np.sum(grown & np.isclose(ref.R2, np.square(cap), rtol=1e-12)) > 10
        for capped in (np.isfinite(cap), np.isinf(cap)):
            assert np.sum(first & radii._through & capped) > 10
    if sectors:                # the linear test vetoes some holds and not others
        vetoed = U.chi2_rejects(ref.sectors, linear=True)
        assert 0.05 < vetoed.mean() < 0.6


@pytest.mark.parametrize("P", [3000, U.PARALLEL_MIN + 3])
@pytest.mark.parametrize("rule", ["CPPM", "APPM"])
@pytest.mark.parametrize("frequency", [False, True])
def test_compiled_baseline_rules_equal_numpy(P, rule, frequency):
    """The baselines' rules run in the compiled update too (only the rule
    differs from FPPM's, not numpy's cost): the same state bit for bit, with
    both of each rule's branches taken."""
    settings = RenderSettings(integrator="PHOTON", radius_rule=rule)
    radii = U.Radii(settings, None, 10.0, frequency, None, 1, P)
    radii.floor_sq = 1e-9
    ref, M, Phi, r_pred, S_pass = _update_case(P, P + 7, True)
    new = PixelState(**{k: v.copy() for k, v in ref.state_dict().items()})
    R = np.sqrt(ref.R2)
    radii.compiled = False
    radii.update(ref, M, Phi, r_pred, S_pass, k=3)
    radii.compiled = True
    radii.update(new, M, Phi, r_pred, S_pass, k=3)
    for f in ("N", "R2", "tau", "held", "r_pred_last", "M_last", "sectors"):
        x, y = getattr(ref, f), getattr(new, f)
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), f
    assert 0.05 < ref.held.mean() < 0.95
    r = ref.r_pred_last
    if rule == "APPM":       # the MSE radius below R somewhere, R itself elsewhere
        assert 0.05 < np.mean(r < R * (1 - 1e-12)) < 0.95
        assert 0.05 < np.mean(r == R) < 0.95
    else:                    # the test rejects somewhere and keeps R elsewhere
        assert 0.05 < np.mean(np.isnan(r) & (R > 0)) < 0.95
        assert 0.05 < np.mean(r == R) < 0.95


def test_split_camera_intersect_equals_one_call(monkeypatch):
    res = 192                                            # 192^2 > INTERSECT_SPLIT_MIN
    assert res * res > V.INTERSECT_SPLIT_MIN
    r = Renderer(warmup_scene(res, ("POINT", "AREA")),
                 RenderSettings(integrator="PHOTON", max_passes=1, seed=1), log=lambda _m: None)
    vp_s, L_s = r.camera_pass(np.random.default_rng(5))
    monkeypatch.setattr(V, "INTERSECT_SPLIT_MIN", 1 << 40)
    vp_1, L_1 = r.camera_pass(np.random.default_rng(5))
    assert vp_1.valid.mean() > 0.5
    for f in ("valid", "p", "ng", "ns", "wo", "mat", "colors", "beta", "depth"):
        assert np.array_equal(getattr(vp_s, f), getattr(vp_1, f)), f
    assert np.array_equal(L_s, L_1)


@pytest.mark.parametrize("P", [60 * 50, 260 * 260])
@pytest.mark.parametrize("kind,transparent", [("PERSP", False), ("ORTHO", True)])
def test_compiled_film_equals_numpy(P, kind, transparent):
    assert (P >= Fm.PARALLEL_MIN) == (P == 260 * 260)
    W = 60 if P < Fm.PARALLEL_MIN else 260
    H = P // W
    cam = _camera(kind, W, H)
    st, M, Phi, r_pred, _ = _update_case(P, 7, False)
    rng = np.random.default_rng(8)
    st.L_sum[:] = rng.uniform(0, 3, (P, 3))
    st.L_sum[5, 1] = np.inf
    st.depth[:] = rng.uniform(0.5, 4, P)
    st.r_pred_last[:] = r_pred
    scene = type("S", (), {"film_transparent": transparent, "camera": cam})()
    settings = RenderSettings(integrator="PHOTON", aov_radius=True, aov_predicted_radius=True,
                              aov_photon_count=True, aov_held=True)
    out = []
    for compiled in (False, True):
        film = Fm.Film(settings, CameraModel(cam), H, W, scene, compiled=compiled)
        film.coverage[:] = rng.uniform(0, 3, P) if not out else out[0][1]
        film.samples = 3
        out.append((film(st, 4, 10**6, 1.0), film.coverage.copy()))
    a, b = out[0][0], out[1][0]
    assert a.image.dtype == b.image.dtype and np.array_equal(a.image, b.image)
    assert a.aovs.keys() == b.aovs.keys() and len(a.aovs) == 5
    for k in a.aovs:
        assert np.array_equal(a.aovs[k], b.aovs[k]), k
    assert a.mean_radius_px == b.mean_radius_px and a.held_fraction == b.held_fraction
    assert a.image[..., :3].reshape(P, 3)[5, 1] == 0.0
    assert (np.ptp(a.image[..., 3]) > 0.5) == transparent


def test_sparse_reflected_sums_equal_dense(monkeypatch):
    from test_gather_buffers import _floor_scene
    st = RenderSettings(integrator="PHOTON",
                        max_passes=2, photons_per_pass=6000, seed=4, aov_photon_count=True)
    calls = []
    images = []
    for fraction in (0, 10**9):                 # always dense, always sparse
        monkeypatch.setattr(PP, "REFLECTED_DENSE_FRACTION", fraction)
        r = Renderer(_floor_scene(), st, log=lambda _m: None)
        f = r.photon_pass._reflected
        r.photon_pass._reflected = lambda vp, dep, pv, pp, Phi, *a: (
            calls.append(pv.size), f(vp, dep, pv, pp, Phi, *a))
        images.append(r.run().image)
    assert min(calls) > 100                      # glossy pairs in every chunk
    assert images[0].max() > 0 and np.array_equal(images[0], images[1])
