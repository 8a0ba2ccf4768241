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


def _cosine_local(u1, u2):
    """Cosine-weighted directions about +z, pdf cos/pi (Malley)."""
    x, y = _unit_disk(u1, u2)
    z = np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))
    return np.stack([x, y, z], axis=1)


def _triangle_bary(u1, u2):
    """Uniform barycentrics (b1, b2) on a triangle (p = p0 + b1 e1 + b2 e2)."""
    s = np.sqrt(u1)
    return s * (1.0 - u2), s * u2
