"""``fppm render --frames`` / ``--animation``: one image per frame in one
process, Blender's frame-number rule in ``-o``, ``--skip-existing``, Ctrl-C
between and during frames; and Animated Seed (``use_animated_seed``).

The renders run ``fppm.addon.cli.main`` in this process (as
tests/test_bad_input.py does), except Ctrl-C, which needs a real process.
"""
import json
import os
import subprocess

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

from fppm.core.io.exr import read_exr, read_exr_metadata  # noqa: E402
from fppm.core.settings import RenderSettings, frame_seed  # noqa: E402
from test_bad_input import FAST, run_cli as run  # noqa: E402  (cli.main in this process)


@pytest.fixture(scope="module")
def blends(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    out = {}
    sc = H.simple_scene(res=(16, 12), passes=2, photons=2000, seed=1)
    # The light's power rises from frame 1 to frame 5: each frame's image differs.
    light = sc.objects["Point"]
    sc.frame_start, sc.frame_end, sc.frame_step = 2, 6, 2
    for f, w in ((1, 100.0), (5, 500.0)):
        light.data.energy = w
        light.data.keyframe_insert("energy", frame=f)
    sc.frame_set(1)
    out["animated"] = H.save_blend(d / "animated.blend")
    # The light leaves the render from frame 3 on: frame 3 has no light.
    light.hide_render = False
    light.keyframe_insert("hide_render", frame=2)
    light.hide_render = True
    light.keyframe_insert("hide_render", frame=3)
    sc.frame_set(1)
    out["dark_from_3"] = H.save_blend(d / "dark_from_3.blend")
    sc = H.simple_scene(res=(16, 12), passes=2, photons=2000, seed=1)
    out["still"] = H.save_blend(d / "still.blend")
    sc.fppm.use_animated_seed = True
    out["seeded"] = H.save_blend(d / "seeded.blend")
    return out


def combined(path):
    return read_exr(str(path))["Combined"]


def test_frames_write_one_image_each_equal_to_a_single_frame_render(blends, tmp_path, capsys):
    code, out, err = run(capsys, "render", blends["animated"], "-o", tmp_path / "shot_##.exr",
                         "--frames", "1,3..4,3", *FAST)
    assert code == 0, err
    assert sorted(os.listdir(tmp_path)) == ["shot_01.exr", "shot_03.exr", "shot_04.exr"]
    assert "Frame 3 (2 of 3):" in out and "Animation: 3 frames written." in out
    for f in (1, 3, 4):
        assert read_exr_metadata(str(tmp_path / f"shot_{f:02d}.exr"))["fppm:frame"] == str(f)
    # The light's power grows with the frame (keyframes 100 W at 1, 500 W at 5).
    means = [combined(tmp_path / f"shot_{f:02d}.exr")[..., :3].mean() for f in (1, 3, 4)]
    assert means[0] < means[1] < means[2]
    # Frame 3 of the animation is the image of `--frame 3`, bit for bit.
    code, _, err = run(capsys, "render", blends["animated"], "-o", tmp_path / "one.exr",
                       "--frame", "3", *FAST)
    assert code == 0, err
    assert np.array_equal(combined(tmp_path / "one.exr"), combined(tmp_path / "shot_03.exr"))


def test_animation_renders_the_files_range_and_skips_existing(blends, tmp_path, capsys):
    # Frame Start 2, End 6, Step 2; no '#' in -o: four digits before .exr.
    code, out, err = run(capsys, "render", blends["animated"], "-o", tmp_path / "a.exr", "-a",
                         *FAST)
    assert code == 0, err
    assert sorted(os.listdir(tmp_path)) == ["a0002.exr", "a0004.exr", "a0006.exr"]
    before = {n: os.stat(tmp_path / n).st_mtime_ns for n in os.listdir(tmp_path)}
    os.remove(tmp_path / "a0004.exr")
    code, out, err = run(capsys, "render", blends["animated"], "-o", tmp_path / "a.exr", "-a",
                         "--skip-existing", *FAST)
    assert code == 0, err
    assert out.count("exists: left out (--skip-existing)") == 2
    assert "Animation: 1 frame written, 2 left out (already written)." in out
    for n in ("a0002.exr", "a0006.exr"):
        assert os.stat(tmp_path / n).st_mtime_ns == before[n]      # not rendered again
    assert read_exr_metadata(str(tmp_path / "a0004.exr"))["fppm:frame"] == "4"


def test_hash_in_output_names_the_single_frame(blends, tmp_path, capsys):
    code, _, err = run(capsys, "render", blends["animated"], "-o", tmp_path / "f_###.exr",
                       "--frame", "-7", *FAST)
    assert code == 0, err
    assert os.listdir(tmp_path) == ["f_-07.exr"]     # Blender pads the sign with the digits


@pytest.mark.parametrize("args, message", [
    (["--frames", "3..1"], "runs backwards"),
    (["--frames", "1,x"], "'x' is not a frame or a range"),
    (["--frames", "1..2000000"], "outside [-1048574, 1048574]"),
    (["--frames", "1", "--frame", "2"], "not allowed with argument"),
    (["-a", "--frames", "1"], "not allowed with argument"),
    (["--frames", "1..2", "--checkpoint", "{tmp}/ck"], "--checkpoint keeps one frame's render"),
    (["--skip-existing"], "--skip-existing needs --frames or --animation"),
])
def test_frame_usage_errors(blends, tmp_path, capsys, args, message):
    code, _, err = run(capsys, "render", blends["still"], "-o", tmp_path / "x.exr",
                       *[a.format(tmp=tmp_path) for a in args], *FAST)
    assert code == 2 and message in err, err
    assert os.listdir(tmp_path) == []                 # nothing written, no folder made


def test_a_failing_frame_stops_the_animation_and_keeps_the_frames_before(blends, tmp_path,
                                                                        capsys):
    code, out, err = run(capsys, "render", blends["dark_from_3"], "-o", tmp_path / "d_#.exr",
                         "--frames", "1..4", *FAST)
    assert code == 4, err
    assert ("frame 3: The scene has no lights: add a light, an emissive material or a world "
            "colour. The 2 frames written before it are kept.") in err
    assert "Traceback" not in err
    assert sorted(os.listdir(tmp_path)) == ["d_1.exr", "d_2.exr"]


def test_animated_seed_gives_each_frame_its_own_noise(blends, tmp_path, capsys):
    for name in ("still", "seeded"):
        code, _, err = run(capsys, "render", blends[name], "-o", tmp_path / f"{name}_#.exr",
                           "--frames", "1..2", *FAST)
        assert code == 0, err
    # A still scene: without Animated Seed every frame is the same image ...
    assert np.array_equal(combined(tmp_path / "still_1.exr"), combined(tmp_path / "still_2.exr"))
    # ... with it each frame renders with frame_seed(Seed, frame), recorded in the EXR.
    a, b = combined(tmp_path / "seeded_1.exr"), combined(tmp_path / "seeded_2.exr")
    assert not np.array_equal(a, b)
    for f in (1, 2):
        st = json.loads(read_exr_metadata(str(tmp_path / f"seeded_{f}.exr"))["fppm:settings"])
        assert st["seed"] == frame_seed(1, f) and st["use_animated_seed"] is True
    # The same noise level: both are renders of the same frame's light.
    assert abs(a[..., :3].mean() / b[..., :3].mean() - 1) < 0.05
    # The stored Seed is untouched (mixed once per render, in the engine).
    code, _, err = run(capsys, "render", blends["seeded"], "-o", tmp_path / "again_#.exr",
                       "--frames", "2", *FAST)
    assert code == 0 and np.array_equal(combined(tmp_path / "again_2.exr"), b), err


def test_frame_seed_is_a_deterministic_spread_in_range():
    seeds = {frame_seed(s, f) for s in range(4) for f in range(-50, 250)}
    assert len(seeds) == 4 * 300                     # no two (seed, frame) pairs collide here
    assert all(0 <= x < 2**31 for x in seeds)
    assert frame_seed(7, 12) == frame_seed(7, 12)
    st = RenderSettings(seed=5)
    assert st.for_frame(9) is st                      # off: the seed as stored
    on = st.replace(use_animated_seed=True).for_frame(9)
    assert on.seed == frame_seed(5, 9) and on.validate() is on


def test_ctrl_c_during_the_second_frame_keeps_the_first(blends, tmp_path):
    import signal
    import time
    out = tmp_path / "c_#.exr"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    # Two seconds a frame: the signal comes 0.3 s after frame 2's first pass.
    p = subprocess.Popen(H.fppm_command() + ["render", blends["still"], "-o", str(out),
                                             "--frames", "1..3", "--time-limit", "2",
                                             "--no-preview"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         cwd=str(tmp_path))
    try:
        seen = 0        # not a terminal: each frame's progress prints its first pass
        while seen < 2:
            line = p.stderr.readline()
            assert line, "the process ended before the second frame"
            seen += "Pass 1 " in line
        time.sleep(0.3)
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, stderr[-3000:]
    assert "Cancelled at frame 2. The 1 frame written before it is kept." in stdout
    assert read_exr_metadata(str(tmp_path / "c_1.exr"))["fppm:cancelled"] == "false"
    meta = read_exr_metadata(str(tmp_path / "c_2.exr"))      # its last complete pass
    assert meta["fppm:cancelled"] == "true" and int(meta["fppm:passes"]) >= 1
    assert not (tmp_path / "c_3.exr").exists()
