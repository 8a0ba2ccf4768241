"""The render plan: analyse the exported scene once and leave out what it cannot use.

Each flag says whether a stage runs; ``reasons`` says why a stage was
left out, so the CLI, Blender's info log and the EXR metadata can show it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .lights.pdf import bsdf_hittable
from .lights.shadow import transparent_materials
from .lights.table import AREA, MESH, POINT, SPOT, SUN
from .materials import glossy_only, used_lobes
from .scene.model import TRANSPARENT
from .settings import RenderSettings

# Convexity test budget: triangles x vertices pairs checked exactly.
_CONVEX_TEST_MAX = 4_000_000


@dataclass
class RenderPlan:
    specular_chains: bool = True       # camera paths through mirrors / glass
    glossy_chains: bool = False        # PHOTON: camera paths through glossy-only materials
    light_samples: int = 1             # PHOTON: next-event estimates per visible point and pass
    frequency_photons: bool = True     # photons carrying a spectrum (a, b, c)
    occlusion_grid: bool = True        # voxel grid for a_occ (needs frequency)
    world_emission: bool = False
    transparent_shadows: bool = False  # shadow rays pass transparent surfaces (core.lights.shadow)
    emitter_kinds: tuple = ()
    aovs: tuple = ()
    strategies: tuple = ("photon mapping",)   # what estimates the image (docs/integrators.md)
    left_out: list = field(default_factory=list)   # (stage, reason)

    def lines(self) -> list[str]:
        on = [n for n, v in (("specular chains", self.specular_chains),
                             ("glossy chains", self.glossy_chains),
                             ("frequency photons", self.frequency_photons),
                             ("occlusion grid", self.occlusion_grid),
                             ("world emission", self.world_emission)) if v]
        bare = "plain photon mapping"
        if "photon mapping" not in self.strategies and not merges(self):
            on, bare = [], "no photon stages"
        if self.transparent_shadows:
            on.append("transparent shadows")
        if self.light_samples > 1:
            on.append(f"{self.light_samples} light samples")
        out = [f"Plan: {', '.join(on) if on else bare}; strategies: {', '.join(self.strategies)}; "
               f"emitters: {', '.join(self.emitter_kinds) or 'none'}; "
               f"AOVs: {', '.join(self.aovs) or 'none'}."]
        for stage, why in self.left_out:
            out.append(f"Left out: {stage} ({why}).")
        return out

    def metadata(self) -> dict:
        return {"fppm/plan": " ".join(self.lines())}


def _can_occlude(tri_p: np.ndarray, light_points=None, distant_light=False) -> bool:
    """False when nothing can occlude the light field: all triangles coplanar,
    or a set of faces that all see each other (every vertex on one side of
    every face plane: the inside or outside of one convex object) with every
    local light on that same side.  A sun or world light comes from outside
    any such set, so with one only the single-plane case is left out."""
    T = tri_p.shape[0]
    if T <= 1:
        return False
    P = tri_p.astype(np.float64)
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    # Size check first: np.unique sorts every vertex (2 s at 500k triangles),
    # and a scene that large almost surely occludes.
    if T * 3 * T > 4 * _CONVEX_TEST_MAX:
        return True
    V = np.unique(P.reshape(-1, 3), axis=0)
    if T * V.shape[0] > _CONVEX_TEST_MAX:
        return True
    ext = float(np.ptp(V, axis=0).max()) or 1.0
    eps = 1e-6 * ext
    s = V @ n.T - np.einsum("ij,ij->i", n, P[:, 0])[None, :]    # (V, T)
    if np.all(np.abs(s) <= eps):
        return False                                              # one plane
    if distant_light:
        return True
    if light_points is not None and len(light_points):
        Lp = np.asarray(light_points, np.float64).reshape(-1, 3)
        s = np.concatenate([s, Lp @ n.T - np.einsum("ij,ij->i", n, P[:, 0])[None, :]])
    all_behind = np.all(s <= eps) or np.all(s >= -eps)
    return not all_behind


#: The strategy name of photon merging in integrator 'COMBINED'.
MERGING = "photon merging (caustics seen through mirrors and glass)"
#: The same with merge_weights 'MIS' (core.integrators.merge): merging is
#: weighted against the other strategies on every path it can sample.
MERGING_MIS = "photon merging (MIS: light reaching diffuse or glossy surfaces indirectly)"


def merges(plan: "RenderPlan") -> bool:
    """Whether the plan merges photons (either kind of weights)."""
    return MERGING in plan.strategies or MERGING_MIS in plan.strategies


def _one_plane(tri_p: np.ndarray) -> bool:
    """True when every vertex lies in the first triangle's plane: no surface
    can light another (no indirect light without a delta vertex)."""
    P = np.asarray(tri_p, np.float64).reshape(-1, 3)
    if P.shape[0] < 3:
        return True
    n = np.cross(P[1] - P[0], P[2] - P[0])
    n /= max(float(np.linalg.norm(n)), 1e-300)
    eps = 1e-6 * (float(np.ptp(P, axis=0).max()) or 1.0)
    return bool(np.all(np.abs((P - P[0]) @ n) <= eps))

STAGES = ("specular chains", "glossy chains", "frequency photons", "occlusion grid")


def with_camera_stop(strategies: tuple, stop, samples: int) -> tuple:
    """strategies with the camera-path entry restated once 'COMBINED' knows
    where light tracing takes its camera paths over (stop: the light
    tracer's ``combined.CameraStop``, decided after the plan because
    'AUTO' reads a pilot of light paths; docs/integrators.md "Camera
    depth"); samples: camera rays per pixel and pass."""
    if stop.camera_free:
        text = ("camera paths: none (every material diffuse or rough: light tracing "
                "takes every path, emitters seen directly included)")
    elif stop.alone:
        text = (f"camera paths: rays to the emitters seen directly only, {samples} per "
                f"pixel and pass (light tracing takes every longer path)")
    else:
        text = (f"camera paths (path tracing and next-event estimation, {samples} per "
                f"pixel and pass) stop at vertex {stop.depth} on diffuse or rough "
                f"materials (light tracing takes the longer paths)")
    return tuple(text if s.startswith("camera paths") else s for s in strategies)


def merges_photons(settings: RenderSettings, has_delta: bool, has_nondelta: bool, tri_p,
                   seen: bool) -> bool:
    """Whether COMBINED merges photons (make_plan; core/warmup.py asks it
    before a render's tables exist).  has_delta / has_nondelta: some
    material has a mirror or glass lobe / a diffuse or glossy one; tri_p
    the triangles' vertices; seen: light tracing has a surface or emitter
    the camera sees (it is whenever has_nondelta)."""
    if settings.merge_weights == "MIS" and seen:
        # Merging as an MIS strategy samples every path whose light reaches
        # the visible point (a non-delta vertex) after at least one bounce
        # (core.integrators.merge): through a mirror or glass, or off
        # another diffuse or glossy surface -- any scene but one plane.  It
        # needs light tracing's paths (its deposits).
        return has_nondelta and (has_delta or not _one_plane(tri_p))
    # Merging owns the paths whose camera end is a delta chain to a
    # non-delta point lit through a delta vertex (core.integrators.merge):
    # none without both kinds of material.
    return has_delta and has_nondelta


#: Next-event estimates per visible point and pass where the direct light is
#: random (settings.light_samples 0): each visible point costs a camera ray
#: and a share of the photon pass, a light sample far less, so a pass
#: spends a little more to take the light samples' noise down (docs/method.md
#: "Light samples at the visible points, round 31": 4 was best of 1, 2, 4, 8
#: on the Cornell box at 128^2 and 200,000 photons at equal CPU).
AUTO_LIGHT_SAMPLES = 4
#: Photons per pixel and pass from which the automatic count is
#: AUTO_LIGHT_SAMPLES, and from which it is 2 (below: 1).  The best count
#: goes as the square root of the ratio of the photons' noise to the light
#: samples' (Veach's cost-variance balance), and a pixel's photon noise as
#: one over its photons: 4 at 12 photons a pixel (128^2 at 200,000), so
#: about 2 at 3 (256^2) and 1 below 1 (1080p: 0.1, where the photons' noise
#: hides what more light samples would take away; docs/method.md).
AUTO_LIGHT_SAMPLES_DENSITY = (8.0, 2.0)


def _lit(light_table) -> np.ndarray:
    """(Nl,) bool: the emitters of nonzero power."""
    return np.any(light_table.flux > 0, axis=1)


def auto_light_samples(light_table, photons_per_pixel: float) -> int:
    """settings.light_samples 0's count: 1 where a visible point's light
    sample is the same every pass (one emitter of nonzero power, a point or
    spot of radius 0 or a sun of angle 0, and no environment map: nothing to
    average); else AUTO_LIGHT_SAMPLES, 2 or 1 by the photons a pixel gets a
    pass (AUTO_LIGHT_SAMPLES_DENSITY)."""
    lit = _lit(light_table)
    if light_table.environment is None and lit.sum() == 1 and not bsdf_hittable(light_table)[lit].any():
        return 1
    many, two = AUTO_LIGHT_SAMPLES_DENSITY
    return AUTO_LIGHT_SAMPLES if photons_per_pixel >= many else 2 if photons_per_pixel >= two else 1


def casts_small_caustics(mtab, light_table) -> bool:
    """Whether a point, spot or sun light (of any radius or angle: small
    against the scene) shines in a scene with a mirror or glass lobe that
    bends light (a delta lobe of nonzero weight and colour other than
    Transparent's straight crossing): its caustics may fall on any surface."""
    small = np.isin(light_table.kind, (POINT, SPOT, SUN)) & _lit(light_table)
    if not mtab.kind.size or not np.any(small):
        return False
    return bool((used_lobes(mtab) & mtab.lobe_delta & (mtab.kind != TRANSPARENT)).any())


def make_plan(scene, settings: RenderSettings, mtab, light_table, force=()) -> RenderPlan:
    """Decide the stages from the scene.  ``force``: stage names kept even when
    the scene does not need them (to check that leaving them out changes
    nothing); a stage switched off by the settings stays off."""
    unknown = set(force) - set(STAGES)
    if unknown:
        raise ValueError(f"unknown stage(s) {sorted(unknown)}; known: {STAGES}")
    plan = RenderPlan()
    has_delta = bool(np.any(mtab.has_delta)) if mtab.has_delta.size else False
    has_nondelta = bool(np.any(mtab.has_nondelta)) if mtab.has_nondelta.size else False
    merging = False
    if settings.integrator == "PATH":
        plan.strategies = (f"camera paths (path tracing, next-event estimation and MIS, "
                           f"{settings.camera_samples} per pixel and pass)",)
    if settings.integrator == "COMBINED":
        # Light tracing ends on a non-delta surface the camera sees (or on an
        # area / mesh emitter it sees); without any it has nothing to splat.
        seen = (bool(np.any(mtab.has_nondelta)) if mtab.has_nondelta.size else False) or bool(
            np.any(((light_table.kind == MESH) | (light_table.kind == AREA))
                   & light_table.visible_camera))
        # And it follows the emitters it draws (integrators.mis.light_classes:
        # not the sun's, the world's or lights hidden from glossy or
        # transmission rays, whose light the camera paths take alone).
        from .integrators.mis import NO_LT, light_classes
        traced = bool(np.any(light_classes(light_table) != NO_LT))
        plan.strategies = (f"camera paths (path tracing and next-event estimation, "
                           f"{settings.camera_samples} per pixel and pass)",)
        if seen and traced:
            plan.strategies += ("light tracing",)
        else:
            plan.left_out.append(("light tracing", "no diffuse or glossy surface for the "
                                                   "camera to see" if not seen else
                                  "shadow rays pass an object (its Shadow visibility off, or "
                                  "a Light Path node's Is Shadow Ray), light paths would not: "
                                  "the camera paths take every light"
                                  if getattr(light_table, "shadow_passes", False) else
                                  "camera rays see a material as another (a Light Path node's "
                                  "Is Camera Ray), light paths would not: the camera paths "
                                  "take every light"
                                  if getattr(light_table, "camera_variants", False) else
                                  "no emitter it traces: the sun and the world are the "
                                  "camera paths'"))
        seen = seen and traced
        plan.strategies += ("power-heuristic MIS",)
        merging = merges_photons(settings, has_delta, has_nondelta, scene.tri_p, seen)
        if settings.merge_weights == "MIS" and seen:
            if merging:
                plan.strategies += (MERGING_MIS,)
            else:
                plan.left_out.append(("photon merging", "no diffuse or glossy surface to "
                                                        "gather on" if not has_nondelta else
                                      "no light reaches a surface indirectly (one plane, "
                                      "no mirror or glass)"))
        else:
            if merging:
                plan.strategies += (MERGING,)
            else:
                plan.left_out.append(("photon merging", "no mirror or glass to see a caustic "
                                                        "through" if has_nondelta else
                                      "no diffuse or glossy surface to gather on"))
    # Glossy chains (core.sppm.visible_points): photon mapping's camera paths
    # go on through materials without a diffuse lobe, with next-event
    # estimation at each vertex; classic PPM's settings keep one vertex.
    plan.glossy_chains = (settings.integrator == "PHOTON" and settings.glossy_chains
                          and not settings.fixed_visible_points
                          and not settings.photons_for_direct
                          and bool(glossy_only(mtab).any()) if mtab.kind.size else False)
    if (plan.glossy_chains and "glossy chains" not in force
            and casts_small_caustics(mtab, light_table)):
        # A glossy point's chain reaches a point, spot or sun light through a
        # mirror or glass only by hitting it: never at radius 0, as fireflies
        # when small.  The visible point on the glossy surface gathers that
        # caustic's photons instead (docs/method.md "Caustics on glossy
        # surfaces keep their visible points, round 31").
        plan.glossy_chains = False
        plan.left_out.append(("glossy chains", "a point, spot or sun light and a mirror or "
                                               "glass: their caustics on glossy surfaces are "
                                               "gathered there"))
    if settings.integrator == "PHOTON" and not settings.photons_for_direct:
        W, H = scene.camera.resolution
        plan.light_samples = settings.light_samples or auto_light_samples(
            light_table, settings.photons_per_pass / max(1, int(W) * int(H)))
    plan.specular_chains = has_delta or "specular chains" in force
    if not plan.specular_chains:
        plan.left_out.append(("specular chains", "no mirror, glass or transparent material"))
    freq = settings.use_frequency and settings.frequency_fraction > 0
    if settings.integrator != "PHOTON" and not merging:
        freq = False
        plan.left_out.append(("frequency photons",
                              f"no photon mapping (integrator {settings.integrator})"))
    elif not settings.use_frequency:
        plan.left_out.append(("frequency photons", "frequency analysis is off"))
    elif settings.frequency_fraction <= 0:
        plan.left_out.append(("frequency photons", "frequency fraction is 0"))
    elif not np.any(mtab.has_nondelta) and "frequency photons" not in force:
        # Any non-delta lobe is a receiver whose radius can be held
        # (core.frequency.kernels.Receivers); only mirrors and glass cannot.
        freq = False
        plan.left_out.append(("frequency photons", "no diffuse or glossy receiver whose radius "
                                                   "could be held"))
    plan.frequency_photons = freq
    local = [np.asarray(lt.matrix_world, np.float64)[:3, 3] for lt in scene.lights
             if lt.kind != "SUN"]
    distant = any(lt.kind == "SUN" for lt in scene.lights) or bool(
        np.any(np.asarray(scene.world_color) > 0))
    occ = freq and (_can_occlude(scene.tri_p, local, distant) or "occlusion grid" in force)
    if freq and not occ:
        plan.left_out.append(("occlusion grid", "nothing in the scene can occlude another surface"))
    elif not freq:
        plan.left_out.append(("occlusion grid", "no frequency photons"))
    plan.occlusion_grid = occ
    plan.world_emission = bool(np.any(np.asarray(scene.world_color) > 0))
    # Shadow rays follow through Transparent BSDFs and alpha cut-outs; without
    # any, they stay one occlusion test (core.lights.shadow).
    # Every integrator: a transparent crossing is no vertex of the MIS
    # weights (PATH, COMBINED's both sides) nor of merging's partition.
    plan.transparent_shadows = bool(transparent_materials(mtab).any()) if mtab.kind.size else False
    kinds = sorted({lt.kind for lt in scene.lights})
    if np.any(mtab.emission.max(axis=1) > 0):
        kinds.append("MESH")
    if plan.world_emission:
        kinds.append("WORLD")
    plan.emitter_kinds = tuple(kinds)
    plan.aovs = tuple(n for n in ("aov_radius", "aov_predicted_radius", "aov_spectrum",
                                  "aov_photon_count", "aov_held") if getattr(settings, n))
    return plan
