"""Build the small (64x64) test scenes used for agreement with Cycles.

Run:  .venv/bin/python tests/scenes/make_test_scenes.py [name ...]

Writes tests/scenes/<name>.blend.  Every scene is tiny (< 400 triangles), has
a black world unless stated, and carries a JSON string in the custom scene
property ``fppm_test`` with what ``tests/references/make_references.py``
needs: the reference sample count, analytic checks (formula parameters) and a
note for comparisons.  Units follow shared/notes/blender.md.
"""
from __future__ import annotations

import json
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import bpy_kit as K  # noqa: E402

RES = (64, 64)
WHITE = (0.8, 0.8, 0.8)
FLOOR = (0.8, 0.8, 0.8)


def _meta(sc, **kw):
    sc["fppm_test"] = json.dumps(kw)


def _box_material():
    return K.material("box", 'DIFFUSE', (0.7, 0.35, 0.2))


# ------------------------------------------------------------------ scenes
def t_cornell():
    sc = K.reset_scene(RES)
    red = K.material("red", 'DIFFUSE', (0.63, 0.065, 0.05))
    green = K.material("green", 'DIFFUSE', (0.14, 0.45, 0.091))
    white = K.material("white", 'DIFFUSE', (0.725, 0.71, 0.68))
    K.quad("floor", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], white)
    K.quad("ceiling", [(-1, -1, 2), (-1, 1, 2), (1, 1, 2), (1, -1, 2)], white)
    K.quad("back", [(-1, 1, 0), (1, 1, 0), (1, 1, 2), (-1, 1, 2)], white)
    K.quad("left", [(-1, -1, 0), (-1, 1, 0), (-1, 1, 2), (-1, -1, 2)], red)
    K.quad("right", [(1, -1, 0), (1, -1, 2), (1, 1, 2), (1, 1, 0)], green)
    K.box("short_box", (0.6, 0.6, 0.6), white, (0.35, -0.3, 0), -17)
    K.box("tall_box", (0.6, 0.6, 1.2), white, (-0.35, 0.35, 0), 17)
    # 0.5 m square, 40 W: L = 40 / (pi * 0.25) = 50.93 seen directly.
    K.light("ceiling_light", 'AREA', 40.0, (0, 0, 1.98), rotation=(0, 0, 0),
            shape='SQUARE', size=0.5)
    K.camera((0, -3.5, 1.0), (0, 0, 1.0), lens=40)
    _meta(sc, samples=6144,
          note="Closed Cornell box (open front). The light (L = 50.93) is seen "
               "directly in the top rows; compare it separately or exclude it.")
    return sc


def t_mirror_caustic():
    sc = K.reset_scene(RES)
    floor = K.material("floor", 'DIFFUSE', FLOOR)
    mirror = K.material("mirror", 'GLOSSY', (0.9, 0.9, 0.9), roughness=0.0)
    K.plane("floor", 6, floor)
    # Vertical mirror facing -Y, standing on the floor.
    K.quad("mirror", [(-0.6, 1, 0), (0.6, 1, 0), (0.6, 1, 0.8), (-0.6, 1, 0.8)],
           mirror)
    # Small area light aimed at the mirror; its image lands on the floor near
    # y ~ 0.5 (reflected beam), on top of the light's direct illumination.
    K.light("small_area", 'AREA', 20.0, (0, -0.5, 1.6), target=(0, 1, 0.4),
            shape='SQUARE', size=0.3)
    K.box("box", (0.3, 0.3, 0.3), _box_material(), (0.9, 0.2, 0), 20)
    K.camera((0, -2.6, 1.9), (0, 0.5, 0.2), lens=32)
    _meta(sc, samples=10240,
          note="Caustic: reflected image of the light on the floor around "
               "y = 0.5 m (rows ~35-50); Cycles reaches it only by BSDF "
               "sampling through the mirror, so it is the noisiest region.")
    return sc


def t_glass_caustic():
    sc = K.reset_scene(RES)
    floor = K.material("floor", 'DIFFUSE', FLOOR)
    glass = K.material("glass", 'GLASS', (1.0, 1.0, 1.0), roughness=0.0, ior=1.5)
    K.plane("floor", 6, floor)
    # Ball lens: focal length 1.5 R from the centre for IOR 1.5, so a centre
    # 0.45 m above the floor (R = 0.3) focuses near the floor.
    K.uv_sphere("glass_sphere", 0.3, glass, (0, 0, 0.45), segments=20, rings=10)
    K.light("area", 'AREA', 30.0, (0, 0, 2.2), rotation=(0, 0, 0),
            shape='SQUARE', size=0.4)
    K.camera((0, -2.2, 1.6), (0, 0, 0.3), lens=35)
    _meta(sc, samples=12288,
          note="Refractive caustic under the sphere (image centre-bottom, "
               "inside its shadow). Sphere pixels show refraction of the "
               "floor and of the light.")
    return sc


def t_glossy_floor():
    sc = K.reset_scene(RES)
    floor = K.material("glossy_floor", 'GLOSSY', (0.8, 0.8, 0.8), roughness=0.4)
    K.plane("floor", 6, floor)
    K.box("box", (0.5, 0.5, 0.5), _box_material(), (-0.4, 0.3, 0), 25)
    K.light("area", 'AREA', 40.0, (0.3, 1.6, 1.3), target=(0, 0, 0),
            shape='SQUARE', size=0.5)
    K.camera((0, -2.5, 1.2), (0, 0.3, 0.2), lens=35)
    _meta(sc, samples=12288,
          note="GGX (single scattering, alpha = 0.16) floor: the glossy "
               "highlight of the light is the main feature; the box is lit "
               "directly and via the floor.")
    return sc


def _light_stage(floor_rho=FLOOR, box_at=(1.0, 1.0, 0), floor_size=20.0):
    """Large Lambert floor plus a 0.4 m diffuse box (shadow, interreflection)."""
    floor = K.material("floor", 'DIFFUSE', floor_rho)
    K.plane("floor", floor_size, floor)
    K.box("box", (0.4, 0.4, 0.4), _box_material(), box_at, 30)


def t_light_point():
    sc = K.reset_scene(RES)
    _light_stage(box_at=(1.0, 1.0, 0))
    # Notes' check: P = 100 W, h = 1 m, rho = 0.8 -> rho P / (4 pi^2 h^2) at the
    # foot point.  Soft falloff off: a sphere of radius r fully above the
    # horizon gives exactly the point-light irradiance I cos / d^2 (with soft
    # falloff Cycles divides by d^2 + r^2 instead, 1 % lower here).
    K.light("point", 'POINT', 100.0, (0, 0, 1.0), visible_camera=False,
            shadow_soft_size=0.1, use_soft_falloff=False)
    K.camera((0, -2.5, 2.5), (0, 0, 0), lens=40)
    _meta(sc, samples=4096,
          analytic=[{"kind": "point_lambert", "P": 100.0, "rho": 0.8,
                     "light": [0, 0, 1.0], "floor_z": 0.0,
                     "around": [0, 0, 0], "radius_px": 2,
                     # Box interreflection measured +0.11 % here (render
                     # without the box); bound = 2x.
                     "indirect_bound": 2.5e-3}],
          note="Point light (r = 0.1, use_soft_falloff False, not visible to "
               "the camera). Floor radiance is analytic away from the box.")
    return sc


def t_light_spot():
    sc = K.reset_scene(RES)
    _light_stage(box_at=(0.75, 0.55, 0))
    K.light("spot", 'SPOT', 100.0, (0, 0, 1.5), rotation=(0, 0, 0),
            visible_camera=False, shadow_soft_size=0.0,
            spot_size=math.radians(60), spot_blend=0.3)
    K.camera((0, -2.5, 2.5), (0, 0, 0), lens=40)
    _meta(sc, samples=4096,
          analytic=[{"kind": "spot_lambert", "P": 100.0, "rho": 0.8,
                     "light": [0, 0, 1.5], "floor_z": 0.0,
                     "spot_size": math.radians(60), "spot_blend": 0.3,
                     "around": [-0.35, -0.35, 0], "radius_px": 2,
                     # Box interreflection, measured without the box; bound 2x.
                     "indirect_bound": 4e-3}],
          note="Spot (60 deg, blend 0.3, radius 0): floor disk of radius "
               "0.87 m with a smoothstep edge; the box sits in the cone.")
    return sc


def t_light_sun():
    sc = K.reset_scene(RES)
    _light_stage(floor_rho=(0.6, 0.6, 0.6), box_at=(0.0, 1.5, 0))
    # Local -Z after Rx(50 deg) is (0, sin 50, -cos 50): elevation 40 deg.
    K.light("sun", 'SUN', 3.0, (0, 0, 3), rotation=(math.radians(50), 0, 0),
            visible_camera=True, angle=math.radians(5))
    K.camera((0, -4, 3), (0, 0, 0), lens=35)
    _meta(sc, samples=4096,
          analytic=[{"kind": "sun_lambert", "S": 3.0, "rho": 0.6,
                     "elevation_deg": 40.0, "floor_z": 0.0,
                     "region_y_max": -1.0,
                     # Box >= 2.5 m away: < 0.06 % estimated; bound 0.1 %.
                     "indirect_bound": 1e-3}],
          note="Sun S = 3 W/m^2 at 40 deg elevation, angle 5 deg: unshadowed "
               "floor far from the box is 0.6/pi*3*sin(40 deg) = 0.36829.")
    return sc


def _area_scene(shape, size, size_y=None, energy=50.0):
    sc = K.reset_scene(RES)
    _light_stage(box_at=(0.8, 0.3, 0))
    props = dict(shape=shape, size=size)
    if size_y is not None:
        props["size_y"] = size_y
    # Tilted 30 deg towards the camera so the camera sees its emitting side.
    K.light("area", 'AREA', energy, (0, 0.5, 1.6),
            rotation=(math.radians(-30), 0, 0), visible_camera=True, **props)
    K.camera((0, -3.5, 1.0), (0, 0, 0.5), lens=35)
    if shape == 'SQUARE':
        area = size * size
    elif shape == 'RECTANGLE':
        area = size * size_y
    elif shape == 'DISK':
        area = math.pi * size * size / 4
    else:
        area = math.pi * size * size_y / 4
    _meta(sc, samples=8192,
          analytic=[{"kind": "emitter_seen", "radiance": energy / (math.pi * area),
                     "formula": "P / (pi A)", "P": energy, "area": area,
                     "object": "area", "erode_px": 2}],
          note=f"Area light ({shape}) seen directly: interior pixels equal "
               f"P/(pi A) = {energy / (math.pi * area):.5f} with zero noise.")
    return sc


def t_light_area_square():
    return _area_scene('SQUARE', 1.0)          # 1 m^2, 50 W -> 50/pi


def t_light_area_disk():
    return _area_scene('DISK', 1.2)


def t_light_area_ellipse():
    return _area_scene('ELLIPSE', 1.4, 0.8)


def t_light_mesh():
    sc = K.reset_scene(RES)
    _light_stage(box_at=(0.8, 0.3, 0))
    strength = 10.0
    color = (1.0, 0.9, 0.8)
    em = K.material("emitter", 'EMISSION', color, strength=strength)
    # 0.6 m quad tilted 30 deg about X, both sides emit L = color * strength.
    q = K.plane("emitter", 0.6, em, location=(0, 0.5, 1.6),
                rotation=(math.radians(150), 0, 0))
    K.camera((0, -3.5, 1.0), (0, 0, 0.5), lens=35)
    _meta(sc, samples=8192,
          analytic=[{"kind": "emitter_seen", "radiance_rgb": [c * strength for c in color],
                     "formula": "Color * Strength", "object": q.name,
                     "erode_px": 2}],
          note="Emissive quad (two-sided, 0.36 m^2, L = (10, 9, 8)) seen "
               "directly; equals an area light of P = pi A S per side.")
    return sc


def t_world():
    wc = (0.4, 0.5, 0.7)
    sc = K.reset_scene(RES, world_color=wc)
    floor = K.material("floor", 'DIFFUSE', FLOOR)
    K.plane("floor", 6, floor)
    K.uv_sphere("sphere", 0.3, K.material("ball", 'DIFFUSE', (0.7, 0.35, 0.2)),
                (0, 1.0, 0.3), segments=16, rings=8)
    K.camera((0, -4, 1.5), (0, 0, 0.4), lens=35)
    _meta(sc, samples=4096,
          analytic=[{"kind": "world_seen", "radiance_rgb": list(wc)},
                    {"kind": "world_lambert", "rho": 0.8, "world_rgb": list(wc),
                     "floor_z": 0.0, "floor_half": 3.0, "sphere": [0, 1.0, 0.3],
                     "sphere_r": 0.3, "min_dist": 1.8, "occlusion_bound": 0.005}],
          note="Constant world (0.4, 0.5, 0.7): sky pixels equal it exactly; "
               "open floor reflects rho * world minus the sphere's occlusion.")
    return sc


SCENES = [t_cornell, t_mirror_caustic, t_glass_caustic, t_glossy_floor,
          t_light_point, t_light_spot, t_light_sun, t_light_area_square,
          t_light_area_disk, t_light_area_ellipse, t_light_mesh, t_world]


def triangle_count(sc):
    n = 0
    for ob in sc.objects:
        if ob.type == 'MESH':
            n += sum(len(p.vertices) - 2 for p in ob.data.polygons)
    return n


def main(names=None):
    for fn in SCENES:
        if names and fn.__name__ not in names:
            continue
        sc = fn()
        meta = json.loads(sc["fppm_test"])
        meta["triangles"] = triangle_count(sc)
        sc["fppm_test"] = json.dumps(meta)
        path = os.path.join(HERE, fn.__name__ + ".blend")
        K.save(path)
        print(f"{fn.__name__}: {meta['triangles']} triangles -> {path}")


if __name__ == "__main__":
    main(sys.argv[1:])
