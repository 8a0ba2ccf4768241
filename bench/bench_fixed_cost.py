"""The fixed cost of frequency photons in a photon trace: what tracing n
photons of which n_freq carry a spectrum costs beyond tracing the same n
photons without (docs/frequency.md "Cost", "Frequency photons traced again").

    .venv/bin/python bench/bench_fixed_cost.py indirect_room [--photons 100000]
        [--freq 0,1,2,24,100] [--repeat 10] [--res 64] [--parts]

The .blend's scene at --res x --res (exported as ``fppm render`` does), a
renderer stepped two passes so that its tracer has a reach map and a radius
cut, then ``PhotonTracer.trace(n, n_freq)`` for every n_freq in turn
(interleaved), CPU time of the process (one numba and one tracing thread),
best (min) and median of --repeat.  --parts: CPU seconds inside each of the
tracer's functions, per trace, min over the repeats.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))


class Parts:
    """CPU seconds inside wrapped functions (module or instance attributes)."""

    def __init__(self):
        self.t = {}

    def wrap(self, obj, name, key=None):
        f = getattr(obj, name)
        key = key or name
        t = self.t
        t.setdefault(key, 0.0)

        def g(*a, **k):
            c0 = time.process_time()
            try:
                return f(*a, **k)
            finally:
                t[key] += time.process_time() - c0
        setattr(obj, name, g)

    def snapshot(self):
        return dict(self.t)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--photons", type=int, default=100_000)
    ap.add_argument("--freq", default="0,1,2,24,100")
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--parts", action="store_true")
    ap.add_argument("--variants", default="",
                    help="comma list of tracer attribute=value toggles to interleave, "
                         "e.g. 'retrace=0,retrace=1'")
    a = ap.parse_args(argv)
    from bench_render import blend_renderer
    import fppm.core.sppm.photons as Ph
    import fppm.core.sppm.photon_kernels as PK
    r = blend_renderer(os.path.join(ROOT, "example_blends", a.scene + ".blend"), a.res)
    tr = r.tracer
    parts = Parts()
    if a.parts:
        parts.wrap(Ph, "intersect_f32", "embree")
        parts.wrap(PK, "bounce_kernel")
        parts.wrap(PK, "classic_rows")
        parts.wrap(PK, "follow_rows")
        for name in ("_generic_bounce", "_spectrum_at_hits", "_spectrum_leaving",
                     "_frequency_first"):
            parts.wrap(tr, name)
        for name in [n for n in ("_retrace",) if hasattr(tr, n)]:
            parts.wrap(tr, name)
        parts.wrap(Ph._Deposits, "result")
    freqs = [int(x) for x in a.freq.split(",")]
    variants = [v for v in a.variants.split(",") if v] or [""]

    def setv(v):
        if v:
            k, x = v.split("=")
            setattr(tr, k, type(getattr(tr, k))(int(x)) if isinstance(getattr(tr, k), bool)
                    else type(getattr(tr, k))(x))

    for v in variants:                      # warm-up (numba caches)
        setv(v)
        for nf in freqs:
            tr.trace(a.photons, nf, np.random.default_rng(1))
    cpu = {(v, nf): [] for v in variants for nf in freqs}
    prt = {(v, nf): [] for v in variants for nf in freqs}
    for k in range(a.repeat):
        for v in variants:
            setv(v)
            for nf in freqs:
                s0 = parts.snapshot()
                c0 = time.process_time()
                tr.trace(a.photons, nf, np.random.default_rng(100 + k))
                cpu[v, nf].append(time.process_time() - c0)
                s1 = parts.snapshot()
                prt[v, nf].append({q: s1[q] - s0[q] for q in s1})
    print(f"{a.scene} {a.res}^2, {a.photons} photons a trace, CPU ms, min / median of "
          f"{a.repeat}, interleaved; load {os.getloadavg()[0]:.1f}")
    for v in variants:
        base = np.array(cpu[v, freqs[0]])
        for nf in freqs:
            c = np.array(cpu[v, nf])
            d = c - base                     # paired with the same repetition
            line = (f"{v or 'default':>12} n_freq {nf:>6}: {1e3 * c.min():7.2f} / "
                    f"{1e3 * np.median(c):7.2f}; over n_freq {freqs[0]}: min "
                    f"{1e3 * (c.min() - base.min()):+6.2f}, paired median "
                    f"{1e3 * np.median(d):+6.2f}")
            print(line)
            if a.parts:
                ks = prt[v, nf][0].keys()
                print("      parts (min): " + ", ".join(
                    f"{q} {1e3 * min(p[q] for p in prt[v, nf]):.2f}" for q in ks))
    return 0


if __name__ == "__main__":
    import fppm_alias  # noqa: F401
    sys.exit(main())
