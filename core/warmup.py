"""Compile every render kernel before the first render needs it.

Numba compiles a kernel at its first call; on a machine with an empty cache
that is most of a minute before the first pass (docs/interactive.md), inside
pass 1, where it would count against the time limit and where Esc cannot
interrupt it.  :func:`compile_kernels` instead renders tiny synthetic scenes
through ``Renderer`` for one pass per settings variant (:func:`warmup_jobs`):
a closed room with diffuse, rough glossy, mirror, glass and emissive
surfaces and every light kind, so that the camera (``core.sppm.camera_kernels``),
direct-light (``core.lights.direct_kernels``: every analytic light kind and
emissive triangles), photon (Lambert, mirror, glass and generic closures),
emission, frequency, occlusion, edge and gather kernels all compile.  With a warm on-disk cache the same call
only loads them.

:class:`Warmup` runs that once per process in a background thread, and on
a first use (nothing compiled yet for these sources) has a subprocess do the
compiling (:func:`compile_then_load`):

- the compile runs in a separate process: numba's compiler is Python, and a
  compiling thread inside Blender holds the GIL and, worse, makes the cyclic
  garbage collector run full collections over the whole process (compiling
  creates ~100 000 cyclic objects at a time): measured pauses of 0.3-0.7 s
  of every other Python thread, i.e. Blender's UI (docs/interactive.md).  A
  subprocess shares neither, and uses another core.  It imports ``core``
  under this process's very module name (``bl_ext.<repo>.fppm.core`` inside
  Blender; the cache is keyed by it, ``core/_numba_cache.py``) and writes the
  kernels to the same cache folder;
- then this process's thread renders the same synthetic scenes, which now
  only loads the kernels from disk (a few seconds), so that they are in
  memory when the first render starts.  If the subprocess cannot run (no
  usable Python executable), the thread compiles them itself.
- :meth:`Warmup.wait` polls ``should_stop`` every 50 ms, so a render waiting
  for the compile can be cancelled at once; the compile itself goes on in the
  background (it is needed by the next render anyway).

A marker file per source version (``warmup-<key>.json`` in the cache folder)
records that a compile finished and how long it took, so callers can tell the
user whether this is a first use and about how long it will take.
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from typing import Callable, Optional

import numpy as np

from . import _numba_cache
from .scene.model import DIFFUSE, GLASS, GLOSSY, Camera, Light, Lobe, Material, make_scene
from .settings import RenderSettings

# Assumed length of a first compile when this machine never finished one
# (used only for the message and the progress bar).
DEFAULT_COMPILE_SECONDS = 60.0
_CORE = os.path.dirname(os.path.abspath(__file__))


def _quad(c, ex, ey):
    """Two triangles c +- ex +- ey (normal ex x ey); (2, 3, 3) float64."""
    c, ex, ey = (np.asarray(v, np.float64) for v in (c, ex, ey))
    p00, p10, p11, p01 = c - ex - ey, c + ex - ey, c + ex + ey, c - ex + ey
    return [[p00, p10, p11], [p00, p11, p01]]


def _box(c, h):
    """12 outward-facing triangles of the cube c +- h."""
    c = np.asarray(c, np.float64)
    tris = []
    for axis in range(3):
        e = np.eye(3)
        n, u, v = e[axis], e[(axis + 1) % 3], e[(axis + 2) % 3]
        tris += _quad(c + n * h, u * h, v * h)           # normal +axis
        tris += _quad(c - n * h, v * h, u * h)           # normal -axis
    return tris


def _look_at(eye, target):
    """(4, 4) camera-to-world looking from eye at target, +Z up (Blender's -Z view)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, back, eye
    return m


def _translate(x, y, z):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def warmup_scene(res: int = 12, analytic_lights: tuple = ("POINT", "AREA"),
                 glossy: bool = True):
    """A synthetic scene of the warm-up (``core.scene.model.Scene``), res x res px.

    A closed 4 x 4 x 2 m room (so that nearly every photon is deposited, and a
    pass of a few ten thousand photons reaches the gather's parallel path)
    with a diffuse floor and walls, a rough glossy wall, a mirror, a glass
    cube and an emissive ceiling quad, lit by ``analytic_lights`` (kinds of
    ``core.scene.model.Light``; POINT and AREA photons are emitted by the
    compiled sampler, SPOT and SUN by the numpy one).  glossy=False makes the
    rough glossy wall diffuse (the camera-path kernels,
    core.integrators.path_kernels, cover scenes without rough lobes).
    """
    mats = [Material("diffuse", (Lobe(DIFFUSE, (0.8, 0.8, 0.8)),)),
            Material("glossy", (Lobe(GLOSSY, (0.8, 0.6, 0.4), roughness=0.3),
                                Lobe(DIFFUSE, (0.2, 0.2, 0.2), weight=0.5))
                     if glossy else (Lobe(DIFFUSE, (0.8, 0.6, 0.4)),)),
            Material("mirror", (Lobe(GLOSSY, (0.9, 0.9, 0.9), roughness=0.0),)),
            Material("glass", (Lobe(GLASS, (1.0, 1.0, 1.0), ior=1.5),)),
            Material("emitter", (Lobe(DIFFUSE, (0.0, 0.0, 0.0)),), emission=(5.0, 5.0, 5.0))]
    parts = [(_quad((0, 0, 0), (2, 0, 0), (0, 2, 0)), 0),            # floor, +Z
             (_quad((0, 0, 2), (0, 2, 0), (2, 0, 0)), 0),            # ceiling, -Z
             (_quad((-2, 0, 1), (0, 2, 0), (0, 0, 1)), 0),           # left wall, +X
             (_quad((2, 0, 1), (0, 0, 1), (0, 2, 0)), 0),            # right wall, -X
             (_quad((0, -2, 1), (0, 0, 1), (2, 0, 0)), 0),           # front wall, +Y
             (_quad((0, 2, 1), (2, 0, 0), (0, 0, 1)), 1),            # back wall, -Y
             (_quad((-1.9, 0.5, 0.6), (0, 0.5, 0), (0, 0, 0.6)), 2),  # mirror, +X
             (_box((0.4, 0.0, 0.35), 0.35), 3),                      # glass cube
             (_quad((0, 0.5, 1.95), (0.3, 0, 0), (0, -0.3, 0)), 4)]  # ceiling lamp, -Z
    tris = [t for p, _ in parts for t in p]
    tri_mat = [m for p, m in parts for _ in p]
    at = {"POINT": _translate(-0.6, -0.6, 1.5), "AREA": _translate(0.8, -0.5, 1.8),
          "SPOT": _translate(0.5, 0.5, 1.9), "SUN": _translate(0.0, 0.0, 1.9)}
    lights = [Light(k.lower(), k, (40.0, 40.0, 40.0) if k != "SUN" else (2.0, 2.0, 2.0),
                    at[k], radius=0.05, size=0.4) for k in analytic_lights]
    cam = Camera(kind="PERSP", matrix_world=_look_at((0.0, -1.9, 1.2), (0.0, 0.3, 0.4)),
                 lens=20.0, resolution=(res, res), clip_start=0.01, clip_end=100.0)
    return make_scene(tris, mats, lights, cam, tri_mat=tri_mat)


def warmup_jobs() -> list:
    """(scene, settings) pairs, one per code path whose kernels differ; one pass each.

    The second gathers enough photons for the gather's parallel path
    (``hashgrid.PARALLEL_MIN_PHOTONS``), every one a frequency photon so that
    the QUANTILE estimator's pair search takes it too; the third covers the
    classic-PPM options and the numpy-sampled light kinds.
    """
    base = RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=3000, seed=1)
    room = warmup_scene()
    return [(room, base),
            (room, base.replace(photons_per_pass=40_000, frequency_fraction=1.0,
                                frequency_estimator="QUANTILE", frequency_model="PAPER",
                                aov_radius=True, aov_predicted_radius=True, aov_spectrum=True,
                                aov_photon_count=True, aov_held=True, radius_mode="WORLD")),
            (warmup_scene(analytic_lights=("SPOT", "SUN")),
             base.replace(use_frequency=False, photons_for_direct=True,
                          fixed_visible_points=True, cap_radius_at_edges=False)),
            # The compiled camera paths and the combined integrator's kernels
            # (COMBINED is the default integrator: tests/test_warmup.py renders it).
            (warmup_scene(glossy=False),
             base.replace(integrator="COMBINED", photons_per_pass=2000, camera_samples=1))]


def compile_kernels(should_stop: Optional[Callable[[], bool]] = None) -> float:
    """Render every job of :func:`warmup_jobs` for one pass; returns the seconds it took.

    Raises RenderCancelled when ``should_stop()`` turns True (polled by the
    Renderer during its set-up and passes).
    """
    from .errors import RenderCancelled
    from .render import Renderer
    t0 = time.perf_counter()
    for k, (scene, st) in enumerate(warmup_jobs()):
        with _split_paths(k == 0):
            r = Renderer(scene, st, log=lambda _m: None, should_stop=should_stop)
            r.run(should_stop=should_stop)
        if should_stop is not None and should_stop():
            raise RenderCancelled("cancelled")
    return time.perf_counter() - t0


class _split_paths:
    """With on=True, the per-pixel stages take their threaded paths at any
    size (their thresholds set to 1 for the block), so that the first job
    compiles the kernels a large render uses (camera rays, grid build,
    update, film)."""
    _LIMITS = (("scene.camera", "PARALLEL_MIN"), ("sppm.update", "PARALLEL_MIN"),
               ("sppm.film", "PARALLEL_MIN"), ("sppm.hashgrid", "PARALLEL_MIN_VPS"),
               ("sppm.visible_points", "INTERSECT_SPLIT_MIN"))

    def __init__(self, on: bool):
        import importlib
        self.on = on
        self.mods = [(importlib.import_module("." + m, __package__), a) for m, a in self._LIMITS]

    def __enter__(self):
        if self.on:
            self.saved = [getattr(m, a) for m, a in self.mods]
            for m, a in self.mods:
                setattr(m, a, 1)

    def __exit__(self, *exc):
        if self.on:
            for (m, a), v in zip(self.mods, self.saved):
                setattr(m, a, v)


# Run by compile_in_subprocess: load the package under the parent's module name
# (stub parents for a dotted name such as bl_ext.user_default.fppm), then
# compile.  It ends with its parent (a quit Blender, an interrupted CLI).
_CHILD = r"""
import importlib, importlib.util, os, sys, threading, time, types
name, root = sys.argv[1], sys.argv[2]


def exit_with_parent(ppid=os.getppid()):
    while os.getppid() == ppid:
        time.sleep(0.5)
    os._exit(1)


threading.Thread(target=exit_with_parent, daemon=True).start()
parts = name.split(".")
for i in range(1, len(parts)):
    parent = ".".join(parts[:i])
    if parent not in sys.modules:
        stub = types.ModuleType(parent)
        stub.__path__ = []
        sys.modules[parent] = stub
spec = importlib.util.spec_from_file_location(name, os.path.join(root, "__init__.py"),
                                              submodule_search_locations=[root])
pkg = importlib.util.module_from_spec(spec)
sys.modules[name] = pkg
spec.loader.exec_module(pkg)
importlib.import_module(name + ".core.warmup").compile_kernels()
"""


def package_name() -> str:
    """The module name the package holding ``core`` is imported under."""
    return __name__.rsplit(".core.warmup", 1)[0]


def compile_in_subprocess(should_stop: Optional[Callable[[], bool]] = None,
                          poll: float = 0.05) -> float:
    """:func:`compile_kernels` in a child Python filling this process's kernel
    cache; returns its seconds.  Raises RenderCancelled (the child is killed)
    when ``should_stop()``, RuntimeError when the child fails."""
    from .errors import RenderCancelled
    root = _numba_cache.cache_dir()
    if root is None:
        raise RuntimeError("no writable kernel cache folder")
    if not os.path.basename(sys.executable).lower().startswith("python"):
        # Blender >= 2.91 sets sys.executable to its bundled Python; never
        # start a second Blender by mistake.
        raise RuntimeError(f"{sys.executable!r} is not a Python interpreter")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p),
               **{_numba_cache.ENV_VAR: root})
    t0 = time.perf_counter()
    # Its own process group: Ctrl-C in the CLI's terminal stops the render
    # (which polls), not the compile that the next render needs.
    group = ({"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP} if sys.platform == "win32"
             else {"start_new_session": True})
    with tempfile.TemporaryFile() as log:     # a file: a full pipe would block the child
        proc = subprocess.Popen([sys.executable, "-c", _CHILD, package_name(),
                                 os.path.dirname(_CORE)], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=log, env=env, cwd=root, **group)
        try:
            while proc.poll() is None:
                if should_stop is not None and should_stop():
                    raise RenderCancelled("cancelled")
                time.sleep(poll)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        log.seek(0)
        err = log.read().decode(errors="replace")
    if proc.returncode != 0:
        raise RuntimeError(f"the compiling process ended with code {proc.returncode}: "
                           f"{err.strip().splitlines()[-1] if err.strip() else 'no message'}")
    return time.perf_counter() - t0


def compile_then_load(should_stop: Optional[Callable[[], bool]] = None) -> float:
    """The warm-up of :class:`Warmup`: on a first use a subprocess compiles,
    then this process loads the kernels (see the module docstring); seconds."""
    from .errors import RenderCancelled
    t0 = time.perf_counter()
    if not is_compiled():
        try:
            compile_in_subprocess(should_stop)
        except RenderCancelled:
            raise
        except (OSError, RuntimeError) as ex:
            print(f"FPPM: compiling the kernels in a separate process failed ({ex}); "
                  f"compiling them in this one.")
    compile_kernels(should_stop)
    return time.perf_counter() - t0


def source_key() -> str:
    """Hash of everything a compiled kernel depends on: core's sources, the
    numba and Python versions, and the module name core is imported under."""
    h = hashlib.sha256()
    for d, dirs, files in sorted(os.walk(_CORE)):
        dirs[:] = sorted(x for x in dirs if x != "__pycache__")
        for f in sorted(files):
            if f.endswith(".py"):
                with open(os.path.join(d, f), "rb") as fh:
                    h.update(f.encode() + b"\0" + fh.read())
    try:
        from importlib.metadata import version
        nb = version("numba")
    except Exception:
        nb = "?"
    h.update(f"{nb}|{sys.version_info[:2]}|{__name__}".encode())
    return h.hexdigest()[:16]


def _marker_path() -> Optional[str]:
    root = _numba_cache.cache_dir()
    return None if root is None else os.path.join(root, "numba", f"warmup-{source_key()}.json")


def last_compile_seconds() -> Optional[float]:
    """Seconds of the last complete first-use compile on this machine (any
    version), or None when there was none."""
    root = _numba_cache.cache_dir()
    if root is None:
        return None
    folder = os.path.join(root, "numba")
    best = None
    try:
        names = [n for n in os.listdir(folder) if n.startswith("warmup-") and n.endswith(".json")]
    except OSError:
        return None
    for n in names:
        try:
            with open(os.path.join(folder, n)) as f:
                d = json.load(f)
            if d.get("cold"):
                best = max(best or 0.0, float(d["seconds"]))
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return best


def is_compiled() -> bool:
    """True when this source version finished a warm-up on this machine (the
    kernels are on disk: loading them takes seconds, not a compile)."""
    p = _marker_path()
    return p is not None and os.path.exists(p)


def expected_seconds() -> float:
    """About how long a first-use compile will take here (for the message)."""
    return last_compile_seconds() or DEFAULT_COMPILE_SECONDS


def _write_marker(seconds: float, cold: bool) -> None:
    p = _marker_path()
    if p is None:
        return
    try:
        os.makedirs(os.path.dirname(p), exist_ok=True)
        tmp = p + f".{os.getpid()}.tmp"
        with open(tmp, "w") as f:
            json.dump({"seconds": seconds, "cold": cold}, f)
        os.replace(tmp, p)
    except OSError:
        pass      # an unwritable cache only costs the message's estimate


class Warmup:
    """The once-per-process background compile.

    ``start()`` launches it (idempotent); ``wait(should_stop)`` blocks until it
    ends or ``should_stop()``; afterwards ``done``, ``error`` (the exception
    text, or None), ``seconds`` and ``was_cold`` (a compile, not a load).
    ``stop()`` asks it to end at the next poll (unregister, tests).
    ``compile(should_stop) -> seconds`` is :func:`compile_then_load` (tests
    pass a stand-in).
    """

    def __init__(self, compile: Callable = None):
        self._compile = compile or compile_then_load
        self._lock = threading.Lock()
        self._thread: Optional[threading.Thread] = None
        self._done = threading.Event()
        self._stop = threading.Event()
        self.error: Optional[str] = None
        self.seconds: Optional[float] = None
        self.was_cold: Optional[bool] = None
        self.started_at: Optional[float] = None

    @property
    def done(self) -> bool:
        return self._done.is_set()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        with self._lock:
            if self._done.is_set() or self.running:
                return
            self._stop.clear()
            self.started_at = time.monotonic()
            self._thread = threading.Thread(target=self._run, name="fppm-warmup", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        from .errors import FPPMError, RenderCancelled
        try:
            cold = not is_compiled()
            secs = self._compile(should_stop=self._stop.is_set)
            if self._stop.is_set():
                return                 # stopped: a later start() begins again
            self.seconds, self.was_cold = secs, cold
            _write_marker(secs, cold)
            self._done.set()
        except RenderCancelled:
            pass                       # stopped: a later start() begins again
        except FPPMError as ex:        # a user-facing condition (e.g. memory): the
            self.error = str(ex)       # render that follows says it again, clearly
            self._done.set()
        except Exception as ex:        # noqa: BLE001 - reported by the caller
            self.error = f"{type(ex).__name__}: {ex}"
            traceback.print_exc()
            self._done.set()

    def wait(self, should_stop: Optional[Callable[[], bool]] = None,
             on_wait: Optional[Callable[[float], None]] = None, poll: float = 0.05) -> bool:
        """Start if needed and block until done; True when done, False when
        ``should_stop()`` returned True first.  ``on_wait(seconds waited)``
        is called at every poll (progress display)."""
        self.start()
        t0 = time.monotonic()
        while not self._done.wait(poll):
            if should_stop is not None and should_stop():
                return False
            if not self.running and not self._done.is_set():
                self.start()           # stopped by stop(): begin again
            if on_wait is not None:
                on_wait(time.monotonic() - t0)
        return True


warmup = Warmup()
"""The process's warm-up (the add-on, the viewport and the CLI share it)."""
