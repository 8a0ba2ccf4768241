"""photon_kernels.flat_normals: the bounce kernel's kept normal of a flat
triangle against the interpolated one (shading_normal) it replaces there:
the same bits for axis-aligned normals (the Cornell box's walls), within
2 x 2^-52 of a unit vector's components on tilted ones (the interpolation
(w0 + u + v) n rounds), and smooth or degenerate triangles left to the
interpolation (docs/architecture.md "Cores at 256² and the bounce kernel,
round 13")."""
import numpy as np
from numba import njit

from core.sppm import photon_kernels as PK


@njit(cache=False)
def _interpolated(N, t, bary, out):
    for i in range(t.shape[0]):
        uu, vv = bary[i, 0], bary[i, 1]
        out[i, 0], out[i, 1], out[i, 2] = PK.shading_normal(N, t[i], 1.0 - uu - vv, uu, vv,
                                                            7.0, 7.0, 7.0)


def _bary(rng, n):
    b = rng.random((n, 2))
    flip = b.sum(axis=1) > 1.0
    b[flip] = 1.0 - b[flip]
    return b


def test_flat_normal_equals_the_interpolation():
    rng = np.random.default_rng(5)
    axis = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, -1, 0]], np.float32)
    tilt = rng.normal(size=(60, 3)).astype(np.float32)
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    n = np.concatenate([axis, tilt]).astype(np.float64)
    N = np.repeat(n[:, None, :], 3, axis=1)
    flat, ns = PK.flat_normals(N)
    assert flat.all()
    t = np.repeat(np.arange(n.shape[0]), 2000)
    got = np.empty((t.size, 3))
    _interpolated(N, t, _bary(rng, t.size), got)
    a = t < axis.shape[0]
    assert np.array_equal(got[a], ns[t[a]])
    err = np.abs(got[~a] - ns[t[~a]])
    # measured: 2.2e-16 at most, 17 % of the normals differ
    assert err.max() <= 2.0 * np.finfo(float).eps


def test_smooth_and_degenerate_triangles_are_interpolated():
    N = np.zeros((3, 3, 3))
    N[0] = [[0, 0, 1], [0, 0, 1], [0, 0.6, 0.8]]        # smooth
    N[1] = 0.0                                            # no normal: ng
    N[2] = [[0, 1, 0]] * 3
    flat, ns = PK.flat_normals(N)
    assert flat.tolist() == [False, False, True]
    assert np.array_equal(ns[2], [0.0, 1.0, 0.0])
