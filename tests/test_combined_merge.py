"""Photon merging in integrator 'COMBINED' (core.integrators.merge).

1. The partition: on concrete paths of both classes in test_combined's rig,
   merging's weight (0 or 1) and the tracers' weights times the
   PathTracer's partition factor equal tests/oracle_mis.py's and sum to one;
   on every lobe sequence up to 5 vertices the classification equals the
   oracle's.
2. Images: a point light's caustic (a mirror above the light) seen through
   a second mirror -- only merging renders it (path tracing cannot hit a
   radius-0 light, next-event estimation cannot go through the mirror,
   light tracing cannot join the mirror to the lens).  COMBINED's mean
   equals the closed form and PHOTON's within the noise of two seeds;
   COMBINED without merging misses the caustic (~19% dark).
"""
import itertools
import math

import numpy as np
import pytest

from core.integrators.merge import CameraPartition
from core.render import Renderer
from core.scene.model import GLOSSY, Camera, Light, Lobe, Material, make_scene
from core.settings import RenderSettings

import oracle_mis as O
from analytic_scenes import lambert, quad, translate
from test_combined import LA, M1, MAT, PATHS, F1, build, camera_side, light_side, oracle, rig  # noqa: F401

KINDS = ("lambert", "mirror")
F3 = (0.6, -0.4, 0.0)
M2 = (1.5, -0.1, 1.2)
# Paths of the rig of test_combined beyond its MIS paths: merging owns the
# ones whose first non-mirror vertex is seen in the mirror and lit through it.
MERGE_PATHS = {
    "mirror-floor-mirror-area": [(2, M1), (0, F1), (2, M2), ("L", LA)],
    "mirror-floor-mirror-point": [(2, M1), (0, F1), (2, M2), ("P", None)],
    "mirror-floor-mirror-floor-area": [(2, M1), (0, F1), (2, M2), (0, F3), ("L", LA)],
    "mirror-floor-mirror-floor-point": [(2, M1), (0, F1), (2, M2), (0, F3), ("P", None)],
}


def _partition(path):
    """(PT factor, NEE factor) of CameraPartition fed the path's lobes as the
    PathTracer feeds it: NEE is taken at y_{k-1} (before its sample), PT
    emission after the sample at y_{k-1}."""
    p = CameraPartition(1)
    for v in path[1:-2]:
        p.sampled(np.array([v["kind"] == "mirror"]))
    f_nee = p.weight()[0]
    p.sampled(np.array([path[-2]["kind"] == "mirror"]))
    return p.weight()[0], f_nee


@pytest.mark.parametrize("name", sorted(PATHS) + sorted(MERGE_PATHS))
def test_partition_weights_sum_to_one(rig, name):
    """The rig's paths of both classes: the implementation's weights (MIS of
    the tracers times the partition factor, merging's 0/1) equal the
    oracle's and sum to one."""
    path = build(rig, {**PATHS, **MERGE_PATHS}[name])
    w_or = O.merge_weights(path, oracle(rig, path))
    f_pt, f_nee = _partition(path)
    w_pt, w_nee = camera_side(rig, path)
    w_lt = light_side(rig, path)
    w_m = 1.0 - f_pt
    if name == "mirror-floor-mirror-area":
        assert w_pt == 1.0              # path tracing's alone before the partition
    if path[-2]["kind"] != "mirror":
        assert f_pt == f_nee                      # one class per path
    else:
        assert w_nee == 0.0                       # no light sample at a mirror
    w = np.array([w_pt * f_pt, w_nee * f_nee, w_lt, w_m])
    print(name, "oracle", w_or, "impl", w)
    assert (name in MERGE_PATHS) == O.merge_owned(path) == (w_m == 1.0)
    np.testing.assert_allclose(w, w_or, rtol=1e-9, atol=1e-12)
    assert abs(w.sum() - 1.0) < 1e-9


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_partition_of_every_lobe_sequence(n):
    """Every sequence of n scattering vertices (mirror or Lambert) before the
    emitter: the PathTracer's classification equals the oracle's."""
    classes = set()
    for kinds in itertools.product(KINDS, repeat=n):
        path = ([dict(kind="camera")] + [dict(kind=k) for k in kinds] + [dict(kind="light")])
        f_pt, f_nee = _partition(path)
        own = O.merge_owned(path)
        classes.add(own)
        assert f_pt == 1.0 - own
        if kinds[-1] == "lambert":
            assert f_nee == 1.0 - own
    assert classes == ({True, False} if n >= 3 else {False})


# ------------------------------------------------------------------ images
H_LIGHT, H_M1, A1, RHO, RHO_M = 1.0, 2.0, 0.5, 0.8, 0.9
P_LIGHT = 100.0
RES, HALF = 12, 0.3


def _scene():
    """Floor z = 0, a point light at z = 1 under a downward mirror M1 (half
    size 0.5 at z = 2): its caustic covers |x|, |y| < 1.5.  An orthographic
    camera at (10, 0, 4) looks along -x at a 45-degree mirror M2 centred at
    (1, 0, 4), which shows the floor x in [0.7, 1.3], |y| < 0.3 (floor x =
    camera z - 3) -- inside the caustic."""
    tris = (quad((0, 0, 0), (10, 0, 0), (0, 10, 0))
            + quad((0, 0, H_M1), (0, A1, 0), (A1, 0, 0))                  # normal -Z
            + quad((1.0, 0, 4.0), (0, HALF, 0), (HALF, 0, HALF)))         # normal (1, 0, -1)
    mirror = Material("mirror", (Lobe(GLOSSY, (RHO_M,) * 3, roughness=0.0),))
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = (0, 1, 0), (0, 0, 1), (1, 0, 0), (10, 0, 4)
    cam = Camera(kind="ORTHO", matrix_world=M, ortho_scale=2 * HALF, resolution=(RES, RES),
                 clip_start=0.01, clip_end=100.0)
    light = Light("point", "POINT", (P_LIGHT,) * 3, translate(0, 0, H_LIGHT))
    return make_scene(tris, [lambert("floor", RHO), mirror], [light], cam,
                      tri_mat=[0, 0, 1, 1, 1, 1])


def _expected(r, caustic=True, n=64):
    """(RES, RES) radiance of the pixels (row 0 at the top), filtered: the
    renderer's camera rays (n filter samples per pixel) reflected by M2 to
    the floor, where the closed form is the point light's irradiance plus
    its image in M1 (rho_m I z' / d'^3 inside M1's footprint)."""
    H, W = RES, RES
    py, px = np.mgrid[0:H, 0:W]
    px = np.repeat(px.ravel(), n).astype(float)
    py = np.repeat((H - 1 - py).ravel(), n).astype(float)
    u = np.random.default_rng(0).random((px.size, 2))
    rays, _ = r.camera.generate(px, py, u, np.zeros_like(u), r.fsamp)
    o, d = rays.o, rays.d
    nrm = np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0)
    t = ((np.array([1.0, 0, 4.0]) - o) @ nrm) / (d @ nrm)
    hit = o + t[:, None] * d
    dr = d - 2.0 * (d @ nrm)[:, None] * nrm
    f = hit - (hit[:, 2] / dr[:, 2])[:, None] * dr         # on the floor z = 0
    x, y = f[:, 0], f[:, 1]
    I = P_LIGHT / (4 * np.pi)
    E = I * H_LIGHT / (x * x + y * y + H_LIGHT ** 2) ** 1.5
    if caustic:
        zi = 2 * H_M1 - H_LIGHT
        tt = (zi - H_M1) / zi
        inside = (np.abs(x * tt) < A1) & (np.abs(y * tt) < A1)
        E = E + np.where(inside, RHO_M * I * zi / (x * x + y * y + zi * zi) ** 1.5, 0.0)
    return (RHO_M * RHO / np.pi * E).reshape(H * W, n).mean(axis=1).reshape(H, W)


def _render(integrator, seed, merging=True, merge_weights="PARTITION"):
    st = RenderSettings(integrator=integrator, max_passes=4, camera_samples=4,
                        photons_per_pass=40_000, seed=seed, max_bounces=4,
                        merge_weights=merge_weights)
    r = Renderer(_scene(), st, log=lambda s: None)
    if not merging:
        r.merging = r.path_tracer.vc.merging = r.tracer.after_delta_only = False
    return r, r.run().image[..., :3].astype(np.float64).mean(axis=2)


def test_caustic_seen_through_a_mirror():
    inner = np.s_[1:-1, 1:-1]                        # pixels fully on M2
    out = {}
    for name, integ, merge, mw in (("COMBINED", "COMBINED", True, "PARTITION"),
                                   ("PHOTON", "PHOTON", True, "PARTITION"),
                                   ("no merging", "COMBINED", False, "PARTITION"),
                                   ("MIS", "COMBINED", True, "MIS")):
        r, a = _render(integ, 1, merge, mw)
        _, b = _render(integ, 2, merge, mw)
        m = 0.5 * (a + b)[inner].mean()
        s = abs(a[inner].mean() - b[inner].mean()) / 2.0 + 1e-12   # one-pair sigma of m
        out[name] = (m, s, r)
    mc, sc, rc = out["COMBINED"]
    mn, sn, _ = out["no merging"]
    mp, sp, _ = out["PHOTON"]
    e = _expected(rc)[inner].mean()
    caustic = e - _expected(rc, caustic=False)[inner].mean()
    # The reference: what the camera paths render without merging (direct
    # light, and the floor's own light seen in M1: a path merging owns, but
    # not one the closed form has) plus the closed-form caustic, 19% of e.
    ref = mn + caustic
    for k, (m, s, _) in out.items():
        print(k, "ratio to reference", m / ref, "rel sigma", s / ref)
    assert "photon merging" in " ".join(rc.plan.strategies)
    assert caustic > 0.15 * e
    # SPPM's smoothing at 4 passes: measured -0.9% (COMBINED), -0.8% (PHOTON).
    assert abs(mc - ref) < 0.02 * ref + 4 * math.hypot(sc, sn)
    assert abs(mc - mp) < 0.02 * ref + 4 * math.hypot(sc, sp)
    assert abs(mc - ref) < 0.1 * abs(mn - ref)      # no merging: the caustic is missing
    # Merging as an MIS strategy (measured 0.993 of the reference, sigma 0.6%).
    mm, sm, rm = out["MIS"]
    assert rm.merge_mis
    assert abs(mm - ref) < 0.02 * ref + 4 * math.hypot(sm, sn)


def test_plan_leaves_merging_out_without_mirror_or_glass():
    from analytic_scenes import point_light_plane
    scene, _ = point_light_plane(res=8)
    r = Renderer(scene, RenderSettings(integrator="COMBINED", max_passes=1), log=lambda s: None)
    assert not r.merging
    assert "photon merging" in dict(r.plan.left_out)
    assert not r.plan.frequency_photons


def test_tracer_keeps_the_deposits_after_a_delta_scattering(rig):
    """PhotonTracer.after_delta_only on the rig (floor, wall, mirror; both
    photon batches): the same random stream gives the deposits of the plain
    tracer whose ray back along wi meets the mirror first, in order."""
    tr = rig.tracer
    try:
        tr.after_delta_only = False
        full = tr.trace(20_000, 5_000, np.random.default_rng(5))
        tr.after_delta_only = True
        kept = tr.trace(20_000, 5_000, np.random.default_rng(5))
    finally:
        tr.after_delta_only = rig.merging
    h = rig.accel.intersect(rig.accel.spawn(full["p"], full["ng"], full["wi"]), full["wi"],
                            np.full(full["p"].shape[0], np.inf))
    from_mirror = h.hit & (rig.scene.tri_mat[np.maximum(h.prim, 0)] == MAT["mirror"])
    print("deposits", full["p"].shape[0], "after the mirror", int(from_mirror.sum()))
    assert 100 < from_mirror.sum() < 0.5 * from_mirror.size
    for k in ("p", "wi", "power", "bounce"):
        np.testing.assert_array_equal(kept[k], full[k][from_mirror])


@pytest.mark.parametrize("merge_weights", ["PARTITION", "MIS"])
def test_checkpoint_resumes_merging_bit_for_bit(merge_weights):
    """Two passes, a checkpoint, one more pass = three passes straight (the
    merging state lives in the PixelState, its streams per pass and stage;
    MIS: the merged radiance in the splat sums)."""
    st = RenderSettings(integrator="COMBINED", max_passes=3, camera_samples=1,
                        photons_per_pass=5_000, seed=3, max_bounces=4,
                        merge_weights=merge_weights)
    whole = Renderer(_scene(), st, log=lambda s: None).run().image
    a = Renderer(_scene(), st, log=lambda s: None)
    a.step(), a.step()
    b = Renderer(_scene(), st, log=lambda s: None)
    b.load_state(a.state_dict())
    assert b.merging and (b.merge_mis or np.any(b.state.tau > 0))
    assert b.merge_mis == (merge_weights == "MIS")
    np.testing.assert_array_equal(b.run().image, whole)


# ------------------------------------------------- merging as an MIS strategy
from core import materials as Bm  # noqa: E402
from core.integrators.combined import first_hit_ratios, nee_owned_rows, splat_weight  # noqa: E402
from core.integrators.mis import light_classes  # noqa: E402
from core.integrators.merge import merge_weight  # noqa: E402
from core.integrators.merge_kernels import y1_terms  # noqa: E402
from test_combined import K_CAM, N_L, W1, _pv, _unit, light_scatter, light_vtx  # noqa: E402

# Paths where merging is a strategy at v = 1 (light tracing competes) and
# v = 2 (through the mirror), with the area light and the radius-0 point light.
VCM_PATHS = {
    **PATHS, **MERGE_PATHS,
    "floor-mirror-floor-point": [(0, F1), (2, M1), (0, F3), ("P", None)],
    "mirror-floor-wall-area": [(2, M1), (0, F1), (1, (0.3, 2.0, 1.2)), ("L", LA)],
    "mirror-floor-wall-point": [(2, M1), (0, F1), (1, (0.3, 2.0, 1.2)), ("P", None)],
}

# The paths merging can sample (k >= v + 2).
VCM_MERGED = {"floor-wall-area", "floor-wall-floor-area", "floor-wall-point",
              "floor-mirror-area", "floor-mirror-point", "floor-wall-mirror-point",
              "floor-mirror-floor-point", *MERGE_PATHS, "mirror-floor-wall-area",
              "mirror-floor-wall-point"}


@pytest.fixture
def mis_rig(rig):  # noqa: F811
    """The rig with merging as an MIS strategy: per-pixel radii 0.07 .. 0.17."""
    r = rig
    R2 = np.random.default_rng(3).uniform(0.005, 0.03, r.width * r.height)
    region = (*r.offset, r.width, r.height)
    r.path_tracer.vc.mis_merge = (R2, float(N_L), region)
    try:
        yield r, R2, region
    finally:
        r.path_tracer.vc.mis_merge = None


def _r2_of(r, R2, region, y1):
    rows = y1_terms(r.camera, np.asarray(y1, float)[None], np.full((1, 2), 0.5), region)[0]
    return R2[rows[0]]


def light_side_mis(r, path, R2, region):
    """(w_LT, w_M) from the light path's B0, B1 (CombinedLightTracer's
    functions): the splat at y_1 with merging's term, the merge at y_v."""
    t = r.light_table
    k = len(path) - 1
    y = [np.asarray(v["p"], float) for v in path]
    row = np.array([path[k]["row"]])
    kn = K_CAM / N_L
    kinds = [q["kind"] for q in path]
    vv = next((i for i in range(1, k) if kinds[i] != "mirror"), None)
    pr = r.camera.project(y[1][None], np.full((1, 2), 0.5))
    r2 = _r2_of(r, R2, region, y[1])
    c1_y1 = pr.weight * abs(np.dot(path[1]["n"], pr.wi[0]))
    if k == 1:
        return 1.0 - camera_side(r, path, merge=True)[0], 0.0
    z0 = y[k] if t.kind[row[0]] in (3, 4) else t.co[row[0]]
    B0, B1 = first_hit_ratios(t, kn, row, z0[None], _unit(y[k - 1] - z0)[None],
                              y[k - 1][None], path[k - 1]["n"][None])
    soft = np.array([t.radius[row[0]] > 0])
    w_lt = w_m = 0.0
    for m in range(1, k):
        i = k - m                                   # z_m = y_i
        v = _pv(r, path[i], _unit(y[i + 1] - y[i]))
        if i == vv and m >= 2:
            wo = _unit(y[i - 1] - y[i])[None]       # towards the camera
            pf = Bm.pdf_bsdf(r.mtab, v.mat, v.colors, v.ns, v.ng, wo, v.wo, subset="all")
            w_m = merge_weight(B0, B1, pf, np.array([1.0 / (np.pi * r2)]), c1_y1,
                               np.array([vv == 1]))[0]
        if i == 1:
            if kinds[1] != "mirror":
                wc = pr.wi
                pf = Bm.pdf_bsdf(r.mtab, v.mat, v.colors, v.ns, v.ng, wc, v.wo, subset="all")
                bm = np.array([0.0 if m == 1 else np.pi * r2 * c1_y1[0]])
                if m == 1 and nee_owned_rows(t, light_classes(t))[row[0]]:
                    B1 = np.full(1, np.inf)          # CombinedLightTracer._chunk
                w_lt = splat_weight(B0, B1, pf, c1_y1, m == 1, soft, bm)[0]
            return w_lt, w_m
        B0, B1 = light_scatter(r, path, y, i, m, v, B0, B1)


@pytest.mark.parametrize("name", sorted(VCM_PATHS))
def test_merging_mis_weights_equal_the_oracle_and_sum_to_one(mis_rig, name):
    """PT, NEE (camera side with CameraMerge), LT (the splat with merging's
    term) and M (merge_weight of the photon's B0, B1 at y_v) equal the power
    heuristic of the oracle's four brute-force densities and sum to one."""
    r, R2, region = mis_rig
    path = build(r, VCM_PATHS[name])
    # q_M from the oracle's products (its c and l), r of y_1's pixel.
    q = _vcm_oracle(r, path, _r2_of(r, R2, region, path[1]["p"]))
    np.testing.assert_allclose(q[:3], oracle(r, path), rtol=1e-12)
    assert (q[3] > 0) == (name in VCM_MERGED)
    w_or = O.power_weights(q)
    w_pt, w_nee = camera_side(r, path, merge=True)
    w_lt, w_m = light_side_mis(r, path, R2, region)
    w = np.array([w_pt, w_nee, w_lt, w_m])
    print(name, "q", q, "oracle", w_or, "impl", w)
    np.testing.assert_allclose(w, w_or, rtol=1e-9, atol=1e-12)
    assert abs(w.sum() - 1.0) < 1e-9


def _vcm_oracle(r, path, r2):
    """oracle() of test_combined with q_M (tests/oracle_mis.vcm_densities)."""
    import test_combined as TC
    captured = {}
    real = O.densities

    def grab(*a):
        captured["a"] = a
        return real(*a)
    O.densities = grab
    try:
        TC.oracle(r, path)
    finally:
        O.densities = real
    return np.array(O.vcm_densities(*captured["a"][:9], N_L, r2))


@pytest.mark.parametrize("use_frequency", [True, False])
def test_merging_takes_a_share_of_the_point_caustic(monkeypatch, use_frequency):
    """The point light's caustic under a mirror seen directly (v = 1): with
    merging as an MIS strategy the merged radiance is a sizeable part of the
    image (light tracing and merging share the caustic paths; measured 14%
    of the image's mean at the initial radius), and the radius reduction
    counts photons (with the frequency kernel's holds or the PPM rule).  The
    Lambert kernel of the gather equals its numpy path (eval_bsdf,
    pdf_bsdf: visible points marked non-Lambert), 1e-12."""
    from dataclasses import replace
    from analytic_scenes import mirror_caustic
    import core.integrators.merge_kernels as MK
    scene, _, _ = mirror_caustic(res=16)
    got = []
    real = MK.merge_gather

    def spy(*a, **k):
        L, M = real(*a, **k)
        got.append((L.mean(), M.sum()))
        if len(got) == 1:
            vp = a[0]
            L2, M2 = real(replace(vp, const=np.zeros_like(vp.const)), *a[1:], **k)
            np.testing.assert_array_equal(M2, M)
            np.testing.assert_allclose(L2, L, rtol=1e-12, atol=1e-12 * L.max())
            assert vp.const[vp.valid].all() and L.max() > 0
        return L, M
    monkeypatch.setattr(MK, "merge_gather", spy)
    r = Renderer(scene, RenderSettings(integrator="COMBINED", max_passes=2, max_bounces=1,
                                       photons_per_pass=20_000, seed=1, merge_weights="MIS",
                                       use_frequency=use_frequency),
                 log=lambda s: None)
    # The frequency kernel's radii come from a pass of frequency photons alone.
    assert (r.merge_freq_pass is not None) == use_frequency
    r.step()
    R2_0 = r.state.R2.copy()
    img = r.run().image[..., :3].astype(np.float64)
    assert r.merge_mis and len(got) == 2
    share = np.mean([g[0] for g in got]) / r.settings.photons_per_pass / img.mean()
    print("merged share of the image", share)
    assert 0.05 < share < 0.5
    assert all(g[1] > 0 for g in got)
    valid = R2_0 > 0
    assert np.all(r.state.R2[valid] <= R2_0[valid]) and np.any(r.state.R2[valid] < R2_0[valid])


SOFT_SPECS = {
    "floor-wall-soft": [(0, F1), (1, W1)],
    "floor-wall-floor-soft": [(0, F1), (1, W1), (0, F3)],
    "mirror-floor-wall-soft": [(2, M1), (0, F1), (1, W1)],
    "floor-mirror-soft": [(0, F1), (2, M1)],
    "mirror-floor-mirror-soft": [(2, M1), (0, F1), (2, M2)],
}


@pytest.mark.parametrize("name", sorted(SOFT_SPECS))
def test_soft_light_merging_weights_sum_to_one(mis_rig, name):
    """A soft point light (radius 0.1; light tracing and merging against the
    camera strategies as one, at the light's centre): the camera side's
    factor (NEE's weight over its two-way weight, or PT's after a mirror at
    y_{k-1}) + w_LT + w_M = 1 (1e-9), merging > 0 on each of these paths."""
    r, R2, region = mis_rig
    t = r.light_table
    path = build(r, SOFT_SPECS[name]) + [light_vtx(r, 2, t.co[2])]
    k = len(path) - 1
    y = [np.asarray(v["p"], float) for v in path]
    w_pt, w_nee = camera_side(r, path, merge=True)
    w_lt, w_m = light_side_mis(r, path, R2, region)
    if path[k - 1]["kind"] == "mirror":
        camera = w_pt               # a light sample cannot take it: 0 when LT or M can
        assert camera == 0.0
    else:
        v = _pv(r, path[k - 1], _unit(y[k - 2] - y[k - 1]))
        wc = _unit(y[k] - y[k - 1])[None]
        w2 = r.path_tracer.mis_light(v, wc, np.array([np.linalg.norm(y[k] - y[k - 1])]),
                                     np.array([2]))[0]
        camera = w_nee / w2
    print(name, "camera", camera, "LT", w_lt, "M", w_m)
    assert w_m > 0.0
    assert abs(camera + w_lt + w_m - 1.0) < 1e-9


def test_mis_frequency_photons_are_amortised():
    """Merging as an MIS strategy traces pass k's frequency photons as
    PHOTON does (photons_per_pass x frequency_fraction x k^-frequency_decay,
    core.sppm.photon_pass.frequency_photons), every one with a spectrum;
    frequency_start 1 (from pass 1; with S the schedule runs from pass S,
    tests/test_frequency_schedule.py::test_frequency_start_schedule)."""
    st = RenderSettings(integrator="COMBINED", max_passes=3, camera_samples=1,
                        photons_per_pass=8_000, seed=3, max_bounces=4, merge_weights="MIS",
                        frequency_start=1)
    r = Renderer(_scene(), st, log=lambda s: None)
    traced = []
    fp = r.merge_freq_pass
    call = type(fp).__call__

    def spy(self, *a, **k):
        traced.append(self.chunks())
        return call(self, *a, **k)
    fp.__class__ = type("Spy", (type(fp),), {"__call__": spy})
    r.run()
    # the default frequency_decay 2: round(2,000 x k^-2), in every pass (no doubling schedule)
    assert traced == [[(2000, 2000)], [(500, 500)], [(222, 222)]]
