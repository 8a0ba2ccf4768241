"""Numba on-disk cache: per user (it survives updates), keyed by module name.

Where: the first writable of
1. ``$FPPM_CACHE_DIR`` (an explicit choice wins);
2. the folder given to :func:`set_cache_dir` (inside Blender the add-on passes
   ``bpy.utils.extension_path_user``, which updates and reinstalls keep);
3. the user cache folder: ``$XDG_CACHE_HOME/fppm`` or ``~/.cache/fppm``
   (``~/Library/Caches/fppm`` on macOS, ``%LOCALAPPDATA%\\fppm`` on Windows);
4. ``<temp dir>/fppm-<user>``.
Kernels go to ``<that>/numba/<module name>/``.  An unwritable location is
skipped, never an import error; if none is writable numba's own locators
decide.  The package folder is never written: an installed extension may be
read-only, and an update replaces it.

Why one folder per module name: a cached kernel records the module name it
was compiled under; the same file imported under another name (``core.x`` in
a dev shell, ``fppm.core.x`` from the CLI, ``bl_ext.user_default.fppm.core.x``
inside Blender) then fails to load with ``ModuleNotFoundError`` instead of
recompiling.  The index of each kernel is keyed by a hash of its source file
(numba's source stamp), so an unchanged file reinstalled elsewhere or with a
new mtime still hits.  Only functions defined in this package are claimed;
everything else keeps numba's defaults.

Importing ``core`` must not import numba (1-2 s of the add-on's enable time,
docs/interactive.md), yet the locator must be in place before the first
``@njit(cache=True)`` decorator runs.  :func:`install_when_numba_loads` does
both: it installs the locator at once when numba is already imported, and
otherwise hooks the import of ``numba`` so the locator is installed right
after numba's own ``__init__`` and before any kernel module continues.
"""
from __future__ import annotations

import getpass
import importlib.abc
import importlib.util
import os
import sys
import tempfile

_HERE = os.path.dirname(os.path.abspath(__file__))
ENV_VAR = "FPPM_CACHE_DIR"
_chosen_dir: str | None = None      # set_cache_dir()
_writable: dict[str, bool] = {}     # root -> usable (checked once per process)


def set_cache_dir(path: str | None) -> None:
    """Use ``path`` for kernels compiled from now on (``$FPPM_CACHE_DIR`` still wins)."""
    global _chosen_dir
    _chosen_dir = os.fspath(path) if path else None


def _user_cache_dir() -> str | None:
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA")
        return os.path.join(base, "fppm") if base else None
    home = os.path.expanduser("~")
    if sys.platform == "darwin":
        return os.path.join(home, "Library", "Caches", "fppm")
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg and os.path.isabs(xdg):
        return os.path.join(xdg, "fppm")
    return os.path.join(home, ".cache", "fppm") if home != "~" else None


def _temp_dir() -> str:
    try:
        user = getpass.getuser()
    except Exception:           # no user name (containers): the uid will do
        user = str(os.getuid()) if hasattr(os, "getuid") else "user"
    return os.path.join(tempfile.gettempdir(), f"fppm-{user}")


def candidate_dirs() -> list[str]:
    """Cache roots in order of preference (see the module docstring)."""
    out = [os.environ.get(ENV_VAR), _chosen_dir, _user_cache_dir(), _temp_dir()]
    return [os.path.abspath(d) for d in out if d]


def _usable(root: str) -> bool:
    ok = _writable.get(root)
    if ok is None:
        try:
            os.makedirs(root, exist_ok=True)
            tempfile.TemporaryFile(dir=root).close()
            ok = True
        except OSError:
            ok = False
        _writable[root] = ok
    return ok


def cache_dir() -> str | None:
    """The cache root kernels compiled now would use, or None (nothing writable)."""
    return next((d for d in candidate_dirs() if _usable(d)), None)


def kernel_dir(root: str, module: str) -> str:
    return os.path.join(root, "numba", module)


def install() -> None:
    try:
        from numba.core import caching
    except ImportError:        # numba missing: the kernels' import will say so
        return
    if any(getattr(c, "_fppm", False) for c in caching.CacheImpl._locator_classes):
        return

    class ModuleNameUserCacheLocator(caching.UserWideCacheLocator):
        """``<cache_dir()>/numba/<module name>``; None (next locator) when unwritable."""
        _fppm = True

        def __init__(self, py_func, py_file, root):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = kernel_dir(root, py_func.__module__)

        @classmethod
        def from_function(cls, py_func, py_file):
            if not os.path.abspath(py_file).startswith(_HERE + os.sep):
                return None
            if not os.path.exists(py_file):
                return None
            for root in candidate_dirs():
                if not _usable(root):
                    continue
                self = cls(py_func, py_file, root)
                try:
                    self.ensure_cache_path()
                except OSError:
                    continue
                return self
            return None

    caching.CacheImpl._locator_classes[0:0] = [ModuleNameUserCacheLocator]


class _AfterNumbaImport(importlib.abc.MetaPathFinder):
    """Finds nothing itself: wraps the loader of ``numba`` so that :func:`install`
    runs as soon as numba's package ``__init__`` has executed."""

    def find_spec(self, name, path=None, target=None):
        if name != "numba":
            return None
        _remove_hook()
        spec = importlib.util.find_spec(name)
        loader = getattr(spec, "loader", None)
        if loader is None or not hasattr(loader, "exec_module"):
            return spec
        inner = loader.exec_module

        def exec_module(module):
            inner(module)
            install()
        loader.exec_module = exec_module      # this loader instance serves numba only
        return spec


def _remove_hook() -> None:
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _AfterNumbaImport)]


def install_when_numba_loads() -> None:
    """Install the locator now if numba is loaded, else right after it loads."""
    if "numba" in sys.modules:
        install()
    elif not any(isinstance(f, _AfterNumbaImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterNumbaImport())


def serial_twin(kernel):
    """``njit(cache=True)`` of a ``parallel=True`` kernel's Python function,
    cached under a name of its own (``<qualname>_serial``).

    Numba's on-disk index is one file per function name and first line, and
    its key is the signature, the CPU and the bytecode, not the compile
    flags.  ``njit(cache=True)(kernel.py_func)`` therefore shares the
    parallel kernel's cache entries: whichever of the two compiled first is
    loaded for both, so on a cache first filled by a small render the
    "parallel" kernel ran the serial code on one thread.  A copy of the
    function with its own name gets its own index file.
    """
    import types

    from numba import njit
    f = kernel.py_func
    code = f.__code__.replace(co_name=f.__name__ + "_serial",
                              co_qualname=f.__qualname__ + "_serial")
    twin = types.FunctionType(code, f.__globals__, code.co_name, f.__defaults__, f.__closure__)
    twin.__module__, twin.__doc__ = f.__module__, f.__doc__
    return njit(cache=True)(twin)
