"""Render border (Ctrl+B): Blender's region size and placement, and the same pixels as a full frame.

Blender computes the border region as ``disprect.xmin = border.xmin * winx``
(a float32 product truncated to int, render/intern/pipeline.cc); a region of
another size makes ``rect.foreach_set`` fail ("expected sequence size ...").
"""
import dataclasses

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

import fppm.addon.engine as E  # noqa: E402
from fppm.addon.export import export_scene  # noqa: E402
from fppm.core.io.exr import read_exr  # noqa: E402
from fppm.core.render import Renderer, border_rect  # noqa: E402
from fppm.core.settings import RenderSettings  # noqa: E402

RES = (37, 29)      # odd sizes: most border edges fall between pixels


def _borders(n=6, seed=3):
    rng = np.random.default_rng(seed)
    out = [(0.1, 0.2, 0.7, 0.9)]            # one of the user's failing kinds
    for _ in range(n - 1):
        x = np.sort(rng.random(2))
        y = np.sort(rng.random(2))
        if x[1] - x[0] < 0.15 or y[1] - y[0] < 0.15:
            x, y = np.array([x[0] * 0.5, x[0] * 0.5 + 0.4]), np.array([y[0] * 0.5, y[0] * 0.5 + 0.4])
        out.append((float(x[0]), float(y[0]), float(x[1]), float(y[1])))
    return out


def test_border_rect_truncates_float32_products():
    # Blender: int(float32(b) * float32(n)); not floor/ceil of the float64 product.
    assert border_rect((0.25, 0.5, 0.75, 1.0), 32, 32) == (8, 16, 24, 32)
    assert border_rect((0.1, 0.2, 0.7, 0.9), 37, 29) == (3, 5, 25, 26)
    # 0.7 * 37 = 25.9: truncated to 25 (ceil gave 26, the user's size error).
    x0, y0, x1, y1 = border_rect((0.0, 0.0, 1.0, 1.0), 37, 29)
    assert (x0, y0, x1, y1) == (0, 0, 37, 29)


def _save(sc, path):
    im = sc.render.image_settings
    if hasattr(im, "media_type"):
        im.media_type = 'IMAGE'
    im.file_format, im.color_depth, im.color_mode = 'OPEN_EXR', '32', 'RGBA'
    bpy.data.images["Render Result"].save_render(filepath=str(path), scene=sc)
    return read_exr(str(path))["Combined"]


@pytest.mark.parametrize("crop", [True, False])
def test_random_borders_render_at_blenders_size(crop, tmp_path):
    tmp = tmp_path
    sc = H.simple_scene(res=RES, passes=1, photons=2000)
    r = sc.render
    r.use_border, r.use_crop_to_border = True, crop
    for i, b in enumerate(_borders()):
        r.border_min_x, r.border_min_y, r.border_max_x, r.border_max_y = b
        sess = E.RenderSession(log=lambda m: None)
        with E.session(sess):
            bpy.ops.render.render()
        assert sess.error is None, (b, sess.error)
        x0, y0, x1, y1 = border_rect(b, *RES)
        img = sess.result.image
        assert img.shape == (y1 - y0, x1 - x0, 4), b
        saved = _save(sc, tmp / f"b{i}.exr")
        if crop:
            # Blender's own result (its disprect) has exactly our size.
            assert saved.shape == img.shape, b
            assert np.array_equal(saved, img)
        else:
            # Uncropped: Blender pastes the region at its place in the frame
            # (rows from the top: H - y1 .. H - y0), black elsewhere.
            Hf = RES[1]
            assert saved.shape == (Hf, RES[0], 4)
            assert np.array_equal(saved[Hf - y1:Hf - y0, x0:x1], img), b
            rest = saved.copy()
            rest[Hf - y1:Hf - y0, x0:x1] = 0
            assert not np.any(rest[..., :3]), b


@pytest.fixture(scope="module")
def exported():
    sc = H.simple_scene(res=RES, passes=1, photons=2000)
    H.set_world(sc, (0.1, 0.1, 0.15))
    return export_scene(H.evaluated_depsgraph(), log=lambda m: None)


def _render(scene, border, seed, passes=8):
    cam = dataclasses.replace(scene.camera, border=border)
    s = dataclasses.replace(scene, camera=cam)
    st = RenderSettings(integrator="PHOTON", max_passes=passes, photons_per_pass=20000, seed=seed)
    r = Renderer(s, st, log=lambda m: None, passes=("Depth", "Normal"))
    return r, r.run()


def test_border_pixels_are_the_full_frames(exported):
    """A border region against the same pixels of a full frame (same seed).

    The camera samples are drawn per absolute pixel (CameraPass), so the
    visible points -- and every first-hit pass -- are the full frame's exactly.
    The direct light's and the specular choices' streams are drawn per visible
    point of the region, so the radiance agrees within noise: measured, the
    RMS difference border vs full frame (same seed) is at most the RMS
    difference of two full frames of different seeds (independent noise), and
    the region means agree within 4 sigma of that noise.
    """
    for b in _borders(4, seed=11):
        x0, y0, x1, y1 = border_rect(b, *RES)
        Hf = RES[1]
        rows, cols = slice(Hf - y1, Hf - y0), slice(x0, x1)
        _, full = _render(exported, None, seed=5)
        _, full2 = _render(exported, None, seed=6)
        _, part = _render(exported, b, seed=5)
        for name in ("Depth", "Normal"):
            assert np.array_equal(part.aovs[name], full.aovs[name][rows, cols]), (b, name)
        L_part, L_full = part.image[..., :3], full.image[rows, cols, :3]
        noise = full.image[rows, cols, :3] - full2.image[rows, cols, :3]
        rms_noise = np.sqrt(np.mean(noise ** 2))
        assert rms_noise > 0
        assert np.sqrt(np.mean((L_part - L_full) ** 2)) <= 1.0 * rms_noise + 1e-6, b
        sigma_mean = rms_noise / np.sqrt(noise.size)
        assert abs(L_part.mean() - L_full.mean()) < 4 * sigma_mean, b
