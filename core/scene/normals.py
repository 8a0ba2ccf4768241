"""Shading normals perturbed by a material's Normal Map or Bump node, as Cycles computes them.

Normal Map, tangent space (Cycles ``svm_node_normal_map``): the texel rgb
becomes c = 2 rgb - 1 (DirectX convention: c.y negated), and

    N' = normalize(c.x T + c.y s (N x T) + c.z N)

with T the interpolated (unnormalised) MikkTSpace tangent of the mesh's UV
map, s its bitangent sign and N the interpolated (unnormalised) shading
normal.  Strength k != 1: N'' = normalize(n + k (N' - n)), n the unit
shading normal.

Bump from a height h(uv) (Cycles ``svm_node_set_bump``): with two surface
tangents dP/dx, dP/dy (Cycles: the ray differentials; here dP/du, dP/dv of
the triangle, and h's exact uv-derivatives, which the formula's degree-2
homogeneity makes equivalent in the limit of a small footprint),

    Rx = dP/dy x n,  Ry = n x dP/dx,  det = dP/dx . Rx,
    N' = normalize(|det| n - d sign(det) (dh/dx Rx + dh/dy Ry)),
    N'' = normalize(k N' + (1 - k) n),

d the Distance (negated by Invert), k the Strength clamped to [0, 1].

Cycles also tilts a perturbed normal whose mirror direction of the view
would go below the surface (``ensure_valid_specular_reflection``, on with
the material's default bump-map correction): :func:`valid_specular_normal`,
applied by ``core.materials`` to materials with a Normal Map / Bump input
(``MaterialTable.bump_correction``), where the view direction is known.

Where the perturbed normal is used: wherever ``core.accel.surface_point``
gives a shading normal (visible points, next-event estimation, the path and
light tracers' BSDF evaluation and sampling, the Normal pass).  The photon
tracer's compiled bounce reads the interpolated normals directly
(``Scene.tri_n``), so photons scatter off the unperturbed surface: the
perturbation reaches photon-mapped light only where it is gathered (docs/shading.md).

The link to ``surface_point``, which receives the triangle arrays and not the
scene: a :class:`ShadingSpec` is attached to the scene's ``tri_n`` array
(:func:`attach`, by :class:`core.scene.model.Scene` itself) and looked up by
identity (:func:`attached`); the entry dies with the array.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from .textures import sample_texture, scalar_gradient

NORMAL_MAP, BUMP = "NORMAL_MAP", "BUMP"


@dataclass(frozen=True)
class NormalInput:
    """What feeds a material's Normal inputs.

    kind: NORMAL_MAP (tangent space) or BUMP.
    texture: index into ``Scene.textures`` (the normal map, or the height).
    strength: the node's Strength.  distance, invert: Bump only.
    channel: Bump height from the image's 'COLOR' (luminance) or 'ALPHA'.
    directx: Normal Map with the DirectX convention (green points down).
    base: Bump only, the NormalInput feeding the Bump's own Normal input (a
      Normal Map under the bump), or None (the interpolated normal).
    shadowing: the diffuse lobes take Cycles' bump shadowing term.  False
      for a displacement's bump alone: Cycles sets the shading normal itself
      to the bumped one (``bump_from_displacement``'s SetNormal node), so its
      closures' normal is the surface's and ``bump_shadowing_term`` is 1.
    """
    kind: str
    texture: int
    strength: float = 1.0
    distance: float = 1.0
    invert: bool = False
    channel: str = "COLOR"
    directx: bool = False
    base: object = None
    shadowing: bool = True


@dataclass(frozen=True)
class ShadingSpec:
    """Everything :func:`perturb` reads: the scene's triangle arrays (tri_p
    (T, 3, 3), tri_n (T, 3, 3), tri_uv (T, 3, 2), tri_mat (T,), tri_tangent
    (T, 3, 4) or None), the per-material :class:`NormalInput` or None, the
    textures and the bump distance's factor per triangle (T,) or None
    (``Scene.tri_bump_scale``)."""
    tri_p: np.ndarray
    tri_n: np.ndarray
    tri_uv: np.ndarray
    tri_mat: np.ndarray
    tri_tangent: object
    inputs: tuple
    textures: list
    tri_bump_scale: object = None


_ATTACHED: dict = {}


def attach(tri_n: np.ndarray, spec: ShadingSpec | None) -> None:
    """Make ``surface_point(..., tri_n, ...)`` perturb its normals by spec (None: stop)."""
    key = id(tri_n)
    if spec is None:
        _ATTACHED.pop(key, None)
        return

    def gone(ref, key=key, table=_ATTACHED):
        # (table bound here: module globals may be None at interpreter exit)
        e = table.get(key)
        if e is not None and e[0] is ref:
            del table[key]

    try:
        ref = weakref.ref(tri_n, gone)
    except TypeError:          # not an ndarray (Scene always holds one)
        return
    _ATTACHED[key] = (ref, spec)


def attached(tri_n) -> ShadingSpec | None:
    """The spec attached to this very array, or None."""
    e = _ATTACHED.get(id(tri_n))
    if e is None or e[0]() is not tri_n:
        return None
    return e[1]


def perturbed_materials(spec: ShadingSpec, M: int) -> np.ndarray:
    """(M,) bool: the materials whose shading normal the spec perturbs (a
    Normal input); materials past the spec's inputs are not."""
    out = np.zeros(M, bool)
    b = np.array([inp is not None for inp in spec.inputs], bool)[:M]
    out[:b.size] = b
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.maximum(n, 1e-300)


def _safe_unit(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(n > 1e-12, v / np.maximum(n, 1e-300), fallback)


def triangle_uv_frame(P: np.ndarray, UV: np.ndarray):
    """dP/du, dP/dv (K, 3) of triangles P (K, 3, 3) with corner uvs UV (K, 3, 2),
    and ok (K,) False where the uvs are degenerate (zero uv area).

    Solves [e1 e2] = [dP/du dP/dv] [[du1, du2], [dv1, dv2]] (pbrt's
    Triangle::InteractionFromIntersection)."""
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    d1, d2 = UV[:, 1] - UV[:, 0], UV[:, 2] - UV[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    scale = np.maximum(np.abs(d1).max(axis=1) * np.abs(d2).max(axis=1), 1e-300)
    ok = np.abs(det) > 1e-9 * scale
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    dpdu = (d2[:, 1:2] * e1 - d1[:, 1:2] * e2) * inv
    dpdv = (-d2[:, 0:1] * e1 + d1[:, 0:1] * e2) * inv
    return dpdu, dpdv, ok


def tangent_space_normal(c: np.ndarray, N: np.ndarray, T: np.ndarray, sign: np.ndarray,
                         n_unit: np.ndarray, strength: float = 1.0) -> np.ndarray:
    """Cycles' tangent-space Normal Map: c (K, 3) = 2 rgb - 1, N and T (K, 3)
    interpolated normal and tangent (unnormalised), sign (K,) the bitangent
    sign, n_unit (K, 3) the unit shading normal.  Returns (K, 3) unit normals."""
    B = sign[:, None] * np.cross(N, T)
    Np = _safe_unit(c[:, 0:1] * T + c[:, 1:2] * B + c[:, 2:3] * N, n_unit)
    if strength != 1.0:
        k = max(float(strength), 0.0)
        Np = _safe_unit(n_unit + (Np - n_unit) * k, n_unit)
    return Np


def bump_normal(n: np.ndarray, dpdx: np.ndarray, dpdy: np.ndarray, dhdx: np.ndarray,
                dhdy: np.ndarray, strength: float = 1.0, distance=1.0,
                invert: bool = False) -> np.ndarray:
    """Cycles' Bump node: n (K, 3) unit normal, dpdx, dpdy (K, 3) surface
    tangents, dhdx, dhdy (K,) the height's derivatives along them, distance
    a float or (K,) per point.  Returns (K, 3) unit normals (see the module
    docstring)."""
    Rx = np.cross(dpdy, n)
    Ry = np.cross(n, dpdx)
    det = np.einsum("ij,ij->i", dpdx, Rx)
    surfgrad = dhdx[:, None] * Rx + dhdy[:, None] * Ry
    d = np.asarray(distance, np.float64) * (-1.0 if invert else 1.0)
    out = _safe_unit(np.abs(det)[:, None] * n - (d * np.sign(det))[..., None] * surfgrad, n)
    k = min(max(float(strength), 0.0), 1.0)
    return _safe_unit(k * out + (1.0 - k) * n, n)


def valid_specular_normal(ng: np.ndarray, i: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Cycles' ``ensure_valid_specular_reflection`` (K, 3): n tilted towards
    ng just enough that the mirror direction of i about it rises to
    t = min(0.9 i.ng, 0.01) above the geometric surface.  ng, n (K, 3) unit on
    i's side (i.ng >= 0), i (K, 3) unit, pointing away from the surface.

    In the frame Z = ng, X = n's part orthogonal to ng, the new normal
    (Nx, 0, Nz) solves 2 (Nx i.x + Nz i.z) Nz - i.z = t; squaring gives
    4 a Nz^4 - 2 b Nz^2 + c = 0 with a = i.x^2 + i.z^2, b = 2 (a + i.z t),
    c = (i.z + t)^2, and the root taken is the one of the unsquared equation."""
    dot = lambda a, b: np.einsum("ij,ij->i", a, b)   # noqa: E731
    R = 2.0 * dot(n, i)[:, None] * n - i
    iz = dot(i, ng)
    t = np.minimum(0.9 * iz, 0.01)
    bad = dot(ng, R) < t
    if not bad.any():
        return n
    out = n.copy()
    nb, gb, ib, izb, tb = n[bad], ng[bad], i[bad], iz[bad], t[bad]
    X = _safe_unit(nb - dot(nb, gb)[:, None] * gb, nb)
    ix = dot(ib, X)
    a = ix * ix + izb * izb
    b = 2.0 * (a + izb * tb)
    c = (tb + izb) ** 2
    root = np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))
    a_safe = np.where(a > 0, a, 1.0)
    nz2 = np.where(ix < 0, 0.25 * (b + root) / a_safe, 0.25 * (b - root) / a_safe)
    nx = np.sqrt(np.maximum(1.0 - nz2, 0.0))
    nz = np.sqrt(np.maximum(nz2, 0.0))
    out[bad] = np.where((a > 0)[:, None], nx[:, None] * X + nz[:, None] * gb, nb)
    return out


def _fallback_tangent(P, UV, N):
    """Per-triangle unit tangent along dP/du, orthogonal to N, and its
    bitangent sign, for triangles without MikkTSpace tangents (Cycles:
    normalize(dPdu); equal to MikkTSpace on flat, uniformly mapped faces)."""
    dpdu, dpdv, ok = triangle_uv_frame(P, UV)
    T = _safe_unit(dpdu - np.einsum("ij,ij->i", dpdu, N)[:, None] * N, dpdu)
    sign = np.where(np.einsum("ij,ij->i", np.cross(N, T), dpdv) < 0, -1.0, 1.0)
    return T, sign, ok


def _apply(spec: ShadingSpec, inp: NormalInput, t, u, v, n, uv):
    """(normals (k, 3), ok (k,)) of one NormalInput at hits (t, u, v) with unit
    normals n (k, 3) and texture coordinates uv (k, 2)."""
    if inp.texture < 0 or inp.texture >= len(spec.textures):
        return n, np.zeros(len(t), bool)
    img = spec.textures[inp.texture]
    w = np.stack([1.0 - u - v, u, v], axis=1)[:, :, None]          # (k, 3, 1)
    P = spec.tri_p[t].astype(np.float64)
    UV = spec.tri_uv[t].astype(np.float64)
    if inp.kind == NORMAL_MAP:
        N = (w * spec.tri_n[t].astype(np.float64)).sum(axis=1)
        T, sign, ok = _fallback_tangent(P, UV, n)
        if spec.tri_tangent is not None:
            tt = np.asarray(spec.tri_tangent)[t].astype(np.float64)
            has = tt[:, 0, 3] != 0.0
            T = np.where(has[:, None], (w * tt[:, :, :3]).sum(axis=1), T)
            sign = np.where(has, np.sign(tt[:, 0, 3]), sign)
            ok = ok | has
        c = 2.0 * sample_texture(img, uv) - 1.0
        if inp.directx:
            c[:, 1] = -c[:, 1]
        return tangent_space_normal(c, N, T, sign, n, inp.strength), ok
    if inp.base is not None:
        # The Bump's Normal input: the normal map below it (Cycles: normal_in).
        nb, okb = _apply(spec, inp.base, t, u, v, n, uv)
        n = np.where(okb[:, None], nb, n)
    dpdu, dpdv, ok = triangle_uv_frame(P, UV)
    _, dhdu, dhdv = scalar_gradient(img, uv, inp.channel)
    dist = inp.distance
    if spec.tri_bump_scale is not None:
        dist = inp.distance * np.asarray(spec.tri_bump_scale, np.float64)[t]
    return bump_normal(n, dpdu, dpdv, dhdu, dhdv, inp.strength, dist, inp.invert), ok


def perturb(spec: ShadingSpec, prim: np.ndarray, u: np.ndarray, v: np.ndarray,
            ns: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The shading normals (K, 3) of hits (prim, u, v) whose material has a
    Normal Map or Bump input; ns (K, 3) unit interpolated normals (returned
    unchanged elsewhere), uv (K, 2) their texture coordinates."""
    prim = np.asarray(prim, np.int64)
    mat = np.asarray(spec.tri_mat)[prim]
    out = ns
    for m, inp in enumerate(spec.inputs):
        if inp is None or inp.texture < 0 or inp.texture >= len(spec.textures):
            continue
        sel = np.nonzero(mat == m)[0]
        if sel.size == 0:
            continue
        if out is ns:
            out = ns.copy()
        res, ok = _apply(spec, inp, prim[sel], u[sel], v[sel], ns[sel], uv[sel])
        out[sel] = np.where(ok[:, None] & np.all(np.isfinite(res), axis=1)[:, None], res, ns[sel])
    return out
