"""Blender's evaluated depsgraph -> ``core.scene.Scene``.

Read from the EVALUATED depsgraph, so modifiers, geometry nodes, collection
instances, drivers and the current frame are already applied:

- geometry: every instance of ``depsgraph.object_instances`` with geometry,
  loop triangles with split (corner) normals, the render UV map and material
  indices, all through ``foreach_get`` into numpy (no per-vertex Python);
  transformed by the instance's ``matrix_world``;
- lights in Cycles' units (docs/cycles_units.md):
  strength = colour x energy x 2^exposure (x blackbody colour when enabled);
- the world as a constant colour (Background colour x strength) or an
  equirectangular Environment Texture with its Mapping / Texture Coordinate;
- what is ignored or approximated: one table, :data:`FEATURE_CHECKS`, plus the
  notes of materials and the world, gathered in ``Scene.approximations``;
- the camera, with sensor fit, shift, clip, border, resolution percentage and
  depth of field as Cycles computes them;
- materials by walking the node tree from the active Material Output's Surface.

Everything unsupported is approximated, never fatal: one warning line per
material, then one summary line of what was exported and one of what was
approximated.  Degenerate/NaN triangles are dropped and counted.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ..core.accel import RAY_ALL, RAY_CAMERA, RAY_FLAGS, RAY_SHADOW
from ..core.scene import color_ops as CO
from ..core.scene.camera import CameraModel
from ..core.scene import nodes as shading
from ..core.errors import MemoryBudgetError, RenderCancelled, SceneError
from ..core.lights.environment import mean_radiance
from ..core.scene.normals import BUMP, NORMAL_MAP, NormalInput
from ..core.scene.textures import (EXTENSIONS, INTERPOLATIONS, LINEAR, REPEAT,
                                   EnvironmentMap, UnassociatedImage, resample,
                                   sampler_code, scalar_weights, with_sampler)
from ..core.scene.model import (DIFFUSE, GLASS, GLOSSY, MAX_LOBES, REFRACTION, TRANSLUCENT,
                          TRANSPARENT, VIEW_SAMPLES, Camera, Light, Lobe, Material, Scene,
                          drop_invalid_triangles)
from ..core.scene import shader_graph as SG
from .export_atlas import AtlasBaker, needs_atlas
from .export_graph import GRAPH_NODES, GraphReader, constant_value
from .export_light_nodes import light_nodes
from .export_links import light_link_sets
from .world_bake_job import CAMERA_RAY, LIGHTING_RAY, SHADOW_RAY
from ..core.scene.holdout import see_through
from ..core.scene.linking import LINK_ALL, split_materials
from ..core.materials.table import is_delta_lobe
from ..core.scene.ray_variants import clear_shadows
from ..core.sppm import cryptomatte as crypto
from .export_displace import TrueDisplacement, displace
from .export_read import (CHUNK, _follow, _never, _use_nodes, corner_topology, image_pixels,
                          mesh_arrays, remove_image, sequence_frame, sequence_image,
                          tile_image)

GEOMETRY_TYPES = {'MESH', 'CURVE', 'SURFACE', 'FONT', 'META'}
# An image under a nonlinear colour node is enlarged UPSAMPLE_FACTOR times
# (textures.upsample), while its larger side stays within UPSAMPLE_MAX.
UPSAMPLE_FACTOR, UPSAMPLE_MAX = 8, 2048
# What Cycles' Image Texture reads without pixels (TEX_IMAGE_MISSING_R, _G, _B).
# Colour nodes folded into an image's texels or a constant (_MaterialBuilder.color_chain).
MISSING_IMAGE = (1.0, 0.0, 1.0)   # Cycles' colour of a missing image
_COLOR_NODES = {'RGB', 'MIX', 'MIX_RGB', 'HUE_SAT', 'BRIGHTCONTRAST', 'GAMMA', 'INVERT',
                'CURVE_RGB', 'VALTORGB', 'RGBTOBW'}
GREY = (0.8, 0.8, 0.8)
DEFAULT_MATERIAL = Material(name="(no material)", lobes=(Lobe(DIFFUSE, GREY),))
NO_LIGHTS = "The scene has no lights: add a light, an emissive material or a world colour."
WORLD_BAKING = ("The world is being baked by Cycles; the scene has no other light: the "
                "render starts when the bake is done.")
NO_CAMERA = "The scene has no camera: add a camera and set it as the scene camera."
NOTHING_VISIBLE = ("Nothing is visible to render: the scene has no mesh objects enabled "
                   "for rendering (check 'Disable in Renders' and ray visibility).")



# Image formats whose pixels Blender holds as float (4 bytes a channel);
# any other is 1 byte a channel until it is read through Image.pixels.
_FLOAT_BYTES = 4


def _file_image_header(path: str) -> tuple[int, int, int] | None:
    """(width, height, bytes a pixel Blender will hold) from a PNG or JPEG
    file's header, read without decoding it; None for other formats or
    unreadable files.  Blender holds 8-bit images as RGBA bytes (4 a pixel)
    and 16-bit PNGs as RGBA float (16 a pixel)."""
    import struct
    try:
        with open(path, "rb") as fh:
            head = fh.read(26)
            if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
                w, h, depth = struct.unpack(">IIB", head[16:25])
                return w, h, 16 if depth == 16 else 4
            if head[:2] == b"\xff\xd8":
                fh.seek(2)
                while True:
                    m = fh.read(4)
                    if len(m) < 4 or m[0] != 0xFF:
                        return None
                    size = struct.unpack(">H", m[2:])[0]
                    if 0xC0 <= m[1] <= 0xCF and m[1] not in (0xC4, 0xC8, 0xCC):
                        h, w = struct.unpack(">HH", fh.read(5)[1:])
                        return w, h, 4
                    fh.seek(size - 2, 1)
    except (OSError, struct.error):
        return None
    return None


# ---------------------------------------------------------------------------
# small helpers

# What the exporter does with each Blender feature, as data for the README's
# "What FPPM supports" table, the UI (addon/ui.py hides the panels of ignored
# features) and tests/test_support_table.py.  Rows: (feature, status, message),
# status "supported", "approximated" or "ignored"; message is the text the
# exporter logs in its "Approximated:" / "Warning:" lines (a template, as in the
# code below or core/scene/nodes.py), or "" when nothing is said because no
# panel offers the feature under FPPM.
SUPPORTED, APPROXIMATED, IGNORED = "supported", "approximated", "ignored"
SUPPORT = (
    ("meshes, curves, surfaces, text, metaballs (evaluated: modifiers, geometry nodes, "
     "instances)", SUPPORTED, ""),
    ("split normals, the render UV map", SUPPORTED, ""),
    ("perspective and orthographic cameras, depth of field, border, resolution %",
     SUPPORTED, ""),
    ("point, spot, sun and area lights (every shape, spread), colour, temperature, "
     "power, exposure, radius, soft falloff, Normalize, cast shadow", SUPPORTED, ""),
    ("light ray visibility: camera, diffuse, glossy, transmission (its light samples leave "
     "the lobes of the hidden kinds out, as Cycles; BSDF rays and mirror or glass chains of "
     "those kinds do not see it), and an emissive object's diffuse, glossy and transmission "
     "visibility in its light samples", SUPPORTED, ""),
    ("photons and light paths of a light or the world hidden from diffuse, glossy or "
     "transmission rays: a "
     "first hit with only such lobes stops them; a first bounce off a material with lobes "
     "of both kinds keeps every lobe", APPROXIMATED,
     "a first bounce off a material with lobes of both kinds keeps every lobe"),
    ("world Background colour x strength; mist pass settings", SUPPORTED, ""),
    ("world Environment Texture (equirectangular) with Mapping and Texture Coordinate "
     "(Generated, Object): HDRI lighting, importance-sampled", SUPPORTED, ""),
    ("any other world shader (Sky Texture, procedural textures, Mix Shader, a linked "
     "Strength, mirror-ball projection): baked by Cycles into a 2048 x 1024 map when the "
     "render starts, a Sky Texture's sun disc into a sun light", SUPPORTED, ""),
    ("Diffuse, Glossy, Glass, Refraction, Transparent, Translucent, Emission, Mix Shader, "
     "Add Shader, Principled BSDF; RGB, Value and Image Texture inputs", SUPPORTED, ""),
    ("Metallic BSDF: F82 Tint (Base Color, Edge Tint) and Physical Conductor (the exact "
     "Fresnel of IOR + i Extinction per channel), GGX and Multiscatter GGX", SUPPORTED, ""),
    ("thin-film iridescence (Thin Film Thickness and IOR) on the Principled BSDF's specular "
     "layer and metal and on the Metallic BSDF: Cycles' Airy sum over the CIE 1931 "
     "matching functions in linear Rec.709", SUPPORTED, ""),
    ("Normal Map (tangent space, MikkTSpace tangents of the render UV map, OpenGL and "
     "DirectX) and Bump (Strength, Distance, Invert) from an Image Texture", SUPPORTED, ""),
    ("Mapping (Point, Texture, Vector), Texture Coordinate (UV, Generated, Object, and "
     "Camera and Window in the material's atlas) and UV Map (any UV map of a mesh) into "
     "Image Texture and procedural texture vectors; the Camera Data node (View Vector, "
     "View Z Depth, View Distance)", SUPPORTED, ""),
    ("Image Texture interpolation (Linear, Closest, Cubic, Smart as Cubic) and extension "
     "(Repeat, Extend, Clip, Mirror)", SUPPORTED, ""),
    ("Image Texture projection: Box (with its blend, over the object-space normal), Sphere, "
     "Tube (the material baked into an atlas)", SUPPORTED, ""),
    ("UDIM images (tiles from files named with <UDIM> or <UVTILE>, or packed): each tile "
     "over its own unit square of uv, Cycles' missing-image magenta where there is no tile "
     "(the material baked into an atlas)", SUPPORTED, ""),
    ("an Attribute node of type Instancer (geometry nodes' instance attributes, which "
     "Python cannot read)", APPROXIMATED, "ignored"),
    ("a UDIM tile with no file (or, in a packed image, no packed data)", APPROXIMATED,
     "could not be read (no file or packed data): magenta"),
    ("image sequences: the file of the render's frame (the node's Frames, Start Frame, "
     "Offset and Cyclic, as Blender counts them)", SUPPORTED, ""),
    ("an image's colour (also through colour nodes: its luminance) or alpha into a Mix "
     "Shader's Fac, the Principled Alpha or Metallic, or an emission's Strength, per hit",
     SUPPORTED, ""),
    ("image alpha into the Principled Alpha or a Mix Shader's Fac (stochastic "
     "pass-through of camera and photon paths; shadow rays pass cut-outs and Transparent "
     "BSDFs with Cycles' weights in every integrator, docs/shading.md); "
     "the colour associated with alpha as Cycles reads it", SUPPORTED, ""),
    ("colour nodes between an Image Texture (or constants) and a colour input: Mix "
     "(Color) and MixRGB (every blend type) with one side constant or two images read at "
     "the same point, Hue/Saturation/Value, Brightness/Contrast, Gamma, Invert, RGB "
     "Curves, RGB to BW, Color Ramp (applied to the image's texels; a small image is enlarged first "
     "for the nonlinear ones); their factors (Fac, Hue, Value, Gamma, ..., a Mix's Factor) "
     "fed by other nodes, a mask image or a texture: per point, the material baked into "
     "an atlas", SUPPORTED, ""),
    ("procedural textures (Noise, Voronoi, Wave, Magic, Brick, Checker, Gradient, White "
     "Noise; every dimension, type and feature) at any vector (Generated, Object, UV, "
     "Mapping, a vector another texture distorts), into any input an image feeds (colour, "
     "roughness, metallic, alpha, emission, bump, normal map), also through colour and "
     "converter nodes and mixed with images: the material's textures baked into a texture "
     "atlas over its triangles when the render starts", SUPPORTED, ""),
    ("converter nodes between textures and inputs: Math, Vector Math, Map Range, Clamp, "
     "Mix (float, vector, colour), Separate / Combine XYZ and Color (RGB, HSV, HSL), "
     "Vector Rotate, Vector Transform, Float Curve, RGB to BW, a Color Ramp's Alpha, "
     "Blackbody, Wavelength, "
     "with Cycles' kernels; an image through them alone is baked over its own uvs",
     SUPPORTED, ""),
    ("colour attributes (Color Attribute and Attribute nodes: point, corner or face "
     "domain), Attribute nodes of type Object (a custom property or RNA path of the object, "
     "then of its data) and View Layer (of the view layer, the scene, the world), "
     "Geometry Position, Normal, True Normal, Pointiness and Random Per Island "
     "(computed from the mesh as Cycles' sync does), Texture Coordinate Normal, Object Info "
     "(Location, Color, Alpha, Object Index, Material Index, Random as Cycles syncs it), in "
     "texture graphs", SUPPORTED, ""),
    ("images read at different vectors in one material (each at its own: baked into the "
     "material's atlas)", SUPPORTED, ""),
    ("a procedural texture's input fed by another node (a Scale from a Math node)",
     APPROXIMATED, "its value used"),
    ("a texture graph whose evaluation fails (an error in a port): that texture grey",
     APPROXIMATED, "could not be evaluated"),
    ("an atlas material on more than 1.8 M triangles (not shared by instances): one value "
     "a triangle", APPROXIMATED, "one value a triangle (atlas budget)"),
    ("a material atlas over the budget of 4 M texels (very many triangles, or very fine "
     "detail over a large surface)", APPROXIMATED, "of their detail (atlas budget)"),
    ("a Mix Shader whose Fac depends on the view: a Fresnel node, a Layer Weight's Fresnel or Facing output, also through converter and colour nodes with constant inputs (Math, Map Range, Color Ramp, ...): each lobe weighed per hit as Cycles weighs it on the camera side (photons and light paths at their arrival)", SUPPORTED, ""),
    ("a Mix Shader Fac of the view and the surface point (a texture times a Fresnel)", APPROXIMATED, "a Fac of the view and the surface point read as its value"),
    ("node groups (flattened, nested)", SUPPORTED, ""),
    ("film transparency, pixel filter (Blackman-Harris, Box, Gaussian) and its width, "
     "object and material pass index (every "
     "integrator but Light Tracing, whose film is opaque)", SUPPORTED, ""),
    ("shader AOVs (AOV Output nodes: a constant or an Image Texture, also through colour "
     "nodes, at the camera ray's first hit; every integrator but Light Tracing)", SUPPORTED, ""),
    ("Cryptomatte (Object, Material, Asset, Levels): Cycles' IDs, coverage through "
     "Transparent BSDFs and manifests, in the render result and the CLI's EXR (every "
     "integrator but Light Tracing)", SUPPORTED, ""),
    ("the Diffuse, Glossy and Transmission Color passes (each kind of closure's albedo as "
     "Cycles estimates it, summed along the camera ray's line through Transparent BSDFs), "
     "the Environment, Ambient Occlusion (the world's AO distance) and UV passes (every "
     "integrator but Light Tracing)",
     SUPPORTED, ""),
    ("other shader nodes", APPROXIMATED, "unsupported node(s) "),
    ("other nodes linked into an input (the input's value is used)", APPROXIMATED,
     "'{src.name}' into {node.name}.{name} ignored"),
    ("an Image Texture into a scalar input other than a Mix Shader's Fac, the "
     "Principled Alpha, Metallic and Roughness, a Glossy, Glass or Refraction Roughness "
     "and an emission's Strength (IOR, Coat Roughness, ..., and a Metallic beside a "
     "textured Alpha): the image's mean over its pixels, not per hit", APPROXIMATED,
     "the image's mean"),
    ("a roughness map into a Principled, Glossy, Glass or Refraction Roughness (an "
     "image's Color or Alpha, also through colour nodes): per hit, in 256 levels uniform in "
     "log alpha, roughness 0.01 at least", SUPPORTED, ""),
    ("more than one roughness map in a material (a Mix Shader of two mapped BSDFs)",
     APPROXIMATED, "the others at their mean"),
    ("photon bounces on normal-mapped or bumped surfaces", APPROXIMATED,
     "photons scatter off the interpolated normal"),
    ("Normal Map in object or world space", APPROXIMATED, "space ignored (tangent space only)"),
    ("Normal Map or Bump fed by an Image Texture or a procedural texture through colour "
     "nodes (a Color Ramp into a Bump's Height)", SUPPORTED, ""),
    ("Normal Map or Bump fed by other nodes", APPROXIMATED, "is not an Image Texture: ignored"),
    ("different Normal inputs on the shaders of one material", APPROXIMATED,
     "applied to all"),
    ("different vector inputs on the image textures of one material that reach them "
     "through a node group's input", APPROXIMATED, "used for all"),
    ("Beckmann / Ashikhmin-Shirley distributions", APPROXIMATED,
     "{node.name}: {dist} distribution rendered as GGX"),
    ("more closures than a material holds", APPROXIMATED,
     "closures cut to the {MAX_LOBES} heaviest"),
    ("Principled subsurface", APPROXIMATED, "rendered as diffuse"),
    ("object ray visibility: camera (camera rays, also through transparent surfaces, and light tracing's joins to the lens pass the object) and shadow (shadow rays pass it, and the first segment of photons and light paths lands both on it and behind it; Combined then takes every light by its camera paths)", SUPPORTED, ""),
    ("object ray visibility: glossy and transmission for the rays a mirror or glass (or a "
     "glossy-only material's chain) casts on the camera side (Photon Mapping, Path Tracing, "
     "Combined)", SUPPORTED, ""),
    ("object ray visibility: diffuse, and glossy and transmission for photons, light paths and "
     "the camera paths' rough bounces", APPROXIMATED, "treated as visible"),
    ("holdout: objects (Object > Visibility > Holdout, a collection's Holdout in the view "
     "layer; an instance takes its instancer's) and the Holdout shader, also mixed or added "
     "with constant Facs: camera rays, also through transparent surfaces, end there and "
     "leave the film transparent (alpha, with either film, as Cycles writes it); every other "
     "ray sees the object's material; light tracing splats nothing there", SUPPORTED, ""),
    ("a holdout object whose material lets light through (a Transparent BSDF, an image's "
     "alpha): held out by 1 - its transparency at each hit, camera rays passing on through "
     "its Transparent closures alone, as Cycles", SUPPORTED, ""),
    ("a Holdout shader mixed by an image's alpha (half and half) or a view factor (its "
     "value at normal incidence)", APPROXIMATED, "a Holdout mixed by"),
    ("stereo 3D / multi-view", APPROXIMATED, "every view is rendered from the scene camera"),
    ("Light Path's Is Camera Ray in a world shader (two maps: what camera rays see, what "
     "lights the scene)", SUPPORTED, ""),
    ("Light Path's Is Camera Ray and Is Shadow Ray as a Mix Shader's Fac in a material: "
     "camera rays (also through transparent surfaces) and shadow rays each see their own "
     "mix, in every integrator (Combined then takes every light by its camera paths); a "
     "white Transparent BSDF for shadow rays (the glass-shadow trick) makes the object "
     "shadowless, whose rule photons and light paths follow too", SUPPORTED, ""),
    ("Light Path's other outputs as a Mix Shader's Fac in a material", APPROXIMATED,
     "read as a diffuse ray's by every ray but camera and shadow rays"),
    ("a material shadow rays see as a tinted or textured Transparent BSDF (Is Shadow Ray): "
     "photons and light paths see the material itself", APPROXIMATED,
     "photons and light paths see the material itself"),
    ("Light Path's other outputs in a world shader", APPROXIMATED,
     "read as a diffuse ray's by every ray but the camera's"),
    ("a world shader whose bake fails", APPROXIMATED, "could not be baked by Cycles"),
    ("Principled sheen", IGNORED, "ignored: no sheen lobe"),
    ("anisotropy", IGNORED, "anisotropy ignored"),
    ("thin-film iridescence on a Principled BSDF's transmission (its specular layer and "
     "metal, and the Metallic BSDF, have it)", IGNORED,
     "thin-film iridescence on the transmission ignored"),
    ("a Volume Absorption of constant Color and Density in a material's Volume (coloured "
     "glass, liquids): Beer-Lambert attenuation of every ray inside the closed surface, "
     "shadow rays through transparent surfaces included, as Cycles' volume stack for volumes "
     "that neither nest nor overlap", SUPPORTED, ""),
    ("a material with a Volume and no Surface: its boundary lets every ray through, as in "
     "Cycles", SUPPORTED, ""),
    ("volumes that scatter, emit or vary (Volume Scatter, Principled Volume, a textured or "
     "mixed volume shader)", IGNORED, "volume ignored"),
    ("material displacement: a Displacement node's Height (an image or a texture graph) as "
     "the bump Cycles renders by default (Displacement method Bump Only)", SUPPORTED, ""),
    ("true displacement (Displacement method Displacement Only, and Displacement and Bump "
     "with the bump over it): the mesh's vertices moved by the Displacement node's Height "
     "(an image or a texture graph) along their normals, in object or world space, each by "
     "its first triangle, the displaced mesh's normals recomputed (corner normals moved by "
     "their vertex's change), as Cycles; at the mesh's own resolution (a Subdivision "
     "Surface modifier's)", SUPPORTED, ""),
    ("true displacement on curves, surfaces, text and metaballs", APPROXIMATED,
     "true displacement applies to meshes"),
    ("a true displacement whose Height is no texture graph FPPM evaluates", APPROXIMATED,
     "true displacement ignored"),
    ("a Displacement beside a Bump node on the shaders' Normal", APPROXIMATED,
     "displacement ignored beside a Bump node"),
    ("Vector Displacement, or other nodes into the Displacement", APPROXIMATED,
     "into the Displacement ignored"),
    ("a light's nodes: an Emission node's Color and Strength, and an IES Texture (a Text "
     "datablock or an .ies file; photometric types A, B and C) into its Strength on point and "
     "spot lights: the profile read, oriented and interpolated as Cycles, in light samples, "
     "rays that meet the light and photons", SUPPORTED, ""),
    ("other light nodes, a linked Emission Color, an IES Texture's linked Vector or Strength",
     IGNORED, "light nodes ignored"),
    ("an IES profile on a sun or area light", IGNORED, "an IES profile on a"),
    ("an IES file that cannot be read (Cycles then multiplies the light by 100)", APPROXIMATED,
     "IES profile not read"),
    ("hair curves", IGNORED, "not rendered"),
    ("motion blur", IGNORED, "motion blur ignored"),
    ("light linking (an emitter's Receiver Collection, Include and Exclude, nested "
     "collections, lights and emissive objects): its light samples, the emission its camera "
     "paths' BSDF rays find and its photons' and light paths' first hits reach only the "
     "objects it lights, as Cycles' receiver sets; seen directly it is always seen",
     SUPPORTED, ""),
    ("shadow linking (an emitter's Blocker Collection, Include and Exclude, lights and "
     "emissive objects): its light samples, photons and light paths pass the objects that do "
     "not block it, which it still lights, as Cycles' blocker sets; its light at a rough "
     "surface comes from light samples alone (Cycles: both strategies, the same expectation)",
     APPROXIMATED, "a mirror or glass in front of the emitter shows it only where no object "
                   "stands between them"),
    ("shadow catcher (Object > Visibility > Mask): the Combined pass the matte with the "
     "catcher's shadow composed as Cycles composes it (its alpha with Film > Transparent, over "
     "the world otherwise; the matte and its alpha with the Shadow Catcher pass on), the "
     "shadow the catcher's light over its light in a scene without the other objects, for "
     "camera rays whose first hit is a catcher (every integrator but Light Tracing)",
     APPROXIMATED, "no light between catchers); the matte at its silhouettes approximated"),
    ("volume objects", IGNORED, "volume object(s) not rendered"),
    ("adaptive subdivision", IGNORED, ""),
    ("clamping", IGNORED, ""),
    ("light groups", IGNORED, ""),
    ("the Direct and Indirect light passes and the Shadow pass", IGNORED, ""),
    ("light probes", IGNORED, ""),
    ("material and sample override", IGNORED, ""),
    ("camera and distance culling", IGNORED, ""),
    ("shadow terminator, caustics flags", IGNORED, ""),
    ("world ray visibility: camera (camera rays that escape see black, or film transparency; the world still lights the scene)", SUPPORTED, ""),
    ("world ray visibility: diffuse, glossy, transmission (the world's light samples leave "
     "those lobes out, Cycles' closure exclusion; a mirror's or glass's ray sees it by its "
     "Glossy and Transmission flags)", SUPPORTED, ""),
    ("world ray visibility: volume scatter (FPPM renders no scattering volume)", IGNORED,
     "world: volume scatter ray visibility has no effect"),
    ("EEVEE material settings", IGNORED, ""),
)


def _mat4(m) -> np.ndarray:
    return np.array(m, dtype=np.float64).reshape(4, 4)


def _linear(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3) float64 rows A @ v_i.

    einsum rather than ``v @ A.T``: numpy's matmul on (N, 3) x (3, 3) is
    ~10x slower here (2 s for 3 M points against 0.2 s).
    """
    return np.einsum("ij,nj->ni", A, v.astype(np.float64))


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 decoding, elementwise (float32 in, float32 out)."""
    c = np.asarray(c, np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _object_info(inst, ob, output) -> np.ndarray:
    """(3,) float64 an Object Info node's output for this instance, as Cycles
    syncs it: Location the world translation, Color / Alpha the object's
    colour, Object Index its pass index, Random ``random_id / (2^32 - 1)``
    in float32 with the instance's random_id, or for an object of its own
    ``hash_uint2(hash_string(name), 0)``."""
    if output == 'Location':
        return _mat4(inst.matrix_world)[:3, 3].copy()
    if output == 'Color':
        return np.array(tuple(ob.color)[:3], np.float64)
    if output == 'Alpha':
        return np.full(3, float(ob.color[3]))
    if output == 'Object Index':
        return np.full(3, float(getattr(ob, "pass_index", 0)))
    from ..core.scene.cycles_hash import hash_string, hash_uint2
    rid = (int(inst.random_id) & 0xFFFFFFFF if inst.is_instance
           else int(hash_uint2(hash_string(ob.name), 0)))
    return np.full(3, float(np.float32(rid) * np.float32(1.0 / 4294967295.0)))


def _property_value(idb, path):
    """(4,) float64 a property of ID ``idb`` at RNA ``path`` as Cycles reads
    it (blender/object.cc ``lookup_property``): a number or boolean as (v,
    v, v, 1), a vector of 1 to 4 numbers into (0, 0, 0, 1); None for
    another type or no such property."""
    try:
        v = idb.path_resolve(path)
    except (ValueError, TypeError, AttributeError):
        return None
    if isinstance(v, (bool, int, float)):
        return np.array([float(v)] * 3 + [1.0])
    try:
        vals = [float(x) for x in v]
    except (TypeError, ValueError):
        return None
    if not 1 <= len(vals) <= 4:
        return None
    out = np.array([0.0, 0.0, 0.0, 1.0])
    out[:len(vals)] = vals
    return out


def id_attribute(ids, name) -> np.ndarray:
    """(4,) float64 an Attribute node's Object or View Layer value: the
    first of ``ids`` (an object, then its data; or the view layer, scene,
    world) holding ``name`` as a custom property, else as an RNA path
    (custom properties first, as in Cycles); zeros when none does."""
    for idb in ids:
        if idb is None:
            continue
        for path in (f'["{name}"]', name):
            v = _property_value(idb, path)
            if v is not None:
                return v
    return np.zeros(4)


def _geometry_corners(me, kind):
    """(T, 3, 3) float64 Pointiness or Random Per Island (``kind``
    'Pointiness', 'RandomPerIsland') of mesh ``me`` at its loop triangles'
    corners, as (f, f, f)."""
    from ..core.scene import mesh_attributes as MA
    V, E, T = len(me.vertices), len(me.edges), len(me.loop_triangles)
    edges = np.empty(E * 2, np.int64)
    me.edges.foreach_get("vertices", edges)
    tri_v = _triangle_corners(me, vertices=True).reshape(T, 3)
    if kind == 'RandomPerIsland':
        f = MA.random_per_island(V, edges, tri_v[:, 0])
        return np.broadcast_to(f[:, None, None], (T, 3, 3)).copy()
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    nv = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("normal", nv)
    f = MA.pointiness(co.reshape(V, 3), nv.reshape(V, 3), edges)
    return np.repeat(f[tri_v][:, :, None], 3, axis=2)


def _triangle_corners(me, vertices=False) -> np.ndarray:
    """(3 T,) int32 the loop triangles' corners (loops), or with
    ``vertices`` their vertices."""
    corners = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("loops", corners)
    if not vertices:
        return corners
    vidx = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", vidx)
    return vidx[corners]


def _attribute_corners(me, name):
    """(T, 3, 3) float64 mesh attribute ``name`` (None: the render colour
    attribute) at the loop triangles' corners, or None."""
    if name is None:
        ca = me.color_attributes
        idx = getattr(ca, "render_color_index", -1)
        at = ca[idx] if 0 <= idx < len(ca) else None
    else:
        at = me.attributes.get(name)
    if at is None or not len(me.loop_triangles):
        return None
    fields = {'FLOAT_COLOR': ("color", 4), 'BYTE_COLOR': ("color", 4),
              'FLOAT_VECTOR': ("vector", 3), 'FLOAT2': ("vector", 2), 'FLOAT': ("value", 1),
              'INT': ("value", 1), 'BOOLEAN': ("value", 1)}
    if at.data_type not in fields or at.domain not in ('POINT', 'CORNER', 'FACE'):
        return None
    field, c = fields[at.data_type]
    n = len(at.data)
    raw = np.empty(n * c, np.float64 if at.data_type != 'BOOLEAN' else bool)
    at.data.foreach_get(field, raw)
    vals = raw.astype(np.float64).reshape(n, c)
    vals = np.repeat(vals, 3, axis=1) if c == 1 else vals[:, :3]
    if vals.shape[1] == 2:
        vals = np.concatenate([vals, np.zeros((n, 1))], axis=1)
    T = len(me.loop_triangles)
    if at.domain == 'FACE':
        poly = np.empty(T, np.int32)
        me.loop_triangles.foreach_get("polygon_index", poly)
        return np.repeat(vals[poly][:, None, :], 3, axis=1)
    return vals[_triangle_corners(me, at.domain == 'POINT')].reshape(T, 3, 3)


def _spec_key(spec) -> tuple:
    """A hashable key of a vector spec (source, object, A (4, 4))."""
    src, ob, A = spec
    return (src, ob, tuple(np.round(np.asarray(A, np.float64), 9).ravel()))


def _all_nodes(tree, depth: int = 0):
    """Every node of a node tree and of the groups it uses, depth first."""
    for nd in tree.nodes:
        yield nd
        if nd.type == 'GROUP' and nd.node_tree is not None and depth < 32:
            yield from _all_nodes(nd.node_tree, depth + 1)


def _mapping_matrix(node, notes) -> np.ndarray:
    """(4, 4) affine map of a Mapping node as Cycles' ``svm_mapping`` applies
    it to a point: POINT R S v + L, TEXTURE S^-1 R^T (v - L), VECTOR R S v,
    NORMAL R S^-1 v (not renormalised here); R the Euler XYZ rotation."""
    from mathutils import Euler
    if any(node.inputs[k].is_linked for k in ("Location", "Rotation", "Scale")
           if node.inputs.get(k) is not None):
        notes.append(f"linked inputs of '{node.name}' ignored")
    R = np.array(Euler(tuple(node.inputs["Rotation"].default_value), 'XYZ').to_matrix(),
                 np.float64)
    sc = np.array(node.inputs["Scale"].default_value, np.float64) \
        if node.inputs.get("Scale") is not None else np.ones(3)
    loc = np.array(node.inputs["Location"].default_value, np.float64) \
        if node.inputs.get("Location") is not None else np.zeros(3)
    with np.errstate(divide="ignore"):
        s_inv = np.where(sc != 0, 1.0 / np.where(sc != 0, sc, 1.0), 0.0)
    M = np.eye(4)
    vt = node.vector_type
    if vt == 'TEXTURE':
        M[:3, :3] = np.diag(s_inv) @ R.T
        M[:3, 3] = -M[:3, :3] @ loc
    elif vt == 'NORMAL':
        M[:3, :3] = R @ np.diag(s_inv)
    else:
        M[:3, :3] = R @ np.diag(sc)
        if vt == 'POINT':
            M[:3, 3] = loc
    return M


# ---------------------------------------------------------------------------
# materials

def _curve_xs(lo: float, hi: float) -> list:
    """Where the sync evaluates a curve spanning [lo, hi]: lo + (i / size)
    (hi - lo) in float32 (``curvemapping_*_to_array``)."""
    f = np.float32
    return [float(f(lo) + f(t) * (f(hi) - f(lo))) for t in CO.table_positions()]


def curves_op(node, fac: float) -> tuple:
    """An RGB Curves node as a ``color_ops`` "curves" op: Cycles' table
    (curvemapping_color_to_array) over the curves' span of x, each
    channel's curve after the combined one."""
    cm = node.mapping
    cm.update()
    lo = min(cv.points[0].location[0] for cv in cm.curves)
    hi = max(cv.points[-1].location[0] for cv in cm.curves)
    table = []
    for t in _curve_xs(lo, hi):
        x = cm.evaluate(cm.curves[3], t)
        table.append(tuple(float(cm.evaluate(cm.curves[j], x)) for j in range(3)))
    return ("curves", tuple(table), lo, (hi - lo) or 1.0, cm.extend == 'EXTRAPOLATED', fac)


def float_curve_params(node) -> tuple:
    """A Float Curve's (table, min_x, range_x, extrapolate), as Cycles syncs
    it (curvemapping_float_to_array): its curve at the table's positions
    over the span of its points' x."""
    cm = node.mapping
    cm.update()
    cv = cm.curves[0]
    lo, hi = cv.points[0].location[0], cv.points[-1].location[0]
    table = tuple(float(cm.evaluate(cv, t)) for t in _curve_xs(lo, hi))
    return table, float(lo), float(hi - lo) or 1.0, cm.extend == 'EXTRAPOLATED'


def _ramp_table(node) -> list:
    """A Color Ramp's rgba at the table's positions (colorramp_to_array)."""
    cr = node.color_ramp
    return [tuple(float(x) for x in cr.evaluate(t)) for t in CO.table_positions()]


def ramp_alpha_params(node) -> tuple:
    """A Color Ramp's (alpha table, interpolate), beside :func:`ramp_op`."""
    return (tuple(c[3] for c in _ramp_table(node)),
            node.color_ramp.interpolation != 'CONSTANT')


def ramp_op(node) -> tuple:
    """A Color Ramp node as a ``color_ops`` "ramp" op (Blender's ramp at
    the table's positions, which Cycles interpolates)."""
    return ("ramp", tuple(c[:3] for c in _ramp_table(node)),
            node.color_ramp.interpolation != 'CONSTANT')


def _emission_sum(parts, notes):
    """Sum of weighted emissions [(weight, Material)] -> (rgb, texture index)."""
    em = np.zeros(3)
    texs = {m.emission_texture for w, m in parts if w > 0 and m.emission_texture >= 0
            and any(m.emission)}
    for w, m in parts:
        em += w * np.asarray(m.emission, np.float64)
    tex = min(texs) if texs else -1
    if len(texs) > 1 or (texs and any(w > 0 and m.emission_texture < 0 and any(m.emission)
                                      for w, m in parts)):
        notes.append("emission textures mixed with other emission: one texture applied to all")
    return tuple(float(x) for x in em), tex


def _holdout_sum(parts) -> float:
    """Sum of weighted Holdout closures [(weight, Material)] (Cycles sums
    the holdout closures' weights, core.scene.holdout)."""
    return float(sum(w * m.holdout for w, m in parts))


def _mix(a: Material, b: Material, fac: float, name: str) -> Material:
    """(1 - fac) A + fac B, like Cycles' Mix Shader (fac clamped to [0, 1])."""
    fac = min(max(float(fac), 0.0), 1.0)
    lobes, notes = shading.mix_materials(a.lobes, b.lobes, fac)
    notes = list(a.approximations) + list(b.approximations) + list(notes)
    em, tex = _emission_sum([(1.0 - fac, a), (fac, b)], notes)
    return Material(name, tuple(lobes), em, tex, tuple(notes),
                    holdout=_holdout_sum([(1.0 - fac, a), (fac, b)]))


def _mix_by_view(a: Material, b: Material, view, name: str) -> Material:
    """Mix Shader whose Fac is a function of the view (view (VIEW_SAMPLES,),
    ``_MaterialBuilder.view_fac``): (1 - f) A + f B per lobe
    (``Lobe.view``); an emission mixed by the factor at normal incidence."""
    lobes, notes = shading.mix_by_view(a.lobes, b.lobes, view)
    notes = list(a.approximations) + list(b.approximations) + list(notes)
    f1 = float(np.clip(view[-1], 0.0, 1.0))
    em, tex = _emission_sum([(1.0 - f1, a), (f1, b)], notes)
    if any(em):
        notes.append("emission mixed by a Fresnel or Layer Weight at normal incidence")
    held = _holdout_sum([(1.0 - f1, a), (f1, b)])
    if a.holdout or b.holdout:
        notes.append("a Holdout mixed by a Fresnel or Layer Weight at normal incidence")
    return Material(name, tuple(lobes), em, tex, tuple(notes), holdout=held)


def _uses_normal_map(inp) -> bool:
    """A NormalInput that is, or sits on, a tangent-space Normal Map."""
    while inp is not None:
        if inp.kind == NORMAL_MAP:
            return True
        inp = inp.base
    return False


def _mix_by_alpha(a: Material, b: Material, texture: int, name: str) -> Material:
    """Mix Shader whose Fac is an image's alpha a(uv): (1 - a) A + a B."""
    lobes, notes = shading.mix_by_alpha(a.lobes, b.lobes, texture)
    notes = list(a.approximations) + list(b.approximations) + list(notes)
    em, tex = _emission_sum([(0.5, a), (0.5, b)], notes)
    if any(em):
        notes.append("emission mixed by an image alpha: mixed half and half")
    if a.holdout or b.holdout:
        notes.append("a Holdout mixed by an image alpha: mixed half and half")
    return Material(name, tuple(lobes), em, tex, tuple(notes),
                    holdout=_holdout_sum([(0.5, a), (0.5, b)]))


def _add(a: Material, b: Material, name: str) -> Material:
    """A + B, like Cycles' Add Shader."""
    lobes, notes = shading.add_materials(a.lobes, b.lobes)
    notes = list(a.approximations) + list(b.approximations) + list(notes)
    em, tex = _emission_sum([(1.0, a), (1.0, b)], notes)
    return Material(name, tuple(lobes), em, tex, tuple(notes),
                    holdout=_holdout_sum([(1.0, a), (1.0, b)]))


def _seen_by(m: Material, kind: str) -> Material:
    """The material rays of ``kind`` ('camera', 'shadow') see for m."""
    return getattr(m, kind) or m


def _with_variants(op, a: Material, b: Material, *args) -> Material:
    """op(a, b, *args), and the same op of what camera rays and shadow
    rays see of a and b where either differs (a Light Path inside them)."""
    out = op(a, b, *args)
    kw = {k: op(_seen_by(a, k), _seen_by(b, k), *args) for k in ("camera", "shadow")
          if getattr(a, k) is not None or getattr(b, k) is not None}
    return dataclasses.replace(out, **kw) if kw else out


#: The Light Path outputs FPPM reads per ray kind (world_bake_job's
#: LIGHTING_RAY: every other ray, read as a diffuse ray).
EXACT_LIGHT_PATH = ("Is Camera Ray", "Is Shadow Ray")


def _mix_by_ray(a: Material, b: Material, output: str, name: str, notes: list,
                node_name: str) -> Material:
    """A Mix Shader whose Fac is the Light Path output ``output``: camera
    rays (also through transparent surfaces) see it mixed at CAMERA_RAY's
    value, shadow rays at SHADOW_RAY's, every other ray at LIGHTING_RAY's
    (core.scene.ray_variants)."""
    def fac(values):
        return min(max(float(values.get(output, 0.0)), 0.0), 1.0)
    if output not in EXACT_LIGHT_PATH:
        notes.append(f"{node_name}: Light Path {output} read as a diffuse ray's by every ray "
                     f"but camera and shadow rays")
    out = _with_variants(_mix, a, b, fac(LIGHTING_RAY), name)
    kw = {}
    for kind, values in (("camera", CAMERA_RAY), ("shadow", SHADOW_RAY)):
        v = _mix(_seen_by(a, kind), _seen_by(b, kind), fac(values), name)
        kw[kind] = None if v == dataclasses.replace(out, camera=None, shadow=None) else v
    return dataclasses.replace(out, **kw)


class _MaterialBuilder:
    """Converts one Blender material's node tree; collects notes as it goes."""

    def __init__(self, exporter: "_Exporter", mat):
        self.ex = exporter
        self.mat = mat
        self.name = mat.name
        self.unsupported: list[str] = []   # node labels -> warning line
        self.notes: list[str] = []         # approximations
        self.ctx: dict = {}                # node pointer -> the group nodes it sits in
        self.normals: list = []            # (shader node name, NormalInput or None)
        self.vectors: list = []            # texture vector specs (see vector())
        self.vector_spec = None            # the one applied to the material (build())
        self.bakes: list = []              # export_atlas.Bake per texture read
        # displacement()'s bump: (height in object space, bump in object
        # space), or None (_Exporter.displacement_scales).
        self.displacement_spaces = None
        self.true_displacement = None      # export_displace.TrueDisplacement, or None
        # A procedural texture, a node only the graph evaluates (Math, a colour
        # attribute, ...) or images read at different vectors make the
        # material an atlas one: every texture it reads is an expression of
        # the surface point (addon/export_graph.py), baked over its triangles
        # (addon/export_atlas.py).
        self.atlas = False
        if _use_nodes(mat):
            nodes = list(_all_nodes(mat.node_tree))
            self.atlas = needs_atlas(nodes, GRAPH_NODES) or len({
                _spec_key(self._quiet_vector(nd)) for nd in nodes
                if nd.type == 'TEX_IMAGE' and any(o.is_linked for o in nd.outputs)}) > 1
        self.graph = GraphReader(self) if self.atlas else None

    # -- links, through reroutes and node groups ----------------------------
    def follow(self, socket):
        """(node, output socket, value socket) feeding ``socket``: the node
        and its output, through reroutes and into / out of node groups
        (flattened: a Group node's output continues at its Group Output's
        input, a Group Input's output at the Group node's input).  When
        nothing is linked, node and output are None and the value socket is
        the one whose ``default_value`` applies (a group's input, if the
        chain ends at a Group Input)."""
        stack = self.ctx.get(socket.node.as_pointer(), ()) if socket is not None else ()
        for _ in range(256):
            node, out = _follow(socket)
            if node is None:
                return None, None, socket
            if node.type == 'GROUP' and node.node_tree is not None:
                outs = [nd for nd in node.node_tree.nodes if nd.type == 'GROUP_OUTPUT']
                act = [nd for nd in outs if nd.is_active_output] or outs
                inner = [i for i in (act[0].inputs if act else ())
                         if i.identifier == out.identifier]
                if not inner:
                    return None, None, socket
                stack = stack + (node,)
                socket = inner[0]
                continue
            if node.type == 'GROUP_INPUT':
                if not stack:
                    return None, None, socket
                outer = [i for i in stack[-1].inputs if i.identifier == out.identifier]
                stack = stack[:-1]
                if not outer:
                    return None, None, socket
                socket = outer[0]
                self.ctx[socket.node.as_pointer()] = stack
                continue
            self.ctx[node.as_pointer()] = stack
            return node, out, socket
        return None, None, socket

    # -- inputs --------------------------------------------------------------
    def color(self, node, name):
        """(rgb tuple, texture index) of a colour input: a constant, an
        Image Texture, or either through colour nodes (:meth:`color_chain`)."""
        sock = node.inputs.get(name)
        if sock is None:
            return GREY, -1
        src, out, vsock = self.follow(sock)
        chain = self.color_chain(sock)
        if chain is None and src is None:
            return GREY, -1                   # a socket without a colour value
        if chain is not None and chain[0] == 'const':
            v = chain[1]
            return (float(v[0]), float(v[1]), float(v[2])), -1
        if chain is not None:
            t = self.image(chain[1], chain[2])
            if t >= 0:
                return (1.0, 1.0, 1.0), t
        self.notes.append(f"'{src.name}' into {node.name}.{name} ignored")
        v = tuple(vsock.default_value)
        return (float(v[0]), float(v[1]), float(v[2])), -1

    def image_chain(self, sock):
        """(Image Texture node, ops) when ``sock`` receives an image's Color,
        also through colour nodes (:meth:`color_chain`), else None."""
        src = self.follow(sock)[0]
        if src is None or not self.atlas and src.type not in _COLOR_NODES | {'TEX_IMAGE'}:
            return None
        chain = self.color_chain(sock)
        return chain[1:] if chain is not None and chain[0] == 'tex' else None

    def emission(self, node, color_name, strength_name, default):
        """(colour rgb, strength, texture index) of an emission: a Strength
        fed by an image's colour (a mask, also through colour nodes; read
        as a float reads a colour, its luminance) becomes a texture of that
        grey times the constant colour (white colour, strength 1 then);
        with a textured colour too, the two images' product when both are
        read at the same point (folded like a Multiply of two images), else
        the Strength is the image's mean."""
        sock = node.inputs.get(strength_name)
        chain = self.image_chain(sock) if sock is not None else None
        cchain = self.image_chain(node.inputs[color_name]) if chain is not None else None
        if cchain is not None and self._same_lookup(cchain[0], chain[0]):
            t = self.image(cchain[0], cchain[1] + (
                ("mix_image", "MULTIPLY", 1.0, chain[0], chain[1] + (("gray",),), False),))
            if t >= 0:
                return (1.0, 1.0, 1.0), 1.0, t
        c, tex = self.color(node, color_name)
        if tex >= 0:
            chain = None
        if chain is not None:
            img, ops = chain
            t = self.image(img, ops + (("gray",), ("mix", "MULTIPLY", 1.0, tuple(c), "A", False)))
            if t >= 0:
                return (1.0, 1.0, 1.0), 1.0, t
        return c, self.value(node, strength_name, default), tex

    @staticmethod
    def _constant(src, vsock):
        """The float a socket receives from nothing (its value socket's
        default) or a Value node; None from anything else."""
        if src is None:
            return float(vsock.default_value)
        if src.type == 'VALUE':
            return float(src.outputs[0].default_value)
        return None

    def _float_in(self, node, ident):
        """A float input's constant value (None when a node computes it)."""
        sock = next((i for i in node.inputs if i.identifier == ident), None)
        return None if sock is None else self._constant(*self.follow(sock)[::2])

    def color_chain(self, sock, depth: int = 0):
        """What a colour socket receives, when FPPM can say it per texel:
        ('const', rgb (3,) float64), ('tex', Image Texture node, ops) - the
        image's Color through ``core.scene.color_ops`` ops - or None.

        Colour nodes with constant float inputs fold: Mix (Color) and
        MixRGB with one side constant, Hue/Saturation/Value,
        Brightness/Contrast, Gamma, Invert, RGB Curves, RGB to BW, and a Color Ramp
        read from a colour (as Cycles reads a colour into a float: its
        luminance)."""
        if depth > 64:
            return None
        if self.atlas:
            # ('tex', an expression of the point, ()) or its constant value.
            e = self.graph.expression(sock)
            c = constant_value(e, 'color')
            return None if e is None else ('const', c) if c is not None else ('tex', e, ())
        src, out, vsock = self.follow(sock)
        if src is None:
            v = getattr(vsock, "default_value", None)
            try:
                return 'const', np.array(tuple(v)[:3], np.float64)
            except TypeError:
                return ('const', np.full(3, float(v))) if v is not None else None
        if src.type == 'RGB':
            return 'const', np.array(tuple(src.outputs[0].default_value)[:3], np.float64)
        if src.type == 'VALUE':
            return 'const', np.full(3, float(src.outputs[0].default_value))
        if src.type == 'TEX_IMAGE':
            return ('tex', src, ()) if out.name == 'Color' and src.image is not None else None
        f = self._float_in

        def inp(ident):
            s2 = next((i for i in src.inputs if i.identifier == ident), None)
            return None if s2 is None else self.color_chain(s2, depth + 1)

        def then(ch, op):
            if ch is None:
                return None
            if ch[0] == 'const':
                return 'const', CO.apply((op,), ch[1][None])[0]
            return 'tex', ch[1], ch[2] + (op,)
        if src.type in ('MIX', 'MIX_RGB'):
            if src.type == 'MIX':
                if getattr(src, "data_type", 'FLOAT') != 'RGBA' or out.identifier != 'Result_Color':
                    return None
                t, ia, ib = f(src, "Factor_Float"), "A_Color", "B_Color"
                if t is not None and src.clamp_factor:
                    t = min(max(t, 0.0), 1.0)
                clamp = bool(src.clamp_result)
            else:
                t, ia, ib = f(src, "Fac"), "Color1", "Color2"
                t = None if t is None else min(max(t, 0.0), 1.0)
                clamp = bool(src.use_clamp)
            blend = src.blend_type
            if t is None or blend not in CO.MIX_BLENDS:
                return None
            a, b = inp(ia), inp(ib)
            if a is None or b is None:
                return None
            if b[0] == 'const':
                return then(a, ("mix", blend, t, tuple(b[1]), "A", clamp))
            if a[0] == 'const':
                return then(b, ("mix", blend, t, tuple(a[1]), "B", clamp))
            if self._same_lookup(a[1], b[1]):
                # Two images read at the same uv (or both baked into an atlas,
                # each at its own vector): B's source and ops ride along as
                # one op, folded onto one grid (_Exporter.folded).
                return 'tex', a[1], a[2] + (("mix_image", blend, t, b[1], b[2], clamp),)
            return None                       # two images of different lookups
        if src.type == 'HUE_SAT':
            p = [f(src, k) for k in ("Hue", "Saturation", "Value", "Fac")]
            return None if None in p else then(inp("Color"), ("hsv", *p))
        if src.type == 'BRIGHTCONTRAST':
            p = [f(src, k) for k in ("Bright", "Contrast")]
            return None if None in p else then(inp("Color"), ("bright", *p))
        if src.type == 'GAMMA':
            g = f(src, "Gamma")
            return None if g is None else then(inp("Color"), ("gamma", g))
        if src.type == 'INVERT':
            k = f(src, "Fac")
            return None if k is None else then(inp("Color"), ("invert", k))
        if src.type == 'CURVE_RGB':
            k = f(src, "Fac")
            return None if k is None else then(inp("Color"), curves_op(src, k))
        if src.type == 'RGBTOBW':
            # Cycles' linear_rgb_to_gray: a colour's luminance, as grey.
            return then(inp("Color"), ("gray",))
        if src.type == 'VALTORGB' and out.name == 'Color':
            fin = src.inputs["Fac"]
            fsrc, _, fval = self.follow(fin)
            op = ramp_op(src)
            table = op[1]
            if fsrc is None:
                return 'const', CO.ramp(np.array(float(fval.default_value)), np.asarray(table),
                                        op[2])
            return then(self.color_chain(fin, depth + 1), op)
        return None

    def roughness(self, node, name="Roughness"):
        """(roughness, texture) of a Roughness input: a map (an image's Color
        or Alpha, also through colour nodes, :meth:`alpha_texture`) is read
        per hit (core.materials.rough_maps), its mean over the image the
        lobe's own roughness (the frequency model's); else (its value, -1)."""
        t = self.alpha_texture(node, name)
        if t < 0:
            return self.value(node, name, 0.5), -1
        img = self.ex.textures[t]
        return (float(img[..., 3].mean()) if img.shape[2] > 3 else 1.0), t

    def _quiet_vector(self, node):
        """:meth:`vector` without its notes (read again when the node is)."""
        kept, self.notes = self.notes, []
        try:
            return self.vector(node)
        finally:
            self.notes = kept

    def _same_lookup(self, na, nb) -> bool:
        """Whether two Image Texture nodes are read at the same point of their
        images: the same texture vector (:meth:`vector`), interpolation,
        extension and projection."""
        if self.atlas:
            return True        # every source baked at its own vector (export_atlas)
        va, vb = self._quiet_vector(na), self._quiet_vector(nb)
        return (va[:2] == vb[:2] and np.allclose(va[2], vb[2])
                and all(getattr(na, k, None) == getattr(nb, k, None)
                        for k in ("interpolation", "extension", "projection")))

    def value(self, node, name, default=0.0) -> float:
        sock = node.inputs.get(name)
        if sock is None:
            return default
        src, out, vsock = self.follow(sock)
        k = self._constant(src, vsock)
        if k is not None:
            return k
        if self.atlas:
            # No per-hit BSDF parameter but the mapped ones: a constant graph
            # (Math of Values) is its value; else the socket's.
            k = constant_value(self.graph.expression(sock))
            if k is not None:
                return k
            self.notes.append(f"'{src.name}' into {node.name}.{name} ignored")
            return float(vsock.default_value)
        chain = self.color_chain(sock) if src.type in _COLOR_NODES else None
        if chain is not None and chain[0] == 'const':
            return float(CO.gray(chain[1]))       # a colour into a float: its luminance
        if chain is not None:
            src, out = chain[1], chain[1].outputs['Color']
        if src.type == 'TEX_IMAGE' and out is not None and out.name in ('Color', 'Alpha'):
            # A roughness or IOR map: no per-hit BSDF parameters (colours
            # and lobe weights are what varies per hit), so its mean over the image
            # (through the colour nodes between) rather than the socket's
            # unrelated default.
            m = self.ex.image_mean(src, out.name, self.notes, chain[2] if chain else ())
            if m is not None:
                self.notes.append(f"'{src.name}' into {node.name}.{name}: "
                                  f"the image's mean ({m:.3g}) used")
                return m
        self.notes.append(f"'{src.name}' into {node.name}.{name} ignored")
        return float(vsock.default_value)

    def alpha_texture(self, node, name) -> int:
        """A texture whose alpha channel is what a float input (a Mix
        Shader's Fac, the Principled Alpha) reads per hit, else -1: an Image
        Texture's Alpha output (the image itself), or its Color, also
        through colour nodes (:meth:`color_chain`), read as Cycles reads a
        colour into a float (its luminance) and clamped to [0, 1] as those
        inputs are (a texture made for it, ``_Exporter.texture`` scalar=True)."""
        sock = node.inputs.get(name)
        if sock is None:
            return -1
        src, out, _ = self.follow(sock)
        if self.atlas:
            e = self.graph.expression(sock) if src is not None else None
            if e is None or constant_value(e) is not None:
                return -1
            return self.image(e, scalar=True)
        if src is not None and src.type == 'TEX_IMAGE' and out.name == 'Alpha':
            return self.image(src)
        chain = self.image_chain(sock)
        return -1 if chain is None else self.image(*chain, scalar=True)

    def image(self, tex_node, ops=(), scalar=False) -> int:
        """An Image Texture node's texture index (its Color through ``ops``,
        :meth:`color_chain`; scalar: as a float input's alpha texture,
        :meth:`alpha_texture`); its Vector input is recorded.  In an atlas
        material, tex_node is an expression (addon/export_graph.py) and the
        texture is baked over its triangles (addon/export_atlas.py)."""
        if self.atlas:
            return self.ex.atlas.texture(self, tex_node, ops, scalar)
        t = self.ex.texture(tex_node, self, ops, scalar)
        if t >= 0:
            self.vectors.append(self.vector(tex_node))
        return t

    def vector(self, tex_node, default='UV'):
        """(source, object, A) of a texture node's Vector input: the texture
        coordinates 'UV', 'Generated' or 'Object' (of ``object``, None = the
        shaded object; for 'UV' the UV Map node's map, None = the render
        one), then A (4, 4) the composed Mapping nodes (Cycles' flat
        projection reads x, y of the result).  Unlinked: ``default`` (an
        Image Texture's UV, a procedural's Generated, as in Cycles)."""
        A = np.eye(4)
        node, out, _ = self.follow(tex_node.inputs.get("Vector"))
        while node is not None and node.type == 'MAPPING':
            A = A @ _mapping_matrix(node, self.notes)
            if node.vector_type == 'NORMAL':
                self.notes.append(f"'{node.name}': Normal mapping of texture coordinates "
                                  f"not renormalised")
            vec = node.inputs["Vector"]
            node, out, _ = self.follow(vec)
        if node is None:
            return (default, None, A)
        if node.type == 'UVMAP':
            # A named UV map: read per mesh (_Exporter.named_uv), '' the render one.
            return ('UV', node.uv_map or None, A)
        if node.type == 'TEX_COORD' and out.name in ('UV', 'Generated', 'Object'):
            ob = node.object if out.name == 'Object' else None
            return (out.name, ob.name if ob is not None else None, A)
        self.notes.append(f"{tex_node.name}: vector input '{node.name}' ignored (UVs used)")
        return ('UV', None, np.eye(4))

    def normal_input(self, node, depth=0):
        """The NormalInput of a node's Normal input (None: unlinked or
        unsupported, with a note).  A Bump's own Normal input may be a Normal
        Map (``NormalInput.base``)."""
        sock = node.inputs.get("Normal")
        if sock is None or not sock.is_linked:
            return None
        src, out, _ = self.follow(sock)
        if src is None:
            return None
        if src.type == 'NORMAL_MAP':
            if getattr(src, "space", 'TANGENT') != 'TANGENT':
                self.notes.append(f"'{src.name}': {src.space} space ignored (tangent space only)")
                return None
            if getattr(src, "uv_map", ""):
                self.notes.append(f"'{src.name}': tangents of UV map '{src.uv_map}' taken "
                                  f"from the render UV map")
            chain = self.color_chain(src.inputs["Color"])
            if chain is None or chain[0] != 'tex':
                self.notes.append(f"'{src.name}': colour input is not an Image Texture: ignored")
                return None
            t = self.image(chain[1], chain[2])      # also through colour nodes
            if t < 0:
                return None
            return NormalInput(NORMAL_MAP, t, strength=self.value(src, "Strength", 1.0),
                               directx=getattr(src, "convention", 'OPENGL') == 'DIRECTX')
        if src.type == 'BUMP':
            base = self.normal_input(src, depth + 1) if depth < 1 else None
            if base is not None and base.kind != NORMAL_MAP:
                base = None
            if base is None and src.inputs.get("Normal") is not None \
                    and src.inputs["Normal"].is_linked:
                self.notes.append(f"'{src.name}': its Normal input ignored")
            h = self.height_texture(src.inputs["Height"])
            if h is None:
                self.notes.append(f"'{src.name}': height is not an Image Texture "
                                  f"or a procedural texture: ignored")
                return None
            t, channel = h
            if t < 0:
                return None
            return NormalInput(BUMP, t, strength=self.value(src, "Strength", 1.0),
                               distance=self.value(src, "Distance", 1.0),
                               invert=bool(getattr(src, "invert", False)),
                               channel=channel, base=base)
        self.notes.append(f"'{src.name}' into {node.name}.Normal ignored")
        return None

    def height_texture(self, sock):
        """(texture index, channel) of what a height input (a Bump's, a
        Displacement's) reads, or None when it is no image or texture graph:
        in an atlas material its expression baked as a grey colour (any
        range); else an image's Color, also through colour nodes (the folded
        image, read as a float reads a colour), or its Alpha.  The index is
        -1 when the image has no pixels (noted by :meth:`image`)."""
        chain = self.image_chain(sock)
        if chain is not None and self.atlas:
            return self.image(chain[0]), 'COLOR'
        img, iout, _ = self.follow(sock)
        ops = ()
        if chain is not None:
            img, ops = chain
            iout = img.outputs["Color"]
        if img is None or img.type != 'TEX_IMAGE':
            return None
        return self.image(img, ops), 'ALPHA' if iout.name == 'Alpha' else 'COLOR'

    def displacement(self, output) -> NormalInput | None:
        """The Material Output's Displacement as Cycles renders it by default
        (the material's Displacement method 'Bump Only':
        ShaderGraph::bump_from_displacement, a bump of distance 1 whose height
        is the displacement along the normal, (Height - Midlevel) Scale): a
        BUMP NormalInput of the Height's image or graph, distance Scale; or
        None (a note when something is linked that is not read)."""
        sock = output.inputs.get("Displacement")
        if sock is None or not sock.is_linked:
            return None
        src, _, _ = self.follow(sock)
        if src is None:
            return None
        if src.type != 'DISPLACEMENT':
            self.notes.append(f"'{src.name}' into the Displacement ignored")
            return None
        if src.inputs.get("Normal") is not None and src.inputs["Normal"].is_linked:
            self.notes.append(f"'{src.name}': its Normal input ignored")
        method = getattr(self.mat, "displacement_method", 'BUMP')
        if method != 'BUMP':
            # True displacement (addon/export_displace.py): the vertices move.
            e = GraphReader(self).expression(src.inputs["Height"])
            if e is None:
                self.notes.append(f"'{src.name}': height is not a texture graph FPPM "
                                  f"evaluates: true displacement ignored")
            else:
                self.true_displacement = TrueDisplacement(
                    SG.as_float(e), self.value(src, "Midlevel", 0.5),
                    self.value(src, "Scale", 1.0), getattr(src, "space", 'OBJECT') == 'OBJECT',
                    method == 'DISPLACEMENT')
            if method == 'DISPLACEMENT':
                return None        # no bump: the moved vertices' own normals
        h = self.height_texture(src.inputs["Height"])
        if h is None:
            self.notes.append(f"'{src.name}': height is not an Image Texture or a procedural "
                              f"texture: displacement ignored")
            return None
        t, channel = h
        if t < 0:
            return None
        # Object space (the node's default): the displacement scales with the
        # object; Displacement and Bump bumps in object space (Cycles'
        # finalize(bump_in_object_space)): _Exporter.displacement_scales.
        self.displacement_spaces = (getattr(src, "space", 'OBJECT') == 'OBJECT',
                                    method == 'BOTH')
        return NormalInput(BUMP, t, strength=1.0, distance=self.value(src, "Scale", 1.0),
                           channel=channel, shadowing=False)

    # -- shaders --------------------------------------------------------------
    def shader(self, socket, depth=0) -> Material:
        node, out, _ = self.follow(socket)
        if node is None:
            # An unconnected shader socket is black (no closure), as in Cycles.
            return Material(self.name, lobes=(), emission=(0.0, 0.0, 0.0))
        if depth > 32:
            self.unsupported.append(f"{node.name} (nested too deep)")
            return Material(self.name, lobes=(Lobe(DIFFUSE, GREY),))
        if node.mute:
            links = [lk for lk in node.internal_links if lk.to_socket == out]
            if links:
                return self.shader(links[0].from_socket, depth + 1) \
                    if links[0].from_socket.is_linked else \
                    Material(self.name, lobes=(), emission=(0.0, 0.0, 0.0))
            return Material(self.name, lobes=(), emission=(0.0, 0.0, 0.0))
        t = node.type
        n = self.name
        if t.startswith('BSDF_') or t in ('SUBSURFACE_SCATTERING',):
            self.normals.append((node.name, self.normal_input(node)))
        if t == 'BSDF_DIFFUSE':
            c, tex = self.color(node, "Color")
            return Material(n, lobes=(Lobe(DIFFUSE, c, 1.0, self.value(node, "Roughness"),
                                           color_texture=tex),))
        if t in ('BSDF_GLOSSY', 'BSDF_ANISOTROPIC', 'BSDF_GLASS', 'BSDF_REFRACTION'):
            return Material(n, lobes=(self.microfacet(node),))
        if t == 'BSDF_TRANSPARENT':
            c, tex = self.color(node, "Color")
            return Material(n, lobes=(Lobe(TRANSPARENT, c, 1.0, color_texture=tex),))
        if t == 'BSDF_TRANSLUCENT':
            c, tex = self.color(node, "Color")
            return Material(n, lobes=(Lobe(TRANSLUCENT, c, 1.0, color_texture=tex),))
        if t == 'HOLDOUT':
            # No closure to scatter with: camera rays take its weight as
            # transparency (core.scene.holdout).
            return Material(n, lobes=(), emission=(0.0, 0.0, 0.0), holdout=1.0)
        if t == 'EMISSION':
            c, s, tex = self.emission(node, "Color", "Strength", 1.0)
            return Material(n, lobes=(), emission=(c[0] * s, c[1] * s, c[2] * s),
                            emission_texture=tex)
        if t == 'MIX_SHADER':
            lp = self.light_path_fac(node)
            if lp is not None:
                a = self.shader(node.inputs[1], depth + 1)
                b = self.shader(node.inputs[2], depth + 1)
                return _mix_by_ray(a, b, lp, n, self.notes, node.name)
            view = self.view_fac(node)
            if view is not None:
                # (A view factor reads no texture: the shaders' textures
                # keep their order.)
                a = self.shader(node.inputs[1], depth + 1)
                b = self.shader(node.inputs[2], depth + 1)
                return _with_variants(_mix_by_view, a, b, view, n)
            at = self.alpha_texture(node, "Fac")
            fac = 0.5 if at >= 0 else min(max(self.value(node, "Fac", 0.5), 0.0), 1.0)
            a = self.shader(node.inputs[1], depth + 1)
            b = self.shader(node.inputs[2], depth + 1)
            if at >= 0:
                return _with_variants(_mix_by_alpha, a, b, at, n)
            return _with_variants(_mix, a, b, fac, n)
        if t == 'ADD_SHADER':
            a = self.shader(node.inputs[0], depth + 1)
            b = self.shader(node.inputs[1], depth + 1)
            return _with_variants(_add, a, b, n)
        if t == 'BSDF_PRINCIPLED':
            return self.principled(node)
        if t == 'BSDF_METALLIC':
            return Material(n, lobes=(self.metallic(node),))
        if node.name not in self.unsupported:    # (a group instanced twice: once)
            self.unsupported.append(node.name)
        return Material(n, lobes=(Lobe(DIFFUSE, GREY),))

    def light_path_fac(self, node):
        """The Light Path output a Mix Shader's Fac is linked to (its name),
        or None."""
        src, out, _ = self.follow(node.inputs["Fac"])
        return out.name if src is not None and src.type == 'LIGHT_PATH' else None

    def _reaches(self, sock, types, limit: int = 256) -> bool:
        """Whether a node of one of ``types`` feeds ``sock``, through any
        nodes, reroutes and groups (:meth:`follow`); looks at ``limit``
        nodes at most."""
        todo, seen = [sock], set()
        while todo and len(seen) < limit:
            node = self.follow(todo.pop())[0]
            if node is None or node.as_pointer() in seen:
                continue
            if node.type in types:
                return True
            seen.add(node.as_pointer())
            todo += [i for i in node.inputs if i.is_linked]
        return False

    def view_fac(self, node):
        """A Mix Shader's Fac as a function of the view alone, sampled at
        mu = |w_o . n_s| = i / (VIEW_SAMPLES - 1) ((VIEW_SAMPLES,) float64), or
        None: a graph (addon/export_graph.py, read with ``view``) that
        reaches a Fresnel or Layer Weight node on the shading normal, through
        converter and colour nodes with constant inputs.  A factor that
        also reads the surface point (a texture times a Fresnel) is None,
        with a note, and the Fac is read as before."""
        sock = node.inputs["Fac"]
        if not self._reaches(sock, ('FRESNEL', 'LAYER_WEIGHT')):
            # (Reading any other Fac as an expression would register its
            # images as textures the material never uses.)
            return None
        e = GraphReader(self, view=True).expression(sock)
        if e is None:
            return None
        keys = SG.attributes(e)
        if SG.VIEW_COS not in keys:
            return None
        if keys != {SG.VIEW_COS} or any(isinstance(x, (SG.Image, SG.Proc)) for x in SG.walk(e)):
            self.notes.append(f"{node.name}: a Fac of the view and the surface point "
                              f"read as its value")
            return None
        mu = np.linspace(0.0, 1.0, VIEW_SAMPLES)
        ctx = SG.EvalContext(attrs={SG.VIEW_COS: np.repeat(mu[:, None], 3, axis=1)},
                             textures=[])
        try:
            f = np.asarray(SG.evaluate(SG.as_float(e), ctx), np.float64)
        except (ArithmeticError, ValueError, KeyError):
            return None
        return np.where(np.isfinite(f), f, 0.0)

    def microfacet(self, node) -> Lobe:
        """Glossy / Glass / Refraction node -> one GGX lobe.

        'MULTI_GGX' (the Glossy and Glass default) is Cycles' Multiscatter GGX,
        reproduced by ``core.materials`` (``multiscatter``); 'GGX' is single
        scattering.  Beckmann and Ashikhmin-Shirley are rendered as GGX of the
        same roughness, and noted (they coincide at roughness 0)."""
        kind = {'BSDF_GLASS': GLASS, 'BSDF_REFRACTION': REFRACTION}.get(node.type, GLOSSY)
        c, tex = self.color(node, "Color")
        rough, rtex = self.roughness(node)
        dist = self.ggx_distribution(node, rough, 'GGX')
        ior = self.value(node, "IOR", 1.45) if kind != GLOSSY else 1.45
        # make_lobe drops multiscatter on REFRACTION (Cycles has no
        # multiscatter refraction-only closure).
        return shading.make_lobe(kind, c, 1.0, rough, ior, tex,
                                 multiscatter=dist == 'MULTI_GGX', roughness_texture=rtex)

    def metallic(self, node) -> Lobe:
        """Metallic BSDF (Blender 4.3 and later) -> one GGX lobe with Cycles'
        conductor Fresnel (``svm_node_closure_bsdf``'s
        CLOSURE_BSDF_F82_CONDUCTOR / PHYSICAL_CONDUCTOR): 'F82' the F82-tint
        model of F0 = Base Color and tint Edge Tint (the Principled BSDF's
        metal); 'PHYSICAL_CONDUCTOR' the exact Fresnel of IOR + i Extinction."""
        rough, rtex = self.roughness(node)
        dist = self.ggx_distribution(node, rough, 'MULTI_GGX')
        film = shading.thin_film(self.value(node, "Thin Film Thickness"),
                                 self.value(node, "Thin Film IOR", 1.33))
        if getattr(node, "fresnel_type", 'F82') == 'PHYSICAL_CONDUCTOR':
            return shading.make_lobe(GLOSSY, (1.0, 1.0, 1.0), 1.0, rough,
                                     multiscatter=dist == 'MULTI_GGX', roughness_texture=rtex,
                                     fresnel="CONDUCTOR", **film,
                                     conductor_n=self.vector_value(node, "IOR"),
                                     conductor_k=self.vector_value(node, "Extinction"))
        c, tex = self.color(node, "Base Color")
        tint, _ = self.color(node, "Edge Tint")
        # Cycles: F0 = saturate(Base Color), tint = saturate(Edge Tint).
        return shading.make_lobe(GLOSSY, np.minimum(c, 1.0), 1.0, rough, color_texture=tex,
                                 multiscatter=dist == 'MULTI_GGX', roughness_texture=rtex,
                                 fresnel="F82", f82_tint=tuple(np.clip(tint, 0.0, 1.0)), **film)

    def ggx_distribution(self, node, rough, default) -> str:
        """A microfacet node's distribution, with the notes of what FPPM
        renders otherwise: Beckmann and Ashikhmin-Shirley as GGX of the same
        roughness (they coincide at roughness 0), an Anisotropy as isotropic."""
        dist = getattr(node, "distribution", default)
        if dist not in ('GGX', 'MULTI_GGX') and rough > 0.0:
            self.notes.append(f"{node.name}: {dist} distribution rendered as GGX")
        if node.inputs.get("Anisotropy") is not None and self.value(node, "Anisotropy") != 0:
            self.notes.append(f"{node.name}: anisotropy ignored")
        return dist

    def vector_value(self, node, name) -> tuple:
        """A vector input's value (3 floats): its own, or with a link the
        linked socket's constant, else its own with a note."""
        src, out, vsock = self.follow(node.inputs[name])
        if src is None:
            return tuple(float(x) for x in vsock.default_value[:3])
        if src.type == 'COMBXYZ':
            return tuple(self.value(src, a) for a in ("X", "Y", "Z"))
        if src.type == 'VALUE':
            return (float(out.default_value),) * 3
        if src.type == 'RGB':
            return tuple(float(x) for x in out.default_value[:3])
        self.notes.append(f"'{src.name}' into {node.name}.{name} ignored")
        return tuple(float(x) for x in node.inputs[name].default_value[:3])

    def principled(self, node) -> Material:
        """Principled BSDF through ``core.scene.nodes.principled_to_lobes``."""
        base, base_tex = self.color(node, "Base Color")
        emis, emis_strength, emis_tex = self.emission(node, "Emission Color",
                                                      "Emission Strength", 0.0)
        v = self.value
        alpha_tex = self.alpha_texture(node, "Alpha")
        # A Metallic map per hit; beside a textured Alpha, its mean (a lobe
        # follows one image: principled_to_lobes).
        metal_tex = self.alpha_texture(node, "Metallic") if alpha_tex < 0 else -1
        rough, rough_tex = self.roughness(node)
        lobes, emission, notes = shading.principled_to_lobes(
            base_color=base, base_color_texture=base_tex, alpha_texture=alpha_tex,
            metallic_texture=metal_tex,
            metallic=0.0 if metal_tex >= 0 else v(node, "Metallic", 0.0),
            roughness=rough, roughness_texture=rough_tex,
            ior=v(node, "IOR", 1.5), alpha=1.0 if alpha_tex >= 0 else v(node, "Alpha", 1.0),
            transmission=v(node, "Transmission Weight", 0.0),
            coat_weight=v(node, "Coat Weight", 0.0),
            coat_roughness=v(node, "Coat Roughness", 0.03), coat_ior=v(node, "Coat IOR", 1.5),
            coat_tint=self.color(node, "Coat Tint")[0],
            sheen_weight=v(node, "Sheen Weight", 0.0),
            subsurface_weight=v(node, "Subsurface Weight", 0.0),
            specular_ior_level=v(node, "Specular IOR Level", 0.5),
            specular_tint=self.color(node, "Specular Tint")[0],
            anisotropic=v(node, "Anisotropic", 0.0),
            diffuse_roughness=v(node, "Diffuse Roughness", 0.0),
            thin_film_thickness=v(node, "Thin Film Thickness", 0.0),
            thin_film_ior=v(node, "Thin Film IOR", 1.33),
            emission_color=emis, emission_strength=emis_strength,
            emission_color_texture=emis_tex,
            multiscatter=getattr(node, "distribution", 'MULTI_GGX') == 'MULTI_GGX')
        return Material(self.name, tuple(lobes), tuple(float(x) for x in emission),
                        emis_tex if emis_tex >= 0 and np.any(np.asarray(emission) > 0) else -1,
                        tuple(f"{node.name}: {n}" for n in notes))

    def build(self) -> Material:
        mat = self.mat
        if not _use_nodes(mat):
            c = tuple(mat.diffuse_color)[:3]
            return Material(self.name, lobes=(Lobe(DIFFUSE, tuple(float(x) for x in c),
                                                   1.0, float(mat.roughness)),))
        nodes = mat.node_tree.nodes
        outs = [nd for nd in nodes if nd.type == 'OUTPUT_MATERIAL'
                and getattr(nd, "target", 'ALL') in ('ALL', 'CYCLES')]
        active = [nd for nd in outs if nd.is_active_output] or outs
        if not active:
            self.notes.append("no Material Output: black")
            return Material(self.name, lobes=(), emission=(0.0, 0.0, 0.0))
        m = self.shader(active[0].inputs["Surface"])
        absorption = ()
        vol = active[0].inputs.get("Volume")
        if vol is not None and vol.is_linked:
            absorption = self.absorption(vol)
            if not active[0].inputs["Surface"].is_linked:
                # Cycles: a volume's object without a surface shader has no
                # surface, every ray passes its boundary (SD_HAS_ONLY_VOLUME).
                m = Material(self.name, lobes=(Lobe(TRANSPARENT, (1.0, 1.0, 1.0)),))
        displaced = self.displacement(active[0])
        m = self._regular(m)
        normal = None
        found = [(nm, inp) for nm, inp in self.normals if inp is not None]
        if found:
            normal = found[0][1]
            if len({inp for _, inp in self.normals}) > 1:
                self.notes.append(f"the shaders' Normal inputs differ: '{found[0][0]}''s "
                                  f"applied to all")
        if displaced is not None:
            if normal is None:
                normal = displaced
            elif normal.kind == NORMAL_MAP:
                # Cycles applies the displacement's bump first and the normal
                # map over it; one bump over a normal map here (NormalInput.base).
                normal = dataclasses.replace(displaced, base=normal, shadowing=True)
                self.notes.append("the displacement's bump applied over the normal map "
                                  "(Cycles: the normal map over the bump)")
            else:
                self.notes.append("displacement ignored beside a Bump node")
                self.displacement_spaces = None
        vecs = {_spec_key(v) for v in self.vectors}
        self.vector_spec = self.vectors[0] if self.vectors else None
        if len(vecs) > 1 and not self.bakes:
            self.notes.append("image textures with different vector inputs: the first one's "
                              "used for all")
        notes = list(m.approximations) + self.notes
        if self.unsupported:
            notes.append("unsupported " + ", ".join(f"'{u}'" for u in self.unsupported)
                         + " -> diffuse grey")
        # The materials camera rays and shadow rays see (a Light Path node),
        # with the same normal input.
        seen = {k: None if getattr(m, k) is None
                else dataclasses.replace(self._regular(getattr(m, k)), name=f"{self.name} ({k})",
                                         normal=normal, camera=None, shadow=None)
                for k in ("camera", "shadow")}
        return Material(self.name, m.lobes, m.emission, m.emission_texture, tuple(notes),
                        normal=normal, holdout=m.holdout, absorption=absorption,
                        aovs=self.shader_aovs(nodes), **seen)

    def shader_aovs(self, nodes) -> tuple:
        """((name, rgb, texture index, scalar), ...) of the AOV Output nodes
        whose name is one of the view layer's shader AOVs (the first node of
        a name): a Color AOV their Color input, a Value AOV their Value input
        (a constant, or an image's value per hit)."""
        out, seen = [], set()
        for nd in nodes:
            kind = self.ex.aov_kinds.get(getattr(nd, "aov_name", None))
            if nd.type != 'OUTPUT_AOV' or nd.mute or kind is None or nd.aov_name in seen:
                continue
            seen.add(nd.aov_name)
            if kind == 'COLOR':
                rgb, tex = self.color(nd, "Color")
                out.append((nd.aov_name, rgb, tex, False))
            else:
                tex = self.alpha_texture(nd, "Value")
                v = 1.0 if tex >= 0 else self.value(nd, "Value")
                out.append((nd.aov_name, (v, v, v), tex, True))
        return tuple(out)

    def absorption(self, socket) -> tuple:
        """sigma_a (3,) [1/m] of a Volume Absorption of constant Color c and
        Density rho linked into the Volume output: rho (1 - c), Cycles'
        extinction of an absorption closure (core.scene.absorption); () and
        a note for any other volume."""
        node, _, _ = self.follow(socket)
        if (node is not None and node.type == 'VOLUME_ABSORPTION' and not node.mute
                and not any(node.inputs[k].is_linked for k in ("Color", "Density"))):
            c = np.asarray(node.inputs["Color"].default_value[:3], np.float64)
            rho = max(float(node.inputs["Density"].default_value), 0.0)
            sigma = rho * np.clip(1.0 - c, 0.0, None)
            return tuple(float(x) for x in sigma) if sigma.max() > 0 else ()
        self.notes.append("volume ignored")
        return ()

    def _regular(self, m: Material) -> Material:
        """m within what core's tables hold: MAX_LOBES lobes (the heaviest),
        one roughness map, at least one lobe."""
        if len(m.lobes) > MAX_LOBES:
            self.notes.append(f"{len(m.lobes)} closures cut to the {MAX_LOBES} heaviest")
            lobes = sorted(m.lobes, key=lambda lb: -lb.weight * max(lb.color))[:MAX_LOBES]
            m = dataclasses.replace(m, lobes=tuple(lobes))
        maps = list(dict.fromkeys(lb.roughness_texture for lb in m.lobes
                                  if lb.roughness_texture >= 0))
        if len(maps) > 1:
            # One roughness map a material (core.materials.rough_maps): the
            # lobes of the others keep their map's mean.
            self.notes.append(f"{len(maps)} roughness maps: the first read per hit, the "
                              f"others at their mean")
            lobes = tuple(dataclasses.replace(lb, roughness_texture=-1)
                          if lb.roughness_texture not in (-1, maps[0]) else lb for lb in m.lobes)
            m = dataclasses.replace(m, lobes=lobes)
        if not m.lobes and not any(m.emission):
            # Pure black: keep one black diffuse lobe so core's tables stay regular.
            m = dataclasses.replace(m, lobes=(Lobe(DIFFUSE, (0.0, 0.0, 0.0)),))
        return m


# ---------------------------------------------------------------------------
# features FPPM ignores or approximates

def _objects(obs) -> str:
    """'2 object(s) (A, B)': the subject of a check's message."""
    names = sorted({ob.name for ob in obs})
    return f"{len(names)} object(s) ({', '.join(names[:3])}{', ...' if len(names) > 3 else ''})"


def _has_hair(ob) -> bool:
    return ob.type == 'CURVES' or any(
        ps.settings.type == 'HAIR' and ps.settings.render_type == 'PATH'
        for ps in getattr(ob, "particle_systems", ()))


def _filter_type(cy) -> str:
    """Cycles' Film > Pixel Filter type ('BLACKMAN_HARRIS', 'BOX', 'GAUSSIAN')."""
    return str(getattr(cy, "pixel_filter_type", 'BLACKMAN_HARRIS')) if cy else 'BLACKMAN_HARRIS'


def _filter_width(cy) -> float:
    """The filter width Cycles renders with: the Box filter is one pixel
    wide whatever the width (measured: Box at 1 and 2 px give the same
    image, tests/test_pixel_filters.py), the others take the setting."""
    if _filter_type(cy) == 'BOX':
        return 1.0
    return float(getattr(cy, "filter_width", 1.5)) if cy else 1.5


def ray_visibility(ob, parent=None) -> int:
    """The RAY_* flags (core.accel) of an object's Ray Visibility; an
    instance's are its instancer's too (Cycles: "for instancers, visibility
    is inherited": the flags of both, and-ed)."""
    flags = 0
    for name, bit in RAY_FLAGS.items():
        if getattr(ob, "visible_" + name, True) and (
                parent is None or getattr(parent, "visible_" + name, True)):
            flags |= bit
    return flags


def is_holdout(ob, parent=None, view_layer=None) -> bool:
    """Cycles' object holdout: the instancer's for an instance, else the
    object's own (Object > Visibility > Holdout, or its collection's Holdout
    in the view layer: Object.holdout_get)."""
    src = parent if parent is not None else ob
    src = getattr(src, "original", src)
    try:
        return bool(src.holdout_get(view_layer=view_layer))
    except (AttributeError, RuntimeError, TypeError):
        return bool(getattr(src, "is_holdout", False))


def is_shadow_catcher(ob, parent=None) -> bool:
    """Object > Visibility > Mask > Shadow Catcher: the object's own, or its
    instancer's for an instance (Cycles takes either)."""
    return any(bool(getattr(getattr(o, "original", o), "is_shadow_catcher", False))
               for o in (ob, parent) if o is not None)


# The flags every integrator honours (core.accel.for_rays at each ray kind);
# glossy and transmission are honoured for the rays of mirror and glass
# chains only (core.accel.chain_kinds), diffuse not at all: photons and
# camera paths would be traced per ray kind of the path they would join.
HONOURED_RAYS = RAY_CAMERA | RAY_SHADOW


def _partly_visible(ob) -> bool:
    vis = ray_visibility(ob)
    return (ob.type in GEOMETRY_TYPES and vis != 0
            and (vis | HONOURED_RAYS) != RAY_ALL)


def _world_visible(world, kind: str) -> bool:
    """The world's Ray Visibility flag ``kind`` (World > Settings > Ray
    Visibility: camera, diffuse, glossy, transmission, scatter)."""
    vis = getattr(world, "cycles_visibility", None) if world is not None else None
    return vis is None or bool(getattr(vis, kind, True))


def world_hidden_bits(world) -> int:
    """The kinds of ray the world is hidden from (``Scene.world_hidden``:
    core.lights.lobe_visibility's bits)."""
    from ..core.lights.lobe_visibility import DIFFUSE_RAYS, GLOSSY_RAYS, TRANSMISSION_RAYS
    return sum(bit for k, bit in (("diffuse", DIFFUSE_RAYS), ("glossy", GLOSSY_RAYS),
                                  ("transmission", TRANSMISSION_RAYS))
               if not _world_visible(world, k))


# The one table of scene features that FPPM ignores or approximates: (feature,
# check(bpy scene, rendered objects) -> the objects concerned (a list) or a
# bool, message; "{}" receives the objects).  Every hit is one sentence of
# Scene.approximations: the CLI's "Approximated:" line and one warning in
# Blender's Info log per render (addon/engine.py).
FEATURE_CHECKS = (
    ("motion blur", lambda sc, obs: bool(sc.render.use_motion_blur),
     "motion blur ignored: the scene is rendered at the current frame"),
    ("stereo", lambda sc, obs: bool(sc.render.use_multiview),
     "stereo 3D / multi-view: every view is rendered from the scene camera "
     "(the right eye repeats the left)"),
    ("ray visibility", lambda sc, obs: [ob for ob in obs if _partly_visible(ob)],
     "ray visibility of {}: diffuse, and glossy and transmission for photons, light paths "
     "and rough bounces, treated as visible (camera, shadow, and a mirror's or glass's rays "
     "are honoured)"),
    ("light visibility", lambda sc, obs: [ob for ob in obs if ob.type == 'LIGHT' and not all(
        getattr(ob, "visible_" + k, True) for k in ("diffuse", "glossy", "transmission"))],
     "photons and light paths of {} (hidden from some kind of ray): "
     "a first bounce off a material with lobes of both kinds keeps every lobe"),
    ("world ray visibility", lambda sc, obs: world_hidden_bits(sc.world) != 0,
     "world (hidden from some kind of ray): its photons and light paths: "
     "a first bounce off a material with lobes of both kinds keeps every lobe"),
    ("world scatter visibility", lambda sc, obs: not _world_visible(sc.world, "scatter"),
     "world: volume scatter ray visibility has no effect"),
    ("hair", lambda sc, obs: [ob for ob in obs if _has_hair(ob)],
     "hair of {} not rendered"),
    ("shadow catcher", lambda sc, obs: [ob for ob in obs if ob.type in GEOMETRY_TYPES
                                        and getattr(ob, "is_shadow_catcher", False)],
     "shadow catcher on {}: lit without the other objects by light samples alone (no light between catchers); the matte at its silhouettes approximated"),
    ("volume objects", lambda sc, obs: [ob for ob in obs if ob.type == 'VOLUME'],
     "volume object(s) not rendered: {}"),
)


def feature_notes(scene, objects) -> list[str]:
    """The messages of :data:`FEATURE_CHECKS` that apply to ``scene`` whose
    rendered (evaluated) objects are ``objects``."""
    out = []
    for _feature, check, message in FEATURE_CHECKS:
        hit = check(scene, objects)
        if isinstance(hit, list):
            if hit:
                out.append(message.format(_objects(hit)))
        elif hit:
            out.append(message)
    return out


# ---------------------------------------------------------------------------
# the exporter

class _Exporter:
    def __init__(self, depsgraph, log, should_stop=None):
        self.dg = depsgraph
        self.should_stop = should_stop or _never
        self.scene = depsgraph.scene
        self.log = log
        self.world_sun = None        # a baked Sky Texture's sun disc (baked_world)
        self.world_camera_map = None  # the world camera rays see, when it differs (baked_world)
        self.bake_wait = True        # False: bake the world in the background (viewport)
        self.world_pending = False   # the world is being baked in the background
        self.materials: list[Material] = []
        self.mat_pass_index: list[int] = []    # material.pass_index per entry of materials
        self.mat_vector: list = []     # texture vector spec per material (_MaterialBuilder.vector)
        self.mat_displace: list = []   # TrueDisplacement or None per material
        self.tangent_parts: list = []  # (T, 3, 4) float32 per entry of parts, or None
        self.tangent_cache: dict = {}
        self.uv_cache: dict = {}           # (mesh, UV map name) -> named_uv's local uvs
        # parts index -> its world corners before a true displacement (the
        # Generated coordinates read them: export_displace).
        self.undisplaced: dict = {}
        self.obj_index_parts: list[np.ndarray] = []   # object.pass_index per triangle of parts
        self.vis_parts: list[np.ndarray] = []         # ray_visibility per triangle of parts
        self.holdout_parts: list[np.ndarray] = []     # is_holdout per triangle of parts
        self.catcher_parts: list[np.ndarray] = []     # is_shadow_catcher per triangle of parts
        self.receiver_parts: list[np.ndarray] = []    # light-linking receiver set per triangle
        self.emitter_parts: list[np.ndarray] = []     # light-linking membership per triangle
        self.blocker_parts: list[np.ndarray] = []     # shadow-linking blocker set per triangle
        self.shadowed_parts: list[np.ndarray] = []    # shadow-linking membership per triangle
        # Cryptomatte (core.sppm.cryptomatte): on when the view layer asks
        # for a kind; the IDs per triangle of parts, each material's, and
        # the names of each kind (the manifests).
        self.crypto = bool(crypto.pass_names(getattr(depsgraph, "view_layer", None)))
        self.crypto_parts: list[np.ndarray] = []
        # The UV pass (core.sppm.color_passes): (u, v, has-uv) per corner.
        self.uv_pass = bool(getattr(getattr(depsgraph, "view_layer", None), "use_pass_uv", False))
        self.render_uv_parts: list[np.ndarray] = []
        self.mat_crypto: list = []         # each material's name (material() order)
        self.mat_ids = np.zeros(0, np.float32)   # the IDs of mat_crypto's first names
        self.crypto_names = {k: set() for k in crypto.KINDS}
        # The view layer's shader AOVs (core.sppm.shader_aovs): name -> type.
        self.aov_kinds = {a.name: a.type for a in getattr(getattr(depsgraph, "view_layer", None),
                                                          "aovs", ()) if a.is_valid}
        self.mat_index: dict = {}
        self.textures: list[np.ndarray] = []
        self.tex_index: dict = {}      # (image name, reading) -> index into textures
        self.udim_index: dict = {}     # (UDIM image name, tile number) -> index, or -1
        self.seq_index: dict = {}      # (sequence name, frame, reading) -> index
        self.camera_model = None       # the render camera's CameraModel, set by run()
        self.tex_pixels: dict = {}     # image name -> its pixels (or None)
        self.mesh_cache: dict = {}
        self.atlas = AtlasBaker(self)  # materials baked into texture atlases
        # material whose displacement's bump the object stretches -> (height,
        # bump) in object space; the triangles' factors (displacement_scales)
        self.disp_spaces: dict = {}
        self.bump_scale_parts: list = []
        self.notes: list[str] = []
        self.n_objects = 0
        self.n_instances = 0

    def poll(self) -> None:
        """A cancellation point: RenderCancelled when should_stop() is true."""
        if self.should_stop():
            raise RenderCancelled("cancelled")

    # -- textures --------------------------------------------------------------
    def check_image_memory(self, img) -> int:
        """Refuse (MemoryBudgetError) an image whose pixels would not fit in
        memory; else return an upper bound of its width x height x channels.

        Checked before its pixels are read: Blender's own buffer (generated
        images are made, file images decoded, on the first access; their size
        comes from the generated size or a PNG / JPEG header, other formats
        are decoded by ``Image.size`` before the check), our
        float32 copy (``Image.pixels``: 4 bytes a channel) and, for 1- or
        2-channel images, the RGB copy made from it: the export's own peak
        comes before the render's memory estimate (docs/reliability.md,
        "Memory").
        """
        from ..core.memory import available_bytes
        header = None
        if img.source == 'FILE' and not img.has_data and img.packed_file is None:
            header = _file_image_header(img.filepath_from_user())
        if img.source == 'GENERATED' and not img.has_data:
            w, h = int(img.generated_width), int(img.generated_height)
            c, held = 4, (_FLOAT_BYTES if img.use_generated_float else 1)
        elif header is not None:
            # A PNG or JPEG not decoded yet: its size from the header; the
            # pixels read back as 4 channels.
            w, h, per_pixel = header
            c, held = 4, per_pixel // 4
        else:
            w, h = (int(x) for x in img.size)       # loads the file, if not yet
            c, held = int(img.channels), (_FLOAT_BYTES if img.is_float else 1)
            if img.has_data:
                held = 0                             # already in memory
        n = w * h
        need = n * c * held + n * c * 4 + (n * 3 * 4 if 0 < c < 3 else 0)
        avail = available_bytes()
        if avail is None or need <= avail:
            return n * c
        def size(b):
            return f"{b / 2 ** 30:.1f} GiB" if b >= 2 ** 30 else f"{b / 2 ** 20:.0f} MiB"
        raise MemoryBudgetError(
            f"Image '{img.name}' ({w}x{h}, {c} channels) needs about {size(need)} to "
            f"load but only {size(avail)} is free: use a smaller image (a lower-"
            f"resolution file, or scale it down in the Image Editor: Image > Resize), or "
            f"close other programs.")

    def udim_tiles(self, node, mb: _MaterialBuilder) -> tuple:
        """((tile number, index in ``textures``), ...) of an Image Texture
        node's UDIM image, each tile's file read as the image's own would be
        (its colour space, alpha and the node's sampler); () for other
        images (a packed image's tiles from their packed data).  A tile
        that cannot be read is left out, with a note: Cycles shows its
        missing-image magenta there, and so does the graph
        (core/scene/shader_graph.py ``udim_sample``)."""
        img = node.image
        if img is None or img.source != 'TILED':
            return ()
        out = []
        for tile in img.tiles:
            key = (img.name_full, int(tile.number))
            if key not in self.udim_index:
                timg = tile_image(img, int(tile.number))
                if timg is None:
                    mb.notes.append(f"image '{img.name}': UDIM tile {tile.number} could not "
                                    f"be read (no file or packed data): magenta")
                    self.udim_index[key] = -1
                else:
                    self.udim_index[key] = self.stand_in_texture(node, mb, timg)
            if self.udim_index[key] >= 0:
                out.append((int(tile.number), self.udim_index[key]))
        return tuple(out)

    def stand_in_texture(self, node, mb, timg, ops=(), scalar=False) -> int:
        """:meth:`texture` of a stand-in image (a UDIM tile's file, an image
        sequence's frame), then the stand-in removed from bpy.data."""
        try:
            return self.texture(node, mb, ops, scalar, image=timg)
        finally:
            # A later stand-in may take the same name.
            name = timg.name_full
            self.tex_pixels.pop(name, None)
            for k in [k for k in self.tex_index if k[0] == name]:
                del self.tex_index[k]
            remove_image(timg)

    def texture(self, node, mb: _MaterialBuilder, ops=(), scalar=False, image=None) -> int:
        """The index in ``textures`` of an Image Texture node's image (or
        ``image``: a UDIM tile's, :meth:`udim_tiles`), its
        colour through ``ops`` (``core.scene.color_ops``: one more entry per
        image and ops, the ops applied to the colour Cycles' Color output
        gives at each texel); scalar: an entry of white texels whose alpha
        is that colour read as a float input reads it (its luminance,
        clamped to [0, 1]); -1 (and a note) without pixels."""
        img = node.image if image is None else image
        if img is None:
            mb.notes.append(f"{node.name}: no image")
            return -1
        if image is None and img.source == 'SEQUENCE':
            # Image.pixels of a sequence is empty: the frame of this render
            # is read from its own file.
            frame = sequence_frame(node.image_user, self.scene.frame_current)
            key = (img.name_full, frame, ops, scalar, self.texture_sampler(node, []))
            if key not in self.seq_index:
                timg = sequence_image(img, node.image_user, self.scene.frame_current)
                if timg is None:
                    mb.notes.append(f"image '{img.name}': frame {frame} of the sequence could "
                                    f"not be read")
                    self.seq_index[key] = self.texture(node, mb, ops, scalar, image=img)
                else:
                    self.seq_index[key] = self.stand_in_texture(node, mb, timg, ops, scalar)
            return self.seq_index[key]
        # Cycles interpolates the colour associated with (multiplied by)
        # alpha, and divides by the interpolated alpha only when the node's
        # Alpha output is linked (NODE_IMAGE_ALPHA_UNASSOCIATE).  One entry
        # of textures per image and reading; the pixels are read once.
        out = node.outputs.get("Alpha")
        mode = 'UNASSOCIATED' if out is not None and out.is_linked else 'ASSOCIATED'
        key = img.name_full
        if key not in self.tex_pixels:
            px = self.pixels(img, mb.notes)
            self.tex_pixels[key] = px
        px = self.tex_pixels[key]
        if px is None:
            return -1
        if (getattr(img, "alpha_mode", 'STRAIGHT') != 'STRAIGHT' or px.shape[2] < 4
                or not np.any(px[..., 3] < 1.0)):
            mode = 'STRAIGHT'     # read as stored
        sampler = self.texture_sampler(node, mb.notes)
        if ops or scalar:
            ik = (key, mode, ops, scalar, sampler)
            if ik not in self.tex_index:
                # Cycles' Color output at a texel: the colour associated with
                # alpha unless the Alpha output is linked (then straight).
                if mode == 'ASSOCIATED':
                    px = np.concatenate([px[..., :3] * px[..., 3:4], px[..., 3:]], -1)
                px, rgb = self.folded(with_sampler(px, sampler), ops, mb.notes)
                if scalar:
                    out = np.ones(px.shape[:2] + (4,), np.float32)
                    out[..., 3] = np.clip(CO.gray(rgb), 0.0, 1.0)
                else:
                    out = np.empty(px.shape[:2] + (max(px.shape[2], 3),), np.float32)
                    out[..., :3] = rgb
                    if px.shape[2] > 3:
                        out[..., 3:] = px[..., 3:]
                self.poll()
                self.tex_index[ik] = len(self.textures)
                self.textures.append(with_sampler(out, sampler))
            return self.tex_index[ik]
        ik = (key, mode, sampler)
        if ik not in self.tex_index:
            if mode != 'STRAIGHT':
                px = px.copy()
                px[..., :3] *= px[..., 3:4]
                if mode == 'UNASSOCIATED':
                    px = px.view(UnassociatedImage)
            self.tex_index[ik] = len(self.textures)
            self.textures.append(with_sampler(px, sampler))
        return self.tex_index[ik]

    @staticmethod
    def texture_sampler(node, notes) -> int:
        """An Image Texture node's interpolation and extension
        (``textures.sampler_code``; Smart is Cubic, as on Cycles' CPU)."""
        interp = getattr(node, "interpolation", 'Linear')
        if interp not in INTERPOLATIONS:
            notes.append(f"{node.name}: {interp} interpolation read as Linear")
        return sampler_code(INTERPOLATIONS.get(interp, LINEAR),
                            EXTENSIONS.get(getattr(node, "extension", 'REPEAT'), REPEAT))

    def node_pixels(self, node, notes) -> np.ndarray | None:
        """The pixels of an Image Texture node's image (:meth:`pixels`, read
        once per image), None (and a note) without any."""
        img = node.image
        if img is None:
            notes.append(f"{node.name}: no image")
            return None
        key = img.name_full
        if key not in self.tex_pixels:
            self.tex_pixels[key] = self.pixels(img, notes)
        return self.tex_pixels[key]

    def color_texels(self, node, notes) -> np.ndarray | None:
        """(H, W, C) float32 texels of an Image Texture node as its Color
        output reads them (the colour associated with a straight alpha, as
        :meth:`texture` reads it without a linked Alpha output), None (and a
        note) without pixels."""
        px = self.node_pixels(node, notes)
        if px is None:
            return None
        if getattr(node.image, "alpha_mode", 'STRAIGHT') == 'STRAIGHT' and px.shape[2] >= 4:
            px = np.concatenate([px[..., :3] * px[..., 3:4], px[..., 3:]], -1)
        return with_sampler(px, self.texture_sampler(node, []))

    def folded(self, px, ops, notes, shape=None):
        """(px, rgb): texels px (H, W, C) resampled to ``shape`` and their
        colour (H', W', 3) float64 through ``ops`` (``core.scene.color_ops``).
        shape None: the largest grid of the chain's images, enlarged for a
        nonlinear chain (Cycles applies the nodes after the bilinear lookup,
        so a small image is first enlarged up to UPSAMPLE_FACTOR times,
        ``textures.upsample``).  A "mix_image" op's second image is folded
        through its own ops on the same grid and mixed as an array (a
        missing image reads Cycles' magenta)."""
        others = [op for op in ops if op[0] == "mix_image"]
        if shape is None:
            sizes = [px.shape[:2]] + [self._chain_size(op, notes) for op in others]
            H, W = max(h for h, _ in sizes), max(w for _, w in sizes)
            k = 1 if CO.is_affine(ops) else min(UPSAMPLE_MAX // max(H, W), UPSAMPLE_FACTOR)
            shape = (H * k, W * k) if k > 1 else (H, W)
        if tuple(px.shape[:2]) != tuple(shape):
            px = resample(px, *shape)
        done = []
        for op in ops:
            if op[0] == "mix_image":
                _, blend, t, node, oops, clamp = op
                opx = self.color_texels(node, notes)
                if opx is None:
                    orgb = np.broadcast_to(MISSING_IMAGE, tuple(shape) + (3,))
                else:
                    orgb = self.folded(opx, oops, notes, shape)[1]
                op = ("mix", blend, t, orgb, "A", clamp)
            done.append(op)
        return px, CO.apply(tuple(done), px[..., :3].astype(np.float64))

    def _chain_size(self, op, notes):
        """(H, W) the largest grid of a "mix_image" op's images."""
        opx = self.color_texels(op[3], notes)
        sizes = [(1, 1) if opx is None else opx.shape[:2]]
        sizes += [self._chain_size(o, notes) for o in op[4] if o[0] == "mix_image"]
        return max(h for h, _ in sizes), max(w for _, w in sizes)

    def image_mean(self, node, output, notes, ops=()) -> float | None:
        """The mean over an Image Texture node's image of the float Cycles
        reads from its output 'Color' (Rec.709 luminance of the linear
        colour, ``textures.scalar_weights``; through the colour nodes
        ``ops``, ``core.scene.color_ops``) or 'Alpha' (1 without an alpha
        channel); None (and a note) when the image has no pixels."""
        px = self.node_pixels(node, notes)
        if px is None:
            return None
        if output == 'Alpha' and px.shape[2] < 4:
            return 1.0
        if ops and output == 'Color':
            return float(np.mean(CO.gray(self.folded(px, ops, notes)[1])))
        w = scalar_weights(px, 'ALPHA' if output == 'Alpha' else 'COLOR')
        return float(np.mean(px.reshape(-1, px.shape[2]).astype(np.float64) @ w))

    def pixels(self, img, notes) -> np.ndarray | None:
        """(H, W, C >= 3) float32 scene-linear pixels of a Blender image, row 0
        at the bottom, or None (and a note) when it has none.  Checked against
        free memory before loading; cancel is polled between the copies."""
        self.poll()
        capacity = self.check_image_memory(img)
        self.poll()
        # Image.pixels has no partial read: made / decoded and read in a
        # child process that a cancel kills (export_read.image_pixels).
        px, w, h, c, is_float = image_pixels(
            img, capacity, self.poll if self.should_stop is not _never else _never)
        self.poll()
        if w * h == 0 or c == 0:
            notes.append(f"image '{img.name}' could not be loaded")
            return None
        px = px.reshape(h, w, c)          # Blender's order: row 0 at the bottom
        rows = max(1, CHUNK // w)
        if c < 3:
            grey = px
            px = np.empty((h, w, 3), np.float32)
            for r in range(0, h, rows):
                px[r:r + rows] = grey[r:r + rows, :, :1]
                self.poll()
            del grey
        cs = img.colorspace_settings.name
        if not is_float:
            # Byte images come back undecoded; float images are scene linear.
            # Decoded in place (px is our own copy), a band of rows at a time.
            decode = cs not in ('Non-Color', 'Linear Rec.709', 'Linear', 'Raw', 'Linear CIE-XYZ E')
            if decode and cs != 'sRGB':
                notes.append(f"image '{img.name}': colour space '{cs}' decoded as sRGB")
            if decode:
                for r in range(0, h, rows):
                    px[r:r + rows, :, :3] = srgb_to_linear(px[r:r + rows, :, :3])
                    self.poll()
        return np.ascontiguousarray(px, np.float32)

    # -- materials -------------------------------------------------------------
    def material(self, mat) -> int:
        key = None if mat is None else mat.name_full
        idx = self.mat_index.get(key)
        if idx is None and mat is None:
            idx = self.mat_index[key] = len(self.materials)
            self.materials.append(DEFAULT_MATERIAL)
            self.mat_pass_index.append(0)
            self.mat_crypto.append(crypto.DEFAULT_MATERIAL)
            self.mat_vector.append(None)
            self.mat_displace.append(None)
        if idx is None:
            mb = _MaterialBuilder(self, mat)
            m = mb.build()
            if mb.unsupported:
                self.log(f"Warning: material '{mat.name}': unsupported node(s) "
                         + ", ".join(f"'{u}'" for u in mb.unsupported)
                         + " replaced by diffuse grey.")
            idx = len(self.materials)
            self.materials.append(m)
            self.mat_pass_index.append(int(getattr(mat, "pass_index", 0)))
            self.mat_crypto.append(mat.name)
            self.mat_vector.append(None if mb.bakes else mb.vector_spec)
            self.mat_displace.append(mb.true_displacement)
            if mb.displacement_spaces is not None and self.materials[idx].normal is not None \
                    and any(mb.displacement_spaces):
                self.disp_spaces[idx] = mb.displacement_spaces
            self.atlas.add_material(idx, mb)
            self.mat_index[key] = idx
        return idx

    # -- geometry --------------------------------------------------------------
    @staticmethod
    def mesh_arrays(me, poll=_never):
        """Local-space (T,3,3) positions and normals, (T,3,2) uvs, (T,) slot
        index: ``export_read.mesh_arrays`` (its reads are cut for cancel)."""
        return mesh_arrays(me, poll)

    def geometry(self, inst, ob, parts):
        if ob.type == 'MESH':
            me = ob.data
            key = me.as_pointer()
            arrs = self.mesh_cache.get(key)
            if arrs is None:
                arrs = self.mesh_arrays(me, self.poll)
                self.mesh_cache[key] = arrs
            mats = [s.material for s in ob.material_slots] or list(me.materials)
            has_uv = len(me.uv_layers) > 0
        else:
            try:
                me = ob.to_mesh()
            except RuntimeError:
                me = None
            if me is None:
                return
            try:
                arrs = self.mesh_arrays(me, self.poll)
                mats = [s.material for s in ob.material_slots] or list(me.materials)
                has_uv = len(me.uv_layers) > 0
            finally:
                ob.to_mesh_clear()
        p, n, uv, slot = arrs
        if p.shape[0] == 0:
            return
        M = _mat4(inst.matrix_world)
        A, t = M[:3, :3], M[:3, 3]
        # Normals transform with the inverse transpose; renormalised.
        try:
            Ninv = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            return  # zero scale: no surface
        T = p.shape[0]
        # Computed in float64 and rounded to float32 once (band by band).
        pw = np.empty((T, 3, 3), np.float32)
        nw = np.empty((T, 3, 3), np.float32)
        for a in range(0, T, CHUNK):
            pw[a:a + CHUNK] = (_linear(A, p[a:a + CHUNK].reshape(-1, 3)) + t).reshape(-1, 3, 3)
            nb = _linear(Ninv.T, n[a:a + CHUNK].reshape(-1, 3))
            nb /= np.maximum(np.linalg.norm(nb, axis=1, keepdims=True), 1e-30)
            nw[a:a + CHUNK] = nb.reshape(-1, 3, 3)
            self.poll()
        if np.linalg.det(A) < 0:
            # A mirroring transform flips the winding; swap two corners so the
            # geometric normal keeps agreeing with the shading normals.
            pw = pw[:, [0, 2, 1]]
            nw = nw[:, [0, 2, 1]]
            uv = uv[:, [0, 2, 1]]
        lut = np.array([self.material(m) for m in mats] or [self.material(None)], np.int32)
        mat = lut[np.clip(slot, 0, len(lut) - 1)]
        if any(self.mat_displace[m] is not None for m in np.unique(lut)):
            pw, nw = self.displaced(inst, ob, pw, nw, uv, mat, len(parts), A)
        parts.append((pw, nw, uv, mat))
        if self.uv_pass:
            # The render UV map and whether the mesh has one (the UV pass:
            # core.sppm.color_passes), before tri_uv is rewritten.
            self.render_uv_parts.append(np.concatenate(
                [uv, np.full(uv.shape[:2] + (1,), float(has_uv), np.float32)], axis=2))

    def concatenate(self, arrays: list, dtype) -> np.ndarray:
        """``np.concatenate(arrays).astype(dtype)``, copied in bands of CHUNK rows
        with a poll between them; a single array of that dtype is not copied."""
        if len(arrays) == 1 and arrays[0].dtype == dtype:
            return arrays[0]
        out = np.empty((sum(len(a) for a in arrays),) + arrays[0].shape[1:], dtype)
        at = 0
        for a in arrays:
            for b in range(0, len(a), CHUNK):
                band = a[b:b + CHUNK]
                out[at:at + len(band)] = band
                at += len(band)
                self.poll()
        return out

    def tri_visibility(self):
        """(T,) uint8 RAY_* flags of the triangles' objects, or None when
        every object is seen by every ray (the renderer's plain path)."""
        if not self.vis_parts or all(np.all(v == RAY_ALL) for v in self.vis_parts):
            return None
        return self.concatenate(self.vis_parts, np.uint8)

    def ray_variants(self) -> tuple:
        """(the scene's materials, their pass indices, {'material_camera',
        'material_shadow': (M',) int32 or nothing}): the materials, then the
        ones camera rays or shadow rays see in place of some of them
        (``Material.camera`` / ``shadow``: a Light Path node;
        core.scene.ray_variants)."""
        mats = [dataclasses.replace(m, camera=None, shadow=None)
                if m.camera is not None or m.shadow is not None else m for m in self.materials]
        pass_index = list(self.mat_pass_index)
        rows = {}
        for i, m in enumerate(self.materials):
            for kind in ("camera", "shadow"):
                v = getattr(m, kind)
                if v is not None:
                    r = rows.setdefault(kind, list(range(len(self.materials))))
                    r[i] = len(mats)
                    mats.append(v)
                    pass_index.append(pass_index[i])
        return mats, pass_index, {"material_" + k: np.asarray(r + list(range(len(r), len(mats))),
                                                               np.int32)
                                  for k, r in rows.items()}

    def crypto_ids(self, ob, parts) -> None:
        """The Cryptomatte IDs (object, material, asset) of the triangles of
        ``ob``'s parts, just made by :meth:`geometry` (their materials still
        the rows of :meth:`material`)."""
        obj, asset = ob.name, crypto.asset_name(ob)
        for k, n in (("Object", obj), ("Asset", asset)):
            self.crypto_names[k].add(n)
        # The IDs of the materials made since the last object (mat_crypto:
        # their names, in material() order), hashed once each.
        new = self.mat_crypto[self.mat_ids.size:]
        if new:
            self.crypto_names["Material"].update(new)
            self.mat_ids = np.concatenate(
                [self.mat_ids, np.array([crypto.name_id(n) for n in new], np.float32)])
        row = np.array([crypto.name_id(obj), 0.0, crypto.name_id(asset)], np.float32)
        for q in parts:
            ids = np.repeat(row[None, :], len(q[0]), axis=0)
            ids[:, 1] = self.mat_ids[q[3]]
            self.crypto_parts.append(ids)

    def tri_holdout(self):
        """(T,) bool the triangles of holdout objects, or None when none is
        (core.scene.holdout)."""
        if not any(h.any() for h in self.holdout_parts):
            return None
        return self.concatenate(self.holdout_parts, bool)

    def drop_invalid(self, fscene: Scene) -> tuple[Scene, int]:
        """``drop_invalid_triangles`` band by band, polled between bands.

        The check is per triangle, so the bands give the same scene as one
        call, which takes long for big meshes (docs/reliability.md).
        """
        T = fscene.n_triangles
        if T <= CHUNK:
            return drop_invalid_triangles(fscene)
        per_tri = ("tri_p", "tri_n", "tri_uv", "tri_mat", "tri_object_index", "tri_tangent",
                   "tri_visibility", "tri_holdout", "tri_blocker", "tri_shadow_sets", "tri_crypto",
                   "tri_catcher", "tri_render_uv", "tri_bump_scale")
        bands, dropped = [], 0
        for a in range(0, T, CHUNK):
            band = dataclasses.replace(fscene, **{
                k: (None if getattr(fscene, k) is None else getattr(fscene, k)[a:a + CHUNK])
                for k in per_tri})
            band, d = drop_invalid_triangles(band)
            bands.append(band)
            dropped += d
            self.poll()
        if not dropped:
            return fscene, 0
        return dataclasses.replace(fscene, **{
            k: (None if getattr(fscene, k) is None
                else np.concatenate([getattr(b, k) for b in bands]))
            for k in per_tri}), dropped

    # -- shading attributes: texture coordinates and tangents -------------------
    def shading_attributes(self, inst, ob, parts, n0: int) -> None:
        """For the parts[n0:] that ``geometry`` just added for ``ob``: the
        texture coordinates of materials whose Image Textures read Generated,
        Object or mapped UV coordinates (``tri_uv`` rewritten to x, y of the
        mapped vector, exact per corner since every mapping is affine), and
        the MikkTSpace tangents of Normal Map materials (``tangent_parts``)."""
        for i in range(n0, len(parts)):
            pw, nw, uv, mat = parts[i]
            used = np.unique(mat)
            new_uv = None
            if self.disp_spaces:
                self.pad_bump_scales(parts, i)
                self.bump_scale_parts.append(self.displacement_scales(inst, pw, mat))
            for m in used:
                if m in self.atlas.keys:
                    if new_uv is None:
                        new_uv = uv.copy()
                    self.record_atlas(inst, ob, i, np.nonzero(mat == m)[0], m, pw, nw, uv)
                    continue
                spec = self.mat_vector[m]
                if spec is None:
                    continue
                src, obname, A = spec
                if src == 'UV' and obname is None and np.allclose(A, np.eye(4)):
                    continue
                rows = np.nonzero(mat == m)[0]
                uvs = uv
                if src == 'UV' and obname is not None:
                    uvs = self.named_uv(inst, ob, obname)
                    if uvs is None or len(uvs) != len(uv):
                        self.notes.append(f"'{ob.name}': no UV map '{obname}': the render "
                                          f"UV map used")
                        uvs = uv
                gen = self.undisplaced.get(i, pw) if src == 'Generated' else pw
                v3 = self.texture_vectors(inst, ob, src, obname, gen[rows], uvs[rows])
                if v3 is None:
                    continue
                if new_uv is None:
                    new_uv = uv.copy()       # uv may be the mesh cache's array
                v3 = v3 @ A[:3, :3].T + A[:3, 3]
                new_uv[rows] = v3[..., :2].astype(np.float32)
                self.poll()
            if new_uv is not None:
                parts[i] = (pw, nw, new_uv, mat)
            needs = any(_uses_normal_map(self.materials[m].normal) for m in used)
            self.tangent_parts.append(self.tangents(inst, ob) if needs else None)

    def pad_bump_scales(self, parts, n: int) -> None:
        """Factors of 1 for the parts before parts[n] that have none (exported
        before the first material with a displacement's bump)."""
        while len(self.bump_scale_parts) < n:
            self.bump_scale_parts.append(
                np.ones(len(parts[len(self.bump_scale_parts)][0]), np.float32))

    def displacement_scales(self, inst, pw, mat) -> np.ndarray:
        """(T,) float32 the factor on the bump distance of a part's triangles
        (``Scene.tri_bump_scale``): for a displacement's bump, the object's
        stretch a = |M^T n| along the world normal n (the face's), once when
        the height is in object space (Cycles' object_dir_transform of the
        displacement vector, whose component along n is the height) and once
        more when the bump is in object space (Displacement and Bump: the
        object-space bump's normal taken back by M^-T); 1 elsewhere.
        docs/shading.md "Displacement"."""
        k = np.ones(len(mat), np.float32)
        sel = np.nonzero(np.isin(mat, list(self.disp_spaces)))[0]
        if sel.size:
            A = _mat4(inst.matrix_world)[:3, :3]
            p = np.asarray(pw[sel], np.float64)
            n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
            a = np.linalg.norm(n @ A, axis=1)          # |A^T n|
            spaces = np.array([self.disp_spaces[int(m)] for m in mat[sel]], bool)
            k[sel] = np.where(spaces[:, 0], a, 1.0) * np.where(spaces[:, 1], a, 1.0)
        return k

    def record_atlas(self, inst, ob, i, rows, m, pw, nw, uv) -> None:
        """Hands the triangles ``rows`` of parts[i] (of atlas material m) to
        the baker with the attributes its graph reads at their corners
        (core/scene/shader_graph.py ``Attr`` keys); instances of one mesh
        share their blocks when every attribute is the mesh's own (UV maps,
        Generated, its own Object space and normals, colour attributes)."""
        attrs, own = self.corner_attributes(inst, ob, self.atlas.keys[m], rows, pw, nw, uv,
                                            self.undisplaced.get(i))
        key = None
        if own and ob.type == 'MESH':
            key = (ob.data.as_pointer(), m,
                   bool(np.linalg.det(_mat4(inst.matrix_world)[:3, :3]) < 0))
        self.atlas.record(m, i, rows, attrs, pw[rows].astype(np.float64), key)
        self.poll()

    def corner_attributes(self, inst, ob, keys, rows, pw, nw, uv, pw_orco=None):
        """({key: (k, 3, 3) float64 at the corners of triangles ``rows``}, own)
        of the shader-graph attribute keys ``keys`` on ``ob``'s triangles
        (world corners pw, normals nw, render uvs uv; pw_orco: the corners
        before a true displacement, which Generated reads as Cycles reads
        its undisplaced coordinates); own: every attribute is the mesh's
        own (instances may share what is computed from them)."""
        attrs, own = {}, True
        k = len(rows)
        gen = pw if pw_orco is None else pw_orco
        for key in keys:
            kind, name = key[0], (key[1] if len(key) > 1 else None)
            if kind == 'UV':
                uvs = uv if name is None else self.named_uv(inst, ob, name)
                if uvs is None or len(uvs) != len(uv):
                    self.notes.append(f"'{ob.name}': no UV map '{name}': the render UV "
                                      f"map used")
                    uvs = uv
                a = self.texture_vectors(inst, ob, 'UV', None, pw[rows], uvs[rows])
            elif kind in ('Generated', 'Object'):
                a = self.texture_vectors(inst, ob, kind, name,
                                         (gen if kind == 'Generated' else pw)[rows], uv[rows])
                own = own and name is None
            elif kind == 'Position':
                a, own = pw[rows].astype(np.float64), False
            elif kind == 'Normal':
                a, own = nw[rows].astype(np.float64), False
            elif kind == 'ObjectNormal':
                # World normals back to object space: n_obj ~ A^T n_world.
                A = _mat4(inst.matrix_world)[:3, :3]
                a = nw[rows].astype(np.float64) @ A
            elif kind == 'ObjectInfo':
                a, own = np.broadcast_to(_object_info(inst, ob, name), (k, 3, 3)), False
            elif kind == 'Camera':
                p = pw[rows].astype(np.float64).reshape(-1, 3)
                a, own = (None if self.camera_model is None else
                          self.camera_model.camera_space(p).reshape(k, 3, 3)), False
            elif kind in ('ObjectAttr', 'ObjectAttrAlpha'):
                v = id_attribute((ob, getattr(ob, "data", None)), name)
                v = v[:3] if kind == 'ObjectAttr' else np.full(3, v[3])
                a, own = np.broadcast_to(v, (k, 3, 3)), False
            elif kind == 'ObjectAxis':
                col = _mat4(inst.matrix_world)[:3, name]
                a, own = np.broadcast_to(col, (k, 3, 3)), False
            elif kind == 'TrueNormal':
                p = pw[rows].astype(np.float64)
                f = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
                a, own = np.repeat(f[:, None, :], 3, axis=1), False
            elif kind in ('Pointiness', 'RandomPerIsland'):
                a = self.geometry_corners(inst, ob, kind)
                a = None if a is None or len(a) != len(uv) else a[rows]
                if a is None:
                    self.notes.append(f"'{ob.name}': Geometry {kind} is for meshes: black")
            else:                                   # 'Attribute'
                a = self.attribute_corners(inst, ob, name)
                a = None if a is None or len(a) != len(uv) else a[rows]
                if a is None:
                    self.notes.append(f"'{ob.name}': no attribute "
                                      f"'{name or '(render colour)'}': black")
            attrs[key] = np.zeros((k, 3, 3)) if a is None else a
        return attrs, own

    def displaced(self, inst, ob, pw, nw, uv, mat, i, A):
        """(pw, nw) of ``ob``'s triangles (parts[i] to be) after the true
        displacement of their materials (addon/export_displace.py); the
        corners before it kept for the Generated coordinates."""
        if ob.type != 'MESH':
            self.notes.append(f"'{ob.name}': true displacement applies to meshes: not "
                              f"applied to this {ob.type.lower()}")
            return pw, nw
        vid, smooth, corner_normals = corner_topology(ob.data, self.poll)
        if np.linalg.det(A) < 0:
            vid = vid[:, [0, 2, 1]]           # geometry's winding swap
        if len(vid) != len(pw):
            return pw, nw

        def height_at(m, tris, corners):
            spec = self.mat_displace[m]
            keys = sorted(SG.attributes(spec.height), key=repr)
            attrs, _ = self.corner_attributes(inst, ob, keys, tris, pw, nw, uv)
            pts = {k: v[np.arange(len(tris)), corners] for k, v in attrs.items()}
            return SG.evaluate(spec.height, SG.EvalContext(pts, self.textures))

        out = displace(pw, nw, vid, smooth, corner_normals, mat, self.mat_displace, A,
                       height_at)
        self.undisplaced[i] = pw
        self.poll()
        return out

    def geometry_corners(self, inst, ob, kind):
        """(T, 3, 3) float64 the Geometry node's Pointiness (a value a
        vertex) or Random Per Island (a value a triangle) at the corners of
        ``ob``'s loop triangles, as Cycles computes them from the evaluated
        mesh (core/scene/mesh_attributes.py); None for other objects."""
        if ob.type != 'MESH' or not len(ob.data.loop_triangles):
            return None
        me = ob.data
        ckey = (me.as_pointer(), "geometry", kind)
        local = self.uv_cache.get(ckey)
        if local is None:
            local = _geometry_corners(me, kind)
            self.uv_cache[ckey] = local
            self.poll()
        if np.linalg.det(_mat4(inst.matrix_world)[:3, :3]) >= 0:
            return local
        return local[:, [0, 2, 1]]

    def attribute_corners(self, inst, ob, name):
        """(T, 3, 3) float64 a mesh attribute at the corners of ``ob``'s loop
        triangles (a colour attribute's rgb, a vector, a float as (f, f, f),
        a 2D vector with z 0; ``name`` None: the render colour attribute; a
        UV map of that name as (u, v, 0), as Cycles' Attribute node reads
        it), in ``geometry``'s corner order; None when there is none."""
        if ob.type != 'MESH':
            return None
        me = ob.data
        ckey = (me.as_pointer(), "attribute", name)
        local = self.uv_cache.get(ckey, False)
        if local is False:
            local = _attribute_corners(me, name)
            if local is None and name is not None and me.uv_layers.get(name) is not None:
                uvs = self.named_uv(inst, ob, name)
                if np.linalg.det(_mat4(inst.matrix_world)[:3, :3]) < 0:
                    uvs = uvs[:, [0, 2, 1]]          # named_uv's swap, undone
                local = np.concatenate([uvs, np.zeros(uvs.shape[:2] + (1,))], axis=2)
            self.uv_cache[ckey] = local
            self.poll()
        if local is None or np.linalg.det(_mat4(inst.matrix_world)[:3, :3]) >= 0:
            return local
        return local[:, [0, 2, 1]]

    def texture_vectors(self, inst, ob, src, obname, pw, uv):
        """(k, 3, 3) float64 texture vectors at the corners: UV (u, v, 0),
        Generated (the object-space position in the mesh's texture space,
        0..1 over its bounds) or Object (the position in ``obname``'s space,
        or ``ob``'s); None (and a note) when unavailable."""
        if src == 'UV':
            return np.concatenate([uv.astype(np.float64), np.zeros(uv.shape[:2] + (1,))], axis=2)
        M = _mat4(inst.matrix_world)
        if src == 'Object' and obname is not None:
            other = self.scene.objects.get(obname)
            if other is None:
                return None
            M = _mat4(other.evaluated_get(self.dg).matrix_world)
        try:
            Minv = np.linalg.inv(M)
        except np.linalg.LinAlgError:
            return None
        local = pw.astype(np.float64) @ Minv[:3, :3].T + Minv[:3, 3]
        if src == 'Object':
            return local
        data = getattr(ob, "data", None)
        loc = getattr(data, "texspace_location", None)
        size = getattr(data, "texspace_size", None)
        if loc is None or size is None:
            self.notes.append(f"Generated coordinates of '{ob.name}' unavailable: UVs used")
            return None
        loc, size = np.array(loc, np.float64), np.array(size, np.float64)
        size = np.where(np.abs(size) > 1e-12, size, 1.0)
        return (local - (loc - size)) / (2.0 * size)

    def named_uv(self, inst, ob, name):
        """(T, 3, 2) float32 uvs of ``ob``'s UV map ``name`` at the corners of
        its loop triangles, in the corner order of ``geometry`` (two corners
        swapped under a mirroring transform); None when the mesh has no such
        map (or ``ob`` is no mesh)."""
        if ob.type != 'MESH':
            return None
        me = ob.data
        key = (me.as_pointer(), name)
        local = self.uv_cache.get(key, False)
        if local is False:
            local = None
            layer = me.uv_layers.get(name)
            if layer is not None and len(me.loop_triangles):
                L = len(me.loops)
                uvl = np.empty(L * 2, np.float32)
                layer.uv.foreach_get("vector", uvl)
                corners = np.empty(len(me.loop_triangles) * 3, np.int32)
                me.loop_triangles.foreach_get("loops", corners)
                local = uvl.reshape(L, 2)[corners].reshape(-1, 3, 2)
            self.uv_cache[key] = local
            self.poll()
        if local is None or np.linalg.det(_mat4(inst.matrix_world)[:3, :3]) >= 0:
            return local
        return local[:, [0, 2, 1]]

    def tangents(self, inst, ob):
        """(T, 3, 4) float32 world-space MikkTSpace tangents (xyz) and
        bitangent signs (w) at the corners of ``ob``'s loop triangles, in the
        corner order of ``geometry``; None when the mesh has no UV map or the
        tangents cannot be computed (then ``core.scene.normals`` uses each
        triangle's dP/du)."""
        if ob.type != 'MESH':
            return None
        me = ob.data
        key = me.as_pointer()
        local = self.tangent_cache.get(key, False)
        if local is False:
            local = None
            layer = me.uv_layers.active_render or me.uv_layers.active
            if layer is not None and len(me.loop_triangles):
                try:
                    me.calc_tangents(uvmap=layer.name)
                    L = len(me.loops)
                    t = np.empty(L * 3, np.float32)
                    sg = np.empty(L, np.float32)
                    me.loops.foreach_get("tangent", t)
                    me.loops.foreach_get("bitangent_sign", sg)
                    me.free_tangents()
                    corners = np.empty(len(me.loop_triangles) * 3, np.int32)
                    me.loop_triangles.foreach_get("loops", corners)
                    local = np.concatenate([t.reshape(L, 3)[corners], sg[corners, None]],
                                           axis=1).reshape(-1, 3, 4)
                except RuntimeError as e:
                    self.notes.append(f"'{ob.name}': tangents not computed ({e}): "
                                      f"per-triangle tangents used")
            self.tangent_cache[key] = local
            self.poll()
        if local is None:
            return None
        A = _mat4(inst.matrix_world)[:3, :3]
        tw = _linear(A, local[..., :3].reshape(-1, 3))
        tw /= np.maximum(np.linalg.norm(tw, axis=1, keepdims=True), 1e-30)
        out = np.empty(local.shape, np.float32)
        out[..., :3] = tw.reshape(-1, 3, 3)
        det = np.linalg.det(A)
        # A mirroring transform flips the bitangent (and geometry() swaps corners).
        out[..., 3] = local[..., 3] * (1.0 if det >= 0 else -1.0)
        if det < 0:
            out = out[:, [0, 2, 1]]
        return out

    # -- lights ----------------------------------------------------------------
    def light(self, inst, ob) -> Light | None:
        ld = ob.data
        color = np.array(ld.color, np.float64)
        if getattr(ld, "use_temperature", False):
            color = color * np.array(ld.temperature_color, np.float64)
        strength = color * float(ld.energy) * 2.0 ** float(getattr(ld, "exposure", 0.0))
        M = _mat4(inst.matrix_world)
        kind = ld.type
        kw = dict(name=ob.name, kind=kind, matrix_world=M,
                  visible_camera=bool(getattr(ob, "visible_camera", True)),
                  visible_glossy=bool(getattr(ob, "visible_glossy", True)),
                  visible_transmission=bool(getattr(ob, "visible_transmission", True)),
                  visible_diffuse=bool(getattr(ob, "visible_diffuse", True)),
                  cast_shadow=bool(getattr(ld, "use_shadow", True)))
        factor, ies = light_nodes(ld, ob.name, kind, self.notes)
        strength = strength * factor
        if ies is not None:
            kw["ies"] = ies
        if kind in ('POINT', 'SPOT'):
            kw["radius"] = float(ld.shadow_soft_size)
            kw["use_soft_falloff"] = bool(getattr(ld, "use_soft_falloff", True))
            if not getattr(ld, "normalize", True):
                # Cycles' unnormalised point light: radiance strength / pi on
                # its disc instead of strength / (pi 4 pi r^2), i.e. the power
                # times 4 pi r^2; with radius 0 an intensity strength / pi
                # instead of strength / (4 pi) (measured: docs/cycles_units.md).
                r = float(ld.shadow_soft_size)
                strength = strength * (4.0 * math.pi * r * r if r > 0 else 4.0)
            if kind == 'SPOT':
                kw["spot_size"] = float(ld.spot_size)
                kw["spot_blend"] = float(ld.spot_blend)
        elif kind == 'SUN':
            kw["angle"] = float(ld.angle)
            if not getattr(ld, "normalize", True) and ld.angle > 0:
                # Unnormalised: radiance = strength, not strength divided by
                # the disc's projected solid angle pi sin^2(angle / 2).
                strength = strength * (math.pi * math.sin(0.5 * float(ld.angle)) ** 2)
        elif kind == 'AREA':
            kw.update(shape=ld.shape, size=float(ld.size), size_y=float(ld.size_y),
                      spread=float(getattr(ld, "spread", math.pi)))
            if not getattr(ld, "normalize", True):
                # Cycles divides by the area only when normalised: undo core's division.
                sx = np.linalg.norm(M[:3, 0])
                sy = np.linalg.norm(M[:3, 1])
                a = {'SQUARE': ld.size ** 2, 'RECTANGLE': ld.size * ld.size_y,
                     'DISK': math.pi * ld.size ** 2 / 4,
                     'ELLIPSE': math.pi * ld.size * ld.size_y / 4}[ld.shape]
                strength = strength * a * sx * sy
        else:
            self.notes.append(f"light '{ob.name}': type {kind} skipped")
            return None
        return Light(strength=tuple(float(x) for x in strength), **kw)

    # -- world -----------------------------------------------------------------
    def world(self) -> tuple[np.ndarray, EnvironmentMap | None]:
        """(constant colour (3,), environment map or None) of the scene's world.

        The Background node's Color: unlinked or an RGB node -> a constant;
        an Environment Texture (equirectangular) -> a map, with the Mapping
        and Texture Coordinate (Generated/Object) nodes on its Vector input
        as Cycles evaluates them (:meth:`world_vector`).  Anything else (a
        Sky Texture, other textures, a linked Strength, a shader other than
        one Background) is baked by Cycles (:meth:`baked_world`)."""
        w = self.scene.world
        if w is None:
            return np.zeros(3), None
        if not _use_nodes(w):
            return np.array(w.color, np.float64)[:3], None
        outs = [nd for nd in w.node_tree.nodes if nd.type == 'OUTPUT_WORLD'
                and getattr(nd, "target", 'ALL') in ('ALL', 'CYCLES')]
        active = [nd for nd in outs if nd.is_active_output] or outs
        if not active:
            return np.zeros(3), None
        vol = active[0].inputs.get("Volume")
        if vol is not None and vol.is_linked:
            self.notes.append("world: volume ignored")
        node, _ = _follow(active[0].inputs["Surface"])
        if node is None:
            return np.zeros(3), None
        if node.type != 'BACKGROUND':
            return self.baked_world(w, f"'{node.name}'", np.zeros(3))
        col = node.inputs["Color"]
        st = node.inputs["Strength"]
        strength = float(st.default_value)
        c = np.array(col.default_value, np.float64)[:3]
        if st.is_linked:
            return self.baked_world(w, "a linked Strength", c * strength)
        src, _ = _follow(col)
        if src is None:
            return c * strength, None
        if src.type == 'RGB':
            return np.array(src.outputs[0].default_value, np.float64)[:3] * strength, None
        if src.type == 'TEX_ENVIRONMENT' and getattr(src, "projection",
                                                     'EQUIRECTANGULAR') == 'EQUIRECTANGULAR':
            env = self.environment(src, strength)
            if env is not None:
                # Scene.world_color: the map's mean radiance.
                return mean_radiance(env), env
            return c * strength, None
        return self.baked_world(w, f"'{src.name}'", c * strength)

    def baked_world(self, w, what: str, fallback: np.ndarray):
        """(mean colour (3,), map) of the world rendered by Cycles
        (addon/world_bake.py); a Sky Texture's sun disc becomes
        ``self.world_sun``, a sun light.  When the bake fails: ``fallback``
        (the Background colour, or black) with a note."""
        from .world_bake import WIDTH, BakeError, bake_world
        instead = 'black' if not np.any(fallback) else 'the Background colour'
        try:
            baked = bake_world(w, self.scene.frame_current, WIDTH, poll=self.poll,
                               wait=self.bake_wait)
        except (BakeError, OSError, KeyError, ValueError) as ex:
            self.notes.append(f"world: {what} could not be baked by Cycles ({ex}): "
                              f"{instead} is used")
            return fallback, None
        if baked is None:
            self.world_pending = True
            self.log(f"world '{w.name}': {what} is being baked by Cycles; {instead} until "
                     f"it is done.")
            return fallback, None
        h, wd = baked.image.shape[:2]
        said = f"world '{w.name}': {what} baked by Cycles into a {wd}x{h} map"
        if baked.sun is not None:
            E, angle, d = baked.sun
            z = np.asarray(d, np.float64)
            x = np.cross([0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0], z)
            x /= np.linalg.norm(x)
            M = np.eye(4)
            M[:3, 0], M[:3, 1], M[:3, 2] = x, np.cross(z, x), z
            self.world_sun = Light(name=f"{w.name} sun disc", kind='SUN',
                                   strength=tuple(float(v) for v in E), matrix_world=M,
                                   angle=float(angle))
            said += (f" and its sun disc into a sun light ({float(np.mean(E)):.4g} W/m^2, "
                     f"{math.degrees(angle):.3g} deg, elevation "
                     f"{math.degrees(math.asin(max(-1.0, min(1.0, z[2])))):.3g} deg)")
        if baked.camera_image is not None:
            # A Light Path node: camera rays see one map, the rest another.
            said += " (lighting), and as camera rays see it (Light Path) into another"
            from .world_bake import node_trees
            other = sorted({o.name for t in node_trees(w.node_tree) for nd in t.nodes
                            if nd.type == 'LIGHT_PATH' for o in nd.outputs
                            if o.is_linked and o.name != "Is Camera Ray"})
            if other:
                self.notes.append(f"world: Light Path {', '.join(other)} read as a diffuse "
                                  f"ray's by every ray but the camera's")
            self.world_camera_map = EnvironmentMap(
                image=baked.camera_image, strength=np.ones(3), to_texture=np.eye(3),
                name=f"{w.name} (baked for the camera)")
        self.log(f"{said} in {baked.seconds:.1f} s.")
        env = EnvironmentMap(image=baked.image, strength=np.ones(3), to_texture=np.eye(3),
                             name=f"{w.name} (baked)")
        return mean_radiance(env), env


    def environment(self, node, strength: float) -> EnvironmentMap | None:
        """An Environment Texture node -> EnvironmentMap, or None (and a note)."""
        img = node.image
        fallback = "the Background colour is used"
        if img is None:
            self.notes.append(f"world: '{node.name}' has no image: {fallback}")
            return None
        notes: list[str] = []
        px = self.pixels(img, notes)
        self.notes += [f"world: {n}" for n in notes]
        if px is None:
            return None
        interp = getattr(node, "interpolation", 'Linear')
        if interp != 'Linear':
            self.notes.append(f"world: '{node.name}' interpolation '{interp}' rendered as Linear")
        A = self.world_vector(node.inputs.get("Vector"))
        return EnvironmentMap(image=px, strength=np.full(3, strength), to_texture=A,
                              name=img.name)

    def world_vector(self, socket) -> np.ndarray:
        """(3, 3) linear map world direction -> texture vector of a world
        texture's Vector input (Cycles normalises the vector afterwards).

        Unlinked or Texture Coordinate Generated: the direction itself
        (``sd->P = ray_D`` in a background shader).  Object output: the
        object's inverse matrix (``object_inverse_position_transform``).
        A Mapping node in between: Cycles' ``svm_mapping`` (POINT: R (S v) + L,
        TEXTURE: R^T (v - L) / S, VECTOR: R (S v), NORMAL: R (v / S)), R the
        Euler XYZ rotation.  Translations move a direction-dependent
        point, not a direction: they are left out with a note."""
        A = np.eye(3)
        node, out = _follow(socket) if socket is not None else (None, None)
        if node is not None and node.type == 'MAPPING':
            notes = []
            M = _mapping_matrix(node, notes)
            self.notes += [f"world: {n}" for n in notes]
            if np.any(M[:3, 3] != 0):
                self.notes.append(f"world: location of '{node.name}' ignored")
            A = M[:3, :3]
            node, out = _follow(node.inputs["Vector"])
        if node is None:
            pass
        elif node.type == 'TEX_COORD' and out.name in ('Generated', 'Object'):
            ob = node.object if out.name == 'Object' else None
            if ob is not None:
                M = _mat4(ob.evaluated_get(self.dg).matrix_world)
                try:
                    Minv = np.linalg.inv(M)
                except np.linalg.LinAlgError:
                    Minv = np.eye(4)
                if np.any(np.abs(Minv[:3, 3]) > 1e-9):
                    self.notes.append(f"world: location of texture coordinate object "
                                      f"'{ob.name}' ignored")
                A = A @ Minv[:3, :3]
        else:
            self.notes.append(f"world: vector input '{node.name}' ignored "
                              f"(the view direction is used)")
        if abs(np.linalg.det(A)) < 1e-12:
            self.notes.append("world: degenerate mapping ignored")
            A = np.eye(3)
        return A

    def mist(self) -> tuple:
        """(start, depth, falloff exponent) of the world's mist pass; Cycles
        maps the falloff QUADRATIC / LINEAR / INVERSE_QUADRATIC to 2 / 1 / 0.5."""
        ms = getattr(self.scene.world, "mist_settings", None)
        if ms is None:
            return (5.0, 25.0, 2.0)
        fall = {'QUADRATIC': 2.0, 'LINEAR': 1.0, 'INVERSE_QUADRATIC': 0.5}.get(ms.falloff, 2.0)
        return (float(ms.start), float(ms.depth), fall)

    # -- camera ----------------------------------------------------------------
    def camera(self, cam_ob) -> Camera:
        if cam_ob is None or cam_ob.type != 'CAMERA':
            raise SceneError(NO_CAMERA)
        cd = cam_ob.data
        if cd.type not in ('PERSP', 'ORTHO'):
            raise SceneError(f"The camera '{cam_ob.name}' is panoramic: FPPM renders "
                             f"perspective and orthographic cameras only.")
        M = _mat4(cam_ob.matrix_world)
        # Blender and Cycles ignore the camera object's scale.
        M[:3, :3] /= np.maximum(np.linalg.norm(M[:3, :3], axis=0, keepdims=True), 1e-30)
        r = self.scene.render
        pct = r.resolution_percentage
        res = (r.resolution_x * pct // 100, r.resolution_y * pct // 100)
        border = None
        if r.use_border:
            border = (float(r.border_min_x), float(r.border_min_y),
                      float(r.border_max_x), float(r.border_max_y))
            if border == (0.0, 0.0, 1.0, 1.0):
                border = None
        aperture, focus = 0.0, 10.0
        dof = cd.dof
        if dof.use_dof:
            fstop = max(float(dof.aperture_fstop), 1e-5)
            # Cycles (blender/camera.cpp): radius = lens / (2 fstop) [m]; 1/(2 fstop) ortho.
            aperture = 1.0 / (2.0 * fstop) if cd.type == 'ORTHO' else cd.lens * 1e-3 / (2.0 * fstop)
            if dof.focus_object is not None:
                fo = dof.focus_object.evaluated_get(self.dg)
                d = fo.matrix_world.translation - cam_ob.matrix_world.translation
                view = -M[:3, 2]
                focus = max(abs(float(np.dot(view, np.array(d)))), 1e-5)
            else:
                focus = float(dof.focus_distance)
            if dof.aperture_blades >= 3 or abs(dof.aperture_ratio - 1.0) > 1e-6:
                self.notes.append("camera: aperture blades/ratio treated as a round aperture")
        return Camera(kind=cd.type, matrix_world=M, lens=float(cd.lens),
                      sensor_width=float(cd.sensor_width), sensor_height=float(cd.sensor_height),
                      sensor_fit=cd.sensor_fit, ortho_scale=float(cd.ortho_scale),
                      shift_x=float(cd.shift_x), shift_y=float(cd.shift_y),
                      clip_start=float(cd.clip_start), clip_end=float(cd.clip_end),
                      resolution=res,
                      pixel_aspect=(float(r.pixel_aspect_x), float(r.pixel_aspect_y)),
                      border=border, aperture_radius=aperture, focus_distance=focus)

    # -- everything ------------------------------------------------------------
    def run(self, camera_object=None) -> Scene:
        t0 = time.perf_counter()
        scene = self.scene
        cam = self.camera(camera_object if camera_object is not None else scene.camera)
        self.camera_model = CameraModel(cam)
        parts, lights = [], []
        seen = {}
        render_mode = getattr(self.dg, "mode", 'RENDER') == 'RENDER'
        # Light linking (addon/export_links.py): receiver sets, memberships.
        originals = [getattr(o, "original", o) for o in self.dg.objects]
        receiver, membership, notes = light_link_sets(originals)
        self.notes += notes
        # Shadow linking: blocker sets, shadow memberships (the same rules).
        blocker, shadowed, notes = light_link_sets(originals, "shadow")
        self.notes += notes
        for inst in self.dg.object_instances:
            self.poll()
            ob = inst.object
            if ob is None:
                continue
            # A render depsgraph has already left out 'Disable in Renders';
            # a viewport one (tests, scripts) has not.  Hidden instancing
            # sources still render through their instances, as in Cycles.
            if not inst.is_instance and not render_mode and ob.original.hide_render:
                continue
            # The original: an instance's evaluated object may not outlive the
            # iteration (reading it later, as feature_notes does, crashed).
            seen.setdefault(ob.name, ob.original)
            if ob.type == 'LIGHT':
                lt = self.light(inst, ob)
                if lt is not None:
                    if self.crypto:
                        self.crypto_names["Object"].add(ob.name)
                        self.crypto_names["Asset"].add(crypto.asset_name(ob))
                    if ob.name in membership:
                        lt = dataclasses.replace(lt, link_sets=membership[ob.name])
                    if ob.name in shadowed:
                        lt = dataclasses.replace(lt, shadow_sets=shadowed[ob.name])
                    lights.append(lt)
                continue
            if ob.type not in GEOMETRY_TYPES:
                continue
            vis = ray_visibility(ob, inst.parent if inst.is_instance else None)
            if not vis:
                continue
            n0 = len(parts)
            self.geometry(inst, ob, parts)
            if self.crypto:
                self.crypto_ids(ob, parts[n0:])
            self.shading_attributes(inst, ob, parts, n0)
            self.obj_index_parts += [np.full(len(q[0]), int(getattr(ob, "pass_index", 0)), np.int32)
                                     for q in parts[n0:]]
            self.vis_parts += [np.full(len(q[0]), vis, np.uint8) for q in parts[n0:]]
            held = is_holdout(ob, inst.parent if inst.is_instance else None,
                              getattr(self.dg, "view_layer", None))
            self.holdout_parts += [np.full(len(q[0]), held, bool) for q in parts[n0:]]
            catcher = is_shadow_catcher(ob, inst.parent if inst.is_instance else None)
            self.catcher_parts += [np.full(len(q[0]), catcher, bool) for q in parts[n0:]]
            if receiver or membership:
                self.receiver_parts += [np.full(len(q[0]), receiver.get(ob.name, 0), np.uint8)
                                        for q in parts[n0:]]
                self.emitter_parts += [np.full(len(q[0]), membership.get(ob.name, LINK_ALL),
                                               np.uint64) for q in parts[n0:]]
            if blocker or shadowed:
                self.blocker_parts += [np.full(len(q[0]), blocker.get(ob.name, 0), np.uint8)
                                       for q in parts[n0:]]
                self.shadowed_parts += [np.full(len(q[0]), shadowed.get(ob.name, LINK_ALL),
                                                np.uint64) for q in parts[n0:]]
            if len(parts) > n0:
                self.n_objects += 1
                self.n_instances += bool(inst.is_instance)
        self.atlas.bake(parts)
        self.notes += feature_notes(scene, list(seen.values()))
        if any(getattr(m, "normal", None) is not None for m in self.materials):
            self.notes.append("normal maps and bump: photons scatter off the interpolated "
                              "normal (the camera side shades with the perturbed one)")
        if parts:
            tri_p = self.concatenate([q[0] for q in parts], np.float32)
            tri_n = self.concatenate([q[1] for q in parts], np.float32)
            tri_uv = self.concatenate([q[2] for q in parts], np.float32)
            tri_mat = self.concatenate([q[3] for q in parts], np.int32)
            tri_tangent = None
            if any(t is not None for t in self.tangent_parts):
                tri_tangent = self.concatenate(
                    [t if t is not None else np.zeros((len(q[0]), 3, 4), np.float32)
                     for t, q in zip(self.tangent_parts, parts)], np.float32)
        else:
            tri_p = np.zeros((0, 3, 3), np.float32)
            tri_n = np.zeros((0, 3, 3), np.float32)
            tri_uv = np.zeros((0, 3, 2), np.float32)
            tri_mat = np.zeros(0, np.int32)
            tri_tangent = None
        world, world_map = self.world()
        if not _world_visible(scene.world, "camera"):
            # Hidden from the camera: camera rays that escape see black (or
            # the film's transparency); the world still lights the scene.
            self.world_camera_map = EnvironmentMap(
                image=np.zeros((1, 2, 3), np.float32), name="(hidden from the camera)")
        if self.world_sun is not None:
            # The sky's sun disc is the world's: its ray visibility.
            lights.append(dataclasses.replace(self.world_sun, **{
                "visible_" + k: _world_visible(scene.world, k)
                for k in ("diffuse", "glossy", "transmission")}))
        cy = getattr(scene, "cycles", None)
        materials, pass_index, seen_rows = self.ray_variants()
        if self.disp_spaces:
            self.pad_bump_scales(parts, len(parts))
        fscene = Scene(tri_p=tri_p, tri_n=tri_n, tri_uv=tri_uv, tri_mat=tri_mat,
                       materials=materials, lights=lights, camera=cam,
                       world_color=world, textures=self.textures, world_map=world_map,
                       world_camera_map=self.world_camera_map,
                       filter_width=_filter_width(cy), filter_type=_filter_type(cy),
                       tri_object_index=(np.concatenate(self.obj_index_parts) if parts
                                         else np.zeros(0, np.int32)),
                       material_pass_index=np.asarray(pass_index, np.int32),
                       film_transparent=bool(getattr(scene.render, "film_transparent", False)),
                       mist=self.mist(), tri_tangent=tri_tangent,
                       ao_distance=float(getattr(getattr(scene.world, "light_settings", None),
                                                 "distance", 10.0)),
                       tri_visibility=self.tri_visibility(), tri_holdout=self.tri_holdout(),
                       tri_catcher=(self.concatenate(self.catcher_parts, bool)
                                    if any(c.any() for c in self.catcher_parts) else None),
                       tri_blocker=(self.concatenate(self.blocker_parts, np.uint8)
                                    if self.blocker_parts else None),
                       tri_shadow_sets=(self.concatenate(self.shadowed_parts, np.uint64)
                                        if self.shadowed_parts else None),
                       tri_crypto=(self.concatenate(self.crypto_parts, np.float32)
                                   if self.crypto and parts else None),
                       crypto_names=({k: tuple(sorted(v)) for k, v in self.crypto_names.items()}
                                     if self.crypto else None),
                       shader_aovs=tuple(self.aov_kinds.items()),
                       tri_render_uv=(self.concatenate(self.render_uv_parts, np.float32)
                                      if self.uv_pass and parts else None),
                       tri_bump_scale=(self.concatenate(self.bump_scale_parts, np.float32)
                                       if self.disp_spaces and parts else None),
                       world_hidden=world_hidden_bits(scene.world),
                       **seen_rows)
        # A holdout object keeps its material's transparency (core.scene.holdout).
        fscene = see_through(fscene)
        # Objects that shadow rays see through untouched (Light Path Is
        # Shadow Ray into a white Transparent BSDF): shadowless.
        fscene = clear_shadows(fscene)
        if fscene.material_shadow is not None:
            names = sorted({self.materials[m].name for m in range(len(self.materials))
                            if fscene.material_shadow[m] != m})
            self.notes.append(f"Light Path Is Shadow Ray: shadow rays see {', '.join(names[:3])} "
                              f"as another material; photons and light paths see the "
                              f"material itself")
        if fscene.tri_blocker is not None and any(
                is_delta_lobe(lb.kind, lb.roughness, lb.ior) for m in fscene.materials
                for lb in m.lobes):
            self.notes.append(
                "shadow linking: "
                "a mirror or glass in front of the emitter shows it only where no object stands between them")
        if self.receiver_parts:
            # One material per (material, receiver set, membership): every
            # stage then knows a vertex's receiver set by its material.
            fscene = split_materials(fscene, np.concatenate(self.receiver_parts),
                                     np.concatenate(self.emitter_parts))
        n_all = fscene.n_triangles
        if n_all == 0:
            raise SceneError(NOTHING_VISIBLE)
        fscene, dropped = self.drop_invalid(fscene)
        if dropped:
            self.log(f"Warning: dropped {dropped} of {n_all} triangles with NaN/infinite "
                     f"corners or zero area.")
        if fscene.n_triangles == 0:
            raise SceneError(NOTHING_VISIBLE)
        used = np.unique(fscene.tri_mat)
        emissive = any(max(fscene.materials[i].emission) > 0 for i in used)
        if not lights and not emissive and not np.any(world > 0):
            raise SceneError(WORLD_BAKING if self.world_pending else NO_LIGHTS)
        dt = time.perf_counter() - t0
        wc = ", ".join(f"{x:.3g}" for x in world)
        if world_map is not None:
            h, w = world_map.image.shape[:2]
            wc = f"map '{world_map.name}' {w}x{h}, mean {wc}"
        self.log(f"Exported {self.n_objects} objects ({self.n_instances} instances), "
                 f"{fscene.n_triangles:,} triangles, {len(self.materials)} materials, "
                 f"{len(lights)} lights, {len(self.textures)} textures, world ({wc}), "
                 f"camera '{(camera_object or scene.camera).name}' "
                 f"{cam.resolution[0]}x{cam.resolution[1]} in {dt:.2f} s.")
        approx = list(self.notes)
        for m in self.materials:
            # One sentence per material (one warning in Blender's Info log),
            # its notes in order, repeats (group instances) said once.
            if m.approximations:
                approx.append(f"material '{m.name}': "
                              + "; ".join(dict.fromkeys(m.approximations)))
        self.log("Approximated: " + ("; ".join(approx) if approx else "nothing") + ".")
        fscene.approximations = tuple(approx)
        return fscene


def export_scene(depsgraph, log=print, camera=None, should_stop=None) -> Scene:
    """Build a ``core`` Scene from an evaluated depsgraph.

    depsgraph: ``bpy.types.Depsgraph`` (render or viewport).
    log: receives the summary lines; warnings start with "Warning:".
    camera: camera object overriding ``scene.camera`` (RenderEngine.camera_override).
    Raises SceneError with a sentence for the user (no camera, no lights,
    nothing visible).  Empty material slots get a diffuse grey "(no material)".
    should_stop: polled between objects, textures and bands of large copies
    (RenderCancelled when it turns true); None = never.  Raises
    MemoryBudgetError when an image's pixels would not fit in free memory.
    """
    return _Exporter(depsgraph, log, should_stop).run(camera)
