"""World shaders baked by Cycles into an environment map (addon/world_bake.py).

- Orientation: an Environment Texture world baked through the child's
  panoramic camera gives back its own image, pixel for pixel, so the baked
  map needs no mapping (measured away from the poles' rows: mean relative
  difference 2e-5; the largest, 1 %, where a jittered sample near a texel's
  edge rounds to its neighbour under Closest interpolation).
- Physics: Blender's default Sky Texture (multiple scattering, sun at 15 deg)
  over a grey floor and a cube, rendered by Cycles and by FPPM.  Region
  means of FPPM against Cycles (1024 spp), measured over two seeds each:
  Path Tracing +0.01 % (sky rows), +0.05 % (floor), +0.01-0.03 % (the cube
  and its shadow), its noise under 0.01 %; Photon Mapping (32 passes of
  50,000 photons) +0.02 %, +0.14 %, -0.4 to +0.6 %, its noise 0.02 %,
  0.01 % and 0.7 % (the cube's band holds its shadow's edge).  Tolerances:
  0.3 % where the noise is under 0.05 % (six times the largest offset
  measured, which is the map's resolution and the disc's measured
  irradiance, not noise), and 3 sigma + 0.3 % in the cube's band for photons.
  Before the bake, FPPM lit this scene by the Background node's grey
  (0.05): the floor read 2 % of Cycles'.
- The sun disc becomes a sun light at the node's elevation (to 0.01 deg)
  and angle, and the child finds none when the sun is below the horizon.
- A failed bake falls back with a note; a cancel kills the child.
"""
from __future__ import annotations

import math
import os
import re
import sys
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import bpy_helpers as H  # noqa: E402

LUM = np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture
def world_bake(monkeypatch):
    from fppm.addon import world_bake as wb
    monkeypatch.setattr(wb, "_cache", {})
    return wb


def _sky_world(sc, rotation_deg=30.0, elevation_deg=15.0):
    w = H.set_world(sc)
    nt = w.node_tree
    bg = next(nd for nd in nt.nodes if nd.type == 'BACKGROUND')
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sun_rotation = math.radians(rotation_deg)
    sky.sun_elevation = math.radians(elevation_deg)
    nt.links.new(sky.outputs["Color"], bg.inputs["Color"])
    return w, sky


def test_an_environment_texture_bakes_to_its_own_pixels(world_bake, tmp_path):
    from fppm.core.io.exr import read_exr, write_exr
    H.empty_scene((8, 8))
    W, Hh = 64, 32
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(Hh) + 0.5) / Hh
    px = np.zeros((Hh, W, 3), np.float32)           # row 0 at the top, as the file
    px[..., 0] = u[None, :]
    px[..., 1] = v[:, None]
    px[..., 2] = 0.1
    px[8:12, 40:44, 2] = 5.0                         # an asymmetric blob
    path = str(tmp_path / "syn.exr")
    write_exr(path, {"Combined": px})
    img = bpy.data.images.load(path)
    img.colorspace_settings.name = 'Linear Rec.709'
    w = H.set_world(bpy.context.scene)
    nt = w.node_tree
    bg = next(nd for nd in nt.nodes if nd.type == 'BACKGROUND')
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = img
    env.interpolation = 'Closest'
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    baked = world_bake.bake_world(w, 1, width=W)
    want = read_exr(path)["Combined"][::-1, :, :3]   # row 0 at the bottom, as the map
    assert baked.image.shape == want.shape and baked.sun is None
    # Rows at the poles left out: there Cycles' Closest lookup of a sample a
    # hair past the pole wraps to the opposite row (2 of their 128 pixels).
    rel = (np.abs(baked.image - want) / (want + 1e-3))[1:-1]
    print(f"mean relative difference {rel.mean():.2e}, largest {rel.max():.3f}")
    assert rel.mean() < 1e-4
    assert np.quantile(rel, 0.99) < 1e-4
    assert rel.max() < 0.02
    # The cache: the same world again is not baked again; a changed value is.
    assert world_bake.bake_world(w, 1, width=W) is baked
    k = world_bake.world_key(w, 1, W)
    bg.inputs["Strength"].default_value = 2.0
    assert world_bake.world_key(w, 1, W) != k
    assert world_bake.world_key(w, 2, W) == world_bake.world_key(w, 1, W)   # not animated


def _sky_scene(engine):
    sc = H.empty_scene((64, 48), engine=engine)
    H.add_camera(sc, location=(0, -6, 1.5), rotation=(math.radians(80), 0, 0), lens=30)
    H.add_plane(sc, size=40.0, material=H.node_material("floor", Color=(0.5, 0.5, 0.5, 1)))
    H.add_cube(sc, location=(0, 0, 0.5), material=H.node_material("cube", Color=(0.8, 0.8, 0.8, 1)))
    _, sky = _sky_world(sc)
    return sc, sky


def _cycles_render(sc, samples):
    """Cycles' image of ``sc`` (mean of RGB): ``samples`` spp, no denoising,
    adaptive sampling, Filter Glossy or clamping, 8 bounces."""
    c = sc.cycles
    c.samples, c.seed = samples, 1
    c.use_denoising = c.use_adaptive_sampling = False
    c.blur_glossy = c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.max_bounces = c.diffuse_bounces = 8
    sc.view_settings.view_transform = 'Standard'
    return H.render_mean_rgb(sc)


REGIONS = {"sky": np.s_[:10], "floor": np.s_[-16:], "cube": np.s_[20:32]}


def test_the_default_sky_renders_as_in_cycles(world_bake, monkeypatch):
    # A 1024-wide map: 0.35 deg a texel against the camera's 0.9 deg pixels.
    monkeypatch.setattr(world_bake, "WIDTH", 1024)
    sc, _ = _sky_scene("CYCLES")
    ref = _cycles_render(sc, 1024)

    sc, sky = _sky_scene("FPPM")
    from fppm.addon.export import export_scene
    lines = []
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lines.append)
    sun = [lt for lt in scene.lights if lt.kind == 'SUN']
    assert len(sun) == 1 and scene.world_map is not None and scene.approximations == ()
    d = sun[0].matrix_world[:3, 2]
    assert math.degrees(math.asin(d[2])) == pytest.approx(15.0, abs=0.01)
    assert sun[0].angle == pytest.approx(sky.sun_size)
    assert any("baked by Cycles into a 1024x512 map and its sun disc" in ln for ln in lines)

    for integrator, passes, photons, tol_cube in (("PATH", 128, 100_000, 0.003),
                                                  ("PHOTON", 32, 50_000, 0.024)):
        H.small_settings(sc, passes=passes, photons=photons, integrator=integrator, seed=1)
        sc.fppm.max_bounces = 8
        img = H.render_mean_rgb(sc)
        for name, rows in REGIONS.items():
            r = img[rows].mean() / ref[rows].mean()
            print(f"{integrator} {name}: FPPM / Cycles {r:.4f}")
            assert r == pytest.approx(1.0, abs=tol_cube if name == "cube" else 0.003), name


def test_no_sun_light_below_the_horizon(world_bake, monkeypatch):
    sc = H.empty_scene((8, 8))
    w, sky = _sky_world(sc, elevation_deg=-10.0)
    baked = world_bake.bake_world(w, 1, width=64)
    assert baked.sun is None
    assert baked.image.shape == (32, 64, 3) and baked.image.max() > 0


def test_a_failed_bake_falls_back_with_a_note(world_bake, monkeypatch):
    monkeypatch.setattr(world_bake, "WIDTH", 16)
    monkeypatch.setattr(world_bake, "_command", lambda spec: [sys.executable, "-c",
                                                              "raise SystemExit(3)"])
    sc = H.simple_scene(res=(16, 16), passes=1)
    _sky_world(sc)
    bg = next(nd for nd in sc.world.node_tree.nodes if nd.type == 'BACKGROUND')
    bg.inputs["Color"].default_value = (0.2, 0.3, 0.4, 1.0)
    from fppm.addon.export import export_scene
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    assert scene.world_map is None and not any(lt.kind == 'SUN' for lt in scene.lights)
    np.testing.assert_allclose(scene.world_color, [0.2, 0.3, 0.4])
    assert len(scene.approximations) == 1
    assert scene.approximations[0].startswith("world: 'Sky Texture' could not be baked by "
                                              "Cycles (Cycles' bake exited with 3")
    assert scene.approximations[0].endswith("the Background colour is used")


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_a_cancel_kills_the_bake(world_bake, monkeypatch):
    from fppm.core.errors import RenderCancelled
    started = []

    def slow(spec):
        started.append(spec)
        return [sys.executable, "-c", "import time; time.sleep(60)"]
    monkeypatch.setattr(world_bake, "_command", slow)
    sc = H.empty_scene((8, 8))
    w, _ = _sky_world(sc)
    t0 = time.monotonic()

    def poll():
        if time.monotonic() - t0 > 0.3:
            raise RenderCancelled("cancelled")
    seen = []
    real = world_bake.subprocess.Popen

    def popen(*a, **k):
        p = real(*a, **k)
        seen.append(p)
        return p
    monkeypatch.setattr(world_bake.subprocess, "Popen", popen)
    with pytest.raises(RenderCancelled):
        world_bake.bake_world(w, 1, width=16, poll=poll)
    assert time.monotonic() - t0 < 5.0
    assert len(seen) == 1 and seen[0].poll() is not None      # killed and reaped
    assert not os.path.exists(os.path.dirname(started[0]))     # its files are gone


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_the_viewport_bakes_in_the_background(world_bake):
    # The viewport exports on Blender's main thread: the first export starts
    # the bake and goes on with the Background colour; when collect() says
    # it has ended, the next export (view_draw's) has the map and the sun.
    from fppm.addon.viewport import export_view
    from fppm.core.scene.model import Camera
    from fppm.addon.export import WORLD_BAKING
    from fppm.core.errors import SceneError
    sc = H.simple_scene(res=(16, 16), passes=1)
    _sky_world(sc)
    world_bake.WIDTH, width = 64, world_bake.WIDTH
    try:
        cam = Camera(resolution=(16, 16))
        lines = []
        t0 = time.monotonic()
        first = export_view(H.evaluated_depsgraph(), cam, lines.append)
        assert time.monotonic() - t0 < 1.0 and world_bake.baking()
        assert first.world_map is None and [lt.kind for lt in first.lights] == ['POINT']
        # Lit by the world alone, the viewport says why it waits.
        sc.objects["Point"].hide_render = True
        with pytest.raises(SceneError, match=re.escape(WORLD_BAKING)):
            export_view(H.evaluated_depsgraph(), cam, lines.append)
        assert any("is being baked by Cycles; black until it is done" in ln
                   for ln in lines)
        deadline = time.monotonic() + 60
        while not world_bake.collect():
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert not world_bake.baking()
        second = export_view(H.evaluated_depsgraph(), cam, lines.append)
        assert second.world_map is not None and second.world_map.image.shape == (32, 64, 3)
        assert [lt.kind for lt in second.lights] == ['SUN']
    finally:
        world_bake.WIDTH = width
        world_bake.cancel_background()


def _light_path_scene(engine):
    """A grey floor under a world that shows the camera a white backdrop
    (Is Camera Ray) and lights the scene with a blue sky gradient."""
    sc = H.empty_scene((48, 32), engine=engine)
    H.add_camera(sc, location=(0, -6, 1.5), rotation=(math.radians(80), 0, 0), lens=30)
    H.add_plane(sc, size=40.0, material=H.node_material("floor", Color=(0.5, 0.5, 0.5, 1)))
    H.add_cube(sc, location=(0, 0, 0.5), material=H.node_material("cube", Color=(0.8, 0.8, 0.8, 1)))
    w = H.set_world(sc)
    nt = w.node_tree
    bg = next(nd for nd in nt.nodes if nd.type == 'BACKGROUND')
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.9, 0.6, 0.3, 1.0)
    ramp.color_ramp.elements[1].color = (0.1, 0.3, 1.5, 1.0)
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(tc.outputs["Generated"], sep.inputs[0])
    nt.links.new(sep.outputs["Z"], ramp.inputs["Fac"])
    white = nt.nodes.new("ShaderNodeBackground")
    white.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    white.inputs["Strength"].default_value = 0.8
    nt.links.new(ramp.outputs["Color"], bg.inputs["Color"])
    mix = nt.nodes.new("ShaderNodeMixShader")
    lp = nt.nodes.new("ShaderNodeLightPath")
    nt.links.new(lp.outputs["Is Camera Ray"], mix.inputs["Fac"])
    nt.links.new(bg.outputs[0], mix.inputs[1])
    nt.links.new(white.outputs[0], mix.inputs[2])
    out = next(nd for nd in nt.nodes if nd.type == 'OUTPUT_WORLD')
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    return sc


def test_is_camera_ray_gives_the_camera_its_own_world(world_bake, monkeypatch):
    # The camera sees a white backdrop (0.8), the floor is lit by a
    # gradient sky.  Region means against Cycles (512 spp).  Measured: Path
    # Tracing sky rows 1.0000, floor 0.9999 (seed to seed 0.03 %); Photon
    # Mapping 1.0000, 0.9958 (seed to seed 0.37 %: the tolerance of 1 % is
    # about 4 sigma of the photons).  Before (one map, as the camera sees
    # it, with a warning) the floor read +28.5 %.
    monkeypatch.setattr(world_bake, "WIDTH", 256)
    sc = _light_path_scene("CYCLES")
    ref = _cycles_render(sc, 512)
    sc = _light_path_scene("FPPM")
    from fppm.addon.export import export_scene
    scene = export_scene(H.evaluated_depsgraph(), log=lambda s: None)
    assert scene.world_camera_map is not None and scene.approximations == ()
    np.testing.assert_allclose(scene.world_camera_map.image[200:, :, :3], 0.8, rtol=1e-4)
    rows = {"sky": np.s_[:6], "floor": np.s_[-10:]}
    assert ref[rows["sky"]].mean() == pytest.approx(0.8, rel=1e-3)
    for integrator, passes in (("PATH", 64), ("PHOTON", 32)):
        H.small_settings(sc, passes=passes, photons=50_000, integrator=integrator, seed=1)
        sc.fppm.max_bounces = 8
        img = H.render_mean_rgb(sc)
        for name, r in rows.items():
            q = img[r].mean() / ref[r].mean()
            print(f"{integrator} {name}: FPPM / Cycles {q:.4f}")
            assert q == pytest.approx(1.0, abs=0.01), (integrator, name)
