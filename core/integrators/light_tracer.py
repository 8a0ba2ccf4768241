"""Light tracing: every non-delta vertex of a photon path is connected to the camera.

    lt = LightTracer(scene, accel, mtab, light_table, camera, settings, plan, D,
                     (x0, y0), (W, H), filter_width)
    sums = lt.trace_pass(n_paths, rng, check_stop)   # (H*W, 3) this pass's splats
    image = (sum of the passes' sums) / (light paths traced)

The photon tracer (core.sppm.photons, with deposits from the first hit on:
``photons_for_direct``) generates the light paths; its deposits are exactly
the non-delta vertices.  Each vertex y with flux weight beta (the photon's
power: Phi / p_select times the sampled BSDF weights and roulette, so that
E[sum_j beta_j g(y_j, w_j)] = int int L_i(y, w) |n_g . w| g dw dA) is joined
to a lens point by a shadow ray and splatted with the pixel filter.

Derivation (Veach 1997 chapter 10, the t = 1 technique; pbrt-v4
LightPathIntegrator / BDPT ``ConnectBDPT`` with t = 1).  The camera pass
(core.scene.camera.CameraModel.generate) estimates, for pixel p with centre
c_p, I_p = int f(x - c_p) <L(l, w(l, x))>_lens dx, f the normalised pixel
filter, x in pixels, l uniform on the lens (area A_lens).  At fixed l the
film point x maps to the direction w through the focus plane:
dx = dw / (A_pix cos^3 theta), A_pix the pixel's area on the unit-depth
plane, theta the ray's angle to the axis; and dw = |n_g(y) . w| dA(y) / d^2
at the surface point y, d = |y - l|.  With L(l, w) = L_o(y, -w) =
int f_s(-w, w_i) L_i |n_s . w_i| dw_i and the photon identity above:

    I_p = E[ sum_j beta_j f_s(w_c, w_j) (|n_s . w_j| / |n_g . w_j|)
                         |n_g . w_c| f(x_j - c_p) / (A_pix cos^3 theta d^2) ]

w_c the unit direction y -> l, w_j the photon's incoming direction;
1 / (A_pix cos^3 d^2) = We / pdf_wi in pbrt-v4's terms
(``CameraProjection.weight``; We = 1 / (A_pix A_lens cos^4),
pdf_wi = d^2 / (cos A_lens)).  The shading factor |n_s . w_j| / |n_g . w_j|
is the photon gather's (Veach 1997 section 5.3, capped at 4 like
core.sppm.photon_pass).  Orthographic cameras: dx = |n_g . w_c| dA / A_pix,
the weight is 1 / A_pix (a delta direction, no d^2).

Emission vertices (path length 1: the camera sees the emitter) of AREA lights
visible to the camera and of emissive MESH triangles, whose photons are
cosine-distributed: Phi_j / pi = L_e / pdf_A(y), so they are splatted with
f_s = 1 / pi and no shading factor, on the emitting side only.  Point/spot
lights with a radius (Cycles shows a disc or sphere), sun discs and the world
are not splatted (they are not seen in LIGHT mode).

What light tracing alone cannot render: anything the camera sees through a
delta (mirror or glass seen directly) -- the camera end of a path must be a
non-delta vertex, as in pbrt-v4's LightPathIntegrator.

Quantities for MIS (VCM, Georgiev et al. 2012, "Light transport simulation
with vertex connection and merging"; the dVCM / dVC / dVM recursion of their
implementation notes).  Camera side, per connection, in ``CameraProjection``:
We, pdf_pos = 1 / A_lens, pdf_dir = 1 / (A_pix cos^3) [solid angle], pdf_wi =
d^2 / (cos A_lens); the camera-path density of reaching y is pdf_dir |n_g . w_c|
/ d^2 [area] and the reverse density of the light path's previous vertex is
pdf_bsdf(w_c -> w_j) (``materials.pdf_bsdf``).  Light side, per vertex: the
emission densities pdf_A (p_select / area; a point light's delta position)
and pdf_W (cos / pi, 1 / (4 pi) for points); at every bounce the forward
solid-angle pdf of the sampled direction, its reverse pdf, and whether the
lobe was a delta.  Integrator 'COMBINED' follows them as running ratios in
the bounce kernel (``photon_kernels.MisState``, core.integrators.combined);
Russian roulette stays out of the densities, as in the paper.

The connection itself (projection, shadow rays, BSDF towards the lens, MIS
weight, splat) is compiled: core.integrators.light_kernels, around one
batched occlusion call (:meth:`LightTracer._transmittance`).
"""
from __future__ import annotations

import time
from typing import NamedTuple, Optional

import numpy as np
from .. import lights as Lt
from .. import materials as B
from ..materials import compiled as C, rough_maps
from ..materials.fast import GENERIC
from ..accel import RAY_CAMERA, REL_OFFSET, surface_point
from ..lights.shadow import attached as shadow_materials, transmittance
from ..scene import holdout as Holdout, ray_variants as RV
from ..sppm import photon_kernels as PK
from ..sppm.photon_pass import chunk_rng
from ..sppm.photons import PhotonTracer, _children, _pool, _threads
from . import light_kernels as LK
from .light_kernels import SHADING_CAP, splat_kernel

#: Light paths per chunk (memory bound; a cancel is seen between chunks).
CHUNK = 65_536
#: Chunks of at least this many paths are traced as two halves.
SPLIT_MIN = 16_384


def _triangles(dep) -> np.ndarray:
    """(K,) int64 the triangles of a PhotonTracer deposit dict's points
    (its bary (K, 3) holds (prim, u, v))."""
    return dep["bary"][:, 0].astype(np.int64)


class SplatSums(NamedTuple):
    """One chunk's splat sums (what a worker sends back): at the pixels idx
    (T,) int64, sums (T, 3) float64; idx None: every pixel (dense, when that
    is smaller); rays cast and seconds (for the statistics)."""
    idx: Optional[np.ndarray]
    sums: np.ndarray
    rays: int = 0
    seconds: float = 0.0

    @classmethod
    def sparse(cls, film: np.ndarray, rays: int = 0, seconds: float = 0.0) -> "SplatSums":
        """The sums of film (P, 3) at its non-zero pixels, or film itself when
        the pixel indices would cost more than the zeros they leave out."""
        idx = np.flatnonzero(np.any(film != 0, axis=1))
        if idx.size * (film.itemsize * 3 + idx.itemsize) >= film.nbytes:
            return cls(None, film, rays, seconds)
        return cls(idx, film[idx], rays, seconds)

    def add_to(self, film: np.ndarray) -> None:
        """film (P, 3) += these sums: the same bits as adding the chunk's
        dense film (x + 0 = x at the pixels left out)."""
        if self.idx is None:
            film += self.sums
        else:
            film[self.idx] += self.sums

    @property
    def nbytes(self) -> int:
        return self.sums.nbytes + (0 if self.idx is None else self.idx.nbytes)


class LightTracer:
    """Light tracing for one scene.  offset (x0, y0), size (W, H): the render
    region in Blender's pixel coordinates (y from the bottom)."""

    def __init__(self, scene, accel, mtab, light_table, camera, settings, plan, D,
                 offset, size, filter_width, filter_type="BLACKMAN_HARRIS"):
        self.scene, self.accel, self.mtab = scene, accel, mtab
        self.light_table, self.camera = light_table, camera
        # The table the light paths are drawn from (COMBINED: the traced
        # emitters only, mis.traced_table); its p_select is their density.
        self.emit_table = light_table
        # Deposits from the first hit on: every non-delta vertex is connected.
        self.tracer = PhotonTracer(scene, accel, mtab, light_table,
                                   settings.replace(photons_for_direct=True), plan, None, None,
                                   0.0, D)
        self.x0, self.y0 = (int(v) for v in offset)
        self.W, self.H = (int(v) for v in size)
        self.filter_width = float(filter_width)
        self.filter_type = filter_type
        # (T,) bool the triangles the camera sees nothing of, or None: those
        # of objects hidden from it and those where its rays end on a
        # holdout (core.scene.holdout); their light vertices are not splatted.
        hid = accel.hidden_from(RAY_CAMERA)
        held = Holdout.ends_camera(Holdout.triangle_weights(scene))
        self._unseen = held if hid is None else hid if held is None else hid | held
        # Each triangle's material as the lens sees it (a Light Path node's
        # Is Camera Ray, core.scene.ray_variants): the splat's BSDF.
        tm = self.tracer.tris.mat
        cam = RV.rows(scene, "camera")
        self._seen_mat = tm if cam is None else RV.seen(cam, tm).astype(tm.dtype)
        t = light_table
        # Emission vertices are splatted only for AREA lights and MESH
        # emitters the camera sees.  The compiled emission (same uniforms, same
        # photons up to round-off) where it covers every emitter kind.
        self.emitters_seen = bool(np.any((t.p_select > 0) & (
            ((t.kind == Lt.AREA) | (t.kind == Lt.MESH)) & t.visible_camera)))
        self.fast_emission = PK.fast_emission_ok(t)
        self.cam_params = LK.camera_params(camera, self.x0, self.y0, self.W, self.H,
                                           self.filter_width, filter_type)
        # What the splat kernel evaluates, and of it the LAMBERT materials
        # without Normal Map / Bump (combined.covered_materials).
        # Colour-textured materials (no alpha texture): each connection on
        # one gets a colour row of its own (materials.hit_colors, _rows).
        from ..materials.compiled import selection_table
        tex = self.tracer.textured
        self._sel = selection_table(mtab) if tex.any() else None
        self.splat_mat = LK.splat_materials(scene, mtab, self.tracer.fmat, tex, self._sel)
        self._colors = None
        if np.any(tex & (self.splat_mat.kind != LK.SLOW)):
            from ..materials.hit_colors import build_color_inputs
            self._colors = build_color_inputs(
                mtab, scene.tri_uv, lambert=tex & (self.splat_mat.kind == LK.LAMBERT_SPLAT))
        self.fast_mat = self.splat_mat.kind == LK.LAMBERT_SPLAT
        # View-dependent lobes (Lobe.view): the colour rows read the view.
        self._view = bool(B.view_dependent(mtab).any())
        # The GENERIC materials, whose connections _slow evaluates compiled.
        self.generic = self.tracer.fmat.cls == GENERIC
        self.rays = 0
        # Paths per chunk, and one random stream per chunk (chunk_rng) rather
        # than one per pass: chunks then split over processes
        # (tools/distributed.py) and give the same image in any of them.
        self.chunk = CHUNK
        self.chunk_streams = False

    # ------------------------------------------------------------------
    def trace_pass(self, n: int, rng, check_stop=lambda: None) -> np.ndarray:
        """Trace n light paths; return their splat sums (H*W, 3) float64 (not
        yet divided by the number of paths).  With ``chunk_streams`` chunk c
        (``chunks``) draws ``chunk_rng(rng, c)`` and its sums are added in
        chunk order: what another process computes for that chunk
        (:meth:`chunk_sums`, tools/distributed.py)."""
        self.begin_pass(n)
        film = np.zeros((self.H * self.W, 3))
        r0 = self.accel.rays_cast
        for c, k in enumerate(self.chunks(n)):
            check_stop()
            if self.chunk_streams:
                film += self._chunk_film(k, chunk_rng(rng, c))
            else:
                self._trace_chunk(k, rng, film)
        self.rays += self.accel.rays_cast - r0
        return film

    def begin_pass(self, n: int) -> None:
        """Per-pass state of n light paths (set before tracing any chunk)."""

    def chunks(self, n: int) -> list[int]:
        """Light paths of every chunk of a pass of n: ``chunk`` each (the last fewer)."""
        return [min(self.chunk, n - a) for a in range(0, n, self.chunk)]

    def chunk_sums(self, n_pass: int, n: int, rng) -> "SplatSums":
        """One chunk of n light paths of a pass of n_pass traced with rng:
        its splat sums at the pixels it touched (for ``SplatSums.add_to``)."""
        self.begin_pass(n_pass)
        r0, t0 = self.accel.rays_cast, time.perf_counter()
        film = self._chunk_film(n, rng)
        rays = self.accel.rays_cast - r0
        self.rays += rays
        return SplatSums.sparse(film, rays, time.perf_counter() - t0)

    def _chunk_film(self, k: int, rng) -> np.ndarray:
        """The splat sums (H*W, 3) of one chunk of k paths alone."""
        film = np.zeros((self.H * self.W, 3))
        self._trace_chunk(k, rng, film)
        return film

    def _trace_chunk(self, k: int, rng, film: np.ndarray) -> None:
        """Trace k light paths with rng, splatted into film (H*W, 3)."""
        if k < SPLIT_MIN:
            self._chunk(k, rng, film)
            return
        # Two halves on independent child streams, always (the image does
        # not depend on the number of cores, as PhotonTracer.trace), in two
        # threads when there are two (Embree, numba and most numpy release
        # the GIL), summed in a fixed order: it does not depend on timing.
        r_a, r_b = _children(rng)
        film_b = np.zeros_like(film)
        if _threads() > 1:
            fut = _pool().submit(self._chunk, k // 2, r_a, film)
            self._chunk(k - k // 2, r_b, film_b)
            fut.result()
        else:
            self._chunk(k // 2, r_a, film)
            self._chunk(k - k // 2, r_b, film_b)
        film += film_b

    def _chunk(self, n: int, rng, film: np.ndarray) -> None:
        if self.fast_emission:
            ph = PK.sample_photons_fast(self.emit_table, n, rng)
        else:
            ph = Lt.sample_photons(self.emit_table, n, rng)
        if self.emitters_seen:
            self._emission_vertices(ph, rng, film)
        dep = self.tracer.trace_emitted(ph, rng)
        if dep is not None:
            self.connect(dep, rng, film)

    def connect(self, dep, rng, film: np.ndarray, mis=None) -> None:
        """Splat the deposits dep (a PhotonTracer deposit dict: p, ng, wi
        (unit, back towards the light), power (K, 3), bary (K, 3) (prim, u,
        v)) into film (H*W, 3): one lens sample each, the projection and the
        shadow rays compiled (light_kernels.project_kernel), the shadow rays
        (:meth:`_transmittance`), the splat compiled on LAMBERT and GENERIC
        materials, colour-textured ones with a colour row per connection
        (light_kernels.splat_fast, ``splat_mat``, :meth:`_rows`), and by
        :meth:`_slow` on the others (Normal Map / Bump, alpha textures).
        mis: None, or (B0, B1, first, soft) (K,) of integrator 'COMBINED'
        (combined.splat_weight), optionally followed by mR2 (P,) (merging as
        an MIS strategy: SplatInputs.mR2)."""
        p = dep["p"]
        K = p.shape[0]
        if K == 0:
            return
        con, nc, tr = self._connections(p, dep["ng"], rng, _triangles(dep))
        if nc == 0:
            return
        one = np.zeros(1)
        B0, B1, first, soft = mis[:4] if mis is not None else (one, one, one > 0, one > 0)
        vin = LK.SplatInputs(dep["bary"], dep["wi"], dep["power"], B0, B1, first, soft,
                             *(mis[4:] if mis is not None else ()))
        tris = self.tracer.tris
        slow = np.empty(nc, np.int64)
        sm, crow = self._rows(con, nc, vin)
        ns = LK.splat_fast(con, nc, tr, vin, tris.n, tris.ng, self._seen_mat, sm, crow,
                           mis is not None, self.cam_params, self.filter_width, film, slow)
        if ns:
            self._slow(con, slow[:ns], tr, vin, mis is not None, film)

    _NO_ROWS = np.zeros(0, np.int64)

    def _rows(self, con, nc, vin):
        """(SplatMaterials, crow): ``splat_mat`` and no rows (each connection
        its material's) where no connection 0..nc-1 is on a colour-textured
        material; else splat_mat with a colour row appended per such
        connection (``hit_colors.hit_rows``: its lobe colours at its uv, their
        selection, the Lambert colour) and crow (nc,) every connection's row."""
        sm = self.splat_mat
        if self._colors is None:
            return sm, self._NO_ROWS
        bary = vin.bary[con.row[:nc]]
        prim = bary[:, 0].astype(np.int64)
        crow = np.asarray(self._seen_mat, np.int64)[prim]
        t = np.nonzero(self.tracer.textured[crow] & (sm.kind[crow] != LK.SLOW))[0]
        if t.size == 0:
            return sm, self._NO_ROWS
        from ..materials.hit_colors import hit_rows
        mu = None
        if self._view:
            # A view-dependent lobe seen from the lens (Cycles' camera side).
            _, _, ns, _ = surface_point(self.scene.tri_p, self.scene.tri_n, self.scene.tri_uv,
                                        prim[t], bary[t, 1], bary[t, 2])
            mu = np.abs(np.einsum("ij,ij->i", ns, con.wc[t]))
        S, col, rows = hit_rows(self._colors, self._sel, prim[t], bary[t, 1], bary[t, 2],
                                crow[t], mu)
        crow[t] = rows
        return sm._replace(col=np.concatenate([sm.col, col]), colors=S.colors, p=S.p), crow

    def _slow(self, con, c, tr, vin, mis, film) -> None:
        """The connections c whose material the splat kernel does not cover:
        eval_bsdf (and pdf_bsdf for the MIS weight), the GENERIC rows'
        compiled (core.materials.compiled "Radiance mode over arrays", the
        camera paths' calls: equal to numpy's to rounding)."""
        from .combined import splat_weight
        rows = con.row[c]
        bary = vin.bary[rows]
        prim = bary[:, 0].astype(np.int64)
        # The mesh's own ng, not the deposit's (flipped to the photon's side):
        # the materials orient ns with ng, and a flipped ng against an
        # unflipped ns let light through single-sided walls (eval_bsdf of
        # wo and wi on opposite sides: +94% on principled_interior.blend).
        _, ng, ns, uv = surface_point(self.scene.tri_p, self.scene.tri_n, self.scene.tri_uv,
                                      prim, bary[:, 1], bary[:, 2])
        m = rough_maps.pick(self.mtab, np.asarray(self._seen_mat, np.int64)[prim], prim,
                            bary[:, 1].astype(np.float32), bary[:, 2].astype(np.float32), uv)
        wc, wi, weight = con.wc[c], vin.wi[rows], con.weight[c]
        colors = B.lobe_colors(self.mtab, m, uv, B.view_mu(self.mtab, wc, ns))
        f = C.eval_radiance(self.mtab, self.generic, m, colors, ns, ng, wc, wi)
        corr = np.minimum(B.shading_correction(ns, ng, wi), SHADING_CAP)
        c1 = np.abs(np.einsum("ij,ij->i", ng, wc)) * weight
        contrib = f * vin.power[rows] * tr[c] * (c1 * corr)[:, None]
        if mis:
            pf = C.pdf_radiance(self.mtab, m, colors, ns, ng, wc, wi)
            bm = None
            if vin.mR2.shape[0] > 0:
                from .merge_kernels import pixel_rows
                cp = self.cam_params
                bm = np.where(vin.first[rows], 0.0,
                              vin.mR2[pixel_rows(con.raster[c], (cp.x0, cp.y0, cp.W, cp.H))] * c1)
            contrib *= splat_weight(vin.B0[rows], vin.B1[rows], pf, c1, vin.first[rows],
                                    vin.soft[rows], bm)[:, None]
        self._splat(con.raster[c], contrib, film)

    def _emission_vertices(self, ph, rng, film, mis=None) -> None:
        """Splat the emission vertices of AREA lights visible to the camera and
        of MESH emitters: f_s = 1 / pi on the emitting side (module doc;
        light_kernels.splat_emitters).  mis: None, or (kn, pA, full) of
        integrator 'COMBINED' (combined.emission_splat_weight; pA, full per
        row of ph)."""
        t = self.light_table
        light = ph["light"]
        ok = light >= 0
        kind = ph["kind"]
        lj = np.where(ok, light, 0)
        sel = ok & ((kind == Lt.AREA) | (kind == Lt.MESH)) & t.visible_camera[lj]
        idx = np.nonzero(sel)[0]
        if idx.size == 0:
            return
        if idx.size == sel.size:
            idx = slice(None)        # every photon (one emitter, seen): views, no copies
        o = ph["o"][idx]
        n = t.dir[light[idx]]
        # MESH photons leave from the side their direction points to.
        n = n * np.where(np.einsum("ij,ij->i", n, ph["d"][idx]) >= 0, 1.0, -1.0)[:, None]
        con, nc, tr = self._connections(o, n, rng)
        if nc == 0:
            return
        kn, pA, full = mis if mis is not None else (0.0, np.ones(1), np.ones(1, bool))
        if mis is not None:
            pA, full = np.ascontiguousarray(pA[idx]), np.ascontiguousarray(full[idx])
        power = np.ascontiguousarray(ph["power"][idx])
        lj = light[idx]
        spread = np.isfinite(t.spread_tan[lj])
        if np.any(spread):
            # An area light's spread: a photon's power carries the factor of
            # its own direction (emission.sample_photons); the emitter seen
            # from the camera carries the factor towards the camera instead,
            # on the light's power a sample (flux / p_select of the table
            # the photons were drawn from).
            power = power.copy()
            s = np.nonzero(spread)[0]
            power[s] = t.flux[lj[s]] / self.emit_table.p_select[lj[s], None]
            k = np.asarray(con.row[:nc])
            ks = k[spread[k]]
            cs = np.nonzero(spread[k])[0]
            cos_o = np.einsum("ij,ij->i", n[ks], con.wc[cs])
            power[ks] *= Lt.spread_atten(t, lj[ks], cos_o)[:, None]
        LK.splat_emitters(con, nc, tr, n, power,
                          mis is not None, float(kn), pA, full, self.cam_params,
                          self.filter_width, film)

    def _connections(self, p, ng, rng, tri=None):
        """Join the points p (K, 3) (geometric normals ng, any side) to a
        fresh lens sample each: (Connections of the points in front and near
        the region (rows 0..n-1; light_kernels.project_kernel), n, their
        (n, 3) transmittance to the lens: :meth:`_transmittance`).  tri (K,)
        int64 or None: the points' triangles; the camera does not see a point
        on an object hidden from it or held out (transmittance 0)."""
        K = p.shape[0]
        # Reused arrays (PhotonTracer.pool: no page faults per batch); the
        # same lens samples as rng.random((K, 2)).
        u_lens = self.tracer.uniforms(K, 2, rng)
        con = self.tracer.pool.take("connections", K, lambda r: list(LK.connections(r)),
                                    lambda a: LK.Connections(*a))
        n = LK.project_kernel(self.cam_params, p, ng, u_lens, REL_OFFSET,
                              self.accel.abs_floor / REL_OFFSET, con)
        if n == 0:
            return con, 0, np.zeros((0, 3))
        # The leaving surfaces' normals matter to transparent shadows alone
        # (their self-hit test); opaque scenes skip the (n, 3) gather.
        n0 = ng[con.row[:n]] if shadow_materials(self.accel, camera=True) is not None else None
        tr = self._transmittance(con.o[:n], con.wc[:n], con.t_max[:n], n0)
        if self._unseen is not None and tri is not None:
            tr[self._unseen[tri[con.row[:n]]]] = 0.0
        return con, n, tr

    def _transmittance(self, o, d, t_max, n0) -> np.ndarray:
        """(K, 3): the light the shadow rays from o (K, 3) along unit d let
        through to the lens before t_max (K,), leaving surfaces of unit
        normals n0 (K, 3) or None (core.lights.shadow: a single batched
        Embree call without transparent materials, which do not read n0;
        0 = blocked).  Every connection of the light tracers is tested here:
        a camera ray's, which passes the objects hidden from the camera."""
        return transmittance(self.accel.for_rays(RAY_CAMERA), o, d, t_max, n0=n0, camera=True)

    def _splat(self, raster, contrib, film) -> None:
        good = np.all(np.isfinite(contrib), axis=1)
        if not np.all(good):
            raster, contrib = raster[good], contrib[good]
        splat_kernel(np.ascontiguousarray(raster), np.ascontiguousarray(contrib),
                     self.x0, self.y0, self.W, self.H, self.filter_width,
                     self.cam_params.fk, film)
