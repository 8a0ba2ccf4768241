"""Compiled light sampling for next-event estimation at the visible points (numba).

:func:`direct_kernel` is :func:`core.lights.sampling.sample_direct` (the
selection by :func:`~core.lights.sampling._entry_weights` with the triangle
group, and every emitter shape: point/spot discs and spheres, sun cones,
spherical rectangles (Urena et al. 2013), area-sampled ellipses, spherical
or area-sampled triangles (Arvo 1995), the constant world cosine-sampled
about the receiver normal) written per visible point in float64, followed by
the BSDF of Lambert-only materials (f = sum of the Lambert lobes / pi on
the lit side) and the contribution beta f |cos| weight, in one loop over the
visible points.  Other materials get their f from
``core.materials.eval_bsdf`` afterwards (``NextEventEstimation``).  Then
:func:`shadow_kernel` writes the shadow rays in Embree's float32 (one
occlusion call for all of them) and :func:`accumulate` adds the unblocked
contributions; the grazing self-hit retry and the emissive triangles' own
test stay ``NextEventEstimation._blocked``'s numpy code, on their rows.

Not compiled (``compiled_lights_ok`` is False, the numpy sampler is used):
textured emissive triangles.  An environment map's light sample
(``sampling._sample_environment``) is compiled here; the visible points'
weighing of it against a BSDF sample towards the map is
``map_mis_kernels``'.

Precision: the same formulas in the same order as the numpy code, but
numba's libm (arccos, sin, cos, sqrt are correctly rounded or within 1 ulp)
may differ from numpy's vectorised transcendental functions in the last bit,
and the spherical-rectangle and -triangle inversions amplify that to ~1e-9
relative near their degenerate ends; tests/test_compiled_stages.py states
the tolerance.  Threads: ``nogil``; NextEventEstimation runs two halves of
the visible points in two threads.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .._numba_options import NO_REFCOUNTS
from ..mathutil import LUM_B as _LUM2, LUM_G as _LUM1, LUM_R as _LUM0
# map_sample is compiled into direct_kernel, and numba's cache is stamped by
# this file: edited with its guide table of round 28 and with map_sample's
# direction, density and radiance from the drawn texture direction (round 29).
from .environment_kernels import EnvironmentKernel, map_sample, no_map
from .ies_kernels import ies_factor
from .table import AREA, MESH, POINT, SPOT, SUN, WORLD, _lum
from .warp_kernels import spread_atten

_PI = np.pi
_INV_PI = 1.0 / np.pi
# sampling._SPH_TRI_MIN (imported there from here would be circular: keep one value).
SPH_TRI_MIN = 1e-3


class DirectLights(NamedTuple):
    """The LightTable's arrays the kernel reads (Nl emitters, E entries, G group
    triangles): kind (Nl,) int8; lum_strength, lum_flux (Nl,) luminance of
    strength / flux (``table._lum``); strength, radiance, co, axis_u, axis_v,
    dir (Nl, 3); len_u, len_v, area, radius, cos_half_spot, spot_smooth,
    half_angle, cos_half_angle, spread_tan, spread_norm (Nl,); ellipse,
    is_sphere, cast_shadow (Nl,)
    bool; lin_inv (Nl, 3, 3); entry (E,) int64 entry -> emitter (-1 group);
    group_tri (G,) int64; group_cdf (G,); group (4,) centre x, y, z and ext^2;
    sel the :class:`EntryLights` of the same emitters; env the world's
    ``environment_kernels.EnvironmentKernel`` (``no_map()``: none); ies the
    packed IES profiles (``LightTable.ies``, empty: none)."""
    kind: np.ndarray
    lum_strength: np.ndarray
    lum_flux: np.ndarray
    strength: np.ndarray
    radiance: np.ndarray
    co: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    dir: np.ndarray
    len_u: np.ndarray
    len_v: np.ndarray
    area: np.ndarray
    radius: np.ndarray
    cos_half_spot: np.ndarray
    spot_smooth: np.ndarray
    half_angle: np.ndarray
    cos_half_angle: np.ndarray
    spread_tan: np.ndarray
    spread_norm: np.ndarray
    ellipse: np.ndarray
    is_sphere: np.ndarray
    cast_shadow: np.ndarray
    lin_inv: np.ndarray
    entry: np.ndarray
    group_tri: np.ndarray
    group_cdf: np.ndarray
    group: np.ndarray
    sel: EntryLights
    env: EnvironmentKernel
    ies: np.ndarray


# Columns of EntryLights.row: kind, luminance of flux / strength, radius,
# area, spot cone (cos_half_spot, spot_smooth), position (co; a triangle's
# centroid), dir, lin_inv (row-major).
_KIND, _LF, _LS, _RAD, _AREA, _CHS, _SSM, _POS, _DIR, _LIN = 0, 1, 2, 3, 4, 5, 6, 7, 10, 13
_ENTRY_COLS = 22


class EntryLights(NamedTuple):
    """What :func:`_entry_weight` and :func:`_spot_atten` read of each of the
    Nl emitters, packed: row (Nl, 22) float64 (columns ``_KIND`` ..
    ``_LIN`` above; :func:`entry_lights`).  Every call of a numba function
    taking a tuple of arrays pays the reference counting of each array (~11
    ns, measured): the 25 arrays of DirectLights cost 270 ns per selection
    weight against 4 ns for the formula of an area light; one array, ~10 ns.
    The same float64 values (the centroid by the same operations), so the
    weights are bit-identical."""
    row: np.ndarray


class Receivers(NamedTuple):
    """The visible points to light, K rows: q (K,) int64 pixel; and per pixel
    (P rows) p, n (oriented shading normal), beta, albedo (P, 3) float64 and
    const (P,) bool (Lambert-only: albedo is the sum of its Lambert lobes);
    u (K, 3) uniforms (selection, u1, u2)."""
    q: np.ndarray
    p: np.ndarray
    n: np.ndarray
    beta: np.ndarray
    albedo: np.ndarray
    const: np.ndarray
    u: np.ndarray


class DirectSamples(NamedTuple):
    """Per receiver row (K): wi (K, 3) unit towards the sample; dist (K,)
    (inf: sun, world); weight (K, 3) L_e G / pdf / p_select (0: nothing);
    cos (K,) |n . wi|; contrib (K, 3) beta f cos weight (Lambert-only rows;
    others: 0 until the caller multiplies f in); kind (K,) int8 (-1 none);
    shadow (K,) bool casts shadows; light (K,) int64 the emitter row
    sampled (-1 none; the path tracer's MIS needs its pdf)."""
    wi: np.ndarray
    dist: np.ndarray
    weight: np.ndarray
    cos: np.ndarray
    contrib: np.ndarray
    kind: np.ndarray
    shadow: np.ndarray
    light: np.ndarray


def compiled_lights_ok(table, environment: bool = False) -> bool:
    """Whether :func:`direct_kernel` covers every emitter of the table: not
    textured emissive triangles, nor an environment map unless
    ``environment`` (the kernel samples a map's distribution; the caller
    weighs it against its BSDF samples: the camera paths' MIS, the visible
    points' ``map_mis_kernels``)."""
    if table.environment is not None and not environment:
        return False
    return not bool(np.any((table.kind == MESH) & (table.tex >= 0)))


def build_direct_lights(table) -> DirectLights:
    """The kernel's view of a ``LightTable`` (same float64 values)."""
    c = np.ascontiguousarray
    n = table.kind.shape[0]
    ls = np.array([float(_lum(table.strength[j])) for j in range(n)], np.float64)
    lf = np.array([float(_lum(table.flux[j])) for j in range(n)], np.float64)
    gt = table.group_tri if table.group_tri is not None else np.zeros(0, np.int64)
    gc = table.group_cdf if table.group_cdf is not None else np.zeros(0)
    gcen = table.group_center if table.group_center is not None else np.zeros(3)
    L = DirectLights(
        kind=c(table.kind, np.int8), lum_strength=ls, lum_flux=lf,
        strength=c(table.strength, np.float64), radiance=c(table.radiance, np.float64),
        co=c(table.co, np.float64), axis_u=c(table.axis_u, np.float64),
        axis_v=c(table.axis_v, np.float64), dir=c(table.dir, np.float64),
        len_u=c(table.len_u, np.float64), len_v=c(table.len_v, np.float64),
        area=c(table.area, np.float64), radius=c(table.radius, np.float64),
        cos_half_spot=c(table.cos_half_spot, np.float64),
        spot_smooth=c(table.spot_smooth, np.float64),
        half_angle=c(table.half_angle, np.float64),
        cos_half_angle=c(table.cos_half_angle, np.float64),
        spread_tan=c(table.spread_tan, np.float64), spread_norm=c(table.spread_norm, np.float64),
        ellipse=c(table.ellipse, bool), is_sphere=c(table.is_sphere, bool),
        cast_shadow=c(table.cast_shadow, bool),
        lin_inv=c(np.asarray(table.lin_inv, np.float64).reshape(n, 3, 3)),
        entry=c(table.entry_emitter, np.int64), group_tri=c(gt, np.int64),
        group_cdf=c(gc, np.float64),
        group=np.array([gcen[0], gcen[1], gcen[2], float(table.group_ext2)], np.float64),
        sel=None, env=_map_of(table), ies=c(table.ies, np.float64))
    return L._replace(sel=entry_lights(L))


def _map_of(table) -> EnvironmentKernel:
    """The table's environment map for the kernel (``no_map`` without one)."""
    env = table.environment
    return env.kernel_data() if env is not None and env.total > 0 else no_map()


def entry_lights(L) -> EntryLights:
    """The :class:`EntryLights` of the DirectLights L."""
    n = L.kind.shape[0]
    row = np.zeros((n, _ENTRY_COLS))
    row[:, _KIND] = L.kind
    row[:, _LF] = L.lum_flux
    row[:, _LS] = L.lum_strength
    row[:, _RAD] = L.radius
    row[:, _AREA] = L.area
    row[:, _CHS] = L.cos_half_spot
    row[:, _SSM] = L.spot_smooth
    mesh = (L.kind == MESH)[:, None]
    row[:, _POS:_POS + 3] = np.where(mesh, L.co + (L.axis_u + L.axis_v) / 3.0, L.co)
    row[:, _DIR:_DIR + 3] = L.dir
    row[:, _LIN:_LIN + 9] = L.lin_inv.reshape(n, 9)
    return EntryLights(row)


def alloc_samples(K: int) -> DirectSamples:
    """Zeroed DirectSamples for K receivers (rows without a light stay so)."""
    return DirectSamples(wi=np.zeros((K, 3)), dist=np.zeros(K), weight=np.zeros((K, 3)),
                         cos=np.zeros(K), contrib=np.zeros((K, 3)),
                         kind=np.full(K, -1, np.int8), shadow=np.ones(K, bool),
                         light=np.full(K, -1, np.int64))


# ----------------------------------------------------------------------------
# Per-sample helpers (scalars in, scalars out).

@njit(cache=True)
def _frame(nx, ny, nz):
    """mathutil.frame (Duff et al. 2017): tangents t, b of unit n."""
    sg = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sg + nz)
    b = nx * ny * a
    return (1.0 + sg * nx * nx * a, sg * b, -sg * nx, b, sg + ny * ny * a, -ny)


@njit(cache=True)
def _to_world(lx, ly, lz, nx, ny, nz):
    tx, ty, tz, bx, by, bz = _frame(nx, ny, nz)
    return (lx * tx + ly * bx + lz * nx, lx * ty + ly * by + lz * ny, lx * tz + ly * bz + lz * nz)


@njit(cache=True)
def _cone_local(cos_max, u1, u2):
    z = 1.0 - u1 * (1.0 - cos_max)
    s = np.sqrt(max(1.0 - z * z, 0.0))
    phi = 2.0 * _PI * u2
    return s * np.cos(phi), s * np.sin(phi), z


@njit(cache=True)
def _nrm3(x, y, z):
    """warps._normalize of one vector."""
    n = np.sqrt(x * x + y * y + z * z)
    if not n > 0.0:
        n = 1.0
    return x / n, y / n, z / n


@njit(cache=True)
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@njit(cache=True, **NO_REFCOUNTS)
def _spot_atten(r, j, wx, wy, wz):
    """table._spot_atten of one direction leaving light j (r: EntryLights.row)."""
    m = _LIN
    lx = r[j, m] * wx + r[j, m + 1] * wy + r[j, m + 2] * wz
    ly = r[j, m + 3] * wx + r[j, m + 4] * wy + r[j, m + 5] * wz
    lz = r[j, m + 6] * wx + r[j, m + 7] * wy + r[j, m + 8] * wz
    lx, ly, lz = _nrm3(lx, ly, lz)
    x = min(max((-lz - r[j, _CHS]) * r[j, _SSM], 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, error_model="numpy")
def _spherical_rect(px, py, pz, sx, sy, sz, exx, exy, exz, lx, eyx, eyy, eyz, ly, u1, u2):
    """sampling._sample_spherical_rect for one receiver: (q x, y, z, S)."""
    zx, zy, zz = _cross(exx, exy, exz, eyx, eyy, eyz)
    dx, dy, dz = sx - px, sy - py, sz - pz
    z0 = dx * zx + dy * zy + dz * zz
    if z0 > 0:
        zx, zy, zz = -zx, -zy, -zz
        z0 = -z0
    x0 = dx * exx + dy * exy + dz * exz
    y0 = dx * eyx + dy * eyy + dz * eyz
    x1 = x0 + lx
    y1 = y0 + ly
    n0x, n0y, n0z = _nrm3(*_cross(x0, y0, z0, x1, y0, z0))
    n1x, n1y, n1z = _nrm3(*_cross(x1, y0, z0, x1, y1, z0))
    n2x, n2y, n2z = _nrm3(*_cross(x1, y1, z0, x0, y1, z0))
    n3x, n3y, n3z = _nrm3(*_cross(x0, y1, z0, x0, y0, z0))
    g0 = np.arccos(min(max(-(n0x * n1x + n0y * n1y + n0z * n1z), -1.0), 1.0))
    g1 = np.arccos(min(max(-(n1x * n2x + n1y * n2y + n1z * n2z), -1.0), 1.0))
    g2 = np.arccos(min(max(-(n2x * n3x + n2y * n3y + n2z * n3z), -1.0), 1.0))
    g3 = np.arccos(min(max(-(n3x * n0x + n3y * n0y + n3z * n0z), -1.0), 1.0))
    b0, b1 = n0z, n2z
    k = 2.0 * _PI - g2 - g3
    S = max(g0 + g1 - k, 0.0)
    au = u1 * S + k
    fu = (np.cos(au) * b0 - b1) / np.sin(au)
    sgn = 1.0 if fu > 0 else (-1.0 if fu < 0 else 0.0)
    cu = sgn / np.sqrt(fu * fu + b0 * b0)
    xu = x0                              # numpy: nan_to_num(xu, nan=x0)
    if not (np.isnan(fu) or np.isnan(cu)):
        cu = min(max(cu, -1.0), 1.0)
        xu = -(cu * z0) / np.sqrt(max(1.0 - cu * cu, 1e-300))
        if np.isnan(xu):
            xu = x0
    xu = min(max(xu, x0), x1)
    dd = np.sqrt(xu * xu + z0 * z0)
    h0 = y0 / np.sqrt(dd * dd + y0 * y0)
    h1 = y1 / np.sqrt(dd * dd + y1 * y1)
    hv = h0 + u2 * (h1 - h0)
    hv2 = hv * hv
    if hv2 < 1.0 - 1e-6:
        yv = hv * dd / np.sqrt(max(1.0 - hv2, 1e-300))
    else:
        yv = y1
    yv = min(max(yv, y0), y1)
    return (px + xu * exx + yv * eyx + z0 * zx, py + xu * exy + yv * eyy + z0 * zy,
            pz + xu * exz + yv * eyz + z0 * zz, S)


@njit(cache=True, error_model="numpy", inline="always")
def spread_rect(tan, cx, cy, cz, nx, ny, nz, ux, uy, uz, lu, vx, vy, vz, lv, px, py, pz):
    """table.spread_rect for one rectangle (centre c, unit normal n, unit
    axes u, v of lengths lu, lv; tan = tan a of its half spread, inf: none)
    and receiver p: (corner x, y, z, len_u, len_v) of the part that can
    light p."""
    hu, hv = 0.5 * lu, 0.5 * lv
    if tan == np.inf:
        return (cx - hu * ux - hv * vx, cy - hu * uy - hv * vy, cz - hu * uz - hv * vz, lu, lv)
    dx, dy, dz = px - cx, py - cy, pz - cz
    r = max(dx * nx + dy * ny + dz * nz, 0.0) * tan
    x = dx * ux + dy * uy + dz * uz
    y = dx * vx + dy * vy + dz * vz
    u0, u1 = max(-hu, x - r), min(hu, x + r)
    v0, v1 = max(-hv, y - r), min(hv, y + r)
    return (cx + u0 * ux + v0 * vx, cy + u0 * uy + v0 * vy, cz + u0 * uz + v0 * vz,
            max(u1 - u0, 0.0), max(v1 - v0, 0.0))


@njit(cache=True, error_model="numpy", inline="always")
def rect_of(L, j, px, py, pz):
    """:func:`spread_rect` of DirectLights L's row j for receiver p."""
    return spread_rect(L.spread_tan[j], L.co[j, 0], L.co[j, 1], L.co[j, 2], L.dir[j, 0],
                       L.dir[j, 1], L.dir[j, 2], L.axis_u[j, 0], L.axis_u[j, 1],
                       L.axis_u[j, 2], L.len_u[j], L.axis_v[j, 0], L.axis_v[j, 1],
                       L.axis_v[j, 2], L.len_v[j], px, py, pz)


@njit(cache=True, error_model="numpy")
def _spherical_rect_solid_angle(px, py, pz, sx, sy, sz, exx, exy, exz, lx, eyx, eyy, eyz, ly):
    """The solid angle S of _spherical_rect (same arguments but u1, u2) alone,
    as two triangles' (Van Oosterom & Strackee 1983: tan(W/2) = |a.(b x c)|
    / (1 + a.b + b.c + c.a) for unit corners a, b, c): for densities, which
    need no sample (no arccos, cos, sin); equal to _spherical_rect's S
    within float rounding."""
    cx, cy, cz = sx - px, sy - py, sz - pz
    ax, ay, az = _nrm3(cx, cy, cz)
    bx, by, bz = _nrm3(cx + lx * exx, cy + lx * exy, cz + lx * exz)
    dx, dy, dz = _nrm3(cx + lx * exx + ly * eyx, cy + lx * exy + ly * eyy,
                       cz + lx * exz + ly * eyz)
    ex, ey, ez = _nrm3(cx + ly * eyx, cy + ly * eyy, cz + ly * eyz)
    ad = ax * dx + ay * dy + az * dz
    kx, ky, kz = _cross(bx, by, bz, dx, dy, dz)
    w = 2.0 * np.arctan2(abs(ax * kx + ay * ky + az * kz),
                         1.0 + ax * bx + ay * by + az * bz + bx * dx + by * dy + bz * dz + ad)
    kx, ky, kz = _cross(dx, dy, dz, ex, ey, ez)
    return w + 2.0 * np.arctan2(abs(ax * kx + ay * ky + az * kz),
                                1.0 + ad + dx * ex + dy * ey + dz * ez + ex * ax + ey * ay
                                + ez * az)


@njit(cache=True, error_model="numpy")
def _spherical_tri(px, py, pz, Ax, Ay, Az, Bx, By, Bz, Cx, Cy, Cz, u1, u2):
    """sampling._sample_spherical_tri for one receiver: (w x, y, z, omega)."""
    ax, ay, az = _nrm3(Ax - px, Ay - py, Az - pz)
    bx, by, bz = _nrm3(Bx - px, By - py, Bz - pz)
    cx, cy, cz = _nrm3(Cx - px, Cy - py, Cz - pz)
    kx, ky, kz = _cross(bx, by, bz, cx, cy, cz)
    trip = abs(ax * kx + ay * ky + az * kz)
    ab = ax * bx + ay * by + az * bz
    bc = bx * cx + by * cy + bz * cz
    ca = cx * ax + cy * ay + cz * az
    omega = 2.0 * np.arctan2(trip, 1.0 + ab + bc + ca)
    if omega < 0:
        omega += 2 * _PI
    nabx, naby, nabz = _nrm3(*_cross(ax, ay, az, bx, by, bz))
    ncax, ncay, ncaz = _nrm3(*_cross(cx, cy, cz, ax, ay, az))
    alpha = np.arccos(min(max(-(nabx * ncax + naby * ncay + nabz * ncaz), -1.0), 1.0))
    cos_c = min(max(ab, -1.0), 1.0)
    area_hat = u1 * omega
    s = np.sin(area_hat - alpha)
    t = np.cos(area_hat - alpha)
    uu = t - np.cos(alpha)
    vv = s + np.sin(alpha) * cos_c
    q = ((vv * t - uu * s) * np.cos(alpha) - vv) / ((vv * s + uu * t) * np.sin(alpha))
    if np.isnan(q):
        q = 1.0
    q = min(max(q, -1.0), 1.0)
    cpx, cpy, cpz = _nrm3(cx - ca * ax, cy - ca * ay, cz - ca * az)
    sq = np.sqrt(max(1.0 - q * q, 0.0))
    chx, chy, chz = q * ax + sq * cpx, q * ay + sq * cpy, q * az + sq * cpz
    chb = chx * bx + chy * by + chz * bz
    z = 1.0 - u2 * (1.0 - chb)
    hpx, hpy, hpz = _nrm3(chx - chb * bx, chy - chb * by, chz - chb * bz)
    sz = np.sqrt(max(1.0 - z * z, 0.0))
    wx, wy, wz = _nrm3(z * bx + sz * hpx, z * by + sz * hpy, z * bz + sz * hpz)
    return wx, wy, wz, omega


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _entry_weight(S, j, px, py, pz):
    """One column of sampling._entry_weights (entry of emitter j >= 0; S:
    EntryLights)."""
    r = S.row
    k = r[j, _KIND]
    lf = r[j, _LF]
    if lf <= 0:
        return 0.0
    if k == SUN:
        return r[j, _LS]
    if k == WORLD:
        return _PI * r[j, _LS]
    dx, dy, dz = px - r[j, _POS], py - r[j, _POS + 1], pz - r[j, _POS + 2]
    d2 = dx * dx + dy * dy + dz * dz
    if k == POINT or k == SPOT:
        Il = r[j, _LS] / (4.0 * _PI)
        w = Il / max(d2 + r[j, _RAD] ** 2, 1e-300)
        if k == SPOT:
            nx, ny, nz = _nrm3(dx, dy, dz)
            att = _spot_atten(r, j, nx, ny, nz)
            w = w * (att if r[j, _RAD] == 0 else max(att, 0.05))
        return w
    if k == AREA:
        h = dx * r[j, _DIR] + dy * r[j, _DIR + 1] + dz * r[j, _DIR + 2]
        cosl = min(max(h / np.sqrt(max(d2, 1e-300)), 0.1), 1.0)
        return lf * cosl / (_PI * (d2 + r[j, _AREA])) if h > 0 else 0.0
    # An emissive triangle: the position column holds its centroid.
    return lf / (2.0 * _PI * (d2 + r[j, _AREA]))


@njit(cache=True, nogil=True, error_model="numpy")
def direct_kernel(k0, k1, L, R, out):
    """Rows k0..k1-1 of the Receivers R into the DirectSamples out (see there)."""
    E = L.entry.shape[0]
    G = L.group_cdf.shape[0]
    W = np.empty(E)
    EL = L.sel
    for k in range(k0, k1):
        i = R.q[k]
        px, py, pz = R.p[i, 0], R.p[i, 1], R.p[i, 2]
        # Selection ~ irradiance bound (sampling._entry_weights).
        tot = 0.0
        for e in range(E):
            j = L.entry[e]
            if j < 0:
                d2 = ((px - L.group[0]) ** 2 + (py - L.group[1]) ** 2
                      + (pz - L.group[2]) ** 2)
                w = L.group_cdf[G - 1] / (2.0 * _PI * (d2 + L.group[3]))
            else:
                w = _entry_weight(EL, j, px, py, pz)
            if not np.isfinite(w):
                w = 0.0
            W[e] = w
            tot += w
        if not tot > 0:
            continue
        x = R.u[k, 0] * tot
        C = 0.0
        e = 0
        # e = the number of cumulative sums <= x (numpy's cumsum order), at most E - 1.
        for e2 in range(E):
            C += W[e2]
            e = e2
            if C > x:
                break
        Ce = C
        We = W[e]
        if not We > 0:
            continue
        p_sel = We / tot
        j = L.entry[e]
        if j < 0:
            u_re = min(max((x - (Ce - We)) / We, 0.0), 1.0 - 1e-16)
            target = u_re * L.group_cdf[G - 1]
            ti = np.searchsorted(L.group_cdf, target, side="right")
            ti = min(ti, G - 1)
            lum_i = L.group_cdf[ti] - (L.group_cdf[ti - 1] if ti > 0 else 0.0)
            p_sel *= lum_i / L.group_cdf[G - 1]
            j = L.group_tri[ti]
        kind = L.kind[j]
        out.kind[k] = kind
        out.light[k] = j
        out.shadow[k] = L.cast_shadow[j]
        u1, u2 = R.u[k, 1], R.u[k, 2]
        wx, wy, wz = 0.0, 0.0, 1.0
        t = 0.0
        l0 = l1 = l2 = 0.0
        if kind == POINT or kind == SPOT:
            r = L.radius[j]
            dx, dy, dz = px - L.co[j, 0], py - L.co[j, 1], pz - L.co[j, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            dm = max(d, 1e-300)
            nx, ny, nz = dx / dm, dy / dm, dz / dm
            wx, wy, wz = -nx, -ny, -nz
            t = d
            sphere = L.is_sphere[j]
            if r == 0:
                dd = max(d ** 2, 1e-300)
                l0 = L.strength[j, 0] / (4.0 * _PI) / dd
                l1 = L.strength[j, 1] / (4.0 * _PI) / dd
                l2 = L.strength[j, 2] / (4.0 * _PI) / dd
            elif not sphere:
                rr = np.sqrt(u1)
                phi = 2.0 * _PI * u2
                x_, y_ = rr * np.cos(phi), rr * np.sin(phi)
                t1x, t1y, t1z, t2x, t2y, t2z = _frame(nx, ny, nz)
                qx = L.co[j, 0] + r * (x_ * t1x + y_ * t2x)
                qy = L.co[j, 1] + r * (x_ * t1y + y_ * t2y)
                qz = L.co[j, 2] + r * (x_ * t1z + y_ * t2z)
                vx, vy, vz = qx - px, qy - py, qz - pz
                tt = np.sqrt(vx * vx + vy * vy + vz * vz)
                tm = max(tt, 1e-300)
                wx, wy, wz = vx / tm, vy / tm, vz / tm
                cosl = -(wx * nx + wy * ny + wz * nz)
                g = _PI * r ** 2 * max(cosl, 0.0) / max(tt * tt, 1e-300)
                l0, l1, l2 = L.radiance[j, 0] * g, L.radiance[j, 1] * g, L.radiance[j, 2] * g
                t = tt
            else:
                out_ = d > r
                if out_:
                    sin2 = (r / max(d, 1e-300)) ** 2
                    omc = sin2 / (1.0 + np.sqrt(max(1.0 - sin2, 0.0)))
                else:
                    omc = 2.0
                lx, ly, lz = _cone_local(1.0 - omc, u1, u2)
                wx, wy, wz = _to_world(lx, ly, lz, -nx, -ny, -nz)
                b = wx * (L.co[j, 0] - px) + wy * (L.co[j, 1] - py) + wz * (L.co[j, 2] - pz)
                c = d * d - r * r
                disc = np.sqrt(max(b * b - c, 0.0))
                tt = b - disc if out_ else b + disc
                g = 2.0 * _PI * omc
                l0, l1, l2 = L.radiance[j, 0] * g, L.radiance[j, 1] * g, L.radiance[j, 2] * g
                t = max(tt, 0.0)
            if kind == SPOT:
                # sampling.sample_direct: the sample's direction (Cycles).
                att = _spot_atten(EL.row, j, -wx, -wy, -wz)
                if sphere and r != 0 and d <= r:
                    att = 1.0
                l0, l1, l2 = l0 * att, l1 * att, l2 * att
            if L.ies.shape[0]:
                # An IES profile along the direction leaving the light's sample.
                f = ies_factor(L.ies, j, -wx, -wy, -wz)
                l0, l1, l2 = l0 * f, l1 * f, l2 * f
        elif kind == SUN:
            ax, ay, az = -L.dir[j, 0], -L.dir[j, 1], -L.dir[j, 2]
            t = np.inf
            if L.half_angle[j] > 0:
                com = 1.0 - L.cos_half_angle[j]
                lx, ly, lz = _cone_local(L.cos_half_angle[j], u1, u2)
                wx, wy, wz = _to_world(lx, ly, lz, ax, ay, az)
                g = 2.0 * _PI * com
                l0, l1, l2 = L.radiance[j, 0] * g, L.radiance[j, 1] * g, L.radiance[j, 2] * g
            else:
                wx, wy, wz = ax, ay, az
                l0, l1, l2 = L.strength[j, 0], L.strength[j, 1], L.strength[j, 2]
        elif kind == WORLD and L.env.total > 0:
            # An environment map: its own distribution (sampling._sample_environment).
            wx, wy, wz, pdf, r0, r1, r2 = map_sample(L.env, u1, u2)
            t = np.inf
            if pdf > 0:
                l0, l1, l2 = r0 / pdf, r1 / pdf, r2 / pdf
        elif kind == WORLD:
            nx, ny, nz = R.n[i, 0], R.n[i, 1], R.n[i, 2]
            rr = np.sqrt(u1)
            phi = 2.0 * _PI * u2
            cz = np.sqrt(max(1.0 - u1, 0.0))
            tx, ty, tz, bx, by, bz = _frame(nx, ny, nz)
            a_, b_ = rr * np.cos(phi), rr * np.sin(phi)
            wx, wy, wz = _nrm3(tx * a_ + bx * b_ + nx * cz, ty * a_ + by * b_ + ny * cz,
                               tz * a_ + bz * b_ + nz * cz)
            t = np.inf
            g = _PI / max(cz, 1e-12)
            l0, l1, l2 = L.strength[j, 0] * g, L.strength[j, 1] * g, L.strength[j, 2] * g
        elif kind == AREA:
            su, sv = u1 - 0.5, u2 - 0.5
            ell = L.ellipse[j]
            if ell:
                rr = np.sqrt(u1)
                phi = 2.0 * _PI * u2
                su, sv = 0.5 * (rr * np.cos(phi)), 0.5 * (rr * np.sin(phi))
            a_ = su * L.len_u[j]
            b_ = sv * L.len_v[j]
            qx = L.co[j, 0] + a_ * L.axis_u[j, 0] + b_ * L.axis_v[j, 0]
            qy = L.co[j, 1] + a_ * L.axis_u[j, 1] + b_ * L.axis_v[j, 1]
            qz = L.co[j, 2] + a_ * L.axis_u[j, 2] + b_ * L.axis_v[j, 2]
            vx, vy, vz = qx - px, qy - py, qz - pz
            t = np.sqrt(vx * vx + vy * vy + vz * vz)
            tm = max(t, 1e-300)
            wx, wy, wz = vx / tm, vy / tm, vz / tm
            cosl = -(wx * L.dir[j, 0] + wy * L.dir[j, 1] + wz * L.dir[j, 2])
            g = L.area[j] * max(cosl, 0.0) / max(t * t, 1e-300)
            l0, l1, l2 = L.radiance[j, 0] * g, L.radiance[j, 1] * g, L.radiance[j, 2] * g
            if not ell:
                # The rectangle (a spread: the part its slats let through to p).
                sx, sy, sz, lu, lv = rect_of(L, j, px, py, pz)
                qx, qy, qz, S = _spherical_rect(
                    px, py, pz, sx, sy, sz, L.axis_u[j, 0], L.axis_u[j, 1], L.axis_u[j, 2],
                    lu, L.axis_v[j, 0], L.axis_v[j, 1], L.axis_v[j, 2], lv, u1, u2)
                if S > 1e-6:
                    front = ((px - L.co[j, 0]) * L.dir[j, 0] + (py - L.co[j, 1]) * L.dir[j, 1]
                             + (pz - L.co[j, 2]) * L.dir[j, 2]) > 0
                    vx, vy, vz = qx - px, qy - py, qz - pz
                    t = np.sqrt(vx * vx + vy * vy + vz * vz)
                    tm = max(t, 1e-300)
                    wx, wy, wz = vx / tm, vy / tm, vz / tm
                    g = S if front else 0.0
                    l0, l1, l2 = (L.radiance[j, 0] * g, L.radiance[j, 1] * g,
                                  L.radiance[j, 2] * g)
            if L.spread_tan[j] != np.inf:
                # A spread below 180 deg: its factor along the sampled direction.
                fsp = spread_atten(L.spread_tan[j], L.spread_norm[j],
                                   -(wx * L.dir[j, 0] + wy * L.dir[j, 1] + wz * L.dir[j, 2]))
                l0, l1, l2 = l0 * fsp, l1 * fsp, l2 * fsp
        elif kind == MESH:
            s_ = np.sqrt(u1)
            b1, b2 = s_ * (1.0 - u2), s_ * u2
            p0x, p0y, p0z = L.co[j, 0], L.co[j, 1], L.co[j, 2]
            e1x, e1y, e1z = L.axis_u[j, 0], L.axis_u[j, 1], L.axis_u[j, 2]
            e2x, e2y, e2z = L.axis_v[j, 0], L.axis_v[j, 1], L.axis_v[j, 2]
            vx = p0x + b1 * e1x + b2 * e2x - px
            vy = p0y + b1 * e1y + b2 * e2y - py
            vz = p0z + b1 * e1z + b2 * e2z - pz
            t = np.sqrt(vx * vx + vy * vy + vz * vz)
            tm = max(t, 1e-300)
            wx, wy, wz = vx / tm, vy / tm, vz / tm
            nx, ny, nz = L.dir[j, 0], L.dir[j, 1], L.dir[j, 2]
            cosl = abs(wx * nx + wy * ny + wz * nz)
            geo = L.area[j] * cosl / max(t * t, 1e-300)
            sx, sy, sz, omega = _spherical_tri(px, py, pz, p0x, p0y, p0z, p0x + e1x, p0y + e1y,
                                               p0z + e1z, p0x + e2x, p0y + e2y, p0z + e2z,
                                               u1, u2)
            if omega > SPH_TRI_MIN:
                den = sx * nx + sy * ny + sz * nz
                ts = (((p0x - px) * nx + (p0y - py) * ny + (p0z - pz) * nz)
                      / (den if den != 0 else 1e-300))
                good = np.isfinite(ts) and ts > 0
                wx, wy, wz = sx, sy, sz
                t = ts if good else 0.0
                geo = omega if good else 0.0
            l0, l1, l2 = L.strength[j, 0] * geo, L.strength[j, 1] * geo, L.strength[j, 2] * geo
            if t <= 0:
                l0 = l1 = l2 = 0.0
        out.wi[k, 0], out.wi[k, 1], out.wi[k, 2] = wx, wy, wz
        out.dist[k] = t
        w0, w1, w2 = l0 / p_sel, l1 / p_sel, l2 / p_sel
        if not np.isfinite(w0):
            w0 = 0.0
        if not np.isfinite(w1):
            w1 = 0.0
        if not np.isfinite(w2):
            w2 = 0.0
        out.weight[k, 0], out.weight[k, 1], out.weight[k, 2] = w0, w1, w2
        nx, ny, nz = R.n[i, 0], R.n[i, 1], R.n[i, 2]
        cdot = nx * wx + ny * wy + nz * wz
        out.cos[k] = abs(cdot)
        if R.const[i] and cdot > 0.0:
            # Lambert-only: f = the Lambert lobes' colours / pi on the lit side.
            f0, f1, f2 = R.albedo[i, 0] * _INV_PI, R.albedo[i, 1] * _INV_PI, R.albedo[i, 2] * _INV_PI
            c = abs(cdot)
            out.contrib[k, 0] = R.beta[i, 0] * f0 * c * w0
            out.contrib[k, 1] = R.beta[i, 1] * f1 * c * w1
            out.contrib[k, 2] = R.beta[i, 2] * f2 * c * w2


@njit(cache=True, nogil=True)
def _positive(c0, c1, c2):
    """numpy's ``max(c) > 0`` of one row (NaN anywhere: False)."""
    if np.isnan(c0) or np.isnan(c1) or np.isnan(c2):
        return False
    return c0 > 0 or c1 > 0 or c2 > 0


@njit(cache=True, nogil=True)
def bsdf_rows(q, const, weight):
    """(n,) int64 the receiver rows k whose f is ``eval_bsdf``'s (not
    Lambert-only, const[q[k]] False) and that have light (weight[k] > 0
    somewhere): ``np.nonzero(~const[q] & (weight.max(axis=1) > 0))[0]``."""
    out = np.empty(q.shape[0], np.int64)
    n = 0
    for k in range(q.shape[0]):
        if not const[q[k]] and _positive(weight[k, 0], weight[k, 1], weight[k, 2]):
            out[n] = k
            n += 1
    return out[:n]


class ShadowRays(NamedTuple):
    """The shadow rays of :func:`shadow_kernel`, compacted: o32, d32 (K, 3)
    float32 Embree's origins (``accel.spawn``) and directions, t32 (K,)
    float32 lengths; rows (K,) int64 the receiver row of each; mesh (K,)
    int64 the rows lit by emissive triangles (their test is
    ``NextEventEstimation._blocked``'s, in numpy)."""
    o32: np.ndarray
    d32: np.ndarray
    t32: np.ndarray
    rows: np.ndarray
    mesh: np.ndarray


def alloc_shadow(K: int) -> ShadowRays:
    return ShadowRays(o32=np.empty((K, 3), np.float32), d32=np.empty((K, 3), np.float32),
                      t32=np.empty(K, np.float32), rows=np.empty(K, np.int64),
                      mesh=np.empty(K, np.int64))


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_kernel(q, p, ng, S, rel, floor, sh, L):
    """The shadow rays of the DirectSamples S (receiver rows k, pixels q[k]).

    Rows whose contribution is not positive are dropped; rows of lights that
    cast no shadow are added to L (P, 3) at once; rows lit by emissive
    triangles go to sh.mesh; the others get a ray from ``accel.spawn``'s
    origin (offset max(|p|_inf, floor) * rel along ng, to wi's side), in
    float32 as Embree takes it.  Returns (rays, mesh rows)."""
    n = 0
    nm = 0
    for k in range(q.shape[0]):
        c0, c1, c2 = S.contrib[k, 0], S.contrib[k, 1], S.contrib[k, 2]
        if not _positive(c0, c1, c2):
            continue
        i = q[k]
        if not S.shadow[k]:
            L[i, 0] += c0
            L[i, 1] += c1
            L[i, 2] += c2
            continue
        if S.kind[k] == MESH:
            sh.mesh[nm] = k
            nm += 1
            continue
        wx, wy, wz = S.wi[k, 0], S.wi[k, 1], S.wi[k, 2]
        gx, gy, gz = ng[i, 0], ng[i, 1], ng[i, 2]
        px, py, pz = p[i, 0], p[i, 1], p[i, 2]
        side = 1.0 if gx * wx + gy * wy + gz * wz >= 0 else -1.0
        off = side * (max(max(abs(px), abs(py), abs(pz)), floor) * rel)
        sh.o32[n, 0] = px + gx * off
        sh.o32[n, 1] = py + gy * off
        sh.o32[n, 2] = pz + gz * off
        sh.d32[n, 0], sh.d32[n, 1], sh.d32[n, 2] = wx, wy, wz
        sh.t32[n] = min(S.dist[k], 3e37)
        sh.rows[n] = k
        n += 1
    return n, nm


@njit(cache=True, nogil=True)
def accumulate(q, rows, blocked, contrib, L):
    """L[q[rows[m]]] += contrib[rows[m]] for the rays m not blocked."""
    for m in range(rows.shape[0]):
        if not blocked[m]:
            k = rows[m]
            i = q[k]
            L[i, 0] += contrib[k, 0]
            L[i, 1] += contrib[k, 1]
            L[i, 2] += contrib[k, 2]
