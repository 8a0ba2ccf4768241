"""Camera paths at glossy vertices: the vertex kernels, the compiled BSDF calls and numpy.

    .venv/bin/python bench/bench_path_bsdf.py [default_cube principled_interior real_scene]
        [--percent 25] [--repeat 5] [--modes PATH,COMBINED] [--cycles | --threads]

For each scene (``default_cube``: Blender's factory start-up file, the cube
with the default Principled BSDF; else an ``example_blends/`` file) at
--percent of its resolution, exported as F12 does, a renderer of each
integrator, then one pass of its camera paths (``PathTracer.__call__``,
camera_samples per pixel) three ways, interleaved, the same random stream
in a round, one numba thread:

- ``numpy``: ``PathTracer.compiled`` off, the reference (radiance-mode
  sample_bsdf, eval_bsdf, pdf_bsdf in numpy);
- ``calls``: numpy vertices whose GENERIC rows' BSDF calls run compiled
  (core.materials.compiled "Radiance mode over arrays"; the vertex kernels
  limited to Lambert, mirror and glass: ``path_kernels.GENERIC_SCOPE`` off,
  round 24's path);
- ``kernels``: the vertex kernels of core.integrators.path_kernels with
  GENERIC materials in their scope (the default).

It prints process CPU, min of --repeat, the ratios numpy ÷ kernels and
calls ÷ kernels with their paired medians, and the largest difference of
each image from numpy's relative to the image's largest pixel.  A scene
that the kernels do not cover (textures, Normal Map / Bump) runs ``calls``
in both of the last two.  --cycles: also Cycles on the same file at the
same size (non-adaptive, no denoising, CPU), rendered in a process of its
own (no numba or Embree threads there, as ``fppm converge``'s Cycles
ladder): its process CPU a path at the margin (4 and 64 x the paths a
pixel, the difference) beside FPPM's.
--threads: instead, the kernels' pass on one thread and on two
(``core.sppm.photons.THREADS``; the pass's pixel blocks shared,
``PathTracer.blocks``), interleaved: wall time one ÷ two, the cores each
used (process CPU ÷ wall), and whether the two images are the same bits.  Ratios
measured in one run (docs/integrators.md "Compiled BSDF calls at glossy
camera vertices, round 24", "GENERIC materials in the vertex kernels,
round 25").
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)
import bpy_helpers  # noqa: E402


def export(name: str, percent: int):
    """(core Scene, RenderSettings) of a scene as F12 exports it."""
    bpy = bpy_helpers.bpy()
    if name == "default_cube":
        bpy.ops.wm.read_factory_settings()
    else:
        bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "example_blends", name + ".blend"),
                                 load_ui=False, use_scripts=False)
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    sc = bpy.context.scene
    sc.render.resolution_percentage = percent
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    return scene, settings_from_scene(sc).replace(time_limit=0.0, max_passes=1)


CYCLES = r"""
import os, sys, time
import bpy
name, pct, spp = sys.argv[-3], int(sys.argv[-2]), int(sys.argv[-1])
if name == "default_cube":
    bpy.ops.wm.read_factory_settings()
else:
    bpy.ops.wm.open_mainfile(filepath=name, load_ui=False, use_scripts=False)
sc = bpy.context.scene
sc.render.engine = "CYCLES"
sc.render.resolution_percentage = pct
c = sc.cycles
c.device, c.samples, c.use_adaptive_sampling, c.use_denoising = "CPU", spp, False, False
c.time_limit = 0.0
bpy.ops.render.render()                      # warm (kernels, BVH)
t = time.process_time()
bpy.ops.render.render()
print("CPU", time.process_time() - t)
"""


def cycles_cpu(name: str, percent: int, spp: int) -> float:
    """Process CPU of one Cycles render of ``spp`` samples a pixel (its own process)."""
    import subprocess
    path = name if name == "default_cube" else os.path.join(ROOT, "example_blends",
                                                           name + ".blend")
    r = subprocess.run([sys.executable, "-c", CYCLES, path, str(percent), str(spp)],
                       capture_output=True, text=True, check=True)
    return float([x for x in r.stdout.splitlines() if x.startswith("CPU ")][-1].split()[1])


VARIANTS = ("numpy", "calls", "kernels")


def one(pt, variant: str, seed: int):
    """(image (P, 3), process CPU seconds) of one call of the camera paths
    the ``variant`` way (module docstring)."""
    from fppm.core.integrators import path_kernels as PK
    PK.GENERIC_SCOPE = variant == "kernels"
    pt.compiled = variant != "numpy"
    pt._kernels = None
    pt.kernels()                      # the scene's kernel tables, built outside the clock
    c0 = time.process_time()
    L = pt(np.random.default_rng(seed))
    return L, time.process_time() - c0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", default=["default_cube", "principled_interior",
                                                  "real_scene"])
    ap.add_argument("--percent", type=int, default=25)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--modes", default="PATH,COMBINED")
    ap.add_argument("--cycles", action="store_true",
                    help="also time Cycles (its own process) at the same paths a pixel")
    ap.add_argument("--threads", action="store_true",
                    help="time the kernels' pass on one thread against two (wall, cores)")
    a = ap.parse_args(argv)
    from fppm.core.render import Renderer
    if a.threads:
        return threads(a, Renderer)
    print("scene, integrator: numpy / calls / kernels CPU (min), numpy and calls ÷ kernels "
          "(paired median), max |diff| / max pixel")
    for name in a.scenes:
        scene, st = export(name, a.percent)
        for mode in a.modes.split(","):
            r = Renderer(scene, st.replace(integrator=mode), log=lambda s: None)
            pt = r.path_tracer
            if pt is None or (pt.camera_stop is not None and pt.camera_stop.camera_free):
                print(f"{name}, {mode}: no camera paths (light tracing takes them)")
                continue
            for v in VARIANTS:
                one(pt, v, 0)                           # warm: kernels, tables
            t = {v: [] for v in VARIANTS}
            diff = {v: 0.0 for v in VARIANTS[1:]}
            for k in range(a.repeat):
                order = VARIANTS[k % 3:] + VARIANTS[:k % 3]
                got = {v: one(pt, v, 100 + k) for v in order}
                Ln = got["numpy"][0]
                for v in VARIANTS:
                    t[v].append(got[v][1])
                    if v != "numpy":
                        diff[v] = max(diff[v], float(np.abs(got[v][0] - Ln).max()
                                                     / max(Ln.max(), 1e-300)))
            t = {v: np.array(x) for v, x in t.items()}
            tk = t["kernels"]
            print(f"{name}, {mode}: {t['numpy'].min():.3f} / {t['calls'].min():.3f} / "
                  f"{tk.min():.3f} s; numpy ÷ kernels {t['numpy'].min() / tk.min():.2f}x "
                  f"(paired {np.median(t['numpy'] / tk):.2f}x), calls ÷ kernels "
                  f"{t['calls'].min() / tk.min():.2f}x (paired {np.median(t['calls'] / tk):.2f}x); "
                  f"{scene.camera.resolution[0]}x{scene.camera.resolution[1]} px, "
                  f"{st.camera_samples} paths a pixel; max diff {diff['calls']:.1e}, "
                  f"{diff['kernels']:.1e}", flush=True)
            if a.cycles and mode == "PATH":
                w, h = scene.camera.resolution
                paths = w * h * st.camera_samples
                # Cycles' CPU a path at the margin: two renders of 4 and 64
                # x camera_samples spp in one process, their difference over
                # the 60 x camera_samples paths a pixel between them, so
                # that its per-render set-up (scene sync, BVH, an HDRI's
                # importance map) is left out as FPPM's is (its tables are
                # built outside the clock).  Until round 27 one 4 x render
                # was divided by its paths: 2-5x Cycles' marginal cost on
                # 128 x 128 images (docs/integrators.md "Cycles' CPU a path
                # at the margin, round 27").
                lo, hi = 4 * st.camera_samples, 64 * st.camera_samples
                cy_lo, cy_hi = cycles_cpu(name, a.percent, lo), cycles_cpu(name, a.percent, hi)
                cy_path = (cy_hi - cy_lo) / ((hi - lo) * w * h)
                us = {v: 1e6 * t[v].min() / paths for v in VARIANTS}
                print(f"  CPU a path: numpy {us['numpy']:.3f} us, calls {us['calls']:.3f} us, "
                      f"kernels {us['kernels']:.3f} us; Cycles {1e6 * cy_path:.3f} us at the "
                      f"margin ({lo} and {hi} spp in its own process; "
                      f"{1e6 * cy_lo / (lo * w * h):.3f} us a path in the {lo}-spp render "
                      f"alone): kernels ÷ Cycles {us['kernels'] / (1e6 * cy_path):.2f}x",
                      flush=True)


def threads(a, Renderer) -> None:
    """--threads: the kernels' pass on one and two threads (module docstring)."""
    from fppm.core.sppm import photons
    print("scene, integrator: wall one / two threads (min), one ÷ two (paired median), "
          "cores used one / two (median), same bits")
    for name in a.scenes:
        scene, st = export(name, a.percent)
        for mode in a.modes.split(","):
            pt = Renderer(scene, st.replace(integrator=mode), log=lambda s: None).path_tracer
            if pt is None or (pt.camera_stop is not None and pt.camera_stop.camera_free):
                print(f"{name}, {mode}: no camera paths (light tracing takes them)")
                continue
            wall = {1: [], 2: []}
            cores = {1: [], 2: []}
            same = True
            for k in range(a.repeat + 1):
                img = {}
                for n in ((1, 2) if k % 2 == 0 else (2, 1)):
                    photons.THREADS = n
                    w0, c0 = time.perf_counter(), time.process_time()
                    img[n] = pt(np.random.default_rng(100 + k))
                    w, c = time.perf_counter() - w0, time.process_time() - c0
                    if k > 0:                       # the first round warms the kernels
                        wall[n].append(w)
                        cores[n].append(c / w)
                same &= bool(np.array_equal(img[1], img[2]))
            w1, w2 = np.array(wall[1]), np.array(wall[2])
            print(f"{name}, {mode}: {w1.min():.3f} / {w2.min():.3f} s, {w1.min() / w2.min():.2f}x "
                  f"(paired {np.median(w1 / w2):.2f}x); cores {np.median(cores[1]):.2f} / "
                  f"{np.median(cores[2]):.2f}; {pt.blocks()} blocks; same bits: {same}",
                  flush=True)


if __name__ == "__main__":
    main()
