"""The reflected flux of the gather's non-Lambert (visible point, photon) pairs, compiled.

``PhotonPass._reflected`` (core.sppm.photon_pass) in one loop over the pairs:
the material's BSDF (``core.materials.compiled.eval_pair``, radiance mode,
with the mesh's normals), Veach's shading-normal factor |wi.ns| / |wi.ng|
capped at 4, the photon's power and the clip's inverse visible fraction,
summed per visible point in pair order in a scratch row and then added to
Phi once: the numpy path's bincount sums, so the same bits up to the BSDF's
own rounding (tests/test_compiled_bsdf.py).
"""
from __future__ import annotations

import numpy as np
from numba import njit

# compiled.eval_pair is compiled into this kernel and numba's cache is
# stamped by this file: edited with the microfacet lobes' geometric side
# test of round 27, with the BSDF evaluation's lobe helpers and reference
# counts of round 32, with the view factor of round 40 and with the
# displacement bump's code of round 45 (F_BUMP 2: no bump shadowing) and
# with the conductor Fresnel of round 46 (F_K, compiled._fresnel_rgb) and
# thin film (F_FILM_D, F_FILM_N), and with the one-signature entry points
# of round 50 (compiled._eval_pair_as).
from ..materials.compiled import _dot3, eval_pair

#: Cap of the gathered photon's shading-normal factor (photon_pass._reflected).
SHADING_CORRECTION_MAX = 4.0


@njit(cache=True, nogil=True, error_model="numpy")
def reflected_flux(S, mat, colors, ns, ng, front, wo, pv, pp, wi, power, icf, Phi, scratch):
    """Phi[pv] += f(wo, wi) |wi.ns|/|wi.ng| power (x icf) over the pairs (K,).

    S: CompiledMaterials; point arrays (P, ...) of VisiblePoints (ns, ng
    flipped to the viewer, front: the mesh's side); pv, pp (K,) int pairs;
    wi, power (N, 3) photon arrays; icf (K,) the clip's inverse visible
    fractions or (0,): none; Phi (P, 3) float64 added to; scratch (P, 3)
    float64 all zero, left all zero."""
    lobes, T = S.lobes, S.tables
    clip = icf.shape[0] > 0
    for i in range(pv.shape[0]):
        q = pv[i]
        e = pp[i]
        sg = 1.0 if front[q] else -1.0
        wx, wy, wz = float(wi[e, 0]), float(wi[e, 1]), float(wi[e, 2])
        nsx, nsy, nsz = float(ns[q, 0]), float(ns[q, 1]), float(ns[q, 2])
        ngx, ngy, ngz = float(ng[q, 0]), float(ng[q, 1]), float(ng[q, 2])
        r = eval_pair(lobes, T, mat[q], colors, q, nsx * sg, nsy * sg, nsz * sg,
                      ngx * sg, ngy * sg, ngz * sg,
                      float(wo[q, 0]), float(wo[q, 1]), float(wo[q, 2]), wx, wy, wz, False)
        # materials.shading_correction (Veach 1997, 5.3), capped
        d = abs(_dot3(ngx, ngy, ngz, wx, wy, wz))
        corr = abs(_dot3(nsx, nsy, nsz, wx, wy, wz)) / d if d > 0 else 0.0
        corr = min(corr, SHADING_CORRECTION_MAX)
        c0 = r[0] * (power[e, 0] * corr)
        c1 = r[1] * (power[e, 1] * corr)
        c2 = r[2] * (power[e, 2] * corr)
        if clip:
            c0 *= icf[i]
            c1 *= icf[i]
            c2 *= icf[i]
        scratch[q, 0] += c0
        scratch[q, 1] += c1
        scratch[q, 2] += c2
    for i in range(pv.shape[0]):
        q = pv[i]
        for c in range(3):
            s = scratch[q, c]
            if s != 0.0 or s != s:
                Phi[q, c] += s
                scratch[q, c] = 0.0


def scratch_rows(P: int) -> np.ndarray:
    """A zeroed (P, 3) float64 scratch for :func:`reflected_flux`."""
    return np.zeros((P, 3))
