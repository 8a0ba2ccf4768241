"""Light tracing (integrator 'LIGHT', core.integrators.light_tracer) and the camera
projection it rests on (core.scene.camera.CameraModel.project).

Tolerances come from the measured noise: light-tracing images are compared
per pixel through z = (estimate - expected) / sigma, sigma from the spread of
the independent passes of the same render (S passes: the mean of z^2 over
pixels is (S-1)/(S-3) for Student-t(S-1) noise, 1.4 for S = 8).
"""
import json
import math

import numpy as np
import pytest

from core.render import Renderer
from core.scene.camera import CameraModel, FilterSampler, filter_weight
from core.scene.model import Camera, Light, Material, Lobe, DIFFUSE, make_scene
from core.settings import RenderSettings

from analytic_scenes import (lambert, mirror_caustic, pixel_centres_ortho,
                             point_light_plane, quad)


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    z = eye - target
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


CAMERAS = {
    "auto_aspect": dict(resolution=(32, 24), pixel_aspect=(1.0, 1.2)),
    "horizontal_tall": dict(resolution=(20, 30), sensor_fit="HORIZONTAL", shift_y=0.1),
    "vertical_shift": dict(resolution=(24, 32), sensor_fit="VERTICAL", shift_x=0.1,
                           shift_y=-0.05),
    "ortho_shift": dict(kind="ORTHO", ortho_scale=5.0, resolution=(32, 24), shift_x=0.05),
    "dof": dict(resolution=(32, 24), aperture_radius=0.08, focus_distance=3.5),
    "border": dict(resolution=(32, 24), border=(0.25, 0.2, 0.8, 0.9)),
}


def camera(name, eye=(0.0, -3.0, 3.0)):
    kw = dict(CAMERAS[name])
    return Camera(matrix_world=look_at(eye, (0.0, 0.0, 0.0)), lens=35.0, clip_start=0.05,
                  clip_end=100.0, **kw)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_project_inverts_generate(name):
    """generate(px, u) then project(point on the ray, same lens sample) gives
    back the raster position px + 0.5 + filter offset (float64 round-off)."""
    rng = np.random.default_rng(3)
    cm = CameraModel(camera(name))
    fs = FilterSampler(1.5)
    K = 500
    W, H = cm.W, cm.H
    px = rng.integers(0, W, K).astype(float)
    py = rng.integers(0, H, K).astype(float)
    uf, ul = rng.random((K, 2)), rng.random((K, 2))
    rays, _ = cm.generate(px, py, uf, ul, fs)
    P = rays.o + rays.d * rng.uniform(0.0, 20.0, K)[:, None]
    pr = cm.project(P, ul)
    expected = np.stack([px + 0.5 + fs.sample(uf[:, 0]), py + 0.5 + fs.sample(uf[:, 1])], 1)
    assert pr.ok.all()
    np.testing.assert_allclose(pr.raster, expected, rtol=0, atol=1e-9)
    # The connection ends at the ray's origin on the lens plane, along -d.
    np.testing.assert_allclose(pr.wi, -rays.d, atol=1e-9)
    # pbrt-v4: We / pdf_wi = 1 / (A_pix cos^3 d^2) (the surface cosine is apart).
    if cm.cam.kind != "ORTHO":
        np.testing.assert_allclose(pr.We / pr.pdf_wi, pr.weight, rtol=1e-12)


def test_project_rejects_behind_and_clipped():
    cm = CameraModel(camera("auto_aspect"))
    o, z = cm.origin, cm.R[:, 2]                 # camera looks along -z
    P = np.stack([o + 5 * z, o - 0.01 * z, o - 200 * z, o - 4 * z])
    assert cm.project(P, np.full((4, 2), 0.5)).ok.tolist() == [False, False, False, True]


def pass_images(scene, **kw):
    """(S, H, W) luminance-free grey images of each independent pass."""
    st = RenderSettings(**{"integrator": "PHOTON", "seed": 1, **kw})
    prev = [None]
    out = []

    def on_pass(res):
        img = res.image[..., :3].astype(np.float64).mean(axis=2) * res.pass_index
        out.append(img - (0.0 if prev[0] is None else prev[0]))
        prev[0] = img
    Renderer(scene, st, log=lambda s: None).run(on_pass=on_pass)
    return np.array(out)


def mean_sigma(passes):
    S = passes.shape[0]
    return passes.mean(axis=0), passes.std(axis=0, ddof=1) / math.sqrt(S)


def checker_scene(cam):
    """A 4 x 4 m checker of albedo 0.15 / 0.85 (16 x 16 squares) under a point light."""
    tris, mats = [], []
    n, s = 16, 0.125                             # squares of 2 s = 0.25 m
    for i in range(n):
        for j in range(n):
            c = (-2.0 + (2 * i + 1) * s, -2.0 + (2 * j + 1) * s, 0.0)
            tris += quad(c, (s, 0, 0), (0, s, 0))
            mats += [(i + j) % 2] * 2
    m = np.eye(4)
    m[:3, 3] = (0.3, 0.2, 1.5)
    light = Light("point", "POINT", (60.0, 60.0, 60.0), m)
    return make_scene(tris, [lambert("dark", 0.15), lambert("bright", 0.85)], [light], cam,
                      tri_mat=mats)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_splats_land_in_the_right_pixel(name):
    """Light tracing of a point-lit checker equals next-event estimation
    (PHOTON mode, no photons needed) per pixel, for every camera model: the
    splat position, the filter and the importance normalisation all show.
    A one-pixel shift of the light-traced image fails the same test."""
    scene = checker_scene(camera(name))
    lt = pass_images(scene, integrator="LIGHT", max_passes=8, photons_per_pass=150_000,
                     max_bounces=1)
    ne = pass_images(scene, integrator="PHOTON", max_passes=96, photons_per_pass=1,
                     max_bounces=1, use_frequency=False)
    m_l, s_l = mean_sigma(lt)
    m_n, s_n = mean_sigma(ne)
    sig = np.sqrt(s_l ** 2 + s_n ** 2)
    lit = m_n > 0.02 * m_n.max()
    assert lit.sum() > 100
    z2 = ((m_l - m_n) / np.maximum(sig, 1e-12))[lit] ** 2
    # Student-t(7)-like light-tracing noise: E[z^2] ~ 1.4; 2.0 leaves room
    # for the NEE sigma's own (95-pass) estimate.
    print("mean z^2", z2.mean())
    assert z2.mean() < 2.0, z2.mean()
    assert abs(m_l[lit].sum() / m_n[lit].sum() - 1) < 4 * np.sqrt((sig[lit] ** 2).sum()) / \
        m_n[lit].sum()
    shifted = np.roll(m_l, 1, axis=1)
    z2s = ((shifted - m_n) / np.maximum(sig, 1e-12))[lit] ** 2
    assert z2s.mean() > 10 * z2.mean()


def filtered(Lfun, X, Y, pix, width=1.5, n=48):
    """The closed form seen through Cycles' pixel filter at ortho pixel centres
    (X, Y): quadrature at n x n filter quantiles."""
    q = FilterSampler(width).sample((np.arange(n) + 0.5) / n) * pix
    acc = np.zeros(X.shape)
    for qx in q:
        for qy in q:
            acc += Lfun(X + qx, Y + qy)
    return acc / (n * n)


def filter_mass(lo, hi, c, pix, width=1.5):
    """Mass of the normalised pixel filter centred at c (metres, pixel size
    pix) over [lo, hi]: 1D trapezoid on 20001 points of filter_weight."""
    t = np.linspace(-width, width, 20001)
    w = filter_weight(t, width)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
    cdf /= cdf[-1]
    F = lambda x: np.interp(x, t, cdf)          # noqa: E731
    return F((hi - c) / pix) - F((lo - c) / pix)


def test_point_light_plane_closed_form():
    """Lambert plane under a point light: per pixel the closed form
    rho/pi * I h / (r^2 + h^2)^1.5, filtered, within the measured noise."""
    scene, Lfun = point_light_plane(res=24)
    X, Y = pixel_centres_ortho(scene)
    pix = scene.camera.ortho_scale / scene.camera.resolution[0]
    expected = filtered(Lfun, X, Y, pix)
    lt = pass_images(scene, integrator="LIGHT", max_passes=8, photons_per_pass=150_000)
    m, s = mean_sigma(lt)
    z2 = ((m - expected) / s) ** 2
    print("mean z^2", z2.mean())
    assert z2.mean() < 2.0, z2.mean()
    # The image mean: noise 4 sigma of the mean (measured relative sigma of
    # one pixel ~1.7% with 1.2 M paths, so ~0.1% for the mean).
    sig_mean = np.sqrt((s ** 2).sum()) / s.size
    assert abs(m.mean() - expected.mean()) < 4 * sig_mean
    assert sig_mean < 0.003 * expected.mean()


def test_mirror_caustic_closed_form():
    """Point light under a flat mirror: the caustic on the diffuse floor
    (image light over the mirror's footprint) plus direct light, per pixel
    within noise -- including the caustic's sharp edge, which no kernel blurs
    (the expectation is only filtered by the pixel filter)."""
    scene, Lfun, half = mirror_caustic(res=24)
    X, Y = pixel_centres_ortho(scene)
    pix = scene.camera.ortho_scale / scene.camera.resolution[0]
    expected = filtered(Lfun, X, Y, pix, n=96)
    lt = pass_images(scene, integrator="LIGHT", max_passes=8, photons_per_pass=150_000,
                     max_bounces=1)
    m, s = mean_sigma(lt)
    z2 = ((m - expected) / s) ** 2
    print("mean z^2", z2.mean())
    assert z2.mean() < 2.0, z2.mean()
    inside = (np.abs(X) < half - 2 * pix) & (np.abs(Y) < half - 2 * pix)
    assert inside.sum() > 50
    sig_in = np.sqrt((s[inside] ** 2).sum()) / inside.sum()
    assert abs(m[inside].mean() - expected[inside].mean()) < 4 * sig_in
    # The caustic is there: inside the footprint the floor is brighter than
    # direct light alone (point_light_plane's closed form, same P, h, rho) by
    # the image light, rho_m I z / (r^2 + z^2)^1.5 at z = 3: +3% at the centre.
    _, direct = point_light_plane()
    gain = m[inside].mean() / filtered(direct, X, Y, pix)[inside].mean() - 1
    assert abs(gain - (expected[inside].mean() / filtered(direct, X, Y, pix)[inside].mean() - 1)) \
        < 4 * sig_in / expected[inside].mean()
    assert gain > 0.02


@pytest.mark.parametrize("kind", ["AREA", "MESH"])
def test_emitter_seen_by_the_camera(kind):
    """Emission vertices: an orthographic camera under a 1 m square emitter
    (area light of power P facing down: L = P / (pi A); or an emissive mesh
    quad of strength L, two-sided) sees its radiance L over the emitter's
    image -- the pixel filter at its edge -- and nothing outside it."""
    P, size, h = 50.0, 1.0, 1.0
    L = P / (np.pi * size * size)
    up = np.diag([1.0, -1.0, -1.0, 1.0])         # ortho camera at z = 0 looking up +Z
    cam = Camera(kind="ORTHO", matrix_world=up, ortho_scale=2.0, resolution=(24, 24),
                 clip_start=0.01, clip_end=100.0)
    tris = quad((0, 0, -5.0), (10, 0, 0), (0, 10, 0))      # a black floor, below
    if kind == "AREA":
        m = np.eye(4)
        m[2, 3] = h
        scene = make_scene(tris, [lambert("black", 0.0)],
                           [Light("area", "AREA", (P, P, P), m, shape="SQUARE", size=size)], cam)
    else:
        glow = Material("glow", (Lobe(DIFFUSE, (0.0, 0.0, 0.0)),), emission=(L, L, L))
        scene = make_scene(tris + quad((0, 0, h), (0, 0.5 * size, 0), (0.5 * size, 0, 0)),
                           [lambert("black", 0.0), glow], [], cam, tri_mat=[0, 0, 1, 1])
    lt = pass_images(scene, integrator="LIGHT", max_passes=8, photons_per_pass=100_000)
    m, s = mean_sigma(lt)
    X, Y = pixel_centres_ortho(scene)
    pix = 2.0 / 24
    # The square's indicator seen through the separable filter: exact
    # products of 1D filter masses (a quantile quadrature of a step errs by
    # half a quantile's mass).
    expected = L * filter_mass(-0.5, 0.5, X, pix) * filter_mass(-0.5, 0.5, Y, pix)
    inside = (np.abs(X) < 0.5 - 2 * pix) & (np.abs(Y) < 0.5 - 2 * pix)
    sig_in = np.sqrt((s[inside] ** 2).sum()) / inside.sum()
    assert abs(m[inside].mean() / L - 1) < 4 * sig_in / L
    assert sig_in < 0.01 * L
    outside = (np.abs(X) > 0.5 + 2 * pix) | (np.abs(Y) > 0.5 + 2 * pix)
    assert np.all(m[outside] == 0)
    z2 = ((m - expected) / np.maximum(s, 1e-12))[s > 0] ** 2
    print("mean z^2", z2.mean())
    assert z2.mean() < 2.0, z2.mean()


def test_cli_mode_light_renders_the_light_tracer(tmp_path):
    """``fppm render --mode light`` sets integrator = LIGHT and writes exactly
    the image of Renderer(integrator='LIGHT') on the exported scene."""
    pytest.importorskip("bpy")
    import bpy_helpers as H
    from fppm.addon import export as E
    from fppm.core.io.exr import read_exr, read_exr_metadata
    sc = H.simple_scene(res=(24, 16), passes=2, photons=20_000, seed=4)
    blend = H.save_blend(tmp_path / "s.blend")
    out = tmp_path / "s.exr"
    r = H.run_fppm("render", blend, "-o", out, "--mode", "light", "-q", "--no-preview")
    assert r.returncode == 0, r.stderr[-3000:]
    st = json.loads(read_exr_metadata(str(out))["fppm:settings"])
    assert st["integrator"] == "LIGHT"
    img = read_exr(str(out))["Combined"]
    scene = E.export_scene(H.evaluated_depsgraph(), lambda s: None)
    want = Renderer(scene, RenderSettings(**st), log=lambda s: None).run().image
    assert img.shape == want.shape and img[..., :3].max() > 0
    assert np.array_equal(img, want)


@pytest.mark.parametrize("integrator", ["LIGHT", "COMBINED"])
def test_light_checkpoint_resumes_bit_for_bit(integrator):
    """The splat film is part of the checkpoint (COMBINED: with the camera
    paths' L_sum): 2 passes, save, resume, 1 more pass equals 3 in one go."""
    scene, _ = point_light_plane(res=12)
    st = RenderSettings(integrator=integrator, max_passes=3, photons_per_pass=20_000, seed=5)
    full = Renderer(scene, st, log=lambda s: None).run().image
    a = Renderer(scene, st.replace(max_passes=2), log=lambda s: None)
    a.run()
    b = Renderer(scene, st, log=lambda s: None)
    b.load_state(a.state_dict())
    assert np.array_equal(b.run().image, full)
