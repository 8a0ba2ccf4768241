"""Grid build alone: wall and CPU time of hashgrid.build_grid on one and on
all numba threads (docs/architecture.md, "Performance").

    .venv/bin/python bench/bench_grid.py [--vps 2000000] [--repeat 3]

The visible points are random points on three faces of a unit box (the
Cornell box's kind of distribution), radii uniform in [0.5, 1.5] / sqrt(K);
both builds give the same grid (checked here).  Best wall and best CPU of
--repeat (each the minimum over the runs), warm, interleaved.
"""
import argparse
import os
import sys
import time

import numba
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from core.sppm import hashgrid as Hg  # noqa: E402


def box_vps(K: int, seed: int = 0):
    """(K, 3) positions on three faces of the unit box, (K,) radii, (K,) active."""
    rng = np.random.default_rng(seed)
    p = rng.random((K, 3))
    p[np.arange(K), rng.integers(0, 3, K)] = 0.0
    return p, rng.uniform(0.5, 1.5, K) / np.sqrt(K), np.ones(K, bool)


def timed(threads, p, R, act):
    numba.set_num_threads(threads)
    w0, c0 = time.perf_counter(), time.process_time()
    g = Hg.build_grid(p, R, act)
    return time.perf_counter() - w0, time.process_time() - c0, g


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--vps", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    p, R, act = box_vps(a.vps)
    T = numba.config.NUMBA_NUM_THREADS
    for t in (1, T):
        timed(t, p, R, act)                              # compile / warm
    best = {}
    for _ in range(a.repeat):                            # interleaved: same load for both
        for t in (1, T):
            w, c, g = timed(t, p, R, act)
            b = best.get(t, (np.inf, np.inf))
            best[t] = (min(b[0], w), min(b[1], c))
            if t == 1:
                ref = g
            else:
                assert np.array_equal(ref.cell_start, g.cell_start)
                assert np.array_equal(ref.vp_ids, g.vp_ids)
    print(f"{a.vps:,} VPs, {ref.summary()}; load average {os.getloadavg()[0]:.1f}")
    for t in (1, T):
        w, c = best[t]
        print(f"  {t} thread(s): best {w:.3f} s wall, best {c:.3f} s CPU")
    print(f"  {T} threads / 1: wall {best[T][0] / best[1][0]:.2f}x, "
          f"CPU {best[T][1] / best[1][1]:.2f}x")


if __name__ == "__main__":
    sys.exit(main())
