"""FPPM core: frequency-based progressive photon mapping in numpy + Embree.

Never imports ``bpy``: everything here runs under plain pytest.  Importing the
package is cheap (no numba, no Embree): the compiled kernels load with the
modules that use them (``core.render`` and below).  ``set_cache_dir`` /
``cache_dir``: where compiled kernels are kept (``core/_numba_cache.py``).

``OMP_WAIT_POLICY`` defaults to ``PASSIVE`` (an explicit setting wins):
numba's OpenMP workers (libgomp) otherwise spin after every parallel region
(300,000 pause loops, milliseconds), billed as CPU and taking a core from
the thread that goes on (the photon tracer's, Blender's, another
process's).  libgomp reads it once, when numba's first parallel kernel
loads it, hence here (docs/architecture.md, "The gather: sorted by cell or
in trace order; OpenMP workers that sleep").
"""
import os as _os

from ._numba_cache import cache_dir, set_cache_dir  # noqa: F401
from ._numba_cache import install_when_numba_loads as _install_numba_cache

__version__ = "0.1.0"
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
_install_numba_cache()
