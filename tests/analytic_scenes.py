"""Scenes with closed-form radiance, built in plain Python (no bpy).

Shared by the analytic renderer tests and the benchmarks.  Units are Cycles'
(docs/cycles_units.md): a point light of power P has intensity P/(4 pi);
an area light of power P and area A has radiance P/(pi A).
"""
from __future__ import annotations

import numpy as np

from core.scene.model import (DIFFUSE, GLOSSY, Camera, Light, Lobe, Material,
                        make_scene)


def quad(center, ex, ey):
    """Two triangles spanning center +- ex +- ey (normal = ex x ey)."""
    c, ex, ey = (np.asarray(v, float) for v in (center, ex, ey))
    p00, p10, p11, p01 = c - ex - ey, c + ex - ey, c + ex + ey, c - ex + ey
    return [[p00, p10, p11], [p00, p11, p01]]


def translate(x, y, z):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def look_down_ortho(height, scale, res):
    """Orthographic camera at (0, 0, height) looking down -Z, covering scale metres."""
    return Camera(kind="ORTHO", matrix_world=translate(0, 0, height), ortho_scale=scale,
                  resolution=(res, res), clip_start=0.01, clip_end=100.0)


def lambert(name, rho):
    return Material(name, (Lobe(DIFFUSE, (rho, rho, rho)),))


def point_light_plane(res=24, P=100.0, h=1.0, rho=0.8, scale=2.0):
    """Lambert plane z = 0 (20 m wide) under a point light at height h.

    Radiance L(x, y) = rho/pi * P/(4 pi) * h / (r^2 + h^2)^(3/2).
    """
    tris = quad((0, 0, 0), (10, 0, 0), (0, 10, 0))
    light = Light("point", "POINT", (P, P, P), translate(0, 0, h))
    scene = make_scene(tris, [lambert("floor", rho)], [light], look_down_ortho(3.0, scale, res))

    def radiance(x, y):
        return rho / np.pi * P / (4 * np.pi) * h / (x * x + y * y + h * h) ** 1.5
    return scene, radiance


def polygon_irradiance(x, poly):
    """Irradiance at points x (K,3) on the plane z = 0 (normal +Z) from a
    unit-radiance polygon poly (V,3) (Lambert's contour formula):
    E = 1/2 * sum_i gamma_i * (n . (v_i x v_{i+1}) / |v_i x v_{i+1}|) with
    L = 1, so the caller multiplies by the radiance."""
    E = np.zeros(x.shape[0])
    V = len(poly)
    for i in range(V):
        a = poly[i][None, :] - x
        b = poly[(i + 1) % V][None, :] - x
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        c = np.cross(a, b)
        cn = np.linalg.norm(c, axis=1)
        gamma = np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1, 1))
        E += gamma * c[:, 2] / np.maximum(cn, 1e-300)
    return 0.5 * np.abs(E)


def area_light_plane(res=24, P=50.0, size=1.0, h=1.0, rho=0.8, scale=2.0):
    """Lambert plane under a square area light (facing down) at height h."""
    tris = quad((0, 0, 0), (10, 0, 0), (0, 10, 0))
    light = Light("area", "AREA", (P, P, P), translate(0, 0, h), shape="SQUARE", size=size)
    scene = make_scene(tris, [lambert("floor", rho)], [light], look_down_ortho(3.0, scale, res))
    L_light = P / (np.pi * size * size)
    s = size / 2
    poly = np.array([[-s, -s, h], [s, -s, h], [s, s, h], [-s, s, h]], float)

    def radiance(x, y):
        pts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
        return (rho / np.pi * L_light * polygon_irradiance(pts, poly)).reshape(x.shape)
    return scene, radiance


def mirror_caustic(res=24, P=100.0, h_light=1.0, h_mirror=2.0, a=0.5, rho=0.8, rho_m=0.9,
                   scale=2.0):
    """A point light under a horizontal mirror (facing down): the mirror acts as
    an image light at z = 2 h_mirror - h_light over its footprint.

    Floor radiance = rho/pi * (E_direct + E_caustic), E_caustic = rho_m I cos/d^2
    from the image where the segment image->x crosses the mirror square.  The
    orthographic camera sits between the light and the mirror looking down, so it
    sees only the floor.  Returns (scene, radiance, footprint half-width).
    """
    tris = quad((0, 0, 0), (10, 0, 0), (0, 10, 0))
    mats = [lambert("floor", rho), Material("mirror", (Lobe(GLOSSY, (rho_m,) * 3, roughness=0.0),))]
    tris_m = quad((0, 0, h_mirror), (0, a, 0), (a, 0, 0))      # normal -Z
    light = Light("point", "POINT", (P, P, P), translate(0, 0, h_light))
    cam = look_down_ortho(1.5, scale, res)
    scene = make_scene(tris + tris_m, mats, [light], cam, tri_mat=[0, 0, 1, 1])
    I = P / (4 * np.pi)
    z_img = 2 * h_mirror - h_light

    def radiance(x, y):
        E_d = I * h_light / (x * x + y * y + h_light ** 2) ** 1.5
        # Where the ray from the image to (x, y, 0) meets z = h_mirror.
        t = (z_img - h_mirror) / z_img
        inside = (np.abs(x * t) < a) & (np.abs(y * t) < a)
        E_c = np.where(inside, rho_m * I * z_img / (x * x + y * y + z_img ** 2) ** 1.5, 0.0)
        return rho / np.pi * (E_d + E_c)
    return scene, radiance, a * z_img / (z_img - h_mirror)


def furnace_box(res=16, Le=1.0, rho=0.5, half=1.0):
    """Closed cube whose inner walls all emit Le and reflect with albedo rho.

    Every wall point sees radiance L = Le / (1 - rho) (white furnace).  The
    camera at the centre looks at the middle of the floor with a narrow view.
    """
    h = half
    tris = []
    # Normals point inwards.
    tris += quad((0, 0, -h), (h, 0, 0), (0, h, 0))     # floor, +Z
    tris += quad((0, 0, h), (0, h, 0), (h, 0, 0))      # ceiling, -Z
    tris += quad((-h, 0, 0), (0, h, 0), (0, 0, h))     # +X
    tris += quad((h, 0, 0), (0, 0, h), (0, h, 0))      # -X
    tris += quad((0, -h, 0), (0, 0, h), (h, 0, 0))     # +Y
    tris += quad((0, h, 0), (h, 0, 0), (0, 0, h))      # -Y
    mat = Material("wall", (Lobe(DIFFUSE, (rho,) * 3),), emission=(Le, Le, Le))
    cam = Camera(kind="PERSP", matrix_world=np.eye(4), lens=50.0, sensor_width=12.0,
                 resolution=(res, res), clip_start=0.01, clip_end=10.0)
    scene = make_scene(tris, [mat], [], cam)
    return scene, Le / (1.0 - rho)


def pixel_centres_ortho(scene):
    """World (x, y) of pixel centres for a look_down_ortho camera, row 0 at the top."""
    cam = scene.camera
    W, H = cam.resolution
    pix = cam.ortho_scale / W
    xs = (np.arange(W) + 0.5 - W / 2) * pix
    ys = ((H - 1 - np.arange(H)) + 0.5 - H / 2) * pix
    return np.meshgrid(xs, ys)
