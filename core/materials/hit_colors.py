"""A textured hit's lobe colours and lobe selection, compiled.

Blender's Image Texture into a Base Color (or any lobe's colour) makes a
material's lobe colours vary per hit: numpy computes them with
``table.lobe_colors`` at the hit's uv and picks a lobe by
``table._selection_probs``.  The compiled samplers (``compiled.sample_pair``,
``pdf_oriented``, ``eval_pair``) read colours and selection from a
``compiled.SelectionTable`` at a row ``r`` beside the material ``m``; this
module appends one such row per textured hit (:func:`hit_rows`), as numpy
makes it, in one loop (:func:`hit_colors_kernel`).  Its users: the camera
paths' vertex kernels (core.integrators.path_kernels.with_hit_colors) and
the photon tracer's generic hits (core.sppm.photons).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..mathutil import LUM_B, LUM_G, LUM_R
from ..scene.model import VIEW_SAMPLES
from ..scene.texture_kernels import TextureList, bilinear_rgb, corner_uv, texture_list
# compiled.sample_pair is compiled into this module's kernel and numba's cache
# is stamped by this file: edited with the BSDF evaluation's lobe helpers and
# reference counts of round 32, and the displacement bump's code of round 45
# (F_BUMP 2: no bump shadowing), and the conductor Fresnel of round 46 (F_K,
# compiled._fresnel_rgb) and thin film (F_FILM_D, F_FILM_N), and the
# one-signature entry points of round 50 (compiled._sample_pair).
from .compiled import SelectionTable, sample_pair


class ColorInputs(NamedTuple):
    """What a textured hit's colour row is made of (M materials, L slots):
    color (M, L, 3) float64, weight, sel_scale (M, L) float64 (ones when the
    table has none), kind, tex (M, L) int64 (``MaterialTable``'s); lambert
    (M,) bool the materials whose sample weight is the sum of the colours
    (the camera paths' Lambert class); tri_uv (T, 3, 2) the corner uvs;
    textures the table's ``TextureList`` (:func:`table_textures`)."""
    color: np.ndarray
    weight: np.ndarray
    sel_scale: np.ndarray
    kind: np.ndarray
    tex: np.ndarray
    lambert: np.ndarray
    tri_uv: np.ndarray
    textures: TextureList
    view_lut: np.ndarray
    view_tab: np.ndarray


def textured_materials(mtab) -> np.ndarray:
    """(M,) bool: the materials with a colour texture on a lobe, or a lobe
    whose weight depends on the view (their lobe colours vary per hit:
    ``materials.lobe_colors`` at the hit's uv and view)."""
    from .table import view_dependent
    return (np.any((np.asarray(mtab.tex) >= 0) & (np.asarray(mtab.kind) >= 0), axis=1)
            | view_dependent(mtab))


def table_textures(mtab) -> TextureList:
    """The ``TextureList`` of a MaterialTable's textures, made once and kept
    on the table (the camera paths, the photon tracer and light tracing
    share it; its images are the table's own arrays, not copies)."""
    tl = getattr(mtab, "_texture_list", None)
    if tl is None:
        tl = texture_list(mtab.textures)
        try:
            mtab._texture_list = tl
        except AttributeError:
            pass
    return tl


def textured_lambert(mtab) -> np.ndarray:
    """(M,) bool: the colour-textured materials sampled as Lambert (numpy
    sample_bsdf's fast path: Lambert lobes only, no delta lobe, no Normal
    Map / Bump; the weight the sum of the hit's colours), by the camera
    paths' kernels and light tracing's splat alike."""
    return (textured_materials(mtab) & np.asarray(mtab.lambert_only, bool)
            & ~np.asarray(mtab.has_delta, bool))


def build_color_inputs(mtab, tri_uv, lambert=None) -> ColorInputs:
    """The :class:`ColorInputs` of a ``MaterialTable`` and its scene's corner
    uvs; lambert (M,) bool (default: none)."""
    c = np.ascontiguousarray
    M, L = mtab.kind.shape
    sel = mtab.sel_scale if mtab.sel_scale is not None else np.ones((M, L))
    lam = np.zeros(M, bool) if lambert is None else np.asarray(lambert, bool)
    vl = getattr(mtab, "view_lut", None)
    return ColorInputs(color=c(mtab.color, np.float64), weight=c(mtab.weight, np.float64),
                       sel_scale=c(sel, np.float64), kind=c(mtab.kind, np.int64),
                       tex=c(mtab.tex, np.int64), lambert=c(lam), tri_uv=c(tri_uv),
                       textures=table_textures(mtab),
                       view_lut=c(np.full((M, L), -1) if vl is None else vl, np.int64),
                       view_tab=c(np.ones((1, VIEW_SAMPLES)) if vl is None
                                  else np.asarray(mtab.view_tab), np.float64))


def hit_rows(X: ColorInputs, base: SelectionTable, prim, bu, bv, mat, mu=None):
    """(SelectionTable, col (K, 3), rows (K,) int64): base's R rows, then one
    row per hit (prim, bu, bv) (K,) on materials mat (K,) int64, which takes
    row R + k (:func:`hit_colors_kernel`); col the hits' sample weights.
    mu (K,) |w_o . n_s| at the hits (view-dependent lobes), None: 1."""
    R, L = base.p.shape
    K = mat.shape[0]
    colors, p = np.empty((R + K, L, 3)), np.empty((R + K, L))
    cdf, last = np.empty((R + K, L)), np.empty(R + K, np.int64)
    colors[:R], p[:R], cdf[:R], last[:R] = base.colors, base.p, base.cdf, base.last
    col = np.empty((K, 3))
    mu = np.ones(K) if mu is None else np.ascontiguousarray(mu, np.float64)
    hit_colors_kernel(X, np.ascontiguousarray(prim, np.int64), np.ascontiguousarray(bu),
                      np.ascontiguousarray(bv), mu, np.ascontiguousarray(mat, np.int64), R,
                      colors, p, cdf, last, col)
    return SelectionTable(colors, p, cdf, last), col, np.arange(R, R + K, dtype=np.int64)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _view_at(tab, row, mu):
    """``table.view_factor`` of one view-factor row at mu."""
    S = tab.shape[1]
    x = min(max(mu, 0.0), 1.0) * (S - 1)
    i = min(int(x), S - 2)
    f = x - i
    return tab[row, i] * (1.0 - f) + tab[row, i + 1] * f


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _colour_row(X, m, t, b1, b2, mu, r, colors, p, cdf, last, cur, img):
    """Row r of colors, p, cdf, last for a hit at barycentrics (b1, b2) of
    triangle t on material m, mu = |w_o . n_s| there (:func:`hit_colors_kernel`'s
    rule); returns the sum of its colours and (cur, img) the texture last
    read and its image (a typed list's item costs a reference count; a
    hit's lobes and the next hits mostly share one)."""
    L = colors.shape[1]
    uu, vv = corner_uv(X.tri_uv, t, 1.0 - b1 - b2, b1, b2)
    tot = 0.0
    s0 = s1 = s2 = 0.0
    for j in range(L):
        c0 = X.color[m, j, 0] * X.weight[m, j]
        c1 = X.color[m, j, 1] * X.weight[m, j]
        c2 = X.color[m, j, 2] * X.weight[m, j]
        if X.kind[m, j] < 0:
            c0 = c1 = c2 = 0.0
        elif X.tex[m, j] >= 0:
            tj = X.tex[m, j]
            if tj != cur:
                img = X.textures.images[tj]
                cur = tj
            a0, a1, a2 = bilinear_rgb(img, uu, vv, X.textures.unassociate[tj],
                                      X.textures.sampler[tj])
            c0, c1, c2 = c0 * a0, c1 * a1, c2 * a2
        if X.view_lut[m, j] >= 0 and X.kind[m, j] >= 0:
            v = _view_at(X.view_tab, X.view_lut[m, j], mu)
            c0, c1, c2 = c0 * v, c1 * v, c2 * v
        colors[r, j, 0], colors[r, j, 1], colors[r, j, 2] = c0, c1, c2
        s0, s1, s2 = s0 + c0, s1 + c1, s2 + c2
        w = max(c0 * LUM_R + c1 * LUM_G + c2 * LUM_B, 0.0) * X.sel_scale[m, j]
        if X.kind[m, j] < 0:
            w = 0.0
        p[r, j] = w
        tot += w
    acc = 0.0
    for j in range(L):
        p[r, j] = p[r, j] / tot if tot > 0 else 0.0
        acc += p[r, j]
        cdf[r, j] = acc
    last[r] = L - 1
    for j in range(L - 1, -1, -1):
        if p[r, j] > 0.0:
            last[r] = j
            break
    return s0, s1, s2, cur, img


@njit(cache=True, nogil=True, error_model="numpy")
def hit_colors_kernel(X, prim, bu, bv, mu, mat, R, colors, p, cdf, last, col):
    """Rows R + k of colors (., L, 3), p, cdf (., L), last (.,) and col[k]
    (K, 3) for the hits k (prim, bu, bv, mat (K,)) as numpy makes them: the
    lobe colours ``table.lobe_colors`` (colour x weight x the bilinear
    texture at the hit's uv, ``accel.hit_uv``), their luminance selection
    ``table._selection_probs`` (subset 'all'), its cumulative sum and last
    slot with p > 0 (``compiled.selection_table``), and the sample weight:
    the sum of the colours where X.lambert, else 0."""
    cur = 0
    img = X.textures.images[0]
    for k in range(mat.shape[0]):
        m = mat[k]
        s0, s1, s2, cur, img = _colour_row(X, m, prim[k], bu[k], bv[k], mu[k], R + k, colors, p,
                                           cdf, last, cur, img)
        if X.lambert[m]:
            col[k, 0], col[k, 1], col[k, 2] = s0, s1, s2
        else:
            col[k, 0] = col[k, 1] = col[k, 2] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def sample_rows(X, lobes, T, mat, rows, bary, ns, ng, wo, ray, u, out, wgt, flags):
    """``compiled.sample_pair`` in importance mode of the hits rows (n,) on
    materials mat (n,) (their rows: a roughness map's level) of
    arrays by hit (bary (., 3) (prim, b1, b2), ns, ng, wo (., 3), ray (.,)
    the row of u (., >= 3) with the hit's uniforms), each with its own
    colour row (:func:`_colour_row`, in a one-row scratch: no (n, L, 3)
    array), the photon tracer's textured hits: out, wgt (., 3) at those rows
    the direction and weight, flags (n,) int8 bit 0 ok, bit 1 delta
    (``compiled.sample_batch``'s)."""
    L = X.color.shape[1]
    colors, p, cdf = np.empty((1, L, 3)), np.empty((1, L)), np.empty((1, L))
    last = np.empty(1, np.int64)
    cur = 0
    img = X.textures.images[0]
    for q in range(rows.shape[0]):
        g = rows[q]
        t = int(bary[g, 0])
        m = mat[q]
        mu = abs(wo[g, 0] * ns[g, 0] + wo[g, 1] * ns[g, 1] + wo[g, 2] * ns[g, 2])
        _, _, _, cur, img = _colour_row(X, m, t, bary[g, 1], bary[g, 2], mu, 0, colors, p, cdf,
                                        last, cur, img)
        i = ray[g]
        r = sample_pair(lobes, T, colors, p, cdf, last, m, 0, ns[g, 0], ns[g, 1], ns[g, 2],
                        ng[g, 0], ng[g, 1], ng[g, 2], wo[g, 0], wo[g, 1], wo[g, 2],
                        u[i, 0], u[i, 1], u[i, 2], False)
        out[g, 0], out[g, 1], out[g, 2] = r[0], r[1], r[2]
        wgt[g, 0], wgt[g, 1], wgt[g, 2] = r[3], r[4], r[5]
        flags[q] = (1 if r[7] else 0) + (2 if r[6] else 0)
