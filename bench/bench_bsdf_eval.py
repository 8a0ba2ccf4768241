"""CPU of one compiled BSDF evaluation and one BSDF sample, per material.

    .venv/bin/python bench/bench_bsdf_eval.py [--pairs 200000] [--repeat 3]
        [--scenes principled_interior,real_scene,glass_sphere,cornell,ring_principled]
        [--save OUT.npz | --compare OTHER.npz]

For every material of the example scenes (and the warm-up scene's metal and
normal-mapped ones): ``pairs`` random pairs (normals, views and lights on both
sides, random lobe colours; the same seed for every code), timed in one loop
each, best of ``repeat``, one thread:

- ``materials.compiled.eval_pair`` (radiance mode, the receivers' smooth sum
  asked for: the gather's and camera paths' call), and ``eval_pair_as`` in
  importance mode without and with the Normal Map / Bump corrections;
- ``materials.compiled.sample_batch`` (``sample_pair``) in importance and
  radiance mode;
- and, as the ratio's base in the same process, a loop that reads the same
  inputs and sums one dot product a pair (``loads``): what a pair costs before
  any BSDF.

Printed: ns a call per lobe combination (lobe kinds of ``core.scene.model``:
0 DIFFUSE, 1 GLOSSY, 2 GLASS ...), and the ratio to ``loads``.  ``--save``
writes every result array, ``--compare`` checks another tree's saved arrays
bit for bit against this one's: run this file of each tree in turn, each with
its own ``FPPM_CACHE_DIR`` (numba's cache is stamped by a kernel's own file):
docs/architecture.md "The BSDF evaluation's fixed cost, round 32".
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))

SCENES = "principled_interior,real_scene,glass_sphere,cornell,ring_principled"


def material_tables(scenes):
    """[(name, MaterialTable)]: the example scenes' and the warm-up scene's."""
    from bench_hold_alpha import export
    from fppm.core.materials.table import build_material_table
    from fppm.core.warmup import warmup_scene
    out = []
    for name in scenes:
        sc, _ = export(name, 25)
        out.append((name, build_material_table(sc.materials, sc.textures)))
    w = warmup_scene(metal=True, normal_map=True)
    out.append(("warmup", build_material_table(w.materials, w.textures)))
    return out


def _kernels():
    from fppm.core.materials import compiled as C

    @njit(cache=False)
    def evals(lobes, T, colors, m, ns, ng, v, l, mode, out):
        for i in range(ns.shape[0]):
            if mode == 0:
                r = C.eval_pair(lobes, T, m, colors, i, ns[i, 0], ns[i, 1], ns[i, 2], ng[i, 0],
                                ng[i, 1], ng[i, 2], v[i, 0], v[i, 1], v[i, 2], l[i, 0], l[i, 1],
                                l[i, 2], True)
            else:
                r = C.eval_pair_as(lobes, T, m, colors, i, ns[i, 0], ns[i, 1], ns[i, 2],
                                   ng[i, 0], ng[i, 1], ng[i, 2], v[i, 0], v[i, 1], v[i, 2],
                                   l[i, 0], l[i, 1], l[i, 2], False, mode == 2)
            for c in range(6):
                out[i, c] = r[c]

    @njit(cache=False)
    def loads(lobes, T, colors, m, ns, ng, v, l, out):
        for i in range(ns.shape[0]):
            s = ((ns[i, 0] * l[i, 0] + ns[i, 2] * l[i, 2]) + ns[i, 1] * l[i, 1]
                 + ng[i, 0] * v[i, 0] + colors[i, 0, 0] + lobes[m, 0, 0] + T[0])
            out[i, 0] = s

    return C, evals, loads


def _best(f, repeat):
    best = np.inf
    for _ in range(repeat):
        t = time.process_time()
        f()
        best = min(best, time.process_time() - t)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scenes", default=SCENES)
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--save")
    g.add_argument("--compare")
    a = ap.parse_args(argv)
    C, evals, loads = _kernels()
    N = a.pairs
    results, rows = {}, {}
    for name, tab in material_tables(a.scenes.split(",")):
        cm, sel = C.compile_materials(tab), C.selection_table(tab)
        lobes, T = cm.lobes, cm.tables
        for m in range(lobes.shape[0]):
            rng = np.random.default_rng([7, m])
            unit = lambda x: x / np.linalg.norm(x, axis=1, keepdims=True)  # noqa: E731
            ng = unit(rng.normal(size=(N, 3)))
            ns = unit(ng + 0.2 * rng.normal(size=(N, 3)))
            v, l = unit(rng.normal(size=(N, 3))), unit(rng.normal(size=(N, 3)))
            v = np.where((np.sum(v * ng, 1) < 0)[:, None] & (rng.random((N, 1)) < 0.8), -v, v)
            l = np.where((np.sum(l * ng, 1) < 0)[:, None] & (rng.random((N, 1)) < 0.7), -l, l)
            colors = rng.random((N, lobes.shape[1], 3)).astype(np.float32)
            u = rng.random((N, 3))
            mat = np.full(N, m, np.int64)
            kinds = tuple(int(lobes[m, j, C.F_KIND]) for j in range(lobes.shape[1])
                          if lobes[m, j, C.F_KIND] >= 0)
            out = np.empty((N, 6))
            loads(lobes, T, colors, m, ns, ng, v, l, out)
            base = _best(lambda: loads(lobes, T, colors, m, ns, ng, v, l, out), a.repeat)
            for mode, label in ((0, "eval radiance"), (1, "eval importance"), (2, "eval bump")):
                evals(lobes, T, colors, m, ns, ng, v, l, mode, out)
                t = _best(lambda: evals(lobes, T, colors, m, ns, ng, v, l, mode, out), a.repeat)
                results[f"{name}/{m}/{label}"] = out.copy()
                rows.setdefault((kinds, label), []).append((t / N, base / N))
            for radiance in (False, True):
                wi, wt = np.empty((N, 3)), np.empty((N, 3))
                pdf, fl = np.empty(N), np.empty(N, np.int8)

                def run():
                    C.sample_batch(lobes, T, sel, mat, ns, ng, v, u, radiance, wi, wt, pdf, fl)
                run()
                t = _best(run, a.repeat)
                label = "sample radiance" if radiance else "sample importance"
                results[f"{name}/{m}/{label}"] = np.concatenate(
                    [wi, wt, pdf[:, None], fl[:, None]], 1)
                rows.setdefault((kinds, label), []).append((t / N, base / N))
    print(f"{N} pairs a material, best of {a.repeat}, CPU ns a call (÷ the loads-only loop)")
    for (kinds, label), v in sorted(rows.items(), key=str):
        t = np.mean([x[0] for x in v]) * 1e9
        b = np.mean([x[1] for x in v]) * 1e9
        print(f"  lobes {str(kinds):10s} {label:18s} {t:7.1f} ns  ({t / b:5.1f}x, {len(v)} materials)")
    if a.save:
        np.savez(a.save, **results)
        print(f"saved {len(results)} arrays to {a.save}")
    if a.compare:
        other = np.load(a.compare)
        same = [np.array_equal(results[k], other[k], equal_nan=True) for k in results]
        print(f"bit for bit against {a.compare}: {sum(same)} of {len(same)} arrays identical")
        return 0 if all(same) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
