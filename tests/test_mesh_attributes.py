"""The Geometry node's Pointiness and Random Per Island
(core/scene/mesh_attributes.py) against closed forms and against Cycles'
own values, baked from an Emission into a colour attribute at every face
corner (``bpy.ops.object.bake(type='EMIT', target='VERTEX_COLORS')``: the
shader evaluated at the corner itself, no sampling noise)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from core.scene import mesh_attributes as MA

#: A unit cube's corners and edges.
CUBE = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
CUBE_EDGES = np.array([[0, 1], [1, 3], [3, 2], [2, 0], [4, 5], [5, 7], [7, 6], [6, 4],
                       [0, 4], [1, 5], [2, 6], [3, 7]])


def test_a_cube_corner_is_acos_of_its_edges_mean():
    """At a cube's corner, normal (1, 1, 1)/sqrt 3 and the mean edge -(1, 1,
    1)/3: raw acos(-1/sqrt 3)/pi; every corner alike, so the blur keeps it.
    Split copies of every corner (a UV seam) weld back: the same values."""
    n = (CUBE - 0.5) / np.linalg.norm(CUBE - 0.5, axis=1, keepdims=True)
    want = math.acos(-1.0 / math.sqrt(3.0)) / math.pi
    assert np.allclose(MA.pointiness(CUBE, n, CUBE_EDGES), want, atol=1e-12)
    split = MA.pointiness(np.concatenate([CUBE, CUBE]), np.concatenate([n, n]),
                          np.concatenate([CUBE_EDGES[:6], CUBE_EDGES[6:] + 8]))
    assert np.allclose(split, want, atol=1e-12)
    assert list(MA.welded(np.concatenate([CUBE, CUBE]))[8:]) == list(range(8))


def test_a_flat_grid_is_one_half():
    """A flat grid's vertices: edges in the plane, normal across it: 1/2."""
    g = np.array([[x, y, 0.0] for y in range(4) for x in range(4)], np.float32)
    e = [[i, i + 1] for i in range(16) if i % 4 < 3] + [[i, i + 4] for i in range(12)]
    n = np.tile([0.0, 0.0, 1.0], (16, 1))
    assert np.allclose(MA.pointiness(g, n, e), 0.5)


def test_islands_follow_union_by_rank():
    """Two islands; each root is the union's (the first argument's root on
    equal ranks): 0 for {0, 1, 2}, 4 for {3, 4}."""
    roots = MA.island_roots(5, [[0, 1], [2, 1], [4, 3]])
    assert list(roots) == [0, 0, 0, 4, 4]


def _cycles_bake(me):
    """(corner vertex (L,), Cycles' Pointiness (L,), Random Per Island (L,))
    at mesh me's face corners, from a bake of an Emission of (Pointiness,
    Random Per Island, 0)."""
    import bpy
    sc = bpy.context.scene
    sc.render.engine = 'CYCLES'
    sc.cycles.samples = 1
    ob = bpy.data.objects.new("Baked", me)
    sc.collection.objects.link(ob)
    m = bpy.data.materials.new("Bake")
    from scenes import bpy_kit as K
    m, nt, out = K._new_material("Bake")
    em = nt.nodes.new('ShaderNodeEmission')
    geo = nt.nodes.new('ShaderNodeNewGeometry')
    cx = nt.nodes.new('ShaderNodeCombineXYZ')
    nt.links.new(geo.outputs['Pointiness'], cx.inputs[0])
    nt.links.new(geo.outputs['Random Per Island'], cx.inputs[1])
    nt.links.new(cx.outputs[0], em.inputs['Color'])
    nt.links.new(em.outputs[0], out.inputs['Surface'])
    me.materials.append(m)
    ca = me.color_attributes.new("Bake", 'FLOAT_COLOR', 'CORNER')
    me.color_attributes.active_color = ca
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)
    bpy.ops.object.bake(type='EMIT', target='VERTEX_COLORS')
    c = np.empty(len(ca.data) * 4, np.float32)
    ca.data.foreach_get("color", c)
    lv = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", lv)
    c = c.reshape(-1, 4).astype(np.float64)
    return lv, c[:, 0], c[:, 1]


def _arrays(me):
    V = len(me.vertices)
    co, nv = np.empty(V * 3, np.float32), np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    me.vertices.foreach_get("normal", nv)
    e = np.empty(len(me.edges) * 2, np.int64)
    me.edges.foreach_get("vertices", e)
    return co.reshape(V, 3), nv.reshape(V, 3), e.reshape(-1, 2)


@pytest.mark.parametrize("split", [False, True])
def test_mesh_attributes_match_cycles(split):
    """Five islands (icospheres of one and two subdivisions, a bevelled box)
    in one mesh; ``split``: the second sphere's edges split, its corners
    duplicated at the same places (welded by Cycles, and here).  Measured:
    Pointiness within 5.4e-5 (float32 against float64 arithmetic),
    Random Per Island exact to float32."""
    pytest.importorskip("bpy")
    import bmesh
    import bpy

    from scenes import bpy_kit as K
    from test_procedural_materials import _islands_mesh
    K.reset_scene((8, 8))
    me = _islands_mesh(bpy)
    if split:
        bm = bmesh.new()
        bm.from_mesh(me)
        bm.verts.ensure_lookup_table()
        near = [e for e in bm.edges
                if all((v.co - __import__("mathutils").Vector((0.1, -0.35, 0))).length < 0.3
                       for v in e.verts)]
        bmesh.ops.split_edges(bm, edges=near)
        bm.to_mesh(me)
        bm.free()
    co, nv, e = _arrays(me)
    welded = MA.welded(co)
    # the split sphere: 80 faces, 240 corners on 42 places: 198 copies welded
    assert (welded != np.arange(len(co))).sum() == (198 if split else 0)
    lv, pointy, island = _cycles_bake(me)
    ours = MA.pointiness(co, nv, e)[lv]
    print(f"pointiness: largest |ours - Cycles| {np.abs(ours - pointy).max():.2g} over "
          f"{len(lv)} corners, values {pointy.min():.3f} .. {pointy.max():.3f}")
    assert np.abs(ours - pointy).max() < 2e-4
    assert pointy.max() - pointy.min() > 0.05
    T = len(me.loop_triangles)
    loops = np.empty(T * 3, np.int32)
    me.loop_triangles.foreach_get("loops", loops)
    isl = MA.random_per_island(len(me.vertices), e, lv[loops[0::3]])
    assert np.abs(np.repeat(isl, 3) - island[loops]).max() < 1e-7
    assert len(np.unique(island)) >= 5
