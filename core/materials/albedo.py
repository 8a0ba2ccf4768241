"""The albedo of each kind of closure at a shading point: Cycles'
``surface_shader_diffuse / _glossy / _transmission``, which sum
``bsdf_albedo`` over the closures of a kind (kernel/integrator/
surface_shader.h, kernel/closure/bsdf.h) and feed the Diffuse, Glossy and
Transmission Color passes.

bsdf_albedo is a closure's weight, times for a microfacet closure the
estimate ``bsdf_microfacet_estimate_albedo`` of its Fresnel over the
visible normals for the view cosine mu:

- no Fresnel (Glossy BSDF, Refraction BSDF): 1 (the colour is the weight);
- a dielectric (Glass BSDF, the Principled specular layer and its
  transmission): F = mix(f0, 1, s), s the ggx_gen_schlick_ior_s table at
  (roughness, mu, z(ior)) (``multiscatter.schlick_s``); the reflection
  gets F, the transmission 1 - F;
- an F82-tint metal: mix(F0, 1, s), s the ggx_gen_schlick_s table at
  exponent 5 (``multiscatter.schlick5_s``).

Multiscatter GGX lobes carry the darkening part of Cycles' energy-preserving
factor in their weight, E + F_ms (1 - E) (``microfacet_ggx_preserve_energy``;
the rest is an energy scale outside it), so their albedo does too; a
diffuse lobe under a Principled specular layer carries that layer's
1 - albedo (``closure_layering_weight``, ``multiscatter.layer_transmission``).
Cycles counts Diffuse, Oren-Nayar, Translucent and subsurface as diffuse;
GGX reflection and a glass's reflection as glossy; refraction and a glass's
transmission as transmission.  Transparent BSDFs are none of them.
"""
from __future__ import annotations

import numpy as np

from ..scene.model import DIFFUSE, GLASS, GLOSSY, REFRACTION, TRANSLUCENT
from .microfacet import (FRESNEL_CONDUCTOR, FRESNEL_DIELECTRIC, FRESNEL_F82, _principled_fresnel,
                         f0_from_ior)
from .multiscatter import layer_transmission, multiscatter_darkening, schlick5_s, schlick_s
from .table import MaterialTable, fresnel_params, seen_weight

#: The kinds of closure albedo, in the order :func:`closure_albedos` returns them.
ALBEDO_KINDS = ("diffuse", "glossy", "transmission")


def closure_albedos(table: MaterialTable, mat: np.ndarray, colors: np.ndarray, mu: np.ndarray,
                    front: np.ndarray) -> np.ndarray:
    """(3, K, 3) float64: the diffuse, glossy and transmission albedos of
    materials mat (K,) int with lobe colours colors (K, L, 3)
    (``lobe_colors`` at the points, view factor at mu), mu (K,) = |w_o . n_s|
    the view cosine, front (K,) bool the view on the front side (a glass's
    relative ior is ior there, 1/ior behind)."""
    mat = np.asarray(mat, np.int64)
    mu = np.clip(np.asarray(mu, np.float64), 0.0, 1.0)
    K = mat.size
    out = np.zeros((3, K, 3))
    kinds = table.kind[mat]
    for j in range(kinds.shape[1]):
        for k in np.unique(kinds[:, j]):
            if k not in (DIFFUSE, TRANSLUCENT, GLOSSY, GLASS, REFRACTION):
                continue
            idx = np.nonzero(kinds[:, j] == k)[0]
            mj, col, m = mat[idx], colors[idx, j], mu[idx]
            if k == TRANSLUCENT:
                out[0, idx] += col
                continue
            if k == REFRACTION:
                out[2, idx] += col
                continue
            if k == DIFFUSE:
                a = col.copy()
                if table.layer_ior is not None:
                    lay = np.nonzero(table.layer_ior[mj, j] > 0)[0]
                    if lay.size:
                        ml = mj[lay]
                        a[lay] *= layer_transmission(
                            table.layer_f0[ml, j], table.layer_roughness[ml, j],
                            table.layer_ior[ml, j], m[lay], table.layer_ms[ml, j],
                            None if table.thin_film is None else table.thin_film[ml, j])[:, None]
                out[0, idx] += a
                continue
            rough = table.roughness[mj, j]
            w = seen_weight(table, mj, j, m)[:, None]
            ucol = np.where(w != 0.0, col / np.where(w != 0.0, w, 1.0), 0.0)
            ms = (np.zeros(idx.size, bool) if table.multiscatter is None
                  else table.multiscatter[mj, j])
            fss = ucol
            if k == GLASS:
                ior = table.ior[mj, j]
                F = (f0_from_ior(ior) + (1.0 - f0_from_ior(ior)) * schlick_s(rough, m, ior))[:, None]
                a_r, a_t = col * F, col * (1.0 - F)
            else:
                a_r, a_t = col.copy(), None
                if table.fresnel is None:
                    mode = np.zeros(idx.size, np.int8)
                else:
                    mode, fiors, tints, exts, films = fresnel_params(table, mj, j)
                for fm in (FRESNEL_DIELECTRIC, FRESNEL_F82, FRESNEL_CONDUCTOR):
                    q = np.nonzero(mode == fm)[0]
                    if q.size == 0:
                        continue
                    fior, tint = fiors[q], tints[q]
                    # The Principled layer's colour is its F0 tint: the
                    # Fresnel estimate replaces it; the mix weight stays.
                    F_q, fss_q = _principled_fresnel(fm, ucol[q], fior, tint, m[q], exts[q],
                                                     films[q])
                    fss = fss.copy() if fss is ucol else fss
                    fss[q] = fss_q
                    # No table in Cycles for a conductor or a film: the
                    # Fresnel at the view (bsdf_microfacet_estimate_albedo's
                    # last case); the others from the tables below.
                    at_view = (films[q, 0] > 0.0) | (fm == FRESNEL_CONDUCTOR)
                    a_r[q[at_view]] = w[q[at_view]] * F_q[at_view]
                    q = q[~at_view]
                    if q.size == 0:
                        continue
                    fior, tint = fiors[q], tints[q]
                    if fm == FRESNEL_DIELECTRIC:
                        f0 = np.clip(f0_from_ior(fior)[:, None] * ucol[q], 0.0, 1.0)
                        s = schlick_s(rough[q], m[q], fior)[:, None]
                    else:
                        f0 = np.clip(ucol[q], 0.0, 1.0)
                        s = schlick5_s(rough[q], m[q])[:, None]
                    a_r[q] = w[q] * (f0 + (1.0 - f0) * s)
            if ms.any():
                eta = np.where(front[idx], table.ior[mj, j], 1.0 / table.ior[mj, j])
                f = multiscatter_darkening(k, fss[ms], rough[ms], eta[ms], m[ms])
                a_r[ms] *= f
                if a_t is not None:
                    a_t[ms] *= f
            out[1, idx] += a_r
            if a_t is not None:
                out[2, idx] += a_t
    return out
