"""A soft spot's penumbra against Cycles itself, rendered in the test.

FPPM's photons, next-event estimation and BSDF hits read a soft spot's cone
the way tests/test_combined.py's quadrature does (each disc sample's
direction, Cycles' ``spot_light_sample`` as read from its source); this
test checks that reading against a Cycles render of the same light: a spot
of radius 0.3 m, 1 m above a white Lambert floor, seen from above by an
orthographic camera, direct light only.  The floor's radiance is E / pi, so
pi x the pixels in rings 1.6 cm wide give Cycles' irradiance profile
across the cone's edge (0.684 m), out to the ring beyond it that only the
disc's blur lights.  Tolerance: 4 sigma of the ring's pixel mean (Cycles'
noise, measured from the pixels) plus 0.5 % (the ring's width against the
profile's curvature, and the quadrature's cells).  Measured at 2048 spp:
every ratio within 0.997-1.003.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import bpy_helpers as H  # noqa: E402
from test_combined import SOFT_SPOT, _cycles_soft_spot_field  # noqa: E402

RES, SPP, ORTHO = 128, 512, 2.0


def _cycles_floor():
    """(RES, RES) Cycles' radiance of the floor under the SOFT_SPOT, and the
    exported scene (the add-on's exporter)."""
    from fppm.addon.export import export_scene
    P, r, h, size = SOFT_SPOT
    sc = H.empty_scene((RES, RES), engine="CYCLES")
    sc.cycles.device = "CPU"
    sc.cycles.samples = SPP
    sc.cycles.use_denoising = False
    sc.cycles.max_bounces = 0
    sc.cycles.seed = 1
    sc.view_settings.view_transform = "Standard"
    H.set_world(sc, strength=0.0)
    white = H.node_material("White", "BSDF_DIFFUSE", Color=(1.0, 1.0, 1.0, 1.0))
    H.add_plane(sc, size=6.0, material=white)
    H.add_light(sc, "SPOT", P, (0.0, 0.0, h), shadow_soft_size=r, spot_size=size,
                spot_blend=0.1)
    cam = H.add_camera(sc, location=(0.5, 0.0, 5.0), rotation=(0.0, 0.0, 0.0))
    cam.data.type, cam.data.ortho_scale = "ORTHO", ORTHO  # looks down -Z: x in [-0.5, 1.5]
    scene = export_scene(H.evaluated_depsgraph(), log=lambda s: None)
    img = H.render_mean_rgb(sc)
    return img, scene


def test_soft_spot_penumbra_is_cycles():
    from fppm.core import lights as Lt
    img, scene = _cycles_floor()
    t = Lt.build_light_table(scene)
    assert t.n == 1 and bool(t.soft_spot[0])
    half = ORTHO / 2
    xs = 0.5 - half + (np.arange(RES) + 0.5) * ORTHO / RES
    ys = half - (np.arange(RES) + 0.5) * ORTHO / RES
    X, Y = np.meshgrid(xs, ys)
    rho = np.hypot(X, Y)
    E = math.pi * img
    P, r, h, size = SOFT_SPOT
    edge = h * math.tan(size / 2)                      # the centre's cone edge
    for x in (0.3, 0.6, edge - 0.02, edge, edge + 0.02, edge + 0.06, edge + 0.15):
        m = np.abs(rho - x) < 0.008
        got, sig = E[m].mean(), E[m].std() / math.sqrt(m.sum())
        want = _cycles_soft_spot_field(t, x, 300)
        print(f"rho {x:.3f}: Cycles {got:.4f} +- {sig:.4f}, FPPM's reading {want:.4f}")
        assert abs(got - want) <= 4 * sig + 5e-3 * want
