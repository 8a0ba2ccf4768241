"""IES light profiles (core/lights/ies.py, addon/export_light_nodes.py).

The reader against hand-made files (the candela conversion, a quadrant
mirrored to the circle, type A and B laid out as type C), the lookup at the
table's nodes and between them (Catmull-Rom), and the render of a point and
a soft spot light shaped by one asymmetric profile against Cycles, two seeds
a side, under tests/test_shading_nodes.py's bound (2x the seed-to-seed noise
plus 1 % of the mean), the profile moving the image by more than 3x that
bound.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.lights import ies as IES

RES = 40
CD_ONE = 177.83 / (4.0 * np.pi)       # candela that Cycles turns into a factor 1


def ies_text(v, h, cd, ptype=1, mult=1.0):
    """An LM-63 file of vertical angles v, horizontal h, candela cd (H, V)."""
    head = ["IESNA:LM-63-2002", "[TEST] FPPM", "TILT=NONE",
            f"1 1000 {mult} {len(v)} {len(h)} {ptype} 2 0 0 0",
            "1.0 1.0 100"]
    body = [" ".join(f"{a:g}" for a in v), " ".join(f"{a:g}" for a in h)]
    body += [" ".join(f"{c:.6g}" for c in row) for row in np.asarray(cd)]
    return "\r\n".join(head + body) + "\r\n"


def _local(v_deg, h_deg):
    """The light-local unit direction of IES angles (v from -Z, h: Cycles'
    atan2(x, y) + pi)."""
    v, h = np.radians(v_deg), np.radians(h_deg) - np.pi
    return np.array([np.sin(v) * np.sin(h), np.sin(v) * np.cos(h), -np.cos(v)])


def _factor(prof, w):
    return float(IES.factors(IES.pack([prof], np.eye(3)[None]), 0, np.atleast_2d(w))[0])


def test_reader_conversion_mirroring_and_nodes():
    """A quadrant (h 0-90) of type C is mirrored to 0-360; its nodes read
    back exactly (Catmull-Rom passes through them) times 4 pi / 177.83 and
    the multipliers; beyond the last vertical angle the factor is 0."""
    v = [0, 30, 60, 90]
    h = [0, 45, 90]
    cd = np.array([[100, 80, 50, 10], [120, 90, 40, 5], [150, 60, 30, 0]], float)
    prof = IES.parse_ies(ies_text(v, h, cd, mult=2.0))
    np.testing.assert_allclose(np.degrees(prof.h), [0, 45, 90, 135, 180, 225, 270, 315, 360])
    np.testing.assert_allclose(np.degrees(prof.v), v)
    k = 2.0 * 4.0 * np.pi / 177.83
    for hi, hd in enumerate(h):
        for vi, vd in enumerate(v[:-1]):
            if vd == 0:
                continue        # the pole: every h is one direction
            assert _factor(prof, _local(vd, hd)) == pytest.approx(k * cd[hi, vi], rel=1e-9)
            # the mirrored half: 360 - h
            assert _factor(prof, _local(vd, 360 - hd - 1e-9)) == pytest.approx(
                k * cd[hi, vi], rel=1e-6)
    assert _factor(prof, _local(120, 10)) == 0.0
    # Between nodes: Cycles' cubic along v at a node column.
    a, b, c, d = k * cd[1, :4]
    x = 0.5
    cm = 0.5 * (((d + 3 * (b - c) - a) * x + (2 * a - 5 * b + 4 * c - d)) * x + (c - a)) * x + b
    assert _factor(prof, _local(45, 45)) == pytest.approx(cm, rel=1e-9)


def test_types_a_b_and_the_constant_profile():
    """A constant CD_ONE profile is a factor 1 everywhere, its mean 1 over
    the sphere and over a spot's cone; a type A and a type B file land on
    Cycles' type C grid (vertical +90 / mirrored, horizontal 0-180)."""
    v = [0, 45, 90, 135, 180]
    h = [0, 90, 180, 270, 360]
    prof = IES.parse_ies(ies_text(v, h, np.full((5, 5), CD_ONE)))
    for w in (_local(10, 20), _local(100, 300), _local(170, 181)):
        assert _factor(prof, w) == pytest.approx(1.0, rel=1e-5)   # 6 digits in the file
    assert IES.mean_factor(prof) == pytest.approx(1.0, rel=1e-5)
    assert IES.mean_factor(prof, np.cos(0.6), 3.0) == pytest.approx(1.0, rel=1e-5)
    a = IES.parse_ies(ies_text([0, 45, 90], [0, 30, 60, 90], np.ones((4, 3)), ptype=3))
    np.testing.assert_allclose(np.degrees(a.v), [90, 135, 180])
    np.testing.assert_allclose(np.degrees(a.h), [90, 120, 150, 180, 210, 240, 270])
    b = IES.parse_ies(ies_text([-90, 0, 90], [0, 45, 90], np.ones((3, 3)), ptype=2))
    np.testing.assert_allclose(np.degrees(b.h), [0, 90, 180])
    np.testing.assert_allclose(np.degrees(b.v), [0, 45, 90, 135, 180])
    with pytest.raises(IES.IesError):
        IES.parse_ies("no tilt line here 1 2 3")


def asymmetric_profile():
    """An IES text: a beam 35 deg off the axis, brighter towards h = 0 than
    h = 180, dim above the horizon; 10 deg vertical and 30 deg horizontal
    steps over the full sphere."""
    v = np.arange(0, 181, 10.0)
    h = np.arange(0, 361, 30.0)
    V, H = np.meshgrid(np.radians(v), np.radians(h))
    cd = 300.0 * (0.25 + np.exp(-((V - np.radians(35)) / 0.3) ** 2)) \
        * (1.0 + 0.8 * np.cos(H)) * np.where(V < np.pi / 2, 1.0, 0.15)
    return ies_text(v, h, cd)


def _scene():
    """tests/test_shading_nodes.py's grey floor seen from above, a point
    light of radius 0 and a soft spot (radius 0.15 m) both shaped by
    :func:`asymmetric_profile` (the point light turned and tilted, so the
    profile's frame is the object's), the IES text in a Text datablock."""
    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16)
    TS.grey_floor()
    TS.ortho_view(sc, 2.4, sun_energy=0.0)
    K.set_world(sc, (0.0, 0.0, 0.0))
    text = bpy.data.texts.new("profile.ies")
    text.write(asymmetric_profile())
    for name, kind, loc, rot, energy in (
            ("Point", 'POINT', (-0.3, 0.2, 0.9), (0.35, -0.2, 0.9), 8.0),
            ("Spot", 'SPOT', (0.5, -0.4, 1.1), (0.3, 0.25, -0.6), 10.0)):
        ld = bpy.data.lights.new(name, kind)
        ld.energy = energy
        ld.shadow_soft_size = 0.0 if kind == 'POINT' else 0.15
        if kind == 'SPOT':
            ld.spot_size, ld.spot_blend = np.radians(110.0), 0.3
        nodes, links = ld.node_tree.nodes, ld.node_tree.links
        em = next(n for n in nodes if n.type == 'EMISSION')
        em.inputs["Strength"].default_value = 1.0
        ies = nodes.new('ShaderNodeTexIES')
        ies.mode = 'INTERNAL'
        ies.ies = text
        links.new(ies.outputs[0], em.inputs["Strength"])
        ob = K.link(bpy.data.objects.new(name, ld))
        ob.location, ob.rotation_euler = loc, rot
    return sc


def _unshaped(scene):
    return dataclasses.replace(
        scene, lights=[dataclasses.replace(lt, ies=None) for lt in scene.lights])


@pytest.mark.parametrize("integrator", ["PATH", "PHOTON"])
def test_ies_lights_agree_with_cycles(integrator, tmp_path):
    """Measured: see docs/cycles_units.md "A light's nodes"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = _scene()
    scene, lines = TS._export()
    assert [lt.ies is not None for lt in scene.lights] == [True, True]
    assert not any("light" in ln and "ignored" in ln for ln in lines), lines
    TS.agrees_with_cycles(sc, scene, integrator, tmp_path, _unshaped(scene), "ies",
                          key=("ies",), passes=8)


def test_light_tree_constants_and_an_unreadable_file():
    """The Emission's Color x Strength multiplies a light's strength; an IES
    file that is missing or not IES leaves the light unshaped with a note
    naming it (docs/reliability.md); a profile on a sun is left out."""
    pytest.importorskip("bpy")
    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    K.reset_scene((8, 8), samples=1)
    TS.ortho_view(bpy.context.scene, 2.0, sun_energy=0.0)
    K.plane("Floor", 2.0, K._new_material("Floor")[0])
    bad = bpy.data.texts.new("bad.ies")
    bad.write("IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 3 1 1 2 0 0 0\n")
    for name, kind, src in (("Tinted", 'POINT', None), ("Missing", 'POINT', "/nonexistent/x.ies"),
                            ("Broken", 'SPOT', bad), ("Sunny", 'SUN', bad)):
        ld = bpy.data.lights.new(name, kind)
        ld.energy = 10.0
        em = next(n for n in ld.node_tree.nodes if n.type == 'EMISSION')
        if src is None:
            em.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
            em.inputs["Strength"].default_value = 2.0
        else:
            ies = ld.node_tree.nodes.new('ShaderNodeTexIES')
            if isinstance(src, str):
                ies.mode, ies.filepath = 'EXTERNAL', src
            else:
                ies.mode, ies.ies = 'INTERNAL', src
            ld.node_tree.links.new(ies.outputs[0], em.inputs["Strength"])
        K.link(bpy.data.objects.new(name, ld))
    scene, lines = TS._export()
    by = {lt.name: lt for lt in scene.lights}
    np.testing.assert_allclose(by["Tinted"].strength, [20.0, 10.0, 5.0])
    assert all(by[n].ies is None for n in by)
    said = "\n".join(lines)
    assert "light 'Missing': IES profile not read (/nonexistent/x.ies" in said
    assert "light 'Broken': IES profile Text 'bad.ies' not read (fewer numbers" in said
    assert "light 'Sunny': an IES profile on a sun light ignored" in said
