"""The world hidden from some kinds of ray (World > Settings > Ray
Visibility: Diffuse, Glossy, Transmission) against Cycles.

Cycles gives its background light the closure exclusion of lights hidden
from those rays (scene/light.cpp ``BackgroundLight::copy_to_kernel``): its
light samples leave the hidden lobes out, a BSDF ray of a hidden kind does
not see it.  FPPM reads the flags into ``Scene.world_hidden`` and treats
the world's emitter row as any hidden emitter (core/lights/
lobe_visibility.py); a mirror's or glass's ray that escapes sees it by its
Glossy and Transmission flags (``lights.world_seen_by``).

The scene is tests/test_holdout.py's (a red box over a grey floor, from
above) under a sun and a bright world: a constant sky, or a two-colour
HDRI (its map's light samples are then the world's light alone, the map
MIS left out).  The floor is a Mix Shader of its Diffuse and a sharp
Glossy at 0.7 (a mirror: the world seen through a delta chain), the box a
Principled BSDF of roughness 0.3 (a rough glossy layer).  Two seeds a side
under tests/test_shading_nodes.py's bound, and the flag moves the image by
more than 3x that bound (the same export with the world seen by all).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

RES = 40


def mirror_floor():
    """tests/test_shading_nodes.py's floor_and_box floor made its Diffuse
    mixed with a mirror (a Glossy BSDF of roughness 0) at 0.7
    (tests/test_ray_visibility.py too)."""
    import bpy
    fl = bpy.data.materials["Floor"].node_tree
    fo = next(n for n in fl.nodes if n.type == 'OUTPUT_MATERIAL')
    fd = next(n for n in fl.nodes if n.type == 'BSDF_DIFFUSE')
    g = fl.nodes.new('ShaderNodeBsdfGlossy')
    g.inputs["Roughness"].default_value = 0.0
    mix = fl.nodes.new('ShaderNodeMixShader')
    mix.inputs["Fac"].default_value = 0.7
    fl.links.new(fd.outputs[0], mix.inputs[1])
    fl.links.new(g.outputs[0], mix.inputs[2])
    fl.links.new(mix.outputs[0], fo.inputs["Surface"])


def _scene(case):

    import test_environment as TE
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16, world_color=(0.5, 0.6, 0.8))
    box, nt, d, out = TS.floor_and_box()
    # The box: a Principled BSDF (a rough glossy layer over its colour).
    p = nt.nodes.new('ShaderNodeBsdfPrincipled')
    p.inputs["Base Color"].default_value = (0.8, 0.15, 0.1, 1.0)
    p.inputs["Roughness"].default_value = 0.3
    nt.links.new(p.outputs[0], out.inputs["Surface"])
    mirror_floor()
    if case.startswith("hdri"):
        img = np.zeros((16, 32, 4), np.float32)
        img[..., :3] = (0.3, 0.35, 0.4)          # the lower half
        img[8:, :, :3] = (0.9, 1.0, 1.3)         # the sky
        img[..., 3] = 1.0
        TE.hdri_world(sc, img)
    TS.ortho_view(sc, 2.2, sun_energy=2.0, sun_rotation=(0.5, 0.3, 0.0))
    flag = {"diffuse": "diffuse", "glossy": "glossy", "hdri_glossy": "glossy",
            "hdri_diffuse": "diffuse"}[case]
    setattr(sc.world.cycles_visibility, flag, False)
    return sc


#: (case, integrator).  Photon Mapping's world photons, the map's light
#: samples alone and its camera chains' escapes; Path Tracing's light
#: samples and delta escapes.  (Photon Mapping's Diffuse case with the sky,
#: the HDRI's Glossy case, and Path Tracing's HDRI Diffuse case were
#: measured once and left out for time: docs/shading.md "The world".)
CASES = [("diffuse", "PATH"), ("glossy", "PHOTON"), ("glossy", "PATH"),
         ("hdri_diffuse", "PHOTON")]


@pytest.mark.parametrize("case,integrator", CASES, ids=[f"{c}-{i}" for c, i in CASES])
def test_world_visibility_agrees_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Emitters hidden from some kinds of ray"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = _scene(case)
    scene, _ = TS._export()
    assert scene.world_hidden != 0
    # Photon Mapping 4x the passes: its one camera ray a pixel and pass picks
    # the floor's mirror or its Diffuse at random, which left a noise of 18 %
    # of the mean in 12 passes (the camera paths take 8 a pass).
    TS.agrees_with_cycles(sc, scene, integrator, tmp_path,
                          dataclasses.replace(scene, world_hidden=0), case, key=(__name__, case),
                          passes=48 if integrator == "PHOTON" else 12)
