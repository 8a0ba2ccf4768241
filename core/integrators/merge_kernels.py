"""Photon merging as an MIS strategy: the pixel of y_1 and the weighted gather.

    L, M = merge_gather(vp, R2, scale_R2, dep, mtab, camera, region)

Integrator 'COMBINED' with ``merge_weights = 'MIS'`` (core.integrators.merge,
docs/integrators.md "Merging as an MIS strategy").  The merging photons are
light tracing's own light paths (N_M = N_L, as in VCM): every deposit past
the first hit (paths with k >= v + 2) with its ratios B0, B1
(``CombinedLightTracer``).  The gather reuses core.sppm.hashgrid (the grid of
the visible points and its acceptance rules, every accepted pair returned)
and weights each pair (photon, visible point) by ``merge.merge_weight``.
The radius in q_M is the one of the pixel containing y_1 (:func:`pixel_rows`),
the same on the camera paths, the splats and here.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import materials as B
from ..mathutil import dot as _dot
from ..sppm import hashgrid as HG
from ..sppm.photon_kernels import lambert_pdf
from .merge import merge_weight


@njit(cache=True, nogil=True, inline="always")
def pixel_row(x, y, x0, y0, W, H):
    """Row (in the region's pixel order: row 0 of the image at the top) of the
    pixel containing full-frame raster point (x, y) (y from the bottom),
    clamped to the region x0..x0+W-1, y0..y0+H-1."""
    i = min(max(int(math.floor(x)) - x0, 0), W - 1)
    j = min(max(int(math.floor(y)) - y0, 0), H - 1)
    return (H - 1 - j) * W + i


@njit(cache=True, nogil=True)
def _pixel_rows(raster, x0, y0, W, H, out):
    for k in range(raster.shape[0]):
        out[k] = pixel_row(raster[k, 0], raster[k, 1], x0, y0, W, H)


def pixel_rows(raster: np.ndarray, region) -> np.ndarray:
    """(K,) int64 :func:`pixel_row` of raster (K, 2); region (x0, y0, W, H)."""
    out = np.empty(raster.shape[0], np.int64)
    x0, y0, W, H = (int(v) for v in region)
    _pixel_rows(np.ascontiguousarray(raster, np.float64), x0, y0, W, H, out)
    return out


def y1_terms(camera, p1, u_lens, region):
    """(pixel row (K,), c_1 without |cos| (K,)) of camera vertices y_1 = p1
    (K, 3) joined to the lens points of uniforms u_lens (K, 2)
    (CameraModel.project: the splat's raster and weight)."""
    pr = camera.project(p1, u_lens)
    return pixel_rows(pr.raster, region), pr.weight, pr.wi


@njit(cache=True, nogil=True, error_model="numpy")
def _lambert_pairs(pv, ph, ns, ng, wo, albedo, wi, power, B0, B1, R2, x, c1, v1, L):
    """The accepted pairs (pv, ph) of Lambert visible points (f = albedo /
    pi, pf = the Lambert density: ``lambert_pdf``, the camera paths' own):
    L[pv] += w_M f power / (pi R2[pv]) with w_M = merge.merge_weight (the
    same expression; x[pv], c1[pv], v1[pv] per visible point).  ns, ng the
    visible points' mesh normals, wo towards the camera."""
    for n in range(pv.shape[0]):
        v = pv[n]
        p = ph[n]
        if not (x[v] < np.inf):
            continue
        pf = lambert_pdf(ns[v, 0], ns[v, 1], ns[v, 2], ng[v, 0], ng[v, 1], ng[v, 2],
                         wo[v, 0], wo[v, 1], wo[v, 2], wi[p, 0], wi[p, 1], wi[p, 2])
        if pf <= 0.0:
            continue
        b0 = B0[p] * pf * x[v]
        b1 = B1[p] * pf * x[v]
        bl = x[v] / c1[v] if v1[v] else 0.0
        w = 1.0 / (1.0 + b0 * b0 + b1 * b1 + bl * bl)
        if not np.isfinite(w):
            continue
        g = w / (np.pi * R2[v]) / np.pi
        for c in range(3):
            L[v, c] += albedo[v, c] * power[p, c] * g


def merge_gather(vp, R2, scale_R2, dep, mtab, camera, region, n_ratio: float = 1.0):
    """This pass' merging at the visible points vp (VisiblePoints, all valid
    ones: v = 1 allowed) of the deposits dep (dict: p, ng, wi, power (n, 3),
    B0, B1 (n,), first (n,) bool the first hit).

    R2 (P,) the pass' squared radii (the search disc of each pixel);
    scale_R2 (P,) the same array (q_M's pi r^2 is read at the pixel containing
    the visible point's y_1); n_ratio = N_L / N_M.
    Returns (L (P, 3) float64: beta sum w_M f power / (pi R^2) per pixel, not
    yet divided by the light paths; M (P,) int64 the unweighted counts of the
    photons merging may take (the radius reduction's))."""
    P = vp.valid.shape[0]
    L = np.zeros((P, 3))
    keep = np.nonzero(~dep["first"])[0]
    act = vp.valid & (R2 > 0)
    if keep.size == 0 or not np.any(act):
        return L, np.zeros(P, np.int64)
    grid = HG.build_grid(vp.p, np.sqrt(np.where(act, R2, 0.0)), act)
    g = HG.gather(grid, dep["p"][keep], dep["ng"][keep], dep["wi"][keep], dep["power"][keep],
                  np.full(keep.size, np.nan), vp.p, vp.ng, np.where(act, R2, 0.0),
                  np.zeros(P, bool))
    pv, ph = g.pair_vp.astype(np.int64), keep[g.pair_ph]
    if pv.size == 0:
        return L, g.M
    # y_1 of the visible points: the first hit (v = 1 when not through a delta).
    first_p = vp.first.p if vp.first is not None else vp.p
    v1 = ~vp.through_delta if vp.through_delta is not None else np.ones(P, bool)
    q = np.unique(pv)
    rows, wt, wc = y1_terms(camera, first_p[q], np.full((q.size, 2), 0.5), region)
    pix = np.zeros(P, np.int64)
    c1 = np.zeros(P)
    pix[q] = rows
    c1[q] = wt * np.abs(_dot(vp.ng[q], wc))
    r2 = scale_R2[pix]
    with np.errstate(divide="ignore"):
        x = np.where(r2 > 0, n_ratio / (np.pi * np.where(r2 > 0, r2, 1.0)), np.inf)
    # Lambert visible points in the kernel, the others in numpy.
    fast = vp.const[pv]
    a = np.nonzero(fast)[0]
    if a.size:
        ns_all, ng_all = vp.mesh_normals(np.arange(P))
        c = np.ascontiguousarray
        _lambert_pairs(c(pv[a]), c(ph[a]), c(ns_all, np.float64), c(ng_all, np.float64),
                       c(vp.wo, np.float64), c(vp.albedo, np.float64),
                       c(dep["wi"], np.float64), c(dep["power"], np.float64),
                       c(dep["B0"], np.float64), c(dep["B1"], np.float64), c(R2, np.float64),
                       x, c1, c(v1), L)
    s = np.nonzero(~fast)[0]
    if s.size:
        pv, ph = pv[s], ph[s]
        ns, ng = vp.mesh_normals(pv)
        mat = vp.mat[pv].astype(np.int64)
        col = vp.colors[pv].astype(np.float64)
        wo = vp.wo[pv].astype(np.float64)
        wi = dep["wi"][ph].astype(np.float64)
        f = B.eval_bsdf(mtab, mat, col, ns, ng, wo, wi)
        pf = B.pdf_bsdf(mtab, mat, col, ns, ng, wo, wi, subset="all")
        w = merge_weight(dep["B0"][ph], dep["B1"][ph], pf, x[pv], c1[pv], v1[pv])
        contrib = f * dep["power"][ph] * (w / (np.pi * R2[pv]))[:, None]
        for k in range(3):
            L[:, k] += np.bincount(pv, contrib[:, k], minlength=P)
    L *= vp.beta.astype(np.float64)
    return L, g.M
