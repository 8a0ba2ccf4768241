"""core/scene/node_math.py's converter nodes against Cycles, pixel by pixel.

Each case is one node of Cycles' (Math, Vector Math, Map Range, Clamp,
Separate / Combine Color, Mix of type Float or Vector, a socket conversion)
whose inputs are affine in the pixel's place in its tile: an input ``Lin(lo,
su, sv)`` is lo + su ku + sv kv, ku, kv = 0 .. 15 the pixel's column and row
within its 16 x 16 tile, so that a case reads a grid of 256 input pairs that
walks across the op's special places (a zero divisor, negative bases and
logarithms, arcsines beyond 1, equal operands, x.5 before a rounding,
reversed ranges, ...).  Cycles builds them with Math nodes from the exact
pixel centres (tests/procedural_cycles.py ``tiled_values``); lo, su and sv
have few bits, so every input is the same float32 number in Cycles and here
(one float32 rounding at most, which :func:`_values` makes too).  A Vector
input is three such components (Combine XYZ), a float case shares its tile
with two others (Combine XYZ of three floats).

Agreement is measured as |ours - Cycles| / max(1, |Cycles|) over a case's
pixels and channels (absolute below 1, relative above: float32 rounding of
values from 1e-3 to 1e4 alike): its median, 99th percentile and largest.
Every op agrees to the bit but for an ulp in a few transcendentals (glibc's
float functions against the correctly rounded ones) and in HSV (color_ops
divides by 6 where Cycles multiplies by 1/6, and does not fuse its
multiply-adds).  Cycles' AVX2 kernel fuses a product and a sum within one C
expression, which node_math ports: BIG inputs (large quotients by 0.1)
show it, as Floored Modulo without the fusion is off by 1e-4.
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
import pytest

from core.scene import node_math
from procedural_cycles import tiled_values

RES, TILES = 128, 8
#: Pixels along a tile's side: ku, kv = 0 .. S - 1.
S = RES // TILES


class Lin(NamedTuple):
    """A float input lo + su ku + sv kv (ku, kv the pixel's column and row
    in its tile)."""
    lo: float
    su: float = 0.0
    sv: float = 0.0


def U(lo, step):
    return Lin(lo, step, 0.0)


def V(lo, step):
    return Lin(lo, 0.0, step)


UV = Lin


class Case(NamedTuple):
    """A node: ``build(graph) -> output socket`` in Cycles, ``ours(val) ->``
    (n,) float (a float case) or (n, 3) float64, with ``val(spec)`` an
    input's values."""
    label: str
    build: Callable
    ours: Callable
    scalar: bool
    op: str = ""


# ------------------------------------------------------------------ inputs

def _values(spec, u, v):
    """(n,) float64 (or (n, 3) for a tuple of specs) the input as Cycles has
    it: c0 = lo - (su + sv) / 2, then + (su S) u, + (sv S) v, each sum
    rounded to float32 (the products are exact)."""
    if isinstance(spec, tuple) and not isinstance(spec, Lin):
        return np.stack([_values(s, u, v) for s in spec], -1)
    if not isinstance(spec, Lin):
        return np.full(u.shape, float(np.float32(spec)))
    x = np.full(u.shape, float(np.float32(spec.lo - (spec.su + spec.sv) / 2)))
    for t, m in ((u, spec.su), (v, spec.sv)):
        if m:
            x = (t * float(np.float32(m * S)) + x).astype(np.float32).astype(np.float64)
    return x


class Graph:
    """Node building in the material: inputs from (u, v), shared by spec."""

    def __init__(self, nodes, links, u, v):
        self.nodes, self.links, self.uv, self.cache = nodes, links, (u, v), {}

    def node(self, idname, props, inputs, output=0):
        """A new node with ``props`` set and ``inputs`` (a list by index or a
        dict by identifier: floats, tuples or sockets) given; its output
        (by index or identifier)."""
        nd = self.nodes.new(idname)
        for key, value in props.items():
            setattr(nd, key, value)
        items = inputs.items() if isinstance(inputs, dict) else enumerate(inputs)
        for key, value in items:
            if isinstance(key, int):
                sock = nd.inputs[key]
            else:
                sock = next(s for s in nd.inputs if s.identifier == key)
            if isinstance(value, (int, float)):
                sock.default_value = value
            elif isinstance(value, tuple):
                sock.default_value = value + (1.0,) * (len(sock.default_value) - len(value))
            else:
                self.links.new(value, sock)
        if isinstance(output, int):
            return nd.outputs[output]
        return next(s for s in nd.outputs if s.identifier == output)

    def scalar(self, spec):
        """A float input: a socket, or a float for a constant."""
        if not isinstance(spec, Lin):
            return float(spec)
        if spec not in self.cache:
            x = spec.lo - (spec.su + spec.sv) / 2
            for t, m in zip(self.uv, (spec.su, spec.sv)):
                if m:
                    x = self.node("ShaderNodeMath", {"operation": "MULTIPLY_ADD"},
                                  [t, m * S, x])
            self.cache[spec] = x
        return self.cache[spec]

    def vector(self, spec):
        """A vector input (three specs): a Combine XYZ, or a tuple of constants."""
        comps = [self.scalar(s) for s in spec]
        if all(isinstance(c, float) for c in comps):
            return tuple(comps)
        key = ("vector",) + tuple(spec)
        if key not in self.cache:
            self.cache[key] = self.node("ShaderNodeCombineXYZ", {}, comps)
        return self.cache[key]


def _tiles(cases):
    """Cases grouped into tiles: a vector case alone, float cases by three."""
    tiles, floats = [], []
    for case in cases:
        if case.scalar:
            floats.append(case)
            if len(floats) == 3:
                tiles.append(floats)
                floats = []
        else:
            tiles.append([case])
    return tiles + ([floats] if floats else [])


def _tile_build(tile):
    def build(nodes, links, u, v):
        g = Graph(nodes, links, u, v)
        if not tile[0].scalar:
            return tile[0].build(g)
        return g.node("ShaderNodeCombineXYZ", {}, [c.build(g) for c in tile])
    return build


def run(cases, tmp_path):
    """[(case, ours, Cycles')] each (n,) for a float case, (n, 3) else, in as
    few renders as the tiles need (TILES * TILES a render), by tile."""
    tiles = _tiles(cases)
    out = []
    per = TILES * TILES
    for k in range(0, len(tiles), per):
        chunk = tiles[k:k + per]
        for tile, (img, u, v) in zip(chunk, tiled_values([_tile_build(t) for t in chunk],
                                                         tmp_path, RES, TILES)):
            def val(spec):
                return _values(spec, u, v)
            for j, case in enumerate(tile):
                ours = np.asarray(case.ours(val), np.float64)
                assert np.isfinite(ours).all(), f"{case.label}: the case's values are not finite"
                out.append((case, ours, img[:, j] if case.scalar else img))
    return out


#: Tolerances of :func:`error` (median, 99th percentile, largest over a
#: case's pixels and channels), a few times the largest measured over all
#: the cases (median 0, p99 1.2e-7, largest 1.2e-7: one float32 ulp).
TOL_MEDIAN, TOL_P99, TOL_MAX = 1e-7, 5e-7, 1e-6


def error(ours, theirs):
    """|ours - theirs| / max(1, |theirs|), per pixel and channel."""
    return np.abs(ours - theirs) / np.maximum(1.0, np.abs(theirs))


def check(results, name, tol_median=TOL_MEDIAN, tol_p99=TOL_P99, tol_max=TOL_MAX):
    """Every case's median, 99th percentile and largest :func:`error` within
    the tolerances (the largest sees an op's special pixel: atan2(0, 0), a
    tie of COMPARE, ...); prints the largest of each over the cases."""
    bad, worst = [], np.zeros(3)
    for case, ours, theirs in results:
        e = error(ours, theirs)
        m = np.array([np.median(e), np.percentile(e, 99), e.max()])
        worst = np.maximum(worst, m)
        if not (m <= (tol_median, tol_p99, tol_max)).all():
            k = int(np.argmax(e.reshape(len(ours), -1).max(-1)))
            bad.append(f"{case.label}: median {m[0]:.3g} p99 {m[1]:.3g} max {m[2]:.3g} (at "
                       f"pixel {k}: ours {ours[k]}, Cycles {theirs[k]})")
    print(f"{name}: largest median {worst[0]:.3g}, p99 {worst[1]:.3g}, max {worst[2]:.3g}")
    assert not bad, f"{name}:\n" + "\n".join(bad)


# ------------------------------------------------------------------- Math

def math_case(op, a, b=0.5, c=0.0, use_clamp=False):
    def build(g):
        return g.node("ShaderNodeMath", {"operation": op, "use_clamp": use_clamp},
                      [g.scalar(a), g.scalar(b), g.scalar(c)])

    def ours(val):
        r = node_math.math(op, val(a), val(b), val(c))
        return node_math.saturate(r) if use_clamp else r
    return Case(f"Math {op}{' clamped' if use_clamp else ''} ({a}, {b}, {c})",
                build, ours, True, op)


A, B, BN = U(-4, 0.5), V(-2, 0.25), V(-3, 0.375)   # B is 0 at kv = 8
C = UV(-1, 0.125, 0.0625)
SMALL_U, SMALL_V = U(-2, 0.25), V(-2, 0.25)         # -2 .. 1.75 by quarters
ANGLE = UV(-8, 1, 1 / 16)
BIG = UV(-3000, 377, 1 / 128)                       # large quotients by 0.1

MATH_CASES = [
    math_case("ADD", A, BN), math_case("SUBTRACT", A, BN), math_case("MULTIPLY", A, BN),
    math_case("DIVIDE", A, B), math_case("DIVIDE", BIG, 0.1),
    math_case("MULTIPLY_ADD", A, BN, C), math_case("MULTIPLY_ADD", BIG, 0.1, C),
    math_case("POWER", SMALL_U, SMALL_V), math_case("POWER", U(0.0625, 0.25), V(-3, 0.5)),
    math_case("POWER", U(-3, 0.375), V(-4, 1)),
    math_case("LOGARITHM", U(-1, 0.25), V(-0.5, 0.25)),
    math_case("LOGARITHM", U(0.125, 0.5), 10.0),
    math_case("SQRT", SMALL_U), math_case("INVERSE_SQRT", SMALL_U),
    math_case("ABSOLUTE", A), math_case("EXPONENT", ANGLE),
    math_case("MINIMUM", A, BN), math_case("MAXIMUM", A, BN),
    math_case("LESS_THAN", SMALL_U, SMALL_V), math_case("GREATER_THAN", SMALL_U, SMALL_V),
    math_case("SIGN", SMALL_U),
    math_case("COMPARE", SMALL_U, SMALL_V, UV(-0.25, 1 / 32, 1 / 16)),
    math_case("SMOOTH_MIN", A, BN, UV(-0.5, 0.125, 0.0625)),
    math_case("SMOOTH_MAX", A, BN, UV(-0.5, 0.125, 0.0625)),
    # x.5 exactly, and 0.5 - (2 kv + 1) 2^-25: 1 - 2^-25 rounds up to 1 in float32
    math_case("ROUND", U(-2.5, 0.25)), math_case("ROUND", UV(-1.5, 0.25, -2.0 ** -24)),
    math_case("FLOOR", SMALL_U), math_case("CEIL", SMALL_U), math_case("TRUNC", SMALL_U),
    math_case("FRACT", UV(-2, 0.25, -2.0 ** -22)),
    math_case("MODULO", A, B), math_case("MODULO", BIG, 0.1),
    math_case("FLOORED_MODULO", A, B), math_case("FLOORED_MODULO", BIG, 0.1),
    math_case("WRAP", A, V(-1, 0.25), 0.25),
    math_case("WRAP", UV(-4, 0.5, 0.0625), V(-2, 0.25), UV(0.5, -0.0625, 0.125)),
    math_case("SNAP", A, B), math_case("SNAP", BIG, 0.1),
    math_case("PINGPONG", A, B), math_case("PINGPONG", UV(-30, 3.75, 1 / 16), 0.7),
    math_case("SINE", ANGLE), math_case("COSINE", ANGLE), math_case("TANGENT", ANGLE),
    math_case("SINE", UV(-1000, 133, 1 / 64)),
    math_case("ARCSINE", SMALL_U), math_case("ARCCOSINE", SMALL_U),
    math_case("ARCTANGENT", U(-8, 1)), math_case("ARCTAN2", SMALL_U, SMALL_V),
    math_case("SINH", UV(-4, 0.5, 1 / 32)), math_case("COSH", UV(-4, 0.5, 1 / 32)),
    math_case("TANH", UV(-4, 0.5, 1 / 32)),
    math_case("RADIANS", U(-360, 45)), math_case("DEGREES", A),
    math_case("SUBTRACT", A, BN, use_clamp=True), math_case("SINE", ANGLE, use_clamp=True),
    math_case("DIVIDE", A, B, use_clamp=True),
]


# ------------------------------------------------------------ Vector Math

def vector_math_case(op, a, b=(0.0,) * 3, c=(0.0,) * 3, scale=1.0):
    output = "Value" if op in ("DOT_PRODUCT", "DISTANCE", "LENGTH") else "Vector"

    def build(g):
        return g.node("ShaderNodeVectorMath", {"operation": op},
                      [g.vector(a), g.vector(b), g.vector(c), g.scalar(scale)], output)

    def ours(val):
        vec, value = node_math.vector_math(op, val(a), val(b), val(c), val(scale))
        return value if output == "Value" else vec
    return Case(f"Vector Math {op} ({a}, {b}, {c}, {scale})", build, ours,
                output == "Value", op)


VA = (SMALL_U, SMALL_V, UV(-1, 0.125, 0.0625))
VB = (V(-1.5, 0.25), UV(-2, 0.125, 0.125), U(-1, 0.125))    # each 0 somewhere
VC = (UV(0.5, -0.0625, 0.125), U(-0.75, 0.125), V(1, -0.125))
V0 = (U(-1, 0.125), V(-1, 0.125), 0.0)                       # 0 at ku = kv = 8
VROUND = (U(-2.5, 0.25), V(-1.5, 0.25), UV(-1.5, 0.25, -2.0 ** -24))
VBIG = (BIG, UV(-2000, 255, 1 / 64), V(-700, 93))
VANGLE = (ANGLE, UV(-1000, 133, 1 / 64), V(-4, 0.5))

VECTOR_CASES = [
    vector_math_case("ADD", VA, VB), vector_math_case("SUBTRACT", VA, VB),
    vector_math_case("MULTIPLY", VA, VB), vector_math_case("DIVIDE", VA, VB),
    vector_math_case("MULTIPLY_ADD", VA, VB, VC), vector_math_case("CROSS_PRODUCT", VA, VB),
    vector_math_case("MULTIPLY_ADD", VBIG, (0.1, 0.3, 0.7), VC),
    vector_math_case("CROSS_PRODUCT", VBIG, (0.1, 0.3, 0.7)),
    vector_math_case("PROJECT", VA, VB), vector_math_case("PROJECT", VA, V0),
    vector_math_case("REFLECT", VA, VB), vector_math_case("REFLECT", VA, V0),
    vector_math_case("REFRACT", VA, VB, scale=UV(0.25, 0.125, 0.0625)),
    vector_math_case("REFRACT", VC, V0, scale=UV(-1.5, 0.0625, 0.25)),
    vector_math_case("FACEFORWARD", VA, VB, VC),
    vector_math_case("DOT_PRODUCT", VA, VB), vector_math_case("DISTANCE", VA, VB),
    vector_math_case("LENGTH", VA),
    vector_math_case("SCALE", VA, scale=UV(-2, 0.25, 1 / 32)),
    vector_math_case("NORMALIZE", VA), vector_math_case("NORMALIZE", V0),
    vector_math_case("ABSOLUTE", VA), vector_math_case("POWER", VA, VB),
    vector_math_case("POWER", (U(0.0625, 0.25), U(-3, 0.375), 0.0),
                     (V(-3, 0.5), V(-4, 1), V(-1, 1))),
    vector_math_case("SIGN", VA), vector_math_case("MINIMUM", VA, VB),
    vector_math_case("MAXIMUM", VA, VB), vector_math_case("ROUND", VROUND),
    vector_math_case("FLOOR", VA), vector_math_case("CEIL", VA),
    vector_math_case("FRACTION", VROUND), vector_math_case("MODULO", VA, VB),
    vector_math_case("MODULO", VBIG, (0.1, 0.3, 0.7)),
    vector_math_case("WRAP", VA, VB, VC), vector_math_case("WRAP", VBIG, (0.1, 0.3, 0.7), VC),
    vector_math_case("SNAP", VA, VB), vector_math_case("SNAP", VBIG, (0.1, 0.3, 0.7)),
    vector_math_case("SINE", VANGLE), vector_math_case("COSINE", VANGLE),
    vector_math_case("TANGENT", VANGLE),
]


# ---------------------------------------------------- Map Range and Clamp

def map_range_case(interpolation, value, from_min, from_max, to_min, to_max, steps, clamp):
    vector = isinstance(value, tuple) and not isinstance(value, Lin)
    names = ("From Min", "From Max", "To Min", "To Max", "Steps")
    specs = (from_min, from_max, to_min, to_max, steps)

    def build(g):
        props = {"data_type": "FLOAT_VECTOR" if vector else "FLOAT",
                 "interpolation_type": interpolation, "clamp": clamp}
        if vector:
            ins = {"Vector": g.vector(value)}
            ins.update({n.replace(" ", "_") + "_FLOAT3": g.vector(s)
                        for n, s in zip(names, specs)})
            return g.node("ShaderNodeMapRange", props, ins, "Vector")
        ins = {"Value": g.scalar(value)}
        ins.update({n: g.scalar(s) for n, s in zip(names, specs)})
        return g.node("ShaderNodeMapRange", props, ins, "Result")

    def ours(val):
        fn = node_math.map_range_vector if vector else node_math.map_range
        return fn(interpolation, val(value), *map(val, specs), clamp=clamp)
    return Case(f"Map Range {interpolation} {'vector' if vector else 'float'} clamp={clamp} "
                f"({value}, {specs})", build, ours, not vector,
                f"{'FLOAT_VECTOR' if vector else 'FLOAT'} {interpolation} {clamp}")


def clamp_case(clamp_type, value, lo, hi):
    def build(g):
        return g.node("ShaderNodeClamp", {"clamp_type": clamp_type},
                      [g.scalar(value), g.scalar(lo), g.scalar(hi)])

    def ours(val):
        return node_math.clamp(clamp_type, val(value), val(lo), val(hi))
    return Case(f"Clamp {clamp_type} ({value}, {lo}, {hi})", build, ours, True, clamp_type)


INTERPOLATIONS = node_math.MAP_RANGE_TYPES
X = U(-0.5, 0.125)                       # -0.5 .. 1.375
#: From Max crosses From Min (0.25) at kv = 6: equal there, reversed below.
FROM_MAX = V(-0.5, 0.125)
VX = (X, V(-0.5, 0.125), UV(-0.5, 0.0625, 0.0625))
V_FROM_MIN = (0.25, 0.0, UV(0.75, -0.0625, 0.0))
V_FROM_MAX = (FROM_MAX, 1.0, 0.75)
V_TO_MIN = (-0.5, 1.0, U(0, 0.125))
V_TO_MAX = (2.0, -1.0, 0.5)
V_STEPS = (4.0, V(-2, 1), 3.0)

MAP_RANGE_CASES = [
    map_range_case(t, X, 0.25, FROM_MAX, -0.5, 2.0, 4.0, clamp)
    for t in INTERPOLATIONS for clamp in (False, True)
] + [
    map_range_case("STEPPED", X, 0.0, 1.0, 0.0, 1.0, V(-2, 1), clamp) for clamp in (False, True)
] + [
    map_range_case(t, X, 0.25, FROM_MAX, 3.0, -1.0, 4.0, True) for t in INTERPOLATIONS
] + [
    # From Min == From Max gives 0, which the Clamp moves into To Min .. To Max
    # for the smooth steps too
    map_range_case(t, X, 0.25, FROM_MAX, 0.5, 2.0, 4.0, clamp)
    for t in ("SMOOTHSTEP", "SMOOTHERSTEP") for clamp in (False, True)
] + [
    clamp_case("MINMAX", A, V(-1, 0.25), 0.5), clamp_case("RANGE", A, V(-1, 0.25), 0.5),
    clamp_case("MINMAX", A, -1.0, V(-1.5, 0.25)), clamp_case("RANGE", A, -1.0, V(-1.5, 0.25)),
] + [
    map_range_case(t, VX, V_FROM_MIN, V_FROM_MAX, V_TO_MIN, V_TO_MAX, V_STEPS, clamp)
    for t in INTERPOLATIONS for clamp in (False, True)
]


# ------------------------------------------- Colours, Mix, conversions

def separate_case(mode, colour):
    def build(g):
        sep = g.nodes.new("ShaderNodeSeparateColor")
        sep.mode = mode
        c = g.vector(colour)
        if isinstance(c, tuple):
            sep.inputs[0].default_value = c + (1.0,)
        else:
            g.links.new(c, sep.inputs[0])
        return g.node("ShaderNodeCombineXYZ", {}, list(sep.outputs))

    def ours(val):
        return node_math.separate_color(mode, val(colour))
    return Case(f"Separate Color {mode} ({colour})", build, ours, False, f"separate {mode}")


def combine_case(mode, x, y, z):
    def build(g):
        return g.node("ShaderNodeCombineColor", {"mode": mode},
                      [g.scalar(x), g.scalar(y), g.scalar(z)])

    def ours(val):
        return node_math.combine_color(mode, val(x), val(y), val(z))
    return Case(f"Combine Color {mode} ({x}, {y}, {z})", build, ours, False, f"combine {mode}")


def mix_case(data_type, t, a, b, clamp_factor, non_uniform=False):
    def build(g):
        props = {"data_type": data_type, "clamp_factor": clamp_factor,
                 "factor_mode": "NON_UNIFORM" if non_uniform else "UNIFORM"}
        if data_type == "FLOAT":
            ins = {"Factor_Float": g.scalar(t), "A_Float": g.scalar(a), "B_Float": g.scalar(b)}
            return g.node("ShaderNodeMix", props, ins, "Result_Float")
        ins = {"Factor_Vector" if non_uniform else "Factor_Float":
               g.vector(t) if non_uniform else g.scalar(t),
               "A_Vector": g.vector(a), "B_Vector": g.vector(b)}
        return g.node("ShaderNodeMix", props, ins, "Result_Vector")

    def ours(val):
        if data_type == "FLOAT":
            return node_math.mix_float(val(t), val(a), val(b), clamp_factor)
        return node_math.mix_vector(val(t), val(a), val(b), clamp_factor,
                                    "NON_UNIFORM" if non_uniform else "UNIFORM")
    return Case(f"Mix {data_type}{' non-uniform' if non_uniform else ''} "
                f"clamp={clamp_factor} ({t}, {a}, {b})", build, ours, data_type == "FLOAT")


def convert_case(kind, spec):
    """A colour (Combine Color RGB) or vector (Combine XYZ) read by a float
    input (Math ADD 0.25, which keeps the conversion node)."""
    def build(g):
        if kind == "RGBA":
            src = g.node("ShaderNodeCombineColor", {"mode": "RGB"}, [g.scalar(s) for s in spec])
        else:
            src = g.vector(spec)
        return g.node("ShaderNodeMath", {"operation": "ADD"}, [src, 0.25])

    def ours(val):
        return node_math.math("ADD", node_math.to_float(val(spec), kind), 0.25)
    return Case(f"convert {kind} to float ({spec})", build, ours, True)


#: Colours 0 .. 1; brighter ones (to 1.44) whose largest and smallest
#: channels never add up to 2 (where HSL's saturation divides by 0).
COLOUR = (U(1 / 128, 1 / 16), V(0, 1 / 16), UV(0.0625, 1 / 32, 1 / 32))
NEGATIVE_COLOUR = (U(-0.5, 0.09375), V(-0.25, 0.0625), UV(-0.5, 0.0625, 0.0625))
BRIGHT_COLOUR = (U(0.25 + 1 / 128, 0.0625), V(0.5, 0.0625), UV(0.3125 + 1 / 256, 1 / 32, 1 / 32))
HUE = U(-0.875, 0.125)                   # -0.875 .. 1, 0 and 1 included
SAT = V(0, 5 / 64)                       # 0 .. 1.17
VAL = UV(0.25, 0.0625, 1 / 32)
T = U(-0.5, 0.125)                       # -0.5 .. 1.375
VT = (T, V(-0.25, 0.09375), UV(0, 0.0625, 0.0625))

COLOUR_CASES = [
    separate_case("RGB", COLOUR), separate_case("HSV", COLOUR), separate_case("HSL", COLOUR),
    separate_case("HSV", NEGATIVE_COLOUR), separate_case("HSV", BRIGHT_COLOUR),
    separate_case("HSL", BRIGHT_COLOUR),
    combine_case("RGB", HUE, SAT, VAL), combine_case("HSV", HUE, SAT, VAL),
    combine_case("HSL", HUE, SAT, VAL), combine_case("HSV", U(-0.5, 0.125), V(-0.25, 0.125), A),
    combine_case("HSL", U(-0.5, 0.125), V(-0.25, 0.125), UV(-0.25, 0.125, 0.0625)),
    mix_case("FLOAT", T, V(-2, 0.25), UV(1, 0.125, -0.25), False),
    mix_case("FLOAT", T, V(-2, 0.25), UV(1, 0.125, -0.25), True),
    convert_case("RGBA", COLOUR), convert_case("VECTOR", VA),
    convert_case("RGBA", NEGATIVE_COLOUR),
    mix_case("VECTOR", T, VA, VB, False), mix_case("VECTOR", T, VA, VB, True),
    mix_case("VECTOR", VT, VA, VB, False, True), mix_case("VECTOR", VT, VA, VB, True, True),
]


# ------------------------------------------------------------------ tests

def test_every_operation_has_a_case():
    """The cases cover every Math and Vector Math operation, Map Range
    interpolation (with and without Clamp, both data types), Clamp type and
    colour mode (no render)."""
    ops = {c.op for c in MATH_CASES + VECTOR_CASES + MAP_RANGE_CASES + COLOUR_CASES}
    assert set(node_math.MATH_OPS) <= {c.op for c in MATH_CASES}
    assert set(node_math.VECTOR_MATH_OPS) <= {c.op for c in VECTOR_CASES}
    assert {f"{d} {t} {c}" for d in ("FLOAT", "FLOAT_VECTOR")
            for t in node_math.MAP_RANGE_TYPES for c in (False, True)} <= ops
    assert {"MINMAX", "RANGE"} <= ops
    assert {f"{k} {m}" for k in ("separate", "combine") for m in ("RGB", "HSV", "HSL")} <= ops


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """``results(cases)``: :func:`run`'s results of ``cases``, every case of
    the module rendered on the first call (146 cases in 89 tiles: two
    renders)."""
    done = {}

    def results(cases):
        if not done:
            every = MATH_CASES + VECTOR_CASES + MAP_RANGE_CASES + COLOUR_CASES
            done.update((id(r[0]), r) for r in run(every, tmp_path_factory.mktemp("node_math")))
        return [done[id(c)] for c in cases]
    return results


def test_math_matches_cycles(rendered):
    """Every Math operation (and its Clamp), on inputs that cross its special
    places, 56 cases.  Measured: median 0, p99 1.2e-7, largest 1.2e-7
    (Sinh, Cosh, Arctan2, Arccosine, Tangent: an ulp); the rest exact."""
    check(rendered(MATH_CASES), "math")


def test_vector_math_matches_cycles(rendered):
    """Every Vector Math operation, 40 cases.  Measured: median 0, p99
    6.6e-8, largest 1.1e-7 (Sine, Cosine, Tangent: an ulp); the rest exact."""
    check(rendered(VECTOR_CASES), "vector math")


def test_map_range_and_clamp_match_cycles(rendered):
    """Map Range FLOAT and FLOAT_VECTOR, every interpolation with and without
    Clamp, equal and reversed ranges, Steps <= 0; Clamp MINMAX and RANGE with
    crossed bounds: 30 cases.  Measured: all exact."""
    check(rendered(MAP_RANGE_CASES), "map range, clamp")


def test_colour_mix_and_conversions_match_cycles(rendered):
    """Separate and Combine Color in every mode, Mix FLOAT and VECTOR
    (uniform and non-uniform factor, clamped or not) and the colour- and
    vector-to-float conversions, 20 cases.  Measured: median 0, p99 6e-8,
    largest 6e-8 (separating HSV: an ulp); the rest exact."""
    check(rendered(COLOUR_CASES), "colour, mix, conversions")
