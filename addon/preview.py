"""Material, light and world previews rendered by FPPM (``bl_use_preview``).

Blender renders the preview spheres of the Properties editor (and the
material/light/world icons) by calling the engine's ``render`` with
``is_preview`` set and a depsgraph of its own preview scene: a sphere, cube,
monkey, ... with the previewed material, the preview lights, a world and, for
some shapes, a checkerboard floor, at the icon's small size (32 px icons,
~128-256 px previews).  The engine hands that call to :func:`render_preview`:

- fixed small settings (:func:`preview_settings`), not the scene's: Blender's
  preview scene carries default FPPM properties anyway, and a preview must be
  quick.  Camera paths (``integrator='PATH'``, core.integrators) need no
  photons and converge fastest on a small image (docs/interactive.md,
  "Previews", has the measurements against photon passes);
- progressive: every pass is written to the result (``update_result``), and
  the render stops at ``should_stop`` (Blender's ``test_break``: the user
  changed the material again) or after :data:`PREVIEW_SECONDS`;
- never blocking on the kernel compile: when the background warm-up
  (core.warmup) has not finished, nothing is drawn and the call returns at
  once; Blender's UI stays responsive and the preview is asked for again
  (:func:`refresh_when_compiled`) once the kernels are loaded;
- never raising: whatever the exporter cannot take (an empty preview scene,
  a light kind or node FPPM skips) ends the preview with nothing drawn and a
  line in the console, not an error report in the UI.

``render_preview`` takes a *sink* instead of the engine (begin/update/end of
the render result) so that tests can run it with real ``bpy`` but without a
render job.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from ..core.errors import SceneError
from ..core.settings import RenderSettings
from ..core.warmup import warmup

#: Seconds of passes a preview may take at most (the first pass is always done).
PREVIEW_SECONDS = 2.0
#: Camera paths per pixel after which a preview is finished.
PREVIEW_SAMPLES = 64
#: Images of at least this many pixels trace one path per pixel and pass (a
#: first image after ~0.3 s at 128 x 128); smaller ones (the 32 px icons) four,
#: where a pass is short and its fixed cost would dominate.
ONE_PATH_PIXELS = 64 * 64


def preview_settings(width: int = 128, height: int = 128) -> RenderSettings:
    """The fixed settings of a preview render of width x height pixels.

    Path tracing (docs/interactive.md, "Previews": lower error at 2 s than
    photon passes on Blender's preview sphere), 8 bounces (glass and mirror
    previews need a few), no frequency analysis (it needs photons).
    """
    spp = 1 if width * height >= ONE_PATH_PIXELS else 4
    return RenderSettings(integrator="PATH", camera_samples=spp,
                          max_passes=PREVIEW_SAMPLES // spp, time_limit=PREVIEW_SECONDS,
                          max_bounces=8, use_frequency=False, cap_radius_at_edges=False,
                          seed=0).validate()


@dataclass
class PreviewOutcome:
    """What one preview call did.

    status: 'done', 'cancelled', 'compiling' (kernels not ready: nothing
    drawn), 'unsupported' (the preview scene could not be rendered: nothing
    drawn; ``message`` says why); image: the last written (H, W, 4) float32
    image (row 0 at the top) or None; passes: completed passes; seconds: wall
    time of the whole call; first_seconds: from the call to the first image
    written (None when none was).
    """
    status: str
    image: Optional[np.ndarray] = None
    passes: int = 0
    seconds: float = 0.0
    message: str = ""
    first_seconds: Optional[float] = None


class EngineSink:
    """The render result of a ``RenderEngine`` as a preview sink."""

    def __init__(self, engine, layer: str = ""):
        self.engine, self.layer, self.result = engine, layer, None

    def begin(self, width: int, height: int) -> None:
        self.result = self.engine.begin_result(0, 0, width, height, layer=self.layer)

    def update(self, image: np.ndarray) -> None:
        from .engine import blender_rows
        self.result.layers[0].passes["Combined"].rect.foreach_set(blender_rows(image, 4))
        self.engine.update_result(self.result)

    def end(self) -> None:
        if self.result is not None:
            self.engine.end_result(self.result)
            self.result = None


_missed = [False]     # a preview was skipped because the kernels were compiling


def render_preview(depsgraph, sink, should_stop: Callable[[], bool] = lambda: False,
                   log: Callable[[str], None] = lambda _m: None,
                   settings: Optional[RenderSettings] = None) -> PreviewOutcome:
    """Render Blender's preview scene ``depsgraph`` into ``sink`` (never raises).

    sink: ``begin(width, height)``, ``update(image)`` with an (H, W, 4)
    float32 image (row 0 at the top), ``end()``; ``begin`` is called only
    when there is something to draw.  should_stop: polled between and inside
    passes.  settings: defaults to :func:`preview_settings`.
    """
    t0 = time.perf_counter()
    warmup.start()
    if not warmup.done:
        _missed[0] = True
        return PreviewOutcome("compiling", seconds=time.perf_counter() - t0)
    began = False
    out = PreviewOutcome("done")
    try:
        # The evaluated camera: the preview scene's original objects are never
        # given their evaluated transforms (the original camera sits at the origin).
        cam = depsgraph.scene.camera
        fscene = preview_exporter(depsgraph, log).run(
            None if cam is None else cam.evaluated_get(depsgraph))
        # Cycles' material and light previews have a transparent background
        # (the UI draws its own behind); the world preview is handled below.
        fscene = dataclasses.replace(fscene, film_transparent=True)
        if should_stop():
            return PreviewOutcome("cancelled", seconds=time.perf_counter() - t0)
        from ..core.render import Renderer
        st = settings or preview_settings(*fscene.camera.resolution)
        r = Renderer(fscene, st, log=log, should_stop=should_stop)
        sink.begin(int(r.width), int(r.height))
        began = True

        def on_pass(pr):
            sink.update(pr.image)
            out.image, out.passes = pr.image, out.passes + 1
            if out.first_seconds is None:
                out.first_seconds = time.perf_counter() - t0

        r.run(should_stop=should_stop, on_pass=on_pass)
        if should_stop():
            out.status = "cancelled"
    except SceneError as ex:
        # Blender's world preview is the camera alone (nothing visible): the
        # image is the world's colour, which every camera ray sees.  The same
        # holds with no light at all (then the world is black, and so is
        # everything).
        flat = None if began else _world_image(depsgraph, log)
        if flat is None:
            out.status, out.message = "unsupported", str(ex)
            log(f"preview not rendered: {ex}")
        else:
            sink.begin(flat.shape[1], flat.shape[0])
            began = True
            sink.update(flat)
            out.image, out.passes = flat, 1
    except Exception as ex:  # noqa: BLE001 - a preview must never raise into the UI
        out.status, out.message = "unsupported", f"{type(ex).__name__}: {ex}"
        log(f"preview not rendered: {out.message}")
    finally:
        if began:
            sink.end()
    out.seconds = time.perf_counter() - t0
    return out


#: Materials of Blender's preview scene (release/datafiles/preview.blend) that
#: hide their object from camera rays with a Light Path node into the alpha
#: (the floor under the preview sphere): FPPM has no per-ray-type alpha, so
#: the preview leaves such an object out, as Cycles' camera does not see it.
CAMERA_HIDDEN_MATERIALS = frozenset({"FloorHidden"})


def preview_exporter(depsgraph, log):
    """``addon/export.py``'s exporter leaving out the objects whose every
    material is in :data:`CAMERA_HIDDEN_MATERIALS`."""
    from .export import _Exporter

    class PreviewExporter(_Exporter):
        def geometry(self, inst, ob, parts):
            mats = [sl.material for sl in getattr(ob, "material_slots", ())]
            if mats and all(m is not None and m.name in CAMERA_HIDDEN_MATERIALS for m in mats):
                return
            return super().geometry(inst, ob, parts)
    return PreviewExporter(depsgraph, log)


def _world_image(depsgraph, log) -> Optional[np.ndarray]:
    """(H, W, 4) float32 of the world colour at the render size (alpha 1), or
    None when the depsgraph has no usable camera."""
    try:
        from .export import _Exporter
        ex = _Exporter(depsgraph, log)
        cam = depsgraph.scene.camera
        cam = ex.camera(None if cam is None else cam.evaluated_get(depsgraph))
        c, _env = ex.world()      # an environment map is previewed by its constant part
    except Exception:  # noqa: BLE001 - see render_preview
        return None
    w, h = cam.resolution
    img = np.ones((h, w, 4), np.float32)
    img[..., :3] = np.asarray(c, np.float32)
    return img


def render_engine_preview(engine, depsgraph) -> PreviewOutcome:
    """``RenderEngine.render`` with ``is_preview``: :func:`render_preview`
    into the engine's result, stopped by ``test_break``; quiet in the
    console but for a preview it could not render."""
    out = render_preview(depsgraph, EngineSink(engine, depsgraph.view_layer.name),
                         should_stop=engine.test_break)
    if out.status == "unsupported":
        print(f"FPPM: preview not rendered: {out.message}")
    return out


def refresh_when_compiled() -> Optional[float]:
    """``bpy.app.timers`` callback: once the warm-up is done, ask Blender to
    render again the previews skipped meanwhile; polls every second until then."""
    if not warmup.done:
        return 1.0
    if _missed[0]:
        _missed[0] = False
        import bpy
        for coll in (bpy.data.materials, bpy.data.lights, bpy.data.worlds):
            for idb in coll:
                prv = idb.preview
                if prv is not None:
                    prv.reload()
    return None
