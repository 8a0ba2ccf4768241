"""Photon tracing for one pass: emission, bounces, deposits, frequency spectra.

Photons leave the emitters (``lights.sample_photons``), bounce by BSDF sampling
in importance mode with Russian roulette, and are deposited at every
non-specular hit after the first bounce (the first hit is next-event
estimation's job) or from the first hit with ``photons_for_direct``.  The
first ``n_freq`` photons of a batch also carry a light-field spectrum (a, b, c)
updated by ``core.frequency`` on travel, occlusion, onto/off the surface, the
BSDF lobe and curvature; each deposit gets its predicted radius.
"""
from __future__ import annotations

import numpy as np

from . import bsdf as B
from . import lights as Lt
from . import frequency as F
from .accel import surface_point
from .scene import Scene

LUM = np.array([0.2126, 0.7152, 0.0722])


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


class PhotonTracer:
    """Traces batches of photons through one scene (state shared across passes)."""

    def __init__(self, scene, accel, mtab, light_table, settings, plan, kappa, occ_grid,
                 occ_locality, D):
        self.scene, self.accel, self.mtab = scene, accel, mtab
        self.light_table, self.settings, self.plan = light_table, settings, plan
        self.kappa, self.occ_grid, self.occ_locality, self.D = kappa, occ_grid, occ_locality, D

    def trace(self, n: int, n_freq: int, rng):
        """Trace n photons (the first n_freq carry a spectrum); return deposits."""
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
        out_p, out_ng, out_wi, out_pow, out_r = [], [], [], [], []
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
                s = F.travel(spec[fq], np.minimum(hits.t[fq], self.D), model, A_MAX)
                if self.occ_grid is not None:
                    from .occlusion import march_occlusion
                    a_occ = march_occlusion(self.occ_grid, o[fq], d[fq], hits.t[fq],
                                            self.occ_locality)
                    s = F.occlude(s, a_occ, model, A_MAX)
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
                "rpred": np.concatenate(out_r)}


def triangle_curvature(scene: Scene) -> np.ndarray:
    """(T,) float64 mean normal curvature of each triangle from its corner normals.

    kappa = mean over edges of dot(n_j - n_i, p_j - p_i) / |p_j - p_i|^2: +1/R
    on the outside of a sphere of radius R whose normals point outwards, 0 on
    flat-shaded triangles (issue 4: curvature comes from the shading normals).
    """
    P = scene.tri_p.astype(np.float64)
    N = scene.tri_n.astype(np.float64)
    k = np.zeros(P.shape[0])
    for i, j in ((0, 1), (1, 2), (2, 0)):
        dp = P[:, j] - P[:, i]
        dn = N[:, j] - N[:, i]
        k += _dot(dn, dp) / np.maximum(_dot(dp, dp), 1e-300)
    return k / 3.0
