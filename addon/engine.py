"""The FPPM render engine: export the evaluated scene, run core's Renderer, stream passes.

Thin on purpose: everything that renders lives in ``core``.  This module turns
Blender's render callbacks into ``Renderer.run`` and copies each completed pass
into the render result (rows bottom-to-top, Blender's order), at most
:data:`UPDATE_INTERVAL` apart so very short passes do not flood the UI.

The command-line tool (``addon/cli.py``) renders through this same engine with
``bpy.ops.render.render`` (so it gets Blender's render-mode depsgraph:
``hide_render``, render subdivision levels, ...) and follows the render
through a :class:`RenderSession`.
"""
from __future__ import annotations

import contextlib
import time
import traceback

import bpy
import numpy as np

from ..core.errors import FPPMError, RenderCancelled
from ..core.settings import SettingsError
from ..core.sppm import cryptomatte
from ..core.sppm.shadow_catcher import PASS as CATCHER_PASS
from ..core.sppm.film import PASSES, pass_enabled
from ..core.warmup import expected_seconds, is_compiled, render_job, warmup
from .export import export_scene
from .properties import settings_from_scene

# (flag that enables it, pass name, channels, chan_id, Blender pass type): the
# table of core.sppm.film.PASSES, FPPM's AOVs and Blender's standard passes.
AOV_PASSES = tuple((p.flag, p.name, p.channels, p.chan_id, p.kind) for p in PASSES)
# Light passes Film > Exposure scales too (Cycles: light passes, not data ones).
EXPOSED_PASSES = frozenset({"Emission"})
UPDATE_INTERVAL = 0.25  # s between image-editor updates (at most ~4 per second)


def enabled_aovs(settings, view_layer=None) -> list[tuple[str, int, str, str]]:
    """(name, channels, chan_id, type) of the passes the settings and the
    view layer (Passes panel: Z, Mist, Normal, ..., Shader AOV, Cryptomatte)
    ask for; a shader AOV as Cycles registers it (a Color AOV RGBA, a
    Value AOV one channel; one whose name conflicts with another pass is
    not ``is_valid``, and left out as Cycles leaves it out)."""
    return [(p.name, p.channels, p.chan_id, p.kind) for p in PASSES
            if pass_enabled(p, settings, view_layer)] + [
        (a.name, 4, "RGBA", 'COLOR') if a.type == 'COLOR' else (a.name, 1, "X", 'VALUE')
        for a in getattr(view_layer, "aovs", ()) if a.is_valid] + [
        (name, 4, "RGBA", 'COLOR') for name in cryptomatte.pass_names(view_layer)] + (
        [(CATCHER_PASS, 3, "RGB", 'COLOR')]
        if getattr(getattr(view_layer, "cycles", None), "use_pass_shadow_catcher", False) else [])


def film_gain(scene) -> float:
    """Cycles' Film > Exposure: a linear scale of the image (1 = unchanged)."""
    cy = getattr(scene, "cycles", None)
    return float(getattr(cy, "film_exposure", 1.0)) if cy is not None else 1.0


def exposed(image: np.ndarray, gain: float) -> np.ndarray:
    """(H, W, 4) RGBA with the film exposure applied: colour scaled, alpha kept."""
    if gain == 1.0:
        return image
    img = image * np.float32(gain)
    img[..., 3] = image[..., 3]
    return img


def blender_rows(img: np.ndarray, channels: int) -> np.ndarray:
    """(H, W, C) row-0-at-top image -> flat float32 for ``rect.foreach_set``.

    Blender's render passes store rows bottom to top; the channel count is
    padded with zeros or cut to the pass's ``channels``.
    """
    img = np.asarray(img, np.float32)
    if img.ndim == 2:
        img = img[:, :, None]
    h, w, c = img.shape
    if c != channels:
        out = np.zeros((h, w, channels), np.float32)
        n = min(c, channels)
        out[:, :, :n] = img[:, :, :n]
        img = out
    return np.ascontiguousarray(img[::-1]).reshape(-1)


def format_elapsed(seconds: float) -> str:
    s = int(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def progress_fraction(result, settings) -> float:
    """Fraction of the pass or time budget used (the larger of the two)."""
    f = 0.0
    if settings.max_passes > 0:
        f = max(f, result.pass_index / settings.max_passes)
    if settings.time_limit > 0:
        f = max(f, result.elapsed / settings.time_limit)
    return min(f, 1.0)


def report_warning(engine, msg: str) -> None:
    """One WARNING in Blender's reports (the Info log; printed as "Warning:
    ..." in background mode).  Module-level so that tests can count calls."""
    engine.report({'WARNING'}, msg)


def export_cancellable(depsgraph, log, camera, should_stop):
    """``export_scene`` polling ``should_stop`` between objects, textures and bands
    of the large copies (docs/reliability.md, "Cancel"); RenderCancelled goes
    to ``render``."""
    return export_scene(depsgraph, log, camera=camera, should_stop=should_stop)


class RenderSession:
    """Lets the CLI (or a test) follow a render done by :class:`FPPMRenderEngine`.

    on_pass(result, settings): after every completed pass.
    log(line): export summary, plan and warnings (instead of printing them).
    should_stop(): polled with ``test_break``; True cancels the render.
    on_renderer(renderer): once the Renderer is built, before the first pass
    (the CLI loads a checkpoint there); also kept as ``renderer``.
    After the render: ``result`` (last complete PassResult or None),
    ``error`` (the FPPMError / SettingsError that stopped it, or None),
    ``cancelled``, ``settings``, ``gain`` (film exposure applied to Combined).
    """

    def __init__(self, on_pass=None, log=None, should_stop=None, on_renderer=None):
        self.on_pass = on_pass
        self.log = log
        self.should_stop = should_stop
        self.on_renderer = on_renderer
        self.renderer = None
        self.result = None
        self.error = None
        self.cancelled = False
        self.settings = None
        self.gain = 1.0


_session: RenderSession | None = None


@contextlib.contextmanager
def session(s: RenderSession):
    """Route the engine's next renders to ``s`` (used by the CLI around render.render)."""
    global _session
    prev, _session = _session, s
    try:
        yield s
    finally:
        _session = prev


class FPPMRenderEngine(bpy.types.RenderEngine):
    bl_idname = "FPPM"
    bl_label = "FPPM"
    # Material/light/world previews of the Properties editor: addon/preview.py.
    bl_use_preview = True
    bl_use_postprocess = True
    # Material preview shading uses EEVEE; Rendered shading is FPPM's
    # progressive viewport (view_update / view_draw below, addon/viewport.py).
    bl_use_eevee_viewport = True

    def update_render_passes(self, scene=None, renderlayer=None):
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", 'COLOR')
        for name, ch, cid, kind in enabled_aovs(settings_from_scene(scene), renderlayer):
            self.register_pass(scene, renderlayer, name, ch, cid, kind)

    # -- rendered viewport: thin; the session logic is addon/viewport.py ------
    def _viewport(self):
        ctl = getattr(self, "_fppm_viewport", None)
        if ctl is None:
            from .viewport import ViewportController
            ctl = self._fppm_viewport = ViewportController()
            self._fppm_texture = None
        return ctl

    @staticmethod
    def _view_state(context):
        from .viewport import ViewState
        rv3d, region = context.region_data, context.region
        return ViewState.of(rv3d.view_matrix, rv3d.window_matrix, (region.width, region.height))

    def view_update(self, context, depsgraph):
        """A depsgraph change (edit, material, light, settings): re-export, maybe restart."""
        from .properties import viewport_settings_from_scene
        scene = depsgraph.scene
        self._viewport().update(depsgraph, self._view_state(context), settings_from_scene(scene),
                                viewport_settings_from_scene(scene))

    def view_draw(self, context, depsgraph):
        """Draw the session's latest image; a moved view restarts the session."""
        from . import world_bake
        if world_bake.collect():
            # The world's background bake has ended: export again (it is
            # cached now, or its failure is said).
            self.view_update(context, depsgraph)
        ctl = self._viewport()
        frame = ctl.draw(self._view_state(context))
        self.update_stats("", ctl.session.status)
        if frame is not None:
            self._draw_frame(frame, depsgraph.scene)
        if ctl.session.busy or world_bake.baking():
            self.tag_redraw()       # keep drawing while passes arrive or the world bakes

    def _draw_frame(self, frame, scene) -> None:
        import gpu
        from gpu_extras.presets import draw_texture_2d
        h, w = frame.image.shape[:2]
        cached = self._fppm_texture
        if cached is None or cached[0] != frame.serial:
            img = exposed(frame.image, film_gain(scene))
            buf = gpu.types.Buffer('FLOAT', w * h * 4, blender_rows(img, 4))
            self._fppm_texture = cached = (frame.serial, gpu.types.GPUTexture(
                (w, h), format='RGBA32F', data=buf))
        gpu.state.blend_set('ALPHA_PREMULT')
        self.bind_display_space_shader(scene)
        draw_texture_2d(cached[1], (0, 0), w, h)
        self.unbind_display_space_shader()
        gpu.state.blend_set('NONE')

    def __del__(self):
        # The viewport closed (or shading left Rendered): stop its passes.
        try:
            ctl = getattr(self, "_fppm_viewport", None)
        except ReferenceError:      # the RNA struct is already gone
            return
        if ctl is not None:
            ctl.free()

    # -- helpers -----------------------------------------------------------
    def break_requested(self) -> bool:
        """Esc in Blender (``test_break``) or the CLI's Ctrl-C: polled inside passes."""
        if self.test_break():
            return True
        sess = _session
        return bool(sess is not None and sess.should_stop is not None and sess.should_stop())

    def _log(self, msg: str) -> None:
        sess = _session
        if sess is not None and sess.log is not None:
            # The CLI prints it (fppm converge's warm-up mutes it): no second
            # copy via report, which Blender prints too in background mode.
            sess.log(msg)
            return
        if msg.startswith(("Plan:", "Left out:")):
            # Blender's info log shows what this scene's render leaves out:
            # the plan's lines at the start, the holds after pass 1
            # (core.render Renderer._drop_holds); ``blender -b`` prints it
            # once, as "Info: ...".
            self.report({'INFO'}, msg)
            return
        print(f"FPPM: {msg}")
        if msg.lower().startswith("warning"):
            self.report({'WARNING'}, msg)

    def _write(self, rresult, pr, aovs, gain) -> None:
        layer = rresult.layers[0]
        img = exposed(pr.image, gain)
        # Multi-view (stereo 3D): every view gets the scene camera's image
        # (the exporter notes it); otherwise the right eye would stay black.
        views = [v.name for v in rresult.views] or [""]
        for view in views:
            p = layer.passes.find_by_name("Combined", view) if view else layer.passes["Combined"]
            if p is not None:
                p.rect.foreach_set(blender_rows(img, 4))
        for name, ch, _cid, _kind in aovs:
            a = pr.aovs.get(name)
            if a is not None and name in EXPOSED_PASSES and gain != 1.0:
                a = a * np.float32(gain)
            for view in views:
                p = layer.passes.find_by_name(name, view) if view else layer.passes.get(name)
                if a is not None and p is not None:
                    p.rect.foreach_set(blender_rows(a, ch))

    def _wait_for_kernels(self, job) -> bool:
        """Wait until the kernels of this render's own job (``core.warmup.
        render_job``) are compiled and loaded, before the Renderer exists, so
        that compiling never counts against the time limit; False when Esc was
        pressed meanwhile.  In Blender's UI the warm-up then goes on with
        every other variant in the background; a one-shot render (the CLI,
        ``blender -b``) does not wait for them.  A failed warm-up is reported
        and the render goes on (the kernels then compile inside the first pass)."""
        if not warmup.ready(job):
            first = not is_compiled(job)
            expected = expected_seconds(job) if first else 0.0
            msg = (f"FPPM: compiling render kernels (first use, about {expected:.0f} s)"
                   if first else "FPPM: loading render kernels")
            self.update_stats("", msg)
            if first:
                self._log(msg[len("FPPM: "):])

            def on_wait(waited):
                if expected > 0:
                    self.update_progress(min(waited / expected, 0.99))
            if not warmup.wait_for(job, should_stop=self.break_requested, on_wait=on_wait,
                                   rest=not bpy.app.background):
                return False
            self.update_progress(0.0)
        error = warmup.job_error(job)
        if error is not None:
            self._log(f"Warning: compiling the kernels ahead of the render failed "
                      f"({error}); rendering anyway")
        return True

    # -- the render callback -------------------------------------------------
    def render(self, depsgraph):
        if self.is_preview:
            from .preview import render_engine_preview
            render_engine_preview(self, depsgraph)
            return
        sess = _session
        scene = depsgraph.scene
        try:
            self._render(depsgraph, scene, sess)
        except RenderCancelled:
            # Esc / Ctrl-C during the set-up (before any pass): nothing to show.
            if sess is not None:
                sess.cancelled = True
        except (FPPMError, SettingsError) as ex:
            # A sentence for the user, no traceback.
            if sess is not None:
                sess.error = ex
            self.report({'ERROR'}, str(ex))
        except Exception as ex:  # a bug: keep the traceback in the console
            traceback.print_exc()
            if sess is not None:
                sess.error = ex
            self.report({'ERROR'}, f"FPPM internal error: {type(ex).__name__}: {ex}")

    def _render(self, depsgraph, scene, sess) -> None:
        # for_frame: Animated Seed mixes the frame into the seed here, once.
        settings = settings_from_scene(scene).for_frame(scene.frame_current).validate()
        gain = film_gain(scene)
        if sess is not None:
            sess.settings, sess.gain = settings, gain
        if not bpy.app.background:
            warmup.start()  # every variant, in the background (after this render's own kernels)
        self.update_stats("", "FPPM: exporting scene")
        cam = self.camera_override
        if cam is not None:
            cam = cam.evaluated_get(depsgraph)
        fscene = export_cancellable(depsgraph, self._log, cam, self.break_requested)
        if sess is None or sess.log is None:
            # Blender's Info log: one warning per approximation, once per
            # render (the CLI prints them in the exporter's "Approximated:" line).
            for msg in getattr(fscene, "approximations", ()):
                report_warning(self, msg)
        aovs = enabled_aovs(settings, depsgraph.view_layer)
        job = render_job(fscene, settings, tuple(a[0] for a in aovs))
        if self.break_requested() or not self._wait_for_kernels(job):
            if sess is not None:
                sess.cancelled = True
            return
        # should_stop is also polled while the renderer is set up (BVH,
        # occlusion grid): RenderCancelled from there is caught in render().
        # Imported here, not at the top: core.render loads numba and Embree,
        # which enabling the add-on must not pay for (docs/interactive.md).
        from ..core.render import Renderer
        renderer = Renderer(fscene, settings, log=self._log, should_stop=self.break_requested,
                            passes=tuple(a[0] for a in aovs))
        if sess is not None:
            sess.renderer = renderer
            if sess.on_renderer is not None:
                sess.on_renderer(renderer)
        for line in renderer.plan_lines():
            self._log(line)
        self.update_stats("", renderer.plan.lines()[0])

        # The AOV passes come from update_render_passes (register_pass), which
        # Blender calls when the render starts; add_pass is not needed.
        # The region Blender expects: the border crop when a border is set.
        w, h = int(renderer.width), int(renderer.height)
        rresult = self.begin_result(0, 0, w, h, layer=depsgraph.view_layer.name)
        # The Cryptomatte manifests, on the render's whole result as Cycles
        # stores them (a tile's stamp data is not merged into it).  Blender
        # writes them into a multilayer EXR's header, whose passes are named
        # "<view layer>.CryptoObject00".
        for k, v in cryptomatte.scene_metadata(fscene, [a[0] for a in aovs],
                                               depsgraph.view_layer.name + ".").items():
            self.get_result().stamp_data_add_field(k, v)
        last_update = [0.0]
        shown = [None]

        should_stop = self.break_requested

        def on_pass(pr):
            now = time.monotonic()
            self.update_progress(progress_fraction(pr, settings))
            self.update_stats("", pr.stats_line())
            if sess is not None:
                sess.result = pr
                if sess.on_pass is not None:
                    sess.on_pass(pr, settings)
            if now - last_update[0] >= UPDATE_INTERVAL:
                self._write(rresult, pr, aovs, gain)
                self.update_result(rresult)
                shown[0] = pr
                last_update[0] = time.monotonic()

        self.update_stats("", "FPPM: rendering")
        try:
            final = renderer.run(should_stop=should_stop, on_pass=on_pass)
        except BaseException:
            # Keep what the user already saw rather than a blank image.
            self.end_result(rresult, cancel=shown[0] is None)
            raise
        cancelled = should_stop()
        if sess is not None:
            sess.result = final
            sess.cancelled = cancelled
        if final is not None:
            if final is not shown[0]:
                self._write(rresult, final, aovs, gain)
            self.update_progress(1.0 if not cancelled else progress_fraction(final, settings))
            self.update_stats("", final.stats_line() + (" | cancelled" if cancelled else ""))
        self.end_result(rresult)
