"""Memory estimate before the first pass: an upper bound on the render's peak.

A render that cannot fit fails up front with the setting to change, instead of
the machine swapping or the process being killed mid-render.

peak <= resident + pixels + AOVs + photons + geometry + occlusion grid, where
``resident`` is what the process holds when the Renderer is built (Python,
numpy, numba, Embree, Blender and the exported scene, textures included: they
are loaded by then and the core makes no full copy of them), read from the
OS, and the other parts are what the passes still allocate.  Only those other
parts need free memory (:func:`check_fits`).  The estimate is also never less
than the process's own peak so far (``VmHWM``: the export's peak).

Per-item costs are upper bounds measured with peak RSS (docs/reliability.md,
"Memory"; tests/test_reliability2.py checks estimate >= peak <= 1.5 x peak):

- per pixel: progressive state (R^2, N, tau, L_sum, r_pred, held, M, depth),
  one pass's visible points (core.sppm.visible_points: float64 positions and
  geometric normals, float32 directions, colours and throughputs: 153 B) and
  the camera and direct-light temporaries -> BYTES_PER_PIXEL, plus
  BYTES_PER_FIRST_HIT where the camera pass keeps its first hits' data
  (``first_hits``: the film's data passes, photon merging; float64
  position, normal and emission, the triangle and the hit flag: 77 B of
  ``FirstHit`` that ``CameraPass(first_data=False)`` does not make).  The
  two were 1040 B together, measured: peak growth 646 B per pixel with the
  compiled stages (64^2 .. 640^2, a point light; 997 B before them), the
  numpy light sampler (environment maps, textured emitters: <= 890 B) and
  the delta chains' buffers where every pixel continues (+272 B).  The
  camera pass's first vertex and the compiled direct light now run in
  blocks of 65536 pixels (no pixel-sized rays, uniforms or Embree hits): a
  1080p Cornell box pass without first-hit data grows by 812-828 B a pixel
  with its 8 sector cells (docs/architecture.md, "The 1080p pass: camera
  and direct light in blocks"), bounded by 1152 B a pixel.  The numpy light
  sampler and the delta chains at every pixel are not measured lower, so
  the sum stays 1040 B.  Two threads now work on two of those blocks at
  once (~270 B a pixel of a camera block, ~170 B of a direct-light one):
  one more block's temporaries, at most ~140 B a pixel of the image (at
  2 x 65536 pixels, less above), alive in those stages only and freed
  before the grid build, the pass's peak
- per AOV channel per pixel: the film's float32 layer, its float64 source and
  the EXR's copy -> BYTES_PER_AOV_CHANNEL
- per radius-histogram bin per pixel (Quantile estimator): the uint32 state,
  one pass's histogram and its sum -> 3 x 4 bytes
- per sector cell per pixel (the radius rules and verified holds that read
  the photons' sector counts, core.sppm.update.needs_sectors: on by
  default): the float64 state, the pass's float64 sums and two threads'
  int32 gather rows -> BYTES_PER_SECTOR_CELL
- the kernel clip (settings.clip_kernel, core.sppm.clip): one uint64 a
  pixel, kept from pass to pass -> BYTES_PER_CLIP (its rays are cast in
  blocks, two at a time by two threads: ~30 MB at most, freed before the
  grid build, the pass's peak), and its grid of the triangles near a point
  (``clip.NearGrid``, once a render) -> BYTES_PER_CLIP_TRIANGLE a triangle
  plus CLIP_GRID_BYTES
- per photon of a chunk: emission, bounce and deposit arrays and the
  gather's sorted copies -> BYTES_PER_PHOTON; and for every chunk queued
  beyond one ahead of the gather (core.sppm.photon_pass.AHEAD_CHUNKS), one
  more deposit set of the tracer's pool -> BYTES_PER_QUEUED_PHOTON (the
  pool's deposits at a 1080p Cornell pass's peak: 4 sets, 185 MiB, with one
  chunk ahead; 5 sets, 239 MiB, with two)
- per triangle: scene arrays, Embree BVH, the plan's copies -> BYTES_PER_TRIANGLE
- per occlusion voxel: kept + during the build -> BYTES_PER_VOXEL
- textures: one more copy of their pixels (float64 gathers of the texels a
  pass touches, bounded by the image) -> their bytes
- the compiled kernels numba loads at the first pass and Embree's per-thread
  buffers -> KERNEL_BYTES (measured: 110 MiB between the estimate and the
  peak of a 64^2 render of 2000 photons, with every other part ~60 MiB)

Kernels compiled in the process after the estimate are not counted: a
render loads its kernels before the Renderer exists (core.warmup: a
subprocess compiles them), so ``resident`` holds them; a process without
that warm-up (the benches, the tests) compiles at its first pass when the
shared kernel cache misses, and numba's compiler then stays in its heap
(docs/architecture.md "The 1080p peak: kernels compiled in the measuring
process").

The costs count the pages an array touches: the Renderer builds and runs
its passes without numpy's huge-page advice (:func:`small_pages`), under
which a partly touched array or reused heap range is resident in 2 MiB
units, by an amount that depends on the kernel's free huge pages and on
timing, not on the render (the 1080p pass held 0.87 GiB in huge pages
at its peak with the advice, 0.02-0.04 GiB without).
"""
from __future__ import annotations

import ctypes
import functools
import os
import threading

import numpy as np

from .errors import MemoryBudgetError

BYTES_PER_PIXEL = 960
BYTES_PER_FIRST_HIT = 80
BYTES_PER_AOV_CHANNEL = 48
BYTES_PER_HIST_BIN = 12
BYTES_PER_SECTOR_CELL = 24
BYTES_PER_CLIP = 8
BYTES_PER_CLIP_TRIANGLE = 48
CLIP_GRID_BYTES = 64 * 2**10
# + 127 in round 21: the gather's sorted copy became one float64 record a
# deposit (hashgrid.PHOTON_RECORD), 36 B more than its float32 geometry
# columns, at the ~3.5 deposits a photon of a 1080p Cornell chunk
BYTES_PER_PHOTON = 1356
BYTES_PER_QUEUED_PHOTON = 432
BYTES_PER_TRIANGLE = 400
# An Embree view of the scene for one kind of ray with objects hidden from it
# (core.accel.Accel.for_rays: camera, shadow): its own BVH over the triangles
# it keeps (measured 136 B a triangle of 1M, as the full scene's BVH: 135 B).
BYTES_PER_VIEW_TRIANGLE = 140
BYTES_PER_VOXEL = 192
KERNEL_BYTES = 96 * 2**20
BASE_BYTES = 300 * 2**20          # resident size when the OS cannot say (Python, numpy, numba, Embree)


def _proc_status(key: str) -> int | None:
    """A ``/proc/self/status`` size in bytes (VmRSS, VmHWM), or None off Linux."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def resident_bytes() -> int:
    """Memory the process holds now (VmRSS), BASE_BYTES when unknown."""
    v = _proc_status("VmRSS")
    return BASE_BYTES if v is None else v


def peak_bytes_so_far() -> int:
    """The process's peak resident size so far (VmHWM), 0 when unknown."""
    return _proc_status("VmHWM") or 0


def keeps_first_hits(data_passes: bool, integrator: str, merging: bool | None = None) -> bool:
    """Whether the camera pass keeps its first hits' data
    (``CameraPass.first_data``, core.sppm.visible_points): the film's data
    passes read them (core.sppm.film.data_passes), and so does photon
    merging (core.plan.merges; only COMBINED merges).  merging None: not
    known yet (the estimate comes before the plan): COMBINED may merge."""
    if data_passes:
        return True
    return integrator == "COMBINED" and (merging is None or bool(merging))


def view_triangles(visibility, scene=None) -> int:
    """The triangles of the Embree views a render builds besides the full
    scene (core.accel.Accel.for_rays at camera and shadow rays), from a
    Scene's tri_visibility (T,) uint8 or None; with the scene, also shadow
    linking's (core.scene.shadow_linking: at most every triangle a view, a
    view a distinct shadow membership) and the shadow catchers' view
    (core.sppm.shadow_catcher: the catchers alone)."""
    from .accel import RAY_CAMERA, RAY_SHADOW, hidden_triangles
    n = 0
    for flag in (RAY_CAMERA, RAY_SHADOW):
        hid = hidden_triangles(visibility, flag)
        n += 0 if hid is None else int(np.count_nonzero(~hid))
    if scene is not None and getattr(scene, "tri_blocker", None) is not None:
        from .scene.linking import LINK_ALL
        sets = {int(lt.shadow_sets) for lt in scene.lights}
        if scene.tri_shadow_sets is not None:
            sets |= {int(s) for s in np.unique(scene.tri_shadow_sets)}
        n += len(sets - {LINK_ALL}) * int(scene.tri_blocker.shape[0])
    if scene is not None and getattr(scene, "tri_catcher", None) is not None:
        n += int(np.count_nonzero(scene.tri_catcher))
    return n


def estimate(n_pixels: int, photon_chunk: int, n_triangles: int, grid_res: int,
             use_grid: bool, aov_channels: int = 0, hist_bins: int = 0,
             texture_bytes: int = 0, resident: int | None = None,
             sector_cells: int = 0, first_hits: bool = True,
             clip_kernel: bool = False, chunks_ahead: int = 1,
             view_triangles: int = 0) -> dict:
    """Bytes per component and 'total' (ints): an upper bound on the peak.

    aov_channels: channels of the enabled AOVs (all layers together);
    hist_bins: radius-histogram bins per pixel (0 without the Quantile estimator);
    sector_cells: sector counts per pixel (0 unless the gather counts them);
    texture_bytes: bytes of the scene's texture images;
    first_hits: the camera pass keeps its first hits' data
    (:func:`keeps_first_hits`); clip_kernel: the gather's discs are clipped;
    chunks_ahead: photon chunks traced ahead of the gather (AHEAD_CHUNKS);
    view_triangles: the triangles of the Embree views of the ray kinds
    some objects hide from (:func:`view_triangles`);
    resident: bytes already held (None: :func:`resident_bytes`).  'runtime' is
    that resident size; 'total' is at least the peak so far.
    """
    parts = {
        "pixels": n_pixels * (BYTES_PER_PIXEL + BYTES_PER_FIRST_HIT * bool(first_hits)
                              + BYTES_PER_AOV_CHANNEL * aov_channels
                              + BYTES_PER_HIST_BIN * hist_bins
                              + BYTES_PER_SECTOR_CELL * sector_cells
                              + BYTES_PER_CLIP * bool(clip_kernel)),
        "photons": photon_chunk * (BYTES_PER_PHOTON
                                   + max(chunks_ahead - 1, 0) * BYTES_PER_QUEUED_PHOTON),
        "geometry": n_triangles * BYTES_PER_TRIANGLE + bool(clip_kernel) * (
            n_triangles * BYTES_PER_CLIP_TRIANGLE + CLIP_GRID_BYTES)
        + int(view_triangles) * BYTES_PER_VIEW_TRIANGLE,
        "occlusion_grid": (grid_res ** 3) * BYTES_PER_VOXEL if use_grid else 0,
        "textures": int(texture_bytes),
        "kernels": KERNEL_BYTES,
        "runtime": resident_bytes() if resident is None else int(resident),
    }
    total = sum(parts.values())
    parts["total"] = max(total, peak_bytes_so_far()) if resident is None else total
    return parts


_LIBC = []
# release_free_heap does nothing for fewer items (pixels, visible points):
# the heap a smaller image leaves is not worth a call.
RELEASE_MIN_ITEMS = 1 << 18


def release_free_heap(items: int = RELEASE_MIN_ITEMS) -> bool:
    """Return the free pages of malloc's heaps to the OS (glibc's
    ``malloc_trim(0)``) when items (the pixels or visible points of the
    arrays just freed) >= RELEASE_MIN_ITEMS; False when it did not (fewer
    items, or no glibc: macOS, Windows, musl).

    numpy's pixel-sized arrays up to glibc's dynamic mmap threshold (32 MiB
    at most) live in the heap, and glibc keeps their pages resident after
    they are freed; later, larger arrays are mmapped beside them, so the
    kept pages add to the peak.  A call costs milliseconds (it walks the
    heap): a few a pass, for large images.
    """
    if items < RELEASE_MIN_ITEMS:
        return False
    if not _LIBC:
        try:
            _LIBC.append(ctypes.CDLL("libc.so.6").malloc_trim)
        except (OSError, AttributeError):
            _LIBC.append(None)
    if _LIBC[0] is None:
        return False
    _LIBC[0](0)
    return True


_SMALL = {"depth": 0, "saved": None}
_SMALL_LOCK = threading.Lock()


def _madvise_switch():
    """numpy's (get, set) of its huge-page advice, or None (numpy without it)."""
    try:
        from numpy._core import multiarray as m
    except ImportError:                                   # numpy < 2
        from numpy.core import multiarray as m
    get = getattr(m, "_get_madvise_hugepage", None)
    put = getattr(m, "_set_madvise_hugepage", None)
    return None if get is None or put is None else (get, put)


def small_pages(f):
    """Decorator: f runs with numpy's huge-page advice off (4 KiB pages for
    every array it allocates, its threads' included), restored after the
    last of the calls that overlap.

    numpy advises transparent huge pages (``madvise(MADV_HUGEPAGE)``) for
    every array of 4 MiB and more, heap-backed ones included.  Where the
    kernel honours it (THP ``madvise`` mode), a touched 4 KiB page of such a
    range faults in, or is later collapsed by ``khugepaged`` into, a whole
    2 MiB page: arrays touched in part (pooled deposit rows, heap ranges
    reused after ``release_free_heap``) become resident in 2 MiB units,
    by an amount that depends on the system's free huge pages and on when
    ``khugepaged`` scanned, i.e. on timing and on the machine's state:
    the 1080p pass read 1.73-2.16 GiB from run to run with the advice,
    docs/architecture.md "The 1080p peak without huge pages".  The process
    switch is numpy's own (``NUMPY_MADVISE_HUGEPAGE=0`` at import): Blender's
    numpy keeps it outside the passes."""
    sw = _madvise_switch()
    if sw is None:
        return f

    @functools.wraps(f)
    def g(*args, **kw):
        with _SMALL_LOCK:
            if _SMALL["depth"] == 0:
                _SMALL["saved"] = sw[0]()
                sw[1](False)
            _SMALL["depth"] += 1
        try:
            return f(*args, **kw)
        finally:
            with _SMALL_LOCK:
                _SMALL["depth"] -= 1
                if _SMALL["depth"] == 0:
                    sw[1](_SMALL["saved"])
    return g


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
    """Raise MemoryBudgetError naming the largest component and its setting.

    What the passes still allocate (every part but 'runtime', which the
    process holds already) must fit in the memory available now.
    """
    avail = available_bytes() if available is None else available
    more = sum(v for k, v in parts.items() if k not in ("total", "runtime"))
    if avail is None or more <= avail:
        return
    hints = {"pixels": "lower the resolution (or its percentage), render a border region or "
                       "turn AOVs off",
             "photons": "lower 'Photons per pass'",
             "geometry": "simplify the geometry (fewer triangles)",
             "occlusion_grid": "lower 'Occlusion grid' resolution or turn frequency analysis off",
             "textures": "use smaller images for the textures",
             "kernels": "close other programs"}
    worst = max(hints, key=lambda k: parts.get(k, 0))
    gib = 2.0 ** 30
    raise MemoryBudgetError(
        f"This render needs about {more / gib:.1f} GiB more (peak {parts['total'] / gib:.1f} GiB) "
        f"but only {avail / gib:.1f} GiB is free (largest part: {worst}, "
        f"{parts[worst] / gib:.1f} GiB): {hints[worst]}.")
