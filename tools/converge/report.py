"""Outputs of ``fppm converge`` as text: convergence.csv (written and read back) and report.md.

Equal-time comparisons interpolate each run's error linearly in log-log
between its recorded points (``tools.metrics.loglog_interp``); over seeds the
interpolated errors are averaged (:func:`error_at`).  report.md has one
section per function below; :func:`report` also returns the numbers as the
summary dict (summary.json).
"""
from __future__ import annotations

import csv
import os

import numpy as np

from .. import metrics as M
from .runs import Run, methods_run

FRACTIONS = (0.1, 0.5, 1.0)
KINDS = ("diffuse", "indirect", "caustic-small", "caustic-point", "caustic-large")
# The targets of the combined integrator and of FPPM (against
# PPM and the published per-pixel radius rules), by scene class.
# Every kind: the combined integrator against the strategies it combines
# (docs/integrators.md), when they ran.  A denominator that is a tuple means
# the best (lowest error) of those methods at that time.
SINGLE_STRATEGIES = ("fppm", "ppm", "path", "light")
_COMBINED = [("Combined relMSE <= 1x the best single strategy", "combined", SINGLE_STRATEGIES, 1.0,
              (1.0,))]
# Every kind: FPPM never worse than PPM, judged early, midway and at the end of the budget.
_NO_WORSE = [("FPPM relMSE <= 1x PPM at 10%, 50% and 100% of the budget", "fppm", "ppm", 1.0,
              (0.1, 0.5, 1.0))]
TARGETS = {
    # kind: [(description, numerator, denominator(s), threshold, fractions of the budget)]
    "diffuse": [("Combined relMSE <= 1x Cycles", "combined", "cycles", 1.0, (1.0,))]
               + _NO_WORSE + _COMBINED,
    # Indirect light dominates: the frequency radius must pay off, and beat
    # the two published per-pixel radius rules (docs/method.md).
    "indirect": [("FPPM relMSE <= 0.7x PPM", "fppm", "ppm", 0.7, (1.0,)),
                 ("FPPM relMSE < APPM", "fppm", "appm", 1.0, (1.0,)),
                 ("FPPM relMSE < CPPM", "fppm", "cppm", 1.0, (1.0,))]
                + _NO_WORSE + _COMBINED,
    "caustic-small": _NO_WORSE
                     + [("Combined relMSE <= 1x FPPM (no worse)", "combined", "fppm", 1.0, (1.0,))]
                     + _COMBINED,
    # A point light's caustic seen directly on diffuse surfaces: light tracing's ground.
    "caustic-point": _NO_WORSE
                     + [("Combined relMSE <= 0.2x FPPM", "combined", "fppm", 0.2, (1.0,))]
                     + _COMBINED,
    "caustic-large": _NO_WORSE + _COMBINED,
}
# An excess error (relMSE - reference floor) below this many floors is
# dominated by the reference's own noise: its ratios are flagged.
FLOOR_WARN = 3.0
# Sections of report.md that --from-csv keeps from the original run (they
# need the final images, which the CSV does not hold).
CARRIED = ("## Bias", "## Throughput")

# ---------------------------------------------------------------------------
# convergence.csv

CSV_HEAD = ["method", "seed", "point", "seconds", "render_seconds", "photons", "samples",
            "wall_seconds", "cpu_seconds"]


def csv_columns() -> list[str]:
    cols = list(CSV_HEAD)
    for reg in M.REGIONS:
        cols += [f"relmse_{reg}", f"rmse_{reg}", f"mre_{reg}", f"flip_{reg}"]
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


def read_csv(path: str) -> list[Run]:
    """The runs of a convergence.csv (rows only: no images, no throughput)."""
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
    return runs


def cores_of(runs, method) -> float:
    """Mean over seeds of the cores a method used (CPU / wall, :meth:`Run.cores`); NaN if unknown."""
    c = [r.cores() for r in runs if r.method == method and r.rows]
    c = [v for v in c if np.isfinite(v)]
    return float(np.mean(c)) if c else float("nan")


def sections(text: str) -> dict:
    """{"## <first word>": section text up to the next '## '} of a report.md."""
    out, cur = {}, None
    for line in text.splitlines():
        if line.startswith("## "):
            cur = " ".join(line.split()[:2])
            out[cur] = [line]
        elif cur:
            out[cur].append(line)
    return {k: "\n".join(v).rstrip() for k, v in out.items()}


# ---------------------------------------------------------------------------
# numbers

def error_at(runs, method, t, key="relmse_all", seed=None) -> tuple[float, float, float]:
    """(mean, min, max) over seeds (only ``seed`` when given) of the log-log
    interpolated error at time t."""
    vals = []
    for r in runs:
        if r.method != method or not r.rows or (seed is not None and r.seed != seed):
            continue
        ts = np.array([row["seconds"] for row in r.rows], float)
        es = np.array([row.get(key, np.nan) for row in r.rows], float)
        vals.append(M.loglog_interp(t, ts, es))
    vals = np.array(vals, float)
    if vals.size == 0 or np.all(np.isnan(vals)):
        return float("nan"), float("nan"), float("nan")
    return float(np.nanmean(vals)), float(np.nanmin(vals)), float(np.nanmax(vals))


def best_of(runs, methods, t, key="relmse_all") -> str | None:
    """The method of ``methods`` with the lowest mean error at time t (None if none ran)."""
    errs = [(error_at(runs, m, t, key)[0], m) for m in methods]
    errs = [(e, m) for e, m in errs if np.isfinite(e)]
    return min(errs)[1] if errs else None


def ratio(runs, num, den, t, floor, excess, key="relmse_all", seed=None) -> float:
    """Equal-time error ratio num / den at time t (relMSE unless ``key``); with
    ``excess`` the reference noise floor is subtracted from both (NaN when
    unknown or not above it).  A tuple ``den`` is the best of those methods at t.
    seed: the ratio of that seed's two runs (else of the means over seeds)."""
    if isinstance(den, tuple):
        den = best_of(runs, den, t, key)
        if den is None:
            return float("nan")
    a = error_at(runs, num, t, key, seed)[0]
    b = error_at(runs, den, t, key, seed)[0]
    if excess:
        if floor is None or not np.isfinite(floor):
            return float("nan")
        a, b = a - floor, b - floor
        if not (a > 0 and b > 0):
            return float("nan")
    return a / b if b and np.isfinite(a) and np.isfinite(b) else float("nan")


def ratio_spread(runs, num, den, t, floor, excess, key="relmse_all") -> tuple[float, float]:
    """(min, max) over the seeds both ran of the seed-by-seed ratio (:func:`ratio`)."""
    dens = den if isinstance(den, tuple) else (den,)
    seeds = sorted({r.seed for r in runs if r.method == num and r.rows}
                   & {r.seed for r in runs if r.method in dens and r.rows})
    v = [ratio(runs, num, den, t, floor, excess, key, sd) for sd in seeds]
    v = [x for x in v if np.isfinite(x)]
    return (float(min(v)), float(max(v))) if v else (float("nan"), float("nan"))


def floor_warnings(runs, methods, floor, t) -> list[str]:
    """Methods whose excess relMSE at time t is below FLOOR_WARN x the reference floor."""
    if floor is None or not np.isfinite(floor) or floor <= 0:
        return []
    out = []
    for m in methods:
        ex = error_at(runs, m, t)[0] - floor
        if np.isfinite(ex) and ex < FLOOR_WARN * floor:
            out.append(f"**Warning**: {m.upper()}'s excess relMSE at {t:g} s ({_fmt(ex)}) is below "
                       f"{FLOOR_WARN:g}x the reference's noise floor ({_fmt(floor)}): its excess "
                       "ratios measure the reference's noise as much as the method; a reference "
                       "with more samples is needed to compare it.")
    return out


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "n/a"
    return f"{v:.3g}"


# ---------------------------------------------------------------------------
# report.md, section by section: each returns its lines and fills ``summary``

def _cycles_process_lines(rs, summary) -> list[str]:
    """The Cycles ladder's process and its samples/s against a standalone Cycles render."""
    lines = []
    proc = next((r.cycles_process for r in rs if r.cycles_process), None)
    if proc is None and "cycles_process" in summary:
        proc = summary["cycles_process"]
    if proc:
        summary["cycles_process"] = proc
    speed = next((r.cycles_speed for r in rs if r.cycles_speed), None)
    if speed is None and "cycles_speed" in summary:
        speed = summary["cycles_speed"]
    if proc:
        loaded = [k for k in ("numba", "embreex") if proc.get(k)]
        lines.append("  Rendered in a process of its own (tools/converge/cycles_worker.py): "
                     + ("numba and embreex never imported there" if not loaded
                        else f"**{' and '.join(loaded)} imported there**")
                     + f", {proc.get('threads', '?')} OS threads at the end.")
    if speed:
        pct = 100 * (speed["ratio"] - 1)
        lines.append(f"  Cycles samples/s: ladder {speed['ladder_sps']:.1f} "
                     f"({speed['samples']} spp in {speed['ladder_seconds']:.2f} s), standalone "
                     f"Cycles process {speed['standalone_sps']:.1f} "
                     f"({speed['standalone_seconds']:.2f} s): {pct:+.1f}%, "
                     + ("**within 5%**: the ladder's times are those of Cycles alone."
                        if speed["within"] else
                        "**more than 5% apart**: the machine's load varied, or the ladder is "
                        "slowed; the ratios against Cycles are uncertain by as much."))
        summary["cycles_speed"] = speed
    elif proc or rs:
        lines.append("  Cycles samples/s not checked against a standalone render "
                     "(--no-cycles-check, or rebuilt from the CSV).")
    return lines


def _header(a, runs, ref, floor, budget, interrupted, summary) -> list[str]:
    H, W = ref["image"].shape[:2]
    known = floor is not None and np.isfinite(floor)
    lines = [f"# Convergence: {os.path.basename(a.blend)}", ""]
    if interrupted:
        lines += ["**Interrupted (Ctrl-C): partial results.**", ""]
    clock = getattr(a, "clock", "wall")
    summary["clock"] = clock
    summary["cores"] = {m: cores_of(runs, m) for m in methods_run(runs)}
    lines += [f"- Clock: **{clock}**: "
              + ("every budget and time below is CPU seconds (`time.process_time`) of the process "
                 "that renders (all its threads), so a machine shared with other jobs does not "
                 "change a method's budget; a method using fewer cores takes longer in wall time "
                 "for the same CPU (see the cores per method, and the wall-equivalent ratios "
                 "against Cycles)." if clock == "cpu" else
                 "wall-clock seconds (`time.perf_counter`): the machine's other load counts."),
              f"- Resolution {W}x{H}, budget {budget:g} s per method, seeds "
              f"{a.seed}..{a.seed + a.seeds - 1}, {os.cpu_count()} CPU threads available "
              "(FPPM's gather and Cycles both use all of them).",
              f"- Reference: {ref['meta'].get('samples', '?')} spp Cycles"
              if "samples" in ref["meta"] else f"- Reference: {ref['path']}",
              f"- Reference noise floor (expected relMSE of a perfect image against it, "
              f"mean (v / (r^2 + 0.01)) of the reference's per-pixel variance v, "
              f"tools.metrics.reference_floor): {_fmt(floor)}"
              + ("" if known else " (unknown: no variance layer)")
              + f"; an excess below {FLOOR_WARN:g}x it is flagged.",
              "- FLIP = mean HDR-FLIP error (flip-evaluator; 0 = identical, 1 = maximal), "
              "reported beside relMSE: relMSE rewards smooth biased images, FLIP also scores "
              "lost edges and features.  It has no noise-floor correction: the reference's "
              "own noise adds to it.",
              "- relMSE = mean (x - r)^2 / (r^2 + 0.01) over pixels and RGB; "
              "excess = relMSE - floor (estimates the error against the true image).",
              "- Time: FPPM/PPM = render set-up (scene export, BVH, occlusion grid) + passes; "
              "Cycles = one render.render per ladder point (1, 2, 4, ... spp).  Values at a "
              "given time are log-log interpolated between recorded points.",
              ""]
    if getattr(a, "max_passes", 0):
        lines.append(f"- FPPM/PPM runs stop after {a.max_passes} passes (--max-passes) if the "
                     "budget is not reached first; after its last pass a run's error is held "
                     "constant.")
    for m in methods_run(runs):
        rs = [r for r in runs if r.method == m]
        if m != "cycles":
            lines.append(f"- {m.upper()}: passes per seed {[len(r.rows) for r in rs]}, photons (M) "
                         f"{[round(int(r.rows[-1]['photons']) / 1e6, 1) for r in rs if r.rows]}, "
                         f"setup {np.mean([r.setup_seconds for r in rs]):.2f} s, "
                         f"cores used (CPU / wall) {_fmt(summary['cores'][m])}.")
        else:
            lines.append(f"- CYCLES: ladder up to {rs[0].rows[-1]['samples'] if rs[0].rows else 0} spp, "
                         f"cores used (CPU / wall) {_fmt(summary['cores'][m])}.")
            lines += _cycles_process_lines(rs, summary)
            if any(r.rows and r.rows[-1]["seconds"] < budget for r in rs):
                lines.append("  The ladder stopped before the budget (--cycles-max-samples or "
                             "Ctrl-C): after its last point Cycles' error is held constant.")
    return lines


def _fractions(runs, floor, budget, summary) -> list[str]:
    known = floor is not None and np.isfinite(floor)
    lines = ["", "## Error at fractions of the budget", "",
             "| method | " + " | ".join(f"relMSE @{int(f * 100)}% ({f * budget:g} s)" for f in FRACTIONS)
             + " | excess @100% | RMSE @100% | MRE @100% | FLIP @100% |",
             "|---|" + "---|" * (len(FRACTIONS) + 4)]
    summary["methods"] = {}
    for m in methods_run(runs):
        vals = [error_at(runs, m, f * budget)[0] for f in FRACTIONS]
        ex = vals[-1] - floor if known and np.isfinite(vals[-1]) else float("nan")
        rm = error_at(runs, m, budget, "rmse_all")[0]
        mre = error_at(runs, m, budget, "mre_all")[0]
        fl = [error_at(runs, m, f * budget, "flip_all")[0] for f in FRACTIONS]
        summary["methods"][m] = {"relmse": dict(zip(FRACTIONS, vals)), "excess": ex,
                                 "relmse_spread": error_at(runs, m, budget)[1:],
                                 "flip_spread": error_at(runs, m, budget, "flip_all")[1:],
                                 "rmse": rm, "mre": mre, "flip": dict(zip(FRACTIONS, fl))}
        lines.append(f"| {m.upper()} | " + " | ".join(_fmt(v) for v in vals)
                     + f" | {_fmt(ex)} | {_fmt(rm)} | {_fmt(mre)} | {_fmt(fl[-1])} |")
    warn = floor_warnings(runs, methods_run(runs), floor, budget)
    if warn:
        lines += [""] + warn
    return lines


def _flip(runs, budget, summary) -> list[str]:
    """HDR-FLIP at fractions of the budget, per region at 100%, and its equal-time ratios."""
    methods = methods_run(runs)
    if not methods or not any("flip_all" in row for r in runs for row in r.rows):
        return []
    lines = ["", "## FLIP (HDR-FLIP, mean over the region; lower is better)", "",
             "| method | " + " | ".join(f"FLIP @{int(f * 100)}%" for f in FRACTIONS) + " | "
             + " | ".join(f"{reg} @100%" for reg in M.REGIONS[1:]) + " |",
             "|---|" + "---|" * (len(FRACTIONS) + len(M.REGIONS) - 1)]
    for m in methods:
        vals = [error_at(runs, m, f * budget, "flip_all")[0] for f in FRACTIONS]
        regs = [error_at(runs, m, budget, f"flip_{reg}")[0] for reg in M.REGIONS[1:]]
        lines.append(f"| {m.upper()} | " + " | ".join(_fmt(v) for v in vals + regs) + " |")
    summary["flip_ratios"] = {}
    pairs = [(n, d) for n, d in _PAIRS if n in methods and d in methods]
    if pairs:
        lines += ["", "| FLIP ratio | " + " | ".join(f"@{int(f * 100)}%" for f in FRACTIONS) + " |",
                  "|---|" + "---|" * len(FRACTIONS)]
        for n, d in pairs:
            rv = [ratio(runs, n, d, f * budget, None, False, "flip_all") for f in FRACTIONS]
            summary["flip_ratios"][f"{n}/{d}"] = rv[-1]
            lines.append(f"| {n.upper()} / {d.upper()} | " + " | ".join(_fmt(v) for v in rv) + " |")
    return lines


def _regions(runs, floors, masks, budget, n_pixels) -> list[str]:
    lines = ["", "## Regions at 100% of the budget (relMSE; floor in brackets)", "",
             "| method | " + " | ".join(f"{reg} ({int(masks[reg].sum()) if reg in masks else n_pixels} px) "
                                        f"[{_fmt(floors.get(reg))}]" for reg in M.REGIONS) + " |",
             "|---|" + "---|" * len(M.REGIONS)]
    for m in methods_run(runs):
        lines.append(f"| {m.upper()} | " + " | ".join(
            _fmt(error_at(runs, m, budget, f"relmse_{reg}")[0]) for reg in M.REGIONS) + " |")
    return lines


# The equal-time ratios reported (numerator, denominator), when both ran.
_PAIRS = (("fppm", "ppm"), ("fppm", "paper"), ("paper", "ppm"), ("fppm", "cycles"),
          ("ppm", "cycles"), ("fppm", "appm"), ("fppm", "cppm"), ("combined", "fppm"),
          ("combined", "path"), ("combined", "light"), ("combined", "cycles"),
          ("path", "cycles"), ("light", "fppm"))


def _ratios(runs, floor, budget, summary) -> list[str]:
    methods = methods_run(runs)
    pairs = [(n, d) for n, d in _PAIRS if n in methods and d in methods]
    summary["ratios"] = {}
    if not pairs:
        return []
    lines = ["", "## Equal-time relMSE ratios", "",
             "Ratio < 1: the first method has the lower error at the same time.  "
             "'excess' subtracts the reference noise floor from both.", "",
             "| ratio | " + " | ".join(f"@{int(f * 100)}%" for f in FRACTIONS)
             + " | @100% (excess) |", "|---|" + "---|" * (len(FRACTIONS) + 1)]
    for n, d in pairs:
        rv = [ratio(runs, n, d, f * budget, floor, False) for f in FRACTIONS]
        rx = ratio(runs, n, d, budget, floor, True)
        summary["ratios"][f"{n}/{d}"] = {"raw": rv[-1], "excess": rx}
        lines.append(f"| {n.upper()} / {d.upper()} | " + " | ".join(_fmt(v) for v in rv)
                     + f" | {_fmt(rx)} |")
    warn = floor_warnings(runs, sorted({m for p in pairs for m in p}, key=methods.index),
                          floor, budget)
    if warn:
        lines += ["", "The '@100% (excess)' column is uncertain where flagged:"] + warn
    lines += _wall_equivalent(pairs, summary)
    if ("ppm", "cycles") in pairs:
        rv = summary["ratios"]["ppm/cycles"]["raw"]
        if np.isfinite(rv):
            lines += ["", f"Classic PPM {'beats' if rv < 1 else 'does not beat'} Cycles here "
                          f"at equal time: PPM/Cycles relMSE = {rv:.3g} "
                          f"({'%.3gx lower' % (1 / rv) if rv < 1 else '%.3gx higher' % rv})."]
    return lines


def _wall_equivalent(pairs, summary) -> list[str]:
    """CPU clock: the ratios against Cycles at equal wall time, assuming relMSE ~ 1 / CPU.

    At equal wall time t a method on c cores gets c t CPU seconds, so its relMSE
    is its equal-CPU relMSE x 1/c (relative to the CPU budget): the method / Cycles
    ratio becomes ratio x c_cycles / c_method (worse for the method on fewer cores).
    """
    if summary.get("clock") != "cpu":
        return []
    cores = summary.get("cores", {})
    rows = []
    for n, d in pairs:
        if d != "cycles":
            continue
        r = summary["ratios"][f"{n}/{d}"]
        v = r["excess"] if np.isfinite(r["excess"]) else r["raw"]
        we = v * cores.get(d, np.nan) / cores.get(n, np.nan)
        r["wall_equivalent"] = we
        rows.append(f"| {n.upper()} / CYCLES | {_fmt(v)} | {_fmt(cores.get(n))} | "
                    f"{_fmt(cores.get(d))} | {_fmt(we)} |")
    if not rows:
        return []
    return ["", "Wall-equivalent ratios against Cycles (the CPU clock favours the method using "
                "fewer cores): equal-CPU ratio x cores(Cycles) / cores(method), since relMSE ~ 1 / "
                "CPU time.", "",
            "| ratio | equal CPU @100% | cores method | cores Cycles | wall-equivalent |",
            "|---|---|---|---|---|"] + rows


def _bias_noise(runs, ref, budget, n_seeds, carry, summary) -> list[str]:
    lines, bn = [], {}
    if "## Bias" in carry:
        lines += ["", carry["## Bias"]]
        bn = carry.get("bias_noise", {})
    elif n_seeds >= 2:
        lines += ["", "## Bias and noise of the final images (relMSE units)", "",
                  "bias2 + noise = expected relMSE of one render (tools.metrics.bias_noise).", "",
                  "| method | bias2 | noise | mean-image relMSE |", "|---|---|---|---|"]
        for m in methods_run(runs):
            rs = [r for r in runs if r.method == m and r.image is not None]
            if m == "cycles":
                # The largest sample count every seed rendered within the budget.
                common = None
                for r in rs:
                    ok = {row["samples"] for row in r.rows if row["seconds"] <= budget}
                    common = ok if common is None else common & ok
                imgs = [r.ladder_images[max(common)] for r in rs] if common else []
            else:
                imgs = [r.image for r in rs]
            if len(imgs) >= 2:
                d = M.bias_noise(imgs, ref["image"], ref.get("trusted"))
                bn[m] = d
                lines.append(f"| {m.upper()} | {_fmt(d['bias2'])} | {_fmt(d['noise'])} | "
                             f"{_fmt(d['relmse_mean_image'])} |")
    summary["bias_noise"] = bn
    return lines


def _throughput(runs, carry, summary) -> list[str]:
    tp = [r for r in runs if r.throughput]
    if "## Throughput" in carry:
        summary["throughput"] = carry.get("throughput", {})
        return ["", carry["## Throughput"]]
    if not tp:
        return []
    lines = ["", "## Throughput", "",
             "Photon pass (trace + gather) time / raw Embree `accel.intersect` time for the same "
             "number of random rays, measured in the same process.", "",
             "| run | photon pass s | rays (M) | raw Embree s | ratio |", "|---|---|---|---|---|"]
    for r in tp:
        t = r.throughput
        lines.append(f"| {r.method.upper()} seed {r.seed} | {t['photon_seconds']:.2f} | "
                     f"{t['photon_rays'] / 1e6:.2f} | {t['raw_seconds']:.2f} | {t['ratio']:.2f} |")
    summary["throughput"] = {f"{r.method}/{r.seed}": r.throughput["ratio"] for r in tp}
    return lines


def _targets(runs, floor, budget, kind, summary) -> list[str]:
    lines = ["", "## Targets", ""]
    methods = methods_run(runs)
    summary["targets"] = []
    if kind is None:
        lines.append("No `--kind` given: the scene class is unknown, so no target is judged.")
        return lines
    lines.append(f"Scene class: **{kind}**.  Judged at 100% of the budget (or the fractions named) on the excess relMSE "
                 "(reference noise subtracted) when both are above the floor, else on raw relMSE.")
    lines.append("")
    for desc, n, d, thr, fracs in TARGETS[kind]:
        dens = d if isinstance(d, tuple) else (d,)
        if n not in methods or not any(m in methods for m in dens):
            lines.append(f"- {desc}: not measured ({n if n not in methods else '/'.join(dens)} not run).")
            continue
        d = tuple(m for m in dens if m in methods) if isinstance(d, tuple) else d
        # The worst ratio over the fractions judged (NaN if any is unknown).
        judged = []
        for f in fracs:
            rx, b = ratio(runs, n, d, f * budget, floor, True), "excess"
            if not np.isfinite(rx):
                rx, b = ratio(runs, n, d, f * budget, floor, False), "raw"
            judged.append((rx, b, f))
        rx, basis, fw = (max(judged) if all(np.isfinite(r) for r, _, _ in judged)
                         else (float("nan"), "raw", 1.0))
        spread = ratio_spread(runs, n, d, fw * budget, floor, basis == "excess")
        flip_r = ratio(runs, n, d, budget, None, False, "flip_all")
        against = d if not isinstance(d, tuple) else best_of(runs, d, budget)
        near = bool(basis == "excess" and floor_warnings(runs, (n, against), floor, budget))
        rx = float(rx)
        met = bool(np.isfinite(rx) and rx <= thr)
        summary["targets"].append({"target": desc, "ratio": rx, "basis": basis, "met": met,
                                   "near_floor": near, "against": against, "fraction": fw,
                                   "spread": spread, "flip_ratio": flip_r})
        lines.append(f"- {desc}: ratio {_fmt(rx)} (seeds {_fmt(spread[0])}-{_fmt(spread[1])}; "
                     f"FLIP ratio @100% {_fmt(flip_r)}; {basis}"
                     + (f", worst of {', '.join(f'{int(f * 100)}%' for f in fracs)}" if len(fracs) > 1 else "")
                     + (f", against {against}" if isinstance(d, tuple) else "")
                     + f") -> **{'MET' if met else 'MISSED'}**"
                     + (f" (an excess below {FLOOR_WARN:g}x the reference floor: uncertain)"
                        if near else ""))
    return lines


def report(path, a, runs, ref, floors, masks, budget, notes, interrupted, carry=None) -> dict:
    """Write report.md; returns the summary numbers (summary.json).

    a: the ``fppm converge`` arguments (blend, seed, seeds, kind).
    floors: {"all" | region: reference noise floor}; masks: {region: (H, W) bool}.
    carry: ``--from-csv``: the :data:`CARRIED` sections of the previous
      report.md and their "bias_noise" / "throughput" summary entries.
    """
    carry = carry or {}
    floor = floors.get("all")
    H, W = ref["image"].shape[:2]
    summary = {"budget": budget, "floor": floor}
    for k in ("cycles_speed", "cycles_process"):
        if carry.get(k):
            summary[k] = carry[k]
    lines = _header(a, runs, ref, floor, budget, interrupted, summary)
    lines += _fractions(runs, floor, budget, summary)
    lines += _regions(runs, floors, masks, budget, H * W)
    lines += _ratios(runs, floor, budget, summary)
    lines += _flip(runs, budget, summary)
    lines += _bias_noise(runs, ref, budget, a.seeds, carry, summary)
    lines += _throughput(runs, carry, summary)
    lines += _targets(runs, floor, budget, getattr(a, "kind", None), summary)
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    lines += ["", "Region definitions: tools/metrics.py (module docstring and constants).", ""]
    with open(path, "w") as f:
        f.write("\n".join(lines))
    return summary
