"""Time to a first image: enabling the add-on, compiling the kernels, the first pass.

Every measurement runs in a fresh Python process (what a Blender start is):

- enable: ``import fppm; fppm.register()`` after ``import bpy`` (Blender's own
  start-up is not counted); also says whether numba or Embree were imported.
- cold (empty kernel cache, ``FPPM_CACHE_DIR`` = a new folder), two ways:
  "no warm-up": the Renderer compiles inside its set-up and pass 1 (what a
  render did before core/warmup.py); "background": the warm-up
  (``core.warmup.warmup``: a subprocess compiles, a thread loads) runs while
  the main thread measures its own responsiveness (the longest wait of a
  1 ms sleep loop = how long Blender's UI could stall),
  then the first render's set-up + pass 1 (the "after the background
  compile" number).
- warm (a new process, the cache filled): the warm-up (now loading kernels
  from disk), then the set-up + pass 1.
- viewport: ``addon.viewport.ViewportSession`` at 256 x 256 (warm): time to
  the first (low-resolution) image and to the first full pass after a
  restart, and how long a cancel takes to stop the old job.

Scene: example_blends/cornell.blend at 256 x 256, its own settings.

    .venv/bin/python bench/bench_first_render.py [--repeat 3] [--skip-cold]

The measured numbers are recorded in docs/interactive.md.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

ENABLE = r"""
import json, sys, time
import bpy
t0 = time.perf_counter()
import fppm
fppm.register()
t1 = time.perf_counter()
print(json.dumps({"enable_s": t1 - t0, "numba": "numba" in sys.modules,
                  "embreex": "embreex" in sys.modules}))
"""


SCENE = r"""
import json, os, sys, time
ROOT = sys.argv[1]
import bpy
import fppm
fppm.register()
from fppm.addon.export import export_scene
from fppm.addon.properties import settings_from_scene
bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "example_blends", "cornell.blend"),
                         load_ui=False, use_scripts=False)
sc = bpy.context.scene
sc.render.resolution_x = sc.render.resolution_y = 256
sc.render.resolution_percentage = 100
scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
settings = settings_from_scene(sc).replace(time_limit=0.0)
out = {}


def first_pass():
    from fppm.core.render import Renderer
    t0 = time.perf_counter()
    r = Renderer(scene, settings.replace(max_passes=1), log=lambda s: None)
    t1 = time.perf_counter()
    r.step()
    t2 = time.perf_counter()
    return {"setup_s": t1 - t0, "pass1_s": t2 - t1, "first_pass_s": t2 - t0}
"""

NO_WARMUP = SCENE + r"""
out.update(first_pass())
print(json.dumps(out))
"""

BACKGROUND = SCENE + r"""
from fppm.core.warmup import warmup
t0 = time.perf_counter()
warmup.start()
gaps, last = [], time.perf_counter()
while not warmup.done:
    time.sleep(0.001)
    now = time.perf_counter()
    gaps.append(now - last)
    last = now
out["warmup_s"] = time.perf_counter() - t0
out["warmup_error"] = warmup.error
out["ui_gap_max_s"] = max(gaps)
out["ui_gap_p99_s"] = sorted(gaps)[int(0.99 * (len(gaps) - 1))]
out.update(first_pass())
print(json.dumps(out))
"""

VIEWPORT = SCENE + r"""
import numpy as np
from fppm.addon import viewport as V
from fppm.core.settings import ViewportSettings
from fppm.core.warmup import warmup
warmup.wait()
s = V.ViewportSession()
vs = ViewportSettings(viewport_resolution_divider=4, viewport_max_passes=0)
firsts, fulls, stops = [], [], []
for i in range(4):
    old = s._job
    t0 = time.perf_counter()
    s.restart(scene, settings, vs)
    if old is not None:
        old.finished.wait(5)
        stops.append(time.perf_counter() - t0)
    while s.frame() is None:
        time.sleep(0.002)
    firsts.append(time.perf_counter() - t0)
    while s.frame().pass_index < 1:
        time.sleep(0.002)
    fulls.append(time.perf_counter() - t0)
    time.sleep(0.1 + 0.2 * i)
s.cancel()
out.update(first_image_s=float(np.median(firsts)), first_full_pass_s=float(np.median(fulls)),
           cancel_s=float(np.median(stops)), cancel_max_s=float(max(stops)))
print(json.dumps(out))
"""


def run_child(code: str, env_extra: dict | None = None) -> dict:
    """Run ``code`` in a fresh interpreter; return the JSON of its last stdout line."""
    env = dict(os.environ, **(env_extra or {}))
    env.pop("PYTHONPATH", None)
    p = subprocess.run([sys.executable, "-c", code, ROOT], capture_output=True, text=True, env=env,
                       cwd=ROOT, timeout=1800)
    if p.returncode != 0:
        raise RuntimeError(p.stderr[-2000:])
    return json.loads(p.stdout.strip().splitlines()[-1])


def bench_enable(repeat: int) -> dict:
    runs = [run_child(ENABLE) for _ in range(repeat)]
    best = min(r["enable_s"] for r in runs)
    return {"enable_s": best, "numba_imported": any(r["numba"] for r in runs),
            "embreex_imported": any(r["embreex"] for r in runs)}


def main(argv=None):
    import tempfile
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-cold", action="store_true", help="no empty-cache runs (minutes each)")
    a = ap.parse_args(argv)
    e = bench_enable(a.repeat)
    print(f"enable: {e['enable_s']:.3f} s (best of {a.repeat}; target <= 0.5 s); "
          f"numba imported: {e['numba_imported']}, embreex imported: {e['embreex_imported']}")
    with tempfile.TemporaryDirectory(prefix="fppm-bench-") as tmp:
        if not a.skip_cold:
            c = run_child(NO_WARMUP, {"FPPM_CACHE_DIR": os.path.join(tmp, "nowarm")})
            print(f"cold, no warm-up: first pass {c['first_pass_s']:.1f} s "
                  f"(set-up {c['setup_s']:.1f} s + pass 1 {c['pass1_s']:.1f} s, compiling included)")
        cache = {"FPPM_CACHE_DIR": os.path.join(tmp, "cache")}
        b = run_child(BACKGROUND, cache)
        label = "cold" if not a.skip_cold else "background"
        print(f"{label}, background warm-up: {b['warmup_s']:.1f} s"
              f"{' (error: ' + b['warmup_error'] + ')' if b['warmup_error'] else ''}; "
              f"main thread's longest wait meanwhile {b['ui_gap_max_s'] * 1e3:.0f} ms "
              f"(p99 {b['ui_gap_p99_s'] * 1e3:.0f} ms); then first pass {b['first_pass_s']:.2f} s "
              f"(set-up {b['setup_s']:.2f} s + pass 1 {b['pass1_s']:.2f} s; target <= 5 s)")
        w = run_child(BACKGROUND, cache)
        print(f"warm: warm-up (loading) {w['warmup_s']:.1f} s; then first pass "
              f"{w['first_pass_s']:.2f} s (set-up {w['setup_s']:.2f} s + pass 1 {w['pass1_s']:.2f} s)")
        v = run_child(VIEWPORT, cache)
        print(f"viewport 256x256 (divider 4): first image {v['first_image_s']:.2f} s, first full "
              f"pass {v['first_full_pass_s']:.2f} s after a restart (target <= 0.5 s); "
              f"cancel {v['cancel_s'] * 1e3:.0f} ms median, {v['cancel_max_s'] * 1e3:.0f} ms max")


if __name__ == "__main__":
    main()
