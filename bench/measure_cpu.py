"""Equal-CPU-time relMSE of FPPM's integrators against a reference (docs/integrators.md).

    .venv/bin/python bench/measure_cpu.py BLEND PCT BUDGET RUNS [--ref light:SECONDS] [--seeds 7,8]
    .venv/bin/python bench/measure_cpu.py BLEND PCT ROUNDS RUNS --cost
    .venv/bin/python bench/measure_cpu.py BLEND PCT BUDGET RUNS --ref exr:REF.exr [--tree DIR]

RUNS: comma-separated fppm, ppm, path<K>, light, combined<K> (K = camera
samples, default 4), cycles; a suffix :p<N> sets photons_per_pass (light
paths per pass for light and combined), :r<X> sets light_paths_per_camera_path
(combined: X light paths per camera path), :d0, :d1, :df, :da set camera_depth
(combined: 'EMITTERS', 'DIRECT', 'FULL', 'AUTO'), :mmis (last) merging as an MIS
strategy (merge_weights 'MIS'; :mppm the same without frequency photons,
PPM radii), :i<X> sets initial_radius_px, :n<N> renders N passes whatever
the time (equal light paths), :own0 (last) turns the rule
core.integrators.mis.NEE_OWNS_DELTA_DIRECT off for that run.  The reference is Cycles at 8192 spp (cached
under ~/.cache/fppm/references/ as ``fppm converge`` does), or with
``--ref light:S`` a light-tracing render of S CPU seconds (for scenes Cycles
cannot render, such as a radius-0 point light's caustic; cached in
~/.cache/fppm/references/ by blend, resolution and seconds), or with
``--ref exr:PATH`` an EXR read as ``fppm converge --reference`` reads it
(the point caustic's Mitsuba light tracer; its noise floor is printed).
``--tree DIR``: the runs are rendered by the checkout DIR (its .venv and
its own copy of BLEND's file name under DIR/example_blends/ when there is
one), in a process of their own (:data:`TREE_RENDER`: only the API that the
code of November 2026 already had), so that an older commit's integrator is
measured with the same clock and error as today's.  ``--seeds``:
the runs' seeds (default 7), every run once per seed, interleaved (seed by
seed, the runs in turn) so that a shared machine's load falls on all alike.

"camera share": the camera paths' part of the camera + light-tracing
wall seconds of the passes (``stage_seconds``; the effort split of COMBINED).

CPU time = time.process_time() of this process (all its threads: Cycles',
numba's, Embree's): the machine is shared, wall time is not a clock.
relMSE = mean (x - r)^2 / (r^2 + 0.01) (tools.metrics.relmse).

``--cost``: CPU seconds of one pass of each run, the runs' passes stepped in
turn (round robin, ROUNDS passes each after a first untimed one, the order
reversed every other round) so that the load of a shared machine falls on
all of them alike, and each run's CPU over the first run's, round by round
(mean +- standard error); no reference.
With a run's passes n and relMSE e from an equal-CPU run, e * n is its
error after one pass (seeded, so free of the load) and e * n * (CPU of a
pass) / T its error at T CPU seconds.
"""
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                "tests"))
import fppm_alias  # noqa: F401,E402  (fppm.* importable)
import bpy  # noqa: E402
from fppm.addon.cli import open_blend, render_scene  # noqa: E402
from fppm.addon.engine import RenderSession  # noqa: E402
from fppm.tools.converge.references import (cycles_reference_setup, cycles_render,  # noqa: E402
                                            layer, load_reference, make_reference)
from fppm.tools.metrics import reference_floor, relmse as relmse_of  # noqa: E402


def settings_of(run: str) -> dict:
    if run.endswith(":own0"):                # the rule mis.NEE_OWNS_DELTA_DIRECT off (no setting)
        return dict(settings_of(run[:-5]), _nee_owns=False)
    if run.endswith(":mmis"):                # e.g. combined4:mmis -- merging as an MIS strategy
        return dict(settings_of(run[:-5]), merge_weights="MIS")
    if run.endswith(":mppm"):                # the same with PPM radii (no frequency photons)
        return dict(settings_of(run[:-5]), merge_weights="MIS", use_frequency=False)
    if ":n" in run:                          # e.g. light:n40 -- 40 passes, no time budget
        run, n = run.split(":n")
        return dict(settings_of(run), max_passes=int(n))
    if ":r" in run:                          # e.g. combined4:r12.2 -- light paths per camera path
        run, r = run.split(":r")
        return dict(settings_of(run), light_paths_per_camera_path=float(r))
    if ":i" in run:                          # e.g. combined4:i1:mmis -- initial radius, pixels
        run, x = run.split(":i")
        return dict(settings_of(run), initial_radius_px=float(x))
    if ":d" in run:                          # e.g. combined4:d0 -- camera_depth (CameraStop)
        run, x = run.split(":d")
        return dict(settings_of(run), camera_depth={"0": "EMITTERS", "1": "DIRECT", "f": "FULL",
                                                    "a": "AUTO"}[x])
    if ":p" in run:                          # e.g. combined4:p50000
        run, n = run.split(":p")
        return dict(settings_of(run), photons_per_pass=int(n))
    if run.startswith("path"):
        return dict(integrator="PATH", camera_samples=int(run[4:] or 4))
    if run.startswith("combined"):
        return dict(integrator="COMBINED", camera_samples=int(run[8:] or 4))
    if run == "light":
        return dict(integrator="LIGHT")
    return dict(integrator="PHOTON", use_frequency=(run == "fppm"))


def _rule(kw: dict):
    """kw without the bench-only key ``_nee_owns``, after setting
    mis.NEE_OWNS_DELTA_DIRECT from it (default on; read when a renderer is built)."""
    from fppm.core.integrators import mis
    mis.NEE_OWNS_DELTA_DIRECT = kw.pop("_nee_owns", True)
    return kw


def render_cpu(blend, pct, budget, run, seed=7, log=True):
    """(image, cpu seconds, passes) of ``run`` stopped after ``budget`` CPU seconds."""
    kw = _rule(dict(dict(max_passes=100000), **settings_of(run), time_limit=0.0, seed=seed))
    if kw["max_passes"] < 100000:
        budget = float("inf")                # equal passes, not equal time
    # Untimed warm-up: numba kernels from the disk cache.
    render_scene(open_blend(blend, resolution=pct), dict(kw, max_passes=1),
                 RenderSession(log=lambda s: None))
    last = {}

    def on_pass(pr, settings):
        last.update(img=pr.image[..., :3].astype(float) * sess.gain,
                    cpu=time.process_time() - c0, wall=time.perf_counter() - w0, n=pr.pass_index)
    sess = RenderSession(on_pass=on_pass, log=lambda s: None,
                         should_stop=lambda: time.process_time() - c0 > budget)
    scene = open_blend(blend, resolution=pct)
    c0, w0 = time.process_time(), time.perf_counter()
    render_scene(scene, kw, sess)
    _rule({})
    last["camera_share"] = camera_share(sess.renderer)
    return last


def camera_share(renderer) -> float:
    """The camera paths' part of the camera + light-tracing seconds of the passes."""
    st = getattr(renderer, "stage_seconds", {})
    side = st.get("camera", 0.0) + st.get("photon_trace", 0.0)
    return st.get("camera", 0.0) / side if side > 0 else float("nan")


def pass_costs(blend, pct, rounds, runs):
    """{run: (CPU s of a pass, camera share, its CPU / the first run's per
    round: mean and standard error)}, passes stepped round robin, the order
    reversed every other round (no run always after the same one)."""
    rend = {}
    for run in runs:
        kw = _rule(dict(settings_of(run), time_limit=0.0, max_passes=1, seed=7))
        sess = RenderSession(log=lambda s: None)
        render_scene(open_blend(blend, resolution=pct), kw, sess)
        rend[run] = sess.renderer
        rend[run]._should_stop = lambda: False     # the Blender engine is gone
    _rule({})
    cpu = {run: [] for run in runs}
    for i in range(rounds):
        for run in (runs if i % 2 == 0 else runs[::-1]):
            c0 = time.process_time()
            rend[run].step()
            cpu[run].append(time.process_time() - c0)
    out = {}
    for run, r in rend.items():
        ratio = np.asarray(cpu[run]) / np.asarray(cpu[runs[0]])
        se = float(ratio.std(ddof=1) / math.sqrt(rounds)) if rounds > 1 else float("nan")
        out[run] = (float(np.mean(cpu[run])), camera_share(r), float(ratio.mean()), se)
    return out


#: The render of a ``--tree`` run, run by that checkout's python with one
#: JSON argument (tree, blend, pct, budget, settings, seed, out): the file
#: opened with scripts off and exported from the viewport depsgraph (as
#: ``fppm converge`` did then), an untimed one-pass warm-up (kernels from
#: the disk cache), then the CPU clock from the Renderer's set-up on, as
#: :func:`render_cpu`; the last complete pass x Film > Exposure is saved to
#: out (.npy) and its CPU seconds and pass count printed as JSON.
TREE_RENDER = r"""
import json, os, sys, time
import numpy as np
a = json.loads(sys.argv[1])
sys.path.insert(0, os.path.join(a["tree"], "tests"))
import fppm_alias
import bpy
from fppm import addon
from fppm.addon.export import export_scene
from fppm.addon.properties import settings_from_scene
from fppm.addon.engine import film_gain
from fppm.core.render import Renderer
addon.register()
bpy.ops.wm.open_mainfile(filepath=a["blend"], load_ui=False, use_scripts=False)
scene = bpy.context.scene
scene.render.resolution_percentage = a["pct"]
fscene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
settings = settings_from_scene(scene)
kw = dict(a["settings"], max_passes=100000, time_limit=0.0, seed=a["seed"])
if not hasattr(settings, "integrator") and kw.pop("integrator", "PHOTON") != "PHOTON":
    raise SystemExit("this checkout has photon mapping only")
settings = settings.replace(**kw).validate()
Renderer(fscene, settings.replace(max_passes=1, photons_per_pass=2000),
         log=lambda s: None).step()
last = {}
def on_pass(pr):
    last.update(cpu=time.process_time() - c0, n=pr.pass_index, img=pr.image)
c0 = time.process_time()
budget = a["budget"]
r = Renderer(fscene, settings, log=lambda s: None)
r.run(should_stop=lambda: time.process_time() - c0 > budget, on_pass=on_pass)
np.save(a["out"], last.pop("img")[..., :3].astype(float) * film_gain(scene))
print("TREE " + json.dumps(last), flush=True)
"""


def render_tree(tree, blend, pct, budget, run, seed=7):
    """:func:`render_cpu` by the checkout ``tree`` (:data:`TREE_RENDER`):
    {img, cpu, n} (no wall time, no camera share)."""
    tree = os.path.abspath(tree)
    own = os.path.join(tree, "example_blends", os.path.basename(blend))
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "img.npy")
        arg = dict(tree=tree, blend=own if os.path.isfile(own) else os.path.abspath(blend),
                   pct=pct, budget=budget, settings=_rule(settings_of(run)), seed=seed, out=out)
        _rule({})
        res = subprocess.run([os.path.join(tree, ".venv", "bin", "python"), "-c", TREE_RENDER,
                              json.dumps(arg)], capture_output=True, text=True, cwd=tree)
        line = [x for x in res.stdout.splitlines() if x.startswith("TREE ")]
        if res.returncode or not line:
            raise SystemExit(f"{tree}: {run} seed {seed} failed:\n{res.stderr[-3000:]}")
        return dict(json.loads(line[-1][5:]), img=np.load(out), wall=float("nan"),
                    camera_share=float("nan"))


def light_reference(blend, pct, seconds):
    from fppm.tools.converge.references import cache_dir
    key = f"light_{os.path.basename(blend)}_{pct}_{seconds:g}.npy"
    path = os.path.join(cache_dir(), key)
    if os.path.isfile(path):
        print(f"Reference: cached {path}", flush=True)
        return np.load(path)
    last = render_cpu(blend, pct, seconds, "light", seed=12345)
    print(f"Reference: light tracing, {last['n']} passes, {last['cpu']:.0f} s CPU", flush=True)
    np.save(path, last["img"])
    return last["img"]


def main(argv):
    blend, pct, budget, runs = argv[0], int(argv[1]), float(argv[2]), argv[3].split(",")
    if "--cost" in argv:
        for run, (c, share, q, se) in pass_costs(blend, pct, int(budget), runs).items():
            print(f"COST {run} cpu per pass {c:.4f} s camera share {share:.2f} "
                  f"/ {runs[0]} {q:.4f} +- {se:.4f}", flush=True)
        return
    spec = argv[argv.index("--ref") + 1] if "--ref" in argv else ""
    if spec.startswith("exr:"):
        r = load_reference(os.path.expanduser(spec[4:]))
        ref = r["image"][..., :3].astype(float)
        if r["var"] is not None:
            print(f"Reference: {spec[4:]}, noise floor {reference_floor(ref, r['var']):.3e}",
                  flush=True)
    elif spec:
        ref = light_reference(blend, pct, float(spec.split(":")[1]))
    else:
        ref = make_reference(bpy, open_blend(blend, resolution=pct), blend, 8192, print,
                             lambda s, force=False: print(s, flush=True))["image"]

    def relmse(x):
        return relmse_of(x, ref)
    tree = argv[argv.index("--tree") + 1] if "--tree" in argv else None
    seeds = [int(x) for x in argv[argv.index("--seeds") + 1].split(",")] if "--seeds" in argv else [7]
    for seed, run in ((seed, run) for seed in seeds for run in runs):
        if run == "cycles":
            scene = open_blend(blend, resolution=pct)
            cycles_reference_setup(scene)
            pts, n = [], 16
            while True:
                c0 = time.process_time()
                lay, dt = cycles_render(bpy, scene, n, 7)
                cpu = time.process_time() - c0
                pts.append((cpu, relmse(layer(lay, "Combined")[..., :3].astype(float))))
                print(f"  cycles {n} spp cpu {cpu:.1f} s (wall {dt:.1f}) relMSE {pts[-1][1]:.3e}",
                      flush=True)
                if cpu > budget:
                    break
                n *= 2
            (t0, e0), (t1, e1) = pts[-2], pts[-1]
            e = math.exp(math.log(e0) + (math.log(budget) - math.log(t0))
                         / (math.log(t1) - math.log(t0)) * (math.log(e1) - math.log(e0)))
            print(f"RESULT cycles relMSE@{budget:g}s cpu {e:.3e}", flush=True)
            continue
        last = (render_tree(tree, blend, pct, budget, run, seed=seed) if tree
                else render_cpu(blend, pct, budget, run, seed=seed))
        print(f"RESULT {run}{' @' + tree if tree else ''} seed {seed} relMSE@{last['cpu']:.1f}s cpu (wall {last['wall']:.1f}) "
              f"{relmse(last['img']):.3e} passes {last['n']} mean ratio "
              f"{last['img'].mean() / ref.mean():.4f} camera share {last['camera_share']:.2f}",
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
