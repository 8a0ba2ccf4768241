"""Holdout (Object > Visibility > Holdout, the Holdout shader), against Cycles.

Camera rays that meet a holdout surface, also through a Transparent BSDF,
add its weight to the film's transparency and end there at weight 1; every
other ray sees the object as an ordinary one (``core.scene.holdout``).
Each case renders a floor under a floating box (or an emitting square) in
FPPM's integrators and in Cycles, two seeds a side, and compares the colour
and the alpha under tests/test_shading_nodes.py's bound (2x the
seed-to-seed noise plus 1 % of the mean), then checks that the holdout
moves the image by more than 3x that bound (the same export rendered
without it).  Light tracing's film is opaque: its colour alone is compared.
Then the unit rules: the weights and the camera rays that end, the
exporter's reading of mixes and instances, and the compiled camera pass
against its numpy reference.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.scene import holdout as H

RES = 40


def test_weights_and_the_rays_that_end():
    """Object holdout is 1 whatever the material; a material's is its
    Holdout closures' weight; only rays on their camera ray's line take it,
    adding weight x mean throughput to their pixel's transparency."""
    from core.scene.model import Material
    mats = [Material("a"), Material("b", holdout=0.5), Material("c", holdout=1.0)]
    sc = type("S", (), {})()
    sc.materials, sc.tri_mat = mats, np.array([0, 1, 2, 0], np.int32)
    sc.tri_holdout = None
    assert list(H.triangle_weights(sc)) == [0.0, 0.5, 1.0, 0.0]
    sc.tri_holdout = np.array([False, False, False, True])
    w = H.triangle_weights(sc)
    assert list(w) == [0.0, 0.5, 1.0, 1.0]
    assert list(H.ends_camera(w)) == [False, False, True, True]
    sc.materials, sc.tri_holdout = [Material("a")] * 3, None
    assert H.triangle_weights(sc) is None and H.ends_camera(None) is None
    prim = np.array([0, 1, 2, 3, -1, 3])
    on_line = np.array([True, True, True, True, True, False])
    beta = np.array([[1, 1, 1], [0.2, 0.4, 0.6], [1, 1, 1], [0.5, 0.5, 0.5], [1, 1, 1],
                     [1, 1, 1]], float)
    escape = np.zeros(4)
    ends = H.camera_hits(w, prim, on_line, beta, escape, np.array([0, 1, 2, 3, 0, 1]))
    assert list(ends) == [False, False, True, True, False, False]
    np.testing.assert_allclose(escape, [0.0, 0.2, 1.0, 0.5])


def test_a_transparent_holdout_object_keeps_its_transparency():
    """see_through: a holdout object's material with a Transparent lobe is
    copied, camera rays seeing that lobe alone; its weight is then taken
    per hit, 1 - the transparency there, and the film's transparency gets
    average((1 - T) x throughput)."""
    from core.scene.model import DIFFUSE, TRANSPARENT, Lobe, Material
    mats = [Material("leaf", (Lobe(DIFFUSE, weight=0.6), Lobe(TRANSPARENT, (1, .5, 0), 0.4))),
            Material("wall")]
    from analytic_scenes import look_down_ortho, quad
    from core.scene.model import make_scene
    tris = np.concatenate([quad((x, 0, 0), (0, 0.4, 0), (0.4, 0, 0)) for x in (-1, 1)])
    sc = dataclasses.replace(make_scene(tris, mats, [], look_down_ortho(3.0, 2.0, 4),
                                        tri_mat=[0, 0, 1, 0]),
                             tri_holdout=np.array([True, True, True, False]))
    out = H.see_through(sc)
    assert list(out.tri_mat) == [2, 2, 1, 0] and len(out.materials) == 4
    assert out.materials[2] is mats[0] and list(out.material_camera) == [0, 1, 3, 3]
    assert [lb.kind for lb in out.materials[3].lobes] == [TRANSPARENT]
    w = H.triangle_weights(out)
    assert np.isnan(w[0]) and np.isnan(w[1]) and w[2] == 1.0 and w[3] == 0.0
    T = np.array([[0.4, 0.2, 0.0]])
    escape = np.zeros(1)
    ends = H.camera_hits(w, np.array([0]), np.array([True]), np.array([[1.0, 0.5, 1.0]]),
                         escape, np.array([0]), (np.zeros(1), np.zeros(1)),
                         lambda p, u, v: T)
    assert not ends[0]
    np.testing.assert_allclose(escape, [((1 - T) * [1.0, 0.5, 1.0]).mean()])


def _scene(case):
    """A 2.4 m grey floor seen from above (orthographic) under a tilted sun,
    a red box floating over it; "object": the box is a holdout, Film >
    Transparent; "opaque": the same, the film opaque; "shader": the box's
    material a Mix Shader of a Holdout and its Diffuse at 0.5; "veil": the
    holdout box seen through a tinted Transparent BSDF; "emitter": no sun,
    an emitting square over the box that is a holdout lights the scene;
    "see": the holdout box's material lets light through (a Mix Shader of
    its Diffuse and a tinted Transparent BSDF at 0.4)."""
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16)
    box, nt, d, out = TS.floor_and_box()
    if case == "shader":
        mix = nt.nodes.new('ShaderNodeMixShader')
        mix.inputs["Fac"].default_value = 0.5
        nt.links.new(nt.nodes.new('ShaderNodeHoldout').outputs[0], mix.inputs[1])
        nt.links.new(d.outputs[0], mix.inputs[2])
        nt.links.new(mix.outputs[0], out.inputs["Surface"])
    if case == "see":
        mix = nt.nodes.new('ShaderNodeMixShader')
        mix.inputs["Fac"].default_value = 0.4
        t = nt.nodes.new('ShaderNodeBsdfTransparent')
        t.inputs["Color"].default_value = (0.9, 0.7, 0.5, 1.0)
        nt.links.new(d.outputs[0], mix.inputs[1])
        nt.links.new(t.outputs[0], mix.inputs[2])
        nt.links.new(mix.outputs[0], out.inputs["Surface"])
    box.is_holdout = case in ("object", "opaque", "veil", "see")
    if case == "veil":
        TS.veil_over_box()
    if case == "emitter":
        TS.lamp_over_box().is_holdout = True
    TS.ortho_view(sc, 2.2, sun_energy=0.0 if case == "emitter" else 3.0)
    sc.render.film_transparent = case != "opaque"
    return sc


def _render(scene, integrator, seed):
    import test_shading_nodes as TS
    return TS.render_integrator(scene, integrator, seed, rgba=True)


_REFS: dict = {}


def _reference(case, tmp_path):
    """(exported scene, its log, Cycles' two seeds) of a case, rendered once."""
    if case not in _REFS:
        import test_shading_nodes as TS
        sc = _scene(case)
        scene, lines = TS._export()
        # Cycles' RGBA (its alpha: 1 - the holdouts' and escapes' transparency).
        _REFS[case] = (scene, lines, TS._cycles(sc, 0, tmp_path / "c0.exr", 256, rgba=True),
                       TS._cycles(sc, 1, tmp_path / "c1.exr", 256, rgba=True))
    return _REFS[case]


def _compare(a1, a2, c1, c2, ch):
    """(mean |FPPM - Cycles| / mean, seed-to-seed noise / mean) on channels ch."""
    ref, img = (c1[..., ch] + c2[..., ch]) / 2, (a1[..., ch] + a2[..., ch]) / 2
    mean = ref.mean()
    noise = (np.abs(a1[..., ch] - a2[..., ch]).mean()
             + np.abs(c1[..., ch] - c2[..., ch]).mean()) / 2 / mean
    return np.abs(img - ref).mean() / mean, noise


#: (case, integrator).  Combined renders Path Tracing's image under the sun
#: alone: it is the emitter case's.
CASES = [("object", "PHOTON"), ("object", "PATH"), ("object", "LIGHT"),
         ("opaque", "PHOTON"), ("shader", "PATH"), ("veil", "PHOTON"),
         ("emitter", "COMBINED"), ("see", "PHOTON"), ("see", "PATH")]
RGB, ALPHA = slice(0, 3), slice(3, 4)


@pytest.mark.parametrize("case,integrator", CASES, ids=[f"{c}-{i}" for c, i in CASES])
def test_holdout_agrees_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Holdout"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    scene, lines, c1, c2 = _reference(case, tmp_path)
    assert not any("holdout" in ln for ln in lines), lines
    if case == "shader":
        assert scene.tri_holdout is None and sorted(m.holdout for m in scene.materials) == [0, .5]
    else:
        assert scene.tri_holdout is not None and scene.tri_holdout.sum() == (
            2 if case == "emitter" else 12)
        assert (scene.material_camera is not None) == (case == "see")
    a1, a2 = _render(scene, integrator, 1), _render(scene, integrator, 2)
    # (Without the holdout: "see"'s camera rays see the whole material again.)
    plain = dataclasses.replace(scene, tri_holdout=None, materials=[
        dataclasses.replace(m, holdout=0.0) for m in scene.materials],
        **({"material_camera": None} if case == "see" else {}))
    without = TS.render_integrator(plain, integrator, 1, rgba=True, passes=TS.EFFECT_PASSES)
    for name, ch in (("colour", RGB), ("alpha", ALPHA)):
        if name == "alpha" and integrator == "LIGHT":
            assert np.all(a1[..., ALPHA] == 1.0)      # light tracing's film is opaque
            continue
        err, noise = _compare(a1, a2, c1, c2, ch)
        ref = (c1[..., ch] + c2[..., ch]) / 2
        effect = np.abs(without[..., ch] - ref).mean() / ref.mean()
        print(f"{case} {integrator} {name}: mean {(a1[..., ch] + a2[..., ch]).mean() / 2:.4f} "
              f"vs Cycles {ref.mean():.4f}; |diff| {err:.4f}, noise {noise:.4f} "
              f"({err / noise:.2f}x); without the holdout {effect:.4f}")
        # The holdout shader's other closure keeps its weight: only the alpha moves.
        moved = name == "alpha" or case != "shader"
        TS._check(err, noise, effect if moved else None)


def test_exporter_reads_holdout_mixes_instances_and_collections():
    """A Holdout in a Mix Shader's first slot at Fac 0.3 gives 0.7, added to an Emission 1 (the ray
    ends: Cycles' isequal(weight, one)); an instance takes its instancer's
    holdout, not its source's; a collection's Holdout in the view layer
    holds out its objects."""
    bpy = pytest.importorskip("bpy")
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((8, 8), samples=1)
    TS.ortho_view(sc, 2.0)
    mats = []
    for name, kind in (("Mixed", 'ShaderNodeMixShader'), ("Added", 'ShaderNodeAddShader')):
        m, nt, out = K._new_material(name)
        mix = nt.nodes.new(kind)
        if kind == 'ShaderNodeMixShader':
            mix.inputs["Fac"].default_value = 0.3
        nt.links.new(nt.nodes.new('ShaderNodeHoldout').outputs[0], mix.inputs[-2])
        nt.links.new(nt.nodes.new('ShaderNodeEmission').outputs[0], mix.inputs[-1])
        nt.links.new(mix.outputs[0], out.inputs["Surface"])
        mats.append(m)
    K.plane("A", 0.4, mats[0], location=(-0.5, 0, 0))
    K.plane("B", 0.4, mats[1], location=(0.5, 0, 0))
    # A source plane (not a holdout) instanced by a holdout vertex cloud.
    src = K.plane("Src", 0.2, mats[0], location=(0, 0.6, 0))
    me = bpy.data.meshes.new("Pts")
    me.from_pydata([(0, -0.6, 0), (0.3, -0.6, 0)], [], [])
    pts = K.link(bpy.data.objects.new("Pts", me))
    pts.instance_type = 'VERTS'
    src.parent = pts
    pts.is_holdout = True
    coll = bpy.data.collections.new("Held")
    sc.collection.children.link(coll)
    c = K.plane("C", 0.4, mats[0], location=(-0.5, 0.6, 0))
    for u in list(c.users_collection):
        u.objects.unlink(c)
    coll.objects.link(c)
    bpy.context.view_layer.layer_collection.children["Held"].holdout = True
    scene, _ = TS._export()
    by_name = {m.name: m.holdout for m in scene.materials}
    assert by_name["Mixed"] == pytest.approx(0.7) and by_name["Added"] == 1.0
    # Triangles: 2 a plane; which are held out, by their centres' positions.
    ctr = scene.tri_p.mean(axis=1)
    held = scene.tri_holdout
    assert held is not None
    for x, y, z, want in ((-0.5, 0, 0, False), (0.5, 0, 0, False), (-0.5, 0.6, 0, True),
                          (0, 0, 0, True), (0.3, 0, 0, True)):
        near = np.linalg.norm(ctr - [x, y, z], axis=1) < 0.1
        assert near.sum() == 2 and held[near].all() == want and held[near].any() == want, (x, y)


@pytest.mark.parametrize("blocked", [False, True])
def test_compiled_camera_pass_equals_numpy_with_holdouts(blocked, monkeypatch):
    """The compiled camera pass (in blocks of 700 pixels, or one call) ends
    the same camera rays on holdouts and keeps the same transparency as the
    numpy reference, bit for bit: a Lambert object held out, a material
    half held out."""
    from core.render import Renderer
    from core.settings import RenderSettings
    from core.sppm import visible_points as VP
    from test_compiled_stages import SCENES
    if blocked:
        monkeypatch.setattr(VP, "CAMERA_BLOCK", 700)
    scene = SCENES["room"](40)
    T = scene.tri_p.shape[0]
    mats = list(scene.materials)
    m = int(np.bincount(scene.tri_mat).argmax())
    mats[m] = dataclasses.replace(mats[m], holdout=0.5)
    held = np.zeros(T, bool)
    held[scene.tri_mat != m] = np.arange(T)[scene.tri_mat != m] % 3 == 0
    scene = dataclasses.replace(scene, materials=mats, tri_holdout=held)
    r = Renderer(scene, RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=100,
                                       seed=1), log=lambda _m: None)
    cam = r.camera_pass
    cam.first_data = True
    out = []
    for compiled in (False, True):
        rng = np.random.default_rng(11)
        cam.compiled = compiled
        vp, L = cam(rng)
        out.append((vp, L.copy(), rng.random(4)))
    (vp_n, L_n, r_n), (vp_c, L_c, r_c) = out
    esc = vp_n.first.escape
    # Some pixels end on a holdout (transparency 1, no visible point), some
    # are half transparent with their visible point.
    assert np.sum(esc == 1) > 20
    assert np.sum((esc == 0.5) & vp_n.valid) > 20
    for f in ("valid", "p", "mat", "colors"):
        assert np.array_equal(getattr(vp_n, f), getattr(vp_c, f)), f
    for f in ("hit", "prim", "emit", "escape"):
        assert np.array_equal(getattr(vp_n.first, f), getattr(vp_c.first, f)), f
    assert np.array_equal(L_n, L_c) and np.array_equal(r_n, r_c)
