"""Photon and light-path passes split over Dask workers: ``fppm render --workers N`` / ``--cluster ADDRESS``.

    client = connect(workers=2)                  # or connect(address="tcp://host:8786")
    distribute(client, renderer)                 # takes over the renderer's chunked stages
    renderer.run()
    close(client)

``distribute`` installs, per integrator: PHOTON, a DistributedPhotonPass in
place of ``renderer.photon_pass``; LIGHT, a DistributedLightTracer in place
of ``renderer.light_tracer``; COMBINED, a DistributedLightTracer in place of
``renderer.combined_lt`` (light tracing) and, when the plan merges photons,
a DistributedPhotonPass (the merging photons; the driver's camera pass
picks the visible points seen through a delta vertex).  PATH has no
light side: it renders in the driver.

The driver (the process that exported the scene and runs
``core.render.Renderer``) keeps every stage of a pass but the photons.  It
sends the exported scene and the settings to the workers once (a broadcast
``scatter``); each worker builds its own BVH, light and material tables,
render plan, occlusion grid and photon tracer from them (the scene half of a
Renderer, no per-pixel state).  Each pass the driver broadcasts what the
gather reads of the active visible points and their squared radii
(``PassJob``), and submits one task per photon chunk
(``PhotonPass.chunks``).  A task traces chunk c with its own random stream
``chunk_rng(pass stream, c)``, gathers it against the pass's grid (built once
per pass on each worker) and returns the chunk's sums at the pixels it
touched (``ChunkSums``: M, Phi, the smallest predicted radius, the radius
histogram and spectrum of the frequency photons).  The driver adds them in
chunk order (``PassSums.add``) and runs the normal update and film.

Same image as one process: a single process with ``photon_pass.chunk_streams``
(``local_chunk_streams``) computes and adds exactly the same chunk sums in the
same order, so the images are bit for bit equal as long as every worker runs
the gather on as many numba threads as that process (the per-thread Phi sums
of ``hashgrid.gather`` are added in thread order; another thread count changes
the last bits).  The default single-process render uses one random stream per
pass instead: same noise level, other random numbers.

Light paths (integrators LIGHT and COMBINED) are split the same way: the
driver keeps the camera side of a pass (COMBINED's camera paths, the film)
and submits one task per chunk of light paths (``LightTracer.chunks``); a
task traces chunk c with ``chunk_rng(pass stream, c)`` and returns its
splat sums at the pixels it touched (``SplatSums``), added by the driver in
chunk order.  Nothing is broadcast per pass: a chunk needs the scene alone.
With ``prefetch`` the driver submits pass k+1's light chunks as soon as
pass k's are in, so the workers trace them while the driver finishes pass
k (merging) and traces pass k+1's camera paths; merging's photon chunks go
ahead of them (Dask priority 1).  Off by default: on 2 shared cores it was
1.3x slower than waiting (the workers took the cores the driver's camera
paths needed; docs/scale_out.md).

A worker that dies mid-pass: the scheduler gives its chunks to another worker
(a nanny restarts a local one); a chunk depends on its inputs alone, so the
result is identical.  The scene and the pass data are broadcast to every
worker, so any survivor holds them (the local cluster runs without Dask's
Active Memory Manager, which would drop the extra copies: :func:`connect`).

Dask is imported only here and only when these flags are used; the Blender
extension never imports this module (tools/ is not shipped).
"""
from __future__ import annotations

import dataclasses
import logging
import os
import threading
import time
import uuid
from typing import NamedTuple, Optional

import numpy as np

from ..core import memory
from ..core.integrators.light_tracer import SplatSums
from ..core.plan import MERGING
from ..core.render import Renderer
from ..core.sppm.photon_pass import PassSums, PhotonEstimate, PhotonPass, chunk_rng
from ..core.sppm.update import Radii
from ..core.sppm.visible_points import VisiblePoints

DASK_MISSING = ("--workers and --cluster need Dask: install it with "
                "`pip install \"dask[distributed]\"` (`make venv` does).")
#: Seconds to wait for the scheduler of --cluster.
CONNECT_TIMEOUT = 10
#: Seconds between two polls of should_stop while waiting for a chunk.
POLL = 0.05


class DaskMissing(ImportError):
    """dask.distributed is not installed (the CLI's usage error)."""


def require():
    """The dask.distributed module; DaskMissing when it is not installed."""
    try:
        import distributed
    except ImportError as ex:
        raise DaskMissing(DASK_MISSING) from ex
    return distributed


def connect(workers: Optional[int] = None, address: Optional[str] = None):
    """A dask.distributed Client: of a new local cluster of ``workers``
    processes (one task thread each, no memory limit, its HTTP endpoints on a
    free port), or of the scheduler at ``address``.  Raises DaskMissing."""
    distributed = require()
    if address:
        return distributed.Client(address, set_as_default=False, timeout=CONNECT_TIMEOUT)
    import dask
    # No Active Memory Manager: its ReduceReplicas policy drops the copies
    # of the broadcast scene and pass data that no queued task waits for
    # (after ~2 s), and a worker that then dies takes the last copy with it
    # (scattered data cannot be recomputed: every chunk fails).
    with dask.config.set({"distributed.scheduler.active-memory-manager.start": False}):
        cluster = distributed.LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                           processes=True, memory_limit=0,
                                           dashboard_address=":0", silence_logs=logging.ERROR)
    client = distributed.Client(cluster, set_as_default=False)
    client._fppm_cluster = cluster          # closed by close()
    # Every worker registered before the scene is built on "every worker"
    # and the log counts them (a loaded machine starts them late).
    client.wait_for_workers(int(workers), timeout=60)
    client.register_plugin(_worker_ignores_sigint(), name="fppm-ignore-sigint")
    client.register_plugin(_worker_quiet_heartbeat(), name="fppm-quiet-heartbeat")
    return client


#: What --workers / --cluster tell a COMBINED render whose merging weights
#: they replace (``partition_fallback``).
PARTITION_FALLBACK = ("FPPM: merging weights 'PARTITION' on Dask workers: merging as an MIS "
                      "strategy gathers light tracing's deposits, which the workers' light "
                      "paths do not return (docs/integrators.md).")


def partition_fallback(a):
    """Set ``--merge-weights partition`` on the CLI arguments a of a
    distributed render (merging as an MIS strategy needs every light path's
    deposits in the driver, core.render ``_step_merge_mis``; the workers
    return splat sums alone).  Returns ``replaced(file_weights) -> bool``:
    whether that replaced 'MIS' weights, a's own when given, else the file's
    (``a.file_settings``, read once the file is open): the caller logs
    PARTITION_FALLBACK for a COMBINED render then, and only then."""
    given = getattr(a, "merge_weights", None)
    a.merge_weights = "partition"
    return lambda file_weights: (given or file_weights).upper() == "MIS"


def _worker_ignores_sigint():
    """A WorkerPlugin: a local worker ignores SIGINT.  Ctrl-C in a terminal
    reaches the whole process group; the driver cancels the render and closes
    the cluster itself, and the workers would only print KeyboardInterrupt
    tracebacks.  (Set in the worker's event-loop thread, its main thread.)"""
    from distributed.diagnostics.plugin import WorkerPlugin

    class IgnoreSigint(WorkerPlugin):
        def setup(self, worker):
            import signal
            import threading
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)
    return IgnoreSigint()


#: The message a local worker logs (ERROR, with a traceback) when its
#: heartbeat meets the scheduler already closed: Dask's own shutdown race,
#: after a render has ended and close() runs (docs/scale_out.md "Errors").
HEARTBEAT_LOST = "Failed to communicate with scheduler during heartbeat"


def _drop_heartbeat_lost(record: logging.LogRecord) -> bool:
    """A logging filter: False (drop) for HEARTBEAT_LOST records."""
    return not str(record.msg).startswith(HEARTBEAT_LOST)


def _worker_quiet_heartbeat():
    """A WorkerPlugin: a local worker does not print HEARTBEAT_LOST.  The
    driver owns the local cluster: a scheduler that really went away fails
    the render's futures there, which say so; the message alone, printed
    after "Done", only alarms.  (Workers of --cluster keep their logging.)"""
    from distributed.diagnostics.plugin import WorkerPlugin

    class QuietHeartbeat(WorkerPlugin):
        def setup(self, worker):
            log = logging.getLogger("distributed.worker")
            if _drop_heartbeat_lost not in log.filters:
                log.addFilter(_drop_heartbeat_lost)
    return QuietHeartbeat()


def close(client) -> None:
    """Close a Client made by :func:`connect` (and its local cluster)."""
    cluster = getattr(client, "_fppm_cluster", None)
    client.close()
    if cluster is not None:
        cluster.close()


def _chunked(renderer: Renderer) -> list:
    """The renderer's stages that split into chunks: its photon pass and its
    light tracer (LIGHT, COMBINED), when it has one."""
    lt = renderer.light_tracer or renderer.combined_lt
    return [renderer.photon_pass] + ([lt] if lt is not None else [])


def chunked_stages(renderer: Renderer) -> str:
    """What of the renderer's passes splits into chunks, for the log
    ("Photons: chunks of 131072", ...); "" when nothing does (PATH)."""
    lt = renderer.light_tracer or renderer.combined_lt
    parts = [f"light paths in chunks of {lt.chunk}"] if lt is not None else []
    if renderer.settings.integrator == "PHOTON" or renderer.merging:
        parts.append(f"{'merging ' * renderer.merging}photons in chunks of "
                     f"{renderer.photon_pass.chunk}")
    return " and ".join(parts).capitalize()


def local_chunk_streams(renderer: Renderer, chunk: Optional[int] = None) -> Renderer:
    """Make a single-process renderer draw one random stream per chunk (of
    photons and of light paths), the streams the workers use: its image
    equals the distributed render's.  chunk: photons or light paths per
    chunk (default: PHOTON_CHUNK, light_tracer.CHUNK)."""
    for stage in _chunked(renderer):
        stage.chunk_streams = True
        if chunk is not None:
            stage.chunk = int(chunk)
    return renderer


# ----------------------------------------------------------------------------
# What the driver sends
# ----------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class SceneJob:
    """(A dataclass, not a tuple: Dask would scatter a tuple's items one by one.)
    Sent once per render: the renderer's scene (after its clean-up and
    recentring, which are then no-ops), its settings, its plan as made
    (``Renderer.scene_plan``: the workers check they made the same) and a
    token naming the render."""
    token: str
    scene: object
    settings: object
    plan: object


@dataclasses.dataclass(frozen=True)
class PassJob:
    """Sent once per pass: what the gather reads of the active visible points
    (valid, with a radius), at their pixels idx (K,) int64: p, ng, albedo
    (K, 3), R2 (K,), const (K,); for the non-Lambert ones alone (their
    positions nc (J,) among the K) the BSDF inputs mat, colors, ns, wo and
    the depth of the receiver radius; frequency: False once the driver's
    photon pass has left out the holds (``PhotonPass.drop_frequency``, from
    the pass after pass 1 on), which the worker then does too; radius_cut:
    the driver's ``PhotonTracer.radius_cut`` for the pass (which occluders
    a frequency photon marches; inf with chunk streams, as in one process:
    ``DistributedPhotonPass.trace_ahead``).  The
    throughput beta and the film's first-hit data stay on the driver.  A
    Lambert point costs 89 bytes."""
    key: str
    idx: np.ndarray
    p: np.ndarray
    ng: np.ndarray
    albedo: np.ndarray
    R2: np.ndarray
    const: np.ndarray
    nc: np.ndarray
    mat: np.ndarray
    colors: np.ndarray
    ns: np.ndarray
    wo: np.ndarray
    depth: np.ndarray
    spectrum_aov: bool
    frequency: bool
    radius_cut: float

    @classmethod
    def pack(cls, key: str, vp, R2: np.ndarray, active: np.ndarray,
             spectrum_aov: bool, frequency: bool, radius_cut: float) -> "PassJob":
        idx = np.flatnonzero(active)
        nc = np.flatnonzero(~vp.const[idx])
        sub = idx[nc]
        return cls(key, idx, vp.p[idx], vp.ng[idx], vp.albedo[idx], R2[idx], vp.const[idx], nc,
                   vp.mat[sub], vp.colors[sub], vp.ns[sub], vp.wo[sub], vp.depth[sub],
                   spectrum_aov, frequency, float(radius_cut))

    def unpack(self):
        """(VisiblePoints (K,), R2 (K,)): the active points alone, every one
        valid; the BSDF inputs of the Lambert ones are zeros (never read)."""
        vp = VisiblePoints.empty(self.idx.size, self.colors.shape[1])
        vp.valid[:] = True
        vp.p[:], vp.ng[:], vp.albedo[:], vp.const[:] = self.p, self.ng, self.albedo, self.const
        nc = self.nc
        vp.mat[nc], vp.colors[nc], vp.ns[nc], vp.wo[nc], vp.depth[nc] = (
            self.mat, self.colors, self.ns, self.wo, self.depth)
        return vp, self.R2

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in dataclasses.astuple(self) if isinstance(a, np.ndarray))


# ----------------------------------------------------------------------------
# Worker side
# ----------------------------------------------------------------------------

class _SceneSide(Renderer):
    """The scene half of a Renderer (``Renderer._setup_scene``: BVH, lights,
    materials, plan, occlusion grid, photon tracer) and its photon pass,
    without the per-pixel state, camera pass and film."""

    def __init__(self, job: SceneJob):
        self.settings = job.settings
        self.log = lambda line: None
        self._should_stop = lambda: False
        self._setup_scene(job.scene, ())
        if self.plan != job.plan:
            raise RuntimeError("FPPM worker: the render plan differs from the driver's "
                               "(another FPPM version on this worker?)")
        # The driver builds an occlusion grid left for later (frequency_start
        # S > 1) in its step of pass S - 1 (Renderer._occlusion_before); a
        # worker runs no steps, and its chunks carry spectra from pass S on:
        # it builds the grid now.
        self._occlusion_before(self.settings.frequency_start - 1)
        freq = self.plan.frequency_photons
        radii = Radii(job.settings, None, self.D, freq, None, self.height, self.width)
        self.photon_pass = PhotonPass(self.tracer, self.mtab, job.settings, freq,
                                      radii.hist if radii.quantile else None,
                                      {"photon_trace": 0.0, "gather": 0.0})
        # COMBINED's photons are the merging ones (caustic paths alone), as
        # Renderer sets them.
        self.tracer.after_delta_only = (job.settings.integrator == "COMBINED"
                                        and MERGING in self.plan.strategies)
        self._light_tracer = None

    def light_tracer(self):
        """The light tracer of integrators LIGHT and COMBINED (built at the
        first light chunk), as Renderer builds it."""
        if self._light_tracer is None:
            from ..core.integrators.combined import CombinedLightTracer
            from ..core.integrators.light_tracer import LightTracer
            st = self.settings
            args = (self.scene, self.accel, self.mtab, self.light_table, self.camera, st,
                    self.plan, self.D, self.offset, (self.width, self.height),
                    self.scene.filter_width)
            self._light_tracer = (LightTracer(*args) if st.integrator == "LIGHT" else
                                  CombinedLightTracer(*args, camera_samples=st.camera_samples))
        return self._light_tracer


# Per worker process: the scene side of the current render and the grid of
# the current pass.  One task at a time per process (the tracer and the
# gather use the process's threads themselves).
_WORKER: dict = {}
_WORKER_LOCK = threading.Lock()


def _scene_side(job: SceneJob) -> _SceneSide:
    side = _WORKER.get("scene")
    if side is None or _WORKER.get("token") != job.token:
        _WORKER.clear()
        side = _SceneSide(job)
        _WORKER.update(scene=side, token=job.token)
    return side


@memory.small_pages
def setup_task(job: SceneJob, kernels: bool = False) -> int:
    """Build the scene side on this worker ahead of the first pass (and with
    ``kernels`` load every compiled kernel now, core.warmup, rather than
    each at its first call inside a pass); returns the worker's pid."""
    with _WORKER_LOCK:
        if kernels:
            from ..core import warmup
            warmup.compile_kernels()
        _scene_side(job)
    return os.getpid()


@memory.small_pages
def chunk_task(job: SceneJob, pj: PassJob, n: int, n_freq: int, rng):
    """Chunk sums (core.sppm.photon_pass.ChunkSums) of n photons (n_freq with
    a spectrum) traced with rng and gathered at the pass's visible points."""
    with _WORKER_LOCK:
        pp = _scene_side(job).photon_pass
        if pp.frequency and not pj.frequency:
            pp.drop_frequency()             # as the driver's did (Renderer._drop_holds)
        pp.tracer.radius_cut = pj.radius_cut
        if _WORKER.get("pass") != pj.key:
            # the last pass's grid dropped first: its kept buffers are then
            # reused (hashgrid.build_grid(..., buffers=)), not allocated again
            _WORKER.pop("grid", None)
            _WORKER.update(grid=pp.begin(*pj.unpack(), pj.spectrum_aov), **{"pass": pj.key})
        part = pp.chunk_sums(_WORKER["grid"], n, n_freq, rng)
    # From the active points' numbering back to the pixels'.
    return part._replace(idx=pj.idx[part.idx], spec_idx=pj.idx[part.spec_idx])


@memory.small_pages
def light_chunk_task(job: SceneJob, n_pass: int, n: int, rng) -> SplatSums:
    """Splat sums of n light paths (one chunk of a pass of n_pass) traced
    with rng (core.integrators.light_tracer.LightTracer.chunk_sums)."""
    with _WORKER_LOCK:
        return _scene_side(job).light_tracer().chunk_sums(n_pass, n, rng)


# ----------------------------------------------------------------------------
# Driver side
# ----------------------------------------------------------------------------

class Session:
    """The renderer's scene on the workers of ``client``: scattered once (a
    SceneJob broadcast) and, with warm, built on every current worker now
    rather than in the first pass (a worker that joins later builds it at
    its first chunk); load_kernels: load the compiled kernels there too
    (they otherwise load at their first call, inside pass 1)."""

    def __init__(self, client, renderer: Renderer, warm: bool = True,
                 load_kernels: bool = False):
        self.client = client
        self.token = uuid.uuid4().hex
        job = SceneJob(self.token, renderer.scene, renderer.settings, renderer.scene_plan)
        self.scene_future = client.scatter(job, broadcast=True, hash=False)
        if warm:
            workers = list(client.scheduler_info()["workers"])
            client.gather([client.submit(setup_task, self.scene_future, load_kernels,
                                         workers=[w], allow_other_workers=False, pure=False,
                                         key=f"fppm-setup-{self.token}-{i}")
                           for i, w in enumerate(workers)])

    def reduce(self, futures, add, check_stop) -> tuple[int, float]:
        """add(result) of every future in turn (in chunk order: the same sums
        as one process), polling check_stop meanwhile; cancel them all on
        any exception.  Returns (bytes returned, seconds spent in add)."""
        returned, seconds = 0, 0.0
        try:
            for f in futures:
                part = self.result(f, check_stop)
                t0 = time.perf_counter()
                add(part)
                seconds += time.perf_counter() - t0
                returned += part.nbytes
        except BaseException:
            self.client.cancel(futures)
            raise
        return returned, seconds

    @staticmethod
    def result(future, check_stop):
        """The future's result, polling check_stop (RenderCancelled) meanwhile."""
        # A done-callback and an Event rather than result(timeout=...): a
        # timed-out result() could fail inside distributed's sync() while a
        # worker was being replaced.
        done = threading.Event()
        future.add_done_callback(lambda f: done.set())
        while not done.wait(POLL):
            check_stop()
        check_stop()
        return future.result()

    def release(self) -> None:
        """Release the scene on the workers (the client stays open)."""
        self.scene_future.release()

class PassStats(NamedTuple):
    """One distributed photon pass: bytes broadcast (visible points and
    radii, sent to every worker), bytes returned (the chunk sums, all of
    them), seconds the driver spent adding the sums, wall seconds of the
    whole photon pass, chunks."""
    broadcast_bytes: int
    returned_bytes: int
    add_seconds: float
    wall_seconds: float
    chunks: int


class DistributedPhotonPass:
    """Takes the place of ``renderer.photon_pass`` (same call, same
    PhotonEstimate): the chunks of every pass go to the Dask workers of
    ``client``.  ``local``: the renderer's own PhotonPass (chunking, the
    empty pass, the throughput).  ``rays``: rays cast by the workers;
    ``stats``: a PassStats per distributed pass.  warm, load_kernels: as
    :class:`Session` (session: one shared with other stages, else its own)."""

    #: No reach map: the workers trace the chunks (PhotonPass.keeps_reach).
    keeps_reach = False

    def __init__(self, client, renderer: Renderer, warm: bool = True,
                 load_kernels: bool = False, retries: int = 3,
                 session: Optional[Session] = None):
        self.client, self.renderer, self.retries = client, renderer, retries
        self.local: PhotonPass = renderer.photon_pass
        self.stage_seconds = renderer.stage_seconds
        self.rays = self.local.rays
        self.stats: list[PassStats] = []
        self.own_session = session is None
        self.session = session or Session(client, renderer, warm, load_kernels)
        self.token, self.scene_future = self.session.token, self.session.scene_future
        self._passes = 0
        self.pending: list = []          # the futures of the pass under way
        renderer.photon_pass = self

    def __call__(self, vp, R2: np.ndarray, spectrum: Optional[np.ndarray],
                 rng: np.random.Generator, check_stop=lambda: None) -> PhotonEstimate:
        t_pass = time.perf_counter()
        local = self.local
        active = local.active(vp, R2)
        if not np.any(active):
            return local(vp, R2, spectrum, rng, check_stop)     # traces nothing
        client = self.client
        self._passes += 1
        tag = f"{self.token}-{self._passes}"
        pj = PassJob.pack(tag, vp, R2, active, spectrum is not None, local.frequency,
                          local.tracer.radius_cut)
        pass_future = client.scatter(pj, broadcast=True, hash=False)
        # Ahead of light chunks submitted for the next pass (COMBINED's
        # merging waits for these now; DistributedLightTracer.prefetch).
        futures = [client.submit(chunk_task, self.scene_future, pass_future, n, n_freq,
                                 chunk_rng(rng, c), key=f"fppm-chunk-{tag}-{c}",
                                 retries=self.retries, pure=False, priority=1)
                   for c, (n, n_freq) in enumerate(local.chunks())]
        self.pending = futures
        acc = PassSums.zeros(vp.valid.shape[0], local.radius_histogram is not None, spectrum,
                             local.sectors)

        def add(part):
            acc.add(part)
            self.rays += part.rays
            self.stage_seconds["photon_trace"] += part.trace_seconds
            self.stage_seconds["gather"] += part.gather_seconds
        try:
            returned, add_seconds = self.session.reduce(futures, add, check_stop)
        finally:
            self.pending = []
            del pass_future
        est = local.finish(vp, acc)
        self.stats.append(PassStats(pj.nbytes, returned, add_seconds,
                                    time.perf_counter() - t_pass, len(futures)))
        return est

    def trace_ahead(self, rng: np.random.Generator, then=None) -> None:
        """Before the camera stage (Renderer.step): the local pass's
        ``PhotonPass.trace_ahead``, which with chunk streams traces nothing
        ahead and sets the pass's radius cut (inf: no reach map), as a
        one-process render with the same chunks does; the workers receive
        that cut in the PassJob."""
        self.local.trace_ahead(rng, then)

    def drop_frequency(self) -> None:
        """The holds left out (``Renderer._drop_holds``): the local pass
        drops its frequency photons and sector counts, and the next PassJob
        tells the workers to do the same."""
        self.local.drop_frequency()

    def close(self) -> None:
        """Release the scene on the workers (the client stays open)."""
        if self.own_session:
            self.session.release()
        self.renderer.photon_pass = self.local


class DistributedLightTracer:
    """Takes the place of a renderer's light tracer (``light_tracer`` of
    LIGHT, ``combined_lt`` of COMBINED; same ``trace_pass``): the chunks of
    light paths of every pass go to the workers of the session, their splat
    sums are added in chunk order.  ``local``: the renderer's own tracer
    (chunking; ``chunk_streams`` must be on: :func:`local_chunk_streams`).
    ``rays``: rays cast by the workers; ``stats``: a PassStats per pass
    (nothing broadcast); ``pending``: the futures of the pass under way.

    prefetch: once pass k's chunks are in, submit pass k+1's (its stream is
    ``renderer._rng(k + 1, 2)``, as Renderer draws it) unless the render
    ends at pass k (``max_passes``); a pass asked with another stream or
    size cancels them and submits its own."""

    def __init__(self, session: Session, renderer: Renderer, retries: int = 3,
                 prefetch: bool = False):
        self.session, self.renderer, self.retries = session, renderer, retries
        self.attr = "light_tracer" if renderer.light_tracer is not None else "combined_lt"
        self.local = getattr(renderer, self.attr)
        if not self.local.chunk_streams:
            raise ValueError("DistributedLightTracer: call local_chunk_streams first")
        self.prefetch = prefetch
        self.rays = self.local.rays
        self.stats: list[PassStats] = []
        self.pending: list = []
        self._ahead = None               # (key of the stream, n, futures) submitted ahead
        setattr(renderer, self.attr, self)

    @staticmethod
    def _stream_key(rng) -> tuple:
        ss = rng.bit_generator.seed_seq
        return tuple(np.atleast_1d(ss.entropy).tolist()), tuple(ss.spawn_key)

    def _submit(self, n: int, rng) -> list:
        client, job = self.session.client, self.session.scene_future
        tag = f"{self.session.token}-{'-'.join(map(str, self._stream_key(rng)[0]))}-{n}"
        return [client.submit(light_chunk_task, job, n, k, chunk_rng(rng, c),
                              key=f"fppm-light-{tag}-{c}", retries=self.retries, pure=False)
                for c, k in enumerate(self.local.chunks(n))]

    def trace_pass(self, n: int, rng, check_stop=lambda: None) -> np.ndarray:
        """The splat sums (H*W, 3) of a pass of n light paths drawn from rng
        (``LightTracer.trace_pass`` with chunk streams, on the workers)."""
        t_pass = time.perf_counter()
        key = self._stream_key(rng)
        ahead, self._ahead = self._ahead, None
        if ahead is not None and ahead[:2] == (key, n):
            futures = ahead[2]
        else:
            if ahead is not None:
                self.session.client.cancel(ahead[2])
            futures = self._submit(n, rng)
        self.pending = futures
        film = np.zeros((self.local.H * self.local.W, 3))

        def add(part):
            part.add_to(film)
            self.rays += part.rays
        try:
            returned, add_seconds = self.session.reduce(futures, add, check_stop)
        finally:
            self.pending = []
        self._submit_next(n)
        self.stats.append(PassStats(0, returned, add_seconds, time.perf_counter() - t_pass,
                                    len(futures)))
        return film

    def in_flight(self) -> list:
        """The futures of the pass under way and of the pass submitted ahead."""
        return list(self.pending) + (list(self._ahead[2]) if self._ahead is not None else [])

    def _submit_next(self, n: int) -> None:
        r = self.renderer
        k = r.pass_index + 2               # the pass after the one just traced
        if self.prefetch and not (r.settings.max_passes and k > r.settings.max_passes):
            rng = r._rng(k, 2)
            self._ahead = (self._stream_key(rng), n, self._submit(n, rng))

    def close(self) -> None:
        """Cancel the chunks submitted ahead; give the renderer its tracer back."""
        if self._ahead is not None:
            self.session.client.cancel(self._ahead[2])
            self._ahead = None
        setattr(self.renderer, self.attr, self.local)


def distribute(client, renderer: Renderer, warm: bool = True, load_kernels: bool = False,
               prefetch: bool = False) -> list:
    """Hand the renderer's chunked stages to the workers of client (module
    doc); the renderer must draw chunk streams (:func:`local_chunk_streams`).
    Returns the stages installed ([] for PATH, or a COMBINED plan with
    neither light tracing nor merging); close each, then the session
    (``stages[0].session.release()``), to release the scene."""
    lt = renderer.light_tracer or renderer.combined_lt
    photons = renderer.settings.integrator == "PHOTON" or renderer.merging
    if lt is None and not photons:
        return []
    session = Session(client, renderer, warm, load_kernels)
    stages = [DistributedLightTracer(session, renderer, prefetch=prefetch)] if lt else []
    if photons:
        stages.append(DistributedPhotonPass(client, renderer, session=session))
    return stages
