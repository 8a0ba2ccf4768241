"""Tests of core.lights against closed forms in Cycles' units.

Tolerances: every Monte-Carlo comparison uses Z = 5 standard errors, the
standard error being measured from the same samples (std / sqrt(N)); a correct
estimator fails such a check with probability 6e-7, and seeds are fixed.
Chi-square tests bin photon directions on the sphere in (cos theta, phi) around
the light's axis, take expected counts from the analytic CDF, pool bins with
fewer than 5 expected, and require p > 0.01 / (number of chi-square tests)
(Bonferroni).
"""
import math
from dataclasses import dataclass

import numpy as np
import pytest

from core import lights as L
from core.lights.table import _spot_atten
from core.lights.warps import _normalize, _uniform_sphere
from core.mathutil import frame as _basis
from core.scene.model import Camera, Light, Material, make_scene

from stats_helpers import chi2_sf

Z = 5.0
N_CHI_TESTS = 5
FLOOR = [[[-5, -5, 0], [5, -5, 0], [5, 5, 0]], [[-5, -5, 0], [5, 5, 0], [-5, 5, 0]]]
CAM = Camera(matrix_world=np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 6.0], [0, 0, 0, 1]]))


@dataclass(frozen=True)
class SphereLight(Light):
    """A light with Cycles' 'Soft Falloff' off (sphere model)."""
    use_soft_falloff: bool = False


def mat(loc=(0, 0, 0), rot=np.eye(3), scale=(1, 1, 1)):
    m = np.eye(4)
    m[:3, :3] = np.asarray(rot, float) @ np.diag(scale)
    m[:3, 3] = loc
    return m


def rot_to(direction):
    """Rotation whose local -Z maps to ``direction`` (a light aimed there)."""
    z = -np.asarray(direction, float) / np.linalg.norm(direction)
    a = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def scene(lights, materials=(Material("floor"),), tris=FLOOR, tri_mat=None, world=(0, 0, 0)):
    return make_scene(tris, list(materials), list(lights), CAM, tri_mat=tri_mat,
                      world_color=world)


def direct_mean(table, p, n_up, K=200_000, seed=1, albedo=1.0):
    """Mean and standard error of albedo/pi * |cos| * weight at a receiver (n_up normal)."""
    rng = np.random.default_rng(seed)
    P = np.broadcast_to(np.asarray(p, float), (K, 3))
    r = L.sample_direct(table, P, rng.random((K, 3)))
    cos = r["wi"] @ np.asarray(n_up, float)
    # Only the upper hemisphere reaches a Lambertian receiver (f = 0 below).
    est = albedo / np.pi * np.where(cos > 0, cos, 0.0) * r["weight"][:, 0]
    return est.mean(), est.std() / math.sqrt(K)


def polygon_irradiance(verts, p, n):
    """Lambert's contour integral: irradiance / L at p (normal n) from a polygon
    fully above the horizon: E/L = 1/2 |sum_i Theta_i n . unit(r_i x r_{i+1})|."""
    r = np.asarray(verts, float) - p
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    s = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        c = np.cross(a, b)
        s += math.acos(np.clip(a @ b, -1, 1)) * (n @ c) / np.linalg.norm(c)
    return 0.5 * abs(s)


def parallel_disc_irradiance(r, h, x):
    """E/L on a plane parallel to a disc (radius r) at height h, offset x from its axis."""
    return 0.5 * math.pi * (1 - (h * h + x * x - r * r)
                            / math.sqrt((h * h + x * x + r * r) ** 2 - 4 * r * r * x * x))


def smoothstep_solid_angle(size, blend, n=200_001):
    """int smoothstep dω of a spot by trapezoid quadrature in mu = cos(angle)."""
    c = math.cos(size / 2)
    mu = np.linspace(c, 1.0, n)
    x = np.clip((mu - c) / ((1 - c) * blend), 0, 1)
    f = x * x * (3 - 2 * x)
    return 2 * math.pi * float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(mu)))


# ---------------------------------------------------------------------------- flux


def test_flux_closed_forms_and_selection():
    spot = Light("s", "SPOT", (30, 20, 10), mat((0, 0, 3)), spot_size=1.0, spot_blend=0.4)
    area = Light("a", "AREA", (40, 40, 40), mat((1, 0, 2), scale=(2, 0.5, 1)), shape="RECTANGLE",
                 size=1.5, size_y=2.0)
    disk = Light("d", "AREA", (5, 5, 5), mat((0, 1, 2)), shape="DISK", size=0.7)
    dead = Light("z", "POINT", (0, 0, 0), mat((0, 0, 1)))
    sun = Light("sun", "SUN", (3, 2, 1), mat((0, 0, 9), rot_to((1, 0, -1))), angle=0.05)
    emis = Material("e", emission=(2.0, 1.0, 0.5))
    tris = FLOOR + [[[0, 0, 1], [0.5, 0, 1], [0, 0.4, 1]]]
    sc = scene([Light("p", "POINT", (100, 50, 25), mat((0, 0, 2))), spot, area, disk, dead, sun],
               materials=(Material("f"), emis), tris=tris, tri_mat=[0, 0, 1], world=(0.1, 0.2, 0.3))
    t = L.build_light_table(sc)
    R = t.radius_scene
    assert R == pytest.approx(0.5 * sc.diameter(), rel=2e-4)
    expect = {
        0: np.array([100, 50, 25.0]),
        1: np.array([30, 20, 10.0]) / (4 * np.pi) * smoothstep_solid_angle(1.0, 0.4),
        2: np.array([40, 40, 40.0]),
        3: np.array([5, 5, 5.0]),
        4: np.zeros(3),
        5: np.array([3, 2, 1.0]) * np.pi * R * R,
        6: np.array([0.1, 0.2, 0.3]) * 4 * np.pi ** 2 * R * R,     # world row
        7: 2 * np.pi * 0.1 * np.array([2.0, 1.0, 0.5]),           # triangle, A = 0.1
    }
    assert list(t.kind) == [L.POINT, L.SPOT, L.AREA, L.AREA, L.POINT, L.SUN, L.WORLD, L.MESH]
    for j, f in expect.items():
        # Triangles are stored in float32 (scene.tri_p): rtol 1e-7 there.
        np.testing.assert_allclose(t.flux[j], f, rtol=1e-7 if j == 7 else 1e-9, atol=1e-12,
                                   err_msg=f"row {j}")
    # Area radiance L = P / (pi A), A includes the object scale.
    np.testing.assert_allclose(t.radiance[2], 40 / (np.pi * (1.5 * 2) * (2.0 * 0.5)))
    np.testing.assert_allclose(t.radiance[3], 5 / (np.pi * np.pi * 0.7 ** 2 / 4))
    assert t.p_select[4] == 0.0 and np.all(np.isfinite(t.p_select))
    assert t.p_select.sum() == pytest.approx(1.0)
    lum = np.array([0.2126, 0.7152, 0.0722])
    np.testing.assert_allclose(t.p_select, t.flux @ lum / (t.flux @ lum).sum(), rtol=1e-12)


def _power_mean_check(t, N, seed):
    """Assert mean(power * [light == j]) = flux_j within Z standard errors,
    every j (a world or sun photon's power over its footprint's share of
    the bounding disc, which ``flux`` counts: emission.distant_footprint;
    a soft spot's photon times its cone along its direction, the far field
    of the factor it takes at its first hit, emission.soft_light_first_hit)."""
    from core.lights.emission import distant_footprint
    from core.lights.table import _spot_atten
    ph = L.sample_photons(t, N, np.random.default_rng(seed))
    assert ph["o"].shape == (N, 3) and ph["power"].shape == (N, 3)
    np.testing.assert_allclose(np.linalg.norm(ph["d"], axis=1), 1.0, atol=1e-12)
    assert np.all(np.isfinite(ph["power"]))
    disc = np.ones(N)
    w = np.nonzero((ph["kind"] == L.WORLD) | (ph["kind"] == L.SUN))[0]
    if w.size:
        area = distant_footprint(t, ph["d"][w], np.zeros(w.size), np.zeros(w.size))[1]
        disc[w] = np.pi * t.radius_scene ** 2 / area
    s = np.nonzero(t.soft_spot[ph["light"]])[0]
    disc[s] *= _spot_atten(t, ph["light"][s], ph["d"][s])
    for j in range(t.n):
        x = ph["power"] * ((ph["light"] == j) * disc)[:, None]
        se = x.std(axis=0) / math.sqrt(N)
        assert np.all(np.abs(x.mean(axis=0) - t.flux[j]) <= Z * se + 1e-9 * np.abs(t.flux[j])), \
            (j, x.mean(0), t.flux[j], se)
    return ph


SUN40 = rot_to((1, 0, -1))


@pytest.mark.parametrize("light", [
    Light("p", "POINT", (100, 50, 25), mat((0, 0, 2)), radius=0.2),
    Light("s", "SPOT", (30, 20, 10), mat((0, 0, 3)), spot_size=1.2, spot_blend=0.5, radius=0.1),
    Light("h", "SPOT", (30, 20, 10), mat((0, 0, 3), SUN40), spot_size=2.5, spot_blend=0.0),
    # Non-uniformly scaled spot: elliptic cone (Jacobian |det M| / |M v|^3).
    Light("s2", "SPOT", (20, 20, 20), mat((1, 1, 3), rot_to((0.3, 0, -1)), (2, 0.7, 1.3)),
          spot_size=0.8, spot_blend=0.2),
    Light("a", "AREA", (40, 40, 40), mat((1, 0, 2)), shape="ELLIPSE", size=1, size_y=2),
    Light("sun", "SUN", (3, 2, 1), mat((0, 0, 9), SUN40), angle=0.1),
], ids=["point", "spot", "spot_hard", "spot_scaled", "area", "sun"])
def test_photon_power_mean_per_light(light):
    """One emitter (p_select = 1): the photon power's mean is its closed-form flux."""
    t = L.build_light_table(scene([light]))
    _power_mean_check(t, 100_000, 7)
    if light.name == "s2":
        # The tabulated flux (quadrature with the Jacobian) vs a brute-force
        # integral over uniform world directions: Omega = 4 pi E[atten].
        N = 400_000
        rng = np.random.default_rng(3)
        w = _uniform_sphere(rng.random(N), rng.random(N))
        est = 20 / (4 * np.pi) * 4 * np.pi * _spot_atten(t, np.zeros(N, int), w)
        assert abs(est.mean() - t.flux[0, 0]) <= Z * est.std() / math.sqrt(N)


def test_photon_power_means_mixture():
    """Several emitters (incl. world, a zero-power light and a textured emissive
    triangle): each emitter's share of the photon power is its flux."""
    emis = Material("e", emission=(2.0, 1.0, 0.5), emission_texture=0)
    tex = np.ones((4, 4, 4), np.float32) * np.array([0.5, 1.0, 2.0, 1.0], np.float32)
    tris = FLOOR + [[[0, 0, 1], [0.5, 0, 1], [0, 0.4, 1]]]
    sc = make_scene(tris, [Material("f"), emis],
                    [Light("p", "POINT", (10, 5, 2.5), mat((0, 0, 2)), radius=0.2),
                     Light("s", "SPOT", (30, 20, 10), mat((0, 0, 3)), spot_size=1.2, spot_blend=0.5),
                     Light("a", "AREA", (4, 4, 4), mat((1, 0, 2)), shape="ELLIPSE", size=1, size_y=2),
                     Light("z", "POINT", (0, 0, 0), mat((0, 0, 1))),
                     Light("sun", "SUN", (0.03, 0.02, 0.01), mat((0, 0, 9), SUN40), angle=0.1)],
                    CAM, tri_mat=[0, 0, 1], world_color=(0.001, 0.002, 0.003), textures=[tex])
    t = L.build_light_table(sc)
    np.testing.assert_allclose(t.flux[-1], 2 * np.pi * 0.1 * np.array([1.0, 1.0, 1.0]), rtol=1e-7)
    ph = _power_mean_check(t, 400_000, 9)
    assert not np.any(ph["light"] == 3)


def test_photon_origins_and_freq_init():
    area = Light("a", "AREA", (40, 40, 40), mat((1, 0, 2), scale=(2, 1, 1)), shape="SQUARE", size=0.5)
    sun = Light("sun", "SUN", (3, 3, 3), mat((0, 0, 9), rot_to((1, 0, -1))), angle=0.2)
    emis = Material("e", emission=(1.0, 1.0, 1.0))
    tris = FLOOR + [[[0, 0, 1], [0.5, 0, 1], [0, 0.4, 1]]]
    sc = scene([SphereLight("p", "POINT", (10, 10, 10), mat((0, 0, 2)), radius=0.3), area, sun],
               materials=(Material("f"), emis), tris=tris, tri_mat=[0, 0, 1], world=(1, 1, 1))
    t = L.build_light_table(sc)
    ph = L.sample_photons(t, 20_000, np.random.default_rng(2))
    k, o, d, f = ph["kind"], ph["o"], ph["d"], ph["freq_init"]
    amax = sc.diameter() ** 2
    m = k == L.POINT   # on the sphere of radius 0.3, leaving it
    np.testing.assert_allclose(np.linalg.norm(o[m] - (0, 0, 2), axis=1), 0.3, rtol=1e-12)
    assert np.all(np.sum((o[m] - (0, 0, 2)) * d[m], axis=1) >= -1e-12)
    np.testing.assert_allclose(f[m], np.tile([0, L.B_DIFFUSE, 0], (m.sum(), 1)))
    assert np.all(ph["falloff_r2"] == 0)
    m = k == L.AREA    # on the 1 x 0.5 rectangle at z = 2, emitting downwards
    np.testing.assert_allclose(o[m, 2], 2.0, atol=1e-12)
    assert np.all(np.abs(o[m, 0] - 1) <= 0.5 + 1e-12) and np.all(np.abs(o[m, 1]) <= 0.25 + 1e-12)
    assert np.all(d[m, 2] < 0)
    np.testing.assert_allclose(f[m, 0], 0.5 / 12)      # w^2/12 with w = sqrt(0.5 m^2)
    m = k == L.MESH
    np.testing.assert_allclose(o[m, 2], 1.0, atol=1e-12)
    assert 0.3 < np.mean(d[m, 2] > 0) < 0.7            # both sides emit
    np.testing.assert_allclose(f[m, 0], 0.1 / 12)
    m = k == L.SUN     # outside the bounding sphere, on a plane facing their direction
    c, R = t.center, t.radius_scene
    axis = np.array([1, 0, -1]) / math.sqrt(2)
    np.testing.assert_allclose(np.einsum("ij,ij->i", o[m] - c, d[m]), -R, rtol=1e-9)
    assert np.all(d[m] @ axis >= math.cos(0.1) - 1e-12)
    np.testing.assert_allclose(f[m], np.tile([amax, 0.1 ** 2 / 3, 0], (m.sum(), 1)))
    m = k == L.WORLD
    np.testing.assert_allclose(f[m], np.tile([amax, L.B_DIFFUSE, 0], (m.sum(), 1)))
    np.testing.assert_allclose(np.einsum("ij,ij->i", o[m] - c, d[m]), -R, rtol=1e-9)
    # Nothing emits: zero power (never NaN).
    t0 = L.build_light_table(scene([Light("z", "POINT", (0, 0, 0), mat())]))
    ph0 = L.sample_photons(t0, 10, np.random.default_rng(0))
    assert np.all(ph0["power"] == 0) and np.all(ph0["light"] == -1)
    r0 = L.sample_direct(t0, np.zeros((4, 3)), np.full((4, 3), 0.5))
    assert np.all(r0["weight"] == 0) and np.all(r0["light"] == -1)
    assert t0.p_select[0] == 0.0


def test_soft_falloff_photons_reproduce_cycles_near_field():
    """Soft-falloff point light (r = 0.5, h = 1): photons from the centre with the
    first-hit factor t^2/(t^2 + r^2) give the Cycles irradiance I cos/(d^2 + r^2)
    (exact for a disc facing the receiver).  Compared on the flux landing in the
    disc rho = 1 around the foot point: int_0^rho E(s) 2 pi s ds by quadrature."""
    P, r, h, rho = 100.0, 0.5, 1.0, 1.0
    t = L.build_light_table(scene([Light("p", "POINT", (P,) * 3, mat((0, 0, h)), radius=r)]))
    N = 400_000
    ph = L.sample_photons(t, N, np.random.default_rng(13))
    np.testing.assert_allclose(ph["o"], np.tile([0, 0, h], (N, 1)))
    np.testing.assert_allclose(ph["falloff_r2"], r * r)
    down = ph["d"][:, 2] < 0
    tt = np.where(down, -h / np.where(down, ph["d"][:, 2], -1.0), np.inf)
    hit = ph["o"] + np.where(down, tt, 0.0)[:, None] * ph["d"]
    inside = down & (np.hypot(hit[:, 0], hit[:, 1]) <= rho)
    tt = np.where(inside, tt, 1.0)
    x = np.where(inside, ph["power"][:, 0] * tt ** 2 / (tt ** 2 + r * r), 0.0)
    s = np.linspace(0, rho, 20001)
    E = P / (4 * np.pi) * (h / np.sqrt(s * s + h * h)) / (s * s + h * h + r * r)
    f = E * 2 * np.pi * s
    ref = float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(s)))
    assert abs(x.mean() - ref) <= Z * x.std() / math.sqrt(N), (x.mean(), ref)
    # The same landing flux from NEE at the foot point is I / (h^2 + r^2):
    # already covered by test_direct_point_light_with_radius.


# ---------------------------------------------------------------------------- direct light


def test_direct_point_light_blender_check():
    """Notes' check: P = 100 W, h = 1 m, rho = 0.8 -> rho P / (4 pi^2 h^2)."""
    t = L.build_light_table(scene([Light("p", "POINT", (100, 100, 100), mat((0, 0, 1)))]))
    m, se = direct_mean(t, (0, 0, 0), (0, 0, 1), K=1000, albedo=0.8)
    exact = 0.8 * 100 / (4 * np.pi ** 2)
    assert se < 1e-12 and m == pytest.approx(exact, rel=1e-12)
    # Cycles' rendered pixel (2.026118) is this foot-point value averaged over
    # the pixel footprint: 0.015% lower.
    assert m == pytest.approx(2.026118, rel=3e-4)
    r = L.sample_direct(t, np.zeros((1, 3)), np.full((1, 3), 0.5))
    assert r["dist"][0] == pytest.approx(1.0) and r["kind"][0] == L.POINT


def test_direct_point_light_with_radius():
    # Soft falloff (Cycles' default): a disc facing the receiver, L = P/(4 pi^2 r^2):
    # E = pi L r^2 / (h^2 + r^2) = I / (h^2 + r^2) at the foot point.
    P, r, h = 100.0, 0.5, 1.0
    t = L.build_light_table(scene([Light("p", "POINT", (P,) * 3, mat((0, 0, h)), radius=r)]))
    m, se = direct_mean(t, (0, 0, 0), (0, 0, 1))
    assert abs(m - P / (4 * np.pi) / (h * h + r * r) / np.pi) <= Z * se
    # Receiver tilted 60 deg, off-axis: the facing disc vs Lambert's polygon
    # formula on a 2000-gon of the same disc.
    p, n = np.array([0.7, 0.2, 0.0]), np.array([0, math.sin(1.0), math.cos(1.0)])
    ax = (p - (0, 0, h)) / np.linalg.norm(p - (0, 0, h))
    t1 = np.cross(ax, (1, 0, 0))
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(ax, t1)
    ang = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    poly = np.array([0, 0, h]) + r * (np.outer(np.cos(ang), t1) + np.outer(np.sin(ang), t2))
    m, se = direct_mean(t, p, n)
    ref = polygon_irradiance(poly, p, n) * P / (4 * np.pi ** 2 * r * r) / np.pi
    assert abs(m - ref) <= Z * se + 1e-5 * ref
    # Sphere model: pi L sin^2(alpha) = I / h^2 at the foot point.
    t = L.build_light_table(scene([SphereLight("p", "POINT", (P,) * 3, mat((0, 0, h)), radius=r)]))
    assert bool(t.is_sphere[0])
    m, se = direct_mean(t, (0, 0, 0), (0, 0, 1))
    assert abs(m - P / (4 * np.pi) / (h * h) / np.pi) <= Z * se


def test_direct_spot_light():
    size, blend, P, h = 1.2, 0.5, 80.0, 2.0
    t = L.build_light_table(scene([Light("s", "SPOT", (P,) * 3, mat((0, 0, h)), spot_size=size,
                                         spot_blend=blend)]))
    c = math.cos(size / 2)
    for x in (0.0, 0.9, 1.2, 1.5):   # inside, in the blend ring, outside
        d2 = x * x + h * h
        mu = h / math.sqrt(d2)
        s = np.clip((mu - c) / ((1 - c) * blend), 0, 1)
        ref = P / (4 * np.pi) * s * s * (3 - 2 * s) * mu / d2 / np.pi
        m, se = direct_mean(t, (x, 0, 0), (0, 0, 1), K=100)
        assert m == pytest.approx(ref, rel=1e-12, abs=1e-15), x


def test_direct_sun():
    """Notes' check: S = 3 at elevation 40 deg, rho = 0.6 -> rho/pi S sin(40) = 0.36829."""
    el = math.radians(40)
    aim = rot_to((-math.cos(el), 0, -math.sin(el)))
    ref = 0.6 / np.pi * 3 * math.sin(el)
    assert ref == pytest.approx(0.36829, rel=2e-5)
    t = L.build_light_table(scene([Light("sun", "SUN", (3, 3, 3), mat((0, 0, 5), aim))]))
    m, _ = direct_mean(t, (0.3, 0.2, 0), (0, 0, 1), K=100, albedo=0.6)
    assert m == pytest.approx(ref, rel=1e-12)
    r = L.sample_direct(t, np.zeros((1, 3)), np.full((1, 3), 0.5))
    assert np.isinf(r["dist"][0])
    # angle > 0: a uniform cap above the horizon has projected solid angle
    # pi sin^2 h cos(theta_0): the irradiance is unchanged.
    t = L.build_light_table(scene([Light("sun", "SUN", (3, 3, 3), mat((0, 0, 5), aim), angle=0.2)]))
    m, se = direct_mean(t, (0.3, 0.2, 0), (0, 0, 1), albedo=0.6)
    assert se > 0 and abs(m - ref) <= Z * se


def test_direct_area_lights_vs_exact_formulas():
    P = 50.0
    # Tilted, scaled rectangle; receivers at several places, one on a tilted plane.
    rot = rot_to((0.3, -0.2, -1))
    sq = Light("a", "AREA", (P,) * 3, mat((0.2, 0.1, 1.2), rot, (1.0, 1.5, 1.0)), shape="SQUARE",
               size=0.8)
    t = L.build_light_table(scene([sq]))
    u, v = 0.4 * rot[:, 0], 0.6 * rot[:, 1]
    c = np.array([0.2, 0.1, 1.2])
    verts = [c - u - v, c + u - v, c + u + v, c - u + v]
    Lr = P / (np.pi * 0.8 * 1.2)
    for p, n in [((0, 0, 0), (0, 0, 1)), ((0.9, -0.4, 0), (0, 0, 1)),
                 ((0.5, 0.5, 0.3), (0.3, 0, 0.954))]:
        n = np.asarray(n) / np.linalg.norm(n)
        m, se = direct_mean(t, p, n)
        ref = Lr * polygon_irradiance(verts, np.asarray(p, float), n) / np.pi
        assert abs(m - ref) <= Z * se, (p, m, ref, se)
    # Behind the one-sided light: nothing (selection probability 0).
    r = L.sample_direct(t, np.array([[0.2, 0.1, 3.0]]), np.full((1, 3), 0.3))
    assert np.all(r["weight"] == 0)
    # Disc, parallel to the receiver, on and off axis: exact formula.
    rd, h = 0.5, 1.0
    t = L.build_light_table(scene([Light("d", "AREA", (P,) * 3, mat((0, 0, h)), shape="DISK",
                                         size=2 * rd)]))
    Ld = P / (np.pi * np.pi * rd * rd)
    for x in (0.0, 0.4, 1.3):
        m, se = direct_mean(t, (x, 0, 0), (0, 0, 1))
        ref = Ld * parallel_disc_irradiance(rd, h, x) / np.pi
        assert abs(m - ref) <= Z * se, (x, m, ref, se)


def test_direct_emissive_triangles_and_mixture():
    """One emissive triangle vs the polygon formula (both sides emit), then a
    mixture of a point light, an area light and 40 emissive triangles (the
    grouped selection path): the estimate equals the sum of the exact terms."""
    Le = 3.0
    tri = np.array([[-0.3, -0.2, 1.0], [0.6, 0.0, 1.3], [0.0, 0.5, 0.9]])
    emis = Material("e", emission=(Le, Le, Le))
    sc = scene([], materials=(Material("f"), emis), tris=FLOOR + [tri.tolist()], tri_mat=[0, 0, 1])
    t = L.build_light_table(sc)
    for p, n in [((0.1, 0.1, 0.0), (0, 0, 1.0)), ((0.1, 0.0, 2.0), (0, 0, -1.0))]:
        m, se = direct_mean(t, p, np.asarray(n))
        ref = Le * polygon_irradiance(tri, np.asarray(p), np.asarray(n)) / np.pi
        assert abs(m - ref) <= Z * se, (p, m, ref)
    # Receivers 2 cm from a horizontal triangle (solid-angle sampling path), on
    # both sides, and far off to the side (area-sampling path, Omega < 1e-3).
    flat = np.array([[-0.3, -0.2, 1.0], [0.6, 0.0, 1.0], [0.0, 0.5, 1.0]])
    sc = scene([], materials=(Material("f"), emis), tris=FLOOR + [flat.tolist()], tri_mat=[0, 0, 1])
    t = L.build_light_table(sc)
    for p, n in [((0.1, 0.1, 1.02), (0, 0, -1.0)), ((0.1, 0.1, 0.98), (0, 0, 1.0)),
                 ((0.7, 0.5, 0.999), (0, 0, 1.0))]:
        m, se = direct_mean(t, p, np.asarray(n))
        ref = Le * polygon_irradiance(flat, np.asarray(p), np.asarray(n)) / np.pi
        assert abs(m - ref) <= Z * se, (p, m, ref)
    # Mixture.
    rng = np.random.default_rng(5)
    tris = []
    for i in range(40):
        c = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(1.5, 2.5)])
        tris.append((c + rng.uniform(-0.15, 0.15, (3, 3))).tolist())
    area = Light("a", "AREA", (20,) * 3, mat((1, -1, 1.5)), shape="SQUARE", size=0.5)
    pt = Light("p", "POINT", (30,) * 3, mat((-1, 1, 1)))
    sc = scene([area, pt], materials=(Material("f"), emis), tris=FLOOR + tris,
               tri_mat=[0, 0] + [1] * 40)
    t = L.build_light_table(sc)
    assert (t.entry_emitter == -1).sum() == 1          # grouped triangles
    p, n = np.array([0.3, -0.2, 0.0]), np.array([0, 0, 1.0])
    ref = 30 / (4 * np.pi) * 1.0 / np.sum((p - (-1, 1, 1)) ** 2) ** 1.5      # I cos / d^2
    h = 0.25
    ref += 20 / (np.pi * 0.25) * polygon_irradiance(
        [(1 - h, -1 - h, 1.5), (1 + h, -1 - h, 1.5), (1 + h, -1 + h, 1.5), (1 - h, -1 + h, 1.5)], p, n)
    for tr in tris:
        ref += Le * polygon_irradiance(np.array(tr), p, n)
    m, se = direct_mean(t, p, n, K=400_000)
    assert abs(m - ref / np.pi) <= Z * se, (m, ref / np.pi, se)


def test_direct_world():
    t = L.build_light_table(scene([], world=(0.5, 0.5, 0.5)))
    m, se = direct_mean(t, (0, 0, 0), (0, 0, 1))
    assert abs(m - 0.5) <= Z * se           # rho/pi * pi L = L for rho = 1
    np.testing.assert_allclose(L.world_radiance(t), 0.5)


# ---------------------------------------------------------------------------- chi-square


def chi_square_p(dirs, axis, cdf_mu, n_mu=24, n_phi=24):
    """p-value of directions vs a pdf uniform in phi with CDF cdf_mu(cos theta)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    t1, t2 = _basis(axis[None, :])
    mu = np.clip(dirs @ axis, -1, 1)
    phi = np.arctan2(dirs @ t2[0], dirs @ t1[0]) % (2 * np.pi)
    im = np.minimum(((mu + 1) / 2 * n_mu).astype(int), n_mu - 1)
    ip = np.minimum((phi / (2 * np.pi) * n_phi).astype(int), n_phi - 1)
    obs = np.bincount(im * n_phi + ip, minlength=n_mu * n_phi).astype(float)
    edges = np.linspace(-1, 1, n_mu + 1)
    F = np.array([cdf_mu(e) for e in edges])
    exp = np.repeat(np.diff(F) / n_phi, n_phi) * dirs.shape[0]
    assert np.all(obs[exp == 0] == 0), "samples where the pdf is zero"
    small = exp < 5
    o = np.concatenate([obs[~small], [obs[small].sum()]]) if small.any() else obs
    e = np.concatenate([exp[~small], [exp[small].sum()]]) if small.any() else exp
    keep = e > 0
    chi2 = float(np.sum((o[keep] - e[keep]) ** 2 / e[keep]))
    dof = int(keep.sum()) - 1
    return chi2_sf(chi2, dof)


def _photon_dirs(light, n=200_000, seed=11):
    t = L.build_light_table(scene([light]))
    ph = L.sample_photons(t, n, np.random.default_rng(seed))
    return ph["d"], ph


def test_chi_square_point_uniform_sphere():
    d, _ = _photon_dirs(Light("p", "POINT", (10, 10, 10), mat((0, 0, 1)), radius=0.2))
    assert chi_square_p(d, (0.3, 0.4, 0.5), lambda m: (m + 1) / 2) > 0.01 / N_CHI_TESTS


def test_chi_square_spot_cone():
    """Spot photons: uniform in the cone (the smoothstep is in the photon weight)."""
    size = 1.4
    c = math.cos(size / 2)
    aim = (0.2, 0.3, -1.0)
    d, ph = _photon_dirs(Light("s", "SPOT", (10, 10, 10), mat((0, 0, 3), rot_to(aim)),
                               spot_size=size, spot_blend=0.3))
    assert chi_square_p(d, aim, lambda m: min(max((m - c) / (1 - c), 0.0), 1.0)) > 0.01 / N_CHI_TESTS
    # The weight is the smoothstep of the angle to the axis.
    mu = d @ (np.array(aim) / np.linalg.norm(aim))
    s = np.clip((mu - c) / ((1 - c) * 0.3), 0, 1)
    np.testing.assert_allclose(ph["power"][:, 0], 10 / 2 * (1 - c) * s * s * (3 - 2 * s), rtol=1e-9)


def test_chi_square_area_cosine():
    aim = (0.5, -0.2, -1.0)
    d, _ = _photon_dirs(Light("a", "AREA", (10, 10, 10), mat((0, 0, 3), rot_to(aim)),
                              shape="ELLIPSE", size=0.5, size_y=0.3))
    assert chi_square_p(d, aim, lambda m: max(m, 0.0) ** 2) > 0.01 / N_CHI_TESTS


def test_chi_square_sun_cone():
    h = 0.15
    c = math.cos(h)
    aim = (1.0, 0.0, -1.0)
    d, _ = _photon_dirs(Light("sun", "SUN", (3, 3, 3), mat((0, 0, 5), rot_to(aim)), angle=2 * h))
    assert chi_square_p(d, aim, lambda m: min(max((m - c) / (1 - c), 0.0), 1.0)) > 0.01 / N_CHI_TESTS


def test_chi_square_mesh_two_sided_cosine():
    emis = Material("e", emission=(1.0, 1.0, 1.0))
    tris = FLOOR + [[[0, 0, 1], [0.5, 0, 1], [0, 0.4, 1]]]
    t = L.build_light_table(scene([], materials=(Material("f"), emis), tris=tris, tri_mat=[0, 0, 1]))
    d = L.sample_photons(t, 200_000, np.random.default_rng(4))["d"]
    # Half the photons each side, cosine about +-Z: CDF(mu) = (1 + sign(mu) mu^2) / 2.
    assert chi_square_p(d, (0, 0, 1), lambda m: 0.5 * (1 + math.copysign(m * m, m))) > 0.01 / N_CHI_TESTS


# ---------------------------------------------------------------------------- rays


def test_emitted_along_rays_area_light_and_flags():
    """A camera ray hitting a 1 m^2 50 W area light sees 50/pi; the back side 0."""
    lt = Light("a", "AREA", (50, 50, 50), mat((0, 0, 2)), shape="SQUARE", size=1.0)
    t = L.build_light_table(scene([lt]))
    o = np.array([[0, 0, 0.0], [0.2, 0.3, 0.0], [0, 0, 4.0], [0.8, 0, 0.0], [0, 0, 0.0]])
    d = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, -1.0], [0, 0, 1.0], [0, 0, 1.0]])
    tmax = np.array([np.inf, np.inf, np.inf, np.inf, 1.5])
    Lc = L.emitted_along_rays(t, o, d, tmax, "camera")
    np.testing.assert_allclose(Lc[:, 0], [50 / np.pi, 50 / np.pi, 0, 0, 0], rtol=1e-12)
    hidden = Light("a", "AREA", (50, 50, 50), mat((0, 0, 2)), shape="SQUARE", size=1.0,
                   visible_camera=False, visible_transmission=False)
    t = L.build_light_table(scene([hidden]))
    assert np.all(L.emitted_along_rays(t, o[:1], d[:1], tmax[:1], "camera") == 0)
    assert np.all(L.emitted_along_rays(t, o[:1], d[:1], tmax[:1], "transmission") == 0)
    np.testing.assert_allclose(L.emitted_along_rays(t, o[:1], d[:1], tmax[:1], "glossy"), 50 / np.pi)
    # Ellipse: inside the ellipse but outside the inscribed... corner of its box: miss.
    el = Light("e", "AREA", (50, 50, 50), mat((0, 0, 2)), shape="ELLIPSE", size=2.0, size_y=1.0)
    t = L.build_light_table(scene([el]))
    Le = L.emitted_along_rays(t, np.array([[0.9, 0, 0], [0.9, 0.45, 0]]),
                              np.array([[0, 0, 1.0], [0, 0, 1.0]]), np.full(2, np.inf))
    np.testing.assert_allclose(Le[:, 0], [50 / (np.pi * np.pi * 2 * 1 / 4), 0])


def test_emitted_along_rays_point_spot_sun():
    P, r = 100.0, 0.25
    Lp = P / (4 * np.pi ** 2 * r * r)
    o = np.array([[0, 0, 0.0], [0.2, 0, 0.0], [0.3, 0, 0.0]])
    d = _normalize(np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0]]))
    inf = np.full(3, np.inf)
    t = L.build_light_table(scene([Light("p", "POINT", (P,) * 3, mat((0, 0, 2)), radius=r)]))
    np.testing.assert_allclose(L.emitted_along_rays(t, o, d, inf)[:, 0], [Lp, Lp, 0], rtol=1e-12)
    # Radius 0: invisible.
    t = L.build_light_table(scene([Light("p", "POINT", (P,) * 3, mat((0, 0, 2)))]))
    assert np.all(L.emitted_along_rays(t, o, d, inf) == 0)
    # Spot aimed down: seen from below inside the cone, not from above.
    sp = Light("s", "SPOT", (P,) * 3, mat((0, 0, 2)), radius=r, spot_size=1.0, spot_blend=0.0)
    t = L.build_light_table(scene([sp]))
    np.testing.assert_allclose(L.emitted_along_rays(t, o[:1], d[:1], inf[:1])[0, 0], Lp)
    assert np.all(L.emitted_along_rays(t, np.array([[0, 0, 4.0]]), np.array([[0, 0, -1.0]]),
                                       inf[:1]) == 0)
    # Sun with angle: only on rays that escape, inside its cone.
    aim = np.array([0, 0, -1.0])
    t = L.build_light_table(scene([Light("sun", "SUN", (3, 3, 3), mat((0, 0, 5), rot_to(aim)),
                                         angle=0.1)]))
    Ls = 3 / (np.pi * math.sin(0.05) ** 2)
    up = np.array([[0, 0, 1.0], [math.sin(0.04), 0, math.cos(0.04)], [math.sin(0.06), 0, math.cos(0.06)],
                   [0, 0, 1.0]])
    got = L.emitted_along_rays(t, np.zeros((4, 3)), up, np.array([np.inf, np.inf, np.inf, 3.0]), "glossy")
    np.testing.assert_allclose(got[:, 0], [Ls, Ls, 0, 0], rtol=1e-12)


def test_spread_is_cycles_soft_box_and_keeps_the_flux():
    """An area light's spread (Cycles' area_light_spread_attenuation): the
    factor max((tan a - tan theta) / (tan a - a), 0), a = spread / 2, is 0
    beyond a, and its mean over the cosine lobe is 1 (the flux stays the
    light's: a Monte Carlo of 2,000,000 cosine-distributed directions within
    4 sigma), for spreads of 5, 60 and 150 deg; 1 at 180 deg; no warning."""
    from core.lights.warps import _cosine_local
    for deg in (5.0, 60.0, 150.0, 180.0):
        lt = Light("a", "AREA", (5, 5, 5), mat((0, 0, 2)), spread=math.radians(deg))
        t = L.build_light_table(scene([lt]))
        assert not t.warnings and t.flux[0, 0] == pytest.approx(5.0)
        a = math.radians(deg) / 2
        z = _cosine_local(*np.random.default_rng(3).random((2, 2_000_000)))[:, 2]
        f = L.spread_atten(t, np.zeros(z.size, int), z)
        if deg == 180.0:
            assert np.all(f == 1.0)
            continue
        norm = 1.0 / (math.tan(a) - a) if a > 0.05 else 3.0 / a ** 3   # Cycles' Taylor form
        assert np.all(f[z < math.cos(a) - 1e-12] == 0)
        assert L.spread_atten(t, np.zeros(1, int), np.ones(1))[0] == pytest.approx(
            math.tan(a) * norm, rel=1e-12)
        assert abs(f.mean() - 1.0) <= 4 * f.std() / math.sqrt(f.size), (deg, f.mean())


def test_box_rectangle_covers_the_box_and_is_the_smallest():
    """emission.box_rectangle: for 2,000 random directions and a flat,
    long box, the eight corners project inside the rectangle (the footprint
    covers every triangle: the world photons are unbiased), and no rectangle
    of another orientation bounds them with a smaller area (a sweep of
    3,600 angles; the rectangle's may be smaller than the sweep's by its
    step)."""
    from core.lights.emission import box_rectangle
    rng = np.random.default_rng(4)
    w = rng.normal(size=(2000, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    e = np.array([3.0, 1.2, 0.05])
    t1, t2, h1, h2 = box_rectangle(w, e)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * e
    np.testing.assert_allclose(np.einsum("ki,ki->k", t1, w), 0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ki,ki->k", t2, w), 0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ki,ki->k", t1, t2), 0, atol=1e-12)
    x1, x2 = corners @ t1.T, corners @ t2.T                    # (8, K)
    assert np.all(np.abs(x1) <= h1 * (1 + 1e-12)) and np.all(np.abs(x2) <= h2 * (1 + 1e-12))
    ang = np.linspace(0, np.pi / 2, 3600, endpoint=False)
    for k in range(0, 2000, 50):
        a = np.cos(ang)[:, None] * t1[k] + np.sin(ang)[:, None] * t2[k]
        b = np.cross(w[k], a)
        sweep = (np.abs(corners @ a.T).max(axis=0) * np.abs(corners @ b.T).max(axis=0)).min()
        assert h1[k] * h2[k] <= sweep * (1 + 1e-9)
