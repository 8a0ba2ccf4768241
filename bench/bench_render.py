"""Photon-pass cost against raw Embree ray casting, measured in one process.

    .venv/bin/python bench/bench_render.py [--res 256] [--photons 200000] [--passes 3]

Prints ratios (issue 2 target: photon pass <= 2x the raw ray casting of its
rays at 256x256 with 200k photons per pass), never a bare time alone.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))

from analytic_scenes import quad, translate  # noqa: E402
from core.render import Renderer  # noqa: E402
from core.scene import DIFFUSE, Camera, Light, Lobe, Material, make_scene  # noqa: E402
from core.settings import RenderSettings  # noqa: E402


def cornell(res: int, subdiv: int = 0):
    """Cornell box (1 m cube, open front) with a ceiling area light and two blocks."""
    tris, mats = [], []
    white, red, green = 0, 1, 2
    def add(q, m):
        tris.extend(q)
        mats.extend([m] * len(q))
    add(quad((0, 0, 0), (0.5, 0, 0), (0, 0.5, 0)), white)        # floor
    add(quad((0, 0, 1), (0, 0.5, 0), (0.5, 0, 0)), white)        # ceiling
    add(quad((0, 0.5, 0.5), (0.5, 0, 0), (0, 0, 0.5)), white)    # back
    add(quad((-0.5, 0, 0.5), (0, 0, 0.5), (0, 0.5, 0)), red)     # left
    add(quad((0.5, 0, 0.5), (0, 0.5, 0), (0, 0, 0.5)), green)    # right
    for c, s, hgt in (((-0.2, 0.15), 0.15, 0.6), ((0.2, -0.15), 0.15, 0.3)):
        x, y = c
        add(quad((x, y, hgt), (s, 0, 0), (0, s, 0)), white)
        add(quad((x, y - s, hgt / 2), (s, 0, 0), (0, 0, -hgt / 2)), white)
        add(quad((x, y + s, hgt / 2), (-s, 0, 0), (0, 0, -hgt / 2)), white)
        add(quad((x - s, y, hgt / 2), (0, s, 0), (0, 0, -hgt / 2)), white)
        add(quad((x + s, y, hgt / 2), (0, -s, 0), (0, 0, -hgt / 2)), white)
    materials = [Material("white", (Lobe(DIFFUSE, (0.8, 0.8, 0.8)),)),
                 Material("red", (Lobe(DIFFUSE, (0.8, 0.1, 0.1)),)),
                 Material("green", (Lobe(DIFFUSE, (0.1, 0.8, 0.1)),))]
    light = Light("ceiling", "AREA", (40.0, 40.0, 40.0), translate(0, 0, 0.999),
                  shape="SQUARE", size=0.3)
    # Camera at y = -1.9 looking along +Y: rotate local -Z onto +Y.
    M = np.array([[1, 0, 0, 0], [0, 0, -1, -1.9], [0, 1, 0, 0.5], [0, 0, 0, 1]], float)
    cam = Camera(kind="PERSP", matrix_world=M, lens=35.0, sensor_width=36.0,
                 resolution=(res, res), clip_start=0.01, clip_end=100.0)
    return make_scene(tris, materials, [light], cam, tri_mat=mats)


def raw_ray_seconds(accel, n: int, rng) -> float:
    """Seconds for embreex to cast n random rays from inside the box (closest hit)."""
    o = rng.uniform([-0.45, -0.45, 0.05], [0.45, 0.45, 0.95], (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    accel.intersect(o[:1000], d[:1000])           # warm-up
    t0 = time.perf_counter()
    accel.intersect(o, d)
    return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--frequency", action="store_true", help="25%% frequency photons")
    a = ap.parse_args(argv)
    scene = cornell(a.res)
    st = RenderSettings(max_passes=a.passes + 1, photons_per_pass=a.photons,
                        use_frequency=a.frequency)
    r = Renderer(scene, st, log=lambda s: None)
    r.step()                                      # warm-up: numba compilation
    for k in r.stage_seconds:
        r.stage_seconds[k] = 0.0
    r.photon_rays = 0
    for _ in range(a.passes):
        r.step()
    s = r.stage_seconds
    photon_pass = s["photon_trace"] + s["gather"]
    rays = r.photon_rays
    ray_s = raw_ray_seconds(r.accel, rays // a.passes, np.random.default_rng(0)) * a.passes
    print(f"scene: Cornell box, {scene.n_triangles} triangles, {a.res}x{a.res}, "
          f"{a.photons} photons/pass, {a.passes} passes, frequency={a.frequency}")
    print(f"photon rays per pass: {rays / a.passes:,.0f}")
    print(f"photons/s: {a.photons * a.passes / photon_pass:,.0f}")
    print(f"photon pass / raw Embree rays: {photon_pass / ray_s:.2f}x  "
          f"(trace {s['photon_trace'] / ray_s:.2f}x + gather {s['gather'] / ray_s:.2f}x)")
    total = sum(s.values())
    print("stage shares: " + ", ".join(f"{k} {v / total:.0%}" for k, v in s.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
