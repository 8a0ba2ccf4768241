"""What the march's rules (docs/frequency.md "Marching only what can matter") cost and change.

    .venv/bin/python bench/bench_march_rules.py [--repeat 10] [--res 256] [--photons 200000]
    .venv/bin/python bench/bench_march_rules.py --images 16 [--blends cornell,coffee_cup,glass_sphere]
    .venv/bin/python bench/bench_march_rules.py --blend example_blends/indirect_room.blend

Default: bench_render's Cornell box (16 bounces), one renderer with 25 %
frequency photons whose chains run with the old rule ("before":
``ChainParams.march_all = True``, ``r_cut = inf``: every segment whose
spectrum is read is marched, every occluder) and the new one ("after"),
toggled pass by pass in one process, against a renderer without frequency
photons: the photon pass (trace + gather) over the plain one, and a
frequency photon over a classic one (65,536 traced each way), CPU time of
all threads (the machine is shared), median of --repeat (range); and the
marginal cost of a frequency photon among classic ones (a quarter of the
65,536).  --blend: the tracer of that scene at --blend-res after two
passes (no photon-pass line).

--images N: FPPM at 64^2 on example_blends/<blend>.blend, N passes, seed 7,
before and after, and before with seed 8 (the noise scale): relMSE
mean (x - r)^2 / (r^2 + 0.01) of the images, and the held share and mean
pixel radius after the last pass.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import types

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))


#: The rules before, by name (--rule): "used", every read segment marched
#: and every occluder (docs/frequency.md "Marching only what can matter").
RULES = {"used": dict(march_all=True, r_cut=np.inf)}


def _rule(cls, before: bool, rule: str = "used"):
    """Make PhotonTracer class cls build its ChainParams with the old rule (before) or not."""
    orig = getattr(cls, "_chain_params_orig", cls.chain_params)
    cls._chain_params_orig = orig
    cls.chain_params = ((lambda self: orig(self)._replace(**RULES[rule])) if before else orig)


def cost(a):
    import bench_render as BR
    from core.sppm.photons import PhotonTracer
    if a.blend:
        _rule(PhotonTracer, False)
        r = BR.blend_renderer(a.blend, a.blend_res)
        from fppm.core.sppm.photons import PhotonTracer    # the class bpy's add-on uses
        tm = r0 = None
    else:
        ns = types.SimpleNamespace(photons=a.photons, bounces=16, numpy=False, decay=0.0)
        scene = BR.cornell(a.res)
        tm = BR.Timers()
        r = BR.make_renderer(scene, ns, True, tm)
        r0 = BR.make_renderer(scene, ns, False, tm)
    tr = r.tracer

    def cpu(n, nf, seed):
        c0 = time.process_time()
        tr.trace(n, nf, np.random.default_rng(seed))
        return time.process_time() - c0
    pp = {True: [], False: []}
    per = {True: [], False: []}
    marg = {True: [], False: []}
    n = min(a.photons, 65536)
    for k in range(a.repeat):
        order = (True, False) if k % 2 == 0 else (False, True)
        if r0 is not None:
            d0, _ = BR.photon_pass(r0, tm)
            base = d0["trace_cpu"] + d0["gather_cpu"]
            for before in order:
                _rule(PhotonTracer, before, a.rule)
                d, _ = BR.photon_pass(r, tm)
                pp[before].append((d["trace_cpu"] + d["gather_cpu"]) / base - 1)
        tc = cpu(n, 0, 100 + k)
        for before in order:
            _rule(PhotonTracer, before, a.rule)
            per[before].append(cpu(n, n, 100 + k) / tc)
            marg[before].append((cpu(n, n // 4, 200 + k) - tc) / (n // 4) / (tc / n))
    _rule(PhotonTracer, False)
    where = (os.path.basename(a.blend) + f" {a.blend_res}^2" if a.blend
             else f"bench Cornell {a.res}^2, {a.photons} photons")
    print(f"{where}{'' if a.blend else ', 16 bounces'}, rule {a.rule!r}, median of {a.repeat} (range), "
          f"load {os.getloadavg()[0]:.1f}")
    for before, name in ((True, "before"), (False, "after")):
        x, y, z = np.array(pp[before]), np.array(per[before]), np.array(marg[before])
        line = f"  {name}: "
        if x.size:
            line += f"photon pass vs none {np.median(x):+.0%} ({x.min():+.0%} to {x.max():+.0%}); "
        print(line + f"frequency / classic photon {np.median(y):.2f}x ({y.min():.2f} to "
              f"{y.max():.2f}); a quarter of {n} among classic ones, marginal "
              f"{np.median(z):.2f}x ({z.min():.2f} to {z.max():.2f})")
    print(f"  paired after / before, a frequency photon: "
          f"{np.median(np.array(per[False]) / np.array(per[True])):.3f}; marginal: "
          f"{np.median(np.array(marg[False]) / np.array(marg[True])):.3f}")


def images(a):
    import fppm_alias  # noqa: F401  (fppm.* importable)
    import bpy  # noqa: F401
    from fppm.addon.cli import open_blend, render_scene
    from fppm.addon.engine import RenderSession
    from fppm.core.sppm.photons import PhotonTracer

    def render(blend, before, seed):
        _rule(PhotonTracer, before, a.rule)
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
    ap.add_argument("--rule", default="used", choices=sorted(RULES),
                    help="the rule toggled (RULES)")
    ap.add_argument("--blend", default="", help="cost: the tracer of this .blend instead")
    ap.add_argument("--blend-res", type=int, default=64)
    a = ap.parse_args(argv)
    images(a) if a.images else cost(a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
