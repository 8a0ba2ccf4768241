"""The compiled photon path (core.sppm.photon_kernels, core.materials.fast)
against the numpy reference (tests/oracle_photons.py).

Three levels:
1. closures: ``materials.fast.sample_fast`` and ``bsdf.sample_bsdf`` fed the
   same uniforms give the same direction and weight (round-off only);
2. emission: ``photon_kernels.sample_photons_fast`` and
   ``lights.sample_photons`` fed the same generator give the same photons;
3. whole tracer: ``PhotonTracer.trace`` and the numpy tracer
   ``oracle_photons.trace_numpy`` (independent random streams) deposit the
   same power per surface group and per bounce, on a Cornell box and on a scene with a glass cube, a mirror, a
   rough GGX wall and an Oren-Nayar wall (those two take the generic fallback
   inside the fast path), on a spot + sun + world scene (numpy emission,
   compiled bounces), and frequency photons get the same predicted radii;
   and the result does not depend on the number of tracing threads (bits).

Tolerances of level 3: each path traces B = 16 independent batches; every
statistic is a per-batch mean, so its standard error is std_b / sqrt(B) from
the batches themselves (no independence assumption between the deposits of
one photon).  Differences are asserted below 4.5 sigma (two-sided odds 7e-6
per statistic, < 1e-3 over the 78 statistics; the seeds are fixed, so the
test is deterministic), and the compared statistics must have relative
standard errors small enough (measured, stated per test) that a bias of a few
per cent fails.  Measured: max |z| 2.9 over the 78 statistics.
"""
import numpy as np
import pytest

from analytic_scenes import quad, translate
from core import materials as B
from core import lights as Lt
from core.materials import fast as FM
from core.sppm import photon_kernels as PK
from core.render import Renderer
from core.scene.model import (DIFFUSE, GLASS, GLOSSY, Camera, Light, Lobe, Material,
                        make_scene)
from core.settings import RenderSettings
from oracle_photons import sample_fast_batch, trace_numpy

LUM = np.array([0.2126, 0.7152, 0.0722])


# ----------------------------------------------------------------- scenes
def _camera():
    M = np.array([[1, 0, 0, 0], [0, 0, -1, -1.9], [0, 1, 0, 0.5], [0, 0, 0, 1]], float)
    return Camera(kind="PERSP", matrix_world=M, lens=35.0, sensor_width=36.0,
                  resolution=(16, 16), clip_start=0.01, clip_end=100.0)


def _box(add, walls):
    add(quad((0, 0, 0), (0.5, 0, 0), (0, 0.5, 0)), walls[0])        # floor +z
    add(quad((0, 0, 1), (0, 0.5, 0), (0.5, 0, 0)), walls[1])        # ceiling -z
    add(quad((0, 0.5, 0.5), (0.5, 0, 0), (0, 0, 0.5)), walls[2])    # back -y
    add(quad((-0.5, 0, 0.5), (0, 0, 0.5), (0, 0.5, 0)), walls[3])   # left +x
    add(quad((0.5, 0, 0.5), (0, 0.5, 0), (0, 0, 0.5)), walls[4])    # right -x


def cornell():
    tris, mats = [], []

    def add(q, m):
        tris.extend(q)
        mats.extend([m] * len(q))
    _box(add, (0, 0, 0, 1, 2))
    for (x, y), s, hgt in (((-0.2, 0.15), 0.15, 0.6), ((0.2, -0.15), 0.15, 0.3)):
        add(quad((x, y, hgt), (s, 0, 0), (0, s, 0)), 0)
        add(quad((x, y - s, hgt / 2), (s, 0, 0), (0, 0, -hgt / 2)), 0)
        add(quad((x, y + s, hgt / 2), (-s, 0, 0), (0, 0, -hgt / 2)), 0)
        add(quad((x - s, y, hgt / 2), (0, s, 0), (0, 0, -hgt / 2)), 0)
        add(quad((x + s, y, hgt / 2), (0, -s, 0), (0, 0, -hgt / 2)), 0)
    materials = [Material("white", (Lobe(DIFFUSE, (0.8, 0.8, 0.8)),)),
                 Material("red", (Lobe(DIFFUSE, (0.8, 0.1, 0.1)),)),
                 Material("green", (Lobe(DIFFUSE, (0.1, 0.8, 0.1)),))]
    light = Light("ceiling", "AREA", (40.0, 40.0, 40.0), translate(0, 0, 0.999),
                  shape="SQUARE", size=0.3)
    return make_scene(tris, materials, [light], _camera(), tri_mat=mats)


CUBE_C, CUBE_H = np.array([0.15, -0.1, 0.16]), 0.15


def glass_mirror():
    """Box with a glass cube, a mirror, a GGX back wall, an Oren-Nayar left wall;
    a disc area light and a soft-falloff point light."""
    tris, mats = [], []

    def add(q, m):
        tris.extend(q)
        mats.extend([m] * len(q))
    _box(add, (0, 0, 3, 4, 1))
    c, h = CUBE_C, CUBE_H
    ex, ey, ez = np.array([h, 0, 0]), np.array([0, h, 0]), np.array([0, 0, h])
    for cen, a, b in ((c + ez, ex, ey), (c - ez, ey, ex), (c + ex, ey, ez), (c - ex, ez, ey),
                      (c + ey, ez, ex), (c - ey, ex, ez)):
        add(quad(cen, a, b), 2)
    # Mirror leaning against the left wall, facing +x and up.
    add(quad((-0.35, 0.1, 0.35), (0, 0.2, 0), (0.1, 0, -0.2)), 5)
    materials = [Material("white", (Lobe(DIFFUSE, (0.8, 0.8, 0.8)),)),
                 Material("green", (Lobe(DIFFUSE, (0.1, 0.8, 0.1)),)),
                 Material("glass", (Lobe(GLASS, (1.0, 1.0, 1.0), ior=1.5),)),
                 Material("ggx", (Lobe(GLOSSY, (0.7, 0.7, 0.7), roughness=0.4),)),
                 Material("oren", (Lobe(DIFFUSE, (0.8, 0.2, 0.2), roughness=0.6),)),
                 Material("mirror", (Lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.0),))]
    lights = [Light("disc", "AREA", (30.0, 30.0, 30.0), translate(0, 0, 0.999), shape="DISK",
                    size=0.3),
              Light("bulb", "POINT", (20.0, 20.0, 20.0), translate(-0.2, 0.2, 0.8), radius=0.05)]
    return make_scene(tris, materials, lights, _camera(), tri_mat=mats)


# ------------------------------------------------------- 1. closures
@pytest.mark.parametrize("lobe, cls", [
    (Lobe(DIFFUSE, (0.6, 0.3, 0.9)), FM.LAMBERT),
    (Lobe(GLOSSY, (0.9, 0.8, 0.7), roughness=0.0), FM.MIRROR),
    (Lobe(GLASS, (1.0, 0.9, 0.8), ior=1.45), FM.SMOOTH_GLASS),
])
def test_fast_closure_matches_sample_bsdf(lobe, cls):
    tab = B.build_material_table([Material("m", (lobe,))], [])
    fm = FM.build_fast_materials(tab)
    assert fm.cls[0] == cls
    rng = np.random.default_rng(3)
    K = 20000
    ng = rng.normal(size=(K, 3))
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    ns = ng + 0.15 * rng.normal(size=(K, 3))            # bumped shading normals
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    wo = rng.normal(size=(K, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    u = rng.random((K, 3))
    mat = np.zeros(K, np.int64)
    colors = B.lobe_colors(tab, mat, np.zeros((K, 2)))
    wi_r, w_r, _, dl_r, ok_r = B.sample_bsdf(tab, mat, colors, ns, ng, wo, u,
                                             subset="all", mode="importance")
    wi_f, w_f, dl_f, ok_f = sample_fast_batch(
        np.full(K, cls, np.int64), np.repeat(fm.col, K, axis=0), np.repeat(fm.ior, K),
        ns, ng, wo, u)
    # Same formulas in another operation order: validity flips only on ties.
    assert np.mean(ok_r != ok_f) < 1e-3
    both = ok_r & ok_f
    assert both.sum() > K // 4
    np.testing.assert_allclose(wi_f[both], wi_r[both], atol=1e-9)
    np.testing.assert_allclose(w_f[both], w_r[both], rtol=1e-9, atol=1e-12)
    assert np.array_equal(dl_f[both], dl_r[both])
    assert np.all(w_f[~ok_f] == 0)


def test_material_classes():
    """Textures, GGX, Oren-Nayar and mixtures stay on the generic path; a
    material without lobes absorbs (bsdf.sample_bsdf: no lobe, invalid)."""
    mats = [Material("tex", (Lobe(DIFFUSE, color_texture=0),)),
            Material("ggx", (Lobe(GLOSSY, roughness=0.3),)),
            Material("on", (Lobe(DIFFUSE, roughness=0.5),)),
            Material("mix", (Lobe(DIFFUSE, weight=0.5), Lobe(GLOSSY, weight=0.5))),
            Material("two_lambert", (Lobe(DIFFUSE, (0.2, 0.2, 0.2)),
                                     Lobe(DIFFUSE, (0.4, 0.1, 0.1)))),
            Material("emitter", (), emission=(1.0, 1.0, 1.0))]
    tab = B.build_material_table(mats, [np.ones((2, 2, 3), np.float32)])
    fm = FM.build_fast_materials(tab)
    assert list(fm.cls) == [FM.GENERIC] * 4 + [FM.LAMBERT, FM.ABSORBER]
    np.testing.assert_allclose(fm.col[4], (0.6, 0.3, 0.3))


# ------------------------------------------------------- 2. emission
def _emission_scene(world=None):
    lights = [Light("sq", "AREA", (30.0, 20.0, 10.0), translate(0, 0, 0.9), shape="SQUARE",
                    size=0.3),
              Light("disc", "AREA", (10.0, 10.0, 10.0), translate(0.2, 0, 0.9), shape="DISK",
                    size=0.2),
              Light("softbox", "AREA", (20.0, 20.0, 20.0), translate(-0.2, -0.2, 0.9),
                    shape="SQUARE", size=0.2, spread=np.radians(40.0)),
              Light("soft", "POINT", (20.0, 20.0, 20.0), translate(-0.2, 0.2, 0.5), radius=0.05),
              Light("sphere", "POINT", (5.0, 5.0, 5.0), translate(0.1, 0.1, 0.5), radius=0.05,
                    use_soft_falloff=False),
              Light("tiny", "POINT", (5.0, 5.0, 5.0), translate(0.1, -0.1, 0.5)),
              # spots: hard, soft (its tail beyond the cone), soft and scaled
              # (an elliptic cone: the tail over the whole sphere), sphere model
              Light("hard", "SPOT", (40.0, 30.0, 20.0), translate(0.3, 0.1, 0.6), spot_size=0.8,
                    spot_blend=0.2),
              Light("softspot", "SPOT", (40.0, 40.0, 40.0), translate(-0.1, 0.3, 0.6),
                    radius=0.04, spot_size=1.0, spot_blend=0.0),
              Light("scaled", "SPOT", (30.0, 30.0, 30.0),
                    translate(0.2, 0.3, 0.7) @ np.diag([1.5, 0.7, 1.0, 1.0]), radius=0.03,
                    spot_size=0.6, spot_blend=0.3),
              Light("spotsphere", "SPOT", (20.0, 20.0, 20.0), translate(0.0, 0.0, 0.8),
                    radius=0.05, spot_size=0.9, spot_blend=0.1, use_soft_falloff=False)]
    tris = quad((0, 0, 0), (0.5, 0, 0), (0, 0.5, 0)) + quad((0, 0.4, 0.5), (0.1, 0, 0),
                                                            (0, 0, 0.1))
    mats = [Material("w", (Lobe(DIFFUSE),)),
            Material("e", (Lobe(DIFFUSE),), emission=(3.0, 2.0, 1.0))]
    scene = make_scene(tris, mats, lights, _camera(), tri_mat=[0, 0, 1, 1],
                       world_color=(0.0, 0.0, 0.0) if world is None else world)
    return Lt.build_light_table(scene)


def test_fast_emission_matches_lights(monkeypatch):
    """The compiled emission (photon_kernels.emit_lights) against
    lights.sample_photons' numpy reference (emission.COMPILED_EMISSION off),
    the same uniforms: every kind it covers, spots hard, soft (their tail
    and disc samples), scaled and spheres."""
    from core.lights import emission as Em
    monkeypatch.setattr(Em, "COMPILED_EMISSION", False)
    table = _emission_scene()
    assert PK.fast_emission_ok(table)
    assert set(np.unique(table.kind[table.p_select > 0])) == {Lt.POINT, Lt.SPOT, Lt.AREA,
                                                                Lt.MESH}
    assert np.count_nonzero(table.spot_tail[:, 0] > 0) == 2
    ref = Lt.sample_photons(table, 100_000, np.random.default_rng(11))
    got = PK.sample_photons_fast(table, 100_000, np.random.default_rng(11))
    beyond = table.spot_tail[ref["light"], 0] > 0
    assert np.count_nonzero(beyond & (np.abs(ref["soft_disc"]).sum(axis=1) > 0)) > 1000
    for k in ("o", "d", "power", "falloff_r2", "freq_init", "soft_disc"):
        np.testing.assert_allclose(got[k], ref[k], rtol=1e-12, atol=1e-12, err_msg=k)
    np.testing.assert_array_equal(got["light"], ref["light"])


def test_mixed_emission_matches_numpy(monkeypatch):
    """A table the compiled emission does not cover whole (a constant
    world beside the lights): lights.sample_photons emits the covered rows
    compiled and the world's by environment_kernels.constant_world_photons;
    both equal the numpy reference (COMPILED_EMISSION and
    COMPILED_ENVIRONMENT off) to round-off, the same uniforms."""
    from core.lights import emission as Em
    table = _emission_scene(world=(0.3, 0.2, 0.1))
    assert not PK.fast_emission_ok(table) and np.any(table.kind[table.p_select > 0] == Lt.WORLD)
    got = Lt.sample_photons(table, 100_000, np.random.default_rng(5))
    monkeypatch.setattr(Em, "COMPILED_EMISSION", False)
    monkeypatch.setattr(Em, "COMPILED_ENVIRONMENT", False)
    ref = Lt.sample_photons(table, 100_000, np.random.default_rng(5))
    assert np.count_nonzero(ref["kind"] == Lt.WORLD) > 1000
    for k in ("o", "d", "power", "falloff_r2", "freq_init", "soft_disc"):
        np.testing.assert_allclose(got[k], ref[k], rtol=1e-9, atol=1e-12, err_msg=k)


# ------------------------------------------------------- 3. tracer
N_BATCH, BATCH = 16, 12_500          # 200k photons per path


def _tracer(scene, **kw):
    # frequency_start 1: the occlusion grid built in the set-up, as the pins were made
    kw.setdefault("frequency_start", 1)
    st = RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=BATCH, **kw)
    return Renderer(scene, st, log=lambda s: None).tracer


def _bins(dep):
    """Surface group of each deposit: dominant axis of the oriented normal
    (0..5 = +x -x +y -y +z -z), 6 = floor under the glass cube (caustic)."""
    ng = dep["ng"]
    ax = np.argmax(np.abs(ng), axis=1)
    sgn = ng[np.arange(len(ng)), ax] < 0
    b = 2 * ax + sgn
    p = dep["p"]
    under = ((np.abs(p[:, 0] - CUBE_C[0]) < CUBE_H) & (np.abs(p[:, 1] - CUBE_C[1]) < CUBE_H)
             & (p[:, 2] < 1e-3))
    return np.where(under, 6, b)


def _batch_stats(tracer, fast, seed, n_freq=0, n_bounce=6):
    """(N_BATCH, S) per-photon statistics: power luminance per surface group,
    deposits per bounce, power per bounce; with n_freq also mean predicted
    radius per surface group.  fast: the compiled tracer (False: the numpy
    oracle, oracle_photons.trace_numpy)."""
    trace = tracer.trace if fast else lambda *a: trace_numpy(tracer, *a)
    rows = []
    for b in range(N_BATCH):
        rng = np.random.default_rng([seed, b])
        dep = trace(BATCH, n_freq, rng)
        g = _bins(dep)
        lum = dep["power"] @ LUM
        bo = np.minimum(dep["bounce"], n_bounce)
        row = [np.bincount(g, weights=lum, minlength=7) / BATCH,
               np.bincount(bo, minlength=n_bounce + 1) / BATCH,
               np.bincount(bo, weights=lum, minlength=n_bounce + 1) / BATCH]
        if n_freq:
            r = dep["rpred"]
            cnt = np.bincount(g, minlength=7)
            row.append(np.bincount(g, weights=r, minlength=7) / np.maximum(cnt, 1))
        rows.append(np.concatenate(row))
    return np.array(rows)


def _compare(a, b, cols):
    """Means of a and b (N_BATCH, S) agree within 4.5 sigma on the columns
    cols whose mean is above 1% of the largest among them.  Returns the
    relative standard errors of those columns (the test's resolution)."""
    a, b = a[:, cols], b[:, cols]
    ma, mb = a.mean(0), b.mean(0)
    m = 0.5 * (ma + mb)
    se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
    big = m > 0.01 * m.max()
    assert big.sum() >= 4
    z = np.abs(ma - mb)[big] / se[big]
    assert np.all(z < 4.5), (z, ma[big], mb[big])
    return se[big] / m[big]


POWER, COUNT, BPOWER, RADIUS = (slice(0, 7), slice(7, 14), slice(14, 21), slice(21, 28))


@pytest.mark.parametrize("make", [cornell, glass_mirror])
def test_tracer_fast_matches_numpy(make):
    tr = _tracer(make(), use_frequency=False)
    fast = _batch_stats(tr, True, 1)
    ref = _batch_stats(tr, False, 2)
    rel = np.concatenate([_compare(fast, ref, c) for c in (POWER, COUNT, BPOWER)])
    # Resolution: measured relative SE median 0.5%, max 4% (the small caustic
    # patch); so a 2.5% bias of a typical statistic is a 4.5 sigma failure.
    assert np.median(rel) < 0.008 and rel.max() < 0.05, rel


def spot_sun_world():
    """Box (open front) with a spot inside, lit from outside by a sun and the
    world too: emission falls back to lights.sample_photons (the kernels then
    start from its arrays)."""
    tris, mats = [], []

    def add(q, m):
        tris.extend(q)
        mats.extend([m] * len(q))
    _box(add, (0, 0, 1, 0, 0))
    add(quad((0.0, 0.0, 0.2), (0.1, 0, 0), (0, 0.1, 0)), 2)
    materials = [Material("white", (Lobe(DIFFUSE, (0.8, 0.8, 0.8)),)),
                 Material("mirror", (Lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.0),)),
                 Material("glass", (Lobe(GLASS, (1.0, 1.0, 1.0), ior=1.5),))]
    down = np.array([[1, 0, 0, 0.1], [0, 1, 0, 0.0], [0, 0, 1, 0.9], [0, 0, 0, 1]], float)
    lights = [Light("spot", "SPOT", (50.0, 50.0, 50.0), down, spot_size=1.0, radius=0.02),
              Light("sun", "SUN", (3.0, 3.0, 3.0), np.eye(4), angle=0.05)]
    return make_scene(tris, materials, lights, _camera(), tri_mat=mats,
                      world_color=(0.1, 0.1, 0.1))


@pytest.mark.parametrize("make", [spot_sun_world])
def test_tracer_fallback_emission(make):
    tr = _tracer(make(), use_frequency=False)
    assert not tr.fast_emission
    fast = _batch_stats(tr, True, 5)
    ref = _batch_stats(tr, False, 6)
    rel = np.concatenate([_compare(fast, ref, c) for c in (POWER, COUNT, BPOWER)])
    # Measured relative SE: median 1.8%, max 3.9% (most sun / world photons
    # miss the box), so a 10% bias of a typical statistic is a 4.5 sigma failure.
    assert np.median(rel) < 0.025 and rel.max() < 0.06, rel


def test_frequency_photons_fast_matches_numpy():
    """Frequency photons (all of them): same deposits, same predicted radii."""
    tr = _tracer(glass_mirror(), use_frequency=True)
    assert tr.kappa is not None and tr.occ_grid is not None
    fast = _batch_stats(tr, True, 3, n_freq=BATCH)
    ref = _batch_stats(tr, False, 4, n_freq=BATCH)
    rel = np.concatenate([_compare(fast, ref, c) for c in (POWER, COUNT, BPOWER, RADIUS)])
    # Mean predicted radius per surface group: measured relative SE 0.3-1.3%.
    assert np.median(rel) < 0.008 and rel.max() < 0.05, rel
    assert np.all(np.isfinite(fast[:, RADIUS]))


def test_threads_do_not_change_deposits(monkeypatch):
    """The two halves of a batch use their own child streams, and their deposits
    are concatenated in a fixed order: one or two threads, same bits."""
    from core.sppm import photons
    tr = _tracer(glass_mirror(), use_frequency=True)
    out = []
    for threads in (1, 2):
        monkeypatch.setattr(photons, "THREADS", threads)
        out.append(tr.trace(20_000, 5_000, np.random.default_rng(9)))
    for k in out[0]:
        assert np.array_equal(out[0][k], out[1][k], equal_nan=True), k


def test_pool_never_overwrites_held_deposits():
    """photons.ArrayPool: deposits a caller still holds are not handed out
    again (a second trace leaves the first result's rows as they were); once
    dropped, the next trace of the same size reuses their arrays and gives
    the same bits as fresh arrays."""
    from core.sppm.photons import ArrayPool
    tr = _tracer(cornell())
    d1 = tr.trace(4000, 0, np.random.default_rng(1))
    kept = {k: v.copy() for k, v in d1.items()}
    d2 = tr.trace(4000, 0, np.random.default_rng(2))
    for k in kept:
        np.testing.assert_array_equal(d1[k], kept[k])
    assert not np.shares_memory(d1["p"], d2["p"])
    # ids, not the arrays: a reference held here would keep them in use
    held = {id(d1["p"].base), id(d2["p"].base)}
    del d1, d2
    d3 = tr.trace(4000, 0, np.random.default_rng(1))
    assert id(d3["p"].base) in held
    tr.pool = ArrayPool(max_sets=0)                  # every set new, none kept
    d4 = tr.trace(4000, 0, np.random.default_rng(1))
    for k in kept:
        np.testing.assert_array_equal(d3[k], kept[k])
        np.testing.assert_array_equal(d4[k], kept[k])


def test_pool_evicts_a_full_kind_by_identity():
    """A full kind of photons.ArrayPool makes room by dropping its smallest
    idle set; sets of equal rows must not be compared by value (numpy's ==
    on the arrays raised when frequency photons made batch sizes vary)."""
    from core.sppm.photons import ArrayPool
    pool = ArrayPool(max_sets=2)
    make = lambda n: [np.zeros(n), np.zeros((n, 3))]  # noqa: E731
    for rows in (10, 10, 12):                         # the third evicts one of the two 10s
        a = pool.take("k", rows, make)
        del a
    sizes = sorted(s[0] for s in pool._sets["k"])
    assert sizes == [10, 12]
    b = pool.take("k", 11, make)
    assert len(b[0]) == 12                            # the smallest free set that fits
