"""An environment map's photons, compiled (core.lights.emission's numpy
code for the world's map, per photon).  A module of its own, so that
importing core.lights (the add-on's register() does) loads no numba.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..materials.compiled import sincos_turn
from ..scene.texture_kernels import bilinear_rgb
from .warp_kernels import basis_world, upper_bound


class EnvironmentKernel(NamedTuple):
    """An EnvironmentLight's tables for :func:`world_photons`: cdf, weight
    (H W,) (row-major ``weight``), z_edges (H + 1,), A (the map's
    to_texture) and A_inv (3, 3), strength (3,), image (H, W, C) the map
    (float32), W its width, det |det A|, total cdf[-1], last the last
    region of positive weight, unassociate: rgb / alpha on lookup
    (``textures.UnassociatedImage``); guide (G + 1,) int64 the search's
    guide table (:func:`guide_table`)."""
    cdf: np.ndarray
    weight: np.ndarray
    z_edges: np.ndarray
    A: np.ndarray
    A_inv: np.ndarray
    strength: np.ndarray
    image: np.ndarray
    W: int
    det: float
    total: float
    last: int
    unassociate: bool
    guide: np.ndarray


def guide_table(cdf: np.ndarray, total: float) -> np.ndarray:
    """(G + 1,) int64: entry g the first region whose cdf exceeds
    (g / G) total, G a power of two about a quarter of the regions.  A u1
    with int(u1 G) = g then finds its region between entries g and g + 1
    (:func:`guided_region`), the region the bisection of the whole cdf finds
    (g / G is exact, so u1 >= g / G and u1 total >= (g / G) total after
    rounding): a few steps within a cache line or two instead of ~20 over a
    supersampled map's 4 MB (docs/integrators.md "The map's guide table,
    round 28")."""
    N = cdf.shape[0]
    G = max(1, (1 << max(int(N - 1).bit_length(), 0)) >> 2)
    return np.searchsorted(cdf, (np.arange(G + 1) / G) * total, side="right").astype(np.int64)


@njit(cache=True, nogil=True, inline="always")
def guided_region(E, u1, x):
    """np.searchsorted(E.cdf, x, side='right') for x = u1 E.total (u1 in
    [0, 1)), the search narrowed by the guide table."""
    G = E.guide.shape[0] - 1
    g = min(int(u1 * G), G - 1)
    lo, hi = E.guide[g], E.guide[g + 1]
    return lo + upper_bound(E.cdf[lo:hi], x)


def no_map() -> EnvironmentKernel:
    """The EnvironmentKernel of no map (total 0), of the same types as a
    float32 map's, for kernels whose lights have none (``DirectLights.env``)."""
    return EnvironmentKernel(cdf=np.zeros(1), weight=np.zeros(1), z_edges=np.array([-1.0, 1.0]),
                             A=np.eye(3), A_inv=np.eye(3), strength=np.zeros(3),
                             image=np.zeros((1, 1, 3), np.float32), W=1, det=1.0, total=0.0,
                             last=0, unassociate=False, guide=np.zeros(2, np.int64))


@njit(cache=True, inline="always")
def _mat3(M, x, y, z):
    """M (3, 3) @ (x, y, z)."""
    return (M[0, 0] * x + M[0, 1] * y + M[0, 2] * z, M[1, 0] * x + M[1, 1] * y + M[1, 2] * z,
            M[2, 0] * x + M[2, 1] * y + M[2, 2] * z)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def map_sample(E, u1, u2):
    """:meth:`EnvironmentLight.sample` for one pair of uniforms, with the
    density and the radiance of its direction: the region by u1 (its
    leftover the position in the region), the height by u2.  Returns
    (wx, wy, wz, pdf, r, g, b): the unit world direction w = A^-1 t / |A^-1 t|
    of the texture direction t drawn, its solid-angle density
    (:func:`region_density`) and the map's radiance (:func:`map_radiance`).
    Both read t itself, which the sample drew: its texture u is the
    region's (uu), its v 1 - arccos(t_z) / pi, and |A w| = 1 / |A^-1 t|,
    so neither takes :func:`texture_vector`'s second rotation or
    map_radiance's arctan2 (the same values to rounding).  The angle's
    sine and cosine are ``compiled.sincos_turn``'s (within 1 ulp)."""
    cdf, wt, ze = E.cdf, E.weight, E.z_edges
    N = cdf.shape[0]
    W = E.W
    x = u1 * E.total
    k = min(guided_region(E, u1, x), N - 1)
    wk = wt[k]
    if wk <= 0.0:
        k = E.last
        wk = wt[k]
    a = min(max((x - (cdf[k] - wk)) / wk, 0.0), 1.0 - 1e-12)
    i = k // W
    j = k - i * W
    uu = (j + a) / W
    z = ze[i] + u2 * (ze[i + 1] - ze[i])
    # phi = pi - 2 pi uu: cos phi = -cos(2 pi uu), sin phi = sin(2 pi uu)
    s2, c2 = sincos_turn(uu)
    sz = np.sqrt(max(1.0 - z * z, 0.0))
    wx, wy, wz = _mat3(E.A_inv, -sz * c2, sz * s2, z)
    n = max(np.sqrt(wx * wx + wy * wy + wz * wz), 1e-300)
    omega = (2.0 * np.pi / W) * (ze[i + 1] - ze[i])
    pdf = region_density(E, wk, omega, 1.0 / n)
    tv = 1.0 - np.arccos(min(max(z, -1.0), 1.0)) / np.pi
    l0, l1, l2 = bilinear_rgb(E.image, uu, tv, E.unassociate)
    return (wx / n, wy / n, wz / n, pdf, l0 * E.strength[0], l1 * E.strength[1],
            l2 * E.strength[2])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def texture_vector(E, wx, wy, wz):
    """A omega (A = the map's to_texture) of a unit world direction, and its
    norm: the norm gives the Jacobian d omega_c / d omega_w = det / |A omega|^3,
    the direction the map's texel (textures.environment_radiance)."""
    cx, cy, cz = _mat3(E.A, wx, wy, wz)
    return cx, cy, cz, np.sqrt(cx * cx + cy * cy + cz * cz)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def region_density(E, wk, omega, nt):
    """The solid-angle density of a direction in a region of weight wk and
    texture-space solid angle omega whose texture vector has norm nt:
    wk / omega / total times the Jacobian det / |A omega|^3
    (:meth:`EnvironmentLight.pdf`)."""
    return wk / omega / E.total * (E.det / max(nt, 1e-300) ** 3)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def map_radiance(E, cx, cy, cz, nt):
    """textures.environment_radiance along the texture vector (c, |c| = nt)
    of :func:`texture_vector`: the map's bilinear lookup times its strength."""
    if not nt > 0:
        nt = 1.0
    tx, ty, tz = cx / nt, cy / nt, cz / nt
    two_pi = 2.0 * np.pi
    tu = 0.5 - np.arctan2(ty, tx) / two_pi
    tv = 1.0 - np.arccos(min(max(tz, -1.0), 1.0)) / np.pi
    l0, l1, l2 = bilinear_rgb(E.image, tu, tv, E.unassociate)
    return l0 * E.strength[0], l1 * E.strength[1], l2 * E.strength[2]


@njit(cache=True, nogil=True, error_model="numpy")
def rays_radiance(E, d, rows, out):
    """out (k, 3) = textures.environment_radiance of the unit directions
    d[rows] (d (K, 3), rows (k,) int64): the camera paths' rays that escape
    to the map (PathTracer._trace, in the kernels' scope)."""
    for q in range(rows.shape[0]):
        r = rows[q]
        cx, cy, cz, nt = texture_vector(E, d[r, 0], d[r, 1], d[r, 2])
        out[q, 0], out[q, 1], out[q, 2] = map_radiance(E, cx, cy, cz, nt)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def map_pdf(E, cx, cy, cz, nt):
    """:meth:`EnvironmentLight.pdf` of the direction whose texture vector is
    (c, nt) (:func:`texture_vector`): the texel's region weight / its solid
    angle / total, times the Jacobian."""
    if not E.total > 0:
        return 0.0
    nn = max(nt, 1e-300)
    tx, ty, tz = cx / nn, cy / nn, cz / nn
    W = E.W
    ze = E.z_edges
    H = ze.shape[0] - 1
    tu = 0.5 - np.arctan2(ty, tx) / (2.0 * np.pi)
    j = int(np.floor(tu * W)) % W
    j = min(max(j, 0), W - 1)
    i = min(max(upper_bound(ze, tz) - 1, 0), H - 1)
    omega = (2.0 * np.pi / W) * (ze[i + 1] - ze[i])
    return region_density(E, E.weight[i * W + j], omega, nn)


class Footprint(NamedTuple):
    """Where world photons start (``emission.distant_footprint``): center (3,)
    and R the bounding sphere's; box_center, half_extent (3,) the
    triangles' box; boxed False: no triangles (the disc only)."""
    center: np.ndarray
    R: float
    box_center: np.ndarray
    half_extent: np.ndarray
    boxed: bool


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def footprint(F, dx, dy, dz, u1, u2):
    """``emission.distant_footprint`` of one photon of unit direction d:
    (origin x, y, z, area), the same choice and formulas (the rectangle of
    ``emission.box_rectangle``)."""
    R = F.R
    C = F.center
    disc = np.pi * R * R
    if F.boxed:
        e, c = F.half_extent, F.box_center
        best = np.inf
        t1x = t1y = t1z = t2x = t2y = t2z = h1 = h2 = n2 = 0.0
        for i in range(3):
            # the box axis a_i's projection v = a_i - (a_i . d) d and d x v,
            # both of length |v| (compared unnormalised: area ha hb / |v|^2)
            di = dx if i == 0 else (dy if i == 1 else dz)
            vx, vy, vz = -di * dx, -di * dy, -di * dz
            if i == 0:
                vx += 1.0
            elif i == 1:
                vy += 1.0
            else:
                vz += 1.0
            m2 = vx * vx + vy * vy + vz * vz
            if not m2 > 1e-18:
                continue
            # np.cross(d, v)
            bx, by, bz = dy * vz - dz * vy, dz * vx - dx * vz, dx * vy - dy * vx
            ha = abs(vx) * e[0] + abs(vy) * e[1] + abs(vz) * e[2]
            hb = abs(bx) * e[0] + abs(by) * e[1] + abs(bz) * e[2]
            if ha * hb / m2 < best:
                best = ha * hb / m2
                t1x, t1y, t1z, t2x, t2y, t2z, h1, h2, n2 = vx, vy, vz, bx, by, bz, ha, hb, m2
        n = np.sqrt(n2)
        t1x, t1y, t1z, t2x, t2y, t2z = t1x / n, t1y / n, t1z / n, t2x / n, t2y / n, t2z / n
        h1, h2 = h1 / n, h2 / n
        rect = 4.0 * h1 * h2
        if rect < disc:
            back = (c[0] - C[0]) * dx + (c[1] - C[1]) * dy + (c[2] - C[2]) * dz + R
            a, b = (2.0 * u1 - 1.0) * h1, (2.0 * u2 - 1.0) * h2
            return (c[0] - back * dx + a * t1x + b * t2x, c[1] - back * dy + a * t1y + b * t2y,
                    c[2] - back * dz + a * t1z + b * t2z, rect)
    rr = np.sqrt(u1)
    ph = 2.0 * np.pi * u2
    ux, uy = rr * np.cos(ph), rr * np.sin(ph)
    # x t1 + y t2 (mathutil.frame of d); the basis' third term is 0 d.
    qx, qy, qz = basis_world(ux, uy, 0.0, dx, dy, dz)
    return C[0] - R * dx + R * qx, C[1] - R * dy + R * qy, C[2] - R * dz + R * qz, disc


@njit(cache=True, nogil=True, error_model="numpy")
def constant_world_photons(u, rows, F, flux, inv_p, o, d, power):
    """The photons rows (k,) of a batch whose emitter is a constant world
    (``emission.sample_photons``): a uniform direction on the sphere from
    u[:, 3], u[:, 4] (``warps._uniform_sphere``), origin and area A by
    :func:`footprint` from u[:, 1], u[:, 2], power flux inv_p A / (pi R^2)
    (the photon's share of the area it crossed; flux (3,) counts the disc)."""
    disc = np.pi * F.R * F.R
    for q in range(rows.shape[0]):
        r = rows[q]
        z = 1.0 - 2.0 * u[r, 3]
        s = np.sqrt(max(1.0 - z * z, 0.0))
        ph = 2.0 * np.pi * u[r, 4]
        dx, dy, dz = s * np.cos(ph), s * np.sin(ph), z
        ox, oy, oz, area = footprint(F, dx, dy, dz, u[r, 1], u[r, 2])
        k = inv_p[q] * area / disc
        power[r, 0], power[r, 1], power[r, 2] = flux[0] * k, flux[1] * k, flux[2] * k
        o[r, 0], o[r, 1], o[r, 2] = ox, oy, oz
        d[r, 0], d[r, 1], d[r, 2] = dx, dy, dz


@njit(cache=True, nogil=True, error_model="numpy")
def world_photons(E, u, rows, F, inv_p, o, d, power):
    """The photons rows (k,) of a batch whose emitter is the world's map
    (``emission.sample_photons``): region by u[:, 3] (its leftover the
    position in the region), height by u[:, 4] (:meth:`EnvironmentLight.sample`),
    the direction d = -omega, origin and area A by :func:`footprint` (the
    Footprint F) from u[:, 1], u[:, 2], power A L(omega) / pdf(omega) inv_p
    (0 where pdf = 0).  The numpy code's operations per photon; its
    matrix products and norms are BLAS's and its arctan2 numpy's, so the
    values agree to rounding (tests/test_environment.py)."""
    for q in range(rows.shape[0]):
        r = rows[q]
        wx, wy, wz, pdf, l0, l1, l2 = map_sample(E, u[r, 3], u[r, 4])
        dx, dy, dz = -wx, -wy, -wz
        ox, oy, oz, area = footprint(F, dx, dy, dz, u[r, 1], u[r, 2])
        s = area / max(pdf, 1e-300)
        ip = inv_p[q]
        if pdf > 0:
            power[r, 0] = l0 * s * ip
            power[r, 1] = l1 * s * ip
            power[r, 2] = l2 * s * ip
        else:
            power[r, 0] = power[r, 1] = power[r, 2] = 0.0
        o[r, 0], o[r, 1], o[r, 2] = ox, oy, oz
        d[r, 0], d[r, 1], d[r, 2] = dx, dy, dz
