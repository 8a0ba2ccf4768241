"""Time to a first image: enabling the add-on, compiling the kernels, the first pass.

Every measurement runs in a fresh Python process (what a Blender start is):

- enable: ``import fppm; fppm.register()`` after ``import bpy`` (Blender's own
  start-up is not counted); also says whether numba or Embree were imported.

    .venv/bin/python bench/bench_first_render.py [--repeat 3]

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


def run_child(code: str, env_extra: dict | None = None) -> dict:
    """Run ``code`` in a fresh interpreter; return the JSON of its last stdout line."""
    env = dict(os.environ, **(env_extra or {}))
    env.pop("PYTHONPATH", None)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
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
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    e = bench_enable(a.repeat)
    print(f"enable: {e['enable_s']:.3f} s (best of {a.repeat}; target <= 0.5 s); "
          f"numba imported: {e['numba_imported']}, embreex imported: {e['embreex_imported']}")


if __name__ == "__main__":
    main()
