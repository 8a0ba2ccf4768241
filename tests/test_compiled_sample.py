"""The compiled importance sampler of a whole material
(core.materials.compiled.sample_pair, the photon tracer's generic hits)
equals the numpy one (the oracle: core.materials.sample_bsdf, subset 'all',
mode 'importance') sample for sample.

Random rays over every lobe kind of tests/test_compiled_bsdf.py's materials
(Lambert, Oren-Nayar, translucent, GGX glossy / glass / refraction with and
without Multiscatter GGX, iors above and below 1, the Principled BSDF's
layers, delta lobes mixed with non-delta ones) plus delta Principled layers,
smooth glass, delta refraction and a transparent lobe; wo on both sides of
the geometric normal, a quarter grazing (1e-3..1e-7 from its plane).
Same formulas in the same operation order: the validity and delta flags
agree exactly, directions and weights to RTOL (measured: all but a few
samples bit for bit; the rest a few ulps, from eval_pair's libm pow / acos
against numpy's, tests/test_compiled_bsdf.py).
"""
import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from core import materials as B  # noqa: E402
from core.materials import compiled as C  # noqa: E402
from core.materials import fast as FM  # noqa: E402
from core.scene.model import (DIFFUSE, GLASS, GLOSSY, REFRACTION, TRANSPARENT,  # noqa: E402
                              Lobe, Material)
from core.scene.nodes import principled_to_lobes  # noqa: E402
from test_compiled_bsdf import _materials, _pairs  # noqa: E402

RTOL, ATOL = 1e-12, 1e-14


def _table():
    P = lambda **kw: tuple(principled_to_lobes(**kw)[0])  # noqa: E731
    extra = [
        P(),                                              # Blender's default Principled
        P(base_color=(0.8, 0.5, 0.3), metallic=0.6, roughness=0.0),     # delta F82 + dielectric
        (Lobe(GLASS, (1.0, 0.9, 0.8), ior=1.45),),        # smooth glass
        P(base_color=(0.8, 0.5, 0.3), metallic=0.5, roughness=0.0,
          thin_film_thickness=500.0),                     # delta F82 + dielectric under a film
        (Lobe(GLOSSY, (1.0, 1.0, 1.0), fresnel="CONDUCTOR", conductor_n=(0.14, 0.37, 1.44),
              conductor_k=(3.98, 2.38, 1.60)), Lobe(DIFFUSE, (0.5, 0.5, 0.5))),  # delta conductor
        (Lobe(REFRACTION, (0.9, 0.9, 1.0), ior=1.33), Lobe(TRANSPARENT, (0.3, 0.3, 0.3)),
         Lobe(GLOSSY, (0.5, 0.6, 0.7), roughness=0.35)),
    ]
    return B.build_material_table([Material(f"m{i}", lobes=lb)
                                   for i, lb in enumerate(_materials() + extra)], [])


def _rays(t, K, seed):
    """test_compiled_bsdf's random points (a quarter grazing), float64, and uniforms."""
    mat, _, ns, ng, wo, _ = _pairs(t, K, seed)
    f64 = lambda a: np.ascontiguousarray(a, np.float64)  # noqa: E731
    return mat, f64(ns), f64(ng), f64(wo), np.random.default_rng(seed).random((K, 3))


def test_compiled_sample_equals_sample_bsdf():
    t = _table()
    fm = FM.build_fast_materials(t)
    # every material without a fast path is covered (Lambert ones have one,
    # and sample_bsdf's Lambert shortcut ignores f's hemisphere test)
    assert np.array_equal(fm.compiled, fm.cls == FM.GENERIC)
    assert fm.compiled[len(_materials())]           # the default Principled
    K = 12000
    mat, ns, ng, wo, u = _rays(t, K, 5)
    keep = fm.compiled[mat]
    mat, ns, ng, wo, u = mat[keep], ns[keep], ng[keep], wo[keep], u[keep]
    K = mat.size
    colors = B.lobe_colors(t, mat, np.zeros((K, 2)))
    wi_r, w_r, _, dl_r, ok_r = B.sample_bsdf(t, mat, colors, ns, ng, wo, u,
                                             subset="all", mode="importance")
    wi, w, flags = np.empty((K, 3)), np.empty((K, 3)), np.empty(K, np.int8)
    C.sample_batch(fm.cm.lobes, fm.cm.tables, C.selection_table(t), mat, ns, ng, wo, u,
                   False, wi, w, np.empty(K), flags)
    ok, dl = (flags & 1) > 0, (flags & 2) > 0
    assert np.array_equal(ok, ok_r)
    assert np.array_equal(dl, dl_r)
    np.testing.assert_allclose(wi[ok], wi_r[ok], rtol=RTOL, atol=ATOL)
    np.testing.assert_allclose(w, w_r, rtol=RTOL, atol=ATOL)
    # bit for bit but for the few ulps of eval_pair's libm calls, where the
    # direction is (the compiled disk's sine and cosine, compiled.sincos_quarter,
    # are within 1 ulp of numpy's: a share of the directions differ in the last bits)
    same = np.all(wi == wi_r, axis=1)
    assert np.mean(same[ok]) > 0.75
    assert np.mean(np.all(w == w_r, axis=1)[same]) > 0.99
    # coverage: every material samples valid rays, delta and not, both sides
    for m in np.nonzero(fm.compiled)[0]:
        assert np.count_nonzero(ok[mat == m]) > 50, m
    assert 300 < np.count_nonzero(dl) < K // 2
    back = np.einsum("ij,ij->i", ng, wo) < 0
    glass = np.isin(t.kind[mat], (GLASS, REFRACTION)).any(axis=1)
    through = np.einsum("ij,ij->i", ng, wi) * np.einsum("ij,ij->i", ng, wo) < 0
    for side in (back, ~back):
        assert np.count_nonzero(ok & glass & side & through) > 100


def test_compiled_radiance_sample_and_pdf_equal_numpy():
    """The camera paths' radiance-mode calls (compiled.sample_radiance,
    eval_radiance, pdf_radiance) against closures.sample_bsdf / eval_bsdf /
    pdf_bsdf in radiance mode on the same rays: flags exactly, directions,
    weights and densities to RTOL; the rows the kernels do not cover (Lambert,
    mirror, glass, absorber) are numpy's own, bit for bit."""
    t = _table()
    fm = FM.build_fast_materials(t)
    rows = C.radiance_rows(t, fm)
    assert np.array_equal(rows, fm.compiled)
    K = 12000
    mat, ns, ng, wo, u = _rays(t, K, 7)
    colors = B.lobe_colors(t, mat, np.zeros((K, 2)))
    ref = B.sample_bsdf(t, mat, colors, ns, ng, wo, u, subset="all", mode="radiance")
    got = C.sample_radiance(t, fm, rows, mat, colors, ns, ng, wo, u)
    wi_r, w_r, pdf_r, dl_r, ok_r = ref
    wi, w, pdf, dl, ok = got
    assert np.array_equal(ok, ok_r) and np.array_equal(dl, dl_r)
    np.testing.assert_allclose(wi[ok], wi_r[ok], rtol=RTOL, atol=ATOL)
    np.testing.assert_allclose(w, w_r, rtol=RTOL, atol=ATOL)
    np.testing.assert_allclose(pdf, pdf_r, rtol=RTOL, atol=ATOL)
    numpy_rows = ~rows[mat]
    for a, b in zip(got, ref):
        assert np.array_equal(a[numpy_rows], b[numpy_rows])
    # radiance differs from importance where it should: refraction and shading normals
    imp = B.sample_bsdf(t, mat, colors, ns, ng, wo, u, subset="all", mode="importance")
    assert np.count_nonzero(np.any(imp[1] != w_r, axis=1) & rows[mat]) > 1000
    # the light sample's f and density at the sampled directions
    sel = np.nonzero(ok)[0]
    generic = fm.cls == FM.GENERIC
    f_r = B.eval_bsdf(t, mat[sel], colors[sel], ns[sel], ng[sel], wo[sel], wi[sel])
    f = C.eval_radiance(t, generic, mat[sel], colors[sel], ns[sel], ng[sel], wo[sel], wi[sel])
    np.testing.assert_allclose(f, f_r, rtol=RTOL, atol=ATOL)
    p_r = B.pdf_bsdf(t, mat[sel], colors[sel], ns[sel], ng[sel], wo[sel], wi[sel], subset="all")
    p = C.pdf_radiance(t, mat[sel], colors[sel], ns[sel], ng[sel], wo[sel], wi[sel])
    np.testing.assert_allclose(p, p_r, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("textured", [False, True, "bumped"])
def test_tracer_same_deposits_with_and_without_compiled_sampling(monkeypatch, textured):
    """The photon tracer with the compiled generic path (default) and with
    COMPILED_SAMPLING off (numpy sample_bsdf): the same photon paths (order,
    positions, bounces bit for bit) and directions and powers to rounding
    (measured: 118 of 34222 deposits' powers 1-2 ulps off, from Oren-Nayar's
    acos; since the compiled disk's sine and cosine, compiled.sincos_quarter,
    directions 6.4e-15 and powers 1.7e-13 relative at most).  textured: the
    GGX wall and the green Lambert wall textured (a checker): their hits
    sampled compiled with colour rows of their own (PhotonTracer.
    _sample_textured, from round 28; none left to numpy's _sample_numpy)
    among the kernel's in one block, against numpy's lobe_colors and
    sample_bsdf (its Lambert fast path for the green wall).
    "bumped": the GGX and Oren-Nayar walls flagged Normal Map / Bump
    (MaterialTable.bump_correction): sampled by the kernel
    (FastMaterials.sampled) though not ``compiled``, as numpy's importance
    mode samples them: without the normal corrections (the valid specular
    normal, the diffuse lobe's bump shadowing)."""
    from test_photon_kernels import _tracer, glass_mirror
    out = []
    for flag in (False, True):
        monkeypatch.setattr(FM, "COMPILED_SAMPLING", flag)
        sc = glass_mirror()
        if textured is True:
            chk = np.full((2, 2, 3), 0.9, np.float32)
            chk[0, 1] = chk[1, 0] = (0.3, 0.6, 0.2)
            sc.textures = [chk]
            sc.materials[3] = Material("ggx_tex", (Lobe(GLOSSY, (0.7, 0.7, 0.7), roughness=0.4,
                                                        color_texture=0),))
            sc.materials[1] = Material("green_tex", (Lobe(DIFFUSE, (0.1, 0.8, 0.1),
                                                          color_texture=0),))
            P = np.asarray(sc.tri_p, np.float64)
            sc.tri_uv = (0.7 * (P[:, :, 0:2] + P[:, :, 1:3])).astype(np.float32)
        if textured == "bumped":
            # tilted shading normals: the corrections would change the samples
            n = sc.tri_n + 0.3 * np.random.default_rng(5).normal(size=sc.tri_n.shape)
            sc.tri_n = n / np.linalg.norm(n, axis=2, keepdims=True)
        tr = _tracer(sc)
        if textured == "bumped":
            import dataclasses
            tr.mtab = dataclasses.replace(tr.mtab, bump_correction=np.isin(
                np.arange(tr.mtab.kind.shape[0]), (3, 4)))
            tr.fmat = FM.build_fast_materials(tr.mtab)
            assert not flag or np.all(tr.fmat.cm.lobes[3:5, 0, C.F_BUMP] == 1.0)
            assert list(np.nonzero(tr.fmat.sampled)[0]) == [3, 4] * flag
            assert not tr.fmat.any_compiled
        else:
            assert tr.fmat.any_compiled == flag
            assert list(np.nonzero(tr.fmat.compiled)[0]) == ([4] if textured else [3, 4]) * flag
        if textured is True and flag:
            def no_numpy(*a, **k):
                raise AssertionError("a textured hit left to numpy")
            monkeypatch.setattr(tr, "_sample_numpy", no_numpy)
        out.append(tr.trace(20_000, 0, np.random.default_rng(17)))
    a, b = out
    assert a["p"].shape[0] > 20_000
    for k in ("p", "ng", "bounce", "bary"):
        assert np.array_equal(a[k], b[k]), k
    # the directions to rounding (measured 6.4e-15 after a few bounces): the
    # compiled GGX sample's disk point (compiled.sincos_quarter) is within
    # 1 ulp of numpy's
    np.testing.assert_allclose(b["wi"], a["wi"], rtol=0, atol=1e-13)
    # powers: 1.7e-13 relative at most, measured (the GGX weights of those directions)
    np.testing.assert_allclose(b["power"], a["power"], rtol=1e-12, atol=0)
