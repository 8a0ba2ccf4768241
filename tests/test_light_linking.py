"""Light linking (an emitter's Receiver Collection), against Cycles.

An emitter lights only the objects its receiver collection lets it
(``core.scene.linking``: Blender's receiver sets and memberships, Cycles'
test): its light samples, the emission a BSDF ray from an unlit object
finds, and the first hits of its photons and light paths; camera rays see
it always.  Each case renders tests/test_shading_nodes.py's floor and box
in FPPM's integrators and in Cycles, two seeds a side, under that file's
bound (2x the seed-to-seed noise plus 1 % of the mean), and checks that
the linking moves the image by more than 3x the bound (the same export
rendered without it).  Then the rules themselves: the exporter's sets on
nested collections, the material split, and the compiled camera pass
against its numpy reference with linked lights.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.scene import linking as LL

RES = 40


def test_linked_and_the_material_split():
    """Bit r of a membership lights receiver set r, a camera ray (-1) sees
    every emitter; the split gives each (material, set, membership) its own
    material, the first copy keeping the index."""
    sets = np.array([LL.LINK_ALL, 0b10, LL.LINK_ALL & ~np.uint64(0b10)], np.uint64)
    assert list(LL.linked(sets, [1, 1, 1])) == [True, True, False]
    assert list(LL.linked(sets, [0, 0, 0])) == [True, False, True]
    assert list(LL.linked(sets, [-1, -1, -1])) == [True, True, True]
    from test_compiled_stages import SCENES
    scene = SCENES["room"](8)
    T, M = scene.tri_mat.shape[0], len(scene.materials)
    rcv = (np.arange(T) % 2).astype(np.uint8)
    out = LL.split_materials(scene, rcv, None)
    assert len(out.materials) > M and out.material_receiver is not None
    assert all(out.materials[m] is scene.materials[m] for m in range(M))
    np.testing.assert_array_equal(out.material_receiver[out.tri_mat], rcv)
    for t in range(T):
        assert out.materials[out.tri_mat[t]] is scene.materials[scene.tri_mat[t]]
    assert LL.split_materials(scene, np.zeros(T, np.uint8), None) is scene


def _scene(case):
    """tests/test_shading_nodes.py's floor and box under its sun; "sets":
    the sun lights the box alone (its receiver collection includes it) and
    a point light lights everything but the floor (excluded); "mirror": no
    sun, the box a tilted mirror, an emitting card that excludes it lights
    the floor (Cycles: it is not seen in the mirror)."""
    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16)
    box, _, _, _ = TS.floor_and_box()
    TS.ortho_view(sc, 2.2, sun_energy=0.0 if case == "mirror" else 3.0)
    K.set_world(sc, (0.05, 0.05, 0.05))
    if case == "sets":
        only_box = bpy.data.collections.new("OnlyBox")
        only_box.objects.link(box)
        bpy.data.objects["Sun"].light_linking.receiver_collection = only_box
        ld = bpy.data.lights.new("Point", 'POINT')
        ld.energy, ld.shadow_soft_size = 60.0, 0.1
        pt = K.link(bpy.data.objects.new("Point", ld))
        pt.location = (0.6, 0.5, 1.4)
        no_floor = bpy.data.collections.new("NoFloor")
        no_floor.objects.link(bpy.data.objects["Floor"])
        no_floor.collection_objects[0].light_linking.link_state = 'EXCLUDE'
        pt.light_linking.receiver_collection = no_floor
    else:
        mirror, nt, out = K._new_material("Mirror")
        g = nt.nodes.new('ShaderNodeBsdfGlossy')
        g.inputs["Roughness"].default_value = 0.0
        nt.links.new(g.outputs[0], out.inputs["Surface"])
        box.data.materials[0] = mirror
        box.rotation_euler = (np.radians(25.0), 0.0, np.radians(20.0))
        lamp = TS.lamp_over_box()
        lamp.location = (0.1, -1.2, 1.6)
        lamp.rotation_euler = (np.radians(-130.0), 0.0, 0.0)
        no_box = bpy.data.collections.new("NoBox")
        no_box.objects.link(box)
        no_box.collection_objects[0].light_linking.link_state = 'EXCLUDE'
        lamp.light_linking.receiver_collection = no_box
    return sc


def _unlinked(scene):
    return dataclasses.replace(
        scene, material_receiver=None, material_emitter=None,
        lights=[dataclasses.replace(lt, link_sets=LL.LINK_ALL) for lt in scene.lights])


#: (case, integrator).  Light tracing renders no mirror seen by the camera.
CASES = [("sets", "PHOTON"), ("sets", "PATH"), ("sets", "COMBINED"), ("sets", "LIGHT"),
         ("mirror", "PHOTON"), ("mirror", "PATH")]


@pytest.mark.parametrize("case,integrator", CASES, ids=[f"{c}-{i}" for c, i in CASES])
def test_light_linking_agrees_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Light linking"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = _scene(case)
    scene, lines = TS._export()
    assert scene.material_receiver is not None
    assert not any("linking" in ln for ln in lines), lines
    TS.agrees_with_cycles(sc, scene, integrator, tmp_path, _unlinked(scene), case,
                          key=(__name__, case))


def _shadow_scene(case):
    """tests/test_shading_nodes.py's floor and box; "sun": the sun is not
    blocked by the box (its blocker collection excludes it) and a point
    light without linking keeps the box's shadow; "area": an area light
    along the sun's direction and an emitting card out of the camera's
    view (emitters BSDF rays find too) are not blocked by the box."""
    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16)
    box, _, _, _ = TS.floor_and_box()
    TS.ortho_view(sc, 2.2, sun_energy=3.0 if case == "sun" else 0.0, sun_rotation=(0.8, 0.4, 0))
    K.set_world(sc, (0.05, 0.05, 0.05))
    no_box = bpy.data.collections.new("NoBox")
    no_box.objects.link(box)
    no_box.collection_objects[0].light_linking.link_state = 'EXCLUDE'
    if case == "sun":
        bpy.data.objects["Sun"].light_linking.blocker_collection = no_box
        ld = bpy.data.lights.new("Point", 'POINT')
        ld.energy, ld.shadow_soft_size = 25.0, 0.0
        K.link(bpy.data.objects.new("Point", ld)).location = (-0.7, 0.6, 1.4)
    else:
        from mathutils import Euler, Vector
        # A 1 m area light 4 m away along the sun's direction, and a small
        # emitting card out of the camera's view; neither is blocked by the box.
        ld = bpy.data.lights.new("Area", 'AREA')
        ld.energy, ld.size = 150.0, 1.0
        area = K.link(bpy.data.objects.new("Area", ld))
        area.rotation_euler = (0.8, 0.4, 0.0)
        area.location = 4.0 * (Euler((0.8, 0.4, 0.0)).to_matrix() @ Vector((0, 0, 1)))
        area.light_linking.blocker_collection = no_box
        lamp = TS.lamp_over_box()
        lamp.scale = (0.4, 0.4, 1.0)
        lamp.location = (-1.5, 0.8, 1.3)
        lamp.rotation_euler = Vector((1.6, -0.85, -1.0)).to_track_quat('-Z', 'Y').to_euler()
        lamp.light_linking.blocker_collection = no_box
    return sc


def _unshadowed(scene):
    return dataclasses.replace(
        scene, tri_blocker=None, tri_shadow_sets=None,
        lights=[dataclasses.replace(lt, shadow_sets=LL.LINK_ALL) for lt in scene.lights])


#: (case, integrator).  The area light's and card's light at the floor is
#: their light samples' alone in FPPM (core.scene.shadow_linking), Cycles'
#: both strategies.
SHADOW_CASES = [("sun", "PHOTON"), ("sun", "PATH"), ("sun", "LIGHT"),
                ("area", "PHOTON"), ("area", "PATH")]


@pytest.mark.parametrize("case,integrator", SHADOW_CASES,
                         ids=[f"{c}-{i}" for c, i in SHADOW_CASES])
def test_shadow_linking_agrees_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Shadow linking"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = _shadow_scene(case)
    scene, lines = TS._export()
    assert scene.tri_blocker is not None
    assert not any("linking" in ln for ln in lines), lines
    from core.lights import build_light_table
    from core.scene.shadow_linking import nee_only
    # The linked rows: the sun; the area light and the card's two triangles.
    assert nee_only(build_light_table(scene)).sum() == (1 if case == "sun" else 3)
    TS.agrees_with_cycles(sc, scene, integrator, tmp_path, _unshadowed(scene), f"shadow {case}",
                          key=(__name__, "shadow", case))


def test_exporter_resolves_nested_collections_as_blender():
    """A child collection's Exclude holds for its nested objects; an object
    named twice takes its last state (Blender visits child collections,
    then the objects); emitters sharing a collection share its sets; an
    Exclude-only collection lights everything else, an Include one only
    what it includes."""
    bpy = pytest.importorskip("bpy")
    import test_shading_nodes as TS
    from fppm.addon.export_links import light_link_sets
    from scenes import bpy_kit as K
    sc = K.reset_scene((8, 8), samples=1)
    TS.ortho_view(sc, 2.0)
    grey, nt, out = K._new_material("Grey")
    nt.links.new(nt.nodes.new('ShaderNodeBsdfDiffuse').outputs[0], out.inputs["Surface"])
    a, b, c, d = (K.plane(n, 0.3, grey, location=(x, 0, 0))
                  for n, x in (("A", -0.6), ("B", -0.2), ("C", 0.2), ("D", 0.6)))
    inc = bpy.data.collections.new("Inc")
    inner = bpy.data.collections.new("Inner")
    deep = bpy.data.collections.new("Deep")
    inc.children.link(inner)
    inner.children.link(deep)
    deep.objects.link(b)                      # Inner's state: Exclude
    inc.collection_children[0].light_linking.link_state = 'EXCLUDE'
    inc.objects.link(a)                       # Include
    inc.objects.link(b)                       # named again: Include wins (last)
    exc = bpy.data.collections.new("Exc")
    exc.objects.link(c)
    exc.collection_objects[0].light_linking.link_state = 'EXCLUDE'
    lights = []
    for name, coll in (("L1", inc), ("L2", inc), ("L3", exc)):
        lo = K.link(bpy.data.objects.new(name, bpy.data.lights.new(name, 'POINT')))
        lo.light_linking.receiver_collection = coll
        lights.append(lo)
    receiver, membership, notes = light_link_sets(list(bpy.data.objects))
    assert notes == [] and membership["L1"] == membership["L2"]

    def lit(light, ob):
        return bool(LL.linked(np.array([membership.get(light, LL.LINK_ALL)], np.uint64),
                              [receiver.get(ob, 0)])[0])
    assert [lit("L1", o) for o in "ABCD"] == [True, True, False, False]
    assert [lit("L3", o) for o in "ABCD"] == [True, True, False, True]
    # The exported scene: the split materials carry the same answers.
    scene, _ = TS._export()
    from core.lights import build_light_table
    t = build_light_table(scene)
    ctr = scene.tri_p.mean(axis=1)
    for ob, x in zip("ABCD", (-0.6, -0.2, 0.2, 0.6)):
        tri = np.nonzero(np.abs(ctr[:, 0] - x) < 0.15)[0]
        rcv = scene.material_receiver[scene.tri_mat[tri]]
        for name in ("L1", "L2", "L3"):
            li = [lt.name for lt in scene.lights].index(name)
            row = np.nonzero((t.kind != 4) & (t.source == li))[0]
            assert LL.linked(t.link_sets[row].repeat(tri.size), rcv).all() == lit(name, ob)


@pytest.mark.parametrize("blocked", [False, True])
def test_compiled_camera_pass_equals_numpy_with_linking(blocked, monkeypatch):
    """The glossy and delta chains of the metal scene with linked lights:
    the compiled camera pass (one call, or blocks of 700 pixels) adds the
    same emission and glossy points' light samples as the numpy reference,
    bit for bit, and the linking removes some of it."""
    from core.render import Renderer
    from core.settings import RenderSettings
    from core.sppm import visible_points as VP
    from test_compiled_stages import SCENES
    if blocked:
        monkeypatch.setattr(VP, "CAMERA_BLOCK", 700)
    base = SCENES["metal"](40)
    T = base.tri_mat.shape[0]
    # The mirror and metal strips in set 1, which the emissive triangles and
    # every other light do not light.
    rcv = np.where(np.isin(base.tri_mat, (0, 3)), 1, 0).astype(np.uint8)
    emt = np.where(base.tri_mat == 4, LL.LINK_ALL & ~np.uint64(2), LL.LINK_ALL).astype(np.uint64)
    scene = LL.split_materials(base, rcv, emt)
    scene = dataclasses.replace(scene, lights=[
        dataclasses.replace(lt, link_sets=LL.LINK_ALL & ~2 if i % 2 else LL.LINK_ALL)
        for i, lt in enumerate(scene.lights)])
    out = {}
    for name, sc in (("linked", scene), ("plain", base)):
        r = Renderer(sc, RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=100,
                                        seed=1), log=lambda _m: None,
                     force_stages=("glossy chains",))
        cam = r.camera_pass
        for compiled in (False, True):
            rng = np.random.default_rng(11)
            cam.compiled = compiled
            vp, L = cam(rng)
            out[name, compiled] = (vp, L.copy(), cam.glossy_count)
    (vp_n, L_n, g_n), (vp_c, L_c, g_c) = out["linked", False], out["linked", True]
    assert g_n == g_c > 50
    assert np.array_equal(L_n, L_c)
    for f in ("valid", "p", "mat", "colors"):
        assert np.array_equal(getattr(vp_n, f), getattr(vp_c, f)), f
    L_plain = out["plain", True][1]
    assert L_n.sum() < 0.98 * L_plain.sum()


def test_compiled_direct_light_equals_numpy_with_shadow_linking():
    """The room of tests/test_compiled_stages.py with half its triangles in
    blocker set 1, which every other light is not blocked by: the compiled
    light samples (shadow rays grouped by view) add what the numpy
    reference adds, and the unblocked lights add light."""
    from core.render import Renderer
    from core.settings import RenderSettings
    from test_compiled_stages import SCENES, _run
    base = SCENES["room"](40)
    T = base.tri_mat.shape[0]
    scene = dataclasses.replace(
        base, tri_blocker=(np.arange(T) % 2).astype(np.uint8),
        lights=[dataclasses.replace(lt, shadow_sets=LL.LINK_ALL & ~2 if i % 2 else LL.LINK_ALL)
                for i, lt in enumerate(base.lights)])
    out = {}
    for name, sc in (("linked", scene), ("plain", base)):
        r = Renderer(sc, RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=100,
                                        seed=1), log=lambda _m: None)
        vp, _ = r.camera_pass(np.random.default_rng(11))
        nee = r.direct_light
        assert (nee.views is not None) == (name == "linked")
        out[name] = [_run(nee, c, vp, np.random.default_rng(12)) for c in (False, True)]
    L_n, L_c = out["linked"]
    np.testing.assert_allclose(L_c, L_n, rtol=1e-9, atol=1e-12 * float(L_n.max()))
    assert L_n.sum() > 1.2 * out["plain"][0].sum()         # (measured 1.36)
