"""Compiled connection of light-path vertices to the camera (integrators LIGHT, COMBINED).

``LightTracer.connect`` joins every deposit of a light path to a lens point
and splats it (core.integrators.light_tracer: the derivation).  Here that is
two numba loops around one batched Embree occlusion call:

    project_kernel   the camera projection (core.scene.camera.CameraModel.
                     project, per point), the render-region test, the
                     shadow ray (accel.spawn, the near-clip t_max)
    (Embree)         LightTracer._transmittance: every shadow ray of the batch
    splat_fast       for the unoccluded vertices on LAMBERT materials and
                     on the GENERIC ones the photon tracer samples compiled
                     (Blender's default Principled BSDF, rough glossy and
                     glass, Oren-Nayar), colour-textured ones included
                     (each connection's colour row: LightTracer.connect):
                     f towards the lens, the shading factor, the MIS weight
                     of 'COMBINED' (combined.splat_weight, with the
                     closed-form diffuse density or
                     ``compiled.pdf_oriented``) and the splat

Vertices on other materials (Normal Map / Bump, alpha textures, ...) are
evaluated by ``LightTracer._slow`` on their rows.
tests/test_light_kernels.py checks both loops against the numpy path
(CameraModel.project, eval_bsdf, pdf_bsdf, combined.splat_weight).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..lights.direct_kernels import _spherical_rect_solid_angle, spread_rect
# compiled.eval_pair and pdf_oriented are compiled into these kernels and
# numba's cache is stamped by this file: edited with the microfacet lobes'
# geometric side test and the Normal Map / Bump density of round 27, and
# the colour row of round 28, and the BSDF evaluation's lobe helpers and
# reference counts of round 32, and the view factor of round 40, and the
# displacement bump's code of round 45 (F_BUMP 2: no bump shadowing), and
# the conductor Fresnel of round 46 (F_K, compiled._fresnel_rgb) and
# thin film (F_FILM_D, F_FILM_N), and the one-signature entry points of
# round 50 (compiled._eval_pair_as).
from ..materials.compiled import eval_pair, pdf_oriented
from ..lights.table import AREA, POINT
from ..scene.camera import (BH_A0, BH_A1, BH_A2, BH_A3, FILTER_TYPES, GAUSS_INTEGRAL,
                            filter_support)
from ..sppm.photon_kernels import _offset_scale, lambert_pdf, shading_normal
from .merge_kernels import pixel_row

_INV_PI = 1.0 / np.pi
_INV_4PI = 1.0 / (4.0 * np.pi)

#: Cap of the shading-normal factor, as the photon gather's.
SHADING_CAP = 4.0


#: The splat's filter codes: core.scene.camera.FILTER_TYPES, and a box of
#: one pixel (weight 1) for a width <= 0.
BH, BOX, GAUSS, PIXEL = 0, 1, 2, -1


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _support(width, kind):
    """(code, half support R, normalisation) of the splat's filter
    (core.scene.camera.filter_support and filter_integral)."""
    if width <= 0.0:
        return PIXEL, 0.5, 1.0
    if kind == BOX:
        return BOX, 0.5 * width, 1.0 / width
    if kind == GAUSS:
        return GAUSS, 1.5 * width, 1.0 / (width * GAUSS_INTEGRAL)   # camera.filter_integral
    return BH, width, 1.0 / (2.0 * width * BH_A0)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _taps(x, a, b, w, r, norm, code, out, o):
    """out[o + k] = the normalised 1D pixel filter at offset x - (a + k + 0.5)
    [px] for the pixels a..b (core.scene.camera.filter_weight, compiled):
    of width w and half support r (:func:`_support`).  Blackman-Harris:
    cos 2v and cos 3v by the Chebyshev recurrence from cos v, and cos v of
    the next pixel by the rotation by the pixel step pi / w: one cos and
    one sin per splat axis instead of three cosines per tap (the splat's
    main cost); equal to filter_weight up to float rounding (~5e-16 of the
    filter's peak)."""
    if code == PIXEL:
        for k in range(b - a + 1):
            out[o + k] = 1.0 if abs(x - (a + k + 0.5)) < 0.5 else 0.0
        return
    if code == BOX or code == GAUSS:
        for k in range(b - a + 1):
            d = x - (a + k + 0.5)
            if abs(d) >= r:
                out[o + k] = 0.0
            elif code == BOX:
                out[o + k] = norm
            else:
                out[o + k] = np.exp(-8.0 * (d / w) * (d / w)) * norm
        return
    v = 2.0 * np.pi * ((x - (a + 0.5)) / (2.0 * w) + 0.5)
    c = np.cos(v)
    s = np.sin(v)
    cd = np.cos(np.pi / w)
    sd = np.sin(np.pi / w)
    for k in range(b - a + 1):
        if abs(x - (a + k + 0.5)) >= w:
            out[o + k] = 0.0
        else:
            c2 = 2.0 * c * c - 1.0
            c3 = (2.0 * c2 - 1.0) * c
            out[o + k] = max(BH_A0 - BH_A1 * c + BH_A2 * c2 - BH_A3 * c3, 0.0) * norm
        # the next pixel's phase: v - pi / w
        c, s = c * cd + s * sd, s * cd - c * sd


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _scratch(width, kind):
    """_splat_one's scratch for the column and row weights."""
    r = _support(width, kind)[1]
    return np.empty(2 * (int(2.0 * r) + 3))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _splat_one(x, y, c0, c1, c2, x0, y0, W, H, width, kind, film, fx):
    """Add (c0, c1, c2) at film position (x, y) (full-frame pixels, y up) to
    film (H*W, 3) (row 0 at the TOP of the region x0..x0+W-1, y0..y0+H-1),
    weighted by the normalised separable pixel filter of width ``width``
    and code ``kind`` (BH, BOX, GAUSS: core.scene.camera.filter_weight); a
    box of one pixel when width <= 0.  fx: scratch (:func:`_scratch`) for
    the column and row weights (each evaluated once, :func:`_taps`)."""
    code, r, norm = _support(width, kind)
    ia = int(np.ceil(x - r - 0.5))
    ib = int(np.floor(x + r - 0.5))
    ja = int(np.ceil(y - r - 0.5))
    jb = int(np.floor(y + r - 0.5))
    if ib < x0 or ia >= x0 + W or jb < y0 or ja >= y0 + H:
        return
    i0 = max(ia, x0)
    i1 = min(ib, x0 + W - 1)
    j0 = max(ja, y0)
    j1 = min(jb, y0 + H - 1)
    oy = fx.shape[0] // 2
    _taps(x, i0, i1, width, r, norm, code, fx, 0)
    _taps(y, j0, j1, width, r, norm, code, fx, oy)
    for j in range(j0, j1 + 1):
        fy = fx[oy + j - j0]
        if fy == 0.0:
            continue
        row = (H - 1 - (j - y0)) * W
        for i in range(i0, i1 + 1):
            wgt = fx[i - i0] * fy
            if wgt == 0.0:
                continue
            q = row + (i - x0)
            film[q, 0] += wgt * c0
            film[q, 1] += wgt * c1
            film[q, 2] += wgt * c2


@njit(cache=True, nogil=True, error_model="numpy")
def splat_kernel(raster, contrib, x0, y0, W, H, width, kind, film):
    """Add contrib (K, 3) at film positions raster (K, 2) to film (H*W, 3)
    (:func:`_splat_one`)."""
    fx = _scratch(width, kind)
    for k in range(raster.shape[0]):
        _splat_one(raster[k, 0], raster[k, 1], contrib[k, 0], contrib[k, 1], contrib[k, 2],
                   x0, y0, W, H, width, kind, film, fx)


class CameraParams(NamedTuple):
    """The camera of ``CameraModel.project`` and the render region, as scalars.

    R (3, 3) camera-to-world rotation (columns: camera axes), origin (3,);
    xmin, ymin, pix, ycor: the film mapping; clip_start, clip_end; aperture
    (lens radius, 0 = pinhole), focus (focus distance); ortho; A_pix, A_lens;
    the region x0, y0, W, H [px] and its margin w = max(the pixel filter's
    half support, 0.5) (camera.filter_support);
    fk the pixel filter's code (core.scene.camera.FILTER_TYPES)."""
    R: np.ndarray
    origin: np.ndarray
    xmin: float
    ymin: float
    pix: float
    ycor: float
    clip_start: float
    clip_end: float
    aperture: float
    focus: float
    ortho: bool
    A_pix: float
    A_lens: float
    x0: int
    y0: int
    W: int
    H: int
    w: float
    fk: int


def camera_params(model, x0, y0, W, H, filter_width, filter_type="BLACKMAN_HARRIS"
                  ) -> CameraParams:
    c = model.cam
    ortho = c.kind == "ORTHO"
    return CameraParams(np.ascontiguousarray(model.R, np.float64),
                        np.ascontiguousarray(model.origin, np.float64),
                        float(model.xmin), float(model.ymin), float(model.pix),
                        float(model.ycor), float(c.clip_start), float(c.clip_end),
                        0.0 if ortho else float(c.aperture_radius), float(c.focus_distance),
                        bool(ortho), float(model.pixel_area), float(model.lens_area),
                        int(x0), int(y0), int(W), int(H),
                        max(filter_support(filter_width, filter_type), 0.5),
                        FILTER_TYPES[filter_type])


def _bent(scene, mtab, M) -> np.ndarray:
    """(M,) bool: materials whose shading normal is not the interpolated one
    (Normal Map / Bump)."""
    from ..scene import normals
    bent = np.zeros(M, bool)
    if mtab.bump_correction is not None:
        bent |= np.asarray(mtab.bump_correction, bool)[:M]
    spec = normals.attached(scene.tri_n)
    if spec is not None:
        for m, inp in enumerate(spec.inputs[:M]):
            bent[m] |= inp is not None
    return bent


#: SplatMaterials.kind: left to LightTracer._slow, f = col / pi, or the
#: compiled GENERIC BSDF.
SLOW, LAMBERT_SPLAT, GENERIC_SPLAT = 0, 1, 2


class SplatMaterials(NamedTuple):
    """Per-material data of :func:`splat_fast` (M materials, L lobe slots):
    kind (M,) int8 (SLOW, LAMBERT_SPLAT, GENERIC_SPLAT); lobes (M', L,
    N_FIELDS), tables (N_TABLES,) the compiled BSDF (1-material
    placeholders when no material is GENERIC_SPLAT).  Per colour row (M
    rows, the materials' untextured colours, then one per connection on a
    colour-textured material: ``LightTracer.connect``, as the camera paths'
    ``path_kernels.PathMaterials``): col (R, 3) the Lambert colour (the sum
    of the lobe colours), colors (R, L, 3) and p (R, L) the
    SelectionTable's lobe colours and selection probabilities."""
    kind: np.ndarray
    col: np.ndarray
    lobes: np.ndarray
    tables: np.ndarray
    colors: np.ndarray
    p: np.ndarray


def splat_materials(scene, mtab, fmat, textured, sel=None) -> SplatMaterials:
    """The SplatMaterials of a scene: LAMBERT_SPLAT the LAMBERT materials
    (materials.fast: diffuse lobes of roughness 0), GENERIC_SPLAT the
    ``compiled`` GENERIC ones, each whose shading normal is the interpolated
    one (no Normal Map / Bump); of the colour-textured ones (textured (M,)
    bool: no alpha texture), the Lambert-only ones LAMBERT_SPLAT and the
    others GENERIC_SPLAT (their colour rows come per connection); sel the
    table's ``compiled.selection_table`` (made here when None and needed)."""
    from ..materials import fast, rough_maps
    from ..materials.compiled import compile_materials, selection_table
    from ..materials.hit_colors import textured_lambert
    M = fmat.cls.shape[0]
    bent = _bent(scene, mtab, M)
    kind = np.where((fmat.cls == fast.LAMBERT) & ~bent, LAMBERT_SPLAT, SLOW)
    if fmat.compiled is not None:
        kind = np.where(np.asarray(fmat.compiled, bool) & ~bent, GENERIC_SPLAT, kind)
    tex = np.asarray(textured, bool) & ~bent & (fmat.cls == fast.GENERIC) & fast.COMPILED_SAMPLING
    tex &= ~rough_maps.mapped(mtab)     # SLOW: numpy picks their roughness level
    lam = tex & textured_lambert(mtab)
    kind = np.where(lam, LAMBERT_SPLAT, np.where(tex, GENERIC_SPLAT, kind))
    cm = compile_materials(mtab) if np.any(tex & ~lam) else fmat.cm
    if tex.any():
        sel = selection_table(mtab) if sel is None else sel
    else:
        sel = fmat.sel
    c = np.ascontiguousarray
    return SplatMaterials(kind=c(kind, np.int8), col=c(fmat.col, np.float64),
                          lobes=c(cm.lobes, np.float64), tables=c(cm.tables, np.float64),
                          colors=c(sel.colors, np.float64), p=c(sel.p, np.float64))


class Connections(NamedTuple):
    """The candidate connections of one batch (rows 0..n-1 used): row (K,)
    int64 the vertex, raster (K, 2), wc (K, 3) unit towards the lens, weight
    (K,) ``CameraProjection.weight``; the shadow rays o (K, 3), t_max (K,)."""
    row: np.ndarray
    raster: np.ndarray
    wc: np.ndarray
    weight: np.ndarray
    o: np.ndarray
    t_max: np.ndarray


def connections(K: int) -> Connections:
    return Connections(np.empty(K, np.int64), np.empty((K, 2)), np.empty((K, 3)), np.empty(K),
                       np.empty((K, 3)), np.empty(K))


@njit(cache=True, nogil=True, error_model="numpy")
def project_kernel(cam, p, ng, u_lens, rel, floor, out):
    """CameraModel.project of the points p (K, 3) through the lens points of
    u_lens (K, 2), kept when in front (clip range, cos > 0) and within the
    region's margin; their shadow rays from p offset along ng (K, 3) to the
    lens side (accel.spawn), t_max shortened to the near clip plane (the
    camera ray starts there).  Writes rows 0..n-1 of the Connections out;
    returns n."""
    R, org = cam.R, cam.origin
    n = 0
    for k in range(p.shape[0]):
        qx, qy, qz = p[k, 0] - org[0], p[k, 1] - org[1], p[k, 2] - org[2]
        cx = qx * R[0, 0] + qy * R[1, 0] + qz * R[2, 0]
        cy = qx * R[0, 1] + qy * R[1, 1] + qz * R[2, 1]
        cz = qx * R[0, 2] + qy * R[1, 2] + qz * R[2, 2]
        depth = -cz
        if not (depth >= cam.clip_start and depth <= cam.clip_end):
            continue
        lx = 0.0
        ly = 0.0
        if cam.ortho:
            xs, ys = cx, cy
            lx, ly = cx, cy
        else:
            dep = depth if depth > 0.0 else 1.0
            if cam.aperture > 0.0:
                r = cam.aperture * np.sqrt(u_lens[k, 0])
                phi = 2.0 * np.pi * u_lens[k, 1]
                lx, ly = r * np.cos(phi), r * np.sin(phi)
                fd = cam.focus
                s = fd / dep
                xs = (lx + (cx - lx) * s) / fd
                ys = (ly + (cy - ly) * s) / fd
            else:
                xs, ys = cx / dep, cy / dep
        rx = (xs - cam.xmin) / cam.pix
        ry = (ys - cam.ymin) / (cam.ycor * cam.pix)
        vx, vy, vz = lx - cx, ly - cy, -cz
        dist = np.sqrt(vx * vx + vy * vy + vz * vz)
        if not dist > 0.0:
            continue
        cos = vz / dist
        if not cos > 0.0:
            continue
        w = cam.w
        if not (rx > cam.x0 - w and rx < cam.x0 + cam.W + w and ry > cam.y0 - w
                and ry < cam.y0 + cam.H + w):
            continue
        vx /= dist
        vy /= dist
        vz /= dist
        wx = vx * R[0, 0] + vy * R[0, 1] + vz * R[0, 2]
        wy = vx * R[1, 0] + vy * R[1, 1] + vz * R[1, 2]
        wz = vx * R[2, 0] + vy * R[2, 1] + vz * R[2, 2]
        if cam.ortho:
            weight = 1.0 / cam.A_pix
        else:
            weight = 1.0 / (cam.A_pix * cos * cos * cos * dist * dist)
        out.row[n] = k
        out.raster[n, 0], out.raster[n, 1] = rx, ry
        out.wc[n, 0], out.wc[n, 1], out.wc[n, 2] = wx, wy, wz
        out.weight[n] = weight
        px, py, pz = p[k, 0], p[k, 1], p[k, 2]
        gx, gy, gz = ng[k, 0], ng[k, 1], ng[k, 2]
        side = 1.0 if gx * wx + gy * wy + gz * wz >= 0.0 else -1.0
        sc = side * _offset_scale(px, py, pz, rel, floor)
        out.o[n, 0], out.o[n, 1], out.o[n, 2] = px + gx * sc, py + gy * sc, pz + gz * sc
        out.t_max[n] = dist * (depth - cam.clip_start) / max(depth, 1e-300)
        n += 1
    return n


class SplatInputs(NamedTuple):
    """Per-vertex data of :func:`splat_fast` (K vertices): bary (K, 3)
    (prim, u, v); wi (K, 3) unit back along the light path; power (K, 3);
    B0, B1 (K,) the light side's MIS ratios, first (K,) bool the first hit,
    soft (K,) bool a soft light's path ('COMBINED'; unused when not mis)."""
    bary: np.ndarray
    wi: np.ndarray
    power: np.ndarray
    B0: np.ndarray
    B1: np.ndarray
    first: np.ndarray
    soft: np.ndarray
    # Merging as an MIS strategy (core.integrators.merge): (P,) (N_M / N_L)
    # pi r^2 by pixel of the region, the factor of q_M / q_L = that x c_1 at
    # the splatted vertex (not a first hit); size 0 = no merging term.
    mR2: np.ndarray = np.zeros(0)


@njit(cache=True, nogil=True, error_model="numpy")
def splat_fast(con, n, tr, vin, tri_n, tri_ng, tri_mat, sm, crow, mis, cam, width, film,
               slow):
    """Splat the unoccluded connections 0..n-1 (tr (n, 3): their
    transmittance to the lens, core.lights.shadow; 0 = blocked) of
    vertices on materials the SplatMaterials sm evaluate, each with the
    colour row r = crow[c] (n,) (or its material's when crow is empty)
    (LAMBERT_SPLAT: f = col[r] / pi where the shading normal, flipped to
    the lens side of
    ng, faces wi; GENERIC_SPLAT: Cycles' f(view = wc, light = wi) by
    ``compiled.eval_pair``) into film (H*W, 3): beta f |ng.wc|
    min(|ns.wi| / |ng.wi|, SHADING_CAP) weight, times the power-heuristic
    weight 1 / (1 + (B0 pf c_1)^2 + (B1 pf c_1)^2) when mis
    (combined.splat_weight: pf the density of sampling wi from wc, the
    diffuse one or ``compiled.pdf_oriented``, c_1 = |ng.wc| weight; soft:
    no B0 term; first: B1 without pf).  Non-finite contributions are
    dropped (LightTracer._splat).  The indices of the other unoccluded
    connections go to slow; returns their number."""
    ns_ = 0
    fx = _scratch(width, cam.fk)
    kinds, col, lobes, T, cols, sp = sm.kind, sm.col, sm.lobes, sm.tables, sm.colors, sm.p
    for c in range(n):
        if tr[c, 0] == 0.0 and tr[c, 1] == 0.0 and tr[c, 2] == 0.0:
            continue
        k = con.row[c]
        t = int(vin.bary[k, 0])
        m = tri_mat[t]
        kind = kinds[m]
        if kind == SLOW:
            slow[ns_] = c
            ns_ += 1
            continue
        r = crow[c] if crow.shape[0] > 0 else m
        uu = vin.bary[k, 1]
        vv = vin.bary[k, 2]
        gx, gy, gz = tri_ng[t, 0], tri_ng[t, 1], tri_ng[t, 2]
        sx, sy, sz = shading_normal(tri_n, t, 1.0 - uu - vv, uu, vv, gx, gy, gz)
        ox, oy, oz = con.wc[c, 0], con.wc[c, 1], con.wc[c, 2]
        ix, iy, iz = vin.wi[k, 0], vin.wi[k, 1], vin.wi[k, 2]
        if kind == LAMBERT_SPLAT:
            # materials.eval_bsdf (radiance mode, view = wc): normals to wc's side of ng.
            sg = 1.0 if gx * ox + gy * oy + gz * oz >= 0.0 else -1.0
            if sg * (sx * ix + sy * iy + sz * iz) <= 0.0:
                continue
            f0, f1, f2 = col[r, 0], col[r, 1], col[r, 2]
            scale = _INV_PI
        else:
            f = eval_pair(lobes, T, m, cols, r, sx, sy, sz, gx, gy, gz, ox, oy, oz, ix, iy, iz,
                          False)
            f0, f1, f2 = f[0], f[1], f[2]
            if f0 == 0.0 and f1 == 0.0 and f2 == 0.0:
                continue
            scale = 1.0
        cg = abs(gx * ix + gy * iy + gz * iz)
        corr = abs(sx * ix + sy * iy + sz * iz) / cg if cg > 0.0 else 0.0
        corr = min(corr, SHADING_CAP)
        c1 = abs(gx * ox + gy * oy + gz * oz) * con.weight[c]
        g = c1 * corr * scale
        if mis:
            if kind == LAMBERT_SPLAT:
                pf = lambert_pdf(sx, sy, sz, gx, gy, gz, ox, oy, oz, ix, iy, iz)
            else:
                pf = pdf_oriented(lobes, sp, m, r, sx, sy, sz, gx, gy, gz, ox, oy, oz, ix, iy, iz)
            b0 = 0.0 if vin.soft[k] else vin.B0[k] * pf * c1
            b1 = vin.B1[k] * c1 * (1.0 if vin.first[k] else pf)
            den = 1.0 + b0 * b0 + b1 * b1
            if vin.mR2.shape[0] > 0 and not vin.first[k]:
                bm = vin.mR2[pixel_row(con.raster[c, 0], con.raster[c, 1], cam.x0, cam.y0,
                                       cam.W, cam.H)] * c1
                den += bm * bm
            wl = 1.0 / den
            if not np.isfinite(wl):
                wl = 0.0
            g *= wl
        c0 = f0 * vin.power[k, 0] * g * tr[c, 0]
        c1_ = f1 * vin.power[k, 1] * g * tr[c, 1]
        c2 = f2 * vin.power[k, 2] * g * tr[c, 2]
        if not (np.isfinite(c0) and np.isfinite(c1_) and np.isfinite(c2)):
            continue
        _splat_one(con.raster[c, 0], con.raster[c, 1], c0, c1_, c2, cam.x0, cam.y0, cam.W,
                   cam.H, width, cam.fk, film, fx)
    return ns_


@njit(cache=True, nogil=True, error_model="numpy")
def splat_emitters(con, n, tr, nrm, power, mis, kn, pA, full, cam, width, film):
    """Splat the unoccluded connections 0..n-1 (tr (n, 3): their
    transmittance, 0 = blocked) of emission vertices (emitting
    normals nrm (K, 3), flux power (K, 3); LightTracer._emission_vertices):
    f_s = 1 / pi on the emitting side, beta |n.wc| weight / pi, times the
    weight against path tracing when mis (combined.emission_splat_weight:
    1 / (1 + (kn c_1 / pA)^2), c_1 = |n.wc| weight; 0 unless full (K,))."""
    fx = _scratch(width, cam.fk)
    for c in range(n):
        if tr[c, 0] == 0.0 and tr[c, 1] == 0.0 and tr[c, 2] == 0.0:
            continue
        k = con.row[c]
        cos_o = nrm[k, 0] * con.wc[c, 0] + nrm[k, 1] * con.wc[c, 1] + nrm[k, 2] * con.wc[c, 2]
        if not cos_o > 0.0:
            continue
        c1 = cos_o * con.weight[c]
        g = c1 * _INV_PI
        if mis:
            if not full[k]:
                continue
            r = kn * c1 / pA[k]
            g *= 1.0 / (1.0 + r * r)
        c0 = power[k, 0] * g * tr[c, 0]
        c1_ = power[k, 1] * g * tr[c, 1]
        c2 = power[k, 2] * g * tr[c, 2]
        if not (np.isfinite(c0) and np.isfinite(c1_) and np.isfinite(c2)):
            continue
        _splat_one(con.raster[c, 0], con.raster[c, 1], c0, c1_, c2, cam.x0, cam.y0, cam.W,
                   cam.H, width, cam.fk, film, fx)

class FirstHitLights(NamedTuple):
    """The emitters' arrays of :func:`first_hits` (Nl rows, float64 unless
    stated): kind (Nl,) int8; co, dir, axis_u, axis_v (Nl, 3); len_u, len_v,
    area (Nl,); rect (Nl,) bool an AREA rectangle (not an ellipse); p_emit
    (Nl,) the emission selection probability (mis.emit_select); spread_sin2,
    spread_tan (Nl,) ``LightTable.spread_sin2``, ``spread_tan``."""
    kind: np.ndarray
    co: np.ndarray
    dir: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    len_u: np.ndarray
    len_v: np.ndarray
    area: np.ndarray
    rect: np.ndarray
    p_emit: np.ndarray
    spread_sin2: np.ndarray
    spread_tan: np.ndarray


def first_hit_lights(table, p_emit) -> FirstHitLights:
    c = np.ascontiguousarray
    return FirstHitLights(c(table.kind, np.int8), c(table.co, np.float64),
                          c(table.dir, np.float64), c(table.axis_u, np.float64),
                          c(table.axis_v, np.float64), c(table.len_u, np.float64),
                          c(table.len_v, np.float64), c(table.area, np.float64),
                          c((table.kind == AREA) & ~np.asarray(table.ellipse, bool)),
                          c(p_emit, np.float64), c(table.spread_sin2, np.float64),
                          c(table.spread_tan, np.float64))


@njit(cache=True, nogil=True, error_model="numpy")
def first_hits(fl, kn, p, ng, d, z0, light, sel, b0, b1):
    """combined.first_hit_ratios for first hits p (n, 3) (geometric normals
    ng, arrival directions d, emitter points z0 (n, 3), emitter rows light
    (n,), next-event selection probabilities sel (n,) of those rows at p:
    lights.pdf._selection_probability) from POINT emitters (radius 0 or
    soft: the centre) and AREA rectangles; b0, b1 (n,) out.  Rows of other
    emitters are left NaN for the caller.  The rectangle's next-event
    density is pdf_direct's: 1 / S of the spherical rectangle
    (direct_kernels._spherical_rect_solid_angle) where S > 1e-6, else by area, 0 behind
    the light."""
    kind, co, ldir, au, av = fl.kind, fl.co, fl.dir, fl.axis_u, fl.axis_v
    len_u, len_v, area, rect, p_emit = fl.len_u, fl.len_v, fl.area, fl.rect, fl.p_emit
    for i in range(p.shape[0]):
        j = light[i]
        point = kind[j] == POINT
        b0[i] = np.nan
        b1[i] = np.nan
        if not (point or rect[j]):
            continue
        px, py, pz = p[i, 0], p[i, 1], p[i, 2]
        wx, wy, wz = px - z0[i, 0], py - z0[i, 1], pz - z0[i, 2]
        dz = np.sqrt(wx * wx + wy * wy + wz * wz)
        s = max(dz, 1e-300)
        wx /= s
        wy /= s
        wz /= s
        cos_z = abs(ng[i, 0] * wx + ng[i, 1] * wy + ng[i, 2] * wz)
        if point:
            x0 = 0.0
            x1 = kn * sel[i] / p_emit[j] * dz * dz / (_INV_4PI * cos_z)
        else:
            nx, ny, nz = ldir[j, 0], ldir[j, 1], ldir[j, 2]
            cos_l = abs(nx * d[i, 0] + ny * d[i, 1] + nz * d[i, 2])
            pA = p_emit[j] / area[j]
            cw = nx * wx + ny * wy + nz * wz
            s2 = fl.spread_sin2[j]
            # mis.emit_pdf_dir: cosine inside a spread's cone.
            pW = (max(cw, 0.0) * _INV_PI if s2 == 1.0 else
                  (cw / (np.pi * s2) if cw >= np.sqrt(1.0 - s2) else 0.0))
            front = ((px - co[j, 0]) * nx + (py - co[j, 1]) * ny + (pz - co[j, 2]) * nz) > 0
            res = dz * dz / max(area[j] * max(cw, 0.0), 1e-300) if cw > 0 else 0.0
            # pdf_direct's rectangle (a spread: the part it lets through to p).
            sx, sy, sz, lu, lv = spread_rect(
                fl.spread_tan[j], co[j, 0], co[j, 1], co[j, 2], nx, ny, nz, au[j, 0], au[j, 1],
                au[j, 2], len_u[j], av[j, 0], av[j, 1], av[j, 2], len_v[j], px, py, pz)
            S = _spherical_rect_solid_angle(px, py, pz, sx, sy, sz, au[j, 0], au[j, 1], au[j, 2],
                                            lu, av[j, 0], av[j, 1], av[j, 2], lv)
            if S > 1e-6:
                res = 1.0 / max(S, 1e-300)
            nee = (res if front else 0.0) * sel[i]
            if not np.isfinite(nee):
                nee = 0.0
            nee *= cos_l
            x0 = kn * cos_l / (pA * pW * cos_z)
            x1 = kn * nee / (pA * pW * cos_z)
        b0[i] = x0 if np.isfinite(x0) else 0.0
        b1[i] = x1 if np.isfinite(x1) else 0.0
