"""Texture atlases: a material's textures baked over its triangles, one block
of texels a triangle, so that anything a material computes from a surface
point (a procedural texture at Generated or Object coordinates, images read
at different vectors, mixes of them) is read per hit as one image is read.

Block layout.  Triangle i gets a square block of (n_i + 2)^2 texels.  Its
corners map to block coordinates (s, t) = (0, 0), (1, 0), (0, 1), the point
of the triangle's plane at (s, t) being P0 + s (P1 - P0) + t (P2 - P0); the
block's texel (i, j) holds the value at s = (i - 0.5) / n, t = (j - 0.5) / n.
So the triangle's own square [0, 1]^2 runs between the centres of the
block's outer texels, and a bilinear lookup anywhere on the triangle reads
texels of its own block only: no seams and no bleeding between blocks.
The texels beyond the hypotenuse (s + t > 1) and the guard ring hold the
texture on the triangle's plane extended, which is the value a bilinear
lookup near those edges needs.  Texture coordinates of the corners are
(x0 + 1 + n s, y0 + 1 + n t) / (W, H) for the block at (x0, y0): a texel
centre at (x + 0.5) / W, as every lookup in core/scene/textures.py reads.

Sizes.  n_i follows the triangle's extent in texture space times a texel
density (texels per unit), from the finest detail of what is baked
(:func:`block_sizes`), rounded up to one of a few sizes so blocks pack in
shelves (:func:`pack`); a budget of texels a material caps the density.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import procedural as PR

#: Texels a feature (a noise lattice cell, a wave's period) of the finest
#: detail of a smooth procedural source; ``SHARP_FACTOR`` times that for a
#: pattern with sharp edges (``procedural.is_sharp``), blurred a texel wide.
TEXELS_PER_FEATURE = 8.0
SHARP_FACTOR = 4.0
#: A Noise's finest counted octave has 1/16 of the first's amplitude or
#: more, so half the texels keep its bake within 0.2 % (measured,
#: tests/test_procedural_materials.py).
FRACTAL_FACTOR = 0.5
#: Texels per image texel when an image is baked with other sources.
TEXELS_PER_TEXEL = 4.0
#: Texels a block side may take inside its guard ring (n), in steps of about
#: sqrt(2) so that a handful of shelf heights pack every block.
SIZES = np.array([1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512,
                  768, 1024, 1536, 2048], np.int64)
#: Texels of one material's atlas at most (64 MB a baked RGBA float32 texture).
BUDGET = 1 << 22
#: Widest atlas row, in texels.
MAX_WIDTH = 8192
#: Texels of the smallest atlas (a 3 x 3 block a triangle) beyond which
#: each triangle gets a single texel instead (:func:`flat`).
HARD_CAP = 4 * BUDGET


class Layout(NamedTuple):
    """Where each triangle's block sits.

    width, height: the atlas's size in texels; x0, y0 (T,) int64 the block
    corners; n (T,) int64 texels inside the guard ring a side."""
    width: int
    height: int
    x0: np.ndarray
    y0: np.ndarray
    n: np.ndarray


class Texels(NamedTuple):
    """Every texel of a :class:`Layout`'s blocks: tri (K,) int64 its
    triangle, s, t (K,) float64 its block coordinates, iy, ix (K,) int64 its
    row and column in the atlas."""
    tri: np.ndarray
    s: np.ndarray
    t: np.ndarray
    iy: np.ndarray
    ix: np.ndarray


def extent(corners: np.ndarray) -> np.ndarray:
    """(T,) float64 the longest edge of each triangle of corner vectors
    (T, 3, D)."""
    c = np.asarray(corners, np.float64)
    e = np.stack([c[:, 1] - c[:, 0], c[:, 2] - c[:, 0], c[:, 2] - c[:, 1]], 1)
    return np.sqrt(np.max(np.sum(e * e, axis=-1), axis=1))


def procedural_density(kind: str, params: dict) -> float:
    """Texels a texture-space unit for a procedural source
    (``procedural.frequency`` features a unit)."""
    return TEXELS_PER_FEATURE * PR.frequency(kind, params) \
        * (SHARP_FACTOR if PR.is_sharp(kind, params) else
           FRACTAL_FACTOR if kind == "TEX_NOISE" else 1.0)


def image_density(shape) -> float:
    """Texels a uv unit for an image of ``shape`` (H, W, ...)."""
    return TEXELS_PER_TEXEL * max(shape[:2])


def _rounded(n: np.ndarray) -> np.ndarray:
    """n rounded up to :data:`SIZES` (capped at its last)."""
    k = np.searchsorted(SIZES, np.maximum(n, 1), side='left')
    return SIZES[np.minimum(k, len(SIZES) - 1)]


def block_sizes(ext: np.ndarray, density: float, budget: int = BUDGET) -> np.ndarray:
    """(T,) int64 block sizes n for triangles of texture-space extent ``ext``
    (T,) at ``density`` texels a unit, the density lowered until the blocks'
    texels, guard rings included, fit ``budget``."""
    ext = np.nan_to_num(np.asarray(ext, np.float64), nan=0.0, posinf=0.0)
    d = float(density) if np.isfinite(density) and density > 0 else 1.0
    for _ in range(8):
        n = _rounded(np.ceil(ext * d).astype(np.int64))
        total = int(np.sum((n + 2) ** 2))
        if total <= budget or np.all(n == 1):
            return n
        d *= 0.95 * np.sqrt(budget / total)
    return n


def pack(n: np.ndarray) -> Layout:
    """Shelf packing of blocks of (n + 2)^2 texels: the largest first, each
    size in rows of its own height, in an atlas about square."""
    n = np.asarray(n, np.int64)
    b = n + 2
    total = int(np.sum(b * b))
    W = int(min(MAX_WIDTH, max(int(b.max(initial=1)), 1 << int(np.ceil(np.log2(
        max(np.sqrt(total), 1.0)))))))
    x0 = np.zeros(len(n), np.int64)
    y0 = np.zeros(len(n), np.int64)
    y = 0
    for size in np.unique(b)[::-1]:
        idx = np.nonzero(b == size)[0]
        per_row = max(W // int(size), 1)
        k = np.arange(len(idx))
        x0[idx] = (k % per_row) * size
        y0[idx] = y + (k // per_row) * size
        y += int(-(-len(idx) // per_row)) * int(size)
    return Layout(W, max(y, 1), x0, y0, n)


def corner_uvs(L: Layout) -> np.ndarray:
    """(T, 3, 2) float32 the atlas texture coordinates of each triangle's
    corners (s, t) = (0, 0), (1, 0), (0, 1)."""
    s = np.array([0.0, 1.0, 0.0])
    t = np.array([0.0, 0.0, 1.0])
    x = (L.x0[:, None] + 1.0 + L.n[:, None] * s) / L.width
    y = (L.y0[:, None] + 1.0 + L.n[:, None] * t) / L.height
    return np.stack([x, y], -1).astype(np.float32)


def texels(L: Layout) -> Texels:
    """Every texel of every block (:class:`Texels`), block by block."""
    b = L.n + 2
    count = b * b
    tri = np.repeat(np.arange(len(b)), count)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    k = np.arange(int(count.sum())) - np.repeat(start, count)
    bt = b[tri]
    i, j = k % bt, k // bt
    n = L.n[tri].astype(np.float64)
    return Texels(tri, (i - 0.5) / n, (j - 0.5) / n, L.y0[tri] + j, L.x0[tri] + i)


def at_texels(corners: np.ndarray, tx: Texels) -> np.ndarray:
    """(K, D) float64 the affine interpolant of per-corner values
    (T, 3, D) at the texels: P0 + s (P1 - P0) + t (P2 - P0)."""
    c = np.asarray(corners, np.float64)[tx.tri]
    return (c[:, 0] + tx.s[:, None] * (c[:, 1] - c[:, 0])
            + tx.t[:, None] * (c[:, 2] - c[:, 0]))


def flat(T: int) -> tuple:
    """(Layout, Texels, corner uvs (T, 3, 2) float32) of an atlas of one
    texel a triangle, row by row: every corner reads its texel's centre,
    which holds the value at the triangle's centroid (s = t = 1/3); for
    more triangles than :data:`HARD_CAP` allows blocks (a texture constant
    over each triangle)."""
    W = int(min(MAX_WIDTH, max(T, 1)))
    H = int(-(-max(T, 1) // W))
    k = np.arange(T)
    iy, ix = k // W, k % W
    third = np.full(T, 1.0 / 3.0)
    uv = np.stack([(ix + 0.5) / W, (iy + 0.5) / H], -1)
    uv = np.repeat(uv[:, None, :], 3, axis=1).astype(np.float32)
    return (Layout(W, H, ix, iy, np.zeros(T, np.int64)), Texels(k, third, third, iy, ix), uv)


def image(L: Layout, tx: Texels, values: np.ndarray) -> np.ndarray:
    """(H, W, C) float32 the atlas holding ``values`` (K, C) at the texels
    (rows between shelves' blocks are 0)."""
    values = np.asarray(values)
    out = np.zeros((L.height, L.width, values.shape[1]), np.float32)
    out[tx.iy, tx.ix] = values
    return out
