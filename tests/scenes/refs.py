"""Cycles reference images for the test scenes, and the analytic radiance
formulas they are checked against.  No bpy here: numpy + OpenEXR only.

Import from tests as ``from scenes.refs import load_reference`` with
``tests/`` on sys.path (tests/test_scenes_cycles.py inserts it).

Files (tests/references/, written by make_references.py):
  <name>.exr       (64, 64, 4) float32 RGBA, linear radiance, row 0 at the TOP,
                   mean of the two half-sample renders.
  <name>_var.exr   (64, 64, 3) float32 per-pixel variance of that mean,
                   estimated as (A - B)^2 / 4 from the two halves A, B
                   (one degree of freedom per pixel: average it over regions).
  <name>.json      metadata (samples, seeds, times, noise, analytic checks).
"""
from __future__ import annotations

import json
import math
import os

import numpy as np

TESTS_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES_DIR = os.path.join(TESTS_DIR, "scenes")
REFERENCES_DIR = os.path.join(TESTS_DIR, "references")

#: relMSE = mean over pixels and RGB of (x - ref)^2 / (ref^2 + RELMSE_EPS).
RELMSE_EPS = 1e-2


def scene_path(name: str) -> str:
    """Path of the test scene ``tests/scenes/<name>.blend``."""
    return os.path.join(SCENES_DIR, name + ".blend")


def reference_names() -> list[str]:
    """Names of all references present (sorted)."""
    return sorted(f[:-5] for f in os.listdir(REFERENCES_DIR)
                  if f.endswith(".json"))


def read_exr(path: str) -> np.ndarray:
    """(H, W, C) float32 array of an RGB/RGBA EXR, row 0 at the top."""
    import OpenEXR
    with OpenEXR.File(path) as f:
        ch = f.channels()
        key = "RGBA" if "RGBA" in ch else "RGB"
        return np.ascontiguousarray(ch[key].pixels, dtype=np.float32)


def write_exr(path: str, img: np.ndarray) -> None:
    """Write (H, W, 3|4) float32 as a ZIP-compressed scanline EXR."""
    import OpenEXR
    img = np.ascontiguousarray(img, dtype=np.float32)
    key = {3: "RGB", 4: "RGBA"}[img.shape[2]]
    header = {"compression": OpenEXR.ZIP_COMPRESSION,
              "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {key: img}).write(path)


def load_reference(name: str) -> tuple[np.ndarray, dict]:
    """Cycles reference of test scene ``name``.

    Returns (img, meta): img (H, W, 4) float32 linear radiance RGBA, row 0 at
    the top; meta the dict of ``<name>.json``.
    """
    img = read_exr(os.path.join(REFERENCES_DIR, name + ".exr"))
    with open(os.path.join(REFERENCES_DIR, name + ".json")) as f:
        meta = json.load(f)
    return img, meta


def load_variance(name: str) -> np.ndarray:
    """(H, W, 3) float32 per-pixel variance of the reference's mean (1 dof)."""
    return read_exr(os.path.join(REFERENCES_DIR, name + "_var.exr"))


def relmse(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean of (img - ref)^2 / (ref^2 + RELMSE_EPS) over RGB and (masked) pixels."""
    img = np.asarray(img, np.float64)[..., :3]
    ref = np.asarray(ref, np.float64)[..., :3]
    e = (img - ref) ** 2 / (ref ** 2 + RELMSE_EPS)
    if mask is not None:
        e = e[np.asarray(mask, bool)]
    return float(e.mean())


# ----------------------------------------------------------- analytic values
def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def point_lambert(points, P, rho, light, floor_z=0.0, spot_size=None,
                  spot_blend=None):
    """Radiance of a Lambert floor (normal +Z) lit by a point or spot light.

    points: (N, 3) floor points.  Cycles' units (blender.md): I = P/(4 pi) W/sr,
    spot I = P/(4 pi) * smoothstep((cos a - cos(size/2)) / ((1 - cos(size/2)) blend)),
    axis straight down.  L = rho/pi * I * cos(theta) / d^2.  Returns (N,).
    """
    p = np.asarray(points, np.float64)
    d = np.asarray(light, np.float64)[None, :] - p
    dist = np.linalg.norm(d, axis=1)
    cos_n = d[:, 2] / dist                       # at the floor, normal +Z
    inten = P / (4 * math.pi) * np.ones(len(p))
    if spot_size is not None:
        cos_a = cos_n                            # axis is -Z: same angle
        c = math.cos(spot_size / 2)
        inten = inten * smoothstep((cos_a - c) / ((1 - c) * spot_blend))
    return rho / math.pi * inten * cos_n / dist ** 2


def sun_lambert(S, rho, elevation_deg):
    """Lambert floor under a sun of irradiance S (normal incidence) at the
    given elevation: rho/pi * S * sin(elevation) (also for angle > 0 while the
    sun disk is above the horizon)."""
    return rho / math.pi * S * math.sin(math.radians(elevation_deg))


def blackman_harris(v, filter_width=1.5):
    """Cycles' pixel filter weight at offset v [px] from the pixel centre.

    Cycles (scene/film.cpp, filter_table) doubles the user width for
    Blackman-Harris before tabulating it over [-width, width]/2, so the
    support is +-filter_width px (3 px in all for the default 1.5), std
    0.416 px per axis.  Pixel value = filter-weighted mean of radiance.
    """
    w = 2.0 * filter_width
    v = np.asarray(v, np.float64)
    x = 2 * math.pi * (v / w + 0.5)
    f = 0.35875 - 0.48829 * np.cos(x) + 0.14128 * np.cos(2 * x) - 0.01168 * np.cos(3 * x)
    return np.where(np.abs(v) <= filter_width, f, 0.0)


def filter_quadrature(filter_width=1.5, n=10):
    """Offsets (n*n, 2) [dy, dx] in px and weights (n*n,) summing to 1 that
    integrate a smooth field against Cycles' pixel filter (Gauss-Legendre)."""
    x, w = np.polynomial.legendre.leggauss(n)
    x = x * filter_width
    w = w * blackman_harris(x, filter_width)
    dy, dx = np.meshgrid(x, x, indexing="ij")
    ww = np.outer(w, w).ravel()
    return np.stack([dy.ravel(), dx.ravel()], axis=1), ww / ww.sum()


def camera_rays(camera: dict, pixels, offsets):
    """Origin (3,) and unnormalised directions (P, K, 3) of camera rays.

    camera: dict with 'origin', 'top_left', 'du', 'dv' (world-space vectors:
    the frame's top-left corner direction and its full width / height
    spans), 'width', 'height'.  pixels (P, 2) [row, col], row 0 at the top;
    offsets (K, 2) [dy, dx] in px (dy down).
    """
    pix = np.asarray(pixels, np.float64).reshape(-1, 2)
    off = np.asarray(offsets, np.float64).reshape(-1, 2)
    v = (pix[:, None, 0] + 0.5 + off[None, :, 0]) / camera["height"]
    u = (pix[:, None, 1] + 0.5 + off[None, :, 1]) / camera["width"]
    tl, du, dv = (np.asarray(camera[k], np.float64) for k in ("top_left", "du", "dv"))
    d = tl + u[..., None] * du + v[..., None] * dv
    return np.asarray(camera["origin"], np.float64), d


def filtered_floor_radiance(check: dict, camera: dict, field, filter_width=1.5):
    """Pixel values of a smooth radiance field on the floor z = floor_z:
    ``field(points (N, 3)) -> (N,)`` integrated against the pixel filter.
    Returns (P,) for check['pixels']."""
    offs, w = filter_quadrature(filter_width)
    o, d = camera_rays(camera, check["pixels"], offs)
    t = (check["floor_z"] - o[2]) / d[..., 2]
    p = o + t[..., None] * d
    vals = field(p.reshape(-1, 3)).reshape(p.shape[:2])
    return vals @ w


def expected_values(check: dict, camera: dict | None = None,
                    filter_width: float = 1.5) -> np.ndarray:
    """Analytic pixel values of a check recorded in a reference's json,
    recomputed from its parameters (and the recorded camera frame for the
    point/spot fields, which are integrated against the pixel filter).

    Returns (N,) or (N, 3) float64 for the check's N pixels.
    """
    kind = check["kind"]
    n = len(check["pixels"])
    if kind in ("point_lambert", "spot_lambert"):
        spot = ((check["spot_size"], check["spot_blend"]) if kind == "spot_lambert"
                else (None, None))
        return filtered_floor_radiance(
            check, camera,
            lambda p: point_lambert(p, check["P"], check["rho"], check["light"],
                                    check["floor_z"], *spot), filter_width)
    if kind == "sun_lambert":
        return np.full(n, sun_lambert(check["S"], check["rho"],
                                      check["elevation_deg"]))
    if kind == "emitter_seen":
        if "radiance_rgb" in check:
            return np.tile(np.asarray(check["radiance_rgb"], np.float64), (n, 1))
        return np.full(n, check["P"] / (math.pi * check["area"]))
    if kind == "world_seen":
        return np.tile(np.asarray(check["radiance_rgb"], np.float64), (n, 1))
    if kind == "world_lambert":
        # Full hemisphere of sky; the sphere's occlusion lowers it by at most
        # check['occlusion_bound'] (relative).
        return np.tile(check["rho"] * np.asarray(check["world_rgb"], np.float64),
                       (n, 1))
    raise ValueError(kind)


#: float32 unit roundoff.  Cycles accumulates the samples of a pixel in a
#: float32 sum, so even a constant radiance comes out low by up to
#: n_samples * F32_EPS relative (measured: -2.4e-4 at 4096 samples).
F32_EPS = 2.0 ** -24


def check_agreement(img, var, check, meta):
    """(measured, expected, tolerance) of the mean over a check's pixels.

    img: (H, W, >=3) reference; var: (H, W, 3) per-pixel variance of it;
    meta: the reference's json (camera frame, filter, sample counts).
    Scalar checks compare the RGB average, colour checks each channel.
    The formula's value may be one-sidedly off by what it leaves out:
    up by at most check['indirect_bound'] (light from the small box,
    measured by rendering the scene without it, bound = 2x that), down by at
    most check['occlusion_bound']; the interval's middle is compared, its
    half width added to the tolerance:
      tolerance = 5 sigma + half width + float32 accumulation,
      sigma^2 = 2 * sum of per-pixel variances / n^2 (the factor 2 covers
        the correlation of neighbouring pixels through the 3 px filter; the
        per-pixel variances are 1-dof estimates, their sum over n >= 10
        pixels is within ~2x of its expectation, inside the 5 sigma),
      float32 accumulation = samples per half * 2^-24 relative.
    Returns three float64 arrays of shape () or (3,).
    """
    pix = np.asarray(check["pixels"], int).reshape(-1, 2)
    exp = np.asarray(expected_values(check, meta.get("camera"),
                                     meta["filter"]["width_px"]), np.float64)
    vals = np.asarray(img, np.float64)[pix[:, 0], pix[:, 1], :3]
    vv = np.asarray(var, np.float64)[pix[:, 0], pix[:, 1], :3]
    if exp.ndim == 1:
        vals, vv = vals.mean(axis=1), vv.mean(axis=1) / 3
    n = max(len(pix), 1)
    meas = vals.mean(axis=0)
    lo = 1.0 - check.get("occlusion_bound", 0.0)
    hi = 1.0 + check.get("indirect_bound", 0.0)
    expm = exp.mean(axis=0) * (lo + hi) / 2
    half = (hi - lo) / 2
    sigma = np.sqrt(2 * vv.sum(axis=0)) / n
    accum = max(h["samples"] for h in meta["halves"]) * F32_EPS
    tol = 5 * sigma + (half + accum) * np.abs(expm)
    return meas, expm, tol
