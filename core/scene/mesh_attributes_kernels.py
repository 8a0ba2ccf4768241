"""The scalar loops of core/scene/mesh_attributes.py, compiled: Cycles'
vertex weld (a forward scan of the vertices sorted by coordinate sum) and
its union by rank.  Both are loops whose steps depend on the ones before;
numpy runs the weld's scan one offset at a time over all the vertices
(seconds on a flat grid of 250,000 vertices, whose anti-diagonals have
equal sums), this module once (docs/shading.md)."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def weld_scan(p, s, order, eps):
    """(V,) int64 for each vertex the vertex it is welded to, itself when
    none: p (V, 3) float32 positions, s (V,) float32 their coordinate sums,
    order (V,) int64 the vertices by sum (equal ones by index down); each
    vertex takes the first later one in that order within distance
    sqrt(eps), looked for while the sums differ by at most 3 eps
    (Cycles' STEP 1, before its chains are followed)."""
    V = p.shape[0]
    orig = np.arange(V)
    for i in range(V):
        a = order[i]
        for j in range(i + 1, V):
            b = order[j]
            if s[b] - s[a] > 3.0 * eps:
                break
            dx = p[b, 0] - p[a, 0]
            dy = p[b, 1] - p[a, 1]
            dz = p[b, 2] - p[a, 2]
            if dx * dx + dy * dy + dz * dz < eps:
                orig[a] = b
                break
    return orig


@njit(cache=True, nogil=True)
def union_by_rank(vertex_count, edges):
    """(V,) int64 each vertex's root after Cycles' DisjointSet joins the
    edges (E, 2) in order: union by rank, the first argument's root kept on
    equal ranks, paths compressed."""
    parent = np.arange(vertex_count)
    rank = np.zeros(vertex_count, np.int64)
    for k in range(edges.shape[0]):
        ra = _find(parent, edges[k, 0])
        rb = _find(parent, edges[k, 1])
        if ra == rb:
            continue
        if rank[ra] < rank[rb]:
            ra, rb = rb, ra
        parent[rb] = ra
        if rank[ra] == rank[rb]:
            rank[ra] += 1
    out = np.empty(vertex_count, np.int64)
    for x in range(vertex_count):
        out[x] = _find(parent, x)
    return out


@njit(cache=True, inline="always")
def _find(parent, x):
    root = x
    while parent[root] != root:
        root = parent[root]
    while parent[x] != root:
        nxt = parent[x]
        parent[x] = root
        x = nxt
    return root
