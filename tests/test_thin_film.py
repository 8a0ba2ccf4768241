"""Thin-film iridescence (core.materials.thin_film, thin_film_kernels) against
physics and Cycles.

The film's reflectance is Cycles' Airy sum in Fourier space (Belcour &
Barla 2017): checked here against the direct spectral integral of the exact
thin-film reflectance |r|^2, r = (r12 + r23 e^{i delta})/(1 + r12 r23
e^{i delta}) per polarisation, weighted by the CIE 1931 matching functions
in linear Rec.709, over a dielectric and over a conductor (gold).  Then
the renders: tests/test_metallic_bsdf.py's sphere with a film on a
Principled BSDF (its specular layer over a dark diffuse, and its metal)
and on a Metallic BSDF, FPPM against Cycles, two seeds a side under
tests/test_shading_nodes.py's bound, and the same scene without the film
moved by more than 3x that bound, all over the sphere's pixels.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.materials import thin_film as TF
from core.materials.thin_film_kernels import iridescence_rgb


def _spectral(c1, d, nf, n3):
    """The exact film reflectance integrated over the spectrum: (3,) RGB."""
    lam5 = 360.0 + 5.0 * np.arange(TF.CIE_1931_2DEG.shape[0])
    lam = np.arange(360.0, 830.0, 0.1)
    rgb = TF.XYZ_TO_REC709 @ np.stack([np.interp(lam, lam5, TF.CIE_1931_2DEG[:, c])
                                       for c in range(3)])
    s1 = np.sqrt(1.0 - c1 * c1)
    c2 = np.sqrt(1.0 - (s1 / nf) ** 2 + 0j)
    c3 = np.sqrt(1.0 - (s1 / complex(n3)) ** 2 + 0j)
    e = np.exp(4j * np.pi * nf * d * c2 / lam)
    R = 0.0
    for r in (lambda na, ca, nb, cb: (na * ca - nb * cb) / (na * ca + nb * cb),    # s
              lambda na, ca, nb, cb: (nb * ca - na * cb) / (nb * ca + na * cb)):   # p
        r12, r23 = r(1.0, c1, nf, c2), r(nf, c2, complex(n3), c3)
        R = R + 0.5 * np.abs((r12 + r23 * e) / (1.0 + r12 * r23 * e)) ** 2
    return (rgb @ R) / rgb.sum(axis=1)


def test_sensitivity_is_normalised():
    """S_c(0) = 1 in every channel (real), and it decays over the table
    (|S| < 0.05 over its last 50 nodes, past 8.6 um)."""
    S = TF.sensitivity_table().reshape(2, 3, TF.TABLE_SIZE)
    np.testing.assert_allclose(S[0, :, 0], 1.0, rtol=1e-12)
    np.testing.assert_allclose(S[1, :, 0], 0.0, atol=1e-12)
    mag = np.hypot(S[0], S[1])
    assert np.all(mag[:, -50:] < 0.05)


@pytest.mark.parametrize("c1,d,nf,n3", [(1.0, 300.0, 1.33, 1.5), (0.6, 500.0, 1.8, 1.5),
                                        (0.9, 800.0, 2.0, 1.2), (0.45, 150.0, 1.45, 2.4)])
def test_film_over_a_dielectric_is_the_spectral_integral(c1, d, nf, n3):
    """Within 0.002 of the exact spectral integral (the Airy sum's
    truncation after three round trips and the table's interpolation)."""
    got = iridescence_rgb(np.array([c1]), d, nf, np.full((1, 3), n3))[0]
    np.testing.assert_allclose(got, _spectral(c1, d, nf, n3), atol=2e-3)


@pytest.mark.parametrize("c1,d,tol", [(1.0, 300.0, 2e-3), (0.5, 400.0, 2e-3), (0.2, 250.0, 6e-3)])
def test_film_over_gold_is_the_spectral_integral(c1, d, tol):
    """Over a conductor (gold's n + ik per channel), within 0.002; 0.006 at
    cos 0.2 (measured 0.0047: the sum stops after three round trips, and
    R12 R23 is largest there)."""
    n = np.array([0.18, 0.42, 1.37])
    k = np.array([3.42, 2.35, 1.77])
    got = iridescence_rgb(np.array([c1]), d, 1.5, n[None], k[None])[0]
    want = [_spectral(c1, d, 1.5, complex(n[c], k[c]))[c] for c in range(3)]
    np.testing.assert_allclose(got, want, atol=tol)


def test_no_film_below_a_nanometre_tends_to_the_bare_fresnel():
    """A film thinner than 1 nm blends its IOR towards the ambient one: at
    d -> 0 the reflectance is the bare interface's Fresnel."""
    from core.materials.microfacet import fresnel_dielectric
    c = np.array([0.3, 0.8])
    got = iridescence_rgb(c, 1e-6, 1.6, np.full((2, 3), 1.5))
    np.testing.assert_allclose(got, np.repeat(fresnel_dielectric(c, np.full(2, 1.5))[0][:, None],
                                              3, 1), rtol=1e-5)


def _principled(nodes):
    """A Principled BSDF with a 300 nm film (IOR 2.2) over a dark rough
    dielectric (its specular layer over the diffuse), a little metallic."""
    p = nodes.new('ShaderNodeBsdfPrincipled')
    p.inputs["Base Color"].default_value = (0.05, 0.05, 0.06, 1.0)
    p.inputs["Roughness"].default_value = 0.25
    p.inputs["Metallic"].default_value = 0.3
    p.inputs["Thin Film Thickness"].default_value = 300.0
    p.inputs["Thin Film IOR"].default_value = 2.2
    return p


def _metallic(nodes):
    """tests/test_metallic_bsdf.py's F82 Metallic BSDF under a 280 nm film (IOR 2.2)."""
    import test_metallic_bsdf as TM
    m = TM.metallic_node(nodes, 'F82', 0.25)
    m.inputs["Thin Film Thickness"].default_value = 280.0
    m.inputs["Thin Film IOR"].default_value = 2.2
    return m


def _filmless(scene):
    mats = [dataclasses.replace(m, lobes=tuple(dataclasses.replace(lb, thin_film_thickness=0.0)
                                               for lb in m.lobes)) for m in scene.materials]
    return dataclasses.replace(scene, materials=mats)


@pytest.mark.parametrize("shader", ["principled", "metallic"])
def test_thin_film_agrees_with_cycles(shader, tmp_path):
    """Path Tracing (the sphere's glossy pixels are too noisy under Photon
    Mapping for the bound to resolve the film; the photons' samples and the
    gather's evaluation are the compiled BSDF these paths use, checked
    against numpy by tests/test_compiled_bsdf.py and test_compiled_sample.py).
    Measured: see docs/shading.md "Thin-film iridescence"."""
    integrator = "PATH"
    pytest.importorskip("bpy")
    import test_metallic_bsdf as TM
    import test_shading_nodes as TS
    sc = TM.sphere_scene(_principled if shader == "principled" else _metallic)
    scene, lines = TS._export()
    assert lines[1] == "Approximated: nothing.", lines[1]
    metal = next(m for m in scene.materials if m.name == "Metal")
    assert sum(lb.thin_film_thickness > 0 for lb in metal.lobes) == (3 if shader == "principled"
                                                                     else 1)
    # The means over the sphere (radius 15 pixels; 14 leaves out its rim).
    y, x = np.mgrid[0:TM.RES, 0:TM.RES] + 0.5 - TM.RES / 2
    TS.agrees_with_cycles(sc, scene, integrator, tmp_path, _filmless(scene),
                          f"thin film {shader}", key=("thin film", shader),
                          passes=8, mask=np.hypot(x, y) < 14)
