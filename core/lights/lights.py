"""Transitional alias of :mod:`core.lights` (the former single module, now split).

Callers import the package (``from .. import lights as Lt``); delete this file
once core/render.py, core/sppm/photons.py, core/sppm/photon_kernels.py,
tests/test_photon_kernels.py and bench/bench_render.py do.
"""
from . import *  # noqa: F401,F403
