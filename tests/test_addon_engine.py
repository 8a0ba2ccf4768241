"""The FPPM RenderEngine inside bpy: streaming, passes, throttling, cancel, errors."""
import os
import time

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

import fppm.addon.engine as E  # noqa: E402
from fppm.core.io.exr import read_exr  # noqa: E402


def render(sc, sess=None):
    """bpy.ops.render.render followed through a RenderSession; returns the session."""
    sess = sess or E.RenderSession(log=lambda m: None)
    with E.session(sess):
        try:
            bpy.ops.render.render()
        except RuntimeError as ex:      # the engine's self.report({'ERROR'})
            sess.report = str(ex)
    return sess


def render_result(sc, tmp_path, multilayer=False):
    """The Render Result as Blender holds it, saved as float EXR and read back."""
    im = sc.render.image_settings
    if hasattr(im, "media_type"):       # Blender 5: multilayer is a media type
        im.media_type = 'MULTI_LAYER_IMAGE' if multilayer else 'IMAGE'
        im.file_format = 'OPEN_EXR_MULTILAYER' if multilayer else 'OPEN_EXR'
    else:
        im.file_format = 'OPEN_EXR_MULTILAYER' if multilayer else 'OPEN_EXR'
    im.color_depth = '32'
    im.exr_codec = 'ZIP'
    if not multilayer:
        im.color_mode = 'RGBA'
    p = str(tmp_path / ("rr_ml.exr" if multilayer else "rr.exr"))
    bpy.data.images["Render Result"].save_render(filepath=p, scene=sc)
    return read_exr(p)


def test_blender_rows_flips_and_pads():
    img = np.arange(2 * 3 * 2, dtype=np.float32).reshape(2, 3, 2)
    flat = E.blender_rows(img, 4).reshape(2, 3, 4)
    assert np.array_equal(flat[0, :, :2], img[1]) and np.array_equal(flat[1, :, :2], img[0])
    assert np.all(flat[..., 2:] == 0)
    assert np.array_equal(E.blender_rows(img, 1).reshape(2, 3), img[::-1, :, 0])


def test_streamed_image_is_the_renderers_image(tmp_path):
    # What Blender ends up holding must be the last PassResult bit for bit
    # (rows flipped into Blender's bottom-to-top order and back).
    sc = H.simple_scene(res=(24, 16), passes=2, photons=3000, seed=5)
    sess = render(sc)
    assert sess.error is None and sess.result.pass_index == 2
    rr = render_result(sc, tmp_path)["Combined"]
    assert rr.shape == (16, 24, 4)
    assert np.array_equal(rr, sess.result.image)
    # A lit scene: the image is not black (the point light hits the plane).
    assert rr[..., :3].mean() > 1e-3


def test_aov_passes_reach_the_render_result(monkeypatch):
    # Blender 5.2 saves only Combined from a Python engine's Render Result
    # (Cycles' passes too), so the passes are read back right after writing.
    sc = H.simple_scene(res=(16, 16), passes=2, photons=3000)
    sc.fppm.aov_radius = True
    sc.fppm.aov_photon_count = True
    seen = {}
    orig = E.FPPMRenderEngine._write

    def spy(self, rresult, pr, aovs, gain):
        orig(self, rresult, pr, aovs, gain)
        for p in rresult.layers[0].passes:
            buf = np.empty(len(p.rect) * p.channels, np.float32)
            p.rect.foreach_get(buf)
            seen[p.name] = (buf, pr)
    monkeypatch.setattr(E.FPPMRenderEngine, "_write", spy)
    sess = render(sc)
    assert sess.error is None
    assert set(seen) == {"Combined", "FPPM Radius", "FPPM Radius px", "Photon Count"}
    for name in ("FPPM Radius", "FPPM Radius px", "Photon Count"):
        buf, pr = seen[name]
        assert np.array_equal(buf, E.blender_rows(pr.aovs[name], 1)), name
    # PPM's N (N + alpha M per pass, so fractional) is >= 0, and photons were gathered.
    n = sess.result.aovs["Photon Count"]
    assert np.all(n >= 0) and n.max() > 0


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_updates_are_throttled(monkeypatch):
    # Many tiny passes: the image editor is updated at most every 0.25 s
    # (plus the final write), not once per pass.
    sc = H.simple_scene(res=(8, 8), passes=60, photons=200)
    writes = []
    orig = E.FPPMRenderEngine._write
    monkeypatch.setattr(E.FPPMRenderEngine, "_write",
                        lambda self, *a: (writes.append(time.monotonic()), orig(self, *a))[1])
    t0 = time.monotonic()
    sess = render(sc)
    wall = time.monotonic() - t0
    assert sess.error is None and sess.result.pass_index == 60
    assert len(writes) <= wall / E.UPDATE_INTERVAL + 2
    assert len(writes) < 60
    gaps = np.diff(writes[:-1]) if len(writes) > 2 else np.array([1.0])
    assert np.all(gaps >= E.UPDATE_INTERVAL * 0.95)


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_cancel_mid_pass_returns_within_a_second(monkeypatch, tmp_path):
    # ~1 s passes (400k photons); Esc is simulated 0.3 s into pass 2 by making
    # break_requested (the engine's test_break poll) return True from then on.
    sc = H.simple_scene(res=(32, 32), passes=50, photons=400_000, seed=2)
    state = {"cancel_at": None, "first_true": None}

    def on_pass(pr, st):
        if state["cancel_at"] is None:
            state["cancel_at"] = time.monotonic() + 0.3

    def fake_break(self):
        if state["cancel_at"] is not None and time.monotonic() >= state["cancel_at"]:
            if state["first_true"] is None:
                state["first_true"] = time.monotonic()
            return True
        return False

    monkeypatch.setattr(E.FPPMRenderEngine, "break_requested", fake_break)
    sess = E.RenderSession(on_pass=on_pass, log=lambda m: None)
    render(sc, sess)
    t_end = time.monotonic()
    assert sess.error is None and sess.cancelled
    assert state["first_true"] is not None
    assert t_end - state["first_true"] < 1.0
    # The last complete pass is kept (pass 1, or 2 if it finished within the
    # 0.3 s) and is what Blender shows.
    assert 1 <= sess.result.pass_index < 50
    rr = render_result(sc, tmp_path)["Combined"]
    assert np.array_equal(rr, sess.result.image)
    assert rr[..., :3].mean() > 1e-3


def test_scene_errors_are_reported_without_traceback(capfd):
    sc = H.empty_scene()
    H.add_camera(sc)
    H.add_plane(sc)
    sess = render(sc)
    assert str(sess.error) == "The scene has no lights: add a light, an emissive material or a world colour."
    assert "no lights" in sess.report
    err = capfd.readouterr()
    assert "Traceback" not in err.err and "Traceback" not in err.out


def test_invalid_settings_are_reported():
    sc = H.simple_scene()
    sc.fppm.max_passes = 0
    sc.fppm.time_limit = 0.0
    sess = render(sc)
    assert "max_passes" in str(sess.error) and "max_passes" in sess.report


def test_nan_mesh_renders_with_one_warning():
    sc = H.simple_scene(res=(16, 16), passes=1, photons=2000)
    nan = float("nan")
    H.mesh_object(sc, "Broken", [(0, 0, 1), (1, 0, 1), (nan, 1, 1)], [(0, 1, 2)])
    lines = []
    sess = render(sc, E.RenderSession(log=lines.append))
    assert sess.error is None and sess.result.pass_index == 1
    assert [ln for ln in lines if "dropped" in ln] == [
        "Warning: dropped 1 of 15 triangles with NaN/infinite corners or zero area."]


def test_border_render_region(tmp_path):
    sc = H.simple_scene(res=(32, 32), passes=1, photons=2000)
    r = sc.render
    r.use_border, r.use_crop_to_border = True, True
    r.border_min_x, r.border_min_y, r.border_max_x, r.border_max_y = 0.25, 0.5, 0.75, 1.0
    sess = render(sc)
    assert sess.error is None
    assert sess.result.image.shape == (16, 16, 4)
    rr = render_result(sc, tmp_path)["Combined"]
    assert np.array_equal(rr, sess.result.image)


def test_film_exposure_scales_combined(tmp_path):
    sc = H.simple_scene(res=(16, 16), passes=1, photons=2000)
    if not hasattr(sc, "cycles"):
        pytest.skip("Cycles add-on not available")
    sc.cycles.film_exposure = 2.0
    sess = render(sc)
    rr = render_result(sc, tmp_path)["Combined"]
    assert sess.gain == 2.0
    assert np.array_equal(rr[..., :3], sess.result.image[..., :3] * np.float32(2.0))
    assert np.array_equal(rr[..., 3], sess.result.image[..., 3])


# --- kernel warm-up before the first render (core/warmup.py) -----------------

def _fake_warmup(monkeypatch, compile, first=True):
    """Give the engine a fresh Warmup whose compile is ``compile``."""
    from fppm.core.warmup import Warmup
    w = Warmup(compile=compile)
    monkeypatch.setattr(E, "warmup", w)
    monkeypatch.setattr(E, "is_compiled", lambda job=None: not first)
    monkeypatch.setattr(E, "expected_seconds", lambda job=None: 42.0)
    return w


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_compile_runs_before_the_render_clock(monkeypatch):
    # The warm-up (here 1 s) happens before the Renderer exists: it is shown
    # as "compiling" (the same text goes to the status line), and the render's elapsed time (which the time limit
    # counts) does not include it.
    def compile(should_stop):
        time.sleep(1.0)
        return 1.0
    w = _fake_warmup(monkeypatch, compile)
    sc = H.simple_scene(res=(8, 8), passes=1, photons=500)
    lines = []
    t0 = time.monotonic()
    sess = render(sc, E.RenderSession(log=lines.append))
    wall = time.monotonic() - t0
    assert sess.error is None and sess.result.pass_index == 1
    assert w.done and w.error is None
    assert "compiling render kernels (first use, about 42 s)" in lines
    assert wall >= 1.0 and sess.result.elapsed < wall - 0.9


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_esc_while_compiling_cancels_at_once(monkeypatch):
    def compile(should_stop):
        t = time.monotonic()
        while time.monotonic() - t < 10 and not should_stop():
            time.sleep(0.01)
        return 10.0
    w = _fake_warmup(monkeypatch, compile)
    t_esc = time.monotonic() + 0.5
    monkeypatch.setattr(E.FPPMRenderEngine, "break_requested",
                        lambda self: time.monotonic() >= t_esc)
    sc = H.simple_scene(res=(8, 8), passes=1, photons=500)
    sess = render(sc)
    assert time.monotonic() - t_esc < 0.1 + 0.05
    assert sess.cancelled and sess.result is None and sess.error is None
    assert not w.done          # the compile goes on in the background
    w.stop()


def test_failed_warmup_is_reported_and_the_render_goes_on(monkeypatch):
    def compile(should_stop):
        raise RuntimeError("no compiler today")
    _fake_warmup(monkeypatch, compile, first=False)
    sc = H.simple_scene(res=(8, 8), passes=1, photons=500)
    lines = []
    sess = render(sc, E.RenderSession(log=lines.append))
    assert sess.error is None and sess.result.pass_index == 1
    assert ("Warning: compiling the kernels ahead of the render failed "
            "(RuntimeError: no compiler today); rendering anyway") in lines
