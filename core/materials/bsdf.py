"""Transitional alias of :mod:`core.materials` (the former single module, now split).

Callers import the package (``from .. import materials as B``); delete this file
once core/render.py, core/sppm/photons.py and tests/test_photon_kernels.py do.
"""
from . import *  # noqa: F401,F403
