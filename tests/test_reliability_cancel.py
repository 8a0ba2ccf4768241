"""Cancel within 0.1 s inside the export of one big mesh or one big image
(addon/export_read.py), and the reads cut for it equal the single Blender calls
they replace, bit for bit (tests/oracle_export_read.py).

docs/reliability.md ("Cancel") has the measured numbers.
"""
import glob
import os
import sys
import time

import numpy as np
import pytest

import bpy_helpers as H
import oracle_export_read as O

from core.errors import RenderCancelled

# Every test here measures a cancel's latency: run alone (tests/conftest.py).
pytestmark = pytest.mark.serial

# The promise of docs/reliability.md: a cancel returns within 0.1 s (idle).
PROMISED = 0.1


def _slowdown(cpu: float = 0.01) -> float:
    """Wall over CPU seconds of a busy loop of ``cpu`` s in this thread: 1 on
    an idle machine, n when the shared machine gives this thread 1/n of a
    core.  A latency measured now, divided by it, is what the promise is
    about (an idle machine); the division is printed with it."""
    w0, c0 = time.perf_counter(), time.thread_time()
    while time.thread_time() - c0 < cpu:
        pass
    return max(1.0, (time.perf_counter() - w0) / (time.thread_time() - c0))


def _idle_latency(cancelled):
    """cancelled() -> a latency [s] (or None: no cancel); returns (latency,
    the latency over the machine's slowdown measured before and after)."""
    before = _slowdown()
    lat = cancelled()
    if lat is None:
        return None, None
    return lat, lat / (0.5 * (before + _slowdown()))


def _poll_site():
    """Where should_stop() was called from: the (file, line) of its three callers."""
    f, out = sys._getframe(2), []
    while f is not None and len(out) < 3:
        out.append((f.f_code.co_filename, f.f_lineno))
        f = f.f_back
    return tuple(out)


class Recorder:
    """should_stop() that never stops and records when it was called,
    counted from arm(), and from where (:func:`_poll_site`)."""

    def arm(self):
        self.t0 = time.perf_counter()
        self.calls = []
        self.sites = []

    def __call__(self):
        self.calls.append(time.perf_counter() - self.t0)
        self.sites.append(_poll_site())
        return False

    def counts(self) -> dict:
        """Polls per site."""
        out = {}
        for site in self.sites:
            out[site] = out.get(site, 0) + 1
        return out


class StopAfter:
    """should_stop() whose ``k``-th call (from 0) from ``site`` still answers
    False and records that instant as the cancel; every later call answers
    True.  The latency is then the gap after that poll plus the unwinding:
    the wait of a cancel that arrives just after it, the worst instant in
    that gap."""

    def __init__(self, site, k):
        self.site, self.k = site, k
        self.seen = 0
        self.t_cancel = None

    def __call__(self):
        if self.t_cancel is not None:
            return True
        if _poll_site() == self.site:
            if self.seen == self.k:
                self.t_cancel = time.perf_counter()
            self.seen += 1
        return False


def _cancel_polls(rec: Recorder, full: float, other: Recorder) -> list:
    """The polls that open the three longest gaps between polls of an
    uncancelled run rec (a cancel arriving just after them waits the
    longest), and the poll half way through, as (site, k): the k-th poll
    from that site.  A poll is named by its site, not its rank among all
    polls: how often a child process's read is polled (every 5 ms while it
    runs) depends on the machine's load, and would shift the rank of every
    later poll.  At such a site (a count that differs in the other
    uncancelled run) k is at most half the smaller count, so that the poll
    is reached in any run."""
    t = np.array(rec.calls)
    # Not the last poll: no later one sees a cancel there (the gap after it
    # is the return from the export).
    longest = np.argsort(np.diff(t))[::-1][:3]
    picked = sorted(set(int(i) for i in longest) | {int(np.searchsorted(t, 0.5 * full))})
    a, b = rec.counts(), other.counts()
    out = []
    for n in picked:
        site = rec.sites[n]
        k = rec.sites[:n].count(site)
        if a[site] != b.get(site, 0):
            k = min(k, min(a[site], b.get(site, 0)) // 2)
        out.append((rec.calls[n], site, k))
    return out


def _assert_cancels_within_promise(prepare, export, what):
    """prepare() -> the evaluated depsgraph of a fresh export (not timed);
    export(depsgraph, should_stop) runs it.  Uncancelled twice (the faster
    run's duration and gaps between polls), then cancelled just after the
    polls of :func:`_cancel_polls`: every cancel must land inside the export
    (RenderCancelled) and return within PROMISED once divided by the
    slowdown of the shared machine measured around it (:func:`_idle_latency`),
    best of 3 tries per poll (a run that never reaches the poll counts as a
    try)."""
    full = np.inf
    runs = []
    for _ in range(2):                          # the faster of 2 (the first warms up)
        r = Recorder()
        dg = prepare()
        c0 = time.process_time()
        r.arm()
        export(dg, r)
        runs.append(r)
        if time.perf_counter() - r.t0 < full:
            full, cpu, rec = time.perf_counter() - r.t0, time.process_time() - c0, r
    other = runs[0] if rec is runs[1] else runs[1]
    lats, missed = [], []
    for at, site, k in _cancel_polls(rec, full, other):
        best = (np.inf, np.inf)

        def cancelled():
            stop = StopAfter(site, k)
            export_dg = prepare()
            try:
                export(export_dg, stop)
                return None                     # the poll not reached
            except RenderCancelled:
                return time.perf_counter() - stop.t_cancel
        for _ in range(3):
            lat, idle = _idle_latency(cancelled)
            if lat is not None and idle < best[1]:
                best = (lat, idle)
            if best[1] < PROMISED:
                break
        (lats if np.isfinite(best[1]) else missed).append((at, *best))
    print(f"{what}: export {full:.3f} s ({cpu:.3f} s CPU) uncancelled, {len(rec.calls)} "
          f"polls from {len(rec.counts())} sites, worst gap "
          f"{np.diff(rec.calls + [full]).max() * 1e3:.0f} ms; cancel at "
          + ", ".join(f"{a:.3f} s -> {x * 1e3:.0f} ms ({y * 1e3:.0f} ms idle)"
                      for a, x, y in lats)
          + (f"; never reached: {', '.join(f'{m[0]:.3f} s' for m in missed)}" if missed else ""))
    assert full > 0.5, full                     # the cancels land mid-export
    # Named by site, every poll is reached (a late one could still be
    # skipped if a run took another path: at most one, and only a late one).
    assert len(missed) <= 1 and all(m[0] > 0.5 * full for m in missed), (lats, missed)
    assert lats and max(y for _, _, y in lats) < PROMISED, lats


def _children():
    """Process ids of this process's children (Linux), once the killed ones
    are reaped, less the kernel warm-up's compiling child (core.warmup: an
    F12 starts it when no earlier render of the session did; it waits 20 s
    for the next render's job).  Tests compare
    them with the children alive before they ran: other tests of the session
    may leave their own."""
    from fppm.addon import export_read as R
    R.reap()
    out = []
    for task in glob.glob(f"/proc/{os.getpid()}/task/*/children"):
        try:
            with open(task) as fh:
                out += [int(x) for x in fh.read().split()]
        except OSError:         # the thread ended between the glob and the open
            pass
    return [p for p in out if b"child_main(" not in _cmdline(p)]


def _cmdline(pid: int) -> bytes:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read()
    except OSError:             # ended meanwhile
        return b""


def _export(dg, should_stop):
    """The export as the engine runs it: ``export_cancellable``, then a check
    of the flag (``FPPMRenderEngine._render`` returns there when cancelled)."""
    import fppm.addon.engine as E
    fscene = E.export_cancellable(dg, lambda m: None, None, should_stop)
    if should_stop():
        raise RenderCancelled("cancelled after the export")
    return fscene


# ---------------------------------------------------------------------------
# cancel inside one 1M-triangle object

def test_cancel_within_promise_inside_1m_triangle_meshes():
    # Two objects of 2 x 707^2 = 999,698 triangles each, smooth shaded (the
    # finding: 1.65 s to cancel one 1M-triangle object; two, so that the
    # export takes > 1 s idle).  Every export starts from fresh evaluated
    # meshes, so Blender computes their normals again as on a first render.
    bpy = H.bpy()
    H.simple_scene(res=(16, 16), passes=1, photons=1000)
    grids = []
    for z in (0.01, 0.02):
        bpy.ops.mesh.primitive_grid_add(x_subdivisions=707, y_subdivisions=707, size=4,
                                        location=(0, 0, z))
        grids.append(bpy.context.active_object)
        grids[-1].data.shade_smooth()

    def prepare():
        for g in grids:
            g.data.update()                    # Blender's caches (normals) dropped
        return H.evaluated_depsgraph()
    _assert_cancels_within_promise(prepare, _export, "two 1M-triangle objects")


# ---------------------------------------------------------------------------
# cancel inside one 4096^2 texture

def test_cancel_within_promise_inside_a_4k_texture(monkeypatch):
    # A 4096^2 generated sRGB texture (the finding: 2.6 s to cancel an 8192^2
    # one): Blender makes it on the first access, then Image.pixels copies it,
    # both single calls: done in a child process that a cancel kills.
    if not os.environ.get("FPPM_TEST_OWN_PROCESS"):
        # In a process of its own, as a Blender session rendering its scene:
        # a cancel that lands just before the fork waits for the fork, whose
        # page-table copy grows with the forking process's heap (0.5 ms for a
        # fresh process, 32 ms with 8M small Python objects alive, 108 ms in
        # the pytest process after a thousand tests of a fresh clone).
        import subprocess
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        r = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider",
             f"{os.path.abspath(__file__)}::test_cancel_within_promise_inside_a_4k_texture"],
            cwd=root, env={**os.environ, "FPPM_TEST_OWN_PROCESS": "1"},
            capture_output=True, text=True, timeout=900)
        print(r.stdout[-3000:])
        assert r.returncode == 0, r.stdout[-6000:] + r.stderr[-3000:]
        return
    from test_reliability3 import _render_cancelled_at, _textured_floor
    before = set(_children())
    img = _textured_floor(4096)
    _assert_cancels_within_promise(H.evaluated_depsgraph, _export, "a 4096^2 texture")
    # What a cancel leaves: no child process, Blender's image not made in
    # this process (the child made its own copy).
    assert set(_children()) <= before
    assert not img.has_data
    # Through F12 (best of 2): the engine reports a cancel, no error, no result.
    lats = []
    for _ in range(2):
        out = {}

        def cancelled():
            lat, out["sess"], out["inside"] = _render_cancelled_at(monkeypatch, 0.3)
            return lat
        lats.append(_idle_latency(cancelled))
        sess = out["sess"]
        assert sess.error is None and sess.cancelled and sess.result is None, sess.error
        assert out["inside"]
        if lats[-1][1] < PROMISED:
            break
    print("F12 cancelled 0.3 s into the export: "
          + ", ".join(f"{x * 1e3:.0f} ms ({y * 1e3:.0f} ms idle)" for x, y in lats))
    assert min(y for _, y in lats) < PROMISED, lats
    assert set(_children()) <= before


# ---------------------------------------------------------------------------
# the reads cut for cancel equal the single calls, bit for bit

def _assert_mesh_equal(me, label):
    from fppm.addon import export_read as R
    got = R.mesh_arrays(me)                    # first: Blender's caches still empty
    corners, *ref = O.mesh_arrays(me)
    for name, a, b in zip(("positions", "normals", "uvs", "slots"), got, ref):
        assert a.dtype == b.dtype and np.array_equal(a, b), (label, name)
    face = np.empty(len(corners), np.int32)
    me.loop_triangle_polygons.foreach_get("value", face)
    cv = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", cv)
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    assert np.array_equal(R.corner_triangles(me, face, co.reshape(-1, 3), cv, single_max=0),
                          corners), label
    return len(corners)


def test_mesh_reads_equal_loop_triangles_on_the_test_scenes(monkeypatch):
    # tests/scenes and example_blends: every mesh object as evaluated, with
    # the triangles rebuilt (small meshes are otherwise read in one call).
    from fppm.addon import export_read as R
    monkeypatch.setattr(R, "SINGLE_MAX", 0)
    bpy = H.bpy()
    n = 0
    for path in sorted(glob.glob(os.path.join(H.ROOT, "tests", "scenes", "*.blend"))
                       + glob.glob(os.path.join(H.ROOT, "example_blends", "*.blend"))):
        bpy.ops.wm.open_mainfile(filepath=path, load_ui=False, use_scripts=False)
        dg = bpy.context.evaluated_depsgraph_get()
        for inst in dg.object_instances:
            if inst.object.type == 'MESH':
                n += _assert_mesh_equal(inst.object.data, f"{path}:{inst.object.name}")
    assert n > 4000, n          # 4250 triangles in 20 files
    # N-gons (Blender's polyfill), and quads that Blender splits along 1-3:
    # concave, collapsed, every rotation of a concave one.
    H.empty_scene()
    rng = np.random.default_rng(1)
    me = bpy.data.meshes.new("ngons")
    me.from_pydata(rng.normal(size=(2000, 3)).tolist(), [],
                   [rng.choice(2000, size=k, replace=False).tolist()
                    for k in rng.integers(3, 9, size=1500)])
    me.update()
    _assert_mesh_equal(me, "random n-gons")
    v = [(0, 0, 0), (1, 0, 0), (0.2, 0.2, 0), (0, 1, 0), (2, 0, 0), (3, 0, 0), (3, 0, 0),
         (2, 1, 0), (4, 0, 0), (5, 0, 0), (6, 0, 0), (7, 0, 0)]
    q = [(0, 1, 2, 3), (1, 2, 3, 0), (2, 3, 0, 1), (3, 0, 1, 2), (4, 5, 6, 7), (8, 9, 10, 11)]
    me = bpy.data.meshes.new("quads")
    me.from_pydata(v, [], q)
    me.update()
    _assert_mesh_equal(me, "special quads")


def test_image_reads_equal_the_single_call(monkeypatch):
    from fppm.addon import export_read as R
    from test_reliability3 import _textured_floor
    bpy = H.bpy()
    before = set(_children())
    img = _textured_floor(1024)                # 4M floats: read in a child
    cases = [("generated", img, 1024 * 1024 * 4)]
    fimg = bpy.data.images.new("Float", 1024, 1024, float_buffer=True)
    fimg.generated_type = "UV_GRID"
    cases.append(("generated float", fimg, 1024 * 1024 * 4))
    img.filepath_raw = os.path.join(bpy.app.tempdir or "/tmp", "fppm_cancel_test.png")
    img.file_format = "PNG"
    img.save()
    png = bpy.data.images.load(img.filepath_raw, check_existing=False)
    cases.append(("PNG file", png, 1024 * 1024 * 4))
    small = bpy.data.images.new("Small", 1024, 1024)
    cases.append(("capacity too small: read in-process", small, R.CHILD_MIN_FLOATS))
    timed_out = bpy.data.images.new("Slow", 1024, 1024)
    cases.append(("child timed out: read in-process", timed_out, 1024 * 1024 * 4))
    for label, im, cap in cases:
        if im is timed_out:
            monkeypatch.setattr(R, "CHILD_TIMEOUT", (0.0, 0.0))
        got = R.image_pixels(im, cap, poll=lambda: None)   # a poll: in a child
        ref = O.image_pixels(im)
        assert got[1:] == ref[1:], label
        assert np.array_equal(got[0], ref[0]), label
    os.remove(img.filepath_raw)
    assert set(_children()) <= before
