"""The Cycles references of the test scenes: present, consistent, and equal to
the analytic radiance values of docs/cycles_units.md within their own noise.

Nothing here needs the FPPM core.  References are made by
tests/references/make_references.py from tests/scenes/*.blend
(tests/scenes/make_test_scenes.py).
"""
import json
import math
import os
import sys

import numpy as np
import pytest

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:          # conftest.py only adds the repo root
    sys.path.insert(0, TESTS)

from scenes import refs  # noqa: E402
from scenes.refs import load_reference, load_variance  # noqa: E402

SCENES = ["t_cornell", "t_mirror_caustic", "t_glass_caustic", "t_glossy_floor",
          "t_light_point", "t_light_spot", "t_light_sun", "t_light_area_square",
          "t_light_area_disk", "t_light_area_ellipse", "t_light_mesh", "t_world"]

CHECKS = [(name, i) for name in SCENES
          for i in range(len(json.load(open(os.path.join(
              refs.REFERENCES_DIR, name + ".json")))["analytic"]))
          if os.path.exists(os.path.join(refs.REFERENCES_DIR, name + ".json"))]


@pytest.mark.parametrize("name", SCENES)
def test_reference_files_exist_and_are_commit_sized(name):
    for path in (refs.scene_path(name),
                 os.path.join(refs.REFERENCES_DIR, name + ".exr"),
                 os.path.join(refs.REFERENCES_DIR, name + "_var.exr"),
                 os.path.join(refs.REFERENCES_DIR, name + ".json")):
        assert os.path.isfile(path), path
        assert os.path.getsize(path) < 1_000_000, path


@pytest.mark.parametrize("name", SCENES)
def test_reference_metadata_consistent(name):
    img, meta = load_reference(name)
    var = load_variance(name)
    W, H = meta["resolution"]
    assert img.shape == (H, W, 4) and img.dtype == np.float32
    assert var.shape == (H, W, 3) and var.dtype == np.float32
    assert np.isfinite(img).all() and (img[..., :3] >= 0).all()
    assert np.all(img[..., 3] == 1.0)          # opaque film
    assert (var >= 0).all()
    # Settings of a reference (blender.md, "For a reference").
    # Cycles' default filter; its support is +-width (Cycles doubles the
    # Blackman-Harris width internally, refs.blackman_harris).
    assert meta["filter"]["type"] == "BLACKMAN_HARRIS"
    assert meta["filter"]["width_px"] == 1.5
    assert meta["filter"]["support_px"] == [-1.5, 1.5]
    assert meta["filter"]["std_px"] == pytest.approx(0.4155, abs=1e-3)
    cy = meta["cycles"]
    assert cy["device"] == "CPU" and cy["view_transform"] == "Standard"
    assert cy["caustics_reflective"] and cy["caustics_refractive"]
    assert cy["blur_glossy"] == 0 and cy["light_sampling_threshold"] == 0
    assert cy["sample_clamp_direct"] == 0 and cy["sample_clamp_indirect"] == 0
    assert not cy["use_adaptive_sampling"] and not cy["use_denoising"]
    # Two halves with distinct seeds make up the sample count.
    seeds = [h["seed"] for h in meta["halves"]]
    assert len(set(seeds)) == 2 and seeds == meta["seeds"]
    assert sum(h["samples"] for h in meta["halves"]) == meta["samples"]
    assert meta["render_time_s"] == pytest.approx(
        sum(h["render_time_s"] for h in meta["halves"]), abs=0.01)
    # Stored statistics are those of the stored images (float32 storage:
    # relative 1e-5).
    mean = img[..., :3].astype(np.float64).mean(axis=(0, 1))
    np.testing.assert_allclose(meta["mean_radiance"], mean, rtol=1e-5)
    relmse = np.mean(var / (img[..., :3].astype(np.float64) ** 2 + refs.RELMSE_EPS))
    assert meta["noise"]["relmse"] == pytest.approx(relmse, rel=1e-4)
    assert meta["triangles"] <= 400


@pytest.mark.parametrize("name", SCENES)
def test_reference_noise_is_small(name):
    """A reference is useful for agreement tests only if its own error is far
    below what the renderer is asked to match.  Bounds from the measured
    values (tests/references/*.json) with a 3x margin: the noisiest are the
    caustic scenes, relMSE 3.3e-4 (glass) and image-mean std 0.05 %
    (mirror); every other scene is below relMSE 1e-4."""
    _, meta = load_reference(name)
    assert meta["noise"]["relmse"] < 1e-3
    assert max(meta["noise"]["rel_std_image_mean"]) < 1.5e-3


@pytest.mark.parametrize("name,index", CHECKS)
def test_reference_matches_analytic_value(name, index):
    """Mean over the check's pixels within 5 sigma of the reference's own
    noise plus a model allowance (see refs.check_agreement for the
    derivation), against values recomputed here from the stored parameters."""
    img, meta = load_reference(name)
    var = load_variance(name)
    check = meta["analytic"][index]
    assert len(check["pixels"]) >= 10
    # The generator's expected values equal the formula recomputed now.
    np.testing.assert_allclose(
        np.broadcast_to(check["expected"], refs.expected_values(
            check, meta["camera"], meta["filter"]["width_px"]).shape),
        refs.expected_values(check, meta["camera"], meta["filter"]["width_px"]),
        rtol=1e-9)
    meas, expm, tol = refs.check_agreement(img, var, check, meta)
    assert np.all(np.abs(meas - expm) <= tol), (meas, expm, tol)


def _check(name, kind):
    img, meta = load_reference(name)
    return img, load_variance(name), next(c for c in meta["analytic"]
                                          if c["kind"] == kind), meta


def _exact_rtol(meta):
    """Deterministic pixels (camera ray hits an emitter / the sky): exact up
    to Cycles' float32 accumulation of the samples, n * 2^-24 relative
    (refs.F32_EPS), plus 1e-6 for float32 storage."""
    return max(h["samples"] for h in meta["halves"]) * refs.F32_EPS + 1e-6


def test_point_light_foot_point_value():
    """blender.md: point P = 100 W, h = 1 m, rho = 0.8 -> rho P / (4 pi^2 h^2)
    = 2.026424 at the foot point (the notes quote 2.026118, 1.5e-4 lower).
    The reference's pixels around the foot point equal that field integrated
    over Cycles' 3 px wide filter (which alone lowers them by ~0.2 %: the
    field's curvature 3/h^2 times the 0.42 px filter std on 5-7 cm pixels)."""
    foot = refs.point_lambert([[0, 0, 0]], 100.0, 0.8, [0, 0, 1])[0]
    assert foot == pytest.approx(0.8 * 100 / (4 * math.pi ** 2), rel=1e-12)
    assert foot == pytest.approx(2.026118, rel=2e-4)
    img, var, chk, meta = _check("t_light_point", "point_lambert")
    center = dict(chk, pixels=[[31, 31], [31, 32], [32, 31], [32, 32]])
    filtered = refs.expected_values(center, meta["camera"], 1.5)
    # The 4 centre pixels straddle the foot point: within 0.5 % of it.
    assert np.all(np.abs(filtered / foot - 1) < 5e-3)
    # Measured: formula + box interreflection (bounded by indirect_bound)
    # within 5 sigma (refs.check_agreement).
    meas, expm, tol = refs.check_agreement(img, var, center, meta)
    assert abs(meas - expm) <= tol, (meas, expm, tol)


def test_sun_value():
    """blender.md: sun S = 3 at 40 deg elevation, rho = 0.6 -> 0.36829."""
    assert refs.sun_lambert(3.0, 0.6, 40.0) == pytest.approx(0.36829, abs=1e-5)
    img, var, chk, meta = _check("t_light_sun", "sun_lambert")
    meas, expm, tol = refs.check_agreement(img, var, chk, meta)
    # expm is the middle of [formula, formula * (1 + indirect_bound)].
    assert expm == pytest.approx(0.36829 * (1 + chk["indirect_bound"] / 2), abs=1e-5)
    assert abs(meas - expm) <= tol
    assert tol < 1e-3 * expm               # a sharp check: 1408 pixels
    assert len(chk["pixels"]) > 500        # a large unshadowed floor region


def test_area_light_seen_directly_is_50_over_pi():
    """blender.md: a 1 m^2, 50 W area light seen directly -> 50/pi.  Camera
    rays hit the light deterministically: zero variance."""
    img, var, chk, meta = _check("t_light_area_square", "emitter_seen")
    assert chk["area"] == 1.0 and chk["P"] == 50.0
    pix = np.asarray(chk["pixels"])
    np.testing.assert_allclose(img[pix[:, 0], pix[:, 1], :3], 50 / math.pi,
                               rtol=_exact_rtol(meta))
    assert np.all(var[pix[:, 0], pix[:, 1]] < 1e-6)


@pytest.mark.parametrize("name,shape_area", [
    ("t_light_area_disk", math.pi * 1.2 ** 2 / 4),
    ("t_light_area_ellipse", math.pi * 1.4 * 0.8 / 4)])
def test_area_light_shapes_radiance(name, shape_area):
    """L = P / (pi A) with A = pi size^2 / 4 (disk), pi size size_y / 4
    (ellipse); deterministic pixels as above."""
    img, var, chk, meta = _check(name, "emitter_seen")
    assert chk["area"] == pytest.approx(shape_area, rel=1e-12)
    pix = np.asarray(chk["pixels"])
    np.testing.assert_allclose(img[pix[:, 0], pix[:, 1], :3],
                               50 / (math.pi * shape_area), rtol=_exact_rtol(meta))


def test_emission_quad_seen_directly():
    """Emission shader: L = Color * Strength = (10, 9, 8), two-sided."""
    img, var, chk, meta = _check("t_light_mesh", "emitter_seen")
    pix = np.asarray(chk["pixels"])
    np.testing.assert_allclose(img[pix[:, 0], pix[:, 1], :3],
                               np.broadcast_to([10.0, 9.0, 8.0], (len(pix), 3)),
                               rtol=_exact_rtol(meta))


def test_world_background_seen_directly():
    img, var, chk, meta = _check("t_world", "world_seen")
    pix = np.asarray(chk["pixels"])
    assert len(pix) > 1000
    np.testing.assert_allclose(img[pix[:, 0], pix[:, 1], :3],
                               np.broadcast_to([0.4, 0.5, 0.7], (len(pix), 3)),
                               rtol=_exact_rtol(meta))


def test_image_orientation_row0_top():
    """Row 0 is the top: the light's pixels were found by casting camera rays
    with row 0 at the top of the frame (make_references.Rays), they lie in
    the upper half, and the image holds 50/pi there but not at the
    vertically mirrored pixels (floor)."""
    img, _ = load_reference("t_light_area_square")
    _, _, chk, _ = _check("t_light_area_square", "emitter_seen")
    pix = np.asarray(chk["pixels"])
    H = img.shape[0]
    assert pix[:, 0].max() < H // 2
    np.testing.assert_allclose(img[pix[:, 0], pix[:, 1], 0], 50 / math.pi, rtol=1e-3)
    assert np.all(img[H - 1 - pix[:, 0], pix[:, 1], 0] < 0.5 * 50 / math.pi)


def test_filter_quadrature_matches_cycles_filter():
    """The analytic pixel values integrate against Cycles' Blackman-Harris
    filter with support +-1.5 px: weights sum to 1, std 0.4155 px (twice the
    std a +-0.75 px window would have)."""
    offs, w = refs.filter_quadrature(1.5)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.abs(offs).max() < 1.5
    assert math.sqrt((w * offs[:, 0] ** 2).sum()) == pytest.approx(0.4155, abs=1e-3)
    assert refs.blackman_harris(1.6) == 0.0 and refs.blackman_harris(0.0) == pytest.approx(1.0)


def test_blend_files_are_set_up_for_references():
    """The .blend scenes carry the reference settings and explicit light
    visibility (bpy objects made through bpy.data default to
    visible_camera = False in 5.2)."""
    bpy = pytest.importorskip("bpy")
    for name in SCENES:
        bpy.ops.wm.open_mainfile(filepath=refs.scene_path(name), load_ui=False,
                                 use_scripts=False)
        sc = bpy.context.scene
        assert sc.render.engine == 'CYCLES'
        assert (sc.render.resolution_x, sc.render.resolution_y) == (64, 64)
        assert sc.render.resolution_percentage == 100
        assert sc.cycles.caustics_reflective and sc.cycles.caustics_refractive
        assert sc.cycles.filter_width == 1.5
        spec = json.loads(sc["fppm_test"])
        assert spec["triangles"] <= 400
        for ob in sc.objects:
            if ob.type == 'LIGHT':
                assert ob.visible_diffuse and ob.visible_glossy
                assert ob.visible_transmission and ob.visible_shadow
                if ob.data.type == 'AREA':
                    assert ob.visible_camera


EXAMPLES_DIR = os.path.join(os.path.dirname(TESTS), "example_blends")
EXAMPLES = ["cornell", "coffee_cup", "glass_sphere", "point_caustic",
            "indirect_room", "ring_lambert", "ring_principled", "principled_interior"]


def _open_example(bpy, name):
    path = os.path.join(EXAMPLES_DIR, name + ".blend")
    assert os.path.getsize(path) < 1_000_000
    import bpy_helpers
    bpy_helpers.ensure_registered()      # else Blender replaces the unknown engine by EEVEE
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    # Saved with FPPM as the engine; the Cycles settings for references stay in the file.
    assert sc.render.engine == 'FPPM'
    assert (sc.render.resolution_x, sc.render.resolution_y) == (128, 128)
    assert sc.cycles.caustics_reflective and sc.cycles.caustics_refractive
    assert sc.cycles.blur_glossy == 0 and sc.camera is not None
    return sc


def _first_hits(sc, offsets=(-0.75, 0.0, 0.75)):
    """First hit (object name or None, location, ray direction) of camera
    rays through every pixel at offsets covering the 1.5 px filter."""
    from references.make_references import Rays
    rays = Rays(sc)
    for r in range(rays.H):
        for c in range(rays.W):
            for dy in offsets:
                for dx in offsets:
                    d = rays.direction(r, c, dy, dx)
                    name, loc = rays.cast(d)
                    yield name, loc, d


def test_example_files():
    bpy = pytest.importorskip("bpy")
    for name in EXAMPLES:
        _open_example(bpy, name)


def test_point_caustic_camera_sees_only_diffuse_surfaces():
    """point_caustic.blend must be renderable by a light tracer as reference:
    every camera ray (with the filter's spread) first hits a surface whose
    material is a single Diffuse BSDF."""
    bpy = pytest.importorskip("bpy")
    sc = _open_example(bpy, "point_caustic")
    lights = [o for o in sc.objects if o.type == 'LIGHT']
    assert len(lights) == 1 and lights[0].data.type == 'POINT'
    assert lights[0].data.shadow_soft_size == 0.0
    seen = set()
    for name, _, _ in _first_hits(sc, offsets=(-0.75, 0.75)):
        if name is not None:
            seen.add(name)
    assert seen and "GlassSphere" not in seen
    for name in seen:
        nodes = sc.objects[name].active_material.node_tree.nodes
        kinds = {n.type for n in nodes} - {'OUTPUT_MATERIAL'}
        assert kinds == {'BSDF_DIFFUSE'}, (name, kinds)


def test_indirect_room_lit_patch_not_visible():
    """indirect_room.blend (paper Fig. 6): no surface point seen by the
    camera receives direct light from the spot (inside its cone and
    unoccluded), so every visible pixel is lit by bounces only."""
    bpy = pytest.importorskip("bpy")
    from mathutils import Vector
    sc = _open_example(bpy, "indirect_room")
    spot = next(o for o in sc.objects if o.type == 'LIGHT')
    assert spot.data.type == 'SPOT'
    sp = spot.matrix_world.translation
    axis = spot.matrix_world.to_3x3() @ Vector((0, 0, -1))
    cos_half = math.cos(spot.data.spot_size / 2)
    dg = bpy.context.evaluated_depsgraph_get()
    n_lit = n_seen = 0
    for name, loc, d in _first_hits(sc, offsets=(-0.75, 0.75)):
        assert name is not None                      # closed room
        n_seen += 1
        to_p = loc - sp
        if to_p.normalized().dot(axis) <= cos_half:
            continue
        # Inside the cone: lit unless something is in between.
        hit, hloc, *_ = sc.ray_cast(dg, sp, to_p.normalized(),
                                    distance=to_p.length - 1e-3)
        if not hit:
            n_lit += 1
    assert n_seen == 128 * 128 * 4
    assert n_lit == 0
