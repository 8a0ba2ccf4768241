"""Checkpoint files of a progressive render: saved atomically, loaded with checks.

A checkpoint is ``Renderer.state_dict()`` in one uncompressed ``.npz`` file
(``np.savez``, no pickles): the per-pixel statistics (float64, (P,) or (P, 3)),
the pass and photon counters, the elapsed time, the settings and scene
digests and the region size.  No RNG state is stored: every random stream is
derived from (seed, pass, stage) (``Renderer._rng``), so the pass count and
the seed (inside the settings digest) are the RNG state.

Atomic save (:func:`core.io.atomic.replace_atomically`): the file is written
to a temporary name in the same folder, ``fsync``-ed, then renamed over the
previous checkpoint (``os.replace``), and the folder is ``fsync``-ed so the
rename itself survives a crash.  A process killed at any instant leaves either the
previous complete checkpoint or the new complete one, never a mix.

Nothing here imports ``bpy``.
"""
from __future__ import annotations

import os
import zipfile

import numpy as np

from ..errors import CheckpointMismatch
from .atomic import replace_atomically

FILENAME = "fppm-checkpoint.npz"
FORMAT_VERSION = 1
# Scalars of Renderer.state_dict() and the Python type they come back as.
_SCALARS = {"pass_index": int, "photons_emitted": int, "elapsed": float,
            "settings_digest": str, "scene_digest": str}


def checkpoint_path(directory: str) -> str:
    """The checkpoint file inside ``directory``."""
    return os.path.join(directory, FILENAME)


def save(directory: str, state: dict) -> str:
    """Write ``state`` (``Renderer.state_dict()``) to ``directory`` atomically.

    Creates ``directory`` if needed.  Returns the checkpoint path.  Raises
    OSError with a sentence naming the path on a full disk, a missing
    permission, ...; the previous checkpoint is then left as it was.
    """
    os.makedirs(directory, exist_ok=True)
    path = checkpoint_path(directory)
    arrays = {"format_version": np.asarray(FORMAT_VERSION)}
    for k, v in state.items():
        if k in _SCALARS and _SCALARS[k] is str:
            arrays[k] = np.asarray(str(v))                 # 0-d unicode: no pickle
        else:
            arrays[k] = np.asarray(v)
    try:
        with replace_atomically(path, prefix=".fppm-checkpoint-", sync_dir=True) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, **arrays)
    except OSError as ex:
        raise OSError(ex.errno, f"cannot write the checkpoint '{path}': "
                                f"{ex.strerror or ex}") from ex
    return path


def exists(directory: str) -> bool:
    return os.path.isfile(checkpoint_path(directory))


def load(directory: str, state_keys=None) -> dict:
    """Read the checkpoint of ``directory`` back into a ``state_dict()``-like dict.

    state_keys: the array names the renderer needs (``Renderer.STATE_KEYS``);
      a file missing one is refused.
    Raises FileNotFoundError when there is no checkpoint, CheckpointMismatch
    when the file is damaged, from another format version, or incomplete.
    (A checkpoint from another scene or other settings is refused later, by
    ``Renderer.load_state``, which knows the current digests.)
    """
    path = checkpoint_path(directory)
    if not os.path.isfile(path):
        raise FileNotFoundError(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            raw = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as ex:
        raise CheckpointMismatch(f"The checkpoint '{path}' is damaged or not an FPPM "
                                 f"checkpoint ({type(ex).__name__}): delete it to start over.")
    version = int(raw.pop("format_version", -1))
    if version != FORMAT_VERSION:
        raise CheckpointMismatch(f"The checkpoint '{path}' has format version {version}, "
                                 f"this FPPM reads version {FORMAT_VERSION}: delete it to start over.")
    need = set(_SCALARS) | {"size"} | set(state_keys or ())
    missing = sorted(need - set(raw))
    if missing:
        raise CheckpointMismatch(f"The checkpoint '{path}' is incomplete (no {', '.join(missing)}): "
                                 f"delete it to start over.")
    d = {}
    for k, v in raw.items():
        if k in _SCALARS:
            d[k] = _SCALARS[k](v.item())
        elif k == "size":
            d[k] = tuple(int(x) for x in v)
        else:
            d[k] = v
    return d
