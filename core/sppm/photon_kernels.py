"""Compiled per-hit work of the photon pass (numba), between two Embree calls.

The numpy photon loop spends ~9x the Embree time on per-bounce array
bookkeeping (surface_point, lobe_colors, sample_bsdf, compaction), for 30
triangles and one Lambert material.  Here everything that happens after an
Embree call is one ``@njit(nogil=True)`` loop over the rays
(:func:`bounce_kernel`):

    barycentric p / ng / ns  ->  deposit (has_nondelta, bounce rule)
    ->  importance sampling of the common closures  ->  Russian roulette
    ->  spawn offset  ->  in-place compaction of the live photon state

The closures sampled in the loop are those of ``core.materials.fast``
(``FastMaterials``, ``sample_fast``); hits on any other material are
"generic" and handed back to ``core.materials.sample_bsdf`` by the
caller.  tests/test_photon_kernels.py checks the whole tracer against the
numpy reference tracer (tests/oracle_photons.py).  Precision: Embree sees
float32 origins/directions; positions, normals, powers and deposits are
float64.

Emission (``emit_lights``, ``emit_lights_state``) is ``lights.sample_photons``
for POINT, AREA and untextured MESH emitters, fed the same uniforms (tested
equal to round-off); other kinds keep the numpy sampler (``emit_kernel`` then
only filters and offsets its photons).

The kernels take their arrays grouped in NamedTuples (numba passes them as
structs): the live photon state (:class:`LiveState`), Embree's hits
(:class:`EmbreeHits`), the triangles (:class:`TriangleData`), the deposit
buffers (:class:`DepositBuffers`), the generic hits (:class:`GenericHits`),
the frequency photons' hit record (:class:`HitRecord`) and the per-bounce
flags (:class:`BounceStep`).

Kernels use ``error_model="numpy"`` (x/0 gives inf/NaN like the numpy path,
no exception checks) and ``nogil=True`` (core.sppm.photons traces two halves
of a batch in two threads).  Per-photon helpers take scalars only: numba
increments and decrements the reference count of every array passed to a
non-inlined call, which cost ~100 ns per photon with 16 light arrays.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import njit
from numba.core import cgutils, types
from numba.extending import intrinsic

# compiled.sample_pair (and eval_pair in it) is compiled into these kernels and
# numba's cache is stamped by this file: edited with the microfacet lobes'
# geometric side test of round 27, sample_pair's colour row of round 28 and
# the BSDF evaluation's lobe helpers and reference counts of round 32, and the
# view factor of round 40 (compiled._seen_w), and the displacement bump's code
# of round 45 (F_BUMP 2: no bump shadowing), and the conductor Fresnel of
# round 46 (F_K, compiled._fresnel_rgb) and thin film (F_FILM_D, F_FILM_N),
# and the one-signature entry points of round 50 (compiled._sample_pair).
from ..materials.compiled import sample_pair, sincos_turn
from ..materials.fast import ABSORBER, GENERIC, sample_fast
from ..lights.ies_kernels import ies_factor
from ..lights.warp_kernels import basis_world, spot_pdf_local, spread_atten, upper_bound
from ..mathutil import LUM_B as _LUM2, LUM_G as _LUM1, LUM_R as _LUM0


class TriangleData(NamedTuple):
    """Float64 per-triangle data for hit interpolation.  T triangles.

    p: (T, 3, 3) corners; n: (T, 3, 3) corner shading normals; ng: (T, 3) unit
    geometric normal (winding order, as ``accel.surface_point``); mat: (T,)
    int32 material index; flat: (T,) bool the three corner normals are equal
    (and not zero); ns: (T, 3) that normal, unit (flat triangles' rows only:
    the bounce kernel's shading normal there, ``flat_normals``).
    """
    p: np.ndarray
    n: np.ndarray
    ng: np.ndarray
    mat: np.ndarray
    flat: np.ndarray
    ns: np.ndarray


class LiveState(NamedTuple):
    """The live photons (rows 0..K-1 used; cap rows): o32, d32 (cap, 3)
    float32 the Embree rays; d64 (cap, 3) float64 the unit directions; power
    (cap, 3) float64; falloff (cap,) float64 the soft-falloff r^2 applied at
    the first hit."""
    o32: np.ndarray
    d32: np.ndarray
    d64: np.ndarray
    power: np.ndarray
    falloff: np.ndarray


class EmbreeHits(NamedTuple):
    """Embree's closest hits of rays 0..K-1: prim (K,) int32 (-1 = miss),
    bu, bv (K,) float32 barycentrics, tfar (K,) float32 distance."""
    prim: np.ndarray
    bu: np.ndarray
    bv: np.ndarray
    tfar: np.ndarray


class DepositBuffers(NamedTuple):
    """Deposit rows (cap rows, float64 unless stated): p, ng (oriented to
    the side the photon came from), wi (unit, back to where it came from),
    power (cap, 3); r (cap,) the radius fold key (NaN for classic photons,
    ``spectrum.radius_fold_key``); bounce (cap,) int32 path vertex; src
    (cap,) int64 the ray of each deposit (frequency photons); spec (cap, 3)
    the spectrum (a, b, c) of frequency photons; bary (cap, 3) (prim, u, v)
    of the hit (light tracing evaluates the BSDF there,
    core.integrators.light_tracer)."""
    p: np.ndarray
    ng: np.ndarray
    wi: np.ndarray
    power: np.ndarray
    r: np.ndarray
    bounce: np.ndarray
    src: np.ndarray
    spec: np.ndarray
    bary: np.ndarray


_NO_ROWS3 = np.empty((1, 3))
_NO_STATE = np.zeros(1, np.int8)


class GenericHits(NamedTuple):
    """Hits on GENERIC materials, for ``bsdf.sample_bsdf`` (rows 0..n_gen-1):
    i (cap,) int64 ray index; p, ng, ns, wi, power (cap, 3) float64; bary
    (cap, 3) float64 (prim, u, v).  With BounceStep.compiled (cap rows,
    else 1-row placeholders): the kernel's samples of the ``sampled``
    materials (``materials.fast``): out (cap, 3) the sampled direction, wgt
    (cap, 3) the weight, state (cap,) int8 SAMPLE_* of each row."""
    i: np.ndarray
    p: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    wi: np.ndarray
    power: np.ndarray
    bary: np.ndarray
    out: np.ndarray = _NO_ROWS3
    wgt: np.ndarray = _NO_ROWS3
    state: np.ndarray = _NO_STATE


# GenericHits.state: left to numpy; sampled in the kernel, invalid / valid
# non-delta / valid delta.
SAMPLE_NUMPY, SAMPLE_INVALID, SAMPLE_OK, SAMPLE_DELTA = 0, 1, 2, 3


def generic_hits(cap: int, compiled: bool) -> GenericHits:
    """GenericHits of cap rows, with the kernel's sample columns (out, wgt,
    state) when it samples ``sampled`` materials (BounceStep.compiled)."""
    extra = ({"out": np.empty((cap, 3)), "wgt": np.empty((cap, 3)),
              "state": np.empty(cap, np.int8)} if compiled else {})
    return GenericHits(np.empty(cap, np.int64), *(np.empty((cap, 3)) for _ in range(6)), **extra)


class HitRecord(NamedTuple):
    """Per-ray hit data the frequency chains read (written when
    BounceStep.record): t (K,) float64 hit distance, ng (K, 3) geometric
    normal, nswi (K,) sign of ns . wi, hit (K,) bool; nxt_src (K,) int64 the
    ray of each survivor, nxt_delta (K,) bool it sampled a delta lobe."""
    t: np.ndarray
    ng: np.ndarray
    nswi: np.ndarray
    hit: np.ndarray
    nxt_src: np.ndarray
    nxt_delta: np.ndarray


class BounceStep(NamedTuple):
    """One call of :func:`bounce_kernel`: K rays; first: apply the
    soft-falloff factor t^2/(t^2 + falloff); store: deposits allowed at this
    bounce; sample: continue the path (False at the last bounce); roulette:
    Russian roulette on the luminance of the bounce weight; bounce: the
    path vertex index; dep0: first free deposit row; record: write the
    HitRecord; rel, floor: the spawn offset (``accel.offset_scale``: max(|p|,
    floor) * rel); mis: follow the light side's MIS factors (:class:`MisState`,
    integrator 'COMBINED'; off for the photon pass, which passes a placeholder);
    compiled: sample the ``sampled`` GENERIC materials here into the
    GenericHits' out / wgt / state (with mis too: the caller's MIS factors
    of the generic survivors, combined.CombinedLightTracer._generic_factors,
    read their sampled directions); rows: write only the source
    ray of each survivor and of each deposit (HitRecord.nxt_src /
    nxt_delta, DepositBuffers.src; implied by record), what following a
    few photons through a batch needs (:func:`follow_rows`)."""
    K: int
    first: bool
    store: bool
    sample: bool
    roulette: bool
    bounce: int
    dep0: int
    record: bool
    rel: float
    floor: float
    mis: bool = False
    compiled: bool = False
    rows: bool = False


class MisState(NamedTuple):
    """The light side's MIS factors of integrator 'COMBINED'
    (core.integrators.combined, docs/integrators.md "Combined"), followed by
    :func:`bounce_kernel` when BounceStep.mis.  B0 and B1 of a light vertex
    z_m are (the first-hit ratios of the photon, numpy) x (these factors):
    1 at the first hit, then per scattering ``pr |cos_out| / pl`` (B1 at the
    first vertex: ``|cos_out| / pl``, 0 after a delta there) and per arrival
    ``1 / |cos_in|`` (core.integrators.combined.scatter_factors).  Delta
    samples: pl = pr = 1; LAMBERT: the closed-form diffuse densities
    (:func:`lambert_pdf`); GENERIC materials: the caller (numpy pdf_bsdf).
    "First" is per ray (``first``): with transparent shadows a transparent
    crossing is no vertex, so a ray that crossed only transparent surfaces
    since the light hits z_1 (the caller sets the flag of such survivors).

    f0, f1 (cap,) float64: the factors of the live rays (compacted with them;
    the arrival division pending).  row (cap,) int64: the photon of each live
    ray (compacted).  h0, h1 (cap,) float64: the factors at this bounce's hit
    of ray i (after the arrival division; read for generic survivors).
    first (cap,) bool: the live ray's hit is z_1 (compacted; True for all at
    the first bounce, False for the fast path's survivors).
    d0, d1 (dcap,) float64, drow (dcap,) int64, dfirst (dcap,) bool: per
    deposit row (as the DepositBuffers' rows).  A placeholder (1-row arrays)
    when off."""
    f0: np.ndarray
    f1: np.ndarray
    row: np.ndarray
    h0: np.ndarray
    h1: np.ndarray
    d0: np.ndarray
    d1: np.ndarray
    drow: np.ndarray
    first: np.ndarray
    dfirst: np.ndarray


def mis_state(cap: int, dcap: int) -> MisState:
    """Empty MisState for cap live rays and dcap deposits (1, 1: placeholder)."""
    return MisState(np.empty(cap), np.empty(cap), np.empty(cap, np.int64), np.empty(cap),
                    np.empty(cap), np.empty(dcap), np.empty(dcap), np.empty(dcap, np.int64),
                    np.ones(cap, np.bool_), np.empty(dcap, np.bool_))


#: The placeholder MisState of the photon pass (never written: BounceStep.mis off).
NO_MIS = mis_state(1, 1)


def build_triangle_data(scene) -> TriangleData:
    P = np.ascontiguousarray(scene.tri_p, np.float64).reshape(-1, 3, 3)
    ng = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    N = np.ascontiguousarray(scene.tri_n, np.float64).reshape(-1, 3, 3)
    flat, ns = flat_normals(N)
    return TriangleData(p=P, n=N, ng=np.ascontiguousarray(ng),
                        mat=np.ascontiguousarray(scene.tri_mat, np.int32), flat=flat, ns=ns)


def flat_normals(N: np.ndarray) -> tuple:
    """(flat (T,) bool, ns (T, 3)) of corner normals N (T, 3, 3): the
    triangles whose three corner normals are equal and longer than
    shading_normal's 1e-12, and that normal made unit as shading_normal does
    (each component divided by the length).  The bounce kernel reads it
    there instead of interpolating: the interpolation (w0 + u + v) n
    rounds, so on a tilted flat triangle the two differ by an ulp or two
    (docs/architecture.md "Cores at 256² and the bounce kernel, round 13")."""
    flat = np.all(N[:, 0] == N[:, 1], axis=1) & np.all(N[:, 0] == N[:, 2], axis=1)
    n0 = N[:, 0]
    nl = np.sqrt(n0[:, 0] * n0[:, 0] + n0[:, 1] * n0[:, 1] + n0[:, 2] * n0[:, 2])
    flat &= nl > 1e-12
    ns = np.where(flat[:, None], n0 / np.where(flat, nl, 1.0)[:, None], 0.0)
    return flat, np.ascontiguousarray(ns)


#: The bounce kernel prefetches the per-triangle data of the hit this many
#: rays ahead (0: none; prefetch, docs/architecture.md "The bounce kernel's
#: triangle reads, round 19").
TRI_PREFETCH = 6


@intrinsic
def prefetch(typingctx, a, t, off):
    """A hint that byte off of row t of the array a (any dimension, its
    first axis indexed) will be read: LLVM's llvm.prefetch (read, keep in
    all cache levels, data), no load, no fault, nothing waits for it."""
    sig = types.void(a, t, off)

    def codegen(context, builder, signature, args):
        aty = signature.args[0]
        ary = context.make_array(aty)(context, builder, args[0])
        row = context.cast(builder, args[1], signature.args[1], types.intp)
        k = context.cast(builder, args[2], signature.args[2], types.intp)
        stride0 = cgutils.unpack_tuple(builder, ary.strides)[0]
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        p8 = builder.gep(builder.bitcast(ary.data, i8p), [builder.add(builder.mul(row, stride0), k)])
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), "llvm.prefetch.p0")
        builder.call(fn, [p8, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()
    return sig, codegen


# ----------------------------------------------------------------------------
# Per-ray helpers (inlined).

@njit(cache=True, inline="always")
def _offset_scale(px, py, pz, rel, floor):
    """accel.offset_scale: max(|p|_inf, floor) * rel, floor = abs_floor / rel."""
    m = max(abs(px), abs(py), abs(pz))
    return max(m, floor) * rel


# ----------------------------------------------------------------------------
# Emission and bounce kernels.

@njit(cache=True, nogil=True, error_model="numpy")
def emit_kernel(o, d, power, falloff, rel, floor, live, src):
    """Keep photons with finite positive power; offset origins along d.

    o, d, power (n, 3) float64 from ``lights.sample_photons``, falloff (n,).
    Writes the K survivors to rows 0..K-1 of the LiveState live and src
    (index in the input).  Returns K.
    """
    o32, d32, d64, pw, fo = live.o32, live.d32, live.d64, live.power, live.falloff
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


class SoftLights(NamedTuple):
    """The soft-falloff point and spot lights for :func:`soft_light_first_hit`
    (Nl rows): soft (Nl,) bool ``LightTable.soft_disc``; lin_inv (Nl, 3, 3);
    cos_h, smooth, r2 (Nl,) float64 the cone's cosine and smoothstep scale
    (-2 and 1 for a point light: attenuation 1 in every direction), the
    radius squared; ies the packed IES profiles (``LightTable.ies``)."""
    soft: np.ndarray
    lin_inv: np.ndarray
    cos_h: np.ndarray
    smooth: np.ndarray
    r2: np.ndarray
    ies: np.ndarray


def soft_lights(table) -> SoftLights:
    """The :class:`SoftLights` of a LightTable."""
    from ..lights.table import SPOT
    c = np.ascontiguousarray
    spot = np.asarray(table.kind) == SPOT
    return SoftLights(c(table.soft_disc, np.bool_),
                      c(np.asarray(table.lin_inv, np.float64).reshape(-1, 3, 3)),
                      c(np.where(spot, table.cos_half_spot, -2.0), np.float64),
                      c(np.where(spot, table.spot_smooth, 1.0), np.float64),
                      c(np.asarray(table.radius, np.float64) ** 2),
                      c(table.ies, np.float64))


@njit(cache=True, inline="always", error_model="numpy")
def _soft_term(th, dx, dy, dz, ox, oy, oz, gx, gy, gz, sg, dn, S, j):
    """One disc turn y = c + o of :func:`soft_light_first_hit`: (its term f,
    the unit direction y -> p)."""
    qx = th * dx - ox
    qy = th * dy - oy
    qz = th * dz - oz
    qq = max(qx * qx + qy * qy + qz * qz, 1e-300)
    qn = np.sqrt(qq)
    qx, qy, qz = qx / qn, qy / qn, qz / qn
    cos_l = max(qx * dx + qy * dy + qz * dz, 0.0)
    cos_y = max(-sg * (gx * qx + gy * qy + gz * qz), 0.0)
    M = S.lin_inv
    lx = M[j, 0, 0] * qx + M[j, 0, 1] * qy + M[j, 0, 2] * qz
    ly = M[j, 1, 0] * qx + M[j, 1, 1] * qy + M[j, 1, 2] * qz
    lz = M[j, 2, 0] * qx + M[j, 2, 1] * qy + M[j, 2, 2] * qz
    ln = np.sqrt(lx * lx + ly * ly + lz * lz)
    x = min(max((-lz / ln - S.cos_h[j]) * S.smooth[j], 0.0), 1.0)
    f = x * x * (3.0 - 2.0 * x) * cos_l * cos_y * (th * th + S.r2[j]) / (qq * abs(dn))
    if S.ies.shape[0]:
        f *= ies_factor(S.ies, j, qx, qy, qz)
    return (f if np.isfinite(f) else 0.0), qx, qy, qz


@njit(cache=True, nogil=True, error_model="numpy")
def soft_light_first_hit(K, hits, live, tri_ng, src, light, disc, S):
    """``lights.emission.soft_light_first_hit`` at the first hits of the live
    rows 0..K-1 (EmbreeHits hits, triangles' geometric normals tri_ng (T, 3)):
    row i is photon src[i] of emitter row light[src[i]] with disc sample
    disc[src[i]] (n, 4) and its three turns; the factor multiplies
    live.power (the bounce kernel applies t^2 / (t^2 + r^2) after it) and
    the picked turn's direction replaces live.d64 and live.d32 (the point
    hit stays Embree's).  The distance is Embree's, as the bounce kernel's."""
    for i in range(K):
        t_ = hits.prim[i]
        if t_ < 0:
            continue
        k = src[i]
        j = light[k]
        if j < 0 or not S.soft[j]:
            continue
        th = np.float64(hits.tfar[i])
        dx, dy, dz = live.d64[i, 0], live.d64[i, 1], live.d64[i, 2]
        gx, gy, gz = tri_ng[t_, 0], tri_ng[t_, 1], tri_ng[t_, 2]
        dn = gx * dx + gy * dy + gz * dz
        sg = -1.0 if dn > 0.0 else (1.0 if dn < 0.0 else 0.0)
        ux, uy, uz = disc[k, 0], disc[k, 1], disc[k, 2]
        vx, vy, vz = dy * uz - dz * uy, dz * ux - dx * uz, dx * uy - dy * ux   # d x u
        f0, ax, ay, az = _soft_term(th, dx, dy, dz, ux, uy, uz, gx, gy, gz, sg, dn, S, j)
        f1, bx, by, bz = _soft_term(th, dx, dy, dz, -ux, -uy, -uz, gx, gy, gz, sg, dn, S, j)
        f2, cx, cy, cz = _soft_term(th, dx, dy, dz, vx, vy, vz, gx, gy, gz, sg, dn, S, j)
        f3, ex, ey, ez = _soft_term(th, dx, dy, dz, -vx, -vy, -vz, gx, gy, gz, sg, dn, S, j)
        tot = f0 + f1 + f2 + f3
        f = 0.25 * tot
        live.power[i, 0] *= f
        live.power[i, 1] *= f
        live.power[i, 2] *= f
        if not tot > 0.0:
            continue
        # The turn whose cumulative share first exceeds the uniform.
        cut = disc[k, 3] * tot
        if f0 > cut:
            nx, ny, nz = ax, ay, az
        elif f0 + f1 > cut:
            nx, ny, nz = bx, by, bz
        elif f0 + f1 + f2 > cut:
            nx, ny, nz = cx, cy, cz
        else:
            nx, ny, nz = ex, ey, ez
        live.d64[i, 0], live.d64[i, 1], live.d64[i, 2] = nx, ny, nz
        live.d32[i, 0], live.d32[i, 1], live.d32[i, 2] = nx, ny, nz


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def shading_normal(tri_n, t, w0, uu, vv, gx, gy, gz):
    """Unit shading normal of triangle t at barycentrics (w0, uu, vv) from its
    corner normals tri_n (T, 3, 3); the geometric normal (gx, gy, gz) where
    they cancel."""
    sx = w0 * tri_n[t, 0, 0] + uu * tri_n[t, 1, 0] + vv * tri_n[t, 2, 0]
    sy = w0 * tri_n[t, 0, 1] + uu * tri_n[t, 1, 1] + vv * tri_n[t, 2, 1]
    sz = w0 * tri_n[t, 0, 2] + uu * tri_n[t, 1, 2] + vv * tri_n[t, 2, 2]
    nl = np.sqrt(sx * sx + sy * sy + sz * sz)
    if nl > 1e-12:
        return sx / nl, sy / nl, sz / nl
    return gx, gy, gz


_INV_PI = 1.0 / np.pi


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def lambert_pdf(sx, sy, sz, gx, gy, gz, ox, oy, oz, ix, iy, iz):
    """core.materials.pdf_bsdf of a LAMBERT material (diffuse lobes only,
    selection probabilities summing to one) for wo = o, wi = i: max(N.wi, 0)
    / pi where Ng.wi > 0, the normals flipped to wo's side of Ng."""
    s = 1.0 if gx * ox + gy * oy + gz * oz >= 0.0 else -1.0
    if s * (gx * ix + gy * iy + gz * iz) <= 0.0:
        return 0.0
    return max(s * (sx * ix + sy * iy + sz * iz), 0.0) * _INV_PI


@njit(cache=True, nogil=True, error_model="numpy")
def bounce_kernel(step, hits, live, tris, mats, u, dep, gen, rec, mis):
    """Everything after one Embree call, for rays 0..step.K-1 (in place).

    step: BounceStep; hits: EmbreeHits; live: LiveState, whose survivors of
    the fast path are compacted in place to rows 0..n_next-1 (row j <= i is
    only written after row i has been read; row n_next of live, of the
    survivor columns of rec and of the live columns of mis may hold a sample
    that did not go on); tris: TriangleData; mats:
    ``materials.fast.FastMaterials``; u (K, 4) uniforms: direction (0, 1),
    lobe / Fresnel (2), roulette (3).
    Deposits go to rows dep0.. of the DepositBuffers dep (r = NaN, bounce =
    step.bounce).  Hits on GENERIC materials are copied to the GenericHits
    gen for ``bsdf.sample_bsdf`` (step.compiled: those on ``sampled``
    materials sampled here, GenericHits.state).  step.record: also write the HitRecord rec
    and the source ray of each deposit (dep.src) -- the frequency photons'
    spectrum updates need them.  step.mis: follow the MisState mis (its
    class doc) and write its rows of the deposits.
    Returns (n_next, n_dep, n_gen).
    """
    K, first, store, sample, roulette = step.K, step.first, step.store, step.sample, step.roulette
    bounce, n_dep0, record, rel, floor = step.bounce, step.dep0, step.record, step.rel, step.floor
    src_rows = record or step.rows
    prim, bu, bv, tfar = hits.prim, hits.bu, hits.bv, hits.tfar
    o32, d32, d64, pw, fo = live.o32, live.d32, live.d64, live.power, live.falloff
    tri_p, tri_n, tri_ng, tri_mat = tris.p, tris.n, tris.ng, tris.mat
    tri_flat, tri_ns = tris.flat, tris.ns
    m_cls, m_col, m_ior, m_dep = mats.cls, mats.col, mats.ior, mats.deposit
    dep_p, dep_ng, dep_wi, dep_pow, dep_r, dep_b = dep.p, dep.ng, dep.wi, dep.power, dep.r, \
        dep.bounce
    dep_src = dep.src
    gen_i, gen_p, gen_ng, gen_ns, gen_wi, gen_pow, gen_bary = (gen.i, gen.p, gen.ng, gen.ns,
                                                               gen.wi, gen.power, gen.bary)
    gen_out, gen_wgt, gen_state = gen.out, gen.wgt, gen.state
    use_comp = step.compiled
    if use_comp and (gen_out.shape[0] < gen_i.shape[0] or gen_state.shape[0] < gen_i.shape[0]):
        # The sample columns are 1-row placeholders (GenericHits built
        # without them): writing the samples there would overrun them.
        raise ValueError("BounceStep.compiled needs GenericHits with its sample columns "
                         "(photon_kernels.generic_hits(cap, True))")
    m_comp = mats.sampled
    c_lobes, c_T = mats.cm.lobes, mats.cm.tables
    s_col, s_p, s_cdf, s_last = mats.sel.colors, mats.sel.p, mats.sel.cdf, mats.sel.last
    rec_t, rec_ng, rec_nswi, rec_hit, nxt_src, nxt_delta = rec
    use_mis = step.mis
    mf0, mf1, mrow, mh0, mh1, md0, md1, mdrow, mfirst, mdfirst = mis
    n_next = 0
    n_dep = n_dep0
    n_gen = 0
    for i in range(K):
        t = prim[i]
        if TRI_PREFETCH > 0 and i + TRI_PREFETCH < K:
            # On a large mesh each array below is a cache miss at a hit, and
            # one ray's work is too long for the core to reach the next
            # ray's loads: ask for them TRI_PREFETCH rays early.  A p row
            # (72 bytes) may span three lines: bytes 0, 40 and 71.
            ta = prim[i + TRI_PREFETCH]
            if ta >= 0:
                prefetch(tri_p, ta, 0)
                prefetch(tri_p, ta, 40)
                prefetch(tri_p, ta, 71)
                prefetch(tri_ng, ta, 0)
                prefetch(tri_flat, ta, 0)
                prefetch(tri_ns, ta, 0)
                prefetch(tri_mat, ta, 0)
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
        # A flat triangle's unit normal is kept (flat_normals): no
        # interpolation, square root and divisions on the path to the sample.
        if tri_flat[t]:
            sx, sy, sz = tri_ns[t, 0], tri_ns[t, 1], tri_ns[t, 2]
        else:
            sx, sy, sz = shading_normal(tri_n, t, w0, uu, vv, gx, gy, gz)
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
        a0 = 1.0
        a1 = 1.0
        prow = 0
        fz = first
        if use_mis:
            prow = mrow[i]
            fz = mfirst[i]
            if not fz:
                # Arrival: divide by |cos| of the geometric normal (inf/NaN -> 0).
                ci = abs(gx * wx + gy * wy + gz * wz)
                a0 = mf0[i] / ci
                a1 = mf1[i] / ci
                if not np.isfinite(a0):
                    a0 = 0.0
                if not np.isfinite(a1):
                    a1 = 0.0
            mh0[i] = a0
            mh1[i] = a1
        if store and m_dep[m]:
            sg = 1.0 if gx * wx + gy * wy + gz * wz >= 0.0 else -1.0
            dep_p[n_dep, 0], dep_p[n_dep, 1], dep_p[n_dep, 2] = px, py, pz
            dep_ng[n_dep, 0], dep_ng[n_dep, 1], dep_ng[n_dep, 2] = gx * sg, gy * sg, gz * sg
            dep_wi[n_dep, 0], dep_wi[n_dep, 1], dep_wi[n_dep, 2] = wx, wy, wz
            dep_pow[n_dep, 0], dep_pow[n_dep, 1], dep_pow[n_dep, 2] = p0, p1, p2
            dep_r[n_dep] = np.nan
            dep_b[n_dep] = bounce
            dep.bary[n_dep, 0], dep.bary[n_dep, 1], dep.bary[n_dep, 2] = t, uu, vv
            if src_rows:
                dep_src[n_dep] = i
            if use_mis:
                md0[n_dep] = a0
                md1[n_dep] = a1
                mdrow[n_dep] = prow
                mdfirst[n_dep] = fz
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
            if use_comp:
                st = SAMPLE_NUMPY
                if m_comp[m]:
                    r = sample_pair(c_lobes, c_T, s_col, s_p, s_cdf, s_last, m, m,
                                    sx, sy, sz, gx, gy, gz, wx, wy, wz, u[i, 0], u[i, 1], u[i, 2],
                                    False)
                    gen_out[n_gen, 0], gen_out[n_gen, 1], gen_out[n_gen, 2] = r[0], r[1], r[2]
                    gen_wgt[n_gen, 0], gen_wgt[n_gen, 1], gen_wgt[n_gen, 2] = r[3], r[4], r[5]
                    st = (SAMPLE_DELTA if r[6] else SAMPLE_OK) if r[7] else SAMPLE_INVALID
                gen_state[n_gen] = st
            n_gen += 1
            continue
        r = sample_fast(c, m_col[m, 0], m_col[m, 1], m_col[m, 2], m_ior[m],
                        sx, sy, sz, gx, gy, gz, wx, wy, wz, u[i, 0], u[i, 1], u[i, 2])
        # Whether the ray goes on: a valid sample with a finite positive
        # weight that survives roulette.  Bitwise & and no branch: the
        # survivor is written to row n_next either way and counted only if it
        # goes on (row n_next <= i is free), so an unpredictable roulette
        # outcome costs no pipeline flush (docs/architecture.md "Photon trace
        # against raw Embree").
        w0_, w1_, w2_ = r[3], r[4], r[5]
        goes_on = (r[7] & np.isfinite(w0_) & np.isfinite(w1_) & np.isfinite(w2_)
                   & (max(w0_, w1_, w2_) > 0.0))
        if roulette:
            q = min(max(w0_ * _LUM0 + w1_ * _LUM1 + w2_ * _LUM2, 0.0), 1.0)
            goes_on = goes_on & (u[i, 3] < q)
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
        if src_rows:
            nxt_src[j] = i
            nxt_delta[j] = r[6]
        if use_mis:
            # Leaving along o: pr |cos_out| / pl (combined.scatter_factors).
            if r[6]:
                pl = 1.0
                pr = 1.0
            else:      # LAMBERT (the only non-delta fast class)
                pl = lambert_pdf(sx, sy, sz, gx, gy, gz, wx, wy, wz, ox, oy, oz)
                pr = lambert_pdf(sx, sy, sz, gx, gy, gz, ox, oy, oz, wx, wy, wz)
            co = abs(gx * ox + gy * oy + gz * oz)
            pend1 = co / pl if pl > 0.0 else 0.0
            mf0[j] = a0 * pr * pend1
            if fz:
                mf1[j] = 0.0 if r[6] else a1 * pend1
            else:
                mf1[j] = a1 * pr * pend1
            mrow[j] = prow
            mfirst[j] = False
        n_next += 1 if goes_on else 0
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


@njit(cache=True, nogil=True)
def classic_rows(q, src, n_fast, n_next, K, out, mark):
    """The row each survivor of a bounce has in the batch traced without
    frequency photons (docs/frequency.md "The same photons").  q (K,) int64:
    that row of each of the bounce's K rays; src (n_next,) the ray of each
    survivor (HitRecord.nxt_src): rows 0..n_fast-1 the bounce kernel's, in
    ray order, n_fast..n_next-1 the generic bounce's.  Without frequency
    photons each block is in the order of its rays' rows q, so a survivor's
    row is its rank by q[src] within its block (plus n_fast for the second).
    out (n_next,) int64 receives them; mark (K,) int64 scratch."""
    for b in range(2):
        lo = 0 if b == 0 else n_fast
        hi = n_fast if b == 0 else n_next
        for k in range(K):
            mark[k] = -1
        for j in range(lo, hi):
            mark[q[src[j]]] = j
        r = lo
        for k in range(K):
            j = mark[k]
            if j >= 0:
                out[j] = r
                r += 1


@njit(cache=True, nogil=True)
def follow_rows(rows, k, src, n_fast, n_next, dsrc, dep0, dep1, out_rows, out_dep):
    """Follow k photons through one bounce of a batch (docs/frequency.md
    "Cost", "Frequency photons traced again").  rows (k,) int64 ascending:
    their rays at this bounce; src (n_next,) the ray of each survivor
    (HitRecord.nxt_src: rows 0..n_fast-1 the bounce kernel's, then the
    generic bounce's, each block in ray order); dsrc the ray of each
    deposit row (DepositBuffers.src; rows dep0..dep1-1 this bounce's, in
    ray order).  out_dep receives the deposit rows of the k rays in ray
    order, out_rows their survivors' rows: the bounce kernel's block, then
    the generic one's, each in ray order, so ascending again.  Returns
    (the survivors, the deposits)."""
    nd = 0
    for q in range(k):
        d = dep0 + np.searchsorted(dsrc[dep0:dep1], rows[q])
        if d < dep1 and dsrc[d] == rows[q]:
            out_dep[nd] = d
            nd += 1
    m = 0
    for b in range(2):
        lo = 0 if b == 0 else n_fast
        hi = n_fast if b == 0 else n_next
        for q in range(k):
            j = lo + np.searchsorted(src[lo:hi], rows[q])
            if j < hi and src[j] == rows[q]:
                out_rows[m] = j
                m += 1
    return m, nd


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _append_row(live, j, px, py, pz, gx, gy, gz, ox, oy, oz, p0, p1, p2, rel, floor):
    """Row j of the LiveState live: a ray from the point p spawned along the
    normal g to the side of the unit direction o (offset as
    :func:`bounce_kernel`), of power (p0, p1, p2)."""
    side = 1.0 if gx * ox + gy * oy + gz * oz >= 0.0 else -1.0
    sc = side * _offset_scale(px, py, pz, rel, floor)
    live.o32[j, 0] = px + gx * sc
    live.o32[j, 1] = py + gy * sc
    live.o32[j, 2] = pz + gz * sc
    live.d32[j, 0], live.d32[j, 1], live.d32[j, 2] = ox, oy, oz
    live.d64[j, 0], live.d64[j, 1], live.d64[j, 2] = ox, oy, oz
    live.power[j, 0], live.power[j, 1], live.power[j, 2] = p0, p1, p2


@njit(cache=True, nogil=True, error_model="numpy")
def append_survivors(j0, sel, gen_p, gen_ng, wo, wgt, gen_pow, rel, floor, live):
    """Append generic-path survivors sel (s,) at rows j0.. of the LiveState
    live (spawn offset as :func:`bounce_kernel`)."""
    for k in range(sel.shape[0]):
        g = sel[k]
        _append_row(live, j0 + k, gen_p[g, 0], gen_p[g, 1], gen_p[g, 2], gen_ng[g, 0],
                    gen_ng[g, 1], gen_ng[g, 2], wo[g, 0], wo[g, 1], wo[g, 2],
                    gen_pow[g, 0] * wgt[g, 0], gen_pow[g, 1] * wgt[g, 1],
                    gen_pow[g, 2] * wgt[g, 2], rel, floor)


@njit(cache=True, nogil=True, error_model="numpy")
def generic_survivors(j0, g, gen, u, roulette, lum, rel, floor, live, record, nxt_src,
                      nxt_delta):
    """The survivors of the g GenericHits gen sampled by the bounce kernel
    (every row's state SAMPLE_INVALID, SAMPLE_OK or SAMPLE_DELTA): a valid
    sample with a finite positive weight that survives roulette on the
    weight's luminance lum (g,) (u (K, 4) the batch's uniforms, column 3 at
    the hit's ray gen.i), appended in row order at rows j0.. of the
    LiveState live (spawn offset as :func:`bounce_kernel`) and, when record,
    their source ray and delta flag to nxt_src, nxt_delta.  Returns the new
    number of live rows.  lum is numpy's ``wgt @ LUMINANCE``, as the generic
    path computed it before this loop was compiled: its dot product's order
    differs from the fast path's sum in the last bit of 15 % of the rows,
    and the pinned photon digests of tests/test_photon_trace_pins.py keep
    their bits on every CPU."""
    out, wgt, state, pw = gen.out, gen.wgt, gen.state, gen.power
    j = j0
    for k in range(g):
        st = state[k]
        if st < SAMPLE_OK:
            continue
        w0, w1, w2 = wgt[k, 0], wgt[k, 1], wgt[k, 2]
        if not (np.isfinite(w0) and np.isfinite(w1) and np.isfinite(w2)
                and max(w0, w1, w2) > 0.0):
            continue
        i = gen.i[k]
        if roulette:
            q = min(max(lum[k], 0.0), 1.0)
            if not u[i, 3] < q:
                continue
            qq = max(q, 1e-12)
            w0 /= qq
            w1 /= qq
            w2 /= qq
        _append_row(live, j, gen.p[k, 0], gen.p[k, 1], gen.p[k, 2], gen.ng[k, 0],
                    gen.ng[k, 1], gen.ng[k, 2], out[k, 0], out[k, 1], out[k, 2],
                    pw[k, 0] * w0, pw[k, 1] * w1, pw[k, 2] * w2, rel, floor)
        if record:
            nxt_src[j] = i
            nxt_delta[j] = st == SAMPLE_DELTA
        j += 1
    return j


# ----------------------------------------------------------------------------
# Emission (lights.sample_photons for point, area and untextured mesh lights).

# Columns of the packed light array (one array argument: numba increments and
# decrements the reference count of every array passed to a call, which cost
# 100 ns per photon with the LightTable's 16 arrays).
_KIND, _PSEL, _STR, _FLUX, _CO, _AU, _AV, _DIR = 0, 1, 2, 5, 8, 11, 14, 17
_LU, _LV, _AREA, _ELL, _RAD, _SPH = 20, 21, 22, 23, 24, 25
# Spots: the object matrix (row-major), |det|, cos_half_spot, spot_smooth and
# the soft spot's tail (share, x0, X, half-angle: LightTable.spot_tail); area
# lights: the spread's tan_half_spread and normalize_spread.
_LIN, _DET, _CHS, _SSM, _TAIL, _SPT, _SPN, _SPS, _NCOL = 26, 35, 36, 37, 38, 42, 43, 44, 45


@njit(cache=True, inline="always", error_model="numpy")
def _spot_direction(u3, u4, u5, L, j):
    """A spot's photon direction as ``lights.sample_photons`` draws it: (w xyz
    world unit, its weight I / (4 pi) x weight / I, soft) with weight = jac /
    spot_pdf_local for a soft spot (its cone, or its tail with probability
    P), att jac 2 pi (1 - cos_h) for a hard one."""
    cos_h = L[j, _CHS]
    P = L[j, _TAIL]
    soft = P > 0.0
    sn, cs = sincos_turn(u4)
    if soft and u5 < P:
        x0, X, h = L[j, _TAIL + 1], L[j, _TAIL + 2], L[j, _TAIL + 3]
        A = 1.0 - 1.0 / (1.0 + X / x0)
        th = h + min(x0 * (1.0 / (1.0 - u3 * A) - 1.0), X)
        s = np.sin(th)
        vx, vy, vz = s * cs, s * sn, np.cos(th)
    else:
        vz = 1.0 - u3 * (1.0 - cos_h)
        s = np.sqrt(max(1.0 - vz * vz, 0.0))
        vx, vy = s * cs, s * sn
    vz = -vz                                  # local axis is -Z
    mx = L[j, _LIN] * vx + L[j, _LIN + 1] * vy + L[j, _LIN + 2] * vz
    my = L[j, _LIN + 3] * vx + L[j, _LIN + 4] * vy + L[j, _LIN + 5] * vz
    mz = L[j, _LIN + 6] * vx + L[j, _LIN + 7] * vy + L[j, _LIN + 8] * vz
    nM = np.sqrt(mx * mx + my * my + mz * mz)
    jac = L[j, _DET] / (nM * nM * nM)
    cz = -vz
    if soft:
        f = jac / spot_pdf_local(P, L[j, _TAIL + 1], L[j, _TAIL + 2], L[j, _TAIL + 3], cos_h, cz)
    else:
        a = min(max((cz - cos_h) * L[j, _SSM], 0.0), 1.0)
        f = a * a * (3.0 - 2.0 * a) * jac * 2.0 * np.pi * (1.0 - cos_h)
    return mx / nM, my / nM, mz / nM, f / (4.0 * np.pi), soft


@njit(cache=True, inline="always", error_model="numpy")
def _emit_one(u0, u1, u2, u3, u4, u5, cdf, last, L, b_diffuse, ies):
    """One photon of ``lights.sample_photons`` (POINT, SPOT, AREA, untextured MESH).

    L: (nL, _NCOL) packed light table, ies its IES profiles (:func:`light_arrays`).
    Returns (o xyz, d xyz, power rgb, falloff r^2, freq_init a b c, the
    emitter row, a soft-falloff light's disc sample xyz and the uniform
    that picks its turn (``soft_disc``))."""
    nL = L.shape[0]
    # np.searchsorted(cdf, x, side="right"): first index with cdf > x.
    x = u0 * cdf[nL - 1]
    j = upper_bound(cdf[:nL], x)
    if j > nL - 1:
        j = nL - 1
    if L[j, _PSEL] <= 0.0:
        j = last
    inv_p = 1.0 / L[j, _PSEL]
    kd = int(L[j, _KIND])
    if kd == 0 or kd == 1:   # POINT, SPOT: sphere model or soft falloff (disc) from the centre
        wgt = 1.0
        sph = L[j, _SPH] != 0.0
        us = u5
        if kd == 0:
            z = 1.0 - 2.0 * u3
            sz = np.sqrt(max(1.0 - z * z, 0.0))
            sn, cs = sincos_turn(u4)
            wx, wy, wz = sz * cs, sz * sn, z
        else:
            wx, wy, wz, wgt, _ = _spot_direction(u3, u4, u5, L, j)
            P = L[j, _TAIL]
            if P > 0.0:          # u5's share left after choosing cone or tail
                us = u5 / P if u5 < P else (u5 - P) / (1.0 - P)
        soft = (not sph) and L[j, _RAD] > 0.0
        r = L[j, _RAD] if sph else 0.0
        fall = 0.0 if sph else L[j, _RAD] * L[j, _RAD]
        rr = np.sqrt(u1)
        sn, cs = sincos_turn(u2)
        dx, dy = rr * cs, rr * sn
        lift = np.sqrt(max(1.0 - dx * dx - dy * dy, 0.0))
        ox, oy, oz = basis_world(dx, dy, lift, wx, wy, wz)
        qx, qy, qz = 0.0, 0.0, 0.0
        if soft:
            qx, qy, qz = basis_world(dx, dy, 0.0, wx, wy, wz)
            qx, qy, qz = qx * L[j, _RAD], qy * L[j, _RAD], qz * L[j, _RAD]
        else:
            us = 0.0
            if ies.shape[0]:
                # An IES profile along the photon's direction (a soft light's
                # along y -> p at its first hit: soft_light_first_hit).
                wgt *= ies_factor(ies, j, wx, wy, wz)
        w = wgt * inv_p
        return (L[j, _CO] + ox * r, L[j, _CO + 1] + oy * r, L[j, _CO + 2] + oz * r,
                wx, wy, wz, L[j, _STR] * w, L[j, _STR + 1] * w,
                L[j, _STR + 2] * w, fall, 0.0, b_diffuse, 0.0, j, qx, qy, qz, us)
    if kd == 3:          # AREA (rectangle or ellipse), one-sided along dir
        su = u1 - 0.5
        sv = u2 - 0.5
        if L[j, _ELL] != 0.0:
            rr = np.sqrt(u1)
            sn, cs = sincos_turn(u2)
            su = 0.5 * (rr * cs)
            sv = 0.5 * (rr * sn)
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
    sn, cs = sincos_turn(u4)
    lx, ly = rr * cs, rr * sn
    spread = kd == 3 and L[j, _SPT] != np.inf
    if spread:
        # Inside the spread's cone only (lights.emission): radius sin a.
        sa = np.sqrt(L[j, _SPS])
        lx, ly = lx * sa, ly * sa
    lz = np.sqrt(max(1.0 - lx * lx - ly * ly, 0.0))
    wx, wy, wz = basis_world(lx, ly, lz, nx, ny, nz)
    if spread:
        # The radiance's factor along the direction, times sin^2 a.
        f = spread_atten(L[j, _SPT], L[j, _SPN], lz) * L[j, _SPS]
        p0, p1, p2 = p0 * f, p1 * f, p2 * f
    return (ox, oy, oz, wx, wy, wz, p0, p1, p2, 0.0, L[j, _AREA] / 12.0, b_diffuse, 0.0, j,
            0.0, 0.0, 0.0, 0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def emit_lights(u, cdf, last, L, b_diffuse, ies, o, d, power, falloff, freq, light, disc):
    """``lights.sample_photons`` for POINT, SPOT, AREA and untextured MESH
    emitters, same formulas and the same use of the uniforms u (n, 6) (so
    the same rng state gives the same photons up to round-off).  cdf, last,
    L, b_diffuse, ies from :func:`light_arrays`.  Writes o, d, power, falloff
    (n,), freq (n, 3) (light inits), light (n,) int64 (the emitter rows)
    and disc (n, 4) (``soft_disc``).  The caller guarantees every emitter
    with p_select > 0 is of those kinds (:func:`fast_emission_ok`).
    """
    for i in range(u.shape[0]):
        r = _emit_one(u[i, 0], u[i, 1], u[i, 2], u[i, 3], u[i, 4], u[i, 5], cdf, last, L,
                      b_diffuse, ies)
        o[i, 0], o[i, 1], o[i, 2] = r[0], r[1], r[2]
        d[i, 0], d[i, 1], d[i, 2] = r[3], r[4], r[5]
        power[i, 0], power[i, 1], power[i, 2] = r[6], r[7], r[8]
        falloff[i] = r[9]
        freq[i, 0], freq[i, 1], freq[i, 2] = r[10], r[11], r[12]
        light[i] = r[13]
        disc[i, 0], disc[i, 1], disc[i, 2], disc[i, 3] = r[14], r[15], r[16], r[17]


@njit(cache=True, nogil=True, error_model="numpy")
def emit_lights_state(u, cdf, last, L, b_diffuse, ies, rel, floor, live, want_freq, freq,
                      want_disc, light, disc):
    """:func:`emit_lights` fused with :func:`emit_kernel`: photons straight
    into the LiveState live (finite positive power only, origin offset along
    d).  freq (n, 3) receives the light inits of the kept photons when
    want_freq, light (n,) int64 and disc (n, 4) their emitter rows and
    ``soft_disc`` when want_disc (:func:`soft_light_first_hit` with src the
    identity).  Returns the number K of photons kept."""
    o32, d32, d64, pw, fo = live.o32, live.d32, live.d64, live.power, live.falloff
    K = 0
    for i in range(u.shape[0]):
        r = _emit_one(u[i, 0], u[i, 1], u[i, 2], u[i, 3], u[i, 4], u[i, 5], cdf, last, L,
                      b_diffuse, ies)
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
        if want_disc:
            light[K] = r[13]
            disc[K, 0], disc[K, 1], disc[K, 2], disc[K, 3] = r[14], r[15], r[16], r[17]
        K += 1
    return K


def light_arrays(table) -> tuple:
    """(cdf, last, L, b_diffuse, ies) for :func:`emit_lights`: cumsum of
    p_select, last emitter with p_select > 0, the LightTable packed into one
    (nL, _NCOL) float64 array, the diffuse angular variance of the light
    inits and the packed IES profiles (``LightTable.ies``)."""
    from ..lights import B_DIFFUSE
    from ..lights.emission import spot_tail
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
    if nL:
        lin = np.asarray(table.lin, np.float64).reshape(nL, 3, 3)
        L[:nL, _LIN:_LIN + 9] = lin.reshape(nL, 9)
        L[:nL, _DET] = np.abs(np.linalg.det(lin))
        L[:nL, _CHS] = table.cos_half_spot
        L[:nL, _SSM] = table.spot_smooth
        L[:nL, _TAIL:_TAIL + 4] = spot_tail(table)
        L[:nL, _SPT] = table.spread_tan
        L[:nL, _SPN] = table.spread_norm
        L[:nL, _SPS] = table.spread_sin2
    if nL == 0:
        L[:, _SPT] = np.inf
    p = np.asarray(table.p_select, np.float64)
    last = int(np.nonzero(p > 0)[0][-1]) if np.any(p > 0) else 0
    return (np.cumsum(p), last, L, float(B_DIFFUSE),
            np.ascontiguousarray(table.ies, np.float64))


def fast_emission_ok(table) -> bool:
    """True when every emitter that can be chosen is a POINT, SPOT, AREA or
    untextured MESH light (the kinds :func:`emit_lights` covers)."""
    if table.n == 0 or not np.any(table.p_select > 0):
        return False
    on = table.p_select > 0
    k = table.kind[on]
    tex = np.asarray(table.tex)[on] if table.tex is not None else np.full(k.shape, -1)
    return bool(np.all((k == 0) | (k == 1) | (k == 3) | ((k == 4) & (tex < 0))))


def sample_photons_fast(table, n: int, rng) -> dict:
    """Drop-in for ``lights.sample_photons`` when :func:`fast_emission_ok`
    (keys o, d, power, falloff_r2, freq_init, soft_disc float64; light
    int64, kind: the emitter row and its kind)."""
    u = rng.random((n, 6))
    o = np.empty((n, 3))
    d = np.empty((n, 3))
    power = np.empty((n, 3))
    falloff = np.empty(n)
    freq = np.empty((n, 3))
    light = np.empty(n, np.int64)
    disc = np.empty((n, 4))
    emit_lights(u, *light_arrays(table), o, d, power, falloff, freq, light, disc)
    return {"o": o, "d": d, "power": power, "falloff_r2": falloff, "freq_init": freq,
            "light": light, "kind": np.asarray(table.kind)[light], "soft_disc": disc}
