"""Cycles' surface closures per lobe, and the BSDF of a whole material.

Per-lobe f and pdf (:func:`_lobe_f`, :func:`_lobe_pdf`) and the material-level
interface every stage calls: :func:`eval_bsdf`, :func:`pdf_bsdf`,
:func:`sample_bsdf` and :func:`shading_correction`.  Conventions (``wo`` /
``wi``, radiance and importance modes, two-sided normals) are those of the
package doc (:mod:`core.materials`).
"""
from __future__ import annotations

import numpy as np

from ..mathutil import LUMINANCE, dot as _dot, frame
from ..scene.model import DIFFUSE, GLASS, GLOSSY, REFRACTION, TRANSLUCENT, TRANSPARENT
from .microfacet import (FRESNEL_CONDUCTOR, FRESNEL_DIELECTRIC, FRESNEL_F82, INV_PI, _disk,
                         _microfacet_f, _microfacet_pdf, _normalize, _principled_fresnel,
                         fresnel_dielectric, ggx_sample_vndf, oren_nayar_f)
from .multiscatter import layer_transmission, multiscatter_factor
from .table import (DIFFUSE_ROUGHNESS_EPS, MaterialTable, _selection_probs, fresnel_params,
                    seen_weight)


# --------------------------------------------------------------------------
# Frames, orientation, shading-normal corrections
# --------------------------------------------------------------------------
def _prep(n_s, n_g, wo, wi):
    f64 = lambda a: np.asarray(a, np.float64).reshape(-1, 3)
    return f64(n_s), f64(n_g), f64(wo), None if wi is None else f64(wi)


def _orient(n_s, n_g, v):
    """Flip both normals to v's side of the geometric normal (Cycles' back faces).

    Returns (N, Ng, front) with front = v on the original geometric side."""
    front = _dot(n_g, v) >= 0.0
    s = np.where(front, 1.0, -1.0)[:, None]
    return n_s * s, n_g * s, front


def _cos_hemisphere(u1, u2):
    x, y = _disk(u1, u2)
    z = np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y))
    return np.stack([x, y, z], axis=1)


def _refract(wo, H, cos_t, eta):
    """Refracted direction of wo (pointing away) about H with h.wo > 0 (Cycles' refract_angle)."""
    inv = 1.0 / eta
    return ((inv * _dot(H, wo) - cos_t)[:, None] * H) - inv[:, None] * wo


def _bump_corrected(table, mat, n_s, n_g, view):
    """n_s with Cycles' ``ensure_valid_specular_reflection`` for the view
    direction on materials with a Normal Map / Bump input
    (``table.bump_correction``); others unchanged.  Same orientation as n_s."""
    flag = getattr(table, "bump_correction", None)
    if flag is None or not flag.any():
        return n_s
    sel = np.nonzero(flag[mat])[0]
    if sel.size == 0:
        return n_s
    from ..scene.normals import valid_specular_normal
    s = np.where(_dot(n_g[sel], view[sel]) >= 0.0, 1.0, -1.0)[:, None]
    out = n_s.copy()
    out[sel] = s * valid_specular_normal(n_g[sel] * s, view[sel], n_s[sel] * s)
    return out


def _adjoint_correction(n_s, n_g, wo, wi):
    """pbrt's CorrectShadingNormal |wo.ns||wi.ng| / (|wo.ng||wi.ns|) (K,)."""
    num = np.abs(_dot(wo, n_s)) * np.abs(_dot(wi, n_g))
    den = np.abs(_dot(wo, n_g)) * np.abs(_dot(wi, n_s))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


def shading_correction(n_s: np.ndarray, n_g: np.ndarray, w: np.ndarray) -> np.ndarray:
    """|w.n_s| / |w.n_g| (K,): factor for a gathered photon arriving along w (Veach 1997, 5.3)."""
    d = np.abs(_dot(n_g, w))
    return np.where(d > 0, np.abs(_dot(n_s, w)) / np.where(d > 0, d, 1.0), 0.0)


# --------------------------------------------------------------------------
# Per-lobe evaluation (Cycles' closure eval, view/light roles explicit)
# --------------------------------------------------------------------------
def _lobe_f(kind, col, ucol, rough, eta, N, v, l, Ng, ms=None, ext=None):
    """Cycles f_C(view=v, light=l) (k, 3) of one non-delta lobe kind.

    ms: (k,) bool, apply Multiscatter GGX energy compensation (GLOSSY, GLASS).
    Ng: (k, 3) the geometric normal oriented like N (the microfacet lobes'
    side test, :func:`microfacet._microfacet_f`).
    ext: dict of Principled-layer arrays for these points (or None):
      'weight' (k,), 'fresnel' (k,), 'fresnel_ior' (k,), 'f82_tint' (k, 3)
      'conductor_k' (k, 3) and 'thin_film' (k, 2) (``table.fresnel_params``),
      'layer_ior', 'layer_f0', 'layer_roughness' (k,)."""
    if kind == DIFFUSE:
        lam = rough < DIFFUSE_ROUGHNESS_EPS
        f = col * (INV_PI * (_dot(N, l) > 0.0))[:, None]
        on = ~lam
        if on.any():
            f[on] = oren_nayar_f(col[on], ucol[on], rough[on], N[on], v[on], l[on])
        if ext is not None and (ext["layer_ior"] > 0).any():
            lay = ext["layer_ior"] > 0
            f[lay] *= layer_transmission(ext["layer_f0"][lay], ext["layer_roughness"][lay],
                                         ext["layer_ior"][lay], _dot(N[lay], v[lay]),
                                         ext["layer_ms"][lay], ext["thin_film"][lay])[:, None]
        return f
    if kind == TRANSLUCENT:
        return col * (INV_PI * (_dot(N, l) < 0.0))[:, None]
    if kind in (GLOSSY, GLASS, REFRACTION):
        alpha2 = rough ** 4
        fs = _microfacet_f(kind, alpha2, eta, N, v, l, Ng)
        f = col * fs[:, None]
        fss = ucol
        if kind == GLOSSY and ext is not None and (ext["fresnel"] > 0).any():
            fss = ucol.copy()
            for mode in (FRESNEL_DIELECTRIC, FRESNEL_F82, FRESNEL_CONDUCTOR):
                q = ext["fresnel"] == mode
                if not q.any():
                    continue
                H = _normalize(v[q] + l[q])
                F, fss[q] = _principled_fresnel(mode, ucol[q], ext["fresnel_ior"][q],
                                                ext["f82_tint"][q], _dot(H, v[q]),
                                                ext["conductor_k"][q], ext["thin_film"][q])
                # The colour is F0 / tint: Fresnel replaces it, the mix weight stays.
                f[q] = ext["weight"][q, None] * F * fs[q, None]
        if ms is not None and ms.any() and kind != REFRACTION:
            f[ms] *= multiscatter_factor(kind, fss[ms], rough[ms], eta[ms],
                                         _dot(N[ms], v[ms]))
        return f
    return np.zeros_like(col)


def _lobe_pdf(kind, rough, eta, N, Ng, wo, wi):
    """Sampling density (k,) of one non-delta lobe kind (N, Ng oriented to wo)."""
    if kind == DIFFUSE:
        return np.maximum(_dot(N, wi), 0.0) * INV_PI * (_dot(Ng, wi) > 0.0)
    if kind == TRANSLUCENT:
        return np.maximum(-_dot(N, wi), 0.0) * INV_PI * (_dot(Ng, wi) < 0.0)
    if kind in (GLOSSY, GLASS, REFRACTION):
        return _microfacet_pdf(kind, rough ** 4, eta, N, Ng, wo, wi)
    return np.zeros(len(rough))


# --------------------------------------------------------------------------
# Material BSDF: evaluation and density
# --------------------------------------------------------------------------
def eval_bsdf(table: MaterialTable, mat, colors, n_s, n_g, wo, wi, mode="radiance"):
    """Sum of the non-delta lobes' f (K, 3), without cosine.

    mat (K,) int; colors (K, L, 3) from :func:`lobe_colors`; n_s, n_g (K, 3)
    unit shading / geometric normals (any orientation); wo, wi (K, 3) unit.
    mode 'radiance': Cycles' f with wo = view; 'importance': the adjoint
    f_C(view=wi, light=wo) (no shading-normal factor, see the package doc).
    """
    mat = np.asarray(mat, np.int64)
    n_s, n_g, wo, wi = _prep(n_s, n_g, wo, wi)
    if mode == "radiance":
        v, l = wo, wi
    elif mode == "importance":
        v, l = wi, wo
    else:
        raise ValueError(f"mode must be 'radiance' or 'importance', not {mode!r}")
    n_s = _bump_corrected(table, mat, n_s, n_g, v)
    N, Ng, front = _orient(n_s, n_g, v)
    return _eval_nd(table, mat, colors, N, front, v, l, Ng,
                    Ng_bump=Ng if mode == "radiance" else None)


def _groups(valid, kinds):
    """Yield (slot j, kind k, index) groups; the index is a full slice when every
    point is in the group (views instead of fancy-indexed copies)."""
    K = kinds.shape[0]
    for j in range(kinds.shape[1]):
        kj = kinds[valid[:, j], j]
        if kj.size == 0:
            continue
        for k in np.unique(kj):
            m = valid[:, j] & (kinds[:, j] == k)
            if kj.size == K and m.all():
                yield j, int(k), slice(None)
            else:
                yield j, int(k), np.nonzero(m)[0]


def _bump_shadowing(Ns, N, l):
    """Cycles' ``bump_shadowing_term`` for a diffuse closure (K,): Conty
    Estevez, Lecocq and Stein 2019, "A Microfacet-Based Shadowing Function to
    Solve the Bump Terminator Problem".  Ns: the surface normal without the
    bump (Cycles: the smooth normal; FPPM's materials see the geometric one,
    equal on flat faces), N: the perturbed normal, l: the light direction.
    0 when l and N lie on different sides of the unbumped surface; else the
    GGX masking G1(cos_i) of alpha^2 = min(tan^2(theta_d) / 8, 1), theta_d
    the angle between N and Ns, cos_i = |Ns.l|."""
    cos_si = _dot(Ns, l)
    cos_sn = _dot(Ns, N)
    cos_ni = _dot(N, l)
    wrong = cos_si * cos_sn * cos_ni < 0.0
    cos_i = np.abs(cos_si)
    cos_d = np.abs(cos_sn)
    a2 = np.clip(0.125 * (1.0 / np.maximum(cos_d, 1e-12) ** 2 - 1.0), 0.0, 1.0)
    tan2_i = (1.0 - cos_i * cos_i) / np.maximum(cos_i * cos_i, 1e-300)
    g1 = 2.0 / (1.0 + np.sqrt(1.0 + a2 * tan2_i))
    g1 = np.where((cos_d >= 1.0) | (cos_i >= 1.0), 1.0, np.where(cos_i < 1e-6, 0.0, g1))
    return np.where(wrong, 0.0, g1)


def _eval_nd(table, mat, colors, N, front_v, v, l, Ng, Ng_bump=None):
    """Σ of the non-delta lobes' f (K, 3).  Ng (K, 3): the geometric normal
    oriented like N (the microfacet lobes' side test).  Ng_bump (K, 3): the
    same, to apply Cycles' bump shadowing to the diffuse lobes of Normal
    Map / Bump materials (camera side); None: not applied."""
    K = len(mat)
    flag = getattr(table, "bump_correction", None)
    off = getattr(table, "bump_unshadowed", None)
    if flag is not None and off is not None:
        flag = np.asarray(flag, bool) & ~np.asarray(off, bool)
    if Ng_bump is not None and (flag is None or not flag[mat].any()):
        Ng_bump = None
    f = np.zeros((K, 3))
    kinds = table.kind[mat]
    nd = (kinds >= 0) & ~table.lobe_delta[mat]
    for j, k, idx in _groups(nd, kinds):
        mj = mat[idx]
        col = colors[idx, j]
        rough = table.roughness[mj, j]
        ms = None if table.multiscatter is None else table.multiscatter[mj, j]
        # Colour without mix weight (nor a view mix's factor): only
        # Oren-Nayar, Multiscatter GGX and the Principled layers need it.
        wseen = seen_weight(table, mj, j, np.abs(_dot(N[idx], v[idx])))
        if (k == DIFFUSE and (rough >= DIFFUSE_ROUGHNESS_EPS).any()) or (ms is not None and ms.any()):
            w = wseen[:, None]
            ucol = np.where(w != 0.0, col / np.where(w != 0.0, w, 1.0), 0.0)
        else:
            ucol = col
        ior = table.ior[mj, j]
        eta = np.where(front_v[idx], ior, 1.0 / ior)
        ext = None
        if table.fresnel is not None and ((table.fresnel[mj, j] > 0).any()
                                          or (table.layer_ior[mj, j] > 0).any()):
            fm_, fior_, tint_, k_, film_ = fresnel_params(table, mj, j)
            ext = {"weight": wseen, "fresnel": fm_, "fresnel_ior": fior_, "f82_tint": tint_,
                   "conductor_k": k_, "thin_film": film_,
                   "layer_ior": table.layer_ior[mj, j], "layer_f0": table.layer_f0[mj, j],
                   "layer_roughness": table.layer_roughness[mj, j],
                   "layer_ms": table.layer_ms[mj, j]}
            if not (ms is not None and ms.any()):
                w = wseen[:, None]
                ucol = np.where(w != 0.0, col / np.where(w != 0.0, w, 1.0), 0.0)
        fk = _lobe_f(k, col, ucol, rough, eta, N[idx], v[idx], l[idx], Ng[idx], ms, ext)
        if Ng_bump is not None and k in (DIFFUSE, TRANSLUCENT):
            term = _bump_shadowing(Ng_bump[idx], N[idx], l[idx])
            fk = fk * np.where(flag[mj], term, 1.0)[:, None]
        f[idx] += fk
    return f


def _pdf_nd(table, mat, sel_p, N, Ng, front_o, wo, wi):
    """Σ over non-delta lobes of p_select x pdf (K,); N, Ng oriented to wo."""
    K = len(mat)
    pdf = np.zeros(K)
    kinds = table.kind[mat]
    nd = (kinds >= 0) & ~table.lobe_delta[mat] & (sel_p > 0.0)
    for j, k, idx in _groups(nd, kinds):
        mj = mat[idx]
        ior = table.ior[mj, j]
        eta = np.where(front_o[idx], ior, 1.0 / ior)
        pdf[idx] += sel_p[idx, j] * _lobe_pdf(k, table.roughness[mj, j], eta,
                                              N[idx], Ng[idx], wo[idx], wi[idx])
    return pdf


def pdf_bsdf(table: MaterialTable, mat, colors, n_s, n_g, wo, wi, subset="all"):
    """Solid-angle density (K,) with which :func:`sample_bsdf` (same subset) produces wi.

    Only non-delta lobes have a density; their selection probabilities are the
    luminance weights normalised within ``subset`` ('all' or 'nondelta').
    """
    return _pdf_nd(table, *pdf_inputs(table, mat, colors, n_s, n_g, wo, wi, subset))


def pdf_inputs(table: MaterialTable, mat, colors, n_s, n_g, wo, wi, subset="all"):
    """What :func:`_pdf_nd` reads for :func:`pdf_bsdf`'s arguments: (mat (K,)
    int64, the lobes' selection probabilities (K, L), N, Ng (K, 3) the normals
    (Normal Map / Bump corrected) oriented to wo's side, front (K,) bool, wo,
    wi (K, 3) float64) -- also the compiled sum's (core.materials.compiled
    pdf_radiance)."""
    mat = np.asarray(mat, np.int64)
    n_s, n_g, wo, wi = _prep(n_s, n_g, wo, wi)
    n_s = _bump_corrected(table, mat, n_s, n_g, wo)
    N, Ng, front = _orient(n_s, n_g, wo)
    return mat, _selection_probs(table, mat, colors, subset), N, Ng, front, wo, wi


# --------------------------------------------------------------------------
# Sampling
# --------------------------------------------------------------------------
def sample_bsdf(table: MaterialTable, mat, colors, n_s, n_g, wo, u, subset="all",
                mode="radiance"):
    """Sample wi for K points (all float64).

    mat (K,) int; colors (K, L, 3) from :func:`lobe_colors`; n_s, n_g (K, 3)
    unit shading / geometric normals in any orientation; wo (K, 3) unit.
    u: (K, 3) uniforms in [0, 1): u[:, 0:2] direction, u[:, 2] lobe choice
    (rescaled and reused for glass' reflect/refract choice).
    subset: 'all', 'delta' or 'nondelta' lobes; lobes are picked by luminance
    of weight x colour within the subset.
    Returns (wi (K, 3), weight (K, 3), pdf (K,), is_delta (K,), valid (K,)):
    - non-delta sample: weight = f·|cos(n_s, wi)|/pdf with f the sum of all
      non-delta lobes (:func:`eval_bsdf`) and pdf their combined density
      (:func:`pdf_bsdf` with the same subset), one-sample MIS over lobes;
    - delta sample: weight = lobe throughput / P(select lobe | subset), pdf =
      that discrete probability.  The caller that chose the subset with
      probability P (e.g. :func:`delta_probability`) divides by P itself.
    mode='importance' weights include the adjoint eta and shading-normal
    factors (package doc, :mod:`core.materials`).  Invalid samples (below the
    geometric surface, total internal reflection of a Refraction BSDF, no
    lobe) have zero weight.
    """
    mat = np.asarray(mat, np.int64)
    n_s, n_g, wo, _ = _prep(n_s, n_g, wo, None)
    u = np.asarray(u, np.float64).reshape(-1, 3)
    if mode not in ("radiance", "importance"):
        raise ValueError(f"mode must be 'radiance' or 'importance', not {mode!r}")
    if subset not in ("all", "delta", "nondelta"):
        raise ValueError(f"subset must be 'all', 'delta' or 'nondelta', not {subset!r}")
    if mode == "radiance":
        n_s = _bump_corrected(table, mat, n_s, n_g, wo)
    K = len(mat)
    # Fast path: materials made only of Lambert lobes (the common wall) need no
    # lobe choice, eval or pdf: cosine sampling has weight = sum of colours.
    fast = table.lambert_only[mat] & ~table.has_delta[mat]
    if subset == "delta" or not fast.any():
        return _sample_general(table, mat, colors, n_s, n_g, wo, u, subset, mode)
    wi = np.zeros((K, 3))
    weight = np.zeros((K, 3))
    pdf = np.zeros(K)
    ok = np.zeros(K, bool)
    is_delta = np.zeros(K, bool)
    fi = np.nonzero(fast)[0]
    N, Ng, _ = _orient(n_s[fi], n_g[fi], wo[fi])
    t, b = frame(N)
    loc = _cos_hemisphere(u[fi, 0], u[fi, 1])
    w = loc[:, 0:1] * t + loc[:, 1:2] * b + loc[:, 2:3] * N
    wt = colors[fi].sum(axis=1)
    good = (_dot(Ng, w) > 0) & (loc[:, 2] > 0) & (wt @ LUMINANCE > 0)
    wi[fi] = w
    pdf[fi] = np.where(good, loc[:, 2] * INV_PI, 0.0)
    if mode == "importance":
        wt = wt * _adjoint_correction(n_s[fi], n_g[fi], wo[fi], w)[:, None]
    weight[fi] = np.where(good[:, None], wt, 0.0)
    ok[fi] = good
    si = np.nonzero(~fast)[0]
    if len(si):
        r = _sample_general(table, mat[si], colors[si], n_s[si], n_g[si], wo[si], u[si],
                            subset, mode)
        wi[si], weight[si], pdf[si], is_delta[si], ok[si] = r
    return wi, weight, pdf, is_delta, ok


def _sample_general(table, mat, colors, n_s, n_g, wo, u, subset, mode):
    """sample_bsdf for any material (arrays already converted)."""
    K = len(mat)
    N, Ng, front = _orient(n_s, n_g, wo)
    kinds = table.kind[mat]
    delta_l = table.lobe_delta[mat]
    p = _selection_probs(table, mat, colors, subset)
    cdf = np.cumsum(p, axis=1)
    any_lobe = cdf[:, -1] > 0
    # Lobe choice: first slot with u < cdf (guard round-off at the top end).
    # Lobe choice: first slot with u < cdf.  Zero-probability slots are skipped
    # automatically; u >= cdf[-1] (round-off) falls back to the last usable slot.
    L = kinds.shape[1]
    rows = np.arange(K)
    last_pos = L - 1 - np.argmax(p[:, ::-1] > 0, axis=1)
    j_sel = np.minimum((u[:, 2:3] >= cdf).sum(axis=1), last_pos)
    p_sel = p[rows, j_sel]
    c_lo = np.where(j_sel > 0, cdf[rows, np.maximum(j_sel - 1, 0)], 0.0)
    u_re = np.clip((u[:, 2] - c_lo) / np.where(p_sel > 0, p_sel, 1.0), 0.0, 1.0 - 1e-16)

    t, b = frame(N)
    wl = np.stack([_dot(wo, t), _dot(wo, b), _dot(wo, N)], axis=1)

    wi = np.zeros((K, 3))
    ok = np.zeros(K, bool)
    dweight = np.zeros((K, 3))      # delta throughput before selection
    is_delta = np.zeros(K, bool)
    k_sel = kinds[rows, j_sel]
    col_sel = colors[rows, j_sel]
    rough_sel = table.roughness[mat, j_sel]
    ior_sel = table.ior[mat, j_sel]
    eta_sel = np.where(front, ior_sel, 1.0 / ior_sel)
    dsel = delta_l[rows, j_sel]

    def to_world(idx, loc):
        return loc[:, 0:1] * t[idx] + loc[:, 1:2] * b[idx] + loc[:, 2:3] * N[idx]

    for k in np.unique(k_sel[any_lobe]):
        for is_d in (False, True):
            idx = np.nonzero(any_lobe & (k_sel == k) & (dsel == is_d))[0]
            if len(idx) == 0:
                continue
            k = int(k)
            if k in (DIFFUSE, TRANSLUCENT):
                loc = _cos_hemisphere(u[idx, 0], u[idx, 1])
                if k == TRANSLUCENT:
                    loc[:, 2] = -loc[:, 2]
                w = to_world(idx, loc)
                gs = _dot(Ng[idx], w)
                wi[idx] = w
                ok[idx] = gs > 0 if k == DIFFUSE else gs < 0
                continue
            if k == TRANSPARENT:
                wi[idx] = -wo[idx]
                ok[idx] = True
                dweight[idx] = col_sel[idx]
                is_delta[idx] = True
                continue
            # Microfacet family.
            cI = wl[idx, 2]
            if is_d:
                H = N[idx]
            else:
                alpha = rough_sel[idx] ** 2
                hl = ggx_sample_vndf(np.where(cI[:, None] > 0, wl[idx], [0.0, 0.0, 1.0]),
                                     alpha, u[idx, 0], u[idx, 1])
                H = to_world(idx, hl)
            hwo = _dot(H, wo[idx])
            eta = eta_sel[idx]
            if k == GLOSSY:
                refr = np.zeros(len(idx), bool)
                F = np.ones(len(idx))
            else:
                F, cos_t = fresnel_dielectric(hwo, eta)
                if k == GLASS:
                    refr = u_re[idx] >= F
                else:   # REFRACTION: always transmit, TIR absorbs
                    refr = np.ones(len(idx), bool)
            wr = 2.0 * hwo[:, None] * H - wo[idx]
            if k != GLOSSY:
                wt = _refract(wo[idx], H, cos_t, eta)
                w = np.where(refr[:, None], wt, wr)
            else:
                w = wr
            w = _normalize(w)
            cN = _dot(N[idx], w)
            cG = _dot(Ng[idx], w)
            good = (cI > 0) & np.where(refr, (cN < 0) & (cG < 0), (cN > 0) & (cG > 0))
            if k == REFRACTION:
                good &= F < 1.0
            wi[idx] = w
            ok[idx] = good
            if is_d:
                is_delta[idx] = True
                dw = col_sel[idx].copy()
                if k == GLOSSY and table.fresnel is not None:
                    # Principled layers at roughness 0: colour is tint / F0, the
                    # Fresnel at h = n scales the mix weight (E = 1: no multiscatter).
                    mj, jj = mat[idx], j_sel[idx]
                    fm, fior_, tint_, k_, film_ = fresnel_params(table, mj, jj)
                    for mode_f in (FRESNEL_DIELECTRIC, FRESNEL_F82, FRESNEL_CONDUCTOR):
                        q = fm == mode_f
                        if q.any():
                            wq = seen_weight(table, mj[q], jj[q], np.abs(hwo[q]))
                            C = dw[q] / np.where(wq != 0, wq, 1.0)[:, None]
                            F, _ = _principled_fresnel(mode_f, C, fior_[q], tint_[q], hwo[q],
                                                       k_[q], film_[q])
                            dw[q] = wq[:, None] * F
                if mode == "importance":
                    # Adjoint of Cycles' unscaled BTDF: (n_wo / n_wi)^2 = 1/eta^2.
                    dw[refr] /= (eta[refr] ** 2)[:, None]
                dweight[idx] = dw

    weight = np.zeros((K, 3))
    pdf = np.zeros(K)
    # Delta samples.
    d = ok & is_delta
    weight[d] = dweight[d] / p_sel[d, None]
    pdf[d] = p_sel[d]
    # Non-delta samples: combined one-sample estimator over all non-delta lobes.
    nd = np.nonzero(ok & ~is_delta)[0]
    if len(nd):
        pdf_n = _pdf_nd(table, mat[nd], p[nd], N[nd], Ng[nd], front[nd], wo[nd], wi[nd])
        if mode == "radiance":
            f = _eval_nd(table, mat[nd], colors[nd], N[nd], front[nd], wo[nd], wi[nd], Ng[nd],
                         Ng_bump=Ng[nd])
        else:
            Nv, Ngv, fv = _orient(n_s[nd], n_g[nd], wi[nd])
            f = _eval_nd(table, mat[nd], colors[nd], Nv, fv, wi[nd], wo[nd], Ngv)
        good = pdf_n > 0
        cos = np.abs(_dot(n_s[nd], wi[nd]))
        weight[nd] = np.where(good[:, None], f * (cos / np.where(good, pdf_n, 1.0))[:, None], 0.0)
        pdf[nd] = pdf_n
        ok[nd] = good
    if mode == "importance":
        weight *= _adjoint_correction(n_s, n_g, wo, wi)[:, None]
    weight[~ok] = 0.0
    pdf[~ok] = 0.0
    return wi, weight, pdf, is_delta & ok, ok
