"""Grid build alone: wall and CPU time of hashgrid.build_grid on one and on
all numba threads (docs/architecture.md, "Performance").

    .venv/bin/python bench/bench_grid.py [--vps 2000000] [--repeat 3]
    .venv/bin/python bench/bench_grid.py --kept [--repeat 5]

--kept: on all threads, builds into new arrays (buffers=None) against
builds into kept buffers (core.kept.KeptBuffers, as the photon pass does),
interleaved; CPU, system time and minor page faults of each build (the
radii scaled by 0.97 to 1.03 from build to build, as passes change them).

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


def kept_vs_new(p, R, act, repeat: int) -> None:
    """--kept: fresh arrays against kept buffers, interleaved, all threads."""
    import resource
    from core.kept import KeptBuffers
    kb = KeptBuffers()
    rows = {"new": [], "kept": []}
    rng = np.random.default_rng(1)
    for i in range(repeat + 1):
        Ri = R * rng.uniform(0.97, 1.03)
        for name, buf in (("new", None), ("kept", kb)):
            u0 = resource.getrusage(resource.RUSAGE_SELF)
            c0 = time.process_time()
            g = Hg.build_grid(p, Ri, act, buffers=buf)
            c = time.process_time() - c0
            u1 = resource.getrusage(resource.RUSAGE_SELF)
            if i:                                        # the first: warm-up
                rows[name].append((c, u1.ru_stime - u0.ru_stime, u1.ru_minflt - u0.ru_minflt))
            if name == "new":
                ref = g
            else:
                assert np.array_equal(ref.cell_start, g.cell_start)
                assert np.array_equal(ref.vp_ids, g.vp_ids)
            del g
        del ref
    print(f"{p.shape[0]:,} VPs, {numba.get_num_threads()} threads; load average "
          f"{os.getloadavg()[0]:.1f}; CPU / system time / minor faults a build, "
          f"min and median of {repeat}:")
    for name, r in rows.items():
        a = np.array(r)
        print(f"  {name:4s}: CPU {a[:, 0].min():.3f} / {np.median(a[:, 0]):.3f} s, "
              f"system {a[:, 1].min():.3f} / {np.median(a[:, 1]):.3f} s, "
              f"faults {a[:, 2].min():,.0f} / {np.median(a[:, 2]):,.0f}")
    print(f"  kept buffers: {kb.allocations} allocated, {kb.reused} takes reused, "
          f"{kb.nbytes() / 2**20:.0f} MiB reserved")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--vps", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--kept", action="store_true",
                    help="new arrays against kept buffers (all threads)")
    a = ap.parse_args(argv)
    p, R, act = box_vps(a.vps)
    if a.kept:
        return kept_vs_new(p, R, act, a.repeat)
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
