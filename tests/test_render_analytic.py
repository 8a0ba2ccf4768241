"""The renderer against closed-form radiance (analytic scenes, furnace).

Tolerances: each test measures its own noise from two seeds.  The per-pixel
noise sigma_pix^2 = var(I1 - I2) / 2; neighbouring pixels share photons over a
kernel of ~pi R^2 pixels, so the region mean's sigma is taken as
sigma_pix * sqrt(pi R_px^2 / n_pixels) (conservative for R_px >= 1; next-event
noise is independent per pixel, so R_px = 1 where it dominates).  Each test
asserts sigma < 0.6% first, so the 2% the issue asks for is a >= 3.3 sigma
bound (false-failure odds < 1e-3) that still detects a 2% bias.
Kernel bias on these smooth fields is second order: for L ~ (r^2 + h^2)^-1.5
the disc average at the peak is L0 (1 - 0.75 R^2/h^2), -0.5% for R = 1 px
footprint (0.083 m) at h = 1 m, so photon-only runs use initial_radius_px=1.
"""
import numpy as np
import pytest

from core.render import Renderer
from core.settings import RenderSettings

from analytic_scenes import (area_light_plane, furnace_box, mirror_caustic,
                             pixel_centres_ortho, point_light_plane)


def render(scene, **kw):
    st = RenderSettings(**{"integrator": "PHOTON",
                           "max_passes": 8, "photons_per_pass": 60_000, "use_frequency": False,
                           **kw})
    r = Renderer(scene, st, log=lambda s: None)
    return r.run().image[..., :3].astype(np.float64)


def region_stats(a, b, mask, r_px=2.0):
    """Mean over mask of the average of two seeds, and its noise sigma."""
    m = 0.5 * (a + b)
    d = (a - b)[mask]
    sigma_pix = np.sqrt(np.var(d) / 2.0)
    n = mask.sum()
    sigma_mean = sigma_pix / np.sqrt(2.0) * np.sqrt(max(np.pi * r_px ** 2, 1.0) / n)
    return m[mask].mean(), sigma_mean


@pytest.mark.parametrize("photons_for_direct", [False, True])
def test_point_light_plane(photons_for_direct):
    scene, Lfun = point_light_plane(res=24)
    X, Y = pixel_centres_ortho(scene)
    expected = Lfun(X, Y)
    kw = dict(photons_for_direct=photons_for_direct, initial_radius_px=1.0,
              photons_per_pass=120_000)
    a = render(scene, seed=1, **kw)
    b = render(scene, seed=2, **kw)
    mask = np.ones(expected.shape, bool)
    mean, sigma = region_stats(a.mean(axis=2), b.mean(axis=2), mask)
    assert sigma < 0.006 * expected.mean()
    assert abs(mean / expected.mean() - 1) < 0.02
    # Per pixel: the foot point region (centre 4x4) within 2% too.
    c = slice(10, 14)
    got = 0.5 * (a + b)[c, c].mean()
    assert abs(got / expected[c, c].mean() - 1) < 0.02
    if not photons_for_direct:
        # Next-event estimation of a point light has no noise but the pixel
        # filter's jitter (8 filter samples per pixel, gradients up to 8% per
        # pixel): that averages out over the image to well under 0.5%.
        assert abs(a.mean() / expected.mean() - 1) < 0.005


def test_area_light_plane():
    scene, Lfun = area_light_plane(res=24)
    X, Y = pixel_centres_ortho(scene)
    expected = Lfun(X, Y)
    kw = dict(photons_for_direct=True, initial_radius_px=1.0, photons_per_pass=120_000)
    a = render(scene, seed=1, **kw)
    b = render(scene, seed=2, **kw)
    mean, sigma = region_stats(a.mean(axis=2), b.mean(axis=2), np.ones(expected.shape, bool),
                               r_px=1.0)
    assert sigma < 0.006 * expected.mean()
    assert abs(mean / expected.mean() - 1) < 0.02
    # NEE of the area light: unbiased, noise only.
    c = render(scene, seed=3, photons_for_direct=False)
    assert abs(c.mean() / expected.mean() - 1) < 0.02


def test_mirror_caustic_point_light():
    """Cycles cannot render this; the image-light closed form can."""
    scene, Lfun, half = mirror_caustic(res=24)
    X, Y = pixel_centres_ortho(scene)
    expected = Lfun(X, Y)
    kw = dict(max_bounces=1, photons_per_pass=100_000)
    a = render(scene, seed=1, **kw)
    b = render(scene, seed=2, **kw)
    # Inside the caustic footprint, away from its edge by 3 px (kernel + filter).
    pix = scene.camera.ortho_scale / scene.camera.resolution[0]
    inside = (np.abs(X) < half - 3 * pix) & (np.abs(Y) < half - 3 * pix)
    assert inside.sum() > 50
    mean, sigma = region_stats(a.mean(axis=2), b.mean(axis=2), inside)
    assert sigma < 0.007 * expected[inside].mean()
    assert abs(mean / expected[inside].mean() - 1) < 0.02


def test_white_furnace():
    scene, L_expected = furnace_box(res=16)
    # Uniform radiance: no kernel bias, so a wide world-space kernel (0.15 m,
    # 10 px; the view covers +-0.12 m of the floor's centre) for low noise.
    # Measured: indirect part 0.50 +- 0.007 per pixel; the noise is next-event
    # estimation of the emitting walls (+-0.13 per pixel, independent).
    kw = dict(max_bounces=64, rr_start=2, photons_per_pass=100_000, radius_mode="WORLD",
              initial_radius=0.15, max_passes=12)
    a = render(scene, seed=1, **kw)
    b = render(scene, seed=2, **kw)
    mean, sigma = region_stats(a.mean(axis=2), b.mean(axis=2), np.ones(a.shape[:2], bool),
                               r_px=1.0)
    assert sigma < 0.006 * L_expected
    assert abs(mean / L_expected - 1) < 0.02


def test_same_seed_same_image():
    scene, _ = point_light_plane(res=12)
    st = RenderSettings(integrator="PHOTON",
                        max_passes=3, photons_per_pass=5_000, seed=7, photons_for_direct=True)
    a = Renderer(scene, st, log=lambda s: None).run().image
    b = Renderer(scene, st, log=lambda s: None).run().image
    assert np.array_equal(a, b)
