"""Compile a render's kernels before its first pass needs them: its own first.

Numba compiles a kernel at its first call; on a machine with an empty cache
that would happen inside pass 1, where it counts against the time limit and
where Esc cannot interrupt it.  Instead, before the Renderer exists:

- **the render's own job first** (:func:`render_job`): the exported scene and
  settings of the render itself, for two passes, at its own resolution and
  photon count, so the kernels compiled are exactly those its passes call,
  and only those (docs/interactive.md: the demo's Cornell box, light tracing
  alone, compiles 8 kernels in ~16 s instead of every variant's in ~130 s);
- **then every variant** (:func:`warmup_jobs`: tiny synthetic scenes, a
  closed room with diffuse, rough glossy, mirror, glass and emissive surfaces
  and every light kind, one pass per settings variant, so that the camera,
  direct-light, photon, emission, frequency, occlusion, edge and gather
  kernels all compile), only when asked for (:meth:`Warmup.start`: Blender's
  UI, so the next render with other settings is warm too), at a lower
  priority, and never waited for by a one-shot render (the CLI, ``blender
  -b``).  With a warm on-disk cache the same calls only load the kernels.

:class:`Warmup` runs this in a background thread of the process, and has a
subprocess do the compiling (:class:`_Child`, :func:`child_main`):

- the compile runs in a separate process: numba's compiler is Python, and a
  compiling thread inside Blender holds the GIL and, worse, makes the cyclic
  garbage collector run full collections over the whole process (compiling
  creates ~100 000 cyclic objects at a time): measured pauses of 0.3-0.7 s
  of every other Python thread, i.e. Blender's UI (docs/interactive.md).  A
  subprocess shares neither, and uses another core.  It imports ``core``
  under this process's very module name (``bl_ext.<repo>.fppm.core`` inside
  Blender; the cache is keyed by it, ``core/_numba_cache.py``), writes the
  kernels to the same cache folder, and takes one job after another (numba
  and the renderer are imported once), ending 20 s after its last;
- for each job the child records the kernels it holds and their argument
  types (:func:`used_kernels`); this process's thread then loads exactly
  those from disk (:func:`load_kernels`, ``Dispatcher.compile`` of a cached
  signature: a load, well under a second for one render's kernels), so that
  they are in memory when the first pass starts, and nothing compiles twice.
  If the subprocess cannot run (no usable Python executable), the thread
  compiles them itself;
- beside a render's job that traces photons, on a cold cache, a second
  subprocess compiles the photon gather's kernels (:func:`compile_gather`,
  about 40 % of such a job's compile) into the same cache on the other
  core, then, beside photon mapping with frequency photons or Combined
  merging photons, the stages that job reaches last
  (:func:`compile_late`), while the job's process renders the
  other stages and then finds them there; beside camera or light paths
  without photons (path tracing, light tracing, and Combined's default on
  a scene without mirror or glass) the subprocess compiles their late
  stages alone; it ends when the job does (:meth:`Warmup._start_gather`);
- :meth:`Warmup.wait_for` and :meth:`Warmup.wait` poll ``should_stop`` every
  50 ms, so a render waiting for the compile can be cancelled at once; the
  compile itself goes on in the background (the next render needs it).

A marker file per source version and job (``warmup-<source>[-<job>].json``
in the cache folder) records that a compile finished, how long it took and
the kernels it loaded, so that a later process loads them without a child,
and callers can tell the user whether this is a first use and about how long
it will take (the last measured compile of that job, :func:`expected_seconds`).
"""
from __future__ import annotations

import base64
import dataclasses
import hashlib
import json
import math
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import weakref
from typing import Callable, Optional

import numpy as np

from . import _numba_cache
from .scene.model import DIFFUSE, GLASS, GLOSSY, Camera, Light, Lobe, Material, make_scene
from .settings import RenderSettings

# Assumed length of a first compile when this machine never finished one
# (used only for the message and the progress bar): every variant, and one
# render's own job by what it compiles (job_kind): wall seconds on an empty
# cache of the project's 2-core machine (docs/interactive.md "The first-use
# compile by kind of render, round 49", "One signature a kernel, round 50",
# for the kinds with photons "The second compiling process takes the late
# stages, round 51", and for the others "The paths' late stages in the
# second process, round 52").
DEFAULT_COMPILE_SECONDS = 410.0
JOB_SECONDS = {"light": 35.0, "path": 50.0, "combined": 40.0, "combined+photons": 150.0,
               "photons": 85.0, "photons+frequency": 115.0}
_CORE = os.path.dirname(os.path.abspath(__file__))


def _quad(c, ex, ey):
    """Two triangles c +- ex +- ey (normal ex x ey); (2, 3, 3) float64."""
    c, ex, ey = (np.asarray(v, np.float64) for v in (c, ex, ey))
    p00, p10, p11, p01 = c - ex - ey, c + ex - ey, c + ex + ey, c - ex + ey
    return [[p00, p10, p11], [p00, p11, p01]]


def _box(c, h):
    """12 outward-facing triangles of the cube c +- h."""
    c = np.asarray(c, np.float64)
    tris = []
    for axis in range(3):
        e = np.eye(3)
        n, u, v = e[axis], e[(axis + 1) % 3], e[(axis + 2) % 3]
        tris += _quad(c + n * h, u * h, v * h)           # normal +axis
        tris += _quad(c - n * h, v * h, u * h)           # normal -axis
    return tris


def _look_at(eye, target):
    """(4, 4) camera-to-world looking from eye at target, +Z up (Blender's -Z view)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, back, eye
    return m


def _translate(x, y, z):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def warmup_scene(res: int = 12, analytic_lights: tuple = ("POINT", "AREA"),
                 glossy: bool = True, environment: bool = False, normal_map: bool = False,
                 metal: bool = False, world_color: tuple = (0.0, 0.0, 0.0)):
    """A synthetic scene of the warm-up (``core.scene.model.Scene``), res x res px.

    A closed 4 x 4 x 2 m room (so that nearly every photon is deposited, and a
    pass of a few ten thousand photons reaches the gather's parallel path)
    with a diffuse floor and walls, a rough glossy wall, a mirror, a glass
    cube and an emissive ceiling quad, lit by ``analytic_lights`` (kinds of
    ``core.scene.model.Light``; POINT, SPOT and AREA photons are emitted by
    the compiled sampler, SUN by the numpy one).  glossy=False makes the
    rough glossy wall diffuse (a Lambert-only room: the small jobs of
    tests/test_warmup.py).  environment=True adds a small environment map
    to the world (its photons' compiled emission, lights.environment);
    world_color a constant world beside the lights (its photons'
    environment_kernels.constant_world_photons, the lights' rows emitted
    apart, lights.emission._compiled_rows).  normal_map=True gives the left wall a normal-mapped rough glossy
    material over a textured diffuse base (the camera paths' compiled
    Normal Map, scene.normal_kernels, about 4 s to compile on first use, and
    a textured hit's colour row, materials.hit_colors, about 1 s).
    metal=True lays a rough metal plate (a Principled-like F82 lobe, no
    diffuse) on the floor: photon mapping's glossy chains (its glossy
    points' compiled BSDF samples and light densities, core.sppm.glossy_mis).
    """
    mats = [Material("diffuse", (Lobe(DIFFUSE, (0.8, 0.8, 0.8)),)),
            Material("glossy", (Lobe(GLOSSY, (0.8, 0.6, 0.4), roughness=0.3),
                                Lobe(DIFFUSE, (0.2, 0.2, 0.2), weight=0.5))
                     if glossy else (Lobe(DIFFUSE, (0.8, 0.6, 0.4)),)),
            Material("mirror", (Lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.0),)),
            Material("glass", (Lobe(GLASS, (1.0, 1.0, 1.0), ior=1.5),)),
            Material("emitter", (Lobe(DIFFUSE, (0.0, 0.0, 0.0)),), emission=(5.0, 5.0, 5.0))]
    kw = {}
    if normal_map:
        from .scene.normals import NORMAL_MAP, NormalInput
        mats.append(Material("bumped", (Lobe(GLOSSY, (0.8, 0.8, 0.8), roughness=0.5),
                                        Lobe(DIFFUSE, (0.5, 0.5, 0.5), weight=0.5,
                                             color_texture=1)),
                             normal=NormalInput(NORMAL_MAP, 0)))
        img = np.full((4, 4, 3), 0.5, np.float32)
        img[..., 2] = 1.0
        img[1, 2] = (0.7, 0.4, 0.9)
        kw["textures"] = [img, np.linspace(0.2, 0.9, 12, dtype=np.float32).reshape(2, 2, 3)]
    parts = [(_quad((0, 0, 0), (2, 0, 0), (0, 2, 0)), 0),            # floor, +Z
             (_quad((0, 0, 2), (0, 2, 0), (2, 0, 0)), 0),            # ceiling, -Z
             (_quad((-2, 0, 1), (0, 2, 0), (0, 0, 1)), 0),           # left wall, +X
             (_quad((2, 0, 1), (0, 0, 1), (0, 2, 0)), 0),            # right wall, -X
             (_quad((0, -2, 1), (0, 0, 1), (2, 0, 0)), 0),           # front wall, +Y
             (_quad((0, 2, 1), (2, 0, 0), (0, 0, 1)), 1),            # back wall, -Y
             (_quad((-1.9, 0.5, 0.6), (0, 0.5, 0), (0, 0, 0.6)), 2),  # mirror, +X
             (_box((0.4, 0.0, 0.35), 0.35), 3),                      # glass cube
             (_quad((0, 0.5, 1.95), (0.3, 0, 0), (0, -0.3, 0)), 4)]  # ceiling lamp, -Z
    if normal_map:
        parts[2] = (parts[2][0], len(mats) - 1)                    # the left wall
    if metal:
        mats.append(Material("metal", (Lobe(GLOSSY, (0.9, 0.7, 0.4), roughness=0.3,
                                            fresnel="F82"),)))
        parts.append((_quad((-0.8, 0.6, 0.01), (0.5, 0, 0), (0, 0.5, 0)), len(mats) - 1))
    tris = [t for p, _ in parts for t in p]
    tri_mat = [m for p, m in parts for _ in p]
    if normal_map:
        kw["tri_uv"] = (0.5 * np.asarray(tris, np.float64)[:, :, 1:]).astype(np.float32)
    at = {"POINT": _translate(-0.6, -0.6, 1.5), "AREA": _translate(0.8, -0.5, 1.8),
          "SPOT": _translate(0.5, 0.5, 1.9), "SUN": _translate(0.0, 0.0, 1.9)}
    lights = [Light(k.lower(), k, (40.0, 40.0, 40.0) if k != "SUN" else (2.0, 2.0, 2.0),
                    at[k], radius=0.05, size=0.4) for k in analytic_lights]
    cam = Camera(kind="PERSP", matrix_world=_look_at((0.0, -1.9, 1.2), (0.0, 0.3, 0.4)),
                 lens=20.0, resolution=(res, res), clip_start=0.01, clip_end=100.0)
    sc = make_scene(tris, mats, lights, cam, tri_mat=tri_mat, world_color=world_color, **kw)
    if environment:
        from .scene.textures import EnvironmentMap
        sc.world_map = EnvironmentMap(np.full((4, 8, 4), 0.2, np.float32))
    return sc


def warmup_jobs() -> list:
    """(scene, settings) pairs, one per code path whose kernels differ; one pass each.

    The first has an environment map besides its lights (the visible
    points' map by two strategies).  The second gathers enough photons for
    the gather's parallel path
    (``hashgrid.PARALLEL_MIN_PHOTONS``), every one a frequency photon so that
    the QUANTILE estimator's pair search takes it too; the third covers the
    classic-PPM options, a soft spot and the numpy-sampled sun beside an
    environment map's photons; the last a constant world beside the lights.
    """
    # frequency_start 1: the one pass traces frequency photons (with the default
    # start, 2, pass 1 traces none and their kernels would compile in the render)
    base = RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=3000, seed=1,
                          frequency_start=1)
    room = warmup_scene()
    # The first job's room is lit by an environment map too: the visible
    # points' next-event estimation weighs the map's light and BSDF samples
    # (core.lights.map_mis_kernels), on two threads (run_jobs' split_first);
    # and a metal plate on its floor: photon mapping's glossy chains.
    return [(warmup_scene(environment=True, metal=True), base),
            (room, base.replace(photons_per_pass=40_000, frequency_fraction=1.0,
                                frequency_estimator="QUANTILE", frequency_model="PAPER",
                                aov_radius=True, aov_predicted_radius=True, aov_spectrum=True,
                                aov_photon_count=True, aov_held=True, radius_mode="WORLD")),
            (warmup_scene(analytic_lights=("SPOT", "SUN"), environment=True),
             base.replace(use_frequency=False, photons_for_direct=True,
                          fixed_visible_points=True, cap_radius_at_edges=False)),
            # The compiled camera paths and the combined integrator's kernels
            # (COMBINED is the default integrator: tests/test_warmup.py renders
            # it), with the rough glossy wall: its light paths' compiled
            # densities (compiled.scatter_pdfs) compile here too; and a
            # normal-mapped wall with a colour texture (the camera paths'
            # Normal Map kernel and textured colour rows).
            (warmup_scene(normal_map=True),
             base.replace(integrator="COMBINED", photons_per_pass=2000, camera_samples=1)),
            # A late pass's few frequency photons, traced again in a batch of
            # their own (core.sppm.photons.RETRACE_MAX_SHARE), in the room
            # with a constant world beside its lights (the glass sphere's and
            # the coffee cup's emission)
            (warmup_scene(world_color=(0.05, 0.05, 0.05)),
             base.replace(frequency_fraction=0.02))]


def run_jobs(jobs, should_stop: Optional[Callable[[], bool]] = None,
             split_first: bool = False) -> float:
    """Render each job (``(scene, settings)`` or ``(scene, settings, passes)``)
    through ``Renderer`` for its settings' passes; returns the seconds it took.

    split_first: the first job takes the per-pixel stages' threaded paths at
    any size (:class:`_split_paths`).  Raises RenderCancelled when
    ``should_stop()`` turns True (polled by the Renderer during its set-up
    and passes).
    """
    from .errors import RenderCancelled
    from .render import Renderer
    t0 = time.perf_counter()
    for k, job in enumerate(jobs):
        scene, st, passes = (tuple(job) + ((),))[:3]
        with _split_paths(split_first and k == 0):
            # glossy chains kept whatever the lights: the first job's metal
            # plate compiles the glossy points' kernels beside its point light
            r = Renderer(scene, st, log=lambda _m: None, should_stop=should_stop, passes=passes,
                         force_stages=("glossy chains",))
            r.run(should_stop=should_stop)
        if should_stop is not None and should_stop():
            raise RenderCancelled("cancelled")
    return time.perf_counter() - t0


def compile_kernels(should_stop: Optional[Callable[[], bool]] = None) -> float:
    """Render every job of :func:`warmup_jobs` for one pass; returns the seconds it took."""
    return run_jobs(warmup_jobs(), should_stop, split_first=True)


class _split_paths:
    """With on=True, the per-pixel stages take their threaded paths at any
    size (their thresholds set to 1 for the block), so that the first job
    compiles the kernels a large render uses (camera rays, grid build,
    update, film).  pixels: only the thresholds a render of that many
    pixels reaches (each stage splits from ``count >= threshold``), so that
    a smaller crop of the render takes the render's own paths
    (:func:`compile_late`)."""
    _LIMITS = (("scene.camera", "PARALLEL_MIN"), ("sppm.update", "PARALLEL_MIN"),
               ("sppm.film", "PARALLEL_MIN"), ("sppm.hashgrid", "PARALLEL_MIN_VPS"),
               ("sppm.visible_points", "INTERSECT_SPLIT_MIN"))

    def __init__(self, on: bool, pixels: Optional[int] = None):
        import importlib
        self.on = on
        self.mods = [(importlib.import_module("." + m, __package__), a) for m, a in self._LIMITS]
        if pixels is not None:
            self.mods = [(m, a) for m, a in self.mods if getattr(m, a) <= pixels]

    def __enter__(self):
        if self.on:
            self.saved = [getattr(m, a) for m, a in self.mods]
            for m, a in self.mods:
                setattr(m, a, 1)

    def __exit__(self, *exc):
        if self.on:
            for (m, a), v in zip(self.mods, self.saved):
                setattr(m, a, v)


# --- the photon gather's kernels, beside a render's job ----------------------

def gather_variant(job) -> tuple:
    """(threaded, sectors, clip, pairs, threaded build): the variant of the
    photon gather a pass of the render job ``(scene, settings, ...)`` most
    likely calls (core/sppm/photon_pass.py: the gather of a chunk of photons
    is split over threads from ``hashgrid.PARALLEL_MIN_PHOTONS``, counts
    sectors for ``update.needs_sectors``, takes clip codes with
    ``clip_kernel`` and frequency pairs with the frequency photons; the grid
    build is split from ``hashgrid.PARALLEL_MIN_VPS`` visible points, one
    per pixel).  For :func:`compile_gather`: a wrong guess leaves that
    variant to the job's process, as before."""
    from .sppm.hashgrid import PARALLEL_MIN_PHOTONS, PARALLEL_MIN_VPS
    from .sppm.photon_pass import PHOTON_CHUNK
    from .sppm.update import needs_sectors
    scene, st = tuple(job)[:2]
    pixels = int(scene.camera.resolution[0]) * int(scene.camera.resolution[1])
    return (min(st.photons_per_pass, PHOTON_CHUNK) >= PARALLEL_MIN_PHOTONS,
            bool(needs_sectors(st, st.use_frequency)), bool(st.clip_kernel),
            bool(st.use_frequency), pixels >= PARALLEL_MIN_VPS)


def compile_gather(first: Optional[tuple] = None, only: bool = False, merge: bool = True,
                   should_stop: Optional[Callable[[], bool]] = None) -> None:
    """Compile the photon gather's kernels as a pass calls them
    (core/sppm/photon_pass.py: kept grid buffers, GatherBuffers with and
    without sectors, clip codes or none, frequency pairs or not, then
    ``fold`` with the float32 and float64 albedo; the merge's gather
    without buffers: core/integrators/merge_kernels.py), on one thread and
    split, on 64 visible points and 400 photons: about 40 % of a photon
    render's first-use compile, run by a second process while the first
    renders the job (:meth:`Warmup._compile_in_child`; tests/precompile.py
    too).  Each variant is (threaded, sectors, clip, pairs), the grid build
    threaded with the gather.  first: the variant to compile before the
    others (:func:`gather_variant`, whose fifth item, the threaded build,
    is then taken apart; None: in the order of the loops, one thread first),
    the others by how far they are from it; only: that variant alone, and
    with merge the merge's gather in its threading.  Stops between variants
    when ``should_stop()`` (RenderCancelled)."""
    from .errors import RenderCancelled
    from .kept import KeptBuffers
    from .sppm import hashgrid as hg
    rng = np.random.default_rng(1)
    K, P = 64, 400
    vp_pos = rng.uniform(-1, 1, (K, 3))
    vp_ng = np.tile([0.0, 0.0, 1.0], (K, 1))
    R = rng.uniform(0.2, 0.4, K)
    active, const = np.ones(K, bool), rng.random(K) < 0.5
    codes = rng.integers(0, 256, (K, 8)).astype(np.uint8).view(np.uint64).reshape(K)
    codes[:10] = hg.CLIP_CLEAR
    ph = (rng.uniform(-1, 1, (P, 3)), np.tile([0.0, 0.0, 1.0], (P, 1)),
          np.tile([0.0, 0.0, 1.0], (P, 1)), rng.uniform(0, 1, (P, 3)),
          np.where(rng.random(P) < 0.3, 0.1, np.nan))
    variants = [(t, s, c, q) for t in (False, True) for s in (False, True)
                for c in (False, True) for q in (False, True)]
    if first is not None:       # stable: ties keep the order above
        variants.sort(key=lambda v: (v[0] != first[0],
                                     sum(a != b for a, b in zip(v[1:], first[1:4]))))
        variants[0] = tuple(first)
    if only:
        variants = variants[:1]
    saved = hg.PARALLEL_MIN_PHOTONS, hg.PARALLEL_MIN_VPS
    try:
        for v in variants:
            threaded, sectors, clip_on, pairs = v[:4]
            if should_stop is not None and should_stop():
                raise RenderCancelled("cancelled")
            hg.PARALLEL_MIN_PHOTONS = 1 if threaded else saved[0]
            hg.PARALLEL_MIN_VPS = 1 if (v[4] if len(v) > 4 else threaded) else saved[1]
            clip = codes if clip_on else None
            kept = KeptBuffers()
            grid = hg.build_grid(vp_pos, R, active, buffers=kept)
            buf = hg.GatherBuffers(K, sectors)
            buf.kept = kept
            hg.gather(grid, *ph, vp_pos, vp_ng, R * R, const, cos_ng=-1.0,
                      want_freq_pairs=pairs, buffers=buf, clip=clip)
            for albedo in (np.full((K, 3), 0.5, np.float32), np.full((K, 3), 0.5)):
                for mask in (None, const):
                    buf.fold(np.zeros(K), np.zeros((K, 3)), albedo, np.pi,
                             np.full(K, np.inf), mask,
                             np.zeros((K, hg.SECTOR_CELLS)) if sectors else None, clip)
                    hg.gather(grid, *ph, vp_pos, vp_ng, R * R, const, cos_ng=-1.0,
                              want_freq_pairs=pairs, buffers=buf, clip=clip)
            buf.clear()
            if merge and (only or not (sectors or clip_on)):    # the merge's: no buffers
                grid = hg.build_grid(vp_pos, R, active)
                hg.gather(grid, *ph, vp_pos, vp_ng, R * R, const, cos_ng=-1.0,
                          want_freq_pairs=pairs)
    finally:
        hg.PARALLEL_MIN_PHOTONS, hg.PARALLEL_MIN_VPS = saved


#: The side of the crop :func:`compile_late` renders (pixels).
LATE_CROP = 64
#: The kinds of job (:func:`job_kind`) whose late stages a second process
#: compiles (:func:`compile_late`); measured in docs/interactive.md "The
#: second compiling process takes the late stages, round 51" (the photon
#: kinds) and "The paths' late stages in the second process, round 52"
#: (light tracing, path tracing, and Combined without photons: the Cornell
#: box's default and most rooms').
LATE_KINDS = ("photons+frequency", "combined+photons", "light", "path", "combined")
#: Of those, the kinds without photons, whose late stages are light
#: tracing's splat and the camera paths' light sample and continuation
#: (:func:`_render_paths`; the others' are a photon pass: :func:`late_job`).
PATH_KINDS = ("light", "path", "combined")


def late_job(job) -> tuple:
    """The part of a render job that its own process compiles last, for
    :func:`compile_late`: its scene cropped to at most a LATE_CROP-pixel
    square at the centre of its region (the render's border, if any), and
    settings by kind.  Photon mapping with frequency photons: no frequency
    photons (the occlusion grid and spectra are what its own process
    compiles first; the photons are not traced either).  Combined merging
    photons: the same scene as photon mapping (its photon emission, bounces,
    spectra, kernel clip, update and film, which its own process reaches
    after its camera and light paths)."""
    from .render import camera_region
    scene, st, passes = (tuple(job) + ((),))[:3]
    cam = scene.camera
    W, H = (int(v) for v in cam.resolution)
    x0, y0, x1, y1 = camera_region(cam)
    w, h = min(x1 - x0, LATE_CROP), min(y1 - y0, LATE_CROP)
    a, b = x0 + (x1 - x0 - w) // 2, y0 + (y1 - y0 - h) // 2
    # pixel edges + 0.5: border_rect's truncation gives back these pixels
    crop = dataclasses.replace(cam, border=((a + 0.5) / W, (b + 0.5) / H,
                                            (a + w + 0.5) / W, (b + h + 0.5) / H))
    if job_kind(job) in PATH_KINDS:
        late = st
    else:
        late = (st.replace(integrator="PHOTON") if st.integrator == "COMBINED"
                else st.replace(use_frequency=False))
    return (dataclasses.replace(scene, camera=crop), late, passes)


def _no_photons(n, n_freq, rng):
    """A tracer's ``trace`` that traces nothing (the pass gathers no chunk)."""
    return None


def _deposits_on_surfaces(tracer):
    """A tracer's ``trace_emitted`` that traces nothing: each photon leaves
    one deposit at a random point of the scene's surfaces (a triangle drawn
    by area, lit from the side of its normal), in the tracer's own deposit
    buffers, so that light tracing's splat is called with the types a
    traced pass gives it (some points are in the crop's view), without the
    bounce kernel, which the job's own process compiles first."""
    from .lights.warps import _triangle_bary
    P = tracer.tris.p
    area = np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    # photons leave no deposit on a mirror or glass (delta lobes alone)
    area = area * tracer.mtab.has_nondelta[np.asarray(tracer.tris.mat, np.int64)]
    cdf = np.cumsum(area)

    def trace_emitted(ph, rng):
        n = ph["o"].shape[0]
        if cdf.size == 0 or cdf[-1] <= 0:
            return None             # no surface a photon could leave a deposit on
        dep = tracer.deposit_buffers(n)
        dep.reserve(n)
        b = dep.buf
        tri = np.minimum(np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right"),
                         len(cdf) - 1)
        u, v = _triangle_bary(rng.random(n), rng.random(n))
        b.p[:n] = (P[tri, 0] + u[:, None] * (P[tri, 1] - P[tri, 0])
                   + v[:, None] * (P[tri, 2] - P[tri, 0]))
        b.ng[:n] = tracer.tris.ng[tri]
        b.wi[:n] = tracer.tris.ng[tri]
        b.power[:n] = ph["power"]
        b.r[:n] = 0.0
        b.bounce[:n] = 1
        b.bary[:n, 0], b.bary[:n, 1], b.bary[:n, 2] = tri, u, v
        dep.n = n
        return dep.result()
    return trace_emitted


def _mis_deposits_on_surfaces(tracer):
    """Combined's light-path trace (``CombinedLightTracer._trace``) that
    traces nothing: :func:`_deposits_on_surfaces`'s deposits, one a
    photon, with MIS ratios 0 and none a first hit (a delta light's first
    hits are next-event estimation's and would not be splatted)."""
    on_surfaces = _deposits_on_surfaces(tracer)

    def trace(ph, z0, rng):
        dep = on_surfaces(ph, rng)
        if dep is None:
            return None, None, None, None
        n = ph["o"].shape[0]
        dep["src_photon"] = np.arange(n, dtype=np.int64)
        return dep, np.zeros(n), np.zeros(n), np.zeros(n, np.bool_)
    return trace


def _no_direct_light(start, end, L, R, S):
    """``direct_kernels.direct_kernel`` that samples no light (S as
    ``alloc_samples`` left it: no light on any row)."""


def _render_paths(scene, st, passes, should_stop) -> None:
    """Render the late stages of a job of :data:`PATH_KINDS` (its own
    process compiles them last, after the emission and bounces of its light
    paths, or its camera paths' emitters, textures, normal maps and direct
    light): light tracing's splat, without the fused emission (numpy's:
    ``emission.COMPILED_EMISSION`` off) or a traced photon
    (:func:`_deposits_on_surfaces`); the camera paths' next-event
    estimation with its MIS weights (``path_kernels.nee_mis_kernel``) and
    their continuation (``continue_kernel``), with no emitter seen, no map
    looked up, no normal perturbed, no colour row of a texture and no light
    sampled (:func:`_no_direct_light`).  Combined's pilot
    (``combined.visible_splats``) traces light paths: taken as passed here
    (a job whose own pilot fails keeps its camera paths, rendered here
    too, and still splats its light paths)."""
    from .integrators import combined, path_tracer
    from .lights import direct_kernels, emission
    from .render import Renderer
    saved = (combined.visible_splats, emission.COMPILED_EMISSION, path_tracer.rays_radiance,
             direct_kernels.direct_kernel)
    combined.visible_splats = lambda lt, seed: math.inf
    emission.COMPILED_EMISSION = False
    path_tracer.rays_radiance = lambda env, d, rows, Le: Le.fill(0.0)
    direct_kernels.direct_kernel = _no_direct_light
    try:
        r = Renderer(scene, st, log=lambda _m: None, should_stop=should_stop, passes=passes)
        lt = r.light_tracer or r.combined_lt
        if lt is not None:
            lt.fast_emission = False
            lt.tracer.trace_emitted = _deposits_on_surfaces(lt.tracer)
            if lt is r.combined_lt:
                lt._trace = _mis_deposits_on_surfaces(lt.tracer)
        pt = None if r.light_only else r.path_tracer
        if pt is not None:
            pt._seen = lambda kern, vis, o, d, t_end: ()
            pt._perturb = lambda prim, bu, bv, ns: None
            pt._hit_colors = lambda M, prim, bu, bv, mat, d, ih, ns: (M, np.asarray(mat, np.int64))
        r.run(should_stop=should_stop)
    finally:
        (combined.visible_splats, emission.COMPILED_EMISSION, path_tracer.rays_radiance,
         direct_kernels.direct_kernel) = saved


def compile_late(jobs, should_stop: Optional[Callable[[], bool]] = None) -> None:
    """Compile what a render job (:func:`render_job`) of one of
    :data:`LATE_KINDS` calls last, the way it calls it (:func:`late_job`):
    rendered on a crop of its scene, with the stages' threaded paths where
    the whole render takes them.  A photon-mapping job with frequency
    photons compiles its occlusion grid, emission, bounces and spectra
    first, then its camera pass, direct light, kernel clip, grid build,
    update and film: those are rendered here, no photon traced.  A
    Combined job that merges photons compiles its camera and light paths
    first, then its photon pass: that is rendered here, as photon mapping.
    Camera or light paths without photons (:data:`PATH_KINDS`): their
    splat, light sample weights and continuation (:func:`_render_paths`).
    The second compiling process runs this after the gather (alone for
    :data:`PATH_KINDS`), so the job's process loads these kernels from the
    cache when it reaches them (docs/interactive.md "The second compiling
    process takes the late stages, round 51", "The paths' late stages in
    the second process, round 52").  Other kinds are skipped: without
    frequency photons a photon-mapping job reaches these stages early
    itself.  Raises RenderCancelled when ``should_stop()``."""
    from .errors import RenderCancelled
    from .render import Renderer, camera_region
    for job in jobs:
        kind = job_kind(job)
        if kind not in LATE_KINDS:
            continue
        scene, st, passes = late_job(job)
        x0, y0, x1, y1 = camera_region(job[0].camera)
        with _split_paths(True, pixels=(x1 - x0) * (y1 - y0)):
            if kind in PATH_KINDS:
                _render_paths(scene, st, passes, should_stop)
            else:
                r = Renderer(scene, st, log=lambda _m: None, should_stop=should_stop,
                             passes=passes, force_stages=("glossy chains",))
                if not st.use_frequency:
                    r.tracer.trace = _no_photons
                r.run(should_stop=should_stop)
        if should_stop is not None and should_stop():
            raise RenderCancelled("cancelled")


def traces_photons(job) -> bool:
    """Whether a render's job (:func:`render_job`) traces and gathers photons:
    integrator PHOTON, or COMBINED where its plan merges photons
    (core.plan.merges_photons, make_plan's rule).  Read from the scene's
    lobes without the Renderer's tables (every material's, not only those
    of triangles: a wrong guess only starts a compiling process for
    nothing); light tracing sees a surface whenever one is diffuse or
    glossy, and without one no rule merges, so ``seen`` is that."""
    from .materials.table import is_delta_lobe
    from .plan import merges_photons
    scene, st = tuple(job)[:2]
    if st.photons_per_pass <= 0 or st.integrator not in ("PHOTON", "COMBINED"):
        return False
    if st.integrator == "PHOTON":
        return True
    delta = [is_delta_lobe(lb.kind, lb.roughness, lb.ior)
             for m in scene.materials for lb in m.lobes]
    has_nondelta = not all(delta)
    return merges_photons(st, any(delta), has_nondelta, scene.tri_p, seen=has_nondelta)


def job_kind(job) -> str:
    """Which of :data:`JOB_SECONDS`'s kinds a render's job (:func:`render_job`)
    is: its integrator, whether it traces photons (:func:`traces_photons`)
    and, for photon mapping, frequency photons; the kernels a job compiles,
    and so its first-use compile, follow these."""
    st = tuple(job)[1]
    if st.integrator in ("LIGHT", "PATH"):
        return st.integrator.lower()
    photons = traces_photons(job)
    if st.integrator == "COMBINED":
        return "combined+photons" if photons else "combined"
    return "photons+frequency" if st.use_frequency and photons else "photons"


# --- the warm-up of one render ----------------------------------------------

#: Passes of a render's own warm-up job (render_job): the second calls the
#: frequency kernels a render first calls after its pass S.
JOB_PASSES = 2

def render_job(scene, settings: RenderSettings, passes: tuple = ()) -> tuple:
    """The warm-up job of one render: ``(scene, settings, passes)`` for
    :data:`JOB_PASSES` passes (no time limit) of the render's own exported
    scene, settings and AOV passes, at its own resolution and photon count,
    so that the size-dependent paths (threads from ``PARALLEL_MIN`` pixels,
    the gather's parallel path from ``hashgrid.PARALLEL_MIN_PHOTONS``
    photons) are the render's: the kernels compiled are those its passes
    call, and only those (the Cornell box's default render, light tracing
    alone, compiles no photon, frequency or camera-path kernel).

    The frequency photons' schedule is moved so that two passes call every
    frequency kernel a render's later passes do: frequency_start 1, so pass
    1 traces what the render's pass S traces (the one batch with spectra);
    pass 2 reads the reach map of pass 1's radii (``kernels.mark_reach``,
    which the render first calls in pass S, from pass S - 1's radii); and, where the render's
    schedule decays, pass 2 traces so few frequency photons that they are
    traced again in a batch of their own (``photon_kernels.follow_rows``,
    a late pass's path: ``photons.RETRACE_MAX_SHARE``).  The fraction is
    the one that gives pass 1's first chunk 1.5x that share of frequency
    photons (above it) and pass 2, at decay 2, a quarter of it (below)."""
    st = settings.replace(max_passes=JOB_PASSES, time_limit=0.0, frequency_start=1)
    if st.frequency_decay > 0 and st.photons_per_pass > 0:
        from .sppm.photon_pass import PHOTON_CHUNK
        from .sppm.photons import RETRACE_MAX_SHARE
        first_chunk = min(st.photons_per_pass, PHOTON_CHUNK)
        st = st.replace(frequency_decay=2.0, frequency_fraction=min(
            1.0, 1.5 * RETRACE_MAX_SHARE * first_chunk / st.photons_per_pass))
    return (scene, st, tuple(passes))


def _scene_kinds(scene) -> tuple:
    """What of a scene selects kernels: the kinds of its materials, lights,
    camera and world, not their values, and its pixel count's power of two
    (the stages' thread thresholds are powers of two: ``PARALLEL_MIN``...);
    two scenes alike in these call the same kernels.  A wrong guess only
    leaves a compile to the first pass, as before the warm-up."""
    lobes = sorted({(lb.kind, lb.roughness == 0.0, lb.color_texture >= 0, bool(lb.multiscatter),
                     lb.fresnel, lb.layer_ior > 0.0, getattr(lb, "alpha_texture", -1) >= 0)
                    for m in scene.materials for lb in m.lobes})
    mats = sorted({(len(m.lobes), any(e > 0 for e in m.emission), m.emission_texture >= 0,
                    getattr(m, "normal", None) is not None) for m in scene.materials})
    lights = sorted({(lt.kind, lt.shape, lt.radius > 0.0, bool(lt.use_soft_falloff))
                     for lt in scene.lights})
    cam = scene.camera
    pixels = int(cam.resolution[0]) * int(cam.resolution[1])
    return (lobes, mats, lights, cam.kind, pixels.bit_length(), cam.border is not None,
            bool(np.any(np.asarray(scene.world_color) > 0)), scene.world_map is not None,
            bool(scene.film_transparent), scene.tri_tangent is not None,
            sorted({np.asarray(t).shape[-1] for t in scene.textures}))


def job_key(job) -> str:
    """Key of a render job's kernels (:func:`render_job`): its settings but
    the seed (Animated Seed too) and budget, its AOV passes and :func:`_scene_kinds`."""
    scene, st, passes = (tuple(job) + ((),))[:3]
    feats = (st.replace(seed=0, use_animated_seed=False).image_digest(), tuple(passes),
             _scene_kinds(scene))
    return hashlib.sha256(repr(feats).encode()).hexdigest()[:16]


# --- which kernels a warm-up compiled, and loading them here ---------------

def _dispatchers():
    """(``module:name``, dispatcher) of every kernel of this package's loaded modules."""
    from numba.core.registry import CPUDispatcher
    prefix, seen = __package__, set()
    for name, mod in list(sys.modules.items()):
        if mod is None or not (name == prefix or name.startswith(prefix + ".")):
            continue
        for attr, d in list(vars(mod).items()):
            if isinstance(d, CPUDispatcher) and id(d) not in seen:
                seen.add(id(d))
                yield f"{name}:{attr}", d


def used_kernels() -> dict:
    """{``module:name``: [argument types, ...]} of every kernel compiled or
    loaded in this process (what :func:`load_kernels` takes)."""
    return {k: list(d.signatures) for k, d in _dispatchers() if d.signatures}


def compiled_count() -> int:
    """How many kernel signatures this process compiled (not loaded from disk)."""
    return sum(sum(d.stats.cache_misses.values()) for _k, d in _dispatchers())


def load_kernels(kernels: dict, should_stop: Optional[Callable[[], bool]] = None) -> int:
    """Load the kernels of :func:`used_kernels` (recorded by another process
    under the same module names) from the disk cache into this process, so
    that the render calling them does not; returns how many.  A kernel that
    is not on disk compiles here (as its first call would)."""
    import importlib

    from .errors import RenderCancelled
    n = 0
    for key, sigs in kernels.items():
        mod, attr = key.split(":")
        try:
            d = getattr(importlib.import_module(mod), attr)
        except (ImportError, AttributeError):
            continue
        for sig in sigs:
            if should_stop is not None and should_stop():
                raise RenderCancelled("cancelled")
            if tuple(sig) not in d.overloads:
                d.compile(tuple(sig))
                n += 1
    return n


def _pack(kernels: dict) -> str:
    """:func:`used_kernels` as text for a marker (numba types pickle)."""
    ok = {}
    for k, sigs in kernels.items():
        try:
            pickle.dumps(sigs)
            ok[k] = sigs
        except Exception:       # noqa: BLE001 - such a kernel just loads at its first call
            continue
    return base64.b64encode(pickle.dumps(ok, protocol=4)).decode()


def _unpack(text: str) -> dict:
    try:
        return pickle.loads(base64.b64decode(text))
    except Exception:           # noqa: BLE001 - a damaged marker: load nothing
        return {}


# Run by _Child: load the package under the parent's module name (stub parents
# for a dotted name such as bl_ext.user_default.fppm), then compile the groups
# the parent hands it (child_main).  It ends with its parent (a quit Blender,
# an interrupted CLI) or after CHILD_IDLE_SECONDS without work.
_CHILD = r"""
import importlib, importlib.util, os, sys, threading, time, types
name, root = sys.argv[1], sys.argv[2]


def exit_with_parent(ppid=int(sys.argv[4])):    # the parent's pid: it may be gone already
    while os.getppid() == ppid:
        time.sleep(0.5)
    import shutil
    shutil.rmtree(sys.argv[3], ignore_errors=True)   # no parent left to read it
    os._exit(1)


threading.Thread(target=exit_with_parent, daemon=True).start()
parts = name.split(".")
for i in range(1, len(parts)):
    parent = ".".join(parts[:i])
    if parent not in sys.modules:
        stub = types.ModuleType(parent)
        stub.__path__ = []
        sys.modules[parent] = stub
spec = importlib.util.spec_from_file_location(name, os.path.join(root, "__init__.py"),
                                              submodule_search_locations=[root])
pkg = importlib.util.module_from_spec(spec)
sys.modules[name] = pkg
spec.loader.exec_module(pkg)
W = importlib.import_module(name + ".core.warmup")
W.child_main(sys.argv[3])
"""
CHILD_IDLE_SECONDS = 20.0
"""A compiling child waits this long for the next group (the next render's
job: a test suite's renders follow each other) before it ends."""


def _dump(path: str, obj) -> None:
    """Pickle ``obj`` to ``path`` atomically (a reader never sees half a file)."""
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "wb") as f:
        pickle.dump(obj, f, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(tmp, path)


def child_main(folder: str, idle: float = CHILD_IDLE_SECONDS) -> None:
    """The compiling process: for each group the parent writes
    (``<folder>/spec-<i>.pkl``: ``{"jobs": [...] or None for warmup_jobs(),
    "nice": bool}``, ``{"gather": variant, "only": bool, "merge": bool}``
    for :func:`compile_gather`, or ``{"late": [...]}`` for :func:`compile_late`)
    render its jobs, then write ``<folder>/<i>.pkl``:
    seconds, CPU seconds, kernels compiled (not loaded) and
    :func:`used_kernels`, for the parent to load.  Importing numba and the
    renderer (seconds) is paid once for all the groups of a process."""
    import gc
    before, i = compiled_count(), 0
    while True:
        path, t = os.path.join(folder, f"spec-{i}.pkl"), time.monotonic()
        while not os.path.exists(path):
            if time.monotonic() - t > idle:
                return
            time.sleep(0.02)
        with open(path, "rb") as f:
            g = pickle.load(f)
        if g["nice"] and hasattr(os, "nice"):
            try:
                os.nice(10)     # every variant: behind the render that now runs
            except OSError:
                pass
        t0, c0 = time.perf_counter(), time.process_time()
        if g.get("gather") is not None:
            compile_gather(tuple(g["gather"]), only=g.get("only", False),
                           merge=g.get("merge", True))
        elif g.get("late") is not None:
            compile_late(g["late"])
        elif g["jobs"] is None:
            compile_kernels()
        else:
            run_jobs(g["jobs"])
        del g
        gc.collect()            # the job's scene and state: not kept while idle
        n = compiled_count()
        _dump(os.path.join(folder, f"{i}.pkl"),
              {"seconds": time.perf_counter() - t0, "cpu": time.process_time() - c0,
               "compiled": n - before, "kernels": used_kernels()})
        before, i = n, i + 1


def package_name() -> str:
    """The module name the package holding ``core`` is imported under."""
    return __name__.rsplit(".core.warmup", 1)[0]


def _child_command() -> tuple:
    """(cache root, environment) of a compiling child; RuntimeError when none can run."""
    root = _numba_cache.cache_dir()
    if root is None:
        raise RuntimeError("no writable kernel cache folder")
    if not os.path.basename(sys.executable).lower().startswith("python"):
        # Blender >= 2.91 sets sys.executable to its bundled Python; never
        # start a second Blender by mistake.
        raise RuntimeError(f"{sys.executable!r} is not a Python interpreter")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p),
               **{_numba_cache.ENV_VAR: root})
    return root, env


CHILD_FOLDER_STALE_SECONDS = 86400.0
"""A compiling child's folder untouched this long belongs to no live
process (a child writes into it while it works, and ends 20 s after its
last group; :func:`_sweep_child_folders`)."""


def _sweep_child_folders(root: str, now: Optional[float] = None) -> None:
    """Remove the ``warmup-*`` folders of compiling children that were
    killed together with their parent (SIGKILL, a crash, power loss): the
    other ways out remove their folder themselves (:class:`_Child`).  Only
    folders holding nothing but a child's own files (``FPPM_CACHE_DIR`` may
    name any folder of the user's)."""
    import re
    ours = re.compile(r"(spec-)?\d+\.pkl(\.\d+\.tmp)?")   # what _Child and child_main write
    now = time.time() if now is None else now
    try:
        names = os.listdir(root)
    except OSError:
        return
    for n in names:
        path = os.path.join(root, n)
        try:
            if n.startswith("warmup-") and os.path.isdir(path) and \
                    now - os.stat(path).st_mtime > CHILD_FOLDER_STALE_SECONDS and \
                    all(ours.fullmatch(f) for f in os.listdir(path)):
                shutil.rmtree(path, ignore_errors=True)
        except OSError:
            pass


def _end_child(proc: subprocess.Popen, log, folder: str) -> None:
    """Stop a compiling child and remove its folder: :meth:`_Child.close`,
    :func:`end_children`, or this process's exit or the object's collection
    without either (``weakref.finalize``), so that no ``warmup-*`` folder
    outlives both."""
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    log.close()
    shutil.rmtree(folder, ignore_errors=True)


_CHILDREN: "weakref.WeakSet" = weakref.WeakSet()
"""This process's :class:`_Child` objects (closing one twice does nothing)."""


def end_children() -> None:
    """Stop every compiling child of this process and remove its folder:
    for a process that ends with ``os._exit`` (the ``fppm`` command,
    ``addon/cli.py`` ``exit_now``), which runs no finalizer, and whose
    child may have ended idle before it (then nobody else removes it)."""
    for child in list(_CHILDREN):
        child.close()


class _Child:
    """A compiling process (:func:`child_main`) taking one group after another."""

    def __init__(self):
        root, env = _child_command()
        _sweep_child_folders(root)
        self.folder = tempfile.mkdtemp(prefix="warmup-", dir=root)
        self.log = tempfile.TemporaryFile()   # a file: a full pipe would block the child
        self.n = 0
        # Its own process group: Ctrl-C in the CLI's terminal stops the render
        # (which polls), not the compile that the next render needs.
        group = ({"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP}
                 if sys.platform == "win32" else {"start_new_session": True})
        self.proc = subprocess.Popen([sys.executable, "-c", _CHILD, package_name(),
                                      os.path.dirname(_CORE), self.folder, str(os.getpid())],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=self.log, env=env, cwd=root, **group)
        self._end = weakref.finalize(self, _end_child, self.proc, self.log, self.folder)
        _CHILDREN.add(self)

    def submit(self, spec: dict) -> int:
        _dump(os.path.join(self.folder, f"spec-{self.n}.pkl"), spec)
        self.n += 1
        return self.n - 1

    def result(self, i: int):
        """Group i's record, None while it runs; ``"idle"`` when the child
        ended idle before it saw the group, RuntimeError when it failed."""
        path = os.path.join(self.folder, f"{i}.pkl")
        for _ in range(2):              # the record may come with the exit
            if os.path.exists(path):
                with open(path, "rb") as f:
                    return pickle.load(f)
            if self.proc.poll() is None:
                return None
        if self.proc.returncode == 0:
            return "idle"
        self.log.seek(0)
        err = self.log.read().decode(errors="replace").strip()
        raise RuntimeError(f"the compiling process ended with code {self.proc.returncode}: "
                           f"{err.splitlines()[-1] if err else 'no message'}")

    def close(self) -> None:
        self._end()


def source_key() -> str:
    """Hash of everything a compiled kernel depends on: core's sources, the
    numba and Python versions, and the module name core is imported under."""
    h = hashlib.sha256()
    for d, dirs, files in sorted(os.walk(_CORE)):
        dirs[:] = sorted(x for x in dirs if x != "__pycache__")
        for f in sorted(files):
            if f.endswith(".py"):
                with open(os.path.join(d, f), "rb") as fh:
                    h.update(f.encode() + b"\0" + fh.read())
    try:
        from importlib.metadata import version
        nb = version("numba")
    except Exception:
        nb = "?"
    h.update(f"{nb}|{sys.version_info[:2]}|{__name__}".encode())
    return h.hexdigest()[:16]


ALL = "all"
"""The key of the warm-up of every variant (:func:`warmup_jobs`)."""


def _cache_marker(kind: str, tail: str = "") -> Optional[str]:
    """``<cache>/numba/<kind>-<source version><tail>.json``: a record kept
    beside the kernels of this source version (None: no writable cache)."""
    root = _numba_cache.cache_dir()
    if root is None:
        return None
    return os.path.join(root, "numba", f"{kind}-{source_key()}{tail}.json")


def _write_json(path: Optional[str], record: dict) -> None:
    """Write a marker whole (core.io.atomic.replace_atomically: a reader
    never sees half a file); an unwritable cache only loses the record."""
    if path is None:
        return
    from .io.atomic import default_file_mode, replace_atomically
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with replace_atomically(path, mode=default_file_mode()) as tmp, open(tmp, "w") as f:
            json.dump(record, f)
    except OSError:
        pass


def _marker_path(key: str = ALL) -> Optional[str]:
    return _cache_marker("warmup", "" if key == ALL else f"-{key}")


def _gather_marker(variant: Optional[tuple] = None) -> Optional[str]:
    """The record that :func:`compile_gather` finished in this cache for this
    source version (a second process beside a render's job, :class:`Warmup`):
    every variant, or ``variant`` alone (:func:`gather_variant`)."""
    return _cache_marker("gather", "" if variant is None
                         else "-" + "".join("1" if x else "0" for x in variant))


def _paths_marker(kind: str) -> Optional[str]:
    """The record that :func:`compile_late` rendered the late stages of a
    job of ``kind`` (one of :data:`PATH_KINDS`) in this cache for this
    source version."""
    return _cache_marker("paths", "-" + kind)


def _read_marker(key: str = ALL) -> Optional[dict]:
    p = _marker_path(key)
    try:
        with open(p) as f:
            return json.load(f)
    except (OSError, TypeError, ValueError):
        return None


def _markers() -> list:
    """Contents of every warm-up marker of this cache (any source version)."""
    root = _numba_cache.cache_dir()
    if root is None:
        return []
    folder = os.path.join(root, "numba")
    try:
        names = [n for n in os.listdir(folder) if n.startswith("warmup-") and n.endswith(".json")]
    except OSError:
        return []
    out = []
    for n in names:
        try:
            with open(os.path.join(folder, n)) as f:
                d = json.load(f)
            kind = d.get("kind")
            out.append((d.get("job", ALL), bool(d.get("cold")), float(d["seconds"]),
                        kind if kind in JOB_SECONDS else None))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            continue
    return out


def last_compile_seconds(job=None) -> Optional[float]:
    """Seconds of the last complete first-use compile on this machine (any
    version) of ``job`` (:func:`render_job`; None: every variant), or None
    when there was none.  For a job never compiled here: its kind's
    :data:`JOB_SECONDS` times this machine's median ratio of measured to
    assumed seconds over the other renders' jobs (they range from seconds
    to minutes by kind: docs/interactive.md); the median of their seconds
    when none recorded its kind (a marker of before round 49)."""
    key = ALL if job is None else job_key(job)
    cold = [(k, s, kind) for k, c, s, kind in _markers() if c]
    same = [s for k, s, _ in cold if k == key]
    if same:
        return max(same)
    if key == ALL:
        return None
    ratios = sorted(s / JOB_SECONDS[kind] for k, s, kind in cold if k != ALL and kind)
    if ratios:
        return ratios[len(ratios) // 2] * JOB_SECONDS[job_kind(job)]
    other = sorted(s for k, s, _ in cold if k != ALL)
    return other[len(other) // 2] if other else None


def is_compiled(job=None) -> bool:
    """True when this source version finished a warm-up of ``job`` (None:
    of every variant) on this machine: its kernels are on disk, loading them
    takes seconds, not a compile."""
    for key in ((ALL,) if job is None else (job_key(job), ALL)):
        p = _marker_path(key)
        if p is not None and os.path.exists(p):
            return True
    return False


def expected_seconds(job=None) -> float:
    """About how long a first-use compile of ``job`` (None: every variant)
    will take here (for the message)."""
    return last_compile_seconds(job) or (DEFAULT_COMPILE_SECONDS if job is None
                                         else JOB_SECONDS[job_kind(job)])


def _write_marker(key: str, seconds: float, cold: bool, kernels: Optional[dict] = None,
                  cpu: Optional[float] = None, kind: Optional[str] = None) -> None:
    d = {"seconds": seconds, "cold": cold, "job": key, "cpu": cpu, "kind": kind}
    if kernels:
        d["kernels"] = _pack(kernels)
    _write_json(_marker_path(key), d)   # unwritable: only the message's estimate is lost


class _Group:
    """One unit of the warm-up: a render's job (key :func:`job_key`) or
    every variant (key :data:`ALL`, jobs None: :func:`warmup_jobs`)."""

    def __init__(self, key: str, jobs):
        self.key, self.jobs = key, jobs
        self.event = threading.Event()
        self.error: Optional[str] = None
        self.seconds: Optional[float] = None
        self.was_cold: Optional[bool] = None


class Warmup:
    """The once-per-process background compile, in one thread.

    ``start()`` asks for every variant (:func:`warmup_jobs`; idempotent);
    ``wait(should_stop)`` blocks until that ends or ``should_stop()``;
    afterwards ``done``, ``error`` (the exception text, or None), ``seconds``
    and ``was_cold`` (a compile, not a load).  ``wait_for(job, ...)`` asks
    for one render's job (:func:`render_job`) before anything else and
    blocks until its kernels are loaded here (``rest``: every variant
    follows it, in the same compiling process at a lower priority).
    ``stop()`` asks the thread to end at the next poll (unregister, tests).
    ``compile(should_stop) -> seconds`` stands in for the whole warm-up
    (tests): any request then runs it and finishes everything.
    """

    def __init__(self, compile: Callable = None):
        self._compile = compile
        self._lock = threading.Lock()
        self._thread: Optional[threading.Thread] = None
        self._exiting = False
        self._all = _Group(ALL, None)
        self._want_all = False
        self._jobs: dict = {}             # job key -> _Group, in request order
        self._stop = threading.Event()
        self._kick = threading.Event()    # a new job: it goes first
        self._child: Optional[_Child] = None
        self._gather: Optional[_Child] = None    # compile_gather beside a job (_start_gather)
        self._gather_i: Optional[int] = None
        self._gather_marks: Optional[str] = None   # its marker (_gather_marker), when it ends
        self.started_at: Optional[float] = None

    done = property(lambda self: self._all.event.is_set())
    error = property(lambda self: self._all.error)
    seconds = property(lambda self: self._all.seconds)
    was_cold = property(lambda self: self._all.was_cold)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _ensure_thread(self) -> None:
        """Start the thread unless it runs (call with the lock held)."""
        if self.running and not self._exiting:
            return
        if self._thread is not None:
            self._thread.join()       # it is ending: it holds no lock and takes none
        self._stop.clear()
        self._exiting = False
        self.started_at = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="fppm-warmup", daemon=True)
        self._thread.start()

    def start(self) -> None:
        with self._lock:
            self._want_all = True
            if not self.done:
                self._ensure_thread()

    def stop(self) -> None:
        self._stop.set()

    def ready(self, job) -> bool:
        """True when ``job``'s kernels (or every variant's) are loaded here."""
        if self.done:
            return True
        g = self._jobs.get(job_key(job))
        return g is not None and g.event.is_set()

    def job_error(self, job) -> Optional[str]:
        """Why ``job``'s warm-up failed (its text), or None."""
        g = self._jobs.get(job_key(job))
        return g.error if g is not None and g.event.is_set() else self.error

    def jobs_status(self) -> list:
        """{"key", "done", "error", "seconds", "was_cold"} of each render job
        asked for in this process, in request order."""
        return [{"key": g.key, "done": g.event.is_set(), "error": g.error, "seconds": g.seconds,
                 "was_cold": g.was_cold} for g in list(self._jobs.values())]

    def _run(self) -> None:
        from .errors import FPPMError, RenderCancelled
        while True:
            with self._lock:
                groups = [g for g in self._jobs.values() if not g.event.is_set()]
                if self._want_all and not self._all.event.is_set():
                    groups.append(self._all)
                if self._stop.is_set() or not groups:
                    self._exiting = True
                    if self._stop.is_set():
                        self._close_child()
                    return
                self._kick.clear()
            try:
                self._work(groups)
            except RenderCancelled:
                continue                   # stopped (the loop ends) or a new job first
            except FPPMError as ex:        # a user-facing condition (e.g. memory): the
                self._fail(groups, str(ex))    # render that follows says it again, clearly
            except Exception as ex:        # noqa: BLE001 - reported by the caller
                traceback.print_exc()
                self._fail(groups, f"{type(ex).__name__}: {ex}")

    @staticmethod
    def _fail(groups, msg: str) -> None:
        for g in groups:
            if not g.event.is_set():
                g.error = msg
                g.event.set()

    def _finish(self, g: _Group, seconds: float, cold: bool, kernels: Optional[dict],
                cpu: Optional[float] = None) -> None:
        g.seconds, g.was_cold = seconds, cold
        _write_marker(g.key, seconds, cold, kernels, cpu,
                      None if g.jobs is None else job_kind(g.jobs[0]))
        g.event.set()

    def _interrupted(self) -> bool:
        return self._stop.is_set() or self._kick.is_set()

    def _work(self, groups: list) -> None:
        """The first of ``groups`` (the loop then orders the rest again: a
        render's job asked for meanwhile goes first)."""
        from .errors import RenderCancelled
        if self._compile is not None:          # a stand-in for the whole warm-up
            cold = not is_compiled()
            secs = self._compile(should_stop=self._interrupted)
            if self._interrupted():
                raise RenderCancelled("interrupted")
            for g in set(groups) | {self._all}:
                self._finish(g, secs, cold, None)
            return
        g = groups[0]
        m = _read_marker(g.key)
        kernels = _unpack(m["kernels"]) if m and m.get("kernels") else None
        if kernels:
            t0 = time.perf_counter()           # compiled before: load what it lists
            load_kernels(kernels, self._stop.is_set)
            g.seconds, g.was_cold = time.perf_counter() - t0, False
            g.event.set()
            return
        try:
            rec = self._compile_in_child(g)
        except RenderCancelled:
            raise
        except (OSError, RuntimeError) as ex:
            print(f"FPPM: compiling the kernels in a separate process failed ({ex}); "
                  f"compiling them in this one.")
            t0, n0 = time.perf_counter(), compiled_count()
            if g.jobs is None:
                compile_kernels(self._interrupted)
            else:
                run_jobs(g.jobs, self._interrupted)
            self._finish(g, time.perf_counter() - t0, compiled_count() > n0, used_kernels())
            return
        load_kernels(rec["kernels"], self._stop.is_set)
        self._finish(g, rec["seconds"], rec["compiled"] > 0, rec["kernels"], rec["cpu"])

    def _compile_in_child(self, g: _Group, poll: float = 0.05) -> dict:
        """Group g's jobs in the compiling child (:class:`_Child`, started
        when none runs), which fills this process's kernel cache; returns its
        record (:func:`child_main`).  Raises RenderCancelled when stopped, or
        when a render's job comes while every variant compiles (the child is
        killed: the job goes first, what was compiled stays on disk);
        RuntimeError when the child fails."""
        from .errors import RenderCancelled
        spec = {"jobs": g.jobs, "nice": g.jobs is None and bool(self._jobs)}
        try:
            for attempt in range(2):
                if self._child is None or self._child.proc.poll() is not None:
                    if self._child is not None:
                        self._child.close()
                    self._child = _Child()
                i = self._child.submit(spec)
                if attempt == 0 and g.jobs is not None:
                    self._start_gather(g.jobs)
                while True:
                    rec = self._child.result(i)
                    if rec is not None:
                        break
                    if self._stop.is_set() or (g.jobs is None and self._kick.is_set()):
                        self._close_child()
                        raise RenderCancelled("cancelled")
                    self._poll_gather()
                    time.sleep(poll)
                if rec != "idle":           # else it ended just before the spec came: again
                    return rec
            raise RuntimeError("the compiling process ended before its work")
        finally:
            self._close_gather()

    def _start_gather(self, jobs: list) -> None:
        """Beside a render's job that traces photons (:func:`traces_photons`),
        on a cold cache (no marker of every variant nor of the gather), start
        a second compiling process on :func:`compile_gather`: the machine's
        other core compiles the gather's kernels, ~40 % of a photon render's
        compile, into the same cache while the job's process renders the
        scene's other stages, and finds them there (docs/interactive.md
        "Two compiling processes, round 20"); then, beside a job of
        :data:`LATE_KINDS`, the stages that job reaches last
        (:func:`compile_late`).  Beside camera or light paths without
        photons (:data:`PATH_KINDS`), until its marker is written, the
        process renders their late stages alone (docs/interactive.md "The
        paths' late stages in the second process, round 52").  It runs at
        the job's priority only while the job runs (:meth:`_close_gather`
        when the job's record comes; what it compiled stays on disk).  Skipped when no child can run (the job's
        child then fails too, and this process compiles)."""
        self._close_gather()
        marker = _gather_marker()
        if marker is None or is_compiled():
            return
        late = [j for j in jobs if job_kind(j) in LATE_KINDS]
        if not any(traces_photons(j) for j in jobs):
            # Camera and light paths alone (PATH_KINDS), until their marker is written.
            paths = _paths_marker(job_kind(late[0])) if late else None
            if paths is None or os.path.exists(paths):
                return
            try:
                self._gather = _Child()
            except (OSError, RuntimeError):
                return
            self._gather_marks = paths
            self._gather_i = self._gather.submit({"jobs": None, "nice": False, "late": late})
            return
        # The job's passes gather in one variant; COMBINED's merging also
        # gathers without buffers (core/integrators/merge_kernels.py).
        variant = gather_variant(jobs[0])
        merge = any(j[1].integrator != "PHOTON" for j in jobs)
        if os.path.exists(marker) or os.path.exists(_gather_marker(variant + (merge,))):
            return
        try:
            self._gather = _Child()
        except (OSError, RuntimeError):
            return
        self._gather_marks = _gather_marker(variant + (merge,))
        self._gather_i = self._gather.submit({"jobs": None, "nice": False, "gather": variant,
                                              "only": True, "merge": merge})
        if late:
            self._gather.submit({"jobs": None, "nice": False, "late": late})

    def _poll_gather(self) -> None:
        """Write the gather's marker once its process finished its variants
        (the process goes on with the late stages, if given, until the job
        ends), or the paths' marker once their late stages are done."""
        if self._gather is None or self._gather_i is None:
            return
        try:
            rec = self._gather.result(self._gather_i)
        except RuntimeError:
            rec = "failed"
        if rec is None:
            return
        if isinstance(rec, dict):
            _write_json(self._gather_marks, {"seconds": rec["seconds"], "cpu": rec["cpu"],
                                             "compiled": rec["compiled"]})
            self._gather_i = None
        else:
            self._close_gather()

    def _close_gather(self) -> None:
        if self._gather is not None:
            self._gather.close()
            self._gather = None
        self._gather_i = None

    def _close_child(self) -> None:
        if self._child is not None:
            self._child.close()
            self._child = None

    def _wait_group(self, g: _Group, should_stop, on_wait, poll: float, restart) -> bool:
        t0 = time.monotonic()
        while not g.event.wait(poll):
            if g is not self._all and self.done:
                return True
            if should_stop is not None and should_stop():
                return False
            if not self.running or self._exiting:
                restart()              # stopped by stop(): begin again
            if on_wait is not None:
                on_wait(time.monotonic() - t0)
        return True

    def wait(self, should_stop: Optional[Callable[[], bool]] = None,
             on_wait: Optional[Callable[[float], None]] = None, poll: float = 0.05) -> bool:
        """Start if needed and block until every variant is done; True when
        done, False when ``should_stop()`` returned True first.
        ``on_wait(seconds waited)`` is called at every poll (progress display)."""
        self.start()
        return self._wait_group(self._all, should_stop, on_wait, poll, self.start)

    def request(self, job, rest: bool = True) -> None:
        """Ask for ``job``'s kernels (:func:`render_job`) before anything not
        asked for yet, without waiting (see :meth:`wait_for`)."""
        if self.done:
            return
        key = job_key(job)
        with self._lock:
            if key not in self._jobs:
                self._jobs[key] = _Group(key, [job])
                self._kick.set()
            if rest:
                self._want_all = True
            self._ensure_thread()

    def _load_here(self, job, should_stop) -> bool:
        """Load ``job``'s kernels in this thread when a marker lists them (a
        compile of every variant under way is not interrupted for a load);
        False when there is none or ``should_stop()`` came first."""
        from .errors import RenderCancelled
        key = job_key(job)
        g = self._jobs.get(key)
        if g is not None and g.event.is_set():
            return True
        m = _read_marker(key)
        kernels = _unpack(m["kernels"]) if m and m.get("kernels") else None
        if not kernels:
            return False
        t0 = time.perf_counter()
        try:
            load_kernels(kernels, should_stop)
        except RenderCancelled:
            return False
        with self._lock:
            g = self._jobs.setdefault(key, _Group(key, [job]))
            if not g.event.is_set():
                g.seconds, g.was_cold = time.perf_counter() - t0, False
                g.event.set()
        return True

    def wait_for(self, job, should_stop: Optional[Callable[[], bool]] = None,
                 on_wait: Optional[Callable[[float], None]] = None, rest: bool = True,
                 poll: float = 0.05) -> bool:
        """Compile (or load) ``job``'s kernels (:func:`render_job`) before
        those of anything asked for later and block until they are loaded
        here; True when done (also when every variant already is), False
        when ``should_stop()`` returned True first (the compile goes on).
        rest: every variant follows (Blender: the next render with other
        settings is warm too); False in a one-shot render (the CLI), which
        does not wait for them."""
        if self.done:
            return True
        if self._compile is None and self._load_here(job, should_stop):
            if rest:
                self.start()
            return True
        self.request(job, rest)
        return self._wait_group(self._jobs[job_key(job)], should_stop, on_wait, poll,
                                lambda: self.request(job, rest))


warmup = Warmup()
"""The process's warm-up (the add-on, the viewport and the CLI share it)."""
