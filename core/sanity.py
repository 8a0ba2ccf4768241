"""Scenes the renderer refuses before the first pass, because it would render them wrong.

Cycles renders some of these as a black or otherwise silently wrong image; FPPM
says what to change instead (docs/reliability.md, "Bad input"), with SceneError
(the CLI's exit code 4):

- a light, emissive material or world with an infinite, NaN or negative
  strength (negative lights are not supported: photons carry flux >= 0);
- a camera whose transform is not finite or not invertible (scaled to 0);
- a scene whose coordinates float32 cannot hold: Embree works in float32
  (core/accel.py), and squared distances of a scene wider than
  :data:`MAX_EXTENT` overflow float32 (3.4e38);
- a scene so wide that float32 cannot resolve the scale the camera sees
  (:func:`check_resolution`): hit points are interpolated from Embree's
  float32 barycentrics, whose error is 2^-24 of the triangle's size.

A scene far from the origin is moved to it (:func:`recentre`) before the
float32 copy that Embree gets, so its image does not depend on where it is.

Nothing here imports ``bpy``.
"""
from __future__ import annotations

import numpy as np

from .errors import SceneError

# Widest scene [m] whose squared diameter and every squared distance inside it
# stay finite in float32 (sqrt(3.4e38) = 1.8e19), with a margin of 10^3 for
# the sums of squares and the kernels' r^2 * area products.
MAX_EXTENT = 1e16
# A transform whose 3x3 part has |det| below this fraction of its largest
# entry cubed cannot be inverted in float64 without losing the digits of the
# image (it is a scale to 0 on some axis, up to rounding).
MIN_RELATIVE_DET = 1e-12
# float32 resolution used for the resolution check: 4 ulps of a coordinate
# (Embree's watertight test and the barycentric interpolation, core/accel.py).
F32_RESOLUTION = 2.0 ** -22


def _rgb_problem(v) -> str | None:
    a = np.asarray(v, np.float64)
    if not np.all(np.isfinite(a)):
        return "an infinite or NaN"
    if np.any(a < 0):
        return "a negative"
    return None


def check_lights(scene) -> None:
    """Every light, emissive material and the world: finite strengths >= 0."""
    for lt in scene.lights:
        why = _rgb_problem(lt.strength)
        if why is not None:
            s = ", ".join(f"{x:g}" for x in np.asarray(lt.strength, np.float64).reshape(-1))
            fix = ("negative lights are not supported: set a power >= 0"
                   if why == "a negative" else "set a finite power")
            raise SceneError(f"Light '{lt.name}' has {why} power (strength {s}): {fix}.")
        if not np.all(np.isfinite(np.asarray(lt.matrix_world, np.float64))):
            raise SceneError(f"Light '{lt.name}' has an infinite or NaN transform: "
                             f"fix its location, rotation and scale.")
        for attr in ("radius", "size", "size_y", "angle", "spot_size", "spread"):
            v = getattr(lt, attr, 0.0)
            if not np.isfinite(v):
                raise SceneError(f"Light '{lt.name}' has an infinite or NaN {attr}: set a finite value.")
    for m in scene.materials:
        why = _rgb_problem(m.emission)
        if why is not None:
            raise SceneError(f"Material '{m.name}' emits with {why} strength: set a finite "
                             f"emission strength >= 0.")
    why = _rgb_problem(scene.world_color)
    if why is not None:
        raise SceneError(f"The world has {why} colour or strength: set a finite strength >= 0.")


def check_camera(cam) -> None:
    """A finite, invertible camera transform and finite lens values."""
    M = np.asarray(cam.matrix_world, np.float64)
    if not np.all(np.isfinite(M)):
        raise SceneError("The camera has an infinite or NaN transform: fix its location, "
                         "rotation and scale.")
    A = M[:3, :3]
    s = float(np.abs(A).max())
    if s == 0.0 or abs(np.linalg.det(A / s)) < MIN_RELATIVE_DET:
        raise SceneError("The camera is scaled to 0 on some axis (its transform cannot be "
                         "inverted): set the camera's scale to 1.")
    for attr in ("lens", "sensor_width", "sensor_height", "ortho_scale"):
        v = float(getattr(cam, attr))
        if not (np.isfinite(v) and v > 0):
            raise SceneError(f"The camera's {attr.replace('_', ' ')} is {v:g}: it must be a "
                             f"finite number > 0.")


def check_extent(scene) -> None:
    """Refuse coordinates float32 cannot hold (see :data:`MAX_EXTENT`).

    Over the finite triangle corners (the NaN or infinite ones are dropped
    later, with a warning), the camera and the lights that have a position.
    """
    pts = np.asarray(scene.tri_p, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    reach = float(np.abs(pts).max()) if pts.size else 0.0
    for M in [scene.camera.matrix_world] + [lt.matrix_world for lt in scene.lights
                                           if lt.kind != "SUN"]:
        co = np.asarray(M, np.float64)[:3, 3]
        reach = max(reach, float(np.abs(co).max()))
    if reach > MAX_EXTENT:
        raise SceneError(f"The scene reaches {reach:.3g} m from the origin; FPPM traces rays in "
                         f"float32 and renders scenes up to {MAX_EXTENT:.0e} m from it: scale "
                         f"the scene down or move it nearer the origin.")


# The clip start understates the scale that matters (it is often set tiny on
# purpose): the resolution is compared with this many clip starts.
CLIP_FACTOR = 100.0


def check_resolution(scene) -> None:
    """Refuse a scene whose float32 resolution is coarser than the scale the camera sees.

    After :func:`recentre` coordinates reach D/2 (D the scene diameter), and a
    hit on a triangle of size up to D is interpolated from float32
    barycentrics: F32_RESOLUTION * D at worst.  The scale that matters is
    taken as the larger of CLIP_FACTOR camera clip starts and the distance
    from the camera to the nearest light with a position.  Measured on the
    analytic point light 1 m over a floor seen 2 m wide from 3 m
    (docs/reliability.md, "Scale"): the floor scaled by 1e5 (resolution
    0.67 m) renders within 0.4 % of the closed form, by 1e6 (6.7 m) 16 %
    too dark, by 1e7 and beyond 91 % too bright; the last two are refused.
    """
    D = scene.diameter()
    res = F32_RESOLUTION * D
    cam = np.asarray(scene.camera.matrix_world, np.float64)[:3, 3]
    d_light = min((float(np.linalg.norm(np.asarray(lt.matrix_world, np.float64)[:3, 3] - cam))
                   for lt in scene.lights if lt.kind != "SUN"), default=0.0)
    clip = float(scene.camera.clip_start)
    scale = max(CLIP_FACTOR * clip, d_light)
    if res > scale:
        raise SceneError(f"The scene is {D:.3g} m wide: FPPM traces rays in float32, which "
                         f"resolves only {res:.2g} m at that size, more than the scale the "
                         f"camera sees ({scale:.2g} m: {CLIP_FACTOR:g} x the clip start or the "
                         f"distance to the nearest light): make the largest objects (a ground "
                         f"plane, a far light) smaller.")


def recentre(scene):
    """(scene, origin): the scene moved by -origin when it lies far from the origin.

    origin (3,) float64 is the centre of the scene's bounds when that centre
    is farther from the origin than the scene's diameter (float32 would lose
    more than a bit there), else zeros and the scene itself (unchanged, so a
    scene near the origin renders bit for bit as before).  Triangles are
    moved in float64 and rounded to float32 once; lights and the camera are
    moved in their float64 matrices.  Radiance does not depend on a
    translation: the image is the same, with the precision of a scene at the
    origin.
    """
    import dataclasses
    lo, hi = scene.bounds()
    c = 0.5 * (lo + hi)
    if not np.abs(c).max() > scene.diameter():
        return scene, np.zeros(3)

    def moved(M):
        M = np.array(M, np.float64, copy=True)
        M[:3, 3] -= c
        return M
    tri_p = (np.asarray(scene.tri_p, np.float64) - c).astype(np.float32)
    lights = [dataclasses.replace(lt, matrix_world=moved(lt.matrix_world)) for lt in scene.lights]
    camera = dataclasses.replace(scene.camera, matrix_world=moved(scene.camera.matrix_world))
    return dataclasses.replace(scene, tri_p=tri_p, lights=lights, camera=camera), c


def check_scene(scene) -> None:
    """All the refusals above, in the order a user would fix them."""
    check_extent(scene)
    check_camera(scene.camera)
    check_lights(scene)
