"""Every Properties panel a Cycles user sees is there under FPPM, has an FPPM
equivalent (addon/ui.py EQUIVALENTS), or is hidden because FPPM ignores what it
sets (addon/ui.py HIDDEN).  Background mode has no window, so panels are polled
with a context object carrying the members the Properties editor gives them
(object, light, material, world, ...) and drawn into a recording layout."""
import inspect

import pytest

bpy = pytest.importorskip("bpy")

import fppm.addon as addon  # noqa: E402
from fppm.addon import export, ui  # noqa: E402


class Ctx:
    """A Properties-editor context: the given members, then bpy.context's, else None."""

    def __init__(self, engine, **members):
        self.engine = engine
        self.__dict__.update(members)

    def __getattr__(self, name):
        return getattr(bpy.context, name, None)


@pytest.fixture(scope="module")
def scene():
    """A scene with a light, a camera, a mesh with a material, and a world."""
    addon.register()
    sc = bpy.data.scenes.new("panels")
    sc.world = bpy.data.worlds.new("panels world")
    mesh = bpy.data.meshes.new("panels mesh")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    mat = bpy.data.materials.new("panels material")
    mesh.materials.append(mat)
    obs = {"mesh": bpy.data.objects.new("panels mesh", mesh),
           "light": bpy.data.objects.new("panels light", bpy.data.lights.new("panels light", 'SPOT')),
           "camera": bpy.data.objects.new("panels camera", bpy.data.cameras.new("panels camera"))}
    for ob in obs.values():
        sc.collection.objects.link(ob)
    sc.camera = obs["camera"]
    yield sc, obs
    addon.unregister()


def contexts(engine, sc, obs):
    """One context per object, as the Properties editor builds them."""
    base = dict(scene=sc, world=sc.world, view_layer=sc.view_layers[0], space_data=None)
    m = obs["mesh"]
    yield Ctx(engine, object=m, active_object=m, mesh=m.data, material=m.active_material,
              material_slot=m.material_slots[0], **base)
    ob = obs["light"]
    yield Ctx(engine, object=ob, active_object=ob, light=ob.data, **base)
    ob = obs["camera"]
    yield Ctx(engine, object=ob, active_object=ob, camera=ob.data, **base)


def properties_panels():
    """Registered Properties-editor panels (not popovers), by name."""
    return {p.__name__: p for p in ui._panel_classes()
            if getattr(p, "bl_space_type", None) == 'PROPERTIES'
            and getattr(p, "bl_region_type", 'WINDOW') == 'WINDOW'}


def shown(panel, ctx) -> bool:
    try:
        return bool(panel.poll(ctx)) if hasattr(panel, "poll") else True
    except (AttributeError, TypeError, KeyError):
        return False   # a poll that needs a member this context lacks


needs_cycles = pytest.mark.skipif(not hasattr(bpy.types, "CYCLES_RENDER_PT_film"),
                                  reason="the Cycles add-on is not enabled")


@needs_cycles
def test_every_cycles_panel_is_covered(scene):
    sc, obs = scene
    panels = properties_panels()
    missing, checked = [], 0
    for name, p in sorted(panels.items()):
        compat = getattr(p, "COMPAT_ENGINES", None)
        cy_ctx = [i for i, c in enumerate(contexts("CYCLES", sc, obs)) if shown(p, c)]
        if not cy_ctx and not (compat and 'CYCLES' in compat):
            continue
        if ui.hidden_reason(name):
            continue
        checked += 1
        fp = list(contexts("FPPM", sc, obs))
        if name in ui.EQUIVALENTS:
            eq = panels[ui.EQUIVALENTS[name][0]]
            # Shown where Cycles' is; if the scene does not call for Cycles'
            # (the mist panel without a mist pass), FPPM's is at least FPPM's.
            ok = any(shown(eq, c) for c in fp) if cy_ctx else \
                'FPPM' in getattr(eq, "COMPAT_ENGINES", ())
        elif cy_ctx:
            ok = all(shown(p, fp[i]) for i in cy_ctx)
        else:
            # Needs data the test scene has not (a cloth, a particle system):
            # FPPM must at least be one of its engines.
            ok = 'FPPM' in compat
        if not ok:
            missing.append(name)
    assert not missing, "\n".join(missing)
    assert checked > 100   # the scan saw the tabs (about 190 panels in Blender 5.2)


@needs_cycles
def test_the_panels_of_the_issue_show(scene):
    # Light, material slots and surface, world surface, object visibility,
    # view layer, physics, particles, texture.
    sc, obs = scene
    panels = properties_panels()
    fp = list(contexts("FPPM", sc, obs))
    for name in ("FPPM_LIGHT_PT_light", "FPPM_LIGHT_PT_beam_shape", "FPPM_PT_context_material",
                 "FPPM_MATERIAL_PT_surface", "FPPM_WORLD_PT_surface",
                 "FPPM_OBJECT_PT_visibility", "FPPM_OBJECT_PT_visibility_ray_visibility",
                 "VIEWLAYER_PT_layer", "FPPM_VIEWLAYER_PT_passes", "PHYSICS_PT_add",
                 "PARTICLE_PT_context_particles", "TEXTURE_PT_context"):
        assert any(shown(panels[name], c) for c in fp), name
    for name, own in ui.REPLACED.items():
        assert own in panels, own
        if name in panels:
            assert not any(shown(panels[name], c) for c in fp), name
    for name in ui.HIDDEN:
        # Hidden: it, or a panel it is drawn inside, refuses FPPM.
        chain, n = [], name
        while n in panels:
            chain.append(panels[n])
            n = getattr(panels[n], "bl_parent_id", None)
        assert all(any(not shown(q, c) for q in chain) for c in fp), name


@needs_cycles
def test_mappings_name_real_panels():
    panels = properties_panels()
    for name, (eq, why) in ui.EQUIVALENTS.items():
        assert name in panels, name
        assert eq in panels, eq
        assert why
    for name, why in ui.HIDDEN.items():
        assert name in panels, name
        assert why


class Layout:
    """Records the properties and node views drawn; a UILayout stand-in."""

    def __init__(self):
        self.props = []
        self.node_views = []
        self.previews = []
        self.use_property_split = False
        self.use_property_decorate = True
        self.active = True

    def prop(self, data, name, **kw):
        assert name in data.bl_rna.properties, name
        self.props.append(name)

    def template_node_view(self, ntree, node, socket):
        self.node_views.append((ntree, node.type, socket.name))

    def template_preview(self, id_data, **kw):
        self.previews.append(id_data)

    def operator(self, *a, **kw):
        return type("Op", (), {})()

    def column(self, **kw):
        return self

    row = split = column

    def label(self, *a, **kw):
        pass

    template_list = template_ID = menu = separator = label


def draw(panel, ctx) -> Layout:
    lay = Layout()
    panel.draw(type("P", (), {"layout": lay, "bl_space_type": 'PROPERTIES'})(), ctx)
    return lay


# Properties drawn that only change the viewport or the editor, not the render.
UI_ONLY = {"show_cone", "hide_select", "hide_surface_pick", "hide_viewport", "link"}


@pytest.mark.parametrize("kind, expect, absent", [
    ('POINT', {"energy", "color", "shadow_soft_size", "use_soft_falloff", "use_shadow"},
     {"normalize", "angle", "size"}),
    ('SPOT', {"energy", "shadow_soft_size", "spot_size", "spot_blend"}, {"normalize"}),
    ('SUN', {"energy", "angle"}, {"shadow_soft_size", "normalize"}),
    ('AREA', {"energy", "shape", "size", "normalize", "spread"}, {"shadow_soft_size"}),
])
def test_light_panels_draw_what_the_exporter_reads(scene, kind, expect, absent):
    sc, obs = scene
    ob = obs["light"]
    ob.data.type = kind
    ctx = list(contexts("FPPM", sc, obs))[1]
    drawn = set(draw(ui.FPPM_LIGHT_PT_light, ctx).props)
    if ui.FPPM_LIGHT_PT_beam_shape.poll(ctx):
        drawn |= set(draw(ui.FPPM_LIGHT_PT_beam_shape, ctx).props)
    drawn |= set(draw(ui.FPPM_OBJECT_PT_visibility_ray_visibility, ctx).props)
    assert expect <= drawn, expect - drawn
    assert not (absent & drawn), absent & drawn
    # Hide what FPPM ignores: every render setting drawn is read by the exporter.
    src = inspect.getsource(export)
    for name in drawn - UI_ONLY - {"type"}:
        assert f'"{name}"' in src or f".{name}" in src, name


def test_material_and_world_surface_draw_the_node_tree(scene):
    sc, obs = scene
    ctx = list(contexts("FPPM", sc, obs))[0]
    lay = draw(ui.FPPM_MATERIAL_PT_surface, ctx)
    assert [v[1:] for v in lay.node_views] == [('OUTPUT_MATERIAL', "Surface")]
    lay = draw(ui.FPPM_WORLD_PT_surface, ctx)
    assert [v[1:] for v in lay.node_views] == [('OUTPUT_WORLD', "Surface")]
    assert draw(ui.FPPM_MATERIAL_PT_settings, ctx).props == ["pass_index",
                                                            "displacement_method"]
    lay = draw(ui.FPPM_MATERIAL_PT_displacement, ctx)
    assert [v[1:] for v in lay.node_views] == [('OUTPUT_MATERIAL', "Displacement")]
    draw(ui.FPPM_PT_context_material, ctx)   # slots: runs against the real object


@pytest.mark.parametrize("kind", ['POINT', 'SPOT', 'SUN', 'AREA'])
def test_every_fppm_panel_draws_where_it_shows(scene, kind):
    sc, obs = scene
    obs["light"].data.type = kind
    sc.view_layers[0].use_pass_mist = True      # the mist panel shows with a mist pass
    try:
        n = 0
        for ctx in contexts("FPPM", sc, obs):
            for cls in ui.classes:
                if cls.bl_context != "render" and cls.poll(ctx):
                    draw(cls, ctx)
                    n += 1
        # mesh: slots, surface, settings, world x2, visibility, view layer passes;
        # light: + light (+ beam shape), ray visibility; camera: the shared ones.
        assert n >= 17
    finally:
        sc.view_layers[0].use_pass_mist = False
