"""Test oracle: the voxel-by-voxel occlusion march.

The first march of the occlusion grid, kept as the reference of the blocked
march (``core.frequency.occlusion_march.march_segment``,
tests/test_frequency_kernels.py, bench/bench_march.py): it visits every voxel
a segment crosses and samples it with the same ``sample_voxel``; the blocked
march skips what provably holds no candidate, and differs only where a
Lipschitz jump of this march landed inside a voxel.
"""
import math

import numba as nb
import numpy as np

from core.frequency.occlusion_grid import OcclusionGrid, check_locality
from core.frequency.occlusion_march import sample_voxel


@nb.njit(cache=True, nogil=True)
def march_dense(dist, cone, lo, cell, R, o, d, t_end,
                 locality, t_skip, out):
    """The first march: every voxel the segment crosses, with Lipschitz
    jumps that may land inside a voxel (which then is sampled on the rest of
    its piece only).  ``occlusion_march.march_segment`` samples the same
    voxels at the same points except after such a jump."""
    N = o.shape[0]
    diag = math.sqrt(cell[0] ** 2 + cell[1] ** 2 + cell[2] ** 2)
    eps = 1e-6 * min(cell[0], min(cell[1], cell[2]))
    ghi = np.empty(3)
    for j in range(3):
        ghi[j] = lo[j] + R * cell[j]
    p = np.empty(3)
    iv = np.empty(3, np.int64)
    for i in range(N):
        out[i] = np.inf
        ta = t_skip
        tb = t_end[i] - t_skip
        # clip to the grid box (slabs); outside it there is no geometry
        for j in range(3):
            if d[i, j] != 0.0:
                t0 = (lo[j] - o[i, j]) / d[i, j]
                t1 = (ghi[j] - o[i, j]) / d[i, j]
                if t0 > t1:
                    t0, t1 = t1, t0
                ta = max(ta, t0)
                tb = min(tb, t1)
            elif o[i, j] < lo[j] or o[i, j] > ghi[j]:
                tb = -np.inf
        best = np.inf
        t = ta
        while t < tb:
            for j in range(3):
                p[j] = o[i, j] + t * d[i, j]
                iv[j] = min(max(int(math.floor((p[j] - lo[j]) / cell[j])), 0), R - 1)
            # parameter where the ray leaves this voxel
            t_exit = tb
            for j in range(3):
                if d[i, j] > 0.0:
                    t_exit = min(t_exit, (lo[j] + (iv[j] + 1) * cell[j] - o[i, j]) / d[i, j])
                elif d[i, j] < 0.0:
                    t_exit = min(t_exit, (lo[j] + iv[j] * cell[j] - o[i, j]) / d[i, j])
            dv = dist[iv[0], iv[1], iv[2]]
            # Lipschitz bound: any point q of this voxel has true distance
            # >= dv - diag/2, and the interpolated distance at q (8 centres
            # within one diagonal) >= true - diag.  So the interpolated value
            # stays above `locality` for a further (dv - 1.5 diag - locality).
            lb = dv - 1.5 * diag - locality
            if lb <= 0.0:
                ts = 0.0
                for j in range(3):
                    ts += (lo[j] + (iv[j] + 0.5) * cell[j] - o[i, j]) * d[i, j]
                ts = min(max(ts, t), min(t_exit, tb))
                best = sample_voxel(dist, cone, lo, cell, R, iv[0], iv[1], iv[2],
                                    o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                     ts, locality, best)
                t_next = t_exit
            else:
                t_next = max(t_exit, t + lb)
            t = t_next + eps
        if best < np.inf:
            out[i] = best * best


def march_occlusion_dense(grid: OcclusionGrid, o, d, t_end, locality: float,
                          skip_voxels: float = 1.0):
    """``occlusion_march.march_occlusion`` (a_occ only) by the dense march:
    (N,) float64 (min candidate distance)^2, inf without occluder."""
    o = np.ascontiguousarray(np.asarray(o, np.float64).reshape(-1, 3))
    d = np.ascontiguousarray(np.asarray(d, np.float64).reshape(-1, 3))
    t_end = np.ascontiguousarray(np.broadcast_to(np.asarray(t_end, np.float64), (len(o),)))
    out = np.empty(len(o))
    if len(o) == 0 or not np.isfinite(grid.dist).any():
        out[:] = np.inf
        return out
    check_locality(grid, locality)
    march_dense(grid.dist, grid.cone, grid.lo, grid.cell, grid.res, o, d, t_end,
                 float(locality), float(skip_voxels) * grid.voxel_diagonal, out)
    return out
