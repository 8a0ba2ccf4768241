"""CPU of the photon tracer alone: chunks of 131,072 photons of the Cornell box.

    .venv/bin/python bench/bench_trace_chunk.py [--chunks 20] [--res 64]

A Renderer (integrator PHOTON, plain) is built and stepped once (kernels
loaded), then its tracer traces three warm-up chunks and ``--chunks`` timed
ones (``PhotonTracer.trace``, seeds 100, 101, ...; photon threads as
``FPPM_PHOTON_THREADS``).  Printed: the CPU (process clock) of a chunk, min /
median; its parts, summed over the tracing threads' own clocks
(``time.thread_time`` around the Embree call, the bounce kernel, the
emission kernel and the uniforms; the rest is the Python per bounce), min /
median; and one more chunk's deposit count and sums of power and positions
(two codes that should trace the same photons print the same sums, to
rounding).  To compare two codes, run this file of each tree in alternating
processes, each with its own ``FPPM_CACHE_DIR`` (numba's cache is stamped by
a kernel's own file, not by the helpers it inlines): docs/architecture.md
"The photon pass's own work against raw Embree".
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

from bench_render import ThreadClock, cornell  # noqa: E402
from core.render import Renderer  # noqa: E402
from core.settings import RenderSettings  # noqa: E402
from core.sppm import photon_kernels as PK  # noqa: E402
from core.sppm import photons as Ph  # noqa: E402

CHUNK = 131_072
PARTS = ("embree", "bounce", "emission", "uniforms")


def wrap_parts(tracer) -> dict:
    """Sum each part's thread CPU into the returned dict (module functions
    as the tracer calls them: photons.intersect_f32, PK.bounce_kernel,
    PK.emit_lights_state; the tracer's uniforms)."""
    tc = ThreadClock()
    tc.t.update(dict.fromkeys(PARTS, 0.0))
    tc.wrap(Ph, "intersect_f32", "embree")
    tc.wrap(PK, "bounce_kernel", "bounce")
    tc.wrap(PK, "emit_lights_state", "emission")
    tc.wrap(tracer, "uniforms", "uniforms")
    return tc.t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--chunks", type=int, default=20)
    ap.add_argument("--res", type=int, default=64)
    a = ap.parse_args(argv)
    r = Renderer(cornell(a.res, height=a.res),
                 RenderSettings(integrator="PHOTON", max_passes=1000, photons_per_pass=200_000,
                                use_frequency=False), log=lambda s: None)
    r.step()
    t = r.photon_pass.tracer
    for i in range(3):
        t.trace(CHUNK, 0, np.random.default_rng(i))
    acc = wrap_parts(t)
    cpu, parts = [], {k: [] for k in PARTS}
    for i in range(a.chunks):
        before = dict(acc)
        c0 = time.process_time()
        t.trace(CHUNK, 0, np.random.default_rng(100 + i))
        cpu.append(time.process_time() - c0)
        for k in PARTS:
            parts[k].append(acc[k] - before[k])
    d = t.trace(CHUNK, 0, np.random.default_rng(7))
    print(f"trace CPU a {CHUNK}-photon chunk: min {min(cpu) * 1e3:.1f} ms, median "
          f"{np.median(cpu) * 1e3:.1f} ms ({a.chunks} chunks); parts, min / median: "
          + ", ".join(f"{k} {min(v) * 1e3:.1f} / {np.median(v) * 1e3:.1f}"
                      for k, v in parts.items())
          + f" ms; deposits {d['p'].shape[0]}, "
          f"power sum {d['power'].sum(axis=0)}, position sum {d['p'].sum():.12e}; "
          f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
