"""Cycles' converter nodes as numpy functions of K points at once.

Math, Vector Math, Map Range, Clamp, Separate / Combine Color, the Mix
node's Float and Vector types, and the conversions between socket types,
for evaluating a material's node graph per texel.  Each function follows
the Cycles 5.2 SVM kernel named in its docstring
(``intern/cycles/kernel/svm``: ``math.h`` / ``math_util.h``
``svm_math`` and ``svm_vector_math``, ``map_range.h``, ``clamp.h``,
``sepcomb_color.h``, ``mix.h``, ``convert.h``; the helpers of
``util/math_base.h``, ``util/math_float3.h`` and ``util/color.h``) and the
way ``scene/shader_nodes.cpp`` compiles the node (a Math node's Clamp and a
float Map Range's Clamp are a Clamp node appended after it).

Shapes: a float input is an array broadcastable to (K,), a vector or colour
input one broadcastable to (K, 3); results are float64 (K,) or (K, 3).
Enumerations are Blender's identifiers (``node.operation``,
``node.interpolation_type``, ``node.clamp_type``, ``node.mode``).

The arithmetic is Cycles' float32 arithmetic, operation by operation in the
order of its kernels, so that floors, remainders, comparisons and
``floorf(a + 0.5f)`` fall where Cycles puts them; the transcendental
functions (sin ... pow) are taken in float64 of the float32 arguments and
rounded to float32 (the correctly rounded value, which glibc's float
functions give to within an ulp).  It is the arithmetic of Cycles' CPU
kernel as built for Blender (AVX2 on a CPU that has it; ``src/CMakeLists.txt``
``-ffp-contract=on -freciprocal-math``), where that differs from the C:
a product and a sum within one scalar C expression are one fused
multiply-add (:func:`_fma`: Math Multiply Add, Floored Modulo, Wrap, Smooth
Min / Max, the float Map Range, HSL to RGB, Mix Float, Refract's scalars),
while float3 operators (SSE intrinsics) are not fused - except ``cross``,
whose ``msub`` is ``_mm_fmsub_ps``; the Vector Math Modulo is the SSE4.2
``a - trunc(a / b) * b`` (``fmod(float3, float3)``), not C's exact
``fmodf`` as the Math node's Modulo; RGB to HSL's ``h /= 6`` is ``h * (1 /
6)``.  Measured against Cycles 5.2 (tests/test_node_math.py) every op
agrees to the bit except by an ulp in some transcendentals and in HSV
(color_ops' ``rgb_to_hsv`` / ``hsv_to_rgb``, reused here, divide by 6 and do
not fuse).
"""
from __future__ import annotations

import numpy as np

from . import color_ops
from ..mathutil import unit_rows
from .color_ops import RGB_TO_Y

F32 = np.float32
_ZERO, _ONE = F32(0.0), F32(1.0)
#: FLT_EPSILON, COMPARE's least threshold.
_FLT_EPSILON = F32(np.finfo(np.float32).eps)


# ------------------------------------------------------------------ helpers

def _f(x) -> np.ndarray:
    """float32 array of x (a float input)."""
    return np.asarray(x, F32)


def _libm(fn):
    """float32 -> float32 fn taken in float64 and rounded (glibc's xxxf)."""
    def g(*args):
        with np.errstate(all="ignore"):
            return fn(*(np.asarray(x, np.float64) for x in args)).astype(F32)
    return g


_sin, _cos, _tan = _libm(np.sin), _libm(np.cos), _libm(np.tan)
_asin, _acos, _atan, _atan2 = _libm(np.arcsin), _libm(np.arccos), _libm(np.arctan), \
    _libm(np.arctan2)
_sinh, _cosh, _tanh = _libm(np.sinh), _libm(np.cosh), _libm(np.tanh)
_exp, _log, _pow = _libm(np.exp), _libm(np.log), _libm(np.power)


def _fma(x, y, z) -> np.ndarray:
    """float32 x y + z rounded once, as Cycles' AVX2 kernel contracts a
    product and a sum within one C expression (``-ffp-contract=on``): x y is
    exact in float64, the sum is rounded to float64 and then float32 (a
    double rounding, off by an ulp only where the sum needs more than 53
    bits).  (The SSE4.2 kernel of a CPU without FMA rounds x y first.)"""
    f64 = np.float64
    return (np.asarray(x, f64) * np.asarray(y, f64) + np.asarray(z, f64)).astype(F32)


def _sel(cond, x, y) -> np.ndarray:
    """float32 ``cond ? x : y`` elementwise."""
    return np.where(cond, x, y).astype(F32)


def _max(a, b):
    """Cycles' ``max(a, b)``: ``a > b ? a : b``."""
    return _sel(a > b, a, b)


def _min(a, b):
    """Cycles' ``min(a, b)``: ``a < b ? a : b``."""
    return _sel(a < b, a, b)


def _clamp(x, lo, hi):
    """Cycles' ``clamp(x, lo, hi)`` = ``min(max(x, lo), hi)`` (hi wins when lo > hi)."""
    return _min(_max(x, lo), hi)


def _safe_divide(a, b):
    """``safe_divide``: a / b, 0 where b is 0 (per component for vectors)."""
    nz = b != 0.0
    with np.errstate(all="ignore"):
        return _sel(nz, a / _sel(nz, b, _ONE), _ZERO)


def _fract(a):
    """``fractf``: a - floor(a)."""
    return a - np.floor(a)


def _safe_powf(a, b):
    """``safe_powf``: 0 for a negative base and an exponent other than
    ``(int)b`` (a truncation; x86 gives INT_MIN beyond the int range), else
    ``compatible_powf``: 1 for b = 0 (0^0 too), 0 for a = 0, else powf."""
    a, b = np.broadcast_arrays(a, b)
    as_int = np.where(np.abs(b) < 2.0 ** 31, np.trunc(b), -(2.0 ** 31))
    p = _sel(a == 0.0, _ZERO, _pow(a, b))
    return _sel((a < 0.0) & (b != as_int), _ZERO, _sel(b == 0.0, _ONE, p))


def _safe_logf(a, b):
    """``safe_logf``: log(a) / log(b) (safe_divide), 0 unless a, b > 0."""
    ok = (a > 0.0) & (b > 0.0)
    return _sel(ok, _safe_divide(_log(_sel(ok, a, _ONE)), _log(_sel(ok, b, _ONE))), _ZERO)


def _sign(a):
    """``compatible_signf``: 0 at 0, else -1 below 0 and 1 above (and for NaN)."""
    return _sel(a == 0.0, _ZERO, _sel(a < 0.0, F32(-1.0), _ONE))


def _smoothmin(a, b, k):
    """``smoothminf``: min(a, b) - h^3 k / 6 with h = max(k - |a - b|, 0) / k
    (fminf(a, b) for k = 0)."""
    m = np.fmin(a, b)
    nz = k != 0.0
    with np.errstate(all="ignore"):
        h = _max(k - np.abs(a - b), _ZERO) / _sel(nz, k, _ONE)
        return _sel(nz, _fma(-(h * h * h * k), _ONE / F32(6.0), m), m)


def _wrapf(a, hi, lo):
    """``wrapf(value, max, min)``: value - range floor((value - min) / range),
    range = max - min; min where the range is 0."""
    r = hi - lo
    nz = r != 0.0
    with np.errstate(all="ignore"):
        return _sel(nz, _fma(-r, np.floor((a - lo) / _sel(nz, r, _ONE)), a), lo)


def _pingpong(a, b):
    """``pingpongf``: |fract((a - b) / 2b) * b * 2 - b|, 0 for b = 0."""
    nz = b != 0.0
    with np.errstate(all="ignore"):
        q = (a - b) / (_sel(nz, b, _ONE) * F32(2.0))
        return _sel(nz, np.abs(_fract(q) * b * F32(2.0) - b), _ZERO)


def _inversesqrt(a):
    """``inversesqrtf``: 1 / sqrt(a) for a > 0, else 0."""
    pos = a > 0.0
    return _sel(pos, _ONE / np.sqrt(_sel(pos, a, _ONE)), _ZERO)


def _compare(a, b, c):
    """COMPARE: 1 where a == b or |a - b| <= max(c, FLT_EPSILON) (fmaxf)."""
    return ((a == b) | (np.abs(a - b) <= np.fmax(c, _FLT_EPSILON))).astype(F32)


#: Math node operation -> float32 f(a, b, c) (``svm_math``).
_MATH = {
    "ADD": lambda a, b, c: a + b,
    "SUBTRACT": lambda a, b, c: a - b,
    "MULTIPLY": lambda a, b, c: a * b,
    "DIVIDE": lambda a, b, c: _safe_divide(a, b),
    "MULTIPLY_ADD": lambda a, b, c: _fma(a, b, c),
    "POWER": lambda a, b, c: _safe_powf(a, b),
    "LOGARITHM": lambda a, b, c: _safe_logf(a, b),
    "SQRT": lambda a, b, c: np.sqrt(_max(a, _ZERO)),
    "INVERSE_SQRT": lambda a, b, c: _inversesqrt(a),
    "ABSOLUTE": lambda a, b, c: np.abs(a),
    "EXPONENT": lambda a, b, c: _exp(a),
    "MINIMUM": lambda a, b, c: np.fmin(a, b),
    "MAXIMUM": lambda a, b, c: np.fmax(a, b),
    "LESS_THAN": lambda a, b, c: (a < b).astype(F32),
    "GREATER_THAN": lambda a, b, c: (a > b).astype(F32),
    "SIGN": lambda a, b, c: _sign(a),
    "COMPARE": _compare,
    "SMOOTH_MIN": lambda a, b, c: _smoothmin(a, b, c),
    "SMOOTH_MAX": lambda a, b, c: -_smoothmin(-a, -b, c),
    "ROUND": lambda a, b, c: np.floor(a + F32(0.5)),
    "FLOOR": lambda a, b, c: np.floor(a),
    "CEIL": lambda a, b, c: np.ceil(a),
    "TRUNC": lambda a, b, c: np.trunc(a),
    "FRACT": lambda a, b, c: _fract(a),
    "MODULO": lambda a, b, c: _sel(b != 0.0, np.fmod(a, _sel(b != 0.0, b, _ONE)), _ZERO),
    "FLOORED_MODULO": lambda a, b, c: _sel(
        b != 0.0, _fma(-np.floor(a / _sel(b != 0.0, b, _ONE)), b, a), _ZERO),
    "WRAP": lambda a, b, c: _wrapf(a, b, c),
    "SNAP": lambda a, b, c: np.floor(_safe_divide(a, b)) * b,
    "PINGPONG": lambda a, b, c: _pingpong(a, b),
    "SINE": lambda a, b, c: _sin(a),
    "COSINE": lambda a, b, c: _cos(a),
    "TANGENT": lambda a, b, c: _tan(a),
    "ARCSINE": lambda a, b, c: _asin(_clamp(a, F32(-1.0), _ONE)),
    "ARCCOSINE": lambda a, b, c: _acos(_clamp(a, F32(-1.0), _ONE)),
    "ARCTANGENT": lambda a, b, c: _atan(a),
    # compatible_atan2(y = a, x = b): 0 at (0, 0) whatever the zeros' signs
    "ARCTAN2": lambda a, b, c: _sel((a == 0.0) & (b == 0.0), _ZERO, _atan2(a, b)),
    "SINH": lambda a, b, c: _sinh(a),
    "COSH": lambda a, b, c: _cosh(a),
    "TANH": lambda a, b, c: _tanh(a),
    "RADIANS": lambda a, b, c: a * (F32(np.pi) / F32(180.0)),
    "DEGREES": lambda a, b, c: a * (F32(180.0) / F32(np.pi)),
}
#: The Math node's identifiers (Blender calls the fraction FRACT).
MATH_OPS = tuple(_MATH)
_MATH_ALIASES = {"FRACTION": "FRACT"}


def math(op: str, a, b=0.5, c=0.0) -> np.ndarray:
    """(K,) float64 the Math node's Value for operation ``op`` (``svm_math``)
    of Value1..3 ``a``, ``b``, ``c`` (broadcastable to (K,); defaults are the
    node's).  The node's Clamp (``use_clamp``) is the caller's:
    :func:`saturate` after, as Cycles appends a Clamp node (0..1)."""
    fn = _MATH[_MATH_ALIASES.get(op, op)]
    a, b, c = np.broadcast_arrays(_f(a), _f(b), _f(c))
    with np.errstate(all="ignore"):
        return np.asarray(fn(a, b, c), F32).astype(np.float64)


def saturate(x) -> np.ndarray:
    """float64 x clamped to [0, 1] as Cycles' Clamp node (MINMAX 0, 1), which
    ``scene/shader_nodes.cpp`` appends to a Math node with Clamp on (and NaN to 0)."""
    return _clamp(_f(x), _ZERO, _ONE).astype(np.float64)


# ------------------------------------------------------------- Vector Math

def _dot(a, b):
    """(K,) float32 ``dot``: (ax bx + ay by) + az bz (``_mm_dp_ps``)."""
    return (a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]) + a[..., 2] * b[..., 2]


def _len(a):
    return np.sqrt(_dot(a, a))


def _safe_normalize(a):
    """``safe_normalize``: a * (1 / |a|), a itself where |a| = 0."""
    t = _len(a)[..., None]
    nz = t != 0.0
    return _sel(nz, a * (_ONE / _sel(nz, t, _ONE)), a)


def _cross(a, b):
    """``cross``: on AVX2 ``msub`` is ``_mm_fmsub_ps``, so each component is
    a fused ay bz - (az by rounded), and so on."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([_fma(ay, bz, -(az * by)), _fma(az, bx, -(ax * bz)),
                     _fma(ax, by, -(ay * bx))], -1)


def _project(a, b):
    """``project(a, b)``: (a.b / b.b) b, 0 where b = 0."""
    ls = _dot(b, b)
    nz = ls != 0.0
    return _sel(nz[..., None], (_dot(a, b) / _sel(nz, ls, _ONE))[..., None] * b, _ZERO)


def _reflect(a, n):
    """``reflect(incident, unit_normal)``: a - 2 n (a.n)."""
    return a - F32(2.0) * n * _dot(a, n)[..., None]


def _refract(a, n, eta):
    """``refract(incident, normal, eta)``: eta a - (eta (n.a) + sqrt(k)) n with
    k = 1 - eta^2 (1 - (n.a)^2) (its float sums fused with their products);
    0 where k < 0."""
    d = _dot(n, a)
    k = _fma(-(eta * eta), _fma(-d, d, _ONE), _ONE)
    ok = k >= 0.0
    r = eta[..., None] * a - _fma(eta, d, np.sqrt(_sel(ok, k, _ZERO)))[..., None] * n
    return _sel(ok[..., None], r, _ZERO)


def _fmod_sse(a, b):
    """``safe_fmod(float3, float3)`` on SSE4.2 / AVX2: a - trunc(a / b) * b,
    0 where b is 0."""
    nz = b != 0.0
    with np.errstate(all="ignore"):
        bb = _sel(nz, b, _ONE)
        return _sel(nz, a - np.trunc(a / bb) * bb, _ZERO)


def _wrap3(a, hi, lo):
    """``wrap(value, max, min)`` of float3: safe_floored_fmod(value - min,
    max - min) + min (so min where the range is 0)."""
    x, r = a - lo, hi - lo
    nz = r != 0.0
    with np.errstate(all="ignore"):
        rr = _sel(nz, r, _ONE)
        return _sel(nz, x - np.floor(x / rr) * rr, _ZERO) + lo


#: Vector Math operations with a Vector output -> float32 f(a, b, c, s)
#: ((K, 3) vectors, s (K,) the Scale socket), ``svm_vector_math``.
_VECTOR = {
    "ADD": lambda a, b, c, s: a + b,
    "SUBTRACT": lambda a, b, c, s: a - b,
    "MULTIPLY": lambda a, b, c, s: a * b,
    "DIVIDE": lambda a, b, c, s: _safe_divide(a, b),
    "MULTIPLY_ADD": lambda a, b, c, s: a * b + c,
    "CROSS_PRODUCT": lambda a, b, c, s: _cross(a, b),
    "PROJECT": lambda a, b, c, s: _project(a, b),
    "REFLECT": lambda a, b, c, s: _reflect(a, _safe_normalize(b)),
    "REFRACT": lambda a, b, c, s: _refract(a, _safe_normalize(b), s),
    "FACEFORWARD": lambda a, b, c, s: _sel((_dot(c, b) < 0.0)[..., None], a, -a),
    "SCALE": lambda a, b, c, s: a * s[..., None],
    "NORMALIZE": lambda a, b, c, s: _safe_normalize(a),
    "ABSOLUTE": lambda a, b, c, s: np.abs(a),
    "POWER": lambda a, b, c, s: _safe_powf(a, b),
    "SIGN": lambda a, b, c, s: _sign(a),
    "MINIMUM": lambda a, b, c, s: _min(a, b),
    "MAXIMUM": lambda a, b, c, s: _max(a, b),
    "ROUND": lambda a, b, c, s: np.floor(a + F32(0.5)),
    "FLOOR": lambda a, b, c, s: np.floor(a),
    "CEIL": lambda a, b, c, s: np.ceil(a),
    "FRACTION": lambda a, b, c, s: _fract(a),
    "MODULO": lambda a, b, c, s: _fmod_sse(a, b),
    "WRAP": lambda a, b, c, s: _wrap3(a, b, c),
    "SNAP": lambda a, b, c, s: np.floor(_safe_divide(a, b)) * b,
    "SINE": lambda a, b, c, s: _sin(a),
    "COSINE": lambda a, b, c, s: _cos(a),
    "TANGENT": lambda a, b, c, s: _tan(a),
}
#: Vector Math operations with a Value output -> float32 f(a, b) (K,).
_VALUE = {
    "DOT_PRODUCT": lambda a, b: _dot(a, b),
    "DISTANCE": lambda a, b: _len(a - b),
    "LENGTH": lambda a, b: _len(a),
}
VECTOR_MATH_OPS = tuple(_VECTOR) + tuple(_VALUE)


def vector_math(op: str, a, b=0.0, c=0.0, scale=1.0) -> tuple[np.ndarray, np.ndarray]:
    """(Vector (K, 3) float64, Value (K,) float64) the Vector Math node's
    outputs for ``op`` (``svm_vector_math``) of its three Vector inputs
    ``a``, ``b``, ``c`` (broadcastable to (K, 3)) and ``scale`` (the Scale
    socket, (K,): SCALE's factor and REFRACT's eta).  DOT_PRODUCT, DISTANCE
    and LENGTH fill the Value (the Vector is 0), every other op the Vector
    (the Value is 0), as Cycles leaves the one it does not write."""
    a, b, c = np.broadcast_arrays(_f(a), _f(b), _f(c))
    a, b, c = (np.broadcast_to(x, np.broadcast_shapes(x.shape, (3,))) for x in (a, b, c))
    s = np.broadcast_to(_f(scale), a.shape[:-1])
    vec = np.zeros(a.shape, np.float64)
    val = np.zeros(a.shape[:-1], np.float64)
    with np.errstate(all="ignore"):
        if op in _VALUE:
            val = np.asarray(_VALUE[op](a, b), F32).astype(np.float64)
        else:
            vec = np.asarray(_VECTOR[op](a, b, c, s), F32).astype(np.float64)
    return vec, val


# --------------------------------------------------------- Map Range, Clamp

MAP_RANGE_TYPES = ("LINEAR", "STEPPED", "SMOOTHSTEP", "SMOOTHERSTEP")


def _smoothstep(e0, e1, x):
    """``smoothstep(edge0, edge1, x)``: 0 below e0, 1 from e1 on, else
    (3 - 2t) t^2 with t = (x - e0) / (e1 - e0)."""
    with np.errstate(all="ignore"):
        t = (x - e0) / (e1 - e0)
        s = (F32(3.0) - F32(2.0) * t) * (t * t)
    return _sel(x < e0, _ZERO, _sel(x >= e1, _ONE, s))


def _smootherstep_unit(t, fused):
    """t^3 (t (6t - 15) + 10) of t in [0, 1]; ``fused`` the float kernel's
    contraction of the bracket's products and sums (not the float3 one's)."""
    if fused:
        return t * t * t * _fma(t, _fma(t, F32(6.0), F32(-15.0)), F32(10.0))
    return t * t * t * (t * (t * F32(6.0) - F32(15.0)) + F32(10.0))


def _stepped(factor, steps):
    """floor(factor (steps + 1)) / steps, 0 where steps <= 0."""
    pos = steps > 0.0
    with np.errstate(all="ignore"):
        return _sel(pos, np.floor(factor * (steps + _ONE)) / _sel(pos, steps, _ONE), _ZERO)


def _clamp_range(x, lo, hi):
    """The Clamp node's RANGE: clamp(x, lo, hi), the bounds swapped when lo > hi."""
    swap = lo > hi
    return _clamp(x, _sel(swap, hi, lo), _sel(swap, lo, hi))


def map_range(interpolation: str, value, from_min=0.0, from_max=1.0, to_min=0.0,
              to_max=1.0, steps=4.0, clamp=True) -> np.ndarray:
    """(K,) float64 the Map Range node's Result for data type FLOAT
    (``svm_node_map_range``), inputs broadcastable to (K,), defaults the
    node's.  0 where from_min == from_max.  ``clamp`` (the node's property):
    Cycles appends a Clamp node (RANGE, To Min .. To Max) for every
    interpolation (``MapRangeNode::expand``), which changes SMOOTHSTEP and
    SMOOTHERSTEP only where from_min == from_max (0 clamped into the range)."""
    v, f0, f1, t0, t1, st = np.broadcast_arrays(*map(_f, (value, from_min, from_max,
                                                          to_min, to_max, steps)))
    with np.errstate(all="ignore"):
        if interpolation in ("LINEAR", "STEPPED"):
            factor = (v - f0) / (f1 - f0)
            if interpolation == "STEPPED":
                factor = _stepped(factor, st)
        elif interpolation == "SMOOTHSTEP":
            factor = _sel(f0 > f1, _ONE - _smoothstep(f1, f0, v), _smoothstep(f0, f1, v))
        elif interpolation == "SMOOTHERSTEP":
            # smootherstep(edge0, edge1, x) in map_range.h clamps safe_divide's t
            def smoother(e0, e1):
                t = _clamp(_safe_divide(v - e0, e1 - e0), _ZERO, _ONE)
                return _smootherstep_unit(t, True)
            factor = _sel(f0 > f1, _ONE - smoother(f1, f0), smoother(f0, f1))
        else:
            raise ValueError(f"unknown Map Range interpolation {interpolation!r}")
        result = _sel(f1 != f0, _fma(factor, t1 - t0, t0), _ZERO)
    if clamp:
        result = _clamp_range(result, t0, t1)
    return result.astype(np.float64)


def map_range_vector(interpolation: str, value, from_min=0.0, from_max=1.0, to_min=0.0,
                     to_max=1.0, steps=4.0, clamp=True) -> np.ndarray:
    """(K, 3) float64 the Map Range node's Vector for data type FLOAT_VECTOR
    (``svm_node_vector_map_range``): per component, the factor a
    safe_divide (so To Min where From Min == From Max), inputs broadcastable
    to (K, 3).  ``clamp`` applies to LINEAR and STEPPED only (the kernel
    ignores it for the smooth steps)."""
    v, f0, f1, t0, t1, st = np.broadcast_arrays(*map(_f, (value, from_min, from_max,
                                                          to_min, to_max, steps)))
    factor = _safe_divide(v - f0, f1 - f0)
    if interpolation == "STEPPED":
        factor = _stepped(factor, st)
    elif interpolation == "SMOOTHSTEP":
        factor = _clamp(factor, _ZERO, _ONE)
        factor = (F32(3.0) - F32(2.0) * factor) * (factor * factor)
    elif interpolation == "SMOOTHERSTEP":
        factor = _smootherstep_unit(_clamp(factor, _ZERO, _ONE), False)
    elif interpolation != "LINEAR":
        raise ValueError(f"unknown Map Range interpolation {interpolation!r}")
    with np.errstate(all="ignore"):
        result = t0 + factor * (t1 - t0)
    if clamp and interpolation in ("LINEAR", "STEPPED"):
        result = _clamp_range(result, t0, t1)
    return np.asarray(result, F32).astype(np.float64)


def clamp(clamp_type: str, value, lo=0.0, hi=1.0) -> np.ndarray:
    """(K,) float64 the Clamp node's Result (``svm_node_clamp``): MINMAX
    min(max(value, lo), hi) (hi wins when lo > hi); RANGE the same with the
    bounds swapped when lo > hi."""
    v, lo, hi = np.broadcast_arrays(_f(value), _f(lo), _f(hi))
    if clamp_type == "RANGE":
        return _clamp_range(v, lo, hi).astype(np.float64)
    if clamp_type != "MINMAX":
        raise ValueError(f"unknown Clamp type {clamp_type!r}")
    return _clamp(v, lo, hi).astype(np.float64)


# ----------------------------------------------------- Separate / Combine

def _rgb_to_hsl(c):
    """util/color.h ``rgb_to_hsl`` of float32 (K, 3): l capped at 1; h, s 0
    for a grey; ``h /= 6`` compiled as h * (1 / 6) (``-freciprocal-math``).
    A saturation's divisor is 0 (infinite s) where the largest and smallest
    channels add up to 0 or, above a lightness of 0.5, to 2, as in Cycles."""
    r, g, b = c[..., 0], c[..., 1], c[..., 2]
    cmax = np.fmax(r, np.fmax(g, b))
    cmin = _min(r, _min(g, b))
    l_ = _min(_ONE, (cmax + cmin) / F32(2.0))
    grey = cmax == cmin
    d = _sel(grey, _ONE, cmax - cmin)
    with np.errstate(all="ignore"):
        s = _sel(l_ > 0.5, d / (F32(2.0) - cmax - cmin), d / (cmax + cmin))
        h = _sel(cmax == r, (g - b) / d + _sel(g < b, F32(6.0), _ZERO),
                 _sel(cmax == g, (b - r) / d + F32(2.0), (r - g) / d + F32(4.0)))
    return np.stack([_sel(grey, _ZERO, h) * (_ONE / F32(6.0)), _sel(grey, _ZERO, s), l_], -1)


def _hsl_to_rgb(c):
    """util/color.h ``hsl_to_rgb`` of float32 (K, 3)."""
    h, s, l_ = c[..., 0], c[..., 1], c[..., 2]
    six = F32(6.0)
    nr = _clamp(np.abs(_fma(h, six, F32(-3.0))) - _ONE, _ZERO, _ONE)
    ng = _clamp(F32(2.0) - np.abs(_fma(h, six, F32(-2.0))), _ZERO, _ONE)
    nb = _clamp(F32(2.0) - np.abs(_fma(h, six, F32(-4.0))), _ZERO, _ONE)
    chroma = (_ONE - np.abs(F32(2.0) * l_ - _ONE)) * s
    return np.stack([_fma(n - F32(0.5), chroma, l_) for n in (nr, ng, nb)], -1)


#: mode -> (separate, combine) of float32 (K, 3) (``svm_separate_color``,
#: ``svm_combine_color``); HSV is color_ops' (util/color.h rgb_to_hsv,
#: hsv_to_rgb), float32 in, float32 out.
_COLOR_MODES = {
    "RGB": (lambda c: c, lambda c: c),
    "HSV": (color_ops.rgb_to_hsv, color_ops.hsv_to_rgb),
    "HSL": (_rgb_to_hsl, _hsl_to_rgb),
}


def _vec3(x) -> np.ndarray:
    """float32 (..., 3) of a vector input."""
    x = _f(x)
    return np.broadcast_to(x, np.broadcast_shapes(x.shape, (3,)))


def separate_color(mode: str, c) -> np.ndarray:
    """(K, 3) float64 the Separate Color node's three outputs (Red/Green/Blue,
    Hue/Saturation/Value or Hue/Saturation/Lightness by ``mode``) of colours
    c (K, 3) (``svm_separate_color``)."""
    with np.errstate(all="ignore"):
        return np.asarray(_COLOR_MODES[mode][0](_vec3(c)), F32).astype(np.float64)


def combine_color(mode: str, x, y, z) -> np.ndarray:
    """(K, 3) float64 the Combine Color node's Color of its three inputs
    (each broadcastable to (K,)) read in ``mode`` (``svm_combine_color``)."""
    c = np.stack(np.broadcast_arrays(_f(x), _f(y), _f(z)), -1)
    with np.errstate(all="ignore"):
        return np.asarray(_COLOR_MODES[mode][1](c), F32).astype(np.float64)


# ------------------------------------------------------------------- Mix

def mix_float(t, a, b, clamp_factor=True) -> np.ndarray:
    """(K,) float64 the Mix node's Result for data type FLOAT
    (``svm_node_mix_float``): a (1 - t) + b t, t saturated first when the
    node clamps its factor; inputs broadcastable to (K,)."""
    t, a, b = np.broadcast_arrays(_f(t), _f(a), _f(b))
    if clamp_factor:
        t = _clamp(t, _ZERO, _ONE)
    return _fma(a, _ONE - t, b * t).astype(np.float64)


def mix_vector(t, a, b, clamp_factor=True, factor_mode=None) -> np.ndarray:
    """(K, 3) float64 the Mix node's Result for data type VECTOR: a (1 - t) +
    b t per component, t saturated first when the node clamps its factor.
    ``factor_mode`` the node's: UNIFORM one factor a point, t broadcastable
    to (K,) (``svm_node_mix_vector``), NON_UNIFORM one per component, t
    broadcastable to (K, 3) (``svm_node_mix_vector_non_uniform``); None
    tells them by t's dimensions (0 or 1: uniform, 2: non-uniform)."""
    t = _f(t)
    if factor_mode is None:
        factor_mode = "UNIFORM" if t.ndim < 2 else "NON_UNIFORM"
    if factor_mode == "UNIFORM":
        t = t[..., None]
    elif factor_mode != "NON_UNIFORM":
        raise ValueError(f"unknown Mix factor mode {factor_mode!r}")
    a, b = _vec3(a), _vec3(b)
    if clamp_factor:
        t = _clamp(t, _ZERO, _ONE)
    return np.asarray(a * (_ONE - t) + b * t, F32).astype(np.float64)


# ----------------------------------------------------------- Vector Rotate

VECTOR_ROTATE_TYPES = ("AXIS_ANGLE", "X_AXIS", "Y_AXIS", "Z_AXIS", "EULER_XYZ")


def _euler_rows(e):
    """(K, 3, 3) float32 Cycles' ``euler_to_transform`` (util/transform.h)
    of XYZ Euler angles e (K, 3): its rows."""
    c, s = np.cos(e), np.sin(e)
    c, s = np.asarray(c, F32), np.asarray(s, F32)
    cx, cy, cz, sx, sy, sz = c[..., 0], c[..., 1], c[..., 2], s[..., 0], s[..., 1], s[..., 2]
    rows = np.stack([
        np.stack([cy * cz, sy * sx * cz - cx * sz, sy * cx * cz + sx * sz], -1),
        np.stack([cy * sz, sy * sx * sz + cx * cz, sy * cx * sz - sx * cz], -1),
        np.stack([-sy, cy * sx, cy * cx], -1)], -2)
    return rows.astype(F32)


def _rotate_around_axis(p, axis, angle):
    """Cycles' ``rotate_around_axis`` (util/math_float3.h): p (K, 3) turned
    by angle (K,) about the unit axis (K, 3), Rodrigues' matrix term by term."""
    c = np.asarray(np.cos(angle), F32)[..., None]
    s = np.asarray(np.sin(angle), F32)[..., None]
    x, y, z = axis[..., 0:1], axis[..., 1:2], axis[..., 2:3]
    px, py, pz = p[..., 0:1], p[..., 1:2], p[..., 2:3]
    k = _ONE - c
    r = np.concatenate([
        ((c + k * x * x) * px) + ((k * x * y - z * s) * py) + ((k * x * z + y * s) * pz),
        ((k * x * y + z * s) * px) + ((c + k * y * y) * py) + ((k * y * z - x * s) * pz),
        ((k * x * z - y * s) * px) + ((k * y * z + x * s) * py) + ((c + k * z * z) * pz)], -1)
    return r.astype(F32)


def vector_rotate(rotate_type: str, invert: bool, vector, center=0.0, axis=(0.0, 0.0, 1.0),
                  angle=0.0, rotation=0.0) -> np.ndarray:
    """(K, 3) float64 the Vector Rotate node (``svm_node_vector_rotate``):
    vector - center turned about center, by the XYZ Euler ``rotation`` (its
    transpose with ``invert``), or by ``angle`` (negated with ``invert``)
    about the X, Y or Z axis or the normalised ``axis`` (the vector itself
    when that axis is zero)."""
    v, c = _vec3(vector), _vec3(center)
    v, c = np.broadcast_arrays(v, c)
    if rotate_type == "EULER_XYZ":
        R = _euler_rows(np.broadcast_to(_vec3(rotation), v.shape))
        d = v - c
        out = (np.einsum("kji,kj->ki", R, d) if invert else np.einsum("kij,kj->ki", R, d))
        return (np.asarray(out, F32) + c).astype(np.float64)
    if rotate_type not in VECTOR_ROTATE_TYPES:
        raise ValueError(f"unknown Vector Rotate type {rotate_type!r}")
    if rotate_type == "AXIS_ANGLE":
        a = np.broadcast_to(_vec3(axis), v.shape)
    else:
        a = np.zeros(v.shape, F32)
        a[..., "XYZ".index(rotate_type[0])] = _ONE
    length = np.sqrt(_dot(a, a)).astype(F32)
    ang = np.broadcast_to(_f(angle), v.shape[:-1])
    ang = -ang if invert else ang
    safe = np.where(length != _ZERO, length, _ONE)[..., None]
    out = _rotate_around_axis(v - c, (a / safe).astype(F32), ang) + c
    return np.where((length != _ZERO)[..., None], out, v).astype(np.float64)


# ---------------------------------------------------------- Vector Transform

def vector_transform(kind: str, src: str, dst: str, v, axes, location, camera) -> np.ndarray:
    """(K, 3) float64 the Vector Transform node (``svm_node_vector_transform``)
    of v (K, 3), ``kind`` 'POINT', 'VECTOR' or 'NORMAL', from space ``src``
    to ``dst`` ('WORLD', 'OBJECT', 'CAMERA'): axes (K, 3, 3) the object's
    matrix (columns: its axes in the world), location (K, 3) its origin;
    camera (C (3, 3), o (3,)) Cycles' camera-to-world rotation (camera z
    along the view) and position.  Points move, vectors turn, normals go
    by the inverse transpose and are normalised; the object step is a
    world step taken through the object's matrix, as Cycles chains them."""
    v = np.asarray(v, np.float64)
    A = np.asarray(axes, np.float64)
    t = np.asarray(location, np.float64)
    C, o = (np.asarray(x, np.float64) for x in camera)
    point, normal = kind == "POINT", kind == "NORMAL"

    def to_world_from_object(x):
        if normal:
            return unit_rows(np.einsum("kji,kj->ki", np.linalg.inv(A), x))
        y = np.einsum("kij,kj->ki", A, x)
        return y + t if point else y

    def to_object_from_world(x):
        if normal:
            return unit_rows(np.einsum("kji,kj->ki", A, x))
        return np.einsum("kij,kj->ki", np.linalg.inv(A), x - t if point else x)

    def to_camera_from_world(x):
        y = (x - o if point else x) @ C
        return unit_rows(y) if normal else y

    def to_world_from_camera(x):
        y = x @ C.T + (o if point else 0.0)
        return unit_rows(y) if normal else y

    if src == dst:
        return v
    if src == "OBJECT":
        v = to_world_from_object(v)
    elif src == "CAMERA":
        v = to_world_from_camera(v)
    if dst == "OBJECT":
        return to_object_from_world(v)
    if dst == "CAMERA":
        return to_camera_from_world(v)
    return v


# ------------------------------------------------- Float Curve, Color Ramp alpha

def float_curve(fac, value, table, min_x: float, range_x: float,
                extrapolate: bool) -> np.ndarray:
    """(K,) float64 the Float Curve node (``svm_node_curve``): value through
    the curve tabulated at table (N,) over [min_x, min_x + range_x]
    (``float_ramp_lookup``, linear, continued by the end slopes when the
    curve extrapolates), mixed with value by fac."""
    value = np.asarray(value, np.float64)
    col = np.repeat(np.asarray(table, np.float64)[:, None], 3, axis=1)
    out = color_ops.curves(np.repeat(value[..., None], 3, axis=-1), col, min_x, range_x,
                           extrapolate, 1.0)[..., 0]
    fac = np.asarray(fac, np.float64)
    return (1.0 - fac) * value + fac * out


def ramp_alpha(fac, table, interpolate: bool) -> np.ndarray:
    """(K,) float64 a Color Ramp's Alpha (``svm_node_rgb_ramp``): the ramp's
    alpha, tabulated at table (N,), at fac (``rgb_ramp_lookup``)."""
    col = np.repeat(np.asarray(table, np.float64)[:, None], 3, axis=1)
    return color_ops.ramp(np.asarray(fac, np.float64), col, interpolate)[..., 0]


# ------------------------------------------------------------ conversions

SOCKET_KINDS = ("VALUE", "VECTOR", "RGBA")



def to_float(x, kind: str) -> np.ndarray:
    """(K,) float64 an output of socket type ``kind`` ('VALUE', 'VECTOR',
    'RGBA') read by a float input (``svm_node_convert``): a colour's
    luminance (NODE_CONVERT_CF, ``linear_rgb_to_gray``: dot with
    :data:`RGB_TO_Y`), a vector's average
    (NODE_CONVERT_VF, (x + y + z) * (1/3) in float32), a float itself."""
    if kind == "VALUE":
        return np.asarray(x, np.float64)
    if kind == "RGBA":
        return _dot(_vec3(x), RGB_TO_Y).astype(np.float64)
    if kind != "VECTOR":
        raise ValueError(f"unknown socket kind {kind!r}")
    v = _vec3(x)
    return (((v[..., 0] + v[..., 1]) + v[..., 2]) * (_ONE / F32(3.0))).astype(np.float64)


def to_vec(x) -> np.ndarray:
    """(K, 3) float64 a float output read by a vector or colour input
    (NODE_CONVERT_FV): (f, f, f)."""
    x = np.asarray(x, np.float64)
    return np.repeat(x[..., None], 3, axis=-1)


# -- view-dependent inputs: Fresnel, Layer Weight ------------------------------

def fresnel_dielectric_cos(cosi, eta) -> np.ndarray:
    """Cycles' ``fresnel_dielectric_cos``: the unpolarised reflectance of a
    dielectric interface of relative IOR eta at |cos| of incidence cosi,
    without the refracted direction; 1 under total internal reflection."""
    c = np.abs(np.asarray(cosi, np.float64))
    eta = np.broadcast_to(np.asarray(eta, np.float64), c.shape)
    g = eta * eta - 1.0 + c * c
    out = np.ones(c.shape)
    m = g > 0
    gs, cm = np.sqrt(g[m]), c[m]
    A = (gs - cm) / (gs + cm)
    B = (cm * (gs + cm) - 1.0) / (cm * (gs - cm) + 1.0)
    out[m] = 0.5 * A * A * (1.0 + B * B)
    return out


def fresnel(cosi, ior) -> np.ndarray:
    """The Fresnel node's Fac (Cycles' ``svm_node_fresnel``) on a front face:
    eta = max(IOR, 1e-5)."""
    return fresnel_dielectric_cos(cosi, np.maximum(np.asarray(ior, np.float64), 1e-5))


def layer_weight(cosi, blend, output: str) -> np.ndarray:
    """The Layer Weight node's output (Cycles' ``svm_node_layer_weight``) on a
    front face: 'Fresnel', the dielectric Fresnel of IOR 1 / max(1 - Blend,
    1e-5); 'Facing', 1 - |cos|^b with b = 2 Blend below 0.5 and
    0.5 / (1 - Blend) above (Blend clamped to [0, 1 - 1e-5]; b = 1 at 0.5)."""
    c = np.abs(np.asarray(cosi, np.float64))
    blend = np.broadcast_to(np.asarray(blend, np.float64), c.shape)
    if output == "Fresnel":
        return fresnel_dielectric_cos(c, 1.0 / np.maximum(1.0 - blend, 1e-5))
    b = np.clip(blend, 0.0, 1.0 - 1e-5)
    b = np.where(b < 0.5, 2.0 * b, 0.5 / (1.0 - b))
    return 1.0 - np.where(blend != 0.5, c ** b, c)
