"""The Geometry node's mesh attributes that Cycles computes when it syncs a
mesh: Pointiness and Random Per Island.

Neither is stored in the .blend: Cycles derives both from the evaluated
mesh (``intern/cycles/blender/mesh.cc``, ``attr_create_pointiness`` and
``attr_create_random_per_island``), and so does the exporter, with these
functions, for the materials whose graph reads them
(core/scene/shader_graph.py ``Attr`` keys ('Pointiness',) and
('RandomPerIsland',)).

- **Pointiness** (a value a vertex, interpolated over each triangle): how
  far the vertex sticks out of its one-ring.  Vertices at the same place
  (a UV seam's split copies) are welded first.  At each welded vertex,
  with n its normalised summed normal and e the mean of the unit vectors
  along its edges, the raw value is acos(n . e) / pi: 0.5 on a flat
  surface, above it on a convex corner, below it in a concave one.  One
  blur then averages each vertex with its edge neighbours (itself
  included: sum / (neighbours + 1)), "to approximate a 2-ring
  neighbourhood".
- **Random Per Island** (a value a triangle): a hash of the island's
  representative vertex, where islands are the mesh's edge-connected
  components and the representative is the root of a union by rank over
  the edges in their order (Cycles' ``DisjointSet``), read at the first
  corner of each loop triangle: ``hash_uint(root) / (2^32 - 1)``.

numpy, with the weld's scan and the union-find compiled
(core/scene/mesh_attributes_kernels.py).
"""
from __future__ import annotations

import numpy as np

from ..mathutil import unit_rows
from .cycles_hash import hash_uint

#: FLT_EPSILON: vertices closer than sqrt(it) are one (Cycles' weld test
#: ``len_squared(a - b) < FLT_EPSILON``), looked for among those whose
#: coordinate sums differ by at most 3 of it.
_FLT_EPSILON = float(np.finfo(np.float32).eps)


def welded(positions) -> np.ndarray:
    """(V,) int64 for each vertex the one it is welded to (itself when
    alone): positions (V, 3) float32 sorted by x + y + z, each compared
    with the following ones while their sums stay within 3 FLT_EPSILON,
    the first within distance sqrt(FLT_EPSILON) taken, then followed to its
    end (Cycles' STEP 1)."""
    p = np.asarray(positions, np.float32)
    V = len(p)
    s = (p[:, 0] + p[:, 1]) + p[:, 2]
    order = np.lexsort((-np.arange(V), s))         # by sum, equal ones by index down
    from .mesh_attributes_kernels import weld_scan
    orig = weld_scan(p, s, order.astype(np.int64), np.float32(_FLT_EPSILON))
    while True:
        nxt = orig[orig]
        if np.array_equal(nxt, orig):
            return orig
        orig = nxt


def pointiness(positions, vertex_normals, edges) -> np.ndarray:
    """(V,) float64 Cycles' Pointiness at each vertex: positions (V, 3)
    float32 in object space, vertex_normals (V, 3), edges (E, 2) int (the
    module doc's rule)."""
    p = np.asarray(positions, np.float64)
    V = len(p)
    if V == 0:
        return np.zeros(0)
    orig = welded(positions)
    n = np.zeros((V, 3))
    np.add.at(n, orig, np.asarray(vertex_normals, np.float64))
    n = unit_rows(n)
    e = orig[np.asarray(edges, np.int64).reshape(-1, 2)]
    # each welded edge once, either way round (Cycles' EdgeMap)
    key = np.minimum(e[:, 0], e[:, 1]) * V + np.maximum(e[:, 0], e[:, 1])
    e = e[np.sort(np.unique(key, return_index=True)[1])]
    v0, v1 = e[:, 0], e[:, 1]
    d = p[v1] - p[v0]
    ln = np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where(ln > 0.0, d / np.where(ln > 0.0, ln, 1.0), 0.0)   # safe_normalize
    acc = np.zeros((V, 3))
    np.add.at(acc, v0, d)
    np.add.at(acc, v1, -d)
    count = np.bincount(v0, minlength=V) + np.bincount(v1, minlength=V)
    own = (orig == np.arange(V)) & (count > 0)
    raw = np.zeros(V)
    c = np.einsum("ij,ij->i", n[own], acc[own] / count[own, None])
    raw[own] = np.arccos(np.clip(c, -1.0, 1.0)) / np.pi
    out = raw.copy()
    np.add.at(out, v0, raw[v1])
    np.add.at(out, v1, raw[v0])
    out /= count + 1
    return out[orig]


def island_roots(vertex_count: int, edges) -> np.ndarray:
    """(V,) int64 each vertex's island representative: Cycles' DisjointSet
    (union by rank, the first argument's root kept on equal ranks, paths
    compressed) joined over edges (E, 2) in their order."""
    from .mesh_attributes_kernels import union_by_rank
    e = np.ascontiguousarray(np.asarray(edges, np.int64).reshape(-1, 2))
    return union_by_rank(int(vertex_count), e)


def random_per_island(vertex_count: int, edges, first_vertex) -> np.ndarray:
    """(T,) float64 Random Per Island of triangles whose first corners are
    at vertices first_vertex (T,): ``hash_uint_to_float`` of their island's
    root, in float32 as Cycles divides."""
    roots = island_roots(vertex_count, edges)[np.asarray(first_vertex, np.int64)]
    h = hash_uint(roots).astype(np.float32)
    return (h / np.float32(0xFFFFFFFF)).astype(np.float64)
