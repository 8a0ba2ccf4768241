"""Object ray visibility (Object > Visibility > Ray Visibility): camera,
shadow, and glossy for a mirror's rays, against Cycles.

An object hidden from the camera is passed by camera rays (also after
transparent crossings) and by light tracing's joins to the lens, and still
casts shadows and reflects light; an object with Shadow off is passed by
shadow rays (next-event estimation) and by the first segment of photons
and light paths, which also land on it (a second set), and is still seen
and still bounces light (``core.accel.Accel.for_rays``,
``core.sppm.photons.PhotonTracer._trace_hidden_first``).  Each case renders a floor under a
floating box (or a hidden emitting square) in FPPM's integrators and in
Cycles, two seeds a side, under tests/test_shading_nodes.py's bound (2x
the seed-to-seed noise plus 1 % of the mean), and checks that the flag
moves the image by more than 3x that bound (the same export rendered with
every object fully visible).  Then the Accel's own rule on two triangles.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.accel import (RAY_ALL, RAY_CAMERA, RAY_SHADOW, Accel, cast_by_kind,
                        intersect_by_kind)

RES = 40


def test_rays_see_the_objects_that_share_a_flag_with_them():
    """Two stacked triangles, the nearer hidden from the camera: camera rays
    hit the farther one, shadow rays and the rest the nearer; hits are the
    base scene's triangle indices, rays mixed in one call are split, every
    ray counts in the base's rays_cast, and the view is built once."""
    tri = np.array([[[0, 0, 1], [1, 0, 1], [0, 1, 1]],
                    [[0, 0, 2], [1, 0, 2], [0, 1, 2]]], np.float32)
    a = Accel(tri, 3.0, np.array([RAY_ALL & ~RAY_CAMERA, RAY_ALL], np.uint8))
    o, d = np.tile([0.2, 0.2, 0.0], (3, 1)), np.tile([0.0, 0.0, 1.0], (3, 1))
    assert list(a.intersect(o, d).prim) == [0, 0, 0]
    cam = a.for_rays(RAY_CAMERA)
    assert cam is a.for_rays(RAY_CAMERA) and list(cam.intersect(o, d).prim) == [1, 1, 1]
    assert a.for_rays(RAY_SHADOW) is a and a.for_rays(RAY_CAMERA | RAY_SHADOW) is a
    h = intersect_by_kind(a, RAY_CAMERA, np.array([True, False, True]), o, d, None)
    assert list(h.prim) == [1, 0, 1] and np.allclose(h.t, [2, 1, 2])
    assert a.rays_cast == 9
    assert not cam.occluded(o, d, np.full(3, 1.5)).any() and a.occluded(o, d, 1.5).all()
    assert list(a.hidden_from(RAY_CAMERA)) == [True, False] and a.hidden_from(RAY_SHADOW) is None
    # Without hidden objects one scene serves every kind (the renderer's plain path).
    b = Accel(tri, 3.0, np.full(2, RAY_ALL, np.uint8))
    assert b.visibility is None and b.for_rays(RAY_CAMERA) is b
    calls = []
    cast_by_kind(lambda acc, *x: calls.append(acc) or (np.zeros(3),), b, RAY_CAMERA,
                 np.array([True, False, True]), o, d, np.full(3, np.inf))
    assert calls == [b]


def _scene(case):
    """A 2.4 m grey floor seen from above (orthographic), a red box floating
    over it; "camera": the box hidden from the camera, under a tilted sun
    ("camera_veil": seen through a Transparent BSDF);
    "shadow": the box's Shadow off, same sun; "emitter": no sun, an emitting
    square over the box hidden from the camera lights the scene
    ("emitter_shadowless": and the box's Shadow is off); "world": a blue
    world hidden from the camera lights the scene, seen past the floor;
    "glossy": the floor a mirror at 0.7 over its Diffuse under a bright
    world hidden from the camera, seen from the side, the box hidden from
    glossy rays (absent from the mirror, still seen and still shadowing)."""
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16,
                       world_color=(0.5, 0.6, 0.8) if case == "glossy" else (0.0, 0.0, 0.0))
    box = TS.floor_and_box()[0]
    if case == "glossy":
        import math

        import bpy_helpers as H
        import test_world_visibility as WV
        WV.mirror_floor()
        box.visible_glossy = False
        H.add_camera(sc, location=(0.0, -2.0, 0.9), rotation=(math.radians(70), 0.0, 0.0))
        sc.world.cycles_visibility.camera = False      # (the sky: black behind the floor)
        return sc
    TS.ortho_view(sc, 3.2 if case == "world" else 2.2,
                  sun_energy=0.0 if case.startswith("emitter") or case == "world" else 3.0)
    if case == "world":
        w = K.set_world(sc, (0.4, 0.5, 0.6))
        w.cycles_visibility.camera = False
    elif case.startswith("emitter"):
        box.visible_shadow = case != "emitter_shadowless"
        TS.lamp_over_box().visible_camera = False
    else:
        box.visible_camera = not case.startswith("camera")
        box.visible_shadow = case != "shadow"
        if case == "camera_veil":
            # A Transparent BSDF veil over the scene: camera rays crossing it
            # are still camera rays (Cycles keeps the flag) and pass the box.
            TS.veil_over_box()
    return sc


def _render(scene, integrator, seed):
    import test_shading_nodes as TS
    return TS.render_integrator(scene, integrator, seed)


#: (case, integrator).  Path Tracing's camera rays are checked through the
#: veil (the camera flag kept), its shadow rays by Combined's camera paths
#: under the shadowless emitter; the world's camera map by Photon Mapping.
CASES = [("camera", "PHOTON"), ("camera", "LIGHT"),
         ("camera_veil", "PHOTON"), ("camera_veil", "PATH"),
         ("shadow", "PHOTON"),
         ("emitter", "PHOTON"), ("emitter", "COMBINED"),
         ("emitter_shadowless", "PHOTON"), ("emitter_shadowless", "COMBINED"),
         ("emitter_shadowless", "LIGHT"), ("world", "PHOTON"),
         ("glossy", "PHOTON"), ("glossy", "PATH")]


@pytest.mark.parametrize("case,integrator", CASES, ids=[f"{c}-{i}" for c, i in CASES])
def test_camera_and_shadow_visibility_agree_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Object ray visibility"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = _scene(case)
    scene, lines = TS._export()
    assert (scene.tri_visibility is not None) == (case != "world")
    # (Glossy off: photons still see the box, which the log says.)
    assert any("ray visibility" in ln for ln in lines) == (case == "glossy"), lines
    err, noise, img, ref = TS.two_seeds(sc, scene, lambda s, seed: _render(s, integrator, seed),
                                        tmp_path, 256, key=(__name__, case))
    mean = ref.mean()
    seen = TS.render_integrator(dataclasses.replace(scene, tri_visibility=None,
                                                    world_camera_map=None),
                                integrator, 1, passes=TS.EFFECT_PASSES)
    effect = np.abs(seen - ref).mean() / mean
    print(f"{case} {integrator}: mean {img.mean():.4f} vs Cycles {mean:.4f}; |diff| "
          f"{err:.4f}, noise {noise:.4f} ({err / noise:.2f}x); fully visible {effect:.4f}")
    TS._check(err, noise, effect)

