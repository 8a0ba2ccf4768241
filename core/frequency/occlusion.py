"""Transitional re-export: the occlusion grid now lives in two modules.

- ``core.frequency.occlusion_grid``: the build (distance field, bi-cones,
  MarchBlocks), ``OcclusionGrid``, ``default_locality``, ``check_locality``;
- ``core.frequency.occlusion_march``: the march (``march_segment``,
  ``march_occlusion``).

Kept only until the importers outside core/frequency (core/render.py,
tests/test_reliability.py) import those modules; then delete this file.
"""
from .occlusion_grid import (BYTES_PER_VOXEL, MARCH_BLOCK, MarchBlocks,  # noqa: F401
                             OcclusionGrid, build_occlusion_grid, build_occlusion_grid_for_scene,
                             check_locality, default_locality, grid_bounds, march_blocks,
                             union_meets)
from .occlusion_march import march_occlusion  # noqa: F401
