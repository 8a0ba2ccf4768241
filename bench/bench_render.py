"""Photon-pass cost against raw Embree ray casting, measured in one process.

    .venv/bin/python bench/bench_render.py [--res 256] [--photons 200000] [--passes 3]
                                           [--frequency] [--numpy] [--deposits 0,1,2]
    .venv/bin/python bench/bench_render.py --stages [--stage-res 256 1024] [--repeat 3]
    .venv/bin/python bench/bench_render.py --gather [--gather-res 256x256 1920x1080] [--repeat 2]
    .venv/bin/python bench/bench_render.py --frequency --blend example_blends/cornell.blend
                                           [--blend-res 64] [--blend-passes 12] [--repeat 2]
    .venv/bin/python bench/bench_render.py --paths [--stage-res 64 256] [--repeat 3]
    .venv/bin/python bench/bench_render.py --pass [--pass-res 256x256 1920x1080] [--passes 2]
                                           [--plain]

Prints ratios (target: photon pass <= 2x the raw ray casting of its
rays at 256x256 with 200k photons per pass), never a bare time alone.

"Raw Embree rays" is ``EmbreeScene.run(o32, d32, output=1)`` on prepared
float32 arrays of as many random rays inside the box as the photon pass cast
(the bare call, the strictest denominator); the ratio against
``Accel.intersect`` on float64 arrays (what the old numpy tracer paid per ray)
is printed too.  Every pass is followed by its own raw-ray timing so that both
see the same machine load; the ratios use the sums.  With ``--frequency`` a
second renderer without frequency photons runs interleaved with the first,
and the tracer is timed on all-frequency vs all-classic batches.  A third
renderer runs the frequency photons as before core.frequency.kernels (the
numpy chains of tests/oracle_photons.py with the voxel-by-voxel march of
tests/oracle_occlusion.py), so the before/after overheads are measured in the
same process; each ratio is the best of ``--repeat`` interleaved measurements
of the process's CPU time (all threads: the machine is shared, its wall time
is no clock).  The whole photon pass is also measured at equal radii (the
FPPM renderer's own pass run again with and without its frequency photons
on the same visible points and radii: the frequency photons' cost alone,
where the line comparing the two renderers also holds the gather of the
radii FPPM's rule grows), per ``--deposits`` variant
(``PhotonTracer.freq_deposits``, docs/frequency.md "Fewer marched
deposits").  ``--numpy`` times the numpy reference tracer
(tests/oracle_photons.py) instead of the compiled one.

``--stages``: the camera pass and the direct light (next-event estimation)
of the same visible points, numpy reference (``compiled=False``) against the
compiled kernels (core.sppm.camera_kernels, core.lights.direct_kernels), at
each ``--stage-res``: the ratio numpy / compiled of wall and CPU time (best
of ``--repeat`` interleaved runs), the cores the compiled stages used (CPU /
wall), and one whole compiled pass (camera, direct, photons, gather,
update) against the bare Embree time of as many random rays as the pass cast.

``--pass``: the issue-17 targets, each resolution in its own process (so
that its peak memory is its own): the share of every stage in the pass's
wall and CPU time (camera, direct, radius init, grid build, photon trace,
gather, update, film, the rest), the pass's wall and CPU time against the
bare Embree call on as many random rays as the pass cast, split over the
photon tracer's threads (core.sppm.photons.THREADS), the photon pass
(trace + grid + gather) against the raw time of its photon rays, the cores
used (CPU / wall), and the peak resident size (``VmHWM``) and its growth
from before the Renderer was built.  The first pass (numba loading, the
boundary cap's camera pass) is not measured; the next ``--passes`` are summed.
With trace-ahead (the default) the photon trace runs while the camera and
direct stages and the gather run, and the process CPU clocks of those
stages count it too: "photon pass alone" reruns ``--passes`` passes with
trace-ahead off, where the photon pass's clocks hold its own CPU alone, and
splits the trace's CPU (its threads' clocks) into Embree, the bounce kernel
and the rest.

``--gather``: the photon pass's gather with the per-thread buffers allocated
once per render (hashgrid.GatherBuffers, folded at the touched points) against
the per-chunk dense sums it replaced (tests/test_gather_buffers.py
``per_chunk_trace_gather``: one set of
pixel-sized thread rows allocated, summed and added per chunk), passes of the
same renderer interleaved at each ``--gather-res``: the gather's CPU seconds
and share of the pass, and the whole pass's CPU seconds, as ratios
before / after (CPU time: the machine is shared), and the cores used.
"""
from __future__ import annotations

import argparse
import functools
import os
import resource
import sys
import threading
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))

from analytic_scenes import quad, translate  # noqa: E402
from core import lights as Lt  # noqa: E402
import oracle_occlusion  # noqa: E402
import oracle_photons  # noqa: E402
from core.sppm import photon_kernels as PK  # noqa: E402
from core.sppm import hashgrid as Hg  # noqa: E402
from core.sppm import clip as Clip  # noqa: E402
from core.sppm import photons as Ph  # noqa: E402
from core.render import Renderer  # noqa: E402
from core.scene.model import DIFFUSE, Camera, Light, Lobe, Material, make_scene  # noqa: E402
from core.settings import RenderSettings  # noqa: E402


def cornell(res: int, subdiv: int = 1, height: int = 0):
    """Cornell box (1 m cube, open front) with a ceiling area light and two
    blocks, res x (height or res) pixels; each of its 15 quads split into
    subdiv x subdiv quads (30 subdiv^2 triangles: the same surfaces, only
    Embree's work per ray grows)."""
    tris, mats = [], []
    white, red, green = 0, 1, 2
    n = max(int(subdiv), 1)
    def add(q, m):
        # q = quad(c, ex, ey): its corners p00, p10, p11 (first triangle)
        p00, p10, p11 = (np.asarray(v, float) for v in q[0])
        ex, ey = (p10 - p00) / (2 * n), (p11 - p10) / (2 * n)
        subs = [q] if n == 1 else [quad(p00 + (2 * i + 1) * ex + (2 * j + 1) * ey, ex, ey)
                                   for i in range(n) for j in range(n)]
        for sub in subs:
            tris.extend(sub)
            mats.extend([m] * len(sub))
    add(quad((0, 0, 0), (0.5, 0, 0), (0, 0.5, 0)), white)        # floor
    add(quad((0, 0, 1), (0, 0.5, 0), (0.5, 0, 0)), white)        # ceiling
    add(quad((0, 0.5, 0.5), (0.5, 0, 0), (0, 0, 0.5)), white)    # back
    add(quad((-0.5, 0, 0.5), (0, 0, 0.5), (0, 0.5, 0)), red)     # left
    add(quad((0.5, 0, 0.5), (0, 0.5, 0), (0, 0, 0.5)), green)    # right
    for c, s, hgt in (((-0.2, 0.15), 0.15, 0.6), ((0.2, -0.15), 0.15, 0.3)):
        x, y = c
        add(quad((x, y, hgt), (s, 0, 0), (0, s, 0)), white)
        add(quad((x, y - s, hgt / 2), (s, 0, 0), (0, 0, -hgt / 2)), white)
        add(quad((x, y + s, hgt / 2), (-s, 0, 0), (0, 0, -hgt / 2)), white)
        add(quad((x - s, y, hgt / 2), (0, s, 0), (0, 0, -hgt / 2)), white)
        add(quad((x + s, y, hgt / 2), (0, -s, 0), (0, 0, -hgt / 2)), white)
    materials = [Material("white", (Lobe(DIFFUSE, (0.8, 0.8, 0.8)),)),
                 Material("red", (Lobe(DIFFUSE, (0.8, 0.1, 0.1)),)),
                 Material("green", (Lobe(DIFFUSE, (0.1, 0.8, 0.1)),))]
    light = Light("ceiling", "AREA", (40.0, 40.0, 40.0), translate(0, 0, 0.999),
                  shape="SQUARE", size=0.3)
    # Camera at y = -1.9 looking along +Y: rotate local -Z onto +Y.
    M = np.array([[1, 0, 0, 0], [0, 0, -1, -1.9], [0, 1, 0, 0.5], [0, 0, 0, 1]], float)
    cam = Camera(kind="PERSP", matrix_world=M, lens=35.0, sensor_width=36.0,
                 resolution=(res, height or res), clip_start=0.01, clip_end=100.0)
    return make_scene(tris, materials, [light], cam, tri_mat=mats)


class RawRays:
    """Random rays from inside the box, prepared once (float32 and float64)."""

    def __init__(self, accel, n: int, seed: int = 0):
        rng = np.random.default_rng(seed)
        o = rng.uniform([-0.45, -0.45, 0.05], [0.45, 0.45, 0.95], (n, 3))
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        self.accel, self.o64, self.d64 = accel, o, d
        self.o32 = np.ascontiguousarray(o, np.float32)
        self.d32 = np.ascontiguousarray(d, np.float32)
        accel._scene.run(self.o32[:1000], self.d32[:1000], output=1)     # warm-up

    def _chunks(self, n):
        m = self.o32.shape[0]
        while n > 0:
            yield min(n, m)
            n -= m

    def seconds(self, n: int) -> float:
        """Bare EmbreeScene.run of n rays."""
        t0 = time.perf_counter()
        for k in self._chunks(n):
            self.accel._scene.run(self.o32[:k], self.d32[:k], output=1)
        return time.perf_counter() - t0

    def seconds_accel(self, n: int) -> float:
        """Accel.intersect (float64 in and out) of n rays."""
        t0 = time.perf_counter()
        for k in self._chunks(n):
            self.accel.intersect(self.o64[:k], self.d64[:k])
        return time.perf_counter() - t0


class Timers:
    """Wall and process-CPU seconds of the photon tracer and the gather, and
    wall seconds inside Embree and the numpy chains' occlusion march during
    tracing (wrappers around the functions core.sppm.photons, core.render
    and tests/oracle_photons.py call)."""

    def __init__(self):
        self.t = {k: 0.0 for k in ("trace", "trace_cpu", "gather", "gather_cpu", "embree",
                                   "march")}
        self._wrap(Ph, "intersect_f32", "embree", cpu=False)
        self._wrap(oracle_photons, "march_occlusion", "march", cpu=False)
        self.dense_march = False        # the march before MarchBlocks (bench "before")
        self._wrap(Hg, "gather", "gather")

    def _wrap(self, mod, name, key, cpu=True):
        f = getattr(mod, name)
        t = self.t

        def g(*a, **k):
            if key == "march" and self.dense_march:
                # "Before": the voxel-by-voxel march gives a_occ; it cannot
                # say where the blocker is, so t comes from the block march
                # (timed too: the "before" cost is an upper bound).
                t0 = time.perf_counter()
                a_occ = oracle_occlusion.march_occlusion_dense(*a)
                _, t_occ = f(*a, **k)
                t[key] += time.perf_counter() - t0
                return (a_occ, t_occ) if k.get("return_t") else a_occ
            t0, c0 = time.perf_counter(), time.process_time()
            r = f(*a, **k)
            t[key] += time.perf_counter() - t0
            if cpu:
                t[key + "_cpu"] += time.process_time() - c0
            return r
        setattr(mod, name, g)

    def wrap_tracer(self, tracer):
        self._wrap(tracer, "trace", "trace")

    def snapshot(self):
        return dict(self.t)


def make_renderer(scene, a, use_frequency, tm, before=False):
    """before: frequency photons as before core.frequency.kernels (numpy
    chains, dense march)."""
    st = RenderSettings(integrator="PHOTON", max_passes=1000, photons_per_pass=a.photons,
                        use_frequency=use_frequency, frequency_decay=a.decay,
                        max_bounces=a.bounces or RenderSettings().max_bounces)
    r = Renderer(scene, st, log=lambda s: None)
    if a.numpy:
        r.tracer.trace = functools.partial(oracle_photons.trace_numpy, r.tracer)
    if before:
        oracle_photons.use_numpy_chains(r.tracer)
    r.bench_before = before
    tm.wrap_tracer(r.tracer)
    photon_pass(r, tm)                            # warm-up: numba compilation
    return r


def photon_pass(r, tm):
    """Differences of the timers over one more pass of r, and its photon rays."""
    tm.dense_march = getattr(r, "bench_before", False)
    s0 = tm.snapshot()
    rays0 = r.photon_rays
    r.step()
    s = tm.snapshot()
    tm.dense_march = False
    return {k: s[k] - s0[k] for k in s}, r.photon_rays - rays0


def trace_seconds(r, tm, n, n_freq, seed):
    """CPU seconds (all threads) of r.tracer.trace(n, n_freq), and wall
    seconds of its march calls (the numpy chains' only)."""
    tm.dense_march = getattr(r, "bench_before", False)
    s0 = tm.snapshot()
    r.tracer.trace(n, n_freq, np.random.default_rng(seed))
    s1 = tm.snapshot()
    tm.dense_march = False
    return s1["trace_cpu"] - s0["trace_cpu"], s1["march"] - s0["march"]


def frequency_report(r, rb, r0, tm, a):
    """Pass overhead and per-photon cost of frequency photons, after (r) and
    before (rb) core.frequency.kernels, against r0 (no frequency photons):
    best of a.repeat interleaved measurements."""
    pp = {"after": [], "before": [], "a batch each": []}
    for _ in range(a.repeat):
        d0, _ = photon_pass(r0, tm)
        for key, rr in (("after", r), ("a batch each", r), ("before", rb)):
            if rr is None:
                continue
            # 'a batch each': frequency and classic photons traced in batches
            # of their own (PhotonTracer.one_batch False, the rule before)
            r.tracer.one_batch = key != "a batch each"
            d, _ = photon_pass(rr, tm)
            pp[key].append((d["trace_cpu"] + d["gather_cpu"])
                           / (d0["trace_cpu"] + d0["gather_cpu"]) - 1)
        r.tracer.one_batch = True
    n = min(a.photons, Ph_chunk())
    cost = {"after": [], "before": [], "no march": []}
    march_b = []
    tr = r.tracer
    occlusion = tr.occlusion
    for k in range(a.repeat):
        tc, _ = trace_seconds(r0, tm, n, 0, 100 + k)
        for key, rr in (("after", r), ("before", rb), ("no march", r)):
            if rr is None:
                continue
            # "no march": the compiled chains without the occlusion step (the
            # march's share of "after" is the difference)
            tr.occlusion = 0 if key == "no march" else occlusion
            tf, m = trace_seconds(rr, tm, n, n, 100 + k)
            cost[key].append(tf / tc)
            if key == "before":
                march_b.append(m / tc)
        tr.occlusion = occlusion
    marginal = mixed_batch_cost(tr, n, a.repeat, lambda nf, seed: trace_seconds(r, tm, n, nf,
                                                                                seed)[0])
    deposits = [int(x) for x in str(a.deposits).split(",") if x != ""]
    equal = equal_radii_pass(r, tm, deposits, a.repeat)
    per_k = deposits_costs(r, r0, tm, n, deposits, a.repeat) if deposits != [0] else None
    print(f"frequency ({r.settings.frequency_fraction:.0%} frequency photons x pass^-"
          f"{r.settings.frequency_decay:g}, CPU time of all "
          f"threads, best of {a.repeat}; "
          f"all values: {[f'{x:+.0%}' for x in pp['after']]} after, "
          f"{[f'{x:+.0%}' for x in pp['before']]} before)")
    print(f"  whole photon pass vs none, a batch for each kind of photon (the rule before): "
          f"{min(pp['a batch each']):+.0%}; all: {[f'{x:+.0%}' for x in pp['a batch each']]}")
    print(f"  {marginal}")
    print(f"  whole photon pass vs none, equal radii (one FPPM renderer's visible points, "
          f"radii, reach map and radius cut, its pass run with and without frequency "
          f"photons; process CPU, min / median of {a.repeat}):")
    for line in equal:
        print(f"    {line}")
    if per_k:
        print("  per freq_deposits (PhotonTracer.freq_deposits; 0 = every deposit), "
              f"min / median of {a.repeat}, interleaved:")
        for line in per_k:
            print(f"    {line}")
    print(f"  (the lines above 'equal radii' keep the old measures: the whole-pass "
          f"line compares the FPPM renderer with its grown radii against a PPM renderer)")
    if rb is None:
        print(f"  whole photon pass vs none: {min(pp['after']):+.0%}")
        print(f"  per-photon tracing cost, frequency / classic photon: "
              f"{min(cost['after']):.2f}x (without the march {min(cost['no march']):.2f}x); "
              f"all: {[round(x, 2) for x in cost['after']]}")
        return
    print(f"  whole photon pass vs none: after {min(pp['after']):+.0%}, "
          f"before {min(pp['before']):+.0%}")
    print(f"  per-photon tracing cost, frequency / classic photon: after "
          f"{min(cost['after']):.2f}x (without the march {min(cost['no march']):.2f}x), "
          f"before {min(cost['before']):.2f}x "
          f"(its march {march_b[int(np.argmin(cost['before']))]:.2f}x"
          f" wall / classic CPU); all: after {[round(x, 2) for x in cost['after']]}, "
          f"before {[round(x, 2) for x in cost['before']]}")


class PassProxy:
    """A renderer's PhotonPass with another __call__: every other attribute
    is the pass's (read through); kw: the proxy's own attributes."""

    def __init__(self, pp, **kw):
        self.__dict__.update(_pp=pp, **kw)

    def __getattr__(self, name):
        return getattr(self._pp, name)


class _EqualRadiiPass(PassProxy):
    """Around a renderer's PhotonPass: each call first runs the same pass
    (the renderer's visible points, radii, radius cut and reach map) once
    per variant on a fresh stream of one seed, timed in process CPU and
    with the trace's and the gather's CPU clocks (Timers), results thrown
    away; then the renderer's own call.  variants: (name, n_freq on: bool,
    freq_deposits)."""

    def __init__(self, pp, tm, variants, seed):
        super().__init__(pp, _tm=tm, _variants=variants, _seed=seed, times={})

    def __call__(self, vp, R2, spectrum, rng, check_stop=lambda: None):
        pp, tr = self._pp, self._pp.tracer
        chunks, k0 = pp.chunks, tr.freq_deposits
        order = list(self._variants)
        shift = len(self.times.get(order[0][0], [])) % len(order)
        for name, freq, k in order[shift:] + order[:shift]:      # rotated: no fixed order
            pp.chunks = chunks if freq else (lambda: [(n, 0) for n, _ in chunks()])
            tr.freq_deposits = k
            s0, c0 = self._tm.snapshot(), time.process_time()
            pp(vp, R2, None if spectrum is None else spectrum.copy(),
               np.random.default_rng(self._seed), check_stop)
            c, s1 = time.process_time() - c0, self._tm.snapshot()
            self.times.setdefault(name, []).append(
                (c, s1["trace_cpu"] - s0["trace_cpu"], s1["gather_cpu"] - s0["gather_cpu"]))
            del pp.chunks
        tr.freq_deposits = k0
        return pp(vp, R2, spectrum, rng, check_stop)


def equal_radii_pass(r, tm, deposits, repeat: int) -> list:
    """The whole photon pass with the renderer's share of frequency photons
    against the same pass without them, at equal radii: r (an FPPM renderer)
    is stepped repeat times, and in each step its pass is first run per
    variant on the same visible points and radii (_EqualRadiiPass).  So the
    ratio is the frequency photons' cost alone, not that of the radii
    FPPM's rule grows (the PPM renderer's pass, the old line).  Returns the
    lines to print."""
    variants = [("none", False, 0)] + [(f"k={k}", True, k) for k in deposits]
    pp = r.photon_pass
    w = _EqualRadiiPass(pp, tm, variants, 300)
    r.photon_pass = w
    try:
        for _ in range(repeat):
            r.step()
    finally:
        r.photon_pass = pp
    t = {k: np.array(v) for k, v in w.times.items()}
    out = []
    for name, _, k in variants[1:]:
        q = t[name] / t["none"]         # paired by step
        out.append(f"freq_deposits {k}: whole pass {np.min(q[:, 0]) - 1:+.0%} / "
                   f"{np.median(q[:, 0]) - 1:+.0%} (trace {np.median(q[:, 1]) - 1:+.0%}, "
                   f"gather {np.median(q[:, 2]) - 1:+.0%}, medians)")
    return out


def deposits_costs(r, r0, tm, n: int, deposits, repeat: int) -> list:
    """Per freq_deposits variant, interleaved: a frequency photon among
    classic ones (marginal, a quarter of n, one batch) and a batch of
    frequency photons alone, each over a classic photon (r0's trace of n
    classic photons in the same repetition), and the segments marched a
    frequency photon.  Returns the lines to print."""
    tr = r.tracer
    k0 = tr.freq_deposits
    nf = n // 4
    res = {k: ([], []) for k in deposits}
    for rep in range(repeat):
        c = trace_seconds(r0, tm, n, 0, 400 + rep)[0]
        for k in deposits[rep % len(deposits):] + deposits[:rep % len(deposits)]:
            tr.freq_deposits = k
            m = trace_seconds(r, tm, n, nf, 400 + rep)[0]
            b = trace_seconds(r, tm, n, n, 400 + rep)[0]
            res[k][0].append((m - c) / nf / (c / n))
            res[k][1].append(b / c)
    tr.freq_deposits = k0
    return [f"freq_deposits {k}: a frequency photon among classic ones, marginal "
            f"{np.min(v[0]):.2f}x / {np.median(v[0]):.2f}x; a batch of them alone "
            f"{np.min(v[1]):.2f}x / {np.median(v[1]):.2f}x" for k, v in res.items()]


def mixed_batch_cost(tr, n: int, repeat: int, cpu) -> str:
    """The marginal cost of a frequency photon among classic ones, as in a
    pass (a quarter of n photons carry a spectrum): (CPU(n, n/4) - CPU(n,
    0)) / (n/4) over a classic photon's CPU(n, 0) / n, with one batch for
    both kinds (PhotonTracer.one_batch) and with a batch each (the rule
    before); cpu(n_freq, seed) is the CPU seconds of tracing n photons.
    Best of repeat, interleaved.  Returns the line to print."""
    nf = n // 4
    best = {True: np.inf, False: np.inf}
    for k in range(repeat):
        for ob in (True, False):
            tr.one_batch = True
            c = cpu(0, 200 + k)
            tr.one_batch = ob
            best[ob] = min(best[ob], (cpu(nf, 200 + k) - c) / nf / (c / n))
        tr.one_batch = True
    return (f"a frequency photon among classic ones ({nf} of {n}) / a classic photon, "
            f"marginal: one batch {best[True]:.2f}x, a batch each {best[False]:.2f}x")


def blend_report(a):
    """``--blend``: CPU seconds per pass of FPPM and of PPM (use_frequency
    off) on a .blend at ``--blend-res``, rendered as ``fppm render`` does
    (addon/cli.py; needs bpy), interleaved, best of ``--repeat``; the set-up
    (export, occlusion grid) is left out: per pass = (CPU at the last pass -
    CPU at the first) / (passes - 1).  Prints the ratio and the passes each
    renders in equal CPU time."""
    import fppm_alias  # noqa: F401  (fppm.* importable)
    import bpy  # noqa: F401
    from fppm.addon.cli import open_blend, render_scene
    from fppm.addon.engine import RenderSession

    def per_pass(freq, passes):
        marks = []
        sess = RenderSession(log=lambda s: None,
                             on_pass=lambda pr, st: marks.append(time.process_time()))
        scene = open_blend(a.blend)
        scene.render.resolution_x = scene.render.resolution_y = a.blend_res
        scene.render.resolution_percentage = 100
        render_scene(scene, dict(integrator="PHOTON", use_frequency=freq, max_passes=passes,
                                 time_limit=0.0, seed=7), sess)
        return (marks[-1] - marks[0]) / (len(marks) - 1)
    per_pass(True, 2)
    per_pass(False, 2)                            # warm-up: kernels from the cache
    best = {True: np.inf, False: np.inf}
    for _ in range(a.repeat):
        for freq in (False, True):
            best[freq] = min(best[freq], per_pass(freq, a.blend_passes))
    q = best[True] / best[False]
    budget = 60.0
    print(f"{os.path.basename(a.blend)} at {a.blend_res}^2, {a.blend_passes} passes, best of "
          f"{a.repeat}: CPU per pass FPPM {best[True] * 1e3:.0f} ms, PPM {best[False] * 1e3:.0f} "
          f"ms: FPPM / PPM {q:.2f}x; in {budget:.0f} s of CPU FPPM renders "
          f"{budget / best[True]:.0f} passes to PPM's {budget / best[False]:.0f}")


def blend_renderer(blend: str, res: int):
    """A PHOTON renderer of the .blend at res^2 (exported as ``fppm render``
    does, frequency_decay 0) after two passes: its tracer has the reach map
    of PhotonTracer.set_reach and a radius cut."""
    import fppm_alias  # noqa: F401  (fppm.* importable)
    import bpy
    import bpy_helpers
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    from fppm.core.render import Renderer as FR
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(blend), load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_x = sc.render.resolution_y = res
    sc.render.resolution_percentage = 100
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    st = settings_from_scene(sc).replace(integrator="PHOTON", time_limit=0.0, max_passes=100,
                                         frequency_decay=0.0)
    r = FR(scene, st, log=lambda s: None)
    r.step()
    r.step()
    return r


def blend_tracer_report(a):
    """``--blend`` with ``--frequency``: the tracer of the .blend's scene (at
    ``--blend-res``, exported as ``fppm render`` does), after two passes of
    a renderer (so that the reach map of PhotonTracer.set_reach exists):
    CPU seconds of tracing PHOTON_CHUNK frequency photons against as many
    classic ones, with the reach map, without it, and without the march;
    best of ``--repeat``, interleaved."""
    r = blend_renderer(a.blend, a.blend_res)
    tr = r.tracer
    reach, occlusion = tr.reach, tr.occlusion
    n = Ph_chunk()

    def cpu(n_freq, seed):
        c0 = time.process_time()
        tr.trace(n, n_freq, np.random.default_rng(seed))
        return time.process_time() - c0
    best = {"gated": np.inf, "every deposit marched": np.inf, "no march": np.inf}
    for k in range(a.repeat):
        c = cpu(0, 100 + k)
        for key in best:
            tr.reach = reach if key == "gated" else None
            tr.occlusion = 0 if key == "no march" else occlusion
            best[key] = min(best[key], cpu(n, 100 + k) / c)
        tr.reach, tr.occlusion = reach, occlusion
    marginal = mixed_batch_cost(tr, n, a.repeat, cpu)
    share = float(np.mean(reach)) if reach is not None else float("nan")
    print(f"{os.path.basename(a.blend)} at {a.blend_res}^2, tracer, {n} photons, best of "
          f"{a.repeat}: frequency / classic photon " + ", ".join(
              f"{k} {v:.2f}x" for k, v in best.items())
          + f" (reach map: {share:.0%} of the voxels); {marginal}")


def raw_cpu(raw, rays):
    """(wall, CPU) seconds of the bare Embree call on `rays` rays."""
    c0 = time.process_time()
    w = raw.seconds(rays)
    return w, time.process_time() - c0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--frequency", action="store_true", help="25%% frequency photons")
    ap.add_argument("--bounces", type=int, default=0,
                    help="max_bounces (default: RenderSettings' default, 16)")
    ap.add_argument("--numpy", action="store_true", help="the numpy reference tracer")
    ap.add_argument("--decay", type=float, default=0.0,
                    help="frequency_decay of the renderers (default 0: every pass traces 25%% "
                         "frequency photons, the target's measure; the render default 0.5 "
                         "traces 25%% x k^-0.5 in pass k)")
    ap.add_argument("--no-numpy", action="store_true",
                    help="with --frequency: leave out the numpy-chain 'before' renderer "
                         "(compare two source trees by running this script in each)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="interleaved repeats of the frequency measurements (best of)")
    ap.add_argument("--deposits", default="0",
                    help="with --frequency: comma-separated PhotonTracer.freq_deposits "
                         "variants (0 = every deposit predicts), each measured interleaved "
                         "in the per-photon costs and the equal-radii whole pass")
    ap.add_argument("--stages", action="store_true",
                    help="camera + direct light: numpy vs compiled (ratios), and whole passes")
    ap.add_argument("--stage-res", type=int, nargs="+", default=[256, 1024])
    ap.add_argument("--gather", action="store_true",
                    help="gather buffers once per render vs per-chunk dense sums (ratios)")
    ap.add_argument("--gather-res", nargs="+", default=["256x256", "1920x1080"])
    ap.add_argument("--blend", default="",
                    help="with --frequency: FPPM vs PPM CPU per pass on this .blend (needs bpy)")
    ap.add_argument("--blend-res", type=int, default=64)
    ap.add_argument("--blend-passes", type=int, default=12)
    ap.add_argument("--paths", action="store_true",
                    help="camera paths (PATH, COMBINED): numpy vs compiled (CPU ratios)")
    ap.add_argument("--pass", dest="whole_pass", action="store_true",
                    help="stage shares, pass vs raw Embree, cores used, peak memory")
    ap.add_argument("--pass-res", nargs="+", default=["256x256", "1920x1080"])
    ap.add_argument("--plain", action="store_true", help="--pass without frequency photons")
    ap.add_argument("--subdiv", type=int, default=1,
                    help="--pass and --frequency: split each of the box's 15 quads into N x N (30 N^2 "
                         "triangles; N = 183: about 1M), the same surfaces with more work per "
                         "Embree ray")
    ap.add_argument("--pass-one", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.blend:
        blend_report(a)
        if a.frequency:
            blend_tracer_report(a)
        return 0
    if a.paths:
        paths_report(a)
        return 0
    if a.pass_one:
        pass_one(a)
        return 0
    if a.whole_pass:
        pass_report(a)
        return 0
    if a.stages:
        stage_report(a)
        return 0
    if a.gather:
        gather_report(a)
        return 0
    scene = cornell(a.res, subdiv=a.subdiv)
    # The trace's and the gather's process-CPU clocks must not hold the
    # camera stage's CPU: no trace-ahead here (photon_pass_alone).
    from core.sppm import photon_pass as PPm
    PPm.TRACE_AHEAD = False
    tm = Timers()
    r = make_renderer(scene, a, a.frequency, tm)
    r0 = make_renderer(scene, a, False, tm) if a.frequency else None
    rb = (make_renderer(scene, a, True, tm, before=True)
          if a.frequency and not a.no_numpy else None)
    raw = RawRays(r.accel, 4 * a.photons)
    PK.sample_photons_fast(r.light_table, 1000, np.random.default_rng(0))   # compile
    per_pass = []       # (pass wall / raw wall, pass CPU / raw CPU)
    acc = {}
    for _ in range(a.passes):
        d, rays = photon_pass(r, tm)
        w, c = raw_cpu(raw, rays)
        d.update(raw=w, raw_cpu=c, rays=rays, raw_accel=raw.seconds_accel(rays))
        if r0 is not None:
            d0, _ = photon_pass(r0, tm)
            d.update(trace0=d0["trace_cpu"], gather0=d0["gather_cpu"])
        for k, v in d.items():
            acc[k] = acc.get(k, 0.0) + v
        per_pass.append(((d["trace"] + d["gather"]) / w, (d["trace_cpu"] + d["gather_cpu"]) / c))
    # Light sampling for one pass' photons, against the raw rays of one pass.
    rng = np.random.default_rng(5)
    t0 = time.perf_counter()
    Lt.sample_photons(r.light_table, a.photons, rng)
    t_lights_np = time.perf_counter() - t0
    t0 = time.perf_counter()
    PK.sample_photons_fast(r.light_table, a.photons, rng)
    t_lights_fast = time.perf_counter() - t0
    raw_pass = raw.seconds(int(acc["rays"]) // a.passes)

    R = acc["raw"]
    pp = acc["trace"] + acc["gather"]
    pr = np.array(per_pass)
    print(f"scene: Cornell box, {scene.n_triangles} triangles, {a.res}x{a.res}, "
          f"{a.photons} photons/pass, {a.passes} passes, frequency={a.frequency}, "
          f"tracer={'numpy' if a.numpy else 'compiled'}, photon threads={Ph.THREADS}")
    print(f"photon rays per pass: {acc['rays'] / a.passes:,.0f}")
    print(f"photon pass / raw Embree rays: {pp / R:.2f}x  "
          f"(trace {acc['trace'] / R:.2f}x + gather {acc['gather'] / R:.2f}x); "
          f"per pass: median {np.median(pr[:, 0]):.2f}x, min {pr[:, 0].min():.2f}x")
    print(f"  CPU time (all threads) / raw Embree CPU: "
          f"{(acc['trace_cpu'] + acc['gather_cpu']) / acc['raw_cpu']:.2f}x  "
          f"(trace {acc['trace_cpu'] / acc['raw_cpu']:.2f}x + gather "
          f"{acc['gather_cpu'] / acc['raw_cpu']:.2f}x); per pass median {np.median(pr[:, 1]):.2f}x")
    if a.numpy:
        print(f"  inside trace (wall): occlusion march {acc['march'] / R:.2f}x")
    else:
        print(f"  inside trace (wall, summed over tracing threads): Embree calls "
              f"{acc['embree'] / R:.2f}x" + (
                  " (the march runs inside core.frequency.kernels: see the "
                  "frequency lines)" if a.frequency else ""))
    print(f"  shares of the photon pass: trace {acc['trace'] / pp:.0%}, "
          f"gather {acc['gather'] / pp:.0%}")
    print(f"  against Accel.intersect (float64 API) instead of the bare call: "
          f"{pp / acc['raw_accel']:.2f}x (its own overhead: {acc['raw_accel'] / R:.2f}x "
          f"the bare call)")
    print(f"light sampling / raw Embree rays of a pass: lights.sample_photons "
          f"{t_lights_np / raw_pass:.2f}x, compiled {t_lights_fast / raw_pass:.2f}x "
          f"({'used' if r.tracer.fast_emission and not a.numpy else 'not used'})")
    if r0 is not None:
        pp0 = acc["trace0"] + acc["gather0"]
        ppc = acc["trace_cpu"] + acc["gather_cpu"]
        print(f"frequency: whole photon pass with {r.settings.frequency_fraction:.0%} "
              f"frequency photons vs none, CPU time, all {a.passes} passes: {ppc / pp0 - 1:+.0%} "
              f"(trace {acc['trace_cpu'] / acc['trace0'] - 1:+.0%}, "
              f"gather {acc['gather_cpu'] / acc['gather0'] - 1:+.0%})")
        frequency_report(r, rb, r0, tm, a)
    total = sum(r.stage_seconds.values())
    print("stage shares of the whole render pass: "
          + ", ".join(f"{k} {v / total:.0%}" for k, v in r.stage_seconds.items()))
    return 0


def stage_report(a):
    """The --stages measurement (see the module docstring); prints ratios."""
    print(f"camera + direct light, numpy reference vs compiled (Cornell box, best of "
          f"{a.repeat} interleaved; OPENBLAS_NUM_THREADS="
          f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, threads {Ph.THREADS})")
    for res in a.stage_res:
        scene = cornell(res)
        r = Renderer(scene, RenderSettings(integrator="PHOTON", max_passes=1000,
                                           photons_per_pass=a.photons),
                     log=lambda s: None)
        cam, nee = r.camera_pass, r.direct_light
        vp, _ = cam(np.random.default_rng(1))
        best = {}
        for rep in range(a.repeat + 1):           # the first round compiles / warms up
            for compiled in (False, True):
                cam.compiled = nee.compiled = compiled
                for key, f in (("camera", lambda: cam(np.random.default_rng(1))),
                               ("direct", lambda: nee(vp, np.random.default_rng(2)))):
                    w0, c0 = time.perf_counter(), time.process_time()
                    f()
                    w, c = time.perf_counter() - w0, time.process_time() - c0
                    if rep:
                        k = (key, compiled)
                        bw, bc = best.get(k, (np.inf, np.inf))
                        best[k] = (min(bw, w), min(bc, c))
        cam.compiled = nee.compiled = True
        line = []
        for key in ("camera", "direct"):
            (nw, nc), (cw, cc) = best[(key, False)], best[(key, True)]
            line.append(f"{key} {nw / cw:.2f}x wall, {nc / cc:.2f}x CPU "
                        f"(compiled {cc / cw:.2f} cores, {cw / (res * res) * 1e9:.0f} ns/px)")
        (nw, nc) = tuple(best[("camera", False)][i] + best[("direct", False)][i] for i in (0, 1))
        (cw, cc) = tuple(best[("camera", True)][i] + best[("direct", True)][i] for i in (0, 1))
        print(f"  {res}^2: camera+direct {nw / cw:.2f}x wall, {nc / cc:.2f}x CPU faster "
              f"compiled ({cc / cw:.2f} cores used, numpy {nc / nw:.2f}); " + "; ".join(line))
        # One whole compiled pass against the bare Embree time of its rays.
        raw = RawRays(r.accel, min(4 * a.photons, 2_000_000))
        r.step()
        rays0, w0, c0 = r.accel.rays_cast, time.perf_counter(), time.process_time()
        r.step()
        pw, pc = time.perf_counter() - w0, time.process_time() - c0
        rays = r.accel.rays_cast - rays0
        rw = raw.seconds(rays)
        print(f"  {res}^2: whole pass ({rays:,} rays, {a.photons:,} photons) = "
              f"{pw / rw:.2f}x raw Embree rays (wall), {pc / pw:.2f} cores used")


def paths_report(a):
    """The --paths measurement: one pass of camera paths (``PathTracer``,
    camera_samples 4) with the numpy reference (``compiled=False``) and the
    kernels of core.integrators.path_kernels, interleaved, best of --repeat
    (the first round compiles / warms up); CPU time (the machine is shared),
    and the paths per CPU second of each; for COMBINED also one light-tracing
    pass of --photons light paths against the compiled camera paths."""
    print(f"camera paths, numpy reference vs compiled (Cornell box, camera_samples 4, "
          f"best of {a.repeat} interleaved, CPU time)")
    for res in a.stage_res:
        for integ in ("PATH", "COMBINED"):
            r = Renderer(cornell(res), RenderSettings(max_passes=1000, integrator=integ,
                                                      camera_samples=4,
                                                      photons_per_pass=a.photons),
                         log=lambda s: None)
            pt = r.path_tracer
            best = {}
            for rep in range(a.repeat + 1):
                for compiled in (False, True):
                    pt.compiled = compiled
                    c0 = time.process_time()
                    pt(np.random.default_rng(rep))
                    c = time.process_time() - c0
                    if rep:
                        best[compiled] = min(best.get(compiled, np.inf), c)
            paths = 4 * res * res
            extra = ""
            if r.combined_lt is not None:
                # The other half of a COMBINED pass: its light paths.
                c0 = time.process_time()
                r.combined_lt.trace_pass(a.photons, np.random.default_rng(9))
                extra = (f"; light tracing of {a.photons:,} light paths = "
                         f"{(time.process_time() - c0) / best[True]:.1f}x the compiled "
                         f"camera paths")
            print(f"  {res}^2 {integ}: numpy / compiled {best[False] / best[True]:.2f}x CPU "
                  f"(numpy {paths / best[False]:,.0f} paths per CPU s, compiled "
                  f"{paths / best[True]:,.0f}; kernels used: {pt.kernels() is not None})"
                  + extra)


def gather_report(a):
    """The --gather measurement (see the module docstring); prints ratios."""
    import types
    import test_gather_buffers
    print(f"gather: per-chunk dense sums (before) vs buffers once per render (after); "
          f"Cornell box, {a.photons:,} photons/pass (chunks of {Ph_chunk():,}), "
          f"{a.repeat} interleaved passes each, numba threads {Hg.numba.get_num_threads()}")
    for wh in a.gather_res:
        w, h = (int(x) for x in wh.split("x"))
        r = Renderer(cornell(w, height=h),
                     RenderSettings(integrator="PHOTON", max_passes=1000,
                                    photons_per_pass=a.photons),
                     log=lambda s: None)
        pp = r.photon_pass
        after = pp._trace_gather
        before = types.MethodType(test_gather_buffers.per_chunk_trace_gather, pp)
        cpu = {}

        def timed(f):
            def g(*args):
                c0 = time.process_time()
                f(*args)
                cpu["tg"] += time.process_time() - c0
            return g
        # pass CPU, pass wall, gather CPU, gather wall (seconds, summed over repeats)
        tot = {k: np.zeros(4) for k in ("before", "after")}
        for rep in range(a.repeat + 1):           # the first round compiles / warms up
            for key, f in (("before", before), ("after", after)):
                pp._trace_gather = timed(f)
                cpu["tg"] = 0.0
                tc0 = tm_trace_cpu(pp)
                g0 = pp.stage_seconds["gather"]
                w0, c0 = time.perf_counter(), time.process_time()
                r.step()
                pw, pc = time.perf_counter() - w0, time.process_time() - c0
                gc = cpu["tg"] - (tm_trace_cpu(pp) - tc0)
                if rep:
                    tot[key] += (pc, pw, gc, pp.stage_seconds["gather"] - g0)
        (bc, bw, bg, bgw), (ac, aw, ag, agw) = tot["before"], tot["after"]
        n = a.repeat
        print(f"  {w}x{h}: gather CPU before/after {bg / ag:.2f}x ({bg / n:.3f} -> "
              f"{ag / n:.3f} s a pass) "
              f"(share of the pass's CPU {bg / bc:.0%} -> {ag / ac:.0%}; wall "
              f"{bgw / bw:.0%} -> {agw / aw:.0%}); whole pass CPU before/after "
              f"{bc / ac:.2f}x ({bc / n:.2f} -> {ac / n:.2f} s), wall {bw / aw:.2f}x; "
              f"cores used {bc / bw:.2f} -> {ac / aw:.2f}")


PASS_STAGES = ("camera", "direct", "radius_init", "clip", "grid_build", "photon_trace",
               "gather", "update", "film")


def pass_report(a):
    """The --pass measurement: one process per resolution (see the module docstring)."""
    import subprocess
    print(f"whole passes (Cornell box, {30 * a.subdiv ** 2:,} triangles, {a.photons:,} photons/pass, "
          f"{'no frequency photons' if a.plain else 'defaults: 25% frequency photons'}, "
          f"{a.passes} passes after a warm-up one; numba threads "
          f"{Hg.numba.get_num_threads()}, photon threads {Ph.THREADS}, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
          f"load average {os.getloadavg()[0]:.1f})")
    for wh in a.pass_res:
        cmd = [sys.executable, os.path.abspath(__file__), "--pass-one", wh,
               "--photons", str(a.photons), "--passes", str(a.passes),
               "--subdiv", str(a.subdiv)] + (
                   ["--plain"] if a.plain else [])
        subprocess.run(cmd, check=True)


def _thread_cpu() -> dict:
    """CPU seconds (user + system) of each thread of this process, by thread
    id (/proc/self/task/*/stat; empty off Linux)."""
    out = {}
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return out
    for t in tids:
        try:
            with open(f"/proc/self/task/{t}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            out[t] = (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError, ValueError):
            pass
    return out


class RssSampler:
    """VmRSS every `period` seconds in a thread of its own, each sample
    labelled with the main thread's stage at that time (``stage``): the
    largest resident size seen during each stage.  tracemalloc does not see
    numba's allocations; the OS does."""

    def __init__(self, period: float = 0.01, probe=None):
        from core import memory
        self._rss = memory.resident_bytes
        self.period, self.stage = period, "rest"
        self.peak: dict = {}
        # probe(): a dict of sizes read at each new largest sample (what is
        # alive at the peak); at_peak: (VmRSS, stage, probe()) of the largest.
        self.probe, self.at_peak = probe, (0, "", {})
        self.entry: dict = {}          # VmRSS at each entry into a stage
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        while not self._stop.wait(self.period):
            v, k = self._rss(), self.stage
            if v > self.peak.get(k, 0):
                self.peak[k] = v
            if v > self.at_peak[0]:
                self.at_peak = (v, k, self.probe() if self.probe else {})

    def stop(self):
        self._stop.set()
        self._t.join()


class StageClock:
    """Wall and process-CPU seconds per stage of Renderer.step (PASS_STAGES),
    by wrapping the objects and functions a pass calls (bench only); also the
    process's system time and minor page faults (getrusage: every thread's,
    photons traced ahead included), the busiest thread's CPU seconds
    (/proc/self/task: a lower bound of the stage's wall time on an idle
    machine) and, through ``sampler``, the largest VmRSS seen in each stage."""

    def __init__(self, r, sampler=None):
        self.reset()
        self.sampler = sampler
        self.nest = 0
        pp = r.photon_pass
        r.camera_pass = self._timed(r.camera_pass, "camera")
        nee = r.direct_light
        r.direct_light = self._timed(nee, "direct")
        # at 256² the direct light is shared out beside the photon pass's set-up
        # (render.DIRECT_BESIDE_SETUP): "direct" times the blocks' hand-out and
        # the blocks' CPU is in the stages they overlap (radius init, clip, grid
        # build), as the photons traced ahead are in the stages they overlap
        r.direct_light.shared = self._timed(nee.shared, "direct")
        r.radii.initialise = self._timed(r.radii.initialise, "radius_init")
        r.radii.predicted = self._timed(r.radii.predicted, "update")
        r.radii.update = self._timed(r.radii.update, "update")
        r.film.accumulate = self._timed(r.film.accumulate, "film")
        r._film = self._timed(r._film, "film")
        pp.tracer.trace = self._timed(pp.tracer.trace, "photon_trace")
        # The gather: everything of a chunk but the trace (gather, fold, pairs).
        self._gather_inner = pp._trace_gather
        pp._trace_gather = self._timed(pp._trace_gather, "gather")
        Hg.build_grid = self._timed(Hg.build_grid, "grid_build")
        # the kernel clip's rays (PhotonPass.begin, before the grid build)
        Clip.clip_codes = self._timed(Clip.clip_codes, "clip")

    def reset(self):
        """Zero the sums (the wrapped functions stay wrapped)."""
        self.wall = dict.fromkeys(PASS_STAGES, 0.0)
        self.cpu = dict.fromkeys(PASS_STAGES, 0.0)
        self.sys = dict.fromkeys(PASS_STAGES, 0.0)
        self.faults = dict.fromkeys(PASS_STAGES, 0)
        self.busiest = dict.fromkeys(PASS_STAGES, 0.0)

    def _timed(self, f, key):
        def g(*args, **kw):
            # not the photons traced ahead (their own thread, PhotonPass.trace_ahead)
            main = not threading.current_thread().name.startswith("fppm-ahead")
            outer = self.sampler.stage if (main and self.sampler) else None
            if outer is not None:
                self.sampler.stage = key
                self.sampler.entry.setdefault(key, []).append(self.sampler._rss())
            t0 = _thread_cpu() if main else {}
            u0 = resource.getrusage(resource.RUSAGE_SELF)
            w0, c0 = time.perf_counter(), time.process_time()
            try:
                return f(*args, **kw)
            finally:
                w, c = time.perf_counter() - w0, time.process_time() - c0
                u1 = resource.getrusage(resource.RUSAGE_SELF)
                self.wall[key] += w
                self.cpu[key] += c
                self.sys[key] += u1.ru_stime - u0.ru_stime
                self.faults[key] += u1.ru_minflt - u0.ru_minflt
                if main:
                    t1 = _thread_cpu()
                    self.busiest[key] += max([t1[t] - t0.get(t, 0.0) for t in t1] or [0.0])
                if outer is not None:
                    self.sampler.stage = outer
                if key == "photon_trace" and threading.current_thread() is threading.main_thread():
                    # inside a gather call: not the gather's (photons traced
                    # ahead run in their own thread, PhotonPass.trace_ahead)
                    self.wall["gather"] -= w
                    self.cpu["gather"] -= c
        return g

    def snapshot(self):
        return dict(self.wall), dict(self.cpu)


def raw_threads(raw, rays: int, threads: int):
    """(wall, CPU) seconds of the bare Embree call on `rays` rays split into
    `threads` Python threads (EmbreeScene.run releases the GIL)."""
    from concurrent.futures import ThreadPoolExecutor
    c0, w0 = time.process_time(), time.perf_counter()
    if threads > 1:
        with ThreadPoolExecutor(threads) as ex:
            list(ex.map(raw.seconds, [rays // threads + (k < rays % threads)
                                      for k in range(threads)]))
    else:
        raw.seconds(rays)
    return time.perf_counter() - w0, time.process_time() - c0


def _mallinfo() -> dict:
    """glibc's heap sizes (mallinfo2, every arena): 'heap' obtained with brk
    or arena mmaps, 'heap_free' of it free but kept, 'mmapped' large blocks;
    empty without glibc >= 2.33."""
    import ctypes
    try:
        f = ctypes.CDLL("libc.so.6").mallinfo2
    except (OSError, AttributeError):
        return {}

    class MI(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
            "uordblks", "fordblks", "keepcost")]
    f.restype = MI
    m = f()
    return {"heap": m.arena, "heap_free": m.fordblks, "mmapped": m.hblkhd}


def _alive_probe(r):
    """What is alive (bytes, by kind) in the photon tracer's ArrayPool (every
    set it keeps, used or not), the gather buffers, plus _mallinfo()."""
    def probe():
        out = _mallinfo()
        try:
            with open("/proc/self/smaps_rollup") as f:
                for line in f:
                    if line.startswith("AnonHugePages:"):
                        out["huge pages"] = int(line.split()[1]) * 1024
        except OSError:
            pass
        pool = r.photon_pass.tracer.pool
        for kind, sets in list(pool._sets.items()):
            out[f"pool {kind} ({len(sets)} sets)"] = sum(
                sum(x.nbytes for x in arrs) for _, arrs in list(sets))
        gb = r.photon_pass.gather_buffers
        if gb is not None:
            out["gather buffers"] = sum(getattr(gb, k).nbytes
                                        for k in ("M", "Phi", "rmin", "S", "touched"))
        return out
    return probe


def pass_one(a):
    """One resolution of --pass, in this process."""
    from core import memory, warmup
    w, h = (int(x) for x in a.pass_one.split("x"))
    rss0 = memory.resident_bytes()
    r = Renderer(cornell(w, subdiv=a.subdiv, height=h), RenderSettings(integrator="PHOTON", max_passes=1000,
                                                      photons_per_pass=a.photons,
                                                      use_frequency=not a.plain),
                 log=lambda s: None)
    sampler = RssSampler(probe=_alive_probe(r))
    clock = StageClock(r, sampler)
    r.step()                                      # warm-up (kernels, the edge cap's pass)
    clock.reset()                                 # not the warm-up's times
    warm_peak, sampler.peak, sampler.entry = sampler.peak, {}, {}
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    raw = RawRays(r.accel, min(4 * a.photons, 2_000_000))
    tot = np.zeros(4)                             # pass wall, pass CPU, raw wall, raw CPU
    ph = np.zeros(3)                              # photon pass wall, CPU, photon rays
    pass_rays = 0
    # The passes back to back, as a render runs them: the next pass's photon
    # chunks are traced under this pass's end (PhotonPass.trace_ahead's
    # then=), so nothing else may run between two steps; the raw Embree
    # time of their rays is taken after them, the next pass's chunk dropped.
    rays0, prays0 = r.accel.rays_cast, r.photon_rays
    w0, c0 = time.perf_counter(), time.process_time()
    sw0, sc0 = clock.snapshot()
    for _ in range(a.passes):
        r.step()
    pw, pc = time.perf_counter() - w0, time.process_time() - c0
    sw, sc = clock.snapshot()
    r.photon_pass.drop_next()
    pass_rays = r.accel.rays_cast - rays0
    rw, rc = raw_threads(raw, pass_rays, Ph.THREADS)
    tot += (pw, pc, rw, rc)
    ph += [sum(sw[k] - sw0[k] for k in ("grid_build", "photon_trace", "gather")),
           sum(sc[k] - sc0[k] for k in ("grid_build", "photon_trace", "gather")),
           r.photon_rays - prays0]
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    sampler.stop()
    pw, pc, rw, rc = tot
    n = a.passes
    # The photon rays' own raw time (same threads), for the photon-pass target.
    prw, prc = raw_threads(raw, int(ph[2] / n), Ph.THREADS)
    # the stage clocks of these passes, before photon_pass_alone adds its own
    st = {k: dict(getattr(clock, k)) for k in ("wall", "cpu", "sys", "faults", "busiest")}
    alone = photon_pass_alone(r, clock, raw, n)
    wall, cpu = st["wall"], st["cpu"]
    rest_w = pw - sum(wall.values())
    rest_c = pc - sum(cpu.values())
    hwm = memory.peak_bytes_so_far()
    print(f"  {w}x{h}: pass {pw / n:.2f} s wall, {pc / n:.2f} s CPU; "
          f"pass / raw Embree of its rays ({Ph.THREADS} threads): {pw / rw:.2f}x wall, "
          f"{pc / rc:.2f}x CPU; cores used {pc / pw:.2f} (raw Embree {rc / rw:.2f})")
    print(f"    photon pass (grid + trace + gather) / raw Embree of its photon rays: "
          f"{ph[0] / n / prw:.2f}x wall, {ph[1] / n / prc:.2f}x CPU")
    print(alone)
    print(f"    {pass_rays / n:,.0f} rays a pass; raw Embree rate {pass_rays / rw / 1e6:.2f} M rays/s "
          f"on {Ph.THREADS} threads: the 4 s target is {4.0 / (rw / n):.1f}x the raw time "
          f"of the pass's rays (measured {pw / rw:.1f}x)")
    print("    stage shares, wall: " + ", ".join(
        f"{k} {wall[k] / pw:.0%}" for k in PASS_STAGES) + f", rest {rest_w / pw:.0%}")
    print("    stage shares, CPU:  " + ", ".join(
        f"{k} {cpu[k] / pc:.0%}" for k in PASS_STAGES) + f", rest {rest_c / pc:.0%}")
    print("    cores used per stage: " + ", ".join(
        f"{k} {cpu[k] / wall[k]:.2f}" for k in PASS_STAGES if wall[k] > 0))
    print("    system time a pass per stage (page faults): " + ", ".join(
        f"{k} {st['sys'][k] / n:.2f} s ({st['faults'][k] / n / 1e3:.0f}k faults)"
        for k in PASS_STAGES if wall[k] > 0)
        + f"; whole run {(ru1.ru_stime - ru0.ru_stime) / n:.2f} s a pass (raw rays included)")
    print("    busiest thread's CPU a pass per stage (wall on an idle machine >= it): " + ", ".join(
        f"{k} {st['busiest'][k] / n:.2f} s" for k in PASS_STAGES if wall[k] > 0))
    # The pass's wall time on an idle machine, estimated from this run's
    # CPU clocks (load-robust): a stage takes at least its busiest thread's
    # CPU and its CPU over the threads.  The photons traced ahead are in the
    # CPU of the stages they overlap (not counted again); what is not in a
    # stage ("rest") is left out, so the cores read high (main, 14:25-14:34
    # UTC at load 15: 1.71-1.74 where an idle run measured 1.47).
    est = sum(max(st["busiest"][k], cpu[k] / Ph.THREADS)
              for k in PASS_STAGES if k != "photon_trace") / n
    print(f"    idle estimate from the stages: pass wall {est:.2f} s (sum over stages of "
          f"max(busiest thread, CPU / {Ph.THREADS})), cores used {pc / n / est:.2f}")
    print("    largest VmRSS seen per stage (10 ms samples): " + ", ".join(
        f"{k} {v / 2**30:.2f} GiB" for k, v in sorted(sampler.peak.items(),
                                                       key=lambda kv: -kv[1])))
    print("    VmRSS at the entry of each stage (the last pass's): " + ", ".join(
        f"{k} {v[-1] / 2**30:.2f} GiB" for k, v in sampler.entry.items()))
    print("    the warm-up pass's (kernels loaded, the edge cap's camera pass): " + ", ".join(
        f"{k} {v / 2**30:.2f} GiB" for k, v in sorted(warm_peak.items(), key=lambda kv: -kv[1])[:3]))
    v, k, alive = sampler.at_peak
    print(f"    at the largest sample ({v / 2**30:.2f} GiB, {k}), alive: " + ", ".join(
        f"{n} {b / 2**20:.0f} MiB" for n, b in alive.items()))
    print(f"    peak resident (VmHWM) {hwm / 2**30:.2f} GiB, growth from before the Renderer "
          f"{(hwm - rss0) / 2**20:.0f} MiB ({(hwm - rss0) / (w * h):.0f} B a pixel)")
    # A kernel compiled here (its cache entry missing or overwritten by
    # another version of its module: the cache is shared by module name,
    # core/_numba_cache.py) leaves numba's compiler in the peak
    # (docs/architecture.md "The 1080p peak: kernels compiled in the pass").
    n_comp = warmup.compiled_count()
    print(f"    kernels compiled in this process (numba cache misses): {n_comp}"
          + (" -- the peak includes numba's compiler, not the render's alone" if n_comp else ""))
    kb = r.photon_pass._grid_kept
    print(f"    grid build's kept buffers (hashgrid.build_grid(buffers=)): {kb.allocations} "
          f"allocated, {kb.reused} takes reused, {kb.nbytes() / 2**20:.0f} MiB reserved "
          f"(touched pages only are resident)")


class ThreadClock:
    """CPU seconds of the calling thread inside wrapped functions, summed
    over the threads that call them (``time.thread_time``: the photon
    tracer's halves and Embree calls run in one thread each, so no other
    stage's CPU falls inside these clocks)."""

    def __init__(self):
        self.t = {}

    def wrap(self, obj, name, key):
        f = getattr(obj, name)
        t = self.t
        lock = threading.Lock()

        def g(*args, **kw):
            c0 = time.thread_time()
            try:
                return f(*args, **kw)
            finally:
                c = time.thread_time() - c0
                with lock:
                    t[key] = t.get(key, 0.0) + c
        setattr(obj, name, g)
        return f


def photon_pass_alone(r, clock, raw, n: int) -> str:
    """n more passes of r with trace-ahead off (PhotonPass.trace_ahead): the
    photon pass (grid + trace + gather) then runs alone, so the process CPU
    inside its clocks is its own -- with trace-ahead on, the trace's thread
    runs during the camera and direct stages and the gather, and the
    process clocks of those stages count it as well.  The trace's own CPU
    (its threads' clocks) split into Embree, the bounce kernel and the rest
    (emission, uniforms, numpy glue).  Returns the report line."""
    from core.sppm import photon_pass as PPm
    keys = ("grid_build", "photon_trace", "gather")
    tc = ThreadClock()
    undo = [(Ph, "intersect_f32", tc.wrap(Ph, "intersect_f32", "embree")),
            (PK, "bounce_kernel", tc.wrap(PK, "bounce_kernel", "bounce")),
            (r.tracer, "_trace_part", tc.wrap(r.tracer, "_trace_part", "trace"))]
    ahead, PPm.TRACE_AHEAD = PPm.TRACE_AHEAD, False
    acc = np.zeros(3)                             # wall, CPU, photon rays
    part = dict.fromkeys(keys, 0.0)               # each stage's process CPU
    try:
        for _ in range(n):
            sw0, sc0 = clock.snapshot()
            prays0 = r.photon_rays
            r.step()
            sw, sc = clock.snapshot()
            acc += [sum(sw[k] - sw0[k] for k in keys), sum(sc[k] - sc0[k] for k in keys),
                    r.photon_rays - prays0]
            for k in keys:
                part[k] += sc[k] - sc0[k]
    finally:
        PPm.TRACE_AHEAD = ahead
        for obj, name, f in undo:
            if obj is r.tracer:
                del obj._trace_part               # back to the class's method
            else:
                setattr(obj, name, f)
    prw, prc = raw_threads(raw, int(acc[2] / n), Ph.THREADS)
    t = {k: v / n / prc for k, v in tc.t.items()}
    return (f"    photon pass alone (trace-ahead off) / raw Embree of its photon rays: "
            f"{acc[0] / n / prw:.2f}x wall, {acc[1] / n / prc:.2f}x CPU; its trace's threads, "
            f"CPU: {t.get('trace', 0):.2f}x = Embree {t.get('embree', 0):.2f}x + bounce kernel "
            f"{t.get('bounce', 0):.2f}x + rest "
            f"{t.get('trace', 0) - t.get('embree', 0) - t.get('bounce', 0):.2f}x; "
            f"grid build {part['grid_build'] / n / prc:.2f}x, gather "
            f"{part['gather'] / n / prc:.2f}x CPU (their stage clocks)")


def tm_trace_cpu(pp):
    """Process CPU seconds spent in pp.tracer.trace so far (wrapped on first use)."""
    t = pp.tracer
    if not hasattr(t, "bench_cpu"):
        t.bench_cpu, f = 0.0, t.trace

        def g(*args, **kw):
            c0 = time.process_time()
            try:
                return f(*args, **kw)
            finally:
                t.bench_cpu += time.process_time() - c0
        t.trace = g
    return t.bench_cpu


def Ph_chunk():
    from core.render import PHOTON_CHUNK
    return PHOTON_CHUNK


if __name__ == "__main__":
    sys.exit(main())
