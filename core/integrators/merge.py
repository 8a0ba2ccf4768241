"""Photon merging in 'COMBINED': a path-space partition (weights 0 or 1) beside the MIS.

A path y_0 (lens) y_1 ... y_k (emitter) is classified by its camera end: v
is its first vertex that scattered by a non-delta lobe (SPPM's visible
point), and the lobe at y_{v+1} (the next vertex towards the light).
**Merging owns** the paths with v > 1 (seen through at least one mirror or
glass vertex: light tracing cannot join y_1 to the lens) whose y_{v+1}
scattered by a delta lobe (v + 1 < k; light reaches y_v through a mirror
or glass: next-event estimation at y_v cannot sample them, only path
tracing can, with the fireflies of small lights).  On those paths the
camera strategies get weight 0 and merging weight 1; on every other path
merging gets 0 and the power-heuristic MIS of path tracing, next-event
estimation and light tracing (core.integrators.mis) is unchanged.  The
weights of every path sum to one (tests/oracle_mis.py), so the image is
unbiased in the limit of merging's vanishing radius, as SPPM is.

Merging is SPPM (core.sppm: visible points, progressive radii, the
frequency kernel) restricted to visible points with ``through_delta`` and
to deposits whose previous scattering sampled a delta lobe
(``PhotonTracer.after_delta_only``).

With ``RenderSettings.merge_weights = 'MIS'`` merging is instead a fourth
strategy of the power heuristic (``CameraMerge``, ``merge_weight`` below,
core.integrators.merge_kernels; docs/integrators.md "Merging as an MIS
strategy").
"""
from __future__ import annotations

import numpy as np


class CameraPartition:
    """The classification of K live camera paths, updated per vertex by
    PathTracer (arrays compacted with the paths).

    chain: no non-delta vertex yet; seen: a delta vertex so far (while
    chain); pend: the last vertex was y_v with v > 1 (this vertex's lobe
    decides); owned: merging owns every later contribution."""

    def __init__(self, K: int):
        self.chain = np.ones(K, bool)
        self.seen = np.zeros(K, bool)
        self.pend = np.zeros(K, bool)
        self.owned = np.zeros(K, bool)

    def keep(self, i: np.ndarray) -> None:
        """The rows i (the ih of a vertex, then its survivors c)."""
        for k in ("chain", "seen", "pend", "owned"):
            setattr(self, k, getattr(self, k)[i])

    def sampled(self, is_delta: np.ndarray) -> None:
        """The lobes sampled at the current vertex (K,) bool (delta)."""
        first = self.chain & ~is_delta               # this vertex is y_v
        self.owned = self.owned | (self.pend & is_delta)
        self.pend = first & self.seen
        self.seen = self.seen | (self.chain & is_delta)
        self.chain = self.chain & is_delta

    def weight(self, rows=None) -> np.ndarray:
        """(K,) the camera strategies' factor: 0 on merging-owned paths, else 1."""
        o = self.owned if rows is None else self.owned[rows]
        return np.where(o, 0.0, 1.0)


# --------------------------------------------------------------------------
# Merging as an MIS strategy (``RenderSettings.merge_weights = 'MIS'``).
#
# Strategy M merges at y_v, the first camera vertex that scattered by a
# non-delta lobe (SPPM's visible point, v = 1 allowed), for paths with
# k >= v + 2 (direct light at y_v stays with PT, NEE and LT).  Its density
# in the units of core.integrators.mis (docs/integrators.md, "Merging as an
# MIS strategy"):
#
#     q_M = 1 c_1 ... c_v  N_M l_v ... l_k  pi r^2
#
# (one SPPM camera sample per pixel and pass, N_M merging photons per pass,
# r the radius of the pixel containing y_1 in that pass).  The camera side
# carries ``QM`` = q_M / q_PT without the factors still to come, the same
# recursion as mis' Q started at y_v; the light side's B0, B1 at the photon
# give q_PT / q_M and q_NEE / q_M, and q_L / q_M = N_L / (N_M pi r^2 c_1)
# at v = 1 (LT cannot connect a delta y_1).

class CameraMerge:
    """Merging's camera-side state of K live camera paths (arrays compacted
    with the paths, as CameraPartition).

    scale (K,): N_M pi r^2 / K of the path's pixel (0: no merging there);
    chain (K,) bool: no non-delta sample yet (y_v not reached); Qs (K,) the
    ray's QM (0 before y_v); em (K,) bool: the ray left a vertex y_j with
    j > v (emission it finds has k >= v + 2: merging can take the path)."""

    def __init__(self, K: int):
        self.scale = np.zeros(K)
        self.chain = np.ones(K, bool)
        self.Qs = np.zeros(K)
        self.em = np.zeros(K, bool)

    def keep(self, i: np.ndarray) -> None:
        """The rows i (the ih of a vertex, then its survivors c)."""
        for k in ("scale", "chain", "Qs", "em"):
            setattr(self, k, getattr(self, k)[i])

    def at_vertex(self, t: np.ndarray) -> np.ndarray:
        """(K,) QM at the vertices the rays hit at distance t: Qs / t^2 (0 in
        the delta chain: next-event estimation at y_v is direct light)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.chain, 0.0, self.Qs / (t * t))

    def sampled(self, QM_next: np.ndarray, cos_out: np.ndarray, is_delta: np.ndarray) -> None:
        """The survivors' samples (rows already kept): QM_next the recursion
        of their vertex's QM (mis' Q update), cos_out |cos| of the sample at
        the vertex.  At y_v (chain and a non-delta sample) QM starts at
        scale |cos_v(w)| (q_M's c_v cancels the recursion's 1 / c_v; no
        reverse density: l_{v-1} is not in q_M)."""
        start = self.chain & ~is_delta
        self.em = ~self.chain
        self.Qs = np.where(start, self.scale * cos_out, np.where(self.chain, 0.0, QM_next))
        self.chain = self.chain & is_delta


def merge_weight(B0, B1, pf, x, c1, v1):
    """(K,) w_M of photons merged at visible points: 1 / (1 + (B0 pf x)^2 +
    (B1 pf x)^2 + v1 (x / c_1)^2), x = N_L / (N_M pi r^2) (r of the pixel
    containing y_1), pf the camera-side BSDF density at the visible point
    towards the photon, c_1 the camera density of y_1 (v1: the visible point
    is y_1, light tracing competes)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        b0, b1 = B0 * pf * x, B1 * pf * x
        bl = np.where(v1, x / c1, 0.0)
        w = 1.0 / (1.0 + b0 * b0 + b1 * b1 + bl * bl)
    return np.where(np.isfinite(w) & (x < np.inf), w, 0.0)
