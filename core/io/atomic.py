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
import errno
import os
import stat
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


def _size_text(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} TiB"


def free_bytes(directory: str) -> int | None:
    """Bytes an unprivileged writer may still use in ``directory``'s file system
    (``statvfs`` f_bavail: the root-reserved blocks are not counted), None if unknown."""
    try:
        st = os.statvfs(directory)
    except (OSError, AttributeError):
        return None
    return st.f_bavail * st.f_frsize


def ensure_free_space(path: str, nbytes: int) -> None:
    """Raise OSError(ENOSPC) when ``path``'s folder has less than ``nbytes`` free.

    Checked before a write so that a full disk is reported with the size
    needed, before anything is written (the writers' own errors on a full
    disk are caught too: the check is a first line, not the only one).
    """
    d = os.path.dirname(os.path.abspath(path))
    free = free_bytes(d)
    if free is not None and free < nbytes:
        raise OSError(errno.ENOSPC, f"No space left on device (about {_size_text(nbytes)} "
                                    f"needed, {_size_text(free)} free in '{d}')")


def check_target(path: str, protected: tuple = (), overwrite: bool = False) -> None:
    """Refuse to replace ``path`` when that would destroy something other than an old output.

    Always refused: a folder, a device, a FIFO, a socket (``os.replace`` would
    swap the node itself for a regular file).  Refused unless ``overwrite``:
    a symbolic link (the link would be replaced, not its target) and any of
    the ``protected`` files (the input scene, also through a hard link or a
    symlink).  Raises FileExistsError with a sentence naming the flag.
    """
    try:
        lst = os.lstat(path)
    except FileNotFoundError:
        return
    except OSError as ex:
        raise OSError(ex.errno, f"cannot inspect '{path}': {ex.strerror}")
    if stat.S_ISLNK(lst.st_mode):
        if not overwrite:
            raise FileExistsError(errno.EEXIST, f"'{path}' is a symbolic link: writing there would "
                                                f"replace the link; give another output path, or "
                                                f"--overwrite to replace the link")
        try:
            st = os.stat(path)
        except OSError:
            return                        # a dangling link: nothing but the link is lost
    else:
        st = lst
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(errno.EISDIR, f"'{path}' is a folder")
    if not stat.S_ISREG(st.st_mode):
        raise FileExistsError(errno.EEXIST, f"'{path}' is not a regular file (a device, FIFO or "
                                            f"socket): FPPM writes images to regular files only")
    for p in protected:
        try:
            same = os.path.samefile(path, p)
        except OSError:
            same = False
        if same and not overwrite:
            raise FileExistsError(errno.EEXIST, f"'{path}' is the input file '{p}': give another "
                                                f"output path (or --overwrite to replace it)")


@contextlib.contextmanager
def replace_atomically(path: str, prefix: str = ".fppm-", suffix: str = ".tmp",
                       mode: int | None = None, sync_dir: bool = False, verify=None):
    """Yield a temporary path beside ``path``; when the block ends, it replaces ``path``.

    The caller writes the whole file to the yielded path (any writer that
    takes a file name: OpenEXR, Blender's ``save_render``, ``open``).  On a
    normal exit the temporary file gets ``mode`` (None: mkstemp's 0o600), is
    ``fsync``-ed (data on disk before the rename) and renamed over ``path``
    with ``os.replace``; with ``sync_dir`` the folder is ``fsync``-ed too, so
    the rename itself survives a crash.  On any exception the temporary file
    is removed, ``path`` is left as it was and the exception propagates
    (OSError unchanged: callers turn it into their own sentence).

    verify(tmp): called after the block, before the rename; it raises OSError
    when the file is not what was meant to be written (a writer that failed
    silently, e.g. Blender's ``save_render`` on a full disk).  An empty file is
    always refused.
    """
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=d)
    os.close(fd)
    try:
        yield tmp
        if os.path.getsize(tmp) == 0:
            raise OSError(errno.EIO, "the writer produced an empty file "
                                     "(is the disk full?)")
        if verify is not None:
            verify(tmp)
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
