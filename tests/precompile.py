"""Compile the suite's kernels into an empty cache in two processes at once.

On a fresh clone the kernel cache (core/_numba_cache.py) is empty, and a
large part of the suite's time is numba compiling kernels at their first
call, one test after another, on one core of the CI machine's two
(docs/architecture.md "The test suite's time", rounds 15 and 19).
``tests/conftest.py`` calls :func:`precompile` before the first test of a
whole-suite run when this source version has not been compiled into the
cache yet: the units below run in two child processes at once, each writing
its kernels to the shared cache, and the tests then load them from disk.  A
kernel both children reach before the other has saved it compiles in both
(the cost of the split); each saves its index file whole (numba writes a
temporary file and renames it), so the later one wins and the other's entry
is lost: one more compile at that kernel's first call, never an error.

Units: each job of ``core.warmup.warmup_jobs()`` (``w0`` ... ``w4``: the
production kernels of every settings variant; ``w0`` takes the per-pixel
stages' threaded paths, as ``compile_kernels()`` does); ``gather``: the
photon gather as a pass and the merge call it (build, gather, fold:
``core.warmup.compile_gather``, which a render's first use also runs in a
second process beside its job), the largest block of ``w0``'s compile, so
that the second process takes it while the first renders ``w0``; and the
test-only signatures that round 15 found among the largest compiles the
warm-up does not reach, each calling its
test's own helpers on tiny inputs: ``grid`` (the grid build split over
threads, tests/test_compiled_pass_stages.py), ``clip`` (the gather with clip
codes, tests/test_clip.py) and ``principled`` (the Principled BSDF's compiled
pair loops in a render, tests/test_compiled_bsdf.py).

Run by hand: ``python tests/precompile.py [--procs 1|2]`` (prints each
unit's CPU seconds, wall seconds and signatures compiled, per process);
``--run UNIT,...`` runs units in this process.
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import time

TESTS = os.path.dirname(os.path.abspath(__file__))

# The two processes' units, balanced by their CPU when compiled cold
# (docs/architecture.md "The test suite's time, round 19"): the first
# renders the warm-up's photon jobs, the second compiles the gather's
# kernels meanwhile (w0 loads most of them from the cache), then the
# combined integrator's job and the clip test's signatures.
GROUPS = (("w0", "w1", "w2", "w4", "grid", "principled"), ("gather", "w3", "clip"))

# Seconds after which a compiling process is stopped (its kernels then
# compile in the tests, as without the precompile).
TIMEOUT = 1800.0


def _setup():
    if TESTS not in sys.path:
        sys.path.insert(0, TESTS)
    import fppm_alias  # noqa: F401  (core.x is fppm.core.x: one numba cache)


def _unit_warmup(k: int) -> None:
    from fppm.core import warmup as W
    W.run_jobs([W.warmup_jobs()[k]], split_first=(k == 0))


def _unit_grid() -> None:
    import numpy as np

    import test_compiled_pass_stages as T
    from fppm.core.sppm import hashgrid as Hg
    saved = Hg.PARALLEL_MIN_VPS
    Hg.PARALLEL_MIN_VPS = 4096
    try:
        p, R, active = T._vps(5000, 1)
        for layout, log2_table in (("auto", None), ("dense", None), ("hash", 6), ("hash", 9)):
            if log2_table == 9:     # a VP over more than _DEDUP_SCAN slots: the sort path
                R[10] = 40.0 / np.sqrt(R.size)
            for parallel in (True, False):
                Hg.build_grid(p, R, active, layout=layout, log2_table=log2_table,
                              parallel=parallel)
    finally:
        Hg.PARALLEL_MIN_VPS = saved


def _unit_gather() -> None:
    """The gather's kernels as a pass and the merge call them
    (``core.warmup.compile_gather``: a render's first use runs it in a
    second process beside its job too)."""
    from fppm.core import warmup as W
    W.compile_gather()


def _unit_clip() -> None:
    import numpy as np

    import test_clip as T
    from fppm.core.sppm import hashgrid as hg
    ph, _ = T._floor_photons(2000, T.WALL, 3.0, 1)
    pos, ng, R2, const = T._vps()
    clip = T._codes(T._wall_accel(), pos, ng, R2, const)
    T._gathered(ph, pos, ng, R2, const, None)
    T._gathered(ph, pos, ng, R2, const, clip)
    rng = np.random.default_rng(5)
    K, P = 50, 500
    vp_pos = rng.uniform(-1, 1, (K, 3))
    vp_ng = rng.normal(size=(K, 3))
    vp_R2 = rng.uniform(0.05, 0.3, K) ** 2
    const = rng.random(K) < 0.5
    clip = rng.integers(0, 256, (K, 8)).astype(np.uint8).view(np.uint64).reshape(K)
    ph = (rng.uniform(-1, 1, (P, 3)), rng.normal(size=(P, 3)), rng.normal(size=(P, 3)),
          rng.uniform(0, 1, (P, 3)), np.where(rng.random(P) < 0.3, 0.1, np.nan))
    grid = hg.build_grid(vp_pos, np.sqrt(vp_R2), np.ones(K, bool))
    for parallel in (False, True):
        hg.gather(grid, *ph, vp_pos, vp_ng, vp_R2, const, cos_ng=-1.0, parallel=parallel,
                  clip=clip, want_freq_pairs=True)


def _unit_principled() -> None:
    import test_compiled_bsdf as T
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    for frequency in (True, False):
        st = RenderSettings(integrator="PHOTON", max_passes=1, time_limit=0.0,
                            photons_per_pass=2000, seed=5, use_frequency=frequency,
                            frequency_estimator="QUANTILE", aov_spectrum=frequency,
                            aov_radius=True, aov_predicted_radius=frequency)
        Renderer(T._principled_floor(8), st, log=lambda s: None).run()


UNITS = {**{f"w{k}": (lambda k=k: _unit_warmup(k)) for k in range(5)},
         "grid": _unit_grid, "gather": _unit_gather, "clip": _unit_clip, "principled": _unit_principled}


def split(procs: int) -> list:
    """The units of :data:`GROUPS` for ``procs`` processes (1: all in one, in
    the order of the groups; 2: the groups)."""
    if procs == 1:
        return [[n for g in GROUPS for n in g]]
    if procs == 2:
        return [list(g) for g in GROUPS]
    raise ValueError("precompile: 1 or 2 processes")


def run_units(names) -> list:
    """Run the named units in this process; one record per unit."""
    _setup()
    from fppm.core.warmup import compiled_count
    out = []
    for n in names:
        t0, c0, k0 = time.perf_counter(), time.process_time(), compiled_count()
        UNITS[n]()
        out.append({"unit": n, "cpu": time.process_time() - c0,
                    "wall": time.perf_counter() - t0, "compiled": compiled_count() - k0})
    return out


def kernel_signatures() -> dict:
    """{``module:name``: [argument types as text, ...]} of every package
    kernel this process compiled or loaded (``core.warmup.used_kernels``):
    the marker keeps both processes' union, which
    tests/test_kernel_signatures.py reads."""
    from fppm.core.warmup import used_kernels
    return {k: sorted(str(s) for s in v) for k, v in used_kernels().items()}


def marker_path() -> str | None:
    """The cache's record that this source version was precompiled (core's
    sources, numba's version and this file), or None (no writable cache)."""
    _setup()
    from fppm.core import _numba_cache
    from fppm.core.warmup import source_key
    root = _numba_cache.cache_dir()
    if root is None:
        return None
    with open(os.path.abspath(__file__), "rb") as f:
        mine = hashlib.sha256(f.read()).hexdigest()[:8]
    return os.path.join(root, "numba", f"suite-precompiled-{source_key()}-{mine}.json")


def is_precompiled() -> bool:
    p = marker_path()
    return p is None or os.path.exists(p)


def precompile(procs: int = 2, log=print) -> dict:
    """Run every unit in ``procs`` child processes at once and wait for them;
    writes the marker when all succeeded.  Returns {"wall", "cpu" (children's
    user + sys), "groups": [[unit records]], "kernels" (every kernel's
    signatures: :func:`kernel_signatures` of both), "ok"}."""
    _setup()
    from fppm.core import _numba_cache
    env = dict(os.environ)
    root = _numba_cache.cache_dir()
    if root is not None:
        env[_numba_cache.ENV_VAR] = root
    groups = split(procs)
    t0 = time.perf_counter()
    r0 = os.times()
    kids = [subprocess.Popen([sys.executable, os.path.abspath(__file__), "--run", ",".join(g)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
            for g in groups]
    outs = []
    for k in kids:
        try:
            outs.append(k.communicate(timeout=max(1.0, TIMEOUT - (time.perf_counter() - t0))))
        except subprocess.TimeoutExpired:
            k.kill()
            outs.append(k.communicate())
    r1 = os.times()
    res = {"wall": time.perf_counter() - t0,
           "cpu": (r1.children_user - r0.children_user) + (r1.children_system - r0.children_system),
           "groups": [], "kernels": {}, "ok": True}
    for k, (out, err) in zip(kids, outs):
        if k.returncode != 0:
            res["ok"] = False
            log(f"precompile: a compiling process failed ({k.returncode}): "
                f"{err.strip().splitlines()[-1] if err.strip() else 'no message'}")
            res["groups"].append([])
        else:
            got = json.loads(out.strip().splitlines()[-1])
            res["groups"].append(got["units"])
            for name, sigs in got["kernels"].items():
                res["kernels"][name] = sorted(set(res["kernels"].get(name, [])) | set(sigs))
    p = marker_path()
    if res["ok"] and p is not None:
        os.makedirs(os.path.dirname(p), exist_ok=True)
        with open(p, "w") as f:
            json.dump(res, f)
    return res


def main(argv) -> None:
    if argv[:1] == ["--run"]:
        units = run_units(argv[1].split(","))
        print(json.dumps({"units": units, "kernels": kernel_signatures()}))
        return
    procs = int(argv[argv.index("--procs") + 1]) if "--procs" in argv else 2
    res = precompile(procs)
    for g in res["groups"]:
        print(" ".join(f"{r['unit']}:{r['cpu']:.1f}s/{r['wall']:.1f}s/{r['compiled']}" for r in g))
    print(f"procs {procs}: wall {res['wall']:.1f} s, children's CPU {res['cpu']:.1f} s, "
          f"ok {res['ok']}")


if __name__ == "__main__":
    main(sys.argv[1:])
