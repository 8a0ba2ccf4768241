"""A pixel's stratified numbers across passes: shuffled, scrambled 2-D Sobol' (numba).

The camera paths' first dimensions (film filter, lens, the first vertex's
light sample) are taken per pixel from one low-discrepancy sequence that runs
over all of the pixel's samples, pass after pass: sample k of pixel b (k =
pass x camera_samples + s) is point k of a 2-D Sobol' (0, 2)-sequence for
each pair of dimensions, so any 2^m consecutive samples starting at a
multiple of 2^m form a (0, m, 2)-net of that pair.  Cycles samples a pixel
the same way (its Sobol-Burley / tabulated Sobol patterns); until round 27
each pass stratified only its own few samples, and
``example_blends/real_scene.blend``'s sunlit floor had 2.4x the error of
one 64-sample pass after sixteen passes of 4 (docs/integrators.md "A
pixel's samples across passes, round 27").

Burley 2020, "Practical Hash-based Owen Scrambling" (JCGT 9(4)): the index
is shuffled by a nested uniform scramble (so that pairs of dimensions, each
with a scramble seed of its own, are not correlated through the index),
then each coordinate is Owen-scrambled by the same hash-based permutation
(Laine and Karras 2011, with Burley's constants).  Seeds come from a hash
of (render seed, pixel, pair): the same pixel gets the same sequence in
every pass, and two pixels independent ones.  Every point is uniform on
[0, 1)^2 on its own (an Owen-scrambled sequence), so estimates stay
unbiased.  32-bit integers are held in int64 with explicit masks (numba
turns a uint64 mixed with an int64 into a float; the low 32 bits of a
wrapped int64 product are the uint32 product's).
"""
from __future__ import annotations

import numpy as np
from numba import njit

_M32 = 0xFFFFFFFF
_INV32 = 1.0 / 4294967296.0


@njit(cache=True, inline="always")
def _hash32(x):
    """Wellons' lowbias32 integer hash of a 32-bit value."""
    x &= _M32
    x ^= x >> 16
    x = (x * 0x7FEB352D) & _M32
    x ^= x >> 15
    x = (x * 0x846CA68B) & _M32
    x ^= x >> 16
    return x


@njit(cache=True, inline="always")
def _combine(a, b):
    """A hash of the pair (a, b) (boost's hash_combine, then _hash32)."""
    return _hash32(a ^ ((b + 0x9E3779B9 + ((a << 6) & _M32) + (a >> 2)) & _M32))


@njit(cache=True, inline="always")
def _reverse32(x):
    x = ((x >> 1) & 0x55555555) | ((x & 0x55555555) << 1)
    x = ((x >> 2) & 0x33333333) | ((x & 0x33333333) << 2)
    x = ((x >> 4) & 0x0F0F0F0F) | ((x & 0x0F0F0F0F) << 4)
    x = ((x >> 8) & 0x00FF00FF) | ((x & 0x00FF00FF) << 8)
    return ((x >> 16) | (x << 16)) & _M32


@njit(cache=True, inline="always")
def _laine_karras(x, seed):
    """Burley 2020's Laine-Karras permutation: bit i of the result depends
    on bits 0..i of x only (an Owen scramble of the reversed bits)."""
    x = (x + seed) & _M32
    x ^= (x * 0x6C50B47C) & _M32
    x ^= (x * 0xB82F1E52) & _M32
    x ^= (x * 0xC7AFE638) & _M32
    x ^= (x * 0x8D22F6E6) & _M32
    return x


@njit(cache=True, inline="always")
def _owen(x, seed):
    """Nested uniform (Owen) scramble of the 32-bit fraction x."""
    return _reverse32(_laine_karras(_reverse32(x), seed))


def _sobol1_table() -> np.ndarray:
    """(4, 256) int64: entry (b, c) the XOR of the bit-reversed direction
    numbers of Sobol' dimension 1 (x + 1: v ^= v >> 1 from 2^31, reversed:
    r ^= r << 1 from 1) over the set bits j of c, for index bits 8 b + j."""
    rv = [1]
    for _ in range(31):
        rv.append((rv[-1] ^ (rv[-1] << 1)) & _M32)
    T = np.zeros((4, 256), np.int64)
    for b in range(4):
        for c in range(256):
            for j in range(8):
                if c >> j & 1:
                    T[b, c] ^= rv[8 * b + j]
    return T


_SOBOL1_REV = _sobol1_table()


@njit(cache=True, inline="always")
def _sobol1_reversed(i):
    """Sobol' dimension 1 of the 32-bit index i, its bits reversed: four
    table reads (the bit loop took up to 32 steps, the index being
    scrambled)."""
    T = _SOBOL1_REV
    return T[0, i & 255] ^ T[1, (i >> 8) & 255] ^ T[2, (i >> 16) & 255] ^ T[3, (i >> 24) & 255]


@njit(cache=True, nogil=True)
def sobol_pairs(seed, pixels, first, n, pairs, out):
    """out (n, B, 2 pairs) float64 in [0, 1): samples first .. first + n - 1
    of the B pixels (ids pixels (B,) int64, stable across passes) for each
    pair of dimensions, the render seed's shuffled, scrambled Sobol' points
    (module doc)."""
    base = _hash32(seed & _M32)
    for b in range(pixels.shape[0]):
        pix = _combine(base, pixels[b] & _M32)
        for i in range(pairs):
            sd = _combine(pix, i)
            s_idx, s_x, s_y = _combine(sd, 0), _combine(sd, 1), _combine(sd, 2)
            for s in range(n):
                k = _owen((first + s) & _M32, s_idx)
                # _owen(x, seed) = reverse(LK(reverse(x))): the reversals of
                # x = reverse(k) and of Sobol' dimension 1 fall away.
                x = _reverse32(_laine_karras(k, s_x))
                y = _reverse32(_laine_karras(_sobol1_reversed(k), s_y))
                out[s, b, 2 * i] = x * _INV32
                out[s, b, 2 * i + 1] = y * _INV32
