"""Amortised frequency photons (docs/method.md "Amortised frequency photons").

Pass k traces photons_per_pass x frequency_fraction x k^-frequency_decay
frequency photons (the first ones of the pass), and with frequency_decay > 0
a pixel that no frequency photon reaches in a pass keeps its last prediction
(update.kept_prediction); frequency_decay = 0 is the previous rule (the same
fraction in every pass, each pass's own prediction).  The convergence of the
held radii under any prediction is tests/test_holds.py's.
"""
import numpy as np
import pytest

from core.render import Renderer
from core.settings import RenderSettings, SettingsError
from core.sppm.state import PixelState
from core.sppm.update import Radii, kept_prediction

from analytic_scenes import point_light_plane


@pytest.mark.parametrize("decay, expected", [
    (0.5, {1: 75_000, 4: 37_500, 9: 0, 16: 18_750, 100: 0, 128: 6_629}),
    (0.0, {1: 75_000, 4: 75_000, 9: 75_000, 100: 75_000}),
    (1.0, {1: 75_000, 4: 18_750, 9: 0, 16: 4_688, 100: 0}),
    (2.0, {1: 75_000, 2: 18_750, 4: 4_688, 9: 0, 16: 293, 100: 0, 128: 5}),
])
@pytest.mark.parametrize("doubling", [True, False])
def test_frequency_photons_per_pass(decay, expected, doubling):
    """The chunks of pass k carry round(300,000 x 0.25 x k^-decay) frequency
    photons, the first ones of the pass (chunks of 131,072); with decay > 0
    only in the passes k = 2^j (PhotonPass.doubling, the default; off: in
    every pass, the schedule before); frequency_start 1 (from pass 1;
    later starts: test_frequency_start_schedule)."""
    scene, _ = point_light_plane(res=8)
    st = RenderSettings(integrator="PHOTON", photons_per_pass=300_000, frequency_decay=decay,
                        frequency_start=1)
    r = Renderer(scene, st, log=lambda s: None)
    assert r.photon_pass.doubling
    r.photon_pass.doubling = doubling
    for k, n_freq in expected.items():
        if not doubling:
            n_freq = int(round(75_000 * float(k) ** -decay))
        r.pass_index = k - 1                    # the renderer is about to trace pass k
        chunks = r.photon_pass.chunks()
        assert [n for n, _ in chunks] == [131_072, 131_072, 37_856]
        assert sum(f for _, f in chunks) == n_freq
        # The frequency photons come first: a chunk has some only if the one before is full.
        assert all(f0 == n0 for (n0, f0), (_, f1) in zip(chunks, chunks[1:]) if f1)


def test_default_schedule():
    """The default schedule (docs/method.md "The frequency schedule and the
    first 10 %"): frequency_decay 2 under the doubling schedule, so pass
    2^j traces 25 % x 4^-j of its photons; with 100,000 photons per pass the
    passes 1, 2, 4, ..., 128 trace 25,000, 6,250, 1,562, 391, 98, 24, 6 and 2,
    none from pass 256 on (round(0.38) = 0), 33,333 in all: 1.33 times pass
    1's, against 81,583 (3.26 times) in the first 256 passes with decay 0.5,
    whose pass 2^j traces 25 % x 2^(-j/2), still 1,562 in pass 256.  Those
    are the passes from frequency_start 1; the default start 2 (docs/method.md
    "Round 19: the rings and the decision") traces the same counts in passes
    2, 4, ..., 256."""
    from core.sppm.photon_pass import frequency_photons
    default = RenderSettings(integrator="PHOTON", photons_per_pass=100_000)
    assert default.frequency_decay == 2.0 and default.frequency_fraction == 0.25
    assert default.frequency_start == 2
    st = default.replace(frequency_start=1)
    n2 = {k: frequency_photons(default, k, doubling=True) for k in range(1, 1025)}
    assert {k: v for k, v in n2.items() if v} == {2: 25_000, 4: 6_250, 8: 1_562, 16: 391,
                                                  32: 98, 64: 24, 128: 6, 256: 2}
    n = {k: frequency_photons(st, k, doubling=True) for k in range(1, 1025)}
    assert {k: v for k, v in n.items() if v} == {1: 25_000, 2: 6_250, 4: 1_562, 8: 391,
                                                 16: 98, 32: 24, 64: 6, 128: 2}
    assert sum(n.values()) == 33_333
    old = st.replace(frequency_decay=0.5)
    n_old = [frequency_photons(old, k, doubling=True) for k in range(1, 1025)]
    assert sum(n_old[:256]) == 81_583 and n_old[255] == 1_562
    # Combined's merging as an MIS strategy (core/render.py) uses the same
    # count in every pass, without the doubling schedule.
    assert [frequency_photons(st, k) for k in (1, 2, 3, 10)] == [25_000, 6_250, 2_778, 250]


def test_frequency_passes_double():
    """The passes with frequency photons under the doubling schedule: 1, 2,
    4, ..., 2^j: 9 of the first 256 passes (the schedule before: 256)."""
    from core.sppm.photon_pass import frequency_pass
    assert [k for k in range(1, 257) if frequency_pass(k)] == [2 ** j for j in range(9)]


def test_decay_is_validated():
    with pytest.raises(SettingsError, match="frequency_decay"):
        RenderSettings(frequency_decay=-0.1).validate()
    with pytest.raises(SettingsError, match="frequency_decay"):
        RenderSettings(frequency_decay=float("nan")).validate()


def _two_passes(decay, compiled, spectrum_alone=True):
    """Three pixels of radius 1 m, 100 photons each per pass with uniform
    sector counts (the verified holds' test accepts): pass 1 predicts
    (10, 10, none) m, pass 2 (none, 0.01, none).  spectrum_alone: the
    uniformity holds and the growth off (the spectrum's prediction alone
    decides a hold: what these passes keep).  Returns (held after pass 1,
    held after pass 2, r_pred_last after pass 2, R2 after pass 2)."""
    st = RenderSettings(frequency_decay=decay)
    radii = Radii(st, None, 1.0, True, None, 1, 3)
    radii.compiled = compiled
    if spectrum_alone:
        radii.hold_uniform, radii.grow = False, 1.0
    state = PixelState.zeros(3, sector_cells=radii.sector_cells)
    state.R2[:] = 1.0
    M, Phi = np.full(3, 100.0), np.ones((3, 3))
    S = np.full((3, radii.sector_cells), 100.0 / radii.sector_cells)
    radii.update(state, M, Phi, np.array([10.0, 10.0, np.inf]), S)
    held1 = state.held.copy()
    radii.update(state, M, Phi, np.array([np.inf, 0.01, np.inf]), S)
    return held1, state.held.copy(), state.r_pred_last.copy(), state.R2.copy()


@pytest.mark.parametrize("compiled", [True, False])
def test_pixel_keeps_its_prediction_without_frequency_photons(compiled):
    """Pixel 0 gets no frequency photon in pass 2: with decay > 0 it keeps
    pass 1's 10 m and stays held (R^2 shrinks at the hold rate: f =
    (N + 0.95 M)/(N + M) with N = 95, M = 100: the spectrum's rate
    HOLD_ALPHA_SPECTRUM, 100 photons over the sector cells are enough for the
    test, and 10 m > R); pixel 1's new small
    prediction replaces the old one (plain PPM step); pixel 2 never had one.
    With decay 0 (the previous rule) pixel 0 is released.  The default rules
    (docs/method.md "X as the default") hold all three by their uniform
    counts whatever the prediction (pixels 0 and 1 grown in pass 1 to
    GROW_MAX R by the 10 m prediction), so the spectrum's part is tested
    with the counts' holds and the growth off."""
    held1, held2, last, R2 = _two_passes(0.5, compiled)
    assert held1.tolist() == [True, True, False]
    assert held2.tolist() == [True, False, False]
    assert last[0] == 10.0 and last[1] == 0.01 and np.isnan(last[2])
    f1 = 0.95                       # pass 1: N = 0, held at the spectrum's rate
    assert R2[0] == pytest.approx(f1 * (95.0 + 95.0) / 195.0, rel=1e-12)
    assert R2[1] == pytest.approx(f1 * (95.0 + 70.0) / 195.0, rel=1e-12)
    held1, held2, last, R2 = _two_passes(0.0, compiled)
    assert held2.tolist() == [False, False, False]
    assert np.isnan(last[0])
    assert R2[0] == pytest.approx(R2[1], rel=1e-12)
    held1, held2, last, R2 = _two_passes(0.5, compiled, spectrum_alone=False)
    assert held1.all() and held2.all()
    assert last[0] == 10.0 and last[1] == 0.01
    # both grown to GROW_MAX^2 R^2 = 4 in pass 1 (N = 100 x 4), both held in pass 2:
    # pixel 0 by its kept 10 m at the spectrum's rate 0.95 (10 m > R = 2 m),
    # pixel 1 by its uniform counts at hold_alpha 0.9 (its 0.01 m is below R)
    assert R2[0] == pytest.approx(4.0 * (400.0 + 95.0) / 500.0, rel=1e-12)
    assert R2[1] == pytest.approx(4.0 * (400.0 + 90.0) / 500.0, rel=1e-12)


def test_kept_prediction():
    r = kept_prediction(np.array([0.2, np.inf, np.inf, np.inf, np.nan]),
                        np.array([0.5, 0.3, np.nan, np.inf, 0.3]))
    assert r[0] == 0.2 and r[1] == 0.3 and np.isnan(r[2]) and np.isinf(r[3]) and np.isnan(r[4])
    # The running minimum: the smaller of the two; NaN and inf are no prediction.
    m = kept_prediction(np.array([0.2, 0.6, np.inf, np.nan, np.inf]),
                        np.array([0.5, 0.3, 0.3, 0.3, np.nan]), minimum=True)
    assert m[:4].tolist() == [0.2, 0.3, 0.3, 0.3] and not np.isfinite(m[4])


@pytest.mark.parametrize("doubling", [True, False])
def test_passes_without_frequency_photons_keep_every_prediction(doubling):
    """A mirror's caustic on a floor (occlusion grid and reach map on), 8
    passes of 20,000 photons.  Doubling schedule: frequency photons and a
    reach map only in passes 1, 2, 4, 8 (the map from the last pass's
    visible points: passes 2, 4, 8); a pass without them leaves every
    pixel's prediction as it was, bit for bit, and holds at the same pixels
    where the photons' counts still agree.  Every pass: 8 and 7."""
    from analytic_scenes import lambert, look_down_ortho, quad, translate
    from core.scene.model import GLOSSY, Light, Lobe, Material, make_scene
    # analytic_scenes.mirror_caustic with a tilted card beside the light: something
    # can occlude (a marched grid, hence the reach map)
    tris = (quad((0, 0, 0), (10, 0, 0), (0, 10, 0)) + quad((0, 0, 2), (0, 0.5, 0), (0.5, 0, 0))
            + quad((0.6, 0, 0.5), (0, 0.3, 0), (0.2, 0, 0.2)))
    mats = [lambert("floor", 0.8), Material("mirror", (Lobe(GLOSSY, (0.9,) * 3, roughness=0.0),))]
    scene = make_scene(tris, mats, [Light("point", "POINT", (100.0,) * 3, translate(0, 0, 1))],
                       look_down_ortho(1.5, 2.0, 16), tri_mat=[0, 0, 1, 1, 0, 0])
    st = RenderSettings(integrator="PHOTON", photons_per_pass=20_000, max_passes=8, seed=3,
                        frequency_start=1)
    r = Renderer(scene, st, log=lambda s: None)
    r.photon_pass.doubling = doubling
    assert r.tracer.uses_reach()
    traced, reach = [], []
    trace, set_reach = r.tracer.trace, r.tracer.set_reach
    r.tracer.trace = lambda n, n_freq, rng: (traced.append((r.pass_index + 1, n_freq)),
                                             trace(n, n_freq, rng))[1]
    r.tracer.set_reach = lambda *a: (reach.append(r.pass_index + 1), set_reach(*a))[1]
    last = []
    for _ in range(8):
        r.step()
        last.append(r.state.r_pred_last.copy())
    with_freq = sorted({k for k, f in traced if f > 0})
    if doubling:
        assert with_freq == [1, 2, 4, 8] and reach == [2, 4, 8]
        for k in (3, 5, 6, 7):                  # 1-based passes without frequency photons
            assert np.array_equal(last[k - 1], last[k - 2], equal_nan=True)
        assert np.isfinite(last[0]).sum() > 50
    else:
        assert with_freq == list(range(1, 9)) and reach == list(range(2, 9))
    # pass 4 brings new spectra: some predictions change
    assert not np.array_equal(last[3], last[2], equal_nan=True)


def test_frequency_start_schedule():
    """frequency_start S (docs/method.md "A late start for the frequency
    photons, round 18"): no frequency photon before pass S, then the
    schedule of S = 1 at k / S: passes S, 2S, 4S, ... under doubling, the
    same counts and total; S = 1 is the schedule of pass k itself (the
    default since round 19: S = 2)."""
    from core.sppm.photon_pass import frequency_photons
    assert RenderSettings().frequency_start == 2
    st = RenderSettings(integrator="PHOTON", photons_per_pass=100_000, frequency_start=1)
    one = {k: frequency_photons(st, k, doubling=True) for k in range(1, 4097)}
    four = {k: frequency_photons(st.replace(frequency_start=4), k, doubling=True)
            for k in range(1, 4097)}
    assert all(four[k] == 0 for k in (1, 2, 3))
    assert {k: v for k, v in four.items() if v} == {4 * k: v for k, v in one.items() if v}
    assert sum(four.values()) == sum(one.values()) == 33_333
    # decay 0 (no doubling, no decay): every pass from S on, the same fraction
    flat = st.replace(frequency_decay=0.0, frequency_start=3)
    assert [frequency_photons(flat, k, doubling=True) for k in (1, 2, 3, 4, 9)] == \
        [0, 0, 25_000, 25_000, 25_000]
    # without doubling (COMBINED's MIS merging): (k / S)^-decay from pass S
    assert [frequency_photons(st.replace(frequency_start=2), k) for k in (1, 2, 4, 6)] == \
        [0, 25_000, 6_250, 2_778]
    for decay in (0.0, 0.5, 2.0):
        s1 = st.replace(frequency_decay=decay)
        for k in range(1, 300):
            f = 0.25 * float(k) ** -decay
            expected = (0 if decay > 0 and k & (k - 1) else int(round(100_000 * f)))
            assert frequency_photons(s1, k, doubling=True) == expected
    with pytest.raises(SettingsError, match="frequency_start"):
        RenderSettings(frequency_start=0).validate()


def _caustic_scene():
    """analytic_scenes.mirror_caustic with a tilted card beside the light:
    something can occlude (a marched grid, hence the reach map)."""
    from analytic_scenes import lambert, look_down_ortho, quad, translate
    from core.scene.model import GLOSSY, Light, Lobe, Material, make_scene
    tris = (quad((0, 0, 0), (10, 0, 0), (0, 10, 0)) + quad((0, 0, 2), (0, 0.5, 0), (0.5, 0, 0))
            + quad((0.6, 0, 0.5), (0, 0.3, 0), (0.2, 0, 0.2)))
    mats = [lambert("floor", 0.8), Material("mirror", (Lobe(GLOSSY, (0.9,) * 3, roughness=0.0),))]
    return make_scene(tris, mats, [Light("point", "POINT", (100.0,) * 3, translate(0, 0, 1))],
                      look_down_ortho(1.5, 2.0, 16), tri_mat=[0, 0, 1, 1, 0, 0])


def _late_render(scene, S, passes=8):
    st = RenderSettings(integrator="PHOTON", photons_per_pass=20_000, max_passes=passes, seed=3,
                        frequency_start=S)
    r = Renderer(scene, st, log=lambda s: None)
    traced, reach = [], []
    trace, set_reach = r.tracer.trace, r.tracer.set_reach
    r.tracer.trace = lambda n, n_freq, rng: (traced.append((r.pass_index + 1, n_freq)),
                                             trace(n, n_freq, rng))[1]
    r.tracer.set_reach = lambda *a: (reach.append(r.pass_index + 1), set_reach(*a))[1]
    return r, traced, reach


def test_late_start_traces_no_frequency_photon_before_pass_s():
    """frequency_start 4 on test_passes_without_frequency_photons_keep_every_
    prediction's caustic: passes 1-3 trace no frequency photon and keep no
    prediction; the occlusion grid is built in pass 3's step (not in the
    set-up), whose photon pass keeps the reach source of pass 4; passes 4
    and 8 trace what passes 1 and 2 trace with S = 1 (5,000 and 1,250), with
    a reach map each.  The passes before S are the same bits whatever S
    (the grid consumes no random number)."""
    scene = _caustic_scene()
    r, traced, reach = _late_render(scene, 4)
    assert r.plan.occlusion_grid and r.occ_grid is None and r.tracer.occlusion == 0
    imgs, last, grid = [], [], []
    for _ in range(8):
        imgs.append(r.step().image.copy())
        last.append(r.state.r_pred_last.copy())
        grid.append(r.occ_grid is not None)
    assert grid == [False, False, True, True, True, True, True, True]
    assert r.tracer.occlusion == 1 and r.tracer.uses_reach()
    per_pass = {}
    for k, f in traced:
        per_pass[k] = per_pass.get(k, 0) + f
    assert {k: f for k, f in per_pass.items() if f} == {4: 5_000, 8: 1_250}
    assert reach == [4, 8]
    assert all(np.isnan(last[k]).all() for k in range(3))
    assert np.isfinite(last[3]).sum() > 50
    r8, _, _ = _late_render(scene, 8, passes=3)
    for k in range(3):
        assert np.array_equal(r8.step().image, imgs[k])
    assert r8.occ_grid is None


def test_late_start_resumes_the_same_bits():
    """A checkpoint of pass 3 (the grid built, pass 4 the first frequency
    pass) resumed by a new renderer: the grid is built on load, the reach
    source rebuilt, the growth of pass 4 capped as without the resume, and
    passes 4-6 are the same bits as the render that went on."""
    scene = _caustic_scene()
    r, _, _ = _late_render(scene, 4, passes=6)
    for _ in range(3):
        r.step()
    d = r.state_dict()
    r2, _, _ = _late_render(scene, 4, passes=6)
    r2.load_state(d)
    assert r2.occ_grid is not None
    for _ in range(3):
        assert np.array_equal(r.step().image, r2.step().image)
