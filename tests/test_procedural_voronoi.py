"""Cycles' Voronoi Texture node (core/scene/voronoi.py, through
core/scene/procedural.py's ``evaluate``) against Cycles, pixel by pixel.

Cases cover 1D-4D, every feature, every distance metric (Minkowski with
exponents 1.5 and 0.7), Detail 0 and fractional (1.6, 2.4, with Roughness
and Lacunarity), Normalize on and off, Randomness below 1, Smoothness, and
each output the feature has (Distance, Color, Position, W; Radius: Blender
hides, and links nothing from, the others).  15 cases share one Cycles render, a
16 x 16 tile each (tests/test_procedural_patterns.py ``mosaic``: the same
rotated, off-centre Mapping, the points moved to where Cycles sampled);
1D reads W from the texture-space x (a W linked to a Separate XYZ, as an
(N,) W for ours), 4D reads W from z in half its cases and a constant in the
others.

What differs is float32 rounding (Cycles' Mapping and ours differ in the
last bits): times the slope (Scale x Lacunarity^octave) for a continuous
output (a distance, a smooth blend); piecewise constant outputs (F1 and F2
Color, Position, W, and N-Sphere Radius) are equal but where a cell edge
passes within that rounding of a pixel's point.
"""
from __future__ import annotations

import pytest

from test_procedural_patterns import TILES, check, mosaic

DIMS = ("1D", "2D", "3D", "4D")
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
    """[(case (kind, output, params), linked inputs)] of one dimension count."""
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
        out.append((("TEX_VORONOI", output, params), link))

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


def _chunks():
    n = TILES * TILES - 1       # the last tile shows the texture-space point
    for dims in DIMS:
        cases = _cases(dims)
        for k in range(0, len(cases), n):
            yield pytest.param(dims, cases[k:k + n], id=f"{dims}-{k // n}")


def _tolerance(case) -> tuple[float, float]:
    """(median, p99) tolerances of a case, a few times the largest measured
    (:func:`test_voronoi_matches_cycles`'s docstring)."""
    _, output, params = case
    continuous = output == "Distance" or params.get("feature") == "SMOOTH_F1"
    return (3e-6, 3e-5) if continuous else (3e-7, 1e-6)


@pytest.mark.parametrize("dims, cases", list(_chunks()))
def test_voronoi_matches_cycles(dims, cases, tmp_path):
    """Each case of a 15-case render within its tolerance (_tolerance), and at
    most 1 % of the render's pixels differing by more than 0.01.  Measured
    over all 13 renders (180 cases): continuous outputs median <= 7.2e-7,
    p99 <= 5.7e-6 (Smooth F1 Color, 3D); piecewise constant ones median <=
    6e-8, p99 <= 2.4e-7 (a float32 ulp of a Position); no pixel differs."""
    plain = [c for c, _ in cases]
    results = mosaic(plain, tmp_path, [link for _, link in cases])
    check(plain, results, lambda c: _tolerance(c)[0], lambda c: _tolerance(c)[1],
          f"Voronoi {dims}")
