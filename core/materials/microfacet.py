"""Microfacet and diffuse building blocks of Cycles' closures (float64, k points).

GGX (``bsdf_microfacet.h``): D, Smith Lambda, Heitz 2018's visible-normal
sampling and the scalar f / pdf of the GLOSSY, GLASS and REFRACTION kinds;
exact dielectric Fresnel, its hemispherical fit and the Principled BSDF's
generalised-Schlick / F82-tint Fresnel; Fujii's energy-preserving Oren-Nayar
(``bsdf_oren_nayar.h``).  The formulas are listed in the package doc
(:mod:`core.materials`).  The per-lobe dispatch lives in
:mod:`core.materials.closures`.
"""
from __future__ import annotations

import numpy as np

from ..mathutil import dot as _dot
from ..scene.model import GLASS, GLOSSY, REFRACTION

INV_PI = 1.0 / np.pi

# GLOSSY Fresnel modes (Principled BSDF layers; the Metallic BSDF's two).
FRESNEL_NONE, FRESNEL_DIELECTRIC, FRESNEL_F82, FRESNEL_CONDUCTOR = 0, 1, 2, 3

# F82's angle: cos = 1/7 (~82 degrees), f = 1 - 1/7 and f^5 (Python's pow).
F82_COS = 1.0 / 7.0
F82_F = 6.0 / 7.0
F82_F5 = F82_F ** 5


def f0_from_ior(ior):
    """Normal-incidence dielectric reflectance ((ior - 1)/(ior + 1))^2."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def _fss_dielectric(eta):
    """Cycles' fresnel_dielectric_Fss: Kulla-Conty fit of 2 ∫ F(mu) mu dmu."""
    eta = np.asarray(eta, np.float64)
    return np.where(eta < 1.0, 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607)),
                    (eta - 1.0) / (4.08567 + 1.00071 * eta))


def _fresnel_tir(cos_i, eta):
    """:func:`fresnel_dielectric`'s F, cos_t before zeroing it, and the TIR mask."""
    c = np.abs(cos_i)
    g2 = eta * eta - 1.0 + c * c
    tir = g2 <= 0.0
    g = np.sqrt(np.where(tir, 1.0, g2))
    A = (g - c) / (g + c)
    B = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    F = np.where(tir, 1.0, 0.5 * A * A * (1.0 + B * B))
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - c * c) / (eta * eta)))
    return F, cos_t, tir


def fresnel_dielectric(cos_i: np.ndarray, eta: np.ndarray):
    """Exact unpolarised Fresnel reflectance and cos of the transmitted angle.

    cos_i: (k,) cosine on the incident side; eta: (k,) index of the far side
    over the incident side.  Returns (F, cos_t) with F = 1 and cos_t = 0 under
    total internal reflection (Cycles' ``fresnel_dielectric_cos``)."""
    F, cos_t, tir = _fresnel_tir(cos_i, eta)
    return F, np.where(tir, 0.0, cos_t)


def conductor_fresnel(cos_i, n, k):
    """Cycles' ``fresnel_conductor``: the unpolarised reflectance (..., 3) of a
    conductor of complex IOR n + ik (..., 3) from air, the mean of the s and
    p reflectances (Born & Wolf 14.4.1), at cos_i (...,) or (..., 1)."""
    c = np.asarray(cos_i, np.float64)
    c = c[..., None] if c.ndim == np.ndim(n) - 1 else c
    n2, k2 = n * n, k * k
    t1 = n2 - k2 - (1.0 - c * c)
    t2 = np.sqrt(t1 * t1 + (2.0 * n * k) ** 2)
    u2 = np.maximum(0.5 * (t2 + t1), 0.0)
    v2 = np.maximum(0.5 * (t2 - t1), 0.0)
    u, v = np.sqrt(u2), np.sqrt(v2)

    def ratio(a, b):                       # Cycles' safe_divide
        return np.where(b != 0.0, a / np.where(b != 0.0, b, 1.0), 0.0)
    Rs = ratio((c - u) ** 2 + v2, (c + u) ** 2 + v2)
    t3, t4 = (n2 - k2) * c, 2.0 * n * k * c
    Rp = ratio((t3 - u) ** 2 + (t4 - v) ** 2, (t3 + u) ** 2 + (t4 + v) ** 2)
    return 0.5 * (Rs + Rp)


def f82_b(F0, F82):
    """Cycles' ``fresnel_f82_B``: the F82 model's B from its values at 0 and ~82 degrees."""
    return (7.0 / (F82_F5 * F82_F)) * (F0 + (1.0 - F0) * F82_F5 - F82)


def f82_fss(F0, B):
    """Cycles' ``fresnel_f82_Fss``: the F82 model's hemispherical average 2 ∫ F mu dmu."""
    return F0 + (1.0 - F0) / 21.0 - B / 126.0


def conductor_fss(n, k):
    """Cycles' ``fresnel_conductor_Fss`` (..., 3): the F82 model fitted to the
    conductor at 0 and ~82 degrees, its average, clamped to [0, 1]."""
    F0 = conductor_fresnel(np.ones(np.shape(n)[:-1]), n, k)
    return np.clip(f82_fss(F0, f82_b(F0, conductor_fresnel(np.full(np.shape(n)[:-1], F82_COS),
                                                            n, k))), 0.0, 1.0)


def _principled_fresnel(mode, C, fior, tint, cos_hv, k=None, film=None):
    """Per-channel Fresnel (k, 3) of a Principled layer and its F_ss (k, 3).

    FRESNEL_DIELECTRIC: generalised Schlick with exponent -ior, f0 = F0 C,
    F = mix(f0, 1, s), s = sat((F_real(h.v) - F0)/(1 - F0)); F_ss uses
    Cycles' Fss fit for s.  FRESNEL_F82: F82-tint conductor, F0 = sat(C),
    F = sat(mix(F0, 1, (1-c)^5) - B c (1-c)^6),
    B = mix(F0, 1, f^5) 7/f^6 (1 - tint), f = 6/7; F_ss = mix(F0, 1, 1/21) - B/126.
    FRESNEL_CONDUCTOR (the Metallic BSDF's Physical Conductor): ``tint`` is
    the IOR n and ``k`` the extinction (k, 3); F = :func:`conductor_fresnel`
    times C, F_ss = :func:`conductor_fss` times C (C = 1: the lobe's
    colour is its mix weight).
    film (k, 2): a thin film's thickness (nm) and IOR over the surface
    (core.materials.thin_film): where it is thicker than THICKNESS_CUTOFF,
    F is the film's (``compiled.film_fresnel``); F_ss stays the bare one
    (Cycles' energy compensation reads it).
    """
    F, Fss = _bare_fresnel(mode, C, fior, tint, cos_hv, k)
    if film is not None:
        from .thin_film import THICKNESS_CUTOFF
        q = np.asarray(film)[:, 0] > THICKNESS_CUTOFF
        if q.any():
            from .compiled import film_fresnel
            ext = np.zeros(np.shape(C)) if k is None else k
            F = F.copy()
            F[q] = film_fresnel(mode, cos_hv[q], np.broadcast_to(fior, q.shape)[q],
                                np.broadcast_to(tint, np.shape(C))[q], ext[q], film[q], C[q])
    return F, Fss


def _bare_fresnel(mode, C, fior, tint, cos_hv, k):
    """:func:`_principled_fresnel` without a film."""
    if mode == FRESNEL_CONDUCTOR:
        return (C * conductor_fresnel(cos_hv, tint, k), C * conductor_fss(tint, k))
    if mode == FRESNEL_DIELECTRIC:
        F0 = f0_from_ior(fior)[:, None]
        f0 = np.clip(F0 * C, 0.0, 1.0)
        Fr = fresnel_dielectric(cos_hv, fior)[0][:, None]
        s = np.clip((Fr - F0) / np.maximum(1.0 - F0, 1e-12), 0.0, 1.0)
        s_ss = np.clip((_fss_dielectric(fior)[:, None] - F0) / np.maximum(1.0 - F0, 1e-12), 0.0, 1.0)
        return f0 + (1.0 - f0) * s, f0 + (1.0 - f0) * s_ss
    F0 = np.clip(C, 0.0, 1.0)
    B = (F0 + (1.0 - F0) * F82_F5) * (7.0 / (F82_F5 * F82_F)) * (1.0 - tint)
    c = cos_hv[:, None]
    sm = np.clip(1.0 - c, 0.0, 1.0)
    F = np.clip(F0 + (1.0 - F0) * sm ** 5 - B * c * sm ** 6, 0.0, 1.0)
    return F, f82_fss(F0, B)


# --------------------------------------------------------------------------
# GGX
# --------------------------------------------------------------------------
def ggx_D(alpha2, cos_h):
    c2 = np.minimum(cos_h * cos_h, 1.0)
    return alpha2 / (np.pi * (1.0 - c2 + alpha2 * c2) ** 2)


def ggx_lambda(alpha2, cos_n):
    c2 = np.maximum(cos_n * cos_n, 1e-300)
    return 0.5 * (np.sqrt(1.0 + alpha2 * np.maximum(1.0 / c2 - 1.0, 0.0)) - 1.0)


def _normalize(a):
    n = np.sqrt(_dot(a, a))
    return a / np.where(n > 0, n, 1.0)[:, None]


def _disk(u1, u2):
    """Shirley-Chiu concentric map of [0,1)^2 onto the unit disk (Cycles' sample_uniform_disk)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    big_a = np.abs(a) > np.abs(b)
    r = np.where(big_a, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(big_a, (np.pi / 4) * (b / a), np.pi / 2 - (np.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def ggx_sample_vndf(wl, alpha, u1, u2):
    """Heitz 2018 visible-normal sample (k, 3) in the local frame; wl (k, 3) with z > 0."""
    v = np.stack([alpha * wl[:, 0], alpha * wl[:, 1], wl[:, 2]], axis=1)
    v = _normalize(v)
    lensq = v[:, 0] ** 2 + v[:, 1] ** 2
    big = lensq > 1e-7
    inv = 1.0 / np.sqrt(np.where(big, lensq, 1.0))
    T1 = np.where(big[:, None], np.stack([-v[:, 1] * inv, v[:, 0] * inv, np.zeros_like(inv)], 1),
                  np.array([1.0, 0.0, 0.0]))
    T2 = np.cross(v, T1)
    tx, ty = _disk(u1, u2)
    s = 0.5 * (1.0 + v[:, 2])
    ty = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - tx * tx)) + s * ty
    tz = np.sqrt(np.maximum(0.0, 1.0 - tx * tx - ty * ty))
    Hh = tx[:, None] * T1 + ty[:, None] * T2 + tz[:, None] * v
    return _normalize(np.stack([alpha * Hh[:, 0], alpha * Hh[:, 1],
                                np.maximum(0.0, Hh[:, 2])], axis=1))


def _refraction_half(kind, eta, N, v, l):
    """Generalised half vector of refraction pairs (Walter 2007 eq. 16).

    eta: (k,) far-side index / v-side index; N, v, l: (k, 3), N oriented to
    v's side.  Returns Hu = -(eta l + v) (k, 3), the unit H on N's side
    (k, 3), h.v and h.l (k,), and the transmitted share (k,): 1 - F(h.v) for
    GLASS, 1 for REFRACTION (0 under total internal reflection)."""
    Hu = -(eta[:, None] * l + v)
    H = _normalize(Hu)
    H = H * np.where(_dot(N, H) < 0.0, -1.0, 1.0)[:, None]
    hv = _dot(H, v)
    hl = _dot(H, l)
    F = fresnel_dielectric(hv, eta)[0]
    T = (1.0 - F) if kind == GLASS else (F < 1.0).astype(np.float64)
    return Hu, H, hv, hl, T


def _microfacet_f(kind, alpha2, eta, N, v, l, Ng):
    """Scalar microfacet f(v, l) (k,) without colour, Cycles' bsdf_microfacet_eval / cos.

    kind GLOSSY, GLASS or REFRACTION; eta = far-side index / v-side index;
    N oriented to v's geometric side.  Ng (k, 3), the geometric normal
    oriented like N: as Cycles (4.0 on), l must be on the side of Ng that
    N says (above it for a reflection, below for a transmission), or f = 0:
    a shading normal that tilts l across the surface lets no light through
    it (and the sampler, :func:`_microfacet_pdf`, never gives such an l)."""
    cI = _dot(N, v)
    cO = _dot(N, l)
    out = np.zeros(len(cI))
    trans = cO < 0.0
    ok = (cI > 0.0) & ((_dot(Ng, l) < 0.0) == trans)
    if kind == GLOSSY:
        ok &= cO > 0.0
    lam_I = ggx_lambda(alpha2, cI)
    lam_O = ggx_lambda(alpha2, cO)
    G2 = 1.0 / (1.0 + lam_I + lam_O)
    # Reflection.
    r = ok & (cO > 0.0)
    if r.any():
        H = _normalize(v[r] + l[r])
        D = ggx_D(alpha2[r], _dot(N[r], H))
        val = D * G2[r] / (4.0 * cI[r] * cO[r])
        if kind == GLASS:
            val *= fresnel_dielectric(_dot(H, v[r]), eta[r])[0]
        elif kind == REFRACTION:
            val[:] = 0.0
        out[r] = val
    # Transmission (generalised half vector, Walter 2007 eq. 16).
    t = ok & trans & (kind != GLOSSY)
    if t.any():
        Hu, H, hv, hl, Tf = _refraction_half(kind, eta[t], N[t], v[t], l[t])
        # A physical refraction pair has h.v > 0 > h.l (Cycles leaves this TODO
        # unchecked in eval; its sampler never produces other pairs).
        phys = (hv > 0.0) & (hl < 0.0)
        D = ggx_D(alpha2[t], _dot(N[t], H))
        val = (Tf * D * G2[t] * eta[t] ** 2 * np.abs(hv * hl)
               / (cI[t] * np.abs(cO[t]) * _dot(Hu, Hu)))
        out[t] = np.where(phys, val, 0.0)
    return out


def _microfacet_pdf(kind, alpha2, eta, N, Ng, wo, wi):
    """Density (k,) of the VNDF sampler of wi given wo; N, Ng oriented to wo's side."""
    cI = _dot(N, wo)
    cO = _dot(N, wi)
    gO = _dot(Ng, wi)
    out = np.zeros(len(cI))
    ok = cI > 0.0
    G1 = 1.0 / (1.0 + ggx_lambda(alpha2, cI))
    r = ok & (cO > 0.0) & (gO > 0.0) & (kind != REFRACTION)
    if r.any():
        H = _normalize(wo[r] + wi[r])
        val = ggx_D(alpha2[r], _dot(N[r], H)) * G1[r] / (4.0 * cI[r])
        if kind == GLASS:
            val *= fresnel_dielectric(_dot(H, wo[r]), eta[r])[0]
        out[r] = val
    t = ok & (cO < 0.0) & (gO < 0.0) & (kind != GLOSSY)
    if t.any():
        Hu, H, ho, hi, sel = _refraction_half(kind, eta[t], N[t], wo[t], wi[t])
        val = (sel * ggx_D(alpha2[t], _dot(N[t], H)) * G1[t] / cI[t]
               * eta[t] ** 2 * np.abs(ho * hi) / _dot(Hu, Hu))
        out[t] = np.where((ho > 0.0) & (hi < 0.0), val, 0.0)
    return out


# --------------------------------------------------------------------------
# Oren-Nayar
# --------------------------------------------------------------------------
def _oren_nayar_G(c):
    """Cycles' bsdf_oren_nayar_G: the b-coefficient of the directional albedo E(mu)."""
    cs = np.maximum(c, 1e-6)
    s = np.sqrt(np.maximum(0.0, 1.0 - cs * cs))
    th = np.arccos(np.clip(cs, -1.0, 1.0))
    g = s * (th - 2.0 / 3.0 - s * cs) + 2.0 / 3.0 * (s / cs) * (1.0 - s * s * s)
    return np.where(c < 1e-6, (np.pi / 2 - 2.0 / 3.0) - c, g)


def oren_nayar_f(col, ucol, sigma, N, v, l):
    """Energy-preserving Oren-Nayar f (k, 3) (no cosine); zero below the normal."""
    sigma = np.clip(sigma, 0.0, 1.0)
    a = 1.0 / (np.pi + sigma * (np.pi / 2 - 2.0 / 3.0))
    b = sigma * a
    nl_raw = _dot(N, l)
    nl = np.maximum(nl_raw, 0.0)
    nv = np.maximum(_dot(N, v), 0.0)
    t = _dot(l, v) - nl * nv
    t = np.where(t > 0.0, t / (np.maximum(nl, nv) + 1e-38), t)
    single = a + b * t
    A = np.clip(ucol, 0.0, 1.0)
    Eavg = (a * np.pi + (2.0 * np.pi - 5.6) / 3.0 * b)[:, None]
    Ems = INV_PI * A * A * (Eavg / (1.0 - Eavg)) / (1.0 - A * (1.0 - Eavg))
    Ev = a * np.pi + b * _oren_nayar_G(nv)
    El = a * np.pi + b * _oren_nayar_G(nl)
    f = col * (single[:, None] + Ems * ((1.0 - Ev) * (1.0 - El))[:, None])
    return f * (nl_raw > 0.0)[:, None]
