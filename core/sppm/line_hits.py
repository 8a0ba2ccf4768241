"""What a camera ray meets while it is still on its line: the surfaces it
crosses and, if it gets through, the world -- the segments at which Cycles
writes its per-path data passes (kernel/film/data_passes.h, the paths that
still have PATH_RAY_TRANSPARENT_BACKGROUND: no vertex yet, or only straight
crossings of Transparent BSDFs).

The camera pass (core.sppm.visible_points) appends one :class:`LineHits`
record for each wavefront of rays it traces when a pass that needs them is
on; the film's consumers read them after the pass:

- Cryptomatte (core.sppm.cryptomatte): each surface's coverage
  mean(beta) (1 - mean(T));
- the colour passes (core.sppm.color_passes): beta x the albedos of the
  surface's diffuse, glossy and transmission closures;
- the Environment pass (core.sppm.color_passes): beta x the world the rays
  that escape see.

FPPM's camera chains cross a Transparent lobe by a random choice (the
throughput divided by its probability), so the sums behind a transparent
surface have Cycles' expectation.  A ray that ends on a holdout surface
(core.scene.holdout) records nothing there.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np


class LineHits(NamedTuple):
    """One wavefront's segments still on their camera ray's line.

    px (n,) int64 pixel; prim (n,) int64 triangle hit (-1: the ray escaped
    to the world); u, v (n,) float64 the hit's barycentrics; beta (n, 3)
    float64 the ray's throughput (before the surface); d (n, 3) float64 the
    ray's direction; through (n,) float64 the mean pass-through weight of
    the surface's Transparent lobes (``core.lights.shadow.pass_through``; 0
    without transparent materials or on a miss)."""
    px: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    beta: np.ndarray
    d: np.ndarray
    through: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.prim >= 0


def record(records: Optional[list], prim: np.ndarray, on_line: np.ndarray, beta: np.ndarray,
           idx: np.ndarray, uv, d: np.ndarray, shadow_materials,
           ends: Optional[np.ndarray]) -> None:
    """Append the LineHits of the K rays of one wavefront to ``records``
    (None: no pass reads them).  prim (K,) the triangle hit (-1: none),
    on_line (K,) bool still on the camera ray's line, beta (K, 3), idx (K,)
    the rays' pixels, uv = (u, v) (K,) the barycentrics, d (K, 3) the rays'
    directions, shadow_materials the camera rays' transparent materials
    (``core.lights.shadow.attached(accel, camera=True)``; None: none is),
    ends (K,) bool the rays that end on a holdout there (or None)."""
    if records is None:
        return
    k = on_line if ends is None else on_line & ~ends
    k = np.nonzero(k)[0]
    if k.size == 0:
        return
    pr = np.asarray(prim[k], np.int64)
    u = np.asarray(uv[0][k], np.float64)
    v = np.asarray(uv[1][k], np.float64)
    through = np.zeros(k.size)
    if shadow_materials is not None:
        from ..lights.shadow import pass_through
        h = np.nonzero(pr >= 0)[0]
        if h.size:
            through[h] = pass_through(shadow_materials, pr[h], u[h], v[h]).mean(axis=1)
    records.append(LineHits(np.asarray(idx[k], np.int64), pr, u, v,
                            np.asarray(beta[k], np.float64), np.asarray(d[k], np.float64),
                            through))
