"""The visible points' environment map by two strategies, compiled (numba).

Next-event estimation at a visible point (``nee.NextEventEstimation``)
finds an environment map's light twice and weighs the two by the balance
heuristic (Veach 1997, eq. 9.10):

- the light sample (``direct_kernels.direct_kernel``), when it picked the
  map: w_L = p_L / (p_L + p_B), p_L = P(world | x) pdf_map(wi) (the
  selection probability of the world's entry at x, ``pdf_kernels
  .selection_kernel``, times the map's solid-angle density), p_B the
  density with which the BSDF's non-delta lobes sample wi
  (:func:`light_mis_kernel`);
- one BSDF sample of the non-delta lobes (``closures.sample_bsdf(subset=
  'nondelta')``), whose ray to infinity sees the map: w_B = p_B / (p_B +
  p_L) (:func:`bsdf_mis_kernel`).  A rough mirror's reflection of a smooth
  sky is found here, the map's bright texels by the light sample.

Both write ``direct_kernels.DirectSamples`` rows, so their shadow rays take
the light sample's path (``shadow_kernel``, one occlusion call, the grazing
self-hit retry, transparent surfaces).  The numpy code (``nee``'s
``_direct_numpy`` and ``_environment_bsdf``) stays as the reference.

Precision: the BSDF's sample, density and value are ``core.materials
.compiled``'s (equal to numpy's to rounding; the Lambert fast path is
``materials.fast.sample_fast``'s direction with the colours' sum as its
weight, numpy's ``sample_bsdf`` fast path), the map's density and radiance
``environment_kernels``'; a visible point's colours are float32, summed here
in float64 (numpy sums them in float32).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

# compiled.sample_pair is compiled into this module's kernels and numba's
# cache is stamped by this file: edited with the BSDF evaluation's lobe
# helpers and reference counts of round 32, the view factor of round 40 and
# the displacement bump's code of round 45 (F_BUMP 2: no bump shadowing)
# and the conductor Fresnel of round 46 (F_K, compiled._fresnel_rgb) and
# thin film (F_FILM_D, F_FILM_N), and the one-signature entry points of
# round 50 (compiled._sample_pair).
from ..materials.compiled import SelectionTable, pdf_oriented, sample_pair, selection_rows
from ..materials.fast import LAMBERT, sample_fast
from ..sppm.photon_kernels import lambert_pdf
from .environment_kernels import map_pdf, map_radiance, texture_vector
from .table import WORLD


class MapMaterials(NamedTuple):
    """The BSDFs of the visible points' materials (M materials): lobes,
    tables a ``compiled.CompiledMaterials``' arrays; fast (M,) bool numpy
    ``sample_bsdf``'s Lambert fast path (Lambert lobes only, no delta lobe,
    no Normal Map / Bump: ``MaterialTable.lambert_only``; the weight is the
    sum of the colours).  Every other material is ``compiled.sample_pair``'s
    in radiance mode (which applies Cycles' valid specular normal)."""
    lobes: np.ndarray
    tables: np.ndarray
    fast: np.ndarray


class MapReceivers(NamedTuple):
    """K visible points: q (K,) int64 their pixels; per pixel (P rows) p, ng
    (P, 3) float64, ns, wo (P, 3) float32 (``VisiblePoints``: ng and ns
    oriented to wo), front (P,) bool wo on the mesh normal's side, mat (P,)
    integer, beta (P, 3) float32; sel (K,) float64 the probability that the
    light sample picks the world at p[q] (``pdf_kernels.selection_kernel``);
    rows: their lobe colours and non-delta selection, row k for point k
    (``compiled.selection_rows``)."""
    q: np.ndarray
    p: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    wo: np.ndarray
    front: np.ndarray
    mat: np.ndarray
    beta: np.ndarray
    sel: np.ndarray
    rows: SelectionTable


def map_materials(mtab, cm) -> MapMaterials:
    """The :class:`MapMaterials` of a ``MaterialTable`` (cm its
    ``compiled.CompiledMaterials``)."""
    fast = np.asarray(mtab.lambert_only, bool) & ~np.asarray(mtab.has_delta, bool)
    return MapMaterials(np.ascontiguousarray(cm.lobes, np.float64),
                        np.ascontiguousarray(cm.tables, np.float64), fast)


def map_receivers(mtab, vp, q, sel) -> MapReceivers:
    """The :class:`MapReceivers` of the visible points q (K,) of ``vp``
    (``sppm.visible_points.VisiblePoints``); sel (K,) as there."""
    mat = vp.mat[q].astype(np.int64)
    rows = selection_rows(mtab, mat, vp.colors[q].astype(np.float64), "nondelta")
    return MapReceivers(q, vp.p, vp.ng, vp.ns, vp.wo, vp.front, vp.mat, vp.beta, sel, rows)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _finite(x):
    """x, or 0 where it is not finite (``pdf_direct``'s rule for p_L)."""
    return x if np.isfinite(x) else 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def light_mis_kernel(E, X, V, S):
    """S.contrib[k] *= p_L / (p_L + p_B) for the light samples S
    (``DirectSamples``, rows of V) that picked the map E (kind WORLD);
    p_B by ``compiled.pdf_oriented`` with V.rows' non-delta selection
    (``closures.pdf_bsdf(subset='nondelta')``) at the mesh's normals."""
    lobes, sp = X.lobes, V.rows.p
    for k in range(V.q.shape[0]):
        if S.kind[k] != WORLD:
            continue
        i = V.q[k]
        s = 1.0 if V.front[i] else -1.0
        wx, wy, wz = S.wi[k, 0], S.wi[k, 1], S.wi[k, 2]
        cx, cy, cz, nt = texture_vector(E, wx, wy, wz)
        pl = _finite(V.sel[k] * map_pdf(E, cx, cy, cz, nt))
        pb = pdf_oriented(lobes, sp, V.mat[i], k, V.ns[i, 0] * s, V.ns[i, 1] * s,
                          V.ns[i, 2] * s, V.ng[i, 0] * s, V.ng[i, 1] * s, V.ng[i, 2] * s,
                          V.wo[i, 0], V.wo[i, 1], V.wo[i, 2], wx, wy, wz)
        f = pl / max(pl + pb, 1e-300)
        S.contrib[k, 0] *= f
        S.contrib[k, 1] *= f
        S.contrib[k, 2] *= f


@njit(cache=True, nogil=True, error_model="numpy")
def bsdf_mis_kernel(E, X, V, u, S):
    """One BSDF sample of the non-delta lobes per row of V (uniforms u (K, 3):
    direction, lobe), towards the map E: S (``DirectSamples``, K rows) gets
    wi, dist inf, kind WORLD, a shadow ray, and contrib = beta f |cos| / p_B
    L_map(wi) p_B / (p_B + p_L) (0 for an invalid or delta sample, or none
    of positive finite weight: ``nee._environment_bsdf``)."""
    lobes, T = X.lobes, X.tables
    C = V.rows
    nl = C.colors.shape[1]
    for k in range(V.q.shape[0]):
        i = V.q[k]
        m = V.mat[i]
        S.kind[k] = WORLD
        S.shadow[k] = True
        S.light[k] = -1
        S.dist[k] = np.inf
        S.cos[k] = 0.0
        S.weight[k, 0] = S.weight[k, 1] = S.weight[k, 2] = 0.0
        S.contrib[k, 0] = S.contrib[k, 1] = S.contrib[k, 2] = 0.0
        s = 1.0 if V.front[i] else -1.0
        sx, sy, sz = V.ns[i, 0] * s, V.ns[i, 1] * s, V.ns[i, 2] * s
        gx, gy, gz = V.ng[i, 0] * s, V.ng[i, 1] * s, V.ng[i, 2] * s
        ox, oy, oz = V.wo[i, 0], V.wo[i, 1], V.wo[i, 2]
        if X.fast[m]:
            c0 = c1 = c2 = 0.0
            for j in range(nl):
                c0 += C.colors[k, j, 0]
                c1 += C.colors[k, j, 1]
                c2 += C.colors[k, j, 2]
            r = sample_fast(LAMBERT, c0, c1, c2, 1.0, sx, sy, sz, gx, gy, gz, ox, oy, oz,
                            u[k, 0], u[k, 1], u[k, 2])
            if not r[7]:
                continue
            wx, wy, wz = r[0], r[1], r[2]
            w0, w1, w2 = c0, c1, c2
            pdf = lambert_pdf(sx, sy, sz, gx, gy, gz, ox, oy, oz, wx, wy, wz)
        else:
            r = sample_pair(lobes, T, C.colors, C.p, C.cdf, C.last, m, k, sx, sy, sz,
                            gx, gy, gz, ox, oy, oz, u[k, 0], u[k, 1], u[k, 2], True)
            if not r[7] or r[6]:
                continue
            wx, wy, wz = r[0], r[1], r[2]
            w0, w1, w2 = r[3], r[4], r[5]
            pdf = r[8]
        if not (pdf > 0.0 and np.isfinite(w0) and np.isfinite(w1) and np.isfinite(w2)
                and max(w0, w1, w2) > 0.0):
            continue
        cx, cy, cz, nt = texture_vector(E, wx, wy, wz)
        pl = _finite(V.sel[k] * map_pdf(E, cx, cy, cz, nt))
        l0, l1, l2 = map_radiance(E, cx, cy, cz, nt)
        f = pdf / (pdf + pl)
        S.wi[k, 0], S.wi[k, 1], S.wi[k, 2] = wx, wy, wz
        S.weight[k, 0], S.weight[k, 1], S.weight[k, 2] = w0, w1, w2
        S.contrib[k, 0] = V.beta[i, 0] * w0 * l0 * f
        S.contrib[k, 1] = V.beta[i, 1] * w1 * l1 * f
        S.contrib[k, 2] = V.beta[i, 2] * w2 * l2 * f
