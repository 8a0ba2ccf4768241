"""Render the Cycles references of the test scenes (tests/scenes/*.blend).

Run:  .venv/bin/python tests/references/make_references.py [name ...]
      [--scale F]   multiply every sample count by F (quick previews)

For each scene: two renders of N/2 samples with seeds 0 and 1 (Cycles CPU,
float EXR, denoising / adaptive sampling / clamping / light threshold off,
view 'Standard', caustics on, blur_glossy 0, Blackman-Harris 1.5 px filter as
the scene stores it).  Their mean is the reference; their difference gives
the reference's own noise:
  per-pixel variance of the mean   v = (A - B)^2 / 4        (1 dof / pixel)
  relMSE of the reference          mean(v / (ref^2 + 0.01)) (expected value of
                                   refs.relmse(ref, true image))
  std of the image mean            from 8x8-pixel blocks of (A - B)/2, whose
                                   means are ~independent (the 1.5 px filter
                                   only correlates neighbours).
Writes tests/references/<name>.exr, <name>_var.exr and <name>.json.
The analytic checks listed by the scene (make_test_scenes.py) get their
pixels, world points and expected values here; the script asserts them with
the same rule as tests/test_scenes_cycles.py (refs.check_agreement).
"""
from __future__ import annotations

import json
import math
import os
import platform
import re
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
TESTS = os.path.dirname(HERE)
sys.path.insert(0, TESTS)

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Vector  # noqa: E402

from scenes import refs  # noqa: E402

SEEDS = (0, 1)
FAILED = []            # analytic checks that did not hold
BLOCK = 8


# ------------------------------------------------------------------ render
def render_exr(sc, samples, seed, path):
    """Render the open scene to a float EXR; returns ((H,W,4) float32, seconds)."""
    sc.cycles.samples = samples
    sc.cycles.seed = seed
    sc.cycles.use_animated_seed = False
    im = sc.render.image_settings
    im.file_format = 'OPEN_EXR'
    im.color_depth = '32'
    im.color_mode = 'RGBA'
    im.exr_codec = 'ZIP'
    sc.render.filepath = path
    sc.render.use_file_extension = False
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    dt = time.perf_counter() - t0
    return refs.read_exr(path), dt


# ------------------------------------------------------------- camera rays
class Rays:
    """Pixel rays of the scene camera, row 0 at the top (as the EXR)."""

    def __init__(self, sc):
        self.sc = sc
        cam = sc.camera
        self.W = sc.render.resolution_x
        self.H = sc.render.resolution_y
        tr, br, bl, tl = cam.data.view_frame(scene=sc)
        self.tl, self.du, self.dv = Vector(tl), Vector(tr) - Vector(tl), Vector(bl) - Vector(tl)
        self.R = cam.matrix_world.to_3x3()
        self.o = cam.matrix_world.translation.copy()
        self.dg = bpy.context.evaluated_depsgraph_get()

    def direction(self, row, col, dy=0.0, dx=0.0):
        u = (col + 0.5 + dx) / self.W
        v = (row + 0.5 + dy) / self.H
        return (self.R @ (self.tl + u * self.du + v * self.dv)).normalized()

    def cast(self, d, dist=1e6):
        hit, loc, nor, idx, ob, _ = self.sc.ray_cast(self.dg, self.o, d, distance=dist)
        return (ob.name if hit else None), (loc if hit else None)

    def frame(self):
        """World-space camera frame for refs.camera_rays (json-ready)."""
        R = self.R
        return {"origin": list(self.o), "top_left": list(R @ self.tl),
                "du": list(R @ self.du), "dv": list(R @ self.dv),
                "width": self.W, "height": self.H}

    def project(self, p):
        """(row, col) in pixel-centre coordinates of world point p."""
        from bpy_extras.object_utils import world_to_camera_view
        co = world_to_camera_view(self.sc, self.sc.camera, Vector(p))
        return (1 - co.y) * self.H - 0.5, co.x * self.W - 0.5


# Offsets covering Cycles' Blackman-Harris support: +-filter_width = +-1.5 px
# (refs.blackman_harris).  The regions tested are convex or nearly so.
FOOTPRINT = [(dy, dx) for dy in (-1.5, -0.75, 0, 0.75, 1.5)
             for dx in (-1.5, -0.75, 0, 0.75, 1.5)]


def _light_hit(ob, o, d):
    """Distance along ray (o, d) to the emitting side of area light ob, or None."""
    M = ob.matrix_world
    Mi = M.inverted()
    ol = Mi @ o
    dl = (Mi.to_3x3() @ d)
    if dl.z <= 1e-12 or ol.z >= 0:    # emits towards local -Z: camera on that side
        return None
    t = -ol.z / dl.z
    q = ol + t * dl
    L = ob.data
    a, b = L.size / 2, (L.size_y if L.shape in ('RECTANGLE', 'ELLIPSE') else L.size) / 2
    if L.shape in ('SQUARE', 'RECTANGLE'):
        inside = abs(q.x) <= a and abs(q.y) <= b
    else:
        inside = (q.x / a) ** 2 + (q.y / b) ** 2 <= 1
    if not inside:
        return None
    return ((M @ q) - o).length


def resolve_check(sc, check, camera, filter_width):
    """Fill pixels / expected of one analytic check from the scene."""
    rays = Rays(sc)
    H, W = rays.H, rays.W
    pix = []
    kind = check["kind"]
    if kind in ("point_lambert", "spot_lambert"):
        r0, c0 = rays.project(check["around"])
        rad = check["radius_px"]
        for r in range(H):
            for c in range(W):
                if (r - r0) ** 2 + (c - c0) ** 2 <= rad ** 2:
                    pix.append([r, c])
    elif kind == "sun_lambert":
        for r in range(H):
            for c in range(W):
                ok = True
                for dy, dx in FOOTPRINT:
                    name, loc = rays.cast(rays.direction(r, c, dy, dx))
                    if name != "floor" or loc.y > check["region_y_max"]:
                        ok = False
                        break
                if ok:
                    pix.append([r, c])
    elif kind == "emitter_seen":
        ob = sc.objects[check["object"]]
        for r in range(H):
            for c in range(W):
                ok = True
                for dy, dx in FOOTPRINT:
                    d = rays.direction(r, c, dy, dx)
                    name, loc = rays.cast(d)
                    if ob.type == 'LIGHT':
                        t = _light_hit(ob, rays.o, d)
                        ok = t is not None and (loc is None or (loc - rays.o).length > t)
                    else:
                        ok = name == ob.name
                    if not ok:
                        break
                if ok:
                    pix.append([r, c])
    elif kind == "world_seen":
        for r in range(H):
            for c in range(W):
                if all(rays.cast(rays.direction(r, c, dy, dx))[0] is None
                       for dy, dx in FOOTPRINT):
                    pix.append([r, c])
    elif kind == "world_lambert":
        s = Vector(check["sphere"])
        for r in range(H):
            for c in range(W):
                ok = True
                for dy, dx in FOOTPRINT:
                    name, loc = rays.cast(rays.direction(r, c, dy, dx))
                    if name != "floor" or (loc - s).length < check["min_dist"]:
                        ok = False
                        break
                if ok:
                    pix.append([r, c])
    else:
        raise ValueError(kind)
    check = dict(check)
    check["pixels"] = pix
    exp = np.asarray(refs.expected_values(check, camera, filter_width))
    if kind in ("point_lambert", "spot_lambert"):
        # Varying field: each pixel's filter-weighted value.
        check["expected"] = exp.tolist()
    else:
        # Constant over the pixels: one value (scalar or RGB).
        check["expected"] = exp[0].tolist() if len(exp) else None
    return check


# ------------------------------------------------------------------- noise
def noise_stats(a, b):
    ref = 0.5 * (a + b)
    var = 0.25 * (a - b) ** 2                         # per-pixel var of the mean
    rel = float(np.mean(var[..., :3] / (ref[..., :3].astype(np.float64) ** 2
                                        + refs.RELMSE_EPS)))
    d = 0.5 * (a - b)[..., :3].astype(np.float64)
    H, W = d.shape[:2]
    bm = d.reshape(H // BLOCK, BLOCK, W // BLOCK, BLOCK, 3).mean(axis=(1, 3))
    nb = bm.shape[0] * bm.shape[1]
    # Var(mean of all blocks) = sum Var(block mean) / nb^2, each estimated by
    # its single zero-mean realisation squared.
    std_mean = np.sqrt((bm ** 2).sum(axis=(0, 1))) / nb
    return ref, var[..., :3], rel, std_mean


def compact_json(obj):
    """Indented JSON with innermost lists kept on one line."""
    text = json.dumps(obj, indent=1)
    return re.sub(r"\[\s+([^\[\]{}]*?)\s+\]",
                  lambda m: "[" + " ".join(m.group(1).split()) + "]", text) + "\n"


def scene_of(name):
    bpy.ops.wm.open_mainfile(filepath=refs.scene_path(name), load_ui=False,
                             use_scripts=False)
    return bpy.context.scene


def make_reference(name, scale=1.0):
    sc = scene_of(name)
    spec = json.loads(sc["fppm_test"])
    n_total = max(2, int(round(spec["samples"] * scale / 2)) * 2)
    half = n_total // 2
    halves, times = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for s in SEEDS:
            img, dt = render_exr(sc, half, s, os.path.join(tmp, f"{name}_{s}.exr"))
            halves.append(img)
            times.append(dt)
    a, b = halves
    ref, var, rel, std_mean = noise_stats(a, b)
    ref = ref.astype(np.float32)
    refs.write_exr(os.path.join(HERE, name + ".exr"), ref)
    refs.write_exr(os.path.join(HERE, name + "_var.exr"), var.astype(np.float32))

    c = sc.cycles
    mean_rgb = ref[..., :3].astype(np.float64).mean(axis=(0, 1))
    meta = {
        "name": name,
        "scene": f"tests/scenes/{name}.blend",
        "resolution": [sc.render.resolution_x, sc.render.resolution_y],
        "samples": n_total,
        "halves": [{"seed": s, "samples": half, "render_time_s": round(t, 3)}
                   for s, t in zip(SEEDS, times)],
        "seeds": list(SEEDS),
        "render_time_s": round(sum(times), 3),
        "filter": {"type": c.pixel_filter_type, "width_px": c.filter_width,
                   "support_px": [-c.filter_width, c.filter_width],
                   "std_px": float(np.sqrt((refs.filter_quadrature(c.filter_width)[1]
                                            * refs.filter_quadrature(c.filter_width)[0][:, 0] ** 2).sum())),
                   "note": "Cycles doubles the Blackman-Harris width internally: "
                           "support +-filter_width px (refs.blackman_harris)"},
        "camera": Rays(sc).frame(),
        "cycles": {"version": bpy.app.version_string, "device": c.device,
                   "threads": os.cpu_count(),
                   "max_bounces": c.max_bounces, "diffuse_bounces": c.diffuse_bounces,
                   "glossy_bounces": c.glossy_bounces,
                   "transmission_bounces": c.transmission_bounces,
                   "caustics_reflective": c.caustics_reflective,
                   "caustics_refractive": c.caustics_refractive,
                   "blur_glossy": c.blur_glossy,
                   "light_sampling_threshold": c.light_sampling_threshold,
                   "sample_clamp_direct": c.sample_clamp_direct,
                   "sample_clamp_indirect": c.sample_clamp_indirect,
                   "use_adaptive_sampling": c.use_adaptive_sampling,
                   "use_denoising": c.use_denoising,
                   "view_transform": sc.view_settings.view_transform,
                   "machine": platform.machine()},
        "mean_radiance": mean_rgb.tolist(),
        "noise": {
            "relmse": rel,
            "relmse_definition": "mean over pixels and RGB of var_of_mean / "
                                 f"(ref^2 + {refs.RELMSE_EPS})",
            "std_image_mean": std_mean.tolist(),
            "rel_std_image_mean": (std_mean / np.maximum(mean_rgb, 1e-30)).tolist(),
            "per_pixel_variance_file": f"{name}_var.exr",
        },
        "triangles": spec.get("triangles"),
        "note": spec.get("note", ""),
        "analytic": [],
    }
    checks = []
    for chk in spec.get("analytic", []):
        chk = resolve_check(sc, chk, meta["camera"], c.filter_width)
        meas, expm, tol = refs.check_agreement(ref, var, chk, meta)
        chk["measured_mean"] = np.atleast_1d(meas).tolist()
        chk["expected_mean"] = np.atleast_1d(expm).tolist()
        chk["tolerance"] = np.atleast_1d(tol).tolist()
        ok = bool(np.all(np.abs(meas - expm) <= tol)) and len(chk["pixels"]) > 0
        print(f"  check {chk['kind']}: n={len(chk['pixels'])} measured {meas} "
              f"expected {expm} tol {tol} -> {'OK' if ok else 'FAIL'}")
        checks.append(chk)
        if not ok:
            FAILED.append(f"{name}: {chk['kind']}")
    meta["analytic"] = checks
    with open(os.path.join(HERE, name + ".json"), "w") as f:
        f.write(compact_json(meta))
    print(f"{name}: {n_total} spp in {sum(times):.1f} s, mean {mean_rgb}, "
          f"relMSE {rel:.2e}, rel std of mean {meta['noise']['rel_std_image_mean']}")
    return meta


def all_scene_names():
    return sorted(f[:-6] for f in os.listdir(refs.SCENES_DIR) if f.endswith(".blend"))


def main(argv):
    scale = 1.0
    if "--scale" in argv:
        i = argv.index("--scale")
        scale = float(argv[i + 1])
        argv = argv[:i] + argv[i + 2:]
    for name in (argv or all_scene_names()):
        make_reference(name, scale)
    if FAILED:
        sys.exit("analytic checks failed: " + ", ".join(FAILED))


if __name__ == "__main__":
    main(sys.argv[1:])
