"""Where FPPM's excess over PPM sits at equal passes, pixel by pixel (docs/method.md
"The glass sphere at 128²").

    .venv/bin/python bench/diag_held_caustic.py glass_sphere --passes 128 --report 16,32,64,128 \
        --seeds 0,1 --ref-passes 200 --methods fppm,fppm:orE=5,cppm,ppm

The file's resolution and photons (as ``bench_hold_alpha.py --full --photons 0``), every method
and seed stepped in one process, one numba thread, against bench_hold_alpha's PPM reference of
seed 100 (``--ref-passes`` x 300,000 photons, cached under $TMPDIR).  At each report pass, per
method: relMSE and its split over the reference's caustic region (tools.metrics.region_masks)
and the rest; over the caustic, the share of FPPM's squared error in pixels held at that pass and
the kind of hold (the first method's state: its counts too few to test, E < 5 per sector cell,
"retained"; the spectrum's prediction >= R, "spectrum"; else the uniformity test), the photons
per sector cell E and R / R_PPM there; with two seeds the bias^2 estimate (the product of the
two seeds' signed relative errors, relMSE's per-pixel term otherwise) summed like relMSE.
"""
from __future__ import annotations

import argparse
import os
import sys

if "numba" not in sys.modules:
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_hold_alpha as B  # noqa: E402

from fppm.core.render import Renderer  # noqa: E402
from fppm.core.sppm.update import CHI2_MIN_EXPECTED, SECTOR_CELLS  # noqa: E402
from fppm.tools.metrics import RELMSE_EPS, region_masks, relmse  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--passes", type=int, default=128)
    ap.add_argument("--report", default="16,32,64,128")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--ref-passes", type=int, default=200)
    ap.add_argument("--ref-photons", type=int, default=300_000)
    ap.add_argument("--methods", default="fppm,ppm")
    ap.add_argument("--percent", type=int, default=100)
    a = ap.parse_args()
    say = lambda s: print(s, flush=True)  # noqa: E731
    scene, base = B.export(a.scene, a.percent)
    ref, floor = B.reference(a.scene, scene, base, a.ref_passes, a.ref_photons, say, a.percent)
    say(f"# {a.scene} {a.percent} %: {base.photons_per_pass} photons/pass; reference "
        f"{a.ref_passes} x {a.ref_photons} PPM seed 100, floor {floor:.3e}")
    H, W = ref.shape[:2]
    caustic = region_masks(ref)["caustic"]
    say(f"# caustic region: {caustic.sum()} of {H * W} pixels")
    g = ref.mean(axis=2)
    methods = a.methods.split(",")
    seeds = [int(s) for s in a.seeds.split(",")]
    report = [int(p) for p in a.report.split(",")]
    rs = {}
    for m in methods:
        for s in seeds:
            r = Renderer(scene, B.method_settings(base, m).replace(seed=s, max_passes=a.passes),
                         log=lambda t: None)
            B.radii_variant(r, m)
            B.planes_or(r, m)
            rs[m, s] = r
    snaps = {}
    for p in range(1, a.passes + 1):
        img = {}
        for k, r in rs.items():
            img[k] = np.asarray(r.step().image[..., :3], np.float64)
        if p not in report:
            continue
        snaps[p] = (img, {k: (r.state.R2.copy(), np.asarray(r.state.held).copy(),
                              None if r.state.sectors is None else r.state.sectors.copy(),
                              None if r.state.r_pred_last is None else
                              np.asarray(r.state.r_pred_last).copy())
                          for k, r in rs.items()})
        say(f"# pass {p} stepped, load {os.getloadavg()[0]:.1f}")
        img, sts = snaps.pop(p)
        say(f"## pass {p}")
        sq, rel = {}, {}
        for k in rs:
            sq[k] = ((img[k] - ref) ** 2 / (ref ** 2 + RELMSE_EPS)).mean(axis=2)
            rel[k] = (img[k].mean(axis=2) - g) / np.maximum(g, 1e-6)
        n = H * W
        for m in methods:
            for s in seeds:
                R2_, held_, S_, rp_ = sts[m, s]
                R = np.sqrt(R2_).reshape(H, W)
                Rp = np.sqrt(sts["ppm", s][0]).reshape(H, W)
                ok = (R > 0) & (Rp > 0)
                held = held_.reshape(H, W)
                e = sq[m, s]
                line = (f"{m:>22} seed {s}: relmse {relmse(img[m, s], ref):.4e} "
                        f"(/ ppm {e.sum() / sq['ppm', s].sum():.3f}); caustic {e[caustic].sum() / n:.3e} "
                        f"rest {e[~caustic].sum() / n:.3e}; held {held.mean():.3f}, in caustic "
                        f"{held[caustic].mean():.3f}; R/R_ppm caustic "
                        f"{np.exp(np.mean(np.log(R[caustic & ok] / Rp[caustic & ok]))):.3f}")
                if S_ is not None and m != "ppm":
                    E = (S_.sum(axis=1) / SECTOR_CELLS).reshape(H, W)
                    rp = rp_.reshape(H, W)
                    ret = held & (E < CHI2_MIN_EXPECTED)
                    spec = held & ~ret & np.isfinite(rp) & (rp >= R)
                    uni = held & ~ret & ~spec
                    hc = held & caustic
                    line += (f"; caustic held: retained {ret[caustic].sum()}, spectrum "
                             f"{spec[caustic].sum()}, uniform {uni[caustic].sum()}; their error "
                             f"{e[ret & caustic].sum() / n:.2e} / {e[spec & caustic].sum() / n:.2e} / "
                             f"{e[uni & caustic].sum() / n:.2e}; not held {e[caustic & ~held].sum() / n:.2e}; "
                             f"E caustic held q10/50/90 "
                             + ("/".join(f"{x:.1f}" for x in np.quantile(E[hc], [.1, .5, .9]))
                                if hc.any() else "-")
                             + f", not held {np.median(E[caustic & ~held]) if (caustic & ~held).any() else 0:.1f}"
                             + f"; r_pred/R caustic median "
                             f"{np.nanmedian(np.where(np.isfinite(rp), rp, np.nan)[caustic] / R[caustic]):.2f}")
                say(line)
            if len(seeds) >= 2:
                pairs = [(i, j) for i in seeds for j in seeds if i < j]
                b2 = np.mean([rel[m, i] * rel[m, j] for i, j in pairs], axis=0)
                say(f"{m:>22} bias^2 (seed pairs): caustic {b2[caustic].sum() / n:.3e}, "
                    f"rest {b2[~caustic].sum() / n:.3e}; mean signed error caustic "
                    f"{np.mean([rel[m, s][caustic].mean() for s in seeds]):+.4f}; "
                    f"relMSE without each seed's 16 worst pixels "
                    + " ".join(f"{np.sort(sq[m, s].ravel())[:-16].sum() / n:.3e}" for s in seeds))
        # the pixels that carry the first method's excess over PPM (summed over the seeds)
        m0 = methods[0]
        d = sum(sq[m0, s] - sq["ppm", s] for s in seeds)
        say(f"excess {m0} - ppm summed over seeds: {d.sum() / n:.3e}; caustic {d[caustic].sum() / n:.3e}; "
            f"top 12 pixels carry {np.sort(d.ravel())[-12:].sum() / n:.3e}, bottom 12 "
            f"{np.sort(d.ravel())[:12].sum() / n:.3e}")
        for i in np.argsort(d.ravel())[::-1][:12]:
            y, x = divmod(int(i), W)
            R2_, held_, S_, rp_ = sts[m0, seeds[0]]
            E0 = S_[i].sum() / SECTOR_CELLS if S_ is not None else float("nan")
            say(f"  px ({y},{x}) d {d.ravel()[i] / n:.2e} ref {g.ravel()[i]:.3g} caustic {caustic.ravel()[i]} "
                f"sq {m0} " + "/".join(f"{sq[m0, s].ravel()[i]:.2f}" for s in seeds)
                + " ppm " + "/".join(f"{sq['ppm', s].ravel()[i]:.2f}" for s in seeds)
                + f" held {held_[i]} E {E0:.1f} R/Rppm {np.sqrt(R2_[i] / sts['ppm', seeds[0]][0][i]):.2f}"
                + f" rp/R {rp_[i] / np.sqrt(R2_[i]):.2f}")
        np.savez_compressed(f"/tmp/h1_diag_{a.scene}_p{p}.npz", ref=ref, caustic=caustic,
                            **{f"img_{m}_{s}": img[m, s] for m in methods for s in seeds},
                            **{f"{n}_{m}_{s}": v for m in methods for s in seeds
                               for n, v in zip(("R2", "held", "S", "rp"), sts[m, s])
                               if v is not None})

if __name__ == "__main__":
    main()
