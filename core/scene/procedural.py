"""Cycles' procedural texture nodes, evaluated at texture-space points.

A procedural node is read as (kind, output, params): ``kind`` the node's
Blender type ('TEX_NOISE', 'TEX_CHECKER', ...), ``output`` the name of the
output socket read, ``params`` a dict of its unlinked input sockets' values
by socket name (floats, or (r, g, b) tuples for colours) and of its enum and
boolean properties by property name.  :func:`evaluate` gives that output at
points p, (N, 3) float64 texture-space vectors (the node's Vector input: the
point after Texture Coordinate and Mapping nodes), as (N, 3) float64
colours; a float output (Factor, Distance, ...) is read as a grey colour, as
Cycles converts a float into a colour socket.

Each port follows Cycles' kernel (intern/cycles/kernel/svm/) closely enough
to pick the same cells, gradients and hashed colours: tests/test_procedural_*.py
compare it with Cycles pixel by pixel (tests/procedural_cycles.py).  The
exporter bakes these values into texture atlases (core/scene/atlas.py), so
every stage reads a procedural texture as it reads an image.
"""
from __future__ import annotations

import numpy as np

from .patterns import brick_texture, checker_texture, gradient_texture, magic_texture
from .noise import noise_texture, wave_texture, white_noise_texture
from .voronoi import voronoi_texture


#: kind -> f(output, params, p) -> (N, 3) float64.
KINDS = {
    "TEX_CHECKER": checker_texture,
    "TEX_GRADIENT": gradient_texture,
    "TEX_MAGIC": magic_texture,
    "TEX_BRICK": brick_texture,
    "TEX_VORONOI": voronoi_texture,
    "TEX_NOISE": noise_texture,
    "TEX_WHITE_NOISE": white_noise_texture,
    "TEX_WAVE": wave_texture,
}

#: The outputs each kind can give (others are not procedural colours).
OUTPUTS = {
    "TEX_CHECKER": ("Color", "Factor"),
    "TEX_GRADIENT": ("Color", "Factor"),
    "TEX_MAGIC": ("Color", "Factor"),
    "TEX_BRICK": ("Color", "Factor"),
    "TEX_VORONOI": ("Distance", "Color", "Position", "W", "Radius"),
    "TEX_NOISE": ("Factor", "Color"),
    "TEX_WHITE_NOISE": ("Value", "Color"),
    "TEX_WAVE": ("Color", "Factor"),
}


def supported(kind: str, output: str) -> bool:
    """Whether :func:`evaluate` gives this node output."""
    return output in OUTPUTS.get(kind, ())


def evaluate(kind: str, output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 the colour of output ``output`` of a ``kind`` node with
    ``params`` at points p (N, 3) float64."""
    p = np.asarray(p, np.float64).reshape(-1, 3)
    return KINDS[kind](output, params, p)


#: Kinds whose output has sharp edges (cell borders, mortar, checker squares).
SHARP = frozenset({"TEX_CHECKER", "TEX_BRICK", "TEX_VORONOI"})


def is_sharp(kind: str, params: dict) -> bool:
    """Whether the node's output jumps along lines (:data:`SHARP`, and a
    Wave's Saw profile)."""
    return kind in SHARP or kind == "TEX_WAVE" and params.get("wave_profile") == "SAW"


def frequency(kind: str, params: dict) -> float:
    """Features a texture-space unit of the finest detail that shows in a
    node's output: what a bake's resolution must follow (addon/export_atlas.py
    gives each feature a fixed number of texels).  A fractal's octaves count
    while their amplitude (Roughness^k) is 1/16 of the first or more; the
    constants are each pattern's period in Cycles' kernel (a wave's phase
    10 Scale (x + y + z): 10 sqrt(3) / (2 pi) = 2.8 periods a unit along
    the diagonal; a brick's width and row height)."""
    g = params.get
    scale = abs(float(g("Scale", 5.0)))
    if kind in ("TEX_NOISE", "TEX_VORONOI"):
        detail = float(g("Detail", 2.0 if kind == "TEX_NOISE" else 0.0))
        rough = float(g("Roughness", 0.5 if kind == "TEX_NOISE" else 0.5))
        lac = max(float(g("Lacunarity", 2.0)), 1.0)
        k = detail if rough >= 1.0 else (
            0.0 if rough <= 0.0 else min(detail, np.log(1 / 16) / np.log(rough)))
        f = scale * lac ** max(k, 0.0) * (1.0 + abs(float(g("Distortion", 0.0))))
    elif kind == "TEX_WAVE":
        f = 2.8 * scale
        if float(g("Distortion", 0.0)) != 0.0:
            f *= max(1.0, abs(float(g("Detail Scale", 1.0)))
                     * 2.0 ** min(float(g("Detail", 2.0)), 4.0))
    elif kind == "TEX_BRICK":
        f = scale / max(min(float(g("Brick Width", 0.5)), float(g("Row Height", 0.25))), 1e-3)
    elif kind == "TEX_MAGIC":
        f = 2.0 * scale * (1.0 + abs(float(g("Distortion", 1.0))))
    elif kind == "TEX_GRADIENT":
        f = 1.0
    elif kind == "TEX_WHITE_NOISE":
        f = 1e6                      # a value a point: as fine as the budget allows
    else:
        f = scale
    return float(min(max(f, 1e-3), 1e6))
