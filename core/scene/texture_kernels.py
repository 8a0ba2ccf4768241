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


class PackedTextures(NamedTuple):
    """A scene's textures in one buffer, for kernels that read any of them:
    data (N,) the images' texels one after another (C order), float32 when
    every image is (Blender's), else float64 (no texel rounded); meta (T, 5)
    int64 per texture: offset into data, H, W, C (``textures._as_image``'s
    shape) and 1 for an ``UnassociatedImage``."""
    data: np.ndarray
    meta: np.ndarray


def pack_textures(textures) -> PackedTextures:
    """The :class:`PackedTextures` of a list of images (``Scene.textures``)."""
    from .textures import UnassociatedImage, _as_image
    imgs = [_as_image(t) for t in textures]
    dt = np.float32 if all(i.dtype == np.float32 for i in imgs) else np.float64
    meta = np.zeros((max(len(imgs), 1), 5), np.int64)
    o = 0
    for i, (t, im) in enumerate(zip(textures, imgs)):
        meta[i] = (o, im.shape[0], im.shape[1], im.shape[2], isinstance(t, UnassociatedImage))
        o += im.size
    data = np.concatenate([np.ascontiguousarray(im, dt).ravel() for im in imgs]) if imgs \
        else np.zeros(1, dt)
    return PackedTextures(data, meta)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def packed_rgb(T, t, u, v):
    """:func:`bilinear_rgb` of texture t of the :class:`PackedTextures` T at (u, v)."""
    o, H, W, C = T.meta[t, 0], T.meta[t, 1], T.meta[t, 2], T.meta[t, 3]
    return bilinear_rgb(T.data[o:o + H * W * C].reshape((H, W, C)), u, v, T.meta[t, 4] != 0)


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
