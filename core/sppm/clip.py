"""The gather disc clipped at walls: per-visible-point kernel clip (docs/method.md
"The kernel clipped at walls").

A visible point's kernel disc of radius R (core.sppm.hashgrid, rules (1)-(4))
reaches through a thin wall standing on its surface: a shadowed floor pixel
at the foot of a wall gathers the photons of the lit floor on the other side
(PPM's light leak), and near a concave corner the part of the disc beyond
the wall holds no floor photons while the estimate still divides by pi R^2
(the boundary bias).  Here each visible point casts CLIP_WEDGES short rays in
its tangent plane, along the edges of CLIP_WEDGES equal wedges of the disc
(the tangent frame of ``hashgrid._tangent_frame``: the same normal gets the
same wedges, as the sector cells do), and each wedge keeps a clip distance:

    d_k = cos(pi / CLIP_WEDGES) * min(t_k, t_{k+1})     (t_j: edge j's hit, R on a miss)

and is unclipped (d_k = R) when both edges miss.  For a planar wall
crossing the tangent plane the wall's nearest point in wedge k is at least
d_k away (the foot of its perpendicular is within pi / CLIP_WEDGES of an
edge, or outside the wedge), so the clipped wedge holds nothing from behind
any planar wall.  The gather rejects a photon of wedge k whose offset in the
tangent plane is d_k or farther (hashgrid rule (5)), and the pass's count
and flux are divided by the clipped area fraction

    f = (1 / CLIP_WEDGES) sum_k (d_k / R)^2

(GatherBuffers.fold), so the progressive update still sees a full disc's
worth of photons where the radiance is uniform over the visible part.

Rays start lifted off the surface by max(the accel's spawn offset,
CLIP_LIFT_REL * R), and a hit on a surface oriented like the visible point's
(|dot(n_hit, n_vp)| > CLIP_COS) does not clip: a concave surface of
curvature radius rho curves up by R^2 / (2 rho) over the ray, which passes
the lift where rho < R / (2 CLIP_LIFT_REL), and the orientation test keeps
it from clipping itself.

Storage: one uint64 a visible point, byte k = floor(255 d_k / R) (at most
254 when clipped: rounded down, a clip is never farther than the wall) or
CLIP_OPEN = 255 (unclipped); CLIP_CLEAR (every byte 255) = no clip at all,
the gather's fast path.  8 B a pixel, in fractions of the pass's R: the
clip is cast every pass with its radii.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..accel import REL_OFFSET
from .hashgrid import (CLIP_CLEAR, CLIP_OPEN, CLIP_WEDGES, SECTOR_CELLS, _tangent_frame,
                       clip_weights)
from .photon_kernels import _offset_scale

#: Ray lift above the visible point's surface, relative to R.
CLIP_LIFT_REL = 0.01
#: A hit on a surface whose normal is within 60 degrees of the visible
#: point's (either side) does not clip (the gather's own orientation rule 3).
CLIP_COS = 0.5
_COS_HALF = math.cos(math.pi / CLIP_WEDGES)
#: Visible points per Embree call: the rays and hits of a block (~450 B a
#: visible point: float32 origins and directions, Embree's and Accel's hit
#: arrays) stay ~15 MB instead of ~1 GB at 1080p (the pass's peak comes
#: later, in the gather, where the clip itself is 8 B a pixel).
CLIP_BLOCK = 1 << 15
# cos, sin of the edge angles 2 pi j / CLIP_WEDGES (once, not per ray)
_EDGE_COS = np.cos(2.0 * np.pi * np.arange(CLIP_WEDGES) / CLIP_WEDGES)
_EDGE_SIN = np.sin(2.0 * np.pi * np.arange(CLIP_WEDGES) / CLIP_WEDGES)


@njit(cache=True)
def _edge_rays(p, ng, idx, R2, rel, floor, ec, es):
    """Rays along the CLIP_WEDGES wedge edges of visible points idx (n,):
    origins o (n * W, 3) float32 = p + lift n, directions d (n * W, 3)
    float32 = cos(2 pi j / W) t1 + sin(2 pi j / W) t2 (j = edge), with
    (t1, t2) = _tangent_frame(ng) and lift = max(accel.offset_scale(p),
    CLIP_LIFT_REL R) (rel, floor: the offset's, photon_kernels._offset_scale);
    R (n,) float64 = sqrt(R2[idx]); the rays' lengths t_max (n * W,)
    float32, R rounded as Accel's t_max is (min(R, 3e37) to float32).  ec,
    es (W,) the edges' cos and sin.  One loop: the lift, the radii and the
    lengths were numpy temporaries of every block (~15 % of the clip's CPU)."""
    n = idx.shape[0]
    W = CLIP_WEDGES
    o = np.empty((n * W, 3), np.float32)
    d = np.empty((n * W, 3), np.float32)
    R = np.empty(n)
    t_max = np.empty(n * W, np.float32)
    for i in range(n):
        v = idx[i]
        r = math.sqrt(R2[v])
        R[i] = r
        lift = max(_offset_scale(p[v, 0], p[v, 1], p[v, 2], rel, floor), CLIP_LIFT_REL * r)
        t = np.float32(min(r, 3e37))
        n0, n1, n2 = ng[v, 0], ng[v, 1], ng[v, 2]
        t0, t1, t2, t3, t4, t5 = _tangent_frame(n0, n1, n2)
        for j in range(W):
            c, s = ec[j], es[j]
            k = i * W + j
            o[k, 0] = p[v, 0] + lift * n0
            o[k, 1] = p[v, 1] + lift * n1
            o[k, 2] = p[v, 2] + lift * n2
            d[k, 0] = c * t0 + s * t3
            d[k, 1] = c * t1 + s * t4
            d[k, 2] = c * t2 + s * t5
            t_max[k] = t
    return o, d, R, t_max


@njit(cache=True)
def _codes(t, prim, tri_ng, ng, idx, R, margin, out):
    """out[idx[i]] = the packed clip of visible point idx[i] from its edge
    rays' hit distances t (n * W,) (inf on a miss) and triangles prim
    (tri_ng (T, 3) their unit geometric normals); margin: the factor
    cos(pi / W) of the module docstring."""
    W = CLIP_WEDGES
    edge = np.empty(W)
    for i in range(idx.shape[0]):
        v = idx[i]
        r = R[i]
        for j in range(W):
            k = i * W + j
            e = r
            if prim[k] >= 0 and t[k] < r:
                q = prim[k]
                dn = abs(tri_ng[q, 0] * ng[v, 0] + tri_ng[q, 1] * ng[v, 1]
                         + tri_ng[q, 2] * ng[v, 2])
                if dn <= CLIP_COS:
                    e = t[k]
            edge[j] = e
        code = np.uint64(0)
        for k in range(W):
            m = min(edge[k], edge[(k + 1) % W])
            b = CLIP_OPEN
            if m < r:
                b = min(int(math.floor(255.0 * margin * m / r)), CLIP_OPEN - 1)
                b = max(b, 0)
            code |= np.uint64(b) << np.uint64(8 * k)
        out[v] = code


def clip_codes(accel, tri_ng: np.ndarray, p: np.ndarray, ng: np.ndarray, R2: np.ndarray,
               active: np.ndarray, check_stop=lambda: None) -> np.ndarray:
    """(P,) uint64 packed clips (module docstring) of the visible points at p
    (P, 3) float64 with unit normals ng (P, 3) float64 and squared radii R2
    (P,), for the active (P,) bool ones (CLIP_CLEAR elsewhere); casts
    CLIP_WEDGES rays of length R per active point through accel
    (core.accel.Accel, float32 at Embree): an occlusion query for all
    (cheaper), the closest hit for the occluded ones alone.  tri_ng (T, 3)
    float64: the unit geometric normals of accel's triangles
    (core.sppm.photon_kernels.build_triangle_data).  check_stop() is called
    before every block (a cancel is seen within one block's rays).

    The blocks (CLIP_BLOCK points; at least four from SPLIT_MIN points) are
    taken in turn by two threads, this one and core.sppm.photons' pool
    (``visible_points.blocks_in_two_threads``; Embree and the kernels release the
    GIL): a point's code depends on its own rays alone, so the codes are the
    same bits however the blocks are shared."""
    from .camera_kernels import SPLIT_MIN
    from .visible_points import blocks_in_two_threads
    P = active.shape[0]
    out = np.full(P, CLIP_CLEAR, np.uint64)
    idx = np.nonzero(active)[0]
    if idx.size == 0 or accel.tri_p.shape[0] == 0:
        return out
    p = np.ascontiguousarray(p, np.float64)
    ng = np.ascontiguousarray(ng, np.float64)
    R2 = np.ascontiguousarray(R2, np.float64)

    def block(ib):
        o, d, R, t_max = _edge_rays(p, ng, ib, R2, REL_OFFSET, accel.abs_floor / REL_OFFSET,
                                    _EDGE_COS, _EDGE_SIN)
        j = np.nonzero(accel.occluded(o, d, t_max))[0]
        t = np.full(t_max.shape[0], np.inf)
        prim = np.full(t_max.shape[0], -1, np.int32)
        if j.size:
            hits = accel.intersect(o[j], d[j], t_max=t_max[j])
            t[j], prim[j] = hits.t, hits.prim
        _codes(t, prim, tri_ng, ng, ib, R, _COS_HALF, out)

    if idx.size < SPLIT_MIN:
        check_stop()
        block(idx)
        return out
    blk = min(CLIP_BLOCK, -(-idx.size // 4))

    def block_at(b0):
        check_stop()
        block(idx[b0:b0 + blk])
    blocks_in_two_threads(idx.size, blk, block_at)
    return out


@njit(cache=True)
def _inverse_fractions(codes, idx, out):
    W = np.empty((SECTOR_CELLS, SECTOR_CELLS))
    for i in range(idx.shape[0]):
        c = codes[idx[i]]
        out[i] = 1.0 if c == CLIP_CLEAR else clip_weights(c, W)


def inverse_fractions(codes: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(n,) float64 the count and flux weight 1 / max(f, CLIP_MIN_FRACTION)
    of the visible points idx (n,) int (1 where unclipped); codes (P,) uint64."""
    out = np.empty(idx.shape[0])
    _inverse_fractions(codes, np.ascontiguousarray(idx, np.int64), out)
    return out
