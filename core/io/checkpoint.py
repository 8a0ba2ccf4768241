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

import glob
import math
import os
import zipfile

import numpy as np

from ..errors import CheckpointBusy, CheckpointMismatch
from .atomic import replace_atomically

FILENAME = "fppm-checkpoint.npz"
LOCKNAME = ".fppm-lock"
TMP_PREFIX = ".fppm-checkpoint-"
FORMAT_VERSION = 1
# Scalars of Renderer.state_dict() and the Python type they come back as.
_SCALARS = {"pass_index": int, "photons_emitted": int, "elapsed": float,
            "settings_digest": str, "scene_digest": str}
# The numpy kinds each scalar may have in the file (0-d arrays only).
_SCALAR_KINDS = {"pass_index": "iu", "photons_emitted": "iu", "elapsed": "fiu",
                 "settings_digest": "U", "scene_digest": "U"}
# Largest pass count a checkpoint may hold (RenderSettings counts passes in int32).
MAX_PASSES = 2**31 - 1


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
        with replace_atomically(path, prefix=TMP_PREFIX, sync_dir=True) as tmp:
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
    fv = raw.pop("format_version", np.asarray(-1))
    version = int(fv.item()) if fv.ndim == 0 and fv.dtype.kind in "iu" else -1
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
            if v.ndim != 0 or v.dtype.kind not in _SCALAR_KINDS[k]:
                raise _damaged(path, f"'{k}' is a {v.dtype} array of shape {v.shape}, "
                                     f"not a scalar")
            d[k] = _SCALARS[k](v.item())
        elif k == "size":
            if v.shape != (2,) or v.dtype.kind not in "iu" or not (v >= 1).all():
                raise _damaged(path, f"'size' is {v!r}, not two pixel counts >= 1")
            d[k] = tuple(int(x) for x in v)
        else:
            d[k] = v
    n, photons, elapsed = d["pass_index"], d["photons_emitted"], d["elapsed"]
    if not 0 <= n <= MAX_PASSES:
        raise _damaged(path, f"pass count {n} is not in [0, {MAX_PASSES}]")
    if photons < 0:
        raise _damaged(path, f"photon count {photons} is negative")
    if not (math.isfinite(elapsed) and elapsed >= 0):
        raise _damaged(path, f"elapsed time {elapsed} is not a number of seconds >= 0")
    return d


def _damaged(path: str, why: str) -> CheckpointMismatch:
    return CheckpointMismatch(f"The checkpoint '{path}' is damaged or not an FPPM checkpoint "
                              f"({why}): delete it to start over.")


class FolderLock:
    """An exclusive ``flock`` on ``DIR/.fppm-lock`` held while a render uses DIR.

    The kernel drops it when the process ends, however it ends (SIGKILL
    included), so a lock never outlives its render.  Not available on
    Windows (no ``fcntl``): there the folder is not locked.
    """

    def __init__(self, fd):
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)          # closing the descriptor drops the flock
            self.fd = None


def lock(directory: str) -> FolderLock:
    """Lock ``directory`` for one render and remove the temporaries that a render
    killed during a save left behind (no other render can be writing them:
    the lock is held).

    Raises CheckpointBusy when another render holds the lock (its process id
    is in the message), OSError when the lock file cannot be created.
    """
    try:
        import fcntl
    except ImportError:
        return FolderLock(None)
    os.makedirs(directory, exist_ok=True)
    path = os.path.join(directory, LOCKNAME)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        try:
            owner = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        finally:
            os.close(fd)
        raise CheckpointBusy(f"The checkpoint folder '{directory}' is in use by another FPPM "
                             f"render (process {owner}): wait for it to end, or give another "
                             f"--checkpoint folder.")
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    for stale in glob.glob(os.path.join(glob.escape(directory), TMP_PREFIX + "*")):
        try:
            os.unlink(stale)
        except OSError:
            pass
    return FolderLock(fd)
