"""FPPM's pass against CPPM's (and PPM's), stage by stage, in CPU time.

    .venv/bin/python bench/bench_pass_stages.py indirect_room [--passes 100] [--seed 0]
        [--methods fppm,cppm] [--percent 100] [--photons 0] [--as-rendered]
    .venv/bin/python bench/bench_pass_stages.py principled_interior --passes 60 \
        --methods fppm,fppm:pairs=every,cppm
        (':pairs=every': the receivers' radii looked for in every chunk, the rule
        before round 16)
    .venv/bin/python bench/bench_pass_stages.py cornell --passes 25 --setup-repeat 3 \
        --ref-grid OLD_OCCLUSION_GRID.py --methods fppm,fppm:refgrid,cppm
        (':refgrid': the renderer built with another core/frequency/occlusion_grid.py's
        grid and march blocks, e.g. ``git show 93c5b51:core/frequency/occlusion_grid.py``;
        the same grid, another set-up cost: docs/method.md "FPPM's first passes on
        the Cornell box, round 17")

The methods of bench/bench_hold_alpha.py (tools/converge/runs.py METHOD_SETTINGS)
render the same export (the file's resolution and photons by default: 128x128
and 200,000 photons on the example scenes), stepped alternately in one process,
the same seed, one numba and one tracing thread, the trace-ahead and the direct
light beside the set-up off, so that every stage of a pass runs one after the
other and its process CPU (``time.process_time``: one busy thread at a time) is
its own.  Each stage is a wrapped call (inclusive CPU; ``other`` is the step's
CPU less the stages'):

- camera: the camera pass; direct: next-event estimation; init: the radii's
  initialisation; grid: ``PhotonPass.begin`` (active radii, kernel clip, hash
  grid build); trace: ``PhotonTracer.trace`` less its frequency part, freq:
  ``PhotonTracer._spectrum_at_hits`` (the march of the frequency photons,
  docs/frequency.md "Cost") and ``set_reach``; gather: ``hashgrid.gather``;
  fold: ``GatherBuffers.fold``; reflected: ``PhotonPass._reflected`` (the
  non-Lambert points' BSDF per pair); pairs: the rest of ``_add_pairs`` (the
  frequency pairs, the receivers' radii); finish; update: the radius rules
  (``Radii.predicted``, ``update``, ``leave_out_holds``); film: the film's
  accumulate and image.

Prints per method the CPU ms per pass of every stage over pass ranges
(1, 2, 3-10, 11-100 ...), the difference to the second method, and the sum
over the run; docs/method.md "FPPM's pass against CPPM's, round 16".
"""
from __future__ import annotations

import argparse
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
from fppm.core.render import Renderer  # noqa: E402
from fppm.core.sppm import hashgrid, photon_pass  # noqa: E402

STAGES = ("camera", "direct", "init", "grid", "trace", "freq", "gather", "fold", "reflected",
          "pairs", "finish", "update", "film")


class Clock:
    """Inclusive process CPU of wrapped calls, per stage, for the pass being stepped."""

    def __init__(self):
        self.now = None             # dict stage -> seconds of the step being measured

    def wrap(self, stage, fn):
        def timed(*a, **kw):
            c0 = time.process_time()
            try:
                return fn(*a, **kw)
            finally:
                if self.now is not None:
                    self.now[stage] = self.now.get(stage, 0.0) + time.process_time() - c0
        return timed


def instrument(r, clock):
    pp, tr = r.photon_pass, r.tracer
    r.camera_pass = clock.wrap("camera", r.camera_pass)
    r.direct_light = clock.wrap("direct", r.direct_light)
    r.radii.initialise = clock.wrap("init", r.radii.initialise)
    for name in ("predicted", "update", "leave_out_holds"):
        setattr(r.radii, name, clock.wrap("update", getattr(r.radii, name)))
    pp.begin = clock.wrap("grid", pp.begin)
    pp.finish = clock.wrap("finish", pp.finish)
    pp._reflected = clock.wrap("reflected", pp._reflected)
    pp._add_pairs = clock.wrap("pairs_incl", pp._add_pairs)
    tr.trace = clock.wrap("trace_incl", tr.trace)
    if hasattr(tr, "_spectrum_at_hits"):
        tr._spectrum_at_hits = clock.wrap("freq", tr._spectrum_at_hits)
    if hasattr(tr, "set_reach"):
        tr.set_reach = clock.wrap("reach", tr.set_reach)
    r.film.accumulate = clock.wrap("film", r.film.accumulate)
    r.film = _Film(r.film, clock)


class _Film:
    def __init__(self, film, clock):
        self._f, self._call = film, clock.wrap("film", film.__call__)

    def __call__(self, *a, **kw):
        return self._call(*a, **kw)

    def __getattr__(self, k):
        return getattr(self._f, k)


def _own(m):
    """(the method name without this bench's own keys, whether ':pairs=every':
    the receivers' radii looked for in every chunk, the rule before round 16)."""
    return m.replace(":pairs=every", "").replace(":refgrid", ""), ":pairs=every" in m


def ref_grid(path):
    """A context manager factory: within it, Renderer builds its occlusion
    grid and march blocks with the core/frequency/occlusion_grid.py at path
    (bench/bench_occlusion_build.py's swap)."""
    import contextlib
    import importlib.util
    from fppm.core.frequency import occlusion_grid as G, occlusion_march as Occ
    spec = importlib.util.spec_from_file_location("_occlusion_grid_ref", path)
    OG = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = OG                  # dataclasses look it up
    spec.loader.exec_module(OG)

    @contextlib.contextmanager
    def swapped():
        new = G.build_occlusion_grid, Occ.march_blocks
        G.build_occlusion_grid, Occ.march_blocks = OG.build_occlusion_grid, OG.march_blocks
        try:
            yield
        finally:
            G.build_occlusion_grid, Occ.march_blocks = new
    return swapped


def pairs_every(r):
    """The rule before: PhotonPass._add_pairs called without the chunk's
    frequency photons, so the receivers' NaN test runs in every chunk."""
    add = r.photon_pass._add_pairs
    r.photon_pass._add_pairs = lambda vp, dep, g, acc, clip=None, n_freq=None: add(
        vp, dep, g, acc, clip)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--passes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--methods", default="fppm,cppm")
    ap.add_argument("--percent", type=int, default=100)
    ap.add_argument("--photons", type=int, default=0, help="0: the file's")
    ap.add_argument("--ranges", default="1,2,3-10,11-40,41-100,101-200")
    ap.add_argument("--as-rendered", action="store_true",
                    help="the renderer as it renders (trace-ahead, direct light beside the "
                         "set-up, the threads of NUMBA_NUM_THREADS / FPPM_PHOTON_THREADS): each "
                         "step's settled process CPU only, no stages (set the two variables "
                         "to 2 for the convergence rows' threads)")
    ap.add_argument("--setup-repeat", type=int, default=1,
                    help="build every method's renderer this many times, interleaved (the "
                         "set-up's min / median; the last one is stepped)")
    ap.add_argument("--ref-grid", default="",
                    help="another core/frequency/occlusion_grid.py for the methods "
                         "with ':refgrid'")
    a = ap.parse_args()
    import contextlib
    swapped = ref_grid(a.ref_grid) if a.ref_grid else None
    if not a.as_rendered:
        photon_pass.TRACE_AHEAD = False
        R.DIRECT_BESIDE_SETUP = False
    scene, base = export(a.scene, a.percent)
    if a.photons:
        base = base.replace(photons_per_pass=a.photons)
    methods = a.methods.split(",")
    clock = Clock()
    gather, fold = hashgrid.gather, hashgrid.GatherBuffers.fold
    if not a.as_rendered:
        hashgrid.gather = clock.wrap("gather", gather)
        hashgrid.GatherBuffers.fold = clock.wrap("fold", fold)
    for m in methods:                       # warm-up: the kernels load or compile
        with (swapped() if ":refgrid" in m else contextlib.nullcontext()):
            w = Renderer(scene, method_settings(base, _own(m)[0]).replace(
                seed=a.seed, max_passes=4, photons_per_pass=2000), log=lambda s: None)
        radii_variant(w, _own(m)[0])
        for _ in range(4):
            w.step()
    rs, setup, setups = {}, {}, {m: [] for m in methods}
    for rep in range(a.setup_repeat):
        for m in methods:
            rs[m] = None
            with (swapped() if ":refgrid" in m else contextlib.nullcontext()):
                c0 = time.process_time()
                rs[m] = Renderer(scene, method_settings(base, _own(m)[0]).replace(
                    seed=a.seed, max_passes=a.passes), log=lambda s: None)
                setups[m].append(time.process_time() - c0)
    for m in methods:
        setup[m] = setups[m][-1]
        radii_variant(rs[m], _own(m)[0])
        if _own(m)[1]:
            pairs_every(rs[m])
        if not a.as_rendered:
            instrument(rs[m], clock)
    rows = {m: [] for m in methods}
    extra = {m: [] for m in methods}
    for p in range(1, a.passes + 1):
        for m in methods:
            clock.now = {}
            c0 = time.process_time()
            rs[m].step()
            settle(rs[m])
            tot = time.process_time() - c0
            d, clock.now = clock.now, None
            d["trace"] = d.pop("trace_incl", 0.0) - d.get("freq", 0.0)
            d["freq"] = d.get("freq", 0.0) + d.pop("reach", 0.0)
            d["pairs"] = d.pop("pairs_incl", 0.0) - d.get("reflected", 0.0)
            d["gather"] = d.get("gather", 0.0)
            d["other"] = tot - sum(d.get(s, 0.0) for s in STAGES)
            d["total"] = tot
            rows[m].append(d)
            st = rs[m].state
            extra[m].append((float(st.M_last.sum()), float(np.mean(st.held))
                             if getattr(st, "held", None) is not None else np.nan))
    cols = STAGES + ("other", "total")
    print(f"# {a.scene} {a.percent}% photons {rs[methods[0]].settings.photons_per_pass} "
          f"seed {a.seed}, {a.passes} passes, CPU ms per pass; load {os.getloadavg()}")
    print("# columns: " + " ".join(cols) + " | gathered/1e3 held")
    ranges = []
    for s in a.ranges.split(","):
        lo, hi = (int(x) for x in (s.split("-") if "-" in s else (s, s)))
        if lo <= a.passes:
            ranges.append((lo, min(hi, a.passes)))
    ranges.append((1, a.passes))
    for lo, hi in ranges:
        for m in methods:
            sl = rows[m][lo - 1:hi]
            v = [1e3 * np.mean([d.get(c, 0.0) for d in sl]) for c in cols]
            g = np.mean([e[0] for e in extra[m][lo - 1:hi]]) / 1e3
            print(f"passes {lo:>3}-{hi:<3} {m:>10}: " + " ".join(f"{x:7.1f}" for x in v)
                  + f" | {g:7.1f} {extra[m][hi - 1][1]:.3f}")
        if len(methods) > 1:
            m0, m1 = methods[0], methods[1]
            d = [1e3 * (np.mean([x.get(c, 0.0) for x in rows[m0][lo - 1:hi]])
                        - np.mean([x.get(c, 0.0) for x in rows[m1][lo - 1:hi]])) for c in cols]
            print(f"passes {lo:>3}-{hi:<3} {m0 + '-' + m1:>10}: " + " ".join(f"{x:+7.1f}" for x in d))
    m0 = methods[0]
    print(f"# sum over the run, s: " + "; ".join(
        f"{m} {sum(d['total'] for d in rows[m]):.2f} (set-up {setup[m]:.2f})" for m in methods)
          + f"; threads: numba {os.environ.get('NUMBA_NUM_THREADS')}, photons "
          f"{os.environ.get('FPPM_PHOTON_THREADS')}, as rendered {a.as_rendered}")
    print("# set-up s, min / median of " + str(a.setup_repeat) + ": " + "; ".join(
        f"{m} {min(setups[m]):.3f} / {np.median(setups[m]):.3f}" for m in methods))
    last = methods[-1]
    for hi in sorted({2, a.passes}):
        tot = {m: float(np.median(setups[m])) + sum(d["total"] for d in rows[m][:hi])
               for m in methods}
        print(f"# set-up (median) + passes 1-{hi}, s: " + "; ".join(
            f"{m} {tot[m]:.3f} ({tot[m] / tot[last]:.3f}x {last})" for m in methods))
    print("# per pass totals ms: " + "; ".join(
        f"{m}: " + " ".join(f"{1e3 * d['total']:.0f}" for d in rows[m]) for m in methods))
    print("# per pass freq ms " + m0 + ": " + " ".join(f"{1e3 * d['freq']:.0f}" for d in rows[m0]))
    if not a.as_rendered:
        for c in ("trace", "gather"):
            print(f"# per pass {c} ms: " + "; ".join(
                f"{m}: " + " ".join(f"{1e3 * d[c]:.0f}" for d in rows[m]) for m in methods))


if __name__ == "__main__":
    main()
