"""The ``fppm`` command: outputs, settings from the file and the flags, exit codes, Ctrl-C."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

from fppm.core.io.exr import read_exr, read_exr_metadata  # noqa: E402

FAST = ["--passes", "2", "--photons", "2000", "-q"]


@pytest.fixture(scope="module")
def blends(tmp_path_factory):
    d = tmp_path_factory.mktemp("blends")
    out = {}
    sc = H.simple_scene(res=(24, 16), passes=2, photons=2000, seed=1)
    out["simple"] = H.save_blend(d / "simple.blend")
    s = sc.fppm
    s.photons_per_pass, s.alpha, s.aov_radius, s.max_bounces = 1234, 0.55, True, 5
    out["custom"] = H.save_blend(d / "custom.blend")
    # A file that never had FPPM settings (scene.fppm never touched).
    sc = H.empty_scene((16, 16), engine="CYCLES")
    H.add_plane(sc)
    H.add_light(sc)
    H.add_camera(sc)
    out["plain"] = H.save_blend(d / "plain.blend")
    out["dark"] = H.save_scene_without(d / "dark.blend", "light")
    out["nocam"] = H.save_scene_without(d / "nocam.blend", "camera")
    bad = d / "corrupt.blend"
    bad.write_bytes(b"BLENDER-v405" + os.urandom(256))
    out["corrupt"] = str(bad)
    out["text"] = str(d / "notes.blend")
    with open(out["text"], "w") as fh:
        fh.write("not a blend file\n")
    return out


def settings_of(exr):
    return json.loads(read_exr_metadata(exr)["fppm:settings"])


def test_package_imports_without_the_repository_on_sys_path():
    # The console script runs with only site-packages on sys.path: every
    # module of the package (core included) must import relatively.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run([sys.executable, "-c",
                        "import fppm.addon.cli, fppm.core.render, fppm.tools.cli"],
                       capture_output=True, text=True, env=env, cwd="/", timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]


# addon/cli.py as the extension ships it: `render` alone, tools/ never imported.
ADDON_CLI_ALONE = ("import sys; from fppm.addon import cli; rc = cli.main(sys.argv[1:]); "
                   "assert not [m for m in sys.modules if m.startswith('fppm.tools')]; "
                   "sys.exit(rc)")


def test_addon_cli_renders_alone_without_tools(blends, tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = tmp_path / "alone.exr"
    r = subprocess.run([sys.executable, "-c", ADDON_CLI_ALONE, "render", blends["simple"],
                        "-o", str(out), "--seed", "3", *FAST, "--no-preview"],
                       capture_output=True, text=True, env=env, cwd=str(tmp_path), timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert read_exr(str(out))["Combined"].shape == (16, 24, 4)
    r = subprocess.run([sys.executable, "-c", ADDON_CLI_ALONE, "converge", blends["simple"]],
                       capture_output=True, text=True, env=env, cwd=str(tmp_path), timeout=300)
    assert r.returncode == 2 and "invalid choice: 'converge'" in r.stderr


def test_render_writes_exr_png_and_summary(blends, tmp_path):
    out, tmp = tmp_path / "a.exr", tmp_path.parent / f"{tmp_path.name}-tmp"
    tmp.mkdir()
    r = H.run_fppm("render", blends["simple"], "-o", out, "--passes", "2", "--photons", "2000",
                   "--seed", "3", env_extra={"TMPDIR": str(tmp)})
    assert r.returncode == 0, r.stderr[-3000:]
    # Blender's session folder (<TMPDIR>/blender_<random>) went with the process
    assert [n for n in os.listdir(tmp) if n.startswith("blender_")] == []
    layers = read_exr(str(out))
    assert set(layers) == {"Combined"}
    img = layers["Combined"]
    assert img.shape == (16, 24, 4) and np.all(np.isfinite(img))
    assert img[..., :3].mean() > 1e-3 and np.all(img[..., 3] == 1.0)
    meta = read_exr_metadata(str(out))
    assert meta["fppm:passes"] == "2" and meta["fppm:photons"] == "4000"
    assert meta["fppm:cancelled"] == "false" and settings_of(str(out))["seed"] == 3
    png = tmp_path / "a.png"
    with open(png, "rb") as fh:
        head = fh.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(head[16:20], "big") == 24 and int.from_bytes(head[20:24], "big") == 16
    assert "Done: 24x16 px, Pass 2" in r.stdout and f"Wrote {out}" in r.stdout
    assert "100%" in r.stderr                     # the progress bar reached the end
    assert sorted(os.listdir(tmp_path)) == ["a.exr", "a.png"]   # no temporaries left
    # Same seed, same image, bit for bit.
    out2 = tmp_path / "b.exr"
    r = H.run_fppm("render", blends["simple"], "-o", out2, "--seed", "3", *FAST)
    assert r.returncode == 0, r.stderr[-3000:]
    assert np.array_equal(read_exr(str(out2))["Combined"], img)


def test_settings_come_from_the_file_then_the_flags(blends, tmp_path):
    out = tmp_path / "c.exr"
    r = H.run_fppm("render", blends["custom"], "-o", out, "--passes", "1", "--seed", "9",
                   "--mode", "ppm", "--resolution", "50", "--frame", "3", "-q", "--no-preview")
    assert r.returncode == 0, r.stderr[-3000:]
    st = settings_of(str(out))
    assert (st["photons_per_pass"], st["alpha"], st["max_bounces"]) == (1234, 0.55, 5)  # file
    assert (st["max_passes"], st["seed"], st["use_frequency"]) == (1, 9, False)        # flags
    layers = read_exr(str(out))
    assert set(layers) == {"Combined", "FPPM Radius", "FPPM Radius px"}
    assert layers["Combined"].shape == (8, 12, 4)                                       # 50 %
    assert read_exr_metadata(str(out))["fppm:frame"] == "3"
    assert not (tmp_path / "c.png").exists()


def test_file_without_fppm_settings_uses_defaults(blends, tmp_path):
    out = tmp_path / "d.exr"
    r = H.run_fppm("render", blends["plain"], "-o", out, "--passes", "1", "--photons", "1000",
                   "-q")
    assert r.returncode == 0, r.stderr[-3000:]
    st = settings_of(str(out))
    from fppm.core.settings import RenderSettings
    d = RenderSettings().to_dict()
    d.update(max_passes=1, photons_per_pass=1000)
    assert st == d
    assert st["integrator"] == "COMBINED"          # the default integrator


@pytest.mark.parametrize("args, code, message", [
    ([], 2, "required"),
    (["render", "{simple}", "-o", "{out}", "--photons", "0"], 2, "photons_per_pass"),
    (["render", "{simple}", "-o", "{out}", "--resolution", "0"], 2, "--resolution"),
    (["render", "{simple}", "-o", "{out}", "--passes", "x"], 2, "invalid int"),
    (["render", "{missing}", "-o", "{out}"], 3, "does not exist"),
    (["render", "{text}", "-o", "{out}"], 3, "not a .blend file"),
    (["render", "{corrupt}", "-o", "{out}"], 3, "cannot open"),
    (["render", "{dark}", "-o", "{out}", *FAST], 4,
     "The scene has no lights: add a light, an emissive material or a world colour."),
    (["render", "{nocam}", "-o", "{out}", *FAST], 4, "no camera"),
    (["render", "{simple}", "-o", "{nodir}", *FAST], 5, "does not exist"),
    (["render", "{simple}", "-o", "{tmp}", *FAST], 5, "is a folder"),
])
def test_exit_codes(blends, tmp_path, args, code, message):
    subst = dict(blends, out=str(tmp_path / "x.exr"), missing=str(tmp_path / "none.blend"),
                 nodir=str(tmp_path / "no" / "x.exr"), tmp=str(tmp_path))
    r = H.run_fppm(*[a.format(**subst) for a in args])
    assert r.returncode == code, (r.stdout[-2000:], r.stderr[-2000:])
    assert message in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "x.exr").exists()


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_ctrl_c_writes_the_last_complete_pass(blends, tmp_path):
    out = tmp_path / "i.exr"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    p = subprocess.Popen(H.fppm_command() + ["render", blends["simple"], "-o", str(out),
                                             "--passes", "50", "--photons", "400000"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         cwd=str(tmp_path))
    # Not a terminal: the progress bar prints a line on the first pass.
    stdout, stderr, dt = H.interrupt_after(p, "Pass 1 ", settle=0.2)
    assert p.returncode == 130, stderr[-3000:]
    # Cancelled within a second of the signal (the pass in flight is dropped),
    # plus the time to write the EXR and the PNG.
    assert dt < 3.0
    meta = read_exr_metadata(str(out))
    assert meta["fppm:cancelled"] == "true" and 1 <= int(meta["fppm:passes"]) < 50
    assert read_exr(str(out))["Combined"][..., :3].mean() > 1e-3
    assert (tmp_path / "i.png").exists()
    assert "(cancelled)" in stdout
