"""Surface boundaries seen from the camera: a cap on each pixel's initial radius.

A photon-mapping kernel that reaches past the edge of the surface it sits on
is biased: the disc of area pi R^2 only partly covers receiving surface (the
rest is air over a table's edge, or another face at another irradiance), so
the density estimate tau / (pi R^2 N_e) darkens or blends there.  Progressive
radius reduction removes the bias only as fast as R shrinks, and a radius
held by frequency photons not at all: the spectrum describes the light
field, not the extent of the receiver.  The measured effect (the indirectly
lit room against Cycles, a plate floating above a floor in tests/test_edges.py)
is in docs/method.md, "Surface boundaries".

So the initial radius of each pixel is capped by the distance to the nearest
*surface boundary* visible around it, found in screen space from one camera
pass through the pixel centres (core.sppm.update.Radii.edge_cap): a
neighbour pixel within ``reach`` pixels is on another surface when

- it sees nothing (background), or
- its normal differs by more than ~37 degrees (``COS_SAME``), or
- its visible point is off pixel i's tangent plane (``PLANE_TOL``), or
- it is much farther than a pixel step on pixel i's surface can be
  (``STEP_TOL`` x l x footprint / cos: a depth discontinuity between
  parallel surfaces, e.g. a table top in front of the floor).

The boundary lies between the two pixels: the cap is half the distance to the
closest such neighbour, measured as min(|p_j - p_i|, l x footprint_i / cos_i)
(the second term: a background neighbour has no point; l = screen distance in
pixels), and never below ``MIN_PX`` pixel footprints.  Edges hidden behind
other geometry, or farther than ``reach`` pixels, are not seen; the cap is a
bias reduction, not a guarantee.  The same cap serves PPM and FPPM, so their
comparison is unchanged by it.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

#: Normals of one smooth surface within a few pixels agree to better than this
#: (cos 37 deg: a 24-segment sphere's facets are 15 deg apart).
COS_SAME = 0.8
#: |(p_j - p_i) . n_i| <= PLANE_TOL |p_j - p_i| on one surface (17 deg).
PLANE_TOL = 0.3
#: On one surface, a step of l pixels moves at most STEP_TOL l footprint / cos.
STEP_TOL = 2.0
#: Cosines below this are treated as this (grazing views: the world step per
#: pixel grows as 1 / cos, the estimate is kept finite).
COS_FLOOR = 0.2
#: The cap never goes below this many pixel footprints.
MIN_PX = 0.5
#: Largest screen-space reach [pixels] (cost grows as reach^2).
MAX_REACH = 8


def reach_for(radius_px: float) -> int:
    """Screen reach [px] that can lower a radius of ``radius_px`` footprints:
    a boundary l pixels away caps at about l/2 footprints, so l < 2 radius_px."""
    return int(min(MAX_REACH, max(1, math.ceil(2.0 * radius_px))))


def boundary_cap(p, n, wo, valid, footprint, H: int, W: int, reach: int) -> np.ndarray:
    """Half the distance to the nearest visible surface boundary, per pixel.

    p, n, wo: (H*W, 3) float64 visible points, unit geometric normals
      (oriented to wo) and unit directions to the camera, row-major over an
      H x W pixel grid (row 0 = one image edge, adjacent rows adjacent);
    valid: (H*W,) bool, the pixel sees a surface;
    footprint: (H*W,) float64 world size of one pixel at the visible point's
      depth [m];
    reach: neighbours within this many pixels (a disc) are examined.
    Returns (H*W,) float64 [m]: max(cap, MIN_PX footprint), inf where no
    boundary is within reach (and for invalid pixels).
    Cost: a compiled loop, 0.5-0.8 s at 1920x1080 with reach 4 on the shared
    2-core machine (the same rule in vectorised numpy: 8.6 s).
    """
    p = np.ascontiguousarray(np.asarray(p, np.float64).reshape(H * W, 3))
    n = np.ascontiguousarray(np.asarray(n, np.float64).reshape(H * W, 3))
    wo = np.ascontiguousarray(np.asarray(wo, np.float64).reshape(H * W, 3))
    valid = np.ascontiguousarray(np.asarray(valid, bool).reshape(H * W))
    fp = np.ascontiguousarray(np.asarray(footprint, np.float64).reshape(H * W))
    out = np.empty(H * W)
    _boundary_cap(p, n, wo, valid, fp, H, W, int(reach), out)
    return out


@nb.njit(cache=True, nogil=True)
def _boundary_cap(p, n, wo, valid, fp, H, W, reach, out):
    for y in range(H):
        for x in range(W):
            i = y * W + x
            out[i] = np.inf
            if not valid[i]:
                continue
            cos_i = max(abs(n[i, 0] * wo[i, 0] + n[i, 1] * wo[i, 1] + n[i, 2] * wo[i, 2]),
                        COS_FLOOR)
            step = fp[i] / cos_i             # world step per pixel on surface i
            cap = np.inf
            for dy in range(-reach, reach + 1):
                yy = y + dy
                if yy < 0 or yy >= H:
                    continue                 # the image border is no boundary
                for dx in range(-reach, reach + 1):
                    l2 = dy * dy + dx * dx
                    if l2 == 0 or l2 > reach * reach:
                        continue
                    xx = x + dx
                    if xx < 0 or xx >= W:
                        continue
                    ell = math.sqrt(l2)
                    reach_i = ell * step
                    j = yy * W + xx
                    if not valid[j]:
                        cap = min(cap, 0.5 * reach_i)   # background: the surface ends
                        continue
                    d0 = p[j, 0] - p[i, 0]
                    d1 = p[j, 1] - p[i, 1]
                    d2 = p[j, 2] - p[i, 2]
                    dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                    same = ((n[i, 0] * n[j, 0] + n[i, 1] * n[j, 1] + n[i, 2] * n[j, 2]) >= COS_SAME
                            and abs(d0 * n[i, 0] + d1 * n[i, 1] + d2 * n[i, 2]) <= PLANE_TOL * dist
                            and dist <= STEP_TOL * reach_i)
                    if not same:
                        cap = min(cap, 0.5 * min(dist, reach_i))
            if cap < np.inf:
                cap = max(cap, MIN_PX * fp[i])
            out[i] = cap
