"""The ``fppm converge`` sub-command: its arguments, the sequence of runs, the output folder.

See the package docstring (``tools/converge/__init__.py``) for what it
measures; this module only checks the arguments, runs the methods in order
(with Ctrl-C handling) and writes DIR/.
"""
from __future__ import annotations

import json
import os
import signal

import numpy as np

from ...addon.cli import (EXIT_CANCELLED, EXIT_INPUT, EXIT_INTERNAL, EXIT_OK, EXIT_OUTPUT,
                          EXIT_SCENE, EXIT_USAGE, CLIError, check_input, open_blend, render_size)
from ...core.io.exr import write_exr
from .. import metrics as M
from . import plots, report as R
from .references import load_mask, load_reference, make_reference, trusted_masks
from .runs import (CLOCKS, CYCLES_HELP, METHOD_SETTINGS, METHODS, Progress, Run, cycles_speed_check,
                   run_cycles_ladder, run_photon_mapping)


def methods_help() -> str:
    """The --methods help: every method name and what it runs."""
    items = [f"'{m}' {h}" for m, (_, h) in METHOD_SETTINGS.items()] + [f"'cycles' {CYCLES_HELP}"]
    return (f"comma-separated subset of {','.join(METHODS)} (default: fppm,ppm,cycles): "
            + "; ".join(items))


def add_parser(sub) -> None:
    """Add the ``converge`` sub-command to an argparse sub-parsers object."""
    c = sub.add_parser("converge", help="error against run time: FPPM, PPM and Cycles",
                       description="Measure error against run time for FPPM, PPM and Cycles "
                                   "on SCENE.blend; writes a CSV, a plot and a report.")
    c.add_argument("blend", metavar="SCENE.blend", help="the .blend file (scripts are not run)")
    c.add_argument("--time-limit", type=float, required=True, metavar="S",
                   help="time budget per method, seconds (of --clock)")
    c.add_argument("--clock", choices=CLOCKS, default="wall",
                   help="what the budget and every time measure: 'wall' (default) or 'cpu', the "
                        "CPU seconds of the process that renders (all its threads: 2 cores for 60 s "
                        "= 120 s), fair on a loaded machine; every run records its cores used")
    c.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    g = c.add_mutually_exclusive_group()
    g.add_argument("--reference", metavar="REF.exr", help="reference image (linear RGB EXR)")
    g.add_argument("--cycles-samples", type=int, metavar="N",
                   help="render the reference with Cycles at N samples (default: the file's)")
    c.add_argument("--methods", default="fppm,ppm,cycles", help=methods_help())
    c.add_argument("--seeds", type=int, default=1, metavar="K", help="seeds per method (K >= 2: bias/noise)")
    c.add_argument("--seed", type=int, default=0, metavar="N", help="first seed (default 0)")
    c.add_argument("--resolution", type=int, metavar="PCT", help="resolution percentage (1-1000)")
    c.add_argument("--photons", type=int, metavar="N", help="photons per pass (FPPM and PPM)")
    c.add_argument("--mask", metavar="MASK", help="region mask image (PNG/EXR): R caustic, G smooth, B indirect")
    c.add_argument("--kind", choices=R.KINDS,
                   help="scene class for the targets section (default: all targets listed as 'n/a')")
    c.add_argument("--cycles-max-samples", type=int, default=1 << 20, metavar="N",
                   help="largest Cycles ladder sample count (default: no practical cap)")
    c.add_argument("--max-passes", type=int, default=0, metavar="N",
                   help="also stop each FPPM/PPM run after N passes (default 0: the time budget "
                        "only); pass-counted runs give the same images on any machine load")
    c.add_argument("--no-cycles-check", action="store_true",
                   help="skip the standalone Cycles render that checks the ladder's samples/s "
                        "(by default the first seed's last ladder point is rendered once more)")
    c.add_argument("--from-csv", action="store_true",
                   help="no renders: rebuild the report and plot from DIR/convergence.csv "
                        "(the bias/noise and throughput sections are kept from DIR/report.md)")
    c.add_argument("-q", "--quiet", action="store_true", help="no progress lines")


def check_args(a) -> list[str]:
    """Checks that need no Blender; returns the methods.  Creates the output folder."""
    check_input(a.blend)
    if not a.time_limit or a.time_limit <= 0:
        raise CLIError(EXIT_USAGE, "--time-limit must be > 0 seconds.")
    methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise CLIError(EXIT_USAGE, f"--methods: unknown {bad or 'empty'}; "
                                   f"choose from {','.join(METHODS)}.")
    if getattr(a, "max_passes", 0) < 0:
        raise CLIError(EXIT_USAGE, "--max-passes must be >= 0.")
    if a.seeds < 1:
        raise CLIError(EXIT_USAGE, "--seeds must be >= 1.")
    if a.resolution is not None and not 1 <= a.resolution <= 1000:
        raise CLIError(EXIT_USAGE, f"--resolution {a.resolution}: must be in [1, 1000].")
    if a.cycles_samples is not None and a.cycles_samples < 1:
        raise CLIError(EXIT_USAGE, "--cycles-samples must be >= 1.")
    try:
        import matplotlib  # noqa: F401  (the plot and the PNG images)
    except ImportError:
        raise CLIError(EXIT_INTERNAL, "fppm converge needs matplotlib (pip install matplotlib).")
    try:
        import flip_evaluator  # noqa: F401  (the FLIP error metric)
    except ImportError:
        raise CLIError(EXIT_INTERNAL, "fppm converge needs flip-evaluator "
                                      "(pip install flip-evaluator).")
    try:
        os.makedirs(a.out, exist_ok=True)
    except OSError as ex:
        raise CLIError(EXIT_OUTPUT, f"cannot create the output folder '{a.out}': {ex.strerror}.")
    if not os.access(a.out, os.W_OK | os.X_OK):
        raise CLIError(EXIT_OUTPUT, f"the output folder '{a.out}' is not writable.")
    return methods


def converge(a, log=print) -> int:
    """Run ``fppm converge``; returns the exit code.  Raises CLIError on bad input."""
    methods = check_args(a)

    import bpy

    from ...addon.export import NO_CAMERA

    progress = Progress(getattr(a, "quiet", False))
    scene = open_blend(a.blend, resolution=a.resolution)
    if scene.camera is None:
        raise CLIError(EXIT_SCENE, NO_CAMERA)
    W, H = render_size(scene)
    budget = float(a.time_limit)
    if a.reference:
        ref = load_reference(a.reference)
    else:
        n = a.cycles_samples or int(scene.cycles.samples)
        ref = make_reference(bpy, scene, a.blend, n, log, progress)
    if ref["image"].shape[:2] != (H, W):
        rh, rw = ref["image"].shape[:2]
        raise CLIError(EXIT_USAGE, f"the reference is {rw}x{rh} but the scene renders "
                                   f"{W}x{H}: match --resolution.")
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
    if ref.get("trusted") is not None:
        masks = trusted_masks(masks, ref["trusted"])
        notes.append(f"The reference vouches for {int(ref['trusted'].sum())} of {H * W} pixels "
                     f"(its Trusted layer): every relMSE, FLIP and floor here, 'all' included, "
                     f"is over those pixels.")
    floors = {}
    if ref["var"] is not None:
        floors["all"] = M.reference_floor(ref["image"], ref["var"])
        for k, m in masks.items():
            floors[k] = M.reference_floor(ref["image"], ref["var"], m)

    if getattr(a, "from_csv", False):
        return rereport(a, ref, floors, masks, budget, notes, log)
    runs, interrupted = run_all(a, bpy, methods, ref, masks, budget, log, progress)
    runs = [r for r in runs if r.rows]
    if not runs:
        log("Nothing was measured: no output written.")
        return EXIT_CANCELLED if interrupted else EXIT_INTERNAL
    write_all(a, runs, ref, floors, masks, budget, notes, interrupted, log)
    return EXIT_CANCELLED if interrupted else EXIT_OK


def run_all(a, bpy, methods, ref, masks, budget, log, progress) -> tuple[list[Run], bool]:
    """Every method for every seed, in that order; returns (runs, interrupted).

    The first Ctrl-C ends the current render after its pass (or ladder point)
    and skips the remaining runs; a second one stops at once.
    """
    runs: list[Run] = []
    clock = getattr(a, "clock", "wall")
    stop = {"flag": False}
    interrupted = False
    warmed = set()

    def on_sigint(signum, frame):
        if stop["flag"]:            # a second Ctrl-C: give up at once
            raise KeyboardInterrupt
        stop["flag"] = True         # the render / the ladder stop after the current step

    prev_handler = signal.signal(signal.SIGINT, on_sigint)
    try:
        for seed in range(a.seed, a.seed + a.seeds):
            for m in methods:
                if stop["flag"]:
                    break
                run = Run(m, seed)
                runs.append(run)        # appended first: Ctrl-C keeps its points
                if m == "cycles":
                    run_cycles_ladder(run, a.blend, a.resolution, budget,
                                      a.cycles_max_samples, ref["image"], masks, log, progress,
                                      stop, clock)
                    if seed == a.seed and not getattr(a, "no_cycles_check", False):
                        progress(f"[cycles] standalone render of {run.rows[-1]['samples'] if run.rows else 0} "
                                 "spp (samples/s check) ...", force=True)
                        cycles_speed_check(run, a.blend, a.resolution, stop, log, clock)
                else:
                    run_photon_mapping(run, a.blend, a.resolution, budget, a.photons,
                                       ref["image"], masks, log, progress, stop, warmed,
                                       getattr(a, "max_passes", 0), clock)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        signal.signal(signal.SIGINT, prev_handler)
    if stop["flag"] or interrupted:
        interrupted = True
        log("Interrupted: writing what is done so far.")
    return runs, interrupted


def _write_summary(path: str, summary: dict) -> None:
    with open(path, "w") as f:
        json.dump(summary, f, indent=1, default=lambda o: None if not np.isfinite(o) else o)


def _plots(out, runs, budget, floors, a) -> None:
    """convergence.png: relMSE and HDR-FLIP against time."""
    plots.plot(os.path.join(out, "convergence.png"), runs, budget, floors,
               f"{os.path.basename(a.blend)}: relMSE and HDR-FLIP vs time "
               f"({budget:g} s {getattr(a, 'clock', 'wall')} budget)")


def rereport(a, ref, floors, masks, budget, notes, log) -> int:
    """--from-csv: rebuild report.md, summary.json and the plot from DIR/convergence.csv."""
    path = os.path.join(a.out, "convergence.csv")
    if not os.path.isfile(path):
        raise CLIError(EXIT_INPUT, f"--from-csv: '{path}' does not exist.")
    runs = R.read_csv(path)
    a.seeds = len({r.seed for r in runs})
    carry = {}
    rp = os.path.join(a.out, "report.md")
    if os.path.isfile(rp):
        with open(rp) as f:
            sec = R.sections(f.read())
        for k in R.CARRIED:
            if k in sec:
                carry[k] = sec[k]
    sp = os.path.join(a.out, "summary.json")
    if os.path.isfile(sp):
        with open(sp) as f:
            old = json.load(f)
        carry["bias_noise"] = old.get("bias_noise", {})
        carry["throughput"] = old.get("throughput", {})
        carry["cycles_speed"] = old.get("cycles_speed")
        carry["cycles_process"] = old.get("cycles_process")
    notes = notes + ["Report rebuilt from convergence.csv (--from-csv); the bias/noise and "
                     "throughput sections are those of the original run."]
    _plots(a.out, runs, budget, floors, a)
    summary = R.report(rp, a, runs, ref, floors, masks, budget, notes, False, carry)
    _write_summary(sp, summary)
    log(f"Rebuilt report.md, summary.json, convergence.png in {a.out}.")
    return EXIT_OK


def write_all(a, runs, ref, floors, masks, budget, notes, interrupted, log) -> None:
    """DIR/convergence.csv, convergence.png, report.md, summary.json, <method>.exr/.png
    (the final image of each method's first seed) and reference.png."""
    out = a.out
    for r in runs:
        r.finish()
    R.write_csv(os.path.join(out, "convergence.csv"), runs)
    _plots(out, runs, budget, floors, a)
    summary = R.report(os.path.join(out, "report.md"), a, runs, ref, floors, masks, budget, notes,
                       interrupted)
    _write_summary(os.path.join(out, "summary.json"), summary)
    written = ["convergence.csv", "convergence.png", "report.md", "summary.json"]
    first = {}
    for r in runs:
        first.setdefault(r.method, r)
    for m, r in first.items():
        if r.image is None:
            continue
        write_exr(os.path.join(out, f"{m}.exr"), {"Combined": r.image.astype(np.float32)},
                  {"fppm:method": m, "fppm:seed": str(r.seed),
                   "fppm:seconds": f"{r.rows[-1]['seconds']:.3f}"})
        plots.write_png(os.path.join(out, f"{m}.png"), r.image)
        written += [f"{m}.exr", f"{m}.png"]
    plots.write_png(os.path.join(out, "reference.png"), ref["image"])
    written.append("reference.png")
    log(f"Wrote {', '.join(written)} in {out}.")
    with open(os.path.join(out, "report.md")) as f:
        text = f.read()
    i = text.find("## Error at fractions")
    j = text.find("## Bias") if "## Bias" in text else text.find("## Throughput")
    if i >= 0:
        log(text[i:j if j > i else None].rstrip())
