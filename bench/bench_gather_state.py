"""The gather of a captured pass of an example scene, with the radii a method really has.

    .venv/bin/python bench/bench_gather_state.py cornell --method fppm --after 20 [--stats]
    .venv/bin/python bench/bench_gather_state.py cornell --method fppm --after 20 \
        --ref OLD_HASHGRID.py [--repeat 10]
        (OLD_HASHGRID.py: another core/sppm/hashgrid.py, e.g.
        ``git show a5ae631:core/sppm/hashgrid.py > /tmp/hashgrid_a5ae631.py``)

The export and the protocol of bench/bench_pass_stages.py (the .blend at 100 %,
its photons, seed 0, one numba and one tracing thread, the trace-ahead off):
the method (tools/converge/runs.py METHOD_SETTINGS) renders --after passes,
then every ``hashgrid.gather`` call of the next pass is captured (the grid,
the deposits, the visible points with their radii, the packed clips, the
sector flag) with the fold's arguments.  FPPM's grown and held radii gather
several times PPM's photon-pixel pairs (docs/method.md "Round 20: the Cornell
box's first passes on an idle machine"); bench/bench_gather_order.py's
capture is of bench_render's box with PPM's radii.

--stats: the radii's spread against the cell size, and a deposit's
candidates (entries of its slot), its photons within the radius (rule (1))
and its counted pairs.

--ref FILE: the captured chunks gathered (``gather(..., buffers=)``) and
folded with this tree's ``hashgrid`` and with FILE's, alternating (the order
swapped each round), a 64-MiB array written before each chunk so that the
gather starts from caches a photon trace has flushed, as in a pass (with
warm caches a change of the count pass's memory traffic does not show:
docs/architecture.md "The gather's sector cells, round 21"); CPU (process
clock) of gather + fold, min / median, the median of the rounds' ratios,
and whether the sums (M, Phi, smallest radii, sector counts) are the same
bits.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time

if "numba" not in sys.modules:
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from bench_hold_alpha import export, method_settings, radii_variant, settle  # noqa: E402
from fppm.core import render as R  # noqa: E402
from fppm.core.kept import KeptBuffers  # noqa: E402
from fppm.core.render import Renderer  # noqa: E402
from fppm.core.sppm import hashgrid as Hg, photon_pass  # noqa: E402

FLUSH_BYTES = 64 << 20


def capture(scene, base, method, after, seed=0):
    """[(grid, gather args, gather kwargs without buffers, fold args)] of
    pass after + 1 of method."""
    photon_pass.TRACE_AHEAD = False
    R.DIRECT_BESIDE_SETUP = False
    r = Renderer(scene, method_settings(base, method).replace(seed=seed, max_passes=after + 1),
                 log=lambda s: None)
    radii_variant(r, method)
    for _ in range(after):
        r.step()
        settle(r)
    calls = []
    g0, f0 = Hg.gather, Hg.GatherBuffers.fold

    def g(grid, *a, **k):
        kw = {x: v for x, v in k.items() if x != "buffers"}
        kw["sectors"] = k["buffers"].with_sectors
        calls.append([grid, [np.array(x, copy=True) if isinstance(x, np.ndarray) else x
                             for x in a], kw, None])
        return g0(grid, *a, **k)

    def f(self, M, Phi, phi_scale, phi_div, rmin, rmin_mask=None, S=None, clip=None):
        calls[-1][3] = (np.array(phi_scale, copy=True), phi_div,
                        None if rmin_mask is None else rmin_mask.copy())
        return f0(self, M, Phi, phi_scale, phi_div, rmin, rmin_mask, S, clip)
    Hg.gather, Hg.GatherBuffers.fold = g, f
    try:
        r.step()
        settle(r)
    finally:
        Hg.gather, Hg.GatherBuffers.fold = g0, f0
    return calls


def stats(calls):
    grid, a = calls[0][0], calls[0][1]
    R2 = a[7]
    Ract = np.sqrt(R2[R2 > 0])
    q = np.percentile(Ract, [5, 25, 50, 75, 95, 100])
    print(f"  {grid.summary()}; radii [m] 5/25/50/75/95/100 %: "
          + " ".join(f"{x:.4f}" for x in q) + f" (h = {grid.h / np.median(Ract):.2f} x median)")
    cand = near = pairs = dep = 0
    cs = grid.cell_start.astype(np.int64)
    for g_, a, kw, _ in calls:
        pos = np.ascontiguousarray(a[0])
        ps = np.empty(pos.shape[0], np.int64)
        Hg._photon_slots(0, ps.shape[0], pos, grid.origin, grid.inv_h, grid.lo, grid.hi,
                         grid.dense, int(grid.dims[0]), int(grid.dims[1]), int(grid.dims[2]),
                         0 if grid.dense else 64 - grid.log2_table, grid.cell_start, ps)
        inside = np.flatnonzero(ps >= 0)
        cand += int((cs[ps[inside] + 1] - cs[ps[inside]]).sum())
        for p in inside:
            vs = grid.vp_ids[cs[ps[p]]:cs[ps[p] + 1]]
            near += int((((a[5][vs] - pos[p]) ** 2).sum(axis=1) < R2[vs]).sum())
        pairs += int(Hg.gather(g_, *a, **kw).M.sum())
        dep += pos.shape[0]
    print(f"  {len(calls)} chunks, {dep:,} deposits; a deposit: {cand / dep:.2f} candidates, "
          f"{near / dep:.2f} within the radius, {pairs / dep:.2f} counted; {pairs:,} pairs")


def load_ref(path):
    """FILE as the module fppm.core.sppm._hashgrid_ref (its relative imports
    are hashgrid's)."""
    name = "fppm.core.sppm._hashgrid_ref"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def compare(calls, ref, repeat):
    grid = calls[0][0]
    K, sect = grid.K, calls[0][2]["sectors"]
    mods = {"this tree": Hg, "ref": ref}
    bufs = {}
    for k, H in mods.items():
        bufs[k] = H.GatherBuffers(K, sect)
        bufs[k].kept = KeptBuffers()
    flush = np.zeros(FLUSH_BYTES // 8)
    cpu = {k: [] for k in mods}
    out = {}
    names = list(mods)
    for rep in range(repeat + 1):
        for k in (names if rep % 2 else names[::-1]):
            H, b = mods[k], bufs[k]
            M, Phi, rmin = np.zeros(K), np.zeros((K, 3)), np.full(K, np.inf)
            S = np.zeros((K, Hg.SECTOR_CELLS)) if sect else None
            t = 0.0
            for g_, a, kw, fo in calls:
                flush += 1.0
                kw = {x: v for x, v in kw.items() if x != "sectors"}
                c0 = time.process_time()
                H.gather(g_, *a, buffers=b, **kw)
                b.fold(M, Phi, fo[0], fo[1], rmin, fo[2], S, kw.get("clip"))
                t += time.process_time() - c0
            if rep:
                cpu[k].append(t)
            out[k] = (M, Phi, rmin, S)
    same = all(x is None or x.tobytes() == y.tobytes()
               for x, y in zip(out["this tree"], out["ref"]))
    for k in names:
        print(f"  {k}: gather + fold CPU min {min(cpu[k]) * 1e3:.1f} ms, median "
              f"{np.median(cpu[k]) * 1e3:.1f} ms (a pass)")
    r = np.divide(cpu["this tree"], cpu["ref"])
    print(f"  this tree / ref: min {min(cpu['this tree']) / min(cpu['ref']):.3f}, median of "
          f"the rounds' ratios {np.median(r):.3f}; sums the same bits: {same}; "
          f"load average {os.getloadavg()[0]:.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("--method", default="fppm")
    ap.add_argument("--after", type=int, default=20, help="passes rendered before the capture")
    ap.add_argument("--percent", type=int, default=100)
    ap.add_argument("--stats", action="store_true")
    ap.add_argument("--ref", default="", help="another core/sppm/hashgrid.py to compare with")
    ap.add_argument("--repeat", type=int, default=10)
    a = ap.parse_args(argv)
    scene, base = export(a.scene, a.percent)
    calls = capture(scene, base, a.method, a.after)
    print(f"{a.scene} {a.percent}%, {a.method}, pass {a.after + 1}, sectors "
          f"{calls[0][2]['sectors']}, clip {calls[0][2].get('clip') is not None}; load average "
          f"{os.getloadavg()[0]:.2f}")
    if a.stats:
        stats(calls)
    if a.ref:
        compare(calls, load_ref(a.ref), a.repeat)


if __name__ == "__main__":
    main()
