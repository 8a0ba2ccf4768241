"""Runs of ``fppm converge``: render each method and record its error against time.

A :class:`Run` is one (method, seed): one row per FPPM/PPM pass or per Cycles
ladder point, with the error metrics of that image against the reference
(``tools.metrics.error_metrics``) over the whole image and each region.

- ``fppm`` / ``paper`` / ``ppm`` (:func:`run_photon_mapping`) render through
  ``addon.cli.open_blend`` + ``addon.cli.render_scene``, the path of
  ``fppm render`` (the FPPM engine, Blender's render-mode depsgraph), with
  the file's FPPM settings and the method's overrides (:func:`method_overrides`).
  Time of a pass = setup (from the start of the render to the Renderer being
  built: export, BVH, occlusion grid) + the Renderer's pass time.
- ``cycles`` (:func:`run_cycles_ladder`): 1, 2, 4, ... samples, each a
  separate ``render.render`` timed by wall clock, until one takes longer than
  the budget.
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np

from ...addon.cli import EXIT_USAGE, CLIError, open_blend, render_scene
from .. import metrics as M
from .references import cycles_reference_setup, cycles_render, layer

# "paper": FPPM with the paper's printed frequency model (frequency_model =
# PAPER), to compare the corrected model against it at equal time.
METHODS = ("fppm", "paper", "ppm", "cycles")
# Photons per pass of the untimed warm-up render (at most).
WARMUP_PHOTONS = 2000


def methods_run(runs) -> list[str]:
    """The methods with at least one recorded row, in :data:`METHODS` order."""
    return [m for m in METHODS if any(r.method == m and r.rows for r in runs)]


class Run:
    """The records of one (method, seed) run."""

    def __init__(self, method: str, seed: int):
        self.method, self.seed = method, seed
        self.rows: list[dict] = []
        self.image = None          # last image (H, W, 3) float64
        self.setup_seconds = 0.0
        self.throughput = None     # dict for fppm/ppm
        self.complete = False
        self.ladder_images = {}    # cycles: {samples: (H, W, 3) float64}

    def record(self, masks, ref, point, seconds, render_seconds, photons, samples, img) -> dict:
        """Append the row of one image (H, W, 3) float64 and keep it as the last image."""
        row = {"method": self.method, "seed": self.seed, "point": point,
               "seconds": round(seconds, 4), "render_seconds": round(render_seconds, 4),
               "photons": photons, "samples": samples}
        row.update(M.error_metrics(img, ref, masks))
        self.rows.append(row)
        self.image = img
        return row


class Progress:
    """One progress line per second (stderr); silent when quiet."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.last = 0.0

    def __call__(self, line: str, force: bool = False) -> None:
        if self.quiet:
            return
        now = time.monotonic()
        if force or now - self.last >= 1.0:
            self.last = now
            print(line, file=sys.stderr, flush=True)


def raw_ray_seconds(accel, scene, n_rays: int, cap: int = 2_000_000, seed: int = 12345) -> float:
    """Seconds ``accel.intersect`` takes for n_rays random rays in the scene bounds.

    At most ``cap`` rays are cast; the time is scaled linearly to n_rays.
    """
    if n_rays <= 0:
        return float("nan")
    n = int(min(n_rays, cap))
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds()
    o = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    accel.intersect(o[:1000], d[:1000])            # warm-up
    t0 = time.perf_counter()
    accel.intersect(o, d)
    return (time.perf_counter() - t0) * n_rays / n


def method_overrides(method: str, seed: int, budget: float, photons) -> dict:
    """The RenderSettings overrides of a photon-mapping method: passes until ``budget`` s."""
    kw = dict(use_frequency=(method in ("fppm", "paper")), time_limit=float(budget),
              max_passes=0, seed=seed)
    if method == "paper":
        kw["frequency_model"] = "PAPER"
    elif method == "fppm":
        kw["frequency_model"] = "CORRECTED"
    if photons is not None:
        kw["photons_per_pass"] = photons
    return kw


def run_photon_mapping(run, blend, resolution, budget, photons, ref, masks, log, progress, stop,
                       warmed: set):
    """FPPM, paper or PPM (run.method) for ``budget`` seconds; records every pass into ``run``.

    stop: ``{"flag": bool}``, set by Ctrl-C; polled during the passes.
    warmed: the methods already warmed up in this process (updated).
    """
    from ...addon.engine import RenderSession

    m, seed = run.method, run.seed
    overrides = method_overrides(m, seed, budget, photons)
    should_stop = lambda: stop["flag"]  # noqa: E731
    if m not in warmed:
        # Warm-up (not timed): loads numba's compiled kernels from the disk
        # cache, a one-off per process that Cycles, already loaded, does not
        # pay either.
        warm = dict(overrides, max_passes=1, time_limit=0.0,
                    photons_per_pass=min(photons or WARMUP_PHOTONS, WARMUP_PHOTONS))
        render_scene(open_blend(blend, resolution=resolution), warm,
                     RenderSession(log=lambda s: None, should_stop=should_stop))
        warmed.add(m)

    def on_renderer(renderer):
        run.setup_seconds = time.perf_counter() - t0

    def on_pass(pr, settings):
        img = pr.image[..., :3].astype(np.float64) * sess.gain
        row = run.record(masks, ref, pr.pass_index, run.setup_seconds + pr.elapsed,
                         pr.elapsed, pr.photons_emitted, "", img)
        progress(f"[{m} seed {seed}] {pr.elapsed:5.1f}/{budget:g} s  pass {pr.pass_index}  "
                 f"relMSE {row['relmse_all']:.3e}")

    sess = RenderSession(on_pass=on_pass, log=lambda s: None, should_stop=should_stop,
                         on_renderer=on_renderer)
    scene = open_blend(blend, resolution=resolution)
    t0 = time.perf_counter()
    render_scene(scene, overrides, sess)
    run.complete = True
    renderer = sess.renderer
    if renderer is None or renderer.pass_index == 0:
        return run
    st = renderer.stage_seconds
    t_photon = st["photon_trace"] + st["gather"]
    rays = int(renderer.photon_rays)
    t_raw = raw_ray_seconds(renderer.accel, renderer.scene, rays)
    run.throughput = {"photon_seconds": t_photon, "photon_rays": rays, "raw_seconds": t_raw,
                      "ratio": t_photon / t_raw if t_raw and t_raw > 0 else float("nan")}
    log(f"{m} seed {seed}: {renderer.pass_index} passes, {renderer.photons_emitted / 1e6:.1f} M "
        f"photons, setup {run.setup_seconds:.2f} s; photon pass {t_photon:.2f} s for "
        f"{rays / 1e6:.2f} M rays = {run.throughput['ratio']:.2f}x raw Embree "
        f"({t_raw:.2f} s).")
    return run


def run_cycles_ladder(run, bpy, blend, resolution, budget, max_samples, ref, masks, log,
                      progress, stop):
    """Cycles at 1, 2, 4, ... spp (run.seed) until a render takes longer than ``budget``."""
    seed = run.seed
    H, W = ref.shape[:2]
    scene = open_blend(blend, resolution=resolution)
    cycles_reference_setup(scene)
    n = 1
    while n <= max_samples and not stop["flag"]:
        layers, dt = cycles_render(bpy, scene, n, seed)
        img = layer(layers, "Combined")[..., :3].astype(np.float64)
        if img.shape[:2] != (H, W):
            raise CLIError(EXIT_USAGE, f"the reference is {W}x{H} but Cycles renders "
                                       f"{img.shape[1]}x{img.shape[0]}: match --resolution.")
        row = run.record(masks, ref, n, dt, dt, "", n, img)
        run.ladder_images[n] = img
        progress(f"[cycles seed {seed}] {n} spp in {dt:.2f} s  relMSE {row['relmse_all']:.3e}",
                 force=True)
        if dt > budget:
            break
        # Doubling, except that the step past the budget aims at ~1.1x the
        # budget rather than up to 2x (the last point only brackets 100%).
        n_next = 2 * n
        if 2 * dt > budget and dt > 0:
            n_next = min(n_next, max(n + 1, int(math.ceil(n * 1.1 * budget / dt))))
        n = n_next
    run.complete = True
    log(f"cycles seed {seed}: ladder 1..{run.rows[-1]['samples'] if run.rows else 0} spp, "
        f"last {run.rows[-1]['seconds'] if run.rows else 0:.1f} s.")
    return run
