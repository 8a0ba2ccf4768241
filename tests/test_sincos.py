"""core.materials.compiled.sincos_quarter / sincos_turn and the concentric
disk built on them, against libm (math.sin, math.cos) and the numpy warp
(microfacet._disk): within 1 ulp on the quarter turn, a few 1e-16 absolute
over the whole turn (the angle 2 pi u is rounded differently), and the disk
to 1e-15 (docs/architecture.md "The photon pass's own work against raw
Embree")."""
import math

import numpy as np
from numba import njit

from core.materials import compiled as C
from core.materials import microfacet as MF


@njit(cache=False)
def _quarter(t, out):
    for i in range(t.shape[0]):
        out[i, 0], out[i, 1] = C.sincos_quarter(t[i])


@njit(cache=False)
def _turn(u, out):
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1] = C.sincos_turn(u[i])


@njit(cache=False)
def _disks(u, out):
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1] = C._disk(u[i, 0], u[i, 1])


def test_sincos_quarter_within_one_ulp_of_libm():
    t = np.concatenate([(np.random.default_rng(3).random(200_000) * 2 - 1) * (np.pi / 4),
                        [0.0, -0.0, np.pi / 4, -np.pi / 4, 1e-300, 1e-8]])
    got = np.empty((t.size, 2))
    _quarter(t, got)
    ref = np.array([[math.sin(x), math.cos(x)] for x in t])
    ulp = np.abs(got - ref) / np.spacing(np.maximum(np.abs(ref), np.finfo(float).tiny))
    assert ulp.max() <= 1.0, ulp.max()


def test_sincos_turn_matches_libm_over_the_turn():
    u = np.concatenate([np.random.default_rng(4).random(200_000),
                        [0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0 - 2 ** -53]])
    got = np.empty((u.size, 2))
    _turn(u, got)
    ph = 2.0 * np.pi * u
    ref = np.stack([np.sin(ph), np.cos(ph)], axis=1)
    # libm's angle 2 pi u is itself rounded (|error| <= 2 pi u 2^-53)
    assert np.abs(got - ref).max() <= 8e-16
    assert np.abs(got[:, 0] ** 2 + got[:, 1] ** 2 - 1.0).max() <= 4e-16


def test_disk_matches_the_numpy_warp():
    u = np.random.default_rng(5).random((200_000, 2))
    u[:4] = [[0.5, 0.5], [0.5, 0.9], [0.9, 0.5], [0.0, 0.0]]
    got = np.empty((u.shape[0], 2))
    _disks(u, got)
    x, y = MF._disk(u[:, 0], u[:, 1])
    assert np.abs(got[:, 0] - x).max() <= 1e-15
    assert np.abs(got[:, 1] - y).max() <= 1e-15
    assert got[0].tolist() == [0.0, 0.0]


@njit(cache=False)
def _disks_branched(u, out):
    """compiled._disk as written before round 13: a branch on |a| > |b| and
    a division on each side (the reference its selects must equal)."""
    for i in range(u.shape[0]):
        a = 2.0 * u[i, 0] - 1.0
        b = 2.0 * u[i, 1] - 1.0
        if abs(a) > abs(b):
            s, c = C.sincos_quarter((np.pi / 4) * (b / a))
            out[i, 0], out[i, 1] = a * c, a * s
        elif b == 0.0:
            out[i, 0], out[i, 1] = 0.0, 0.0
        else:
            s, c = C.sincos_quarter((np.pi / 4) * (a / b))
            out[i, 0], out[i, 1] = b * s, b * c


def test_disk_selects_equal_the_branches_bit_for_bit():
    """The branch-free disk (one division of selected operands) is the
    branched map's arithmetic: the same bits, the centre and the diagonals
    (|a| = |b|) included."""
    u = np.random.default_rng(11).random((200_000, 2))
    edge = np.array([[0.5, 0.5], [0.5, 0.0], [0.0, 0.5], [0.5, 1.0], [1.0, 0.5], [0.0, 0.0],
                     [1.0, 1.0], [0.0, 1.0], [0.25, 0.75], [0.75, 0.75], [0.3, 0.5]])
    u = np.concatenate([edge, u])
    got, ref = np.empty((u.shape[0], 2)), np.empty((u.shape[0], 2))
    _disks(u, got)
    _disks_branched(u, ref)
    assert np.array_equal(got.view(np.int64), ref.view(np.int64))
