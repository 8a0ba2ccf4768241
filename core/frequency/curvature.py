"""Curvature of a triangle mesh for the frequency photons' interface operator.

At a delta bounce (mirror, smooth glass) ``spectrum.interface`` bends a
frequency photon's spectrum by the surface's curvature along its flatland
axis, with Coddington's cosines for oblique incidence and Snell's angle
scaling for refraction (docs/frequency.md "Refraction and oblique
incidence").  :func:`principal_frame` estimates, per triangle, both
principal curvatures and the first principal direction from its corner
(shading) normals: the shape operator fitted to the triangle's edges
(Rusinkiewicz 2004, "Estimating curvatures and their derivatives on
triangle meshes", per-face step); :func:`bounce_interface` turns them into
the operator for a photon's plane of incidence.  A curved mirror focuses
most strongly along its principal direction of largest curvature, and that
focus is where the caustic line forms (docs/frequency.md "Curvature of a
mesh").

The mean of the edges' normal curvatures ``dot(dn, dp) / |dp|^2`` is not a
substitute: on a cylinder of radius R split into tall thin triangles (a ring
reflector) two of the three edges run almost along the axis, and the mean is
about 0.34 / R, which moves the focus of a mirror lit from 2.5 m from
0.28 m to 1.05 m and predicts smooth light on the caustic line
(docs/frequency.md, measured on ring_lambert).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..scene import model as _sc
from . import spectrum as F


class Curvature(NamedTuple):
    """Principal curvatures of a mesh per triangle (:func:`principal_frame`).

    k1: (T,) float64 the principal curvature of largest magnitude [1/m];
    k2: (T,) float64 the other one; e1: (T, 3) float64 the unit principal
    direction of k1, in the triangle's plane (any tangent direction where
    k1 = k2).  Signs as :func:`principal_curvature`."""
    k1: np.ndarray
    k2: np.ndarray
    e1: np.ndarray


def principal_frame(tri_p, tri_n) -> Curvature:
    """Both principal curvatures and the first principal direction of each
    triangle: :func:`principal_curvature`'s fitted shape operator, and its
    eigenvectors.  tri_p, tri_n: (T, 3, 3).  Flat-shaded or degenerate
    triangles give k1 = k2 = 0 and e1 = their first edge's direction.

    The interface operator of a frequency photon needs both: at oblique
    incidence it bends the beam by the normal curvature along the plane of
    incidence (tangential) and across it (sagittal), Euler's
    k1 cos^2 + k2 sin^2 of the angle between e1 and that plane
    (docs/frequency.md "Refraction and oblique incidence").
    """
    P = np.asarray(tri_p, np.float64)
    Nn = np.asarray(tri_n, np.float64)
    T = P.shape[0]
    if T == 0:
        return Curvature(np.zeros(0), np.zeros(0), np.zeros((0, 3)))
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
    p, q, r = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    m = 0.5 * (p + r)
    h = np.sqrt((0.5 * (p - r)) ** 2 + q ** 2)
    first = np.abs(m + h) >= np.abs(m - h)
    k1 = np.where(first, m + h, m - h)
    k2 = np.where(first, m - h, m + h)
    # eigenvector of [[p, q], [q, r]] for k1: (q, k1 - p) or (k1 - r, q),
    # whichever is longer (both vanish only where k1 = k2: any direction)
    va = np.stack([q, k1 - p], -1)
    vb = np.stack([k1 - r, q], -1)
    v = np.where((np.abs(va).sum(-1) >= np.abs(vb).sum(-1))[:, None], va, vb)
    nv = np.linalg.norm(v, axis=1)
    v = np.where((nv > 0)[:, None], v / np.where(nv > 0, nv, 1.0)[:, None], [1.0, 0.0])
    good = ok & np.isfinite(k1) & np.isfinite(k2) & np.isfinite(v).all(1)
    d1 = np.where(good[:, None], v[:, :1] * t1 + v[:, 1:] * t2, t1)
    return Curvature(np.where(good, k1, 0.0), np.where(good, k2, 0.0), d1)


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
    return principal_frame(tri_p, tri_n).k1


def scene_curvature(scene) -> Curvature:
    """:func:`principal_frame` of a ``core.scene`` Scene's triangles: what
    the photon tracer's interface step reads."""
    return principal_frame(scene.tri_p, scene.tri_n)


def delta_ior(mtab) -> np.ndarray:
    """(M,) float64 per material: the ior of its first delta GLASS or
    REFRACTION lobe, 1 without one (a transparent lobe goes straight
    through: no angle scaling).  mtab: ``core.materials.MaterialTable``."""
    kind = np.asarray(mtab.kind)
    ref = np.asarray(mtab.lobe_delta, bool) & np.isin(kind, (_sc.GLASS, _sc.REFRACTION))
    ior = np.asarray(mtab.ior, np.float64)
    first = np.argmax(ref, axis=1)
    out = ior[np.arange(kind.shape[0]), first]
    return np.where(ref.any(axis=1) & np.isfinite(out) & (out > 0), out, 1.0)


def bounce_interface(curv: Curvature, prim, sign, ng, d_in, d_out, ior):
    """(scale, mu, k) of ``spectrum.interface`` for delta bounces, each (N,).

    curv: the scene's :class:`Curvature`; prim (N,) hit triangles; sign (N,)
    +-1, the side the photon arrives on (sign of n_s . w_i, w_i towards the
    source: the curvature seen from there); ng (N, 3) geometric normals;
    d_in, d_out (N, 3) unit directions of travel before and after; ior (N,)
    ``delta_ior`` of the hit material.

    A reflection when d_in and d_out lie on opposite sides of ng, else a
    refraction with eta = 1/ior entering (arriving on ng's side), ior
    leaving.  The shape operator in the axes of the plane of incidence
    (spanned by ng and d_in) and across it: normal curvatures
    k1 cos^2 phi + k2 sin^2 phi and k1 sin^2 phi + k2 cos^2 phi, twist
    (k1 - k2) cos phi sin phi, phi the angle between e1 and the plane (k1
    along e1 at normal incidence); ``spectrum.interface_map`` turns them
    into the operator of the most focusing axis.
    """
    ng = np.asarray(ng, np.float64)
    di = np.asarray(d_in, np.float64)
    do = np.asarray(d_out, np.float64)
    ni = np.einsum("ij,ij->i", ng, di)
    no = np.einsum("ij,ij->i", ng, do)
    t = di - ni[:, None] * ng
    t2 = np.einsum("ij,ij->i", t, t)
    e = np.einsum("ij,ij->i", curv.e1[prim], t)
    big = t2 > 1e-12
    c2 = np.where(big, np.minimum(e * e / np.where(big, t2, 1.0), 1.0), 1.0)
    k1, k2 = curv.k1[prim], curv.k2[prim]
    sg = np.asarray(sign, np.float64)
    kt = sg * (k1 * c2 + k2 * (1.0 - c2))
    ks = sg * (k1 * (1.0 - c2) + k2 * c2)
    tw = (k1 - k2) * np.sqrt(c2 * (1.0 - c2))
    ior = np.asarray(ior, np.float64)
    eta = np.where(ni < 0.0, 1.0 / ior, ior)
    return F.interface_map(np.abs(ni), np.abs(no), eta, kt, ks, tw, ni * no <= 0.0)
