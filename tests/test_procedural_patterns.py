"""Cycles' Checker, Gradient, Magic and Brick Texture nodes
(core/scene/patterns.py, through core/scene/procedural.py's ``evaluate``)
against Cycles, pixel by pixel.

One Cycles render (tests/procedural_cycles.py: a plane's Object coordinates
through a Mapping node with a rotation and an off-centre location, so that z
and negative coordinates are read) shows up to 15 cases, one a 16 x 16 tile:
:func:`mosaic` builds each case's node from the very params dict given to
``evaluate`` and picks the tile's node by Math and Mix nodes reading the
plane's Object x and y (a Mix of factor exactly 0 or 1 passes a colour
unchanged).  Each case's tile is compared with ``evaluate`` at the tile's
texture-space points: the median and 99th percentile of |ours - Cycles| over
its pixels' channels, and the fraction of pixels off by more than DIFFERS.

Cycles' one sample through the 0.01-pixel box filter lands at the same
offset from every pixel centre: (+4.9e-4, +4.9e-4) pixel, 1.5e-5 object
units at 64 x 64 (measured with Linear Gradients).  The last tile shows the
Mapping node's output itself, and :func:`mosaic` moves every point by that
tile's median difference from the pixel centres' points, so the points are
where Cycles read; what is left is float32 rounding (Cycles' Mapping and
ours differ in the last bits) times each texture's slope.
"""
from __future__ import annotations

import numpy as np

from core.scene import procedural
from procedural_cycles import add_node, agreement, cycles_values

#: The Mapping node's transform: texture space is rotated and shifted off the
#: origin so that the plane reads z and negative coordinates.
LOCATION = (0.37, -0.81, 0.45)
ROTATION = (0.5, 0.3, 0.8)
RES, TILES = 64, 4
#: A pixel differs when some channel is off by more than this.
DIFFERS = 0.01

def mosaic(cases, tmp_path, linked=None):
    """[(ours, theirs) (n, 3) float64 per case]: Cycles' and our values of each
    case (kind, output, params) over its tile of a RES x RES render of
    TILES x TILES tiles, row by row from the top left; the last tile shows
    the texture-space point, to find where Cycles sampled.  ``linked`` (one
    dict a case, or None) links an input to a component ('X', 'Y', 'Z') of
    the texture-space point; ours then gets that component as an (n,) array."""
    assert len(cases) < TILES * TILES
    linked = linked or [{}] * len(cases)

    def build(nodes, links, vector):
        def math(op, *args):
            nd = nodes.new("ShaderNodeMath")
            nd.operation = op
            for sock, a in zip(nd.inputs, args):
                if isinstance(a, (int, float)):
                    sock.default_value = a
                else:
                    links.new(a, sock)
            return nd.outputs[0]

        def socket(sockets, identifier):
            return next(s for s in sockets if s.identifier == identifier)

        # the tile under a pixel from the plane's Object x and y in [-1, 1]
        # (pixel centres are half a pixel off the tile borders)
        coords = vector.node.inputs["Vector"].links[0].from_node.outputs["Object"]
        obj = nodes.new("ShaderNodeSeparateXYZ")
        links.new(coords, obj.inputs[0])
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(vector, sep.inputs[0])
        half = TILES / 2
        col = math("FLOOR", math("MULTIPLY_ADD", obj.outputs["X"], half, half))
        row = math("FLOOR", math("MULTIPLY_ADD", obj.outputs["Y"], -half, half))
        tile = math("MULTIPLY_ADD", row, float(TILES), col)
        out = vector                    # the last tile's, unless a case's
        for i, ((kind, output, params), link) in enumerate(zip(cases, linked)):
            nd = add_node(nodes, kind, params)
            if nd.inputs.get("Vector") is not None:     # not 1D Voronoi's
                links.new(vector, nd.inputs["Vector"])
            for name, comp in link.items():
                links.new(sep.outputs[comp], nd.inputs[name])
            mix = nodes.new("ShaderNodeMix")
            mix.data_type = "RGBA"
            links.new(math("COMPARE", tile, float(i), 0.25), socket(mix.inputs, "Factor_Float"))
            links.new(out, socket(mix.inputs, "A_Color"))
            links.new(nd.outputs[output], socket(mix.inputs, "B_Color"))
            out = socket(mix.outputs, "Result_Color")
        return out

    img, pts = cycles_values(build, tmp_path, res=RES, location=LOCATION, rotation=ROTATION)
    s = RES // TILES
    # where Cycles read the pixels: one offset from their centres for all
    shown = (img - pts)[RES - s:, RES - s:].reshape(-1, 3)
    pts = pts + np.median(shown, axis=0)
    result = []
    for i, ((kind, output, params), link) in enumerate(zip(cases, linked)):
        r, c = divmod(i, TILES)
        p = pts[r * s:(r + 1) * s, c * s:(c + 1) * s].reshape(-1, 3)
        ps = dict(params, **{name: p[:, "XYZ".index(comp)] for name, comp in link.items()})
        ours = procedural.evaluate(kind, output, ps, p)
        result.append((ours, img[r * s:(r + 1) * s, c * s:(c + 1) * s].reshape(-1, 3)))
    return result


def stats(ours, theirs) -> tuple[float, float, float]:
    """(median, 99th percentile of |diff| over pixels' channels, fraction of
    pixels some channel of which differs by more than DIFFERS)."""
    med, p99 = agreement(ours, theirs)
    return med, p99, float(np.mean(np.abs(ours - theirs).max(-1) > DIFFERS))


def check(cases, results, tol_median, tol_p99, name=""):
    """Each case within (tol_median, tol_p99) (a scalar, or a function of the
    case), and at most 1 % of all the render's pixels differing."""
    bad, differing = [], []
    for case, (ours, theirs) in zip(cases, results):
        med, p99, frac = stats(ours, theirs)
        differing.append(frac)
        tm = tol_median(case) if callable(tol_median) else tol_median
        tp = tol_p99(case) if callable(tol_p99) else tol_p99
        if not (med <= tm and p99 <= tp):
            bad.append(f"{case}: median {med:.3g} (tol {tm:g}), p99 {p99:.3g} (tol {tp:g}), "
                       f"{frac:.1%} of pixels differ")
    assert not bad, f"{name}: " + "\n".join(bad)
    assert np.mean(differing) <= 0.01, f"{name}: {np.mean(differing):.2%} of pixels differ"


# ------------------------------------------------------------------- cases

CHECKER_GRADIENT = [
    ("TEX_CHECKER", "Color", {}),
    ("TEX_CHECKER", "Color", {"Scale": 3.3, "Color1": (0.9, 0.1, 0.3),
                              "Color2": (0.05, 0.6, 0.95)}),
    ("TEX_CHECKER", "Factor", {"Scale": 7.5}),
] + [
    ("TEX_GRADIENT", "Factor", {"gradient_type": t})
    for t in ("LINEAR", "QUADRATIC", "EASING", "DIAGONAL", "SPHERICAL", "QUADRATIC_SPHERE",
              "RADIAL")
] + [
    ("TEX_GRADIENT", "Color", {}),
    ("TEX_GRADIENT", "Color", {"gradient_type": "RADIAL"}),
]

MAGIC_BRICK = [
    ("TEX_MAGIC", "Color", {"turbulence_depth": 0}),
    ("TEX_MAGIC", "Color", {}),
    ("TEX_MAGIC", "Factor", {"turbulence_depth": 2, "Distortion": 2.5, "Scale": 3.0}),
    ("TEX_MAGIC", "Color", {"turbulence_depth": 5, "Distortion": 1.7, "Scale": 2.0}),
    ("TEX_MAGIC", "Color", {"turbulence_depth": 5, "Distortion": 0.0}),
    ("TEX_MAGIC", "Factor", {"turbulence_depth": 10, "Distortion": 0.8, "Scale": 1.5}),
    ("TEX_MAGIC", "Color", {"turbulence_depth": 2, "Distortion": -1.3, "Scale": 4.0}),
    ("TEX_BRICK", "Color", {}),
    ("TEX_BRICK", "Color", {"Mortar Size": 0.1, "Mortar Smooth": 0.5}),
    ("TEX_BRICK", "Factor", {"Mortar Size": 0.08, "Mortar Smooth": 0.7, "Scale": 3.0}),
    ("TEX_BRICK", "Color", {"Mortar Size": 0.05, "Mortar Smooth": 0.0, "Bias": 0.3,
                            "Color1": (0.9, 0.4, 0.1), "Color2": (0.2, 0.5, 0.9),
                            "Mortar": (0.1, 0.8, 0.2)}),
    ("TEX_BRICK", "Color", {"offset": 0.3, "offset_frequency": 3, "squash": 0.6,
                            "squash_frequency": 2, "Mortar Size": 0.1, "Mortar Smooth": 0.6,
                            "Bias": -0.2}),
    ("TEX_BRICK", "Factor", {"offset": 0.7, "offset_frequency": 1, "squash": 1.8,
                             "squash_frequency": 3, "Mortar Size": 0.12, "Mortar Smooth": 0.4,
                             "Brick Width": 0.7, "Row Height": 0.3}),
    ("TEX_BRICK", "Color", {"Scale": 2.5, "Brick Width": 0.3, "Row Height": 0.41,
                            "Mortar Size": 0.06, "Mortar Smooth": 1.0, "Bias": 0.6}),
    ("TEX_BRICK", "Color", {"offset_frequency": 4, "squash_frequency": 1, "squash": 0.5,
                            "Mortar Size": 0.1, "Mortar Smooth": 0.3}),
]


#: (median, p99) tolerances of |ours - Cycles| by node, a few times the
#: largest measured (in each test's docstring).
TOLERANCE = {
    "TEX_CHECKER": (1e-7, 1e-6),
    "TEX_GRADIENT": (5e-7, 2e-6),
    "TEX_MAGIC": (5e-6, 5e-5),
    "TEX_BRICK": (2e-6, 3e-4),
}


def _check(cases, results, name):
    check(cases, results, lambda c: TOLERANCE[c[0]][0], lambda c: TOLERANCE[c[0]][1], name)


def test_checker_and_gradient_match_cycles(tmp_path):
    """Every Gradient type (Color and Factor) and Checker (Color, Factor, its
    colours and scale).  Measured: Checker median <= 1.5e-8, p99 <= 6e-8
    (float32 colours); Gradient median <= 6e-8, p99 <= 1.6e-7; no pixel
    differs by more than DIFFERS."""
    results = mosaic(CHECKER_GRADIENT, tmp_path)
    _check(CHECKER_GRADIENT, results, "checker, gradient")


def test_magic_and_brick_match_cycles(tmp_path):
    """Magic at depths 0, 2, 5 and 10 with distortions 0, -1.3 and 0.8..2.5
    (Color and Factor); Brick with offset and squash on several row
    frequencies, mortar smoothing 0 to 1 (and the default narrow band),
    bias, colours and scales.  Measured: Magic median <= 8.6e-7, p99 <=
    7.1e-6 (float32 rounding through its chain of sines); Brick median <=
    2.1e-7, p99 <= 9.2e-5 (the default mortar band's slope, 1 over 2e-3 of a
    scaled unit, times the points' rounding); no pixel differs by more than
    DIFFERS."""
    results = mosaic(MAGIC_BRICK, tmp_path)
    _check(MAGIC_BRICK, results, "magic, brick")
