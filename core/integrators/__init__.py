"""Integrators beside photon mapping (docs/integrators.md).

The setting ``integrator`` chooses the strategies a render runs: 'PHOTON'
(stochastic progressive photon mapping, core.sppm) or 'PATH' (camera paths:
path tracing with next-event estimation and MIS, :mod:`.path_tracer`).  The
combined VCM integrator (Georgiev et al. 2012) will add light tracing and
photon merging as further strategies with MIS between them.
"""
from __future__ import annotations

from .path_tracer import PATH_CHUNK, PathTracer, PathVertices, power_heuristic

__all__ = ["PathTracer", "PathVertices", "PATH_CHUNK", "power_heuristic"]
