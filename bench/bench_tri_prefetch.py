"""The bounce kernel's prefetch of the hit triangles' data, replayed.

One photon chunk's bounce-kernel calls on the Cornell box of
``bench_render.cornell`` (``--subdiv N``: 30 N^2 triangles, the same
surfaces) are captured (copies of their inputs), then replayed on fresh
copies by the kernel of a base commit (``--base``: no prefetch), by this
tree's (``photon_kernels.TRI_PREFETCH`` rays ahead), by a second compilation
of the base kernel (the noise) and by this tree's compiled again with each
``--prefetch`` distance, interleaved in one process, the order rotated each
round.  Each call is timed on the thread's CPU clock, its input copies made
outside the clock.  Prints per variant the sum over the chunk's calls, min /
median over the rounds, the median (min, max) of the per-round ratios to the
base, and whether every variant wrote the same deposits, generic hits and
survivors (bit for bit) as the base.

    FPPM_CACHE_DIR=... .venv/bin/python bench/bench_tri_prefetch.py --subdiv 183 --rounds 8 --prefetch 0,12

docs/architecture.md "The bounce kernel's triangle reads, round 19".
"""
import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

from bench_render import cornell  # noqa: E402
from core.render import Renderer  # noqa: E402
from core.settings import RenderSettings  # noqa: E402
from core.sppm import photon_kernels as PK  # noqa: E402

CHUNK = 131_072


def copy(x):
    """Deep copy of a kernel argument: NamedTuples and tuples of arrays."""
    if isinstance(x, np.ndarray):
        return x.copy()
    if isinstance(x, tuple):
        items = [copy(v) for v in x]
        return type(x)(*items) if hasattr(x, "_fields") else tuple(items)
    return x


def load_copy(name: str, source: str):
    """The module core.sppm.<name> compiled from source (its own numba kernels)."""
    path = os.path.join(tempfile.gettempdir(), f"fppm_{name}_{os.getpid()}.py")
    with open(path, "w") as f:
        f.write(source)
    spec = importlib.util.spec_from_file_location(f"core.sppm.{name}", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--subdiv", type=int, default=1)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--base", default="d453c65")
    ap.add_argument("--prefetch", default="",
                    help="comma-separated TRI_PREFETCH values: this tree's kernel compiled "
                         "again with each (variants 'pfD'; 0: no prefetch)")
    a = ap.parse_args(argv)
    src = subprocess.run(["git", "-C", ROOT, "show", f"{a.base}:core/sppm/photon_kernels.py"],
                         check=True, capture_output=True, text=True).stdout
    base, base2 = load_copy("_pk_base", src), load_copy("_pk_base2", src)
    scene = cornell(a.res, subdiv=a.subdiv, height=a.res)
    r = Renderer(scene, RenderSettings(integrator="PHOTON", max_passes=1000,
                                       photons_per_pass=200_000, use_frequency=False),
                 log=lambda s: None)
    r.step()
    r.photon_pass.drop_next()                    # no chunk traced ahead in a thread
    t = r.photon_pass.tracer
    calls = []
    kernel = PK.bounce_kernel

    def capture(*args):
        calls.append(copy(args))
        return kernel(*args)

    PK.bounce_kernel = capture
    try:
        t.trace(CHUNK, 0, np.random.default_rng(11))
    finally:
        PK.bounce_kernel = kernel
    tris = t.tris
    variants = {"base": base.bounce_kernel, f"pf{PK.TRI_PREFETCH}": kernel,
                "base again": base2.bounce_kernel}
    here = open(PK.__file__).read()
    line = f"TRI_PREFETCH = {PK.TRI_PREFETCH}\n"
    for d in filter(None, a.prefetch.split(",")):
        mod = load_copy(f"_pk_pf{d}", here.replace(line, f"TRI_PREFETCH = {int(d)}\n"))
        variants[f"pf{d}"] = mod.bounce_kernel
    K = sum(c[0].K for c in calls)
    print(f"{30 * a.subdiv ** 2:,} triangles, {len(calls)} calls, {K:,} rays; the arrays a "
          f"hit reads: {sum(getattr(tris, f).nbytes for f in ('p', 'ng', 'ns', 'flat', 'mat')) / 2**20:.1f}"
          f" MiB")

    def replay(fn, keep=False):
        cpu, outs = 0.0, []
        for c in calls:
            step, hits, live, _, mats, u, dep, gen, rec, mis = copy(c)
            c0 = time.thread_time()
            res = fn(step, hits, live, tris, mats, u, dep, gen, rec, mis)
            cpu += time.thread_time() - c0
            if keep:
                n_next, n_dep, n_gen = res
                outs.append((res, dep.p[:n_dep].copy(), dep.ng[:n_dep].copy(),
                             dep.wi[:n_dep].copy(), dep.power[:n_dep].copy(),
                             gen.ns[:n_gen].copy(), live.o32[:n_next].copy(),
                             live.d64[:n_next].copy(), live.power[:n_next].copy()))
        return cpu, outs

    ref = None
    for name, fn in variants.items():                # compile + the bits
        _, outs = replay(fn, keep=True)
        if ref is None:
            ref = outs
        same = all(o[0] == q[0] and all(np.array_equal(x, y, equal_nan=True)
                                        for x, y in zip(o[1:], q[1:]))
                   for o, q in zip(outs, ref))
        print(f"  {name}: the same outputs as base: {same}")
    names = list(variants)
    times = {n: [] for n in names}
    for k in range(a.rounds):
        order = names[k % len(names):] + names[:k % len(names)]
        for n in order:
            times[n].append(replay(variants[n])[0])
    b = np.array(times["base"])
    for n in names:
        v = np.array(times[n])
        print(f"  {n:11s} CPU ms: min {v.min() * 1e3:.2f}, median {np.median(v) * 1e3:.2f}; "
              f"ratio to base, median of rounds {np.median(v / b):.3f} "
              f"(min {np.min(v / b):.3f}, max {np.max(v / b):.3f})")
    print("load:", os.getloadavg())


if __name__ == "__main__":
    main()
