"""``fppm converge``: error against run time for FPPM, PPM and Cycles.

    fppm converge SCENE.blend --time-limit S --out DIR
                  [--reference REF.exr | --cycles-samples N] [--methods fppm,ppm,cycles]
                  [--seeds K] [--resolution PCT] [--photons N] [--mask MASK.png|exr]
                  [--kind diffuse|indirect|caustic-small|caustic-large]

1. Reference: REF.exr, or a Cycles render of the same file at N samples
   (default: the file's Cycles samples) with reference settings (CPU, caustics
   on, blur_glossy 0, no denoising / adaptive sampling / clamping / light
   threshold, view 'Standard', the scene's pixel filter), rendered as two
   halves of N/2 samples with independent seeds: their mean is the reference,
   (A - B)^2 / 4 its per-pixel variance (the floor of every relMSE, see
   core.metrics.reference_floor).  DiffDir / DiffInd passes are kept for the
   "indirect" region.  Cached as a multi-layer EXR under
   ``$FPPM_CACHE_DIR`` (default ``~/.cache/fppm``) ``/references/<sha256>.exr``,
   the key being the .blend's bytes plus these settings.
2. Methods: ``fppm`` (the file's FPPM settings, frequency kernel on) and
   ``ppm`` (the same with use_frequency off), same seed, photons per pass and
   resolution, time_limit = S; ``cycles`` at 1, 2, 4, ... samples, each a
   separate render timed by wall clock, until one takes longer than S.
   The scene is exported once from the viewport depsgraph (the file is opened
   with scripts disabled; for files whose render and viewport visibility agree
   this is the F12 scene).  FPPM/PPM time = Renderer construction (BVH,
   occlusion grid) + pass time; Cycles time = the whole ``render.render``.
3. After every pass (or ladder point): time, photons, relMSE / RMSE / MRE over
   the image and over the smooth / caustic / indirect regions
   (core.metrics.region_masks, or the --mask image: R caustic, G smooth, B indirect).
4. --seeds K >= 2: every method runs with seeds seed..seed+K-1; bias and noise
   of the final images are separated (core.metrics.bias_noise).
5. DIR/convergence.csv, DIR/convergence.png (matplotlib, optional), DIR/report.md,
   DIR/<method>.exr and .png (the final image of the first seed), DIR/reference.png.
6. Throughput: FPPM photon-pass time (trace + gather) / raw Embree time for as
   many random rays, in the same process.
7. Ctrl-C: the runs done so far (and the passes of the current one) are written.

Equal-time comparisons interpolate each method's error linearly in log-log
between its recorded points (core.metrics.loglog_interp).
"""
from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import sys
import tempfile
import time
import zlib
import struct

import numpy as np

from . import metrics as M

REF_VERSION = "fppm-converge-ref-2"   # 2: with DiffDir/DiffInd passes
REF_SEEDS = (1_000_003, 1_000_004)     # independent of every method's seeds
# "paper": FPPM with the paper's printed frequency model (frequency_model =
# PAPER), to compare the corrected model against it at equal time.
METHODS = ("fppm", "paper", "ppm", "cycles")
FRACTIONS = (0.1, 0.5, 1.0)
KINDS = ("diffuse", "indirect", "caustic-small", "caustic-large")


class ConvergeError(Exception):
    def __init__(self, code: int, msg: str):
        super().__init__(msg)
        self.code = code


def add_parser(sub) -> None:
    """Add the ``converge`` sub-command to an argparse sub-parsers object."""
    c = sub.add_parser("converge", help="error against run time: FPPM, PPM and Cycles",
                       description="Measure error against run time for FPPM, PPM and Cycles "
                                   "on SCENE.blend; writes a CSV, a plot and a report.")
    c.add_argument("blend", metavar="SCENE.blend", help="the .blend file (scripts are not run)")
    c.add_argument("--time-limit", type=float, required=True, metavar="S",
                   help="time budget per method, seconds")
    c.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    g = c.add_mutually_exclusive_group()
    g.add_argument("--reference", metavar="REF.exr", help="reference image (linear RGB EXR)")
    g.add_argument("--cycles-samples", type=int, metavar="N",
                   help="render the reference with Cycles at N samples (default: the file's)")
    c.add_argument("--methods", default="fppm,ppm,cycles",
                   help="comma-separated subset of fppm,paper,ppm,cycles (default: fppm,ppm,cycles; "
                        "'fppm' uses the corrected frequency model whatever the file sets, "
                        "'paper' the paper's printed one)")
    c.add_argument("--seeds", type=int, default=1, metavar="K", help="seeds per method (K >= 2: bias/noise)")
    c.add_argument("--seed", type=int, default=0, metavar="N", help="first seed (default 0)")
    c.add_argument("--resolution", type=int, metavar="PCT", help="resolution percentage (1-1000)")
    c.add_argument("--photons", type=int, metavar="N", help="photons per pass (FPPM and PPM)")
    c.add_argument("--mask", metavar="MASK", help="region mask image (PNG/EXR): R caustic, G smooth, B indirect")
    c.add_argument("--kind", choices=KINDS,
                   help="scene class for the targets section (default: all targets listed as 'n/a')")
    c.add_argument("--cycles-max-samples", type=int, default=1 << 20, metavar="N",
                   help="largest Cycles ladder sample count (default: no practical cap)")
    c.add_argument("--from-csv", action="store_true",
                   help="no renders: rebuild the report and plot from DIR/convergence.csv "
                        "(the bias/noise and throughput sections are kept from DIR/report.md)")
    c.add_argument("-q", "--quiet", action="store_true", help="no progress lines")


# ---------------------------------------------------------------------------
# small I/O helpers (no plotting library needed)

def write_png(path: str, img, exposure_gain: float = 1.0) -> None:
    """(H, W, >=3) linear radiance -> 8-bit sRGB PNG ('Standard' view: clamp + sRGB OETF)."""
    a = np.clip(np.asarray(img, np.float64)[..., :3] * exposure_gain, 0.0, 1.0)
    s = np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.power(a, 1 / 2.4) - 0.055)
    b = (np.clip(s, 0, 1) * 255 + 0.5).astype(np.uint8)
    H, W = b.shape[:2]
    raw = b"".join(b"\x00" + b[y].tobytes() for y in range(H))

    def chunk(tag, data):
        c = tag + data
        return struct.pack(">I", len(data)) + c + struct.pack(">I", zlib.crc32(c) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(png)


def cache_dir() -> str:
    base = os.environ.get("FPPM_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "fppm")
    return os.path.join(base, "references")


def reference_key(blend_bytes: bytes, settings: dict) -> str:
    """sha256 of the .blend's bytes and the reference settings (JSON, sorted keys)."""
    h = hashlib.sha256()
    h.update(blend_bytes)
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()


def _layer(layers: dict, name: str):
    """A layer of read_exr's dict by exact name or by '<view layer>.<name>' suffix."""
    if name in layers:
        return layers[name]
    for k, v in layers.items():
        if k.endswith("." + name):
            return v
    return None


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


# ---------------------------------------------------------------------------
# Blender side

def _open(bpy, path: str, resolution) -> object:
    from .. import addon
    addon.register()
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False, use_scripts=False)
    except RuntimeError as ex:
        raise ConvergeError(3, f"cannot open '{path}': {str(ex).strip()}")
    scene = bpy.context.scene
    if resolution is not None:
        scene.render.resolution_percentage = resolution
    if scene.camera is None:
        raise ConvergeError(4, "The scene has no camera: add a camera and set it as the scene camera.")
    return scene


def cycles_reference_setup(scene) -> None:
    """Cycles settings for an unbiased, comparable render (docs/cycles_units.md)."""
    r = scene.render
    r.engine = "CYCLES"
    r.use_persistent_data = False
    vs = scene.view_settings
    vs.view_transform = "Standard"
    vs.look = "None"
    vs.exposure = 0.0
    vs.gamma = 1.0
    c = scene.cycles
    c.device = "CPU"
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.blur_glossy = 0.0
    c.use_animated_seed = False


def cycles_render(bpy, scene, samples: int, seed: int, passes: bool = False):
    """Render with Cycles; returns ({layer: (H, W, C) float32}, wall seconds of render.render)."""
    from ..core.io.exr import read_exr
    scene.cycles.samples = int(samples)
    scene.cycles.seed = int(seed)
    vl = bpy.context.view_layer
    vl.use_pass_diffuse_direct = passes
    vl.use_pass_diffuse_indirect = passes
    im = scene.render.image_settings
    if hasattr(im, "media_type"):        # Blender >= 5: multilayer is a media type
        im.media_type = "MULTI_LAYER_IMAGE" if passes else "IMAGE"
    im.file_format = "OPEN_EXR_MULTILAYER" if passes else "OPEN_EXR"
    im.color_depth = "32"
    im.color_mode = "RGBA"
    im.exr_codec = "ZIP"
    with tempfile.TemporaryDirectory() as tmp:
        p = os.path.join(tmp, "r.exr")
        if passes:
            # write_still writes every pass (save_render keeps only Combined);
            # the reference's time is not a measurement, the file write may count.
            scene.render.filepath = p
            scene.render.use_file_extension = False
            t0 = time.perf_counter()
            bpy.ops.render.render(write_still=True)
            dt = time.perf_counter() - t0
        else:
            t0 = time.perf_counter()
            bpy.ops.render.render()
            dt = time.perf_counter() - t0
            bpy.data.images["Render Result"].save_render(filepath=p, scene=scene)
        layers = read_exr(p)
    return layers, dt


def make_reference(bpy, scene, blend_path: str, samples: int, log, progress) -> dict:
    """Cycles reference (cached): {"image", "var", "diff_direct", "diff_indirect", "meta", "path"}."""
    from ..core.io.exr import read_exr, read_exr_metadata, write_exr
    r = scene.render
    pct = r.resolution_percentage
    W, H = r.resolution_x * pct // 100, r.resolution_y * pct // 100
    half = max(1, samples // 2)
    key_settings = {"version": REF_VERSION, "samples": 2 * half, "seeds": list(REF_SEEDS),
                    "resolution": [W, H], "frame": scene.frame_current,
                    "blender": bpy.app.version_string}
    with open(blend_path, "rb") as f:
        key = reference_key(f.read(), key_settings)
    path = os.path.join(cache_dir(), key + ".exr")
    if os.path.isfile(path):
        layers = read_exr(path)
        meta = json.loads(read_exr_metadata(path).get("fppm:reference", "{}"))
        log(f"Reference: cached {path} ({meta.get('samples')} spp, "
            f"{meta.get('render_seconds', float('nan')):.0f} s when made).")
    else:
        cycles_reference_setup(scene)
        halves, secs = [], []
        for i, s in enumerate(REF_SEEDS):
            progress(f"[reference] rendering half {i + 1}/2: {half} spp with Cycles ...", force=True)
            lay, dt = cycles_render(bpy, scene, half, s, passes=True)
            halves.append(lay)
            secs.append(dt)
        a, b = (_layer(h, "Combined") for h in halves)
        if a is None or b is None:
            raise ConvergeError(1, "internal error: Cycles produced no Combined layer.")
        img = 0.5 * (a.astype(np.float64) + b)
        var = 0.25 * (a.astype(np.float64) - b) ** 2
        layers = {"Combined": img.astype(np.float32), "Variance": var[..., :3].astype(np.float32)}
        for nm, bl in (("DiffDir", "Diffuse Direct"), ("DiffInd", "Diffuse Indirect")):
            x, y = _layer(halves[0], bl), _layer(halves[1], bl)
            if x is not None and y is not None:
                layers[nm] = (0.5 * (x.astype(np.float64) + y))[..., :3].astype(np.float32)
        meta = dict(key_settings, render_seconds=sum(secs), source=os.path.basename(blend_path))
        os.makedirs(os.path.dirname(path), exist_ok=True)
        write_exr(path, layers, {"fppm:reference": json.dumps(meta)})
        log(f"Reference: {2 * half} spp in {sum(secs):.1f} s, cached as {path}.")
    return {"image": _layer(layers, "Combined")[..., :3].astype(np.float64),
            "var": None if _layer(layers, "Variance") is None else _layer(layers, "Variance").astype(np.float64),
            "diff_direct": _layer(layers, "DiffDir"), "diff_indirect": _layer(layers, "DiffInd"),
            "meta": meta, "path": path}


def load_reference(path: str) -> dict:
    from ..core.io.exr import read_exr
    try:
        layers = read_exr(path)
    except OSError as ex:
        raise ConvergeError(3, str(ex))
    comb = _layer(layers, "Combined")
    if comb is None or comb.shape[2] < 3:
        raise ConvergeError(3, f"'{path}' has no RGB (Combined) image.")
    var = _layer(layers, "Variance")
    sib = os.path.splitext(path)[0] + "_var.exr"
    if var is None and os.path.isfile(sib):
        # tests/references/<name>_var.exr: per-pixel variance of the reference.
        var = _layer(read_exr(sib), "Combined")
    return {"image": comb[..., :3].astype(np.float64),
            "var": None if var is None else var[..., :3].astype(np.float64),
            "diff_direct": _layer(layers, "DiffDir"), "diff_indirect": _layer(layers, "DiffInd"),
            "meta": {"source": path}, "path": path}


def load_mask(bpy, path: str, shape) -> dict:
    if path.lower().endswith(".exr"):
        from ..core.io.exr import read_exr
        a = _layer(read_exr(path), "Combined")
    else:
        try:
            img = bpy.data.images.load(os.path.abspath(path), check_existing=False)
        except RuntimeError as ex:
            raise ConvergeError(3, f"cannot read the mask '{path}': {str(ex).strip()}")
        img.colorspace_settings.name = "Non-Color"
        w, h = img.size
        px = np.empty(w * h * img.channels, np.float32)
        img.pixels.foreach_get(px)
        a = px.reshape(h, w, img.channels)[::-1]
    if a is None or a.shape[:2] != tuple(shape):
        raise ConvergeError(2, f"the mask '{path}' must be {shape[1]}x{shape[0]} pixels.")
    return M.masks_from_image(a)


# ---------------------------------------------------------------------------
# runs

class Run:
    """The records of one (method, seed) run."""

    def __init__(self, method: str, seed: int):
        self.method, self.seed = method, seed
        self.rows: list[dict] = []
        self.image = None          # last image (H, W, 3) float64
        self.setup_seconds = 0.0
        self.throughput = None     # dict for fppm/ppm
        self.complete = False


def _record(run: Run, masks, ref, point, seconds, render_seconds, photons, samples, img):
    row = {"method": run.method, "seed": run.seed, "point": point,
           "seconds": round(seconds, 4), "render_seconds": round(render_seconds, 4),
           "photons": photons, "samples": samples}
    row.update(M.error_metrics(img, ref, masks))
    run.rows.append(row)
    run.image = img
    return row


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


# ---------------------------------------------------------------------------
# outputs

CSV_HEAD = ["method", "seed", "point", "seconds", "render_seconds", "photons", "samples"]


def csv_columns() -> list[str]:
    cols = list(CSV_HEAD)
    for reg in M.REGIONS:
        cols += [f"relmse_{reg}", f"rmse_{reg}", f"mre_{reg}"]
    return cols


def write_csv(path: str, runs) -> None:
    cols = csv_columns()
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for run in runs:
            for row in run.rows:
                w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v)
                            for k, v in row.items()})


def error_at(runs, method, t, key="relmse_all") -> tuple[float, float, float]:
    """(mean, min, max) over seeds of the log-log interpolated error at time t."""
    vals = []
    for r in runs:
        if r.method != method or not r.rows:
            continue
        ts = np.array([row["seconds"] for row in r.rows], float)
        es = np.array([row[key] for row in r.rows], float)
        vals.append(M.loglog_interp(t, ts, es))
    vals = np.array(vals, float)
    if vals.size == 0 or np.all(np.isnan(vals)):
        return float("nan"), float("nan"), float("nan")
    return float(np.nanmean(vals)), float(np.nanmin(vals)), float(np.nanmax(vals))


def plot(path: str, runs, budget, floors, title) -> str | None:
    """convergence.png with matplotlib (optional).  Returns a message when skipped."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "matplotlib is not installed: convergence.png skipped (pip install matplotlib)."
    colors = {"fppm": "tab:red", "paper": "tab:orange", "ppm": "tab:blue", "cycles": "tab:green"}
    fig, axes = plt.subplots(2, 2, figsize=(10, 8), sharex=True)
    methods = [m for m in METHODS if any(r.method == m and r.rows for r in runs)]
    for ax, reg in zip(axes.ravel(), M.REGIONS):
        key = f"relmse_{reg}"
        for m in methods:
            mr = [r for r in runs if r.method == m and r.rows]
            tmin = max(min(row["seconds"] for row in r.rows) for r in mr)
            tmax = min(max(row["seconds"] for row in r.rows) for r in mr)
            if len(mr) == 1 or tmax <= tmin:
                r = mr[0]
                ax.plot([row["seconds"] for row in r.rows], [row[key] for row in r.rows],
                        "-" if m != "cycles" else "o-", color=colors[m], label=m.upper(), ms=3)
                continue
            grid = np.geomspace(tmin, tmax, 60)
            vals = np.array([[M.loglog_interp(t, [row["seconds"] for row in r.rows],
                                              [row[key] for row in r.rows]) for t in grid]
                             for r in mr])
            ax.plot(grid, np.exp(np.nanmean(np.log(vals), axis=0)), color=colors[m],
                    label=f"{m.upper()} ({len(mr)} seeds)")
            ax.fill_between(grid, np.nanmin(vals, axis=0), np.nanmax(vals, axis=0),
                            color=colors[m], alpha=0.2, lw=0)
        fl = floors.get(reg)
        if fl is not None and np.isfinite(fl) and fl > 0:
            ax.axhline(fl, color="grey", ls=":", lw=1, label="reference noise")
        ax.axvline(budget, color="k", ls="--", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{reg}")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_ylabel("relMSE")
    for ax in axes[1]:
        ax.set_xlabel("seconds")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return None


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "n/a"
    return f"{v:.3g}"


TARGETS = {
    # kind: [(description, numerator, denominator, threshold)]
    "diffuse": [("FPPM relMSE <= 0.7x PPM", "fppm", "ppm", 0.7),
                ("FPPM relMSE <= 3x Cycles (purely diffuse)", "fppm", "cycles", 3.0)],
    "indirect": [("FPPM relMSE <= 0.7x PPM", "fppm", "ppm", 0.7),
                 ("FPPM relMSE <= 3x Cycles (purely diffuse)", "fppm", "cycles", 3.0)],
    "caustic-small": [("FPPM relMSE <= 1x PPM (no worse)", "fppm", "ppm", 1.0),
                      ("FPPM relMSE <= 0.1x Cycles (point / very small light)", "fppm", "cycles", 0.1)],
    "caustic-large": [("FPPM relMSE <= 1x PPM (no worse)", "fppm", "ppm", 1.0),
                      ("FPPM relMSE <= 1x Cycles (large area light: parity)", "fppm", "cycles", 1.0)],
}


def report(path, a, runs, ref, floors, masks, budget, notes, interrupted) -> dict:
    """Write report.md; returns the summary numbers (also used by the example script)."""
    methods = [m for m in METHODS if any(r.method == m and r.rows for r in runs)]
    fl = floors.get("all")
    use_excess = fl is not None and np.isfinite(fl)
    H, W = ref["image"].shape[:2]
    lines = [f"# Convergence: {os.path.basename(a.blend)}", ""]
    if interrupted:
        lines += ["**Interrupted (Ctrl-C): partial results.**", ""]
    lines += [f"- Resolution {W}x{H}, budget {budget:g} s per method, seeds "
              f"{a.seed}..{a.seed + a.seeds - 1}, {os.cpu_count()} CPU threads available "
              "(FPPM's gather and Cycles both use all of them).",
              f"- Reference: {ref['meta'].get('samples', '?')} spp Cycles"
              if "samples" in ref["meta"] else f"- Reference: {ref['path']}",
              f"- Reference noise floor (expected relMSE of a perfect image against it): "
              f"{_fmt(fl)}" + ("" if use_excess else " (unknown: no variance layer)"),
              "- relMSE = mean (x - r)^2 / (r^2 + 0.01) over pixels and RGB; "
              "excess = relMSE - floor (estimates the error against the true image).",
              "- Time: FPPM/PPM = Renderer setup (BVH, occlusion grid) + passes; Cycles = "
              "one render.render per ladder point (1, 2, 4, ... spp).  Values at a given time are "
              "log-log interpolated between recorded points.",
              ""]
    for m in methods:
        rs = [r for r in runs if r.method == m]
        if m != "cycles":
            lines.append(f"- {m.upper()}: passes per seed {[len(r.rows) for r in rs]}, photons (M) "
                         f"{[round(int(r.rows[-1]['photons']) / 1e6, 1) for r in rs if r.rows]}, "
                         f"setup {np.mean([r.setup_seconds for r in rs]):.2f} s.")
        else:
            lines.append(f"- CYCLES: ladder up to {rs[0].rows[-1]['samples'] if rs[0].rows else 0} spp.")
            if any(r.rows and r.rows[-1]["seconds"] < budget for r in rs):
                lines.append("  The ladder stopped before the budget (--cycles-max-samples or "
                             "Ctrl-C): after its last point Cycles' error is held constant.")
    lines += ["", "## Error at fractions of the budget", "",
              "| method | " + " | ".join(f"relMSE @{int(f * 100)}% ({f * budget:g} s)" for f in FRACTIONS)
              + " | excess @100% | RMSE @100% | MRE @100% |",
              "|---|" + "---|" * (len(FRACTIONS) + 3)]
    summary = {"budget": budget, "floor": fl, "methods": {}}
    for m in methods:
        vals = [error_at(runs, m, f * budget)[0] for f in FRACTIONS]
        ex = vals[-1] - fl if use_excess and np.isfinite(vals[-1]) else float("nan")
        rm = error_at(runs, m, budget, "rmse_all")[0]
        mre = error_at(runs, m, budget, "mre_all")[0]
        summary["methods"][m] = {"relmse": dict(zip(FRACTIONS, vals)), "excess": ex,
                                 "rmse": rm, "mre": mre}
        lines.append(f"| {m.upper()} | " + " | ".join(_fmt(v) for v in vals)
                     + f" | {_fmt(ex)} | {_fmt(rm)} | {_fmt(mre)} |")

    lines += ["", "## Regions at 100% of the budget (relMSE; floor in brackets)", "",
              "| method | " + " | ".join(f"{reg} ({int(masks[reg].sum()) if reg in masks else H * W} px) "
                                         f"[{_fmt(floors.get(reg))}]" for reg in M.REGIONS) + " |",
              "|---|" + "---|" * len(M.REGIONS)]
    for m in methods:
        lines.append(f"| {m.upper()} | " + " | ".join(
            _fmt(error_at(runs, m, budget, f"relmse_{reg}")[0]) for reg in M.REGIONS) + " |")

    def ratio(num, den, f, excess):
        a_ = error_at(runs, num, f * budget)[0]
        b_ = error_at(runs, den, f * budget)[0]
        if excess and not use_excess:
            return float("nan")
        if excess:
            a_, b_ = a_ - fl, b_ - fl
            if not (a_ > 0 and b_ > 0):
                return float("nan")
        return a_ / b_ if b_ and np.isfinite(a_) and np.isfinite(b_) else float("nan")

    pairs = [(n, d) for n, d in (("fppm", "ppm"), ("fppm", "paper"), ("paper", "ppm"),
                                  ("fppm", "cycles"), ("ppm", "cycles"))
             if n in methods and d in methods]
    summary["ratios"] = {}
    if pairs:
        lines += ["", "## Equal-time relMSE ratios", "",
                  "Ratio < 1: the first method has the lower error at the same time.  "
                  "'excess' subtracts the reference noise floor from both.", "",
                  "| ratio | " + " | ".join(f"@{int(f * 100)}%" for f in FRACTIONS)
                  + " | @100% (excess) |", "|---|" + "---|" * (len(FRACTIONS) + 1)]
        for n, d in pairs:
            rv = [ratio(n, d, f, False) for f in FRACTIONS]
            rx = ratio(n, d, 1.0, True)
            summary["ratios"][f"{n}/{d}"] = {"raw": rv[-1], "excess": rx}
            lines.append(f"| {n.upper()} / {d.upper()} | " + " | ".join(_fmt(v) for v in rv)
                         + f" | {_fmt(rx)} |")
        if ("ppm", "cycles") in pairs:
            rv = summary["ratios"]["ppm/cycles"]["raw"]
            if np.isfinite(rv):
                lines += ["", f"Classic PPM {'beats' if rv < 1 else 'does not beat'} Cycles here "
                              f"at equal time: PPM/Cycles relMSE = {rv:.3g} "
                              f"({'%.3gx lower' % (1 / rv) if rv < 1 else '%.3gx higher' % rv})."]

    carry = getattr(a, "_carry", None) or {}
    bn = {}
    if "## Bias" in carry:
        lines += ["", carry["## Bias"]]
        bn = carry.get("bias_noise", {})
    elif a.seeds >= 2:
        lines += ["", "## Bias and noise of the final images (relMSE units)", "",
                  "bias2 + noise = expected relMSE of one render (core.metrics.bias_noise).", "",
                  "| method | bias2 | noise | mean-image relMSE |", "|---|---|---|---|"]
        for m in methods:
            rs = [r for r in runs if r.method == m and r.image is not None]
            if m == "cycles":
                # The ladder point closest to the budget that every seed has.
                # The largest sample count every seed rendered within the budget.
                common = None
                for r in rs:
                    ok = {row["samples"] for row in r.rows if row["seconds"] <= budget}
                    common = ok if common is None else common & ok
                rs_imgs = ([r.ladder_images[max(common)] for r in rs] if common else [])
            else:
                rs_imgs = [r.image for r in rs]
            if len(rs_imgs) >= 2:
                d = M.bias_noise(rs_imgs, ref["image"])
                bn[m] = d
                lines.append(f"| {m.upper()} | {_fmt(d['bias2'])} | {_fmt(d['noise'])} | "
                             f"{_fmt(d['relmse_mean_image'])} |")
    summary["bias_noise"] = bn

    tp = [r for r in runs if r.throughput]
    if "## Throughput" in carry:
        lines += ["", carry["## Throughput"]]
        summary["throughput"] = carry.get("throughput", {})
    elif tp:
        lines += ["", "## Throughput", "",
                  "Photon pass (trace + gather) time / raw Embree `accel.intersect` time for the same "
                  "number of random rays, measured in the same process.", "",
                  "| run | photon pass s | rays (M) | raw Embree s | ratio |", "|---|---|---|---|---|"]
        for r in tp:
            t = r.throughput
            lines.append(f"| {r.method.upper()} seed {r.seed} | {t['photon_seconds']:.2f} | "
                         f"{t['photon_rays'] / 1e6:.2f} | {t['raw_seconds']:.2f} | {t['ratio']:.2f} |")
        summary["throughput"] = {f"{r.method}/{r.seed}": r.throughput["ratio"] for r in tp}

    lines += ["", "## Targets", ""]
    kind = getattr(a, "kind", None)
    summary["targets"] = []
    if kind is None:
        lines.append("No `--kind` given: the scene class is unknown, so no target is judged.")
    else:
        lines.append(f"Scene class: **{kind}**.  Judged at 100% of the budget on the excess relMSE "
                     "(reference noise subtracted) when both are above the floor, else on raw relMSE.")
        lines.append("")
        for desc, n, d, thr in TARGETS[kind]:
            if n not in methods or d not in methods:
                lines.append(f"- {desc}: not measured ({d} not run).")
                continue
            rx = ratio(n, d, 1.0, True)
            basis = "excess"
            if not np.isfinite(rx):
                rx, basis = ratio(n, d, 1.0, False), "raw"
            met = bool(np.isfinite(rx) and rx <= thr)
            summary["targets"].append({"target": desc, "ratio": rx, "basis": basis, "met": met})
            lines.append(f"- {desc}: ratio {_fmt(rx)} ({basis}) -> **{'MET' if met else 'MISSED'}**")
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    lines += ["", "Region definitions: core/metrics.py (module docstring and constants).", ""]
    with open(path, "w") as f:
        f.write("\n".join(lines))
    return summary


# ---------------------------------------------------------------------------
# the command

def converge(a, log=print) -> int:
    """Run ``fppm converge``; returns the exit code.  Raises ConvergeError on bad input."""
    from ..addon.cli import check_input
    check_input(a.blend)
    if not a.time_limit or a.time_limit <= 0:
        raise ConvergeError(2, "--time-limit must be > 0 seconds.")
    methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ConvergeError(2, f"--methods: unknown {bad or 'empty'}; choose from fppm,paper,ppm,cycles.")
    if a.seeds < 1:
        raise ConvergeError(2, "--seeds must be >= 1.")
    if a.resolution is not None and not 1 <= a.resolution <= 1000:
        raise ConvergeError(2, f"--resolution {a.resolution}: must be in [1, 1000].")
    if a.cycles_samples is not None and a.cycles_samples < 1:
        raise ConvergeError(2, "--cycles-samples must be >= 1.")
    try:
        os.makedirs(a.out, exist_ok=True)
    except OSError as ex:
        raise ConvergeError(5, f"cannot create the output folder '{a.out}': {ex.strerror}.")
    if not os.access(a.out, os.W_OK | os.X_OK):
        raise ConvergeError(5, f"the output folder '{a.out}' is not writable.")

    import bpy
    progress = Progress(getattr(a, "quiet", False))
    scene = _open(bpy, a.blend, a.resolution)
    budget = float(a.time_limit)
    if a.reference:
        ref = load_reference(a.reference)
    else:
        n = a.cycles_samples or int(scene.cycles.samples)
        ref = make_reference(bpy, scene, a.blend, n, log, progress)
        scene = _open(bpy, a.blend, a.resolution)    # undo the reference's pass settings
    H, W = ref["image"].shape[:2]
    notes = []
    if a.mask:
        masks = load_mask(bpy, a.mask, (H, W))
        notes.append(f"Regions from the mask image {a.mask} (R caustic, G smooth, B indirect).")
    else:
        masks = M.region_masks(ref["image"], ref["diff_direct"], ref["diff_indirect"])
        if ref["diff_direct"] is None:
            notes.append("Regions derived from the reference's luminance and gradient only "
                         "(no DiffDir/DiffInd passes): 'indirect' is the proxy 'dim and smooth'.")
        else:
            notes.append("Regions derived from the reference: caustic/smooth from luminance and "
                         "gradient, indirect from Cycles' DiffInd / (DiffDir + DiffInd) > 0.8.")
    floors = {}
    if ref["var"] is not None:
        floors["all"] = M.reference_floor(ref["image"], ref["var"])
        for k, m in masks.items():
            floors[k] = M.reference_floor(ref["image"], ref["var"], m)

    if getattr(a, "from_csv", False):
        return rereport(a, ref, floors, masks, budget, notes, log)
    runs: list[Run] = []
    stop = {"flag": False}
    interrupted = False
    seeds = list(range(a.seed, a.seed + a.seeds))
    fscene = None
    def on_sigint(signum, frame):
        if stop["flag"]:            # a second Ctrl-C: give up at once
            raise KeyboardInterrupt
        stop["flag"] = True         # Renderer.run / the ladder stop after the current step

    import signal
    prev_handler = signal.signal(signal.SIGINT, on_sigint)
    try:
        if "fppm" in methods or "ppm" in methods or "paper" in methods:
            from ..core.errors import FPPMError
            from ..addon.export import export_scene
            try:
                fscene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
            except FPPMError as ex:
                raise ConvergeError(4, str(ex))
            cam = fscene.camera.resolution
            if (int(cam[1]), int(cam[0])) != (H, W):
                raise ConvergeError(2, f"the reference is {W}x{H} but the scene renders "
                                       f"{int(cam[0])}x{int(cam[1])}: match --resolution.")
        for seed in seeds:
            for m in methods:
                if stop["flag"]:
                    break
                if m == "cycles":
                    run = Run("cycles", seed)
                    runs.append(run)        # appended first: Ctrl-C keeps its points
                    run_cycles_ladder(run, bpy, scene, seed, budget, a.cycles_max_samples,
                                      ref["image"], masks, log, progress, stop, H, W)
                else:
                    run = Run(m, seed)
                    runs.append(run)
                    run_photon_mapping(run, scene, fscene, budget, a.photons, ref["image"],
                                       masks, log, progress, stop)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        signal.signal(signal.SIGINT, prev_handler)
    if stop["flag"] or interrupted:
        interrupted = True
        log("Interrupted: writing what is done so far.")
    runs = [r for r in runs if r.rows]
    if not runs:
        log("Nothing was measured: no output written.")
        return 130 if interrupted else 1
    _write_all(a, runs, ref, floors, masks, budget, notes, interrupted, log)
    return 130 if interrupted else 0


def run_photon_mapping(run, scene, fscene, budget, photons, ref, masks, log, progress, stop):
    """FPPM or PPM (run.method) for ``budget`` seconds; records every pass into ``run``."""
    from ..core.render import Renderer
    from ..core.settings import SettingsError
    from ..addon.engine import film_gain
    from ..addon.properties import settings_from_scene
    m, seed = run.method, run.seed
    kw = dict(use_frequency=(m in ("fppm", "paper")), time_limit=float(budget), max_passes=0,
              seed=seed)
    if m == "paper":
        kw["frequency_model"] = "PAPER"
    elif m == "fppm":
        kw["frequency_model"] = "CORRECTED"
    if photons is not None:
        kw["photons_per_pass"] = photons
    try:
        settings = settings_from_scene(scene).replace(**kw).validate()
    except SettingsError as ex:
        raise ConvergeError(2, str(ex))
    gain = film_gain(scene)
    # Warm-up (not timed): loads numba's compiled kernels from the disk cache,
    # a one-off per process that Cycles, already loaded, does not pay either.
    warm = Renderer(fscene, settings.replace(max_passes=1, time_limit=0.0,
                                             photons_per_pass=min(settings.photons_per_pass, 2000)),
                    log=lambda s: None)
    warm.step()
    del warm
    t0 = time.perf_counter()
    renderer = Renderer(fscene, settings, log=lambda s: None)
    run.setup_seconds = time.perf_counter() - t0

    def on_pass(pr):
        img = pr.image[..., :3].astype(np.float64) * gain
        row = _record(run, masks, ref, pr.pass_index, run.setup_seconds + pr.elapsed,
                      pr.elapsed, pr.photons_emitted, "", img)
        progress(f"[{m} seed {seed}] {pr.elapsed:5.1f}/{budget:g} s  pass {pr.pass_index}  "
                 f"relMSE {row['relmse_all']:.3e}")

    renderer.run(should_stop=lambda: stop["flag"], on_pass=on_pass)
    run.complete = True
    st = renderer.stage_seconds
    t_photon = st["photon_trace"] + st["gather"]
    rays = int(renderer.photon_rays)
    t_raw = raw_ray_seconds(renderer.accel, renderer.scene, rays)
    run.throughput = {"photon_seconds": t_photon, "photon_rays": rays, "raw_seconds": t_raw,
                              "ratio": t_photon / t_raw if t_raw and t_raw > 0 else float("nan")}
    msg = (f"{m} seed {seed}: {renderer.pass_index} passes, {renderer.photons_emitted / 1e6:.1f} M "
           f"photons, setup {run.setup_seconds:.2f} s; photon pass {t_photon:.2f} s for "
           f"{rays / 1e6:.2f} M rays = {run.throughput['ratio']:.2f}x raw Embree "
           f"({t_raw:.2f} s).")
    log(msg)
    return run


def run_cycles_ladder(run, bpy, scene, seed, budget, max_samples, ref, masks, log, progress,
                           stop, H, W):
    cycles_reference_setup(scene)
    run.ladder_images = {}
    n = 1
    while n <= max_samples and not stop["flag"]:
        layers, dt = cycles_render(bpy, scene, n, seed)
        img = _layer(layers, "Combined")[..., :3].astype(np.float64)
        if img.shape[:2] != (H, W):
            raise ConvergeError(2, f"the reference is {W}x{H} but Cycles renders "
                                   f"{img.shape[1]}x{img.shape[0]}: match --resolution.")
        row = _record(run, masks, ref, n, dt, dt, "", n, img)
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


def _sections(text: str) -> dict:
    """{"## <first word>": section text up to the next '## '} of a report.md."""
    out, cur = {}, None
    for line in text.splitlines():
        if line.startswith("## "):
            cur = " ".join(line.split()[:2])
            out[cur] = [line]
        elif cur:
            out[cur].append(line)
    return {k: "\n".join(v).rstrip() for k, v in out.items()}


def rereport(a, ref, floors, masks, budget, notes, log) -> int:
    """--from-csv: rebuild report.md, summary.json and the plot from DIR/convergence.csv."""
    path = os.path.join(a.out, "convergence.csv")
    if not os.path.isfile(path):
        raise ConvergeError(3, f"--from-csv: '{path}' does not exist.")
    runs: dict = {}
    with open(path) as f:
        for row in csv.DictReader(f):
            key = (row["method"], int(row["seed"]))
            r = runs.setdefault(key, Run(*key))
            d = {k: (v if k in ("method",) else (float(v) if v not in ("", None) else ""))
                 for k, v in row.items()}
            d["seed"] = int(row["seed"])
            for k in ("point", "photons", "samples"):
                if d[k] != "":
                    d[k] = int(d[k])
            r.rows.append(d)
    runs = list(runs.values())
    for r in runs:
        if r.method != "cycles" and r.rows:
            r.setup_seconds = r.rows[0]["seconds"] - r.rows[0]["render_seconds"]
    a.seeds = len({r.seed for r in runs})
    carry = {}
    rp = os.path.join(a.out, "report.md")
    if os.path.isfile(rp):
        with open(rp) as f:
            sec = _sections(f.read())
        for k in ("## Bias", "## Throughput"):
            if k in sec:
                carry[k] = sec[k]
    sp = os.path.join(a.out, "summary.json")
    if os.path.isfile(sp):
        with open(sp) as f:
            old = json.load(f)
        carry["bias_noise"] = old.get("bias_noise", {})
        carry["throughput"] = old.get("throughput", {})
    a._carry = carry
    notes = notes + ["Report rebuilt from convergence.csv (--from-csv); the bias/noise and "
                     "throughput sections are those of the original run."]
    msg = plot(os.path.join(a.out, "convergence.png"), runs, budget, floors,
               f"{os.path.basename(a.blend)}: relMSE vs time ({budget:g} s budget)")
    if msg:
        notes.append(msg)
    summary = report(rp, a, runs, ref, floors, masks, budget, notes, False)
    with open(sp, "w") as f:
        json.dump(summary, f, indent=1, default=lambda o: None if not np.isfinite(o) else o)
    log(f"Rebuilt report.md, summary.json{'' if msg else ', convergence.png'} in {a.out}.")
    return 0


def _write_all(a, runs, ref, floors, masks, budget, notes, interrupted, log):
    from ..core.io.exr import write_exr
    out = a.out
    write_csv(os.path.join(out, "convergence.csv"), runs)
    written = ["convergence.csv"]
    msg = plot(os.path.join(out, "convergence.png"), runs, budget, floors,
               f"{os.path.basename(a.blend)}: relMSE vs time ({budget:g} s budget)")
    if msg:
        log(msg)
        notes = notes + [msg]
    else:
        written.append("convergence.png")
    summary = report(os.path.join(out, "report.md"), a, runs, ref, floors, masks, budget, notes,
                     interrupted)
    written.append("report.md")
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, default=lambda o: None if not np.isfinite(o) else o)
    written.append("summary.json")
    first = {}
    for r in runs:
        first.setdefault(r.method, r)
    for m, r in first.items():
        if r.image is None:
            continue
        write_exr(os.path.join(out, f"{m}.exr"), {"Combined": r.image.astype(np.float32)},
                  {"fppm:method": m, "fppm:seed": str(r.seed),
                   "fppm:seconds": f"{r.rows[-1]['seconds']:.3f}"})
        write_png(os.path.join(out, f"{m}.png"), r.image)
        written += [f"{m}.exr", f"{m}.png"]
    write_png(os.path.join(out, "reference.png"), ref["image"])
    written.append("reference.png")
    log(f"Wrote {', '.join(written)} in {out}.")
    with open(os.path.join(out, "report.md")) as f:
        text = f.read()
    i = text.find("## Error at fractions")
    j = text.find("## Bias") if "## Bias" in text else text.find("## Throughput")
    if i >= 0:
        log(text[i:j if j > i else None].rstrip())
