"""The rendered viewport's restart latency with and without the set-up kept
across restarts (core/setup_cache.py), on a large mesh.

    .venv/bin/python bench/bench_viewport_setup.py [--segments 1000] [--repeats 3]

The scene: a glass UV sphere of ``segments`` x segments/2 faces (about
segments^2 triangles) on a 10 m plane under a point light, photon mapping at
the add-on's defaults (frequency kernel on), 400 x 300 px.  In one process,
interleaved ``--repeats`` times, each arm timed from the Renderer's
construction to the end of its set-up (wall seconds, what a user waits):

- restart: the viewport's quick look (1/4 resolution, no frequency
  analysis), then the full passes' Renderer, as addon/viewport.py makes
  them after every change;
- view moved: the full Renderer of a view moved inside the scene's bounds
  (the camera over the plane), after a restart;
- view moved out: a view that widens the bounds.

Without the cache every Renderer builds everything; with it (a
SetupCache a viewport session, as addon/viewport.py) the later ones take
what does not depend on the change.  Prints each arm's min / median and
the ratio with / without (medians).  docs/interactive.md "Set-up kept
across the viewport's restarts" records a run.
"""
from __future__ import annotations

import argparse
import dataclasses
import gc
import math
import os
import statistics
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

import fppm_alias  # noqa: E402,F401


def scene(segments: int):
    import bpy
    import bpy_helpers as H
    from fppm.addon.engine import settings_from_scene
    from fppm.addon.export import export_scene
    sc = H.empty_scene((400, 300))
    H.add_plane(sc, material=H.node_material("Floor", "BSDF_DIFFUSE"), size=10.0)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(0.0, 0.0, 1.0),
                                         segments=segments, ring_count=segments // 2)
    bpy.context.active_object.data.materials.append(H.node_material("Glass", "BSDF_GLASS"))
    H.add_light(sc, "POINT", 500.0, (2.0, -2.0, 4.0))
    H.add_camera(sc, location=(0.0, -4.0, 1.5), rotation=(math.radians(80), 0.0, 0.0))
    return export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None), \
        settings_from_scene(sc)


def moved(scene, shift, turn_deg):
    M = np.array(scene.camera.matrix_world, np.float64, copy=True)
    c, s = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    M[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ M[:3, :3]
    M[:3, 3] += shift
    return dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, matrix_world=M))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--segments", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    from fppm.core.render import Renderer
    from fppm.core.setup_cache import SetupCache
    sc, st = scene(a.segments)
    W, H = sc.camera.resolution
    small = dataclasses.replace(sc, camera=dataclasses.replace(
        sc.camera, resolution=(-(-W // 4), -(-H // 4))))
    quick = st.replace(max_passes=1, use_frequency=False,
                       photons_per_pass=max(1000, st.photons_per_pass // 16))
    inside = moved(sc, (0.5, 0.5, 0.0), 15.0)       # over the plane, below the sphere's top
    outside = moved(sc, (0.0, -6.0, 0.0), 5.0)      # beyond the plane: the bounds widen

    def setup(scene, settings, cache):
        gc.collect()                       # the last arm's Renderer freed before the clock
        t0 = time.perf_counter()
        r = Renderer(scene, settings, log=lambda _m: None, setup_cache=cache)
        t = time.perf_counter() - t0
        del r
        return t

    times = {}
    setup(sc, st, None)                    # numba's cache load, not counted
    for _ in range(a.repeats):
        for cached in (False, True):
            cache = SetupCache() if cached else None
            t = setup(small, quick, cache) + setup(sc, st, cache)
            times.setdefault(("restart", cached), []).append(t)
            times.setdefault(("view moved", cached), []).append(setup(inside, st, cache))
            if cached:
                setup(sc, st, cache)       # back to the first view's bounds
            times.setdefault(("view moved out", cached), []).append(setup(outside, st, cache))
    print(f"{sc.n_triangles} triangles, {W}x{H} px, {a.repeats} repeats (wall s, min / median)")
    for arm in ("restart", "view moved", "view moved out"):
        off, on = times[(arm, False)], times[(arm, True)]
        print(f"{arm:15s} without {min(off):6.2f} / {statistics.median(off):6.2f}   "
              f"with {min(on):6.2f} / {statistics.median(on):6.2f}   "
              f"ratio {statistics.median(on) / statistics.median(off):.2f}")


if __name__ == "__main__":
    main()
