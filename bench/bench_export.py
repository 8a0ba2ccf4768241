"""Export time of a 1M-triangle mesh (addon/export.py), not a test.

    .venv/bin/python bench/bench_export.py [--tris N]

Builds a grid of ~N triangles (smooth shaded, with UVs and two material
slots) plus 100 instances of a small mesh, then times ``export_scene`` on the
evaluated depsgraph: best of 3, with the share spent in ``foreach_get`` +
indexing (``mesh_arrays``) and the rest (transforms, materials, checks).
"""
import argparse
import math
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

import bpy_helpers as H  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tris", type=int, default=1_000_000)
    a = ap.parse_args()
    import bpy
    from fppm.addon import export as E

    sc = H.simple_scene()
    n = int(math.sqrt(a.tris / 2)) + 1          # (n-1)^2 quads = 2 (n-1)^2 triangles
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=n - 1, y_subdivisions=n - 1, size=4)
    grid = bpy.context.active_object
    grid.data.shade_smooth()
    grid.data.materials.append(bpy.data.materials["Grey"])
    grid.data.materials.append(bpy.data.materials["Red"])
    dg = H.evaluated_depsgraph()

    t_arr = []
    orig = E._Exporter.mesh_arrays

    def timed(me, *a):
        t = time.perf_counter()
        r = orig(me, *a)
        t_arr.append(time.perf_counter() - t)
        return r
    E._Exporter.mesh_arrays = staticmethod(timed)
    best, best_arr, s = float("inf"), 0.0, None
    for _ in range(3):
        t_arr.clear()
        t0 = time.perf_counter()
        s = E.export_scene(dg, log=lambda m: None)
        dt = time.perf_counter() - t0
        if dt < best:
            best, best_arr = dt, sum(t_arr)
    T = s.n_triangles
    print(f"export_scene: {T:,} triangles in {best:.3f} s (best of 3) = "
          f"{T / best / 1e6:.2f} M triangles/s")
    print(f"  mesh_arrays (foreach_get + corner indexing): {best_arr:.3f} s "
          f"({100 * best_arr / best:.0f} %); transforms, materials, checks: "
          f"{best - best_arr:.3f} s")


if __name__ == "__main__":
    main()
