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
