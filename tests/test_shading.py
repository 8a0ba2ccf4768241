"""Tests of core.scene.nodes: Principled BSDF mapping and Mix/Add Shader flattening."""
import math

import numpy as np

from core import materials as B
from core.scene.model import (DIFFUSE, GLASS, GLOSSY, MAX_LOBES, TRANSLUCENT, TRANSPARENT, Lobe,
                              Material)
from core.scene.nodes import (add_materials, f0_from_ior, ior_from_f0, merge_lobes, mix_materials,
                              principled_to_lobes)


def albedo(lobes, theta, n=100_000, seed=0):
    """∫ f |cos| dω (3,) by uniform-sphere MC, and the sd of that mean."""
    T = B.build_material_table([Material("m", lobes=tuple(lobes))], [])
    mat = np.zeros(n, np.int32)
    cols = B.lobe_colors(T, mat, np.zeros((n, 2)))
    nn = np.tile([0.0, 0.0, 1.0], (n, 1))
    wo = np.tile([math.sin(theta), 0.0, math.cos(theta)], (n, 1))
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    x = B.eval_bsdf(T, mat, cols, nn, nn, wo, d) * np.abs(d[:, 2:3]) * 4 * np.pi
    return x.mean(0), x.std(0) / math.sqrt(n)


def test_f0_ior_roundtrip():
    assert abs(f0_from_ior(1.5) - 0.04) < 1e-15
    assert abs(ior_from_f0(0.04) - 1.5) < 1e-12


def test_principled_pure_diffuse_is_close_to_diffuse_base():
    base = (0.8, 0.5, 0.2)
    lobes, emission, notes = principled_to_lobes(base_color=base, metallic=0.0, roughness=1.0)
    kinds = sorted(lb.kind for lb in lobes)
    assert kinds == [DIFFUSE, GLOSSY]
    d = [lb for lb in lobes if lb.kind == DIFFUSE][0]
    g = [lb for lb in lobes if lb.kind == GLOSSY][0]
    # Diffuse = base colour under a dielectric layer (ior 1.5, F0 = 0.04) that
    # takes its view-dependent albedo away; the layer is GGX with real Fresnel.
    np.testing.assert_allclose(np.array(d.color) * d.weight, base, rtol=1e-12)
    assert d.layer_ior == 1.5 and abs(d.layer_f0 - 0.04) < 1e-12 and d.layer_roughness == 1.0
    assert g.fresnel == "DIELECTRIC" and g.fresnel_ior == 1.5 and g.multiscatter
    np.testing.assert_allclose(emission, 0.0)
    for th in (0.2, 0.8):
        m, sd = albedo(lobes, th)
        # base (1 - A) + (white specular albedo ~ A) with the layer albedo A of a
        # few %: within 0.03 of the base colour (absolute, per channel).
        assert np.all(np.abs(m - np.array(base)) < 0.03 + 5 * sd), (th, m)
    assert notes == ()


def test_principled_metallic_is_glossy_base_color():
    lobes, _, notes = principled_to_lobes(base_color=(0.9, 0.6, 0.2), metallic=1.0, roughness=0.3,
                                          specular_tint=(1.0, 0.5, 0.5))
    assert len(lobes) == 1
    lb = lobes[0]
    assert lb.kind == GLOSSY and lb.roughness == 0.3 and lb.fresnel == "F82"
    np.testing.assert_allclose(np.array(lb.color) * lb.weight, [0.9, 0.6, 0.2], rtol=1e-12)
    np.testing.assert_allclose(lb.f82_tint, [1.0, 0.5, 0.5])
    # Colours above 1 are clamped like Cycles' clamped_base_color.
    lobes, _, _ = principled_to_lobes(base_color=(2.0, 0.5, 0.5), metallic=1.0)
    assert max(lobes[0].color) * lobes[0].weight <= 1.0 + 1e-12


def test_principled_transmission_is_glass():
    lobes, _, _ = principled_to_lobes(base_color=(1, 1, 1), transmission=1.0, roughness=0.0,
                                      ior=1.33)
    assert len(lobes) == 1
    lb = lobes[0]
    assert lb.kind == GLASS and lb.ior == 1.33 and lb.roughness == 0.0 and lb.weight == 1.0
    np.testing.assert_allclose(lb.color, 1.0)
    # A coloured glass: sqrt(base) per interface, so a slab in+out transmits the base colour.
    lobes, _, notes = principled_to_lobes(base_color=(0.25, 0.64, 1.0), transmission=1.0)
    np.testing.assert_allclose(lobes[0].color, [0.5, 0.8, 1.0], rtol=1e-12)
    assert any("sqrt" in n for n in notes)


def test_principled_alpha_and_emission():
    lobes, emission, _ = principled_to_lobes(base_color=(0.5, 0.5, 0.5), alpha=0.25,
                                             emission_color=(1.0, 0.5, 0.25),
                                             emission_strength=4.0)
    tr = [lb for lb in lobes if lb.kind == TRANSPARENT]
    assert len(tr) == 1 and abs(tr[0].weight - 0.75) < 1e-12
    np.testing.assert_allclose(tr[0].color, 1.0)
    # Emission = colour x strength, attenuated by alpha (Cycles applies alpha first).
    np.testing.assert_allclose(emission, [1.0, 0.5, 0.25])
    # Everything but the transparent part sums to alpha x what alpha = 1 gives.
    full, _, _ = principled_to_lobes(base_color=(0.5, 0.5, 0.5))
    w_full = sum(lb.weight * np.array(lb.color) for lb in full)
    w_cut = sum(lb.weight * np.array(lb.color) for lb in lobes if lb.kind != TRANSPARENT)
    np.testing.assert_allclose(w_cut, 0.25 * w_full, rtol=1e-12)


def test_principled_metallic_map_is_the_metal_and_dielectric_builds_mixed():
    """A Metallic map m(uv): the metal lobe of Metallic 1 scaled by m, the
    specular and diffuse of Metallic 0 by 1 - m (Cycles' Principled is
    linear in Metallic), in the slots Metallic 0.5 gives; the coat above
    is not scaled."""
    import dataclasses
    kw = dict(base_color=(0.9, 0.45, 0.1), roughness=0.3, coat_weight=0.5)
    lobes, _, notes = principled_to_lobes(metallic_texture=3, **kw)
    half, _, _ = principled_to_lobes(metallic=0.5, **kw)
    one, _, _ = principled_to_lobes(metallic=1.0, **kw)
    zero, _, _ = principled_to_lobes(metallic=0.0, **kw)
    assert [lb.kind for lb in lobes] == [lb.kind for lb in half]
    plain = [dataclasses.replace(lb, alpha_texture=-1, alpha_invert=False) for lb in lobes]
    assert [lb.alpha_texture for lb in lobes] == [-1, 3, 3, 3]
    assert [lb.alpha_invert for lb in lobes[1:]] == [False, True, True]
    assert plain[0] == one[0] == zero[0]
    assert plain[1] == one[1] and plain[2:] == list(zero[1:])


def test_principled_notes_unsupported_features():
    lobes, _, notes = principled_to_lobes(sheen_weight=0.5, coat_weight=1.0, subsurface_weight=0.3,
                                          anisotropic=0.5, diffuse_roughness=0.5)
    text = " ".join(notes)
    for word in ("sheen", "coat", "subsurface", "anisotropy"):
        assert word in text
    assert len(lobes) <= MAX_LOBES
    # Coat layer on top: GGX with the exact dielectric Fresnel of coat_ior.
    coat = [lb for lb in lobes if lb.kind == GLOSSY and lb.roughness == 0.03]
    assert len(coat) == 1 and coat[0].fresnel == "DIELECTRIC" and coat[0].fresnel_ior == 1.5
    assert coat[0].weight == 1.0 and coat[0].multiscatter
    assert any(lb.kind == DIFFUSE and lb.roughness == 0.5 for lb in lobes)


def test_mix_shader_is_linear_in_f():
    a = (Lobe(DIFFUSE, (0.8, 0.2, 0.2), roughness=0.6), Lobe(GLOSSY, (0.5, 0.5, 0.5), roughness=0.3))
    b = (Lobe(DIFFUSE, (0.2, 0.8, 0.2), roughness=0.6), Lobe(GLOSSY, (0.9, 0.1, 0.1), roughness=0.3),
         Lobe(TRANSLUCENT, (0.3, 0.3, 0.9)))
    fac = 0.3
    mixed, notes = mix_materials(a, b, fac)
    assert notes == ()
    # Glossy lobes merge (f linear in colour); Oren-Nayar of different colours do not.
    assert sorted(lb.kind for lb in mixed) == [DIFFUSE, DIFFUSE, GLOSSY, TRANSLUCENT]
    T = B.build_material_table([Material("a", a), Material("b", b), Material("m", mixed)], [])
    rng = np.random.default_rng(1)
    K = 2000
    wo = rng.normal(size=(K, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi = rng.normal(size=(K, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    n = np.tile([0.0, 0.0, 1.0], (K, 1))

    def f(m):
        mat = np.full(K, m, np.int32)
        return B.eval_bsdf(T, mat, B.lobe_colors(T, mat, np.zeros((K, 2))), n, n, wo, wi)

    np.testing.assert_allclose(f(2), (1 - fac) * f(0) + fac * f(1), rtol=1e-12, atol=1e-15)
    # Fac is clamped to [0, 1] like Cycles' Mix Shader.
    only_b, _ = mix_materials(a, b, 1.5)
    assert len(only_b) == len(b)


def test_add_shader_merges_identical_lobes_and_drops_beyond_max():
    d = Lobe(DIFFUSE, (0.5, 0.5, 0.5))
    added, notes = add_materials((d,), (d,))
    assert len(added) == 1 and abs(added[0].weight - 2.0) < 1e-12 and notes == ()
    many = tuple(Lobe(DIFFUSE, (0.1 * (i + 1),) * 3, roughness=0.1 * (i + 1)) for i in range(MAX_LOBES + 2))
    kept, notes = merge_lobes(many)
    assert len(kept) == MAX_LOBES and len(notes) == 2
    # The two dimmest lobes are the ones dropped, and the order is kept.
    assert [lb.roughness for lb in kept] == [lb.roughness for lb in many[2:]]
    assert all("dropped" in n for n in notes)
