"""Compiled frequency updates: the ``core.frequency.spectrum`` operators per photon.

``core.frequency.spectrum`` is the numpy specification (one array operation
per guard, per operator).  On the photon path its calls cost more than
tracing the photon, so the tracer (``core.sppm.photons``) runs the two chains
of a frequency photon's spectrum (a, b, c) here, one numba loop over the
photons each, with the occlusion march (``occlusion_march.march_segments``)
of a bounce's segments in one call:

- arriving at a hit (:func:`arrive`): travel -> occlude -> onto_surface,
  then the predicted radius of every deposit (receiver diffuse, z = inf);
- leaving it (:func:`leave`): interface (delta lobes: reflection or
  refraction at the curved surface) -> off_surface -> brdf (lobe variance).

Each chain is written once, per photon, in :func:`arrive` and :func:`leave`;
the batch kernels :func:`spectrum_at_hits` and :func:`spectrum_leaving` loop
them over the bounce kernel's hit record (``core.sppm.photon_kernels``).
The numpy form of the chains is a test oracle (tests/oracle_photons.py).

Every scalar helper below is the numpy operator of the same name written per
photon with the same floating-point expressions in the same order, for both
models ('CORRECTED': guarded, sanitize on input and output; 'PAPER': the
seed's formulas verbatim).  IEEE arithmetic (no fastmath), so the results
are bit-identical except tan (libm vs numpy's SIMD tan, <= 1 ulp) and the
hit cosine's dot product (einsum's summation order); the tests hold them to
1e-12 relative on random and stiff inputs (tests/test_frequency_kernels.py).
NaN semantics follow numpy: ``_fmax``/``_fmin``/``_clip`` propagate NaN like
np.maximum / np.minimum / np.clip.

Arrays: spectra (N, 3) float64 columns (a, b, c); photon-indexed arrays as
in ``core.sppm.photon_kernels.bounce_kernel``'s record buffers.
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import materials as B
from ..scene import model as _sc
from . import spectrum as F
from . import curvature as _curv
from . import occlusion_grid as _occlusion_grid
from . import occlusion_march as _occlusion_march
from .occlusion_march import march_segments, plane_cosine

BETA = F.BETA
B_CAP = F.B_CAP
COS_MIN = F.COS_MIN
ANGLE_MAX = F.ANGLE_MAX
A_MAX_DEFAULT = F.A_MAX_DEFAULT


# ------------------------------------------------------------ numpy semantics
@njit(cache=True)
def _fmax(x, y):
    """np.maximum: NaN if either is NaN."""
    if x != x or y != y:
        return np.nan
    return x if x >= y else y


@njit(cache=True)
def _fmin(x, y):
    """np.minimum: NaN if either is NaN."""
    if x != x or y != y:
        return np.nan
    return x if x <= y else y


@njit(cache=True)
def _clip(x, lo, hi):
    """np.clip(x, lo, hi) = minimum(maximum(x, lo), hi)."""
    return _fmin(_fmax(x, lo), hi)


@njit(cache=True)
def _nan_to_num(x):
    """np.nan_to_num(x, nan=1.0) for the cosines."""
    if x != x:
        return 1.0
    if x == np.inf:
        return 1.7976931348623157e308
    if x == -np.inf:
        return -1.7976931348623157e308
    return x


# ------------------------------------------------------------ operators
@njit(cache=True)
def sanitize(a, b, c, A_MAX):
    """spectrum.sanitize for one spectrum."""
    if a != a or b != b or c != c:
        return 0.0, 0.0, 0.0
    a = _clip(a, 0.0, A_MAX)
    b = _clip(b, 0.0, B_CAP)
    lim = math.sqrt(a * b)
    if not (lim - lim == 0.0):            # not finite
        lim = 0.0
    c = _clip(c, -lim, lim)
    return a, b, c


@njit(cache=True)
def travel(a, b, c, d, paper, A_MAX):
    """spectrum.travel (d: distance [m])."""
    if paper:
        return a - 2 * c * d + b * d * d, b, c - b * d
    a, b, c = sanitize(a, b, c, A_MAX)
    D = math.sqrt(A_MAX)
    d = _clip(d, -D, D)
    c1 = c + b * d
    det = _fmax(a * b - c * c, 0.0)
    a1 = (det + c1 * c1) / b if b > 0 else a
    return sanitize(a1, b, c1, A_MAX)


@njit(cache=True)
def occlude(a, b, c, ao, paper, A_MAX):
    """spectrum.occlude (ao: a_occ [m^2])."""
    if paper:
        return a * ao / (a + ao), b, c
    a, b, c = sanitize(a, b, c, A_MAX)
    ao = 0.0 if ao != ao else _fmax(ao, 0.0)
    if ao >= A_MAX:                       # no occluder: identity
        return sanitize(a, b, c, A_MAX)
    t = a + ao
    if t > 0:
        return sanitize(a * ao / t, b - c * c / t, c * ao / t, A_MAX)
    return sanitize(0.0, b, 0.0, A_MAX)


@njit(cache=True)
def onto_surface(a, b, c, cs, paper, A_MAX):
    """spectrum.onto_surface (disc=False; cs: cosine to the normal)."""
    if paper:
        return a * cs * cs, b, c * cs
    a, b, c = sanitize(a, b, c, A_MAX)
    cs = _clip(abs(_nan_to_num(cs)), COS_MIN, 1.0)
    return sanitize(a / (cs * cs), b, c / cs, A_MAX)


@njit(cache=True)
def off_surface(a, b, c, cs, paper, A_MAX):
    """spectrum.off_surface (cos_i = cos_o for PAPER)."""
    if paper:
        return a / (cs * cs), b, c / cs
    a, b, c = sanitize(a, b, c, A_MAX)
    cs = _clip(abs(_nan_to_num(cs)), COS_MIN, 1.0)
    return sanitize(a * cs * cs, b, c * cs, A_MAX)


@njit(cache=True)
def brdf(a, b, c, bl, paper, A_MAX):
    """spectrum.brdf (bl: the lobe's angular variance)."""
    if paper:
        return a, b + bl, c
    a, b, c = sanitize(a, b, c, A_MAX)
    bl = 0.0 if bl != bl else _fmax(bl, 0.0)
    return sanitize(a, b + bl, c, A_MAX)


@njit(cache=True)
def curvature(a, b, c, kappa, paper, A_MAX, factor):
    """spectrum.curvature (PAPER: identity): interface(1, 1, factor kappa)."""
    return interface(a, b, c, 1.0, 1.0, factor * kappa, paper, A_MAX)


@njit(cache=True)
def interface(a, b, c, sc, mu, k, paper, A_MAX):
    """spectrum.interface: (u, theta) -> (sc u, mu theta + k u) (PAPER: identity)."""
    if paper:
        return a, b, c
    a, b, c = sanitize(a, b, c, A_MAX)
    if not (sc - sc == 0.0):
        sc = 1.0
    if not (mu - mu == 0.0):
        mu = 1.0
    if not (k - k == 0.0):
        k = 0.0
    a1 = sc * sc * a
    c1 = sc * (mu * c + k * a)
    det = sc * sc * mu * mu * _fmax(a * b - c * c, 0.0)
    b1 = (det + c1 * c1) / a1 if a1 > 0 else mu * mu * b
    f = B_CAP / b1 if b1 > B_CAP else 1.0
    return sanitize(a1 * f, b1 * f, c1 * f, A_MAX)


@njit(cache=True)
def interface_map(ci, ct, eta, kt, ks, tw, reflect):
    """spectrum.interface_map for one bounce: (scale, mu, k)."""
    ci = _clip(abs(_nan_to_num(ci)), COS_MIN, 1.0)
    ct = _clip(abs(_nan_to_num(ct)), COS_MIN, 1.0)
    eta = 1.0 if eta != eta else eta
    kt = kt if kt - kt == 0.0 else 0.0
    ks = ks if ks - ks == 0.0 else 0.0
    tw = tw if tw - tw == 0.0 else 0.0
    if reflect:
        ct = ci
        p_t = 2.0 * kt / ci
        p_s = 2.0 * ks * ci
        p_x = 2.0 * tw
        mu_t, mu_s = 1.0, 1.0
    else:
        g = eta * ci - ct
        p_t = g * kt / (ct * ct)
        p_s = g * ks
        p_x = g * tw / ct
        mu_t, mu_s = eta * ci / ct, eta
    p = 0.5 * (p_t + p_s) - math.sqrt((0.5 * (p_t - p_s)) ** 2 + p_x * p_x)
    if p_s < p_t:
        return ci / ct, mu_s, p * ci
    return 1.0, mu_t, p * ct


@njit(cache=True)
def bounce_interface(k1, k2, e1x, e1y, e1z, sign, ngx, ngy, ngz, dix, diy, diz,
                     dox, doy, doz, ior):
    """curvature.bounce_interface for one delta bounce: (scale, mu, k)."""
    ni = ngx * dix + ngy * diy + ngz * diz
    no = ngx * dox + ngy * doy + ngz * doz
    tx, ty, tz = dix - ni * ngx, diy - ni * ngy, diz - ni * ngz
    t2 = tx * tx + ty * ty + tz * tz
    if t2 > 1e-12:
        e = e1x * tx + e1y * ty + e1z * tz
        c2 = _fmin(e * e / t2, 1.0)
    else:
        c2 = 1.0
    kt = sign * (k1 * c2 + k2 * (1.0 - c2))
    ks = sign * (k1 * (1.0 - c2) + k2 * c2)
    tw = (k1 - k2) * math.sqrt(c2 * (1.0 - c2))
    eta = 1.0 / ior if ni < 0.0 else ior
    return interface_map(abs(ni), abs(no), eta, kt, ks, tw, ni * no <= 0.0)


@njit(cache=True)
def predicted_radius(a, b, c, br, z, paper):
    """spectrum.predicted_radius (br: receiver lobe variance, inf = diffuse;
    z: camera distance).  NaN -> 0."""
    z = abs(z)
    diffuse = br == np.inf or br == -np.inf
    if paper:
        rx = math.pi * math.sqrt(a) * BETA if a >= 0 else np.nan
        if diffuse:
            rt = np.inf
        else:
            s = b + br
            rt = z * math.tan(math.pi * math.sqrt(s) * BETA) if s >= 0 else np.nan
        r = _fmin(rx, rt)
        return 0.0 if r != r else r
    a, b, c = sanitize(a, b, c, A_MAX_DEFAULT)
    br = 0.0 if br != br else _fmax(br, 0.0)
    den = b + br
    a_eff = a - c * c / den if den > 0 else a
    a_eff = _fmax(a_eff, 0.0)
    rx = math.sqrt(2.0 * BETA * a_eff) if a_eff >= 0 else np.nan
    ang = math.sqrt(2.0 * BETA * den) if den >= 0 else np.nan
    if diffuse or not (ang < ANGLE_MAX):
        rt = np.inf
    else:
        rt = z * math.tan(min(ang, ANGLE_MAX))
    r = _fmin(rx, rt)
    return 0.0 if r != r else r


# ------------------------------------------------------------ the two chains
@njit(cache=True)
def arrive(a, b, c, t, a_occ, t_occ, has_grid, cs, paper, A_MAX, D):
    """The spectrum (a, b, c) leaving a vertex, after a segment of length t
    and onto the surface it hits at cosine cs (|ng . d|).

    The blocker acts where it is (docs/frequency.md, occlusion operator):
    travel to it (t_occ), multiply by its visibility (a_occ), travel on;
    without a blocker (a_occ = inf) travel t and occlude(inf).  has_grid
    False: no occlusion step at all (a render without an occlusion grid).
    Distances are clipped to D.  Returns onto_surface of the result."""
    if has_grid and a_occ < np.inf:
        a, b, c = travel(a, b, c, _fmin(t_occ, D), paper, A_MAX)
        a, b, c = occlude(a, b, c, a_occ, paper, A_MAX)
        a, b, c = travel(a, b, c, _fmin(_fmax(t - t_occ, 0.0), D), paper, A_MAX)
    else:
        a, b, c = travel(a, b, c, _fmin(t, D), paper, A_MAX)
        if has_grid:
            a, b, c = occlude(a, b, c, a_occ, paper, A_MAX)
    return onto_surface(a, b, c, cs, paper, A_MAX)


@njit(cache=True)
def leave(a, b, c, cs, b_lobe, sc, mu, k, curved, paper, A_MAX):
    """The on-surface spectrum (a, b, c) leaving along a direction at cosine
    cs (|ng . wo|) through a lobe of angular variance b_lobe (0 for a delta
    lobe); curved: first the interface (sc, mu, k) of a delta bounce
    (:func:`bounce_interface`), in surface coordinates."""
    if curved:
        a, b, c = interface(a, b, c, sc, mu, k, paper, A_MAX)
    a, b, c = off_surface(a, b, c, cs, paper, A_MAX)
    return brdf(a, b, c, b_lobe, paper, A_MAX)


@njit(cache=True)
def marked_segments(rows, rec, dep, march_all, need, used):
    """Which of a bounce's rays 0..K-1 the arriving chain reads: need (K,)
    bool, set for the rays that deposit (dep.src[dep0:dep1]) or continue
    (rec.nxt_src[:n_next]); used (K,) bool, set for the rays whose occluder
    is marched: the deposits, and the survivors of a delta lobe (mirror,
    glass, transparent), whose spectrum reaches the next deposit without a
    lobe's blur.  A ray that only continues through a non-delta lobe (the
    first hit without ``photons_for_direct``) travels without its occluder
    (docs/frequency.md "Cost": what that changes, measured).  march_all:
    used = need.  Deposits and survivors of rays >= K (classic photons
    traced in the same batch, rows K.. of its live state) are skipped."""
    K = rows.K
    for k in range(rows.dep0, rows.dep1):
        i = dep.src[k]
        if i < K:
            need[i] = True
            used[i] = True
    for j in range(rows.n_next):
        i = rec.nxt_src[j]
        if i >= K:
            continue
        need[i] = True
        if march_all or rec.nxt_delta[j]:
            used[i] = True


@njit(cache=True)
def gate_unreached(rows, rec, dep, seg, m, reach, used, unreached):
    """Deposits no visible point can gather (docs/frequency.md "Cost",
    "Deposits no pixel reads"): unreached (K,) bool is set for the rays
    0..K-1 that deposit at a hit point whose voxel of the march grid m
    (lo, icell, res) is 0 in reach (R, R, R) uint8 (``PhotonTracer.set_reach``:
    the voxels within a visible point's radius, plus a voxel), and used is
    cleared for them unless the ray continues through a delta lobe (whose
    spectrum reaches the next deposit unblurred).  Such a segment is not
    marched; the caller sets its deposit's radius to ChainParams.r_gated
    (the conservative value should a visible point gather it after all)."""
    K = rows.K
    delta = np.zeros(K, np.bool_)
    for j in range(rows.n_next):
        if rec.nxt_delta[j] and rec.nxt_src[j] < K:
            delta[rec.nxt_src[j]] = True
    R = m.res
    for k in range(rows.dep0, rows.dep1):
        i = dep.src[k]
        if i >= K:                        # a classic photon's deposit
            continue
        t = rec.t[i]
        ix = min(max(int(math.floor((seg.o[i, 0] + t * seg.d[i, 0] - m.lo[0]) * m.icell[0])), 0),
                 R - 1)
        iy = min(max(int(math.floor((seg.o[i, 1] + t * seg.d[i, 1] - m.lo[1]) * m.icell[1])), 0),
                 R - 1)
        iz = min(max(int(math.floor((seg.o[i, 2] + t * seg.d[i, 2] - m.lo[2]) * m.icell[2])), 0),
                 R - 1)
        if reach[ix, iy, iz] == 0:
            unreached[i] = True
            if not delta[i]:
                used[i] = False


@njit(cache=True)
def mark_reach(p, r, lo, cell, res, out):
    """out (res, res, res) uint8 (zeroed by the caller) = 1 on every voxel
    of the grid (lo, cell (3,) float64) that the box [p - r - cell, p + r +
    cell] of a visible point p (P, 3) with radius r (P,) [m] touches: a
    superset of the voxels its gather sphere reaches, one voxel wider
    (the next pass's visible points jitter within their pixels).
    Indices clipped to the grid, as :func:`gate_unreached` looks them up.
    A box inside the last one marked is skipped (the same map: neighbouring
    pixels' points, in pixel order, mostly mark the same voxels)."""
    lo_i = np.empty(3, np.int64)
    hi_i = np.empty(3, np.int64)
    lo_m = np.full(3, res, np.int64)          # the last box marked (none yet)
    hi_m = np.full(3, -1, np.int64)
    for n in range(p.shape[0]):
        inside = True
        for a in range(3):
            e = r[n] + cell[a]
            lo_i[a] = min(max(int(math.floor((p[n, a] - e - lo[a]) / cell[a])), 0), res - 1)
            hi_i[a] = min(max(int(math.floor((p[n, a] + e - lo[a]) / cell[a])), 0), res - 1)
            inside = inside and lo_m[a] <= lo_i[a] and hi_i[a] <= hi_m[a]
        if inside:
            continue
        for a in range(3):
            lo_m[a] = lo_i[a]
            hi_m[a] = hi_i[a]
        for x in range(lo_i[0], hi_i[0] + 1):
            for y in range(lo_i[1], hi_i[1] + 1):
                for z in range(lo_i[2], hi_i[2] + 1):
                    out[x, y, z] = 1


@njit(cache=True)
def radius_cut(a, b, c, t, r_cut, A_MAX, D):
    """(q0, q1, q2): the march of a segment of length t leaving with the
    spectrum (a, b, c) may ignore an occluder at distance l at t_o when l^2
    >= q0 + 2 q1 t_o + q2 t_o^2 = L a(t_o), the spatial variance there times
    L = r_cut^2 / (2 BETA a_end - r_cut^2); (inf, inf, inf) when the
    unoccluded deposit's radius sqrt(2 BETA a_end) is not above r_cut.

    Why (docs/frequency.md "Cost"): occluding Q at t_o with a_o = l^2 and
    travelling on gives, in any direction u = (1, s), u^T Q'' u =
    u^T Q u - (e1^T Q u)^2 / (a(t_o) + l^2) >= a_end l^2 / (a(t_o) + l^2)
    (Cauchy-Schwarz), so the deposit's diffuse radius sqrt(2 BETA a'') (and
    onto_surface only widens it) stays >= r_cut: no pixel's decision
    changes.  An occluder that could bring it below r_cut is still found,
    and the nearest such one is returned."""
    a, b, c = sanitize(a, b, c, A_MAX)
    ae = travel(a, b, c, _fmin(t, D), bool(False), A_MAX)[0]   # bool(): not a literal
    den = 2.0 * BETA * ae - r_cut * r_cut
    if not (den > 0.0) or not (r_cut < np.inf):
        return np.inf, np.inf, np.inf
    L = r_cut * r_cut / den
    return L * a, L * c, L * b


# ------------------------------------------------------------ kernel arguments
class ChainParams(NamedTuple):
    """The frequency model of a render.  paper: the PAPER model's formulas;
    D [m]: the scene diameter (longest distance); A_MAX = D^2 [m^2] (largest
    spatial variance); occlusion: 0 = no grid, 1 = march the grid, 2 = a
    grid without geometry (a_occ = inf for every segment); march_all: march
    every segment whose spectrum is read, not only the used ones
    (:func:`marked_segments`; the rule before docs/frequency.md "Cost",
    kept for the benchmarks); r_cut [m]: a radius no pixel's decision can
    tell from infinity (the largest pixel radius), inf = none: the march
    ignores the occluders that cannot bring a deposit's radius below it
    (:func:`radius_cut`; CORRECTED only); gate: the reach map passed to
    :func:`spectrum_at_hits` applies (:func:`gate_unreached`); r_gated [m]:
    the radius an unmarched deposit of a gated pass predicts (a positive
    radius below any pixel's: the radius floor); own_planes: the march
    does not take the surfaces a segment leaves and lands on for its
    occluders (False: the rule before docs/method.md "Principled interior:
    quality or cost", kept for the benchmarks); deposits: a frequency
    photon predicts a radius at its first ``deposits`` counted deposits
    only (counted: a deposit that is not gated as unreached), and is
    neither marched nor given a spectrum after them: its later deposits
    carry r = NaN, a classic photon's (docs/frequency.md "Cost", "Fewer
    marched deposits"); 0 = every deposit."""
    paper: bool
    D: float
    A_MAX: float
    occlusion: int
    march_all: bool = False
    r_cut: float = np.inf
    gate: bool = False
    r_gated: float = 0.0
    own_planes: bool = True
    deposits: int = 0


class Segments(NamedTuple):
    """The segments the photons just travelled: o, d (K, 3) float64 origin
    and unit direction (copied before the bounce kernel overwrites the live
    state); ng0 (K, 3) float64 the geometric normal of the surface each
    leaves (zeros: an emitter, or unknown), or (1, 3) zeros for none: the
    march does not take that surface for an occluder
    (``occlusion_march.march_segments``' planes)."""
    o: np.ndarray
    d: np.ndarray
    ng0: np.ndarray = np.zeros((1, 3))


class Rows(NamedTuple):
    """Which rows of a bounce's record the chains read: rays 0..K-1 (the
    frequency photons), deposits dep0..dep1-1 and survivors 0..n_next-1 of
    those rays (the others' are skipped: classic photons of the batch)."""
    K: int
    dep0: int
    dep1: int
    n_next: int


class SurfaceLobes(NamedTuple):
    """What the leaving chain reads of the hit surfaces.  tri_mat (T,) int32
    material of each triangle; lobe_b (M,) float64 the angular variance of
    each material's first lobe (``spectrum.lobe_variance``), lobe_ok (M,)
    bool False where that raises; delta_ior (M,) float64 the ior of the
    first delta GLASS / REFRACTION lobe (1 without one); kappa, kappa2 (T,)
    float64 and e1 (T, 3) the triangles' principal curvatures and first
    principal direction (``curvature.Curvature``), used when has_kappa
    (delta lobes only)."""
    tri_mat: np.ndarray
    lobe_b: np.ndarray
    lobe_ok: np.ndarray
    kappa: np.ndarray
    has_kappa: bool
    kappa2: np.ndarray = np.zeros(1)
    e1: np.ndarray = np.zeros((1, 3))
    delta_ior: np.ndarray = np.ones(1)


# ------------------------------------------------------------ cache token
def _dependency_token() -> int:
    """Hash of the sources compiled into the kernels besides this file.

    Numba's on-disk cache is keyed by this file's time stamp and each
    kernel's own bytecode; the march (core.frequency.occlusion_march, and
    the constants of occlusion_grid) and the constants of
    core.frequency.spectrum are invisible to it, so an edit there would keep
    running stale cached code.  The kernels are closures over this token,
    whose value is part of numba's cache key (closure variables are hashed):
    any change to those files recompiles them.
    """
    h = hashlib.sha256()
    for mod in (_occlusion_march, _occlusion_grid, F):
        with open(mod.__file__, "rb") as f:
            h.update(f.read())
    return int(h.hexdigest()[:12], 16)


def _kernels(token):
    """The cached entry points, as closures over ``token``."""

    # ------------------------------------------------------------ batch kernels
    @njit(cache=True, nogil=True, error_model="numpy")
    def spectrum_at_hits(chain, rows, spec, seg, rec, march, dep, reach, left):
        """Frequency photons arriving at their hits (rays 0..K-1).

        chain: ChainParams; rows: Rows; spec (K, 3): spectra leaving the
        previous vertex; seg: Segments; rec: the bounce kernel's hit record
        (``photon_kernels.HitRecord``: t, ng, hit, nxt_src); march: an
        ``occlusion_march.MarchGrid`` (read when chain.occlusion == 1); dep:
        the deposit buffers (``photon_kernels.DepositBuffers``: src, spec, r).
        Only rays that deposit (dep.src[dep0:dep1]) or continue
        (rec.nxt_src[:n_next]) are evaluated: the spectrum of any other hit
        is never read.  Rays K.. of the bounce are classic photons of the
        same batch (``PhotonTracer._trace_batch`` keeps the frequency
        photons in the first rows): their deposits and survivors are skipped.  For those, out[i] = :func:`arrive` with (a_occ,
        t_occ) = ``march_segments`` of the segment [o, o + t d].
        Deposits dep0..dep1-1: dep.spec[k] = out[dep.src[k]] and dep.r[k] =
        its predicted radius for a diffuse receiver.  reach (R, R, R) uint8
        on the march grid, read when chain.gate (and chain.occlusion == 1):
        deposits in its 0 voxels are not marched and get r = chain.r_gated
        (:func:`gate_unreached`).
        left (K,) int32, read when chain.deposits > 0: the counted deposits
        each ray may still make with a prediction; a ray at 0 is skipped
        (out[i] = spec[i], its deposit r = NaN, spec 0), and a counted
        deposit of a ray above 0 takes one off (in place).
        Returns (out (K, 3) float64, rows of other rays unset; the number
        of segments marched).
        """
        if token < 0:                     # never: ties the code to the token
            raise RuntimeError("token")
        K = rows.K
        need = np.zeros(K, np.bool_)
        used = np.zeros(K, np.bool_)
        marked_segments(rows, rec, dep, chain.march_all, need, used)
        paper, A_MAX, D = chain.paper, chain.A_MAX, chain.D
        marched = chain.occlusion == 1
        has_grid = chain.occlusion != 0
        gated = marched and chain.gate
        unreached = np.zeros(K if gated else 1, np.bool_)
        if gated:
            gate_unreached(rows, rec, dep, seg, march, reach, used, unreached)
        budget = chain.deposits > 0
        if budget:
            # a photon past its first `deposits` counted deposits is a
            # classic one from here on: no march, no spectrum
            for i in range(K):
                if left[i] <= 0:
                    need[i] = False
                    used[i] = False
        out = np.empty((K, 3))
        # The segments to march, in one call (march_segments unpacks the
        # grid's arrays once per call, not per segment)
        rows_m = np.empty(K, np.int64)
        n_march = 0
        for i in range(K):
            if used[i] and rec.hit[i]:
                rows_m[n_march] = i
                n_march += 1
        if not marched:
            n_march = 0
        a_occ = np.empty(K)
        t_occ = np.empty(K)
        cut = np.empty((K, 3))
        planes = np.empty((K, 2))
        has_ng0 = seg.ng0.shape[0] == K
        for k in range(n_march):
            i = rows_m[k]
            # the surfaces the segment connects are not its occluders
            planes[i, 0] = planes[i, 1] = np.inf
            if chain.own_planes:
                if has_ng0:
                    planes[i, 0] = plane_cosine(seg.ng0[i, 0], seg.ng0[i, 1], seg.ng0[i, 2],
                                                seg.d[i, 0], seg.d[i, 1], seg.d[i, 2])
                planes[i, 1] = plane_cosine(rec.ng[i, 0], rec.ng[i, 1], rec.ng[i, 2],
                                            seg.d[i, 0], seg.d[i, 1], seg.d[i, 2])
            if paper or not (chain.r_cut < np.inf):
                cut[i, 0] = cut[i, 1] = cut[i, 2] = np.inf
            else:
                cut[i, 0], cut[i, 1], cut[i, 2] = radius_cut(
                    spec[i, 0], spec[i, 1], spec[i, 2], rec.t[i], chain.r_cut, A_MAX, D)
        # np.int64: n_march may be typed Literal[int](0), a second compile of
        # the march (~15 s) beside march_occlusion's (core/warmup.py)
        march_segments(march, seg.o, seg.d, rec.t, rows_m, np.int64(n_march), a_occ, t_occ,
                       cut, planes)
        for i in range(K):
            if not (need[i] and rec.hit[i]):
                if budget:
                    out[i, 0] = spec[i, 0]
                    out[i, 1] = spec[i, 1]
                    out[i, 2] = spec[i, 2]
                continue
            t = rec.t[i]
            ao, to = np.inf, np.inf
            if marched and used[i]:
                ao, to = a_occ[i], t_occ[i]
            cs = abs(rec.ng[i, 0] * seg.d[i, 0] + rec.ng[i, 1] * seg.d[i, 1]
                     + rec.ng[i, 2] * seg.d[i, 2])
            a, b, c = arrive(spec[i, 0], spec[i, 1], spec[i, 2], t, ao, to, has_grid, cs,
                             paper, A_MAX, D)
            out[i, 0] = a
            out[i, 1] = b
            out[i, 2] = c
        for k in range(rows.dep0, rows.dep1):
            i = dep.src[k]
            if i >= K:                    # a classic photon's deposit: r stays NaN
                continue
            if budget:
                if left[i] <= 0:          # past its budget: a classic deposit
                    dep.spec[k, 0] = dep.spec[k, 1] = dep.spec[k, 2] = 0.0
                    dep.r[k] = np.nan
                    continue
                if not (gated and unreached[i]):
                    left[i] -= 1
            a, b, c = out[i, 0], out[i, 1], out[i, 2]
            dep.spec[k, 0] = a
            dep.spec[k, 1] = b
            dep.spec[k, 2] = c
            dep.r[k] = predicted_radius(a, b, c, np.inf, np.inf, paper)
            if gated and unreached[i] and not used[i]:
                dep.r[k] = chain.r_gated
        return out, n_march


    @njit(cache=True, nogil=True, error_model="numpy")
    def spectrum_leaving(chain, n_next, spec_hit, rec, d, prim, lobes, din):
        """Frequency photons leaving their hits: rows 0..n_next-1 of the live state.

        chain: ChainParams; spec_hit (K, 3): on-surface spectra
        (``spectrum_at_hits``); rec: the hit record (ng, nswi, and nxt_src,
        nxt_delta: each survivor's ray and whether it sampled a delta lobe);
        d (n_next, 3) the survivors' new directions; prim (K,) the hit
        triangles; lobes: SurfaceLobes; din (K, 3) the directions the rays
        arrived along (``Segments.d``).
        out[j] = :func:`leave` of spec_hit[nxt_src[j]] at |ng . wo|, after
        a delta lobe through the interface :func:`bounce_interface`.
        Returns (out (n_next, 3) float64; the first survivor j whose material
        has no lobe variance, or -1).
        """
        if token < 0:                     # never: ties the code to the token
            raise RuntimeError("token")
        paper, A_MAX = chain.paper, chain.A_MAX
        out = np.empty((n_next, 3))
        bad = -1
        for j in range(n_next):
            i = rec.nxt_src[j]
            dl = rec.nxt_delta[j]
            cs = abs(rec.ng[i, 0] * d[j, 0] + rec.ng[i, 1] * d[j, 1] + rec.ng[i, 2] * d[j, 2])
            p = prim[i]
            m = lobes.tri_mat[p]
            if not lobes.lobe_ok[m] and bad < 0:
                bad = j
            bl = 0.0 if dl else lobes.lobe_b[m]
            curved = lobes.has_kappa and dl
            sc, mu, k = 1.0, 1.0, 0.0
            if curved:
                sc, mu, k = bounce_interface(
                    lobes.kappa[p], lobes.kappa2[p], lobes.e1[p, 0], lobes.e1[p, 1],
                    lobes.e1[p, 2], rec.nswi[i], rec.ng[i, 0], rec.ng[i, 1], rec.ng[i, 2],
                    din[i, 0], din[i, 1], din[i, 2], d[j, 0], d[j, 1], d[j, 2],
                    lobes.delta_ior[m])
            a, b, c = leave(spec_hit[i, 0], spec_hit[i, 1], spec_hit[i, 2], cs, bl, sc, mu, k,
                            curved, paper, A_MAX)
            out[j, 0] = a
            out[j, 1] = b
            out[j, 2] = c
        return out, bad


    # ------------------------------------------------------------ array wrappers
    # (N, 3) in, (N, 3) out, like the numpy operators: the tests compare them.
    @njit(cache=True, nogil=True, error_model="numpy")
    def _apply(op, s, x, paper, A_MAX, out):
        if token < 0:                     # never: ties the code to the token
            raise RuntimeError("token")
        for i in range(s.shape[0]):
            a, b, c = s[i, 0], s[i, 1], s[i, 2]
            v = x[i]
            if op == 0:
                a, b, c = travel(a, b, c, v, paper, A_MAX)
            elif op == 1:
                a, b, c = occlude(a, b, c, v, paper, A_MAX)
            elif op == 2:
                a, b, c = onto_surface(a, b, c, v, paper, A_MAX)
            elif op == 3:
                a, b, c = off_surface(a, b, c, v, paper, A_MAX)
            elif op == 4:
                a, b, c = brdf(a, b, c, v, paper, A_MAX)
            elif op == 5:
                a, b, c = curvature(a, b, c, v, paper, A_MAX, 2.0)
            else:
                a, b, c = sanitize(a, b, c, A_MAX)
            out[i, 0] = a
            out[i, 1] = b
            out[i, 2] = c



    @njit(cache=True, nogil=True, error_model="numpy")
    def _radius(s, br, z, paper, out):
        if token < 0:                     # never: ties the code to the token
            raise RuntimeError("token")
        for i in range(s.shape[0]):
            out[i] = predicted_radius(s[i, 0], s[i, 1], s[i, 2], br[i], z[i], paper)

    return spectrum_at_hits, spectrum_leaving, _apply, _radius


spectrum_at_hits, spectrum_leaving, _apply, _radius = _kernels(_dependency_token())


def surface_lobes(mtab, tri_mat, kappa) -> SurfaceLobes:
    """SurfaceLobes of a scene: tri_mat (T,) int32, the material table mtab
    and kappa a ``curvature.Curvature`` of the triangles or None (no
    interface step).  lobe_b is ``spectrum.lobe_variance`` of each
    material's first lobe (kind[:, 0], roughness[:, 0]); lobe_ok False (and
    lobe_b NaN) where it raises (unused slot, unknown kind); delta_ior
    ``curvature.delta_ior``."""
    kinds = np.asarray(mtab.kind)[:, 0]
    rough = np.asarray(mtab.roughness, np.float64)[:, 0]
    M = kinds.shape[0]
    lobe_b = np.full(M, np.nan)
    ok = np.zeros(M, bool)
    for m in range(M):
        try:
            lobe_b[m] = F.lobe_variance(kinds[m:m + 1], rough[m:m + 1])[0]
            ok[m] = True
        except ValueError:
            pass
    if kappa is None:
        return SurfaceLobes(tri_mat, lobe_b, ok, np.zeros(1), False)
    return SurfaceLobes(tri_mat, lobe_b, ok, np.ascontiguousarray(kappa.k1, np.float64), True,
                        np.ascontiguousarray(kappa.k2, np.float64),
                        np.ascontiguousarray(kappa.e1, np.float64), _curv.delta_ior(mtab))


OPS = {"travel": 0, "occlude": 1, "onto_surface": 2, "off_surface": 3, "brdf": 4,
       "curvature": 5, "sanitize": 6}


def apply(name, s, x=0.0, model="CORRECTED", A_MAX=A_MAX_DEFAULT):
    """The compiled operator ``name`` on spectra s (N, 3) with its per-photon
    argument x ((N,) or scalar): equals ``getattr(core.frequency.spectrum,
    name)(s, x, model, A_MAX)`` (curvature with factor 2; sanitize ignores x and model)."""
    s = np.ascontiguousarray(np.asarray(s, np.float64).reshape(-1, 3))
    x = np.ascontiguousarray(np.broadcast_to(np.asarray(x, np.float64), (s.shape[0],)))
    out = np.empty_like(s)
    _apply(OPS[name], s, x, str(model).upper() == "PAPER", float(A_MAX), out)
    return out


def radius(s, b_receiver, z_camera, model="CORRECTED"):
    """Compiled ``spectrum.predicted_radius``: (N, 3), (N,) or scalar x2 -> (N,)."""
    s = np.ascontiguousarray(np.asarray(s, np.float64).reshape(-1, 3))
    n = s.shape[0]
    br = np.ascontiguousarray(np.broadcast_to(np.asarray(b_receiver, np.float64), (n,)))
    z = np.ascontiguousarray(np.broadcast_to(np.asarray(z_camera, np.float64), (n,)))
    out = np.empty(n)
    _radius(s, br, z, str(model).upper() == "PAPER", out)
    return out


class Receivers:
    """The predicted radius of a deposit at a visible point of any material
    (docs/frequency.md "Receivers").

    The deposit keeps its spectrum (a, b, c) on the surface; the visible point
    knows its receiver: b_receiver (M,) = ``spectrum.receiver_variance`` of
    each material, and the split of its BSDF into a diffuse part (Lambert,
    Oren-Nayar, translucent lobes: ``smooth``, a copy of the material table
    with the other lobes marked unused) and a glossy part (the rest).  For
    a (visible point, frequency photon) pair the glossy share is
    w = 1 - Y(f_smooth) / Y(f) (Y: luminance of the BSDF values), and the
    radius is ``spectrum.layered_radius`` of the diffuse radius (b_r = inf)
    and the glossy one (b_r, camera distance z) -- combined where the pairs
    are already formed (the gather's non-Lambert pairs), so that a Lambert
    scene pays nothing.
    mtab: core.materials MaterialTable.
    """

    LUMA = np.array([0.2126, 0.7152, 0.0722])

    def __init__(self, mtab):
        used = (np.asarray(mtab.kind) >= 0) & (np.asarray(mtab.weight) != 0.0)
        nondelta = used & ~np.asarray(mtab.lobe_delta, bool)
        self.mtab = mtab
        self.b_receiver = F.receiver_variance(mtab.kind, mtab.roughness, nondelta)
        # The other lobes are marked unused (kind -1), not given a zero
        # weight: lobe_colors already carry the mix weight, so a zeroed
        # weight would leave a plain Glossy lobe in the "diffuse" part.
        smooth = np.isin(mtab.kind, (_sc.DIFFUSE, _sc.TRANSLUCENT))
        self.smooth = dataclasses.replace(mtab, kind=np.where(smooth, mtab.kind, -1))

    #: Evaluate f and f_smooth with core.materials.compiled (one loop over
    #: the pairs, no per-pair copies) rather than twice with numpy.
    compiled = True

    def _luminances(self, vp, dep, pv, pp):
        """Luminances (K,) of f and of the smooth part's f at the pairs."""
        if not self.compiled:
            args = (vp.mat[pv], vp.colors[pv], vp.ns[pv], vp.ng[pv], vp.wo[pv], dep["wi"][pp])
            return (B.eval_bsdf(self.mtab, *args) @ self.LUMA,
                    B.eval_bsdf(self.smooth, *args) @ self.LUMA)
        from ..materials import compiled as MC
        K = pv.shape[0]
        f, fs = np.empty((K, 3)), np.empty((K, 3))
        MC.eval_indexed(MC.compile_materials(self.mtab), vp.mat, vp.colors, vp.ns, vp.ng,
                        np.zeros(0, bool), vp.wo, pv, dep["wi"], pp, f, fs)
        return f @ self.LUMA, fs @ self.LUMA

    def radius_keys(self, vp, dep, pv, pp, model="CORRECTED"):
        """Fold keys (``spectrum.radius_fold_key``) of the predicted radii of
        the pairs (visible point pv, frequency photon pp) (K,): vp the camera
        pass's visible points (mat, colors, ns, ng, wo, depth), dep the
        deposits (spec (P, 3), wi (P, 3)).  Returns (K,) float64.
        z: the visible point's camera depth times |cos| to the normal, at
        most its distance projected on the normal (a smaller z is a smaller,
        conservative r_theta)."""
        if pv.size == 0:
            return np.zeros(0)
        mat = vp.mat[pv]
        Y, Ys = self._luminances(vp, dep, pv, pp)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(Y > 0, 1.0 - Ys / Y, 0.0)
        s = dep["spec"][pp]
        z = vp.depth[pv] * np.abs(np.einsum("ij,ij->i", vp.ng[pv], vp.wo[pv]))
        r_s = radius(s, np.inf, np.inf, model)
        r_g = radius(s, self.b_receiver[mat], z, model)
        r = F.layered_radius(r_s, r_g, w)
        return F.radius_fold_key(r, model)
