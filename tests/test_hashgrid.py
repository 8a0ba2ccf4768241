"""core.sppm.hashgrid: the grid gather must equal the O(P*K) numpy brute force.

The counting tests are evaluated in float64 in the same operation order by the
numba kernel and by the oracle tests/oracle_gather.py, so M, the (VP, photon)
pair sets and rpred_min are compared EXACTLY (no tolerance: a missed candidate or a VP
counted twice changes an integer).  Phi_sum differs only by summation order:
relative 1e-12 bounds n * eps = (a few hundred terms) * 1.1e-16 with a wide margin.
"""
import numpy as np
import pytest

from core.sppm import hashgrid as hg
from oracle_gather import gather_bruteforce


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


PLANES = [  # (point, normal): floor, wall, tilted plane, its back side
    (np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
    (np.array([1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])),
    (np.array([0.3, 0.4, 0.5]), _unit(np.array([1.0, 1.0, 1.0]))),
    (np.array([0.3, 0.4, 0.5]), -_unit(np.array([1.0, 1.0, 1.0]))),
]


def _on_planes(rng, n, jitter_normals=0.0):
    """n points on the PLANES (within ~1 unit of each plane's point), normals."""
    k = rng.integers(0, len(PLANES), n)
    pos = np.empty((n, 3))
    nrm = np.empty((n, 3))
    for i, (p0, nv) in enumerate(PLANES):
        m = k == i
        t1 = _unit(np.cross(nv, [0.3, 0.5, 0.7]))
        t2 = np.cross(nv, t1)
        ab = rng.uniform(-0.6, 0.6, (m.sum(), 2))
        pos[m] = p0 + ab[:, :1] * t1 + ab[:, 1:] * t2
        nrm[m] = nv
    if jitter_normals:
        nrm = _unit(nrm + jitter_normals * rng.normal(size=nrm.shape))
    return pos, nrm


def random_case(seed, K=1500, P=6000, radius_spread=100.0, f32=True):
    """VPs on 4 planes, radii log-uniform over radius_spread x, photons on the
    planes (1/6 of them scattered off-plane), random incident directions."""
    rng = np.random.default_rng(seed)
    vp_pos, vp_ng = _on_planes(rng, K)
    vp_R = 0.004 * np.exp(rng.uniform(0, np.log(radius_spread), K))
    ph_pos, ph_ng = _on_planes(rng, P, jitter_normals=0.4)
    off = rng.random(P) < 1 / 6
    ph_pos[off] += rng.normal(scale=0.05, size=(off.sum(), 3))
    # Half the photons near a VP (so each VP sees several), the rest anywhere.
    near = rng.random(P) < 0.5
    j = rng.integers(0, K, near.sum())
    ph_pos[near] = vp_pos[j] + _unit(rng.normal(size=(near.sum(), 3))) * \
        (vp_R[j] * rng.uniform(0, 1.2, near.sum()))[:, None]
    ph_ng[near] = vp_ng[j]
    dt = np.float32 if f32 else np.float64
    return dict(
        vp_pos=vp_pos, vp_ng=vp_ng, vp_R=vp_R, vp_R2=vp_R * vp_R,
        vp_const=rng.random(K) < 0.6, active=rng.random(K) < 0.85,
        ph_pos=ph_pos.astype(dt), ph_ng=ph_ng.astype(dt),
        ph_wi=_unit(rng.normal(size=(P, 3))).astype(dt),
        ph_power=rng.exponential(size=(P, 3)),
        ph_rpred=np.where(rng.random(P) < 0.3, rng.random(P), np.nan))


def _args(c):
    return (c["ph_pos"], c["ph_ng"], c["ph_wi"], c["ph_power"], c["ph_rpred"],
            c["vp_pos"], c["vp_ng"], c["vp_R2"], c["vp_const"])


def assert_same(res, ref, want_freq_pairs=False):
    np.testing.assert_array_equal(res.M, ref.M)
    np.testing.assert_allclose(res.Phi_sum, ref.Phi_sum, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(res.rpred_min, ref.rpred_min)
    got = np.stack([res.pair_vp, res.pair_ph], 1) if len(res.pair_vp) else np.zeros((0, 2))
    exp = np.stack([ref.pair_vp, ref.pair_ph], 1) if len(ref.pair_vp) else np.zeros((0, 2))
    got = got[np.lexsort(got.T[::-1])]
    exp = exp[np.lexsort(exp.T[::-1])]
    np.testing.assert_array_equal(got, exp)   # same pairs, each exactly once
    if want_freq_pairs:    # same set of (VP, frequency photon) pairs
        assert sorted(zip(res.freq_pair_vp.tolist(), res.freq_pair_ph.tolist())) == \
            sorted(zip(ref.freq_pair_vp.tolist(), ref.freq_pair_ph.tolist()))


def run_both(c, **build_kw):
    grid = hg.build_grid(c["vp_pos"], c["vp_R"], c["active"], **build_kw)
    ref = gather_bruteforce(*_args(c), active=c["active"], want_freq_pairs=True)
    for parallel in (False, True):
        res = hg.gather(grid, *_args(c), want_freq_pairs=True, parallel=parallel)
        assert_same(res, ref, want_freq_pairs=True)
    return grid, ref


@pytest.mark.parametrize("seed,f32,layout", [(0, True, "auto"), (1, False, "hash"),
                                             (2, True, "dense")])
def test_grid_equals_bruteforce_random(seed, f32, layout):
    c = random_case(seed, f32=f32)
    grid, ref = run_both(c, layout=layout)
    assert grid.dense == (layout == "dense") or layout == "auto"
    # The case must exercise every branch: counted photons, pairs, frequency
    # photons, and radii spanning 100x (many VPs larger than one cell).
    assert ref.M.sum() > 2000 and len(ref.pair_vp) > 500
    assert np.isfinite(ref.rpred_min).sum() > 200
    act_R = c["vp_R"][c["active"]]
    assert act_R.max() / act_R.min() > 50
    assert act_R.max() > 2 * grid.h          # the largest VPs span >= 4 cells per axis


def test_hash_collisions_never_double_count():
    # 2**3 slots for ~thousands of cells: every slot mixes many cells, and a
    # VP's own cells collide with each other; the per-slot mark must keep one copy.
    c = random_case(3, K=400, P=3000, radius_spread=20.0)
    grid, ref = run_both(c, log2_table=3)
    assert not grid.dense and grid.n_slots == 8
    assert np.diff(grid.cell_start).max() > 64    # exercises the no-hitmask path too
    assert ref.M.sum() > 500


def test_photons_on_cell_boundaries():
    """Photons exactly on cell faces/edges/corners (x = origin + i*h in float64),
    VPs on the same lattice, radius = 1 or 2 cells so distances hit R^2 exactly."""
    rng = np.random.default_rng(4)
    vp_lat = rng.integers(-6, 7, (300, 3)).astype(np.float64)
    vp_lat[:, 2] = 0.0
    h = 0.0625
    vp_pos = vp_lat * h
    vp_R = np.where(rng.random(300) < 0.5, h, 2 * h)
    c = dict(vp_pos=vp_pos, vp_ng=np.tile([0, 0, 1.0], (300, 1)), vp_R=vp_R,
             vp_R2=vp_R * vp_R, vp_const=rng.random(300) < 0.5,
             active=np.ones(300, bool))
    grid = hg.build_grid(vp_pos, vp_R, c["active"])
    P = 4000
    # Points on the grid's own cell faces, and on the VP lattice (half-steps).
    cells = rng.integers(-2, 30, (P // 2, 3))
    on_faces = grid.origin + cells * grid.h
    on_faces[:, 2] = 0.0
    on_lattice = rng.integers(-14, 15, (P - P // 2, 3)) * (h / 2)
    on_lattice[:, 2] = 0.0
    ph_pos = np.concatenate([on_faces, on_lattice])
    c.update(ph_pos=ph_pos, ph_ng=np.tile(np.float32([0, 0, 1]), (P, 1)),
             ph_wi=np.tile(np.float32([0, 0.6, 0.8]), (P, 1)),
             ph_power=rng.random((P, 3)),
             ph_rpred=np.where(rng.random(P) < 0.5, rng.random(P), np.nan))
    ref = gather_bruteforce(*_args(c), active=c["active"], want_freq_pairs=True)
    for kw in ({}, {"layout": "hash"}, {"cell_factor": 2.0}):
        grid = hg.build_grid(vp_pos, vp_R, c["active"], **kw)
        for parallel in (False, True):
            assert_same(hg.gather(grid, *_args(c), want_freq_pairs=True,
                                  parallel=parallel), ref, True)
    # plenty of lattice photons are inside: the case is not empty
    assert ref.M.sum() > 1000
    # distance exactly R does not count (strict <); one float64 ulp inside does
    one = dict(vp_pos=np.zeros((1, 3)), vp_ng=np.array([[0, 0, 1.0]]), vp_R=np.array([h]),
               vp_R2=np.array([h * h]), vp_const=np.ones(1, bool), active=np.ones(1, bool))
    x = np.array([[h, 0, 0], [0, -h, 0], [np.nextafter(h, 0), 0, 0]])
    one.update(ph_pos=x, ph_ng=np.tile([0, 0, 1.0], (3, 1)),
               ph_wi=np.tile([0, 0, 1.0], (3, 1)), ph_power=np.ones((3, 3)),
               ph_rpred=np.array([0.1, 0.2, 0.3]))
    r = hg.gather(hg.build_grid(one["vp_pos"], one["vp_R"], one["active"]), *_args(one))
    assert r.M[0] == 1 and r.rpred_min[0] == 0.3


def test_empty_inputs():
    c = random_case(5, K=50, P=200)
    # P = 0
    c0 = dict(c, ph_pos=c["ph_pos"][:0], ph_ng=c["ph_ng"][:0], ph_wi=c["ph_wi"][:0],
              ph_power=c["ph_power"][:0], ph_rpred=c["ph_rpred"][:0])
    run_both(c0)
    r = hg.gather(hg.build_grid(c["vp_pos"], c["vp_R"], c["active"]), *_args(c0))
    assert r.M.shape == (50,) and r.M.sum() == 0 and np.all(np.isinf(r.rpred_min))
    # K = 0
    k0 = dict(c, vp_pos=np.zeros((0, 3)), vp_ng=np.zeros((0, 3)), vp_R=np.zeros(0),
              vp_R2=np.zeros(0), vp_const=np.zeros(0, bool), active=np.zeros(0, bool))
    grid = hg.build_grid(k0["vp_pos"], k0["vp_R"], k0["active"])
    r = hg.gather(grid, *_args(k0), want_freq_pairs=True)
    assert r.M.shape == (0,) and r.Phi_sum.shape == (0, 3) and len(r.pair_vp) == 0
    assert len(r.freq_pair_ph) == 0
    # all VPs inactive: nothing counted although photons sit on the VPs
    ia = dict(c, active=np.zeros(50, bool), ph_pos=c["vp_pos"][np.arange(200) % 50])
    grid, ref = run_both(ia)
    assert grid.n_active == 0 and ref.M.sum() == 0 and len(ref.pair_vp) == 0
    # the same photons with the VPs active are counted (the case is not vacuous)
    _, ref2 = run_both(dict(ia, active=np.ones(50, bool)))
    assert ref2.M.sum() > 0


def test_corner_orientation_threshold():
    """Floor VP at a wall's foot: photons on the wall within R are rejected by
    the normal test (dot = 0 <= 0.5), accepted when cos_ng = -1; photons arriving
    from below the floor (dot(wi, ng) <= 0) are always rejected."""
    vp_pos = np.array([[0.01, 0.5, 0.0]])
    vp_ng = np.array([[0.0, 0.0, 1.0]])
    R = np.array([0.05])
    n = 100
    rng = np.random.default_rng(6)
    wall = np.stack([np.zeros(n), 0.5 + rng.uniform(-0.02, 0.02, n),
                     rng.uniform(0, 0.02, n)], 1)
    floor = np.stack([rng.uniform(0, 0.03, n), 0.5 + rng.uniform(-0.02, 0.02, n),
                      np.zeros(n)], 1)
    ph_pos = np.concatenate([wall, floor])
    ph_ng = np.concatenate([np.tile([1.0, 0, 0], (n, 1)), np.tile([0, 0, 1.0], (n, 1))])
    wi = np.tile(_unit(np.array([0.5, 0.0, 0.5])), (2 * n, 1))
    wi[n + n // 2:] *= -1                   # half the floor photons from below
    args = (ph_pos, ph_ng, wi, np.ones((2 * n, 3)), np.full(2 * n, np.nan),
            vp_pos, vp_ng, R * R, np.ones(1, bool))
    grid = hg.build_grid(vp_pos, R, np.ones(1, bool))
    assert hg.gather(grid, *args).M[0] == n // 2
    assert hg.gather(grid, *args, cos_ng=-1.0).M[0] == n + n // 2
    r = hg.gather(grid, *args, cos_ng=-1.0)
    np.testing.assert_allclose(r.Phi_sum[0], n + n // 2)
    assert np.all(np.isinf(r.rpred_min))


def test_radius_larger_than_grid_is_refused():
    c = random_case(7, K=30, P=10)
    grid = hg.build_grid(c["vp_pos"], c["vp_R"], c["active"])
    with pytest.raises(ValueError, match="rebuild the grid"):
        hg.gather(grid, *_args(dict(c, vp_R2=4 * c["vp_R2"])))
    with pytest.raises(ValueError, match="built for"):
        hg.gather(grid, *_args(dict(c, vp_pos=c["vp_pos"][:5])))


def test_nonfinite_photons_and_vps_ignored():
    c = random_case(8, K=200, P=1000)
    c["ph_pos"][::7] = np.nan
    c["ph_pos"][1::7, 0] = np.inf
    c["vp_pos"] = c["vp_pos"].copy()
    c["vp_pos"][::11] = np.nan
    c["ph_wi"][2::7] = np.nan                 # NaN direction / normals / R^2:
    c["vp_ng"] = c["vp_ng"].copy()            # the "count only if True"
    c["vp_ng"][3::11] = np.nan                # comparisons must reject them
    c["vp_R2"] = c["vp_R2"].copy()
    c["vp_R2"][4::11] = np.nan
    grid, ref = run_both(c)
    assert grid.n_active == int((c["active"] & np.isfinite(c["vp_pos"]).all(1)).sum())
    assert all(ref.M[k::11].sum() == 0 for k in (0, 3, 4))
    assert ref.M.sum() > 100


def _tangent_frames_numpy(ng):
    """(K, 6) the gather's frames as the numpy code computed them before they
    were computed per photon (Duff et al. 2017), the reference of the sector
    cells of every pinned image."""
    n = np.asarray(ng, np.float64).reshape(-1, 3)
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    return np.stack([1.0 + sign * n[:, 0] * n[:, 0] * a, sign * b, -sign * n[:, 0],
                     b, sign + n[:, 1] * n[:, 1] * a, -n[:, 1]], axis=1)


def test_inline_tangent_frame_equals_numpy_frames():
    """The frame computed per counted photon is the same bits as the numpy
    (K, 6) frames it replaced, on random unit normals, both hemispheres,
    n_z = +-0 and the poles; and it is orthonormal to the normal."""
    rng = np.random.default_rng(5)
    ng = _unit(rng.normal(size=(4000, 3)))
    ng[:200, 2] = 0.0
    ng[200:400, 2] = -0.0
    ng[:400] = _unit(ng[:400])
    ng[400:402] = [[0, 0, 1], [0, 0, -1]]
    ref = _tangent_frames_numpy(ng)
    got = np.array([hg._tangent_frame(*n) for n in ng])
    assert np.array_equal(got.view(np.int64), ref.view(np.int64))
    t1, t2 = got[:, :3], got[:, 3:]
    for a, b in ((t1, ng), (t2, ng), (t1, t2)):
        assert np.abs((a * b).sum(axis=1)).max() < 1e-12
    assert np.abs(np.linalg.norm(t1, axis=1) - 1).max() < 1e-12


def _sector_cells_branches(u, w, d2, r2):
    """The sector cells as the gather computed them with branches before
    round 21 (quadrant of (u, w), outer ring from 2 d2 >= r2), in numpy."""
    q = np.where(u < 0.0, np.where(w >= 0.0, 1, 2), np.where(w < 0.0, 3, 0))
    return q + np.where(2.0 * d2 >= r2, hg.SECTOR_QUADRANTS, 0)


def test_sector_cell_arithmetic_equals_branches():
    """hashgrid._sector_of (the quadrant in arithmetic, no branch) is the
    branching rule it replaced, on random offsets, the axes (+-0), the ring's
    boundary 2 d2 = r2 and NaN / inf (NaN w with u < 0: quadrant 2)."""
    rng = np.random.default_rng(21)
    n = 20000
    u = rng.normal(size=n)
    w = rng.normal(size=n)
    d2 = u * u + w * w + rng.random(n) * 0.1
    r2 = d2 * rng.uniform(1.0, 3.0, n)
    special = np.array([0.0, -0.0, 1.0, -1.0, np.nan, np.inf, -np.inf])
    su, sw = np.meshgrid(special, special)
    u = np.r_[u, su.ravel()]
    w = np.r_[w, sw.ravel()]
    m = su.size
    d2 = np.r_[d2, np.full(m, 0.5)]
    r2 = np.r_[r2, np.where(np.arange(m) % 2 == 0, 1.0, np.nan)]   # 2 d2 == r2, and NaN
    ref = _sector_cells_branches(u, w, d2, r2)
    got = np.array([hg._sector_of(*a) for a in zip(u, w, d2, r2)])
    np.testing.assert_array_equal(got, ref)
    assert set(np.unique(ref)) == set(range(hg.SECTOR_CELLS))
