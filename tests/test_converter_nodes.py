"""Vector Rotate, Float Curve, a Color Ramp's Alpha, Blackbody, Wavelength
and RGB to BW (core/scene/node_math.py, core/spectrum.py, the exporter's
tables in addon/export.py) against Cycles, pixel by pixel.

The cases are tests/test_node_math.py's: each node's inputs are affine in
the pixel's place in its 16 x 16 tile, built by Cycles from the exact pixel
centres, and its output read back from a one-sample render through a tiny
Box filter (tests/procedural_cycles.py ``tiled_values``).  Float Curve and
Color Ramp cases read their tables from the very nodes Cycles rendered,
through the exporter's ``float_curve_params`` and ``ramp_alpha_params``.
The error is test_node_math's |ours - Cycles| / max(1, |Cycles|).
"""
from __future__ import annotations

import numpy as np
import pytest

from core import spectrum
from core.scene import color_ops, node_math
from test_node_math import COLOUR, Case, Lin, U, V, UV, check, run

pytest.importorskip("bpy")

VEC = (U(-2, 0.25), V(-1.5, 0.1875), UV(-1, 0.0625, 0.0625))
CENTRE = (0.25, -0.5, 0.125)
ROTATION = (U(-3, 0.375), V(-2, 0.25), UV(-1, 0.125, 0.125))
ANGLE = UV(-6, 0.75, 0.046875)


def rotate_case(kind, invert, axis=(0.5, -1.0, 2.0)):
    def build(g):
        ins = {"Vector": g.vector(VEC), "Center": CENTRE, "Axis": axis, "Angle": g.scalar(ANGLE),
               "Rotation": g.vector(ROTATION)}
        return g.node("ShaderNodeVectorRotate", {"rotation_type": kind, "invert": invert}, ins)

    def ours(val):
        return node_math.vector_rotate(kind, invert, val(VEC), CENTRE, axis, val(ANGLE),
                                       val(ROTATION))
    return Case(f"Vector Rotate {kind} invert={invert} axis={axis}", build, ours, False, kind)


ROTATE_CASES = [rotate_case(k, inv) for k in node_math.VECTOR_ROTATE_TYPES
                for inv in (False, True)] + [rotate_case("AXIS_ANGLE", False, (0.0, 0.0, 0.0))]


def _curve_node(g, extend, fac, value):
    nd = g.nodes.new("ShaderNodeFloatCurve")
    cv = nd.mapping.curves[0]
    cv.points[0].location = (-0.25, 0.1)
    cv.points[1].location = (1.25, 0.9)
    cv.points.new(0.4, 0.75)
    cv.points.new(0.8, 0.2)
    nd.mapping.extend = extend
    nd.mapping.update()
    for name, x in (("Factor", fac), ("Value", value)):
        sock = nd.inputs[name]
        x = g.scalar(x)
        if isinstance(x, float):
            sock.default_value = x
        else:
            g.links.new(x, sock)
    return nd


def curve_case(extend, fac, value=UV(-1, 0.125, 0.0078125)):
    held = {}

    def build(g):
        held["node"] = _curve_node(g, extend, fac, value)
        return held["node"].outputs[0]

    def ours(val):
        from fppm.addon.export import float_curve_params
        return node_math.float_curve(val(fac), val(value), *float_curve_params(held["node"]))
    return Case(f"Float Curve {extend} fac={fac}", build, ours, True, "curve " + extend)


def ramp_case(interpolation, fac=UV(-0.25, 0.09375, 0.00390625)):
    held = {}

    def build(g):
        nd = g.nodes.new("ShaderNodeValToRGB")
        cr = nd.color_ramp
        cr.interpolation = interpolation
        cr.elements[0].color = (0.2, 0.4, 0.6, 0.9)
        cr.elements[0].position = 0.1
        cr.elements[1].color = (0.8, 0.1, 0.3, 0.05)
        cr.elements[1].position = 0.85
        el = cr.elements.new(0.5)
        el.color = (0.5, 0.5, 0.1, 0.6)
        g.links.new(g.scalar(fac), nd.inputs["Fac"])
        held["node"] = nd
        return nd.outputs["Alpha"]

    def ours(val):
        from fppm.addon.export import ramp_alpha_params
        return node_math.ramp_alpha(val(fac), *ramp_alpha_params(held["node"]))
    return Case(f"Color Ramp Alpha {interpolation}", build, ours, True, "ramp " + interpolation)


CURVE_CASES = [curve_case("HORIZONTAL", 1.0), curve_case("EXTRAPOLATED", 1.0),
               curve_case("EXTRAPOLATED", U(-0.25, 0.09375)),
               ramp_case("LINEAR"), ramp_case("CONSTANT"), ramp_case("EASE")]

#: Temperatures 500 .. 14000 K, past both ends of Cycles' fit (800, 12000 K).
KELVIN = Lin(500.0, 50.0, 850.0)
#: Wavelengths 370 .. 786 nm, past both ends of the table (380, 780 nm).
NM = Lin(370.0, 0.5, 26.0)


def spectrum_case(kind, spec):
    def build(g):
        node = {"blackbody": "ShaderNodeBlackbody", "wavelength": "ShaderNodeWavelength"}[kind]
        return g.node(node, {}, [g.scalar(spec)])

    def ours(val):
        if kind == "blackbody":
            return np.maximum(spectrum.blackbody_rec709(val(spec)), 0.0)
        return spectrum.wavelength_rec709(val(spec))
    return Case(f"{kind} ({spec})", build, ours, False, kind)


def grey_case(colour):
    def build(g):
        src = g.node("ShaderNodeCombineColor", {"mode": "RGB"}, [g.scalar(s) for s in colour])
        return g.node("ShaderNodeRGBToBW", {}, [src])

    def ours(val):
        return color_ops.gray(val(colour))
    return Case(f"RGB to BW ({colour})", build, ours, True, "rgb to bw")


#: Colour nodes' float inputs fed per point, by node: (idname, [(input, spec)]).
_FACTORS = {
    "HUE_SAT": ("ShaderNodeHueSaturation", [("Hue", U(-0.25, 0.09375)), ("Saturation", V(0, 0.125)),
                                            ("Value", UV(0.5, 0.0625, 0.03125)),
                                            ("Fac", UV(0.125, 0.03125, 0.03125))]),
    "BRIGHTCONTRAST": ("ShaderNodeBrightContrast", [("Bright", U(-0.5, 0.0625)),
                                                    ("Contrast", V(-0.75, 0.125))]),
    "GAMMA": ("ShaderNodeGamma", [("Gamma", UV(0.125, 0.125, 0.0625))]),
    "INVERT": ("ShaderNodeInvert", [("Fac", UV(-0.25, 0.0625, 0.03125))]),
    "CURVE_RGB": ("ShaderNodeRGBCurve", [("Fac", UV(-0.25, 0.0625, 0.03125))]),
}


def factor_case(kind, colour=COLOUR):
    """A colour node whose float inputs nodes feed (the graph's "color_at"
    op), on a colour input too."""
    idname, ins = _FACTORS[kind]
    held = {}

    def build(g):
        nd = g.nodes.new(idname)
        if kind == "CURVE_RGB":
            cv = nd.mapping.curves[3]
            cv.points.new(0.3, 0.6)
            nd.mapping.curves[0].points.new(0.5, 0.2)
            nd.mapping.update()
        src = g.node("ShaderNodeCombineColor", {"mode": "RGB"}, [g.scalar(x) for x in colour])
        g.links.new(src, nd.inputs["Color"])
        for name, spec in ins:
            g.links.new(g.scalar(spec), nd.inputs[name])
        held["node"] = nd
        return nd.outputs[0]

    def ours(val):
        from core.scene import shader_graph
        from fppm.addon.export import curves_op
        params = (kind,) + (curves_op(held["node"], 1.0)[1:5] if kind == "CURVE_RGB" else ())
        return shader_graph.OPS["color_at"]([val(colour)] + [val(x) for _, x in ins], params)
    return Case(f"{kind} with linked factors", build, ours, False, kind)


FACTOR_CASES = [factor_case(k) for k in _FACTORS]
BLACKBODY, WAVELENGTH = spectrum_case("blackbody", KELVIN), spectrum_case("wavelength", NM)
EVERY = (ROTATE_CASES + CURVE_CASES + FACTOR_CASES
         + [BLACKBODY, WAVELENGTH, grey_case(COLOUR)])


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """``results(cases)`` from one render of every case of the module."""
    done = {}

    def results(cases):
        if not done:
            done.update((id(r[0]), r) for r in run(EVERY, tmp_path_factory.mktemp("convert")))
        return [done[id(c)] for c in cases]
    return results


def test_vector_rotate_matches_cycles(rendered):
    """Every rotation type, inverted or not, and a zero axis (the vector
    passes).  Measured: median 0, p99 1.8e-7, largest 2.4e-7 (float32
    sines and cosines, an ulp or two)."""
    check(rendered(ROTATE_CASES), "vector rotate", 1e-7, 1e-6, 2e-6)


def test_float_curve_and_ramp_alpha_match_cycles(rendered):
    """A Float Curve (four points, extended or extrapolated beyond them,
    factor 1 or a ramp of factors) and a Color Ramp's Alpha (linear,
    constant, ease), their tables read from the rendered nodes by the
    exporter.  Measured: largest 1.0e-7 (an ulp).  With the tables at 256
    positions i / 255, as the exporter made them before, the curve was
    2.8e-4 off and the constant ramp's step a table entry late."""
    check(rendered(CURVE_CASES), "float curve, ramp alpha", 1e-7, 5e-7, 1e-6)


def test_blackbody_matches_cycles(rendered):
    """Planck's spectrum through the CIE 1931 observer (core/spectrum.py)
    against Cycles' piecewise fit of the same curve, 500 to 14000 K.
    Measured: median 1.6e-4, largest 1.7e-3 of the largest channel (at
    800 K and below, where red is 5.4)."""
    (case, ours, theirs), = rendered([BLACKBODY])
    rel = np.abs(ours - theirs) / np.maximum(np.abs(theirs).max(axis=1, keepdims=True), 1e-6)
    print(f"blackbody: median {np.median(rel):.2g}, largest {rel.max():.2g}")
    assert np.median(rel) < 1.5e-3 and rel.max() < 5e-3


def test_wavelength_matches_cycles(rendered):
    """The matching functions at four decimals, 370 to 786 nm.  Measured:
    median 0, p99 3.2e-5, largest 1.0e-4 (a few of Cycles' rows differ
    from the CIE 1931 table's in the fourth decimal)."""
    check(rendered([WAVELENGTH]), "wavelength", 1e-7, 1e-4, 2e-4)


def test_rgb_to_bw_matches_cycles(rendered):
    """A colour's luminance (Cycles' linear_rgb_to_gray).  Measured: largest
    7e-8."""
    check(rendered([rgb for rgb in EVERY if rgb.op == "rgb to bw"]), "rgb to bw")


def test_colour_nodes_with_linked_factors_match_cycles(rendered):
    """Hue/Saturation/Value, Brightness/Contrast, Gamma, Invert and RGB
    Curves with every float input fed per point.  Measured: median 7e-9,
    p99 2.7e-7, largest 3.7e-7 (HSV: an ulp or two)."""
    check(rendered(FACTOR_CASES), "colour nodes, linked factors", 1e-7, 5e-7, 1e-6)


def test_vector_transform_closed_forms():
    """node_math.vector_transform: object <-> world <-> camera round trips
    return the input; a transformed normal stays perpendicular to a
    transformed tangent; the camera's own position is camera-space 0, a
    point ahead of it has z > 0 (Cycles' camera z along the view)."""
    rng = np.random.default_rng(7)
    K = 50
    A = rng.normal(size=(K, 3, 3)) + 2.0 * np.eye(3)
    t = rng.normal(size=(K, 3))
    th = 0.7
    R = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0, 0, 1]])
    C, o = R * np.array([1.0, 1.0, -1.0]), np.array([0.5, -1.0, 3.0])
    v = rng.normal(size=(K, 3))
    f = node_math.vector_transform
    for kind in ("POINT", "VECTOR", "NORMAL"):
        for a, b in (("OBJECT", "WORLD"), ("WORLD", "CAMERA"), ("OBJECT", "CAMERA")):
            x = v if kind != "NORMAL" else v / np.linalg.norm(v, axis=1, keepdims=True)
            back = f(kind, b, a, f(kind, a, b, x, A, t, (C, o)), A, t, (C, o))
            np.testing.assert_allclose(back, x, atol=1e-9, err_msg=f"{kind} {a} {b}")
    n, tan = np.cross(v, rng.normal(size=(K, 3))), v
    nw = f("NORMAL", "OBJECT", "WORLD", n, A, t, (C, o))
    tw = f("VECTOR", "OBJECT", "WORLD", tan, A, t, (C, o))
    assert np.abs(np.einsum("ki,ki->k", nw, tw)).max() < 1e-9
    cam = f("POINT", "WORLD", "CAMERA", np.stack([o, o - 2.0 * R[:, 2]]), A[:2], t[:2], (C, o))
    np.testing.assert_allclose(cam[0], 0.0, atol=1e-12)
    assert cam[1, 2] == pytest.approx(2.0)
