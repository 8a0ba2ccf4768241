"""The compiled connection of light vertices to the camera (core.integrators.light_kernels)
against the numpy path it replaces.

1. ``project_kernel`` = ``CameraModel.project`` + the region test + accel.spawn
   and the near-clip t_max of the shadow rays, on every test camera
   (perspective, shifted, orthographic, thin lens, border), to round-off.
2. ``first_hits`` (point lights, rectangles) = ``combined.first_hit_ratios``.
3. ``splat_emitters`` (emitters seen directly) = the numpy splat of
   ``combined.emission_splat_weight``.
4. ``splat_fast`` (LAMBERT vertices and GENERIC ones, colour-textured ones
   included: f, shading factor, the MIS weight of 'COMBINED') = the numpy splat
   (eval_bsdf, pdf_bsdf, combined.splat_weight) that ``LightTracer._slow``
   applies to every other material: the same deposits and lens samples
   splatted both ways give the same film.
"""
import numpy as np
import pytest

from core import lights as Lt
from core.accel import intersect_f32, surface_point
from core.integrators import light_kernels as LK
from core.integrators import mis as M
from core.integrators.combined import emission_splat_weight, first_hit_ratios
from core.render import Renderer
from core.scene import nodes as shading
from core.scene.camera import CameraModel
from core.scene.model import DIFFUSE, GLOSSY, Lobe, Material, make_scene
from core.settings import RenderSettings
from core.sppm import photon_kernels as PK

from analytic_scenes import furnace_box, lambert, quad
from test_combined import rig  # noqa: F401  (the fixture)
from test_light_tracer import CAMERAS, camera, checker_scene


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_project_kernel_equals_project(name):
    cam = camera(name)
    cm = CameraModel(cam)
    rng = np.random.default_rng(5)
    K = 4000
    p = rng.uniform(-3.0, 3.0, (K, 3))
    ng = rng.normal(size=(K, 3))
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    u = rng.random((K, 2))
    W, H = cam.resolution
    x0, y0, fw = 3, 2, 1.5
    cp = LK.camera_params(cm, x0, y0, W - 6, H - 4, fw)
    rel, floor = 1e-5, 1e-3
    con = LK.connections(K)
    n = LK.project_kernel(cp, p, ng, u, rel, floor, con)
    pr = cm.project(p, u)
    w = max(fw, 0.5)
    x, y = pr.raster[:, 0], pr.raster[:, 1]
    near = (pr.ok & (x > x0 - w) & (x < x0 + W - 6 + w) & (y > y0 - w) & (y < y0 + H - 4 + w))
    idx = np.nonzero(near)[0]
    assert 50 < idx.size < K
    np.testing.assert_array_equal(con.row[:n], idx)
    np.testing.assert_allclose(con.raster[:n], pr.raster[idx], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(con.wc[:n], pr.wi[idx], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(con.weight[:n], pr.weight[idx], rtol=1e-12)
    depth = -((p[idx] - cm.origin) @ cm.R[:, 2])
    t_max = pr.dist[idx] * (depth - cam.clip_start) / depth
    np.testing.assert_allclose(con.t_max[:n], t_max, rtol=1e-12)
    side = np.where(np.sum(ng[idx] * pr.wi[idx], axis=1) >= 0, 1.0, -1.0)
    scale = np.maximum(np.abs(p[idx]).max(axis=1), floor) * rel
    np.testing.assert_allclose(con.o[:n], p[idx] + ng[idx] * (side * scale)[:, None],
                               rtol=1e-14, atol=1e-14)


def _films(lt, dep, mis):
    """The film of dep splatted by the kernel and by the numpy path (same lens samples)."""
    out = []
    sm = lt.splat_mat
    for kind in (sm.kind, np.zeros_like(sm.kind)):
        lt.splat_mat = sm._replace(kind=kind)
        film = np.zeros((lt.H * lt.W, 3))
        lt.connect(dep, np.random.default_rng(9), film, mis=mis)
        out.append(film)
    lt.splat_mat = sm
    return out


def _scene():
    """The point-lit checker (two Lambert materials) with four strips in
    front: a rough metal and Blender's default Principled BSDF (GENERIC
    materials the kernel evaluates compiled), a textured rough metal and a
    textured Lambert strip (a colour checker into their colours: each
    connection's own colour row, LightTracer._rows); corner normals tilted
    at random (interpolated shading normals, the shading factor)."""
    base = checker_scene(camera("dof"))
    strips = [np.asarray(quad((x, -0.5, 0.3), (0.3, 0, 0), (0, 0.2, 0.2)), float)
              for x in (-0.6, 0.0, 0.6, 1.2)]
    tris = np.concatenate([base.tri_p] + strips)
    tri_n = np.concatenate([base.tri_n] + [np.repeat(
        np.cross(s[:, 1] - s[:, 0], s[:, 2] - s[:, 0])[:, None], 3, axis=1) for s in strips])
    tri_n = tri_n + 0.3 * np.random.default_rng(2).normal(size=tri_n.shape)
    tri_n /= np.linalg.norm(tri_n, axis=2, keepdims=True)
    principled, _, _ = shading.principled_to_lobes()       # Blender's defaults
    mats = [lambert("dark", 0.15), lambert("bright", 0.85),
            Material("metal", (Lobe(GLOSSY, (0.8, 0.7, 0.6), roughness=0.4),)),
            Material("principled", tuple(principled)),
            Material("metal_tex", (Lobe(GLOSSY, (0.8, 0.7, 0.6), roughness=0.4,
                                        color_texture=0),)),
            Material("lambert_tex", (Lobe(DIFFUSE, (0.7, 0.7, 0.7), color_texture=0),))]
    tri_mat = np.concatenate([base.tri_mat, [2, 2, 3, 3, 4, 4, 5, 5]])
    chk = np.full((2, 2, 3), 0.9, np.float32)
    chk[0, 1] = chk[1, 0] = (0.2, 0.5, 0.8)
    sc = make_scene(tris, mats, base.lights, base.camera, tri_mat=tri_mat, tri_n=tri_n,
                    tri_uv=(4.0 * tris[:, :, :2]).astype(np.float32), textures=[chk])
    return sc


@pytest.mark.parametrize("integrator", ["LIGHT", "COMBINED"])
def test_compiled_splat_equals_numpy(integrator):
    r = Renderer(_scene(), RenderSettings(integrator=integrator, photons_per_pass=20_000,
                                          max_passes=1, seed=3), log=lambda s: None)
    lt = r.light_tracer if integrator == "LIGHT" else r.combined_lt
    dep = lt.tracer.trace(20_000, 0, np.random.default_rng(4))
    k = dep["p"].shape[0]
    mis = None
    if integrator == "COMBINED":
        g = np.random.default_rng(6)
        mis = (g.exponential(size=k), g.exponential(size=k), g.random(k) < 0.3,
               g.random(k) < 0.2)
    assert lt.fast_mat.tolist() == [True, True, False, False, False, True]
    assert lt.splat_mat.kind.tolist() == [LK.LAMBERT_SPLAT] * 2 + [LK.GENERIC_SPLAT] * 3 + [
        LK.LAMBERT_SPLAT]
    # Every kind of vertex is splatted: the strips are the last 8 triangles.
    strip = (dep["bary"][:, 0].astype(int) - (r.scene.tri_p.shape[0] - 8)) // 2
    assert [np.count_nonzero(strip == i) > 100 for i in range(4)] == [True] * 4, np.bincount(
        strip[strip >= 0])
    fast, ref = _films(lt, dep, mis)
    assert ref.sum() > 0
    np.testing.assert_allclose(fast, ref, rtol=1e-10, atol=1e-12 * ref.max())


def test_first_hits_equal_first_hit_ratios(rig):  # noqa: F811  (the fixture)
    """CombinedLightTracer._first_hit (compiled for point lights and
    rectangles) equals combined.first_hit_ratios at the first hits of
    photons from the rig's area, point, soft point and soft spot lights."""
    lt = rig.combined_lt
    lt.kn = 4 / 5000.0
    t = lt.light_table
    ph = Lt.sample_photons(t, 6000, np.random.default_rng(8))
    ph["light"] = ph["light"].astype(np.int64)
    assert set(np.unique(t.kind[ph["light"]])) == {Lt.POINT, Lt.SPOT, Lt.AREA}
    o32 = (ph["o"] + 1e-4 * ph["d"]).astype(np.float32)
    hits = PK.EmbreeHits(*intersect_f32(lt.accel, o32, ph["d"].astype(np.float32)))
    K = o32.shape[0]
    area = t.kind[ph["light"]] == Lt.AREA
    z0 = np.where(area[:, None], ph["o"], t.co[ph["light"]])
    fb0, fb1 = np.full(K, -1.0), np.full(K, -1.0)
    lt._first_hit(hits, K, ph["d"], np.arange(K), ph, z0, fb0, fb1)
    hit = np.nonzero(hits.prim >= 0)[0]
    P = lt.tracer.tris.p[hits.prim[hit]]
    u, v = hits.bu[hit, None].astype(float), hits.bv[hit, None].astype(float)
    p = (1 - u - v) * P[:, 0] + u * P[:, 1] + v * P[:, 2]
    _, ng, _, _ = surface_point(lt.scene.tri_p, lt.scene.tri_n, lt.scene.tri_uv,
                                hits.prim[hit].astype(np.int64), hits.bu[hit].astype(float),
                                hits.bv[hit].astype(float))
    B0, B1 = first_hit_ratios(t, lt.kn, ph["light"][hit], z0[hit], ph["d"][hit], p, ng)
    a = area[hit]
    assert np.count_nonzero(B1[a]) > 500 and np.count_nonzero(B1[~a]) > 500
    np.testing.assert_allclose(fb0[hit], B0, rtol=1e-9, atol=0)
    np.testing.assert_allclose(fb1[hit], B1, rtol=1e-9, atol=0)


def test_emission_splat_equals_numpy():
    """LightTracer._emission_vertices (compiled splat, 'COMBINED' weights)
    equals the numpy splat of the same emission vertices and lens samples:
    CameraModel.project, the shadow rays, f_s = 1 / pi on the emitting side
    and combined.emission_splat_weight (mesh emitters seen directly)."""
    scene, _ = furnace_box(res=8)
    r = Renderer(scene, RenderSettings(integrator="COMBINED", photons_per_pass=4000,
                                       max_passes=1), log=lambda s: None)
    lt, t = r.combined_lt, r.light_table
    lt.kn = 4 / 4000.0
    ph = Lt.sample_photons(t, 200_000, np.random.default_rng(2))
    light = ph["light"].astype(np.int64)
    pA = M.emit_pdf_pos(t, light)
    full = lt.cls[light] == M.FULL
    film = np.zeros((lt.H * lt.W, 3))
    lt._emission_vertices(ph, np.random.default_rng(3), film, mis=(lt.kn, pA, full))
    # numpy: every photon is a MESH emission vertex here.
    assert np.all(t.kind[light] == Lt.MESH)
    o = ph["o"]
    n = t.dir[light] * np.where(np.sum(t.dir[light] * ph["d"], axis=1) >= 0, 1.0, -1.0)[:, None]
    pr = lt.camera.project(o, np.random.default_rng(3).random((o.shape[0], 2)))
    cp = lt.cam_params
    x, y = pr.raster[:, 0], pr.raster[:, 1]
    k = np.nonzero(pr.ok & (x > cp.x0 - cp.w) & (x < cp.x0 + cp.W + cp.w)
                   & (y > cp.y0 - cp.w) & (y < cp.y0 + cp.H + cp.w))[0]
    depth = -((o[k] - lt.camera.origin) @ lt.camera.R[:, 2])
    t_max = pr.dist[k] * (depth - lt.camera.cam.clip_start) / depth
    k = k[~lt.accel.occluded(lt.accel.spawn(o[k], n[k], pr.wi[k]), pr.wi[k], t_max)]
    cos_o = np.sum(n[k] * pr.wi[k], axis=1)
    k, cos_o = k[cos_o > 0], cos_o[cos_o > 0]
    c1 = cos_o * pr.weight[k]
    contrib = (ph["power"][k] * (c1 / np.pi)[:, None]
               * emission_splat_weight(lt.kn, c1, pA[k], full[k])[:, None])
    ref = np.zeros_like(film)
    LK.splat_kernel(np.ascontiguousarray(pr.raster[k]), contrib, lt.x0, lt.y0, lt.W, lt.H,
                    lt.filter_width, lt.cam_params.fk, ref)
    assert k.size > 300 and ref.sum() > 0
    np.testing.assert_allclose(film, ref, rtol=1e-10, atol=1e-12 * ref.max())


@pytest.mark.parametrize("width, kind", [(1.5, "BLACKMAN_HARRIS"), (0.7, "BLACKMAN_HARRIS"),
                                         (2.3, "BLACKMAN_HARRIS"), (0.0, "BLACKMAN_HARRIS"),
                                         (1.0, "BOX"), (2.5, "BOX"), (1.5, "GAUSSIAN"),
                                         (0.6, "GAUSSIAN")])
def test_splat_filter_equals_filter_weight(width, kind):
    """splat_kernel's taps (Blackman-Harris: the Chebyshev recurrence, the
    phase rotated pixel by pixel: light_kernels._taps) against the separable
    camera.filter_weight film, region cut at the edges; width 0: the
    one-pixel box.  Measured max error 5.4e-16 of the film's peak (1.5 px)."""
    from core.scene.camera import FILTER_TYPES, filter_weight
    rng = np.random.default_rng(3)
    W, H, x0, y0 = 9, 7, 2, 1
    raster = rng.uniform([x0 - 3, y0 - 3], [x0 + W + 3, y0 + H + 3], (300, 2))
    contrib = rng.random((300, 3))
    film = np.zeros((H * W, 3))
    LK.splat_kernel(raster, contrib, x0, y0, W, H, width, FILTER_TYPES[kind], film)
    px = np.arange(x0, x0 + W) + 0.5
    py = np.arange(y0, y0 + H) + 0.5
    if width > 0:
        fx = filter_weight(raster[:, :1] - px, width, kind)        # (K, W)
        fy = filter_weight(raster[:, 1:] - py, width, kind)        # (K, H)
    else:
        fx = (np.abs(raster[:, :1] - px) < 0.5).astype(float)
        fy = (np.abs(raster[:, 1:] - py) < 0.5).astype(float)
    ref = np.einsum("kh,kw,kc->hwc", fy[:, ::-1], fx, contrib).reshape(H * W, 3)
    assert ref.max() > 0.5
    np.testing.assert_allclose(film, ref, rtol=0, atol=1e-14 * ref.max())


def test_rect_solid_angle_equals_sampler():
    """direct_kernels._spherical_rect_solid_angle (two triangles' solid
    angles) = the S of _spherical_rect (four arccos), to float rounding,
    over random receivers and rectangles; a 2 x 2 square seen from 1 above
    its centre subtends 4 asin(1/2) = 2 pi / 3."""
    from core.lights.direct_kernels import _spherical_rect, _spherical_rect_solid_angle
    assert _spherical_rect_solid_angle(0.0, 0.0, 1.0, -1.0, -1.0, 0.0, 1.0, 0.0, 0.0, 2.0,
                                       0.0, 1.0, 0.0, 2.0) == pytest.approx(2 * np.pi / 3,
                                                                             rel=1e-14)
    rng = np.random.default_rng(1)
    for _ in range(500):
        p = rng.normal(size=3) * rng.choice([0.1, 1.0, 10.0])
        s = rng.normal(size=3)
        ex = rng.normal(size=3)
        ex /= np.linalg.norm(ex)
        ey = np.cross(ex, rng.normal(size=3))
        ey /= np.linalg.norm(ey)
        lx, ly = rng.uniform(0.01, 2.0, 2)
        S = _spherical_rect(*p, *s, *ex, lx, *ey, ly, 0.5, 0.5)[3]
        # The arccos sum loses ~1e-13 absolute to cancellation (measured
        # 2.3e-13 at most over 20k such draws).
        assert _spherical_rect_solid_angle(*p, *s, *ex, lx, *ey, ly) == pytest.approx(
            S, rel=1e-9, abs=1e-12)
