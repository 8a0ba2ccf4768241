"""Benchmark of the SPPM photon gather (core/sppm/hashgrid.py) against Embree ray casting.

    .venv/bin/python bench/bench_gather.py [--quick]

Scenes (K = 256 x 256 = 65,536 visible points, R = 1.5 pixel footprints, VP
spacing = 1 pixel footprint, 600,000 photon hits on the same surfaces, 25%
frequency photons, 10% of the VPs non-constant (pairs)):
  plane: VPs on the square z = 0 (flat, axis-aligned),
  box:   VPs on 5 walls of a cube, photons too (3D extent).
Both pick the dense layout automatically; the "hash" row forces the spatial hash.

Printed: gather throughput in photon hits/s for the numba kernel (1 thread and
all threads) and a vectorised-numpy gather over the same grid (CSR lookup +
np.repeat + bincount), each as a ratio to the Embree ray rate
(EmbreeScene.run(origins, dirs, output=1), 200k random triangles) measured in
the same process, alternating with the gather (the machine is shared: both
sides of a ratio see the same load; each is the best of a few runs).
Ratio > 1: gathering one photon hit costs less than casting one ray.  Also a
sweep of the cell size factor (h = factor * median R).
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numba  # noqa: E402

from core.sppm import hashgrid as hg  # noqa: E402

RES = 256
N_PHOTONS = 600_000
R_PX = 1.5


def hemisphere(rng, n, normals):
    """Uniform directions on the hemisphere around each normal (n, 3)."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    flip = np.einsum("ij,ij->i", d, normals) < 0
    d[flip] *= -1
    return d


def scene_plane(rng):
    s = 1.0 / RES
    u = (np.arange(RES) + 0.5) * s
    X, Y = np.meshgrid(u, u, indexing="ij")
    vp_pos = np.stack([X.ravel(), Y.ravel(), np.zeros(RES * RES)], axis=1)
    vp_ng = np.tile([0.0, 0.0, 1.0], (RES * RES, 1))
    ph_pos = np.concatenate([rng.random((N_PHOTONS, 2)), np.zeros((N_PHOTONS, 1))], axis=1)
    ph_ng = np.tile(np.float32([0, 0, 1]), (N_PHOTONS, 1))
    return vp_pos, vp_ng, R_PX * s, ph_pos, ph_ng


def scene_box(rng):
    """Unit cube without its +y wall (open towards the camera); 5 walls with
    inward normals; VPs on a jittered grid per wall, same total K."""
    K = RES * RES
    walls = [  # (axis, coordinate, inward normal sign)
        (0, 0.0, +1), (0, 1.0, -1), (1, 0.0, +1), (2, 0.0, +1), (2, 1.0, -1)]
    per = K // len(walls)
    n_side = int(np.ceil(np.sqrt(per)))
    s = 1.0 / n_side

    def on_walls(n_per, grid):
        pos, nrm = [], []
        for ax, c, sg in walls:
            if grid:
                u = (np.arange(n_side) + 0.5) * s
                A, B = np.meshgrid(u, u, indexing="ij")
                ab = np.stack([A.ravel(), B.ravel()], axis=1)[:n_per]
            else:
                ab = rng.random((n_per, 2))
            p = np.empty((len(ab), 3))
            others = [a for a in range(3) if a != ax]
            p[:, ax] = c
            p[:, others[0]] = ab[:, 0]
            p[:, others[1]] = ab[:, 1]
            n = np.zeros((len(ab), 3))
            n[:, ax] = sg
            pos.append(p)
            nrm.append(n)
        return np.concatenate(pos), np.concatenate(nrm)

    vp_pos, vp_ng = on_walls(per, True)
    extra = K - len(vp_pos)       # pad to exactly K with floor VPs
    if extra:
        vp_pos = np.concatenate([vp_pos, vp_pos[:extra] * [1, 1, 0]])
        vp_ng = np.concatenate([vp_ng, np.tile([0, 0, 1.0], (extra, 1))])
    ph_pos, ph_ng = on_walls(N_PHOTONS // len(walls), False)
    return vp_pos, vp_ng, R_PX * s, ph_pos, ph_ng.astype(np.float32)


def make_case(name, rng):
    vp_pos, vp_ng, R, ph_pos, ph_ng = (scene_plane if name == "plane" else scene_box)(rng)
    K, P = len(vp_pos), len(ph_pos)
    vp_R = np.full(K, R)
    ph_wi = hemisphere(rng, P, ph_ng.astype(np.float64)).astype(np.float32)
    return dict(
        vp_pos=vp_pos, vp_ng=vp_ng, vp_R=vp_R, vp_R2=vp_R * vp_R,
        vp_const=rng.random(K) >= 0.10, active=np.ones(K, bool),
        ph_pos=ph_pos.astype(np.float32), ph_ng=ph_ng, ph_wi=ph_wi,
        ph_power=rng.random((P, 3)),
        ph_rpred=np.where(rng.random(P) < 0.25, rng.random(P) * R, np.nan))


def gather_args(c):
    return (c["ph_pos"], c["ph_ng"], c["ph_wi"], c["ph_power"], c["ph_rpred"],
            c["vp_pos"], c["vp_ng"], c["vp_R2"], c["vp_const"])


def gather_numpy(grid, ph_pos, ph_ng, ph_wi, ph_power, ph_rpred, vp_pos, vp_ng, vp_R2,
                 vp_const, cos_ng=hg.COS_NG_DEFAULT, chunk=100_000):
    """Vectorised-numpy gather over the same CSR grid (M, Phi_sum, pairs, rpred_min)."""
    K = vp_pos.shape[0]
    M = np.zeros(K, np.int64)
    Phi = np.zeros((K, 3))
    rmin = np.full(K, np.inf)
    pv, pp = [], []
    for c0 in range(0, len(ph_pos), chunk):
        x = ph_pos[c0:c0 + chunk].astype(np.float64)
        inside = np.all((x >= grid.lo) & (x <= grid.hi), axis=1)
        idx = np.nonzero(inside)[0]
        ijk = np.floor((x[idx] - grid.origin) * grid.inv_h).astype(np.int64)
        if grid.dense:
            nx, ny, _ = grid.dims
            s = ijk[:, 0] + nx * (ijk[:, 1] + ny * ijk[:, 2])
        else:
            u = ijk.astype(np.uint64)
            k = (u[:, 0] * hg._H1) ^ (u[:, 1] * hg._H2) ^ (u[:, 2] * hg._H3)
            s = ((k * hg._HM) >> np.uint64(64 - grid.log2_table)).astype(np.int64)
        e0 = grid.cell_start[s]
        n = grid.cell_start[s + 1] - e0
        ph = np.repeat(idx, n)
        # entry index = e0 of the photon + rank within its run
        run0 = np.repeat(np.cumsum(n) - n, n)
        e = np.repeat(e0, n) + (np.arange(len(ph)) - run0)
        v = grid.vp_ids[e]
        xp = x[ph]
        d = xp - vp_pos[v]
        ok = np.einsum("ij,ij->i", d, d) < vp_R2[v]
        ph, v = ph[ok], v[ok]
        ng = vp_ng[v]
        ok = (np.einsum("ij,ij->i", ph_wi[c0 + ph].astype(np.float64), ng) > 0) & \
             (np.einsum("ij,ij->i", ph_ng[c0 + ph].astype(np.float64), ng) > cos_ng)
        ph, v = ph[ok] + c0, v[ok]
        M += np.bincount(v, minlength=K)
        cst = vp_const[v]
        for ch in range(3):
            Phi[:, ch] += np.bincount(v[cst], ph_power[ph[cst], ch], minlength=K)
        pv.append(v[~cst])
        pp.append(ph[~cst])
        r = ph_rpred[ph]
        f = ~np.isnan(r)
        np.minimum.at(rmin, v[f], r[f])
    return M, Phi, np.concatenate(pv), np.concatenate(pp), rmin


class EmbreeReference:
    """EmbreeScene.run(origins, dirs, output=1) on ~200k small random triangles
    in the unit cube (a triangle soup; rays start inside it and mostly hit)."""

    def __init__(self, rng, n_tris=200_000, n_rays=300_000):
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh
        c = rng.random((n_tris, 1, 3))
        tri = (c + 0.005 * rng.normal(size=(n_tris, 3, 3))).astype(np.float32)
        self.scene = rtcs.EmbreeScene()
        TriangleMesh(self.scene, tri)
        self.o = rng.random((n_rays, 3)).astype(np.float32)
        d = rng.normal(size=(n_rays, 3))
        self.d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
        self.scene.run(self.o[:1000], self.d[:1000], output=1)   # BVH build untimed
        self.n_rays = n_rays

    def seconds(self):
        t0 = time.perf_counter()
        self.scene.run(self.o, self.d, output=1)
        return time.perf_counter() - t0


def interleaved(emb, f, repeat=3):
    """(best seconds of f, best ray rate) measured alternately, so that load
    from other processes on the shared machine hits both sides of the ratio."""
    tf = tr = np.inf
    out = None
    for _ in range(repeat):
        tr = min(tr, emb.seconds())
        t0 = time.perf_counter()
        out = f()
        tf = min(tf, time.perf_counter() - t0)
    return tf, emb.n_rays / tr, out


def main():
    quick = "--quick" in sys.argv
    rng = np.random.default_rng(1)
    n_thr = numba.get_num_threads()
    print(f"numba threads: {n_thr}; photons {N_PHOTONS}, K = {RES * RES}, R = {R_PX} px; "
          f"ratios are photon hits/s over Embree rays/s, measured alternately")
    emb = EmbreeReference(rng, n_rays=100_000 if quick else 300_000)

    for name in ("plane", "box"):
        c = make_case(name, rng)
        P = len(c["ph_pos"])
        args = gather_args(c)
        # warm up (compilation is cached on disk, but the first call loads it)
        g = hg.build_grid(c["vp_pos"], c["vp_R"], c["active"])
        hg.gather(g, *[a[:1000] for a in args[:5]], *args[5:], parallel=False)
        hg.gather(g, *[a[:1000] for a in args[:5]], *args[5:], parallel=True)
        tb, _, g = interleaved(emb, lambda: hg.build_grid(c["vp_pos"], c["vp_R"],
                                                         c["active"]))
        print(f"\n[{name}] {g.summary()}; build {tb * 1e3:.1f} ms")
        rows = []
        t1, rate1, r1 = interleaved(emb, lambda: hg.gather(g, *args, parallel=False))
        hits = int(r1.M.sum())
        print(f"  counted (photon, VP) hits: {hits} ({hits / P:.2f} per photon), "
              f"pairs {len(r1.pair_vp)}")
        rows.append(("numba, 1 thread", t1, rate1))
        if n_thr > 1:
            tp, ratep, rp = interleaved(emb, lambda: hg.gather(g, *args, parallel=True))
            assert np.array_equal(rp.M, r1.M) and np.allclose(rp.Phi_sum, r1.Phi_sum)
            rows.append((f"numba, {n_thr} threads", tp, ratep))
        gh = hg.build_grid(c["vp_pos"], c["vp_R"], c["active"], layout="hash")
        th, rateh, rh = interleaved(emb, lambda: hg.gather(gh, *args, parallel=False))
        assert np.array_equal(rh.M, r1.M)
        rows.append(("numba 1 thr., hash", th, rateh))
        n_np = 200_000 if not quick else 50_000
        sub = [a[:n_np] for a in args[:5]] + list(args[5:])
        tn, raten, rn = interleaved(emb, lambda: gather_numpy(g, *sub),
                                    repeat=1 if quick else 2)
        ref = hg.gather(g, *sub, parallel=False)
        assert np.array_equal(rn[0], ref.M), "numpy variant disagrees with numba"
        rows.append(("vectorised numpy", tn * P / n_np, raten))
        for label, t, ray_rate in rows:
            rate = P / t
            print(f"  {label:18s}: {rate / 1e6:6.2f} M photon hits/s = "
                  f"{rate / ray_rate:5.2f} x Embree ray rate ({ray_rate / 1e6:.2f} M/s); "
                  f"incl. build: {(t + tb) * ray_rate / P:4.2f} rays per photon")
        print(f"  numba 1 thread / vectorised numpy: {rows[-1][1] / t1:.1f}x")

        print("  cell size sweep (numba, 1 thread, build + gather, in rays per photon):")
        for f in ((1.0, 2.0) if quick else (0.75, 1.0, 1.5, 2.0, 3.0)):
            tbf, rb, gf = interleaved(emb, lambda: hg.build_grid(
                c["vp_pos"], c["vp_R"], c["active"], cell_factor=f), repeat=2)
            tgf, rg, _ = interleaved(emb, lambda: hg.gather(gf, *args, parallel=False),
                                     repeat=2)
            print(f"    h = {f:4.2f} R: {gf.n_entries / gf.n_active:5.1f} entries/VP, "
                  f"build {tbf * 1e3:5.1f} ms, gather {tgf * 1e3:6.1f} ms -> "
                  f"{tbf * rb / P + tgf * rg / P:4.2f}")


if __name__ == "__main__":
    main()
