"""Are the occlusions of the frequency photons real?  (docs/method.md
"Principled interior: quality or cost").

    .venv/bin/python bench/bench_occlusion_truth.py principled_interior [--passes 3]

Renders ``--passes`` FPPM passes of an example scene (the protocol of
bench_hold_alpha.py: 64x64, photon mapping only, one numba thread), records
every frequency deposit of the last pass (the segment it arrived along, its
spectrum before the segment, the hit normal), marches each segment again
(every occluder: no radius cut) and, for the occluded ones, finds the
triangle really nearest the blocker point the march reported (brute force):

- ``receiver``: that triangle lies in the plane of the surface the segment
  ends on (it cannot cut light arriving at that surface);
- ``source``: it lies in the plane the segment leaves (it cannot cut light
  leaving that surface);
- ``behind``: its nearest point lies behind the receiving plane, seen from
  the arriving photon, or behind the plane it leaves, seen from the leaving
  one;
- ``other``: a real candidate.

Prints the shares of each class among the occluded deposits and among those
whose predicted radius falls below the median pixel radius, with the
radius ratio occluded / unoccluded per class.
"""
from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numba as nb  # noqa: E402
import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))
sys.path.insert(0, os.path.join(ROOT, "tests"))

import fppm_alias  # noqa: E402,F401
from bench_hold_alpha import export  # noqa: E402

from fppm.core.frequency import spectrum as F  # noqa: E402
from fppm.core.frequency.occlusion_grid import _closest_point  # noqa: E402
from fppm.core.frequency.occlusion_march import march_occlusion  # noqa: E402
from fppm.core.render import Renderer  # noqa: E402


@nb.njit(cache=True)
def nearest_triangles(p, tri):
    """(N,) index and (N, 3) closest point of the triangle nearest each p (N, 3)."""
    N, T = p.shape[0], tri.shape[0]
    idx = np.empty(N, np.int64)
    q = np.empty((N, 3))
    for i in range(N):
        best = np.inf
        for t in range(T):
            x, y, z = _closest_point(p[i, 0], p[i, 1], p[i, 2],
                                     tri[t, 0, 0], tri[t, 0, 1], tri[t, 0, 2],
                                     tri[t, 1, 0], tri[t, 1, 1], tri[t, 1, 2],
                                     tri[t, 2, 0], tri[t, 2, 1], tri[t, 2, 2])
            d2 = (x - p[i, 0]) ** 2 + (y - p[i, 1]) ** 2 + (z - p[i, 2]) ** 2
            if d2 < best:
                best = d2
                idx[i] = t
                q[i, 0], q[i, 1], q[i, 2] = x, y, z
    return idx, q


def record(r, passes):
    """Deposits of the last pass: dict of arrays o, d, t, ng, spec (spectrum
    leaving the previous vertex)."""
    for _ in range(passes - 1):
        r.step()
    tr = r.tracer
    orig = tr._spectrum_at_hits
    rows = []

    def hook(spec, seg, rec, dep, rw):
        src = dep.buf.src[rw.dep0:rw.dep1].copy()
        src = src[src < rw.K]            # rays K..: classic photons of the batch
        ok = rec.hit[src]
        src = src[ok]
        ng0 = seg.ng0[src] if seg.ng0.shape[0] == rw.K else np.zeros((src.size, 3))
        rows.append(dict(o=seg.o[src].copy(), d=seg.d[src].copy(), t=rec.t[src].copy(),
                         ng=rec.ng[src].copy(), spec=spec[src].copy(), ng0=ng0.copy()))
        return orig(spec, seg, rec, dep, rw)
    tr._spectrum_at_hits = hook
    try:
        r.step()
    finally:
        tr._spectrum_at_hits = orig
    return {k: np.concatenate([x[k] for x in rows]) for k in rows[0]}


def arrive_radius(tr, spec, d, t, ng, a_occ, t_occ):
    """Diffuse predicted radius of the arriving chain with (a_occ, t_occ)."""
    A = tr.D * tr.D
    has = np.isfinite(a_occ)
    s = F.travel(spec, np.minimum(np.where(has, t_occ, t), tr.D), "CORRECTED", A)
    s = F.occlude(s, a_occ, "CORRECTED", A)
    if has.any():
        s[has] = F.travel(s[has], np.minimum(np.maximum(t[has] - t_occ[has], 0.0), tr.D),
                          "CORRECTED", A)
    s = F.onto_surface(s, np.abs(np.sum(ng * d, axis=1)), "CORRECTED", A)
    return F.predicted_radius(s, np.inf, np.inf, "CORRECTED")


def classify(scene, rec, a_occ, t_occ):
    """Class per occluded deposit (0 receiver, 1 source, 2 behind, 3 other)
    and the true distance from the blocker point to the nearest triangle."""
    tri = np.ascontiguousarray(scene.tri_p, np.float64)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    D = float(np.linalg.norm(tri.reshape(-1, 3).max(0) - tri.reshape(-1, 3).min(0)))
    p = rec["o"] + t_occ[:, None] * rec["d"]
    idx, q = nearest_triangles(p, tri)
    l_true = np.linalg.norm(q - p, axis=1)
    hit = rec["o"] + rec["t"][:, None] * rec["d"]
    nb_ = n[idx]
    tol = 1e-4 * D
    coplanar = lambda pt, nn: ((np.abs(np.sum(nb_ * nn, 1)) > 0.999)  # noqa: E731
                               & (np.abs(np.sum(nb_ * (tri[idx, 0] - pt), 1)) < tol))
    ng = rec["ng"]
    cls = np.full(len(p), 3)
    side = np.sign(np.sum(ng * -rec["d"], 1))          # the photon's side of the receiver
    behind = np.sum(ng * (q - hit), 1) * side < -tol
    # or behind the plane the segment leaves, seen from the leaving photon
    n0 = rec["ng0"]
    side0 = np.sign(np.sum(n0 * rec["d"], 1))
    behind |= np.sum(n0 * (q - rec["o"]), 1) * side0 < -tol
    cls[behind] = 2
    # the leaving plane: the triangle's plane contains o
    src = np.abs(np.sum(nb_ * (tri[idx, 0] - rec["o"]), 1)) < tol
    cls[src] = 1
    cls[coplanar(hit, ng)] = 0
    return cls, l_true


def disc_error(L, r_px):
    """(H, W) relative error |disc mean - L| / L of a disc of radius r_px
    pixels in image space (a proxy of PPM's kernel bias at that radius on
    the reference luminance L (H, W); geometry edges included)."""
    k = int(np.ceil(r_px))
    yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
    w = (xx * xx + yy * yy <= r_px * r_px).astype(np.float64)
    H, W = L.shape
    P = np.pad(L, k, mode="edge")
    m = np.zeros_like(L)
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            if w[dy + k, dx + k]:
                m += P[k + dy:k + dy + H, k + dx:k + dx + W]
    m /= w.sum()
    return np.abs(m - L) / np.maximum(L, 1e-12)


def smoothness(scene, st, name, passes, seed):
    """Pixels whose kept prediction is below their radius after ``passes``
    FPPM passes, with the planes rule and without it: how smooth is the
    reference there (disc_error at 2 px, the initial radius), against the
    pixels that hold?"""
    import tempfile
    from fppm.tools.metrics import luminance
    ref = np.load(os.path.join(tempfile.gettempdir(), "fppm_bench_refs",
                               f"{name}_200x300000.npz"))["ref"]
    L = luminance(ref)
    e = disc_error(L, st.initial_radius_px).reshape(-1)
    for planes in (False, True):
        r = Renderer(scene, st.replace(seed=seed, max_passes=passes), log=lambda s: None)
        if not planes:
            cp = r.tracer.chain_params
            r.tracer.chain_params = lambda cp=cp: cp()._replace(own_planes=False)
        for _ in range(passes):
            r.step()
        s = r.state
        R = np.sqrt(s.R2)
        seen = (s.R2 > 0) & (L.reshape(-1) > 0)
        below = seen & np.isfinite(s.r_pred_last) & (s.r_pred_last < R)
        rest = seen & ~below
        print(f"{name} seed {seed} pass {passes}, planes {planes}: held {np.mean(s.held[seen]):.1%}, "
              f"prediction below R at {below.sum() / seen.sum():.1%} of the pixels; reference disc "
              f"error at {st.initial_radius_px:g} px, median below / rest {np.median(e[below]):.4f} / "
              f"{np.median(e[rest]):.4f}; share above 2.5 %: {np.mean(e[below] > 0.025):.1%} / "
              f"{np.mean(e[rest] > 0.025):.1%}")


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-planes", action="store_true",
                    help="march as before: the segment's own surfaces may be occluders")
    ap.add_argument("--smoothness", type=int, default=0, metavar="K",
                    help="after K passes: the reference's smoothness where the prediction "
                         "is below the radius, with and without the planes rule")
    a = ap.parse_args(argv)
    scene, st = export(a.scene)
    if a.smoothness:
        return smoothness(scene, st, a.scene, a.smoothness, a.seed)
    r = Renderer(scene, st.replace(seed=a.seed, max_passes=a.passes), log=lambda s: None)
    rec = record(r, a.passes)
    tr = r.tracer
    R_med = float(np.median(np.sqrt(r.state.R2[r.state.R2 > 0])))
    planes = {} if a.no_planes else dict(n_start=rec["ng0"], n_end=rec["ng"])
    a_occ, t_occ = march_occlusion(tr.occ_grid, rec["o"], rec["d"], rec["t"], tr.occ_locality,
                                   return_t=True, **planes)
    inf = np.full_like(a_occ, np.inf)
    r_occ = arrive_radius(tr, rec["spec"], rec["d"], rec["t"], rec["ng"], a_occ, t_occ)
    r_free = arrive_radius(tr, rec["spec"], rec["d"], rec["t"], rec["ng"], inf, inf)
    occ = np.isfinite(a_occ)
    print(f"{a.scene} seed {a.seed} pass {a.passes}: {len(a_occ)} frequency deposits, "
          f"{occ.mean():.1%} occluded; voxel diagonal {tr.occ_grid.voxel_diagonal:.4f} m, "
          f"locality {tr.occ_locality:.4f} m; median pixel radius {R_med:.4f} m")
    print(f"  below R_med: {np.mean(r_occ < R_med):.1%} of deposits (without the march "
          f"{np.mean(r_free < R_med):.1%})")
    sub = {k: v[occ] for k, v in rec.items()}
    cls, l_true = classify(scene, sub, a_occ[occ], t_occ[occ])
    l_m = np.sqrt(a_occ[occ])
    small = r_occ[occ] < R_med
    from_end = (rec["t"][occ] - t_occ[occ])
    names = ("receiver", "source", "behind", "other")
    diag = tr.occ_grid.voxel_diagonal
    for c, nm in enumerate(names):
        m = cls == c
        if not m.any():
            print(f"  {nm:>9}: none")
            continue
        print(f"  {nm:>9}: {m.mean():.1%} of occluded, {np.mean(m[small]) if small.any() else 0:.1%} "
              f"of those below R_med; l march/true median {np.median(l_m[m] / np.maximum(l_true[m], 1e-9)):.2f}; "
              f"blocker from end median {np.median(from_end[m]) / diag:.1f} diag, from start "
              f"{np.median(t_occ[occ][m]) / diag:.1f} diag; r occ/free median "
              f"{np.median(r_occ[occ][m] / np.maximum(r_free[occ][m], 1e-12)):.3f}")
    np.savez(os.path.join(os.environ.get("TMPDIR", "/tmp"), f"occ_truth_{a.scene}.npz"),
             cls=cls, l_true=l_true, l_m=l_m, r_occ=r_occ, r_free=r_free, occ=occ,
             t_occ=t_occ, a_occ=a_occ, R_med=R_med, **rec)


if __name__ == "__main__":
    main()
