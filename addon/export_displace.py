"""True displacement: a material's Displacement method 'Displacement Only'
or 'Displacement and Bump' moves the mesh's vertices before the render,
as Cycles does (scene/mesh_displace.cpp; the mesh's resolution is its own,
a Subdivision Surface modifier's for detail).

- Each vertex is displaced once, by the first triangle (in the mesh's
  triangle order) that has such a material, evaluated at that triangle's
  corner: the Displacement node's (Height - Midlevel) x Scale along the
  corner's normal -- in object space (the node's default) the normal taken
  to object space and the offset back through the object's transform, so
  that it stretches with the object; in world space as it is.  The Height
  is the material's texture graph (core/scene/shader_graph.py) at the
  corner's undisplaced attributes.
- Normals afterwards: with 'Displacement Only', the vertices of such
  materials' triangles take the normal of the displaced mesh (the sum of
  the unit face normals of those triangles around the vertex), which
  every smooth triangle around them reads; flat triangles are shaded with
  their new face normal.  A mesh with per-corner normals (sharp
  edges, custom normals) keeps them, each moved by its vertex's change of
  normal over every triangle, flat ones again the face normal.  'Both'
  keeps a mesh's vertex normals (its bump perturbs them).

Offsets that are not finite are 0 (Cycles' ensure_finite).
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np


class TrueDisplacement(NamedTuple):
    """A material's true displacement: height, a float expression of
    core/scene/shader_graph.py (the Displacement node's Height); midlevel,
    scale its inputs; object_space: the node's Space is Object; recompute:
    the method is 'Displacement Only' (its vertex normals are recomputed)."""
    height: object
    midlevel: float
    scale: float
    object_space: bool
    recompute: bool


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 0, v / np.where(n > 0, n, 1.0), 0.0)


def face_normals(p: np.ndarray) -> np.ndarray:
    """(T, 3) unit normals of triangles p (T, 3, 3) (corner order: 0 -> 1 -> 2)."""
    return _unit(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))


def vertex_normal_sums(p: np.ndarray, vid: np.ndarray, tris: np.ndarray, V: int) -> np.ndarray:
    """(V, 3) the sum of the unit face normals of triangles ``tris`` around
    each vertex (Cycles' compute_vertex_normals)."""
    fn = face_normals(p[tris])
    out = np.zeros((V, 3))
    for c in range(3):
        np.add.at(out, vid[tris, c], fn)
    return out


def displace(pw: np.ndarray, nw: np.ndarray, vid: np.ndarray, smooth: np.ndarray,
             corner_normals: bool, mat: np.ndarray, specs: list, A: np.ndarray,
             height_at: Callable) -> tuple[np.ndarray, np.ndarray]:
    """The displaced (pw, nw) (T, 3, 3) float32 of one object's triangles.

    pw, nw: world corners and corner normals (geometry's order, its winding
    swap applied); vid (T, 3) the corners' vertices; smooth (T,) bool;
    corner_normals: the mesh's normals are per corner; mat (T,) material
    rows and specs[m] their TrueDisplacement or None; A (3, 3) the object's
    linear transform; height_at(m, tris, corners) -> (n,) float64 the Height
    of material m at corner ``corners`` (n,) of triangles ``tris`` (n,)."""
    T = pw.shape[0]
    has = np.array([specs[m] is not None for m in range(len(specs))], bool)
    disp = has[mat]
    if not disp.any():
        return pw, nw
    V = int(vid.max()) + 1
    p = pw.astype(np.float64)
    n = nw.astype(np.float64)
    # The first corner of each vertex over the displaced triangles, in order.
    tris = np.nonzero(disp)[0]
    flat_v = vid[tris].ravel()
    verts, first = np.unique(flat_v, return_index=True)
    ft, fc = tris[first // 3], first % 3
    off = np.zeros((V, 3))
    for m in np.unique(mat[ft]):
        k = np.nonzero(mat[ft] == m)[0]
        s = specs[m]
        h = np.broadcast_to(np.asarray(height_at(int(m), ft[k], fc[k]), np.float64), (k.size,))
        amount = (h - s.midlevel) * s.scale
        N = n[ft[k], fc[k]]
        if s.object_space:
            # Normals go to object space with A^T (they transform with A^-T);
            # the offset comes back through A.
            d = (_unit(N @ A) * amount[:, None]) @ A.T
        else:
            d = _unit(N) * amount[:, None]
        off[verts[k]] = np.where(np.isfinite(d), d, 0.0)
    pre = vertex_normal_sums(p, vid, np.arange(T), V) if corner_normals else None
    p = p + off[vid]
    recompute = np.array([specs[m] is not None and specs[m].recompute
                          for m in range(len(specs))], bool)[mat]
    if corner_normals:
        # Every triangle: its corners moved by the change of their vertex's normal.
        post = vertex_normal_sums(p, vid, np.arange(T), V)
        delta = _unit(post) - _unit(pre)
        sm = np.nonzero(smooth)[0]
        n[sm] = _unit(n[sm] + delta[vid[sm]])
        fl = np.nonzero(~smooth)[0]
        n[fl] = face_normals(p[fl])[:, None, :]
    else:
        if recompute.any():
            # The vertex normals of the displaced triangles' vertices, which
            # every smooth triangle around them reads (per vertex).
            r = np.nonzero(recompute)[0]
            post = _unit(vertex_normal_sums(p, vid, r, V))
            redone = np.zeros(V, bool)
            redone[vid[r].ravel()] = True
            t, c = np.nonzero(redone[vid] & smooth[:, None])
            n[t, c] = post[vid[t, c]]
        # Flat triangles are shaded with their own (moved) face normal.
        fl = np.nonzero(~smooth)[0]
        n[fl] = face_normals(p[fl])[:, None, :]
    return p.astype(np.float32), n.astype(np.float32)
