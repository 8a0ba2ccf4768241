"""A roughness map read per hit: a material as a family of roughness levels.

An Image Texture into a Roughness input (a Principled BSDF's, a Glossy's or
a Glass's) makes a lobe's roughness vary across the surface.  Every BSDF
kernel (numpy and compiled) reads a lobe's roughness from its material's
row, so instead of a per-hit roughness in each of them, such a material is
given ROUGH_LEVELS more rows of the ``MaterialTable`` (:func:`append_levels`),
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

#: Level rows of a mapped material.
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


def mapped_lobes(materials):
    """(materials, maps): the list with every mapped lobe's roughness (a
    layered DIFFUSE's ``layer_roughness``) raised to ROUGH_MIN and its map
    left out (the material's own row: the map's mean, what the frequency
    model reads), and maps a list of (material index, texture, ((lobe slot,
    "roughness" | "layer_roughness"), ...)) for :func:`append_levels`."""
    out, maps = [], []
    for m, mat in enumerate(materials):
        tex = {int(getattr(lb, "roughness_texture", -1)) for lb in mat.lobes} - {-1}
        if not tex:
            out.append(mat)
            continue
        if len(tex) > 1:
            raise ValueError(f"material '{mat.name}': more than one roughness map")
        lobes, slots = [], []
        for j, lb in enumerate(mat.lobes):
            if getattr(lb, "roughness_texture", -1) >= 0:
                field = "layer_roughness" if getattr(lb, "layer_ior", 0.0) > 0.0 else "roughness"
                lb = dataclasses.replace(lb, roughness_texture=-1,
                                         **{field: max(getattr(lb, field), ROUGH_MIN)})
                slots.append((j, field))
            lobes.append(lb)
        out.append(dataclasses.replace(mat, lobes=tuple(lobes)))
        maps.append((m, tex.pop(), tuple(slots)))
    return out, maps


def append_levels(table, maps):
    """The MaterialTable ``table`` (of :func:`mapped_lobes`' materials) with
    ROUGH_LEVELS rows appended for each of ``maps``: copies of its row
    whose mapped lobes take :func:`level_roughness` (k) at level k (their
    delta and Lambert flags are the row's: no level is a delta, and a
    mapped lobe is never a Lambert one), with ``rough_first`` (M,) the first
    level row of each mapped material (-1: none, the level rows too) and
    ``rough_tex`` its map."""
    if not maps:
        return table
    M, K = table.kind.shape[0], ROUGH_LEVELS
    src = np.repeat(np.array([m for m, _, _ in maps], np.int64), K)
    out = {}
    for f in dataclasses.fields(table):
        a = getattr(table, f.name)
        if isinstance(a, np.ndarray) and a.ndim >= 1 and a.shape[0] == M:
            out[f.name] = np.concatenate([a, a[src]])
    levels = level_roughness(np.arange(K))
    first = np.full(M + K * len(maps), -1, np.int64)
    tex = np.full(M + K * len(maps), -1, np.int32)
    for i, (m, t, slots) in enumerate(maps):
        rows = slice(M + K * i, M + K * (i + 1))
        for j, field in slots:
            out[field][rows, j] = levels
        first[m], tex[m] = M + K * i, t
    out.update(rough_first=first, rough_tex=tex)
    return dataclasses.replace(table, **out)


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
