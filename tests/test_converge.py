"""``fppm converge`` end to end on a tiny scene (subprocesses, as a user runs it).

tests/scenes/t_light_point.blend is 64x64; its Cycles reference is
tests/references/t_light_point.exr (with _var.exr beside it), so the main run
needs no Cycles reference render.  Its FPPM/PPM runs are counted in passes
(--max-passes), so the numbers checked do not depend on the machine's load or
on numba's compile time.  A second run makes a tiny Cycles reference
(8 spp) in a temporary cache and runs only the Cycles ladder, twice (the
second time from the cache).  Total about 35 s on this machine.

The subprocesses share this session's kernel cache (``$FPPM_CACHE_DIR`` as
inherited): the CLI imports the kernels under the same module names as the
tests (tests/fppm_alias.py), so they compile once per suite, not once per
subprocess.  Only the reference-cache test points ``$FPPM_CACHE_DIR`` at a
temporary folder, since the rendered reference is what it checks.
"""
import csv
import json
import os
import subprocess

import numpy as np
import pytest

import bpy_helpers as H
from tools import metrics as M
from core.io.exr import read_exr
from scenes import refs

# Budgets counted in passes (--max-passes): a pass-counted run gives the same
# images on any machine load; the time budget is only an upper bound here.
PASSES = 6
BUDGET = 60.0
SEEDS = (0, 1)
COLUMNS = (["method", "seed", "point", "seconds", "render_seconds", "photons", "samples",
            "wall_seconds", "cpu_seconds"]
           + [f"{k}_{g}" for g in ("all", "smooth", "caustic", "indirect")
              for k in ("relmse", "rmse", "mre", "flip")])


def _env(tmp, own_cache=False):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if own_cache:
        env["FPPM_CACHE_DIR"] = str(tmp)
    return env


def _run(args, tmp, timeout=900, own_cache=False):
    return subprocess.run(H.fppm_command() + [str(a) for a in args], capture_output=True,
                          text=True, env=_env(tmp, own_cache), cwd=str(tmp), timeout=timeout)


def _rows(out):
    with open(out / "convergence.csv") as f:
        r = csv.DictReader(f)
        return r.fieldnames, list(r)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("converge")
    out = tmp / "out"
    r = _run(["converge", refs.scene_path("t_light_point"), "--time-limit", BUDGET,
              "--out", out, "--reference", os.path.join(refs.REFERENCES_DIR, "t_light_point.exr"),
              "--methods", "fppm,paper,ppm,cycles", "--seeds", len(SEEDS),
              "--max-passes", PASSES, "--cycles-max-samples", 16, "--kind", "diffuse"], tmp)
    return r, out


def test_tiny_report_runs_and_writes_everything(tiny):
    r, out = tiny
    assert r.returncode == 0, r.stderr[-3000:]
    for f in ("convergence.csv", "report.md", "summary.json", "reference.png",
              "fppm.exr", "fppm.png", "ppm.exr", "ppm.png", "cycles.exr", "cycles.png"):
        assert (out / f).is_file(), f
    try:
        import matplotlib  # noqa: F401
        assert (out / "convergence.png").is_file()
    except ImportError:
        assert "matplotlib is not installed" in r.stdout
    # Throughput line: photon pass / raw Embree, for each FPPM/PPM run.
    assert r.stdout.count("x raw Embree") == 3 * len(SEEDS)   # fppm, paper, ppm
    # Progress lines on stderr.
    assert "[fppm seed 0]" in r.stderr and "[cycles seed 1]" in r.stderr


def test_csv_columns_rows_and_monotone_time(tiny):
    r, out = tiny
    cols, rows = _rows(out)
    assert cols == COLUMNS
    for seed in SEEDS:
        for m in ("fppm", "ppm"):
            rs = [x for x in rows if x["method"] == m and int(x["seed"]) == seed]
            assert [int(x["point"]) for x in rs] == list(range(1, PASSES + 1))
            t = np.array([float(x["seconds"]) for x in rs])
            # The default clock is wall: the CSV's seconds are wall_seconds.
            assert np.array_equal(t, [float(x["wall_seconds"]) for x in rs])
            ph = np.array([int(x["photons"]) for x in rs])
            assert np.all(np.diff(t) > 0) and np.all(np.diff(ph) > 0)
            assert np.all(ph == ph[0] * np.arange(1, len(rs) + 1))   # photons per pass constant
            # Converging: the same images whatever the load (seeded, pass-counted);
            # measured drop over 6 passes 4.8x-6.7x (8.1e-3 -> 1.2e-3 for FPPM seed 0).
            e = [float(x["relmse_all"]) for x in rs]
            assert e[-1] < e[0] / 3
            # FLIP at log-spaced times and at the last pass (the others NaN).
            f = np.array([float(x["flip_all"]) for x in rs])
            assert np.isfinite(f[0]) and np.isfinite(f[-1]) and f[-1] < f[0]
        cy = [x for x in rows if x["method"] == "cycles" and int(x["seed"]) == seed]
        # Each point is far below the budget, so the ladder runs to its cap.
        assert [int(x["samples"]) for x in cy] == [1, 2, 4, 8, 16]
        assert float(cy[-1]["seconds"]) > float(cy[0]["seconds"])


def test_csv_numbers_are_the_metrics_of_the_written_image(tiny):
    r, out = tiny
    _, rows = _rows(out)
    ref, _ = refs.load_reference("t_light_point")
    img = read_exr(str(out / "fppm.exr"))["Combined"]
    last = [x for x in rows if x["method"] == "fppm" and int(x["seed"]) == 0][-1]
    # CSV: 6 significant digits; the EXR is the float32 of the same image.
    assert float(last["relmse_all"]) == pytest.approx(M.relmse(img, ref), rel=1e-4)
    assert float(last["rmse_all"]) == pytest.approx(M.rmse(img, ref), rel=1e-4)
    assert float(last["mre_all"]) == pytest.approx(M.mean_relative_error(img, ref), rel=1e-4)
    # FLIP column = flip-evaluator's own HDR mean of the same pair (its float32
    # average and the CSV's 6 digits: 1e-4).
    F = pytest.importorskip("flip_evaluator")
    _, flip_mean, _ = F.evaluate(np.ascontiguousarray(ref[..., :3], np.float32),
                                 np.ascontiguousarray(np.maximum(img[..., :3], 0), np.float32),
                                 "HDR")
    assert float(last["flip_all"]) == pytest.approx(flip_mean, rel=1e-4)
    # Converged images score low (0 = identical): measured FPPM 0.03 at 3 s.
    assert 0.0 < float(last["flip_all"]) < 0.2


def test_cycles_ladder_runs_in_its_own_process_and_reports_samples_per_second(tiny):
    r, out = tiny
    text = (out / "report.md").read_text()
    assert "Rendered in a process of its own" in text
    assert "numba and embreex never imported there" in text
    assert "Cycles samples/s: ladder" in text and "standalone Cycles process" in text
    with open(out / "summary.json") as f:
        summ = json.load(f)
    proc, speed = summ["cycles_process"], summ["cycles_speed"]
    assert proc["numba"] is False and proc["embreex"] is False
    # The speed check re-rendered the first seed's last ladder point (16 spp),
    # and its samples/s are those of the CSV row.
    _, rows = _rows(out)
    last = [x for x in rows if x["method"] == "cycles" and int(x["seed"]) == SEEDS[0]][-1]
    assert speed["samples"] == int(last["samples"]) == 16
    assert speed["ladder_sps"] == pytest.approx(16 / float(last["seconds"]), rel=1e-3)
    assert speed["ratio"] == pytest.approx(speed["ladder_sps"] / speed["standalone_sps"], rel=1e-9)
    assert speed["within"] == (abs(speed["ratio"] - 1) <= 0.05)
    assert "cycles speed: ladder" in r.stdout


def test_report_tables_and_equal_time_ratios(tiny):
    r, out = tiny
    text = (out / "report.md").read_text()
    for s in ("## Error at fractions of the budget", "| FPPM |", "| PPM |", "| CYCLES |",
              "## Regions at 100%", "## Equal-time relMSE ratios", "| FPPM / PPM |",
              "| PAPER |", "| FPPM / PAPER |",
              "## Bias and noise", "## Throughput", "## Targets", "FLIP @100%",
              "## FLIP", "| FPPM / CYCLES |", "Reference noise floor"):
        assert s in text, s
    assert ("MET" in text) or ("MISSED" in text)
    with open(out / "summary.json") as f:
        summ = json.load(f)
    _, rows = _rows(out)

    def err(m, t, key="relmse_all"):
        # Mean over the seeds that have a point by time t (report.error_at).
        vals = []
        for seed in SEEDS:
            rs = [x for x in rows if x["method"] == m and int(x["seed"]) == seed]
            vals.append(M.loglog_interp(t, [float(x["seconds"]) for x in rs],
                                        [float(x[key]) for x in rs]))
        return float(np.nanmean(vals))

    for m in ("fppm", "paper", "ppm", "cycles"):
        for f in ("0.5", "1.0"):
            assert summ["methods"][m]["relmse"][f] == pytest.approx(err(m, float(f) * BUDGET),
                                                                   rel=1e-4)
    assert summ["ratios"]["fppm/ppm"]["raw"] == pytest.approx(
        err("fppm", BUDGET) / err("ppm", BUDGET), rel=1e-4)
    # The corrected model against the paper's printed one.
    assert summ["ratios"]["fppm/paper"]["raw"] == pytest.approx(
        err("fppm", BUDGET) / err("paper", BUDGET), rel=1e-4)
    # The reference's variance (_var.exr beside it) gives the floor: the
    # t_light_point.json noise estimate (same formula, same file).
    meta = refs.load_reference("t_light_point")[1]
    assert summ["floor"] == pytest.approx(meta["noise"]["relmse"], rel=1e-3)
    # Excess errors below 3x the floor are flagged, and only those.
    for m in ("fppm", "paper", "ppm", "cycles"):
        ex = err(m, BUDGET) - summ["floor"]
        flagged = f"**Warning**: {m.upper()}'s excess relMSE" in text
        assert flagged == (ex < 3 * summ["floor"]), (m, ex, summ["floor"])
    for f in ("0.5", "1.0"):
        assert summ["methods"]["fppm"]["flip"][f] == pytest.approx(
            err("fppm", float(f) * BUDGET, "flip_all"), rel=1e-4)
    assert summ["flip_ratios"]["fppm/ppm"] == pytest.approx(
        err("fppm", BUDGET, "flip_all") / err("ppm", BUDGET, "flip_all"), rel=1e-4)
    # Bias + noise over 2 seeds reproduce the mean per-seed relMSE of the final images.
    bn = summ["bias_noise"]["fppm"]
    assert bn["bias2"] + bn["noise"] == pytest.approx(bn["relmse_per_seed"], rel=1e-9)


CPU_BUDGET = 1.5


def test_cpu_clock_budget_is_the_rendering_process_cpu(tmp_path):
    """--clock cpu: FPPM's passes and Cycles' ladder stop at the first point whose
    process CPU time reaches the budget (no pass is cut), and the report gives the
    cores each method used and the wall-equivalent ratio against Cycles."""
    out = tmp_path / "cpu"
    r = _run(["converge", refs.scene_path("t_light_point"), "--time-limit", CPU_BUDGET,
              "--clock", "cpu", "--out", out,
              "--reference", os.path.join(refs.REFERENCES_DIR, "t_light_point.exr"),
              "--methods", "fppm,cycles", "--no-cycles-check"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    _, rows = _rows(out)
    with open(out / "summary.json") as f:
        summ = json.load(f)
    assert summ["clock"] == "cpu"
    for m in ("fppm", "cycles"):
        rs = [x for x in rows if x["method"] == m]
        t = [float(x["seconds"]) for x in rs]
        assert t == [float(x["cpu_seconds"]) for x in rs]
        # Budget reached by the last point only: >= budget, < budget + one pass
        # (or ladder point).
        assert len(t) >= 2 and t[-2] < CPU_BUDGET <= t[-1], (m, t)
        cores = float(rs[-1]["cpu_seconds"]) / float(rs[-1]["wall_seconds"])
        assert summ["cores"][m] == pytest.approx(cores, rel=1e-3)
        # At most every CPU thread busy (5% for the clocks' granularity).
        assert 0 < cores <= 1.05 * os.cpu_count()
    ratio = summ["ratios"]["fppm/cycles"]
    v = ratio["excess"] if ratio["excess"] is not None else ratio["raw"]
    assert ratio["wall_equivalent"] == pytest.approx(
        v * summ["cores"]["cycles"] / summ["cores"]["fppm"], rel=1e-9)
    text = (out / "report.md").read_text()
    assert "Clock: **cpu**" in text and "wall-equivalent |" in text


def test_cycles_reference_is_made_then_cached(tmp_path):
    out = tmp_path / "c"
    args = ["converge", refs.scene_path("t_light_point"), "--time-limit", 0.5, "--out", out,
            "--cycles-samples", 8, "--methods", "cycles", "--cycles-max-samples", 4,
            "--no-cycles-check"]
    r1 = _run(args, tmp_path, own_cache=True)
    assert r1.returncode == 0, r1.stderr[-3000:]
    cached = list((tmp_path / "references").glob("*.exr"))
    assert len(cached) == 1
    layers = read_exr(str(cached[0]))
    assert layers["Combined"].shape[:2] == (64, 64)
    assert "Variance" in layers and "DiffDir" in layers and "DiffInd" in layers
    # An 8-spp Cycles reference of the same scene agrees with the committed one
    # to its noise: measured relMSE 2e-3 (8 spp); 1e-2 is 5x that.
    ref, _ = refs.load_reference("t_light_point")
    assert M.relmse(layers["Combined"], ref) < 1e-2
    r2 = _run(args, tmp_path, own_cache=True)
    assert r2.returncode == 0 and "Reference: cached" in r2.stdout
    _, rows = _rows(out)
    assert [int(x["samples"]) for x in rows] == [1, 2, 4]


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_ctrl_c_writes_what_is_done(tmp_path):
    out = tmp_path / "i"
    p = subprocess.Popen(H.fppm_command() + [
        "converge", refs.scene_path("t_light_point"), "--time-limit", "60", "--out", str(out),
        "--reference", os.path.join(refs.REFERENCES_DIR, "t_light_point.exr"),
        "--methods", "fppm,cycles"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=_env(tmp_path), cwd=str(tmp_path))
    stdout, stderr, dt = H.interrupt_after(p, "[fppm seed 0]", settle=1.0)
    assert p.returncode == 130, stderr[-3000:]
    assert dt < 10.0           # the pass in flight, the raw-ray timing and the outputs
    _, rows = _rows(out)
    assert len(rows) >= 2 and {x["method"] for x in rows} == {"fppm"}
    assert "Interrupted" in (out / "report.md").read_text()


def test_usage_errors(tmp_path):
    blend = refs.scene_path("t_light_point")
    r = _run(["converge", blend, "--time-limit", 1, "--out", tmp_path / "o", "--methods", "fppm,mlt"],
             tmp_path)
    assert r.returncode == 2 and "mlt" in r.stderr and "Traceback" not in r.stderr
    r = _run(["converge", tmp_path / "missing.blend", "--time-limit", 1, "--out", tmp_path / "o"],
             tmp_path)
    assert r.returncode == 3


def test_from_csv_rebuilds_the_same_report(tiny, tmp_path):
    import shutil
    r, out = tiny
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    with open(out / "summary.json") as f:
        before = json.load(f)
    r2 = _run(["converge", refs.scene_path("t_light_point"), "--time-limit", BUDGET, "--out", copy,
               "--reference", os.path.join(refs.REFERENCES_DIR, "t_light_point.exr"),
               "--kind", "diffuse", "--from-csv"], tmp_path)
    assert r2.returncode == 0, r2.stderr[-3000:]
    with open(copy / "summary.json") as f:
        after = json.load(f)
    # Same numbers up to the CSV's 6 significant digits (NaN stays NaN: a
    # fraction of the budget before a method's first recorded point).
    for m, d in before["methods"].items():
        for f_, v in d["relmse"].items():
            assert after["methods"][m]["relmse"][f_] == pytest.approx(v, rel=1e-4, nan_ok=True)
    assert after["bias_noise"] == before["bias_noise"]
    text = (copy / "report.md").read_text()
    assert "## Bias and noise" in text and "## Throughput" in text and "rebuilt" in text
    assert "## FLIP" in text and after["cycles_speed"] == before["cycles_speed"]


def test_help_lists_every_method():
    r = H.run_fppm("converge", "--help")
    assert r.returncode == 0
    from tools.converge.runs import METHODS
    for m in METHODS:
        assert f"'{m}'" in " ".join(r.stdout.split()), m


EXAMPLES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        "example_blends")


def test_examples_cycles_bounces_equal_fppm_max_bounces():
    """Every example is saved with FPPM as its engine, and its Cycles light
    paths (kept for the references of `fppm converge`) bounce as deep as FPPM."""
    bpy = pytest.importorskip("bpy")
    H.ensure_registered()
    names = sorted(f[:-6] for f in os.listdir(EXAMPLES) if f.endswith(".blend"))
    assert {"ring_lambert", "ring_principled", "principled_interior"} <= set(names)
    for name in names:
        bpy.ops.wm.open_mainfile(filepath=os.path.join(EXAMPLES, name + ".blend"),
                                 load_ui=False, use_scripts=False)
        sc = bpy.context.scene
        assert sc.render.engine == "FPPM", name
        c, n = sc.cycles, sc.fppm.max_bounces
        assert (c.max_bounces, c.diffuse_bounces, c.glossy_bounces, c.transmission_bounces) \
            == (n, n, n, n), name
        assert (sc.render.resolution_x, sc.render.resolution_y) == (128, 128), name
