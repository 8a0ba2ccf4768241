"""register()/unregister(): everything added is removed, COMPAT_ENGINES restored exactly."""
import pytest

bpy = pytest.importorskip("bpy")

import fppm.addon as addon  # noqa: E402
from fppm.addon import ui  # noqa: E402


def _panels():
    out = {}
    for name in dir(bpy.types):
        cls = getattr(bpy.types, name, None)
        try:
            if isinstance(cls, type) and issubclass(cls, bpy.types.Panel) \
                    and hasattr(cls, "COMPAT_ENGINES"):
                out[name] = cls
        except TypeError:
            pass
    return out


def _snapshot():
    # (own attribute object or None, contents) per panel: identity matters,
    # because many panels share one set through a mix-in class.
    return {n: (c.__dict__.get("COMPAT_ENGINES"), frozenset(c.COMPAT_ENGINES))
            for n, c in _panels().items()}


@pytest.fixture
def unregistered():
    addon.unregister()
    yield
    addon.unregister()


def test_round_trip_restores_everything(unregistered):
    before = _snapshot()
    assert not hasattr(bpy.types.Scene, "fppm")
    addon.register()
    try:
        assert hasattr(bpy.types.Scene, "fppm")
        bpy.context.scene.render.engine = "FPPM"   # TypeError if not an engine
        bpy.context.scene.render.engine = "CYCLES"
        for cls in ui.classes:
            assert getattr(bpy.types, cls.__name__, None) is cls
        with_fppm = {n for n, c in _panels().items() if "FPPM" in c.COMPAT_ENGINES}
        # The roles of the issue: dimensions, output, colour management, film,
        # camera, light, world, material surface.
        for must in ("RENDER_PT_format", "RENDER_PT_output", "RENDER_PT_color_management",
                     "DATA_PT_lens", "DATA_PT_camera_dof", "DATA_PT_context_light",
                     "WORLD_PT_context_world"):
            assert must in with_fppm, must
        has_cycles = hasattr(bpy.types, "CYCLES_RENDER_PT_film")
        if has_cycles:
            assert "CYCLES_RENDER_PT_film" in with_fppm
            # Cycles' light/world/material panels poll CyclesButtonsPanel.poll,
            # which refuses FPPM whatever their COMPAT_ENGINES: FPPM draws its own
            # (tests/test_panels.py checks they show).
            for must_not in ("CYCLES_LIGHT_PT_light", "CYCLES_WORLD_PT_surface",
                             "CYCLES_MATERIAL_PT_surface"):
                assert must_not not in with_fppm, must_not
            # Cycles' own settings must NOT show for FPPM (they share one set).
            for must_not in ("CYCLES_RENDER_PT_sampling", "CYCLES_RENDER_PT_light_paths",
                             "CYCLES_RENDER_PT_performance"):
                assert must_not not in with_fppm, must_not
        for must_not in ("RENDER_PT_eevee_sampling", "RENDER_PT_opengl_lighting"):
            assert must_not not in with_fppm
    finally:
        addon.unregister()
    after = _snapshot()
    assert not hasattr(bpy.types.Scene, "fppm")
    with pytest.raises(TypeError):
        bpy.context.scene.render.engine = "FPPM"
    for cls in ui.classes:
        assert getattr(bpy.types, cls.__name__, None) is None
    assert after.keys() == before.keys()
    for n in before:
        assert after[n][1] == before[n][1], n
        assert after[n][0] is before[n][0], n


def test_register_twice_is_harmless(unregistered):
    addon.register()
    addon.register()
    addon.unregister()
    assert not hasattr(bpy.types.Scene, "fppm")
    assert not any("FPPM" in c.COMPAT_ENGINES for c in _panels().values())


def test_panels_draw_for_fppm(unregistered):
    # Each FPPM panel shows for the FPPM engine only (background mode has no
    # window to draw into, so poll is what can be checked here).
    addon.register()
    sc = bpy.context.scene
    sc.render.engine = "FPPM"

    class Ctx:
        engine = "FPPM"
        scene = sc
    for cls in _settings_panels():
        assert cls.poll(Ctx)
        assert cls.__name__.startswith(("FPPM_RENDER_PT_", "FPPM_VIEWLAYER_PT_"))

    class Other:
        engine = "CYCLES"
    assert not any(cls.poll(Other) for cls in ui.classes)


def _settings_panels():
    """FPPM's panels of its own settings (scene.fppm): the render and view layer tabs."""
    return [c for c in ui.classes if c.bl_context in ("render", "view_layer")]


class _Layout:
    """Records every prop() drawn; stands in for a UILayout in background mode."""

    def __init__(self, drawn):
        self.drawn = drawn
        self.use_property_split = False
        self.use_property_decorate = True
        self.active = True

    def prop(self, data, name, **kw):
        assert name in data.bl_rna.properties, name
        self.drawn.add(name)

    def column(self, **kw):
        return self

    row = column


def test_panels_draw_every_setting(unregistered):
    from fppm.core.settings import field_names, viewport_field_names
    addon.register()
    sc = bpy.context.scene
    drawn = set()
    # Each conditional row shows under one of these states.
    for mode, integrator in (("AUTO", "PHOTON"), ("WORLD", "PATH"), ("AUTO", "COMBINED")):
        sc.fppm.radius_mode = mode
        sc.fppm.integrator = integrator
        for cls in _settings_panels():
            lay = _Layout(drawn)

            class Ctx:
                scene = sc
            cls.draw(type("P", (), {"layout": lay})(), Ctx)
            if hasattr(cls, "draw_header"):
                cls.draw_header(type("P", (), {"layout": lay})(), Ctx)
    assert drawn == set(field_names()) | set(viewport_field_names())


def test_enable_imports_no_kernels():
    # Enabling the add-on must stay cheap: numba, Embree and the compiled
    # kernels load at the first render (or the background warm-up), never at
    # register().  A fresh interpreter, as at a Blender start.
    import subprocess
    import sys
    code = ("import sys, bpy, fppm\nfppm.register()\n"
            "bad = [m for m in ('numba', 'embreex', 'llvmlite', 'fppm.core.render') if m in sys.modules]\n"
            "print(bad)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().splitlines()[-1] == "[]"
