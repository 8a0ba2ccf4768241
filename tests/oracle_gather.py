"""Test oracle of the photon gather: core.sppm.hashgrid.gather by brute force.

Used by tests/test_hashgrid.py and bench/bench_gather.py (tests/ is on their
sys.path); not shipped.
"""
import numpy as np

from core.sppm import hashgrid as hg


def gather_bruteforce(ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_pos, vp_ng, vp_R2,
                      vp_const, active=None, cos_ng: float = hg.COS_NG_DEFAULT,
                      want_freq_pairs: bool = False,
                      block_elems: int = 1 << 22, clip=None) -> hg.GatherResult:
    """Reference gather in numpy: tests every (photon, VP) pair, O(P*K).

    Same arguments as core.sppm.hashgrid.gather plus active (K,) bool (the
    mask given to build_grid; None = all); clip (K,) uint64 packed clips
    (rule (5)) or None.  Same float64 arithmetic in the
    same order, so M, the pair sets and rpred_min are bit-identical to the
    grid gather.  Pairs are sorted by (photon, VP).
    """
    P, K, ph, vp = hg._prepare(ph_pos, ph_ng, ph_wi, ph_power, ph_rpred,
                               vp_pos, vp_ng, vp_R2, vp_const)
    if P == 0 or K == 0:
        return hg._empty_result(K, want_freq_pairs)
    ph_pos, ph_ng, ph_wi, ph_power, ph_rpred = ph
    vp_pos, vp_ng, vp_R2, vp_const = vp
    act = np.ones(K, bool) if active is None else np.asarray(active, bool).reshape(K)
    with np.errstate(invalid="ignore"):
        # the VPs build_grid drops: non-finite position or radius
        act = act & np.isfinite(vp_pos).all(axis=1) & np.isfinite(vp_R2)
    x = ph_pos.astype(np.float64)
    wi = ph_wi.astype(np.float64)
    ng = ph_ng.astype(np.float64)
    M = np.zeros(K, np.int64)
    Phi = np.zeros((K, 3))
    rmin = np.full(K, np.inf)
    pv, pp, fv, fp = [], [], [], []
    B = max(1, block_elems // K)
    for b0 in range(0, P, B):
        b1 = min(P, b0 + B)
        sl = slice(b0, b1)
        dx = x[sl, 0, None] - vp_pos[None, :, 0]
        dy = x[sl, 1, None] - vp_pos[None, :, 1]
        dz = x[sl, 2, None] - vp_pos[None, :, 2]
        ok = (dx * dx + dy * dy + dz * dz) < vp_R2[None, :]
        ok &= (wi[sl, 0, None] * vp_ng[None, :, 0] + wi[sl, 1, None] * vp_ng[None, :, 1]
               + wi[sl, 2, None] * vp_ng[None, :, 2]) > 0.0
        cg = (ng[sl, 0, None] * vp_ng[None, :, 0] + ng[sl, 1, None] * vp_ng[None, :, 1]
              + ng[sl, 2, None] * vp_ng[None, :, 2])
        ok &= cg > cos_ng
        # (4): not behind the VP's plane unless similarly oriented
        ok &= ~((cg <= hg.COS_NG_DEFAULT)
                & ((dx * vp_ng[None, :, 0] + dy * vp_ng[None, :, 1] + dz * vp_ng[None, :, 2]) < 0.0))
        ok &= act[None, :]
        if clip is not None:
            ok &= ~_clipped(np.asarray(clip, np.uint64), vp_ng, vp_R2, dx, dy, dz)
        # photons outside the finite range are never counted (as in the grid)
        ok &= np.isfinite(x[sl]).all(axis=1)[:, None]
        ip, iv = np.nonzero(ok)
        ip = ip + b0
        M += np.bincount(iv, minlength=K)
        c = vp_const[iv]
        for ch in range(3):
            Phi[:, ch] += np.bincount(iv[c], weights=ph_power[ip[c], ch], minlength=K)
        pv.append(iv[~c])
        pp.append(ip[~c])
        r = ph_rpred[ip]
        f = ~np.isnan(r)
        np.minimum.at(rmin, iv[f], r[f])
        fv.append(iv[f])
        fp.append(ip[f])
    pair_vp = np.concatenate(pv).astype(np.int32)
    pair_ph = np.concatenate(pp).astype(np.int32)
    return hg.GatherResult(M, Phi, pair_vp, pair_ph, rmin,
                        np.concatenate(fv).astype(np.int32) if want_freq_pairs else None,
                        np.concatenate(fp).astype(np.int32) if want_freq_pairs else None)


def _clipped(clip, vp_ng, vp_R2, dx, dy, dz):
    """(B, K) bool: rule (5) rejects the photon offsets (dx, dy, dz) (B, K)
    of their visible points: wedge k of the offset in the tangent frame
    (Duff et al. 2017) at floor(255 d_k / R) or farther."""
    n0, n1, n2 = vp_ng[:, 0], vp_ng[:, 1], vp_ng[:, 2]
    sign = np.where(n2 >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n2)
    b = n0 * n1 * a
    t = (1.0 + sign * n0 * n0 * a, sign * b, -sign * n0, b, sign + n1 * n1 * a, -n1)
    u = dx * t[0][None] + dy * t[1][None] + dz * t[2][None]
    w = dx * t[3][None] + dy * t[4][None] + dz * t[5][None]
    q = np.where(u < 0.0, np.where(w >= 0.0, 1, 2), np.where(w < 0.0, 3, 0))
    sub = np.where(q % 2 == 0, np.abs(w) >= np.abs(u), np.abs(u) >= np.abs(w))
    k = (2 * q + sub).astype(np.uint64)
    byte = ((clip[None, :] >> (np.uint64(8) * k)) & np.uint64(0xFF)).astype(np.int64)
    return (byte < hg.CLIP_OPEN) & (65025.0 * (u * u + w * w)
                                    >= (byte * byte).astype(np.float64) * vp_R2[None, :])
