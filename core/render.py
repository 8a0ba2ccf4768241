"""The progressive render loop: the one entry point the add-on, the CLI and tests use.

    r = Renderer(scene, settings, log=print)   # may raise SceneError / SettingsError
    for line in r.plan_lines(): print(line)
    result = r.run(should_stop=lambda: False, on_pass=callback)

API CONTRACT
- ``Renderer(scene: Scene, settings: RenderSettings, log: Callable[[str], None] = print,
  should_stop=None, ..., passes=())``: ``should_stop()`` is polled during the set-up too
  (BVH, plan, occlusion grid); True raises RenderCancelled.  ``passes``: names of
  core.sppm.film.PASSES (Depth, Normal, ...) to produce in ``PassResult.aovs``.
- ``Renderer.width, Renderer.height``: size of the rendered region (the border
  crop when ``scene.camera.border`` is set), ``Renderer.offset``: (x0, y0) of that
  region in Blender's pixel coordinates (y from the bottom).
- ``Renderer.plan_lines() -> list[str]``: the render plan and export summary.
- ``Renderer.step() -> PassResult``: runs one pass.
- ``Renderer.run(should_stop=None, on_pass=None) -> PassResult``: passes until
  ``settings.max_passes`` or ``settings.time_limit`` is reached or
  ``should_stop()`` returns True (polled inside passes; a cancelled pass is
  discarded and the last complete result is returned).  ``on_pass(result)`` is
  called after every completed pass.
- ``PassResult`` (core.sppm.film): ``pass_index`` (1-based), ``photons_emitted``
  (total so far), ``elapsed`` (s since the first pass started), ``image`` (H, W, 4)
  float32 RGBA linear radiance with row 0 at the TOP, ``aovs`` dict name ->
  (H, W, C) float32 (row 0 at the top), ``mean_radius_px`` float, ``stats_line() -> str``.
- ``Renderer.state_dict()`` / ``load_state(d)``: checkpoint and resume
  (core.io.checkpoint); ``Renderer.STATE_KEYS``: the arrays every checkpoint holds.
- ``Renderer.state``: the per-pixel progressive state (core.sppm.state.PixelState);
  its fields are also readable as ``Renderer.R2``, ``Renderer.N``, ...

Pass stages (pbrt-v4 SPPM order), one home each:
1. camera pass: visible points through specular chains, emission seen along
   them (core.sppm.visible_points);
2. direct light by next-event estimation (core.lights.nee);
3. initial radii of new visible points (core.sppm.update);
4. photon pass: trace, grid of visible points, gather (core.sppm.photon_pass);
5. per-pixel N / R / tau update (core.sppm.update), into the state (core.sppm.state);
6. film and AOVs (core.sppm.film).
With ``integrator = 'LIGHT'`` a pass is instead photons_per_pass light paths
connected to the camera (core.integrators.light_tracer); the image is their
splat sums over the paths traced (no AOVs).
With ``integrator = 'PATH'`` a pass is instead camera paths alone
(core.integrators.PathTracer, docs/integrators.md) into the same film;
``'COMBINED'`` (the default) adds light tracing and photon merging.  Both
take the film's alpha and data passes from stage 1's camera pass, run when
merging or the film needs it (docs/integrators.md, "Passes and film alpha").
A 'COMBINED' pass with no camera path and no such need is a 'LIGHT' pass
(``Renderer.light_pass``).
"""
from __future__ import annotations

import copy
import time
from dataclasses import fields, replace
from typing import Callable, Optional

import numpy as np

from . import memory
from .accel import RAY_SHADOW, Accel
from .integrators import PathTracer
from .errors import CheckpointMismatch, FPPMError, RenderCancelled, SceneError
from .lights import build_light_table
from .lights import shadow
from .lights.nee import NextEventEstimation
from .materials import build_material_table
from .scene.linking import table_receivers
from .scene.shadow_linking import views as shadow_views
from .plan import RenderPlan, make_plan, merges, with_camera_stop
from .sanity import check_resolution, check_scene, recentre
from .scene.camera import CameraModel, FilterSampler
from .scene.model import Scene, drop_invalid_triangles, scene_digest
from . import setup_cache as SC
from .setup_cache import SetupCache
from .settings import RenderSettings
from .sppm import hashgrid
from .sppm.film import AOVS, PASSES, Film, PassResult, data_passes, pass_enabled
from .sppm import cryptomatte
from .sppm.shadow_catcher import ShadowCatcher
from .sppm.shader_aovs import film_passes
from .sppm.photon_pass import AHEAD_CHUNKS, PHOTON_CHUNK, PhotonPass, frequency_photons
from .frequency.curvature import scene_curvature
from .sppm.photons import PhotonTracer
from .sppm.state import PixelState
from .sppm.update import HIST_BINS, SECTOR_CELLS, Radii, needs_sectors
from .sppm.visible_points import CameraPass, InTurn, VisiblePoints

__all__ = ["Renderer", "PassResult", "VisiblePoints", "PHOTON_CHUNK"]

_STATE_FIELDS = frozenset(f.name for f in fields(PixelState))
#: The random stream of the Ambient Occlusion pass's rays (the film's).
AO_STREAM = 0xA0


#: malloc_trim before each pass's camera stage (memory.release_free_heap).
TRIM_BEFORE_CAMERA = True
#: Below hashgrid.PARALLEL_MIN_VPS pixels (the photon pass's grid build on
#: one thread: 256²), a pass's direct light is shared out in blocks
#: (``NextEventEstimation.shared``): a thread of its own (``_side_executor``)
#: takes them from the end of the camera stage, beside the radius
#: initialisation, the kernel clip and the grid build, and this thread takes
#: those left once its grid is built (``PhotonPass.beside``).  Before, the
#: direct light ran first on two threads and the build then left a core
#: idle.  Each visible point's light is its own: the same sums either way
#: (docs/architecture.md "Cores at 256², round 15").  False: as before.
DIRECT_BESIDE_SETUP = True
_SIDE = None


def _side_executor():
    """The one thread that takes a pass's direct-light blocks beside its
    photon pass's set-up (DIRECT_BESIDE_SETUP)."""
    global _SIDE
    if _SIDE is None:
        from concurrent.futures import ThreadPoolExecutor
        _SIDE = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fppm-side")
    return _SIDE


def _timed(fn) -> float:
    """fn(); its wall seconds."""
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def border_rect(border, W: int, H: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) pixel rectangle of a render border, exactly as Blender
    computes its ``disprect`` (render/intern/pipeline.cc, render_init_from_main:
    ``disprect.xmin = rd->border.xmin * winx`` -- a float32 product truncated
    to int), so the region has the size of Blender's render result; y from
    the bottom.  Blender refuses an empty region ("Image too small"); here it
    is widened to one pixel for callers outside Blender."""
    f32 = np.float32
    x0, y0, x1, y1 = (int(f32(b) * f32(n)) for b, n in zip(border, (W, H, W, H)))
    x0, y0 = min(max(x0, 0), W - 1), min(max(y0, 0), H - 1)
    return x0, y0, min(max(x1, x0 + 1), W), min(max(y1, y0 + 1), H)


def camera_region(cam) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) pixel rectangle a render of camera ``cam`` renders:
    its border's (:func:`border_rect`), or the whole image."""
    W, H = (int(v) for v in cam.resolution)
    return (0, 0, W, H) if cam.border is None else border_rect(cam.border, W, H)


class Renderer:
    #: Arrays every checkpoint holds (the optional r_hist / spectrum come with
    #: the settings that need them); derived from the state's fields.
    STATE_KEYS = PixelState.required_keys()
    #: The set-up kept from the last Renderer of the scene (core.setup_cache),
    #: or None; a class default for the subclasses that build only the
    #: scene half (tools/distributed.py's workers).
    _setup_cache: Optional[SetupCache] = None

    @memory.small_pages
    def __init__(self, scene: Scene, settings: RenderSettings,
                 log: Callable[[str], None] = print, should_stop=None,
                 force_stages: tuple = (), passes: tuple = (),
                 setup_cache: Optional[SetupCache] = None):
        self.settings = settings.validate()
        self.log = log
        # The set-up products the last Renderer of this scene built
        # (core.setup_cache: the viewport's restarts), or None.
        self._setup_cache = setup_cache
        # Polled between the set-up stages too (cancel within 1 s).
        self._should_stop = should_stop or (lambda: False)
        self._setup_scene(scene, force_stages, passes)
        self.settings = self.settings.effort_split(self.width * self.height)   # COMBINED's light paths
        st = self.settings
        P = self.width * self.height
        # Seconds per stage, for the benchmark (ratios, not bare times).
        self.stage_seconds = {k: 0.0 for k in ("camera", "direct", "photon_trace", "gather", "update")}
        chains = self.plan.specular_chains or self.plan.glossy_chains
        self.camera_pass = CameraPass(self.scene, self.accel, self.mtab, self.light_table,
                                      self.camera, self.fsamp, self.px, self.py,
                                      st.max_bounces if chains else 1,
                                      frame=self.full_size,
                                      transparent=self.scene.film_transparent,
                                      glossy_chains=self.plan.glossy_chains)
        # Shadow rays pass the objects whose Shadow visibility is off, and
        # those that do not block their emitter (shadow linking).
        self.direct_light = NextEventEstimation(
            self.light_table, self.mtab, self.accel.for_rays(RAY_SHADOW), self.scene.tri_p,
            views=shadow_views(self.accel, self.scene, self.light_table))
        self.camera_pass.nee = self.direct_light    # the glossy points' shadow rays
        freq = self.plan.frequency_photons
        self.radii = Radii(st, self.camera, self.D, freq, self.camera_pass, self.height, self.width)
        self.photon_pass = PhotonPass(self.tracer, self.mtab, st, freq,
                                      self.radii.hist if self.radii.quantile else None,
                                      self.stage_seconds)
        self.photon_pass.next_pass = lambda: self.pass_index + 1
        self.film = Film(st, self.camera, self.height, self.width, self.scene, passes)
        # integrator 'PATH': camera paths alone (core.integrators) into the same film.
        self.path_tracer = (PathTracer(self.scene, self.accel, self.mtab, self.light_table,
                                       self.camera, self.fsamp, self.px, self.py, st,
                                       self.direct_light,
                                       transparent=self.scene.film_transparent)
                            if st.integrator in ("PATH", "COMBINED") else None)
        self.state = PixelState.zeros(P, HIST_BINS if self.radii.quantile else 0, st.aov_spectrum,
                                      self.radii.sector_cells)
        self.pass_index = 0
        self.photons_emitted = 0
        self.elapsed = 0.0
        self._fixed: Optional[tuple[VisiblePoints, np.ndarray]] = None
        self.last_result: Optional[PassResult] = None
        # (k, the photon stream of pass k) handed to the photon pass before
        # pass k began (PhotonPass.trace_ahead's then=); its next trace_ahead
        # carries on with it.
        self._early_photon_rng: Optional[tuple[int, np.random.Generator]] = None
        self.light_tracer = None
        if st.integrator == "LIGHT":
            from .integrators.light_tracer import LightTracer
            self.light_tracer = LightTracer(self.scene, self.accel, self.mtab, self.light_table,
                                            self.camera, st, self.plan, self.D, self.offset,
                                            (self.width, self.height), self.scene.filter_width,
                                            self.scene.filter_type)
            self.light_splat = np.zeros((P, 3))      # splat sums of every pass
        # integrator 'COMBINED': camera paths + light tracing, MIS-weighted
        # (core.integrators.combined); the splats go to their own buffer.
        self.combined_lt = None
        self.merge_mis = False
        self.light_pass = False
        # Photon merging in 'COMBINED' (core.integrators.merge): SPPM on the
        # visible points seen through a delta vertex, caustic photons only.
        self.merging = st.integrator == "COMBINED" and merges(self.plan)
        # The first hits' positions, normals, triangles and emission: only
        # the film's data passes and photon merging read them (not alpha).
        self.camera_pass.first_data = memory.keeps_first_hits(bool(self.film.data_passes),
                                                              st.integrator, self.merging)
        self.camera_pass.line_hits = self.film.reads_line_hits
        self.film.mtab, self.film.light_table = self.mtab, self.light_table
        self.film.shadow_accel = self.accel.for_rays(RAY_SHADOW)
        self.film.rng = np.random.default_rng([st.seed, AO_STREAM])
        # Shadow catchers (core.sppm.shadow_catcher): their sums read the first hits.
        self.film.catcher = ShadowCatcher.of_scene(self.scene, self.accel, self.light_table,
                                                   self.mtab, P, getattr(self.film, "eye", None),
                                                   getattr(self.film, "view", None), st.seed,
                                                   passes, self.direct_light)
        if self.film.catcher is not None:
            self.camera_pass.first_data = True
        if st.integrator == "COMBINED":
            from .integrators.combined import CameraMIS, CombinedLightTracer
            self.path_tracer.vc = CameraMIS(self.light_table, self.mtab, self.camera,
                                            st.photons_per_pass, st.camera_samples)
            self.path_tracer.vc.merging = self.merging
            self.tracer.after_delta_only = self.merging
            # Merging as an MIS strategy (merge_weights 'MIS', needs light
            # tracing's paths: core.integrators.merge_kernels) instead of the partition.
            self.merge_mis = (self.merging and st.merge_weights == "MIS"
                              and "light tracing" in self.plan.strategies)
            if self.merge_mis:
                self.path_tracer.vc.merging = self.tracer.after_delta_only = False
                # The frequency kernel's radii (predicted radius, holds): a
                # pass of frequency photons alone (frequency_fraction of the
                # light paths, amortised over the passes as PHOTON's:
                # _step_merge_mis), whose flux is not used.
                self.merge_freq_pass = None
                if self.plan.frequency_photons and st.frequency_fraction > 0:
                    n_f = max(1, int(round(st.photons_per_pass * st.frequency_fraction)))
                    self.merge_freq_pass = PhotonPass(
                        self.tracer, self.mtab,
                        replace(st, photons_per_pass=n_f, frequency_fraction=1.0,
                                frequency_decay=0.0, frequency_start=1), True,
                        self.radii.hist if self.radii.quantile else None, self.stage_seconds)
            if "light tracing" in self.plan.strategies:
                self.combined_lt = CombinedLightTracer(
                    self.scene, self.accel, self.mtab, self.light_table, self.camera, st,
                    self.plan, self.D, self.offset, (self.width, self.height),
                    self.scene.filter_width, self.scene.filter_type,
                    camera_samples=st.camera_samples)
            # Camera paths that light tracing takes over (combined.CameraStop).
            stop = self.path_tracer.vc.stop = getattr(self.combined_lt, "stop", None)
            if stop is not None:
                if stop.one:
                    self.path_tracer.samples = self.combined_lt.K
                    self.path_tracer.vc.set_samples(self.combined_lt.K)
                self.plan.strategies = with_camera_stop(self.plan.strategies, stop,
                                                        self.path_tracer.samples)
            if self.combined_lt is None and not self.merging:
                # Neither light tracing nor merging (the plan left both out:
                # an HDRI or a sun alone): every weight of the camera side
                # is 1, and the camera paths render PATH's image without
                # CameraMIS's terms.
                self.path_tracer.vc = None
            self.light_splat = np.zeros((P, 3))
            # No camera path (CameraStop.camera_free), no merging and nothing
            # the film reads from a camera pass or the photon state (alpha,
            # data passes, FPPM's AOVs): a pass is LIGHT's pass and its image
            # LIGHT's image (_step_light, _film), without the camera side's
            # per-pass calls (docs/integrators.md "Camera depth").
            self.light_pass = (stop is not None and stop.camera_free and not self.merging
                               and not self.film.needs_camera
                               and not any(getattr(st, a.flag) for a in AOVS))

    def _setup_scene(self, scene: Scene, force_stages: tuple, passes: tuple = ()) -> None:
        """Region, lights, materials, BVH, plan, occlusion grid and photon tracer."""
        log = self.log
        check_scene(scene)          # refusals: non-finite lights or camera, float32 range
        given, cache = scene, self._setup_cache
        valid, dropped = SC.get(cache, given, ("valid",), lambda: drop_invalid_triangles(given))
        # (a kept Scene carries an earlier camera: this one's)
        scene = valid if valid.camera is scene.camera else replace(valid, camera=scene.camera)
        self.dropped_triangles = dropped
        if dropped:
            log(f"FPPM: dropped {dropped} NaN, infinite or zero-area triangle(s).")
        # A scene far from the origin is moved to it before Embree's float32
        # copy (core.sanity.recentre); self.origin [m] is where it was.
        scene, self.origin = recentre(scene)
        check_resolution(scene)
        # What the products below depend on beyond the scene's fields: the
        # recentring and the bounds and diameter, which hold the camera.
        lo, hi = scene.bounds()
        placed = (self.origin.tobytes(), lo.tobytes(), hi.tobytes())
        self.scene = scene
        cam = scene.camera
        W, H = (int(v) for v in cam.resolution)
        if W < 1 or H < 1:
            raise SceneError(f"The render resolution {W}x{H} is empty: set a resolution of at least 1x1.")
        self.full_size = (W, H)
        x0, y0, x1, y1 = camera_region(cam)
        self.offset = (x0, y0)
        self.width, self.height = x1 - x0, y1 - y0
        self.D = scene.diameter()
        st0 = self.settings
        self.memory = memory.estimate(self.width * self.height,
                                      min(st0.photons_per_pass, PHOTON_CHUNK), scene.n_triangles,
                                      st0.occlusion_grid_res, st0.use_frequency,
                                      aov_channels=sum(p.channels for p in PASSES
                                                       if p.name in passes or pass_enabled(p, st0))
                                      + sum(p.channels for p in film_passes(scene, passes))
                                      + 4 * sum(map(cryptomatte.is_pass, passes))
                                      # the shadow catchers' sums (7 float64 a pixel)
                                      + 2 * (scene.tri_catcher is not None),
                                      hist_bins=HIST_BINS if st0.frequency_estimator == "QUANTILE" else 0,
                                      texture_bytes=sum(np.asarray(t).nbytes for t in scene.textures),
                                      sector_cells=SECTOR_CELLS if needs_sectors(st0, st0.use_frequency) else 0,
                                      clip_kernel=st0.clip_kernel,
                                      chunks_ahead=AHEAD_CHUNKS,
                                      view_triangles=memory.view_triangles(scene.tri_visibility, scene),
                                      # CameraPass.first_data (set in __init__), before the plan
                                      first_hits=memory.keeps_first_hits(bool(data_passes(passes, scene))
                                                                         or scene.tri_catcher is not None,
                                                                         st0.integrator))
        memory.check_fits(self.memory)
        self.light_table = SC.get(cache, given, ("lights",) + placed,
                                  lambda: build_light_table(scene))
        for w in getattr(self.light_table, "warnings", []):
            log(f"FPPM: {w}")
        if not np.any(self.light_table.flux.sum(axis=1) > 0):
            raise SceneError("The scene has no light: add a light with non-zero power, "
                             "an emissive material or a world colour.")
        self.mtab = build_material_table(scene.materials, scene.textures)
        # Light linking: each material row's receiver set (core.scene.linking).
        self.mtab.receiver = table_receivers(scene, self.mtab)
        self._check_stop()
        accel = SC.get(cache, given, ("accel", self.origin.tobytes()),
                       lambda: Accel(scene.tri_p, self.D, scene.tri_visibility))
        # Its offset floor is relative to the diameter: another diameter's
        # Accel shares the BVH only.
        self.accel = (accel if accel.diameter == self.D else
                      Accel(scene.tri_p, self.D, scene.tri_visibility, embree=accel._scene))
        self._check_stop()
        self.camera = CameraModel(cam)
        self.fsamp = FilterSampler(scene.filter_width, scene.filter_type)
        # force_stages: stage names the plan must keep even when the scene does
        # not need them (tests and benchmarks of the leave-out plan).
        # Light tracing uses no frequency photons (no occlusion grid either).
        # COMBINED's plan keeps them for photon merging alone (core.plan).
        plan_st = st0.replace(use_frequency=False) if st0.integrator == "LIGHT" else st0
        self.plan: RenderPlan = make_plan(scene, plan_st, self.mtab, self.light_table,
                                          force=tuple(force_stages))
        # The plan as the scene and settings make it, before the renderer
        # restates COMBINED's camera paths (with_camera_stop) or leaves out
        # the holds after pass 1: what a Dask worker's own make_plan must
        # equal (tools/distributed.py).
        self.scene_plan: RenderPlan = copy.deepcopy(self.plan)
        if self.plan.transparent_shadows:
            shadow.attach(self.accel, scene, self.mtab)     # core.lights.shadow
        self._check_stop()
        self.kappa = (SC.get(cache, given, ("kappa", self.origin.tobytes()),
                             lambda: scene_curvature(scene))
                      if self.plan.frequency_photons else None)
        self._placed = (given, placed)
        self._check_stop()
        self.occ_grid = None
        self.occ_locality = 0.0
        # frequency_start S > 1 (photon mapping): no frequency photon before
        # pass S, so the occlusion grid is built lazily, in the step of pass
        # S - 1 (_occlusion_before), whose photon pass then keeps the reach
        # source of pass S (docs/method.md "A late start for the frequency
        # photons, round 18").
        self._occ_pending = (self.plan.occlusion_grid and st0.frequency_start > 1
                             and st0.integrator == "PHOTON")
        if self.plan.occlusion_grid and not self._occ_pending:
            self.occ_grid, self.occ_locality = self._build_occlusion(scene)
        self.tracer = PhotonTracer(self.scene, self.accel, self.mtab, self.light_table,
                                   self.settings, self.plan, self.kappa, self.occ_grid,
                                   self.occ_locality, self.D)
        # Pixel grid of the region, py counted from the bottom (Blender's).
        ys, xs = np.mgrid[0:self.height, 0:self.width]
        self.px = (xs.ravel() + x0).astype(np.float64)
        self.py = ((self.height - 1 - ys).ravel() + y0).astype(np.float64)

    def _build_occlusion(self, scene: Scene):
        """(occlusion grid, its locality [m]) of scene (core.frequency.occlusion_grid);
        its wall seconds in ``occ_build_seconds``."""
        given, placed = self._placed
        return SC.get(self._setup_cache, given,
                      ("occlusion", self.settings.occlusion_grid_res) + placed,
                      lambda: self._build_occlusion_now(scene))

    def _build_occlusion_now(self, scene: Scene):
        """:meth:`_build_occlusion` without the cache."""
        from .frequency.occlusion_grid import (build_occlusion_grid, default_locality,
                                               geometry_bounds)
        t0 = time.perf_counter()
        lo, hi = geometry_bounds(scene)
        pad = 1e-3 * self.D
        res = self.settings.occlusion_grid_res
        # Locality = 2 voxel diagonals (the grid's default); distances
        # beyond 4x that are never used, so the build may stop there.
        diag = float(np.linalg.norm((hi - lo + 2 * pad) / res))
        locality = 2.0 * diag
        grid = self._interruptible(build_occlusion_grid, scene.tri_p, lo - pad, hi + pad, res,
                                   max_distance=4.0 * locality + 2 * diag)
        self.occ_build_seconds = time.perf_counter() - t0
        return grid, default_locality(grid)

    def _occlusion_before(self, k: int) -> None:
        """Build the occlusion grid left for later (``_occ_pending``) before
        pass k when pass k + 1 may be the first frequency pass (k >= S - 1):
        pass k's photon pass keeps its reach source (the tracer then uses
        one) for pass k + 1's reach map and radius cut.  The chunks traced
        ahead meanwhile carry no spectrum: they read neither the grid nor
        the march."""
        if not self._occ_pending or k < self.settings.frequency_start - 1:
            return
        self.occ_grid, self.occ_locality = self._build_occlusion(self.scene)
        tr = self.tracer
        tr.occ_grid, tr.occ_locality = self.occ_grid, self.occ_locality
        tr.occlusion, tr.march = tr._occlusion_march()
        self._occ_pending = False

    def __getattr__(self, name):
        # renderer.R2, renderer.N, ...: the fields of the per-pixel state.
        state = self.__dict__.get("state")
        if state is not None and name in _STATE_FIELDS:
            return getattr(state, name)
        raise AttributeError(f"'Renderer' object has no attribute '{name}'")

    @property
    def radius_floor(self) -> float:
        """Smallest radius [m] (core.frequency.spectrum.R_FLOOR_REL x the scene diameter)."""
        return self.radii.floor

    @property
    def light_only(self) -> bool:
        """A pass is light tracing's alone: integrator LIGHT, or a Combined
        plan without camera paths (``light_pass``)."""
        return self.light_tracer is not None or self.light_pass

    @property
    def photons_per_step(self) -> int:
        """Photons (light paths) one pass emits: none for camera paths alone
        (PATH, or COMBINED with neither light tracing nor merging)."""
        if self.path_tracer is not None and self.combined_lt is None and not self.merging:
            return 0
        return self.settings.photons_per_pass

    @property
    def photon_rays(self) -> int:
        """Rays cast by the photon passes so far."""
        return self.photon_pass.rays

    # ------------------------------------------------------------------ API
    def plan_lines(self) -> list[str]:
        s = self.scene
        lines = [f"Scene: {s.n_triangles} triangles, {len(s.materials)} materials, "
                 f"{len(s.lights)} lights, {self.width}x{self.height} px."]
        if self.settings.integrator == "LIGHT":
            lines.append("Integrator: light tracing (photon paths connected to the camera).")
        else:
            lines += self.plan.lines()
        return lines

    def settle(self) -> None:
        """Wait for the work this renderer runs between passes (the next
        pass's photons, traced ahead: ``PhotonPass.settle``) to finish.  The
        next pass is unchanged; a caller timing passes by CPU calls it before
        work of its own that it leaves out of the passes' time."""
        settle = getattr(self.photon_pass, "settle", None)    # None: a stand-in
        if settle is not None:
            settle()

    def run(self, should_stop=None, on_pass=None) -> PassResult:
        st = self.settings
        if should_stop is not None:
            self._should_stop = should_stop
        while True:
            if st.max_passes and self.pass_index >= st.max_passes:
                break
            if st.time_limit and self.elapsed >= st.time_limit:
                break
            if self._should_stop():
                break
            try:
                res = self.step()
            except RenderCancelled:
                break
            if on_pass is not None:
                on_pass(res)
            del res     # not held through the next pass: its film may reuse the image
        self._drop_early()
        if self.last_result is None:
            self.last_result = self._film()
        if self.pass_index and not np.any(self.last_result.image[..., :3] > 0):
            # A hidden emitter or a camera inside a closed object is
            # rendered as it is (black, like Cycles), but said so.
            self.log("FPPM: the image is black: no light reaches anything the camera sees "
                     "(every light is hidden behind geometry, or the camera is inside a "
                     "closed object).")
        return self.last_result

    @memory.small_pages
    def step(self) -> PassResult:
        """One pass; the state changes only once the pass is complete (a cancel
        keeps the last one), except the footprint depths of its visible points."""
        if self.light_only:
            return self._step_light()
        if self.path_tracer is not None:
            return self._step_path()
        t0 = time.perf_counter()
        k = self.pass_index + 1
        st, state, clock = self.settings, self.state, self.stage_seconds
        self._occlusion_before(k)
        rng_photons = self._photon_stream(k)
        # The photons are traced while the camera and direct light run, and
        # the next pass's first chunk from when this pass's last chunk is
        # traced (then=).  A stand-in photon pass may have no trace_ahead
        # (a benchmark's wrapper; tools/distributed.py's delegates it to its
        # local pass, for the pass's radius cut): _photons then sets the cut.
        ahead = getattr(self.photon_pass, "trace_ahead", None)
        if ahead is not None:
            ahead(rng_photons, then=lambda: self._next_photon_stream(k + 1))
        tc = time.perf_counter()
        if st.cap_radius_at_edges and k == 1:
            # The edge cap's own camera pass (once a render, for the first
            # radii) before this pass's: its arrays are freed before the
            # pass's are made, not held beside them (the first pass's peak).
            self.radii.edge_cap(self._check_stop)
        if TRIM_BEFORE_CAMERA:
            memory.release_free_heap(state.R2.size)   # the last pass's freed temporaries
        if st.fixed_visible_points and self._fixed is not None:
            vp, L_emit = self._fixed
        else:
            vp, L_emit = self._interruptible(self.camera_pass, self._rng(k, 0), self._check_stop)
            if st.fixed_visible_points:
                self._fixed = vp, L_emit
        td = time.perf_counter()
        clock["camera"] += td - tc
        L_pass = L_emit
        job = None
        K = 1                                         # light samples a visible point
        if not st.photons_for_direct:
            streams = self._direct_streams(k)
            K = len(streams)
            # The estimates go into this pass's own emission array (no (P, 3)
            # array beside it), which holds K L_emit plus the K estimates
            # until the division below (by 2 or 4, the automatic K: exact).
            if st.fixed_visible_points:
                L_pass = L_pass * K                   # a copy: L_emit is kept for the next passes
            elif K > 1:
                L_pass *= K
            shared = getattr(self.direct_light, "shared", None)   # None: a stand-in
            if (DIRECT_BESIDE_SETUP and shared is not None and not st.fixed_visible_points
                    and vp.valid.shape[0] < hashgrid.PARALLEL_MIN_VPS):
                jobs = [shared(vp, r, L_pass) for r in streams]
                job = None if jobs[0] is None else InTurn(jobs)
            if job is None:
                for r in streams:
                    self._interruptible(self.direct_light, vp, r, add_to=L_pass)
        clock["direct"] += time.perf_counter() - td
        side = None
        try:
            if job is not None:
                # vp and L_pass are only read by the photon pass
                side = _side_executor().submit(_timed, job.take)
                self.photon_pass.beside = job.take
            self._check_stop()
            self._photons(vp, rng_photons, cut_set=ahead is not None)
            if job is not None:
                job.take()              # those left (the photon pass found no active point)
        finally:
            if job is not None:
                self.photon_pass.beside = None
                job.stop()              # a cancel: no block starts now
                if side is not None:
                    side.exception()    # waits: nothing writes L_pass after the pass
        if side is not None:
            clock["direct"] += side.result()
        if K > 1:
            L_pass /= K
        tu = time.perf_counter()
        state.L_sum += L_pass
        self.film.accumulate(vp)
        clock["update"] += time.perf_counter() - tu
        self.pass_index = k
        self.photons_emitted += st.photons_per_pass
        self.elapsed += time.perf_counter() - t0
        self.last_result = self._film()
        return self.last_result

    def _step_light(self) -> PassResult:
        """One pass of light tracing (integrator 'LIGHT', or 'COMBINED' with
        ``light_pass``): photons_per_pass light paths splatted to the camera
        (core.integrators.light_tracer); the image is the splat sums over
        the light paths traced."""
        t0 = time.perf_counter()
        k = self.pass_index + 1
        st = self.settings
        lt = self.light_tracer or self.combined_lt
        sums = lt.trace_pass(st.photons_per_pass, self._rng(k, 2), self._check_stop)
        self.light_splat += sums
        self.pass_index = k
        self.photons_emitted += st.photons_per_pass
        dt = time.perf_counter() - t0
        self.stage_seconds["photon_trace"] += dt
        self.elapsed += dt
        self.last_result = self._film()
        return self.last_result

    def _step_path(self) -> PassResult:
        """One pass of the path tracer: camera_samples paths per pixel, averaged
        over the passes by the film (L_sum / passes; no photons).  The camera
        pass's visible points (stream 0, as :meth:`step`'s) feed photon
        merging and the film's alpha and data passes: first-hit quantities,
        computed as photon mapping computes them (core.sppm.film PASSES)."""
        t0 = time.perf_counter()
        k = self.pass_index + 1
        if self.merge_mis:
            return self._step_merge_mis(k, t0)
        L_pass = self._interruptible(self.path_tracer, self._rng(k, 3), self._check_stop,
                                     pass_index=k)
        tl = time.perf_counter()
        self.stage_seconds["camera"] += tl - t0
        vp = None
        if self.merging or self.film.needs_camera:
            vp, _ = self._interruptible(self.camera_pass, self._rng(k, 0), self._check_stop)
            self.stage_seconds["camera"] += time.perf_counter() - tl
            tl = time.perf_counter()
        sums = None
        if self.combined_lt is not None:
            st = self.settings
            sums = self._interruptible(self.combined_lt.trace_pass, st.photons_per_pass,
                                       self._rng(k, 2), self._check_stop)
            self.stage_seconds["photon_trace"] += time.perf_counter() - tl
        if self.merging:
            self._merge(k, vp)   # last: a cancel inside leaves the splats uncommitted
        if sums is not None:
            self.light_splat += sums
        self.photons_emitted += self.photons_per_step
        self.state.L_sum += L_pass
        if vp is not None:
            self.film.accumulate(vp)
        self.pass_index = k
        self.elapsed += time.perf_counter() - t0
        self.last_result = self._film()
        return self.last_result

    def _step_merge_mis(self, k: int, t0: float) -> PassResult:
        """:meth:`_step_path` with merging as an MIS strategy: the camera
        pass first (its visible points' radii initialised), so that the
        camera paths, light tracing's splats and the weighted gather of light
        tracing's own deposits (core.integrators.merge_kernels) read the same
        radii.  The radius reduction counts the gathered photons unweighted,
        its predicted radii and holds from a pass of frequency photons alone
        (``merge_freq_pass``; plain PPM without one); the merged radiance
        joins the splats (both / light paths traced)."""
        from .integrators.merge_kernels import merge_gather
        if not hasattr(self.combined_lt, "merge_deposits"):
            raise FPPMError("Merging as an MIS strategy needs light tracing's paths in this "
                            "process (not with tools/distributed.py): use merge weights "
                            "'PARTITION'.")
        st, state = self.settings, self.state
        vp, _ = self._interruptible(self.camera_pass, self._rng(k, 0), self._check_stop)
        self.radii.initialise(state, vp, self._check_stop)
        R2 = state.R2.copy()
        region = (*self.offset, self.width, self.height)
        self.path_tracer.vc.mis_merge = (R2, float(st.photons_per_pass), region)
        self.combined_lt.merge_R2 = R2
        tl = time.perf_counter()
        self.stage_seconds["camera"] += tl - t0
        L_pass = self._interruptible(self.path_tracer, self._rng(k, 3), self._check_stop,
                                     pass_index=k)
        tp = time.perf_counter()
        self.stage_seconds["camera"] += tp - tl
        sums = self._interruptible(self.combined_lt.trace_pass, st.photons_per_pass,
                                   self._rng(k, 2), self._check_stop)
        dep = self.combined_lt.merge_deposits()
        self.combined_lt.kept = None
        tg = time.perf_counter()
        self.stage_seconds["photon_trace"] += tg - tp
        P = R2.shape[0]
        M, r_pred, sectors = np.zeros(P), np.full(P, np.inf), None
        if dep is not None:
            Lm, M = merge_gather(vp, R2, R2, dep, self.mtab, self.camera, region)
            sums = sums + Lm
        self.stage_seconds["gather"] += time.perf_counter() - tg
        if self.merge_freq_pass is not None and k >= st.frequency_start:
            # Pass k's frequency photons (frequency_photons: fewer in later
            # passes, docs/method.md "Amortised frequency photons"), all of them.
            fp = self.merge_freq_pass
            fp.settings = replace(fp.settings, photons_per_pass=max(1, frequency_photons(st, k)))
            self.tracer.set_radius_cut(R2)
            est = self.merge_freq_pass(vp, R2, state.spectrum, self._rng(k, 4),
                                       self._check_stop)
            if est.r_hist is not None:
                state.r_hist += est.r_hist
            if est.spectrum is not None:
                state.spectrum[...] = est.spectrum
            r_pred = (self.radii.predicted(est.r_pred_min, state.r_hist) if est.gathered
                      else est.r_pred_min)
            sectors = est.sectors
        tu = time.perf_counter()
        if state.sectors is not None and sectors is None:
            sectors = np.zeros_like(state.sectors)
        self.radii.update(state, np.asarray(M, np.float64), np.zeros((P, 3)), r_pred, sectors)
        self.stage_seconds["update"] += time.perf_counter() - tu
        self.light_splat += sums
        self.photons_emitted += self.photons_per_step
        self.state.L_sum += L_pass
        self.film.accumulate(vp)
        self.pass_index = k
        self.elapsed += time.perf_counter() - t0
        self.last_result = self._film()
        return self.last_result

    def _merge(self, k: int, vp: VisiblePoints) -> None:
        """Photon merging of pass k (integrator 'COMBINED'): the SPPM stages
        of :meth:`step` -- radii, photon pass, progressive update -- on the
        camera pass's visible points vp reached through a delta vertex, with
        the caustic photons the tracer keeps (``after_delta_only``); the film
        adds tau / (pi R^2 N_emitted).  No next-event estimation or emission
        here: the camera paths have them."""
        self._photons(replace(vp, valid=vp.through_delta), self._rng(k, 4))

    def _photons(self, vp, rng, cut_set: bool = False) -> None:
        """SPPM stages 3-5 on the visible points vp: initial radii, the photon
        pass, the progressive update of the state.  cut_set: the photon pass's
        trace_ahead has set this pass's radius cut (before its first chunk);
        else it is set here, from the initialised radii, before the pass
        traces anything."""
        state = self.state
        self.radii.initialise(state, vp, self._check_stop)
        np.copyto(state.depth, vp.depth, where=vp.valid)   # in place: no (P,) array a pass
        if not cut_set:
            self.tracer.set_radius_cut(state.R2)
        est = self.photon_pass(vp, state.R2, state.spectrum, rng, self._check_stop)
        tu = time.perf_counter()
        if est.r_hist is not None:
            state.r_hist += est.r_hist
        if est.spectrum is not None:
            state.spectrum[...] = est.spectrum
        r_pred = self.radii.predicted(est.r_pred_min, state.r_hist) if est.gathered else est.r_pred_min
        self.radii.update(state, est.M, est.Phi, r_pred, est.sectors, k=self.pass_index + 1)
        why = self.radii.leave_out_holds(state, self.pass_index + 1)
        if why is not None:
            self._drop_holds(why)
        self.stage_seconds["update"] += time.perf_counter() - tu

    def _drop_holds(self, why: str) -> None:
        """The holds left out (core.sppm.update.Radii.leave_out_holds): the
        photon pass as PPM's from the next pass on, and the plan says why."""
        if self.radii.holds_left_out is None:
            self.radii.drop_holds(why)
        self.photon_pass.drop_frequency()
        self.plan.left_out.append(("frequency holds", why))
        self.log(self.plan.lines()[-1])

    def _film(self) -> PassResult:
        # Dropped first (its caller assigns the new one): the film reuses the
        # last image in place when nothing else holds it (Film._image, core.kept).
        self.last_result = None
        if self.light_only:
            L = self.light_splat / max(self.photons_emitted, 1)
            img = np.ones((self.height, self.width, 4), np.float32)
            img[..., :3] = L.reshape(self.height, self.width, 3)
            return PassResult(self.pass_index, self.photons_emitted, self.elapsed, img)
        res = self.film(self.state, self.pass_index, self.photons_emitted, self.elapsed)
        if self.combined_lt is not None and self.photons_emitted:
            L = self.light_splat / self.photons_emitted
            res.image[..., :3] += L.reshape(self.height, self.width, 3).astype(np.float32)
        return res

    # ------------------------------------------------------ checkpointing
    def state_dict(self) -> dict:
        """Everything needed to continue this render bit for bit: per-pixel
        state, counters and the digests that must match on resume.  RNG
        streams are derived from (seed, pass, stage), so no RNG state is kept."""
        d = self.state.state_dict()
        d.update(pass_index=self.pass_index, photons_emitted=self.photons_emitted,
                 elapsed=self.elapsed, settings_digest=self.settings.image_digest(),
                 scene_digest=scene_digest(self.scene), size=(self.width, self.height))
        d.update(self.film.state_dict())
        if self.radii.holds_left_out is not None:
            d["holds_left_out"] = self.radii.holds_left_out
        if self.light_tracer is not None or self.combined_lt is not None:
            d["light_splat"] = self.light_splat.copy()
        return d

    def load_state(self, d: dict) -> None:
        """Continue from ``state_dict()`` output; refuse a different scene or settings."""
        if d["scene_digest"] != scene_digest(self.scene):
            raise CheckpointMismatch("The checkpoint was made from a different scene "
                                     "(geometry, materials, lights or camera changed).")
        if d["settings_digest"] != self.settings.image_digest():
            raise CheckpointMismatch("The checkpoint was made with different render settings.")
        if tuple(d["size"]) != (self.width, self.height):
            raise CheckpointMismatch("The checkpoint was made at a different resolution.")
        # Every array and counter is checked before use (core.sppm.state.check_state).
        why = self.state.check_state(d)
        if why is None and int(d["photons_emitted"]) != int(d["pass_index"]) * self.photons_per_step:
            why = (f"{d['photons_emitted']} photons for {d['pass_index']} passes of "
                   f"{self.photons_per_step}")
        if why is not None:
            raise CheckpointMismatch(f"The checkpoint is damaged ({why}): delete it to start over.")
        self._drop_early()
        self.state.load_state(d)
        self.film.load_state(d)
        if self.light_tracer is not None or self.combined_lt is not None:
            if "light_splat" not in d:
                raise CheckpointMismatch("The checkpoint has no light tracing film.")
            self.light_splat[...] = d["light_splat"]
        if d.get("holds_left_out") is not None and self.radii.holds_left_out is None:
            self._drop_holds(str(d["holds_left_out"]))
        self.pass_index = int(d["pass_index"])
        self.photons_emitted = int(d["photons_emitted"])
        self.elapsed = float(d["elapsed"])
        if self.settings.fixed_visible_points and self.pass_index > 0:
            # Fixed visible points come from pass 1's camera stream: rebuild them.
            self._fixed = self.camera_pass(self._rng(1, 0), self._check_stop)
        if self.pass_index > 0:
            self._occlusion_before(self.pass_index)
        if (self.photon_pass.keeps_reach and self.pass_index > 0
                and self.path_tracer is None and self.light_tracer is None):
            # The frequency photons' reach map comes from the last pass's
            # visible points (PhotonPass.keep_reach_source): rebuild them.
            vp = self._fixed[0] if self._fixed is not None else self.camera_pass(
                self._rng(self.pass_index, 0), self._check_stop)[0]
            self.photon_pass.keep_reach_source(vp, self.state.R2)
        self.last_result = self._film()

    # ------------------------------------------------------------ helpers
    def _photon_stream(self, k: int) -> np.random.Generator:
        """Pass k's photon stream: the one handed out before it began
        (:meth:`_next_photon_stream`, traced from already), else a new one.
        Either is used once: a pass that is run again draws a new stream."""
        early, self._early_photon_rng = self._early_photon_rng, None
        return early[1] if early is not None and early[0] == k else self._rng(k, 2)

    def _next_photon_stream(self, k: int) -> Optional[np.random.Generator]:
        """Pass k's photon stream for PhotonPass.trace_ahead's then= (pass k
        - 1 is under way), kept for pass k's :meth:`_photon_stream`; None
        after the last pass of max_passes."""
        if self.settings.max_passes and k > self.settings.max_passes:
            return None
        rng = self._rng(k, 2)
        self._early_photon_rng = (k, rng)
        return rng

    def _drop_early(self) -> None:
        """The render is over (or its state replaced): drop the photon
        chunks queued ahead, the next pass's and a cancelled pass's
        (PhotonPass.drop_next: not started, cancelled; running, it finishes
        in its thread)."""
        self._early_photon_rng = None
        drop = getattr(self.photon_pass, "drop_next", None)
        if drop is not None:
            drop(wait=False)

    def _direct_streams(self, k: int) -> list:
        """The random streams of pass k's light samples at the visible
        points, one per estimate (plan.light_samples): the first is the
        direct stage's own stream (one sample: the same image as before the
        setting), each other one its own."""
        K = max(1, int(self.plan.light_samples))
        return [self._rng(k, 1)] + [self._rng(k, 1, j) for j in range(1, K)]

    def _rng(self, k: int, stage: int, *sub: int) -> np.random.Generator:
        # One independent stream per (seed, pass, stage[, sub-streams]):
        # deterministic, and a resumed render continues the same sequence.
        return np.random.Generator(np.random.PCG64(
            np.random.SeedSequence([self.settings.seed, k, stage, *sub])))

    def _check_stop(self):
        if self._should_stop():
            raise RenderCancelled("cancelled")

    def _interruptible(self, fn, *args, **kw):
        """fn(*args, **kw) in a worker thread while this thread polls should_stop.

        For stages whose longest calls cannot poll (the occlusion grid's
        numba kernels, camera.generate and the hit attributes over every
        pixel): they release the GIL often enough (numpy, numba nogil) that
        the poll here runs every ~20 ms and cancel returns at once.  fn must
        not change the renderer's state (its result is simply dropped).  The
        worker's own _check_stop sees a threading.Event, not should_stop
        (which may be Blender's test_break: called from this thread only),
        so an abandoned worker stops at its next check; it is a daemon.
        """
        import threading
        out = {}
        stop = threading.Event()
        caller_should_stop = self._should_stop

        def work():
            try:
                out["value"] = fn(*args, **kw)
            except BaseException as ex:  # re-raised in the caller's thread
                out["error"] = ex
        self._should_stop = stop.is_set
        try:
            th = threading.Thread(target=work, name="fppm-stage", daemon=True)
            th.start()
            while th.is_alive():
                th.join(0.02)
                if caller_should_stop():
                    stop.set()
                    raise RenderCancelled("cancelled")
        finally:
            self._should_stop = caller_should_stop
        if "error" in out:
            raise out["error"]
        return out["value"]
