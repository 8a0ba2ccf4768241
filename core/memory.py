"""Memory estimate before the first pass.

A render that cannot fit fails up front with the setting to change, instead of
the machine swapping or the process being killed mid-render.  Per-item costs
are upper bounds read off the arrays the renderer allocates (float64 SoA):

- per pixel: progressive state (R^2, N, tau, L_sum, r_pred, held, M, depth:
  ~90 B) + one pass's visible points (p, ng, ns, wo, colours, beta, albedo...:
  ~300 B) + camera-pass temporaries (~600 B)            -> 1 KiB
- per photon of a chunk: emission, bounce and deposit arrays (~800 B) and the
  gather's sorted copies (~100 B per deposit, ~4 deposits) -> 1.2 KiB
- per triangle: scene arrays (100 B), Embree BVH (~150 B), exporter copies -> 400 B
- per occlusion voxel: 41 B kept + ~150 B during the build -> 192 B
"""
from __future__ import annotations

import os

from .errors import MemoryBudgetError

BYTES_PER_PIXEL = 1024
BYTES_PER_PHOTON = 1229
BYTES_PER_TRIANGLE = 400
BYTES_PER_VOXEL = 192
BASE_BYTES = 300 * 2**20          # Python, numpy, numba, Embree runtime


def estimate(n_pixels: int, photon_chunk: int, n_triangles: int, grid_res: int,
             use_grid: bool) -> dict:
    """Bytes per component and 'total' (ints)."""
    parts = {
        "pixels": n_pixels * BYTES_PER_PIXEL,
        "photons": photon_chunk * BYTES_PER_PHOTON,
        "geometry": n_triangles * BYTES_PER_TRIANGLE,
        "occlusion_grid": (grid_res ** 3) * BYTES_PER_VOXEL if use_grid else 0,
        "runtime": BASE_BYTES,
    }
    parts["total"] = sum(parts.values())
    return parts


def available_bytes() -> int | None:
    """Memory the OS can give now (Linux MemAvailable), or None if unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_fits(parts: dict, available: int | None = None) -> None:
    """Raise MemoryBudgetError naming the largest component and its setting."""
    avail = available_bytes() if available is None else available
    if avail is None or parts["total"] <= avail:
        return
    hints = {"pixels": "lower the resolution (or its percentage) or render a border region",
             "photons": "lower 'Photons per pass'",
             "geometry": "simplify the geometry (fewer triangles)",
             "occlusion_grid": "lower 'Occlusion grid' resolution or turn frequency analysis off",
             "runtime": "close other programs"}
    worst = max((k for k in parts if k != "total"), key=lambda k: parts[k])
    gib = 2.0 ** 30
    raise MemoryBudgetError(
        f"This render needs about {parts['total'] / gib:.1f} GiB but only {avail / gib:.1f} GiB "
        f"is free (largest part: {worst}, {parts[worst] / gib:.1f} GiB): {hints[worst]}.")
