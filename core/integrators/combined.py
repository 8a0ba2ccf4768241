"""Integrator 'COMBINED': camera paths and light tracing, weighted by MIS.

    cam = CameraMIS(light_table, mtab, camera, n_light_paths, camera_samples)
    path_tracer.vc = cam                      # PathTracer then weights with it
    lt = CombinedLightTracer(<LightTracer arguments>, camera_samples)
    splats = lt.trace_pass(n_light_paths, rng, check_stop)

Image = (camera paths: mean over the passes of each pass' mean of
camera_samples paths per pixel) + (light tracing: splat sums / light paths).
The weights (power heuristic over PT emission, next-event estimation and
light tracing) and their running products are in :mod:`.mis` and
docs/integrators.md ("Combined").
"""
from __future__ import annotations

import numpy as np

from .. import lights as Lt
from .. import materials as B
from ..accel import surface_point
from ..lights.pdf import _selection_probability
from ..lights.table import AREA, MESH
from ..mathutil import LUMINANCE as LUM, dot as _dot
from . import mis as M
from .light_tracer import CHUNK, LightTracer


def _finite(w):
    return np.where(np.isfinite(w), w, 0.0)


def _shrink(w, r):
    """The weight w of a camera strategy against its camera rival, with the
    light-tracing ratio r = q_L / q_this added: 1 / (1/w + r^2)."""
    return _finite(w / (1.0 + w * r * r))


class CameraMIS:
    """The light-tracing terms of the camera strategies' weights (module
    :mod:`.mis`): PathTracer calls these with its vertex arrays."""

    def __init__(self, table, mtab, camera, n_light: int, K: int):
        self.t, self.mtab, self.camera = table, mtab, camera
        self.ratio = float(n_light) / float(K)      # N_L / K
        self.cls = M.light_classes(table)
        self.ortho = camera.cam.kind == "ORTHO"

    # ---------------------------------------------------------- densities
    def c1(self, d, cos_surf, t):
        """(K,) c_1: the one-pixel camera density of the point at distance t
        along the camera rays d, |cos_surf| there (area measure)."""
        A = self.camera.pixel_area
        if self.ortho:
            return cos_surf / A
        cc = -(d @ self.camera.R[:, 2])
        return cos_surf / (A * cc ** 3 * t * t)

    def camera_state(self, d):
        """Q carried by the camera rays (K,): N_L / K."""
        return np.full(d.shape[0], self.ratio)

    def at_hit(self, Qs, pf, ih, d, ng, t, depth):
        """(Q, c) at the vertices hit by rays ih at distance t."""
        cos = np.abs(_dot(ng, d))
        if depth == 0:
            return Qs, self.c1(d, cos, t)
        with np.errstate(divide="ignore", invalid="ignore"):
            return Qs / (t * t), pf[ih] * cos / (t * t)

    def continued(self, v, c, wi, pdf, is_delta, depth):
        """(Qs, pf) of the rays leaving the vertices v[c] along wi: Q times
        the light-side density pr at the vertex (from the second vertex on;
        1 after a delta) times |cos| / c; Q = 0 after a delta at the first
        vertex (light tracing cannot connect there)."""
        pr = np.ones(c.size)
        if depth >= 1:
            nd = np.nonzero(~is_delta)[0]
            if nd.size:
                i = c[nd]
                pr[nd] = B.pdf_bsdf(self.mtab, v.mat[i], v.colors[i], v.ns[i], v.ng[i],
                                    wi[nd], v.wo[i], subset="all")
        with np.errstate(divide="ignore", invalid="ignore"):
            Q = _finite(v.Q[c] * pr * np.abs(_dot(v.ng[c], wi)) / v.c[c])
        if depth == 0:
            Q = np.where(is_delta, 0.0, Q)
        return Q, np.where(is_delta, 1.0, pdf)

    def _reverse(self, v, wo_light, depth):
        """(K,) pr at vertices v for light arriving along wo_light (1 at the first vertex)."""
        if depth == 0:
            return np.ones(v.p.shape[0])
        return B.pdf_bsdf(self.mtab, v.mat, v.colors, v.ns, v.ng, wo_light, v.wo, subset="all")

    def soft_ratio(self, v, light, depth):
        """(K,) q_L / q_C of a soft light's centre seen from vertices v."""
        wc = self.t.co[light] - v.p
        dc = np.linalg.norm(wc, axis=1)
        wc = wc / np.maximum(dc, 1e-300)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            return _finite(v.Q * self._reverse(v, wc, depth) * np.abs(_dot(v.ng, wc))
                           * M.point_emit_over_nee(self.t, v.p, light, -wc, dc) / v.c)

    # ------------------------------------------------------------ weights
    def emission(self, w, idx, row, d, t, ng, depth, Qs, pf, pdf_prev, vprev):
        """(k,) weights of emission found by rays idx (emitter rows row, -1 =
        none) given their PT-vs-NEE weights w."""
        w = w.copy()
        ok = row >= 0
        cls = np.where(ok, self.cls[np.maximum(row, 0)], M.NO_LT)
        f = np.nonzero(cls == M.FULL)[0]
        if f.size:
            j, dd = row[f], d[idx[f]]
            cos_l = np.abs(_dot(dd, self.t.dir[j]))
            pA = M.emit_pdf_pos(self.t, j)
            with np.errstate(divide="ignore", invalid="ignore"):
                if depth == 0:
                    r = Qs[idx[f]] * pA / self.c1(dd, cos_l, t[f])
                else:
                    r = (Qs[idx[f]] * M.emit_pdf_dir(self.t, j, -dd) * pA
                         / (pf[idx[f]] * cos_l))
            w[f] = _shrink(w[f], _finite(r))
        s = np.nonzero(cls == M.SOFT)[0]
        if s.size and depth >= 1:
            i = idx[s]
            delta = pdf_prev[i] <= 0
            r = self.soft_ratio(vprev.take(i), row[s], depth - 1)
            wl = np.where(delta, 1.0, r * r / (1.0 + r * r))
            w[s] *= 1.0 - wl
        return w

    def nee(self, w, v, wi, dist, light, depth):
        """(K,) weights of the light samples (wi, dist, light) at vertices v
        given their NEE-vs-PT weights w."""
        w = w.copy()
        cls = self.cls[light]
        f = np.nonzero(cls == M.FULL)[0]
        if f.size:
            vf, j, wf = v.take(f), light[f], wi[f]
            ar = (self.t.kind[j] == AREA) | (self.t.kind[j] == MESH)
            T = np.zeros(f.size)
            a = np.nonzero(ar)[0]
            if a.size:
                pl = Lt.pdf_direct(self.t, vf.p[a], wf[a], j[a], dist[f][a], n=vf.ns_wo()[a])
                cos_l = np.abs(_dot(wf[a], self.t.dir[j[a]]))
                T[a] = M.area_emit_over_nee(self.t, j[a], -wf[a], pl, cos_l)
            p = np.nonzero(~ar)[0]
            if p.size:
                T[p] = M.point_emit_over_nee(self.t, vf.p[p], j[p], -wf[p], dist[f][p])
            with np.errstate(divide="ignore", invalid="ignore"):
                r = _finite(vf.Q * self._reverse(vf, wf, depth) * np.abs(_dot(vf.ng, wf)) * T
                            / vf.c)
            w[f] = _shrink(w[f], r)
        s = np.nonzero(cls == M.SOFT)[0]
        if s.size:
            r = self.soft_ratio(v.take(s), light[s], depth)
            w[s] *= 1.0 / (1.0 + r * r)
        return w


def first_hit_ratios(t, kn, light, z0, d, p, ng):
    """(B0, B1) (K,) at the first vertex z_1 = p of light paths from the
    emitter points z0 (a point or soft light's centre) of rows light along
    d; kn = K / N_L.  B0 = kn c_k' / (l_k l_{k-1}) (the camera-side density
    of the emitter point without its BSDF density at z_1, applied later;
    0 for point and soft lights, which no ray hits), B1 = kn n_k / (l_k l_{k-1})
    with n_k the next-event density of z0 from z_1."""
    kind = t.kind[light]
    a = (kind == AREA) | (kind == MESH)
    cos_l = np.abs(_dot(t.dir[light], d))
    wz = p - z0
    dz = np.linalg.norm(wz, axis=1)
    wz = wz / np.maximum(dz, 1e-300)[:, None]
    cos_z = np.abs(_dot(ng, wz))
    pA = M.emit_pdf_pos(t, light)
    pW = M.emit_pdf_dir(t, light, wz)
    nee = np.where(a, 0.0, _selection_probability(t, p, light))
    aa = np.nonzero(a)[0]
    if aa.size:
        nee[aa] = Lt.pdf_direct(t, p[aa], -wz[aa], light[aa], dz[aa]) * cos_l[aa]
    with np.errstate(divide="ignore", invalid="ignore"):
        B0 = np.where(a, kn * cos_l / (pA * pW * cos_z), 0.0)
        B1 = np.where(a, kn * nee / (pA * pW * cos_z), kn * nee / pA * dz * dz / (pW * cos_z))
    return _finite(B0), _finite(B1)


def scatter_factors(pr, ng, wn, pdf, is_delta, first):
    """(pend, pend1) (K,): what B0 and B1 are multiplied by when a light path
    leaves a vertex (normal ng) along wn with forward density pdf: pr |cos| /
    pdf (pr the camera-side density of the previous light vertex from here,
    deferred from the splat; densities 1 at a delta), divided by |cos| at the
    next vertex on arrival.  B1 skips pr at the first vertex (q_1 has no
    camera-side density at the emitter)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        pend1 = _finite(np.abs(_dot(ng, wn)) / np.where(is_delta, 1.0, pdf))
    pend = pr * pend1
    return pend, (pend1 if first else pend)


def splat_weight(B0, B1, pf, c1, first, soft):
    """(K,) w_LT of light vertices connected to the camera: 1 / (1 + (B0 pf
    c_1)^2 + (B1 pf c_1)^2), c_1 the camera density of the vertex, pf the
    camera path's BSDF density there towards the light side (not in B1 at
    the first vertex, see scatter_factors); soft lights: no PT term."""
    b0 = np.where(soft, 0.0, B0 * pf * c1)
    b1 = B1 * c1 * (1.0 if first else pf)
    return _finite(1.0 / (1.0 + b0 * b0 + b1 * b1))


def emission_splat_weight(kn, c1, pA, full):
    """(K,) w_LT of emitter points seen by the camera (paths of one segment):
    against PT only, q_0 / q_L = kn c_1 / pA; 0 for emitters not in the
    three-way scheme (class NO_LT)."""
    r = kn * c1 / pA
    return np.where(full, 1.0 / (1.0 + r * r), 0.0)


class CombinedLightTracer(LightTracer):
    """Light paths traced in numpy with their MIS ratios (B0 = q_0 / q_L and
    B1 = q_1 / q_L without the camera-side factors of the current vertex),
    every non-delta vertex splatted with w_LT = 1 / (1 + (B0 X)^2 + (B1 X)^2),
    X = pf c_1 (the camera path's BSDF density there and its camera density).
    Light from emitters of class NO_LT (sun, world) is not traced."""

    def __init__(self, *args, camera_samples: int, **kw):
        super().__init__(*args, **kw)
        self.cls = M.light_classes(self.light_table)
        self.K = int(camera_samples)
        self.max_bounces = int(self.tracer.settings.max_bounces)
        self.rr_start = int(self.tracer.settings.rr_start)

    def trace_pass(self, n: int, rng, check_stop=lambda: None) -> np.ndarray:
        """Trace n light paths; their weighted splat sums (H*W, 3)."""
        film = np.zeros((self.H * self.W, 3))
        self.kn = self.K / float(n)          # K / N_L
        done = 0
        r0 = self.accel.rays_cast
        while done < n:
            check_stop()
            k = min(CHUNK, n - done)
            self._chunk(k, rng, film)
            done += k
        self.rays += self.accel.rays_cast - r0
        return film

    def _chunk(self, n: int, rng, film: np.ndarray) -> None:
        t, mtab, s = self.light_table, self.mtab, self.scene
        ph = Lt.sample_photons(t, n, rng)
        light = ph["light"].astype(np.int64)
        live = np.nonzero((light >= 0) & (self.cls[np.maximum(light, 0)] != M.NO_LT)
                          & (ph["power"].max(axis=1) > 0))[0]
        if live.size == 0:
            return
        ph = {k: v[live] for k, v in ph.items()}
        light = light[live]
        kn = self.kn
        pA = M.emit_pdf_pos(t, light)

        def emis_w(rows, weight, cos_o):
            return emission_splat_weight(kn, weight * cos_o, pA[rows],
                                         self.cls[light[rows]] == M.FULL)
        self._emission_vertices(ph, rng, film, mis=emis_w)
        kind = t.kind[light]
        ar = (kind == AREA) | (kind == MESH)
        n_l = t.dir[light] * np.where(_dot(t.dir[light], ph["d"]) >= 0, 1.0, -1.0)[:, None]
        o = np.where(ar[:, None], self.accel.spawn(ph["o"], n_l, ph["d"]), ph["o"])
        d = ph["d"]
        power = ph["power"].copy()
        falloff = ph["falloff_r2"]
        z0 = np.where(ar[:, None], ph["o"], t.co[light])     # the light end of the weights
        soft = self.cls[light] == M.SOFT
        B0 = B1 = None
        pend = None                   # pr |cos| / pl of the last scattering (per live path)
        idx = np.arange(live.size)    # row into the chunk's light arrays
        for bounce in range(self.max_bounces + 1):
            if idx.size == 0:
                break
            h = self.accel.intersect(o, d, np.full(idx.size, np.inf))
            ih = np.nonzero(h.hit)[0]
            if ih.size == 0:
                break
            idx, d, power = idx[ih], d[ih], power[ih]
            prim = h.prim[ih]
            p, ng, ns, uv = surface_point(s.tri_p, s.tri_n, s.tri_uv, prim, h.u[ih], h.v[ih])
            mat = s.tri_mat[prim]
            cos_in = np.abs(_dot(ng, d))
            j = light[idx]
            if bounce == 0:
                tt = h.t[ih]
                fr = falloff[idx] > 0
                if np.any(fr):
                    power[fr] *= (tt[fr] ** 2 / (tt[fr] ** 2 + falloff[idx][fr]))[:, None]
                B0, B1 = first_hit_ratios(t, kn, j, z0[idx], d, p, ng)
            else:
                with np.errstate(divide="ignore", invalid="ignore"):
                    B0 = _finite(pend[ih] * B0[ih] / cos_in)
                    B1 = _finite(pend1[ih] * B1[ih] / cos_in)
            colors = B.lobe_colors(mtab, mat, uv)
            wi = -d
            nd = np.nonzero(mtab.has_nondelta[mat])[0]
            if nd.size:
                def splat_w(keep, pr, col, nd=nd, first=bounce == 0):
                    r = nd[keep]
                    wc = pr.wi[keep]
                    pf = B.pdf_bsdf(mtab, mat[r], col, ns[r], ng[r], wc, wi[r], subset="all")
                    c1 = pr.weight[keep] * np.abs(_dot(ng[r], wc))
                    return splat_weight(B0[r], B1[r], pf, c1, first, soft[idx[r]])
                self.connect(p[nd], ng[nd], ns[nd], wi[nd], power[nd], mat[nd], uv[nd], rng,
                             film, mis=splat_w)
            if bounce >= self.max_bounces:
                break
            u = rng.random((idx.size, 4))
            wn, wgt, pdf, is_delta, valid = B.sample_bsdf(mtab, mat, colors, ns, ng, wi,
                                                          u[:, :3], subset="all",
                                                          mode="importance")
            ok = valid & np.all(np.isfinite(wgt), axis=1) & (wgt.max(axis=1) > 0)
            if bounce + 1 >= self.rr_start:
                q = np.clip(wgt @ LUM, 0.0, 1.0)
                ok &= u[:, 3] < q
                wgt = wgt / np.maximum(q, 1e-12)[:, None]
            c = np.nonzero(ok)[0]
            wn, pdf, is_delta = wn[c], pdf[c], is_delta[c]
            pr = np.ones(c.size)
            nd = np.nonzero(~is_delta)[0]
            if nd.size:
                k = c[nd]
                pr[nd] = B.pdf_bsdf(mtab, mat[k], colors[k], ns[k], ng[k], wn[nd], wi[k],
                                    subset="all")
            pend, pend1 = scatter_factors(pr, ng[c], wn, pdf, is_delta, bounce == 0)
            B0, B1 = B0[c], B1[c]
            if bounce == 0:
                B1 = np.where(is_delta, 0.0, B1)     # no light sample at a delta z_1
            o = self.accel.spawn(p[c], ng[c], wn)
            d = wn
            power = power[c] * wgt[c]
            idx = idx[c]
