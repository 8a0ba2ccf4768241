"""Multi-layer OpenEXR files (OpenEXR >= 3.3 Python API), written atomically
(:func:`core.io.atomic.replace_atomically`).

Layout of a file written by :func:`write_exr`:

- the layer ``"Combined"`` is stored as the plain channels ``R, G, B, A`` (any
  EXR viewer shows it as the beauty image);
- every other layer ``name`` with C channels is stored as ``name.<c>`` with the
  channel letters of :data:`CHANNEL_LETTERS` (``"FPPM Radius px.X"``,
  ``"Spectrum.R"`` ...), the usual ``layer.channel`` convention (a
  Cryptomatte layer's ``r, g, b, a``, the Cryptomatte convention);
- pixels are float32, ZIP-compressed, row 0 at the TOP (EXR's increasing-y
  order, the same as ``core``'s images);
- ``metadata`` becomes string attributes of the header.

Nothing here imports ``bpy``.
"""
from __future__ import annotations

import errno
import os

import numpy as np

from .atomic import default_file_mode, ensure_free_space, replace_atomically

COMBINED = "Combined"
# Channel letters by channel count (Blender's pass chan_id conventions).
CHANNEL_LETTERS = {1: "X", 2: "XY", 3: "RGB", 4: "RGBA"}
_COMBINED_CHANNELS = ("R", "G", "B", "A")


def _as_hwc(name: str, img) -> np.ndarray:
    a = np.asarray(img, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in CHANNEL_LETTERS:
        raise ValueError(f"layer '{name}' must be (H, W, C) with C in 1..4, got shape {a.shape}")
    return a


def _channels_of(layers: dict) -> dict[str, np.ndarray]:
    """Flatten ``{layer: (H, W, C)}`` to ``{channel name: (H, W) float32}``."""
    chans: dict[str, np.ndarray] = {}
    shape = None
    for name, img in layers.items():
        if "." in name and name != COMBINED:
            # A dot would make the layer ambiguous when the file is read back.
            raise ValueError(f"layer name '{name}' must not contain '.'")
        a = _as_hwc(name, img)
        if shape is None:
            shape = a.shape[:2]
        elif a.shape[:2] != shape:
            raise ValueError(f"layer '{name}' is {a.shape[:2]}, other layers are {shape}")
        if name == COMBINED:
            if a.shape[2] == 3:
                # An opaque beauty image: alpha 1.
                a = np.concatenate([a, np.ones(a.shape[:2] + (1,), np.float32)], axis=2)
            if a.shape[2] != 4:
                raise ValueError("layer 'Combined' must have 3 or 4 channels")
            letters = _COMBINED_CHANNELS
            prefix = ""
        else:
            from ..sppm.cryptomatte import is_pass
            # Cryptomatte layers: r, g, b, a (the Cryptomatte convention, as
            # Blender writes them).
            letters = "rgba" if is_pass(name) else CHANNEL_LETTERS[a.shape[2]]
            prefix = name + "."
        for i, c in enumerate(letters):
            chans[prefix + c] = np.ascontiguousarray(a[:, :, i])
    if not chans:
        raise ValueError("write_exr needs at least one layer")
    return chans


def _check_writable(path: str) -> None:
    d = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(d):
        raise OSError(f"Cannot write '{path}': the folder '{d}' does not exist.")
    if not os.access(d, os.W_OK | os.X_OK):
        raise OSError(f"Cannot write '{path}': the folder '{d}' is not writable.")
    if os.path.isdir(path):
        raise OSError(f"Cannot write '{path}': it is a folder.")


def exr_size_bound(chans: dict, header: dict) -> int:
    """Upper bound on the bytes of the scanline EXR of ``chans`` ({name: (H, W) float32}).

    ZIP (zlib deflate) never grows a 16-line block by more than 5 bytes per
    16 KiB plus 6 bytes (RFC 1950/1951 stored blocks); OpenEXR stores a block
    uncompressed when compression does not help.  Plus the offset table (8
    bytes per block), 8 bytes of block header, and the header attributes.
    """
    n_raw = sum(int(a.size) * 4 for a in chans.values())
    H = next(iter(chans.values())).shape[0]
    blocks = -(-H // 16)
    head = 4096 + sum(len(str(k)) + len(str(v)) + 32 for k, v in header.items())
    head += 64 * len(chans)
    return int(n_raw * (1 + 5 / 16384)) + blocks * (16 + 6) + head


def layers_size_bound(layers: dict, metadata: dict | None = None) -> int:
    """Upper bound on the bytes of the file :func:`write_exr` makes of ``layers``."""
    return exr_size_bound(_channels_of(layers), dict(metadata or {}))


def verify_exr(path: str, names, size: tuple) -> None:
    """Read ``path`` back and raise OSError unless it holds exactly the channels
    ``names``, each of ``size`` = (H, W) (a writer that stopped early, a disk that lost data)."""
    import OpenEXR

    H, W = size
    try:
        with OpenEXR.File(path, separate_channels=True) as f:
            hd = f.header()
            (x0, y0), (x1, y1) = (np.asarray(v) for v in hd["dataWindow"])
            got = {name: np.asarray(ch.pixels) for name, ch in f.parts[0].channels.items()}
    except (RuntimeError, ValueError, KeyError, OSError) as ex:
        raise OSError(errno.EIO, f"the file written does not read back ({ex})") from ex
    if (int(x1 - x0 + 1), int(y1 - y0 + 1)) != (W, H) or set(got) != set(names):
        raise OSError(errno.EIO, "the file written does not read back with the channels and "
                                 "size that were written")
    if any(a.shape != (H, W) for a in got.values()):
        raise OSError(errno.EIO, "the file written holds incomplete channels")


def write_exr(path: str, layers: dict, metadata: dict | None = None) -> None:
    """Write ``layers`` to ``path`` as one multi-channel scanline EXR, atomically.

    layers: ``{name: (H, W, C) float32}``, row 0 at the top, C in 1..4, all the
      same H and W.  ``"Combined"`` (3 or 4 channels) becomes R, G, B, A.
    metadata: ``{key: str}`` header attributes.
    The file is written to a temporary file in the same folder, ``fsync``-ed and
    renamed over ``path`` (``replace_atomically``), so a reader never sees a
    half-written image, and after a power cut ``path`` holds the old image or
    the new one, never an empty file.
    Before writing, the folder must have room for the file's upper bound
    (:func:`exr_size_bound`); after writing, the temporary file is read back
    (:func:`verify_exr`) before the rename.
    Raises OSError with a clear sentence when the folder is missing, not
    writable or full, or when OpenEXR fails (its RuntimeError, e.g. "No space
    left on device", becomes an OSError: every writer failure is a write
    failure); ValueError on malformed layers.
    """
    import OpenEXR

    chans = _channels_of(layers)
    _check_writable(path)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (metadata or {}).items():
        header[str(k)] = str(v)
    try:
        ensure_free_space(path, exr_size_bound(chans, header))
        # OpenEXR.File turns the arrays of chans into its Channel objects: keep
        # what the read-back must find.
        names, size = tuple(chans), next(iter(chans.values())).shape
        with replace_atomically(path, suffix=".exr", mode=default_file_mode(),
                                verify=lambda tmp: verify_exr(tmp, names, size)) as tmp:
            try:
                with OpenEXR.File(header, chans) as f:
                    f.write(tmp)
            except RuntimeError as ex:
                # OpenEXR reports every I/O failure (full disk included) as
                # RuntimeError('Failed to write ... No space left on device.').
                msg = str(ex).strip().rstrip(".")
                code = errno.ENOSPC if "space left" in msg else errno.EIO
                raise OSError(code, msg.rsplit(". ", 1)[-1] if code == errno.ENOSPC else msg) from ex
    except OSError as ex:
        raise OSError(ex.errno, f"Cannot write '{path}': {ex.strerror or ex}.") from ex


def read_exr(path: str) -> dict[str, np.ndarray]:
    """Read an EXR written by :func:`write_exr`, or any single- or multi-part EXR.

    Returns ``{layer: (H, W, C) float32}`` (row 0 at the top).  Plain
    ``R, G, B[, A]`` channels come back as ``"Combined"``; ``name.c`` channels
    are grouped by ``name`` and ordered by :data:`CHANNEL_LETTERS` (in
    either case; then alphabetically for unknown letters).  Every part is read: Blender 5 writes
    a multilayer render as one part per pass ("ViewLayer.Combined",
    "ViewLayer.Diffuse Direct", ...).
    """
    import OpenEXR

    if not os.path.isfile(path):
        raise OSError(f"Cannot read '{path}': no such file.")
    order = "RGBAXYZ"
    out = {}
    with OpenEXR.File(path, separate_channels=True) as f:
        for part in f.parts:
            groups: dict[str, dict[str, np.ndarray]] = {}
            for name, ch in part.channels.items():
                layer, _, c = name.rpartition(".")
                groups.setdefault(layer or COMBINED, {})[c] = np.asarray(ch.pixels, np.float32)
            for layer, chs in groups.items():
                keys = sorted(chs, key=lambda c: (order.find(c.upper()) if c.upper() in order
                                                  else len(order), c))
                out[layer] = np.stack([chs[k] for k in keys], axis=2)
    return out


def read_exr_metadata(path: str) -> dict[str, str]:
    """The string attributes of an EXR header (e.g. what :func:`write_exr` stored)."""
    import OpenEXR

    with OpenEXR.File(path, header_only=True) as f:
        return {k: v for k, v in f.header().items() if isinstance(v, str)}
