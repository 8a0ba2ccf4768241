"""Compiled evaluation of a material's non-delta BSDF, one (point, direction) pair at a time.

The numba twin of :func:`core.materials.eval_bsdf` in radiance mode
(``closures._eval_nd`` with ``_bump_corrected`` and ``_orient``): every lobe
kind and option of the :class:`MaterialTable` -- Lambert and Fujii's
Oren-Nayar diffuse, translucent, GGX glossy / glass / refraction, the
Principled BSDF's generalised-Schlick and F82-tint Fresnel, the diffuse
under a specular layer, Multiscatter GGX, and for Normal Map / Bump
materials Cycles' normal tilt and diffuse bump shadowing.  The formulas are
those of :mod:`.closures`, :mod:`.microfacet` and :mod:`.multiscatter`
(listed in the package doc), written per pair in float64 in the same
operation order, so the two agree to rounding (tests/test_compiled_bsdf.py,
numpy is the oracle).  The albedo tables are read from arrays filled once
per material table (:func:`compile_materials`) with the slices the numpy
code would compute.

Used where the photon gather hands back (visible point, photon) pairs of
non-Lambert points (``core.sppm.photon_pass``: the reflected flux, and the
receivers' glossy share for the frequency kernel's per-pair radius), where
the numpy evaluation cost ~2 us a pair; by the photon tracer's generic hits
(:func:`sample_pair`, importance mode); and by the camera paths' glossy
vertices (radiance mode: "Radiance mode over arrays" at the end).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .._numba_options import NO_REFCOUNTS
from ..scene.model import (DIFFUSE, GLASS, GLOSSY, REFRACTION, TRANSLUCENT, TRANSPARENT,
                           VIEW_SAMPLES)
from .microfacet import (F82_COS, F82_F as _F82_F, F82_F5 as _F82_F5, FRESNEL_CONDUCTOR,
                         FRESNEL_DIELECTRIC, FRESNEL_F82, INV_PI)
from .multiscatter import _lerp_index, _ms_glass_slice, _ms_tables, _schlick_s_slice
from .table import DIFFUSE_ROUGHNESS_EPS
from .thin_film import TABLE_SIZE as _N_FILM, THICKNESS_CUTOFF, sensitivity_table
from .thin_film_kernels import _conductor_polarized, iridescence

# Sizes of Cycles' albedo tables (multiscatter.py).
_N_GGX, _N_GLASS, _N_S = 32, 16, 16


# Columns of CompiledMaterials.lobes (per material and slot, float64).
F_KIND, F_ND, F_W, F_ROUGH, F_A2, F_IOR, F_MS, F_FRES, F_FIOR = range(9)
F_TINT = 9                     # 9, 10, 11: f82_tint RGB, or a conductor's IOR n
F_LIOR, F_LF0, F_LROUGH, F_LMS, F_BUMP = 12, 13, 14, 15, 16
F_VIEW = 17                    # 1 + the offset in tables of the lobe's view factor (Lobe.view), 0 none
F_K = 18                       # 18, 19, 20: a conductor's extinction k
F_FILM_D, F_FILM_N = 21, 22    # a thin film's thickness (nm; 0: none) and IOR (a DIFFUSE's: its layer's)
N_FIELDS = 23
# Offsets of the albedo tables in CompiledMaterials.tables (flat, C order).
T_GGX_E = 0                                    # (32, 32) [rough, mu]
T_GGX_EAVG = T_GGX_E + _N_GGX * _N_GGX         # (32,) [rough]
T_GLASS_E = T_GGX_EAVG + _N_GGX                # (2, 16, 16, 16) [1/ior?, ior node, rough, mu]
T_GLASS_EAVG = T_GLASS_E + 2 * _N_GLASS ** 3   # (2, 16, 16) [1/ior?, ior node, rough]
T_S = T_GLASS_EAVG + 2 * _N_GLASS ** 2         # (16, 16, 16) [ior node, rough, mu]
T_FILM = T_S + _N_S ** 3                       # (6, 512) thin_film.sensitivity_table
_T_FILM = np.int64(T_FILM)    # an int64 in the kernels, not a literal: one signature (eval_pair_as)
N_TABLES = T_FILM + 6 * _N_FILM
# After them: the view factors' rows (VIEW_SAMPLES each, MaterialTable.view_tab).


class CompiledMaterials(NamedTuple):
    """A :class:`MaterialTable` as the compiled evaluation reads it: two
    arrays, so that a kernel takes them once (numba reference-counts every
    array it reads from a struct, ~27 atomic operations a pair with one
    array per field).

    lobes (M, L, N_FIELDS) float64, M materials, L lobe slots, columns F_*:
    kind (-1 unused), nd (1: used and not delta), mix weight, roughness,
    GGX alpha^2 = roughness^4 (computed by numpy: its pow differs from
    libm's in the last bit for ~5 % of values, and numpy's is the oracle's),
    ior, Multiscatter GGX (0 / 1), FRESNEL_*, fresnel_ior, f82_tint RGB
    (FRESNEL_CONDUCTOR: its IOR n), layer_ior, layer_f0, layer_roughness,
    layer_ms, the material's Normal Map / Bump flag (normal tilt, diffuse
    bump shadowing) in every slot, the view factor's offset and a
    FRESNEL_CONDUCTOR's extinction k RGB, a thin film's thickness and IOR
    (a DIFFUSE lobe's: its specular layer's).  Absent optional table
    fields take what the numpy code assumes.
    tables (N_TABLES,) float64: the albedo tables at the T_* offsets; only
    the ior nodes some lobe reads are filled (the rest are zero)."""
    lobes: np.ndarray
    tables: np.ndarray


def _z_nodes(ior):
    """The ior-axis nodes (k and k + 1) :func:`multiscatter._lerp_index` reads for iors (n,)."""
    z = np.sqrt(np.abs((ior - 1.0) / (ior + 1.0)))
    k, _ = _lerp_index(z, _N_GLASS)
    return sorted(set(k.tolist()) | set((k + 1).tolist()))


def _bump_codes(table) -> np.ndarray:
    """(M,) float64 F_BUMP: 0 no Normal Map / Bump, 1 its two corrections
    (the valid specular normal, the diffuse lobes' bump shadowing), 2 the
    normal's alone (a displacement's bump: ``MaterialTable.bump_unshadowed``)."""
    M = table.kind.shape[0]
    b = getattr(table, "bump_correction", None)
    if b is None:
        return np.zeros(M)
    off = getattr(table, "bump_unshadowed", None)
    off = np.zeros(M, bool) if off is None else np.asarray(off, bool)
    return np.where(np.asarray(b, bool), np.where(off, 2.0, 1.0), 0.0)


def compile_materials(table) -> CompiledMaterials:
    """The :class:`CompiledMaterials` of a ``MaterialTable`` (cached on the table:
    tables are not modified once built)."""
    cm = getattr(table, "_compiled", None)
    if cm is not None:
        return cm
    M, L = table.kind.shape
    kind = np.asarray(table.kind)
    nd = (kind >= 0) & ~np.asarray(table.lobe_delta, bool)

    def opt(name, fill, shape=(M, L)):
        a = getattr(table, name, None)
        return np.full(shape, fill, np.float64) if a is None else np.asarray(a, np.float64)
    lo = np.zeros((M, L, N_FIELDS))
    rough = np.asarray(table.roughness, np.float64)
    ior = np.asarray(table.ior, np.float64)
    for col, a in ((F_KIND, kind), (F_ND, nd), (F_W, table.weight), (F_ROUGH, rough),
                   (F_A2, rough ** 4), (F_IOR, ior), (F_MS, opt("multiscatter", 0.0)),
                   (F_FRES, opt("fresnel", 0.0)), (F_FIOR, opt("fresnel_ior", 1.0)),
                   (F_LIOR, opt("layer_ior", 0.0)), (F_LF0, opt("layer_f0", 0.0)),
                   (F_LROUGH, opt("layer_roughness", 0.0)), (F_LMS, opt("layer_ms", 0.0)),
                   (F_BUMP, _bump_codes(table)[:, None])):
        lo[:, :, col] = a
    lo[:, :, F_TINT:F_TINT + 3] = opt("f82_tint", 1.0, (M, L, 3))
    if getattr(table, "thin_film", None) is not None:
        lo[:, :, F_FILM_D:F_FILM_N + 1] = table.thin_film
    cond = opt("fresnel", 0.0) == FRESNEL_CONDUCTOR
    if cond.any():
        lo[cond, F_TINT:F_TINT + 3] = np.asarray(table.conductor_n, np.float64)[cond]
        lo[cond, F_K:F_K + 3] = np.asarray(table.conductor_k, np.float64)[cond]
    vl = getattr(table, "view_lut", None)
    nv = 0 if vl is None else len(table.view_tab)
    if nv:
        lo[:, :, F_VIEW] = np.where(vl >= 0, 1 + N_TABLES + VIEW_SAMPLES * vl, 0.0)
    tabs = np.zeros(N_TABLES + VIEW_SAMPLES * nv)
    if nv:
        tabs[N_TABLES:] = np.concatenate([np.asarray(r, np.float64) for r in table.view_tab])
    E, Eavg = _ms_tables()
    tabs[T_GGX_E:T_GGX_EAVG] = E.ravel()
    tabs[T_FILM:N_TABLES] = sensitivity_table()
    tabs[T_GGX_EAVG:T_GLASS_E] = Eavg
    gE = tabs[T_GLASS_E:T_GLASS_EAVG].reshape(2, _N_GLASS, _N_GLASS, _N_GLASS)
    gA = tabs[T_GLASS_EAVG:T_S].reshape(2, _N_GLASS, _N_GLASS)
    sT = tabs[T_S:T_FILM].reshape(_N_S, _N_S, _N_S)
    # Glass: multiscatter_factor reads (1/ior?, node) for eta = ior entering
    # and 1/ior leaving; it folds eta < 1 to 1/eta, as here.
    g = (lo[:, :, F_MS] > 0) & nd & (kind == GLASS)
    for eta in (ior[g], 1.0 / ior[g]):
        inv = eta < 1.0
        ior_n = np.where(inv, 1.0 / eta, eta)
        for s_ in (0, 1):
            for kk in _z_nodes(ior_n[inv == bool(s_)]):
                gE[s_, kk], gA[s_, kk] = _ms_glass_slice(s_, kk)
    lior = lo[:, :, F_LIOR]
    for kk in _z_nodes(lior[nd & (kind == DIFFUSE) & (lior > 0.0)]):
        sT[kk] = _schlick_s_slice(kk)
    cm = CompiledMaterials(lobes=lo, tables=tabs)
    try:
        table._compiled = cm
    except AttributeError:
        pass
    return cm


# --------------------------------------------------------------------------
# Building blocks (scalar twins of microfacet.py / multiscatter.py)
# --------------------------------------------------------------------------
@njit(cache=True, inline="always", error_model="numpy")
def _clip01(x):
    return min(max(x, 0.0), 1.0)


@njit(cache=True, inline="always", error_model="numpy")
def _lerp(x, n):
    """multiscatter._lerp_index for one x: (node, fraction)."""
    t = _clip01(x) * (n - 1)
    i = min(int(math.floor(t)), n - 2)
    return i, t - i


@njit(cache=True, inline="always", error_model="numpy")
def _bilerp(T, o, n, i, ti, j, tj):
    """multiscatter._bilerp of the (n, n) table at offset o of the flat T."""
    a = o + i * n + j
    return ((1 - ti) * ((1 - tj) * T[a] + tj * T[a + 1])
            + ti * ((1 - tj) * T[a + n] + tj * T[a + n + 1]))


@njit(cache=True, inline="always", error_model="numpy")
def _fresnel(cos_i, eta):
    """microfacet._fresnel_tir's F (1 under total internal reflection)."""
    c = abs(cos_i)
    g2 = eta * eta - 1.0 + c * c
    if g2 <= 0.0:
        return 1.0
    g = math.sqrt(g2)
    A = (g - c) / (g + c)
    B = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * A * A * (1.0 + B * B)


@njit(cache=True, inline="always", error_model="numpy")
def _fss(eta):
    """microfacet._fss_dielectric."""
    if eta < 1.0:
        return 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607))
    return (eta - 1.0) / (4.08567 + 1.00071 * eta)


@njit(cache=True, inline="always", error_model="numpy")
def _f0(ior):
    q = (ior - 1.0) / (ior + 1.0)
    return q * q


@njit(cache=True, inline="always", error_model="numpy")
def _lambda(a2, c):
    """microfacet.ggx_lambda."""
    c2 = max(c * c, 1e-300)
    return 0.5 * (math.sqrt(1.0 + a2 * max(1.0 / c2 - 1.0, 0.0)) - 1.0)


@njit(cache=True, inline="always", error_model="numpy")
def _D(a2, ch):
    """microfacet.ggx_D."""
    c2 = min(ch * ch, 1.0)
    q = 1.0 - c2 + a2 * c2
    return a2 / (np.pi * (q * q))


@njit(cache=True, inline="always", error_model="numpy")
def _dot3(ax, ay, az, bx, by, bz):
    """mathutil.dot of one row, bit for bit: numpy's einsum("ij,ij->i") of
    3-vectors adds (x z) first, then y (measured; the pairing of its
    unrolled loop)."""
    return (ax * bx + az * bz) + ay * by


@njit(cache=True, inline="always", error_model="numpy")
def _unit(x, y, z):
    n = math.sqrt(_dot3(x, y, z, x, y, z))
    if not n > 0:
        n = 1.0
    return x / n, y / n, z / n


@njit(cache=True, inline="always", error_model="numpy")
def _refraction_half(kind, eta, Nx, Ny, Nz, vx, vy, vz, lx, ly, lz):
    """microfacet._refraction_half for one pair (Walter 2007 eq. 16): Hu,
    the unit H on N's side, h.v, h.l and the transmitted share."""
    ux, uy, uz = -(eta * lx + vx), -(eta * ly + vy), -(eta * lz + vz)
    hx, hy, hz = _unit(ux, uy, uz)
    if _dot3(Nx, Ny, Nz, hx, hy, hz) < 0.0:
        hx, hy, hz = hx * -1.0, hy * -1.0, hz * -1.0
    hv = _dot3(hx, hy, hz, vx, vy, vz)
    hl = _dot3(hx, hy, hz, lx, ly, lz)
    F = _fresnel(hv, eta)
    if kind == GLASS:
        T = 1.0 - F
    else:
        T = 1.0 if F < 1.0 else 0.0
    return ux, uy, uz, hx, hy, hz, hv, hl, T


@njit(cache=True, error_model="numpy")
def _microfacet(kind, a2, eta, Nx, Ny, Nz, vx, vy, vz, lx, ly, lz, gl):
    """microfacet._microfacet_f for one pair (scalar, no colour); gl = Ng.l,
    the geometric normal oriented like N (its side test)."""
    cI = _dot3(Nx, Ny, Nz, vx, vy, vz)
    cO = _dot3(Nx, Ny, Nz, lx, ly, lz)
    if not cI > 0.0:
        return 0.0
    if (gl < 0.0) != (cO < 0.0):
        return 0.0
    if kind == GLOSSY and not cO > 0.0:
        return 0.0
    G2 = 1.0 / (1.0 + _lambda(a2, cI) + _lambda(a2, cO))
    if cO > 0.0:
        if kind == REFRACTION:
            return 0.0
        hx, hy, hz = _unit(vx + lx, vy + ly, vz + lz)
        val = _D(a2, _dot3(Nx, Ny, Nz, hx, hy, hz)) * G2 / (4.0 * cI * cO)
        if kind == GLASS:
            val *= _fresnel(_dot3(hx, hy, hz, vx, vy, vz), eta)
        return val
    if cO < 0.0 and kind != GLOSSY:
        ux, uy, uz, hx, hy, hz, hv, hl, T = _refraction_half(kind, eta, Nx, Ny, Nz,
                                                             vx, vy, vz, lx, ly, lz)
        if not (hv > 0.0 and hl < 0.0):
            return 0.0
        D = _D(a2, _dot3(Nx, Ny, Nz, hx, hy, hz))
        return (T * D * G2 * (eta * eta) * abs(hv * hl)
                / (cI * abs(cO) * _dot3(ux, uy, uz, ux, uy, uz)))
    return 0.0


@njit(cache=True, inline="always", error_model="numpy")
def _on_G(c):
    """microfacet._oren_nayar_G."""
    if c < 1e-6:
        return (np.pi / 2 - 2.0 / 3.0) - c
    cs = max(c, 1e-6)
    s = math.sqrt(max(0.0, 1.0 - cs * cs))
    th = math.acos(min(max(cs, -1.0), 1.0))
    return s * (th - 2.0 / 3.0 - s * cs) + 2.0 / 3.0 * (s / cs) * (1.0 - s * s * s)


@njit(cache=True, inline="always", error_model="numpy")
def _ggx_albedo(T, rough, mu):
    """multiscatter._ggx_albedo: (E, E_avg)."""
    i, ti = _lerp(rough, _N_GGX)
    j, tj = _lerp(mu, _N_GGX)
    return (_bilerp(T, T_GGX_E, _N_GGX, i, ti, j, tj),
            (1 - ti) * T[T_GGX_EAVG + i] + ti * T[T_GGX_EAVG + i + 1])


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _layer_transmission(T, f0, rough, ior, mu, ms, fd, fn):
    """multiscatter.layer_transmission for one point (a film of thickness
    fd and IOR fn on the layer: its Fresnel at mu, the largest channel)."""
    if fd > THICKNESS_CUTOFF:
        A = 0.0
        for ch in range(3):
            A = max(A, _film_dielectric(T, ch, mu, fd, fn, ior, f0))
    else:
        z = math.sqrt(abs((ior - 1.0) / (ior + 1.0)))
        k, tk = _lerp(z, _N_S)
        i, ti = _lerp(rough, _N_S)
        j, tj = _lerp(mu, _N_S)
        s = 0.0
        s += (1 - tk) * _bilerp(T, T_S + k * _N_S * _N_S, _N_S, i, ti, j, tj)
        s += tk * _bilerp(T, T_S + (k + 1) * _N_S * _N_S, _N_S, i, ti, j, tj)
        A = f0 + (1.0 - f0) * s
    if ms:
        F0 = _f0(ior)
        s_ss = _clip01((_fss(ior) - F0) / max(1.0 - F0, 1e-12))
        fss = f0 + (1.0 - f0) * s_ss
        E, Eavg = _ggx_albedo(T, rough, mu)
        fms = fss * Eavg / max(1.0 - fss * (1.0 - Eavg), 1e-12)
        A *= E + fms * (1.0 - E)
    return _clip01(1.0 - A)


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _ms_albedo(T, kind, rough, eta, mu):
    """The (E, E_avg) of multiscatter.multiscatter_factor."""
    if kind != GLASS:
        return _ggx_albedo(T, rough, mu)
    inv = 1 if eta < 1.0 else 0
    ior = 1.0 / eta if inv == 1 else eta
    z = math.sqrt(abs((ior - 1.0) / (ior + 1.0)))
    k, tk = _lerp(z, _N_GLASS)
    i, ti = _lerp(rough, _N_GLASS)
    j, tj = _lerp(mu, _N_GLASS)
    E = 0.0
    Eavg = 0.0
    for dk in range(2):
        wk = tk if dk else 1 - tk
        node = inv * _N_GLASS + k + dk
        E += wk * _bilerp(T, T_GLASS_E + node * _N_GLASS * _N_GLASS, _N_GLASS, i, ti, j, tj)
        a = T_GLASS_EAVG + node * _N_GLASS + i
        Eavg += wk * ((1 - ti) * T[a] + ti * T[a + 1])
    return E, Eavg


@njit(cache=True, inline="always", error_model="numpy")
def _ms_channel(C, E, Eavg):
    """One channel of multiscatter_factor: 1 + F_ms (1 - E)/E (E already >= 1e-6)."""
    C = max(C, 0.0)
    Fms = C * Eavg / max(1.0 - C * (1.0 - Eavg), 1e-12)
    return 1.0 + Fms * (1.0 - E) / E


@njit(cache=True, inline="always", error_model="numpy")
def _schlick_channel(C, F0, s, s_ss):
    """FRESNEL_DIELECTRIC of microfacet._principled_fresnel, one channel: (F, F_ss)."""
    f0 = _clip01(F0 * C)
    return f0 + (1.0 - f0) * s, f0 + (1.0 - f0) * s_ss


@njit(cache=True, inline="always", error_model="numpy")
def _f82_channel(C, tint, c):
    """FRESNEL_F82 of microfacet._principled_fresnel, one channel: (F, F_ss)."""
    F0 = _clip01(C)
    B = (F0 + (1.0 - F0) * _F82_F5) * (7.0 / (_F82_F5 * _F82_F)) * (1.0 - tint)
    sm = _clip01(1.0 - c)
    F = _clip01(F0 + (1.0 - F0) * sm ** 5.0 - B * c * sm ** 6.0)
    return F, F0 + (1.0 - F0) / 21.0 - B / 126.0


@njit(cache=True, error_model="numpy")
def _conductor(c, n, k):
    """microfacet.conductor_fresnel of one channel (Cycles' fresnel_conductor):
    the mean of the s and p reflectances from air."""
    r = _conductor_polarized(c, 1.0, n, k, -1.0)
    return 0.5 * (r[0] + r[1])


@njit(cache=True, error_model="numpy")
def _conductor_channel(C, n, k, c):
    """FRESNEL_CONDUCTOR of microfacet._principled_fresnel, one channel: (F, F_ss)."""
    F0 = _conductor(1.0, n, k)
    B = (7.0 / (_F82_F5 * _F82_F)) * (F0 + (1.0 - F0) * _F82_F5 - _conductor(F82_COS, n, k))
    return C * _conductor(c, n, k), C * _clip01(F0 + (1.0 - F0) / 21.0 - B / 126.0)


@njit(cache=True, inline="always", error_model="numpy")
def _bump_shadowing(Sx, Sy, Sz, Nx, Ny, Nz, lx, ly, lz):
    """closures._bump_shadowing (Conty Estevez et al. 2019) for one pair."""
    cos_si = _dot3(Sx, Sy, Sz, lx, ly, lz)
    cos_sn = _dot3(Sx, Sy, Sz, Nx, Ny, Nz)
    cos_ni = _dot3(Nx, Ny, Nz, lx, ly, lz)
    if cos_si * cos_sn * cos_ni < 0.0:
        return 0.0
    cos_i = abs(cos_si)
    cos_d = abs(cos_sn)
    if cos_d >= 1.0 or cos_i >= 1.0:
        return 1.0
    if cos_i < 1e-6:
        return 0.0
    m = max(cos_d, 1e-12)
    a2 = _clip01(0.125 * (1.0 / (m * m) - 1.0))
    tan2_i = (1.0 - cos_i * cos_i) / max(cos_i * cos_i, 1e-300)
    return 2.0 / (1.0 + math.sqrt(1.0 + a2 * tan2_i))


@njit(cache=True, error_model="numpy")
def _valid_specular_normal(gx, gy, gz, ix, iy, iz, nx, ny, nz):
    """core.scene.normals.valid_specular_normal for one point (ng, n on i's side)."""
    ni = _dot3(nx, ny, nz, ix, iy, iz)
    Rx, Ry, Rz = 2.0 * ni * nx - ix, 2.0 * ni * ny - iy, 2.0 * ni * nz - iz
    iz_ = _dot3(ix, iy, iz, gx, gy, gz)
    t = min(0.9 * iz_, 0.01)
    if not _dot3(gx, gy, gz, Rx, Ry, Rz) < t:
        return nx, ny, nz
    ng_ = _dot3(nx, ny, nz, gx, gy, gz)
    Xx, Xy, Xz = nx - ng_ * gx, ny - ng_ * gy, nz - ng_ * gz
    ln = math.sqrt(Xx * Xx + Xy * Xy + Xz * Xz)
    if ln > 1e-12:
        d = max(ln, 1e-300)
        Xx, Xy, Xz = Xx / d, Xy / d, Xz / d
    else:
        Xx, Xy, Xz = nx, ny, nz
    ix_ = _dot3(ix, iy, iz, Xx, Xy, Xz)
    a = ix_ * ix_ + iz_ * iz_
    if not a > 0:
        return nx, ny, nz
    b = 2.0 * (a + iz_ * t)
    c = (t + iz_) * (t + iz_)
    root = math.sqrt(max(b * b - 4.0 * a * c, 0.0))
    if ix_ < 0:
        nz2 = 0.25 * (b + root) / a
    else:
        nz2 = 0.25 * (b - root) / a
    ex = math.sqrt(max(1.0 - nz2, 0.0))
    ez = math.sqrt(max(nz2, 0.0))
    return ex * Xx + ez * gx, ex * Xy + ez * gy, ex * Xz + ez * gz


# --------------------------------------------------------------------------
# A material's non-delta BSDF at one pair
# --------------------------------------------------------------------------
@njit(cache=True, error_model="numpy", inline="always")
def eval_pair(lobes, T, m, colors, row, nsx, nsy, nsz, ngx, ngy, ngz, vx, vy, vz, lx, ly, lz,
              want_smooth):
    """Cycles' f(view=v, light=l) of material m's non-delta lobes, radiance
    mode (closures.eval_bsdf): (f_r, f_g, f_b, s_r, s_g, s_b).  lobes, T:
    a CompiledMaterials' arrays (passed alone: no reference counting of a
    struct's members in the loop).  colors[row] (L, 3) the point's lobe colours (``lobe_colors``, any float dtype); ns, ng unit
    mesh normals in any orientation; v, l unit; all float64 scalars.
    s: with want_smooth, the same sum as ``Receivers.smooth`` evaluates it
    (the DIFFUSE / TRANSLUCENT lobes alone, the microfacet lobes left out),
    else 0.  A Normal Map / Bump material (F_BUMP) gets Cycles' two
    corrections (docs/shading.md): :func:`eval_pair_as`."""
    return eval_pair_as(lobes, T, m, colors, row, nsx, nsy, nsz, ngx, ngy, ngz, vx, vy, vz,
                        lx, ly, lz, want_smooth, lobes[m, 0, F_BUMP] > 0.0)


# The two lobe helpers are functions of their own, called from eval_pair_as's
# lobe loop, not inlined into it: written inline, LLVM hoisted their parts
# that do not depend on the lobe (F82's two powers of 1 - h.v, the half
# vector, ...) out of the loop and computed them on every call, for every
# material, whether it had such a lobe or not (about 40 % of the cost of a
# Lambert material's f; docs/architecture.md "The BSDF evaluation's fixed
# cost, round 32").  A call is not hoisted.  Same arithmetic, same bits.
@njit(cache=True, error_model="numpy")
def _diffuse_lobe(k, rough, c0, c1, c2, u0, u1, u2, nl, nv, lv):
    """f of one DIFFUSE or TRANSLUCENT lobe (colour c, albedo u = c / weight):
    Lambert (roughness below DIFFUSE_ROUGHNESS_EPS) or microfacet.oren_nayar_f
    (Fujii, energy-preserving); nl = N.l, nv = N.v, lv = l.v.  (g0, g1, g2)."""
    if k == TRANSLUCENT:
        q = INV_PI * (1.0 if nl < 0.0 else 0.0)
        return c0 * q, c1 * q, c2 * q
    if rough < DIFFUSE_ROUGHNESS_EPS:
        q = INV_PI * (1.0 if nl > 0.0 else 0.0)
        return c0 * q, c1 * q, c2 * q
    sigma = _clip01(rough)
    a = 1.0 / (np.pi + sigma * (np.pi / 2 - 2.0 / 3.0))
    b = sigma * a
    nlp = max(nl, 0.0)
    nvp = max(nv, 0.0)
    t = lv - nlp * nvp
    if t > 0.0:
        t = t / (max(nlp, nvp) + 1e-38)
    single = a + b * t
    Eavg = a * np.pi + (2.0 * np.pi - 5.6) / 3.0 * b
    EE = (1.0 - (a * np.pi + b * _on_G(nvp))) * (1.0 - (a * np.pi + b * _on_G(nlp)))
    above = 1.0 if nl > 0.0 else 0.0
    A = _clip01(u0)
    g0 = c0 * (single + INV_PI * A * A * (Eavg / (1.0 - Eavg))
               / (1.0 - A * (1.0 - Eavg)) * EE) * above
    A = _clip01(u1)
    g1 = c1 * (single + INV_PI * A * A * (Eavg / (1.0 - Eavg))
               / (1.0 - A * (1.0 - Eavg)) * EE) * above
    A = _clip01(u2)
    g2 = c2 * (single + INV_PI * A * A * (Eavg / (1.0 - Eavg))
               / (1.0 - A * (1.0 - Eavg)) * EE) * above
    return g0, g1, g2


@njit(cache=True, error_model="numpy")
def _microfacet_lobe(T, k, a2, eta, fm, fi, t0, t1, t2, e0, e1, e2, fd, fn, w, c0, c1, c2,
                     u0, u1, u2, Nx, Ny, Nz, vx, vy, vz, lx, ly, lz, gl):
    """f of one GLOSSY, GLASS or REFRACTION lobe (:func:`_microfacet` times
    the colour, or the Fresnel fm of a GLOSSY lobe: FRESNEL_DIELECTRIC with
    Fresnel IOR fi, FRESNEL_F82 with tint t, FRESNEL_CONDUCTOR with IOR t
    and extinction e; under a thin film of thickness fd and IOR fn) and the
    single-scattering Fresnel the multiple-scattering factor reads: (g0,
    g1, g2, fss0, fss1, fss2)."""
    fs = _microfacet(k, a2, eta, Nx, Ny, Nz, vx, vy, vz, lx, ly, lz, gl)
    g0, g1, g2 = c0 * fs, c1 * fs, c2 * fs
    fss0, fss1, fss2 = u0, u1, u2
    if fm != 0:
        hx, hy, hz = _unit(vx + lx, vy + ly, vz + lz)
        F_0, F_1, F_2, fss0, fss1, fss2 = _fresnel_rgb(
            T, fm, _dot3(hx, hy, hz, vx, vy, vz), fi, t0, t1, t2, e0, e1, e2, fd, fn,
            u0, u1, u2)
        g0, g1, g2 = w * F_0 * fs, w * F_1 * fs, w * F_2 * fs
    return g0, g1, g2, fss0, fss1, fss2


@njit(cache=True, error_model="numpy")
def _film_dielectric(T, ch, c, fd, fn, fi, f0):
    """A Principled specular layer's Fresnel under a thin film, channel ch
    (Cycles' generalized_schlick_fresnel): the film over a dielectric of
    IOR fi, scaled towards f0 / F0(fi) (f0 its tinted normal reflectance)
    as it nears F0(fi)."""
    F = iridescence(T, _T_FILM, ch, c, fd, fn, fi, 0.0, -1.0, bool(False))
    F0r = _f0(fi)
    if F0r > 1e-5 and F != 1.0:
        s = _clip01((F - 1.0) / (F0r - 1.0))
        F *= 1.0 + (f0 / F0r - 1.0) * s
    return F


@njit(cache=True, error_model="numpy")
def _film_f82(T, ch, c, fd, fn, C, tint):
    """An F82-tint metal's Fresnel under a thin film, channel ch (Cycles'
    microfacet_fresnel: n and k from F0 and F82 read as Gulbrandsen's r
    and g)."""
    r = min(_clip01(C), 0.999)
    g = _f82_channel(C, tint, F82_COS)[0]
    q = math.sqrt(r)
    n = (1.0 + q) / (1.0 - q) + g * ((1.0 - r) / (1.0 + r) - (1.0 + q) / (1.0 - q))
    k = math.sqrt(max((r * (n + 1.0) * (n + 1.0) - (n - 1.0) * (n - 1.0)) / (1.0 - r), 0.0))
    return iridescence(T, _T_FILM, ch, c, fd, fn, n, k, g, bool(True))


@njit(cache=True, error_model="numpy")
def _fresnel_rgb(T, fm, c, fi, t0, t1, t2, e0, e1, e2, fd, fn, u0, u1, u2):
    """microfacet._principled_fresnel of one point, mode fm (FRESNEL_*, not
    NONE) at c = h.v, albedo colour u, under a thin film of thickness fd
    (nm; none below THICKNESS_CUTOFF) and IOR fn: (F0, F1, F2, Fss0, Fss1,
    Fss2).  The film changes F, not F_ss (Cycles' energy compensation
    reads the bare Fresnel)."""
    if fm == FRESNEL_DIELECTRIC:
        F0 = _f0(fi)
        s = _clip01((_fresnel(c, fi) - F0) / max(1.0 - F0, 1e-12))
        s_ss = _clip01((_fss(fi) - F0) / max(1.0 - F0, 1e-12))
        a0, b0 = _schlick_channel(u0, F0, s, s_ss)
        a1, b1 = _schlick_channel(u1, F0, s, s_ss)
        a2, b2 = _schlick_channel(u2, F0, s, s_ss)
    elif fm == FRESNEL_F82:
        a0, b0 = _f82_channel(u0, t0, c)
        a1, b1 = _f82_channel(u1, t1, c)
        a2, b2 = _f82_channel(u2, t2, c)
    else:
        a0, b0 = _conductor_channel(u0, t0, e0, c)
        a1, b1 = _conductor_channel(u1, t1, e1, c)
        a2, b2 = _conductor_channel(u2, t2, e2, c)
    if fd > THICKNESS_CUTOFF:
        # The channels and flags as int64 and plain bool, not literals: one
        # compile of each film kernel, not one a channel (see eval_pair_as).
        r, g, b = np.int64(0), np.int64(1), np.int64(2)
        if fm == FRESNEL_DIELECTRIC:
            F0r = _f0(fi)
            a0 = _film_dielectric(T, r, c, fd, fn, fi, _clip01(F0r * u0))
            a1 = _film_dielectric(T, g, c, fd, fn, fi, _clip01(F0r * u1))
            a2 = _film_dielectric(T, b, c, fd, fn, fi, _clip01(F0r * u2))
        elif fm == FRESNEL_F82:
            a0 = _film_f82(T, r, c, fd, fn, u0, t0)
            a1 = _film_f82(T, g, c, fd, fn, u1, t1)
            a2 = _film_f82(T, b, c, fd, fn, u2, t2)
        else:
            a0 = u0 * iridescence(T, _T_FILM, r, c, fd, fn, t0, e0, -1.0, bool(True))
            a1 = u1 * iridescence(T, _T_FILM, g, c, fd, fn, t1, e1, -1.0, bool(True))
            a2 = u2 * iridescence(T, _T_FILM, b, c, fd, fn, t2, e2, -1.0, bool(True))
    return a0, a1, a2, b0, b1, b2


@njit(cache=True, error_model="numpy")
def _film_rows(T, fm, c, fi, tint, ext, film, u, layer, out):
    """:func:`_fresnel_rgb`'s F of K points (layer False) or the largest
    channel of a specular layer's film Fresnel (layer True: u[:, 0] its
    tinted F0) into out (K, 3)."""
    for i in range(c.shape[0]):
        if layer:
            A = 0.0
            for ch in range(3):
                A = max(A, _film_dielectric(T, ch, c[i], film[i, 0], film[i, 1], fi[i], u[i, 0]))
            out[i, 0] = out[i, 1] = out[i, 2] = A
            continue
        r = _fresnel_rgb(T, fm[i], c[i], fi[i], tint[i, 0], tint[i, 1], tint[i, 2], ext[i, 0],
                         ext[i, 1], ext[i, 2], film[i, 0], film[i, 1], u[i, 0], u[i, 1], u[i, 2])
        out[i, 0], out[i, 1], out[i, 2] = r[0], r[1], r[2]


_FILM_TABLES = None


def film_fresnel(fm, c, fi, tint, ext, film, u, layer=False) -> np.ndarray:
    """(K, 3) float64: the Fresnel of K points under their thin films
    (``microfacet._principled_fresnel`` and ``multiscatter.layer_transmission``
    call it for the rows with a film, so that the film's formulas are
    written once): fm (K,) FRESNEL_*, c, fi (K,), tint, ext (K, 3) as
    ``table.fresnel_params``, film (K, 2) thickness and IOR, u (K, 3) the
    albedo colour; layer: a specular layer's largest channel (u[:, 0] its
    tinted F0), repeated in the three columns."""
    K = np.shape(c)[0]
    f = lambda a, n: np.ascontiguousarray(np.broadcast_to(a, (K, n) if n else (K,)),  # noqa: E731
                                          np.float64)
    out = np.empty((K, 3))
    global _FILM_TABLES
    if _FILM_TABLES is None:          # the tables' layout with the film's alone filled
        _FILM_TABLES = np.zeros(N_TABLES)
        _FILM_TABLES[T_FILM:] = sensitivity_table()
    _film_rows(_FILM_TABLES, np.ascontiguousarray(np.broadcast_to(fm, (K,)), np.int64), f(c, 0),
               f(fi, 0), f(tint, 3), f(ext, 3), f(film, 2), f(u, 3), bool(layer), out)
    return out


@njit(cache=True, inline="always", error_model="numpy")
def _seen_w(lobes, T, m, j, mu):
    """table.seen_weight of slot j of material m at mu = |w_o . n_s|: the
    mix weight times the view factor (F_VIEW), what a colour row's entry
    divides by to give the closure's own colour."""
    w = lobes[m, j, F_W]
    o = lobes[m, j, F_VIEW]
    if o > 0.0:
        x = min(abs(mu), 1.0) * (VIEW_SAMPLES - 1)
        i = min(int(x), VIEW_SAMPLES - 2)
        f = x - i
        b = int(o) - 1 + i
        w *= T[b] * (1.0 - f) + T[b + 1] * f
    return w


# One signature a body.  numba compiles a called kernel once for each
# distinct tuple of argument types it meets, and a constant argument is a
# type of its own (Literal[bool](False), Literal[int](0)): the callers of
# the two largest BSDF bodies below passed int16, int32 or int64 material
# ids, float32 or float64 directions and literal flags, 13 and 5 signatures
# of the same code, every one compiled in full (docs/interactive.md "One
# signature a kernel, round 50").  Their entry points are inlined wrappers
# that cast every scalar to int64, float64 or a plain bool (np.float64:
# numba's float() keeps a float32 a float32), so the bodies
# compile once for each dtype of the colour array.
@njit(cache=True, inline="always", error_model="numpy")
def eval_pair_as(lobes, T, m, colors, row, nsx, nsy, nsz, ngx, ngy, ngz, vx, vy, vz, lx, ly, lz,
                 want_smooth, bump):
    """:func:`eval_pair` with the Normal Map / Bump corrections (the valid
    specular normal, the diffuse lobes' bump shadowing) applied when bump:
    off, it is closures._eval_nd without them, as the importance mode of
    closures.sample_bsdf evaluates every material."""
    f = np.float64
    return _eval_pair_as(lobes, T, np.int64(m), colors, np.int64(row), f(nsx), f(nsy), f(nsz),
                         f(ngx), f(ngy), f(ngz), f(vx), f(vy), f(vz), f(lx), f(ly), f(lz),
                         bool(want_smooth), bool(bump))


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _eval_pair_as(lobes, T, m, colors, row, nsx, nsy, nsz, ngx, ngy, ngz, vx, vy, vz, lx, ly, lz,
                  want_smooth, bump):
    """:func:`eval_pair_as`'s body: m, row int64, the directions float64."""
    front = _dot3(ngx, ngy, ngz, vx, vy, vz) >= 0.0
    sg = 1.0 if front else -1.0
    if bump:
        ax, ay, az = _valid_specular_normal(ngx * sg, ngy * sg, ngz * sg, vx, vy, vz,
                                            nsx * sg, nsy * sg, nsz * sg)
        nsx, nsy, nsz = sg * ax, sg * ay, sg * az
    Nx, Ny, Nz = nsx * sg, nsy * sg, nsz * sg
    Gx, Gy, Gz = ngx * sg, ngy * sg, ngz * sg
    nl = _dot3(Nx, Ny, Nz, lx, ly, lz)
    nv = _dot3(Nx, Ny, Nz, vx, vy, vz)
    gl = _dot3(Gx, Gy, Gz, lx, ly, lz)
    f0_ = f1_ = f2_ = 0.0
    s0 = s1 = s2 = 0.0
    for j in range(lobes.shape[1]):
        if not lobes[m, j, F_ND] > 0.0:
            continue
        k = int(lobes[m, j, F_KIND])
        # np.float64, not float(): numba's float() keeps a float32 colour a
        # float32, and the lobe helpers would compile for it a second time
        f = np.float64
        c0, c1, c2 = f(colors[row, j, 0]), f(colors[row, j, 1]), f(colors[row, j, 2])
        w = _seen_w(lobes, T, m, j, nv)
        if w != 0.0:
            u0, u1, u2 = c0 / w, c1 / w, c2 / w
        else:
            u0 = u1 = u2 = 0.0
        rough = lobes[m, j, F_ROUGH]
        if k == DIFFUSE or k == TRANSLUCENT:
            g0, g1, g2 = _diffuse_lobe(k, rough, c0, c1, c2, u0, u1, u2, nl, nv,
                                       _dot3(lx, ly, lz, vx, vy, vz))
            if k == DIFFUSE and lobes[m, j, F_LIOR] > 0.0:
                q = _layer_transmission(T, lobes[m, j, F_LF0], lobes[m, j, F_LROUGH],
                                        lobes[m, j, F_LIOR], nv, lobes[m, j, F_LMS] > 0.0,
                                        lobes[m, j, F_FILM_D], lobes[m, j, F_FILM_N])
                g0, g1, g2 = g0 * q, g1 * q, g2 * q
            if bump and lobes[m, 0, F_BUMP] < 1.5:
                q = _bump_shadowing(Gx, Gy, Gz, Nx, Ny, Nz, lx, ly, lz)
                g0, g1, g2 = g0 * q, g1 * q, g2 * q
            if want_smooth:
                s0 += g0
                s1 += g1
                s2 += g2
        elif k == GLOSSY or k == GLASS or k == REFRACTION:
            ior = lobes[m, j, F_IOR]
            eta = ior if front else 1.0 / ior
            fm = int(lobes[m, j, F_FRES]) if k == GLOSSY else 0
            g0, g1, g2, fss0, fss1, fss2 = _microfacet_lobe(
                T, k, lobes[m, j, F_A2], eta, fm, lobes[m, j, F_FIOR], lobes[m, j, F_TINT],
                lobes[m, j, F_TINT + 1], lobes[m, j, F_TINT + 2], lobes[m, j, F_K],
                lobes[m, j, F_K + 1], lobes[m, j, F_K + 2], lobes[m, j, F_FILM_D],
                lobes[m, j, F_FILM_N], w, c0, c1, c2, u0, u1, u2,
                Nx, Ny, Nz, vx, vy, vz, lx, ly, lz, gl)
            if lobes[m, j, F_MS] > 0.0 and k != REFRACTION:
                E, Eavg = _ms_albedo(T, k, rough, eta, nv)
                E = max(E, 1e-6)
                g0 *= _ms_channel(fss0, E, Eavg)
                g1 *= _ms_channel(fss1, E, Eavg)
                g2 *= _ms_channel(fss2, E, Eavg)
        else:
            continue
        f0_ += g0
        f1_ += g1
        f2_ += g2
    return f0_, f1_, f2_, s0, s1, s2


@njit(cache=True, nogil=True, error_model="numpy")
def eval_indexed(S, mat, colors, ns, ng, front, wo, pv, wi, pp, out, smooth):
    """f (and the receivers' smooth sum) of the pairs (point pv[i], direction
    pp[i]) (K,) into out, smooth (K, 3) float64 (smooth may be (0, 3): not
    computed).  Point arrays: mat (P,), colors (P, L, 3), ns, ng, wo (P, 3),
    front (P,) bool: ns and ng are flipped where front is False to give the
    mesh's normals (``VisiblePoints.mesh_normals``), or (0,): taken as they
    are.  wi (N, 3): directions indexed by pp."""
    lobes, T = S.lobes, S.tables
    flip = front.shape[0] > 0
    want = smooth.shape[0] > 0
    for i in range(pv.shape[0]):
        q = pv[i]
        e = pp[i]
        sg = 1.0
        if flip and not front[q]:
            sg = -1.0
        r = eval_pair(lobes, T, mat[q], colors, q,
                      ns[q, 0] * sg, ns[q, 1] * sg, ns[q, 2] * sg,
                      ng[q, 0] * sg, ng[q, 1] * sg, ng[q, 2] * sg,
                      float(wo[q, 0]), float(wo[q, 1]), float(wo[q, 2]),
                      float(wi[e, 0]), float(wi[e, 1]), float(wi[e, 2]), want)
        out[i, 0], out[i, 1], out[i, 2] = r[0], r[1], r[2]
        if want:
            smooth[i, 0], smooth[i, 1], smooth[i, 2] = r[3], r[4], r[5]


def _f64(a, n):
    return np.ascontiguousarray(np.asarray(a, np.float64).reshape(-1, n))


def eval_bsdf(table, mat, colors, n_s, n_g, wo, wi, with_smooth=False):
    """Compiled :func:`core.materials.eval_bsdf` (radiance mode) of K pairs:
    the same arguments, (K, 3) float64; with_smooth: also the sum
    ``Receivers.smooth`` evaluates (:func:`eval_pair`), returned second."""
    mat = np.ascontiguousarray(mat, np.int64)
    K = mat.shape[0]
    idx = np.arange(K)
    colors = np.ascontiguousarray(np.asarray(colors, np.float64).reshape(K, -1, 3))
    out = np.empty((K, 3))
    smooth = np.empty((K if with_smooth else 0, 3))
    eval_indexed(compile_materials(table), mat, colors, _f64(n_s, 3), _f64(n_g, 3),
                 np.zeros(0, bool), _f64(wo, 3), idx, _f64(wi, 3), idx, out, smooth)
    return (out, smooth) if with_smooth else out


# --------------------------------------------------------------------------
# Importance sampling of a whole material, one ray at a time
# --------------------------------------------------------------------------
# The numba twin of closures.sample_bsdf(subset='all') for untextured
# materials without Normal Map / Bump, in importance mode (the photon
# tracer's generic hits, core.sppm.photon_kernels.bounce_kernel) and radiance
# mode (the camera paths, sample_radiance): the same lobe choice, lobe
# sampler, combined one-sample MIS density (closures._pdf_nd), f from
# eval_pair and, in importance mode, the adjoint factors, in the same
# operation order (tests/test_compiled_sample.py: sample for sample against
# numpy).


class SelectionTable(NamedTuple):
    """Lobe choice of untextured materials (their colours are constants):
    colors (M, L, 3) ``table.lobe_colors``; p (M, L) the luminance selection
    probabilities (``table._selection_probs``, subset 'all'); cdf (M, L)
    their cumulative sum; last (M,) int64 the last slot with p > 0 (L - 1
    when none).  Computed by numpy (the oracle's bits)."""
    colors: np.ndarray
    p: np.ndarray
    cdf: np.ndarray
    last: np.ndarray


def selection_table(table) -> SelectionTable:
    """The :class:`SelectionTable` of every material of a ``MaterialTable``,
    evaluated as untextured (rows of textured materials are not meaningful)."""
    from .table import lobe_colors
    M = table.kind.shape[0]
    mat = np.arange(M)
    return selection_rows(table, mat, lobe_colors(table, mat, np.zeros((M, 2))), "all")


def selection_rows(table, mat, colors, subset) -> SelectionTable:
    """The :class:`SelectionTable` of K rows: materials mat (K,) int with
    lobe colours colors (K, L, 3) float64, lobes chosen within ``subset``
    ('all' or 'nondelta', ``table._selection_probs``); row k is read with
    r = k (the visible points' BSDF samples towards an environment map,
    core.lights.map_mis_kernels, take 'nondelta')."""
    from .table import _selection_probs
    L = table.kind.shape[1]
    p = _selection_probs(table, mat, colors, subset)
    last = (L - 1 - np.argmax(p[:, ::-1] > 0, axis=1)).astype(np.int64)
    return SelectionTable(np.ascontiguousarray(colors), np.ascontiguousarray(p),
                          np.ascontiguousarray(np.cumsum(p, axis=1)), last)


# Taylor coefficients of sin t = t + t^3 S(t^2) and cos t = 1 - t^2 C(t^2) to
# t^17 / t^18: on |t| <= pi/4 the first term left out is below 2^-60 of the
# result, so the polynomial evaluated in float64 is within 1 ulp of sin, cos.
_S = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(8, 0, -1))
_C = tuple((-1.0) ** (k + 1) / math.factorial(2 * k) for k in range(9, 0, -1))


@njit(cache=True, inline="always", error_model="numpy")
def sincos_quarter(t):
    """(sin t, cos t) for |t| <= pi/4, within 1 ulp (Horner on t^2); a third
    of libm's sincos, whose range reduction the sampling warps never need
    (docs/architecture.md "The photon pass's own work against raw Embree")."""
    t2 = t * t
    s = _S[0]
    for k in range(1, 8):
        s = s * t2 + _S[k]
    c = _C[0]
    for k in range(1, 9):
        c = c * t2 + _C[k]
    return t + t * t2 * s, 1.0 - t2 * c


@njit(cache=True, inline="always", error_model="numpy")
def sincos_turn(u):
    """(sin, cos) of 2 pi u for u in [0, 1]: u minus the nearest quarter turn
    q / 4 (exact: Sterbenz), sincos_quarter of its angle, rotated by q
    quarter turns."""
    q = math.floor(4.0 * u + 0.5)
    s, c = sincos_quarter((2.0 * np.pi) * (u - 0.25 * q))
    k = int(q) & 3
    if k == 0:
        return s, c
    if k == 1:
        return c, -s
    if k == 2:
        return -s, -c
    return -c, s


@njit(cache=True, inline="always", error_model="numpy")
def _disk(u1, u2):
    """microfacet._disk (Shirley-Chiu concentric map); its angle's sine and
    cosine by sincos_quarter (phi = pi/2 - t on the second branch: cos phi =
    sin t, sin phi = cos t)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    # Which branch is a coin flip: selects of the operands, one division,
    # no branch to mispredict (the same operations on each branch's values,
    # so the same bits; docs/architecture.md "Cores at 256² and the bounce
    # kernel, round 13").  a = b = 0: (0, 0), and no 0 / 0 (a caller with
    # numba's python error model would raise).
    big = abs(a) > abs(b)
    num = b if big else a
    r = a if big else b
    zero = r == 0.0
    s, c = sincos_quarter((np.pi / 4) * (num / (1.0 if zero else r)))
    x = r * c if big else r * s
    y = r * s if big else r * c
    return (0.0 if zero else x), (0.0 if zero else y)


@njit(cache=True, error_model="numpy")
def _vndf(wx, wy, wz, alpha, u1, u2):
    """microfacet.ggx_sample_vndf (Heitz 2018) for one local direction (z > 0)."""
    vx, vy, vz = _unit(alpha * wx, alpha * wy, wz)
    lensq = vx * vx + vy * vy
    if lensq > 1e-7:
        inv = 1.0 / math.sqrt(lensq)
        t1x, t1y, t1z = -vy * inv, vx * inv, 0.0
    else:
        t1x, t1y, t1z = 1.0, 0.0, 0.0
    # np.cross(v, T1), its operation order.
    t2x = vy * t1z - vz * t1y
    t2y = vz * t1x - vx * t1z
    t2z = vx * t1y - vy * t1x
    tx, ty = _disk(u1, u2)
    s = 0.5 * (1.0 + vz)
    ty = (1.0 - s) * math.sqrt(max(0.0, 1.0 - tx * tx)) + s * ty
    tz = math.sqrt(max(0.0, 1.0 - tx * tx - ty * ty))
    hx = tx * t1x + ty * t2x + tz * vx
    hy = tx * t1y + ty * t2y + tz * vy
    hz = tx * t1z + ty * t2z + tz * vz
    return _unit(alpha * hx, alpha * hy, max(0.0, hz))


@njit(cache=True, error_model="numpy")
def _microfacet_pdf(kind, a2, eta, Nx, Ny, Nz, Gx, Gy, Gz, ox, oy, oz, ix, iy, iz):
    """microfacet._microfacet_pdf for one pair (N, Ng oriented to wo = o)."""
    cI = _dot3(Nx, Ny, Nz, ox, oy, oz)
    cO = _dot3(Nx, Ny, Nz, ix, iy, iz)
    gO = _dot3(Gx, Gy, Gz, ix, iy, iz)
    if not cI > 0.0:
        return 0.0
    G1 = 1.0 / (1.0 + _lambda(a2, cI))
    if cO > 0.0 and gO > 0.0 and kind != REFRACTION:
        hx, hy, hz = _unit(ox + ix, oy + iy, oz + iz)
        val = _D(a2, _dot3(Nx, Ny, Nz, hx, hy, hz)) * G1 / (4.0 * cI)
        if kind == GLASS:
            val *= _fresnel(_dot3(hx, hy, hz, ox, oy, oz), eta)
        return val
    if cO < 0.0 and gO < 0.0 and kind != GLOSSY:
        ux, uy, uz, hx, hy, hz, ho, hi, sel = _refraction_half(kind, eta, Nx, Ny, Nz,
                                                               ox, oy, oz, ix, iy, iz)
        if not (ho > 0.0 and hi < 0.0):
            return 0.0
        return (sel * _D(a2, _dot3(Nx, Ny, Nz, hx, hy, hz)) * G1 / cI * (eta * eta)
                * abs(ho * hi) / _dot3(ux, uy, uz, ux, uy, uz))
    return 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _pdf_nd_one(lobes, p, r, m, front, Nx, Ny, Nz, Gx, Gy, Gz, ox, oy, oz, wx, wy, wz):
    """closures._pdf_nd of one direction: the combined density of material m's
    non-delta lobes at wi = w, each lobe weighted by its selection
    probability p[r] (slot order, as numpy sums); N, G the normals oriented
    to wo's side (front: wo on the mesh normal's side)."""
    pdf = 0.0
    for jj in range(lobes.shape[1]):
        pj = p[r, jj]
        if not (lobes[m, jj, F_ND] > 0.0 and pj > 0.0):
            continue
        kj = int(lobes[m, jj, F_KIND])
        if kj == DIFFUSE:
            v = (max(_dot3(Nx, Ny, Nz, wx, wy, wz), 0.0) * INV_PI
                 * (1.0 if _dot3(Gx, Gy, Gz, wx, wy, wz) > 0.0 else 0.0))
        elif kj == TRANSLUCENT:
            v = (max(-_dot3(Nx, Ny, Nz, wx, wy, wz), 0.0) * INV_PI
                 * (1.0 if _dot3(Gx, Gy, Gz, wx, wy, wz) < 0.0 else 0.0))
        elif kj == GLOSSY or kj == GLASS or kj == REFRACTION:
            ij = lobes[m, jj, F_IOR]
            v = _microfacet_pdf(kj, lobes[m, jj, F_A2], ij if front else 1.0 / ij,
                                Nx, Ny, Nz, Gx, Gy, Gz, ox, oy, oz, wx, wy, wz)
        else:
            v = 0.0
        pdf += pj * v
    return pdf


@njit(cache=True, error_model="numpy", inline="always")
def pdf_oriented(lobes, p, m, r, sx, sy, sz, gx, gy, gz, ox, oy, oz, wx, wy, wz):
    """closures.pdf_bsdf(subset='all') of material m for wo = o, wi = w:
    closures.pdf_inputs' orientation of the unit normals s (shading) and g
    (geometric, any orientation) to o's side (a Normal Map / Bump material's
    s made Cycles' valid specular normal for o first), then
    :func:`_pdf_nd_one` with the selection probabilities p[r] (p (R, L): a
    SelectionTable's rows, r = m, or a textured hit's own row)."""
    # the directions in float64: one signature of the helpers (eval_pair_as)
    ox, oy, oz = np.float64(ox), np.float64(oy), np.float64(oz)
    wx, wy, wz = np.float64(wx), np.float64(wy), np.float64(wz)
    front = gx * ox + gy * oy + gz * oz >= 0.0
    sg = 1.0 if front else -1.0
    if lobes[m, 0, F_BUMP] > 0.0:
        # closures.pdf_inputs: Cycles' valid specular normal for the view o.
        ax, ay, az = _valid_specular_normal(gx * sg, gy * sg, gz * sg, ox, oy, oz,
                                            sx * sg, sy * sg, sz * sg)
        return _pdf_nd_one(lobes, p, r, m, front, ax, ay, az, gx * sg, gy * sg, gz * sg,
                           ox, oy, oz, wx, wy, wz)
    return _pdf_nd_one(lobes, p, r, m, front, sx * sg, sy * sg, sz * sg, gx * sg, gy * sg,
                       gz * sg, ox, oy, oz, wx, wy, wz)


@njit(cache=True, nogil=True, error_model="numpy")
def scatter_pdfs(lobes, p, mat, ns, ng, wo, wi, delta, pl, pr):
    """The densities of K scatterings (mat (K,) int64 untextured materials
    without Normal Map / Bump; ns, ng, wo, wi (K, 3); delta (K,) bool):
    pl (K,) = pdf(wo -> wi), the one that sampled wi, and pr (K,) =
    pdf(wi -> wo), the reverse (:func:`pdf_oriented`); both 1 for a delta
    sample (the light side's MIS factors, combined.scatter_factors)."""
    for i in range(mat.shape[0]):
        if delta[i]:
            pl[i] = 1.0
            pr[i] = 1.0
            continue
        m = mat[i]
        sx, sy, sz = ns[i, 0], ns[i, 1], ns[i, 2]
        gx, gy, gz = ng[i, 0], ng[i, 1], ng[i, 2]
        ox, oy, oz = wo[i, 0], wo[i, 1], wo[i, 2]
        wx, wy, wz = wi[i, 0], wi[i, 1], wi[i, 2]
        pl[i] = pdf_oriented(lobes, p, m, m, sx, sy, sz, gx, gy, gz, ox, oy, oz, wx, wy, wz)
        pr[i] = pdf_oriented(lobes, p, m, m, sx, sy, sz, gx, gy, gz, wx, wy, wz, ox, oy, oz)


@njit(cache=True, inline="always", error_model="numpy")
def sample_pair(lobes, T, colors, p, cdf, last, m, r, nsx, nsy, nsz, ngx, ngy, ngz,
                ox, oy, oz, u0, u1, u2, radiance):
    """:func:`_sample_pair` with its scalars cast to one type each (int64,
    float64, a plain bool: one compile of the body, as :func:`eval_pair_as`)."""
    f = np.float64
    return _sample_pair(lobes, T, colors, p, cdf, last, np.int64(m), np.int64(r), f(nsx), f(nsy),
                        f(nsz), f(ngx), f(ngy), f(ngz), f(ox), f(oy), f(oz), f(u0), f(u1), f(u2),
                        bool(radiance))


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _sample_pair(lobes, T, colors, p, cdf, last, m, r, nsx, nsy, nsz, ngx, ngy, ngz,
                 ox, oy, oz, u0, u1, u2, radiance):
    """closures.sample_bsdf(subset='all', mode='importance', or 'radiance'
    with ``radiance``) of material m (a Normal Map / Bump material gets
    Cycles' valid specular normal in radiance mode only, as there) for one
    ray: lobes, T a CompiledMaterials' arrays; colors, p, cdf, last a
    SelectionTable's, read at row r (r = m for an untextured material, or
    a textured hit's own row of its lobe colours and their selection,
    core.integrators.path_kernels.PathMaterials); ns, ng unit mesh normals
    in any orientation; o = wo
    unit (importance: back towards where the photon came from; radiance:
    towards the camera side); u0, u1 direction, u2 lobe choice (rescaled for
    glass' reflect / refract choice).  Returns (wi xyz, weight rgb,
    is_delta, ok, pdf); weight and pdf 0 when not ok; pdf the combined
    density of the non-delta lobes, or the lobe's selection probability for
    a delta sample (sample_bsdf's pdf)."""
    front = _dot3(ngx, ngy, ngz, ox, oy, oz) >= 0.0
    sg = 1.0 if front else -1.0
    # The mesh's shading normal: eval_pair makes it valid for the view itself.
    msx, msy, msz = nsx, nsy, nsz
    if radiance and lobes[m, 0, F_BUMP] > 0.0:
        # closures.sample_bsdf, radiance mode: a Normal Map / Bump material
        # samples about Cycles' valid specular normal for the view wo.
        ax, ay, az = _valid_specular_normal(ngx * sg, ngy * sg, ngz * sg, ox, oy, oz,
                                            nsx * sg, nsy * sg, nsz * sg)
        nsx, nsy, nsz = sg * ax, sg * ay, sg * az
    Nx, Ny, Nz = nsx * sg, nsy * sg, nsz * sg
    Gx, Gy, Gz = ngx * sg, ngy * sg, ngz * sg
    L = lobes.shape[1]
    if not cdf[r, L - 1] > 0.0:          # no lobe: invalid
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False, 0.0
    # Lobe choice: first slot with u < cdf, at most the last usable one.
    j = 0
    for jj in range(L):
        if u2 >= cdf[r, jj]:
            j += 1
    j = min(j, last[r])
    p_sel = p[r, j]
    c_lo = cdf[r, j - 1] if j > 0 else 0.0
    u_re = min(max((u2 - c_lo) / (p_sel if p_sel > 0 else 1.0), 0.0), 1.0 - 1e-16)
    # Tangent frame of N (mathutil.frame, Duff et al. 2017).
    s = 1.0 if Nz >= 0.0 else -1.0
    a = -1.0 / (s + Nz)
    b = Nx * Ny * a
    tx, ty, tz = 1.0 + s * (Nx * Nx) * a, s * b, -s * Nx
    bx, by, bz = b, s + (Ny * Ny) * a, -Ny
    k = int(lobes[m, j, F_KIND])
    delta = not lobes[m, j, F_ND] > 0.0
    c0, c1, c2 = colors[r, j, 0], colors[r, j, 1], colors[r, j, 2]
    ior = lobes[m, j, F_IOR]
    eta = ior if front else 1.0 / ior
    d0 = d1 = d2 = 0.0                   # delta throughput before selection
    if k == DIFFUSE or k == TRANSLUCENT:
        lx, ly = _disk(u0, u1)
        lz = math.sqrt(max(0.0, 1.0 - lx * lx - ly * ly))
        if k == TRANSLUCENT:
            lz = -lz
        wx = lx * tx + ly * bx + lz * Nx
        wy = lx * ty + ly * by + lz * Ny
        wz = lx * tz + ly * bz + lz * Nz
        gs = _dot3(Gx, Gy, Gz, wx, wy, wz)
        ok = gs > 0.0 if k == DIFFUSE else gs < 0.0
        delta = False
    elif k == TRANSPARENT:
        wx, wy, wz = -ox, -oy, -oz
        ok = True
        delta = True
        d0, d1, d2 = c0, c1, c2
    else:                                # GGX family
        cI = _dot3(ox, oy, oz, Nx, Ny, Nz)
        if delta:
            hx, hy, hz = Nx, Ny, Nz
        else:
            alpha = lobes[m, j, F_ROUGH] * lobes[m, j, F_ROUGH]
            if cI > 0:
                l0, l1, l2 = (_dot3(ox, oy, oz, tx, ty, tz), _dot3(ox, oy, oz, bx, by, bz), cI)
            else:
                l0, l1, l2 = 0.0, 0.0, 1.0
            qx, qy, qz = _vndf(l0, l1, l2, alpha, u0, u1)
            hx = qx * tx + qy * bx + qz * Nx
            hy = qx * ty + qy * by + qz * Ny
            hz = qx * tz + qy * bz + qz * Nz
        hwo = _dot3(hx, hy, hz, ox, oy, oz)
        refr = False
        F = 1.0
        cos_t = 0.0
        if k != GLOSSY:
            c = abs(hwo)
            g2 = eta * eta - 1.0 + c * c
            F = _fresnel(hwo, eta)
            if g2 > 0.0:
                cos_t = math.sqrt(max(0.0, 1.0 - (1.0 - c * c) / (eta * eta)))
            refr = u_re >= F if k == GLASS else True
        if refr:
            inv = 1.0 / eta
            q = inv * hwo - cos_t
            wx, wy, wz = q * hx - inv * ox, q * hy - inv * oy, q * hz - inv * oz
        else:
            q = 2.0 * hwo
            wx, wy, wz = q * hx - ox, q * hy - oy, q * hz - oz
        wx, wy, wz = _unit(wx, wy, wz)
        cN = _dot3(Nx, Ny, Nz, wx, wy, wz)
        cG = _dot3(Gx, Gy, Gz, wx, wy, wz)
        if refr:
            ok = cI > 0.0 and cN < 0.0 and cG < 0.0
        else:
            ok = cI > 0.0 and cN > 0.0 and cG > 0.0
        if k == REFRACTION:
            ok = ok and F < 1.0
        if delta:
            d0, d1, d2 = c0, c1, c2
            fm = int(lobes[m, j, F_FRES]) if k == GLOSSY else 0
            if fm != 0:
                # Principled layer or Metallic BSDF at roughness 0: colour is
                # tint / F0, the Fresnel at h = n scales the mix weight
                # (closures._sample_general).
                w = _seen_w(lobes, T, m, j, hwo)
                dv = w if w != 0 else 1.0
                F_ = _fresnel_rgb(T, fm, hwo, lobes[m, j, F_FIOR], lobes[m, j, F_TINT],
                                  lobes[m, j, F_TINT + 1], lobes[m, j, F_TINT + 2],
                                  lobes[m, j, F_K], lobes[m, j, F_K + 1], lobes[m, j, F_K + 2],
                                  lobes[m, j, F_FILM_D], lobes[m, j, F_FILM_N],
                                  d0 / dv, d1 / dv, d2 / dv)
                d0, d1, d2 = w * F_[0], w * F_[1], w * F_[2]
            if refr and not radiance:
                # Adjoint of Cycles' unscaled BTDF: (n_wo / n_wi)^2 = 1/eta^2.
                e2 = eta * eta
                d0, d1, d2 = d0 / e2, d1 / e2, d2 / e2
    if not ok:
        return wx, wy, wz, 0.0, 0.0, 0.0, False, False, 0.0
    if delta:
        w0, w1, w2 = d0 / p_sel, d1 / p_sel, d2 / p_sel
        pdf = p_sel
    else:
        pdf = _pdf_nd_one(lobes, p, r, m, front, Nx, Ny, Nz, Gx, Gy, Gz, ox, oy, oz,
                          wx, wy, wz)
        if not pdf > 0.0:
            return wx, wy, wz, 0.0, 0.0, 0.0, False, False, 0.0
        if radiance:
            # closures._sample_general, mode 'radiance': Cycles' f(view=wo, light=wi).
            f = eval_pair(lobes, T, m, colors, r, msx, msy, msz, ngx, ngy, ngz,
                          ox, oy, oz, wx, wy, wz, False)
        else:
            # Importance mode: the adjoint f_C(view=wi, light=wo), without the
            # Normal Map / Bump corrections (closures.sample_bsdf applies them
            # in radiance mode only).
            f = eval_pair_as(lobes, T, m, colors, r, nsx, nsy, nsz, ngx, ngy, ngz,
                             wx, wy, wz, ox, oy, oz, False, False)
        cs = abs(_dot3(nsx, nsy, nsz, wx, wy, wz)) / pdf
        w0, w1, w2 = f[0] * cs, f[1] * cs, f[2] * cs
    if radiance:
        return wx, wy, wz, w0, w1, w2, delta, True, pdf
    # closures._adjoint_correction |wo.ns||wi.ng| / (|wo.ng||wi.ns|).
    num = abs(_dot3(ox, oy, oz, nsx, nsy, nsz)) * abs(_dot3(wx, wy, wz, ngx, ngy, ngz))
    den = abs(_dot3(ox, oy, oz, ngx, ngy, ngz)) * abs(_dot3(wx, wy, wz, nsx, nsy, nsz))
    adj = num / den if den > 0 else 0.0
    return wx, wy, wz, w0 * adj, w1 * adj, w2 * adj, delta, True, pdf


@njit(cache=True, nogil=True, error_model="numpy")
def sample_batch(lobes, T, sel, mat, ns, ng, wo, u, radiance, wi, weight, pdf, flags):
    """:func:`sample_pair` of K rays: mat (K,) int64, ns, ng, wo (K, 3),
    u (K, 3); writes wi, weight (K, 3), pdf (K,) and flags (K,) int8: bit 0
    ok, bit 1 is_delta."""
    for i in range(mat.shape[0]):
        r = sample_pair(lobes, T, sel.colors, sel.p, sel.cdf, sel.last, mat[i], mat[i],
                        ns[i, 0], ns[i, 1], ns[i, 2], ng[i, 0], ng[i, 1], ng[i, 2],
                        wo[i, 0], wo[i, 1], wo[i, 2], u[i, 0], u[i, 1], u[i, 2], radiance)
        wi[i, 0], wi[i, 1], wi[i, 2] = r[0], r[1], r[2]
        weight[i, 0], weight[i, 1], weight[i, 2] = r[3], r[4], r[5]
        pdf[i] = r[8]
        flags[i] = (1 if r[7] else 0) + (2 if r[6] else 0)


@njit(cache=True, nogil=True, error_model="numpy")
def pdf_batch(lobes, mat, p, N, Ng, front, wo, wi, out):
    """closures._pdf_nd of K rows (out (K,)): mat (K,) int64, p (K, L) the
    selection probabilities, N, Ng (K, 3) the normals oriented to wo's side,
    front (K,) bool, wo, wi (K, 3)."""
    for i in range(mat.shape[0]):
        out[i] = _pdf_nd_one(lobes, p, i, mat[i], front[i], N[i, 0], N[i, 1], N[i, 2],
                             Ng[i, 0], Ng[i, 1], Ng[i, 2], wo[i, 0], wo[i, 1], wo[i, 2],
                             wi[i, 0], wi[i, 1], wi[i, 2])


# --------------------------------------------------------------------------
# Radiance mode over arrays: the camera paths' BSDF calls
# --------------------------------------------------------------------------
# The camera paths (core.integrators.path_tracer, combined) call sample_bsdf,
# eval_bsdf and pdf_bsdf in radiance mode on every vertex; on GENERIC
# materials (Blender's default Principled BSDF, glossy, glass with a rough
# lobe) numpy spent ~2 us a row there.  These take the same arguments and
# return the same arrays, the rows they cover by the kernels above (same
# formulas in the same order: equal to rounding, tests/test_compiled_sample.py)
# and the others by numpy.


def radiance_rows(table, fm) -> np.ndarray:
    """(M,) bool: the materials :func:`sample_radiance` samples compiled, the
    photon tracer's ``fm.compiled`` (GENERIC, untextured, no Normal Map /
    Bump) without an alpha texture (whose lobe colours vary per hit)."""
    rows = np.asarray(fm.compiled, bool).copy()
    alpha = getattr(table, "alpha_tex", None)
    if alpha is not None:
        a = np.asarray(alpha).reshape(rows.shape[0], -1)
        rows &= ~np.any(a >= 0, axis=1)
    return rows


def sample_radiance(table, fm, rows, mat, colors, n_s, n_g, wo, u):
    """closures.sample_bsdf(table, mat, colors, n_s, n_g, wo, u, subset='all',
    mode='radiance'): the same (wi, weight, pdf, is_delta, ok); rows (M,)
    bool from :func:`radiance_rows` (their colours are the material's)."""
    from .closures import sample_bsdf
    mat = np.asarray(mat, np.int64)
    c = rows[mat]
    if not c.any():
        return sample_bsdf(table, mat, colors, n_s, n_g, wo, u, subset="all", mode="radiance")
    K = mat.shape[0]
    ci = np.nonzero(c)[0]
    n = ci.size
    wi, weight, pdf = np.zeros((K, 3)), np.zeros((K, 3)), np.zeros(K)
    is_delta, ok = np.zeros(K, bool), np.zeros(K, bool)
    w_c, g_c, p_c, fl = np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n, np.int8)
    sample_batch(fm.cm.lobes, fm.cm.tables, fm.sel, mat[ci], _f64(np.asarray(n_s)[ci], 3),
                 _f64(np.asarray(n_g)[ci], 3), _f64(np.asarray(wo)[ci], 3),
                 _f64(np.asarray(u)[ci], 3), True, w_c, g_c, p_c, fl)
    wi[ci], weight[ci], pdf[ci] = w_c, g_c, p_c
    ok[ci] = (fl & 1) > 0
    is_delta[ci] = (fl & 3) == 3
    ni = np.nonzero(~c)[0]
    if ni.size:
        r = sample_bsdf(table, mat[ni], np.asarray(colors)[ni], np.asarray(n_s)[ni],
                        np.asarray(n_g)[ni], np.asarray(wo)[ni], np.asarray(u)[ni],
                        subset="all", mode="radiance")
        wi[ni], weight[ni], pdf[ni], is_delta[ni], ok[ni] = r
    return wi, weight, pdf, is_delta, ok


def eval_radiance(table, generic, mat, colors, n_s, n_g, wo, wi):
    """closures.eval_bsdf(table, mat, colors, n_s, n_g, wo, wi) (radiance):
    the rows of materials ``generic`` (M,) bool by :func:`eval_indexed`
    (every lobe kind and option, textured colours and Normal Map / Bump
    included), the others (Lambert walls: numpy is as fast) by numpy."""
    from .closures import eval_bsdf as eval_numpy
    mat = np.asarray(mat, np.int64)
    c = generic[mat]
    if not c.any():
        return eval_numpy(table, mat, colors, n_s, n_g, wo, wi)
    out = np.empty((mat.shape[0], 3))
    ci = np.nonzero(c)[0]
    out[ci] = eval_bsdf(table, mat[ci], np.asarray(colors)[ci], np.asarray(n_s)[ci],
                        np.asarray(n_g)[ci], np.asarray(wo)[ci], np.asarray(wi)[ci])
    ni = np.nonzero(~c)[0]
    if ni.size:
        out[ni] = eval_numpy(table, mat[ni], np.asarray(colors)[ni], np.asarray(n_s)[ni],
                             np.asarray(n_g)[ni], np.asarray(wo)[ni], np.asarray(wi)[ni])
    return out


def pdf_radiance(table, mat, colors, n_s, n_g, wo, wi):
    """closures.pdf_bsdf(table, mat, colors, n_s, n_g, wo, wi, subset='all'):
    numpy's set-up (closures.pdf_inputs: Normal Map / Bump correction,
    orientation, the lobes' selection probabilities), then
    closures._pdf_nd's per-lobe sum compiled (:func:`pdf_batch`)."""
    from .closures import pdf_inputs
    mat, p, N, Ng, front, wo, wi = pdf_inputs(table, mat, colors, n_s, n_g, wo, wi, "all")
    out = np.empty(mat.shape[0])
    pdf_batch(compile_materials(table).lobes, mat, np.ascontiguousarray(p, np.float64),
              _f64(N, 3), _f64(Ng, 3), np.ascontiguousarray(front), _f64(wo, 3), _f64(wi, 3),
              out)
    return out
