"""Build the extension zip with Blender's own builder, install it through Blender's
operator into a scratch user folder, render, and compare with the CLI.

The zip built here leaves out the bundled wheels (embreex, OpenEXR, numba,
llvmlite: ~80 MB per platform): the venv running Blender already has those
modules, and the manifest's wheel list is checked separately against the
Makefile's pins.  ``make extension`` builds the real zips with the wheels.
"""
import ast
import glob
import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

from fppm.core.io.exr import read_exr  # noqa: E402
from test_warmup import SMALL_JOBS, USE_JOBS  # noqa: E402

ROOT = H.ROOT
# bpy.__file__ is <site-packages>/bpy/<version>/scripts/modules/bpy/__init__.py.
_SCRIPTS = os.path.dirname(os.path.dirname(os.path.dirname(bpy.__file__)))
BLENDER_EXT = sorted(glob.glob(os.path.join(_SCRIPTS, "addons_core", "bl_pkg", "cli",
                                            "blender_ext.py")))
EXCLUDED_TOP = {"tests", "bench", "tools", "example_blends", "dist", "wheels", "out", ".venv",
                ".git", ".ci", "Makefile", "pyproject.toml", "README.md"}


def ext_cli(*args):
    r = subprocess.run([sys.executable, BLENDER_EXT[0], *args], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return r.stdout


def test_manifest_lists_the_pinned_wheels_for_every_platform():
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        m = tomllib.load(fh)
    assert m["schema_version"] == "1.0.0" and m["id"] == "fppm" and m["type"] == "add-on"
    assert m["blender_version_min"] == "4.2.0" and m["license"] == ["SPDX:GPL-3.0-or-later"]
    assert set(m["platforms"]) == {"linux-x64", "windows-x64", "macos-arm64"}
    with open(os.path.join(ROOT, "Makefile")) as fh:
        mk = fh.read()
    pins = dict(re.findall(r"^(\w+)_VERSION\s*:=\s*(\S+)", mk, re.M))
    wheels = [os.path.basename(w) for w in m["wheels"]]
    assert all(w.startswith("./wheels/") for w in m["wheels"])
    for pkg, key in (("embreex", "EMBREEX"), ("openexr", "OPENEXR"), ("numba", "NUMBA"),
                     ("llvmlite", "LLVMLITE")):
        mine = [w for w in wheels if w.lower().startswith(pkg + "-")]
        assert len(mine) == 3, pkg
        assert all(w.split("-")[1] == pins[key] and "-cp313-cp313-" in w for w in mine), mine
        assert sum("manylinux" in w and "x86_64" in w for w in mine) == 1
        assert sum(w.endswith("win_amd64.whl") for w in mine) == 1
        assert sum("macosx" in w and w.endswith("arm64.whl") for w in mine) == 1
    assert not any(w.startswith("numpy") for w in wheels)   # Blender ships numpy


@pytest.fixture(scope="module")
def test_zip(tmp_path_factory):
    """The extension zip of the current sources, without the wheels."""
    if not BLENDER_EXT:
        pytest.skip("blender_ext.py not found in the bpy wheel")
    d = tmp_path_factory.mktemp("ext")
    src = d / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".venv", ".git", "dist", "wheels", "out", "__pycache__", "*.egg-info", ".pytest_cache",
        ".hypothesis", "*.blend1", "*.exr", "*.png"))
    man = (src / "blender_manifest.toml").read_text()
    man, n = re.subn(r"(?ms)^wheels\s*=\s*\[.*?\]\s*$", "", man)
    assert n == 1
    (src / "blender_manifest.toml").write_text(man)
    out = d / "dist"
    out.mkdir()
    ext_cli("build", "--source-dir", str(src), "--output-dir", str(out))
    zips = sorted(out.glob("*.zip"))
    assert [z.name for z in zips] == ["fppm-0.1.0.zip"]
    ext_cli("validate", str(zips[0]))
    return zips[0]


def test_zip_contains_the_package_and_nothing_else(test_zip):
    import zipfile
    names = zipfile.ZipFile(test_zip).namelist()
    top = {n.split("/")[0] for n in names}
    assert {"__init__.py", "blender_manifest.toml", "addon", "core"} <= top
    assert not (top & EXCLUDED_TOP), top & EXCLUDED_TOP
    assert "addon/engine.py" in names and "core/render.py" in names
    assert not any(n.endswith((".pyc", ".blend")) for n in names)


def imported_modules(name: str, source: str) -> set[str]:
    """Modules imported by the package file ``name`` ("addon/cli.py"), as dotted
    paths from the package root ("tools.converge", "core.render"); absolute
    imports of ``fppm.x`` count as ``x``.  ``from .. import tools`` gives "tools"."""
    pkg = name.split("/")[:-1]           # the module's own package
    out = set()
    for node in ast.walk(ast.parse(source, filename=name)):
        if isinstance(node, ast.Import):
            bases = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[:len(pkg) - (node.level - 1)] if node.level - 1 <= len(pkg) else ["<outside>"]
                base = ".".join(base + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            bases = [base] + [f"{base}.{a.name}" if base else a.name for a in node.names]
        else:
            continue
        for b in bases:
            out.add(b[len("fppm."):] if b.startswith("fppm.") else b)
    return out


def test_import_scan_sees_relative_and_absolute_imports():
    src = ("from ..tools.converge import add_parser\nfrom .. import tools\n"
           "import fppm.tools.cli\nfrom . import engine\n")
    mods = imported_modules("addon/cli.py", src)
    assert {"tools.converge", "tools", "tools.cli", "addon.engine"} <= mods


def test_no_shipped_module_imports_tools(test_zip):
    # tools/ (fppm converge, metrics) is not in the extension: a shipped
    # module importing it would fail inside Blender.
    import zipfile
    z = zipfile.ZipFile(test_zip)
    bad = {}
    for n in z.namelist():
        if n.endswith(".py"):
            mods = imported_modules(n, z.read(n).decode())
            hits = sorted(m for m in mods if m == "tools" or m.startswith("tools."))
            if hits:
                bad[n] = hits
    assert not bad, bad


# The installed copy compiles its kernels again, under its own module names
# (bl_ext.user_default.fppm.core.*: core/_numba_cache.py), ~95 s cold on CI
# for every kernel of the default render and of the warm-up's variants.  It
# renders with integrator PATH (camera paths: the export, the film and the
# engine's streaming are the same for every integrator), and its warm-up
# child (compiling under the dotted bl_ext name) runs the render's own job
# (core.warmup.render_job), or the small PATH job of tests/test_warmup.py
# instead of all of warmup_jobs() if asked for them; every module of the
# installed package is imported, so each integrator's code is still loaded
# under the extension's names.
INTEGRATOR = "PATH"

INSTALL_AND_RENDER = r"""
import importlib, json, os, sys, bpy
zip_path, blend, out, pct, passes, photons, seed, integrator, SMALL = sys.argv[1:]
bpy.ops.extensions.package_install_files(filepath=zip_path, repo='user_default',
                                         enable_on_install=True)
assert "bl_ext.user_default.fppm" in bpy.context.preferences.addons, \
    list(bpy.context.preferences.addons.keys())
mod = sys.modules["bl_ext.user_default.fppm"]
print("INSTALLED_AT", mod.__file__)
W = importlib.import_module("bl_ext.user_default.fppm.core.warmup")
S = importlib.import_module("bl_ext.user_default.fppm.core.settings")
""" + USE_JOBS + r"""
import pkgutil
names = [m.name for m in pkgutil.walk_packages(mod.__path__, mod.__name__ + ".")]
for name in names:
    importlib.import_module(name)
print("IMPORTED", len(names))
bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False, use_scripts=False)
sc = bpy.context.scene
sc.render.engine = 'FPPM'
sc.render.resolution_percentage = int(pct)
s = sc.fppm
s.max_passes, s.photons_per_pass, s.seed = int(passes), int(photons), int(seed)
s.integrator = integrator
bpy.ops.render.render()
im = sc.render.image_settings
if hasattr(im, "media_type"):
    im.media_type = 'IMAGE'
im.file_format, im.color_depth, im.color_mode, im.exr_codec = 'OPEN_EXR', '32', 'RGBA', 'ZIP'
bpy.data.images["Render Result"].save_render(filepath=out, scene=sc)
print("RENDERED", out)
kernels = os.path.join(W._numba_cache.cache_dir(), "numba")
job = W.warmup.jobs_status()[-1]       # the render's own kernels (core/warmup.py)
print("WARMUP", json.dumps({"done": job["done"], "error": job["error"],
                            "cached": sorted(n for n in os.listdir(kernels)
                                             if n.startswith("bl_ext.user_default.fppm.core."))}))
"""


def _scene_blend(tmp_path):
    cornell = os.path.join(ROOT, "example_blends", "cornell.blend")
    if os.path.exists(cornell):
        bpy.ops.wm.open_mainfile(filepath=cornell, load_ui=False, use_scripts=False)
        H.ensure_registered()
        return cornell, bpy.context.scene.render.resolution_x
    H.simple_scene(res=(32, 24))
    return H.save_blend(tmp_path / "scene.blend"), 32


def test_install_and_render_through_blender_equals_cli(test_zip, tmp_path):
    blend, res_x = _scene_blend(tmp_path)
    pct = max(1, min(100, 3200 // res_x))          # at most ~32 px wide
    passes, photons, seed = 2, 5000, 11
    user = tmp_path / "user"
    user.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["BLENDER_USER_RESOURCES"] = str(user)
    script = tmp_path / "install_and_render.py"
    script.write_text(INSTALL_AND_RENDER)
    blender_exr = tmp_path / "blender.exr"
    r = subprocess.run([sys.executable, str(script), str(test_zip), blend, str(blender_exr),
                        str(pct), str(passes), str(photons), str(seed), INTEGRATOR, SMALL_JOBS],
                       capture_output=True, text=True, env=env, cwd=str(tmp_path), timeout=600)
    assert r.returncode == 0 and "RENDERED" in r.stdout, r.stdout[-3000:] + r.stderr[-3000:]
    # The engine that rendered is the installed copy under the scratch user folder.
    installed = r.stdout.split("INSTALLED_AT", 1)[1].split()[0]
    assert installed.startswith(str(user)), installed
    # Its warm-up ran (in a child under the dotted bl_ext name) and cached the
    # kernels under the installed module names.
    warm = json.loads(r.stdout.split("WARMUP", 1)[1].strip().splitlines()[0])
    assert warm["done"] and warm["error"] is None, warm
    assert "bl_ext.user_default.fppm.core.integrators.path_kernels" in warm["cached"], warm
    shipped = [n for n in zipfile.ZipFile(test_zip).namelist() if n.endswith(".py")]
    assert int(r.stdout.split("IMPORTED", 1)[1].split()[0]) == len(shipped) - 1   # less __init__.py
    cli_exr = tmp_path / "cli.exr"
    c = H.run_fppm("render", blend, "-o", cli_exr, "--resolution", pct, "--passes", passes,
                   "--photons", photons, "--seed", seed, "--mode", INTEGRATOR.lower(), "-q",
                   "--no-preview")
    assert c.returncode == 0, c.stderr[-3000:]
    a = read_exr(str(blender_exr))["Combined"]
    b = read_exr(str(cli_exr))["Combined"]
    assert a.shape == b.shape and a[..., :3].mean() > 1e-3
    # Same core, same seed, same export: identical bit for bit.
    assert np.array_equal(a, b)
