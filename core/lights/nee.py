"""Next-event estimation at the visible points: direct light with a shadow test.

    nee = NextEventEstimation(light_table, mtab, accel, tri_p)
    L_direct = nee(vp, rng)          # (P, 3) float64

One light sample per visible point (core.lights.sampling.sample_direct picks the
emitter and the point on it), weighted by the BSDF (core.materials.closures) and
the shading cosine, then a shadow ray: analytic lights are not geometry, so
any hit before them occludes (with a retry that discards float32 self-hits at
grazing incidence); emissive triangles are geometry, so the emitter's own hit
does not occlude.  In scenes with Transparent lobes (the plan's "transparent
shadows") the rays that test blocks are followed through transparent
surfaces (core.lights.shadow: Cycles' transparent shadows).  Photons then
carry only indirect light (core.sppm.photons stores from the second bounce
on, and not the light that crossed only transparent surfaces) unless
``photons_for_direct`` is set, in which case the renderer does not call this
stage.  An environment map is found by two strategies, its light sample and
one BSDF sample of the non-delta lobes towards it, weighed by the balance
heuristic.  The light samples, the BSDF values, the map's weights and the
shadow rays' set-up are compiled (core.lights.direct_kernels,
core.lights.map_mis_kernels, in blocks that two threads share); the numpy
code (``compiled=False``) stays as their reference.  With shadow linking
each shadow ray is cast in its emitter's view of the scene
(core.scene.shadow_linking: ``views``).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple, Optional

import numpy as np

from ..accel import REL_OFFSET
from .. import materials as B
from ..mathutil import dot as _dot
from . import shadow
from .pdf import environment_pdf
from .sampling import sample_direct
from .table import MESH, WORLD
from ..scene.linking import lit
from .lobe_visibility import masked_colors

if TYPE_CHECKING:
    from ..sppm.visible_points import SharedBlocks, VisiblePoints


#: Visible points per block of the compiled direct light (``_direct_blocks``).
DIRECT_BLOCK = 1 << 16
#: The compiled direct light evaluates the BSDF of its non-Lambert receivers
#: with core.materials.compiled (False: numpy's eval_bsdf; the same values
#: to rounding, tests/test_compiled_bsdf.py).
COMPILED_BSDF = True


class _MapState(NamedTuple):
    """What the compiled path weighs an environment map with
    (``map_mis_kernels``): env its ``EnvironmentKernel``; materials the
    ``MapMaterials``; light_pdf the ``pdf_kernels.LightPdf`` of the table;
    world the world's emitter row."""
    env: object
    materials: object
    light_pdf: object
    world: int


class NextEventEstimation:
    """Direct light at visible points.  tri_p (T, 3, 3): the triangles of
    ``accel`` (their planes decide which hits are the emitter or a self-hit).
    views: the emitters' ``shadow_linking.ShadowViews``, or None (every
    shadow ray in ``accel``)."""

    def __init__(self, light_table, mtab, accel, tri_p: np.ndarray, compiled: bool = True,
                 views=None):
        self.light_table, self.mtab, self.accel, self.tri_p = light_table, mtab, accel, tri_p
        self.compiled = bool(compiled)
        self.views = views
        self._lights = None
        self._map_state = None

    def __call__(self, vp: "VisiblePoints", rng: np.random.Generator,
                 add_to: np.ndarray | None = None) -> np.ndarray:
        """(P, 3) float64 reflected direct radiance times vp.beta (0 at invalid
        points).  add_to (P, 3) float64: the radiance is added into it and it
        is returned, the same sums as ``add_to += nee(vp, rng)`` (each pixel
        gets one addition; with an environment map two, its light sample's
        then its BSDF sample's, so equal to rounding) without a pixel-sized
        array of its own."""
        q = np.nonzero(vp.valid)[0]
        if self.compiled and q.size and self._compiled_lights() is not None:
            L = np.zeros((vp.valid.shape[0], 3)) if add_to is None else add_to
            self._direct_blocks(vp, q, rng, L)
            return L
        L = self._direct_numpy(vp, q, rng)
        if add_to is None:
            return L
        add_to += L
        return add_to

    def _direct_numpy(self, vp, q, rng) -> np.ndarray:
        """:meth:`__call__` with the numpy sampler (the compiled path's
        reference; textured emitters): (P, 3)."""
        P = vp.valid.shape[0]
        L = np.zeros((P, 3))
        if q.size == 0:
            return L
        u = rng.random((q.size, 3))
        smp = sample_direct(self.light_table, vp.p[q], u, n=vp.ns[q])
        env = self._mis_environment()
        if env is not None:
            L += self._environment_bsdf(vp, rng)
        wi, dist, wgt, casts = smp["wi"], smp["dist"], smp["weight"], smp["cast_shadow"]
        live = (wgt.max(axis=1) > 0) & np.all(np.isfinite(wgt), axis=1)
        q, wi, dist, wgt, casts = q[live], wi[live], dist[live], wgt[live], casts[live]
        if q.size == 0:
            return L
        # The normals as the mesh has them: the BSDF tells a visible point
        # inside glass (wo behind ng) by them, for the relative IOR.
        ns_m, ng_m = vp.mesh_normals(q)
        f = B.eval_bsdf(self.mtab, vp.mat[q], vp.colors[q], ns_m, ng_m, vp.wo[q], wi)
        if self.light_table.hidden is not None:
            # Emitters hidden from some kind of ray: those lobes left out.
            h, cols = masked_colors(self.mtab, self.light_table.hidden, smp["light"][live],
                                    vp.mat[q], vp.colors[q])
            if h.size:
                f[h] = B.eval_bsdf(self.mtab, vp.mat[q[h]], cols, ns_m[h], ng_m[h],
                                   vp.wo[q[h]], wi[h])
        cos = np.abs(_dot(vp.ns[q], wi))
        contrib = vp.beta[q] * f * cos[:, None] * wgt
        if env is not None:
            # An environment map: its light samples share the directions with
            # BSDF samples (_environment_bsdf), balance heuristic (Veach 1997).
            wk = np.nonzero(smp["kind"][live] == WORLD)[0]
            if wk.size:
                qk = q[wk]
                pl = environment_pdf(self.light_table, vp.p[qk], wi[wk])
                pb = B.pdf_bsdf(self.mtab, vp.mat[qk], vp.colors[qk], ns_m[wk], ng_m[wk],
                                vp.wo[qk], wi[wk], subset="nondelta")
                contrib[wk] *= (pl / np.maximum(pl + pb, 1e-300))[:, None]
        ok = lit(self.light_table, self.mtab, smp["light"][live], vp.mat[q])
        if ok is not None:
            contrib[~ok] = 0.0          # light linking: an emitter that does not light it
        nz = contrib.max(axis=1) > 0
        q, wi, dist, contrib, casts = q[nz], wi[nz], dist[nz], contrib[nz], casts[nz]
        mesh = smp["kind"][live][nz] == MESH
        _add_lit(L, q, contrib, self.transmittance(vp.p[q], vp.ng[q], wi, dist, mesh, casts,
                                                   light=smp["light"][live][nz]))
        return L

    def _direct_blocks(self, vp, q, rng, L) -> None:
        """The compiled direct light of the visible points q (K,) added to L
        (P, 3), in blocks of DIRECT_BLOCK rows (four blocks from K < 4
        DIRECT_BLOCK; one thread below camera_kernels.SPLIT_MIN rows) that two
        threads (this one and core.sppm.photons' pool) take in turn, each block end to end --
        uniforms, light samples, shadow rays, sums -- so no step waits on one
        thread's numpy glue, and a thread whose blocks cost less (unshadowed
        points) takes more of them.  Row k takes the uniforms 3k .. 3k+2 of
        rng's stream (a block draws from a copy of the stream advanced to its
        first row: the same numbers as one (K, 3) draw), and rng is left
        after the 3K of them.  Each point's light is its own and the blocks'
        pixels are distinct, so the sums are the same bits however the blocks
        are shared."""
        from ..sppm.camera_kernels import SPLIT_MIN
        from ..sppm.visible_points import in_two_threads
        K = q.size
        if K < SPLIT_MIN or not isinstance(rng.bit_generator, np.random.PCG64):
            # one thread (PCG64 alone advances by draws), in blocks
            if self._map() is not None:
                # the map's BSDF samples draw after the light samples (_direct_numpy)
                u, ub = rng.random((K, 3)), rng.random((K, 3))
                for a in range(0, K, DIRECT_BLOCK):
                    b = slice(a, a + DIRECT_BLOCK)
                    self._direct_compiled(vp, q[b], u[b], L, ub[b])
                return
            for a in range(0, K, DIRECT_BLOCK):
                qb = q[a:a + DIRECT_BLOCK]
                self._direct_compiled(vp, qb, rng.random((qb.size, 3)), L)
            return
        # at least four blocks to share (256^2: a quarter of the points each)
        in_two_threads(self._shared_blocks(vp, q, rng, L, 4).take)

    def _shared_blocks(self, vp, q, rng, L, parts: int) -> "SharedBlocks":
        """:meth:`_direct_blocks`' blocks of the rows q (K,) (at least
        ``parts`` of them) as a ``SharedBlocks`` for any threads to take;
        they draw from a copy of rng's stream, and rng is moved past their
        3K uniforms at once."""
        from ..sppm.visible_points import SharedBlocks, stream_at
        K = q.size
        blk = min(DIRECT_BLOCK, -(-K // parts))
        base = stream_at(rng)
        with_map = self._map() is not None
        # With a map its BSDF samples' 3K uniforms follow the light samples'.
        rng.bit_generator.advance((6 if with_map else 3) * K)

        def block(a):
            qb = q[a:a + blk]
            ub = stream_at(base, 3 * (K + a)).random((qb.size, 3)) if with_map else None
            self._direct_compiled(vp, qb, stream_at(base, 3 * a).random((qb.size, 3)), L, ub)
        return SharedBlocks(K, blk, block)

    def shared(self, vp: "VisiblePoints", rng: np.random.Generator, add_to: np.ndarray,
               parts: int = 8) -> Optional["SharedBlocks"]:
        """:meth:`__call__` (into add_to) as blocks that any threads take
        (``SharedBlocks.take``; at least ``parts`` blocks), when the compiled
        blocks of :meth:`_direct_blocks` apply: the same sums, however the
        blocks are shared.  None: they do not (call this object instead);
        nothing was drawn or added."""
        from ..sppm.camera_kernels import SPLIT_MIN
        if not (self.compiled and isinstance(rng.bit_generator, np.random.PCG64)
                and self._compiled_lights() is not None):
            return None
        q = np.nonzero(vp.valid)[0]
        if q.size < SPLIT_MIN:
            return None
        return self._shared_blocks(vp, q, rng, add_to, parts)

    def _direct_compiled(self, vp, q, u, L, ub=None) -> np.ndarray:
        """The numpy path above with the light sample, the Lambert BSDF, the
        shadow rays and the sums in ``direct_kernels``, in the calling
        thread; with an environment map (ub (K, 3): the uniforms of its BSDF
        samples) its two strategies weighed as ``_direct_numpy`` weighs
        them, in ``map_mis_kernels``.  Adds to and returns L (P, 3)."""
        from . import direct_kernels as DK
        S = self._sample_compiled(vp, q, u)
        # f of the points that are not Lambert-only: eval_bsdf on their rows.
        r = DK.bsdf_rows(q, vp.const, S.weight)
        if r.size:
            qr = q[r]
            if COMPILED_BSDF:
                from ..materials import compiled as MC
                f = np.empty((r.size, 3))
                MC.eval_indexed(MC.compile_materials(self.mtab), vp.mat, vp.colors, vp.ns, vp.ng,
                                vp.front, vp.wo, qr, S.wi, r, f, np.empty((0, 3)))
            else:
                ns_m, ng_m = vp.mesh_normals(qr)
                f = B.eval_bsdf(self.mtab, vp.mat[qr], vp.colors[qr], ns_m, ng_m, vp.wo[qr],
                                S.wi[r])
            S.contrib[r] = vp.beta[qr] * f * S.cos[r, None] * S.weight[r]
        if self.light_table.hidden is not None:
            self._leave_out_hidden(vp, q, S)
        mp = self._map()
        if mp is not None:
            from . import map_mis_kernels as MM
            V = self._map_receivers(vp, q, mp)
            MM.light_mis_kernel(mp.env, mp.materials, V, S)
            self._add_unshadowed(vp, q, S, L)
            Sb = DK.alloc_samples(q.size)
            MM.bsdf_mis_kernel(mp.env, mp.materials, V, ub, Sb)
            return self._add_unshadowed(vp, q, Sb, L)
        return self._add_unshadowed(vp, q, S, L)

    def _leave_out_hidden(self, vp, q, S) -> None:
        """The DirectSamples S (rows of the visible points q) of emitters
        hidden from some kind of ray, their contributions evaluated again
        without those lobes (core.lights.lobe_visibility; numpy's BSDF)."""
        h, cols = masked_colors(self.mtab, self.light_table.hidden, S.light, vp.mat[q],
                                vp.colors[q])
        if h.size:
            qh = q[h]
            ns_m, ng_m = vp.mesh_normals(qh)
            f = B.eval_bsdf(self.mtab, vp.mat[qh], cols, ns_m, ng_m, vp.wo[qh], S.wi[h])
            S.contrib[h] = vp.beta[qh] * f * S.cos[h, None] * S.weight[h]

    def _add_unshadowed(self, vp, q, S, L) -> np.ndarray:
        """Adds to L (P, 3) the contributions of the DirectSamples S (rows of
        the visible points q) whose shadow rays are not blocked (or what
        transparent surfaces let through); returns L."""
        from . import direct_kernels as DK
        ok = lit(self.light_table, self.mtab, S.light, vp.mat[q])
        if ok is not None:
            # Light linking: the samples of emitters that do not light the
            # point add nothing (core.scene.linking).
            S.contrib[~ok] = 0.0
            S.weight[~ok] = 0.0
        sh = DK.alloc_shadow(q.size)
        n, nm = DK.shadow_kernel(q, vp.p, vp.ng, S, REL_OFFSET, self.accel.abs_floor / REL_OFFSET,
                                 sh, L)
        if n:
            rows = sh.rows[:n]
            o32, d32, t32 = sh.o32[:n], sh.d32[:n], sh.t32[:n]
            if self.views is None:
                blocked = self._occluded_rows(self.accel, vp, q, S, rows, o32, d32, t32)
            else:
                # Shadow linking: each group of rays in its emitters' view.
                blocked = np.empty(n, bool)
                for accel, g in self.views.split(S.light[rows]):
                    blocked[g] = self._occluded_rows(accel, vp, q, S, rows[g], o32[g], d32[g],
                                                     t32[g])
            DK.accumulate(q, rows, blocked, S.contrib, L)
            self._through_transparent(vp, q, rows, blocked, S, L)
        if nm:
            km = sh.mesh[:nm]
            qm = q[km]
            blocked = self._blocked(vp.p[qm], vp.ng[qm], S.wi[km], S.dist[km],
                                    np.ones(nm, bool), S.light[km])
            DK.accumulate(q, km, blocked, S.contrib, L)
            self._through_transparent(vp, q, km, blocked, S, L, mesh=True)
        return L

    def _occluded_rows(self, accel, vp, q, S, rows, o32, d32, t32) -> np.ndarray:
        """(n,) bool the shadow rays (o32, d32, t32) of the DirectSamples
        rows (n,) blocked in ``accel``, float32 self-hits at grazing
        incidence retried (``_grazing_self_hit_retry``)."""
        blocked = _occluded_f32(accel, o32, d32, t32)
        b = np.nonzero(blocked)[0]
        if b.size:
            kb = rows[b]
            pb, gb, wb = vp.p[q[kb]], vp.ng[q[kb]], S.wi[kb]
            blocked[b] = self._grazing_self_hit_retry(pb, gb, accel.spawn(pb, gb, wb), wb,
                                                      S.dist[kb], accel)
        return blocked

    def _split(self, light) -> list:
        """[(Accel, rows)]: the shadow rays of emitter rows light (K,) by
        the scene each is cast in (without shadow linking, or light None:
        ``accel`` and every row, as a slice: no copies)."""
        if self.views is None or light is None:
            return [(self.accel, slice(None))]
        return self.views.split(light)

    def _through_transparent(self, vp, q, rows, blocked, S, L, mesh=False) -> None:
        """Adds to L (P, 3) the light of the blocked shadow rays rows[blocked]
        (rows of the DirectSamples S) that transparent surfaces let through
        (core.lights.shadow); nothing in scenes without any."""
        if shadow.attached(self.accel) is None:
            return
        k = rows[np.nonzero(blocked)[0]]
        if k.size:
            qk = q[k]
            _add_lit(L, qk, S.contrib[k],
                     self._followed(vp.p[qk], vp.ng[qk], S.wi[k], S.dist[k],
                                    np.full(k.size, mesh), S.light[k]))

    def _compiled_lights(self):
        """The light table for ``direct_kernels`` (None: it needs the numpy sampler)."""
        if self._lights is None:
            from . import direct_kernels as DK
            self._lights = (DK.build_direct_lights(self.light_table)
                            if DK.compiled_lights_ok(self.light_table, environment=True)
                            else False)
        return self._lights or None

    def _mis_environment(self):
        """The environment map whose light samples are weighed against BSDF
        samples, or None: no map, or a world hidden from some kind of ray
        (core.lights.lobe_visibility: its light is the light samples'
        alone, ``pdf.samples_only``)."""
        t = self.light_table
        env = t.environment
        if env is None or not env.total > 0:
            return None
        hidden = getattr(t, "hidden", None)
        if hidden is not None and np.any(np.asarray(hidden)[t.kind == WORLD]):
            return None
        return env

    def _map(self) -> Optional[_MapState]:
        """The compiled path's environment map (``map_mis_kernels``), or
        None: no map (a constant world is sampled as any light), or one
        whose light is its light samples' alone (:meth:`_mis_environment`)."""
        if self._mis_environment() is None:
            return None
        if self._map_state is None:
            from ..materials.compiled import compile_materials
            from . import map_mis_kernels as MM
            from .pdf_kernels import build_light_pdf
            t, DL = self.light_table, self._compiled_lights()
            em = t.entry_emitter
            world = int(em[(em >= 0) & (t.kind[np.maximum(em, 0)] == WORLD)][0])
            self._map_state = _MapState(
                DL.env, MM.map_materials(self.mtab, compile_materials(self.mtab)),
                build_light_pdf(t, np.zeros(t.kind.shape[0], bool), DL), world)
        return self._map_state

    def _map_receivers(self, vp, q, mp):
        """``map_mis_kernels.MapReceivers`` of the visible points q (K,), with
        the world's selection probability at each (``pdf_kernels``)."""
        from . import map_mis_kernels as MM
        from .pdf_kernels import selection_kernel
        sel = np.empty(q.size)
        selection_kernel(self._compiled_lights(), mp.light_pdf, np.ascontiguousarray(vp.p[q]),
                         np.full(q.size, mp.world, np.int64), sel)
        return MM.map_receivers(self.mtab, vp, q, sel)

    def _sample_compiled(self, vp, q, u):
        """sample_direct plus the Lambert-only BSDF in ``direct_kernels``: the
        ``DirectSamples`` of the rows q (contrib 0 where the material is not
        Lambert-only)."""
        from . import direct_kernels as DK
        K = q.size
        R = DK.Receivers(q, vp.p, vp.ns, vp.beta, vp.albedo, vp.const, u)
        out = DK.alloc_samples(K)
        DK.direct_kernel(0, K, self._compiled_lights(), R, out)
        return out

    def _environment_bsdf(self, vp: "VisiblePoints", rng: np.random.Generator) -> np.ndarray:
        """(P, 3) the environment map seen along one BSDF sample per visible
        point (non-delta lobes), weighted by pdf_bsdf / (pdf_bsdf + pdf_light):
        the BSDF half of the multiple importance sampling of the map.  A rough
        mirror's reflection of a smooth sky is found here; the map's bright
        texels by the light samples."""
        P = vp.valid.shape[0]
        L = np.zeros((P, 3))
        q = np.nonzero(vp.valid)[0]
        if q.size == 0:
            return L
        ns_m, ng_m = vp.mesh_normals(q)
        wi, wgt, pdf, is_delta, ok = B.sample_bsdf(
            self.mtab, vp.mat[q], vp.colors[q], ns_m, ng_m, vp.wo[q],
            rng.random((q.size, 3)), subset="nondelta")
        k = np.nonzero(ok & ~is_delta & (pdf > 0) & (wgt.max(axis=1) > 0)
                       & np.all(np.isfinite(wgt), axis=1))[0]
        if k.size == 0:
            return L
        q, wi, wgt, pdf = q[k], wi[k], wgt[k], pdf[k]
        pl = environment_pdf(self.light_table, vp.p[q], wi)
        contrib = (vp.beta[q] * wgt * self.light_table.environment.radiance(wi)
                   * (pdf / (pdf + pl))[:, None])
        _add_lit(L, q, contrib, self.transmittance(vp.p[q], vp.ng[q], wi,
                                                   np.full(q.size, np.inf),
                                                   np.zeros(q.size, bool)))
        return L

    def transmittance(self, p, ng, wi, dist, mesh, cast_shadow=None, through=None,
                      light=None) -> np.ndarray:
        """(K, 3) float64 light let through by the shadow rays of ``_blocked``
        (same arguments; cast_shadow (K,) bool, False: the light casts no
        shadow, 1): 0 or 1 in scenes without transparent materials (one
        occlusion test), else the product of the pass-through weights of the
        transparent surfaces crossed (core.lights.shadow, Cycles'
        transparent shadows).  through (K,) bool or None (all): the rows
        whose light is not also found by another strategy through the
        transparent surfaces; on the others any surface blocks.  light (K,)
        the emitter rows (None: every ray in ``accel``): with shadow linking
        each ray is cast in its emitter's view."""
        blocked = self._blocked(p, ng, wi, dist, mesh, light)
        if cast_shadow is not None:
            blocked &= cast_shadow
        T = np.repeat((~blocked)[:, None].astype(np.float64), 3, axis=1)
        b = np.nonzero(blocked if through is None else blocked & through)[0]
        if b.size and shadow.attached(self.accel) is not None:
            T[b] = self._followed(p[b], ng[b], wi[b], dist[b], mesh[b],
                                  None if light is None else np.asarray(light)[b])
        return T

    def _followed(self, p, ng, wi, dist, mesh, light=None) -> np.ndarray:
        """(K, 3) ``shadow.transmittance`` of shadow rays that the opaque test
        found blocked: their first hit may be a transparent surface."""
        T = np.empty((p.shape[0], 3))
        for accel, g in self._split(light):
            T[g] = shadow.transmittance(accel, accel.spawn(p[g], ng[g], wi[g]), wi[g], dist[g],
                                        emitter=mesh[g], n0=ng[g])
        return T

    def _blocked(self, p, ng, wi, dist, mesh, light=None) -> np.ndarray:
        """(K,) bool: the shadow ray from p (K, 3) towards wi over dist is
        occluded; mesh (K,) bool: the sample lies on an emissive triangle;
        light (K,) its emitter rows (shadow linking's views) or None."""
        if self.views is not None and light is not None:
            blocked = np.empty(p.shape[0], bool)
            for accel, g in self.views.split(light):
                blocked[g] = self._blocked_in(accel, p[g], ng[g], wi[g], dist[g], mesh[g])
            return blocked
        return self._blocked_in(self.accel, p, ng, wi, dist, mesh)

    def _blocked_in(self, accel, p, ng, wi, dist, mesh) -> np.ndarray:
        """:meth:`_blocked` with every shadow ray cast in ``accel``."""
        o = accel.spawn(p, ng, wi)
        blocked = np.zeros(p.shape[0], bool)
        # Analytic lights are not geometry: any hit before them occludes.
        a = np.nonzero(~mesh)[0]
        if a.size:
            blocked[a] = accel.occluded(o[a], wi[a], dist[a])
            b = a[blocked[a]]
            if b.size:
                blocked[b] = self._grazing_self_hit_retry(p[b], ng[b], o[b], wi[b], dist[b],
                                                          accel)
        # Emissive triangles are geometry: the shadow ray must not be stopped by
        # the emitter itself.  Embree's float32 hit distance errs by about
        # offset/|cos| at grazing angles, so a closest hit counts as the emitter
        # when it lies within that tolerance of the sample.
        m = np.nonzero(mesh)[0]
        if m.size:
            end = p[m] + wi[m] * dist[m][:, None]
            h = accel.intersect(o[m], wi[m], dist[m] * (1 + 1e-6) + accel.offset_scale(end))
            hitm = h.hit
            cos_l = np.ones(m.size)
            if np.any(hitm):
                cos_l[hitm] = np.abs(_dot(self._unit_normals(h.prim[hitm]), wi[m][hitm]))
            tol = 4.0 * accel.offset_scale(end) / np.maximum(cos_l, 1e-4)
            blocked[m] = hitm & (h.t < dist[m] - tol)
        return blocked

    def _unit_normals(self, prim) -> np.ndarray:
        """(K, 3) float64 unit geometric normals of triangles prim (K,)."""
        return shadow.unit_normals(self.tri_p, prim)

    def _grazing_self_hit_retry(self, p, ng, o, wi, dist, accel=None) -> np.ndarray:
        """(K,) bool: still blocked after discarding float32 self-hits.

        Embree subtracts the ray origin from the vertices in float32, so a
        triangle's plane is only known to ~|vertex| * 2^-24; a shadow ray
        leaving a large triangle near the origin at grazing incidence (89.9
        deg) re-hits its own plane although it starts |p| * REL_OFFSET above
        it.  A first hit whose plane passes within 8 REL_OFFSET |vertex|_max
        of the origin is such a self-hit: the ray is cast again from an
        offset relative to that triangle's vertices.  A real occluder is
        never that close to the origin's plane at a magnitude that large, so
        shadows are kept.  accel: the scene the ray is cast in (None: ``accel``).
        """
        accel = self.accel if accel is None else accel
        h = accel.intersect(o, wi, dist)
        still = h.hit.copy()
        i = np.nonzero(h.hit)[0]
        if i.size == 0:
            return still
        self_hit, eps = shadow.self_hit(self.tri_p, h.prim[i], o[i])
        j = i[self_hit]
        if j.size:
            side = np.where(_dot(ng[j], wi[j]) >= 0, 1.0, -1.0)
            off = np.maximum(eps[self_hit], accel.offset_scale(p[j]))
            o2 = p[j] + ng[j] * (side * off)[:, None]
            still[j] = accel.occluded(o2, wi[j], dist[j])
        return still


def _add_lit(L: np.ndarray, q: np.ndarray, contrib: np.ndarray, T: np.ndarray) -> None:
    """L[q] += contrib * T on the rows that let light through (T (K, 3) > 0
    somewhere; q (K,) distinct): blocked rows are skipped, not multiplied by
    0, so an infinite contribution behind a wall stays out."""
    k = np.nonzero(T.max(axis=1) > 0)[0]
    L[q[k]] += contrib[k] * T[k]


def _occluded_f32(accel, o32: np.ndarray, d32: np.ndarray, t32: np.ndarray) -> np.ndarray:
    """``Accel.occluded`` of rays already in Embree's float32 (C-contiguous
    (K, 3), (K, 3), (K,)): (K,) bool, no conversions, in the calling thread
    (``_direct_blocks`` runs two of them at a time; Embree releases the GIL)."""
    K = o32.shape[0]
    accel.count_rays(K)
    if accel._scene is None or K == 0:
        return np.zeros(K, bool)
    return np.asarray(accel._scene.run(o32, d32, dists=t32, query="OCCLUDED")) >= 0
