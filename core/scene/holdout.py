"""Holdout: the camera rays that meet a holdout object or a Holdout shader.

Cycles (``integrate_surface_holdout``, ``surface_shader_apply_holdout``): a
ray still on the camera ray's line (the lens, then only straight crossings
of Transparent BSDFs: its PATH_RAY_TRANSPARENT_BACKGROUND flag) that hits a
surface of holdout weight h adds h x its throughput to the film's
transparency (alpha = 1 - that sum), and ends there when h = 1.  h is 1 on
an object marked holdout (Object > Visibility > Holdout, or its collection's
Holdout in the view layer; an instance takes its instancer's), else the sum
of the material's Holdout closures' mix weights (``Material.holdout``).  The
other closures keep their own mix weights: a Mix Shader of a Holdout and a
Diffuse at 0.5 is half transparent and shows half the diffuse.

Every other ray (reflections, shadows, photons) meets the surface as an
ordinary one: a holdout object shades with its material, a Holdout closure
scatters nothing.  Light tracing does not splat a light vertex on a
surface of weight 1 (the camera's ray would end there).
"""
from __future__ import annotations

from typing import Optional

import numpy as np


def triangle_weights(scene) -> Optional[np.ndarray]:
    """(T,) float32 the holdout weight of each triangle (1 on a holdout
    object, else its material's ``holdout``), or None when every one is 0
    (the renderer's plain path).  Computed once per scene: the camera pass,
    the camera paths, light tracing, the light table and the film all ask
    (kept on the scene with the arrays it was computed from)."""
    key = (getattr(scene, "tri_mat", None), getattr(scene, "materials", None),
           getattr(scene, "tri_holdout", None), getattr(scene, "material_camera", None))
    memo = getattr(scene, "__dict__", {}).get("_holdout_weights")
    if memo is not None and all(a is b for a, b in zip(memo[0], key)):
        return memo[1]
    w = _weights(scene)
    if hasattr(scene, "__dict__"):
        scene.__dict__["_holdout_weights"] = (key, w)
    return w


def _weights(scene) -> Optional[np.ndarray]:
    h = np.array([float(getattr(m, "holdout", 0.0)) for m in getattr(scene, "materials", ())],
                 np.float32)
    obj = getattr(scene, "tri_holdout", None)
    if not h.any() and (obj is None or not np.any(obj)):
        return None     # (also a film's stand-in scene without triangles)
    from .ray_variants import rows, seen
    # Camera rays' holdout: the material they see (a Light Path node).
    w = h[seen(rows(scene, "camera"), np.asarray(scene.tri_mat, np.int64))] if h.size \
        else np.zeros(scene.tri_mat.shape[0], np.float32)
    if obj is not None:
        w = np.where(np.asarray(obj, bool), np.float32(1.0), w)
    return w if w.any() else None


def ends_camera(weights: Optional[np.ndarray]) -> Optional[np.ndarray]:
    """(T,) bool the triangles where a camera ray ends (weight >= 1, Cycles'
    ``isequal(holdout_weight, one)``), or None when there are none."""
    if weights is None:
        return None
    end = weights >= 1.0
    return end if end.any() else None


def camera_hits(weights: Optional[np.ndarray], prim: np.ndarray, on_line: np.ndarray,
                beta: np.ndarray, escape: Optional[np.ndarray], idx: np.ndarray):
    """The holdout of K rays' hits: prim (K,) the triangle hit (-1: none),
    on_line (K,) bool the rays still on their camera ray's line, beta (K, 3)
    their throughput, idx (K,) their pixels.  Adds h x mean(beta) to
    escape[idx] (the film's transparency; escape None: not kept) and returns
    (K,) bool the rays that end there, or None when none meets a holdout."""
    if weights is None:
        return None
    hit = on_line & (prim >= 0)
    if not hit.any():
        return None
    h = np.zeros(prim.shape[0])
    h[hit] = weights[prim[hit]]
    held = np.nonzero(h > 0)[0]
    if held.size == 0:
        return None
    if escape is not None:
        np.add.at(escape, idx[held], h[held] * beta[held].mean(axis=1))
    return h >= 1.0
