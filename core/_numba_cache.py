"""Numba on-disk cache keyed by the importing module's name.

Numba's default cache lives in ``__pycache__`` next to the source and records
the module name a kernel was compiled under; the same file imported under
another name (``core.x`` in a dev shell, ``fppm.core.x`` from the CLI,
``bl_ext.user_default.fppm.core.x`` inside Blender with a symlinked checkout)
then fails to load with ``ModuleNotFoundError`` instead of recompiling.  This
locator gives each module name its own cache folder.  It only claims
functions defined in this package; everything else keeps numba's defaults.
"""
from __future__ import annotations

import os

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
