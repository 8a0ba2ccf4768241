"""Atomic file replacement: write a temporary file, ``fsync`` it, rename it over the target.

Every file FPPM writes for the user (the EXR, the PNG preview, the
checkpoint) goes through :func:`replace_atomically`, so a reader, or the
disk after a crash or a power cut, sees the previous complete file or the
new complete one, never a half-written or empty one
(docs/reliability.md, "atomic output").

Nothing here imports ``bpy``.
"""
from __future__ import annotations

import contextlib
import os
import tempfile


def default_file_mode() -> int:
    """0o666 minus the process umask: what ``open()`` would have given the file
    (``mkstemp`` creates 0o600 files)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def fsync_dir(directory: str) -> None:
    """``fsync`` a folder, so that a rename inside it survives a power loss.

    Not possible on Windows (folders cannot be opened): skipped there.
    """
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def replace_atomically(path: str, prefix: str = ".fppm-", suffix: str = ".tmp",
                       mode: int | None = None, sync_dir: bool = False):
    """Yield a temporary path beside ``path``; when the block ends, it replaces ``path``.

    The caller writes the whole file to the yielded path (any writer that
    takes a file name: OpenEXR, Blender's ``save_render``, ``open``).  On a
    normal exit the temporary file gets ``mode`` (None: mkstemp's 0o600), is
    ``fsync``-ed (data on disk before the rename) and renamed over ``path``
    with ``os.replace``; with ``sync_dir`` the folder is ``fsync``-ed too, so
    the rename itself survives a crash.  On any exception the temporary file
    is removed, ``path`` is left as it was and the exception propagates
    (OSError unchanged: callers turn it into their own sentence).
    """
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=d)
    os.close(fd)
    try:
        yield tmp
        if mode is not None:
            os.chmod(tmp, mode)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    if sync_dir:
        fsync_dir(d)
