"""Cycles' colour nodes as functions of an image's texels (numpy).

A material whose colour input is an Image Texture passed through colour
nodes - Mix (Color), MixRGB, Hue/Saturation/Value, Brightness/Contrast,
Gamma, Invert, RGB Curves, Color Ramp - is exported as one image: the nodes applied to
its texels once (``addon/export.py`` ``_MaterialBuilder.color_chain``), so
that every integrator reads it like any texture.  Each function here is
the Cycles kernel's (``intern/cycles/kernel/svm``: ``mix.h``, ``hsv.h``,
``brightness.h``, ``gamma.h``, ``invert.h``, ``ramp.h``, ``curves.h``; ``util/color.h``
for the HSV conversions), on (..., 3) float arrays.  Cycles applies them
after the texture lookup; here they come before its bilinear
interpolation, which is the same for the affine ones (:func:`is_affine`)
and differs within a texel for the others, so for those the exporter first
enlarges a small image by bilinear interpolation (``textures.upsample``)
(docs/shading.md "Colour nodes on an image").

An op is a hashable tuple (name, parameters...); :func:`apply` runs a
sequence of them.
"""
from __future__ import annotations

import numpy as np


#: Cycles' ``RAMP_TABLE_SIZE``: Blender's sync evaluates a Color Ramp, RGB
#: Curves or Float Curve at RAMP_TABLE_SIZE + 1 positions i / RAMP_TABLE_SIZE
#: of its span, i = 0 .. RAMP_TABLE_SIZE (``colorramp_to_array``,
#: ``curvemapping_*_to_array``), and Cycles interpolates between them.
RAMP_TABLE_SIZE = 256


def table_positions() -> np.ndarray:
    """(RAMP_TABLE_SIZE + 1,) float64 where the sync evaluates a ramp or a
    curve, as fractions of its span: i / RAMP_TABLE_SIZE in float32."""
    return (np.arange(RAMP_TABLE_SIZE + 1, dtype=np.float32)
            / np.float32(RAMP_TABLE_SIZE)).astype(np.float64)

#: Mix blend types evaluated here: all of Blender's ``blend_type`` identifiers.
MIX_BLENDS = ("MIX", "ADD", "MULTIPLY", "SCREEN", "OVERLAY", "SUBTRACT", "DIVIDE",
              "DIFFERENCE", "EXCLUSION", "DARKEN", "LIGHTEN", "SOFT_LIGHT", "LINEAR_LIGHT",
              "DODGE", "BURN", "HUE", "SATURATION", "VALUE", "COLOR")


def _lerp(a, b, t):
    return (1.0 - t) * a + t * b


def mix(blend: str, t: float, c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """svm_mix of colours c1 (A), c2 (B) with factor t (already clamped
    when the node clamps it)."""
    tm = 1.0 - t
    if blend == "MIX":
        return _lerp(c1, c2, t)
    if blend == "ADD":
        return _lerp(c1, c1 + c2, t)
    if blend == "MULTIPLY":
        return _lerp(c1, c1 * c2, t)
    if blend == "SCREEN":
        return 1.0 - (tm + t * (1.0 - c2)) * (1.0 - c1)
    if blend == "OVERLAY":
        return np.where(c1 < 0.5, c1 * (tm + 2.0 * t * c2),
                        1.0 - (tm + 2.0 * t * (1.0 - c2)) * (1.0 - c1))
    if blend == "SUBTRACT":
        return _lerp(c1, c1 - c2, t)
    if blend == "DIVIDE":
        c1, c2 = np.broadcast_arrays(c1, c2)
        safe = np.where(c2 != 0.0, c2, 1.0)
        return np.where(c2 != 0.0, tm * c1 + t * c1 / safe, c1)
    if blend == "DIFFERENCE":
        return _lerp(c1, np.abs(c1 - c2), t)
    if blend == "EXCLUSION":
        return np.maximum(_lerp(c1, c1 + c2 - 2.0 * c1 * c2, t), 0.0)
    if blend == "DARKEN":
        return _lerp(c1, np.minimum(c1, c2), t)
    if blend == "LIGHTEN":
        return _lerp(c1, np.maximum(c1, c2), t)
    if blend == "SOFT_LIGHT":
        scr = 1.0 - (1.0 - c2) * (1.0 - c1)
        return tm * c1 + t * ((1.0 - c1) * c2 * c1 + c1 * scr)
    if blend == "LINEAR_LIGHT":
        return c1 + t * (2.0 * c2 - 1.0)
    c1, c2 = np.broadcast_arrays(np.asarray(c1, np.float64), np.asarray(c2, np.float64))
    if blend == "DODGE":
        # c1 / (1 - t c2) capped at 1 (1 where the divisor is not positive); 0 stays 0.
        d = 1.0 - t * c2
        q = np.minimum(c1 / np.where(d > 0.0, d, 1.0), 1.0)
        return np.where(c1 == 0.0, c1, np.where(d > 0.0, q, 1.0))
    if blend == "BURN":
        # 1 - (1 - c1) / (1 - t + t c2) in [0, 1] (0 where the divisor is not positive).
        d = tm + t * c2
        q = np.clip(1.0 - (1.0 - c1) / np.where(d > 0.0, d, 1.0), 0.0, 1.0)
        return np.where(d > 0.0, q, 0.0)
    hsv1, hsv2 = rgb_to_hsv(c1), rgb_to_hsv(c2)
    if blend == "VALUE":
        hsv1[..., 2] = _lerp(hsv1[..., 2], hsv2[..., 2], t)
        return hsv_to_rgb(hsv1)
    if blend == "SATURATION":
        # Only a coloured c1 takes the saturation (a grey one has no hue).
        grey = (hsv1[..., 1] == 0.0)[..., None]
        hsv1[..., 1] = _lerp(hsv1[..., 1], hsv2[..., 1], t)
        return np.where(grey, c1, hsv_to_rgb(hsv1))
    if blend in ("HUE", "COLOR"):
        # c2's hue (and for COLOR its saturation) where c2 has one, mixed by t.
        hsv1[..., 0] = hsv2[..., 0]
        if blend == "COLOR":
            hsv1[..., 1] = hsv2[..., 1]
        return np.where((hsv2[..., 1] == 0.0)[..., None], c1, _lerp(c1, hsv_to_rgb(hsv1), t))
    raise ValueError(f"blend type {blend!r} is not evaluated")


def rgb_to_hsv(c: np.ndarray) -> np.ndarray:
    """util/color.h rgb_to_hsv: h in [0, 1)."""
    r, g, b = c[..., 0], c[..., 1], c[..., 2]
    cmax = np.maximum(np.maximum(r, g), b)
    cmin = np.minimum(np.minimum(r, g), b)
    cdelta = cmax - cmin
    v = cmax
    s = np.where(cmax != 0.0, cdelta / np.where(cmax != 0.0, cmax, 1.0), 0.0)
    d = np.where(cdelta != 0.0, cdelta, 1.0)
    cr, cg, cb = (cmax - r) / d, (cmax - g) / d, (cmax - b) / d
    h = np.where(r == cmax, cb - cg, np.where(g == cmax, 2.0 + cr - cb, 4.0 + cg - cr)) / 6.0
    h = np.where(h < 0.0, h + 1.0, h)
    h = np.where(s != 0.0, h, 0.0)
    return np.stack([h, s, v], -1)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """util/color.h hsv_to_rgb."""
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    h = np.where(h == 1.0, 0.0, h) * 6.0
    i = np.floor(h)
    f = h - i
    p = v * (1.0 - s)
    q = v * (1.0 - s * f)
    t = v * (1.0 - s * (1.0 - f))
    sel = [i == k for k in range(5)]
    r = np.select(sel, [v, q, p, p, t], v)
    g = np.select(sel, [t, v, v, q, p], p)
    b = np.select(sel, [p, p, t, v, v], q)
    grey = s == 0.0
    return np.stack([np.where(grey, v, r), np.where(grey, v, g), np.where(grey, v, b)], -1)


def hue_sat_val(c: np.ndarray, hue: float, sat: float, val: float, fac: float) -> np.ndarray:
    """svm_node_hsv: hue shifted (0.5 = none), saturation scaled and
    clamped, value scaled, mixed with the input by fac, negatives cut."""
    hsv = rgb_to_hsv(c)
    h = np.fmod(hsv[..., 0] + hue + 0.5, 1.0)
    s = np.clip(hsv[..., 1] * sat, 0.0, 1.0)
    out = hsv_to_rgb(np.stack([h, s, hsv[..., 2] * val], -1))
    return np.maximum(fac * out + (1.0 - fac) * c, 0.0)


def bright_contrast(c: np.ndarray, bright: float, contrast: float) -> np.ndarray:
    """svm_node_brightness: max((1 + contrast) c + bright - contrast / 2, 0)."""
    return np.maximum((1.0 + contrast) * c + (bright - 0.5 * contrast), 0.0)


def gamma(c: np.ndarray, g: float) -> np.ndarray:
    """svm_node_gamma: c^g where c > 0, else c."""
    pos = c > 0.0
    return np.where(pos, np.power(np.where(pos, c, 1.0), g), c)


def invert(c: np.ndarray, fac: float) -> np.ndarray:
    """svm_node_invert: lerp(c, 1 - c, fac)."""
    return _lerp(c, 1.0 - c, fac)


#: Cycles' ``rgb_to_y`` under Blender 5.2's default colour management, in
#: float32 (read back from renders of the three primaries): the Y row of the
#: inverse of OCIO's CIE XYZ -> Linear Rec.709 (``ShaderManager::
#: init_xyz_transforms``; the config's matrix gives 0.2126390, 0.7151687,
#: 0.0721923, and OCIO's processor adds its float rounding: a grey of 1 reads
#: 1.000001).  Not the config's rounded ``luma`` (0.2126, 0.7152, 0.0722) of
#: mathutil.LUMINANCE (the renderer's own weights, for sampling): 4e-5 off.
RGB_TO_Y = np.array([0.2126391, 0.71516913, 0.07219274], np.float32)


def gray(c: np.ndarray) -> np.ndarray:
    """A colour read by a float input (Cycles' linear_rgb_to_gray: the
    luminance of :data:`RGB_TO_Y`)."""
    return c @ RGB_TO_Y.astype(np.float64)


def ramp(f: np.ndarray, table: np.ndarray, interpolate: bool) -> np.ndarray:
    """rgb_ramp_lookup without extrapolation: f (...,) -> (..., 3) from
    table (N, 3) (:func:`table_positions`), linear between entries unless
    constant."""
    n = table.shape[0]
    x = np.clip(np.nan_to_num(f, nan=0.0), 0.0, 1.0) * (n - 1)
    i = np.clip(x.astype(np.int64), 0, n - 1)
    t = x - i
    out = table[i]
    if interpolate:
        nxt = table[np.minimum(i + 1, n - 1)]
        out = np.where((t > 0.0)[..., None], (1.0 - t)[..., None] * out + t[..., None] * nxt, out)
    return out


#: Mix blends that are affine in the image's colour for a constant other side.
_AFFINE_BLENDS = ("MIX", "ADD", "MULTIPLY", "SCREEN", "SUBTRACT", "LINEAR_LIGHT")


#: Mix blends that are affine in both sides together (two images mixed).
_AFFINE_PAIR_BLENDS = ("MIX", "ADD", "SUBTRACT", "LINEAR_LIGHT")


def is_affine(ops) -> bool:
    """Whether ops commute with bilinear interpolation (up to their clamps
    at 0): then applying them to the texels is what Cycles computes.  A
    ("mix_image", blend, t, image, its ops, clamp) op mixes a second image
    of the same lookup (the exporter turns it into a "mix" with that
    image's folded texels before :func:`apply`)."""
    for op in ops:
        if op[0] == "mix_image":
            _, blend, _, _, other, clamp = op
            if clamp or blend not in _AFFINE_PAIR_BLENDS or not is_affine(other):
                return False
        elif op[0] == "mix":
            _, blend, _, _, side, clamp = op
            if clamp or not (blend in _AFFINE_BLENDS or (blend == "DIVIDE" and side == "A")):
                return False
        elif op[0] not in ("bright", "invert", "gray"):
            return False
    return True


def curves(c: np.ndarray, table: np.ndarray, min_x: float, range_x: float,
           extrapolate: bool, fac: float) -> np.ndarray:
    """svm_node_curves: each channel through its column of table
    (N, 3) over [min_x, min_x + range_x], continued by the
    end slopes when the curves extrapolate (rgb_ramp_lookup), mixed with c
    by fac."""
    n = table.shape[0]
    rel = (c - min_x) / range_x
    out = np.empty_like(c, dtype=np.float64)
    for k in range(3):
        col = np.repeat(table[:, k:k + 1], 3, axis=1)
        out[..., k] = ramp(rel[..., k], col, True)[..., 0]
        if extrapolate:
            lo, hi = rel[..., k] < 0.0, rel[..., k] > 1.0
            d0, d1 = table[0, k] - table[1, k], table[-1, k] - table[-2, k]
            out[..., k] = np.where(lo, table[0, k] + d0 * (-rel[..., k]) * (n - 1), out[..., k])
            out[..., k] = np.where(hi, table[-1, k] + d1 * (rel[..., k] - 1.0) * (n - 1),
                                   out[..., k])
    return (1.0 - fac) * c + fac * out


def apply(ops, c: np.ndarray) -> np.ndarray:
    """Run ops (a sequence of op tuples) on colours c (..., 3) float64."""
    for op in ops:
        name = op[0]
        if name == "mix":           # ("mix", blend, t, other rgb, image side 'A'/'B', clamp)
            _, blend, t, k, side, clamp = op
            k = np.asarray(k, np.float64)
            c = mix(blend, t, c, k) if side == "A" else mix(blend, t, k, c)
            if clamp:
                c = np.clip(c, 0.0, 1.0)
        elif name == "hsv":
            c = hue_sat_val(c, *op[1:])
        elif name == "bright":
            c = bright_contrast(c, *op[1:])
        elif name == "gamma":
            c = gamma(c, op[1])
        elif name == "invert":
            c = invert(c, op[1])
        elif name == "ramp":                  # ("ramp", table as a tuple of rgb, interpolate)
            c = ramp(gray(c), np.asarray(op[1], np.float64), op[2])
        elif name == "gray":                  # ("gray",): a colour read as a float, as grey
            c = np.repeat(gray(c)[..., None], 3, axis=-1)
        elif name == "curves":                # ("curves", table, min_x, range_x, extrapolate, fac)
            c = curves(c, np.asarray(op[1], np.float64), *op[2:])
        else:
            raise ValueError(f"unknown colour op {name!r}")
    return c
