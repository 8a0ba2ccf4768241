"""The fixed cost of a late frequency pass: the photon stage of pass K with
its frequency photons against the same stage without them, on one state.

    .venv/bin/python bench/bench_frequency_pass.py principled_interior [--pass 32]
        [--repeat 20] [--photons 100000] [--percent 50] [--parts] [--against 3]

The .blend at --percent of its resolution (bench/bench_hold_alpha.py's
export), FPPM with the file's settings stepped K - 1 passes, then the SPPM
stages 3-5 of pass K (``Renderer._photons``: radii, reach map, photon trace
and gather, update) on one camera pass's visible points, from the same saved
state each time, as pass K (its ``frequency_photons``, e.g. 24 of 100,000 in
pass 32 with the default schedule) and as pass K + 1 (none; --against J:
as pass J, e.g. pass 1 against pass 3), interleaved,
the same photon stream for both in a repetition; the trace-ahead off so
that every stage runs in this thread; one numba and one tracing thread;
process CPU, min and paired median of --repeat.  --parts: CPU inside the
frequency-only stages, per repetition, min.
"""
from __future__ import annotations

import argparse
import copy
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--pass", dest="k", type=int, default=32)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--photons", type=int, default=100_000)
    ap.add_argument("--percent", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--parts", action="store_true")
    ap.add_argument("--against", type=int, default=0,
                    help="the pass without frequency photons (default K + 1)")
    a = ap.parse_args(argv)
    j = a.against or a.k + 1
    import fppm_alias  # noqa: F401
    from bench_fixed_cost import Parts
    from bench_hold_alpha import export
    from fppm.core.render import Renderer
    from fppm.core.sppm import photon_pass as PP
    from fppm.core.sppm.photon_pass import frequency_photons
    scene, st = export(a.scene, a.percent)
    st = st.replace(photons_per_pass=a.photons, seed=a.seed, max_passes=0, time_limit=1e9)
    r = Renderer(scene, st, log=lambda s: None)
    for _ in range(a.k - 1):
        r.step()
    r.photon_pass.drop_next()
    PP.TRACE_AHEAD = False
    pp = r.photon_pass
    vp, _ = r.camera_pass(r._rng(a.k, 0), r._check_stop)
    def arrays(d):
        # the radius rules' own arrays copied, the rest (tables, the tracer) shared
        return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in d.items()}
    saved = copy.deepcopy(r.state), arrays(r.radii.__dict__)
    reach_src = getattr(pp, "_reach_source", None)
    parts = Parts()
    if a.parts:
        parts.wrap(r.tracer, "set_reach")
        parts.wrap(r.tracer, "_retrace")
        parts.wrap(pp, "_frequency_pairs")
        parts.wrap(pp, "_reflected")
        parts.wrap(r.radii, "update")
        parts.wrap(r.radii, "predicted")
        import fppm.core.sppm.hashgrid as H
        parts.wrap(H, "gather")
    ks = (a.k, j)
    nf = {k: frequency_photons(st, k, pp.doubling) for k in ks}

    def once(k, rng):
        r.state = copy.deepcopy(saved[0])
        r.radii.__dict__.update(arrays(saved[1]))
        r.pass_index = k - 1
        pp._reach_source = reach_src
        s0 = parts.snapshot()
        c0 = time.process_time()
        pp.trace_ahead(rng)                 # the reach map (a frequency pass only)
        r._photons(vp, rng)
        c = time.process_time() - c0
        s1 = parts.snapshot()
        return c, {q: s1[q] - s0[q] for q in s1}

    for k in ks:                            # warm-up
        once(k, np.random.default_rng(1))
    cpu = {k: [] for k in ks}
    prt = {k: [] for k in ks}
    for i in range(a.repeat):
        for k in ks:
            c, p = once(k, np.random.default_rng(100 + i))
            cpu[k].append(c)
            prt[k].append(p)
    print(f"{a.scene} at {a.percent} %, {a.photons} photons, stages 3-5 of pass {a.k} "
          f"({nf[a.k]} frequency photons) against pass {j} ({nf[j]}), CPU ms, "
          f"min / median of {a.repeat}, interleaved; load {os.getloadavg()[0]:.1f}")
    base = np.array(cpu[j])
    for k in ks:
        c = np.array(cpu[k])
        print(f"  pass {k} ({nf[k]:>5} frequency photons): {1e3 * c.min():7.2f} / "
              f"{1e3 * np.median(c):7.2f}; over pass {j}: min "
              f"{1e3 * (c.min() - base.min()):+6.2f}, paired median {1e3 * np.median(c - base):+6.2f}")
        if a.parts:
            print("      parts (min): " + ", ".join(
                f"{q} {1e3 * min(p[q] for p in prt[k]):.2f}" for q in prt[k][0]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
