"""FPPM core: frequency-based progressive photon mapping in numpy + Embree.

Never imports ``bpy``: everything here runs under plain pytest.
"""
from ._numba_cache import install as _install_numba_cache

__version__ = "0.1.0"
_install_numba_cache()
