"""A tangent-space Normal Map at hits, compiled: the numba twin of
:func:`core.scene.normals.perturb` for a NORMAL_MAP input (Bump stays numpy).

A module of its own, so that the add-on's register() (which imports
``core.scene.normals``) loads no numba.  Used by the camera paths' kernels
(``PathTracer._perturb``), where the numpy perturbation of a normal-mapped
floor was a quarter of a pass of ``example_blends/real_scene.blend``
(docs/integrators.md "A user's HDRI scene in the vertex kernels, round 27").
The numpy code's operations per hit in its order (its norms and sums of
three terms are sequential there too), so the normals agree to rounding
(tests/test_shading_nodes.py).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .texture_kernels import bilinear_rgb, corner_uv


@njit(cache=True, inline="always")
def _safe_unit(x, y, z, fx, fy, fz):
    """normals._safe_unit of one vector: x / |x|, or the fallback below 1e-12."""
    n = np.sqrt(x * x + y * y + z * z)
    if n > 1e-12:
        m = max(n, 1e-300)
        return x / m, y / m, z / m
    return fx, fy, fz


@njit(cache=True, nogil=True, error_model="numpy")
def normal_map(tri_p, tri_n, tri_uv, tri_tangent, prim, bu, bv, rows, ns, img, unassociate,
               strength, directx):
    """ns[rows] (K, 3) perturbed in place as ``normals.perturb`` perturbs the
    hits (prim, bu, bv)[rows] of a material whose Normal input is a
    tangent-space Normal Map of img (H, W, C): tri_p, tri_n (T, 3, 3),
    tri_uv (T, 3, 2), tri_tangent (T, 3, 4) or (0, 3, 4) (none: the
    fallback tangent along dP/du).  A hit whose uvs are degenerate and has
    no MikkTSpace tangent, or whose result is not finite, keeps its normal."""
    has_tt = tri_tangent.shape[0] > 0
    for q in range(rows.shape[0]):
        k = rows[q]
        t = prim[k]
        u, v = bu[k], bv[k]
        w0 = 1.0 - u - v
        nx, ny, nz = ns[k, 0], ns[k, 1], ns[k, 2]
        # Interpolated (unnormalised) normal and uv.
        Nx = w0 * np.float64(tri_n[t, 0, 0]) + u * np.float64(tri_n[t, 1, 0]) + v * np.float64(tri_n[t, 2, 0])
        Ny = w0 * np.float64(tri_n[t, 0, 1]) + u * np.float64(tri_n[t, 1, 1]) + v * np.float64(tri_n[t, 2, 1])
        Nz = w0 * np.float64(tri_n[t, 0, 2]) + u * np.float64(tri_n[t, 1, 2]) + v * np.float64(tri_n[t, 2, 2])
        uu, vv = corner_uv(tri_uv, t, w0, u, v)
        # The fallback tangent (normals._fallback_tangent, triangle_uv_frame).
        p0x, p0y, p0z = np.float64(tri_p[t, 0, 0]), np.float64(tri_p[t, 0, 1]), np.float64(tri_p[t, 0, 2])
        e1x, e1y, e1z = (np.float64(tri_p[t, 1, 0]) - p0x, np.float64(tri_p[t, 1, 1]) - p0y,
                         np.float64(tri_p[t, 1, 2]) - p0z)
        e2x, e2y, e2z = (np.float64(tri_p[t, 2, 0]) - p0x, np.float64(tri_p[t, 2, 1]) - p0y,
                         np.float64(tri_p[t, 2, 2]) - p0z)
        u0, v0 = np.float64(tri_uv[t, 0, 0]), np.float64(tri_uv[t, 0, 1])
        d1u, d1v = np.float64(tri_uv[t, 1, 0]) - u0, np.float64(tri_uv[t, 1, 1]) - v0
        d2u, d2v = np.float64(tri_uv[t, 2, 0]) - u0, np.float64(tri_uv[t, 2, 1]) - v0
        det = d1u * d2v - d1v * d2u
        scale = max(max(abs(d1u), abs(d1v)) * max(abs(d2u), abs(d2v)), 1e-300)
        ok = abs(det) > 1e-9 * scale
        inv = 1.0 / det if ok else 0.0
        dux, duy, duz = (d2v * e1x - d1v * e2x) * inv, (d2v * e1y - d1v * e2y) * inv, \
            (d2v * e1z - d1v * e2z) * inv
        dvx, dvy, dvz = (-d2u * e1x + d1u * e2x) * inv, (-d2u * e1y + d1u * e2y) * inv, \
            (-d2u * e1z + d1u * e2z) * inv
        dn = dux * nx + duy * ny + duz * nz
        Tx, Ty, Tz = _safe_unit(dux - dn * nx, duy - dn * ny, duz - dn * nz, dux, duy, duz)
        cx_, cy_, cz_ = ny * Tz - nz * Ty, nz * Tx - nx * Tz, nx * Ty - ny * Tx
        sign = -1.0 if cx_ * dvx + cy_ * dvy + cz_ * dvz < 0 else 1.0
        if has_tt and tri_tangent[t, 0, 3] != 0.0:
            Tx = (w0 * np.float64(tri_tangent[t, 0, 0]) + u * np.float64(tri_tangent[t, 1, 0])
                  + v * np.float64(tri_tangent[t, 2, 0]))
            Ty = (w0 * np.float64(tri_tangent[t, 0, 1]) + u * np.float64(tri_tangent[t, 1, 1])
                  + v * np.float64(tri_tangent[t, 2, 1]))
            Tz = (w0 * np.float64(tri_tangent[t, 0, 2]) + u * np.float64(tri_tangent[t, 1, 2])
                  + v * np.float64(tri_tangent[t, 2, 2]))
            sign = np.sign(np.float64(tri_tangent[t, 0, 3]))
            ok = True
        if not ok:
            continue
        r, g, b = bilinear_rgb(img, uu, vv, unassociate)
        c0, c1, c2 = 2.0 * r - 1.0, 2.0 * g - 1.0, 2.0 * b - 1.0
        if directx:
            c1 = -c1
        # normals.tangent_space_normal: B = sign (N x T), N' = unit(c0 T + c1 B + c2 N).
        Bx, By, Bz = (sign * (Ny * Tz - Nz * Ty), sign * (Nz * Tx - Nx * Tz),
                      sign * (Nx * Ty - Ny * Tx))
        px, py, pz = _safe_unit(c0 * Tx + c1 * Bx + c2 * Nx, c0 * Ty + c1 * By + c2 * Ny,
                                c0 * Tz + c1 * Bz + c2 * Nz, nx, ny, nz)
        if strength != 1.0:
            kk = max(strength, 0.0)
            px, py, pz = _safe_unit(nx + (px - nx) * kk, ny + (py - ny) * kk,
                                    nz + (pz - nz) * kk, nx, ny, nz)
        if np.isfinite(px) and np.isfinite(py) and np.isfinite(pz):
            ns[k, 0], ns[k, 1], ns[k, 2] = px, py, pz
