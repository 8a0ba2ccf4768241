"""The kernel clip's rays cast only for the visible points near a wall
(core.sppm.clip ``_near``, ``NearGrid``): the codes are the bits of casting
every active point's rays (``clip_codes(..., near=False)``), on scenes made
to catch a test that is not conservative: walls just within and just out of
reach, diagonal and degenerate triangles, a curved mesh the points lie on, a
flat scene, points outside the triangles' box, radii larger than the scene,
and a grid too fine for its entry budget.  And the codes' array is reused
from call to call only while nothing else holds it.
"""
import math

import numpy as np
import pytest

from core.accel import Accel
from core.sppm import clip as C
from core.sppm import hashgrid as hg
from test_clip import WALL, _codes, _wall_accel


def _both(acc, p, ng, R2, active):
    near = _codes(acc, p, ng, R2, active)
    every = _codes(acc, p, ng, R2, active, near=False)
    assert np.array_equal(near, every)
    return every


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_walls_at_the_edge_of_reach():
    """Floor points whose distance to the wall is R (1 + x), x in +-1e-3:
    the edge rays that point at the wall end just before or just after it.
    Normals tilted up to 30 degrees, so the rays leave the floor plane."""
    rng = np.random.default_rng(11)
    n = 6000
    R = rng.uniform(0.01, 0.3, n)
    x = WALL - R * (1.0 + rng.uniform(-1e-3, 1e-3, n))
    p = np.c_[x, rng.uniform(-5, 5, n), np.zeros(n)]
    tilt = np.radians(rng.uniform(0, 30, n))
    az = rng.uniform(0, 2 * np.pi, n)
    ng = np.c_[np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
    codes = _both(_wall_accel(), p, ng, R ** 2, rng.random(n) > 0.05)
    clipped = np.count_nonzero(codes != hg.CLIP_CLEAR)
    assert 0.02 * n < clipped < 0.5 * n          # 8 %: edges that point at the wall


def _soup(rng, n, size):
    """n random triangles in the unit cube, of about `size`: diagonal planes,
    slivers, and a few degenerate ones (a repeated vertex, collinear)."""
    c = rng.random((n, 1, 3))
    tri = c + rng.normal(0, size, (n, 3, 3))
    tri[: n // 20, 2] = tri[: n // 20, 0]                                   # repeated vertex
    tri[n // 20: n // 10, 2] = 2 * tri[n // 20: n // 10, 1] - tri[n // 20: n // 10, 0]  # collinear
    return tri.astype(np.float32)


def _points_on(rng, tri, n):
    """n points on random triangles of tri, with those triangles' normals
    (zero-area ones replaced by +z), so that walls around are at every angle."""
    k = rng.integers(0, tri.shape[0], n)
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    T = tri[k].astype(np.float64)
    p = T[:, 0] + u[:, None] * (T[:, 1] - T[:, 0]) + v[:, None] * (T[:, 2] - T[:, 0])
    ng = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    ln = np.linalg.norm(ng, axis=1)
    ng[ln < 1e-12] = (0, 0, 1)
    return p, _unit(ng)


def test_a_triangle_soup():
    """400 triangles at every angle (a tenth degenerate), 5000 points on them
    and 1000 in the air with random normals, radii from a 1000th to a
    tenth of the scene."""
    rng = np.random.default_rng(12)
    tri = _soup(rng, 400, 0.08)
    acc = Accel(tri, 2.0)
    p1, n1 = _points_on(rng, tri, 5000)
    p2, n2 = rng.random((1000, 3)), _unit(rng.normal(size=(1000, 3)))
    p, ng = np.r_[p1, p2], np.r_[n1, n2]
    R2 = np.exp(rng.uniform(np.log(1e-3), np.log(0.1), p.shape[0])) ** 2
    codes = _both(acc, p, ng, R2, np.ones(p.shape[0], bool))
    near = C._near_points(C.near_grid(acc.tri_p), _tri_ng(acc), p, ng, R2,
                          np.ones(p.shape[0], bool), C.REL_OFFSET,
                          acc.abs_floor / C.REL_OFFSET, np.empty(p.shape[0], np.uint64))
    clipped = np.count_nonzero(codes != hg.CLIP_CLEAR)
    # the test skips most points and keeps every clipped one
    assert 0 < clipped <= near.size < 0.6 * p.shape[0]


def _tri_ng(acc):
    from types import SimpleNamespace
    from core.sppm.photon_kernels import build_triangle_data
    s = SimpleNamespace(tri_p=acc.tri_p, tri_n=np.zeros_like(acc.tri_p),
                        tri_mat=np.zeros(acc.tri_p.shape[0], np.int32))
    return build_triangle_data(s).ng


def test_points_on_a_sphere_mesh():
    """A sphere of 3,200 triangles with points on it: the edge rays start
    inside the curve and hit the sphere itself (not a wall to them); a
    radius larger than the sphere spans more cells than a point tests."""
    rng = np.random.default_rng(13)
    th = np.linspace(0, np.pi, 41)
    ph = np.linspace(0, 2 * np.pi, 41)
    V = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph),
                  np.cos(th)[:, None] * np.ones_like(ph)], axis=-1)
    q = [(V[i, j], V[i + 1, j], V[i + 1, j + 1], V[i, j + 1]) for i in range(40) for j in range(40)]
    tri = np.array([t for a, b, c, d in q for t in ((a, b, c), (a, c, d))], np.float32)
    acc = Accel(tri, 2.0)
    p, ng = _points_on(rng, tri, 4000)
    out = np.sum(p * ng, axis=1) < 0
    ng[out] *= -1                                  # outward (the sphere seen from outside)
    R2 = np.exp(rng.uniform(np.log(1e-3), np.log(3.0), p.shape[0])) ** 2
    _both(acc, p, ng, R2, np.ones(p.shape[0], bool))


def test_a_flat_scene_and_points_away_from_it():
    """Every triangle in the plane z = 0 (a flat grid box), walls standing on
    it from z = 0 only in a second accel; points above, below, far outside
    the triangles' box."""
    rng = np.random.default_rng(14)
    floor = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]],
                     np.float32)
    wall = np.array([[[0.5, 0, 0], [0.5, 1, 0], [0.5, 1, 1]], [[0.5, 0, 0], [0.5, 1, 1],
                                                                [0.5, 0, 1]]], np.float32)
    n = 3000
    p = np.c_[rng.uniform(-1, 2, n), rng.uniform(-1, 2, n), rng.uniform(-0.2, 0.2, n)]
    p[:200] += 1e3                                  # far out
    ng = _unit(rng.normal(size=(n, 3)))
    ng[: n // 2] = (0, 0, 1)
    R2 = rng.uniform(0.01, 0.4, n) ** 2
    for tri in (floor, np.r_[floor, wall]):
        _both(Accel(tri, 2.0), p, ng, R2, rng.random(n) > 0.1)


def test_a_grid_over_its_entry_budget_coarsens():
    """Large diagonal triangles would put far more than
    NEAR_ENTRIES_PER_TRIANGLE entries a triangle in the finest grid: the
    grid coarsens until they fit, and the codes are still every point's."""
    rng = np.random.default_rng(15)
    tri = _soup(rng, 300, 1.0)
    g = C.near_grid(tri)
    T = tri.shape[0]
    assert g.entries.size <= C.NEAR_ENTRIES_PER_TRIANGLE * T + C.NEAR_MIN_CELLS
    assert int(np.prod(g.dims)) < C.NEAR_MIN_CELLS     # coarser than the first try
    acc = Accel(tri, 3.0)
    p, ng = _points_on(rng, tri, 3000)
    R2 = rng.uniform(0.005, 0.1, p.shape[0]) ** 2
    _both(acc, p, ng, R2, np.ones(p.shape[0], bool))


def _flat_tiles(k):
    """A k x k tiled floor (2 k^2 triangles in z = 0)."""
    x = np.arange(k + 1, dtype=np.float64) / k
    a = np.stack(np.meshgrid(x[:-1], x[:-1], indexing="ij"), -1).reshape(-1, 2)
    d = 1.0 / k
    corners = [a, a + (d, 0), a + (d, d), a + (0, d)]
    c = [np.c_[q, np.zeros(len(q))] for q in corners]
    return np.concatenate([np.stack([c[0], c[1], c[2]], 1), np.stack([c[0], c[2], c[3]], 1)]
                          ).astype(np.float32)


@pytest.mark.parametrize("case", ["soup", "big soup", "tiles", "one"])
def test_grid_bytes_within_the_memory_estimate(case):
    from core import memory
    rng = np.random.default_rng(17)
    tri = {"soup": lambda: _soup(rng, 20000, 0.01), "big soup": lambda: _soup(rng, 3000, 1.0),
           "tiles": lambda: _flat_tiles(120),
           "one": lambda: _soup(rng, 1, 0.1)}[case]()
    g = C.near_grid(tri)
    used = g.start.nbytes + g.entries.nbytes
    assert used <= tri.shape[0] * memory.BYTES_PER_CLIP_TRIANGLE + memory.CLIP_GRID_BYTES


def test_no_grid_without_finite_triangles():
    tri = np.zeros((2, 3, 3), np.float32)
    tri[1, 1, 0] = np.nan
    assert C.near_grid(tri) is None
    assert C.near_grid(np.zeros((0, 3, 3), np.float32)) is None


def test_the_codes_array_is_reused_only_when_dropped():
    acc = _wall_accel()
    rng = np.random.default_rng(16)
    n = 500
    p = np.c_[rng.uniform(WALL - 1, WALL - 0.01, n), rng.uniform(-5, 5, n), np.zeros(n)]
    ng = np.tile([0.0, 0.0, 1.0], (n, 1))
    R2 = rng.uniform(0.05, 0.5, n) ** 2
    tng = _tri_ng(acc)
    a = C.clip_codes(acc, tng, p, ng, R2, np.ones(n, bool))
    first = a.copy()
    b = C.clip_codes(acc, tng, p, ng, np.full(n, 1e-4), np.ones(n, bool))
    assert not np.shares_memory(a, b)                 # a is held: not overwritten
    assert np.array_equal(a, first) and (b == hg.CLIP_CLEAR).all()
    addr = b.ctypes.data
    del a, b
    c = C.clip_codes(acc, tng, p, ng, R2, np.ones(n, bool))
    assert np.array_equal(c, first)
    d_addr = c.ctypes.data
    del c
    assert C.clip_codes(acc, tng, p, ng, R2, np.ones(n, bool)).ctypes.data in (addr, d_addr)
