"""Glossy chains: photon mapping's camera paths go on through materials
without a diffuse lobe (core.sppm.visible_points, pbrt-v4's SPPM rule),
their direct light by two strategies weighed by MIS (core.sppm.glossy_mis).

A metal floor (GGX, its only lobe) under a Lambert slab that it reflects,
lit by a point light between them, an area light, an emissive quad and a
constant world; the camera looks down at the floor.  At a glossy point one
light sample and the emission the continuing ray meets are weighed by the
power heuristic; the visible point is the first vertex with a diffuse lobe
(here the slab's underside).

What is asserted, and where each tolerance comes from:
- Photon Mapping's image mean equals Path Tracing's (core.integrators.path_tracer,
  checked against Cycles in tests/test_cycles_agreement.py) within 4 standard
  errors of the two means, from the seeds' spread (PHOTON, 4 seeds of 24
  passes at 24x24: sd 1.4 % of the mean, measured 0.96 standard errors
  apart; PATH sd 0.6 %).  Adding the emission the continuing rays meet at
  full weight beside the light samples reads +39 % (measured).
- An area light reflected by a polished metal (roughness 0.1) alone: the
  seeds' spread is 1/9 of the visible point's on the metal
  (glossy_chains off: its light samples alone, measured sd 0.030 against
  0.27 on a mean of 1.33, 4 seeds of 16 passes); asserted below 1/5, and
  the mean Path Tracing's within 4 standard errors (measured 0.25 apart).
- Through a Transparent BSDF pane (no vertex: the chain keeps its glossy
  point's densities through a straight crossing, as next-event
  estimation's shadow rays pass the pane): Photon Mapping's mean is Path
  Tracing's within 4 standard errors (measured 0.5270 and 0.5256, sd
  0.0079 and 0.0048 over 4 seeds of 16 passes, 0.3 apart); clearing the
  densities at the crossing reads +24 %.
- A point light's caustic on a metal (light -> mirror -> metal floor ->
  camera: analytic_scenes.mirror_caustic with a GGX floor): a glossy
  point's chain cannot hit the light, so the plan leaves glossy chains out
  (core.plan.casts_small_caustics) and the floor's visible points gather
  the caustic.  Photon Mapping's mean equals Combined's (whose light tracing
  reaches the floor through the mirror) within 4 standard errors (measured
  3.812 and 3.817, sd 0.020 and 0.018 over 4 and 2 seeds of 24 passes);
  with the chains forced the mean is 2.34, below the closed form of the
  direct light and the caustic's first bounce alone (2.93).
- The numpy and the compiled camera passes find the same glossy points and
  add the same light: tests/test_compiled_stages.py ("metal"); the glossy
  points' light samples by Path Tracing's kernels equal numpy's to 1e-6 of
  the largest (measured 2.6e-8: the points' float32 normals).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.materials import eval_bsdf, lobe_colors
from core.render import Renderer
from core.scene.model import DIFFUSE, GLOSSY, TRANSPARENT, Light, Lobe, Material, make_scene
from core.settings import RenderSettings
from core.sppm.glossy_mis import GlossyMIS, glossy_rows

from analytic_scenes import look_down_ortho, mirror_caustic, quad, translate

def metal_scene(res=24, lights=True, slab=True, world=(0.1, 0.15, 0.2), roughness=0.3,
                area=False):
    """The metal floor (GGX of that roughness) and (``slab``) the slab over
    its middle; with ``lights`` the point light under the slab, an area light
    and an emissive quad above; ``area``: the area light alone."""
    tris = quad((0, 0, 0), (3, 0, 0), (0, 3, 0))
    tri_mat = [0, 0]
    if slab:
        tris += quad((0, 0, 1.2), (0.6, 0, 0), (0, 3, 0))
        tri_mat += [1, 1]
    mats = [Material("metal", (Lobe(GLOSSY, (0.9, 0.85, 0.8), roughness=roughness),)),
            Material("slab", (Lobe(DIFFUSE, (0.7, 0.6, 0.5)),)),
            Material("emit", emission=(4.0, 3.0, 2.0))]
    # The area light alone: over the view, its reflection in it.
    lt = [Light("area", "AREA", (40.0, 40.0, 40.0), translate(-0.8, 0.5, 2.0), size=1.0)] if area else []
    if lights:
        tris += quad((1.5, 0.8, 2.0), (0.3, 0, 0), (0, -0.3, 0))
        tri_mat += [2, 2]
        lt = [Light("pt", "POINT", (60.0, 60.0, 60.0), translate(1.2, 0.3, 0.7)),
              Light("area", "AREA", (40.0, 40.0, 40.0), translate(-1.6, 0.5, 2.0), size=1.0)]
    return make_scene(tris, mats, lt, look_down_ortho(4.0, 3.0, res), tri_mat=tri_mat,
                      world_color=world)


def _means(scene_fn, seeds, passes, force=(), chains=True, **kw):
    out = []
    for seed in seeds:
        r = Renderer(scene_fn(), RenderSettings(max_passes=passes, photons_per_pass=20000,
                                                seed=seed, **kw), log=lambda _m: None,
                     force_stages=force)
        for _ in range(passes):
            res = r.step()
        out.append(float(np.asarray(res.image, np.float64)[..., :3].mean()))
        if kw.get("integrator") == "PHOTON" and kw.get("glossy_chains", True) and chains:
            assert "glossy chains" in r.plan.lines()[0]
            assert r.camera_pass.glossy_count > 100
    return np.array(out)


def test_photon_mapping_through_glossy_renders_path_tracings_mean():
    photon = _means(metal_scene, range(4), 24, integrator="PHOTON")
    path = _means(metal_scene, range(2), 24, integrator="PATH")
    se = np.hypot(photon.std(ddof=1) / 2.0, path.std(ddof=1) / np.sqrt(2))
    assert photon.std(ddof=1) < 0.05 * photon.mean()          # the noise the tolerance assumes
    assert abs(photon.mean() - path.mean()) < 4 * max(se, 1e-3 * path.mean()), (photon, path)


def test_a_light_reflected_by_a_polished_metal():
    def polished():
        return metal_scene(lights=False, slab=False, roughness=0.1, area=True)
    glossy = _means(polished, range(4), 16, integrator="PHOTON")
    nee = _means(polished, range(4), 16, integrator="PHOTON", glossy_chains=False)
    path = _means(polished, range(2), 16, integrator="PATH")
    assert glossy.std(ddof=1) < 0.2 * nee.std(ddof=1), (glossy, nee)
    se = np.hypot(glossy.std(ddof=1) / 2.0, path.std(ddof=1) / np.sqrt(2))
    assert abs(glossy.mean() - path.mean()) < 4 * max(se, 1e-3 * path.mean()), (glossy, path)


def test_a_light_through_a_transparent_pane():
    def pane():
        # The metal floor, a Transparent BSDF pane between it and the area
        # light, a constant world: the camera rays cross the pane, and so do
        # the glossy points' shadow rays and their continuing rays.
        tris = quad((0, 0, 0), (3, 0, 0), (0, 3, 0)) + quad((-0.8, 0.5, 1.0), (0.9, 0, 0),
                                                              (0, 0.9, 0))
        mats = [Material("metal", (Lobe(GLOSSY, (0.9, 0.85, 0.8), roughness=0.2),)),
                Material("pane", (Lobe(TRANSPARENT, (0.5, 0.6, 0.7)),))]
        lt = [Light("area", "AREA", (40.0, 40.0, 40.0), translate(-0.8, 0.5, 2.0), size=1.0)]
        return make_scene(tris, mats, lt, look_down_ortho(4.0, 3.0, 24), tri_mat=[0, 0, 1, 1],
                          world_color=(0.1, 0.15, 0.2))
    glossy = _means(pane, range(4), 16, integrator="PHOTON")
    path = _means(pane, range(2), 16, integrator="PATH")
    se = np.hypot(glossy.std(ddof=1) / 2.0, path.std(ddof=1) / np.sqrt(2))
    assert abs(glossy.mean() - path.mean()) < 4 * max(se, 1e-3 * path.mean()), (glossy, path)


def _metal_caustic():
    """A point light under a mirror over a GGX floor (roughness 0.3)."""
    sc, _radiance, _half = mirror_caustic(res=24)
    mats = [Material("metal", (Lobe(GLOSSY, (0.9, 0.85, 0.8), roughness=0.3),))] + sc.materials[1:]
    return dataclasses.replace(sc, materials=mats)


def _metal_caustic_bound():
    """The floor's mean radiance from the light and its image in the mirror,
    each reflected once (mirror_caustic's geometry, the floor's f): a lower
    bound of the image mean (the floor and mirror's interreflections add)."""
    sc = _metal_caustic()
    mt = Renderer(sc, RenderSettings(photons_per_pass=100), log=lambda _m: None).mtab
    c = (np.arange(24) + 0.5) / 24 * 2.0 - 1.0           # pixel centres, scale 2
    x, y = (a.ravel() for a in np.meshgrid(c, c))
    K, I = x.size, 100.0 / (4 * np.pi)
    n = np.tile([0.0, 0.0, 1.0], (K, 1))
    col = lobe_colors(mt, np.zeros(K, np.int64), np.zeros((K, 2)))
    total = np.zeros((K, 3))
    # the light at z = 1, and its image at z = 3 seen through the 1 m mirror at z = 2
    for z, seen, rho in ((1.0, np.ones(K, bool), 1.0),
                         (3.0, (np.abs(x) < 1.5) & (np.abs(y) < 1.5), 0.9)):
        v = np.stack([-x, -y, np.full(K, z)], axis=1)
        d2 = (v * v).sum(axis=1)
        wi = v / np.sqrt(d2)[:, None]
        f = eval_bsdf(mt, np.zeros(K, np.int64), col, n, n, n, wi)
        total += np.where(seen[:, None], rho * f * I * wi[:, 2:3] / d2[:, None], 0.0)
    return float(total.mean())


def test_a_point_lights_caustic_on_a_metal_keeps_its_visible_points():
    r = Renderer(_metal_caustic(), RenderSettings(integrator="PHOTON"), log=lambda _m: None)
    assert not r.plan.glossy_chains
    assert any(stage == "glossy chains" for stage, _why in r.plan.left_out)
    photon = _means(_metal_caustic, range(4), 24, chains=False, integrator="PHOTON")
    combined = _means(_metal_caustic, range(2), 24, integrator="COMBINED")
    se = np.hypot(photon.std(ddof=1) / 2.0, combined.std(ddof=1) / np.sqrt(2))
    assert abs(photon.mean() - combined.mean()) < 4 * max(se, 1e-3 * combined.mean()), (
        photon, combined)
    # Forced, the chains lose the caustic: below the once-reflected bound.
    bound = _metal_caustic_bound()
    forced = _means(_metal_caustic, range(2), 24, force=("glossy chains",), integrator="PHOTON")
    assert photon.mean() > bound > 1.1 * forced.mean(), (photon, bound, forced)


def test_glossy_light_samples_compiled_equal_numpy():
    # Path Tracing's kernels (GlossyMIS._direct_compiled) against the numpy
    # light samples on the metal floor's points: the same light to rounding
    # (measured 2.6e-8 of the largest: the points' float32 normals).
    r = Renderer(metal_scene(res=48), RenderSettings(integrator="PHOTON", glossy_chains=False,
                                                     photons_per_pass=1000, seed=1),
                 log=lambda _m: None)
    mis = GlossyMIS(r.light_table, r.mtab, r.scene.tri_p.shape[0])
    vp, _ = r.camera_pass(np.random.default_rng(3))
    q = np.nonzero(vp.valid & (vp.mat == 0))[0]
    kern = mis._kernels()
    assert q.size > 500 and kern and kern[3][0]
    u = np.random.default_rng(5).random((q.size, 3))
    g = glossy_rows(vp, q)
    a = mis._direct_compiled(g, u, r.direct_light, kern)
    b = mis._direct_numpy(g, u, r.direct_light)
    assert np.count_nonzero(b.max(axis=1) > 0) > 0.5 * q.size
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6 * np.abs(b).max())
