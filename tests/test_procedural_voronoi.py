"""Cycles' Voronoi Texture node (core/scene/voronoi.py, through
core/scene/procedural.py's ``evaluate``) against Cycles, pixel by pixel.

Cases cover 1D-4D, every feature, every distance metric (Minkowski with
exponents 1.5 and 0.7), Detail 0 and fractional (1.6, 2.4, with Roughness
and Lacunarity), Normalize on and off, Randomness below 1, Smoothness, and
each output the feature has (Distance, Color, Position, W; Radius: Blender
hides, and links nothing from, the others).  The cases of a dimension count
(42, 54 in 4D) share one Cycles render of 128 x 128 pixels, a 16 x 16 tile
each (``procedural_cycles.mosaic``: the whole plane at the tile's exact
pixel centres through test_procedural_patterns.py's rotated, off-centre
Mapping); 1D reads W from the texture-space x (a W linked to a Separate
XYZ, as an (N,) W for ours), 4D reads W from z in half its cases and a
constant in the others.

A tile costs Cycles its own pixels only (``procedural_cycles.tiled_values``).
4D Smooth F1 searches 5^4 cells an octave at each sample: 15 4D cases (13
Smooth F1) in a 64 x 64 render whose every pixel evaluated every case's
node took Cycles 2 s; the render of all 54 now takes 0.2 s.  What is left
of the 4D test's 2.8 s is the port's: a Python loop over the 625 cells for
each of the 36 octaves of its 16 Smooth F1 cases (about 0.1 ms a cell,
whatever the number of points: fewer pixels would not shorten it).

What differs is float32 rounding (Cycles' Mapping and ours differ in the
last bits): times the slope (Scale x Lacunarity^octave) for a continuous
output (a distance, a smooth blend); piecewise constant outputs (F1 and F2
Color, Position, W, and N-Sphere Radius) are equal but where a cell edge
passes within that rounding of a pixel's point.
"""
from __future__ import annotations

import pytest

from procedural_cycles import Case, mosaic
from test_procedural_patterns import LOCATION, ROTATION, check

DIMS = ("1D", "2D", "3D", "4D")
#: One render a dimension count: up to 64 cases, a 16 x 16 tile each.
RES, TILES = 128, 8
METRICS = ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI")

#: Settings the cases cycle through: Detail 0 or fractional, Normalize,
#: Randomness < 1, Scale.
VARIANTS = (
    {},
    {"Detail": 1.6, "Roughness": 0.6, "Lacunarity": 2.3, "normalize": True},
    {"Randomness": 0.7, "normalize": True, "Scale": 3.5},
    {"Detail": 2.4, "Roughness": 0.45, "Randomness": 0.85, "Scale": 4.0},
)


def _outputs(dims: str) -> tuple:
    """The outputs F1, F2 and Smooth F1 have in ``dims`` (Blender hides the
    others): Position but in 1D, W in 1D and 4D."""
    return (("Distance", "Color") + (("Position",) if dims != "1D" else ())
            + (("W",) if dims in ("1D", "4D") else ()))


def _cases(dims: str) -> list:
    """[procedural_cycles.Case] of one dimension count."""
    out = []

    def add(output, params, i):
        params = dict(params, voronoi_dimensions=dims)
        link = {}
        if dims == "1D":
            link = {"W": "X"}
        elif dims == "4D":
            if i % 2:
                link = {"W": "Z"}
            else:
                params["W"] = 0.37
        out.append(Case("TEX_VORONOI", output, params, link,
                        location=LOCATION, rotation=ROTATION))

    metrics = METRICS if dims != "1D" else ("EUCLIDEAN",)
    for feature in ("F1", "F2", "SMOOTH_F1"):
        for oi, output in enumerate(_outputs(dims)):
            # 1D has one metric: it runs through every variant per output
            for mi, metric in enumerate(metrics if dims != "1D" else METRICS):
                v = dict(VARIANTS[(oi + mi) % len(VARIANTS)], feature=feature)
                if dims != "1D":
                    v["distance"] = metric
                if metric == "MINKOWSKI" and dims != "1D":
                    v["Exponent"] = 1.5 if oi % 2 == 0 else 0.7
                if feature == "SMOOTH_F1" and mi % 2:
                    v["Smoothness"] = 0.6
                add(output, v, len(out))
    for v in VARIANTS:
        add("Distance", dict(v, feature="DISTANCE_TO_EDGE"), len(out))
    for v in ({}, {"Randomness": 0.6, "Scale": 3.5}):
        add("Radius", dict(v, feature="N_SPHERE_RADIUS"), len(out))
    return out


def _tolerance(case) -> tuple[float, float]:
    """(median, p99) tolerances of a case, above the largest measured
    (:func:`test_voronoi_matches_cycles`'s docstring)."""
    continuous = case.output == "Distance" or case.params.get("feature") == "SMOOTH_F1"
    return (3e-6, 3e-5) if continuous else (3e-7, 1e-6)


@pytest.mark.parametrize("dims", DIMS)
def test_voronoi_matches_cycles(dims, tmp_path):
    """Each case of a dimension count's render within its tolerance
    (_tolerance), and at most 1 % of the render's pixels differing by more
    than 0.01.  Measured over the 4 renders (180 cases): continuous outputs
    median <= 1.2e-7, p99 <= 3.9e-6 (Smooth F1 Color, 4D, Minkowski 0.7);
    piecewise constant ones median <= 3e-8, p99 <= 1.2e-7 (1D W); no pixel
    differs."""
    cases = _cases(dims)
    assert len(cases) <= TILES * TILES
    check(cases, mosaic(cases, tmp_path, RES, TILES), lambda c: _tolerance(c)[0],
          lambda c: _tolerance(c)[1], f"Voronoi {dims}")
