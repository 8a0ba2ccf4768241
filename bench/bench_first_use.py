"""A render's first-use compile: wall time from the start of the warm-up to
the job's kernels loaded, and the CPU of this process and its compiling
children, on an empty kernel cache (docs/interactive.md "Two compiling
processes, round 20").

    .venv/bin/python bench/bench_first_use.py [--integrator PHOTON] [--scene cornell]
        [--percent 100] [--no-frequency]

Exports ``example_blends/<scene>.blend`` (its own settings; --integrator
overrides, --no-frequency turns frequency photons off), sets
``FPPM_CACHE_DIR`` to a new empty folder, then asks the process's warm-up
for the render's own job as a one-shot render does
(``core.warmup.warmup.wait_for(render_job(...), rest=False)``), then ends the
compiling child and reads the children's CPU.  Prints one JSON line: wall,
cpu (this process after the export + every child), the job child's own
record (seconds, cpu, signatures compiled) and the load average before and
after.  Run the same file from another tree's ``bench/`` (with that tree on
PYTHONPATH as ``fppm``) to compare versions; alternate them.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--integrator", default="")
    ap.add_argument("--scene", default="cornell")
    ap.add_argument("--percent", type=int, default=100)
    ap.add_argument("--no-frequency", action="store_true")
    a = ap.parse_args()
    cache = tempfile.mkdtemp(prefix="fppm-first-use-")
    os.environ["FPPM_CACHE_DIR"] = cache
    import fppm_alias  # noqa: F401  (core.x is fppm.core.x: one numba cache)
    import bpy_helpers
    bpy = bpy_helpers.bpy()
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    from fppm.core import warmup as W
    assert os.path.dirname(W._CORE) == ROOT, (W._CORE, ROOT)
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "example_blends", a.scene + ".blend"),
                             load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = a.percent
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    st = settings_from_scene(sc).replace(time_limit=0.0)
    if a.no_frequency:
        st = st.replace(use_frequency=False)
    if a.integrator:
        st = st.replace(integrator=a.integrator)
    recs = []
    result = W._Child.result

    def recording(self, i):
        r = result(self, i)
        if isinstance(r, dict):
            recs.append({k: r[k] for k in ("seconds", "cpu", "compiled")})
        return r
    W._Child.result = recording
    close, errors = W._Child.close, []

    def closing(self):      # a failing child's message (the gather's is killed silently)
        if self.proc.poll() not in (None, 0, -9):
            self.log.seek(0)
            errors.append(self.log.read().decode(errors="replace")[-2000:])
        close(self)
    W._Child.close = closing
    load0 = os.getloadavg()[0]
    t0, r0 = time.perf_counter(), os.times()
    ok = W.warmup.wait_for(W.render_job(scene, st), rest=False)
    wall = time.perf_counter() - t0
    W.warmup._close_child()
    r1 = os.times()
    cpu = sum(getattr(r1, k) - getattr(r0, k)
              for k in ("user", "system", "children_user", "children_system"))
    print(json.dumps({"tree": ROOT, "integrator": st.integrator, "ok": ok,
                      "gather_child": hasattr(W, "compile_gather"), "wall": round(wall, 1),
                      "cpu": round(cpu, 1), "job": recs, "errors": errors,
                      "gather_done": any(n.startswith("gather-") for n in os.listdir(
                          os.path.join(cache, "numba"))), "load": [round(load0, 2),
                                                                  round(os.getloadavg()[0], 2)]}))
    shutil.rmtree(cache, ignore_errors=True)


if __name__ == "__main__":
    main()
