"""The photon pass's pixel-sized steps (``core.sppm.photon_pass.PhotonPass``:
``begin``, ``_zero_sums``, ``finish``) as compiled loops over pixel ranges,
split over the numba threads from ``hashgrid.PARALLEL_MIN_VPS`` pixels.

At 1080p each was a numpy operation over 2 M pixels on one thread while the
other core waited: the active mask and the square roots of the radii
(``begin``), a fresh zeroed M (``_zero_sums``; its pages faulted in by one
thread), Phi x beta (``finish``).  The same operations per pixel in the same
dtypes (sqrt and products correctly rounded), so the same bits.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from . import hashgrid


@njit(cache=True, nogil=True, error_model="numpy")
def _active_range(i0, i1, valid, R2, active, R):
    """active = valid & (R2 > 0), R = sqrt(R2) for pixels i0..i1-1; the active count."""
    n = 0
    for i in range(i0, i1):
        a = valid[i] and R2[i] > 0.0
        active[i] = a
        R[i] = np.sqrt(R2[i])
        n += a
    return n


@njit(cache=True, error_model="numpy", parallel=True)
def _active_parallel(T, valid, R2, active, R):
    P = R2.shape[0]
    counts = np.zeros(T, np.int64)
    for c in prange(T):
        counts[c] = _active_range(c * P // T, (c + 1) * P // T, valid, R2, active, R)
    return counts.sum()


@njit(cache=True, nogil=True)
def _scale_range(i0, i1, Phi, beta):
    """Phi[i] *= beta[i] (float32 beta widened, as numpy's ``*=``) for i0..i1-1."""
    for i in range(i0, i1):
        for c in range(3):
            Phi[i, c] *= np.float64(beta[i, c])


@njit(cache=True, parallel=True)
def _scale_parallel(T, Phi, beta):
    P = Phi.shape[0]
    for c in prange(T):
        _scale_range(c * P // T, (c + 1) * P // T, Phi, beta)


@njit(cache=True, parallel=True)
def _zeros_parallel(T, out):
    P = out.shape[0]
    for c in prange(T):
        out[c * P // T:(c + 1) * P // T] = 0.0


def _threads(P: int) -> int:
    """Numba threads for a loop over P pixels (1: the serial kernel)."""
    return numba.get_num_threads() if P >= hashgrid.PARALLEL_MIN_VPS else 1


def active_radii(valid: np.ndarray, R2: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(active (P,) bool = valid & (R2 > 0), R (P,) float64 = sqrt(R2), the
    active count) of valid (P,) bool and R2 (P,) float64."""
    P = R2.shape[0]
    active, R = np.empty(P, bool), np.empty(P)
    T = _threads(P)
    if T > 1:
        n = _active_parallel(T, valid, R2, active, R)
    else:
        n = _active_range(0, P, valid, R2, active, R)
    return active, R, int(n)


def scale_by_beta(Phi: np.ndarray, beta: np.ndarray) -> None:
    """Phi (P, 3) float64 *= beta (P, 3) float32, in place."""
    T = _threads(Phi.shape[0])
    if T > 1:
        _scale_parallel(T, Phi, beta)
    else:
        _scale_range(0, Phi.shape[0], Phi, beta)


def zeros(P: int) -> np.ndarray:
    """np.zeros(P) whose pages the numba threads fault in (from PARALLEL_MIN_VPS)."""
    T = _threads(P)
    if T == 1:
        return np.zeros(P)
    out = np.empty(P)
    _zeros_parallel(T, out)
    return out
