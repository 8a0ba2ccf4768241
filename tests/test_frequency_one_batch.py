"""Frequency and classic photons traced in one batch (``PhotonTracer._trace_batch``,
docs/frequency.md "One batch for both kinds of photon").

The frequency photons stay in the first live rows (``_frequency_first``);
one batch and a batch each (``PhotonTracer.one_batch = False``, the rule
before) draw the first bounce's uniforms for the frequency photons alike,
so every frequency photon's first deposit after a scattering (path vertex
1) is the same in both, bit for bit: what the row bookkeeping must keep,
through the generic numpy bounce (GGX and Oren-Nayar walls) that appends
its survivors after the compiled ones.
"""
import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from core.sppm import photon_kernels as PK  # noqa: E402
from core.sppm.photons import PhotonTracer  # noqa: E402
from builds import EARLIER_CPU, for_this_cpu  # noqa: E402
from test_photon_kernels import _tracer, cornell, glass_mirror  # noqa: E402


def _vertex1_frequency_rows(dep):
    """The frequency photons' deposits at path vertex 1, rows sorted by position."""
    k = (dep["bounce"] == 1) & ~np.isnan(dep["rpred"])
    rows = np.concatenate([dep["p"][k], dep["power"][k], dep["spec"][k],
                           dep["rpred"][k][:, None]], axis=1)
    return rows[np.lexsort(rows[:, ::-1].T)]


@pytest.mark.parametrize("make", [glass_mirror, cornell])
def test_first_deposits_equal_a_batch_each(make):
    tr = _tracer(make(), use_frequency=True)
    n, nf = 20_000, 5_000              # two halves of 10,000, 2,500 frequency photons each
    out = {}
    for one in (True, False):
        tr.one_batch = one
        dep = tr.trace(n, nf, np.random.default_rng(17))
        out[one] = dep
    a, b = _vertex1_frequency_rows(out[True]), _vertex1_frequency_rows(out[False])
    assert a.shape[0] > 500                    # ~0.4 such deposits a frequency photon
    np.testing.assert_array_equal(a, b)
    # every pass's photons still deposit alike: frequency deposits per
    # frequency photon within their binomial noise (a batch each draws the
    # later bounces' numbers in another order)
    f = {k: np.count_nonzero(~np.isnan(d["rpred"])) for k, d in out.items()}
    c = {k: np.count_nonzero(np.isnan(d["rpred"])) for k, d in out.items()}
    assert abs(f[True] - f[False]) < 5 * np.sqrt(f[False])
    assert abs(c[True] - c[False]) < 5 * np.sqrt(c[False])


def _all_rows(dep):
    """Every deposit's position, power and path vertex, rows sorted."""
    rows = np.concatenate([dep["p"], dep["ng"], dep["wi"], dep["power"],
                           dep["bounce"][:, None]], axis=1)
    return rows[np.lexsort(rows[:, ::-1].T)]


@pytest.mark.parametrize("make", [glass_mirror, cornell])
@pytest.mark.parametrize("n, nf", [(20_000, 5_000), (5_000, 2_500), (20_000, 20_000)])
def test_the_same_photons_as_without_spectra(make, n, nf):
    """docs/frequency.md "The same photons": a frequency photon is a photon
    plus its spectrum.  Every live row draws the uniforms of its row in the
    batch without frequency photons (PhotonTracer._trace_batch's order), so
    the deposits of n photons are the same, bit for bit, whichever share
    carries a spectrum.  glass_mirror's GGX and Oren-Nayar walls go through
    the generic bounce, whose frequency survivors _frequency_first moves to
    the front (before: 34,199 against 34,222 deposits, other paths)."""
    tr = _tracer(make(), use_frequency=True)
    a = tr.trace(n, nf, np.random.default_rng(17))
    b = tr.trace(n, 0, np.random.default_rng(17))
    assert np.count_nonzero(~np.isnan(a["rpred"])) > nf // 4
    assert np.all(np.isnan(b["rpred"]))
    np.testing.assert_array_equal(_all_rows(a), _all_rows(b))


def _layout(n_ff, n_cf, n_fg, n_cg, Kf):
    """Live state and record after a bounce of rays 0.. whose first Kf are
    frequency photons: fast survivors (n_ff frequency, n_cf classic, in ray
    order) then generic ones (n_fg, n_cg): as bounce_kernel and
    _generic_bounce leave them."""
    rng = np.random.default_rng(n_ff * 1000 + n_cf * 100 + n_fg * 10 + n_cg)
    ray_f = np.sort(rng.choice(Kf, n_ff + n_fg, replace=False))
    ray_c = np.sort(Kf + rng.choice(400, n_cf + n_cg, replace=False))
    fast = np.sort(np.concatenate([rng.permutation(ray_f)[:n_ff], ray_c[:n_cf]]))
    gen = np.sort(np.concatenate([np.setdiff1d(ray_f, fast), ray_c[n_cf:]]))
    src = np.concatenate([fast, gen])
    n = src.size + 1
    live = PK.LiveState(*(np.empty((n, 3), np.float32), np.empty((n, 3), np.float32),
                          np.empty((n, 3)), np.empty((n, 3)), np.empty(n)))
    for arr in live:
        arr[:src.size] = (src * 7 + 1).reshape((-1,) + (1,) * (arr.ndim - 1))
    rec = PK.HitRecord(np.empty(n), np.empty((n, 3)), np.empty(n), np.empty(n, bool),
                       np.zeros(n, np.int64), np.zeros(n, bool))
    rec.nxt_src[:src.size] = src
    rec.nxt_delta[:src.size] = src % 3 == 0
    return live, rec, fast.size, src.size


@pytest.mark.parametrize("counts", [(5, 9, 3, 4), (5, 2, 6, 4), (0, 3, 4, 2), (4, 0, 3, 5),
                                    (4, 6, 0, 2), (3, 4, 5, 0), (0, 0, 0, 3), (6, 0, 0, 0)])
def test_frequency_survivors_lead_the_live_rows(counts):
    Kf = 50
    live, rec, n_fast, n_next = _layout(*counts, Kf)
    before = sorted(zip(rec.nxt_src[:n_next], rec.nxt_delta[:n_next], live.d64[:n_next, 0]))
    kf = PhotonTracer._frequency_first(Kf, n_fast, n_next, live, rec)
    assert kf == counts[0] + counts[2]
    src = rec.nxt_src[:n_next]
    assert np.all(src[:kf] < Kf) and np.all(src[kf:] >= Kf)
    # each row moved whole: live rows, source ray and delta flag together
    for arr in live:
        np.testing.assert_array_equal(arr[:n_next].reshape(n_next, -1)[:, 0], src * 7 + 1)
    assert sorted(zip(src, rec.nxt_delta[:n_next], live.d64[:n_next, 0])) == before


#: tests/test_photon_trace_pins.py's digests of the frequency cases before
#: one batch: ``one_batch = False`` is that tracer, bit for bit.  glass_mirror
#: regenerated for the compiled sampling of its GGX and Oren-Nayar walls
#: (same paths, a few deposit powers 1-2 ulps off; with
#: ``materials.fast.COMPILED_SAMPLING = False``: b5e69c5b84ceafd863fd8dc9d1b4ceb0);
#: both regenerated when the march's end-plane test after a Lipschitz jump
#: began to read the segment's end (occlusion_march; before: cornell
#: 2a8c75fef944182a72a0580655e059cf, glass_mirror f0452f0ee70dfc9ef2bb4acbd8d96c06);
#: both again with compiled.sincos_quarter / sincos_turn (every direction's
#: last bits; before: cornell 5bd23aee6b3b768c2cc3c561fae5f44a, glass_mirror
#: 5fed417aff716dd0b899121ed6d49519); glass_mirror again with the bounce
#: kernel's kept normal of flat triangles (photon_kernels.flat_normals; before:
#: 575b2242994140eeb3e6fd7390dfb680); glass_mirror again when a soft light's
#: photons took their direction from their disc sample at the first hit
#: (round 36; before: b140bbc72ea8f4af6d6b25295de007a5, znver3
#: bb3970b20e344e80c0d34ca9c5d4951d).
A_BATCH_EACH = {EARLIER_CPU: {"cornell": "8b55cff7af7e184318f024a5f7ce8a4d",
                             "glass_mirror": "e5acff37d92b228dc5d317476fdd2d33"},
                # llvmlite's host CPU znver3, the same code (739843f): tests/builds.py
                # glass_mirror: not computed again on znver3 since round 36
                # (tests/test_photon_trace_pins.py PINS_BY_CPU): skipped there
                "znver3": {"cornell": "453f96ddf0e9a4a7a513362766fdc913",
                           "glass_mirror": None}}


@pytest.mark.parametrize("make", [glass_mirror, cornell])
def test_a_batch_each_is_the_tracer_before(make):
    from test_photon_trace_pins import _digest
    tr = _tracer(make(), use_frequency=True)
    tr.one_batch = False
    want = for_this_cpu(A_BATCH_EACH)[make.__name__]
    if want is None:
        pytest.skip(f"{make.__name__}: no digest for this CPU since round 36 (A_BATCH_EACH)")
    dep = tr.trace(20_000, 5_000, np.random.default_rng(17))
    assert _digest(dep[k] for k in sorted(dep)) == want


@pytest.mark.parametrize("make", [glass_mirror, cornell])
@pytest.mark.parametrize("n, nf", [(20_000, 5_000), (20_000, 3), (5_000, 5_000)])
def test_traced_again_are_the_batch_photons_with_their_spectra(make, n, nf):
    """docs/frequency.md "Frequency photons traced again": the batch is traced
    as without frequency photons (the same deposits in the same order, bit for
    bit) and the frequency photons traced again on the uniforms they drew
    there give those deposits the predicted radii and spectra the one batch
    (retrace = 0, the rule before) gives them, bit for bit.  retrace = 1:
    traced again at any share (the default only up to RETRACE_MAX_SHARE)."""
    tr = _tracer(make(), use_frequency=True)
    tr.retrace = 1.0
    a = tr.trace(n, nf, np.random.default_rng(17))
    b = tr.trace(n, 0, np.random.default_rng(17))
    for k in ("p", "ng", "wi", "power", "bounce", "bary"):
        np.testing.assert_array_equal(a[k], b[k])        # the order too
    tr.retrace = 0.0
    c = tr.trace(n, nf, np.random.default_rng(17))
    freq = ~np.isnan(a["rpred"])
    assert np.count_nonzero(freq) == np.count_nonzero(~np.isnan(c["rpred"])) > nf // 4
    rows = lambda d: np.concatenate([d["p"], d["power"], d["bounce"][:, None], d["spec"],  # noqa: E731
                                     d["rpred"][:, None]], axis=1)
    ra, rc = rows(a), rows(c)
    np.testing.assert_array_equal(ra[np.lexsort(ra[:, ::-1].T)], rc[np.lexsort(rc[:, ::-1].T)])
    assert np.all(a["spec"][~freq] == 0) and np.all(np.any(a["spec"][freq] != 0, axis=1))
    assert tr.retrace_mismatches == 0


def test_paths_that_differ_keep_no_spectrum():
    """Should a photon traced again leave its path (here: its uniforms of the
    second bounce perturbed), the batch's deposits stay PPM's, without
    spectra, and the tracer counts it."""
    from core.sppm import photons as Ph
    tr = _tracer(cornell(), use_frequency=True)
    tr.retrace = 1.0
    b = tr.trace(5_000, 0, np.random.default_rng(17))
    orig = Ph._Follow.draw

    def draw(self, u):
        orig(self, u)
        if len(self.u) == 2:
            self.u[-1] = self.u[-1] * 0.5
    Ph._Follow.draw = draw
    try:
        a = tr.trace(5_000, 200, np.random.default_rng(17))
    finally:
        Ph._Follow.draw = orig
    assert tr.retrace_mismatches == 1
    assert np.all(np.isnan(a["rpred"])) and np.all(a["spec"] == 0)
    np.testing.assert_array_equal(a["p"], b["p"])
