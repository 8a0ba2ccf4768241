"""Cycles' Checker, Gradient, Magic and Brick Texture nodes
(core/scene/patterns.py, through core/scene/procedural.py's ``evaluate``)
against Cycles, pixel by pixel.

One Cycles render (``procedural_cycles.mosaic``) shows up to 16 cases, one a
64 x 64 tile of a 256 x 256 render: each case's node, built from the very
params dict given to ``evaluate``, reads the whole plane at the tile's
pixel centres (exact in float32: ``procedural_cycles.exact_centres``
removes the 0.01-pixel filter's offset) through a Mapping node with a
rotation and an off-centre location, so that z and negative coordinates
are read.  Each case's tile is compared with ``evaluate`` at the tile's
texture-space points: the median and 99th percentile of |ours - Cycles|
over its pixels' channels, and the fraction of pixels off by more than
DIFFERS.  What differs is float32 rounding (Cycles' Mapping and ours
differ in the last bits) times each texture's slope.

:func:`check` and :func:`stats` also serve tests/test_procedural_voronoi.py.
"""
from __future__ import annotations

import numpy as np

from procedural_cycles import Case, agreement, mosaic

#: The Mapping node's transform: texture space is rotated and shifted off the
#: origin so that the plane reads z and negative coordinates.
LOCATION = (0.37, -0.81, 0.45)
ROTATION = (0.5, 0.3, 0.8)
#: 4 x 4 tiles of 64 x 64 pixels.
RES, TILES = 256, 4
#: A pixel differs when some channel is off by more than this.
DIFFERS = 0.01


def stats(ours, theirs) -> tuple[float, float, float]:
    """(median, 99th percentile of |diff| over pixels' channels, fraction of
    pixels some channel of which differs by more than DIFFERS)."""
    med, p99 = agreement(ours, theirs)
    return med, p99, float(np.mean(np.abs(ours - theirs).max(-1) > DIFFERS))


def label(case) -> str:
    """A case's kind, output, params (and linked inputs) for a message."""
    return f"{case.kind} {case.output} {case.params}" + (f" {case.linked}" if case.linked else "")


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
            bad.append(f"{label(case)}: median {med:.3g} (tol {tm:g}), p99 {p99:.3g} "
                       f"(tol {tp:g}), {frac:.1%} of pixels differ")
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


def _cases(cases):
    """procedural_cycles.Case of each (kind, output, params), through the
    rotated, off-centre Mapping."""
    return [Case(kind, output, params, location=LOCATION, rotation=ROTATION)
            for kind, output, params in cases]


def _check(cases, results, name):
    check(cases, results, lambda c: TOLERANCE[c.kind][0], lambda c: TOLERANCE[c.kind][1], name)


def test_checker_and_gradient_match_cycles(tmp_path):
    """Every Gradient type (Color and Factor) and Checker (Color, Factor, its
    colours and scale).  Measured: Checker equal at every pixel; Gradient
    median 0, p99 <= 1.2e-7; no pixel differs by more than DIFFERS."""
    cases = _cases(CHECKER_GRADIENT)
    _check(cases, mosaic(cases, tmp_path, RES, TILES), "checker, gradient")


def test_magic_and_brick_match_cycles(tmp_path):
    """Magic at depths 0, 2, 5 and 10 with distortions 0, -1.3 and 0.8..2.5
    (Color and Factor); Brick with offset and squash on several row
    frequencies, mortar smoothing 0 to 1 (and the default narrow band),
    bias, colours and scales.  Measured: Magic median <= 1.2e-7, p99 <=
    8.1e-6 (float32 rounding through its chain of sines); Brick median 0,
    p99 <= 1.3e-5 (a smoothed mortar band's slope times the points'
    rounding); no pixel differs by more than DIFFERS."""
    cases = _cases(MAGIC_BRICK)
    _check(cases, mosaic(cases, tmp_path, RES, TILES), "magic, brick")
