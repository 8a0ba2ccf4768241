"""Photon tracing for one pass: emission, bounces, deposits, frequency spectra.

Photons leave the emitters (``lights.sample_photons``), bounce by BSDF sampling
in importance mode with Russian roulette, and are deposited at every
non-specular hit after the first bounce (the first hit is next-event
estimation's job) or from the first hit with ``photons_for_direct``.  The
first ``n_freq`` photons of a batch also carry a light-field spectrum (a, b, c)
updated by ``core.frequency`` on travel, occlusion, onto/off the surface, the
BSDF lobe and curvature; each deposit gets its predicted radius.

Two implementations with the same statistics (tests/test_photon_kernels.py):

- the compiled path (default): after each Embree call one numba kernel
  (``core.photon_kernels.bounce_kernel``) interpolates the hits, stores the
  deposits, samples Lambert / mirror / smooth-glass closures, plays Russian
  roulette and compacts the live photons in place.  Photons on any other
  material (textures, GGX, Oren-Nayar, multi-lobe, translucent...) go through
  ``bsdf.sample_bsdf`` in numpy, and are appended back.  Frequency photons
  are traced as a separate batch through the same kernels; their spectrum
  updates run compiled on the hits and survivors the kernel records
  (``core.frequency_kernels``: travel -> occlusion march -> occlude ->
  onto_surface -> predicted radius, then off_surface -> lobe -> curvature;
  the same numbers as the ``core.frequency`` operators, which
  ``compiled_frequency = False`` runs instead), only for hits that deposit
  or continue.
- the numpy path (``PhotonTracer.fast = False``), every closure through
  ``bsdf.sample_bsdf``: the reference.
"""
from __future__ import annotations

import os

import numpy as np

from ..materials import bsdf as B
from ..lights import lights as Lt
from ..frequency import spectrum as F
from ..frequency import kernels as FK
from . import photon_kernels as PK
from ..accel import REL_OFFSET, intersect_f32, surface_point
from ..scene.model import Scene

from ..mathutil import LUMINANCE as LUM, dot as _dot  # noqa: E402
#: Batches of at least this many photons are traced as two halves (see trace).
SPLIT_MIN = 8192
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


def _children(rng):
    """Two independent child generators of rng (deterministic)."""
    try:
        return rng.spawn(2)
    except (AttributeError, TypeError, ValueError):    # no SeedSequence behind rng
        return [np.random.default_rng(int(s)) for s in rng.integers(0, 2**63, 2)]


def _travel_occlude_travel(spec, t, a_occ, t_occ, D, model, A_MAX):
    """(N, 3) spectra after a segment of length t whose nearest occluder
    (a_occ, at t_occ; inf = none) acts where it stands: travel t_occ, occlude,
    travel t - t_occ (the numpy reference of frequency_kernels.spectrum_at_hits)."""
    has = np.isfinite(a_occ)
    t1 = np.where(has, t_occ, t)
    s = F.travel(spec, np.minimum(t1, D), model, A_MAX)
    s = F.occlude(s, a_occ, model, A_MAX)
    if np.any(has):
        s2 = F.travel(s[has], np.minimum(np.maximum(t[has] - t_occ[has], 0.0), D), model, A_MAX)
        s[has] = s2
    return s


class _Deposits:
    """Growable deposit buffers (rows 0..n-1 used), float64; r = predicted radius."""

    def __init__(self, cap):
        cap = max(int(cap), 16)
        self.p = np.empty((cap, 3))
        self.ng = np.empty((cap, 3))
        self.wi = np.empty((cap, 3))
        self.power = np.empty((cap, 3))
        self.r = np.empty(cap)
        self.src = np.empty(cap, np.int64)
        self.bounce = np.empty(cap, np.int32)
        self.spec = np.empty((cap, 3))       # (a, b, c); rows of classic photons unused
        self.n = 0

    def reserve(self, k: int):
        """Make room for k more rows (doubling: amortised O(1) per deposit)."""
        need = self.n + int(k)
        cap = self.r.shape[0]
        if need <= cap:
            return
        cap = max(2 * cap, need)
        for name in ("p", "ng", "wi", "power", "r", "src", "bounce", "spec"):
            a = getattr(self, name)
            b = np.empty((cap,) + a.shape[1:], a.dtype)
            b[:self.n] = a[:self.n]
            setattr(self, name, b)

    def extend(self, other: "_Deposits"):
        """Append the rows of another buffer (one copy of its rows)."""
        k = other.n
        self.reserve(k)
        a, b = self.n, self.n + k
        for name in ("p", "ng", "wi", "power", "r", "bounce", "spec"):
            getattr(self, name)[a:b] = getattr(other, name)[:k]
        self.n = b

    def result(self):
        if self.n == 0:
            return None
        n = self.n
        return {"p": self.p[:n], "ng": self.ng[:n], "wi": self.wi[:n],
                "power": self.power[:n], "rpred": self.r[:n], "bounce": self.bounce[:n],
                "spec": np.where(np.isnan(self.r[:n])[:, None], 0.0, self.spec[:n])}


class PhotonTracer:
    """Traces batches of photons through one scene (state shared across passes)."""

    #: Use the compiled path (False: the numpy reference path).
    fast = True
    #: Compiled path: frequency spectra by core.frequency_kernels (False: the
    #: numpy core.frequency operators on the recorded hits; same results).
    compiled_frequency = True

    def __init__(self, scene, accel, mtab, light_table, settings, plan, kappa, occ_grid,
                 occ_locality, D):
        self.scene, self.accel, self.mtab = scene, accel, mtab
        self.light_table, self.settings, self.plan = light_table, settings, plan
        self.kappa, self.occ_grid, self.occ_locality, self.D = kappa, occ_grid, occ_locality, D
        self.tris = PK.build_triangle_data(scene)
        self.fmat = PK.build_fast_materials(mtab)
        self._tri_uv = None
        self.fast_emission = PK.fast_emission_ok(light_table)
        self._light_arrays = PK.light_arrays(light_table) if self.fast_emission else None
        # Deposits per photon (max seen, x1.25 margin on use): buffer sizing.
        self._dpp = 2.0
        self._lobe_b = None          # (lobe_b, lobe_ok) per material, on first use
        # FK.spectrum_at_hits' occlusion arguments (builds the march's blocks:
        # 0.14 s at 64^3, here rather than in the first pass)
        self._occ_args = self._occlusion_args() if occ_grid is not None else None

    def trace(self, n: int, n_freq: int, rng):
        """Trace n photons (the first n_freq carry a spectrum); return deposits.

        Returns None when nothing is deposited, else a dict of float64 arrays:
        p (K, 3) hit position, ng (K, 3) geometric normal on the side the
        photon came from, wi (K, 3) unit direction back to where it came from,
        power (K, 3), rpred (K,) predicted radius (NaN for classic photons;
        negated with the PAPER model: the grid keeps a minimum), bounce (K,)
        int32 index of the path vertex (0 = first hit; diagnostics and tests).
        """
        if not self.fast:
            return self._trace_numpy(n, n_freq, rng)
        if n < SPLIT_MIN:
            return self._trace_part(n, n_freq, rng, _Deposits(self._dpp * n + 64)).result()
        # Two halves on independent child streams, always (the image does not
        # depend on the number of cores), traced concurrently when there are
        # two threads: Embree and the kernels release the GIL.  The deposits
        # are the first half's followed by the second's in both cases.
        r0, r1 = _children(rng)
        h, hf = n // 2, n_freq // 2
        # The first buffer is sized for both halves (deposits per photon seen
        # so far, +25%): the second is appended without reallocating.
        d0 = _Deposits(self._dpp * n + 64)
        if _threads() > 1:
            d1 = _Deposits(self._dpp * (n - h) + 64)
            f0 = _pool().submit(self._trace_part, h, hf, r0, d0)
            self._trace_part(n - h, n_freq - hf, r1, d1)
            f0.result()
            d0.extend(d1)                # one copy of the second half's rows
        else:
            self._trace_part(h, hf, r0, d0)
            self._trace_part(n - h, n_freq - hf, r1, d0)
        return d0.result()

    def _trace_part(self, n: int, n_freq: int, rng, dep: "_Deposits") -> "_Deposits":
        """Emit and trace n photons (the first n_freq with a spectrum); their
        deposits are appended to dep."""
        n_before = dep.n
        if self.fast_emission:
            u = rng.random((n, 6))
            ph = None
        else:
            u = None
            ph = Lt.sample_photons(self.light_table, n, rng)
        if n_freq:
            self._trace_batch(u, ph, 0, n_freq, rng, dep, True)
        if n > n_freq:
            self._trace_batch(u, ph, n_freq, n, rng, dep, False)
        self._dpp = max(self._dpp, 1.25 * (dep.n - n_before) / max(n, 1))
        return dep

    # ------------------------------------------------------- compiled path
    def _trace_batch(self, u_emit, ph, a: int, b: int, rng, dep: _Deposits, freq: bool):
        """Trace photons a..b-1: from the uniforms u_emit (n, 6) of the fused
        emission kernel, or from the emission ``ph`` of lights.sample_photons.
        freq: these photons carry a spectrum."""
        st = self.settings
        n = b - a
        o32 = np.empty((n, 3), np.float32)
        d32 = np.empty((n, 3), np.float32)
        d64 = np.empty((n, 3))
        pw = np.empty((n, 3))
        fo = np.empty(n)
        rel = REL_OFFSET
        floor = self.accel.abs_floor / REL_OFFSET
        spec = None
        if u_emit is not None:
            spec = np.empty((n if freq else 1, 3))
            K = PK.emit_lights_state(u_emit[a:b], *self._light_arrays, rel, floor,
                                     o32, d32, d64, pw, fo, freq, spec)
            spec = spec[:K] if freq else None
        else:
            fal = ph.get("falloff_r2")
            fal = np.zeros(n) if fal is None else np.ascontiguousarray(fal[a:b], np.float64)
            src = np.empty(n, np.int64)
            K = PK.emit_kernel(np.ascontiguousarray(ph["o"][a:b], np.float64),
                               np.ascontiguousarray(ph["d"][a:b], np.float64),
                               np.ascontiguousarray(ph["power"][a:b], np.float64),
                               fal, rel, floor, o32, d32, d64, pw, fo, src)
            if freq:
                spec = np.asarray(ph["freq_init"], np.float64)[a:b][src[:K]]
        tr, fm = self.tris, self.fmat
        record = freq
        cg = n if fm.any_generic else 1
        gen = (np.empty(cg, np.int64), np.empty((cg, 3)), np.empty((cg, 3)), np.empty((cg, 3)),
               np.empty((cg, 3)), np.empty((cg, 3)), np.empty((cg, 3)))
        cr = n if record else 1
        rec = (np.empty(cr), np.empty((cr, 3)), np.empty(cr), np.empty(cr, bool))
        nxt = (np.empty(cr, np.int64), np.empty(cr, bool))
        for bounce in range(st.max_bounces + 1):
            if K == 0:
                break
            prim, bu, bv, tf = intersect_f32(self.accel, o32[:K], d32[:K])
            sample = bounce < st.max_bounces
            store = bool(st.photons_for_direct or bounce > 0)
            roulette = bounce + 1 >= st.rr_start
            u = rng.random((K, 4))
            dep.reserve(K)
            if record:
                o_seg = o32[:K].astype(np.float64)
                d_seg = d64[:K].copy()
            n0 = dep.n
            n_next, n_dep, n_gen = PK.bounce_kernel(
                K, prim, bu, bv, tf, o32, d32, d64, pw, fo, bounce == 0, store, sample,
                roulette, tr.p, tr.n, tr.ng, tr.mat, fm.cls, fm.col, fm.ior, fm.deposit,
                u, rel, floor, dep.p, dep.ng, dep.wi, dep.power, dep.r, dep.bounce, n0, bounce,
                *gen,
                record, *rec, dep.src, *nxt)
            dep.n = n_dep
            if n_gen:
                n_next = self._generic_bounce(n_gen, n_next, gen, u, roulette, o32, d32, d64,
                                              pw, nxt if record else None)
            if record:
                # After the generic bounce: only hits that deposit or continue
                # need a spectrum (the bounce reads o_seg/d_seg/rec, not the
                # live state it appended to).
                spec_hit = self._spectrum_at_hits(spec, K, o_seg, d_seg, rec, dep, n0,
                                                  nxt, n_next)
                if n_next:
                    spec = self._spectrum_leaving(spec_hit, n_next, prim, rec, nxt, d64)
            K = n_next

    def _generic_bounce(self, g, n_next, gen, u, roulette, o32, d32, d64, pw, nxt):
        """bsdf.sample_bsdf for the g hits on materials without a fast path;
        survivors are appended at row n_next of the live state.  Returns the
        new number of live photons."""
        gi, gp, gng, gns, gwi, gpow, gbary = (x[:g] for x in gen)
        prim = gbary[:, 0].astype(np.int64)
        mat = self.tris.mat[prim]
        uv = np.zeros((g, 2))
        if self.mtab.textures and np.any(self.mtab.tex[mat] >= 0):
            if self._tri_uv is None:
                self._tri_uv = np.ascontiguousarray(self.scene.tri_uv, np.float64)
            PK.gen_attributes(gbary, g, self._tri_uv, uv)
        colors = B.lobe_colors(self.mtab, mat, uv)
        ug = u[gi]
        wo, wgt, pdf, is_delta, valid = B.sample_bsdf(
            self.mtab, mat, colors, gns, gng, gwi, ug[:, :3], subset="all", mode="importance")
        ok = valid & np.all(np.isfinite(wgt), axis=1) & (wgt.max(axis=1) > 0)
        if roulette:
            q = np.clip(wgt @ LUM, 0.0, 1.0)
            ok &= ug[:, 3] < q
            wgt = wgt / np.maximum(q, 1e-12)[:, None]
        sel = np.nonzero(ok)[0]
        if sel.size == 0:
            return n_next
        PK.append_survivors(n_next, sel, gp, gng, wo, wgt, gpow, REL_OFFSET,
                            self.accel.abs_floor / REL_OFFSET, o32, d32, d64, pw)
        if nxt is not None:
            nxt[0][n_next:n_next + sel.size] = gi[sel]
            nxt[1][n_next:n_next + sel.size] = is_delta[sel]
        return n_next + sel.size

    def _spectrum_at_hits(self, spec, K, o_seg, d_seg, rec, dep, n0, nxt, n_next):
        """Frequency photons: travel, occlusion and projection onto the hit
        surface (rays 0..K-1 that deposit or continue); predicted radius of
        the deposits n0..dep.n-1.  Returns the (K, 3) on-surface spectra
        (rows of other rays unused)."""
        model = self.settings.frequency_model
        A_MAX = self.D * self.D
        rec_t, rec_ng, rec_nswi, rec_hit = rec
        if self.compiled_frequency:
            out = np.empty((K, 3))
            if self._occ_args is None:
                self._occ_args = self._occlusion_args()
            occ, args = self._occ_args
            FK.spectrum_at_hits(model == "PAPER", K, spec, rec_t, rec_ng, rec_hit, o_seg, d_seg,
                                float(self.D), float(A_MAX), n0, dep.n, dep.src, n_next, nxt[0],
                                np.empty(K, bool), occ, *args, out, dep.spec, dep.r)
            return out
        hi = np.nonzero(rec_hit[:K])[0]
        t = rec_t[hi]
        if self.occ_grid is not None:
            from ..frequency.occlusion import march_occlusion
            a_occ, t_occ = march_occlusion(self.occ_grid, o_seg[hi], d_seg[hi], t,
                                           self.occ_locality, return_t=True)
            s = _travel_occlude_travel(spec[hi], t, a_occ, t_occ, self.D, model, A_MAX)
        else:
            s = F.travel(spec[hi], np.minimum(t, self.D), model, A_MAX)
        cos_i = np.abs(_dot(rec_ng[hi], d_seg[hi]))
        s = F.onto_surface(s, cos_i, model, A_MAX)
        out = np.zeros((K, 3))
        out[hi] = s
        if dep.n > n0:
            dep.spec[n0:dep.n] = out[dep.src[n0:dep.n]]
            rp = F.predicted_radius(dep.spec[n0:dep.n], np.inf, np.inf, model)
            # The grid keeps a per-pixel minimum; the paper's rule keeps the
            # maximum, so its radii travel negated.
            dep.r[n0:dep.n] = -rp if model == "PAPER" else rp
        return out

    def _occlusion_args(self):
        """(mode, grid arrays) for FK.spectrum_at_hits: mode 0 = no grid, 1 =
        march, 2 = a grid without geometry (march_occlusion gives inf)."""
        g = self.occ_grid
        if g is not None and np.isfinite(g.dist).any():
            from ..frequency.occlusion import check_locality, march_blocks
            check_locality(g, self.occ_locality)
            mb = march_blocks(g)
            return 1, (g.dist, g.cone, mb.bmin, mb.bcone, mb.vmin, mb.vcone, mb.has_voxel_level,
                       mb.B, g.lo, g.cell, g.res, float(self.occ_locality), g.voxel_diagonal)
        z1, z4 = np.zeros((1, 1, 1), np.float32), np.zeros((1, 1, 1, 4), np.float32)
        # Same dtypes and ranks as a real grid's MarchBlocks (block cones
        # (NB,NB,NB,8) float64, voxel cones (R,R,R,8) int16), so the kernel
        # compiles once for both.
        return (0 if g is None else 2), (z1, z4, np.zeros((1, 1, 1)), np.zeros((1, 1, 1, 8)), z1,
                                         np.zeros((1, 1, 1, 8), np.int16), False, 1, np.zeros(3),
                                         np.ones(3), 1, 0.0, 0.0)

    def _spectrum_leaving(self, spec_hit, n_next, prim, rec, nxt, d64):
        """Frequency photons leaving the surface: off_surface, lobe, curvature."""
        model = self.settings.frequency_model
        A_MAX = self.D * self.D
        rec_t, rec_ng, rec_nswi, rec_hit = rec
        srcs = nxt[0][:n_next]
        dl = nxt[1][:n_next]
        if self.compiled_frequency:
            if self._lobe_b is None:
                self._lobe_b = FK.material_lobe_variance(self.mtab)
            out = np.empty((n_next, 3))
            kap = self.kappa if self.kappa is not None else np.zeros(1)
            bad = FK.spectrum_leaving(model == "PAPER", n_next, spec_hit, nxt[0], nxt[1], rec_ng,
                                      rec_nswi, d64, prim, self.tris.mat, *self._lobe_b, kap,
                                      self.kappa is not None, float(A_MAX), out)
            if bad >= 0:       # raise what frequency.lobe_variance raises
                m = self.tris.mat[prim[srcs[bad]]]
                F.lobe_variance(self.mtab.kind[m:m + 1, 0], self.mtab.roughness[m:m + 1, 0])
            return out
        s = spec_hit[srcs]
        cos_o = np.abs(_dot(rec_ng[srcs], d64[:n_next]))
        s = F.off_surface(s, cos_o, model, A_MAX)
        pr = prim[srcs]
        mat = self.tris.mat[pr]
        kinds = self.mtab.kind[mat, 0]
        rough = self.mtab.roughness[mat, 0]
        b_lobe = np.where(dl, 0.0, F.lobe_variance(kinds, rough))
        s = F.brdf(s, b_lobe, model, A_MAX)
        if self.kappa is not None:
            kap = self.kappa[pr] * rec_nswi[srcs]
            s = np.where(dl[:, None], F.curvature(s, kap, model, A_MAX), s)
        return s

    # ---------------------------------------------------------- numpy path
    def _trace_numpy(self, n: int, n_freq: int, rng):
        """The generic numpy path (every closure through ``bsdf.sample_bsdf``): the
        reference the compiled path is tested against (``fast = False``)."""
        st = self.settings
        ph = Lt.sample_photons(self.light_table, n, rng)
        d = ph["d"]
        o = ph["o"] + d * self.accel.offset_scale(ph["o"])[:, None]
        power = ph["power"]
        # Cycles' soft falloff (point/spot with a radius) scales the field by
        # d^2/(d^2 + r^2); no physical emitter does that, so it is applied at
        # the photon's first hit (lights.sample_photons gives r^2 per photon).
        falloff_r2 = np.asarray(ph.get("falloff_r2", np.zeros(n)), np.float64)
        alive = np.all(np.isfinite(power), axis=1) & (power.max(axis=1) > 0)
        is_freq = np.zeros(n, bool)
        is_freq[:n_freq] = True
        spec = np.zeros((n, 3))
        if n_freq:
            spec = np.asarray(ph["freq_init"], np.float64).copy()
        idx = np.nonzero(alive)[0]
        o, d, power, spec, is_freq = o[idx], d[idx], power[idx], spec[idx], is_freq[idx]
        falloff_r2 = falloff_r2[idx]
        A_MAX = self.D * self.D
        model = st.frequency_model
        out_p, out_ng, out_wi, out_pow, out_r, out_b, out_s = [], [], [], [], [], [], []
        for bounce in range(st.max_bounces + 1):
            if o.shape[0] == 0:
                break
            h = self.accel.intersect(o, d)
            keep = h.hit
            o, d, power, spec, is_freq = o[keep], d[keep], power[keep], spec[keep], is_freq[keep]
            if o.shape[0] == 0:
                break
            ii = np.nonzero(keep)[0]
            hits = type(h)(h.t[ii], h.prim[ii], h.u[ii], h.v[ii])
            if bounce == 0 and np.any(falloff_r2 > 0):
                t2 = hits.t ** 2
                power = power * (t2 / (t2 + falloff_r2[ii]))[:, None]
            p, ng, ns, uv = surface_point(self.scene.tri_p, self.scene.tri_n, self.scene.tri_uv,
                                          hits.prim, hits.u, hits.v)
            wi = -d
            mat = self.scene.tri_mat[hits.prim]
            if np.any(is_freq):
                fq = np.nonzero(is_freq)[0]
                if self.occ_grid is not None:
                    from ..frequency.occlusion import march_occlusion
                    a_occ, t_occ = march_occlusion(self.occ_grid, o[fq], d[fq], hits.t[fq],
                                                   self.occ_locality, return_t=True)
                    s = _travel_occlude_travel(spec[fq], hits.t[fq], a_occ, t_occ, self.D,
                                               model, A_MAX)
                else:
                    s = F.travel(spec[fq], np.minimum(hits.t[fq], self.D), model, A_MAX)
                cos_i = np.abs(_dot(ng[fq], wi[fq]))
                s = F.onto_surface(s, cos_i, model, A_MAX)
                spec[fq] = s
            deposit = self.mtab.has_nondelta[mat]
            if not (st.photons_for_direct or bounce > 0):
                deposit = np.zeros_like(deposit)
            if np.any(deposit):
                dq = np.nonzero(deposit)[0]
                sgn = np.where(_dot(ng[dq], wi[dq]) >= 0, 1.0, -1.0)[:, None]
                out_p.append(p[dq])
                out_ng.append(ng[dq] * sgn)
                out_wi.append(wi[dq])
                out_pow.append(power[dq])
                r = np.full(dq.size, np.nan)
                fqd = is_freq[dq]
                if np.any(fqd):
                    rp = F.predicted_radius(spec[dq[fqd]], np.inf, np.inf, model)
                    # The grid keeps a per-pixel minimum; the paper's rule keeps
                    # the maximum, so its radii travel negated.
                    r[fqd] = -rp if model == "PAPER" else rp
                out_r.append(r)
                out_b.append(np.full(dq.size, bounce, np.int32))
                out_s.append(spec[dq])
            if bounce == st.max_bounces:
                break
            colors = B.lobe_colors(self.mtab, mat, uv)
            u = rng.random((mat.size, 4))
            wo_new, wgt, pdf, is_delta, valid = B.sample_bsdf(
                self.mtab, mat, colors, ns, ng, wi, u[:, :3], subset="all", mode="importance")
            ok = valid & np.all(np.isfinite(wgt), axis=1) & (wgt.max(axis=1) > 0)
            if bounce + 1 >= st.rr_start:
                # Russian roulette on the luminance of the bounce weight.
                q = np.clip(wgt @ LUM, 0.0, 1.0)
                survive = u[:, 3] < q
                wgt = wgt / np.maximum(q, 1e-12)[:, None]
                ok &= survive
            k = np.nonzero(ok)[0]
            if is_freq.any():
                fk = k[is_freq[k]]
                if fk.size:
                    s = spec[fk]
                    cos_o = np.abs(_dot(ng[fk], wo_new[fk]))
                    s = F.off_surface(s, cos_o, model, A_MAX)
                    kinds = self.mtab.kind[mat[fk], 0]
                    rough = self.mtab.roughness[mat[fk], 0]
                    dl = is_delta[fk]
                    b_lobe = np.where(dl, 0.0, F.lobe_variance(kinds, rough))
                    s = F.brdf(s, b_lobe, model, A_MAX)
                    if self.kappa is not None:
                        kap = self.kappa[hits.prim[fk]] * np.where(_dot(ns[fk], wi[fk]) >= 0, 1.0, -1.0)
                        s = np.where(dl[:, None], F.curvature(s, kap, model, A_MAX), s)
                    spec[fk] = s
            o = self.accel.spawn(p[k], ng[k], wo_new[k])
            d = wo_new[k]
            power = power[k] * wgt[k]
            spec = spec[k]
            is_freq = is_freq[k]
        if not out_p:
            return None
        return {"p": np.concatenate(out_p), "ng": np.concatenate(out_ng),
                "wi": np.concatenate(out_wi), "power": np.concatenate(out_pow),
                "rpred": np.concatenate(out_r), "bounce": np.concatenate(out_b),
                "spec": np.concatenate(out_s)}


def triangle_curvature(scene: Scene) -> np.ndarray:
    """(T,) float64 mean normal curvature of each triangle from its corner normals.

    kappa = mean over edges of dot(n_j - n_i, p_j - p_i) / |p_j - p_i|^2: +1/R
    on the outside of a sphere of radius R whose normals point outwards, 0 on
    flat-shaded triangles (curvature comes from the shading normals).
    """
    P = scene.tri_p.astype(np.float64)
    N = scene.tri_n.astype(np.float64)
    k = np.zeros(P.shape[0])
    for i, j in ((0, 1), (1, 2), (2, 0)):
        dp = P[:, j] - P[:, i]
        dn = N[:, j] - N[:, i]
        k += _dot(dn, dp) / np.maximum(_dot(dp, dp), 1e-300)
    return k / 3.0
