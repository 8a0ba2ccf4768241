"""Image textures as Cycles samples them by default.

Cycles' Image Texture node defaults are *Linear* interpolation and *Repeat*
extension.  Its CPU kernel (``kernel/device/cpu/image.h``, ``interp_linear``)
maps uv to continuous pixel coordinates ``x = u * W``, ``y = v * H``, shifts by
half a pixel so that texel centres sit at integer + 0.5, and blends the four
neighbouring texels with periodic wrapping.  Images here are stored as Blender
stores them: row 0 at the BOTTOM, so ``v = 0`` is row 0 with no flip.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _bilinear_corners(img: np.ndarray, uv: np.ndarray, ch):
    """The four texels around each uv and the blend weights (Cycles' interp_linear).

    Returns (a, b, c, d, tx, ty, W, H, bad): texels (K, len(ch)) float64 at
    (row iy, col ix), (iy, ix+1), (iy+1, ix), (iy+1, ix+1) with repeat
    wrapping, tx, ty (K, 1) the fractions, and bad (K,) non-finite uv."""
    H, W, _ = img.shape
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
    im = img[:, :, ch]

    def rd(r, c):
        return im[r, c].astype(np.float64)

    bad = ~np.isfinite(tx[:, 0]) | ~np.isfinite(ty[:, 0])
    return rd(iy, ix), rd(iy, nix), rd(niy, ix), rd(niy, nix), tx, ty, W, H, bad


class UnassociatedImage(np.ndarray):
    """An image stored with associated alpha (rgb x a, a) whose colour reads
    unassociated: the interpolated rgb divided by the interpolated alpha
    (Cycles' Image Texture with its Alpha output linked,
    ``NODE_IMAGE_ALPHA_UNASSOCIATE``); 0 where that alpha is 0.  Make one
    with ``associated_pixels.view(UnassociatedImage)``."""


def _as_image(img) -> np.ndarray:
    img = np.asarray(img)
    return img[:, :, None] if img.ndim == 2 else img


def sample_texture(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear, repeat-wrapped texture lookup.

    img: (H, W, C) float array (C = 1, 3 or 4; alpha is ignored, one channel is
      replicated to grey), row 0 = bottom.
    uv: (K, 2) float array of texture coordinates.
    Returns (K, 3) float64 linear RGB.
    """
    unassociate = isinstance(img, UnassociatedImage)
    img = _as_image(img)
    ch = [0, 1, 2] if img.shape[2] >= 3 else [0, 0, 0]
    if unassociate and img.shape[2] >= 4:
        ch = [0, 1, 2, 3]
    a, b, c, d, tx, ty, _, _, bad = _bilinear_corners(img, uv, ch)
    out = (1.0 - ty) * ((1.0 - tx) * a + tx * b) + ty * ((1.0 - tx) * c + tx * d)
    if out.shape[1] == 4:
        al = out[:, 3:4]
        out = np.where(al > 0, out[:, :3] / np.where(al > 0, al, 1.0), 0.0)
    if bad.any():
        out[bad] = 0.0
    return out


def upsample(img: np.ndarray, k: int) -> np.ndarray:
    """(k H, k W, C) float32: the bilinear, repeat-wrapped interpolant of img
    (H, W, C) read at the centres of k x k sub-texels - an image whose own
    bilinear lookup follows the original's within a sub-texel, so that a
    nonlinear colour node applied to its texels approaches the node applied
    after the lookup (core.scene.color_ops)."""
    H, W = _as_image(img).shape[:2]
    return resample(img, k * H, k * W)


def resample(img: np.ndarray, H2: int, W2: int) -> np.ndarray:
    """(H2, W2, C) float32: img (H, W, C)'s bilinear, repeat-wrapped
    interpolant read at the texel centres of an H2 x W2 grid over the same
    uv square (two images of one lookup brought to one grid, and
    :func:`upsample`)."""
    img = _as_image(img)
    C = img.shape[2]
    v, u = np.mgrid[0:H2, 0:W2]
    uv = np.stack([(u.ravel() + 0.5) / W2, (v.ravel() + 0.5) / H2], -1)
    a, b, c, d, tx, ty, _, _, _ = _bilinear_corners(img, uv, list(range(C)))
    out = (1.0 - ty) * ((1.0 - tx) * a + tx * b) + ty * ((1.0 - tx) * c + tx * d)
    return out.reshape(H2, W2, C).astype(np.float32)


def sample_alpha(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(K,) float64 alpha of an Image Texture at uv (K, 2), bilinear like
    :func:`sample_texture`; 1 for images without an alpha channel (Cycles)."""
    img = _as_image(img)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if img.shape[2] < 4:
        return np.ones(uv.shape[0])
    a, b, c, d, tx, ty, _, _, bad = _bilinear_corners(img, uv, [3])
    out = ((1.0 - ty) * ((1.0 - tx) * a + tx * b) + ty * ((1.0 - tx) * c + tx * d))[:, 0]
    out[bad] = 1.0
    return out


def scalar_weights(img: np.ndarray, channel: str = "COLOR") -> np.ndarray:
    """Channel weights (C,) turning a texel into the float Cycles reads when an
    Image Texture output feeds a float socket: 'COLOR' -> Rec.709 luminance
    (``linear_rgb_to_gray``), 'ALPHA' -> the alpha channel (1 without one)."""
    from ..mathutil import LUM_B, LUM_G, LUM_R
    img = _as_image(img)
    C = img.shape[2]
    w = np.zeros(C)
    if channel == "ALPHA":
        if C >= 4:
            w[3] = 1.0
        return w
    if C >= 3:
        w[:3] = (LUM_R, LUM_G, LUM_B)
    else:
        w[0] = 1.0
    return w


def scalar_gradient(img: np.ndarray, uv: np.ndarray, channel: str = "COLOR"):
    """Value and exact uv-gradient of the bilinear interpolant of a scalar
    read of the image (see :func:`scalar_weights`).

    Returns h (K,), dh_du (K,), dh_dv (K,) float64.  The bilinear
    interpolant is piecewise bilinear, so its derivative is what a finite
    difference much smaller than a texel measures (Cycles' Bump node with a
    pixel footprint below the texel size)."""
    img = _as_image(img)
    w = scalar_weights(img, channel)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if channel == "ALPHA" and img.shape[2] < 4:
        one = np.ones(uv.shape[0])
        return one, 0.0 * one, 0.0 * one
    ch = list(range(img.shape[2]))
    a, b, c, d, tx, ty, W, H, bad = _bilinear_corners(img, uv, ch)
    a, b, c, d = a @ w, b @ w, c @ w, d @ w
    tx, ty = tx[:, 0], ty[:, 0]
    h = (1.0 - ty) * ((1.0 - tx) * a + tx * b) + ty * ((1.0 - tx) * c + tx * d)
    du = W * ((1.0 - ty) * (b - a) + ty * (d - c))
    dv = H * ((1.0 - tx) * (c - a) + tx * (d - b))
    for arr in (h, du, dv):
        arr[bad] = 0.0
    return h, du, dv


# ----------------------------------------------------------------------------
# World environment maps (Cycles' Environment Texture node, equirectangular).

@dataclass
class EnvironmentMap:
    """The world's Environment Texture as Cycles evaluates it.

    image: (H, W, C) float32 linear image, row 0 at the bottom (as
      :func:`sample_texture` reads it); looked up bilinearly with repeat in
      both u and v (Cycles' ``image_params``: extension REPEAT always).
    strength: (3,) float64 factor on the texture: the Background node's
      Strength (times a constant colour multiplier, if any).
    to_texture: (3, 3) float64 linear map from a world direction to the
      texture-space vector (Texture Coordinate Object / Mapping node), which
      Cycles normalises before :func:`equirectangular_uv`.  Identity: the
      world direction itself (Cycles' default vector is ``sd->P = ray_D``).
    name: the image's name (for summaries).
    """
    image: np.ndarray
    strength: np.ndarray = field(default_factory=lambda: np.ones(3))
    to_texture: np.ndarray = field(default_factory=lambda: np.eye(3))
    name: str = ""

    def digest_bytes(self) -> bytes:
        """Everything that changes the image, as bytes (for scene digests)."""
        return b"".join(np.ascontiguousarray(a).tobytes() for a in (
            np.asarray(self.image, np.float32), np.asarray(self.strength, np.float64),
            np.asarray(self.to_texture, np.float64)))


def equirectangular_uv(c: np.ndarray) -> np.ndarray:
    """(K, 3) unit texture-space directions -> (K, 2) uv, Cycles' convention.

    ``direction_to_equirectangular`` (kernel/camera/projection.h) with range
    (-2 pi, pi, -pi, pi): u = (atan2(y, x) - pi) / (-2 pi) = 1/2 - atan2(y, x) / (2 pi),
    v = (acos(z) - pi) / (-pi) = 1 - acos(z) / pi.  So +X is u = 1/2, +Y
    u = 1/4, the zenith +Z v = 1 (top row) and the nadir v = 0 (row 0).
    """
    c = np.asarray(c, np.float64).reshape(-1, 3)
    u = 0.5 - np.arctan2(c[:, 1], c[:, 0]) / (2.0 * np.pi)
    v = 1.0 - np.arccos(np.clip(c[:, 2], -1.0, 1.0)) / np.pi
    return np.stack([u, v], axis=1)


def equirectangular_direction(u: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Inverse of :func:`equirectangular_uv` given u (K,) and z = cos(theta) (K,):
    phi = pi - 2 pi u, direction (sin(theta) cos(phi), sin(theta) sin(phi), z)."""
    phi = np.pi - 2.0 * np.pi * np.asarray(u, np.float64)
    z = np.asarray(z, np.float64)
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def environment_radiance(env: EnvironmentMap, d: np.ndarray) -> np.ndarray:
    """(K, 3) float64 radiance of the world map seen along unit world directions d (K, 3)."""
    d = np.asarray(d, np.float64).reshape(-1, 3)
    c = d @ np.asarray(env.to_texture, np.float64).T
    n = np.linalg.norm(c, axis=1, keepdims=True)
    c = c / np.where(n > 0, n, 1.0)
    return sample_texture(env.image, equirectangular_uv(c)) * np.asarray(env.strength)[None, :]
