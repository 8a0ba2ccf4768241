"""Sweep ``hold_alpha``: FPPM against PPM on an example scene at equal CPU time.

    .venv/bin/python bench/bench_hold_alpha.py indirect_room [--hold 0.9,0.95,0.98,1.0]
        [--passes 64] [--seeds 0,1] [--photons 100000] [--ref-passes 100] [--ref-photons 300000]
    .venv/bin/python bench/bench_hold_alpha.py indirect_room --hold "" --passes 116 --report 29,58,116
        (PPM only, to read it at FPPM's CPU time)
    .venv/bin/python bench/bench_hold_alpha.py indirect_room --cost-only 24
        (CPU per pass of PPM and FPPM, stepped alternately in one process)

The protocol of docs/method.md ("Consistent holds", "Radius rules"): the
.blend at 50 % resolution (64x64) with the file's settings, photon mapping
only, one numba thread; relMSE against a PPM render of seed 100 with more
photons and passes (its floor: the relMSE between its half- and full-pass
images).  Every method renders with ``Renderer.step`` from the same export.
CPU time (``time.process_time``, one thread: less sensitive than wall time to
the shared machine's load) is recorded per pass, so PPM's relMSE is also read at FPPM's
CPU time (PPM renders ``--ppm-extra`` more passes for that and its error is
interpolated in log-log).  Per-run CPU times scatter under a shared
machine's load; ``--cost-only`` gives the FPPM/PPM cost ratio robustly, and
PPM's error at ``ratio x`` FPPM's passes is then the equal-time comparison
(docs/method.md "hold_alpha sweep").  Prints one line per method, seed and report pass.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)
import bpy_helpers  # noqa: E402

from fppm.core.render import Renderer  # noqa: E402
from fppm.tools.metrics import relmse  # noqa: E402


def export(name):
    bpy = bpy_helpers.bpy()
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "example_blends", name + ".blend"),
                             load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = 50
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    return scene, settings_from_scene(sc).replace(integrator="PHOTON", time_limit=0.0)


def run(scene, st, passes):
    """(images (passes, H, W, 3) float64, CPU seconds per pass, held fraction at the end)."""
    r = Renderer(scene, st.replace(max_passes=passes), log=lambda s: None)
    imgs, cpu = [], []
    for _ in range(passes):
        c0 = time.process_time()
        res = r.step()
        cpu.append(time.process_time() - c0)
        imgs.append(np.asarray(res.image[..., :3], dtype=np.float64).copy())
    held = float(np.mean(r.state.held)) if getattr(r.state, "held", None) is not None else float("nan")
    return np.stack(imgs), np.array(cpu), held


def ppm_at_cpu(err, cpu, t):
    """PPM's relMSE at CPU time t: log-log interpolation over its passes, or,
    beyond its last pass, the power law of its last octave of passes
    extrapolated (flagged True)."""
    le, lc = np.log(err), np.log(cpu)
    if t <= cpu[-1]:
        return float(np.exp(np.interp(np.log(t), lc, le))), False
    h = len(err) // 2 - 1
    slope = (le[-1] - le[h]) / (lc[-1] - lc[h])
    return float(np.exp(le[-1] + slope * (np.log(t) - lc[-1]))), True


def cost(scene, st, passes, say):
    """CPU seconds per pass of PPM and FPPM, stepped alternately in one
    process so that the machine's load drifts over both alike (the first 2
    passes, compilation and warm-up, are left out)."""
    rs = {"ppm": Renderer(scene, st.replace(use_frequency=False, max_passes=passes), log=lambda s: None),
          "fppm": Renderer(scene, st.replace(max_passes=passes), log=lambda s: None)}
    cpu = {k: [] for k in rs}
    for _ in range(passes):
        for k, r in rs.items():
            c0 = time.process_time()
            r.step()
            cpu[k].append(time.process_time() - c0)
    c = {k: np.array(v[2:]) for k, v in cpu.items()}
    for k, v in c.items():
        say(f"cost {k}: {1e3 * v.mean():.1f} ms CPU per pass (median {1e3 * np.median(v):.1f}, n {v.size})")
    say(f"cost fppm/ppm: mean {c['fppm'].mean() / c['ppm'].mean():.3f}, "
        f"median {np.median(c['fppm']) / np.median(c['ppm']):.3f}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--hold", default="0.9,0.95,0.98,1.0")
    ap.add_argument("--passes", type=int, default=64)
    ap.add_argument("--ppm-extra", type=int, default=8)
    ap.add_argument("--report", default="16,32,64")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--photons", type=int, default=100_000)
    ap.add_argument("--ref-passes", type=int, default=100)
    ap.add_argument("--ref-photons", type=int, default=300_000)
    ap.add_argument("--cost-only", type=int, default=0, metavar="K",
                    help="only measure CPU per pass, PPM and FPPM (--hold's first value) "
                         "stepped alternately K passes each in this process")
    a = ap.parse_args()
    scene, base = export(a.scene)
    base = base.replace(photons_per_pass=a.photons)
    say = lambda s: print(s, flush=True)  # noqa: E731
    say(f"# {a.scene}: {base.photons_per_pass} photons/pass, alpha {base.alpha}, "
        f"verify_holds {base.verify_holds}, file hold_alpha {base.hold_alpha}")

    if a.cost_only:
        return cost(scene, base.replace(hold_alpha=float(a.hold.split(",")[0])), a.cost_only, say)
    t0 = time.process_time()
    ref_imgs, _, _ = run(scene, base.replace(use_frequency=False, seed=100,
                                             photons_per_pass=a.ref_photons), a.ref_passes)
    ref = ref_imgs[-1]
    floor = relmse(ref_imgs[a.ref_passes // 2 - 1], ref)
    del ref_imgs
    say(f"# reference: {a.ref_passes} passes x {a.ref_photons} photons, seed 100, "
        f"{time.process_time() - t0:.0f} s CPU; floor (half vs full) {floor:.3e}")

    report = [int(p) for p in a.report.split(",")]
    seeds = [int(s) for s in a.seeds.split(",")]
    ppm = {}
    for seed in seeds:
        imgs, cpu, _ = run(scene, base.replace(use_frequency=False, seed=seed), a.passes + a.ppm_extra)
        ppm[seed] = (np.array([relmse(im, ref) for im in imgs]), np.cumsum(cpu))
        e, c = ppm[seed]
        for p in report:
            say(f"ppm seed {seed} pass {p} relmse {e[p - 1]:.4e} cpu {c[p - 1]:.2f}")
    for h in [float(x) for x in a.hold.split(",") if x]:   # --hold "": PPM only
        for seed in seeds:
            imgs, cpu, held = run(scene, base.replace(hold_alpha=h, seed=seed), a.passes)
            e = np.array([relmse(im, ref) for im in imgs])
            c = np.cumsum(cpu)
            pe, pc = ppm[seed]
            for p in report:
                pe_t, extra = ppm_at_cpu(pe, pc, c[p - 1])
                say(f"fppm hold {h} seed {seed} pass {p} relmse {e[p - 1]:.4e} cpu {c[p - 1]:.2f} "
                    f"ratio_pass {e[p - 1] / pe[p - 1]:.3f} ratio_cpu {e[p - 1] / pe_t:.3f}"
                    + (" (extrapolated)" if extra else "")
                    + (f" held {held:.3f}" if p == report[-1] else ""))


if __name__ == "__main__":
    main()
