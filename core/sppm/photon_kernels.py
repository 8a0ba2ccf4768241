"""Compiled per-hit work of the photon pass (numba), between two Embree calls.

The numpy photon loop spends ~9x the Embree time on per-bounce array
bookkeeping (surface_point, lobe_colors, sample_bsdf, compaction), for 30
triangles and one Lambert material.  Here everything that happens after an
Embree call is one ``@njit(nogil=True)`` loop over the rays:

    barycentric p / ng / ns  ->  deposit (has_nondelta, bounce rule)
    ->  importance sampling of the common closures  ->  Russian roulette
    ->  spawn offset  ->  in-place compaction of the live photon state

Fast closures (``FastMaterials``; everything else is "generic" and handed back
to ``core.bsdf.sample_bsdf`` by the caller, photon by photon):

- LAMBERT: every used lobe is DIFFUSE with roughness 0, no texture, no delta
  lobe.  Cosine sampling; weight = sum of lobe colours x Veach's
  shading-normal factor (``bsdf.sample_bsdf`` fast path).
- MIRROR: a single used lobe, GLOSSY and delta (alpha^2 <= 2e-10), no texture.
- GLASS: a single used lobe, GLASS and delta (smooth, or |ior - 1| < 1e-4),
  no texture.  Reflect with probability F (exact dielectric Fresnel), weight
  C (/eta^2 on refraction, the importance-mode adjoint), x shading factor.

The formulas are those of ``core.bsdf`` (``_cos_hemisphere``, ``_frame``,
``fresnel_dielectric``, ``_refract``, ``_adjoint_correction``) written per ray
in float64; ``tests/test_photon_kernels.py`` checks the kernels sample for
sample against ``bsdf.sample_bsdf`` and the whole tracer against the numpy
path.  Precision: Embree sees float32 origins/directions; positions, normals,
powers and deposits are float64.

Emission (``emit_lights``, ``emit_lights_state``) is ``lights.sample_photons``
for POINT, AREA and untextured MESH emitters, fed the same uniforms (tested
equal to round-off); other kinds keep the numpy sampler (``emit_kernel`` then
only filters and offsets its photons).

Kernels use ``error_model="numpy"`` (x/0 gives inf/NaN like the numpy path,
no exception checks) and ``nogil=True`` (core.photons traces two halves of a
batch in two threads).  Per-photon helpers take scalars only: numba
increments and decrements the reference count of every array passed to a
non-inlined call, which cost ~100 ns per photon with 16 light arrays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..scene.model import GLASS, GLOSSY

# Fast-path classes of a material.
GENERIC = 0
LAMBERT = 1
MIRROR = 2
SMOOTH_GLASS = 3
ABSORBER = 4          # no lobe with a non-zero weight (e.g. emission only)

from ..mathutil import LUM_B as _LUM2, LUM_G as _LUM1, LUM_R as _LUM0  # noqa: E402


@dataclass
class FastMaterials:
    """Per-material data of the fast path.  M materials.

    cls: (M,) int8 GENERIC / LAMBERT / MIRROR / SMOOTH_GLASS / ABSORBER.
    col: (M, 3) float64 LAMBERT: sum of lobe colour x weight; MIRROR / GLASS:
      the lobe's colour x weight.
    ior: (M,) float64 GLASS index of refraction.
    deposit: (M,) bool material has a non-delta lobe (photons are stored).
    """
    cls: np.ndarray
    col: np.ndarray
    ior: np.ndarray
    deposit: np.ndarray

    @property
    def any_generic(self) -> bool:
        return bool(np.any(self.cls == GENERIC))


def build_fast_materials(mtab) -> FastMaterials:
    """Classify the materials of a ``bsdf.MaterialTable`` for the fast path."""
    M = mtab.kind.shape[0]
    cls = np.zeros(M, np.int8)
    col = np.zeros((M, 3))
    ior = np.ones(M)
    for m in range(M):
        kinds = mtab.kind[m]
        slots = [j for j in range(kinds.shape[0]) if kinds[j] >= 0]
        used = [j for j in slots if mtab.weight[m, j] != 0.0]
        if not used:
            cls[m] = ABSORBER           # bsdf.sample_bsdf: no lobe, invalid
            continue
        if any(mtab.tex[m, j] >= 0 for j in slots):
            continue
        cw = [mtab.color[m, j] * mtab.weight[m, j] for j in slots]
        if bool(mtab.lambert_only[m]) and not bool(mtab.has_delta[m]):
            # bsdf.sample_bsdf's Lambert fast path: weight = sum of all colours.
            cls[m] = LAMBERT
            col[m] = np.sum(cw, axis=0)
        elif len(used) == 1 and mtab.lobe_delta[m, used[0]]:
            j = used[0]
            if kinds[j] == GLOSSY:
                cls[m] = MIRROR
            elif kinds[j] == GLASS:
                cls[m] = SMOOTH_GLASS
                ior[m] = mtab.ior[m, j]
            else:
                continue
            col[m] = mtab.color[m, j] * mtab.weight[m, j]
    return FastMaterials(cls=cls, col=col, ior=ior,
                         deposit=np.asarray(mtab.has_nondelta, bool).copy())


@dataclass
class TriangleData:
    """Float64 per-triangle data for hit interpolation.  T triangles.

    p: (T, 3, 3) corners; n: (T, 3, 3) corner shading normals; ng: (T, 3) unit
    geometric normal (winding order, as ``accel.surface_point``); mat: (T,)
    int32 material index.
    """
    p: np.ndarray
    n: np.ndarray
    ng: np.ndarray
    mat: np.ndarray


def build_triangle_data(scene) -> TriangleData:
    P = np.ascontiguousarray(scene.tri_p, np.float64).reshape(-1, 3, 3)
    ng = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    return TriangleData(p=P, n=np.ascontiguousarray(scene.tri_n, np.float64).reshape(-1, 3, 3),
                        ng=np.ascontiguousarray(ng),
                        mat=np.ascontiguousarray(scene.tri_mat, np.int32))


# ----------------------------------------------------------------------------
# Per-ray helpers (inlined).

@njit(cache=True, inline="always")
def _offset_scale(px, py, pz, rel, floor):
    """accel.offset_scale: max(|p|_inf, floor) * rel, floor = abs_floor / rel."""
    m = max(abs(px), abs(py), abs(pz))
    return max(m, floor) * rel


@njit(cache=True, inline="always")
def _adjoint(nsx, nsy, nsz, ngx, ngy, ngz, wox, woy, woz, wix, wiy, wiz):
    """bsdf._adjoint_correction: |wo.ns||wi.ng| / (|wo.ng||wi.ns|)."""
    num = abs(wox * nsx + woy * nsy + woz * nsz) * abs(wix * ngx + wiy * ngy + wiz * ngz)
    den = abs(wox * ngx + woy * ngy + woz * ngz) * abs(wix * nsx + wiy * nsy + wiz * nsz)
    if den > 0.0:
        return num / den
    return 0.0


@njit(cache=True, error_model="numpy")
def sample_fast(cls, cr, cg, cb, ior, nsx, nsy, nsz, ngx, ngy, ngz, wox, woy, woz,
                u0, u1, u2):
    """Importance-mode sample of one fast-path closure (``bsdf.sample_bsdf``).

    ns, ng: unit shading / geometric normals (any orientation); wo: unit, the
    direction back towards where the photon came from; u0, u1 direction,
    u2 Fresnel choice.  Returns (wx, wy, wz, weight r, g, b, is_delta, ok);
    weight = 0 when not ok.
    """
    # Orient both normals to wo's side of the geometric normal (Cycles' back faces).
    front = ngx * wox + ngy * woy + ngz * woz >= 0.0
    s = 1.0 if front else -1.0
    Nx, Ny, Nz = nsx * s, nsy * s, nsz * s
    Gx, Gy, Gz = ngx * s, ngy * s, ngz * s
    lum = cr * _LUM0 + cg * _LUM1 + cb * _LUM2
    if cls == LAMBERT:
        # Shirley-Chiu concentric disk, lifted (bsdf._cos_hemisphere).
        a = 2.0 * u0 - 1.0
        b = 2.0 * u1 - 1.0
        if abs(a) > abs(b):
            r = a
            phi = (np.pi / 4) * (b / a)
        else:
            r = b
            if a == 0.0 and b == 0.0:
                phi = 0.0
            else:
                phi = np.pi / 2 - (np.pi / 4) * (a / b)
        lx = r * np.cos(phi)
        ly = r * np.sin(phi)
        lz = np.sqrt(max(0.0, 1.0 - lx * lx - ly * ly))
        # Tangent frame of N (Duff et al. 2017, bsdf._frame).
        sg = 1.0 if Nz >= 0.0 else -1.0
        aa = -1.0 / (sg + Nz)
        bb = Nx * Ny * aa
        tx, ty, tz = 1.0 + sg * Nx * Nx * aa, sg * bb, -sg * Nx
        bx, by, bz = bb, sg + Ny * Ny * aa, -Ny
        wx = lx * tx + ly * bx + lz * Nx
        wy = lx * ty + ly * by + lz * Ny
        wz = lx * tz + ly * bz + lz * Nz
        ok = (Gx * wx + Gy * wy + Gz * wz > 0.0) and lz > 0.0 and lum > 0.0
        if not ok:
            return wx, wy, wz, 0.0, 0.0, 0.0, False, False
        c = _adjoint(nsx, nsy, nsz, ngx, ngy, ngz, wox, woy, woz, wx, wy, wz)
        return wx, wy, wz, cr * c, cg * c, cb * c, False, True
    # Delta microfacet lobes: H = N.
    if not lum > 0.0:          # no lobe to select (bsdf: any_lobe False)
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False
    cI = wox * Nx + woy * Ny + woz * Nz
    hwo = cI
    refr = False
    wgt_scale = 1.0
    if cls == MIRROR:
        wx = 2.0 * hwo * Nx - wox
        wy = 2.0 * hwo * Ny - woy
        wz = 2.0 * hwo * Nz - woz
    else:
        eta = ior if front else 1.0 / ior
        # bsdf.fresnel_dielectric
        cc = abs(hwo)
        g2 = eta * eta - 1.0 + cc * cc
        if g2 <= 0.0:
            F = 1.0
            cos_t = 0.0
        else:
            g = np.sqrt(g2)
            A = (g - cc) / (g + cc)
            B = (cc * (g + cc) - 1.0) / (cc * (g - cc) + 1.0)
            F = 0.5 * A * A * (1.0 + B * B)
            cos_t = np.sqrt(max(0.0, 1.0 - (1.0 - cc * cc) / (eta * eta)))
        u_re = min(max(u2, 0.0), 1.0 - 1e-16)
        refr = u_re >= F
        if refr:
            inv = 1.0 / eta
            k = inv * hwo - cos_t
            wx = k * Nx - inv * wox
            wy = k * Ny - inv * woy
            wz = k * Nz - inv * woz
            wgt_scale = 1.0 / (eta * eta)   # adjoint of Cycles' unscaled BTDF
        else:
            wx = 2.0 * hwo * Nx - wox
            wy = 2.0 * hwo * Ny - woy
            wz = 2.0 * hwo * Nz - woz
    nrm = np.sqrt(wx * wx + wy * wy + wz * wz)
    if nrm > 0.0:
        wx /= nrm
        wy /= nrm
        wz /= nrm
    cN = Nx * wx + Ny * wy + Nz * wz
    cG = Gx * wx + Gy * wy + Gz * wz
    if refr:
        ok = cI > 0.0 and cN < 0.0 and cG < 0.0
    else:
        ok = cI > 0.0 and cN > 0.0 and cG > 0.0
    if not ok:
        return wx, wy, wz, 0.0, 0.0, 0.0, True, False
    c = _adjoint(nsx, nsy, nsz, ngx, ngy, ngz, wox, woy, woz, wx, wy, wz) * wgt_scale
    return wx, wy, wz, cr * c, cg * c, cb * c, True, True


@njit(cache=True)
def sample_fast_batch(cls, col, ior, ns, ng, wo, u):
    """Vectorised :func:`sample_fast` for tests: per-point class (K,) int,
    col (K, 3), ior (K,), ns, ng, wo (K, 3), u (K, 3).
    Returns wi (K, 3), weight (K, 3), is_delta (K,), ok (K,)."""
    K = cls.shape[0]
    wi = np.zeros((K, 3))
    wt = np.zeros((K, 3))
    dl = np.zeros(K, np.bool_)
    ok = np.zeros(K, np.bool_)
    for i in range(K):
        r = sample_fast(cls[i], col[i, 0], col[i, 1], col[i, 2], ior[i],
                        ns[i, 0], ns[i, 1], ns[i, 2], ng[i, 0], ng[i, 1], ng[i, 2],
                        wo[i, 0], wo[i, 1], wo[i, 2], u[i, 0], u[i, 1], u[i, 2])
        wi[i, 0], wi[i, 1], wi[i, 2] = r[0], r[1], r[2]
        wt[i, 0], wt[i, 1], wt[i, 2] = r[3], r[4], r[5]
        dl[i] = r[6]
        ok[i] = r[7]
    return wi, wt, dl, ok


# ----------------------------------------------------------------------------
# Emission and bounce kernels.

@njit(cache=True, nogil=True, error_model="numpy")
def emit_kernel(o, d, power, falloff, rel, floor, o32, d32, d64, pw, fo, src):
    """Keep photons with finite positive power; offset origins along d.

    o, d, power (n, 3) float64 from ``lights.sample_photons``, falloff (n,).
    Writes the K survivors to o32, d32 (float32, Embree input), d64, pw (power),
    fo (falloff r^2) and src (index in the input).  Returns K.
    """
    K = 0
    for i in range(o.shape[0]):
        p0, p1, p2 = power[i, 0], power[i, 1], power[i, 2]
        if not (np.isfinite(p0) and np.isfinite(p1) and np.isfinite(p2)):
            continue
        if not max(p0, p1, p2) > 0.0:
            continue
        sc = _offset_scale(o[i, 0], o[i, 1], o[i, 2], rel, floor)
        for c in range(3):
            o32[K, c] = o[i, c] + d[i, c] * sc
            d32[K, c] = d[i, c]
            d64[K, c] = d[i, c]
            pw[K, c] = power[i, c]
        fo[K] = falloff[i]
        src[K] = i
        K += 1
    return K


@njit(cache=True, nogil=True, error_model="numpy")
def bounce_kernel(K, prim, bu, bv, tfar, o32, d32, d64, pw, fo, first, store, sample,
                  roulette, tri_p, tri_n, tri_ng, tri_mat, m_cls, m_col, m_ior, m_dep,
                  u, rel, floor,
                  dep_p, dep_ng, dep_wi, dep_pow, dep_r, dep_b, n_dep0, bounce,
                  gen_i, gen_p, gen_ng, gen_ns, gen_wi, gen_pow, gen_bary,
                  record, rec_t, rec_ng, rec_nswi, rec_hit, dep_src, nxt_src, nxt_delta):
    """Everything after one Embree call, for rays 0..K-1 (in place).

    prim (K,) int32, bu, bv, tfar (K,) float32: Embree's closest hits.
    o32, d32 (cap, 3) float32, d64, pw (cap, 3) float64, fo (cap,): live state;
    survivors of the fast path are compacted in place to rows 0..n_next-1
    (row j <= i is only written after row i has been read).
    first: apply the soft-falloff factor t^2/(t^2 + fo); store: deposits
    allowed at this bounce; sample: continue the path (False at the last
    bounce); roulette: Russian roulette on the luminance of the bounce weight.
    u (K, 4) uniforms: direction (0, 1), lobe / Fresnel (2), roulette (3).
    Deposits go to dep_* rows n_dep0.. (dep_r = NaN, dep_b = bounce).  Hits on GENERIC
    materials are copied to gen_* (ray index, p, ng, ns, wi, power, (prim, u, v))
    for ``bsdf.sample_bsdf``.  record: also write per-ray hit data rec_t,
    rec_ng, rec_nswi (sign of ns.wi), rec_hit, the source ray of each deposit
    (dep_src) and of each survivor (nxt_src, nxt_delta) -- the frequency
    photons' spectrum updates need them.
    Returns (n_next, n_dep, n_gen).
    """
    n_next = 0
    n_dep = n_dep0
    n_gen = 0
    for i in range(K):
        t = prim[i]
        if record:
            rec_hit[i] = t >= 0
        if t < 0:
            continue
        uu = np.float64(bu[i])
        vv = np.float64(bv[i])
        w0 = 1.0 - uu - vv
        th = np.float64(tfar[i])
        px = w0 * tri_p[t, 0, 0] + uu * tri_p[t, 1, 0] + vv * tri_p[t, 2, 0]
        py = w0 * tri_p[t, 0, 1] + uu * tri_p[t, 1, 1] + vv * tri_p[t, 2, 1]
        pz = w0 * tri_p[t, 0, 2] + uu * tri_p[t, 1, 2] + vv * tri_p[t, 2, 2]
        gx, gy, gz = tri_ng[t, 0], tri_ng[t, 1], tri_ng[t, 2]
        sx = w0 * tri_n[t, 0, 0] + uu * tri_n[t, 1, 0] + vv * tri_n[t, 2, 0]
        sy = w0 * tri_n[t, 0, 1] + uu * tri_n[t, 1, 1] + vv * tri_n[t, 2, 1]
        sz = w0 * tri_n[t, 0, 2] + uu * tri_n[t, 1, 2] + vv * tri_n[t, 2, 2]
        nl = np.sqrt(sx * sx + sy * sy + sz * sz)
        if nl > 1e-12:
            sx /= nl
            sy /= nl
            sz /= nl
        else:
            sx, sy, sz = gx, gy, gz
        wx, wy, wz = -d64[i, 0], -d64[i, 1], -d64[i, 2]
        p0, p1, p2 = pw[i, 0], pw[i, 1], pw[i, 2]
        if first and fo[i] > 0.0:
            f = th * th / (th * th + fo[i])
            p0 *= f
            p1 *= f
            p2 *= f
        if record:
            rec_t[i] = th
            rec_ng[i, 0], rec_ng[i, 1], rec_ng[i, 2] = gx, gy, gz
            rec_nswi[i] = 1.0 if sx * wx + sy * wy + sz * wz >= 0.0 else -1.0
        m = tri_mat[t]
        if store and m_dep[m]:
            sg = 1.0 if gx * wx + gy * wy + gz * wz >= 0.0 else -1.0
            dep_p[n_dep, 0], dep_p[n_dep, 1], dep_p[n_dep, 2] = px, py, pz
            dep_ng[n_dep, 0], dep_ng[n_dep, 1], dep_ng[n_dep, 2] = gx * sg, gy * sg, gz * sg
            dep_wi[n_dep, 0], dep_wi[n_dep, 1], dep_wi[n_dep, 2] = wx, wy, wz
            dep_pow[n_dep, 0], dep_pow[n_dep, 1], dep_pow[n_dep, 2] = p0, p1, p2
            dep_r[n_dep] = np.nan
            dep_b[n_dep] = bounce
            if record:
                dep_src[n_dep] = i
            n_dep += 1
        if not sample:
            continue
        c = m_cls[m]
        if c == ABSORBER:
            continue
        if c == GENERIC:
            gen_i[n_gen] = i
            gen_p[n_gen, 0], gen_p[n_gen, 1], gen_p[n_gen, 2] = px, py, pz
            gen_ng[n_gen, 0], gen_ng[n_gen, 1], gen_ng[n_gen, 2] = gx, gy, gz
            gen_ns[n_gen, 0], gen_ns[n_gen, 1], gen_ns[n_gen, 2] = sx, sy, sz
            gen_wi[n_gen, 0], gen_wi[n_gen, 1], gen_wi[n_gen, 2] = wx, wy, wz
            gen_pow[n_gen, 0], gen_pow[n_gen, 1], gen_pow[n_gen, 2] = p0, p1, p2
            gen_bary[n_gen, 0], gen_bary[n_gen, 1], gen_bary[n_gen, 2] = t, uu, vv
            n_gen += 1
            continue
        r = sample_fast(c, m_col[m, 0], m_col[m, 1], m_col[m, 2], m_ior[m],
                        sx, sy, sz, gx, gy, gz, wx, wy, wz, u[i, 0], u[i, 1], u[i, 2])
        if not r[7]:
            continue
        w0_, w1_, w2_ = r[3], r[4], r[5]
        if not (np.isfinite(w0_) and np.isfinite(w1_) and np.isfinite(w2_)):
            continue
        if not max(w0_, w1_, w2_) > 0.0:
            continue
        if roulette:
            q = min(max(w0_ * _LUM0 + w1_ * _LUM1 + w2_ * _LUM2, 0.0), 1.0)
            if not u[i, 3] < q:
                continue
            qq = max(q, 1e-12)
            w0_ /= qq
            w1_ /= qq
            w2_ /= qq
        ox, oy, oz = r[0], r[1], r[2]
        # accel.spawn: push along ng to the side the new direction leaves on.
        side = 1.0 if gx * ox + gy * oy + gz * oz >= 0.0 else -1.0
        sc = side * _offset_scale(px, py, pz, rel, floor)
        j = n_next
        o32[j, 0] = px + gx * sc
        o32[j, 1] = py + gy * sc
        o32[j, 2] = pz + gz * sc
        d32[j, 0], d32[j, 1], d32[j, 2] = ox, oy, oz
        d64[j, 0], d64[j, 1], d64[j, 2] = ox, oy, oz
        pw[j, 0] = p0 * w0_
        pw[j, 1] = p1 * w1_
        pw[j, 2] = p2 * w2_
        if record:
            nxt_src[j] = i
            nxt_delta[j] = r[6]
        n_next += 1
    return n_next, n_dep, n_gen


@njit(cache=True, nogil=True, error_model="numpy")
def gen_attributes(gen_bary, n, tri_uv, uv):
    """uv (n, 2) of generic hits from their (prim, u, v) rows (textures)."""
    for k in range(n):
        t = int(gen_bary[k, 0])
        uu = gen_bary[k, 1]
        vv = gen_bary[k, 2]
        w0 = 1.0 - uu - vv
        for c in range(2):
            uv[k, c] = w0 * tri_uv[t, 0, c] + uu * tri_uv[t, 1, c] + vv * tri_uv[t, 2, c]


@njit(cache=True, nogil=True, error_model="numpy")
def append_survivors(j0, sel, gen_p, gen_ng, wo, wgt, gen_pow, rel, floor, o32, d32, d64, pw):
    """Append generic-path survivors sel (s,) at rows j0.. of the live state
    (spawn offset as :func:`bounce_kernel`)."""
    for k in range(sel.shape[0]):
        g = sel[k]
        j = j0 + k
        px, py, pz = gen_p[g, 0], gen_p[g, 1], gen_p[g, 2]
        gx, gy, gz = gen_ng[g, 0], gen_ng[g, 1], gen_ng[g, 2]
        ox, oy, oz = wo[g, 0], wo[g, 1], wo[g, 2]
        side = 1.0 if gx * ox + gy * oy + gz * oz >= 0.0 else -1.0
        sc = side * _offset_scale(px, py, pz, rel, floor)
        o32[j, 0] = px + gx * sc
        o32[j, 1] = py + gy * sc
        o32[j, 2] = pz + gz * sc
        for c in range(3):
            d32[j, c] = wo[g, c]
            d64[j, c] = wo[g, c]
            pw[j, c] = gen_pow[g, c] * wgt[g, c]


# ----------------------------------------------------------------------------
# Emission (lights.sample_photons for point, area and untextured mesh lights).

@njit(cache=True, inline="always")
def _basis_world(lx, ly, lz, nx, ny, nz):
    """lights._to_world: local (lx, ly, lz) about unit n (Duff et al. 2017)."""
    s = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (s + nz)
    b = nx * ny * a
    tx, ty, tz = 1.0 + s * nx * nx * a, s * b, -s * nx
    bx, by, bz = b, s + ny * ny * a, -ny
    return (lx * tx + ly * bx + lz * nx, lx * ty + ly * by + lz * ny,
            lx * tz + ly * bz + lz * nz)


# Columns of the packed light array (one array argument: numba increments and
# decrements the reference count of every array passed to a call, which cost
# 100 ns per photon with the LightTable's 16 arrays).
_KIND, _PSEL, _STR, _FLUX, _CO, _AU, _AV, _DIR = 0, 1, 2, 5, 8, 11, 14, 17
_LU, _LV, _AREA, _ELL, _RAD, _SPH, _NCOL = 20, 21, 22, 23, 24, 25, 26


@njit(cache=True, inline="always", error_model="numpy")
def _emit_one(u0, u1, u2, u3, u4, u5, cdf, last, L, b_diffuse):
    """One photon of ``lights.sample_photons`` (POINT, AREA, untextured MESH).

    L: (nL, _NCOL) packed light table (:func:`light_arrays`).
    Returns (o xyz, d xyz, power rgb, falloff r^2, freq_init a b c)."""
    nL = L.shape[0]
    # np.searchsorted(cdf, x, side="right"): first index with cdf > x.
    x = u0 * cdf[nL - 1]
    lo, hi = 0, nL
    while lo < hi:
        mid = (lo + hi) >> 1
        if cdf[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    j = lo
    if j > nL - 1:
        j = nL - 1
    if L[j, _PSEL] <= 0.0:
        j = last
    inv_p = 1.0 / L[j, _PSEL]
    kd = int(L[j, _KIND])
    if kd == 0:          # POINT: sphere model or soft falloff (disc) from the centre
        z = 1.0 - 2.0 * u3
        sz = np.sqrt(max(1.0 - z * z, 0.0))
        ph = 2.0 * np.pi * u4
        wx, wy, wz = sz * np.cos(ph), sz * np.sin(ph), z
        sph = L[j, _SPH] != 0.0
        r = L[j, _RAD] if sph else 0.0
        fall = 0.0 if sph else L[j, _RAD] * L[j, _RAD]
        rr = np.sqrt(u1)
        ph2 = 2.0 * np.pi * u2
        dx, dy = rr * np.cos(ph2), rr * np.sin(ph2)
        lift = np.sqrt(max(1.0 - dx * dx - dy * dy, 0.0))
        ox, oy, oz = _basis_world(dx, dy, lift, wx, wy, wz)
        return (L[j, _CO] + ox * r, L[j, _CO + 1] + oy * r, L[j, _CO + 2] + oz * r,
                wx, wy, wz, L[j, _STR] * inv_p, L[j, _STR + 1] * inv_p,
                L[j, _STR + 2] * inv_p, fall, 0.0, b_diffuse, 0.0)
    if kd == 3:          # AREA (rectangle or ellipse), one-sided along dir
        su = u1 - 0.5
        sv = u2 - 0.5
        if L[j, _ELL] != 0.0:
            rr = np.sqrt(u1)
            ph2 = 2.0 * np.pi * u2
            su = 0.5 * (rr * np.cos(ph2))
            sv = 0.5 * (rr * np.sin(ph2))
        a_ = su * L[j, _LU]
        b_ = sv * L[j, _LV]
        ox = L[j, _CO] + a_ * L[j, _AU] + b_ * L[j, _AV]
        oy = L[j, _CO + 1] + a_ * L[j, _AU + 1] + b_ * L[j, _AV + 1]
        oz = L[j, _CO + 2] + a_ * L[j, _AU + 2] + b_ * L[j, _AV + 2]
        nx, ny, nz = L[j, _DIR], L[j, _DIR + 1], L[j, _DIR + 2]
        p0, p1, p2 = L[j, _FLUX] * inv_p, L[j, _FLUX + 1] * inv_p, L[j, _FLUX + 2] * inv_p
    else:                # MESH (untextured), two-sided: side chosen by u5
        sq = np.sqrt(u1)
        b1 = sq * (1.0 - u2)
        b2 = sq * u2
        ox = L[j, _CO] + b1 * L[j, _AU] + b2 * L[j, _AV]
        oy = L[j, _CO + 1] + b1 * L[j, _AU + 1] + b2 * L[j, _AV + 1]
        oz = L[j, _CO + 2] + b1 * L[j, _AU + 2] + b2 * L[j, _AV + 2]
        side = 1.0 if u5 < 0.5 else -1.0
        nx, ny, nz = L[j, _DIR] * side, L[j, _DIR + 1] * side, L[j, _DIR + 2] * side
        g = 2.0 * np.pi * L[j, _AREA]
        p0 = g * L[j, _STR] * inv_p
        p1 = g * L[j, _STR + 1] * inv_p
        p2 = g * L[j, _STR + 2] * inv_p
    # Cosine-weighted direction about n (lights._cosine_local, _to_world).
    rr = np.sqrt(u3)
    ph = 2.0 * np.pi * u4
    lx, ly = rr * np.cos(ph), rr * np.sin(ph)
    lz = np.sqrt(max(1.0 - lx * lx - ly * ly, 0.0))
    wx, wy, wz = _basis_world(lx, ly, lz, nx, ny, nz)
    return (ox, oy, oz, wx, wy, wz, p0, p1, p2, 0.0, L[j, _AREA] / 12.0, b_diffuse, 0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def emit_lights(u, cdf, last, L, b_diffuse, o, d, power, falloff, freq):
    """``lights.sample_photons`` for POINT, AREA and untextured MESH emitters,
    same formulas and the same use of the uniforms u (n, 6) (so the same
    rng state gives the same photons up to round-off).  cdf, last, L,
    b_diffuse from :func:`light_arrays`.  Writes o, d, power, falloff (n,) and
    freq (n, 3) (light inits).  The caller guarantees every emitter with
    p_select > 0 is of those kinds (:func:`fast_emission_ok`).
    """
    for i in range(u.shape[0]):
        r = _emit_one(u[i, 0], u[i, 1], u[i, 2], u[i, 3], u[i, 4], u[i, 5], cdf, last, L,
                      b_diffuse)
        o[i, 0], o[i, 1], o[i, 2] = r[0], r[1], r[2]
        d[i, 0], d[i, 1], d[i, 2] = r[3], r[4], r[5]
        power[i, 0], power[i, 1], power[i, 2] = r[6], r[7], r[8]
        falloff[i] = r[9]
        freq[i, 0], freq[i, 1], freq[i, 2] = r[10], r[11], r[12]


@njit(cache=True, nogil=True, error_model="numpy")
def emit_lights_state(u, cdf, last, L, b_diffuse, rel, floor, o32, d32, d64, pw, fo,
                      want_freq, freq):
    """:func:`emit_lights` fused with :func:`emit_kernel`: photons straight
    into the live state (finite positive power only, origin offset along d).
    freq (n, 3) receives the light inits of the kept photons when want_freq.
    Returns the number K of photons kept."""
    K = 0
    for i in range(u.shape[0]):
        r = _emit_one(u[i, 0], u[i, 1], u[i, 2], u[i, 3], u[i, 4], u[i, 5], cdf, last, L,
                      b_diffuse)
        p0, p1, p2 = r[6], r[7], r[8]
        if not (np.isfinite(p0) and np.isfinite(p1) and np.isfinite(p2)):
            continue
        if not max(p0, p1, p2) > 0.0:
            continue
        sc = _offset_scale(r[0], r[1], r[2], rel, floor)
        o32[K, 0] = r[0] + r[3] * sc
        o32[K, 1] = r[1] + r[4] * sc
        o32[K, 2] = r[2] + r[5] * sc
        d32[K, 0], d32[K, 1], d32[K, 2] = r[3], r[4], r[5]
        d64[K, 0], d64[K, 1], d64[K, 2] = r[3], r[4], r[5]
        pw[K, 0], pw[K, 1], pw[K, 2] = p0, p1, p2
        fo[K] = r[9]
        if want_freq:
            freq[K, 0], freq[K, 1], freq[K, 2] = r[10], r[11], r[12]
        K += 1
    return K


def light_arrays(table) -> tuple:
    """(cdf, last, L, b_diffuse) for :func:`emit_lights`: cumsum of p_select,
    last emitter with p_select > 0, the LightTable packed into one (nL, 26)
    float64 array, and the diffuse angular variance of the light inits."""
    from ..lights.lights import B_DIFFUSE
    nL = table.n
    L = np.zeros((max(nL, 1), _NCOL))
    L[:nL, _KIND] = table.kind
    L[:nL, _PSEL] = table.p_select
    for col, name in ((_STR, "strength"), (_FLUX, "flux"), (_CO, "co"), (_AU, "axis_u"),
                      (_AV, "axis_v"), (_DIR, "dir")):
        L[:nL, col:col + 3] = getattr(table, name)
    for col, name in ((_LU, "len_u"), (_LV, "len_v"), (_AREA, "area"), (_ELL, "ellipse"),
                      (_RAD, "radius"), (_SPH, "is_sphere")):
        L[:nL, col] = getattr(table, name)
    p = np.asarray(table.p_select, np.float64)
    last = int(np.nonzero(p > 0)[0][-1]) if np.any(p > 0) else 0
    return np.cumsum(p), last, L, float(B_DIFFUSE)


def fast_emission_ok(table) -> bool:
    """True when every emitter that can be chosen is a POINT, AREA or
    untextured MESH light (the kinds :func:`emit_lights` covers)."""
    if table.n == 0 or not np.any(table.p_select > 0):
        return False
    on = table.p_select > 0
    k = table.kind[on]
    tex = np.asarray(table.tex)[on] if table.tex is not None else np.full(k.shape, -1)
    return bool(np.all((k == 0) | (k == 3) | ((k == 4) & (tex < 0))))


def sample_photons_fast(table, n: int, rng) -> dict:
    """Drop-in for ``lights.sample_photons`` when :func:`fast_emission_ok`
    (keys o, d, power, falloff_r2, freq_init; float64)."""
    u = rng.random((n, 6))
    o = np.empty((n, 3))
    d = np.empty((n, 3))
    power = np.empty((n, 3))
    falloff = np.empty(n)
    freq = np.empty((n, 3))
    emit_lights(u, *light_arrays(table), o, d, power, falloff, freq)
    return {"o": o, "d": d, "power": power, "falloff_r2": falloff, "freq_init": freq}
