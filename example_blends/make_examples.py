"""Build the example .blend files shipped with FPPM.

Run:  .venv/bin/python example_blends/make_examples.py [name ...]

Each file: 128x128, camera set, saved with ``render.engine`` 'FPPM' (the
add-on is registered while building); the Cycles settings stay set for
references (caustics on, no denoising / adaptive sampling / clamping,
'Standard' view; ``fppm converge`` switches the engine to Cycles for its
reference and ladder), and Cycles' bounces equal FPPM's ``max_bounces`` (16),
so both trace paths of the same depth (tests/test_converge.py checks it).
Only shader nodes the exporter supports are used (Diffuse, Glossy, Glass,
Emission, Mix, Principled BSDF; real_scene adds Image Texture, Normal Map,
Mapping, Texture Coordinate and Environment Texture).  Scene helpers live in
tests/scenes/bpy_kit.py.

  cornell.blend        Cornell box, ceiling area light (the default example)
  coffee_cup.blend     the seed paper's Figure 1: cardioid caustic inside a
                       mirror ring lit by a small, low light
  glass_sphere.blend   glass sphere (IOR 1.5) on a plane, focused caustic
  point_caustic.blend  caustic from a point light (radius 0), which Cycles
                       cannot render; the camera sees only diffuse surfaces
  indirect_room.blend  room lit only indirectly (paper's Figure 6): a spot
                       lights a ceiling patch behind the camera
  ring_lambert.blend   the seed paper's Figure 1 setting: a mirror ring section
                       (half a cylinder) under a 1 m square area light over a
                       Lambert floor: a caustic from a large light
  ring_principled.blend  the same ring over a floor of Blender's default
                       material (Principled BSDF, its default inputs)
  principled_interior.blend  a room, every object Blender's default material,
                       lit through a window by an area light outside the view
  real_scene.blend     a user's set-up: Principled materials, an HDRI world
                       (a small procedural equirectangular sky with a sun,
                       packed) and a tiled floor with Image Textures into
                       its Base Color and Roughness and a tangent-space
                       normal map (all generated and packed, Mapping +
                       Texture Coordinate UV)
"""
from __future__ import annotations

import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests", "scenes"))

import bpy_kit as K  # noqa: E402

RES = (128, 128)


def _note(sc, text):
    sc["fppm_example"] = text


def cornell():
    sc = K.reset_scene(RES, samples=1024)
    red = K.material("Red", 'DIFFUSE', (0.63, 0.065, 0.05))
    green = K.material("Green", 'DIFFUSE', (0.14, 0.45, 0.091))
    white = K.material("White", 'DIFFUSE', (0.725, 0.71, 0.68))
    K.quad("Floor", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], white)
    K.quad("Ceiling", [(-1, -1, 2), (-1, 1, 2), (1, 1, 2), (1, -1, 2)], white)
    K.quad("BackWall", [(-1, 1, 0), (1, 1, 0), (1, 1, 2), (-1, 1, 2)], white)
    K.quad("LeftWall", [(-1, -1, 0), (-1, 1, 0), (-1, 1, 2), (-1, -1, 2)], red)
    K.quad("RightWall", [(1, -1, 0), (1, -1, 2), (1, 1, 2), (1, 1, 0)], green)
    K.box("ShortBox", (0.6, 0.6, 0.6), white, (0.35, -0.3, 0), -17)
    K.box("TallBox", (0.6, 0.6, 1.2), white, (-0.35, 0.35, 0), 17)
    K.light("CeilingLight", 'AREA', 40.0, (0, 0, 1.985), rotation=(0, 0, 0),
            shape='SQUARE', size=0.5, color=(1.0, 0.92, 0.8))
    K.camera((0, -3.9, 1.0), (0, 0, 1.0), lens=53)
    _note(sc, "Cornell box: 40 W ceiling area light (0.5 m square).")
    return sc


def coffee_cup():
    # Parallel-ish light entering a mirror ring reflects off the far inner
    # wall and focuses on the floor into the cardioid ("coffee cup") caustic.
    sc = K.reset_scene(RES, samples=2048, world_color=(0.015, 0.015, 0.02))
    floor = K.material("Table", 'DIFFUSE', (0.8, 0.78, 0.74))
    metal = K.material("Mirror", 'GLOSSY', (0.95, 0.9, 0.8), roughness=0.0)
    K.plane("Table", 6, floor)
    K.open_cylinder("Ring", 0.5, 0.35, metal, segments=96, smooth=True)
    # Small spot low on one side (elevation 25 deg, 3 m away), aimed at the
    # ring; radius 5 cm so Cycles can hit it at all.
    el = math.radians(25)
    pos = (-3.0 * math.cos(el), 0.0, 3.0 * math.sin(el))
    K.light("LowSpot", 'SPOT', 500.0, pos, target=(0, 0, 0.1),
            visible_camera=False, shadow_soft_size=0.05,
            spot_size=math.radians(30), spot_blend=0.15,
            color=(1.0, 0.95, 0.85))
    K.camera((0.9, -1.6, 1.9), (0.0, 0.05, 0.12), lens=42)
    _note(sc, "Seed paper Fig. 1: cardioid caustic inside a mirror ring. "
              "Cycles needs many samples (caustic via a 5 cm light).")
    return sc


def glass_sphere():
    sc = K.reset_scene(RES, samples=2048, world_color=(0.02, 0.02, 0.025))
    floor = K.material("Floor", 'DIFFUSE', (0.8, 0.8, 0.8))
    glass = K.material("Glass", 'GLASS', (1.0, 1.0, 1.0), roughness=0.0, ior=1.5)
    K.plane("Floor", 6, floor)
    K.quad("BackWall", [(-3, 1.5, 0), (3, 1.5, 0), (3, 1.5, 2.5), (-3, 1.5, 2.5)],
           K.material("Wall", 'DIFFUSE', (0.5, 0.55, 0.6)))
    K.uv_sphere("GlassSphere", 0.35, glass, (0, 0, 0.35), segments=32, rings=16)
    K.light("Spot", 'SPOT', 400.0, (-1.5, 1.2, 2.4), target=(0, 0, 0.35),
            visible_camera=False, shadow_soft_size=0.05,
            spot_size=math.radians(35), spot_blend=0.2)
    K.camera((0.3, -2.4, 1.3), (0.1, 0, 0.2), lens=40)
    _note(sc, "Glass sphere (IOR 1.5) focusing a small spot light into a "
              "caustic inside its shadow.")
    return sc


def point_caustic():
    # Ball lens (R = 0.3, IOR 1.5, f = 1.5 R from the centre) 0.7 m below a
    # point light images it near the floor: a caustic Cycles cannot render
    # (a radius-0 light is never hit by a ray).  The camera looks down at
    # the floor and back wall only, so a light tracer can serve as reference.
    sc = K.reset_scene(RES, samples=512)
    floor = K.material("Floor", 'DIFFUSE', (0.8, 0.8, 0.8))
    wall = K.material("Wall", 'DIFFUSE', (0.6, 0.6, 0.65))
    K.plane("Floor", 8, floor)
    K.quad("BackWall", [(-4, 2.0, 0), (4, 2.0, 0), (4, 2.0, 3.5), (-4, 2.0, 3.5)], wall)
    K.uv_sphere("GlassSphere", 0.3, K.material("Glass", 'GLASS', (1, 1, 1), ior=1.5),
                (0, 0, 2.3), segments=32, rings=16)
    K.box("Box", (0.5, 0.5, 0.5), K.material("Clay", 'DIFFUSE', (0.7, 0.35, 0.2)),
          (1.0, 0.6, 0), 30)
    K.light("Point", 'POINT', 250.0, (0, 0, 3.0), visible_camera=False,
            shadow_soft_size=0.0)
    K.camera((0, -3.2, 0.9), (0, 0.3, 0.0), lens=50)
    _note(sc, "Point-light caustic through a glass sphere above the frame; "
              "Cycles renders the sphere's shadow but not the caustic.")
    return sc


def indirect_room():
    # Room 4 x 5 x 2.6 m; a spot on the floor behind the camera points up at
    # the ceiling.  The lit ceiling patch (y < -0.6) is outside the view
    # (the camera sees the ceiling only for y > 0.5), so every visible
    # surface is lit by bounces only.
    sc = K.reset_scene(RES, samples=2048)
    wall = K.material("Plaster", 'DIFFUSE', (0.75, 0.73, 0.7))
    blue = K.material("BlueWall", 'DIFFUSE', (0.25, 0.35, 0.65))
    wood = K.material("Floor", 'DIFFUSE', (0.5, 0.35, 0.2))
    x0, x1, y0, y1, z1 = -2.0, 2.0, -2.5, 2.5, 2.6
    K.quad("Floor", [(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)], wood)
    K.quad("Ceiling", [(x0, y0, z1), (x0, y1, z1), (x1, y1, z1), (x1, y0, z1)], wall)
    K.quad("FarWall", [(x0, y1, 0), (x1, y1, 0), (x1, y1, z1), (x0, y1, z1)], blue)
    K.quad("NearWall", [(x0, y0, 0), (x0, y0, z1), (x1, y0, z1), (x1, y0, 0)], wall)
    K.quad("LeftWall", [(x0, y0, 0), (x0, y1, 0), (x0, y1, z1), (x0, y0, z1)], wall)
    K.quad("RightWall", [(x1, y0, 0), (x1, y0, z1), (x1, y1, z1), (x1, y1, 0)], wall)
    K.box("Table", (1.2, 0.7, 0.75), K.material("Oak", 'DIFFUSE', (0.55, 0.4, 0.25)),
          (0.4, 1.3, 0), 10)
    K.uv_sphere("Ball", 0.3, K.mix_material(
        "Ceramic", 0.15, dict(kind='DIFFUSE', color=(0.8, 0.15, 0.1)),
        dict(kind='GLOSSY', color=(1, 1, 1), roughness=0.25)),
        (-0.9, 1.2, 0.3), segments=24, rings=12)
    K.box("Cabinet", (0.5, 0.8, 1.4), wall, (1.6, -0.2, 0), 0)
    K.light("UpSpot", 'SPOT', 1500.0, (0, -2.2, 0.3), rotation=(math.pi, 0, 0),
            visible_camera=False, shadow_soft_size=0.05,
            spot_size=math.radians(70), spot_blend=0.3)
    K.camera((0, -1.6, 1.3), (0, 2.5, 0.9), lens=24)
    _note(sc, "Paper Fig. 6: lit only indirectly, by a spot on a ceiling "
              "patch behind the camera.")
    return sc


def default_material(name):
    """Blender's default material: a new material's Principled BSDF, inputs untouched."""
    import bpy
    m = bpy.data.materials.new(name)
    nodes = m.node_tree.nodes
    assert [n.type for n in nodes] == ['BSDF_PRINCIPLED', 'OUTPUT_MATERIAL'] or \
        {n.type for n in nodes} == {'BSDF_PRINCIPLED', 'OUTPUT_MATERIAL'}, [n.type for n in nodes]
    return m


def ring_arc(name, radius, height, mat, a0_deg, a1_deg, segments=48):
    """A section of an open cylinder (axis z, on z = 0) from angle a0 to a1 (degrees)."""
    verts = []
    for z in (0.0, height):
        for j in range(segments + 1):
            ph = math.radians(a0_deg + (a1_deg - a0_deg) * j / segments)
            verts.append((radius * math.cos(ph), radius * math.sin(ph), z))
    n = segments + 1
    faces = [(j, j + 1, n + j + 1, n + j) for j in range(segments)]
    return K.mesh_object(name, verts, faces, mat, smooth=True)


def _ring_scene(make_floor_material):
    # A half ring of mirror (radius 0.5 m, 0.3 m high) opening towards a
    # 1 m square area light 2 m away and 1.6 m up: the concave inner wall
    # focuses the light into a caustic on the floor inside the ring, blurred
    # by the light's size (the seed paper's Figure 1 setting).
    sc = K.reset_scene(RES, samples=2048, world_color=(0.01, 0.01, 0.012))
    K.plane("Floor", 6, make_floor_material())
    metal = K.material("Mirror", 'GLOSSY', (0.95, 0.9, 0.8), roughness=0.0)
    ring_arc("Ring", 0.5, 0.3, metal, -90.0, 90.0)
    K.light("AreaLight", 'AREA', 40.0, (-2.0, 0.0, 1.6), target=(0.2, 0.0, 0.0),
            visible_camera=False, shape='SQUARE', size=1.0, color=(1.0, 0.95, 0.85))
    K.camera((0.5, -1.3, 2.1), (0.15, 0.0, 0.05), lens=40)
    return sc


def ring_lambert():
    sc = _ring_scene(lambda: K.material("Lambert", 'DIFFUSE', (0.8, 0.8, 0.8)))
    _note(sc, "Seed paper Fig. 1 setting: mirror half ring under a 1 m square area "
              "light over a Lambert floor.")
    return sc


def ring_principled():
    sc = _ring_scene(lambda: default_material("Material"))
    _note(sc, "The mirror half ring of ring_lambert over a floor of Blender's "
              "default material (Principled BSDF).")
    return sc


def principled_interior():
    # Room 4 x 4 x 2.5 m with a 1 x 1 m window in the left wall (x = -2); a
    # 1 m square area light outside, above the window, shines in and down
    # onto the floor near the wall.  The camera looks at the back and right
    # of the room: the light is outside the view, and most of what it sees
    # is lit by bounces.  Every object has Blender's default material.
    sc = K.reset_scene(RES, samples=2048)
    mat = default_material("Material")
    x0, x1, y0, y1, z1 = -2.0, 2.0, -2.0, 2.0, 2.5
    wy0, wy1, wz0, wz1 = -0.5, 0.5, 0.9, 1.9          # the window in x = x0
    K.quad("Floor", [(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)], mat)
    K.quad("Ceiling", [(x0, y0, z1), (x0, y1, z1), (x1, y1, z1), (x1, y0, z1)], mat)
    K.quad("BackWall", [(x0, y1, 0), (x1, y1, 0), (x1, y1, z1), (x0, y1, z1)], mat)
    K.quad("FrontWall", [(x0, y0, 0), (x0, y0, z1), (x1, y0, z1), (x1, y0, 0)], mat)
    K.quad("RightWall", [(x1, y0, 0), (x1, y0, z1), (x1, y1, z1), (x1, y1, 0)], mat)
    # Left wall: four quads around the window.
    for nm, (ya, yb, za, zb) in (("WallBelow", (y0, y1, 0, wz0)), ("WallAbove", (y0, y1, wz1, z1)),
                                 ("WallFront", (y0, wy0, wz0, wz1)), ("WallBack", (wy1, y1, wz0, wz1))):
        K.quad("Left" + nm, [(x0, ya, za), (x0, yb, za), (x0, yb, zb), (x0, ya, zb)], mat)
    K.box("Table", (1.0, 0.6, 0.75), mat, (0.6, 1.0, 0), 15)
    K.box("Cabinet", (0.5, 0.9, 1.5), mat, (1.65, -0.4, 0), 0)
    K.uv_sphere("Ball", 0.3, mat, (-0.6, 1.2, 0.3), segments=24, rings=12)
    K.light("WindowLight", 'AREA', 150.0, (-3.0, 0.0, 2.6), target=(-1.2, 0.2, 0.0),
            visible_camera=False, shape='SQUARE', size=1.0, color=(1.0, 0.96, 0.9))
    K.camera((1.2, -1.85, 1.4), (-0.6, 2.0, 0.8), lens=22)
    _note(sc, "Principled interior: Blender's default material everywhere, lit "
              "through a window by an area light outside the view.")
    return sc


def _packed_image(name, px, non_color):
    """A packed float image from (H, W, 4) float32 pixels (row 0 = bottom)."""
    import bpy
    import numpy as np
    H, W = px.shape[:2]
    im = bpy.data.images.new(name, W, H, alpha=True, float_buffer=True)
    im.colorspace_settings.name = 'Non-Color' if non_color else 'Linear Rec.709'
    im.pixels.foreach_set(np.ascontiguousarray(px, np.float32).ravel())
    im.pack()
    return im


def sky_pixels(W=128, H=64):
    """An equirectangular HDR sky (Cycles' convention: row 0 = nadir): a blue
    gradient above the horizon, a warm ground below and a small bright sun
    (about 3 degrees) 35 degrees up."""
    import numpy as np
    v = (np.arange(H) + 0.5) / H
    u = (np.arange(W) + 0.5) / W
    elev = (v - 0.5) * np.pi                       # -pi/2 .. pi/2
    phi = np.pi - 2 * np.pi * u
    E, P = np.meshgrid(elev, phi, indexing="ij")
    up = np.clip(np.sin(E), 0, 1)
    sky = np.stack([0.25 + 0.35 * (1 - up), 0.45 + 0.3 * (1 - up), 0.9 + 0.1 * up], -1) * 0.8
    ground = np.broadcast_to(np.array([0.18, 0.15, 0.12]), sky.shape)
    img = np.where((E > 0)[..., None], sky, ground)
    d = np.stack([np.cos(E) * np.cos(P), np.cos(E) * np.sin(P), np.sin(E)], -1)
    s_el, s_az = np.radians(35.0), np.radians(-40.0)
    s = np.array([np.cos(s_el) * np.cos(s_az), np.cos(s_el) * np.sin(s_az), np.sin(s_el)])
    img = img + (d @ s > np.cos(np.radians(3.0)))[..., None] * np.array([600.0, 520.0, 420.0])
    out = np.ones((H, W, 4), np.float32)
    out[..., :3] = img
    return out


def tile_normal_pixels(n=64, tiles=4, bevel=0.12):
    """A tangent-space normal map of tiles with bevelled edges (OpenGL
    convention, rgb = (n + 1) / 2)."""
    import numpy as np
    t = ((np.arange(n) + 0.5) / n * tiles) % 1.0
    def slope(x):       # the bevel's slope across a tile: -1 .. 1 near the edges
        return np.where(x < bevel, -(1 - x / bevel), np.where(x > 1 - bevel, (x - 1 + bevel) / bevel, 0.0))
    sy, sx = np.meshgrid(slope(t), slope(t), indexing="ij")
    nrm = np.stack([0.8 * sx, 0.8 * sy, np.ones_like(sx)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    out = np.ones((n, n, 4), np.float32)
    out[..., :3] = (nrm + 1) / 2
    return out


def tile_color_pixels(n=64, tiles=4, grout=0.04):
    """The tiles' base colour (linear): two warm tones in a checker, each
    tile shaded a little by its index, dark grout along the edges; on the
    normal map's grid (:func:`tile_normal_pixels`)."""
    import numpy as np
    x = (np.arange(n) + 0.5) / n * tiles
    X, Y = np.meshgrid(x, x)                     # row = y
    ix, iy = np.floor(X), np.floor(Y)
    odd = ((ix + iy) % 2 == 1)[..., None]
    shade = (0.9 + 0.1 * np.sin(3.1 * ix + 1.7 * iy))[..., None]
    col = np.where(odd, [0.62, 0.52, 0.40], [0.48, 0.36, 0.27]) * shade
    fx, fy = X % 1.0, Y % 1.0
    edge = ((np.minimum(fx, 1 - fx) < grout) | (np.minimum(fy, 1 - fy) < grout))[..., None]
    col = np.where(edge, [0.12, 0.11, 0.10], col)
    out = np.ones((n, n, 4), np.float32)
    out[..., :3] = col
    return out


def tile_roughness_pixels(n=64, tiles=4, grout=0.04):
    """The tiles' roughness (Non-Color grey) on the same grid: each tile a
    little worn (0.15 to 0.4 by its index, rougher towards one corner), the
    grout matte (0.9)."""
    import numpy as np
    x = (np.arange(n) + 0.5) / n * tiles
    X, Y = np.meshgrid(x, x)
    ix, iy = np.floor(X), np.floor(Y)
    fx, fy = X % 1.0, Y % 1.0
    r = 0.15 + 0.12 * (0.5 + 0.5 * np.sin(2.3 * ix + 4.1 * iy)) + 0.13 * fx * fy
    edge = (np.minimum(fx, 1 - fx) < grout) | (np.minimum(fy, 1 - fy) < grout)
    r = np.where(edge, 0.9, r)
    out = np.ones((n, n, 4), np.float32)
    out[..., :3] = r[..., None]
    return out


def _principled(name, base, roughness=0.5, metallic=0.0, coat=0.0):
    m, nt, out = K._new_material(name)
    p = nt.nodes.new('ShaderNodeBsdfPrincipled')
    p.inputs["Base Color"].default_value = (*base, 1.0)
    p.inputs["Roughness"].default_value = roughness
    p.inputs["Metallic"].default_value = metallic
    p.inputs["Coat Weight"].default_value = coat
    nt.links.new(p.outputs[0], out.inputs["Surface"])
    return m, nt, p


def real_scene():
    # A tiled floor under an HDRI sky with three Principled objects: what a
    # user's first scene looks like.  The floor's normal map comes through
    # Texture Coordinate (UV) -> Mapping (scale 2) -> Image Texture -> Normal
    # Map, its colour and roughness through the same Mapping -> Image Texture
    # -> Base Color, Roughness.
    import bpy
    sc = K.reset_scene(RES, samples=1024)
    floor, nt, p = _principled("Tiles", (0.55, 0.5, 0.45), roughness=0.35)
    tex = nt.nodes.new('ShaderNodeTexImage')
    tex.image = _packed_image("TileNormal", tile_normal_pixels(), non_color=True)
    mp = nt.nodes.new('ShaderNodeMapping')
    mp.inputs["Scale"].default_value = (2.0, 2.0, 1.0)
    tc = nt.nodes.new('ShaderNodeTexCoord')
    nm = nt.nodes.new('ShaderNodeNormalMap')
    nt.links.new(tc.outputs["UV"], mp.inputs["Vector"])
    nt.links.new(mp.outputs["Vector"], tex.inputs["Vector"])
    nt.links.new(tex.outputs["Color"], nm.inputs["Color"])
    nt.links.new(nm.outputs["Normal"], p.inputs["Normal"])
    ctex = nt.nodes.new('ShaderNodeTexImage')
    ctex.image = _packed_image("TileColor", tile_color_pixels(), non_color=False)
    nt.links.new(mp.outputs["Vector"], ctex.inputs["Vector"])
    nt.links.new(ctex.outputs["Color"], p.inputs["Base Color"])
    rtex = nt.nodes.new('ShaderNodeTexImage')
    rtex.image = _packed_image("TileRoughness", tile_roughness_pixels(), non_color=True)
    nt.links.new(mp.outputs["Vector"], rtex.inputs["Vector"])
    nt.links.new(rtex.outputs["Color"], p.inputs["Roughness"])
    ob = K.plane("Floor", 8.0, floor)
    uvl = ob.data.uv_layers.new(name="UVMap")
    for loop in ob.data.loops:
        co = ob.data.vertices[loop.vertex_index].co
        uvl.data[loop.index].uv = (co.x / 8.0 + 0.5, co.y / 8.0 + 0.5)
    K.uv_sphere("Ball", 0.5, _principled("RedPlastic", (0.7, 0.08, 0.05), 0.25)[0],
                (-0.7, 0.3, 0.5), segments=32, rings=16)
    K.box("Block", (0.8, 0.8, 0.8), _principled("Gold", (1.0, 0.76, 0.33), 0.3, 1.0)[0],
          (0.8, 0.6, 0.0), 25)
    K.uv_sphere("Pebble", 0.25, _principled("Chalk", (0.8, 0.8, 0.78), 0.8)[0],
                (0.2, -0.6, 0.25), segments=24, rings=12)
    w = bpy.data.worlds.new("Sky")
    wt = w.node_tree
    wt.nodes.clear()
    out = wt.nodes.new('ShaderNodeOutputWorld')
    bg = wt.nodes.new('ShaderNodeBackground')
    env = wt.nodes.new('ShaderNodeTexEnvironment')
    env.image = _packed_image("SkyHDR", sky_pixels(), non_color=False)
    wt.links.new(env.outputs["Color"], bg.inputs["Color"])
    wt.links.new(bg.outputs[0], out.inputs["Surface"])
    sc.world = w
    K.camera((0.0, -4.2, 1.8), (0.0, 0.2, 0.35), lens=35)
    _note(sc, "Real-scene set-up: Principled materials, an HDRI world and a "
              "tiled floor with colour and roughness textures and a normal map.")
    return sc


EXAMPLES = [cornell, coffee_cup, glass_sphere, point_caustic, indirect_room,
            ring_lambert, ring_principled, principled_interior, real_scene]


def save_for_fppm(sc, path):
    """Save with FPPM as the render engine; its bounces equal Cycles' (kept for references)."""
    import fppm.addon as addon
    addon.register()
    sc.render.engine = 'FPPM'
    sc.fppm.max_bounces = sc.cycles.max_bounces
    K.save(path)


def main(names=None):
    for fn in EXAMPLES:
        if names and fn.__name__ not in names:
            continue
        sc = fn()
        path = os.path.join(HERE, fn.__name__ + ".blend")
        save_for_fppm(sc, path)
        print(f"{fn.__name__}: {os.path.getsize(path) / 1e3:.0f} kB -> {path}")


if __name__ == "__main__":
    main(sys.argv[1:])
