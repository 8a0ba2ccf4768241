"""Compiled warps that the compiled emissions share (photon_kernels'
analytic lights, environment_kernels' map): the bisection of a cdf, the
Duff et al. 2017 basis, a spot's emission density (photon_kernels'
spots, path_kernels' MIS) and an area light's spread factor (the photons,
next-event estimation and the rays that hit the light).  A module of its own, so that importing
core.lights (the add-on's register() does) loads no numba.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always", error_model="numpy")
def spot_pdf_local(P, x0, X, h, cos_h, cz):
    """lights.emission.spot_pdf_local of one local direction (cosine cz to
    the axis) of a spot of cone cosine cos_h and tail (P, x0, X, h)
    (``LightTable.spot_tail``; P 0 for a hard spot)."""
    if cz >= cos_h:
        return (1.0 - P) / (2.0 * np.pi * (1.0 - cos_h))
    if not P > 0.0:
        return 0.0
    th = np.arccos(min(max(cz, -1.0), 1.0))
    x = th - h
    if not x <= X:
        return 0.0
    A = 1.0 - 1.0 / (1.0 + X / x0)
    t = P / (x0 * A * (1.0 + x / x0) ** 2) / (2.0 * np.pi * np.sin(th))
    return t if np.isfinite(t) else 0.0


@njit(cache=True, inline="always")
def upper_bound(a, x):
    """np.searchsorted(a, x, side='right') of one x in the sorted 1-D a: the
    first index whose value is > x (a.size if none), by bisection (numba's
    scalar searchsorted costs more than the search in the compiled loops)."""
    lo, hi = 0, a.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if a[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, inline="always")
def basis_world(lx, ly, lz, nx, ny, nz):
    """lights._to_world: local (lx, ly, lz) about unit n (Duff et al. 2017)."""
    s = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (s + nz)
    b = nx * ny * a
    tx, ty, tz = 1.0 + s * nx * nx * a, s * b, -s * nx
    bx, by, bz = b, s + ny * ny * a, -ny
    return (lx * tx + ly * bx + lz * nx, lx * ty + ly * by + lz * ny,
            lx * tz + ly * bz + lz * nz)


@njit(cache=True, inline="always", error_model="numpy")
def spread_atten(tan_s, norm, cos_l):
    """lights.table.spread_atten of one direction: an area light's spread
    factor at cosine cos_l to its normal (tan_s = inf: 180 deg, 1)."""
    if tan_s == np.inf:
        return 1.0
    if not cos_l > 0.0:
        return 0.0
    tan_a = np.sqrt(max(1.0 - cos_l * cos_l, 0.0)) / cos_l
    return max((tan_s - tan_a) * norm, 0.0)
