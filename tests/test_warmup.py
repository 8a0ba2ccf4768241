"""Kernel cache location and the warm-up (core/_numba_cache.py, core/warmup.py)."""
import os
import shutil
import subprocess
import sys

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
