"""What baking a material's atlas costs at render start, in passes of the
render it starts.

    .venv/bin/python bench/bench_atlas.py

Five scenes at 256 x 256 under a sun, each with one atlas material
(addon/export_atlas.py): the default cube under a default Noise (Color into
the Base Color, Generated coordinates); a 128 x 64 UV sphere under a
Voronoi; a 10 m floor of two triangles under a Noise at Object coordinates
(over the atlas budget); 51 instances of an icosphere sharing their blocks;
and a graph (a Noise whose vector a second Noise distorts, through Map
Range and Math into a metal's Roughness).  For each it exports the scene
with the material and with the material's node tree cut to a plain
Principled BSDF, three times each, and times a pass of the default Photon
Mapping render (200,000 photons: 5 passes less 1, over 4); it prints the
bake's wall time (export with the atlas minus export without, medians) over
the pass's, with the atlas's texels (docs/shading.md "Procedural textures,
node graphs and material atlases").
"""
from __future__ import annotations

import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

import fppm_alias  # noqa: E402,F401


def _material(build):
    from scenes import bpy_kit as K
    m, nt, out = K._new_material("Procedural")
    p = nt.nodes.new('ShaderNodeBsdfPrincipled')
    nt.links.new(p.outputs[0], out.inputs['Surface'])
    build(nt.nodes, nt.links, p)
    return m


def _noise_color(coord=None):
    def build(nodes, links, p):
        n = nodes.new('ShaderNodeTexNoise')
        if coord:
            tc = nodes.new('ShaderNodeTexCoord')
            links.new(tc.outputs[coord], n.inputs['Vector'])
        links.new(n.outputs['Color'], p.inputs['Base Color'])
    return build


def _voronoi(nodes, links, p):
    v = nodes.new('ShaderNodeTexVoronoi')
    links.new(v.outputs['Color'], p.inputs['Base Color'])


def _graph(nodes, links, p):
    from test_procedural_materials import distorted_noise_roughness
    distorted_noise_roughness(nodes, links, p)


def _scenes():
    import bpy

    def cube(m):
        bpy.ops.mesh.primitive_cube_add()
        bpy.context.object.data.materials.append(m)

    def sphere(m):
        bpy.ops.mesh.primitive_uv_sphere_add(segments=128, ring_count=64)
        bpy.context.object.data.materials.append(m)

    def floor(m):
        bpy.ops.mesh.primitive_plane_add(size=10)
        bpy.context.object.data.materials.append(m)

    def instances(m):
        bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3)
        ob = bpy.context.object
        ob.data.materials.append(m)
        for i in range(50):
            o2 = ob.copy()
            o2.location = (i % 10 - 5, i // 10 - 2, 0)
            bpy.context.scene.collection.objects.link(o2)

    return [("cube, Noise", cube, _noise_color()), ("UV sphere, Voronoi", sphere, _voronoi),
            ("10 m floor, Noise (Object)", floor, _noise_color('Object')),
            ("51 instances, Noise", instances, _noise_color()), ("cube, graph", cube, _graph)]


def main():
    import bpy
    import numpy as np

    from fppm.addon.export import export_scene
    from fppm.addon.export_atlas import _CACHE
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    from scenes import bpy_kit as K
    for label, geometry, build in _scenes():
        sc = K.reset_scene((256, 256))
        bpy.ops.object.camera_add(location=(0, -7, 4), rotation=(1.05, 0, 0))
        sc.camera = bpy.context.object
        bpy.ops.object.light_add(type='SUN', rotation=(0.4, 0.2, 0))
        m = _material(build)
        geometry(m)

        def export():
            _CACHE.clear()        # each export bakes (the viewport's cache left out)
            dg = bpy.context.evaluated_depsgraph_get()
            t = time.perf_counter()
            s = export_scene(dg, log=lambda line: None)
            return time.perf_counter() - t, s

        with_atlas, scene = [], None
        for _ in range(3):
            dt, scene = export()
            with_atlas.append(dt)
        texels = sum(int(np.prod(t.shape[:2])) for t in scene.textures)
        nt = m.node_tree
        for nd in [nd for nd in nt.nodes if nd.type not in ('OUTPUT_MATERIAL', 'BSDF_PRINCIPLED')]:
            nt.nodes.remove(nd)
        plain = [export()[0] for _ in range(3)]
        def render(passes):
            t = time.perf_counter()
            Renderer(scene, RenderSettings(max_passes=passes, seed=1), log=lambda s: None).run()
            return time.perf_counter() - t
        render(1)
        one_pass = (render(5) - render(1)) / 4     # a pass, without the set-up
        bake = np.median(with_atlas) - np.median(plain)
        print(f"{label:28s} bake {bake / one_pass:5.2f} passes ({bake:.2f} s / a pass "
              f"{one_pass:.2f} s), {texels / 1e6:.2f} M texels")


if __name__ == "__main__":
    main()
