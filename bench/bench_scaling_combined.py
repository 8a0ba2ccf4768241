"""Integrator COMBINED on 1 and 2 local Dask workers against one process, in one run.

    .venv/bin/python bench/bench_scaling_combined.py [--res 64] [--passes 4] [--paths 262144]
                                                     [--chunk 32768] [--samples 1]
                                                     [--repeat 2] [--threads T]

The scene is bench/bench_render.py's Cornell box with a mirror tall block,
so that a COMBINED pass has all three light-side stages the workers take:
light tracing (splat sums returned) and photon merging (visible points
broadcast, photon sums returned), next to the camera paths the driver
traces.  Every configuration renders the same passes with the same seed and
chunking (``tools.distributed.local_chunk_streams``): one process, then a
local cluster of 1 and of 2 workers, and of 2 with the next pass's light
chunks submitted ahead (``distribute(prefetch=True)``) (all started first;
scene set-up and kernel loading precede the timed passes), round robin ``--repeat`` times,
the fastest run of each kept.  Printed per configuration: wall seconds of
the passes and their ratio to one worker and to one process, CPU seconds of
driver + workers against one process, and per pass the bytes the driver
receives (light-path splat sums, merging-photon sums) and broadcasts (the
merging pass's visible points), and the largest difference from the
one-process image (0: bit-identical).  Ratios, not bare times: the machine
may be shared.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))

# First: bench_scaling applies --threads T (numba and photon-tracer threads of
# every process, inherited by the workers) before numba loads, and puts
# tests/ on the path for fppm_alias.
import bench_scaling  # noqa: E402,F401
import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)

import numpy as np  # noqa: E402

from bench_render import cornell  # noqa: E402
from fppm.core.render import Renderer  # noqa: E402
from fppm.core.scene.model import GLOSSY, Lobe, Material  # noqa: E402
from fppm.core.settings import RenderSettings  # noqa: E402
from fppm.tools import distributed as D  # noqa: E402


def mirror_cornell(res: int):
    """The Cornell box, its tall block a mirror (photon merging sees it)."""
    s = cornell(res)
    mats = list(s.materials) + [Material("mirror", (Lobe(GLOSSY, (0.9,) * 3, roughness=0.0),))]
    tri_mat = np.array(s.tri_mat, np.int32)
    tri_mat[10:20] = len(mats) - 1              # the 5 quads of the first (tall) block
    return dataclasses.replace(s, materials=mats, tri_mat=tri_mat)


def render(scene, st, chunk, client=None, prefetch=False):
    """(image, wall seconds of the passes, CPU seconds of driver + workers,
    the distributed stages)."""
    r = D.local_chunk_streams(Renderer(scene, st, log=lambda s: None), chunk)
    stages = (D.distribute(client, r, load_kernels=True, prefetch=prefetch)
              if client is not None else [])
    w0 = client.run(time.process_time) if client is not None else {}
    c0, t0 = time.process_time(), time.perf_counter()
    img = r.run().image
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if client is not None:
        cpu += sum(t - w0[w] for w, t in client.run(time.process_time).items())
        for s in stages:
            s.close()
        stages[0].session.release()
    return img, wall, cpu, stages


def per_pass(stages, kind, field):
    """Mean over the passes of a PassStats field of the stage of that kind."""
    rows = [s for st in stages if type(st).__name__ == kind for s in st.stats]
    return float(np.mean([getattr(s, field) for s in rows])) if rows else 0.0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--passes", type=int, default=4)
    ap.add_argument("--paths", type=int, default=262_144,
                    help="light paths (and merging photons) per pass")
    ap.add_argument("--chunk", type=int, default=32_768)
    ap.add_argument("--samples", type=int, default=1, help="camera samples per pixel and pass")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--threads", type=int, default=None)
    a = ap.parse_args(argv)
    scene = mirror_cornell(a.res)
    st = RenderSettings(integrator="COMBINED", max_passes=a.passes, photons_per_pass=a.paths,
                        camera_samples=a.samples, seed=11, time_limit=0.0)
    probe = Renderer(scene, st, log=lambda s: None)
    assert probe.merging and probe.combined_lt is not None, probe.plan.strategies
    print(f"Mirror Cornell box {a.res}x{a.res}, COMBINED, {a.passes} passes of {a.paths} light "
          f"paths + {a.paths} merging photons, {a.samples} camera sample(s)/px, chunks of "
          f"{a.chunk}; {os.cpu_count()} cores (possibly shared).")
    render(mirror_cornell(16), st.replace(max_passes=1, photons_per_pass=4096), a.chunk)
    clients = {n: D.connect(workers=n) for n in a.workers}
    # (workers, prefetch): the largest cluster also with the next pass's
    # light chunks submitted ahead.
    configs = [(0, False)] + [(n, False) for n in a.workers] + [(a.workers[-1], True)]
    best = {}
    try:
        for _ in range(a.repeat):   # round robin: every configuration sees the same load
            for n, pre in configs:
                run = render(scene, st, a.chunk, clients.get(n), pre)
                if (n, pre) not in best or run[1] < best[n, pre][1]:
                    best[n, pre] = run
    finally:
        for c in clients.values():
            D.close(c)
    ref, wall0, cpu0, _ = best[0, False]
    w1 = best[a.workers[0], False][1]
    print(f"one process: {wall0:.2f} s for the passes (CPU {cpu0:.1f} s); best of {a.repeat}.")
    print(f"\n{'workers':>10} {'wall s':>7} {'vs 1st':>6} {'vs 1 proc':>9} {'CPU vs 1 proc':>13} "
          f"{'light returned/pass':>19} {'merge returned/pass':>19} {'merge broadcast/pass':>20} "
          f"{'max |diff|':>10}")
    for n, pre in configs[1:]:
        img, wall, cpu, stages = best[n, pre]
        name = f"{n}" + (" prefetch" if pre else "")
        print(f"{name:>10} {wall:>7.2f} {w1 / wall:>6.2f} {wall0 / wall:>9.2f} {cpu / cpu0:>13.2f} "
              f"{per_pass(stages, 'DistributedLightTracer', 'returned_bytes') / 1e3:>16.0f} kB "
              f"{per_pass(stages, 'DistributedPhotonPass', 'returned_bytes') / 1e3:>16.0f} kB "
              f"{per_pass(stages, 'DistributedPhotonPass', 'broadcast_bytes') / 1e3:>17.0f} kB "
              f"{float(np.abs(img - ref).max()):>10.3g}")


if __name__ == "__main__":
    main()
