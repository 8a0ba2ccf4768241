"""Reference images of ``fppm converge``: Cycles renders and their cache, reference files, masks.

A Cycles reference of N samples is rendered as two halves of N/2 samples
with independent seeds (:data:`REF_SEEDS`): their mean is the reference,
(A - B)^2 / 4 its per-pixel variance (the floor of every relMSE, see
``tools.metrics.reference_floor``).  Cycles' DiffDir / DiffInd passes are
kept for the "indirect" region.  The result is cached as a multi-layer EXR
``$FPPM_CACHE_DIR/references/<sha256>.exr`` (default ``~/.cache/fppm``), the
key being the .blend's bytes plus the reference settings.

Image dicts returned here: ``{"image": (H, W, 3) float64, "var": (H, W, 3)
float64 or None, "diff_direct" / "diff_indirect": (H, W, C) float32 or None,
"meta": dict, "path": str}``.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile

import numpy as np

from ...addon.cli import EXIT_INPUT, EXIT_INTERNAL, EXIT_USAGE, CLIError, render_size
from ...core.io.exr import read_exr, read_exr_metadata, write_exr
from .. import metrics as M
from .cycles_worker import cycles_reference_setup, render_to_file

REF_VERSION = "fppm-converge-ref-2"   # 2: with DiffDir/DiffInd passes
REF_SEEDS = (1_000_003, 1_000_004)     # independent of every method's seeds


def cache_dir() -> str:
    """The reference cache folder: ``$FPPM_CACHE_DIR/references`` (default ``~/.cache/fppm``)."""
    base = os.environ.get("FPPM_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "fppm")
    return os.path.join(base, "references")


def reference_key(blend_bytes: bytes, settings: dict) -> str:
    """sha256 of the .blend's bytes and the reference settings (JSON, sorted keys)."""
    h = hashlib.sha256()
    h.update(blend_bytes)
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()


def layer(layers: dict, name: str):
    """A layer of read_exr's dict by exact name or by '<view layer>.<name>' suffix."""
    if name in layers:
        return layers[name]
    for k, v in layers.items():
        if k.endswith("." + name):
            return v
    return None


def cycles_render(bpy, scene, samples: int, seed: int, passes: bool = False):
    """Render with Cycles in this process; returns ({layer: (H, W, C) float32}, wall
    seconds of render.render).  For the reference only: the timed ladder renders
    in a process of its own (``cycles_worker.py``)."""
    with tempfile.TemporaryDirectory() as tmp:
        p = os.path.join(tmp, "r.exr")
        dt = render_to_file(bpy, scene, samples, seed, p, passes)
        layers = read_exr(p)
    return layers, dt


def _as_reference(layers: dict, var, meta: dict, path: str) -> dict:
    """The reference dict (module docstring) of a Combined layer and its variance."""
    return {"image": layer(layers, "Combined")[..., :3].astype(np.float64),
            "var": None if var is None else var[..., :3].astype(np.float64),
            "diff_direct": layer(layers, "DiffDir"), "diff_indirect": layer(layers, "DiffInd"),
            "meta": meta, "path": path}


def make_reference(bpy, scene, blend_path: str, samples: int, log, progress) -> dict:
    """Cycles reference of ``samples`` spp of the open ``scene``, from the cache when there.

    Changes the scene's Cycles and pass settings: reopen the file afterwards.
    """
    W, H = render_size(scene)
    half = max(1, samples // 2)
    key_settings = {"version": REF_VERSION, "samples": 2 * half, "seeds": list(REF_SEEDS),
                    "resolution": [W, H], "frame": scene.frame_current,
                    "blender": bpy.app.version_string}
    with open(blend_path, "rb") as f:
        key = reference_key(f.read(), key_settings)
    path = os.path.join(cache_dir(), key + ".exr")
    if os.path.isfile(path):
        layers = read_exr(path)
        meta = json.loads(read_exr_metadata(path).get("fppm:reference", "{}"))
        log(f"Reference: cached {path} ({meta.get('samples')} spp, "
            f"{meta.get('render_seconds', float('nan')):.0f} s when made).")
    else:
        cycles_reference_setup(scene)
        halves, secs = [], []
        for i, s in enumerate(REF_SEEDS):
            progress(f"[reference] rendering half {i + 1}/2: {half} spp with Cycles ...", force=True)
            lay, dt = cycles_render(bpy, scene, half, s, passes=True)
            halves.append(lay)
            secs.append(dt)
        a, b = (layer(h, "Combined") for h in halves)
        if a is None or b is None:
            raise CLIError(EXIT_INTERNAL, "internal error: Cycles produced no Combined layer.")
        img = 0.5 * (a.astype(np.float64) + b)
        var = 0.25 * (a.astype(np.float64) - b) ** 2
        layers = {"Combined": img.astype(np.float32), "Variance": var[..., :3].astype(np.float32)}
        for nm, bl in (("DiffDir", "Diffuse Direct"), ("DiffInd", "Diffuse Indirect")):
            x, y = layer(halves[0], bl), layer(halves[1], bl)
            if x is not None and y is not None:
                layers[nm] = (0.5 * (x.astype(np.float64) + y))[..., :3].astype(np.float32)
        meta = dict(key_settings, render_seconds=sum(secs), source=os.path.basename(blend_path))
        os.makedirs(os.path.dirname(path), exist_ok=True)
        write_exr(path, layers, {"fppm:reference": json.dumps(meta)})
        log(f"Reference: {2 * half} spp in {sum(secs):.1f} s, cached as {path}.")
    return _as_reference(layers, layer(layers, "Variance"), meta, path)


def load_reference(path: str) -> dict:
    """A reference EXR given with --reference (its variance from a "Variance"
    layer, or from ``<name>_var.exr`` beside it)."""
    try:
        layers = read_exr(path)
    except OSError as ex:
        raise CLIError(EXIT_INPUT, str(ex))
    comb = layer(layers, "Combined")
    if comb is None or comb.shape[2] < 3:
        raise CLIError(EXIT_INPUT, f"'{path}' has no RGB (Combined) image.")
    var = layer(layers, "Variance")
    sib = os.path.splitext(path)[0] + "_var.exr"
    if var is None and os.path.isfile(sib):
        # tests/references/<name>_var.exr: per-pixel variance of the reference.
        var = layer(read_exr(sib), "Combined")
    return _as_reference(layers, var, {"source": path}, path)


def load_mask(bpy, path: str, shape) -> dict:
    """Region masks from --mask (R caustic, G smooth, B indirect): {region: (H, W) bool}."""
    if path.lower().endswith(".exr"):
        a = layer(read_exr(path), "Combined")
    else:
        try:
            img = bpy.data.images.load(os.path.abspath(path), check_existing=False)
        except RuntimeError as ex:
            raise CLIError(EXIT_INPUT, f"cannot read the mask '{path}': {str(ex).strip()}")
        img.colorspace_settings.name = "Non-Color"
        w, h = img.size
        px = np.empty(w * h * img.channels, np.float32)
        img.pixels.foreach_get(px)
        a = px.reshape(h, w, img.channels)[::-1]
    if a is None or a.shape[:2] != tuple(shape):
        raise CLIError(EXIT_USAGE, f"the mask '{path}' must be {shape[1]}x{shape[0]} pixels.")
    return M.masks_from_image(a)
