"""Blender-facing side of FPPM: settings, panels, the render engine, export, CLI.

Everything here is thin: the rendering itself is ``core``.  ``register()``
adds, and ``unregister()`` removes, exactly:
- the classes of :data:`classes` (PropertyGroup, RenderEngine, panels);
- ``bpy.types.Scene.fppm``;
- "FPPM" in ``COMPAT_ENGINES`` of the standard panels of ``ui.STANDARD_PANELS``.
"""
import bpy

from . import engine, properties, ui

classes = (
    properties.FPPMRenderSettings,
    engine.FPPMRenderEngine,
    *ui.classes,
)

_registered = False


def register():
    global _registered
    if _registered:
        return
    for cls in classes:
        bpy.utils.register_class(cls)
    properties.register_properties()
    ui.add_to_standard_panels()
    _registered = True


def unregister():
    global _registered
    if not _registered:
        return
    ui.remove_from_standard_panels()
    properties.unregister_properties()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    _registered = False


def is_registered() -> bool:
    return _registered
