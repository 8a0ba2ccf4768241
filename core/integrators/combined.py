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
from ..mathutil import dot as _dot
from . import mis as M
from . import mis_kernels as MK
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
        # Photon merging owns some paths (core.integrators.merge): set by the renderer.
        self.merging = False

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

    def nee_compiled(self, w, v, wi, dist, light, pl, sel, depth):
        """:meth:`nee` for vertices in the scope of the path kernels
        (``path_kernels.camera_nee_kernel``; pl, sel the samples'
        light-sampling density and selection probability)."""
        from . import path_kernels as PK
        if getattr(self, "_mis_lights", None) is None:
            self._mis_lights = PK.build_mis_lights(self.t, self.cls)
        w = np.array(w, np.float64)
        c = np.ascontiguousarray
        PK.camera_nee_kernel(self._mis_lights, depth == 0, c(v.Q), c(v.c), c(v.p),
                             c(v.ng), c(v.ns), c(v.wo), c(wi), c(dist), c(light, np.int64),
                             c(pl), c(sel), w)
        return w

    def continued_compiled(self, v, nx, depth):
        """:meth:`continued` for the NextRays nx of ``path_kernels.continue_kernel``."""
        from . import path_kernels as PK
        Q = np.empty(nx.src.size)
        c = np.ascontiguousarray
        PK.camera_continued_kernel(depth == 0, nx.src, nx.delta, nx.d, c(v.ng), c(v.ns),
                                   c(v.wo), c(v.Q), c(v.c), Q)
        return Q, nx.pdf

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
            vp = vprev.take(i)
            r = self.soft_ratio(vp, row[s], depth - 1)
            # After a delta at y_{k-1} next-event estimation cannot take the
            # path: light tracing takes it all if it can (the ray's Q > 0: y_1
            # did not scatter by a delta), else path tracing alone (a light
            # seen in a mirror).
            wl = np.where(delta, np.where(Qs[i] > 0, 1.0, 0.0), r * r / (1.0 + r * r))
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
    b1 = B1 * c1 * np.where(first, 1.0, pf)
    return _finite(1.0 / (1.0 + b0 * b0 + b1 * b1))


def emission_splat_weight(kn, c1, pA, full):
    """(K,) w_LT of emitter points seen by the camera (paths of one segment):
    against PT only, q_0 / q_L = kn c_1 / pA; 0 for emitters not in the
    three-way scheme (class NO_LT)."""
    r = kn * c1 / pA
    return np.where(full, 1.0 / (1.0 + r * r), 0.0)


class CombinedLightTracer(LightTracer):
    """Light paths traced by the compiled photon kernels, with their MIS
    ratios (B0 = q_0 / q_L and B1 = q_1 / q_L without the camera-side
    factors of the current vertex) followed from the kernels' hit records
    (:mod:`.mis_kernels`),
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
        z0 = np.where(ar[:, None], ph["o"], t.co[light])     # the light end of the weights
        soft = self.cls[light] == M.SOFT
        dep, B0d, B1d, first = self._trace(ph, z0, rng)
        if dep is None:
            return
        bary = dep["bary"]
        prim = bary[:, 0].astype(np.int64)
        # The mesh's ng, as LightTracer._chunk (not the deposit's flipped one).
        _, ng, ns, uv = surface_point(s.tri_p, s.tri_n, s.tri_uv, prim, bary[:, 1], bary[:, 2])
        mat = np.asarray(s.tri_mat, np.int64)[prim]
        sft = soft[dep["src_photon"]]
        wi = dep["wi"]

        def splat_w(keep, pr, col):
            wc = pr.wi[keep]
            pf = B.pdf_bsdf(mtab, mat[keep], col, ns[keep], ng[keep], wc, wi[keep], subset="all")
            c1 = pr.weight[keep] * np.abs(_dot(ng[keep], wc))
            return splat_weight(B0d[keep], B1d[keep], pf, c1, first[keep], sft[keep])
        self.connect(dep["p"], ng, ns, wi, dep["power"], mat, uv, rng, film, mis=splat_w)

    def _trace(self, ph, z0, rng):
        """Trace the photons ph with the compiled photon kernels
        (core.sppm.photon_kernels, deposits from the first hit on, hit
        records on) and follow B0, B1 along each path in numpy from the
        records: the first-hit ratios, then per scattering the forward and
        reverse BSDF densities of the direction the kernel sampled.
        Returns (deposits + src_photon (row of ph), B0, B1, first) or Nones."""
        from ..accel import REL_OFFSET, intersect_f32
        from ..sppm import photon_kernels as PK
        from ..sppm.photons import _Deposits
        tr, t, mtab, s = self.tracer, self.light_table, self.mtab, self.scene
        n = ph["o"].shape[0]
        live = PK.LiveState(o32=np.empty((n, 3), np.float32), d32=np.empty((n, 3), np.float32),
                            d64=np.empty((n, 3)), power=np.empty((n, 3)), falloff=np.empty(n))
        rel, floor = REL_OFFSET, self.accel.abs_floor / REL_OFFSET
        src = np.empty(n, np.int64)
        K = PK.emit_kernel(np.ascontiguousarray(ph["o"], np.float64),
                           np.ascontiguousarray(ph["d"], np.float64),
                           np.ascontiguousarray(ph["power"], np.float64),
                           np.ascontiguousarray(ph["falloff_r2"], np.float64), rel, floor, live,
                           src)
        row = src[:K].copy()                 # photon of each live ray
        light = ph["light"].astype(np.int64)
        cg = n if tr.fmat.any_generic else 1
        gen = PK.GenericHits(np.empty(cg, np.int64), *(np.empty((cg, 3)) for _ in range(6)))
        rec = PK.HitRecord(t=np.empty(n), ng=np.empty((n, 3)), nswi=np.empty(n),
                           hit=np.empty(n, bool), nxt_src=np.empty(n, np.int64),
                           nxt_delta=np.empty(n, bool))
        dep = _Deposits(2.0 * n + 64)
        kn = self.kn
        Bp0 = Bp1 = None
        out_B0, out_B1, out_first, out_row = [], [], [], []
        for bounce in range(self.max_bounces + 1):
            if K == 0:
                break
            hits = PK.EmbreeHits(*intersect_f32(self.accel, live.o32[:K], live.d32[:K]))
            step = PK.BounceStep(K=K, first=bounce == 0, store=True,
                                 sample=bounce < self.max_bounces,
                                 roulette=bounce + 1 >= self.rr_start, bounce=bounce,
                                 dep0=dep.n, record=True, rel=rel, floor=floor)
            u = rng.random((K, 4))
            dep.reserve(K)
            d_old = live.d64[:K].copy()
            dep0 = dep.n
            n_next, n_dep, n_gen = PK.bounce_kernel(step, hits, live, tr.tris, tr.fmat, u,
                                                    dep.buf, gen, rec)
            dep.n = n_dep
            if n_gen:
                n_next = tr._generic_bounce(n_gen, n_next, gen, u, step.roulette, live, rec)
            # B at the vertices hit (rays i of this bounce).
            hit = np.nonzero(rec.hit[:K])[0]
            B0 = np.zeros(K)
            B1 = np.zeros(K)
            if bounce == 0:
                p, ngh, _, _ = surface_point(s.tri_p, s.tri_n, s.tri_uv,
                                             hits.prim[hit].astype(np.int64),
                                             hits.bu[hit].astype(np.float64),
                                             hits.bv[hit].astype(np.float64))
                j = light[row[hit]]
                B0[hit], B1[hit] = first_hit_ratios(t, kn, j, z0[row[hit]], d_old[hit], p, ngh)
            else:
                cos_in = np.abs(_dot(tr.tris.ng[hits.prim[hit]], d_old[hit]))
                with np.errstate(divide="ignore", invalid="ignore"):
                    B0[hit] = _finite(Bp0[hit] / cos_in)
                    B1[hit] = _finite(Bp1[hit] / cos_in)
            ds = dep.buf.src[dep0:n_dep]
            out_B0.append(B0[ds])
            out_B1.append(B1[ds])
            out_first.append(np.full(ds.size, bounce == 0))
            out_row.append(row[ds])
            if n_next == 0:
                break
            # The scatterings the kernel sampled: survivor jn came from ray i.
            i = rec.nxt_src[:n_next].copy()
            Bp0, Bp1 = np.empty(n_next), np.empty(n_next)
            generic = np.empty(n_next, bool)
            MK.scatter_ratios(n_next, rec.nxt_src, rec.nxt_delta, live.d64, hits.prim, hits.bu,
                              hits.bv, d_old, tr.tris.n, tr.tris.ng, tr.tris.mat, tr.fmat.cls,
                              B0, B1, bounce == 0, Bp0, Bp1, generic)
            g = np.nonzero(generic)[0]
            if g.size:
                ig = i[g]
                _, ngg, nsg, uvg = surface_point(s.tri_p, s.tri_n, s.tri_uv,
                                                 hits.prim[ig].astype(np.int64),
                                                 hits.bu[ig].astype(np.float64),
                                                 hits.bv[ig].astype(np.float64))
                mat = np.asarray(s.tri_mat, np.int64)[hits.prim[ig]]
                col = B.lobe_colors(mtab, mat, uvg)
                wo, wg = -d_old[ig], live.d64[g]
                pl = B.pdf_bsdf(mtab, mat, col, nsg, ngg, wo, wg, subset="all")
                pr = B.pdf_bsdf(mtab, mat, col, nsg, ngg, wg, wo, subset="all")
                pend, pend1 = scatter_factors(pr, ngg, wg, pl, np.zeros(g.size, bool),
                                              bounce == 0)
                Bp0[g], Bp1[g] = B0[ig] * pend, B1[ig] * pend1
            row = row[i]
            K = n_next
        res = dep.result()
        if res is None:
            return None, None, None, None
        res["src_photon"] = np.concatenate(out_row)
        return res, np.concatenate(out_B0), np.concatenate(out_B1), np.concatenate(out_first)
