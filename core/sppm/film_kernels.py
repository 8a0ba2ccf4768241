"""The compiled film of :class:`core.sppm.film.Film` (image, radius and
radius in pixels per pixel range).  A module of its own so that importing
:mod:`core.sppm.film` (the add-on does, at register) does not load numba.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange


class FilmArrays(NamedTuple):
    """The film kernel's arrays (P pixels).  In: L_sum, tau (P, 3), R2,
    depth, coverage (P,) float64.  Out: img (P, 4) float32 (its alpha
    column already 1), R, r_px (P,) float64."""
    L_sum: np.ndarray
    tau: np.ndarray
    R2: np.ndarray
    depth: np.ndarray
    coverage: np.ndarray
    img: np.ndarray
    R: np.ndarray
    r_px: np.ndarray


@njit(cache=True)
def _film_range(i0, i1, a, prm, alpha, ortho):
    """Film.__call__'s image, R and r_px for pixels i0..i1-1 (its numpy
    operations in their order); prm = (passes, photons emitted, alpha's
    sample count, CameraModel.pix)."""
    passes, n_emit, samples, pix = prm[0], prm[1], prm[2], prm[3]
    for i in range(i0, i1):
        R2 = a.R2[i]
        R2d = R2 if R2 > 0 else np.inf
        den = np.pi * R2d * n_emit
        for c in range(3):
            L = a.L_sum[i, c] / passes + a.tau[i, c] / den
            a.img[i, c] = L if np.isfinite(L) else 0.0
        if alpha:
            a.img[i, 3] = a.coverage[i] / samples
        R = np.sqrt(R2 if R2 > 0 else 0.0)
        fp = pix if ortho else a.depth[i] * pix
        a.R[i] = R
        a.r_px[i] = R / max(fp, 1e-300) if fp > 0 else 0.0


@njit(cache=True, parallel=True)
def _film_parallel(n_chunks, a, prm, alpha, ortho):
    P = a.R2.shape[0]
    for c in prange(n_chunks):
        _film_range(c * P // n_chunks, (c + 1) * P // n_chunks, a, prm, alpha, ortho)


@njit(cache=True)
def compact_positive(R2, x):
    """x[:n] = x[R2 > 0] in place, in order (a read never follows its own
    slot's write: n <= i); returns n."""
    n = 0
    for i in range(R2.shape[0]):
        if R2[i] > 0:
            x[n] = x[i]
            n += 1
    return n
