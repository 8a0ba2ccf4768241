"""The camera and direct-light stages' blocks shared by two threads, and the
photon pass's compiled pixel loops, against their one-thread / numpy results.

What is asserted (all bit for bit: each pixel's result depends on that
pixel alone, and the uniforms are the same draws of the same stream):
- ``stream_at(rng, n)`` draws what rng draws after n draws, and leaves rng
  where it was.
- The blocked camera pass (``CameraPass._trace_blocked``: blocks taken in turn
  by two threads, each drawing its delta choices at 4P + 4 x the hits before
  it) equals the numpy reference, the glass cube's delta chains included,
  and leaves the stream where the reference does; a cancel raised in either
  thread reaches the caller (no block waits forever) and the next pass is
  unchanged; with the pool's workers busy the stage's thread does every
  block and returns without waiting for them.
- The direct light in blocks taken by two threads equals the same blocks
  in one thread and leaves the stream at 3K draws; handed out as shared
  blocks (``NextEventEstimation.shared``, taken by one thread or by three
  at once) it adds the same sums and moves the stream as far.
- ``core.sppm.pass_kernels``: the active mask and radii, Phi x beta and the
  zeroed M equal numpy's, serial and split over the numba threads.
"""
from __future__ import annotations

import numpy as np
import pytest

from core.lights import nee as NEE
from core.render import Renderer
from core.settings import RenderSettings
from core.sppm import camera_kernels as CK
from core.sppm import hashgrid as Hg
from core.sppm import pass_kernels as PK
from core.sppm import photons as Ph
from core.sppm import visible_points as VP
from core.warmup import warmup_scene

VP_FIELDS = ("valid", "front", "p", "ng", "ns", "wo", "mat", "colors", "beta", "depth",
             "const", "albedo", "through_delta")


@pytest.fixture(scope="module")
def stages():
    """The warm-up room (mirror, glass cube: delta chains; every light kind) at 40x40."""
    r = Renderer(warmup_scene(40, ("POINT", "AREA", "SPOT", "SUN")),
                 RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=100, seed=1),
                 log=lambda _m: None)
    return r.camera_pass, r.direct_light


def test_stream_at_draws_the_stream_ahead():
    rng = np.random.default_rng(4)
    want = np.random.default_rng(4).random(40)
    assert np.array_equal(VP.stream_at(rng, 13).random(27), want[13:])
    assert np.array_equal(rng.random(40), want)         # rng was not moved


def _camera(cam, rng, **kw):
    vp, L = cam(rng, **kw)
    return {f: getattr(vp, f).copy() for f in VP_FIELDS}, L.copy(), vp.first.escape.copy()


def test_camera_blocks_in_two_threads_equal_numpy(stages, monkeypatch):
    cam, _ = stages
    monkeypatch.setattr(VP, "CAMERA_BLOCK", 150)          # 11 blocks, the last one partial
    assert Ph.THREADS == 2
    out = []
    for compiled in (False, True):
        cam.compiled = compiled
        rng = np.random.default_rng(11)
        out.append(_camera(cam, rng) + (rng.random(4),))
    cam.compiled = True
    (vn, Ln, en, rn), (vc, Lc, ec, rc) = out
    assert vn["through_delta"].any() and vn["valid"].mean() > 0.5
    for f in VP_FIELDS:
        if f == "beta":       # the luminance dot product (test_compiled_stages: 1e-15)
            np.testing.assert_allclose(vc[f], vn[f], rtol=1e-15, atol=0)
        else:
            assert np.array_equal(vc[f], vn[f]), f
    assert np.array_equal(Lc, Ln) and np.array_equal(ec, en) and np.array_equal(rc, rn)


class _Stop(Exception):
    pass


@pytest.mark.parametrize("when", [1, 4, 9])
def test_camera_blocks_cancel_reaches_the_caller(stages, monkeypatch, when):
    """check_stop raising at its when-th call (either thread) ends the pass
    with that exception; the next pass is the uncancelled one bit for bit."""
    cam, _ = stages
    monkeypatch.setattr(VP, "CAMERA_BLOCK", 150)
    want = _camera(cam, np.random.default_rng(11))
    calls = []

    def stop():
        calls.append(1)
        if len(calls) == when:
            raise _Stop
    with pytest.raises(_Stop):
        cam(np.random.default_rng(11), stop)
    got = _camera(cam, np.random.default_rng(11))
    for f in VP_FIELDS:
        assert np.array_equal(got[0][f], want[0][f]), f
    assert np.array_equal(got[1], want[1])


def test_camera_blocks_with_the_pool_busy(stages, monkeypatch):
    """With both of the pool's workers busy (photons traced ahead), the stage's
    own thread does every block and returns without waiting for a worker:
    the pool's call, not started, is dropped (in_two_threads)."""
    import threading
    cam, _ = stages
    monkeypatch.setattr(VP, "CAMERA_BLOCK", 150)
    want = _camera(cam, np.random.default_rng(11))
    release = threading.Event()
    safety = threading.Timer(60.0, release.set)        # never hang the suite
    safety.start()
    busy = [Ph._pool().submit(release.wait) for _ in range(2)]
    try:
        got = _camera(cam, np.random.default_rng(11))
        assert not release.is_set()                     # returned while the pool was busy
    finally:
        release.set()
        safety.cancel()
        for f in busy:
            f.result()
    for f in VP_FIELDS:
        assert np.array_equal(got[0][f], want[0][f]), f
    assert np.array_equal(got[1], want[1])


def test_direct_blocks_in_two_threads_equal_one_thread(stages, monkeypatch):
    cam, nee = stages
    vp, _ = cam(np.random.default_rng(11))
    K = int(vp.valid.sum())
    monkeypatch.setattr(NEE, "DIRECT_BLOCK", 300)          # 5+ blocks
    monkeypatch.setattr(CK, "SPLIT_MIN", 1000)
    assert K > 1200
    out = []
    for threads in (1, 2):
        monkeypatch.setattr(Ph, "THREADS", threads)
        rng = np.random.default_rng(12)
        L = nee(vp, rng)
        out.append((L, rng.random(3)))
    (L1, r1), (L2, r2) = out
    assert np.array_equal(L1, L2) and np.array_equal(r1, r2)
    ref = np.random.default_rng(12)
    ref.random((K, 3))
    assert np.array_equal(r2, ref.random(3))                # 3K draws
    assert np.count_nonzero(L2.max(axis=1) > 0) > 0.3 * K


@pytest.mark.parametrize("takers", [1, 3])
def test_direct_shared_blocks_equal_the_call(stages, monkeypatch, takers):
    import threading
    cam, nee = stages
    vp, L0 = cam(np.random.default_rng(11))
    K = int(vp.valid.sum())
    monkeypatch.setattr(CK, "SPLIT_MIN", 1000)
    assert K > 1200
    rng = np.random.default_rng(12)
    want = nee(vp, rng, add_to=L0.copy())
    after = rng.random(3)
    rng = np.random.default_rng(12)
    got = L0.copy()
    job = nee.shared(vp, rng, got, parts=8)
    assert job is not None
    assert np.array_equal(rng.random(3), after)             # moved past the 3K draws at once
    threads = [threading.Thread(target=job.take) for _ in range(takers - 1)]
    for t in threads:
        t.start()
    job.take()
    for t in threads:
        t.join()
    assert np.array_equal(got, want)
    assert np.count_nonzero(got.max(axis=1) > L0.max(axis=1)) > 0.3 * K
    # not shared: another bit generator, or fewer points than SPLIT_MIN
    assert nee.shared(vp, np.random.Generator(np.random.MT19937(1)), L0.copy()) is None
    monkeypatch.setattr(CK, "SPLIT_MIN", K + 1)
    assert nee.shared(vp, np.random.default_rng(12), L0.copy()) is None


def test_shared_blocks_each_taken_once_and_stopped():
    import threading
    seen, lock = [], threading.Lock()

    def block(a):
        with lock:
            seen.append(a)
    job = VP.SharedBlocks(1000, 7, block)
    threads = [threading.Thread(target=job.take) for _ in range(3)]
    for t in threads:
        t.start()
    job.take()
    for t in threads:
        t.join()
    assert sorted(seen) == list(range(0, 1000, 7))
    job = VP.SharedBlocks(1000, 7, lambda a: seen.append(a) or job.stop())
    seen.clear()
    job.take()
    job.take()
    assert seen == [0]                                      # none starts after stop()


@pytest.mark.parametrize("min_vps", [10**9, 1])
def test_pass_kernels_equal_numpy(monkeypatch, min_vps):
    monkeypatch.setattr(Hg, "PARALLEL_MIN_VPS", min_vps)   # serial / numba threads
    rng = np.random.default_rng(3)
    P = 5003
    valid = rng.random(P) < 0.8
    R2 = rng.uniform(1e-8, 1e-2, P) * (rng.random(P) < 0.9)
    active, R, n = PK.active_radii(valid, R2)
    want = valid & (R2 > 0)
    assert np.array_equal(active, want) and n == int(want.sum())
    assert np.array_equal(R, np.sqrt(R2))
    Phi = rng.random((P, 3)) * 1e3
    beta = rng.random((P, 3)).astype(np.float32)
    want = Phi * beta
    PK.scale_by_beta(Phi, beta)
    assert np.array_equal(Phi, want)
    M = PK.zeros(P)
    assert M.shape == (P,) and M.dtype == np.float64 and not M.any()
