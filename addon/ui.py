"""Render-properties panels for FPPM, and FPPM's place in Blender's standard panels."""
import bpy
from bpy.types import Panel
from bl_ui.properties_view_layer import ViewLayerAOVPanelHelper, ViewLayerCryptomattePanelHelper
from .export import GEOMETRY_TYPES

ENGINE = "FPPM"


def split(layout):
    """``layout`` with labels beside the values (Blender's property split)."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout


class FPPMPanel:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def split_layout(self):
        """The panel's layout with labels beside the values (Blender's property split)."""
        layout = split(self.layout)
        return layout


class FPPM_RENDER_PT_sampling(FPPMPanel, Panel):
    bl_label = "Sampling"

    def draw(self, context):
        layout = split(self.layout)
        s = context.scene.fppm
        col = layout.column(align=True)
        col.prop(s, "max_passes")
        col.prop(s, "time_limit")
        col = layout.column()
        col.prop(s, "integrator")
        if s.integrator in ('PATH', 'COMBINED'):
            col.prop(s, "camera_samples")
            if s.integrator == 'COMBINED':
                col.prop(s, "light_paths_per_camera_path")
                col.prop(s, "camera_depth")
                col.prop(s, "merge_weights")
        else:
            col.prop(s, "photons_per_pass")
        row = col.row(align=True)
        row.prop(s, "seed")
        row.prop(s, "use_animated_seed", text="", icon='TIME')


class FPPM_RENDER_PT_viewport(FPPMPanel, Panel):
    bl_label = "Viewport"
    bl_parent_id = "FPPM_RENDER_PT_sampling"

    def draw(self, context):
        layout = split(self.layout)
        s = context.scene.fppm
        col = layout.column(align=True)
        col.prop(s, "viewport_max_passes", text="Max Passes")
        col.prop(s, "viewport_resolution_divider")


class FPPM_RENDER_PT_kernel(FPPMPanel, Panel):
    bl_label = "Kernel"

    def draw(self, context):
        layout = split(self.layout)
        s = context.scene.fppm
        col = layout.column()
        col.prop(s, "radius_mode")
        if s.radius_mode == 'AUTO':
            col.prop(s, "initial_radius_px")
        else:
            col.prop(s, "initial_radius")
        col.prop(s, "cap_radius_at_edges")
        col.prop(s, "clip_kernel")
        col.prop(s, "alpha")
        row = col.row()
        row.active = not s.use_frequency  # APPM / CPPM are the baselines without it
        row.prop(s, "radius_rule")


class FPPM_RENDER_PT_light_paths(FPPMPanel, Panel):
    bl_label = "Light Paths"

    def draw(self, context):
        layout = split(self.layout)
        s = context.scene.fppm
        col = layout.column()
        col.prop(s, "max_bounces")
        col.prop(s, "rr_start")
        col.prop(s, "glossy_chains")
        col.prop(s, "light_samples")
        col = layout.column(heading="Classic PPM")
        col.prop(s, "photons_for_direct")
        col.prop(s, "fixed_visible_points")


class FPPM_RENDER_PT_frequency(FPPMPanel, Panel):
    bl_label = "Frequency"

    def draw_header(self, context):
        self.layout.prop(context.scene.fppm, "use_frequency", text="")

    def draw(self, context):
        layout = split(self.layout)
        s = context.scene.fppm
        col = layout.column()
        col.active = s.use_frequency
        col.prop(s, "frequency_fraction", slider=True)
        col.prop(s, "frequency_decay")
        col.prop(s, "frequency_start")
        col.prop(s, "frequency_model")
        col.prop(s, "frequency_estimator")
        col.prop(s, "hold_alpha", slider=True)
        col.prop(s, "verify_holds")
        col.prop(s, "occlusion_grid_res")


class FPPM_RENDER_PT_output(FPPMPanel, Panel):
    bl_label = "Passes"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = split(self.layout)
        s = context.scene.fppm
        col = layout.column(heading="Include")
        col.prop(s, "aov_radius")
        col.prop(s, "aov_predicted_radius")
        col.prop(s, "aov_spectrum")
        col.prop(s, "aov_photon_count")
        col.prop(s, "aov_held")
        draw_view_layer_passes(layout, getattr(context, "view_layer", None))


def draw_view_layer_passes(layout, view_layer):
    """The active view layer's flags of Blender's standard passes FPPM writes
    (core.sppm.film.PASSES: Depth, Mist, Normal, ..., denoising data)."""
    if view_layer is None:
        return
    from ..core.sppm.film import PASSES
    col = layout.column(heading="View Layer")
    seen = set()
    for p in PASSES:
        if not p.flag.startswith("view_layer.") or p.flag in seen:
            continue
        seen.add(p.flag)
        owner = view_layer
        *path, prop = p.flag.split(".")[1:]
        for part in path:
            owner = getattr(owner, part, None)
        if owner is not None and hasattr(owner, prop):
            col.prop(owner, prop, text="Denoising Data" if prop == "denoising_store_passes"
                     else p.name)
    # Shadow catchers' pass (core.sppm.shadow_catcher), Cycles' flag.
    cy = getattr(view_layer, "cycles", None)
    if cy is not None and hasattr(cy, "use_pass_shadow_catcher"):
        col.prop(cy, "use_pass_shadow_catcher", text="Shadow Catcher")


class FPPM_VIEWLAYER_PT_passes(FPPMPanel, Panel):
    """The same rows as the render tab's Passes, where a Cycles user looks for them."""
    bl_label = "Passes"
    bl_context = "view_layer"
    draw = FPPM_RENDER_PT_output.draw


class FPPM_VIEWLAYER_PT_passes_aov(FPPMPanel, ViewLayerAOVPanelHelper, Panel):
    """Shader AOVs (core.sppm.shader_aovs): Blender's list, as Cycles shows it."""
    bl_context = "view_layer"
    bl_parent_id = "FPPM_VIEWLAYER_PT_passes"

    def draw(self, context):
        if getattr(context, "view_layer", None) is not None:
            ViewLayerAOVPanelHelper.draw(self, context)


class FPPM_VIEWLAYER_PT_passes_crypto(FPPMPanel, ViewLayerCryptomattePanelHelper, Panel):
    """Cryptomatte (core.sppm.cryptomatte): the kinds and their levels, as
    Cycles shows them."""
    bl_context = "view_layer"
    bl_parent_id = "FPPM_VIEWLAYER_PT_passes"

    def draw(self, context):
        if getattr(context, "view_layer", None) is not None:
            ViewLayerCryptomattePanelHelper.draw(self, context)


# -- the other tabs ------------------------------------------------------------
# Cycles' own panels call ``CyclesButtonsPanel.poll``, whose COMPAT_ENGINES is
# Cycles' alone, so adding FPPM to them shows nothing; these are FPPM's copies
# (as Cycles' add-on itself writes its own copies of Blender's panels), drawing
# only what addon/export.py reads.

class FPPMDataPanel(FPPMPanel):
    """A panel of the Properties editor outside the render tab."""

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES and cls.poll_data(context)

    @classmethod
    def poll_data(cls, context):
        return True


def node_output_draw(layout, id_data, input_name) -> bool:
    """Draw the node tree feeding ``input_name`` of the output node the exporter
    reads (target All or Cycles: ``get_output_node('CYCLES')``), as Cycles'
    ``panel_node_draw`` does; False when ``id_data`` has no node tree."""
    ntree = getattr(id_data, "node_tree", None)
    if ntree is None:
        return False
    node = ntree.get_output_node('CYCLES')
    if node is None:
        layout.label(text="No output node")
        return True
    sock = node.inputs.get(input_name)
    if sock is None:
        layout.label(text="Incompatible output node")
    else:
        layout.template_node_view(ntree, node, sock)
    return True


class FPPM_LIGHT_PT_light(FPPMDataPanel, Panel):
    bl_label = "Light"
    bl_context = "data"

    @classmethod
    def poll_data(cls, context):
        return getattr(context, "light", None) is not None

    def draw(self, context):
        layout = self.layout
        light = context.light
        layout.row().prop(light, "type", expand=True)
        split(layout)
        col = layout.column()
        row = col.row(heading="Temperature")
        row.prop(light, "use_temperature", text="")
        sub = row.row()
        sub.active = light.use_temperature
        sub.prop(light, "temperature", text="")
        col.prop(light, "color", text="Tint" if light.use_temperature else "Color")
        col = layout.column()
        col.prop(light, "energy")
        col.prop(light, "exposure")
        if light.type == 'AREA':
            # Point and spot lights are always normalised (export: 'Normalize' off
            # treated as on); the area light honours it.
            col.prop(light, "normalize")
        col = layout.column()
        if light.type in {'POINT', 'SPOT'}:
            col.prop(light, "shadow_soft_size", text="Radius")
            col.prop(light, "use_soft_falloff")
        elif light.type == 'SUN':
            col.prop(light, "angle")
        elif light.type == 'AREA':
            col.prop(light, "shape", text="Shape")
            sub = col.column(align=True)
            if light.shape in {'SQUARE', 'DISK'}:
                sub.prop(light, "size")
            else:
                sub.prop(light, "size", text="Size X")
                sub.prop(light, "size_y", text="Y")
        col.prop(light, "use_shadow", text="Cast Shadow")


class FPPM_LIGHT_PT_nodes(FPPMDataPanel, Panel):
    """The light's node tree: its Emission and an IES Texture into the
    Emission's Strength (addon/export_light_nodes.py)."""
    bl_label = "Nodes"
    bl_context = "data"
    poll_data = FPPM_LIGHT_PT_light.poll_data

    def draw(self, context):
        self.layout.use_property_split = True
        node_output_draw(self.layout, context.light, 'Surface')


class FPPM_LIGHT_PT_beam_shape(FPPMDataPanel, Panel):
    bl_label = "Beam Shape"
    bl_context = "data"
    bl_parent_id = "FPPM_LIGHT_PT_light"

    @classmethod
    def poll_data(cls, context):
        light = getattr(context, "light", None)
        return light is not None and light.type in {'SPOT', 'AREA'}

    def draw(self, context):
        layout = split(self.layout)
        light = context.light
        col = layout.column()
        if light.type == 'SPOT':
            col.prop(light, "spot_size", text="Angle")
            col.prop(light, "spot_blend", text="Blend", slider=True)
            col.prop(light, "show_cone")
        else:
            col.prop(light, "spread", text="Spread")


class FPPM_PT_context_material(FPPMDataPanel, Panel):
    """Material slots and the active material (Cycles' CYCLES_PT_context_material)."""
    bl_label = ""
    bl_context = "material"
    bl_options = {'HIDE_HEADER'}

    @classmethod
    def poll_data(cls, context):
        ob = getattr(context, "active_object", None)
        if ob is not None and ob.type == 'GREASEPENCIL':
            return False
        return bool(getattr(context, "material", None) or getattr(context, "object", None))

    def draw(self, context):
        layout = self.layout
        mat = context.material
        ob = context.object
        slot = getattr(context, "material_slot", None)
        if ob:
            sortable = len(ob.material_slots) > 1
            row = layout.row()
            row.template_list("MATERIAL_UL_matslots", "", ob, "material_slots", ob,
                              "active_material_index", rows=4 if sortable else 3)
            col = row.column(align=True)
            col.operator("object.material_slot_add", icon='ADD', text="")
            col.operator("object.material_slot_remove", icon='REMOVE', text="")
            col.separator()
            col.menu("MATERIAL_MT_context_menu", icon='DOWNARROW_HLT', text="")
            if sortable:
                col.separator()
                col.operator("object.material_slot_move", icon='TRIA_UP', text="").direction = 'UP'
                col.operator("object.material_slot_move", icon='TRIA_DOWN',
                             text="").direction = 'DOWN'
            if ob.mode == 'EDIT':
                row = layout.row(align=True)
                row.operator("object.material_slot_assign", text="Assign")
                row.operator("object.material_slot_select", text="Select")
                row.operator("object.material_slot_deselect", text="Deselect")
            row = layout.row()
            row.template_ID(ob, "active_material", new="material.new")
            if slot:
                icon = 'MESH_DATA' if slot.link == 'DATA' else 'OBJECT_DATA'
                row.prop(slot, "link", text="", icon=icon, icon_only=True)
        elif mat:
            layout.template_ID(context.space_data, "pin_id")


class FPPM_MATERIAL_PT_surface(FPPMDataPanel, Panel):
    bl_label = "Surface"
    bl_context = "material"

    @classmethod
    def poll_data(cls, context):
        mat = getattr(context, "material", None)
        return mat is not None and not mat.grease_pencil

    def draw(self, context):
        layout = split(self.layout)
        mat = context.material
        if not node_output_draw(layout, mat, "Surface"):
            layout.prop(mat, "diffuse_color")


class FPPM_MATERIAL_PT_displacement(FPPMDataPanel, Panel):
    """The Material Output's Displacement, which FPPM renders as the bump
    Cycles makes of it by default (docs/shading.md)."""
    bl_label = "Displacement"
    bl_context = "material"
    bl_options = {'DEFAULT_CLOSED'}
    poll_data = FPPM_MATERIAL_PT_surface.poll_data

    def draw(self, context):
        node_output_draw(split(self.layout), context.material, "Displacement")


class FPPM_MATERIAL_PT_settings(FPPMDataPanel, Panel):
    bl_label = "Settings"
    bl_context = "material"
    bl_options = {'DEFAULT_CLOSED'}
    poll_data = FPPM_MATERIAL_PT_surface.poll_data

    def draw(self, context):
        # The pass index (the Material Index pass writes it) and the
        # displacement method (anything but Bump Only is noted: rendered as bump).
        layout = split(self.layout)
        layout.prop(context.material, "pass_index")
        layout.prop(context.material, "displacement_method", text="Displacement")


class FPPMPreviewPanel(FPPMDataPanel):
    """The datablock's preview, rendered by FPPM (addon/preview.py); Cycles'
    preview panels poll true for Cycles only."""
    bl_label = "Preview"
    bl_options = {'DEFAULT_CLOSED'}


class FPPM_MATERIAL_PT_preview(FPPMPreviewPanel, Panel):
    bl_context = "material"
    poll_data = classmethod(lambda cls, context: getattr(context, "material", None) is not None)

    def draw(self, context):
        self.layout.template_preview(context.material)


class FPPM_LIGHT_PT_preview(FPPMPreviewPanel, Panel):
    bl_context = "data"
    poll_data = classmethod(lambda cls, context: getattr(context, "light", None) is not None)

    def draw(self, context):
        self.layout.template_preview(context.light)


class FPPM_WORLD_PT_preview(FPPMPreviewPanel, Panel):
    bl_context = "world"
    poll_data = classmethod(lambda cls, context: getattr(context, "world", None) is not None)

    def draw(self, context):
        self.layout.template_preview(context.world)


class FPPM_WORLD_PT_surface(FPPMDataPanel, Panel):
    bl_label = "Surface"
    bl_context = "world"

    @classmethod
    def poll_data(cls, context):
        return getattr(context, "world", None) is not None

    def draw(self, context):
        layout = split(self.layout)
        world = context.world
        if not node_output_draw(layout, world, "Surface"):
            layout.prop(world, "color")


class FPPM_WORLD_PT_ray_visibility(FPPMDataPanel, Panel):
    """The world's ray visibility: camera (export.py: camera rays that escape
    see black; the world still lights the scene), diffuse, glossy and
    transmission (``Scene.world_hidden``: core.lights.lobe_visibility).
    Volume scatter is not drawn: FPPM renders no scattering volume."""
    bl_label = "Ray Visibility"
    bl_context = "world"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll_data(cls, context):
        world = getattr(context, "world", None)
        return world is not None and getattr(world, "cycles_visibility", None) is not None

    def draw(self, context):
        layout = split(self.layout)
        vis = context.world.cycles_visibility
        col = layout.column()
        for k in ("camera", "diffuse", "glossy", "transmission"):
            col.prop(vis, k)


class FPPM_WORLD_PT_mist(FPPMDataPanel, Panel):
    bl_label = "Mist Pass"
    bl_context = "world"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll_data(cls, context):
        world = getattr(context, "world", None)
        scene = getattr(context, "scene", None)
        return world is not None and scene is not None and \
            any(vl.use_pass_mist for vl in scene.view_layers)

    def draw(self, context):
        layout = split(self.layout)
        ms = context.world.mist_settings
        col = layout.column(align=True)
        col.prop(ms, "start")
        col.prop(ms, "depth")
        layout.column().prop(ms, "falloff")


class FPPM_OBJECT_PT_visibility(FPPMDataPanel, Panel):
    bl_label = "Visibility"
    bl_context = "object"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll_data(cls, context):
        return getattr(context, "object", None) is not None

    def draw(self, context):
        layout = split(self.layout)
        ob = context.object
        layout.prop(ob, "hide_select", text="Selectable", invert_checkbox=True, toggle=False)
        layout.prop(ob, "hide_surface_pick", text="Surface Picking", toggle=False,
                    invert_checkbox=True)
        col = layout.column(heading="Show In")
        col.prop(ob, "hide_viewport", text="Viewports", invert_checkbox=True, toggle=False)
        col.prop(ob, "hide_render", text="Renders", invert_checkbox=True, toggle=False)
        if ob.type in GEOMETRY_TYPES:
            # Cycles' Mask: the shadow catcher (core.sppm.shadow_catcher) and
            # the holdout (core.scene.holdout).
            col = layout.column(heading="Mask")
            col.prop(ob, "is_shadow_catcher")
            col.prop(ob, "is_holdout")


class FPPM_OBJECT_PT_visibility_ray_visibility(FPPMDataPanel, Panel):
    """The rays an object is seen by: a light's camera, diffuse, glossy and
    transmission visibility; a geometry object's camera, diffuse, glossy,
    transmission and shadow visibility (an emitting object's diffuse,
    glossy and transmission in its light samples, its glossy and
    transmission for mirrors' and glass's rays; photons and light paths see
    it, the log says so: export.py ``HONOURED_RAYS``)."""
    bl_label = "Ray Visibility"
    bl_context = "object"
    bl_parent_id = "FPPM_OBJECT_PT_visibility"

    @classmethod
    def poll_data(cls, context):
        ob = getattr(context, "object", None)
        return ob is not None and (ob.type == 'LIGHT' or ob.type in GEOMETRY_TYPES)

    def draw(self, context):
        layout = split(self.layout)
        ob = context.object
        col = layout.column()
        col.prop(ob, "visible_camera", text="Camera")
        col.prop(ob, "visible_diffuse", text="Diffuse")
        col.prop(ob, "visible_glossy", text="Glossy")
        col.prop(ob, "visible_transmission", text="Transmission")
        if ob.type != 'LIGHT':
            col.prop(ob, "visible_shadow", text="Shadow")


class FPPM_OBJECT_PT_light_linking(FPPMDataPanel, Panel):
    """An emitter's Receiver Collection (core.scene.linking): the objects it
    lights, each Include or Exclude.  Cycles draws it inside Object >
    Shading, whose other settings FPPM does not read (HIDDEN)."""
    bl_label = "Light Linking"
    bl_context = "object"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll_data(cls, context):
        ob = getattr(context, "object", None)
        return ob is not None and getattr(ob, "light_linking", None) is not None

    def draw(self, context):
        layout = split(self.layout)
        ll = context.object.light_linking
        layout.column().template_ID(ll, "receiver_collection",
                                    new="object.light_linking_receiver_collection_new")
        if ll.receiver_collection is None:
            return
        row = layout.row()
        row.column().template_light_linking_collection(row, ll, "receiver_collection")
        col = row.column(align=True)
        add = col.operator("object.light_linking_receivers_link", icon='ADD', text="")
        add.link_state = 'INCLUDE'
        col.operator("object.light_linking_unlink_from_collection", icon='REMOVE', text="")


classes = (
    FPPM_RENDER_PT_sampling,
    FPPM_RENDER_PT_viewport,
    FPPM_RENDER_PT_kernel,
    FPPM_RENDER_PT_light_paths,
    FPPM_RENDER_PT_frequency,
    FPPM_RENDER_PT_output,
    FPPM_VIEWLAYER_PT_passes,
    FPPM_VIEWLAYER_PT_passes_aov,
    FPPM_VIEWLAYER_PT_passes_crypto,
    FPPM_LIGHT_PT_preview,
    FPPM_LIGHT_PT_light,
    FPPM_LIGHT_PT_nodes,
    FPPM_LIGHT_PT_beam_shape,
    FPPM_PT_context_material,
    FPPM_MATERIAL_PT_preview,
    FPPM_MATERIAL_PT_surface,
    FPPM_MATERIAL_PT_displacement,
    FPPM_MATERIAL_PT_settings,
    FPPM_WORLD_PT_preview,
    FPPM_WORLD_PT_surface,
    FPPM_WORLD_PT_ray_visibility,
    FPPM_WORLD_PT_mist,
    FPPM_OBJECT_PT_visibility,
    FPPM_OBJECT_PT_visibility_ray_visibility,
    FPPM_OBJECT_PT_light_linking,
)

# Standard panels FPPM uses, by role.  For each role the candidates are tried
# in order and every one that exists gets FPPM (Cycles' panels exist only while
# the Cycles add-on is enabled; the generic ones are the fallback).
STANDARD_PANELS = {
    "dimensions": ("RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_time_stretching",
                   "RENDER_PT_stereoscopy"),
    "output": ("RENDER_PT_output", "RENDER_PT_output_views",
               "RENDER_PT_output_color_management", "RENDER_PT_output_pixel_density",
               "RENDER_PT_encoding", "RENDER_PT_encoding_video", "RENDER_PT_encoding_audio",
               "RENDER_PT_post_processing", "RENDER_PT_stamp", "RENDER_PT_stamp_note",
               "RENDER_PT_stamp_burn"),
    "colour management": ("RENDER_PT_color_management",
                          "RENDER_PT_color_management_working_space",
                          "RENDER_PT_color_management_display_settings",
                          "RENDER_PT_color_management_curves",
                          "RENDER_PT_color_management_white_balance",
                          "RENDER_PT_color_management_advanced"),
    "film": ("CYCLES_RENDER_PT_film", "CYCLES_RENDER_PT_film_pixel_filter",
             "CYCLES_RENDER_PT_film_transparency"),
    "camera": ("DATA_PT_context_camera", "DATA_PT_lens", "DATA_PT_camera",
               "DATA_PT_camera_dof", "DATA_PT_camera_dof_aperture", "DATA_PT_camera_display",
               "DATA_PT_camera_display_composition_guides", "DATA_PT_camera_safe_areas",
               "DATA_PT_camera_safe_areas_center_cut", "DATA_PT_camera_background_image",
               "DATA_PT_custom_props_camera"),
    "light": ("DATA_PT_context_light", "DATA_PT_custom_props_light"),
    "world": ("WORLD_PT_context_world", "WORLD_PT_custom_props"),
    "material": ("MATERIAL_PT_custom_props",),
    "custom properties": ("OBJECT_PT_custom_props", "STRIP_PT_custom_props"),
    "mesh": ("DATA_PT_context_mesh", "DATA_PT_vertex_groups", "DATA_PT_shape_keys",
             "DATA_PT_uv_texture", "DATA_PT_vertex_colors", "DATA_PT_mesh_attributes",
             "DATA_PT_customdata", "DATA_PT_custom_props_mesh"),
}
# Without Cycles, the generic equivalents of the Cycles-only roles.
FALLBACK_PANELS = {
    "film": (),
}

# Blender's panels that claim every built-in engine (Cycles' add-on gives
# itself these too, through 'BLENDER_RENDER'): they draw settings of the scene,
# the objects or the simulations, independent of the renderer, and FPPM gets
# them all except those of HIDDEN.
ANY_ENGINE = frozenset({'BLENDER_RENDER', 'BLENDER_EEVEE', 'BLENDER_WORKBENCH'})

# The Cycles panels FPPM replaces by its own, each with why.  Checked by
# tests/test_panels.py: every panel a Cycles user sees is shown under FPPM, is
# a key here (its equivalent shows), or is in HIDDEN.
EQUIVALENTS = {
    "CYCLES_LIGHT_PT_preview": ("FPPM_LIGHT_PT_preview", "the light's preview, rendered by FPPM"),
    "CYCLES_MATERIAL_PT_preview": ("FPPM_MATERIAL_PT_preview",
                                   "the material's preview, rendered by FPPM"),
    "CYCLES_WORLD_PT_preview": ("FPPM_WORLD_PT_preview", "the world's preview, rendered by FPPM"),
    "CYCLES_RENDER_PT_sampling": ("FPPM_RENDER_PT_sampling",
                                  "passes, time limit, photons per pass, seed"),
    "CYCLES_RENDER_PT_sampling_render": ("FPPM_RENDER_PT_sampling", "max passes, time limit"),
    "CYCLES_RENDER_PT_sampling_viewport": ("FPPM_RENDER_PT_viewport",
                                           "viewport passes and resolution"),
    "CYCLES_RENDER_PT_light_paths": ("FPPM_RENDER_PT_light_paths",
                                     "max bounces, Russian roulette"),
    "CYCLES_RENDER_PT_light_paths_max_bounces": ("FPPM_RENDER_PT_light_paths",
                                                 "one total bounce limit"),
    "CYCLES_RENDER_PT_passes": ("FPPM_VIEWLAYER_PT_passes",
                                "the passes FPPM writes (core.sppm.film.PASSES) and its AOVs"),
    "CYCLES_RENDER_PT_passes_data": ("FPPM_VIEWLAYER_PT_passes",
                                     "depth, mist, normal, UV, indices written by the film"),
    "CYCLES_RENDER_PT_passes_crypto": ("FPPM_VIEWLAYER_PT_passes_crypto",
                                       "object, material and asset mattes, levels"),
    "CYCLES_RENDER_PT_passes_aov": ("FPPM_VIEWLAYER_PT_passes_aov",
                                    "the view layer's shader AOVs"),
    "CYCLES_PT_post_processing": ("RENDER_PT_post_processing",
                                  "Blender's own compositing/sequencer switches"),
    "CYCLES_LIGHT_PT_light": ("FPPM_LIGHT_PT_light",
                              "type, colour, temperature, power, exposure, radius/angle/size"),
    "CYCLES_LIGHT_PT_beam_shape": ("FPPM_LIGHT_PT_beam_shape", "spot size/blend, area spread"),
    "CYCLES_LIGHT_PT_nodes": ("FPPM_LIGHT_PT_nodes", "the light's Emission and IES Texture"),
    "CYCLES_LIGHT_PT_settings": ("FPPM_LIGHT_PT_light",
                                 "Cast Shadow is the one setting read: drawn in Light"),
    "CYCLES_PT_context_material": ("FPPM_PT_context_material", "slots, active material"),
    "CYCLES_MATERIAL_PT_surface": ("FPPM_MATERIAL_PT_surface", "the Surface node tree"),
    "CYCLES_MATERIAL_PT_settings": ("FPPM_MATERIAL_PT_settings",
                                    "pass index (Material Index pass), displacement method"),
    "CYCLES_MATERIAL_PT_displacement": ("FPPM_MATERIAL_PT_displacement",
                                        "the Displacement input (rendered as bump)"),
    "CYCLES_WORLD_PT_surface": ("FPPM_WORLD_PT_surface", "Background colour and strength"),
    "CYCLES_WORLD_PT_mist": ("FPPM_WORLD_PT_mist", "mist start, depth, falloff"),
    "CYCLES_WORLD_PT_ray_visibility": ("FPPM_WORLD_PT_ray_visibility",
                                       "camera, diffuse, glossy and transmission visibility"),
    "CYCLES_CAMERA_PT_dof": ("DATA_PT_camera_dof", "focus distance/object, F-stop"),
    "CYCLES_CAMERA_PT_dof_aperture": ("DATA_PT_camera_dof_aperture", "F-stop, blades, rotation"),
    "CYCLES_OBJECT_PT_visibility": ("FPPM_OBJECT_PT_visibility",
                                    "selectable, show in viewports/renders"),
    "CYCLES_OBJECT_PT_visibility_ray_visibility": (
        "FPPM_OBJECT_PT_visibility_ray_visibility",
        "lights: camera/glossy/transmission; geometry: camera/shadow"),
}

# Blender's engine-independent panels that FPPM's own replace (as Cycles'
# add-on excludes them from its copies): they would show twice.
REPLACED = {
    "OBJECT_PT_visibility": "FPPM_OBJECT_PT_visibility",
    "DATA_PT_light": "FPPM_LIGHT_PT_light",
    "DATA_PT_spot": "FPPM_LIGHT_PT_beam_shape",
    "MATERIAL_PT_context_material": "FPPM_PT_context_material",
    "VIEWLAYER_PT_layer_passes": "FPPM_VIEWLAYER_PT_passes",
    "VIEWLAYER_PT_layer_passes_cryptomatte": "FPPM_VIEWLAYER_PT_passes_crypto",
    "VIEWLAYER_PT_layer_passes_aov": "FPPM_VIEWLAYER_PT_passes_aov",
}

#: The panels of the volumes FPPM ignores (a constant Volume Absorption is
#: rendered: docs/shading.md "Absorbing volumes").
VOLUMES_IGNORED = ("volumes that scatter, emit or vary (Volume Scatter, Principled Volume, "
                   "a textured or mixed volume shader): ignored")

# Panels a Cycles user sees that FPPM hides, because FPPM ignores what they
# set ("<feature>: ignored" names a row of addon/export.py SUPPORT), or why
# they have no meaning for FPPM.  A panel whose parent is hidden is hidden with it.
HIDDEN = {
    # render tab: Cycles' integrator, devices and features FPPM does not have
    "CYCLES_RENDER_PT_sampling_viewport_denoise": "no denoiser (use the compositor's)",
    "CYCLES_RENDER_PT_sampling_render_denoise": "no denoiser (use the compositor's)",
    "CYCLES_RENDER_PT_sampling_path_guiding": "Cycles' path guiding",
    "CYCLES_RENDER_PT_sampling_lights": "Cycles' light tree",
    "CYCLES_RENDER_PT_sampling_advanced": "Cycles' sample patterns; FPPM has a seed",
    "CYCLES_RENDER_PT_light_paths_clamping": "clamping: ignored",
    "CYCLES_RENDER_PT_light_paths_caustics": "caustics are what photons render: no filter",
    "CYCLES_RENDER_PT_light_paths_fast_gi": "Cycles' fast GI approximation",
    "CYCLES_RENDER_PT_volumes": VOLUMES_IGNORED,
    "CYCLES_RENDER_PT_subdivision": "adaptive subdivision: ignored",
    "CYCLES_RENDER_PT_curves": "hair curves: ignored",
    "CYCLES_RENDER_PT_simplify": "Cycles' copy of Simplify (FPPM gets Blender's, ANY_ENGINE)",
    "CYCLES_RENDER_PT_motion_blur": "motion blur: ignored",
    "CYCLES_RENDER_PT_performance": "Cycles' threads, tiles and BVH",
    "CYCLES_RENDER_PT_bake": "baking: FPPM does not bake",
    "CYCLES_RENDER_PT_debug": "Cycles' developer options",
    # view layer tab
    "CYCLES_RENDER_PT_filter": "Cycles' per-layer filter of surfaces/curves/volumes",
    # (its Color, Environment and AO flags are in FPPM's own Passes panel)
    "CYCLES_RENDER_PT_passes_light": "the Direct and Indirect light passes and the Shadow "
                                     "pass: ignored",
    "CYCLES_RENDER_PT_passes_lightgroups": "light groups: ignored",
    "VIEWLAYER_PT_layer_passes_lightgroups": "light groups: ignored",
    "VIEWLAYER_PT_override": "material and sample override: ignored",
    # object tab
    "CYCLES_OBJECT_PT_visibility_culling": "camera and distance culling: ignored",
    "CYCLES_OBJECT_PT_motion_blur": "motion blur: ignored",
    "OBJECT_PT_shading": "shadow terminator, caustics flags: ignored",
    "OBJECT_PT_shadow_terminator": "shadow terminator, caustics flags: ignored",
    # data / material / world tabs
    "CYCLES_MATERIAL_PT_volume": VOLUMES_IGNORED,
    "CYCLES_MATERIAL_PT_settings_surface": "Cycles' displacement method, emission "
                                           "sampling, transparent shadows, thin walls",
    "CYCLES_MATERIAL_PT_settings_volume": VOLUMES_IGNORED,
    "CYCLES_CAMERA_PT_lens_custom_parameters": "custom (OSL) cameras: FPPM renders "
                                               "perspective and orthographic cameras",
    "DATA_PT_context_lightprobe": "light probes: ignored",
    "DATA_PT_lightprobe": "light probes: ignored",
    "DATA_PT_lightprobe_display": "light probes: ignored",
    "DATA_PT_lightprobe_parallax": "light probes: ignored",
    "DATA_PT_lightprobe_visibility": "light probes: ignored",
    "EEVEE_MATERIAL_PT_viewport_settings": "EEVEE material settings: ignored",
    "CYCLES_WORLD_PT_volume": VOLUMES_IGNORED,
    "CYCLES_WORLD_PT_settings": "Cycles' world sampling (the world is a constant colour)",
}

# (panel, attribute the class itself had, or None) for every panel changed.
_added: list = []
_MISSING = object()


def compat_panels() -> list:
    """The standard panel classes FPPM should appear in, as they exist now."""
    out = []
    for role, names in STANDARD_PANELS.items():
        found = [getattr(bpy.types, n, None) for n in names]
        found = [p for p in found if p is not None]
        if not any(p.__name__.startswith("CYCLES") for p in found) and role in FALLBACK_PANELS:
            found += [p for p in (getattr(bpy.types, n, None) for n in FALLBACK_PANELS[role])
                      if p is not None]
        out.extend(p for p in found if hasattr(p, "COMPAT_ENGINES"))
    seen = set(out)
    for p in _panel_classes():
        if p not in seen and ANY_ENGINE <= set(getattr(p, "COMPAT_ENGINES", ())) \
                and p.__name__ not in REPLACED and not hidden_reason(p.__name__):
            out.append(p)
            seen.add(p)
    return out


def hidden_reason(name: str) -> str | None:
    """HIDDEN's reason for the panel ``name`` or a panel it is drawn inside."""
    while name is not None:
        if name in HIDDEN:
            return HIDDEN[name]
        name = getattr(getattr(bpy.types, name, None), "bl_parent_id", None)
    return None


def _panel_classes():
    """Every registered Panel class (subclasses of subclasses too)."""
    stack, out = list(Panel.__subclasses__()), []
    while stack:
        p = stack.pop()
        out.append(p)
        stack.extend(p.__subclasses__())
    return [p for p in out if getattr(bpy.types, p.__name__, None) is p]


def add_to_standard_panels():
    """Give each panel of :func:`compat_panels` its own COMPAT_ENGINES plus FPPM.

    Many panels share one COMPAT_ENGINES set through a mix-in class (all of
    Cycles' panels share CyclesButtonsPanel's), so adding to the set in place
    would show every Cycles panel.  A new set on the class itself affects that
    panel only, and unregister puts the original attribute back.
    """
    for panel in compat_panels():
        if ENGINE in panel.COMPAT_ENGINES:
            continue
        own = panel.__dict__.get("COMPAT_ENGINES", _MISSING)
        _added.append((panel, own))
        panel.COMPAT_ENGINES = set(panel.COMPAT_ENGINES) | {ENGINE}


def remove_from_standard_panels():
    while _added:
        panel, own = _added.pop()
        if own is _MISSING:
            try:
                del panel.COMPAT_ENGINES
            except AttributeError:
                pass
        else:
            panel.COMPAT_ENGINES = own
