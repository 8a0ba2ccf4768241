"""Materials that camera rays or shadow rays see differently (a Light Path node).

A Mix Shader whose Fac is a Light Path output shades a surface by the kind
of ray that meets it: Is Camera Ray is 1 for a camera ray (Cycles keeps the
flag through Transparent BSDF crossings), Is Shadow Ray for a shadow ray
(next-event estimation's, which passes transparent surfaces).  The
exporter mixes the material once per kind and keeps the camera rays' and
the shadow rays' materials as materials of their own:
``Scene.material_camera`` / ``material_shadow`` (M,) give the material those
rays see in place of each one (itself where nothing differs).

Who reads them:
- camera rays: the camera pass of photon mapping and the camera paths of
  Path Tracing and Combined, on hits still on the camera ray's line
  (:func:`seen`); the holdout weights (core.scene.holdout);
- shadow rays: the transparent-shadow test (core.lights.shadow), which
  then passes what shadow rays see as transparent.  The glass-shadow trick
  (a Glass that shadow rays see as a white Transparent BSDF) makes the
  object shadowless instead (:func:`clear_shadows`: Shadow visibility off),
  whose rule photons and light paths follow too;
- every other ray (BSDF rays after the first vertex, photons, light paths)
  sees the material itself.

Light tracing joins a light vertex to the lens with what other rays see;
Combined leaves light tracing out of such scenes (core.integrators.mis).
"""
from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np


def rows(scene, kind: str) -> Optional[np.ndarray]:
    """(M,) int64 the material rays of ``kind`` ('camera', 'shadow') see in
    place of each material, or None where they see every one as it is."""
    a = getattr(scene, "material_" + kind, None)
    if a is None:
        return None
    a = np.asarray(a, np.int64)
    return None if np.array_equal(a, np.arange(a.size)) else a


def seen(variant: Optional[np.ndarray], mat: np.ndarray,
         on_line: Optional[np.ndarray] = None) -> np.ndarray:
    """The materials (K,) hits of materials ``mat`` (K,) are shaded with:
    ``variant``'s rows (``rows(scene, 'camera')``) where on_line (K,) bool
    (None: every hit), mat elsewhere or without variants."""
    if variant is None:
        return mat
    m = np.asarray(mat, np.int64)
    if on_line is None:
        return variant[m]
    return np.where(on_line, variant[m], m)


def _clear(material) -> bool:
    """Whether a material lets shadow rays through untouched: white
    Transparent BSDFs only (weights x colours summing to 1 in every
    channel), no texture, alpha or view factor."""
    from .model import TRANSPARENT
    lobes = material.lobes
    if not lobes or any(lb.kind != TRANSPARENT or lb.color_texture >= 0
                        or getattr(lb, "alpha_texture", -1) >= 0 or getattr(lb, "view", ())
                        for lb in lobes):
        return False
    total = np.sum([lb.weight * np.asarray(lb.color, np.float64) for lb in lobes], axis=0)
    return bool(np.all(np.abs(total - 1.0) < 1e-6))


def clear_shadows(scene):
    """The scene with the objects whose shadow rays' material (Is Shadow
    Ray) is a white Transparent BSDF made shadowless instead (Shadow
    visibility off: ``Scene.tri_visibility``), which every integrator
    honours for shadow rays and for the first segment of photons and light
    paths (core.accel, core.sppm.photons); their ``material_shadow`` then
    maps to themselves.  The scene itself when there are none."""
    from ..accel import RAY_ALL, RAY_SHADOW
    sh = rows(scene, "shadow")
    if sh is None:
        return scene
    mats = scene.materials
    clear = np.array([sh[m] != m and _clear(mats[sh[m]]) for m in range(sh.size)], bool)
    tri = clear[np.asarray(scene.tri_mat, np.int64)]
    if not tri.any():
        return scene
    vis = (np.full(tri.size, RAY_ALL, np.uint8) if scene.tri_visibility is None
           else np.asarray(scene.tri_visibility, np.uint8).copy())
    vis[tri] &= np.uint8(~RAY_SHADOW & 0xFF)
    new = np.where(clear, np.arange(sh.size), sh).astype(np.int32)
    return dataclasses.replace(
        scene, tri_visibility=vis,
        material_shadow=None if np.array_equal(new, np.arange(sh.size)) else new)
