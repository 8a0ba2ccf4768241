"""Are frequency photons ordinary photons?  Their deposits against the classic photons' of the same passes.

    .venv/bin/python bench/bench_photon_populations.py principled_interior [--warm 8] [--reps 12]
        [--photons 100000] [--share 0.5]

The protocol of bench/bench_hold_alpha.py (64x64, one numba thread): an FPPM
render is stepped ``--warm`` passes for realistic visible points and radii;
then, with that pass's visible points and radii fixed, ``--reps`` batches of
``--photons`` photons are traced, the first ``--share`` of each carrying a
spectrum (one batch, as the renderer traces them), and the two kinds'
deposits are gathered apart.  Per pixel, each kind's flux estimate
(Phi / its photons) over the reps gives a mean and a variance; the
frequency photons must have the classic ones' (a photon plus its spectrum).
Prints the deposits per photon, the power distribution, the bounce
histogram, and per region (tools/metrics.region_masks of the image) the
mean ratio and the variance ratio of the per-pixel estimates.
"""
from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import fppm_alias  # noqa: E402,F401

from fppm.core.render import Renderer  # noqa: E402
from fppm.core.sppm import hashgrid  # noqa: E402
from fppm.core.mathutil import LUMINANCE  # noqa: E402


def gather(pp, pg, dep, acc):
    """PhotonPass._trace_gather's gather of the deposits dep (dict) into acc."""
    vp, P = pg.vp, pg.vp.valid.shape[0]
    buf = pp._buffers(P)
    g = hashgrid.gather(pg.grid, dep["p"], dep["ng"], dep["wi"], dep["power"], dep["rpred"],
                        vp.p, vp.ng, pg.R2, vp.const, cos_ng=-1.0, want_freq_pairs=False,
                        buffers=buf, clip=pg.clip)
    buf.fold(acc.M, acc.Phi, vp.albedo, np.pi, acc.r_pred, None, acc.sectors, pg.clip)
    if g.pair_vp.size:
        pp._reflected(vp, dep, g.pair_vp, g.pair_ph, acc.Phi, pg.clip)


def subset(dep, keep):
    return {k: np.ascontiguousarray(v[keep]) for k, v in dep.items()}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--warm", type=int, default=8)
    ap.add_argument("--reps", type=int, default=12)
    ap.add_argument("--photons", type=int, default=100_000)
    ap.add_argument("--share", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    from bench_hold_alpha import export
    scene, base = export(a.scene)
    st = base.replace(photons_per_pass=a.photons, seed=a.seed)
    r = Renderer(scene, st, log=lambda s: None)
    for _ in range(a.warm):
        r.step()
    vp, _ = r.camera_pass(r._rng(a.warm + 1, 0), lambda: None)
    pp, tr = r.photon_pass, r.tracer
    tr.set_reach(vp.p, vp.valid, r.state.R2)
    tr.set_radius_cut(r.state.R2)
    P = vp.valid.shape[0]
    pg = pp.begin(vp, r.state.R2.copy(), False)
    n, nf = a.photons, int(round(a.share * a.photons))
    est = {"freq": [], "classic": []}
    deps = {"freq": [], "classic": []}
    for rep in range(a.reps):
        rng = np.random.default_rng([a.seed, 777, rep])
        dep = tr.trace(n, nf, rng)
        fr = ~np.isnan(dep["rpred"])
        for kind, keep, count in (("freq", fr, nf), ("classic", ~fr, n - nf)):
            acc = pp._zero_sums(P, None)
            acc.Phi[:] = 0.0
            acc.M[:] = 0.0
            sub = subset(dep, keep)
            gather(pp, pg, sub, acc)
            est[kind].append((acc.Phi * vp.beta) @ LUMINANCE / count)
            pw = sub["power"] @ LUMINANCE
            deps[kind].append((keep.sum() / count, pw.mean(), np.mean(pw ** 2), pw.max(),
                               np.bincount(sub["bounce"], minlength=12)[:12] / count,
                               np.sum(pw > 5 * pw.mean()) / count))
    print(f"# {a.scene}: {n} photons a rep, {nf} with a spectrum, {a.reps} reps, "
          f"after {a.warm} FPPM passes; load {os.getloadavg()[0]:.1f}", flush=True)
    for kind in ("freq", "classic"):
        d = deps[kind]
        print(f"{kind:>8}: deposits/photon {np.mean([x[0] for x in d]):.4f} "
              f"(sd {np.std([x[0] for x in d]):.4f}); mean power {np.mean([x[1] for x in d]):.4e}; "
              f"E[power^2] {np.mean([x[2] for x in d]):.4e}; max {np.max([x[3] for x in d]):.3e}; "
              f">5x mean per photon {np.mean([x[5] for x in d]):.2e}")
        print(f"{'':>8}  deposits per photon by bounce: "
              + " ".join(f"{v:.4f}" for v in np.mean([x[4] for x in d], axis=0)))
    F, C = np.array(est["freq"]), np.array(est["classic"])
    mF, mC = F.mean(0), C.mean(0)
    vF, vC = F.var(0, ddof=1), C.var(0, ddof=1)
    ok = vp.valid & (mC > 0)
    from fppm.tools.metrics import region_masks
    img = np.zeros((r.height, r.width, 3))
    img[..., :] = (r.last_result.image[..., :3])
    masks = {"all": np.ones((r.height, r.width), bool), **region_masks(img)}
    for name, mk in masks.items():
        m = ok & mk.ravel()
        if not m.any():
            continue
        # The whole region's estimate: sum over its pixels (means and the
        # variance of the sum over reps).
        sF, sC = F[:, m].sum(1), C[:, m].sum(1)
        print(f"{name:>10} ({m.sum()} px): mean F/C {mF[m].sum() / mC[m].sum():.4f} "
              f"(region sums' sd F {sF.std(ddof=1) / sF.mean():.4f} C {sC.std(ddof=1) / sC.mean():.4f}); "
              f"per-pixel var F/C: mean {vF[m].sum() / vC[m].sum():.3f}, median "
              f"{np.median(vF[m] / np.maximum(vC[m], 1e-300)):.3f}; relvar F "
              f"{np.mean(vF[m] / mC[m] ** 2):.3e} C {np.mean(vC[m] / mC[m] ** 2):.3e}", flush=True)


if __name__ == "__main__":
    main()
