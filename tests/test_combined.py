"""Integrator 'COMBINED' (core.integrators.combined, core.integrators.mis):
camera paths and light tracing weighted by the power heuristic.

1. MIS: on concrete short paths (1 to 4 segments, with and without a mirror)
   the weights the camera side (PT emission, next-event estimation) and the
   light side (light tracing) compute with their running ratios equal the
   brute-force densities of tests/oracle_mis.py and sum to 1.
2. Images: the combined image agrees with the closed forms (point light
   over a plane, the mirror caustic that path tracing cannot render) and the
   furnace within the noise measured from two seeds.
"""
import math

import numpy as np
import pytest

from core import materials as Bm
from core.integrators.combined import (emission_splat_weight, first_hit_ratios, nee_owned_rows,
                                       scatter_factors, splat_weight)
from core.integrators import path_kernels as PKp
from core.integrators.mis import light_classes
from core.integrators.merge import CameraMerge
from core.integrators.path_tracer import PathVertices
from core.lights.pdf import _selection_probability
from core.lights import pdf_direct
from core.render import Renderer
from core.scene.model import GLOSSY, Camera, Light, Lobe, Material, make_scene
from core.settings import RenderSettings

import oracle_mis as O
from analytic_scenes import (area_light_plane, furnace_box, lambert, mirror_caustic,
                             pixel_centres_ortho, point_light_plane, quad, translate)
from test_light_tracer import filtered, look_at

K_CAM, N_L = 4, 5000
LENS = np.array([0.0, -3.0, 3.0])


@pytest.fixture(scope="module")
def rig():
    """A renderer of a tiny scene: floor (Lambert), wall (Lambert), mirror;
    an area light, a point light, a soft point light (radius 0.1) and a soft
    spot light (radius 0.1)."""
    tris = (quad((0, 0, 0), (5, 0, 0), (0, 5, 0)) + quad((0, 2, 1), (0, 0, 1), (2, 0, 0))
            + quad((1.5, 0, 1), (0, 0, 0.5), (0, 0.5, 0)))
    mats = [lambert("floor", 0.8), lambert("wall", 0.5),
            Material("mirror", (Lobe(GLOSSY, (0.9,) * 3, roughness=0.0),))]
    area = Light("area", "AREA", (40.0,) * 3, translate(0, 0, 2.5), shape="SQUARE", size=1.0)
    point = Light("point", "POINT", (30.0,) * 3, translate(0.5, 0.5, 2.0))
    soft = Light("soft", "POINT", (20.0,) * 3, translate(-0.5, 0.5, 2.0), radius=0.1)
    # A soft spot (row 3), aimed down, its cone scaled (elliptic) and wide
    # enough to hold F1, F2, W1 and M1.
    sm = translate(0.3, 1.2, 2.4)
    sm[:3, :3] = np.diag([1.3, 0.8, 1.0])
    spot = Light("softspot", "SPOT", (25.0,) * 3, sm, radius=0.1, spot_size=2.2, spot_blend=0.3)
    cam = Camera(matrix_world=look_at(LENS, (0.0, 0.0, 0.5)), lens=35.0, clip_start=0.05,
                 clip_end=100.0, resolution=(16, 16))
    scene = make_scene(tris, mats, [area, point, soft, spot], cam, tri_mat=[0, 0, 1, 1, 2, 2])
    r = Renderer(scene, RenderSettings(integrator="COMBINED", photons_per_pass=N_L,
                                       camera_samples=K_CAM, max_passes=1),
                 log=lambda s: None)
    return r


MAT = {"lambert": 0, "wall": 1, "mirror": 2}
NORMAL = {0: (0, 0, 1.0), 1: (0, -1.0, 0), 2: (-1.0, 0, 0)}


def vtx(p, mat):
    kind = "mirror" if mat == 2 else "lambert"
    return dict(p=np.asarray(p, float), n=np.asarray(NORMAL[mat], float), kind=kind, mat=mat)


def light_vtx(r, row, p):
    t = r.light_table
    n = t.dir[row] if t.kind[row] in (3, 4) else np.zeros(3)
    return dict(p=np.asarray(p, float), n=n, kind="light", row=row)


def _pv(r, v, wo):
    mat = np.array([v["mat"]])
    return PathVertices(path=np.zeros(1, np.int64), p=v["p"][None], ng=v["n"][None],
                        ns=v["n"][None], wo=wo[None], mat=mat,
                        colors=Bm.lobe_colors(r.mtab, mat, np.zeros((1, 2))), beta=np.ones((1, 3)))


def _unit(v):
    return v / np.linalg.norm(v)


def _path_materials(mtab):
    """The path kernels' PathMaterials of a material table (the compiled twins' M)."""
    from core.materials.fast import build_fast_materials
    return PKp.build_path_materials(mtab, build_fast_materials(mtab))


def camera_side(r, path, merge=False):
    """(w_PT, w_NEE) from the PathTracer's CameraMIS along path[1:] (y_0 =
    LENS).  merge: with merging as an MIS strategy (CameraMIS.mis_merge set),
    its CameraMerge steps as the PathTracer takes them; the compiled twins
    (nee_compiled, continued_compiled) then give the same numbers (1e-12)."""
    pt, cam = r.path_tracer, r.path_tracer.vc
    k = len(path) - 1
    y = [np.asarray(v["p"], float) for v in path]
    row = np.array([path[k]["row"]])
    d = _unit(y[1] - y[0])[None]
    t = np.array([np.linalg.norm(y[1] - y[0])])
    Qs, i0 = cam.camera_state(d), np.zeros(1, np.int64)
    mg = CameraMerge(1) if merge else None
    if k == 1:
        return cam.emission(np.ones(1), i0, row, d, t, None, 0, Qs, None, np.zeros(1), None,
                            *((np.zeros(1),) if merge else ()))[0], 0.0
    v = _pv(r, path[1], -d[0])
    v.Q, v.c = cam.at_hit(Qs, None, i0, d, v.ng, t, 0)
    if merge:
        mg.scale = cam.merge_scale(v.p, np.full((1, 2), 0.5))
        v.QM = mg.at_vertex(t)
    w_nee = 0.0
    for j in range(1, k):
        depth = j - 1
        delta = path[j]["kind"] == "mirror"
        if j == k - 1 and not delta:
            wi = _unit(y[k] - y[j])[None]
            dist = np.array([np.linalg.norm(y[k] - y[j])])
            w2 = pt.mis_light(v, wi, dist, row)
            w_nee = cam.nee(w2, v, wi, dist, row, depth)[0]
            if merge:
                pl = pt.pdf_light(v.p, wi, row, dist, v.ns_wo())
                sel = _selection_probability(r.light_table, v.p, row)
                got = cam.nee_compiled(_path_materials(r.mtab), w2, v, wi, dist, row, pl, sel,
                                       depth)
                np.testing.assert_allclose(got, w_nee, rtol=1e-12, atol=1e-15)
        wi = _unit(y[j + 1] - y[j])[None]
        t = np.array([np.linalg.norm(y[j + 1] - y[j])])
        pdf = np.ones(1) if delta else Bm.pdf_bsdf(r.mtab, v.mat, v.colors, v.ns, v.ng, v.wo,
                                                     wi, subset="all")
        if merge:
            QMn = cam.continued(v, i0, wi, pdf, np.array([delta]), depth, Q=v.QM)[0]
            nx = PKp.NextRays(i0, v.p, wi, np.ones((1, 3)), pdf, np.array([delta]), v.ns,
                              np.ones(1))
            got = cam.continued_compiled(_path_materials(r.mtab), v, nx, depth, Q=v.QM)[0]
            np.testing.assert_allclose(got, QMn, rtol=1e-12, atol=1e-300)
            mg.sampled(QMn, np.abs(np.sum(v.ng * wi, axis=1)), np.array([delta]))
        Qs, pf = cam.continued(v, i0, wi, pdf, np.array([delta]), depth)
        pdf_prev = np.zeros(1) if delta else pdf
        if j + 1 == k:
            if not pt.hittable[row[0]]:
                return 0.0, w_nee        # no ray finds a radius-0 light
            w2 = pt._mis_bsdf(pdf_prev, v.p, v.ns_wo(), wi, row, t)
            w_pt = cam.emission(w2, i0, row, wi, t, None, j, Qs, pf, pdf_prev, v,
                                *((np.where(mg.em, mg.Qs, 0.0),) if merge else ()))[0]
            return w_pt, w_nee
        v = _pv(r, path[j + 1], -wi[0])
        v.Q, v.c = cam.at_hit(Qs, pf, i0, wi, v.ng, t, j)
        if merge:
            v.QM = mg.at_vertex(t)


def light_side(r, path):
    """w_LT of the light path y_k .. y_1 connected to the pinhole, from the
    functions CombinedLightTracer uses."""
    t = r.light_table
    k = len(path) - 1
    y = [np.asarray(v["p"], float) for v in path]
    row = np.array([path[k]["row"]])
    kn = K_CAM / N_L
    cam = r.camera
    pr = cam.project(y[1][None], np.full((1, 2), 0.5))
    if k == 1:
        c1 = pr.weight * abs(np.dot(path[1]["n"], pr.wi[0]))
        return emission_splat_weight(kn, c1, np.array([t.p_select[row[0]] / t.p_select.sum()
                                                       / t.area[row[0]]]), True)[0]
    z0 = y[k] if t.kind[row[0]] in (3, 4) else t.co[row[0]]
    d = _unit(y[k - 1] - z0)[None]
    vz = path[k - 1]
    B0, B1 = first_hit_ratios(t, kn, row, z0[None], d, vz["p"][None], vz["n"][None])
    soft = np.array([t.radius[row[0]] > 0])
    owned = nee_owned_rows(t, light_classes(t))[row]     # CombinedLightTracer._chunk
    for m in range(1, k):
        i = k - m                                   # z_m = y_i
        v = _pv(r, path[i], _unit(y[i + 1] - y[i]))
        if i == 1:
            if not r.mtab.has_nondelta[path[1]["mat"]]:
                return 0.0               # light tracing splats non-delta vertices only
            wc = pr.wi
            pf = Bm.pdf_bsdf(r.mtab, v.mat, v.colors, v.ns, v.ng, wc, v.wo, subset="all")
            c1 = pr.weight * np.abs(np.sum(v.ng * wc, axis=1))
            if m == 1:
                B1 = np.where(owned, np.inf, B1)
            return splat_weight(B0, B1, pf, c1, m == 1, soft)[0]
        B0, B1 = light_scatter(r, path, y, i, m, v, B0, B1)


def light_scatter(r, path, y, i, m, v, B0, B1):
    """(B0, B1) of a light path leaving z_m = y_i (vertex v) towards y_{i-1}
    (CombinedLightTracer's scatter_factors, then the |cos| on arrival)."""
    delta = path[i]["kind"] == "mirror"
    wn = _unit(y[i - 1] - y[i])[None]
    pdf = np.ones(1) if delta else Bm.pdf_bsdf(r.mtab, v.mat, v.colors, v.ns, v.ng, v.wo,
                                                 wn, subset="all")
    prv = np.ones(1) if delta else Bm.pdf_bsdf(r.mtab, v.mat, v.colors, v.ns, v.ng, wn,
                                                 v.wo, subset="all")
    pend, pend1 = scatter_factors(prv, v.ng, wn, pdf, np.array([delta]), m == 1)
    if m == 1 and delta:
        B1 = np.zeros(1)
    cos_in = abs(np.dot(path[i - 1]["n"], wn[0]))
    return pend * B0 / cos_in, pend1 * B1 / cos_in


def oracle(r, path, nee_owns=True):
    t = r.light_table
    k = len(path) - 1
    row = path[k]["row"]
    y = [np.asarray(v["p"], float) for v in path]
    p_sel = t.p_select[row] / t.p_select.sum()
    if t.kind[row] == 3:                               # AREA
        emit_pos = p_sel / t.area[row]
        emit_dir = lambda w: max(np.dot(t.dir[row], w), 0.0) / np.pi   # noqa: E731
        nee = 0.0
        if k >= 2:
            dv = y[k] - y[k - 1]
            dist = np.linalg.norm(dv)
            nee = (pdf_direct(t, y[k - 1][None], (dv / dist)[None], np.array([row]),
                              np.array([dist]))[0] * abs(np.dot(t.dir[row], dv / dist)) / dist ** 2)
        hittable = True
    else:                                              # POINT, radius 0
        emit_pos = p_sel
        emit_dir = lambda w: 1.0 / (4.0 * np.pi)     # noqa: E731
        nee = _selection_probability(t, y[k - 1][None], np.array([row]))[0]
        hittable = False
    axis = -r.camera.R[:, 2]
    return O.densities(path, r.camera.pixel_area, axis, K_CAM, N_L, emit_pos, emit_dir, nee,
                       hittable, nee_owns)


F1, F2 = (0.2, 0.1, 0.0), (-0.3, 0.4, 0.0)
W1 = (0.3, 2.0, 1.2)
M1 = (1.5, 0.2, 0.9)
LA = (0.1, -0.2, 2.5)

PATHS = {
    "area seen": [("L", LA)],
    "floor-area": [(0, F1), ("L", LA)],
    "floor-wall-area": [(0, F1), (1, W1), ("L", LA)],
    "floor-mirror-area": [(0, F1), (2, M1), ("L", LA)],
    "mirror-floor-area": [(2, M1), (0, F1), ("L", LA)],
    "floor-wall-floor-area": [(0, F1), (1, W1), (0, F2), ("L", LA)],
    "floor-point": [(0, F1), ("P", None)],
    "floor-wall-point": [(0, F1), (1, W1), ("P", None)],
    "floor-mirror-point": [(0, F1), (2, M1), ("P", None)],
    "floor-wall-mirror-point": [(0, F1), (1, W1), (2, M1), ("P", None)],
}


def build(r, spec):
    path = [dict(p=LENS, n=np.zeros(3), kind="camera")]
    for m, p in spec:
        if m == "L":
            path.append(light_vtx(r, 0, p))
        elif m == "P":
            path.append(light_vtx(r, 1, r.light_table.co[1]))
        else:
            path.append(vtx(p, m))
    return path


@pytest.mark.parametrize("name", sorted(PATHS))
def test_mis_weights_equal_the_oracle_and_sum_to_one(rig, name):
    path = build(rig, PATHS[name])
    q = oracle(rig, path)
    w_or = O.power_weights(q)
    w_pt, w_nee = camera_side(rig, path)
    w_lt = light_side(rig, path)
    print(name, "oracle", w_or, "impl", (w_pt, w_nee, w_lt))
    np.testing.assert_allclose([w_pt, w_nee, w_lt], w_or, rtol=1e-9, atol=1e-12)
    assert abs(w_pt + w_nee + w_lt - 1.0) < 1e-9
    # Every strategy that can sample the path has weight > 0 somewhere in the set.
    assert sum(x > 0 for x in q) >= 1


SOFT_SPECS = [[(0, F1)], [(0, F1), (1, W1)], [(0, F1), (2, M1)], [(0, F1), (1, W1), (0, F2)]]


@pytest.mark.parametrize("row", [2, 3], ids=["point", "spot"])
@pytest.mark.parametrize("spec", SOFT_SPECS)
def test_soft_light_weights_depend_on_the_prefix_only(rig, spec, row):
    """A soft point or spot light (radius 0.1): light tracing against the
    camera strategies over the path without its emitter point, evaluated at
    the light's centre on both sides: the camera side's factor (1 - w_LT) on
    next-event estimation (numpy and compiled) equals 1 - the light side's
    w_LT (1e-9)."""
    t = rig.light_table
    path = build(rig, spec) + [light_vtx(rig, row, t.co[row])]
    # Camera side: NEE towards the centre; its combined weight over the
    # two-way weight is 1 - w_LT (no NEE through the mirror: w_LT = 1).
    k = len(path) - 1
    w_lt = light_side(rig, path)
    cam, pt = rig.path_tracer.vc, rig.path_tracer
    if path[k - 1]["kind"] == "mirror":
        assert w_lt == pytest.approx(1.0, abs=1e-12)
        return
    # The prefix ratio q_L / q_C from the camera side at y_{k-1}.
    y = [np.asarray(v["p"], float) for v in path]
    d = _unit(y[1] - y[0])[None]
    v = _pv(rig, path[1], -d[0])
    v.Q, v.c = cam.at_hit(cam.camera_state(d), None, np.zeros(1, np.int64), d, v.ng,
                          np.array([np.linalg.norm(y[1] - y[0])]), 0)
    for j in range(1, k - 1):
        wi = _unit(y[j + 1] - y[j])[None]
        pdf = Bm.pdf_bsdf(rig.mtab, v.mat, v.colors, v.ns, v.ng, v.wo, wi, subset="all")
        Qs, pf = cam.continued(v, np.zeros(1, np.int64), wi, pdf, np.array([False]), j - 1)
        v2 = _pv(rig, path[j + 1], -wi[0])
        v2.Q, v2.c = cam.at_hit(Qs, pf, np.zeros(1, np.int64), wi, v2.ng,
                                np.array([np.linalg.norm(y[j + 1] - y[j])]), j)
        v = v2
    wc = _unit(t.co[row] - y[k - 1])[None]
    dist = np.array([np.linalg.norm(t.co[row] - y[k - 1]) - 0.1])
    rows = np.array([row])
    w2 = pt.mis_light(v, wc, dist, rows)
    w = cam.nee(w2, v, wc, dist, rows, k - 2)
    assert 0.0 < w_lt < 1.0
    np.testing.assert_allclose(w / w2, 1.0 - w_lt, rtol=1e-9)
    pl = pt.pdf_light(v.p, wc, rows, dist, v.ns_wo())
    sel = _selection_probability(t, v.p, rows)
    got = cam.nee_compiled(_path_materials(rig.mtab), w2, v, wc, dist, rows, pl, sel, k - 2)
    np.testing.assert_allclose(got, w, rtol=1e-12)


#: A soft spot over a floor: strength P, radius r, height h, spot size.
SOFT_SPOT = (80.0, 0.3, 1.0, 1.2)


def _soft_spot_scene():
    """The soft spot of SOFT_SPOT aimed down at a Lambert floor (albedo 1)."""
    P, r, h, size = SOFT_SPOT
    return make_scene(quad((0, 0, 0), (4, 0, 0), (0, 4, 0)), [lambert("floor", 1.0)],
                      [Light("s", "SPOT", (P,) * 3, translate(0, 0, h), radius=r,
                             spot_size=size, spot_blend=0.1)],
                      Camera(matrix_world=look_at(LENS, (0.0, 0.0, 0.0)), resolution=(4, 4)))


def _nee_irradiance(t, p, N, compiled, seed):
    """(K,) one-sample next-event estimates of the irradiance at p on the
    floor (normal +z) from the table t (numpy or compiled)."""
    from core import lights as Lt
    from core.lights import direct_kernels as DK
    u = np.random.default_rng(seed).random((N, 3))
    if compiled:
        R = DK.Receivers(q=np.zeros(N, np.int64), p=p[None], n=np.array([[0, 0, 1.0]]),
                         beta=np.ones((1, 3)), albedo=np.ones((1, 3)),
                         const=np.ones(1, bool), u=u)
        out = DK.alloc_samples(N)
        DK.direct_kernel(0, N, DK.build_direct_lights(t), R, out)
        wi, weight = out.wi, out.weight
    else:
        s = Lt.sample_direct(t, np.tile(p, (N, 1)), u)
        wi, weight = s["wi"], s["weight"]
    return np.maximum(wi[:, 2], 0.0) * weight[:, 0]


def _cycles_soft_spot_field(t, x, n=400):
    """Cycles' irradiance at (x, 0, 0) on the floor (normal +z) from the soft
    spot of table t: the disc facing p, radiance x pi r^2 cos_l cos_p / t^2
    with the cone's attenuation of each sample's direction q -> p, averaged
    over the disc uniformly by area (a midpoint quadrature of n x n cells;
    Cycles' ``spot_light_sample``)."""
    from core.lights.table import _spot_atten
    from core.mathutil import frame
    P, r, h, size = SOFT_SPOT
    c, Le = np.array([0.0, 0.0, h]), t.radiance[0, 0]
    rho = np.sqrt((np.arange(n) + 0.5) / n)[:, None]            # uniform by area
    phi = 2 * np.pi * (np.arange(n) + 0.5)[None, :] / n
    p = np.array([x, 0.0, 0.0])
    ln = _unit(p - c)
    t1, t2 = frame(ln[None])
    q = (c + r * ((rho * np.cos(phi))[..., None] * t1[0]
                  + (rho * np.sin(phi))[..., None] * t2[0])).reshape(-1, 3)
    v = q - p
    tt = np.linalg.norm(v, axis=1)
    w = v / tt[:, None]
    cos_l = np.maximum(-(w @ ln), 0.0)
    att = _spot_atten(t, np.zeros(len(q), int), -w)
    return float(np.mean(Le * np.pi * r * r * cos_l * np.maximum(w[:, 2], 0.0) / tt ** 2 * att))


def test_soft_spot_photons_carry_cycles_field():
    """Light tracing and the camera strategies estimate one field, Cycles',
    so that the soft-light weights above sum to one on it (COMBINED) and
    photon mapping's and light tracing's images agree with Cycles.  A soft
    spot's photons (lights.sample_photons: from its centre, a share from the
    wide cone, one disc sample each) multiplied at their first hit on the
    floor by emission.soft_light_first_hit and t^2 / (t^2 + r^2) give, in
    annuli 4 cm wide, the annulus' mean of Cycles' field (the quadrature,
    at eight radii weighted by area) within 4 sigma of the photons' own
    noise: at the centre, in the blend, in the ring just outside the
    centre's cone that no photon of the centre's cone reaches (the wide
    cone's photons light it: the cone's half-angle plus asin(r / h), h the
    nearest triangle's distance), and 0 well outside.  The compiled factor
    and direction (photon_kernels.soft_light_first_hit) equal numpy's to
    1e-12 (factors of order 1)."""
    from core import lights as Lt
    from core.lights.emission import soft_light_first_hit
    from core.sppm import photon_kernels as PK
    P, r, h, size = SOFT_SPOT
    t = Lt.build_light_table(_soft_spot_scene())
    # The tail beyond the cone reaches asin(r / h): the floor, h below the
    # centre, is the nearest triangle.
    tail = t.spot_tail
    assert tail[0, 2] == pytest.approx(math.asin(r / h), rel=1e-6) and 0.01 < tail[0, 0] < 0.5
    ph = Lt.sample_photons(t, 2_000_000, np.random.default_rng(7))
    d = ph["d"]
    down = d[:, 2] < 0
    th = np.where(down, h / np.maximum(-d[:, 2], 1e-300), 0.0)
    ng = np.tile([0.0, 0.0, 1.0], (len(th), 1))
    f = soft_light_first_hit(t, ph["light"], ph["soft_disc"], d, th, ng)[0]
    e = np.where(down, ph["power"][:, 0] * f * th * th / (th * th + r * r), 0.0)
    p = ph["o"] + th[:, None] * d
    rho = np.hypot(p[:, 0], p[:, 1])
    edge = h * math.tan(size / 2)                      # 0.684: the centre's cone edge
    N, dr = len(e), 0.02
    for x in (0.0, 0.6, edge + 0.03, edge + 0.5):
        lo, hi = max(x - dr, 0.0), x + dr
        inb = down & (rho >= lo) & (rho < hi)
        area = math.pi * (hi * hi - lo * lo)
        est, sig = e[inb].sum() / (N * area), math.sqrt((e[inb] ** 2).sum()) / (N * area)
        rk = lo + (hi - lo) * (np.arange(8) + 0.5) / 8
        ref = float(np.average([_cycles_soft_spot_field(t, xk, 200) for xk in rk], weights=rk))
        print(x, "photons", est, "+-", sig, "Cycles' field", ref)
        if x > edge + 0.3:
            assert ref == 0 and est == 0
        else:
            assert ref > 0 and abs(est - ref) <= 4 * sig
    # The compiled factor at the same hits (a floor triangle, Embree's float32 distance).
    k = np.nonzero(down)[0][:50_000]
    K = k.size
    hits = PK.EmbreeHits(np.zeros(K, np.int32), np.zeros(K, np.float32), np.zeros(K, np.float32),
                         th[k].astype(np.float32))
    live = PK.LiveState(np.zeros((K, 3), np.float32), np.zeros((K, 3), np.float32),
                        np.ascontiguousarray(d[k]), np.ones((K, 3)), np.zeros(K))
    PK.soft_light_first_hit(K, hits, live, np.array([[0.0, 0.0, 1.0]]), np.arange(K),
                            np.ascontiguousarray(ph["light"][k], np.int64),
                            np.ascontiguousarray(ph["soft_disc"][k]), PK.soft_lights(t))
    want, want_d = soft_light_first_hit(t, ph["light"][k], ph["soft_disc"][k], d[k],
                                        th[k].astype(np.float32).astype(np.float64), ng[k])
    assert np.any(want == 0) and np.any(want > 1)
    np.testing.assert_allclose(live.power[:, 0], want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(live.d64, want_d, rtol=0, atol=1e-12)


@pytest.mark.parametrize("compiled", [False, True], ids=["numpy", "compiled"])
def test_soft_spot_cone_along_the_sample_as_cycles(compiled):
    """A soft spot's cone is read along each disc
    sample's direction, as Cycles' spot_light_sample does: the irradiance on
    the floor is the disc's, radiance x pi r^2 cos_l cos_p / t^2, averaged
    over the disc facing p (uniform by area) with the cone's attenuation of
    each sample's direction q -> p (a midpoint quadrature of 400 x 400
    cells), so the cone's edge is blurred by the disc's angular size and a
    ring just outside the centre's cone is lit.  Next-event estimation
    (numpy and compiled) within 4 sigma at the centre, in the blend, just
    outside and well outside the centre's cone (0 there: no disc sample's
    direction is inside); a BSDF ray from just outside to the disc's side
    inside the cone finds radiance x the attenuation of its direction."""
    from core import lights as Lt
    from core.lights.table import _spot_atten
    P, r, h, size = SOFT_SPOT
    t = Lt.build_light_table(_soft_spot_scene())
    Le = t.radiance[0, 0]
    N = 20_000
    edge = h * math.tan(size / 2)
    lit_outside = []
    for i, x in enumerate((0.0, 0.6, edge + 0.03, edge + 0.5)):
        p = np.array([x, 0.0, 0.0])
        ref = _cycles_soft_spot_field(t, x)
        e = _nee_irradiance(t, p, N, compiled, 11 + i)
        print(x, "NEE", e.mean(), "+-", e.std() / math.sqrt(N), "Cycles' field", ref)
        assert abs(e.mean() - ref) <= 4 * e.std() / math.sqrt(N) + 1e-12 * P
        if x > edge:
            lit_outside.append(ref)
    assert lit_outside[0] > 0 and lit_outside[1] == 0     # the ring outside, then dark
    o = np.array([[edge + 0.03, 0.0, 0.0]])
    d = _unit(np.array([0.25, 0.0, h]) - o[0])[None]
    got = Lt.emitted_along_rays(t, o, d, np.full(1, np.inf))[0, 0]
    att = _spot_atten(t, np.zeros(1, int), -d)[0]
    assert att > 0 and got == pytest.approx(Le * att, rel=1e-12)


@pytest.mark.parametrize("spec,w_pt", [([(2, M1)], 1.0), ([(0, F1), (2, M1)], 0.0)])
def test_soft_light_after_a_mirror(rig, spec, w_pt):
    """A soft light found by a BSDF ray right after a mirror: no light sample
    can take the path; light tracing takes it all when y_1 is diffuse
    (camera side 0, light side 1), path tracing when y_1 is the mirror
    (camera side 1, light side 0: a light seen in a mirror)."""
    t = rig.light_table
    path = build(rig, spec) + [light_vtx(rig, 2, t.co[2])]
    w, _ = camera_side(rig, path)
    assert w == w_pt
    assert light_side(rig, path) == 1.0 - w_pt


# ------------------------------------------------------------------ images
def _render(scene, seed, **kw):
    st = RenderSettings(**{"integrator": "COMBINED", "max_passes": 4, "camera_samples": 4,
                           "photons_per_pass": 40_000, "seed": seed, **kw})
    return Renderer(scene, st, log=lambda s: None).run().image[..., :3].astype(np.float64)


def _two_seeds(scene, **kw):
    """(mean image, per-pixel sigma of the mean) from two seeds, the sigma
    pooled over the image (pixels independent)."""
    a, b = _render(scene, 1, **kw).mean(axis=2), _render(scene, 2, **kw).mean(axis=2)
    d = a - b
    return 0.5 * (a + b), np.sqrt(np.mean(d * d) / 4.0)


def test_point_light_plane_closed_form():
    scene, Lfun = point_light_plane(res=16)
    X, Y = pixel_centres_ortho(scene)
    pix = scene.camera.ortho_scale / scene.camera.resolution[0]
    exp = filtered(Lfun, X, Y, pix, n=16)
    m, s = _two_seeds(scene)
    # Image mean within 4 sigma of the mean; per pixel mean z^2 ~ 1.
    s_mean = s / math.sqrt(m.size)
    print("mean ratio", m.mean() / exp.mean(), "rel sigma", s_mean / exp.mean())
    assert abs(m.mean() - exp.mean()) < 4 * s_mean + 1e-3 * exp.mean()
    z2 = np.mean(((m - exp) / s) ** 2)
    print("mean z^2", z2)
    assert z2 < 1.5


@pytest.mark.parametrize("merge_weights", ["PARTITION", "MIS"])
def test_mirror_caustic_that_path_tracing_misses(merge_weights):
    """Point light under a mirror (max_bounces 1): the floor's caustic is
    reached by light tracing only (w_LT = 1 through the mirror) -- and, with
    merging as an MIS strategy, by merging at y_1 as well (light tracing and
    merging share it by q_M / q_L = pi r^2 c_1); the combined image matches
    the closed form inside the footprint, where PATH is 13% dark."""
    scene, Lfun, half = mirror_caustic(res=16)
    X, Y = pixel_centres_ortho(scene)
    pix = scene.camera.ortho_scale / scene.camera.resolution[0]
    exp = filtered(Lfun, X, Y, pix, n=32)
    m, s = _two_seeds(scene, max_bounces=1, merge_weights=merge_weights)
    inside = (np.abs(X) < half - 2 * pix) & (np.abs(Y) < half - 2 * pix)
    s_in = s / math.sqrt(inside.sum())
    ratio = m[inside].mean() / exp[inside].mean()
    print("inside ratio", ratio, "rel sigma", s_in / exp[inside].mean())
    assert abs(m[inside].mean() - exp[inside].mean()) < 4 * s_in + 2e-3 * exp[inside].mean()
    z2 = np.mean(((m - exp) / s) ** 2)
    print("mean z^2", z2)
    assert z2 < 1.5


@pytest.mark.parametrize("merge_weights", ["PARTITION", "MIS"])
def test_white_furnace(merge_weights):
    """Emissive closed box (mesh emitters seen directly and through every
    bounce: all three strategies): Le / (1 - rho) within 4 sigma.  With
    merging as an MIS strategy the plan merges here too (diffuse
    interreflection, no mirror; measured 0.997, sigma 0.48%)."""
    scene, L = furnace_box(res=8)
    st = RenderSettings(integrator="COMBINED", max_passes=1, merge_weights=merge_weights)
    assert Renderer(scene, st, log=lambda s: None).merge_mis == (merge_weights == "MIS")
    m, s = _two_seeds(scene, max_bounces=64, rr_start=2, photons_per_pass=10_000,
                      merge_weights=merge_weights)
    s_mean = s / math.sqrt(m.size)
    print("furnace ratio", m.mean() / L, "rel sigma", s_mean / L)
    assert s_mean < 0.006 * L
    assert abs(m.mean() - L) < 4 * s_mean


def test_plan_names_the_strategies():
    scene, _ = point_light_plane(res=8)
    r = Renderer(scene, RenderSettings(integrator="COMBINED", max_passes=1), log=lambda s: None)
    line = r.plan_lines()[1]
    assert "strategies: camera paths" in line and "light tracing" in line and "MIS" in line


@pytest.mark.parametrize("integrator", ["LIGHT", "COMBINED"])
def test_no_light_through_a_single_sided_quad(integrator):
    """A quad (normal facing the camera below it) lit only on its far side by
    a point light: nothing reaches the camera.  The splat's BSDF must get the
    mesh's normals (the deposit's ng is flipped to the photon's side; with
    the mesh's ns that made eval_bsdf see wo and wi on one side, +94% on
    example_blends/principled_interior.blend)."""
    tris = quad((0, 0, 1.0), (0, 2.0, 0), (2.0, 0, 0))            # normal -Z
    cam = Camera(kind="ORTHO", matrix_world=np.diag([1.0, -1.0, -1.0, 1.0]), ortho_scale=1.5,
                 resolution=(8, 8), clip_start=0.01, clip_end=100.0)   # at z = 0 looking up
    scene = make_scene(tris, [lambert("ceiling", 0.8)],
                       [Light("p", "POINT", (100.0,) * 3, translate(0, 0, 1.5))], cam)
    img = Renderer(scene, RenderSettings(integrator=integrator, max_passes=2,
                                         photons_per_pass=20_000, seed=1),
                   log=lambda s: None).run().image[..., :3]
    assert np.all(img == 0)


def test_light_paths_start_on_traced_emitters_only():
    """A square area light over a Lambert plane under a constant world:
    light tracing does not follow the world's light (class NO_LT), so its
    light paths are drawn from the area light alone (``mis.traced_table``:
    no world photon drawn and dropped, the compiled emission), and the
    weights use that selection (``mis.emit_select``).  The image agrees with
    PATH's (the unbiased reference of tests/test_path_tracer.py) within 4
    sigma of the image mean (two seeds of each; measured +0.12 % of the
    mean, 0.5 sigma)."""
    import dataclasses
    from core.lights.table import WORLD
    scene, _ = area_light_plane(res=16)
    scene = dataclasses.replace(scene, world_color=np.array([0.3, 0.3, 0.3]))
    r = Renderer(scene, RenderSettings(integrator="COMBINED", max_passes=1), log=lambda s: None)
    t, lt = r.light_table, r.combined_lt
    world = t.kind == WORLD
    assert t.p_select[world].sum() > 0.1
    assert lt.emit_table.p_select[world].sum() == 0.0
    assert abs(lt.emit_table.p_select.sum() - 1.0) < 1e-12 and lt.fast_emission
    from core.sppm import photon_kernels as PK
    ph = PK.sample_photons_fast(lt.emit_table, 10_000, np.random.default_rng(3))
    assert not np.any(world[ph["light"]])
    comb, s_c = _two_seeds(scene)
    path, s_p = _two_seeds(scene, integrator="PATH", max_passes=16)
    sigma = math.sqrt((s_c ** 2 + s_p ** 2) / comb.size)
    diff = comb.mean() - path.mean()
    print("COMBINED - PATH", diff / path.mean(), "sigma", sigma / path.mean())
    assert abs(diff) < 4.0 * sigma
    assert sigma < 0.01 * path.mean()

