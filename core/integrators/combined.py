"""Integrator 'COMBINED': camera paths and light tracing, weighted by MIS.

    cam = CameraMIS(light_table, mtab, camera, n_light_paths, camera_samples)
    path_tracer.vc = cam                      # PathTracer then weights with it
    lt = CombinedLightTracer(<LightTracer arguments>, camera_samples)
    splats = lt.trace_pass(n_light_paths, rng, check_stop)   # chunks: LightTracer

Image = (camera paths: mean over the passes of each pass' mean of
camera_samples paths per pixel) + (light tracing: splat sums / light paths).
The weights (power heuristic over PT emission, next-event estimation and
light tracing) and their running products are in :mod:`.mis` and
docs/integrators.md ("Combined").
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

from .. import lights as Lt
from .. import materials as B
from ..materials import rough_maps
from ..accel import RAY_CAMERA, REL_OFFSET, intersect_f32, surface_point
from ..lights import direct_kernels as DK
from ..lights import pdf_kernels as PdfK
from ..lights import shadow
from ..lights.pdf import _selection_probability
from ..lights.shadow import transparent_materials
from ..lights.table import AREA, MESH
from ..materials.compiled import scatter_pdfs
from ..mathutil import dot as _dot
from . import light_kernels as LK
from . import mis as M
from . import path_kernels as PathK
from ..sppm import photon_kernels as PK
from .light_tracer import LightTracer, _triangles
from ..scene import absorption as Absorb
from ..scene.linking import unlit_first_hits


def _finite(w):
    return np.where(np.isfinite(w), w, 0.0)


def _y1(depth):
    """Whether vertices are y_1: depth the vertex index (int, every row:
    depth == 0) or (K,) bool per row (PathTracer with transparent crossings,
    which are no vertex: only crossings since the lens)."""
    return np.bool_(depth == 0) if np.ndim(depth) == 0 else np.asarray(depth, bool)


def _rows(flag, i):
    """flag (a bool or an array) at rows i."""
    return flag if np.ndim(flag) == 0 else flag[i]


def _shrink(w, r):
    """The weight w of a camera strategy against its camera rival, with the
    light-tracing ratio r = q_L / q_this added: 1 / (1/w + r^2)."""
    return _finite(w / (1.0 + w * r * r))


def _ratio2(f):
    """r^2 from a factor f = 1 / (1 + r^2) (a weight computed with w = 1)."""
    with np.errstate(divide="ignore"):
        return 1.0 / f - 1.0


def _with_merge(w, rl2, rm2, soft):
    """(K,) a camera strategy's weight w (against its camera rival) with the
    light-tracing and merging ratios squared rl2, rm2 added (power
    heuristic: 1 / (1/w + rl2 + rm2)); soft lights: w / (1 + rl2 + rm2)
    (light tracing and merging against the camera strategies as one)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return _finite(np.where(soft, w / (1.0 + rl2 + rm2), w / (1.0 + w * (rl2 + rm2))))


class CameraStop(NamedTuple):
    """Where the camera paths of 'COMBINED' stop because light tracing takes
    the rest (``RenderSettings.camera_depth``; docs/integrators.md "Camera
    depth"): a camera path whose first vertex y_1 is on a ``covered``
    material keeps the camera strategies whose last camera vertex is y_j,
    j <= depth (next-event estimation at y_j, emission found from y_j; j = 0
    is the camera ray), and is not traced further.  Light tracing is then the
    only strategy of the longer paths through a covered y_1 and takes them
    with weight 1: its splat at z_m (= y_1, m light vertices) drops the camera
    terms when m > depth.  The weights of the shorter paths are unchanged
    (the same three strategies sample them), so they still sum to one on
    every path.  depth 0 or 1; covered (M,) bool by material; alone: depth 0
    and every material of the scene covered, so that no splat of a light
    vertex has a camera strategy beside it (light tracing then needs no MIS
    ratios: LIGHT's trace); camera_free: alone, and light tracing splats every
    emitter the camera can see (no soft point or spot light, whose disc only
    camera rays find), so that the camera paths would only find emitters seen
    directly: none are traced and light tracing's splat of those emitters
    takes weight 1 as well.  one: one camera path a pixel and pass (K = 1
    in both sides' weights), set where the camera paths only find emitters
    (alone) or, at depth 1, where the camera sees covered materials only
    (:func:`camera_stop`'s 'AUTO'), so that every camera path a pixel adds
    is one more light sample at y_1 (docs/integrators.md "The point
    caustic: `COMBINED` below FPPM and `LIGHT`")."""
    depth: int
    covered: np.ndarray
    alone: bool = False
    camera_free: bool = False
    one: bool = False

    def ends(self, depth: int, mat_hit, mat_y1) -> np.ndarray:
        """(K,) bool: the camera rays of loop step ``depth`` (0: the camera
        rays, hitting y_1) that stop at their hit (materials mat_hit) after
        its emission was counted: at y_1 when depth 0, at y_2 when depth 1
        (mat_y1: the material of the vertex y_1 the ray left)."""
        if depth != self.depth:
            return np.zeros(np.shape(mat_hit)[0], bool)
        return self.covered[mat_y1 if depth else mat_hit]

    def light_only(self, mat, first) -> np.ndarray:
        """(K,) bool: the light vertices (materials mat, ``first`` = z_1)
        whose splat has no camera strategy beside it (weight 1)."""
        cov = self.covered[mat]
        return cov if self.depth == 0 else cov & ~np.asarray(first, bool)


def camera_stop(lt) -> Optional[CameraStop]:
    """The CameraStop of the 'COMBINED' light tracer lt (its settings'
    ``camera_depth``: 'EMITTERS' depth 0, 'DIRECT' depth 1, 'AUTO' depth 0
    where every material of the scene is covered and light paths reach the
    camera often enough (:func:`visible_splats` >= VISIBLE_SPLATS), else
    none), or None (camera paths at full length) when it is 'FULL' or light
    tracing cannot take every path the camera would stop: merging as an MIS
    strategy, transparent crossings (no vertex of the
    weights), an emitter light tracing does not trace (sun, world, hidden
    lights: ``all_traced``), the world's light, or emissive triangles that
    are no light row.  Built by the light tracer itself, so that
    tools/distributed.py's workers apply the same rule; the renderer hands
    it to the camera side (CameraMIS.stop).  The covered materials:
    :func:`covered_materials`."""
    st, t = lt.tracer.settings, lt.light_table
    depth = {"FULL": -1, "EMITTERS": 0, "DIRECT": 1}.get(st.camera_depth, 0)
    if (depth < 0 or st.merge_weights == "MIS" or lt.tracer.plan.transparent_shadows
            or not lt.all_traced or np.any(t.world > 0)
            or (t.environment is not None and t.environment.total > 0)):
        return None
    tri_mat = np.asarray(lt.scene.tri_mat, np.int64)
    emissive = np.nonzero(lt.mtab.emission[tri_mat].max(axis=1) > 0)[0]
    if not np.isin(emissive, t.source[t.kind == MESH]).all():
        return None
    covered = covered_materials(lt.mtab, lt.fast_mat)
    alone = depth == 0 and bool(covered[np.unique(tri_mat)].all())
    soft = np.any((lt.cls == M.SOFT) & (t.p_select > 0))
    if st.camera_depth == "AUTO":
        if visible_splats(lt, st.seed) < VISIBLE_SPLATS:
            return None
        if not alone:
            # A mirror or glass somewhere: 'DIRECT' with one camera path a
            # pixel where the camera sees none (camera_sees_covered_only)
            # and every traced emitter is a delta light (measured on those
            # only: docs/integrators.md, the point caustic), else FULL.
            if not (delta_light_rows(t, lt.cls)[t.p_select > 0].all()
                    and camera_sees_covered_only(lt, covered)):
                return None
            return CameraStop(1, covered, one=True)
    return CameraStop(depth, covered, alone, alone and not soft, one=alone)


#: 'AUTO' leaves the camera paths out only where light paths reach the
#: camera this often (unoccluded splats in the image per light path, the
#: pilot of visible_splats): measured 0.5 to 2.0 on the diffuse rooms of
#: example_blends (64x64), 0.008 in the furnace box of tests/test_combined.py
#: whose camera sees a small part of a closed box (light tracing alone there:
#: 6x the noise of the combined camera paths).
VISIBLE_SPLATS = 0.1

#: Light paths of that pilot.
PILOT_PATHS = 8192


def camera_sees_covered_only(lt, covered) -> bool:
    """Whether the camera rays through the pixel centres of the light
    tracer lt's region (and the lens centre) hit covered materials only
    (misses count as covered: camera_stop has no world light).  A pilot for
    'AUTO''s choice only: a mirror or glass it misses still has its camera
    paths at full length (CameraStop stops camera paths at covered y_1
    only), so the image stays unbiased whatever it finds."""
    from ..scene.camera import FilterSampler
    ys, xs = np.mgrid[0:lt.H, 0:lt.W]
    px = (xs.ravel() + lt.x0).astype(np.float64)
    py = ((lt.H - 1 - ys).ravel() + lt.y0).astype(np.float64)
    u = np.full((px.size, 2), 0.5)       # FilterSampler.sample(0.5) = 0: the centre
    rays, _ = lt.camera.generate(px, py, u, u, FilterSampler(lt.filter_width, lt.filter_type))
    prim = lt.accel.for_rays(RAY_CAMERA).intersect(rays.o, rays.d, rays.t_max).prim
    mat = np.asarray(lt.scene.tri_mat, np.int64)[prim[prim >= 0]]
    return bool(covered[mat].all())


def visible_splats(lt, seed: int) -> float:
    """Unoccluded splats in the image per light path of the light tracer lt:
    PILOT_PATHS light paths of a stream of their own (seed: the render's, so
    that the decision is the same in every process of a seeded render), each
    vertex joined to the lens as light tracing does (LightTracer._connections)."""
    rng = np.random.default_rng([int(seed), 0x5EED])
    t = lt.emit_table
    ph = (PK.sample_photons_fast(t, PILOT_PATHS, rng) if lt.fast_emission
          else Lt.sample_photons(t, PILOT_PATHS, rng))
    dep = lt.tracer.trace_emitted(ph, rng)
    if dep is None or dep["p"].shape[0] == 0:
        return 0.0
    _, n, tr = lt._connections(dep["p"], dep["ng"], rng, _triangles(dep))
    return float(np.count_nonzero(tr.max(axis=1) > 0)) / PILOT_PATHS if n else 0.0


#: Glossy lobes at least this rough (Cycles roughness; GGX alpha = its square)
#: leave a material's camera vertices to light tracing (covered_materials).
COVER_ROUGHNESS = 0.25


def covered_materials(mtab, fast_mat) -> np.ndarray:
    """(M,) bool: the materials of CameraStop -- no delta lobe (a camera
    path that scattered by one at y_1 is no light-tracing path) and every
    lobe diffuse (Lambert, Oren-Nayar) or glossy with roughness >=
    COVER_ROUGHNESS, where a light vertex joined to the lens sees a BSDF
    about as flat as a camera path's first bounce does; LightTracer.fast_mat
    (LAMBERT without Normal Map / Bump) always."""
    from ..scene.model import DIFFUSE, GLOSSY
    k = mtab.kind
    flat = (k < 0) | (k == DIFFUSE) | ((k == GLOSSY) & (mtab.roughness >= COVER_ROUGHNESS))
    return (np.asarray(fast_mat, bool)
            | (mtab.has_nondelta & ~mtab.has_delta & np.all(flat, axis=1)))


def _mat_rows(v):
    """(mat, row) (K,) int64 of vertices v for the path kernels: their
    materials and colour rows (``PathVertices.row``; the materials' own
    where it is None)."""
    mat = np.ascontiguousarray(v.mat, np.int64)
    row = getattr(v, "row", None)
    return mat, (mat if row is None else np.ascontiguousarray(row, np.int64))


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
        # Merging as an MIS strategy (merge_weights 'MIS', core.integrators.merge):
        # (R2 (P,) the pass' squared radii by pixel, N_M merging photons per
        # pass, the region (x0, y0, W, H)), set by the renderer before each
        # pass; None = no such term.
        self.mis_merge = None
        self.K = int(K)
        # Where the camera paths stop (CameraStop), set by the renderer; None = never.
        self.stop = None
        # Direct light of radius-0 point/spot lights at y_1: NEE's alone
        # (mis.NEE_OWNS_DELTA_DIRECT; the light side's _chunk agrees).
        self.owns = bool(M.NEE_OWNS_DELTA_DIRECT)

    # ---------------------------------------------------------- densities
    def c1(self, d, cos_surf, t):
        """(K,) c_1: the one-pixel camera density of the point at distance t
        along the camera rays d, |cos_surf| there (area measure)."""
        A = self.camera.pixel_area
        if self.ortho:
            return cos_surf / A
        cc = -(d @ self.camera.R[:, 2])
        return cos_surf / (A * cc ** 3 * t * t)

    def set_samples(self, K: int) -> None:
        """K camera paths per pixel and pass instead (CameraStop.one)."""
        self.ratio *= self.K / float(K)
        self.K = int(K)

    def merge_scale(self, p1, u_lens):
        """(K,) merging's N_M pi r^2 / K for camera paths whose y_1 is p1 (K, 3)
        (lens uniforms u_lens (K, 2)): r^2 of the pixel containing y_1
        (``mis_merge``; core.integrators.merge_kernels.pixel_rows)."""
        from .merge_kernels import y1_terms
        R2, n_m, region = self.mis_merge
        rows = y1_terms(self.camera, p1, u_lens, region)[0]
        return n_m * np.pi * R2[rows] / self.K

    def camera_state(self, d):
        """Q carried by the camera rays (K,): N_L / K."""
        return np.full(d.shape[0], self.ratio)

    def at_hit(self, Qs, pf, ih, d, ng, t, depth):
        """(Q, c) at the vertices hit by rays ih at distance t from the vertex
        they left (past transparent crossings, which are no vertex); depth:
        as :func:`_y1` (per hit: the hit is y_1)."""
        first = _y1(depth)
        cos = np.abs(_dot(ng, d))
        if np.all(first):
            return Qs, self.c1(d, cos, t)
        with np.errstate(divide="ignore", invalid="ignore"):
            Q, c = Qs / (t * t), pf[ih] * cos / (t * t)
        if np.any(first):
            Q, c = np.where(first, Qs, Q), np.where(first, self.c1(d, cos, t), c)
        return Q, c

    def continued(self, v, c, wi, pdf, is_delta, depth, Q=None):
        """(Qs, pf) of the rays leaving the vertices v[c] along wi: Q times
        the light-side density pr at the vertex (from the second vertex on;
        1 after a delta) times |cos| / c; Q = 0 after a delta at the first
        vertex (light tracing cannot connect there).  depth: as :func:`_y1`
        (per vertex of v).  Q: the vertices' ratio to carry instead of
        v.Q (merging's QM, never at a first vertex: depth False)."""
        pr = np.ones(c.size)
        fc = np.broadcast_to(_y1(depth), (v.p.shape[0],))[c]
        nd = np.nonzero(~is_delta & ~fc)[0]
        if nd.size:
            i = c[nd]
            pr[nd] = B.pdf_bsdf(self.mtab, v.mat[i], v.colors[i], v.ns[i], v.ng[i],
                                wi[nd], v.wo[i], subset="all")
        with np.errstate(divide="ignore", invalid="ignore"):
            Q = _finite((v.Q if Q is None else Q)[c] * pr * np.abs(_dot(v.ng[c], wi)) / v.c[c])
        Q = np.where(is_delta & fc, 0.0, Q)
        return Q, np.where(is_delta, 1.0, pdf)

    def nee_compiled(self, pmat, w, v, wi, dist, light, pl, sel, depth):
        """:meth:`nee` for vertices in the scope of the path kernels
        (``path_kernels.camera_nee_kernel``; pmat their PathMaterials; pl, sel
        the samples' light-sampling density and selection probability).  With merging's
        QM (v.QM) the kernel gives each ratio as a factor 1 / (1 + r^2) of a
        unit weight, combined by :func:`_with_merge`."""
        from . import path_kernels as PK
        c = np.ascontiguousarray
        mat, row = _mat_rows(v)
        geo = (c(v.c), c(v.p), c(v.ng), c(v.ns), c(v.wo), c(wi), c(dist), c(light, np.int64),
               c(pl), c(sel))
        if getattr(v, "QM", None) is not None:
            fl, fm = np.ones(light.size), np.ones(light.size)
            X = self.mis_lights
            PK.camera_nee_kernel(X, pmat, mat, row, depth == 0, self.owns, c(v.Q), *geo, fl)
            PK.camera_nee_kernel(X, pmat, mat, row, False, self.owns, c(v.QM), *geo, fm)
            return _with_merge(np.asarray(w, np.float64), _ratio2(fl), _ratio2(fm),
                               self.cls[light] == M.SOFT)
        w = np.array(w, np.float64)
        PK.camera_nee_kernel(self.mis_lights, pmat, mat, row, depth == 0, self.owns, c(v.Q),
                             *geo, w)
        return w

    @property
    def mis_lights(self):
        """The emitter arrays of ``path_kernels.camera_nee_kernel``
        (``path_kernels.MisLights``), built on first use."""
        if getattr(self, "_mis_lights", None) is None:
            from . import path_kernels as PK
            self._mis_lights = PK.build_mis_lights(self.t, self.cls)
        return self._mis_lights

    def continued_compiled(self, pmat, v, nx, depth, Q=None):
        """:meth:`continued` for the NextRays nx of ``path_kernels.continue_kernel``
        (pmat the kernels' PathMaterials, v.row its colour rows, None: the
        materials'; Q: as :meth:`continued`)."""
        from . import path_kernels as PK
        out = np.empty(nx.src.size)
        c = np.ascontiguousarray
        mat, row = _mat_rows(v)
        PK.camera_continued_kernel(pmat, mat, row, depth == 0 and Q is None, nx.src,
                                   nx.delta, nx.d, c(v.ng),
                                   c(v.ns), c(v.wo), c(v.Q if Q is None else Q), c(v.c), out)
        return out, nx.pdf

    def _reverse(self, v, wo_light, depth):
        """(K,) pr at vertices v for light arriving along wo_light (1 at the
        first vertex; depth as :func:`_y1`)."""
        pr = np.ones(v.p.shape[0])
        i = np.nonzero(~np.broadcast_to(_y1(depth), pr.shape))[0]
        if i.size:
            pr[i] = B.pdf_bsdf(self.mtab, v.mat[i], v.colors[i], v.ns[i], v.ng[i], wo_light[i],
                               v.wo[i], subset="all")
        return pr

    def soft_ratio(self, v, light, depth, Q=None):
        """(K,) q_L / q_C of a soft light's centre seen from vertices v
        (depth as :func:`_y1`; Q: merging's QM for q_M / q_C)."""
        wc = self.t.co[light] - v.p
        dc = np.linalg.norm(wc, axis=1)
        wc = wc / np.maximum(dc, 1e-300)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            return _finite((v.Q if Q is None else Q) * self._reverse(v, wc, depth)
                           * np.abs(_dot(v.ng, wc))
                           * M.point_emit_over_nee(self.t, v.p, light, -wc, dc) / v.c)

    # ------------------------------------------------------------ weights
    def emission(self, w, idx, row, d, t, ng, depth, Qs, pf, pdf_prev, vprev, QMs=None):
        """(k,) weights of emission found by rays idx (emitter rows row, -1 =
        none) at distance t from the vertex they left (past transparent
        crossings) given their PT-vs-NEE weights w; depth: the index of the
        vertex hit (int) or (K,) bool per ray, the camera ray (only
        transparent crossings since the lens: :func:`_y1`), the vertices
        vprev the rays left then carrying ``first`` (y_1).  QMs: merging's
        QM of the rays (all rays, 0 where merging cannot take the path) or
        None; the vertices vprev then carry theirs (``QM``)."""
        first = _rows(_y1(depth), idx)
        w = w.copy()
        ok = row >= 0
        cls = np.where(ok, self.cls[np.maximum(row, 0)], M.NO_LT)
        f = np.nonzero(cls == M.FULL)[0]
        if f.size:
            j, dd = row[f], d[idx[f]]
            cos_l = np.abs(_dot(dd, self.t.dir[j]))
            pA = M.emit_pdf_pos(self.t, j)
            fr = _rows(first, f)
            with np.errstate(divide="ignore", invalid="ignore"):
                r = Qs[idx[f]] * pA / self.c1(dd, cos_l, t[f])
                rm = np.zeros(f.size)
                if not np.all(fr):
                    pW = M.emit_pdf_dir(self.t, j, -dd)
                    r = np.where(fr, r, Qs[idx[f]] * pW * pA / (pf[idx[f]] * cos_l))
                    if QMs is not None:
                        # q_M / q_0: the same far end with QM (0 on camera rays).
                        rm = np.where(fr, 0.0, QMs[idx[f]] * pW * pA / (pf[idx[f]] * cos_l))
            if QMs is None:
                w[f] = _shrink(w[f], _finite(r))
            else:
                r, rm = _finite(r), _finite(rm)
                w[f] = _with_merge(w[f], r * r, rm * rm, False)
        s = np.nonzero((cls == M.SOFT) & ~first)[0]
        if s.size:
            i = idx[s]
            delta = pdf_prev[i] <= 0
            vp = vprev.take(i)
            dp = depth - 1 if np.ndim(depth) == 0 else vp.first
            r = self.soft_ratio(vp, row[s], dp)
            # After a delta at y_{k-1} next-event estimation cannot take the
            # path: light tracing takes it all if it can (the ray's Q > 0: y_1
            # did not scatter by a delta), else path tracing alone (a light
            # seen in a mirror).  Merging as an MIS strategy: light tracing
            # and merging (QM > 0) share it, path tracing gets it if neither can.
            if QMs is None:
                wl = np.where(delta, np.where(Qs[i] > 0, 1.0, 0.0), r * r / (1.0 + r * r))
                w[s] *= 1.0 - wl
            else:
                can = (Qs[i] > 0) | (QMs[i] > 0)
                rm = self.soft_ratio(vp, row[s], dp, Q=vp.QM)
                with np.errstate(divide="ignore", invalid="ignore"):
                    w[s] *= _finite(np.where(delta, np.where(can, 0.0, 1.0),
                                             1.0 / (1.0 + r * r + rm * rm)))
        return w

    def nee(self, w, v, wi, dist, light, depth):
        """(K,) weights of the light samples (wi, dist, light) at vertices v
        given their NEE-vs-PT weights w; depth as :func:`_y1`.  With
        merging's QM at the vertices (v.QM) its ratio is added as well."""
        first = np.broadcast_to(_y1(depth), light.shape)
        if getattr(v, "QM", None) is not None:
            from dataclasses import replace
            one = np.ones(light.size)
            fl = self.nee(one, replace(v, QM=None), wi, dist, light, depth)
            # QM is 0 at y_1 (merging starts after y_v): no first vertex here.
            fm = self.nee(one, replace(v, Q=v.QM, QM=None), wi, dist, light,
                          np.zeros(light.size, bool))
            return _with_merge(w, _ratio2(fl), _ratio2(fm), self.cls[light] == M.SOFT)
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
                r = _finite(vf.Q * self._reverse(vf, wf, first[f]) * np.abs(_dot(vf.ng, wf)) * T
                            / vf.c)
            if self.owns:
                # A delta light's direct light at y_1: NEE's alone (mis.NEE_OWNS_DELTA_DIRECT).
                r = np.where(first[f] & ~ar, 0.0, r)
            w[f] = _shrink(w[f], r)
        s = np.nonzero(cls == M.SOFT)[0]
        if s.size:
            r = self.soft_ratio(v.take(s), light[s], first[s])
            w[s] *= 1.0 / (1.0 + r * r)
        return w


def delta_light_rows(t, cls) -> np.ndarray:
    """(Nl,) bool: the radius-0 point and spot lights of table t (classes
    cls) in the three-way weights."""
    return (cls == M.FULL) & (t.kind != AREA) & (t.kind != MESH)


def nee_owned_rows(t, cls) -> np.ndarray:
    """(Nl,) bool: the emitter rows of table t (classes cls) whose direct
    light at a non-delta y_1 is next-event estimation's alone
    (mis.NEE_OWNS_DELTA_DIRECT: radius-0 point and spot lights); all False
    when that rule is off.  Their first hits' splats take B1 = inf (w_LT = 0)."""
    return delta_light_rows(t, cls) & bool(M.NEE_OWNS_DELTA_DIRECT)


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
    camera-side density at the emitter); first: bool or (K,) bool."""
    with np.errstate(divide="ignore", invalid="ignore"):
        pend1 = _finite(np.abs(_dot(ng, wn)) / np.where(is_delta, 1.0, pdf))
    pend = pr * pend1
    return pend, np.where(first, pend1, pend)


def splat_weight(B0, B1, pf, c1, first, soft, bm=None):
    """(K,) w_LT of light vertices connected to the camera: 1 / (1 + (B0 pf
    c_1)^2 + (B1 pf c_1)^2), c_1 the camera density of the vertex, pf the
    camera path's BSDF density there towards the light side (not in B1 at
    the first vertex, see scatter_factors); soft lights: no PT term.
    bm: merging's q_M / q_L = (N_M / N_L) pi r^2 c_1 (0 at first hits), or
    None (core.integrators.merge)."""
    b0 = np.where(soft, 0.0, B0 * pf * c1)
    b1 = B1 * c1 * np.where(first, 1.0, pf)
    if bm is not None:
        return _finite(1.0 / (1.0 + b0 * b0 + b1 * b1 + bm * bm))
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
    factors of the current vertex) followed by the bounce kernel
    (``photon_kernels.MisState``),
    every non-delta vertex splatted with w_LT = 1 / (1 + (B0 X)^2 + (B1 X)^2),
    X = pf c_1 (the camera path's BSDF density there and its camera density).
    Light from emitters of class NO_LT (sun, world) is not traced."""

    def __init__(self, *args, camera_samples: int, **kw):
        super().__init__(*args, **kw)
        self.cls = M.light_classes(self.light_table)
        # Light paths start on the emitters light tracing follows only
        # (mis.traced_table: no sun or world photons drawn to be dropped),
        # with the compiled emission where those are all it covers.
        self.emit_table = M.traced_table(self.light_table)
        self.fast_emission = PK.fast_emission_ok(self.emit_table)
        self.K = int(camera_samples)
        self.max_bounces = int(self.tracer.settings.max_bounces)
        self.rr_start = int(self.tracer.settings.rr_start)
        t = self.light_table
        self.all_traced = not np.any((t.p_select > 0) & (self.cls == M.NO_LT))
        self.first_lights = LK.first_hit_lights(t, M.emit_select(t, np.arange(t.n)))
        # Rows whose direct light at a first hit is next-event estimation's
        # alone (radius-0 point and spot lights: mis.NEE_OWNS_DELTA_DIRECT;
        # CameraMIS.nee agrees), None = none.
        owned = nee_owned_rows(t, self.cls)
        self.nee_owned = owned if owned.any() else None
        # Where the camera paths stop (CameraStop; None = never).
        self.stop = camera_stop(self)
        if self.stop is not None and self.stop.one:
            # One camera path a pixel and pass (the weights' K; the renderer
            # sets the PathTracer's).
            self.K = 1
        # No light vertex needs its MIS ratios either (LIGHT's trace, less the
        # first hits) when the camera stops after its light sample at y_1
        # (depth 1), every traced emitter's direct light is that sample's
        # (nee_owned) and every material a light vertex is splatted on is
        # covered: first hits weigh 0, later vertices 1 (CameraStop.light_only).
        st_ = self.stop
        self.plain = bool(st_ is not None and st_.depth == 1 and self.nee_owned is not None
                          and self.nee_owned[t.p_select > 0].all()
                          and st_.covered[self.mtab.has_nondelta].all())
        # The compiled next-event selection probability of _first_hit
        # (lights.pdf_kernels.selection_kernel reads LightPdf's entry and group_frac
        # only, not its hittable), None where the compiled lights do not
        # cover the table: then lights.pdf._selection_probability.
        self._sel_lights = None
        if DK.compiled_lights_ok(t):
            L = DK.build_direct_lights(t)
            self._sel_lights = (L, PdfK.build_light_pdf(t, np.zeros(t.n, bool), L))

    def begin_pass(self, n: int) -> None:
        """A pass of n light paths (all its chunks): the weights' K / N_L;
        with merging as an MIS strategy (``merge_R2``, set by the renderer:
        the pass' squared radii (P,)) the deposits are kept for the gather."""
        self.kn = self.K / float(n)
        self.kept = [] if getattr(self, "merge_R2", None) is not None else None

    def merge_deposits(self):
        """The pass' deposits kept for merging (dict: p, ng, wi, power, B0, B1,
        first), or None; chunk by chunk in an order that does not depend on
        the threads (the chunks' deposit counts and first positions)."""
        if not self.kept:
            return None
        kept = [c for _, c in sorted(self.kept, key=lambda kc: kc[0])]
        return {k: np.concatenate([c[k] for c in kept]) for k in kept[0]}

    def _chunk(self, n: int, rng, film: np.ndarray) -> None:
        t = self.light_table
        et = self.emit_table
        ph = (PK.sample_photons_fast(et, n, rng) if self.fast_emission
              else Lt.sample_photons(et, n, rng))
        light = np.asarray(ph["light"], np.int64)
        if not self.fast_emission:
            # No emitter at all, or photons of zero power (the compiled
            # emission's are dropped by the emission kernel; the traced table
            # draws no NO_LT emitter).
            # An area light's spread zeroes the power of some directions;
            # those photons' points are still its emitter samples
            # (_emission_vertices).
            lj = np.where(light >= 0, light, 0)
            live = np.nonzero((light >= 0) & ((ph["power"].max(axis=1) > 0)
                                              | np.isfinite(et.spread_tan[lj])))[0]
            if live.size == 0:
                return
            if live.size < n:
                ph = {k: v[live] for k, v in ph.items()}
                light = light[live]
        ph["light"] = light
        stop = self.stop
        if self.emitters_seen:
            # No camera paths (CameraStop.camera_free): the splat's weight is 1.
            self._emission_vertices(ph, rng, film, mis=None if stop is not None and stop.camera_free
                                    else (self.kn, M.emit_pdf_pos(t, light),
                                          self.cls[light] == M.FULL))
        if stop is not None and (stop.alone or self.plain):
            # No camera strategy beside any light vertex (CameraStop): LIGHT's
            # trace; plain: without the first hits (next-event estimation's).
            dep = self.tracer.trace_emitted(ph, rng)
            if dep is not None and self.plain:
                keep = dep["bounce"] > 0
                dep = {k: dep[k][keep] for k in ("p", "ng", "wi", "power", "bary")}
            if dep is not None:
                self.connect(dep, rng, film)
            return
        kind = t.kind[light]
        ar = (kind == AREA) | (kind == MESH)
        z0 = np.where(ar[:, None], ph["o"], t.co[light])     # the light end of the weights
        soft = self.cls[light] == M.SOFT
        dep, B0d, B1d, first = self._trace(ph, z0, rng)
        if dep is None:
            return
        if self.nee_owned is not None:
            # A delta light's direct light: next-event estimation's alone
            # (q_1 / q_L infinite: w_LT = 0), unless the camera stops before
            # its light sample (below).
            B1d[first & self.nee_owned[light[dep["src_photon"]]]] = np.inf
        if stop is not None:
            # Paths the camera does not trace (CameraStop): light tracing's alone.
            mat = self.tracer.tris.mat[dep["bary"][:, 0].astype(np.int64)]
            alone = stop.light_only(mat, first)
            B0d[alone] = 0.0
            B1d[alone] = 0.0
        if self.nee_owned is not None and getattr(self, "kept", None) is None:
            # Their splats weigh 0: not joined to the lens (no shadow ray).
            keep = ~(first & np.isinf(B1d))
            if not keep.all():
                dep = {k: dep[k][keep] for k in ("p", "ng", "wi", "power", "bary", "src_photon")}
                B0d, B1d, first = B0d[keep], B1d[keep], first[keep]
        mis = (B0d, B1d, first, soft[dep["src_photon"]])
        if getattr(self, "kept", None) is not None:
            # Merging as an MIS strategy: q_M / q_L = pi r^2 c_1 (N_M = N_L).
            mis = mis + (np.pi * self.merge_R2,)
            p = dep["p"]
            self.kept.append(((p.shape[0], *(float(x) for x in p[0])),
                              dict(p=p, ng=dep["ng"], wi=dep["wi"], power=dep["power"],
                                   B0=B0d, B1=B1d, first=first)))
        self.connect(dep, rng, film, mis=mis)

    def _trace(self, ph, z0, rng):
        """Trace the photons ph with the compiled photon kernels
        (core.sppm.photon_kernels, deposits from the first hit on), which
        follow the MIS factors per scattering (``MisState``: LAMBERT and
        delta samples in the kernel, other materials by ``pdf_bsdf`` here);
        B0, B1 = the first-hit ratios of the photon (numpy, once per photon)
        times the factors of each deposit.
        Returns (deposits + src_photon (row of ph), B0, B1, first) or Nones."""
        tr = self.tracer
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
        generic = tr.fmat.any_generic
        # The GENERIC materials the bounce kernel samples itself (importance
        # mode, core.materials.compiled.sample_pair), the rest in numpy.
        comp = tr.fmat.any_sampled
        cg = n if generic else 1
        gen = PK.generic_hits(cg, comp)
        rec = PK.HitRecord(t=np.empty(1), ng=np.empty((1, 3)), nswi=np.empty(1),
                           hit=np.empty(1, bool), nxt_src=np.empty(n, np.int64),
                           nxt_delta=np.empty(n, bool))
        dep = tr.deposit_buffers(n)
        mis = PK.mis_state(n, dep.buf.r.shape[0])
        mis.row[:K] = src[:K]
        # Transparent shadows: a transparent crossing is no vertex (the
        # photons straight from the light keep MisState.first).
        clear = (transparent_materials(self.mtab) if shadow.attached(self.accel) is not None
                 else None)
        # First-hit ratios per photon (B0, B1 at z_1).
        fb0, fb1 = np.zeros(n), np.zeros(n)
        for bounce in range(self.max_bounces + 1):
            if K == 0:
                break
            hits = PK.EmbreeHits(*intersect_f32(self.accel, live.o32[:K], live.d32[:K]))
            if bounce == 0 and tr.link is not None:
                # Light linking: no light arrives on an unlit first hit.
                unlit_first_hits(hits.prim[:K], np.asarray(ph["light"], np.int64)[src[:K]],
                                 *tr.link)
            Absorb.attenuate(tr.absorb, hits.prim[:K], hits.tfar[:K], live.d64[:K],
                             live.power[:K])        # absorbing volumes
            step = PK.BounceStep(K=K, first=bounce == 0, store=True,
                                 sample=bounce < self.max_bounces,
                                 roulette=bounce + 1 >= self.rr_start, bounce=bounce,
                                 dep0=dep.n, record=False, rel=rel, floor=floor, mis=True,
                                 compiled=comp)
            u = rng.random((K, 4))
            dep.reserve(K)
            if mis.d0.shape[0] < dep.buf.r.shape[0]:
                mis = _grow_deposit_rows(mis, dep.buf.r.shape[0], dep.n)
            # The rays hitting z_1 now (all at the first bounce).
            fst = mis.first[:K]
            if bounce == 0 or fst.any():
                self._first_hit(hits, K, live.d64[:K], mis.row[:K], ph, z0, fb0, fb1, fst)
            if bounce == 0 and tr.soft_lights is not None and "soft_disc" in ph:
                # After the MIS ratios, which read the light's centre
                # (core.integrators.mis: soft lights).
                PK.soft_light_first_hit(K, hits, live, tr.tris.ng, src,
                                        np.ascontiguousarray(ph["light"], np.int64),
                                        np.ascontiguousarray(ph["soft_disc"], np.float64),
                                        tr.soft_lights)
            # Generic survivors need their rays' photon rows, directions and
            # first flags from before the kernel compacts them.
            fst = fst.copy() if generic else None
            row = mis.row[:K].copy() if generic else None
            d_old = live.d64[:K].copy() if generic else None
            dep0 = dep.n
            n_next, n_dep, n_gen = PK.bounce_kernel(step, hits, live, tr.tris, tr.fmat, u,
                                                    dep.buf, gen, rec, mis)
            dep.n = n_dep
            # B0, B1 of this bounce's deposits: their photon's first-hit ratios
            # (rewritten at z_1 when a photon crossed transparent surfaces).
            r = mis.drow[dep0:n_dep]
            mis.d0[dep0:n_dep] *= fb0[r]
            mis.d1[dep0:n_dep] *= fb1[r]
            if n_gen:
                n_fast = n_next
                n_next = tr._generic_bounce(n_gen, n_next, gen, u, step.roulette, live, rec,
                                            compiled=comp)
                if n_next > n_fast:
                    self._generic_factors(n_fast, n_next, hits, rec, live, d_old, row, mis,
                                          fst, clear)
            K = n_next
        tr.note_deposits(n, dep.n)
        res = dep.result()
        if res is None:
            return None, None, None, None
        nd = dep.n
        drow = mis.drow[:nd]
        res["src_photon"] = drow
        return res, _finite(mis.d0[:nd]), _finite(mis.d1[:nd]), mis.dfirst[:nd].copy()

    def _first_hit(self, hits, K, d, row, ph, z0, fb0, fb1, sel=True):
        """fb0, fb1 [photon] = first_hit_ratios at the hits of the rays
        0..K-1 where sel (K,) bool (default all; z_1: their first hit, or
        the first past transparent crossings) (positions from the barycentrics, the
        triangles' geometric normals):
        compiled for point lights and rectangles (light_kernels.first_hits;
        the points by path_kernels.hit_kernel, the selection probabilities by
        lights.pdf_kernels.selection_kernel), first_hit_ratios for the others."""
        t, tris = self.light_table, self.tracer.tris
        hit = np.nonzero((hits.prim[:K] >= 0) & sel)[0]
        if hit.size == 0:
            return
        h = hit.size
        p, ng, ns = np.empty((h, 3)), np.empty((h, 3)), np.empty((h, 3))
        PathK.hit_kernel(tris, hits.prim[hit], hits.bu[hit].astype(np.float64),
                         hits.bv[hit].astype(np.float64), p, ng, ns)
        r = row[hit]
        light, zr, dh = ph["light"][r], z0[r], d[hit]
        if self._sel_lights is not None:
            p_sel = np.empty(h)
            PdfK.selection_kernel(*self._sel_lights, p, light, p_sel)
        else:
            p_sel = _selection_probability(t, p, light)
        b0, b1 = np.empty(h), np.empty(h)
        LK.first_hits(self.first_lights, self.kn, p, ng, dh, zr, light, p_sel, b0, b1)
        s = np.nonzero(np.isnan(b0))[0]
        if s.size:
            b0[s], b1[s] = first_hit_ratios(t, self.kn, light[s], zr[s], dh[s], p[s], ng[s])
        fb0[r], fb1[r] = b0, b1

    def _generic_factors(self, a, b, hits, rec, live, d_old, row, mis, fst, clear):
        """The MIS factors of the generic-material survivors a..b-1 (appended by
        PhotonTracer._generic_bounce): the forward and reverse pdf_bsdf,
        compiled on the materials the bounce kernel samples
        (``compiled.scatter_pdfs``), in numpy on the others (textures, Normal
        Map / Bump), delta samples 1; fst (K,) bool the hits'
        MisState.first.  clear (materials,) bool the
        transparent materials when transparent shadows are on (else None):
        a Transparent lobe's sample (straight on) is no vertex -- its factors
        pass unchanged (|cos| in = |cos| out) and a ray from z_0 stays first."""
        s, mtab = self.scene, self.mtab
        j = np.arange(a, b)
        i = rec.nxt_src[a:b]
        delta = rec.nxt_delta[a:b]
        _, ngg, nsg, uvg = surface_point(s.tri_p, s.tri_n, s.tri_uv,
                                         hits.prim[i].astype(np.int64),
                                         hits.bu[i].astype(np.float64),
                                         hits.bv[i].astype(np.float64))
        mat = rough_maps.pick(mtab, np.asarray(s.tri_mat, np.int64)[hits.prim[i]],
                              hits.prim[i], hits.bu[i], hits.bv[i], uvg)
        wo, wg = -d_old[i], live.d64[a:b]
        pl = np.ones(j.size)
        pr = np.ones(j.size)
        fm = self.tracer.fmat
        comp = fm.compiled[mat] if fm.any_compiled else np.zeros(j.size, bool)
        c = np.nonzero(comp)[0]
        if c.size:
            q = np.ascontiguousarray
            pc, rc = np.empty(c.size), np.empty(c.size)
            scatter_pdfs(fm.cm.lobes, fm.sel.p, mat[c], q(nsg[c]), q(ngg[c]), q(wo[c]),
                         q(wg[c]), q(delta[c]), pc, rc)
            pl[c], pr[c] = pc, rc
        nd = np.nonzero(~delta & ~comp)[0]
        if nd.size:
            # A view-dependent lobe weighed at the light path's own arrival
            # (the photons' rule: core.sppm.photons).
            col = B.lobe_colors(mtab, mat[nd], uvg[nd], B.view_mu(mtab, wo[nd], nsg[nd]))
            pl[nd] = B.pdf_bsdf(mtab, mat[nd], col, nsg[nd], ngg[nd], wo[nd], wg[nd],
                                subset="all")
            pr[nd] = B.pdf_bsdf(mtab, mat[nd], col, nsg[nd], ngg[nd], wg[nd], wo[nd],
                                subset="all")
        first = fst[i]
        pend, pend1 = scatter_factors(pr, ngg, wg, pl, delta, first)
        mis.f0[a:b] = mis.h0[i] * pend
        mis.f1[a:b] = np.where(first, np.where(delta, 0.0, mis.h1[i] * pend1), mis.h1[i] * pend)
        mis.row[a:b] = row[i]
        through = np.zeros(j.size, bool)
        if clear is not None:
            through = (delta & clear[mat]
                       & (np.einsum("ij,ij->i", wg, d_old[i]) > 1.0 - 1e-9))
        mis.first[a:b] = through & first


def _grow_deposit_rows(mis, cap, n):
    """A MisState whose deposit rows hold cap (the first n copied)."""
    g = PK.mis_state(1, cap)
    g.d0[:n], g.d1[:n], g.drow[:n] = mis.d0[:n], mis.d1[:n], mis.drow[:n]
    g.dfirst[:n] = mis.dfirst[:n]
    return mis._replace(d0=g.d0, d1=g.d1, drow=g.drow, dfirst=g.dfirst)
