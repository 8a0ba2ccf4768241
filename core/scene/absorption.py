"""Absorbing volumes: Beer-Lambert attenuation inside closed surfaces.

A material whose Volume output is a Volume Absorption of constant Color c
and Density rho fills the inside of its surface with a homogeneous medium of
absorption coefficient sigma_a = rho (1 - c) per metre (Cycles'
``svm_node_closure_volume``: an absorption closure's extinction is its
weight 1 - c times the density).  A ray keeps exp(-sigma_a t) of its
throughput over a length t inside (Beer-Lambert; no scattering, so nothing
else changes).

Which segments are inside: Cycles keeps a volume stack, entering a volume
where a ray crosses the front side of its surface and leaving it at the back
side (``volume_stack_enter_exit``, by the geometric normal's side).  For
volumes that neither nest nor overlap, and closed surfaces with outward
winding, that is stateless: a segment that ends on the back side of a
surface with a volume (its geometric normal, by winding, along the ray)
travelled inside that volume from its start.  :func:`attenuate` applies it
to any batch of hits: camera rays and camera paths (their throughput),
photons and light paths (their power), and shadow rays that cross
transparent surfaces (core.lights.shadow).  A ray that leaves a volume
through a surface without one, or ends inside it (a light inside the
medium), is not attenuated on that segment.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np


class Absorption(NamedTuple):
    """sigma (M, 3) float64 each material's absorption coefficient [1/m]
    (0: no volume), has (M,) bool sigma > 0 somewhere, tri_mat (T,) the
    triangles' materials, tri_p (T, 3, 3) float32 their corners."""
    sigma: np.ndarray
    has: np.ndarray
    tri_mat: np.ndarray
    tri_p: np.ndarray


def of_scene(scene) -> Optional[Absorption]:
    """The scene's :class:`Absorption`, or None when no material has an
    absorbing volume.  Computed once per scene (kept with the arrays it was
    computed from)."""
    mats = getattr(scene, "materials", None)
    key = (getattr(scene, "tri_mat", None), mats, getattr(scene, "tri_p", None))
    memo = getattr(scene, "__dict__", {}).get("_absorption")
    if memo is not None and all(a is b for a, b in zip(memo[0], key)):
        return memo[1]
    out = None
    if mats and any(getattr(m, "absorption", ()) for m in mats):
        sigma = np.array([np.asarray(m.absorption, np.float64) if getattr(m, "absorption", ())
                          else np.zeros(3) for m in mats], np.float64).reshape(-1, 3)
        has = sigma.max(axis=1) > 0
        if has.any():
            out = Absorption(sigma, has, np.asarray(scene.tri_mat, np.int64),
                             np.asarray(scene.tri_p))
    if hasattr(scene, "__dict__"):
        scene.__dict__["_absorption"] = (key, out)
    return out


def attenuate(ab: Optional[Absorption], prim: np.ndarray, t: np.ndarray, d: np.ndarray,
              beta: np.ndarray, rows: Optional[np.ndarray] = None) -> None:
    """beta (K, 3) *= exp(-sigma_a t |d|) in place on the rays whose hit
    (prim (K,), -1 none; ray parameter t (K,)) is the back side of a
    surface with an absorbing volume (d (K, 3) the rays' directions); rows
    (K,): beta's rows of the K rays (None: the K first).  Nothing when ab
    is None."""
    if ab is None:
        return
    prim = np.asarray(prim)
    k = np.nonzero(prim >= 0)[0]
    if k.size == 0:
        return
    m = ab.tri_mat[prim[k]]
    k, m = k[ab.has[m]], m[ab.has[m]]
    if k.size == 0:
        return
    P = ab.tri_p[prim[k]].astype(np.float64)
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    dk = np.asarray(d[k], np.float64)
    back = np.einsum("ij,ij->i", n, dk) > 0
    k, m, dk = k[back], m[back], dk[back]
    if k.size == 0:
        return
    length = np.asarray(t, np.float64)[k] * np.linalg.norm(dk, axis=1)
    r = k if rows is None else np.asarray(rows)[k]
    beta[r] *= np.exp(-ab.sigma[m] * length[:, None])
