"""Image error metrics and region masks for the convergence report.  Pure numpy, no bpy.

Conventions
- Images are (H, W, C) arrays, C >= 3; only the first three (RGB, linear
  radiance) channels are compared.  Everything is computed in float64.
- ``mask`` is an optional (H, W) bool array; a metric over an empty mask is NaN.
- relMSE (the convention of tests/scenes/refs.py):
      relMSE = mean_{pixels, RGB} (x - r)^2 / (r^2 + eps),   eps = RELMSE_EPS = 1e-2
  The eps keeps black pixels from dominating; it acts like an absolute error
  for radiances below ~0.1.
- RMSE  = sqrt(mean (x - r)^2).
- MRE (mean relative error) = mean |x - r| / (|r| + sqrt(eps)): the same
  regulariser as relMSE, on the radiance scale (0.1).
- FLIP = the mean of the HDR-FLIP error map (Andersson et al. 2021,
  "Visualizing Errors in Rendered High Dynamic Range Images"), computed by
  the ``flip-evaluator`` package (a development dependency, imported only
  here): the test image and the reference are tone mapped at the exposures
  the reference's range calls for, and each pixel's perceived colour and
  feature difference is in [0, 1].  relMSE is a variance-like measure that
  rewards smooth, biased images (a blur trades noise for a bias it weighs
  lightly); FLIP also scores blurred edges and lost features as a viewer
  sees them, so the report gives both.  The region values are means of the one map over
  the region (the exposure range always comes from the whole reference).

Bias and noise over K seeds (:func:`bias_noise`): with x_k the K images and
m their mean, per pixel/channel weight w = 1 / (r^2 + eps),
      noise = mean w s^2,        s^2 = sum_k (x_k - m)^2 / (K - 1)
      bias2 = mean w (m - r)^2 - noise / K
so that ``bias2 + noise`` is an unbiased estimate of the expected relMSE of one
render (because mean_k (x_k - r)^2 = (m - r)^2 + (K-1)/K s^2).

Reference noise (:func:`reference_floor`): a reference r = t + e with its own
per-pixel variance v gives E[relMSE(x, r)] = relMSE(x, t) + mean w v for x
independent of e (to first order in the weight), so mean w v is the floor
below which no method can be measured, and relMSE - floor estimates the
error against the true image.

Region masks (:func:`region_masks`), derived from the reference when no mask
image is given (thresholds are module constants, documented there):
- caustic: a high relative gradient (at or next to the pixel) AND brighter
  than its blurred surround;
- smooth: a low relative gradient, and not caustic;
- indirect: the direct fraction of diffuse light is small (from Cycles'
  DiffDir/DiffInd passes when the reference has them); otherwise a
  luminance/gradient proxy: dim and smooth.
"""
from __future__ import annotations

import numpy as np

from ..core.mathutil import LUMINANCE as LUMA  # Rec. 709

RELMSE_EPS = 1e-2
MRE_EPS = float(np.sqrt(RELMSE_EPS))

# --- automatic region thresholds --------------------------------------------
#: Gaussian blur (std, pixels) that defines a pixel's "surround".
BLUR_SIGMA_PX = 4.0
#: Relative gradient G = |grad log(L + delta)| per pixel (central differences),
#: delta = LOG_DELTA_FRAC * mean(L) so black areas do not produce huge G.
LOG_DELTA_FRAC = 0.05
#: caustic: max of G over the 3x3 neighbourhood > CAUSTIC_GRAD (a >= ~30%
#: change across one pixel, at or next to the pixel) AND
#: L > CAUSTIC_RATIO * blur(L) (concentrated light, brighter than its surround)
#: AND L > 0.1 * mean(L) (not a dim speck).
CAUSTIC_GRAD = 0.3
CAUSTIC_RATIO = 1.5
#: smooth: G < SMOOTH_GRAD (< ~5% change per pixel) and not caustic.
SMOOTH_GRAD = 0.05
#: indirect (with Cycles passes): DiffInd / (DiffDir + DiffInd) > INDIRECT_FRACTION
#: in luminance, and not caustic.
INDIRECT_FRACTION = 0.8
#: indirect proxy (no passes): L < PROXY_DIM * 90th percentile of L and G < PROXY_GRAD.
PROXY_DIM = 0.25
PROXY_GRAD = 0.1

REGIONS = ("all", "smooth", "caustic", "indirect")


def _rgb(img) -> np.ndarray:
    a = np.asarray(img, np.float64)
    if a.ndim != 3 or a.shape[2] < 3:
        raise ValueError(f"expected an (H, W, C>=3) image, got shape {a.shape}")
    return a[..., :3]


def _select(a: np.ndarray, mask) -> np.ndarray:
    """(n, 3) values of the (H, W, 3) array ``a`` inside ``mask`` (all when None)."""
    if mask is None:
        return a.reshape(-1, a.shape[-1])
    m = np.asarray(mask, bool)
    if m.shape != a.shape[:2]:
        raise ValueError(f"mask shape {m.shape} does not match the image {a.shape[:2]}")
    return a[m]


def _check(img, ref):
    x, r = _rgb(img), _rgb(ref)
    if x.shape != r.shape:
        raise ValueError(f"image {x.shape[:2]} and reference {r.shape[:2]} differ in size")
    return x, r


def relmse(img, ref, mask=None, eps: float = RELMSE_EPS) -> float:
    """mean over (masked) pixels and RGB of (x - r)^2 / (r^2 + eps); NaN if empty."""
    x, r = _check(img, ref)
    d, rr = _select(x - r, mask), _select(r, mask)
    if d.size == 0:
        return float("nan")
    return float(np.mean(d * d / (rr * rr + eps)))


def rmse(img, ref, mask=None) -> float:
    """sqrt(mean over (masked) pixels and RGB of (x - r)^2); NaN if empty."""
    x, r = _check(img, ref)
    d = _select(x - r, mask)
    if d.size == 0:
        return float("nan")
    return float(np.sqrt(np.mean(d * d)))


def mean_relative_error(img, ref, mask=None, eps: float = MRE_EPS) -> float:
    """mean over (masked) pixels and RGB of |x - r| / (|r| + eps); NaN if empty."""
    x, r = _check(img, ref)
    d, rr = _select(x - r, mask), _select(r, mask)
    if d.size == 0:
        return float("nan")
    return float(np.mean(np.abs(d) / (np.abs(rr) + eps)))


def flip_map(img, ref) -> np.ndarray:
    """(H, W) float64 HDR-FLIP error map of ``img`` against ``ref`` (module docstring).

    Both (H, W, >=3) linear radiance; negative values and NaN (which FLIP's
    HDR mode does not accept) are set to 0.  Raises ImportError without the
    ``flip-evaluator`` package.
    """
    import flip_evaluator

    x, r = _check(img, ref)
    prep = lambda a: np.ascontiguousarray(np.nan_to_num(np.maximum(a, 0.0), nan=0.0,  # noqa: E731
                                                        posinf=0.0), np.float32)
    m, _, _ = flip_evaluator.evaluate(prep(r), prep(x), "HDR", applyMagma=False)
    return np.asarray(m, np.float64).reshape(x.shape[:2])


def flip(img, ref, mask=None) -> float:
    """Mean HDR-FLIP error over (masked) pixels; NaN if empty (see :func:`flip_map`)."""
    v = _select(flip_map(img, ref)[..., None], mask)
    return float(np.mean(v)) if v.size else float("nan")


def error_metrics(img, ref, masks: dict | None = None, with_flip: bool = True) -> dict[str, float]:
    """{"relmse_<region>", "rmse_<region>", "mre_<region>", "flip_<region>"} for "all"
    and each mask (flip only ``with_flip``).

    masks: {region name: (H, W) bool}; "all" (no mask) is always included.
    """
    out = {}
    regions = {"all": None}
    regions.update(masks or {})
    fm = flip_map(img, ref)[..., None] if with_flip else None
    for name, m in regions.items():
        out[f"relmse_{name}"] = relmse(img, ref, m)
        out[f"rmse_{name}"] = rmse(img, ref, m)
        out[f"mre_{name}"] = mean_relative_error(img, ref, m)
        if fm is not None:
            v = _select(fm, m)
            out[f"flip_{name}"] = float(np.mean(v)) if v.size else float("nan")
    return out


def reference_floor(ref, ref_var, mask=None, eps: float = RELMSE_EPS) -> float:
    """mean w v: the relMSE a perfect image would get against the noisy reference.

    ref (H, W, >=3), ref_var (H, W, >=3) per-pixel variance of the reference.
    """
    r, v = _check(ref_var, ref)[1], _rgb(ref_var)
    vv, rr = _select(v, mask), _select(r, mask)
    if vv.size == 0:
        return float("nan")
    return float(np.mean(vv / (rr * rr + eps)))


def bias_noise(images, ref, mask=None, eps: float = RELMSE_EPS) -> dict[str, float]:
    """Bias and noise of K >= 2 renders with different seeds (module docstring).

    images: (K, H, W, C) or a list of K (H, W, C).  Returns {"bias2", "noise",
    "relmse_mean_image", "relmse_per_seed"} (relMSE-weighted, float).
    """
    xs = np.stack([_rgb(i) for i in images])
    K = xs.shape[0]
    if K < 2:
        raise ValueError("bias_noise needs at least 2 images")
    r = _rgb(ref)
    w = 1.0 / (r * r + eps)
    m = xs.mean(axis=0)
    s2 = xs.var(axis=0, ddof=1)
    sel = (lambda a: _select(a, mask))
    if sel(w).size == 0:
        nan = float("nan")
        return {"bias2": nan, "noise": nan, "relmse_mean_image": nan, "relmse_per_seed": nan}
    noise = float(np.mean(sel(w * s2)))
    raw = float(np.mean(sel(w * (m - r) ** 2)))
    per_seed = float(np.mean([np.mean(sel(w * (x - r) ** 2)) for x in xs]))
    return {"bias2": raw - noise / K, "noise": noise, "relmse_mean_image": raw,
            "relmse_per_seed": per_seed}


# --- region masks ------------------------------------------------------------

def luminance(img) -> np.ndarray:
    """(H, W) float64 Rec. 709 luminance of the RGB channels."""
    return _rgb(img) @ LUMA


def gaussian_blur(a: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur of an (H, W) array, edges reflected (float64)."""
    a = np.asarray(a, np.float64)
    if sigma <= 0:
        return a.copy()
    rad = max(1, int(np.ceil(3 * sigma)))
    x = np.arange(-rad, rad + 1)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    out = a
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (rad, rad)
        p = np.pad(out, pad, mode="reflect" if out.shape[axis] > rad else "edge")
        acc = np.zeros_like(out)
        n = out.shape[axis]
        for i, kv in enumerate(k):
            acc += kv * (p[i:i + n, :] if axis == 0 else p[:, i:i + n])
        out = acc
    return out


def relative_gradient(L: np.ndarray, delta: float) -> np.ndarray:
    """(H, W) |grad log(L + delta)| by central differences (one-sided at edges)."""
    g = np.log(np.maximum(np.asarray(L, np.float64), 0.0) + delta)
    gy, gx = np.gradient(g) if min(g.shape) > 1 else (np.zeros_like(g), np.zeros_like(g))
    return np.hypot(gx, gy)


def max_filter3(a: np.ndarray) -> np.ndarray:
    """(H, W) maximum over each pixel's 3x3 neighbourhood (edges replicated)."""
    p = np.pad(np.asarray(a, np.float64), 1, mode="edge")
    H, W = a.shape
    return np.max([p[i:i + H, j:j + W] for i in range(3) for j in range(3)], axis=0)


def region_masks(ref, diff_direct=None, diff_indirect=None) -> dict[str, np.ndarray]:
    """{"smooth", "caustic", "indirect"}: (H, W) bool masks derived from the reference.

    ref (H, W, >=3) linear radiance; diff_direct, diff_indirect optional
    (H, W, >=3) Cycles DiffDir / DiffInd passes (light only, same size).
    Thresholds: the module constants above.  Regions may overlap except that
    smooth and indirect exclude caustic pixels.
    """
    L = luminance(ref)
    mean = float(L.mean()) if L.size else 0.0
    delta = max(LOG_DELTA_FRAC * mean, 1e-8)
    G = relative_gradient(L, delta)
    Lb = gaussian_blur(L, BLUR_SIGMA_PX)
    # The gradient test uses the 3x3 maximum of G: the inside of a caustic a
    # few pixels wide has a flat top, and is caustic all the same.
    caustic = (max_filter3(G) > CAUSTIC_GRAD) & (L > CAUSTIC_RATIO * Lb) & (L > 0.1 * mean)
    smooth = (G < SMOOTH_GRAD) & ~caustic
    if diff_direct is not None and diff_indirect is not None:
        dd, di = luminance(diff_direct), luminance(diff_indirect)
        tot = dd + di
        frac = np.where(tot > 0, di / np.where(tot > 0, tot, 1.0), 0.0)
        indirect = (frac > INDIRECT_FRACTION) & ~caustic
    else:
        p90 = float(np.percentile(L, 90)) if L.size else 0.0
        indirect = (L < PROXY_DIM * p90) & (G < PROXY_GRAD) & ~caustic
    return {"smooth": smooth, "caustic": caustic, "indirect": indirect}


def masks_from_image(mask_img, threshold: float = 0.5) -> dict[str, np.ndarray]:
    """Region masks from a mask image: R = caustic, G = smooth, B = indirect (> threshold).

    mask_img (H, W, >=3) (values in [0, 1]); a 1-channel image marks "caustic" only.
    """
    a = np.asarray(mask_img, np.float64)
    if a.ndim == 2:
        a = a[..., None]
    if a.shape[2] < 3:
        z = np.zeros(a.shape[:2], bool)
        return {"smooth": z, "caustic": a[..., 0] > threshold, "indirect": z.copy()}
    return {"caustic": a[..., 0] > threshold, "smooth": a[..., 1] > threshold,
            "indirect": a[..., 2] > threshold}


def loglog_interp(t_query: float, t: np.ndarray, e: np.ndarray) -> float:
    """Error at time t_query by linear interpolation in log(t)-log(e) between
    the recorded points (e > 0; sorted by t here).  NaN before the first point; the
    last point's value after it (a render stopped there keeps its image).
    """
    t = np.asarray(t, np.float64)
    e = np.asarray(e, np.float64)
    ok = (t > 0) & np.isfinite(e) & (e > 0)
    t, e = t[ok], e[ok]
    # Independent renders (a Cycles ladder) on a loaded machine may finish out
    # of order: interpolate over the points sorted by time.
    order = np.argsort(t, kind="stable")
    t, e = t[order], e[order]
    if t.size == 0 or t_query < t[0]:
        return float("nan")
    if t_query >= t[-1]:
        return float(e[-1])
    return float(np.exp(np.interp(np.log(t_query), np.log(t), np.log(e))))
