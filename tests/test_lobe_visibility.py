"""Emitters hidden from diffuse, glossy or transmission rays, against Cycles.

A light (or an emissive object) with a kind of ray visibility off is not
seen by BSDF rays of that kind, and its light samples leave the lobes of
that kind out (``core.lights.lobe_visibility``; Cycles'
``_surface_shader_exclude``): Glossy off removes its highlights, Diffuse
off makes a specular-only light.  Each case renders a Principled floor (a
diffuse and a glossy lobe) in FPPM's integrators and in Cycles, two seeds a
side, under tests/test_shading_nodes.py's bound (2x the seed-to-seed noise
plus 1 % of the mean), and checks that the visibility moves the image by
more than 3x that bound (the same export with every emitter seen).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

RES = 40


def test_masked_colors_and_first_hits():
    """A light hidden from glossy rays leaves the glossy slots out, a glass
    slot only when transmission is hidden too; a photon whose first hit has
    only hidden lobes ends there."""
    from core.lights import lobe_visibility as LV
    from core.scene.model import DIFFUSE, GLASS, GLOSSY
    mtab = type("T", (), {})()
    mtab.kind = np.array([[DIFFUSE, GLOSSY, -1], [GLASS, -1, -1], [DIFFUSE, -1, -1]])
    hidden = np.array([0, LV.GLOSSY_RAYS, LV.GLOSSY_RAYS | LV.TRANSMISSION_RAYS,
                       LV.DIFFUSE_RAYS], np.uint8)
    cols = np.ones((4, 3, 3))
    r, c = LV.masked_colors(mtab, hidden, np.array([1, 2, 1, 0]), np.array([0, 1, 1, 0]), cols)
    assert list(r) == [0, 1, 2]
    assert c[0, :, 0].tolist() == [1, 0, 1] and c[1, 0, 0] == 0 and c[2, 0, 0] == 1
    prim = np.array([0, 1, 2, 0, -1])
    LV.unseen_first_hits(prim, np.array([3, 3, 1, 1, 3]), hidden,
                         np.array([0, 2, 1]), mtab)
    assert prim.tolist() == [0, -1, 2, 0, -1]


def _scene(case):
    """A 2.4 m Principled floor (roughness 0.3) seen from above; "glossy":
    a 0.5 m area light hidden from glossy rays and a sun; "diffuse": a
    small point light hidden from diffuse rays (a specular-only light) and
    a sun; "emitter": an emitting card hidden from glossy rays over the
    floor made partly metallic, and a sun."""
    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16)
    mat, nt, out = K._new_material("Floor")
    p = nt.nodes.new('ShaderNodeBsdfPrincipled')
    p.inputs["Roughness"].default_value = 0.3
    p.inputs["Base Color"].default_value = (0.2, 0.3, 0.6, 1.0)
    if case == "emitter":
        p.inputs["Metallic"].default_value = 0.7        # the card's reflection matters
    nt.links.new(p.outputs[0], out.inputs["Surface"])
    K.plane("Floor", 2.4, mat)
    TS.ortho_view(sc, 2.2, sun_energy=0.6)
    K.set_world(sc, (0.02, 0.02, 0.02))
    if case == "emitter":
        card = TS.lamp_over_box()
        card.location = (0.0, 0.0, 1.2)
        card.visible_glossy = False
        return sc
    kind, size = ("AREA", 0.5) if case == "glossy" else ("POINT", 0.05)
    ld = bpy.data.lights.new("Key", kind)
    ld.energy = 100.0
    if kind == "AREA":
        ld.size = size
    else:
        ld.shadow_soft_size = size
    key = K.link(bpy.data.objects.new("Key", ld))
    key.location = (0.1, -0.1, 1.5)
    if case == "glossy":
        key.visible_glossy = False
    else:
        key.visible_diffuse = False
    return sc


def _seen(scene):
    """The scene with every emitter seen by every kind of ray."""
    return dataclasses.replace(scene, tri_visibility=None, lights=[
        dataclasses.replace(lt, visible_diffuse=True, visible_glossy=True,
                            visible_transmission=True) for lt in scene.lights])


#: (case, integrator).  Combined takes such an emitter's light by its camera
#: paths alone: Path Tracing's image.
CASES = [("glossy", "PHOTON"), ("glossy", "PATH"), ("diffuse", "PHOTON"), ("diffuse", "PATH"),
         ("emitter", "PATH")]


@pytest.mark.parametrize("case,integrator", CASES, ids=[f"{c}-{i}" for c, i in CASES])
def test_hidden_lobes_agree_with_cycles(case, integrator, tmp_path):
    """Measured: see docs/shading.md "Emitters hidden from some kinds of ray"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    from core.lights import build_light_table
    sc = _scene(case)
    scene, lines = TS._export()
    assert build_light_table(scene).hidden is not None
    TS.agrees_with_cycles(sc, scene, integrator, tmp_path, _seen(scene), case,
                          key=(__name__, case))
