"""Lights seen by rays: the analytic emitters a camera, mirror or glass ray hits.

Area lights, point/spot discs or spheres and sun discs are not part of the
triangle geometry, so rays test them here; emissive triangles are found by
the ray's hit, and the world by a ray that escapes (:func:`world_radiance`).
:func:`emitted_along_rays` is the numpy reference; :func:`seen_kernel` the
same tests per ray, compiled, for the camera paths' kernels
(core.integrators.path_tracer), equal to it to rounding
(tests/test_path_kernels.py).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..mathutil import dot as _dot
from .direct_kernels import _nrm3, _spot_atten as _spot_atten_one
from .table import AREA, MESH, POINT, SPOT, SUN, WORLD, LightTable, _spot_atten
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
                # Soft falloff: the cone along the centre's direction to the
                # ray's origin, as next-event estimation evaluates it
                # (sampling.sample_direct).
                aim = -d if table.is_sphere[j] else _normalize(oc)
                att = _spot_atten(table, np.full(K, j), aim)
                L = L * att[:, None]
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


def world_radiance(table: LightTable, d: np.ndarray | None = None) -> np.ndarray:
    """The world's radiance seen by rays that escape.

    d None: (3,) the constant world colour (with an environment map: its mean).
    d (K, 3) unit directions: (K, 3) the radiance along each (the map's
    lookup, or the constant broadcast)."""
    if d is None:
        return table.world.copy()
    d = np.asarray(d, np.float64).reshape(-1, 3)
    if table.environment is not None and table.environment.total > 0:
        return table.environment.radiance(d)
    return np.broadcast_to(table.world, d.shape).copy()


#: The visibility flag arrays of :func:`emitted_along_rays`, by name.
VISIBILITY = ("camera", "glossy", "transmission")


def visibility_flags(table: LightTable) -> np.ndarray:
    """(3, Nl) bool: the emitters' visible_camera, visible_glossy and
    visible_transmission (:data:`VISIBILITY`'s order), for :func:`seen_kernel`."""
    return np.ascontiguousarray(np.stack([table.visible_camera, table.visible_glossy,
                                          table.visible_transmission]).astype(bool))


@njit(cache=True, nogil=True, error_model="numpy")
def seen_kernel(L, flags, vis, o, d, t_max, idx, Le, row, t_hit):
    """:func:`emitted_along_rays` (return_hit) of the rays idx (k,) of o, d
    (K, 3), t_max (K,), each with its visibility code vis (K,) int8 (a row of
    flags (3, Nl): camera, glossy, transmission), the emitters of the
    DirectLights L: the nearest analytic emitter hit before t_max -- area
    lights (front side), point / spot discs facing the ray origin or
    spheres (the spot one-sided, its cone's attenuation), sun discs on rays
    that escape -- written to Le (k, 3), row (k,) (-1: none) and t_hit (k,)
    (inf: none, or the sun).  The numpy function's tests in its order, per
    ray; the same values to rounding (its dot products are BLAS's)."""
    nl = L.kind.shape[0]
    er = L.sel.row
    for q in range(idx.shape[0]):
        i = idx[q]
        f = flags[vis[i]]
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        best = t_max[i]
        Le[q, 0] = Le[q, 1] = Le[q, 2] = 0.0
        row[q] = -1
        t_hit[q] = np.inf
        for j in range(nl):
            k = L.kind[j]
            if not f[j] or k == MESH or k == WORLD:
                continue
            r0, r1, r2 = L.radiance[j, 0], L.radiance[j, 1], L.radiance[j, 2]
            if r0 == 0.0 and r1 == 0.0 and r2 == 0.0:
                continue
            cx, cy, cz = L.co[j, 0], L.co[j, 1], L.co[j, 2]
            if k == AREA:
                nx, ny, nz = L.dir[j, 0], L.dir[j, 1], L.dir[j, 2]
                den = dx * nx + dy * ny + dz * nz
                t = ((cx - ox) * nx + (cy - oy) * ny + (cz - oz) * nz) / den
                if not (np.isfinite(t) and t > 0.0 and t < best and den < 0.0):
                    continue
                qx, qy, qz = ox + t * dx - cx, oy + t * dy - cy, oz + t * dz - cz
                a = 2.0 * (qx * L.axis_u[j, 0] + qy * L.axis_u[j, 1] + qz * L.axis_u[j, 2]) \
                    / L.len_u[j]
                b = 2.0 * (qx * L.axis_v[j, 0] + qy * L.axis_v[j, 1] + qz * L.axis_v[j, 2]) \
                    / L.len_v[j]
                if L.ellipse[j]:
                    if not a * a + b * b <= 1.0:
                        continue
                elif not (abs(a) <= 1.0 and abs(b) <= 1.0):
                    continue
                att = 1.0
            elif k == POINT or k == SPOT:
                r = L.radius[j]
                if r <= 0.0:
                    continue
                px, py, pz = ox - cx, oy - cy, oz - cz
                if L.is_sphere[j]:
                    b = dx * px + dy * py + dz * pz
                    cc = px * px + py * py + pz * pz - r * r
                    disc = b * b - cc
                    sq = np.sqrt(max(disc, 0.0))
                    t0 = -b - sq
                    t = t0 if t0 > 0.0 else -b + sq
                    if not (disc >= 0.0 and t > 0.0 and t < best):
                        continue
                else:
                    # _ray_disc with the disc facing the ray origin.
                    nx, ny, nz = _nrm3(px, py, pz)
                    den = dx * nx + dy * ny + dz * nz
                    t = ((cx - ox) * nx + (cy - oy) * ny + (cz - oz) * nz) / den
                    if not (np.isfinite(t) and t > 0.0 and t < best):
                        continue
                    qx, qy, qz = ox + t * dx - cx, oy + t * dy - cy, oz + t * dz - cz
                    if not qx * qx + qy * qy + qz * qz <= r * r:
                        continue
                att = 1.0
                if k == SPOT:
                    if not dx * px + dy * py + dz * pz < 0.0:
                        continue
                    if L.is_sphere[j]:
                        att = _spot_atten_one(er, j, -dx, -dy, -dz)
                    else:
                        ax, ay, az = _nrm3(px, py, pz)
                        att = _spot_atten_one(er, j, ax, ay, az)
            elif k == SUN:
                if not (L.half_angle[j] > 0.0 and np.isinf(best)
                        and -(dx * L.dir[j, 0] + dy * L.dir[j, 1] + dz * L.dir[j, 2])
                        >= L.cos_half_angle[j]):
                    continue
                # The sun never beats a finite hit; a later finite light would.
                Le[q, 0], Le[q, 1], Le[q, 2] = r0, r1, r2
                row[q] = j
                t_hit[q] = np.inf
                continue
            else:
                continue
            best = t
            Le[q, 0], Le[q, 1], Le[q, 2] = r0 * att, r1 * att, r2 * att
            row[q] = j
            t_hit[q] = t
