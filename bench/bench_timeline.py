"""Where a pass's wall time has one core busy: a timeline of Renderer.step.

    .venv/bin/python bench/bench_timeline.py [--res 256x256] [--passes 8] [--photons 200000]

Cornell box (bench_render.cornell), plain photons.  Every stage of a pass
(and the calls between them) is wrapped; at each entry and exit the wrapper
reads the CPU clock of every thread of the process (clock_gettime of each
thread's CPU clock) and the process CPU clock.  The pass is thus cut
into segments (a stage, or the gap between two stages on the calling
thread) and each segment gets its wall time, its CPU time (all threads) and
its busiest thread's CPU.  On an idle 2-core machine a segment takes at
least max(busiest thread, CPU / 2) of wall; ``lost`` is 2 x that minus the
CPU: the core-seconds the segment leaves idle by its own serial work (a
lower bound, load-robust).  The photons traced ahead (their own thread)
are in the CPU of the segments they overlap, so a serial stage that
overlaps the trace is not counted as lost.  Segments shorter than the
clock read (~0.1 ms) are noise.  Sums over ``--passes`` passes after a
warm-up pass; printed a pass.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

from bench_render import cornell  # noqa: E402
from core import memory  # noqa: E402
from core.render import Renderer  # noqa: E402
from core.settings import RenderSettings  # noqa: E402
from core.sppm import clip as Clip  # noqa: E402
from core.sppm import hashgrid as Hg  # noqa: E402
from core.sppm import pass_kernels as PKs  # noqa: E402


class ThreadClocks:
    """Per-thread CPU seconds: each thread's CPU clock (clock_gettime on the
    clock id of a thread of this process, MAKE_THREAD_CPUCLOCK(tid,
    CPUCLOCK_SCHED)), exact for running threads too (schedstat lags them by
    up to a scheduler tick)."""

    def read(self) -> dict:
        out = {}
        for t in os.listdir("/proc/self/task"):
            try:
                out[t] = time.clock_gettime(((~int(t)) << 3) | 6)
            except OSError:
                pass
        return out


class Timeline:
    def __init__(self):
        self.clocks = ThreadClocks()
        self.events = []          # (label, perf_counter, process CPU, {tid: ns})
        self.on = False

    def mark(self, label):
        if self.on:
            th = self.clocks.read()        # first: a preempted read then lags the clocks
            self.events.append((label, time.perf_counter(), time.process_time(), th))

    def wrap(self, obj, name, label):
        f = getattr(obj, name)

        def g(*a, **k):
            self.mark("+" + label)
            try:
                return f(*a, **k)
            finally:
                self.mark("-" + label)
        setattr(obj, name, g)

    def segments(self):
        """(segment label, wall, CPU, busiest thread CPU) of consecutive events."""
        out = []
        ev = self.events
        for a, b in zip(ev, ev[1:]):
            if a[0] == "-step" and b[0] == "+step":
                continue                    # between passes: the bench's own
            la, lb = a[0], b[0]
            if la[0] == "+" and lb == "-" + la[1:]:
                lab = la[1:]
            elif la[0] == "+":
                lab = f"{la[1:]}: before {lb[1:]}"
            else:
                lab = f"gap {la[1:]} -> {lb[1:]}"
            dt = {t: b[3][t] - a[3].get(t, 0.0) for t in b[3]}
            out.append((lab, b[1] - a[1], b[2] - a[2], max(dt.values() or [0.0])))
        return out


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--res", default="256x256")
    ap.add_argument("--passes", type=int, default=8)
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--ahead", type=int, default=None,
                    help="photon_pass.AHEAD_CHUNKS (default: the module's)")
    ap.add_argument("--no-next", action="store_true",
                    help="photon_pass.TRACE_NEXT_PASS = False (each pass starts its own trace)")
    ap.add_argument("--min-vps", type=int, default=None,
                    help="hashgrid.PARALLEL_MIN_VPS: the grid build's (and its insertion's, "
                         "by active VPs), records' and fold's threads (default: the module's)")
    ap.add_argument("--direct-first", action="store_true",
                    help="render.DIRECT_BESIDE_SETUP = False (the direct light on two threads "
                         "before the photon pass's set-up, not beside it)")
    a = ap.parse_args()
    if a.direct_first:
        import core.render as Rd
        Rd.DIRECT_BESIDE_SETUP = False
    if a.min_vps is not None:
        Hg.PARALLEL_MIN_VPS = a.min_vps
    from core.sppm import photon_pass as PP
    if a.ahead is not None:
        PP.AHEAD_CHUNKS = a.ahead
    if a.no_next and hasattr(PP, "TRACE_NEXT_PASS"):
        PP.TRACE_NEXT_PASS = False
    w, h = (int(x) for x in a.res.split("x"))
    r = Renderer(cornell(w, height=h), RenderSettings(integrator="PHOTON", max_passes=1000,
                                                      photons_per_pass=a.photons,
                                                      use_frequency=False),
                 log=lambda s: None)
    tl = Timeline()
    pp = r.photon_pass
    nee = r.direct_light
    # the calls of Renderer.step and PhotonPass.__call__, in their order
    for obj, name, label in (
            (r, "step", "step"), (pp, "trace_ahead", "trace_ahead"),
            (r, "_interruptible", "thread"),
            (memory, "release_free_heap", "release_free_heap"), (r, "camera_pass", "camera"),
            (r, "direct_light", "direct"), (r.radii, "initialise", "radius_init"),
            (r.tracer, "set_radius_cut", "set_radius_cut"), (pp, "_zero_sums", "zero_sums"),
            (PKs, "active_radii", "active_radii"), (Clip, "clip_codes", "clip"),
            (Hg, "build_grid", "grid_build"), (pp, "_trace", "trace_wait"),
            (Hg, "gather", "gather"), (pp, "_add_pairs", "add_pairs"),
            (pp, "_drop_ahead", "drop_ahead"), (pp, "finish", "finish"),
            (r.radii, "predicted", "predicted"), (r.radii, "update", "update"),
            (r.film, "accumulate", "film_accumulate"), (r, "_film", "film")):
        tl.wrap(obj, name, label)
    # the direct light shared out beside the photon pass's set-up
    # (render.DIRECT_BESIDE_SETUP): its blocks' CPU is in the segments they
    # overlap, like the photons traced ahead; "direct" is then the blocks'
    # hand-out alone
    r.direct_light.shared = nee.shared
    tl.wrap(r.direct_light, "shared", "direct")
    r.step()                                        # warm-up
    if pp.gather_buffers is not None:               # made by the first pass
        tl.wrap(pp.gather_buffers, "fold", "fold")
    tl.on = True
    c0, w0 = time.process_time(), time.perf_counter()
    steps = []
    for _ in range(a.passes):
        s0, sc = time.perf_counter(), time.process_time()
        r.step()
        steps.append((time.perf_counter() - s0, time.process_time() - sc))
    tl.on = False
    n = a.passes
    wall = sum(s[0] for s in steps)
    cpu = sum(s[1] for s in steps)
    agg = defaultdict(lambda: [0.0, 0.0, 0.0, 0.0, 0])
    order = []
    for lab, dw, dc, bz in tl.segments():
        if lab not in agg:
            order.append(lab)
        x = agg[lab]
        x[0] += dw
        x[1] += dc
        x[2] += bz
        x[3] += max(0.0, 2 * max(bz, dc / 2) - dc)
        x[4] += 1
    idle = sum(max(x[2], x[1] / 2) for x in agg.values())
    lost = sum(x[3] for x in agg.values())
    print(f"{a.res}, {n} passes (load average {os.getloadavg()[0]:.1f}): pass wall "
          f"{wall / n * 1e3:.1f} ms, CPU {cpu / n * 1e3:.1f} ms, cores used {cpu / wall:.2f}; "
          f"idle estimate from the segments {idle / n * 1e3:.1f} ms, cores {cpu / idle:.2f}; "
          f"core-ms left idle by serial work a pass {lost / n * 1e3:.1f} "
          f"({lost / (2 * idle):.1%} of 2 x the idle wall)")
    print(f"{'segment':52s} {'wall ms':>8s} {'CPU ms':>8s} {'busiest':>8s} {'lost ms':>8s}  n")
    for lab in sorted(order, key=lambda k: -agg[k][3]):
        x = agg[lab]
        print(f"{lab[:52]:52s} {x[0] / n * 1e3:8.2f} {x[1] / n * 1e3:8.2f} "
              f"{x[2] / n * 1e3:8.2f} {x[3] / n * 1e3:8.2f}  {x[4] // n}")


if __name__ == "__main__":
    main()
