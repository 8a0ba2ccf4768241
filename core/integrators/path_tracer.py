"""Camera paths: unidirectional path tracing with next-event estimation and MIS.

    pt = PathTracer(scene, accel, mtab, light_table, camera, fsamp, px, py, settings, nee)
    L = pt(rng, check_stop)          # (P, 3) float64, mean of camera_samples paths per pixel

The first strategy of a combined integrator (vertex connection and merging,
Georgiev et al. 2012; docs/integrators.md).  Like Cycles' path tracer:

- every camera path continues by BSDF sampling (core.materials.sample_bsdf,
  all lobes, delta ones included);
- at every vertex with a non-delta lobe one light sample
  (core.lights.sample_direct) is weighted by the BSDF and tested with the
  shadow ray of core.lights.nee;
- emission found by a BSDF-sampled ray (area lights, point/spot discs and
  spheres, sun discs, emissive triangles, the world) and the light sample of
  the vertex it left are combined by the power heuristic (Veach 1997, eq.
  9.13): w_light = p_light^2 / (p_light^2 + p_bsdf^2) with p_light from
  core.lights.pdf_direct and p_bsdf from core.materials.pdf_bsdf; emission
  seen from the camera or after a delta scattering has weight 1 (the other
  strategy cannot produce it);
- transparent shadows (core.lights.shadow attached): as in Cycles a
  transparent crossing (a Transparent lobe's sample) is no scattering
  vertex for MIS: the ray keeps the BSDF pdf, position and normal of the
  vertex before it, the emitter's distance is measured from there, and the
  light sample's shadow ray passes transparent surfaces for every light;
  COMBINED's camera-side state and merging's partition go on unchanged
  too (core.integrators.combined.CameraMIS: ``first``, the rays still on
  the camera ray's line);
- ``max_bounces`` counts bounces as Cycles' Total: light samples at vertices
  0..max_bounces (vertex 0 = the camera ray's hit, so max_bounces = 0 is
  direct light only), and the emission found by the last vertex's BSDF ray;
- Russian roulette from vertex ``rr_start`` on, survival probability
  min(1, sqrt(largest throughput component)) as Cycles'
  ``path_state_continuation_probability``, weight divided by it;
- the filter, the lens and the light and BSDF samples of the first
  ``SEQUENCE_DEPTHS`` vertices of a pixel's paths are points of one
  low-discrepancy sequence per pixel that runs across the passes
  (``sequence_kernels.sobol_pairs``: shuffled, scrambled 2-D Sobol').

All paths of a pass are traced together as a structure of arrays, masked and
compacted per vertex (Mitsuba 3 style wavefront); throughput is float64.
With ``compiled`` (default) and a scene the kernels cover (Lambert, mirror,
glass and GENERIC materials such as Blender's default Principled BSDF, with
colour textures, an environment map, a Normal Map / Bump on GENERIC
materials: ``path_kernels.compiled_scene_ok``), the light sample and its MIS
weight, the light-sampling densities and the continuation (BSDF sample,
throughput, roulette, spawn, compaction) are the numba kernels of
:mod:`.path_kernels`; elsewhere (Transparent lobes, alpha textures, textured
emission) the numpy vertices' radiance-mode sample_bsdf, eval_bsdf and
pdf_bsdf run compiled on GENERIC materials (the PathTracer methods of those
names, core.materials.compiled "Radiance mode over arrays");
``compiled = False`` is the numpy reference.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..accel import chain_kinds, hit_uv, intersect_by_kinds, surface_point
from ..scene import absorption as Absorb, holdout as Holdout, ray_variants as RV
from ..scene import linking
from ..scene.linking import lit
from ..lights.lobe_visibility import masked_colors
from .. import lights as Lt
from .. import materials as B
from ..materials import compiled as C, rough_maps
from ..materials.fast import GENERIC, build_fast_materials
from ..lights import seen as Seen, shadow as Sh
from ..lights.environment_kernels import rays_radiance
from ..lights import pdf_kernels as PdfK
from ..lights.seen_kernels import seen_kernel
from ..lights.table import MESH
from ..mathutil import dot as _dot, power_heuristic
from . import path_kernels as PK
from .merge import CameraMerge, CameraPartition
from .sequence_kernels import sobol_pairs

#: Paths traced together at most: ~1 kB each in flight (64 MiB), and past the
#: ~30k paths per batch where the per-vertex numpy overhead is amortised
#: (docs/integrators.md, "Camera samples per pass").
PATH_CHUNK = 1 << 16
#: A pass of at least this many paths is traced as at least two blocks, so
#: that two threads share it (docs/integrators.md "Camera paths on two
#: cores, round 25").  The blocks depend on the image and the samples a
#: pixel alone, not on the threads: the same image on any machine.
PATH_SPLIT_MIN = 1 << 14
#: The vertices (depth 0, 1, ...) whose light sample and BSDF sample are
#: dimensions of the pixel's sequence (``sequence_kernels.sobol_pairs``, as
#: Cycles draws every dimension of a path from its pixel's sequence); the
#: deeper vertices draw from the path's random stream (docs/integrators.md
#: "A path's first vertex from the pixel's sequence, round 28").
SEQUENCE_DEPTHS = 1


def sequence_dims(depth: int) -> tuple:
    """(light, bsdf): the columns of a path's sequence numbers (``_trace``'s
    u) that vertex ``depth`` < SEQUENCE_DEPTHS samples with: its light
    sample (emitter choice, then the point on it: the position is one 2-D
    pair) and its BSDF sample (direction: one pair; lobe choice, roulette:
    the next).  Columns 0:2 are the filter's, 2:4 the lens'."""
    b = 4 + 8 * depth
    return [b + 2, b, b + 1], slice(b + 4, b + 8)


#: The per-path arrays of merging's partition (core.integrators.merge.CameraPartition).
_PART = ("chain", "seen", "pend", "owned")


def _put_rows(v, x, w) -> None:
    """v's rows x = the PathVertices w (the fields both hold)."""
    for k, a in v.__dict__.items():
        b = getattr(w, k)
        if a is not None and b is not None:
            a[x] = b


@dataclass
class PathVertices:
    """The scattering vertices of the live camera paths, K rows (structure of arrays).

    path (K,) int64 row into the pass' path list (pixel = path % P);
    p, ng, ns, wo (K, 3) float64, ng and ns as the mesh has them (the
    materials orient them themselves, and tell entering from leaving glass by
    wo's side of ng); mat (K,) int; colors (K, L, 3); beta (K, 3) float64
    throughput from the camera, divided by the sampling densities so far.

    Room for VCM (Georgiev et al. 2012, technical report section 4): the
    recursive MIS quantities dVCM, dVC, dVM (K,) float64 per vertex are
    updated from the pdfs this class's users already compute (the forward
    BSDF pdf of the sample that reached the vertex, the reverse pdf from
    pdf_bsdf with wo and wi swapped, the cosine at the vertex); they are
    fields to add here, next to beta, and carried through ``take``.
    """
    path: np.ndarray
    p: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    wo: np.ndarray
    mat: np.ndarray
    colors: np.ndarray
    beta: np.ndarray
    # Integrator 'COMBINED' (core.integrators.mis): Q (K,) the light-tracing
    # ratio carried to the vertex, c (K,) its area density from the camera.
    Q: np.ndarray | None = None
    c: np.ndarray | None = None
    # Photon merging's partition (core.integrators.merge): (K,) 0 where
    # merging owns the path, else 1; None without merging.
    m: np.ndarray | None = None
    # 'COMBINED' with transparent crossings: (K,) bool, the vertex is y_1
    # (only transparent crossings since the lens).
    first: np.ndarray | None = None
    # Merging as an MIS strategy (core.integrators.merge.CameraMerge): (K,)
    # merging's ratio QM at the vertex (0 up to y_v); None without it.
    QM: np.ndarray | None = None
    # The kernels' vertices: (K,) int64 the colour row of each (its
    # material's, or a textured hit's own: path_kernels.PathMaterials);
    # None: the material's (the numpy vertices).
    row: np.ndarray | None = None

    def take(self, i: np.ndarray) -> "PathVertices":
        """The rows i (compaction)."""
        return PathVertices(**{k: (None if v is None else v[i]) for k, v in self.__dict__.items()})

    def ns_wo(self) -> np.ndarray:
        """(K, 3) shading normal flipped with ng to wo's side (Cycles' back-face
        flip): the receiver normal of light sampling (core.lights.nee's convention)."""
        return self.ns * np.where(_dot(self.ng, self.wo) >= 0, 1.0, -1.0)[:, None]


class PathTracer:
    """Camera paths over the pixels (px, py) (P,) float64 of the region, py from
    the bottom; settings: RenderSettings (max_bounces, rr_start,
    camera_samples); nee: core.lights.nee.NextEventEstimation (its shadow test);
    compiled: use :mod:`.path_kernels` where they cover the scene; transparent:
    Film > Transparent (a camera ray that escapes directly or straight through
    Transparent BSDFs adds no world, as in Cycles and core.sppm.visible_points;
    the film's alpha is its coverage)."""

    def __init__(self, scene, accel, mtab, light_table, camera, fsamp, px, py, settings, nee,
                 compiled: bool = True, transparent: bool = False):
        self.scene, self.accel, self.mtab, self.lights = scene, accel, mtab, light_table
        self.transparent = bool(transparent)
        # (T,) holdout weights or None: camera rays end on holdout objects
        # (core.scene.holdout; the film's alpha is the camera pass's).
        self._holdout = Holdout.triangle_weights(scene)
        self._held_through = Holdout.transparency(accel)    # (PER_HIT weights)
        self._absorb = Absorb.of_scene(scene)        # absorbing volumes, or None
        # (M,) the materials camera rays see in place of others (a Light
        # Path node, core.scene.ray_variants), or None: the hits of rays
        # still on the camera ray's line are shaded with them.
        self._camera_mat = RV.rows(scene, "camera")
        self.camera, self.fsamp, self.px, self.py = camera, fsamp, px, py
        self.max_bounces = int(settings.max_bounces)
        self.rr_start = int(settings.rr_start)
        self.samples = int(settings.camera_samples)
        self.seed = int(settings.seed)
        self.nee = nee
        # Integrator 'COMBINED': core.integrators.combined.CameraMIS (the
        # light-tracing and merging terms of the weights); None = PATH.
        self.vc = None
        # Emitter row of every emissive triangle (-1: none) and of the world:
        # what a BSDF-sampled ray hit, for the light-sampling pdf.
        self.tri_light, self.world_row = Lt.emitter_rows(light_table, scene.tri_p.shape[0])
        self.world = Lt.world_radiance(light_table)
        env = light_table.environment
        self.env = env if env is not None and env.total > 0 else None
        # Emitters a BSDF-sampled ray can hit (not delta): MIS applies to
        # them; a shadow-linked one's or one hidden from some kind of ray's
        # light at a non-delta vertex is its light samples' alone.
        self.hittable = Lt.mis_hittable(light_table)
        self.nee_only = Lt.samples_only(light_table)
        self._world_seen = Lt.world_seen_by(light_table)
        self.compiled = compiled
        # (DirectLights, LightPdf, PathMaterials, TriangleData) or False
        self._kernels = None
        # Materials with a colour texture: their hits' lobe colours are
        # looked up per hit (the kernels' colour rows, _hit_colors).
        self._textured = PK.textured_materials(mtab)
        self._color_inputs = None       # materials.hit_colors.ColorInputs, built in _prepare
        # The radiance-mode BSDF calls of the numpy vertices run compiled on
        # GENERIC materials (core.materials.compiled "Radiance mode over
        # arrays"), numpy where ``compiled`` is off (the reference): the
        # materials' classes, built on first use.
        self._radiance = None
        self._fmat = None
        self._flags = None          # seen.visibility_flags, built on first use
        # Normal Map / Bump: the spec attached to the mesh normals and the
        # materials it perturbs (the kernels' hits, _perturb).
        from ..scene import normals
        from ..scene.textures import UnassociatedImage, _as_image, sampler_of
        self._spec = spec = normals.attached(scene.tri_n)
        self._bumped = (None if spec is None
                        else normals.perturbed_materials(spec, mtab.kind.shape[0]))
        # Per tangent-space Normal Map material, normal_kernels.normal_map's
        # arguments after the hits (image, unassociated, strength, DirectX);
        # the other perturbed materials (Bump, a Normal Map read Closest or
        # with another extension than Repeat) take normals.perturb.
        self._normal_maps = {}
        if spec is not None:
            self._tri_args = (spec.tri_p, spec.tri_n, spec.tri_uv,
                              spec.tri_tangent if spec.tri_tangent is not None
                              else np.zeros((0, 3, 4), np.float32))
            for m, inp in enumerate(spec.inputs):
                if (inp is not None and inp.kind == normals.NORMAL_MAP
                        and 0 <= inp.texture < len(spec.textures)
                        and sampler_of(spec.textures[inp.texture]) == 0):
                    img = spec.textures[inp.texture]
                    self._normal_maps[m] = (np.ascontiguousarray(_as_image(img)),
                                            isinstance(img, UnassociatedImage),
                                            float(inp.strength), bool(inp.directx))
            self._bump_numpy = self._bumped.copy()
            self._bump_numpy[list(self._normal_maps)] = False

    def fast_materials(self):
        """The materials' ``materials.fast.FastMaterials`` (the kernels' and the
        compiled calls' classes and tables), built once on first use."""
        if self._fmat is None:
            self._fmat = build_fast_materials(self.mtab)
        return self._fmat

    def _radiance_rows(self):
        """(FastMaterials, the rows sample_radiance covers, GENERIC (M,) bool)."""
        if self._radiance is None:
            fm = self.fast_materials()
            self._radiance = (fm, C.radiance_rows(self.mtab, fm), fm.cls == GENERIC)
        return self._radiance

    def sample_bsdf(self, mat, colors, ns, ng, wo, u):
        """materials.sample_bsdf(subset 'all', radiance mode) of the numpy vertices."""
        if not self.compiled:
            return B.sample_bsdf(self.mtab, mat, colors, ns, ng, wo, u, subset="all",
                                 mode="radiance")
        fm, rows, _ = self._radiance_rows()
        return C.sample_radiance(self.mtab, fm, rows, mat, colors, ns, ng, wo, u)

    def eval_bsdf(self, mat, colors, ns, ng, wo, wi):
        """materials.eval_bsdf (radiance mode) of the numpy vertices."""
        if not self.compiled:
            return B.eval_bsdf(self.mtab, mat, colors, ns, ng, wo, wi)
        return C.eval_radiance(self.mtab, self._radiance_rows()[2], mat, colors, ns, ng, wo, wi)

    def pdf_bsdf(self, mat, colors, ns, ng, wo, wi):
        """materials.pdf_bsdf (subset 'all') of the numpy vertices."""
        if not self.compiled:
            return B.pdf_bsdf(self.mtab, mat, colors, ns, ng, wo, wi, subset="all")
        return C.pdf_radiance(self.mtab, mat, colors, ns, ng, wo, wi)

    def kernels(self):
        """The kernels' view of the scene, None where they do not cover it
        (``path_kernels.compiled_scene_ok``) or ``compiled`` is off."""
        if not self.compiled:
            return None
        if self._kernels is None:
            from ..lights import direct_kernels as DK
            from ..sppm.photon_kernels import build_triangle_data
            fmat = self.fast_materials()
            if PK.compiled_scene_ok(self.mtab, fmat, self.lights, self.scene.tri_n):
                L = DK.build_direct_lights(self.lights)
                self._kernels = (L, PdfK.build_light_pdf(self.lights, self.hittable, L),
                                 PK.build_path_materials(self.mtab, fmat),
                                 build_triangle_data(self.scene))
            else:
                self._kernels = False
        return self._kernels or None

    @property
    def camera_stop(self):
        """COMBINED's ``combined.CameraStop`` (where its camera paths stop),
        or None: full length (also integrator PATH, which has no vc)."""
        return None if self.vc is None else self.vc.stop

    def blocks(self) -> int:
        """The number of pixel blocks of a pass: ``PATH_CHUNK`` paths at most
        each, and at least two from ``PATH_SPLIT_MIN`` paths on."""
        paths = self.px.shape[0] * self.samples
        nb = -(-paths // PATH_CHUNK)
        return max(nb, 2) if paths >= PATH_SPLIT_MIN else max(nb, 1)

    def __call__(self, rng: np.random.Generator, check_stop=lambda: None,
                 pass_index: int = 1) -> np.ndarray:
        """(P, 3) float64: the mean over ``camera_samples`` paths per pixel of
        the radiance each carries (filter-importance-sampled, so a plain mean).

        The pixels are cut into :meth:`blocks` equal runs, block i traced
        with the i-th child stream of rng (``Generator.spawn``; one block:
        rng itself), so a block's
        paths do not depend on which thread takes it or when: two threads
        take the blocks (``visible_points.in_two_threads``; one with
        ``FPPM_PHOTON_THREADS=1``) and give the same image either way.
        pass_index (1, 2, ...): the pass these paths belong to, so that a
        pixel's samples continue its sequence (``sequence_kernels``: the
        paths' first dimensions are samples (pass_index - 1) x
        camera_samples onwards)."""
        P, n = self.px.shape[0], self.samples
        L = np.zeros((P, 3))
        stop = self.camera_stop
        if stop is not None and stop.camera_free:
            return L        # COMBINED: light tracing takes every path (combined.CameraStop)
        from ..sppm.photons import _children
        from ..sppm.visible_points import SharedBlocks, in_two_threads
        nb = self.blocks()
        block = -(-P // nb)
        rngs = _children(rng, nb) if nb > 1 else [rng]
        self._prepare()

        def trace_block(a: int) -> None:
            pix_b = np.arange(a, min(a + block, P))
            r = rngs[a // block]
            # Paths sample-major: row s * B + b is sample s of pixel pix_b[b].
            pix = np.tile(pix_b, n)
            D = 4 + 8 * SEQUENCE_DEPTHS
            u = np.empty((n, pix_b.size, D))
            sobol_pairs(self.seed, pix_b, (pass_index - 1) * n, n, D // 2, u)
            u = u.reshape(n * pix_b.size, D)
            Lp = self._trace(pix, u, r, check_stop)
            for c in range(3):
                L[a:a + pix_b.size, c] = np.bincount(pix - a, Lp[:, c], minlength=pix_b.size)

        work = SharedBlocks(P, block, trace_block)
        if nb > 1:
            in_two_threads(work.take)
        else:
            work.take()
        return L / n

    def _prepare(self) -> None:
        """Build what the blocks read before two threads share them: the
        kernels' tables, the compiled calls' materials, COMBINED's emitter
        arrays, the emitters' visibility flags (each otherwise built on first
        use)."""
        kern = self.kernels()
        if self.compiled:
            self._radiance_rows()
        if kern and self._textured.any() and self._color_inputs is None:
            from ..materials.fast import LAMBERT
            from ..materials.hit_colors import build_color_inputs
            self._color_inputs = build_color_inputs(self.mtab, self.scene.tri_uv,
                                                    lambert=kern[2].cls == LAMBERT)
        if kern and self._flags is None:
            self._flags = Seen.visibility_flags(self.lights)
        if kern and self.vc is not None:
            _ = self.vc.mis_lights      # built here, read by both threads

    # ------------------------------------------------------------------ paths
    def _trace(self, pix, u, rng, check_stop) -> np.ndarray:
        """(K, 3) radiance of one camera path per entry of pix (K,) (pixel rows);
        u (K, 4 + 8 SEQUENCE_DEPTHS) the sequence's numbers of the path's
        first dimensions: filter (0:2), lens (2:4), then the light and BSDF
        samples of the first vertices (:func:`sequence_dims`)."""
        mtab, accel, s, lt = self.mtab, self.accel, self.scene, self.lights
        K = pix.size
        kern = self.kernels()
        rays, dz = self.camera.generate(self.px[pix], self.py[pix], u[:, :2], u[:, 2:4],
                                        self.fsamp)
        out = np.zeros((K, 3))
        path = np.arange(K)
        o, d, tmax = rays.o, rays.d, rays.t_max
        beta = np.ones((K, 3))
        # The vertex the ray left: its BSDF pdf (0 = camera or delta sample:
        # no MIS), position and oriented shading normal (light pdf there).
        pdf_prev = np.zeros(K)
        p_prev = np.zeros((K, 3))
        n_prev = np.zeros((K, 3))
        vis = np.zeros(K, np.int8)
        # The material row of the vertex each ray left (-1: the lens), light
        # linking's receiver of the emission the ray finds (kept through
        # transparent crossings, as Cycles keeps mis_ray_object).
        m_prev = np.full(K, -1, np.int64)
        track = linking.active(lt, mtab)     # (else no light is unlinked: not kept)
        # Distance from the ray's origin back to p_prev along d: > 0 after
        # transparent crossings (below), which are no MIS vertex.  A camera
        # ray starts at the near clip plane (CameraModel.generate: depth
        # clip_start, t0 = clip_start / -dz from the lens): COMBINED's camera
        # density c_1 of the first hit takes the distance from the lens, as
        # light tracing's splat does (CameraModel.project); with the clipped
        # distance the camera side overestimated c_1 and the weights summed
        # to more than one (+2.5% at 40x32 px, clip_start 0.1 m, 4 m away).
        t_acc = self.camera.cam.clip_start / np.maximum(-dz, 1e-12)
        vc = self.vc
        # Transparent crossings skipped by MIS (Cycles: a transparent bounce
        # leaves mis_ray_pdf and mis_origin alone), as the shadow rays of
        # next-event estimation pass those surfaces for every light
        # (core.lights.shadow attached).  COMBINED's camera-side state (Q, pf,
        # the vertex left, merging's partition) goes on unchanged as well, and
        # ``first`` tells the rays still on the camera ray's line.
        clear = Sh.transparent_materials(mtab) if Sh.attached(accel) is not None else None
        first = np.ones(K, bool)
        if vc is not None:
            Qs, pf, vprev = vc.camera_state(d), np.ones(K), None
        part = CameraPartition(K) if getattr(vc, "merging", False) else None
        mg = CameraMerge(K) if getattr(vc, "mis_merge", None) is not None else None
        if mg is not None:
            part = None
        for depth in range(self.max_bounces + 2):
            if path.size == 0:
                break
            check_stop()
            # ``first``: camera rays, which pass the objects hidden from the
            # camera; after a mirror or glass, glossy or transmission rays
            # (those after a rough bounce see every object: their lobe's
            # kind is not known here).
            kinds = chain_kinds(first, vis)
            kinds[~first & (pdf_prev > 0)] = 0
            h = intersect_by_kinds(accel, kinds, o, d, tmax)
            Absorb.attenuate(self._absorb, h.prim, h.t, d, beta)
            ends = Holdout.camera_hits(self._holdout, h.prim, first, beta, None, path,
                                       (h.u, h.v), self._held_through)
            t_end = np.minimum(np.where(h.hit, h.t, np.inf), tmax)
            # Analytic emitters before the hit, per ray type's visibility flag.
            for sel, Le, row, t in self._seen(kern, vis, o, d, t_end):
                # Only the rays that found an emitter add light (the others
                # added 0: the same sums), and their weights are per ray.
                f = np.nonzero(row >= 0)[0]
                if f.size == 0:
                    continue
                sel, Le, row, t = sel[f], Le[f], row[f], t[f] + t_acc[sel[f]]
                w = self._mis_bsdf(pdf_prev, p_prev, n_prev, d, row, t, rows=sel)
                ok = lit(lt, mtab, row, m_prev[sel])
                if ok is not None:
                    w = w * ok
                if vc is not None:
                    w = vc.emission(w, sel, row, d, t, None, first, Qs, pf, pdf_prev, vprev,
                                    None if mg is None else np.where(mg.em, mg.Qs, 0.0))
                if part is not None:
                    w = w * part.weight(sel)
                PK.add_emission(out, path, sel, beta, Le, w)
            miss = np.nonzero(~h.hit)[0]
            if self.transparent:
                # ``first``: only transparent crossings since the lens.
                miss = miss[~first[miss]]
            cam_env = lt.camera_environment
            if cam_env is not None and miss.size:
                # Rays still on the camera ray's line see the camera's map
                # (Scene.world_camera_map); no light sample competes there.
                on_line = miss[first[miss]]
                if on_line.size:
                    Le = np.empty((on_line.size, 3))
                    rays_radiance(cam_env.kernel_data(), np.ascontiguousarray(d, np.float64),
                                  on_line, Le)
                    w = np.ones(on_line.size) if part is None else part.weight(on_line)
                    PK.add_emission(out, path, on_line, beta, Le, w)
                miss = miss[~first[miss]]
            if miss.size and np.any(self.world > 0):
                row = np.full(miss.size, self.world_row, np.int64)
                w = self._mis_bsdf(pdf_prev, p_prev, n_prev, d, row,
                                   np.full(miss.size, np.inf), rows=miss)
                # After a mirror or glass: the world's Glossy and Transmission
                # visibility (Scene.world_hidden; the rough vertices' weight
                # is the light samples' alone there, _mis_bsdf).
                w = w * self._world_seen[vis[miss]]
                if part is not None:
                    w = w * part.weight(miss)
                # An environment map: its radiance along each escaped ray
                # (self.world is only its mean), compiled in the kernels' scope.
                if self.env is None:
                    Le = self.world[None, :]
                elif kern:
                    Le = np.empty((miss.size, 3))
                    rays_radiance(kern[0].env, np.ascontiguousarray(d, np.float64), miss, Le)
                else:
                    Le = np.ascontiguousarray(Lt.world_radiance(lt, d[miss]), np.float64)
                PK.add_emission(out, path, miss, beta, Le, w)
            ih = np.nonzero(h.hit if ends is None else h.hit & ~ends)[0]
            if ih.size == 0:
                break
            prim = h.prim[ih]
            mat = RV.seen(self._camera_mat, s.tri_mat[prim], first[ih])
            if mtab.rough_first is not None:     # a roughness map's level row per hit
                mat = rough_maps.pick(mtab, mat, prim, h.u[ih], h.v[ih],
                                      hit_uv(s.tri_uv, prim, h.u[ih], h.v[ih]))
            if kern:
                p, ng, ns = (np.empty((ih.size, 3)) for _ in range(3))
                PK.hit_kernel(kern[3], prim, h.u[ih], h.v[ih], p, ng, ns)
                if self._spec is not None:
                    self._perturb(prim, h.u[ih], h.v[ih], ns)
                # The hits' colour rows; uv only where the emission reads it
                # (no emission texture in the kernels' scope: never).
                Mk, row = self._hit_colors(kern[2], prim, h.u[ih], h.v[ih], mat, d, ih, ns)
                uv = np.zeros((ih.size, 2))
            else:
                p, ng, ns, uv = surface_point(s.tri_p, s.tri_n, s.tri_uv, prim, h.u[ih],
                                              h.v[ih])
                row = None
            em = np.nonzero(mtab.emission[mat].max(axis=1) > 0)[0]
            if em.size:
                Le = B.emission_radiance(mtab, mat[em], uv[em])
                e = ih[em]
                w = self._mis_bsdf(pdf_prev, p_prev, n_prev, d, self.tri_light[prim[em]],
                                   h.t[e] + t_acc[e], rows=e)
                ok = lit(lt, mtab, self.tri_light[prim[em]], m_prev[e])
                if ok is not None:
                    w = w * ok
                if vc is not None:
                    w = vc.emission(w, e, self.tri_light[prim[em]], d, h.t[e] + t_acc[e],
                                    ng[em], first, Qs, pf, pdf_prev, vprev,
                                    None if mg is None else np.where(mg.em, mg.Qs, 0.0))
                if part is not None:
                    w = w * part.weight(e)
                PK.add_emission(out, path, e, beta, np.ascontiguousarray(Le, np.float64), w)
            stop = self.camera_stop
            if stop is not None and depth <= stop.depth:
                # COMBINED: light tracing alone takes the longer paths
                # (combined.CameraStop; no transparent crossings then, so
                # step ``depth`` hits y_{depth+1}).
                keep = np.nonzero(~stop.ends(depth, mat, None if depth == 0
                                             else vprev.mat[ih]))[0]
                if keep.size < ih.size:
                    ih, prim, p, ng, ns, uv, mat = (a[keep] for a in (ih, prim, p, ng, ns, uv,
                                                                     mat))
                    row = None if row is None else row[keep]
                    if ih.size == 0:
                        break
            if depth > self.max_bounces:
                break       # the last BSDF ray only collects emission
            # The kernels' colours are their rows' (read by the numpy
            # CameraMIS terms only).
            colors = (B.lobe_colors(mtab, mat, uv, B.view_mu(mtab, d[ih], ns)) if not kern
                      else Mk.sel_colors[row] if vc is not None else None)
            v = PathVertices(path=path[ih], p=p, ng=ng, ns=ns, wo=-d[ih], mat=mat,
                             colors=colors, beta=beta[ih], row=row)
            if vc is not None:
                v.Q, v.c = vc.at_hit(Qs[ih], pf, ih, d[ih], ng, h.t[ih] + t_acc[ih], first[ih])
            v.first = first[ih]
            if part is not None:
                part.keep(ih)
                v.m = part.weight()
            if mg is not None:
                mg.keep(ih)
                f1 = np.nonzero(first[ih])[0]
                if f1.size:
                    # y_1: merging's scale N_M pi r^2 / K of the pixel containing it.
                    mg.scale[f1] = vc.merge_scale(p[f1], u[v.path[f1], 2:4])
                v.QM = mg.at_vertex(h.t[ih] + t_acc[ih])
            nd = np.nonzero(mtab.has_nondelta[mat])[0]
            if nd.size:
                ud = (u[v.path[nd][:, None], sequence_dims(depth)[0]]
                      if depth < SEQUENCE_DEPTHS else rng.random((nd.size, 3)))
                vn = v if nd.size == ih.size else v.take(nd)
                if kern:
                    self._direct_compiled(vn, ud, out, depth, Mk)
                else:
                    self._direct(vn, ud, out, depth)
            # Continue by sampling the BSDF (all lobes).
            ur = (u[v.path, sequence_dims(depth)[1]] if depth < SEQUENCE_DEPTHS
                  else rng.random((ih.size, 4)))
            if kern:
                nx = self._continue_compiled(v, ur, depth >= self.rr_start, Mk)
                c = nx.src
                if part is not None:
                    # part.sampled is per row: on the survivors only, as numpy's keep(c) after.
                    part.keep(c)
                    part.sampled(nx.delta)
                if mg is not None:
                    mg.keep(c)
                    mg.sampled(vc.continued_compiled(Mk, v, nx, depth, Q=v.QM)[0],
                               np.abs(_dot(v.ng[c], nx.d)), nx.delta)
                if vc is not None:
                    Qs, pf = vc.continued_compiled(Mk, v, nx, depth)
                    vprev = v.take(c)
                o, d, beta = nx.o, nx.d, nx.beta
                tmax = np.full(c.size, np.inf)
                pdf_prev = np.where(nx.delta, 0.0, nx.pdf)
                p_prev, n_prev, vis = v.p[c], nx.n_prev, nx.vis
                if track:
                    m_prev = np.asarray(v.mat, np.int64)[c]
                t_acc = np.zeros(c.size)    # no transparent material in the kernels' scope
                first = np.zeros(c.size, bool)
                path = v.path[c]
                continue
            wi, wgt, pdf, is_delta, valid = self.sample_bsdf(v.mat, v.colors, v.ns, v.ng, v.wo,
                                                            ur[:, :3])
            bt = v.beta * wgt
            ok = valid & np.all(np.isfinite(bt), axis=1) & (bt.max(axis=1) > 0)
            if depth >= self.rr_start:
                q = np.minimum(np.sqrt(bt.max(axis=1)), 1.0)
                ok &= ur[:, 3] < q
                bt = bt / np.maximum(q, 1e-300)[:, None]
            c = np.nonzero(ok)[0]
            # A Transparent lobe's sample (wi = -wo exactly): the ray goes on
            # from the last real vertex, with its pdf, normal, origin,
            # visibility flag and COMBINED's state (rows x of c).
            x = (np.nonzero(is_delta[c] & clear[v.mat[c]] & np.all(wi[c] == -v.wo[c], axis=1))[0]
                 if clear is not None else np.zeros(0, np.int64))
            if part is not None:
                before = {k: getattr(part, k)[c[x]] for k in _PART}   # per vertex (keep(ih))
                part.sampled(is_delta)
                part.keep(c)
                for k in _PART:
                    getattr(part, k)[x] = before[k]
            if mg is not None:
                mbefore = {k: getattr(mg, k)[c[x]] for k in ("scale", "chain", "Qs", "em")}
                QMn = vc.continued(v, c, wi[c], pdf[c], is_delta[c], v.first, Q=v.QM)[0]
                mg.keep(c)
                mg.sampled(QMn, np.abs(_dot(v.ng[c], wi[c])), is_delta[c])
                for k, a in mbefore.items():
                    getattr(mg, k)[x] = a
            if vc is not None:
                state = (Qs[ih[c[x]]], pf[ih[c[x]]], None if vprev is None else
                         vprev.take(ih[c[x]]))
                Qs, pf = vc.continued(v, c, wi[c], pdf[c], is_delta[c], v.first)
                vnew = v.take(c)
                if x.size:
                    Qs[x], pf[x] = state[0], state[1]
                    if state[2] is not None:
                        _put_rows(vnew, x, state[2])
                vprev = vnew
            first = np.zeros(c.size, bool)
            first[x] = v.first[c[x]]
            wi = wi[c]
            refl = (_dot(wi, v.ng[c]) * _dot(v.wo[c], v.ng[c])) > 0
            o_prev = o
            o = accel.spawn(v.p[c], v.ng[c], wi)
            d = wi
            tmax = np.full(c.size, np.inf)
            beta = bt[c]
            prev = (pdf_prev[ih[c]], p_prev[ih[c]], n_prev[ih[c]], vis[ih[c]],
                    t_acc[ih[c]] + _dot(o - o_prev[ih[c]], d))
            pdf_prev = np.where(is_delta[c], 0.0, pdf[c])
            p_prev, n_prev = v.p[c], v.ns_wo()[c]
            vis = np.where(refl, 1, 2).astype(np.int8)
            t_acc = np.zeros(c.size)
            if track:
                prev += (m_prev[ih[c]],)
                m_prev = np.asarray(v.mat, np.int64)[c]
            for a, b in zip((pdf_prev, p_prev, n_prev, vis, t_acc, m_prev), prev):
                a[x] = b[x]
            path = v.path[c]
        return out

    def _hit_colors(self, M, prim, bu, bv, mat, d, ih, ns):
        """(PathMaterials, row (K,) int64) of the kernels' hits (prim, bu, bv,
        materials mat (K,), shading normals ns (K, 3) of the rays d[ih]): M and
        the materials themselves where no hit is on a textured material; else
        M with a colour row appended per textured hit
        (``path_kernels.with_hit_colors``: its lobe colours at the hit's uv
        and view, their selection)."""
        row = np.asarray(mat, np.int64)
        if not self._textured.any():
            return M, row
        t = np.nonzero(self._textured[row])[0]
        if t.size == 0:
            return M, row
        mu = np.abs(_dot(d[ih[t]], ns[t])) if self.mtab.view_lut is not None else None
        Mk, rows = PK.with_hit_colors(M, self._color_inputs, prim[t], bu[t], bv[t], row[t], mu)
        row = row.copy()
        row[t] = rows
        return Mk, row

    def _perturb(self, prim, bu, bv, ns) -> None:
        """The shading normals ns (K, 3) of the kernels' hits (prim, bu, bv)
        on Normal Map / Bump materials perturbed in place as
        ``accel.surface_point`` perturbs them, on those rows only: a
        tangent-space Normal Map by ``normal_kernels.normal_map``, a Bump by
        ``normals.perturb`` with the hits' interpolated uvs."""
        from ..scene import normals
        from ..scene.normal_kernels import normal_map
        mat = self.scene.tri_mat[prim]
        r = np.nonzero(self._bumped[mat])[0]
        if r.size == 0:
            return
        for m, args in self._normal_maps.items():
            rm = r[mat[r] == m]
            if rm.size:
                normal_map(*self._tri_args, prim, bu, bv, rm, ns, *args)
        r = r[self._bump_numpy[mat[r]]]
        if r.size:
            t, u, v = prim[r], bu[r], bv[r]
            ns[r] = normals.perturb(self._spec, t, u, v, ns[r],
                                    hit_uv(self.scene.tri_uv, t, u, v))

    def _seen(self, kern, vis, o, d, t_end):
        """The analytic emitters the rays (o, d (K, 3), visibility codes vis
        (K,) int8 of the ray that left a vertex: ``seen.VISIBILITY``) hit
        before t_end (K,): (rays (k,), Le (k, 3),
        emitter row (k,) (-1 none), distance (k,)) per group of rays --
        one group by ``seen_kernels.seen_kernel`` in the kernels' scope, else one
        per visibility code (``lights.emitted_along_rays``)."""
        lt = self.lights
        if kern:
            if self._flags is None:
                self._flags = Seen.visibility_flags(lt)
            K = vis.shape[0]
            Le, row, t = np.empty((K, 3)), np.empty(K, np.int64), np.empty(K)
            idx = np.arange(K)
            seen_kernel(kern[0], self._flags, vis, o, d, t_end, idx, Le, row, t)
            return [(idx, Le, row, t)]
        out = []
        for code, name in enumerate(Seen.VISIBILITY):
            sel = np.nonzero(vis == code)[0]
            if sel.size:
                out.append((sel, *Lt.emitted_along_rays(lt, o[sel], d[sel], t_end[sel], name,
                                                        return_hit=True)))
        return out

    def _mis_bsdf(self, pdf_bsdf, p_prev, n_prev, wi, light, dist, rows=None) -> np.ndarray:
        """(K,) power-heuristic weight of emission reached by BSDF sampling:
        1 after the camera or a delta sample (pdf_bsdf = 0), else against the
        density of the light sample taken at the previous vertex.  rows (K,):
        pdf_bsdf, p_prev, n_prev, wi are every ray's and rows the K rays
        (light, dist per ray of rows), so that only the rays with a density
        are gathered; None: all four are the K rays'."""
        pb = pdf_bsdf if rows is None else pdf_bsdf[rows]
        w = np.ones(pb.shape[0])
        m = np.nonzero((pb > 0) & (light >= 0))[0]
        if m.size:
            r = m if rows is None else rows[m]
            pl = self.pdf_light(p_prev[r], wi[r], light[m], dist[m], n_prev[r])
            w[m] = power_heuristic(pb[m], pl)
            w[m[self.nee_only[light[m]]]] = 0.0      # shadow linking: light samples' alone
        return w

    def pdf_light(self, p, wi, light, dist, n) -> np.ndarray:
        """(K,) core.lights.pdf_direct(lights, p, wi, light, dist, n=n), compiled
        (lights.pdf_kernels.pdf_kernel) where the kernels cover the scene."""
        kern = self.kernels()
        if not kern:
            return Lt.pdf_direct(self.lights, p, wi, light, dist, n=n)
        K = p.shape[0]
        c = np.ascontiguousarray
        p, light = c(p, np.float64), c(light, np.int64)
        sel, out = np.empty(K), np.empty(K)
        PdfK.selection_kernel(kern[0], kern[1], p, light, sel)
        PdfK.pdf_kernel(kern[0], kern[1], p, c(wi, np.float64), light, c(dist, np.float64),
                      c(n, np.float64), sel, out)
        return out

    def _direct(self, v: PathVertices, u, out, depth: int = 0) -> None:
        """Adds to out[v.path] the light sample of each vertex (all have a
        non-delta lobe), MIS-weighted against BSDF sampling; u (K, 3) uniforms."""
        lt = self.lights
        n_l = v.ns_wo()
        smp = Lt.sample_direct(lt, v.p, u, n=n_l)
        wi, dist, wgt, light = smp["wi"], smp["dist"], smp["weight"], smp["light"]
        live = np.nonzero((wgt.max(axis=1) > 0) & np.all(np.isfinite(wgt), axis=1))[0]
        if live.size == 0:
            return
        v, wi, dist, wgt, light = v.take(live), wi[live], dist[live], wgt[live], light[live]
        shadow = smp["cast_shadow"][live]
        f = self.eval_bsdf(v.mat, v.colors, v.ns, v.ng, v.wo, wi)
        x, cols = masked_colors(self.mtab, lt.hidden, light, v.mat, v.colors)
        if x.size:      # emitters hidden from some kind of ray: those lobes left out
            f[x] = self.eval_bsdf(v.mat[x], cols, v.ns[x], v.ng[x], v.wo[x], wi[x])
        cos = np.abs(_dot(v.ns, wi))
        contrib = v.beta * f * (cos[:, None] * wgt)
        nz = np.nonzero(contrib.max(axis=1) > 0)[0]
        if nz.size == 0:
            return
        v, wi, dist, contrib, light, shadow = (v.take(nz), wi[nz], dist[nz], contrib[nz],
                                               light[nz], shadow[nz])
        w = self.mis_light(v, wi, dist, light, n_l[live][nz])
        self._add_direct(v, wi, dist, contrib, light, shadow, w, out, depth)

    def _direct_compiled(self, v: PathVertices, u, out, depth: int, M) -> None:
        """_direct with the light sample, f and the MIS weight in the kernels
        (the Lambert f in ``direct_kernel``, a GENERIC material's in
        ``nee_mis_kernel``: path_kernels' scope); M the step's PathMaterials
        (v.row its colour rows)."""
        from ..lights import direct_kernels as DK
        L, Q = self.kernels()[:2]
        K = v.path.size
        n_l = v.ns_wo()
        c = np.ascontiguousarray
        mat = c(v.mat, np.int64)
        row = c(v.row, np.int64)
        R = DK.Receivers(np.arange(K), c(v.p), n_l, c(v.beta), c(M.col[row]),
                         M.cls[mat] != GENERIC, c(u, np.float64))
        S = DK.alloc_samples(K)
        DK.direct_kernel(0, K, L, R, S)
        w, pl, sel = np.empty(K), np.empty(K), np.empty(K)
        live = np.empty(K, bool)
        PK.nee_mis_kernel(L, Q, M, mat, row, R.beta, R.p, c(v.ng), c(v.ns), n_l, c(v.wo), S, w,
                          live, pl, sel)
        if self.lights.hidden is not None:
            # Emitters hidden from some kind of ray: those lobes left out.
            x, cols = masked_colors(self.mtab, self.lights.hidden, S.light, mat, M.sel_colors[row])
            if x.size:
                f = self.eval_bsdf(mat[x], cols, v.ns[x], v.ng[x], v.wo[x], S.wi[x])
                S.contrib[x] = (R.beta[x] * f
                                * (np.abs(_dot(v.ns[x], S.wi[x]))[:, None] * S.weight[x]))
                live[x] &= S.contrib[x].max(axis=1) > 0
        r = np.nonzero(live)[0]
        if r.size == 0:
            return
        if r.size < K:
            v = v.take(r)
        wi, dist, light, w = S.wi[r], S.dist[r], S.light[r], w[r]
        if self.vc is not None:
            w = self.vc.nee_compiled(M, w, v, wi, dist, light, pl[r], sel[r], depth)
        self._add_direct(v, wi, dist, S.contrib[r], light, S.shadow[r], w, out, depth,
                         camera_mis=False)

    def _add_direct(self, v, wi, dist, contrib, light, shadow, w, out, depth,
                    camera_mis=True) -> None:
        """Adds the light samples (wi, dist, light, contrib = beta f |cos| weight,
        shadow: the light casts shadows) at vertices v with PT-vs-NEE weights
        w to out[v.path]: the COMBINED (unless camera_mis is False: applied
        already) and merging factors, the shadow test (:meth:`transmittance`)."""
        if self.vc is not None and camera_mis:
            w = self.vc.nee(w, v, wi, dist, light, depth if v.first is None else v.first)
        if v.m is not None:
            w = w * v.m
        ok = lit(self.lights, self.mtab, light, v.mat)
        if ok is not None:
            w = w * ok          # light linking: the light does not light v (core.scene.linking)
        tr = self.transmittance(v.p, v.ng, wi, dist, light, shadow)
        keep = tr.max(axis=1) > 0
        out[v.path[keep]] += contrib[keep] * tr[keep] * w[keep, None]     # one vertex per path

    def transmittance(self, p, ng, wi, dist, light, shadow) -> np.ndarray:
        """(K, 3) light let through to the samples (wi, dist) of emitter rows
        light taken at p (normal ng); shadow (K,) bool the light casts
        shadows -- the one shadow test of the camera paths (numpy and
        compiled).  Transparent shadows for every light: a BSDF ray crossing
        a transparent surface is weighed against the light sample of the
        vertex before it (``_trace``: the crossing is no MIS vertex)."""
        return self.nee.transmittance(p, ng, wi, dist, self.lights.kind[light] == MESH, shadow,
                                      light=light)

    def _continue_compiled(self, v: PathVertices, ur, roulette: bool, M) -> "PK.NextRays":
        """The continuation of the vertices v (path_kernels.continue_kernel;
        M the step's PathMaterials, v.row its colour rows): the NextRays of
        the survivors, trimmed to their number."""
        from ..accel import REL_OFFSET
        K = v.path.size
        nx = PK.alloc_next(K)
        c = np.ascontiguousarray
        n = PK.continue_kernel(M, c(v.mat, np.int64), c(v.row, np.int64), c(v.p), c(v.ng),
                               c(v.ns), c(v.wo), c(v.beta), ur, bool(roulette), REL_OFFSET,
                               self.accel.abs_floor / REL_OFFSET, nx)
        return PK.NextRays(*(a[:n] for a in nx))

    def mis_light(self, v: PathVertices, wi, dist, light, n_l=None) -> np.ndarray:
        """(K,) power-heuristic weight of the light samples (wi, dist, light) (K,)
        taken at vertices v (receiver normals n_l, default v.ns_wo()): against
        the BSDF density of wi where a BSDF ray along wi would find the emitter
        (not a delta light, visible to that ray type), else 1."""
        seen = Lt.bsdf_sees(self.lights, self.hittable, light, v.ng, v.wo, wi)
        w = np.ones(light.shape[0])
        m = np.nonzero(seen)[0]
        if m.size:
            n_l = v.ns_wo() if n_l is None else n_l
            pl = self.pdf_light(v.p[m], wi[m], light[m], dist[m], n_l[m])
            pb = self.pdf_bsdf(v.mat[m], v.colors[m], v.ns[m], v.ng[m], v.wo[m], wi[m])
            w[m] = power_heuristic(pl, pb)
        return w
