"""An area light's spread, as Cycles renders it.

Blender's area lights have a Spread (Cycles' ``area_light_spread_attenuation``,
a soft box: the radiance leaving at theta to the normal is multiplied by
max((tan a - tan theta) / (tan a - a), 0), a = spread / 2, which keeps the
light's flux; ``core.lights.table.spread_atten``).  A 0.6-m square with a
spread of 60 deg hangs 1 m over a white Lambert floor, facing it: its light
falls off where the slats cut it, from about 0.6 m out to 0.9 m.  The
irradiance E(x) on the floor along a line through its centre is:

- integrated directly (a 200 x 200 midpoint grid over the square of
  L A(theta) cos_l cos_p / d^2);
- rendered by Cycles itself (orthographic camera from above, direct light
  only, a box pixel filter: pi x the floor's pixels in bands 2 cm wide,
  against the integral over the same pixels);
- estimated by FPPM's next-event estimation (numpy and compiled) and by its
  photons (their first hits on the floor, in the same bands).

Tolerances: 4 sigma of each estimate's own noise plus 0.5 % of the
largest value (the integral's grid; 1 % for the photons, whose 4-cm bands
are compared with the integral at their centres).  Measured: Cycles within
0.1 % of the integral in every band.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from analytic_scenes import lambert, look_down_ortho, quad, translate
from core import lights as Lt
from core.scene.model import Light, make_scene

P_W, SIZE, H, SPREAD = 60.0, 0.6, 1.0, math.radians(60.0)
XS = (0.0, 0.3, 0.5, 0.6, 0.7, 0.8, 0.9, 1.1)


def _scene():
    light = Light("box", "AREA", (P_W,) * 3, translate(0, 0, H), shape="SQUARE", size=SIZE,
                  spread=SPREAD)
    return make_scene(quad((0, 0, 0), (4, 0, 0), (0, 4, 0)), [lambert("floor", 1.0)], [light],
                      look_down_ortho(3.0, 2.0, 4))


def _integral(t, x, n=200):
    """E at (x, 0, 0): the square's radiance times the spread factor, over a
    midpoint grid of n x n cells."""
    g = (np.arange(n) + 0.5) / n * SIZE - SIZE / 2
    qx, qy = np.meshgrid(g, g)
    v = np.stack([x - qx.ravel(), -qy.ravel(), np.full(qx.size, -H)], axis=1)   # light -> p
    d2 = np.sum(v * v, axis=1)
    cos = H / np.sqrt(d2)                          # at the light (facing -z) and at the floor
    f = Lt.spread_atten(t, np.zeros(d2.size, int), cos)
    L = float(t.radiance[0, 0])
    return float(np.sum(L * f * cos * cos / d2) * (SIZE / n) ** 2)


def test_spread_profile_of_every_estimator():
    t = Lt.build_light_table(_scene())
    ref = np.array([_integral(t, x) for x in XS])
    assert ref[0] > 0 and ref[-1] == 0.0 and ref[4] < 0.6 * ref[0]
    from test_combined import _nee_irradiance
    for compiled in (False, True):
        for x, r_ in zip(XS, ref):
            e = _nee_irradiance(t, np.array([x, 0.0, 0.0]), 200_000, compiled, 3)
            m, s = e.mean(), e.std() / math.sqrt(e.size)
            assert abs(m - r_) <= 4 * s + 5e-3 * ref[0], ("NEE", compiled, x, m, s, r_)
    # Photons: their first hits on the floor z = 0 (every photon leaves downwards).
    n, batches = 1_000_000, 4
    rows = []
    for b in range(batches):
        ph = Lt.sample_photons(t, n, np.random.default_rng([9, b]))
        tt = ph["o"][:, 2] / -ph["d"][:, 2]
        p = ph["o"] + tt[:, None] * ph["d"]
        band = np.abs(p[:, 1]) < 0.02
        e = []
        for x in XS:
            m = band & (np.abs(p[:, 0] - x) < 0.02)
            e.append(ph["power"][m, 0].sum() / (n * 0.04 * 0.04))
        rows.append(e)
    rows = np.array(rows)
    est, sig = rows.mean(0), rows.std(0, ddof=1) / math.sqrt(batches)
    for x, e, s, r_ in zip(XS, est, sig, ref):
        print(f"x {x:.2f}: integral {r_:.4f}, photons {e:.4f} +- {s:.4f}")
        assert abs(e - r_) <= 4 * s + 1e-2 * ref[0], ("photons", x, e, s, r_)


def test_spread_profile_is_cycles():
    """Cycles, 512 spp, a box pixel filter 1 px wide (0.47 cm on the floor),
    the row through the light's centre (8 pixel rows, |y| < 1.9 cm): in each
    band of 4 pixels around x (both sides of the centre), pi x the pixels'
    mean against the integral averaged over the same pixels' centres."""
    pytest.importorskip("bpy")
    import bpy_helpers as Hb
    res, ortho = (512, 8), 2.4
    sc = Hb.empty_scene(res, engine="CYCLES")
    sc.cycles.device = "CPU"
    sc.cycles.samples = 512
    sc.cycles.use_denoising = False
    sc.cycles.max_bounces = 0
    sc.cycles.seed = 1
    sc.cycles.pixel_filter_type = "BOX"
    sc.cycles.filter_width = 1.0
    sc.view_settings.view_transform = "Standard"
    Hb.set_world(sc, strength=0.0)
    Hb.add_plane(sc, size=6.0, material=Hb.node_material("White", "BSDF_DIFFUSE",
                                                         Color=(1.0, 1.0, 1.0, 1.0)))
    Hb.add_light(sc, "AREA", P_W, (0.0, 0.0, H), shape="SQUARE", size=SIZE, spread=SPREAD)
    cam = Hb.add_camera(sc, location=(0.0, 0.0, 3.0), rotation=(0.0, 0.0, 0.0))
    cam.data.type, cam.data.ortho_scale = "ORTHO", ortho
    E = math.pi * Hb.render_mean_rgb(sc)
    t = Lt.build_light_table(_scene())
    xs = -ortho / 2 + (np.arange(res[0]) + 0.5) * ortho / res[0]
    top = _integral(t, 0.0)
    for x in XS:
        m = np.abs(np.abs(xs) - x) < 0.01              # both sides of the centre
        v = E[:, m].ravel()
        got, sig = v.mean(), v.std() / math.sqrt(v.size)
        want = float(np.mean([_integral(t, abs(xp)) for xp in xs[m]]))
        print(f"x {x:.2f}: Cycles {got:.4f} +- {sig:.4f}, integral {want:.4f}")
        assert abs(got - want) <= 4 * sig + 5e-3 * top, (x, got, sig, want)


@pytest.mark.parametrize("integrator", ["PATH", "LIGHT", "COMBINED"])
def test_the_soft_box_seen_by_the_camera(integrator):
    """The soft box seen from 20 deg off its axis (an orthographic camera
    below it, the light visible to the camera): its pixels read L times the
    spread factor towards the camera (3.97 L here), whichever integrator
    draws them: path tracing's rays that hit it, and light tracing's splat
    of its emission points (light_tracer._emission_vertices: the factor
    towards the camera on the light's power a sample, not the factor of
    each photon's own direction, which gave L alone).  Within 1 % (the
    light tracers' noise at 10 passes is about 0.3 %)."""
    from core.render import Renderer
    from core.scene.model import Camera
    from core.settings import RenderSettings
    ang = math.radians(20.0)
    c, s = math.cos(ang), math.sin(ang)
    light = Light("box", "AREA", (30.0,) * 3, translate(0, 0, 1.0), shape="SQUARE", size=1.0,
                  spread=SPREAD, visible_camera=True)
    M = np.eye(4)
    M[:3, :3] = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ np.diag([1, -1, -1])
    M[:3, 3] = (-0.8 * s, 0, 1.0 - 0.8 * c)                 # looks up at the box, 20 deg off
    cam = Camera(kind="ORTHO", matrix_world=M, ortho_scale=0.5, resolution=(8, 8),
                 clip_start=0.01, clip_end=100.0)
    sc = make_scene(quad((0, 0, -3), (4, 0, 0), (0, 4, 0)), [lambert("floor", 0.0)], [light], cam)
    t = Lt.build_light_table(sc)
    cos_cam = float(M[:3, 2] @ t.dir[0])                   # towards the camera, to the normal
    want = float(t.radiance[0, 0] * Lt.spread_atten(t, np.zeros(1, int), np.array([cos_cam]))[0])
    assert want > 3.5 * float(t.radiance[0, 0])
    st = RenderSettings(integrator=integrator, max_passes=10, photons_per_pass=200_000, seed=1,
                        camera_samples=4)
    r = Renderer(sc, st, log=lambda s_: None)
    for _ in range(10):
        img = np.asarray(r.step().image[..., :3], np.float64).mean(-1)
    assert img[2:6, 2:6].mean() == pytest.approx(want, rel=0.01)
