"""FPPM core: frequency-based progressive photon mapping in numpy + Embree.

Never imports ``bpy``: everything here runs under plain pytest.  Importing the
package is cheap (no numba, no Embree): the compiled kernels load with the
modules that use them (``core.render`` and below).  ``set_cache_dir`` /
``cache_dir``: where compiled kernels are kept (``core/_numba_cache.py``).
"""
from ._numba_cache import cache_dir, set_cache_dir  # noqa: F401
from ._numba_cache import install_when_numba_loads as _install_numba_cache

__version__ = "0.1.0"
_install_numba_cache()
