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

A holdout object whose material lets light through (a Transparent BSDF,
an image's alpha) keeps that transparency (``surface_shader_apply_holdout``
removes every other closure and gives weight 1 - its transparency):
:func:`see_through` gives such an object's triangles a material whose
camera rays see its Transparent lobes alone, and their weight is taken per
hit (:func:`camera_hits` with ``transparency``), so a camera ray is held
out where the surface is opaque and passes on where it is transparent.

Every other ray (reflections, shadows, photons) meets the surface as an
ordinary one: a holdout object shades with its material, a Holdout closure
scatters nothing.  Light tracing does not splat a light vertex on a
surface of weight 1 (the camera's ray would end there), nor on a held-out
transparent object (camera rays see its Transparent lobes alone).
"""
from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np

#: The weight of the triangles whose holdout is taken per hit (1 - the
#: transparency there): a holdout object whose material lets light through.
PER_HIT = np.float32(np.nan)


def triangle_weights(scene) -> Optional[np.ndarray]:
    """(T,) float32 the holdout weight of each triangle (1 on a holdout
    object, PER_HIT on one whose camera rays see a Transparent lobe, else
    its material's ``holdout``), or None when every one is 0
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
    cam = seen(rows(scene, "camera"), np.asarray(scene.tri_mat, np.int64))
    w = h[cam] if h.size else np.zeros(scene.tri_mat.shape[0], np.float32)
    if obj is not None:
        obj = np.asarray(obj, bool)
        clear = np.array([_transparent(m) for m in scene.materials], bool)
        w = np.where(obj, np.where(clear[cam], PER_HIT, np.float32(1.0)), w)
    return w if np.any(w != 0) else None


def _transparent(material) -> bool:
    from .model import TRANSPARENT
    return any(lb.kind == TRANSPARENT and lb.weight != 0 for lb in material.lobes)


def see_through(scene):
    """The scene with each holdout object's material that lets light
    through (a used Transparent lobe) copied, the copy's camera rays
    seeing its Transparent lobes alone (``Scene.material_camera``; other
    rays see the material itself): Cycles keeps only those closures on a
    holdout object.  The scene itself when there is none."""
    obj = getattr(scene, "tri_holdout", None)
    if obj is None or not np.any(obj):
        return scene
    from .model import TRANSPARENT, Material
    from .ray_variants import rows, seen
    obj = np.asarray(obj, bool)
    mats = list(scene.materials)
    M = len(mats)
    tri = np.asarray(scene.tri_mat, np.int64)
    cam0 = rows(scene, "camera")
    cam = list(range(M)) if cam0 is None else [int(c) for c in cam0]
    shd0 = getattr(scene, "material_shadow", None)
    shd = list(range(M)) if shd0 is None else [int(c) for c in np.asarray(shd0)]
    pidx = (None if scene.material_pass_index is None
            else list(np.asarray(scene.material_pass_index)))
    new_tri = tri.copy()
    for b in np.unique(tri[obj]).tolist():
        c = mats[cam[b]]
        lobes = tuple(lb for lb in c.lobes if lb.kind == TRANSPARENT and lb.weight != 0)
        if not lobes:
            continue
        copy, v = len(mats), len(mats) + 1
        mats += [mats[b], Material(f"{c.name} (holdout)", lobes)]
        cam += [v, v]
        shd += [shd[b], v]
        if pidx is not None:
            pidx += [pidx[b], pidx[b]]
        new_tri[obj & (tri == b)] = copy
    if len(mats) == M:
        return scene
    return dataclasses.replace(
        scene, materials=mats, tri_mat=new_tri.astype(np.int32),
        material_camera=np.asarray(cam, np.int32),
        material_shadow=None if shd0 is None else np.asarray(shd, np.int32),
        material_pass_index=None if pidx is None else np.asarray(pidx, np.int32))


def ends_camera(weights: Optional[np.ndarray]) -> Optional[np.ndarray]:
    """(T,) bool the triangles where a camera ray ends (weight >= 1, Cycles'
    ``isequal(holdout_weight, one)``), or None when there are none."""
    if weights is None:
        return None
    end = weights >= 1.0
    return end if end.any() else None


def camera_hits(weights: Optional[np.ndarray], prim: np.ndarray, on_line: np.ndarray,
                beta: np.ndarray, escape: Optional[np.ndarray], idx: np.ndarray,
                uv=None, transparency=None):
    """The holdout of K rays' hits: prim (K,) the triangle hit (-1: none),
    on_line (K,) bool the rays still on their camera ray's line, beta (K, 3)
    their throughput, idx (K,) their pixels.  Adds h x mean(beta) to
    escape[idx] (the film's transparency; escape None: not kept) and returns
    (K,) bool the rays that end there, or None when none meets a holdout.
    uv = (u, v) (K,) the hits' barycentrics and transparency(prim, u, v)
    (n, 3) the light a surface lets through there (:func:`transparency`):
    the weight of a PER_HIT triangle is 1 - its mean."""
    if weights is None:
        return None
    hit = on_line & (prim >= 0)
    if not hit.any():
        return None
    h = np.zeros(prim.shape[0])
    h[hit] = weights[prim[hit]]
    per = np.nonzero(np.isnan(h))[0]
    hb = None
    if per.size:
        # Cycles: average((1 - T) x throughput), T the surface's RGB transparency.
        T = transparency(prim[per], uv[0][per], uv[1][per])
        h[per] = np.clip(1.0 - T.mean(axis=1), 0.0, 1.0)
        hb = ((1.0 - T) * beta[per]).mean(axis=1)
    held = np.nonzero(h > 0)[0]
    if held.size == 0:
        return None
    if escape is not None:
        add = h * beta.mean(axis=1)
        if hb is not None:
            add[per] = hb
        np.add.at(escape, idx[held], add[held])
    return h >= 1.0


def transparency(accel):
    """The ``camera_hits`` transparency of the scene of ``accel``: the
    Transparent lobes camera rays see at the hits (core.lights.shadow's
    pass-through weights, camera view; attached with the render plan's
    transparent shadows, which a PER_HIT triangle's material implies)."""
    from ..lights import shadow

    def at(prim, u, v):
        return shadow.pass_through(shadow.attached(accel, camera=True),
                                   np.asarray(prim, np.int64), np.asarray(u, np.float64),
                                   np.asarray(v, np.float64))
    return at
