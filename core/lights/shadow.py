"""Transparent shadows: how much light a shadow segment lets through.

    T = transmittance(accel, o, d, t_max)      # (K, 3) float64

Cycles' shadow rays (``integrate_intersect_shadow_transparent``,
``integrate_transparent_shadow``) do not stop at a surface whose shader has
a Transparent BSDF: each such crossing multiplies the shadow throughput by
``surface_shader_transparency``, the sum of the Transparent closures'
weights there (colour x mix weight, x 1 - alpha of an image cut-out), and
an opaque hit (a shader without Transparent closures) ends it at 0.  More
than ``transparent_max_bounce - 1`` transparent hits count as opaque.  FPPM
follows the same rule with batched Embree calls: closest hit, its weight
(``core.materials.lobe_colors`` of the TRANSPARENT lobes at the hit's uv),
a new ray from just past the surface, until every segment ends or is
blocked.

A crossing out of an absorbing volume (core.scene.absorption) also takes
the volume's Beer-Lambert factor of the segment that reached it.

Scenes without a transparent material attach nothing (``attach`` returns
False; the render plan then says no "transparent shadows") and
``transmittance`` is one ``Accel.occluded`` call, as before.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..accel import REL_OFFSET
from ..mathutil import dot as _dot
from ..scene.absorption import attenuate, of_scene as absorption_of
from ..scene.model import TRANSPARENT

# Cycles' default Light Paths > Max Bounces > Transparent.  A shadow ray from
# a path with no transparent bounce yet may cross one less
# (``integrate_shadow_max_transparent_hits``); FPPM does not count the camera
# path's transparent bounces, so every shadow ray gets that budget.
TRANSPARENT_MAX_BOUNCES = 8
MAX_CROSSINGS = TRANSPARENT_MAX_BOUNCES - 1

# Where the attached materials live on an Accel (core.accel is not told):
# as shadow rays see them, and as camera rays do (light tracing's joins to
# the lens), which differ where a Light Path node gives either a material
# of its own (core.scene.ray_variants).
_ATTR = "_transparent_shadows"
_ATTR_CAMERA = "_transparent_for_camera"


@dataclass(frozen=True)
class ShadowMaterials:
    """What a shadow ray needs at a hit: the material table, tri_mat (T,)
    int64, tri_uv (T, 3, 2) float32, and transparent (M,) bool: the
    material has a used TRANSPARENT lobe (the others are opaque); absorb
    the scene's absorbing volumes (core.scene.absorption) or None."""
    mtab: object
    tri_mat: np.ndarray
    tri_uv: np.ndarray
    transparent: np.ndarray
    absorb: object = None


def transparent_materials(mtab) -> np.ndarray:
    """(M,) bool: materials with a Transparent lobe of non-zero weight (a
    Transparent BSDF, a Principled Alpha below 1 or an image alpha cut-out)."""
    return ((mtab.kind == TRANSPARENT) & (mtab.weight != 0.0)).any(axis=1)


def attach(accel, scene, mtab) -> bool:
    """Make ``transmittance`` on ``accel`` see the scene's transparent
    materials (shadow rays each triangle's ``Scene.material_shadow``, camera
    rays its ``material_camera``); nothing (and False) when it has none."""
    from ..scene import ray_variants as RV
    tr = transparent_materials(mtab)
    if not tr.any():
        setattr(accel, _ATTR, None)
        setattr(accel, _ATTR_CAMERA, None)
        return False
    tri = np.asarray(scene.tri_mat, np.int64)
    uv = np.asarray(scene.tri_uv)
    seen = {k: RV.rows(scene, k) for k in ("shadow", "camera")}
    ab = absorption_of(scene)
    sv = ShadowMaterials(mtab, RV.seen(seen["shadow"], tri), uv, tr, ab)
    cv = (sv if seen["shadow"] is None and seen["camera"] is None
          else ShadowMaterials(mtab, RV.seen(seen["camera"], tri), uv, tr, ab))
    setattr(accel, _ATTR, sv)
    setattr(accel, _ATTR_CAMERA, cv)
    return True


def attached(accel, camera: bool = False):
    """The :class:`ShadowMaterials` attached to ``accel`` (or to the scene
    whose ``Accel.for_rays`` view it is) as shadow rays see them (camera:
    as camera rays do), or None."""
    base = getattr(accel, "base", accel)
    return getattr(base, _ATTR_CAMERA if camera else _ATTR, None)


def unit_normals(tri_p: np.ndarray, prim: np.ndarray) -> np.ndarray:
    """(K, 3) float64 unit geometric normals (winding order) of triangles prim (K,)."""
    P = tri_p[prim].astype(np.float64)
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return n


def self_hit(tri_p: np.ndarray, prim: np.ndarray, o: np.ndarray):
    """((K,) bool, (K,) eps): the plane of triangle prim passes within
    eps = 8 REL_OFFSET |vertex|_max of the ray origin o (K, 3).  Embree's
    float32 vertices make such a hit the surface the ray left (see
    ``NextEventEstimation._grazing_self_hit_retry``), not an occluder."""
    P0 = tri_p[prim].astype(np.float64)
    n = unit_normals(tri_p, prim)
    eps = 8.0 * REL_OFFSET * np.abs(P0).max(axis=(1, 2))
    return np.abs(_dot(o - P0[:, 0], n)) < eps, eps


def pass_through(sm: ShadowMaterials, prim: np.ndarray, u: np.ndarray, v: np.ndarray,
                 mu: np.ndarray = None):
    """(K, 3) float64 Cycles' ``closure_transparent_extinction`` at the hits
    (prim, u, v) (K,): the sum of the TRANSPARENT lobes' colours, with their
    mix weights, textures and image alpha (0 on opaque materials), and view
    factors at mu (K,) = |d . n| of the shadow ray (None: 1)."""
    from ..materials import lobe_colors
    out = np.zeros((prim.shape[0], 3))
    mat = sm.tri_mat[prim]
    k = np.nonzero(sm.transparent[mat])[0]
    if k.size:
        UV = sm.tri_uv[prim[k]].astype(np.float64)
        uu, vv = u[k][:, None], v[k][:, None]
        uv = (1.0 - uu - vv) * UV[:, 0] + uu * UV[:, 1] + vv * UV[:, 2]
        cols = lobe_colors(sm.mtab, mat[k], uv, None if mu is None else mu[k])   # (k, L, 3)
        out[k] = (cols * (sm.mtab.kind[mat[k]] == TRANSPARENT)[:, :, None]).sum(axis=1)
    return out


def transmittance(accel, o: np.ndarray, d: np.ndarray, t_max, emitter=None,
                  n0=None, camera: bool = False) -> np.ndarray:
    """(K, 3) float64: the light let through along the segments o + t d,
    t in (0, t_max) (o, d (K, 3); t_max (K,) or a scalar, np.inf allowed):
    0 where an opaque surface lies on the segment, else the product of the
    pass-through weights of the transparent surfaces crossed (module doc).

    emitter (K,) bool or None: the segment ends ON an emissive triangle
    (geometry): a hit within Embree's float32 tolerance of the end, about
    offset / |cos| at grazing angles, is that emitter and ends the segment
    unblocked (``NextEventEstimation._blocked``'s rule).  o must already be
    off the surface it leaves (``Accel.spawn``).  n0 (K, 3) or None: the
    unit geometric normals of the surfaces the segments leave.  A hit on a
    plane parallel to the surface last left (n0, then each crossed one) and
    passing through the current origin is a float32 self-hit (see
    :func:`self_hit`) and is stepped over; an occluder standing on the
    surface (a wall on a floor) is not parallel to it and still blocks.
    camera: the materials as camera rays see them (light tracing's joins to
    the lens), not as shadow rays do (core.scene.ray_variants).
    """
    o = np.asarray(o, np.float64)
    K = o.shape[0]
    t_max = np.broadcast_to(np.asarray(t_max, np.float64), (K,))
    sm = attached(accel, camera)
    if sm is None and (emitter is None or not np.any(emitter)):
        return np.repeat((~accel.occluded(o, d, t_max))[:, None].astype(np.float64), 3, axis=1)
    d = np.asarray(d, np.float64)
    em = np.zeros(K, bool) if emitter is None else np.asarray(emitter, bool)
    T = np.ones((K, 3))
    end = o + d * np.where(np.isfinite(t_max), t_max, 0.0)[:, None]
    end_off = accel.offset_scale(end)
    cur, t_rem = o.copy(), t_max.astype(np.float64).copy()
    live = np.arange(K)
    crossings = np.zeros(K, np.int64)
    n_prev = np.zeros((K, 3)) if n0 is None else np.array(n0, np.float64)
    tri_p = accel.tri_p
    # Each step crosses one surface or steps over one self-hit per ray; the
    # bound only guards against a ray that never leaves a surface.
    for _ in range(2 * MAX_CROSSINGS + 4):
        if live.size == 0:
            break
        e = em[live]
        reach = np.where(e, t_rem[live] * (1 + 1e-6) + end_off[live], t_rem[live])
        h = accel.intersect(cur[live], d[live], reach)
        hit = h.hit
        if e.any() and hit.any():
            # The emitter itself: a hit within the tolerance of the end.
            j = np.nonzero(e & hit)[0]
            dn = d[live[j]] / np.linalg.norm(d[live[j]], axis=1, keepdims=True)
            cos_l = np.abs(_dot(unit_normals(tri_p, h.prim[j]), dn))
            tol = 4.0 * end_off[live[j]] / np.maximum(cos_l, 1e-4)
            hit[j] = h.t[j] < t_rem[live[j]] - tol
        if not hit.any():
            break
        live, hi = live[hit], np.nonzero(hit)[0]
        prim, u, v = h.prim[hi], h.u[hi], h.v[hi]
        sh, eps = self_hit(tri_p, prim, cur[live])
        n = unit_normals(tri_p, prim)
        sh &= np.abs(_dot(n, n_prev[live])) > 1.0 - 1e-6
        p = _surface(tri_p, prim, u, v)
        # Crossed surfaces (not self-hits) weigh in; opaque ones give 0.
        c = np.nonzero(~sh)[0]
        if c.size:
            mu = None
            if sm is not None and getattr(sm.mtab, "view_lut", None) is not None:
                dl = d[live[c]]
                mu = np.abs(_dot(n[c], dl)) / np.linalg.norm(dl, axis=1)
            w = (pass_through(sm, prim[c], u[c], v[c], mu) if sm is not None
                 else np.zeros((c.size, 3)))
            crossings[live[c]] += 1
            w[crossings[live[c]] > MAX_CROSSINGS] = 0.0      # Cycles: too many -> opaque
            T[live[c]] *= w
            if sm is not None and sm.absorb is not None:
                # The segment to a crossing out of an absorbing volume.
                attenuate(sm.absorb, prim[c], h.t[hi[c]], d[live[c]], T, rows=live[c])
        # Continue from just past the surface (a self-hit: from farther off it).
        side = np.where(_dot(n, d[live]) >= 0, 1.0, -1.0)
        off = np.where(sh, np.maximum(eps, accel.offset_scale(p)), accel.offset_scale(p))
        new = p + n * (side * off)[:, None]
        dd = np.einsum("ij,ij->i", d[live], d[live])
        t_rem[live] -= _dot(new - cur[live], d[live]) / dd
        cur[live] = new
        n_prev[live] = n
        go = (T[live].max(axis=1) > 0) & (t_rem[live] > 0)
        live = live[go]
    else:
        T[live] = 0.0       # still crossing after the bound: opaque, as Cycles' cap
    return T


def _surface(tri_p, prim, u, v) -> np.ndarray:
    """(K, 3) float64 points of triangles prim at Embree barycentrics u, v."""
    P = tri_p[prim].astype(np.float64)
    return (1.0 - u - v)[:, None] * P[:, 0] + u[:, None] * P[:, 1] + v[:, None] * P[:, 2]
