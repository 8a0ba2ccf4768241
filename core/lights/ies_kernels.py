"""The IES profile's lookup in compiled code (:mod:`.ies` for the layout
and Cycles' conventions): one function every emitter site calls."""
from __future__ import annotations

import numpy as np
from numba import njit

from .ies import HEAD as _HEAD


@njit(cache=True, inline="always", error_model="numpy")
def _catmull(a, b, c, d, x):
    """Cycles' cubic_interp (Catmull-Rom) between b and c."""
    return 0.5 * (((d + 3.0 * (b - c) - a) * x + (2.0 * a - 5.0 * b + 4.0 * c - d)) * x
                  + (c - a)) * x + b


@njit(cache=True, error_model="numpy")
def _along_v(ies, vals, V, wrap_lo, wrap_hi, vi, vf, hi):
    """The column hi read at v between rows vi and vi + 1 (Cycles:
    the far points across the pole taken at the same h)."""
    base = vals + hi * V
    b = ies[base + vi]
    c = ies[base + vi + 1]
    a = b
    if vi > 0:
        a = ies[base + vi - 1]
    elif wrap_lo:
        a = ies[base + 1]
    d = c
    if vi + 2 < V:
        d = ies[base + vi + 2]
    elif wrap_hi:
        d = ies[base + V - 2]
    return _catmull(a, b, c, d, vf)


@njit(cache=True, error_model="numpy")
def ies_factor(ies, j, wx, wy, wz):
    """The IES factor of light row j along the world direction (wx, wy, wz)
    leaving it (any length): 1 when the table or the light has no profile.
    ies: the packed array of ``ies.pack`` (``LightTable.ies``)."""
    if ies.shape[0] == 0:
        return 1.0
    o = int(ies[j])
    if o < 0:
        return 1.0
    x = ies[o] * wx + ies[o + 1] * wy + ies[o + 2] * wz
    y = ies[o + 3] * wx + ies[o + 4] * wy + ies[o + 5] * wz
    z = ies[o + 6] * wx + ies[o + 7] * wy + ies[o + 8] * wz
    n = np.sqrt(x * x + y * y + z * z)
    if not n > 0.0:
        return 0.0
    va = np.arccos(min(max(-z / n, -1.0), 1.0))
    ha = np.arctan2(x, y) + np.pi
    H = int(ies[o + 9])
    V = int(ies[o + 10])
    ho = o + _HEAD
    vo = ho + H
    vals = vo + V
    v_lo, v_hi = ies[vo], ies[vo + V - 1]
    h_lo, h_hi = ies[ho], ies[ho + H - 1]
    if va < v_lo or va >= v_hi or ha < h_lo or ha >= h_hi:
        return 0.0
    wrap_h = h_lo < 1e-7 and h_hi > 2.0 * np.pi - 1e-7
    wrap_lo = v_lo < 1e-7
    wrap_hi = v_hi > np.pi - 1e-7
    hi = 0
    while ies[ho + hi + 1] < ha:
        hi += 1
    vi = 0
    while ies[vo + vi + 1] < va:
        vi += 1
    hf = (ha - ies[ho + hi]) / (ies[ho + hi + 1] - ies[ho + hi])
    vf = (va - ies[vo + vi]) / (ies[vo + vi + 1] - ies[vo + vi])
    b = _along_v(ies, vals, V, wrap_lo, wrap_hi, vi, vf, hi)
    c = _along_v(ies, vals, V, wrap_lo, wrap_hi, vi, vf, hi + 1)
    a = b
    if hi > 0:
        a = _along_v(ies, vals, V, wrap_lo, wrap_hi, vi, vf, hi - 1)
    elif wrap_h:
        # The 360 entry repeats the 0 one: wrap to the one before it.
        a = _along_v(ies, vals, V, wrap_lo, wrap_hi, vi, vf, H - 2)
    d = b          # Cycles falls back to b (not c) at the h table's end
    if hi + 2 < H:
        d = _along_v(ies, vals, V, wrap_lo, wrap_hi, vi, vf, hi + 2)
    elif wrap_h:
        # column 1 as int64, not a literal: _along_v's one signature
        d = _along_v(ies, vals, V, wrap_lo, wrap_hi, vi, vf, np.int64(1))
    return max(_catmull(a, b, c, d, hf), 0.0)


@njit(cache=True, error_model="numpy")
def ies_factors(ies, j, w):
    """(K,) float64 :func:`ies_factor` of rows j (K,) int64 along w (K, 3)."""
    out = np.ones(j.shape[0])
    if ies.shape[0] == 0:
        return out
    for k in range(j.shape[0]):
        out[k] = ies_factor(ies, j[k], w[k, 0], w[k, 1], w[k, 2])
    return out
