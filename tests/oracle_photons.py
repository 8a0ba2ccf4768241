"""Test oracles of the photon tracer: the numpy tracer and the numpy chains.

- :func:`trace_numpy`: ``PhotonTracer.trace`` in numpy, every closure through
  ``bsdf.sample_bsdf`` (the reference of tests/test_photon_kernels.py);
- :func:`arrive_numpy`, :func:`leave_numpy`: the two chains of a frequency
  photon (``core.frequency.kernels.arrive`` / ``leave``) by the numpy
  operators of ``core.frequency.spectrum``; :func:`use_numpy_chains` makes a
  tracer run them on the hits its compiled path records
  (tests/test_frequency_kernels.py: same stream, same paths);
- :func:`sample_fast_batch`: ``core.materials.fast.sample_fast`` over arrays.
"""
import types

import numpy as np
from numba import njit

from core.accel import surface_point
from core.frequency import spectrum as F
from core.frequency.curvature import bounce_interface, delta_ior
from core.frequency.occlusion_march import march_occlusion
from core import lights as Lt
from core.lights.emission import soft_light_first_hit
from core import materials as B
from core.materials.fast import sample_fast
from core.mathutil import LUMINANCE as LUM, dot as _dot


def travel_occlude_travel(spec, t, a_occ, t_occ, D, model, A_MAX):
    """(N, 3) spectra after a segment of length t whose nearest occluder
    (a_occ, at t_occ; inf = none) acts where it stands: travel t_occ, occlude,
    travel t - t_occ."""
    has = np.isfinite(a_occ)
    t1 = np.where(has, t_occ, t)
    s = F.travel(spec, np.minimum(t1, D), model, A_MAX)
    s = F.occlude(s, a_occ, model, A_MAX)
    if np.any(has):
        s2 = F.travel(s[has], np.minimum(np.maximum(t[has] - t_occ[has], 0.0), D), model, A_MAX)
        s[has] = s2
    return s


def radius_cut_numpy(spec, t, r_cut, D):
    """``kernels.radius_cut`` of spectra spec (N, 3) over segments of length
    t (N,): (N, 3) rows (q0, q1, q2), inf where there is no cut."""
    A_MAX = D * D
    s = F.sanitize(np.asarray(spec, np.float64), A_MAX)
    ae = F.travel(s, np.minimum(t, D), "CORRECTED", A_MAX)[:, 0]
    den = 2.0 * F.BETA * ae - r_cut * r_cut
    ok = (den > 0) & np.isfinite(r_cut)
    L = np.where(ok, r_cut * r_cut / np.where(ok, den, 1.0), 0.0)
    q = s[:, [0, 2, 1]] * L[:, None]
    q[~ok] = np.inf
    return q


def arrive_numpy(tracer, spec, o, d, t, ng, used=None, ng0=None):
    """The arriving chain (``kernels.arrive``) of spectra spec (N, 3) along
    segments o, d (N, 3), t (N,) onto surfaces of geometric normal ng (N, 3),
    with the tracer's model, occlusion grid and D.  used (N,) bool: the
    segments whose occluder is marched (``kernels.marked_segments``; the
    others get a_occ = inf), None = all.  ng0 (N, 3): the normals of the
    surfaces the segments leave (``kernels.Segments.ng0``), None = none.
    Returns (N, 3)."""
    model = tracer.settings.frequency_model
    A_MAX = tracer.D * tracer.D
    if tracer.occ_grid is not None:
        a_occ, t_occ = np.full(len(t), np.inf), np.full(len(t), np.inf)
        u = np.ones(len(t), bool) if used is None else np.asarray(used, bool)
        cut = None
        r_cut = float(getattr(tracer, "radius_cut", np.inf))
        if model == "CORRECTED" and r_cut < np.inf:
            cut = radius_cut_numpy(spec[u], t[u], r_cut, tracer.D)
        if u.any():
            a_occ[u], t_occ[u] = march_occlusion(tracer.occ_grid, o[u], d[u], t[u],
                                                 tracer.occ_locality, return_t=True, cut=cut,
                                                 n_start=None if ng0 is None else ng0[u],
                                                 n_end=ng[u])
        s = travel_occlude_travel(spec, t, a_occ, t_occ, tracer.D, model, A_MAX)
    else:
        s = F.travel(spec, np.minimum(t, tracer.D), model, A_MAX)
    return F.onto_surface(s, np.abs(_dot(ng, d)), model, A_MAX)


def leave_numpy(tracer, spec, ng, wo, mat, delta, iface):
    """The leaving chain (``kernels.leave``) of on-surface spectra spec (N, 3)
    along wo (N, 3) from surfaces of geometric normal ng (N, 3) and material
    mat (N,); delta (N,) bool a delta lobe was sampled; iface the (scale, mu,
    k) of ``curvature.bounce_interface``, or None (no interface step).
    Returns (N, 3)."""
    model = tracer.settings.frequency_model
    A_MAX = tracer.D * tracer.D
    if iface is not None:
        spec = np.where(delta[:, None], F.interface(spec, *iface, model, A_MAX), spec)
    s = F.off_surface(spec, np.abs(_dot(ng, wo)), model, A_MAX)
    b_lobe = np.where(delta, 0.0, F.lobe_variance(tracer.mtab.kind[mat, 0],
                                                  tracer.mtab.roughness[mat, 0]))
    return F.brdf(s, b_lobe, model, A_MAX)


def _iface(tracer, prim, sign, ng, d_in, d_out, mat):
    """``curvature.bounce_interface`` of a tracer's hits, or None without curvature."""
    if tracer.kappa is None:
        return None
    return bounce_interface(tracer.kappa, prim, sign, ng, d_in, d_out,
                            delta_ior(tracer.mtab)[mat])


def spectrum_at_hits_numpy(self, spec, seg, rec, dep, rows):
    """``PhotonTracer._spectrum_at_hits`` by :func:`arrive_numpy` (every hit;
    the occluder of the segments ``kernels.marked_segments`` marks)."""
    model = self.settings.frequency_model
    K = rows.K
    hi = np.nonzero(rec.hit[:K])[0]
    used = np.zeros(K, bool)
    src = dep.buf.src[rows.dep0:rows.dep1]
    used[src[src < K]] = True            # rays >= K: classic photons of the batch
    nxt = rec.nxt_src[:rows.n_next]
    used[nxt[(rec.nxt_delta[:rows.n_next] | self.chain_params().march_all) & (nxt < K)]] = True
    out = np.zeros((K, 3))
    ng0 = seg.ng0[hi] if seg.ng0.shape[0] == K else None
    out[hi] = arrive_numpy(self, spec[hi], seg.o[hi], seg.d[hi], rec.t[hi], rec.ng[hi],
                           used[hi], ng0)
    buf = dep.buf
    k = rows.dep0 + np.flatnonzero(buf.src[rows.dep0:rows.dep1] < K)
    if k.size:
        buf.spec[k] = out[buf.src[k]]
        buf.r[k] = F.radius_fold_key(F.predicted_radius(buf.spec[k], np.inf, np.inf, model),
                                     model)
    return out


def spectrum_leaving_numpy(self, spec_hit, n_next, prim, rec, d64, din):
    """``PhotonTracer._spectrum_leaving`` by :func:`leave_numpy`."""
    srcs = rec.nxt_src[:n_next]
    pr = prim[srcs]
    mat = self.tris.mat[pr]
    iface = _iface(self, pr, rec.nswi[srcs], rec.ng[srcs], din[srcs], d64[:n_next], mat)
    return leave_numpy(self, spec_hit[srcs], rec.ng[srcs], d64[:n_next], mat,
                       rec.nxt_delta[:n_next], iface)


def use_numpy_chains(tracer):
    """Make ``tracer`` (a PhotonTracer) run the numpy chains on the hits its
    compiled path records (an instance override; a new tracer is unchanged)."""
    tracer._spectrum_at_hits = types.MethodType(spectrum_at_hits_numpy, tracer)
    tracer._spectrum_leaving = types.MethodType(spectrum_leaving_numpy, tracer)
    return tracer


def trace_numpy(self, n: int, n_freq: int, rng):
    """``PhotonTracer.trace`` of the tracer ``self`` in numpy: every closure
    through ``bsdf.sample_bsdf``, the spectra by the ``spectrum`` operators
    (:func:`arrive_numpy`, :func:`leave_numpy`).  Same statistics as the
    compiled tracer (another use of the random stream)."""
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
    ng0 = np.zeros((idx.size, 3))          # the surface each segment leaves (emitter: none)
    falloff_r2 = falloff_r2[idx]
    # A soft light's disc sample, read at the first hit
    # (lights.emission.soft_light_first_hit: power and direction).
    light = np.asarray(ph["light"], np.int64)[idx]
    soft_disc = np.asarray(ph.get("soft_disc", np.zeros((n, 4))), np.float64)[idx]
    model = st.frequency_model
    out_p, out_ng, out_wi, out_pow, out_r, out_b, out_s = [], [], [], [], [], [], []
    for bounce in range(st.max_bounces + 1):
        if o.shape[0] == 0:
            break
        h = self.accel.intersect(o, d)
        keep = h.hit
        o, d, power, spec, is_freq = o[keep], d[keep], power[keep], spec[keep], is_freq[keep]
        ng0 = ng0[keep]
        if o.shape[0] == 0:
            break
        ii = np.nonzero(keep)[0]
        hits = type(h)(h.t[ii], h.prim[ii], h.u[ii], h.v[ii])
        if bounce == 0 and np.any(falloff_r2 > 0):
            t2 = hits.t ** 2
            power = power * (t2 / (t2 + falloff_r2[ii]))[:, None]
        p, ng, ns, uv = surface_point(self.scene.tri_p, self.scene.tri_n, self.scene.tri_uv,
                                      hits.prim, hits.u, hits.v)
        # wi_f: the direction the frequency chain travelled (a soft light's
        # centre at the first hit, as photons.PhotonTracer's segments).
        wi = wi_f = -d
        if bounce == 0:
            f, d_soft = soft_light_first_hit(self.light_table, light[ii], soft_disc[ii], d,
                                             hits.t, ng)
            power = power * f[:, None]
            wi = -d_soft
        mat = self.scene.tri_mat[hits.prim]
        if np.any(is_freq):
            # the occluder is marched on the segments kernels.marked_segments
            # marks: deposits (spec) and delta survivors; the others continue
            # with spec_plain (chosen after sampling)
            fq = np.nonzero(is_freq)[0]
            spec_plain = spec.copy()
            spec_plain[fq] = arrive_numpy(self, spec[fq], o[fq], d[fq], hits.t[fq], ng[fq],
                                          np.zeros(fq.size, bool), ng0[fq])
            spec[fq] = arrive_numpy(self, spec[fq], o[fq], d[fq], hits.t[fq], ng[fq],
                                    None, ng0[fq])
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
                r[fqd] = F.radius_fold_key(
                    F.predicted_radius(spec[dq[fqd]], np.inf, np.inf, model), model)
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
            plain = is_freq & ~deposit & ~is_delta
            spec[plain] = spec_plain[plain]
            fk = k[is_freq[k]]
            if fk.size:
                sgn = np.where(_dot(ns[fk], wi[fk]) >= 0, 1.0, -1.0)
                iface = _iface(self, hits.prim[fk], sgn, ng[fk], -wi_f[fk], wo_new[fk], mat[fk])
                spec[fk] = leave_numpy(self, spec[fk], ng[fk], wo_new[fk], mat[fk],
                                       is_delta[fk], iface)
        o = self.accel.spawn(p[k], ng[k], wo_new[k])
        d = wo_new[k]
        power = power[k] * wgt[k]
        spec = spec[k]
        is_freq = is_freq[k]
        ng0 = ng[k]
    if not out_p:
        return None
    return {"p": np.concatenate(out_p), "ng": np.concatenate(out_ng),
            "wi": np.concatenate(out_wi), "power": np.concatenate(out_pow),
            "rpred": np.concatenate(out_r), "bounce": np.concatenate(out_b),
            "spec": np.concatenate(out_s)}


@njit(cache=True)
def sample_fast_batch(cls, col, ior, ns, ng, wo, u):
    """Vectorised ``materials.fast.sample_fast`` for tests: per-point class (K,) int,
    col (K, 3), ior (K,), ns, ng, wo (K, 3), u (K, 3).
    Returns wi (K, 3), weight (K, 3), is_delta (K,), ok (K,)."""
    K = cls.shape[0]
    wi = np.zeros((K, 3))
    wt = np.zeros((K, 3))
    dl = np.zeros(K, np.bool_)
    ok = np.zeros(K, np.bool_)
    for i in range(K):
        r = sample_fast(cls[i], col[i, 0], col[i, 1], col[i, 2], ior[i],
                        ns[i, 0], ns[i, 1], ns[i, 2], ng[i, 0], ng[i, 1], ng[i, 2],
                        wo[i, 0], wo[i, 1], wo[i, 2], u[i, 0], u[i, 1], u[i, 2])
        wi[i, 0], wi[i, 1], wi[i, 2] = r[0], r[1], r[2]
        wt[i, 0], wt[i, 1], wt[i, 2] = r[3], r[4], r[5]
        dl[i] = r[6]
        ok[i] = r[7]
    return wi, wt, dl, ok
