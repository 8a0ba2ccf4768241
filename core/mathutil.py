"""Constants and row-wise vector helpers shared by the numpy stages.

Vectors are ``(K, 3)`` float64 arrays, one row per ray, photon or visible point.
"""
from __future__ import annotations

import numpy as np

# Rec. 709 luminance weights, as Cycles' default scene-linear colour space.
LUM_R, LUM_G, LUM_B = 0.2126, 0.7152, 0.0722
LUMINANCE = np.array([LUM_R, LUM_G, LUM_B])


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) row-wise dot product of two (K, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)
