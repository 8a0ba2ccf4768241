"""Export time and cancel poll gaps of a 1M-triangle mesh and a 4k texture
(addon/export.py, addon/export_read.py), not a test.

    .venv/bin/python bench/bench_export.py [--tris N] [--image PX] [--repeat R]

Builds a grid of ~N triangles (smooth shaded, with UVs and two material
slots) plus a PX^2 generated texture on a floor, then, for each:
- times ``export_scene`` on the evaluated depsgraph (best of R), with the
  share spent in ``mesh_arrays`` (the Blender reads), and the same reads done
  as single Blender calls (tests/oracle_export_read.py, today's reader before
  cancel was cut) in the same run: the throughput ratio;
- the worst poll gap: the longest time between two calls of ``should_stop``
  during the export (what a cancel arriving at any instant waits for), CPU
  and wall time.
The machine may be shared: read the ratios and CPU times, not the wall times.
"""
import argparse
import math
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

import fppm_alias  # noqa: E402,F401
import bpy_helpers as H  # noqa: E402


class Gaps:
    """should_stop() that records the longest wall and CPU time between two calls."""

    def __init__(self):
        self.last = None
        self.where = ""
        self.worst = (0.0, 0.0, "")

    def __call__(self):
        import traceback
        now = (time.perf_counter(), time.process_time())
        here = " < ".join(f"{f.name}:{f.lineno}" for f in traceback.extract_stack()[-4:-1][::-1])
        if self.last is not None:
            gap = (now[0] - self.last[0], now[1] - self.last[1])
            if gap[0] > self.worst[0]:
                self.worst = gap + (f"{self.where} -> {here}",)
        self.last, self.where = now, here
        return False


def _best(fn, repeat):
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def bench_mesh(tris, repeat):
    import bpy
    from fppm.addon import export as E
    import oracle_export_read as O
    H.simple_scene()
    n = int(math.sqrt(tris / 2)) + 1          # (n-1)^2 quads = 2 (n-1)^2 triangles
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=n - 1, y_subdivisions=n - 1, size=4)
    grid = bpy.context.active_object
    grid.data.shade_smooth()
    grid.data.materials.append(bpy.data.materials["Grey"])
    grid.data.materials.append(bpy.data.materials["Red"])

    def fresh():      # a new evaluated mesh: Blender's normal caches empty
        grid.data.update()
        return H.evaluated_depsgraph()

    gaps, t_cut, t_one, t_exp = Gaps(), [], [], []
    for _ in range(repeat):
        dg = fresh()
        t = time.perf_counter()
        gaps.last = None                      # gaps within one export only
        s = E.export_scene(dg, log=lambda m: None, should_stop=gaps)
        t_exp.append(time.perf_counter() - t)
        me = grid.evaluated_get(fresh()).data
        t = time.perf_counter()
        E.mesh_arrays(me)
        t_cut.append(time.perf_counter() - t)
        me = grid.evaluated_get(fresh()).data
        t = time.perf_counter()
        O.mesh_arrays(me)
        t_one.append(time.perf_counter() - t)
    T = s.n_triangles
    print(f"mesh: export_scene {T:,} triangles in {min(t_exp):.3f} s (best of {repeat})")
    print(f"  reads cut for cancel {min(t_cut):.3f} s, as single calls {min(t_one):.3f} s: "
          f"ratio {min(t_cut) / min(t_one):.2f}")
    print(f"  worst poll gap {gaps.worst[0] * 1e3:.1f} ms wall, {gaps.worst[1] * 1e3:.1f} ms CPU "
          f"({gaps.worst[2]})")


def bench_image(size, repeat):
    from fppm.addon import export as E
    from fppm.addon import export_read as R
    import oracle_export_read as O
    from test_reliability3 import _textured_floor
    t_exp, t_child, t_one, gaps = [], [], [], Gaps()
    for _ in range(repeat):
        img = _textured_floor(size)            # a new scene and image, not made yet
        t = time.perf_counter()
        gaps.last = None
        E.export_scene(H.evaluated_depsgraph(), log=lambda m: None, should_stop=gaps)
        t_exp.append(time.perf_counter() - t)
        t = time.perf_counter()
        R.image_pixels(img, size * size * 4, lambda: None)   # made and read in a child
        t_child.append(time.perf_counter() - t)
        t = time.perf_counter()
        O.image_pixels(img)                            # made and read in-process
        t_one.append(time.perf_counter() - t)
    print(f"image {size}^2 generated: export_scene {min(t_exp):.3f} s (best of {repeat})")
    print(f"  make + read in a child {min(t_child):.3f} s, in-process (one call) "
          f"{min(t_one):.3f} s: ratio {min(t_child) / min(t_one):.2f}")
    print(f"  worst poll gap {gaps.worst[0] * 1e3:.1f} ms wall, {gaps.worst[1] * 1e3:.1f} ms CPU "
          f"({gaps.worst[2]})")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tris", type=int, default=1_000_000)
    ap.add_argument("--image", type=int, default=4096)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    if a.tris:
        bench_mesh(a.tris, a.repeat)
    if a.image:
        bench_image(a.image, a.repeat)


if __name__ == "__main__":
    main()
