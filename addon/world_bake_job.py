"""Render a world shader to an equirectangular map with Cycles (a child process).

Run by ``addon/world_bake.py`` as ``blender -b --factory-startup --python
world_bake_job.py -- SPEC.json`` (inside Blender) or ``python
world_bake_job.py SPEC.json`` (the ``bpy`` module).  It imports nothing of
FPPM (and addon/world_bake.py imports it for :func:`node_trees` and
:func:`sun_nodes`): it appends one world from a .blend that the parent wrote
(``bpy.data.libraries.write``), renders it alone and writes OpenEXR files.

SPEC (JSON): blend, world (name), frame, width (the map is width x width/2),
samples, out (the map's path), camera_out (with a Light Path node in the
world: the map camera rays see; ``out`` then holds the one that lights the
scene, :func:`as_lighting_ray`), and, when ``sun`` is true, sun_out and
sun_res: the sky is rendered with every Sky Texture's sun disc (of at most
MAX_DISC) off, and the brightest disc is rendered again through a narrow perspective camera
aimed at it, for the parent to turn into a sun light (world_bake.py says
why).  The result's JSON (SPEC's ``result``) gives the aim and the field
of view.

The map: a panoramic equirectangular camera at the origin looking along
+X (rotation X 90 deg, Z -90 deg), so that pixel (row, column) sees the
direction an Environment Texture's pixel at the same place is looked up
by (tests/test_world_bake.py renders an Environment Texture world both ways).
Pixel filter: a box of one pixel, so a pixel is the mean radiance over its
extent in (u, v), what a map's texel stands for.
"""
import json
import math
import sys

import bpy


def _args() -> dict:
    argv = sys.argv
    rest = argv[argv.index("--") + 1:] if "--" in argv else argv[1:]
    with open(rest[-1]) as f:
        return json.load(f)


def node_trees(tree, seen=None):
    """The node tree and every node group inside it, once each (also used by
    addon/world_bake.py, which imports this module without running it)."""
    seen = set() if seen is None else seen
    if tree is None or tree.as_pointer() in seen:
        return
    seen.add(tree.as_pointer())
    yield tree
    for nd in tree.nodes:
        if getattr(nd, "node_tree", None) is not None:
            yield from node_trees(nd.node_tree, seen)


# A disc is found when the probe's brightest pixel is this many times its
# median (a disc at the horizon is 1e3-1e4 times the sky around it).
DISC_CONTRAST = 50.0
# Discs wider than this [rad] stay in the map (world_bake.py: the disc
# render's median would be the disc).
MAX_DISC = math.radians(10.0)


def sun_nodes(world):
    """Sky Texture nodes that draw a sun disc small enough to become a light."""
    return [nd for t in node_trees(world.node_tree) for nd in t.nodes
            if nd.type == 'TEX_SKY' and getattr(nd, "sun_disc", False)
            and nd.sky_type in ('SINGLE_SCATTERING', 'MULTIPLE_SCATTERING')
            and nd.sun_size <= MAX_DISC]


#: What a Light Path node says to a ray that lights a surface: Cycles'
#: values for the first diffuse bounce (the ray from a diffuse surface to
#: the world; glossy reflections of the world see it too, where Cycles would
#: say Is Glossy Ray).
LIGHTING_RAY = {"Is Camera Ray": 0.0, "Is Shadow Ray": 0.0, "Is Diffuse Ray": 1.0,
                "Is Glossy Ray": 0.0, "Is Singular Ray": 0.0, "Is Reflection Ray": 1.0,
                "Is Transmission Ray": 0.0, "Is Volume Scatter Ray": 0.0,
                "Ray Length": 1.0e10, "Ray Depth": 1.0, "Diffuse Depth": 1.0,
                "Glossy Depth": 0.0, "Transparent Depth": 0.0, "Transmission Depth": 0.0,
                "Portal Depth": 0.0}

#: What it says to a camera ray (also through Transparent BSDFs) and to a
#: shadow ray, as far as a constant can (Ray Length is a distance; FPPM's
#: materials read Is Camera Ray and Is Shadow Ray per ray kind,
#: addon/export.py ``_mix_by_ray``).
CAMERA_RAY = dict(LIGHTING_RAY, **{"Is Camera Ray": 1.0, "Is Diffuse Ray": 0.0,
                                   "Is Reflection Ray": 0.0, "Ray Depth": 0.0,
                                   "Diffuse Depth": 0.0})
SHADOW_RAY = dict(LIGHTING_RAY, **{"Is Shadow Ray": 1.0})


def has_light_path(world) -> bool:
    return any(nd.type == 'LIGHT_PATH' for t in node_trees(world.node_tree) for nd in t.nodes)


def as_lighting_ray(world) -> None:
    """Every Light Path output in the world's trees replaced by a Value node
    holding LIGHTING_RAY's value (unknown outputs: 0)."""
    for t in node_trees(world.node_tree):
        for nd in [n for n in t.nodes if n.type == 'LIGHT_PATH']:
            for out in nd.outputs:
                targets = [ln.to_socket for ln in t.links if ln.from_socket == out]
                if not targets:
                    continue
                v = t.nodes.new('ShaderNodeValue')
                v.outputs[0].default_value = LIGHTING_RAY.get(out.name, 0.0)
                for sock in targets:
                    t.links.new(v.outputs[0], sock)


def _scene(spec):
    sc = bpy.context.scene
    for ob in list(sc.objects):
        bpy.data.objects.remove(ob)
    with bpy.data.libraries.load(spec["blend"], link=False) as (src, dst):
        dst.worlds = [spec["world"]]
    world = dst.worlds[0]
    sc.world = world
    vis = getattr(world, "cycles_visibility", None)
    if vis is not None:
        vis.camera = True
    sc.frame_set(int(spec["frame"]))
    r = sc.render
    r.engine = 'CYCLES'
    r.resolution_percentage = 100
    r.film_transparent = False
    r.use_border = False
    r.use_compositing = False
    r.use_sequencer = False
    r.image_settings.file_format = 'OPEN_EXR'
    r.image_settings.color_depth = '32'
    c = sc.cycles
    c.device = 'CPU'
    c.samples = int(spec["samples"])
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = 0
    c.pixel_filter_type = 'BOX'
    c.filter_width = 1.0
    vs = sc.view_settings
    vs.view_transform = 'Standard'
    vs.look = 'None'
    vs.exposure = 0.0
    vs.gamma = 1.0
    return sc, world


def _render(sc, path):
    sc.render.filepath = path
    bpy.ops.render.render(write_still=True)


def main():
    spec = _args()
    sc, world = _scene(spec)
    suns = sun_nodes(world) if spec.get("sun") else []
    for nd in suns:
        nd.sun_disc = False
    cam = bpy.data.cameras.new("fppm_bake")
    cam.type = 'PANO'
    cam.panorama_type = 'EQUIRECTANGULAR'
    co = bpy.data.objects.new("fppm_bake", cam)
    sc.collection.objects.link(co)
    sc.camera = co
    co.rotation_euler = (math.pi / 2, 0.0, -math.pi / 2)
    W = int(spec["width"])
    sc.render.resolution_x, sc.render.resolution_y = W, max(1, W // 2)
    if spec.get("camera_out"):
        # A Light Path node: this render is what camera rays see; the map
        # that lights the scene is rendered with every Light Path output
        # fixed to a diffuse ray's values (LIGHTING_RAY).
        _render(sc, spec["camera_out"])
        as_lighting_ray(world)
    _render(sc, spec["out"])
    result = {"suns": len(suns)}
    if suns:
        # Where the disc is: a Mapping node may turn the sky, so the disc is
        # found in a small render of the sky with its discs on (a probe
        # pixel is 1.4 deg, the default disc 0.545 deg and 1e4-1e5 times
        # the sky: the brightest pixel holds it).
        for nd in suns:
            nd.sun_disc = True
        pw = 256
        sc.render.resolution_x, sc.render.resolution_y = pw, pw // 2
        probe = spec["sun_out"] + ".probe.exr"
        _render(sc, probe)
        img = bpy.data.images.load(probe)
        px = list(img.pixels)
        bpy.data.images.remove(img)
        lum = [0.2126 * px[i] + 0.7152 * px[i + 1] + 0.0722 * px[i + 2]
               for i in range(0, len(px), 4)]
        k = max(range(len(lum)), key=lum.__getitem__)
        if lum[k] > DISC_CONTRAST * sorted(lum)[len(lum) // 2]:
            result.update(_disc(sc, spec, suns, k, pw))
        else:
            # No disc stands out: the sun is below the horizon (the ground
            # hides it).  The sky keeps no disc and there is no sun light.
            result["suns"] = 0
    with open(spec["result"], "w") as f:
        json.dump(result, f)


def _disc(sc, spec, suns, k, pw) -> dict:
    """Render the disc seen in the probe's pixel k (pw pixels wide, row 0
    at the bottom) through a narrow perspective camera into sun_out; the
    camera's field of view, matrix and the disc's size for the parent."""
    row, col = divmod(k, pw)              # row 0 at the bottom
    u, v = (col + 0.5) / pw, (row + 0.5) / (pw // 2)
    lat, phi = (v - 0.5) * math.pi, (0.5 - u) * 2.0 * math.pi
    aim = (math.cos(lat) * math.cos(phi), math.cos(lat) * math.sin(phi), math.sin(lat))
    # The disc again through a narrow perspective camera: twice the disc
    # plus the probe's pixel error (+-0.7 deg), sun_res pixels square,
    # so that the disc covers under a fifth of it and the median pixel
    # is sky.
    size = max(float(nd.sun_size) for nd in suns)
    fov = 2.0 * size + math.radians(3.0)
    cam2 = bpy.data.cameras.new("fppm_sun")
    cam2.type = 'PERSP'
    cam2.sensor_fit = 'HORIZONTAL'
    cam2.angle = fov
    co2 = bpy.data.objects.new("fppm_sun", cam2)
    sc.collection.objects.link(co2)
    from mathutils import Vector
    co2.rotation_mode = 'QUATERNION'
    co2.rotation_quaternion = Vector(aim).to_track_quat('-Z', 'Y')
    sc.camera = co2
    n = int(spec["sun_res"])
    sc.render.resolution_x = sc.render.resolution_y = n
    _render(sc, spec["sun_out"])
    bpy.context.view_layer.update()
    return {"fov": fov, "size": size, "matrix": [list(r) for r in co2.matrix_world]}


if __name__ == "__main__":
    main()
