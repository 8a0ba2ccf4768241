"""Sweep ``hold_alpha``: FPPM against PPM on an example scene at equal CPU time.

    .venv/bin/python bench/bench_hold_alpha.py indirect_room [--hold 0.9,0.95,0.98,1.0]
        [--passes 64] [--seeds 0,1] [--photons 100000] [--ref-passes 100] [--ref-photons 300000]
    .venv/bin/python bench/bench_hold_alpha.py indirect_room --hold "" --passes 116 --report 29,58,116
        (PPM only, to read it at FPPM's CPU time)
    .venv/bin/python bench/bench_hold_alpha.py indirect_room --cost-only 24
        (CPU per pass of PPM and FPPM, stepped alternately in one process)
    .venv/bin/python bench/bench_hold_alpha.py indirect_room --breakdown 12
        (CPU per pass of PPM and FPPM variants: the frequency photons, verify_holds, the schedule)
    .venv/bin/python bench/bench_hold_alpha.py indirect_room --equal-cpu 15 --ref-passes 200 \
        --methods fppm,fppm:frequency_decay=0,ppm,appm,cppm
        (relMSE at equal CPU time, docs/method.md "Amortised frequency photons";
        'fppm:keep=min' / 'fppm:keep=none': the other prediction-keeping rules;
        without 'ppm' in --methods the ratios are ÷ the first method, docs/method.md
        "The spectrum rate's cap, round 17")
    .venv/bin/python bench/bench_hold_alpha.py principled_interior --equal-passes 32 --ref-passes 200 \
        --report 8,16,32 --seeds 0,1 --methods fppm,ppm,appm,cppm
        (relMSE at equal passes, same seed: quality apart from cost, docs/method.md
        "Principled interior: quality or cost"; 'fppm:keep=noocc': no occlusion operator;
        'fppm:fdep=1': a frequency photon predicts at its first counted deposit only,
        docs/frequency.md "Fewer marched deposits"; 'fppm:hmax=A': the spectrum's hold
        rate A, "What the spectrum adds over the counts", where the counts can test the hold
        (5 per sector cell; 'hmaxE=0': everywhere, 'hmaxE=10': from 10), "A slower hold
        where the counts can test it, round 15"; 0.95 is the default since round 16 and
        'fppm:hmax=0' the rule before, "The gated spectrum rate as the default, round 16")
    .venv/bin/python bench/bench_hold_alpha.py ring_lambert --cycles-ref --equal-passes 128 \
        --report 16,64,128 --seeds 0,1 --methods fppm,fppm:power=0,ppm,appm,cppm
        (the file's resolution and photons against the Cycles reference of ``fppm converge``,
        from its cache; 'fppm:power=0': holds the verified-holds test cannot yet judge
        stand, the rule before docs/method.md "Rings under a 1 m light")
    .venv/bin/python bench/bench_hold_alpha.py ring_lambert --full --photons 0 --equal-cpu 30 \
        --ref-passes 200 --methods fppm,fppm:keep=every,ppm
        (the file's resolution and photons against a PPM reference of that resolution;
        'fppm:keep=every': frequency photons in every pass, not only in passes 1, 2, 4, ...,
        docs/method.md "Frequency photons in doubling passes")
    .venv/bin/python bench/bench_hold_alpha.py ring_lambert --signed 128 --ref-passes 200 \
        --methods fppm,fppm:keep=every,fppm:hold_alpha=0.7:release=0.7,ppm
        (where the errors differ: held pixels, caustic lines, the rest; 'hold_alpha=0.7:
        release=0.7': frequency photons traced, no pixel held)

    .venv/bin/python bench/bench_hold_alpha.py ring_principled --equal-cpu 12 --ref-passes 200 \
        --seeds 0,1,2,3 --methods fppm,fppm:share=0,ppm,cppm
        ('share=0': the holds kept where few hold, 'sharepass=K': decided after pass K;
        'verify_holds=0' sets a bool field; docs/method.md "Where FPPM's extras do not pay";
        'through=1': visible points reached through glass or a mirror hold, the rule before
        docs/method.md "The glass sphere at equal passes, round 17", 'through=0' the default;
        'kappa=2': every hold reads the spectrum's prediction / 2, tried there, not kept;
        'gmax=G': the steepest linear fit a verified hold keeps, GRADIENT_MAX, 'gmax=inf' the
        rule before docs/method.md "Steep counts refuse a hold, round 33"; 'relall=0': the
        release rate only where a prediction is rejected, RELEASE_EVERYWHERE off, the rule
        before "Counts that reject shrink faster, round 34")
    .venv/bin/python bench/bench_hold_alpha.py cornell --cycles-ref --photons 0 --equal-cpu 6 \
        --bill-setup --seeds 0,1,2,3 --methods fppm,fppm:fstart=4,fppm:fstart=8:growS=0,cppm,ppm
        ('fstart=S': no frequency photons before pass S, frequency_start (default 2 since
        docs/method.md "Round 19: the rings and the decision": 'fppm' is S = 2, 'fppm:fstart=1'
        frequency photons from pass 1); 'growS=0': the
        verified holds do not grow in pass S (GROW_AT_START); 'eager=1': the occlusion grid built in the set-up,
        not before pass S - 1; --bill-setup: each method's CPU starts with its renderer's
        construction; docs/method.md "A late start for the frequency photons, round 18")

The protocol of docs/method.md ("Consistent holds", "Radius rules"): the
.blend at 50 % resolution (64x64) with the file's settings, photon mapping
only, one numba thread; relMSE against a PPM render of seed 100 with more
photons and passes (its floor: the relMSE between its half- and full-pass
images).  Every method renders with ``Renderer.step`` from the same export.
CPU time (``time.process_time``, one thread: less sensitive than wall time to
the shared machine's load; each pass billed its own photons' trace, ``OwnTrace``)
is recorded per pass, so PPM's relMSE is also read at FPPM's
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

# One thread for the protocol, when this file is the program.  Imported into a
# process that already has numba (pytest), leave the variables alone: numba
# re-reads NUMBA_NUM_THREADS whenever it compiles, and a 1 against the threads
# already launched makes every later compile in that process raise.
if "numba" not in sys.modules:
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)
import bpy_helpers  # noqa: E402

from fppm.core.render import Renderer  # noqa: E402
from fppm.tools.metrics import relmse  # noqa: E402


def export(name, percent=50):
    bpy = bpy_helpers.bpy()
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "example_blends", name + ".blend"),
                             load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = percent
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


def settle(r):
    """Wait for the chunks r's photon pass has started tracing for its next
    pass (PhotonPass.trace_ahead's then=: a pass whose successor traces no
    frequency photon queues the successor's chunks as its own last chunk is
    traced).  They run in a thread on after step() returns, and
    time.process_time is the whole process's: unwaited, their CPU is billed
    to whichever renderer steps next (docs/method.md "Where FPPM's extras do
    not pay").  Waiting leaves them queued for the next pass: the same bits
    (``Renderer.settle``, which ``fppm converge`` calls before its metrics)."""
    r.settle()


class OwnTrace:
    """Each pass billed its own photons' trace, wherever it ran.

    The trace-ahead moves a pass's trace into the step before it
    (``trace_ahead``'s then=), except before a frequency pass (its photons
    read the last pass's radii) and after the last pass of max_passes: a
    settled step's CPU is then its own work plus the next pass's trace or
    not.  Settled, FPPM's pass 2^j - 1 reads about 0.5x PPM's same pass,
    pass 2^j 2x, and the last pass of a run of 2^j passes 4-6x (PPM's last
    pass traces nothing; docs/method.md "The frequency passes' fixed cost").
    Here the thread CPU of every chunk's trace (``PhotonPass._trace_now``) is
    recorded with the pass whose stream it draws (``Renderer._photon_stream``,
    ``_next_photon_stream``), and a step's own CPU is its settled CPU minus
    the traces that ran in it plus its own pass's.  Exact with one tracing
    thread (FPPM_PHOTON_THREADS=1, this bench's default: a trace's halves
    then run in the thread that traces the chunk)."""

    def __init__(self, r):
        from fppm.core.sppm import photons
        self.exact = photons._threads() == 1
        self.done = []                      # (pass, thread CPU seconds) per chunk traced
        self.k_of = {}                      # id(stream) -> (pass, stream): kept alive, ids unique
        pp = r.photon_pass
        trace = pp._trace_now

        def traced(n, n_freq, rng):
            c0 = time.thread_time()
            try:
                return trace(n, n_freq, rng)
            finally:
                self.done.append((self.k_of.get(id(rng), (None,))[0], time.thread_time() - c0))
        pp._trace_now = traced
        for name in ("_photon_stream", "_next_photon_stream"):
            stream = getattr(r, name)

            def streams(k, stream=stream):
                rng = stream(k)
                if rng is not None:
                    self.k_of[id(rng)] = (k, rng)
                return rng
            setattr(r, name, streams)

    def own(self, k, n0, billed):
        """Pass k's own CPU: billed (its settled step, during which the
        chunks done[n0:] were traced) less those traces plus pass k's."""
        if not self.exact:
            return billed
        self.k_of = {i: v for i, v in self.k_of.items() if v[0] >= k}
        ran = sum(t for _, t in self.done[n0:])
        mine = sum(t for q, t in self.done if q == k)
        self.done = [d for d in self.done if d[0] is not None and d[0] > k]
        return billed - ran + mine


def step_cpu(r):
    """(r.step()'s result, its CPU seconds with its trace-ahead settled,
    billed its own photons' trace: OwnTrace; the settled CPU of the step as
    it ran is left in ``r._own_trace.billed``)."""
    own = getattr(r, "_own_trace", None)
    if own is None:
        own = r._own_trace = OwnTrace(r)
    n0 = len(own.done)
    c0 = time.process_time()
    res = r.step()
    settle(r)
    own.billed = time.process_time() - c0
    return res, own.own(r.pass_index, n0, own.billed)


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
            cpu[k].append(step_cpu(r)[1])
    c = {k: np.array(v[2:]) for k, v in cpu.items()}
    for k, v in c.items():
        say(f"cost {k}: {1e3 * v.mean():.1f} ms CPU per pass (median {1e3 * np.median(v):.1f}, n {v.size})")
    say(f"cost fppm/ppm: mean {c['fppm'].mean() / c['ppm'].mean():.3f}, "
        f"median {np.median(c['fppm']) / np.median(c['ppm']):.3f}")


def reference(name, scene, base, passes, photons, say, percent=50):
    """(reference image (H, W, 3) float64, its floor): a PPM render of seed
    100 with ``photons`` x ``passes``, cached under $TMPDIR (the same scene,
    passes and photons give the same image); the floor is the relMSE
    between its half- and full-pass images."""
    import tempfile
    tag = "" if percent == 50 else f"_{percent}pct"
    path = os.path.join(tempfile.gettempdir(), "fppm_bench_refs",
                        f"{name}{tag}_{passes}x{photons}.npz")
    if os.path.exists(path):
        d = np.load(path)
        return d["ref"], float(d["floor"])
    t0 = time.process_time()
    imgs, _, _ = run(scene, base.replace(use_frequency=False, seed=100, photons_per_pass=photons),
                     passes)
    ref, floor = imgs[-1], relmse(imgs[passes // 2 - 1], imgs[-1])
    os.makedirs(os.path.dirname(path), exist_ok=True)
    np.savez(path, ref=ref, floor=floor)
    say(f"# reference computed in {time.process_time() - t0:.0f} s CPU")
    return ref, floor


#: The methods of the equal-CPU comparison: FPPM with the file's settings and
#: the radius rules of tools/converge/runs.py METHOD_SETTINGS (frequency off).
EQUAL_CPU_METHODS = ("fppm", "ppm", "appm", "cppm")


def method_settings(base, method):
    from fppm.tools.converge.runs import METHOD_SETTINGS
    over = dict(METHOD_SETTINGS[method.split(":")[0]][0])
    over.pop("frequency_model", None)
    if ":" in method:                       # "fppm:decay=0" etc.
        for kv in method.split(":")[1:]:
            k, v = kv.split("=")
            if k in ("keep", "kappa", "eager") or k in RADII_KEYS or k in TRACER_KEYS:   # planes_or, radii_variant
                continue
            k = SETTING_KEYS.get(k, k)
            cur = getattr(base, k)
            if isinstance(cur, bool):       # 'verify_holds=0': bool("0") would be True
                over[k] = v.lower() in ("1", "true", "yes")
            else:
                over[k] = type(cur)(float(v) if isinstance(cur, float) else v)
    return base.replace(**over)


#: Short method-name keys of settings fields ('fppm:fstart=4': no frequency
#: photons before pass 4, docs/method.md "A late start for the frequency
#: photons, round 18"; with ':eager=1' the occlusion grid is built in the
#: set-up, not lazily before pass 3: equal_cpu; ':growS=0': the verified holds
#: do not grow in pass 4, RADII_KEYS).
SETTING_KEYS = {"fstart": "frequency_start"}


#: Method-name keys of :func:`radii_variant` and the Radii attribute each sets.
RADII_KEYS = {"power": "hold_min_expected", "release": "release_alpha", "top2": "hold_max_top2",
              "or": "hold_uniform", "orE": "uniform_min_expected", "crit": "uniform_critical",
              "grow": "grow", "growE": "grow_min_expected", "growZ": "grow_curvature_z",
              "hmax": "hold_alpha_spectrum", "hmaxE": "hold_spectrum_min_expected",
              "share": "hold_share_min", "growS": "grow_at_start",
              "sharepass": "hold_share_pass", "through": "hold_through_delta",
              "gmax": "gradient_max", "relall": "release_everywhere"}


#: Method-name keys of :func:`planes_or` and the PhotonTracer attribute each
#: sets ('fdep=1': a frequency photon predicts at its first counted deposit
#: only, docs/frequency.md "Fewer marched deposits").
TRACER_KEYS = {"fdep": "freq_deposits"}


def radii_variant(renderer, method):
    """Set the Radii attributes a method name asks for: 'keep=min' (the running
    minimum of the predictions), 'keep=none' (none kept), 'power=0' (a hold
    the verified-holds test has too few photons to judge stands), and every
    key=value of RADII_KEYS ('or=0:grow=1': the rule before docs/method.md
    "Spectrum and counts"; 'keep=or' is 'or=1')."""
    if ":keep=min" in method:
        renderer.radii.keep_minimum = True
    if ":keep=none" in method:
        renderer.radii.keep_predictions = False
    if ":keep=or" in method:
        renderer.radii.hold_uniform = True
    for kv in method.split(":")[1:]:
        k, v = kv.split("=")
        if k == "kappa":                    # the holds read r_pred / kappa (a margin)
            pred, kap = renderer.radii.predicted, float(v)
            renderer.radii.predicted = lambda *x, pred=pred, kap=kap: pred(*x) / kap
        if k in RADII_KEYS:
            setattr(renderer.radii, RADII_KEYS[k], int(v) if k == "sharepass"
                    else v not in ("0", "false") if k == "through" else float(v))


def cycles_reference(name, say, trusted: bool = False):
    """(reference image (H, W, 3) float64, its floor) of ``fppm converge``:
    the Cycles render of bench/converge_examples.py's sample count at the
    file's resolution, from the converge cache (rendered there if missing);
    the floor is tools.metrics.reference_floor of its per-pixel variance.
    trusted: (image, floor, mask), the mask (H, W) bool the pixels the
    reference vouches for (its Trusted layer, all pixels when it has none:
    tools.converge.references.trusted_masks) and the floor over them."""
    from converge_examples import SCENES
    from fppm.tools.converge.references import make_reference
    from fppm.tools.metrics import reference_floor
    bpy = bpy_helpers.bpy()
    bpy_helpers.ensure_registered()
    path = os.path.join(ROOT, "example_blends", name + ".blend")
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False, use_scripts=False)
    spp = SCENES[name][1]
    if isinstance(spp, str):            # a file reference (Mitsuba, LuxCore) in the cache folder
        from fppm.tools.converge.references import cache_dir, load_reference
        ref = load_reference(os.path.join(cache_dir(), spp))
    else:
        ref = make_reference(bpy, bpy.context.scene, path, spp, say, say)
    mask = ref.get("trusted") if trusted else None
    floor = reference_floor(ref["image"], ref["var"], mask) if ref["var"] is not None else np.nan
    if not trusted:
        return ref["image"], float(floor)
    return ref["image"], float(floor), (np.ones(ref["image"].shape[:2], bool) if mask is None
                                        else mask)


def equal_cpu(scene, base, methods, seed, budget, report, ref, say, bill_setup=False):
    """relMSE of every method at equal CPU time: the renderers are stepped
    in one process, always the one with the least CPU so far, so that the
    machine's load drifts over all alike, until each has ``budget`` CPU
    seconds; each method's error is read at the ``report`` fractions of the
    budget by log-log interpolation over its passes.  bill_setup: each
    method's clock starts at its renderer's construction CPU (process CPU
    around the constructor: no other renderer has started a pass, so no
    thread of theirs runs), as ``fppm converge`` bills it."""
    for m in methods:
        # Warm-up (not timed): the first pass of a process compiles or loads
        # the numba kernels, which would be charged to whichever method ran first.
        w = Renderer(scene, method_settings(base, m).replace(seed=seed, max_passes=1, photons_per_pass=2000),
                     log=lambda s: None)
        radii_variant(w, m)
        w.step()
    rs, setup = {}, {}
    for m in methods:
        c0 = time.process_time()
        rs[m] = Renderer(scene, method_settings(base, m).replace(seed=seed, max_passes=0,
                                                                   time_limit=1e9), log=lambda s: None)
        if ":eager=1" in m:     # 'fppm:fstart=8:eager=1': the occlusion grid built in the set-up
            rs[m]._occlusion_before(10 ** 9)
        setup[m] = time.process_time() - c0
    for m in methods:
        radii_variant(rs[m], m)
        planes_or(rs[m], m)
    say(f"seed {seed} set-up CPU, s ({'billed' if bill_setup else 'not billed'}): "
        + ", ".join(f"{m} {setup[m]:.3f}" for m in methods))
    cpu = {m: [setup[m] if bill_setup else 0.0] for m in methods}
    err = {m: [np.nan] for m in methods}
    while True:
        m = min(methods, key=lambda k: cpu[k][-1])
        if cpu[m][-1] >= budget:
            break
        res, dt = step_cpu(rs[m])
        cpu[m].append(cpu[m][-1] + dt)
        err[m].append(relmse(np.asarray(res.image[..., :3], np.float64), ref))
    out = {}
    for m in methods:
        c, e = np.array(cpu[m][1:]), np.array(err[m][1:])
        held = getattr(rs[m].state, "held", None)
        out[m] = [float(np.exp(np.interp(np.log(budget * q), np.log(c), np.log(e)))) for q in report]
        say(f"seed {seed} {m:>24}: passes {len(c)}, cpu {c[-1]:.1f} s, relmse at "
            + ", ".join(f"{budget * q:.0f} s {v:.3e}" for q, v in zip(report, out[m]))
            + (f", held {np.mean(held):.3f}" if held is not None else ""))
    den = "ppm" if "ppm" in methods else methods[0]     # without PPM: ÷ the first method
    for m in methods:
        say(f"seed {seed} {m:>24} / {den}: "
            + " ".join(f"{a / b:.3f}" for a, b in zip(out[m], out[den])))
    return out


def planes_or(r, m):
    """The variant of method name m on renderer r: 'fppm:keep=noplanes' the
    march as before (a segment's own surfaces may occlude); 'fppm:keep=every'
    frequency photons in every pass, not only in passes 1, 2, 4, 8, ..."""
    if ":keep=noplanes" in m:
        cp = r.tracer.chain_params
        r.tracer.chain_params = lambda cp=cp: cp()._replace(own_planes=False)
    if ":keep=batches" in m:            # a batch for each kind of photon (the tracer before)
        r.tracer.one_batch = False
    if ":keep=otherphotons" in m:       # frequency photons on other uniforms (the tracer before)
        r.tracer.same_photons = False
    if ":keep=oneb" in m:               # frequency photons never traced again (the tracer before)
        r.tracer.retrace = 0.0
    if ":keep=every" in m:              # frequency photons in every pass (the schedule before)
        r.photon_pass.doubling = False
    for kv in m.split(":")[1:]:
        k, v = kv.split("=")
        if k in TRACER_KEYS:
            setattr(r.tracer, TRACER_KEYS[k], int(v))


def equal_passes(scene, base, methods, seed, passes, report, ref, say):
    """relMSE of every method after the same passes (same seed), stepped
    alternately in one process: per report pass the whole image and the
    regions of tools.metrics.region_masks (from the reference), the held
    fraction and the geometric mean of R / R_ppm; then CPU and photons
    gathered per pass (passes 3..) relative to PPM."""
    from fppm.tools.metrics import region_masks
    masks = region_masks(ref)
    for m in methods:
        # Warm-up (not timed), as in equal_cpu: the first pass of a method
        # loads its numba kernels, which would be charged to its pass 1 or 2
        # and to the first frequency pass.
        w = Renderer(scene, method_settings(base, m).replace(seed=seed, max_passes=4,
                                                             photons_per_pass=2000),
                     log=lambda s: None)
        radii_variant(w, m)
        for _ in range(4):
            w.step()
    rs = {m: Renderer(scene, method_settings(base, m).replace(seed=seed, max_passes=passes),
                      log=lambda s: None) for m in methods}
    for m in methods:
        radii_variant(rs[m], m)
        if ":keep=noocc" in m:          # the frequency chain without its occlusion operator
            from fppm.core.frequency.occlusion_march import no_march_grid
            rs[m].tracer.occlusion, rs[m].tracer.march = 0, no_march_grid()
        planes_or(rs[m], m)
    cpu = {m: [] for m in methods}          # own CPU per pass (step_cpu)
    billed = {m: [] for m in methods}       # the settled step's CPU as it ran
    gathered = {m: [] for m in methods}
    stages = {m: [] for m in methods}       # per pass: the renderer's stage clocks (wall)
    out = {}
    for p in range(1, passes + 1):
        for m in methods:
            s0 = dict(rs[m].stage_seconds)
            res, dt = step_cpu(rs[m])
            cpu[m].append(dt)
            billed[m].append(rs[m]._own_trace.billed)
            gathered[m].append(rs[m].state.M_last.sum())
            stages[m].append({c: t - s0[c] for c, t in rs[m].stage_seconds.items()})
            if p in report:
                img = np.asarray(res.image[..., :3], np.float64)
                out[m, p] = (relmse(img, ref), {k: relmse(img, ref, v) for k, v in masks.items()},
                             float(np.mean(rs[m].state.held)), np.sqrt(rs[m].state.R2))
    for p in report:
        e_ppm, _, _, R_ppm = out["ppm", p]
        for m in methods:
            e, reg, held, R = out[m, p]
            ok = (R_ppm > 0) & (R > 0)
            say(f"seed {seed} pass {p} {m:>18}: relmse {e:.4e} / ppm {e / e_ppm:.3f}; "
                + ", ".join(f"{k} {v:.3e}" for k, v in reg.items())
                + f"; held {held:.3f}; R/R_ppm {np.exp(np.mean(np.log(R[ok] / R_ppm[ok]))):.3f}")
    c_ppm, g_ppm = np.mean(cpu["ppm"][2:]), np.mean(gathered["ppm"][2:])
    for m in methods:
        c, g = np.mean(cpu[m][2:]), np.mean(gathered[m][2:])
        say(f"seed {seed} {m:>18}: CPU per pass {1e3 * c:.0f} ms ({c / c_ppm:.3f} x PPM), "
            f"photons gathered per pass {g:.3g} ({g / g_ppm:.3f} x PPM)")
    # where a pass's time goes (wall clocks of the stages, interleaved, so
    # the load drifts over every method alike): passes 3..16 and 17..
    for lo, hi in ((2, min(16, passes)), (16, passes)):
        if hi <= lo:
            continue
        for m in methods:
            c = np.mean(cpu[m][lo:hi])
            st = {k: np.mean([s[k] for s in stages[m][lo:hi]]) for k in stages[m][0]}
            ref_st = {k: np.mean([s[k] for s in stages["ppm"][lo:hi]]) for k in stages["ppm"][0]}
            say(f"seed {seed} passes {lo + 1}-{hi} {m:>18}: CPU {1e3 * c:.1f} ms "
                f"({c / np.mean(cpu['ppm'][lo:hi]):.3f} x PPM); stage wall ms (- PPM's): "
                + ", ".join(f"{k} {1e3 * v:.1f} ({1e3 * (v - ref_st[k]):+.1f})" for k, v in st.items())
                + f"; gathered {np.mean(gathered[m][lo:hi]) / np.mean(gathered['ppm'][lo:hi]):.3f} x PPM")
    # the passes 4, 8, 16, ... alone: those that trace frequency photons under
    # the doubling schedule (photon_pass.frequency_pass); FPPM over PPM there
    # (own CPU: each pass billed its own photons' trace, OwnTrace; billed: the
    # settled steps as they ran, the pass before a frequency pass tracing
    # nothing ahead, docs/method.md "The frequency passes' fixed cost")
    from fppm.core.sppm.photon_pass import frequency_pass
    fp = [p - 1 for p in range(3, passes + 1) if frequency_pass(p)]
    f_ppm = np.array([cpu["ppm"][i] for i in fp])
    for m in methods:
        f = np.array([cpu[m][i] for i in fp])
        say(f"seed {seed} {m:>18}: CPU of the frequency passes {[p + 1 for p in fp]}: "
            f"{1e3 * f.mean():.0f} ms, x PPM's same passes: sum {f.sum() / f_ppm.sum():.3f}, "
            f"each " + " ".join(f"{x:.3f}" for x in f / f_ppm))
    for m in methods:
        say(f"seed {seed} {m:>18}: per pass p / p - 1, ms, own (billed): " + "; ".join(
            f"{p + 1}: {1e3 * cpu[m][p]:.0f} ({1e3 * billed[m][p]:.0f}) / "
            f"{1e3 * cpu[m][p - 1]:.0f} ({1e3 * billed[m][p - 1]:.0f})"
            for p in [1] + fp))


def signed(scene, base, methods, seed, passes, ref, say):
    """Where the methods' errors differ after the same passes (same seed):
    relMSE, and over three sets of pixels the share of the squared
    relative error (relMSE's per-pixel term) and the mean signed relative
    error (image - ref) / ref of the grey images: the pixels held at the
    end by the first method, the caustic lines (the 2 % brightest
    reference pixels among those with a prediction of the first method)
    and the rest (docs/method.md "Frequency photons in doubling passes")."""
    from fppm.tools.metrics import RELMSE_EPS
    rs = {m: Renderer(scene, method_settings(base, m).replace(seed=seed, max_passes=passes),
                      log=lambda s: None) for m in methods}
    for m in methods:
        radii_variant(rs[m], m)
        planes_or(rs[m], m)
    img = {}
    for _ in range(passes):
        for m in methods:
            img[m] = np.asarray(rs[m].step().image[..., :3], np.float64)
    g = ref.mean(axis=2)
    first = rs[methods[0]].state
    held = first.held.reshape(g.shape)
    has = np.isfinite(first.r_pred_last.reshape(g.shape))
    lines = has & (g >= np.quantile(g[has], 0.98)) if has.any() else has
    rest = ~held & ~lines
    for m in methods:
        rel = (img[m].mean(axis=2) - g) / np.maximum(g, 1e-6)
        sq = ((img[m] - ref) ** 2 / (ref ** 2 + RELMSE_EPS)).mean(axis=2)
        say(f"seed {seed} pass {passes} {m:>34}: relmse {relmse(img[m], ref):.4e}; share of the "
            f"squared error held {sq[held].sum() / sq.sum():.3f} lines {sq[lines].sum() / sq.sum():.3f}; "
            f"mean signed error held {rel[held].mean():+.4f} (n {held.sum()}), lines "
            f"{rel[lines].mean():+.4f} (n {lines.sum()}), rest {rel[rest].mean():+.4f}")


def breakdown(scene, base, passes, say):
    """CPU per pass of FPPM variants stepped alternately (the first 2 passes
    left out): what the frequency photons, the verified holds and the
    gather-side frequency work each add to a PPM pass."""
    variants = {"ppm": base.replace(use_frequency=False),
                "fppm decay 0": base.replace(frequency_decay=0.0),
                "fppm decay 0, no verify": base.replace(frequency_decay=0.0, verify_holds=False),
                "fppm 1 frequency photon": base.replace(frequency_decay=0.0,
                                                        frequency_fraction=1.0 / base.photons_per_pass),
                "fppm": base}
    rs = {k: Renderer(scene, v.replace(max_passes=passes), log=lambda s: None)
          for k, v in variants.items()}
    cpu = {k: [] for k in rs}
    pairs = {k: [] for k in rs}
    for i in range(passes):
        for k, r in rs.items():
            if i == 2:
                for c in r.stage_seconds:
                    r.stage_seconds[c] = 0.0
            cpu[k].append(step_cpu(r)[1])
            pairs[k].append(r.state.M_last.sum())
    ppm = np.mean(cpu["ppm"][2:])
    for k, v in cpu.items():
        v = np.array(v[2:])
        st = rs[k].stage_seconds
        say(f"breakdown {k:>24}: {1e3 * v.mean():.1f} ms CPU per pass (median "
            f"{1e3 * np.median(v):.1f}), {v.mean() / ppm:.3f} x PPM; last 4 passes "
            f"{1e3 * v[-4:].mean():.1f} ms; photons gathered per pass {np.mean(pairs[k][2:]):.3g}; "
            f"wall ms per pass: " + ", ".join(f"{c} {1e3 * t / v.size:.0f}" for c, t in st.items())
            + f"; held {np.mean(rs[k].state.held):.3f}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--hold", default="0.9,0.95,0.98,1.0")
    ap.add_argument("--passes", type=int, default=64)
    ap.add_argument("--ppm-extra", type=int, default=8)
    ap.add_argument("--report", default="16,32,64")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--photons", type=int, default=100_000)
    ap.add_argument("--percent", type=int, default=50,
                    help="resolution percentage of the .blend's (50: the 64x64 protocol; "
                         "--cycles-ref uses 100)")
    ap.add_argument("--ref-passes", type=int, default=100)
    ap.add_argument("--ref-photons", type=int, default=300_000)
    ap.add_argument("--cost-only", type=int, default=0, metavar="K",
                    help="only measure CPU per pass, PPM and FPPM (--hold's first value) "
                         "stepped alternately K passes each in this process")
    ap.add_argument("--breakdown", type=int, default=0, metavar="K",
                    help="CPU per pass of PPM and FPPM variants, stepped alternately K passes")
    ap.add_argument("--equal-cpu", type=float, default=0.0, metavar="SECONDS",
                    help="relMSE of --methods at equal CPU time, SECONDS each per seed")
    ap.add_argument("--bill-setup", action="store_true",
                    help="--equal-cpu: each method's CPU starts at its renderer's construction")
    ap.add_argument("--fractions", default="0.25,0.5,1",
                    help="--equal-cpu: the fractions of SECONDS the errors are read at")
    ap.add_argument("--equal-passes", type=int, default=0, metavar="K",
                    help="relMSE of --methods after the passes of --report (up to K), same seed")
    ap.add_argument("--signed", type=int, default=0, metavar="K",
                    help="after K passes of --methods (same seed): share of the squared error "
                         "and mean signed error on the held pixels, the caustic lines, the rest")
    ap.add_argument("--methods", default=",".join(EQUAL_CPU_METHODS),
                    help="equal-CPU / equal-pass methods; 'fppm:frequency_decay=0' sets a field")
    ap.add_argument("--full", action="store_true",
                    help="the file's resolution against the PPM reference of --ref-passes "
                         "(--photons 0 keeps the file's photons)")
    ap.add_argument("--cycles-ref", action="store_true",
                    help="the file's resolution, against fppm converge's Cycles reference "
                         "(--equal-passes / --equal-cpu; --photons 0 keeps the file's)")
    a = ap.parse_args()
    if a.cycles_ref:
        ref_floor = cycles_reference(a.scene, lambda s, **_: print(s, flush=True))
    percent = 100 if a.cycles_ref or a.full else a.percent
    scene, base = export(a.scene, percent)
    if a.photons:
        base = base.replace(photons_per_pass=a.photons)
    say = lambda s: print(s, flush=True)  # noqa: E731
    say(f"# {a.scene}: {base.photons_per_pass} photons/pass, alpha {base.alpha}, "
        f"verify_holds {base.verify_holds}, file hold_alpha {base.hold_alpha}")

    if a.cost_only:
        return cost(scene, base.replace(hold_alpha=float(a.hold.split(",")[0])), a.cost_only, say)
    if a.breakdown:
        return breakdown(scene, base, a.breakdown, say)
    def the_reference():
        """(reference image, its floor) of --equal-passes / --equal-cpu, said once."""
        ref, floor = ref_floor if a.cycles_ref else reference(
            a.scene, scene, base, a.ref_passes, a.ref_photons, say, percent)
        say(("# reference: fppm converge's Cycles render; floor (its variance) "
             if a.cycles_ref else f"# reference: {a.ref_passes} passes x {a.ref_photons} photons, "
             "seed 100; floor (half vs full) ") + f"{floor:.3e}; load {os.getloadavg()[0]:.1f}")
        return ref, floor

    if a.signed:
        ref, floor = the_reference()
        for seed in [int(x) for x in a.seeds.split(",")]:
            signed(scene, base, a.methods.split(","), seed, a.signed, ref, say)
        return
    if a.equal_passes:
        ref, floor = the_reference()
        methods = a.methods.split(",")
        methods += [] if "ppm" in methods else ["ppm"]     # the ratios' denominator
        for seed in [int(x) for x in a.seeds.split(",")]:
            equal_passes(scene, base, methods, seed, a.equal_passes,
                         [int(x) for x in a.report.split(",")], ref, say)
        say(f"# load at the end {os.getloadavg()[0]:.1f}")
        return
    if a.equal_cpu:
        ref, floor = the_reference()
        if not a.methods:                   # --methods "": the reference only
            return
        methods = a.methods.split(",")
        for seed in [int(x) for x in a.seeds.split(",")]:
            equal_cpu(scene, base, methods, seed, a.equal_cpu,
                      [float(x) for x in a.fractions.split(",")], ref, say, a.bill_setup)
        say(f"# load at the end {os.getloadavg()[0]:.1f}")
        return
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
