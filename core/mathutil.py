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


def unit_rows(v: np.ndarray) -> np.ndarray:
    """v (..., 3) with each row scaled to length 1 (a zero row stays zero)."""
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


def frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents (t, b), each (K, 3), of unit normals n (K, 3).

    Duff et al. 2017, "Building an Orthonormal Basis, Revisited": branchless
    and continuous except across n_z = 0, where the sign flips.
    """
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    bb = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, bb


def power_heuristic(pdf_a: np.ndarray, pdf_b: np.ndarray) -> np.ndarray:
    """(K,) MIS weight of strategy a: pdf_a^2 / (pdf_a^2 + pdf_b^2) (Veach 1997,
    eq. 9.13, beta = 2); 1 where both are 0 (the strategy a is then the only one)."""
    a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
    s = a2 + b2
    return np.where(s > 0, a2 / np.where(s > 0, s, 1.0), 1.0)
