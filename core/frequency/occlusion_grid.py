"""Occlusion grid of Belcour & Soler 2011 (frequency photons, Sec. "occlusion").

A frequency photon must know when it passes close to geometry that blocks part
of the light field around it: that blocker convolves the local spectrum with a
Gaussian visibility of variance ``a_occ = (distance to blocker)**2``
(``docs/frequency.md``, occlusion row; the exact operator is applied by
the caller, ``core.frequency.spectrum.occlude(s, a_occ)``).  Tracing extra rays per
photon is too expensive, so the paper pre-computes a voxel grid over the scene
bounds.  Each voxel stores

- ``dist``: the distance from its centre to the closest triangle (exact
  point-triangle distance, nearest-triangle query in a BVH, restricted to
  each 4^3 block's candidate triangles: ``_nearest_blocked``);
- a bi-cone of the normals of the geometry overlapping it: ``axis`` (the
  sign-free mean normal = principal eigenvector of the area-weighted
  ``sum n n^T``) and ``aperture`` (half-angle containing every normal;
  pi/2 = "unknown" for an empty voxel).

The march over this grid is ``core.frequency.occlusion_march``.  Marching a
photon segment, a voxel near geometry (``dist < locality``) is an
occluder when its bi-cone intersects the plane orthogonal to the ray: some
surface there is seen edge-on and clips the light field passing by.  When all
normals point along the ray the surface is met head-on: it is the reflector /
receiver at the segment's end, not an occluder.

Refinements over the paper, each documented where it happens:

- An *empty* voxel has no normals of its own ("unknown", which intersects every
  plane).  Testing it as such would flag the free space just above every
  receiver as an occluder.  So each voxel also records ``near``, the voxel
  holding the closest point of its closest triangle, and an empty voxel is
  tested with that voxel's bi-cone (``cone``, resolved at build time): the
  geometry at distance ``dist`` is the geometry the test is about.
- The distance at a sample point on the ray is the trilinear interpolation of
  ``dist`` (exact for a plane more than a voxel away, error <= h/2 otherwise,
  the distance field being 1-Lipschitz), rather than the distance from the
  voxel centre (error up to half a diagonal everywhere).
- The cones of the 8 voxels the distance was interpolated from are tested
  too: on a curved surface the edge-on patch may lie in a voxel the ray does
  not enter (a ray grazing a sphere missed it in 1 of 2000 cases otherwise).
- The bi-cone axis is the principal eigenvector of sum n n^T, or the mean of
  the normals oriented into its hemisphere when that gives a narrower cone:
  at a right-angled edge (floor meets wall) the eigenvector is the heavier of
  the two normals and needs a 90-degree cone; the oriented mean is the
  bisector with 45 degrees.

Memory: ``BYTES_PER_VOXEL`` = 41 bytes (dist 4, axis 12, aperture 4,
occupied 1, near 4, and the march's resolved cone 16): 10.7 MB at 64^3,
86 MB at 128^3; the march derives 20 more bytes a voxel on first use
(``MarchBlocks``: 5.5 MB at 64^3, none above VOXEL_LEVEL_MAX; and 80 bytes
a block of 4^3 voxels: bmin, bcone and runs; its build
holds 33 bytes a voxel of temporaries, ``_cone_members``).  The build
also holds about 50 bytes per voxel of temporaries (float64 distances and
closest points, the occupied voxels' index) and about 150 bytes per
occupied voxel (normal sums, two candidate axes), 12 bytes per (triangle, voxel) overlap
and about 100 bytes per triangle (normals, BVH, sorted copy);
bench/bench_occlusion.py measures the peaks.

Scale rule (docs/frequency.md): every epsilon is relative to the voxel size, the
triangle's own size, or the grid diameter; nothing is in absolute metres.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numba as nb
import numpy as np

# float32 axis/aperture rounding: |axis . d| <= sin(aperture) is tested with this
# slack so that a wall exactly parallel to the ray (aperture 0) still counts.
SIN_TOL = 1e-5
# A triangle overlaps a voxel when its clipped area exceeds this fraction of its
# own area: an edge or corner merely touching a voxel face has zero clipped
# area up to rounding (~1e-16 relative), and must not widen that voxel's cone.
_AREA_FRAC = 1e-7
# Triangles whose |e1 x e2| < this * (|e1|^2 + |e2|^2) are degenerate (Embree
# does not hit them either) and are ignored.
_DEGENERATE = 1e-12
# BVH leaf size for the nearest-triangle query.
_LEAF = 4
#: _nearest_all's margins for skipping a triangle by its own box: relative to
#: the best squared distance so far, and absolute as a share of the grid's
#: squared diagonal (both far above float64 rounding, ~1e-16).
NEAREST_REL = 1e-9
NEAREST_SLACK = 1e-12

BYTES_PER_VOXEL = 4 + 12 + 4 + 1 + 4 + 16


@dataclass(frozen=True)
class OcclusionGrid:
    """Voxel grid over [lo, hi], ``res`` voxels per axis, indexed [ix, iy, iz].

    lo, hi, cell: (3,) float64; cell = (hi - lo) / res (voxels may be boxes).
    max_distance: dist is exact up to it (see build_occlusion_grid).
    dist: (R, R, R) float32 distance from voxel centre to the closest triangle
      (inf when the scene has no triangle).
    axis: (R, R, R, 3) float32 unit mean-normal axis (sign-free); zeros if empty.
    aperture: (R, R, R) float32 bi-cone half-angle [rad], pi/2 if empty.
    occupied: (R, R, R) bool, some triangle overlaps the voxel (clipped area > 0).
    near: (R, R, R) int32 flat index (ix*R + iy)*R + iz of the voxel holding the
      closest point of the closest triangle, -1 without triangles (or none
      within max_distance).
    cone: (R, R, R, 4) float32 the bi-cone the march tests, resolved once:
      (axis, sin(aperture)) of the voxel if occupied, else of ``near`` if that
      is occupied, else (0, 0, 0, 1) = unknown (meets every plane); (0, 0, 0,
      -2) = farther than max_distance from everything (meets none).
    """
    lo: np.ndarray
    hi: np.ndarray
    cell: np.ndarray
    res: int
    max_distance: float
    dist: np.ndarray
    axis: np.ndarray
    aperture: np.ndarray
    occupied: np.ndarray
    near: np.ndarray
    cone: np.ndarray

    @property
    def voxel_diagonal(self) -> float:
        return float(np.linalg.norm(self.cell))

    @property
    def nbytes(self) -> int:
        return int(self.dist.nbytes + self.axis.nbytes + self.aperture.nbytes
                   + self.occupied.nbytes + self.near.nbytes + self.cone.nbytes)


def default_locality(grid: OcclusionGrid) -> float:
    """A locality threshold of two voxel diagonals [m].

    The grid resolves geometry to about a voxel: a sample is up to half a
    diagonal from the centre whose cone it uses and its interpolated distance
    errs by up to h/2, so occluders closer than ~1 diagonal are seen
    reliably; two diagonals leave a margin.  Larger values let geometry far
    from the photon clip its spectrum (a_occ = l^2 grows, the effect fades).
    """
    return 2.0 * grid.voxel_diagonal




def check_locality(grid: OcclusionGrid, locality: float) -> None:
    """Raise ValueError when ``locality`` exceeds what the grid's distances
    are exact for (max_distance - 1.5 voxel diagonals)."""
    if locality > grid.max_distance - 1.5 * grid.voxel_diagonal:
        raise ValueError(f"locality {locality} exceeds the grid's max_distance "
                         f"{grid.max_distance} - 1.5 voxel diagonals")


# ----------------------------------------------------------------- kernels

@nb.njit(cache=True)
def _closest_point(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point of triangle abc to p (Ericson, Real-Time Collision
    Detection, 5.1.5: Voronoi regions of vertices, edges, face).  Corners
    may be float32; the arithmetic is float64."""
    ax, ay, az = np.float64(ax), np.float64(ay), np.float64(az)
    bx, by, bz = np.float64(bx), np.float64(by), np.float64(bz)
    cx, cy, cz = np.float64(cx), np.float64(cy), np.float64(cz)
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    return (ax + abx * v + acx * w, ay + aby * v + acy * w,
            az + abz * v + acz * w)


@nb.njit(cache=True)
def nearest_distance(tri_p, px, py, pz):
    """The distance from p to the nearest of the triangles tri_p (T, 3, 3)
    (:func:`_closest_point`, every triangle; inf for none)."""
    best = np.inf
    for i in range(tri_p.shape[0]):
        qx, qy, qz = _closest_point(px, py, pz, tri_p[i, 0, 0], tri_p[i, 0, 1], tri_p[i, 0, 2],
                                    tri_p[i, 1, 0], tri_p[i, 1, 1], tri_p[i, 1, 2],
                                    tri_p[i, 2, 0], tri_p[i, 2, 1], tri_p[i, 2, 2])
        d2 = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
        if d2 < best:
            best = d2
    return np.sqrt(best)


@nb.njit(cache=True)
def _clip_area(tri, blo, bhi, buf_a, buf_b):
    """Area of triangle ``tri`` (3, 3) float64 clipped to the closed box
    [blo, bhi] (Sutherland-Hodgman against the 6 slabs; <= 9 vertices)."""
    for k in range(3):
        for j in range(3):
            buf_a[k, j] = tri[k, j]
    n = 3
    src, dst = buf_a, buf_b
    for plane in range(6):
        ax = plane // 2
        upper = plane % 2 == 1
        m = 0
        for k in range(n):
            k2 = (k + 1) % n
            if upper:
                s0 = bhi[ax] - src[k, ax]
                s1 = bhi[ax] - src[k2, ax]
            else:
                s0 = src[k, ax] - blo[ax]
                s1 = src[k2, ax] - blo[ax]
            if s0 >= 0.0:
                for j in range(3):
                    dst[m, j] = src[k, j]
                m += 1
            if (s0 >= 0.0) != (s1 >= 0.0):
                f = s0 / (s0 - s1)
                for j in range(3):
                    dst[m, j] = src[k, j] + f * (src[k2, j] - src[k, j])
                # pin the clipped coordinate exactly on the plane
                dst[m, ax] = bhi[ax] if upper else blo[ax]
                m += 1
        n = m
        if n < 3:
            return 0.0
        src, dst = dst, src
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for k in range(1, n - 1):
        ux = src[k, 0] - src[0, 0]
        uy = src[k, 1] - src[0, 1]
        uz = src[k, 2] - src[0, 2]
        vx = src[k + 1, 0] - src[0, 0]
        vy = src[k + 1, 1] - src[0, 1]
        vz = src[k + 1, 2] - src[0, 2]
        sx += uy * vz - uz * vy
        sy += uz * vx - ux * vz
        sz += ux * vy - uy * vx
    return 0.5 * math.sqrt(sx * sx + sy * sy + sz * sz)


@nb.njit(cache=True)
def _overlaps(tri_p, nrm, area, valid, lo, cell, R):
    """Every (triangle, voxel) overlap with clipped area > _AREA_FRAC * area.

    Returns pair_t (P,) int32 triangle, pair_v (P,) int32 flat voxel index,
    pair_w (P,) float32 clipped area [m^2].  Computed once (clipping is the
    expensive part) and reused by the three accumulations below; 12 bytes a
    pair.
    """
    T = tri_p.shape[0]
    cap = max(1024, 4 * T)
    pair_t = np.empty(cap, np.int32)
    pair_v = np.empty(cap, np.int32)
    pair_w = np.empty(cap, np.float32)
    P = 0
    tri = np.empty((3, 3))
    blo = np.empty(3)
    bhi = np.empty(3)
    buf_a = np.empty((12, 3))
    buf_b = np.empty((12, 3))
    i0 = np.empty(3, np.int64)
    i1 = np.empty(3, np.int64)
    for t in range(T):
        if not valid[t]:
            continue
        for k in range(3):
            for j in range(3):
                tri[k, j] = tri_p[t, k, j]
        for j in range(3):
            mn = min(tri[0, j], tri[1, j], tri[2, j])
            mx = max(tri[0, j], tri[1, j], tri[2, j])
            # +-1e-6 voxel: include the voxel on the other side of a face the
            # triangle lies in; the clip decides.
            a = int(math.floor((mn - lo[j]) / cell[j] - 1e-6))
            b = int(math.floor((mx - lo[j]) / cell[j] + 1e-6))
            i0[j] = min(max(a, 0), R - 1)
            i1[j] = min(max(b, 0), R - 1)
        nx, ny, nz = nrm[t, 0], nrm[t, 1], nrm[t, 2]
        off = nx * tri[0, 0] + ny * tri[0, 1] + nz * tri[0, 2]
        thr = _AREA_FRAC * area[t]
        hx, hy, hz = 0.5 * cell[0], 0.5 * cell[1], 0.5 * cell[2]
        rad = abs(nx) * hx + abs(ny) * hy + abs(nz) * hz
        for ix in range(i0[0], i1[0] + 1):
            blo[0] = lo[0] + ix * cell[0]
            bhi[0] = blo[0] + cell[0]
            for iy in range(i0[1], i1[1] + 1):
                blo[1] = lo[1] + iy * cell[1]
                bhi[1] = blo[1] + cell[1]
                for iz in range(i0[2], i1[2] + 1):
                    blo[2] = lo[2] + iz * cell[2]
                    bhi[2] = blo[2] + cell[2]
                    # cheap reject: the triangle's plane misses the box
                    cx = blo[0] + hx
                    cy = blo[1] + hy
                    cz = blo[2] + hz
                    if abs(nx * cx + ny * cy + nz * cz - off) > rad * (1.0 + 1e-9):
                        continue
                    w = _clip_area(tri, blo, bhi, buf_a, buf_b)
                    if w <= thr:
                        continue
                    if P == cap:
                        cap *= 2
                        nt = np.empty(cap, np.int32)
                        nv = np.empty(cap, np.int32)
                        nw = np.empty(cap, np.float32)
                        nt[:P] = pair_t[:P]
                        nv[:P] = pair_v[:P]
                        nw[:P] = pair_w[:P]
                        pair_t, pair_v, pair_w = nt, nv, nw
                    pair_t[P] = t
                    pair_v[P] = (ix * R + iy) * R + iz
                    pair_w[P] = w
                    P += 1
    return pair_t[:P], pair_v[:P], pair_w[:P]     # views: no second copy


@nb.njit(cache=True)
def _accumulate(pair_t, pair_v, pair_w, nrm, mode, S, W, axes, mincos):
    """mode 0: S[v] += w (nx^2, ny^2, nz^2, nx ny, nx nz, ny nz), W[v] += w
    (area-weighted second moment of the normals).
    mode 2: S[v, :3] += w sign(n . axes[v, 0]) n (oriented mean normal).
    mode 1: mincos[v, k] = min |n . axes[v, k]| (aperture = arccos of it)."""
    for p in range(pair_t.shape[0]):
        t = pair_t[p]
        v = pair_v[p]
        w = np.float64(pair_w[p])
        nx, ny, nz = nrm[t, 0], nrm[t, 1], nrm[t, 2]
        if mode == 0:
            S[v, 0] += w * nx * nx
            S[v, 1] += w * ny * ny
            S[v, 2] += w * nz * nz
            S[v, 3] += w * nx * ny
            S[v, 4] += w * nx * nz
            S[v, 5] += w * ny * nz
            W[v] += w
        elif mode == 2:
            s = nx * axes[v, 0, 0] + ny * axes[v, 0, 1] + nz * axes[v, 0, 2]
            ws = w if s >= 0.0 else -w
            S[v, 0] += ws * nx
            S[v, 1] += ws * ny
            S[v, 2] += ws * nz
        else:
            for k in range(axes.shape[1]):
                c = abs(nx * axes[v, k, 0] + ny * axes[v, k, 1] + nz * axes[v, k, 2])
                if c < mincos[v, k]:
                    mincos[v, k] = c


@nb.njit(cache=True)
def _distinct_rows(keys, inv):
    """Rows of keys (n, m) int64 (the bits of float64 rows) that first hold
    each distinct row, in order of first occurrence: (d,) int64; inv (n,)
    int64 receives each row's index among them.  An open-addressing hash of
    the bits: rows equal bit for bit share an index (0.0 and -0.0 do not,
    which only costs a duplicate)."""
    n, m = keys.shape
    size = 2
    while size < 2 * n:
        size *= 2
    table = np.full(size, -1, np.int64)
    first = np.empty(n, np.int64)
    d = 0
    for i in range(n):
        h = np.uint64(_FNV0)
        for k in range(m):
            h = _fnv(h, keys[i, k])
        h ^= h >> np.uint64(29)
        j = np.int64(h & np.uint64(size - 1))
        while True:
            t = table[j]
            if t < 0:
                table[j] = d
                first[d] = i
                inv[i] = d
                d += 1
                break
            r = first[t]
            same = True
            for k in range(m):
                if keys[r, k] != keys[i, k]:
                    same = False
                    break
            if same:
                inv[i] = t
                break
            j = (j + 1) & (size - 1)
    return first[:d]


@nb.njit(cache=True)
def _box_d2(node_lo, node_hi, k, px, py, pz):
    dx = max(node_lo[k, 0] - px, 0.0, px - node_hi[k, 0])
    dy = max(node_lo[k, 1] - py, 0.0, py - node_hi[k, 1])
    dz = max(node_lo[k, 2] - pz, 0.0, pz - node_hi[k, 2])
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, nogil=True, inline="always")
def _box_too_far(tri_lo, tri_hi, t, px, py, pz, best, slack):
    """True when triangle t's own box is farther from p than the best squared
    distance so far allows (best (1 + NEAREST_REL) + slack): the skip both
    nearest queries share (docs/frequency.md "The set-up: the occlusion grid
    and its march blocks")."""
    return _box_d2(tri_lo, tri_hi, t, px, py, pz) > best * (1.0 + NEAREST_REL) + slack


@nb.njit(cache=True, nogil=True, inline="always")
def _tri_d2(tris, t, px, py, pz):
    """(d2, qx, qy, qz): triangle t's closest point q to p and |q - p|^2."""
    qx, qy, qz = _closest_point(
        px, py, pz, tris[t, 0, 0], tris[t, 0, 1], tris[t, 0, 2],
        tris[t, 1, 0], tris[t, 1, 1], tris[t, 1, 2],
        tris[t, 2, 0], tris[t, 2, 1], tris[t, 2, 2])
    return (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2, qx, qy, qz


@nb.njit(cache=True, inline="always")
def _fnv(h, k):
    """One step of the FNV-1a hash of int64 words (the tables of
    _distinct_rows, _member_codes and _voxel_level)."""
    return (h ^ np.uint64(k)) * np.uint64(1099511628211)


#: FNV-1a's offset basis (_fnv).
_FNV0 = 1469598103934665603


@nb.njit(cache=True, nogil=True, inline="always")
def _seeded(tris, prev, px, py, pz, cap2):
    """A nearest query's start from its seed triangle prev: (best, bt, bqx,
    bqy, bqz), best = min(|q - p|^2, cap2), bqx = nan when the seed is not
    closer than the cap (its y, z kept)."""
    best, bqx, bqy, bqz = _tri_d2(tris, prev, px, py, pz)
    if best >= cap2:
        best = cap2
        bqx = np.nan
    return best, prev, bqx, bqy, bqz


@nb.njit(cache=True, nogil=True, inline="always")
def _store_nearest(out_d, out_q, v, cap, best, bqx, bqy, bqz):
    """Voxel v's distance (cap where nothing is closer: bqx nan) and closest point."""
    out_d[v] = cap if bqx != bqx else math.sqrt(best)
    out_q[v, 0] = bqx
    out_q[v, 1] = bqy
    out_q[v, 2] = bqz


@nb.njit(cache=True, nogil=True, inline="always")
def _nearest_one(tris, tri_lo, tri_hi, node_lo, node_hi, n_leaves, px, py, pz, prev, cap2,
                 slack, stack, stack_d):
    """One query of :func:`_nearest_all` from point p seeded with triangle
    prev: (best, bt, bqx, bqy, bqz), best the squared distance (cap2 and
    bqx = nan when no triangle is closer than the cap; bt then stays prev)."""
    T = tris.shape[0]
    best, bt, bqx, bqy, bqz = _seeded(tris, prev, px, py, pz, cap2)
    stack[0] = 1
    stack_d[0] = 0.0
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if stack_d[sp] >= best:
            continue
        if node >= n_leaves:
            first = (node - n_leaves) * _LEAF
            last = min(first + _LEAF, T)
            for t in range(first, last):
                if _box_too_far(tri_lo, tri_hi, t, px, py, pz, best, slack):
                    continue
                d2, qx, qy, qz = _tri_d2(tris, t, px, py, pz)
                if d2 < best:
                    best = d2
                    bt = t
                    bqx, bqy, bqz = qx, qy, qz
        else:
            l = 2 * node
            dl = _box_d2(node_lo, node_hi, l, px, py, pz)
            dr = _box_d2(node_lo, node_hi, l + 1, px, py, pz)
            # push the far child first so the near one pops first
            if dl <= dr:
                if dr < best:
                    stack[sp] = l + 1
                    stack_d[sp] = dr
                    sp += 1
                if dl < best:
                    stack[sp] = l
                    stack_d[sp] = dl
                    sp += 1
            else:
                if dl < best:
                    stack[sp] = l
                    stack_d[sp] = dl
                    sp += 1
                if dr < best:
                    stack[sp] = l + 1
                    stack_d[sp] = dr
                    sp += 1
    return best, bt, bqx, bqy, bqz


@nb.njit(cache=True, nogil=True)
def _nearest_all(tris, tri_lo, tri_hi, node_lo, node_hi, n_leaves, lo, cell, R, cap, slack,
                 out_d, out_q):
    """Exact distance from every voxel centre to the closest triangle.

    tris: (T, 3, 3) float32 in BVH (Morton) order; tri_lo, tri_hi (T, 3)
    float64 their own bounding boxes; node boxes in heap order
    (root 1, children 2k and 2k+1, leaf j = node n_leaves + j holding triangles
    [j*_LEAF, (j+1)*_LEAF)).  Voxels are visited in grid order and the previous
    voxel's triangle seeds the bound (its exact distance is an upper bound), so
    most BVH nodes are pruned at once.  out_q: closest points (R^3, 3).
    cap: voxels with no triangle closer than cap get out_d = cap, out_q = nan.
    slack [m^2]: in a leaf, a triangle whose own box is farther than
    best (1 + NEAREST_REL) + slack is not tested: the box's distance is a
    lower bound of the triangle's, and the margin is far above the rounding
    of either, so every triangle that could still replace the best (d2 <
    best, ties in visiting order) is tested as before: the same distances
    and closest points, bit for bit.  It pays because a leaf's box spans the
    walls of a room while a wall triangle's own box is a thin slab (measured:
    docs/frequency.md "The set-up: the occlusion grid and its march blocks").
    The winner is the seed when it attains the minimum, else the first
    triangle attaining it in the query's depth-first order (pruning only
    removes nodes that cannot hold a strictly smaller distance):
    :func:`_nearest_blocked` relies on this.
    """
    cap2 = cap * cap
    stack = np.empty(128, np.int64)
    stack_d = np.empty(128)
    prev = 0
    for ix in range(R):
        px = lo[0] + (ix + 0.5) * cell[0]
        for iy in range(R):
            py = lo[1] + (iy + 0.5) * cell[1]
            for iz in range(R):
                pz = lo[2] + (iz + 0.5) * cell[2]
                best, bt, bqx, bqy, bqz = _nearest_one(
                    tris, tri_lo, tri_hi, node_lo, node_hi, n_leaves, px, py, pz, prev, cap2,
                    slack, stack, stack_d)
                prev = bt
                _store_nearest(out_d, out_q, (ix * R + iy) * R + iz, cap, best, bqx, bqy, bqz)


#: _nearest_blocked: blocks of NEAREST_BLOCK^3 voxels share a candidate list
#: of at most NEAREST_CANDIDATES triangles (longer: the block's voxels query
#: the BVH as _nearest_all does).
NEAREST_BLOCK = 4
NEAREST_CANDIDATES = 24
#: Relative margin of the candidate bound (far above float64 rounding, ~1e-16).
_CAND_REL = 1e-9
_ALL_CAPPED = -1
_QUERY_BVH = -2


@nb.njit(cache=True, nogil=True, inline="always")
def _box_box_d2(alo, ahi, k, b0, b1, b2, c0, c1, c2):
    """Squared distance between box k of (alo, ahi) and the box [b, c]."""
    dx = max(alo[k, 0] - c0, 0.0, b0 - ahi[k, 0])
    dy = max(alo[k, 1] - c1, 0.0, b1 - ahi[k, 1])
    dz = max(alo[k, 2] - c2, 0.0, b2 - ahi[k, 2])
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, nogil=True)
def _nearest_blocked(tris, tri_lo, tri_hi, node_lo, node_hi, n_leaves, lo, cell, R, cap,
                     slack, out_d, out_q):
    """:func:`_nearest_all`'s distances and closest points, bit for bit, with
    fewer triangle tests: the voxels of a block of NEAREST_BLOCK^3 test only
    the block's candidates, the triangles whose own box lies within
    min(dc + h, cap) (1 + _CAND_REL) of the box of the block's voxel centres
    (dc: the exact distance from the block's centre to the scene, h: half
    that box's diagonal; every voxel centre of the block has a triangle
    within dc + h, so no other triangle can attain a voxel's minimum or beat
    the cap).  Each voxel is seeded with the previous voxel's triangle as in
    _nearest_all and keeps the same winner: the seed when it attains the
    minimum, else the only candidate attaining it; a voxel where two
    candidates tie for the minimum (a shared edge or vertex) runs
    _nearest_all's query, whose depth-first order decides.  A block whose
    centre is farther than cap + h from every triangle is capped whole
    (no triangle is closer than the cap to any of its voxels).  Returns
    (5,) int64: blocks capped whole, blocks with a candidate list, blocks
    querying the BVH, candidates in all lists, voxels that ran the query
    for a tie (tests, docs/frequency.md)."""
    B = NEAREST_BLOCK
    counts = np.zeros(5, np.int64)
    NB = -(-R // B)
    cap2 = cap * cap
    T = tris.shape[0]
    stack = np.empty(128, np.int64)
    stack_d = np.empty(128)
    state = np.empty(NB * NB * NB, np.int64)       # >= 0: candidates start; or a code
    count = np.zeros(NB * NB * NB, np.int64)
    cand = np.empty(NB * NB * NB * NEAREST_CANDIDATES, np.int64)
    for bx in range(NB):
        for by in range(NB):
            for bz in range(NB):
                b = (bx * NB + by) * NB + bz
                x0 = lo[0] + (bx * B + 0.5) * cell[0]
                y0 = lo[1] + (by * B + 0.5) * cell[1]
                z0 = lo[2] + (bz * B + 0.5) * cell[2]
                x1 = lo[0] + (min((bx + 1) * B, R) - 0.5) * cell[0]
                y1 = lo[1] + (min((by + 1) * B, R) - 0.5) * cell[1]
                z1 = lo[2] + (min((bz + 1) * B, R) - 0.5) * cell[2]
                h = 0.5 * math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2 + (z1 - z0) ** 2)
                dc2, _t, _a, _b, _c = _nearest_one(
                    tris, tri_lo, tri_hi, node_lo, node_hi, n_leaves, 0.5 * (x0 + x1),
                    0.5 * (y0 + y1), 0.5 * (z0 + z1), 0, np.inf, slack, stack, stack_d)
                dc = math.sqrt(dc2)
                if dc - h > cap * (1.0 + _CAND_REL):
                    state[b] = _ALL_CAPPED
                    counts[0] += 1
                    continue
                u = min(dc + h, cap) * (1.0 + _CAND_REL)
                thr = u * u + slack
                o = b * NEAREST_CANDIDATES
                k = 0
                full = False
                stack[0] = 1
                sp = 1
                while sp > 0 and not full:
                    sp -= 1
                    node = stack[sp]
                    if node >= n_leaves:
                        first = (node - n_leaves) * _LEAF
                        last = min(first + _LEAF, T)
                        for t in range(first, last):
                            if _box_box_d2(tri_lo, tri_hi, t, x0, y0, z0, x1, y1, z1) <= thr:
                                if k == NEAREST_CANDIDATES:
                                    full = True
                                    break
                                cand[o + k] = t
                                k += 1
                    else:
                        for c in (2 * node, 2 * node + 1):
                            if _box_box_d2(node_lo, node_hi, c, x0, y0, z0, x1, y1, z1) <= thr:
                                stack[sp] = c
                                sp += 1
                if full:
                    state[b] = _QUERY_BVH
                    counts[2] += 1
                else:
                    state[b] = o
                    count[b] = k
                    counts[1] += 1
                    counts[3] += k
    prev = 0
    for ix in range(R):
        px = lo[0] + (ix + 0.5) * cell[0]
        for iy in range(R):
            py = lo[1] + (iy + 0.5) * cell[1]
            for iz in range(R):
                pz = lo[2] + (iz + 0.5) * cell[2]
                v = (ix * R + iy) * R + iz
                b = ((ix // B) * NB + iy // B) * NB + iz // B
                s = state[b]
                if s == _ALL_CAPPED:
                    # _nearest_all: the seed is beyond the cap and nothing
                    # replaces it (prev stays); out_q keeps the seed's
                    # closest point but its x (nan)
                    _d2, qx, qy, qz = _tri_d2(tris, prev, px, py, pz)
                    out_d[v] = cap
                    out_q[v, 0] = np.nan
                    out_q[v, 1] = qy
                    out_q[v, 2] = qz
                    continue
                tie = False
                if s >= 0:
                    best, bt, bqx, bqy, bqz = _seeded(tris, prev, px, py, pz, cap2)
                    for j in range(s, s + count[b]):
                        t = cand[j]
                        if t == prev:
                            continue
                        if _box_too_far(tri_lo, tri_hi, t, px, py, pz, best, slack):
                            continue
                        d2, qx, qy, qz = _tri_d2(tris, t, px, py, pz)
                        if d2 < best:
                            best = d2
                            bt = t
                            bqx, bqy, bqz = qx, qy, qz
                            tie = False
                        elif d2 == best and bqx == bqx:
                            tie = True
                if s < 0 or (tie and bt != prev):
                    if s >= 0:
                        counts[4] += 1
                    best, bt, bqx, bqy, bqz = _nearest_one(
                        tris, tri_lo, tri_hi, node_lo, node_hi, n_leaves, px, py, pz, prev,
                        cap2, slack, stack, stack_d)
                prev = bt
                _store_nearest(out_d, out_q, v, cap, best, bqx, bqy, bqz)
    return counts


def _build_bvh(tri: np.ndarray):
    """Morton-ordered implicit BVH: (sorted tris, node_lo, node_hi, n_leaves).

    Triangles are sorted along a 30-bit Morton curve of their centroids and
    cut into leaves of _LEAF consecutive triangles; the tree is the complete
    binary tree over the leaves (padded to a power of two with empty boxes
    lo = +inf, hi = -inf whose distance is inf), so building it is a few
    vectorised reductions (LBVH with median splits along the curve).
    """
    T = tri.shape[0]
    cen = tri.mean(axis=1, dtype=np.float64)
    cmin = cen.min(axis=0)
    ext = np.maximum(cen.max(axis=0) - cmin, 1e-300)
    q = np.clip(((cen - cmin) / ext * 1023.0), 0, 1023).astype(np.uint64)

    def spread(x):
        x = (x | (x << np.uint64(16))) & np.uint64(0x030000FF)
        x = (x | (x << np.uint64(8))) & np.uint64(0x0300F00F)
        x = (x | (x << np.uint64(4))) & np.uint64(0x030C30C3)
        x = (x | (x << np.uint64(2))) & np.uint64(0x09249249)
        return x
    code = (spread(q[:, 0]) << np.uint64(2)) | (spread(q[:, 1]) << np.uint64(1)) | spread(q[:, 2])
    order = np.argsort(code, kind="stable")
    tris = np.ascontiguousarray(tri[order])
    n_leaves = 1
    while n_leaves * _LEAF < T:
        n_leaves *= 2
    pad = n_leaves * _LEAF - T
    tmin = np.concatenate([tris.min(axis=1), np.full((pad, 3), np.inf, np.float32)])
    tmax = np.concatenate([tris.max(axis=1), np.full((pad, 3), -np.inf, np.float32)])
    node_lo = np.empty((2 * n_leaves, 3), np.float64)
    node_hi = np.empty((2 * n_leaves, 3), np.float64)
    node_lo[n_leaves:] = tmin.reshape(n_leaves, _LEAF, 3).min(axis=1)
    node_hi[n_leaves:] = tmax.reshape(n_leaves, _LEAF, 3).max(axis=1)
    s = n_leaves // 2
    while s >= 1:
        node_lo[s:2 * s] = np.minimum(node_lo[2 * s:4 * s:2], node_lo[2 * s + 1:4 * s:2])
        node_hi[s:2 * s] = np.maximum(node_hi[2 * s:4 * s:2], node_hi[2 * s + 1:4 * s:2])
        s //= 2
    node_lo[0] = np.inf
    node_hi[0] = -np.inf
    return tris, node_lo, node_hi, n_leaves


def grid_bounds(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Grid box from scene bounds: each axis at least 1e-3 of the diagonal
    (a flat scene would otherwise give zero-thickness voxels), and padded by
    1e-6 of the diagonal so geometry on the bounds is strictly inside."""
    lo = np.asarray(lo, np.float64).reshape(3)
    hi = np.asarray(hi, np.float64).reshape(3)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo)):
        raise ValueError(f"occlusion grid bounds lo={lo}, hi={hi}: must be finite, lo <= hi")
    D = float(np.linalg.norm(hi - lo))
    if D <= 0.0:            # a single point: no scene scale to be relative to
        D = max(1.0, 1e-3 * float(np.abs(lo).max()))
    mid = 0.5 * (lo + hi)
    half = np.maximum(0.5 * (hi - lo), 0.5e-3 * D) + 1e-6 * D
    return mid - half, mid + half


@nb.njit(cache=True)
def _near_voxels(q, lo, cell, R, near):
    """near[v] = the flat index of the voxel holding closest point q[v] (nan
    = none within max_distance: stays -1), clipped into the grid."""
    for v in range(q.shape[0]):
        if q[v, 0] != q[v, 0]:
            continue
        i0 = min(max(np.int64(math.floor((q[v, 0] - lo[0]) / cell[0])), 0), R - 1)
        i1 = min(max(np.int64(math.floor((q[v, 1] - lo[1]) / cell[1])), 0), R - 1)
        i2 = min(max(np.int64(math.floor((q[v, 2] - lo[2]) / cell[2])), 0), R - 1)
        near[v] = (i0 * R + i1) * R + i2


@nb.njit(cache=True)
def _resolve_cones(cidx, near, dist, axis_o, sin_o, cone):
    """cone (nvox, 4) float32 of OcclusionGrid: (axis, sin aperture) of the
    voxel if occupied (cidx >= 0: its row of axis_o, sin_o), else of
    ``near`` if that is occupied, else (0, 0, 0, 1) = unknown; (0, 0, 0,
    -2) for an unoccupied voxel with no closest point and a finite dist
    (beyond max_distance: never an occluder)."""
    for v in range(cidx.shape[0]):
        src = v if cidx[v] >= 0 else near[v]
        k = cidx[src] if src >= 0 else -1
        if k >= 0:
            cone[v, 0] = axis_o[k, 0]
            cone[v, 1] = axis_o[k, 1]
            cone[v, 2] = axis_o[k, 2]
            cone[v, 3] = sin_o[k]
        elif cidx[v] < 0 and near[v] < 0 and np.isfinite(dist[v]):
            cone[v, 3] = -2.0
        else:
            cone[v, 3] = 1.0


def build_occlusion_grid(tri_p: np.ndarray, lo, hi, res: int = 64,
                         max_distance: float = np.inf,
                         stats: dict | None = None) -> OcclusionGrid:
    """Build the occlusion grid of ``res``^3 voxels over [lo, hi].

    tri_p: (T, 3, 3) float32 world-space triangles (``Scene.tri_p``).
    lo, hi: (3,) bounds (``geometry_bounds``); widened by ``grid_bounds``.
    Geometric normals (from the corner positions) define the bi-cones.
    max_distance [m]: distances are exact up to it; a voxel farther than it
      from every triangle stores dist = max_distance (a lower bound: the
      march's Lipschitz skip stays valid), near = -1 and a cone that meets no
      plane, so ``occlusion_march.march_occlusion`` needs locality <= max_distance - 1.5
      voxel diagonals (checked).  inf (default) = exact everywhere.  Finite
      values bound the cost of voxels deep inside closed meshes, where many
      triangles are nearly equidistant and the BVH cannot prune (a 1M-triangle
      sphere: see bench/bench_occlusion.py).
    stats: if a dict, receives the CPU seconds of each stage.
    """
    clock = [time.process_time()]

    def stage(name):
        if stats is not None:
            now = time.process_time()
            stats[name] = stats.get(name, 0.0) + now - clock[0]
            clock[0] = now

    R = int(res)
    if R < 2:
        raise ValueError(f"occlusion grid res = {R}: must be >= 2")
    if not float(max_distance) > 0.0:
        raise ValueError(f"max_distance = {max_distance}: must be > 0")
    lo, hi = grid_bounds(lo, hi)
    cell = (hi - lo) / R
    nvox = R ** 3
    tri = np.ascontiguousarray(np.asarray(tri_p, np.float32).reshape(-1, 3, 3))
    # geometric normals in float64 (edges subtracted in float64: no float32
    # cancellation for small triangles far from the origin)
    e1 = tri[:, 1].astype(np.float64) - tri[:, 0]
    e2 = tri[:, 2].astype(np.float64) - tri[:, 0]
    nrm = np.cross(e1, e2)
    n2 = np.linalg.norm(nrm, axis=1)
    valid = (n2 > _DEGENERATE * (np.einsum("ij,ij->i", e1, e1) + np.einsum("ij,ij->i", e2, e2)))
    valid &= np.isfinite(tri).all(axis=(1, 2))
    del e1, e2
    nrm /= np.where(valid, n2, 1.0)[:, None]
    area = 0.5 * n2
    del n2
    stage("normals")

    # --- bi-cones.  Axis candidate 0: principal eigenvector of the
    # area-weighted sum n n^T (the paper's sign-free mean).  It fails where
    # two faces meet at a right angle (x and z normals: the eigenvector is the
    # heavier normal and the cone must open to 90 degrees, no information).
    # Candidate 1: the area-weighted mean of the normals oriented into that
    # eigenvector's hemisphere (the bisector there: 45 degrees).  Keep the
    # candidate with the narrower bi-cone.
    pair_t, pair_v, pair_w = _overlaps(tri, nrm, area, valid, lo, cell, R)
    stage("clip triangles to voxels")
    # The cones of the occupied voxels alone (every pair has a clipped area
    # > 0, so they are the voxels of the pairs; a few % of the grid), in
    # voxel order: the same sums in the same order, the same eigh batch.
    uv, inv = np.unique(pair_v, return_inverse=True)
    pair_o = inv.astype(np.int32)
    del inv
    no = len(uv)
    S = np.zeros((no, 6))
    W = np.zeros(no)
    axes = np.zeros((no, 2, 3))
    mincos = np.ones((no, 2))
    _accumulate(pair_t, pair_o, pair_w, nrm, 0, S, W, axes, mincos)
    if no:
        # The eigh batch on the distinct sums only: the voxels of a flat
        # wall share theirs (860 distinct of 25,987 on cornell.blend at 64^3),
        # and each matrix's eigenvectors are LAPACK's for its own bits, so
        # every voxel gets the same axis as from the whole batch
        # (docs/frequency.md "The nearest-triangle queries by block, round 17").
        inv = np.empty(no, np.int64)
        first = _distinct_rows(S.view(np.int64), inv)
        Su = S[first]
        M = np.empty((len(first), 3, 3))
        M[:, 0, 0], M[:, 1, 1], M[:, 2, 2] = Su[:, 0], Su[:, 1], Su[:, 2]
        M[:, 0, 1] = M[:, 1, 0] = Su[:, 3]
        M[:, 0, 2] = M[:, 2, 0] = Su[:, 4]
        M[:, 1, 2] = M[:, 2, 1] = Su[:, 5]
        axes[:, 0] = np.linalg.eigh(M)[1][:, :, -1][inv]     # largest eigenvalue
        del M, Su, first, inv
    stage("accumulate, eigh")
    S[:] = 0.0
    _accumulate(pair_t, pair_o, pair_w, nrm, 2, S, W, axes, mincos)
    m = S[:, :3]
    mn = np.linalg.norm(m, axis=1)
    axes[:, 1] = np.where((mn > 0)[:, None], m / np.where(mn > 0, mn, 1.0)[:, None], axes[:, 0])
    del S, m, mn
    _accumulate(pair_t, pair_o, pair_w, nrm, 1, np.zeros((1, 6)), W, axes, mincos)
    pick = np.argmax(mincos, axis=1)                      # narrower cone
    axis_o = axes[np.arange(no), pick]
    mc = mincos[np.arange(no), pick]
    # canonical sign (largest |component| positive): determinism only
    big = np.argmax(np.abs(axis_o), axis=1)
    axis_o *= np.where(axis_o[np.arange(no), big] < 0, -1.0, 1.0)[:, None]
    ap_o = np.arccos(np.clip(mc, 0.0, 1.0))
    if stats is not None:
        stats["overlap pairs"] = len(pair_t)
    del axes, mincos, pair_t, pair_v, pair_w, pair_o, nrm, area
    stage("oriented mean, apertures")

    # --- exact distances and the voxel of each closest point
    dist = np.full(nvox, np.inf)
    near = np.full(nvox, -1, np.int32)
    tv = tri if valid.all() else tri[valid]
    if len(tv):
        tris, node_lo, node_hi, n_leaves = _build_bvh(tv)
        tri_lo = tris.min(axis=1).astype(np.float64)
        tri_hi = tris.max(axis=1).astype(np.float64)
        # NEAREST_SLACK of the grid's squared diagonal: far above the
        # rounding of a distance across the grid (~1e-16 of it)
        slack = NEAREST_SLACK * float(np.sum(np.square(hi - lo)))
        stage("bvh build")
        q = np.empty((nvox, 3))
        nc = _nearest_blocked(tris, tri_lo, tri_hi, node_lo, node_hi, n_leaves, lo, cell, R,
                              float(max_distance), slack, dist, q)
        stage("nearest-triangle queries")
        if stats is not None:
            stats["nearest blocks capped, listed, querying"] = tuple(int(c) for c in nc[:3])
        _near_voxels(q, lo, cell, R, near)
        del q

    # the cone each voxel is tested with (own, else its closest point's),
    # the unoccupied voxels' axis 0 and aperture pi/2
    cidx = np.full(nvox, -1, np.int64)
    cidx[uv] = np.arange(no)
    cone = np.zeros((nvox, 4), np.float32)
    _resolve_cones(cidx, near, dist, axis_o, np.sin(ap_o), cone)
    axis = np.zeros((nvox, 3), np.float32)
    axis[uv] = axis_o
    aperture = np.full(nvox, np.pi / 2, np.float32)
    aperture[uv] = ap_o
    occ = cidx >= 0
    stage("cones")

    shp = (R, R, R)
    return OcclusionGrid(lo=lo, hi=hi, cell=cell, res=R, max_distance=float(max_distance),
                         dist=dist.astype(np.float32).reshape(shp),
                         axis=axis.reshape(shp + (3,)),
                         aperture=aperture.reshape(shp),
                         occupied=occ.reshape(shp), near=near.reshape(shp),
                         cone=cone.reshape(shp + (4,)))


def geometry_bounds(scene) -> tuple[np.ndarray, np.ndarray]:
    """The box the occlusion grid needs: the bounds of the triangles, float64
    (3,) each (``Scene.bounds()`` when the scene has none).

    Not ``Scene.bounds()``, which also holds the camera and the lights: no
    occluder is outside the triangles' box (the march clips segments to the
    grid), and a camera 4 m in front of a 2 m box (example_blends/cornell.blend)
    stretched the voxels 2.4x along that axis, the locality (2 voxel
    diagonals) with them, and so the stretch of every segment the march
    samples voxel by voxel (docs/frequency.md, "Cost")."""
    if not scene.n_triangles:
        return scene.bounds()
    p = np.asarray(scene.tri_p, np.float64).reshape(-1, 3)
    return p.min(axis=0), p.max(axis=0)


def build_occlusion_grid_for_scene(scene, res: int = 64,
                                   max_distance: float = np.inf) -> OcclusionGrid:
    """``build_occlusion_grid(scene.tri_p, *geometry_bounds(scene), res,
    max_distance)``; res = ``RenderSettings.occlusion_grid_res``."""
    lo, hi = geometry_bounds(scene)
    return build_occlusion_grid(scene.tri_p, lo, hi, res, max_distance)


# -------------------------------------------------- coarse blocks of the march
#: Block edge [voxels] of the march's coarse level (see MarchBlocks): a
#: compile-time power of two (index >> BLOCK_SHIFT; a runtime integer
#: division per step cost 15% of the march).
BLOCK_SHIFT = 2
MARCH_BLOCK = 1 << BLOCK_SHIFT
# Relative slack of the block tests (float64 rounding of the trilinear
# weights: a convex combination of values >= m is >= m (1 - 4e-16)).
BLOCK_REL = 1e-12
# Angular slack [rad] of the union cone: covers the float32 axes' norm
# (1 +- 1e-7) and the float64 rounding of atan2 / asin (~1e-16 rad).
_UNION_SLACK = 1e-5
# Union cones wider than pi/2 - this [rad] meet every plane ("unknown").
_UNION_WIDE = 1e-3


@dataclass(frozen=True)
class MarchBlocks:
    """Coarse level of the march: blocks of B^3 voxels (NB = ceil(R / B) per axis).

    For each block, over the block *dilated by one voxel* (every voxel a
    sample inside the block reads: its own, and the 8 its distance is
    interpolated from):
    bmin: (NB, NB, NB) float64 the smallest ``dist``;
    bcone: (NB, NB, NB, 8) float64 two bi-cones (unit axis, sin of
      half-angle; then the second) whose union contains every voxel cone
      there that a sample can read: the cones of the block's own voxels, and
      of the dilation's voxels closer than ``cut_locality`` (a sample reads a
      neighbour's cone only when its dist < min(locality, best), see
      ``occlusion_march.sample_voxel``).  The members are split in two clusters (two
      walls meeting at an edge: one cone each); sin = 2: a member is unknown
      or the cone is wider than pi/2 - 1e-3 (meets every plane); sin = -2:
      meets no plane (no member).
    cut_locality: [m] that cut, default_locality(grid) (+1e-9 relative); a
      march with a larger locality skips by bmin / vmin only.
    runs: (NB, NB, NB, 8) uint8, per block and direction octant (index
      ``direction_octant``) the side k of a cube of (k + 1)^3 blocks that
      has the block at its corner and extends along the octant, every block
      of which a segment leaves at once whenever it leaves this one by its
      cones (``_block_runs``): the march crosses the cube in one step.
    The same for each voxel and its 26 neighbours (B = 1) when R^3 * 20
    bytes <= VOXEL_LEVEL_MAX: vmin (R, R, R) float32 (exact: a minimum of
    float32 values), vcone (R, R, R, 8) int16 (axis and sin times _CONE_Q,
    rounded conservatively, see _quantize_cone); else (1, 1, 1)
    placeholders and has_voxel_level False.
    A block (voxel) can hold no occluder candidate of a segment when its
    min >= the current threshold min(locality, best) or (locality <=
    cut_locality) neither union cone meets the plane orthogonal to d
    (:func:`union_meets`); ``occlusion_march.march_segment`` then skips it.
    So the cones of a block (voxel) whose min (1 - BLOCK_REL) >=
    cut_locality are never read: they are not built and hold "meets none"
    (sin = -2 in both).

    Tightness, on the Cornell grid of tests/test_frequency_kernels.py and
    500 directions: the members meet the plane for 0.486 of (block, d)
    pairs and 0.216 of (voxel, d) pairs; one uncut union per block passed
    0.852 and 0.489, one cut union 0.665 and 0.338, the two cut unions
    pass 0.570 and 0.244.  In bench_render's Cornell box the cut
    made the march 0.89x as long, the second cone 0.89x again (same
    results, bench/bench_march.py).
    """
    B: int
    bmin: np.ndarray
    bcone: np.ndarray
    vmin: np.ndarray
    vcone: np.ndarray
    has_voxel_level: bool
    cut_locality: float
    runs: np.ndarray


#: Largest per-voxel level of MarchBlocks [bytes] (20 B/voxel: 5 MB at 64^3,
#: 42 MB at 128^3); finer grids march with the block level only.
VOXEL_LEVEL_MAX = 64 * 2 ** 20


@nb.njit(cache=True)
def cut_locality(c0, c1, c2):
    """The locality [m] the union cones of MarchBlocks are cut for:
    default_locality (2 voxel diagonals), by one formula for the build and
    the march (bit-identical), + 1e-9 relative so that default_locality's
    own rounding (np.linalg.norm) stays below it."""
    return 2.0 * math.sqrt(c0 * c0 + c1 * c1 + c2 * c2) * (1.0 + 1e-9)


@nb.njit(cache=True)
def _in_cut(dist, x, y, z, inner, L):
    """Is voxel (x, y, z)'s cone a member of a union cone cut at locality L?
    A sample reads a neighbour's cone only when that neighbour's dist <
    min(locality, best) <= L (occlusion_march.sample_voxel: dist < thr before the
    interpolation, dn = max(di, dist) < locality after it); its own cone
    (inner: a voxel of the block itself) always."""
    return inner or np.float64(dist[x, y, z]) < L


@nb.njit(cache=True, nogil=True)
def _union_cone(ax_, ay_, az_, as_, idx, n, out, o, seen):
    """out[o:o+4] = a bi-cone (unit axis, sin of half-angle) containing the
    members idx[:n] (unit axes ax_, ay_, az_; as_ = asin of the sin of the
    half-angle within which a member's axis meets a plane): axis = the
    sign-aligned mean, half-angle = max over members of asin(sk) + angle to
    the axis, + _UNION_SLACK.  sin = 2: wider than pi/2 - _UNION_WIDE or the
    axes cancel (meets every plane); -2: no member (meets none).  seen
    (>= 4 * _SEEN,) scratch: the half-angle's maximum skips a member equal
    to one already taken (a flat wall's voxels and the empty voxels that
    take its cone are one member 27 times over): the same maximum, the
    same bits."""
    if n == 0:
        out[o + 3] = -2.0
        return
    rx, ry, rz = ax_[idx[0]], ay_[idx[0]], az_[idx[0]]     # sign reference
    sx = sy = sz = 0.0
    for k in range(n):
        m = idx[k]
        ax, ay, az = ax_[m], ay_[m], az_[m]
        if ax * rx + ay * ry + az * rz < 0.0:
            ax, ay, az = -ax, -ay, -az
        sx += ax
        sy += ay
        sz += az
    nrm = math.sqrt(sx * sx + sy * sy + sz * sz)
    if nrm < 1e-6 * n:
        out[o + 3] = 2.0
        return
    ux, uy, uz = sx / nrm, sy / nrm, sz / nrm
    psi = 0.0
    ns = 0
    for k in range(n):
        m = idx[k]
        ax, ay, az, am = ax_[m], ay_[m], az_[m], as_[m]
        dup = False
        for j in range(ns):
            if (seen[4 * j] == ax and seen[4 * j + 1] == ay and seen[4 * j + 2] == az
                    and seen[4 * j + 3] == am):
                dup = True
                break
        if dup:
            continue
        if ns < _SEEN:
            seen[4 * ns] = ax
            seen[4 * ns + 1] = ay
            seen[4 * ns + 2] = az
            seen[4 * ns + 3] = am
            ns += 1
        # the member meets the plane iff its unit axis is within asin(sk)
        # of it; the union axis then within that plus the angle between
        # the axes (sign-free)
        cx = uy * az - uz * ay
        cy = uz * ax - ux * az
        cz = ux * ay - uy * ax
        th = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), abs(ux * ax + uy * ay + uz * az))
        psi = max(psi, am + th)
    psi += _UNION_SLACK
    out[o] = ux
    out[o + 1] = uy
    out[o + 2] = uz
    out[o + 3] = 2.0 if psi >= 0.5 * math.pi - _UNION_WIDE else math.sin(psi)


#: Distinct members a union cone's half-angle remembers (_union_cone).
_SEEN = 8


@nb.njit(cache=True, nogil=True)
def _cone_members(cone, R, kind, un, asn):
    """Per voxel, what a union cone reads of its cone (_build_blocks), once
    instead of once per block or voxel that reads it (27 times at the voxel
    level): kind 0 = meets no plane, 1 = unknown (meets every plane), 2 = a
    member with unit axis un (R, R, R, 3) float64 and asn = asin of the sin
    of the half-angle within which its axis meets a plane.  A voxel whose
    cone has the bits of the voxel before it (z - 1: the empty voxels that
    take a wall's cone, a wall's own) gets that voxel's results, the same
    bits, without the square root and the arcsine again.  cone: C order."""
    cb = cone.view(np.int32)
    p0 = p1 = p2 = p3 = 0
    pk = -1
    u0 = u1 = u2 = pa = 0.0
    for x in range(R):
        for y in range(R):
            pk = -1                  # no voxel before this one on z
            for z in range(R):
                b0, b1, b2, b3 = cb[x, y, z, 0], cb[x, y, z, 1], cb[x, y, z, 2], cb[x, y, z, 3]
                if pk >= 0 and b0 == p0 and b1 == p1 and b2 == p2 and b3 == p3:
                    kind[x, y, z] = pk
                    if pk == 2:
                        un[x, y, z, 0] = u0
                        un[x, y, z, 1] = u1
                        un[x, y, z, 2] = u2
                        asn[x, y, z] = pa
                    continue
                p0, p1, p2, p3 = b0, b1, b2, b3
                s = np.float64(cone[x, y, z, 3])
                if s < -1.0:
                    kind[x, y, z] = 0
                    pk = 0
                    continue
                ax = np.float64(cone[x, y, z, 0])
                ay = np.float64(cone[x, y, z, 1])
                az = np.float64(cone[x, y, z, 2])
                nrm = math.sqrt(ax * ax + ay * ay + az * az)
                if s + SIN_TOL >= 1.0 or nrm == 0.0:
                    kind[x, y, z] = 1
                    pk = 1
                    continue
                # the member meets the plane iff |a.d| <= s + tol, i.e. its
                # unit axis is within asin((s + tol)/|a|)
                kind[x, y, z] = 2
                pk = 2
                u0, u1, u2 = ax / nrm, ay / nrm, az / nrm
                pa = math.asin(min((s + SIN_TOL) / nrm, 1.0))
                un[x, y, z, 0] = u0
                un[x, y, z, 1] = u1
                un[x, y, z, 2] = u2
                asn[x, y, z] = pa


@nb.njit(cache=True, nogil=True)
def _dilated_min(dist, R, out, tmp):
    """out (R, R, R) float64 = the smallest dist over each voxel and its 26
    neighbours (those inside the grid): three one-axis passes of 3 instead of
    27 reads a voxel.  A minimum is exact whatever the order, so it is the
    27-voxel loop's value bit for bit (the voxel level's bmin of
    :func:`_build_blocks` with B = 1, which takes it as ``pre``).  tmp: (R,
    R, R) float64 scratch."""
    for x in range(R):
        for y in range(R):
            for z in range(R):
                m = np.float64(dist[x, y, z])
                if z > 0:
                    m = min(m, np.float64(dist[x, y, z - 1]))
                if z < R - 1:
                    m = min(m, np.float64(dist[x, y, z + 1]))
                out[x, y, z] = m
    for x in range(R):
        for y in range(R):
            for z in range(R):
                m = out[x, y, z]
                if y > 0:
                    m = min(m, out[x, y - 1, z])
                if y < R - 1:
                    m = min(m, out[x, y + 1, z])
                tmp[x, y, z] = m
    for x in range(R):
        for y in range(R):
            for z in range(R):
                m = tmp[x, y, z]
                if x > 0:
                    m = min(m, tmp[x - 1, y, z])
                if x < R - 1:
                    m = min(m, tmp[x + 1, y, z])
                out[x, y, z] = m


@nb.njit(cache=True, nogil=True, inline="always")
def _two_cones(ax_, ay_, az_, as_, n, ia, ib, out, seen):
    """out[0:8] = the two union cones of the members 0..n-1 (n >= 1; out's
    other entries as _build_blocks set them).  Two clusters: seeded by the
    first member and the member most orthogonal to it, each member to the
    nearer seed (sign-free).  Where two walls meet, the members are the two
    walls' normals: one union of both is a ~90-degree cone that meets nearly
    every plane, two unions meet only the planes grazing a wall."""
    q = 0
    cmin = 2.0
    for k in range(n):
        c = abs(ax_[k] * ax_[0] + ay_[k] * ay_[0] + az_[k] * az_[0])
        if c < cmin:
            cmin = c
            q = k
    na = 0
    nb_ = 0
    for k in range(n):
        ca = abs(ax_[k] * ax_[0] + ay_[k] * ay_[0] + az_[k] * az_[0])
        cb = abs(ax_[k] * ax_[q] + ay_[k] * ay_[q] + az_[k] * az_[q])
        if ca >= cb:
            ia[na] = k
            na += 1
        else:
            ib[nb_] = k
            nb_ += 1
    # np.int64: one compile, not one per literal (core/warmup.py)
    _union_cone(ax_, ay_, az_, as_, ia, np.int64(na), out, np.int64(0), seen)
    _union_cone(ax_, ay_, az_, as_, ib, np.int64(nb_), out, np.int64(4), seen)


@nb.njit(cache=True, nogil=True)
def _member_codes(kind, ubits, abits, dist, vmin, R, L, code, mu):
    """code (R, R, R) int32: what each voxel gives the voxel level's union
    cones (_voxel_level), as a neighbour of a voxel and as that voxel
    itself (a neighbour counts only within the cut, dist < L; a voxel's own
    cone always: _in_cut): -1 nothing either way (kind 0, or a voxel that no
    voxel of the level reads: outside the cut and vmin (1 - BLOCK_REL) >=
    L, its own cones "meets none"); kind 1 (unknown, meets every plane) -2
    within the cut, -3 outside it (itself only); kind 2 an index per
    distinct member (its unit axis and asin bits ubits (R, R, R, 3), abits
    (R, R, R) int64, the views of _cone_members' un and asn), i within the
    cut, -4 - i outside it.  mu (R^3,) int64: the flat voxel of each
    index's first member; equal indices, equal bits.  Returns the number of
    indices."""
    size = 2
    while size < 2 * R * R * R:
        size *= 2
    table = np.full(size, -1, np.int64)
    d = 0
    for x in range(R):
        for y in range(R):
            for z in range(R):
                kd = kind[x, y, z]
                cut = _in_cut(dist, x, y, z, bool(False), L)   # bool(): no literal
                if kd == 0 or (not cut and vmin[x, y, z] * (1.0 - BLOCK_REL) >= L):
                    code[x, y, z] = -1
                    continue
                if kd == 1:
                    code[x, y, z] = -2 if cut else -3
                    continue
                k0, k1, k2, k3 = ubits[x, y, z, 0], ubits[x, y, z, 1], ubits[x, y, z, 2], abits[x, y, z]
                h = np.uint64(_FNV0)
                for k in (k0, k1, k2, k3):
                    h = _fnv(h, k)
                h ^= h >> np.uint64(29)
                j = np.int64(h & np.uint64(size - 1))
                while True:
                    t = table[j]
                    if t < 0:
                        table[j] = d
                        mu[d] = (x * R + y) * R + z
                        t = d
                        d += 1
                        break
                    f = mu[t]
                    fx, fy, fz = f // (R * R), (f // R) % R, f % R
                    if (ubits[fx, fy, fz, 0] == k0 and ubits[fx, fy, fz, 1] == k1
                            and ubits[fx, fy, fz, 2] == k2 and abits[fx, fy, fz] == k3):
                        break
                    j = (j + 1) & (size - 1)
                code[x, y, z] = t if cut else -4 - t
    return d


#: _voxel_level's memo: at most this many distinct member sequences kept.
VOXEL_MEMO = 1 << 15
#: march_blocks builds the voxel level with _voxel_level (False:
#: _build_blocks with B = 1, the same bits; tests compare the two).
VOXEL_LEVEL_MEMO = True


@nb.njit(cache=True, nogil=True, inline="always")
def _slices_equal(code, x0, x1, y0, y1, z):
    """Are the codes of columns [x0, x1) x [y0, y1) equal at z and z + 1?"""
    for xx in range(x0, x1):
        for yy in range(y0, y1):
            if code[xx, yy, z] != code[xx, yy, z + 1]:
                return False
    return True


@nb.njit(cache=True, nogil=True)
def _voxel_level(code, mu, un, asn, R, vmin, vcone, L):
    """The voxel level of MarchBlocks (vcone, int16), the cones of
    :func:`_build_blocks` with B = 1 bit for bit: vmin (R, R, R) float64 the
    dilated minima (:func:`_dilated_min`); code, mu of
    :func:`_member_codes`.  A voxel's two cones are a function of its
    members in order (their bits), so they are computed once per distinct
    sequence of member indices and looked up for the voxels with the same
    sequence (a wall's voxels, an edge's along it): the same bits as
    computing them again.  And a voxel whose 27 codes are those of the
    voxel before it on z (both inside the grid on z: the four slices z - 2
    .. z + 1 of its 3 x 3 columns equal) has that voxel's sequence, so its
    cones: copied (a wall parallel to z).  Returns the number of sequences
    kept."""
    ax_ = np.empty(27)
    ay_ = np.empty(27)
    az_ = np.empty(27)
    as_ = np.empty(27)
    ia = np.empty(27, np.int64)
    ib = np.empty(27, np.int64)
    ids = np.empty(27, np.int64)
    out = np.empty(8)
    seen = np.empty(4 * _SEEN)
    size = 2 * VOXEL_MEMO
    table = np.full(size, -1, np.int64)
    seq_at = np.empty(VOXEL_MEMO, np.int64)
    seq_n = np.empty(VOXEL_MEMO, np.int64)
    pool = np.empty(VOXEL_MEMO * 8, np.int64)
    outs = np.empty((VOXEL_MEMO, 8), np.int16)
    # per column: are the slices z and z + 1 equal (1), not (0), unknown (-1)
    eq = np.empty(R, np.int8)
    ne = 0
    npool = 0
    for x in range(R):
        x0, x1 = max(x - 1, 0), min(x + 2, R)
        for y in range(R):
            y0, y1 = max(y - 1, 0), min(y + 2, R)
            for z in range(R):
                eq[z] = -1
            prev = False                 # voxel z - 1 has its sequence's cones
            for z in range(R):
                if vmin[x, y, z] * (1.0 - BLOCK_REL) >= L:
                    # never read: "meets none" (as _build_blocks)
                    for k in range(8):
                        vcone[x, y, z, k] = 0
                    vcone[x, y, z, 3] = -32768
                    vcone[x, y, z, 7] = -32768
                    prev = False
                    continue
                if prev and 2 <= z <= R - 2:
                    same = True
                    for k in range(z - 2, z + 1):
                        if eq[k] < 0:
                            eq[k] = 1 if _slices_equal(code, x0, x1, y0, y1, k) else 0
                        if eq[k] == 0:
                            same = False
                            break
                    if same:
                        for k in range(8):
                            vcone[x, y, z, k] = vcone[x, y, z - 1, k]
                        continue
                prev = True
                wide = False
                n = 0
                h = np.uint64(_FNV0)
                for xx in range(x0, x1):
                    for yy in range(y0, y1):
                        for zz in range(max(z - 1, 0), min(z + 2, R)):
                            c = code[xx, yy, zz]
                            if xx == x and yy == y and zz == z:
                                # its own cone: outside the cut too
                                if c == -3:
                                    c = -2
                                elif c <= -4:
                                    c = -4 - c
                            if c == -2:
                                wide = True         # unknown: meets every plane
                                continue
                            if c < 0:
                                continue            # meets no plane / never read
                            ids[n] = c
                            h = _fnv(h, c)
                            n += 1
                if wide or n == 0:
                    for k in range(8):
                        out[k] = 0.0
                    out[7] = -2.0
                    out[3] = 2.0 if wide else -2.0
                    _store_cones(out, vcone, x, y, z, bool(True))
                    continue
                h ^= h >> np.uint64(29)
                j = np.int64(h & np.uint64(size - 1))
                hit = -1
                while True:
                    t = table[j]
                    if t < 0:
                        break
                    if seq_n[t] == n:
                        a = seq_at[t]
                        same = True
                        for k in range(n):
                            if pool[a + k] != ids[k]:
                                same = False
                                break
                        if same:
                            hit = t
                            break
                    j = (j + 1) & (size - 1)
                if hit >= 0:
                    for k in range(8):
                        vcone[x, y, z, k] = outs[hit, k]
                    continue
                for k in range(n):
                    f = mu[ids[k]]
                    fx, fy, fz = f // (R * R), (f // R) % R, f % R
                    ax_[k] = un[fx, fy, fz, 0]
                    ay_[k] = un[fx, fy, fz, 1]
                    az_[k] = un[fx, fy, fz, 2]
                    as_[k] = asn[fx, fy, fz]
                for k in range(8):
                    out[k] = 0.0
                out[7] = -2.0
                _two_cones(ax_, ay_, az_, as_, n, ia, ib, out, seen)
                _store_cones(out, vcone, x, y, z, bool(True))
                if ne < VOXEL_MEMO and npool + n <= pool.shape[0]:
                    table[j] = ne
                    seq_at[ne] = npool
                    seq_n[ne] = n
                    for k in range(n):
                        pool[npool + k] = ids[k]
                    npool += n
                    # the quantized cones: a copy per later voxel
                    for k in range(8):
                        outs[ne, k] = vcone[x, y, z, k]
                    ne += 1
    return ne


@nb.njit(cache=True, nogil=True)
def _build_blocks(dist, kind, un, asn, R, B, NB, bmin, bcone, L, quant, pre):
    """bmin (NB, NB, NB) and bcone (NB, NB, NB, 8) of MarchBlocks for blocks
    of B^3 voxels: float64, or int16 (quant: the voxel level's vcone);
    kind, un, asn of :func:`_cone_members`.  pre: bmin already computed
    (:func:`_dilated_min`, B = 1), else an empty (0, 0, 0) array."""
    have = pre.shape[0] == NB
    cap = (B + 2) ** 3
    ax_ = np.empty(cap)
    ay_ = np.empty(cap)
    az_ = np.empty(cap)
    as_ = np.empty(cap)
    ia = np.empty(cap, np.int64)
    ib = np.empty(cap, np.int64)
    out = np.empty(8)
    seen = np.empty(4 * _SEEN)
    memo = np.empty(4)
    memo_out = np.empty(8)
    memo_n = -1
    for bx in range(NB):
        for by in range(NB):
            for bz in range(NB):
                x0, x1 = max(bx * B - 1, 0), min((bx + 1) * B + 1, R)
                y0, y1 = max(by * B - 1, 0), min((by + 1) * B + 1, R)
                z0, z1 = max(bz * B - 1, 0), min((bz + 1) * B + 1, R)
                ix0, ix1 = bx * B, min((bx + 1) * B, R)
                iy0, iy1 = by * B, min((by + 1) * B, R)
                iz0, iz1 = bz * B, min((bz + 1) * B, R)
                if have:
                    m = pre[bx, by, bz]
                else:
                    m = np.inf
                    for x in range(x0, x1):
                        for y in range(y0, y1):
                            for z in range(z0, z1):
                                m = min(m, np.float64(dist[x, y, z]))
                bmin[bx, by, bz] = m
                if m * (1.0 - BLOCK_REL) >= L:
                    # Never read: the march tests the cones only where
                    # bmin (1 - BLOCK_REL) < its threshold <= locality <=
                    # L (MarchGrid.cones), so they are left as "meets none"
                    # and not built (most voxels of an open room).
                    for k in range(8):
                        out[k] = 0.0
                    out[3] = -2.0
                    out[7] = -2.0
                    _store_cones(out, bcone, bx, by, bz, quant)
                    continue
                wide = False
                same = True
                n = 0
                for x in range(x0, x1):
                    for y in range(y0, y1):
                        for z in range(z0, z1):
                            kd = kind[x, y, z]
                            inner = (ix0 <= x < ix1 and iy0 <= y < iy1 and iz0 <= z < iz1)
                            if kd == 0 or not _in_cut(dist, x, y, z, inner, L):
                                continue            # meets no plane / never read
                            if kd == 1:
                                wide = True         # unknown: meets every plane
                                continue
                            ax_[n] = un[x, y, z, 0]
                            ay_[n] = un[x, y, z, 1]
                            az_[n] = un[x, y, z, 2]
                            as_[n] = asn[x, y, z]
                            if n > 0 and (ax_[n] != ax_[0] or ay_[n] != ay_[0]
                                          or az_[n] != az_[0] or as_[n] != as_[0]):
                                same = False
                            n += 1
                for k in range(8):
                    out[k] = 0.0
                out[7] = -2.0
                if wide or n == 0:
                    out[3] = 2.0 if wide else -2.0
                    _store_cones(out, bcone, bx, by, bz, quant)
                    continue
                # n copies of one member (a wall's voxels, the empty voxels
                # that take its cone): the cones below are a function of
                # that member and n alone, so the last such result is reused
                # when both are the same (the same bits).
                if same:
                    if (n == memo_n and ax_[0] == memo[0] and ay_[0] == memo[1]
                            and az_[0] == memo[2] and as_[0] == memo[3]):
                        _store_cones(memo_out, bcone, bx, by, bz, quant)
                        continue
                _two_cones(ax_, ay_, az_, as_, n, ia, ib, out, seen)
                _store_cones(out, bcone, bx, by, bz, quant)
                if same:
                    memo_n = n
                    memo[0], memo[1], memo[2], memo[3] = ax_[0], ay_[0], az_[0], as_[0]
                    for k in range(8):
                        memo_out[k] = out[k]


@nb.njit(cache=True, nogil=True)
def _store_cones(out, bcone, x, y, z, quant):
    if quant:
        # int64 offsets, not literals: one compile for both (a literal is a
        # signature of its own: core.materials.compiled.eval_pair_as)
        _quantize_cone(out, np.int64(0), bcone, x, y, z)
        _quantize_cone(out, np.int64(4), bcone, x, y, z)
    else:
        for k in range(8):
            bcone[x, y, z, k] = out[k]


#: int16 scale of the voxel level's union cones (axis and sin times this).
_CONE_Q = 32767.0


@nb.njit(cache=True, nogil=True)
def _quantize_cone(out, o, q, x, y, z):
    """q[x, y, z, o:o+4] = the float64 cone out[o:o+4] in int16 units of
    1 / _CONE_Q, conservatively: an axis component rounds by <= 0.5 / Q, so
    |a_q . d| <= Q |a . d| + sqrt(3) / 2; sin is rounded up by 3e-5 Q + 1
    (covers that and the float64 evaluation of the test).  Unknown -> (0,
    0, 0, 32767), none -> (0, 0, 0, -32768)."""
    s = out[o + 3]
    sq = math.ceil((s + 3e-5) * _CONE_Q) + 1.0
    for k in range(3):
        q[x, y, z, o + k] = 0
    if s < -1.5:
        q[x, y, z, o + 3] = -32768
    elif s > 1.5 or sq > 32767.0:
        q[x, y, z, o + 3] = 32767
    else:
        for k in range(3):
            q[x, y, z, o + k] = int(round(out[o + k] * _CONE_Q))
        q[x, y, z, o + 3] = int(sq)


def union_meets(c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The march's test of MarchBlocks union cones c (..., 8) (bcone float64
    or vcone int16) against unit directions d (n, 3): (..., n) bool, True
    where one of the two cones meets the plane orthogonal to d."""
    c = np.asarray(c, np.float64)
    d = np.asarray(d, np.float64)
    return ((np.abs(np.einsum("...k,nk->...n", c[..., 0:3], d)) <= c[..., 3:4])
            | (np.abs(np.einsum("...k,nk->...n", c[..., 4:7], d)) <= c[..., 7:8]))


@nb.njit(cache=True, nogil=True, inline="always")
def direction_octant(dx, dy, dz):
    """The index (0..7) of the octant of direction d in MarchBlocks.runs:
    bit 0, 1, 2 set where dx, dy, dz <= 0 (the march steps towards -1 on
    that axis)."""
    return (0 if dx > 0.0 else 1) + (0 if dy > 0.0 else 2) + (0 if dz > 0.0 else 4)


@nb.njit(cache=True, nogil=True)
def _runs_octant(lab, NB, sx, sy, sz, runs, oc, w, g, gl):
    """runs[..., oc] of :func:`_block_runs` for the octant (sx, sy, sz) (+-1
    each): a dynamic programme over the blocks, from the far corner of the
    octant back.  A cube of side n + 1 at b is b and the 7 cubes of side n
    at its forward neighbours; so with f(b, X) the largest side whose
    labels are all -1 or X, f(b, X) = 0 if lab(b) is neither, else 1 + the
    smallest f of the 7 neighbours (0 outside the grid).  f(c, X) is read
    off two numbers a block keeps: w(c), the largest all -1 side, and g(c),
    the largest side with at most one label besides -1, that label gl(c)
    (-1 if none): f(c, X) = g(c) if gl(c) is -1 or X, else w(c) (a larger
    cube than w(c) holds gl(c), and one larger than g(c) holds two labels).
    w, g, gl: (NB, NB, NB) scratch."""
    for i0 in range(NB):
        x = NB - 1 - i0 if sx > 0 else i0
        for i1 in range(NB):
            y = NB - 1 - i1 if sy > 0 else i1
            for i2 in range(NB):
                z = NB - 1 - i2 if sz > 0 else i2
                lb = lab[x, y, z]
                inside = (0 <= x + sx < NB and 0 <= y + sy < NB and 0 <= z + sz < NB)
                # w: every neighbour all -1 too
                wb = 0
                if lb < 0:
                    wb = 1
                    if inside:
                        mw = NB
                        for e in range(1, 8):
                            mw = min(mw, w[x + sx * (e & 1), y + sy * ((e >> 1) & 1),
                                           z + sz * ((e >> 2) & 1)])
                        wb = 1 + mw
                # g: the best label X over b's own and its neighbours' (one
                # of them is the cube's label if it has one)
                gb, glb = wb, -1
                for e in range(8):
                    if e == 0:
                        X = lb
                    elif inside:
                        X = gl[x + sx * (e & 1), y + sy * ((e >> 1) & 1), z + sz * ((e >> 2) & 1)]
                    else:
                        break
                    if X < 0 or (lb >= 0 and X != lb):
                        continue
                    f = 1
                    if inside:
                        mf = NB
                        for q in range(1, 8):
                            cx, cy, cz = x + sx * (q & 1), y + sy * ((q >> 1) & 1), z + sz * ((q >> 2) & 1)
                            gc = gl[cx, cy, cz]
                            mf = min(mf, g[cx, cy, cz] if (gc < 0 or gc == X) else w[cx, cy, cz])
                        f = 1 + mf
                    if f > gb:
                        gb, glb = f, X
                w[x, y, z] = wb
                g[x, y, z] = gb
                gl[x, y, z] = glb
                # the run: a block with a label, the cube of its label and -1;
                # a block left for every direction (-1), the cube of -1 only
                runs[x, y, z, oc] = min((gb if lb >= 0 else wb) - 1, 255)


def _block_runs(bmin: np.ndarray, bcone: np.ndarray, L: float) -> np.ndarray:
    """MarchBlocks.runs.  A block is labelled -1 when a march with the union
    cones (locality <= L) leaves it for every direction: bmin (1 -
    BLOCK_REL) >= L (>= its threshold) or both cones meet no plane; else by
    its two union cones (equal labels: the same 8 floats, bit for bit, so
    the same test result for every direction).  A cube holding only the
    block's own label and -1 is left at once by a segment that leaves the
    block by its cones; a block labelled -1 gets the cube of -1 only."""
    NB = bmin.shape[0]
    flat = np.ascontiguousarray(bcone.reshape(-1, 8))
    wild = ((bmin.reshape(-1) * (1.0 - BLOCK_REL) >= L)
            | ((flat[:, 3] < -1.5) & (flat[:, 7] < -1.5)))
    lab = np.full(NB ** 3, -1, np.int64)
    if (~wild).any():
        _, inv = np.unique(flat[~wild].view(np.dtype((np.void, 64))), return_inverse=True)
        lab[~wild] = inv.reshape(-1)
    lab = lab.reshape(NB, NB, NB)
    runs = np.zeros((NB, NB, NB, 8), np.uint8)
    w = np.empty((NB, NB, NB), np.int64)
    g = np.empty((NB, NB, NB), np.int64)
    gl = np.empty((NB, NB, NB), np.int64)
    for oc in range(8):
        _runs_octant(lab, NB, -1 if oc & 1 else 1, -1 if oc & 2 else 1, -1 if oc & 4 else 1,
                     runs, oc, w, g, gl)
    return runs


_BLOCKS_LOCK = threading.Lock()


def march_blocks(grid: OcclusionGrid, B: int = MARCH_BLOCK) -> MarchBlocks:
    """The coarse level of ``grid``'s march (built once, cached on the grid;
    about 0.1 s and 5.5 MB at 64^3).  Thread-safe.  The march uses B = MARCH_BLOCK."""
    mb = getattr(grid, "_march_blocks", None)
    if mb is not None and mb.B == B:
        return mb
    with _BLOCKS_LOCK:
        mb = getattr(grid, "_march_blocks", None)
        if mb is not None and mb.B == B:
            return mb
        R = grid.res
        NB = -(-R // B)
        bmin = np.empty((NB, NB, NB))
        bcone = np.zeros((NB, NB, NB, 8))
        L = cut_locality(float(grid.cell[0]), float(grid.cell[1]), float(grid.cell[2]))
        kind = np.empty((R, R, R), np.int8)
        un = np.empty((R, R, R, 3))
        asn = np.empty((R, R, R))
        # C order: _cone_members reads the cones' bits through a view
        _cone_members(np.ascontiguousarray(grid.cone), R, kind, un, asn)
        _build_blocks(grid.dist, kind, un, asn, R, B, NB, bmin, bcone, L, False,
                      np.empty((0, 0, 0)))
        if R ** 3 * 20 <= VOXEL_LEVEL_MAX:
            vm = np.empty((R, R, R))
            # the voxel level's minima first (separable: bit for bit the
            # 27-voxel loop's); _build_blocks writes each back in place
            _dilated_min(grid.dist, R, vm, np.empty((R, R, R)))
            vcone = np.zeros((R, R, R, 8), np.int16)
            if VOXEL_LEVEL_MEMO:
                code = np.empty((R, R, R), np.int32)
                mu = np.empty(R ** 3, np.int64)
                _member_codes(kind, un.view(np.int64), asn.view(np.int64), grid.dist, vm, R, L,
                              code, mu)
                _voxel_level(code, mu, un, asn, R, vm, vcone, L)
                del code, mu
            else:
                _build_blocks(grid.dist, kind, un, asn, R, 1, R, vm, vcone, L, True, vm)
            # dist is float32, so its minimum is exact in float32
            vmin = vm.astype(np.float32)
            del vm
            has_v = True
        else:
            vmin = np.zeros((1, 1, 1), np.float32)
            vcone = np.zeros((1, 1, 1, 8), np.int16)
            has_v = False
        del kind, un, asn
        mb = MarchBlocks(B=B, bmin=bmin, bcone=bcone, vmin=vmin, vcone=vcone,
                         has_voxel_level=has_v, cut_locality=L,
                         runs=_block_runs(bmin, bcone, L))
        object.__setattr__(grid, "_march_blocks", mb)    # frozen dataclass: a derived cache
        return mb
