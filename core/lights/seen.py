"""Lights seen by rays: the analytic emitters a camera, mirror or glass ray hits.

Area lights, point/spot discs or spheres and sun discs are not part of the
triangle geometry, so rays test them here; emissive triangles are found by
the ray's hit, and the world by a ray that escapes (:func:`world_radiance`).
:func:`emitted_along_rays` is the numpy reference;
``seen_kernels.seen_kernel`` the same tests per ray, compiled, for the
camera paths' kernels (core.integrators.path_tracer), equal to it to
rounding (tests/test_path_kernels.py).
"""
from __future__ import annotations

import numpy as np

from ..mathutil import dot as _dot
from .table import AREA, MESH, POINT, SPOT, SUN, WORLD, LightTable, _spot_atten, spread_atten
from . import ies as IES
from .warps import _normalize


def _ray_disc(o, d, c, n, r, t_max):
    """Hit distance of rays with discs (centre c, unit normal n, radius r), inf on miss."""
    den = _dot(d, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _dot(c - o, n) / den
    hit = np.isfinite(t) & (t > 0) & (t < t_max)
    q = o + np.where(hit, t, 0.0)[:, None] * d - c
    hit &= np.sum(q * q, axis=1) <= r * r
    return np.where(hit, t, np.inf)


def emitted_along_rays(table: LightTable, o: np.ndarray, d: np.ndarray, t_max: np.ndarray,
                       visibility: str = "camera", return_hit: bool = False):
    """Radiance (K, 3) of analytic emitters hit by rays o + t d, 0 < t < t_max.

    Area lights (front side only), point/spot lights with radius > 0 (Cycles'
    disc facing the ray origin, or the sphere without soft falloff) and, for
    rays that escape (t_max = inf), the disc of a sun with angle > 0.  The
    nearest light hit wins; lights whose ``visible_<visibility>`` flag is off
    are skipped.  Mesh emission and the world are not included.
    visibility: 'camera', 'glossy' or 'transmission'.
    return_hit=True: returns (radiance, light (K,) int64 emitter row hit or
    -1, t (K,) its distance, inf for the sun) for multiple importance sampling.
    """
    o = np.asarray(o, np.float64).reshape(-1, 3)
    d = np.asarray(d, np.float64).reshape(-1, 3)
    K = o.shape[0]
    t_max = np.broadcast_to(np.asarray(t_max, np.float64), (K,))
    Lout = np.zeros((K, 3))
    row = np.full(K, -1, np.int64)
    t_hit = np.full(K, np.inf)

    def result():
        return (Lout, row, t_hit) if return_hit else Lout
    if K == 0 or table.n == 0:
        return result()
    flags = {"camera": table.visible_camera, "glossy": table.visible_glossy,
             "transmission": table.visible_transmission}
    if visibility not in flags:
        raise ValueError(f"visibility must be 'camera', 'glossy' or 'transmission', "
                         f"not {visibility!r}")
    flag = flags[visibility]
    best = t_max.copy()
    for j in np.nonzero(flag & (table.kind != MESH) & (table.kind != WORLD))[0]:
        k = table.kind[j]
        if not np.any(table.radiance[j] != 0):
            continue
        if k == AREA:
            n = table.dir[j]
            den = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((table.co[j] - o) @ n) / den
            # Front side: the ray travels against the emission direction.
            hit = np.isfinite(t) & (t > 0) & (t < best) & (den < 0)
            q = o + np.where(hit, t, 0.0)[:, None] * d - table.co[j]
            a = 2.0 * (q @ table.axis_u[j]) / table.len_u[j]
            b = 2.0 * (q @ table.axis_v[j]) / table.len_v[j]
            if table.ellipse[j]:
                hit &= a * a + b * b <= 1.0
            else:
                hit &= (np.abs(a) <= 1.0) & (np.abs(b) <= 1.0)
            L = np.broadcast_to(table.radiance[j], (K, 3))
            if np.isfinite(table.spread_tan[j]):
                L = L * spread_atten(table, np.full(K, j), -den)[:, None]
        elif k in (POINT, SPOT):
            r = table.radius[j]
            if r <= 0:
                continue
            c = table.co[j]
            oc = o - c
            if table.is_sphere[j]:
                b = _dot(d, oc)
                cc = np.sum(oc * oc, axis=1) - r * r
                disc = b * b - cc
                sq = np.sqrt(np.maximum(disc, 0.0))
                t0 = -b - sq
                t = np.where(t0 > 0, t0, -b + sq)
                hit = (disc >= 0) & (t > 0) & (t < best)
            else:
                n = _normalize(oc)
                t = _ray_disc(o, d, np.broadcast_to(c, (K, 3)), n, r, best)
                hit = np.isfinite(t)
            L = np.broadcast_to(table.radiance[j], (K, 3))
            if k == SPOT:
                hit &= _dot(d, oc) < 0                # Cycles: one-sided spot disc
                # The cone along the ray, as Cycles reads it.
                att = _spot_atten(table, np.full(K, j), -d)
                L = L * att[:, None]
            if table.ies.shape[0]:
                # An IES profile along the direction leaving the light.
                L = L * IES.factors(table.ies, j, -d)[:, None]
        elif k == SUN:
            if table.half_angle[j] <= 0:
                continue
            t = np.full(K, np.inf)
            hit = np.isinf(best) & ((-d @ table.dir[j]) >= table.cos_half_angle[j])
            L = np.broadcast_to(table.radiance[j], (K, 3))
            # The sun never beats a finite hit; a later finite light would.
            Lout[hit] = L[hit]
            row[hit] = j
            t_hit[hit] = np.inf
            continue
        else:
            continue
        best = np.where(hit, t, best)
        Lout[hit] = L[hit]
        row[hit] = j
        t_hit[hit] = t[hit]
    return result()


def world_radiance(table: LightTable, d: np.ndarray | None = None,
                   camera: bool = False) -> np.ndarray:
    """The world's radiance seen by rays that escape.

    d None: (3,) the constant world colour (with an environment map: its mean).
    d (K, 3) unit directions: (K, 3) the radiance along each (the map's
    lookup, or the constant broadcast).  camera: the rays are on the camera
    ray's line, and see ``table.camera_environment`` when there is one."""
    if d is None:
        return table.world.copy()
    d = np.asarray(d, np.float64).reshape(-1, 3)
    if camera and table.camera_environment is not None:
        return table.camera_environment.radiance(d)
    if table.environment is not None and table.environment.total > 0:
        return table.environment.radiance(d)
    return np.broadcast_to(table.world, d.shape).copy()


def world_seen_by(table: LightTable) -> np.ndarray:
    """(3,) float64 whether the world is seen by rays of each visibility
    code (:data:`VISIBILITY`: camera 1, a mirror's or a glass's reflection
    and transmission by its Glossy and Transmission visibility), for the
    rays a delta vertex or the lens leaves (after a rough vertex the
    world's light is weighed by ``pdf.samples_only``)."""
    w = np.nonzero(table.kind == WORLD)[0]
    if w.size == 0:
        return np.ones(3)
    return np.array([1.0, float(table.visible_glossy[w[0]]),
                     float(table.visible_transmission[w[0]])])


#: The visibility flag arrays of :func:`emitted_along_rays`, by name.
VISIBILITY = ("camera", "glossy", "transmission")


def visibility_flags(table: LightTable) -> np.ndarray:
    """(3, Nl) bool: the emitters' visible_camera, visible_glossy and
    visible_transmission (:data:`VISIBILITY`'s order), for ``seen_kernels.seen_kernel``."""
    return np.ascontiguousarray(np.stack([table.visible_camera, table.visible_glossy,
                                          table.visible_transmission]).astype(bool))
