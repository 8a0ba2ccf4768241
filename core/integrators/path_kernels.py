"""Compiled per-vertex work of the camera paths (numba), between two Embree calls.

``core.integrators.path_tracer.PathTracer`` traces its paths as a wavefront;
with ``compiled=True`` (the default, where :func:`compiled_scene_ok` holds)
the work per vertex that dominated the numpy path is done by these kernels,
the Embree calls (closest hits, shadow rays) staying in Python between them
as in the photon tracer (core.sppm.photon_kernels):

- the shading point of each hit (:func:`hit_kernel`: ``accel.surface_point``
  with the photon tracer's triangle data and shading normal);
- next-event estimation: the light sample and the Lambert BSDF are
  ``core.lights.direct_kernels.direct_kernel`` (the SPPM direct light's
  kernel, unchanged), then :func:`nee_mis_kernel` weights each sample by the
  power heuristic against BSDF sampling (``PathTracer.mis_light``);
- the light-sampling density of a direction (``core.lights.pdf_direct``):
  ``core.lights.pdf_kernels``' ``selection_kernel`` and ``pdf_kernel``;
- the continuation (:func:`continue_kernel`): BSDF sampling with
  ``core.materials.fast.sample_fast`` (its direction; the radiance-mode
  weight is the lobe colour), throughput, Russian roulette, the spawn offset
  of ``Accel.spawn`` and the compaction of the surviving paths;
- COMBINED: the light-tracing ratios of ``combined.CameraMIS.nee`` and
  ``.continued`` (:func:`camera_nee_kernel`, :func:`camera_continued_kernel`).

GENERIC materials (Blender's default Principled BSDF, rough glossy, rough
glass, Oren-Nayar, a diffuse base under a specular layer) are sampled,
evaluated and weighed at those steps by the photon tracer's compiled BSDF in
radiance mode: ``core.materials.compiled.sample_pair`` (radiance=True),
``eval_pair`` (Cycles' f(view = wo, light = wi), in :func:`nee_mis_kernel`)
and ``pdf_oriented`` (:func:`_bsdf_pdf`: the light sample's MIS weight and
COMBINED's reverse densities).

Scope (:func:`compiled_scene_ok`; otherwise the numpy path runs): materials
Lambert-only, perfect mirror, smooth glass, emission-only (the photon fast
path's classes) or GENERIC, with no Transparent lobe and no alpha texture;
colour textures on any of them (Blender's Image Texture into a Base Color:
a textured Lambert-only material is sampled as Lambert, any other as
GENERIC, each hit with its own lobe colours and lobe selection,
:class:`PathMaterials`); a Normal Map / Bump only on GENERIC materials
(their perturbed normals come from ``PathTracer._perturb`` on those hits,
and the compiled BSDF applies Cycles' valid specular normal and bump
shadowing in radiance mode); lights as ``direct_kernels.compiled_lights_ok``
with an environment map (its light sample, density and radiance compiled),
no textured emissive triangles.  Photon merging's partition
(core.integrators.merge) is applied by the caller.  The emission found
along rays (analytic emitters, the world, emissive triangles) with its MIS
and COMBINED weights, and the shadow test, stay numpy, on their rows.

Precision: the same formulas as the numpy path in float64 (GENERIC rows:
those of core.materials.compiled, equal to numpy's to rounding), but the Lambert f
is (sum of colours)/pi against the per-lobe sum, products are grouped as
``direct_kernel`` groups them, the Lambert sample density is N.wi/pi against
the sampler's local z/pi, and numba's libm may differ from numpy's in the
last bit (amplified near the spherical rectangle's degenerate ends, see
``direct_kernels``); paths make the same random decisions, so images agree
to ~1e-14 relative (tests/test_path_kernels.py).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

# The light-sampling density, compiled into nee_mis_kernel (edited with its move
# to core.lights.pdf_kernels: numba's cache is stamped by this file).
from ..lights.emission import spot_tail
from ..lights.pdf_kernels import pdf_kernel, selection_kernel
from ..lights.warp_kernels import spot_pdf_local
from ..lights.table import AREA, MESH, POINT, SPOT, WORLD
# sample_fast (and compiled._disk in it) and compiled.sample_pair, eval_pair
# and pdf_oriented are compiled into this module's kernels: numba's on-disk
# cache is stamped by each kernel's own file, so a change of the samplers
# (core.materials.compiled, .fast) must come with an edit here and in
# core.sppm.photon_kernels, or a cache filled before it keeps the old code
# (this note came with compiled.sincos_quarter; edited again with the disk
# warp's one division and sample_fast inlined, with compiled.sample_pair's
# radiance mode, with the GENERIC materials in these kernels, with the
# Normal Map / Bump corrections of the radiance-mode sample and density, with
# the microfacet lobes' geometric side test, with the colour row of
# sample_pair and pdf_oriented, with the BSDF evaluation's lobe helpers
# and reference counts of round 32, with the view factor of round 40, and
# with the displacement bump's code of round 45: F_BUMP 2, no bump shadowing,
# and with the conductor Fresnel and the thin film of round 46: F_K, F_FILM_D,
# F_FILM_N, compiled._fresnel_rgb, and with the one-signature entry points
# of round 50: compiled._eval_pair_as, _sample_pair).
from ..materials.compiled import SelectionTable, eval_pair, pdf_oriented, sample_pair
from ..materials.hit_colors import hit_rows, textured_lambert, textured_materials
from ..materials.fast import ABSORBER, GENERIC, LAMBERT, MIRROR, SMOOTH_GLASS, sample_fast
from ..materials import rough_maps
from ..sppm.photon_kernels import shading_normal
from .mis import FULL, SOFT, emit_select
from .light_kernels import lambert_pdf as _lambert_pdf

_PI = np.pi


class PathMaterials(NamedTuple):
    """The materials of the vertex kernels (M materials, L lobe slots).

    Per material m: cls (M,) int8 the kernels' class (``materials.fast``'s,
    a colour-textured material's by :func:`kernel_classes`); ior (M,)
    float64; lobes (M, L, N_FIELDS), tables (N_TABLES,) the compiled BSDF of
    the GENERIC materials (core.materials.compiled, which applies Cycles'
    Normal Map / Bump corrections in radiance mode; 1-material placeholders
    when no material is GENERIC).

    Per colour row r (R rows): rows 0..M-1 are the materials' untextured
    colours; a vertex step with textured hits appends one row per such hit
    (:func:`with_hit_colors`) and the kernels read row[k] of vertex k for
    these: col (R, 3) float64 the radiance-mode sample weight of Lambert,
    mirror and glass (the sum of the lobe colours, or the lobe's colour);
    lum_col (R, 3) the photon fast path's colour (its luminance gates a
    sample, as there); sel_colors (R, L, 3), sel_p, sel_cdf (R, L),
    sel_last (R,) the lobe colours and the luminance selection of
    ``compiled.SelectionTable``."""
    cls: np.ndarray
    ior: np.ndarray
    col: np.ndarray
    lum_col: np.ndarray
    lobes: np.ndarray
    tables: np.ndarray
    sel_colors: np.ndarray
    sel_p: np.ndarray
    sel_cdf: np.ndarray
    sel_last: np.ndarray


class NextRays(NamedTuple):
    """The paths that continue (rows 0..n-1 of cap rows, written by
    :func:`continue_kernel`): src (cap,) int64 row of the vertex it left;
    o, d (cap, 3) float64 origin (spawned) and unit direction; beta (cap, 3)
    throughput; pdf (cap,) the sample's density (1 for a delta sample);
    delta (cap,) bool; n_prev (cap, 3) the vertex's shading normal flipped to
    wo's side; vis (cap,) int8 1 reflected, 2 transmitted."""
    src: np.ndarray
    o: np.ndarray
    d: np.ndarray
    beta: np.ndarray
    pdf: np.ndarray
    delta: np.ndarray
    n_prev: np.ndarray
    vis: np.ndarray


#: GENERIC materials in the kernels' scope (off: such a scene runs the numpy
#: vertices with the compiled BSDF calls, round 24's path; benchmarks).
GENERIC_SCOPE = True


def kernel_classes(mtab, fmat) -> np.ndarray:
    """(M,) int8: the class the kernels sample each material as, the photon
    fast path's (``fmat.cls``) but for colour-textured materials, which it
    leaves GENERIC: Lambert-only ones without a delta lobe are LAMBERT (numpy
    sample_bsdf's fast path, the weight the sum of the hit's colours), the
    others GENERIC (``compiled.sample_pair`` with the hit's colour row)."""
    cls = np.array(fmat.cls, np.int8)
    cls[textured_lambert(mtab) & (cls == GENERIC)] = LAMBERT
    return cls


def compiled_scene_ok(mtab, fmat, table, tri_n) -> bool:
    """Whether the kernels cover the scene (module docstring: scope)."""
    from ..lights.direct_kernels import compiled_lights_ok
    from ..lights.shadow import transparent_materials
    from ..scene import normals
    if not compiled_lights_ok(table, environment=True):
        return False
    if np.any(mtab.emission_tex >= 0):
        return False
    if mtab.alpha_tex is not None and np.any(mtab.alpha_tex >= 0):
        return False
    # Transparent lobes (GENERIC class anyway): their crossings are no MIS
    # vertex (PathTracer._trace), which only the numpy continuation tells.
    if transparent_materials(mtab).any():
        return False
    # Normal Map / Bump: GENERIC materials only (the compiled BSDF applies
    # Cycles' corrections in radiance mode); the numpy Lambert, mirror and
    # glass paths sample them as those classes without (closures.sample_bsdf).
    bumped = np.zeros(fmat.cls.shape[0], bool)
    if mtab.bump_correction is not None:
        bumped |= np.asarray(mtab.bump_correction, bool)
    spec = normals.attached(tri_n)
    if spec is not None:
        bumped |= normals.perturbed_materials(spec, bumped.size)
    cls = kernel_classes(mtab, fmat)
    if np.any(bumped & (cls != GENERIC)):
        return False
    cls_ok = np.isin(cls, (LAMBERT, MIRROR, SMOOTH_GLASS, ABSORBER))
    if GENERIC_SCOPE:
        # A roughness map's own rows: the camera paths pick a level row first.
        cls_ok |= (cls == GENERIC) & (np.asarray(fmat.sampled, bool) | textured_materials(mtab)
                                      | rough_maps.mapped(mtab))
    # Lambert here is the radiance-mode Lambert (lambert_only), not the photons' lambert_lobes.
    lam_ok = (cls != LAMBERT) | np.asarray(mtab.lambert_only, bool)
    return bool(np.all(cls_ok & lam_ok))




def _sample_weights(mtab, cls, mat, colors) -> np.ndarray:
    """(K, 3) the radiance-mode sample weight of K hits of materials mat (K,)
    of kernel classes cls (M,), lobe colours colors (K, L, 3): the sum of the
    colours (Lambert: sample_bsdf's colors.sum(axis=1)) or the single used
    lobe's colour (mirror, glass: materials.fast.build_fast_materials), else 0."""
    c = cls[mat]
    col = np.zeros((mat.shape[0], 3))
    lam = c == LAMBERT
    col[lam] = colors[lam].sum(axis=1)
    one = np.nonzero((c == MIRROR) | (c == SMOOTH_GLASS))[0]
    if one.size:
        used = (mtab.kind[mat[one]] >= 0) & (mtab.weight[mat[one]] != 0.0)
        col[one] = colors[one, np.argmax(used, axis=1)]
    return col


def build_path_materials(mtab, fmat) -> PathMaterials:
    """The kernels' materials: their classes (:func:`kernel_classes`), the
    compiled BSDF (``fmat``'s, or compiled here when only textured
    materials are GENERIC) and the M colour rows of the untextured colours
    (``compiled.selection_table``)."""
    from ..materials.compiled import compile_materials, selection_table
    M = fmat.cls.shape[0]
    cls = kernel_classes(mtab, fmat)
    sel = selection_table(mtab)
    cm = fmat.cm
    if np.any((cls == GENERIC) & ~np.asarray(fmat.sampled, bool)):
        cm = compile_materials(mtab)
    c = np.ascontiguousarray
    return PathMaterials(cls=cls, ior=c(fmat.ior, np.float64),
                         col=_sample_weights(mtab, cls, np.arange(M), sel.colors),
                         lum_col=c(fmat.col, np.float64), lobes=c(cm.lobes, np.float64),
                         tables=c(cm.tables, np.float64),
                         sel_colors=c(sel.colors, np.float64),
                         sel_p=c(sel.p, np.float64), sel_cdf=c(sel.cdf, np.float64),
                         sel_last=c(sel.last, np.int64))


def with_hit_colors(M: PathMaterials, X, prim, bu, bv, mat, mu=None):
    """(PathMaterials, rows (K,) int64): M with one colour row appended per
    hit (prim, bu, bv) (K,) on textured materials mat (K,) int64, mu (K,)
    |w_o . n_s| there (``materials.hit_colors.hit_rows``, X its
    ColorInputs), and the rows R .. R + K - 1 they take (R = M's rows);
    their sample weight (Lambert: the sum of the colours) is also the fast
    path's gating colour."""
    S, col, rows = hit_rows(X, SelectionTable(M.sel_colors, M.sel_p, M.sel_cdf, M.sel_last),
                            prim, bu, bv, mat, mu)
    cat = np.concatenate
    return (M._replace(col=cat([M.col, col]), lum_col=cat([M.lum_col, col]),
                       sel_colors=S.colors, sel_p=S.p, sel_cdf=S.cdf, sel_last=S.last), rows)




@njit(cache=True, inline="always")
def _power(a, b):
    """mathutil.power_heuristic of one pair."""
    a2, b2 = a * a, b * b
    s = a2 + b2
    return a2 / s if s > 0 else 1.0


@njit(cache=True, error_model="numpy", inline="always")
def _bsdf_pdf(M, lobes, p, m, r, sx, sy, sz, gx, gy, gz, ox, oy, oz, wx, wy, wz):
    """core.materials.pdf_bsdf(subset='all') of material m for wo = o, wi = w
    (ns = s, ng = g unit, any orientation): the Lambert density, or a
    GENERIC material's by ``compiled.pdf_oriented`` with the selection
    probabilities p[r] of its colour row r.  lobes, p: M's arrays, taken out
    of the struct once by the caller."""
    if M.cls[m] != GENERIC:
        return _lambert_pdf(sx, sy, sz, gx, gy, gz, ox, oy, oz, wx, wy, wz)
    return pdf_oriented(lobes, p, m, r, sx, sy, sz, gx, gy, gz, ox, oy, oz, wx, wy, wz)


# ----------------------------------------------------------------------------
# The shading points, next-event estimation's MIS weight and the continuation.

@njit(cache=True, nogil=True, error_model="numpy")
def hit_kernel(T, prim, bu, bv, p, ng, ns):
    """accel.surface_point of the hits prim (K,) at barycentrics bu, bv (K,)
    float64 on the triangles T (``photon_kernels.TriangleData``): p, ng, ns
    (K, 3), the same operations in the same order (bit for bit)."""
    for k in range(prim.shape[0]):
        t = prim[k]
        uu, vv = bu[k], bv[k]
        w0 = 1.0 - uu - vv
        for c in range(3):
            p[k, c] = w0 * T.p[t, 0, c] + uu * T.p[t, 1, c] + vv * T.p[t, 2, c]
            ng[k, c] = T.ng[t, c]
        ns[k, 0], ns[k, 1], ns[k, 2] = shading_normal(T.n, t, w0, uu, vv, T.ng[t, 0],
                                                      T.ng[t, 1], T.ng[t, 2])


@njit(cache=True, nogil=True, error_model="numpy")
def nee_mis_kernel(L, Q, M, mat, row, beta, p, ng, ns, n_l, wo, S, w, live, pl, sel):
    """For the light samples S (``direct_kernels.DirectSamples``, K rows) taken
    at vertices of materials mat (K,) and colour rows row (K,) (PathMaterials
    M), throughput beta,
    p, ng, ns, wo (K, 3), receiver normals n_l (ns flipped to wo's side):
    the contribution of GENERIC rows, S.contrib = beta f |ns.wi| weight with
    Cycles' f(view = wo, light = wi) (``compiled.eval_pair``, as
    ``PathTracer._direct``; Lambert rows have it from ``direct_kernel``);
    live (K,) bool the sample adds something (contrib > 0, finite); w (K,)
    its power-heuristic weight against BSDF sampling where a BSDF ray along
    it would find the emitter, else 1 (``PathTracer.mis_light``); pl, sel
    (K,) its light-sampling density and selection probability
    (:func:`pdf_kernel`, :func:`selection_kernel`; the COMBINED ratios
    read them)."""
    selection_kernel(L, Q, p, S.light, sel)
    pdf_kernel(L, Q, p, S.wi, S.light, S.dist, n_l, sel, pl)
    lobes, T, cols, sp = M.lobes, M.tables, M.sel_colors, M.sel_p
    for k in range(p.shape[0]):
        m = mat[k]
        j = S.light[k]
        wx, wy, wz = S.wi[k, 0], S.wi[k, 1], S.wi[k, 2]
        if M.cls[m] == GENERIC and j >= 0:
            f = eval_pair(lobes, T, m, cols, row[k], ns[k, 0], ns[k, 1], ns[k, 2], ng[k, 0],
                          ng[k, 1], ng[k, 2], wo[k, 0], wo[k, 1], wo[k, 2], wx, wy, wz, False)
            cs = abs(ns[k, 0] * wx + ns[k, 1] * wy + ns[k, 2] * wz)
            S.contrib[k, 0] = beta[k, 0] * f[0] * (cs * S.weight[k, 0])
            S.contrib[k, 1] = beta[k, 1] * f[1] * (cs * S.weight[k, 1])
            S.contrib[k, 2] = beta[k, 2] * f[2] * (cs * S.weight[k, 2])
        c0, c1, c2 = S.contrib[k, 0], S.contrib[k, 1], S.contrib[k, 2]
        ok = (np.isfinite(c0) and np.isfinite(c1) and np.isfinite(c2)
              and (c0 > 0 or c1 > 0 or c2 > 0))
        live[k] = ok
        w[k] = 1.0
        if not ok:
            continue
        gw = ng[k, 0] * wx + ng[k, 1] * wy + ng[k, 2] * wz
        go = ng[k, 0] * wo[k, 0] + ng[k, 1] * wo[k, 1] + ng[k, 2] * wo[k, 2]
        kind = L.kind[j]
        if not Q.hittable[j]:
            continue
        if kind != MESH and kind != WORLD:
            if not (Q.vis_glossy[j] if gw * go > 0 else Q.vis_trans[j]):
                continue
        pb = _bsdf_pdf(M, lobes, sp, m, row[k], ns[k, 0], ns[k, 1], ns[k, 2], ng[k, 0],
                       ng[k, 1], ng[k, 2], wo[k, 0], wo[k, 1], wo[k, 2], wx, wy, wz)
        w[k] = _power(pl[k], pb)


@njit(cache=True, nogil=True, error_model="numpy")
def continue_kernel(M, mat, row, p, ng, ns, wo, beta, u, roulette, rel, floor, nx):
    """Sample the BSDF at the K vertices (mat (K,), colour rows row (K,), p,
    ng, ns, wo, beta (K, 3),
    u (K, 4): direction (0, 1), lobe / Fresnel (2), roulette (3)) as
    ``sample_bsdf(subset='all', mode='radiance')`` does for the materials of
    ``PathMaterials`` M (Lambert, mirror and glass by ``sample_fast``, GENERIC
    by ``compiled.sample_pair`` in radiance mode), multiply the throughput,
    apply Russian roulette (``roulette``: survival min(1, sqrt(max
    component))) and write the survivors to the NextRays nx (origin from
    ``Accel.spawn``: offset max(|p|_inf, floor) rel along ng to wi's side;
    pdf 1 for a delta sample, as ``CameraMIS.continued``'s).  Returns their
    number."""
    lobes, T = M.lobes, M.tables
    cols, sp, scdf, slast = M.sel_colors, M.sel_p, M.sel_cdf, M.sel_last
    n = 0
    for k in range(mat.shape[0]):
        m = mat[k]
        r_k = row[k]
        c = M.cls[m]
        sx, sy, sz = ns[k, 0], ns[k, 1], ns[k, 2]
        gx, gy, gz = ng[k, 0], ng[k, 1], ng[k, 2]
        ox, oy, oz = wo[k, 0], wo[k, 1], wo[k, 2]
        if c == GENERIC:
            r = sample_pair(lobes, T, cols, sp, scdf, slast, m, r_k, sx, sy, sz, gx, gy, gz,
                            ox, oy, oz, u[k, 0], u[k, 1], u[k, 2], True)
            if not r[7]:
                continue
            wx, wy, wz, is_delta = r[0], r[1], r[2], r[6]
            b0, b1, b2 = beta[k, 0] * r[3], beta[k, 1] * r[4], beta[k, 2] * r[5]
            pdf = 1.0 if is_delta else r[8]
        elif c == LAMBERT or c == MIRROR or c == SMOOTH_GLASS:
            q = sample_fast(c, M.lum_col[r_k, 0], M.lum_col[r_k, 1], M.lum_col[r_k, 2],
                            M.ior[m], sx, sy, sz, gx, gy, gz, ox, oy, oz, u[k, 0], u[k, 1],
                            u[k, 2])
            if not q[7]:
                continue
            wx, wy, wz, is_delta = q[0], q[1], q[2], q[6]
            b0 = beta[k, 0] * M.col[r_k, 0]
            b1 = beta[k, 1] * M.col[r_k, 1]
            b2 = beta[k, 2] * M.col[r_k, 2]
            # Cosine sampling (Lambert): the density of the direction drawn.
            pdf = 1.0 if is_delta else _lambert_pdf(sx, sy, sz, gx, gy, gz, ox, oy, oz,
                                                    wx, wy, wz)
        else:
            continue
        if not (np.isfinite(b0) and np.isfinite(b1) and np.isfinite(b2)):
            continue
        bm = max(b0, b1, b2)
        if not bm > 0:
            continue
        if roulette:
            qs = min(np.sqrt(bm), 1.0)
            if not u[k, 3] < qs:
                continue
            qq = max(qs, 1e-300)
            b0, b1, b2 = b0 / qq, b1 / qq, b2 / qq
        go = gx * ox + gy * oy + gz * oz
        gw = gx * wx + gy * wy + gz * wz
        sg = 1.0 if go >= 0 else -1.0
        px, py, pz = p[k, 0], p[k, 1], p[k, 2]
        off = (1.0 if gw >= 0 else -1.0) * (max(max(abs(px), abs(py), abs(pz)), floor) * rel)
        nx.src[n] = k
        nx.o[n, 0], nx.o[n, 1], nx.o[n, 2] = px + gx * off, py + gy * off, pz + gz * off
        nx.d[n, 0], nx.d[n, 1], nx.d[n, 2] = wx, wy, wz
        nx.beta[n, 0], nx.beta[n, 1], nx.beta[n, 2] = b0, b1, b2
        nx.pdf[n] = pdf
        nx.delta[n] = is_delta
        nx.n_prev[n, 0], nx.n_prev[n, 1], nx.n_prev[n, 2] = sx * sg, sy * sg, sz * sg
        nx.vis[n] = 1 if gw * go > 0 else 2
        n += 1
    return n


@njit(cache=True, nogil=True, error_model="numpy")
def add_emission(out, path, idx, beta, Le, w):
    """out[path[i]] += beta[i] * Le[k] * w[k] for the rays i = idx[k] (k,)
    that found emission Le (k, 3), or (1, 3): one radiance for all (the
    world); the numpy expression ``out[path[idx]] += beta[idx] * Le *
    w[:, None]`` in one pass, its operations in its order (bit for bit; a
    path is one row of out)."""
    one = Le.shape[0] == 1
    for k in range(idx.shape[0]):
        i = idx[k]
        r = path[i]
        q = 0 if one else k
        for c in range(3):
            out[r, c] += beta[i, c] * Le[q, c] * w[k]


def alloc_next(K: int) -> NextRays:
    return NextRays(src=np.empty(K, np.int64), o=np.empty((K, 3)), d=np.empty((K, 3)),
                    beta=np.empty((K, 3)), pdf=np.empty(K), delta=np.empty(K, bool),
                    n_prev=np.empty((K, 3)), vis=np.empty(K, np.int8))


# ----------------------------------------------------------------------------
# COMBINED: the light-tracing terms of the camera strategies' weights
# (combined.CameraMIS.nee and .continued for the vertices in the kernels' scope:
# their reverse density is the Lambert pdf, 1 at the first vertex).

class MisLights(NamedTuple):
    """The emitter data of the COMBINED ratios (Nl emitters; few arrays, see
    :class:`EntryLights`): cls (Nl,) int8 ``mis.light_classes``; sel (Nl,)
    float64 ``mis.emit_select``; kind (Nl,) int8; co, dir (Nl, 3); area,
    cos_half_spot (Nl,); tail (Nl, 4) a soft spot's photons beyond its cone
    (``LightTable.spot_tail``); lin, lin_inv
    (Nl, 3, 3) the spot's object matrix and its inverse, det (Nl,) |det lin|;
    spread_sin2 (Nl,) ``LightTable.spread_sin2``."""
    cls: np.ndarray
    sel: np.ndarray
    kind: np.ndarray
    co: np.ndarray
    dir: np.ndarray
    area: np.ndarray
    cos_half_spot: np.ndarray
    tail: np.ndarray
    lin: np.ndarray
    lin_inv: np.ndarray
    det: np.ndarray
    spread_sin2: np.ndarray


def build_mis_lights(table, cls) -> MisLights:
    c = np.ascontiguousarray
    lin = c(np.asarray(table.lin, np.float64).reshape(-1, 3, 3))
    return MisLights(cls=c(cls, np.int8), sel=emit_select(table, np.arange(table.n)),
                     kind=c(table.kind, np.int8),
                     co=c(table.co, np.float64), dir=c(table.dir, np.float64),
                     area=c(table.area, np.float64),
                     cos_half_spot=c(table.cos_half_spot, np.float64),
                     tail=c(spot_tail(table), np.float64), lin=lin,
                     lin_inv=c(np.asarray(table.lin_inv, np.float64).reshape(-1, 3, 3)),
                     det=np.abs(np.linalg.det(lin)) if lin.shape[0] else np.zeros(0),
                     spread_sin2=c(table.spread_sin2, np.float64))


@njit(cache=True, error_model="numpy", inline="always")
def _fin(x):
    return x if np.isfinite(x) else 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _emit_pdf_dir(X, j, wx, wy, wz):
    """mis.emit_pdf_dir of one direction w leaving emitter j."""
    k = X.kind[j]
    c = X.dir[j, 0] * wx + X.dir[j, 1] * wy + X.dir[j, 2] * wz
    if k == AREA:
        s2 = X.spread_sin2[j]
        return c / (_PI * s2) if c >= np.sqrt(1.0 - s2) else 0.0
    if k == MESH:
        return 0.5 * abs(c) / _PI
    if k == POINT:
        return 1.0 / (4.0 * _PI)
    if k == SPOT:
        M = X.lin_inv
        vx = M[j, 0, 0] * wx + M[j, 0, 1] * wy + M[j, 0, 2] * wz
        vy = M[j, 1, 0] * wx + M[j, 1, 1] * wy + M[j, 1, 2] * wz
        vz = M[j, 2, 0] * wx + M[j, 2, 1] * wy + M[j, 2, 2] * wz
        vn = np.sqrt(vx * vx + vy * vy + vz * vz)
        vx, vy, vz = vx / vn, vy / vn, vz / vn
        N = X.lin
        mx = N[j, 0, 0] * vx + N[j, 0, 1] * vy + N[j, 0, 2] * vz
        my = N[j, 1, 0] * vx + N[j, 1, 1] * vy + N[j, 1, 2] * vz
        mz = N[j, 2, 0] * vx + N[j, 2, 1] * vy + N[j, 2, 2] * vz
        Mv = np.sqrt(mx * mx + my * my + mz * mz)
        T = X.tail
        return Mv ** 3 / X.det[j] * spot_pdf_local(T[j, 0], T[j, 1], T[j, 2], T[j, 3],
                                                    X.cos_half_spot[j], -vz)
    return 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _point_emit_over_nee(X, j, nee, wx, wy, wz, dist):
    """mis.point_emit_over_nee of one sample (w = wi_out; nee the
    next-event selection probability of j there)."""
    return (_emit_pdf_dir(X, j, wx, wy, wz) / (dist * dist) * X.sel[j]
            / (nee if nee > 0 else np.inf))


@njit(cache=True, nogil=True, error_model="numpy")
def camera_nee_kernel(X, M, mat, row, first, own, Qv, cv, p, ng, ns, wo, wi, dist, light, pl,
                      sel, w):
    """combined.CameraMIS.nee at the kernels' vertices (K rows of materials
    mat (K,), colour rows row (K,), PathMaterials M: the reverse density is
    :func:`_bsdf_pdf`'s;
    Qv, cv (K,) the vertex's Q and c; p, ng, ns, wo, wi (K, 3); dist,
    light, pl, sel (K,),
    pl and sel the light sample's density and selection probability from
    :func:`nee_mis_kernel`): w (K,),
    the NEE-vs-PT weights, shrunk in place by the light-tracing ratio (FULL
    emitters) or scaled by 1 / (1 + r^2) (SOFT).  first: vertex 0 (reverse
    density 1); own: a radius-0 point or spot light's direct light at
    vertex 0 is next-event estimation's alone (mis.NEE_OWNS_DELTA_DIRECT:
    w unchanged)."""
    lobes, sp = M.lobes, M.sel_p
    for k in range(p.shape[0]):
        j = light[k]
        cl = X.cls[j]
        if cl != FULL and cl != SOFT:
            continue
        if own and first and cl == FULL and X.kind[j] != AREA and X.kind[j] != MESH:
            continue
        px, py, pz = p[k, 0], p[k, 1], p[k, 2]
        sx, sy, sz = ns[k, 0], ns[k, 1], ns[k, 2]
        gx, gy, gz = ng[k, 0], ng[k, 1], ng[k, 2]
        ox, oy, oz = wo[k, 0], wo[k, 1], wo[k, 2]
        if cl == FULL:
            wx, wy, wz = wi[k, 0], wi[k, 1], wi[k, 2]
            kind = X.kind[j]
            if kind == AREA or kind == MESH:
                cos_l = abs(wx * X.dir[j, 0] + wy * X.dir[j, 1] + wz * X.dir[j, 2])
                den = pl[k] * cos_l
                pos = X.sel[j] / X.area[j]
                T = _emit_pdf_dir(X, j, -wx, -wy, -wz) * pos / (den if den > 0 else np.inf)
            else:
                T = _point_emit_over_nee(X, j, sel[k], -wx, -wy, -wz, dist[k])
        else:
            wx, wy, wz = X.co[j, 0] - px, X.co[j, 1] - py, X.co[j, 2] - pz
            dc = np.sqrt(wx * wx + wy * wy + wz * wz)
            dm = max(dc, 1e-300)
            wx, wy, wz = wx / dm, wy / dm, wz / dm
            T = _point_emit_over_nee(X, j, sel[k], -wx, -wy, -wz, dc)
        pr = 1.0 if first else _bsdf_pdf(M, lobes, sp, mat[k], row[k], sx, sy, sz, gx, gy, gz,
                                         wx, wy, wz, ox, oy, oz)
        r = _fin(Qv[k] * pr * abs(gx * wx + gy * wy + gz * wz) * T / cv[k])
        if cl == FULL:
            wk = w[k]
            w[k] = _fin(wk / (1.0 + wk * r * r))
        else:
            w[k] *= 1.0 / (1.0 + r * r)


@njit(cache=True, nogil=True, error_model="numpy")
def camera_continued_kernel(M, mat, row, first, src, delta, d, ng, ns, wo, Qv, cv, Q):
    """combined.CameraMIS.continued for the NextRays (src, delta, d) left by
    the kernels' vertices (mat, row, ng, ns, wo, Qv, cv by vertex row; PathMaterials
    M): Q (n,) = Q_v pr |ng.wi| / c_v, pr the reverse density of
    :func:`_bsdf_pdf` (1 at the first vertex or after a delta), 0 after a
    delta at the first vertex."""
    lobes, sp = M.lobes, M.sel_p
    for n in range(src.shape[0]):
        k = src[n]
        wx, wy, wz = d[n, 0], d[n, 1], d[n, 2]
        gx, gy, gz = ng[k, 0], ng[k, 1], ng[k, 2]
        pr = 1.0
        if not first and not delta[n]:
            pr = _bsdf_pdf(M, lobes, sp, mat[k], row[k], ns[k, 0], ns[k, 1], ns[k, 2], gx, gy,
                           gz, wx, wy, wz, wo[k, 0], wo[k, 1], wo[k, 2])
        q = _fin(Qv[k] * pr * abs(gx * wx + gy * wy + gz * wz) / cv[k])
        Q[n] = 0.0 if (first and delta[n]) else q
