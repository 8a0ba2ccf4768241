"""Multiple-scattering GGX and the Principled layer albedo (Cycles' precomputed tables).

Cycles' ``microfacet_ggx_preserve_energy`` and ``closure_layering_weight``
read tables of directional albedos (``cycles_precompute.cpp``); they are
recomputed here by deterministic quadrature, once per process and only for
the slices a scene reads.
"""
from __future__ import annotations

import numpy as np

from ..scene.model import GLASS
from .microfacet import (_fresnel_tir, _fss_dielectric, f0_from_ior, fresnel_dielectric,
                         ggx_lambda)


# Cycles scales single-scattering GGX by 1 + F_ms (1 - E)/E, with E(rough, mu)
# the directional albedo of the lobe for the view cosine mu, looked up in
# precomputed tables, and F_ms = C E_avg / (1 - C (1 - E_avg)) (Kulla & Conty
# 2017) for the closure colour C (no mix weight).  The tables here are
# recomputed with the same grids as ``cycles_precompute.cpp``: rough = x/(n-1),
# mu = y/(n-1) (both clamped to >= 1e-4), glass ior = (1 + z^2)/(1 - z^2) for
# z = y/(n-1) in [1e-4, 0.99]; E is the mean sample weight G2/G1 of the VNDF
# sampler (glass: Fresnel-weighted reflection + transmission, no eta^2), here
# by deterministic quadrature instead of Monte Carlo.
_MS_CACHE = {}


def _vndf_grid(alpha, mu, n):
    """Nodes of the n x n midpoint rule over (t, phi) shared by the albedo tables.

    alpha, mu: arrays of shape S (GGX alpha, cosine of wo; wo = (so, 0, mu)).
    Returns a2 = alpha^2 and m = mu (S', 1, 1), jac = du/dt (1, n, 1),
    ph = phi in [0, pi] (1, 1, n), cos / sin of the half vector's polar angle
    ch, sh (S', n, 1) and so = sin of wo's (S', 1, 1), with S' = prod(S).
    """
    a2 = (alpha.reshape(-1, 1, 1) ** 2)
    m = mu.reshape(-1, 1, 1)
    g = (np.arange(n) + 0.5) / n
    # u = 1 - (1 - t)^2, du = 2 (1 - t) dt, removes the 1/sqrt(1 - u) growth of
    # (wo.h)/(n.h) at the horizon of h.
    t = g.reshape(1, -1, 1)
    u = 1.0 - (1.0 - t) ** 2
    jac = 2.0 * (1.0 - t)
    ph = (np.pi * g).reshape(1, 1, -1)
    tan2 = a2 * u / (1.0 - u)
    ch = 1.0 / np.sqrt(1.0 + tan2)
    sh = np.sqrt(np.maximum(0.0, 1.0 - ch * ch))
    so = np.sqrt(np.maximum(0.0, 1.0 - m * m))
    return a2, m, jac, ph, ch, sh, so


def _ms_weight(alpha, mu, eta, glass, n):
    """Albedo E (shape S) of single-scattering GGX (or glass) for arrays alpha, mu, eta.

    E = ∫ D(h) G2(wo, wi(h)) (wo.h) / (n.wo) dω_h (the mean VNDF weight G2/G1).
    With u = tan^2/(alpha^2 + tan^2), D cos dω_h = du dphi / (2 pi), so E is the
    mean of G2 (wo.h)/((n.wo)(n.h)) over (u, phi); the integrand is continuous
    (G2 -> 0 at the horizon, 1 - F -> 0 at total internal reflection), so an
    n x n midpoint rule over t in [0, 1) (u = 1 - (1-t)^2), phi in [0, pi]
    (mirror symmetry) converges.
    """
    S = alpha.shape
    a2, m, jac, ph, ch, sh, so = _vndf_grid(alpha, mu, n)
    e = eta.reshape(-1, 1, 1)
    hwo = so * (sh * np.cos(ph)) + m * ch        # wo = (so, 0, m)
    base = np.maximum(hwo, 0.0) / (m * ch) * jac
    lam_o = ggx_lambda(a2, m)
    # Reflection: wi_z = 2 (wo.h) h_z - wo_z.
    wr_z = 2.0 * hwo * ch - m
    G2r = np.where(wr_z > 0, 1.0 / (1.0 + lam_o + ggx_lambda(a2, np.maximum(wr_z, 1e-300))), 0.0)
    if not glass:
        return (G2r * base).mean(axis=(1, 2)).reshape(S)
    F, cos_t, tir = _fresnel_tir(hwo, e)
    # Refraction about h: wt = (hwo/eta - cos_t) h - wo/eta, z component:
    wt_z = (hwo / e - cos_t) * ch - m / e
    G2t = np.where((wt_z < 0) & ~tir,
                   1.0 / (1.0 + lam_o + ggx_lambda(a2, np.minimum(wt_z, -1e-300))), 0.0)
    return ((F * G2r + (1.0 - F) * G2t) * base).mean(axis=(1, 2)).reshape(S)


def _ms_tables():
    """Reflection (E (32 rough, 32 mu), E_avg (32,)), computed once per process."""
    if "ggx" not in _MS_CACHE:
        n = 32
        grid = np.clip(np.arange(n) / (n - 1), 1e-4, 1.0)
        # One roughness row at a time: the same values as the (32, 32) grid at
        # once (each node's mean is its own), without its ~230 MB of
        # temporaries (a render's peak memory, docs/reliability.md).
        E = np.empty((n, n))
        for i, r in enumerate(grid):
            E[i] = np.clip(_ms_weight(np.full(n, r * r), grid, np.ones(n), False, 64), 0.0, 1.0)
        # E_avg = 2 ∫ mu E(mu) dmu, trapezoid over the mu nodes.
        _MS_CACHE["ggx"] = (E, np.trapezoid(2.0 * grid * E, grid, axis=-1))
    return _MS_CACHE["ggx"]


def _ms_glass_slice(inv: int, k: int):
    """Glass (E (16 rough, 16 mu), E_avg (16,)) for ior node k (inv: 1/ior), cached.

    Scenes use few iors, so only the slices that are read get computed."""
    key = ("glass", inv, k)
    if key not in _MS_CACHE:
        n = 16
        grid = np.clip(np.arange(n) / (n - 1), 1e-4, 1.0)
        z = min(max(k / (n - 1), 1e-4), 0.99)
        ior = (1 + z * z) / (1 - z * z)
        R, Mu = np.meshgrid(grid, grid, indexing="ij")
        eta = np.full_like(R, 1.0 / ior if inv else ior)
        E = np.clip(_ms_weight(R * R, Mu, eta, True, 48), 0.0, 1.0)
        _MS_CACHE[key] = (E, np.trapezoid(2.0 * grid * E, grid, axis=-1))
    return _MS_CACHE[key]


def _gen_s_weight(alpha, mu, s_of, n):
    """Mean (shape of alpha) over VNDF samples (invalid = 0) of s_of(h.wo)
    (Cycles' ``precompute_ggx_gen_schlick_s``), by the quadrature of
    :func:`_ms_weight`."""
    S = alpha.shape
    a2, m, jac, ph, ch, sh, so = _vndf_grid(alpha, mu, n)
    hwo = so * sh * np.cos(ph) + m * ch          # as _ms_weight, grouped as before (same bits)
    G1 = 1.0 / (1.0 + ggx_lambda(a2, m))
    vndf = G1 * np.maximum(hwo, 0.0) / (m * ch) * jac          # VNDF in (t, phi) measure
    valid = (2.0 * hwo * ch - m) > 0
    return (vndf * s_of(hwo) * valid).mean(axis=(1, 2)).reshape(S)


def _schlick_s_weight(alpha, mu, eta, n):
    """Cycles' ggx_gen_schlick_ior_s: s = sat((F_real(h.wo) - F0)/(1 - F0))."""
    e = eta.reshape(-1, 1, 1)

    def s_of(hwo):
        shp = np.broadcast_shapes(hwo.shape, e.shape)
        Fr = fresnel_dielectric(np.broadcast_to(hwo, shp).reshape(-1),
                                np.broadcast_to(e, shp).reshape(-1))[0].reshape(shp)
        F0 = f0_from_ior(e)
        return np.clip((Fr - F0) / np.maximum(1.0 - F0, 1e-12), 0.0, 1.0)
    return _gen_s_weight(alpha, mu, s_of, n)


def _rough_mu_nodes(n: int = 16):
    """(R, Mu) (n, n): the roughness and mu nodes of Cycles' 16-node tables
    (x/(n-1), clamped to >= 1e-4)."""
    grid = np.clip(np.arange(n) / (n - 1), 1e-4, 1.0)
    return np.meshgrid(grid, grid, indexing="ij")


def _schlick_s_slice(k: int):
    """s table (16 rough, 16 mu) at ior node k (Cycles' z = k/15 grid), cached."""
    key = ("schlick_s", k)
    if key not in _MS_CACHE:
        n = 16
        z = min(max(k / (n - 1), 1e-4), 0.99)
        R, Mu = _rough_mu_nodes(n)
        eta = np.full_like(R, (1 + z * z) / (1 - z * z))
        _MS_CACHE[key] = np.clip(_schlick_s_weight(R * R, Mu, eta, 48), 0.0, 1.0)
    return _MS_CACHE[key]


def _schlick5_s_table():
    """Cycles' ggx_gen_schlick_s read at z = 0.5 (what the F82-tint metal's
    albedo reads), (16 rough, 16 mu), cached.  The table's z axis holds
    exponent e = 5 (1 - z)/z with s = (1 - h.wo)^e on the nodes z = k/15;
    z = 0.5 falls halfway between nodes 7 and 8 (e = 40/7 and 35/8), which
    Cycles' lookup mixes half and half."""
    key = ("schlick5_s",)
    if key not in _MS_CACHE:
        n = 16
        R, Mu = _rough_mu_nodes(n)
        T = 0.0
        for k in (7, 8):
            e = 5.0 * (1.0 - k / (n - 1)) / (k / (n - 1))
            T = T + 0.5 * np.clip(_gen_s_weight(
                R * R, Mu, lambda hwo: np.clip(1.0 - hwo, 0.0, 1.0) ** e, 48), 0.0, 1.0)
        _MS_CACHE[key] = T
    return _MS_CACHE[key]


def _lerp_index(x, n):
    """Cycles' lookup_table_read: clamp x to [0, 1], linear between n nodes."""
    t = np.clip(x, 0.0, 1.0) * (n - 1)
    i = np.minimum(np.floor(t).astype(np.int64), n - 2)
    return i, t - i


def _bilerp(T, i, ti, j, tj):
    """Bilinear read of a table T (n, n) at nodes i, j (k,) plus fractions ti, tj (k,)."""
    return ((1 - ti) * ((1 - tj) * T[i, j] + tj * T[i, j + 1])
            + ti * ((1 - tj) * T[i + 1, j] + tj * T[i + 1, j + 1]))


def _ggx_albedo(rough, mu):
    """Single-scattering GGX albedo E(rough, mu) and E_avg(rough), (k,) each, from the table."""
    E_t, Eavg_t = _ms_tables()
    i, ti = _lerp_index(rough, 32)
    j, tj = _lerp_index(mu, 32)
    return _bilerp(E_t, i, ti, j, tj), (1 - ti) * Eavg_t[i] + ti * Eavg_t[i + 1]


def schlick_s(rough, mu, ior):
    """Cycles' ggx_gen_schlick_ior_s (k,) at (roughness, mu, z(ior)) (k,)
    each: F = mix(F0, 1, s) is the Fresnel-weighted albedo estimate of a
    dielectric GGX lobe (``bsdf_microfacet_estimate_albedo``)."""
    z = np.sqrt(np.abs((ior - 1.0) / (ior + 1.0)))
    k, tk = _lerp_index(z, 16)
    i, ti = _lerp_index(rough, 16)
    j, tj = _lerp_index(mu, 16)
    s = np.zeros(len(mu))
    for dk in (0, 1):
        wk = tk if dk else 1 - tk
        for kk in np.unique(k + dk):
            sel = k + dk == kk
            T = _schlick_s_slice(int(kk))
            ii, ti_, jj, tj_ = i[sel], ti[sel], j[sel], tj[sel]
            s[sel] += wk[sel] * _bilerp(T, ii, ti_, jj, tj_)
    return s


def schlick5_s(rough, mu):
    """Cycles' ggx_gen_schlick_s (k,) at exponent 5 (z = 0.5): F = mix(F0, 1,
    s) is the albedo estimate of an F82-tint metal lobe."""
    i, ti = _lerp_index(rough, 16)
    j, tj = _lerp_index(mu, 16)
    return _bilerp(_schlick5_s_table(), i, ti, j, tj)


def layer_transmission(f0, rough, ior, mu, ms=None, film=None):
    """1 - albedo (k,) of a Principled dielectric specular layer seen at cosine mu.

    Cycles' closure_layering_weight: the diffuse below gets 1 - A with the
    layer's bsdf_albedo A = d mix(f0, 1, s), s from the ggx_gen_schlick_ior_s
    table at (roughness, mu, z(ior)), and d = E + F_ms (1 - E) the weight
    change of microfacet_ggx_preserve_energy for Multiscatter GGX (d = 1 for
    plain GGX).  f0: (k,) max-channel F0 x tint; rough, ior, mu: (k,); ms: (k,) bool.
    film (k, 2): a thin film's thickness and IOR on the layer; where there
    is one, mix(f0, 1, s) is the film's Fresnel at mu, its largest channel
    (Cycles' bsdf_microfacet_estimate_albedo has no table for films)."""
    A = f0 + (1.0 - f0) * schlick_s(rough, mu, ior)
    if film is not None:
        from .thin_film import THICKNESS_CUTOFF
        q = np.asarray(film)[:, 0] > THICKNESS_CUTOFF
        if q.any():
            from .compiled import film_fresnel
            A = A.copy()
            A[q] = film_fresnel(0, mu[q], ior[q], 1.0, 0.0, film[q], f0[q, None],
                                layer=True)[:, 0]
    if ms is not None and np.any(ms):
        F0 = f0_from_ior(ior[ms])
        s_ss = np.clip((_fss_dielectric(ior[ms]) - F0) / np.maximum(1.0 - F0, 1e-12), 0.0, 1.0)
        fss = f0[ms] + (1.0 - f0[ms]) * s_ss
        E, Eavg = _ggx_albedo(rough[ms], mu[ms])
        fms = fss * Eavg / np.maximum(1.0 - fss * (1.0 - Eavg), 1e-12)
        A[ms] *= E + fms * (1.0 - E)
    return np.clip(1.0 - A, 0.0, 1.0)


def multiscatter_factor(kind, color, rough, eta, mu):
    """Per-channel factor (k, 3) turning single- into multiple-scattering GGX.

    color: (k, 3) closure colour without mix weight; rough: (k,) roughness;
    eta: (k,) relative ior (glass); mu: (k,) cosine of the view direction.
    """
    E, Fms = _ms_terms(kind, color, rough, eta, mu)
    return 1.0 + Fms * (1.0 - E) / E


def multiscatter_darkening(kind, color, rough, eta, mu):
    """(k, 3) the part of :func:`multiscatter_factor` Cycles puts into the
    closure's weight, E + F_ms (1 - E) (``microfacet_ggx_preserve_energy``'s
    darkening; the rest, 1/E, is its energy_scale): what the closure's
    albedo (``bsdf_albedo``) carries.  Arguments as multiscatter_factor's."""
    E, Fms = _ms_terms(kind, color, rough, eta, mu)
    return E + Fms * (1.0 - E)


def _ms_terms(kind, color, rough, eta, mu):
    """(E (k, 1), F_ms (k, 3)) of :func:`multiscatter_factor`."""
    if kind != GLASS:
        E, Eavg = _ggx_albedo(rough, mu)
    else:
        inv = (eta < 1.0).astype(np.int64)
        ior = np.where(inv == 1, 1.0 / eta, eta)
        z = np.sqrt(np.abs((ior - 1.0) / (ior + 1.0)))
        # Cycles reads the z axis linearly on the node grid k/15 (clamped nodes).
        k, tk = _lerp_index(z, 16)
        i, ti = _lerp_index(rough, 16)
        j, tj = _lerp_index(mu, 16)
        E = np.zeros(len(rough))
        Eavg = np.zeros(len(rough))
        for dk in (0, 1):
            wk = tk if dk else 1 - tk
            for s_, kk in set(zip(inv.tolist(), (k + dk).tolist())):
                sel = (inv == s_) & (k + dk == kk)
                E_t, Eavg_t = _ms_glass_slice(s_, kk)
                ii, ti_, jj, tj_ = i[sel], ti[sel], j[sel], tj[sel]
                E[sel] += wk[sel] * _bilerp(E_t, ii, ti_, jj, tj_)
                Eavg[sel] += wk[sel] * ((1 - ti_) * Eavg_t[ii] + ti_ * Eavg_t[ii + 1])
    E = np.maximum(E, 1e-6)[:, None]
    Eavg = Eavg[:, None]
    C = np.maximum(color, 0.0)
    return E, C * Eavg / np.maximum(1.0 - C * (1.0 - Eavg), 1e-12)
