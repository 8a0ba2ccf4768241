"""What the march's rules (docs/frequency.md "Marching only what can matter") cost and change.

    .venv/bin/python bench/bench_march_rules.py [--repeat 10] [--res 256] [--photons 200000]
    .venv/bin/python bench/bench_march_rules.py --images 16 [--blends cornell,coffee_cup,glass_sphere]

Default: bench_render's Cornell box (16 bounces), one renderer with 25 %
frequency photons whose chains run with the old rule ("before":
``ChainParams.march_all = True``, ``r_cut = inf``: every segment whose
spectrum is read is marched, every occluder) and the new one ("after"),
toggled pass by pass in one process, against a renderer without frequency
photons: the photon pass (trace + gather) over the plain one, and a
frequency photon over a classic one (65,536 traced each way), CPU time of
all threads (the machine is shared), median of --repeat (range).

--images N: FPPM at 64^2 on example_blends/<blend>.blend, N passes, seed 7,
before and after, and before with seed 8 (the noise scale): relMSE
mean (x - r)^2 / (r^2 + 0.01) of the images, and the held share and mean
pixel radius after the last pass.
"""
from __future__ import annotations

import argparse
import os
import sys
import types

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))


def _rule(cls, before: bool):
    """Make PhotonTracer class cls build its ChainParams with the old rule (before) or not."""
    orig = getattr(cls, "_chain_params_orig", cls.chain_params)
    cls._chain_params_orig = orig
    cls.chain_params = ((lambda self: orig(self)._replace(march_all=True, r_cut=np.inf))
                        if before else orig)


def cost(a):
    import bench_render as BR
    from core.sppm.photons import PhotonTracer
    ns = types.SimpleNamespace(photons=a.photons, bounces=16, numpy=False)
    scene = BR.cornell(a.res)
    tm = BR.Timers()
    r = BR.make_renderer(scene, ns, True, tm)
    r0 = BR.make_renderer(scene, ns, False, tm)
    pp = {True: [], False: []}
    per = {True: [], False: []}
    n = min(a.photons, 65536)
    for k in range(a.repeat):
        d0, _ = BR.photon_pass(r0, tm)
        base = d0["trace_cpu"] + d0["gather_cpu"]
        order = (True, False) if k % 2 == 0 else (False, True)
        for before in order:
            _rule(PhotonTracer, before)
            d, _ = BR.photon_pass(r, tm)
            pp[before].append((d["trace_cpu"] + d["gather_cpu"]) / base - 1)
        tc, _ = BR.trace_seconds(r0, tm, n, 0, 100 + k)
        for before in order:
            _rule(PhotonTracer, before)
            tf, _ = BR.trace_seconds(r, tm, n, n, 100 + k)
            per[before].append(tf / tc)
    _rule(PhotonTracer, False)
    print(f"bench Cornell {a.res}^2, {a.photons} photons, 16 bounces, median of {a.repeat} (range)")
    for before, name in ((True, "before"), (False, "after")):
        x, y = np.array(pp[before]), np.array(per[before])
        print(f"  {name}: photon pass vs none {np.median(x):+.0%} ({x.min():+.0%} to {x.max():+.0%});"
              f" frequency / classic photon {np.median(y):.2f}x ({y.min():.2f} to {y.max():.2f})")
    print(f"  paired after / before, a frequency photon: "
          f"{np.median(np.array(per[False]) / np.array(per[True])):.3f}")


def images(a):
    import fppm_alias  # noqa: F401  (fppm.* importable)
    import bpy  # noqa: F401
    from fppm.addon.cli import open_blend, render_scene
    from fppm.addon.engine import RenderSession
    from fppm.core.sppm.photons import PhotonTracer

    def render(blend, before, seed):
        _rule(PhotonTracer, before)
        out = {}
        sess = RenderSession(log=lambda s: None,
                             on_pass=lambda pr, st: out.update(img=pr.image[..., :3].astype(float)))
        scene = open_blend(os.path.join(ROOT, "example_blends", blend + ".blend"))
        scene.render.resolution_x = scene.render.resolution_y = 64
        scene.render.resolution_percentage = 100
        render_scene(scene, dict(integrator="PHOTON", use_frequency=True, max_passes=a.images,
                                 time_limit=0.0, seed=seed), sess)
        st = sess.renderer.state
        v = st.R2 > 0
        return out["img"], float(st.held[v].mean()), float(np.sqrt(st.R2[v]).mean())

    def rel(x, r):
        return float(np.mean((x - r) ** 2 / (r ** 2 + 0.01)))
    for blend in a.blends.split(","):
        A, ha, ra = render(blend, True, 7)
        B, hb, rb = render(blend, False, 7)
        C, _, _ = render(blend, True, 8)
        print(f"{blend}: {a.images} passes at 64^2: relMSE after vs before {rel(B, A):.2e}, "
              f"noise (before, seed 8 vs 7) {rel(C, A):.2e}; mean {A.mean():.5f} -> {B.mean():.5f};"
              f" held {ha:.1%} -> {hb:.1%}; mean radius {ra:.4f} -> {rb:.4f} m", flush=True)
    _rule(PhotonTracer, False)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--images", type=int, default=0)
    ap.add_argument("--blends", default="cornell,coffee_cup,glass_sphere")
    a = ap.parse_args(argv)
    images(a) if a.images else cost(a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
