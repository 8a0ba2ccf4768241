"""Visible points: the camera pass of one SPPM pass (pbrt-v4 SPPM, stage 1).

    camera_pass = CameraPass(scene, accel, mtab, light_table, camera, fsamp, px, py, max_depth)
    vp, L_emit = camera_pass(rng, check_stop)

One camera ray per pixel (filter and lens samples from ``rng``) follows the
delta (specular) lobes of the surfaces it hits, choosing one lobe per vertex,
until it reaches a vertex with a non-delta lobe: that vertex is the pixel's
visible point, where next-event estimation (core.lights.nee) and the photon
gather (core.sppm.photon_pass) estimate the reflected radiance.  Emission seen
along the chain (analytic emitters before each hit, emissive triangles, the
world on a miss) is returned separately as ``L_emit``.

With ``glossy_chains`` (photon mapping's default, the plan's "glossy chains")
a non-delta vertex on a material without a diffuse lobe (a metal, a Glossy
BSDF, rough glass: ``materials.glossy_only``) below the last vertex is a
glossy point instead, as pbrt-v4's SPPM makes its visible points only where
the BSDF has a diffuse part: the chain goes on by a sample of its non-delta
lobes.  Its direct light is found by two strategies weighed by multiple
importance sampling (core.sppm.glossy_mis): a light sample, added into
``L_emit`` at once (no glossy point is kept), and the emission the leaving
ray meets on its way to the next vertex (docs/method.md "Glossy chains,
round 30").
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, fields
from typing import Optional

import numpy as np

from ..accel import RAY_CAMERA, cast_by_kinds, chain_kinds, intersect_by_kinds, surface_point
from ..lights.shadow import attached as shadow_attached
from ..kept import KeptArrays
from ..scene import absorption as Absorb, holdout as Holdout, normals as shading_normals, ray_variants as RV
from ..scene.linking import lit
from .. import lights as Lt
from .. import materials as B
from ..materials import rough_maps
from ..mathutil import dot as _dot
from .glossy_mis import GlossyMIS, glossy_rows, light_uniforms
from . import line_hits as Line

#: Camera rays from which a wavefront's Embree call is split in two threads.
INTERSECT_SPLIT_MIN = 1 << 15
#: Rays per Embree call of the camera pass (``_intersect``).
INTERSECT_BLOCK = 1 << 14
#: Camera rays from which the emitters they see are found in blocks of
#: SEEN_BLOCK rays shared by two threads (``CameraPass._seen_by_camera``).
SEEN_SPLIT_MIN = 1 << 16
SEEN_BLOCK = 1 << 14
#: Pixels per block of the compiled camera pass's first vertex
#: (``CameraPass._trace_blocked``): its temporaries (~270 B a pixel) stay in
#: malloc's heap, reused block after block, instead of being page-faulted in
#: at every pass; still large enough for the two-thread splits above.
CAMERA_BLOCK = 1 << 16


@dataclass
class VisiblePoints:
    """Per-pixel visible points of one camera pass (P = pixels in the region).

    Each quantity in the smallest dtype its use allows (core.memory counts
    them): positions and geometric normals float64 (spawn offsets and the
    gather's plane tests are relative to |p| ~ 2^-18); directions, colours
    and throughputs float32 (their consumers compute in float64; 6e-8
    relative is far below the estimators' noise).

    valid (P,) bool; p, ng (P,3) float64; ns, wo (P,3) float32 (ng, ns
    oriented to wo); mat (P,) int16 (int32 beyond 32767 materials); colors
    (P,L,3) float32; beta (P,3) float32 path throughput / selection
    probability; depth (P,) float32 camera depth proxy for the pixel
    footprint; const (P,) bool (Lambert-only: f = albedo/pi); albedo (P,3)
    float32.
    front (P,) bool: wo lies on the mesh's geometric-normal side (ng and ns
    were not flipped).  The BSDF tells entering from leaving glass by it:
    :meth:`mesh_normals` gives the normals as the mesh has them.
    first: FirstHit of the camera rays (the film's data passes), or None.
    through_delta (P,) bool: the visible point was reached through at least
    one delta vertex (it is not the camera ray's first hit), or None.
    """
    valid: np.ndarray
    p: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    wo: np.ndarray
    mat: np.ndarray
    colors: np.ndarray
    beta: np.ndarray
    depth: np.ndarray
    const: np.ndarray
    albedo: np.ndarray
    front: Optional[np.ndarray] = None
    first: Optional["FirstHit"] = None
    through_delta: Optional[np.ndarray] = None

    @classmethod
    def empty(cls, P: int, n_lobes: int, n_materials: int = 1) -> "VisiblePoints":
        """P invalid visible points (every array zero)."""
        f32 = np.float32
        return cls(valid=np.zeros(P, bool), p=np.zeros((P, 3)), ng=np.zeros((P, 3)),
                   ns=np.zeros((P, 3), f32), wo=np.zeros((P, 3), f32),
                   mat=np.zeros(P, np.int16 if n_materials < 2**15 else np.int32),
                   colors=np.zeros((P, n_lobes, 3), f32), beta=np.zeros((P, 3), f32),
                   depth=np.zeros(P, f32), const=np.zeros(P, bool),
                   albedo=np.zeros((P, 3), f32), front=np.ones(P, bool))

    def mesh_normals(self, q) -> tuple[np.ndarray, np.ndarray]:
        """(ns, ng) (K, 3) of visible points q as the mesh has them (the
        materials orient them to wo themselves and use that side for the
        relative IOR, core.materials.eval_bsdf)."""
        s = np.where(self.front[q], 1.0, -1.0)[:, None]
        return self.ns[q] * s, self.ng[q] * s


#: The arrays of ``VisiblePoints.empty`` (``first`` and ``through_delta`` are set per pass).
_VP_ARRAYS = tuple(f.name for f in fields(VisiblePoints)
                   if f.name not in ("first", "through_delta"))


@dataclass
class FirstHit:
    """What each pixel's camera ray meets first (Cycles' data passes are
    written there: Depth, Normal, Mist, Emit, IndexOB, IndexMA).

    hit (P,) bool (False: the ray escaped to the world); p (P,3) float64;
    n (P,3) float64 shading normal facing the ray (Cycles flips N and Ng on
    back-face hits); prim (P,) int32 triangle (-1 on a miss); emit (P,3)
    float64 emission the camera ray sees directly (analytic emitters before
    the hit and the surface's own; not the world); escape (P,) float64 the
    throughput with which the camera ray escaped to the world straight
    through transparent surfaces (1 on a miss, 0 on an opaque hit), plus
    the holdout weight x throughput of the holdout surfaces it met there
    (core.scene.holdout): Cycles' alpha is 1 - escape.
    line: the pass's ``core.sppm.line_hits`` records (what the camera rays
    meet on their lines: Cryptomatte, the colour and Environment passes),
    or None (no pass reads them).
    """
    hit: np.ndarray
    p: np.ndarray
    n: np.ndarray
    prim: np.ndarray
    emit: np.ndarray
    escape: np.ndarray
    line: Optional[list] = None


_FIRST = tuple(f.name for f in fields(FirstHit) if f.name != "line")


def _crossings_only(accel, rays, vp) -> None:
    """Transparent crossings are no vertex (transparent shadows attached to
    accel, core.lights.shadow; photon merging's partition,
    core.integrators.merge): clears ``through_delta`` of the visible points
    reached through them only -- still on the camera ray's line (up to the
    crossings' spawn offsets) with nothing but transparent surfaces between
    the lens and them (glass at normal incidence keeps the line too)."""
    from ..lights import shadow
    if shadow.attached(accel, camera=True) is None:
        return
    w = vp.p - rays.o
    lw = np.linalg.norm(w, axis=1)
    tol = 1e-4 * (lw + np.linalg.norm(rays.o, axis=1))
    i = np.nonzero(vp.through_delta & (np.einsum("ij,ij->i", w, rays.d) > 0)
                   & (np.linalg.norm(np.cross(w, rays.d), axis=1) <= tol))[0]
    if i.size:
        T = shadow.transmittance(accel.for_rays(RAY_CAMERA), rays.o[i], w[i] / lw[i, None],
                                 lw[i] - tol[i], camera=True)
        vp.through_delta[i[T.max(axis=1) > 0]] = False


class CameraPass:
    """The camera pass over the pixels (px, py) (P,) float64 of the region,
    py counted from the bottom (Blender's); max_depth: vertices a delta chain
    may have (1 = the first hit only).  frame: (W, H) of the full frame when
    the region is a border: the filter and lens samples are then drawn as for
    the whole frame and picked by absolute pixel, so a border pixel's camera
    ray is the full-frame render's (None: the region is the frame).
    transparent: Film > Transparent (camera rays that escape add no world).
    compiled: the per-hit work in ``core.sppm.camera_kernels`` (False: the
    numpy reference, the same results).

    first_data: record the first hits' position, normal, triangle, hit flag
    and emission (``FirstHit``: the film's data passes, photon merging).
    False (the Renderer's choice when neither needs them): those arrays are
    empty (0 rows) and only ``escape`` (the film's alpha) is kept per pixel,
    77 of the 262 bytes a pixel the camera pass keeps from pass to pass
    (1080p: 0.16 GB less resident through the photon pass)."""

    def __init__(self, scene, accel, mtab, light_table, camera, fsamp, px, py, max_depth: int,
                 frame: Optional[tuple] = None, transparent: bool = False,
                 compiled: bool = True, first_data: bool = True, glossy_chains: bool = False):
        self.scene, self.accel, self.mtab, self.light_table = scene, accel, mtab, light_table
        # (T,) holdout weights or None (core.scene.holdout: camera rays end on
        # holdout objects and add the weight to the film's transparency).
        self._holdout = Holdout.triangle_weights(scene)
        self._held_through = Holdout.transparency(accel)    # (PER_HIT weights)
        self._absorb = Absorb.of_scene(scene)        # absorbing volumes, or None
        # (M,) the materials camera rays see in place of others (a Light
        # Path node, core.scene.ray_variants), or None: hits still on the
        # camera ray's line are shaded with them.
        self._camera_mat = RV.rows(scene, "camera")
        # (3,) whether the world is seen by camera, glossy and transmission
        # rays (a mirror's or glass's escaping ray: lights.world_seen_by).
        self._world_seen = Lt.world_seen_by(light_table)
        # Light linking (core.scene.linking): each triangle's emitter row,
        # for the emission a chain's ray finds on a triangle (None: no
        # linking).  The chains carry the material row of the vertex each
        # ray left (the receiver; -1 from the lens), the mis tuple's last.
        self._tri_light = (Lt.emitter_rows(light_table, scene.tri_p.shape[0])[0]
                           if getattr(light_table, "link_sets", None) is not None
                           and getattr(mtab, "receiver", None) is not None else None)
        # Glossy chains (pbrt-v4 SPPM): a vertex on a material without a
        # diffuse lobe (B.glossy_only) is a glossy point, not a visible point,
        # below max_depth; the chain goes on by a sample of its non-delta lobes.
        self._glossy_mat = B.glossy_only(mtab) if glossy_chains else None
        if self._glossy_mat is not None and not self._glossy_mat.any():
            self._glossy_mat = None
        # Their two strategies' weights; nee: the renderer's next-event
        # estimation, whose shadow rays the light samples take.
        self.mis = (GlossyMIS(light_table, mtab, scene.tri_p.shape[0])
                    if self._glossy_mat is not None else None)
        self.nee = None
        self.glossy_count = 0           # glossy points of the last call (a count, for tests)
        self._ones = np.ones(0)         # _glossy_emission's weights without glossy chains
        # The compiled kernel interpolates tri_n itself: scenes whose shading
        # normals are perturbed (Normal Map / Bump, core.scene.normals) take
        # the numpy pass, whose surface_point applies the perturbation.
        self.compiled = bool(compiled) and shading_normals.attached(scene.tri_n) is None
        self._cmats = None
        self.camera, self.fsamp = camera, fsamp
        self.px, self.py = px, py
        self.max_depth = int(max_depth)
        self.transparent = bool(transparent)
        self.first_data = bool(first_data)
        # Record what the camera rays meet on their lines (core.sppm.line_hits;
        # the Renderer sets it when a film pass reads them).
        self.line_hits = False
        self.pixel_id = None
        self._kept = KeptArrays()
        if frame is not None:
            Wf, Hf = (int(v) for v in frame)
            # Row 0 of the frame's sample array is the top row (py = Hf - 1).
            pid = ((Hf - 1 - py.astype(np.int64)) * Wf + px.astype(np.int64))
            if not np.array_equal(pid, np.arange(px.shape[0])):
                # Only the frame rows the region spans are drawn; the others
                # are skipped (PCG64.advance: one uint64 per float64 draw).
                r0, r1 = int(pid.min() // Wf), int(pid.max() // Wf) + 1
                self.skip = (4 * r0 * Wf, 4 * (Hf - r1) * Wf)
                self.block = (r1 - r0) * Wf
                self.pixel_id = pid - r0 * Wf

    def __call__(self, rng: np.random.Generator, check_stop=lambda: None,
                 centre: bool = False) -> tuple[VisiblePoints, np.ndarray]:
        """(visible points, L_emit (P, 3) float64 emission seen along the chains).

        centre=True: through the pixel centre and the lens centre (the
        surface-boundary cap's pass, core.sppm.edges).  check_stop() is called
        before every vertex (it raises to cancel)."""
        P = self.px.shape[0]
        mtab, accel = self.mtab, self.accel
        self._glossy_n = []
        if (self.compiled and self.pixel_id is None and P > CAMERA_BLOCK
                and isinstance(rng.bit_generator, np.random.PCG64)
                and shadow_attached(accel) is None):
            vp, L = self._outputs(P, keep=not centre)
            self._trace_blocked(rng, vp, L, check_stop, centre)
            self.glossy_count = sum(self._glossy_n)
            return vp, L
        if self.pixel_id is None:
            u = rng.random((P, 4))
        else:
            rng.bit_generator.advance(self.skip[0])
            u = rng.random((self.block, 4))[self.pixel_id]
            rng.bit_generator.advance(self.skip[1])
        if centre:
            u[:, :2] = 0.5      # FilterSampler.sample(0.5) = 0: the pixel centre
            u[:, 2:] = 0.0      # lens radius sqrt(0) = 0
        rays, dz = self.camera.generate(self.px, self.py, u[:, :2], u[:, 2:], self.fsamp)
        del u                   # (P, 4) float64: not held through the trace (the stage's peak)
        # The edge cap's pass (once a render) gets arrays of its own: through
        # the kept ones, they would stay resident beside the next pass's
        # through the first pass's photons (0.5 GiB at 1080p).
        vp, L = self._outputs(P, keep=not centre)
        trace = self._trace_compiled if self.compiled else self._trace_numpy
        trace(rng, rays, dz, vp, L, check_stop)
        # vp.through_delta: written with the visible point (False at the
        # first hit, True after a delta or glossy vertex; False where no point).
        _crossings_only(accel, rays, vp)
        self.glossy_count = sum(self._glossy_n)
        return vp, L

    def _outputs(self, P: int, keep: bool = True) -> tuple[VisiblePoints, np.ndarray]:
        """Cleared visible points (with their FirstHit and through_delta) and
        L (P, 3) for one pass: the last pass's arrays when the caller has dropped them
        (core.kept: no page faults of fresh pixel-sized arrays every pass);
        keep=False: new arrays, not kept.  Without ``first_data`` the
        FirstHit arrays but ``escape`` have 0 rows."""
        mtab = self.mtab
        Pf = P if self.first_data else 0

        def make():
            vp = VisiblePoints.empty(P, mtab.kind.shape[1], mtab.kind.shape[0])
            first = FirstHit(hit=np.zeros(Pf, bool), p=np.zeros((Pf, 3)), n=np.zeros((Pf, 3)),
                             prim=np.full(Pf, -1, np.int32), emit=np.zeros((Pf, 3)),
                             escape=np.zeros(P))
            return ([getattr(vp, f) for f in _VP_ARRAYS] + [getattr(first, f) for f in _FIRST]
                    + [np.zeros(P, bool), np.zeros((P, 3))])
        a = self._kept.get(make, (P, Pf)) if keep else make()
        n = len(_VP_ARRAYS)
        vp = VisiblePoints(**dict(zip(_VP_ARRAYS, a[:n])))
        vp.first = FirstHit(**dict(zip(_FIRST, a[n:n + len(_FIRST)])),
                            line=[] if self.line_hits else None)
        vp.through_delta = a[-2]
        return vp, a[-1]

    def _seen_along(self, depth, L, first, o, d, tmax, t, hit, idx, beta, last, see_through,
                    fast=False, split=True, left=None):
        """The emission rays (K,) of one vertex see before their hit t (K,)
        float64 (inf on a miss): analytic emitters, and on a miss the world
        (or, for camera rays seen through, alpha under Film > Transparent).
        fast: skip the masks and scatters that change nothing (the camera
        rays of depth 0 are consecutive pixels in order; a black constant
        world adds 0); the same sums.  split=False: in the calling thread.
        left (K,): the material row of the vertex each ray left (-1: the
        lens), the receiver of light linking."""
        whole = fast and depth == 0             # idx consecutive pixels, last = 0 (camera)
        for code, name in ((0, "camera"), (1, "glossy"), (2, "transmission")):
            if whole:
                if code == 0 and self._any_seen("camera"):
                    # idx: the pixels a0.. in order (a block of them, _trace_blocked)
                    a0 = int(idx[0]) if idx.size else 0
                    emit = first.emit[a0:a0 + idx.size] if first.emit.shape[0] else first.emit
                    self._seen_by_camera(L[a0:a0 + idx.size], emit, o, d, tmax, t, beta,
                                         SEEN_SPLIT_MIN if split else np.inf)
                continue
            sel = last == code
            if np.any(sel) and (not fast or self._any_seen(name)):
                if self._tri_light is not None and left is not None:
                    Le, row, _ = Lt.emitted_along_rays(self.light_table, o[sel], d[sel],
                                                       np.minimum(t[sel], tmax[sel]), name,
                                                       return_hit=True)
                    ok = lit(self.light_table, self.mtab, row, left[sel])
                    Le[~ok] = 0.0
                else:
                    Le = Lt.emitted_along_rays(self.light_table, o[sel], d[sel],
                                               np.minimum(t[sel], tmax[sel]), name)
                L[idx[sel]] += beta[sel] * Le
                if depth == 0 and first.emit.shape[0]:
                    first.emit[idx[sel]] += Le
        miss = ~hit
        esc = miss & see_through
        if np.any(esc):
            first.escape[idx[esc]] += beta[esc].mean(axis=1)
            if self.transparent:
                miss = miss & ~esc      # Film > Transparent: alpha 0, no world
        lt = self.light_table
        if fast and lt.environment is None and lt.camera_environment is None \
                and not np.any(lt.world):
            return
        if np.any(miss):
            if lt.camera_environment is not None:
                # The rays still on the camera ray's line see the camera's map.
                cam = miss & see_through
                if np.any(cam):
                    L[idx[cam]] += beta[cam] * Lt.world_radiance(lt, d[cam], camera=True)
                miss = miss & ~see_through
            if np.any(miss):
                # A mirror's or glass's ray sees the world by its Glossy and
                # Transmission visibility (Scene.world_hidden).
                seen = self._world_seen[last[miss]]
                L[idx[miss]] += beta[miss] * Lt.world_radiance(lt, d[miss]) * seen[:, None]

    def _seen_by_camera(self, L, emit, o, d, tmax, t, beta, split_min=SEEN_SPLIT_MIN) -> None:
        """L += beta * Le and emit += Le, Le the analytic emitters the camera
        rays (every pixel, in order) see before t (K,) (``_seen_along``).
        Above SEEN_SPLIT_MIN rays: in blocks of SEEN_BLOCK rays (so that
        ``emitted_along_rays``' temporaries stay small and are not page-faulted
        in afresh), the blocks shared by two threads (numpy releases the GIL);
        each ray's Le depends on that ray alone, so the sums are the same bits.
        split_min: rays from which the blocks are shared (np.inf: never)."""
        from .photons import in_two_halves

        def blocks(a0, a1):
            for a in range(a0, a1, SEEN_BLOCK):
                b = min(a + SEEN_BLOCK, a1)
                Le = Lt.emitted_along_rays(self.light_table, o[a:b], d[a:b],
                                           np.minimum(t[a:b], tmax[a:b]), "camera")
                L[a:b] += beta[a:b] * Le
                if emit.shape[0]:
                    emit[a:b] += Le
        in_two_halves(blocks, o.shape[0], split_min, align=SEEN_BLOCK)

    def _any_seen(self, visibility: str) -> bool:
        """Whether any analytic emitter can be seen by rays of this kind
        (``core.lights.seen.emitted_along_rays`` adds 0 otherwise)."""
        lt = self.light_table
        flag = getattr(lt, "visible_" + visibility)
        return bool(np.any(flag & (lt.kind != Lt.MESH) & (lt.kind != Lt.WORLD)
                           & np.any(lt.radiance != 0, axis=1)))

    def _trace_numpy(self, rng, rays, dz, vp, L, check_stop):
        """The camera pass in numpy (the reference of :meth:`_trace_compiled`)."""
        P = self.px.shape[0]
        mtab, accel, first = self.mtab, self.accel, vp.first
        # Still "seen through" by the camera: no vertex yet, or only straight
        # transmissions (Transparent BSDF); Cycles' transparent background.
        see_through = np.ones(P, bool)
        idx = np.arange(P)
        o, d, tmax = rays.o, rays.d, rays.t_max
        beta = np.ones((P, 3))
        path_len = np.zeros(P)
        last = np.zeros(P, np.int8)      # 0 camera, 1 reflection, 2 transmission
        mis = _no_mis(P)                 # (pdf, p, n) of the glossy point each ray leaves
        for depth in range(self.max_depth):
            if idx.size == 0:
                break
            check_stop()
            # Rays still on the camera ray's line are camera rays (Cycles keeps
            # the flag through transparent crossings): they pass the objects
            # hidden from the camera; a mirror's or a glass's rays those
            # hidden from glossy or transmission rays.
            h = intersect_by_kinds(accel, chain_kinds(see_through, last), o, d, tmax)
            hit = h.hit
            Absorb.attenuate(self._absorb, h.prim, h.t, d, beta)
            ends = Holdout.camera_hits(self._holdout, h.prim, see_through, beta, first.escape,
                                       idx, (h.u, h.v), self._held_through)
            Line.record(first.line, h.prim, see_through, beta, idx, (h.u, h.v), d,
                        shadow_attached(accel, camera=True), ends)
            # Analytic emitters (area lights, light spheres) seen before the hit.
            self._seen_along(depth, L, first, o, d, tmax, h.t, hit, idx,
                             self._emitting(beta, mis[0]), last, see_through, left=mis[3])
            ew = self._glossy_emission(L, idx, o, d, h.t, h.prim, beta, last, mis)
            ih = np.nonzero(hit if ends is None else hit & ~ends)[0]
            if ih.size == 0:
                break
            s = self.scene
            p, ng, ns, uv = surface_point(s.tri_p, s.tri_n, s.tri_uv, h.prim[ih], h.u[ih], h.v[ih])
            wo = -d[ih]
            mat = rough_maps.pick(mtab, RV.seen(self._camera_mat, s.tri_mat[h.prim[ih]],
                                                see_through[ih]),
                                  h.prim[ih], h.u[ih], h.v[ih], uv)
            colors = B.lobe_colors(mtab, mat, uv, B.view_mu(mtab, wo, ns))
            em = mtab.emission[mat]
            if np.any(em > 0):
                if mtab.emission_tex is not None and np.any(mtab.emission_tex[mat] >= 0):
                    em = em * _emission_texture(mtab, s, mat, uv)
                L[idx[ih]] += beta[ih] * em * ew[ih, None]
            if depth == 0 and first.p.shape[0]:
                sgn0 = np.where(_dot(ng, wo) >= 0, 1.0, -1.0)[:, None]
                q = idx[ih]
                first.hit[q], first.p[q], first.n[q] = True, p, ns * sgn0
                first.prim[q] = h.prim[ih]
                if np.any(em > 0):
                    first.emit[q] += em
            bt = beta[ih]
            plen = path_len[ih] + h.t[ih]
            p_delta = B.delta_probability(mtab, mat, colors)
            ur = rng.random((ih.size, 4))
            go_delta = ur[:, 0] < p_delta
            if depth == self.max_depth - 1:
                go_delta[:] = False
            # Visible points where the chain stops (pbrt-v4 SPPM: first
            # non-specular vertex); throughput divided by the choice probability.
            mk = ~go_delta & mtab.has_nondelta[mat]
            if np.any(mk):
                q = idx[ih[mk]]
                sgn = np.where(_dot(ng[mk], wo[mk]) >= 0, 1.0, -1.0)[:, None]
                vp.valid[q] = True
                vp.through_delta[q] = depth > 0
                vp.front[q] = sgn[:, 0] > 0
                vp.p[q] = p[mk]
                vp.ng[q] = ng[mk] * sgn
                # Cycles flips the shading normal together with the geometric
                # one (back-face hits), not by its own side of wo.
                vp.ns[q] = ns[mk] * sgn
                vp.wo[q] = wo[mk]
                vp.mat[q] = mat[mk]
                vp.colors[q] = colors[mk]
                vp.beta[q] = bt[mk] / np.maximum(1.0 - p_delta[mk], 1e-12)[:, None]
                vp.depth[q] = plen[mk] * np.abs(dz[q])
                vp.const[q] = mtab.lambert_only[mat[mk]]
                vp.albedo[q] = B.lambert_albedo(mtab, mat[mk], colors[mk])
            gl = None
            if self._glossy_mat is not None and depth < self.max_depth - 1:
                g = np.nonzero(mk & self._glossy_mat[mat])[0]
                if g.size:
                    q = idx[ih[g]]
                    gl = self._glossy_chains(vp, L, q, ur[g, 1:4], plen[g], dz[q])
            cont = go_delta & (p_delta > 0)
            c = np.nonzero(cont)[0]
            nxt = None
            if c.size:
                nxt = self._continue(p[c], ng[c], ns[c], wo[c], mat[c], colors[c], bt[c],
                                     plen[c], p_delta[c], ur[c, 1:4], see_through[ih[c]],
                                     d[ih[c]], tuple(a[ih[c]] for a in mis))
            parts = []
            if nxt is not None:
                keep = nxt[0]
                parts.append((c[keep], (idx[ih[c[keep]]],) + nxt[1:]))
            if gl is not None:
                keep = gl[0]
                parts.append((g[keep], (idx[ih[g[keep]]],) + gl[1:7] + gl[8:]))
            if not parts:
                break
            idx, o, d, beta, path_len, last, see_through, *mis = _in_row_order(parts)
            tmax = np.full(idx.size, np.inf)

    def _continue(self, p, ng, ns, wo, mat, colors, bt, plen, p_delta, u, see_through, d_in,
                  mis):
        """Sample the delta lobes of the K chains that continue (mesh normals
        ng, ns; throughput bt before the lobe; u (K, 3) uniforms; mis the
        (pdf, p, n) of the glossy point each ray left, pdf 0: none, and the
        material row of the vertex it left).  Returns (kept rows (n,), o, d,
        beta (n, 3), path length (n,), last (n,) int8 1 reflection / 2
        transmission, see_through (n,), pdf, p, n, left), None when none is
        kept.  A straight crossing of a transparent surface is no vertex
        where shadow rays pass them (core.lights.shadow): the ray keeps its
        glossy point's state; any other delta vertex clears it.  Its
        receiver for light linking is the vertex's material, but after a
        straight crossing (Cycles: a transparent bounce keeps the path's
        mis_ray_object)."""
        mtab = self.mtab
        wi, wgt, pdf, is_delta, valid = B.sample_bsdf(mtab, mat, colors, ns, ng, wo, u,
                                                      subset="delta", mode="radiance")
        wgt = wgt / p_delta[:, None]
        ok = valid & np.all(np.isfinite(wgt), axis=1) & (wgt.max(axis=1) > 0)
        keep = np.nonzero(ok)[0]
        if keep.size == 0:
            return None
        wi = wi[keep]
        straight = _dot(wi, d_in[keep]) > 1.0 - 1e-9
        st = see_through[keep] & straight
        o, last = self._leaving(p[keep], ng[keep], wo[keep], wi)
        out = _no_mis(keep.size)[:3]
        if shadow_attached(self.accel) is not None and np.any(mis[0][keep] > 0):
            out = tuple(np.where(straight.reshape((-1,) + (1,) * (a.ndim - 1)), a[keep], 0.0)
                        for a in mis[:3])
        left = (np.where(straight, mis[3][keep], mat[keep]) if self._tri_light is not None
                else _no_mis(keep.size)[3])     # (without light linking: not read)
        return (keep, o, wi, bt[keep] * wgt[keep], plen[keep], last, st) + out + (left,)

    def _emitting(self, beta, pdf):
        """The throughput (K, 3) with which rays add the emission ``_seen_along``
        finds: beta, but 0 where a ray leaves a glossy point (pdf > 0), whose
        emission ``_glossy_emission`` weighs (no test without glossy chains)."""
        if self.mis is None or pdf.size == 0 or not np.any(pdf > 0):
            return beta
        return np.where((pdf > 0)[:, None], 0.0, beta)

    def _glossy_emission(self, L, idx, o, d, t, prim, beta, last, mis) -> np.ndarray:
        """The emission the rays leaving glossy points (mis = (pdf, p, n) (K,),
        (K, 3), (K, 3) of the point each ray left, pdf > 0) meet before their
        hit at t (K,) (inf on a miss; prim (K,) the triangle or -1), weighed
        against the light sample taken at the point (``GlossyMIS.bsdf_weight``):
        the analytic emitters and, where they escape, the world, added to L
        at pixels idx with throughput beta.  Returns ew (K,) float64 the
        weight of an emissive triangle at each ray's hit (``Wavefront.ew``):
        1 for the rays that leave no glossy point (without glossy chains a
        view of ones kept from call to call, which no one writes: no
        per-pass array).  With light linking, 0 also where the triangle's
        emitter does not light the vertex the ray left (``mis``' last)."""
        K = idx.size
        if self.mis is None:
            if self._ones.size < K:
                self._ones = np.ones(K)     # only read (a writeable array: one kernel type)
            return self._unlit_hits(self._ones[:K], prim, mis[3])
        pdf, pp, nn, left = mis
        ew = self._unlit_hits(np.ones(K), prim, left)
        g = np.nonzero(pdf > 0)[0]
        if g.size == 0:
            return ew
        M, lt = self.mis, self.light_table
        seen = ew[g] > 0                 # (light linking)
        ew[g] = 0.0
        row = np.where(prim[g] >= 0, M.tri_light[np.maximum(prim[g], 0)], -1)
        e = np.nonzero((row >= 0) & seen)[0]
        if e.size:
            r = g[e]
            dist = np.linalg.norm(o[r] + t[r, None] * d[r] - pp[r], axis=1)
            ew[r] = M.bsdf_weight(pdf[r], pp[r], nn[r], d[r], row[e], dist)
        for code, name in ((1, "glossy"), (2, "transmission")):
            sel = g[last[g] == code]
            if sel.size == 0:
                continue
            Le, rw, th = Lt.emitted_along_rays(lt, o[sel], d[sel], t[sel], name, return_hit=True)
            m = np.nonzero(rw >= 0)[0]
            if m.size:
                r = sel[m]
                # The distance from the glossy point (inf: a sun's disc).
                dist = np.full(m.size, np.inf)
                f = np.isfinite(th[m])
                dist[f] = np.linalg.norm(o[r[f]] + th[m[f], None] * d[r[f]] - pp[r[f]], axis=1)
                w = M.bsdf_weight(pdf[r], pp[r], nn[r], d[r], rw[m], dist)
                ok = lit(lt, self.mtab, rw[m], left[r])
                if ok is not None:
                    w = w * ok
                L[idx[r]] += beta[r] * Le[m] * w[:, None]
        esc = g[prim[g] < 0]
        if esc.size and M.world_row >= 0:
            w = M.bsdf_weight(pdf[esc], pp[esc], nn[esc], d[esc], np.full(esc.size, M.world_row),
                              np.full(esc.size, np.inf))
            L[idx[esc]] += beta[esc] * Lt.world_radiance(lt, d[esc]) * w[:, None]
        return ew

    def _unlit_hits(self, ew, prim, left):
        """ew (K,) with 0 where a ray's hit triangle (prim (K,), -1 none)
        emits for an emitter that does not light the vertex the ray left
        (left (K,) material rows, -1 the lens): light linking
        (core.scene.linking); ew itself without linking or such a ray."""
        if self._tri_light is None:
            return ew
        k = np.nonzero((left >= 0) & (prim >= 0))[0]
        if k.size == 0:
            return ew
        row = self._tri_light[prim[k]]
        ok = lit(self.light_table, self.mtab, row, left[k])
        if ok.all():
            return ew
        ew = ew.copy()
        ew[k[~ok]] = 0.0
        return ew

    def _leaving(self, p, ng, wo, wi):
        """Origins (n, 3) of the rays leaving points p (n, 3) along wi, and
        their kind (n,) int8: 1 reflection, 2 transmission (wi on wo's side
        of the mesh normal ng or not)."""
        refl = (_dot(wi, ng) * _dot(wo, ng)) > 0
        return self.accel.spawn(p, ng, wi), np.where(refl, 1, 2).astype(np.int8)

    def _glossy_chains(self, vp, L, q, u, plen, dz):
        """The visible points just written at pixels q (K,) on glossy-only
        materials become glossy points: their light samples
        (``GlossyMIS.direct``) are added into L (P, 3), they are visible
        points no longer, and their chains go on by a sample of the
        non-delta lobes (u (K, 3) the hit's unused uniforms ur[:, 1:4];
        plen, dz (K,) path length and depth factor).  vp: the VisiblePoints
        or their VPBuffers.  Returns (kept rows (n,), o, d, beta (n, 3), path
        length, last (n,) int8 1 reflection / 2 transmission, see_through
        (n,) False, dz (n,), then the glossy points' (pdf (n,), p (n, 3), n
        (n, 3)) for the MIS weight of the emission the rays meet,
        ``_glossy_emission``), None when none is kept.

        The throughput is the visible point's (over the probability of not
        choosing a delta lobe) times f |cos| / pdf of the sample.  The light
        samples' uniforms are a hash of u (``glossy_mis.light_uniforms``):
        each point's own, however the wavefront was split."""
        self._glossy_n.append(q.size)
        g = glossy_rows(vp, q)
        L[q] += self.mis.direct(g, light_uniforms(u), self.nee)
        vp.valid[q] = False
        vp.through_delta[q] = False
        wi, wgt, pdf, _, ok = self.mis.sample(g.mat, g.colors, g.ns, g.ng, g.wo, u)
        ok = ok & np.all(np.isfinite(wgt), axis=1) & (wgt.max(axis=1) > 0)
        keep = np.nonzero(ok)[0]
        if keep.size == 0:
            return None
        wi = wi[keep]
        o, last = self._leaving(g.p[keep], g.ng[keep], g.wo[keep], wi)
        return (keep, o, wi, g.beta[keep] * wgt[keep], plen[keep], last,
                np.zeros(keep.size, bool), dz[keep], pdf[keep], g.p[keep], g.n[keep],
                np.asarray(g.mat, np.int64)[keep] if self._tri_light is not None
                else _no_mis(keep.size)[3])

    def _trace_compiled(self, rng, rays, dz, vp, L, check_stop):
        """The camera pass with the per-hit work in ``camera_kernels.hit_kernel``
        (same random numbers, same results as :meth:`_trace_numpy`)."""
        P = self.px.shape[0]
        dz = np.ascontiguousarray(dz, np.float64)   # one kernel signature (C layout)
        live = (rays.o, rays.d, rays.t_max, np.arange(P), np.ones((P, 3)), np.zeros(P),
                np.zeros(P, np.int8), np.ones(P, bool), dz) + _no_mis(P)
        self._chains_from(0, live, rng, self._kernel_context(vp, L), check_stop)

    def _trace_blocked(self, rng, vp, L, check_stop, centre):
        """:meth:`__call__`'s camera rays and :meth:`_trace_compiled`'s first
        vertex in blocks of CAMERA_BLOCK pixels, the delta chains' later
        vertices after them: the same random numbers and results, without
        pixel-sized temporaries (rays, uniforms, Embree's hits: 0.4 GB at
        1080p, page-faulted in every pass).  The camera's depth factors dz
        travel with the live chains (one a ray, the live tuple's last
        array), not in a (P,) array: 16 MB at 1080p, 4k page faults a pass.

        Two threads (this one and core.sppm.photons' pool) take the blocks in
        turn and do each one end to end (``_first_block``): no step of it
        waits on numpy glue in one thread.  The filter and lens uniforms of
        pixel i are the draws 4i .. 4i+3 of rng's stream, the delta choices
        of the first hits the next ones, 4 a hit in pixel order: a block
        draws from copies of the stream advanced to its own (``stream_at``),
        the second at 4 P + 4 x (the hits of the blocks before it), which it
        waits for (the blocks before it have cast their rays by then, in
        either thread).  Each pixel's results are its own, so they are the
        same bits however the blocks are shared."""
        P = self.px.shape[0]
        ctx = self._kernel_context(vp, L)
        starts = list(range(0, P, CAMERA_BLOCK))
        n = len(starts)
        # hits[i]: the first hits of blocks 0 .. i-1, set once ready[i] is
        hits, ready = [0] * (n + 1), [threading.Event() for _ in range(n + 1)]
        ready[0].set()
        nxt, todo, failed = [None] * n, iter(range(n)), []
        take = threading.Lock()

        def worker():
            try:
                while not failed:
                    with take:
                        i = next(todo, None)
                    if i is None:
                        return
                    check_stop()
                    a = starts[i]
                    nxt[i] = self._first_block(a, min(a + CAMERA_BLOCK, P), rng, ctx, centre,
                                               hits, ready, i, failed)
            except BaseException:
                failed.append(True)
                for e in ready:             # no block waits for one that will not come
                    e.set()
                raise
        in_two_threads(worker)
        rng.bit_generator.advance(4 * P + 4 * hits[n])
        nxt = [x for x in nxt if x is not None]
        if nxt:
            live = tuple(np.concatenate(c) for c in zip(*nxt))
            self._chains_from(1, live, rng, ctx, check_stop)

    def _first_block(self, a, b, rng, ctx, centre, hits, ready, i, failed):
        """Block i, pixels a .. b-1, of :meth:`_trace_blocked` in the calling
        thread: its camera rays (uniforms from rng's stream at 4a), their
        first hits, the emission they see, then -- once the hits before the
        block are counted (ready[i]) -- its delta choices and visible points.
        Sets hits[i + 1] and ready[i + 1].  The next vertex's live chains, or None."""
        n = b - a
        u = stream_at(rng, 4 * a).random((n, 4))
        if centre:
            u[:, :2], u[:, 2:] = 0.5, 0.0     # as __call__
        # threads=False: two threads may generate at once (one numba parallel
        # region at a time)
        rays, dz = self.camera.generate(self.px[a:b], self.py[a:b], u[:, :2], u[:, 2:],
                                        self.fsamp, threads=False)
        del u
        live = (rays.o, rays.d, rays.t_max, np.arange(a, b), np.ones((n, 3)), np.zeros(n),
                np.zeros(n, np.int8), np.ones(n, bool),
                np.ascontiguousarray(dz, np.float64)) + _no_mis(n)
        hit = self._wavefront_rays(0, live, ctx, split=False)
        ready[i].wait()
        if failed:
            return None
        h0 = hits[i]
        hits[i + 1] = h0 + int(np.count_nonzero(hit[0] >= 0))
        ready[i + 1].set()
        P = self.px.shape[0]
        return self._wavefront_hits(0, live, hit, stream_at(rng, 4 * P + 4 * h0), ctx,
                                    split=False)

    def _kernel_context(self, vp, L):
        """What every wavefront's kernel call shares: (camera materials,
        textured (M,) bool, VPBuffers, FirstBuffers, the FirstHit, L)."""
        from . import camera_kernels as CK
        mtab, s = self.mtab, self.scene
        if self._cmats is None:
            self._cmats = CK.build_camera_materials(mtab, s)
            tex = np.any(mtab.tex >= 0, axis=1) | B.view_dependent(mtab)
            if self._camera_mat is not None:
                # Their camera-line hits pick the camera rays' material.
                tex[:self._camera_mat.size] |= self._camera_mat != np.arange(self._camera_mat.size)
            if mtab.emission_tex is not None:
                tex |= mtab.emission_tex >= 0
            if mtab.rough_first is not None:
                tex |= mtab.rough_first >= 0      # their hits pick a level row
            self._textured = tex
        first = vp.first
        return (self._cmats, self._textured, CK.vp_buffers(vp),
                CK.FirstBuffers(first.hit, first.p, first.n, first.prim, first.emit, L), first, L)

    def _chains_from(self, depth0, live, rng, ctx, check_stop):
        """Wavefronts depth0, depth0 + 1, ... of the live chains until none is left."""
        for depth in range(depth0, self.max_depth):
            if live[3].size == 0:
                break
            check_stop()
            live = self._wavefront(depth, live, rng, ctx)
            if live is None:
                break

    def _wavefront(self, depth, live, rng, ctx):
        """One vertex of the live chains (o, d, tmax, idx (K,) pixel, beta,
        path_len, last, see_through, dz (K,) the camera's depth factor of the
        pixel, then the (pdf (K,), p, n (K, 3)) of the glossy point each ray
        left, pdf 0 where none): Embree, the emission seen along the rays
        (``_wavefront_rays``), ``hit_kernel``, the delta lobes' samples
        (uniforms from rng; ``_wavefront_hits``).  The next vertex's live
        chains, or None when none continues."""
        hit = self._wavefront_rays(depth, live, ctx)
        return self._wavefront_hits(depth, live, hit, rng, ctx)

    def _wavefront_rays(self, depth, live, ctx, split=True):
        """Embree's hits of the live chains' rays (prim, u, v, tfar (K,),
        ``_intersect``) and ew (K,) the weight of the emission each finds at
        its hit (``_glossy_emission``), and the emission the rays see before
        them (``_seen_along``).  split=False: in the calling thread."""
        o, d, tmax, idx, beta, path_len, last, see_through, dz, *mis = live
        mats, textured, vb, fb, first, L = ctx
        hit4 = cast_by_kinds(lambda a, o_, d_, t_: _intersect(
            a, o_, d_, t_, INTERSECT_SPLIT_MIN if split else np.inf),
            self.accel, chain_kinds(see_through, last), o, d, tmax)
        prim, tfar = hit4[0], hit4[3]
        hit = prim >= 0
        t = np.where(hit, tfar, np.inf).astype(np.float64)
        Absorb.attenuate(self._absorb, prim, t, d, beta)
        ends = Holdout.camera_hits(self._holdout, prim, see_through, beta, first.escape, idx,
                                   hit4[1:3], self._held_through)
        Line.record(first.line, prim, see_through, beta, idx, hit4[1:3], d,
                    shadow_attached(self.accel, camera=True), ends)
        self._seen_along(depth, L, first, o, d, tmax, t, hit, idx, self._emitting(beta, mis[0]),
                         last, see_through, fast=True, split=split, left=mis[3])
        ew = self._glossy_emission(L, idx, o, d, t, prim, beta, last, mis)
        if ends is not None:
            prim[ends] = -1          # the rays that end on a holdout are no hits to shade
        return hit4 + (ew,)

    def _wavefront_hits(self, depth, live, hit4, rng, ctx, split=True):
        """``hit_kernel`` on the hits hit4 of :meth:`_wavefront_rays` (their
        uniforms from rng, one row of 4 a hit in ray order) and the delta
        lobes' samples of the chains that continue: the next vertex's live
        chains, or None.  split=False: in the calling thread."""
        from . import camera_kernels as CK
        from .photons import _pool, _threads
        o, d, tmax, idx, beta, path_len, last, see_through, dz, *mis = live
        mats, textured, vb, fb, first, L = ctx
        mtab, s = self.mtab, self.scene
        K = idx.size
        prim, bu, bv, tfar, ew = hit4
        hit = prim >= 0
        nh = int(np.count_nonzero(hit))
        if nh == 0:
            return None
        pre = np.full(K, -1, np.int64)
        Lb = mtab.kind.shape[1]
        colors_pre, em_pre = np.zeros((0, Lb, 3)), np.zeros((0, 3))
        mat_pre = np.zeros(0, np.int32)
        mat_h = s.tri_mat[prim[hit]]
        if textured.any() and textured[mat_h].any():
            # Textured materials: their colours and emission in numpy (rows
            # only), and a roughness map's level row.
            it = np.nonzero(hit)[0][textured[mat_h]]
            pr = prim[it]
            _, _, ns, uv = surface_point(s.tri_p, s.tri_n, s.tri_uv, pr,
                                         bu[it].astype(np.float64), bv[it].astype(np.float64))
            mt = rough_maps.pick(mtab, RV.seen(self._camera_mat, s.tri_mat[pr], see_through[it]),
                                 pr, bu[it], bv[it], uv)
            mat_pre = mt.astype(np.int32)
            colors_pre = B.lobe_colors(mtab, mt, uv, B.view_mu(mtab, d[it], ns))
            em_pre = mtab.emission[mt]
            if mtab.emission_tex is not None and np.any(mtab.emission_tex[mt] >= 0):
                em_pre = em_pre * _emission_texture(mtab, s, mt, uv)
            pre[it] = np.arange(it.size)
        ur = rng.random((nh, 4))
        wf = CK.Wavefront(prim, bu, bv, tfar, idx, np.ascontiguousarray(d, np.float64), beta,
                          path_len, dz, ur, pre, colors_pre, em_pre, ew, mat_pre)
        ch = CK.alloc_chains(K, Lb)
        lastv = depth == self.max_depth - 1
        if split and K >= CK.SPLIT_MIN and _threads() > 1:
            h = K // 2
            u1 = int(np.count_nonzero(hit[:h]))
            f1 = _pool().submit(CK.hit_kernel, h, K, u1, h, depth == 0, lastv, wf, mats,
                                vb, fb, ch)
            n0 = CK.hit_kernel(0, h, 0, 0, depth == 0, lastv, wf, mats, vb, fb, ch)
            n1 = f1.result()
            rows = np.r_[0:n0, h:h + n1]
        else:
            rows = np.arange(CK.hit_kernel(0, K, 0, 0, depth == 0, lastv, wf, mats, vb, fb, ch))
        gl = None
        if self._glossy_mat is not None and not lastv:
            r = np.nonzero(hit)[0]          # the hits, in the order of ur's rows
            qv = idx[r]
            g = np.nonzero(vb.valid[qv] & self._glossy_mat[vb.mat[qv]])[0]
            if g.size:
                rg = r[g]
                gl = self._glossy_chains(vb, L, idx[rg], ur[g, 1:4],
                                         path_len[rg] + tfar[rg].astype(np.float64), dz[rg])
        parts = []
        if rows.size:
            k = ch.k[rows]
            nxt = self._continue(ch.p[rows], ch.ng[rows], ch.ns[rows], ch.wo[rows], ch.mat[rows],
                                 ch.colors[rows], ch.beta[rows], ch.plen[rows],
                                 ch.p_delta[rows], ch.u[rows], see_through[k], d[k],
                                 tuple(a[k] for a in mis))
            if nxt is not None:
                keep, o, d2, beta, path_len2, last, see_through2, *mis2 = nxt
                kk = k[keep]
                parts.append((kk, (o, d2, np.full(keep.size, np.inf), idx[kk], beta, path_len2,
                                   last, see_through2, dz[kk], *mis2)))
        if gl is not None:
            keep, o, d2, beta, path_len2, last, see_through2, dzg, *mis2 = gl
            kk = rg[keep]
            parts.append((kk, (o, d2, np.full(keep.size, np.inf), idx[kk], beta, path_len2,
                               last, see_through2, dzg, *mis2)))
        if not parts:
            return None
        return _in_row_order(parts)


_Z1, _Z3, _LENS = np.zeros(1), np.zeros((1, 3)), np.full(1, -1, np.int64)


def _no_mis(n: int) -> tuple:
    """The (pdf, p, n) of n rays that leave no glossy point: zeros, and the
    material row of the vertex they left (light linking's receiver): -1,
    the lens; as read-only views (no memory a ray)."""
    return (np.broadcast_to(_Z1, (n,)), np.broadcast_to(_Z3, (n, 3)),
            np.broadcast_to(_Z3, (n, 3)), np.broadcast_to(_LENS, (n,)))





def _in_row_order(parts):
    """The next vertex's live chains from parts [(rows (n,), arrays), ...]:
    each part's arrays concatenated and put in the order of the rows they
    come from, so that the delta and the glossy continuations of a
    wavefront are one list in ray order (the uniforms of the next vertex
    are drawn in that order, however the wavefront was split)."""
    if len(parts) == 1:
        return parts[0][1]
    rows = np.concatenate([r for r, _ in parts])
    order = np.argsort(rows, kind="stable")
    return tuple(np.concatenate(a)[order] for a in zip(*(arrs for _, arrs in parts)))


def in_two_threads(work) -> None:
    """work() in this thread and, at the same time, in core.sppm.photons'
    pool (one call with one thread, ``FPPM_PHOTON_THREADS``), for work that
    takes its shares of one job until none is left: the pool's call is
    dropped when it has not started by the time this thread's returns (the
    pool's workers busy with photons traced ahead).  Returns once both calls
    have, raising the first exception (this thread's first)."""
    from .photons import _pool, _threads
    if _threads() < 2:
        work()
        return
    f = _pool().submit(work)
    try:
        work()
    finally:
        if not f.cancel():
            f.exception()       # waits for it: no block is written after a raise
    if not f.cancelled():
        f.result()


class SharedBlocks:
    """block(a) for the block starts a = 0, blk, 2 blk, ... < n, each taken
    exactly once by whichever thread calls :meth:`take` next: any number of
    threads, at any time, until none is left."""

    def __init__(self, n: int, blk: int, block):
        self._todo, self._lock, self._block = iter(range(0, n, blk)), threading.Lock(), block
        self._stopped = False

    def take(self) -> None:
        """Run the blocks not yet taken, one at a time, until none is left
        (or :meth:`stop`); the blocks another thread runs meanwhile are not
        waited for."""
        while True:
            with self._lock:
                a = None if self._stopped else next(self._todo, None)
            if a is None:
                return
            self._block(a)

    def stop(self) -> None:
        """No block starts after this (those running finish)."""
        with self._lock:
            self._stopped = True


class InTurn:
    """Several :class:`SharedBlocks` (a pass's light samples) taken one after
    the other by whichever threads call :meth:`take`."""

    def __init__(self, jobs):
        self.jobs = jobs

    def take(self) -> None:
        for j in self.jobs:
            j.take()

    def stop(self) -> None:
        for j in self.jobs:
            j.stop()


def blocks_in_two_threads(n: int, blk: int, block) -> None:
    """block(a) for the block starts a = 0, blk, 2 blk, ... < n, taken in
    turn by two threads (:func:`in_two_threads`) until none is left; each
    start is taken exactly once, in no fixed thread."""
    in_two_threads(SharedBlocks(n, blk, block).take)


def stream_at(rng: np.random.Generator, n: int = 0) -> np.random.Generator:
    """A generator n draws ahead of rng's position in rng's stream (rng is
    not moved): its ``random()`` gives the float64 draws n, n + 1, ... of rng
    (PCG64: one uint64 a draw, ``advance``), so that two threads can draw
    two parts of one stream."""
    bg = type(rng.bit_generator)()
    bg.state = rng.bit_generator.state
    if n:
        bg.advance(n)
    return np.random.Generator(bg)


def _intersect(accel, o, d, tmax, split_min=INTERSECT_SPLIT_MIN):
    """Embree's closest hits of rays o + t d, t < tmax (K,): (prim (K,) int32,
    u, v, tfar (K,) float32), as ``Accel.intersect`` casts them (float32 in).

    In blocks of INTERSECT_BLOCK rays, converted to float32 block by block:
    at 1080p the whole wavefront's float32 copies and Embree's own outputs
    were ~110 MB of fresh arrays per call, page-faulted in every pass.  From
    split_min rays the blocks are shared by two threads
    (EmbreeScene.run releases the GIL; np.inf: never).  Each ray's hit does
    not depend on the blocks."""
    K = o.shape[0]
    accel.count_rays(K)
    if accel._scene is None or K == 0:
        return (np.full(K, -1, np.int32), np.zeros(K, np.float32), np.zeros(K, np.float32),
                np.full(K, np.inf, np.float32))
    f32, run = accel._f32, accel._scene.run
    prim = np.empty(K, np.int32)
    bu, bv, tfar = np.empty(K, np.float32), np.empty(K, np.float32), np.empty(K, np.float32)

    def blocks(a0, a1):
        for a in range(a0, a1, INTERSECT_BLOCK):
            b = min(a + INTERSECT_BLOCK, a1)
            r = run(f32(o[a:b]), f32(d[a:b]), dists=f32(np.minimum(tmax[a:b], 3e37)), output=1)
            prim[a:b], bu[a:b], bv[a:b], tfar[a:b] = (accel.global_prim(r["primID"]), r["u"],
                                                      r["v"], r["tfar"])
    from .photons import in_two_halves
    in_two_halves(blocks, K, split_min)
    return prim, bu, bv, tfar


def _emission_texture(mtab, scene, mat, uv):
    """(K, 3) emission texture factor of materials mat (K,) at uv (K, 2); 1 without texture."""
    from ..scene.textures import sample_texture
    out = np.ones((mat.size, 3))
    for t in np.unique(mtab.emission_tex[mat]):
        if t < 0:
            continue
        sel = mtab.emission_tex[mat] == t
        out[sel] = sample_texture(scene.textures[t], uv[sel])
    return out
