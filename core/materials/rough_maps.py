"""A roughness map read per hit: a material as a family of roughness levels.

An Image Texture into a Roughness input (a Principled BSDF's, a Glossy's or
a Glass's) makes a lobe's roughness vary across the surface.  Every BSDF
kernel (numpy and compiled) reads a lobe's roughness from its material's
row, so instead of a per-hit roughness in each of them, such a material is
expanded into ROUGH_LEVELS rows of the ``MaterialTable`` (:func:`expand`),
identical but for the mapped lobes' roughness, and a hit picks its row from
the map at its uv (:func:`pick`) where a stage reads the hit's material to
shade it: the camera pass, the camera paths, the photon tracer's generic
hits (light paths too), light tracing's connections and Combined's light
vertex densities.  The compiled samplers never see a mapped material's own
row (:func:`mapped`): the pick comes first, in numpy, and hands them the
level's row; everything downstream (lobe choice, f, pdf, sampling, the
receivers' kernels) sees a material of that roughness.  The
material's own row keeps the map's mean: what the frequency model reads
of a photon's bounce.

Levels are uniform in log GGX alpha = r^2 between ALPHA_MIN and 1 (a step
of 3.7 % in alpha at 256 levels), and a hit between two levels takes the
upper one with probability its fractional position (a hash of the hit,
:func:`dither`): the expected BSDF interpolates linearly in log alpha
between neighbours, whose error is second order in the step (about 0.1 %
of a GGX peak; docs/shading.md "Roughness maps").  A roughness below
sqrt(ALPHA_MIN) = 0.01 reads as 0.01: mapped lobes are never Dirac deltas,
so a material's delta flags do not depend on the hit.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..scene.textures import sample_alpha

#: Rows a mapped material expands into.
ROUGH_LEVELS = 256
#: The smallest GGX alpha of a level (roughness 0.01).
ALPHA_MIN = 1e-4
#: The smallest roughness of a mapped lobe.
ROUGH_MIN = float(np.sqrt(ALPHA_MIN))


def level_roughness(k) -> np.ndarray:
    """Roughness of levels k (int array-like, 0 .. ROUGH_LEVELS - 1)."""
    x = np.asarray(k, np.float64) / (ROUGH_LEVELS - 1)
    return np.sqrt(ALPHA_MIN ** (1.0 - x))


def level_position(r) -> np.ndarray:
    """Fractional level (0 .. ROUGH_LEVELS - 1) of roughness r (array-like)."""
    a = np.maximum(np.square(np.clip(np.asarray(r, np.float64), 0.0, 1.0)), ALPHA_MIN)
    return (np.log(a) / np.log(ALPHA_MIN) * -1.0 + 1.0) * (ROUGH_LEVELS - 1)


def expand(materials):
    """(materials + levels, first (M,) int64, tex (M,) int32): the list
    with ROUGH_LEVELS rows appended for each material with a mapped lobe
    (``Lobe.roughness_texture`` >= 0: its roughness, or a layered DIFFUSE's
    ``layer_roughness``, follows that scalar texture's alpha), level k with
    :func:`level_roughness` (k) on those lobes; first[m] its first row (-1:
    none; the appended rows have -1 too), tex[m] the map.  The material's
    own row keeps its lobes' roughness (the map's mean, what light paths
    read), raised to ROUGH_MIN."""
    first, tex, out, levels = [], [], [], []
    n = len(materials)
    for mat in materials:
        maps = {int(getattr(lb, "roughness_texture", -1)) for lb in mat.lobes} - {-1}
        if not maps:
            first.append(-1)
            tex.append(-1)
            out.append(mat)
            continue
        if len(maps) > 1:
            raise ValueError(f"material '{mat.name}': more than one roughness map")
        first.append(n + ROUGH_LEVELS * len(levels))
        tex.append(maps.pop())
        out.append(_at(mat, None))
        levels.append(mat)
    for mat in levels:
        out.extend(_at(mat, float(r)) for r in level_roughness(np.arange(ROUGH_LEVELS)))
    pad = len(out) - n
    return (out, np.array(first + [-1] * pad, np.int64),
            np.array(tex + [-1] * pad, np.int32))


def _at(mat, r):
    """mat with its mapped lobes at roughness r (None: their own, raised to
    ROUGH_MIN), the map left out."""
    lobes = []
    for lb in mat.lobes:
        if getattr(lb, "roughness_texture", -1) >= 0:
            field = "layer_roughness" if getattr(lb, "layer_ior", 0.0) > 0.0 else "roughness"
            v = max(getattr(lb, field), ROUGH_MIN) if r is None else r
            kw = {field: v}
            if field == "layer_roughness":
                kw["roughness"] = lb.roughness
            lb = dataclasses.replace(lb, roughness_texture=-1, **kw)
        lobes.append(lb)
    return dataclasses.replace(mat, lobes=tuple(lobes))


def mapped(table) -> np.ndarray:
    """(M,) bool: the table's rows whose hits pick a level (the compiled
    samplers and splats leave them to numpy, where :func:`pick` runs)."""
    first = getattr(table, "rough_first", None)
    return np.zeros(table.kind.shape[0], bool) if first is None else first >= 0


def dither(prim, bu, bv) -> np.ndarray:
    """(K,) float64 in [0, 1): a hash of the hits (prim, bu, bv) (K,) (their
    float32 barycentrics' bits), the same for the same hit in any stage."""
    mask = np.uint64(0xFFFFFFFF)
    a = np.asarray(bu, np.float32).view(np.uint32).astype(np.uint64)
    b = np.asarray(bv, np.float32).view(np.uint32).astype(np.uint64)
    h = (a * np.uint64(0x9E3779B1) ^ b * np.uint64(0x85EBCA77)
         ^ np.asarray(prim, np.int64).astype(np.uint64) * np.uint64(0xC2B2AE3D)) & mask
    # murmur3's finaliser.
    h ^= h >> np.uint64(16)
    h = (h * np.uint64(0x85EBCA6B)) & mask
    h ^= h >> np.uint64(13)
    h = (h * np.uint64(0xC2B2AE35)) & mask
    h ^= h >> np.uint64(16)
    return h.astype(np.float64) / 4294967296.0


def pick(table, mat, prim, bu, bv, uv) -> np.ndarray:
    """The hits' material rows (K,) int64: mat (K,) as it is where the
    material has no roughness map (``table.rough_first`` -1), else its level
    for the map's roughness at uv (K, 2), rounded up with probability its
    fraction (:func:`dither` of prim, bu, bv (K,))."""
    mat = np.asarray(mat, np.int64)
    first = getattr(table, "rough_first", None)
    if first is None or mat.size == 0:
        return mat
    f = first[mat]
    rows = np.nonzero(f >= 0)[0]
    if rows.size == 0:
        return mat
    out = mat.copy()
    rt = table.rough_tex[mat[rows]]
    r = np.empty(rows.size)
    for t in np.unique(rt):
        s = rt == t
        r[s] = sample_alpha(table.textures[t], np.asarray(uv, np.float64)[rows[s]])
    x = level_position(r) + dither(np.asarray(prim)[rows], np.asarray(bu)[rows],
                                   np.asarray(bv)[rows])
    k = np.minimum(np.floor(x).astype(np.int64), ROUGH_LEVELS - 1)
    out[rows] = f[rows] + k
    return out
