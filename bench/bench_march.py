"""Occlusion march micro-benchmark: the photon segments of bench_render's Cornell box.

    .venv/bin/python bench/bench_march.py [--photons 40000] [--repeat 15]
                                          [--ref OLD_OCCLUSION.py ...] [--no-dense]
                                          [--planes] [--blend NAME]

Captures the segments the frequency photons march (the numpy chains of
tests/oracle_photons.py call ``march_occlusion``; the compiled path marches the
same segments inside core.frequency.kernels), then times the block march
(``occlusion_march.march_segment``) against the dense voxel-by-voxel reference
(tests/oracle_occlusion.py) and, with ``--ref``, against another version of
core/frequency/occlusion_march.py (e.g. ``git show
HEAD~1:core/frequency/occlusion_march.py > /tmp/old.py``; a core/occlusion.py
of before the split works too), on the same segments and 200k random ones,
and checks that a_occ (and t_occ against --ref) are bit-identical.  Ratios
only, each the best of ``--repeat`` interleaved runs and the median of the
paired ratios (process CPU time; the machine is shared); the us/segment
figure is for scale.  ``--no-dense`` leaves out the dense march.
``--planes``: the photon segments are marched as the tracer marches them,
with the end planes of the surfaces they connect and their radius cuts
(``occlusion_march.march_segments``' planes and cut; the cuts are inf here:
the capture sets no pixel radii), against --ref's ``_march_cut``.
``--blend NAME``: the segments of example_blends/NAME.blend's scene (its
frequency photons, exported as bench/bench_hold_alpha.py does) instead of
bench_render's Cornell box.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from core.frequency import occlusion_march as Occ  # noqa: E402
import oracle_occlusion  # noqa: E402
import oracle_photons  # noqa: E402


def capture(photons: int, seed: int = 1, blend: str = ""):
    """(grid, locality, o, d, t_end, planes, cut) of the marched segments of
    `photons` frequency photons in bench_render's Cornell box (or the scene
    of example_blends/`blend`.blend); planes (N, 2) and cut (N, 3) as
    ``march_segments`` takes them."""
    from core.render import Renderer
    from core.settings import RenderSettings
    if blend:
        import fppm_alias  # noqa: F401  (core.x is fppm.core.x)
        from bench_hold_alpha import export
        scene, st = export(blend)
    else:
        import bench_render as BR
        scene, st = BR.cornell(64), RenderSettings(integrator="PHOTON")
    r = Renderer(scene, st.replace(max_passes=10, photons_per_pass=photons,
                                   use_frequency=True, frequency_start=1), log=lambda s: None)
    tr = oracle_photons.use_numpy_chains(r.tracer)
    segs = []
    f = oracle_photons.march_occlusion

    def rec(grid, o, d, t, loc, **k):
        o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
        planes = np.full((len(o), 2), np.inf)
        for j, key in enumerate(("n_start", "n_end")):
            if k.get(key) is not None:
                planes[:, j] = Occ.plane_cosines(
                    np.ascontiguousarray(np.asarray(k[key], np.float64).reshape(-1, 3)), d)
        cut = (np.full((len(o), 3), np.inf) if k.get("cut") is None
               else np.asarray(k["cut"], np.float64))
        segs.append((o.copy(), d.copy(), np.array(t, np.float64), planes, cut.copy()))
        return f(grid, o, d, t, loc, **k)
    oracle_photons.march_occlusion = rec
    try:
        tr.trace(photons, photons, np.random.default_rng(seed))
    finally:
        oracle_photons.march_occlusion = f
    o, d, t, planes, cut = (np.ascontiguousarray(np.concatenate([s[k] for s in segs]))
                            for k in range(5))
    return r.occ_grid, float(r.occ_locality), o, d, t, planes, cut


def _ref_march(path, g, loc, k=0, planes=None):
    """The array march of another occlusion_march.py (or a core/occlusion.py
    of before the split): f(o, d, t, out, out_t); planes: None, or (cut,
    planes) of the segments for ``_march_cut``."""
    spec = importlib.util.spec_from_file_location(
        "core.frequency._occlusion_ref" + (str(k) if k else ""), path)
    ref = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = ref                  # dataclasses look it up
    spec.loader.exec_module(ref)
    if hasattr(ref, "march_grid"):
        m = ref.march_grid(g, loc)
        if planes is not None:
            return lambda o_, d_, t_, out, ot: ref._march_cut(m, o_, d_, t_, out, ot, *planes)
        return lambda o_, d_, t_, out, ot: ref._march(m, o_, d_, t_, out, ot)
    gr = ref.OcclusionGrid(**{k: getattr(g, k) for k in g.__dataclass_fields__})
    mb = ref.march_blocks(gr)
    args = (gr.dist, gr.cone, mb.bmin, mb.bcone, mb.vmin, mb.vcone, mb.has_voxel_level, mb.B,
            gr.lo, gr.cell, gr.res)
    return lambda o_, d_, t_, out, ot: ref._march(*args, o_, d_, t_, loc, gr.voxel_diagonal,
                                                  out, ot)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--photons", type=int, default=40_000)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--ref", action="append", default=[],
                    help="another core/frequency/occlusion_march.py to compare with "
                         "(repeatable: each is timed interleaved with the others)")
    ap.add_argument("--no-dense", action="store_true",
                    help="leave out the dense reference march (slow)")
    ap.add_argument("--planes", action="store_true",
                    help="march the photon segments with their end planes and cuts (the tracer's)")
    ap.add_argument("--blend", default="",
                    help="an example_blends/ scene's segments instead of the Cornell box")
    a = ap.parse_args(argv)
    g, loc, o, d, t, planes, cut = capture(a.photons, blend=a.blend)
    t_skip = g.voxel_diagonal
    rng = np.random.default_rng(3)
    M = 200_000
    o2 = g.lo + rng.random((M, 3)) * (g.hi - g.lo)
    d2 = rng.normal(size=(M, 3))
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    t2 = rng.uniform(0, 2, M)

    m = Occ.march_grid(g, loc)
    fns = {"block march": lambda o_, d_, t_, out, ot: Occ._march(m, o_, d_, t_, out, ot)}
    for k, path in enumerate(a.ref):
        fns[f"--ref {os.path.basename(path)}"] = _ref_march(path, g, loc, k)
    if not a.no_dense:
        fns["dense march"] = lambda o_, d_, t_, out, ot: oracle_occlusion.march_dense(
            g.dist, g.cone, g.lo, g.cell, g.res, o_, d_, t_, loc, t_skip, out)
    what = f"{a.blend} photon segments" if a.blend else "Cornell photon segments"
    sets = [(what, (o, d, t), fns), ("random segments (length U(0, 2) m)", (o2, d2, t2), fns)]
    if a.planes:
        # the tracer's march: the same segments with their end planes and cuts
        fp = {"block march": lambda o_, d_, t_, out, ot: Occ._march_cut(m, o_, d_, t_, out, ot,
                                                                        cut, planes)}
        for k, path in enumerate(a.ref):
            fp[f"--ref {os.path.basename(path)}"] = _ref_march(path, g, loc, k + len(a.ref),
                                                               (cut, planes))
        sets.insert(1, (what + ", with their end planes and cuts", (o, d, t), fp))

    for name, (oo, dd, tt), fs in sets:
        N = len(oo)
        res, ts = {}, {k: [] for k in fs}
        for rep in range(a.repeat + 1):           # first round: compilation
            for k, f in fs.items():
                out, ot = np.empty(N), np.full(N, np.inf)
                t0 = time.process_time()
                f(oo, dd, tt, out, ot)
                if rep:
                    ts[k].append(time.process_time() - t0)
                res[k] = (out, ot)
        base = min(ts["block march"])
        print(f"{name}: {N} segments, {np.isfinite(res['block march'][0]).mean():.0%} occluded; "
              f"block march {base / N * 1e6:.2f} us/segment (scale only)")
        for k in fs:
            if k == "block march":
                continue
            same_a = np.array_equal(res[k][0], res["block march"][0])
            same_t = np.array_equal(res[k][1], res["block march"][1]) if k != "dense march" else None
            med = np.median(np.array(ts[k]) / np.array(ts["block march"]))
            print(f"  {k} / block march: {min(ts[k]) / base:.3f}x (paired median {med:.3f}x); identical a_occ: {same_a}"
                  + ("" if same_t is None else f", t_occ: {same_t}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
