"""Where a convergence run's error lies: the final relMSE split by region.

    .venv/bin/python bench/region_shares.py docs/convergence/SCENE/RUN [RUN ...]

Reads a run folder of bench/converge_examples.py (its convergence.csv and the
pixel counts of report.md's "Regions" table) and prints, per method (means
over the seeds' last points), the relMSE of all pixels, of the smooth and the
caustic regions (disjoint: tools.metrics.region_masks), and of the rest (the
pixels in neither: edges and gradients), each with its share of the total
(relMSE x pixels).  Two runs of one scene at different pass counts show what
falls with passes (docs/method.md "What the error at 60 s is made of, round 36").
"""
from __future__ import annotations

import csv
import os
import re
import sys


def counts(run):
    txt = open(os.path.join(run, "report.md")).read()
    head = next(line for line in txt.splitlines() if line.startswith("| method | all ("))
    n = {k: int(v) for k, v in re.findall(r"(\w+) \((\d+) px\)", head)}
    return n["all"], n["smooth"], n["caustic"]


def main(runs):
    for run in runs:
        na, ns, nc = counts(run)
        last = {}
        for row in csv.DictReader(open(os.path.join(run, "convergence.csv"))):
            last[row["method"], row["seed"]] = row          # rows in order: the last wins
        for m in sorted({k[0] for k in last}):
            rows = [r for k, r in last.items() if k[0] == m]
            mean = lambda c: sum(float(r[c]) for r in rows) / len(rows)  # noqa: E731
            passes = sum(int(r["point"]) for r in rows) / len(rows)
            A, S, C = mean("relmse_all"), mean("relmse_smooth"), mean("relmse_caustic")
            rest = (A * na - S * ns - C * nc) / (na - ns - nc)
            print(f"{run}: {m}, {passes:.0f} passes (mean of {len(rows)} seeds): all {A:.3e}; "
                  f"smooth {S:.3e} ({S * ns / (A * na):.0%}, {ns} px); caustic {C:.3e} "
                  f"({C * nc / (A * na):.0%}, {nc} px); rest {rest:.3e} "
                  f"({rest * (na - ns - nc) / (A * na):.0%}, {na - ns - nc} px)")


if __name__ == "__main__":
    main(sys.argv[1:])
