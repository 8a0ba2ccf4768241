"""What a roughness map costs: renders with the map against the same scene at its mean.

    .venv/bin/python bench/bench_rough_maps.py [INTEGRATOR ...]

The scene of tests/test_rough_maps.py's reflected-light test at 128 x 128: a
metal floor with a banded roughness map, which every photon and camera path
meets, and a white wall.  For each INTEGRATOR (default PHOTON PATH LIGHT
COMBINED) it renders 16 passes (200,000 photons a pass) with the map and
with the floor at its mean roughness (``Lobe.roughness_texture`` cleared),
alternating, three times each after a warm-up, and prints the ratio of the
process CPU times, min and median (docs/shading.md "Roughness maps").
"""
from __future__ import annotations

import dataclasses
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

import fppm_alias  # noqa: E402,F401


def main(integrators=("PHOTON", "PATH", "LIGHT", "COMBINED")):
    import numpy as np

    import test_rough_maps as T
    import test_shading_nodes as TS
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    T.wall_scene(128)
    scene, _ = TS._export()
    fm = next(i for i, m in enumerate(scene.materials) if m.name == "Floor")
    mats = list(scene.materials)
    mats[fm] = dataclasses.replace(mats[fm], lobes=tuple(
        dataclasses.replace(lb, roughness_texture=-1) for lb in mats[fm].lobes))
    flat = dataclasses.replace(scene, materials=mats, tri_n=scene.tri_n.copy())

    def cpu(sc, integrator):
        st = RenderSettings(integrator=integrator, max_passes=16, photons_per_pass=200_000,
                            seed=1, use_frequency=False, max_bounces=4)
        t = time.process_time()
        Renderer(sc, st, log=lambda s: None).run()
        return time.process_time() - t

    for integrator in integrators:
        cpu(scene, integrator), cpu(flat, integrator)
        a, b = [], []
        for _ in range(3):
            a.append(cpu(scene, integrator))
            b.append(cpu(flat, integrator))
        print(f"{integrator:9s} with the map / at its mean, process CPU: min "
              f"{min(a) / min(b):.2f}x, median {np.median(a) / np.median(b):.2f}x "
              f"({min(a):.2f} s / {min(b):.2f} s)")


if __name__ == "__main__":
    main(*([tuple(sys.argv[1:])] if len(sys.argv) > 1 else []))
