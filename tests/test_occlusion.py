"""Occlusion grid (core.frequency.occlusion_grid, occlusion_march): exact voxel
distances, bi-cones, marching.

Every tolerance below is derived in a comment from the grid's own resolution
(voxel size h) or from float32 storage; nothing is random at run time (fixed
seeds).
"""
import numpy as np
import pytest

from core.frequency.occlusion_grid import BYTES_PER_VOXEL, build_occlusion_grid, default_locality
from core.frequency.occlusion_march import march_occlusion

from builds import EARLIER_CPU, for_this_cpu


# ------------------------------------------------------------------ helpers

def quad(p0, p1, p2, p3):
    """Two triangles (p0 p1 p2), (p0 p2 p3)."""
    return [[p0, p1, p2], [p0, p2, p3]]


def box(lo, hi):
    """12 triangles of an axis-aligned box."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
         (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (2, 3, 7, 6), (1, 2, 6, 5), (0, 4, 7, 3)]
    tris = []
    for a, b, c, d in faces:
        tris += quad(v[a], v[b], v[c], v[d])
    return tris


def icosphere(center, radius, subdiv):
    """Geodesic sphere; vertices ON the sphere, so the mesh lies inside it."""
    t = (1 + 5 ** 0.5) / 2
    V = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t),
         (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    F = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    tri = np.array([[V[i] for i in f] for f in F], np.float64)
    tri /= np.linalg.norm(tri, axis=-1, keepdims=True)
    for _ in range(subdiv):
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        ab, bc, ca = [(u + w) / np.linalg.norm(u + w, axis=-1, keepdims=True)
                      for u, w in ((a, b), (b, c), (c, a))]
        tri = np.concatenate([np.stack(s, 1) for s in
                              ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return tri * radius + np.asarray(center, np.float64)


def brute_distance(p, tri):
    """Point-triangle distance by a different algorithm than the module's
    (plane projection + inside test, else the nearest of the 3 edges), float64.
    p (P, 3), tri (T, 3, 3) -> (P,) min over triangles."""
    tri = tri.astype(np.float64)[None]
    p = p[:, None, :]
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    h = ((p - a) * n).sum(-1)
    q = p - h[..., None] * n

    def side(u, w):
        return (np.cross(w - u, q - u) * n).sum(-1)

    def seg2(u, w):
        e = w - u
        s = np.clip(((p - u) * e).sum(-1) / (e * e).sum(-1), 0, 1)
        return ((p - u - s[..., None] * e) ** 2).sum(-1)

    inside = (side(a, b) >= 0) & (side(b, c) >= 0) & (side(c, a) >= 0)
    edge = np.minimum(np.minimum(seg2(a, b), seg2(b, c)), seg2(c, a))
    return np.sqrt(np.where(inside, h * h, edge)).min(axis=1)


UNIT_LO, UNIT_HI = np.zeros(3), np.ones(3)


# ------------------------------------------------------------------ build

def test_voxel_distances_match_brute_force():
    rng = np.random.default_rng(7)
    # 50 random triangles (large and overlapping: all three corners uniform in
    # the box) plus 50 small ones, so both long and short distances occur.
    big = rng.random((50, 3, 3))
    small = rng.random((50, 1, 3)) + 0.05 * (rng.random((50, 3, 3)) - 0.5)
    tri = np.concatenate([big, small]).astype(np.float32)
    R = 12
    g = build_occlusion_grid(tri, UNIT_LO, UNIT_HI, R)
    idx = np.indices((R, R, R)).reshape(3, -1).T
    centres = g.lo + (idx + 0.5) * g.cell
    ref = brute_distance(centres, tri).reshape(R, R, R)
    assert g.dist.dtype == np.float32 and g.dist.shape == (R, R, R)
    # Both are exact in float64 from the same float32 corners; the grid then
    # stores float32: relative error <= 2^-24 = 6e-8 of the value, plus the
    # float64 cancellation in the brute force's plane projection (~1e-15 D).
    np.testing.assert_allclose(g.dist, ref, rtol=1.2e-7, atol=1e-12)
    assert ref.min() < 0.5 * g.cell.min() and ref.max() > 2 * g.cell.max()  # range exercised


def test_nearest_query_skips_no_triangle_that_could_win():
    """_nearest_all skips a leaf's triangle whose own box is farther than the
    best so far plus a margin (docs/frequency.md "The set-up: the occlusion
    grid and its march blocks"): the distances and closest points are those
    of the same query testing every triangle it reaches (slack = inf), bit
    for bit, on an axis-aligned box with a post and a sphere (exact ties
    between a wall's two triangles) and on random triangles, with voxels
    nearer than the cap and beyond it.  (What it saves: 168 -> 72 ms CPU on
    cornell.blend's 64^3 grid, measured in that section.)"""
    from core.frequency import occlusion_grid as OG
    rng = np.random.default_rng(3)
    scenes = [np.concatenate([np.array(box((0, 0, 0), (2, 1.5, 1))),
                              np.array(box((0.3, 0.2, 0.0), (0.5, 0.25, 0.6))),
                              icosphere((1.2, 0.7, 0.35), 0.3, 1)]).astype(np.float32),
              rng.random((60, 3, 3)).astype(np.float32)]
    for tri in scenes:
        p = tri.reshape(-1, 3)
        lo, hi = OG.grid_bounds(p.min(0), p.max(0))
        R = 24
        cell = (hi - lo) / R
        tris, node_lo, node_hi, n_leaves = OG._build_bvh(tri)
        t_lo, t_hi = tris.min(axis=1).astype(np.float64), tris.max(axis=1).astype(np.float64)
        cap = 2.0 * float(np.linalg.norm(cell))
        slack = OG.NEAREST_SLACK * float(np.sum(np.square(hi - lo)))
        out = []
        for s in (slack, np.inf):
            d, q = np.empty(R ** 3), np.empty((R ** 3, 3))
            OG._nearest_all(tris, t_lo, t_hi, node_lo, node_hi, n_leaves, lo, cell, R, cap, s, d, q)
            out.append((d, q))
        assert np.array_equal(out[0][0], out[1][0])
        assert np.array_equal(out[0][1], out[1][1], equal_nan=True)
        assert np.isnan(out[0][1][:, 0]).any() and (out[0][0] < cap).any()   # both kinds of voxel


def test_blocked_nearest_queries_equal_the_query_per_voxel():
    """_nearest_blocked (the build's nearest-triangle queries since round 17:
    each block of NEAREST_BLOCK^3 voxels tests only the triangles within its
    bound, docs/frequency.md "The nearest-triangle queries by block, round
    17") gives _nearest_all's distances and closest points bit for bit, the
    closest points' coordinates of capped voxels included: an axis-aligned
    box with a post and a sphere (exact ties between a wall's two
    triangles), the same with the sphere finer (blocks with more candidates
    than NEAREST_CANDIDATES query the BVH), random triangles, and a far
    small box (blocks capped whole); caps of 2 and 10 voxel diagonals and
    none; grids of 24, 32 and 33 voxels (a last block cut short).  Every
    branch is taken: blocks capped whole, listed and querying the BVH, and
    voxels whose candidates tie running the query."""
    from core.frequency import occlusion_grid as OG
    rng = np.random.default_rng(3)
    walls = np.array(box((0, 0, 0), (2, 1.5, 1)))
    post = np.array(box((0.3, 0.2, 0.0), (0.5, 0.25, 0.6)))
    scenes = [np.concatenate([walls, post, icosphere((1.2, 0.7, 0.35), 0.3, 1)]),
              np.concatenate([walls[:10], post, icosphere((1.2, 0.7, 0.35), 0.3, 3),
                              np.array(box((3.8, 2.8, 1.9), (4.0, 3.0, 2.0)))]),
              rng.random((60, 3, 3))]
    seen = np.zeros(5, np.int64)
    for tri in scenes:
        tri = tri.astype(np.float32)
        p = tri.reshape(-1, 3)
        tris, node_lo, node_hi, n_leaves = OG._build_bvh(tri)
        t_lo, t_hi = tris.min(axis=1).astype(np.float64), tris.max(axis=1).astype(np.float64)
        for R in (24, 32, 33):
            lo, hi = OG.grid_bounds(p.min(0), p.max(0))
            cell = (hi - lo) / R
            slack = OG.NEAREST_SLACK * float(np.sum(np.square(hi - lo)))
            diag = float(np.linalg.norm(cell))
            for cap in (2.0 * diag, 10.0 * diag, np.inf):
                d0, q0 = np.empty(R ** 3), np.empty((R ** 3, 3))
                d1, q1 = np.empty(R ** 3), np.empty((R ** 3, 3))
                OG._nearest_all(tris, t_lo, t_hi, node_lo, node_hi, n_leaves, lo, cell, R, cap,
                                slack, d0, q0)
                seen += OG._nearest_blocked(tris, t_lo, t_hi, node_lo, node_hi, n_leaves, lo,
                                            cell, R, cap, slack, d1, q1)
                assert np.array_equal(d0, d1)
                assert np.array_equal(q0, q1, equal_nan=True)
    # capped whole, listed, querying the BVH, candidates, tie queries
    assert seen[0] > 0 and seen[1] > 0 and seen[2] > 0 and seen[4] > 0, seen


def test_voxel_level_memo_equals_the_block_loop():
    """_voxel_level (the march blocks' voxel level with its cones computed once
    per distinct sequence of members, round 17) gives the vcone of
    _build_blocks with B = 1 bit for bit, every voxel (also those the march
    never reads), on the digest scene below (an open box, a sphere of many
    distinct cones, a post and a far box) at 32 and 33 voxels; and
    march_blocks gives the same MarchBlocks with VOXEL_LEVEL_MEMO off."""
    from core.frequency import occlusion_grid as OG
    tri = np.concatenate([np.array(box((0, 0, 0), (2, 1.5, 1)))[:10],
                          icosphere((1.2, 0.7, 0.35), 0.3, 2),
                          np.array(box((0.3, 0.2, 0.0), (0.5, 0.25, 0.6))),
                          np.array(box((3.8, 2.8, 1.9), (4.0, 3.0, 2.0)))]).astype(np.float32)
    p = tri.reshape(-1, 3)
    for R in (32, 33):
        g = build_occlusion_grid(tri, p.min(0), p.max(0), R,
                                 max_distance=10 * np.linalg.norm(np.array([4, 3, 2]) / R))
        L = OG.cut_locality(float(g.cell[0]), float(g.cell[1]), float(g.cell[2]))
        kind, un, asn = np.empty((R, R, R), np.int8), np.empty((R, R, R, 3)), np.empty((R, R, R))
        OG._cone_members(g.cone, R, kind, un, asn)
        vm = np.empty((R, R, R))
        OG._dilated_min(g.dist, R, vm, np.empty((R, R, R)))
        a, b = np.zeros((R, R, R, 8), np.int16), np.zeros((R, R, R, 8), np.int16)
        OG._build_blocks(g.dist, kind, un, asn, R, 1, R, vm.copy(), a, L, True, vm.copy())
        code, mu = np.empty((R, R, R), np.int32), np.empty(R ** 3, np.int64)
        members = OG._member_codes(kind, un.view(np.int64), asn.view(np.int64), g.dist, vm, R, L,
                                   code, mu)
        sequences = OG._voxel_level(code, mu, un, asn, R, vm, b, L)
        assert np.array_equal(a, b)
        assert 1 < members < sequences < np.count_nonzero(vm * (1 - OG.BLOCK_REL) < L)
    old = OG.VOXEL_LEVEL_MEMO
    try:
        mbs = []
        for memo in (True, False):
            OG.VOXEL_LEVEL_MEMO = memo
            g2 = build_occlusion_grid(tri, p.min(0), p.max(0), 32,
                                      max_distance=10 * np.linalg.norm(np.array([4, 3, 2]) / 32))
            mbs.append(OG.march_blocks(g2))
    finally:
        OG.VOXEL_LEVEL_MEMO = old
    for f in ("bmin", "bcone", "vmin", "vcone"):
        assert np.array_equal(getattr(mbs[0], f), getattr(mbs[1], f)), f


def test_distinct_rows_index_every_row_by_its_bits():
    """_distinct_rows (the build's eigh batch on the distinct sums only, round
    17): the first rows of each distinct row in order of first occurrence,
    and each row's index among them, as np.unique finds them; the grid it
    feeds is checked bit for bit by test_grid_and_march_blocks_equal_the_build_before."""
    from core.frequency import occlusion_grid as OG
    rng = np.random.default_rng(7)
    base = rng.random((40, 6))
    rows = base[rng.integers(0, 40, 5000)]
    inv = np.empty(len(rows), np.int64)
    first = OG._distinct_rows(rows.view(np.int64), inv)
    assert np.array_equal(rows[first][inv], rows)
    assert len(first) == len(np.unique(rows, axis=0)) == 40
    assert np.all(np.diff(first) > 0) and np.array_equal(inv[first], np.arange(40))


def test_dilated_min_equals_the_neighbourhood_loop():
    """_dilated_min (the voxel level's minima in three one-axis passes, round
    17) equals the minimum over each voxel's 3^3 neighbourhood clipped to the
    grid, bit for bit, on random float32 distances with infinities."""
    from core.frequency import occlusion_grid as OG
    rng = np.random.default_rng(5)
    R = 9
    dist = rng.random((R, R, R)).astype(np.float32)
    dist[rng.random((R, R, R)) < 0.1] = np.inf
    out = np.empty((R, R, R))
    OG._dilated_min(dist, R, out, np.empty((R, R, R)))
    pad = np.pad(dist.astype(np.float64), 1, constant_values=np.inf)
    ref = np.full((R, R, R), np.inf)
    for a in range(3):
        for b in range(3):
            for c in range(3):
                ref = np.minimum(ref, pad[a:a + R, b:b + R, c:c + R])
    assert np.array_equal(out, ref)


def test_bicone_of_floor_wall_and_corner():
    tri = np.array(quad((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0))
                   + quad((0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)), np.float32)
    R = 8
    g = build_occlusion_grid(tri, UNIT_LO, UNIT_HI, R)
    # A flat floor voxel: axis +-z, aperture 0 (float32 eigenvector ~1e-7).
    assert g.occupied[4, 4, 0]
    assert abs(abs(g.axis[4, 4, 0, 2]) - 1) < 1e-6 and g.aperture[4, 4, 0] < 1e-3
    # The corner voxel holds floor (z) and wall (x) normals with equal areas:
    # axis along the bisector (x + z)/sqrt2, aperture exactly 45 degrees.
    ax = g.axis[0, 4, 0]
    assert abs(abs(ax[0]) - 2 ** -0.5) < 1e-5 and abs(abs(ax[2]) - 2 ** -0.5) < 1e-5
    assert abs(g.aperture[0, 4, 0] - np.pi / 4) < 1e-5
    # Empty voxels: unknown cone (pi/2), not occupied, and 'near' points to
    # the occupied voxel holding their closest point.
    assert not g.occupied[6, 4, 2] and g.aperture[6, 4, 2] == np.float32(np.pi / 2)
    assert g.near[6, 4, 2] == (6 * R + 4) * R + 0      # floor below (z 0.31 < x 0.81)
    assert g.near[2, 4, 6] == (0 * R + 4) * R + 6      # wall beside (x 0.31 < z 0.81)
    assert g.nbytes == R ** 3 * BYTES_PER_VOXEL


def test_max_distance_caps_only_far_voxels():
    rng = np.random.default_rng(11)
    tri = rng.random((200, 1, 3)) * 0.6 + 0.05 * (rng.random((200, 3, 3)) - 0.5)
    tri = tri.astype(np.float32)
    exact = build_occlusion_grid(tri, UNIT_LO, UNIT_HI, 16)
    cap = 0.2
    capped = build_occlusion_grid(tri, UNIT_LO, UNIT_HI, 16, max_distance=cap)
    near = exact.dist < cap
    assert 0.2 < near.mean() < 0.9                      # both kinds of voxel present
    # Same exact distances (bit-identical float32) below the cap, the cap above.
    assert np.array_equal(capped.dist[near], exact.dist[near])
    assert np.all(capped.dist[~near] == np.float32(cap)) and np.all(capped.near[~near] == -1)
    o = rng.random((500, 3)) * 0.6                        # among the triangles
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    loc = cap - 1.5 * exact.voxel_diagonal
    a, b = (march_occlusion(g, o, d, np.full(500, 0.6), loc) for g in (exact, capped))
    assert np.array_equal(a, b) and np.isfinite(a).mean() > 0.2
    with pytest.raises(ValueError):
        march_occlusion(capped, o, d, np.full(500, 0.6), cap)


def test_empty_scene_has_no_occluder():
    g = build_occlusion_grid(np.zeros((0, 3, 3), np.float32), UNIT_LO, UNIT_HI, 8)
    assert np.all(np.isinf(g.dist)) and not g.occupied.any()
    a = march_occlusion(g, [[0.5, 0.5, 0.1]], [[0, 0, 1.0]], [0.8], 0.5)
    assert np.isinf(a[0])


# ------------------------------------------------------------------ march

R32 = 32
H = 1.0 / R32       # voxel size of the 32^3 unit grid


@pytest.fixture(scope="module")
def floor_and_wall():
    """Floor z = 0 over the unit square and a thin wall (4 mm thick box)
    centred on x = 0.5, 0.8 m high, across y in [0, 1]."""
    tri = np.array(quad((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0))
                   + box((0.498, 0.0, 0.0), (0.502, 1.0, 0.8)), np.float32)
    return build_occlusion_grid(tri, UNIT_LO, UNIT_HI, R32)


def test_ray_onto_reflecting_plane_is_not_occluded(floor_and_wall):
    g = floor_and_wall
    # 0.15 = 5 voxels: the floor is within it over the last 0.15 m of the
    # rays; the wall (0.3 m and more away) is not.
    # Straight down and at 45 degrees onto the floor, away from the wall: the
    # floor's normals lie along the ray's plane of incidence, far from the
    # plane orthogonal to the ray -> the receiver, not an occluder.
    o = np.array([[0.2, 0.5, 0.6], [0.1, 0.3, 0.3]])
    d = np.array([[0, 0, -1.0], [2 ** -0.5, 0, -(2 ** -0.5)]])
    t = np.array([0.6, 0.3 * 2 ** 0.5])
    assert np.all(np.isinf(march_occlusion(g, o, d, t, 0.15)))
    # The same ray leaving the floor (the emitter/reflector at the start).
    assert np.all(np.isinf(march_occlusion(g, o + t[:, None] * d, -d, t, 0.15)))
    # With a locality of 0.35 the wall, seen edge-on by the vertical ray 0.298 m
    # away (the wall face is at x = 0.498), becomes its occluder.  Near
    # z = 0.298 floor and wall are equally far: the interpolant of the concave
    # min(z, 0.298) kink underestimates it there, by less than h/2 (the
    # 8 centres are within a voxel of the sample and the field is 1-Lipschitz).
    a = march_occlusion(g, o[:1], d[:1], t[:1], 0.35)
    assert 0.298 - 0.5 * H < np.sqrt(a[0]) <= 0.298 + 1e-6


def test_ray_beside_thin_wall_reports_its_distance(floor_and_wall):
    g = floor_and_wall
    deltas = np.array([0.01, 0.02, 0.05, 0.1])
    n = len(deltas)
    # Rays along +y at height 0.5 (0.3 below the wall's top, 0.5 above the
    # floor: both beyond the locality for the floor), delta off the wall face.
    o = np.stack([0.502 + deltas, np.full(n, 0.05), np.full(n, 0.5)], 1)
    d = np.tile([0.0, 1.0, 0.0], (n, 1))
    a = march_occlusion(g, o, d, np.full(n, 0.9), 0.15)
    r = np.sqrt(a)
    # The wall's distance field is linear in x between voxel centres on the
    # same side of the wall, so the interpolated distance is exact there (up
    # to float32 storage); when the wall lies between the two centres the
    # interpolant of |x| overestimates by at most h/2 (its kink is cut).
    assert np.all(np.isfinite(a))
    assert np.all(r >= deltas - 1e-6) and np.all(r <= deltas + 0.5 * H)
    far = deltas > 1.5 * H + 0.002
    np.testing.assert_allclose(r[far], deltas[far], rtol=1e-5)
    # Same rays with a locality below their distance: no occluder.
    b = march_occlusion(g, o, d, np.full(n, 0.9), 0.03)
    assert np.all(np.isfinite(b[deltas < 0.025])) and np.all(np.isinf(b[deltas > 0.04]))


def test_segment_ending_next_to_an_occupied_voxel_is_not_narrowed(floor_and_wall):
    """A photon landing on the open floor within half a voxel of the wall's
    foot, arriving towards the wall from the open side, is not occluded: the
    voxels at the foot hold floor and wall, so their cone meets every plane
    (45 degrees about the bisector), and without the receiving plane the
    march credited them with the floor's own distance (docs/frequency.md
    "Occlusion": the surfaces a segment connects are not its occluders)."""
    g = floor_and_wall
    loc = default_locality(g)
    rng = np.random.default_rng(3)
    n = 2000
    gap = rng.uniform(0.05, 0.5, n) * H
    p = np.stack([0.498 - gap, rng.uniform(0.2, 0.8, n), np.zeros(n)], 1)
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    w[:, 0], w[:, 2] = np.abs(w[:, 0]), -np.abs(w[:, 2])
    # towards the wall (no segment crosses it), not grazing the floor
    ok = (w[:, 0] > 0.3) & (w[:, 2] < -0.2)
    d, p = w[ok], p[ok]
    m = len(d)
    t = np.full(m, 0.4)
    o = p - t[:, None] * d
    up = np.tile([0.0, 0.0, 1.0], (m, 1))
    before = march_occlusion(g, o, d, t, loc)
    after, t_occ = march_occlusion(g, o, d, t, loc, n_end=up, return_t=True)
    # measured: 14.9 % of these segments occluded before, 0.46 % after
    assert np.isfinite(before).mean() > 0.10
    assert np.isfinite(after).mean() < 0.01
    # What is left is the wall (nearer than the floor by more than half a
    # voxel), at its own distance (interpolation: within h/2).
    f = np.isfinite(after)
    q = o[f] + t_occ[f, None] * d[f]
    np.testing.assert_allclose(np.sqrt(after[f]), 0.498 - q[:, 0], atol=0.5 * H)
    assert np.all(np.sqrt(after[f]) < q[:, 2] - 0.5 * H)
    # The same segments leaving the floor (the plane they leave): likewise.
    before = march_occlusion(g, p, -d, t, loc)
    after = march_occlusion(g, p, -d, t, loc, n_start=up)
    assert np.isfinite(before).mean() > 0.10 and np.isfinite(after).mean() < 0.01


def test_end_planes_keep_a_real_occluder(floor_and_wall):
    """A segment leaving the floor beside the wall, rising along it (the
    wall edge-on at 0.038 m), still finds the wall with the planes given:
    only distances the segment's own surfaces explain are dropped."""
    g = floor_and_wall
    o = np.array([[0.46, 0.05, 0.0]])
    d = np.array([[0.0, 2 ** -0.5, 2 ** -0.5]])
    t = np.array([0.6])
    a0, t0 = march_occlusion(g, o, d, t, 0.15, return_t=True)
    a1 = march_occlusion(g, o, d, t, 0.15, n_start=[[0.0, 0.0, 1.0]], n_end=[[0.0, 1.0, 0.0]])
    # the wall face at x = 0.498: exact up to float32 between centres on its
    # side, at most h/2 over where it lies between them
    assert 0.038 - 1e-6 <= np.sqrt(a1[0]) <= 0.038 + 0.5 * H
    # Without the planes the floor's own distance just past the skipped
    # start (the voxels at the wall's foot meet every plane) came first.
    assert np.sqrt(a0[0]) < 0.038 - 1e-3
    assert abs(np.sqrt(a0[0]) - t0[0] * d[0, 2]) < 0.5 * H


def test_ray_far_from_geometry_reports_inf(floor_and_wall):
    g = floor_and_wall
    o = np.array([[0.9, 0.05, 0.6], [0.1, 0.9, 0.95]])
    d = np.array([[0, 1.0, 0], [1.0, 0, 0]])
    assert np.all(np.isinf(march_occlusion(g, o, d, np.array([0.9, 0.8]), 0.15)))


@pytest.fixture(scope="module")
def sphere():
    r0, c = 0.25, np.array([0.5, 0.5, 0.5])
    tri = icosphere(c, r0, 4).astype(np.float32)     # 5120 triangles
    return build_occlusion_grid(tri, UNIT_LO, UNIT_HI, R32), r0, c


# Sphere distance errors: the inscribed mesh (vertices on the sphere; subdiv-4
# edge ~0.016 r0 -> sagitta <= 2e-4) lies inside the sphere, plus the
# interpolation error <= h/2 (distance field 1-Lipschitz).
SPHERE_TOL = 0.5 * H + 2e-4


def test_grazing_sphere_distance_order(sphere):
    g, r0, c = sphere
    deltas = np.array([0.015, 0.04, 0.08, 0.12])
    n = len(deltas)
    # Tangent-parallel rays along +y in the equatorial plane z = 0.5, passing
    # at delta from the sphere (closest approach at y = 0.5).
    o = np.stack([c[0] + r0 + deltas, np.full(n, 0.02), np.full(n, 0.5)], 1)
    d = np.tile([0.0, 1.0, 0.0], (n, 1))
    a = march_occlusion(g, o, d, np.full(n, 0.96), default_locality(g) * 3)
    r = np.sqrt(a)
    assert np.all(np.isfinite(a)) and np.all(np.diff(a) > 0)
    assert np.all(np.abs(r - deltas) <= SPHERE_TOL)
    # A ray aimed at the centre, ending on the sphere: met head-on, no occluder.
    hit = march_occlusion(g, [[0.5, 0.02, 0.5]], [[0, 1.0, 0]], [0.5 - r0 - 0.02],
                          default_locality(g) * 3)
    assert np.isinf(hit[0])


def test_sphere_random_rays(sphere):
    """2000 random rays passing the sphere at delta in [0.01, 0.15] (closest
    approach mid-segment) all find it at delta within SPHERE_TOL (measured max
    error 0.006 = 0.2 voxel); 2000 random rays ending on / leaving the sphere
    at incidence < 80 degrees never report an occluder (measured: none up to
    85 degrees; 1.4% between 85 and 90 where the ray skims the surface)."""
    g, r0, c = sphere
    rng = np.random.default_rng(3)
    M = 2000
    u = rng.normal(size=(M, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = rng.normal(size=(M, 3))
    w -= (w * u).sum(1, keepdims=True) * u
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    delta = rng.uniform(0.01, 0.15, M)
    o = c + w * (r0 + delta)[:, None] - 0.4 * u
    r = np.sqrt(march_occlusion(g, o, u, np.full(M, 0.8), 0.2))
    assert np.all(np.abs(r - delta) <= SPHERE_TOL)

    nrm = u                                    # reuse: random surface normals
    x = c + r0 * nrm * np.cos(np.pi / 2 ** 10)  # on the mesh side of the sphere
    theta = rng.uniform(0, np.radians(80), M)
    d_in = -(np.cos(theta)[:, None] * nrm + np.sin(theta)[:, None] * w)
    assert np.all(np.isinf(march_occlusion(g, x - 0.2 * d_in, d_in, np.full(M, 0.2),
                                           default_locality(g))))
    assert np.all(np.isinf(march_occlusion(g, x, -d_in, np.full(M, 0.2), default_locality(g))))


def test_scale_invariance():
    """Every epsilon is relative (frequency.md scale rule): scaling the scene
    by s scales a_occ by s^2 exactly up to float32 storage."""
    base = np.array(quad((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0))
                    + box((0.498, 0.0, 0.0), (0.502, 1.0, 0.8)), np.float64)
    o = np.array([[0.532, 0.05, 0.5], [0.2, 0.5, 0.6]])
    d = np.array([[0, 1.0, 0], [0, 0, -1.0]])
    ref = None
    for s in (1e-3, 1.0, 1e3):
        g = build_occlusion_grid((base * s).astype(np.float32), UNIT_LO * s, UNIT_HI * s, 16)
        a = march_occlusion(g, o * s, d, np.array([0.9, 0.6]) * s, 0.15 * s) / s ** 2
        if ref is None:
            ref = a
        assert np.isinf(a[1]) and np.isfinite(a[0])
        # float32 dist: relative 6e-8, squared 1.2e-7; margin 10x.
        np.testing.assert_allclose(a[0], ref[0], rtol=2e-6)


#: The digest of test_grid_and_march_blocks_equal_the_build_before per CPU
#: numba compiles for (tests/builds.py): the same on the machine before and
#: on znver3; on znver4 (AVX-512) both c330335's build and this one give the
#: second.
GRID_DIGEST_BY_CPU = {EARLIER_CPU: "c17b32da9487bb0f", "znver3": "c17b32da9487bb0f",
                      "znver4": "3581018362d445a6"}


def test_grid_and_march_blocks_equal_the_build_before():
    """The build over the occupied voxels only and the cheaper march blocks
    (docs/frequency.md "The set-up: the occlusion grid and its march
    blocks") give the grid of the code before, bit for bit, and the march
    blocks wherever the march reads them (bmin, vmin, and the cones of the
    blocks and voxels whose minimum is below cut_locality): the digest was
    computed with core/frequency/occlusion_grid.py of c330335 (and agrees
    with this code), per CPU (GRID_DIGEST_BY_CPU).  An open box, a sphere (many distinct cones), a thin
    post, and a small far box that leaves most voxels far from everything
    (36 % of the blocks and 28 % of the voxels read)."""
    import hashlib
    from core.frequency import occlusion_grid as OG
    tri = np.concatenate([np.array(box((0, 0, 0), (2, 1.5, 1)))[:10],     # floor and walls
                          icosphere((1.2, 0.7, 0.35), 0.3, 2),
                          np.array(box((0.3, 0.2, 0.0), (0.5, 0.25, 0.6))),
                          np.array(box((3.8, 2.8, 1.9), (4.0, 3.0, 2.0)))]).astype(np.float32)
    p = tri.reshape(-1, 3)
    g = build_occlusion_grid(tri, p.min(0), p.max(0), 32,
                             max_distance=10 * np.linalg.norm(np.array([4, 3, 2]) / 32))
    mb = OG.march_blocks(g)
    rb = mb.bmin * (1 - OG.BLOCK_REL) < mb.cut_locality
    rv = mb.vmin.astype(np.float64) * (1 - OG.BLOCK_REL) < mb.cut_locality
    assert 0.2 < rv.mean() < 0.5 and not OG.union_meets(mb.vcone[~rv], np.eye(3)).any()
    h = hashlib.sha256()
    for a in (g.dist, g.axis, g.aperture, g.occupied, g.near, g.cone, mb.bmin, mb.vmin,
              mb.bcone[rb], mb.vcone[rv]):
        h.update(np.ascontiguousarray(a).tobytes())
    assert h.hexdigest()[:16] == for_this_cpu(GRID_DIGEST_BY_CPU)
