"""The compiled BSDF (core.materials.compiled) equals the numpy one (the oracle:
core.materials.eval_bsdf, radiance mode) pair for pair, to float rounding.

Random pairs over every lobe kind and option of the material table (Lambert,
Oren-Nayar, translucent, GGX glossy / glass / refraction with and without
Multiscatter GGX, iors above and below 1, the Principled BSDF's dielectric and
F82 layers and the diffuse under its specular layer, the Metallic BSDF's
physical conductor, thin films over them, delta lobes that must be
skipped), views on both sides of the geometric normal, grazing views and
lights, and the same materials with a Normal Map / Bump (normal tilt and
bump shadowing).  Inputs in float32 as the visible points keep them.
Tolerance: |compiled - numpy| <= 1e-12 |numpy| + 1e-14 (both are float64
with the same operation order; the measured worst is a few ulps, from
libm's pow/acos against numpy's).
"""
import dataclasses

import numpy as np
import pytest

from core import materials as B
from core.frequency.kernels import Receivers
from core.materials import compiled as C
from core.scene.model import (DIFFUSE, GLASS, GLOSSY, REFRACTION, TRANSLUCENT, TRANSPARENT,
                              Lobe, Material)
from core.scene.nodes import principled_to_lobes

RTOL, ATOL = 1e-12, 1e-14


def _materials():
    ms = dict(multiscatter=True)
    P = lambda **kw: tuple(principled_to_lobes(**kw)[0])  # noqa: E731
    return [
        (Lobe(DIFFUSE, (0.8, 0.6, 0.4)),),
        (Lobe(DIFFUSE, (0.7, 0.5, 0.9), roughness=0.6, weight=0.8),),
        (Lobe(TRANSLUCENT, (0.5, 0.6, 0.7)), Lobe(DIFFUSE, (0.2, 0.3, 0.1), roughness=1.0)),
        (Lobe(GLOSSY, (0.9, 0.8, 0.7), roughness=0.3),),
        (Lobe(GLOSSY, (0.9, 0.9, 0.6), roughness=0.7, weight=0.6, **ms),
         Lobe(DIFFUSE, (0.5, 0.5, 0.5), weight=0.4)),
        (Lobe(GLASS, (1.0, 0.95, 0.9), roughness=0.4, ior=1.5, **ms),),
        (Lobe(GLASS, (0.9, 1.0, 1.0), roughness=0.25, ior=1.45),),
        (Lobe(GLASS, (1.0, 1.0, 1.0), roughness=0.5, ior=0.75, **ms),),
        (Lobe(REFRACTION, (0.8, 0.9, 1.0), roughness=0.5, ior=1.33),),
        (Lobe(GLOSSY, (0.95, 0.64, 0.54), roughness=0.3, fresnel="F82",
              f82_tint=(0.9, 0.8, 0.7), **ms),
         Lobe(GLOSSY, (1.0, 0.9, 0.8), weight=0.7, roughness=0.45, fresnel="DIELECTRIC",
              fresnel_ior=1.6, **ms),
         Lobe(DIFFUSE, (0.6, 0.3, 0.2), weight=0.7, roughness=0.25, layer_ior=1.6,
              layer_f0=0.05, layer_roughness=0.45, layer_multiscatter=True)),
        (Lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.2, fresnel="DIELECTRIC", fresnel_ior=1.45),
         Lobe(DIFFUSE, (0.6, 0.6, 0.6), layer_ior=1.45, layer_f0=0.034, layer_roughness=0.2)),
        # the Metallic BSDF's Physical Conductor (gold's n, k), with a diffuse
        (Lobe(GLOSSY, (1.0, 1.0, 1.0), weight=0.8, roughness=0.35, fresnel="CONDUCTOR",
              conductor_n=(0.18, 0.42, 1.37), conductor_k=(3.42, 2.35, 1.77), **ms),
         Lobe(DIFFUSE, (0.4, 0.4, 0.4), weight=0.2)),
        (Lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.2, fresnel="CONDUCTOR",
              conductor_n=(2.76, 2.51, 2.23), conductor_k=(3.87, 3.40, 3.01)),),
        P(base_color=(0.7, 0.4, 0.2), metallic=0.3, roughness=0.4),
        # thin films: over a Principled metal, specular layer and its diffuse;
        # over a conductor
        P(base_color=(0.7, 0.4, 0.2), metallic=0.4, roughness=0.35, thin_film_thickness=380.0,
          thin_film_ior=1.45, specular_tint=(1.0, 0.8, 0.9)),
        (Lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.25, fresnel="CONDUCTOR",
              conductor_n=(0.18, 0.42, 1.37), conductor_k=(3.42, 2.35, 1.77),
              thin_film_thickness=0.6, thin_film_ior=1.6, **ms),),
        P(base_color=(0.8, 0.8, 0.8), roughness=0.5, ior=1.5, coat_weight=0.5,
          diffuse_roughness=0.4),
        P(base_color=(0.9, 0.9, 0.9), roughness=0.2, transmission=0.7, ior=1.45),
        # delta lobes are skipped; a weight-0 lobe is still evaluated (colour 0)
        (Lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.0), Lobe(DIFFUSE, (0.3, 0.4, 0.5)),
         Lobe(TRANSPARENT, (0.5, 0.5, 0.5)), Lobe(GLOSSY, (0.5, 0.5, 0.5), roughness=0.5,
                                                   weight=0.0)),
    ]


def _table(bump):
    t = B.build_material_table([Material(f"m{i}", lobes=lb)
                                for i, lb in enumerate(_materials())], [])
    if bump:
        t = dataclasses.replace(t, bump_correction=np.ones(t.n_materials, bool))
    return t


def _unit(a):
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def _pairs(t, K, seed):
    """K random pairs: float32 normals / view / colours (as VisiblePoints), float64 light."""
    rng = np.random.default_rng(seed)
    mat = rng.integers(0, t.n_materials, K)
    ng = _unit(rng.normal(size=(K, 3)))
    ns = _unit(ng + 0.35 * rng.normal(size=(K, 3)))
    wo = _unit(rng.normal(size=(K, 3)))
    wi = _unit(rng.normal(size=(K, 3)))
    # a quarter grazing: 1e-3..1e-7 from the geometric plane (view or light)
    g = rng.random(K) < 0.25
    for w in (wo, wi):
        h = rng.random(K) < 0.5
        sel = g & h
        eps = 10.0 ** rng.uniform(-7, -3, sel.sum()) * rng.choice([-1, 1], sel.sum())
        w[sel] = _unit(w[sel] - np.einsum("ij,ij->i", w[sel], ng[sel])[:, None] * ng[sel]
                       + eps[:, None] * ng[sel])
    colors = (t.color * t.weight[:, :, None])[mat] * rng.uniform(0.5, 1.0, (K, 1, 1))
    f32 = lambda a: a.astype(np.float32)  # noqa: E731
    return mat, f32(colors), f32(ns), ng, f32(wo), wi


def _assert_close(got, want):
    err = np.abs(got - want)
    tol = RTOL * np.abs(want) + ATOL
    bad = ~(err <= tol)
    assert not bad.any(), (f"{bad.sum()} of {bad.size} differ; worst rel "
                           f"{np.max(err / (np.abs(want) + 1e-300)):.3g}")


@pytest.mark.parametrize("bump", [False, True])
def test_compiled_equals_numpy_every_lobe_kind(bump):
    t = _table(bump)
    mat, colors, ns, ng, wo, wi = _pairs(t, 6000, 1 + bump)
    want = B.eval_bsdf(t, mat, colors, ns, ng, wo, wi)
    got = C.eval_bsdf(t, mat, colors, ns, ng, wo, wi)
    _assert_close(got, want)
    # every material gives non-zero values somewhere (the pairs reach each lobe)
    for m in range(t.n_materials):
        assert np.count_nonzero(want[mat == m]) > 20, m
    # both orientations: the transmission of the glasses from inside and outside
    back = np.einsum("ij,ij->i", ng, wo) < 0
    kinds = t.kind[mat]
    glass = np.isin(kinds, (GLASS, REFRACTION)).any(axis=1)
    lo = np.einsum("ij,ij->i", ng, wi) * np.einsum("ij,ij->i", ng, wo) < 0
    for side in (back, ~back):
        assert np.count_nonzero(want[glass & side & lo]) > 50


def test_compiled_smooth_sum_is_the_receivers_smooth_table():
    """with_smooth: the sum Receivers.smooth (the diffuse and translucent
    lobes alone) evaluates; a material without such lobes has none, and one
    made of them alone is all smooth."""
    t = _table(False)
    mat, colors, ns, ng, wo, wi = _pairs(t, 4000, 3)
    f, s = C.eval_bsdf(t, mat, colors, ns, ng, wo, wi, with_smooth=True)
    _assert_close(f, B.eval_bsdf(t, mat, colors, ns, ng, wo, wi))
    _assert_close(s, B.eval_bsdf(Receivers(t).smooth, mat, colors, ns, ng, wo, wi))
    kinds = t.kind[mat]
    diffuse = np.isin(kinds, (DIFFUSE, TRANSLUCENT))
    glossy_only = ~diffuse.any(axis=1)      # e.g. a plain Glossy BSDF: its w is 1
    assert glossy_only.sum() > 100 and np.any(f[glossy_only] > 0)
    assert np.all(s[glossy_only] == 0.0)
    smooth_only = ~(np.isin(kinds, (GLOSSY, GLASS, REFRACTION)) & ~t.lobe_delta[mat]).any(axis=1)
    assert smooth_only.sum() > 100
    np.testing.assert_array_equal(s[smooth_only], f[smooth_only])


def _principled_floor(res=20):
    """test_gather_buffers' floor with a Principled half (layered diffuse,
    dielectric and F82 specular, Multiscatter GGX) and a Diffuse + Glossy mix."""
    from test_gather_buffers import _floor_scene
    sc = _floor_scene(res)
    lobes = tuple(principled_to_lobes(base_color=(0.7, 0.5, 0.3), metallic=0.3,
                                      roughness=0.35, diffuse_roughness=0.3)[0])
    sc.materials[1] = Material("principled", lobes)
    return sc


@pytest.mark.parametrize("frequency", [True, False])
def test_render_compiled_equals_numpy(monkeypatch, frequency):
    """The renderer's image and AOVs with the compiled pair loops equal the
    numpy path's to rounding (photon_pass.COMPILED_BSDF, Receivers.compiled,
    the direct light's non-Lambert receivers nee.COMPILED_BSDF):
    same sums per point in the same order, the BSDF within 1 ulp."""
    from core.render import Renderer
    from core.settings import RenderSettings
    from core.lights import nee
    from core.sppm import photon_pass as PP
    st = RenderSettings(integrator="PHOTON", max_passes=2, time_limit=0.0,
                        photons_per_pass=8000, seed=5, use_frequency=frequency,
                        frequency_estimator="QUANTILE", aov_spectrum=frequency,
                        aov_radius=True, aov_predicted_radius=frequency)
    out = []
    for on in (False, True):
        monkeypatch.setattr(PP, "COMPILED_BSDF", on)
        monkeypatch.setattr(Receivers, "compiled", on)
        monkeypatch.setattr(nee, "COMPILED_BSDF", on)
        out.append(Renderer(_principled_floor(), st, log=lambda s: None).run())
    a, b = out
    assert a.image[..., :3].max() > 0
    np.testing.assert_allclose(b.image, a.image, rtol=1e-12, atol=0)
    assert a.aovs.keys() == b.aovs.keys()
    for k in a.aovs:
        np.testing.assert_allclose(b.aovs[k], a.aovs[k], rtol=1e-12, atol=0, err_msg=k)


def test_per_pair_functions_take_no_reference_counts():
    """The functions the kernels call once per pair, ray or light sample with
    arrays take no reference counts (``core._numba_options.NO_REFCOUNTS``), and
    the lobe helpers stay functions of their own: both are what keeps a
    Lambert material's f at about half its cost before round 32, with the same
    bits (docs/architecture.md "The BSDF evaluation's fixed cost, round
    32").  numba would accept their removal silently and only run slower."""
    from core.lights import direct_kernels as D
    for f in (C._eval_pair_as, C._sample_pair, C._layer_transmission, C._ms_albedo,
              D._entry_weight, D._spot_atten):
        assert f.targetoptions.get("_nrt") is False, f.__name__
    # the two bodies stay functions of their own; their entry points, which
    # only cast the arguments, are inlined (one signature a body)
    for f in (C._diffuse_lobe, C._microfacet_lobe, C._eval_pair_as, C._sample_pair):
        assert f.targetoptions.get("inline", "never") == "never", f.__name__
    for f in (C.eval_pair_as, C.sample_pair):
        assert f.targetoptions.get("inline") == "always", f.__name__
