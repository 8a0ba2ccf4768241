"""Cycles' pattern textures - Checker, Gradient, Magic and Brick - evaluated at
texture-space points, vectorised over them.

Each ``*_texture(output, params, p)`` follows core/scene/procedural.py's
interface: p (N, 3) float64 texture-space points (the node's Vector input),
``params`` the node's input sockets by name and properties by identifier (a
missing key is Blender's default: the ``*_DEFAULTS`` tables, read from fresh
Blender 5.2 nodes), the result (N, 3) float64 (a Factor as a grey colour).

The arithmetic is Cycles' float32 arithmetic, operation by operation in the
order of its kernels (intern/cycles/kernel/svm/checker.h, gradient.h,
magic.h, brick.h), so that cell faces, brick rows and mortar edges fall where
Cycles puts them; sines, cosines and arctangents are taken in float64 of the
float32 argument and rounded to float32 (the correctly rounded value, which
glibc's sinf/cosf/atan2f give).

:func:`_grey` (a float output read as a colour) lives here, the leaf module
of the procedural textures, so that core/scene/voronoi.py and
core/scene/procedural.py both import it without an import cycle.
"""
from __future__ import annotations

import numpy as np

F32 = np.float32


def _grey(f: np.ndarray) -> np.ndarray:
    """(N, 3) float64 a float output (N,) read as a colour, as Cycles converts a
    float into a colour socket."""
    return np.repeat(np.asarray(f, np.float64)[:, None], 3, axis=1)


def _get(params: dict, defaults: dict, name: str):
    return params.get(name, defaults[name])


def _colour(params: dict, defaults: dict, name: str) -> np.ndarray:
    """(3,) float32 an RGB(A) socket's colour (alpha dropped)."""
    return np.asarray(_get(params, defaults, name), F32)[:3]


def _sin(x: np.ndarray) -> np.ndarray:
    """float32 sinf(x) of float32 x (correctly rounded)."""
    return np.sin(x.astype(np.float64)).astype(F32)


def _cos(x: np.ndarray) -> np.ndarray:
    """float32 cosf(x) of float32 x (correctly rounded)."""
    return np.cos(x.astype(np.float64)).astype(F32)


def _scaled(p: np.ndarray, scale) -> np.ndarray:
    """(3, N) float32 the node's ``co * scale``, each component a row."""
    return np.asarray(p, F32).T * F32(scale)


# ----------------------------------------------------------------- Checker

#: Blender 5.2's defaults of a Checker Texture node.
CHECKER_DEFAULTS = {
    "Color1": (0.8, 0.8, 0.8),
    "Color2": (0.2, 0.2, 0.2),
    "Scale": 5.0,
}


def checker_texture(output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 Cycles' ``svm_node_tex_checker`` at p (N, 3) float64: the
    parity of the cell of p * Scale, nudged off the cell faces as Cycles
    nudges it ((q + 1e-6) * 0.999999 in float32, ``svm_checker``)."""
    q = (_scaled(p, _get(params, CHECKER_DEFAULTS, "Scale")) + F32(0.000001)) * F32(0.999999)
    i = np.abs(np.floor(q).astype(np.int64))
    f = (i[0] % 2 == i[1] % 2) == (i[2] % 2 == 1)
    if output != "Color":
        return _grey(f)
    c1 = _colour(params, CHECKER_DEFAULTS, "Color1")
    c2 = _colour(params, CHECKER_DEFAULTS, "Color2")
    return np.where(f[:, None], c1, c2).astype(np.float64)


# ---------------------------------------------------------------- Gradient

#: Blender 5.2's default of a Gradient Texture node.
GRADIENT_DEFAULTS = {
    "gradient_type": "LINEAR",
}

_TWO_PI = F32(6.2831853071795864)   # Cycles' M_2PI_F


def gradient_texture(output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 Cycles' ``svm_node_tex_gradient`` at p (N, 3) float64:
    ``svm_gradient`` of the point's type, clamped to [0, 1]; Color and Factor
    are the same grey."""
    kind = _get(params, GRADIENT_DEFAULTS, "gradient_type")
    x, y, z = np.asarray(p, F32).T
    if kind == "LINEAR":
        f = x
    elif kind == "QUADRATIC":
        r = np.maximum(x, F32(0))
        f = r * r
    elif kind == "EASING":
        r = np.clip(x, F32(0), F32(1))
        t = r * r
        f = F32(3) * t - F32(2) * t * r
    elif kind == "DIAGONAL":
        f = (x + y) * F32(0.5)
    elif kind == "RADIAL":
        a = np.arctan2(y.astype(np.float64), x.astype(np.float64)).astype(F32)
        f = a / _TWO_PI + F32(0.5)
    elif kind in ("QUADRATIC_SPHERE", "SPHERICAL"):
        # biased by 1e-6 so that a unit vector gives exactly 0 (svm_gradient)
        r = np.maximum(F32(0.999999) - np.sqrt(x * x + y * y + z * z), F32(0))
        f = r * r if kind == "QUADRATIC_SPHERE" else r
    else:
        raise ValueError(f"unknown gradient_type {kind!r}")
    return _grey(np.clip(f, F32(0), F32(1)))


# ------------------------------------------------------------------- Magic

#: Blender 5.2's defaults of a Magic Texture node.
MAGIC_DEFAULTS = {
    "Scale": 5.0,
    "Distortion": 1.0,
    "turbulence_depth": 2,
}


def magic_texture(output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 Cycles' ``svm_node_tex_magic`` at p (N, 3) float64:
    ``svm_magic``'s chain of sines and cosines, ``turbulence_depth`` links of
    it, each scaled by Distortion; Factor is the colour's average."""
    scale = F32(_get(params, MAGIC_DEFAULTS, "Scale"))
    dist = F32(_get(params, MAGIC_DEFAULTS, "Distortion"))
    n = int(_get(params, MAGIC_DEFAULTS, "turbulence_depth"))
    # the scaled point wrapped into (-2 pi, 2 pi) first, as Cycles keeps large
    # coordinates from losing the small ones' precision (svm_magic; Scale
    # before the wrap since Blender 5.2, as OSL and EEVEE)
    px, py, pz = np.fmod(_scaled(p, scale), _TWO_PI)
    x = _sin((px + py + pz) * F32(5))
    y = _cos((-px + py - pz) * F32(5))
    z = -_cos((-px - py + pz) * F32(5))
    if n > 0:
        x, y, z = x * dist, y * dist, z * dist
        y = -_cos(x - y + z) * dist
        # the links beyond the first, in svm_magic's order: (the component
        # replaced, its function of (x, y, z))
        links = [
            ("x", lambda x, y, z: _cos(x - y - z)),
            ("z", lambda x, y, z: _sin(-x - y - z)),
            ("x", lambda x, y, z: -_cos(-x + y - z)),
            ("y", lambda x, y, z: -_sin(-x + y + z)),
            ("y", lambda x, y, z: -_cos(-x + y + z)),
            ("x", lambda x, y, z: _cos(x + y + z)),
            ("z", lambda x, y, z: _sin(x + y - z)),
            ("x", lambda x, y, z: -_cos(-x - y + z)),
            ("y", lambda x, y, z: -_sin(x - y + z)),
        ]
        for comp, fn in links[:max(0, n - 1)]:
            v = fn(x, y, z) * dist
            if comp == "x":
                x = v
            elif comp == "y":
                y = v
            else:
                z = v
    if dist != 0:
        d2 = dist * F32(2)
        x, y, z = x / d2, y / d2, z / d2
    col = np.stack([F32(0.5) - x, F32(0.5) - y, F32(0.5) - z], -1)
    if output == "Color":
        return col.astype(np.float64)
    # Cycles' average(): the components' sum times 1/3
    return _grey((col[:, 0] + col[:, 1] + col[:, 2]) * F32(1.0 / 3.0))


# ------------------------------------------------------------------- Brick

#: Blender 5.2's defaults of a Brick Texture node.
BRICK_DEFAULTS = {
    "Color1": (0.8, 0.8, 0.8),
    "Color2": (0.2, 0.2, 0.2),
    "Mortar": (0.0, 0.0, 0.0),
    "Scale": 5.0,
    "Mortar Size": 0.02,
    "Mortar Smooth": 0.1,
    "Bias": 0.0,
    "Brick Width": 0.5,
    "Row Height": 0.25,
    "offset_frequency": 2,
    "squash_frequency": 2,
    "offset": 0.5,
    "squash": 1.0,
}


def _brick_noise(n: np.ndarray) -> np.ndarray:
    """(N,) float32 Cycles' ``brick_noise``: an integer hash of the uint32 word n
    in [0, 1)."""
    with np.errstate(over="ignore"):
        n = (n + np.uint32(1013)) & np.uint32(0x7FFFFFFF)
        n = (n >> np.uint32(13)) ^ n
        nn = (n * (n * n * np.uint32(60493) + np.uint32(19990303)) + np.uint32(1376312589)
              ) & np.uint32(0x7FFFFFFF)
    return F32(0.5) * (nn.astype(F32) / F32(1073741824.0))


def _smoothstepf(f: np.ndarray) -> np.ndarray:
    """float32 Cycles' ``smoothstepf``: 3 f^2 - 2 f^3 on [0, 1], 0 below, 1 above."""
    ff = f * f
    return np.where(f <= 0, F32(0), np.where(f >= 1, F32(1), F32(3) * ff - F32(2) * ff * f))


def brick_texture(output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 Cycles' ``svm_node_tex_brick`` at p (N, 3) float64: rows of
    Row Height, each brick of Brick Width (every ``squash_frequency``-th row's
    squashed by ``squash``, every ``offset_frequency``-th row's shifted by
    ``offset`` of a width), tinted between Color1 and Color2 by a hash of
    (row, brick) plus Bias; Factor the mortar's weight, smoothed over the
    inner Mortar Smooth of the Mortar Size band (``svm_brick``)."""
    g = lambda name: _get(params, BRICK_DEFAULTS, name)  # noqa: E731
    px, py, _ = _scaled(p, g("Scale"))
    mortar_size, mortar_smooth = F32(g("Mortar Size")), F32(g("Mortar Smooth"))
    row_height = F32(g("Row Height"))
    width = np.full(px.shape, F32(g("Brick Width")))
    offset_freq, squash_freq = int(g("offset_frequency")), int(g("squash_frequency"))

    row = np.floor(py / row_height)
    rownum = row.astype(np.int64)
    offset = np.zeros_like(px)
    if offset_freq and squash_freq:
        # C's % is nonzero exactly where Python's is, whatever the sign
        width = np.where(rownum % squash_freq != 0, width, width * F32(g("squash")))
        offset = np.where(rownum % offset_freq != 0, F32(0), width * F32(g("offset")))
    brick = np.floor((px + offset) / width)
    bricknum = brick.astype(np.int64)
    x = (px + offset) - width * brick
    y = py - row_height * row

    # (rownum << 16) + (bricknum & 0xFFFF) in C's wrapping int, as the uint word
    word = (((rownum << 16) + (bricknum & 0xFFFF)) & 0xFFFFFFFF).astype(np.uint32)
    tint = np.clip(_brick_noise(word) + F32(g("Bias")), F32(0), F32(1))
    min_dist = np.minimum(np.minimum(x, y), np.minimum(width - x, row_height - y))
    if mortar_smooth == 0:
        smooth = np.ones_like(min_dist)
    else:
        smooth = _smoothstepf((F32(1) - min_dist / mortar_size) / mortar_smooth)
    f = np.where(min_dist >= mortar_size, F32(0), smooth)
    if output != "Color":
        return _grey(f)

    c1 = _colour(params, BRICK_DEFAULTS, "Color1")
    c2 = _colour(params, BRICK_DEFAULTS, "Color2")
    mortar = _colour(params, BRICK_DEFAULTS, "Mortar")
    t = tint[:, None]
    # the brick's tint is mixed in only off the full mortar (f != 1), as Cycles
    brick_col = np.where((f != 1)[:, None], (F32(1) - t) * c1 + t * c2, c1)
    fc = f[:, None]
    return (brick_col * (F32(1) - fc) + mortar * fc).astype(np.float64)
