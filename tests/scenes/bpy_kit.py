"""Small bpy helpers that build scenes from code (used by the scene generators).

Shared by ``tests/scenes/make_test_scenes.py`` and
``example_blends/make_examples.py``.  Everything is created through
``bpy.data`` (no operators besides the factory reset), so scripts run the same
in background mode and inside Blender.

Only shader nodes the FPPM exporter supports are used: Diffuse, Glossy, Glass,
Emission, Principled BSDF and Mix Shader.
"""
from __future__ import annotations

import math

import bpy
from mathutils import Matrix, Vector

from fppm.tools.converge import cycles_reference_setup


# --------------------------------------------------------------------- scene
def reset_scene(resolution=(64, 64), samples=256, world_color=(0.0, 0.0, 0.0)):
    """Empty the file and configure render settings for a Cycles reference.

    The settings follow shared/notes/blender.md ("For a reference"): Cycles CPU,
    caustics on with blur_glossy 0 (otherwise glossy/glass after a diffuse
    bounce is dropped), no denoising, no adaptive sampling, no clamping, no
    light threshold (it terminates light samples probabilistically and biases),
    view transform 'Standard', Blackman-Harris 1.5 px pixel filter (Cycles'
    default, recorded in the reference metadata).
    Returns the scene.
    """
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    # The settings shared with `fppm converge`'s references: engine, CPU,
    # view transform, no denoising / adaptive sampling / clamping, caustics.
    cycles_reference_setup(sc)
    r = sc.render
    r.resolution_x, r.resolution_y = resolution
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = False
    r.use_border = False
    r.threads_mode = 'AUTO'
    c = sc.cycles
    c.samples = samples
    # Deep enough that truncation is negligible in these closed/open scenes
    # (every extra bounce multiplies by albedo * (1 - escape) < 0.6).
    c.max_bounces = 16
    c.diffuse_bounces = 16
    c.glossy_bounces = 16
    c.transmission_bounces = 16
    c.transparent_max_bounces = 16
    c.volume_bounces = 0
    c.min_light_bounces = 0
    c.min_transparent_bounces = 0
    c.pixel_filter_type = 'BLACKMAN_HARRIS'
    c.filter_width = 1.5
    c.seed = 0
    c.film_exposure = 1.0
    c.use_guiding = False
    set_world(sc, world_color)
    return sc


def set_world(sc, color, strength=1.0):
    """Constant world of radiance ``color * strength`` (a Background node)."""
    w = bpy.data.worlds.new("World")
    w.color = color
    nt = w.node_tree
    bg = next(n for n in nt.nodes if n.type == 'BACKGROUND')
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    sc.world = w
    return w


def link(obj):
    bpy.context.scene.collection.objects.link(obj)
    return obj


def look_at_rotation(location, target, up_axis='Y'):
    """Euler rotation that points local -Z from ``location`` to ``target``."""
    d = Vector(target) - Vector(location)
    return d.to_track_quat('-Z', up_axis).to_euler()


# ------------------------------------------------------------------ materials
def _new_material(name):
    m = bpy.data.materials.new(name)
    nt = m.node_tree
    nt.nodes.clear()
    out = nt.nodes.new('ShaderNodeOutputMaterial')
    return m, nt, out


def _shader_node(nt, kind, color=(0.8, 0.8, 0.8), roughness=0.0, ior=1.5,
                 strength=1.0):
    if kind == 'DIFFUSE':
        n = nt.nodes.new('ShaderNodeBsdfDiffuse')
        n.inputs["Roughness"].default_value = roughness
    elif kind == 'GLOSSY':
        n = nt.nodes.new('ShaderNodeBsdfGlossy')
        # Single-scattering GGX, the model in blender.md (MULTI_GGX is the
        # node's default and is ~0.2 % brighter at roughness 0.2).
        n.distribution = 'GGX'
        n.inputs["Roughness"].default_value = roughness
    elif kind == 'GLASS':
        n = nt.nodes.new('ShaderNodeBsdfGlass')
        n.distribution = 'GGX'
        n.inputs["Roughness"].default_value = roughness
        n.inputs["IOR"].default_value = ior
    elif kind == 'EMISSION':
        n = nt.nodes.new('ShaderNodeEmission')
        n.inputs["Strength"].default_value = strength
    else:
        raise ValueError(kind)
    n.inputs["Color"].default_value = (*color, 1.0)
    return n


def material(name, kind, color=(0.8, 0.8, 0.8), roughness=0.0, ior=1.5,
             strength=1.0):
    """A one-node material: kind in DIFFUSE, GLOSSY, GLASS, EMISSION."""
    m, nt, out = _new_material(name)
    n = _shader_node(nt, kind, color, roughness, ior, strength)
    nt.links.new(n.outputs[0], out.inputs["Surface"])
    m.diffuse_color = (*color, 1.0)      # viewport colour only
    return m


def mix_material(name, fac, a, b):
    """Mix Shader of two one-node shaders; a, b are dicts of material() args
    (kind=..., color=..., ...).  fac weights b (Cycles' Mix: (1-fac)a + fac b)."""
    m, nt, out = _new_material(name)
    na = _shader_node(nt, **a)
    nb = _shader_node(nt, **b)
    mix = nt.nodes.new('ShaderNodeMixShader')
    mix.inputs["Fac"].default_value = fac
    nt.links.new(na.outputs[0], mix.inputs[1])
    nt.links.new(nb.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    return m


# ------------------------------------------------------------------ geometry
def mesh_object(name, verts, faces, mat=None, smooth=False, location=(0, 0, 0),
                rotation=(0, 0, 0), scale=(1, 1, 1)):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    me.validate()
    me.update()
    for p in me.polygons:
        p.use_smooth = smooth
    if mat is not None:
        me.materials.append(mat)
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    ob.rotation_euler = rotation
    ob.scale = scale
    return link(ob)


def quad(name, corners, mat):
    """One quad from 4 corners (counter-clockwise seen from the front side)."""
    return mesh_object(name, corners, [(0, 1, 2, 3)], mat)


def plane(name, size, mat, location=(0, 0, 0), rotation=(0, 0, 0)):
    """Square of side ``size`` in local XY, normal +Z."""
    h = size / 2
    return mesh_object(name, [(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)],
                       [(0, 1, 2, 3)], mat, location=location, rotation=rotation)


def box(name, size, mat, location=(0, 0, 0), rot_z_deg=0.0):
    """Axis box of ``size`` = (sx, sy, sz) resting on its base at ``location``."""
    sx, sy, sz = size[0] / 2, size[1] / 2, size[2]
    v = [(-sx, -sy, 0), (sx, -sy, 0), (sx, sy, 0), (-sx, sy, 0),
         (-sx, -sy, sz), (sx, -sy, sz), (sx, sy, sz), (-sx, sy, sz)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6),
         (3, 0, 4, 7)]
    return mesh_object(name, v, f, mat, location=location,
                       rotation=(0, 0, math.radians(rot_z_deg)))


def uv_sphere(name, radius, mat, location=(0, 0, 0), segments=20, rings=10,
              smooth=True):
    """UV sphere: 2*segments*(rings-1) triangles' worth of faces."""
    verts = [(0, 0, radius)]
    for i in range(1, rings):
        th = math.pi * i / rings
        for j in range(segments):
            ph = 2 * math.pi * j / segments
            verts.append((radius * math.sin(th) * math.cos(ph),
                          radius * math.sin(th) * math.sin(ph),
                          radius * math.cos(th)))
    verts.append((0, 0, -radius))
    south = len(verts) - 1
    faces = []
    for j in range(segments):
        faces.append((0, 1 + j, 1 + (j + 1) % segments))
    for i in range(rings - 2):
        a = 1 + i * segments
        b = a + segments
        for j in range(segments):
            j1 = (j + 1) % segments
            faces.append((a + j, b + j, b + j1, a + j1))
    a = 1 + (rings - 2) * segments
    for j in range(segments):
        faces.append((a + j, south, a + (j + 1) % segments))
    return mesh_object(name, verts, faces, mat, smooth=smooth, location=location)


def open_cylinder(name, radius, height, mat, location=(0, 0, 0), segments=48,
                  smooth=True):
    """Open tube (no caps) standing on z = 0 of its local frame: a thin ring."""
    verts = []
    for z in (0.0, height):
        for j in range(segments):
            ph = 2 * math.pi * j / segments
            verts.append((radius * math.cos(ph), radius * math.sin(ph), z))
    faces = [(j, (j + 1) % segments, segments + (j + 1) % segments, segments + j)
             for j in range(segments)]
    return mesh_object(name, verts, faces, mat, smooth=smooth, location=location)


# -------------------------------------------------------------------- lights
def light(name, kind, energy, location, target=None, rotation=None,
          color=(1.0, 1.0, 1.0), visible_camera=True, **props):
    """A light object; ``props`` set light-data attributes (size, shape,
    shadow_soft_size, spot_size, spot_blend, angle, ...).

    Visibility is set explicitly: in 5.2 objects made through bpy.data get
    visible_camera = False (blender.md).
    """
    ld = bpy.data.lights.new(name, kind)
    ld.energy = energy
    ld.color = color
    ld.exposure = 0.0
    ld.normalize = True
    ld.use_temperature = False
    for k, v in props.items():
        setattr(ld, k, v)
    ob = bpy.data.objects.new(name, ld)
    ob.location = location
    if target is not None:
        ob.rotation_euler = look_at_rotation(location, target)
    elif rotation is not None:
        ob.rotation_euler = rotation
    ob.visible_camera = visible_camera
    ob.visible_diffuse = True
    ob.visible_glossy = True
    ob.visible_transmission = True
    ob.visible_volume_scatter = True
    ob.visible_shadow = True
    return link(ob)


# -------------------------------------------------------------------- camera
def camera(location, target, lens=35.0, sensor=36.0, up_axis='Y'):
    cd = bpy.data.cameras.new("Camera")
    cd.lens = lens
    cd.sensor_width = sensor
    cd.sensor_fit = 'AUTO'
    cd.clip_start = 0.01
    cd.clip_end = 1000.0
    ob = bpy.data.objects.new("Camera", cd)
    ob.location = location
    ob.rotation_euler = look_at_rotation(location, target, up_axis)
    link(ob)
    bpy.context.scene.camera = ob
    return ob


def save(path):
    """Save compressed, without a .blend1 backup."""
    bpy.context.preferences.filepaths.save_version = 0
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True,
                                check_existing=False)
