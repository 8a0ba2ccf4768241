"""CPU time per receiver of ``core.lights.direct_kernels.direct_kernel`` alone.

    .venv/bin/python bench/bench_direct_kernel.py [--res 256] [--repeat 6]

The visible points of one camera pass (every valid pixel, uniforms of a
fixed seed) of two scenes: the Cornell box of bench_render.py (one
rectangular area light: one selection entry) and the warm-up room with a
point, an area, a spot and a sun light (six entries); one thread, best of
``--repeat`` calls after a first that loads / compiles the kernel.  CPU time
(``time.process_time``): the machine may be shared.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))

from bench_render import cornell  # noqa: E402
from core.lights import direct_kernels as DK  # noqa: E402
from core.render import Renderer  # noqa: E402
from core.settings import RenderSettings  # noqa: E402
from core.warmup import warmup_scene  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=6)
    a = ap.parse_args()
    scenes = (("Cornell box", cornell(a.res)),
              ("room, 4 analytic lights", warmup_scene(a.res, ("POINT", "AREA", "SPOT", "SUN"))))
    for name, scene in scenes:
        r = Renderer(scene, RenderSettings(integrator="PHOTON", max_passes=1,
                                           photons_per_pass=100, seed=1),
                     log=lambda _m: None)
        vp, _ = r.camera_pass(np.random.default_rng(1))
        q = np.nonzero(vp.valid)[0]
        u = np.random.default_rng(2).random((q.size, 3))
        R = DK.Receivers(q, vp.p, vp.ns, vp.beta, vp.albedo, vp.const, u)
        L = r.direct_light._compiled_lights()
        best = np.inf
        for rep in range(a.repeat + 1):
            out = DK.alloc_samples(q.size)
            c0 = time.process_time()
            DK.direct_kernel(0, q.size, L, R, out)
            if rep:
                best = min(best, time.process_time() - c0)
        print(f"{name}: {L.entry.shape[0]} selection entries, {q.size:,} receivers: "
              f"{best / q.size * 1e9:.0f} ns per receiver (CPU, best of {a.repeat})")


if __name__ == "__main__":
    main()
