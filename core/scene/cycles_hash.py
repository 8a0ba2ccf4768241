"""The integer hashes Cycles' procedural textures draw their randomness from,
vectorised over numpy arrays, so that a texture evaluated here picks the very
cells, gradients and colours Cycles picks.

Bob Jenkins' lookup3 ``final`` and ``mix`` on 32-bit unsigned words, seeded
``0xdeadbeef + (n << 2) + 13`` for n words, as Cycles' ``hash_uint``..
``hash_uint4``; a float is hashed through its bits (``__float_as_uint``), so
float inputs are rounded to float32 first, as Cycles holds them.  The
``*_to_float`` forms map the hash to [0, 1] (``uint_to_float_incl``: n /
(2^32 - 1) in float32).

Every function takes and returns arrays of one shape; integer inputs are
reduced to uint32 (two's complement for negative ints, as C's cast).
"""
from __future__ import annotations

import numpy as np

_U32 = np.uint32


def _u(x) -> np.ndarray:
    """An integer array as uint32, wrapping negatives as C's (uint) cast."""
    return np.asarray(x).astype(np.int64).astype(_U32)


def _rot(x: np.ndarray, k: int) -> np.ndarray:
    return (x << _U32(k)) | (x >> _U32(32 - k))


def _final(a, b, c):
    c ^= b; c -= _rot(b, 14)          # noqa: E702  (lookup3's final, line by line)
    a ^= c; a -= _rot(c, 11)          # noqa: E702
    b ^= a; b -= _rot(a, 25)          # noqa: E702
    c ^= b; c -= _rot(b, 16)          # noqa: E702
    a ^= c; a -= _rot(c, 4)           # noqa: E702
    b ^= a; b -= _rot(a, 14)          # noqa: E702
    c ^= b; c -= _rot(b, 24)          # noqa: E702
    return a, b, c


def _mix(a, b, c):
    a -= c; a ^= _rot(c, 4); c += b   # noqa: E702  (lookup3's mix)
    b -= a; b ^= _rot(a, 6); a += c   # noqa: E702
    c -= b; c ^= _rot(b, 8); b += a   # noqa: E702
    a -= c; a ^= _rot(c, 16); c += b  # noqa: E702
    b -= a; b ^= _rot(a, 19); a += c  # noqa: E702
    c -= b; c ^= _rot(b, 4); b += a   # noqa: E702
    return a, b, c


def _seed(n: int, shape) -> tuple:
    s = np.full(shape, (0xdeadbeef + (n << 2) + 13) & 0xFFFFFFFF, _U32)
    return s, s.copy(), s.copy()


def hash_uint(kx) -> np.ndarray:
    """lookup3 of one word (Cycles ``hash_uint``)."""
    kx = _u(kx)
    with np.errstate(over='ignore'):
        a, b, c = _seed(1, kx.shape)
        a += kx
        return _final(a, b, c)[2]


def hash_uint2(kx, ky) -> np.ndarray:
    """lookup3 of two words (Cycles ``hash_uint2``)."""
    kx, ky = np.broadcast_arrays(_u(kx), _u(ky))
    with np.errstate(over='ignore'):
        a, b, c = _seed(2, kx.shape)
        b += ky
        a += kx
        return _final(a, b, c)[2]


def hash_uint3(kx, ky, kz) -> np.ndarray:
    """lookup3 of three words (Cycles ``hash_uint3``)."""
    kx, ky, kz = np.broadcast_arrays(_u(kx), _u(ky), _u(kz))
    with np.errstate(over='ignore'):
        a, b, c = _seed(3, kx.shape)
        c += kz
        b += ky
        a += kx
        return _final(a, b, c)[2]


def hash_uint4(kx, ky, kz, kw) -> np.ndarray:
    """lookup3 of four words (Cycles ``hash_uint4``: a mix, then the fourth)."""
    kx, ky, kz, kw = np.broadcast_arrays(_u(kx), _u(ky), _u(kz), _u(kw))
    with np.errstate(over='ignore'):
        a, b, c = _seed(4, kx.shape)
        a += kx
        b += ky
        c += kz
        a, b, c = _mix(a, b, c)
        a += kw
        return _final(a, b, c)[2]


def hash_string(s: str) -> int:
    """Cycles' ``hash_string``: i = 37 i + c over the bytes of s (UTF-8),
    each a C ``char`` (signed: bytes from 0x80 sign-extended), mod 2^32."""
    i = 0
    for b in s.encode("utf-8"):
        i = (i * 37 + (b if b < 128 else b - 256)) & 0xFFFFFFFF
    return i


def to_float(h: np.ndarray) -> np.ndarray:
    """A hash in [0, 1] as Cycles' ``uint_to_float_incl`` (float32 product)."""
    return (h.astype(np.float32) * np.float32(1.0 / 4294967295.0)).astype(np.float64)


def float_bits(x) -> np.ndarray:
    """The bits of x rounded to float32 (``__float_as_uint``)."""
    return np.ascontiguousarray(np.asarray(x, np.float32)).view(_U32)


def hash_float_to_float(x) -> np.ndarray:
    return to_float(hash_uint(float_bits(x)))


def hash_float2_to_float(x, y) -> np.ndarray:
    return to_float(hash_uint2(float_bits(x), float_bits(y)))


def hash_float3_to_float(x, y, z) -> np.ndarray:
    return to_float(hash_uint3(float_bits(x), float_bits(y), float_bits(z)))


def hash_float4_to_float(x, y, z, w) -> np.ndarray:
    return to_float(hash_uint4(float_bits(x), float_bits(y), float_bits(z), float_bits(w)))


def hash_float_to_float3(x) -> np.ndarray:
    """(..., 3) Cycles' ``hash_float_to_float3``."""
    one, two = np.ones_like(x), np.full_like(x, 2.0)
    return np.stack([hash_float_to_float(x), hash_float2_to_float(x, one),
                     hash_float2_to_float(x, two)], -1)


def hash_float2_to_float3(x, y) -> np.ndarray:
    """(..., 3) Cycles' ``hash_float2_to_float3``."""
    one, two = np.ones_like(x), np.full_like(x, 2.0)
    return np.stack([hash_float2_to_float(x, y), hash_float3_to_float(x, y, one),
                     hash_float3_to_float(x, y, two)], -1)


def hash_float3_to_float3(x, y, z) -> np.ndarray:
    """(..., 3) Cycles' ``hash_float3_to_float3``."""
    one, two = np.ones_like(x), np.full_like(x, 2.0)
    return np.stack([hash_float3_to_float(x, y, z), hash_float4_to_float(x, y, z, one),
                     hash_float4_to_float(x, y, z, two)], -1)


def hash_float4_to_float3(x, y, z, w) -> np.ndarray:
    """(..., 3) Cycles' ``hash_float4_to_float3``."""
    return np.stack([hash_float4_to_float(x, y, z, w), hash_float4_to_float(z, x, w, y),
                     hash_float4_to_float(w, z, y, x)], -1)



# PCG hashes of integer lattice points (Jarzynski and Olano, "Hash Functions for
# GPU Rendering", JCGT 2020), as Cycles' ``hash_pcg{2,3,4}d_i``: signed 32-bit
# words that wrap, arithmetic shifts, the result's sign bit cleared.  Cycles'
# 2D-4D Voronoi hashes its integer cells with them (since Blender 5.0).

_I32 = np.int32
_PCG_MUL, _PCG_ADD = _I32(1664525), _I32(1013904223)


def _i32(*ks) -> list:
    """Integer arrays as int32 of one shape (C's wrapping cast)."""
    return [k.copy() for k in np.broadcast_arrays(
        *(np.asarray(k).astype(np.int64).astype(_I32) for k in ks))]


def hash_pcg2d_i(kx, ky) -> tuple:
    """(x, y) int32 in [0, 2^31) Cycles' ``hash_pcg2d_i`` of int words."""
    x, y = (v * _PCG_MUL + _PCG_ADD for v in _i32(kx, ky))
    x += y * _PCG_MUL
    y += x * _PCG_MUL
    x ^= x >> 16
    y ^= y >> 16
    x += y * _PCG_MUL
    y += x * _PCG_MUL
    return x & 0x7FFFFFFF, y & 0x7FFFFFFF


def hash_pcg3d_i(kx, ky, kz) -> tuple:
    """(x, y, z) int32 in [0, 2^31) Cycles' ``hash_pcg3d_i`` of int words."""
    x, y, z = (v * _PCG_MUL + _PCG_ADD for v in _i32(kx, ky, kz))
    for r in range(2):
        if r:
            x ^= x >> 16
            y ^= y >> 16
            z ^= z >> 16
        x += y * z
        y += z * x
        z += x * y
    return x & 0x7FFFFFFF, y & 0x7FFFFFFF, z & 0x7FFFFFFF


def hash_pcg4d_i(kx, ky, kz, kw) -> tuple:
    """(x, y, z, w) int32 in [0, 2^31) Cycles' ``hash_pcg4d_i`` of int words."""
    x, y, z, w = (v * _PCG_MUL + _PCG_ADD for v in _i32(kx, ky, kz, kw))
    for r in range(2):
        if r:
            x ^= x >> 16
            y ^= y >> 16
            z ^= z >> 16
            w ^= w >> 16
        x += y * w
        y += z * x
        z += x * y
        w += y * z
    return x & 0x7FFFFFFF, y & 0x7FFFFFFF, z & 0x7FFFFFFF, w & 0x7FFFFFFF


def _pcg_to_float(hs) -> np.ndarray:
    """(..., k) the PCG words in [0, 1]: float32(h) * (1 / 2^31), as Cycles'
    ``hash_int*_to_float*`` (``1.0f / (float)0x7FFFFFFFu`` is 2^-31)."""
    return np.stack([h.astype(np.float32) * np.float32(2.0 ** -31) for h in hs],
                    -1).astype(np.float64)


def hash_int2_to_float2(kx, ky) -> np.ndarray:
    """(..., 2) Cycles' ``hash_int2_to_float2``."""
    return _pcg_to_float(hash_pcg2d_i(kx, ky))


def hash_int3_to_float3(kx, ky, kz) -> np.ndarray:
    """(..., 3) Cycles' ``hash_int3_to_float3``."""
    return _pcg_to_float(hash_pcg3d_i(kx, ky, kz))


def hash_int4_to_float4(kx, ky, kz, kw) -> np.ndarray:
    """(..., 4) Cycles' ``hash_int4_to_float4``."""
    return _pcg_to_float(hash_pcg4d_i(kx, ky, kz, kw))


def hash_int2_to_float3(kx, ky) -> np.ndarray:
    """(..., 3) Cycles' ``hash_int2_to_float3``: the 3D hash of (x, y, 0)."""
    return hash_int3_to_float3(kx, ky, np.zeros_like(np.asarray(kx)))


def hash_int4_to_float3(kx, ky, kz, kw) -> np.ndarray:
    """(..., 3) Cycles' ``hash_int4_to_float3``: the 4D hash's first three."""
    return hash_int4_to_float4(kx, ky, kz, kw)[..., :3]
