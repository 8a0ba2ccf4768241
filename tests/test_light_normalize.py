"""A light's 'Normalize' off, as Cycles renders it.

Blender's point, spot, sun and area lights have a Normalize option (on by
default): on, the power is spread over the light's size; off, the light's
radiance no longer divides by it, so it grows with the size.  Measured with
Cycles (this file's scene, irradiance on a floor, off / on): a point or spot
light of radius r > 0 gains 4 pi r^2 (0.12566 at 0.1 m, 1.13097 at 0.3 m,
12.566 at 1 m, soft falloff on or off), of radius 0 a factor 4; a sun of
angle a > 0 gains pi sin^2(a / 2) (0.0078474 at 0.1 rad, 0.19229 at 0.5),
of angle 0 nothing; an area light gains its area (addon/export.py).

Each case renders the floor under the light with Normalize off in Cycles
(256 spp) and in FPPM (Path Tracing, 64 passes).  Measured, two seeds each:
FPPM / Cycles 1.0005 (sun 1.0009-1.0010) in every case, each renderer's
seed-to-seed difference of this mean at most 6e-5; the offset is the same
whatever the factor, so it is not the factor's.  Tolerance 0.3 %: three
times the offset, and a wrong factor is off by far more (the nearest,
1.131 at r = 0.3 m, is 13 %).  Before, FPPM rendered Normalize off as on
(and said so only for a radius > 0; a sun's, not at all).
"""
from __future__ import annotations

import math

import pytest

bpy = pytest.importorskip("bpy")

import bpy_helpers as H  # noqa: E402

CASES = {                       # light kind, radius, angle or size
    "point_r0": ("POINT", 0.0),
    "point_r0.3": ("POINT", 0.3),
    "spot_r0.1": ("SPOT", 0.1),
    "sun_0.5": ("SUN", 0.5),
    "area_0.5": ("AREA", 0.5),
}


def _scene(engine, kind, size):
    sc = H.empty_scene((16, 16), engine=engine)
    cam = H.add_camera(sc, location=(0.3, 0.0, 5.0), rotation=(0.0, 0.0, 0.0))
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = 1.0
    H.add_plane(sc, size=4.0, material=H.node_material("floor", Color=(0.8, 0.8, 0.8, 1.0)))
    lt = H.add_light(sc, kind, energy=100.0 if kind != 'SUN' else 3.0, location=(0.0, 0.0, 1.5))
    ld = lt.data
    if kind in ('POINT', 'SPOT'):
        ld.shadow_soft_size = size
    elif kind == 'SUN':
        ld.angle = size
        lt.rotation_euler = (0.4, 0.0, 0.0)
    else:
        ld.size = size
    if kind == 'SPOT':
        ld.spot_size = math.radians(120.0)
    ld.normalize = False
    return sc


@pytest.mark.parametrize("name", list(CASES))
def test_normalize_off_as_in_cycles(name):
    kind, size = CASES[name]
    sc = _scene("CYCLES", kind, size)
    sc.cycles.samples = 256
    ref = H.render_mean_rgb(sc).mean()
    sc = _scene("FPPM", kind, size)
    H.small_settings(sc, passes=64, integrator="PATH")
    got = H.render_mean_rgb(sc).mean()
    print(f"{name}: FPPM {got:.5f}, Cycles {ref:.5f}, ratio {got / ref:.4f}")
    assert got == pytest.approx(ref, rel=0.003)
