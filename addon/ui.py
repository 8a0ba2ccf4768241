"""Render-properties panels for FPPM, and FPPM's place in Blender's standard panels."""
import bpy
from bpy.types import Panel

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
        if s.integrator == 'PATH':
            col.prop(s, "camera_samples")
        else:
            col.prop(s, "photons_per_pass")
        col.prop(s, "seed")


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
        col.prop(s, "alpha")


class FPPM_RENDER_PT_light_paths(FPPMPanel, Panel):
    bl_label = "Light Paths"

    def draw(self, context):
        layout = split(self.layout)
        s = context.scene.fppm
        col = layout.column()
        col.prop(s, "max_bounces")
        col.prop(s, "rr_start")
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
        col.prop(s, "frequency_model")
        col.prop(s, "frequency_estimator")
        col.prop(s, "hold_alpha", slider=True)
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


classes = (
    FPPM_RENDER_PT_sampling,
    FPPM_RENDER_PT_viewport,
    FPPM_RENDER_PT_kernel,
    FPPM_RENDER_PT_light_paths,
    FPPM_RENDER_PT_frequency,
    FPPM_RENDER_PT_output,
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
    "light": ("DATA_PT_context_light", "CYCLES_LIGHT_PT_light", "CYCLES_LIGHT_PT_beam_shape",
              "DATA_PT_custom_props_light"),
    "world": ("WORLD_PT_context_world", "CYCLES_WORLD_PT_surface", "WORLD_PT_custom_props"),
    "material": ("CYCLES_PT_context_material", "CYCLES_MATERIAL_PT_surface",
                 "MATERIAL_PT_custom_props"),
    "mesh": ("DATA_PT_context_mesh", "DATA_PT_vertex_groups", "DATA_PT_shape_keys",
             "DATA_PT_uv_texture", "DATA_PT_vertex_colors", "DATA_PT_mesh_attributes",
             "DATA_PT_customdata", "DATA_PT_custom_props_mesh"),
}
# Without Cycles, the EEVEE/generic equivalents of the Cycles-only roles.
FALLBACK_PANELS = {
    "film": (),
    "light": ("DATA_PT_light",),
    "world": ("EEVEE_WORLD_PT_surface",),
    "material": ("EEVEE_MATERIAL_PT_context_material", "EEVEE_MATERIAL_PT_surface"),
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
    return out


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
