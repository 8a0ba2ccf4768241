"""The gather disc clipped at walls: per-visible-point kernel clip (docs/method.md
"The kernel clipped at walls").

A visible point's kernel disc of radius R (core.sppm.hashgrid, rules (1)-(4))
reaches through a thin wall standing on its surface: a shadowed floor pixel
at the foot of a wall gathers the photons of the lit floor on the other side
(PPM's light leak), and near a concave corner the part of the disc beyond
the wall holds no floor photons while the estimate still divides by pi R^2
(the boundary bias).  Here each visible point casts CLIP_WEDGES short rays in
its tangent plane, along the edges of CLIP_WEDGES equal wedges of the disc
(the tangent frame of ``hashgrid._tangent_frame``: the same normal gets the
same wedges, as the sector cells do), and each wedge keeps a clip distance:

    d_k = cos(pi / CLIP_WEDGES) * min(t_k, t_{k+1})     (t_j: edge j's hit, R on a miss)

and is unclipped (d_k = R) when both edges miss.  For a planar wall
crossing the tangent plane the wall's nearest point in wedge k is at least
d_k away (the foot of its perpendicular is within pi / CLIP_WEDGES of an
edge, or outside the wedge), so the clipped wedge holds nothing from behind
any planar wall.  The gather rejects a photon of wedge k whose offset in the
tangent plane is d_k or farther (hashgrid rule (5)), and the pass's count
and flux are divided by the clipped area fraction

    f = (1 / CLIP_WEDGES) sum_k (d_k / R)^2

(GatherBuffers.fold), so the progressive update still sees a full disc's
worth of photons where the radiance is uniform over the visible part.

Rays start lifted off the surface by max(the accel's spawn offset,
CLIP_LIFT_REL * R), and a hit on a surface oriented like the visible point's
(|dot(n_hit, n_vp)| > CLIP_COS) does not clip: a concave surface of
curvature radius rho curves up by R^2 / (2 rho) over the ray, which passes
the lift where rho < R / (2 CLIP_LIFT_REL), and the orientation test keeps
it from clipping itself.

Storage: one uint64 a visible point, byte k = floor(255 d_k / R) (at most
254 when clipped: rounded down, a clip is never farther than the wall) or
CLIP_OPEN = 255 (unclipped); CLIP_CLEAR (every byte 255) = no clip at all,
the gather's fast path.  8 B a pixel, in fractions of the pass's R: the
clip is cast every pass with its radii.

Rays only where a wall is near (``_near_points``): a visible point whose
ball of radius R + lift (plus a rounding margin) meets no triangle oriented
as a wall to it (|dot(n_tri, n_vp)| <= CLIP_COS) gets CLIP_CLEAR without
rays -- every edge ray would miss or end on a non-wall, the closest hit, and
leave its edge at R.  The triangles near a point are found in a uniform grid
of the accel's triangles (``_NearGrid``, built once per Accel): a triangle is
listed in each cell its bounding box and plane meet, and a point tests the
triangles of the cells its ball's box spans (orientation, bounding box,
plane distance: each test conservative, so a skipped point's code is
CLIP_CLEAR exactly as its rays would have made it).  Walls are near a small
share of the points, so most cast no ray (docs/architecture.md "The 1080p
clip, camera and film without per-pass allocations" has the measurements).
"""
from __future__ import annotations

import math
import threading
import weakref
from typing import NamedTuple, Optional

import numpy as np
from numba import njit, prange

from ..accel import REL_OFFSET
from ..kept import KeptBuffers
from .hashgrid import (CLIP_CLEAR, CLIP_OPEN, CLIP_WEDGES, SECTOR_CELLS, _tangent_frame,
                       clip_weights)
from .photon_kernels import _offset_scale

#: Ray lift above the visible point's surface, relative to R.
CLIP_LIFT_REL = 0.01
#: A hit on a surface whose normal is within 60 degrees of the visible
#: point's (either side) does not clip (the gather's own orientation rule 3).
CLIP_COS = 0.5
_COS_HALF = math.cos(math.pi / CLIP_WEDGES)
#: Visible points per Embree call: the rays and hits of a block (~450 B a
#: visible point: float32 origins and directions, Embree's and Accel's hit
#: arrays) stay ~15 MB instead of ~1 GB at 1080p (the pass's peak comes
#: later, in the gather, where the clip itself is 8 B a pixel).
CLIP_BLOCK = 1 << 15
#: The wall-proximity grid (``_NearGrid``): about this many cells a
#: triangle, at least NEAR_MIN_CELLS, at most NEAR_MAX_CELLS ...
NEAR_CELLS_PER_TRIANGLE = 2
NEAR_MIN_CELLS = 1 << 12
NEAR_MAX_CELLS = 1 << 21
#: ... and at most this many cell entries a triangle (plus NEAR_MIN_CELLS):
#: fewer cells while a count exceeds it.  The grid's int32 starts (at most
#: 2 x the cells asked for) and entries are then <= 48 B a triangle + 48 KiB
#: (core.memory.BYTES_PER_CLIP_TRIANGLE, CLIP_GRID_BYTES).
NEAR_ENTRIES_PER_TRIANGLE = 8
#: A point whose ball spans more cells than this casts its rays untested.
NEAR_MAX_QUERY_CELLS = 64
#: Rounding margin of the proximity tests, relative to the scene's largest
#: coordinate (float32 positions at Embree: 2^-24; this is 256 times that).
NEAR_REL_PAD = 2.0 ** -16
#: Visible points from which the proximity test runs in the numba threads.
NEAR_PARALLEL_MIN = 1 << 16
# cos, sin of the edge angles 2 pi j / CLIP_WEDGES (once, not per ray)
_EDGE_COS = np.cos(2.0 * np.pi * np.arange(CLIP_WEDGES) / CLIP_WEDGES)
_EDGE_SIN = np.sin(2.0 * np.pi * np.arange(CLIP_WEDGES) / CLIP_WEDGES)


@njit(cache=True)
def _edge_rays(p, ng, idx, R2, rel, floor, ec, es):
    """Rays along the CLIP_WEDGES wedge edges of visible points idx (n,):
    origins o (n * W, 3) float32 = p + lift n, directions d (n * W, 3)
    float32 = cos(2 pi j / W) t1 + sin(2 pi j / W) t2 (j = edge), with
    (t1, t2) = _tangent_frame(ng) and lift = max(accel.offset_scale(p),
    CLIP_LIFT_REL R) (rel, floor: the offset's, photon_kernels._offset_scale);
    R (n,) float64 = sqrt(R2[idx]); the rays' lengths t_max (n * W,)
    float32, R rounded as Accel's t_max is (min(R, 3e37) to float32).  ec,
    es (W,) the edges' cos and sin.  One loop: the lift, the radii and the
    lengths were numpy temporaries of every block (~15 % of the clip's CPU)."""
    n = idx.shape[0]
    W = CLIP_WEDGES
    o = np.empty((n * W, 3), np.float32)
    d = np.empty((n * W, 3), np.float32)
    R = np.empty(n)
    t_max = np.empty(n * W, np.float32)
    for i in range(n):
        v = idx[i]
        r = math.sqrt(R2[v])
        R[i] = r
        lift = max(_offset_scale(p[v, 0], p[v, 1], p[v, 2], rel, floor), CLIP_LIFT_REL * r)
        t = np.float32(min(r, 3e37))
        n0, n1, n2 = ng[v, 0], ng[v, 1], ng[v, 2]
        t0, t1, t2, t3, t4, t5 = _tangent_frame(n0, n1, n2)
        for j in range(W):
            c, s = ec[j], es[j]
            k = i * W + j
            o[k, 0] = p[v, 0] + lift * n0
            o[k, 1] = p[v, 1] + lift * n1
            o[k, 2] = p[v, 2] + lift * n2
            d[k, 0] = c * t0 + s * t3
            d[k, 1] = c * t1 + s * t4
            d[k, 2] = c * t2 + s * t5
            t_max[k] = t
    return o, d, R, t_max


@njit(cache=True)
def _codes(t, prim, tri_ng, ng, idx, R, margin, out):
    """out[idx[i]] = the packed clip of visible point idx[i] from its edge
    rays' hit distances t (n * W,) (inf on a miss) and triangles prim
    (tri_ng (T, 3) their unit geometric normals); margin: the factor
    cos(pi / W) of the module docstring."""
    W = CLIP_WEDGES
    edge = np.empty(W)
    for i in range(idx.shape[0]):
        v = idx[i]
        r = R[i]
        for j in range(W):
            k = i * W + j
            e = r
            if prim[k] >= 0 and t[k] < r:
                q = prim[k]
                dn = abs(tri_ng[q, 0] * ng[v, 0] + tri_ng[q, 1] * ng[v, 1]
                         + tri_ng[q, 2] * ng[v, 2])
                if dn <= CLIP_COS:
                    e = t[k]
            edge[j] = e
        code = np.uint64(0)
        for k in range(W):
            m = min(edge[k], edge[(k + 1) % W])
            b = CLIP_OPEN
            if m < r:
                b = min(int(math.floor(255.0 * margin * m / r)), CLIP_OPEN - 1)
                b = max(b, 0)
            code |= np.uint64(b) << np.uint64(8 * k)
        out[v] = code


class NearGrid(NamedTuple):
    """The accel's triangles by cell, for the wall-proximity test
    (``_near_points``).  tri (T, 3, 3) float32 (the accel's own); lo, hi (3,)
    their bounding box; h (3,) the cells' sizes, dims (3,) int64 their
    numbers; start (C + 1,) int32, entries (E,) int32: cell c lists the
    triangles entries[start[c]:start[c + 1]], cells numbered (ix * ny + iy) *
    nz + iz; prm (2,) float64: the triangles' largest |coordinate|, the pad
    their boxes were grown by."""
    tri: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    h: np.ndarray
    dims: np.ndarray
    start: np.ndarray
    entries: np.ndarray
    prm: np.ndarray


@njit(cache=True, error_model="numpy", inline="always")
def _cell(x, lo, h, n):
    """The cell of coordinate x on an axis of n cells of size h from lo,
    clamped to 0..n-1 (monotone in x: the build and the test agree)."""
    f = np.floor((x - lo) / h)
    if f < 0.0:
        return 0
    if f > n - 1:
        return n - 1
    return int(f)


@njit(cache=True, error_model="numpy")
def _near_cells(tri, lo, h, dims, pad, start, entries, cur, budget, fill):
    """List each triangle of tri (T, 3, 3) in the cells its bounding box,
    grown by pad, spans and whose box, grown by pad, its plane meets (a
    conservative triangle-box test).  fill False: count into start[c + 1]
    and return the total, -1 as soon as it exceeds budget; fill True: write
    entries at the cursors cur (C,) (start's first C values)."""
    ny, nz = dims[1], dims[2]
    total = 0
    for t in range(tri.shape[0]):
        a0, a1, a2 = np.float64(tri[t, 0, 0]), np.float64(tri[t, 0, 1]), np.float64(tri[t, 0, 2])
        b0, b1, b2 = np.float64(tri[t, 1, 0]), np.float64(tri[t, 1, 1]), np.float64(tri[t, 1, 2])
        c0, c1, c2 = np.float64(tri[t, 2, 0]), np.float64(tri[t, 2, 1]), np.float64(tri[t, 2, 2])
        ix0 = _cell(min(a0, b0, c0) - pad, lo[0], h[0], dims[0])
        ix1 = _cell(max(a0, b0, c0) + pad, lo[0], h[0], dims[0])
        iy0 = _cell(min(a1, b1, c1) - pad, lo[1], h[1], dims[1])
        iy1 = _cell(max(a1, b1, c1) + pad, lo[1], h[1], dims[1])
        iz0 = _cell(min(a2, b2, c2) - pad, lo[2], h[2], dims[2])
        iz1 = _cell(max(a2, b2, c2) + pad, lo[2], h[2], dims[2])
        e0, e1, e2 = b0 - a0, b1 - a1, b2 - a2
        f0, f1, f2 = c0 - a0, c1 - a1, c2 - a2
        n0, n1, n2 = e1 * f2 - e2 * f1, e2 * f0 - e0 * f2, e0 * f1 - e1 * f0
        # the plane meets the grown cell box: |n . (centre - a)| <= sum |n_k| half_k
        rad = (abs(n0) * (0.5 * h[0] + pad) + abs(n1) * (0.5 * h[1] + pad)
               + abs(n2) * (0.5 * h[2] + pad))
        for ix in range(ix0, ix1 + 1):
            x = lo[0] + (ix + 0.5) * h[0] - a0
            for iy in range(iy0, iy1 + 1):
                y = lo[1] + (iy + 0.5) * h[1] - a1
                for iz in range(iz0, iz1 + 1):
                    z = lo[2] + (iz + 0.5) * h[2] - a2
                    if abs(n0 * x + n1 * y + n2 * z) > rad:
                        continue
                    c = (ix * ny + iy) * nz + iz
                    if fill:
                        entries[cur[c]] = t
                        cur[c] += 1
                    else:
                        start[c + 1] += 1
                        total += 1
                        if total > budget:
                            return -1
    return total


def near_grid(tri_p: np.ndarray) -> Optional[NearGrid]:
    """The NearGrid of the triangles tri_p (T, 3, 3) float32 (None: no
    triangle, or one not finite: every active point then casts its rays).
    About NEAR_CELLS_PER_TRIANGLE cells a triangle, fewer while the entries
    would exceed NEAR_ENTRIES_PER_TRIANGLE a triangle (a single cell at
    worst)."""
    T = tri_p.shape[0]
    tri = np.ascontiguousarray(tri_p, np.float32)
    if T == 0 or not np.all(np.isfinite(tri)):
        return None
    v = tri.reshape(-1, 3).astype(np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    scale = float(max(np.abs(lo).max(), np.abs(hi).max(), 1e-30))
    pad = NEAR_REL_PAD * scale
    # a flat axis (a scene in one plane) gets a thickness, so cells have a volume
    ext = np.maximum(hi - lo, max(float((hi - lo).max()) * 1e-3, pad))
    budget = NEAR_ENTRIES_PER_TRIANGLE * T + NEAR_MIN_CELLS
    cells = min(max(NEAR_CELLS_PER_TRIANGLE * T, NEAR_MIN_CELLS), NEAR_MAX_CELLS)
    while True:
        dims = _grid_dims(ext, cells)
        h = ext / dims
        start = np.zeros(int(np.prod(dims)) + 1, np.int32)
        none32 = np.empty(0, np.int32)
        total = _near_cells(tri, lo, h, dims, pad, start, none32, start[:0], budget, False)
        if total >= 0 or cells <= 1:
            break
        cells //= 8
    np.cumsum(start, out=start)
    entries = np.empty(int(start[-1]), np.int32)
    _near_cells(tri, lo, h, dims, pad, start, entries, start[:-1].copy(), 0, True)
    return NearGrid(tri, lo, hi, h, dims, start, entries, np.array([scale, pad]))


def _grid_dims(ext: np.ndarray, cells: int) -> np.ndarray:
    """(3,) int64 cells along each axis of a box of sides ext (3,) > 0:
    cubes of the side that makes about `cells` of them, at most 2 cells (a
    thin axis still gets one cell), at most 1024 an axis."""
    if cells <= 1:
        return np.ones(3, np.int64)
    side = (float(np.prod(ext)) / cells) ** (1.0 / 3.0)
    while True:
        dims = np.clip(np.ceil(ext / side), 1, 1024).astype(np.int64)
        if int(np.prod(dims)) <= 2 * cells:
            return dims
        side *= 1.1


@njit(cache=True, error_model="numpy", inline="always")
def _near(v, g, tri_ng, p, ng, R2, rel, floor):
    """Whether a triangle oriented as a wall to visible point v (the kernel
    clip's rule: |dot(tri_ng, ng[v])| <= CLIP_COS) may meet the ball of
    radius R + lift (the reach of its edge rays, _edge_rays) around p[v],
    grown by a rounding margin.  Conservative: True also when the ball
    spans more than NEAR_MAX_QUERY_CELLS cells or p, R are not finite."""
    px, py, pz = p[v, 0], p[v, 1], p[v, 2]
    r = math.sqrt(R2[v])
    lift = max(_offset_scale(px, py, pz, rel, floor), CLIP_LIFT_REL * r)
    m = max(abs(px), abs(py), abs(pz), g.prm[0])
    rho = (r + lift) * (1.0 + 2.0 ** -10) + NEAR_REL_PAD * m
    if not (rho < 1e300):                   # inf or nan (p or R)
        return True
    lo, hi, h, dims = g.lo, g.hi, g.h, g.dims
    if (px + rho < lo[0] or px - rho > hi[0] or py + rho < lo[1] or py - rho > hi[1]
            or pz + rho < lo[2] or pz - rho > hi[2]):
        return False                        # no triangle within reach
    ix0, ix1 = _cell(px - rho, lo[0], h[0], dims[0]), _cell(px + rho, lo[0], h[0], dims[0])
    iy0, iy1 = _cell(py - rho, lo[1], h[1], dims[1]), _cell(py + rho, lo[1], h[1], dims[1])
    iz0, iz1 = _cell(pz - rho, lo[2], h[2], dims[2]), _cell(pz + rho, lo[2], h[2], dims[2])
    if (ix1 - ix0 + 1) * (iy1 - iy0 + 1) * (iz1 - iz0 + 1) > NEAR_MAX_QUERY_CELLS:
        return True
    q0, q1, q2 = ng[v, 0], ng[v, 1], ng[v, 2]
    tri = g.tri
    ny, nz = dims[1], dims[2]
    for ix in range(ix0, ix1 + 1):
        for iy in range(iy0, iy1 + 1):
            for iz in range(iz0, iz1 + 1):
                c = (ix * ny + iy) * nz + iz
                for e in range(g.start[c], g.start[c + 1]):
                    t = g.entries[e]
                    dn = abs(tri_ng[t, 0] * q0 + tri_ng[t, 1] * q1 + tri_ng[t, 2] * q2)
                    if dn > CLIP_COS + 1e-6:
                        continue            # not a wall to this point (nan: tested on)
                    a0, a1, a2 = np.float64(tri[t, 0, 0]), np.float64(tri[t, 0, 1]), np.float64(tri[t, 0, 2])
                    b0, b1, b2 = np.float64(tri[t, 1, 0]), np.float64(tri[t, 1, 1]), np.float64(tri[t, 1, 2])
                    c0, c1, c2 = np.float64(tri[t, 2, 0]), np.float64(tri[t, 2, 1]), np.float64(tri[t, 2, 2])
                    if (min(a0, b0, c0) > px + rho or max(a0, b0, c0) < px - rho
                            or min(a1, b1, c1) > py + rho or max(a1, b1, c1) < py - rho
                            or min(a2, b2, c2) > pz + rho or max(a2, b2, c2) < pz - rho):
                        continue            # its bounding box is out of reach
                    e0, e1, e2 = b0 - a0, b1 - a1, b2 - a2
                    f0, f1, f2 = c0 - a0, c1 - a1, c2 - a2
                    n0, n1, n2 = e1 * f2 - e2 * f1, e2 * f0 - e0 * f2, e0 * f1 - e1 * f0
                    s = n0 * (px - a0) + n1 * (py - a1) + n2 * (pz - a2)
                    if s * s > rho * rho * (n0 * n0 + n1 * n1 + n2 * n2):
                        continue            # its plane is out of reach
                    return True
    return False


@njit(cache=True, error_model="numpy")
def _near_range(i0, i1, g, tri_ng, p, ng, R2, active, rel, floor, out, cand):
    """Visible points i0..i1-1: out[v] = CLIP_CLEAR where inactive or no
    wall is near (_near), else 0 (its code comes from its rays) and v listed
    at cand[i0], cand[i0 + 1], ...  Returns how many were listed."""
    n = 0
    for v in range(i0, i1):
        if active[v] and _near(v, g, tri_ng, p, ng, R2, rel, floor):
            out[v] = 0
            cand[i0 + n] = v
            n += 1
        else:
            out[v] = CLIP_CLEAR
    return n


@njit(cache=True, parallel=True)
def _near_parallel(n_chunks, counts, g, tri_ng, p, ng, R2, active, rel, floor, out, cand):
    P = active.shape[0]
    for c in prange(n_chunks):
        counts[c] = _near_range(c * P // n_chunks, (c + 1) * P // n_chunks, g, tri_ng, p, ng,
                                R2, active, rel, floor, out, cand)


def _near_points(g: NearGrid, tri_ng, p, ng, R2, active, rel, floor, out) -> np.ndarray:
    """(n,) int64 the active visible points near a wall (``_near``), in
    order; out (P,) = CLIP_CLEAR at the others, 0 at them.  By pixel ranges
    in the numba threads from NEAR_PARALLEL_MIN points (each point's test is
    its own)."""
    import numba
    P = active.shape[0]
    T = numba.get_num_threads() if P >= NEAR_PARALLEL_MIN else 1
    # written at the start of each range only: pages of it are touched
    # where points are near a wall
    cand = np.empty(P, np.int64)
    counts = np.zeros(T, np.int64)
    # the parallel kernel also for one range: numba's parallel pipeline
    # compiles _near's loop several times faster than njit's (measured in
    # docs/architecture.md, "The 1080p clip, camera and film ...")
    _near_parallel(T, counts, g, tri_ng, p, ng, R2, active, rel, floor, out, cand)
    return np.concatenate([cand[c * P // T:c * P // T + counts[c]] for c in range(T)])


class _AccelClip:
    """What the kernel clip keeps for one Accel: its NearGrid (built at the
    first call) and the codes' buffer, reused from pass to pass when the
    last pass's codes are no longer referenced (core.kept.KeptBuffers)."""

    def __init__(self, accel):
        self.tri_p = accel.tri_p
        self.grid = near_grid(accel.tri_p)
        self.kept = KeptBuffers()


_BY_ACCEL: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_BY_ACCEL_LOCK = threading.Lock()


def _accel_clip(accel) -> _AccelClip:
    with _BY_ACCEL_LOCK:
        s = _BY_ACCEL.get(accel)
        if s is None or s.tri_p is not accel.tri_p:
            s = _BY_ACCEL[accel] = _AccelClip(accel)
        return s


def clip_codes(accel, tri_ng: np.ndarray, p: np.ndarray, ng: np.ndarray, R2: np.ndarray,
               active: np.ndarray, check_stop=lambda: None, near: bool = True) -> np.ndarray:
    """(P,) uint64 packed clips (module docstring) of the visible points at p
    (P, 3) float64 with unit normals ng (P, 3) float64 and squared radii R2
    (P,), for the active (P,) bool ones (CLIP_CLEAR elsewhere); casts
    CLIP_WEDGES rays of length R per active point near a wall (``_near``;
    near=False: per active point, the reference) through accel
    (core.accel.Accel, float32 at Embree): an occlusion query for all
    (cheaper), the closest hit for the occluded ones alone.  tri_ng (T, 3)
    float64: the unit geometric normals of accel's triangles
    (core.sppm.photon_kernels.build_triangle_data).  check_stop() is called
    after the proximity test and before every block (a cancel is seen within
    one block's rays).

    The result is the last call's array (for this accel) when nothing else
    references it any more (core.kept: no page faults of a fresh (P,) array
    every pass), else a new one.

    The blocks (CLIP_BLOCK points; at least four from SPLIT_MIN points) are
    taken in turn by two threads, this one and core.sppm.photons' pool
    (``visible_points.blocks_in_two_threads``; Embree and the kernels release the
    GIL): a point's code depends on its own rays alone, so the codes are the
    same bits however the blocks are shared."""
    from .camera_kernels import SPLIT_MIN
    from .visible_points import blocks_in_two_threads
    P = active.shape[0]
    st = _accel_clip(accel)
    with _BY_ACCEL_LOCK:                # two callers never get one buffer
        out, = st.kept.take("codes", [((P,), np.uint64)])
    p = np.ascontiguousarray(p, np.float64)
    ng = np.ascontiguousarray(ng, np.float64)
    R2 = np.ascontiguousarray(R2, np.float64)
    rel, floor = REL_OFFSET, accel.abs_floor / REL_OFFSET
    if near and st.grid is not None:
        idx = _near_points(st.grid, np.ascontiguousarray(tri_ng, np.float64), p, ng, R2,
                           np.ascontiguousarray(active, np.bool_), rel, floor, out)
    else:
        out[...] = CLIP_CLEAR
        idx = np.nonzero(active)[0] if accel.tri_p.shape[0] else np.zeros(0, np.int64)
    # a cancel during the proximity test is seen here, not after the grid build
    check_stop()
    if idx.size == 0:
        return out

    def block(ib):
        o, d, R, t_max = _edge_rays(p, ng, ib, R2, rel, floor, _EDGE_COS, _EDGE_SIN)
        j = np.nonzero(accel.occluded(o, d, t_max))[0]
        t = np.full(t_max.shape[0], np.inf)
        prim = np.full(t_max.shape[0], -1, np.int32)
        if j.size:
            hits = accel.intersect(o[j], d[j], t_max=t_max[j])
            t[j], prim[j] = hits.t, hits.prim
        _codes(t, prim, tri_ng, ng, ib, R, _COS_HALF, out)

    if idx.size < SPLIT_MIN:
        check_stop()
        block(idx)
        return out
    blk = min(CLIP_BLOCK, -(-idx.size // 4))

    def block_at(b0):
        check_stop()
        block(idx[b0:b0 + blk])
    blocks_in_two_threads(idx.size, blk, block_at)
    return out


@njit(cache=True)
def _inverse_fractions(codes, idx, out):
    W = np.empty((SECTOR_CELLS, SECTOR_CELLS))
    for i in range(idx.shape[0]):
        c = codes[idx[i]]
        out[i] = 1.0 if c == CLIP_CLEAR else clip_weights(c, W)


def inverse_fractions(codes: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(n,) float64 the count and flux weight 1 / max(f, CLIP_MIN_FRACTION)
    of the visible points idx (n,) int (1 where unclipped); codes (P,) uint64."""
    out = np.empty(idx.shape[0])
    _inverse_fractions(codes, np.ascontiguousarray(idx, np.int64), out)
    return out
