"""Test oracle of the visible-point grid build: core.sppm.hashgrid.build_grid
as it was before its compiled, parallel build.

The active VPs and their extent in numpy, and the serial two-pass insertion
(a counting pass and a fill pass over every VP's cells, hash collisions
within a VP removed with a per-slot last-writer mark).  Used by
tests/test_compiled_pass_stages.py; not shipped.
"""
import math

import numpy as np
from numba import njit

from core.sppm import hashgrid as hg


def _bbox_entries(pos, R, origin, inv_h) -> int:
    """Upper bound on cell entries: sum over VPs of their bounding-box cell count."""
    a = np.floor((pos - R[:, None] - origin) * inv_h)
    b = np.floor((pos + R[:, None] - origin) * inv_h)
    return int(np.prod(b - a + 1.0, axis=1).sum())


def build_grid_reference(vp_pos, vp_R, active, cell_factor=hg.CELL_FACTOR, layout="auto",
                         log2_table=None) -> hg.Grid:
    """build_grid's Grid by the numpy extent and the serial insertion."""
    vp_pos = np.ascontiguousarray(vp_pos, dtype=np.float64).reshape(-1, 3)
    K = vp_pos.shape[0]
    vp_R = np.ascontiguousarray(vp_R, dtype=np.float64).reshape(K)
    active = np.asarray(active, dtype=bool).reshape(K)
    with np.errstate(invalid="ignore"):
        act = active & np.isfinite(vp_pos).all(axis=1) & np.isfinite(vp_R) & (vp_R > 0)
    n_active = int(act.sum())
    R_ins = np.zeros(K)
    P_act = vp_pos[act]
    R_act = vp_R[act]
    scale = float(np.abs(P_act).max() + R_act.max())
    R_act = R_act * (1.0 + hg._REL_PAD) + hg._ABS_PAD * scale
    R_ins[act] = R_act
    lo = (P_act - R_act[:, None]).min(axis=0)
    hi = (P_act + R_act[:, None]).max(axis=0)
    origin = lo.copy()
    h = cell_factor * float(np.median(R_act))
    while True:
        inv_h = 1.0 / h
        est = _bbox_entries(P_act, R_act, origin, inv_h)
        if est <= hg.ENTRY_BUDGET_PER_VP * n_active:
            break
        h *= 1.25
    dims = (np.floor((hi - origin) * inv_h).astype(np.int64) + 1)
    n_dense = int(np.prod(dims.astype(np.float64)))
    if log2_table is None:
        log2_table = max(1, int(math.ceil(math.log2(max(est, 2)))))
    else:
        log2_table, layout = max(1, min(int(log2_table), 40)), "hash"
    dense = {"auto": n_dense <= (1 << log2_table), "dense": True, "hash": False}[layout]
    n_slots, shift = (n_dense, 0) if dense else (1 << log2_table, 64 - log2_table)
    args = (vp_pos, R_ins, act, origin, h, inv_h, dense,
            int(dims[0]), int(dims[1]), int(dims[2]), shift, n_slots)
    count = np.zeros(n_slots + 1, np.int64)
    mark = np.full(0 if dense else n_slots, -1, np.int64)
    _insert(*args, count, mark, count, np.zeros(0, np.int32), False)
    cell_start = np.zeros(n_slots + 1, np.int64)
    np.cumsum(count[:n_slots], out=cell_start[1:])
    vp_ids = np.empty(int(cell_start[-1]), np.int32)
    cursor = cell_start.copy()
    mark[:] = -1
    _insert(*args, cursor, mark, cell_start, vp_ids, True)
    cell_start = cell_start.astype(hg.start_dtype(est))      # the build's storage dtype
    return hg.Grid(K, n_active, origin, h, inv_h, lo, hi, bool(dense), dims,
                   0 if dense else log2_table, cell_start, vp_ids, R_ins)


@njit(cache=True)
def _insert(pos, R_ins, active, origin, h, inv_h, dense, nx, ny, nz, shift,
            n_slots, count, mark, cell_start, vp_ids, fill):
    """Counting pass (fill=False: count[s] += 1) or fill pass (fill=True:
    vp_ids[count[s]++] = v, count = running write cursor) over every cell a
    VP's sphere overlaps.  mark[s] = last VP written to slot s (dedup of hash
    collisions within one VP)."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    for v in range(pos.shape[0]):
        if not active[v]:
            continue
        cx, cy, cz = pos[v, 0], pos[v, 1], pos[v, 2]
        r = R_ins[v]
        r2 = r * r
        x0 = np.int64(math.floor((cx - r - ox) * inv_h))
        x1 = np.int64(math.floor((cx + r - ox) * inv_h))
        y0 = np.int64(math.floor((cy - r - oy) * inv_h))
        y1 = np.int64(math.floor((cy + r - oy) * inv_h))
        z0 = np.int64(math.floor((cz - r - oz) * inv_h))
        z1 = np.int64(math.floor((cz + r - oz) * inv_h))
        for iz in range(z0, z1 + 1):
            bz0 = oz + iz * h
            dz = max(bz0 - cz, 0.0, cz - (bz0 + h))
            for iy in range(y0, y1 + 1):
                by0 = oy + iy * h
                dy = max(by0 - cy, 0.0, cy - (by0 + h))
                dyz = dy * dy + dz * dz
                if dyz > r2:
                    continue
                for ix in range(x0, x1 + 1):
                    bx0 = ox + ix * h
                    dx = max(bx0 - cx, 0.0, cx - (bx0 + h))
                    # sphere-box overlap (closest point of the cell box)
                    if dx * dx + dyz > r2:
                        continue
                    s = hg._slot(ix, iy, iz, dense, nx, ny, nz, shift)
                    if s < 0:
                        continue
                    if not dense:
                        if mark[s] == v:
                            continue
                        mark[s] = v
                    if fill:
                        vp_ids[count[s]] = v
                        count[s] += 1
                    else:
                        count[s] += 1
