"""What a frequency pass of the doubling schedule changes: per pass k = 2, 4,
8, ... the share of pixels whose kept prediction (r_pred_last) or hold
changes in that pass, the frequency photons it traced, and its CPU against
the passes around it (without frequency photons).

    .venv/bin/python bench/bench_frequency_decisions.py principled_interior [--passes 128] \
        [--decays 0.5,2] [--photons 100000] [--percent 50]

The protocol of bench/bench_hold_alpha.py (64x64, one numba thread);
docs/method.md "The frequency schedule and the first 10 %".
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_hold_alpha import export  # noqa: E402

from fppm.core.render import Renderer  # noqa: E402
from fppm.core.sppm.photon_pass import frequency_pass, frequency_photons  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--passes", type=int, default=128)
    ap.add_argument("--decays", default="0.5,2")
    ap.add_argument("--photons", type=int, default=100_000)
    ap.add_argument("--percent", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    scene, base = export(a.scene, a.percent)
    base = base.replace(photons_per_pass=a.photons, seed=a.seed, max_passes=0, time_limit=1e9)
    decays = [float(d) for d in a.decays.split(",")]
    rs = {d: Renderer(scene, base.replace(frequency_decay=d), log=lambda s: None) for d in decays}
    rows = {d: [] for d in decays}
    for k in range(1, a.passes + 1):
        for d, r in rs.items():               # interleaved: the load drifts over both
            last, held = r.state.r_pred_last.copy(), r.state.held.copy()
            c0 = time.process_time()
            r.step()
            cpu = time.process_time() - c0
            valid = np.isfinite(r.state.r_pred_last) | np.isfinite(last)
            changed = ~np.isclose(np.nan_to_num(r.state.r_pred_last, nan=-1.0, posinf=-2.0),
                                  np.nan_to_num(last, nan=-1.0, posinf=-2.0), rtol=1e-12)
            rows[d].append((k, frequency_photons(r.settings, k, True), cpu,
                            float(np.mean(changed)), float(np.mean(r.state.held != held)),
                            float(np.mean(valid))))
    print(f"# {a.scene} {a.percent}% {a.photons} photons/pass seed {a.seed}; load {os.getloadavg()[0]:.1f}")
    for d in decays:
        R = rows[d]
        cpu = np.array([x[2] for x in R])
        for k, nf, c, ch, hh, v in R:
            if frequency_pass(k) and k > 1:
                # the passes without frequency photons just before k (k/2+1 .. k-1), median CPU
                around = [cpu[j - 1] for j in range(max(2, k // 2 + 1), k) if not frequency_pass(j)]
                ref = np.median(around) if around else float("nan")
                print(f"decay {d:g} pass {k:4d}: {nf:6d} frequency photons, predictions changed "
                      f"{100 * ch:6.2f} %, holds changed {100 * hh:5.2f} % (of all pixels; predicted "
                      f"{100 * v:.0f} %), CPU {1e3 * c:.1f} ms vs {1e3 * ref:.1f} ms (median of "
                      f"the passes before without)", flush=True)
        print(f"decay {d:g}: total CPU {cpu.sum():.1f} s over {len(R)} passes; passes 2-4 "
              f"{cpu[1:4].sum():.2f} s", flush=True)


if __name__ == "__main__":
    main()
