"""Compiled update of the light side's MIS ratios (core.integrators.mis) per scattering.

After each bounce of the photon kernels (core.sppm.photon_kernels, hit
records on), survivor j continues from ray i = nxt_src[j] along wn[j].  For
Lambert materials (core.materials.fast LAMBERT: diffuse lobes only, no
texture) and delta samples the densities are closed forms here, equal to
core.materials.pdf_bsdf's (DIFFUSE: max(N.wi, 0) / pi where Ng.wi > 0, the
normals flipped to wo's side of Ng; the lobe selection probabilities sum to
one); every other material is flagged for pdf_bsdf in numpy.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..materials.fast import LAMBERT
from ..sppm.photon_kernels import shading_normal

_INV_PI = 1.0 / np.pi


@njit(cache=True, nogil=True, error_model="numpy")
def _lambert_pdf(sx, sy, sz, gx, gy, gz, ox, oy, oz, ix, iy, iz):
    s = 1.0 if gx * ox + gy * oy + gz * oz >= 0.0 else -1.0
    if s * (gx * ix + gy * iy + gz * iz) <= 0.0:
        return 0.0
    return max(s * (sx * ix + sy * iy + sz * iz), 0.0) * _INV_PI


@njit(cache=True, nogil=True, error_model="numpy")
def scatter_ratios(n_next, nxt_src, nxt_delta, wn, prim, bu, bv, d_old, tri_n, tri_ng, tri_mat,
                   m_cls, B0, B1, first, out0, out1, generic):
    """out0, out1 (n_next,): B0 and B1 of survivor j times what leaving its
    vertex adds (core.integrators.combined.scatter_factors: pr |cos| / pl,
    B1 without pr at the first vertex and 0 after a delta there), still to be
    divided by |cos| on arrival.  generic[j] = True where the material needs
    pdf_bsdf (out0, out1 are then left for the caller)."""
    for j in range(n_next):
        i = nxt_src[j]
        t = prim[i]
        gx, gy, gz = tri_ng[t, 0], tri_ng[t, 1], tri_ng[t, 2]
        wx, wy, wz = wn[j, 0], wn[j, 1], wn[j, 2]
        cos_out = abs(gx * wx + gy * wy + gz * wz)
        delta = nxt_delta[j]
        generic[j] = False
        if delta:
            pl = 1.0
            pr = 1.0
        else:
            if m_cls[tri_mat[t]] != LAMBERT:
                generic[j] = True
                continue
            uu = np.float64(bu[i])
            vv = np.float64(bv[i])
            sx, sy, sz = shading_normal(tri_n, t, 1.0 - uu - vv, uu, vv, gx, gy, gz)
            ox, oy, oz = -d_old[i, 0], -d_old[i, 1], -d_old[i, 2]
            pl = _lambert_pdf(sx, sy, sz, gx, gy, gz, ox, oy, oz, wx, wy, wz)
            pr = _lambert_pdf(sx, sy, sz, gx, gy, gz, wx, wy, wz, ox, oy, oz)
        pend1 = cos_out / pl if pl > 0.0 else 0.0
        pend = pr * pend1
        out0[j] = B0[i] * pend
        if first:
            out1[j] = 0.0 if delta else B1[i] * pend1
        else:
            out1[j] = B1[i] * pend
