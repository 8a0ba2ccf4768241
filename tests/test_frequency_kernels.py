"""Compiled frequency updates (core.frequency.kernels) and the blocked occlusion
march (core.frequency.occlusion_march with occlusion_grid.MarchBlocks) against
their references (tests/oracle_photons.py, tests/oracle_occlusion.py).

1. Each compiled operator against the numpy operator of core.frequency.spectrum, both
   models, on random spectra plus every row of the stiff table (grazing cos,
   a + a_o -> 0, a_o = inf or >= A_MAX, huge d, c^2 > ab, NaN / inf in every
   input).  The kernels repeat the numpy expressions in the same order with
   IEEE arithmetic, so they agree to the last bit except tan (libm vs
   numpy's SIMD tan, <= 1 ulp) in predicted_radius: asserted to rtol 1e-12
   with NaN / inf in the same places.
2. The photon tracer with the compiled chains (travel -> march -> occlude ->
   onto_surface -> radius; off_surface -> lobe -> curvature) against the
   same tracer running the numpy chains of tests/oracle_photons.py on the
   same hits: same deposits
   and predicted radii, to 1e-12 (one fixed stream: the paths are identical).
3. The blocked march against the dense march: its block / voxel bounds are
   conservative (checked by brute force over every block and 500
   directions, union cones cut at MarchBlocks.cut_locality), so it differs
   from the dense march only where the latter's Lipschitz jump landed
   inside a voxel and a candidate depended on it (measured: 0 of 117k photon
   segments of the benchmark's Cornell box (bench/bench_march.py), 0 of the
   3 x 20000 random segments below, 31 of the 12000 segments on voxel
   corners and faces).
4. What the march may skip (docs/frequency.md "Marching only what can
   matter"): with the radius cut, every deposit radius below the cut is
   unchanged bit for bit; the compiled tracer with the cut and the
   used-segment rule equals the numpy chains with both.
"""
import numpy as np
import pytest

from core.frequency import spectrum as F
from core.frequency import kernels as FK
from core.frequency import occlusion_grid as OG
from core.frequency import occlusion_march as Occ
from core.render import Renderer
from core.settings import RenderSettings

import oracle_photons
import test_photon_kernels as TPK
from oracle_occlusion import march_occlusion_dense

A_MAX = 25.0                 # D = 5 m
RTOL = 1e-12


def _spectra(rng, n=4000):
    """Random (a, b, c) over many decades, 10% with c^2 > ab, plus stiff rows."""
    a = 10.0 ** rng.uniform(-12, 4, n)
    b = rng.uniform(0, 1.0, n)
    c = rng.uniform(-1, 1, n) * np.sqrt(a * b) * np.where(rng.random(n) < 0.1, 3.0, 1.0)
    s = np.stack([a, b, c], 1)
    stiff = np.array([[0, 0, 0], [0, 0.467, 0], [np.nan, 0.1, 0], [0.1, np.nan, 0],
                      [0.1, 0.1, np.nan], [np.inf, 0.2, 0.0], [0.1, np.inf, 0.0],
                      [-1.0, 0.2, 0.1], [0.1, -0.2, 0.1], [1e300, 0.3, 1e150],
                      [0.0415, 0.1544, -0.0801], [A_MAX, 0.467, 0.0], [1e-300, 1e-300, 0]])
    return np.concatenate([s, stiff])


def _args(rng, n, kind):
    """Per-photon arguments of an operator, random plus stiff values."""
    if kind == "travel":
        x = rng.uniform(-3, 10, n)
        special = [0.0, -0.0, 1e20, -1e20, np.inf, np.nan, 0.5185, 5.0]
    elif kind == "occlude":
        x = 10.0 ** rng.uniform(-8, 3, n)
        special = [0.0, np.inf, np.nan, A_MAX, 2 * A_MAX, -1.0, 1e-300]
    elif kind in ("onto_surface", "off_surface"):
        x = rng.uniform(-1, 1, n)
        special = [1e-20, 0.0, -0.0, 1.0, -1.0, np.nan, np.inf, 1e-3, 2.0]
    elif kind == "brdf":
        x = rng.uniform(0, 0.6, n)
        special = [0.0, np.inf, np.nan, -1.0, 0.467, 1e300]
    else:  # curvature
        x = rng.normal(0, 10, n)
        special = [0.0, np.inf, -np.inf, np.nan, 1e200, -2.0, 1e-300]
    x[:len(special)] = special
    return x


def _same(k, n):
    """Equal to RTOL, NaN and inf in the same places (inf compares exactly)."""
    assert k.shape == n.shape
    np.testing.assert_array_equal(np.isnan(k), np.isnan(n))
    np.testing.assert_allclose(k, n, rtol=RTOL, atol=0.0, equal_nan=True)


@pytest.mark.parametrize("model", ["CORRECTED", "PAPER"])
@pytest.mark.parametrize("op", ["travel", "occlude", "onto_surface", "off_surface", "brdf",
                                "curvature"])
def test_operator_matches_numpy(op, model):
    rng = np.random.default_rng(hash((op, model)) % 2**32)
    s = _spectra(rng)
    x = _args(rng, s.shape[0], op)
    with np.errstate(all="ignore"):
        ref = getattr(F, op)(s, x, model, A_MAX)
        got = FK.apply(op, s, x, model, A_MAX)
    _same(got, ref)
    if model == "CORRECTED":                        # the guards hold: finite PSD
        assert F.is_psd(got).all()


def test_sanitize_matches_numpy():
    s = _spectra(np.random.default_rng(1))
    _same(FK.apply("sanitize", s, 0.0, "CORRECTED", A_MAX), F.sanitize(s, A_MAX))
    _same(FK.apply("sanitize", s, 0.0, "CORRECTED", np.inf), F.sanitize(s, np.inf))


@pytest.mark.parametrize("model", ["CORRECTED", "PAPER"])
def test_predicted_radius_matches_numpy(model):
    rng = np.random.default_rng(5)
    s = _spectra(rng)
    n = s.shape[0]
    br = np.where(rng.random(n) < 0.3, np.inf, rng.uniform(0, 2, n))
    br[:6] = [np.nan, -1.0, 0.0, 100.0, np.inf, 1e-300]
    z = rng.uniform(-3, 3, n)
    z[:4] = [0.0, np.inf, np.nan, -np.inf]
    with np.errstate(all="ignore"):
        ref = F.predicted_radius(s, br, z, model)
        got = FK.radius(s, br, z, model)
    _same(got, ref)
    with np.errstate(all="ignore"):
        _same(FK.radius(s, np.inf, np.inf, model), F.predicted_radius(s, np.inf, np.inf, model))


@pytest.mark.parametrize("model", ["CORRECTED", "PAPER"])
def test_random_chains_match_numpy(model):
    """10-operator random chains (the photon's life) stay 1e-12-close."""
    rng = np.random.default_rng(11)
    s = k = _spectra(rng, 2000)
    ops = ["travel", "occlude", "onto_surface", "off_surface", "brdf", "curvature"]
    for step in range(10):
        op = ops[rng.integers(len(ops))]
        x = _args(rng, s.shape[0], op)
        with np.errstate(all="ignore"):
            s = getattr(F, op)(s, x, model, A_MAX)
            k = FK.apply(op, k, x, model, A_MAX)
        _same(k, s)


# ------------------------------------------------------------ 2. in the tracer
def _tracer(scene, model):
    # frequency_start 1: the occlusion grid built in the set-up
    st = RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=4000, use_frequency=True,
                        frequency_model=model, frequency_start=1)
    return Renderer(scene, st, log=lambda s: None).tracer


@pytest.mark.parametrize("make, model", [(TPK.cornell, "CORRECTED"),
                                         (TPK.glass_mirror, "CORRECTED"),
                                         (TPK.glass_mirror, "PAPER")])
def test_tracer_compiled_chain_matches_numpy_operators(make, model):
    """Same stream, same paths: the compiled chains give the numpy operators'
    spectra and radii for every deposit (both use the blocked march)."""
    tr = _tracer(make(), model)
    assert tr.occ_grid is not None and tr.kappa is not None
    a = tr.trace(6000, 6000, np.random.default_rng(3))
    b = oracle_photons.use_numpy_chains(_tracer(make(), model)).trace(
        6000, 6000, np.random.default_rng(3))
    assert a["p"].shape[0] > 5000
    for key in a:
        _same(np.asarray(a[key], np.float64), np.asarray(b[key], np.float64))
    r = F.radius_from_fold_key(a["rpred"], model)
    assert np.all(r >= 0)
    if model == "CORRECTED":
        assert (r > 0).mean() > 0.5                          # radii exercised
    # (PAPER: occlude(a_occ = inf) is a inf / inf = NaN -> r = 0 for every
    # unoccluded photon, in core.frequency.spectrum as here: 99.5% zeros.)


# ------------------------------------------------------------ 3. the march
def _random_tris(rng, n=300):
    big = rng.random((n // 3, 3, 3))
    small = rng.random((n - n // 3, 1, 3)) + 0.06 * (rng.random((n - n // 3, 3, 3)) - 0.5)
    return np.concatenate([big, small]).astype(np.float32)


@pytest.fixture(scope="module")
def grids():
    rng = np.random.default_rng(2)
    g1 = OG.build_occlusion_grid(_random_tris(rng), np.zeros(3), np.ones(3), 24)
    g2 = OG.build_occlusion_grid(TPK.cornell().tri_p, (-0.5, -0.5, 0), (0.5, 0.5, 1), 32,
                                 max_distance=0.3)
    return g1, g2


def test_block_bounds_are_conservative(grids):
    """For every block (and voxel) and 500 directions: union cones (two per
    block; the voxel level's quantized to int16) that both miss the plane
    orthogonal to d imply that every voxel cone a sample there can read
    misses it (the voxel test of _cone_meets): the block's own voxels, and
    those of the dilation closer than cut_locality (the only neighbours
    _sample_voxel reads when locality <= cut_locality); and bmin is <= every
    dist of the dilated block; and the unions pass few pairs no member
    meets.  A block (voxel) with bmin (1 - BLOCK_REL) >= cut_locality is
    never tested by its cones (the march reads them only below its
    threshold <= locality <= cut_locality) and holds "meets none"."""
    rng = np.random.default_rng(4)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    n_far = 0
    for g in grids:
        R = g.res
        cone = g.cone.astype(np.float64)
        meets = (np.abs(np.einsum("xyzk,nk->xyzn", cone[..., :3], d))
                 <= cone[..., 3:4] + OG.SIN_TOL)
        mb = OG.march_blocks(g, OG.MARCH_BLOCK)
        assert mb.has_voxel_level
        loc = OG.default_locality(g)
        assert loc <= mb.cut_locality <= loc * (1 + 1e-8)
        near = g.dist < mb.cut_locality
        n_cut = n_pass = n_false = 0
        for B, bmin, bcone in ((OG.MARCH_BLOCK, mb.bmin, mb.bcone), (1, mb.vmin, mb.vcone)):
            # the march's test, vectorised: one of the two cones meets
            unions = OG.union_meets(bcone, d)
            NB = bmin.shape[0]
            for bx in range(NB):
                for by in range(NB):
                    for bz in range(NB):
                        sl = tuple(slice(max(i * B - 1, 0), min((i + 1) * B + 1, R))
                                   for i in (bx, by, bz))
                        # voxels a sample there reads: near ones, and its own
                        read = near[sl].copy()
                        read[tuple(slice(i * B - s.start, min((i + 1) * B, R) - s.start)
                                   for i, s in zip((bx, by, bz), sl))] = True
                        assert bmin[bx, by, bz] <= g.dist[sl].min()
                        union = unions[bx, by, bz]
                        if np.float64(bmin[bx, by, bz]) * (1.0 - OG.BLOCK_REL) >= mb.cut_locality:
                            assert not union.any()            # never read, not built
                            n_far += 1
                            continue
                        m = meets[sl] & read[..., None]
                        anym = m.reshape(-1, len(d)).any(axis=0)
                        assert not np.any(anym & ~union), (B, bx, by, bz)
                        n_cut += (~read).sum()
                        n_pass += union.sum()
                        n_false += (union & ~anym).sum()
        assert n_cut > 0                                  # the cut is exercised
        # Tightness: passes where no member meets (measured 12.6% and 11.3%
        # here; on the Cornell grid a single union per block passed 0.665
        # of (block, d) and 0.338 of (voxel, d), two pass 0.570 and 0.244,
        # the members 0.486 and 0.216).
        assert n_false < 0.2 * n_pass
    assert n_far > 0                   # blocks and voxels whose cones are never read


def test_blocked_march_matches_dense(grids):
    """Random segments through both grids: the blocked march equals the
    dense one except where a dense Lipschitz jump landed inside a voxel
    (measured: none of these 60000); such a segment would differ by at most
    the distance error of sampling a voxel on part of its piece, <= 1 voxel.
    Allowed: 0.1% (20 segments per grid).  Also at 1.6x the default
    locality, beyond MarchBlocks.cut_locality: the march then skips by
    distance only (its union cones leave out neighbours it may read)."""
    rng = np.random.default_rng(6)
    for g, scale in ((grids[0], 1.0), (grids[1], 1.0), (grids[1], 1.6)):
        M = 20000
        lo, hi = g.lo, g.hi
        o = lo + rng.random((M, 3)) * (hi - lo)
        d = rng.normal(size=(M, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        t = rng.uniform(0, 1.0, M)
        loc = scale * OG.default_locality(g)
        assert (loc <= OG.march_blocks(g).cut_locality) == (scale == 1.0)
        _assert_matches_dense(g, o, d, t, loc, min_same=0.999, min_finite=0.1)


def test_blocked_march_on_voxel_corners_and_faces(grids):
    """Segments that start on voxel corners, centres and edges and run along
    axes and diagonals (exits of two or three axes tie at every corner):
    the block DDA steps blocks and voxels where the dense march locates
    every voxel by floor.  They agree except where the dense march's
    Lipschitz jump landed inside a voxel (measured: 3, 9 and 19 of 4000
    here; the march before the block DDA gave the same a_occ and t_occ on
    all 12000); allowed 1%, and a differing
    occluder distance by at most a voxel diagonal (as above)."""
    rng = np.random.default_rng(8)
    dirs = np.array([(1, 1, 1), (1, 1, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, -1, -1),
                     (1, -1, 1), (-1, 1, 0), (2, 1, 0), (1, 2, 3)], float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # and a grid whose res is no multiple of the block (last block partial)
    g30 = OG.build_occlusion_grid(TPK.cornell().tri_p, (-0.5, -0.5, 0), (0.5, 0.5, 1), 30,
                                  max_distance=0.3)
    for g in grids + (g30,):
        R, M = g.res, 4000
        ks = rng.integers(0, R + 1, size=(M, 3))
        o = g.lo + ks * g.cell                                    # corners
        o[1000:2000] = g.lo + (ks[1000:2000] + 0.5) * g.cell      # centres
        o[2000:3000, 2] = g.lo[2] + rng.random(1000) * (g.hi[2] - g.lo[2])   # z edges
        d = dirs[rng.integers(0, len(dirs), M)]
        t = rng.uniform(0, 1.5, M)
        t[:2000] = g.voxel_diagonal * rng.integers(1, 30, 2000)  # ends on corners too
        loc = OG.default_locality(g)
        _assert_matches_dense(g, o, d, t, loc, min_same=0.99, min_finite=0.2)


def _runs_brute(bmin, bcone, L):
    """MarchBlocks.runs by growing each cube shell by shell (the definition
    of occlusion_grid._block_runs, without its dynamic programme)."""
    NB = bmin.shape[0]
    wild = (bmin * (1.0 - OG.BLOCK_REL) >= L) | ((bcone[..., 3] < -1.5) & (bcone[..., 7] < -1.5))
    runs = np.zeros((NB, NB, NB, 8), np.uint8)
    for b in np.ndindex(NB, NB, NB):
        for oc in range(8):
            s = np.array([-1 if oc & (1 << a) else 1 for a in range(3)])
            k = 0
            while True:
                far = np.array(b) + s * (k + 1)
                if np.any(far < 0) or np.any(far >= NB):
                    break
                lo, hi = np.minimum(b, far), np.maximum(b, far) + 1
                cube = tuple(slice(lo[a], hi[a]) for a in range(3))
                ok = wild[cube] | (not wild[b] and
                                   np.all(bcone[cube] == bcone[b], axis=-1))
                if not ok.all():
                    break
                k += 1
            runs[b + (oc,)] = k
    return runs


def test_block_runs_are_exact(grids):
    """MarchBlocks.runs (the cube the march crosses in one step): its
    dynamic programme equals the cubes grown shell by shell, every block of
    a cube is left whenever its corner block is left by its cones, and the
    march with the runs gives the same a_occ and t_occ, bit for bit, as the
    march without them (runs all 0: the march of before, block by block),
    on random segments with and without end planes and radius cuts."""
    g30 = OG.build_occlusion_grid(TPK.cornell().tri_p, (-0.5, -0.5, 0), (0.5, 0.5, 1), 30,
                                  max_distance=0.3)
    rng = np.random.default_rng(14)
    for g in grids + (g30,):
        mb = OG.march_blocks(g)
        np.testing.assert_array_equal(mb.runs, _runs_brute(mb.bmin, mb.bcone, mb.cut_locality))
        assert mb.runs.any() or g is grids[0]     # random triangles fill every block
        loc = OG.default_locality(g)
        m = Occ.march_grid(g, loc)
        m0 = m._replace(runs=np.zeros_like(m.runs))
        M = 20000
        o, d, t = _random_segments(g, rng, M, 0.0, 1.5)
        cut = np.full((M, 3), np.inf)
        cut[::2] = np.abs(rng.normal(size=(M // 2, 3))) * loc ** 2 * [1.0, 0.0, 4.0]
        planes = np.full((M, 2), np.inf)
        planes[::3] = rng.random((len(planes[::3]), 2))
        for c, p in ((np.full((M, 3), np.inf), np.full((M, 2), np.inf)), (cut, planes)):
            (a1, t1), (a0, t0) = [(np.empty(M), np.empty(M)) for _ in range(2)]
            Occ._march_cut(m, o, d, t, a1, t1, c, p)
            Occ._march_cut(m0, o, d, t, a0, t0, c, p)
            assert np.isfinite(a1).mean() > 0.05
            np.testing.assert_array_equal(a1, a0)
            np.testing.assert_array_equal(t1, t0)


def _assert_matches_dense(g, o, d, t, loc, min_same, min_finite):
    """The block march against the dense reference on segments (o, d, t):
    equal on at least ``min_same`` of them, occluders found on more than
    ``min_finite``, and a differing occluder distance off by at most a voxel
    diagonal."""
    a = Occ.march_occlusion(g, o, d, t, loc)
    b = march_occlusion_dense(g, o, d, t, loc)
    same = (a == b) | (np.isinf(a) & np.isinf(b))
    assert same.mean() >= min_same, same.mean()
    assert np.isfinite(a).mean() > min_finite                  # occluders exercised
    both = ~same & np.isfinite(a) & np.isfinite(b)
    assert np.all(np.abs(np.sqrt(a[both]) - np.sqrt(b[both])) <= g.voxel_diagonal)


def _random_segments(g, rng, M, t_lo, t_hi):
    """M segments (o, d, t) in grid g's box: uniform origins and
    directions, lengths U(t_lo, t_hi)."""
    o = g.lo + rng.random((M, 3)) * (g.hi - g.lo)
    d = rng.normal(size=(M, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d, rng.uniform(t_lo, t_hi, M)


def test_end_plane_rule_reads_the_segment_end_after_a_jump(grids):
    """``march_segments``' end-plane test compares a candidate with the
    plane the segment lands on at (t_end - ts) |n . d|.  A landing plane
    facing the segment (|n . d| = 1: its distance is what is left of the
    segment) explains no candidate nearer than what is left, less the
    half-voxel tolerance, so every such nearest candidate is found with
    the plane as without it.  On random segments through the Cornell grid
    (many leave blocks by a Lipschitz jump): the jump once overwrote the
    segment's end with its landing parameter, and every candidate after a
    jump was taken for the plane (22 of these 5,387 occluders lost)."""
    g = grids[1]
    o, d, t = _random_segments(g, np.random.default_rng(12), 20000, 0.3, 1.5)
    loc = OG.default_locality(g)
    a0, t0 = Occ.march_occlusion(g, o, d, t, loc, return_t=True)
    a1, t1 = Occ.march_occlusion(g, o, d, t, loc, return_t=True, n_end=d)
    # kept for sure: nearer than the plane's distance less the tolerance
    # (half the largest cell side), with a margin of a voxel for the march
    # of the plane run reaching that candidate's voxel at another sample
    keep = np.sqrt(a0) < (t - t0) - 1.5 * g.cell.max()
    assert keep.sum() > 500
    np.testing.assert_array_equal(a1[keep], a0[keep])
    np.testing.assert_array_equal(t1[keep], t0[keep])


# ------------------------------------------------------------ 4. what the march may skip
def test_radius_cut_keeps_every_radius_below_it(grids):
    """``kernels.radius_cut``: the march ignores an occluder that cannot
    bring the deposit's diffuse radius below r_cut.  On random segments
    through the Cornell grid with random leaving spectra (a point light's
    rank-1 beam, area-light and post-bounce ones): every deposit whose
    radius without the cut is below r_cut keeps it bit for bit, and every
    radius the cut leaves at or above r_cut was at or above it without the
    cut (the held-radius decision of a pixel of radius <= r_cut cannot
    change).  The cut must skip something: radii above r_cut change."""
    g = grids[1]
    rng = np.random.default_rng(9)
    M, D = 20000, 2.0
    o, d, t = _random_segments(g, rng, M, 0.05, 1.0)
    a = np.where(rng.random(M) < 0.2, 0.0, 10.0 ** rng.uniform(-4, 0, M))
    b = np.full(M, F.B_DIFFUSE)
    c = rng.uniform(-1, 1, M) * np.sqrt(a * b)
    spec = np.stack([a, b, c], 1)
    loc = OG.default_locality(g)
    cs = rng.uniform(0.05, 1.0, M)

    def radius(cut):
        ao, to = Occ.march_occlusion(g, o, d, t, loc, return_t=True, cut=cut)
        s = oracle_photons.travel_occlude_travel(spec, t, ao, to, D, "CORRECTED", D * D)
        return F.predicted_radius(F.onto_surface(s, cs, "CORRECTED", D * D), np.inf, np.inf)
    full = radius(None)
    for r_cut in (0.01, 0.03):
        cut = oracle_photons.radius_cut_numpy(spec, t, r_cut, D)
        # the compiled twin gives the same rows
        got = np.array([FK.radius_cut(*spec[i], t[i], r_cut, D * D, D) for i in range(200)])
        np.testing.assert_array_equal(got, cut[:200])
        r = radius(cut)
        below = full < r_cut
        assert below.sum() > 100                              # the decision exercised
        np.testing.assert_array_equal(r[below], full[below])
        assert np.all(full[r >= r_cut] >= r_cut)
        assert (r != full).sum() > 100                        # something skipped


def test_tracer_with_radius_cut_matches_numpy_chains():
    """The compiled tracer with a radius cut (set_radius_cut) and the used
    segments only (kernels.marked_segments) against the numpy chains with
    the same cut and rule: same deposits and radii (same stream)."""
    trs = [_tracer(TPK.cornell(), "CORRECTED") for _ in range(2)]
    for tr in trs:
        tr.set_radius_cut(np.array([0.0, 0.02 ** 2]))
        assert tr.radius_cut == pytest.approx(0.02)
    a = trs[0].trace(3000, 3000, np.random.default_rng(5))
    b = oracle_photons.use_numpy_chains(trs[1]).trace(3000, 3000, np.random.default_rng(5))
    for key in a:
        _same(np.asarray(a[key], np.float64), np.asarray(b[key], np.float64))


# ------------------------------------------------------------ 5. deposits no pixel reads
def test_reach_map_covers_every_gather_sphere():
    """``kernels.mark_reach``: every point within a visible point's radius
    lies in a marked voxel (random points, radii and offsets), and the map
    leaves most of the grid unmarked (it is not trivially full)."""
    rng = np.random.default_rng(4)
    R, lo, cell = 32, np.array([-1.0, -0.5, 0.0]), np.array([0.05, 0.04, 0.06])
    p = lo + rng.random((200, 3)) * R * cell
    r = rng.uniform(0.0, 0.08, 200)
    out = np.zeros((R, R, R), np.uint8)
    FK.mark_reach(p, r, lo, cell, R, out)
    u = rng.normal(size=(200, 50, 3))
    u *= (r[:, None] * rng.random((200, 50)) ** (1 / 3) / np.linalg.norm(u, axis=2))[..., None]
    q = (p[:, None, :] + u).reshape(-1, 3)
    idx = np.clip(np.floor((q - lo) / cell).astype(int), 0, R - 1)
    assert out[idx[:, 0], idx[:, 1], idx[:, 2]].all()
    assert out.mean() < 0.5


def test_reach_map_is_rebuilt_in_place():
    """``PhotonTracer.set_reach`` rewrites the last pass's map (no new grid a
    pass): the second map is the first array, holding exactly what
    ``mark_reach`` marks from zeros for the new points, none of the old."""
    tr = _tracer(TPK.cornell(), "CORRECTED")
    m = tr.march
    assert tr.uses_reach()
    rng = np.random.default_rng(2)
    p = m.lo + rng.random((50, 3)) * m.res * m.cell
    R2 = np.full(50, (2.0 * m.cell.max()) ** 2)
    tr.set_reach(p, np.ones(50, bool), R2)
    first = tr.reach
    n_first = int(first.sum())
    tr.set_reach(p[:10], np.ones(10, bool), R2[:10])
    fresh = np.zeros_like(first)
    FK.mark_reach(p[:10].copy(), np.sqrt(R2[:10]), m.lo, m.cell, m.res, fresh)
    assert tr.reach is first
    np.testing.assert_array_equal(tr.reach, fresh)
    assert n_first > int(fresh.sum()) > 0


def test_unreached_deposits_predict_zero_and_first_deposits_match():
    """``PhotonTracer.set_reach`` / ``kernels.gate_unreached``: with a reach
    map covering half the Cornell box, deposits in unmarked voxels are not
    marched and predict the radius floor (<= the full march's radius: the
    conservative side), while the first deposit of every photon in a marked
    voxel (no gated segment before it) keeps the ungated radius bit for bit
    (same stream, same paths)."""
    trs = [_tracer(TPK.cornell(), "CORRECTED") for _ in range(2)]
    m = trs[1].march
    reach = np.zeros((m.res, m.res, m.res), np.uint8)
    reach[: m.res // 2] = 1
    trs[1].reach = reach
    a = trs[0].trace(3000, 3000, np.random.default_rng(6))
    b = trs[1].trace(3000, 3000, np.random.default_rng(6))
    np.testing.assert_array_equal(a["p"], b["p"])
    ra = F.radius_from_fold_key(a["rpred"], "CORRECTED")
    rb = F.radius_from_fold_key(b["rpred"], "CORRECTED")
    idx = np.clip(np.floor((a["p"] - m.lo) / m.cell).astype(int), 0, m.res - 1)
    inside = reach[idx[:, 0], idx[:, 1], idx[:, 2]] == 1
    first = a["bounce"] == a["bounce"].min()
    assert (~inside).sum() > 500 and (inside & first).sum() > 500
    floor = trs[1].chain_params().r_gated
    assert 0.0 < floor < 1e-6
    assert np.all(rb[~inside] == floor)
    assert np.all(rb[~inside] <= np.maximum(ra[~inside], floor))
    np.testing.assert_array_equal(rb[inside & first], ra[inside & first])


def test_reach_map_gates_hidden_surfaces_and_resumes_bit_for_bit(monkeypatch, tmp_path):
    """The reach map of a render (PhotonPass.keep_reach_source ->
    trace_ahead -> PhotonTracer.set_reach): with a narrow camera that sees
    the middle of the back wall only, most of the box's deposits fall in
    unmarked voxels; a render resumed from a checkpoint after pass 2
    (Renderer.load_state rebuilds the last pass's visible points) gives the
    uninterrupted render's image bit for bit."""
    from core.io import checkpoint
    from core.scene.model import Camera
    M = np.array([[1, 0, 0, 0], [0, 0, -1, -1.9], [0, 1, 0, 0.5], [0, 0, 0, 1]], float)
    monkeypatch.setattr(TPK, "_camera", lambda: Camera(
        kind="PERSP", matrix_world=M, lens=200.0, sensor_width=36.0, resolution=(16, 16),
        clip_start=0.01, clip_end=100.0))
    sc = TPK.cornell()
    st = RenderSettings(integrator="PHOTON", max_passes=4, photons_per_pass=4000, seed=3,
                        use_frequency=True, frequency_decay=0.0)
    full = Renderer(sc, st, log=lambda s: None).run()
    a = Renderer(sc, st.replace(max_passes=2), log=lambda s: None)
    a.run()
    reach, m = a.tracer.reach, a.tracer.march
    assert reach is not None
    dep = a.tracer.trace(3000, 3000, np.random.default_rng(1))
    idx = np.clip(np.floor((dep["p"] - m.lo) / m.cell).astype(int), 0, m.res - 1)
    assert np.mean(reach[idx[:, 0], idx[:, 1], idx[:, 2]] == 0) > 0.5
    checkpoint.save(str(tmp_path), a.state_dict())
    b = Renderer(sc, st, log=lambda s: None)
    b.load_state(checkpoint.load(str(tmp_path), Renderer.STATE_KEYS))
    assert np.array_equal(b.run().image, full.image)
