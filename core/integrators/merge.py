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
