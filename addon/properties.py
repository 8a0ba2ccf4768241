"""``scene.fppm``: the render settings as a Blender PropertyGroup.

Field names, types and defaults mirror ``core.settings.RenderSettings`` and
``core.settings.ViewportSettings`` one to one (``tests/test_settings_mirror.py``
checks every field).  Enum items have
explicit indices so files saved by one version read back the same way.
Validation proper stays in ``RenderSettings.validate()``; the limits here only
keep the UI inside the valid ranges.
"""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty
from bpy.types import PropertyGroup

from ..core.settings import RenderSettings, ViewportSettings, field_names, viewport_field_names

_D = RenderSettings()  # defaults come from core, never duplicated by hand
_V = ViewportSettings()

RADIUS_MODES = (
    ('AUTO', "Pixel Footprint",
     "Initial radius in pixels: this many pixel footprints at each visible point", 0),
    ('WORLD', "World Units",
     "Initial radius in metres, the same at every visible point", 1),
)
CAMERA_DEPTHS = (
    ('AUTO', "Auto",
     "Emitters where every material is diffuse or rough and light paths often reach the "
     "camera (a pilot of light paths decides; light tracing takes the rest); Direct with "
     "one camera path a pixel where the scene has mirrors or glass but the camera sees "
     "none of them and every light is a point or spot light of radius 0; else Full", 0),
    ('FULL', "Full", "Camera paths at full length, every strategy weighted by MIS", 1),
    ('EMITTERS', "Emitters",
     "Camera rays on diffuse first vertices only find emitters seen directly", 2),
    ('DIRECT', "Direct",
     "Camera paths on diffuse first vertices keep next-event estimation and emission "
     "there, then stop", 3),
)

MERGE_WEIGHTS = (
    ('PARTITION', "Partition",
     "Merging takes whole path classes (caustics seen through mirrors and glass), "
     "weight 0 or 1", 0),
    ('MIS', "MIS",
     "Merging is a fourth MIS strategy at the visible point: its weight grows with the "
     "gathering radius", 1),
)
INTEGRATORS = (
    ('PHOTON', "Photon Mapping",
     "Stochastic progressive photon mapping with the frequency-adapted kernel (FPPM)", 0),
    ('PATH', "Path Tracing",
     "Camera paths alone: path tracing with next-event estimation and MIS, like Cycles", 1),
    ('LIGHT', "Light Tracing",
     "Light tracing alone: every diffuse or glossy vertex of the photon paths is connected "
     "to the camera (sharp point-light caustics; misses what the camera sees in mirrors)", 2),
    ('COMBINED', "Combined",
     "Path tracing and light tracing weighted by multiple importance sampling: each path is "
     "counted by the strategy that samples it best", 3),
)
RADIUS_RULES = (
    ('PPM', "PPM",
     "One reduction rate alpha for every pixel (Hachisuka et al. 2008), slowed where the "
     "Frequency Kernel predicts smooth light", 0),
    ('APPM', "Adaptive (APPM)",
     "Per-pixel radius that minimises the estimated error, the bias from the photons' "
     "Laplacian (Kaplanyan & Dachsbacher 2013); needs Frequency Kernel off", 1),
    ('CPPM', "Chi-Squared (CPPM)",
     "Keep a pixel's radius while its photons pass a chi-squared uniformity test, shrink it "
     "where they fail (Lin et al. 2020); needs Frequency Kernel off", 2),
)
FREQUENCY_MODELS = (
    ('CORRECTED', "Corrected",
     "Frequency analysis with the corrected curvature and BSDF terms (see the documentation)", 0),
    ('PAPER', "Paper",
     "Frequency analysis exactly as printed in Belcour & Soler 2011", 1),
)
FREQUENCY_ESTIMATORS = (
    ('MIN', "Minimum",
     "Radius from the smallest radius predicted by the frequency photons in the kernel", 0),
    ('QUANTILE', "Quantile",
     "Radius from a low quantile of the predicted radii: less sensitive to one outlier photon", 1),
)


class FPPMRenderSettings(PropertyGroup):
    """FPPM render settings, one property per ``RenderSettings`` field."""

    # --- Sampling
    time_limit: FloatProperty(
        name="Time Limit", default=_D.time_limit, min=0.0, soft_max=3600.0,
        unit='TIME_ABSOLUTE', precision=1,
        description="Stop after this many seconds of passes (0 = no time limit)")
    max_passes: IntProperty(
        name="Max Passes", default=_D.max_passes, min=0, max=1_000_000, soft_max=4096,
        description="Stop after this many progressive passes "
                    "(0 = no limit: then a time limit is required)")
    photons_per_pass: IntProperty(
        name="Photons per Pass", default=_D.photons_per_pass, min=1, max=100_000_000,
        soft_min=1000, soft_max=10_000_000,
        description="Photons traced from the lights in every pass")
    seed: IntProperty(
        name="Seed", default=_D.seed, min=0, max=2**31 - 1,
        description="Random seed: the same seed renders the same image bit for bit")
    use_animated_seed: BoolProperty(
        name="Animated Seed", default=_D.use_animated_seed,
        description="Mix the frame number into the seed, so that each frame of an animation "
                    "has its own noise (off: every frame uses Seed, as Cycles' default)")

    # --- Integrator
    integrator: EnumProperty(
        name="Integrator", items=INTEGRATORS, default=_D.integrator,
        description="Which strategies estimate the image: photon mapping (FPPM), path "
                    "tracing alone, light tracing alone, or path and light tracing combined")
    camera_samples: IntProperty(
        name="Camera Samples", default=_D.camera_samples, min=1, max=4096, soft_max=64,
        description="Path Tracing and Combined: camera paths per pixel in every pass")
    light_paths_per_camera_path: FloatProperty(
        name="Light Paths per Camera Path", default=_D.light_paths_per_camera_path,
        min=0.0, max=10_000.0, soft_max=64.0, precision=1,
        description="Combined: light paths in every pass per camera path of the pass "
                    "(Camera Samples x pixels), the same balance at any resolution; "
                    "0 = Photons per Pass")
    camera_depth: EnumProperty(
        name="Camera Depth", items=CAMERA_DEPTHS, default=_D.camera_depth,
        description="Combined: where camera paths whose first vertex is diffuse stop; "
                    "light tracing alone takes the longer paths there")
    merge_weights: EnumProperty(
        name="Merging Weights", items=MERGE_WEIGHTS, default=_D.merge_weights,
        description="Combined: how photon merging shares paths with the other strategies")

    # --- Kernel
    radius_mode: EnumProperty(
        name="Initial Radius", items=RADIUS_MODES, default=_D.radius_mode,
        description="How the initial photon gathering radius is chosen")
    initial_radius_px: FloatProperty(
        name="Radius (Pixels)", default=_D.initial_radius_px, min=0.01, max=1000.0,
        soft_min=0.25, soft_max=16.0, precision=2,
        description="Initial gathering radius in pixel footprints at the visible point")
    initial_radius: FloatProperty(
        name="Radius", default=_D.initial_radius, min=1e-6, soft_min=1e-4, soft_max=1.0,
        subtype='DISTANCE', unit='LENGTH', precision=4,
        description="Initial gathering radius in world units")
    alpha: FloatProperty(
        name="Alpha", default=_D.alpha, min=0.01, max=1.0, soft_min=0.5, soft_max=0.95,
        subtype='FACTOR',
        description="Progressive radius reduction (Hachisuka 2008): the fraction of new "
                    "photons kept per pass; lower shrinks the radius faster")
    cap_radius_at_edges: BoolProperty(
        name="Cap Radius at Edges", default=_D.cap_radius_at_edges,
        description="Keep each pixel's initial radius within half the distance to the nearest "
                    "surface edge seen around it, so that kernels do not darken or blend "
                    "across the edges of tables, walls and objects")
    clip_kernel: BoolProperty(
        name="Clip Kernel at Walls", default=_D.clip_kernel,
        description="Cast a few short rays around each pixel's gathering disc and leave out "
                    "the photons behind a wall standing in it (no light leaks through thin "
                    "walls); the count is rescaled to the visible part of the disc")
    radius_rule: EnumProperty(
        name="Radius Rule", items=RADIUS_RULES, default=_D.radius_rule,
        description="How each pixel's gathering radius shrinks over passes")

    # --- Light paths
    max_bounces: IntProperty(
        name="Max Bounces", default=_D.max_bounces, min=1, max=1024, soft_max=64,
        description="Maximum number of bounces of camera and photon paths. To compare with "
                    "Cycles, use the same number in Cycles' Light Paths (default 16, as the "
                    "example scenes)")
    rr_start: IntProperty(
        name="Russian Roulette Start", default=_D.rr_start, min=0, max=1024, soft_max=32,
        description="Bounce from which paths are terminated at random by their throughput")
    photons_for_direct: BoolProperty(
        name="Photons for Direct Light", default=_D.photons_for_direct,
        description="Classic PPM: estimate direct light with photons too, instead of "
                    "sampling the lights with shadow rays")
    fixed_visible_points: BoolProperty(
        name="Fixed Visible Points", default=_D.fixed_visible_points,
        description="Classic PPM: trace the visible points once instead of with fresh "
                    "jitter every pass (no anti-aliasing, no glossy or depth of field)")
    glossy_chains: BoolProperty(
        name="Through Glossy", default=_D.glossy_chains,
        description="Photon Mapping: camera paths go on through metals, Glossy BSDFs and "
                    "rough glass (materials without a diffuse part), with their direct "
                    "light by light and BSDF samples weighed by MIS, and gather photons "
                    "at the next diffuse surface, as pbrt-v4's SPPM: sharp reflections "
                    "instead of photons gathered through a glossy lobe. Left out where a "
                    "point, spot or sun light and a mirror or glass are in the scene: their "
                    "caustics on glossy surfaces are gathered there")
    light_samples: IntProperty(
        name="Light Samples", default=_D.light_samples, min=0, max=64, soft_max=16,
        description="Photon Mapping: light samples averaged at each visible point in a "
                    "pass. 0: automatic (4 from 8 photons a pixel and pass, 2 from 2, else "
                    "1; and 1 where the only light is a point, spot or sun without size, "
                    "which every pass would sample alike)")

    # --- Frequency
    use_frequency: BoolProperty(
        name="Frequency Kernel", default=_D.use_frequency,
        description="Adapt the gathering radius per pixel from the local frequency "
                    "content of the light (Belcour & Soler 2011). Where fewer than 25% of "
                    "the pixels hold after the first pass, the render goes on as plain PPM")
    frequency_fraction: FloatProperty(
        name="Frequency Photons", default=_D.frequency_fraction, min=0.0, max=1.0,
        subtype='FACTOR',
        description="Fraction of each pass's photons that carry a frequency spectrum")
    frequency_decay: FloatProperty(
        name="Frequency Decay", default=_D.frequency_decay, min=0.0, max=2.0,
        description="Passes 1, 2, 4, 8, ... trace Frequency Photons / k^decay frequency "
                    "photons (pass k), the others none, and each pixel keeps its last "
                    "prediction through passes that bring it none (0 = the same fraction "
                    "every pass, each pass's own prediction)")
    frequency_start: IntProperty(
        name="Frequency Start", default=_D.frequency_start, min=1, max=1_000_000,
        soft_max=64,
        description="First pass that traces frequency photons; the passes before keep a "
                    "radius only where the photon counts look uniform (as CPPM), pass S "
                    "grows the verified holds, and the schedule runs from it: passes S, 2S, "
                    "4S, ... trace Frequency Photons / (k/S)^decay (1 = from the first pass)")
    frequency_model: EnumProperty(
        name="Model", items=FREQUENCY_MODELS, default=_D.frequency_model,
        description="Which equations propagate the light-field spectrum")
    frequency_estimator: EnumProperty(
        name="Estimator", items=FREQUENCY_ESTIMATORS, default=_D.frequency_estimator,
        description="How the predicted radii of the frequency photons become a pixel's radius")
    hold_alpha: FloatProperty(
        name="Hold Alpha", default=_D.hold_alpha, min=0.01, max=1.0, soft_min=0.7, soft_max=1.0,
        subtype='FACTOR',
        description="Radius reduction where the light is smooth (predicted by the spectrum or, "
                    "with Verify Holds, uniform photon counts): a held radius shrinks like "
                    "PPM with this alpha (at least Alpha), so its bias still vanishes; where "
                    "the counts can test a hold and the spectrum predicts light smooth well "
                    "beyond the radius, up to 0.95; 1 holds it forever (the paper's rule, "
                    "inconsistent). Pixels seen through glass or a mirror never hold")
    verify_holds: BoolProperty(
        name="Verify Holds", default=_D.verify_holds,
        description="Check holds against the photons in the kernel (chi-squared tests of "
                    "their sector counts): release a hold where they show more than a linear "
                    "gradient or a ramp too steep to stay linear across the kernel (there "
                    "the radius shrinks faster than Alpha, held or not), hold "
                    "where they look uniform (or are too few to test) even "
                    "without a smooth prediction, and let a pixel's first hold grow its "
                    "radius towards the prediction (at most 2x) where its sector cells hold "
                    "10 photons or more and the neighbouring pixels' photon densities do not "
                    "curve at the grown scale")
    occlusion_grid_res: IntProperty(
        name="Occlusion Grid", default=_D.occlusion_grid_res, min=4, max=512,
        soft_min=16, soft_max=256,
        description="Resolution of the voxel grid that estimates occluder frequencies")

    # --- Viewport (rendered shading of the 3D viewport)
    viewport_resolution_divider: IntProperty(
        name="Start Resolution Divider", default=_V.viewport_resolution_divider, min=1, max=64,
        soft_max=16,
        description="The viewport's first pass renders at its resolution divided by this, "
                    "for a quick first image after every change (1 = full resolution)")
    viewport_max_passes: IntProperty(
        name="Viewport Passes", default=_V.viewport_max_passes, min=0, max=1_000_000,
        soft_max=4096,
        description="The rendered viewport stops after this many passes (0 = no limit)")

    # --- Output (AOV passes)
    aov_radius: BoolProperty(
        name="Radius", default=_D.aov_radius,
        description="Passes 'FPPM Radius' (metres) and 'FPPM Radius px' (pixels): the "
                    "current gathering radius per pixel")
    aov_predicted_radius: BoolProperty(
        name="Predicted Radius", default=_D.aov_predicted_radius,
        description="Pass 'Predicted Radius': the radius the frequency analysis asks for")
    aov_spectrum: BoolProperty(
        name="Spectrum", default=_D.aov_spectrum,
        description="Pass 'Spectrum': the accumulated local light-field spectrum (a, b, c)")
    aov_photon_count: BoolProperty(
        name="Photon Count", default=_D.aov_photon_count,
        description="Pass 'Photon Count': photons gathered per pixel so far (N)")
    aov_held: BoolProperty(
        name="Held", default=_D.aov_held,
        description="Pass 'Held': 1 where the radius is held back from shrinking by the "
                    "frequency estimate")


def to_settings(props) -> RenderSettings:
    """Copy every field of ``scene.fppm`` into a (not yet validated) RenderSettings."""
    kw = {}
    for name in field_names():
        v = getattr(props, name)
        default = getattr(_D, name)
        # Blender floats are float32: keep Python floats, and round-trip exact
        # defaults (0.7f != 0.7) so the settings digest matches core's defaults.
        if isinstance(default, float):
            v = float(v)
            if abs(v - default) <= 1e-7 * max(1.0, abs(default)):
                v = default
            else:
                v = float(f"{v:.7g}")
        kw[name] = v
    return RenderSettings(**kw)


def viewport_settings_from_scene(scene) -> ViewportSettings:
    """The scene's viewport settings, or the defaults when ``scene.fppm`` is not registered."""
    props = getattr(scene, "fppm", None)
    if props is None:
        return ViewportSettings()
    return ViewportSettings(**{n: getattr(props, n) for n in viewport_field_names()})


def settings_from_scene(scene) -> RenderSettings:
    """The scene's settings, or the defaults when ``scene.fppm`` is not registered."""
    props = getattr(scene, "fppm", None)
    if props is None:
        return RenderSettings()
    return to_settings(props)


def apply_settings(props, settings: RenderSettings) -> None:
    """Write a RenderSettings into ``scene.fppm`` (the CLI's overrides)."""
    for name in field_names():
        setattr(props, name, getattr(settings, name))


classes = (FPPMRenderSettings,)


def register_properties():
    bpy.types.Scene.fppm = bpy.props.PointerProperty(
        type=FPPMRenderSettings, name="FPPM", description="FPPM render settings")


def unregister_properties():
    del bpy.types.Scene.fppm
