"""Reference images of ``fppm converge``: Cycles renders and their cache, reference files, masks.

A Cycles reference of N samples is the sample-weighted mean of K >= 2
pieces rendered with independent seeds (piece i's seed ``REF_SEEDS[0] + i``,
:func:`piece_seed`), by default two halves of N/2 samples.  Its per-pixel
variance (the floor of every relMSE, see ``tools.metrics.reference_floor``)
is the unbiased estimate of the mean's variance from the pieces' spread,
``M2 / ((K - 1) N)`` with ``M2 = sum_i n_i (X_i - mean)^2``
(:func:`piece_variance`); for two halves that is ``(A - B)^2 / 4``.
Cycles' DiffDir / DiffInd passes are kept for the "indirect" region.

The cache, ``$FPPM_CACHE_DIR/references/`` (default ``~/.cache/fppm``), holds
multi-layer EXRs named by a sha256 of the .blend's bytes plus the settings:

- the two-halves file of REF_VERSION 2 (key settings with ``samples`` and
  ``seeds``): layers Combined (mean), Variance (of the mean), DiffDir, DiffInd;
- the growing file of :data:`PIECES_VERSION` (key settings without samples or
  seeds, so one file a scene and resolution): the same layers plus ``M2``;
  its ``fppm:reference`` metadata lists ``samples`` (N), ``pieces`` (K),
  ``seeds`` and ``piece_samples`` of every piece.  A request for more samples
  than it holds adds pieces of at most ``piece_samples`` (default
  :data:`PIECE_SAMPLES`) to it, the file rewritten (atomically) after each
  piece, so an interrupted render resumes from the last piece.  When no such
  file exists, the largest two-halves file of the scene is its first two
  pieces (M2 = N x Variance).

Image dicts returned here: ``{"image": (H, W, 3) float64, "var": (H, W, 3)
float64 or None, "diff_direct" / "diff_indirect": (H, W, C) float32 or None,
"trusted": (H, W) bool or None (:func:`trusted_masks`), "meta": dict, "path": str}``.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time

import numpy as np

from ...addon.cli import EXIT_INPUT, EXIT_INTERNAL, EXIT_USAGE, CLIError, render_size
from ...core.io.exr import read_exr, read_exr_metadata, write_exr
from .. import metrics as M
from .cycles_worker import cycles_reference_setup, render_to_file

REF_VERSION = "fppm-converge-ref-2"   # 2: with DiffDir/DiffInd passes (two halves)
PIECES_VERSION = "fppm-converge-ref-3"  # 3: K pieces, a file that grows
REF_SEEDS = (1_000_003, 1_000_004)     # independent of every method's seeds
PIECE_SAMPLES = 8192                   # the largest piece added to a growing reference
# The reference layers averaged over the pieces (Combined: the image).
MEAN_LAYERS = ("Combined", "DiffDir", "DiffInd")


def piece_seed(i: int) -> int:
    """Cycles seed of a reference's piece i (pieces 0 and 1 are the two halves)."""
    return REF_SEEDS[0] + int(i)


def merge_pieces(a: dict | None, b: dict) -> dict:
    """The pieces of ``a`` and ``b`` as one group (Chan et al.'s parallel variance update).

    A group: ``{"samples": N, "pieces": K, "M2": (H, W, C) float64, layer: (H, W, C)
    float64 for each of MEAN_LAYERS it has}``, the layers being the
    sample-weighted means of its pieces and ``M2 = sum_i n_i (X_i - mean)^2``
    of Combined; a single piece of n samples is ``{"samples": n, "pieces": 1,
    "M2": 0, ...}``.  Merging is exact: the result's M2 is the sum over all
    pieces of both groups.  ``a`` None: ``b``.
    """
    if a is None:
        return dict(b)
    na, nb = a["samples"], b["samples"]
    n = na + nb
    d = b["Combined"] - a["Combined"]
    out = {"samples": n, "pieces": a["pieces"] + b["pieces"],
           "M2": a["M2"] + b["M2"] + d * d * (na * nb / n)}
    for k in MEAN_LAYERS:
        if a.get(k) is not None and b.get(k) is not None:
            out[k] = (na * a[k] + nb * b[k]) / n
    return out


def piece_variance(group: dict):
    """Unbiased estimate of the per-pixel variance of the group's mean,
    ``M2 / ((K - 1) N)``: E[M2] = (K - 1) sigma^2 for pieces of variance
    sigma^2 / n_i, and the mean's variance is sigma^2 / N.  None for K < 2."""
    k = group["pieces"]
    return None if k < 2 else group["M2"] / ((k - 1) * group["samples"])


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
    trusted = layer(layers, "Trusted")
    return {"image": layer(layers, "Combined")[..., :3].astype(np.float64),
            "var": None if var is None else var[..., :3].astype(np.float64),
            "diff_direct": layer(layers, "DiffDir"), "diff_indirect": layer(layers, "DiffInd"),
            "trusted": None if trusted is None else np.asarray(trusted).reshape(
                trusted.shape[:2] + (-1,))[..., 0] > 0.5,
            "meta": meta, "path": path}


def trusted_masks(masks: dict, trusted) -> dict:
    """``masks`` ({region: (H, W) bool}) restricted to a reference's trusted
    pixels, with "all" = ``trusted`` ((H, W) bool; None: ``masks`` unchanged).

    A file reference may carry a "Trusted" layer: the pixels whose error it
    vouches for with its Variance layer.  bench/luxcore_reference.py's
    composed glass-sphere reference leaves out the pixels that may see the
    glass first, where Cycles' rare hits of the small light through the glass
    make its two halves' spread understate its error (docs/peers.md "The
    composed reference's margin, round 34")."""
    if trusted is None:
        return masks
    return {"all": trusted, **{k: m & trusted for k, m in masks.items() if k != "all"}}


def _piece(layers: dict, samples: int) -> dict:
    """One rendered piece as a group of :func:`merge_pieces`."""
    comb = layer(layers, "Combined")
    if comb is None:
        raise CLIError(EXIT_INTERNAL, "internal error: Cycles produced no Combined layer.")
    g = {"samples": int(samples), "pieces": 1, "Combined": comb.astype(np.float64),
         "M2": np.zeros(comb.shape)}
    for nm, bl in (("DiffDir", "Diffuse Direct"), ("DiffInd", "Diffuse Indirect")):
        x = layer(layers, bl)
        if x is not None:
            g[nm] = x[..., :3].astype(np.float64)
    return g


def _group_of_file(layers: dict, meta: dict) -> dict:
    """A cached reference as a group: a growing file's M2, or a two-halves
    file's (K = 2, M2 = N x Variance)."""
    n, k = int(meta["samples"]), int(meta.get("pieces", 2))
    comb = layer(layers, "Combined").astype(np.float64)
    m2 = np.zeros(comb.shape)          # RGB; alpha's is 0
    if layer(layers, "M2") is not None:
        m2[..., :3] = layer(layers, "M2")[..., :3]
    else:
        m2[..., :3] = layer(layers, "Variance")[..., :3] * float((k - 1) * n)
    g = {"samples": n, "pieces": k, "Combined": comb, "M2": m2}
    for nm in MEAN_LAYERS[1:]:
        x = layer(layers, nm)
        if x is not None:
            g[nm] = x.astype(np.float64)
    return g


def _file_layers(group: dict) -> dict:
    """The EXR layers of a growing reference (module docstring)."""
    out = {k: group[k].astype(np.float32) for k in MEAN_LAYERS if group.get(k) is not None}
    out["M2"] = group["M2"][..., :3].astype(np.float32)
    var = piece_variance(group)
    if var is not None:
        out["Variance"] = var[..., :3].astype(np.float32)
    return out


def _read_cached(path: str):
    layers = read_exr(path)
    return layers, json.loads(read_exr_metadata(path).get("fppm:reference", "{}"))


def make_reference(bpy, scene, blend_path: str, samples: int, log, progress,
                   piece_samples: int = PIECE_SAMPLES, threads: int = 0,
                   first_piece: int = 0) -> dict:
    """Cycles reference of at least ``samples`` spp of the open ``scene``, from the cache when there.

    In order: the two-halves file of exactly ``samples``; the growing file when
    it holds ``samples`` or more; else pieces of at most ``piece_samples`` are
    rendered and added to the growing file (started from the largest
    two-halves file, or two halves when there is none) until it holds
    ``samples`` (module docstring).  threads > 0: Cycles' render threads (its
    images do not depend on them; more threads than cores take a larger share
    of a loaded machine).  first_piece > 0: a separate growing file (its key
    has first_piece) whose piece k has the seed of piece first_piece + k, to
    render pieces in another process at the same time and join the two with
    :func:`join_growing`.  Changes the scene's Cycles and pass settings:
    reopen the file afterwards.
    """
    W, H = render_size(scene)
    base = {"resolution": [W, H], "frame": scene.frame_current, "blender": bpy.app.version_string}
    with open(blend_path, "rb") as f:
        blend = f.read()

    def halves_path(n):
        half = max(1, n // 2)
        ks = dict(base, version=REF_VERSION, samples=2 * half, seeds=list(REF_SEEDS))
        return os.path.join(cache_dir(), reference_key(blend, ks) + ".exr")

    def done(layers, meta, path, how):
        log(f"Reference: {how} {path} ({meta.get('samples')} spp in {meta.get('pieces', 2)} "
            f"pieces, {meta.get('render_seconds', float('nan')):.0f} s when made).")
        return _as_reference(layers, layer(layers, "Variance"), meta, path)

    path = halves_path(samples)
    if os.path.isfile(path):
        return done(*_read_cached(path), path, "cached")
    grow_settings = dict(base, version=PIECES_VERSION)
    if first_piece:
        grow_settings["first_piece"] = int(first_piece)
    path = os.path.join(cache_dir(), reference_key(blend, grow_settings) + ".exr")
    group, meta = None, dict(grow_settings, seeds=[], piece_samples=[], render_seconds=0.0,
                             source=os.path.basename(blend_path))
    if os.path.isfile(path):
        layers, old = _read_cached(path)
        if int(old["samples"]) >= samples:
            return done(layers, old, path, "cached")
        group, meta = _group_of_file(layers, old), old
    elif not first_piece:
        n = 2
        while n < samples:      # the largest two-halves file below ``samples``
            if os.path.isfile(halves_path(n)):
                hp = halves_path(n)
                layers, old = _read_cached(hp)
                group = _group_of_file(layers, old)
                meta.update(seeds=list(REF_SEEDS), piece_samples=[n // 2, n // 2],
                            render_seconds=old.get("render_seconds", 0.0), first=os.path.basename(hp))
            n *= 2
    cycles_reference_setup(scene)
    if threads > 0:
        scene.render.threads_mode, scene.render.threads = "FIXED", int(threads)
    while group is None or group["samples"] < samples:
        k, have = (0, 0) if group is None else (group["pieces"], group["samples"])
        n = min(int(piece_samples), samples - have)
        if k == 0:
            n = min(n, max(1, samples // 2))       # at least two pieces: a variance
        seed = piece_seed(first_piece + k)
        progress(f"[reference] piece {k + 1}: {n} spp with Cycles (seed {seed}; "
                 f"{have} of {samples} spp done) ...", force=True)
        c0 = time.process_time()           # Cycles' threads are this process's
        lay, dt = cycles_render(bpy, scene, n, seed, passes=True)
        cpu = time.process_time() - c0
        group = merge_pieces(group, _piece(lay, n))
        meta.update(samples=group["samples"], pieces=group["pieces"],
                    seeds=meta["seeds"] + [seed], piece_samples=meta["piece_samples"] + [n],
                    render_seconds=meta["render_seconds"] + dt,
                    cpu_seconds=meta.get("cpu_seconds", 0.0) + cpu)
        if group["pieces"] >= 2:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            write_exr(path, _file_layers(group), {"fppm:reference": json.dumps(meta)})
            log(f"Reference: {group['samples']} spp in {group['pieces']} pieces "
                f"({meta['render_seconds']:.0f} s wall; this piece {dt:.0f} s wall, {cpu:.0f} "
                f"CPU s, load {os.getloadavg()[0]:.1f}), cached as {path}.")
    layers = _file_layers(group)
    return _as_reference(layers, layer(layers, "Variance"), meta, path)


def join_growing(into: str, other: str) -> dict:
    """Add the growing file ``other`` (pieces of other seeds, make_reference's
    first_piece) to the growing file ``into``, rewritten; returns its metadata.
    Raises ValueError when the two share a seed or differ in their settings."""
    la, ma = _read_cached(into)
    lb, mb = _read_cached(other)
    if set(ma["seeds"]) & set(mb["seeds"]):
        raise ValueError(f"{into} and {other} share seeds")
    for k in ("resolution", "frame", "blender", "version"):
        if ma.get(k) != mb.get(k):
            raise ValueError(f"{into} and {other} differ in {k}")
    g = merge_pieces(_group_of_file(la, ma), _group_of_file(lb, mb))
    meta = dict(ma, samples=g["samples"], pieces=g["pieces"], seeds=ma["seeds"] + mb["seeds"],
                piece_samples=ma["piece_samples"] + mb["piece_samples"],
                render_seconds=ma.get("render_seconds", 0.0) + mb.get("render_seconds", 0.0),
                cpu_seconds=ma.get("cpu_seconds", 0.0) + mb.get("cpu_seconds", 0.0))
    write_exr(into, _file_layers(g), {"fppm:reference": json.dumps(meta)})
    return meta


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
