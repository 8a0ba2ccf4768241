"""The thin film's Airy sum, compiled (core.materials.thin_film: the model,
the table and Cycles' functions it follows)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .microfacet import F82_F, F82_F5
from .thin_film import TABLE_SIZE, sensitivity_table


@njit(cache=True, error_model="numpy")
def _sensitivity(T, off, ch, D):
    """(Re, Im) of S_ch at path difference D (nm): Cycles' lookup_table_read."""
    x = min(max(2.0 * math.pi * D / 60000.0, 0.0), 1.0) * (TABLE_SIZE - 1)
    i = min(int(x), TABLE_SIZE - 1)
    j = min(i + 1, TABLE_SIZE - 1)
    t = x - i
    a = off + ch * TABLE_SIZE
    b = off + (ch + 3) * TABLE_SIZE
    return (1.0 - t) * T[a + i] + t * T[a + j], (1.0 - t) * T[b + i] + t * T[b + j]


@njit(cache=True, error_model="numpy")
def _airy(T, off, ch, R12, R23, D, pr, pi_):
    """The Airy sum of one polarisation (Belcour & Barla eq. 10), the phase
    e^{i phi} = pr + i pi_."""
    T121 = 1.0 - R12
    R123 = R12 * R23
    r123 = math.sqrt(R123)
    Rs = T121 * T121 * R23 / (1.0 - R123)
    ar, ai = pr, pi_
    R = Rs + R12
    Cm = Rs - T121
    for m in range(1, 4):
        Cm *= r123
        sr, si = _sensitivity(T, off, ch, m * D)
        R += Cm * 2.0 * (ar * sr + ai * si)
        ar, ai = ar * pr - ai * pi_, ar * pi_ + ai * pr
    return R


@njit(cache=True, error_model="numpy")
def _dielectric_polarized(c, eta):
    """Cycles' fresnel_dielectric_polarized: (R_s, R_p, cos_t, sign of r_s,
    sign of r_p); total internal reflection: (1, 1, 0, 1, 1)."""
    e2 = eta * eta - (1.0 - c * c)
    if e2 <= 0.0:
        return 1.0, 1.0, 0.0, 1.0, 1.0
    c = abs(c)
    ct = -math.sqrt(e2) / eta
    rs = (c + eta * ct) / (c - eta * ct)
    rp = (ct + eta * c) / (eta * c - ct)
    return rs * rs, rp * rp, ct, 1.0 if rs >= 0.0 else -1.0, 1.0 if rp >= 0.0 else -1.0


@njit(cache=True, error_model="numpy")
def _f82(c, F0, B):
    """Cycles' scalar fresnel_f82."""
    s = min(max(1.0 - c, 0.0), 1.0)
    s5 = s * s * s * s * s
    return min(max(F0 + (1.0 - F0) * s5 - B * c * s5 * s, 0.0), 1.0)


@njit(cache=True, error_model="numpy")
def _conductor_polarized(c, e1, n, k, F82):
    """Cycles' fresnel_conductor_polarized from a medium of index e1 onto
    n + ik: (R_s, R_p, phasor_s re, im, phasor_p re, im); F82 >= 0: the
    reflectances of the F82 model through F0(n/e1, k/e1) and F82."""
    e1s, n2, k2 = e1 * e1, n * n, k * k
    tnk = 2.0 * n * k
    t1 = n2 - k2 - e1s * (1.0 - c * c)
    t2 = math.sqrt(t1 * t1 + tnk * tnk)
    u2 = max(0.5 * (t2 + t1), 0.0)
    v2 = max(0.5 * (t2 - t1), 0.0)
    u, v = math.sqrt(u2), math.sqrt(v2)
    if F82 >= 0.0:
        nn, kk = n / e1, (k / e1) * (k / e1)
        F0 = ((nn - 1.0) * (nn - 1.0) + kk) / ((nn + 1.0) * (nn + 1.0) + kk)
        B = (7.0 / (F82_F5 * F82_F)) * (F0 + (1.0 - F0) * F82_F5 - F82)   # fresnel_f82_B
        Rs = _f82(c, F0, B)
        Rp = Rs
    else:
        b = (e1 * c + u) ** 2 + v2
        Rs = ((e1 * c - u) ** 2 + v2) / b if b != 0.0 else 0.0
        t3, t4 = (n2 - k2) * c, tnk * c
        b = (t3 + e1 * u) ** 2 + (t4 + e1 * v) ** 2
        Rp = ((t3 - e1 * u) ** 2 + (t4 - e1 * v) ** 2) / b if b != 0.0 else 0.0
    re = -u2 - v2 + (e1 * c) ** 2
    im = -2.0 * e1 * c * v
    mag = math.sqrt(re * re + im * im)
    psr, psi = (1.0, 0.0) if mag == 0.0 else (re / mag, im / mag)
    re = ((n2 + k2) * c) ** 2 - e1s * (u2 + v2)
    im = 2.0 * e1 * c * (tnk * u - (n2 - k2) * v)
    mag = math.sqrt(re * re + im * im)
    ppr, ppi = (1.0, 0.0) if mag == 0.0 else (re / mag, im / mag)
    return Rs, Rp, psr, psi, ppr, ppi


@njit(cache=True, error_model="numpy")
def iridescence(T, off, ch, c, d, nf, n3, k3, F82, conductive):
    """Cycles' fresnel_iridescence_channel from air (index 1): the
    reflectance of channel ch at cos(theta_1) = c of a film of thickness d
    (nm) and index nf over a dielectric of index n3 (conductive False) or a
    conductor n3 + i k3 (F82 >= 0: its reflectances from the F82 model).
    T, off: the table (:func:`sensitivity_table`) at offset off of T."""
    if d < 1.0:                        # below 1 nm: blend towards no film
        t = min(max(d, 0.0), 1.0)
        nf = 1.0 + (nf - 1.0) * (t * t * (3.0 - 2.0 * t))
    R12s, R12p, c2, p12s, p12p = _dielectric_polarized(c, nf)
    if R12s == 1.0 and R12p == 1.0:
        return 1.0
    if conductive:
        R23s, R23p, p23sr, p23si, p23pr, p23pi = _conductor_polarized(-c2, nf, n3, k3, F82)
    else:
        R23s, R23p, _, s_, p_ = _dielectric_polarized(-c2, n3 / nf)
        if R23s == 1.0 and R23p == 1.0:
            return 1.0
        p23sr, p23si, p23pr, p23pi = s_, 0.0, p_, 0.0
    D = -2.0 * nf * d * c2
    Rs = _airy(T, off, ch, R12s, R23s, D, -p12s * p23sr, -p12s * p23si)
    Rp = _airy(T, off, ch, R12p, R23p, D, -p12p * p23pr, -p12p * p23pi)
    return min(max(0.5 * (Rs + Rp), 0.0), 1.0)


@njit(cache=True, error_model="numpy")
def _rgb_kernel(T, c, d, nf, n3, k3, F82, conductive, out):
    for i in range(c.shape[0]):
        for ch in range(3):
            # offset 0 as int64, not a literal: the signature compiled.py's
            # calls compile (one a kernel)
            out[i, ch] = iridescence(T, np.int64(0), ch, c[i], d[i], nf[i], n3[i, ch], k3[i, ch],
                                     F82[i, ch], conductive)


def iridescence_rgb(c, d, nf, n3, k3=None, F82=None) -> np.ndarray:
    """(k, 3) float64 :func:`iridescence` of k points: c, d, nf (k,); n3
    (k, 3) the substrate's index (a dielectric when k3 is None) or a
    conductor's n with k3 (k, 3) and F82 (k, 3) (negative: the exact
    conductor)."""
    c = np.ascontiguousarray(c, np.float64).reshape(-1)
    K = c.shape[0]
    f = lambda a, fill: np.ascontiguousarray(  # noqa: E731
        np.broadcast_to(fill if a is None else a, (K, 3)), np.float64)
    g = lambda a: np.ascontiguousarray(np.broadcast_to(a, (K,)), np.float64)  # noqa: E731
    out = np.empty((K, 3))
    _rgb_kernel(sensitivity_table(), c, g(d), g(nf), f(n3, 1.0), f(k3, 0.0), f(F82, -1.0),
                k3 is not None, out)
    return out
