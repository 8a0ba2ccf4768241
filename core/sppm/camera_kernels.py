"""Compiled per-hit work of the camera pass (numba), between two Embree calls.

``core.sppm.visible_points.CameraPass`` traces one wavefront of camera rays
per delta-chain vertex.  After each Embree call, everything that is done per
hit and per pixel is one ``@njit(nogil=True)`` loop (:func:`hit_kernel`):

    barycentric p / ng / ns  ->  material, lobe colours, emission
    ->  first-hit record (depth 0)  ->  delta-lobe choice (p_delta)
    ->  visible-point record, or a row of the continuing chains

writing straight into preallocated structure-of-arrays buffers indexed by
pixel (:class:`VPBuffers`, :class:`FirstBuffers`), instead of a dozen
fancy-index scatters of numpy temporaries.  What stays numpy is per ray set,
not per pixel: the misses (world, analytic emitters seen along the rays,
``core.lights.seen``), texture look-ups of textured materials (their rows
only; ``pre`` below) and the delta-lobe sampling of the continuing chains
(``core.materials.sample_bsdf``; only the specular pixels).

The formulas are those of ``core.accel.surface_point``,
``core.materials.lobe_colors``, ``delta_probability`` and ``lambert_albedo``
written per hit in float64 in the same order; tests/test_compiled_stages.py
checks the compiled camera pass against the numpy one (``CameraPass(...,
compiled=False)``).  The luminance dot product is written c.r Y_r + c.g Y_g +
c.b Y_b where numpy's ``colors @ LUMINANCE`` may round differently, so
p_delta and the throughput agree to 1e-15 relative, everything else bit for
bit.

Threads: a wavefront of at least ``SPLIT_MIN`` rays is processed as two
halves in two threads (``nogil``; the photon tracer's pool and its
``FPPM_PHOTON_THREADS`` setting, core.sppm.photons), each compacting its continuing chains
into its own half of the output; the halves are then joined in order, so
the result does not depend on the split.
"""
from __future__ import annotations

from collections import namedtuple
from dataclasses import fields
from typing import NamedTuple

import numpy as np
from numba import njit

from ..mathutil import LUM_B as _LUM2, LUM_G as _LUM1, LUM_R as _LUM0
from ..materials.table import DIFFUSE_ROUGHNESS_EPS
from ..scene.model import DIFFUSE
from .visible_points import VisiblePoints

#: Wavefronts of at least this many rays run as two halves in two threads.
SPLIT_MIN = 4096


class CameraMaterials(NamedTuple):
    """Per-material data of the camera kernel.  M materials, L lobe slots.

    col: (M, L, 3) float64 colour x mix weight, 0 in unused slots (the
      untextured ``lobe_colors``); sel: (M, L) float64 lobe-selection scale,
      0 in unused slots; delta: (M, L) bool delta lobe; lam: (M, L) bool
      Lambert lobe (``lambert_albedo``'s mask); nondelta, lambert_only: (M,)
      bool; emission: (M, 3) float64; tri_mat: (T,) int32 material of each
      triangle; tri_p, tri_n: (T, 3, 3) float64 corners and corner normals.
    """
    col: np.ndarray
    sel: np.ndarray
    delta: np.ndarray
    lam: np.ndarray
    nondelta: np.ndarray
    lambert_only: np.ndarray
    emission: np.ndarray
    tri_mat: np.ndarray
    tri_p: np.ndarray
    tri_n: np.ndarray


#: The visible points' arrays (``VisiblePoints``' fields but ``first``, P
#: pixels), written by pixel: one list of fields, the dataclass's.
VPBuffers = namedtuple("VPBuffers", [f.name for f in fields(VisiblePoints) if f.name != "first"])


def vp_buffers(vp: VisiblePoints) -> VPBuffers:
    """The kernel's view of vp's arrays (no copies)."""
    return VPBuffers(*(getattr(vp, n) for n in VPBuffers._fields))


class FirstBuffers(NamedTuple):
    """``FirstHit``'s arrays (P pixels) and L (P, 3) the emission seen along the chains."""
    hit: np.ndarray
    p: np.ndarray
    n: np.ndarray
    prim: np.ndarray
    emit: np.ndarray
    L: np.ndarray


class Wavefront(NamedTuple):
    """One vertex of the live chains, K rays: prim (K,) int32 (-1 miss), bu, bv,
    tfar (K,) float32 Embree's hits; idx (K,) int64 pixel; d (K, 3) float64 unit
    direction; beta (K, 3) throughput; plen (K,) path length before this hit;
    dz (K,) float64 the camera's depth factor of each ray's pixel; ur (H, 4) uniforms,
    one row per hit in ray order (the delta choice is ur[:, 0]); pre (K,) int64 row of colors_pre /
    em_pre for hits on textured materials (-1: untextured);
    colors_pre (n, L, 3), em_pre (n, 3); ew (K,) float64 the weight of the
    emission each ray finds at its hit: 1, or on a ray leaving a glossy
    point the MIS weight of that emissive triangle against the point's
    light sample (``visible_points.CameraPass._glossy_emission``); mat_pre
    (n,) int32 those hits' material rows (a roughness map's level,
    core.materials.rough_maps)."""
    prim: np.ndarray
    bu: np.ndarray
    bv: np.ndarray
    tfar: np.ndarray
    idx: np.ndarray
    d: np.ndarray
    beta: np.ndarray
    plen: np.ndarray
    dz: np.ndarray
    ur: np.ndarray
    pre: np.ndarray
    colors_pre: np.ndarray
    em_pre: np.ndarray
    ew: np.ndarray
    mat_pre: np.ndarray


class Chains(NamedTuple):
    """The chains that continue along a delta lobe (rows written by
    :func:`hit_kernel`): k (n,) int64 row in the wavefront; p, ng, ns, wo
    (n, 3) float64 (normals as the mesh has them); mat (n,) int32; colors
    (n, L, 3); beta (n, 3) throughput before the lobe; plen (n,); p_delta (n,);
    u (n, 3) the uniforms of the lobe sample (ur[:, 1:4])."""
    k: np.ndarray
    p: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    wo: np.ndarray
    mat: np.ndarray
    colors: np.ndarray
    beta: np.ndarray
    plen: np.ndarray
    p_delta: np.ndarray
    u: np.ndarray


def build_camera_materials(mtab, scene) -> CameraMaterials:
    """The kernel's view of a ``MaterialTable`` and the scene's triangles."""
    used = mtab.kind >= 0
    col = mtab.color * mtab.weight[:, :, None]
    col[~used] = 0.0
    sel = np.ones(mtab.kind.shape) if mtab.sel_scale is None else mtab.sel_scale.astype(np.float64)
    sel = np.where(used, sel, 0.0)
    lam = (mtab.kind == DIFFUSE) & (mtab.roughness < DIFFUSE_ROUGHNESS_EPS)
    if mtab.layer_ior is not None:
        lam &= mtab.layer_ior <= 0.0
    c = np.ascontiguousarray
    return CameraMaterials(
        col=c(col), sel=c(sel), delta=c(mtab.lobe_delta, bool), lam=c(lam),
        nondelta=c(mtab.has_nondelta, bool), lambert_only=c(mtab.lambert_only, bool),
        emission=c(mtab.emission, np.float64), tri_mat=c(scene.tri_mat, np.int32),
        tri_p=c(np.asarray(scene.tri_p, np.float64).reshape(-1, 3, 3)),
        tri_n=c(np.asarray(scene.tri_n, np.float64).reshape(-1, 3, 3)))


def alloc_chains(K: int, L: int) -> Chains:
    """Buffers for up to K continuing chains."""
    return Chains(k=np.empty(K, np.int64), p=np.empty((K, 3)), ng=np.empty((K, 3)),
                  ns=np.empty((K, 3)), wo=np.empty((K, 3)), mat=np.empty(K, np.int32),
                  colors=np.empty((K, L, 3)), beta=np.empty((K, 3)), plen=np.empty(K),
                  p_delta=np.empty(K), u=np.empty((K, 3)))


@njit(cache=True, nogil=True, error_model="numpy")
def hit_kernel(i0, i1, u0, out0, first_vertex, last_vertex, wf, mats, vp, fb, ch):
    """Rays i0..i1-1 of the Wavefront wf; continuing chains to rows out0.. of
    Chains ch.  u0: the row of wf.ur of the first hit at or after i0 (one row
    per hit, in ray order).  first_vertex: record FirstBuffers (depth 0);
    last_vertex: no delta continuation (max_depth reached).  Returns the
    chains written."""
    prim, bu, bv, tfar = wf.prim, wf.bu, wf.bv, wf.tfar
    tri_p, tri_n, tri_mat = mats.tri_p, mats.tri_n, mats.tri_mat
    m_col, m_sel, m_delta, m_lam = mats.col, mats.sel, mats.delta, mats.lam
    L = m_col.shape[1]
    n = out0
    ui = u0
    for i in range(i0, i1):
        t = prim[i]
        if t < 0:
            continue
        q = wf.idx[i]
        ui += 1
        uu = np.float64(bu[i])
        vv = np.float64(bv[i])
        w0 = 1.0 - uu - vv
        # accel.surface_point, per hit and in the same order.
        px = w0 * tri_p[t, 0, 0] + uu * tri_p[t, 1, 0] + vv * tri_p[t, 2, 0]
        py = w0 * tri_p[t, 0, 1] + uu * tri_p[t, 1, 1] + vv * tri_p[t, 2, 1]
        pz = w0 * tri_p[t, 0, 2] + uu * tri_p[t, 1, 2] + vv * tri_p[t, 2, 2]
        e1x = tri_p[t, 1, 0] - tri_p[t, 0, 0]
        e1y = tri_p[t, 1, 1] - tri_p[t, 0, 1]
        e1z = tri_p[t, 1, 2] - tri_p[t, 0, 2]
        e2x = tri_p[t, 2, 0] - tri_p[t, 0, 0]
        e2y = tri_p[t, 2, 1] - tri_p[t, 0, 1]
        e2z = tri_p[t, 2, 2] - tri_p[t, 0, 2]
        gx = e1y * e2z - e1z * e2y
        gy = e1z * e2x - e1x * e2z
        gz = e1x * e2y - e1y * e2x
        gl = max(np.sqrt(gx * gx + gy * gy + gz * gz), 1e-300)
        gx /= gl
        gy /= gl
        gz /= gl
        sx = w0 * tri_n[t, 0, 0] + uu * tri_n[t, 1, 0] + vv * tri_n[t, 2, 0]
        sy = w0 * tri_n[t, 0, 1] + uu * tri_n[t, 1, 1] + vv * tri_n[t, 2, 1]
        sz = w0 * tri_n[t, 0, 2] + uu * tri_n[t, 1, 2] + vv * tri_n[t, 2, 2]
        sl = np.sqrt(sx * sx + sy * sy + sz * sz)
        if sl > 1e-12:
            sl = max(sl, 1e-300)
            sx /= sl
            sy /= sl
            sz /= sl
        else:
            sx, sy, sz = gx, gy, gz
        wox, woy, woz = -wf.d[i, 0], -wf.d[i, 1], -wf.d[i, 2]
        r = wf.pre[i]
        m = tri_mat[t] if r < 0 else wf.mat_pre[r]
        b0, b1, b2 = wf.beta[i, 0], wf.beta[i, 1], wf.beta[i, 2]
        if r >= 0:
            e0, e1, e2 = wf.em_pre[r, 0], wf.em_pre[r, 1], wf.em_pre[r, 2]
        else:
            e0, e1, e2 = mats.emission[m, 0], mats.emission[m, 1], mats.emission[m, 2]
        ew = wf.ew[i]
        fb.L[q, 0] += b0 * e0 * ew
        fb.L[q, 1] += b1 * e1 * ew
        fb.L[q, 2] += b2 * e2 * ew
        # Cycles flips both normals to wo's side of the geometric one.
        sgn = 1.0 if gx * wox + gy * woy + gz * woz >= 0.0 else -1.0
        if first_vertex and fb.p.shape[0] > 0:    # 0 rows: CameraPass.first_data off
            fb.hit[q] = True
            fb.p[q, 0], fb.p[q, 1], fb.p[q, 2] = px, py, pz
            fb.n[q, 0], fb.n[q, 1], fb.n[q, 2] = sx * sgn, sy * sgn, sz * sgn
            fb.prim[q] = t
            fb.emit[q, 0] += e0
            fb.emit[q, 1] += e1
            fb.emit[q, 2] += e2
        plen = wf.plen[i] + np.float64(tfar[i])
        # delta_probability: luminance-weighted lobe choice.
        tot = 0.0
        wd = 0.0
        for j in range(L):
            if r >= 0:
                c0, c1, c2 = wf.colors_pre[r, j, 0], wf.colors_pre[r, j, 1], wf.colors_pre[r, j, 2]
            else:
                c0, c1, c2 = m_col[m, j, 0], m_col[m, j, 1], m_col[m, j, 2]
            w = max(c0 * _LUM0 + c1 * _LUM1 + c2 * _LUM2, 0.0) * m_sel[m, j]
            tot += w
            if m_delta[m, j]:
                wd += w
        p_delta = wd / tot if tot > 0.0 else 0.0
        go_delta = (wf.ur[ui - 1, 0] < p_delta) and not last_vertex
        if not go_delta and mats.nondelta[m]:
            # The visible point: the chain's first non-delta vertex (pbrt-v4
            # SPPM), throughput over the probability of not choosing a delta lobe.
            vp.valid[q] = True
            vp.through_delta[q] = not first_vertex
            vp.front[q] = sgn > 0.0
            vp.p[q, 0], vp.p[q, 1], vp.p[q, 2] = px, py, pz
            vp.ng[q, 0], vp.ng[q, 1], vp.ng[q, 2] = gx * sgn, gy * sgn, gz * sgn
            vp.ns[q, 0], vp.ns[q, 1], vp.ns[q, 2] = sx * sgn, sy * sgn, sz * sgn
            vp.wo[q, 0], vp.wo[q, 1], vp.wo[q, 2] = wox, woy, woz
            vp.mat[q] = m
            inv = max(1.0 - p_delta, 1e-12)
            vp.beta[q, 0], vp.beta[q, 1], vp.beta[q, 2] = b0 / inv, b1 / inv, b2 / inv
            vp.depth[q] = plen * abs(wf.dz[i])
            vp.const[q] = mats.lambert_only[m]
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for j in range(L):
                if r >= 0:
                    c0, c1, c2 = (wf.colors_pre[r, j, 0], wf.colors_pre[r, j, 1],
                                  wf.colors_pre[r, j, 2])
                else:
                    c0, c1, c2 = m_col[m, j, 0], m_col[m, j, 1], m_col[m, j, 2]
                vp.colors[q, j, 0], vp.colors[q, j, 1], vp.colors[q, j, 2] = c0, c1, c2
                if m_lam[m, j]:
                    a0 += c0
                    a1 += c1
                    a2 += c2
                else:
                    a0 += 0.0 * c0
                    a1 += 0.0 * c1
                    a2 += 0.0 * c2
            vp.albedo[q, 0], vp.albedo[q, 1], vp.albedo[q, 2] = a0, a1, a2
        if go_delta and p_delta > 0.0:
            ch.k[n] = i
            ch.p[n, 0], ch.p[n, 1], ch.p[n, 2] = px, py, pz
            ch.ng[n, 0], ch.ng[n, 1], ch.ng[n, 2] = gx, gy, gz
            ch.ns[n, 0], ch.ns[n, 1], ch.ns[n, 2] = sx, sy, sz
            ch.wo[n, 0], ch.wo[n, 1], ch.wo[n, 2] = wox, woy, woz
            ch.mat[n] = m
            for j in range(L):
                for c in range(3):
                    if r >= 0:
                        ch.colors[n, j, c] = wf.colors_pre[r, j, c]
                    else:
                        ch.colors[n, j, c] = m_col[m, j, c]
            ch.beta[n, 0], ch.beta[n, 1], ch.beta[n, 2] = b0, b1, b2
            ch.plen[n] = plen
            ch.p_delta[n] = p_delta
            ch.u[n, 0], ch.u[n, 1], ch.u[n, 2] = wf.ur[ui - 1, 1], wf.ur[ui - 1, 2], wf.ur[ui - 1, 3]
            n += 1
    return n - out0
