"""Scene arrays consumed by the renderer.

The add-on builds a :class:`Scene` from Blender's evaluated depsgraph
(``addon/export.py``, with ``core.scene.nodes`` turning shader nodes into
lobes); tests build one in plain Python.  Nothing here imports ``bpy``.

Conventions (shared by every ``core`` module)
--------------------------------------------
- World space is Blender's: right-handed, +Z up, metres.
- Colours are linear RGB, shape ``(3,)`` or ``(..., 3)``.
- Light quantities use Cycles' units (``docs/cycles_units.md``):
  ``Light.strength = color * energy * 2**exposure``.
- Images produced by ``core`` are ``(H, W, C)`` float32 with row 0 at the TOP.
  Texture images (as Blender stores them) have row 0 at the BOTTOM, uv (0, 0)
  at the bottom-left corner.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .textures import EnvironmentMap

# Lobe kinds (closures).  A material is a weighted sum of lobes, like Cycles'
# closure list after Mix/Add shaders are flattened.
DIFFUSE = 0       # Lambert (roughness 0) or Oren-Nayar (roughness > 0), f = color/pi
GLOSSY = 1        # GGX, alpha = roughness**2; roughness 0 = perfect mirror
GLASS = 2         # dielectric reflection + refraction with exact Fresnel
REFRACTION = 3    # dielectric refraction only (Cycles' Refraction BSDF)
TRANSPARENT = 4   # straight pass-through, weight = color
TRANSLUCENT = 5   # diffuse transmission (Cycles' Translucent BSDF)
LOBE_NAMES = {DIFFUSE: "diffuse", GLOSSY: "glossy", GLASS: "glass",
              REFRACTION: "refraction", TRANSPARENT: "transparent",
              TRANSLUCENT: "translucent"}
MAX_LOBES = 4


@dataclass(frozen=True)
class Lobe:
    """One closure of a material.

    kind: one of DIFFUSE, GLOSSY, GLASS, REFRACTION, TRANSPARENT, TRANSLUCENT.
    color: linear RGB reflectance/transmittance (Cycles' "Color" input).
    weight: scalar mix weight from Mix/Add shaders (Add may exceed 1).
    roughness: Cycles' roughness; GGX alpha = roughness**2.
    ior: index of refraction (GLASS / REFRACTION).
    color_texture: index into ``Scene.textures`` multiplying ``color``, or -1.

    Exact Cycles features (read by ``core.materials.build_material_table``;
    the defaults are plain single-scattering GGX / Lambert):
    multiscatter: Multiscatter GGX energy compensation (GLOSSY / GLASS; the
      'MULTI_GGX' distribution of the Glossy, Glass and Principled nodes).
    fresnel: '' | 'DIELECTRIC' | 'F82' | 'CONDUCTOR' (GLOSSY only; the
      Principled BSDF's layers, the Metallic BSDF).  'DIELECTRIC': colour =
      specular tint, f scaled by the generalised-Schlick Fresnel of
      ``fresnel_ior``.  'F82': colour = F0 of Cycles' F82-tint conductor
      with tint ``f82_tint`` (RGB in [0, 1]).  'CONDUCTOR': f scaled by the
      exact Fresnel of a conductor of IOR ``conductor_n`` + i
      ``conductor_k`` (RGB each; left out of the repr like alpha_texture).
    thin_film_thickness > 0.1 (nm), thin_film_ior: a thin film over a GLOSSY
      lobe with a ``fresnel`` (or over a DIFFUSE's specular layer): its
      Fresnel is the film's (core.materials.thin_film).  Left out of the
      repr like alpha_texture.
    layer_ior > 0: a DIFFUSE lying under a dielectric specular layer of that
      IOR, normal reflectance ``layer_f0``, roughness ``layer_roughness`` and
      ``layer_multiscatter``, scaled by 1 - the layer's albedo (Cycles'
      ``closure_layering_weight``).  The other layer_* fields are read only
      when layer_ior > 0, so set them together.
    alpha_texture >= 0: the lobe's colour is scaled by that texture's alpha
      a(uv), or by 1 - a(uv) when ``alpha_invert`` (an Image Texture's Alpha
      into the Principled Alpha or a Mix Shader's Fac: the Transparent lobe
      gets 1 - a, the others a).  Left out of the repr when unset (the
      ``scene_digest`` of scenes without them is unchanged).
    roughness_texture >= 0: the lobe's roughness (a layered DIFFUSE's
      ``layer_roughness``) is that texture's alpha r(uv) where the camera
      side reads a hit (core.materials.rough_maps), ``roughness`` its mean
      elsewhere.  Left out of the repr like alpha_texture.
    view: () or VIEW_SAMPLES floats: the lobe's weight is also scaled by a
      function of the view, sampled at mu = |w_o . n_s| = i / (VIEW_SAMPLES
      - 1) (a Mix Shader whose Fac a Fresnel or Layer Weight node computes;
      core.materials.table.view_factor interpolates it).  Left out of the
      repr like alpha_texture.
    """
    kind: int
    color: tuple = (0.8, 0.8, 0.8)
    weight: float = 1.0
    roughness: float = 0.0
    ior: float = 1.45
    color_texture: int = -1
    multiscatter: bool = False
    fresnel: str = ""
    fresnel_ior: float = 1.5
    f82_tint: tuple = (1.0, 1.0, 1.0)
    layer_ior: float = 0.0
    layer_f0: float = 0.0
    layer_roughness: float = 0.0
    layer_multiscatter: bool = False
    alpha_texture: int = field(default=-1, repr=False)
    alpha_invert: bool = field(default=False, repr=False)
    roughness_texture: int = field(default=-1, repr=False)
    view: tuple = field(default=(), repr=False)
    conductor_n: tuple = field(default=(), repr=False)
    conductor_k: tuple = field(default=(), repr=False)
    thin_film_thickness: float = field(default=0.0, repr=False)
    thin_film_ior: float = field(default=1.33, repr=False)


#: Samples of a lobe's view factor over mu = |w_o . n_s| in [0, 1] (Lobe.view).
VIEW_SAMPLES = 257


@dataclass(frozen=True)
class Material:
    """A flattened surface shader.

    lobes: up to MAX_LOBES closures, summed.
    emission: RGB radiance [W/(m^2 sr)] emitted from both sides (Cycles'
      Emission color * strength, times its mix weight).
    emission_texture: index into ``Scene.textures`` multiplying ``emission``, or -1.
    approximations: human-readable notes of what the exporter approximated.
    normal: a :class:`core.scene.normals.NormalInput` (Normal Map or Bump
      node feeding the shaders' Normal inputs) or None.
    holdout: the summed mix weight of the shader's Holdout closures (Cycles'
      ``surface_shader_apply_holdout``): the transparency camera rays take
      from the surface; they end there at 1 (core.scene.holdout).
    camera, shadow: the Material camera rays / shadow rays see instead, or
      None (a Light Path node's Is Camera Ray / Is Shadow Ray in the shader:
      core.scene.ray_variants; the exporter appends them to the scene's
      materials, ``Scene.material_camera`` / ``material_shadow``).
    absorption: (3,) the absorption coefficient sigma_a [1/m] of the
      homogeneous volume inside the surface (Cycles' Volume Absorption:
      density x (1 - color)), or () without one (core.scene.absorption).
    aovs: the values its AOV Output nodes write into the view layer's
      shader AOVs, ((name, rgb (3,), texture index or -1, scalar), ...):
      rgb times the texture's colour (scalar: its alpha channel, a Value
      AOV's image) (core.sppm.shader_aovs).
    """
    name: str
    lobes: tuple = (Lobe(DIFFUSE),)
    emission: tuple = (0.0, 0.0, 0.0)
    emission_texture: int = -1
    approximations: tuple = ()
    normal: object = field(default=None, repr=False)
    holdout: float = field(default=0.0, repr=False)
    camera: object = field(default=None, repr=False)
    shadow: object = field(default=None, repr=False)
    absorption: tuple = field(default=(), repr=False)
    aovs: tuple = field(default=(), repr=False)


@dataclass(frozen=True)
class Light:
    """A Blender light object in Cycles' units.

    kind: 'POINT', 'SPOT', 'SUN' or 'AREA'.
    strength: RGB, color * energy * 2**exposure (W for point/spot/area,
      W/m^2 for sun).
    matrix_world: (4, 4) float64 object-to-world, including scale (an area
      light's size is scaled by it).  Lights emit along local -Z.
    radius: point/spot ``shadow_soft_size`` [m].
    spot_size: full cone angle [rad]; spot_blend in [0, 1].
    angle: sun angular diameter [rad].
    shape: 'SQUARE', 'RECTANGLE', 'DISK' or 'ELLIPSE'; size, size_y [m].
    visible_camera / visible_glossy / visible_transmission: ray visibility
      (what the camera sees directly, and through mirror / glass chains);
      with visible_diffuse, the kinds of lobe its light samples light
      (core.lights.lobe_visibility).
    use_soft_falloff: point/spot with radius > 0 act as a disc facing the
      shading point (Cycles' default), giving I cos / (d^2 + r^2).
    link_sets: the receiver sets the light lights (light linking, a 64-bit
      mask: core.scene.linking; LINK_ALL without linking).
    shadow_sets: the blocker sets whose objects shadow the light (shadow
      linking, core.scene.shadow_linking; LINK_ALL without).
    ies: a point or spot light's IES profile (core.lights.ies.IesProfile,
      its values the factor on strength along each direction leaving the
      light, in the light's object frame), or None.
    """
    name: str
    kind: str
    strength: tuple
    matrix_world: np.ndarray
    radius: float = 0.0
    spot_size: float = np.pi / 4
    spot_blend: float = 0.15
    angle: float = 0.0
    shape: str = "SQUARE"
    size: float = 1.0
    size_y: float = 1.0
    spread: float = np.pi
    visible_camera: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    visible_diffuse: bool = True
    cast_shadow: bool = True
    use_soft_falloff: bool = True   # Cycles >= 4.0 point/spot default
    link_sets: int = field(default=(1 << 64) - 1, repr=False)
    shadow_sets: int = field(default=(1 << 64) - 1, repr=False)
    ies: object = field(default=None, repr=False)


@dataclass(frozen=True)
class Camera:
    """Blender camera parameters, evaluated.

    kind: 'PERSP' or 'ORTHO'.  matrix_world: (4, 4) float64; the camera looks
    along local -Z with +Y up.  lens, sensor_width, sensor_height in mm;
    sensor_fit 'AUTO', 'HORIZONTAL' or 'VERTICAL'; ortho_scale in metres;
    shift_x/shift_y in units of the larger sensor side (Blender's rule).
    resolution: (width, height) in pixels after the percentage is applied.
    pixel_aspect: (x, y) Blender pixel aspect.
    border: (min_x, min_y, max_x, max_y) in [0, 1] (Blender's, y up) or None.
    aperture_radius [m] and focus_distance [m] for depth of field (0 = pinhole).
    """
    kind: str = "PERSP"
    matrix_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    lens: float = 50.0
    sensor_width: float = 36.0
    sensor_height: float = 24.0
    sensor_fit: str = "AUTO"
    ortho_scale: float = 7.0
    shift_x: float = 0.0
    shift_y: float = 0.0
    clip_start: float = 0.1
    clip_end: float = 1000.0
    resolution: tuple = (64, 64)
    pixel_aspect: tuple = (1.0, 1.0)
    border: Optional[tuple] = None
    aperture_radius: float = 0.0
    focus_distance: float = 10.0


@dataclass
class Scene:
    """Everything the renderer needs, as arrays.

    tri_p: (T, 3, 3) float32 world-space corner positions.
    tri_n: (T, 3, 3) float32 unit shading normals per corner.
    tri_uv: (T, 3, 2) float32 UVs per corner (zeros when the mesh has none).
    tri_mat: (T,) int32 index into ``materials``.
    materials: list of Material.
    lights: list of Light.
    camera: Camera.
    world_color: (3,) float64 constant background radiance (with ``world_map``:
      the map's mean radiance, for plans and summaries).
    world_map: the world's Environment Texture
      (:class:`core.scene.textures.EnvironmentMap`) or None.
    world_camera_map: the world as camera rays see it when that differs
      from what lights the scene (a Light Path node in the world: Cycles'
      Is Camera Ray), or None; rays still on the camera ray's line (through
      transparent surfaces) that escape see it.
    approximations: what the exporter approximated or ignored, one sentence each.
    textures: list of (H, W, 3|4) float32 linear images, row 0 at the bottom.
    filter_width: Cycles' pixel filter width in pixels.
    filter_type: Cycles' pixel filter, 'BLACKMAN_HARRIS' (default), 'BOX' or
      'GAUSSIAN' (core.scene.camera).
    tri_object_index: (T,) int32 the object's pass index (IndexOB pass) or None (0).
    material_pass_index: (M,) int32 each material's pass index (IndexMA) or None (0).
    film_transparent: Film > Transparent (camera rays that escape give alpha 0).
    mist: (start, depth, falloff exponent) of the world's mist pass [m, m, 1].
    ao_distance: the world's ambient occlusion distance [m] (World >
      Settings > Ambient Occlusion > Distance: the Ambient Occlusion pass's
      rays, core.sppm.color_passes).
    tri_tangent: (T, 3, 4) float32 per-corner MikkTSpace tangent (xyz, unit)
      and bitangent sign (w, +-1; 0 = none: the triangle's dP/du is used), for
      Normal Map materials; or None.
    tri_visibility: (T,) uint8 the ray visibility of each triangle's object
      (``core.accel``'s RAY_* flags: Cycles' Object > Visibility > Ray
      Visibility), or None (every object seen by every ray).
    tri_holdout: (T,) bool the triangles of holdout objects (Object >
      Visibility > Holdout, or the collection's in the view layer), or None
      (core.scene.holdout).
    material_camera, material_shadow: (M,) int32 the material camera rays
      (on the camera ray's line) / shadow rays see in place of each one (its
      own index where they see it), or None (core.scene.ray_variants).
    material_receiver: (M,) uint8 the light-linking receiver set of each
      material's objects, and material_emitter (M,) uint64 the sets an
      emissive material's objects light (core.scene.linking: the exporter
      gives each combination a material of its own), or None (no linking).
    tri_blocker: (T,) uint8 the shadow-linking blocker set of each
      triangle's object, and tri_shadow_sets (T,) uint64 the blocker sets
      that shadow it as an emitter (core.scene.shadow_linking), or None (no
      shadow linking).
    tri_crypto: (T, 3) float32 each triangle's Cryptomatte IDs (object,
      material, asset: core.sppm.cryptomatte), and crypto_names {kind:
      names} the manifests, or None (no Cryptomatte pass asked for).
    shader_aovs: ((name, 'COLOR' | 'VALUE'), ...) the view layer's shader
      AOVs (core.sppm.shader_aovs).
    tri_catcher: (T,) bool the triangles of shadow catchers, or None (none
      is: core.sppm.shadow_catcher).
    world_hidden: the kinds of ray the world is hidden from (World > Ray
      Visibility: core.lights.lobe_visibility's DIFFUSE_RAYS | GLOSSY_RAYS |
      TRANSMISSION_RAYS bits; 0: seen by all).
    tri_render_uv: (T, 3, 3) float32 the render UV map at each corner and
      1 where the mesh has one (u, v, 1; else 0, 0, 0), for the UV pass
      (core.sppm.color_passes), or None (the pass is off).  tri_uv may hold
      other coordinates (a material's mapped vector, an atlas).
    tri_bump_scale: (T,) float32 the factor on each triangle's bump distance
      (a displacement's bump: its object's stretch along the normal, as
      Cycles transforms the displacement; ``addon/export.py``
      ``_Exporter.displacement_scales``), or None (1 everywhere).
    """
    tri_p: np.ndarray
    tri_n: np.ndarray
    tri_uv: np.ndarray
    tri_mat: np.ndarray
    materials: list
    lights: list
    camera: Camera
    world_color: np.ndarray = field(default_factory=lambda: np.zeros(3))
    textures: list = field(default_factory=list)
    filter_width: float = 1.5
    filter_type: str = "BLACKMAN_HARRIS"
    tri_object_index: Optional[np.ndarray] = None
    material_pass_index: Optional[np.ndarray] = None
    film_transparent: bool = False
    mist: tuple = (5.0, 25.0, 2.0)
    ao_distance: float = 10.0
    world_map: Optional[EnvironmentMap] = None
    world_camera_map: Optional[EnvironmentMap] = None
    approximations: tuple = ()
    tri_tangent: Optional[np.ndarray] = None
    tri_visibility: Optional[np.ndarray] = None
    tri_holdout: Optional[np.ndarray] = None
    material_receiver: Optional[np.ndarray] = None
    material_emitter: Optional[np.ndarray] = None
    material_camera: Optional[np.ndarray] = None
    material_shadow: Optional[np.ndarray] = None
    tri_blocker: Optional[np.ndarray] = None
    tri_shadow_sets: Optional[np.ndarray] = None
    tri_crypto: Optional[np.ndarray] = None
    crypto_names: Optional[dict] = None
    shader_aovs: tuple = ()
    tri_catcher: Optional[np.ndarray] = None
    world_hidden: int = 0
    tri_render_uv: Optional[np.ndarray] = None
    tri_bump_scale: Optional[np.ndarray] = None

    def __post_init__(self):
        self.attach_shading_normals()

    def __setstate__(self, state: dict) -> None:
        # Unpickling (a Dask worker's copy of the scene, tools/distributed.py)
        # and copy.copy do not run __post_init__: attach the shading normals
        # to the new tri_n array here, or its Normal Map / Bump inputs would
        # be lost (the attachment is keyed by the array, not pickled with it).
        self.__dict__.update(state)
        self.attach_shading_normals()

    def attach_shading_normals(self) -> None:
        """Let ``core.accel.surface_point`` perturb this scene's shading normals
        by its materials' Normal Map / Bump inputs (``core.scene.normals``).
        Called on construction; call again after replacing the triangle
        arrays or materials in place.  The spec is attached to the tri_n
        array: scenes sharing one (``dataclasses.replace``) share the last
        constructed one's, so give a scene with other materials its own copy."""
        from . import normals
        inputs = tuple(getattr(m, "normal", None) for m in self.materials)
        if not any(inp is not None for inp in inputs):
            normals.attach(self.tri_n, None)
            return
        normals.attach(self.tri_n, normals.ShadingSpec(
            tri_p=self.tri_p, tri_n=self.tri_n, tri_uv=self.tri_uv, tri_mat=self.tri_mat,
            tri_tangent=self.tri_tangent, inputs=inputs, textures=self.textures,
            tri_bump_scale=self.tri_bump_scale))

    @property
    def n_triangles(self) -> int:
        return int(self.tri_p.shape[0])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds of the geometry and the camera, float64 (3,) each."""
        pts = [self.camera.matrix_world[:3, 3][None, :]]
        if self.n_triangles:
            pts.extend(triangle_bounds(self.tri_p))
        for lt in self.lights:
            if lt.kind != "SUN":
                pts.append(np.asarray(lt.matrix_world, np.float64)[:3, 3][None, :])
        allp = np.concatenate(pts, axis=0)
        return allp.min(axis=0), allp.max(axis=0)

    def diameter(self) -> float:
        """Scene diameter D used for every relative epsilon (docs/frequency.md)."""
        lo, hi = self.bounds()
        return float(max(np.linalg.norm(hi - lo), 1e-30))


#: id(tri_p) -> (a weak reference to tri_p, its lo (1, 3), hi (1, 3)).
_TRI_BOUNDS: dict = {}


def triangle_bounds(tri_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (1, 3) float64 the corners' bounds of triangles tri_p (T, 3, 3),
    computed once an array: a renderer's set-up reads the scene's bounds
    several times (the diameter, the recentring, the light table, the
    float32 check; 0.25 s each at a million triangles), and the viewport's
    renderers share the arrays of one export (addon/viewport.py).  The
    float32 extremes converted are the float64 extremes of the converted
    corners: the same bounds as before.  Arrays are not changed in place
    once exported (a new export makes new ones)."""
    key = id(tri_p)
    got = _TRI_BOUNDS.get(key)
    if got is not None and got[0]() is tri_p:
        return got[1], got[2]
    flat = tri_p.reshape(-1, 3)
    lo = flat.min(axis=0).astype(np.float64)[None, :]
    hi = flat.max(axis=0).astype(np.float64)[None, :]
    try:
        ref = weakref.ref(tri_p, lambda _r, k=key: _TRI_BOUNDS.pop(k, None))
    except TypeError:           # not weak-referenceable: not kept
        return lo, hi
    _TRI_BOUNDS[key] = (ref, lo, hi)
    return lo, hi


def make_scene(tri_p, materials, lights, camera, tri_mat=None, tri_n=None,
               tri_uv=None, world_color=(0.0, 0.0, 0.0), textures=()):
    """Convenience constructor for tests: fills flat normals and zero UVs.

    tri_p: (T, 3, 3) array-like.  Returns a :class:`Scene`.
    """
    tri_p = np.asarray(tri_p, np.float32).reshape(-1, 3, 3)
    T = tri_p.shape[0]
    if tri_n is None:
        e1 = tri_p[:, 1] - tri_p[:, 0]
        e2 = tri_p[:, 2] - tri_p[:, 0]
        ng = np.cross(e1.astype(np.float64), e2.astype(np.float64))
        ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
        tri_n = np.repeat(ng[:, None, :], 3, axis=1)
    if tri_uv is None:
        tri_uv = np.zeros((T, 3, 2), np.float32)
    if tri_mat is None:
        tri_mat = np.zeros(T, np.int32)
    return Scene(tri_p=tri_p, tri_n=np.asarray(tri_n, np.float32).reshape(T, 3, 3),
                 tri_uv=np.asarray(tri_uv, np.float32).reshape(T, 3, 2),
                 tri_mat=np.asarray(tri_mat, np.int32).reshape(T),
                 materials=list(materials), lights=list(lights), camera=camera,
                 world_color=np.asarray(world_color, np.float64),
                 textures=list(textures))


def drop_invalid_triangles(scene: Scene) -> tuple[Scene, int]:
    """Remove triangles with NaN/Inf corners or zero area; return (scene, dropped).

    Zero area is relative: |e1 x e2| <= (1e-7 * longest edge)^2 (so millimetre
    and kilometre meshes are treated alike).  Non-finite shading normals are
    replaced by the geometric normal, non-finite UVs by 0.
    """
    P = scene.tri_p.astype(np.float64)
    finite = np.all(np.isfinite(P.reshape(P.shape[0], -1)), axis=1)
    Pz = np.where(np.isfinite(P), P, 0.0)
    e1 = Pz[:, 1] - Pz[:, 0]
    e2 = Pz[:, 2] - Pz[:, 0]
    e3 = Pz[:, 2] - Pz[:, 1]
    cross = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest = np.sqrt(np.maximum.reduce([(e1 * e1).sum(1), (e2 * e2).sum(1), (e3 * e3).sum(1)]))
    ok = finite & (cross > (1e-7 * longest) ** 2) & (longest > 0)
    dropped = int((~ok).sum())
    tri_n = scene.tri_n
    bad_n = ~np.all(np.isfinite(tri_n.reshape(tri_n.shape[0], -1)), axis=1) | \
        np.any(np.linalg.norm(tri_n, axis=2) < 1e-6, axis=1)
    tri_uv = scene.tri_uv
    if np.any(bad_n[ok]) or not np.all(np.isfinite(tri_uv)) or dropped:
        ng = np.cross(e1, e2)
        ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
        tri_n = np.where(bad_n[:, None, None], ng[:, None, :].astype(np.float32), tri_n)
        tri_uv = np.where(np.isfinite(tri_uv), tri_uv, 0.0).astype(np.float32)
        scene = Scene(tri_p=scene.tri_p[ok], tri_n=tri_n[ok], tri_uv=tri_uv[ok],
                      tri_mat=scene.tri_mat[ok], materials=scene.materials,
                      lights=scene.lights, camera=scene.camera, world_color=scene.world_color,
                      textures=scene.textures, filter_width=scene.filter_width,
                      filter_type=scene.filter_type,
                      tri_object_index=None if scene.tri_object_index is None
                      else scene.tri_object_index[ok],
                      material_pass_index=scene.material_pass_index,
                      film_transparent=scene.film_transparent, mist=scene.mist,
                      world_map=scene.world_map, world_camera_map=scene.world_camera_map,
                      approximations=scene.approximations,
                      tri_tangent=None if scene.tri_tangent is None else scene.tri_tangent[ok],
                      tri_visibility=None if scene.tri_visibility is None
                      else scene.tri_visibility[ok],
                      tri_holdout=None if scene.tri_holdout is None else scene.tri_holdout[ok],
                      material_receiver=scene.material_receiver,
                      material_emitter=scene.material_emitter,
                      material_camera=scene.material_camera,
                      material_shadow=scene.material_shadow,
                      tri_blocker=None if scene.tri_blocker is None else scene.tri_blocker[ok],
                      tri_shadow_sets=None if scene.tri_shadow_sets is None
                      else scene.tri_shadow_sets[ok],
                      tri_crypto=None if scene.tri_crypto is None else scene.tri_crypto[ok],
                      crypto_names=scene.crypto_names, shader_aovs=scene.shader_aovs,
                      tri_catcher=None if scene.tri_catcher is None else scene.tri_catcher[ok],
                      world_hidden=scene.world_hidden, ao_distance=scene.ao_distance,
                      tri_render_uv=None if scene.tri_render_uv is None
                      else scene.tri_render_uv[ok],
                      tri_bump_scale=None if scene.tri_bump_scale is None
                      else scene.tri_bump_scale[ok])
    return scene, dropped


def scene_digest(scene: Scene) -> str:
    """Stable hash of everything that changes the image (geometry, materials,
    lights, camera, world, textures); used to refuse a stale checkpoint."""
    import hashlib
    h = hashlib.sha256()
    for a in (scene.tri_p, scene.tri_n, scene.tri_uv, scene.tri_mat,
              np.asarray(scene.world_color, np.float64)):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr(scene.materials).encode())
    # Fields left out of the reprs (only when set: older checkpoints keep their digest).
    extra = [(i, m.normal) for i, m in enumerate(scene.materials)
             if getattr(m, "normal", None) is not None]
    extra += [(i, j, lb.alpha_texture, lb.alpha_invert) for i, m in enumerate(scene.materials)
              for j, lb in enumerate(m.lobes) if getattr(lb, "alpha_texture", -1) >= 0]
    extra += [(i, j, "roughness", lb.roughness_texture) for i, m in enumerate(scene.materials)
              for j, lb in enumerate(m.lobes) if getattr(lb, "roughness_texture", -1) >= 0]
    extra += [(i, j, "view", lb.view) for i, m in enumerate(scene.materials)
              for j, lb in enumerate(m.lobes) if getattr(lb, "view", ())]
    extra += [(i, j, "conductor", lb.conductor_n, lb.conductor_k)
              for i, m in enumerate(scene.materials) for j, lb in enumerate(m.lobes)
              if getattr(lb, "conductor_n", ())]
    extra += [(i, j, "film", lb.thin_film_thickness, lb.thin_film_ior)
              for i, m in enumerate(scene.materials) for j, lb in enumerate(m.lobes)
              if getattr(lb, "thin_film_thickness", 0.0) > 0.0]
    extra += [(i, "holdout", m.holdout) for i, m in enumerate(scene.materials)
              if getattr(m, "holdout", 0.0)]
    extra += [(i, "absorption", m.absorption) for i, m in enumerate(scene.materials)
              if getattr(m, "absorption", ())]
    extra += [(i, "aovs", m.aovs) for i, m in enumerate(scene.materials)
              if getattr(m, "aovs", ())]
    if getattr(scene, "shader_aovs", ()):
        extra.append(("shader_aovs", scene.shader_aovs))
    if getattr(scene, "world_hidden", 0):
        extra.append(("world_hidden", scene.world_hidden))
    if extra:
        h.update(repr(extra).encode())
    if scene.tri_tangent is not None:
        h.update(np.ascontiguousarray(scene.tri_tangent).tobytes())
    if scene.tri_visibility is not None:
        h.update(b"visibility" + np.ascontiguousarray(scene.tri_visibility).tobytes())
    if getattr(scene, "tri_holdout", None) is not None:
        h.update(b"holdout" + np.ascontiguousarray(scene.tri_holdout).tobytes())
    for name in ("material_camera", "material_shadow"):
        if getattr(scene, name, None) is not None:
            h.update(name.encode() + np.ascontiguousarray(getattr(scene, name)).tobytes())
    if getattr(scene, "material_receiver", None) is not None:
        h.update(b"linking" + np.ascontiguousarray(scene.material_receiver).tobytes()
                 + np.ascontiguousarray(scene.material_emitter).tobytes())
    for name in ("tri_blocker", "tri_shadow_sets", "tri_crypto", "tri_catcher", "tri_render_uv",
                 "tri_bump_scale"):
        if getattr(scene, name, None) is not None:
            h.update(name.encode() + np.ascontiguousarray(getattr(scene, name)).tobytes())
    unset = {"link_sets": (1 << 64) - 1, "shadow_sets": (1 << 64) - 1, "visible_diffuse": True}
    for lt in scene.lights:
        # (the fields of ``unset`` only when set: older checkpoints keep their digest)
        h.update(repr({k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
                       for k, v in lt.__dict__.items()
                       if k != "ies" and (k not in unset or v != unset[k])}).encode())
        if getattr(lt, "ies", None) is not None:
            for a in lt.ies:
                h.update(b"ies" + np.ascontiguousarray(a, np.float64).tobytes())
    cam = scene.camera
    h.update(repr({k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
                   for k, v in cam.__dict__.items()}).encode())
    for t in scene.textures:
        h.update(np.ascontiguousarray(t).tobytes())
        if getattr(t, "sampler", 0):     # (only when set: older checkpoints keep their digest)
            h.update(b"sampler %d" % t.sampler)
    h.update(repr(scene.filter_width).encode())
    if scene.filter_type != "BLACKMAN_HARRIS":   # (older checkpoints keep their digest)
        h.update(scene.filter_type.encode())
    if scene.film_transparent:      # (only when set: older checkpoints keep their digest)
        h.update(b"film_transparent")
    if scene.world_map is not None:
        h.update(scene.world_map.digest_bytes())
    if scene.world_camera_map is not None:
        h.update(b"camera")
        h.update(scene.world_camera_map.digest_bytes())
    return h.hexdigest()[:16]
