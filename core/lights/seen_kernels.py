"""The analytic emitters a ray sees, compiled (core.lights.seen's
:func:`emitted_along_rays` per ray, for the camera paths' kernels).  A
module of its own, so that importing core.lights (the add-on's register()
does) loads no numba.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .direct_kernels import _nrm3, _spot_atten as _spot_atten_one
from .ies_kernels import ies_factor
from .table import AREA, MESH, POINT, SPOT, SUN, WORLD
from .warp_kernels import spread_atten


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
                att = spread_atten(L.spread_tan[j], L.spread_norm[j], -den)   # 1 at 180 deg
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
                    att = _spot_atten_one(er, j, -dx, -dy, -dz)
                if L.ies.shape[0]:
                    # An IES profile along the direction leaving the light.
                    att *= ies_factor(L.ies, j, -dx, -dy, -dz)
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
