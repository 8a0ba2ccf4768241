"""FPPM's set-up: the occlusion grid build and its march blocks, against another version.

    .venv/bin/python bench/bench_occlusion_build.py --ref OLD_OCCLUSION_GRID.py
        [--scenes ring_principled,cornell,principled_interior] [--res 0] [--repeat 3]
        [--setup ring_principled]

The grids are built as ``Renderer`` builds them (``geometry_bounds`` padded by
1e-3 of the scene diameter, ``max_distance`` 10 voxel diagonals) from the
triangles of example_blends/NAME.blend (exported with bpy, at the file's
``occlusion_grid_res`` or ``--res``) and of bench_render's Cornell box
(``bench``).  Each repetition builds the grid and its ``march_blocks`` with this
tree's core/frequency/occlusion_grid.py and with ``--ref`` (e.g. ``git show
c330335:core/frequency/occlusion_grid.py > /tmp/old_grid.py``), in turn, and
prints the process CPU of both (best, paired median ratio) and whether the grids
are identical and the march blocks are identical wherever the march reads them
(bmin, vmin, and the cones of the blocks and voxels whose minimum is below
``cut_locality``).  ``--setup NAME``: also ``Renderer(...)`` of that file at 128^2
(FPPM with either module swapped in, and PPM), CPU.  Ratios only; say the load.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import fppm_alias  # noqa: E402,F401  (core.x and fppm.core.x: one module, one numba cache)

GRID_FIELDS = ("lo", "hi", "cell", "dist", "axis", "aperture", "occupied", "near", "cone")


def _blend_scene(name: str, res: int = 128):
    import bpy
    import bpy_helpers
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "example_blends", name + ".blend"),
                             load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_x = sc.render.resolution_y = res
    sc.render.resolution_percentage = 100
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    return scene, settings_from_scene(sc)


def _build(G, scene, res):
    lo, hi = G.geometry_bounds(scene)
    D = scene.diameter()
    pad = 1e-3 * D
    diag = float(np.linalg.norm((hi - lo + 2 * pad) / res))
    g = G.build_occlusion_grid(scene.tri_p, lo - pad, hi + pad, res, max_distance=10.0 * diag)
    return g, G.march_blocks(g)


def _same_read(G, a, b):
    """March blocks a, b identical wherever the march reads them."""
    L = a.cut_locality
    rb = a.bmin * (1.0 - G.BLOCK_REL) < L
    rv = a.vmin.astype(np.float64) * (1.0 - G.BLOCK_REL) < L
    return (np.array_equal(a.bmin, b.bmin) and np.array_equal(a.vmin, b.vmin)
            and np.array_equal(a.bcone[rb], b.bcone[rb]) and np.array_equal(a.vcone[rv], b.vcone[rv]))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--ref", required=True, help="another core/frequency/occlusion_grid.py")
    ap.add_argument("--scenes", default="ring_principled,cornell,principled_interior,bench")
    ap.add_argument("--res", type=int, default=0, help="grid resolution (0: the file's)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--setup", default="", help="also time Renderer() of this .blend at 128^2")
    a = ap.parse_args(argv)
    from fppm.core.frequency import occlusion_grid as G, occlusion_march as Occ
    spec = importlib.util.spec_from_file_location("_occlusion_grid_ref", a.ref)
    OG = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = OG                  # dataclasses look it up
    spec.loader.exec_module(OG)
    print(os.popen("uptime").read().strip())
    for name in a.scenes.split(","):
        if name == "bench":
            import bench_render as BR
            scene, res = BR.cornell(64), 64
        else:
            scene, st = _blend_scene(name)
            res = st.occlusion_grid_res
        res = a.res or res
        ts = {"new": [], "ref": []}
        built = {}
        for rep in range(a.repeat + 1):              # first round: compilation
            for k, M in (("new", G), ("ref", OG)):
                c0 = time.process_time()
                built[k] = _build(M, scene, res)
                if rep:
                    ts[k].append(time.process_time() - c0)
        (gn, mn), (go, mo) = built["new"], built["ref"]
        same = all(np.array_equal(getattr(gn, f), getattr(go, f)) for f in GRID_FIELDS)
        r = np.array(ts["new"]) / np.array(ts["ref"])
        print(f"{name} {res}^3: grid + march blocks {min(ts['new']) * 1e3:.0f} ms, --ref "
              f"{min(ts['ref']) * 1e3:.0f} ms (best of {a.repeat}), paired median "
              f"{np.median(r):.3f}x; grid identical: {same}; march blocks identical where "
              f"read: {_same_read(G, mn, mo)}")
    if a.setup:
        from fppm.core.render import Renderer
        scene, st = _blend_scene(a.setup)
        st = st.replace(integrator="PHOTON", time_limit=0.0, max_passes=100)
        new = (G.build_occlusion_grid, Occ.march_blocks)
        variants = {"FPPM": (st, new), "FPPM --ref": (st, (OG.build_occlusion_grid, OG.march_blocks)),
                    "PPM": (st.replace(use_frequency=False), new)}
        ts = {k: [] for k in variants}
        try:
            for rep in range(a.repeat + 1):
                for k, (s, fns) in variants.items():
                    G.build_occlusion_grid, Occ.march_blocks = fns
                    c0 = time.process_time()
                    Renderer(scene, s, log=lambda s: None)
                    if rep:
                        ts[k].append(time.process_time() - c0)
        finally:
            G.build_occlusion_grid, Occ.march_blocks = new
        print(f"{a.setup} 128^2, Renderer() CPU, best / median of {a.repeat}: " + "; ".join(
            f"{k} {min(v) * 1e3:.0f} / {np.median(v) * 1e3:.0f} ms" for k, v in ts.items()))
    print(os.popen("uptime").read().strip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
