"""Image textures as Cycles samples them.

Cycles' Image Texture node defaults are *Linear* interpolation and *Repeat*
extension.  Its CPU kernel (``kernel/device/cpu/image.h``, ``interp_linear``)
maps uv to continuous pixel coordinates ``x = u * W``, ``y = v * H``, shifts by
half a pixel so that texel centres sit at integer + 0.5, and blends the four
neighbouring texels with periodic wrapping.  *Closest* reads the texel holding
(x, y) without the shift.  The other extensions read texel indices outside the
image clamped to the edge (*Extend*), reflected (*Mirror*) or as transparent
black (*Clip*).  An image read another way than Linear / Repeat carries its
:func:`sampler_code` (a :class:`SampledImage`), so that every lookup here reads
it as its node does.  Images are stored as Blender stores them: row 0 at the
BOTTOM, so ``v = 0`` is row 0 with no flip.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


# Interpolation and extension of an Image Texture node (Cycles' order;
# Smart is Cubic in Cycles' CPU kernel, interp's default branch).
LINEAR, CLOSEST, CUBIC = 0, 1, 2
REPEAT, EXTEND, CLIP, MIRROR = 0, 1, 2, 3
INTERPOLATIONS = {'Linear': LINEAR, 'Closest': CLOSEST, 'Cubic': CUBIC, 'Smart': CUBIC}
EXTENSIONS = {'REPEAT': REPEAT, 'EXTEND': EXTEND, 'CLIP': CLIP, 'MIRROR': MIRROR}


def sampler_code(interpolation: int = LINEAR, extension: int = REPEAT) -> int:
    """One int for an interpolation and an extension (0: Linear, Repeat)."""
    return int(interpolation) | (int(extension) << 2)


def _wrap(i, n, ext):
    """Texel indices i (int64 array) of an axis of n texels under extension
    ext (Cycles' wrap_periodic, wrap_clamp, wrap_mirror; CLIP: unchanged)."""
    if ext == REPEAT:
        return np.mod(i, n)
    if ext == EXTEND:
        return np.clip(i, 0, n - 1)
    if ext == MIRROR:
        m = np.mod(np.abs(i + (i < 0)), 2 * n)
        return np.where(m >= n, 2 * n - m - 1, m)
    return i


def _axis(t, interp):
    """(weights, their derivatives in t, first offset) of one axis's taps at
    fractions t (K,): Linear (1 - t, t) from the texel below, Closest (1, 0)
    from the texel holding the point, Cubic the uniform B-spline's four
    (Cycles' SET_CUBIC_SPLINE_WEIGHTS) from the texel before."""
    if interp == CLOSEST:
        one = np.ones_like(t)
        return (one, 0.0 * t), (0.0 * t, 0.0 * t), 0
    if interp == CUBIC:
        w = ((((-1.0 / 6.0) * t + 0.5) * t - 0.5) * t + (1.0 / 6.0),
             ((0.5 * t - 1.0) * t) * t + (2.0 / 3.0),
             ((-0.5 * t + 0.5) * t + 0.5) * t + (1.0 / 6.0),
             (1.0 / 6.0) * t * t * t)
        dw = ((-0.5 * t + 1.0) * t - 0.5, (1.5 * t - 2.0) * t, (-1.5 * t + 1.0) * t + 0.5,
              0.5 * t * t)
        return w, dw, -1
    return (1.0 - t, t), (-1.0 + 0.0 * t, 1.0 + 0.0 * t), 0


def _taps(img: np.ndarray, uv: np.ndarray, ch, sampler: int = 0, gradient=False):
    """The interpolant of channels ch of img at each uv (K, 2) as Cycles'
    interp_linear, interp_closest or interp_cubic reads it under the
    sampler's extension (repeat wrapping by default; CLIP: texels outside
    read as 0).  Returns (value (K, len(ch)) float64, bad (K,) non-finite
    uv) and with gradient (d/du, d/dv) of the value too (0 under Closest)."""
    H, W, _ = img.shape
    interp, ext = sampler & 3, sampler >> 2
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    # Half-texel shift: texel i covers [i, i+1) and its centre is i + 0.5;
    # Closest reads the texel holding the point.
    half = 0.0 if interp == CLOSEST else 0.5
    x = uv[:, 0] * W - half
    y = uv[:, 1] * H - half
    fx = np.floor(x)
    fy = np.floor(y)
    tx = x - fx
    ty = y - fy
    bad = ~np.isfinite(tx) | ~np.isfinite(ty)
    # Non-finite uv (degenerate meshes) would make the integer cast undefined.
    fx = np.where(np.isfinite(fx), fx, 0.0).astype(np.int64)
    fy = np.where(np.isfinite(fy), fy, 0.0).astype(np.int64)
    im = img[:, :, ch]
    (wx, dwx, o), (wy, dwy, _) = _axis(tx, interp), _axis(ty, interp)
    cols = [_wrap(fx + o + b, W, ext) for b in range(len(wx))]
    rows = [_wrap(fy + o + a, H, ext) for a in range(len(wy))]

    def rd(r, c):
        if ext != CLIP:
            return im[r, c].astype(np.float64)
        inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
        out = im[np.clip(r, 0, H - 1), np.clip(c, 0, W - 1)].astype(np.float64)
        return np.where(inside[:, None], out, 0.0)

    def blend(ax, ay):
        # sum_a ay[a] (sum_b ax[b] t[a, b]), each sum in tap order.
        out = None
        for a in range(len(ay)):
            inner = None
            for b in range(len(ax)):
                term = ax[b][:, None] * texels[a][b]
                inner = term if inner is None else inner + term
            out = ay[a][:, None] * inner if out is None else out + ay[a][:, None] * inner
        return out

    texels = [[rd(r, c) for c in cols] for r in rows]
    value = blend(wx, wy)
    if not gradient:
        return value, bad
    return value, bad, W * blend(dwx, wy), H * blend(wx, dwy)


class SampledImage(np.ndarray):
    """An image whose Image Texture node reads it with another interpolation
    or extension than Linear / Repeat: ``sampler`` (:func:`sampler_code`),
    kept through views and pickling.  Make one with :func:`with_sampler`."""
    sampler = 0

    def __array_finalize__(self, obj):
        self.sampler = int(getattr(obj, "sampler", 0))

    def __reduce__(self):
        r = super().__reduce__()
        return r[0], r[1], r[2] + (self.sampler,)

    def __setstate__(self, state):
        self.sampler = int(state[-1])
        super().__setstate__(state[:-1])


def sampler_of(img) -> int:
    """An image's :func:`sampler_code` (0 for a plain array)."""
    return int(getattr(img, "sampler", 0))


def with_sampler(img: np.ndarray, sampler: int) -> np.ndarray:
    """img read with ``sampler``: itself when 0 (Linear / Repeat) and plain,
    else a view (a :class:`SampledImage`, or its own class when it is one,
    ``UnassociatedImage``) carrying it."""
    if sampler == sampler_of(img):
        return img
    out = img.view(type(img) if isinstance(img, SampledImage) else SampledImage)
    out.sampler = int(sampler)
    return out


class UnassociatedImage(SampledImage):
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
    sampler = sampler_of(img)
    img = _as_image(img)
    ch = [0, 1, 2] if img.shape[2] >= 3 else [0, 0, 0]
    if unassociate and img.shape[2] >= 4:
        ch = [0, 1, 2, 3]
    out, bad = _taps(img, uv, ch, sampler)
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
    """(H2, W2, C) float32: img (H, W, C)'s interpolant (bilinear and
    repeat-wrapped, or as its sampler reads it, which the result keeps)
    read at the texel centres of an H2 x W2 grid over the same uv square
    (two images of one lookup brought to one grid, and :func:`upsample`)."""
    sampler = sampler_of(img)
    img = _as_image(img)
    C = img.shape[2]
    v, u = np.mgrid[0:H2, 0:W2]
    uv = np.stack([(u.ravel() + 0.5) / W2, (v.ravel() + 0.5) / H2], -1)
    out, _ = _taps(img, uv, list(range(C)), sampler)
    return with_sampler(out.reshape(H2, W2, C).astype(np.float32), sampler)


def sample_alpha(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(K,) float64 alpha of an Image Texture at uv (K, 2), bilinear like
    :func:`sample_texture`; 1 for images without an alpha channel (Cycles)."""
    sampler = sampler_of(img)
    img = _as_image(img)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if img.shape[2] < 4:
        return np.ones(uv.shape[0])
    out, bad = _taps(img, uv, [3], sampler)
    out = out[:, 0]
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
    """Value and exact uv-gradient of the interpolant of a scalar read of
    the image (see :func:`scalar_weights`).

    Returns h (K,), dh_du (K,), dh_dv (K,) float64.  The bilinear
    interpolant is piecewise bilinear (the cubic one a piecewise bicubic),
    so its derivative is what a finite difference much smaller than a texel
    measures (Cycles' Bump node with a pixel footprint below the texel
    size); 0 under Closest (a step)."""
    sampler = sampler_of(img)
    img = _as_image(img)
    w = scalar_weights(img, channel)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if channel == "ALPHA" and img.shape[2] < 4:
        one = np.ones(uv.shape[0])
        return one, 0.0 * one, 0.0 * one
    ch = list(range(img.shape[2]))
    h, bad, du, dv = _taps(img, uv, ch, sampler, gradient=True)
    h, du, dv = h @ w, du @ w, dv @ w
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
