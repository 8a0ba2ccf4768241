"""Where FPPM's error differs from PPM's at equal passes, pixel by pixel, against a
file reference (docs/method.md "The glass sphere at equal passes, round 17").

    .venv/bin/python bench/diag_glass_equal_passes.py glass_sphere --passes 100 \
        --report 10,25,50,100 --seeds 0,2 --methods fppm,ppm,fppm:grow=1 --out /tmp/glass-diag

The file's resolution and photons, every method and seed stepped in one process (one numba
thread, Renderer.step), against ``fppm converge``'s reference of bench/converge_examples.py
SCENES (bench_hold_alpha.cycles_reference).  The same seed gives FPPM and PPM the same photons
and camera samples, so the per-pixel difference of their squared relative errors is paired.
Writes ``OUT/METHOD_sSEED.npz`` per method and seed: the images at the report passes
(``img_P``, (H, W, 3) float64), R^2 and the held flags there (``R2_P``, ``held_P``, (P,)),
relMSE and CPU seconds per pass (``relmse``, ``cpu``), ``R2_1`` / ``held_first`` (after pass
1), ``held_n`` (passes each pixel held so far) and ``R2`` / ``held`` / ``rp`` (r_pred_last) /
``E`` (photons per sector cell) at the last report pass (the file is rewritten at each).
The reference and its region masks go to ``OUT/ref.npz`` ("all": the pixels it vouches for,
tools.converge.references.trusted_masks; relMSE is over those).  Method names as
bench_hold_alpha.py's ('fppm:hmax=0', 'fppm:through=1', 'fppm:hold_alpha=0.7:release=0.7').
"""
from __future__ import annotations

import argparse
import os
import sys
import time

if "numba" not in sys.modules:
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_hold_alpha as B  # noqa: E402

from fppm.core.render import Renderer  # noqa: E402
from fppm.core.sppm.update import SECTOR_CELLS  # noqa: E402
from fppm.tools.converge.references import trusted_masks  # noqa: E402
from fppm.tools.metrics import region_masks, relmse  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--passes", type=int, default=100)
    ap.add_argument("--report", default="10,25,50,100")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--methods", default="fppm,ppm")
    ap.add_argument("--out", default="/tmp/glass-diag")
    a = ap.parse_args()
    say = lambda s: print(s, flush=True)  # noqa: E731
    os.makedirs(a.out, exist_ok=True)
    ref, floor, trusted = B.cycles_reference(a.scene, lambda s, **_: None, trusted=True)
    ref = np.asarray(ref[..., :3], np.float64)
    scene, base = B.export(a.scene, 100)
    masks = trusted_masks(region_masks(ref), trusted)
    np.savez_compressed(os.path.join(a.out, "ref.npz"), ref=ref, floor=floor, **masks)
    say(f"# {a.scene}: {base.photons_per_pass} photons/pass, {ref.shape[1]}x{ref.shape[0]}, "
        f"reference floor {floor:.3e} over its {int(trusted.sum())} trusted pixels, "
        f"load {os.getloadavg()[0]:.1f}")
    methods, seeds = a.methods.split(","), [int(s) for s in a.seeds.split(",")]
    report = [int(p) for p in a.report.split(",")]
    rs, rec = {}, {}
    for m in methods:
        for s in seeds:
            r = Renderer(scene, B.method_settings(base, m).replace(seed=s, max_passes=a.passes),
                         log=lambda t: None)
            B.radii_variant(r, m)
            B.planes_or(r, m)
            rs[m, s] = r
            rec[m, s] = {"relmse": [], "cpu": []}
    for p in range(1, a.passes + 1):
        for k, r in rs.items():
            c0 = time.process_time()
            img = np.asarray(r.step().image[..., :3], np.float64)
            B.settle(r)
            d = rec[k]
            d["cpu"].append(time.process_time() - c0)
            d["relmse"].append(relmse(img, ref, trusted))
            st = r.state
            held = None if getattr(st, "held", None) is None else np.asarray(st.held).copy()
            if p == 1:
                d["R2_1"] = st.R2.copy()
                if held is not None:
                    d["held_first"] = held
            if held is not None:
                d["held_n"] = d.get("held_n", 0) + held.astype(np.int32)
            if p in report:
                d[f"img_{p}"] = img
                d[f"R2_{p}"] = st.R2.copy()
                if held is not None:
                    d[f"held_{p}"] = held
        if p in report:
            say(f"# pass {p}, load {os.getloadavg()[0]:.1f}: " + "; ".join(
                f"{m} s{s} {rec[m, s]['relmse'][-1]:.4e}" for m in methods for s in seeds))
            save(a.out, rs, rec, p, say)


def save(out, rs, rec, p, say):
    """Write every method's and seed's record with its state at pass p."""
    for (m, s), r in rs.items():
        d, st = dict(rec[m, s]), r.state
        d["R2"] = st.R2.copy()
        if getattr(st, "held", None) is not None:
            d["held"] = np.asarray(st.held).copy()
        if getattr(st, "r_pred_last", None) is not None:
            d["rp"] = np.asarray(st.r_pred_last).copy()
        if getattr(st, "sectors", None) is not None:
            d["E"] = st.sectors.sum(axis=1) / SECTOR_CELLS
        d["relmse"], d["cpu"] = np.array(d["relmse"]), np.array(d["cpu"])
        np.savez_compressed(os.path.join(out, f"{m.replace(':', '_')}_s{s}.npz"), **d)
        say(f"{m} seed {s}: relMSE at pass {p} {d['relmse'][-1]:.4e}, CPU {d['cpu'].sum():.1f} s")


if __name__ == "__main__":
    main()
