"""The compiled camera and direct-light stages against their numpy references,
and next-event estimation at visible points hit from the back of a surface.

What is asserted, and where each tolerance comes from:
- The compiled camera pass (core.sppm.camera_kernels) gives the numpy
  reference's visible points, first hits and emission bit for bit, except
  p_delta-dependent throughput (beta): the luminance dot product is written
  out instead of numpy's matmul, so beta may differ by 2 ulp (rtol 1e-15;
  measured: equal on these scenes).  Scenes: Lambert walls, a rough glossy +
  diffuse mix, a mirror, a glass cube (delta chains), an emitter mesh, a
  Principled-style layered material, a textured Lambert with textured
  emission, a constant world; both the one-thread and the two-thread split
  (SPLIT_MIN).
- The compiled direct light (core.lights.direct_kernels) equals the numpy
  sampler + eval_bsdf within rtol 1e-9 (measured 5e-12): the same formulas,
  but numba's libm arccos/sin/cos against numpy's, amplified by the
  spherical-rectangle and -triangle inversions near their degenerate ends,
  and f = (sum of Lambert colours)/pi against the sum of colour/pi per lobe.
  Lights: point (radius 0, soft disc, sphere), spot, sun with an angle, a
  square and a disc area light, single emissive triangles and a group of
  more than 16 (selected by flux), a constant world; and an environment
  map beside them all (core.lights.map_mis_kernels: its light samples and
  the visible points' BSDF samples weighed by the balance heuristic),
  over Lambert, glossy, Normal-Mapped, bump-mapped and colour-textured
  Principled-like materials (measured 1.3e-12).  Without the map's BSDF
  samples the image loses 7.4-7.8 % of its light there, far outside the
  tolerance; the draws end where numpy's do.
- Rough glass seen from its back (a single-sided quad whose normal points away
  from the camera, lit through it by a point light of radius 0): PHOTON mode's
  direct light equals the PATH integrator's image.  With a radius-0 point
  light and nothing else in the scene, both are the same deterministic NEE
  at the first vertex (BSDF rays escape to a black world; photons find no
  second surface), so the only difference is where the pixel filter puts the
  camera rays: the image means agree to 4% (measured -0.3% to -1.4% over
  three seeds); with the relative IOR of a front-face hit (eta instead of
  1/eta, the bug this guards) they differ by +28% to +32%.
- The compiled radius initialisation (core.sppm.update ``_initialise_range``)
  sets the numpy reference's R2 (``Radii.compiled = False``) bit for bit: the
  same operations in numpy's dtypes (the footprint rule in float32, the cap
  and WORLD radii in float64).  Perspective and orthographic footprints,
  AUTO and WORLD radii, with and without the edge cap (infinite caps, caps
  below the rule and below the floor, depths whose rule is below the floor),
  invalid pixels and pixels that already have a radius; one thread and split
  (hashgrid.PARALLEL_MIN_VPS, lowered for the test); and a render's first
  pass (the warm-up room), whose edge cap is its own camera pass.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from core.render import Renderer
from core.scene.camera import CameraModel
from core.scene.model import DIFFUSE, GLASS, GLOSSY, Camera, Light, Lobe, Material, make_scene
from core.settings import RenderSettings
from core.sppm import camera_kernels as CK
from core.sppm import hashgrid as Hg
from core.sppm import update as U
from core.sppm.state import PixelState
from core.warmup import warmup_scene

from analytic_scenes import look_down_ortho, quad, translate
from test_path_tracer import every_light_kind


def _mixed_scene(res, n_small_tris=20, textured_emission=True):
    """A floor of three materials (Principled-style layered dielectric over
    diffuse, a textured Lambert with a textured emission, a mirror + Lambert
    mix), n_small_tris small emissive triangles (> 16: the triangle group),
    every analytic light kind and a constant world, seen from above."""
    tris = quad((-3, 0, 0), (2, 0, 0), (0, 5, 0)) + quad((1, 0, 0), (2, 0, 0), (0, 5, 0))
    tris += quad((4, 0, 0), (1, 0, 0), (0, 5, 0))
    rng = np.random.default_rng(3)
    for _ in range(n_small_tris):
        c = rng.uniform([-3, -3, 1.5], [3, 3, 2.5])
        tris.append([c, c + [0.05, 0, 0], c + [0, 0.05, -0.01]])
    emit_tex = dict(emission=(0.2, 0.2, 0.2), emission_texture=0) if textured_emission else {}
    tex = np.random.default_rng(1).uniform(0.2, 1.0, (8, 8, 3)).astype(np.float32)
    mats = [Material("principled", (Lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.4,
                                         fresnel="DIELECTRIC", fresnel_ior=1.5),
                                    Lobe(DIFFUSE, (0.7, 0.3, 0.2), layer_ior=1.5,
                                         layer_roughness=0.4))),
            Material("textured", (Lobe(DIFFUSE, (0.9, 0.9, 0.9), color_texture=0),), **emit_tex),
            Material("mirror_mix", (Lobe(GLOSSY, (0.9, 0.9, 0.9), weight=0.3),
                                    Lobe(DIFFUSE, (0.5, 0.6, 0.7), weight=0.7))),
            Material("emit", emission=(3.0, 2.0, 1.0))]
    tri_mat = [0, 0, 1, 1, 2, 2] + [3] * n_small_tris
    uv = np.random.default_rng(2).random((len(tris), 3, 2))
    lights = every_light_kind(Light("tiny", "POINT", (5, 5, 5), translate(2, 2, 1.0)))
    return make_scene(tris, mats, lights, look_down_ortho(3.0, 9.0, res), tri_mat=tri_mat,
                      tri_uv=uv, world_color=(0.1, 0.2, 0.3), textures=[tex])


def _metal_scene(res):
    """Glossy chains (visible_points.CameraPass): a rough metal floor under a
    Lambert slab whose underside it reflects, a strip of rough glass and a
    mirror strip beside it, the small emitters, every light kind and a
    constant world, seen from above."""
    tris = quad((-3, 0, 0), (5, 0, 0), (0, 5, 0)) + quad((-1, 0, 1.2), (2, 0, 0), (0, 5, 0))
    tris += quad((2, 0, 0), (1, 0, 0), (0, 5, 0)) + quad((3, 0, 0.1), (1, 0, 0), (0, 5, 0.4))
    rng = np.random.default_rng(3)
    for _ in range(20):
        c = rng.uniform([-3, -3, 1.5], [3, 3, 2.5])
        tris.append([c, c + [0.05, 0, 0], c + [0, 0.05, -0.01]])
    mats = [Material("metal", (Lobe(GLOSSY, (0.9, 0.8, 0.6), roughness=0.3, fresnel="F82"),)),
            Material("slab", (Lobe(DIFFUSE, (0.7, 0.6, 0.5)),)),
            Material("rough_glass", (Lobe(GLASS, (1.0, 1.0, 1.0), roughness=0.3, ior=1.5),)),
            Material("mirror", (Lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.0),)),
            Material("emit", emission=(3.0, 2.0, 1.0))]
    tri_mat = [0, 0, 1, 1, 2, 2, 3, 3] + [4] * 20
    lights = every_light_kind(Light("tiny", "POINT", (5, 5, 5), translate(2, 2, 1.0)))
    return make_scene(tris, mats, lights, look_down_ortho(3.0, 9.0, res), tri_mat=tri_mat,
                      world_color=(0.1, 0.2, 0.3))


def _hdri_scene(res, **kw):
    """test_path_kernels' room under an environment map (every light kind
    besides it): a glossy wall and a glass block, and with ``kw`` a Normal
    Map, a Bump and colour textures."""
    from test_path_kernels import _scene
    return _scene(res=res, world_map=True, glossy=True, **kw)


SCENES = {"room": lambda res: warmup_scene(res, ("POINT", "AREA", "SPOT", "SUN")),
          "mixed": _mixed_scene,
          # Textured emissive triangles are sampled by the numpy sampler only.
          "mixed_untextured_emission": lambda res: _mixed_scene(res, textured_emission=False),
          "metal": _metal_scene,
          "hdri": _hdri_scene,
          "hdri_bumped_textured": lambda res: _hdri_scene(res, bumped=True, textured=True)}
# 40^2 < SPLIT_MIN rays (one thread), 72^2 > SPLIT_MIN (two halves).
assert 40 * 40 < CK.SPLIT_MIN < 72 * 72


def _stages(name, res):
    scene = SCENES[name](res)
    # "glossy chains" forced: the metal scene's point light and mirror would
    # leave them out (core.plan.casts_small_caustics)
    r = Renderer(scene, RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=100, seed=1),
                 log=lambda _m: None, force_stages=("glossy chains",))
    return r.camera_pass, r.direct_light


def _run(stage, compiled, *args):
    stage.compiled = compiled
    try:
        return stage(*args)
    finally:
        stage.compiled = True


def _same_glossy_points(g_n, g_c, name):
    """The numpy and compiled camera passes found as many glossy points
    (their light samples are in L, compared bit for bit)."""
    assert g_n == g_c and (g_n > 50 if name == "metal" else True)


@pytest.mark.parametrize("name", ["room", "mixed", "metal"])
@pytest.mark.parametrize("res", [40, 72])
def test_compiled_camera_pass_equals_numpy(name, res):
    cam, _ = _stages(name, res)
    cam.first_data = True            # the Renderer's PHOTON passes skip the first hits' data
    vp_n, L_n = _run(cam, False, np.random.default_rng(11))
    g_n = cam.glossy_count
    vp_c, L_c = _run(cam, True, np.random.default_rng(11))
    _same_glossy_points(g_n, cam.glossy_count, name)
    assert vp_n.valid.sum() > (0.4 if name == "metal" else 0.5) * vp_n.valid.size
    for f in ("valid", "front", "p", "ng", "ns", "wo", "mat", "colors", "depth", "const",
              "albedo", "through_delta"):
        a, b = getattr(vp_n, f), getattr(vp_c, f)
        assert a.dtype == b.dtype and np.array_equal(a, b), f
    # through_delta as it was derived from the first hits (a delta chain
    # never returns to its first hit), before the kernel wrote it.
    assert np.array_equal(vp_c.through_delta,
                          vp_c.valid & np.any(vp_c.p != vp_c.first.p, axis=1))
    np.testing.assert_allclose(vp_c.beta, vp_n.beta, rtol=1e-15, atol=0)
    for f in ("hit", "p", "n", "prim", "emit", "escape"):
        assert np.array_equal(getattr(vp_n.first, f), getattr(vp_c.first, f)), f
    assert np.array_equal(L_n, L_c)
    if name == "room":       # delta chains through the mirror and the glass cube
        assert np.any(vp_n.beta.max(axis=1) < 0.99)


@pytest.mark.parametrize("name", ["room", "mixed", "metal"])
@pytest.mark.parametrize("centre", [False, True])
def test_blocked_camera_pass_equals_numpy(name, centre, monkeypatch):
    """The compiled pass in blocks of pixels (CameraPass._trace_blocked; 1080p
    takes it with 65536-pixel blocks, here 700 so that a 40x40 image has
    three, the last one partial) gives the numpy reference's results bit for
    bit (beta within the 1e-15 above) and leaves the random stream where
    the reference leaves it."""
    from core.sppm import visible_points as VP
    monkeypatch.setattr(VP, "CAMERA_BLOCK", 700)
    cam, _ = _stages(name, 40)
    cam.first_data = True
    out = []
    for compiled in (False, True):
        rng = np.random.default_rng(11)
        cam.compiled = compiled
        vp, L = cam(rng, centre=centre)
        out.append((vp, L.copy(), rng.random(4), cam.glossy_count))
    cam.compiled = True
    (vp_n, L_n, r_n, g_n), (vp_c, L_c, r_c, g_c) = out
    _same_glossy_points(g_n, g_c, name)
    assert vp_n.valid.sum() > (0.4 if name == "metal" else 0.5) * vp_n.valid.size
    for f in ("valid", "front", "p", "ng", "ns", "wo", "mat", "colors", "depth", "const",
              "albedo", "through_delta"):
        assert np.array_equal(getattr(vp_n, f), getattr(vp_c, f)), f
    np.testing.assert_allclose(vp_c.beta, vp_n.beta, rtol=1e-15, atol=0)
    for f in ("hit", "p", "n", "prim", "emit", "escape"):
        assert np.array_equal(getattr(vp_n.first, f), getattr(vp_c.first, f)), f
    assert np.array_equal(L_n, L_c) and np.array_equal(r_n, r_c)
    if name == "room":
        assert np.any(vp_c.through_delta)


@pytest.mark.parametrize("compiled", [False, True])
def test_camera_pass_without_first_data(compiled):
    """first_data=False (PHOTON passes without data passes or merging) keeps
    the first hits' alpha (escape) and changes nothing else, bit for bit;
    the other first-hit arrays have no rows."""
    cam, _ = _stages("room", 40)
    out = {}
    for fd in (True, False):
        cam.first_data = fd
        vp, L = _run(cam, compiled, np.random.default_rng(11))
        out[fd] = vp, L.copy()
    (vp_t, L_t), (vp_f, L_f) = out[True], out[False]
    assert np.any(vp_t.through_delta)
    for f in ("valid", "front", "p", "ng", "ns", "wo", "mat", "colors", "beta", "depth",
              "const", "albedo", "through_delta"):
        assert np.array_equal(getattr(vp_t, f), getattr(vp_f, f)), f
    assert np.array_equal(vp_t.first.escape, vp_f.first.escape)
    assert np.array_equal(L_t, L_f)
    for f in ("hit", "p", "n", "prim", "emit"):
        assert getattr(vp_f.first, f).shape[0] == 0, f


@pytest.mark.parametrize("name", ["room", "mixed_untextured_emission", "hdri",
                                  "hdri_bumped_textured"])
@pytest.mark.parametrize("res", [40, 72])
def test_compiled_direct_light_equals_numpy(name, res):
    cam, nee = _stages(name, res)
    vp, _ = cam(np.random.default_rng(11))
    rn, rc = np.random.default_rng(12), np.random.default_rng(12)
    L_n = _run(nee, False, vp, rn)
    L_c = _run(nee, True, vp, rc)
    assert nee._compiled_lights() is not None
    assert (nee._map() is not None) == name.startswith("hdri")
    lit = L_n.max(axis=1) > 0
    assert lit.mean() > 0.3
    np.testing.assert_allclose(L_c, L_n, rtol=1e-9, atol=1e-12 * float(L_n.max()))
    assert np.array_equal(rn.random(3), rc.random(3))      # the same draws


def _back_lit_rough_glass(res=24):
    """A rough glass quad at z = 1 with its normal down (-Z), seen from above by
    an orthographic camera (its back face), lit by a point light below it."""
    tris = quad((0, 0, 1.0), (0, 5, 0), (5, 0, 0))          # normal (0,5,0) x (5,0,0) = -Z
    mats = [Material("rough_glass", (Lobe(GLASS, (1.0, 1.0, 1.0), roughness=0.7, ior=1.5),))]
    lights = [Light("pt", "POINT", (100.0, 100.0, 100.0), translate(0.2, 0.1, -0.5), radius=0.0)]
    return make_scene(tris, mats, lights, look_down_ortho(3.0, 2.0, res), tri_mat=[0, 0])


def test_nee_back_face_rough_glass_matches_path():
    scene = _back_lit_rough_glass()
    base = RenderSettings(integrator="PHOTON",
                          max_passes=4, photons_per_pass=500, seed=3, use_frequency=False)
    img_photon = Renderer(scene, base, log=lambda _m: None).run().image[..., :3]
    img_path = Renderer(scene, base.replace(integrator="PATH", camera_samples=4),
                        log=lambda _m: None).run().image[..., :3]
    m_photon, m_path = float(img_photon.mean()), float(img_path.mean())
    assert m_path > 0.01
    assert abs(m_photon / m_path - 1.0) < 0.04, (m_photon, m_path)


def test_textured_emitters_use_the_numpy_sampler():
    _, nee = _stages("mixed", 8)
    assert nee._compiled_lights() is None


@pytest.mark.parametrize("name", ["room", "mixed_untextured_emission", "hdri"])
def test_blocked_direct_light_and_add_to(name, monkeypatch):
    """The compiled direct light in blocks of visible points (1080p: 65536,
    here 500: four blocks) is bit for bit the one-block result, and the
    stream ends where the one-block draw leaves it; add_to=E (the renderer's
    emission array) gives bit for bit E + L (one addition per pixel), or
    with an environment map E + L to rounding (two additions a pixel: its
    light sample's, then its BSDF sample's)."""
    from core.lights import nee as NEE
    cam, nee = _stages(name, 40)
    vp, _ = cam(np.random.default_rng(11))
    assert vp.valid.sum() > 1200          # more than two blocks of 500
    rng = np.random.default_rng(12)
    L1 = nee(vp, rng)
    r1 = rng.random(3)
    monkeypatch.setattr(NEE, "DIRECT_BLOCK", 500)
    rng = np.random.default_rng(12)
    assert np.array_equal(nee(vp, rng), L1) and np.array_equal(rng.random(3), r1)
    E = np.random.default_rng(5).uniform(0, 2, L1.shape)
    want = E + L1
    out = nee(vp, np.random.default_rng(12), add_to=E)
    assert out is E
    if nee._map() is None:
        assert np.array_equal(E, want)
    else:
        np.testing.assert_allclose(E, want, rtol=1e-15, atol=0)
    assert np.count_nonzero(L1.max(axis=1) > 0) > 0.3 * L1.shape[0]


def _init_case(P, seed, kind):
    """A pass's visible points (valid, float32 depth), a state with some radii
    set, a camera of this kind and an edge cap (P,) relative to the rule's radius."""
    rng = np.random.default_rng(seed)
    W = 250
    cam = CameraModel(Camera(kind=kind, matrix_world=np.eye(4), lens=35.0, sensor_width=36.0,
                             resolution=(W, P // W), clip_start=0.01, clip_end=100.0,
                             ortho_scale=2.5))
    depth = rng.uniform(0.5, 8.0, P).astype(np.float32)
    depth[rng.random(P) < 0.02] = np.float32(1e-9)     # the rule below the floor
    vp = SimpleNamespace(valid=rng.random(P) > 0.1, depth=depth)
    st = PixelState.zeros(P)
    st.R2[:] = rng.uniform(1e-6, 1e-4, P) * (rng.random(P) < 0.3)
    cap = rng.uniform(0.2, 1.5, P)                     # times the rule's radius
    cap[rng.random(P) < 0.3] = np.inf
    cap[rng.random(P) < 0.02] = 1e-12                  # below the floor
    return cam, vp, st, cap


@pytest.mark.parametrize("P", [3000, 250 * 280])
@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
@pytest.mark.parametrize("mode,capped", [("AUTO", True), ("AUTO", False), ("WORLD", True),
                                         ("WORLD", False)])
def test_compiled_radius_initialisation_equals_numpy(P, kind, mode, capped, monkeypatch):
    monkeypatch.setattr(Hg, "PARALLEL_MIN_VPS", 250 * 280)   # the split path at 250 x 280
    cam, vp, st, cap = _init_case(P, P, kind)
    settings = RenderSettings(integrator="PHOTON", radius_mode=mode, initial_radius=0.004,
                              cap_radius_at_edges=capped)
    rule = (np.full(P, 0.004) if mode == "WORLD"
            else settings.initial_radius_px * cam.footprint(vp.depth))
    cap = cap * rule
    R2 = {}
    for compiled in (False, True):
        radii = U.Radii(settings, cam, 3.7, False, None, P // 250, 250)
        radii._edge_cap = cap                          # not its camera pass
        radii.compiled = compiled
        s = st.R2.copy()
        st_c = type(st)(**{**st.state_dict(), "R2": s})
        radii.initialise(st_c, vp)
        R2[compiled] = s
    new = vp.valid & (st.R2 == 0)
    assert new.mean() > 0.5 and np.all(R2[False][new] > 0)
    assert np.array_equal(R2[False][~new], st.R2[~new])
    assert R2[True].dtype == np.float64 and np.array_equal(R2[True], R2[False])
    if capped:                                         # the cap and the floor both bind somewhere
        r = np.sqrt(R2[False][new])
        assert np.mean(r < 0.99 * rule[new]) > 0.2
        assert np.any(r == radii.floor)


def test_compiled_radius_initialisation_in_a_render():
    R2 = {}
    for compiled in (False, True):
        r = Renderer(warmup_scene(40), RenderSettings(integrator="PHOTON", max_passes=1,
                                                      photons_per_pass=2000, seed=2),
                     log=lambda _m: None)
        r.radii.compiled = compiled
        init = r.radii.initialise

        def keep(state, vp, check_stop, init=init, compiled=compiled):
            init(state, vp, check_stop)
            R2[compiled] = state.R2.copy()
        r.radii.initialise = keep
        r.step()
    assert np.mean(R2[False] > 0) > 0.9
    assert np.array_equal(R2[True], R2[False])
