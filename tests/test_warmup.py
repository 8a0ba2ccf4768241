"""Kernel cache location and the warm-up (core/_numba_cache.py, core/warmup.py)."""
import os
import shutil
import subprocess
import sys
import time

import pytest


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PY = sys.executable


def _copy_package(dst):
    """The shipped part of the repository as ``dst/fppm`` (what an extension install holds)."""
    pkg = os.path.join(dst, "fppm")
    shutil.copytree(ROOT, pkg, ignore=shutil.ignore_patterns(
        ".venv", ".git", "tests", "bench", "tools", "docs", "example_blends", "__pycache__",
        "*.egg-info", "dist", "out", "wheels"))
    return pkg


def _run(code, env, cwd):
    env = {k: v for k, v in env.items() if k not in ("PYTHONPATH", "FPPM_CACHE_DIR",
                                                     "XDG_CACHE_HOME")} | env.get("_extra", {})
    env.pop("_extra", None)
    return subprocess.run([PY, "-c", code], capture_output=True, text=True, env=env, cwd=cwd,
                          timeout=600)


PROBE = (
    "import json\n"
    "import fppm.core.render\n"
    "from fppm.core.sppm import hashgrid\n"
    "import numpy as np\n"
    "print(json.dumps({'path': hashgrid._slot_starts._cache._cache_path,\n"
    "                  'n': int(hashgrid._slot_starts(np.zeros(3, np.int64), 4).sum())}))\n")


def test_read_only_package_and_unwritable_home_fall_back_to_temp(tmp_path):
    # An installed extension's folder may be read-only and HOME unwritable:
    # importing the renderer must still work, with the kernels cached in the
    # temporary folder, and nothing written into the package.
    pkg = _copy_package(tmp_path / "site")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    for d, _, files in os.walk(pkg):
        for f in files:
            os.chmod(os.path.join(d, f), 0o444)
        os.chmod(d, 0o555)
    try:
        env = dict(os.environ, HOME="/dev/null/home", TMPDIR=str(tmp),
                   PYTHONDONTWRITEBYTECODE="1",
                   _extra={"PYTHONPATH": str(tmp_path / "site")})
        p = _run(PROBE, env, str(tmp_path))
        assert p.returncode == 0, p.stderr[-3000:]
        import json
        out = json.loads(p.stdout.strip().splitlines()[-1])
        assert out["path"].startswith(str(tmp) + os.sep), out
        assert out["path"].endswith(os.path.join("numba", "fppm.core.sppm.hashgrid"))
        assert any(f.endswith(".nbi") for f in os.listdir(out["path"]))
        written = [os.path.join(d, f) for d, _, fs in os.walk(pkg) for f in fs
                   if f.endswith((".nbi", ".nbc"))]
        assert written == []
    finally:
        for d, _, _ in os.walk(pkg):
            os.chmod(d, 0o755)


def test_every_cached_kernel_has_an_index_file_of_its_own():
    # Numba's cache index is keyed by name and line, signature and bytecode,
    # not by the compile flags: a serial njit of a parallel kernel's Python
    # function shared its index file, and the parallel kernel then loaded
    # whichever compiled first (the grid build ran on one thread).
    # core._numba_cache.serial_twin gives the serial copy its own name.
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    import fppm.core as core
    owners = {}
    for m in pkgutil.walk_packages(core.__path__, core.__name__ + "."):
        mod = importlib.import_module(m.name)
        for name, d in vars(mod).items():
            if isinstance(d, CPUDispatcher) and d._cache is not None \
                    and getattr(d._cache, "_cache_file", None) is not None:
                key = (d._cache._cache_path, d._cache._cache_file._index_name)
                owners.setdefault(key, set()).add(id(d))
    shared = {k[1] for k, ids in owners.items() if len(ids) > 1}
    assert len(owners) > 50
    assert not shared, shared
    from fppm.core.sppm import hashgrid as Hg
    assert Hg._active_extent.targetoptions.get("parallel") is True
    assert not Hg._active_extent_serial.targetoptions.get("parallel")


def test_precompile_runs_every_unit_once():
    # tests/precompile.py: each unit in exactly one of the two processes, and
    # all of them in one process, w0 (the threaded paths) first there.
    import precompile as PC
    two = PC.split(2)
    assert len(two) == 2 and sorted(n for g in two for n in g) == sorted(PC.UNITS)
    one = PC.split(1)
    assert len(one) == 1 and sorted(one[0]) == sorted(PC.UNITS) and one[0][0] == "w0"


def test_cache_dir_order(tmp_path, monkeypatch):
    from fppm.core import _numba_cache as C
    monkeypatch.delenv(C.ENV_VAR, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(C, "_chosen_dir", None)
    if sys.platform.startswith("linux"):
        assert C.cache_dir() == str(tmp_path / "xdg" / "fppm")
    C.set_cache_dir(str(tmp_path / "ext"))
    try:
        assert C.cache_dir() == str(tmp_path / "ext")
        monkeypatch.setenv(C.ENV_VAR, str(tmp_path / "env"))
        assert C.cache_dir() == str(tmp_path / "env")
        # An unwritable choice is skipped, never an error.
        monkeypatch.setenv(C.ENV_VAR, "/dev/null/nope")
        assert C.cache_dir() == str(tmp_path / "ext")
    finally:
        C.set_cache_dir(None)


COVERAGE = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import fppm_alias  # noqa
from numba.core.registry import CPUDispatcher
from fppm.core import warmup as W


def signatures():
    out = {}
    for name, m in list(sys.modules.items()):
        if name.startswith("fppm.core"):
            for k, v in vars(m).items():
                if isinstance(v, CPUDispatcher):
                    out[name + "." + k] = len(v.signatures)
    return out


W.compile_kernels()
before = signatures()
import bpy
import fppm.addon as addon
addon.register()
from fppm.addon.export import export_scene
from fppm.addon.properties import settings_from_scene
from fppm.core.render import Renderer
new = {}
# Photon mapping's variants, then the default integrator (COMBINED: camera
# paths, light tracing, merging through the glass sphere; Principled materials
# on the ring's floor) as the files have it.
for name, kw in [("cornell", dict(integrator="PHOTON", aov_radius=True, aov_spectrum=True,
                                  aov_held=True)),
                 ("indirect_room", dict(integrator="PHOTON", frequency_estimator="QUANTILE")),
                 ("glass_sphere", dict(integrator="PHOTON", use_frequency=False,
                                       photons_for_direct=True, fixed_visible_points=True)),
                 ("cornell", {}), ("glass_sphere", {}), ("ring_principled", {}),
                 # an HDRI, Principled, normal-mapped and textured materials
                 ("real_scene", dict(integrator="PHOTON"))]:
    bpy.ops.wm.open_mainfile(filepath=sys.argv[2] + "/" + name + ".blend", load_ui=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = 25
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    st = settings_from_scene(sc).replace(max_passes=1, time_limit=0.0,
                                         photons_per_pass=30000, **kw)
    Renderer(scene, st, log=lambda s: None).run()
after = signatures()
print(json.dumps({k: after[k] - before.get(k, 0) for k in after if after[k] != before.get(k, 0)}))
"""


def test_warmup_compiles_what_the_example_scenes_use():
    # After compile_kernels(), rendering the example scenes (frequency with
    # AOVs, QUANTILE, classic PPM, 30k photons: the gather's parallel path;
    # the default integrator, COMBINED) compiles nothing more: no compile is
    # left for the first pass.
    p = subprocess.run([PY, "-c", COVERAGE, os.path.join(ROOT, "tests"),
                        os.path.join(ROOT, "example_blends")],
                       capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    assert p.stdout.strip().splitlines()[-1] == "{}"


LATE_PASSES = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import fppm_alias  # noqa
import fppm.core.warmup as W
from fppm.core.render import Renderer
from fppm.core.settings import RenderSettings
scene = W.warmup_scene(res=16)
# The defaults' schedule (frequency_start 2, decay 2): frequency photons in
# passes 2, 4, 8; pass 8's 1.6 % are traced again in a batch of their own.
st = RenderSettings(integrator="PHOTON", photons_per_pass=20000, seed=2, time_limit=0.0)
W.run_jobs([W.render_job(scene, st)])
def signatures():
    return {k: len(d.signatures) for k, d in W._dispatchers()}
job = signatures()
r = Renderer(scene, st.replace(max_passes=9), log=lambda m: None)
r.run()
after = signatures()
print(json.dumps({"new": {k: after[k] - job.get(k, 0) for k in after if after[k] != job.get(k, 0)},
                  "job": sorted(k for k, n in job.items() if n),
                  "frequency": bool(r.plan.frequency_photons)}))
"""


def test_a_renders_job_covers_its_later_frequency_passes():
    # A photon render's own warm-up job (two passes, core.warmup.render_job)
    # calls every kernel its passes 1-9 call: the reach map of pass S + 1
    # and the few frequency photons traced again of pass 8 included (before,
    # a cold cache compiled them inside passes 3 and 8: ~0.5 s each).
    p = subprocess.run([PY, "-c", LATE_PASSES, os.path.join(ROOT, "tests")],
                       capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    out = __import__("json").loads(p.stdout.strip().splitlines()[-1])
    assert out["frequency"], out
    assert "fppm.core.frequency.kernels:mark_reach" in out["job"], out["job"]
    assert "fppm.core.sppm.photon_kernels:follow_rows" in out["job"], out["job"]
    assert out["new"] == {}, out["new"]


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_wait_returns_within_a_poll_of_should_stop():
    from fppm.core.warmup import Warmup

    def compile(should_stop):
        while not should_stop():
            time.sleep(0.01)
        return 0.0
    w = Warmup(compile=compile)
    t_stop = time.monotonic() + 0.3
    assert w.wait(should_stop=lambda: time.monotonic() >= t_stop) is False
    assert time.monotonic() - t_stop < 0.1
    assert w.running and not w.done
    w.stop()
    w._thread.join(1.0)
    assert not w.running and not w.done   # stopped, not finished: a later start() begins again


def test_marker_records_a_first_compile(tmp_path, monkeypatch):
    from fppm.core import warmup as W
    monkeypatch.setenv("FPPM_CACHE_DIR", str(tmp_path))
    assert not W.is_compiled() and W.last_compile_seconds() is None
    assert W.expected_seconds() == W.DEFAULT_COMPILE_SECONDS
    w = W.Warmup(compile=lambda should_stop: 12.5)
    assert w.wait() is True
    assert w.done and w.error is None and w.was_cold and w.seconds == 12.5
    assert W.is_compiled()
    assert W.last_compile_seconds() == 12.5 and W.expected_seconds() == 12.5


def test_the_first_use_estimate_follows_the_kind_of_render(tmp_path, monkeypatch):
    # core.warmup.expected_seconds: before any compile here, each kind of
    # render's own assumed seconds (JOB_SECONDS, docs/interactive.md: 75 to
    # 260 s on the project's machine); after one, this machine's measured
    # speed scales the other kinds; a marker of before round 49 (no kind)
    # still gives the median of the others.
    import dataclasses

    from fppm.core import warmup as W
    from fppm.core.scene.model import DIFFUSE, Lobe, Material
    from fppm.core.settings import RenderSettings
    monkeypatch.setenv("FPPM_CACHE_DIR", str(tmp_path))
    room = W.warmup_scene(res=8)                  # a mirror and a glass cube
    diffuse = Material("d", (Lobe(DIFFUSE, (0.5, 0.5, 0.5)),))
    matte = dataclasses.replace(room, materials=[diffuse] * len(room.materials))
    jobs = {kind: W.render_job(scene, RenderSettings(integrator=integrator, **kw))
            for kind, scene, integrator, kw in (
                ("light", room, "LIGHT", {}), ("path", room, "PATH", {}),
                ("combined", matte, "COMBINED", {}), ("combined+photons", room, "COMBINED", {}),
                ("photons", room, "PHOTON", {"use_frequency": False}),
                ("photons+frequency", room, "PHOTON", {}))}
    assert {k: W.job_kind(j) for k, j in jobs.items()} == {k: k for k in jobs}
    assert set(jobs) == set(W.JOB_SECONDS)
    for kind, job in jobs.items():
        assert W.expected_seconds(job) == W.JOB_SECONDS[kind]
    assert W.expected_seconds() == W.DEFAULT_COMPILE_SECONDS
    # this machine compiled a light-tracing job in twice the assumed time
    W._write_marker(W.job_key(jobs["light"]), 2 * W.JOB_SECONDS["light"], True, kind="light")
    assert W.expected_seconds(jobs["light"]) == 2 * W.JOB_SECONDS["light"]
    assert W.expected_seconds(jobs["photons+frequency"]) == \
        pytest.approx(2 * W.JOB_SECONDS["photons+frequency"])
    assert W.expected_seconds() == W.DEFAULT_COMPILE_SECONDS      # every variant: not scaled
    # only markers without a kind: the median of their seconds, as before
    monkeypatch.setenv("FPPM_CACHE_DIR", str(tmp_path / "old"))
    W._write_marker(W.job_key(jobs["light"]), 40.0, True)
    W._write_marker(W.job_key(jobs["path"]), 50.0, True)
    assert W.expected_seconds(jobs["photons"]) == 50.0


def test_failed_compile_is_kept_as_a_message():
    from fppm.core.warmup import Warmup

    def compile(should_stop):
        raise ImportError("embreex is missing")
    w = Warmup(compile=compile)
    assert w.wait() is True
    assert w.error == "ImportError: embreex is missing"


# One small job instead of warmup_jobs(): the mechanism under test (compile in
# a child, load here) is the same for any job list, and the full list costs
# a whole cold compile of every kernel (about 100 s on CI) that the rest of
# the suite pays once anyway.  The child gets the same list.
SMALL_JOBS = ("lambda: [(W.warmup_scene(res=8, glossy=False), S.RenderSettings("
              "integrator='PATH', max_passes=1, camera_samples=1, seed=1))]")

# Script lines: W (a core.warmup module) and the child it starts warm up with
# the jobs of the expression SMALL (W and S, its core.settings, in scope)
# instead of warmup_jobs() (also tests/test_addon_install.py).
USE_JOBS = r"""
W.warmup_jobs = eval(SMALL)
CALL = 'W.child_main('
assert CALL in W._CHILD
W._CHILD = W._CHILD.replace(CALL, "S = importlib.import_module(name + '.core.settings'); "
                            "W.warmup_jobs = " + SMALL + "; W.child_main(")
"""

FIRST_USE = r"""
import json, sys, threading, time
sys.path.insert(0, sys.argv[1])
import fppm_alias  # noqa
import fppm.core.settings as S
import fppm.core.warmup as W
from fppm.core.warmup import warmup
SMALL = sys.argv[2]
""" + USE_JOBS + r"""
# A render's own job, here the very scene and settings of SMALL.
scene, st = eval(SMALL)()[0]
job = W.render_job(scene, st)
ok = []
threading.Thread(target=lambda: ok.append(warmup.wait_for(job, rest=False))).start()
last, gaps = time.perf_counter(), []
while not ok:
    time.sleep(0.001)
    now = time.perf_counter()
    gaps.append(now - last)
    last = now
from numba.core.registry import CPUDispatcher
compiled_here = sorted(f"{n}.{k}" for n, m in list(sys.modules.items()) if n.startswith("fppm.core")
                       for k, v in vars(m).items()
                       if isinstance(v, CPUDispatcher) and v.stats.cache_misses)
# The render itself, three passes: every kernel it calls is already loaded.
from fppm.core.render import Renderer
n0 = W.compiled_count()
Renderer(scene, st.replace(max_passes=3), log=lambda m: None).run()
in_render = W.compiled_count() - n0
print(json.dumps({"ok": ok, "job": warmup.jobs_status()[0], "max_gap": max(gaps),
                  "compiled_here": compiled_here, "compiled_in_render": in_render,
                  "job_compiled": W.is_compiled(job)}))
"""


def test_first_use_compiles_in_a_subprocess_and_keeps_this_process_responsive(tmp_path):
    # Empty cache: a render's own kernels compile in a child process (under
    # this process's module names, into the same cache), this process only
    # loads them: nothing compiles here, neither during the warm-up nor in
    # the render's passes after it (the job covers the render), and a 1 ms
    # sleep loop on the main thread never waits long (no GIL or
    # garbage-collector pauses from the compiler).  Not marked serial: the
    # bound is 5x the longest wait measured with three busy processes on
    # the two cores beside the compiling child (52 ms; docs/architecture.md
    # "The test suite's time, round 49"), and its 70-100 s, mostly the
    # child's compile on one core, overlap the other worker's tests.
    env = dict(os.environ, FPPM_CACHE_DIR=str(tmp_path / "cache"))
    p = subprocess.run([PY, "-c", FIRST_USE, os.path.join(ROOT, "tests"), SMALL_JOBS],
                       capture_output=True,
                       text=True, timeout=1200, cwd=str(tmp_path), env=env)
    assert p.returncode == 0, p.stderr[-3000:]
    out = __import__("json").loads(p.stdout.strip().splitlines()[-1])
    assert out["ok"] == [True] and out["job_compiled"], out
    assert out["job"]["done"] and out["job"]["error"] is None and out["job"]["was_cold"], out
    assert out["compiled_here"] == []
    assert out["compiled_in_render"] == 0
    print(f"the main thread's longest wait: {out['max_gap'] * 1000:.1f} ms")
    assert out["max_gap"] < 0.25, out["max_gap"]
    # the compiling children's folders went with them (the process ended
    # without closing them: weakref.finalize at exit)
    assert [n for n in os.listdir(tmp_path / "cache") if n.startswith("warmup-")] == []


def _child_folder_of(script, tmp_path):
    """Run ``script`` (it starts a compiling child and prints its folder) with
    its own kernel cache; returns (returncode, the child's folder)."""
    env = dict(os.environ, FPPM_CACHE_DIR=str(tmp_path / "cache"))
    p = subprocess.run([PY, "-c", "from fppm.core import warmup as W\n"
                        "c = W._Child()\n"
                        "print(c.folder, flush=True)\n" + script],
                       capture_output=True, text=True, timeout=120, cwd=str(tmp_path), env=env)
    folder = p.stdout.strip().splitlines()[-1] if p.stdout.strip() else ""
    assert os.path.basename(folder).startswith("warmup-"), p.stdout + p.stderr[-2000:]
    return p.returncode, folder


def test_a_compiling_childs_folder_goes_when_its_parent_is_killed(tmp_path):
    # No finalizer runs in a killed process: the child, which notices its
    # parent's end within half a second, removes its own folder.
    _, folder = _child_folder_of("import os, signal\nos.kill(os.getpid(), signal.SIGKILL)\n",
                                 tmp_path)
    t0 = time.monotonic()
    while os.path.exists(folder) and time.monotonic() - t0 < 30:
        time.sleep(0.1)
    assert not os.path.exists(folder)


def test_the_fppm_commands_exit_ends_the_compiling_childs_folder(tmp_path):
    # The console script ends with os._exit (addon/cli.py exit_now), which
    # runs no finalizer; a child that ended idle before it no longer removes
    # its folder: exit_now does.
    rc, folder = _child_folder_of("from fppm.addon import cli\n"
                                  "c.proc.kill()\n"
                                  "c.proc.wait()   # the child ended (idle) before the command did\n"
                                  "cli.exit_now(0)\n", tmp_path)
    assert rc == 0
    assert not os.path.exists(folder)


def test_stale_child_folders_are_swept_and_live_ones_kept(tmp_path):
    from fppm.core import warmup as W
    old, live = tmp_path / "warmup-old", tmp_path / "warmup-live"
    users = tmp_path / "warmup-notes"               # a user's own folder: never touched
    marker = tmp_path / "warmup-x.json"            # not a folder: never touched
    for d in (old, live, users):
        d.mkdir()
        (d / "spec-0.pkl").write_bytes(b"")
    (old / "0.pkl.123.tmp").write_bytes(b"")
    (users / "notes.txt").write_text("mine")
    marker.write_text("{}")
    now = time.time()
    past = now - W.CHILD_FOLDER_STALE_SECONDS - 1
    for p in (old, users, marker):
        os.utime(p, (past, past))
    W._sweep_child_folders(str(tmp_path), now)
    assert sorted(os.listdir(tmp_path)) == ["warmup-live", "warmup-notes", "warmup-x.json"]


def test_without_a_python_executable_the_thread_compiles(monkeypatch, capsys, tmp_path):
    # Never start something that is not Python (an old Blender's
    # sys.executable was Blender itself): compile in this process instead.
    from fppm.core import warmup as W
    calls = []
    monkeypatch.setenv("FPPM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(sys, "executable", "/opt/blender/blender")
    monkeypatch.setattr(W, "compile_kernels", lambda should_stop=None: calls.append(1))
    w = W.Warmup()
    assert w.wait() is True and w.error is None
    assert calls == [1]
    assert "is not a Python interpreter" in capsys.readouterr().out


def test_job_key_follows_the_kinds_not_the_values():
    # A render's job (core.warmup.render_job) is two passes of its own scene
    # and settings; its key (which kernels it needs) ignores what changes no
    # kernel -- the seed, the budget, a colour, an object moved -- and
    # follows what does: the integrator, a lobe kind, the pixel count's
    # power of two.
    import dataclasses

    import numpy as np

    from fppm.core import warmup as W
    from fppm.core.scene.model import DIFFUSE, GLASS, Lobe, Material
    from fppm.core.settings import RenderSettings
    scene = W.warmup_scene(res=8, glossy=False)
    st = RenderSettings(seed=3, max_passes=64, time_limit=30.0)
    job = W.render_job(scene, st)
    assert job[1].max_passes == W.JOB_PASSES and job[1].time_limit == 0.0 and job[1].seed == 3
    key = W.job_key(job)
    moved = dataclasses.replace(scene, tri_p=scene.tri_p + np.float32(0.25))
    green = Material("diffuse", (Lobe(DIFFUSE, (0.1, 0.9, 0.2)),))
    recoloured = dataclasses.replace(scene, materials=[green] + list(scene.materials[1:]))
    assert W.job_key(W.render_job(moved, st.replace(seed=9, time_limit=5.0))) == key
    assert W.job_key(W.render_job(recoloured, st)) == key

    def sized(n):
        cam = dataclasses.replace(scene.camera, resolution=(n, n))
        return dataclasses.replace(scene, camera=cam)
    assert W.job_key(W.render_job(sized(11), st)) == key      # 64 and 121 px: both in [2^6, 2^7)
    huge = sized(256)
    glass_only = dataclasses.replace(scene, materials=[Material("g", (Lobe(GLASS, ior=1.5),))] * 5)
    others = [W.render_job(scene, st.replace(integrator="PHOTON")), W.render_job(huge, st),
              W.render_job(glass_only, st), W.render_job(scene, st, ("Depth",))]
    keys = {W.job_key(j) for j in others}
    assert key not in keys and len(keys) == len(others)


def test_a_renders_job_goes_first_and_one_shot_renders_skip_the_variants(tmp_path, monkeypatch):
    # The order of the compiling child's work (core.warmup.Warmup), with a
    # stand-in child: a render's job before every variant, which a job asked
    # for meanwhile interrupts (the real child is killed there) and which
    # then starts again; a one-shot render (rest=False) asks for no variant.
    from fppm.core import warmup as W
    from fppm.core.errors import RenderCancelled
    from fppm.core.settings import RenderSettings
    monkeypatch.setenv("FPPM_CACHE_DIR", str(tmp_path))
    calls = []

    class Child(W.Warmup):
        def _compile_in_child(self, g, poll=0.01):
            name = "all" if g.jobs is None else g.jobs[0][1].integrator
            calls.append(name)
            while name == "all" and len(calls) == 1:   # the first compile of the variants
                if self._kick.is_set():
                    calls[-1] = "all (interrupted)"
                    raise RenderCancelled("a job first")
                time.sleep(poll)
            return {"seconds": 1.0, "compiled": 1, "kernels": {}, "cpu": 1.0}

    scene = W.warmup_scene(res=8, glossy=False)
    light = W.render_job(scene, RenderSettings(integrator="LIGHT"))
    path = W.render_job(scene, RenderSettings(integrator="PATH"))
    one_shot = Child()
    assert one_shot.wait_for(light, rest=False) and not one_shot.done
    one_shot._thread.join(5.0)
    assert calls == ["LIGHT"] and not one_shot.running
    assert W.is_compiled(light) and W.expected_seconds(light) == 1.0
    calls.clear()
    ui = Child()
    ui.start()
    while not calls:
        time.sleep(0.01)
    assert ui.wait_for(path, rest=True) and ui.wait() and ui.error is None
    assert calls == ["all (interrupted)", "PATH", "all"]


def test_a_photon_job_compiles_the_gather_in_a_second_process(tmp_path, monkeypatch):
    # core.warmup.Warmup._start_gather, with stand-in children (no compile):
    # beside a photon-mapping job on a cold cache a second child takes
    # compile_gather (the job's guessed variant first) and is closed when
    # the job's record comes; not beside a light-only job, nor when the
    # gather's marker or every variant's says the cache holds it.
    import dataclasses

    from fppm.core import warmup as W
    from fppm.core.scene.model import DIFFUSE, Lobe, Material
    from fppm.core.settings import RenderSettings
    monkeypatch.setenv("FPPM_CACHE_DIR", str(tmp_path))
    children = []

    class Proc:
        def poll(self):
            return None

    class Child:
        def __init__(self):
            self.specs, self.closed, self.asked, self.proc = [], False, 0, Proc()
            children.append(self)

        def submit(self, spec):
            self.specs.append(spec)
            return len(self.specs) - 1

        def result(self, i):
            if self.specs[i].get("gather") is not None:
                return None                     # the gather outlasts the job
            self.asked += 1
            return None if self.asked < 3 else {"seconds": 1.0, "compiled": 1,
                                                 "kernels": {}, "cpu": 1.0}

        def close(self):
            self.closed = True

    monkeypatch.setattr(W, "_Child", Child)
    scene = W.warmup_scene(res=8, glossy=False)
    photon = W.render_job(scene, RenderSettings(integrator="PHOTON", photons_per_pass=3000))
    assert W.traces_photons(photon)
    assert W.Warmup().wait_for(photon, rest=False)
    assert len(children) == 2, [c.specs for c in children]
    job, gather = children
    assert job.specs[0]["jobs"] == [photon] and "gather" not in job.specs[0]
    # then the stages the job reaches after its photon trace (compile_late)
    assert gather.specs == [{"jobs": None, "nice": False, "only": True, "merge": False,
                             "gather": W.gather_variant(photon)},
                            {"jobs": None, "nice": False, "late": [photon]}]
    assert gather.closed and not job.closed     # the job's child stays for the next job
    # without frequency photons the job reaches those stages early: the gather alone
    children.clear()
    ppm = W.render_job(scene, photon[1].replace(use_frequency=False))
    assert W.Warmup().wait_for(ppm, rest=False)
    assert [list(s) for s in children[1].specs] == [["jobs", "nice", "gather", "only", "merge"]]
    # a chunk of 3000 photons gathers on one thread, of 200 000 split
    assert W.gather_variant(photon)[0] is False and W.gather_variant(
        (scene, RenderSettings(integrator="PHOTON")))[0] is True

    # Camera or light paths without photons (the demo's COMBINED on a scene
    # without mirror or glass, LIGHT, PATH) gather no photon: the second
    # child renders their late stages alone, until the kind's marker says
    # they are on disk.
    diffuse = Material("d", (Lobe(DIFFUSE, (0.5, 0.5, 0.5)),))
    matte = dataclasses.replace(scene, materials=[diffuse] * len(scene.materials))
    for job, kind in ((W.render_job(matte, RenderSettings()), "combined"),
                      (W.render_job(scene, RenderSettings(integrator="LIGHT")), "light"),
                      (W.render_job(scene, RenderSettings(integrator="PATH")), "path")):
        assert not W.traces_photons(job) and W.job_kind(job) == kind
        children.clear()
        assert W.Warmup().wait_for(job, rest=False)
        assert len(children) == 2, kind
        assert children[1].specs == [{"jobs": None, "nice": False, "late": [job]}]
        marker = W._paths_marker(kind)
        os.makedirs(os.path.dirname(marker), exist_ok=True)
        with open(marker, "w") as f:
            f.write("{}")
        children.clear()
        job = W.render_job(job[0], job[1].replace(seed=7))      # a new key
        assert W.Warmup().wait_for(job, rest=False)
        assert len(children) == 1, kind
        os.remove(marker)
    # COMBINED with a mirror and glass merges photons: a second child, the
    # gather (and the merge's), then its photon pass as photon mapping.
    combined = W.render_job(scene, RenderSettings())
    assert W.traces_photons(combined)
    children.clear()
    assert W.Warmup().wait_for(combined, rest=False)
    assert children[1].specs == [{"jobs": None, "nice": False, "only": True, "merge": True,
                                  "gather": W.gather_variant(combined)},
                                 {"jobs": None, "nice": False, "late": [combined]}]

    # A cache that holds the job's variant (its marker: the gather's process
    # finished it) or every variant starts none either; another variant does.
    os.makedirs(os.path.dirname(W._gather_marker()), exist_ok=True)
    other = W.render_job(scene, RenderSettings(integrator="PHOTON", photons_per_pass=5000,
                                               use_frequency=False))
    for k, (marker, started) in enumerate(((W._gather_marker(W.gather_variant(photon)
                                                             + (False,)), 2),
                                           (W._gather_marker(W.gather_variant(other)
                                                             + (False,)), 1),
                                           (W._gather_marker(), 1))):
        with open(marker, "w") as f:
            f.write("{}")
        children.clear()
        job = W.render_job(scene, other[1].replace(photons_per_pass=5000 + k))   # a new key
        assert W.gather_variant(job) == W.gather_variant(other)
        assert W.Warmup().wait_for(job, rest=False)
        assert len(children) == started, marker
        os.remove(marker)


LATE = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import fppm_alias  # noqa
import fppm.core.settings as S
import fppm.core.warmup as W
job = W.render_job(W.warmup_scene(res=8, glossy=False),
                   S.RenderSettings(integrator=sys.argv[3], photons_per_pass=3000, seed=1))
assert W.job_kind(job) in W.LATE_KINDS
if sys.argv[2] == "late":
    W.compile_late([job])
else:
    W.run_jobs([job])
print(json.dumps({k: [str(t) for t in v] for k, v in W.used_kernels().items()}))
"""


def _late_and_job(integrator):
    """(kernel signatures compile_late calls, those the job calls) for a
    small job of that integrator, each side in a process of its own on the
    suite's kernel cache (what a process calls, compiled or loaded)."""
    used = {}
    for mode in ("late", "job"):
        p = subprocess.run([PY, "-c", LATE, os.path.join(ROOT, "tests"), mode, integrator],
                           capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stderr[-3000:]
        out = __import__("json").loads(p.stdout.strip().splitlines()[-1])
        used[mode] = {(k, t) for k, v in out.items() for t in v}
    return used["late"], used["job"]


def _names(used):
    return {k.rsplit(":", 1)[1] for k, _t in used}


def test_the_late_stages_call_only_kernels_the_photon_job_calls():
    # core.warmup.compile_late (the second compiling process, after the
    # gather) beside photon mapping with frequency photons: every kernel
    # signature it calls is one the job itself calls, so none of its
    # compile is wasted; it calls the stages the job reaches after its
    # photon trace (direct light, camera, radius update, film), and no
    # photon kernel, gather or frequency kernel (what the job compiles first).
    late, job = _late_and_job("PHOTON")
    assert late <= job, sorted(late - job)
    names = _names(late)
    assert {"direct_kernel", "hit_kernel", "_ppm_update_range"} <= names, sorted(names)
    assert not names & {"bounce_kernel", "emit_lights_state", "_count_serial", "_count_parallel"}
    assert not [k for k, _t in late if ".frequency." in k.rsplit(":", 1)[0]
                and not k.endswith(":cut_locality")]


def test_the_late_stages_of_a_combined_job_are_its_photon_pass():
    # Beside Combined merging photons: its photon pass rendered as photon
    # mapping (emission, bounces, spectra, update).  Every signature it
    # calls is the job's but the direct light at the visible points
    # (float32 receivers; the job's direct light reads float64 ones) and
    # the reach map Combined's frequency photons do without.
    late, job = _late_and_job("COMBINED")
    extra = {k for k, _t in late - job}
    assert all(k.rsplit(":", 1)[0].endswith(".direct_kernels") or k.endswith(":mark_reach")
               for k in extra), sorted(extra)
    names = _names(late & job)
    assert {"bounce_kernel", "spectrum_at_hits", "_ppm_update_range"} <= names, sorted(names)
    # the camera and light paths are not rendered
    assert not [k for k, _t in late if ".integrators." in k.rsplit(":", 1)[0]]


@pytest.mark.parametrize("integrator,late_names,first_names", [
    # Light tracing (and Combined without photons whose plan is light
    # tracing alone: the Cornell box's default): the splat of its light
    # vertices, without the fused emission or the bounce kernel.
    ("LIGHT", {"project_kernel", "splat_fast"}, {"emit_lights", "bounce_kernel"}),
    # Path tracing: next-event estimation's MIS weights and the
    # continuation, without the emitters seen or the light sample.
    ("PATH", {"nee_mis_kernel", "continue_kernel"}, {"direct_kernel", "seen_kernel"})])
def test_the_late_stages_of_paths_leave_out_what_the_job_compiles_first(
        integrator, late_names, first_names):
    # Every signature the late stages call is one the job calls; they call
    # the job's last stages and none of those its own process compiles first.
    late, job = _late_and_job(integrator)
    assert late <= job, sorted(late - job)
    names = _names(late)
    assert late_names <= names, sorted(names)
    assert first_names <= _names(job) and not names & first_names, sorted(names)


def test_the_late_stages_deposits_lie_on_the_surfaces_photons_reach():
    # _deposits_on_surfaces: one deposit a photon, at the point its
    # (triangle, u, v) names, never on a mirror or glass (no photon leaves a
    # deposit there); none at all in a scene of delta surfaces alone.
    import dataclasses

    import numpy as np

    from fppm.core import warmup as W
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    scene = W.warmup_scene(res=8, glossy=False)
    st = RenderSettings(integrator="LIGHT", photons_per_pass=1000)
    tracer = Renderer(scene, st, log=lambda _m: None).light_tracer.tracer
    n = 4000
    ph = {"o": np.zeros((n, 3)), "d": np.zeros((n, 3)), "power": np.ones((n, 3))}
    dep = W._deposits_on_surfaces(tracer)(ph, np.random.default_rng(1))
    tri, u, v = dep["bary"][:, 0].astype(np.int64), dep["bary"][:, 1], dep["bary"][:, 2]
    assert dep["p"].shape == (n, 3) and np.all((u >= 0) & (v >= 0) & (u + v <= 1))
    P = tracer.tris.p[tri]
    np.testing.assert_allclose(dep["p"], P[:, 0] + u[:, None] * (P[:, 1] - P[:, 0])
                               + v[:, None] * (P[:, 2] - P[:, 0]), atol=1e-12)
    mat = np.asarray(tracer.tris.mat, np.int64)
    assert tracer.mtab.has_nondelta[mat[tri]].all()
    assert not tracer.mtab.has_nondelta[mat].all()      # the scene has a mirror and glass
    mirror = next(m for m in scene.materials if m.name == "mirror")
    delta = dataclasses.replace(scene, materials=[mirror] * len(scene.materials))
    tracer = Renderer(delta, st, log=lambda _m: None).light_tracer.tracer
    assert W._deposits_on_surfaces(tracer)(ph, np.random.default_rng(1)) is None


def test_the_late_stages_render_a_crop_on_the_renders_own_paths():
    # late_job: at most a LATE_CROP-pixel square inside the render's region
    # (its border), without frequency photons; _split_paths(True, pixels):
    # the threaded path of each stage a render of that many pixels takes.
    import dataclasses

    from fppm.core import warmup as W
    from fppm.core.render import border_rect
    from fppm.core.settings import RenderSettings
    from fppm.core.sppm import film, hashgrid, update, visible_points
    scene = W.warmup_scene(res=8, glossy=False)
    for res, border in (((640, 480), None), ((640, 480), (0.5, 0.25, 0.9, 0.5)),
                        ((30, 20), None), ((640, 480), (0.1, 0.1, 0.13, 0.2))):
        cam = dataclasses.replace(scene.camera, resolution=res, border=border)
        job = W.render_job(dataclasses.replace(scene, camera=cam),
                           RenderSettings(integrator="PHOTON"))
        sc, st, _ = W.late_job(job)
        assert not st.use_frequency and st.replace(use_frequency=True) == job[1]
        combined = W.late_job((job[0], job[1].replace(integrator="COMBINED")))[1]
        assert combined == job[1]         # photon mapping, frequency photons kept
        x0, y0, x1, y1 = border_rect(sc.camera.border, *res)
        X0, Y0, X1, Y1 = border_rect(border or (0, 0, 1, 1), *res)
        assert X0 <= x0 < x1 <= X1 and Y0 <= y0 < y1 <= Y1, (res, border)
        assert x1 - x0 == min(W.LATE_CROP, X1 - X0) and y1 - y0 == min(W.LATE_CROP, Y1 - Y0)
    limits = [(visible_points, "INTERSECT_SPLIT_MIN"), (update, "PARALLEL_MIN"),
              (film, "PARALLEL_MIN"), (hashgrid, "PARALLEL_MIN_VPS")]
    saved = [getattr(m, a) for m, a in limits]
    pixels = 1 << 16
    with W._split_paths(True, pixels=pixels):
        assert [getattr(m, a) for m, a in limits] == [1 if v <= pixels else v for v in saved]
    assert [getattr(m, a) for m, a in limits] == saved
