"""The bad-input table of docs/reliability.md, case by case: every case ends
with its documented exit code and message, never a traceback.

The cases run ``fppm.addon.cli.main`` in this process (the console script is
``sys.exit(main())``; test_cli.py runs it as a real process), which saves a
Blender start per case.
"""
import os

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

from fppm.addon import cli  # noqa: E402
from fppm.addon.export import NO_CAMERA, NO_LIGHTS, NOTHING_VISIBLE  # noqa: E402
from fppm.core.io.exr import read_exr  # noqa: E402

FAST = ["--passes", "2", "--photons", "2000", "-q", "--no-preview"]


@pytest.fixture(scope="module")
def blends(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad_blends")
    out = {}
    H.simple_scene(res=(24, 16), passes=2, photons=2000, seed=1)
    out["simple"] = H.save_blend(d / "simple.blend")
    out["nocam"] = H.save_scene_without(d / "nocam.blend", "camera")
    out["dark"] = H.save_scene_without(d / "dark.blend", "light")
    out["empty"] = H.save_scene_without(d / "empty.blend", "plane")
    # The same plane once with an unsupported node, once with no material.
    for name, mat in (("skin", lambda: H.node_material("Skin", "SUBSURFACE_SCATTERING")),
                      ("nomat", lambda: None)):
        sc = H.empty_scene((16, 12))
        H.add_plane(sc, material=mat())
        H.add_light(sc, "POINT", 200.0, (1.0, -1.0, 3.0))
        H.add_camera(sc)
        H.small_settings(sc, passes=2, photons=3000, seed=4)
        out[name] = H.save_blend(d / f"{name}.blend")
    bad = d / "corrupt.blend"
    bad.write_bytes(b"BLENDER-v405" + bytes(range(256)))
    out["corrupt"] = str(bad)
    out["text"] = str(d / "notes.blend")
    with open(out["text"], "w") as fh:
        fh.write("not a blend file\n")
    out["folder"] = str(d)
    out["file"] = out["text"]
    return out


def run_cli(capsys, *args):
    code = cli.main([str(a) for a in args])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


# (case, argv template, exit code, message in stderr).  {out} is an EXR path
# in an empty folder; the same rows are the table in docs/reliability.md.
CASES = [
    ("no command", [], 2, "the following arguments are required: COMMAND"),
    ("unknown option", ["render", "{simple}", "-o", "{out}", "--bogus"], 2,
     "unrecognized arguments: --bogus"),
    ("no output", ["render", "{simple}"], 2, "the following arguments are required: -o/--output"),
    ("not a number", ["render", "{simple}", "-o", "{out}", "--passes", "x"], 2,
     "argument --passes: invalid int value: 'x'"),
    ("unknown mode", ["render", "{simple}", "-o", "{out}", "--mode", "pt"], 2,
     "argument --mode: invalid choice: 'pt'"),
    ("resolution 0", ["render", "{simple}", "-o", "{out}", "--resolution", "0"], 2,
     "--resolution 0: must be in [1, 1000]."),
    ("resolution 1001", ["render", "{simple}", "-o", "{out}", "--resolution", "1001"], 2,
     "--resolution 1001: must be in [1, 1000]."),
    ("photons 0", ["render", "{simple}", "-o", "{out}", "--photons", "0"], 2,
     "setting 'photons_per_pass' = 0: must be in [1, 100000000]"),
    ("negative passes", ["render", "{simple}", "-o", "{out}", "--passes", "-1"], 2,
     "setting 'max_passes' = -1: must be >= 0 (0 = no limit)"),
    ("no limit at all", ["render", "{simple}", "-o", "{out}", "--passes", "0"], 2,
     "setting 'max_passes' = 0: 0 (unlimited) needs a time_limit > 0"),
    ("negative time limit", ["render", "{simple}", "-o", "{out}", "--time-limit", "-5"], 2,
     "setting 'time_limit' = -5.0: must be >= 0 (0 = no limit)"),
    ("seed out of range", ["render", "{simple}", "-o", "{out}", "--seed", "-1"], 2,
     "setting 'seed' = -1: must be in [0, 2^31)"),
    ("negative checkpoint interval",
     ["render", "{simple}", "-o", "{out}", "--checkpoint", "{ck}", "--checkpoint-every", "-1"], 2,
     "--checkpoint-every -1.0: must be a number of seconds >= 0"),
    ("--resume alone", ["render", "{simple}", "-o", "{out}", "--resume"], 2,
     "--resume needs --checkpoint DIR"),
    ("missing file", ["render", "{missing}", "-o", "{out}"], 3, "does not exist."),
    ("input is a folder", ["render", "{folder}", "-o", "{out}"], 3, "is not a file."),
    ("not a .blend", ["render", "{text}", "-o", "{out}"], 3, "is not a .blend file."),
    ("damaged .blend", ["render", "{corrupt}", "-o", "{out}"], 3, "cannot open"),
    ("no camera", ["render", "{nocam}", "-o", "{out}", *FAST], 4, NO_CAMERA),
    ("zero resolution", ["render", "{simple}", "-o", "{out}", "--resolution", "1", *FAST], 4,
     "The render resolution 0x0 is empty (24x16 at 1%): raise the resolution or its percentage."),
    ("no lights", ["render", "{dark}", "-o", "{out}", *FAST], 4, NO_LIGHTS),
    ("nothing visible", ["render", "{empty}", "-o", "{out}", *FAST], 4, NOTHING_VISIBLE),
    ("output folder missing", ["render", "{simple}", "-o", "{nodir}", *FAST], 5,
     "the folder '{nodir_parent}' does not exist."),
    ("output is a folder", ["render", "{simple}", "-o", "{tmp}", *FAST], 5, "is a folder."),
    ("checkpoint is a file", ["render", "{simple}", "-o", "{out}", "--checkpoint", "{file}"], 5,
     "is not a folder."),
]


@pytest.mark.parametrize("case, args, code, message", CASES, ids=[c[0] for c in CASES])
def test_bad_input(blends, tmp_path, capsys, case, args, code, message):
    outdir = tmp_path / "out"
    outdir.mkdir()
    subst = dict(blends, out=str(outdir / "x.exr"), missing=str(tmp_path / "none.blend"),
                 nodir=str(tmp_path / "no" / "x.exr"), nodir_parent=str(tmp_path / "no"),
                 tmp=str(outdir), ck=str(tmp_path / "ck"))
    got, out, err = run_cli(capsys, *[a.format(**subst) for a in args])
    assert got == code, (out[-2000:], err[-2000:])
    assert message.format(**subst) in err, err[-2000:]
    assert "Traceback" not in err
    assert os.listdir(outdir) == []                      # nothing half-written


def test_unsupported_node_warns_and_renders_diffuse_grey(blends, tmp_path, capsys):
    # The fallback is the exporter's diffuse grey (0.8): the image must be the
    # one of the same plane with no material (also diffuse grey 0.8), bit
    # for bit (same seed, same passes).
    code, out, err = run_cli(capsys, "render", blends["skin"], "-o", tmp_path / "s.exr", "-q",
                             "--no-preview")
    assert code == 0, err[-2000:]
    # One warning line for the material (Blender's own report may echo it
    # as "Warning: Warning: ..." in background mode).
    expected = ("Warning: material 'Skin': unsupported node(s) 'Subsurface Scattering' "
                "replaced by diffuse grey.")
    assert out.splitlines().count(expected) == 1
    assert "Approximated:" in out and "-> diffuse grey" in out
    code, out, err = run_cli(capsys, "render", blends["nomat"], "-o", tmp_path / "g.exr", "-q",
                             "--no-preview")
    assert code == 0, err[-2000:]
    skin = read_exr(str(tmp_path / "s.exr"))["Combined"]
    grey = read_exr(str(tmp_path / "g.exr"))["Combined"]
    assert skin[..., :3].mean() > 1e-3
    assert np.array_equal(skin, grey)
