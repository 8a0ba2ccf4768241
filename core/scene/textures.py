"""Image textures as Cycles samples them by default.

Cycles' Image Texture node defaults are *Linear* interpolation and *Repeat*
extension.  Its CPU kernel (``kernel/device/cpu/image.h``, ``interp_linear``)
maps uv to continuous pixel coordinates ``x = u * W``, ``y = v * H``, shifts by
half a pixel so that texel centres sit at integer + 0.5, and blends the four
neighbouring texels with periodic wrapping.  Images here are stored as Blender
stores them: row 0 at the BOTTOM, so ``v = 0`` is row 0 with no flip.
"""
from __future__ import annotations

import numpy as np


def sample_texture(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear, repeat-wrapped texture lookup.

    img: (H, W, C) float array (C = 1, 3 or 4; alpha is ignored, one channel is
      replicated to grey), row 0 = bottom.
    uv: (K, 2) float array of texture coordinates.
    Returns (K, 3) float64 linear RGB.
    """
    img = np.asarray(img)
    if img.ndim == 2:
        img = img[:, :, None]
    H, W, C = img.shape
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    # Half-texel shift: texel i covers [i, i+1) and its centre is i + 0.5.
    x = uv[:, 0] * W - 0.5
    y = uv[:, 1] * H - 0.5
    fx = np.floor(x)
    fy = np.floor(y)
    tx = (x - fx)[:, None]
    ty = (y - fy)[:, None]
    # Non-finite uv (degenerate meshes) would make the integer cast undefined.
    fx = np.where(np.isfinite(fx), fx, 0.0)
    fy = np.where(np.isfinite(fy), fy, 0.0)
    ix = np.mod(fx.astype(np.int64), W)
    iy = np.mod(fy.astype(np.int64), H)
    nix = np.mod(ix + 1, W)
    niy = np.mod(iy + 1, H)
    ch = [0, 1, 2] if C >= 3 else [0, 0, 0]
    im = img[:, :, ch]

    def rd(r, c):
        return im[r, c].astype(np.float64)

    out = ((1.0 - ty) * ((1.0 - tx) * rd(iy, ix) + tx * rd(iy, nix))
           + ty * ((1.0 - tx) * rd(niy, ix) + tx * rd(niy, nix)))
    tx_bad = ~np.isfinite(tx[:, 0]) | ~np.isfinite(ty[:, 0])
    if tx_bad.any():
        out[tx_bad] = 0.0
    return out
