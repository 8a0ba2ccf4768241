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
    bool (an ``UnassociatedImage``)."""
    images: object
    unassociate: np.ndarray


def texture_list(textures) -> TextureList:
    """The :class:`TextureList` of a list of images (``Scene.textures``)."""
    from numba.typed import List

    from .textures import UnassociatedImage, _as_image
    imgs = [_as_image(t) for t in textures]
    dt = np.float32 if all(i.dtype == np.float32 for i in imgs) else np.float64
    imgs = [np.ascontiguousarray(i, dt) for i in imgs] or [np.zeros((1, 1, 3), dt)]
    return TextureList(List(imgs), np.array([isinstance(t, UnassociatedImage)
                                             for t in textures] or [False]))


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
def bilinear_rgb(img, u, v, unassociate):
    """:func:`sample_texture` of one uv: (r, g, b) float64 of img (H, W, C)
    (C = 1: grey; unassociate with C >= 4: rgb / alpha where alpha > 0, else
    0), bilinear with repeat wrapping around texel centres (Cycles'
    interp_linear), 0 for a non-finite uv; the numpy expressions' operations
    in their order."""
    H, W, C = img.shape
    x = u * W - 0.5
    y = v * H - 0.5
    fx = np.floor(x)
    fy = np.floor(y)
    tx = x - fx
    ty = y - fy
    if not (np.isfinite(tx) and np.isfinite(ty)):
        return 0.0, 0.0, 0.0
    ix = int(fx) % W
    iy = int(fy) % H
    nix = (ix + 1) % W
    niy = (iy + 1) % H
    grey = C < 3
    r = _blend(img, iy, ix, niy, nix, 0, tx, ty)
    g = r if grey else _blend(img, iy, ix, niy, nix, 1, tx, ty)
    b = r if grey else _blend(img, iy, ix, niy, nix, 2, tx, ty)
    if unassociate and C >= 4:
        al = _blend(img, iy, ix, niy, nix, 3, tx, ty)
        if al > 0:
            return r / al, g / al, b / al
        return 0.0, 0.0, 0.0
    return r, g, b


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _blend(img, iy, ix, niy, nix, ch, tx, ty):
    """Channel ch of the bilinear blend of the four texels (sample_texture's order)."""
    a = np.float64(img[iy, ix, ch])
    b = np.float64(img[iy, nix, ch])
    c = np.float64(img[niy, ix, ch])
    d = np.float64(img[niy, nix, ch])
    return (1.0 - ty) * ((1.0 - tx) * a + tx * b) + ty * ((1.0 - tx) * c + tx * d)
