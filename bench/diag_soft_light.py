"""A soft-falloff light's caustic against the same light as a sphere.

    .venv/bin/python bench/diag_soft_light.py SCENE [--passes 200] [--percent 50]
        [--radius R] [--seeds 0,1]

Renders the example scene with Photon Mapping's PPM rule (bench_hold_alpha.py's
'ppm': no frequency kernel, so that only the photons differ), once with its
point and spot lights as they are (Cycles' soft falloff: a disc turned towards
each point it lights) and once with ``use_soft_falloff`` off (a sphere of the
same radius and intensity, whose photons leave its surface: a physical light
field of the same angular size), optionally with every such light's radius set
to R.  The two describe the same light but for the near field (I / (d^2 + r^2)
against I / d^2, 2.7 % at r = 0.5 m and 3 m) and their cones' edges, so their
caustics should match in shape: a soft light's photons leaving its centre alone
drew a point light's caustic (docs/integrators.md "A soft light's photons
arrive from its disc, round 36").  Prints, over the sphere image's brightest
1 % and 3 % of pixels, the brightest pixel of each, the ratio of their sums,
relMSE between the two (seeds averaged) and each one's own noise (half the
relMSE between two seeds, over the number of seeds averaged).
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_hold_alpha as B  # noqa: E402

from fppm.core.render import Renderer  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--passes", type=int, default=200)
    ap.add_argument("--percent", type=int, default=50)
    ap.add_argument("--radius", type=float, default=0.0, help="set every point/spot radius [m]")
    ap.add_argument("--seeds", default="0,1")
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    scene, base = B.export(a.scene, a.percent)
    pt = ("POINT", "SPOT")
    if a.radius > 0:
        scene = dataclasses.replace(scene, lights=[dataclasses.replace(lt, radius=a.radius)
                                                   if lt.kind in pt else lt for lt in scene.lights])
    sphere = dataclasses.replace(scene, lights=[dataclasses.replace(lt, use_soft_falloff=False)
                                                if lt.kind in pt else lt for lt in scene.lights])
    print(f"# {a.scene} at {a.percent} %, {a.passes} passes, lights "
          f"{[(lt.kind, round(lt.radius, 3)) for lt in scene.lights]}", flush=True)
    imgs = {}
    for name, sc in (("soft", scene), ("sphere", sphere)):
        for s in seeds:
            r = Renderer(sc, B.method_settings(base, "ppm").replace(seed=s, max_passes=a.passes),
                         log=lambda t: None)
            c0 = time.process_time()
            for _ in range(a.passes):
                img = np.asarray(r.step().image[..., :3], np.float64)
            B.settle(r)
            imgs[name, s] = img.mean(axis=2)
            print(f"{name} seed {s}: {time.process_time() - c0:.1f} CPU s, image mean "
                  f"{img.mean():.5f}", flush=True)
    soft = np.mean([imgs["soft", s] for s in seeds], axis=0)
    sph = np.mean([imgs["sphere", s] for s in seeds], axis=0)

    def rel(x, y, m):
        return float(np.mean((x[m] - y[m]) ** 2 / (y[m] ** 2 + 1e-2)))
    for pc in (99.0, 97.0):
        m = sph > np.percentile(sph, pc)
        noise = {k: (rel(imgs[k, seeds[0]], imgs[k, seeds[1]], m) / 2 / len(seeds)
                     if len(seeds) > 1 else float("nan")) for k in ("soft", "sphere")}
        print(f"brightest {100 - pc:.0f} % ({int(m.sum())} px): brightest pixel soft "
              f"{soft[m].max():.3f}, sphere {sph[m].max():.3f}; sum soft / sphere "
              f"{soft[m].sum() / sph[m].sum():.4f}; relMSE soft against sphere {rel(soft, sph, m):.3e}"
              f" (noise: soft {noise['soft']:.3e}, sphere {noise['sphere']:.3e})")


if __name__ == "__main__":
    main()
