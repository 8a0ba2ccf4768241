"""Colour nodes on an image (core/scene/color_ops.py, addon/export.py
``_MaterialBuilder.color_chain``) against Cycles.

An Image Texture passed through Mix (Color) and MixRGB (a sample of the blend
types: Multiply, Screen, Overlay, Dodge, Burn, Color, Value), Hue/Saturation/Value,
Brightness/Contrast, Gamma, Invert, RGB Curves or a Color Ramp into a Diffuse colour is
exported as one image with the nodes applied to its texels.  Each case
renders tests/test_shading_nodes.py's plane (32 x 32, orthographic, a sun,
direct light only) with FPPM and Cycles, two seeds each, under that file's
bound (2x the seed-to-seed noise + 1 % of the mean).  Measured: mean |diff|
0.2-0.8 % of the mean, 0.5-0.9x the noise, in every case; without the nodes
(the image alone, what FPPM rendered before: the node was ignored with a
note) each image moves by 17-85 % of its mean, over 3x the bound.  The
8 x 8 image is magnified (a texel spans 2.7 pixels): applied to the texels
as they are, the nonlinear cases missed by 2.4-4.8 % (Hue/Saturation 2.9 %,
Color Ramp 4.8 %, 3-7x the noise); enlarged 8 times first
(``textures.upsample``), they are within the noise.

The HSV round trip and the blend formulas are also checked on their own.
"""
from __future__ import annotations

import numpy as np
import pytest

from core.scene import color_ops as CO


def test_hsv_round_trip_and_known_values():
    rng = np.random.default_rng(3)
    c = rng.random((500, 3))
    c[:5] = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0.5], [0, 0, 0]]
    hsv = CO.rgb_to_hsv(c)
    np.testing.assert_allclose(CO.hsv_to_rgb(hsv), c, atol=1e-12)
    np.testing.assert_allclose(hsv[:4], [[0, 1, 1], [1 / 3, 1, 1], [2 / 3, 1, 1], [0, 0, 0.5]],
                               atol=1e-12)
    # Hue 0.5, saturation 1, value 1, fac 1: the identity.
    np.testing.assert_allclose(CO.hue_sat_val(c, 0.5, 1.0, 1.0, 1.0), c, atol=1e-12)
    # Hue + 1/3 turns red into green.
    np.testing.assert_allclose(CO.hue_sat_val(np.array([[1.0, 0, 0]]), 0.5 + 1 / 3, 1, 1, 1),
                               [[0, 1, 0]], atol=1e-12)


def test_mix_blends_at_factor_zero_and_one():
    rng = np.random.default_rng(4)
    a, b = rng.random((50, 3)) + 0.05, rng.random((50, 3)) + 0.05
    for blend in CO.MIX_BLENDS:
        out0 = CO.mix(blend, 0.0, a, b)
        if blend not in ("EXCLUSION", "DODGE", "BURN"):     # these two clamp to [0, 1]
            np.testing.assert_allclose(out0, a, atol=1e-12, err_msg=blend)
    want = {"MIX": b, "ADD": a + b, "MULTIPLY": a * b, "SUBTRACT": a - b, "DIVIDE": a / b,
            "DIFFERENCE": np.abs(a - b), "DARKEN": np.minimum(a, b),
            "LIGHTEN": np.maximum(a, b), "SCREEN": 1 - (1 - a) * (1 - b),
            "LINEAR_LIGHT": a + 2 * b - 1}
    want["DODGE"] = np.where(b >= 1.0, 1.0, np.minimum(a / np.where(b < 1.0, 1.0 - b, 1.0), 1.0))
    want["BURN"] = np.clip(1.0 - (1.0 - a) / b, 0.0, 1.0)
    for blend, w in want.items():
        np.testing.assert_allclose(CO.mix(blend, 1.0, a, b), w, atol=1e-12, err_msg=blend)
    # The HSV blends at factor 1 take B's value, saturation, hue (and
    # saturation) and keep A's other components.
    ha, hb = CO.rgb_to_hsv(a), CO.rgb_to_hsv(b)
    for blend, took in (("VALUE", [2]), ("SATURATION", [1]), ("HUE", [0]), ("COLOR", [0, 1])):
        h = CO.rgb_to_hsv(CO.mix(blend, 1.0, a, b))
        kept = [k for k in range(3) if k not in took]
        np.testing.assert_allclose(h[:, took], hb[:, took], atol=1e-9, err_msg=blend)
        np.testing.assert_allclose(h[:, kept], ha[:, kept], atol=1e-9, err_msg=blend)
    # A grey B has no hue: HUE and COLOR leave A as it is.
    grey = np.full_like(b, 0.4)
    for blend in ("HUE", "COLOR"):
        np.testing.assert_allclose(CO.mix(blend, 0.7, a, grey), a, atol=1e-12)


def test_ramp_lookup_is_linear_between_entries():
    table = np.stack([np.linspace(0, 1, CO.RAMP_TABLE_SIZE)] * 3, -1) ** 2
    f = np.array([-0.5, 0.0, 0.3, 1.0, 2.0, np.nan])
    out = CO.ramp(f, table, True)[:, 0]
    x = 0.3 * 255
    i = int(x)
    assert out[2] == pytest.approx((1 - (x - i)) * table[i, 0] + (x - i) * table[i + 1, 0])
    np.testing.assert_allclose(out[[0, 1, 3, 4, 5]], [0, 0, 1, 1, 0])
    assert CO.ramp(f, table, False)[2, 0] == table[i, 0]


# ------------------------------------------------------------------ Cycles

def _chain(kind):
    """build(nodes, links, image_colour_socket) -> the socket into the Diffuse colour."""
    def mix_new(nodes, links, col, blend, fac, const, side):
        m = nodes.new('ShaderNodeMix')
        m.data_type = 'RGBA'
        m.blend_type = blend
        m.inputs["Factor"].default_value = fac
        a = next(i for i in m.inputs if i.identifier == "A_Color")
        b = next(i for i in m.inputs if i.identifier == "B_Color")
        (b if side == "A" else a).default_value = const
        links.new(col, a if side == "A" else b)
        return next(o for o in m.outputs if o.identifier == "Result_Color")

    def mixrgb(nodes, links, col):
        m = nodes.new('ShaderNodeMixRGB')
        m.blend_type = 'OVERLAY'
        m.inputs["Fac"].default_value = 0.8
        m.inputs["Color2"].default_value = (0.9, 0.3, 0.6, 1.0)
        links.new(col, m.inputs["Color1"])
        return m.outputs["Color"]

    def node(nodes, links, col, idname, **inputs):
        """A colour node of idname with its float inputs set, col into its Color."""
        n = nodes.new(idname)
        for k, v in inputs.items():
            n.inputs[k].default_value = v
        links.new(col, n.inputs["Color"])
        return n.outputs["Color"]

    def hsv(nodes, links, col):
        return node(nodes, links, col, 'ShaderNodeHueSaturation', Hue=0.8, Saturation=1.6,
                    Value=0.9, Fac=0.9)

    def bright(nodes, links, col):
        c = node(nodes, links, col, 'ShaderNodeBrightContrast', Bright=0.1, Contrast=0.6)
        c = node(nodes, links, c, 'ShaderNodeGamma', Gamma=2.2)
        return node(nodes, links, c, 'ShaderNodeInvert', Fac=0.7)

    def ramp(nodes, links, col):
        r = nodes.new('ShaderNodeValToRGB')
        els = r.color_ramp.elements
        els[0].position, els[0].color = 0.25, (0.05, 0.1, 0.8, 1.0)
        els[1].position, els[1].color = 0.6, (0.9, 0.7, 0.1, 1.0)
        e = els.new(0.45)
        e.color = (0.8, 0.1, 0.1, 1.0)
        r.color_ramp.interpolation = 'EASE'
        links.new(col, r.inputs["Fac"])
        return r.outputs["Color"]

    def rgb_curves(nodes, links, col):
        n = nodes.new('ShaderNodeRGBCurve')
        cm = n.mapping
        cm.curves[3].points.new(0.4, 0.7)           # the combined curve lifts the mids
        cm.curves[0].points[1].location = (1.0, 0.6)  # red capped at 0.6
        cm.curves[2].points.new(0.5, 0.2)           # blue pushed down
        cm.update()
        n.inputs["Fac"].default_value = 0.9
        links.new(col, n.inputs["Color"])
        return n.outputs["Color"]
    return {
        "rgb_curves": rgb_curves,
        "mix_multiply": lambda n, l, c: mix_new(n, l, c, 'MULTIPLY', 0.7, (0.9, 0.4, 0.2, 1.0), "A"),
        "mix_screen_b": lambda n, l, c: mix_new(n, l, c, 'SCREEN', 0.6, (0.1, 0.5, 0.3, 1.0), "B"),
        "mixrgb_overlay": mixrgb,
        "mix_dodge": lambda n, l, c: mix_new(n, l, c, 'DODGE', 0.8, (0.7, 0.4, 0.9, 1.0), "A"),
        "mix_burn_b": lambda n, l, c: mix_new(n, l, c, 'BURN', 0.7, (0.8, 0.6, 0.3, 1.0), "B"),
        "mix_color": lambda n, l, c: mix_new(n, l, c, 'COLOR', 0.9, (0.1, 0.6, 0.8, 1.0), "A"),
        "mix_value_b": lambda n, l, c: mix_new(n, l, c, 'VALUE', 0.6, (0.9, 0.2, 0.1, 1.0), "B"),
        "hue_saturation": hsv,
        "bright_gamma_invert": bright,
        "color_ramp": ramp,
    }[kind]


CASES = ["mix_multiply", "mix_screen_b", "mixrgb_overlay", "mix_dodge", "mix_burn_b",
         "mix_color", "mix_value_b", "hue_saturation",
         "bright_gamma_invert", "rgb_curves", "color_ramp"]


@pytest.mark.parametrize("kind", CASES)
def test_colour_nodes_on_an_image_agree_with_cycles(kind, tmp_path):
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    build = _chain(kind)

    def mat(nodes, links, surface):
        d = TS.diffuse_with_normal(nodes, links, surface)
        tex = nodes.new('ShaderNodeTexImage')
        tex.image = TS._image("C", TS._color_pixels(), non_color=False)
        links.new(build(nodes, links, tex.outputs["Color"]), d.inputs["Color"])

    sc, _ = TS.plane_scene(mat)
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, kind)
    assert lines[1] == "Approximated: nothing.", lines[1]
    assert len(scene.textures) == 1
    TS._check(err, noise)
    # The nodes matter: the image alone is far from Cycles.
    import dataclasses
    raw = TS._color_pixels()
    plain = dataclasses.replace(scene, textures=[np.concatenate(
        [raw, np.ones(raw.shape[:2] + (1,), np.float32)], -1)])
    alone = (TS._fppm(plain, 1) + TS._fppm(plain, 2)) / 2
    effect = np.abs(alone - img).mean() / ref.mean()
    print(f"{kind}: without the nodes the image moves by {effect:.3f} of the mean")
    TS._check(err, noise, effect)


# ----------------------------------------------- an image's colour as a factor

def _mask_pixels(n=8):
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    g = np.clip(1.2 * np.abs(np.sin(np.pi * x)) * (0.3 + 0.7 * y), 0, 1)
    return np.repeat(g[..., None], 3, -1).astype(np.float32)


@pytest.mark.parametrize("how", ["mix_fac", "mix_fac_ramp", "principled_alpha"])
def test_an_image_colour_as_a_factor_agrees_with_cycles(how, tmp_path):
    """An image's Color (a grey mask, also through a Color Ramp) into a Mix
    Shader's Fac (a blue Diffuse and a rough Glossy) or the Principled
    Alpha (over a red emitting floor): per hit, through a texture whose
    alpha is the colour's luminance (``_MaterialBuilder.alpha_texture``).
    Before, the image's mean was used (noted).  Measured: Mix mean |diff|
    0.7-0.8 % of the mean (1.5-1.9x the noise, the image mean -0.6 %, under
    the bound of 2x the noise + 1 %), the mean factor instead 18-20 %;
    Principled Alpha (a per-sample coin flip, image means within 4
    standard errors + 0.5 %, as tests/test_shading_nodes.py's alpha test):
    -0.06 %."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    from scenes import bpy_kit as K

    def mat(nodes, links, surface):
        tex = nodes.new('ShaderNodeTexImage')
        tex.image = TS._image("M", _mask_pixels(), non_color=True)
        col = tex.outputs["Color"]
        if how == "mix_fac_ramp":
            col = _chain("color_ramp")(nodes, links, col)
        if how == "principled_alpha":
            p = nodes.new('ShaderNodeBsdfPrincipled')
            p.inputs["Base Color"].default_value = (0.2, 0.7, 0.3, 1.0)
            links.new(col, p.inputs["Alpha"])
            links.new(p.outputs[0], surface)
            return
        mix = nodes.new('ShaderNodeMixShader')
        d = nodes.new('ShaderNodeBsdfDiffuse')
        d.inputs["Color"].default_value = (0.1, 0.2, 0.9, 1.0)
        g = nodes.new('ShaderNodeBsdfGlossy')
        g.inputs["Roughness"].default_value = 0.4
        links.new(col, mix.inputs["Fac"])
        links.new(d.outputs[0], mix.inputs[1])
        links.new(g.outputs[0], mix.inputs[2])
        links.new(mix.outputs[0], surface)

    sc, _ = TS.plane_scene(mat)
    if how == "principled_alpha":
        K.plane("Floor", 4.0, K.material("Red", "EMISSION", color=(0.8, 0.1, 0.05)),
                location=(0, 0, -0.5))
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, how)
    assert lines[1] == "Approximated: nothing.", lines[1]
    if how == "principled_alpha":
        assert abs(img.mean() / ref.mean() - 1.0) < 4.0 * noise / TS.RES + 0.005
        return
    TS._check(err, noise)
    # The mask matters: the same mix at the mask's mean factor.
    import dataclasses
    from core.scene.nodes import mix_materials
    m = scene.materials[0]
    lobes = [dataclasses.replace(lb, alpha_texture=-1, alpha_invert=False) for lb in m.lobes]
    tex = scene.textures[m.lobes[0].alpha_texture]
    f = float(tex[..., 3].mean())
    a = [lb for lb in lobes if lb.kind == m.lobes[0].kind][:1]
    b = [lb for lb in lobes if lb.kind != m.lobes[0].kind][:1]
    mixed, _ = mix_materials(a if m.lobes[0].alpha_invert else b,
                             b if m.lobes[0].alpha_invert else a, f)
    flat = dataclasses.replace(scene, materials=[dataclasses.replace(m, lobes=mixed)])
    flat_img = (TS._fppm(flat, 1) + TS._fppm(flat, 2)) / 2
    effect = np.abs(flat_img - img).mean() / ref.mean()
    print(f"{how}: at the mean factor {f:.3f} the image moves by {effect:.3f} of the mean")
    TS._check(err, noise, effect)


def test_a_bump_height_through_a_color_ramp_agrees_with_cycles(tmp_path):
    """Image -> Color Ramp (a contrast curve) -> Bump Height: the folded
    image is the height (``_MaterialBuilder.normal_input``).  Before, the
    height was ignored with a note.  Measured: mean |diff| 0.36 % of the
    mean, 0.8x the noise; without the bump the image differs by 7.6 %."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def bump(nodes, links):
        tex = nodes.new('ShaderNodeTexImage')
        tex.image = TS._image("H", TS.height_pixels())
        r = nodes.new('ShaderNodeValToRGB')
        r.color_ramp.elements[0].position = 0.2
        r.color_ramp.elements[1].position = 0.8
        b = nodes.new('ShaderNodeBump')
        b.inputs["Distance"].default_value = 0.1
        links.new(tex.outputs["Color"], r.inputs["Fac"])
        links.new(r.outputs["Color"], b.inputs["Height"])
        return b.outputs["Normal"]

    sc, _ = TS.plane_scene(lambda n, lk, s: TS.diffuse_with_normal(n, lk, s, bump))
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, "bump_ramp")
    assert scene.materials[0].normal is not None and lines[1] == TS.PHOTON_NOTE, lines
    flat = TS._fppm(TS._without_normals(scene), 1)
    effect = np.abs(flat - ref).mean() / ref.mean()
    print(f"bump through a ramp: without the perturbation mean |diff| {effect:.4f}")
    TS._check(err, noise, effect)


@pytest.mark.parametrize("how", ["emission", "principled", "both"])
def test_an_emission_strength_mask_agrees_with_cycles(how, tmp_path):
    """A grey mask into the Emission's Strength (or the Principled Emission
    Strength), seen directly: the emission is the constant colour times the
    mask's luminance per hit (``_MaterialBuilder.emission``).  Before, the
    mask's mean was used (noted).  Measured: image means equal to 4 digits,
    mean |diff| 0.95 % of the mean, 0.85x the seed-to-seed noise (the pixel
    filter's jitter over the mask's edges); the mean strength instead 44 %.
    "both": the Emission's Color an image too (read at the same point):
    the two images' product, where before the colour image was scaled by
    the mask's mean."""
    pytest.importorskip("bpy")
    import dataclasses
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        tex = nodes.new('ShaderNodeTexImage')
        tex.image = TS._image("M", _mask_pixels(), non_color=True)
        if how in ("emission", "both"):
            e = nodes.new('ShaderNodeEmission')
            e.inputs["Color"].default_value = (1.0, 0.5, 0.2, 1.0)
            links.new(tex.outputs["Color"], e.inputs["Strength"])
            if how == "both":
                col = nodes.new('ShaderNodeTexImage')
                col.image = TS._image("C", TS._color_pixels(), non_color=False)
                links.new(col.outputs["Color"], e.inputs["Color"])
        else:
            e = nodes.new('ShaderNodeBsdfPrincipled')
            e.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
            e.inputs["Roughness"].default_value = 1.0
            e.inputs["Specular IOR Level"].default_value = 0.0
            e.inputs["Emission Color"].default_value = (1.0, 0.5, 0.2, 1.0)
            links.new(tex.outputs["Color"], e.inputs["Emission Strength"])
        links.new(e.outputs[0], surface)

    sc, _ = TS.plane_scene(mat)
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, how)
    assert lines[1] == "Approximated: nothing.", lines[1]
    m = scene.materials[0]
    assert m.emission_texture >= 0 and len(scene.textures) == 1
    g = scene.textures[m.emission_texture]
    if how == "both":
        # The colour image times the mask's mean luminance (what FPPM did).
        mean = float(CO.gray(_mask_pixels().astype(np.float64)).mean())
        raw = TS._color_pixels() * mean
        flat = dataclasses.replace(scene, textures=[np.concatenate(
            [raw, np.ones(raw.shape[:2] + (1,), np.float32)], -1)])
    else:
        flat = dataclasses.replace(scene, materials=[dataclasses.replace(
            m, emission=tuple(float(x) for x in g[..., :3].reshape(-1, 3).mean(0)),
            emission_texture=-1)])
    effect = np.abs((TS._fppm(flat, 1) + TS._fppm(flat, 2)) / 2 - img).mean() / ref.mean()
    print(f"{how}: at the mask's mean the image moves by {effect:.3f} of the mean")
    TS._check(err, noise, effect)


@pytest.mark.parametrize("how", ["color", "alpha"])
def test_a_metallic_map_agrees_with_cycles(how, tmp_path):
    """A grey mask into the Principled Metallic (its Color, or its Alpha
    output) over an orange rough base: per hit, the metal lobe scaled by
    m(uv) and the specular and diffuse by 1 - m(uv) (``principled_to_lobes``
    ``metallic_texture``; Cycles' Principled BSDF is linear in Metallic).
    Before, the mask's mean was used (noted)."""
    pytest.importorskip("bpy")
    import dataclasses
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        tex = nodes.new('ShaderNodeTexImage')
        m = _mask_pixels()
        if how == "alpha":      # the mask in the alpha channel, the colour constant
            m = np.concatenate([np.full(m.shape, 0.3, np.float32), m[..., :1]], -1)
        tex.image = TS._image("M", m, non_color=True)
        p = nodes.new('ShaderNodeBsdfPrincipled')
        p.inputs["Base Color"].default_value = (0.9, 0.45, 0.1, 1.0)
        p.inputs["Roughness"].default_value = 0.35
        links.new(tex.outputs["Color" if how == "color" else "Alpha"], p.inputs["Metallic"])
        links.new(p.outputs[0], surface)

    sc, _ = TS.plane_scene(mat)
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, f"metallic_{how}")
    assert lines[1] == "Approximated: nothing.", lines[1]
    m = scene.materials[0]
    scaled = [lb for lb in m.lobes if lb.alpha_texture >= 0]
    assert len(scaled) == len(m.lobes) == 3 and sum(not lb.alpha_invert for lb in scaled) == 1
    TS._check(err, noise)
    # The map matters: every lobe at the mask's mean instead.
    f = float(scene.textures[scaled[0].alpha_texture][..., 3].mean())
    flat = dataclasses.replace(scene, materials=[dataclasses.replace(m, lobes=tuple(
        dataclasses.replace(lb, alpha_texture=-1, alpha_invert=False,
                            weight=lb.weight * ((1.0 - f) if lb.alpha_invert else f))
        for lb in m.lobes))])
    effect = np.abs((TS._fppm(flat, 1) + TS._fppm(flat, 2)) / 2 - img).mean() / ref.mean()
    print(f"metallic {how}: at the mask's mean {f:.3f} the image moves by {effect:.3f} "
          "of the mean")
    TS._check(err, noise, effect)


def _stripes(h=5, w=12):
    """A second image of another size: colour stripes across u, a ramp in v."""
    y, x = np.mgrid[0:h, 0:w] + 0.5
    y, x = y / h, x / w
    return np.stack([0.3 + 0.6 * (np.sin(6 * np.pi * x) > 0), 0.9 - 0.7 * y,
                     0.4 + 0.5 * x], -1).astype(np.float32)


@pytest.mark.parametrize("blend, fac, b_node", [("MULTIPLY", 0.8, None),
                                                ("MIX", 0.6, "hue_saturation"),
                                                ("OVERLAY", 0.7, None)])
def test_two_images_mixed_agree_with_cycles(blend, fac, b_node, tmp_path):
    """A Mix (Color) of two Image Textures of one lookup (an albedo times an
    ambient-occlusion map, a detail layer), images of different sizes (8 x 8
    and 12 x 5), the second also through its own colour node: both folded
    onto one grid, the larger one's, enlarged for a nonlinear blend
    (``_Exporter.folded``).  Before, such a Mix was not folded and the
    Diffuse kept its own colour (noted).  The effect is the image against
    the first image alone."""
    pytest.importorskip("bpy")
    import dataclasses
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = TS.diffuse_with_normal(nodes, links, surface)
        ta, tb = nodes.new('ShaderNodeTexImage'), nodes.new('ShaderNodeTexImage')
        ta.image = TS._image("A", TS._color_pixels(), non_color=False)
        tb.image = TS._image("B", _stripes(), non_color=False)
        col_b = tb.outputs["Color"]
        if b_node is not None:
            col_b = _chain(b_node)(nodes, links, col_b)
        m = nodes.new('ShaderNodeMix')
        m.data_type = 'RGBA'
        m.blend_type = blend
        m.inputs["Factor"].default_value = fac
        links.new(ta.outputs["Color"], next(i for i in m.inputs if i.identifier == "A_Color"))
        links.new(col_b, next(i for i in m.inputs if i.identifier == "B_Color"))
        links.new(next(o for o in m.outputs if o.identifier == "Result_Color"), d.inputs["Color"])

    sc, _ = TS.plane_scene(mat)
    label = f"two images {blend.lower()}"
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, label)
    assert lines[1] == "Approximated: nothing.", lines[1]
    assert len(scene.textures) == 1
    # Enlarged 8 times from the larger grid (12 x 8) for the nonlinear chains.
    want = (8, 12) if blend == "MIX" and b_node is None else (64, 96)
    assert scene.textures[0].shape[:2] == want
    TS._check(err, noise)
    raw = TS._color_pixels()
    alone = dataclasses.replace(scene, textures=[np.concatenate(
        [raw, np.ones(raw.shape[:2] + (1,), np.float32)], -1)])
    effect = np.abs((TS._fppm(alone, 1) + TS._fppm(alone, 2)) / 2 - img).mean() / ref.mean()
    print(f"{label}: the first image alone moves the image by {effect:.3f} of the mean")
    TS._check(err, noise, effect)


@pytest.mark.parametrize("how", ["invert_hsv", "mix_factor"])
def test_colour_nodes_with_a_mask_as_factor_agree_with_cycles(how, tmp_path):
    """An image's colour through colour nodes whose factors a second image
    (a grey mask at the same uvs) feeds: Invert's Fac and Hue/Saturation's
    Value (through a Math), or a Mix (Multiply) node's Factor.  The material
    is baked into an atlas, each node applied per point (the graph's
    ``color_at`` and ``mix_color`` ops); before, a fed factor cut the chain
    (the image alone, with a note).  Measured: mean |diff| 0.58 % and
    0.60 % of the mean, 0.84x and 0.85x the seed-to-seed noise."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = TS.diffuse_with_normal(nodes, links, surface)
        tex = nodes.new('ShaderNodeTexImage')
        tex.image = TS._image("C", TS._color_pixels(), non_color=False)
        mask = nodes.new('ShaderNodeTexImage')
        mask.image = TS._image("M", _mask_pixels(), non_color=True)
        if how == "mix_factor":
            m = nodes.new('ShaderNodeMix')
            m.data_type, m.blend_type = 'RGBA', 'MULTIPLY'
            links.new(mask.outputs["Color"], m.inputs["Factor"])
            links.new(tex.outputs["Color"], next(i for i in m.inputs if i.identifier == "A_Color"))
            next(i for i in m.inputs if i.identifier == "B_Color").default_value = \
                (0.2, 0.5, 0.9, 1.0)
            out = next(o for o in m.outputs if o.identifier == "Result_Color")
        else:
            inv = nodes.new('ShaderNodeInvert')
            links.new(mask.outputs["Color"], inv.inputs["Fac"])
            links.new(tex.outputs["Color"], inv.inputs["Color"])
            value = nodes.new('ShaderNodeMath')
            value.operation = 'MULTIPLY_ADD'
            value.inputs[1].default_value, value.inputs[2].default_value = 0.8, 0.5
            links.new(mask.outputs["Color"], value.inputs[0])
            hsv = nodes.new('ShaderNodeHueSaturation')
            hsv.inputs["Hue"].default_value = 0.7
            links.new(value.outputs[0], hsv.inputs["Value"])
            links.new(inv.outputs["Color"], hsv.inputs["Color"])
            out = hsv.outputs["Color"]
        links.new(out, d.inputs["Color"])

    sc, _ = TS.plane_scene(mat)
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, how)
    assert lines[1] == "Approximated: nothing.", lines[1]
    TS._check(err, noise)
