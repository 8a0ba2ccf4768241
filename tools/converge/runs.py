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
  the budget, rendered in a process of its own (``cycles_worker.py``: no
  numba or Embree threads alive beside Cycles).  The first seed's last point
  is then rendered once more by a fresh standalone Cycles process
  (:func:`cycles_speed_check`): the two samples/s must agree (within
  :data:`SPEED_TOLERANCE`) for the equal-time ratios against Cycles to be fair.

Clocks (:data:`CLOCKS`, ``fppm converge --clock``): ``wall`` (the default)
times everything by ``time.perf_counter``; ``cpu`` by ``time.process_time``
of the process that renders (this one for the photon-mapping methods, minus
the metrics computed between passes; the Cycles worker for Cycles), so that a
method's budget is the CPU it used whatever else loads the machine.  Every
row records both (``wall_seconds``, ``cpu_seconds``); ``seconds`` is the
chosen clock's, and CPU / wall of a run's last row is the cores it used.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from ...addon.cli import EXIT_INTERNAL, EXIT_USAGE, CLIError, open_blend, render_scene
from ...core.io.exr import read_exr
from .. import metrics as M
from . import cycles_worker as CW
from .references import layer

# The photon-mapping methods: name -> (RenderSettings overrides, --methods help).
# The time budget, seed and photons per pass are added by method_overrides.
# "paper": FPPM with the paper's printed frequency model, to compare the
# corrected model against it at equal time.
METHOD_SETTINGS = {
    "fppm": ({"integrator": "PHOTON", "use_frequency": True, "frequency_model": "CORRECTED"},
             "FPPM, the corrected frequency model whatever the file sets"),
    "paper": ({"integrator": "PHOTON", "use_frequency": True, "frequency_model": "PAPER"},
              "FPPM with the paper's printed frequency model"),
    "ppm": ({"integrator": "PHOTON", "use_frequency": False}, "progressive photon mapping (frequency off)"),
    "appm": ({"integrator": "PHOTON", "use_frequency": False, "radius_rule": "APPM"},
             "adaptive PPM (Kaplanyan & Dachsbacher 2013), per-pixel MSE-optimal radius"),
    "cppm": ({"integrator": "PHOTON", "use_frequency": False, "radius_rule": "CPPM"},
             "chi-squared PPM (Lin et al. 2020), radius kept while the photons look uniform"),
    "path": ({"integrator": "PATH", "use_frequency": False},
             "path tracing alone (camera paths, next-event estimation, MIS)"),
    "light": ({"integrator": "LIGHT", "use_frequency": False},
              "light tracing alone (photon paths connected to the camera)"),
    "combined": ({"integrator": "COMBINED", "use_frequency": True},
                 "path tracing + light tracing weighted by MIS, and photon merging with the "
                 "frequency radius for caustics seen through mirrors and glass (integrator COMBINED)"),
}
METHODS = tuple(METHOD_SETTINGS) + ("cycles",)
CYCLES_HELP = "Cycles at 1, 2, 4, ... spp, in a process of its own"
# Samples/s of the ladder and of a standalone Cycles render must agree within this.
SPEED_TOLERANCE = 0.05
# HDR-FLIP costs ~100x relMSE (0.1-0.4 s per 128^2 image): it is computed at
# points spaced by this factor in time (log-spaced, as the plot and the
# log-log interpolation use them) and at a run's last point; the other rows
# hold NaN, which tools.metrics.loglog_interp skips.
FLIP_TIME_STEP = 1.25
# Photons per pass of the untimed warm-up render (at most).
WARMUP_PHOTONS = 2000
# "wall": time.perf_counter; "cpu": time.process_time of the rendering process.
CLOCKS = ("wall", "cpu")
# --clock cpu: the Renderer's own (wall) time limit is only a safety net,
# this many times the CPU budget (settings need a limit when max_passes is 0).
CPU_CLOCK_WALL_CAP = 100.0


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
        self.cycles_process = None  # cycles: the worker's "done" line (numba, embreex, threads)
        self.cycles_speed = None   # cycles, first seed: cycles_speed_check's dict
        self._next_flip = 0.0
        self._last = None          # (masks, ref) of the last record

    def record(self, masks, ref, point, seconds, render_seconds, photons, samples, img,
               wall=None, cpu=None) -> dict:
        """Append the row of one image (H, W, 3) float64 and keep it as the last image.

        seconds: on the run's clock; wall, cpu: both clocks (None: not measured).
        FLIP is computed when ``seconds`` has grown by FLIP_TIME_STEP since the
        last FLIP (else NaN until :meth:`finish`)."""
        row = {"method": self.method, "seed": self.seed, "point": point,
               "seconds": round(seconds, 4), "render_seconds": round(render_seconds, 4),
               "photons": photons, "samples": samples,
               "wall_seconds": "" if wall is None else round(wall, 4),
               "cpu_seconds": "" if cpu is None else round(cpu, 4)}
        row.update(M.error_metrics(img, ref, masks, with_flip=False))
        if seconds >= self._next_flip:
            row.update(self._flip(img, ref, masks))
            self._next_flip = seconds * FLIP_TIME_STEP
        else:
            row.update({k.replace("relmse_", "flip_"): float("nan")
                        for k in row if k.startswith("relmse_")})
        self.rows.append(row)
        self.image = img
        self._last = (masks, ref)
        return row

    def cores(self) -> float:
        """CPU / wall seconds of the last row (NaN when either is unknown)."""
        if not self.rows:
            return float("nan")
        w, c = self.rows[-1].get("wall_seconds", ""), self.rows[-1].get("cpu_seconds", "")
        return float(c) / float(w) if w != "" and c != "" and float(w) > 0 else float("nan")

    @staticmethod
    def _flip(img, ref, masks) -> dict:
        return {k: v for k, v in M.error_metrics(img, ref, masks).items() if k.startswith("flip_")}

    def finish(self) -> None:
        """FLIP of the last row when the time spacing skipped it (its image is kept)."""
        if self.rows and self._last and not np.isfinite(self.rows[-1].get("flip_all", np.nan)):
            self.rows[-1].update(self._flip(self.image, self._last[1], self._last[0]))


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


def method_overrides(method: str, seed: int, budget: float, photons, max_passes: int = 0,
                     clock: str = "wall") -> dict:
    """The RenderSettings overrides of a photon-mapping method: passes until ``budget`` s
    (or ``max_passes`` passes when > 0, whichever comes first).  With the cpu clock
    the caller stops the passes; the wall limit is a safety net (CPU_CLOCK_WALL_CAP)."""
    limit = float(budget) * (CPU_CLOCK_WALL_CAP if clock == "cpu" else 1.0)
    kw = dict(METHOD_SETTINGS[method][0], time_limit=limit, max_passes=int(max_passes),
              seed=seed)
    if photons is not None:
        kw["photons_per_pass"] = photons
    return kw


def run_photon_mapping(run, blend, resolution, budget, photons, ref, masks, log, progress, stop,
                       warmed: set, max_passes: int = 0, clock: str = "wall"):
    """FPPM, paper or PPM (run.method) for ``budget`` seconds (at most ``max_passes``
    passes when > 0); records every pass into ``run``.

    stop: ``{"flag": bool}``, set by Ctrl-C; polled during the passes.
    warmed: the methods already warmed up in this process (updated).
    clock: "cpu": ``budget`` is this process's CPU seconds (set-up and passes,
      not the metrics recorded between passes); the first pass that ends at or
      past it is the last (polled between passes, so no pass is cut).
    """
    from ...addon.engine import RenderSession

    m, seed = run.method, run.seed
    overrides = method_overrides(m, seed, budget, photons, max_passes, clock)
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

    setup = {"wall": 0.0, "cpu": 0.0}
    metrics_cpu = [0.0]           # CPU of run.record (not the method's): excluded
    settled_wall = [0.0]          # wall of the waits for the traced-ahead photons
    cpu_done = [False]

    def on_renderer(renderer):
        setup["wall"], setup["cpu"] = time.perf_counter() - t0, time.process_time() - c0
        run.setup_seconds = setup[clock]

    def on_pass(pr, settings):
        # The next pass's photons are traced ahead, in a thread of their own,
        # while this callback runs: their CPU is the method's and must not
        # fall into the metrics' time left out below, so they are traced
        # first (Renderer.settle; the next pass is unchanged).  On the wall
        # clock that wait counts too; it loses the overlap with the next
        # pass's camera stage that an unrecorded render has (a little
        # pessimistic; docs/method.md "The convergence runs' CPU clock,
        # round 22").
        w_in = time.perf_counter()
        if sess.renderer is not None:
            sess.renderer.settle()
        settled_wall[0] += time.perf_counter() - w_in
        c_in = time.process_time()
        cpu = c_in - c0 - metrics_cpu[0]
        wall = setup["wall"] + pr.elapsed + settled_wall[0]
        secs = cpu if clock == "cpu" else wall
        img = pr.image[..., :3].astype(np.float64) * sess.gain
        row = run.record(masks, ref, pr.pass_index, secs, secs - setup[clock],
                         pr.photons_emitted, "", img, wall=wall, cpu=cpu)
        progress(f"[{m} seed {seed}] {secs:5.1f}/{budget:g} s ({clock})  pass {pr.pass_index}  "
                 f"relMSE {row['relmse_all']:.3e}")
        cpu_done[0] = clock == "cpu" and cpu >= budget
        metrics_cpu[0] += time.process_time() - c_in

    sess = RenderSession(on_pass=on_pass, log=lambda s: None,
                         should_stop=lambda: stop["flag"] or cpu_done[0],
                         on_renderer=on_renderer)
    scene = open_blend(blend, resolution=resolution)
    t0, c0 = time.perf_counter(), time.process_time()
    render_scene(scene, overrides, sess)
    run.complete = True
    renderer = sess.renderer
    if renderer is None or renderer.pass_index == 0 or renderer.settings.integrator != "PHOTON":
        return run       # the photon-pass throughput is FPPM's and PPM's
    st = renderer.stage_seconds
    t_photon = st["photon_trace"] + st["gather"]
    rays = int(renderer.photon_rays)
    t_raw = raw_ray_seconds(renderer.accel, renderer.scene, rays)
    run.throughput = {"photon_seconds": t_photon, "photon_rays": rays, "raw_seconds": t_raw,
                      "ratio": t_photon / t_raw if t_raw and t_raw > 0 else float("nan")}
    log(f"{m} seed {seed}: {renderer.pass_index} passes, {renderer.photons_emitted / 1e6:.1f} M "
        f"photons, setup {run.setup_seconds:.2f} s ({clock}), {run.cores():.2f} cores; photon pass {t_photon:.2f} s for "
        f"{rays / 1e6:.2f} M rays = {run.throughput['ratio']:.2f}x raw Embree "
        f"({t_raw:.2f} s).")
    return run


def cycles_process(cfg: dict, stop, on_point) -> dict:
    """Run ``cycles_worker.py`` with ``cfg`` (its module docstring) in a new process.

    on_point(d) is called with each render's line ``{"samples", "seconds",
    "path"}`` as it arrives; when ``stop["flag"]`` is set after a point the
    worker is ended.  Returns the worker's "done" line ({} when stopped).
    The worker has its own session, so a Ctrl-C in the terminal reaches only
    this process, which decides.
    """
    cfg_path = os.path.join(cfg["dir"], "config.json")
    with open(cfg_path, "w") as f:
        json.dump(cfg, f)
    err_path = os.path.join(cfg["dir"], "stderr.txt")
    done = {}
    with open(err_path, "w") as err:
        p = subprocess.Popen([sys.executable, CW.__file__, cfg_path], stdout=subprocess.PIPE,
                             stderr=err, text=True, start_new_session=True)
        try:
            for line in p.stdout:
                if not line.startswith(CW.PREFIX):
                    continue
                d = json.loads(line[len(CW.PREFIX):])
                if d.get("done"):
                    done = d
                    continue
                on_point(d)
                if stop["flag"]:
                    break
        finally:
            if p.poll() is None and (stop["flag"] or not done):
                p.kill()
            p.wait()
    if p.returncode != 0 and not stop["flag"]:
        with open(err_path) as f:
            tail = f.read()[-2000:]
        raise CLIError(EXIT_INTERNAL, f"the Cycles process failed (exit {p.returncode}):\n{tail}")
    return done


def cycles_image(path: str, shape) -> np.ndarray:
    """(H, W, 3) float64 Combined image of a worker's EXR; checks the size."""
    img = layer(read_exr(path), "Combined")[..., :3].astype(np.float64)
    if img.shape[:2] != tuple(shape):
        H, W = shape
        raise CLIError(EXIT_USAGE, f"the reference is {W}x{H} but Cycles renders "
                                   f"{img.shape[1]}x{img.shape[0]}: match --resolution.")
    return img


def run_cycles_ladder(run, blend, resolution, budget, max_samples, ref, masks, log,
                      progress, stop, clock: str = "wall"):
    """Cycles at 1, 2, 4, ... spp (run.seed) until a render takes longer than ``budget``
    (on ``clock``: the worker's own process CPU for "cpu"), in a process of its own
    (:func:`cycles_process`)."""
    seed = run.seed

    def on_point(d):
        n, dt = int(d["samples"]), float(d["seconds"])
        img = cycles_image(d["path"], ref.shape[:2])
        os.remove(d["path"])
        row = run.record(masks, ref, n, dt, dt, "", n, img, wall=d.get("wall_seconds"),
                         cpu=d.get("cpu_seconds"))
        run.ladder_images[n] = img
        progress(f"[cycles seed {seed}] {n} spp in {dt:.2f} s  relMSE {row['relmse_all']:.3e}",
                 force=True)

    with tempfile.TemporaryDirectory(prefix="fppm-cycles-") as tmp:
        cfg = {"blend": os.path.abspath(blend), "resolution": resolution, "seed": seed,
               "dir": tmp, "mode": "ladder", "budget": float(budget),
               "max_samples": int(max_samples), "clock": clock}
        run.cycles_process = cycles_process(cfg, stop, on_point)
    run.complete = True
    last = run.rows[-1] if run.rows else None
    log(f"cycles seed {seed}: ladder 1..{last['samples'] if last else 0} spp, "
        f"last {last['seconds'] if last else 0:.1f} s"
        + (f" = {last['samples'] / last['seconds']:.1f} spp/s" if last and last["seconds"] > 0
           else "") + " (own process).")
    return run


def cycles_speed_check(run, blend, resolution, stop, log, clock: str = "wall") -> dict | None:
    """Render the ladder's last point again in a fresh standalone Cycles process;
    sets and returns ``run.cycles_speed``: {"samples", "ladder_seconds",
    "standalone_seconds", "ladder_sps", "standalone_sps", "ratio" (ladder /
    standalone samples/s), "within" (|ratio - 1| <= SPEED_TOLERANCE)}."""
    if not run.rows or stop["flag"]:
        return None
    last = run.rows[-1]
    n, dt = int(last["samples"]), float(last["seconds"])
    got = {}
    with tempfile.TemporaryDirectory(prefix="fppm-cycles-") as tmp:
        cfg = {"blend": os.path.abspath(blend), "resolution": resolution, "seed": run.seed,
               "dir": tmp, "mode": "fixed", "samples": [n], "clock": clock}
        cycles_process(cfg, stop, lambda d: got.update(d))
    if "seconds" not in got or dt <= 0 or got["seconds"] <= 0:
        return None
    sps_l, sps_s = n / dt, n / float(got["seconds"])
    r = sps_l / sps_s
    run.cycles_speed = {"samples": n, "ladder_seconds": dt, "standalone_seconds": got["seconds"],
                        "ladder_sps": sps_l, "standalone_sps": sps_s, "ratio": r,
                        "within": bool(abs(r - 1.0) <= SPEED_TOLERANCE)}
    log(f"cycles speed: ladder {sps_l:.1f} spp/s, standalone {sps_s:.1f} spp/s "
        f"({n} spp): ratio {r:.3f}.")
    return run.cycles_speed
