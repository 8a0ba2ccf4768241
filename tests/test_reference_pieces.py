"""The Cycles reference of ``fppm converge`` in K pieces (tools/converge/references.py).

The floor arithmetic on synthetic images (no Cycles): merging pieces is exact,
two equal halves give the two-halves estimate (A - B)^2 / 4, and the K-piece
variance estimate has the same expectation (the mean's variance sigma^2 / N)
as the two-halves estimate of the same N samples, within the estimates' own
sampling noise.  Then the growing cache file with a fake renderer: resumed,
started from a two-halves file, the seeds of its pieces.
"""
import json
import types

import numpy as np
import pytest

import fppm.tools.converge.references as R
from core.io.exr import read_exr_metadata
from tools import metrics as M

SHAPE = (128, 128, 3)


def _pieces(rng, mu, sigma, ns):
    """Pieces of ns[i] samples: mu + sigma / sqrt(n) z (pixel noise of a sample: sigma)."""
    return [{"samples": n, "pieces": 1, "M2": np.zeros(mu.shape),
             "Combined": mu + sigma / np.sqrt(n) * rng.standard_normal(mu.shape)} for n in ns]


def _merge_all(ps):
    g = None
    for p in ps:
        g = R.merge_pieces(g, p)
    return g


def test_merge_is_the_direct_formula_in_any_order():
    rng = np.random.default_rng(1)
    mu, sigma = rng.uniform(0.2, 2.0, SHAPE), rng.uniform(0.5, 3.0, SHAPE)
    ns = [4096, 4096, 8192, 8192, 1000, 8192]
    ps = _pieces(rng, mu, sigma, ns)
    x = np.stack([p["Combined"] for p in ps])
    w = np.array(ns, float)[:, None, None, None]
    mean = (w * x).sum(0) / w.sum()
    m2 = (w * (x - mean) ** 2).sum(0)
    seq = _merge_all(ps)
    tree = R.merge_pieces(_merge_all(ps[:2]), _merge_all(ps[2:]))
    for g in (seq, tree):
        assert g["samples"] == sum(ns) and g["pieces"] == len(ns)
        np.testing.assert_allclose(g["Combined"], mean, rtol=1e-12)
        np.testing.assert_allclose(g["M2"], m2, rtol=1e-9)
        np.testing.assert_allclose(R.piece_variance(g), m2 / ((len(ns) - 1) * sum(ns)), rtol=1e-9)


def test_two_halves_are_the_two_halves_estimate():
    rng = np.random.default_rng(2)
    a, b = rng.uniform(0, 3, SHAPE), rng.uniform(0, 3, SHAPE)
    g = _merge_all([{"samples": 4096, "pieces": 1, "M2": np.zeros(SHAPE), "Combined": x}
                    for x in (a, b)])
    np.testing.assert_allclose(g["Combined"], 0.5 * (a + b), rtol=1e-14)
    np.testing.assert_allclose(R.piece_variance(g), 0.25 * (a - b) ** 2, rtol=1e-12, atol=1e-15)
    assert R.piece_variance(_merge_all([{"samples": 8, "pieces": 1, "M2": np.zeros(SHAPE),
                                          "Combined": a}])) is None


@pytest.mark.parametrize("ns", [[4096, 4096] + [8192] * 7, [8192] * 8, [20000, 30000, 15536]])
def test_k_piece_floor_has_the_two_halves_expectation(ns):
    """E[var estimate] = sigma^2 / N for K pieces of any sizes, as for two halves
    of N / 2.  Gaussian pieces: a pixel's estimate of K - 1 degrees of freedom
    has relative variance 2 / (K - 1), so the floor (a weighted mean over the
    pixels) has standard error sqrt(2 / (K - 1) sum (w v)^2) / sum w v; the test
    allows 4 of them for each estimate."""
    rng = np.random.default_rng(3)
    N = sum(ns)
    mu, sigma = rng.uniform(0.2, 2.0, SHAPE), rng.uniform(0.5, 3.0, SHAPE)
    wv = sigma ** 2 / N / (mu * mu + M.RELMSE_EPS)
    truth = float(wv.mean())
    se = {k: float(np.sqrt(2.0 / (k - 1) * (wv ** 2).sum()) / wv.sum()) for k in (2, len(ns))}
    # The floor's weights 1 / (r^2 + eps) use the reference itself; its noise
    # (sigma / sqrt(N) <= 0.03 of mu >= 0.2 here) moves them by < 1e-2 of the SE.
    g = _merge_all(_pieces(rng, mu, sigma, ns))
    halves = _merge_all(_pieces(rng, mu, sigma, [N // 2, N - N // 2]))
    fk = M.reference_floor(mu, R.piece_variance(g)) / truth
    f2 = M.reference_floor(mu, R.piece_variance(halves)) / truth
    assert abs(fk - 1.0) < 4 * se[len(ns)], (fk, se)
    assert abs(f2 - 1.0) < 4 * se[2], (f2, se)
    # The K-piece estimate is the sharper one: the floor itself is known better.
    assert se[len(ns)] < se[2] or len(ns) == 2


def _fake_cycles(calls):
    """A renderer of a fixed image plus seed-dependent noise: (layers, seconds)."""
    mu = np.linspace(0.5, 1.5, 8 * 8 * 4).reshape(8, 8, 4)

    def render(bpy, scene, samples, seed, passes=False):
        calls.append((samples, seed))
        z = np.random.default_rng(seed).standard_normal(mu.shape)
        img = (mu + z / np.sqrt(samples)).astype(np.float32)
        return {"Combined": img, "Diffuse Direct": 0.5 * img[..., :3],
                "Diffuse Indirect": 0.25 * img[..., :3]}, 1.0
    return render


def _fake_setup(tmp_path, monkeypatch):
    """references.py with the fake renderer and a cache in tmp_path: (the list of
    (samples, seed) rendered, bpy, scene, the .blend's path)."""
    monkeypatch.setenv("FPPM_CACHE_DIR", str(tmp_path))
    calls = []
    monkeypatch.setattr(R, "cycles_render", _fake_cycles(calls))
    monkeypatch.setattr(R, "cycles_reference_setup", lambda scene: None)
    monkeypatch.setattr(R, "render_size", lambda scene: (8, 8))
    blend = tmp_path / "s.blend"
    blend.write_bytes(b"scene")
    return (calls, types.SimpleNamespace(app=types.SimpleNamespace(version_string="test")),
            types.SimpleNamespace(frame_current=1), blend)


def test_growing_file_resumes_from_halves_and_from_itself(tmp_path, monkeypatch):
    calls, bpy, scene, blend = _fake_setup(tmp_path, monkeypatch)
    log = []
    # A two-halves file of 4 spp made the old way (REF_VERSION 2).
    render = _fake_cycles([])
    a, b = (render(None, None, 2, s)[0]["Combined"].astype(np.float64) for s in R.REF_SEEDS)
    base = {"resolution": [8, 8], "frame": 1, "blender": "test"}
    ks = dict(base, version=R.REF_VERSION, samples=4, seeds=list(R.REF_SEEDS))
    (tmp_path / "references").mkdir()
    R.write_exr(str(tmp_path / "references" / (R.reference_key(b"scene", ks) + ".exr")),
                {"Combined": (0.5 * (a + b)).astype(np.float32),
                 "Variance": (0.25 * (a - b) ** 2)[..., :3].astype(np.float32),
                 "DiffDir": (0.25 * (a + b))[..., :3].astype(np.float32),
                 "DiffInd": (0.125 * (a + b))[..., :3].astype(np.float32)},
                {"fppm:reference": json.dumps(dict(ks, render_seconds=2.0))})
    ref4 = R.make_reference(bpy, scene, str(blend), 4, log.append, lambda *x, **k: None)
    assert calls == [] and ref4["meta"]["samples"] == 4
    # 10 spp: the halves plus pieces of 4 and 2 with the next seeds.
    ref10 = R.make_reference(bpy, scene, str(blend), 10, log.append, lambda *x, **k: None,
                             piece_samples=4)
    assert calls == [(4, R.piece_seed(2)), (2, R.piece_seed(3))]
    meta = json.loads(read_exr_metadata(ref10["path"])["fppm:reference"])
    assert meta["samples"] == 10 and meta["pieces"] == 4
    assert meta["seeds"] == [R.piece_seed(i) for i in range(4)] == list(range(1_000_003, 1_000_007))
    assert meta["piece_samples"] == [2, 2, 4, 2]
    # The file is the direct K-piece estimate of those four renders (float32).
    xs = [render(None, None, n, s)[0]["Combined"].astype(np.float64)[..., :3]
          for n, s in zip(meta["piece_samples"], meta["seeds"])]
    w = np.array(meta["piece_samples"], float)[:, None, None, None]
    mean = (w * np.stack(xs)).sum(0) / 10
    var = (w * (np.stack(xs) - mean) ** 2).sum(0) / (3 * 10)
    for ref in (ref10, R.make_reference(bpy, scene, str(blend), 8, log.append, lambda *x, **k: None)):
        np.testing.assert_allclose(ref["image"], mean, rtol=2e-6)
        np.testing.assert_allclose(ref["var"], var, rtol=2e-5, atol=1e-9)
        np.testing.assert_allclose(ref["diff_indirect"], 0.25 * mean, rtol=2e-6)
    assert len(calls) == 2                       # 8 <= 10 spp: read, not rendered
    # Resumed: 12 spp adds one piece of 2 to the growing file.
    ref12 = R.make_reference(bpy, scene, str(blend), 12, log.append, lambda *x, **k: None,
                             piece_samples=4)
    assert calls[2:] == [(2, R.piece_seed(4))] and ref12["meta"]["pieces"] == 5
    assert ref12["path"] == ref10["path"]


def test_fresh_reference_is_two_halves(tmp_path, monkeypatch):
    calls, bpy, scene, blend = _fake_setup(tmp_path, monkeypatch)
    ref = R.make_reference(bpy, scene, str(blend), 6,
                           lambda s: None, lambda *x, **k: None)
    assert calls == [(3, R.REF_SEEDS[0]), (3, R.REF_SEEDS[1])]
    a, b = (_fake_cycles([])(None, None, 3, s)[0]["Combined"].astype(np.float64)[..., :3]
            for s in R.REF_SEEDS)
    np.testing.assert_allclose(ref["var"], 0.25 * (a - b) ** 2, rtol=2e-5, atol=1e-9)


def test_two_processes_joined_are_one_reference(tmp_path, monkeypatch):
    """Pieces rendered in another process (first_piece: other seeds, another
    file) joined to the growing file: the direct K-piece estimate of all."""
    calls, bpy, scene, blend = _fake_setup(tmp_path, monkeypatch)
    quiet = (lambda s: None, lambda *x, **k: None)
    a = R.make_reference(bpy, scene, str(blend), 6, *quiet, piece_samples=2)
    b = R.make_reference(bpy, scene, str(blend), 8, *quiet, piece_samples=4, first_piece=100)
    assert a["path"] != b["path"]
    assert [s for _, s in calls] == [R.piece_seed(i) for i in (0, 1, 2, 100, 101)]
    meta = R.join_growing(a["path"], b["path"])
    assert meta["samples"] == 14 and meta["pieces"] == 5
    xs = [_fake_cycles([])(None, None, n, s)[0]["Combined"].astype(np.float64)[..., :3]
          for n, s in calls]
    w = np.array([n for n, _ in calls], float)[:, None, None, None]
    mean = (w * np.stack(xs)).sum(0) / 14
    var = (w * (np.stack(xs) - mean) ** 2).sum(0) / (4 * 14)
    ref = R.make_reference(bpy, scene, str(blend), 14, *quiet)
    assert len(calls) == 5                       # read, not rendered
    np.testing.assert_allclose(ref["image"], mean, rtol=2e-6)
    np.testing.assert_allclose(ref["var"], var, rtol=2e-5, atol=1e-9)
    with pytest.raises(ValueError):
        R.join_growing(a["path"], a["path"])


def test_trusted_layer_restricts_every_region(tmp_path):
    # A reference's Trusted layer: load_reference reads it as an (H, W) bool,
    # and trusted_masks makes "all" those pixels and cuts every region to
    # them, so that error_metrics scores only the pixels the reference
    # vouches for (bench/luxcore_reference.py's composed glass sphere).
    from core.io.exr import write_exr
    rng = np.random.default_rng(5)
    H, W = 16, 24
    ref = rng.uniform(0.1, 2.0, (H, W, 3)).astype(np.float32)
    trusted = np.ones((H, W), bool)
    trusted[4:9, 6:15] = False
    path = str(tmp_path / "ref.exr")
    write_exr(path, {"Combined": ref, "Variance": np.full((H, W, 3), 1e-4, np.float32),
                     "Trusted": trusted.astype(np.float32)[..., None]})
    r = R.load_reference(path)
    assert r["trusted"].dtype == bool and (r["trusted"] == trusted).all()
    smooth = rng.random((H, W)) < 0.5
    masks = R.trusted_masks({"smooth": smooth}, r["trusted"])
    assert (masks["all"] == trusted).all() and (masks["smooth"] == (smooth & trusted)).all()
    img = ref.astype(np.float64) * rng.uniform(0.5, 1.5, (H, W, 3))
    img[~trusted] = 1e6                             # what the untrusted pixels read is not scored
    e = M.error_metrics(img, r["image"], masks, with_flip=False)
    w = ((img - r["image"]) ** 2 / (r["image"] ** 2 + M.RELMSE_EPS))
    assert e["relmse_all"] == pytest.approx(w[trusted].mean(), rel=1e-12)
    assert e["relmse_smooth"] == pytest.approx(w[smooth & trusted].mean(), rel=1e-12)
    assert R.trusted_masks({"smooth": smooth}, None) == {"smooth": smooth}
    plain = str(tmp_path / "plain.exr")
    write_exr(plain, {"Combined": ref})
    assert R.load_reference(plain)["trusted"] is None
