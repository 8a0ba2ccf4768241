"""Does an example scene render as Cycles renders it?  Means and blocks, two seeds each.

    .venv/bin/python bench/example_agreement.py [BLEND] [INTEGRATOR] [PASSES] [SAMPLES]

BLEND an example of example_blends/ (default real_scene.blend), INTEGRATOR
PATH, PHOTON, LIGHT or COMBINED (default PHOTON), PASSES each FPPM seed's
passes (default 64), SAMPLES each Cycles seed's samples (default 1024); both
at half the file's resolution (64 x 64 for the examples), FPPM at the file's
own settings otherwise.  Prints the FPPM / Cycles ratio of the image's mean
and of its lower and upper halves with each side's seed-to-seed difference,
and the mean |difference| of 8 x 8-pixel block means against the two sides'
seed noise there: about 1 or below where FPPM agrees (docs/shading.md
"Roughness maps" quotes it on real_scene.blend).
"""
from __future__ import annotations

import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

import fppm_alias  # noqa: E402,F401


def cycles(sc, seed, samples, path):
    """One Cycles render of the open scene (its own settings, seed, samples) as (H, W, 3)."""
    import bpy
    import OpenEXR
    sc.render.engine = 'CYCLES'
    sc.cycles.samples = samples
    sc.cycles.seed = seed
    sc.render.filepath = path
    sc.render.image_settings.file_format = 'OPEN_EXR'
    sc.render.image_settings.color_depth = '32'
    bpy.ops.render.render(write_still=True)
    with OpenEXR.File(path) as f:
        ch = f.channels()
        rgb = ch["RGB"].pixels if "RGB" in ch else ch["RGBA"].pixels[..., :3]
    return np.asarray(rgb, np.float64)


def main(blend="real_scene.blend", integrator="PHOTON", passes=64, samples=1024):
    import bpy
    import bpy_helpers as H
    from fppm.addon.export import export_scene
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    bpy.ops.wm.open_mainfile(filepath=os.path.join(H.ROOT, "example_blends", blend),
                             load_ui=False, use_scripts=False)
    H.ensure_registered()
    sc = bpy.context.scene
    sc.render.resolution_percentage = 50
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    with tempfile.TemporaryDirectory() as tmp:
        c = [cycles(sc, k, samples, os.path.join(tmp, f"c{k}.exr")) for k in (0, 1)]
    f = []
    for seed in (1, 2):
        st = RenderSettings(integrator=integrator, max_passes=passes, seed=seed,
                            max_bounces=16)
        f.append(Renderer(scene, st, log=lambda s: None).run().image[..., :3].astype(np.float64))
    ref, img = (c[0] + c[1]) / 2, (f[0] + f[1]) / 2
    Hh, W = ref.shape[:2]
    print(f"{blend} {integrator} {passes} passes against Cycles {samples} samples, {W}x{Hh}:")
    for name, sl in (("image", np.s_[:, :]), ("lower half", np.s_[Hh // 2:, :]),
                     ("upper half", np.s_[:Hh // 2, :])):
        r = ref[sl].mean()
        print(f"  {name:10s} FPPM / Cycles {img[sl].mean() / r:.4f}; seed to seed: "
              f"FPPM {abs(f[0][sl].mean() - f[1][sl].mean()) / r:.4f}, "
              f"Cycles {abs(c[0][sl].mean() - c[1][sl].mean()) / r:.4f}")

    def blocks(a):
        return a[:Hh // 8 * 8, :W // 8 * 8].reshape(Hh // 8, 8, W // 8, 8, 3).mean(axis=(1, 3))
    err = np.abs(blocks(img) - blocks(ref)).mean() / ref.mean()
    noise = (np.abs(blocks(f[0]) - blocks(f[1])).mean()
             + np.abs(blocks(c[0]) - blocks(c[1])).mean()) / 2 / ref.mean()
    print(f"  8x8 blocks: mean |FPPM - Cycles| {err:.4f} of the mean, seed noise {noise:.4f} "
          f"({err / noise:.2f}x)")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(*a[:2], *[int(x) for x in a[2:4]])
