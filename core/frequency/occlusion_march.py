"""The march of the occlusion grid: a_occ of photon segments.

``core.frequency.occlusion_grid`` builds the grid (distance field, bi-cones,
the coarse ``MarchBlocks``); this module walks a segment through it and
returns the squared distance of the nearest occluder candidate, a_occ, and
where on the segment it stands (the occlusion operator of docs/frequency.md
acts there).  :func:`march_segment` is one segment with scalars in and out,
for the compiled frequency chains (core.frequency.kernels);
:func:`march_occlusion` is the array form.  The voxel-by-voxel reference
march lives in tests/oracle_occlusion.py.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from .occlusion_grid import (BLOCK_REL, BLOCK_SHIFT, MARCH_BLOCK, SIN_TOL, OcclusionGrid,
                             check_locality, cut_locality, direction_octant, march_blocks)

# Numba caches the kernels below by this file's hash, and BLOCK_SHIFT is
# frozen into them: a cached march of another block size would read the
# MarchBlocks wrongly.  Keep this line equal to occlusion_grid.BLOCK_SHIFT.
_COMPILED_FOR_BLOCK_SHIFT = 2
if _COMPILED_FOR_BLOCK_SHIFT != BLOCK_SHIFT:
    raise ImportError("occlusion_march: _COMPILED_FOR_BLOCK_SHIFT != occlusion_grid.BLOCK_SHIFT")


class MarchGrid(NamedTuple):
    """What :func:`march_segment` reads: an OcclusionGrid's dist (R, R, R)
    float32 and cone (R, R, R, 4) float32, its MarchBlocks (bmin (NB, NB, NB)
    float64, bcone (NB, NB, NB, 8) float64, vmin (R, R, R) float32, vcone
    (R, R, R, 8) int16, has_voxel_level, B, runs (NB, NB, NB, 8) uint8 and
    cut_locality as bcut [m]), lo and cell (3,) float64, res R;
    locality [m] and t_skip [m] (the segment ends ignored) of the march;
    and what every segment's set-up would compute again (``march_grid``, by
    the same expressions: the same bits): icell (3,) float64 1 / cell, eps
    [m] the step past an exit (1e-6 of the smallest cell side), vjump [m]
    the margin of a Lipschitz jump (1.5 voxel diagonals, +1e-6), cones:
    the union cones of the MarchBlocks apply (locality <= cut_locality)."""
    dist: np.ndarray
    cone: np.ndarray
    bmin: np.ndarray
    bcone: np.ndarray
    vmin: np.ndarray
    vcone: np.ndarray
    has_voxel_level: bool
    B: int
    lo: np.ndarray
    cell: np.ndarray
    res: int
    locality: float
    t_skip: float
    icell: np.ndarray
    eps: float
    vjump: float
    cones: bool
    runs: np.ndarray
    bcut: float


def _constants(cell, locality):
    """(icell, eps, vjump, cones) of a MarchGrid (see there)."""
    c0, c1, c2 = (float(x) for x in cell)
    icell = np.array([1.0 / c0, 1.0 / c1, 1.0 / c2])
    eps = 1e-6 * min(c0, min(c1, c2))
    vjump = 1.5 * math.sqrt(c0 * c0 + c1 * c1 + c2 * c2) * (1.0 + 1e-6)
    # The union cones leave out neighbours farther than the cut locality
    # (MarchBlocks): valid for a march with locality <= it.  A larger
    # locality skips by distance only (bmin, vmin hold every member).
    return icell, eps, vjump, bool(locality <= cut_locality(c0, c1, c2))


def march_grid(grid: OcclusionGrid, locality: float, skip_voxels: float = 1.0) -> MarchGrid:
    """The :class:`MarchGrid` of ``grid`` for a march with ``locality`` [m]
    that ignores ``skip_voxels`` voxel diagonals at both ends of a segment
    (builds the grid's MarchBlocks on first use; checks the locality)."""
    check_locality(grid, locality)
    mb = march_blocks(grid, MARCH_BLOCK)
    return MarchGrid(grid.dist, grid.cone, mb.bmin, mb.bcone, mb.vmin, mb.vcone,
                     bool(mb.has_voxel_level), int(mb.B), grid.lo, grid.cell, int(grid.res),
                     float(locality), float(skip_voxels) * grid.voxel_diagonal,
                     *_constants(grid.cell, float(locality)), mb.runs, float(mb.cut_locality))


def no_march_grid() -> MarchGrid:
    """A placeholder MarchGrid (never marched) with the dtypes and ranks of a
    real one, so that a kernel taking one compiles once for both."""
    z1 = np.zeros((1, 1, 1), np.float32)
    return MarchGrid(z1, np.zeros((1, 1, 1, 4), np.float32), np.zeros((1, 1, 1)),
                     np.zeros((1, 1, 1, 8)), z1, np.zeros((1, 1, 1, 8), np.int16), False, 1,
                     np.zeros(3), np.ones(3), 1, 0.0, 0.0, *_constants(np.ones(3), 0.0),
                     np.zeros((1, 1, 1, 8), np.uint8), 0.0)


# cone_meets and sample_voxel are inlined into the march (numba IR): a little
# cheaper, the same bits (docs/frequency.md "Where a marched segment's time
# goes").
@nb.njit(cache=True, inline="always")
def cone_meets(cone, vx, vy, vz, dx, dy, dz):
    """Does voxel v's bi-cone (``OcclusionGrid.cone``) meet the plane
    orthogonal to d?  It does iff the axis is within the aperture of that
    plane: arcsin|axis.d| <= aperture.  Unknown cones (0, 0, 0, 1) always."""
    c = abs(cone[vx, vy, vz, 0] * dx + cone[vx, vy, vz, 1] * dy + cone[vx, vy, vz, 2] * dz)
    return c <= cone[vx, vy, vz, 3] + SIN_TOL



@nb.njit(cache=True, inline="always")
def sample_voxel(dist, cone, lo, cell, R, ix, iy, iz, ox, oy, oz, dx, dy, dz, ts,
                  locality, best):
    """The occluder test of voxel (ix, iy, iz) at the segment point o + ts d:
    returns min(best, its candidate distance) (best unchanged if none)."""
    fx = (ox + ts * dx - lo[0]) / cell[0] - 0.5
    fy = (oy + ts * dy - lo[1]) / cell[1] - 0.5
    fz = (oz + ts * dz - lo[2]) / cell[2] - 0.5
    x0 = min(max(int(math.floor(fx)), 0), R - 2)
    y0 = min(max(int(math.floor(fy)), 0), R - 2)
    z0 = min(max(int(math.floor(fz)), 0), R - 2)
    # No candidate unless the own cone or a neighbour's (closer than
    # min(locality, best): dn = max(di, dist) below) meets the plane: decide
    # that before paying for the interpolation (same result).
    if not cone_meets(cone, ix, iy, iz, dx, dy, dz):
        thr = min(locality, best)
        any_n = False
        for ka in range(2):
            for kb in range(2):
                for kc in range(2):
                    if (not any_n and dist[x0 + ka, y0 + kb, z0 + kc] < thr
                            and cone_meets(cone, x0 + ka, y0 + kb, z0 + kc, dx, dy, dz)):
                        any_n = True
        if not any_n:
            return best
    # trilinear interpolation of dist at o + ts d
    di = 0.0
    ux = min(max(fx - x0, 0.0), 1.0)
    uy = min(max(fy - y0, 0.0), 1.0)
    uz = min(max(fz - z0, 0.0), 1.0)
    for ka in range(2):
        wa = ux if ka else 1.0 - ux
        for kb in range(2):
            wb = uy if kb else 1.0 - uy
            for kc in range(2):
                wc = uz if kc else 1.0 - uz
                di += wa * wb * wc * dist[x0 + ka, y0 + kb, z0 + kc]
    if di < locality and di < best:
        # Bi-cone test (cone_meets) of the voxel holding the sample; its
        # distance is di.  On a curved surface the edge-on patch nearest the
        # ray may sit in a neighbour that the ray does not enter: the 8
        # voxels di was interpolated from are tested too, each with the
        # distance max(di, its own dist) so that a neighbour looking at
        # another surface (a wall beside the floor the ray is about to hit)
        # is not credited with the floor's distance.
        if cone_meets(cone, ix, iy, iz, dx, dy, dz):
            best = di
        else:
            for ka in range(2):
                for kb in range(2):
                    for kc in range(2):
                        dn = max(di, np.float64(dist[x0 + ka, y0 + kb, z0 + kc]))
                        if dn < locality and dn < best and cone_meets(
                                cone, x0 + ka, y0 + kb, z0 + kc, dx, dy, dz):
                            best = dn
    return best

@nb.njit(cache=True, nogil=True)
def _clip_slab(lo, c, R, o, d, ta, tb):
    """[ta, tb] clipped to the grid's slab [lo, lo + R c] on one axis (empty,
    tb = -inf, when a ray parallel to the slab lies outside it)."""
    if d != 0.0:
        t0 = (lo - o) / d
        t1 = (lo + R * c - o) / d
        if t0 > t1:
            t0, t1 = t1, t0
        return max(ta, t0), min(tb, t1)
    if o < lo or o > lo + R * c:
        return ta, -np.inf
    return ta, tb


@nb.njit(cache=True, nogil=True)
def _axis_exit(lo, c, i, o, d):
    """Parameter where o + t d leaves voxel slab i of one axis (inf if d = 0)."""
    if d > 0.0:
        return (lo + (i + 1) * c - o) / d
    if d < 0.0:
        return (lo + i * c - o) / d
    return np.inf


@nb.njit(cache=True, nogil=True, inline="always")
def _union_meets(c, x, y, z, dx, dy, dz):
    """Does one of the two union cones c[x, y, z] (MarchBlocks bcone / vcone)
    meet the plane orthogonal to d?  (union_meets, per block.)"""
    return (abs(np.float64(c[x, y, z, 0]) * dx + np.float64(c[x, y, z, 1]) * dy
                + np.float64(c[x, y, z, 2]) * dz) <= np.float64(c[x, y, z, 3])
            or abs(np.float64(c[x, y, z, 4]) * dx + np.float64(c[x, y, z, 5]) * dy
                   + np.float64(c[x, y, z, 6]) * dz) <= np.float64(c[x, y, z, 7]))


@nb.njit(cache=True, nogil=True)
def _far_face(b, B, R, d):
    """Index of the last voxel of block b along an axis, in direction d."""
    return min((b + 1) * B, R) - 1 if d > 0.0 else b * B


@nb.njit(cache=True, nogil=True)
def _cut_over(q0, q1, q2, t0, t1):
    """The largest l_cut(t) = sqrt(q0 + 2 q1 t + q2 t^2) over [t0, t1] (q2
    >= 0: the largest at an end)."""
    return math.sqrt(max(max(q0 + t0 * (2.0 * q1 + t0 * q2), q0 + t1 * (2.0 * q1 + t1 * q2)),
                         0.0))


NO_CUT = np.full((1, 3), np.inf)
NO_PLANES = np.full((1, 2), np.inf)


@nb.njit(cache=True, nogil=True, inline="always")
def _end_plane_explains(l, ts, t_end, ps, pe, tol):
    """Is a candidate at distance l at ts no nearer than the plane the segment
    leaves (cosine ps = |n_s . d|, at distance ts ps) or the plane it lands on
    (cosine pe, at (t_end - ts) pe), less tol?  inf = no such plane.  Such a
    distance is that surface's own: a surface does not cut the light leaving
    or arriving at it, and a candidate of another surface at the same or a
    larger distance is left to the samples farther from the end, where the
    plane's distance has grown (docs/frequency.md "Occlusion")."""
    if ps < np.inf and l >= ts * ps - tol:
        return True
    return pe < np.inf and l >= (t_end - ts) * pe - tol


@nb.njit(cache=True, nogil=True)
def march_segments(m, o, d, t_end, rows, n, out, out_t, cut, planes):
    """(a_occ, t_occ) of segments: for i = rows[k], k < n, out[i], out_t[i] =
    those of the segment [o[i] + t_skip d[i], o[i] + (t_end[i] - t_skip)
    d[i]] (see :func:`march_occlusion`): m a :class:`MarchGrid`; o, d (N, 3)
    float64 (d unit), t_end (N,); rows (>= n,) int64; out, out_t (N,)
    float64 get a_occ [m^2] and the segment parameter t_occ of that
    occluder, (inf, inf) without one.  cut (N, 3) float64 (q0, q1, q2): a
    candidate at distance l at t counts only if l^2 < q0 + 2 q1 t + q2 t^2
    (``kernels.radius_cut``: farther ones cannot bring the deposit's radius
    below the pixels'), inf = every candidate; the skips take that
    threshold's largest value over the block, voxel piece or jump (a convex
    quadratic: at an end).  planes (N, 2) float64: the cosines |n . d| of
    the plane the segment leaves and of the plane it lands on (geometric
    normals), inf = none: a candidate no nearer than either plane at its
    sample (:func:`_end_plane_explains`) is that surface, not an occluder.
    The frequency chains
    (core.frequency.kernels) march the rows of one bounce in one call: the
    arrays of m are unpacked once per call, not per segment: numba counts
    the references of each array it takes out of m, and those counts cost
    as much as a fifth of the march (docs/frequency.md, "Cost").

    Two-level 3D-DDA.  The segment enters the grid at the voxel holding
    o + t d (floor, as the dense march, tests/oracle_occlusion.py) and steps from block to block
    (Amanatides-Woo on the blocks' far faces); a block whose ``MarchBlocks``
    bounds prove that no voxel in it can give a candidate below the current
    threshold min(locality, best) is left at once (its exit + eps).
    Otherwise the segment steps through the block's voxels (per-axis exits
    by the dense march's formula, next voxel where the exit + eps lies) and
    each is sampled at the point of its piece nearest its centre, exactly as
    the dense march does, unless its own 27-voxel bounds (vmin, vcone) prove
    it holds no candidate.  Skipping is exact: a skipped voxel's sample
    could not have lowered best (its interpolated distance is a convex
    combination of dist values >= the bound, and no cone it reads meets the
    plane).  A block skipped for its distance may also be left by a
    Lipschitz jump (sphere tracing), which lands on the entry of the voxel
    it reaches, as the voxel walk would; the dense march's jump could land
    inside a voxel and sample it on part of its piece only, so the result no
    longer depends on where a jump landed.  A block left by its union cones
    (or by a distance >= cut_locality) may also be left with the whole cube
    of blocks ahead of it in ``MarchBlocks.runs`` (each of them left for
    every direction, or by the same union cones, so left too): the segment
    goes on at the cube's exit, the exit formula at its far voxels, and is
    located there by floor as after a jump (docs/frequency.md "Runs of
    blocks, round 20").  Every exit parameter is the
    dense march's expression (a quotient, never a product with 1/d), so the
    sample points carry the same bits.

    Measured: identical a_occ to the dense march on the 60k random segments
    of tests/test_frequency_kernels.py and on 117k photon segments of
    bench_render's Cornell box; identical a_occ and t_occ to the previous
    version of this march (block entries by floor, one uncut union cone per
    block) on those, on 200k random segments (bench/bench_march.py) and on
    12k segments along voxel faces and corners.  Time against that version:
    0.72x on the Cornell segments (cut unions 0.89x, block DDA and reused
    exits 0.90x, two union cones 0.89x), 0.79x on the random ones; about
    0.65 us a Cornell segment, 3.1x faster than the dense march.
    """
    dist, cone, bmin, bcone, vmin, vcone = m.dist, m.cone, m.bmin, m.bcone, m.vmin, m.vcone
    has_v, B, lo, cell, R = m.has_voxel_level, m.B, m.lo, m.cell, m.res
    locality, t_skip = m.locality, m.t_skip
    eps = m.eps
    lo0, lo1, lo2 = lo[0], lo[1], lo[2]
    c0, c1, c2 = cell[0], cell[1], cell[2]
    # 1/cell for the voxel index at block entries (t = an exit + eps, 1e-6
    # voxel past the face: a product instead of a quotient moves the index
    # only within ~1e-14 voxel of a face)
    ic0, ic1, ic2 = m.icell[0], m.icell[1], m.icell[2]
    vjump = m.vjump
    cones = m.cones
    runs, bcut = m.runs, m.bcut
    # The interpolated distance of a point whose nearest surface is one of
    # the planes errs below the plane's distance by up to half a voxel
    # (neighbouring centres nearer other geometry: measured up to 0.25 of a
    # voxel on principled_interior's furniture), so a candidate within half
    # a voxel of a plane's distance is not told from the plane.
    ptol = 0.5 * max(c0, max(c1, c2))
    NB = bmin.shape[0]
    for k in range(n):
        i = rows[k]
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        out[i] = np.inf
        out_t[i] = np.inf
        ta = t_skip
        tb = t_end[i] - t_skip
        if not ta < tb:
            continue                         # nothing between the skipped ends
        # l_cut(t)^2 = q0 + 2 q1 t + q2 t^2 (see the docstring): a convex
        # quadratic, so its largest value over [t0, t1] is at an end
        q0, q1, q2 = cut[i, 0], cut[i, 1], cut[i, 2]
        has_cut = q0 < np.inf
        ps, pe = planes[i, 0], planes[i, 1]
        te = t_end[i]
        # clip to the grid box (slabs); outside it there is no geometry
        ta, tb = _clip_slab(lo0, c0, R, ox, dx, ta, tb)
        ta, tb = _clip_slab(lo1, c1, R, oy, dy, ta, tb)
        ta, tb = _clip_slab(lo2, c2, R, oz, dz, ta, tb)
        sx = 1 if dx > 0.0 else -1
        sy = 1 if dy > 0.0 else -1
        sz = 1 if dz > 0.0 else -1
        oc = direction_octant(dx, dy, dz)
        best = np.inf
        t_best = np.inf
        t = ta
        # Block DDA: the block (bx, by, bz) holding o + t d and the parameters
        # where the segment crosses its far faces (tbx, tby, tbz: the voxel exit
        # formula at the block's last voxel, so bit-identical to the exits of
        # the voxel walk).  Stepping the axes whose exit is behind t replaces a
        # floor and three divisions per block by one division.
        bx = by = bz = 0
        tbx = tby = tbz = np.inf
        ix = iy = iz = 0
        init = True          # locate o + t d by floor (at the start, after a jump)
        have_v = False       # (ix, iy, iz) is the voxel holding o + t d
        # The last voxel exit of each axis (index kx, parameter tnx): a walk that
        # starts in the slab the previous walk ended in reuses it (same bits).
        kx = ky = kz = -2
        tnx = tny = tnz = np.inf
        while t < tb:
            if init:
                ix = min(max(int(math.floor((ox + t * dx - lo0) * ic0)), 0), R - 1)
                iy = min(max(int(math.floor((oy + t * dy - lo1) * ic1)), 0), R - 1)
                iz = min(max(int(math.floor((oz + t * dz - lo2) * ic2)), 0), R - 1)
                bx, by, bz = ix >> BLOCK_SHIFT, iy >> BLOCK_SHIFT, iz >> BLOCK_SHIFT
                tbx = _axis_exit(lo0, c0, _far_face(bx, B, R, dx), ox, dx)
                tby = _axis_exit(lo1, c1, _far_face(by, B, R, dy), oy, dy)
                tbz = _axis_exit(lo2, c2, _far_face(bz, B, R, dz), oz, dz)
                init = False
                have_v = True
            thr = min(locality, best)
            t_exit = min(min(tb, tbx), min(tby, tbz))
            if has_cut:
                thr = min(thr, _cut_over(q0, q1, q2, t, t_exit))
            bm = bmin[bx, by, bz]
            far = bm * (1.0 - BLOCK_REL) >= thr
            if far or (cones and not _union_meets(bcone, bx, by, bz, dx, dy, dz)):
                # leave the block
                # Far from everything, go further (sphere tracing, exact): o + t d
                # is within diag/2 of a centre of this block (dist >= bm), so every
                # point within jump of it has true distance >= bm - diag/2 - jump
                # and interpolated distance (centres within a diagonal) >= that
                # - diag >= thr.  Land on the *entry* of the voxel there, as the
                # voxel walk would: no voxel is sampled on part of its piece.
                jump = bm * (1.0 - 1e-6) - vjump - thr
                if has_cut and jump > 0.0:
                    # the threshold over the whole jump: at most that over
                    # [t, t + jump], so the shorter jump it gives is covered
                    thr = min(min(locality, best),
                              _cut_over(q0, q1, q2, t, max(t_exit, t + jump)))
                    jump = bm * (1.0 - 1e-6) - vjump - thr
                if cones:
                    # Cross the run of blocks ahead in one step (MarchBlocks.runs,
                    # exact): each of its blocks is left by its distance for
                    # every direction, or by the same union cones as this one.
                    # Valid when this block was left by its cones: not by its
                    # distance, or by a distance >= bcut (>= locality >=
                    # thr), or its cones do not meet the plane either.
                    kr = np.int64(runs[bx, by, bz, oc])
                    if kr > 0 and (not far or bm * (1.0 - BLOCK_REL) >= bcut
                                   or not _union_meets(bcone, bx, by, bz, dx, dy, dz)):
                        # its far faces: the exit formula at its last voxels
                        tc = min(min(
                            _axis_exit(lo0, c0, _far_face(bx + sx * kr, B, R, dx), ox, dx),
                            _axis_exit(lo1, c1, _far_face(by + sy * kr, B, R, dy), oy, dy)),
                            _axis_exit(lo2, c2, _far_face(bz + sz * kr, B, R, dz), oz, dz))
                        if not t + jump > tc:          # unless the jump goes further
                            t = tc + eps
                            if not t < tb:
                                break
                            init = True
                            continue
                if t + jump > t_exit:
                    tl = t + jump
                    if not tl < tb:
                        break
                    jx = min(max(int(math.floor((ox + tl * dx - lo0) * ic0)), 0), R - 1)
                    jy = min(max(int(math.floor((oy + tl * dy - lo1) * ic1)), 0), R - 1)
                    jz = min(max(int(math.floor((oz + tl * dz - lo2) * ic2)), 0), R - 1)
                    # entry = the previous voxel's exit on each axis (same formula)
                    # (tj, not te: te is the segment's end, read by the
                    # end-plane test of every later sample)
                    tj = t_exit
                    if dx != 0.0:
                        tj = max(tj, _axis_exit(lo0, c0, jx - 1 if dx > 0.0 else jx + 1, ox, dx))
                    if dy != 0.0:
                        tj = max(tj, _axis_exit(lo1, c1, jy - 1 if dy > 0.0 else jy + 1, oy, dy))
                    if dz != 0.0:
                        tj = max(tj, _axis_exit(lo2, c2, jz - 1 if dz > 0.0 else jz + 1, oz, dz))
                    t = tj + eps
                    init = True
                    continue
                t = t_exit + eps
                if not t < tb:
                    break
                # the next block holds o + t d: step the axes whose exit is behind
                if tbx < t:
                    bx += sx
                    tbx = _axis_exit(lo0, c0, _far_face(bx, B, R, dx), ox, dx)
                if tby < t:
                    by += sy
                    tby = _axis_exit(lo1, c1, _far_face(by, B, R, dy), oy, dy)
                if tbz < t:
                    bz += sz
                    tbz = _axis_exit(lo2, c2, _far_face(bz, B, R, dz), oz, dz)
                if bx < 0 or bx >= NB or by < 0 or by >= NB or bz < 0 or bz >= NB:
                    init = True                # rounding at the grid's edge
                have_v = False
                continue
            if not have_v:
                # entered by a block step: the voxel holding o + t d (floor, as
                # the dense march), in this block unless t sits on a tie of two
                # exits that the step resolved otherwise (then locate again)
                ix = min(max(int(math.floor((ox + t * dx - lo0) * ic0)), 0), R - 1)
                iy = min(max(int(math.floor((oy + t * dy - lo1) * ic1)), 0), R - 1)
                iz = min(max(int(math.floor((oz + t * dz - lo2) * ic2)), 0), R - 1)
                if (ix >> BLOCK_SHIFT != bx or iy >> BLOCK_SHIFT != by
                        or iz >> BLOCK_SHIFT != bz):
                    init = True
                    continue
            # voxel by voxel through this block
            if ix != kx:
                tnx = _axis_exit(lo0, c0, ix, ox, dx)
            if iy != ky:
                tny = _axis_exit(lo1, c1, iy, oy, dy)
            if iz != kz:
                tnz = _axis_exit(lo2, c2, iz, oz, dz)
            while True:
                t_exit = min(min(tb, tnx), min(tny, tnz))
                thr = min(locality, best)
                loc = locality
                if has_cut:
                    thr = min(thr, _cut_over(q0, q1, q2, t, t_exit))
                if (not has_v or (vmin[ix, iy, iz] * (1.0 - BLOCK_REL) < thr
                                  and (not cones
                                       or _union_meets(vcone, ix, iy, iz, dx, dy, dz)))):
                    # sample: the point of this voxel's piece nearest its centre
                    ts = 0.0
                    ts += (lo0 + (ix + 0.5) * c0 - ox) * dx
                    ts += (lo1 + (iy + 0.5) * c1 - oy) * dy
                    ts += (lo2 + (iz + 0.5) * c2 - oz) * dz
                    ts = min(max(ts, t), min(t_exit, tb))
                    if has_cut:
                        loc = min(locality, _cut_over(q0, q1, q2, ts, ts))
                    nb_ = sample_voxel(dist, cone, lo, cell, R, ix, iy, iz, ox, oy, oz,
                                        dx, dy, dz, ts, loc, best)
                    if nb_ < best and not _end_plane_explains(nb_, ts, te, ps, pe, ptol):
                        best = nb_
                        t_best = ts
                t = t_exit + eps
                if not t < tb:
                    break
                # the next voxel holds o + t d: step the axes whose exit is behind
                if tnx < t:
                    ix += sx
                    tnx = _axis_exit(lo0, c0, ix, ox, dx)
                if tny < t:
                    iy += sy
                    tny = _axis_exit(lo1, c1, iy, oy, dy)
                if tnz < t:
                    iz += sz
                    tnz = _axis_exit(lo2, c2, iz, oz, dz)
                nx, ny, nz = ix >> BLOCK_SHIFT, iy >> BLOCK_SHIFT, iz >> BLOCK_SHIFT
                if nx != bx or ny != by or nz != bz or ix >= R or iy >= R or iz >= R:
                    # a new block (ix = R may still be in the last block when B
                    # does not divide R): its voxel is the stepped one; its
                    # far-face exit changes on the axes that stepped only
                    kx, ky, kz = ix, iy, iz
                    if ix < 0 or ix >= R or iy < 0 or iy >= R or iz < 0 or iz >= R:
                        init = True            # rounding at the grid's edge
                    else:
                        if nx != bx:
                            bx = nx
                            tbx = _axis_exit(lo0, c0, _far_face(bx, B, R, dx), ox, dx)
                        if ny != by:
                            by = ny
                            tby = _axis_exit(lo1, c1, _far_face(by, B, R, dy), oy, dy)
                        if nz != bz:
                            bz = nz
                            tbz = _axis_exit(lo2, c2, _far_face(bz, B, R, dz), oz, dz)
                        have_v = True
                    break
        if best < np.inf:
            out[i] = best * best
            out_t[i] = t_best


def march_segment(m, ox, oy, oz, dx, dy, dz, t_end):
    """(a_occ, t_occ) of one segment (:func:`march_segments` on one row):
    m a :class:`MarchGrid`, o and d (unit) scalars."""
    out, out_t = np.empty(1), np.empty(1)
    march_segments(m, np.array([[ox, oy, oz]], np.float64), np.array([[dx, dy, dz]], np.float64),
                   np.array([t_end], np.float64), np.zeros(1, np.int64), 1, out, out_t, NO_CUT,
                   NO_PLANES)
    return out[0], out_t[0]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _march_cut(m, o, d, t_end, out, out_t, cut, planes):
    march_segments(m, o, d, t_end, np.arange(o.shape[0]), o.shape[0], out, out_t, cut, planes)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _march(m, o, d, t_end, out, out_t):
    """Every candidate, no plane (bench/bench_march.py times this)."""
    _march_cut(m, o, d, t_end, out, out_t, np.full((o.shape[0], 3), np.inf),
               np.full((o.shape[0], 2), np.inf))


def march_occlusion(grid: OcclusionGrid, o, d, t_end, locality: float,
                    skip_voxels: float = 1.0, return_t: bool = False, cut=None,
                    n_start=None, n_end=None):
    """a_occ [m^2] for each photon segment [o, o + t_end d].

    o: (N, 3), d: (N, 3) unit directions, t_end: (N,) segment lengths (inf for
    a photon leaving the scene); locality [m]: only geometry closer than this
    to the segment counts (``default_locality(grid)`` = 2 voxel diagonals).
    skip_voxels: the first and last ``skip_voxels`` voxel diagonals of the
    segment are ignored -- the emitter / reflector the segment leaves and the
    receiver it ends on are within a voxel there, and are the surfaces the
    segment connects, not occluders.

    Every voxel the segment crosses is a sample: the distance at the segment
    point of its piece nearest the voxel centre is interpolated trilinearly;
    if < locality and the voxel's bi-cone (or one of the 8 the distance came
    from) meets the plane orthogonal to d, it is an occluder candidate.
    Returns (N,) float64: (min candidate distance)^2, np.inf without occluder;
    with return_t also (N,) the segment parameter t of that occluder (inf
    without one): the occlusion operator acts there, and the light field
    travels on for t_end - t (docs/frequency.md: occlusion is a
    multiplication of the field at the blocker).
    cut: None, or (N, 3) the per-segment threshold of :func:`march_segments`.
    n_start, n_end: None, or (N, 3) the geometric normals of the surface each
    segment leaves and lands on (rows of zeros: none): a candidate no nearer
    than those planes is not an occluder (:func:`march_segments`' planes).
    The traversal (:func:`march_segment`) skips whole blocks of voxels that
    provably hold no candidate below the current minimum (``MarchBlocks``);
    tests/oracle_occlusion.py holds the voxel-by-voxel reference.
    The kernels release the GIL: callers may split N across threads.
    """
    o = np.ascontiguousarray(np.asarray(o, np.float64).reshape(-1, 3))
    d = np.ascontiguousarray(np.asarray(d, np.float64).reshape(-1, 3))
    t_end = np.ascontiguousarray(np.broadcast_to(np.asarray(t_end, np.float64), (len(o),)))
    out = np.empty(len(o))
    out_t = np.full(len(o), np.inf)
    if len(o) == 0 or not np.isfinite(grid.dist).any():
        out[:] = np.inf
        return (out, out_t) if return_t else out
    cut = (np.full((len(o), 3), np.inf) if cut is None
           else np.ascontiguousarray(np.asarray(cut, np.float64).reshape(-1, 3)))
    planes = np.full((len(o), 2), np.inf)
    for k, nrm in enumerate((n_start, n_end)):
        if nrm is not None:
            planes[:, k] = plane_cosines(
                np.ascontiguousarray(np.asarray(nrm, np.float64).reshape(-1, 3)), d)
    _march_cut(march_grid(grid, locality, skip_voxels), o, d, t_end, out, out_t, cut, planes)
    return (out, out_t) if return_t else out


@nb.njit(cache=True, nogil=True)
def plane_cosine(nx, ny, nz, dx, dy, dz):
    """|n . d| of a geometric normal n and a unit direction d, inf for a zero
    n (no plane): one entry of :func:`march_segments`' planes."""
    if nx * nx + ny * ny + nz * nz > 0.25:
        return abs(nx * dx + ny * dy + nz * dz)
    return np.inf


@nb.njit(cache=True, nogil=True)
def plane_cosines(n, d):
    """(N,) :func:`plane_cosine` of normals n (N, 3) and directions d (N, 3)."""
    out = np.empty(n.shape[0])
    for i in range(n.shape[0]):
        out[i] = plane_cosine(n[i, 0], n[i, 1], n[i, 2], d[i, 0], d[i, 1], d[i, 2])
    return out
