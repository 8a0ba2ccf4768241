"""Occlusion grid build: time and memory on random and realistic scenes.

    .venv/bin/python bench/bench_occlusion.py

Prints, per scene, the build's wall and CPU seconds by stage, its peak RSS,
the grid's size and the march's throughput on random segments (see
:func:`bench_occlusion_grid`).  Not a test.
"""
from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from core.frequency.occlusion_grid import (BYTES_PER_VOXEL, build_occlusion_grid,  # noqa: E402
                                           default_locality, grid_bounds)
from core.frequency.occlusion_march import march_occlusion  # noqa: E402


def _sphere_mesh(n_tri: int, center, radius):
    """UV sphere with about n_tri triangles, (T, 3, 3) float32."""
    nu = max(4, int(math.sqrt(n_tri / 4)))
    nv = max(3, n_tri // (2 * nu) + 1)
    th = np.linspace(0, np.pi, nv + 1)
    ph = np.linspace(0, 2 * np.pi, 2 * nu + 1)
    P = np.stack(np.meshgrid(th, ph, indexing="ij"), -1)
    X = np.stack([np.sin(P[..., 0]) * np.cos(P[..., 1]), np.sin(P[..., 0]) * np.sin(P[..., 1]),
                  np.cos(P[..., 0])], -1) * radius + np.asarray(center)
    a, b, c, e = X[:-1, :-1], X[1:, :-1], X[1:, 1:], X[:-1, 1:]
    tri = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3),
                          np.stack([a, c, e], -2).reshape(-1, 3, 3)])
    return tri[:n_tri].astype(np.float32)


def _rss_mb():
    """(current RSS, peak RSS since the last reset) in MB, from /proc (Linux)."""
    cur = peak = float("nan")
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    cur = int(line.split()[1]) / 1024
                elif line.startswith("VmHWM:"):
                    peak = int(line.split()[1]) / 1024
    except OSError:
        pass
    return cur, peak


def _reset_peak_rss():
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def _bench_scene(kind: str, n: int, seed: int):
    rng = np.random.default_rng(seed)
    if kind == "random":
        c = rng.random((n, 1, 3))
        return (c + (rng.random((n, 3, 3)) - 0.5) / 30.0).astype(np.float32)
    room = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]],
                     [[0, 1, 0], [1, 1, 0], [1, 1, 1]], [[0, 1, 0], [1, 1, 1], [0, 1, 1]],
                     [[0, 0, 0], [0, 1, 0], [0, 1, 1]], [[0, 0, 0], [0, 1, 1], [0, 0, 1]],
                     [[1, 0, 0], [1, 1, 1], [1, 1, 0]], [[1, 0, 0], [1, 0, 1], [1, 1, 1]]],
                    np.float32)
    return np.concatenate([room, _sphere_mesh(n, (0.5, 0.5, 0.35), 0.3)])


def _bench_case(kind: str, n: int, res: int, capped: bool, seed: int) -> dict:
    """One benchmark case, meant to run in a fresh process (clean peak RSS)."""
    g0 = build_occlusion_grid(_sphere_mesh(200, (0, 0, 0), 1.0), (-1,) * 3, (1,) * 3, 8)
    march_occlusion(g0, np.zeros((1, 3)), np.array([[0, 0, 1.0]]), np.ones(1), 0.1)  # JIT
    tri = _bench_scene(kind, n, seed)
    lo, hi = tri.reshape(-1, 3).min(0), tri.reshape(-1, 3).max(0)
    gl, gh = grid_bounds(lo, hi)
    cap = 4.0 * 2.0 * float(np.linalg.norm((gh - gl) / res)) if capped else np.inf
    rss0, _ = _rss_mb()
    _reset_peak_rss()
    st = {}
    t0, c0 = time.perf_counter(), time.process_time()
    g = build_occlusion_grid(tri, lo, hi, res, max_distance=cap, stats=st)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    _, peak = _rss_mb()
    rng = np.random.default_rng(seed + 1)
    M = 200_000
    o = rng.random((M, 3))
    d = rng.normal(size=(M, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c1 = time.process_time()
    a = march_occlusion(g, o, d, np.full(M, 0.5), default_locality(g))
    dm = time.process_time() - c1
    return dict(scene=kind + (f" (max_distance {cap:.3f})" if capped else ""), T=len(tri),
                res=res, wall=wall, cpu=cpu, stages=st, peak_mb=peak - rss0,
                grid_mb=g.nbytes / 2**20, march_mps=M / dm / 1e6,
                occluded=float(np.isfinite(a).mean()))


def bench_occlusion_grid(sizes=(100_000, 1_000_000), res: int = 64, seed: int = 0):
    """Print build time and memory for random and realistic scenes (not a test).

    random: n small triangles (edge ~ 1/30 of the unit cube) at random places
    and orientations.  realistic: a room (floor, ceiling, walls: 8 triangles)
    holding a UV sphere of n triangles -- its interior is the worst case of
    the exact distance (all triangles nearly equidistant from the centre), so
    it is also built with max_distance = 4 * default_locality.
    Each case runs in a fresh process, one at a time; memory = peak RSS of
    the build above the RSS before it (numpy and numba allocations alike).
    Also times march_occlusion on 200k random 0.5 m segments (CPU time).
    """
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    rows = []
    for n in sizes:
        for kind, capped in (("random", False), ("realistic", False), ("realistic", True)):
            with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as ex:
                r = ex.submit(_bench_case, kind, n, res, capped, seed).result()
            st = r["stages"]
            stages = ", ".join(f"{k} {v:.2f}" for k, v in st.items() if k != "overlap pairs")
            print(f"{r['scene']:30s} T={r['T']:8d} res={res}: build {r['wall']:6.2f} s wall, "
                  f"{r['cpu']:6.2f} s CPU [{stages}]; {int(st.get('overlap pairs', 0))} "
                  f"overlaps; build peak RSS +{r['peak_mb']:6.1f} MB; grid "
                  f"{r['grid_mb']:5.1f} MB ({BYTES_PER_VOXEL} B/voxel); march "
                  f"{r['march_mps']:5.2f} M segments/s CPU, {r['occluded']:.0%} occluded",
                  flush=True)
            rows.append(r)
    return rows


if __name__ == "__main__":
    bench_occlusion_grid()
