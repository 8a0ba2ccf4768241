"""Integrators other than the photon pass: light tracing (light_tracer.py) and path tracing,
the strategies a combined (VCM-style) integrator weights against photon merging."""
