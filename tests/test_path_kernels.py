"""The compiled camera paths (core.integrators.path_kernels) against the numpy reference.

What is asserted, and where each tolerance comes from:
- One pass of PATH and of COMBINED with ``PathTracer.compiled`` on equals the
  numpy reference (``compiled = False``) fed the same random numbers, within
  rtol 1e-9 plus 1e-9 of the image's largest pixel (measured: 5e-16 of the
  largest pixel, 1.4e-14 relative per pixel): the kernels compute the same
  formulas in float64, but group some products differently (direct_kernels'
  beta f cos weight), take the Lambert f as (sum of colours)/pi, the sampled
  density as N.wi/pi instead of the sampler's local z/pi, and numba's libm may round arccos/sin/cos
  differently from numpy's, which the spherical rectangle and triangle
  inversions amplify near their degenerate ends (tests/test_compiled_stages.py,
  the same 1e-9).  Paths make the same decisions (roulette, lobe, glass
  Fresnel choice), so a wrong branch would show as an O(1) difference.
  Scene: Lambert floor and walls (one material of two Lambert lobes), a
  perfect mirror, a smooth glass block, every analytic light kind with a
  shape, a radius-0 point light (delta), emissive triangles (single, and a
  group of more than 16), a constant world, seen by a perspective camera.
- The compiled light-sampling density (``lights.pdf_kernels.selection_kernel`` and
  ``pdf_kernel`` through ``PathTracer.pdf_light``) equals ``core.lights.pdf_direct`` for samples of
  every emitter kind, rtol 1e-9 (the same libm argument).
- A rough glossy wall (GENERIC) is in the kernels' scope and gives numpy's
  image to the same tolerance, with the kernels and with round 24's numpy
  vertices; a scene outside the scope (a Transparent lobe) uses the numpy
  path (``kernels()`` is None).
"""
from __future__ import annotations

import numpy as np
import pytest

from core import lights as Lt
from core.materials.fast import MIRROR, SMOOTH_GLASS, build_fast_materials
from core.render import Renderer
from core.scene.model import (DIFFUSE, GLASS, GLOSSY, TRANSPARENT, Camera, Light, Lobe, Material,
                              make_scene)
from core.settings import RenderSettings

from analytic_scenes import quad, translate
from test_path_tracer import every_light_kind


def _box(c, s):
    """The six faces (12 triangles) of a cube of half size s centred at c, normals out."""
    x, y, z = c
    return (quad((x, y, z + s), (s, 0, 0), (0, s, 0)) + quad((x, y, z - s), (0, s, 0), (s, 0, 0))
            + quad((x + s, y, z), (0, s, 0), (0, 0, s)) + quad((x - s, y, z), (0, 0, s), (0, s, 0))
            + quad((x, y + s, z), (0, 0, s), (s, 0, 0)) + quad((x, y - s, z), (s, 0, 0), (0, 0, s)))


def _bumps(n=16):
    """A tangent-space normal map (bumps of slope up to ~0.6, rgb in [0, 1])
    and a height field, float32 (n, n, 3)."""
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    c = np.stack([0.6 * np.sin(2 * np.pi * x) * np.cos(2 * np.pi * y),
                  0.4 * np.cos(2 * np.pi * x + 1.0), np.ones_like(x)], -1)
    c /= np.linalg.norm(c, axis=-1, keepdims=True)
    h = (0.5 + 0.5 * np.sin(2 * np.pi * x) * np.sin(2 * np.pi * (y + 0.1)))[..., None]
    return ((c + 1) / 2).astype(np.float32), (h * np.ones(3)).astype(np.float32)


def _checker(n=8):
    """A colour checker (n, n, 3) float32 of two tints, for Base Color textures."""
    y, x = np.mgrid[0:n, 0:n]
    odd = ((x + y) % 2 == 1)[..., None]
    return np.where(odd, [0.9, 0.8, 0.3], [0.2, 0.5, 0.9]).astype(np.float32)


def _scene(res=16, n_small_tris=4, glossy=False, clear=False, world_map=False, bumped=False,
           textured=False):
    tris = quad((0, 0, 0), (4, 0, 0), (0, 4, 0))                     # floor
    tris += quad((0, 4, 1.5), (4, 0, 0), (0, 0, 1.5))                 # back wall
    tris += quad((2.5, 0, 2.0), (0, 0.5, 0), (0.5, 0, 0))             # emissive quad, facing down
    tris += quad((-1.5, 1.0, 0.6), (0.5, 0, 0), (0, 0.3, 0.3))        # tilted mirror
    tris += _box((1.0, -1.0, 0.41), 0.4)                              # glass block
    rng = np.random.default_rng(3)
    for _ in range(n_small_tris):
        c = rng.uniform([-3, -3, 1.5], [3, 3, 2.5])
        tris.append([c, c + [0.05, 0, 0], c + [0, 0.05, -0.01]])
    top = (Lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.3) if glossy or bumped
           else Lobe(DIFFUSE, (0.3, 0.3, 0.2)))
    floor = (Lobe(DIFFUSE, (0.8, 0.7, 0.6)),)
    nm = bump = None
    if bumped:
        # GENERIC materials with a Normal Map (the floor, under a glossy
        # layer) and a Bump (the wall).
        from core.scene import normals as SN
        floor += (Lobe(GLOSSY, (0.5, 0.5, 0.5), roughness=0.2, weight=0.5),)
        nm = SN.NormalInput(SN.NORMAL_MAP, 0, strength=0.8)
        bump = SN.NormalInput(SN.BUMP, 1, distance=0.15)
    wall = (Lobe(DIFFUSE, (0.5, 0.2, 0.2), weight=0.6), top)
    if textured:
        # Image Textures into a Base Color: the Lambert floor's (sampled as
        # Lambert) and a Principled-like wall's diffuse base under a
        # dielectric layer and its metallic F82 lobe (GENERIC).
        tx = 2 if bumped else 0
        floor = (Lobe(DIFFUSE, (0.8, 0.7, 0.6), color_texture=tx),) + floor[1:]
        wall = (Lobe(GLOSSY, (1.0, 1.0, 1.0), weight=0.7, roughness=0.3, fresnel="DIELECTRIC",
                     fresnel_ior=1.5),
                Lobe(DIFFUSE, (0.7, 0.6, 0.5), weight=0.7, layer_ior=1.5, layer_f0=0.04,
                     layer_roughness=0.3, color_texture=tx),
                Lobe(GLOSSY, (0.9, 0.7, 0.6), weight=0.3, roughness=0.35, fresnel="F82",
                     color_texture=tx))
    mats = [Material("floor", floor, normal=nm),
            Material("wall", wall, normal=bump),
            Material("emit", emission=(3.0, 2.0, 1.0)),
            Material("mirror", (Lobe(TRANSPARENT, (0.9, 0.9, 0.9)) if clear
                                else Lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.0),)),
            Material("glass", (Lobe(GLASS, (1.0, 1.0, 1.0), roughness=0.0, ior=1.5),))]
    tri_mat = [0, 0, 1, 1, 2, 2, 3, 3] + [4] * 12 + [2] * n_small_tris
    lights = every_light_kind(Light("tiny", "POINT", (5, 5, 5), translate(2, 2, 1.0)))
    cam = Camera(kind="PERSP", matrix_world=translate(0.3, -0.2, 7.0), lens=30.0,
                 sensor_width=36.0, resolution=(res, res), clip_start=0.01, clip_end=100.0)
    kw = {}
    if bumped or textured:
        # uv = (x, y) / 2 on the floor and (x, z) / 2 elsewhere: the maps tile.
        P = np.asarray(tris, np.float64)
        kw = dict(tri_uv=(0.5 * P[:, :, [0, 2]]).astype(np.float32),
                  textures=(list(_bumps()) if bumped else []) + ([_checker()] if textured else []))
        kw["tri_uv"][:2] = 0.5 * P[:2, :, :2]
    sc = make_scene(tris, mats, lights, cam, tri_mat=tri_mat, world_color=(0.1, 0.2, 0.3), **kw)
    if world_map:
        # An HDRI (a gradient sky and three bright texels), turned.
        from core.scene.textures import EnvironmentMap
        from test_environment import rotation, spiky_image
        sc.world_map = EnvironmentMap(spiky_image(), strength=np.full(3, 0.8),
                                      to_texture=rotation((0.2, 0.1, 1.0), 0.9))
    return sc


def _tracer(integrator, **kw):
    st = RenderSettings(integrator=integrator, max_passes=1, camera_samples=4,
                        photons_per_pass=200, seed=1)
    return Renderer(_scene(**kw), st, log=lambda _m: None).path_tracer


@pytest.mark.parametrize("integrator", ["PATH", "COMBINED"])
@pytest.mark.parametrize("n_small_tris,world_map,bumped,textured", [
    (4, False, False, False), (20, False, False, False), (4, True, False, False),
    (4, True, True, False), (4, False, False, True), (4, True, True, True)],
    ids=["4", "20", "hdri", "hdri-bumped", "textured", "hdri-bumped-textured"])
def test_compiled_paths_equal_numpy(integrator, n_small_tris, world_map, bumped, textured):
    """hdri: the world is an environment map (its light sample and its
    density in direct_kernel and pdf_kernel).
    bumped: a normal-mapped glossy floor and a bump-mapped glossy wall
    (their perturbed normals at the kernels' hits, and Cycles' valid
    specular normal and bump shadowing in the compiled radiance-mode
    sample, evaluation and densities).
    textured: Image Textures into the floor's Lambert colour and a
    Principled-like wall's base colour (each hit's own colour row: the
    Lambert weight, GENERIC sampling, evaluation and lobe selection, and
    COMBINED's reverse densities)."""
    pt = _tracer(integrator, n_small_tris=n_small_tris, world_map=world_map, bumped=bumped,
                 textured=textured)
    assert (pt.lights.environment is not None) == world_map
    assert bool(np.any(pt.mtab.bump_correction)) == bumped
    assert bool(np.any(pt.mtab.tex >= 0)) == textured
    cls = build_fast_materials(pt.mtab).cls
    assert MIRROR in cls and SMOOTH_GLASS in cls
    # COMBINED: photon merging owns the paths seen through a delta vertex (its partition).
    assert getattr(pt.vc, "merging", False) == (integrator == "COMBINED")
    pt.compiled = False
    L_n = pt(np.random.default_rng(4))
    pt.compiled = True
    assert pt.kernels() is not None
    L_c = pt(np.random.default_rng(4))
    assert (L_n.max(axis=1) > 0).mean() > 0.9
    np.testing.assert_allclose(L_c, L_n, rtol=1e-9, atol=1e-9 * float(L_n.max()))


def test_hit_colors_equal_lobe_colors():
    """materials.hit_colors.hit_colors_kernel (a textured hit's colour row,
    through path_kernels.with_hit_colors) against
    numpy's materials.lobe_colors at accel.hit_uv, table._selection_probs,
    its cumsum and last used slot, and the Lambert sample weight, on 5,000
    random hits of the textured floor (Lambert) and the Principled-like wall
    (GENERIC; a grey and an unassociated-alpha texture on its two lobes):
    equal to 1e-15 relative (the same products; numpy's luminance dot and
    lobe sum may round the last bit differently)."""
    import dataclasses

    from core.accel import hit_uv
    from core.integrators import path_kernels as PKp
    from core.materials import lobe_colors
    from core.materials.hit_colors import build_color_inputs
    from core.materials.table import _selection_probs
    from core.scene.textures import UnassociatedImage
    pt = _tracer("PATH", textured=True)
    mtab = pt.mtab
    grey = np.linspace(0.1, 0.9, 12, dtype=np.float32).reshape(3, 4)
    rgba = np.random.default_rng(2).random((4, 5, 4)).astype(np.float32)
    tex = np.array(mtab.tex)
    wall = 1
    j = np.nonzero(tex[wall] >= 0)[0]
    tex[wall, j[0]], tex[wall, j[-1]] = len(mtab.textures), len(mtab.textures) + 1
    mtab = dataclasses.replace(mtab, tex=tex, textures=list(mtab.textures)
                               + [grey, rgba.view(UnassociatedImage)])
    fm = build_fast_materials(mtab)
    M = PKp.build_path_materials(mtab, fm)
    X = build_color_inputs(mtab, pt.scene.tri_uv, lambert=M.cls == PKp.LAMBERT)
    rng = np.random.default_rng(5)
    K = 5000
    prim = rng.integers(0, 4, K).astype(np.int64)            # floor and wall triangles
    u, v = rng.random(K), rng.random(K)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    mat = np.asarray(pt.scene.tri_mat, np.int64)[prim]
    Mk, rows = PKp.with_hit_colors(M, X, prim, u, v, mat)
    colors = lobe_colors(mtab, mat, hit_uv(pt.scene.tri_uv, prim, u, v))
    p = _selection_probs(mtab, mat, colors, "all")
    L = p.shape[1]
    assert np.array_equal(rows, M.col.shape[0] + np.arange(K))
    np.testing.assert_allclose(Mk.sel_colors[rows], colors, rtol=1e-15, atol=0)
    np.testing.assert_allclose(Mk.sel_p[rows], p, rtol=1e-15, atol=1e-16)
    np.testing.assert_allclose(Mk.sel_cdf[rows], np.cumsum(p, axis=1), rtol=1e-15, atol=1e-16)
    np.testing.assert_array_equal(Mk.sel_last[rows], L - 1 - np.argmax(p[:, ::-1] > 0, axis=1))
    lam = M.cls[mat] == PKp.LAMBERT
    assert lam.any() and (~lam).any()
    np.testing.assert_allclose(Mk.col[rows][lam], colors[lam].sum(axis=1), rtol=1e-15)
    assert np.all(Mk.col[rows][~lam] == 0)
    np.testing.assert_array_equal(Mk.sel_p[:M.col.shape[0]], M.sel_p)   # the materials' rows


@pytest.mark.parametrize("tangents,strength,directx", [(False, 0.8, False), (True, 1.0, True),
                                                       (True, 1.7, False)])
def test_compiled_normal_map_equals_perturb(tangents, strength, directx):
    """normal_kernels.normal_map (the kernels' Normal Map hits) against
    normals.perturb (accel.surface_point's) on 20,000 random hits of the
    normal-mapped floor and of the other triangles: with the fallback
    tangent along dP/du, with per-corner MikkTSpace tangents (one triangle
    without: its fallback), strengths 0.8, 1 and 1.7, the DirectX
    convention.  The same normals to 1e-12; the other materials' rows
    untouched."""
    import dataclasses

    from core.scene import normals as SN
    from core.scene.normal_kernels import normal_map
    sc = _scene(bumped=True)
    mats = list(sc.materials)
    mats[0] = dataclasses.replace(mats[0], normal=SN.NormalInput(SN.NORMAL_MAP, 0,
                                                                 strength=strength,
                                                                 directx=directx))
    kw = {}
    if tangents:
        rng = np.random.default_rng(4)
        tt = np.zeros((sc.tri_p.shape[0], 3, 4), np.float32)
        tt[:, :, :3] = rng.normal(size=(sc.tri_p.shape[0], 3, 3))
        tt[:, :, 3] = np.where(rng.random((sc.tri_p.shape[0], 1)) < 0.5, -1.0, 1.0)
        tt[1, :, 3] = 0.0                         # the floor's second triangle: no tangent
        kw["tri_tangent"] = tt
    sc = make_scene(sc.tri_p, mats, sc.lights, sc.camera, tri_mat=sc.tri_mat, tri_uv=sc.tri_uv,
                    textures=sc.textures)
    # The spec is attached to the scene's own tri_n (core.scene.normals.attach).
    sc = dataclasses.replace(sc, tri_n=sc.tri_n.copy(), **kw)
    spec = SN.attached(sc.tri_n)
    rng = np.random.default_rng(7)
    K = 20_000
    prim = np.where(rng.random(K) < 0.7, rng.integers(0, 2, K),
                    rng.integers(0, sc.tri_p.shape[0], K)).astype(np.int64)
    u, v = rng.random(K), rng.random(K)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    from core.accel import surface_point
    _, _, ns_ref, _ = surface_point(sc.tri_p, sc.tri_n, sc.tri_uv, prim, u, v)
    plain = make_scene(sc.tri_p, [dataclasses.replace(m, normal=None) for m in mats], sc.lights,
                       sc.camera, tri_mat=sc.tri_mat, tri_uv=sc.tri_uv)
    _, _, ns, _ = surface_point(plain.tri_p, plain.tri_n, plain.tri_uv, prim, u, v)
    ns = np.ascontiguousarray(ns)
    before = ns.copy()
    rows = np.nonzero(np.asarray(sc.tri_mat)[prim] == 0)[0]
    tt = spec.tri_tangent if spec.tri_tangent is not None else np.zeros((0, 3, 4), np.float32)
    normal_map(spec.tri_p, spec.tri_n, spec.tri_uv, tt, prim, u, v, rows, ns,
               np.ascontiguousarray(sc.textures[0]), False, float(strength), directx)
    assert rows.size > 10_000
    assert np.abs(ns[rows] - before[rows]).max() > 0.1       # the map tilts them
    np.testing.assert_allclose(ns[rows], ns_ref[rows], rtol=0, atol=1e-12)
    others = np.setdiff1d(np.arange(K), rows)
    np.testing.assert_array_equal(ns[others], before[others])


@pytest.mark.parametrize("world_map", [False, True], ids=["world", "hdri"])
def test_compiled_light_pdf_equals_pdf_direct(world_map):
    pt = _tracer("PATH", n_small_tris=20, world_map=world_map)
    table = pt.lights
    rng = np.random.default_rng(2)
    K = 20_000
    p = np.column_stack([rng.uniform(-2, 2, K), rng.uniform(-2, 2, K), rng.uniform(0, 1, K)])
    n = np.tile([0.0, 0.0, 1.0], (K, 1))
    smp = Lt.sample_direct(table, p, rng.random((K, 3)), n=n)
    ok = smp["weight"].max(axis=1) > 0
    wi, dist, light = smp["wi"][ok], smp["dist"][ok], smp["light"][ok]
    ref = Lt.pdf_direct(table, p[ok], wi, light, dist, n=n[ok])
    got = pt.pdf_light(p[ok], wi, light, dist, n[ok])
    assert set(table.kind[light].tolist()) >= {Lt.AREA, Lt.POINT, Lt.SPOT, Lt.SUN, Lt.MESH,
                                               Lt.WORLD}
    assert np.mean(ref > 0) > 0.9
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=0)


@pytest.mark.parametrize("scope", ["kernels", "numpy vertices"])
@pytest.mark.parametrize("integrator", ["PATH", "COMBINED"])
def test_compiled_bsdf_of_glossy_vertices_equals_numpy(integrator, scope, monkeypatch):
    """A wall of a Lambert and a rough GGX lobe (the GENERIC class) beside
    the Lambert, mirror and glass materials.  ``kernels``: the vertex kernels
    sample, evaluate and weigh it with the compiled BSDF in radiance mode
    (``compiled.sample_pair``, ``eval_pair``, ``_pdf_nd_one``; COMBINED's
    reverse densities too).  ``numpy vertices`` (``GENERIC_SCOPE`` off,
    round 24's path): numpy vertices whose sample_bsdf, eval_bsdf and
    pdf_bsdf of the GENERIC rows run compiled (core.materials.compiled
    "Radiance mode over arrays").  Both give numpy's image to the same
    tolerance (the same formulas and operation order, eval_pair's libm pow /
    acos against numpy's, tests/test_compiled_sample.py)."""
    from core.integrators import path_kernels as PK
    monkeypatch.setattr(PK, "GENERIC_SCOPE", scope == "kernels")
    pt = _tracer(integrator, glossy=True)
    assert (pt.kernels() is not None) == (scope == "kernels")
    pt.compiled = False
    L_n = pt(np.random.default_rng(5))
    pt.compiled = True
    L_c = pt(np.random.default_rng(5))
    assert (L_n.max(axis=1) > 0).mean() > 0.9
    from core.materials.compiled import radiance_rows
    assert radiance_rows(pt.mtab, build_fast_materials(pt.mtab)).sum() == 1     # the wall
    np.testing.assert_allclose(L_c, L_n, rtol=1e-9, atol=1e-9 * float(L_n.max()))


def test_scenes_outside_the_kernels_use_numpy():
    # A Transparent lobe: its crossings are no MIS vertex, which only the
    # numpy continuation tells (PathTracer._trace).
    assert _tracer("PATH", clear=True).kernels() is None


@pytest.mark.parametrize("integrator", ["PATH", "COMBINED"])
def test_two_threads_give_the_same_image_as_one(integrator, monkeypatch):
    """A pass of 64x64 pixels x 4 paths is cut into two blocks
    (``PathTracer.blocks``), each traced with its own child stream: two
    threads taking them give one thread's image bit for bit."""
    from core.sppm import photons
    pt = _tracer(integrator, res=64, glossy=True)
    assert pt.blocks() == 2
    images = []
    for threads in (1, 2):
        monkeypatch.setattr(photons, "THREADS", threads)
        images.append(pt(np.random.default_rng(6)))
    assert (images[0].max(axis=1) > 0).mean() > 0.9
    np.testing.assert_array_equal(images[0], images[1])


def test_combined_light_side_samples_glossy_materials_compiled(monkeypatch):
    """COMBINED's light paths scatter off the glossy wall (GENERIC) in the
    bounce kernel (``compiled.sample_pair``, importance mode) and take their
    MIS factors from ``compiled.scatter_pdfs``; with
    ``materials.fast.COMPILED_SAMPLING`` off both are numpy's
    (``_generic_bounce``, ``pdf_bsdf``).  The same random numbers give the
    same splats within rtol 1e-9 of the largest pixel (the formulas of
    tests/test_compiled_sample.py, equal to rounding)."""
    from core.materials import fast
    sums = {}
    for on in (False, True):
        monkeypatch.setattr(fast, "COMPILED_SAMPLING", on)
        st = RenderSettings(integrator="COMBINED", max_passes=1, camera_samples=4,
                            photons_per_pass=20_000, seed=1)
        r = Renderer(_scene(glossy=True), st, log=lambda _m: None)
        assert r.combined_lt.tracer.fmat.any_compiled == on
        sums[on] = r.combined_lt.trace_pass(20_000, np.random.default_rng(7), lambda: None)
    assert (sums[False].max(axis=1) > 0).mean() > 0.5
    np.testing.assert_allclose(sums[True], sums[False], rtol=1e-9,
                               atol=1e-9 * float(sums[False].max()))



def test_compiled_sampling_without_its_sample_columns_is_refused(monkeypatch):
    """The bounce kernel writes its GENERIC samples into GenericHits' out,
    wgt and state: handed the 1-row placeholders instead (what Combined's
    light side first passed), it raises rather than write past them."""
    from core.sppm import photon_kernels as PK
    real = PK.generic_hits
    monkeypatch.setattr(PK, "generic_hits", lambda cap, compiled: real(cap, False))
    st = RenderSettings(integrator="COMBINED", max_passes=1, camera_samples=4,
                        photons_per_pass=2000, seed=1)
    r = Renderer(_scene(glossy=True), st, log=lambda _m: None)
    with pytest.raises(ValueError, match="sample columns"):
        r.combined_lt.trace_pass(2000, np.random.default_rng(7), lambda: None)


def test_sobol1_table_is_the_direction_number_loop():
    """sequence_kernels._sobol1_reversed (four table reads) equals Sobol'
    dimension 1 by its direction numbers (v ^= v >> 1 from 2^31, XOR over
    the index's set bits), bit-reversed, on 100,000 random 32-bit indices
    and the single bits."""
    from core.integrators.sequence_kernels import _reverse32, _sobol1_reversed

    def loop(i):
        v, r = 0x80000000, 0
        while i:
            if i & 1:
                r ^= v
            i >>= 1
            v ^= v >> 1
        return r
    idx = [int(x) for x in np.random.default_rng(3).integers(0, 2**32, 100_000)]
    idx += [1 << j for j in range(32)] + [0, 2**32 - 1]
    assert all(_sobol1_reversed(i) == _reverse32(loop(i)) for i in idx)


@pytest.mark.parametrize("first_block", [0, 1, 5])
def test_a_pixels_samples_form_nets_across_passes(first_block):
    """sequence_kernels.sobol_pairs: for every pixel and pair of dimensions,
    the 2^m samples of an aligned block (samples first .. first + 2^m - 1,
    first a multiple of 2^m: passes of 4 samples, 16, 64 ...) form a
    (0, m, 2)-net: every elementary interval of area 2^-m (2^a x 2^(m-a)
    cells) holds exactly one point, m = 1..7.  A pass's 4 samples alone, as
    the stratification of one pass before round 27, make the m = 2 nets."""
    from core.integrators.sequence_kernels import sobol_pairs
    B, pairs = 40, 4
    pix = np.arange(B, dtype=np.int64) * 37 + 3
    for m in range(1, 8):
        n = 2 ** m
        out = np.full((n, B, 2 * pairs), np.nan)
        sobol_pairs(11, pix, first_block * n, n, pairs, out)
        assert np.all((out >= 0.0) & (out < 1.0))
        for a in range(m + 1):
            cx = np.floor(out[..., 0::2] * 2 ** a).astype(np.int64)
            cy = np.floor(out[..., 1::2] * 2 ** (m - a)).astype(np.int64)
            cells = np.sort(cx * 2 ** (m - a) + cy, axis=0)          # (n, B, pairs)
            np.testing.assert_array_equal(cells, np.arange(n)[:, None, None]
                                          * np.ones((1, B, pairs), np.int64))


def test_sequence_points_are_uniform_and_independent():
    """Over 200 pixels x 4096 samples each coordinate is uniform (chi-square
    on 64 bins, p > 1e-3), pairs of dimensions and pixels are uncorrelated
    (|r| < 4.5 / sqrt(N)), and the same (seed, pixel, sample) gives the same
    point whichever block computes it (the passes' sequence is resumable)."""
    from core.integrators.sequence_kernels import sobol_pairs
    from stats_helpers import chi2_sf
    B, n = 200, 4096
    out = np.empty((n, B, 8))
    sobol_pairs(3, np.arange(B, dtype=np.int64), 0, n, 4, out)
    flat = out.reshape(-1, 8)
    N = flat.shape[0]
    for d in range(8):
        h = np.bincount(np.floor(flat[:, d] * 64).astype(np.int64), minlength=64)
        stat = float(((h - N / 64) ** 2 / (N / 64)).sum())
        assert chi2_sf(stat, 63) > 1e-3, (d, stat)
    lim = 4.5 / np.sqrt(N)
    for d0, d1 in ((0, 2), (0, 4), (1, 5), (2, 6), (3, 7), (0, 1)):
        assert abs(np.corrcoef(flat[:, d0], flat[:, d1])[0, 1]) < lim
    r = np.corrcoef(out[:, :, 0].T)[np.triu_indices(B, 1)]
    assert np.abs(r).max() < 4.5 * 4 / np.sqrt(n)       # 19,900 pairs of pixels
    part = np.empty((8, 3, 8))
    sobol_pairs(3, np.array([5, 17, 199], np.int64), 1000, 8, 4, part)
    np.testing.assert_array_equal(part, out[1000:1008][:, [5, 17, 199]])


def test_seen_kernel_equals_emitted_along_rays():
    """lights.seen_kernels.seen_kernel (the camera paths' analytic emitters, per ray)
    equals the numpy emitted_along_rays on 200,000 random rays of the three
    visibility codes, against a rectangle, a disc, a sphere, a soft point
    light's disc, a spot and a sun (two of them hidden from one kind of ray),
    half the rays escaping: the same emitter for every ray, the radiance
    and distance to 1e-12.  Every emitter is found by some rays."""
    from core.lights import direct_kernels as DK
    from core.lights import seen as Seen
    from core.lights.seen_kernels import seen_kernel
    from test_path_tracer import _many_lights_scene
    table = Lt.build_light_table(_many_lights_scene(4))
    table.visible_glossy[2] = False
    table.visible_transmission[4] = False
    rng = np.random.default_rng(5)
    K = 200_000
    o = rng.uniform([-3, -3, 0.2], [3, 3, 3.0], (K, 3))
    d = rng.normal(size=(K, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_max = np.where(rng.random(K) < 0.5, np.inf, rng.uniform(0.5, 5.0, K))
    vis = rng.integers(0, 3, K).astype(np.int8)
    Le, row, t = np.empty((K, 3)), np.empty(K, np.int64), np.empty(K)
    idx = np.arange(K)
    seen_kernel(DK.build_direct_lights(table), Seen.visibility_flags(table), vis, o, d,
                     t_max, idx, Le, row, t)
    for code, name in enumerate(Seen.VISIBILITY):
        s = np.nonzero(vis == code)[0]
        L_ref, row_ref, t_ref = Lt.emitted_along_rays(table, o[s], d[s], t_max[s], name,
                                                      return_hit=True)
        np.testing.assert_array_equal(row[s], row_ref)
        np.testing.assert_allclose(Le[s], L_ref, rtol=1e-12, atol=0)
        np.testing.assert_allclose(t[s], t_ref, rtol=1e-12, atol=0)
    emitters = np.nonzero((table.kind != Lt.MESH) & (table.kind != Lt.WORLD))[0]
    assert set(emitters) <= set(np.unique(row))
