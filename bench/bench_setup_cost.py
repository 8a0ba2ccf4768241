"""CPU of FPPM's set-up and first passes against PPM's, at the file's resolution.

    .venv/bin/python bench/bench_setup_cost.py glass_sphere ring_principled coffee_cup [--repeats 3] [--passes 4]

For each scene: Renderer construction (``_setup_scene`` and the stages) and
the first ``--passes`` passes of FPPM (the file's settings) and PPM
(frequency off), interleaved ``--repeats`` times in one process (process CPU
seconds, all threads; min / median), and the CPU of the set-up's parts
(occlusion grid, curvature, plan, photon tracer).  The first construction of
each method is a warm-up (numba's cache load) and not counted.
docs/method.md "The frequency schedule and the first 10 %".
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

import fppm_alias  # noqa: E402,F401
from bench_hold_alpha import export  # noqa: E402

import fppm.core.render as R  # noqa: E402
from fppm.core.render import Renderer  # noqa: E402

PARTS = {}


def _timed(mod, name, key):
    f = getattr(mod, name)

    def g(*a, **k):
        c0 = time.process_time()
        out = f(*a, **k)
        PARTS[key] = PARTS.get(key, 0.0) + time.process_time() - c0
        return out
    setattr(mod, name, g)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--passes", type=int, default=4)
    ap.add_argument("--methods", default="fppm,ppm",
                    help="fppm, ppm, or fppm:field=value (a RenderSettings field)")
    a = ap.parse_args()
    from fppm.core.frequency import occlusion_grid as og
    _timed(og, "build_occlusion_grid", "occlusion grid")
    _timed(R, "scene_curvature", "curvature")
    _timed(R, "make_plan", "plan")
    _timed(R, "PhotonTracer", "photon tracer")
    _timed(R, "Accel", "bvh")
    for name in a.scenes:
        scene, base = export(name, 100)
        methods = a.methods.split(",")

        def settings(m):
            st = base.replace(use_frequency=(m.split(":")[0] == "fppm"))
            for kv in m.split(":")[1:]:
                k, v = kv.split("=")
                st = st.replace(**{k: type(getattr(base, k))(v)})
            return st
        rec = {m: {"setup": [], "parts": [], "passes": []} for m in methods}
        for rep in range(a.repeats + 1):
            for m in methods:
                PARTS.clear()
                c0 = time.process_time()
                r = Renderer(scene, settings(m).replace(max_passes=a.passes), log=lambda s: None)
                c1 = time.process_time()
                ps = []
                for _ in range(a.passes):
                    p0 = time.process_time()
                    r.step()
                    ps.append(time.process_time() - p0)
                if rep:
                    rec[m]["setup"].append(c1 - c0)
                    rec[m]["parts"].append(dict(PARTS))
                    rec[m]["passes"].append(ps)
        print(f"# {name}: {scene.camera.resolution}, {base.photons_per_pass} photons/pass, "
              f"load {os.getloadavg()[0]:.1f}", flush=True)
        for m in methods:
            s = np.array(rec[m]["setup"])
            p = np.array(rec[m]["passes"])
            parts = {k: np.median([d.get(k, 0.0) for d in rec[m]["parts"]])
                     for k in rec[m]["parts"][0]}
            print(f"{name} {m:>20}: set-up min {s.min():.3f} median {np.median(s):.3f} s; passes "
                  + " ".join(f"{np.min(p[:, i]):.3f}/{np.median(p[:, i]):.3f}" for i in range(p.shape[1]))
                  + " s (min/median); parts (median) "
                  + ", ".join(f"{k} {v:.3f}" for k, v in parts.items()), flush=True)


if __name__ == "__main__":
    main()
