"""Arrays kept from one pass to the next (core.kept), the camera pass's
blocked, two-thread Embree calls and emitter look-ups, and the photons traced
ahead of the camera pass (PhotonPass.trace_ahead).

What is asserted, and why the tolerances are zero:
- ``KeptArrays.get`` returns the last call's arrays, cleared to the values
  they were made with, only when nothing else references any of them: a
  caller holding an array, a view of one, or an object holding one gets new
  arrays, and what it holds is left as it was; a new key gives new arrays.
- A camera pass on reused arrays gives the visible points, first hits and
  emission of a fresh camera pass bit for bit (the clear restores every
  value ``VisiblePoints.empty`` starts from), and a result the caller keeps
  is never overwritten by the next pass.  The photon pass's sums, reused,
  give a whole render the same image bit for bit.
- The camera pass with its Embree calls in small blocks
  (visible_points.INTERSECT_BLOCK) and the emitters seen by camera rays in
  small blocks over two threads (SEEN_SPLIT_MIN, SEEN_BLOCK) gives the
  one-call visible points bit for bit: each ray's hit and emission is its own.
- Photons traced ahead, in their own thread while the camera and direct
  light run, give the image of photons traced at the gather bit for bit
  (the same stream drawn in the same order), with the same photon ray count;
  a pass whose traced-ahead photons are not gathered (another stream) traces
  its own and gives the same image too.
- The next pass's chunks queued behind this pass's last one
  (TRACE_NEXT_PASS, PhotonPass.trace_ahead's then=) give every pass's image
  bit for bit, with 1 to 3 chunks ahead, over passes with and without
  frequency photons (those are never started early: their reach map and
  radius cut come from the pass before), through a pass cancelled in its
  gather and run again (a new stream: what was queued is dropped), and
  nothing is queued after the last pass of max_passes nor after run()
  returns.
"""
from __future__ import annotations

import numpy as np

from core.errors import RenderCancelled
from core.kept import KeptArrays
from core.sppm import photon_pass as PP
from core.render import Renderer
from core.settings import RenderSettings
from core.sppm import visible_points as V
from core.warmup import warmup_scene


def _make():
    return [np.zeros((5000, 3)), np.full(5000, -1, np.int32), np.ones(7, bool)]


def test_kept_arrays_reused_only_when_unshared():
    k = KeptArrays()
    a = k.get(_make, 1)
    a[0][:] = 3.0
    a[1][:] = 9
    a[2][:] = False
    ids = [id(x) for x in a]
    del a
    b = k.get(_make, 1)
    assert [id(x) for x in b] == ids and k.reused == 1
    assert not b[0].any() and np.all(b[1] == -1) and b[2].all()
    for hold in (lambda arrs: arrs[1], lambda arrs: arrs[0][10:20], lambda arrs: {"x": arrs[2]}):
        b[0][:] = 5.0
        held = hold(b)
        before = np.array(held["x"] if isinstance(held, dict) else held, copy=True)
        del b
        b = k.get(_make, 1)
        assert k.reused == 1, "an array still referenced was reused"
        after = held["x"] if isinstance(held, dict) else held
        assert np.array_equal(after, before)
        del held, after
    del b
    assert len(k.get(_make, 2)) == 3 and k.reused == 1      # another key: new arrays


def _renderer(res, **kw):
    r = Renderer(warmup_scene(res, ("POINT", "AREA")),
                 RenderSettings(integrator="PHOTON", max_passes=4, seed=1, **kw),
                 log=lambda _m: None)
    r.camera_pass.first_data = True      # the first hits' arrays compared too
    return r


def _assert_same_camera_pass(a, b):
    (vp_a, L_a), (vp_b, L_b) = a, b
    for f in V._VP_ARRAYS:
        assert np.array_equal(getattr(vp_a, f), getattr(vp_b, f)), f
    for f in V._FIRST:
        assert np.array_equal(getattr(vp_a.first, f), getattr(vp_b.first, f)), f
    assert np.array_equal(vp_a.through_delta, vp_b.through_delta)
    assert np.array_equal(L_a, L_b)


def test_reused_camera_pass_equals_fresh():
    cam = _renderer(40).camera_pass
    fresh = _renderer(40).camera_pass(np.random.default_rng(6))
    kept = cam(np.random.default_rng(5))
    kept_copy = {f: getattr(kept[0], f).copy() for f in V._VP_ARRAYS}
    second = cam(np.random.default_rng(6))        # the first result is held: new arrays
    assert cam._kept.reused == 0
    for f, v in kept_copy.items():
        assert np.array_equal(getattr(kept[0], f), v), f
    del kept, second
    reused = cam(np.random.default_rng(6))
    assert cam._kept.reused == 1
    assert reused[0].valid.mean() > 0.5 and np.any(reused[0].first.emit > 0)
    _assert_same_camera_pass(reused, fresh)


def test_reused_photon_sums_give_the_same_image(monkeypatch):
    r = _renderer(24, photons_per_pass=20_000)
    for _ in range(3):
        img = r.step().image
    assert r.photon_pass._kept.reused == 2
    monkeypatch.setattr(KeptArrays, "get", lambda self, make, key=None: list(make()))
    r2 = _renderer(24, photons_per_pass=20_000)
    for _ in range(3):
        img2 = r2.step().image
    assert np.array_equal(img, img2)


def test_blocked_camera_calls_equal_one_call(monkeypatch):
    r = _renderer(64)
    one = r.camera_pass(np.random.default_rng(7))
    monkeypatch.setattr(V, "INTERSECT_BLOCK", 300)
    monkeypatch.setattr(V, "INTERSECT_SPLIT_MIN", 1000)
    monkeypatch.setattr(V, "SEEN_BLOCK", 256)
    monkeypatch.setattr(V, "SEEN_SPLIT_MIN", 1000)
    blocked = r.camera_pass(np.random.default_rng(7))
    assert np.any(one[0].first.emit > 0)
    _assert_same_camera_pass(one, blocked)


def test_photons_traced_ahead_give_the_same_image(monkeypatch):
    def render(passes=3):
        r = _renderer(24, photons_per_pass=20_000)       # 4 chunks, one queued ahead at a time
        r.photon_pass.chunk = 6_000
        return [r.step().image for _ in range(passes)], r.photon_rays
    ahead, rays_ahead = render()
    monkeypatch.setattr(PP, "TRACE_AHEAD", False)
    here, rays_here = render()
    for a, b in zip(ahead, here):
        assert np.array_equal(a, b)
    assert rays_ahead == rays_here > 20_000
    monkeypatch.undo()
    r = _renderer(24, photons_per_pass=20_000)
    r.photon_pass.chunk = 6_000
    r.photon_pass.trace_ahead(np.random.default_rng(99))   # never gathered: dropped
    assert r.photon_pass._ahead is not None
    assert np.array_equal(r.step().image, here[0])


def _passes(n, cancel_in=None, max_passes=None):
    """n passes of 4 chunks (the last one short) at 24x24, default
    frequency photons (passes 1, 2 and 4 trace them); cancel_in: (pass,
    chunk) whose gather raises RenderCancelled once (the pass is run again)."""
    r = Renderer(warmup_scene(24, ("POINT", "AREA")),
                 RenderSettings(integrator="PHOTON", max_passes=max_passes or n, seed=1,
                                photons_per_pass=20_000), log=lambda _m: None)
    r.photon_pass.chunk = 6_000
    if cancel_in is not None:
        inner, calls = r.photon_pass._trace_gather, []

        def gather(*a, **kw):
            calls.append(r.pass_index + 1)
            if (r.pass_index + 1, calls.count(r.pass_index + 1)) == cancel_in and len(calls) < 99:
                calls.extend([0] * 99)
                r.cancelled = True
                raise RenderCancelled("cancelled")
            return inner(*a, **kw)
        r.photon_pass._trace_gather = gather
    imgs = []
    while len(imgs) < n:
        try:
            imgs.append(r.step().image.copy())
        except RenderCancelled:
            pass
    return imgs, r


def test_next_pass_traced_early_gives_the_same_image(monkeypatch):
    monkeypatch.setattr(PP, "TRACE_NEXT_PASS", False)
    here, r = _passes(5)
    assert r.photon_pass.next_adopted == 0
    monkeypatch.setattr(PP, "TRACE_NEXT_PASS", True)
    for ahead in (1, 3):
        monkeypatch.setattr(PP, "AHEAD_CHUNKS", ahead)
        early, r = _passes(5)
        # passes 3 and 5 (no frequency photons) carried on with the chunks
        # queued under passes 2 and 4; none after the last pass
        assert r.photon_pass.next_adopted == 2
        assert r.photon_pass._next is None
        for k, (a, b) in enumerate(zip(here, early)):
            assert np.array_equal(a, b), (ahead, k)
    monkeypatch.setattr(PP, "AHEAD_CHUNKS", 2)
    # a render stopped after pass 2 (pass 3's chunks queued under it): run()
    # drops the queue; the image is pass 2's
    r = _passes(0, max_passes=5)[1]
    r.run(should_stop=lambda: r.pass_index >= 2)
    assert r.pass_index == 2 and r.photon_pass._next is r.photon_pass._ahead is None
    assert np.array_equal(r.last_result.image, here[1])
    # a cancel in pass 3 (started early under pass 2) and in pass 4 (pass
    # 5's chunks queued under it): the pass is run again with a new stream
    for cancel_in in ((3, 3), (4, 4)):
        again, r = _passes(5, cancel_in)
        assert r.cancelled
        for k, (a, b) in enumerate(zip(here, again)):
            assert np.array_equal(a, b), (cancel_in, k)


def test_direct_beside_setup_gives_the_same_image(monkeypatch):
    """The direct light shared out beside the photon pass's set-up
    (render.DIRECT_BESIDE_SETUP; taken by the side thread and by the pass's
    thread after its grid build) gives every pass's image bit for bit as
    the direct light before the set-up, also around a cancel in a gather;
    with several light samples a pass (its K jobs taken in turn)."""
    from core import render as Rd
    from core.lights import nee as NEE
    from core.sppm import camera_kernels as CK
    monkeypatch.setattr(CK, "SPLIT_MIN", 64)          # 24x24: the blocks shared
    monkeypatch.setattr(Rd, "DIRECT_BESIDE_SETUP", False)
    here, _ = _passes(4)
    monkeypatch.setattr(Rd, "DIRECT_BESIDE_SETUP", True)
    inner, jobs = NEE.NextEventEstimation.shared, []

    def shared(self, *a, **kw):
        jobs.append(inner(self, *a, **kw))
        return jobs[-1]
    monkeypatch.setattr(NEE.NextEventEstimation, "shared", shared)
    for cancel_in in (None, (2, 1), (3, 4)):
        jobs.clear()
        beside, r = _passes(4, cancel_in)
        # one job per light sample (plan.light_samples) of each pass started
        K = r.plan.light_samples
        assert len(jobs) == K * (4 + (cancel_in is not None)) and all(j is not None for j in jobs)
        assert r.photon_pass.beside is None
        for k, (a, b) in enumerate(zip(here, beside)):
            assert np.array_equal(a, b), (cancel_in, k)


def test_radius_cut_is_set_before_the_pass_traces(monkeypatch):
    """A frequency pass's radius cut (PhotonTracer.radius_cut) is set once,
    before its first chunk is traced (PhotonPass.trace_ahead), so the image
    does not depend on how far the trace-ahead got while the camera pass ran:
    every pass bit for bit with a camera pass slowed by 0.3 s (the chunks
    traced ahead all finished before the pass's radii are initialised) and
    with no trace-ahead at all.  The cut is in effect from pass 2 (finite),
    and pass 1, with no radii yet, marches every occluder (inf)
    (frequency_start 1: frequency photons from pass 1)."""
    from core.sppm import photons as PH
    cuts = []
    inner = PH.PhotonTracer.set_radius_cut

    def record(self, R2):
        inner(self, R2)
        cuts.append(self.radius_cut)
    monkeypatch.setattr(PH.PhotonTracer, "set_radius_cut", record)

    def render(delay):
        cuts.clear()
        r = _renderer(24, photons_per_pass=20_000, frequency_decay=0.0, frequency_start=1)
        r.photon_pass.chunk = 6_000
        if delay:
            cam = r.camera_pass

            def slow(*a, **kw):
                import time
                time.sleep(delay)
                return cam(*a, **kw)
            r.camera_pass = slow
        return [r.step().image.copy() for _ in range(3)], list(cuts)

    fast, cuts_fast = render(0.0)
    slow, cuts_slow = render(0.3)
    monkeypatch.setattr(PP, "TRACE_AHEAD", False)
    here, cuts_here = render(0.0)
    assert cuts_fast == cuts_slow == cuts_here
    assert cuts_fast[0] == np.inf and all(np.isfinite(c) and c > 0 for c in cuts_fast[1:])
    for a, b, c in zip(fast, slow, here):
        assert np.array_equal(a, b) and np.array_equal(a, c)


def _ahead_thread_cpu() -> float:
    """CPU seconds of the threads that trace photons (the trace-ahead thread
    and the tracer's pool: thread names "fppm-ahead", "fppm-photons")."""
    import threading
    import time
    t = 0.0
    for th in threading.enumerate():
        if th.name.startswith(("fppm-ahead", "fppm-photons")) and th.ident:
            t += time.clock_gettime(time.pthread_getcpuclockid(th.ident))
    return t


def test_settle_traces_the_next_pass_before_work_between_passes():
    """Renderer.settle (what ``fppm converge`` calls before its metrics,
    which it leaves out of a method's CPU time): once it returns, no thread
    of the renderer traces photons, so the next pass's chunks traced ahead
    are not done in the metrics' time; and the next passes gather them as
    they would have, the same images bit for bit.  Without it the
    trace-ahead thread works on while the caller measures its own work."""
    import time
    here, _ = _passes(5)
    r = _passes(0, max_passes=5)[1]
    got, during = [], []
    for _ in range(5):
        got.append(r.step().image.copy())
        if r.photon_pass._next is not None or r.photon_pass._ahead is not None:
            r.settle()
            queued = [f for q in (r.photon_pass._ahead, r.photon_pass._next)
                      if q is not None for f in q[1]]
            assert all(f.done() for f in queued)
        c0 = _ahead_thread_cpu()
        time.sleep(0.05)                       # the caller's own work
        during.append(_ahead_thread_cpu() - c0)
    # passes 3 and 5 have no frequency photons: queued under passes 2 and 4
    assert r.photon_pass.next_adopted == 2
    assert max(during) < 0.002, during
    for k, (a, b) in enumerate(zip(here, got)):
        assert np.array_equal(a, b), k
