"""What the leave-out plan saves, measured in one process.

    .venv/bin/python bench/bench_plan.py [--res 128] [--photons 100000] [--passes 3]

For each stage a scene cannot use, the same render with the stage forced on
(Renderer(force_stages=...)) and left out: time ratio and memory saved.
Images are identical either way (tests/test_plan.py).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
import fppm_alias  # noqa: E402,F401

from analytic_scenes import point_light_plane  # noqa: E402
from core.render import Renderer  # noqa: E402
from core.scene.model import GLOSSY, Lobe, Material  # noqa: E402
from core.settings import RenderSettings  # noqa: E402


def timed(scene, st, force, repeat=3):
    """Best of ``repeat`` runs (the machine is shared: the minimum is the
    least disturbed measurement)."""
    best = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        r = Renderer(scene, st, log=lambda s: None, force_stages=force)
        r.run()
        dt = time.perf_counter() - t0
        best = dt if best is None else min(best, dt)
    return best, r


def grid_bytes(r):
    g = r.occ_grid
    if g is None:
        return 0
    return sum(getattr(g, k).nbytes for k in ("dist", "axis", "aperture", "occupied", "near", "cone")
               if isinstance(getattr(g, k, None), np.ndarray))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--photons", type=int, default=100_000)
    ap.add_argument("--passes", type=int, default=3)
    a = ap.parse_args(argv)
    st = RenderSettings(integrator="PHOTON", max_passes=a.passes, photons_per_pass=a.photons,
                        photons_for_direct=True)
    plane, _ = point_light_plane(res=a.res)
    Renderer(plane, st.replace(max_passes=1), log=lambda s: None).run()      # warm-up (numba)
    rows = []
    t_out, r_out = timed(plane, st, ())
    t_in, r_in = timed(plane, st, ("occlusion grid",))
    rows.append(("occlusion grid (open plane)", t_in / t_out, grid_bytes(r_in) - grid_bytes(r_out)))
    glossy = point_light_plane(res=a.res)[0]
    glossy.materials = [Material("rough metal", (Lobe(GLOSSY, (0.8,) * 3, roughness=0.5),))]
    t_out, _ = timed(glossy, st, ())
    t_in, _ = timed(glossy, st, ("frequency photons",))
    rows.append(("frequency photons (no Lambert receiver)", t_in / t_out, 0))
    t_out, _ = timed(plane, st, ())
    t_in, _ = timed(plane, st, ("specular chains",))
    rows.append(("specular chains (no mirror/glass)", t_in / t_out, 0))
    st_q = st.replace(frequency_estimator="QUANTILE", aov_spectrum=True)
    _, rq = timed(plane, st_q, ())
    rows.append(("AOV/estimator arrays (spectrum + histogram)", float("nan"),
                 rq.spectrum.nbytes + rq.r_hist.nbytes))
    print(f"{a.res}x{a.res}, {a.photons} photons/pass, {a.passes} passes")
    print(f"{'stage left out':45s} {'time forced/left out':>22s} {'memory saved':>14s}")
    for name, ratio, mem in rows:
        rs = "-" if ratio != ratio else f"{ratio:.2f}x"
        print(f"{name:45s} {rs:>22s} {mem / 2**20:>11.1f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
