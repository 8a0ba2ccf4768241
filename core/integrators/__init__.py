"""Integrators beside photon mapping (docs/integrators.md).

The setting ``integrator`` chooses the strategies a render runs: 'PHOTON'
(stochastic progressive photon mapping, core.sppm), 'PATH' (camera paths:
path tracing with next-event estimation and MIS, :mod:`.path_tracer`) or
'LIGHT' (photon-path vertices connected to the camera, :mod:`.light_tracer`).
The combined VCM integrator (Georgiev et al. 2012) will weight them and
photon merging against each other with MIS.
"""
from __future__ import annotations

from .path_tracer import PATH_CHUNK, PathTracer, PathVertices, power_heuristic

__all__ = ["PathTracer", "PathVertices", "PATH_CHUNK", "power_heuristic"]
