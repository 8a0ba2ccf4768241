"""Batched ray queries over embreex, and scale-free self-intersection offsets.

Embree works in float32 and has no ``tnear``: a ray leaving a surface must
start slightly off it.  The offset is relative to the magnitude of the hit
position (float32 positions carry ``|p| * 2**-24`` of rounding), never a fixed
epsilon, so a 1 mm object and a 1 km plane are both handled.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import normals as shading_normals

# Cycles' object ray visibility (Object > Visibility > Ray Visibility), one
# bit a flag of ``Scene.tri_visibility``.  As in Cycles' BVH traversal an
# object is hit by a ray when its flags share a bit with the ray's: a camera
# ray (also after Transparent crossings) carries CAMERA, a shadow ray SHADOW.
RAY_CAMERA, RAY_DIFFUSE, RAY_GLOSSY, RAY_TRANSMISSION, RAY_SHADOW = 1, 2, 4, 8, 16
RAY_ALL = 31
RAY_FLAGS = {"camera": RAY_CAMERA, "diffuse": RAY_DIFFUSE, "glossy": RAY_GLOSSY,
             "transmission": RAY_TRANSMISSION, "shadow": RAY_SHADOW}

# Relative offset: 2**-18 ~ 3.8e-6 of |p|, i.e. 64 float32 ulps of the
# coordinate, which covers Embree's watertight-intersection error while staying
# far below any feature we render (1 mm at 260 m).
REL_OFFSET = 2.0 ** -18


@dataclass
class Hits:
    """Closest hits of K rays.

    t: (K,) float64 hit distance, np.inf on a miss.
    prim: (K,) int32 triangle index, -1 on a miss.
    u, v: (K,) float64 Embree barycentrics (p = (1-u-v) p0 + u p1 + v p2).
    """
    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.prim >= 0


def hidden_triangles(visibility, flags: int) -> np.ndarray | None:
    """(T,) bool: the triangles whose RAY_* visibility (T,) shares no flag
    with rays carrying ``flags`` (Cycles' test), or None when there is none
    (visibility None: every object seen)."""
    if visibility is None:
        return None
    hid = (np.asarray(visibility) & int(flags)) == 0
    return hid if hid.any() else None


class Accel:
    """Embree scene over world-space triangles ``tri_p`` (T, 3, 3) float32.

    visibility: (T,) uint8 RAY_* flags of each triangle's object, or None
    (every object seen by every ray).  embree: the Embree scene of another
    Accel of the same tri_p (``core.setup_cache``), or None: built here.  The Accel itself holds every triangle
    (photons, and the rays of the kinds no object hides from); the rays of a
    kind some objects hide from are cast in :meth:`for_rays`' scene, whose
    hits are still the triangles' indices here.
    """

    def __init__(self, tri_p: np.ndarray, scene_diameter: float, visibility=None,
                 _subset=None, _base=None, embree=None):
        self.tri_p = np.ascontiguousarray(tri_p, dtype=np.float32)
        self.diameter = float(scene_diameter)
        # Floor for the offset at the origin, relative to the scene size.
        self.abs_floor = 1e-9 * self.diameter
        self.rays_cast = 0
        self.base = self if _base is None else _base
        # (n,) int32 the triangles of a for_rays scene (its Embree primID ->
        # tri_p's index), None: every triangle.
        self.subset = _subset
        vis = None if visibility is None else np.asarray(visibility, np.uint8)
        self.visibility = None if vis is None or np.all(vis & RAY_ALL == RAY_ALL) else vis
        self._kinds: dict = {}               # flags -> the Accel those rays see
        self._hidden: dict = {}              # flags -> hidden_from's array or None
        self._hidden_key = b""
        self._views: list = []               # the scenes of ``without``, one a hidden set
        self._scene = None
        tri = self.tri_p if _subset is None else self.tri_p[_subset]
        if embree is not None:
            # Another Accel's Embree scene of these very triangles (its BVH
            # does not depend on the diameter: core.setup_cache).
            self._scene = embree
        elif tri.shape[0]:
            from embreex import rtcore_scene as rtcs
            from embreex.mesh_construction import TriangleMesh
            self._scene = rtcs.EmbreeScene()
            TriangleMesh(self._scene, np.ascontiguousarray(tri))

    def for_rays(self, flags: int) -> "Accel":
        """The scene as rays carrying the RAY_* ``flags`` see it: without the
        triangles whose objects share no flag with them (Cycles' visibility
        test), built once per set of hidden objects; self when nothing hides."""
        base = self.base
        if base.visibility is None:
            return base
        flags = int(flags)
        got = base._kinds.get(flags)          # per call in the passes: looked up once
        if got is not None:
            return got
        hid = base.hidden_from(flags)
        sub = base if hid is None else base.without(hid)
        base._kinds[flags] = sub
        return sub

    def without(self, hidden: np.ndarray) -> "Accel":
        """The scene without the triangles hidden (T,) bool (a kind of ray's
        view, :meth:`for_rays`, or a shadow linking view,
        core.scene.shadow_linking): built once per set of hidden triangles
        (two kinds of ray or memberships may share it); self's base when
        nothing is hidden."""
        base = self.base
        if not np.any(hidden):
            return base
        key = np.asarray(hidden, bool).tobytes()
        sub = next((a for a in base._views if a._hidden_key == key), None)
        if sub is None:
            sub = Accel(base.tri_p, base.diameter,
                        _subset=np.nonzero(~np.asarray(hidden, bool))[0].astype(np.int32),
                        _base=base)
            sub._hidden_key = key
            base._views.append(sub)
        return sub

    def hidden_from(self, flags: int) -> np.ndarray | None:
        """(T,) bool: the triangles rays carrying ``flags`` do not see, or None
        when they see every one (computed once per flags)."""
        base = self.base
        if base.visibility is None:
            return None
        flags = int(flags)
        if flags not in base._hidden:
            base._hidden[flags] = hidden_triangles(base.visibility, flags)
        return base._hidden[flags]

    def global_prim(self, prim: np.ndarray) -> np.ndarray:
        """prim (K,) int32 Embree primIDs of this scene (-1 = miss), as
        indices of ``tri_p`` (in place, and returned)."""
        if self.subset is not None:
            h = prim >= 0
            prim[h] = self.subset[prim[h]]
        return prim

    def count_rays(self, K: int) -> None:
        """rays_cast += K, thread-safe: photons may be traced (two threads)
        while the camera and shadow rays are cast (PhotonPass.trace_ahead).
        A for_rays scene counts into its base's."""
        with _COUNT_LOCK:
            self.base.rays_cast += K

    @staticmethod
    def _f32(a):
        return np.ascontiguousarray(a, dtype=np.float32)

    def intersect(self, o: np.ndarray, d: np.ndarray, t_max=None) -> Hits:
        """Closest hit of rays o (K,3) + t d (K,3), t in (0, t_max)."""
        K = o.shape[0]
        self.count_rays(K)
        if self._scene is None or K == 0:
            return Hits(np.full(K, np.inf), np.full(K, -1, np.int32),
                        np.zeros(K), np.zeros(K))
        dists = None
        if t_max is not None:
            dists = self._f32(np.minimum(np.broadcast_to(t_max, (K,)), 3e37))
        r = self._scene.run(self._f32(o), self._f32(d), dists=dists, output=1)
        prim = self.global_prim(r["primID"].astype(np.int32))
        t = np.where(prim >= 0, r["tfar"].astype(np.float64), np.inf)
        return Hits(t, prim, r["u"].astype(np.float64), r["v"].astype(np.float64))

    def occluded(self, o: np.ndarray, d: np.ndarray, t_max) -> np.ndarray:
        """(K,) bool: anything hit in (0, t_max)?  t_max may be np.inf."""
        K = o.shape[0]
        self.count_rays(K)
        if self._scene is None or K == 0:
            return np.zeros(K, bool)
        dists = self._f32(np.minimum(np.broadcast_to(t_max, (K,)), 3e37))
        r = self._scene.run(self._f32(o), self._f32(d), dists=dists, query="OCCLUDED")
        return np.asarray(r) >= 0

    def offset_scale(self, p: np.ndarray) -> np.ndarray:
        """(K,) float64 offset length for points p (K,3): relative to |p|_inf."""
        return np.maximum(np.abs(p).max(axis=1), self.abs_floor / REL_OFFSET) * REL_OFFSET

    def spawn(self, p: np.ndarray, ng: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Origin for a ray leaving surface point p (K,3) along w (K,3).

        Pushed along the geometric normal ng to the side w points to, so the
        new ray cannot re-hit its own triangle (pbrt's OffsetRayOrigin idea
        with a relative error bound).
        """
        side = np.where(np.einsum("ij,ij->i", ng, w) >= 0, 1.0, -1.0)
        return p + ng * (side * self.offset_scale(p))[:, None]


def hit_uv(tri_uv: np.ndarray, prim: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(K, 2) float64 texture coordinates of the hits (prim, u, v) (K,) on
    triangles with corner uvs tri_uv (T, 3, 2)."""
    UV = tri_uv[prim].astype(np.float64)
    w0 = (1.0 - u - v)[:, None]
    return w0 * UV[:, 0] + u[:, None] * UV[:, 1] + v[:, None] * UV[:, 2]


def surface_point(tri_p: np.ndarray, tri_n: np.ndarray, tri_uv: np.ndarray,
                  prim: np.ndarray, u: np.ndarray, v: np.ndarray):
    """Interpolate hit attributes in float64.

    Returns p (K,3) position from barycentrics (more precise than o + t d),
    ng (K,3) unit geometric normal (winding order), ns (K,3) unit shading
    normal (perturbed by the material's Normal Map / Bump when the scene
    attached one to tri_n: ``core.scene.normals``), uv (K,2).
    """
    P = tri_p[prim].astype(np.float64)           # (K,3,3)
    w0 = (1.0 - u - v)[:, None]
    p = w0 * P[:, 0] + u[:, None] * P[:, 1] + v[:, None] * P[:, 2]
    ng = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    N = tri_n[prim].astype(np.float64)
    ns = w0 * N[:, 0] + u[:, None] * N[:, 1] + v[:, None] * N[:, 2]
    nlen = np.linalg.norm(ns, axis=1, keepdims=True)
    ns = np.where(nlen > 1e-12, ns / np.maximum(nlen, 1e-300), ng)
    uv = hit_uv(tri_uv, prim, u, v)
    # Normal Map / Bump materials: the spec the Scene attached to its tri_n.
    spec = shading_normals.attached(tri_n)
    if spec is not None:
        ns = shading_normals.perturb(spec, prim, u, v, ns, uv)
    return p, ng, ns, uv


_COUNT_LOCK = __import__("threading").Lock()


def intersect_f32(accel: Accel, o32: np.ndarray, d32: np.ndarray):
    """Closest hits of K rays given as C-contiguous (K, 3) float32 arrays, no copies.

    Returns Embree's own arrays: prim (K,) int32 (-1 = miss), u, v, tfar (K,)
    float32 (p = (1-u-v) p0 + u p1 + v p2; tfar meaningless on a miss).
    Counts the rays in ``accel.rays_cast`` (thread-safe; Embree releases the
    GIL, so callers may trace in several threads).  For compiled callers that
    interpolate hits themselves (``core.photon_kernels``): the float64
    conversions of :meth:`Accel.intersect` cost as much as Embree itself on
    small scenes.
    """
    K = o32.shape[0]
    accel.count_rays(K)
    if accel._scene is None or K == 0:
        return (np.full(K, -1, np.int32), np.zeros(K, np.float32), np.zeros(K, np.float32),
                np.full(K, np.inf, np.float32))
    r = accel._scene.run(o32, d32, output=1)
    return accel.global_prim(r["primID"]), r["u"], r["v"], r["tfar"]


def cast_by_kind(cast, accel: Accel, flags: int, rows: np.ndarray, o: np.ndarray,
                 d: np.ndarray, tmax: np.ndarray) -> tuple:
    """``cast(a, o, d, tmax)`` (a tuple of (K, ...) arrays a ray) with the
    rays rows (K,) bool carrying the RAY_* ``flags`` cast in
    ``accel.for_rays(flags)`` and the others in ``accel``: one call when one
    scene serves every ray (the rays of every scene without hidden objects)."""
    kind = accel.for_rays(flags)
    if kind is accel or not rows.any():
        return cast(accel, o, d, tmax)
    if rows.all():
        return cast(kind, o, d, tmax)
    return _cast_groups(cast, [(kind, rows), (accel, ~rows)], o, d, tmax)


#: The kinds of :func:`cast_by_kinds` (0: the whole scene).
_KINDS = (0, RAY_CAMERA, RAY_GLOSSY, RAY_TRANSMISSION)


def cast_by_kinds(cast, accel: Accel, kinds: np.ndarray, o: np.ndarray, d: np.ndarray,
                  tmax: np.ndarray) -> tuple:
    """``cast(a, o, d, tmax)`` (a tuple of (K, ...) arrays a ray) with each
    ray cast in ``accel.for_rays(kinds[i])`` (kinds (K,) int: 0 (in
    ``accel``) or one of :data:`_KINDS`' RAY_* flags): one call a scene, one
    call in all when one scene serves every ray (the rays of every scene
    without hidden objects)."""
    if accel.base.visibility is None:
        return cast(accel, o, d, tmax)
    # The scenes of the kinds (few: the camera side's), grouped by scene;
    # a scene's rays by comparisons, not a sort of the K kinds.
    views: dict = {}
    for k in _KINDS:
        a = accel if k == 0 else accel.for_rays(k)
        views.setdefault(id(a), (a, []))[1].append(k)
    if len(views) == 1:
        return cast(accel, o, d, tmax)
    groups = []
    for a, ks in views.values():
        m = kinds == ks[0]
        for k in ks[1:]:
            m |= kinds == k
        if m.any():
            groups.append((a, m))
    if len(groups) == 1:
        return cast(groups[0][0], o, d, tmax)
    return _cast_groups(cast, groups, o, d, tmax)


def _cast_groups(cast, groups, o, d, tmax) -> tuple:
    """``cast`` of each group's rays ((scene, rows (K,) bool), ... covering
    every ray once) in its scene, the results put back in ray order."""
    out = None
    for a, m in groups:
        r = np.nonzero(m)[0]
        got = cast(a, o[r], d[r], tmax[r])
        if out is None:
            out = [np.empty((m.size,) + x.shape[1:], x.dtype) for x in got]
        for x, y in zip(out, got):
            x[r] = y
    return tuple(out)


def _intersect_cast(a, o_, d_, t_):
    h = a.intersect(o_, d_, t_)
    return h.t, h.prim, h.u, h.v


def intersect_by_kind(accel: Accel, flags: int, rows: np.ndarray, o, d, tmax) -> Hits:
    """:meth:`Accel.intersect` with the rays rows (K,) bool carrying the RAY_*
    ``flags`` (:func:`cast_by_kind`)."""
    tmax = np.broadcast_to(np.inf if tmax is None else tmax, rows.shape)
    return Hits(*cast_by_kind(_intersect_cast, accel, flags, rows, o, d, tmax))


def intersect_by_kinds(accel: Accel, kinds: np.ndarray, o, d, tmax) -> Hits:
    """:meth:`Accel.intersect` with each ray in the scene its RAY_* kinds
    (K,) see (:func:`cast_by_kinds`)."""
    tmax = np.broadcast_to(np.inf if tmax is None else tmax, kinds.shape)
    return Hits(*cast_by_kinds(_intersect_cast, accel, kinds, o, d, tmax))


def chain_kinds(on_line: np.ndarray, last: np.ndarray) -> np.ndarray:
    """(K,) the RAY_* kind of the camera side's rays that leave the lens or
    a mirror or glass (Cycles' ray types): a camera ray while on its line
    (on_line (K,) bool: no vertex yet, or straight Transparent crossings),
    else glossy after a reflection and transmission after a refraction
    (last (K,) int8: 1 reflection, 2 transmission)."""
    return np.where(on_line, RAY_CAMERA,
                    np.where(last == 2, RAY_TRANSMISSION, RAY_GLOSSY)).astype(np.int64)
