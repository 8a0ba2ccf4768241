"""Visible-point hash grid and photon gather (stochastic progressive photon mapping).

Each pass (pbrt-v4 SPPM, Hachisuka & Jensen 2009):

    grid = build_grid(vp_pos, vp_R, active)          # once per pass, O(K)
    res = gather(grid, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                 vp_pos, vp_ng, vp_R2, vp_const)    # O(P * candidates)

The grid stores *visible points* (VPs): every active VP is inserted in every
cell its sphere of radius R overlaps, so a photon looks up exactly one cell.
This is the hot loop of the renderer.  The gather first sorts the photons
by cell (a counting sort over a small table, else a merge sort), copying
their data into sorted rows of one record array, so that consecutive photons test
the same VPs (the VP records stay in cache) and read photon data
sequentially; the gather then runs ~2x faster than in photon order.

Counting rule.  Photon p counts for visible point v when
  (1) |x_p - x_v|^2 < R_v^2                      (disc/sphere kernel of PPM),
  (2) dot(wi_p, ng_v) > 0                         (photon arrives from the camera's
                                                   side of the VP's surface),
  (3) dot(ng_p, ng_v) > cos_ng (default 0.5 = cos 60 deg)
                                                  (rejects photons on a differently
                                                   oriented surface, e.g. the other
                                                   wall of a corner).
  (4) a photon on a differently oriented surface (dot(ng_p, ng_v) <= 0.5)
      must not lie behind the VP's tangent plane: dot(x_p - x_v, ng_v) >= 0.
      A no-op with the default cos_ng; with cos_ng = -1 (core.sppm.photon_pass) it keeps
      the concave corner's other wall (in front of the plane) and rejects
      photons inside a closed object at its convex edges, which otherwise
      leak through zero-thickness walls (a light sealed in a box lit
      the box's outer edges; tests/test_stiff_scenes.py).
  (5) with a clip (gather(..., clip=), core.sppm.clip): a photon whose
      offset in the VP's tangent plane lies in wedge k at d_k or farther
      (a wall stands in between) does not count; the fold then divides
      the VP's count and flux by the visible fraction of its disc.
All tests are evaluated in float64 in a fixed operation order, so the
numba kernel and the numpy oracle of tests/oracle_gather.py agree exactly; each is
written as "count only if the comparison is True", so a NaN anywhere (radius,
normal, direction) never counts.

Outputs per VP (see :class:`GatherResult`): the photon count M, Phi_sum = sum of
photon power for VPs whose BSDF is constant (diffuse: the caller multiplies by
albedo/pi), (VP, photon) pairs for the other VPs (the caller evaluates the BSDF
vectorised and scatters), r_pred = min of the frequency photons' predicted
radius (Belcour & Soler 2011; docs/frequency.md "Conservative
accumulation keeps the MINIMUM") and, on request, every (VP, frequency photon)
pair (the QUANTILE estimator's histogram and the spectrum AOV,
core.sppm.photon_pass) and the photon counts per sector cell of the kernel
disc (4 tangent-plane quadrants x 2 equal-area rings: the radius rules of
core.sppm.update).

Cell size (documented choice, measured with bench/bench_gather.py):
  h = CELL_FACTOR * median(active R), CELL_FACTOR = 1.5.
With VP spacing s on a surface and R = 1.5 s, a photon's cell holds about
(h + 2R)^2 / s^2 candidates for pi R^2 / s^2 = 7 hits, while each VP is
stored in about (2R/h + 1)^2 cells.  Build + gather CPU time, K = 65,536,
P = 600,000 (plane / box), for h/R = 0.75, 1, 1.5, 2, 3:
165/160, 153/143, 149/142, 149/145, 173/168 ms -- flat between R and 2R;
1.5 R keeps the memory at ~10 entries per VP.  pbrt-v4 sizes cells from the
max radius; the median is used so that a few large radii (distant surfaces,
held frequency radii) do not coarsen the grid for every VP.  Clamp: h grows
by 25% steps until the grid holds at most ENTRY_BUDGET_PER_VP cell entries per
active VP on average, which bounds build time and memory whatever the radius
distribution (a single VP of 100x the median radius would otherwise occupy
~10^6 cells).

Storage: CSR (cell_start, vp_ids): each active VP's slots (a counting pass
and, after a prefix sum over the VPs, a fill pass), then a counting sort of
these entries by slot, so the VPs of a slot are in ascending order.  Dense 3D grid over the active bounds when that has at most as many
cells as the hash table would have (flat axis-aligned sets); otherwise a
spatial hash of the integer cell coordinates into a power-of-two table of about
one slot per cell entry.  Hash collisions only add candidates (rejected by the
exact test (1)); a VP whose cells collide into one slot is stored once there
(its own slots are deduplicated), so it is never counted twice.

Pairs: the counting pass records, per photon, a 64-bit mask of the counted
entries of its cell and the number of pairs; a prefix sum gives each photon
its output range, and a second pass writes the pairs from the mask (cells of
more than 64 entries redo the exact tests).  No over-allocation, no growth.

Parallelism: with ``parallel=True`` the sorted photons are split into one
contiguous chunk per numba thread, each chunk accumulating into its own (K,)
arrays (race-free, no atomics), summed afterwards (or, with GatherBuffers,
rows reused by every chunk and folded at the touched VPs); the sort copies the
photons by disjoint slot (counting sort) or row (merge sort) ranges, one per
thread.  The build splits the VPs into one
range per thread for their slots, each VP's slots going to one of
SORT_GROUPS = 2 parts (the slots below a split that halves the VPs'
centres, and the others); each part is counting-sorted by slot on its own
thread, in place in cell_start (with more threads, each part is split
further by slot ranges), its entries read in VP order, so a slot's VPs
stay ascending.  The grid's arrays and the build's temporaries can come
from kept buffers (build_grid(..., buffers=)), reused from pass to pass.
Results do not depend on the thread count except for the summation order of
Phi_sum; the grid does not depend on it at all.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional

import numba
import numpy as np
from llvmlite import ir
from numba import njit, prange
from numba.core import types
from numba.extending import intrinsic

from .. import memory
from ..kept import KeptBuffers
from .._numba_cache import serial_twin

COS_NG_DEFAULT = 0.5          # cos(60 deg): photon / VP surface orientation test (3)
CELL_FACTOR = 1.5             # h = CELL_FACTOR * median active radius
ENTRY_BUDGET_PER_VP = 64      # clamp: mean cell entries per active VP
PARALLEL_MIN_PHOTONS = 50_000  # below this, thread start-up outweighs the split
PARALLEL_MIN_VPS = 1 << 18      # build_grid: below this many VPs, one thread
# gather's photon sort: a counting sort over the table's slots up to this
# many slots a photon, a merge sort of the photons' slots above (_sort_photons).
COUNT_SORT_SLOTS_PER_PHOTON = 8
# The count pass tests runs of at least this many photons of one slot
# candidate by candidate, rule (1) as a bit mask over the run, shorter runs
# photon by photon; and only in a chunk whose slots hold this many photons
# on average (256 x 256: ~13; 1080p: ~1, where the candidates' records miss
# the caches and the masks measured 1.1-1.4x slower): _run_min,
# docs/architecture.md "The count pass by runs of a slot, round 14".
COUNT_RUN_MIN = 4
# The gather's sorted photons, a row each (_sorted_photons): position, normal,
# direction, power (3 float64 each) and predicted radius.
PHOTON_RECORD = 13
# The build's counting sort splits the slots in two parts (below a split
# and the others; _insert_parallel is written for two), each VP's slots
# written to its part's list: more threads split each part's slots, and
# scan its entries.
SORT_GROUPS = 2
# A VP's slots are deduplicated by a scan of the ones it already has up to
# this many, then by a sort (a VP far larger than the cells).
_DEDUP_SCAN = 64
# GatherBuffers.fold visits every VP in order, not the touched lists, when at
# least 1/FOLD_SWEEP_FRACTION of them were touched (the lists' random access
# cost ~250 ns a VP, a sequential sweep ~65 ns for every VP: 256², loaded
# machine).  Serial below PARALLEL_MIN_VPS VPs (a parallel region's hand-off
# cost more than a 256² sweep); above, by VP ranges in threads.
FOLD_SWEEP_FRACTION = 8
# Sector counts (gather(..., sectors=True)): the kernel disc split into the 4
# quadrants of the visible point's tangent frame times 2 rings of equal area
# (inner |d| < R / sqrt 2), 8 cells of equal area: the chi-square uniformity
# test of CPPM (Lin et al. 2020) and the Laplacian of APPM read them
# (core.sppm.update; docs/method.md "Radius rules").
SECTOR_QUADRANTS = 4
SECTOR_CELLS = 2 * SECTOR_QUADRANTS
# Insertion radius = R * (1 + REL_PAD) + ABS_PAD * (scene scale): makes the
# cell overlap test conservative against float64 rounding of the cell bounds
# and of R^2 (vp_R2 may be computed as R*R by the caller).  Only adds candidates.
_REL_PAD = 1e-9
_ABS_PAD = 1e-12
# Rule (5), the kernel clipped at walls (core.sppm.clip casts it): a visible
# point's packed clip is one uint64, byte k the clip distance of wedge k of
# CLIP_WEDGES (angles [k, k + 1) * 2 pi / CLIP_WEDGES in the tangent frame)
# as floor(255 d_k / R), CLIP_OPEN = not clipped; CLIP_CLEAR = no wedge is.
CLIP_WEDGES = 8
CLIP_OPEN = 255
CLIP_CLEAR = np.uint64(0xFFFF_FFFF_FFFF_FFFF)
#: The count and flux of a clipped disc are scaled by at most 1 /
#: CLIP_MIN_FRACTION: a visible point walled in on most sides (a crack)
#: keeps a bounded weight.
CLIP_MIN_FRACTION = 1.0 / CLIP_WEDGES
#: A sector cell of a clipped disc keeps its own count (scaled to a full
#: cell's) when at least this fraction of it is visible, else it reads the
#: mean of those that are (clip_weights).
CLIP_CELL_MIN = 0.5

# 64-bit odd multipliers for the spatial hash (splitmix / xxhash constants).
_H1 = np.uint64(0x9E3779B97F4A7C15)
_H2 = np.uint64(0xC2B2AE3D27D4EB4F)
_H3 = np.uint64(0x165667B19E3779F9)
_HM = np.uint64(0xD6E8FEB86659FD93)


@dataclass(frozen=True)
class Grid:
    """Visible points bucketed by cell, CSR layout.

    K: number of visible points the grid was built for (active or not).
    n_active: number of VPs inserted.
    origin: (3,) float64 world position of cell (0, 0, 0)'s min corner.
    h: float cell edge [m]; inv_h = 1/h.
    lo, hi: (3,) float64 bounds of all inserted spheres; photons outside are skipped.
    dense: True = dense grid of dims (3,) int64 cells; False = spatial hash
      with 2**log2_table slots.
    cell_start: (n_slots + 1,) int32 (int64 when the entry bound reaches 2^31:
      see start_dtype); VPs of slot s are vp_ids[cell_start[s]:cell_start[s+1]].
    vp_ids: (n_entries,) int32, ascending within a slot.
    R_ins: (K,) float64 insertion radius (0 for inactive VPs); gather requires
      vp_R2 <= R_ins**2.
    """
    K: int
    n_active: int
    origin: np.ndarray
    h: float
    inv_h: float
    lo: np.ndarray
    hi: np.ndarray
    dense: bool
    dims: np.ndarray
    log2_table: int
    cell_start: np.ndarray
    vp_ids: np.ndarray
    R_ins: np.ndarray

    @property
    def n_slots(self) -> int:
        return self.cell_start.shape[0] - 1

    @property
    def n_entries(self) -> int:
        return self.vp_ids.shape[0]

    def summary(self) -> str:
        kind = "dense %dx%dx%d" % tuple(self.dims) if self.dense else \
            "hash 2^%d" % self.log2_table
        return (f"grid {kind}, h={self.h:.4g}, {self.n_active}/{self.K} VPs, "
                f"{self.n_entries} entries ({self.n_entries / max(self.n_active, 1):.1f}/VP)")


@dataclass
class GatherResult:
    """Per-pass photon statistics of the visible points.

    M: (K,) int64 photons counted by each VP (all VPs).
    Phi_sum: (K, 3) float64 sum of photon power, VPs with vp_const True only
      (0 elsewhere); the caller multiplies by albedo/pi.
    pair_vp, pair_ph: (n_pairs,) int32 (VP, photon) pairs for VPs with vp_const
      False; grouped by photon, otherwise unordered.
    rpred_min: (K,) float64 min ph_rpred over counted frequency photons
      (non-NaN ph_rpred); inf when none.
    freq_pair_vp, freq_pair_ph: (n_freq_pairs,) int32 every (VP, photon) pair
      of a counted frequency photon (non-NaN ph_rpred), all VPs, grouped by
      photon in the order of pair_vp / pair_ph; only when
      gather(..., want_freq_pairs=True), else None.
    sectors: (K, SECTOR_CELLS) int64 photons counted by each VP per sector cell
      (rows sum to M; see _sector_cell), only when gather(..., sectors=True),
      else None.
    """
    M: np.ndarray
    Phi_sum: np.ndarray
    pair_vp: np.ndarray
    pair_ph: np.ndarray
    rpred_min: np.ndarray
    freq_pair_vp: Optional[np.ndarray] = None
    freq_pair_ph: Optional[np.ndarray] = None
    sectors: Optional[np.ndarray] = None


# ----------------------------------------------------------------------------
# Kernels
# ----------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _slot(ix, iy, iz, dense, nx, ny, nz, shift):
    """Slot of integer cell (ix, iy, iz): dense index, or -1 outside a dense grid;
    hash: xor of odd multiples, then a multiplicative (Fibonacci) mix whose top
    log2_table bits are the slot."""
    if dense:
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            return -1
        return ix + nx * (iy + ny * iz)
    k = (np.uint64(ix) * _H1) ^ (np.uint64(iy) * _H2) ^ (np.uint64(iz) * _H3)
    return np.int64((k * _HM) >> np.uint64(shift))


@njit(cache=True, inline="always")
def _vp_cells(v, pos, R_ins, origin, h, inv_h, dense, nx, ny, nz, shift, buf):
    """The slots of the cells VP v's sphere overlaps (sphere-box overlap:
    the closest point of the cell box), each once (a hash may map two of its
    cells to one slot), in buf (any order; its size at least the VP's
    bounding-box cell count, see _bbox_range); returns how many.""" 
    ox, oy, oz = origin[0], origin[1], origin[2]
    cx, cy, cz = pos[v, 0], pos[v, 1], pos[v, 2]
    r = R_ins[v]
    r2 = r * r
    x0 = np.int64(math.floor((cx - r - ox) * inv_h))
    x1 = np.int64(math.floor((cx + r - ox) * inv_h))
    y0 = np.int64(math.floor((cy - r - oy) * inv_h))
    y1 = np.int64(math.floor((cy + r - oy) * inv_h))
    z0 = np.int64(math.floor((cz - r - oz) * inv_h))
    z1 = np.int64(math.floor((cz + r - oz) * inv_h))
    n = 0
    unchecked = False          # past _DEDUP_SCAN slots: sorted and made unique at the end
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
                if dx * dx + dyz > r2:
                    continue
                s = _slot(ix, iy, iz, dense, nx, ny, nz, shift)
                if s < 0:
                    continue
                if not dense and not unchecked:
                    seen = False
                    for i in range(n):
                        if buf[i] == s:
                            seen = True
                            break
                    if seen:
                        continue
                buf[n] = s
                n += 1
                if n >= _DEDUP_SCAN:
                    unchecked = True
    if unchecked and not dense:
        srt = np.sort(buf[:n])
        m = 0
        for i in range(n):
            if i == 0 or srt[i] != srt[i - 1]:
                buf[m] = srt[i]
                m += 1
        n = m
    return n


@njit(cache=True)
def _count_cells(k0, k1, pos, R_ins, active, origin, h, inv_h, dense, nx, ny, nz, shift, split,
                 n_ent, n_low, cap):
    """n_ent[v] = number of slots VP v is stored in, n_low[v] = how many of
    them are below split, for VPs k0..k1-1; cap: the largest bounding-box
    cell count of a VP."""
    buf = np.empty(cap, np.int64)
    for v in range(k0, k1):
        n = 0
        lo = 0
        if active[v]:
            n = _vp_cells(v, pos, R_ins, origin, h, inv_h, dense, nx, ny, nz, shift, buf)
            for i in range(n):
                lo += buf[i] < split
        n_ent[v] = n
        n_low[v] = lo


@njit(cache=True)
def _fill_cells(k0, k1, pos, R_ins, active, origin, h, inv_h, dense, nx, ny, nz, shift, split,
                off, low, E0, ent_slot, cap):
    """The slots of VP v, for VPs k0..k1-1, in the two halves of ent_slot:
    those below split at ent_slot[low[v]:low[v + 1]], the others at
    ent_slot[E0 + off[v] - low[v]:E0 + off[v + 1] - low[v + 1]]."""
    buf = np.empty(cap, np.int64)
    for v in range(k0, k1):
        if active[v]:
            n = _vp_cells(v, pos, R_ins, origin, h, inv_h, dense, nx, ny, nz, shift, buf)
            a = low[v]
            b = E0 + off[v] - low[v]
            for i in range(n):
                s = buf[i]
                if s < split:
                    ent_slot[a] = s
                    a += 1
                else:
                    ent_slot[b] = s
                    b += 1


@njit(cache=True, inline="always")
def _part_range(g, v, off, low, E0):
    """The entries of VP v in part g (0: slots below the split, 1: the others)."""
    if g == 0:
        return low[v], low[v + 1]
    return E0 + off[v] - low[v], E0 + off[v + 1] - low[v + 1]


@njit(cache=True)
def _part_counts(g, s0, s1, K, off, low, E0, ent_slot, cell_start):
    """cell_start[s + 1] = the number of part g's entries in slot s, for the
    slots s0..s1-1 (zeroed here: by the thread that counts, page faults
    included); returns their total."""
    cell_start[s0 + 1:s1 + 1] = 0
    e0, e1 = (0, low[K]) if g == 0 else (E0, off[K])
    t = 0
    for e in range(e0, e1):
        s = ent_slot[e]
        if s >= s0 and s < s1:
            cell_start[s + 1] += 1
            t += 1
    return t


@njit(cache=True)
def _slot_cursors(s0, s1, run, cell_start):
    """Counts to write cursors for slots s0..s1-1, run = the entries of the
    slots before s0: cell_start[s + 1] = the start of slot s, which the fill
    advances to the start of slot s + 1."""
    for s in range(s0, s1):
        n = cell_start[s + 1]
        cell_start[s + 1] = run
        run += n


@njit(cache=True)
def _part_fill(g, s0, s1, K, off, low, E0, ent_slot, cell_start, vp_ids):
    """vp_ids[cell_start[s + 1]++] = v for part g's entries (v, s) with s in
    s0..s1-1, in VP order (so the VPs of a slot are ascending)."""
    for v in range(K):
        a, b = _part_range(g, v, off, low, E0)
        for e in range(a, b):
            s = ent_slot[e]
            if s >= s0 and s < s1:
                q = cell_start[s + 1]
                vp_ids[q] = v
                cell_start[s + 1] = q + 1


@njit(cache=True, parallel=True)
def _insert_parallel(n_chunks, pos, R_ins, active, origin, h, inv_h, dense, nx, ny, nz, shift,
                     n_slots, split, cap, off, low, ent_slot, cell_start, vp_ids):
    """The CSR arrays of the grid, by n_chunks threads, into the caller's
    arrays: cell_start (n_slots + 1,) and vp_ids (room for the entries,
    int32, the VPs of a slot ascending); returns the number of entries E.
    off, low (K + 1,) int64 and ent_slot (room for E) are the build's
    temporaries.  Each VP's slots (VP ranges in parallel) go to one of two
    parts, the slots below split and the others (SORT_GROUPS = 2 parts
    with about E / 2 entries each); each part is counting-sorted by slot on
    its own, in place in cell_start (its slot range is its own), split by
    slot ranges when there are more threads than parts.  No (n_slots,) row
    of cursors, no mark array: a VP's hash collisions are removed from its
    own list."""
    K = pos.shape[0]
    off[0] = 0
    low[0] = 0
    for c in prange(n_chunks):
        _count_cells(c * K // n_chunks, (c + 1) * K // n_chunks, pos, R_ins, active, origin,
                     h, inv_h, dense, nx, ny, nz, shift, split, off[1:], low[1:], cap)
    for v in range(K):
        off[v + 1] += off[v]
        low[v + 1] += low[v]
    E = off[K]
    E0 = low[K]
    for c in prange(n_chunks):
        _fill_cells(c * K // n_chunks, (c + 1) * K // n_chunks, pos, R_ins, active, origin,
                    h, inv_h, dense, nx, ny, nz, shift, split, off, low, E0, ent_slot, cap)
    # Task t = (g, j): part g's slots [split_g, split_g+1), slot range j of S.
    G = min(n_chunks, SORT_GROUPS)
    S = n_chunks // G
    bounds = np.empty(G + 1, np.int64)
    bounds[0] = 0
    bounds[G] = n_slots
    if G > 1:
        bounds[1] = split
    cell_start[0] = 0
    tot = np.zeros(G * S + 1, np.int64)
    for t in prange(G * S):
        g, j = t // S, t % S
        a, b = bounds[g], bounds[g + 1]
        tot[t + 1] = _part_counts(g, a + j * (b - a) // S, a + (j + 1) * (b - a) // S, K, off,
                                  low, E0, ent_slot, cell_start)
    for t in range(G * S):
        tot[t + 1] += tot[t]
    for t in prange(G * S):
        g, j = t // S, t % S
        a, b = bounds[g], bounds[g + 1]
        _slot_cursors(a + j * (b - a) // S, a + (j + 1) * (b - a) // S, tot[t], cell_start)
    for t in prange(G * S):
        g, j = t // S, t % S
        a, b = bounds[g], bounds[g + 1]
        _part_fill(g, a + j * (b - a) // S, a + (j + 1) * (b - a) // S, K, off, low, E0,
                   ent_slot, cell_start, vp_ids)
    return E


@njit(cache=True)
def _insert_one_pass(pos, R_ins, active, origin, h, inv_h, dense, nx, ny, nz, shift, n_slots,
                     cap, off, ent_slot, cell_start, vp_ids):
    """_insert_parallel's grid on one thread (build_grid below
    PARALLEL_MIN_VPS VPs), each VP's cells found once:
    with one part nothing needs a VP's entry count before its entries are
    written (ent_slot has room for the bounding-box bound), so the slots
    are appended in VP order and counted as they are written, then
    counting-sorted by slot as there.  The same cell_start and vp_ids (the
    VPs of a slot ascending); returns E.  off (K + 1,) int64: each VP's
    first entry.  _insert_parallel on one chunk finds every VP's cells
    twice (count, then fill), twice the time."""
    K = pos.shape[0]
    buf = np.empty(cap, np.int64)
    cell_start[:] = 0
    e = 0
    off[0] = 0
    for v in range(K):
        if active[v]:
            n = _vp_cells(v, pos, R_ins, origin, h, inv_h, dense, nx, ny, nz, shift, buf)
            for i in range(n):
                s = buf[i]
                ent_slot[e] = s
                cell_start[s + 1] += 1
                e += 1
        off[v + 1] = e
    # int64 zeros, not literals: a literal argument is a signature of its
    # own, and the threaded path's calls pass int64 (one compile a kernel,
    # core.materials.compiled.eval_pair_as)
    _slot_cursors(np.int64(0), n_slots, np.int64(0), cell_start)
    for v in range(K):
        for j in range(off[v], off[v + 1]):
            s = ent_slot[j]
            q = cell_start[s + 1]
            vp_ids[q] = v
            cell_start[s + 1] = q + 1
    return e


@njit(cache=True)
def _centre_hist(k0, k1, pos, act, origin, inv_h, dense, nx, ny, nz, shift, n_slots, hist):
    """hist[b] += 1 for the active VPs k0..k1-1 whose centre's slot s is in
    bin b = s * hist.size // n_slots."""
    nb = hist.shape[0]
    for v in range(k0, k1):
        if act[v]:
            s = _slot(np.int64(math.floor((pos[v, 0] - origin[0]) * inv_h)),
                      np.int64(math.floor((pos[v, 1] - origin[1]) * inv_h)),
                      np.int64(math.floor((pos[v, 2] - origin[2]) * inv_h)),
                      dense, nx, ny, nz, shift)
            if s >= 0:
                hist[s * nb // n_slots] += 1


@njit(cache=True, parallel=True)
def _part_split(n_chunks, pos, act, origin, inv_h, dense, nx, ny, nz, shift, n_slots):
    """The slot below which about half of the active VPs' centres lie (a bin
    boundary of a 4096-bin histogram of their slots), so that the build's
    two parts hold about half of the entries each: a hash spreads them
    evenly, but a dense grid's slots follow z (a floor and a lamp far above
    it would leave one part nearly empty)."""
    K = pos.shape[0]
    nb = min(4096, n_slots)
    hist = np.zeros((n_chunks, nb), np.int64)
    for c in prange(n_chunks):
        _centre_hist(c * K // n_chunks, (c + 1) * K // n_chunks, pos, act, origin, inv_h,
                     dense, nx, ny, nz, shift, n_slots, hist[c])
    tot = hist.sum(axis=0)
    half = tot.sum() // 2
    run = 0
    for b in range(nb):
        run += tot[b]
        if run >= half:
            return -(-(b + 1) * n_slots // nb)
    return n_slots


@njit(cache=True)
def _photon_slots(p0, p1, ph_pos, origin, inv_h, lo, hi, dense, nx, ny, nz, shift,
                  cell_start, ps):
    """ps[p] = slot of photon p, or -1 outside the grid / in an empty slot."""
    # Scalars hoisted and a branch-free bounds test: passing the arrays to a
    # helper per photon was measured 10x slower than the loop body itself.
    lx, ly, lz, hx, hy, hz = lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    ox, oy, oz = origin[0], origin[1], origin[2]
    for p in range(p0, p1):
        x = np.float64(ph_pos[p, 0])
        y = np.float64(ph_pos[p, 1])
        z = np.float64(ph_pos[p, 2])
        # False for NaN too: non-finite photons are never counted.
        inside = (x >= lx) & (x <= hx) & (y >= ly) & (y <= hy) & (z >= lz) & (z <= hz)
        s = -1
        if inside:
            s = _slot(np.int64(math.floor((x - ox) * inv_h)),
                      np.int64(math.floor((y - oy) * inv_h)),
                      np.int64(math.floor((z - oz) * inv_h)), dense, nx, ny, nz, shift)
            if s >= 0 and cell_start[s + 1] == cell_start[s]:
                s = -1
        ps[p] = s


@njit(cache=True)
def _slot_starts(ps, n_slots):
    """Counting-sort prefix: start[s] = number of photons in slots < s."""
    start = np.zeros(n_slots + 1, np.int64)
    for p in range(ps.shape[0]):
        if ps[p] >= 0:
            start[ps[p] + 1] += 1
    for s in range(n_slots):
        start[s + 1] += start[s]
    return start


@njit(cache=True)
def _scatter(s0, s1, ps, cursor, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
             order, slot, pos, ng, wi, power, rpred):
    """Copy the photons of slots s0..s1-1 to their sorted places (stable: by
    photon index within a slot).  Threads own disjoint slot ranges, hence
    disjoint cursor entries and output rows."""
    for p in range(ps.shape[0]):
        s = ps[p]
        if s >= s0 and s < s1:
            q = cursor[s]
            cursor[s] = q + 1
            order[q] = p
            _copy_photon(q, p, s, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                         slot, pos, ng, wi, power, rpred)


@njit(cache=True, inline="always")
def _copy_photon(q, p, s, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                 slot, pos, ng, wi, power, rpred):
    """Row q of the sorted arrays = photon p's, in slot s."""
    slot[q] = s
    for k in range(3):
        pos[q, k] = ph_pos[p, k]
        ng[q, k] = ph_ng[p, k]
        wi[q, k] = ph_wi[p, k]
        power[q, k] = ph_power[p, k]
    rpred[q] = ph_rpred[p]


@njit(cache=True)
def _copy_sorted(q0, q1, order, ps, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                 slot, pos, ng, wi, power, rpred):
    """Row q of the sorted arrays = photon order[q]'s, for q0..q1-1."""
    for q in range(q0, q1):
        p = order[q]
        _copy_photon(q, p, ps[p], ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                     slot, pos, ng, wi, power, rpred)


@njit(cache=True)
def _merge_runs(key, src, a0, a1, b1, dst):
    """dst[a0:b1] = the runs src[a0:a1] and src[a1:b1] (indices into key, each
    sorted by key) merged stably: on equal keys the first run's index first."""
    i, j = a0, a1
    for k in range(a0, b1):
        if j >= b1 or (i < a1 and key[src[i]] <= key[src[j]]):
            dst[k] = src[i]
            i += 1
        else:
            dst[k] = src[j]
            j += 1


@njit(cache=True)
def _argsort_run(key, q0, q1, out):
    """out[q0:q1] = the indices q0..q1-1 stably sorted by key (one run)."""
    out[q0:q1] = np.argsort(key[q0:q1], kind="mergesort") + q0


@njit(cache=True)
def _merge_sorted_runs(key, a, T):
    """np.argsort(key, kind="mergesort") from a (n,): T consecutive runs
    (run c = indices c n / T .. (c + 1) n / T - 1) each sorted by
    :func:`_argsort_run`, merged pairwise (a stable merge of the stable runs
    of consecutive ranges is the stable sort).  a may be overwritten."""
    n = key.shape[0]
    b = np.empty(n, np.int64) if T > 1 else a
    width = 1                           # runs of width chunks are sorted
    while width < T:
        for c0 in range(0, T, 2 * width):
            c1, c2 = min(c0 + width, T), min(c0 + 2 * width, T)
            _merge_runs(key, a, c0 * n // T, c1 * n // T, c2 * n // T, b)
        a, b = b, a
        width *= 2
    return a


@njit(cache=True, parallel=True)
def _sort_photons(ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                  origin, inv_h, lo, hi, dense, nx, ny, nz, shift, cell_start, n_chunks,
                  ps, order, slot, pos, ng, wi, power, rpred):
    """Stable sort of the photons by slot, copying their data into sorted,
    contiguous arrays.  Consecutive photons then share their candidate VPs and
    read memory sequentially: measured 2.5x faster than photon order (VP
    records missing the cache) or sorted indices (photon data missing it).
    Photons outside the grid or in an empty slot are dropped.  n_chunks
    threads (1 = serial); the result does not depend on n_chunks.
    A counting sort when the table has at most COUNT_SORT_SLOTS_PER_PHOTON
    slots a photon, else a merge sort of the photons' slots: a counting
    sort's (n_slots + 1,) int64 starts were 256 MiB for the 2^25 slots of a
    1080p pass, allocated, zeroed and scanned on one thread for every chunk
    of 131,072 photons.  Both order a slot's photons by index: the same
    result.
    Writes order (n,) int32 original photon index, slot (n,) int64, and the
    sorted pos, ng, wi, power (n, 3), rpred (n,) into the first n rows of
    the caller's arrays of P rows (column views of one record array there,
    or arrays of their own; ps (P,) int64: the photons' slots), and returns
    n (:func:`_sorted_photons`)."""
    P = ph_pos.shape[0]
    n_slots = cell_start.shape[0] - 1
    for c in prange(n_chunks):
        _photon_slots(c * P // n_chunks, (c + 1) * P // n_chunks, ph_pos, origin, inv_h,
                      lo, hi, dense, nx, ny, nz, shift, cell_start, ps)
    counting = n_slots <= COUNT_SORT_SLOTS_PER_PHOTON * P
    if counting:
        start = _slot_starts(ps, n_slots)
        n = start[n_slots]
    else:
        start = np.empty(0, np.int64)
        n = 0
        for p in range(P):
            n += ps[p] >= 0
    if counting:
        # Slot ranges holding ~n / n_chunks photons each.
        bounds = np.empty(n_chunks + 1, np.int64)
        for c in range(n_chunks + 1):
            bounds[c] = np.searchsorted(start, c * n // n_chunks)
        bounds[n_chunks] = n_slots
        for c in prange(n_chunks):
            _scatter(bounds[c], bounds[c + 1], ps, start, ph_pos, ph_ng, ph_wi, ph_power,
                     ph_rpred, order, slot, pos, ng, wi, power, rpred)
        return n
    inside = np.empty(n, np.int32)        # the photons in a slot, in index order
    key = np.empty(n, np.int64)
    j = 0
    for p in range(P):
        if ps[p] >= 0:
            inside[j] = p
            key[j] = ps[p]
            j += 1
    # Stable by slot: runs sorted in the threads (the serial merge sort was
    # ~20 ms of one thread a 131,072-photon chunk), then merged.
    T = max(1, min(n_chunks, n))
    by_slot = np.empty(n, np.int64)
    for c in prange(T):
        _argsort_run(key, c * n // T, (c + 1) * n // T, by_slot)
    by_slot = _merge_sorted_runs(key, by_slot, T)
    for q in range(n):
        order[q] = inside[by_slot[q]]
    for c in prange(n_chunks):
        _copy_sorted(c * n // n_chunks, (c + 1) * n // n_chunks, order, ps, ph_pos, ph_ng,
                     ph_wi, ph_power, ph_rpred, slot, pos, ng, wi, power, rpred)
    return n


def _sorted_photons(sort, ph, grid: Grid, n_chunks: int, kept: Optional[KeptBuffers] = None):
    """The photons ph = (pos, ng, wi, power, rpred) sorted by slot of grid
    (sort: _sort_photons or its serial twin): (order, slot, pos, ng, wi,
    power, rpred) of the n photons kept (see _sort_photons), and hitmask
    (n,) uint64, n_pair, n_freq (n,) int32 uninitialised for the count
    pass.  pos, ng, wi (n, 3), power (n, 3) and rpred (n,) are float64
    column views of one (P, PHOTON_RECORD) array, a row a photon: the sort
    writes each photon it places to one row instead of five arrays
    (docs/architecture.md "The gather's sector cells, round 21"); float32
    geometry is widened exactly, as the count pass reads it.  kept: carve
    them from its buffer "gather_sort" (reused from chunk to chunk: no page
    faults), else new arrays."""
    P = ph[0].shape[0]
    specs = [((P,), np.int64), ((P,), np.int32), ((P,), np.int64),
             ((P, PHOTON_RECORD), np.float64),
             ((P,), np.uint64), ((P,), np.int32), ((P,), np.int32)]
    bufs = (kept.take("gather_sort", specs) if kept is not None
            else [np.empty(shape, d) for shape, d in specs])
    ps, order, slot, rec = bufs[:4]
    cols = (rec[:, 0:3], rec[:, 3:6], rec[:, 6:9], rec[:, 9:12], rec[:, 12])
    n = int(sort(*ph, grid.origin, grid.inv_h, grid.lo, grid.hi, grid.dense,
                 int(grid.dims[0]), int(grid.dims[1]), int(grid.dims[2]),
                 0 if grid.dense else 64 - grid.log2_table, grid.cell_start, n_chunks,
                 ps, order, slot, *cols))
    return tuple(b[:n] for b in (order, slot, *cols, *bufs[4:]))


#: The same sort compiled without ``parallel``: a numba parallel region costs a
#: thread hand-off even for n_chunks = 1, ~10 ms per call on a loaded 2-core
#: machine (10,000 small passes took 137 s instead of ~15 s).
_sort_photons_serial = serial_twin(_sort_photons)


@njit(cache=True, inline="always")
def _vp_record(vp_rec, v):
    """Visible point v's record as scalars (x, y, z, R^2, nx, ny, nz, const).
    Candidates are tested on scalars (_accepts, _sector_cell) rather than on
    the arrays: an inlined helper that takes an array and returns from
    several branches kept numba's reference-count increment and decrement
    of the array at every call (two atomic operations a candidate, on a
    counter both gather threads share); LLVM's pruning removes the pair
    only when it sits in one straight block, as here (no branch: the
    caller reads the packed clip itself; docs/architecture.md "The count
    pass without reference counts")."""
    return (vp_rec[v, 0], vp_rec[v, 1], vp_rec[v, 2], vp_rec[v, 3], vp_rec[v, 4],
            vp_rec[v, 5], vp_rec[v, 6], vp_rec[v, 7])


@njit(cache=True, inline="always")
def _accepts(rx, ry, rz, r2, nvx, nvy, nvz, code, x, y, z, wx, wy, wz, gx, gy, gz, cos_ng):
    """Gather rules (1)-(5) of the module docstring for photon (x, w, g) and
    the visible point (r, r2, nv) of _vp_record: the one place they are
    written (count and pair passes; rules (2)-(5) in _accepts_near).  code:
    its packed clip, CLIP_CLEAR for no rule (5)."""
    dx = x - rx
    dy = y - ry
    dz = z - rz
    if not (dx * dx + dy * dy + dz * dz < r2):                              # (1)
        return False
    return _accepts_near(dx, dy, dz, r2, nvx, nvy, nvz, code, wx, wy, wz, gx, gy, gz, cos_ng)


@njit(cache=True, inline="always")
def _accepts_near(dx, dy, dz, r2, nvx, nvy, nvz, code, wx, wy, wz, gx, gy, gz, cos_ng):
    """Rules (2)-(5) of _accepts for a photon at offset (dx, dy, dz) from
    the visible point, rule (1) (dx^2 + dy^2 + dz^2 < r2) already passed."""
    if not (wx * nvx + wy * nvy + wz * nvz > 0.0):                          # (2)
        return False
    cg = gx * nvx + gy * nvy + gz * nvz
    if not (cg > cos_ng):                                                   # (3)
        return False
    if cg <= COS_NG_DEFAULT and dx * nvx + dy * nvy + dz * nvz < 0.0:       # (4)
        return False
    if code != CLIP_CLEAR:                                                  # (5)
        t0, t1, t2, t3, t4, t5 = _tangent_frame(nvx, nvy, nvz)
        u = dx * t0 + dy * t1 + dz * t2
        w = dx * t3 + dy * t4 + dz * t5
        b = np.int64((code >> np.uint64(8 * wedge_of(u, w))) & np.uint64(0xFF))
        if b < CLIP_OPEN and 65025.0 * (u * u + w * w) >= np.float64(b * b) * r2:
            return False
    return True


@intrinsic
def _trailing_zeros(typingctx, x):
    """The index of the lowest set bit of the uint64 x (x != 0): LLVM's
    llvm.cttz (one tzcnt / bsf instruction on x86-64)."""
    sig = types.int64(types.uint64)

    def codegen(context, builder, signature, args):
        return builder.cttz(args[0], ir.Constant(ir.IntType(1), 1))
    return sig, codegen


@njit(cache=True, inline="always")
def wedge_of(u, w):
    """Wedge (0 .. CLIP_WEDGES-1) of a tangent-plane offset (u, w): angle
    atan2(w, u) in [k, k + 1) * 45 degrees; wedges 2q and 2q + 1 make up
    quadrant q of _sector_cell."""
    q = 0
    if u < 0.0:
        q = 1 if w >= 0.0 else 2
    elif w < 0.0:
        q = 3
    if q % 2 == 0:
        return 2 * q + (1 if abs(w) >= abs(u) else 0)
    return 2 * q + (1 if abs(u) >= abs(w) else 0)


@njit(cache=True, inline="always")
def wedge_rho2(code, k):
    """(d_k / R)^2 of wedge k of a packed clip (1 when open)."""
    b = np.int64((code >> np.uint64(8 * k)) & np.uint64(0xFF))
    if b >= CLIP_OPEN:
        return 1.0
    x = b / 255.0
    return x * x


@njit(cache=True)
def clip_weights(code, W_cells):
    """The fold's weights of a clipped visible point (code != CLIP_CLEAR):
    returns 1 / max(f, CLIP_MIN_FRACTION) (f: the visible fraction of the
    disc, module docstring) and fills W_cells (SECTOR_CELLS, SECTOR_CELLS):
    the pass's sector counts S become W_cells @ S, a full disc's.

    Cell c (quadrant q = c % 4 holds wedges 2q, 2q + 1; inner ring
    |d| < R / sqrt 2 for c < 4) has the visible fraction a_c of its area;
    with a_c >= CLIP_CELL_MIN its count is divided by a_c (a full cell's
    expected count where the light is uniform), else it reads the mean of
    the scaled cells (too little of it is visible to test), or M / f / 8
    when no cell is: so a wall does not look like a non-uniform disc to the
    chi-square tests of core.sppm.update (the visible part still does)."""
    f = 0.0
    a = np.zeros(SECTOR_CELLS)
    for k in range(CLIP_WEDGES):
        r2 = wedge_rho2(code, k)
        f += r2
        q = k // 2
        # each wedge is half of its quadrant's two cells (areas 1/2 of R^2
        # in the ring's units: inner r^2 < 1/2, outer 1/2 <= r^2 < 1)
        a[q] += min(r2, 0.5)                      # / 0.5 area, * 1/2 wedge
        a[q + SECTOR_QUADRANTS] += max(r2 - 0.5, 0.0)
    f /= CLIP_WEDGES
    inv_f = 1.0 / max(f, CLIP_MIN_FRACTION)
    W_cells[:, :] = 0.0
    n_good = 0
    for c in range(SECTOR_CELLS):
        if a[c] >= CLIP_CELL_MIN:
            n_good += 1
    for c in range(SECTOR_CELLS):
        if a[c] >= CLIP_CELL_MIN:
            W_cells[c, c] = 1.0 / a[c]
        elif n_good > 0:
            for j in range(SECTOR_CELLS):
                if a[j] >= CLIP_CELL_MIN:
                    W_cells[c, j] = 1.0 / (a[j] * n_good)
        else:
            for j in range(SECTOR_CELLS):
                W_cells[c, j] = inv_f / SECTOR_CELLS
    return inv_f


@njit(cache=True, inline="always")
def _tangent_frame(n0, n1, n2):
    """(t1, t2) as 6 floats: an orthonormal tangent frame of the unit normal
    (n0, n1, n2), continuous except across n2 = 0 (Duff et al. 2017,
    "Building an orthonormal basis, revisited"); the same normal always gets
    the same frame, so sector counts of a pixel add up across passes.
    Computed per counted photon from the VP's record instead of a stored
    (K, 6) array (48 B a pixel during the photons)."""
    sign = 1.0 if n2 >= 0.0 else -1.0
    a = -1.0 / (sign + n2)
    b = n0 * n1 * a
    return (1.0 + sign * n0 * n0 * a, sign * b, -sign * n0,
            b, sign + n1 * n1 * a, -n1)


@njit(cache=True, inline="always")
def _sector_cell(rx, ry, rz, r2, nvx, nvy, nvz, x, y, z):
    """Sector cell (0 .. SECTOR_CELLS-1) of a counted photon at (x, y, z) in
    the kernel of the visible point (r, r2, nv) of _vp_record: quadrant of
    its offset in the tangent frame (t1, t2) of its normal (_tangent_frame),
    plus SECTOR_QUADRANTS for the outer ring (|d|^2 >= R^2 / 2).  The
    SECTOR_CELLS cells have equal areas on the disc."""
    dx = x - rx
    dy = y - ry
    dz = z - rz
    t0, t1, t2, t3, t4, t5 = _tangent_frame(nvx, nvy, nvz)
    u = dx * t0 + dy * t1 + dz * t2
    w = dx * t3 + dy * t4 + dz * t5
    return _sector_of(u, w, dx * dx + dy * dy + dz * dz, r2)


@njit(cache=True, inline="always")
def _sector_of(u, w, d2, r2):
    """_sector_cell's cell of the tangent-plane offset (u, w) at squared
    distance d2 from the centre of a disc of radius^2 r2: quadrant 0 (u >=
    0, w >= 0), 1 (u < 0, w >= 0), 2 (u < 0, w < 0) or 3 (u >= 0, w < 0),
    plus SECTOR_QUADRANTS when 2 d2 >= r2.  In arithmetic, not branches:
    a counted photon's signs are random, and the branches on them were
    mispredicted about every other photon (docs/architecture.md "The
    gather's sector cells, round 21").  A NaN w reads as the branches read
    it: quadrant 2 when u < 0, else 0 (tests/test_hashgrid.py)."""
    left = np.int64(u < 0.0)
    c = left * (1 + np.int64(not (w >= 0.0))) + (1 - left) * 3 * np.int64(w < 0.0)
    return c + SECTOR_QUADRANTS * np.int64(2.0 * d2 >= r2)


@njit(cache=True)
def _count_range(q0, q1, slot, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                 vp_rec, vp_clip, cos_ng, cell_start, vp_ids,
                 M, Phi, rmin, hitmask, n_pair, n_freq, S, touched, n_touched, run_min):
    """Sorted photons q0..q1-1 (ph_* already in sorted order): accumulate M,
    Phi (const VPs), rmin into this chunk's arrays, and (S with SECTOR_CELLS
    columns, else 0 columns) each counted photon's sector cell into S.  n_pair[q] / n_freq[q] =
    number of non-const / frequency pairs of the photon; hitmask[q] bit j =
    entry cell_start[s] + j counted (cells of <= 64 entries), so the pair pass
    need not redo the tests.  touched (K,) int32 (size 0: not recorded): each
    VP whose M goes from 0 to 1 is appended at n_touched[0] (GatherBuffers).

    By runs of run_min to 64 photons in one slot (_run_min), candidate by
    candidate (shorter runs photon by photon, in the same arithmetic): rule
    (1), the distance, is evaluated for the whole run without a branch into
    a bit mask (bit j: photon a + j within the radius), and only its set
    bits go on to rules (2)-(5) and the sums (the run's positions are
    copied to float64 columns xs, ys, zs first, so that the distance loop
    runs in SIMD lanes).  Photon by photon, rule (1) was a branch taken about
    one time in three at random, mispredicted at most candidates
    (docs/architecture.md "The count pass by runs of a slot, round 14").
    A candidate's sums stay in registers over the run (its sector counts
    as 8 byte-wide counters of one uint64):
    Phi[v] still receives the photons' powers one by one in photon order
    (the local sum starts from Phi[v]), rmin is a minimum, M and S are
    counts, so the outputs are the same bits as testing photon by photon
    (tests/test_count_runs.py); only the touched list's order differs (the
    fold does not depend on it)."""
    one = np.uint64(1)
    with_sectors = S.shape[1] > 0
    track = touched.shape[0] > 0
    clipped = vp_clip.shape[0] > 0
    xs = np.empty(64)
    ys = np.empty(64)
    zs = np.empty(64)
    a = q0
    while a < q1:
        s = slot[a]
        b = a + 1
        while b < q1 and b - a < 64 and slot[b] == s:
            b += 1
        L = b - a
        if L < run_min:
            # a short run (1080p: ~0.3 deposits a slot): photon by photon,
            # the mask's set-up would cost more than its branches save
            for p in range(a, b):
                x = np.float64(ph_pos[p, 0])
                y = np.float64(ph_pos[p, 1])
                z = np.float64(ph_pos[p, 2])
                r = ph_rpred[p]
                is_freq = not math.isnan(r)
                npair = 0
                nfreq = 0
                mask = np.uint64(0)
                for e in range(cell_start[s], cell_start[s + 1]):
                    v = vp_ids[e]
                    rx, ry, rz, r2, nvx, nvy, nvz, const = _vp_record(vp_rec, v)
                    code = vp_clip[v] if clipped else CLIP_CLEAR
                    if not _accepts(rx, ry, rz, r2, nvx, nvy, nvz, code, x, y, z,
                                    np.float64(ph_wi[p, 0]), np.float64(ph_wi[p, 1]),
                                    np.float64(ph_wi[p, 2]), np.float64(ph_ng[p, 0]),
                                    np.float64(ph_ng[p, 1]), np.float64(ph_ng[p, 2]), cos_ng):
                        continue
                    M[v] += 1
                    if track and M[v] == 1:
                        touched[n_touched[0]] = v
                        n_touched[0] += 1
                    if with_sectors:
                        S[v, _sector_cell(rx, ry, rz, r2, nvx, nvy, nvz, x, y, z)] += 1
                    if const != 0.0:
                        Phi[v, 0] += ph_power[p, 0]
                        Phi[v, 1] += ph_power[p, 1]
                        Phi[v, 2] += ph_power[p, 2]
                    else:
                        npair += 1
                    if is_freq:
                        nfreq += 1
                        if r < rmin[v]:
                            rmin[v] = r
                    if e - cell_start[s] < 64:
                        mask |= one << np.uint64(e - cell_start[s])
                hitmask[p] = mask
                n_pair[p] = npair
                n_freq[p] = nfreq
            a = b
            continue
        for q in range(a, b):
            xs[q - a] = np.float64(ph_pos[q, 0])
            ys[q - a] = np.float64(ph_pos[q, 1])
            zs[q - a] = np.float64(ph_pos[q, 2])
            hitmask[q] = np.uint64(0)
            n_pair[q] = 0
            n_freq[q] = 0
        e0 = cell_start[s]
        e1 = cell_start[s + 1]
        for e in range(e0, e1):
            v = vp_ids[e]
            rx, ry, rz, r2, nvx, nvy, nvz, const = _vp_record(vp_rec, v)
            near = np.uint64(0)
            for j in range(L):                                             # (1)
                dx = xs[j] - rx
                dy = ys[j] - ry
                dz = zs[j] - rz
                near |= np.uint64(dx * dx + dy * dy + dz * dz < r2) << np.uint64(j)
            if near == 0:
                continue
            code = vp_clip[v] if clipped else CLIP_CLEAR
            bit = one << np.uint64(e - e0) if e - e0 < 64 else np.uint64(0)
            m = 0
            p0 = 0.0
            p1 = 0.0
            p2 = 0.0
            rl = np.inf
            # The run's sector counts, one byte a cell (a run has at most 64
            # photons), added to the candidate's row of S once, as M is: S
            # is not read and written at every counted photon
            # (docs/architecture.md "The gather's sector cells, round 21").
            cells = np.uint64(0)
            while near != 0:
                q = a + _trailing_zeros(near)
                near &= near - one
                x = np.float64(ph_pos[q, 0])
                y = np.float64(ph_pos[q, 1])
                z = np.float64(ph_pos[q, 2])
                if not _accepts_near(x - rx, y - ry, z - rz, r2, nvx, nvy, nvz, code,
                                     np.float64(ph_wi[q, 0]), np.float64(ph_wi[q, 1]),
                                     np.float64(ph_wi[q, 2]), np.float64(ph_ng[q, 0]),
                                     np.float64(ph_ng[q, 1]), np.float64(ph_ng[q, 2]), cos_ng):
                    continue
                if m == 0:
                    # the first photon of the run counted here: the sums so far
                    p0, p1, p2 = Phi[v, 0], Phi[v, 1], Phi[v, 2]
                m += 1
                if with_sectors:
                    cells += one << np.uint64(8 * _sector_cell(rx, ry, rz, r2, nvx, nvy, nvz,
                                                               x, y, z))
                if const != 0.0:
                    p0 += ph_power[q, 0]
                    p1 += ph_power[q, 1]
                    p2 += ph_power[q, 2]
                else:
                    n_pair[q] += 1
                # Without a branch: frequency and classic deposits are mixed
                # at random in a slot, so "is r a number" was mispredicted
                # at a large share of the counted pairs in a frequency pass.
                # NaN == NaN is False and NaN < rl is False: a classic
                # deposit adds 0 and leaves rl (the same values as the branch).
                r = ph_rpred[q]
                n_freq[q] += np.int32(r == r)
                rl = r if r < rl else rl
                hitmask[q] |= bit
            if m == 0:
                continue
            if track and M[v] == 0:
                touched[n_touched[0]] = v
                n_touched[0] += 1
            M[v] += m
            if with_sectors:
                for k in range(SECTOR_CELLS):
                    S[v, k] += np.int64((cells >> np.uint64(8 * k)) & np.uint64(0xFF))
            if const != 0.0:
                Phi[v, 0] = p0
                Phi[v, 1] = p1
                Phi[v, 2] = p2
            if rl < rmin[v]:
                rmin[v] = rl
        a = b


@njit(cache=True)
def _record_pair(v, p, is_freq, vp_rec, k, kf, pair_vp, pair_ph, fpair_vp, fpair_ph):
    """Write the accepted (visible point v, photon p) pair at k when v's BSDF is
    evaluated per pair (vp_rec[v, 7] == 0: not Lambert-only), and at kf when p
    is a frequency photon; returns the next (k, kf)."""
    if vp_rec[v, 7] == 0.0:
        pair_vp[k] = v
        pair_ph[k] = p
        k += 1
    if is_freq:
        fpair_vp[kf] = v
        fpair_ph[kf] = p
        kf += 1
    return k, kf


@njit(cache=True)
def _pairs_range(q0, q1, order, slot, ph_pos, ph_ng, ph_wi, ph_rpred,
                 vp_rec, vp_clip, cos_ng, cell_start, vp_ids, hitmask,
                 n_pair, pair_off, pair_vp, pair_ph,
                 n_freq, freq_off, fpair_vp, fpair_ph, want_freq):
    """Second pass over photons with pairs: the counted entries come from
    hitmask, or (cells of > 64 entries) from the same tests as _count_range in
    the same arithmetic; pairs are written at the photon's prefix-sum offset."""
    one = np.uint64(1)
    clipped = vp_clip.shape[0] > 0
    for q in range(q0, q1):
        if n_pair[q] == 0 and not (want_freq and n_freq[q] > 0):
            continue
        p = order[q]           # original photon index (for pair_ph)
        s = slot[q]
        e0 = cell_start[s]
        e1 = cell_start[s + 1]
        r = ph_rpred[q]
        is_freq = want_freq and not math.isnan(r)
        k = pair_off[q]
        kf = freq_off[q]
        if e1 - e0 <= 64:
            mask = hitmask[q]
            for j in range(e1 - e0):
                if (mask >> np.uint64(j)) & one:
                    k, kf = _record_pair(vp_ids[e0 + j], p, is_freq, vp_rec, k, kf,
                                         pair_vp, pair_ph, fpair_vp, fpair_ph)
            continue
        x = np.float64(ph_pos[q, 0])
        y = np.float64(ph_pos[q, 1])
        z = np.float64(ph_pos[q, 2])
        wx = np.float64(ph_wi[q, 0])
        wy = np.float64(ph_wi[q, 1])
        wz = np.float64(ph_wi[q, 2])
        gx = np.float64(ph_ng[q, 0])
        gy = np.float64(ph_ng[q, 1])
        gz = np.float64(ph_ng[q, 2])
        for e in range(e0, e1):
            v = vp_ids[e]
            rx, ry, rz, r2, nvx, nvy, nvz, const = _vp_record(vp_rec, v)
            code = vp_clip[v] if clipped else CLIP_CLEAR
            if not _accepts(rx, ry, rz, r2, nvx, nvy, nvz, code, x, y, z, wx, wy, wz, gx, gy,
                            gz, cos_ng):
                continue
            k, kf = _record_pair(v, p, is_freq, vp_rec, k, kf, pair_vp, pair_ph, fpair_vp, fpair_ph)


@njit(cache=True)
def _run_min(slot):
    """_count_range's run_min for the sorted photons' slots slot (n,):
    COUNT_RUN_MIN when a slot holds at least that many photons on average,
    else 65 (every run photon by photon: runs are cut at 64)."""
    n = slot.shape[0]
    runs = 1
    for q in range(1, n):
        runs += slot[q] != slot[q - 1]
    return COUNT_RUN_MIN if n >= COUNT_RUN_MIN * runs else 65


@njit(cache=True)
def _count_serial(slot, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_rec, vp_clip, cos_ng,
                  cell_start, vp_ids, M, Phi, rmin, hitmask, n_pair, n_freq, S,
                  touched, n_touched):
    _count_range(np.int64(0), slot.shape[0], slot, ph_pos, ph_ng, ph_wi, ph_power,
                 ph_rpred, vp_rec, vp_clip, cos_ng, cell_start, vp_ids, M[0], Phi[0], rmin[0],
                 hitmask, n_pair, n_freq, S[0], touched[0], n_touched[0:1], _run_min(slot))


@njit(cache=True, parallel=True)
def _count_parallel(slot, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_rec,
                    vp_clip, cos_ng, cell_start, vp_ids, M, Phi, rmin, hitmask, n_pair, n_freq,
                    S, touched, n_touched, n_chunks):
    # One contiguous range of sorted photons per accumulator row: chunks never
    # share a row, and the per-photon outputs are indexed by q: no race.
    n = slot.shape[0]
    run_min = _run_min(slot)
    for c in prange(n_chunks):
        _count_range(c * n // n_chunks, (c + 1) * n // n_chunks, slot, ph_pos,
                     ph_ng, ph_wi, ph_power, ph_rpred, vp_rec, vp_clip, cos_ng, cell_start,
                     vp_ids, M[c], Phi[c], rmin[c], hitmask, n_pair, n_freq, S[c],
                     touched[c], n_touched[c:c + 1], run_min)


@njit(cache=True)
def _pairs_serial(order, slot, ph_pos, ph_ng, ph_wi, ph_rpred, vp_rec, vp_clip, cos_ng,
                  cell_start, vp_ids, hitmask, n_pair, pair_off, pair_vp, pair_ph,
                  n_freq, freq_off, fpair_vp, fpair_ph, want_freq):
    _pairs_range(np.int64(0), order.shape[0], order, slot, ph_pos, ph_ng, ph_wi, ph_rpred,
                 vp_rec, vp_clip, cos_ng, cell_start, vp_ids, hitmask, n_pair, pair_off,
                 pair_vp, pair_ph, n_freq, freq_off, fpair_vp, fpair_ph, want_freq)


@njit(cache=True, parallel=True)
def _pairs_parallel(order, slot, ph_pos, ph_ng, ph_wi, ph_rpred, vp_rec, vp_clip, cos_ng,
                    cell_start, vp_ids, hitmask, n_pair, pair_off, pair_vp, pair_ph,
                    n_freq, freq_off, fpair_vp, fpair_ph, want_freq, n_chunks):
    # Each photon writes only its own [offset, offset + count) ranges: race-free.
    n = order.shape[0]
    for c in prange(n_chunks):
        _pairs_range(c * n // n_chunks, (c + 1) * n // n_chunks, order, slot, ph_pos,
                     ph_ng, ph_wi, ph_rpred, vp_rec, vp_clip, cos_ng, cell_start, vp_ids,
                     hitmask, n_pair, pair_off, pair_vp, pair_ph, n_freq, freq_off,
                     fpair_vp, fpair_ph, want_freq)


# ----------------------------------------------------------------------------
# Build
# ----------------------------------------------------------------------------

@njit(cache=True)
def _active_range(k0, k1, pos, R, active, act):
    """act[v] for VPs k0..k1-1 (active, finite, R > 0); returns their count,
    max |coordinate| and max R."""
    n, pm, rm = 0, 0.0, -np.inf
    for v in range(k0, k1):
        x, y, z, r = pos[v, 0], pos[v, 1], pos[v, 2], R[v]
        a = (active[v] and np.isfinite(x) and np.isfinite(y) and np.isfinite(z)
             and np.isfinite(r) and r > 0)
        act[v] = a
        if a:
            n += 1
            pm = max(pm, abs(x), abs(y), abs(z))
            rm = max(rm, r)
    return n, pm, rm


@njit(cache=True)
def _extent_range(k0, k1, j, pos, R, act, scale, R_ins, R_act, lo, hi):
    """R_ins (0 for the inactive), R_act[j..] (in VP order) of the active
    VPs k0..k1-1, and the bounds lo, hi (3,) of their spheres (updated in
    place)."""
    for v in range(k0, k1):
        R_ins[v] = 0.0
        if act[v]:
            r = R[v] * (1.0 + _REL_PAD) + _ABS_PAD * scale
            R_ins[v] = r
            R_act[j] = r
            j += 1
            for k in range(3):
                lo[k] = min(lo[k], pos[v, k] - r)
                hi[k] = max(hi[k], pos[v, k] + r)


@njit(cache=True, parallel=True)
def _active_extent(n_chunks, pos, R, active, act, R_ins, R_act):
    """build_grid's active VPs and their extent, by n_chunks threads (exact:
    minima, maxima and per-VP arithmetic, whatever n_chunks), into the
    caller's (K,) arrays: act (active, finite, R > 0), R_ins (0 where
    inactive) and R_act[:n_active] the active insertion radii in VP order.
    Returns n_active, lo, hi (3,)."""
    K = pos.shape[0]
    cnt = np.zeros(n_chunks, np.int64)
    pmax = np.zeros(n_chunks)
    rmax = np.full(n_chunks, -np.inf)
    for c in prange(n_chunks):
        cnt[c], pmax[c], rmax[c] = _active_range(c * K // n_chunks, (c + 1) * K // n_chunks,
                                                 pos, R, active, act)
    start = np.zeros(n_chunks + 1, np.int64)
    for c in range(n_chunks):
        start[c + 1] = start[c] + cnt[c]
    n_active = start[n_chunks]
    lo = np.full((n_chunks, 3), np.inf)
    hi = np.full((n_chunks, 3), -np.inf)
    if n_active > 0:
        scale = pmax.max() + rmax.max()
        for c in prange(n_chunks):
            _extent_range(c * K // n_chunks, (c + 1) * K // n_chunks, start[c], pos, R, act,
                          scale, R_ins, R_act, lo[c], hi[c])
    else:
        R_ins[:] = 0.0
    lo_all = np.full(3, np.inf)
    hi_all = np.full(3, -np.inf)
    for c in range(n_chunks):
        for k in range(3):
            lo_all[k] = min(lo_all[k], lo[c, k])
            hi_all[k] = max(hi_all[k], hi[c, k])
    return n_active, lo_all, hi_all


@njit(cache=True)
def _bbox_range(k0, k1, pos, R_ins, act, origin, inv_h):
    """The bounding-box cell counts of the active VPs k0..k1-1: their sum
    and their largest."""
    n = 0
    mx = 0
    for v in range(k0, k1):
        if act[v]:
            r = R_ins[v]
            m = 1
            for k in range(3):
                a = math.floor((pos[v, k] - r - origin[k]) * inv_h)
                b = math.floor((pos[v, k] + r - origin[k]) * inv_h)
                m *= np.int64(b - a + 1.0)
            n += m
            mx = max(mx, m)
    return n, mx


@njit(cache=True, parallel=True)
def _bbox_cells(n_chunks, pos, R_ins, act, origin, inv_h):
    """Upper bound on cell entries: the sum over the active VPs of their
    bounding box's cell count, and the largest count, by n_chunks threads."""
    K = pos.shape[0]
    tot = np.zeros(n_chunks, np.int64)
    mx = np.zeros(n_chunks, np.int64)
    for c in prange(n_chunks):
        tot[c], mx[c] = _bbox_range(c * K // n_chunks, (c + 1) * K // n_chunks, pos, R_ins,
                                    act, origin, inv_h)
    return tot.sum(), mx.max()


@njit(cache=True)
def _digit_range(k0, k1, bits, shift, prefix, full, cnt):
    """cnt[digit] += 1, digit = (bits[v] >> shift) & 0xFFFF, for v in k0..k1-1
    whose bits above the digit equal prefix (every v when full)."""
    for v in range(k0, k1):
        b = bits[v]
        if full or (b >> np.uint64(shift + 16)) == prefix:
            cnt[np.int64((b >> np.uint64(shift)) & np.uint64(0xFFFF))] += 1


@njit(cache=True)
def _below_range(k0, k1, x, y):
    """(how many of x[k0:k1] are < y, the largest of them or -inf)."""
    n, m = 0, -np.inf
    for v in range(k0, k1):
        if x[v] < y:
            n += 1
            m = max(m, x[v])
    return n, m


@njit(cache=True)
def _digit_rows(k0, k1, bits, d, out, o):
    """out[o:] = the bits[v] (v in k0..k1-1) whose top 16 bits are d, in order."""
    for v in range(k0, k1):
        if (bits[v] >> np.uint64(48)) == d:
            out[o] = bits[v]
            o += 1


@njit(cache=True)
def _digit_of_rank(cnt, k):
    """(digit, rank within it) of the value of rank k, from per-thread digit
    counts cnt (T, 65536)."""
    tot = cnt.sum(axis=0)
    d = 0
    while k >= tot[d]:
        k -= tot[d]
        d += 1
    return d, k


@njit(cache=True, parallel=True)
def _median_parallel(n_chunks, x):
    """np.median of x (n,) float64, n >= 1, every value finite and >= 0 (the
    active radii), by n_chunks threads, exactly: a positive float64's bits,
    read as an unsigned integer, order as its value, so the value of rank
    n // 2 is found 16 bits at a time -- the top 16 bits by counts split
    over the threads, the values with those bits gathered (by the threads,
    in their counts' order) and the lower 48 bits found among them alone;
    no copy of x, no sort.  For even n the value below it is the largest
    smaller one (or the same value, when repeated), and the two are
    averaged as numpy's mean of two does, (a + b) / 2."""
    n = x.shape[0]
    bits = x.view(np.uint64)
    cnt = np.zeros((n_chunks, 1 << 16), np.int64)
    for c in prange(n_chunks):
        _digit_range(c * n // n_chunks, (c + 1) * n // n_chunks, bits, np.int64(48),
                     np.uint64(0), bool(True), cnt[c])
    d, k = _digit_of_rank(cnt, n // 2)
    # the values of digit d, each thread's after the threads' before it
    o = np.zeros(n_chunks + 1, np.int64)
    for c in range(n_chunks):
        o[c + 1] = o[c] + cnt[c, d]
    cand = np.empty(o[n_chunks], np.uint64)
    for c in prange(n_chunks):
        _digit_rows(c * n // n_chunks, (c + 1) * n // n_chunks, bits, np.uint64(d), cand, o[c])
    prefix = np.uint64(d)
    one = cnt[:1]
    for level in range(1, 4):
        shift = 48 - 16 * level
        one[:] = 0
        _digit_range(np.int64(0), cand.shape[0], cand, shift, prefix, bool(False), one[0])
        d, k = _digit_of_rank(one, k)
        prefix = (prefix << np.uint64(16)) | np.uint64(d)
    hi = np.array([prefix]).view(np.float64)[0]
    if n % 2 == 1:
        return hi
    below = np.zeros(n_chunks, np.int64)
    below_max = np.full(n_chunks, -np.inf)
    for c in prange(n_chunks):
        below[c], below_max[c] = _below_range(c * n // n_chunks, (c + 1) * n // n_chunks,
                                              x, hi)
    lo = below_max.max() if below.sum() >= n // 2 else hi
    return (lo + hi) / 2.0


#: Serial builds of the three (small grids: no thread hand-off).
_active_extent_serial = serial_twin(_active_extent)
_bbox_cells_serial = serial_twin(_bbox_cells)
_median_serial = serial_twin(_median_parallel)


def start_dtype(entry_bound: int):
    """The dtype of Grid.cell_start (and of the build's cursors) for at most
    entry_bound entries: int32 while it fits (the table of about one slot
    per entry is the grid's largest array; int32 halves it)."""
    return np.int32 if entry_bound < 2**31 else np.int64


def build_grid(vp_pos: np.ndarray, vp_R: np.ndarray, active: np.ndarray,
               cell_factor: float = CELL_FACTOR, layout: str = "auto",
               log2_table: Optional[int] = None, parallel: bool = True,
               buffers: Optional[KeptBuffers] = None,
               check_stop: Callable[[], None] = lambda: None) -> Grid:
    """Bucket the active visible points into a grid (see the module docstring).

    vp_pos: (K, 3) float64 world positions.  vp_R: (K,) float64 radii [m].
    active: (K,) bool; VPs with a non-finite position or radius, or R <= 0, are
    treated as inactive.  cell_factor: h = cell_factor * median active radius
    (before the entry-budget clamp).  layout: 'auto', 'dense' or 'hash';
    log2_table forces a hash table of 2**log2_table slots (tests use tiny
    tables to exercise collisions).  parallel: numba threads from
    PARALLEL_MIN_VPS VPs (False: one thread; the same grid).  buffers: the
    grid's arrays and the build's temporaries are carved from these kept
    buffers (core.kept.KeptBuffers: "grid_R", "grid_act", "grid",
    "grid_tmp"), reused from the last build when nothing holds its grid
    (None: new ones).  check_stop() is called between the build's phases
    (extent, cell size, insertion), so that a cancel waits for one phase
    only (a 1080p build is several tenths of a second of CPU).
    tests/oracle_grid.py is the reference it is checked against (the numpy
    extent and the serial two-pass insertion it replaced).
    """
    if layout not in ("auto", "dense", "hash"):
        raise ValueError("build_grid: layout must be 'auto', 'dense' or 'hash', "
                         f"not {layout!r}")
    vp_pos = np.ascontiguousarray(vp_pos, dtype=np.float64).reshape(-1, 3)
    K = vp_pos.shape[0]
    vp_R = np.ascontiguousarray(vp_R, dtype=np.float64).reshape(K)
    active = np.asarray(active, dtype=bool).reshape(K)
    T = numba.get_num_threads() if (parallel and K >= PARALLEL_MIN_VPS) else 1
    kb = KeptBuffers() if buffers is None else buffers
    # The camera and direct-light stages' freed pixel-sized temporaries stay
    # resident in glibc's heap: hand them back before the build's own arrays
    # and the gather's (the pass's peak, docs/architecture.md "Performance").
    memory.release_free_heap(K)
    R_ins, = kb.take("grid_R", [((K,), np.float64)])
    act, R_act = kb.take("grid_act", [((K,), np.bool_), ((K,), np.float64)])
    n_active, lo, hi = (_active_extent if T > 1 else _active_extent_serial)(
        T, vp_pos, vp_R, active, act, R_ins, R_act)
    n_active = int(n_active)
    R_act = R_act[:n_active]
    if n_active == 0:
        z3 = np.zeros(3)
        return Grid(K, 0, z3, 1.0, 1.0, np.full(3, np.inf), np.full(3, -np.inf),
                    True, np.ones(3, np.int64), 0, np.zeros(2, np.int32),
                    np.zeros(0, np.int32), R_ins)
    origin = lo.copy()
    check_stop()

    # np.median's value, in the numba threads (it was the build's serial part)
    h = cell_factor * float((_median_parallel if T > 1 else _median_serial)(T, R_act))
    del R_act
    budget = ENTRY_BUDGET_PER_VP * n_active
    while True:
        inv_h = 1.0 / h
        est, cap = (_bbox_cells if T > 1 else _bbox_cells_serial)(
            T, vp_pos, R_ins, act, origin, inv_h)
        est = int(est)
        if est <= budget:
            break
        h *= 1.25
    dims = (np.floor((hi - origin) * inv_h).astype(np.int64) + 1)
    n_dense = int(np.prod(dims.astype(np.float64)))
    if log2_table is None:
        log2_table = max(1, int(math.ceil(math.log2(max(est, 2)))))
    else:
        log2_table, layout = max(1, min(int(log2_table), 40)), "hash"
    dense = {"auto": n_dense <= (1 << log2_table), "dense": True, "hash": False}[layout]
    if dense:
        n_slots, shift = n_dense, 0
    else:
        n_slots, shift = 1 << log2_table, 64 - log2_table
    nx, ny, nz = int(dims[0]), int(dims[1]), int(dims[2])
    check_stop()

    # est bounds the entries (a VP's cells are among its bounding box's):
    # room for est of them, the pages past the E written are never touched.
    parallel_insert = n_active >= PARALLEL_MIN_VPS and T > 1
    split = (int(_part_split(T, vp_pos, act, origin, inv_h, dense, nx, ny, nz, shift, n_slots))
             if parallel_insert else n_slots)
    cell_start, vp_ids = kb.take("grid", [((n_slots + 1,), start_dtype(est)),
                                          ((est,), np.int32)])
    off, low, ent_slot = kb.take("grid_tmp", [
        ((K + 1,), np.int64), ((K + 1,), np.int64),
        ((est,), np.int32 if n_slots < 2**31 else np.int64)])
    args = (vp_pos, R_ins, act, origin, h, inv_h, dense, nx, ny, nz, shift, n_slots, split,
            int(cap), off, low, ent_slot, cell_start, vp_ids)
    if parallel_insert:
        E = _insert_parallel(T, *args)
    else:
        E = _insert_one_pass(vp_pos, R_ins, act, origin, h, inv_h, dense, nx, ny, nz, shift,
                             n_slots, int(cap), off, ent_slot, cell_start, vp_ids)
    return Grid(K, n_active, origin, h, inv_h, lo, hi, bool(dense), dims,
                0 if dense else log2_table, cell_start, vp_ids[:int(E)], R_ins)


# ----------------------------------------------------------------------------
# Gather
# ----------------------------------------------------------------------------

def _geom(a, P, dtype):
    return np.ascontiguousarray(a, dtype=dtype).reshape(P, 3)


def _prepare(ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_pos, vp_ng, vp_R2, vp_const):
    ph_pos = np.asarray(ph_pos)
    P = ph_pos.size // 3
    # Photon geometry stays float32 when it all comes from Embree (no copy);
    # any float64 input promotes all three to float64.
    dt = np.result_type(ph_pos.dtype, np.asarray(ph_ng).dtype, np.asarray(ph_wi).dtype,
                        np.float32)
    dt = np.float32 if dt == np.float32 else np.float64
    ph = (_geom(ph_pos, P, dt), _geom(ph_ng, P, dt), _geom(ph_wi, P, dt),
          np.ascontiguousarray(ph_power, dtype=np.float64).reshape(P, 3),
          np.ascontiguousarray(ph_rpred, dtype=np.float64).reshape(P))
    vp_pos = np.ascontiguousarray(vp_pos, dtype=np.float64).reshape(-1, 3)
    K = vp_pos.shape[0]
    vp = (vp_pos, np.ascontiguousarray(vp_ng, dtype=np.float64).reshape(K, 3),
          np.ascontiguousarray(vp_R2, dtype=np.float64).reshape(K),
          np.ascontiguousarray(vp_const, dtype=np.bool_).reshape(K))
    return P, K, ph, vp


def _empty_result(K, want_freq_pairs, sectors=False):
    e = np.zeros(0, np.int32)
    return GatherResult(np.zeros(K, np.int64), np.zeros((K, 3)), e, e.copy(),
                        np.full(K, np.inf),
                        e.copy() if want_freq_pairs else None,
                        e.copy() if want_freq_pairs else None,
                        np.zeros((K, SECTOR_CELLS), np.int64) if sectors else None)


def _vp_records(vp_pos, vp_ng, vp_R2, vp_const, out=None):
    """(K, 8) float64: one 64-byte record per VP (x, y, z, R^2, ng, const), so a
    candidate reads one cache line instead of four arrays; vp_pos, vp_ng (K,
    3), vp_R2 (K,) float64 and vp_const (K,) bool, contiguous (``_prepare``).
    out: a (K, 8) float64 array to write them into (GatherBuffers: a kept
    buffer), else a new one.

    Copied by a compiled kernel (into a new array of numba's allocator
    when out is None), by VP ranges in the numba threads from
    PARALLEL_MIN_VPS VPs.  numpy advises
    huge pages for arrays of 4 MiB and more (``NUMPY_MADVISE_HUGEPAGE``):
    faulting in the fresh 128 MiB of a 1080p pass's records took 0.5-0.8 s
    of system time a pass on the virtual machine FPPM is measured on,
    numba's 4 KiB pages ~0.05 s (docs/architecture.md, "Cores used: the
    gather's records and the radius initialisation").  A copy: the same
    values as numpy's column assignments (tests/test_gather_buffers.py)."""
    T = numba.get_num_threads()
    K = vp_pos.shape[0]
    rec = _new_records(K) if out is None else out
    if K >= PARALLEL_MIN_VPS and T > 1:
        _vp_records_parallel(T, vp_pos, vp_ng, vp_R2, vp_const, rec)
    else:
        _vp_records_serial(1, vp_pos, vp_ng, vp_R2, vp_const, rec)
    return rec


@njit(cache=True)
def _new_records(K):
    """An uninitialised (K, 8) float64 array from numba's allocator."""
    return np.empty((K, 8))


@njit(cache=True)
def _vp_records_range(v0, v1, vp_pos, vp_ng, vp_R2, vp_const, rec):
    """Records v0..v1-1 of :func:`_vp_records` into rec (K, 8)."""
    for v in range(v0, v1):
        rec[v, 0] = vp_pos[v, 0]
        rec[v, 1] = vp_pos[v, 1]
        rec[v, 2] = vp_pos[v, 2]
        rec[v, 3] = vp_R2[v]
        rec[v, 4] = vp_ng[v, 0]
        rec[v, 5] = vp_ng[v, 1]
        rec[v, 6] = vp_ng[v, 2]
        rec[v, 7] = 1.0 if vp_const[v] else 0.0


@njit(cache=True, parallel=True)
def _vp_records_parallel(n_chunks, vp_pos, vp_ng, vp_R2, vp_const, rec):
    """:func:`_vp_records` into rec (K, 8) by n_chunks VP ranges (each record
    is its own)."""
    K = vp_pos.shape[0]
    for c in prange(n_chunks):
        _vp_records_range(c * K // n_chunks, (c + 1) * K // n_chunks, vp_pos, vp_ng, vp_R2,
                          vp_const, rec)


_vp_records_serial = serial_twin(_vp_records_parallel)


class GatherBuffers:
    """Per-thread gather accumulators allocated once and reused by every chunk
    (``gather(..., buffers=)``), folded into a pass's sums by :meth:`fold`.

    Allocating and summing (threads, K) arrays for every photon chunk cost
    O(K) per chunk in allocations, page faults and passes over pixel-sized
    arrays, most of a chunk's gather at 1080p; here the count pass also lists
    the VPs each thread touched, and ``fold`` adds and zeroes those alone (or,
    when many were touched, sweeps every VP's counts in order), so a chunk
    costs O(photons + touched VPs) with no allocation of pixel size.

    K visible points, threads accumulator rows, sectors: with sector counts.
    M (threads, K) int32, Phi (threads, K, 3) float64, rmin (threads, K)
    float64 (inf), S (threads, K, SECTOR_CELLS or 0) int32 (a VP counts a
    photon once: int32 holds any gather of fewer than 2**31 photons between
    two folds); touched (threads, K) int32 with n_touched (threads,) int64
    entries each: 144 B a VP with two threads and sectors, 80 B without.
    Between chunks every row is zero (rmin inf).  vp_rec (K, 8) is built
    once per grid (``bind``; the visible points must not
    change while the grid does not), in the buffer ``kept`` (the grid
    build's temporaries', when set) and dropped by ``unbind`` (end of a pass,
    so that the next build can reuse that buffer).  ``allocations`` counts the
    (re)allocations of the rows.
    """

    def __init__(self, K: int, sectors: bool = False, threads: Optional[int] = None):
        self.K, self.with_sectors, self.allocations = int(K), bool(sectors), 0
        self.grid = None
        # core.kept.KeptBuffers the records are carved from (build_grid's
        # "grid_tmp"), or None: new records every bind
        self.kept: Optional[KeptBuffers] = None
        self._allocate(max(1, int(threads or numba.get_num_threads())))

    def _allocate(self, T: int) -> None:
        K = self.K
        self.T = T
        self.M = np.zeros((T, K), np.int32)
        self.Phi = np.zeros((T, K, 3))
        self.rmin = np.full((T, K), np.inf)
        self.S = np.zeros((T, K, SECTOR_CELLS if self.with_sectors else 0), np.int32)
        self.touched = np.empty((T, K), np.int32)
        self.n_touched = np.zeros(T, np.int64)
        self.n_used = 1
        self.unbind()
        self.allocations += 1

    def clear(self) -> None:
        """Zero rows a gather left unfolded (a pass interrupted between its
        gather and fold); nothing to do when every gather was folded."""
        if self.n_touched.any():
            self.M[:] = 0
            self.Phi[:] = 0.0
            self.rmin[:] = np.inf
            self.S[:] = 0
            self.n_touched[:] = 0

    def unbind(self) -> None:
        """Drop the per-pass records (the next gather rebuilds them)."""
        self.grid = self.vp_rec = None

    def bind(self, grid: Grid, vp, n_chunks: int) -> None:
        """Records of the prepared VPs vp = (pos, ng, R2, const) for grid (once
        per grid), room for n_chunks rows."""
        if n_chunks > self.T:
            self._allocate(n_chunks)
        if self.grid is grid:
            return
        _check_radii(grid, vp[2])
        self.vp_rec = None
        out = None
        if self.kept is not None:
            # the grid build's temporaries' buffer: free once the grid is
            # built, and already resident (no page faults a pass)
            out, = self.kept.take("grid_tmp", [((self.K, 8), np.float64)])
        self.vp_rec = _vp_records(*vp, out=out)
        self.grid = grid

    def fold(self, M, Phi, phi_scale, phi_div: float, rmin, rmin_mask=None, S=None,
             clip=None) -> None:
        """Add the rows' sums at the touched VPs into a pass's sums and zero
        the rows: M (K,) += sum M rows; Phi (K, 3) += (sum Phi rows) *
        (phi_scale (K, 3) / phi_div); rmin (K,) = min(rmin, min rmin rows)
        where rmin_mask (K,) bool (None: everywhere); S (K, SECTOR_CELLS) +=
        sum S rows when given; phi_scale float32 or float64, divided by
        phi_div in its own dtype.  The rows are summed in thread order, as
        ``gather`` without buffers does, then scaled and added with the same
        float64 operations as ``acc += g.Phi_sum * (scale / div)`` in numpy:
        the same bits as adding that chunk's GatherResult.  clip (K,)
        uint64, the packed clips the gather used (None: none): a clipped
        VP's M and Phi are added times 1 / its visible fraction and its S
        through its cell weights (clip_weights)."""
        # The division in phi_scale's dtype, as numpy does (NEP 50: a float32
        # albedo / pi is a float32), then the product in float64.
        scale = np.ascontiguousarray(phi_scale)
        if scale.dtype not in (np.float32, np.float64):
            scale = scale.astype(np.float64)
        empty2 = np.zeros((0, 0))
        # The touched lists while few VPs were touched, else every VP in order.
        sweep = bool(self.n_touched.sum() * FOLD_SWEEP_FRACTION >= self.K)
        rest = (M, Phi, scale, scale.dtype.type(phi_div), rmin,
                np.zeros(0, np.bool_) if rmin_mask is None else rmin_mask,
                empty2 if S is None else S,
                np.zeros(0, np.uint64) if clip is None else clip)
        T = numba.get_num_threads()
        if sweep and T > 1 and self.K >= PARALLEL_MIN_VPS:
            # a pixel-sized sweep (1080p: 2M VPs): by VP ranges in threads
            _fold_sweep_parallel(T, self.M, self.Phi, self.rmin, self.S, self.touched,
                                 self.n_touched,
                                 self.n_used, *rest)
            return
        _fold(self.M, self.Phi, self.rmin, self.S, self.touched, self.n_touched,
              self.n_used, *rest, sweep)


@njit(cache=True)
def _fold_run(c, i0, i1, touched, bM, bPhi, brmin, bS, n_used, M, Phi, scale, div, rmin,
              rmin_mask, S, clip):
    """Fold visible points into the sums and zero their rows (thread
    order; clip (K,) uint64 or (0,): GatherBuffers.fold): c >= 0, those
    listed at touched[c, i0:i1] whose row c still counts (else folded from
    an earlier row's list); c < 0, the visible points i0..i1-1 that a row
    counts (a sweep).  The per-point body is written here, in the loop, not
    in an inlined helper taking the arrays: such a helper, with its
    branches, kept numba's reference-count increment and decrement of each
    of its 14 arrays at every point (atomic operations; docs/architecture.md
    "The count pass without reference counts")."""
    for i in range(i0, i1):
        if c >= 0:
            v = np.int64(touched[c, i])
            if bM[c, v] == 0:
                continue
        else:
            v = np.int64(i)
            counted = False
            for t in range(n_used):
                counted |= bM[t, v] != 0
            if not counted:
                continue
        m = bM[0, v]
        r = brmin[0, v]
        p0, p1, p2 = bPhi[0, v, 0], bPhi[0, v, 1], bPhi[0, v, 2]
        for t in range(1, n_used):
            m += bM[t, v]
            r = min(r, brmin[t, v])
            p0 += bPhi[t, v, 0]
            p1 += bPhi[t, v, 1]
            p2 += bPhi[t, v, 2]
        if clip.shape[0] > 0 and clip[v] != CLIP_CLEAR:
            # np.int64: one compile for int32 and int64 callers (core/warmup.py)
            _fold_clipped(v, np.int64(m), p0, p1, p2, bS, n_used, M, Phi, scale, div, S,
                          clip[v])
        else:
            M[v] += m
            Phi[v, 0] += p0 * (scale[v, 0] / div)
            Phi[v, 1] += p1 * (scale[v, 1] / div)
            Phi[v, 2] += p2 * (scale[v, 2] / div)
            for t in range(n_used):
                if S.shape[0] > 0:
                    for j in range(S.shape[1]):
                        S[v, j] += bS[t, v, j]
        if rmin_mask.shape[0] == 0 or rmin_mask[v]:
            rmin[v] = min(rmin[v], r)
        for t in range(n_used):
            bM[t, v] = 0
            brmin[t, v] = np.inf
            bPhi[t, v, 0] = 0.0
            bPhi[t, v, 1] = 0.0
            bPhi[t, v, 2] = 0.0
            for j in range(bS.shape[2]):
                bS[t, v, j] = 0


@njit(cache=True)
def _fold_clipped(v, m, p0, p1, p2, bS, n_used, M, Phi, scale, div, S, code):
    """_fold_run's sums for a clipped visible point: count m and flux (p0,
    p1, p2) times 1 / its visible fraction, sector counts through the cell
    weights of clip_weights (a full disc's, where the light is uniform)."""
    Wc = np.empty((SECTOR_CELLS, SECTOR_CELLS))
    w = clip_weights(code, Wc)
    M[v] += m * w
    Phi[v, 0] += p0 * (scale[v, 0] / div) * w
    Phi[v, 1] += p1 * (scale[v, 1] / div) * w
    Phi[v, 2] += p2 * (scale[v, 2] / div) * w
    if S.shape[0] > 0:
        for c in range(SECTOR_CELLS):
            acc = 0.0
            for j in range(SECTOR_CELLS):
                for t in range(n_used):
                    acc += Wc[c, j] * bS[t, v, j]
            S[v, c] += acc


@njit(cache=True)
def _fold(bM, bPhi, brmin, bS, touched, n_touched, n_used, M, Phi, scale, div, rmin,
          rmin_mask, S, clip, sweep):
    """GatherBuffers.fold.  sweep False: every VP listed by a row, once (its M
    rows are zero afterwards, which marks it done for the other rows' lists);
    sweep True: every VP with a count, in order (sequential memory).  One
    kernel for both, so that the warm-up compiles the one the renders use."""
    if sweep:
        _fold_run(np.int64(-1), np.int64(0), bM.shape[1], touched, bM, bPhi, brmin, bS, n_used,
                  M, Phi, scale, div, rmin, rmin_mask, S, clip)
        n_touched[:] = 0
        return
    for c in range(n_used):
        _fold_run(c, np.int64(0), n_touched[c], touched, bM, bPhi, brmin, bS, n_used, M, Phi,
                  scale, div, rmin, rmin_mask, S, clip)
        n_touched[c] = 0


@njit(cache=True, parallel=True)
def _fold_sweep_parallel(n_chunks, bM, bPhi, brmin, bS, touched, n_touched, n_used, M, Phi,
                         scale, div, rmin, rmin_mask, S, clip):
    """_fold's sweep by n_chunks threads, one VP range each (the same sums:
    a VP's fold does not depend on the others')."""
    K = bM.shape[1]
    for c in prange(n_chunks):
        _fold_run(np.int64(-1), c * K // n_chunks, (c + 1) * K // n_chunks, touched, bM, bPhi,
                  brmin, bS, n_used, M, Phi, scale, div, rmin, rmin_mask, S, clip)
    n_touched[:] = 0


def _check_radii(grid: Grid, vp_R2) -> None:
    if np.any((vp_R2 > grid.R_ins * grid.R_ins) & (grid.R_ins > 0)):
        raise ValueError("gather: vp_R2 exceeds the radius the grid was built with; "
                         "rebuild the grid after the radii grow")


def gather(grid: Grid, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
           vp_pos, vp_ng, vp_R2, vp_const, cos_ng: float = COS_NG_DEFAULT,
           want_freq_pairs: bool = False, parallel: Optional[bool] = None,
           sectors: bool = False, buffers: Optional[GatherBuffers] = None,
           clip: Optional[np.ndarray] = None) -> GatherResult:
    """Count photons into visible points (rules (1)-(4) of the module docstring).

    ph_pos (P, 3) float32/64 photon hit positions; ph_ng (P, 3) geometric normal
    of the surface the photon hit; ph_wi (P, 3) unit direction towards where the
    photon came from; ph_power (P, 3) float64; ph_rpred (P,) float64 predicted
    radius, NaN = not a frequency photon.  vp_pos (K, 3) float64; vp_ng (K, 3)
    geometric normal oriented to the camera side; vp_R2 (K,) float64 squared
    radius, must be <= grid.R_ins**2 (build the grid with the pass's radii);
    vp_const (K,) bool: BSDF is constant (Phi_sum) or not (pairs).  VPs not
    active in the grid count nothing.  The caller rejects photons with
    non-finite or non-positive power before the gather.
    parallel: split photons over numba threads (None = when P >=
    PARALLEL_MIN_PHOTONS and more than one thread is available).
    sectors: also count each VP's photons per sector cell (GatherResult.sectors);
    the other outputs are the same bits either way.
    buffers: accumulate M, Phi_sum, rpred_min and the sectors (when
    buffers.with_sectors; the ``sectors`` argument is then ignored) in these
    reused per-thread rows instead; the result's M, Phi_sum, rpred_min and
    sectors are then None until ``buffers.fold``.  Pairs are returned as usual.
    clip: (K,) uint64 packed clips (core.sppm.clip.clip_codes) for rule (5),
    None: none.  The counts returned are the photons counted (not scaled:
    GatherBuffers.fold(..., clip=) scales them).
    """
    K = np.asarray(vp_pos).size // 3
    if K != grid.K:
        raise ValueError(f"gather: {K} visible points but the grid was built for {grid.K}")
    P, K, ph, vp = _prepare(ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                            vp_pos, vp_ng, vp_R2, vp_const)
    n_threads = numba.get_num_threads()
    if parallel is None:
        parallel = n_threads > 1 and P >= PARALLEL_MIN_PHOTONS
    n_chunks = n_threads if parallel else 1
    if buffers is None:
        _check_radii(grid, vp[2])
    else:
        if buffers.K != K:
            raise ValueError(f"gather: buffers for {buffers.K} visible points, not {K}")
        buffers.bind(grid, vp, n_chunks)
        sectors = buffers.with_sectors
    if P == 0 or grid.n_active == 0:
        return _no_photons(K, want_freq_pairs, sectors, buffers)

    sort = _sort_photons if parallel else _sort_photons_serial
    (order, slot, ph_pos_, ph_ng_, ph_wi_, ph_power_, ph_rpred_, hitmask, n_pair,
     n_freq) = _sorted_photons(sort, ph, grid, n_chunks,
                               None if buffers is None else buffers.kept)
    n = order.shape[0]
    if n == 0:
        return _no_photons(K, want_freq_pairs, sectors, buffers)

    if buffers is None:
        vp_rec = _vp_records(*vp)
        # int32 rows as GatherBuffers' (a chunk's counts fit): the count
        # kernels compile once for both (core.materials.compiled.eval_pair_as)
        M = np.zeros((n_chunks, K), np.int32)
        Phi = np.zeros((n_chunks, K, 3))
        rmin = np.full((n_chunks, K), np.inf)
        S = np.zeros((n_chunks, K, SECTOR_CELLS if sectors else 0), np.int32)
        touched, n_touched = np.empty((n_chunks, 0), np.int32), np.zeros(n_chunks, np.int64)
    else:
        b = buffers
        vp_rec, M, Phi, rmin, S = b.vp_rec, b.M, b.Phi, b.rmin, b.S
        touched, n_touched = b.touched, b.n_touched
        b.n_used = max(b.n_used, n_chunks) if n_touched.any() else n_chunks
    g = (grid.cell_start, grid.vp_ids)
    vp_clip = (np.zeros(0, np.uint64) if clip is None
               else np.ascontiguousarray(clip, np.uint64).reshape(K))
    cargs = (slot, ph_pos_, ph_ng_, ph_wi_, ph_power_, ph_rpred_, vp_rec, vp_clip,
             float(cos_ng), *g, M, Phi, rmin, hitmask, n_pair, n_freq, S,
             touched, n_touched)
    if parallel:
        _count_parallel(*cargs, n_chunks)
    else:
        _count_serial(*cargs)
    if buffers is not None:
        M = Phi = rmin = S = None
    elif parallel:
        M = M.sum(axis=0, dtype=np.int64)
        Phi = Phi.sum(axis=0)
        rmin = rmin.min(axis=0)
        S = S.sum(axis=0, dtype=np.int64)
    else:
        M, Phi, rmin, S = M[0].astype(np.int64), Phi[0], rmin[0], S[0].astype(np.int64)

    pair_off = np.zeros(n + 1, np.int64)
    np.cumsum(n_pair, out=pair_off[1:])
    n_pairs = int(pair_off[-1])
    freq_off = np.zeros(n + 1, np.int64)
    if want_freq_pairs:
        np.cumsum(n_freq, out=freq_off[1:])
    n_fp = int(freq_off[-1])
    pair_vp = np.empty(n_pairs, np.int32)
    pair_ph = np.empty(n_pairs, np.int32)
    fpair_vp = np.empty(n_fp, np.int32)
    fpair_ph = np.empty(n_fp, np.int32)
    if n_pairs or n_fp:
        pargs = (order, slot, ph_pos_, ph_ng_, ph_wi_, ph_rpred_, vp_rec, vp_clip, float(cos_ng),
                 *g, hitmask, n_pair, pair_off, pair_vp, pair_ph, n_freq, freq_off,
                 fpair_vp, fpair_ph, bool(want_freq_pairs))
        if parallel:
            _pairs_parallel(*pargs, n_chunks)
        else:
            _pairs_serial(*pargs)
    return GatherResult(M, Phi, pair_vp, pair_ph, rmin,
                        fpair_vp if want_freq_pairs else None,
                        fpair_ph if want_freq_pairs else None,
                        S if sectors and buffers is None else None)


def _no_photons(K, want_freq_pairs, sectors, buffers) -> GatherResult:
    """The result of a gather that counted nothing."""
    r = _empty_result(K, want_freq_pairs, sectors)
    if buffers is not None:
        r.M = r.Phi_sum = r.rpred_min = r.sectors = None
    return r
