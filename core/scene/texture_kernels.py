"""Compiled texture lookups: the numba twins of core.scene.textures' numpy
functions, for the kernels that read a texture per ray or photon (an
environment map's photons, core.lights.environment_kernels; the camera
paths' textured hits, core.integrators.path_kernels).  A module of their
own, so that the add-on's register() (which imports the numpy module) loads
no numba.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit


class TextureList(NamedTuple):
    """A scene's textures for kernels that read any of them, without a copy:
    images a ``numba.typed.List`` of the (H, W, C) images
    (``textures._as_image``'s views; float32 as Blender's, or every one
    float64 when any is not float32: no texel rounded), unassociate (T,)
    bool (an ``UnassociatedImage``), sampler (T,) int64 each one's
    ``textures.sampler_code``."""
    images: object
    unassociate: np.ndarray
    sampler: np.ndarray


def texture_list(textures) -> TextureList:
    """The :class:`TextureList` of a list of images (``Scene.textures``)."""
    from numba.typed import List

    from .textures import UnassociatedImage, _as_image, sampler_of
    imgs = [_as_image(t) for t in textures]
    dt = np.float32 if all(i.dtype == np.float32 for i in imgs) else np.float64
    imgs = [np.ascontiguousarray(i, dt) for i in imgs] or [np.zeros((1, 1, 3), dt)]
    return TextureList(List(imgs), np.array([isinstance(t, UnassociatedImage)
                                             for t in textures] or [False]),
                       np.array([sampler_of(t) for t in textures] or [0], np.int64))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def corner_uv(tri_uv, t, w0, u, v):
    """``accel.hit_uv`` of one hit: the uv of triangle t (tri_uv (T, 3, 2),
    any float dtype) at barycentrics (w0, u, v), in float64, its products
    and sums in numpy's order."""
    uu = w0 * np.float64(tri_uv[t, 0, 0]) + u * np.float64(tri_uv[t, 1, 0]) + v * np.float64(
        tri_uv[t, 2, 0])
    vv = w0 * np.float64(tri_uv[t, 0, 1]) + u * np.float64(tri_uv[t, 1, 1]) + v * np.float64(
        tri_uv[t, 2, 1])
    return uu, vv


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def bilinear_rgb(img, u, v, unassociate, sampler=0):
    """:func:`sample_texture` of one uv: (r, g, b) float64 of img (H, W, C)
    (C = 1: grey; unassociate with C >= 4: rgb / alpha where alpha > 0, else
    0), bilinear with repeat wrapping around texel centres (Cycles'
    interp_linear), or as ``sampler`` says (``textures.sampler_code``:
    Closest, Cubic; Extend, Clip, Mirror), 0 for a non-finite uv; the numpy
    expressions' operations in their order (``textures._taps``)."""
    if sampler == 0:
        return _linear_repeat(img, u, v, unassociate)
    return _sampled_rgb(img, u, v, unassociate, sampler)


# Not inlined: the other samplers' taps are compiled once, not into every
# kernel that reads a texture (inlined, they made the suite's kernels take
# 23 % longer to compile: docs/shading.md "Interpolation and extension").
@njit(cache=True, nogil=True, error_model="numpy")
def _sampled_rgb(img, u, v, unassociate, sampler):
    """:func:`bilinear_rgb` of a sampler other than Linear / Repeat."""
    H, W, C = img.shape
    interp = sampler & 3
    ext = sampler >> 2
    fx, fy, tx, ty = _cell(img, u, v, 0.0 if interp == 1 else 0.5)
    if not (np.isfinite(tx) and np.isfinite(ty)):
        return 0.0, 0.0, 0.0
    n = 4 if interp == 2 else 2
    ix = int(fx) - (1 if interp == 2 else 0)
    iy = int(fy) - (1 if interp == 2 else 0)
    wx = _weights(tx, interp)
    wy = _weights(ty, interp)
    r = _blend(img, iy, ix, n, ext, 0, wx, wy)
    if C < 3:
        return r, r, r
    rgb = (r, _blend(img, iy, ix, n, ext, 1, wx, wy), _blend(img, iy, ix, n, ext, 2, wx, wy))
    if unassociate and C >= 4:
        return _unassociated(rgb, _blend(img, iy, ix, n, ext, 3, wx, wy))
    return rgb


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _linear_repeat(img, u, v, unassociate):
    """:func:`bilinear_rgb` of the default sampler (Linear, Repeat): four
    wrapped texels, no bounds tests (the general taps cost 2.8x as much on
    a 1024^2 image: docs/shading.md "Interpolation and extension")."""
    H, W, C = img.shape
    fx, fy, tx, ty = _cell(img, u, v, 0.5)
    if not (np.isfinite(tx) and np.isfinite(ty)):
        return 0.0, 0.0, 0.0
    ix = int(fx) % W
    iy = int(fy) % H
    nix = (ix + 1) % W
    niy = (iy + 1) % H
    r = _corners(img, iy, ix, niy, nix, 0, tx, ty)
    if C < 3:
        return r, r, r
    rgb = (r, _corners(img, iy, ix, niy, nix, 1, tx, ty),
           _corners(img, iy, ix, niy, nix, 2, tx, ty))
    if unassociate and C >= 4:
        return _unassociated(rgb, _corners(img, iy, ix, niy, nix, 3, tx, ty))
    return rgb


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cell(img, u, v, half):
    """The texel cell of uv in img: floor and fraction of u W - half, v H -
    half (half 0.5: texel centres at integer + 0.5; 0 for Closest)."""
    x = u * img.shape[1] - half
    y = v * img.shape[0] - half
    fx = np.floor(x)
    fy = np.floor(y)
    return fx, fy, x - fx, y - fy


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _unassociated(rgb, al):
    """An associated colour divided by its interpolated alpha, 0 where that is 0."""
    if al > 0:
        return rgb[0] / al, rgb[1] / al, rgb[2] / al
    return 0.0, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _corners(img, iy, ix, niy, nix, ch, tx, ty):
    """Channel ch of the bilinear blend of four texels (``textures._taps``' order)."""
    a = np.float64(img[iy, ix, ch])
    b = np.float64(img[iy, nix, ch])
    c = np.float64(img[niy, ix, ch])
    d = np.float64(img[niy, nix, ch])
    return (1.0 - ty) * ((1.0 - tx) * a + tx * b) + ty * ((1.0 - tx) * c + tx * d)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _weights(t, interp):
    """textures._axis's weights of one fraction (unused taps 0)."""
    if interp == 1:
        return 1.0, 0.0 * t, 0.0, 0.0
    if interp == 2:
        return (((((-1.0 / 6.0) * t + 0.5) * t - 0.5) * t + (1.0 / 6.0)),
                ((0.5 * t - 1.0) * t) * t + (2.0 / 3.0),
                ((-0.5 * t + 0.5) * t + 0.5) * t + (1.0 / 6.0),
                (1.0 / 6.0) * t * t * t)
    return 1.0 - t, t, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _wrap(i, n, ext):
    """textures._wrap of one index: repeat (0), extend (1), mirror (3); clip
    (2) unchanged (read as 0 outside by :func:`_texel`)."""
    if ext == 0:
        return i % n
    if ext == 1:
        return min(max(i, 0), n - 1)
    if ext == 3:
        m = abs(i + (1 if i < 0 else 0)) % (2 * n)
        return 2 * n - m - 1 if m >= n else m
    return i


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _texel(img, iy, ix, ch):
    """A texel's channel in float64, 0 outside the image (CLIP's indices)."""
    H, W = img.shape[0], img.shape[1]
    if iy < 0 or iy >= H or ix < 0 or ix >= W:
        return 0.0
    return np.float64(img[iy, ix, ch])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _blend(img, iy, ix, n, ext, ch, wx, wy):
    """Channel ch of the n x n taps from texel (iy, ix) on, weights wx, wy:
    sum_a wy[a] (sum_b wx[b] t[a, b]) in tap order (``textures._taps``)."""
    H, W = img.shape[0], img.shape[1]
    out = 0.0
    for a in range(n):
        yy = _wrap(iy + a, H, ext)
        inner = 0.0
        for b in range(n):
            term = wx[b] * _texel(img, yy, _wrap(ix + b, W, ext), ch)
            inner = term if b == 0 else inner + term
        out = wy[a] * inner if a == 0 else out + wy[a] * inner
    return out
