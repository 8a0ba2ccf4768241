"""Photon tracing for one pass: emission, bounces, deposits, frequency spectra.

Photons leave the emitters (``lights.sample_photons``), bounce by BSDF sampling
in importance mode with Russian roulette, and are deposited at every
non-specular hit after the first bounce (the first hit is next-event
estimation's job) or from the first hit with ``photons_for_direct``.  The
first ``n_freq`` photons of a batch also carry a light-field spectrum (a, b, c)
updated on travel, occlusion, onto/off the surface, the BSDF lobe and
curvature; each deposit gets its predicted radius.

After each Embree call one numba kernel (``photon_kernels.bounce_kernel``)
interpolates the hits, stores the deposits, samples the closures of
``core.materials.fast`` (Lambert / mirror / smooth glass), plays Russian
roulette and compacts the live photons in place.  Photons on any other
material (textures, GGX, Oren-Nayar, multi-lobe, translucent...) go through
``bsdf.sample_bsdf`` in numpy, and are appended back.  Frequency photons are
traced in the same batch, in its first live rows; their spectra follow
the two compiled chains of ``core.frequency.kernels`` on the hits and
survivors the kernel records (arriving: travel -> occlusion march ->
occlude -> onto_surface -> predicted radius; leaving: off_surface -> lobe
-> curvature), only for hits that deposit or continue.  A batch with few
of them (``RETRACE_MAX_SHARE``) is traced as without, and they are traced
again in a small batch of their own on the same numbers for the spectra.

The numpy reference tracer, every closure through ``bsdf.sample_bsdf`` and
the chains by the ``core.frequency.spectrum`` operators, is a test oracle
(tests/oracle_photons.py).
"""
from __future__ import annotations

import os
import threading

import numpy as np

from .. import materials as B
from .. import lights as Lt
from ..frequency import spectrum as F
from ..frequency import kernels as FK
from ..frequency.occlusion_march import march_grid, no_march_grid
from ..materials import compiled as C, fast, hit_colors, rough_maps
from ..materials.fast import GENERIC, build_fast_materials
from . import photon_kernels as PK
from ..accel import _COUNT_LOCK, RAY_SHADOW, REL_OFFSET, hit_uv, intersect_f32
from ..scene.linking import light_links, unlit_first_hits
from ..scene.shadow_linking import views as shadow_views
from ..scene import absorption as Absorb
from ..lights.lobe_visibility import unseen_first_hits
from ..kept import _ALONE, _refcounts
from ..scene.model import Scene
from .update import R_FLOOR_REL

from ..mathutil import LUMINANCE as LUM, dot as _dot  # noqa: E402
#: Batches of at least this many photons are traced as two halves (see trace).
SPLIT_MIN = 8192
#: A batch whose frequency photons are at most this share of its photons
#: traces them again in a batch of their own (PhotonTracer._trace_batch):
#: below it the second trace of their paths costs less than what spectra
#: cost every ray of the batch (crossover 3-6 %, docs/frequency.md "Cost",
#: "Frequency photons traced again").
RETRACE_MAX_SHARE = 0.04
#: PhotonTracer.freq_deposits: the counted deposits (not gated as unreached)
#: at which a frequency photon predicts a radius; after them it is traced as
#: a classic photon (docs/frequency.md "Fewer marched deposits"); 0 = all.
FREQ_DEPOSITS = 0
#: Threads tracing the halves: FPPM_PHOTON_THREADS, else min(2, cores).
THREADS = int(os.environ.get("FPPM_PHOTON_THREADS", "0")) or min(2, os.cpu_count() or 1)
_POOL = None


def _threads() -> int:
    return THREADS


def _pool():
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor
        _POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="fppm-photons")
    return _POOL


def in_two_halves(work, K: int, split_min: int, align: int = 1) -> None:
    """work(a0, a1) over the rows [0, K): as one call below split_min rows
    or with one thread, else [0, h) in this thread and [h, K) in the pool's,
    h = K / 2 rounded down to a multiple of align.  For work whose result
    for a row depends on that row alone (the same bits either way); work
    that releases the GIL (Embree, numba, large numpy operations)."""
    if K < split_min or _threads() < 2:
        work(0, K)
        return
    h = (K // 2 // align) * align
    f1 = _pool().submit(work, h, K)
    work(0, h)
    f1.result()


def _children(rng, n: int = 2):
    """n independent child generators of rng (deterministic)."""
    try:
        return rng.spawn(n)
    except (AttributeError, TypeError, ValueError):    # no SeedSequence behind rng
        return [np.random.default_rng(int(s)) for s in rng.integers(0, 2**63, n)]


class ArrayPool:
    """Sets of arrays reused from one batch, chunk and pass to the next, so
    that the tracer does not page-fault its deposit rows, live photons and
    uniforms in afresh each time (docs/architecture.md "Photon trace against
    raw Embree": the faults were inside the bounce kernel's time, and
    serialised the two tracing threads).  A set is handed out only
    while nothing but the pool references any of its arrays (the rule of
    core.kept: a caller that keeps deposits, a view of them or a result
    dict, keeps them untouched); uninitialised like np.empty.  Thread-safe:
    the halves of a batch and the chunks traced ahead draw from one pool."""

    def __init__(self, max_sets: int = 8):
        self.max_sets = int(max_sets)      # per kind
        self._sets: dict = {}              # kind -> [[rows, [arrays]], ...]
        self._lock = threading.Lock()

    def take(self, kind: str, rows: int, make, wrap=list):
        """wrap(arrays) of a free set of this kind with at least rows rows
        (the smallest), else of make(rows)'s new arrays, kept for later
        calls (at most max_sets of a kind: the smallest idle one makes
        room).  wrap runs under the pool's lock: what it builds holds the
        arrays before another thread looks at them."""
        rows = int(rows)
        with self._lock:
            sets = self._sets.setdefault(kind, [])
            free = [s for s in sets if s[0] >= rows and max(_refcounts(s[1])) <= _ALONE]
            if free:
                return wrap(min(free, key=lambda s: s[0])[1])
            arrays = list(make(rows))
            if len(sets) >= self.max_sets:
                idle = [s for s in sets if max(_refcounts(s[1])) <= _ALONE]
                if idle:
                    # by identity: list.remove's == would compare the arrays
                    smallest = min(idle, key=lambda s: s[0])
                    sets[:] = [s for s in sets if s is not smallest]
            if len(sets) < self.max_sets:
                sets.append([rows, arrays])
            return wrap(arrays)


def _deposit_arrays(cap: int) -> list:
    """New arrays of the DepositBuffers fields, cap rows."""
    return [np.empty((cap, 3)), np.empty((cap, 3)), np.empty((cap, 3)), np.empty((cap, 3)),
            np.empty(cap), np.empty(cap, np.int32), np.empty(cap, np.int64),
            np.empty((cap, 3)),           # spec (a, b, c); rows of classic photons unused
            np.empty((cap, 3))]           # bary (prim, u, v): light tracing's BSDF


def _record_arrays(n: int) -> list:
    """New arrays of the HitRecord fields, n rows."""
    return [np.empty(n), np.empty((n, 3)), np.empty(n), np.empty(n, bool),
            np.empty(n, np.int64), np.empty(n, bool)]


def _live_arrays(n: int) -> list:
    """New arrays of the LiveState fields, n rows."""
    return [np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty((n, 3)),
            np.empty((n, 3)), np.empty(n)]


#: The spectrum of classic photons, read only at frequency photons' rows: a
#: batch without them returns this broadcast to (n, 3) (read-only, nothing
#: allocated; np.zeros((n, 3)) cost ~3 ms a 131k-photon chunk in calloc's
#: memset and page faults, docs/architecture.md "Photon trace against raw Embree").
_NO_SPECTRUM = np.zeros(3)
#: spectrum_at_hits' ``left`` without a deposit budget (not read): no (K,)
#: array a bounce on the default path (freq_deposits = 0).
_NO_BUDGET = np.ones(1, np.int32)
# generic_survivors' columns when nothing is recorded (src, delta) or no roulette (lum).
_NO_SRC, _NO_DELTA, _NO_LUM = np.zeros(1, np.int64), np.zeros(1, bool), np.zeros(1)


class _Deposits:
    """Growable deposit buffers (``photon_kernels.DepositBuffers``, rows
    0..n-1 used), float64; r = the radius fold key.  pool: an ArrayPool to
    draw the buffers from (None: new arrays)."""

    def __init__(self, cap, pool: "ArrayPool" = None):
        self.pool = pool
        self.buf = self._arrays(max(int(cap), 16))
        self.n = 0
        # The rows (int64 arrays) of frequency photons' deposits: the only
        # spec rows written (and read).
        self.freq_rows = []

    def _arrays(self, cap: int) -> "PK.DepositBuffers":
        wrap = lambda a: PK.DepositBuffers(*a)          # noqa: E731
        if self.pool is None:
            return wrap(_deposit_arrays(cap))
        return self.pool.take("deposits", cap, _deposit_arrays, wrap)

    def reserve(self, k: int):
        """Make room for k more rows (doubling: amortised O(1) per deposit)."""
        need = self.n + int(k)
        cap = self.buf.r.shape[0]
        if need <= cap:
            return
        grown = self._arrays(max(2 * cap, need))
        for a, b in zip(self.buf, grown):
            b[:self.n] = a[:self.n]
        self.buf = grown

    def extend(self, other: "_Deposits"):
        """Append the rows of another buffer (one copy of its rows)."""
        k = other.n
        self.reserve(k)
        a, b = self.n, self.n + k
        for name in ("p", "ng", "wi", "power", "r", "bounce", "bary"):
            getattr(self.buf, name)[a:b] = getattr(other.buf, name)[:k]
        for rows in other.freq_rows:
            self.buf.spec[a + rows] = other.buf.spec[rows]
            self.freq_rows.append(a + rows)
        self.n = b

    def result(self):
        if self.n == 0:
            return None
        n, d = self.n, self.buf
        if self.freq_rows:
            # zeros: calloc's pages, faulted in only where written or read
            # (np.where over every row cost ~2 ms a 100,000-photon trace)
            spec = np.zeros((n, 3))
            rows = np.concatenate(self.freq_rows)
            spec[rows] = d.spec[rows]
        else:
            spec = np.broadcast_to(_NO_SPECTRUM, (n, 3))
        return {"p": d.p[:n], "ng": d.ng[:n], "wi": d.wi[:n],
                "power": d.power[:n], "rpred": d.r[:n], "bounce": d.bounce[:n],
                "spec": spec, "bary": d.bary[:n]}


def _keep_rows(dep: "_Deposits", a: int, keep: np.ndarray) -> None:
    """Keep the deposit rows a..dep.n-1 where keep (dep.n - a,) bool, compacted in order."""
    rows = a + np.flatnonzero(keep)
    for arr in dep.buf:
        arr[a:a + rows.size] = arr[rows]
    dep.n = a + rows.size


class _PathsDiffer(Exception):
    """Photons traced again left the paths they had in their batch."""


class _Follow:
    """A batch's first photons, followed through it while it is traced as
    without spectra (PhotonTracer._trace_batch): at each bounce their rays
    (ascending), the uniforms those drew, and their deposit rows."""

    def __init__(self):
        self.k = 0
        self.u = []              # per bounce: (k, 4) the followed rays' uniforms
        self._dep = []           # per bounce: their deposit rows, in ray order

    def start(self, k: int, n: int):
        """k photons, rays 0..k-1 of a batch of n rays."""
        self.k = int(k)
        self.rows = np.arange(self.k, dtype=np.int64)
        self._next = np.empty(self.k, np.int64)
        self._deps = np.empty(self.k, np.int64)

    def draw(self, u: np.ndarray):
        """The bounce's uniforms (K, 4): keep the followed rays'."""
        self.u.append(u[self.rows[:self.k]])

    def step(self, src, n_fast: int, n_next: int, dsrc, dep0: int, dep1: int):
        """After the bounce (PK.follow_rows): the followed rays' deposit rows
        and their survivors' rays."""
        m, nd = PK.follow_rows(self.rows, self.k, src, n_fast, n_next, dsrc, dep0, dep1,
                               self._next, self._deps)
        self._dep.append(self._deps[:nd].copy())
        self.rows, self._next = self._next, self.rows
        self.k = m

    def deposit_rows(self) -> np.ndarray:
        """Every followed deposit row, bounce by bounce."""
        return np.concatenate(self._dep) if self._dep else np.zeros(0, np.int64)


def _delta_landing(light_table, mtab, scene, hidden):
    """(delta emitter rows (Nl,) bool: points and spots of radius 0, suns
    of angle 0; the triangles some emitter's shadow rays pass (``hidden``
    (T,) bool, or None) whose material has delta lobes only (T,) bool), or
    None when either is empty."""
    if hidden is None:
        return None
    from ..lights import POINT, SPOT, SUN
    t = light_table
    dl = ((((t.kind == POINT) | (t.kind == SPOT)) & (t.radius <= 0))
          | ((t.kind == SUN) & (t.half_angle <= 0)))
    tri = hidden & ~np.asarray(mtab.has_nondelta)[np.asarray(scene.tri_mat, np.int64)]
    return (dl, tri) if dl.any() and tri.any() else None


class PhotonTracer:
    """Traces batches of photons through one scene (state shared across passes)."""

    def __init__(self, scene, accel, mtab, light_table, settings, plan, kappa, occ_grid,
                 occ_locality, D):
        self.scene, self.accel, self.mtab = scene, accel, mtab
        self.light_table, self.settings, self.plan = light_table, settings, plan
        self.kappa, self.occ_grid, self.occ_locality, self.D = kappa, occ_grid, occ_locality, D
        self.tris = PK.build_triangle_data(scene)
        self.fmat = build_fast_materials(mtab)
        # textured (M,) bool: the colour-textured materials without an alpha
        # texture (light tracing reads it too): their generic hits are
        # sampled compiled, each with a colour row of its own
        # (materials.hit_colors; _sample_textured), else by numpy.
        # Roughness-mapped ones too (their rows are a level's, picked first).
        self.textured = hit_colors.textured_materials(mtab)
        self._mapped_all = rough_maps.mapped(mtab)    # _sample_numpy's picks
        self._mapped = self._mapped_all.copy()
        if mtab.alpha_tex is not None:
            alpha = np.any(np.asarray(mtab.alpha_tex) >= 0, axis=1)
            self.textured &= ~alpha
            self._mapped &= ~alpha
        self._colors = (hit_colors.build_color_inputs(mtab, scene.tri_uv)
                        if (self.textured | self._mapped).any() else None)
        self._tri_mat = np.ascontiguousarray(self.tris.mat, np.int64)
        # Objects whose Shadow visibility is off (Scene.tri_visibility): a
        # light's direct light reaches every surface its shadow rays do, the
        # surfaces behind such an object and the object itself (Cycles).  So
        # the photons' first segment is traced twice: in the scene as shadow
        # rays see it (first hits behind the objects), and in the whole scene
        # keeping only the photons whose first hit is on such an object
        # (_trace_hidden_first).  None: no such object.
        self._shadow_hidden = accel.hidden_from(RAY_SHADOW)
        # (delta emitter rows (Nl,) bool, the shadowless triangles of
        # delta-only materials (T,) bool) or None: light a point or sun light
        # lands on a shadowless glass or mirror with is the light its shadow
        # rays pass (Cycles cannot hit such a light by a BSDF ray, so it
        # shows no caustic of it there), and is not bounced on
        # (_trace_hidden_first).
        # Shadow linking (core.scene.shadow_linking): each emitter's first
        # segment in its own view, and the second set lands on the objects
        # that view leaves out.  None: no shadow linking.
        self.views = shadow_views(accel, scene, light_table)
        hidden = self._shadow_hidden
        if self.views is not None:
            hid = [h for h in self.views.hidden if h is not None]
            hidden = np.logical_or.reduce(hid) if hid else None
        # Whether a second set of photons lands on what shadow rays pass.
        self._second_set = hidden is not None
        self._delta_landing = _delta_landing(light_table, mtab, scene, hidden)
        # Light linking (core.scene.linking): (the emitter rows' memberships
        # (Nl,) uint64, each triangle's receiver set (T,) int64), or None.
        # A photon whose first hit is on an object its emitter does not
        # light ends there (unlit_first_hits).
        self.link = light_links(light_table, mtab, scene)
        # Absorbing volumes (core.scene.absorption), or None.
        self.absorb = Absorb.of_scene(scene)
        # (Nl,) uint8 the kinds of ray each emitter is hidden from, or None: a
        # photon whose first hit has only lobes hidden from its emitter ends
        # there (core.lights.lobe_visibility).
        self.hidden = getattr(light_table, "hidden", None)
        # Photon rays cast by this tracer (accel.rays_cast also counts the
        # camera's, which may be cast meanwhile: PhotonPass.trace_ahead).
        self.rays_cast = 0
        self._tri_uv = None
        self.fast_emission = PK.fast_emission_ok(light_table)
        self._light_arrays = PK.light_arrays(light_table) if self.fast_emission else None
        # Soft-falloff point and spot lights: their photons' power and
        # direction set at the first hit (lights.emission.soft_light_first_hit),
        # None without any.
        self.soft_lights = (PK.soft_lights(light_table)
                            if np.any(light_table.soft_disc & (light_table.p_select > 0)) else None)
        # Deposits per photon (max seen, x1.25 margin on use): buffer sizing.
        self._dpp = 2.0
        # Deposit rows, live photons and uniforms reused across batches (ArrayPool).
        self.pool = ArrayPool()
        self._lobes = None           # FK.SurfaceLobes, on first use
        # The march's arguments (builds its blocks: 0.14 s at 64^3, here
        # rather than in the first pass).
        self.occlusion, self.march = self._occlusion_march()
        # Integrator 'COMBINED' (photon merging, core.integrators.merge): keep
        # only deposits whose previous scattering sampled a delta lobe
        # (caustic photons).  Off for PHOTON, whose deposits stay as they are.
        self.after_delta_only = False
        # Transparent shadows (core.lights.shadow): next-event estimation
        # already carries the light that reached a surface through
        # Transparent BSDFs only, so photons that have crossed nothing but
        # transparent surfaces since the light deposit nothing.
        self.clear_through = bool(getattr(plan, "transparent_shadows", False))
        self.skip_straight = self.clear_through and not settings.photons_for_direct
        self._clear = None
        # The march ignores occluders that cannot bring a deposit's radius
        # below this [m] (set_radius_cut; kernels.ChainParams.r_cut).
        self.radius_cut = np.inf
        # (R, R, R) uint8 on the march grid: voxels a visible point of the
        # last pass can gather from (set_reach); None: every deposit counts.
        self.reach = None
        # Frequency and classic photons traced in one batch (_trace_batch);
        # False: a batch each, the rule before (benchmarks).
        self.one_batch = True
        # Frequency photons trace the photons of a batch without spectra
        # (docs/frequency.md "The same photons"); False: the rows they move
        # to draw other uniforms, the rule before (benchmarks).
        self.same_photons = True
        # Batches whose frequency photons are at most this share of their
        # photons trace those again in a batch of their own (_trace_batch);
        # 0: never, the rule before (benchmarks).
        self.retrace = RETRACE_MAX_SHARE
        # Batches whose frequency photons, traced again, left other deposits
        # than in the batch (_retrace: then no spectra; 0 on every test scene).
        self.retrace_mismatches = 0
        # A frequency photon predicts radii at its first this many counted
        # deposits only, and is traced as a classic photon after them
        # (kernels.ChainParams.deposits; docs/frequency.md "Fewer marched
        # deposits"); 0: every deposit.
        self.freq_deposits = FREQ_DEPOSITS

    def trace(self, n: int, n_freq: int, rng):
        """Trace n photons (the first n_freq carry a spectrum); return deposits.

        Returns None when nothing is deposited, else a dict of float64 arrays:
        p (K, 3) hit position, ng (K, 3) geometric normal on the side the
        photon came from, wi (K, 3) unit direction back to where it came from,
        power (K, 3), rpred (K,) the predicted radius's fold key
        (``spectrum.radius_fold_key``; NaN for classic photons), bounce (K,)
        int32 index of the path vertex (0 = first hit; diagnostics and tests),
        bary (K, 3) (prim, u, v) of the hit.
        """
        if n < SPLIT_MIN:
            return self._trace_part(n, n_freq, rng, self.deposit_buffers(n)).result()
        # Two halves on independent child streams, always (the image does not
        # depend on the number of cores), traced concurrently when there are
        # two threads: Embree and the kernels release the GIL.  The deposits
        # are the first half's followed by the second's in both cases.
        r0, r1 = _children(rng)
        h, hf = n // 2, n_freq // 2
        # The first buffer is sized for both halves (deposits per photon seen
        # so far, +25%): the second is appended without reallocating.
        d0 = self.deposit_buffers(n)
        if _threads() > 1:
            d1 = self.deposit_buffers(n - h)
            f0 = _pool().submit(self._trace_part, h, hf, r0, d0)
            self._trace_part(n - h, n_freq - hf, r1, d1)
            f0.result()
            d0.extend(d1)                # one copy of the second half's rows
        else:
            self._trace_part(h, hf, r0, d0)
            self._trace_part(n - h, n_freq - hf, r1, d0)
        return d0.result()

    def trace_emitted(self, ph: dict, rng):
        """Trace the photons ph of ``lights.sample_photons`` (keys o, d, power,
        falloff_r2; n rows) without spectra, in this thread; deposits as
        :meth:`trace`.  Light tracing needs the emission vertices too
        (core.integrators.light_tracer), which the fused emission kernel
        does not return."""
        n = ph["o"].shape[0]
        dep = self.deposit_buffers(n)
        self._trace_batch(None, ph, 0, n, rng, dep)
        self._trace_hidden_first(None, ph, n, rng, dep)
        self.note_deposits(n, dep.n)
        return dep.result()

    def deposit_buffers(self, n: int) -> "_Deposits":
        """Empty deposit buffers for n photons (deposits per photon seen so
        far, +25%: :meth:`note_deposits`), from the tracer's pool."""
        return _Deposits(self._dpp * n + 64, self.pool)

    def note_deposits(self, n: int, k: int) -> None:
        """n photons left k deposits: sizes the next deposit_buffers."""
        self._dpp = max(self._dpp, 1.25 * k / max(n, 1))

    def uniforms(self, K: int, m: int, rng, buf: np.ndarray = None) -> np.ndarray:
        """rng.random((K, m)) (the same numbers: drawn in the same order) into
        buf (flat float64, at least K m; :meth:`uniform_buffer`), else into
        an array of the pool (one still referenced is never handed out)."""
        if buf is None:
            buf = self.uniform_buffer(K * m)
        u = buf[:K * m].reshape(K, m)
        rng.random(out=u)
        return u

    def uniform_buffer(self, size: int) -> np.ndarray:
        """A flat float64 array of at least size from the pool, for the
        uniforms of every bounce of a batch (one pool look-up a batch)."""
        return self.pool.take("uniforms", size, lambda r: [np.empty(r)], lambda a: a[0])

    def _trace_part(self, n: int, n_freq: int, rng, dep: "_Deposits") -> "_Deposits":
        """Emit and trace n photons (the first n_freq with a spectrum); their
        deposits are appended to dep."""
        n_before = dep.n
        if self.fast_emission:
            u = self.uniforms(n, 6, rng)
            ph = None
        else:
            u = None
            ph = Lt.sample_photons(self.light_table, n, rng)
        if self.one_batch or not 0 < n_freq < n:
            self._trace_batch(u, ph, 0, n, rng, dep, n_freq)
        else:                          # the rule before (benchmarks): a batch each
            self._trace_batch(u, ph, 0, n_freq, rng, dep, n_freq)
            self._trace_batch(u, ph, n_freq, n, rng, dep)
        self._trace_hidden_first(u, ph, n, rng, dep)
        self.note_deposits(n, dep.n - n_before)
        return dep

    def _trace_hidden_first(self, u_emit, ph, n: int, rng, dep: "_Deposits") -> None:
        """With objects whose Shadow is off: the n photons just emitted (the
        same u_emit or ph) traced again without spectra, their first segment
        in the whole scene, keeping those whose first hit lies on such an
        object (the main batch's passed it: :attr:`_shadow_hidden`); their
        deposits are appended to dep.  Each keeps its emitted power: the two
        sets split the light's direct light by where it lands, as shadow
        rays do, and together carry it to every surface they light."""
        if self._second_set and n:
            self._trace_rows(u_emit, ph, 0, n, rng, dep, first="hidden")

    def _trace_batch(self, u_emit, ph, a: int, b: int, rng, dep: _Deposits, n_freq: int = 0):
        """Trace photons a..b-1: from the uniforms u_emit (n, 6) of the fused
        emission kernel, or from the emission ``ph`` of lights.sample_photons.
        The first n_freq of them carry a spectrum.

        With at most a share ``retrace`` of frequency photons the batch is
        traced as without them, following the first n_freq (their rows, the
        uniforms they draw, their deposit rows: :class:`_Follow`), and those
        are traced again in a batch of their own from the same numbers for
        their spectra (:meth:`_retrace`): the same paths, bit for bit, and
        no per-ray cost of the spectra in the large batch (docs/frequency.md
        "Cost", "Frequency photons traced again")."""
        nf = min(max(int(n_freq), 0), b - a)
        if 0 < nf <= self.retrace * (b - a) and self.one_batch and self.same_photons:
            follow = _Follow()
            self._trace_rows(u_emit, ph, a, b, rng, dep, nf, follow=follow)
            self._retrace(u_emit, ph, a, nf, follow, dep)
        else:
            self._trace_rows(u_emit, ph, a, b, rng, dep, nf)

    def _retrace(self, u_emit, ph, a: int, nf: int, follow: "_Follow", dep: _Deposits):
        """Trace photons a..a+nf-1 again, with their spectra, on the uniforms
        follow recorded in the batch they belong to, and give its deposit
        rows (follow.deposit_rows()) their predicted radii and spectra.
        Within a bounce both batches keep the photons' relative order (each
        compacts its survivors in ray order, the bounce kernel's block first,
        and a photon lands in the same block in both), so the k-th survivor
        here is the k-th followed row, and the deposits pair up in order.
        Should the paths differ all the same (a numpy reduction rounding
        otherwise on fewer rows: not seen), the batch's deposits keep no
        spectrum, PPM's rule for them, and ``retrace_mismatches`` counts it."""
        small = _Deposits(self._dpp * nf + 64, self.pool)
        try:
            self._trace_rows(u_emit, ph, a, a + nf, None, small, nf, given=follow.u)
        except _PathsDiffer:
            self.retrace_mismatches += 1
            return
        rows = follow.deposit_rows()
        m = small.n
        if rows.size != m or not np.array_equal(small.buf.p[:m], dep.buf.p[rows]):
            self.retrace_mismatches += 1
            return
        dep.buf.r[rows] = small.buf.r[:m]
        dep.buf.spec[rows] = small.buf.spec[:m]
        if self.freq_deposits > 0:
            # past their budget the photons are classic ones: no spectrum
            dep.buf.spec[rows[np.isnan(small.buf.r[:m])]] = 0.0
        dep.freq_rows.append(rows)

    def _trace_rows(self, u_emit, ph, a: int, b: int, rng, dep: _Deposits, nf: int = 0,
                    follow: "_Follow" = None, given: list = None, first: str = "shadow"):
        """:meth:`_trace_batch`'s work: photons a..b-1, the first nf with a
        spectrum, or, with follow, followed (:class:`_Follow`) and traced
        without one; given: the uniforms (K, 4) of each bounce (the rows of
        a batch follow recorded), else drawn from rng.  first: the first
        segment as shadow rays see the scene ("shadow": it passes the
        objects whose Shadow is off), or in the whole scene keeping only the
        photons that land on such an object ("hidden",
        :meth:`_trace_hidden_first`); the same scene without such objects.

        Frequency and classic photons share the batch: every bounce's Embree
        call, bounce kernel and numpy bounce of the generic materials, whose
        fixed costs a batch of their own paid again for a few thousand
        frequency photons (docs/frequency.md "One batch for both kinds of
        photon").  The frequency photons are kept in the first Kf rows of
        the live state (:meth:`_frequency_first`), so the chains read rows
        0..Kf-1 of each bounce."""
        st = self.settings
        n = b - a
        live = self.pool.take("live", n, _live_arrays, lambda a: PK.LiveState(*a))
        rel = REL_OFFSET
        floor = self.accel.abs_floor / REL_OFFSET
        cone = None                              # soft lights' first hits
        spec = None
        Kf = 0                                   # live rows 0..Kf-1: frequency photons
        if u_emit is not None:
            spec = np.empty((max(nf, 1), 3))
            # Soft lights: each kept photon's emitter row and disc sample
            # (the rows also for light linking's first hits).
            soft = self.soft_lights is not None
            want_rows = (soft or self.link is not None or self.views is not None
                         or self.hidden is not None
                         or (first == "hidden" and self._delta_landing is not None))
            rows = np.empty(n if want_rows else 1, np.int64)
            disc = np.empty((n if want_rows else 1, 4))
            if nf:
                Kf = PK.emit_lights_state(u_emit[a:a + nf], *self._light_arrays, rel, floor,
                                          live, True, spec, want_rows, rows, disc)
            rest = PK.LiveState(*(x[Kf:] for x in live)) if Kf else live
            K = Kf + PK.emit_lights_state(u_emit[a + nf:b], *self._light_arrays, rel, floor,
                                          rest, False, spec, want_rows,
                                          rows[Kf:] if want_rows else rows,
                                          disc[Kf:] if want_rows else disc)
            spec = spec[:Kf]
            if soft:
                cone = (np.arange(K, dtype=np.int64), rows, disc)
            emitter = rows[:K] if want_rows else None
        else:
            fal = ph.get("falloff_r2")
            fal = np.zeros(n) if fal is None else np.ascontiguousarray(fal[a:b], np.float64)
            src = np.empty(n, np.int64)
            K = PK.emit_kernel(np.ascontiguousarray(ph["o"][a:b], np.float64),
                               np.ascontiguousarray(ph["d"][a:b], np.float64),
                               np.ascontiguousarray(ph["power"][a:b], np.float64),
                               fal, rel, floor, live, src)
            if self.soft_lights is not None and "soft_disc" in ph:
                cone = (src, np.ascontiguousarray(ph["light"][a:b], np.int64),
                        np.ascontiguousarray(ph["soft_disc"][a:b], np.float64))
            emitter = (np.asarray(ph["light"][a:b], np.int64)[src[:K]]
                       if self.link is not None or first == "hidden" or self.views is not None
                       or self.hidden is not None else None)
            if nf:
                Kf = int(np.searchsorted(src[:K], nf))      # kept in order
                spec = np.asarray(ph["freq_init"], np.float64)[a:b][src[:Kf]]
        if follow is not None:
            follow.start(Kf, n)              # followed, traced without spectra
            Kf, spec = 0, None
        # the geometric normal of the surface each frequency photon leaves
        # (zeros: the emitter): the march does not take it for an occluder
        ng0 = np.zeros((Kf, 3))
        # counted deposits each frequency row may still predict at (only
        # with a budget, freq_deposits > 0)
        left = (np.full(Kf, int(self.freq_deposits), np.int32) if self.freq_deposits > 0
                else None)
        caustic = self.after_delta_only
        # Hit records: frequency photons' chains, and the delta flag of the
        # scattering each survivor sampled (caustic photons).
        record = caustic or self.skip_straight
        prev_delta = np.zeros(K, bool) if caustic else None
        straight = np.ones(K, bool) if self.skip_straight else None
        cg = n if self.fmat.any_generic else 1
        comp = self.fmat.any_sampled or self._textured_rows().any()
        gen = PK.generic_hits(cg, comp)
        ubuf = self.uniform_buffer(4 * K)       # K never grows: one survivor a ray at most
        cr = n if record or Kf or follow is not None else 1
        rec = self.pool.take("record", cr, _record_arrays, lambda a: PK.HitRecord(*a))
        # The same photons as a batch without frequency photons
        # (docs/frequency.md "The same photons"): order (K,) is each live
        # row's row in that batch, whose uniforms it draws; None while the
        # rows are in that batch's order (no swap by _frequency_first yet).
        order = None
        track = Kf and self.same_photons
        if track:
            order_bufs = self.pool.take("order", K, lambda r: [np.empty(r, np.int64)
                                                               for _ in range(3)])
            ubuf2 = self.uniform_buffer(4 * K)
        hidden = self._shadow_hidden
        for bounce in range(st.max_bounces + 1):
            if K == 0:
                break
            acc = (self.accel.for_rays(RAY_SHADOW) if bounce == 0 and first == "shadow"
                   else self.accel)
            hits = PK.EmbreeHits(*intersect_f32(acc, live.o32[:K], live.d32[:K]))
            if bounce == 0 and self.views is not None:
                self._first_in_views(hits, live, K, emitter, first)
            elif bounce == 0 and first == "hidden":
                # Only the first hits on objects whose Shadow is off go on.
                h = hits.prim[:K] >= 0
                h[h] = ~hidden[hits.prim[:K][h]]
                hits.prim[:K][h] = -1
            if bounce == 0 and first == "hidden":
                if self._delta_landing is not None:     # (hits kept: shadow rays pass them)
                    dl, tri = self._delta_landing
                    k = np.nonzero(hits.prim[:K] >= 0)[0]
                    off = k[dl[emitter[k]] & tri[hits.prim[:K][k]]]
                    hits.prim[:K][off] = -1
            if bounce == 0 and self.link is not None:
                unlit_first_hits(hits.prim[:K], emitter, *self.link)
            if bounce == 0 and self.hidden is not None:
                unseen_first_hits(hits.prim[:K], emitter, self.hidden, self._tri_mat, self.mtab)
            # Absorbing volumes: the power left after a segment inside one.
            Absorb.attenuate(self.absorb, hits.prim[:K], hits.tfar[:K], live.d64[:K],
                             live.power[:K])
            with _COUNT_LOCK:                    # the halves run in two threads
                self.rays_cast += K
            step = PK.BounceStep(K=K, first=bounce == 0,
                                 store=bool(st.photons_for_direct or bounce > 0),
                                 sample=bounce < st.max_bounces,
                                 roulette=bounce + 1 >= st.rr_start, bounce=bounce,
                                 dep0=dep.n, record=bool(record or Kf or order is not None),
                                 rel=rel, floor=floor, compiled=comp,
                                 rows=follow is not None and follow.k > 0)
            if given is None:
                u = self.uniforms(K, 4, rng, ubuf)
            else:
                if bounce >= len(given) or given[bounce].shape[0] != K:
                    raise _PathsDiffer()
                u = given[bounce]
            if step.rows:
                follow.draw(u)
            if order is not None:
                u = np.take(u, order[:K], axis=0, out=ubuf2[:4 * K].reshape(K, 4), mode="clip")
            dep.reserve(K)
            if Kf:
                # the segments just travelled: the kernel overwrites the live state
                seg = FK.Segments(live.o32[:Kf].astype(np.float64), live.d64[:Kf].copy(), ng0)
            if bounce == 0 and cone is not None:
                # After the frequency photons' segments (from the light's
                # centre, as travelled), before a transparent crossing's test.
                PK.soft_light_first_hit(K, hits, live, self.tris.ng, *cone, self.soft_lights)
            through = straight is not None or (caustic and self.clear_through)
            if through:
                d_in, prim_in = live.d64[:K].copy(), hits.prim[:K].astype(np.int64)
            n_next, n_dep, n_gen = PK.bounce_kernel(step, hits, live, self.tris, self.fmat, u,
                                                    dep.buf, gen, rec, PK.NO_MIS)
            dep.n = n_dep
            n_fast = n_next
            if n_gen:
                n_next = self._generic_bounce(n_gen, n_next, gen, u, step.roulette, live,
                                              rec if step.record or step.rows else None, comp)
            if order is not None:
                nxt = order_bufs[1] if order is order_bufs[0] else order_bufs[0]
                PK.classic_rows(order, rec.nxt_src, n_fast, n_next, K, nxt, order_bufs[2])
                order = nxt
            kf_rays = Kf
            if Kf:
                split = self._frequency_split(Kf, n_fast, n_next, rec.nxt_src)
                if track and order is None and split[2]:
                    order = order_bufs[0]
                    order[:n_next] = np.arange(n_next)   # the rows so far are that batch's
                kf_next = self._frequency_first(Kf, n_fast, n_next, live, rec, order, split)
                # After the generic bounce: only hits that deposit or continue
                # need a spectrum (the bounce reads seg and rec, not the live
                # state it appended to).
                rows = FK.Rows(Kf, step.dep0, dep.n, n_next)
                # left only with a budget: the numpy chains of the tests and
                # the benches' hooks take the five arguments
                spec_hit = (self._spectrum_at_hits(spec, seg, rec, dep, rows, left)
                            if self.freq_deposits > 0 else
                            self._spectrum_at_hits(spec, seg, rec, dep, rows))
                if kf_next and self.freq_deposits > 0:
                    # rows past their budget at the end of the prefix are
                    # classic photons from here on (rows >= Kf)
                    left = left[rec.nxt_src[:kf_next]]
                    kf_next = int(np.flatnonzero(left > 0)[-1]) + 1 if left.any() else 0
                    left = left[:kf_next]
                if kf_next:
                    spec = self._spectrum_leaving(spec_hit, kf_next, hits.prim, rec, live.d64,
                                                  seg.d)
                    ng0 = rec.ng[rec.nxt_src[:kf_next]]
                Kf = kf_next
            if through:
                th = self._through(d_in, prim_in, rec, live, n_next)
            if caustic:
                _keep_rows(dep, step.dep0, prev_delta[dep.buf.src[step.dep0:dep.n]])
                nxt = rec.nxt_delta[:n_next].copy()
                if through:
                    # A transparent crossing is no vertex (transparent
                    # shadows): the flag of the scattering before it goes on.
                    nxt = np.where(th, prev_delta[rec.nxt_src[:n_next]], nxt)
                prev_delta = nxt
            if straight is not None:
                straight = self._straight_filter(dep, step.dep0, straight, th, rec, n_next)
            if step.rows:
                follow.step(rec.nxt_src, n_fast, n_next, dep.buf.src, step.dep0, dep.n)
            if kf_rays:
                # the deposits of rays 0..kf_rays-1 lead the bounce's (ray order)
                nfd = int(np.searchsorted(dep.buf.src[step.dep0:dep.n], kf_rays))
                if nfd:
                    dep.freq_rows.append(np.arange(step.dep0, step.dep0 + nfd))
            K = n_next

    def _first_in_views(self, hits, live, K: int, emitter, first: str) -> None:
        """Shadow linking: the first hits (K photons, their emitter rows
        emitter (K,)) as each emitter's shadow rays see the scene, in place:
        "shadow", cast again in the view of each linked emitter's photons;
        "hidden" (cast in the whole scene), kept only on the triangles that
        view leaves out."""
        V = self.views
        g = V.group[emitter[:K]]
        prim = hits.prim[:K]
        for i, acc in enumerate(V.accels):
            k = np.nonzero(g == i)[0]
            if k.size == 0:
                continue
            if first == "hidden":
                hid = V.hidden[i]
                h = k[prim[k] >= 0]
                off = h if hid is None else h[~hid[prim[h]]]
                prim[off] = -1
            elif i > 0:
                p, u, v, t = intersect_f32(acc, live.o32[k], live.d32[k])
                prim[k], hits.bu[k], hits.bv[k], hits.tfar[k] = p, u, v, t

    @staticmethod
    def _frequency_split(Kf: int, n_fast: int, n_next: int, src) -> tuple:
        """(f1, gf, m) of :meth:`_frequency_first`: the frequency survivors
        of the bounce kernel's block (f1) and of the generic block (gf), and
        the rows m it swaps (0: the rows stay where they are)."""
        f1 = int(np.searchsorted(src[:n_fast], Kf))
        gf = int(np.searchsorted(src[n_fast:n_next], Kf))
        return f1, gf, min(n_fast - f1, gf)

    @staticmethod
    def _frequency_first(Kf: int, n_fast: int, n_next: int, live, rec, order=None,
                         split=None) -> int:
        """After a bounce of rays whose first Kf are frequency photons (split:
        their :meth:`_frequency_split` when the caller has it): the
        live rows 0..n_fast-1 hold the bounce kernel's survivors and
        n_fast..n_next-1 the generic bounce's, each in ray order, so those
        of rays < Kf lead each block.  Swaps the generic block's frequency
        survivors with as many classic ones of the first block, live rows,
        rec.nxt_src / nxt_delta and order (n_next,) (the rows of the batch
        without frequency photons, None: not kept) alike, so that the
        frequency survivors are rows 0..Kf'-1.  Returns Kf'."""
        src = rec.nxt_src
        f1, gf, m = split or PhotonTracer._frequency_split(Kf, n_fast, n_next, src)
        if m:
            i, j = slice(f1, f1 + m), slice(n_fast + gf - m, n_fast + gf)
            for arr in (*live, src, rec.nxt_delta) + (() if order is None else (order,)):
                t = arr[i].copy()
                arr[i] = arr[j]
                arr[j] = t
        return f1 + gf

    def _straight_filter(self, dep, dep0, straight, th, rec, n_next):
        """Drops the deposits dep0.. of photons that so far crossed only
        transparent surfaces (``skip_straight``); returns the flag (n_next,)
        of the survivors: still straight when they just passed through (th,
        :meth:`_through`)."""
        _keep_rows(dep, dep0, ~straight[dep.buf.src[dep0:dep.n]])
        return straight[rec.nxt_src[:n_next]] & th

    def _through(self, d_in, prim_in, rec, live, n_next):
        """(n_next,) bool: the survivors' scattering kept the direction on a
        material with a Transparent lobe (a transparent crossing)."""
        if self._clear is None:
            from ..lights.shadow import transparent_materials
            self._clear = transparent_materials(self.mtab)
        src = rec.nxt_src[:n_next]
        same = np.einsum("ij,ij->i", live.d64[:n_next], d_in[src]) > 1.0 - 1e-9
        return same & self._clear[self.tris.mat[prim_in[src]]]

    def _generic_bounce(self, g, n_next, gen, u, roulette, live, rec, compiled=False):
        """bsdf.sample_bsdf for the g hits on materials without a fast path
        (compiled: the bounce kernel sampled the rows of GenericHits.state
        != SAMPLE_NUMPY already); survivors are appended at row n_next of
        the live state (and their source ray to rec, when recording).
        Returns the new number of live photons."""
        gi, gp, gng, gns, gwi, gpow, gbary = (x[:g] for x in gen[:7])
        if compiled:
            # The rows left to numpy are sampled into the kernel's columns,
            # then one compiled loop keeps the survivors (the same tests and
            # row order as below).
            st = gen.state[:g]
            rows = np.nonzero(st == PK.SAMPLE_NUMPY)[0]
            if rows.size and self._colors is not None:
                rows = self._sample_textured(rows, gen, u)
            if rows.size:
                wo, wgt, valid, is_delta = self._sample_numpy(
                    rows.size, gns[rows], gng[rows], gwi[rows], gbary[rows], u[gi[rows]])
                gen.out[rows], gen.wgt[rows] = wo, wgt
                st[rows] = np.where(valid, np.where(is_delta, PK.SAMPLE_DELTA, PK.SAMPLE_OK),
                                    PK.SAMPLE_INVALID)
            record = rec is not None
            lum = gen.wgt[:g] @ LUM if roulette else _NO_LUM
            return PK.generic_survivors(n_next, g, gen, u, roulette, lum, REL_OFFSET,
                                        self.accel.abs_floor / REL_OFFSET, live, record,
                                        rec.nxt_src if record else _NO_SRC,
                                        rec.nxt_delta if record else _NO_DELTA)
        ug = u[gi]
        wo, wgt, valid, is_delta = self._sample_numpy(g, gns, gng, gwi, gbary, ug)
        ok = valid & np.all(np.isfinite(wgt), axis=1) & (wgt.max(axis=1) > 0)
        if roulette:
            q = np.clip(wgt @ LUM, 0.0, 1.0)
            ok &= ug[:, 3] < q
            wgt = wgt / np.maximum(q, 1e-12)[:, None]
        sel = np.nonzero(ok)[0]
        if sel.size == 0:
            return n_next
        PK.append_survivors(n_next, sel, gp, gng, wo, wgt, gpow, REL_OFFSET,
                            self.accel.abs_floor / REL_OFFSET, live)
        if rec is not None:
            rec.nxt_src[n_next:n_next + sel.size] = gi[sel]
            rec.nxt_delta[n_next:n_next + sel.size] = is_delta[sel]
        return n_next + sel.size

    def _textured_rows(self) -> np.ndarray:
        """(M,) bool: the materials whose generic hits :meth:`_sample_textured`
        samples (textured or roughness-mapped GENERIC ones, under
        ``fast.COMPILED_SAMPLING``)."""
        return ((self.textured | self._mapped) & (self.fmat.cls == GENERIC)
                & fast.COMPILED_SAMPLING)

    def _sample_textured(self, rows, gen, u) -> np.ndarray:
        """The generic hits rows (of GenericHits gen) on :meth:`_textured_rows`
        materials sampled by ``compiled.sample_pair`` (importance mode), a
        roughness map's at the hit's level row, with their own colour rows
        (``hit_colors.sample_rows``: numpy's ``lobe_colors`` at the hit's uv
        and its lobe selection, one row at a time) into the kernel's columns (out, wgt, state), as numpy's
        :meth:`_sample_numpy` samples them to rounding (a Lambert-only one by
        its lobes, where numpy takes the fast path: the same direction and
        weight).  Returns the rows left to numpy."""
        mat = self._tri_mat[gen.bary[rows, 0].astype(np.int64)]
        t = self._textured_rows()[mat]
        if not t.any():
            return rows
        r = rows[t]
        mr = mat[t].astype(np.int64)
        mapped = self._mapped[mr]
        if mapped.any():        # a roughness map: the hit's level row
            b = gen.bary[r[mapped]]
            prim = b[:, 0].astype(np.int64)
            bu, bv = b[:, 1].astype(np.float32), b[:, 2].astype(np.float32)
            mr[mapped] = rough_maps.pick(self.mtab, mr[mapped], prim, bu, bv,
                                         hit_uv(self.scene.tri_uv, prim, b[:, 1], b[:, 2]))
        cm = C.compile_materials(self.mtab)
        fl = np.empty(r.size, np.int8)
        hit_colors.sample_rows(self._colors, cm.lobes, cm.tables, mr, r, gen.bary,
                               gen.ns, gen.ng, gen.wi, gen.i, u, gen.out, gen.wgt, fl)
        gen.state[r] = np.where((fl & 1) > 0, np.where((fl & 2) > 0, PK.SAMPLE_DELTA,
                                                       PK.SAMPLE_OK), PK.SAMPLE_INVALID)
        return rows[~t]

    def _sample_numpy(self, g, gns, gng, gwi, gbary, ug):
        """bsdf.sample_bsdf (importance) of g generic hits: (wo, weight, valid, is_delta)."""
        prim = gbary[:, 0].astype(np.int64)
        mat = self.tris.mat[prim]
        uv = np.zeros((g, 2))
        mapped = self._mapped_all[mat]
        if self.mtab.textures and (np.any(self.mtab.tex[mat] >= 0) or mapped.any()):
            # (view factors read no uv)
            if self._tri_uv is None:
                self._tri_uv = np.ascontiguousarray(self.scene.tri_uv, np.float64)
            PK.gen_attributes(np.ascontiguousarray(gbary), g, self._tri_uv, uv)
        if mapped.any():        # a roughness map: the hit's level row
            mat = rough_maps.pick(self.mtab, mat, prim, gbary[:, 1].astype(np.float32),
                                  gbary[:, 2].astype(np.float32), uv)
        # A view-dependent lobe (Lobe.view) weighed at the photon's arrival:
        # the outgoing direction that Cycles' camera-side weight reads is
        # the one being sampled (docs/shading.md "View-dependent mixes").
        colors = B.lobe_colors(self.mtab, mat, uv, B.view_mu(self.mtab, gwi, gns))
        wo, wgt, _, is_delta, valid = B.sample_bsdf(
            self.mtab, mat, colors, gns, gng, gwi, ug[:, :3], subset="all", mode="importance")
        return wo, wgt, valid, is_delta

    def chain_params(self) -> FK.ChainParams:
        """The frequency model of this render, for the compiled chains."""
        return FK.ChainParams(paper=self.settings.frequency_model == "PAPER", D=float(self.D),
                              A_MAX=float(self.D * self.D), occlusion=self.occlusion,
                              r_cut=float(self.radius_cut), gate=self.reach is not None,
                              r_gated=R_FLOOR_REL * float(self.D),
                              deposits=int(self.freq_deposits))

    _NO_REACH = np.ones((1, 1, 1), np.uint8)

    def set_reach(self, p, valid, R2):
        """Before a pass (PhotonPass.trace_ahead): the reach map of the last
        pass's visible points p (P, 3) [m], valid (P,) bool, squared radii
        R2 (P,) (after its update) for this pass's frequency photons
        (docs/frequency.md "Cost", "Deposits no pixel reads"): a deposit
        in a voxel no visible point's sphere (plus a voxel) touches is not
        marched, and predicts the radius floor
        (R_FLOOR_REL D: no hold).  None (every deposit marched) under the
        exact conditions of set_radius_cut, without a marched grid, for
        the PAPER model and for photon merging (after_delta_only)."""
        R2 = np.asarray(R2)
        ok = np.asarray(valid, bool) & (R2 > 0) if self.uses_reach() else None
        if ok is None or not np.isfinite(R2[ok]).all():
            self.reach = None
            return
        m = self.march
        # The last pass's map is rewritten (its voxels zeroed): no fresh
        # pages each pass; the chunks that read it have finished
        # (PhotonPass.trace_ahead drops them first).
        out = self.reach
        if out is None or out.shape != (m.res, m.res, m.res):
            out = np.zeros((m.res, m.res, m.res), np.uint8)
        else:
            out.fill(0)
        FK.mark_reach(np.ascontiguousarray(np.asarray(p, np.float64)[ok]),
                      np.sqrt(R2[ok]).astype(np.float64), m.lo, m.cell, m.res, out)
        self.reach = out

    def uses_reach(self) -> bool:
        """The conditions of :meth:`set_reach` that do not depend on the
        pass: a marched grid, the CORRECTED model, PPM's radius rule, no
        predicted-radius or spectrum AOV, no photon merging."""
        st = self.settings
        return not (self.occlusion != 1 or st.aov_predicted_radius or st.aov_spectrum
                    or st.radius_rule != "PPM" or self.after_delta_only
                    or st.frequency_model == "PAPER")

    def set_radius_cut(self, R2):
        """Before a pass: radius_cut = the largest pixel radius sqrt(R2 (P,)),
        which no pixel's held-radius decision tells from infinity
        (docs/frequency.md "Cost"); inf (every occluder marched) when the
        predicted radii are shown (AOVs) or the radius rule is not PPM's."""
        st = self.settings
        R2 = np.asarray(R2)
        exact = (st.aov_predicted_radius or st.aov_spectrum or st.radius_rule != "PPM"
                 or not R2.size or not np.isfinite(R2).all())
        self.radius_cut = np.inf if exact else float(np.sqrt(R2.max()))

    def _spectrum_at_hits(self, spec, seg, rec, dep, rows, left=None):
        """Frequency photons: travel, occlusion and projection onto the hit
        surface (rays 0..K-1 that deposit or continue); the predicted radius
        of the deposits dep0..dep1-1, as fold keys.  left (K,) int32: the
        counted deposits each ray may still predict at (freq_deposits;
        updated in place).  Returns the (K, 3) on-surface spectra (rows of
        other rays unused)."""
        reach = self.reach                   # once: the flag and the map agree
        chain = self.chain_params()._replace(gate=reach is not None)
        if left is None:
            # no budget: the kernel reads left only when chain.deposits > 0
            left = _NO_BUDGET
            chain = chain._replace(deposits=0)
        out, _ = FK.spectrum_at_hits(chain, rows, spec, seg, rec, self.march,
                                     dep.buf, self._NO_REACH if reach is None else reach,
                                     left)
        # rays 0..K-1's deposits lead the bounce's (ray order); the others' keep NaN
        d0 = rows.dep0
        r = dep.buf.r[d0:d0 + int(np.searchsorted(dep.buf.src[d0:rows.dep1], rows.K))]
        r[:] = F.radius_fold_key(r, self.settings.frequency_model)
        return out

    def _occlusion_march(self):
        """(occlusion mode, MarchGrid) for the arriving chain: mode 0 = no
        grid, 1 = march, 2 = a grid without geometry (march_occlusion gives
        inf); a placeholder MarchGrid unless 1."""
        g = self.occ_grid
        if g is not None and np.isfinite(g.dist).any():
            return 1, march_grid(g, float(self.occ_locality))
        return (0 if g is None else 2), no_march_grid()

    def _spectrum_leaving(self, spec_hit, n_next, prim, rec, d64, din):
        """Frequency photons leaving the surface: interface (delta lobes),
        off_surface, lobe; din (K, 3) the directions the rays arrived along."""
        if self._lobes is None:
            self._lobes = FK.surface_lobes(self.mtab, self.tris.mat, self.kappa)
        out, bad = FK.spectrum_leaving(self.chain_params(), n_next, spec_hit, rec, d64, prim,
                                       self._lobes, din)
        if bad >= 0:       # raise what spectrum.lobe_variance raises
            m = self.tris.mat[prim[rec.nxt_src[bad]]]
            F.lobe_variance(self.mtab.kind[m:m + 1, 0], self.mtab.roughness[m:m + 1, 0])
        return out
