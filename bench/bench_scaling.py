"""Photon passes on 1, 2 and 4 local Dask workers against one process, in one run.

    .venv/bin/python bench/bench_scaling.py [--res 128] [--passes 3] [--photons 262144]
                                            [--chunk 32768] [--workers 1 2 4]

The scene is bench/bench_render.py's Cornell box.  Every configuration
renders the same passes with the same seed and chunking (one random stream
per chunk): one process first, then a local cluster per worker count
(``tools.distributed.connect``), warmed up before its first pass (scene
set-up and kernel loading are not timed).  Printed per configuration:

- photon throughput (photons per wall second of the photon stage, the only
  stage the workers take) and its ratio to one worker and to one process;
- per pass: bytes broadcast (visible points + radii, to every worker),
  bytes returned (all chunk sums) and per chunk, and the driver's time to
  add them, as a share of the photon stage;
- the largest difference from the one-process image (0: bit-identical).

Ratios, not bare times: the machine may be shared.  Dask needs
``pip install "dask[distributed]"`` (``make venv``).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)

from bench_render import cornell  # noqa: E402
from fppm.core.render import Renderer  # noqa: E402
from fppm.core.settings import RenderSettings  # noqa: E402
from fppm.tools import distributed as D  # noqa: E402


def render(scene, st, chunk, client=None):
    """(image, photon-stage wall seconds, driver CPU seconds, PassStats list)."""
    r = D.local_chunk_streams(Renderer(scene, st, log=lambda s: None), chunk)
    dist = D.DistributedPhotonPass(client, r) if client is not None else None
    photon_wall = [0.0]
    if dist is None:                      # time the local photon stage the same way
        local = r.photon_pass

        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return local(*a, **k)
            finally:
                photon_wall[0] += time.perf_counter() - t0
        timed.rays = 0
        r.photon_pass = timed
    c0 = time.process_time()
    img = r.run().image
    cpu = time.process_time() - c0
    if dist is not None:
        photon_wall[0] = sum(s.wall_seconds for s in dist.stats)
    return img, photon_wall[0], cpu, (dist.stats if dist is not None else [])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--photons", type=int, default=262_144)
    ap.add_argument("--chunk", type=int, default=32_768)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    a = ap.parse_args(argv)
    scene = cornell(a.res)
    st = RenderSettings(max_passes=a.passes, photons_per_pass=a.photons, seed=11,
                        time_limit=0.0)
    n_chunks = -(-a.photons // a.chunk)
    photons = a.passes * a.photons
    print(f"Cornell box {a.res}x{a.res}, {a.passes} passes of {a.photons} photons "
          f"({n_chunks} chunks of {a.chunk}); {os.cpu_count()} cores (possibly shared).")
    render(cornell(16), st.replace(max_passes=1, photons_per_pass=4096), a.chunk)  # compile/load
    ref, wall1, cpu1, _ = render(scene, st, a.chunk)
    print(f"one process: {photons / wall1:,.0f} photons/s in the photon stage "
          f"(driver CPU {cpu1:.1f} s).")
    rows = []
    for n in a.workers:
        client = D.connect(workers=n)
        try:
            img, wall, cpu, stats = render(scene, st, a.chunk, client)
        finally:
            D.close(client)
        rows.append((n, photons / wall, cpu, stats, float(np.abs(img - ref).max())))
    base = rows[0][1]
    P = a.res * a.res
    print(f"\n{'workers':>7} {'photons/s':>11} {'vs 1 worker':>11} {'vs 1 process':>12} "
          f"{'broadcast/pass':>14} {'returned/pass':>13} {'per chunk':>10} {'B/px/chunk':>10} "
          f"{'add share':>9} {'driver CPU':>10} {'max |diff|':>10}")
    for n, thr, cpu, stats, diff in rows:
        bc = np.mean([s.broadcast_bytes for s in stats])
        rb = np.mean([s.returned_bytes for s in stats])
        per_chunk = rb / n_chunks
        add_share = sum(s.add_seconds for s in stats) / sum(s.wall_seconds for s in stats)
        print(f"{n:>7} {thr:>11,.0f} {thr / base:>11.2f} {thr * wall1 / photons:>12.2f} "
              f"{bc / 1e6:>11.2f} MB {rb / 1e6:>10.2f} MB {per_chunk / 1e3:>7.0f} kB "
              f"{per_chunk / P:>10.1f} {add_share:>9.1%} {cpu:>8.1f} s {diff:>10.3g}")
    print(f"\nBroadcast per pixel: {bc / P:.0f} B; returned per pixel per chunk: "
          f"{per_chunk / P:.1f} B (sparse: the pixels a chunk touched).")


if __name__ == "__main__":
    main()
