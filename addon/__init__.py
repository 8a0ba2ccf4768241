"""Blender-facing side of FPPM: settings, panels, the render engine, export, CLI.

Everything here is thin: the rendering itself is ``core``.  ``register()``
adds, and ``unregister()`` removes, exactly:
- the classes of :data:`classes` (PropertyGroup, RenderEngine, panels);
- ``bpy.types.Scene.fppm``;
- "FPPM" in ``COMPAT_ENGINES`` of the standard panels of ``ui.STANDARD_PANELS``
  and of Blender's engine-independent panels (``ui.ANY_ENGINE``, less ``ui.HIDDEN``);
- a one-shot timer that starts the background kernel warm-up (``core.warmup``).
It also points core's kernel cache at the extension's user folder (kept by
updates and reinstalls).  Nothing here imports numba, Embree or the kernels:
enabling stays cheap (docs/interactive.md).
"""
import bpy

from . import engine, properties, ui

classes = (
    properties.FPPMRenderSettings,
    engine.FPPMRenderEngine,
    *ui.classes,
)

_registered = False


def extension_cache_dir() -> str | None:
    """``<extension user folder>/cache``, or None when not installed as an extension
    (tests, the CLI: core then uses the user cache folder)."""
    package = (__package__ or "").rpartition(".")[0]
    try:
        path = bpy.utils.extension_path_user(package, path="cache", create=True)
    except (ValueError, AttributeError):
        return None
    return path or None


WARMUP_DELAY = 1.0  # s after enable (or Blender's start) before the background compile


def start_warmup():
    """Start compiling the render kernels in a background thread (core.warmup)."""
    from ..core.warmup import warmup
    warmup.start()
    return None         # a one-shot timer


def refresh_previews():
    """Timer: once the kernels are compiled, re-render the material, light and
    world previews skipped meanwhile (addon/preview.py); polls every second."""
    from .preview import refresh_when_compiled
    return refresh_when_compiled()


def register():
    global _registered
    if _registered:
        return
    from .. import core
    core.set_cache_dir(extension_cache_dir())
    for cls in classes:
        bpy.utils.register_class(cls)
    properties.register_properties()
    ui.add_to_standard_panels()
    # The kernels compile in the background once Blender's UI runs (a timer
    # fires from the event loop, not during start-up; bpy as a module never
    # runs timers: the CLI's first render does the warm-up).
    bpy.app.timers.register(start_warmup, first_interval=WARMUP_DELAY, persistent=True)
    bpy.app.timers.register(refresh_previews, first_interval=WARMUP_DELAY + 1.0, persistent=True)
    _registered = True


def unregister():
    global _registered
    if not _registered:
        return
    for timer in (start_warmup, refresh_previews):
        if bpy.app.timers.is_registered(timer):
            bpy.app.timers.unregister(timer)
    from ..core.warmup import warmup
    warmup.stop()
    from .viewport import cancel_all
    cancel_all()
    ui.remove_from_standard_panels()
    properties.unregister_properties()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    _registered = False


def is_registered() -> bool:
    return _registered
