"""Multiple importance sampling at the glossy points of the camera pass.

    mis = GlossyMIS(light_table, mtab, n_triangles)
    L = mis.direct(glossy_rows(vp, q), light_uniforms(u), nee)   # (K, 3) the light samples' part
    w = mis.bsdf_weight(pdf_b, p, n, wi, light, dist)

A glossy point (core.sppm.visible_points, "glossy chains": a vertex on a
material without a diffuse lobe, where the camera chain goes on by a sample
of its non-delta lobes) finds its direct light by two strategies, as a path
tracer's vertex does (core.integrators.path_tracer):

- one light sample (core.lights.sample_direct), tested by next-event
  estimation's shadow rays (core.lights.nee: transparent shadows included):
  :meth:`GlossyMIS.direct`;
- the BSDF sample the chain goes on with, where its ray meets an emitter (an
  area light, a light's disc or sphere, a sun's disc, an emissive triangle,
  the world) before anything else: the camera pass weighs that emission by
  :meth:`GlossyMIS.bsdf_weight`.

Each is weighed by the power heuristic (Veach 1997, eq. 9.13) against the
other strategy's density of the same direction: ``core.lights.pdf_direct``
for the light sample, ``core.materials.pdf_bsdf`` of the non-delta lobes for
the BSDF sample.  A light that no ray meets (a point or spot of radius 0, a
sun of angle 0) or that rays of that kind do not see (Ray Visibility) is the
light sample's alone (weight 1).  A transparent crossing is no vertex (the
chain keeps the glossy point's densities through it, as next-event
estimation's shadow rays pass it).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import lights as Lt
from .. import materials as B
from ..materials import compiled as C
from ..materials.fast import GENERIC, build_fast_materials
from ..lights.table import MESH
from ..scene.linking import lit
from ..lights.lobe_visibility import masked_colors
from ..mathutil import dot as _dot, power_heuristic


class GlossyRows(NamedTuple):
    """K glossy points, read once from the camera pass's visible-point rows
    (:func:`glossy_rows`), float64 but mat: p (K, 3); ns, ng (K, 3) the
    normals as the mesh has them (the materials orient them); n (K, 3) the
    shading normal flipped with ng to wo's side (next-event estimation's
    receiver normal); wo (K, 3); mat (K,) int64; colors (K, L, 3); beta
    (K, 3) the throughput."""
    p: np.ndarray
    ns: np.ndarray
    ng: np.ndarray
    n: np.ndarray
    wo: np.ndarray
    mat: np.ndarray
    colors: np.ndarray
    beta: np.ndarray

    def take(self, i) -> "GlossyRows":
        """The rows i."""
        return GlossyRows(*(a[i] for a in self))


def glossy_rows(vp, q) -> GlossyRows:
    """The rows q (K,) of vp (VisiblePoints or their VPBuffers) as GlossyRows."""
    c = np.ascontiguousarray
    n = c(vp.ns[q], np.float64)             # oriented to wo with ng (Cycles' back-face flip)
    s = np.where(vp.front[q], 1.0, -1.0)[:, None]
    return GlossyRows(p=c(vp.p[q], np.float64), ns=n * s, ng=c(vp.ng[q] * s), n=n,
                      wo=c(vp.wo[q], np.float64), mat=c(vp.mat[q], np.int64),
                      colors=c(vp.colors[q], np.float64), beta=c(vp.beta[q], np.float64))


class GlossyMIS:
    """The MIS weights of the glossy points' two strategies (module doc).
    light_table: the renderer's; mtab: its MaterialTable; T: the scene's
    triangle count (emissive triangles by their emitter row)."""

    def __init__(self, light_table, mtab, T: int):
        self.lights, self.mtab = light_table, mtab
        self.hittable = Lt.mis_hittable(light_table)
        self.nee_only = Lt.samples_only(light_table)   # (shadow linking, hidden kinds)
        self.tri_light, self.world_row = Lt.emitter_rows(light_table, T)
        self._compiled = None
        self._lights_k = None
        self._nee_kernels = None

    def _radiance(self):
        """(FastMaterials, sample_radiance's rows, GENERIC (M,) bool), once."""
        if self._compiled is None:
            fm = build_fast_materials(self.mtab)
            self._compiled = (fm, C.radiance_rows(self.mtab, fm), fm.cls == GENERIC)
        return self._compiled

    def sample(self, mat, colors, ns, ng, wo, u):
        """``materials.sample_bsdf(subset="nondelta", mode="radiance")``: (wi,
        weight, pdf, is_delta, ok).  A material without delta lobes has
        nothing but its non-delta ones, so subset "all" is the same
        distribution: those rows take the compiled sampler
        (``materials.compiled.sample_radiance``), the others numpy's."""
        mat = np.asarray(mat, np.int64)
        nd = ~self.mtab.has_delta[mat]
        if not nd.all():
            return B.sample_bsdf(self.mtab, mat, colors, ns, ng, wo, u, subset="nondelta",
                                 mode="radiance")
        fm, rows, _ = self._radiance()
        return C.sample_radiance(self.mtab, fm, rows, mat, colors, ns, ng, wo, u)

    def pdf(self, mat, colors, ns, ng, wo, wi):
        """``materials.pdf_bsdf(subset="nondelta")``, compiled as :meth:`sample`."""
        if self.mtab.has_delta[np.asarray(mat, np.int64)].any():
            return B.pdf_bsdf(self.mtab, mat, colors, ns, ng, wo, wi, subset="nondelta")
        return C.pdf_radiance(self.mtab, mat, colors, ns, ng, wo, wi)

    def bsdf_weight(self, pdf_b, p, n, wi, light, dist) -> np.ndarray:
        """(K,) weight of emission that BSDF samples of density pdf_b (K,),
        cast from glossy points p (K, 3) (receiver normals n, as
        :meth:`direct` gives sample_direct) along wi, met on emitter rows
        light (K,) at distance dist (inf: the world, a sun)."""
        w = np.ones(pdf_b.shape[0])
        m = np.nonzero((light >= 0) & (pdf_b > 0))[0]
        if m.size:
            w[m] = power_heuristic(pdf_b[m], self._pdf_light(p[m], wi[m], light[m], dist[m], n[m]))
            w[m[self.nee_only[light[m]]]] = 0.0      # shadow linking: light samples' alone
        return w

    def _pdf_light(self, p, wi, light, dist, n) -> np.ndarray:
        """``lights.pdf_direct``, compiled (``lights.pdf_kernels``, as Path
        Tracing's ``pdf_light``) where ``direct_kernels`` covers the lights;
        0 where it is not finite (a degenerate light sample at grazing
        incidence: the map_mis_kernels rule), so that both strategies'
        weights of one direction still sum to one."""
        lights = self._lights()
        with np.errstate(over="ignore", invalid="ignore"):
            if lights:
                from ..lights import pdf_kernels as PdfK
                L, Q = lights
                K, c = p.shape[0], np.ascontiguousarray
                p, light = c(p, np.float64), c(light, np.int64)
                sel, pl = np.empty(K), np.empty(K)
                PdfK.selection_kernel(L, Q, p, light, sel)
                PdfK.pdf_kernel(L, Q, p, c(wi, np.float64), light, c(dist, np.float64),
                                c(n, np.float64), sel, pl)
            else:
                pl = Lt.pdf_direct(self.lights, p, wi, light, dist, n=n)
        return np.where(np.isfinite(pl), pl, 0.0)

    def _lights(self):
        """(DirectLights, LightPdf) of the light table for the compiled light
        samples and densities, or False where its lights need numpy's."""
        if self._lights_k is None:
            from ..lights import direct_kernels as DK, pdf_kernels as PdfK
            lt = self.lights
            self._lights_k = False
            if DK.compiled_lights_ok(lt, environment=True):
                L = DK.build_direct_lights(lt)
                self._lights_k = (L, PdfK.build_light_pdf(lt, self.hittable, L))
        return self._lights_k

    def _kernels(self):
        """Path Tracing's light-sample kernels for the glossy points
        (``direct_kernels.direct_kernel``, ``path_kernels.nee_mis_kernel``):
        (DirectLights, LightPdf, PathMaterials, (M,) bool the materials they
        take: GENERIC, untextured, no delta lobe), or False where the lights
        need the numpy sampler."""
        if self._nee_kernels is None:
            from ..integrators import path_kernels as PK
            from ..materials.hit_colors import textured_materials
            self._nee_kernels = False
            lights, mtab = self._lights(), self.mtab
            if lights:
                fm = self._radiance()[0]
                cls = PK.kernel_classes(mtab, fm)
                ok = ((cls == GENERIC) & ~np.asarray(mtab.has_delta, bool)
                      & ~np.asarray(textured_materials(mtab), bool))
                if mtab.bump_correction is not None:
                    ok &= ~np.asarray(mtab.bump_correction, bool)
                self._nee_kernels = lights + (PK.build_path_materials(mtab, fm), ok)
        return self._nee_kernels

    def direct(self, g: GlossyRows, u, nee) -> np.ndarray:
        """(K, 3) float64 the light samples of the K glossy points g times
        their throughput, each weighed against the density with which the
        point's BSDF sample finds the same direction; u (K, 3) uniforms;
        shadow rays by nee (``NextEventEstimation.transmittance``).  The rows
        of the materials Path Tracing's kernels take (:meth:`_kernels`) by
        them, the others by numpy (:meth:`_direct_numpy`): the same weights,
        to rounding."""
        kern = self._kernels()
        if not kern:
            return self._direct_numpy(g, u, nee)
        out = np.zeros((g.mat.size, 3))
        c = kern[3][g.mat]
        ci = np.nonzero(c)[0]
        if ci.size:
            out[ci] = self._direct_compiled(g.take(ci), u[ci], nee, kern)
        ni = np.nonzero(~c)[0]
        if ni.size:
            out[ni] = self._direct_numpy(g.take(ni), u[ni], nee)
        return out

    def _direct_compiled(self, g: GlossyRows, u, nee, kern) -> np.ndarray:
        """:meth:`direct` by Path Tracing's kernels (``PathTracer._direct_compiled``'s
        calls: the light sample, the BSDF's value, the power-heuristic weight)."""
        from ..integrators import path_kernels as PK
        from ..lights import direct_kernels as DK
        L, Q, M, _ = kern
        K = g.mat.size
        R = DK.Receivers(np.arange(K), g.p, g.n, g.beta, np.ascontiguousarray(M.col[g.mat]),
                         np.zeros(K, bool), np.ascontiguousarray(u, np.float64))
        S = DK.alloc_samples(K)
        DK.direct_kernel(0, K, L, R, S)
        w, pl, sel, live = np.empty(K), np.empty(K), np.empty(K), np.empty(K, bool)
        with np.errstate(over="ignore", invalid="ignore"):
            PK.nee_mis_kernel(L, Q, M, g.mat, g.mat, g.beta, g.p, g.ng, g.ns, g.n, g.wo, S, w,
                              live, pl, sel)
        out = np.zeros((K, 3))
        x, cols = masked_colors(self.mtab, self.lights.hidden, S.light, g.mat, g.colors)
        if x.size:      # emitters hidden from some kind of ray: those lobes left out
            f = C.eval_radiance(self.mtab, self._radiance()[2], g.mat[x], cols, g.ns[x], g.ng[x],
                                g.wo[x], S.wi[x])
            S.contrib[x] = g.beta[x] * f * (np.abs(_dot(g.n[x], S.wi[x]))[:, None] * S.weight[x])
        ok = lit(self.lights, self.mtab, S.light, g.mat)
        if ok is not None:
            live = live & ok            # light linking (core.scene.linking)
        r = np.nonzero(live & np.isfinite(w))[0]
        if r.size:
            tr = nee.transmittance(g.p[r], g.ng[r], S.wi[r], S.dist[r],
                                   self.lights.kind[S.light[r]] == MESH, S.shadow[r],
                                   light=S.light[r])
            out[r] = S.contrib[r] * tr * w[r, None]
        return out

    def _direct_numpy(self, g: GlossyRows, u, nee) -> np.ndarray:
        """:meth:`direct` in numpy (every material, textured colours and
        delta lobes included)."""
        out = np.zeros((g.mat.size, 3))
        lt = self.lights
        smp = Lt.sample_direct(lt, g.p, u, n=g.n)
        wi, dist, wgt, light = smp["wi"], smp["dist"], smp["weight"], smp["light"].astype(np.int64)
        r = np.nonzero((wgt.max(axis=1) > 0) & np.all(np.isfinite(wgt), axis=1))[0]
        if r.size == 0:
            return out
        wi, dist, wgt, light, shadow = wi[r], dist[r], wgt[r], light[r], smp["cast_shadow"][r]
        h = g.take(r)
        f = C.eval_radiance(self.mtab, self._radiance()[2], h.mat, h.colors, h.ns, h.ng, h.wo, wi)
        x, cols = masked_colors(self.mtab, lt.hidden, light, h.mat, h.colors)
        if x.size:      # emitters hidden from some kind of ray: those lobes left out
            f[x] = C.eval_radiance(self.mtab, self._radiance()[2], h.mat[x], cols, h.ns[x],
                                   h.ng[x], h.wo[x], wi[x])
        contrib = h.beta * f * (np.abs(_dot(h.n, wi))[:, None] * wgt)
        # Weighed where the chain's BSDF ray could find the light too.
        seen = Lt.bsdf_sees(lt, self.hittable, light, h.ng, h.wo, wi)
        w = np.ones(r.size)
        m = np.nonzero(seen)[0]
        if m.size:
            pl = self._pdf_light(h.p[m], wi[m], light[m], dist[m], h.n[m])
            pb = self.pdf(h.mat[m], h.colors[m], h.ns[m], h.ng[m], h.wo[m], wi[m])
            w[m] = power_heuristic(pl, pb)
        ok = lit(lt, self.mtab, light, h.mat)
        if ok is not None:
            w = w * ok                  # light linking (core.scene.linking)
        tr = nee.transmittance(h.p, h.ng, wi, dist, lt.kind[light] == MESH, shadow, light=light)
        out[r] = contrib * tr * w[:, None]
        return out


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def light_uniforms(u: np.ndarray) -> np.ndarray:
    """(K, 3) float64 uniforms in [0, 1) for the glossy points' light
    samples: splitmix64 (Steele et al. 2014) of the 53-bit draws u (K, 3) the
    point's BSDF sample takes.  Each point's numbers are its own whatever
    rows share the call, so the camera pass's blocks and threads give the
    same image; the two samples of a point are then dependent, which leaves
    each strategy's expectation, and so the MIS sum's, unchanged."""
    x = (np.asarray(u, np.float64) * 2.0 ** 53).astype(np.uint64)
    with np.errstate(over="ignore"):
        h = (x[:, 0] ^ (x[:, 1] * np.uint64(0xBF58476D1CE4E5B9))
             ^ (x[:, 2] * np.uint64(0x94D049BB133111EB)))
        out = np.empty((x.shape[0], 3))
        for i in range(3):
            h = h + _GOLDEN
            z = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
            z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
            z = z ^ (z >> np.uint64(31))
            out[:, i] = (z >> np.uint64(11)).astype(np.float64) * 2.0 ** -53
    return out
