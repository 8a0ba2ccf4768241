"""Numba on-disk cache keyed by the importing module's name.

Numba's default cache lives in ``__pycache__`` next to the source and records
the module name a kernel was compiled under; the same file imported under
another name (``core.x`` in a dev shell, ``fppm.core.x`` from the CLI,
``bl_ext.user_default.fppm.core.x`` inside Blender with a symlinked checkout)
then fails to load with ``ModuleNotFoundError`` instead of recompiling.  This
locator gives each module name its own cache folder.  It only claims
functions defined in this package; everything else keeps numba's defaults.

Importing ``core`` must not import numba (1-2 s: the add-on's enable time,
docs/interactive.md), yet the locator must be in place before the first
``@njit(cache=True)`` decorator runs.  :func:`install_when_numba_loads` does
both: it installs the locator at once when numba is already imported, and
otherwise hooks the import of ``numba`` so the locator is installed right
after numba's own ``__init__`` and before any kernel module continues.
"""
from __future__ import annotations

import importlib.abc
import importlib.util
import os
import sys

_HERE = os.path.dirname(os.path.abspath(__file__))


def install() -> None:
    try:
        from numba.core import caching
    except ImportError:        # numba missing: the kernels' import will say so
        return
    if any(getattr(c, "_fppm", False) for c in caching.CacheImpl._locator_classes):
        return

    class ModuleNameCacheLocator(caching.InTreeCacheLocator):
        _fppm = True

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            self._cache_path = os.path.join(os.path.dirname(py_file), "__pycache__",
                                            "numba-" + py_func.__module__)

        @classmethod
        def from_function(cls, py_func, py_file):
            if not os.path.abspath(py_file).startswith(_HERE + os.sep):
                return None
            return super().from_function(py_func, py_file)

    class ModuleNameUserCacheLocator(caching.UserWideCacheLocator):
        """Fallback when the package folder is read-only (installed extension)."""
        _fppm = True

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            self._cache_path = os.path.join(self._cache_path, "numba-" + py_func.__module__)

        @classmethod
        def from_function(cls, py_func, py_file):
            if not os.path.abspath(py_file).startswith(_HERE + os.sep):
                return None
            return super().from_function(py_func, py_file)

    caching.CacheImpl._locator_classes[0:0] = [ModuleNameCacheLocator, ModuleNameUserCacheLocator]


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
