"""A roughness map read per hit (core/materials/rough_maps.py): a mapped
material's level rows in the MaterialTable, the dithered pick of a hit's
level, and the map against Cycles (a Principled metal and a Glossy BSDF under
a sun, Photon Mapping and Path Tracing)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.materials import build_material_table
from core.materials import rough_maps as RM
from core.scene.model import DIFFUSE, GLOSSY, Lobe, Material
from core.scene.nodes import principled_to_lobes


def test_levels_span_the_roughness_range_in_log_alpha():
    k = np.arange(RM.ROUGH_LEVELS)
    r = RM.level_roughness(k)
    assert r[0] == pytest.approx(RM.ROUGH_MIN) and r[-1] == pytest.approx(1.0)
    np.testing.assert_allclose(RM.level_position(r), k, atol=1e-9)
    # One step in alpha = r^2 is a constant ratio.
    ratio = (r[1:] / r[:-1]) ** 2
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)
    assert ratio[0] < 1.04
    # Below ROUGH_MIN (and NaN-free clipping above 1): the end levels.
    np.testing.assert_allclose(RM.level_position([0.0, 0.005, 2.0]),
                               [0, 0, RM.ROUGH_LEVELS - 1], atol=1e-9)


def _mapped(tex=0):
    lobes, _, _ = principled_to_lobes(base_color=(0.8, 0.5, 0.2), roughness=0.004,
                                      roughness_texture=tex)
    return Material("mapped", lobes)


def test_append_levels_adds_the_rows_of_a_mapped_material():
    plain = Material("plain", (Lobe(DIFFUSE, (0.5, 0.5, 0.5)),))
    mats = [plain, _mapped(), plain]
    t = build_material_table(mats, [np.full((2, 2, 4), 0.5, np.float32)])
    n = len(mats)
    assert t.kind.shape[0] == n + RM.ROUGH_LEVELS
    assert list(t.rough_first[:n]) == [-1, n, -1] and (t.rough_first[n:] == -1).all()
    assert t.rough_tex[1] == 0
    # Principled: specular (GLOSSY) and diffuse under it; the specular's
    # roughness and the diffuse's layer roughness follow the map.
    j_spec = int(np.nonzero(t.kind[1] == GLOSSY)[0][0])
    j_diff = int(np.nonzero(t.kind[1] == DIFFUSE)[0][0])
    levels = RM.level_roughness(np.arange(RM.ROUGH_LEVELS))
    np.testing.assert_allclose(t.roughness[n:, j_spec], levels)
    np.testing.assert_allclose(t.layer_roughness[n:, j_diff], levels)
    assert (t.roughness[n:, j_diff] == t.roughness[1, j_diff]).all()
    # The material's own row: the mean (0.004) raised to ROUGH_MIN; no row is
    # a delta lobe, so a hit's flags do not depend on its level.
    assert t.roughness[1, j_spec] == pytest.approx(RM.ROUGH_MIN)
    assert not t.has_delta[1:n + RM.ROUGH_LEVELS].any()
    for f in ("color", "weight", "kind", "tex", "fresnel_ior"):
        a = getattr(t, f)
        assert (a[n:] == a[1]).all(), f
    # Without a map: no level rows, no rough_first.
    assert build_material_table([plain], []).rough_first is None


@pytest.mark.parametrize("r", [0.013, 0.37, 0.9])
def test_pick_takes_the_two_nearest_levels_in_proportion(r):
    """The pick of many hits on a constant map: only the two levels around
    r, the upper one with probability frac(level_position(r)) (a binomial
    test at 4 standard deviations), so the expected BSDF interpolates
    between them."""
    img = np.ones((4, 4, 4), np.float32)
    img[..., 3] = r
    t = build_material_table([_mapped()], [img])
    rng = np.random.default_rng(5)
    K = 200_000
    prim = rng.integers(0, 1000, K)
    bu, bv = rng.random(K).astype(np.float32), rng.random(K).astype(np.float32)
    uv = rng.random((K, 2))
    k = RM.pick(t, np.zeros(K, np.int64), prim, bu, bv, uv) - t.rough_first[0]
    x = float(RM.level_position(r))
    lo = int(np.floor(x))
    assert set(np.unique(k)) <= {lo, lo + 1}
    p = x - lo
    got = float(np.mean(k == lo + 1))
    assert abs(got - p) < 4.0 * np.sqrt(p * (1 - p) / K) + 1e-9, (got, p)
    # The same hit picks the same level in any stage.
    again = RM.pick(t, np.zeros(K, np.int64), prim, bu, bv, uv) - t.rough_first[0]
    assert np.array_equal(k, again)


def test_dither_is_uniform():
    """Chi-square of the hash over 64 bins (prim, bu, bv of random hits)."""
    rng = np.random.default_rng(11)
    K, B = 256_000, 64
    u = RM.dither(rng.integers(0, 50_000, K), rng.random(K).astype(np.float32),
                  rng.random(K).astype(np.float32))
    counts = np.bincount((u * B).astype(np.int64), minlength=B)
    chi2 = float(((counts - K / B) ** 2 / (K / B)).sum())
    # 63 degrees of freedom: the 99.9 % quantile is 103.4.
    assert 0.0 <= u.min() and u.max() < 1.0 and chi2 < 103.4, chi2


# ------------------------------------------------------------------ Cycles

def _rough_pixels(n=8):
    """A roughness map: smooth stripes from 0.05 to 0.85 across u, a ramp in v."""
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    g = 0.05 + 0.8 * (0.5 + 0.5 * np.sin(2 * np.pi * x)) * (0.4 + 0.6 * y)
    return np.repeat(g[..., None], 3, -1).astype(np.float32)


@pytest.mark.parametrize("how, integrator", [("principled", "PHOTON"),
                                             ("glossy", "PHOTON"),
                                             ("principled", "PATH")])
def test_a_roughness_map_agrees_with_cycles(how, integrator, tmp_path, monkeypatch):
    """A roughness map (an image's Color) into a Principled metal (orange)
    or a Glossy BSDF on tests/test_shading_nodes.py's plane under a sun
    near the zenith, seen straight down: the highlight's width follows the
    map.  Against Cycles, two seeds each, under that file's bound.  The
    map's mean roughness, what FPPM read before, is the effect."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        tex = nodes.new('ShaderNodeTexImage')
        tex.image = TS._image("R", _rough_pixels(), non_color=True)
        if how == "principled":
            b = nodes.new('ShaderNodeBsdfPrincipled')
            b.inputs["Base Color"].default_value = (0.9, 0.5, 0.15, 1.0)
            b.inputs["Metallic"].default_value = 1.0
        else:
            b = nodes.new('ShaderNodeBsdfGlossy')
            b.inputs["Color"].default_value = (0.3, 0.6, 0.9, 1.0)
        links.new(tex.outputs["Color"], b.inputs["Roughness"])
        links.new(b.outputs[0], surface)

    # The sun 20 degrees from the zenith: the highlight fills the view.
    sc, _ = TS.plane_scene(mat, sun_rotation=(0.25, 0.22, 0.0))
    if integrator == "PATH":
        def fppm(scene, seed, photons=2000):
            from fppm.core.render import Renderer
            from fppm.core.settings import RenderSettings
            st = RenderSettings(integrator="PATH", max_passes=16, seed=seed, max_bounces=4)
            return Renderer(scene, st, log=lambda s: None).run().image[..., :3].astype(
                np.float64)
        monkeypatch.setattr(TS, "_fppm", fppm)
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, f"rough map {how} {integrator}")
    assert lines[1] == "Approximated: nothing.", lines[1]
    m = scene.materials[0]
    assert all(lb.roughness_texture >= 0 for lb in m.lobes)
    TS._check(err, noise)
    flat = dataclasses.replace(scene, materials=[dataclasses.replace(m, lobes=tuple(
        dataclasses.replace(lb, roughness_texture=-1) for lb in m.lobes))])
    effect = np.abs((TS._fppm(flat, 1) + TS._fppm(flat, 2)) / 2 - img).mean() / ref.mean()
    print(f"rough map {how} {integrator}: at the mean roughness the image moves by "
          f"{effect:.3f} of the mean")
    TS._check(err, noise, effect)


def _bands(n=16):
    """A roughness map of bands across u: 0.15 and 0.5 in turn (smoothed by
    the bilinear lookup), a different width each."""
    x = (np.arange(n) + 0.5) / n
    g = np.where(np.sin(2 * np.pi * 2.5 * x ** 1.3) > 0, 0.15, 0.5)
    return np.repeat(np.tile(g[None, :], (n, 1))[..., None], 3, -1).astype(np.float32)


def wall_scene(res=None):
    """The bpy scene of :func:`test_light_reflected_by_a_roughness_map_agrees_with_cycles`
    (res: its square resolution, tests/test_shading_nodes.py's RES by
    default; bench/bench_rough_maps.py times renders of it)."""
    import math

    import bpy
    import test_shading_nodes as TS
    from scenes import bpy_kit as K
    res = TS.RES if res is None else res
    sc = K.reset_scene((res, res))
    sc.render.engine = 'CYCLES'
    m, nt, out = K._new_material("Floor")
    tex = nt.nodes.new('ShaderNodeTexImage')
    tex.image = TS._image("R", _bands(), non_color=True)
    b = nt.nodes.new('ShaderNodeBsdfPrincipled')
    b.inputs["Base Color"].default_value = (0.95, 0.9, 0.8, 1.0)
    b.inputs["Metallic"].default_value = 1.0
    nt.links.new(tex.outputs["Color"], b.inputs["Roughness"])
    nt.links.new(b.outputs[0], out.inputs["Surface"])
    floor = K.plane("Floor", 2.0, m)
    uvl = floor.data.uv_layers.new(name="UVMap")
    for loop in floor.data.loops:
        co = floor.data.vertices[loop.vertex_index].co
        uvl.data[loop.index].uv = (0.5 * (co.x + 1.0), 0.5 * (co.y + 1.0))
    K.plane("Wall", 2.0, K.material("White", "DIFFUSE", color=(0.8, 0.8, 0.8)),
            location=(0.9, 0.0, 1.0), rotation=(0.0, -math.pi / 2, 0.0))
    cam_d = bpy.data.cameras.new("Cam")
    cam_d.type = 'ORTHO'
    cam_d.ortho_scale = 1.2
    cam = bpy.data.objects.new("Cam", cam_d)
    cam.location = (0.0, 0.0, 1.0)
    cam.rotation_euler = (math.pi / 2, 0.0, -math.pi / 2)     # looking along +x
    K.link(cam)
    sc.camera = cam
    ld = bpy.data.lights.new("Sun", 'SUN')
    ld.energy = 3.0
    ld.angle = 0.1          # Cycles' paths then find the sun through the floor
    sun = bpy.data.objects.new("Sun", ld)
    sun.rotation_euler = (0.0, -math.pi / 4, 0.0)    # light along (+x, -z) / sqrt 2
    K.link(sun)
    return sc


def test_light_reflected_by_a_roughness_map_agrees_with_cycles(tmp_path):
    """The camera sees only a white diffuse wall, lit by a sun directly and
    by its reflection off a metal floor whose roughness map has bands of
    0.15 and 0.5: the reflected light on the wall is sharp bands and broad
    glows, so it is what photons bouncing off the floor (and Cycles' paths
    through it) make of the map.  Photon Mapping against Cycles, two seeds
    each; the floor at its mean roughness is the
    effect.  The sun is 5.7 degrees wide and Cycles takes 4096 samples: a
    delta sun seen through the floor left Cycles' rows 11 % noisy at 512.
    Compared by rows (the bands run across the wall)."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS
    sc = wall_scene()
    scene, lines = TS._export()
    assert lines[1] == "Approximated: nothing.", lines[1]
    # The bands run across the wall (the map varies along the floor's x, the
    # reflection's height on the wall): compared by rows, each the mean of
    # a row of 32 pixels.
    rows = lambda a: a.mean(axis=(1, 2))     # noqa: E731
    c = [rows(TS._cycles(sc, k, tmp_path / f"c{k}.exr", 4096)) for k in (0, 1)]
    f = [rows(TS._fppm(scene, k, 40000)) for k in (1, 2)]
    ref, img = (c[0] + c[1]) / 2, (f[0] + f[1]) / 2
    err = np.abs(img - ref).mean() / ref.mean()
    noise = (np.abs(f[0] - f[1]).mean() + np.abs(c[0] - c[1]).mean()) / 2 / ref.mean()
    print(f"reflected rough map, by rows: mean {img.mean():.4f} vs Cycles {ref.mean():.4f}; "
          f"mean |diff| {err:.4f} of the mean, seed-to-seed noise {noise:.4f}")
    TS._check(err, noise)
    fm = next(i for i, mm in enumerate(scene.materials) if mm.name == "Floor")
    mats = list(scene.materials)
    mats[fm] = dataclasses.replace(mats[fm], lobes=tuple(
        dataclasses.replace(lb, roughness_texture=-1) for lb in mats[fm].lobes))
    flat = dataclasses.replace(scene, materials=mats)
    flat_rows = (rows(TS._fppm(flat, 1, 40000)) + rows(TS._fppm(flat, 2, 40000))) / 2
    effect = np.abs(flat_rows - img).mean() / ref.mean()
    print(f"reflected rough map: the floor at its mean roughness moves the rows by "
          f"{effect:.3f} of the mean")
    TS._check(err, noise, effect)


def test_two_roughness_maps_in_one_material_keep_the_first():
    """A Mix Shader of two Glossy BSDFs, each with its own roughness map:
    the first map is read per hit, the second lobe keeps its map's mean,
    said in the Approximated line (one map a material: rough_maps)."""
    pytest.importorskip("bpy")
    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        mix = nodes.new('ShaderNodeMixShader')
        for k, px in ((1, _rough_pixels()), (2, _bands())):
            g = nodes.new('ShaderNodeBsdfGlossy')
            g.inputs["Color"].default_value = (0.8, 0.6 if k == 1 else 0.2, 0.3, 1.0)
            tex = nodes.new('ShaderNodeTexImage')
            tex.image = TS._image(f"R{k}", px, non_color=True)
            links.new(tex.outputs["Color"], g.inputs["Roughness"])
            links.new(g.outputs[0], mix.inputs[k])
        links.new(mix.outputs[0], surface)

    TS.plane_scene(mat)
    scene, lines = TS._export()
    assert "2 roughness maps: the first read per hit, the others at their mean" in lines[1]
    maps = [lb.roughness_texture for lb in scene.materials[0].lobes]
    assert sorted(maps)[0] == -1 and sum(t >= 0 for t in maps) == 1
    t = build_material_table(scene.materials, scene.textures)
    assert t.rough_first is not None and t.kind.shape[0] == 1 + RM.ROUGH_LEVELS
