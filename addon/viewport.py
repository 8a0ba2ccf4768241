"""Rendered viewport: a progressive FPPM session in a background thread.

The engine's ``view_update`` / ``view_draw`` (``addon/engine.py``) stay thin;
everything that decides what to render lives here and runs without a GPU:

- :func:`camera_from_view`: the 3D view's camera (``RegionView3D.view_matrix``
  and ``window_matrix``) as a ``core`` Camera at the region's pixel size.
- :func:`export_view`: the evaluated depsgraph exported with that camera (the
  scene needs no camera object of its own).  Runs on Blender's main thread.
- :class:`ViewportSession`: renders in a daemon thread: waits for the kernel
  warm-up (``core.warmup``), renders one quick pass at the resolution divided
  by ``viewport_resolution_divider`` (a first image after every change:
  fewer photons, no frequency analysis), then
  passes at full resolution up to ``viewport_max_passes``.  The full
  resolution passes are ``Renderer`` passes with the scene's own settings, so
  pass k is bit for bit pass k of a final render of the same camera.
  ``restart`` and ``cancel`` only set flags and hand the job to the
  session's worker thread (which waits for jobs; starting a thread per
  restart would wait for the new thread to be scheduled): they never block
  the caller; a cancelled job stops at the Renderer's next poll.
- :class:`ViewportController`: what the engine calls: re-exports on a
  depsgraph update and restarts only when the scene or the settings really
  changed (``scene_digest``: a selection does not restart); restarts with a
  new camera when the view moved (checked at every draw).
"""
from __future__ import annotations

import dataclasses
import threading
import time
import weakref
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from ..core.scene.model import Camera, Scene, scene_digest
from ..core.settings import RenderSettings, ViewportSettings
from ..core.setup_cache import SetupCache

NO_CAP_PASSES = 1_000_000    # viewport_max_passes = 0: passes until the next change
# A session nobody has asked for an image for this long stops: the viewport
# was closed or left Rendered shading (Blender gives no reliable callback:
# the engine's __del__ may run after its RNA struct is gone).
IDLE_STOP_SECONDS = 10.0
_sessions: "weakref.WeakSet[ViewportSession]" = weakref.WeakSet()


def cancel_all() -> None:
    """Stop every viewport session (the add-on's unregister)."""
    for s in list(_sessions):
        s.cancel()


# --- the view's camera ----------------------------------------------------------

def camera_from_view(view_matrix, window_matrix, size, template: Optional[Camera] = None) -> Camera:
    """A ``core`` Camera seeing exactly what the 3D view shows.

    view_matrix: (4, 4) world -> view; window_matrix: (4, 4) OpenGL projection
    (``RegionView3D.window_matrix``, or ``Object.calc_matrix_camera`` for a
    camera object); size: (width, height) in pixels.  The projection gives the
    field of view, the off-centre shift and the clipping planes; see
    core/scene/camera.py for the view-plane conventions (horizontal sensor
    fit, shift in units of the width).  ``template`` supplies nothing but is
    replaced field by field (keeps a scene camera's other fields).
    """
    V = np.asarray(view_matrix, np.float64).reshape(4, 4)
    P = np.asarray(window_matrix, np.float64).reshape(4, 4)
    W, H = (int(v) for v in size)
    M = np.linalg.inv(V)
    M[:3, :3] /= np.maximum(np.linalg.norm(M[:3, :3], axis=0, keepdims=True), 1e-30)
    persp = abs(P[3, 3]) < 0.5          # OpenGL: w = -z (persp) or w = 1 (ortho)
    if persp:
        # x_ndc = P00 x/(-z) - P02 ; core: x_ndc = (2 lens/sensor) x/(-z) - 2 shift_x
        kind, lens, ortho = "PERSP", 18.0 * P[0, 0], 7.0
        shift_x, shift_y = P[0, 2] / 2.0, P[1, 2] * H / (2.0 * W)
        near, far = P[2, 3] / (P[2, 2] - 1.0), P[2, 3] / (P[2, 2] + 1.0)
    else:
        # x_ndc = P00 x + P03 ; core: x_ndc = 2 x / ortho_scale - 2 shift_x
        kind, lens, ortho = "ORTHO", 50.0, 2.0 / P[0, 0]
        shift_x, shift_y = -P[0, 3] / 2.0, -P[1, 3] * H / (2.0 * W)
        near, far = (P[2, 3] + 1.0) / P[2, 2], (P[2, 3] - 1.0) / P[2, 2]
    base = template or Camera()
    return dataclasses.replace(
        base, kind=kind, matrix_world=M, lens=float(lens), sensor_width=36.0,
        sensor_height=36.0 * H / max(W, 1), sensor_fit="HORIZONTAL", ortho_scale=float(ortho),
        shift_x=float(shift_x), shift_y=float(shift_y), clip_start=float(near),
        clip_end=float(far), resolution=(W, H), pixel_aspect=(1.0, 1.0), border=None,
        aperture_radius=0.0)


def export_view(depsgraph, camera: Camera, log=lambda _m: None) -> Scene:
    """The depsgraph exported by ``addon/export.py`` with ``camera`` as the camera.

    The exporter's own camera step (which needs a scene camera object) is
    replaced; geometry, materials, lights and world are exported as for a
    final render.  Raises SceneError like ``export_scene``.
    """
    from . import export as X

    class _ViewExporter(X._Exporter):
        # On Blender's main thread: a world to bake is baked in the
        # background (addon/world_bake.py), the engine's view_draw exports
        # again when it is done.
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.bake_wait = False

        def camera(self, cam_ob):
            return camera

    class _View:
        name = "viewport"
    return _ViewExporter(depsgraph, log).run(_View())


# --- the background session ----------------------------------------------------

@dataclass
class Frame:
    """The latest image of a session.

    image: (H, W, 4) float32, row 0 at the TOP (core's order), at the view's
    full size (the low-resolution first pass is enlarged pixel by pixel);
    pass_index: passes of the full-resolution render (0 for the first,
    low-resolution image); generation: the restart it belongs to; serial:
    increases with every new image (the drawer re-uploads on change).
    """
    image: np.ndarray
    pass_index: int
    generation: int
    serial: int


@dataclass
class _Job:
    scene: Scene
    settings: RenderSettings
    viewport: ViewportSettings
    generation: int
    stop: threading.Event = dataclasses.field(default_factory=threading.Event)
    finished: threading.Event = dataclasses.field(default_factory=threading.Event)


def enlarge(img: np.ndarray, factor: int, size) -> np.ndarray:
    """(h, w, C) -> (H, W, C): each pixel repeated factor x factor times, cut to size (W, H)."""
    W, H = size
    big = np.repeat(np.repeat(img, factor, axis=0), factor, axis=1)
    return np.ascontiguousarray(big[:H, :W])


class ViewportSession:
    """A progressive render of one view, restarted on every change.

    ``status`` is a short line for the viewport header ("FPPM: compiling
    render kernels ...", "FPPM: Pass 3 | ... (of 64 passes)", an error
    sentence).  ``on_frame()`` (optional)
    is called from the worker thread after each new frame; it must not touch
    bpy (the engine redraws from ``view_draw`` instead).
    """

    def __init__(self, on_frame: Optional[Callable[[], None]] = None):
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._thread: Optional[threading.Thread] = None
        self._job: Optional[_Job] = None
        self._frame: Optional[Frame] = None
        self._generation = 0
        self._serial = 0
        self.on_frame = on_frame
        self.status = ""
        self.error: Optional[str] = None
        self._seen = time.monotonic()     # last frame() call (see IDLE_STOP_SECONDS)
        # The set-up the session's last Renderer built (core.setup_cache):
        # the next one of the same scene (a moved view, the full passes after
        # the quick look) takes what does not depend on what changed.  Only
        # the worker thread uses it.
        self.setup_cache = SetupCache()
        _sessions.add(self)

    # -- control (never blocks) ------------------------------------------------
    def restart(self, scene: Scene, settings: RenderSettings,
                viewport: ViewportSettings = ViewportSettings()) -> int:
        """Cancel the current job and start rendering ``scene``; returns its generation."""
        viewport = viewport.validate()
        cap = viewport.viewport_max_passes or NO_CAP_PASSES
        settings = settings.replace(max_passes=cap, time_limit=0.0).validate()
        with self._lock:
            if self._job is not None:
                self._job.stop.set()
            self._generation += 1
            job = _Job(scene, settings, viewport, self._generation)
            self._job = job
            self.error = None
            self.status = "FPPM: starting"
            self._seen = time.monotonic()
            self._wake.notify()
            start = self._thread is None or not self._thread.is_alive()
            if start:
                self._thread = threading.Thread(target=self._loop, name="fppm-viewport",
                                                daemon=True)
        if start:
            self._thread.start()     # the first restart only (or after an idle exit)
        return job.generation

    def cancel(self) -> None:
        """Stop rendering (the current job ends at the Renderer's next poll)."""
        with self._lock:
            if self._job is not None:
                self._job.stop.set()

    def frame(self) -> Optional[Frame]:
        """The latest image of the current generation (None before the first)."""
        self._seen = time.monotonic()
        with self._lock:
            f = self._frame
            return f if f is not None and f.generation == self._generation else None

    @property
    def busy(self) -> bool:
        job = self._job
        return job is not None and not job.finished.is_set() and not job.stop.is_set()

    def join(self, timeout: float = None) -> bool:
        """Wait for the current job to end (tests); True if it has."""
        job = self._job
        return job is None or job.finished.wait(timeout)

    # -- the worker -------------------------------------------------------------
    IDLE_EXIT_SECONDS = 30.0     # the worker thread ends after this long without a job

    def _loop(self) -> None:
        done: Optional[_Job] = None
        while True:
            with self._lock:
                while self._job is done or self._job is None:
                    if not self._wake.wait(self.IDLE_EXIT_SECONDS):
                        if self._job is done or self._job is None:
                            self._thread = None
                            return
                job = self._job
            try:
                self._work(job)
            finally:
                job.finished.set()
                done = job

    def _publish(self, job: _Job, image: np.ndarray, pass_index: int, status: str) -> None:
        with self._lock:
            if job.generation != self._generation or job.stop.is_set():
                return
            self._serial += 1
            self._frame = Frame(image, pass_index, job.generation, self._serial)
            self.status = status
        if self.on_frame is not None:
            self.on_frame()

    def _set_status(self, job: _Job, status: str) -> None:
        with self._lock:
            if job.generation == self._generation:
                self.status = status

    def _work(self, job: _Job) -> None:
        from ..core.errors import FPPMError, RenderCancelled
        from ..core.settings import SettingsError
        from ..core.warmup import expected_seconds, is_compiled, render_job, warmup

        def stop():
            if not job.stop.is_set() and time.monotonic() - self._seen > IDLE_STOP_SECONDS:
                job.stop.set()
            return job.stop.is_set()

        def kernels(wjob) -> bool:
            # This session's own kernels (core.warmup.render_job), compiled first.
            if not warmup.ready(wjob):
                self._set_status(job, "FPPM: compiling render kernels (first use, about "
                                      f"{expected_seconds(wjob):.0f} s)" if not is_compiled(wjob)
                                 else "FPPM: loading render kernels")
                return warmup.wait_for(wjob, should_stop=stop)
            return True
        try:
            scene, st = job.scene, job.settings
            W, H = (int(v) for v in scene.camera.resolution)
            d = job.viewport.viewport_resolution_divider
            full = render_job(scene, st)
            if d > 1 and W * H > 1:
                small = dataclasses.replace(scene, camera=dataclasses.replace(
                    scene.camera, resolution=(max(1, -(-W // d)), max(1, -(-H // d)))))
                # A quick look, not a pass of the render: 1/d^2 of the photons
                # and without the frequency analysis, whose set-up (occlusion
                # grid, ~0.3-0.5 s whatever the resolution) would delay it.
                pst = st.replace(max_passes=1, use_frequency=False,
                                 photons_per_pass=max(1000, st.photons_per_pass // (d * d)))
                quick = render_job(small, pst)
                warmup.request(quick)
                warmup.request(full)            # compiled right after, in the same child
                if not kernels(quick):
                    return
                from ..core.render import Renderer
                r = Renderer(small, pst, log=lambda _m: None, should_stop=stop,
                             setup_cache=self.setup_cache)
                res = r.run(should_stop=stop)
                if stop():
                    return
                self._publish(job, enlarge(res.image, d, (W, H)), 0,
                              f"FPPM: first pass at 1/{d} resolution")
            if not kernels(full):
                return
            from ..core.render import Renderer
            r = Renderer(scene, st, log=lambda _m: None, should_stop=stop,
                         setup_cache=self.setup_cache)

            def on_pass(pr):
                cap = f" (of {st.max_passes} passes)" if job.viewport.viewport_max_passes else ""
                self._publish(job, pr.image, pr.pass_index, f"FPPM: {pr.stats_line()}{cap}")
            r.run(should_stop=stop, on_pass=on_pass)
            if not stop():
                self._set_status(job, self.status + " | done")
        except RenderCancelled:
            return
        except (FPPMError, SettingsError) as ex:
            self._fail(job, str(ex))
        except Exception as ex:     # a bug: keep the traceback in the console
            import traceback
            traceback.print_exc()
            self._fail(job, f"FPPM internal error: {type(ex).__name__}: {ex}")

    def _fail(self, job: _Job, msg: str) -> None:
        with self._lock:
            if job.generation == self._generation:
                self.error = msg
                self.status = "FPPM: " + msg


# --- what the engine calls --------------------------------------------------------

@dataclass(frozen=True)
class ViewState:
    """The 3D view: world -> view matrix, projection, region size (W, H)."""
    view_matrix: tuple
    window_matrix: tuple
    size: tuple

    @classmethod
    def of(cls, view_matrix, window_matrix, size) -> "ViewState":
        def flat(m):
            return tuple(float(x) for row in m for x in row)
        return cls(flat(view_matrix), flat(window_matrix), (int(size[0]), int(size[1])))

    def camera(self, template: Optional[Camera] = None) -> Camera:
        return camera_from_view(np.array(self.view_matrix).reshape(4, 4),
                                np.array(self.window_matrix).reshape(4, 4), self.size, template)


class ViewportController:
    """Keeps a :class:`ViewportSession` in step with Blender's viewport.

    ``update(depsgraph, view, settings, viewport)``: from ``view_update``
    (Blender's main thread): re-export and restart if the scene, the view or
    the settings changed.  ``draw(view)``: from ``view_draw``: restart with a
    new camera if the view moved; returns the latest Frame (or None).
    """

    def __init__(self, log: Callable[[str], None] = lambda _m: None):
        self.session = ViewportSession()
        self.log = log
        self.scene: Optional[Scene] = None
        self.view: Optional[ViewState] = None
        self._digest = None
        self._settings = None

    def update(self, depsgraph, view: ViewState, settings: RenderSettings,
               viewport: ViewportSettings) -> bool:
        """Returns True when the session was restarted."""
        from ..core.errors import FPPMError
        from ..core.settings import SettingsError
        try:
            scene = export_view(depsgraph, view.camera(), self.log)
        except (FPPMError, SettingsError) as ex:
            self.session.cancel()
            self.session.error = str(ex)
            self.session.status = f"FPPM: {ex}"
            self.scene, self._digest = None, None
            return False
        digest = scene_digest(scene)
        if digest == self._digest and (settings, viewport) == self._settings \
                and view == self.view:
            return False
        self.scene, self.view, self._digest = scene, view, digest
        self._settings = (settings, viewport)
        self._restart()
        return True

    def draw(self, view: ViewState) -> Optional[Frame]:
        if self.scene is not None and view != self.view:
            self.view = view
            self.scene = dataclasses.replace(self.scene, camera=view.camera(self.scene.camera))
            self._digest = scene_digest(self.scene)
            self._restart()
        return self.session.frame()

    def _restart(self) -> None:
        from ..core.settings import SettingsError
        settings, viewport = self._settings
        try:
            self.session.restart(self.scene, settings, viewport)
        except SettingsError as ex:
            self.session.cancel()
            self.session.error = str(ex)
            self.session.status = f"FPPM: {ex}"

    def free(self) -> None:
        from .world_bake import cancel_background
        self.session.cancel()
        # (a Renderer still building holds its own reference)
        self.session.setup_cache.clear()
        cancel_background()
