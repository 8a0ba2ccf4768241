"""The gather with the photons sorted by cell against a lookup in trace order.

    .venv/bin/python bench/bench_gather_order.py [--res 256x256 1920x1080] [--repeat 5]
    .venv/bin/python bench/bench_gather_order.py --res 256x256 --cell-factors 1.5 1 2
    .venv/bin/python bench/bench_gather_order.py --res 256x256 --splat --repeat 10
    .venv/bin/python bench/bench_gather_order.py --res 256x256 --count-runs --repeat 12

The deposits of one pass of the Cornell box (plain, 200k photons: its
chunks), the grid and the visible points, captured from a render; then,
interleaved in this process, each chunk gathered and folded into a pass's
sums by

  sorted:  hashgrid.gather(..., buffers=) and GatherBuffers.fold, as a pass
           does (the photons sorted by slot, copied, then the count pass);
  direct:  each photon, in trace order, looks its cell up and walks its
           visible points (pbrt-v4's SPPM way), accumulating into the same
           per-thread rows (photon index ranges per thread), then the same
           fold.

The branch-free count pass of docs/architecture.md ("Tried, not kept: the
count pass without branches") was timed by this file's --count as of commit
4441bd1 (`git show 4441bd1:bench/bench_gather_order.py`); it is not kept
here, where it repeated hashgrid's count pass.

--cell-factors F ...: instead, the pass's grid built with each h = F x the
median radius (hashgrid.build_grid(cell_factor=)) and its chunks gathered
(sorted) and folded with it, the factors interleaved: the build's and the
gather's CPU and, a deposit, the candidates tested and the hits
(docs/architecture.md "The count pass without reference counts").

--splat: instead, the pass's photons traced again (the same chunks and
seeds), alternating: deposit, then gather sorted (hashgrid.gather) and fold,
against each bounce's deposits gathered in trace order inside the tracing
thread right after the bounce kernel wrote them, into that thread's row of
a GatherBuffers (pbrt-v4's SPPM splats at deposit time), then the same fold
(docs/architecture.md "The photon pass's own work against raw Embree").

--count-runs: instead, the pass's chunks gathered (sorted) and folded with
hashgrid's count pass (by runs of a slot, rule (1) as a bit mask) and with
the photon-by-photon count pass it replaced
(tests/test_count_runs.py ``count_photon_by_photon``, in the same prange
split), alternating, the count pass's CPU on its own; the sums and pairs
compared bit for bit (docs/architecture.md "The count pass by runs of a
slot, round 14").

Printed: CPU (process clock) of each, min / median of --repeat rounds,
and the largest differences of the sums (M, sector counts and the
smallest radius exactly; Phi within float64 rounding: the summation order
differs).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numba
import numpy as np
from numba import njit, prange

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))
sys.path.insert(0, os.path.join(ROOT, "tests"))

from core.sppm import hashgrid as Hg  # noqa: E402
from core.render import Renderer  # noqa: E402
from core.settings import RenderSettings  # noqa: E402
from core.kept import KeptBuffers  # noqa: E402
from test_count_runs import count_photon_by_photon  # noqa: E402


def capture(w, h, photons, plain=True, builds=None):
    """(renderer, [gather call args/kwargs]) of one pass after a warm-up one;
    builds (a list): the pass's build_grid calls (args, kwargs) appended."""
    from bench_render import cornell
    r = Renderer(cornell(w, height=h), RenderSettings(integrator="PHOTON", max_passes=1000,
                                                      photons_per_pass=photons,
                                                      use_frequency=not plain),
                 log=lambda s: None)
    r.step()
    calls = []
    f = Hg.gather

    def g(grid, *a, **k):
        calls.append((grid, [np.array(x, copy=True) if isinstance(x, np.ndarray) else x
                             for x in a], dict(k)))
        return f(grid, *a, **k)
    b = Hg.build_grid

    def bg(*a, **k):
        if builds is not None:
            builds.append(([np.array(x, copy=True) if isinstance(x, np.ndarray) else x
                            for x in a], {k_: v for k_, v in k.items()
                                          if k_ not in ("buffers", "check_stop")}))
        return b(*a, **k)
    Hg.gather = g
    Hg.build_grid = bg
    try:
        r.step()
    finally:
        Hg.gather = f
        Hg.build_grid = b
    return r, calls


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--res", nargs="+", default=["256x256", "1920x1080"])
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, nargs="+", default=[numba.get_num_threads()])
    ap.add_argument("--cell-factors", type=float, nargs="+", default=None,
                    help="instead: the grid built with each h / median R and the pass "
                         "gathered with it (sorted), interleaved")
    ap.add_argument("--splat", action="store_true",
                    help="instead: the pass's photons traced again, deposit-then-gather "
                         "against splatting each bounce's deposits in the trace, interleaved")
    ap.add_argument("--count-runs", action="store_true",
                    help="instead: the count pass by runs against photon by photon, "
                         "alternating")
    a = ap.parse_args(argv)
    THREADS[:] = a.threads
    print(f"load average {os.getloadavg()[0]:.1f}, numba threads {numba.get_num_threads()}")
    for wh in a.res:
        w, h = (int(x) for x in wh.split("x"))
        builds = []
        r, calls = capture(w, h, a.photons, builds=builds)
        if a.splat:
            run_splat(wh, r, calls, a.repeat)
        elif a.count_runs:
            run_count_runs(wh, calls, a.repeat)
        elif a.cell_factors:
            run_cells(wh, builds[-1], calls, a.cell_factors, a.repeat)
        else:
            run_res(wh, calls, a.repeat)
        del r, calls


def _part_clock(T):
    """Wrap the kernels whose process CPU is reported on their own."""
    undo = []
    for mod, name in ((Hg, "_sorted_photons"), (Hg, "_count_parallel"), (Hg, "_count_serial"),
                      (sys.modules[__name__], "_direct_parallel")):
        f = getattr(mod, name)

        def g(*a, _f=f, _n=name, **k):
            c0 = time.process_time()
            try:
                return _f(*a, **k)
            finally:
                T[_n] = T.get(_n, 0.0) + time.process_time() - c0
        setattr(mod, name, g)
        undo.append((mod, name, f))
    return undo


def run_res(wh, calls, repeat):
    grid = calls[0][0]
    K = grid.K
    sectors = calls[0][2]["buffers"].with_sectors
    clip = calls[0][2].get("clip")
    variants = [(m, t) for t in THREADS for m in ("sorted", "direct")]
    bufs = {f"{m}/{t}": Hg.GatherBuffers(K, sectors) for m, t in variants}
    for b in bufs.values():
        b.kept = KeptBuffers()          # as PhotonPass: the sort's arrays reused
    n_ph = sum(c[1][0].shape[0] for c in calls)
    print(f"  {wh}: {len(calls)} chunks, {n_ph:,} deposits, {grid.summary()}, "
          f"sectors {sectors}, clip {clip is not None}")
    cpu = {k: [] for k in bufs}
    parts = []
    sums = {}
    ALBEDO[0] = np.full((K, 3), 0.8, np.float32)
    T = {}
    undo = _part_clock(T)
    try:
        for rep in range(repeat + 1):
            T.clear()
            for name, buf in bufs.items():
                numba.set_num_threads(int(name.split("/")[1]))
                M = np.zeros(K, np.int64)
                Phi = np.zeros((K, 3))
                rmin = np.full(K, np.inf)
                S = np.zeros((K, Hg.SECTOR_CELLS), np.int64) if sectors else None
                c0 = time.process_time()
                for grid_, args, kw in calls:
                    kw = dict(kw, buffers=buf)
                    if name.startswith("sorted"):
                        g = Hg.gather(grid_, *args, **kw)
                    else:
                        g = gather_direct(grid_, *args, **kw)
                    f0 = time.process_time()
                    buf.fold(M, Phi, ALBEDO[0], np.pi, rmin, None, S, kw.get("clip"))
                    T["fold " + name] = T.get("fold " + name, 0.0) + time.process_time() - f0
                    for k_ in ("_sorted_photons", "_count_parallel", "_count_serial", "_direct_parallel"):
                        if k_ in T:
                            T[f"{k_} {name}"] = T.get(f"{k_} {name}", 0.0) + T.pop(k_)
                    _ = g.pair_vp.size
                c = time.process_time() - c0
                if rep:
                    cpu[name].append(c)
                sums[name] = (M, Phi, rmin, S)
            if rep:
                parts.append(dict(T))
    finally:
        for mod, name, f in undo:
            setattr(mod, name, f)
        numba.set_num_threads(THREADS[0])
    a, b = sums[f"sorted/{THREADS[0]}"], sums[f"direct/{THREADS[0]}"]
    dM = int(np.abs(a[0] - b[0]).max())
    fin = np.isfinite(a[2])
    dr = bool(np.array_equal(a[2], b[2]))
    dS = 0 if a[3] is None else int(np.abs(a[3] - b[3]).max())
    rel = np.abs(a[1] - b[1]).max() / max(np.abs(a[1]).max(), 1e-300)
    for k, v in cpu.items():
        print(f"    {k}: gather + fold CPU min {min(v) * 1e3:.1f} ms, median "
              f"{np.median(v) * 1e3:.1f} ms (a pass)")
    print("    parts, min / median a pass: " + ", ".join(
        f"{k} {min(p[k] for p in parts) * 1e3:.1f} / "
        f"{np.median([p[k] for p in parts]) * 1e3:.1f} ms" for k in parts[0]))
    for t in THREADS:
        d_, s_ = cpu[f"direct/{t}"], cpu[f"sorted/{t}"]
        print(f"    {t} threads: direct / sorted: min {min(d_) / min(s_):.3f}, median "
              f"{np.median(d_) / np.median(s_):.3f}, rounds "
              + " ".join(f"{x / y:.2f}" for x, y in zip(d_, s_)))
    print(f"    {THREADS[0]} threads: max |dM| {dM}, max |dS| {dS}, rmin equal {dr} ({fin.sum()} finite), "
          f"max |dPhi| / max |Phi| {rel:.2e}; load average {os.getloadavg()[0]:.1f}")


ALBEDO = [None]
THREADS = [2]


def run_cells(wh, build, calls, factors, repeat):
    """The pass's grid built with each cell factor and its chunks gathered
    (hashgrid.gather, sorted) and folded with it, the factors interleaved:
    CPU (process clock) of the build and of the gather + fold, and per
    deposit the candidates tested (entries of its slot) and the hits."""
    (bargs, bkw) = build
    K = calls[0][0].K
    sectors = calls[0][2]["buffers"].with_sectors
    ALBEDO[0] = np.full((K, 3), 0.8, np.float32)
    kb = {f: KeptBuffers() for f in factors}
    gb = {f: Hg.GatherBuffers(K, sectors) for f in factors}
    for b in gb.values():
        b.kept = KeptBuffers()
    t_build = {f: [] for f in factors}
    t_gather = {f: [] for f in factors}
    stats, sums = {}, {}
    for rep in range(repeat + 1):
        for f in factors:
            c0 = time.process_time()
            grid = Hg.build_grid(*bargs, **dict(bkw, cell_factor=f), buffers=kb[f])
            c1 = time.process_time()
            M = np.zeros(K, np.int64)
            Phi = np.zeros((K, 3))
            rmin = np.full(K, np.inf)
            S = np.zeros((K, Hg.SECTOR_CELLS), np.int64) if sectors else None
            for _, args, kw in calls:
                kw = dict(kw, buffers=gb[f])
                Hg.gather(grid, *args, **kw)
                gb[f].fold(M, Phi, ALBEDO[0], np.pi, rmin, None, S, kw.get("clip"))
            c2 = time.process_time()
            if rep:
                t_build[f].append(c1 - c0)
                t_gather[f].append(c2 - c1)
            if f not in stats:
                cand = dep = 0
                for _, args, kw in calls:
                    ps = np.empty(args[0].shape[0], np.int64)
                    Hg._photon_slots(0, ps.shape[0], np.ascontiguousarray(args[0]), grid.origin,
                                     grid.inv_h, grid.lo, grid.hi, grid.dense,
                                     int(grid.dims[0]), int(grid.dims[1]), int(grid.dims[2]),
                                     0 if grid.dense else 64 - grid.log2_table,
                                     grid.cell_start, ps)
                    cs = grid.cell_start.astype(np.int64)
                    s = ps[ps >= 0]
                    cand += int((cs[s + 1] - cs[s]).sum())
                    dep += ps.shape[0]
                stats[f] = (grid, cand / dep, int(M.sum()) / dep, dep)
            sums[f] = (M, Phi, rmin, S)
    print(f"  {wh}: {len(calls)} chunks, {stats[factors[0]][3]:,} deposits, "
          f"{K:,} visible points")
    f0 = factors[0]
    for f in factors:
        grid, cand, hits, _ = stats[f]
        a, b = sums[f0], sums[f]
        same = (np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2])
                and (a[3] is None or np.array_equal(a[3], b[3])))
        rel = np.abs(a[1] - b[1]).max() / max(np.abs(a[1]).max(), 1e-300)
        print(f"    h = {f:g} R: {grid.summary()}; a deposit: {cand:.1f} candidates, "
              f"{hits:.2f} hits; build CPU min / median {min(t_build[f]) * 1e3:.1f} / "
              f"{np.median(t_build[f]) * 1e3:.1f} ms, gather + fold "
              f"{min(t_gather[f]) * 1e3:.1f} / {np.median(t_gather[f]) * 1e3:.1f} ms, "
              f"sum {min(np.add(t_build[f], t_gather[f])) * 1e3:.1f} / "
              f"{np.median(np.add(t_build[f], t_gather[f])) * 1e3:.1f} ms; "
              f"M, S, rmin as h = {f0:g} R: {same}, max |dPhi| / max |Phi| {rel:.1e}")
    print(f"    load average {os.getloadavg()[0]:.1f}")


# ---------------------------------------------------------------------------
# The count pass by runs against photon by photon
# ---------------------------------------------------------------------------

@njit(cache=True, parallel=True)
def _count_by_photon_parallel(slot, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_rec,
                              vp_clip, cos_ng, cell_start, vp_ids, M, Phi, rmin, hitmask,
                              n_pair, n_freq, S, touched, n_touched, n_chunks):
    """hashgrid._count_parallel with the photon-by-photon count pass."""
    n = slot.shape[0]
    for c in prange(n_chunks):
        count_photon_by_photon(c * n // n_chunks, (c + 1) * n // n_chunks, slot, ph_pos,
                               ph_ng, ph_wi, ph_power, ph_rpred, vp_rec, vp_clip, cos_ng,
                               cell_start, vp_ids, M[c], Phi[c], rmin[c], hitmask, n_pair,
                               n_freq, S[c], touched[c], n_touched[c:c + 1])


def run_count_runs(wh, calls, repeat):
    """--count-runs: gather + fold of the pass's chunks with hashgrid's count
    pass ("runs") and the photon-by-photon one ("photon"), alternating (the
    order swapped each round); CPU of the whole and of the count pass."""
    grid = calls[0][0]
    K = grid.K
    sectors = calls[0][2]["buffers"].with_sectors
    clip = calls[0][2].get("clip")
    n_ph = sum(c[1][0].shape[0] for c in calls)
    print(f"  {wh}: {len(calls)} chunks, {n_ph:,} deposits, {grid.summary()}, "
          f"sectors {sectors}, clip {clip is not None}")
    kernels = {"photon": _count_by_photon_parallel, "runs": Hg._count_parallel}
    bufs = {k: Hg.GatherBuffers(K, sectors) for k in kernels}
    for b in bufs.values():
        b.kept = KeptBuffers()
    alb = np.full((K, 3), 0.8, np.float32)
    cpu = {k: [] for k in kernels}
    cnt = {k: [] for k in kernels}
    out = {}
    T = [0.0]
    kept = Hg._count_parallel
    try:
        for rep in range(repeat + 1):
            for name in (("photon", "runs") if rep % 2 == 0 else ("runs", "photon")):
                f = kernels[name]

                def timed(*a, _f=f):
                    c0 = time.process_time()
                    try:
                        return _f(*a)
                    finally:
                        T[0] += time.process_time() - c0
                Hg._count_parallel = timed
                b = bufs[name]
                M = np.zeros(K, np.int64)
                Phi = np.zeros((K, 3))
                rmin = np.full(K, np.inf)
                S = np.zeros((K, Hg.SECTOR_CELLS), np.int64) if sectors else None
                pairs = []
                T[0] = 0.0
                c0 = time.process_time()
                for grid_, args, kw in calls:
                    g = Hg.gather(grid_, *args, **dict(kw, buffers=b))
                    b.fold(M, Phi, alb, np.pi, rmin, None, S, kw.get("clip"))
                    pairs.append((g.pair_vp.copy(), g.pair_ph.copy()))
                c = time.process_time() - c0
                if rep:
                    cpu[name].append(c)
                    cnt[name].append(T[0])
                out[name] = (M, Phi, rmin, S, pairs)
    finally:
        Hg._count_parallel = kept
    a, b = out["photon"], out["runs"]
    same = (all(np.array_equal(x, y) for x, y in zip(a[:3], b[:3]))
            and (a[3] is None or np.array_equal(a[3], b[3]))
            and all(np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1])
                    for x, y in zip(a[4], b[4])))
    for k in kernels:
        print(f"    {k}: gather + fold CPU min {min(cpu[k]) * 1e3:.1f} / median "
              f"{np.median(cpu[k]) * 1e3:.1f} ms, of it the count pass min "
              f"{min(cnt[k]) * 1e3:.1f} / median {np.median(cnt[k]) * 1e3:.1f} ms (a pass)")
    r_all = [x / y for x, y in zip(cpu["runs"], cpu["photon"])]
    r_cnt = [x / y for x, y in zip(cnt["runs"], cnt["photon"])]
    print(f"    runs / photon, medians of the rounds' ratios: gather + fold {np.median(r_all):.3f}, "
          f"count pass {np.median(r_cnt):.3f}; rounds (count) "
          + " ".join(f"{x:.2f}" for x in r_cnt))
    print(f"    M, Phi, rmin, sectors, pairs the same bits: {same}; "
          f"load average {os.getloadavg()[0]:.1f}")


# ---------------------------------------------------------------------------
# The trace-order gather
# ---------------------------------------------------------------------------

@njit(cache=True)
def _direct_range(p0, p1, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, origin, inv_h, lo, hi,
                  dense, nx, ny, nz, shift, vp_rec, vp_clip, cos_ng, cell_start, vp_ids,
                  M, Phi, rmin, ps, hitmask, n_pair, n_freq, S, touched, n_touched):
    """Deposits p0..p1-1 in trace order: their slots (hashgrid._photon_slots),
    then hashgrid's count pass on each run of deposits that have a slot (its
    body, in trace order, photon by photon: run_min 65)."""
    Hg._photon_slots(p0, p1, ph_pos, origin, inv_h, lo, hi, dense, nx, ny, nz, shift,
                     cell_start, ps)
    p = p0
    while p < p1:
        if ps[p] < 0:
            hitmask[p] = 0
            n_pair[p] = 0
            n_freq[p] = 0
            p += 1
            continue
        q = p
        while q < p1 and ps[q] >= 0:
            q += 1
        Hg._count_range(p, q, ps, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_rec, vp_clip,
                        cos_ng, cell_start, vp_ids, M, Phi, rmin, hitmask, n_pair, n_freq, S,
                        touched, n_touched, 65)
        p = q


@njit(cache=True, parallel=True)
def _direct_parallel(ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, origin, inv_h, lo, hi,
                     dense, nx, ny, nz, shift, vp_rec, vp_clip, cos_ng, cell_start, vp_ids,
                     M, Phi, rmin, ps, hitmask, n_pair, n_freq, S, touched, n_touched, n_chunks):
    n = ph_pos.shape[0]
    for c in prange(n_chunks):
        _direct_range(c * n // n_chunks, (c + 1) * n // n_chunks, ph_pos, ph_ng, ph_wi,
                      ph_power, ph_rpred, origin, inv_h, lo, hi, dense, nx, ny, nz, shift,
                      vp_rec, vp_clip, cos_ng, cell_start, vp_ids, M[c], Phi[c], rmin[c], ps,
                      hitmask, n_pair, n_freq, S[c], touched[c], n_touched[c:c + 1])


_KEEP = {}


def gather_direct(grid, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_pos, vp_ng, vp_R2,
                  vp_const, cos_ng=Hg.COS_NG_DEFAULT, want_freq_pairs=False, buffers=None,
                  clip=None):
    """hashgrid.gather(..., buffers=) in trace order (pairs not written: the
    Cornell box has none; their counts are)."""
    P, K, ph, vp = Hg._prepare(ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_pos, vp_ng,
                               vp_R2, vp_const)
    T = numba.get_num_threads()
    b = buffers
    b.bind(grid, vp, T)
    if P > _KEEP.get("P", 0):
        _KEEP.update(P=P, ps=np.empty(P, np.int64), hitmask=np.empty(P, np.uint64),
                     n_pair=np.empty(P, np.int32), n_freq=np.empty(P, np.int32))
    ps, hitmask, n_pair, n_freq = (_KEEP[k][:P] for k in ("ps", "hitmask", "n_pair", "n_freq"))
    b.n_used = max(b.n_used, T) if b.n_touched.any() else T
    vp_clip = (np.zeros(0, np.uint64) if clip is None
               else np.ascontiguousarray(clip, np.uint64).reshape(K))
    _direct_parallel(*ph, grid.origin, grid.inv_h, grid.lo, grid.hi, grid.dense,
                     int(grid.dims[0]), int(grid.dims[1]), int(grid.dims[2]),
                     0 if grid.dense else 64 - grid.log2_table, b.vp_rec, vp_clip,
                     float(cos_ng), grid.cell_start, grid.vp_ids, b.M, b.Phi, b.rmin, ps,
                     hitmask, n_pair, n_freq, b.S, b.touched, b.n_touched, T)
    n_pairs = int(n_pair.sum())
    e = np.zeros(n_pairs, np.int32)
    return Hg.GatherResult(None, None, e, e, None)


# ---------------------------------------------------------------------------
# Splatting at deposit time, inside the trace (pbrt-v4's SPPM)

@njit(cache=True, nogil=True)
def _splat_rows(d0, d1, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, origin, inv_h, lo, hi,
                dense, nx, ny, nz, shift, vp_rec, vp_clip, cos_ng, cell_start, vp_ids,
                M, Phi, rmin, ps, hitmask, n_pair, n_freq, S, touched, n_touched):
    """One bounce's deposit rows d0..d1-1, gathered in the tracing thread that
    just wrote them (GIL released), into that thread's accumulator row."""
    _direct_range(d0, d1, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, origin, inv_h, lo, hi,
                  dense, nx, ny, nz, shift, vp_rec, vp_clip, cos_ng, cell_start, vp_ids,
                  M, Phi, rmin, ps, hitmask, n_pair, n_freq, S, touched, n_touched)


class Splat:
    """Wraps the photon tracer so that each bounce's deposits are gathered
    right after the bounce kernel wrote them (``_splat_rows``), in the tracing
    thread, into its own row of a GatherBuffers (a row per half being traced,
    taken in ``_trace_part``): no sort, no second pass over the chunk's
    deposits.  The deposits are still written (frequency photons, pairs and
    light tracing read them): not storing them was measured at ~1 ns of a
    ray's 69 ns in the bounce kernel (docs/architecture.md "Photon trace
    against raw Embree")."""

    def __init__(self, tracer, grid, vp, buf, clip, cos_ng):
        import threading
        from core.sppm import photon_kernels as PK
        self.PK, self.tracer, self.grid, self.buf = PK, tracer, grid, buf
        K = grid.K
        self.vp_clip = (np.zeros(0, np.uint64) if clip is None
                        else np.ascontiguousarray(clip, np.uint64).reshape(K))
        self.cos_ng = float(cos_ng)
        self.local = threading.local()
        self.lock = threading.Lock()
        self.free = [0, 1]
        self.scratch = [None, None]
        buf.bind(grid, vp, 2)
        self.bounce = PK.bounce_kernel
        self.trace_part = tracer._trace_part

    def __enter__(self):
        sp = self

        def trace_part(*a, **k):
            with sp.lock:
                row = sp.free.pop(0)
            sp.local.row = row
            try:
                return sp.trace_part(*a, **k)
            finally:
                with sp.lock:
                    sp.free.append(row)
                    sp.free.sort()

        def bounce(step, hits, live, tris, fmat, u, dep, *rest):
            out = sp.bounce(step, hits, live, tris, fmat, u, dep, *rest)
            sp.splat(dep, step.dep0, out[1])
            return out
        self.tracer._trace_part = trace_part
        self.PK.bounce_kernel = bounce
        self.buf.n_used = 2
        return self

    def __exit__(self, *exc):
        del self.tracer._trace_part
        self.PK.bounce_kernel = self.bounce

    def splat(self, dep, d0, d1):
        if d1 <= d0:
            return
        c = self.local.row
        cap = dep.r.shape[0]
        sc = self.scratch[c]
        if sc is None or sc[0].shape[0] < cap:
            sc = self.scratch[c] = (np.empty(cap, np.int64), np.empty(cap, np.uint64),
                                    np.empty(cap, np.int32), np.empty(cap, np.int32))
        g, b = self.grid, self.buf
        _splat_rows(d0, d1, dep.p, dep.ng, dep.wi, dep.power, dep.r, g.origin, g.inv_h, g.lo,
                    g.hi, g.dense, int(g.dims[0]), int(g.dims[1]), int(g.dims[2]),
                    0 if g.dense else 64 - g.log2_table, b.vp_rec, self.vp_clip, self.cos_ng,
                    g.cell_start, g.vp_ids, b.M[c], b.Phi[c], b.rmin[c], *sc[:1], *sc[1:],
                    b.S[c], b.touched[c], b.n_touched[c:c + 1])

    def nbytes(self):
        return sum(a.nbytes for sc in self.scratch if sc is not None for a in sc)


def run_splat(wh, r, calls, repeat, seed=12345):
    """The pass's photons traced again (the same chunks and seeds in both),
    interleaved: trace then hashgrid.gather (sorted) and fold, as a pass
    does, against the trace with each bounce's deposits splatted into the
    grid in the tracing threads (Splat) and the same fold.  Photon threads:
    photons.THREADS; the gather's: numba's."""
    from core.sppm import photons as Ph
    grid, args0, kw0 = calls[0]
    K = grid.K
    sectors = kw0["buffers"].with_sectors
    clip = kw0.get("clip")
    cos_ng = kw0.get("cos_ng", Hg.COS_NG_DEFAULT)
    vp_args = args0[5:9]
    _, _, _, vp = Hg._prepare(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)),
                              np.zeros((1, 3)), np.zeros(1), *vp_args)
    pp = r.photon_pass
    tracer = pp.tracer
    chunks = [(n, 0) for n, _ in pp.chunks()]
    ALBEDO[0] = np.full((K, 3), 0.8, np.float32)
    bufA = Hg.GatherBuffers(K, sectors)
    bufA.kept = KeptBuffers()
    bufB = Hg.GatherBuffers(K, sectors, threads=2)
    names = ("deposit, sort, gather", "splat in the trace")
    cpu = {k: [] for k in names}
    trace_cpu = {k: [] for k in names}
    sums = {}
    n_dep = 0
    print(f"  {wh}: {len(chunks)} chunks {[c[0] for c in chunks]}, {K:,} visible points, "
          f"{grid.summary()}, photon threads {Ph.THREADS}, numba threads "
          f"{numba.get_num_threads()}")
    sp = None
    for rep in range(repeat + 1):
        for name in (names if rep % 2 == 0 else names[::-1]):
            M = np.zeros(K, np.int64)
            Phi = np.zeros((K, 3))
            rmin = np.full(K, np.inf)
            S = np.zeros((K, Hg.SECTOR_CELLS), np.int64) if sectors else None
            tc = 0.0
            c0 = time.process_time()
            for c, (n, _) in enumerate(chunks):
                rng = np.random.default_rng([seed, c])
                if name == names[0]:
                    t0 = time.process_time()
                    dep = tracer.trace(n, 0, rng)
                    tc += time.process_time() - t0
                    n_dep += dep["p"].shape[0] if rep == 0 else 0
                    Hg.gather(grid, dep["p"], dep["ng"], dep["wi"], dep["power"], dep["rpred"],
                              *vp_args, cos_ng=cos_ng, buffers=bufA, clip=clip)
                    bufA.fold(M, Phi, ALBEDO[0], np.pi, rmin, None, S, clip)
                else:
                    sp = Splat(tracer, grid, vp, bufB, clip, cos_ng)
                    t0 = time.process_time()
                    with sp:
                        dep = tracer.trace(n, 0, rng)
                    tc += time.process_time() - t0
                    bufB.fold(M, Phi, ALBEDO[0], np.pi, rmin, None, S, clip)
                del dep
            cc = time.process_time() - c0
            if rep:
                cpu[name].append(cc)
                trace_cpu[name].append(tc)
            sums[name] = (M, Phi, rmin, S)
    a, b = sums[names[0]], sums[names[1]]
    rel = np.abs(a[1] - b[1]).max() / max(np.abs(a[1]).max(), 1e-300)
    dS = 0 if a[3] is None else int(np.abs(a[3] - b[3]).max())
    srt = bufA.kept._bufs.get("gather_sort")
    print(f"    {n_dep:,} deposits a pass; the gather's sort buffer "
          f"{0 if srt is None else srt.nbytes / 2**20:.0f} MiB (kept; not needed by the "
          f"splat), the splat's per-thread scratch {sp.nbytes() / 2**20:.0f} MiB")
    for k in names:
        print(f"    {k}: CPU a pass min {min(cpu[k]) * 1e3:.1f} / median "
              f"{np.median(cpu[k]) * 1e3:.1f} ms; of it in the trace call "
              f"{min(trace_cpu[k]) * 1e3:.1f} / {np.median(trace_cpu[k]) * 1e3:.1f} ms")
    x, y = cpu[names[1]], cpu[names[0]]
    print(f"    splat / deposit-then-gather: min {min(x) / min(y):.3f}, median "
          f"{np.median(x) / np.median(y):.3f}, rounds " + " ".join(
              f"{p / q:.2f}" for p, q in zip(x, y)))
    print(f"    max |dM| {int(np.abs(a[0] - b[0]).max())}, max |dS| {dS}, rmin equal "
          f"{bool(np.array_equal(a[2], b[2]))}, max |dPhi| / max |Phi| {rel:.2e}; "
          f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
