"""Does a render agree with its Cycles reference at the edges? Chi-square by region.

    .venv/bin/python bench/edge_agreement.py [SCENE] [INTEGRATOR] [PASSES]

SCENE is a test scene with a Cycles reference (tests/references, default
t_cornell), INTEGRATOR PATH, PHOTON, LIGHT or COMBINED (default PHOTON),
PASSES the passes of each of two seeds (default 256, 100,000 photons a
pass).  Prints, per region of ``tools.metrics.region_masks`` (smooth,
caustic, and the rest: edges and gradients), the sum of squared
differences from the reference over the sum of the expected ones (the
two-seed mean's variance, (a1 - a2)^2 / 4, plus the reference's stored
variance): about 1 for an unbiased render that agrees, above where a bias
or a difference of camera or filter shows (docs/method.md "What the error
at 60 s is made of, round 36").
"""
from __future__ import annotations

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

import fppm_alias  # noqa: E402,F401


def main(name="t_cornell", integrator="PHOTON", passes=256):
    import bpy
    from scenes.refs import RELMSE_EPS, load_reference, load_variance, scene_path
    from fppm.addon.export import export_scene
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    from fppm.tools.metrics import region_masks
    ref = load_reference(name)[0][..., :3].astype(np.float64)
    var_ref = load_variance(name)[..., :3].astype(np.float64)
    bpy.ops.wm.open_mainfile(filepath=scene_path(name), load_ui=False, use_scripts=False)
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    a = []
    for seed in (1, 2):
        st = RenderSettings(integrator=integrator, max_passes=passes, photons_per_pass=100_000,
                            seed=seed, use_frequency=False, max_bounces=16)
        a.append(Renderer(scene, st, log=lambda s: None).run().image[..., :3].astype(np.float64))
    m = 0.5 * (a[0] + a[1])
    var_m = (a[0] - a[1]) ** 2 / 4
    R = region_masks(ref)
    rest = ~R["smooth"] & ~R["caustic"]
    for k, msk in (("smooth", R["smooth"]), ("caustic", R["caustic"]), ("rest", rest),
                   ("all", np.ones_like(rest))):
        if not msk.any():
            continue
        chi = ((m - ref) ** 2)[msk].sum() / (var_m + var_ref)[msk].sum()
        rel = float(np.mean(((m - ref) ** 2 / (ref ** 2 + RELMSE_EPS))[msk]))
        print(f"{name} {integrator} {passes} passes: {k:8s} {int(msk.sum()):5d} px, "
              f"chi2 / expected {chi:6.3f}, relMSE {rel:.3e}, "
              f"mean ratio {m[msk].mean() / ref[msk].mean():.4f}")


if __name__ == "__main__":
    args = sys.argv[1:]
    main(*(args[:2]), *([int(args[2])] if len(args) > 2 else []))
