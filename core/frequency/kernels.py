"""Compiled frequency-photon updates: the ``core.frequency`` operators per photon.

``core.frequency`` is the numpy reference (one array operation per guard, per
operator).  On the photon path its calls cost more than tracing the photon
(~2.4x a classic photon), so the tracer (``core.photons``) runs the two
chains of a frequency photon's spectrum (a, b, c) here, one numba loop over
the photons each, with the occlusion march inlined:

- at the hits:  travel -> occlude (``occlusion._march_one``) -> onto_surface,
  then the predicted radius of every deposit (receiver diffuse, z = inf);
- leaving:      off_surface -> brdf (lobe variance) -> curvature (delta lobes).

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
in ``core.photon_kernels.bounce_kernel``'s record buffers.
"""
from __future__ import annotations

import hashlib
import math

import numpy as np
from numba import njit

from . import spectrum as F
from . import occlusion as _occlusion
from .occlusion import _march_one

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
    """frequency.sanitize for one spectrum."""
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
    """frequency.travel (d: distance [m])."""
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
    """frequency.occlude (ao: a_occ [m^2])."""
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
    """frequency.onto_surface (disc=False; cs: cosine to the normal)."""
    if paper:
        return a * cs * cs, b, c * cs
    a, b, c = sanitize(a, b, c, A_MAX)
    cs = _clip(abs(_nan_to_num(cs)), COS_MIN, 1.0)
    return sanitize(a / (cs * cs), b, c / cs, A_MAX)


@njit(cache=True)
def off_surface(a, b, c, cs, paper, A_MAX):
    """frequency.off_surface (cos_i = cos_o for PAPER)."""
    if paper:
        return a / (cs * cs), b, c / cs
    a, b, c = sanitize(a, b, c, A_MAX)
    cs = _clip(abs(_nan_to_num(cs)), COS_MIN, 1.0)
    return sanitize(a * cs * cs, b, c * cs, A_MAX)


@njit(cache=True)
def brdf(a, b, c, bl, paper, A_MAX):
    """frequency.brdf (bl: the lobe's angular variance)."""
    if paper:
        return a, b + bl, c
    a, b, c = sanitize(a, b, c, A_MAX)
    bl = 0.0 if bl != bl else _fmax(bl, 0.0)
    return sanitize(a, b + bl, c, A_MAX)


@njit(cache=True)
def curvature(a, b, c, kappa, paper, A_MAX, factor):
    """frequency.curvature (PAPER: identity)."""
    if paper:
        return a, b, c
    a, b, c = sanitize(a, b, c, A_MAX)
    k = factor * kappa
    if not (k - k == 0.0):
        k = 0.0
    c1 = c + k * a
    det = _fmax(a * b - c * c, 0.0)
    b1 = (det + c1 * c1) / a if a > 0 else b
    sc = B_CAP / b1 if b1 > B_CAP else 1.0
    return sanitize(a * sc, b1 * sc, c1 * sc, A_MAX)


@njit(cache=True)
def predicted_radius(a, b, c, br, z, paper):
    """frequency.predicted_radius (br: receiver lobe variance, inf = diffuse;
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


# ------------------------------------------------------------ cache token
def _dependency_token() -> int:
    """Hash of the sources compiled into the kernels besides this file.

    Numba's on-disk cache is keyed by this file's time stamp and each
    kernel's own bytecode; the inlined march (core.occlusion) and the
    constants of core.frequency are invisible to it, so an edit there would
    keep running stale cached code.  The kernels are closures over this
    token, whose value is part of numba's cache key (closure variables are
    hashed): any change to those files recompiles them.
    """
    h = hashlib.sha256()
    for mod in (_occlusion, F):
        with open(mod.__file__, "rb") as f:
            h.update(f.read())
    return int(h.hexdigest()[:12], 16)


def _kernels(token):
    """The cached entry points, as closures over ``token``."""

    # ------------------------------------------------------------ batch kernels
    @njit(cache=True, nogil=True, error_model="numpy")
    def spectrum_at_hits(paper, K, spec, rec_t, rec_ng, rec_hit, o_seg, d_seg, D, A_MAX,
                         n0, n_dep, dep_src, n_next, nxt_src, need,
                         occ, dist, cone, bmin, bcone, vmin, vcone, has_v, B, lo, cell, R,
                         locality, t_skip, out, dep_spec, dep_r):
        """Frequency photons arriving at their hits (rays 0..K-1), in place.

        spec (K, 3): spectra leaving the previous vertex; rec_t (K,), rec_ng
        (K, 3), rec_hit (K,) bool: the bounce kernel's hit record; o_seg, d_seg
        (K, 3) float64: the segments' origins and unit directions.
        Only rays that deposit (dep_src[n0:n_dep]) or continue (nxt_src[:n_next])
        are evaluated (``need`` (K,) bool scratch): the spectrum of any other hit
        is never read.  For those, out[i] = onto_surface(travel(occlude(travel(
        spec[i], t_occ), a_occ), t - t_occ), |ng . d|) (travel(spec, t) and
        occlude(., inf) without an occluder), with (a_occ, t_occ) = occlusion._march_one of the
        segment [o, o + t d] when occ == 1, inf when occ == 2 (a grid without
        geometry), no occlusion step when occ == 0 (no grid).
        Deposits n0..n_dep-1: dep_spec[k] = out[dep_src[k]] and dep_r[k] = its
        predicted radius for a diffuse receiver (negated for PAPER: the grid
        keeps a minimum, the paper's rule a maximum).
        Returns the number of segments marched.
        """
        if token < 0:                     # never: ties the code to the token
            raise RuntimeError("token")
        for i in range(K):
            need[i] = False
        for k in range(n0, n_dep):
            need[dep_src[k]] = True
        for j in range(n_next):
            need[nxt_src[j]] = True
        n_march = 0
        for i in range(K):
            if not (need[i] and rec_hit[i]):
                continue
            t = rec_t[i]
            if occ == 1:
                # The blocker acts where it is: travel to it, multiply by its
                # visibility, travel on (docs/frequency.md, occlusion operator).
                ao, to = _march_one(dist, cone, bmin, bcone, vmin, vcone, has_v, B, lo, cell,
                                    R, o_seg[i, 0], o_seg[i, 1], o_seg[i, 2],
                                    d_seg[i, 0], d_seg[i, 1], d_seg[i, 2], t, locality, t_skip)
                n_march += 1
                if ao < np.inf:
                    a, b, c = travel(spec[i, 0], spec[i, 1], spec[i, 2], _fmin(to, D), paper,
                                     A_MAX)
                    a, b, c = occlude(a, b, c, ao, paper, A_MAX)
                    a, b, c = travel(a, b, c, _fmin(_fmax(t - to, 0.0), D), paper, A_MAX)
                else:
                    a, b, c = travel(spec[i, 0], spec[i, 1], spec[i, 2], _fmin(t, D), paper,
                                     A_MAX)
                    a, b, c = occlude(a, b, c, ao, paper, A_MAX)
            else:
                a, b, c = travel(spec[i, 0], spec[i, 1], spec[i, 2], _fmin(t, D), paper, A_MAX)
                if occ == 2:                  # a grid without geometry: a_occ = inf
                    a, b, c = occlude(a, b, c, np.inf, paper, A_MAX)
            cs = abs(rec_ng[i, 0] * d_seg[i, 0] + rec_ng[i, 1] * d_seg[i, 1]
                     + rec_ng[i, 2] * d_seg[i, 2])
            a, b, c = onto_surface(a, b, c, cs, paper, A_MAX)
            out[i, 0] = a
            out[i, 1] = b
            out[i, 2] = c
        for k in range(n0, n_dep):
            i = dep_src[k]
            a, b, c = out[i, 0], out[i, 1], out[i, 2]
            dep_spec[k, 0] = a
            dep_spec[k, 1] = b
            dep_spec[k, 2] = c
            r = predicted_radius(a, b, c, np.inf, np.inf, paper)
            dep_r[k] = -r if paper else r
        return n_march


    @njit(cache=True, nogil=True, error_model="numpy")
    def spectrum_leaving(paper, n_next, spec_hit, nxt_src, nxt_delta, rec_ng, rec_nswi, d64,
                         prim, tri_mat, lobe_b, lobe_ok, kappa, has_kappa, A_MAX, out):
        """Frequency photons leaving their hits: rows 0..n_next-1 of the live state.

        spec_hit (K, 3): on-surface spectra (``spectrum_at_hits``); nxt_src,
        nxt_delta: each survivor's ray and whether it sampled a delta lobe;
        d64 (n_next, 3) its new direction; prim (K,) the hit triangles;
        lobe_b (M,) the first lobe's angular variance of each material
        (``frequency.lobe_variance``), lobe_ok (M,) False where that raises;
        kappa (T,) triangle curvature (used when has_kappa, delta lobes only).
        out[j] = curvature(brdf(off_surface(spec_hit[i], |ng . wo|), b_lobe), kappa).
        Returns the first survivor j whose material has no lobe variance, or -1.
        """
        if token < 0:                     # never: ties the code to the token
            raise RuntimeError("token")
        bad = -1
        for j in range(n_next):
            i = nxt_src[j]
            dl = nxt_delta[j]
            cs = abs(rec_ng[i, 0] * d64[j, 0] + rec_ng[i, 1] * d64[j, 1] + rec_ng[i, 2] * d64[j, 2])
            a, b, c = off_surface(spec_hit[i, 0], spec_hit[i, 1], spec_hit[i, 2], cs, paper, A_MAX)
            p = prim[i]
            m = tri_mat[p]
            if not lobe_ok[m] and bad < 0:
                bad = j
            bl = 0.0 if dl else lobe_b[m]
            a, b, c = brdf(a, b, c, bl, paper, A_MAX)
            if has_kappa and dl:
                a, b, c = curvature(a, b, c, kappa[p] * rec_nswi[i], paper, A_MAX, 2.0)
            out[j, 0] = a
            out[j, 1] = b
            out[j, 2] = c
        return bad



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


def material_lobe_variance(mtab):
    """(lobe_b (M,), lobe_ok (M,)): ``frequency.lobe_variance`` of each
    material's first lobe (kind[:, 0], roughness[:, 0]); lobe_ok False (and
    lobe_b NaN) where it raises (unused slot, unknown kind)."""
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
    return lobe_b, ok


OPS = {"travel": 0, "occlude": 1, "onto_surface": 2, "off_surface": 3, "brdf": 4,
       "curvature": 5, "sanitize": 6}


def apply(name, s, x=0.0, model="CORRECTED", A_MAX=A_MAX_DEFAULT):
    """The compiled operator ``name`` on spectra s (N, 3) with its per-photon
    argument x ((N,) or scalar): equals ``getattr(core.frequency, name)(s, x,
    model, A_MAX)`` (curvature with factor 2; sanitize ignores x and model)."""
    s = np.ascontiguousarray(np.asarray(s, np.float64).reshape(-1, 3))
    x = np.ascontiguousarray(np.broadcast_to(np.asarray(x, np.float64), (s.shape[0],)))
    out = np.empty_like(s)
    _apply(OPS[name], s, x, str(model).upper() == "PAPER", float(A_MAX), out)
    return out


def radius(s, b_receiver, z_camera, model="CORRECTED"):
    """Compiled ``frequency.predicted_radius``: (N, 3), (N,) or scalar x2 -> (N,)."""
    s = np.ascontiguousarray(np.asarray(s, np.float64).reshape(-1, 3))
    n = s.shape[0]
    br = np.ascontiguousarray(np.broadcast_to(np.asarray(b_receiver, np.float64), (n,)))
    z = np.ascontiguousarray(np.broadcast_to(np.asarray(z_camera, np.float64), (n,)))
    out = np.empty(n)
    _radius(s, br, z, str(model).upper() == "PAPER", out)
    return out
