"""Reference for example_blends/point_caustic.blend from Mitsuba 3's light tracer.

Cycles cannot render the caustic of a radius-0 point light, so the reference
comes from an unbiased light tracer (Mitsuba 3 ``ptracer``; the camera sees
only diffuse surfaces, which is what a light tracer needs).  Three steps, two
Python environments (Mitsuba is not a project dependency):

    .venv/bin/python bench/point_caustic_reference.py export  SCENE.npz      # bpy -> arrays
    MITSUBA_PY bench/point_caustic_reference.py render  SCENE.npz HALVES.npz --spp N [--seeds 11,12]
    .venv/bin/python bench/point_caustic_reference.py finish  HALVES.npz [HALVES2.npz ...] REF.exr

``export`` writes the scene FPPM renders (core.scene.model.Scene from
addon.export.export_scene: corner positions and normals per triangle,
diffuse/glass materials, lights, camera).  ``render`` (in an environment with
``pip install mitsuba``, variant scalar_rgb) renders two halves of N/2
samples with different seeds (default 11 and 12).  ``finish`` writes REF.exr:
Combined = their mean, Variance = (A - B)^2 / 4 (what ``fppm converge
--reference`` reads).  Given several HALVES files (renders of other seeds),
``finish`` first joins them: half A is the sample-weighted mean of every
file's first half, B of the second halves.  The 65536-spp reference of
bench/converge_examples.py is ``--spp 16384`` (seeds 11, 12) joined with
``--spp 49152 --seeds 13,14`` (docs/peers.md "References rebuilt, round 16").

Mitsuba is installed in a virtual environment of its own, never in .venv:
``python3.13 -m venv /tmp/mitsuba-venv && /tmp/mitsuba-venv/bin/pip install
mitsuba numpy`` (MITSUBA_PY = /tmp/mitsuba-venv/bin/python).

Unit match (core/lights/lights.py, module docstring): a Cycles point light
of power P has intensity I = P / (4 pi) W/sr in Cycles' radiance units, which
is Mitsuba's ``point`` ``intensity``.  Pixel filter: Cycles' Blackman-Harris of width w
(support +-w px) is replaced by Mitsuba's Gaussian with the same standard
deviation (0.3 px for w = 1.5), a small difference at edges only.
"""
from __future__ import annotations

import json
import math
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLEND = os.path.join(ROOT, "example_blends", "point_caustic.blend")


def blackman_harris_std(width: float = 1.5, n: int = 4001) -> float:
    """Standard deviation [px] of Cycles' Blackman-Harris filter of support +-width."""
    x = np.linspace(-width, width, n)
    u = (x + width) / (2 * width)
    w = (0.35875 - 0.48829 * np.cos(2 * np.pi * u) + 0.14128 * np.cos(4 * np.pi * u)
         - 0.01168 * np.cos(6 * np.pi * u))
    return float(np.sqrt((w * x * x).sum() / w.sum()))


def export(out_npz: str) -> None:
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    import fppm_alias  # noqa: F401  (fppm.* importable)
    import bpy
    from fppm.addon.export import export_scene
    bpy.ops.wm.open_mainfile(filepath=BLEND, load_ui=False, use_scripts=False)
    s = export_scene(bpy.context.evaluated_depsgraph_get(), log=print)
    from fppm.core.scene.model import DIFFUSE, GLASS
    mats = []
    for m in s.materials:
        if len(m.lobes) != 1 or m.lobes[0].kind not in (DIFFUSE, GLASS) or any(m.emission):
            raise SystemExit(f"material {m.name}: only single diffuse or glass lobes are converted")
        lb = m.lobes[0]
        if lb.kind == GLASS and lb.roughness > 0:
            raise SystemExit(f"material {m.name}: rough glass is not converted")
        mats.append((m.name, "diffuse" if lb.kind == DIFFUSE else "glass", lb.color, lb.ior))
    lights = []
    for lt in s.lights:
        if lt.kind != "POINT" or lt.radius > 0:
            raise SystemExit(f"light {lt.name}: only radius-0 point lights are converted")
        lights.append((lt.matrix_world[:3, 3], np.asarray(lt.strength) / (4 * np.pi)))
    c = s.camera
    if c.kind != "PERSP" or c.shift_x or c.shift_y or c.border is not None:
        raise SystemExit("only an unshifted perspective camera without border is converted")
    W, H = (int(v) for v in c.resolution)
    fit = c.sensor_fit if c.sensor_fit != "AUTO" else ("HORIZONTAL" if W >= H else "VERTICAL")
    sensor = c.sensor_width if (c.sensor_fit == "AUTO" or fit == "HORIZONTAL") else c.sensor_height
    fov = math.degrees(2 * math.atan(0.5 * sensor / c.lens))
    np.savez(out_npz, tri_p=s.tri_p, tri_n=s.tri_n, tri_mat=s.tri_mat,
             mat_kind=np.array([m[1] for m in mats]), mat_color=np.array([m[2] for m in mats]),
             mat_ior=np.array([m[3] for m in mats]),
             light_pos=np.array([l[0] for l in lights]), light_I=np.array([l[1] for l in lights]),
             cam=c.matrix_world, fov=fov, fov_axis="x" if fit == "HORIZONTAL" else "y",
             res=np.array([W, H]), filter_std=blackman_harris_std(s.filter_width),
             world=np.asarray(s.world_color))
    print(f"exported {len(s.tri_p)} triangles, {len(mats)} materials, {len(lights)} lights, "
          f"{W}x{H}, fov {fov:.3f} deg -> {out_npz}")


def render(in_npz: str, out_npz: str, spp: int, seeds=(11, 12)) -> None:
    import time
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    from mitsuba import ScalarTransform4f as T
    d = np.load(in_npz)
    if np.any(d["world"] > 0):
        raise SystemExit("a world colour is not converted")
    C = d["cam"]
    o, fwd, up = C[:3, 3], -C[:3, 2], C[:3, 1]
    W, H = (int(v) for v in d["res"])
    scene = {"type": "scene",
             "integrator": {"type": "ptracer", "max_depth": -1, "rr_depth": 8,
                            "hide_emitters": True},
             "sensor": {"type": "perspective", "fov": float(d["fov"]), "fov_axis": str(d["fov_axis"]),
                        "near_clip": 0.01, "far_clip": 1000.0,
                        "to_world": T().look_at(origin=o.tolist(), target=(o + fwd).tolist(),
                                                up=up.tolist()),
                        "film": {"type": "hdrfilm", "width": W, "height": H, "pixel_format": "rgb",
                                 "rfilter": {"type": "gaussian", "stddev": float(d["filter_std"])}},
                        "sampler": {"type": "independent", "sample_count": 1}}}
    for i, (kind, col, ior) in enumerate(zip(d["mat_kind"], d["mat_color"], d["mat_ior"])):
        sel = d["tri_mat"] == i
        if not np.any(sel):
            continue
        P = d["tri_p"][sel].reshape(-1, 3).astype(np.float32)
        N = d["tri_n"][sel].reshape(-1, 3).astype(np.float32)
        if kind == "diffuse":
            bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": col.tolist()}}
        else:
            if np.any(np.abs(col - 1) > 1e-6):
                raise SystemExit("tinted glass is not converted")
            bsdf = {"type": "dielectric", "int_ior": float(ior), "ext_ior": 1.0}
        scene[f"mesh{i}"] = {"type": "ply", "filename": _write_ply(P, N, f"/tmp/fppm_pc_{i}.ply"),
                             "bsdf": bsdf, "face_normals": False}
    for j, (p, I) in enumerate(zip(d["light_pos"], d["light_I"])):
        scene[f"light{j}"] = {"type": "point", "position": p.tolist(),
                              "intensity": {"type": "rgb", "value": I.tolist()}}
    sc = mi.load_dict(scene)
    halves, cpu = [], 0.0
    for seed in seeds:
        t0, c0 = time.time(), time.process_time()
        img = np.array(mi.render(sc, spp=spp // 2, seed=seed), dtype=np.float64)
        dc = time.process_time() - c0
        cpu += dc
        print(f"half seed {seed}: {spp // 2} spp in {time.time() - t0:.1f} s ({dc:.1f} CPU s), "
              f"mean {img.mean(axis=(0, 1))}, load {os.getloadavg()[0]:.1f}", flush=True)
        halves.append(img[..., :3])
    np.savez(out_npz, a=halves[0], b=halves[1], spp=spp, seeds=np.array(seeds), cpu=cpu)


def _write_ply(P, N, path):
    """Binary little-endian PLY with positions and normals, one vertex per corner."""
    nv = len(P)
    nf = nv // 3
    head = ("ply\nformat binary_little_endian 1.0\n"
            f"element vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\n"
            f"element face {nf}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    v = np.concatenate([P, N], axis=1).astype("<f4")
    f = np.zeros(nf, dtype=[("n", "u1"), ("i", "<i4", 3)])
    f["n"] = 3
    f["i"] = np.arange(nv, dtype="<i4").reshape(nf, 3)
    with open(path, "wb") as fh:
        fh.write(head)
        fh.write(v.tobytes())
        fh.write(f.tobytes())
    return path


def join_halves(in_npzs: list[str]):
    """(A, B, spp, seeds, CPU s) of several ``render`` outputs: each half the
    sample-weighted mean of the files' halves (their seeds must differ)."""
    ds = [np.load(p) for p in in_npzs]
    seeds = [int(s) for d in ds for s in (d["seeds"] if "seeds" in d else (11, 12))]
    if len(set(seeds)) != len(seeds):
        raise SystemExit(f"shared seeds in {in_npzs}: {seeds}")
    w = np.array([float(d["spp"]) for d in ds])
    a = sum(wi * d["a"] for wi, d in zip(w, ds)) / w.sum()
    b = sum(wi * d["b"] for wi, d in zip(w, ds)) / w.sum()
    cpu = sum(float(d["cpu"]) for d in ds if "cpu" in d)
    return a, b, int(w.sum()), seeds, cpu


def finish(in_npzs: list[str], out_exr: str) -> None:
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    import fppm_alias  # noqa: F401
    from fppm.core.io.exr import write_exr
    from fppm.tools.metrics import reference_floor
    a, b, spp, seeds, cpu = join_halves(in_npzs)
    ref = 0.5 * (a + b)
    var = 0.25 * (a - b) ** 2
    floor = reference_floor(ref, var)
    meta = {"source": "mitsuba3 ptracer", "samples": spp, "seeds": seeds,
            "cpu_seconds": round(cpu, 1)}
    write_exr(out_exr, {"Combined": ref.astype(np.float32), "Variance": var.astype(np.float32)},
              {"fppm:reference": json.dumps(meta)})
    print(f"wrote {out_exr}: {spp} spp, seeds {seeds}, {cpu:.0f} CPU s, "
          f"mean {ref.mean(axis=(0, 1))}, relMSE floor {floor:.3g}")


if __name__ == "__main__":
    cmd = sys.argv[1]
    if cmd == "export":
        export(sys.argv[2])
    elif cmd == "render":
        spp = int(sys.argv[sys.argv.index("--spp") + 1]) if "--spp" in sys.argv else 1024
        seeds = (tuple(int(x) for x in sys.argv[sys.argv.index("--seeds") + 1].split(","))
                 if "--seeds" in sys.argv else (11, 12))
        if len(seeds) != 2:
            raise SystemExit("--seeds takes two seeds (one a half)")
        render(sys.argv[2], sys.argv[3], spp, seeds)
    elif cmd == "finish":
        finish(sys.argv[2:-1], sys.argv[-1])
    else:
        raise SystemExit(__doc__)
