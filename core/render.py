"""The progressive render loop: the one entry point the add-on, the CLI and tests use.

    r = Renderer(scene, settings, log=print)   # may raise SceneError / SettingsError
    for line in r.plan_lines(): print(line)
    result = r.run(should_stop=lambda: False, on_pass=callback)

API CONTRACT
- ``Renderer(scene: Scene, settings: RenderSettings, log: Callable[[str], None] = print,
  should_stop=None, ...)``: ``should_stop()`` is polled during the set-up too
  (BVH, plan, occlusion grid); True raises RenderCancelled.
- ``Renderer.width, Renderer.height``: size of the rendered region (the border
  crop when ``scene.camera.border`` is set), ``Renderer.offset``: (x0, y0) of that
  region in Blender's pixel coordinates (y from the bottom).
- ``Renderer.plan_lines() -> list[str]``: the render plan and export summary.
- ``Renderer.step() -> PassResult``: runs one pass.
- ``Renderer.run(should_stop=None, on_pass=None) -> PassResult``: passes until
  ``settings.max_passes`` or ``settings.time_limit`` is reached or
  ``should_stop()`` returns True (polled inside passes; a cancelled pass is
  discarded and the last complete result is returned).  ``on_pass(result)`` is
  called after every completed pass.
- ``PassResult``: ``pass_index`` (1-based), ``photons_emitted`` (total so far),
  ``elapsed`` (s since the first pass started), ``image`` (H, W, 4) float32 RGBA
  linear radiance with row 0 at the TOP, ``aovs`` dict name -> (H, W, C) float32
  (row 0 at the top), ``mean_radius_px`` float, ``stats_line() -> str``.

Pass stages (pbrt-v4 SPPM order): 1. camera pass (visible points through
specular chains, emission seen along them, direct light by next-event
estimation), 2. grid of visible points, 3. photon pass (deposits after the
first bounce), 4. gather, 5. per-pixel N/R/tau update, 6. film.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from .materials import bsdf as B
from .sppm import edges
from .frequency import spectrum as F
from .sppm import hashgrid
from .lights import lights as Lt
from . import memory
from .accel import Accel, surface_point
from .scene.camera import CameraModel, FilterSampler
from .errors import CheckpointMismatch, RenderCancelled, SceneError
from .sppm.photons import PhotonTracer, triangle_curvature
from .plan import RenderPlan, make_plan
from .scene.model import Scene, drop_invalid_triangles, scene_digest
from .settings import RenderSettings
from .mathutil import dot as _dot

PHOTON_CHUNK = 131_072


@dataclass
class PassResult:
    pass_index: int
    photons_emitted: int
    elapsed: float
    image: np.ndarray
    aovs: dict = field(default_factory=dict)
    mean_radius_px: float = 0.0
    held_fraction: float = 0.0

    def stats_line(self) -> str:
        m, s = divmod(int(self.elapsed), 60)
        return (f"Pass {self.pass_index} | {self.photons_emitted / 1e6:.1f} M photons | "
                f"{m}:{s:02d} | mean radius {self.mean_radius_px:.2f} px")


@dataclass
class VisiblePoints:
    """Per-pixel visible points of one camera pass (P = pixels in the region).

    valid (P,) bool; p, ng, ns, wo (P,3) float64 (ng, ns oriented to wo);
    mat (P,) int32; colors (P,L,3); beta (P,3) path throughput / selection
    probability; depth (P,) camera depth proxy for the pixel footprint;
    const (P,) bool (Lambert-only: f = albedo/pi); albedo (P,3).
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


class Renderer:
    def __init__(self, scene: Scene, settings: RenderSettings,
                 log: Callable[[str], None] = print, should_stop=None,
                 force_stages: tuple = ()):
        self.settings = settings.validate()
        self.log = log
        # Polled between the set-up stages too (cancel within 1 s).
        self._should_stop = should_stop or (lambda: False)
        scene, dropped = drop_invalid_triangles(scene)
        self.dropped_triangles = dropped
        if dropped:
            log(f"FPPM: dropped {dropped} NaN, infinite or zero-area triangle(s).")
        self.scene = scene
        cam = scene.camera
        W, H = (int(v) for v in cam.resolution)
        if W < 1 or H < 1:
            raise SceneError(f"The render resolution {W}x{H} is empty: set a resolution of at least 1x1.")
        self.full_size = (W, H)
        if cam.border is not None:
            bx0, by0, bx1, by1 = cam.border
            x0, x1 = int(np.floor(bx0 * W)), int(np.ceil(bx1 * W))
            y0, y1 = int(np.floor(by0 * H)), int(np.ceil(by1 * H))
            x0, y0 = max(x0, 0), max(y0, 0)
            x1, y1 = min(max(x1, x0 + 1), W), min(max(y1, y0 + 1), H)
        else:
            x0, y0, x1, y1 = 0, 0, W, H
        self.offset = (x0, y0)
        self.width, self.height = x1 - x0, y1 - y0
        self.D = scene.diameter()
        st0 = self.settings
        self.memory = memory.estimate(self.width * self.height,
                                      min(st0.photons_per_pass, PHOTON_CHUNK), scene.n_triangles,
                                      st0.occlusion_grid_res, st0.use_frequency)
        memory.check_fits(self.memory)
        self.light_table = Lt.build_light_table(scene)
        for w in getattr(self.light_table, "warnings", []):
            log(f"FPPM: {w}")
        if not np.any(self.light_table.flux.sum(axis=1) > 0):
            raise SceneError("The scene has no light: add a light with non-zero power, "
                             "an emissive material or a world colour.")
        self.mtab = B.build_material_table(scene.materials, scene.textures)
        self._check_stop()
        self.accel = Accel(scene.tri_p, self.D)
        self._check_stop()
        self.camera = CameraModel(cam)
        self.fsamp = FilterSampler(scene.filter_width)
        # force_stages: stage names the plan must keep even when the scene does
        # not need them (tests and benchmarks of the leave-out plan).
        self.plan: RenderPlan = make_plan(scene, self.settings, self.mtab, self.light_table,
                                          force=tuple(force_stages))
        self._check_stop()
        self.kappa = triangle_curvature(scene) if self.plan.frequency_photons else None
        self._check_stop()
        self.occ_grid = None
        if self.plan.occlusion_grid:
            from .frequency.occlusion import build_occlusion_grid, default_locality
            t0 = time.perf_counter()
            lo, hi = scene.bounds()
            pad = 1e-3 * self.D
            res = self.settings.occlusion_grid_res
            # Locality = 2 voxel diagonals (the grid's default); distances
            # beyond 4x that are never used, so the build may stop there.
            diag = float(np.linalg.norm((hi - lo + 2 * pad) / res))
            self.occ_locality = 2.0 * diag
            self.occ_grid = self._interruptible(build_occlusion_grid, scene.tri_p, lo - pad, hi + pad, res,
                                                 max_distance=4.0 * self.occ_locality + 2 * diag)
            self.occ_locality = default_locality(self.occ_grid)
            self.occ_build_seconds = time.perf_counter() - t0
        self.tracer = PhotonTracer(self.scene, self.accel, self.mtab, self.light_table,
                                   self.settings, self.plan, self.kappa, self.occ_grid,
                                   getattr(self, "occ_locality", 0.0), self.D)
        # Pixel grid of the region, py counted from the bottom (Blender's).
        ys, xs = np.mgrid[0:self.height, 0:self.width]
        self.px = (xs.ravel() + x0).astype(np.float64)
        self.py = ((self.height - 1 - ys).ravel() + y0).astype(np.float64)
        P = self.width * self.height
        # Per-pixel progressive statistics, float64 (docs/frequency.md: float32
        # counters stall at 2^24).
        self.R2 = np.zeros(P)            # 0 = not initialised yet
        self.N = np.zeros(P)
        self.tau = np.zeros((P, 3))
        self.L_sum = np.zeros((P, 3))    # direct + emission, summed over passes
        self.r_pred_last = np.full(P, np.inf)
        self.held = np.zeros(P, bool)
        self.M_last = np.zeros(P)
        self.pass_index = 0
        self.photons_emitted = 0
        self.elapsed = 0.0
        self._fixed_vp: Optional[VisiblePoints] = None
        self._edge_cap: Optional[np.ndarray] = None
        # Seconds and rays per stage, for the benchmark (ratios, not bare times).
        self.stage_seconds = {k: 0.0 for k in ("camera", "direct", "photon_trace", "gather", "update")}
        self.photon_rays = 0
        st = self.settings
        self._freq_pairs_needed = self.plan.frequency_photons and (
            st.frequency_estimator == "QUANTILE" or st.aov_spectrum)
        self.r_hist = (np.zeros((P, self.HIST_BINS), np.uint32)
                       if self.plan.frequency_photons and st.frequency_estimator == "QUANTILE" else None)
        self.spectrum = np.zeros((P, 3)) if st.aov_spectrum else None
        self._pass_hist = self._pass_spec = None
        self._depth_for_fp = np.zeros(P)
        self.last_result: Optional[PassResult] = None

    # ------------------------------------------------------------------ API
    def plan_lines(self) -> list[str]:
        s = self.scene
        lines = [f"Scene: {s.n_triangles} triangles, {len(s.materials)} materials, "
                 f"{len(s.lights)} lights, {self.width}x{self.height} px."]
        lines += self.plan.lines()
        return lines

    def run(self, should_stop=None, on_pass=None) -> PassResult:
        st = self.settings
        if should_stop is not None:
            self._should_stop = should_stop
        while True:
            if st.max_passes and self.pass_index >= st.max_passes:
                break
            if st.time_limit and self.elapsed >= st.time_limit:
                break
            if self._should_stop():
                break
            try:
                res = self.step()
            except RenderCancelled:
                break
            if on_pass is not None:
                on_pass(res)
        if self.last_result is None:
            self.last_result = self._film()
        if self.pass_index and not np.any(self.last_result.image[..., :3] > 0):
            # A hidden emitter or a camera inside a closed object is
            # rendered as it is (black, like Cycles), but said so.
            self.log("FPPM: the image is black: no light reaches anything the camera sees "
                     "(every light is hidden behind geometry, or the camera is inside a "
                     "closed object).")
        return self.last_result

    def step(self) -> PassResult:
        t0 = time.perf_counter()
        k = self.pass_index + 1
        st = self.settings
        tc = time.perf_counter()
        if st.fixed_visible_points and self._fixed_vp is not None:
            vp, L_emit = self._fixed_vp, self._fixed_emit
        else:
            vp, L_emit = self._interruptible(self._camera_pass, self._rng(k, 0))
            if st.fixed_visible_points:
                self._fixed_vp, self._fixed_emit = vp, L_emit
        td = time.perf_counter()
        self.stage_seconds["camera"] += td - tc
        L_pass = L_emit + self._interruptible(self._direct, vp, self._rng(k, 1))
        self.stage_seconds["direct"] += time.perf_counter() - td
        self._check_stop()
        self._init_radii(vp)
        self._depth_for_fp = np.where(vp.valid, vp.depth, self._depth_for_fp)
        M, Phi, r_pred = self._photon_pass(vp, self._rng(k, 2))
        # Commit the pass only once it is complete (cancel keeps the last one).
        tu = time.perf_counter()
        self.L_sum += L_pass
        if self.r_hist is not None and self._pass_hist is not None:
            self.r_hist += self._pass_hist
        if self.spectrum is not None and self._pass_spec is not None:
            self.spectrum[...] = self._pass_spec
        self._update(vp, M, Phi, r_pred)
        self.stage_seconds["update"] += time.perf_counter() - tu
        self.pass_index = k
        self.photons_emitted += st.photons_per_pass
        self.elapsed += time.perf_counter() - t0
        self.last_result = self._film()
        return self.last_result

    # ------------------------------------------------------ checkpointing
    STATE_KEYS = ("R2", "N", "tau", "L_sum", "r_pred_last", "held", "M_last", "_depth_for_fp")

    def state_dict(self) -> dict:
        """Everything needed to continue this render bit for bit: per-pixel
        statistics, counters and the digests that must match on resume.  RNG
        streams are derived from (seed, pass, stage), so no RNG state is kept."""
        d = {k: getattr(self, k).copy() for k in self.STATE_KEYS}
        for k in ("r_hist", "spectrum"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k).copy()
        d.update(pass_index=self.pass_index, photons_emitted=self.photons_emitted,
                 elapsed=self.elapsed, settings_digest=self.settings.image_digest(),
                 scene_digest=scene_digest(self.scene), size=(self.width, self.height))
        return d

    def load_state(self, d: dict) -> None:
        """Continue from ``state_dict()`` output; refuse a different scene or settings."""
        if d["scene_digest"] != scene_digest(self.scene):
            raise CheckpointMismatch("The checkpoint was made from a different scene "
                                     "(geometry, materials, lights or camera changed).")
        if d["settings_digest"] != self.settings.image_digest():
            raise CheckpointMismatch("The checkpoint was made with different render settings.")
        if tuple(d["size"]) != (self.width, self.height):
            raise CheckpointMismatch("The checkpoint was made at a different resolution.")
        for k in self.STATE_KEYS + ("r_hist", "spectrum"):
            if k in d and getattr(self, k) is not None:
                getattr(self, k)[...] = d[k]
        self.pass_index = int(d["pass_index"])
        self.photons_emitted = int(d["photons_emitted"])
        self.elapsed = float(d["elapsed"])
        if self.settings.fixed_visible_points and self.pass_index > 0:
            # Fixed visible points come from pass 1's camera stream: rebuild them.
            self._fixed_vp, self._fixed_emit = self._camera_pass(self._rng(1, 0))
        self.last_result = self._film()

    # ------------------------------------------------------------ helpers
    def _rng(self, k: int, stage: int) -> np.random.Generator:
        # One independent stream per (seed, pass, stage): deterministic, and a
        # resumed render continues the same sequence.
        return np.random.Generator(np.random.PCG64(
            np.random.SeedSequence([self.settings.seed, k, stage])))

    def _check_stop(self):
        if self._should_stop():
            raise RenderCancelled("cancelled")

    def _interruptible(self, fn, *args, **kw):
        """fn(*args, **kw) in a worker thread while this thread polls should_stop.

        For stages whose longest calls cannot poll (the occlusion grid's
        numba kernels, camera.generate and the hit attributes over every
        pixel): they release the GIL often enough (numpy, numba nogil) that
        the poll here runs every ~20 ms and cancel returns at once.  fn must
        not change the renderer's state (its result is simply dropped).  The
        worker's own _check_stop sees a threading.Event, not should_stop
        (which may be Blender's test_break: called from this thread only),
        so an abandoned worker stops at its next check; it is a daemon.
        """
        import threading
        out = {}
        stop = threading.Event()
        caller_should_stop = self._should_stop

        def work():
            try:
                out["value"] = fn(*args, **kw)
            except BaseException as ex:  # re-raised in the caller's thread
                out["error"] = ex
        self._should_stop = stop.is_set
        try:
            th = threading.Thread(target=work, name="fppm-stage", daemon=True)
            th.start()
            while th.is_alive():
                th.join(0.02)
                if caller_should_stop():
                    stop.set()
                    raise RenderCancelled("cancelled")
        finally:
            self._should_stop = caller_should_stop
        if "error" in out:
            raise out["error"]
        return out["value"]

    def _hit_attributes(self, h, idx):
        s = self.scene
        return surface_point(s.tri_p, s.tri_n, s.tri_uv, h.prim[idx], h.u[idx], h.v[idx])

    # -------------------------------------------------------- camera pass
    def _camera_pass(self, rng, centre: bool = False) -> tuple[VisiblePoints, np.ndarray]:
        """One visible point per pixel; centre=True: through the pixel centre
        and the lens centre (the boundary cap's pass, core.edges)."""
        st = self.settings
        P = self.px.shape[0]
        u = rng.random((P, 4))
        if centre:
            u[:, :2] = 0.5      # FilterSampler.sample(0.5) = 0: the pixel centre
            u[:, 2:] = 0.0      # lens radius sqrt(0) = 0
        rays, dz = self.camera.generate(self.px, self.py, u[:, :2], u[:, 2:], self.fsamp)
        L = np.zeros((P, 3))
        nL = self.mtab.kind.shape[1]
        vp = VisiblePoints(valid=np.zeros(P, bool), p=np.zeros((P, 3)), ng=np.zeros((P, 3)),
                           ns=np.zeros((P, 3)), wo=np.zeros((P, 3)), mat=np.zeros(P, np.int32),
                           colors=np.zeros((P, nL, 3)), beta=np.zeros((P, 3)),
                           depth=np.zeros(P), const=np.zeros(P, bool), albedo=np.zeros((P, 3)))
        idx = np.arange(P)
        o, d, tmax = rays.o, rays.d, rays.t_max
        beta = np.ones((P, 3))
        path_len = np.zeros(P)
        last = np.zeros(P, np.int8)      # 0 camera, 1 reflection, 2 transmission
        max_depth = st.max_bounces if self.plan.specular_chains else 1
        for depth in range(max_depth):
            if idx.size == 0:
                break
            self._check_stop()
            h = self.accel.intersect(o, d, tmax)
            hit = h.hit
            # Analytic emitters (area lights, light spheres) seen before the hit.
            for code, name in ((0, "camera"), (1, "glossy"), (2, "transmission")):
                sel = last == code
                if np.any(sel):
                    Le = Lt.emitted_along_rays(self.light_table, o[sel], d[sel],
                                               np.minimum(h.t[sel], tmax[sel]), name)
                    L[idx[sel]] += beta[sel] * Le
            miss = ~hit
            if np.any(miss):
                L[idx[miss]] += beta[miss] * Lt.world_radiance(self.light_table)[None, :]
            ih = np.nonzero(hit)[0]
            if ih.size == 0:
                break
            p, ng, ns, uv = self._hit_attributes(h, ih)
            wo = -d[ih]
            mat = self.scene.tri_mat[h.prim[ih]]
            colors = B.lobe_colors(self.mtab, mat, uv)
            em = self.mtab.emission[mat]
            if np.any(em > 0):
                if self.mtab.emission_tex is not None and np.any(self.mtab.emission_tex[mat] >= 0):
                    em = em * _emission_texture(self.mtab, self.scene, mat, uv)
                L[idx[ih]] += beta[ih] * em
            bt = beta[ih]
            plen = path_len[ih] + h.t[ih]
            p_delta = B.delta_probability(self.mtab, mat, colors)
            ur = rng.random((ih.size, 4))
            go_delta = ur[:, 0] < p_delta
            if depth == max_depth - 1:
                go_delta[:] = False
            # Visible points where the chain stops (pbrt-v4 SPPM: first
            # non-specular vertex); throughput divided by the choice probability.
            mk = ~go_delta & self.mtab.has_nondelta[mat]
            if np.any(mk):
                q = idx[ih[mk]]
                sgn = np.where(_dot(ng[mk], wo[mk]) >= 0, 1.0, -1.0)[:, None]
                vp.valid[q] = True
                vp.p[q] = p[mk]
                vp.ng[q] = ng[mk] * sgn
                # Cycles flips the shading normal together with the geometric
                # one (back-face hits), not by its own side of wo.
                ns_o = ns[mk] * sgn
                vp.ns[q] = ns_o
                vp.wo[q] = wo[mk]
                vp.mat[q] = mat[mk]
                vp.colors[q] = colors[mk]
                vp.beta[q] = bt[mk] / np.maximum(1.0 - p_delta[mk], 1e-12)[:, None]
                vp.depth[q] = plen[mk] * np.abs(dz[q])
                vp.const[q] = self.mtab.lambert_only[mat[mk]]
                vp.albedo[q] = B.lambert_albedo(self.mtab, mat[mk], colors[mk])
            cont = go_delta & (p_delta > 0)
            if not np.any(cont):
                break
            c = np.nonzero(cont)[0]
            wi, wgt, pdf, is_delta, valid = B.sample_bsdf(
                self.mtab, mat[c], colors[c], ns[c], ng[c], wo[c], ur[c, 1:4],
                subset="delta", mode="radiance")
            wgt = wgt / p_delta[c][:, None]
            ok = valid & np.all(np.isfinite(wgt), axis=1) & (wgt.max(axis=1) > 0)
            c = c[ok]
            wi = wi[ok]
            refl = (_dot(wi, ng[c]) * _dot(wo[c], ng[c])) > 0
            new_idx = ih[c]
            o = self.accel.spawn(p[c], ng[c], wi)
            d = wi
            beta = bt[c] * wgt[ok]
            tmax = np.full(c.size, np.inf)
            path_len = plen[c]
            last = np.where(refl, 1, 2).astype(np.int8)
            idx = idx[new_idx]
        return vp, L

    # -------------------------------------------------------- direct light
    def _direct(self, vp: VisiblePoints, rng) -> np.ndarray:
        P = vp.valid.shape[0]
        L = np.zeros((P, 3))
        if self.settings.photons_for_direct:
            return L
        q = np.nonzero(vp.valid)[0]
        if q.size == 0:
            return L
        smp = Lt.sample_direct(self.light_table, vp.p[q], rng.random((q.size, 3)), n=vp.ns[q])
        wi, dist, wgt, shadow = smp["wi"], smp["dist"], smp["weight"], smp["cast_shadow"]
        live = (wgt.max(axis=1) > 0) & np.all(np.isfinite(wgt), axis=1)
        q, wi, dist, wgt, shadow = q[live], wi[live], dist[live], wgt[live], shadow[live]
        if q.size == 0:
            return L
        f = B.eval_bsdf(self.mtab, vp.mat[q], vp.colors[q], vp.ns[q], vp.ng[q], vp.wo[q], wi)
        cos = np.abs(_dot(vp.ns[q], wi))
        contrib = vp.beta[q] * f * cos[:, None] * wgt
        nz = contrib.max(axis=1) > 0
        q, wi, dist, contrib, shadow = q[nz], wi[nz], dist[nz], contrib[nz], shadow[nz]
        o = self.accel.spawn(vp.p[q], vp.ng[q], wi)
        blocked = np.zeros(q.size, bool)
        mesh = smp["kind"][live][nz] == Lt.MESH
        # Analytic lights are not geometry: any hit before them occludes.
        a = np.nonzero(~mesh)[0]
        if a.size:
            blocked[a] = self.accel.occluded(o[a], wi[a], dist[a])
            b = a[blocked[a]]
            if b.size:
                blocked[b] = self._grazing_self_hit_retry(vp.p[q[b]], vp.ng[q[b]], o[b],
                                                          wi[b], dist[b])
        # Emissive triangles are geometry: the shadow ray must not be stopped by
        # the emitter itself.  Embree's float32 hit distance errs by about
        # offset/|cos| at grazing angles, so a closest hit counts as the emitter
        # when it lies within that tolerance of the sample.
        m = np.nonzero(mesh)[0]
        if m.size:
            end = vp.p[q[m]] + wi[m] * dist[m][:, None]
            h = self.accel.intersect(o[m], wi[m], dist[m] * (1 + 1e-6) + self.accel.offset_scale(end))
            hitm = h.hit
            cos_l = np.ones(m.size)
            if np.any(hitm):
                P = self.scene.tri_p[h.prim[hitm]].astype(np.float64)
                ngl = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
                ngl /= np.maximum(np.linalg.norm(ngl, axis=1, keepdims=True), 1e-300)
                cos_l[hitm] = np.abs(_dot(ngl, wi[m][hitm]))
            tol = 4.0 * self.accel.offset_scale(end) / np.maximum(cos_l, 1e-4)
            blocked[m] = hitm & (h.t < dist[m] - tol)
        blocked &= shadow
        L[q[~blocked]] += contrib[~blocked]
        return L

    def _grazing_self_hit_retry(self, p, ng, o, wi, dist) -> np.ndarray:
        """(K,) bool: still blocked after discarding float32 self-hits.

        Embree subtracts the ray origin from the vertices in float32, so a
        triangle's plane is only known to ~|vertex| * 2^-24; a shadow ray
        leaving a large triangle near the origin at grazing incidence (89.9
        deg) re-hits its own plane although it starts |p| * REL_OFFSET above
        it (-15 % at 89.9 deg on a rotated 4 m plane).  A first hit
        whose plane passes within 8 REL_OFFSET |vertex|_max of the origin is
        such a self-hit: the ray is cast again from an offset relative to
        that triangle's vertices.  A real occluder is never that close to the
        origin's plane at a magnitude that large, so shadows are kept.
        """
        from .accel import REL_OFFSET
        h = self.accel.intersect(o, wi, dist)
        still = h.hit.copy()
        i = np.nonzero(h.hit)[0]
        if i.size == 0:
            return still
        P = self.scene.tri_p[h.prim[i]].astype(np.float64)
        n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        vmax = np.abs(P).max(axis=(1, 2))
        eps = 8.0 * REL_OFFSET * vmax
        self_hit = np.abs(_dot(o[i] - P[:, 0], n)) < eps
        j = i[self_hit]
        if j.size:
            side = np.where(_dot(ng[j], wi[j]) >= 0, 1.0, -1.0)
            off = np.maximum(eps[self_hit], self.accel.offset_scale(p[j]))
            o2 = p[j] + ng[j] * (side * off)[:, None]
            still[j] = self.accel.occluded(o2, wi[j], dist[j])
        return still

    # ------------------------------------------------------------- radii
    def _init_radii(self, vp: VisiblePoints):
        new = vp.valid & (self.R2 == 0)
        if not np.any(new):
            return
        st = self.settings
        if st.radius_mode == "WORLD":
            r = np.full(int(new.sum()), st.initial_radius)
        else:
            # Rule: initial radius = initial_radius_px pixel footprints at the
            # visible point's camera depth (slope ignored).
            r = st.initial_radius_px * self.camera.footprint(vp.depth[new])
        if st.cap_radius_at_edges:
            r = np.minimum(r, self._boundary_cap()[new])
        r = np.maximum(r, self.radius_floor)
        self.R2[new] = r * r

    def _boundary_cap(self) -> np.ndarray:
        """(P,) float64 cap on each pixel's initial radius [m] (inf = none):
        half the distance to the nearest surface boundary seen around the
        pixel (core.edges.boundary_cap), computed once from a camera pass
        through the pixel centres.

        Measured on example_blends/indirect_room.blend (128^2, FPPM, 120
        passes, same seed): relMSE excess against Cycles 8.3e-4 without the
        cap, 6.3e-4 with it (the pixels next to strong gradients: 6.5e-4 ->
        4.2e-4).  Taking in addition the minimum over the pixels a filter
        sample can reach (so that a silhouette pixel's samples on the near
        object get the near object's radius) gave 8.6e-4: the extra noise of
        the smaller radii outweighed the bias it removed."""
        if self._edge_cap is None:
            st = self.settings
            vp, _ = self._camera_pass(np.random.default_rng([st.seed, 0xED6E]), centre=True)
            fp = self.camera.footprint(vp.depth)
            if st.radius_mode == "WORLD":
                r_px = st.initial_radius / np.maximum(fp[vp.valid], 1e-300)
                reach = edges.reach_for(float(r_px.max()) if r_px.size else 1.0)
            else:
                reach = edges.reach_for(st.initial_radius_px)
            self._edge_cap = edges.boundary_cap(vp.p, vp.ng, vp.wo, vp.valid, fp,
                                                self.height, self.width, reach)
        return self._edge_cap

    @property
    def radius_floor(self) -> float:
        # docs/frequency.md stiff table: R >= 1e-7 D keeps 1/(pi R^2) finite.
        return 1e-7 * self.D

    # -------------------------------------------------------- photon pass
    def _photon_pass(self, vp: VisiblePoints, rng):
        st = self.settings
        P = vp.valid.shape[0]
        active = vp.valid & (self.R2 > 0)
        M = np.zeros(P)
        Phi = np.zeros((P, 3))
        r_pred = np.full(P, np.inf)
        if not np.any(active):
            return M, Phi, r_pred
        # Pass-local histogram and spectrum: committed in step() with the
        # rest of the pass, so a cancelled pass leaves no trace.
        self._pass_hist = None if self.r_hist is None else np.zeros_like(self.r_hist)
        self._pass_spec = None if self.spectrum is None else self.spectrum.copy()
        grid = hashgrid.build_grid(vp.p, np.sqrt(self.R2), active)
        n_total = st.photons_per_pass
        n_freq_total = int(round(n_total * st.frequency_fraction)) if self.plan.frequency_photons else 0
        done = 0
        while done < n_total:
            self._check_stop()
            n = min(PHOTON_CHUNK, n_total - done)
            n_freq = int(np.clip(n_freq_total - done, 0, n))
            t0 = time.perf_counter()
            rays0 = self.accel.rays_cast
            dep = self.tracer.trace(n, n_freq, rng)
            self.photon_rays += self.accel.rays_cast - rays0
            t1 = time.perf_counter()
            self.stage_seconds["photon_trace"] += t1 - t0
            done += n
            if dep is None:
                continue
            # cos_ng = -1: count photons on every surface inside the sphere
            # (pbrt-v4 SPPM) but only from the camera's side.  Rejecting the
            # adjacent wall's photons darkened Cornell-box corners by 13%
            # against Cycles; accepting them leaves 3% (measured, t_cornell).
            g = hashgrid.gather(grid, dep["p"], dep["ng"], dep["wi"], dep["power"], dep["rpred"],
                                vp.p, vp.ng, self.R2, vp.const, cos_ng=-1.0)
            M += g.M
            Phi += g.Phi_sum * (vp.albedo / np.pi)
            if g.pair_vp.size:
                pv, pp = g.pair_vp, g.pair_ph
                f = B.eval_bsdf(self.mtab, vp.mat[pv], vp.colors[pv], vp.ns[pv], vp.ng[pv],
                                vp.wo[pv], dep["wi"][pp])
                # Photons estimate flux per geometric area; radiance wants the
                # shading cosine: |wi.ns| / |wi.ng| (Veach 1997, 5.3), capped
                # so a grazing geometric normal cannot spike.
                corr = np.minimum(B.shading_correction(vp.ns[pv], vp.ng[pv], dep["wi"][pp]), 4.0)
                contrib = f * (dep["power"][pp] * corr[:, None])
                for ch in range(3):
                    Phi[:, ch] += np.bincount(pv, weights=contrib[:, ch], minlength=P)
            r_pred = np.minimum(r_pred, g.rpred_min)
            if self._freq_pairs_needed and n_freq:
                self._collect_frequency_pairs(grid, dep, vp)
            self.stage_seconds["gather"] += time.perf_counter() - t1
        Phi *= vp.beta
        if st.frequency_model == "PAPER":
            r_pred = np.where(np.isinf(r_pred), np.inf, -r_pred)
        if st.frequency_estimator == "QUANTILE" and self.plan.frequency_photons:
            r_pred = self._quantile_radius(r_pred)
        return M, Phi, r_pred

    # Robust estimator (the paper's future work): a per-pixel histogram of the
    # predicted radii of every frequency photon gathered so far; the radius is
    # the lower edge of the bin holding the QUANTILE-th fraction, so a few
    # outliers (false occlusions pinning r near 0) no longer set it.
    QUANTILE = 0.1
    HIST_BINS = 24

    def _hist_bin(self, r):
        lo, hi = 1e-6 * self.D, self.D
        x = (np.log(np.maximum(np.abs(r), 1e-300)) - np.log(lo)) / (np.log(hi) - np.log(lo))
        return np.clip((x * (self.HIST_BINS - 1)).astype(np.int64) + 1, 0, self.HIST_BINS - 1)

    def _hist_edge(self, b):
        lo, hi = 1e-6 * self.D, self.D
        e = np.exp(np.log(lo) + (b - 1) / (self.HIST_BINS - 1) * (np.log(hi) - np.log(lo)))
        return np.where(b <= 0, 0.0, e)

    def _collect_frequency_pairs(self, grid, dep, vp):
        """(VP, frequency photon) pairs: histogram of r, and the spectrum AOV."""
        fq = np.nonzero(~np.isnan(dep["rpred"]))[0]
        if fq.size == 0:
            return
        g = hashgrid.gather(grid, dep["p"][fq], dep["ng"][fq], dep["wi"][fq], dep["power"][fq],
                            dep["rpred"][fq], vp.p, vp.ng, self.R2,
                            np.zeros_like(vp.const), cos_ng=-1.0)
        pv, pp = g.pair_vp, fq[g.pair_ph]
        if pv.size == 0:
            return
        rr = dep["rpred"][pp]
        if self._pass_hist is not None:
            np.add.at(self._pass_hist, (pv, self._hist_bin(rr)), 1)
        if self.settings.aov_spectrum and "spec" in dep:
            # The spectrum of the photon that predicted the smallest radius.
            order = np.lexsort((np.abs(rr), pv))
            first = np.ones(order.size, bool)
            first[1:] = pv[order][1:] != pv[order][:-1]
            sel = order[first]
            self._pass_spec[pv[sel]] = dep["spec"][pp[sel]]

    def _quantile_radius(self, r_pred_min):
        h = self.r_hist + self._pass_hist
        tot = h.sum(axis=1)
        cum = np.cumsum(h, axis=1)
        b = np.argmax(cum >= np.ceil(self.QUANTILE * np.maximum(tot, 1))[:, None], axis=1)
        return np.where(tot > 0, self._hist_edge(b), r_pred_min)

    # --------------------------------------------------------- PPM update
    def _update(self, vp, M, Phi, r_pred):
        st = self.settings
        floor2 = self.radius_floor ** 2
        if not self.plan.frequency_photons:
            r_pred = np.full_like(r_pred, np.nan)
        else:
            # Only Lambert visible points may hold: the predicted radius is
            # computed for a diffuse receiver (a_eff = a, r_theta = inf).
            r_pred = np.where(vp.const, r_pred, np.nan)
            r_pred = np.where(np.isinf(r_pred), np.nan, r_pred)
        m = M > 0
        N2, R2n, tau2, held = F.ppm_radius_update(self.N[m], self.R2[m], self.tau[m], M[m],
                                                  Phi[m], st.alpha, r_pred[m], floor2)
        self.N[m], self.R2[m], self.tau[m] = N2, R2n, tau2
        self.held[:] = False
        self.held[np.nonzero(m)[0]] = held
        self.r_pred_last = r_pred
        self.M_last = M

    # --------------------------------------------------------------- film
    def _film(self) -> PassResult:
        P = self.px.shape[0]
        k = max(self.pass_index, 1)
        L = self.L_sum / k
        n_emit = max(self.photons_emitted, 1)
        R2 = np.where(self.R2 > 0, self.R2, np.inf)
        L = L + self.tau / (np.pi * R2[:, None] * n_emit)
        L = np.where(np.isfinite(L), L, 0.0)
        H, W = self.height, self.width
        img = np.ones((H, W, 4), np.float32)
        img[..., :3] = L.reshape(H, W, 3)
        st = self.settings
        aovs = {}
        R = np.sqrt(np.where(self.R2 > 0, self.R2, 0.0))
        fp = self._footprint_px_cache()
        r_px = np.where(fp > 0, R / np.maximum(fp, 1e-300), 0.0)
        if st.aov_radius:
            aovs["FPPM Radius"] = R.reshape(H, W, 1).astype(np.float32)
            aovs["FPPM Radius px"] = r_px.reshape(H, W, 1).astype(np.float32)
        if st.aov_predicted_radius:
            rp = np.where(np.isfinite(self.r_pred_last), self.r_pred_last, 0.0)
            aovs["Predicted Radius"] = rp.reshape(H, W, 1).astype(np.float32)
        if st.aov_spectrum:
            # The PAPER model is unguarded by design and can overflow: the AOV
            # stays finite (NaN -> 0, +-inf -> +-float32 max) so viewers cope.
            f32 = np.finfo(np.float32).max
            aovs["Spectrum"] = np.nan_to_num(np.clip(self.spectrum, -f32, f32), nan=0.0).reshape(
                H, W, 3).astype(np.float32)
        if st.aov_photon_count:
            aovs["Photon Count"] = self.N.reshape(H, W, 1).astype(np.float32)
        if st.aov_held:
            aovs["Held"] = self.held.reshape(H, W, 1).astype(np.float32)
        valid = self.R2 > 0
        mean_px = float(r_px[valid].mean()) if np.any(valid) else 0.0
        return PassResult(self.pass_index, self.photons_emitted, self.elapsed, img, aovs,
                          mean_px, float(self.held.mean()) if P else 0.0)

    def _footprint_px_cache(self):
        """(P,) pixel footprint [m] at the visible points of the last pass."""
        return self.camera.footprint(self._depth_for_fp)


def _emission_texture(mtab, scene, mat, uv):
    from .scene.textures import sample_texture
    out = np.ones((mat.size, 3))
    for t in np.unique(mtab.emission_tex[mat]):
        if t < 0:
            continue
        sel = mtab.emission_tex[mat] == t
        out[sel] = sample_texture(scene.textures[t], uv[sel])
    return out
