"""bench/peer_luxcore.py: FPPM's scene model translated to LuxCoreRender.

The unit formulas are checked without LuxCore; the camera and the light
units through a small LuxCore render (skipped when pyluxcore, a
benchmark-only dependency, is not installed: ``make bench-deps``).
"""
import math
import os
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))
import peer_luxcore as P  # noqa: E402
from fppm.core.lights.table import _spot_solid_angle  # noqa: E402
from fppm.core.scene.camera import CameraModel, FilterSampler  # noqa: E402
from fppm.core.scene.model import DIFFUSE, Camera, Light, Lobe, Material, make_scene  # noqa: E402

needs_lux = pytest.mark.skipif(not P.have_pyluxcore(), reason=P.INSTALL_HINT)


def lambert(rho):
    return Lobe(DIFFUSE, color=(rho, rho, rho))


def _look_down(pos, resolution, **kw):
    """A camera at ``pos`` looking straight down (-Z), +Y up in the image."""
    M = np.eye(4)
    M[:3, 3] = pos
    return Camera(matrix_world=M, resolution=resolution, clip_start=0.01, **kw)


def test_unit_formulas():
    # docs/cycles_units.md worked value: a 1 m^2 area light of 50 W seen head-on.
    assert P.area_radiance(50.0, 1.0) == pytest.approx(15.9155, rel=1e-4)
    # LuxCore's map average of a constant map is 4 pi (its midpoint sum is exact).
    assert P.lux_map_average(lambda th: np.ones_like(th)) == pytest.approx(4 * math.pi, rel=1e-12)
    # The spot map's average on LuxCore's 256 rows against the closed-form cone
    # solid angle FPPM uses for the spot's flux (core.lights.table): within
    # the midpoint rule's error over a 0.7-degree row.
    for size, blend in ((math.radians(35), 0.2), (math.radians(90), 0.5)):
        exact = _spot_solid_angle(np.eye(3), math.cos(size / 2), blend)
        assert P.lux_map_average(lambda th: P.spot_profile(th, size, blend)) == \
            pytest.approx(exact, rel=5e-3)
    # Area light meshes face local -Z and keep the light's area.
    M = np.eye(4)
    M[:3, 3] = (0, 0, 2)
    for shape, area in (("SQUARE", 0.25), ("DISK", math.pi * 0.0625)):
        lt = Light("a", "AREA", (1, 1, 1), M, shape=shape, size=0.5)
        v, f, a = P.area_light_mesh(lt)
        ng = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        assert np.all(ng[:, 2] < 0)
        assert a == pytest.approx(area, rel=2e-3)       # 64-gon: 1 - sin(2pi/64)/(2pi/64)


def test_unsupported_is_refused():
    cam = _look_down((0, 0, 2), (8, 8))
    sc = make_scene([[(-1, -1, 0), (1, -1, 0), (1, 1, 0)]], [Material("m")],
                    [Light("s", "SUN", (1, 1, 1), np.eye(4), angle=0.1)], cam)
    with pytest.raises(P.Unsupported, match="angle"):
        P.translate(sc)


def _floor_cells(n=8, half=2.0):
    """An n x n grid of floor cells (two triangles each), cell i its own material."""
    tris, mats = [], []
    edges = np.linspace(-half, half, n + 1)
    for j in range(n):
        for i in range(n):
            x0, x1, y0, y1 = edges[i], edges[i + 1], edges[j], edges[j + 1]
            tris += [[(x0, y0, 0), (x1, y0, 0), (x1, y1, 0)],
                     [(x0, y0, 0), (x1, y1, 0), (x0, y1, 0)]]
            mats += [j * n + i] * 2
    return tris, mats, edges


def _centre_rays(cam):
    """FPPM's rays through the pixel centres, (H, W) hit points on z = 0 (row 0 at the top)."""
    cm = CameraModel(cam)
    W, H = cam.resolution
    py, px = np.mgrid[0:H, 0:W]
    rays, _ = cm.generate(px.ravel().astype(float), (H - 1 - py).ravel().astype(float),
                          np.full((W * H, 2), 0.5), np.zeros((W * H, 2)), FilterSampler(0.0),
                          compiled=False)
    t = -rays.o[:, 2] / rays.d[:, 2]
    return (rays.o + t[:, None] * rays.d).reshape(H, W, 3)


@needs_lux
def test_camera_and_point_light_match():
    """Each pixel centre's camera ray hits the same floor cell in LuxCore and
    FPPM (non-square film, vertical sensor fit, shift), and a 100 W point
    light 1 m above a Lambert floor (rho 0.8) gives rho I cos / (pi d^2)."""
    n, rho, power = 8, 0.8, 100.0
    tris, mats, edges = _floor_cells(n)
    cam = _look_down((0.2, -0.1, 2.5), (40, 24), lens=30.0, sensor_fit="VERTICAL",
                     shift_x=0.08, shift_y=-0.05)
    L = np.eye(4)
    L[:3, 3] = (0.3, 0.2, 1.0)
    materials = [Material(f"c{i}", lobes=(lambert(rho),)) for i in range(n * n)]
    sc = make_scene(tris, materials, [Light("p", "POINT", (power,) * 3, L)], cam, tri_mat=mats)
    out = P.render_luxcore(P.translate(sc), "lux_path", 0, 60.0, outputs=("RGB", "MATERIAL_ID"),
                           extra={"batch.haltspp": 16, "film.filter.type": "NONE"})
    hit = _centre_rays(cam)
    cell = np.clip(np.searchsorted(edges, hit[..., :2], side="right") - 1, 0, n - 1)
    want = cell[..., 1] * n + cell[..., 0]
    # Pixels whose whole footprint lies in one cell (LuxCore jitters in the pixel).
    pix = CameraModel(cam).pix * 2.5
    frac = (hit[..., :2] - edges[0]) / (edges[1] - edges[0])
    inner = np.all(np.abs(frac - np.round(frac)) * (edges[1] - edges[0]) > pix, axis=2)
    got = out["MATERIAL_ID"][..., 0].astype(int)
    assert inner.sum() > 300
    assert np.array_equal(got[inner], want[inner])
    # Radiance: Lambert floor under a point light of intensity P / (4 pi).
    d = np.asarray(L[:3, 3]) - hit
    r2 = (d * d).sum(axis=2)
    exact = rho / math.pi * power / (4 * math.pi) * d[..., 2] / r2 ** 1.5
    on_floor = np.all(np.abs(hit[..., :2]) < edges[-1] - pix, axis=2)
    ratio = out["img"][..., 0][on_floor] / exact[on_floor]
    # Box-filtered pixels of a smooth field: the centre value on the median.
    assert np.median(ratio) == pytest.approx(1.0, abs=2e-3)
    # One pixel: 16 jittered samples over a gradient of up to ~15% a pixel
    # (measured: at most 1.2% off).
    assert np.all(np.abs(ratio - 1) < 2.5e-2)


@needs_lux
def test_spot_light_matches_cycles_cone():
    """A spot (LuxCore mappoint with the smoothstep map) aimed down at the
    floor: inside its cone the radiance is rho I cos / (pi d^2) with
    I = S / (4 pi), outside it is black, and the whole image's sum follows
    the smoothstep in between."""
    rho, power, size, blend = 0.8, 200.0, math.radians(70), 0.3
    cam = _look_down((0.0, 0.0, 3.0), (32, 32), lens=24.0)
    a = math.radians(20)                 # tilted: the spot's axis is (0, sin a, -cos a)
    L = np.eye(4)
    L[1:3, 1:3] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    L[:3, 3] = (0.1, -0.3, 1.5)
    tri = [[(-5, -5, 0), (5, -5, 0), (5, 5, 0)], [(-5, -5, 0), (5, 5, 0), (-5, 5, 0)]]
    sc = make_scene(tri, [Material("f", lobes=(lambert(rho),))],
                    [Light("s", "SPOT", (power,) * 3, L, spot_size=size, spot_blend=blend)], cam)
    out = P.render_luxcore(P.translate(sc), "lux_path", 0, 60.0,
                           extra={"batch.haltspp": 64, "film.filter.type": "NONE"})
    hit = _centre_rays(cam)
    d = np.asarray(L[:3, 3]) - hit
    r = np.sqrt((d * d).sum(axis=2))
    alpha = np.arccos(np.clip(-(d / r[..., None]) @ -L[:3, 2], -1, 1))
    exact = rho / math.pi * power / (4 * math.pi) * d[..., 2] / r ** 3 * \
        P.spot_profile(alpha, size, blend)
    img = out["img"][..., 0]
    inside = P.spot_profile(alpha + 0.05, size, blend) == 1.0
    outside = P.spot_profile(alpha - 0.05, size, blend) == 0.0
    assert inside.sum() > 50 and outside.sum() > 50
    assert np.median(img[inside] / exact[inside]) == pytest.approx(1.0, abs=3e-3)
    assert np.all(img[outside] == 0)
    assert img.sum() / exact.sum() == pytest.approx(1.0, abs=1e-2)


def test_composed_reference_parts():
    # bench/luxcore_reference.py compose: the world / no-world selections
    # split the lights and keep everything else; the specular-first mask grows
    # a glass pixel by ceil(filter width + 1/2) pixels (Chebyshev).
    import luxcore_reference as R
    lux = P.LuxScene(props={"scene.lights.world.type": ["constantinfinite"],
                            "scene.lights.world.color": [0.1] * 3,
                            "scene.lights.light0.type": ["mappoint"],
                            "scene.lights.light0.color": [1.0] * 3,
                            "scene.materials.mat0.type": ["matte"],
                            "scene.materials.mat1.type": ["glass"],
                            "scene.camera.type": ["perspective"]},
                     size=(9, 9), filter_width=1.5)
    w, nw = R.select_lights(lux, "world"), R.select_lights(lux, "noworld")
    lights = {k for k in lux.props if k.startswith("scene.lights.")}
    assert {k for k in w.props if k.startswith("scene.lights.")} == \
        {k for k in lights if ".world." in k}
    assert {k for k in nw.props if k.startswith("scene.lights.")} == \
        {k for k in lights if ".world." not in k}
    others = {k: v for k, v in lux.props.items() if k not in lights}
    assert {k: v for k, v in w.props.items() if k not in lights} == others
    assert {k: v for k, v in nw.props.items() if k not in lights} == others
    ids = np.zeros((9, 9), np.uint32)
    ids[4, 4] = 1                                   # one pixel sees the glass
    m = R.specular_first(lux, ids)
    assert m.sum() == 25 and m[2:7, 2:7].all()       # ceil(1.5 + 0.5) = 2 pixels around it


def test_first_hit_split_adds_up_to_cycles():
    # bench/luxcore_reference.py cycles_by_first_hit: with the same seed, the
    # render whose diffuse materials are holdouts for camera rays and the one
    # whose glass is add up to the plain Cycles render (the camera samples are
    # the same; each path lands in exactly one of the two), to float32
    # rounding; the glass-first part lives on the sphere's pixels and its
    # filter margin, the diffuse-first part on all the others.
    import bpy_helpers as H
    import luxcore_reference as R
    from fppm.addon.cli import open_blend
    from fppm.tools.converge.cycles_worker import cycles_reference_setup
    from fppm.tools.converge.references import cycles_render, layer
    bpy = H.bpy()

    def render(keep):
        open_blend(R.blend_of("glass_sphere"), resolution=25)
        sc = bpy.context.scene
        cycles_reference_setup(sc)
        if keep is not None:
            R.hold_out_for_camera(bpy, {"Glass"}, keep)
        return layer(cycles_render(bpy, sc, 64, 5)[0], "Combined")[..., :3].astype(np.float64)

    full, glass_first, diffuse_first = render(None), render(True), render(False)
    np.testing.assert_allclose(glass_first + diffuse_first, full, rtol=0, atol=1e-6)
    g, d = glass_first.sum(-1) > 0, diffuse_first.sum(-1) > 0
    assert 50 < g.sum() < 200 and d.sum() > 900 and (g & d).sum() < g.sum()
