"""Shader AOVs: the passes a material's AOV Output nodes write (View Layer >
Passes > Shader AOV), as Cycles writes them.

Cycles evaluates an AOV Output node with the surface's shader at a camera
ray's hit, while the ray is still on its line and no earlier surface has
taken the pixel's data passes (``svm_node_aov_check``), and adds the
input's value unweighted: a Color AOV (r, g, b, 1), a Value AOV its value
(kernel/film/aov_passes.h).  The pass is the mean over the samples, so an
edge pixel blends the objects its samples hit, and the background adds 0.

FPPM writes the value at the camera ray's first hit (the pass's other
first-hit data: Depth, Normal, ...), a mean over the passes: each
material's AOVs are its constant times its texture at the hit (its colour,
or for a Value AOV read from an image the texture's alpha channel: the
exporter's scalar textures).  A material without the AOV writes nothing
(a Color AOV's alpha 0 there, as in Cycles).  Left out: a surface
whose transparency is above the view layer's Alpha Threshold (Cycles
writes its AOVs and the next surface's too).
"""
from __future__ import annotations

import numpy as np

from ..scene.textures import sample_alpha, sample_texture


def film_passes(scene, passes) -> tuple:
    """The ``core.sppm.film.FilmPass`` of each shader AOV of ``scene``
    (``Scene.shader_aovs``) named in ``passes``: 'mean' passes of the first
    hits, a Color AOV 4 channels (RGBA), a Value AOV 1 (X)."""
    from .film import FilmPass
    names = set(passes)
    out = []
    for name, kind in getattr(scene, "shader_aovs", ()) or ():
        if name not in names:
            continue
        table = _table(scene, name)
        if kind == 'COLOR':
            out.append(FilmPass(name, 4, "RGBA", "COLOR", "", "mean",
                                lambda x, t=table: _values(x, t, 4)))
        else:
            out.append(FilmPass(name, 1, "X", "VALUE", "", "mean",
                                lambda x, t=table: _values(x, t, 1)))
    return tuple(out)


def _table(scene, name) -> tuple:
    """(rgb (M, 3) float64, texture (M,) int64, scalar (M,) bool, has (M,)
    bool) of AOV ``name`` for each material row of the scene (0, -1, False,
    False without it)."""
    M = len(scene.materials)
    rgb, tex, scalar = np.zeros((M, 3)), np.full(M, -1, np.int64), np.zeros(M, bool)
    has = np.zeros(M, bool)
    for i, m in enumerate(scene.materials):
        for n, c, t, sc in getattr(m, "aovs", ()):
            if n == name:
                rgb[i], tex[i], scalar[i], has[i] = c, t, sc, True
                break
    return rgb, tex, scalar, has


def _values(x, table, channels: int) -> np.ndarray:
    """(P, channels) the AOV at each pixel's first hit (PassSample x): the
    material's value times its texture there; a Color AOV's alpha 1 on a
    hit whose material has it; 0 elsewhere."""
    rgb, tex, scalar, has = table
    f, s = x.first, x.scene
    out = np.zeros((f.hit.shape[0], channels))
    k = np.nonzero(f.hit)[0]
    if k.size == 0:
        return out
    prim = f.prim[k]
    mat = np.asarray(s.tri_mat, np.int64)[prim]
    v = rgb[mat]
    t = tex[mat]
    if np.any(t >= 0):
        uv = _uv_at(s, prim, f.p[k])
        for ti in np.unique(t[t >= 0]):
            sel = t == ti
            for sc in (False, True):
                g = sel & (scalar[mat] == sc)
                if g.any():
                    img = s.textures[ti]
                    v[g] = v[g] * (sample_alpha(img, uv[g])[:, None] if sc
                                   else sample_texture(img, uv[g]))
    if channels == 4:
        out[k, :3], out[k, 3] = v, has[mat]
    else:
        out[k, 0] = v[:, 0]
    return out


def _uv_at(scene, prim: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(K, 2) the texture coordinates at points p (K, 3) on triangles prim
    (K,): their barycentrics in the triangle's plane, interpolating
    ``Scene.tri_uv``."""
    P = np.asarray(scene.tri_p[prim], np.float64)
    e1, e2, w = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], p - P[:, 0]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    w1, w2 = (w * e1).sum(1), (w * e2).sum(1)
    det = np.maximum(d11 * d22 - d12 * d12, 1e-300)
    b1 = (d22 * w1 - d12 * w2) / det
    b2 = (d11 * w2 - d12 * w1) / det
    UV = np.asarray(scene.tri_uv[prim], np.float64)
    return (1 - b1 - b2)[:, None] * UV[:, 0] + b1[:, None] * UV[:, 1] + b2[:, None] * UV[:, 2]
