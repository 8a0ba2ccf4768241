"""The Metallic BSDF node (Blender 4.3 and later) against Cycles.

Cycles renders it as one GGX closure with a conductor's Fresnel
(``svm_node_closure_bsdf``): 'F82' the F82-tint model of the Principled
BSDF's metal (F0 = Base Color, tint Edge Tint), 'PHYSICAL_CONDUCTOR' the
exact Fresnel of a complex IOR n + ik per channel (``fresnel_conductor``),
with Multiscatter GGX's energy compensation from the F82 fit of that
Fresnel (``fresnel_conductor_Fss``).  FPPM maps it to a GLOSSY lobe of
``fresnel='F82'`` or ``'CONDUCTOR'`` (core.materials.microfacet).  Before,
the node was an unsupported node: a grey diffuse.

The scene: a metal sphere over tests/test_shading_nodes.py's grey floor,
seen from above under a tilted sun and a blue-grey world, so the sphere
shows the Fresnel from normal incidence to grazing.  Two seeds a side
under that file's bound (2x the seed-to-seed noise + 1 % of the mean),
and the grey diffuse of before moves the image by more than 3x the bound.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.materials.microfacet import (F82_COS, conductor_fresnel, conductor_fss, f82_b,
                                       f82_fss, fresnel_dielectric)

RES = 40

#: Gold's complex IOR at (R, G, B) ~ (650, 550, 450) nm.
GOLD_N, GOLD_K = (0.18, 0.42, 1.37), (3.42, 2.35, 1.77)


def test_conductor_fresnel_closed_forms():
    """At normal incidence ((n-1)^2 + k^2)/((n+1)^2 + k^2); with k = 0 the
    dielectric Fresnel; 1 at grazing; F_ss is the F82 fit's 2 ∫ F mu dmu of
    the model through F(0) and F(~82 degrees), within 2.5 % of the exact
    integral for gold (2.2 % in blue: Cycles' own approximation)."""
    n, k = np.array(GOLD_N), np.array(GOLD_K)
    np.testing.assert_allclose(conductor_fresnel(np.array(1.0), n, k),
                               ((n - 1) ** 2 + k ** 2) / ((n + 1) ** 2 + k ** 2), rtol=1e-12)
    c = np.array([0.05, 0.3, 0.7, 1.0])
    np.testing.assert_allclose(conductor_fresnel(c, np.full((4, 3), 1.5), np.zeros((4, 3)))[:, 0],
                               fresnel_dielectric(c, np.full(4, 1.5))[0], rtol=1e-12)
    np.testing.assert_allclose(conductor_fresnel(np.array(0.0), n, k), 1.0, rtol=1e-12)
    F0, F82 = conductor_fresnel(np.array(1.0), n, k), conductor_fresnel(np.array(F82_COS), n, k)
    np.testing.assert_allclose(conductor_fss(n, k), f82_fss(F0, f82_b(F0, F82)), rtol=1e-12)
    mu = np.linspace(0.0, 1.0, 20001)
    F = conductor_fresnel(mu, np.broadcast_to(n, (mu.size, 3)), np.broadcast_to(k, (mu.size, 3)))
    exact = np.trapezoid(2.0 * F * mu[:, None], mu, axis=0)
    np.testing.assert_allclose(conductor_fss(n, k), exact, rtol=0.025)


def sphere_scene(shader):
    """A sphere of material "Metal" over the grey floor, seen from above
    under a tilted sun and a blue-grey world; shader(nodes) returns the
    node whose first output is the sphere's Surface (tests/test_thin_film.py)."""
    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    sc = K.reset_scene((RES, RES), samples=16)
    TS.grey_floor()
    TS.ortho_view(sc, 1.6, sun_energy=3.0, sun_rotation=(0.6, 0.3, 0.0))
    K.set_world(sc, (0.35, 0.45, 0.6))
    metal, nt, out = K._new_material("Metal")
    nt.links.new(shader(nt.nodes).outputs[0], out.inputs["Surface"])
    TS.uv_sphere_object("Ball", metal, radius=0.6)
    bpy.data.objects["Ball"].location = (0.0, 0.0, 0.65)
    return sc


def metallic_node(nodes, mode, roughness):
    """A Metallic BSDF: F82 a copper-like F0 with a green edge tint,
    PHYSICAL_CONDUCTOR gold's n and k."""
    m = nodes.new('ShaderNodeBsdfMetallic')
    m.fresnel_type = mode
    m.inputs["Roughness"].default_value = roughness
    if mode == 'F82':
        m.inputs["Base Color"].default_value = (0.95, 0.64, 0.54, 1.0)
        m.inputs["Edge Tint"].default_value = (0.6, 0.9, 0.5, 1.0)
    else:
        m.inputs["IOR"].default_value = GOLD_N
        m.inputs["Extinction"].default_value = GOLD_K
    return m


def _scene(mode, roughness):
    """The sphere of a Metallic BSDF (``mode``, ``roughness``) over the floor."""
    return sphere_scene(lambda nodes: metallic_node(nodes, mode, roughness))


def _grey(scene):
    """The scene as FPPM rendered it before: the Metallic BSDF a grey diffuse."""
    from core.scene.model import DIFFUSE, Lobe
    mats = [dataclasses.replace(m, lobes=(Lobe(DIFFUSE, (0.8, 0.8, 0.8)),))
            if m.name == "Metal" else m for m in scene.materials]
    return dataclasses.replace(scene, materials=mats)


@pytest.mark.parametrize("mode,roughness,integrator", [
    ("F82", 0.3, "PATH"), ("PHYSICAL_CONDUCTOR", 0.3, "PATH"),
    ("PHYSICAL_CONDUCTOR", 0.3, "PHOTON"), ("PHYSICAL_CONDUCTOR", 0.0, "PATH")])
def test_metallic_bsdf_agrees_with_cycles(mode, roughness, integrator, tmp_path):
    """Measured: see docs/shading.md "The Metallic BSDF"."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = _scene(mode, roughness)
    scene, lines = TS._export()
    assert lines[1] == "Approximated: nothing.", lines[1]
    (lobe,) = next(m for m in scene.materials if m.name == "Metal").lobes
    assert lobe.fresnel == ("F82" if mode == "F82" else "CONDUCTOR")
    TS.agrees_with_cycles(sc, scene, integrator, tmp_path, _grey(scene),
                          f"metallic {mode} {roughness}", key=("metallic", mode, roughness),
                          passes=32 if integrator == "PHOTON" else 8)
