"""Read an ``fppm converge`` CSV at equal passes: what of an equal-CPU ratio is cost and what is
the error of a pass (docs/method.md "The glass sphere at 128²").

    .venv/bin/python bench/converge_equal_passes.py docs/convergence/glass_sphere/fppm_ppm_60s/convergence.csv \
        [--methods fppm,ppm] [--passes 10,40,160,380] [--fractions 0.1,0.5,1]

The CSV has one row per method, seed and ladder point (pass) with its CPU seconds and the relMSE
of the whole image and of each region.  Prints, for A / B (--methods):

- at equal passes: the ratio of the seeds' mean relMSE, whole image and per region, and the ratio
  seed by seed (the same seed: the same camera and photon streams, so a shared firefly cancels);
- at equal CPU (the fractions of the largest CPU any run reached, as the converge report reads
  them): the pass each run had reached, the mean ratio, and the ratio with each seed left out;
- every jump of a run's relMSE by 1.5x or more from one pass to the next (a rare photon of large
  weight, a firefly: its term in the progressive estimate (1/i) sum_k Phi_k / (pi R_k^2 n) then
  falls as 1/i, its squared error as 1/i^2, so a run that is d passes behind at equal CPU reads
  ((i + d) / i)^2 its error while the firefly dominates).
"""
from __future__ import annotations

import argparse
import csv
from collections import defaultdict

import numpy as np


def load(path):
    """{(method, seed): {pass: row}} of a converge CSV (ladder points as passes)."""
    runs = defaultdict(dict)
    for r in csv.DictReader(open(path)):
        runs[r["method"], int(r["seed"])][int(r["point"])] = r
    return runs


def at_cpu(run, t):
    """(pass, relMSE) of a run at CPU time t: the last pass whose CPU is <= t."""
    ps = sorted(run)
    cpu = np.array([float(run[p]["cpu_seconds"]) for p in ps])
    i = max(int(np.searchsorted(cpu, t, side="right")) - 1, 0)
    return ps[i], float(run[ps[i]]["relmse_all"])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("csv")
    ap.add_argument("--methods", default="fppm,ppm")
    ap.add_argument("--passes", default="10,40,160,380")
    ap.add_argument("--fractions", default="0.1,0.5,1")
    a = ap.parse_args()
    runs = load(a.csv)
    A, B = a.methods.split(",")
    seeds = sorted(s for m, s in runs if m == A and (B, s) in runs)
    regions = [k[len("relmse_"):] for k in next(iter(runs[A, seeds[0]].values())) if k.startswith("relmse_")]
    print(f"# {a.csv}: {A} / {B}, seeds {seeds}")
    for p in [int(x) for x in a.passes.split(",")]:
        if not all(p in runs[A, s] and p in runs[B, s] for s in seeds):
            continue
        parts = []
        for reg in regions:
            ea = [float(runs[A, s][p]["relmse_" + reg]) for s in seeds]
            eb = [float(runs[B, s][p]["relmse_" + reg]) for s in seeds]
            parts.append(f"{reg} {np.mean(ea) / np.mean(eb):.3f}")
        per = [float(runs[A, s][p]["relmse_all"]) / float(runs[B, s][p]["relmse_all"]) for s in seeds]
        cpu = [float(runs[A, s][p]["cpu_seconds"]) / float(runs[B, s][p]["cpu_seconds"]) for s in seeds]
        print(f"equal passes, pass {p}: " + ", ".join(parts) + "; seed by seed (all) "
              + " / ".join(f"{x:.3f}" for x in per) + "; CPU to reach it "
              + " / ".join(f"{x:.2f}" for x in cpu))
    T = max(float(r["cpu_seconds"]) for run in runs.values() for r in run.values())
    for fr in [float(x) for x in a.fractions.split(",")]:
        t = fr * T
        pa = {s: at_cpu(runs[A, s], t) for s in seeds}
        pb = {s: at_cpu(runs[B, s], t) for s in seeds}
        mean = np.mean([pa[s][1] for s in seeds]) / np.mean([pb[s][1] for s in seeds])
        out = [np.mean([pa[s][1] for s in seeds if s != o]) / np.mean([pb[s][1] for s in seeds if s != o])
               for o in seeds]
        print(f"equal CPU {t:.1f} s: ratio {mean:.3f}; passes {A} / {B} "
              + ", ".join(f"{pa[s][0]} / {pb[s][0]}" for s in seeds) + "; without seed "
              + ", ".join(f"{o}: {x:.3f}" for o, x in zip(seeds, out)))
    for (m, s), run in sorted(runs.items()):
        ps = sorted(run)
        e = [float(run[p]["relmse_all"]) for p in ps]
        jumps = [f"pass {ps[i]} x{e[i] / e[i - 1]:.1f}" for i in range(1, len(ps)) if e[i] >= 1.5 * e[i - 1]]
        if jumps:
            print(f"jumps {m} seed {s}: " + ", ".join(jumps))


if __name__ == "__main__":
    main()
