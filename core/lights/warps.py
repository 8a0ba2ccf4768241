"""Uniform numbers -> points and directions on the emitters' shapes (float64).

The warps that photon emission (:mod:`.emission`) and next-event estimation
(:mod:`.sampling`) share, and the row-wise vector helpers they use; every
argument and result is (K,) or (K, 3).
"""
from __future__ import annotations

import numpy as np

from ..mathutil import frame


def _normalize(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _to_world(local, n):
    t, b = frame(n)
    return local[:, :1] * t + local[:, 1:2] * b + local[:, 2:3] * n


def _unit_disk(u1, u2):
    """Uniform points in the unit disc, (K,) x and y."""
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    return r * np.cos(phi), r * np.sin(phi)


def _uniform_sphere(u1, u2):
    z = 1.0 - 2.0 * u1
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * u2
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def _cone_local(cos_max, u1, u2):
    """Uniform directions in the cone cos(theta) >= cos_max around +z (local)."""
    z = 1.0 - u1 * (1.0 - cos_max)
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * u2
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def smoothstep(x):
    """Cycles' smoothstep of x clamped to [0, 1] (a spot's cone)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def cone_grid(cos_max, n_mu: int, n_phi: int):
    """A midpoint grid of the cone cos(theta) >= cos_max around -z (a
    light's local axis), uniform in mu = -z and phi: (mu (n,), v (n, 3) unit
    local directions, the solid angle of each cell), n = n_mu n_phi."""
    mu = cos_max + (1.0 - cos_max) * (np.arange(n_mu) + 0.5) / n_mu
    phi = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    MU, PH = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(np.maximum(1.0 - MU ** 2, 0.0))
    v = np.stack([st * np.cos(PH), st * np.sin(PH), -MU], axis=-1).reshape(-1, 3)
    return MU.ravel(), v, (1.0 - cos_max) / n_mu * 2.0 * np.pi / n_phi


def _cosine_local(u1, u2):
    """Cosine-weighted directions about +z, pdf cos/pi (Malley)."""
    x, y = _unit_disk(u1, u2)
    z = np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))
    return np.stack([x, y, z], axis=1)


def _triangle_bary(u1, u2):
    """Uniform barycentrics (b1, b2) on a triangle (p = p0 + b1 e1 + b2 e2)."""
    s = np.sqrt(u1)
    return s * (1.0 - u2), s * u2
