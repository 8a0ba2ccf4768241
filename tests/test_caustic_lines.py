"""Caustic lines: the frequency prediction is small along the
caustic of a curved mirror under a 1 m light (docs/frequency.md "Curvature of
a mesh").

The curvature step of a frequency photon reads the mirror's curvature per
triangle.  The mean of the edges' normal curvatures gave 0.34/R on the ring
of example_blends/ring_lambert.blend (tall thin triangles of a cylinder of
radius R = 0.5 m): the predicted focus moved from 0.28 m to about 1 m off the
mirror and the predicted radius on the caustic was 3.6x the PPM radius.  The
principal curvature (core.frequency.curvature) puts it at 0.5x.
"""
import os

import numpy as np
import pytest

from core.frequency import spectrum as F
from core.frequency.curvature import principal_curvature, principal_frame, scene_curvature

BLENDS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                      "example_blends")
RING = os.path.join(BLENDS, "ring_lambert.blend")


def _cylinder(R, height, segments, a0=-np.pi / 2, a1=np.pi / 2, inward=False):
    """Triangles (T, 3, 3) and corner normals of a cylinder section split
    like ring_lambert's quads (j, j+1, top j+1) and (j, top j+1, top j)."""
    ph = np.linspace(a0, a1, segments + 1)
    ring = np.c_[R * np.cos(ph), R * np.sin(ph)]
    P, N = [], []
    s = -1.0 if inward else 1.0
    for j in range(segments):
        b0, b1 = np.r_[ring[j], 0.0], np.r_[ring[j + 1], 0.0]
        t0, t1 = np.r_[ring[j], height], np.r_[ring[j + 1], height]
        n0, n1 = s * np.r_[ring[j] / R, 0.0], s * np.r_[ring[j + 1] / R, 0.0]
        P += [[b0, b1, t1], [b0, t1, t0]]
        N += [[n0, n1, n1], [n0, n1, n0]]
    return np.array(P), np.array(N)


def _sphere_patch(R, n=6):
    """Triangles and exact normals of a small patch of a sphere of radius R."""
    u = np.linspace(-0.3, 0.3, n)
    V = np.array([[np.cos(a) * np.cos(b), np.sin(a) * np.cos(b), np.sin(b)] for a in u for b in u])
    P, N = [], []
    for i in range(n - 1):
        for j in range(n - 1):
            q = [i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1]
            for tri in ((q[0], q[1], q[2]), (q[0], q[2], q[3])):
                P.append(R * V[list(tri)])
                N.append(V[list(tri)])
    return np.array(P), np.array(N)


def test_principal_curvature_of_a_cylinder_and_a_sphere():
    """Exact (1e-6) on cylinders (either normal orientation) and spheres, 0
    on a flat-shaded triangle; the mean of edge curvatures is 1/3 of it on
    the ring's thin triangles."""
    P, N = _cylinder(0.5, 0.3, 48)
    k = principal_curvature(P, N)
    assert np.allclose(k, 2.0, rtol=1e-4)
    assert np.allclose(principal_curvature(*_cylinder(0.5, 0.3, 48, inward=True)), -2.0, rtol=1e-4)
    # the former estimate: mean over edges of dot(dn, dp) / |dp|^2
    mean_edge = np.mean([np.einsum("ij,ij->i", N[:, j] - N[:, i], P[:, j] - P[:, i])
                         / np.einsum("ij,ij->i", P[:, j] - P[:, i], P[:, j] - P[:, i])
                         for i, j in ((0, 1), (1, 2), (2, 0))], axis=0)
    assert np.all(mean_edge < 0.7 * k)
    assert np.allclose(principal_curvature(*_sphere_patch(2.0)), 0.5, rtol=1e-3)
    flat = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    assert principal_curvature(flat, np.tile([0, 0, 1.0], (1, 3, 1)))[0] == 0.0
    assert principal_curvature(np.zeros((1, 3, 3)), np.zeros((1, 3, 3)))[0] == 0.0


def test_focus_of_the_ring_in_flatland():
    """The spectrum chain of a photon from ring_lambert's light (2.9 m to the
    mirror, 1 m light, R = 0.5 m) focuses 0.276 m off the mirror with the
    principal curvature (the mirror equation gives 1/(4 - 1/2.9) = 0.274 m),
    near the floor 0.3 m away; the mean edge curvature puts the focus at
    0.99 m and predicts a wide radius on the floor."""
    s = F.light_init("AREA", 1, size=1.0)
    s = F.travel(s, 2.9)
    r = {}
    for name, kappa in (("principal", -2.0), ("mean_edge", -0.675)):
        t = F.curvature(s, kappa)
        a, b, c = t[0]
        r[name] = (-c / b, F.predicted_radius(F.travel(t, 0.3), np.inf, np.inf)[0])
    assert r["principal"][0] == pytest.approx(0.276, abs=0.005)
    assert r["mean_edge"][0] > 0.9
    assert r["principal"][1] < 0.01 < 0.1 < r["mean_edge"][1]


def _render_ring(size, monkeypatch):
    return _render(RING, lambda bpy: setattr(bpy.data.objects["AreaLight"].data, "size", size))


def _render(path, edit=None):
    """(image (P,) grey, PPM radius (P,), predicted radius of the last pass
    (P,)) of `path` at 32x32 after 16 passes of 50k photons, seed 0; edit(bpy)
    changes the scene first.  frequency_decay 0.5 (the default before, 25 % x
    k^-0.5 frequency photons in passes 1, 2, 4, 8, 16): these tests compare
    the operators at the photon count they were measured with.  The default
    decay 2 traces 16,650 frequency photons in these 16 passes instead of
    35,133, and a thin caustic's last prediction comes from fewer photons:
    median predicted / PPM radius 0.29 on the ring's line, 0.053 at the
    sphere's focus (decay 1: 0.064, 0.077), while the images' errors at
    equal CPU are not worse (docs/method.md "The frequency schedule and the
    first 10 %")."""
    bpy_helpers = pytest.importorskip("bpy_helpers")
    bpy = bpy_helpers.bpy()
    bpy_helpers.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    from core.render import Renderer
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = 25                      # 32 x 32
    if edit is not None:
        edit(bpy)
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    st = settings_from_scene(sc).replace(integrator="PHOTON", max_passes=16, photons_per_pass=50_000,
                                         verify_holds=False, frequency_decay=0.5)
    r = Renderer(scene, st, log=lambda s: None)
    for _ in range(16):
        img = r.step().image[..., :3].mean(axis=2).ravel()
    return img, np.sqrt(r.R2), r.state.r_pred_last


def test_predicted_radius_on_the_caustic_line_under_a_1m_light(monkeypatch):
    """ring_lambert (1 m light), 32x32, 16 passes of 50k photons, seed 0.
    Caustic line: the 2% brightest of the pixels that collected frequency
    photons (the brightest pixels overall include directly lit floor near
    the light, which no frequency photon reaches).  Smooth region: the pixels
    with frequency photons below the median brightness of those.
    Measured (deterministic for the seed): median predicted / PPM radius
    0.029 on the caustic line (3 pixels) and 0.90 on the smooth region (42
    pixels) with the interface operator (the ring's curvature is sagittal
    for a light 30 deg up: 2 kappa cos_i, docs/frequency.md "Refraction and
    oblique incidence"); 0.24 and 1.55 with k = 2 kappa at any incidence;
    2.19 and 1.85 with the mean edge curvature.  Under a 5 cm light: 0.002
    and 1.03."""
    img, R, rp = _render_ring(1.0, monkeypatch)
    fin = np.isfinite(rp)
    idx = np.nonzero(fin)[0]
    order = idx[np.argsort(img[idx])]
    caustic = order[-max(3, idx.size // 50):]
    smooth = order[: idx.size // 2]
    ratio_c = np.median(rp[caustic] / R[caustic])
    ratio_s = np.median(rp[smooth] / R[smooth])
    assert ratio_c < 0.1
    assert ratio_s > 0.6


def test_principal_frame_of_a_cylinder():
    """Both principal curvatures and the first direction: on the ring's
    cylinder k1 = 1/R across the axis (e1 horizontal, normal to the axis), k2 = 0
    along it; on a sphere k1 = k2 = 1/R."""
    P, N = _cylinder(0.5, 0.3, 48)
    cv = principal_frame(P, N)
    assert np.allclose(cv.k1, 2.0, rtol=1e-4) and np.allclose(cv.k2, 0.0, atol=1e-6)
    assert np.allclose(np.abs(cv.e1[:, 2]), 0.0, atol=1e-6)        # perpendicular to the axis z
    assert np.allclose(np.linalg.norm(cv.e1, axis=1), 1.0)
    radial = P.mean(axis=1) * [1, 1, 0]
    assert np.allclose(np.einsum("ij,ij->i", cv.e1, radial), 0.0, atol=0.02)
    sp = principal_frame(*_sphere_patch(2.0))
    assert np.allclose(sp.k1, 0.5, rtol=1e-3) and np.allclose(sp.k2, 0.5, rtol=1e-3)


def test_predicted_radius_at_the_focus_of_a_glass_sphere():
    """glass_sphere (ball lens R = 0.35 m, n = 1.5, a 5 cm spot 2.8 m away),
    32x32, 16 passes of 50k photons, seed 0.  The focus: the 4 brightest
    pixels that collect frequency photons (radiance 3.3 to 8.8, against
    <= 1 on the directly lit floor).  Median predicted / PPM radius there,
    measured: 0.0035 with the refraction operator; 0.059 with the mirror
    factor the renderer applied to glass before (a diverging bend entering
    the sphere, whose b was capped, so small by accident).  The paraxial
    focus lies 0.28 m behind the sphere and the floor 0.13 m along the
    central ray: the photons that make the spot come from the zone whose
    (aberrated) focus is on the floor (tests/test_interface_operator.py,
    ball lens at height 0.6 R: 0.083 m)."""
    img, R, rp = _render(os.path.join(BLENDS, "glass_sphere.blend"))
    idx = np.nonzero(np.isfinite(rp))[0]
    focus = idx[np.argsort(img[idx])][-4:]
    assert img[focus].min() > 2.0
    assert np.median(rp[focus] / R[focus]) < 0.02
