"""The world's environment map: Cycles' equirectangular convention, the
importance sampler (chi-square), closed forms, and agreement with Cycles.

Tolerances: chi-square p-values > 0.01 / N_CHI_TESTS (as tests/test_lights.py);
Monte Carlo means within Z = 4.5 standard errors (false-failure odds ~7e-6 per
assertion, as tests/test_lights.py); Cycles agreement with
tests/test_cycles_agreement.py's bounds (mean within 2 %, relMSE under
1.5 x measured noise + its bias allowance).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from core import lights as L
from core.lights.environment import EnvironmentLight
from core.scene.model import Camera, Material, make_scene
from core.scene.textures import (EnvironmentMap, environment_radiance, equirectangular_direction,
                                 equirectangular_uv)
from stats_helpers import chi2_sf, emitter_free_mask, two_seed_block_sigma, two_seed_relmse_noise

Z = 4.5
N_CHI_TESTS = 3


def spiky_image(H=16, W=32, base=0.05, seed=3):
    """A small HDRI: a dim gradient sky and three bright texels (float32, row 0 = nadir)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((H, W, 4), np.float32)
    rows = (np.arange(H) + 0.5) / H
    img[..., 0] = base * (0.5 + rows)[:, None]
    img[..., 1] = base
    img[..., 2] = base * (1.5 - rows)[:, None] + 0.01 * rng.random((H, W))
    img[..., 3] = 1.0
    img[12, 5, :3] = (40.0, 30.0, 20.0)
    img[10, 20, :3] = (5.0, 8.0, 12.0)
    img[3, 27, :3] = (0.0, 6.0, 0.0)      # below the horizon
    return img


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def floor_scene(world_map=None, world=(0.0, 0.0, 0.0)):
    sc = make_scene([[(-1, -1, 0), (1, -1, 0), (1, 1, 0)]], [Material("f")], [], Camera(),
                    world_color=world)
    sc.world_map = world_map
    return sc


# ---------------------------------------------------------------------------- convention

def test_equirectangular_convention_of_cycles():
    # Cycles' direction_to_equirectangular: +X at u = 1/2, +Y at u = 1/4,
    # -Y at 3/4, -X at the seam; zenith v = 1, nadir v = 0.
    d = np.array([[1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0],
                  [math.sqrt(0.5), 0, math.sqrt(0.5)]])
    uv = equirectangular_uv(d)
    np.testing.assert_allclose(uv[:, 0][[0, 1, 2]], [0.5, 0.25, 0.75], atol=1e-15)
    np.testing.assert_allclose(uv[:, 1], [0.5, 0.5, 0.5, 1.0, 0.0, 0.75], atol=1e-15)
    u = np.random.default_rng(0).random(1000)
    z = np.random.default_rng(1).uniform(-1, 1, 1000)
    back = equirectangular_uv(equirectangular_direction(u, z))
    np.testing.assert_allclose(back[:, 0] % 1.0, u, atol=1e-12)
    np.testing.assert_allclose(np.cos(np.pi * (1 - back[:, 1])), z, atol=1e-12)


def test_lookup_hits_the_texel_at_its_centre_and_follows_the_mapping():
    img = spiky_image()
    env = EnvironmentMap(img, strength=np.full(3, 2.0))
    H, W = img.shape[:2]
    # Texel (12, 5)'s centre: u = 5.5 / W, v = 12.5 / H.
    c = equirectangular_direction(np.array([5.5 / W]), np.array([-math.cos(math.pi * 12.5 / H)]))
    np.testing.assert_allclose(environment_radiance(env, c)[0], 2.0 * img[12, 5, :3], rtol=1e-6)
    # Mapping: texture vector = A w.  The world direction that sees the texel is A^-1 c.
    A = rotation((0.2, -0.5, 1.0), 0.7) @ np.diag([1.0, 2.0, 0.5])
    env_r = EnvironmentMap(img, strength=np.ones(3), to_texture=A)
    w = np.linalg.solve(A, c[0])
    w /= np.linalg.norm(w)
    np.testing.assert_allclose(environment_radiance(env_r, w[None])[0], img[12, 5, :3], rtol=1e-6)


# ---------------------------------------------------------------------------- sampler

def _region_of(el, w):
    """Texel region index (row-major) of world directions w through the map's mapping."""
    c = w @ el.A.T
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    uv = equirectangular_uv(c)
    j = np.floor(uv[:, 0] * el.W).astype(int) % el.W
    i = np.clip(np.searchsorted(el.z_edges, c[:, 2], side="right") - 1, 0, el.H - 1)
    return i * el.W + j


def _chi_square_regions(el, w):
    """p-value of directions against the region probabilities weight / total."""
    obs = np.bincount(_region_of(el, w), minlength=el.H * el.W).astype(float)
    exp = el.weight.ravel() / el.total * w.shape[0]
    assert np.all(obs[exp == 0] == 0)
    small = exp < 5
    o = np.concatenate([obs[~small], [obs[small].sum()]])
    e = np.concatenate([exp[~small], [exp[small].sum()]])
    keep = e > 0
    chi2 = float(np.sum((o[keep] - e[keep]) ** 2 / e[keep]))
    return chi2_sf(chi2, int(keep.sum()) - 1)


@pytest.mark.parametrize("A", [np.eye(3), rotation((1, 2, 3), 1.1) @ np.diag([1.5, 1.0, 0.7])],
                         ids=["identity", "rotated-scaled"])
def test_chi_square_environment_sampler(A):
    el = EnvironmentLight.build(EnvironmentMap(spiky_image(), to_texture=A))
    rng = np.random.default_rng(5)
    w, pdf = el.sample(rng.random(300_000), rng.random(300_000))
    assert _chi_square_regions(el, w) > 0.01 / N_CHI_TESTS
    # The returned pdf is the density pdf() reports for the same direction.
    np.testing.assert_allclose(pdf, el.pdf(w), rtol=1e-9)


def test_pdf_integrates_to_one_and_is_positive_where_light_is():
    A = rotation((1, 2, 3), 1.1) @ np.diag([1.5, 1.0, 0.7])
    el = EnvironmentLight.build(EnvironmentMap(spiky_image(), to_texture=A))
    # Midpoint rule on a fine (z, phi) grid of world directions.
    n_z, n_p = 800, 1600
    z = -1 + 2 * (np.arange(n_z) + 0.5) / n_z
    p = 2 * np.pi * (np.arange(n_p) + 0.5) / n_p
    Zg, Pg = np.meshgrid(z, p, indexing="ij")
    s = np.sqrt(1 - Zg ** 2)
    w = np.stack([s * np.cos(Pg), s * np.sin(Pg), Zg], -1).reshape(-1, 3)
    pdf = el.pdf(w)
    integral = pdf.sum() * (2 / n_z) * (2 * np.pi / n_p)
    # Discretisation error of the grid across region edges: ~1e-3 here.
    assert integral == pytest.approx(1.0, abs=3e-3)
    radiance = el.radiance(w).max(axis=1)
    assert np.all(pdf[radiance > 0] > 0)


def test_chi_square_photon_directions_follow_the_map():
    el_map = EnvironmentMap(spiky_image())
    t = L.build_light_table(floor_scene(el_map))
    ph = L.sample_photons(t, 200_000, np.random.default_rng(8))
    assert np.all(ph["kind"] == L.WORLD)
    # Photons travel along -omega, omega distributed as the map.
    assert _chi_square_regions(t.environment, -ph["d"]) > 0.01 / N_CHI_TESTS
    # They start on a plane facing the scene, at distance R from its centre.
    rel = ph["o"] - t.center
    np.testing.assert_allclose(np.einsum("ij,ij->i", rel, ph["d"]), -t.radius_scene, rtol=1e-9)


# ---------------------------------------------------------------------------- closed forms

@pytest.mark.parametrize("kind", ["constant", "map", "sun"])
def test_distant_photons_through_a_quad_carry_their_irradiance(kind):
    """A 4 x 1 m quad at z = 0, the scene's only triangles, with the camera
    8 m away (the bounding sphere is ten times the quad's size): the world's
    photons that cross the quad carry A (E_top + E_bottom), E the irradiance
    int L |w_z| dw of each side (pi L for a constant world; the map's by
    quadrature; a 5-degree sun's on the top face), whether they start on
    the bounding disc (the rule before
    round 29) or on the smallest rectangle about the quad's box seen along
    their direction (emission.distant_footprint), within Z standard errors;
    the rectangle wastes fewer photons."""
    from core.lights.emission import distant_footprint
    tris = [[(-2, -0.5, 0), (2, -0.5, 0), (2, 0.5, 0)], [(-2, -0.5, 0), (2, 0.5, 0), (-2, 0.5, 0)]]
    cam = Camera(matrix_world=np.array([[1, 0, 0, 0], [0, 1, 0, -8.0], [0, 0, 1, 0],
                                        [0, 0, 0, 1.0]]))
    Lw = 0.7
    if kind == "sun":
        # Blender's sun: strength S is the irradiance facing it; 40 degrees
        # from the zenith, 5 degrees wide (directions in its cone)
        from core.scene.model import Light
        tilt = rotation((0.0, 1.0, 0.0), math.radians(40.0))
        sun = np.eye(4)
        sun[:3, :3] = tilt
        sc = make_scene(tris, [Material("f")], [Light("sun", "SUN", (3.0, 3.0, 3.0), sun,
                                                      angle=math.radians(5.0))], cam)
    else:
        sc = make_scene(tris, [Material("f")], [], cam, world_color=(Lw, Lw, Lw))
    if kind == "map":
        sc.world_map = EnvironmentMap(spiky_image(), to_texture=rotation((0.3, 0.2, 1.0), 0.7))
    t = L.build_light_table(sc)
    if kind == "sun":
        # S on a plane facing each direction of the cone (a uniform cap of
        # half angle h about the axis): on the top face S E[|w_z|] = S cos(40
        # degrees) (1 + cos h) / 2
        h = float(t.half_angle[t.kind == L.SUN][0])
        E2 = 3.0 * math.cos(math.radians(40.0)) * (1.0 + math.cos(h)) / 2.0
    elif kind == "constant":
        E2 = 2 * np.pi * Lw
    else:
        z = -1 + 2 * (np.arange(1000) + 0.5) / 1000
        p = 2 * np.pi * (np.arange(2000) + 0.5) / 2000
        Zg, Pg = np.meshgrid(z, p, indexing="ij")
        s = np.sqrt(1 - Zg ** 2)
        w = np.stack([s * np.cos(Pg), s * np.sin(Pg), Zg], -1).reshape(-1, 3)
        E2 = ((t.environment.radiance(w) * np.abs(w[:, 2:3])).sum(axis=0)
              * (2 / 1000) * (2 * np.pi / 2000))
    want = 4.0 * E2
    K = 400_000
    hits = {}
    box = t.triangle_box
    for name in ("disc", "rectangle"):
        t.triangle_box = box if name == "rectangle" else None
        ph = L.sample_photons(t, K, np.random.default_rng(5))
        o, d = ph["o"], ph["d"]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -o[:, 2] / d[:, 2]
        x, y = o[:, 0] + s * d[:, 0], o[:, 1] + s * d[:, 1]
        hit = (s > 0) & (np.abs(x) <= 2) & (np.abs(y) <= 0.5)
        v = ph["power"] * hit[:, None]
        m, se = v.mean(axis=0), v.std(axis=0) / math.sqrt(K)
        assert np.all(np.abs(m - want) <= Z * se + 1e-3 * want), (name, m, want, se)
        hits[name] = hit.mean()
    assert hits["rectangle"] > 5 * hits["disc"], hits
    # the footprint never exceeds the disc
    area = distant_footprint(t, ph["d"], np.zeros(K), np.zeros(K))[1]
    assert np.all(area <= np.pi * t.radius_scene ** 2)


def test_constant_map_equals_the_constant_world_exactly():
    Lw = 0.5                                   # exact in float32
    img = np.full((8, 16, 4), Lw, np.float32)
    t_map = L.build_light_table(floor_scene(EnvironmentMap(img), world=(Lw, Lw, Lw)))
    t_const = L.build_light_table(floor_scene(None, world=(Lw, Lw, Lw)))
    # The same row: flux 4 pi^2 R^2 L, selection, and the radiance seen by rays.
    np.testing.assert_allclose(t_map.flux, t_const.flux, rtol=1e-14)
    np.testing.assert_array_equal(t_map.p_select, t_const.p_select)
    d = np.random.default_rng(2).normal(size=(1000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_array_equal(L.world_radiance(t_map, d), L.world_radiance(t_const, d))
    # Every photon carries exactly the constant world's power over its
    # footprint's area (L / pdf = 4 pi L; the area depends on its direction).
    from core.lights.emission import distant_footprint
    per_area = []
    for t in (t_map, t_const):
        ph = L.sample_photons(t, 10_000, np.random.default_rng(3))
        area = distant_footprint(t, ph["d"], np.zeros(10_000), np.zeros(10_000))[1]
        per_area.append(ph["power"] / area[:, None])
    np.testing.assert_allclose(per_area[0], per_area[1], rtol=1e-12)
    # Next-event estimation of the irradiance / pi on an upward plane: L exactly in
    # expectation (rho / pi * pi L with rho = 1).
    K = 400_000
    rng = np.random.default_rng(4)
    r = L.sample_direct(t_map, np.zeros((K, 3)), rng.random((K, 3)), n=np.tile([0, 0, 1.0], (K, 1)))
    est = r["weight"][:, 0] * np.maximum(r["wi"][:, 2], 0) / np.pi
    assert abs(est.mean() - Lw) <= Z * est.std() / math.sqrt(K), (est.mean(), est.std())


def _irradiance_quadrature(el, n, n_z=1000, n_p=2000):
    """int L(w) max(n.w, 0) dw by the midpoint rule (3,)."""
    z = -1 + 2 * (np.arange(n_z) + 0.5) / n_z
    p = 2 * np.pi * (np.arange(n_p) + 0.5) / n_p
    Zg, Pg = np.meshgrid(z, p, indexing="ij")
    s = np.sqrt(1 - Zg ** 2)
    w = np.stack([s * np.cos(Pg), s * np.sin(Pg), Zg], -1).reshape(-1, 3)
    cos = np.maximum(w @ np.asarray(n, float), 0)
    return (el.radiance(w) * cos[:, None]).sum(axis=0) * (2 / n_z) * (2 * np.pi / n_p)


@pytest.mark.parametrize("normal", [(0, 0, 1), (0.6, 0, 0.8), (0, -1, 0)])
def test_next_event_estimate_of_irradiance_matches_quadrature(normal):
    A = rotation((0, 0, 1), 0.4)
    el_map = EnvironmentMap(spiky_image(), strength=np.full(3, 1.5), to_texture=A)
    t = L.build_light_table(floor_scene(el_map))
    n = np.asarray(normal, float)
    E = _irradiance_quadrature(t.environment, n)
    K = 400_000
    rng = np.random.default_rng(9)
    r = L.sample_direct(t, np.zeros((K, 3)), rng.random((K, 3)), n=np.tile(n, (K, 1)))
    est = r["weight"] * np.maximum(r["wi"] @ n, 0)[:, None]
    m, se = est.mean(axis=0), est.std(axis=0) / math.sqrt(K)
    # Quadrature error (bright texels are ~1/16 of a region wide on the grid): < 0.3 %.
    assert np.all(np.abs(m - E) <= Z * se + 3e-3 * E), (m, E, se)


@pytest.mark.parametrize("with_normals", [False, True])
def test_pdf_direct_is_the_density_of_the_maps_light_sample(with_normals):
    """pdf_direct of the world's row is the density sample_direct drew the
    map's directions with (the map's own, with or without receiver normals):
    weight = L(wi) / pdf_direct on every sample, so the camera paths' MIS
    weights of a map's light sample and of a BSDF ray that escapes are those
    of one density (they once used the constant world's)."""
    from core.lights.pdf import environment_pdf
    A = rotation((0.3, 0.2, 1.0), 0.7)
    el_map = EnvironmentMap(spiky_image(), strength=np.full(3, 1.5), to_texture=A)
    t = L.build_light_table(floor_scene(el_map))
    K = 20_000
    rng = np.random.default_rng(4)
    p = rng.normal(size=(K, 3))
    n = rng.normal(size=(K, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    r = L.sample_direct(t, p, rng.random((K, 3)), n=n if with_normals else None)
    ok = r["weight"].max(axis=1) > 0
    assert ok.mean() > 0.45
    wi, light = r["wi"][ok], r["light"][ok]
    pdf = L.pdf_direct(t, p[ok], wi, light, r["dist"][ok], n=n[ok] if with_normals else None)
    Le = t.environment.radiance(wi)
    np.testing.assert_allclose(r["weight"][ok], Le / pdf[:, None], rtol=1e-12)
    np.testing.assert_array_equal(pdf, environment_pdf(t, p[ok], wi))


def test_supersampled_map_bounds_radiance_over_density(monkeypatch):
    """The importance map's cells (8 x 8 per texel of the 32 x 16 map) take
    the bilinear image's maximum over each cell, so L / pdf stays at most
    the map's total on every direction (no fireflies from the light
    sample), and it varies less than over the texels' own regions (the
    bright texels' light is sampled where it is): the relative variance of
    L / pdf under the sampler falls below a third of the texel grid's
    (measured: 0.030 against 1.01)."""
    from core.lights import environment as E
    assert E.supersampling(32) == 8 and E.supersampling(4096) == 1
    rng = np.random.default_rng(5)
    stats = {}
    for width in (1024, 0):
        monkeypatch.setattr(E, "SUPERSAMPLE_WIDTH", width)
        el = EnvironmentLight.build(EnvironmentMap(spiky_image(), strength=np.ones(3)))
        assert el.weight.shape == ((128, 256) if width else (16, 32))
        w, pdf = el.sample(rng.random(200_000), rng.random(200_000))
        r = el.radiance(w).mean(axis=1) / pdf
        assert r.max() <= el.total * (1 + 1e-9)
        v = rng.normal(size=(200_000, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        p = el.pdf(v)
        assert np.all(el.radiance(v).mean(axis=1) <= el.total * p * (1 + 1e-9))
        stats[width] = r.var() / r.mean() ** 2
    assert stats[1024] < stats[0] / 3, stats


def test_guided_region_is_the_bisection_of_the_whole_cdf():
    """environment_kernels.guided_region (the map's guide table) finds the
    region np.searchsorted(cdf, u1 total, side='right') finds, on the
    supersampled spiky map (32,768 cells, a guide of 8,192 steps), a
    2 x 4 map with one bright texel and one whose regions are mostly empty, for
    200,000 random u1 and the edges: 0, the guide's own steps g / G and the
    floats just below them, the largest float below 1."""
    from core.lights.environment_kernels import guided_region
    rng = np.random.default_rng(8)
    sparse = np.zeros((16, 32, 4), np.float32)
    sparse[3, 7, :3], sparse[12, 30, :3] = 50.0, 0.1
    small = np.ones((2, 4, 4), np.float32)
    small[1, 2, :3] = 9.0
    for img in (spiky_image(), small, sparse):
        el = EnvironmentLight.build(EnvironmentMap(img, strength=np.ones(3)))
        E = el.kernel_data()
        G = E.guide.shape[0] - 1
        assert G & (G - 1) == 0 and G >= E.cdf.shape[0] // 8
        steps = np.arange(G) / G
        u = np.concatenate([rng.random(200_000), steps, np.nextafter(steps, -1.0)[1:],
                            [0.0, np.nextafter(1.0, 0.0)]])
        got = np.array([guided_region(E, q, q * E.total) for q in u])
        np.testing.assert_array_equal(got, np.searchsorted(E.cdf, u * E.total, side="right"))


def test_photon_power_mean_is_the_map_flux():
    el_map = EnvironmentMap(spiky_image(), strength=np.full(3, 1.5))
    t = L.build_light_table(floor_scene(el_map))
    R = t.radius_scene
    # pi R^2 int L dw: int L dw from the quadrature of the radiance (n = no cosine:
    # two opposite hemispheres' cosine-weighted integrals are not it, so sum cells).
    z = -1 + 2 * (np.arange(1000) + 0.5) / 1000
    p = 2 * np.pi * (np.arange(2000) + 0.5) / 2000
    Zg, Pg = np.meshgrid(z, p, indexing="ij")
    s = np.sqrt(1 - Zg ** 2)
    w = np.stack([s * np.cos(Pg), s * np.sin(Pg), Zg], -1).reshape(-1, 3)
    flux = np.pi * R * R * t.environment.radiance(w).sum(axis=0) * (2 / 1000) * (2 * np.pi / 2000)
    K = 400_000
    ph = L.sample_photons(t, K, np.random.default_rng(12))
    # over its footprint's share of the disc (emission.distant_footprint)
    from core.lights.emission import distant_footprint
    area = distant_footprint(t, ph["d"], np.zeros(K), np.zeros(K))[1]
    pw = ph["power"] * (np.pi * R * R / area)[:, None]
    m, se = pw.mean(axis=0), pw.std(axis=0) / math.sqrt(K)
    assert np.all(np.abs(m - flux) <= Z * se + 3e-3 * flux), (m, flux, se)
    # The table's flux (used for light selection only) is the region-mean sum: within 1 %.
    np.testing.assert_allclose(t.flux[0], flux, rtol=1e-2)


# ---------------------------------------------------------------------------- Blender

def hdri_world(sc, img, strength=1.0, rotation=None, coord=None, coord_object=None):
    """The world: Texture Coordinate -> Mapping -> Environment Texture -> Background.

    img: (H, W, 4) float32 pixels (row 0 = nadir), made into a float image;
    rotation: the Mapping node's Euler XYZ (None: no Mapping node);
    coord: 'Generated' or 'Object' (None: no Texture Coordinate node)."""
    import bpy
    H, W = img.shape[:2]
    im = bpy.data.images.new("HDRI", W, H, alpha=True, float_buffer=True)
    im.colorspace_settings.name = 'Linear Rec.709'
    im.pixels.foreach_set(np.ascontiguousarray(img, np.float32).ravel())
    im.pack()
    w = bpy.data.worlds.new("HDRI World")
    nt = w.node_tree
    nt.nodes.clear()
    out = nt.nodes.new('ShaderNodeOutputWorld')
    bg = nt.nodes.new('ShaderNodeBackground')
    bg.inputs["Strength"].default_value = strength
    env = nt.nodes.new('ShaderNodeTexEnvironment')
    env.image = im
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs[0], out.inputs["Surface"])
    vec = env.inputs["Vector"]
    if rotation is not None:
        mp = nt.nodes.new('ShaderNodeMapping')
        mp.inputs["Rotation"].default_value = rotation
        nt.links.new(mp.outputs[0], vec)
        vec = mp.inputs["Vector"]
    if coord is not None:
        tc = nt.nodes.new('ShaderNodeTexCoord')
        tc.object = coord_object
        nt.links.new(tc.outputs[coord], vec)
    sc.world = w
    return w


def _export():
    import bpy

    from fppm.addon.export import export_scene
    lines = []
    s = export_scene(bpy.context.evaluated_depsgraph_get(), log=lines.append)
    return s, lines


def test_export_reads_the_map_mapping_and_coordinates():
    bpy = pytest.importorskip("bpy")
    import bpy_helpers as H
    from mathutils import Euler
    sc = H.empty_scene((16, 16))
    H.add_plane(sc)
    H.add_camera(sc)
    img = spiky_image()
    rot = (0.3, -0.2, 1.0)
    hdri_world(sc, img, strength=2.5, rotation=rot, coord='Generated')
    s, lines = _export()
    m = s.world_map
    np.testing.assert_array_equal(m.image, img)
    np.testing.assert_array_equal(m.strength, [2.5, 2.5, 2.5])
    R = np.array(Euler(rot, 'XYZ').to_matrix())
    np.testing.assert_allclose(m.to_texture, R, atol=1e-7)
    assert lines[1] == "Approximated: nothing.", lines[1]
    np.testing.assert_allclose(s.world_color, EnvironmentLight.build(m).mean_radiance)
    # Texture Coordinate Object: the object's inverse matrix, then the mapping.
    e = bpy.data.objects.new("Turn", None)
    e.rotation_euler = (0.0, 0.4, 0.9)
    H.link(e, sc)
    hdri_world(sc, img, rotation=rot, coord='Object', coord_object=e)
    s, lines = _export()
    Mi = np.linalg.inv(np.array(Euler((0.0, 0.4, 0.9), 'XYZ').to_matrix()))
    np.testing.assert_allclose(s.world_map.to_texture, R @ Mi, atol=1e-6)
    assert lines[1] == "Approximated: nothing.", lines[1]


# Passes and photons per pass: as tests/test_cycles_agreement.py's default, and
# for the glossy floor 1.5x its glossy floor's passes (measured sigma of the
# mean: diffuse 0.41 %, glossy 0.56 % at 96 passes, 0.7 % expected at 64).
HDRI_BUDGET = {"diffuse": (12, 100_000), "object": (12, 100_000), "glossy": (96, 40_000)}
# Per seed, two seeds: the reference's own noise on the mean is then ~0.05 %
# (measured: 0.01-0.02 % at 512), negligible against FPPM's.
CYCLES_SAMPLES = 128


def _hdri_image():
    """64 x 32 sky: a dim gradient and a few bright texels above the horizon."""
    H, W = 32, 64
    img = np.zeros((H, W, 4), np.float32)
    rows = (np.arange(H) + 0.5) / H
    img[..., 0] = (0.15 + 0.25 * rows)[:, None]
    img[..., 1] = 0.25
    img[..., 2] = (0.45 - 0.2 * rows)[:, None]
    img[..., 3] = 1.0
    img[26, 9, :3] = (300.0, 240.0, 180.0)
    img[22, 40, :3] = (60.0, 90.0, 150.0)
    img[19, 55, :3] = (0.0, 120.0, 0.0)
    return img


def _hdri_scene(kind):
    import bpy
    from scenes import bpy_kit as K
    sc = K.reset_scene((64, 64), samples=CYCLES_SAMPLES)
    floor = (K.material("Floor", "DIFFUSE", color=(0.8, 0.8, 0.8)) if kind != "glossy"
             else K.material("Floor", "GLOSSY", color=(0.9, 0.9, 0.9), roughness=0.3))
    K.plane("Floor", 6.0, floor)
    K.box("Box", (1.0, 1.0, 1.0), K.material("Red", "DIFFUSE", color=(0.8, 0.2, 0.1)),
          rot_z_deg=30.0)
    K.camera((0.0, -5.0, 2.5), (0.0, 0.0, 0.3))
    if kind == "object":
        # Texture Coordinate Object: the map turns with an empty (at the origin).
        turn = bpy.data.objects.new("Turn", None)
        turn.rotation_euler = (0.3, -0.2, 2.0)
        K.link(turn)
        hdri_world(sc, _hdri_image(), strength=1.0, rotation=(0.0, 0.0, 0.5), coord='Object',
                   coord_object=turn)
        return sc
    hdri_world(sc, _hdri_image(), strength=1.0,
               rotation=(0.0, 0.0, 0.0) if kind == "diffuse" else (0.2, 0.0, 1.3),
               coord='Generated')
    return sc


def _cycles(sc, seed, path, rgba=False):
    sc.render.engine = 'CYCLES'
    sc.cycles.samples = CYCLES_SAMPLES
    sc.cycles.seed = seed
    sc.cycles.use_animated_seed = False
    im = sc.render.image_settings
    im.file_format, im.color_depth, im.color_mode = 'OPEN_EXR', '32', 'RGBA'
    sc.render.filepath = str(path)
    sc.render.use_file_extension = False
    import bpy

    from scenes.refs import read_exr
    bpy.ops.render.render(write_still=True)
    img = read_exr(str(path)).astype(np.float64)
    return img if rgba else img[..., :3]


def _render_camera_paths(scene, integrator, seed, passes):
    """A camera-path integrator's image (4 paths a pixel a pass)."""
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    st = RenderSettings(integrator=integrator, max_passes=passes, seed=seed, max_bounces=16,
                        use_frequency=False)
    return Renderer(scene, st, log=lambda s: None).run().image[..., :3].astype(np.float64)


#: Passes of the camera-path integrators (4 paths a pixel each) per seed.
HDRI_PATH_PASSES = 48


#: Cycles' two seeds of each kind of scene, rendered once (every case of
#: one kind renders the same scene).
_HDRI_REFS: dict = {}


@pytest.mark.parametrize("kind,integrator", [
    ("diffuse", "PHOTON"), ("glossy", "PHOTON"), ("object", "PHOTON"),
    ("glossy", "PATH"), ("glossy", "COMBINED")])
def test_hdri_agrees_with_cycles(kind, integrator, tmp_path):
    """The bounds of tests/test_cycles_agreement.py, with the reference
    rendered here (two seeds: its noise is measured the same way).  The
    camera paths (PATH, COMBINED) see the map where they escape: directly,
    in the glossy floor, and through their MIS with the map's light sample.
    The map's Object coordinates are the export's, checked with PHOTON."""
    pytest.importorskip("bpy")
    from test_cycles_agreement import BIAS_ALLOWANCE, render

    from scenes.refs import RELMSE_EPS
    sc = _hdri_scene(kind)
    scene, _ = _export()
    assert scene.world_map is not None
    if kind not in _HDRI_REFS:
        _HDRI_REFS[kind] = (_cycles(sc, 0, tmp_path / "c0.exr"), _cycles(sc, 1, tmp_path / "c1.exr"))
    c1, c2 = _HDRI_REFS[kind]
    ref = 0.5 * (c1 + c2)
    if integrator == "PHOTON":
        passes, photons = HDRI_BUDGET[kind]
        a1 = render(scene, 1, passes, photons)
        a2 = render(scene, 2, passes, photons)
    else:
        a1 = _render_camera_paths(scene, integrator, 1, HDRI_PATH_PASSES)
        a2 = _render_camera_paths(scene, integrator, 2, HDRI_PATH_PASSES)
    mean_img = 0.5 * (a1 + a2)
    denom = ref ** 2 + RELMSE_EPS
    noise_fppm = two_seed_relmse_noise(a1, a2, denom)
    noise_ref = two_seed_relmse_noise(c1, c2, denom)
    relmse = float(np.mean((mean_img - ref) ** 2 / denom))
    mask = emitter_free_mask(ref)
    m, r = mean_img[mask].mean(), ref[mask].mean()
    sigma_mean = two_seed_block_sigma(a1, a2, mask)
    sigma_ref = two_seed_block_sigma(c1, c2, mask)
    print(f"hdri {kind} {integrator}: mean {m:.5f} vs Cycles {r:.5f} (ratio {m / r:.4f}, "
          f"sigma {sigma_mean / r:.2%} + Cycles {sigma_ref / r:.2%}, {mask.mean():.0%} of pixels); relMSE {relmse:.2e}, "
          f"noise fppm {noise_fppm:.2e} + ref {noise_ref:.2e}")
    assert math.hypot(sigma_mean, sigma_ref) < 0.0067 * r
    assert abs(m / r - 1.0) < 0.02
    assert relmse < 1.5 * (noise_fppm + noise_ref) + BIAS_ALLOWANCE


@pytest.mark.parametrize("photons_for_direct", [False, True])
def test_lambert_plane_under_a_map_has_the_closed_form_radiance(photons_for_direct):
    """A Lambert plane z = 0 (2.5 m wide, the view 2 m) under the spiky map:
    nothing else in the scene, so every pixel is rho / pi * int_{z > 0} L(w) w_z dw (the
    quadrature), whether next-event estimation (light and BSDF samples) or the
    photons (emitted by the map's distribution) carry the direct light.
    Bounds as tests/test_render_analytic.py's point-light plane: mean within
    2 %, its noise (two seeds) under 0.6 % (measured: 0.45 % next-event, 0.28 %
    photons; means -0.5 % and -0.5 %)."""
    from analytic_scenes import lambert, look_down_ortho, quad

    from core.render import Renderer
    from core.settings import RenderSettings
    rho = 0.8
    env = EnvironmentMap(spiky_image(), strength=np.full(3, 2.0),
                         to_texture=rotation((0, 0, 1), 0.4))
    sc = make_scene(quad((0, 0, 0), (1.25, 0, 0), (0, 1.25, 0)), [lambert("floor", rho)], [],
                    look_down_ortho(3.0, 2.0, 32))
    sc.world_map = env
    sc.world_color = EnvironmentLight.build(env).mean_radiance
    expected = rho / np.pi * _irradiance_quadrature(EnvironmentLight.build(env), (0, 0, 1))
    imgs = []
    for seed in (1, 2):
        st = RenderSettings(integrator="PHOTON",
                            max_passes=48, photons_per_pass=30_000, use_frequency=False, seed=seed,
                            photons_for_direct=photons_for_direct, initial_radius_px=1.0)
        imgs.append(Renderer(sc, st, log=lambda s: None).run().image[..., :3].astype(np.float64))
    a, b = imgs
    mean = 0.5 * (a + b).reshape(-1, 3).mean(axis=0)
    # Pixels share photons within ~1 px: 4x4 blocks for the noise of the mean.
    d = (a - b).reshape(8, 4, 8, 4, 3).mean(axis=(1, 3)).reshape(-1, 3)
    sigma = np.sqrt(np.sum(d ** 2 / 4.0, axis=0)) / d.shape[0]
    print(f"plane under map (photons_for_direct={photons_for_direct}): {mean} vs {expected}, "
          f"sigma {sigma / expected}")
    assert np.all(sigma < 0.006 * expected)
    assert np.all(np.abs(mean / expected - 1) < 0.02)


def _map_of_kind(kind):
    """spiky_image as an RGBA, grey (one channel) or unassociated-alpha map,
    and a rotated, scaled mapping A (to_texture)."""
    from core.scene.textures import UnassociatedImage
    img = spiky_image()
    if kind == "grey":
        img = np.ascontiguousarray(img[..., :1])
    elif kind == "unassociated":
        img[..., 3] = np.linspace(0.2, 1.0, img.shape[1], dtype=np.float32)[None, :]
        img[0, 0, 3] = 0.0
        img = img.view(UnassociatedImage)
    return img, rotation((1, 2, 3), 0.7) @ np.diag([1.0, 1.3, 0.8])


@pytest.mark.parametrize("kind", ["rgba", "grey", "unassociated"])
def test_compiled_map_lookup_and_density_equal_numpy(kind):
    """environment_kernels.rays_radiance (the camera paths' escaped rays)
    equals textures.environment_radiance, and map_pdf equals
    EnvironmentLight.pdf, on 50,000 random directions of a map with a
    rotated, scaled mapping: radiance to 1e-9 relative (numpy's arctan2 and
    BLAS's products), density to 1e-12 relative; grey and unassociated-alpha
    maps read as sample_texture reads them."""
    from core.lights.environment_kernels import map_pdf, rays_radiance, texture_vector
    img, A = _map_of_kind(kind)
    el = EnvironmentLight.build(EnvironmentMap(img, strength=np.array([1.5, 1.0, 0.5]),
                                               to_texture=A))
    E = el.kernel_data()
    rng = np.random.default_rng(8)
    d = rng.normal(size=(50_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rows = np.arange(0, 50_000, 2, dtype=np.int64)
    out = np.empty((rows.size, 3))
    rays_radiance(E, d, rows, out)
    ref = el.radiance(d[rows])
    np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-12 * ref.max())
    assert ref.max() > 10.0                       # the bright texels are among them
    pdf = np.array([map_pdf(E, *texture_vector(E, *w)) for w in d[:2000]])
    np.testing.assert_allclose(pdf, el.pdf(d[:2000]), rtol=1e-12)


@pytest.mark.parametrize("kind", ["rgba", "grey", "unassociated"])
def test_compiled_world_photons_equal_numpy(monkeypatch, kind):
    """lights.environment_kernels.world_photons (an environment map's photons in one
    compiled step) equals the numpy emission it replaces
    (emission.COMPILED_ENVIRONMENT off) on 100,000 photons of a map with a
    rotated, scaled mapping, beside an area light: the same photons to 1e-12
    (directions, origins) and 1e-9 (powers: the map's lookup through
    numpy's arctan2 and BLAS's products).  A grey map (one channel) and an
    unassociated-alpha map read as sample_texture reads them."""
    from core.lights import emission as Em
    from core.scene.model import Light
    img, A = _map_of_kind(kind)
    sc = floor_scene(EnvironmentMap(img, strength=np.array([1.5, 1.0, 0.5]), to_texture=A))
    m = np.eye(4)
    m[:3, 3] = (0, 0, 2)
    sc.lights = [Light("area", "AREA", (10, 10, 10), m, size=0.5)]
    t = L.build_light_table(sc)
    out = []
    for flag in (True, False):
        monkeypatch.setattr(Em, "COMPILED_ENVIRONMENT", flag)
        out.append(L.sample_photons(t, 100_000, np.random.default_rng(4)))
    a, b = out
    world = a["kind"] == L.WORLD
    assert 50_000 < np.count_nonzero(world) < 100_000
    np.testing.assert_array_equal(a["kind"], b["kind"])
    np.testing.assert_allclose(a["d"], b["d"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a["o"], b["o"], rtol=0, atol=1e-12 * t.radius_scene)
    np.testing.assert_allclose(a["power"], b["power"], rtol=1e-9, atol=0)
    np.testing.assert_array_equal(a["freq_init"], b["freq_init"])
    assert np.all(a["power"][world].max(axis=1) > 0)
