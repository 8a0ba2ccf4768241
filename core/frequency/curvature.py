"""Curvature of a triangle mesh for the frequency photons' curvature operator.

``spectrum.curvature`` bends a frequency photon's spectrum by the curvature of
the mirror it leaves, ``theta' = theta + 2 kappa x`` along the flatland axis
x.  A curved mirror focuses most strongly along its principal direction of
largest curvature, and that focus is where the caustic line forms
(docs/frequency.md "Curvature of a mesh").  :func:`principal_curvature`
estimates, per triangle, the principal curvature of largest magnitude from
its corner (shading) normals: the shape operator fitted to the triangle's
edges (Rusinkiewicz 2004, "Estimating curvatures and their derivatives on
triangle meshes", per-face step).

The mean of the edges' normal curvatures ``dot(dn, dp) / |dp|^2`` is not a
substitute: on a cylinder of radius R split into tall thin triangles (a ring
reflector) two of the three edges run almost along the axis, and the mean is
about 0.34 / R, which moves the focus of a mirror lit from 2.5 m from
0.28 m to 1.05 m and predicts smooth light on the caustic line
(docs/frequency.md, measured on ring_lambert).
"""
from __future__ import annotations

import numpy as np


def principal_curvature(tri_p, tri_n) -> np.ndarray:
    """(T,) float64 signed principal curvature of largest magnitude [1/m].

    tri_p: (T, 3, 3) corner positions; tri_n: (T, 3, 3) corner shading
    normals (any length; normalised here).  Sign: +1/R on the outside of a
    sphere or cylinder of radius R whose normals point outwards (convex seen
    from the side the normals face), -1/R seen from inside; 0 on flat-shaded
    or degenerate triangles.

    In a tangent frame (t1, t2) of the triangle, the shape operator S maps
    an edge e to the change of normal along it, dn = S e.  Two edges give
    four equations for the four entries of S (the third edge is their
    negated sum); S is then symmetrised (the shape operator is self-adjoint)
    and the eigenvalue of largest magnitude returned.  Exact for a
    triangle whose corner normals are those of a sphere or a cylinder.
    """
    P = np.asarray(tri_p, np.float64)
    Nn = np.asarray(tri_n, np.float64)
    T = P.shape[0]
    if T == 0:
        return np.zeros(0)
    ln = np.linalg.norm(Nn, axis=2, keepdims=True)
    Nn = np.where(ln > 0, Nn / np.where(ln > 0, ln, 1.0), 0.0)
    e1 = P[:, 1] - P[:, 0]
    e2 = P[:, 2] - P[:, 0]
    ng = np.cross(e1, e2)
    area2 = np.linalg.norm(ng, axis=1)
    ok = area2 > 0
    t1 = e1 / np.maximum(np.linalg.norm(e1, axis=1), 1e-300)[:, None]
    t2 = np.cross(ng / np.where(ok, area2, 1.0)[:, None], t1)
    E = np.stack([np.stack([np.einsum("ij,ij->i", e, t) for e in (e1, e2)], axis=-1)
                  for t in (t1, t2)], axis=1)                 # (T, 2, 2): columns e1, e2
    dn1 = Nn[:, 1] - Nn[:, 0]
    dn2 = Nn[:, 2] - Nn[:, 0]
    G = np.stack([np.stack([np.einsum("ij,ij->i", d, t) for d in (dn1, dn2)], axis=-1)
                  for t in (t1, t2)], axis=1)                 # (T, 2, 2): columns dn1, dn2
    det = E[:, 0, 0] * E[:, 1, 1] - E[:, 0, 1] * E[:, 1, 0]
    ok &= np.abs(det) > 0
    ds = np.where(ok, det, 1.0)
    Einv = np.stack([np.stack([E[:, 1, 1], -E[:, 0, 1]], -1),
                     np.stack([-E[:, 1, 0], E[:, 0, 0]], -1)], axis=1) / ds[:, None, None]
    S = G @ Einv
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    m = 0.5 * (S[:, 0, 0] + S[:, 1, 1])
    h = np.sqrt((0.5 * (S[:, 0, 0] - S[:, 1, 1])) ** 2 + S[:, 0, 1] ** 2)
    k = np.where(np.abs(m + h) >= np.abs(m - h), m + h, m - h)
    return np.where(ok & np.isfinite(k), k, 0.0)


def scene_curvature(scene) -> np.ndarray:
    """:func:`principal_curvature` of a ``core.scene`` Scene's triangles, (T,)
    float64: the ``kappa`` the photon tracer's curvature step reads."""
    return principal_curvature(scene.tri_p, scene.tri_n)
