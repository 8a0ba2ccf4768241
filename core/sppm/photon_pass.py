"""The photon pass of one SPPM pass: trace photons, gather them at the visible points.

    photon_pass = PhotonPass(tracer, mtab, settings, frequency, radius_histogram, stage_seconds)
    est = photon_pass(vp, R2, spectrum, rng, check_stop)

Photons are traced (core.sppm.photons) in chunks of PHOTON_CHUNK, so memory
stays bounded and a cancel is seen between chunks; each chunk is gathered
(core.sppm.hashgrid) into the grid of this pass's visible points and their
radii.  A photon counts for every visible point whose sphere it falls in
(cos_ng = -1: every surface inside the sphere, pbrt-v4 SPPM, but only from the
camera's side: rejecting the adjacent wall's photons darkened Cornell-box
corners against Cycles, docs/method.md).  The estimate is pass-local: the
renderer commits it only once the pass is complete, so a cancelled pass
leaves no trace.

The trace does not depend on the visible points: ``trace_ahead`` starts a
pass's chunks in a thread of their own before the camera pass, and the
gather takes them in order (the same photons).  When the next pass's photons
need nothing from this one (no frequency photons: no reach map, no radius
cut), its first chunk starts as soon as this pass's last chunk is traced
(``trace_ahead(..., then=)``): under this pass's gathers, update and film.

A chunk is also the unit of work another process can do
(tools/distributed.py): with ``chunk_streams`` each chunk draws its own
random stream (``chunk_rng``) and its sums (``chunk_sums``) are added in
chunk order (``PassSums.add``), whichever process traced it.
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple, Optional

import numpy as np

from .. import materials as B
from ..kept import KeptArrays, KeptBuffers
from ..frequency.kernels import Receivers
from . import clip as kernel_clip
from . import hashgrid
from .update import HIST_BINS, needs_sectors

PHOTON_CHUNK = 131_072
#: _reflected sums at the touched points alone when there are fewer than
#: P / REFLECTED_DENSE_FRACTION pairs (sorting them is then cheaper than
#: three passes over P points).
REFLECTED_DENSE_FRACTION = 8
#: _reflected and the receivers' radii evaluate the BSDF of the pairs in
#: compiled loops (core.sppm.reflected_kernels, core.materials.compiled)
#: rather than with numpy (1-2 us a pair; the same values to rounding).
COMPILED_BSDF = True


#: ``PhotonPass.trace_ahead`` traces a pass's photons while its camera and
#: direct light run (False: each chunk is traced where it is gathered; the
#: same image either way).
TRACE_AHEAD = True
#: Chunks queued ahead of the one being gathered: the trace of chunk 0
#: overlaps the camera and direct light, that of chunk c + 1 the gather of
#: chunk c; a cancelled pass or dropped renderer leaves at most this many
#: chunks tracing in the background (and the next trace_ahead waits for them).
AHEAD_CHUNKS = 2
#: With trace-ahead, the next pass's chunks are queued behind this pass's
#: last one (``trace_ahead(..., then=)``), AHEAD_CHUNKS ahead of the gather
#: as before: traced under this pass's grid build, gathers, update and film,
#: which run on one core in part.  Only for a next pass without frequency
#: photons (theirs read this pass's radii).  False: each pass starts its
#: trace in its own ``trace_ahead``.
TRACE_NEXT_PASS = True
_AHEAD = None


def _ahead_executor():
    """The one thread that traces passes ahead (``PhotonPass.trace_ahead``);
    its traces split their halves over core.sppm.photons' pool, like the others."""
    global _AHEAD
    if _AHEAD is None:
        from concurrent.futures import ThreadPoolExecutor
        _AHEAD = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fppm-ahead")
    return _AHEAD


class PhotonEstimate(NamedTuple):
    """This pass's photons at the visible points (P pixels).

    gathered: False when no visible point was active (nothing traced).
    M (P,) float64 photons counted; Phi (P, 3) float64 their reflected flux
      (BSDF x power, times the visible point's throughput beta).
    r_pred_min (P,) float64 smallest predicted radius of a counted frequency
      photon [m] (inf = none; negated with the PAPER model).
    r_hist (P, HIST_BINS) uint32 counts of the predicted radii of the counted
      frequency photons (core.sppm.update.RadiusHistogram), or None.
    spectrum (P, 3) float64 the spectrum AOV after this pass, or None.
    sectors (P, SECTOR_CELLS) float64 photons counted per sector cell of each
      kernel disc (core.sppm.hashgrid), or None unless the radius rule needs
      them (core.sppm.update.needs_sectors).
    """
    gathered: bool
    M: np.ndarray
    Phi: np.ndarray
    r_pred_min: np.ndarray
    r_hist: Optional[np.ndarray] = None
    spectrum: Optional[np.ndarray] = None
    sectors: Optional[np.ndarray] = None


def chunk_rng(rng: np.random.Generator, c: int) -> np.random.Generator:
    """The stream of chunk c of a pass whose stream is rng: the c-th child of
    rng's SeedSequence (numpy's spawn key), so a chunk's photons depend on
    (seed, pass, chunk) alone, not on the process that traces it or when."""
    ss = rng.bit_generator.seed_seq
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(
        ss.entropy, spawn_key=tuple(ss.spawn_key) + (int(c),), pool_size=ss.pool_size)))


class PassGrid(NamedTuple):
    """What every chunk of a pass gathers into (``PhotonPass.begin``): the
    visible points vp, their squared radii R2 (P,), the grid of the active
    ones, whether the frequency pairs are needed, whether the spectrum AOV is
    on, and the packed clips of the kernel discs (P,) uint64
    (core.sppm.clip; None: settings.clip_kernel off)."""
    vp: object
    R2: np.ndarray
    grid: object
    want_pairs: bool
    spectrum_aov: bool
    clip: Optional[np.ndarray] = None


class ChunkSums(NamedTuple):
    """One chunk's sums at the pixels it touched (``PassSums.sparse``).

    idx (T,) int64 touched pixels; M (T,), Phi (T, 3) (before the throughput
    beta), r_pred (T,) float64; hist (T, HIST_BINS) uint32 or None;
    spec_idx (S,) int64 pixels whose spectrum the chunk set, spec (S, 3);
    rays cast, trace and gather seconds (for the statistics).
    """
    idx: np.ndarray
    M: np.ndarray
    Phi: np.ndarray
    r_pred: np.ndarray
    hist: Optional[np.ndarray]
    spec_idx: np.ndarray
    spec: np.ndarray
    sectors: Optional[np.ndarray] = None
    rays: int = 0
    trace_seconds: float = 0.0
    gather_seconds: float = 0.0

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.idx, self.M, self.Phi, self.r_pred, self.hist,
                                      self.spec_idx, self.spec, self.sectors) if a is not None)


@dataclass
class PassSums:
    """A pass's accumulators (P pixels): M (P,), Phi (P, 3) before beta,
    r_pred (P,) float64; hist (P, HIST_BINS) uint32 or None; spec (P, 3) or
    None; spec_set (P,) bool: pixels whose spec a chunk set (chunk sums only)."""
    M: np.ndarray
    Phi: np.ndarray
    r_pred: np.ndarray
    hist: Optional[np.ndarray] = None
    spec: Optional[np.ndarray] = None
    spec_set: Optional[np.ndarray] = None
    sectors: Optional[np.ndarray] = None

    @classmethod
    def zeros(cls, P: int, hist: bool, spectrum: Optional[np.ndarray],
              sectors: bool = False) -> "PassSums":
        """Empty sums; spectrum (P, 3): the committed spectrum AOV (copied), or None;
        sectors: with the photons' sector counts (P, hashgrid.SECTOR_CELLS) float64."""
        return cls(np.zeros(P), np.zeros((P, 3)), np.full(P, np.inf),
                   np.zeros((P, HIST_BINS), np.uint32) if hist else None,
                   None if spectrum is None else spectrum.copy(),
                   sectors=np.zeros((P, hashgrid.SECTOR_CELLS)) if sectors else None)

    def sparse(self, rays=0, trace_seconds=0.0, gather_seconds=0.0) -> ChunkSums:
        """These sums at the pixels they touch (what a worker sends back)."""
        touched = (self.M != 0) | np.any(self.Phi != 0, axis=1) | (self.r_pred != np.inf)
        if self.hist is not None:
            touched |= np.any(self.hist != 0, axis=1)
        if self.sectors is not None:
            touched |= np.any(self.sectors != 0, axis=1)
        idx = np.flatnonzero(touched)
        spec_idx = (np.zeros(0, np.int64) if self.spec_set is None
                    else np.flatnonzero(self.spec_set))
        return ChunkSums(idx, self.M[idx], self.Phi[idx], self.r_pred[idx],
                         None if self.hist is None else self.hist[idx], spec_idx,
                         np.zeros((0, 3)) if self.spec is None else self.spec[spec_idx],
                         None if self.sectors is None else self.sectors[idx],
                         rays, trace_seconds, gather_seconds)

    def add(self, part: ChunkSums) -> None:
        """Add the next chunk's sums (chunks are added in chunk order: the
        float sums, and the spectrum a later chunk overwrites, depend on it)."""
        i = part.idx
        self.M[i] += part.M
        self.Phi[i] += part.Phi
        self.r_pred[i] = np.minimum(self.r_pred[i], part.r_pred)
        if self.hist is not None:
            self.hist[i] += part.hist
        if self.spec is not None:
            self.spec[part.spec_idx] = part.spec
        if self.sectors is not None:
            self.sectors[i] += part.sectors


#: With amortised frequency photons (frequency_decay > 0) only the passes
#: k = 1, 2, 4, 8, ... trace any (:func:`frequency_passes`); the other passes
#: keep every pixel's last prediction (docs/method.md "Rings under a 1 m
#: light", "Frequency photons in doubling passes").
DOUBLING_PASSES = True


def frequency_pass(k: int) -> bool:
    """Whether pass k (1-based) traces frequency photons under the doubling
    schedule: k a power of two.  A pass with frequency photons pays for their
    spectra, the reach map and the frequency pairs whatever their number
    (docs/method.md "Frequency photons in doubling passes"); a pass of the
    same k^-decay count keeps the spectra's statistics where it is traced."""
    k = max(int(k), 1)
    return k & (k - 1) == 0


def frequency_photons(settings, k: int, doubling: bool = False) -> int:
    """Photons of pass k (1-based) that carry a spectrum: photons_per_pass x
    frequency_fraction x k^-frequency_decay (docs/method.md "Amortised
    frequency photons": the spectrum belongs to the light field at the pixel,
    not to the pass, so a pixel keeps its prediction and later passes need
    fewer frequency photons; decay 0: the same fraction in every pass);
    doubling (with decay > 0): none unless :func:`frequency_pass`.
    With frequency_start S > 1 the schedule runs from pass S: none before
    it, and pass k >= S traces what pass k / S does from 1 (so passes S, 2S,
    4S, ... under doubling, and the schedule's total is S = 1's; docs/method.md
    "A late start for the frequency photons, round 18")."""
    S = int(getattr(settings, "frequency_start", 1))
    doubles = doubling and settings.frequency_decay > 0
    k = max(int(k), 1)
    if k < S or (doubles and k % S):
        return 0
    # Pass k traces at the rate of pass k / S from 1 (a whole number under doubling).
    x = k // S if doubles else k / S
    if doubles and not frequency_pass(x):
        return 0
    f = settings.frequency_fraction * float(x) ** -settings.frequency_decay
    return int(round(settings.photons_per_pass * f))


class PhotonPass:
    """tracer: core.sppm.photons.PhotonTracer; mtab: material table; settings:
    RenderSettings; frequency: the plan traces frequency photons;
    radius_histogram: core.sppm.update.RadiusHistogram when the QUANTILE
    estimator needs the predicted radii, else None; stage_seconds: dict whose
    "photon_trace" and "gather" entries accumulate wall seconds.
    ``rays``: rays cast by the tracer so far."""

    def __init__(self, tracer, mtab, settings, frequency: bool, radius_histogram,
                 stage_seconds: dict):
        self.tracer, self.mtab, self.settings = tracer, mtab, settings
        self.frequency, self.radius_histogram = frequency, radius_histogram
        self.stage_seconds = stage_seconds
        self.rays = 0
        # Photons per chunk, and one random stream per chunk (chunk_rng) rather
        # than one per pass: chunks then split over processes
        # (tools/distributed.py) and give the same image in any of them.
        self.chunk = PHOTON_CHUNK
        self.chunk_streams = False
        # Non-Lambert visible points: the radius for their own receiver lobes.
        self.receivers = Receivers(mtab) if frequency else None
        self.sectors = needs_sectors(settings, frequency)
        # Per-thread gather accumulators, allocated at the first chunk and
        # reused by every chunk of every pass (hashgrid.GatherBuffers).
        self.gather_buffers: Optional[hashgrid.GatherBuffers] = None
        self._kept = KeptArrays()
        # The grid's arrays, the build's temporaries and the gather's
        # visible-point records, kept from pass to pass (hashgrid.build_grid,
        # GatherBuffers.kept).
        self._grid_kept = KeptBuffers()
        # trace_ahead's (rng, futures of the queued chunks' deposits, chunks
        # not queued yet, then), or None.
        self._ahead = None
        # The next pass's chunks queued early (_start_next): (rng, futures,
        # chunks not queued yet, its chunks), or None; how many passes
        # carried on with them (trace_ahead).
        self._next = None
        self.next_adopted = 0
        # Futures of dropped chunks still running (_drop(wait=False)): the
        # next trace_ahead waits for them before its own chunks queue.
        self._orphans = []
        # The 1-based index of the pass being traced (its share of frequency
        # photons, frequency_photons); the renderer sets it to its own count.
        self.next_pass = lambda: 1
        # Frequency photons only in the passes 1, 2, 4, 8, ... (frequency_pass).
        self.doubling = DOUBLING_PASSES
        # CPU seconds of the kernel clip's rays and codes (core.sppm.clip),
        # also counted in stage_seconds["gather"].
        self.clip_seconds = 0.0
        # None, or a callable run right after the set-up (grid build) of the
        # next call: the pass's direct-light blocks left over by the thread
        # that took them beside the set-up (core.render.DIRECT_BESIDE_SETUP).
        self.beside = None
        # _reflected's per-point sums (P, 3), all zero between calls.
        self._reflected_scratch = None

    def __call__(self, vp, R2: np.ndarray, spectrum: Optional[np.ndarray],
                 rng: np.random.Generator, check_stop=lambda: None) -> PhotonEstimate:
        """Photons of one pass at the visible points vp with squared radii R2
        (P,) (0 = none yet); spectrum (P, 3): the committed spectrum AOV (None:
        no spectrum AOV).  check_stop() is called before every chunk.
        With ``chunk_streams`` chunk c is traced with ``chunk_rng(rng, c)`` and
        its sums are added in chunk order (``chunk_sums``, ``PassSums.add``):
        what another process computes for that chunk."""
        P = vp.valid.shape[0]
        acc = self._zero_sums(P, spectrum)
        pg = self.begin(vp, R2, spectrum is not None, check_stop)
        if self.beside is not None:
            # other work of the pass, shared with a thread that ran it beside
            # the set-up (core.render.DIRECT_BESIDE_SETUP): what is left of it
            # before the gathers
            self.beside()
        if pg is None:
            self._drop_ahead()
            return PhotonEstimate(False, acc.M, acc.Phi, acc.r_pred)
        for c, (n, n_freq) in enumerate(self.chunks()):
            check_stop()
            if self.chunk_streams:
                acc.add(self.chunk_sums(pg, n, n_freq, chunk_rng(rng, c)))
            else:
                self._trace_gather(pg, n, n_freq, rng, acc)
        self._drop_ahead()
        self.keep_reach_source(vp, R2)
        return self.finish(vp, acc)

    def drop_frequency(self) -> None:
        """From the next pass on, PPM's photon pass: no frequency photons, no
        sector counts, no receiver radii (core.sppm.update.Radii.leave_out_holds)."""
        self.frequency = False
        self.sectors = False
        self.receivers = None
        self._reach_source = None

    def keep_reach_source(self, vp, R2: np.ndarray) -> None:
        """Keep this pass's visible points vp and the state's radii R2 (the
        array itself, updated in place after the pass): the next pass's
        :meth:`trace_ahead` builds the tracer's reach map from them
        (``PhotonTracer.set_reach``).  A resumed render calls this with the
        last pass's visible points, rebuilt from its camera stream, and the
        checkpointed radii: the same map.  Not with chunk_streams (other
        processes trace those chunks)."""
        if self.keeps_reach and self.tracer.uses_reach():
            # copies (vp's arrays may be reused), into the last pass's buffers
            kept = getattr(self, "_reach_kept", None)
            if kept is None or kept[0].shape != vp.p.shape:
                kept = self._reach_kept = (np.empty(vp.p.shape), np.empty(vp.valid.shape, bool))
            np.copyto(kept[0], vp.p)
            np.copyto(kept[1], vp.valid)
            self._reach_source = (kept[0], kept[1], R2)

    @property
    def keeps_reach(self) -> bool:
        """Whether :meth:`keep_reach_source` keeps anything: frequency
        photons traced here (not in other processes' chunk streams)."""
        return self.frequency and not self.chunk_streams

    def trace_ahead(self, rng: np.random.Generator, then=None) -> None:
        """Start tracing the chunks of the pass whose stream is rng now, one
        after the other in a thread of their own, AHEAD_CHUNKS ahead of the
        gather: the trace does not depend on the visible points (only the
        gather does), so it overlaps the camera and direct-light stages and
        then the gather.  The next call with this very rng gathers them in
        chunk order: the same photons as tracing them there (the same
        stream, drawn in the same order).  Not with ``chunk_streams`` (each
        chunk is traced where it is gathered).

        then: None, or a callable returning the next pass's photon stream (a
        new Generator, the one the next pass will call this with, or None):
        once every chunk of this pass is queued, the next pass's chunks
        follow with it in the same queue (TRACE_NEXT_PASS; only when the next
        pass has no frequency photons), still at most AHEAD_CHUNKS ahead of
        the gather.  A call with that rng carries on with what was started;
        a call with another drops it."""
        self._drop_ahead()
        orphans, self._orphans = self._orphans, []
        for f in orphans:                   # a dropped render's chunk, still running
            f.exception()
        nxt, self._next = self._next, None
        if nxt is not None:
            if nxt[0] is rng and nxt[3] == self.chunks() and not self.chunk_streams:
                # started under the last pass (_start_next): a pass without
                # frequency photons, so no reach map to set
                self._reach_source = None
                self._ahead = nxt[:3] + (then,)
                self.next_adopted += 1
                self._fill_ahead()
                return
            self._drop(nxt[1])
        src = getattr(self, "_reach_source", None)
        self._reach_source = None
        if any(f for _, f in self.chunks()):
            # The reach map and the radius cut of a pass with frequency
            # photons, set once here, before any of its chunks is traced:
            # from the last pass's visible points and the radii of its
            # update (R2 not yet initialised for this pass's new pixels), the
            # same with or without trace-ahead and after a resume; the first
            # pass, with no radii yet, marches every occluder (cut inf).
            # Setting the cut later, once this pass's radii are initialised,
            # raced with the chunks already tracing (docs/frequency.md
            # "One radius cut a pass").
            if src is not None:
                self.tracer.set_reach(src[0], src[1], np.array(src[2]))
                self.tracer.set_radius_cut(src[2])
            else:
                self.tracer.set_radius_cut(np.zeros(0))
        if self.chunk_streams or not TRACE_AHEAD:
            return
        self._ahead = (rng, deque(), deque(self.chunks()), then)
        self._fill_ahead()

    def _fill_ahead(self) -> None:
        """Queue chunks (in chunk order: one thread, one stream) until
        AHEAD_CHUNKS are queued and not yet taken by the gather: this pass's,
        then the next pass's (_start_next)."""
        rng, futures, todo, then = self._ahead
        while True:
            queued = len(futures) + (len(self._next[1]) if self._next is not None else 0)
            if queued >= AHEAD_CHUNKS:
                return
            if todo:
                n, n_freq = todo.popleft()
                futures.append(_ahead_executor().submit(self._trace_now, n, n_freq, rng))
                continue
            if self._next is None:
                if then is None or not self._start_next(then):
                    return
            nrng, nfut, ntodo, _ = self._next
            if not ntodo:
                return
            n, n_freq = ntodo.popleft()
            nfut.append(_ahead_executor().submit(self._trace_now, n, n_freq, nrng))

    def _start_next(self, then) -> bool:
        """Open the next pass's queue with the stream then(), when its photons
        need nothing from this pass: no frequency photons (their reach map
        and radius cut come from this pass's radii).  False: not opened."""
        if not TRACE_NEXT_PASS:
            return False
        chunks = self.chunks(self.next_pass() + 1)
        if not chunks or any(f for _, f in chunks):
            return False
        rng = then()
        if rng is None:
            return False
        self._next = (rng, deque(), deque(chunks), chunks)
        return True

    def _drop(self, futures, wait: bool = True) -> None:
        """Cancel the queued traces of futures, wait for the one running
        (wait=False: the next trace_ahead waits for it, as for a cancelled
        pass's, before its own chunks queue behind it)."""
        futures = list(futures)
        for f in futures:
            f.cancel()
        running = [f for f in futures if not f.cancelled()]
        if not wait:
            self._orphans = self._orphans + running
            return
        for f in running:
            f.exception()

    def settle(self) -> None:
        """Wait until every chunk queued ahead (this pass's, and the next
        pass's queued behind its last one) is traced; nothing is taken or
        dropped, so the next pass gathers them as it would have.  Between
        passes the trace-ahead thread goes on tracing the next pass's
        chunks: a caller that times the passes by the process's CPU and
        leaves out its own work between them (``fppm converge``'s metrics)
        calls this first, so that the trace's CPU is the pass's, not the
        metrics' (docs/method.md "The convergence runs' CPU clock, round 22")."""
        for queue in (self._ahead, self._next):
            if queue is not None:
                for f in list(queue[1]):
                    f.exception()             # waits; a failure is raised where it is taken

    def _drop_ahead(self) -> None:
        """Cancel the chunks traced ahead and not started, wait for the one
        running (a pass that was cancelled or found no visible point).  The
        next pass's chunk started early stays (trace_ahead adopts or drops it)."""
        if self._ahead is not None:
            futures, self._ahead = self._ahead[1], None
            self._drop(futures)

    def drop_next(self, wait: bool = True) -> None:
        """Drop every chunk queued ahead: the next pass's, and those of a
        pass that was cancelled (the render is over, or its state was
        replaced); wait=False: the one running finishes in its thread,
        unwaited (its deposits are then dropped), as after a cancel."""
        for queue in (self._ahead, self._next):
            if queue is not None:
                self._drop(queue[1], wait)
        self._ahead = self._next = None

    def _zero_sums(self, P: int, spectrum: Optional[np.ndarray]) -> "PassSums":
        """``PassSums.zeros`` of a pass, on the last pass's arrays when the
        renderer has dropped them (core.kept: the serial fold no longer
        page-faults fresh pixel-sized sums in every pass).  M is new every
        pass: the state keeps it (``PixelState.M_last``)."""
        hist = self.radius_histogram is not None
        names = ("Phi", "r_pred") + ("hist",) * hist + ("sectors",) * self.sectors

        def make():
            z = PassSums.zeros(P, hist, None, self.sectors)
            return [getattr(z, n) for n in names]
        a = self._kept.get(make, (P, hist, self.sectors))
        from . import pass_kernels
        return PassSums(M=pass_kernels.zeros(P), **dict(zip(names, a)),
                        spec=None if spectrum is None else spectrum.copy())

    def active(self, vp, R2: np.ndarray) -> np.ndarray:
        """(P,) bool: the visible points that gather this pass (valid, with a radius)."""
        return vp.valid & (R2 > 0)

    def chunks(self, k: Optional[int] = None) -> list[tuple[int, int]]:
        """(n, n_freq) of every chunk of pass k (default ``next_pass()``, the
        pass being traced): ``chunk`` photons each (the last one fewer); the
        first :func:`frequency_photons` of the pass carry a spectrum."""
        st = self.settings
        n_total = st.photons_per_pass
        n_freq_total = (frequency_photons(st, self.next_pass() if k is None else k,
                                          self.doubling)
                        if self.frequency else 0)
        out = []
        for a in range(0, n_total, self.chunk):
            n = min(self.chunk, n_total - a)
            out.append((n, int(np.clip(n_freq_total - a, 0, n))))
        return out

    def begin(self, vp, R2: np.ndarray, spectrum_aov: bool,
              check_stop=lambda: None) -> Optional["PassGrid"]:
        """The grid of this pass's active visible points (None: none is active).
        The mask (:meth:`active`) and the radii sqrt(R2) in one compiled loop
        over the pixels (core.sppm.pass_kernels); check_stop() is called
        between the kernel clip's blocks of rays and the grid build's phases."""
        from . import pass_kernels
        active, R, n_active = pass_kernels.active_radii(vp.valid, R2)
        if self.gather_buffers is not None:
            # unbind: a pass stopped in its gather left its records in the
            # buffer the build reuses
            self.gather_buffers.clear()
            self.gather_buffers.unbind()
        if n_active == 0:
            return None
        want_pairs = self.frequency and (self.radius_histogram is not None or spectrum_aov)
        clip = None
        if self.settings.clip_kernel:
            t0, c0 = time.perf_counter(), time.process_time()
            clip = kernel_clip.clip_codes(self.tracer.accel, self.tracer.tris.ng, vp.p, vp.ng,
                                          R2, active, check_stop)
            self.clip_seconds += time.process_time() - c0
            self.stage_seconds["gather"] += time.perf_counter() - t0
        grid = hashgrid.build_grid(vp.p, R, active, buffers=self._grid_kept,
                                   check_stop=check_stop)
        return PassGrid(vp, R2, grid, want_pairs, spectrum_aov, clip)

    def chunk_sums(self, pg: "PassGrid", n: int, n_freq: int,
                   rng: np.random.Generator) -> "ChunkSums":
        """Trace one chunk of n photons (n_freq with a spectrum) with rng and
        gather it into pg: its sums alone (ChunkSums), for ``PassSums.add``."""
        P = pg.vp.valid.shape[0]
        part = PassSums.zeros(P, self.radius_histogram is not None,
                              np.zeros((P, 3)) if pg.spectrum_aov else None, self.sectors)
        part.spec_set = None if part.spec is None else np.zeros(P, bool)
        rays0 = self.rays
        t = self.stage_seconds["photon_trace"], self.stage_seconds["gather"]
        self._trace_gather(pg, n, n_freq, rng, part)
        return part.sparse(self.rays - rays0, self.stage_seconds["photon_trace"] - t[0],
                           self.stage_seconds["gather"] - t[1])

    def finish(self, vp, acc: "PassSums") -> PhotonEstimate:
        """The pass's estimate from its summed chunks (Phi times the visible
        points' throughput, once; core.sppm.pass_kernels: numba threads)."""
        from . import pass_kernels
        pass_kernels.scale_by_beta(acc.Phi, vp.beta)
        if self.gather_buffers is not None:
            self.gather_buffers.unbind()
        return PhotonEstimate(True, acc.M, acc.Phi, acc.r_pred, acc.hist, acc.spec, acc.sectors)

    def _trace_gather(self, pg: "PassGrid", n: int, n_freq: int, rng, acc: "PassSums") -> None:
        """Trace n photons (the first n_freq with a spectrum) and gather them
        into acc (in place)."""
        vp, P = pg.vp, pg.vp.valid.shape[0]
        dep = self._trace(n, n_freq, rng)
        if dep is None:
            return
        t1 = time.perf_counter()
        buf = self._buffers(P)
        g = hashgrid.gather(pg.grid, dep["p"], dep["ng"], dep["wi"], dep["power"], dep["rpred"],
                            vp.p, vp.ng, pg.R2, vp.const, cos_ng=-1.0,
                            want_freq_pairs=pg.want_pairs and n_freq > 0,
                            buffers=buf, clip=pg.clip)
        # M, sectors, Phi of the Lambert points (times albedo / pi) and, for
        # them alone when the receivers own the others, the smallest predicted
        # radius: added at the touched points only, the same bits as adding
        # the chunk's dense GatherResult (GatherBuffers.fold).
        buf.fold(acc.M, acc.Phi, vp.albedo, np.pi, acc.r_pred,
                 None if self.receivers is None else vp.const, acc.sectors, pg.clip)
        self._add_pairs(vp, dep, g, acc, pg.clip, n_freq)
        self.stage_seconds["gather"] += time.perf_counter() - t1

    def _add_pairs(self, vp, dep, g: "hashgrid.GatherResult", acc: "PassSums",
                   clip: Optional[np.ndarray] = None, n_freq: Optional[int] = None) -> None:
        """Add the (visible point, photon) pairs of the gather g to acc: the
        non-Lambert points' reflected flux and predicted radii (their own
        receiver lobes), the frequency photons' histograms and spectrum.
        clip: the packed clips of the gather (the flux of a clipped disc is
        divided by its visible fraction, as the fold does), or None.
        n_freq: the chunk's frequency photons (0: its deposits are all
        classic, rpred NaN, so no receiver radius is looked for), None:
        unknown (looked for)."""
        if g.pair_vp.size:
            self._reflected(vp, dep, g.pair_vp, g.pair_ph, acc.Phi, clip)
        if g.freq_pair_vp is not None:
            # Every frequency photon's pairs: its pairs at the non-Lambert
            # points are among them, so their radii are computed once there.
            if g.freq_pair_vp.size:
                self._frequency_pairs(g.freq_pair_vp, g.freq_pair_ph, dep, acc.hist, acc.spec,
                                      vp, acc.spec_set, acc.r_pred)
        elif self.receivers is not None and n_freq != 0:
            # A chunk without frequency photons (every pass but 1, 2, 4, 8,
            # ...: frequency_pass) has no receiver radius to find: its NaN
            # test over every non-Lambert pair is skipped (the same bits;
            # docs/method.md "FPPM's pass against CPPM's, round 16").
            fr = ~np.isnan(dep["rpred"][g.pair_ph])
            pv, pp = g.pair_vp[fr], g.pair_ph[fr]
            np.minimum.at(acc.r_pred, pv, self.receivers.radius_keys(
                vp, dep, pv, pp, self.settings.frequency_model))

    def _trace(self, n: int, n_freq: int, rng) -> Optional[dict]:
        """The deposits of n photons (the first n_freq with a spectrum), or
        None: the next chunk ``trace_ahead`` traced with this rng, else
        traced now."""
        if self._ahead is not None and self._ahead[0] is rng and self._ahead[1]:
            f = self._ahead[1].popleft()
            self._fill_ahead()              # traced while this chunk is gathered
            return f.result()
        self._drop_ahead()
        return self._trace_now(n, n_freq, rng)

    def _trace_now(self, n: int, n_freq: int, rng) -> Optional[dict]:
        """``_trace`` in this thread; counts the rays and the trace's wall seconds."""
        t0 = time.perf_counter()
        rays0 = self.tracer.rays_cast
        dep = self.tracer.trace(n, n_freq, rng)
        self.rays += self.tracer.rays_cast - rays0
        self.stage_seconds["photon_trace"] += time.perf_counter() - t0
        return dep

    def _buffers(self, P: int) -> "hashgrid.GatherBuffers":
        """The gather buffers for P visible points (allocated once per render:
        P changes only with the resolution)."""
        b = self.gather_buffers
        if b is None or b.K != P or b.with_sectors != self.sectors:
            b = self.gather_buffers = hashgrid.GatherBuffers(P, self.sectors)
            b.kept = self._grid_kept
        return b

    def _reflected(self, vp, dep, pv, pp, Phi: np.ndarray, clip=None) -> None:
        """Add to Phi (P, 3) the BSDF-weighted power of the (visible point pv,
        photon pp) pairs (K,) of the non-Lambert visible points, summed per
        point (in pair order, then added: the same bits either way below)."""
        if COMPILED_BSDF:
            from ..materials.compiled import compile_materials
            from . import reflected_kernels as RK
            P = Phi.shape[0]
            if self._reflected_scratch is None or self._reflected_scratch.shape[0] != P:
                self._reflected_scratch = RK.scratch_rows(P)
            icf = (np.zeros(0) if clip is None
                   else kernel_clip.inverse_fractions(clip, pv))
            RK.reflected_flux(compile_materials(self.mtab), vp.mat, vp.colors, vp.ns, vp.ng,
                              vp.front, vp.wo, pv, pp, dep["wi"], dep["power"], icf, Phi,
                              self._reflected_scratch)
            return
        # The mesh's normals, not the ones flipped to the viewer: the
        # materials tell a rough-glass point seen from inside by wo's side of
        # ng and use 1/eta there (VisiblePoints.mesh_normals).
        ns_m, ng_m = vp.mesh_normals(pv)
        f = B.eval_bsdf(self.mtab, vp.mat[pv], vp.colors[pv], ns_m, ng_m, vp.wo[pv], dep["wi"][pp])
        # Photons estimate flux per geometric area; radiance wants the
        # shading cosine: |wi.ns| / |wi.ng| (Veach 1997, 5.3), capped so a
        # grazing geometric normal cannot spike.
        from .reflected_kernels import SHADING_CORRECTION_MAX
        corr = np.minimum(B.shading_correction(vp.ns[pv], vp.ng[pv], dep["wi"][pp]),
                          SHADING_CORRECTION_MAX)
        contrib = f * (dep["power"][pp] * corr[:, None])
        if clip is not None:
            contrib *= kernel_clip.inverse_fractions(clip, pv)[:, None]
        P = Phi.shape[0]
        if pv.size * REFLECTED_DENSE_FRACTION < P:
            # Few pairs: sums at the touched points only, no (P, 3) array per
            # chunk (np.unique's inverse keeps each point's pairs in order).
            pts, inv = np.unique(pv, return_inverse=True)
            for ch in range(3):
                Phi[pts, ch] += np.bincount(inv, weights=contrib[:, ch], minlength=pts.size)
            return
        for ch in range(3):
            Phi[:, ch] += np.bincount(pv, weights=contrib[:, ch], minlength=P)

    def _frequency_pairs(self, pv, pp, dep, hist, spec, vp, spec_set=None,
                         r_pred=None) -> None:
        """(visible point pv, frequency photon pp) pairs (K,): add the
        predicted radii to hist (P, HIST_BINS) and keep in spec (P, 3) the
        spectrum of each point's photon that predicted the smallest radius
        (marked in spec_set (P,) bool when given); r_pred (P,): the smallest
        predicted radius of the non-Lambert points (their receiver lobes), or
        None."""
        rr = dep["rpred"][pp].copy()
        nc = ~vp.const[pv]
        if np.any(nc):
            rr[nc] = self.receivers.radius_keys(vp, dep, pv[nc], pp[nc],
                                                self.settings.frequency_model)
            if r_pred is not None:
                np.minimum.at(r_pred, pv[nc], rr[nc])
        if hist is not None:
            np.add.at(hist, (pv, self.radius_histogram.bin(rr)), 1)
        if spec is not None and "spec" in dep:
            order = np.lexsort((np.abs(rr), pv))
            first = np.ones(order.size, bool)
            first[1:] = pv[order][1:] != pv[order][:-1]
            sel = order[first]
            spec[pv[sel]] = dep["spec"][pp[sel]]
            if spec_set is not None:
                spec_set[pv[sel]] = True
