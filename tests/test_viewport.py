"""Rendered viewport session (addon/viewport.py) with the real bpy, no GPU."""
import time

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

import fppm.addon.engine as E  # noqa: E402
from fppm.addon import viewport as V  # noqa: E402
from fppm.addon.export import export_scene  # noqa: E402
from fppm.addon.properties import settings_from_scene  # noqa: E402
from fppm.core.render import Renderer  # noqa: E402
from fppm.core.scene.camera import CameraModel, FilterSampler  # noqa: E402
from fppm.core.settings import ViewportSettings  # noqa: E402
from fppm.core.warmup import warmup  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def kernels():
    assert warmup.wait(), warmup.error


def camera_view(sc, size):
    """The ViewState of looking through the scene camera at ``size`` pixels."""
    dg = H.evaluated_depsgraph()
    cam = sc.camera.evaluated_get(dg)
    P = cam.calc_matrix_camera(dg, x=size[0], y=size[1])
    return V.ViewState.of(cam.matrix_world.inverted(), P, size)


def wait_for(session, passes, timeout=60.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        f = session.frame()
        if f is not None and f.pass_index >= passes:
            return f
        assert session.error is None, session.error
        time.sleep(0.01)
    raise AssertionError(f"no pass {passes} within {timeout} s: {session.status}")


def rays(cam, n=200, seed=0):
    rng = np.random.default_rng(seed)
    W, H = cam.resolution
    px, py = rng.integers(0, W, n).astype(float), rng.integers(0, H, n).astype(float)
    r, _ = CameraModel(cam).generate(px, py, rng.random((n, 2)), rng.random((n, 2)),
                                     FilterSampler(1.5))
    return r


@pytest.mark.parametrize("kind,shift", [("PERSP", (0.0, 0.0)), ("PERSP", (0.2, -0.1)),
                                        ("ORTHO", (0.1, 0.05))])
def test_view_camera_sees_what_the_scene_camera_sees(kind, shift):
    # Blender's projection of a camera object, read back by camera_from_view,
    # gives the exporter's camera rays (to the float32 round-off of Blender's
    # matrices).
    sc = H.simple_scene(res=(40, 30))
    cd = sc.camera.data
    cd.type = kind
    cd.shift_x, cd.shift_y = shift
    cd.clip_start, cd.clip_end = 0.5, 50.0
    ref = export_scene(H.evaluated_depsgraph(), log=lambda m: None).camera
    got = camera_view(sc, (40, 30)).camera()
    a, b = rays(ref), rays(got)
    assert np.allclose(a.o, b.o, atol=1e-5) and np.allclose(a.d, b.d, atol=1e-6)
    assert np.allclose(a.t_max, b.t_max, rtol=1e-5)


def test_session_image_equals_the_final_render():
    # Pass k of the viewport session is pass k of a final render of the same
    # camera, bit for bit (the low-resolution first image comes before it).
    sc = H.simple_scene(res=(24, 16), passes=3, photons=3000, seed=4)
    scene = export_scene(H.evaluated_depsgraph(), log=lambda m: None)
    st = settings_from_scene(sc)
    s = V.ViewportSession()
    s.restart(scene, st, ViewportSettings(viewport_resolution_divider=4, viewport_max_passes=3))
    assert s.join(60)
    f = s.frame()
    assert f.pass_index == 3 and f.image.shape == (16, 24, 4)
    final = Renderer(scene, st, log=lambda m: None).run()
    assert np.array_equal(f.image, final.image)
    # ... and the image F12 streams into Blender (rows in core's order).
    sess = E.RenderSession(log=lambda m: None)
    with E.session(sess):
        bpy.ops.render.render()
    assert np.array_equal(f.image, sess.result.image)


def test_first_image_is_the_low_resolution_pass():
    sc = H.simple_scene(res=(30, 20), passes=2, photons=3000)
    scene = export_scene(H.evaluated_depsgraph(), log=lambda m: None)
    seen = []
    s = V.ViewportSession(on_frame=lambda: seen.append(s.frame()))
    s.restart(scene, settings_from_scene(sc),
              ViewportSettings(viewport_resolution_divider=4, viewport_max_passes=2))
    assert s.join(60)
    assert [f.pass_index for f in seen if f is not None][:3] == [0, 1, 2]
    first = seen[0].image
    assert first.shape == (20, 30, 4)
    # 4 x 4 blocks of equal pixels (an 8 x 5 render enlarged).
    assert np.array_equal(first[:16:4, :28:4], first[3:16:4, 3:28:4])


def test_edits_restart_the_session_and_change_the_image():
    sc = H.simple_scene(res=(32, 24), passes=2, photons=3000)
    vs = ViewportSettings(viewport_resolution_divider=1, viewport_max_passes=2)
    ctl = V.ViewportController()
    view = camera_view(sc, (32, 24))

    def update():
        return ctl.update(H.evaluated_depsgraph(), view, settings_from_scene(sc), vs)

    def image():
        assert ctl.session.join(60)
        return wait_for(ctl.session, 2).image

    assert update()
    img0 = image()
    assert not update()                     # nothing changed (a selection, a redraw)
    cube = bpy.data.objects["Cube"]
    cube.location.x += 0.4                  # transform
    assert update()
    img1 = image()
    assert not np.array_equal(img0, img1)
    mat = bpy.data.materials["Red"]         # material
    mat.node_tree.nodes["Diffuse BSDF"].inputs["Color"].default_value = (0.1, 0.1, 0.8, 1.0)
    assert update()
    img2 = image()
    assert not np.array_equal(img1, img2)
    bpy.data.lights[0].energy *= 3.0        # light
    assert update()
    img3 = image()
    assert img3[..., :3].mean() > 2.0 * img2[..., :3].mean()
    sc.fppm.seed += 1                       # render setting
    assert update()
    image()
    # The view moves (no depsgraph update): draw() restarts with the new camera.
    cam = sc.camera
    cam.location.x += 0.3
    moved = camera_view(sc, (32, 24))
    g = ctl.session._generation
    ctl.draw(moved)
    assert ctl.session._generation == g + 1
    img4 = image()
    assert ctl.draw(moved) is not None and ctl.session._generation == g + 1
    assert not np.array_equal(img3, img4)


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_cancel_and_restart_never_block_and_stop_within_100_ms():
    # restart()/cancel() return at once (they set flags and hand the job to
    # the session's worker); the cancelled job ends within 0.1 s.  Judged on the median of
    # several cancels at random moments: on a shared machine one thread
    # wake-up can come late.  Without the frequency kernel: the occlusion
    # grid's build holds the GIL in kernels that cannot poll (up to 0.6 s on a
    # loaded machine, docs/interactive.md), which is the Renderer's, not the
    # session's.
    sc = H.simple_scene(res=(64, 64), passes=2, photons=20000)
    sc.fppm.use_frequency = False
    scene = export_scene(H.evaluated_depsgraph(), log=lambda m: None)
    s = V.ViewportSession()
    vs = ViewportSettings(viewport_resolution_divider=1, viewport_max_passes=0)
    s.restart(scene, settings_from_scene(sc), vs)
    wait_for(s, 1)
    rng = np.random.default_rng(0)
    stops = []
    for _ in range(7):
        time.sleep(0.02 + 0.1 * rng.random())
        old = s._job
        t0 = time.monotonic()
        s.restart(scene, settings_from_scene(sc), vs)     # cancels the running job
        assert time.monotonic() - t0 < 0.05
        old.finished.wait(2.0)
        stops.append(time.monotonic() - t0)
    assert np.median(stops) < 0.1 and max(stops) < 0.2, stops
    t0 = time.monotonic()
    s.cancel()
    assert time.monotonic() - t0 < 0.01
    assert s.join(2.0) and time.monotonic() - t0 < 0.2
    assert not s.busy


def test_scene_errors_are_shown_not_raised():
    sc = H.empty_scene((16, 16))
    H.add_camera(sc)
    H.add_plane(sc)            # no light
    ctl = V.ViewportController()
    assert not ctl.update(H.evaluated_depsgraph(), camera_view(sc, (16, 16)),
                          settings_from_scene(sc), ViewportSettings())
    assert "no lights" in ctl.session.status
    assert ctl.draw(camera_view(sc, (16, 16))) is None


def test_a_session_nobody_draws_stops(monkeypatch):
    # A viewport that is no longer drawn (closed, shading changed) stops its
    # passes by itself once nobody asked for an image for IDLE_STOP_SECONDS.
    sc = H.simple_scene(res=(32, 32), passes=2, photons=20000)
    scene = export_scene(H.evaluated_depsgraph(), log=lambda m: None)
    s = V.ViewportSession()
    s.restart(scene, settings_from_scene(sc),
              ViewportSettings(viewport_resolution_divider=1, viewport_max_passes=0))
    wait_for(s, 1)
    monkeypatch.setattr(V, "IDLE_STOP_SECONDS", 0.3)
    assert s.join(5.0)
    assert not s.busy
