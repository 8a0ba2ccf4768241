"""Import the repository as the package ``fppm`` and alias ``core`` to ``fppm.core``.

Numba's on-disk cache (``cache=True``) records the module name a kernel was
compiled under; importing the same file as both ``core.x`` and ``fppm.core.x``
makes one of them fail to load the other's cache.  Tests and benchmarks import
this first, so ``core.x`` and ``fppm.core.x`` are the very same module objects.
Works with or without the editable install made by ``make``.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _load_fppm():
    try:
        import fppm  # editable install
        if os.path.samefile(os.path.dirname(fppm.__file__), ROOT):
            return fppm
    except (ImportError, OSError, TypeError):
        pass
    spec = importlib.util.spec_from_file_location(
        "fppm", os.path.join(ROOT, "__init__.py"), submodule_search_locations=[ROOT])
    mod = importlib.util.module_from_spec(spec)
    sys.modules["fppm"] = mod
    spec.loader.exec_module(mod)
    return mod


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target):
        self.target = target

    def create_module(self, spec):
        module = importlib.import_module(self.target)
        self._saved = (module.__spec__, getattr(module, "__loader__", None),
                       getattr(module, "__package__", None))
        return module

    def exec_module(self, module):
        # The import system stamped the alias spec on the real module: put the
        # real one back so relative imports inside it keep working.
        module.__spec__, module.__loader__, module.__package__ = self._saved


class _AliasFinder(importlib.abc.MetaPathFinder):
    PREFIXES = ("core", "addon", "tools")

    def find_spec(self, name, path=None, target=None):
        head = name.split(".")[0]
        if head not in self.PREFIXES:
            return None
        target_name = "fppm." + name
        real = importlib.util.find_spec(target_name)
        if real is None:
            return None
        spec = importlib.util.spec_from_loader(name, _AliasLoader(target_name),
                                               is_package=real.submodule_search_locations is not None)
        return spec


def install():
    _load_fppm()
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _AliasFinder())
    # The repository root must not shadow the alias with top-level core/addon.
    sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != ROOT]


install()
