"""Cycles' Voronoi Texture node evaluated at texture-space points, vectorised
over them (intern/cycles/kernel/svm/voronoi.h, ``svm_node_tex_voronoi``).

:func:`voronoi_texture` follows core/scene/procedural.py's interface: p (N, 3)
float64 texture-space points, ``params`` the node's sockets by name and
properties by identifier (a missing key is Blender 5.2's default,
:data:`VORONOI_DEFAULTS`), the result (N, 3) float64.

The space, 1D (W), 2D (x, y), 3D (x, y, z) or 4D (x, y, z, W) scaled by Scale,
is cut into unit cells, each with one random point: Cycles (since Blender
5.0) hashes a 2D-4D cell's integer corner by PCG (``hash_int{2,3,4}_to_float*``)
and a 1D cell's float corner by Jenkins' lookup3 (``hash_float_to_float``),
both in core/scene/cycles_hash.py; the point is the hash times Randomness.  A
point is held as a (d, N) float32 array, one row a coordinate; every search
is a Python loop over the 3^d (5^d for Smooth F1) neighbour offsets in
Cycles' loop order (x fastest) with arrays over the N points inside, so that
ties go as in Cycles (a strictly smaller distance wins).  All arithmetic is
float32 in Cycles' order: cells, their hashes and the distances are Cycles'
to the last bit but for the sums' order and libm's powf.  F1 and N-Sphere
Radius search by Cycles' cheaper ``voronoi_distance_bound`` (the squared
Euclidean distance, Minkowski's sum before its root) and take the distance
of the point found, as Cycles does.

Points share cells, so a cell's random point is hashed once per distinct cell
(:class:`_Lattice`) and gathered to the points.

Features: F1, F2 and Smooth F1 go through ``fractal_voronoi_x_fx`` (Detail
octaves of Lacunarity-scaled frequency, Roughness-scaled amplitude, the
fractional last octave blended in, Normalize dividing by the sum of the
amplitudes and the largest distance); Distance to Edge through
``fractal_voronoi_distance_to_edge``; N-Sphere Radius is a single octave.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from . import cycles_hash as H
from .patterns import _grey

F32 = np.float32
FLT_MAX = F32(np.finfo(np.float32).max)

#: Blender 5.2's defaults of a Voronoi Texture node (sockets, then properties).
VORONOI_DEFAULTS = {
    "W": 0.0,
    "Scale": 5.0,
    "Detail": 0.0,
    "Roughness": 0.5,
    "Lacunarity": 2.0,
    "Smoothness": 1.0,
    "Exponent": 0.5,
    "Randomness": 1.0,
    "voronoi_dimensions": "3D",
    "distance": "EUCLIDEAN",
    "feature": "F1",
    "normalize": False,
}

_DIMS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}


@dataclass
class _Params:
    """Cycles' ``VoronoiParams``, clamped as ``svm_node_tex_voronoi`` clamps them."""
    dims: int
    feature: str
    metric: str
    scale: F32
    detail: F32
    roughness: F32
    lacunarity: F32
    smoothness: F32
    exponent: F32
    randomness: F32
    normalize: bool
    max_distance: F32 = F32(0)


@lru_cache(maxsize=None)
def _offsets(d: int, r: int) -> np.ndarray:
    """(K, d, 1) float32 the neighbour offsets -r..r of a d-dimensional cell in
    Cycles' loop order: x varies fastest, the last coordinate slowest."""
    offs = [tuple(reversed(o)) for o in itertools.product(range(-r, r + 1), repeat=d)]
    return np.asarray(offs, F32)[:, :, None]


def _point_hash(c: np.ndarray) -> np.ndarray:
    """(d, M) float32 the random point in [0, 1]^d of cells c (d, M): 1D a
    float32 corner (``hash_float_to_float``), 2D-4D an int64 one
    (``hash_int2_to_float2`` / ``hash_int3_to_float3`` / ``hash_int4_to_float4``)."""
    d = c.shape[0]
    if d == 1:
        return H.hash_float_to_float(c[0])[None].astype(F32)
    fn = {2: H.hash_int2_to_float2, 3: H.hash_int3_to_float3, 4: H.hash_int4_to_float4}[d]
    return fn(*c).T.astype(F32)


def _colour_hash(c: np.ndarray) -> np.ndarray:
    """(3, M) float32 the colour of cells c (d, M) as :func:`_point_hash` takes
    them: Cycles' ``hash_float_to_float3`` / ``hash_int{2,3,4}_to_float3``."""
    fn = {1: H.hash_float_to_float3, 2: H.hash_int2_to_float3,
          3: H.hash_int3_to_float3, 4: H.hash_int4_to_float3}[c.shape[0]]
    return fn(*c).T.astype(F32)


def _unique_columns(cell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cells (d, M) float32, inverse (N,) intp): the distinct columns of cell
    (d, N) float32 (integer-valued) and each column's index among them."""
    d, n = cell.shape
    if n == 0:
        return cell.copy(), np.zeros(0, np.intp)
    lo, hi = cell.min(axis=1).astype(np.float64), cell.max(axis=1).astype(np.float64)
    span = hi - lo + 1
    if not (np.all(np.isfinite(span)) and np.prod(span) < 2.0 ** 53):
        u, inv = np.unique(cell, axis=1, return_inverse=True)
        return u, inv.reshape(-1)
    # the cells of the points' bounding box numbered row-major: one int64 key
    key = np.zeros(n, np.int64)
    for k in range(d):
        key *= int(span[k])
        key += cell[k].astype(np.int64)
        key -= int(lo[k])
    size = int(np.prod(span))
    if size <= max(4 * n, 1 << 16):     # a dense box: a table, no sort
        present = np.zeros(size, bool)
        present[key] = True
        ukey = np.flatnonzero(present)
        inv = np.take(np.cumsum(present) - 1, key)
    else:
        ukey, inv = np.unique(key, return_inverse=True)
    u = np.empty((d, ukey.size), F32)
    for k in reversed(range(d)):
        u[k] = ukey % int(span[k]) + lo[k]
        ukey = ukey // int(span[k])
    return u, inv.reshape(-1)


class _Lattice:
    """The distinct cells of N points, so that a hash of a cell's neighbour is
    taken once per distinct cell and gathered to the points."""

    def __init__(self, cell: np.ndarray):
        """cell (d, N) float32 integer-valued cell corners."""
        self.cells, self.inv = _unique_columns(cell)
        if self.cells.shape[0] > 1:
            # Cycles' int cell (make_int2/3/4 of the floored float); the
            # neighbours' corners are int sums (float sums in 1D)
            self.cells = self.cells.astype(np.int64)

    def _gather(self, v: np.ndarray) -> np.ndarray:
        """(k, N) the per-cell v (k, M) at each point (np.take: 4x v[:, inv])."""
        return np.take(v, self.inv, axis=1)

    def hashed(self, fn, off: np.ndarray) -> np.ndarray:
        """(k, N) float32 fn (cells (d, M) -> (k, M)) of each point's cell + off
        (d, 1) float32: Cycles' hash of ``cellPosition + cellOffset``."""
        return self._gather(fn(self.cells + off.astype(self.cells.dtype)))

    def point(self, off: np.ndarray, randomness: F32) -> np.ndarray:
        """(d, N) float32 the random point of the cell at off from each point's,
        relative to the point's cell: ``cellOffset + hash * randomness``
        (taken per distinct cell, then gathered)."""
        cells = self.cells + off.astype(self.cells.dtype)
        return self._gather(off + _point_hash(cells) * randomness)


def _distance(a: np.ndarray, b: np.ndarray, metric: str, exponent: F32,
              bound: bool = False) -> np.ndarray:
    """(N,) float32 Cycles' ``voronoi_distance`` of a and b (d, N) float32, or
    with bound ``voronoi_distance_bound`` (ordered as the distance: Euclidean
    squared, Minkowski without its root); 1D is always |a - b| (Cycles' float
    overload has no metric)."""
    diff = a - b
    if metric == "EUCLIDEAN" and diff.shape[0] > 1:
        sq = _sum(diff * diff)          # len_squared: no fabs needed
        return sq if bound else np.sqrt(sq)
    diff = np.abs(diff, out=diff)
    if diff.shape[0] == 1:
        return diff[0]
    if metric == "MANHATTAN":
        return _sum(diff)
    if metric == "CHEBYCHEV":
        return np.max(diff, axis=0)
    if metric == "MINKOWSKI":
        s = _sum(np.power(diff, exponent))
        return s if bound else np.power(s, F32(1) / exponent)
    raise ValueError(f"unknown Voronoi distance {metric!r}")


def _sum(v: np.ndarray) -> np.ndarray:
    """(N,) float32 the rows of v (d, N) summed in order (``reduce_add``, ``dot``)."""
    s = v[0].copy()
    for row in v[1:]:
        s += row
    return s


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return _sum(a * b)


def _mix(a, b, t):
    """Cycles' ``mix``: a + t (b - a), in the operands' float32."""
    return a + t * (b - a)


def _position4(pos: np.ndarray) -> np.ndarray:
    """(4, N) float32 Cycles' ``voronoi_position`` of pos (d, N) float32: 1D
    (0, 0, 0, w), 2D (x, y, 0, 0), 3D (x, y, z, 1) (``make_float4(float3)``),
    4D (x, y, z, w)."""
    d, n = pos.shape
    out = np.zeros((4, n), F32)
    if d == 1:
        out[3] = pos[0]
    else:
        out[:d] = pos
        if d == 3:
            out[3] = 1
    return out


# ------------------------------------------------------------- one octave

def _nearest(P: _Params, lat: _Lattice, local: np.ndarray, metric: str, second: bool,
             bound: bool = False):
    """Cycles' search of ``voronoi_f1`` / ``voronoi_f2`` over the 3^d cells
    around each point: (distance (N,) float32, offset index (N,) int) of the
    nearest point (second=False) or of the second nearest (second=True);
    indices into ``_offsets(d, 1)``; bound: searched by (and giving)
    ``voronoi_distance_bound``."""
    offs = _offsets(local.shape[0], 1)
    n = local.shape[1]
    centre = len(offs) // 2        # Cycles starts from the offset 0 ...
    d1 = np.full(n, FLT_MAX, F32)   # ... at FLT_MAX
    k1 = np.full(n, centre, np.int16)
    if second:
        d2, k2 = d1.copy(), k1.copy()
    for k, off in enumerate(offs):
        dist = _distance(lat.point(off, P.randomness), local, metric, P.exponent, bound)
        c1 = dist < d1
        if second:
            c2 = ~c1 & (dist < d2)
            np.copyto(d2, d1, where=c1)
            np.copyto(k2, k1, where=c1)
            np.copyto(d2, dist, where=c2)
            np.copyto(k2, np.int16(k), where=c2)
        np.copyto(d1, dist, where=c1)
        np.copyto(k1, np.int16(k), where=c1)
    return (d2, k2) if second else (d1, k1)


def _chosen(P: _Params, cell: np.ndarray, k: np.ndarray, colour: bool):
    """(point (d, N) float32 relative to the cell, colour (3, N) float32 or
    None) of the cell at offset index k from each point's cell (``targetOffset``)."""
    off = _offsets(cell.shape[0], 1)[k.astype(np.intp), :, 0].T
    lat = _Lattice(cell + off)
    zero = np.zeros((cell.shape[0], 1), F32)
    point = off + lat.hashed(_point_hash, zero) * P.randomness
    return point, (lat.hashed(_colour_hash, zero) if colour else None)


def _octave_f(P: _Params, coord: np.ndarray, want: set):
    """Cycles' ``voronoi_f1`` / ``voronoi_f2`` / ``voronoi_smooth_f1`` of one
    octave at coord (d, N) float32: (distance (N,), colour (3, N) or None,
    position (4, N) or None), float32."""
    cell = np.floor(coord)
    local = coord - cell
    lat = _Lattice(cell)
    if P.feature == "SMOOTH_F1" and P.smoothness != 0:
        return _smooth_f1(P, lat, cell, local, want)
    f2 = P.feature == "F2"
    # F1 searches by the bound and measures the point found (voronoi_f1)
    dist, k = _nearest(P, lat, local, P.metric, f2, bound=not f2)
    measure = not f2 and cell.shape[0] > 1
    if not (measure or want & {"Color", "Position", "W"}):
        return dist, None, None
    point, colour = _chosen(P, cell, k, "Color" in want)
    if measure:
        dist = _distance(point, local, P.metric, P.exponent)
    return dist, colour, _position4(point + cell) if want & {"Position", "W"} else None


def _smooth_f1(P: _Params, lat: _Lattice, cell, local, want: set):
    """Cycles' ``voronoi_smooth_f1``: the distances, colours and points of the
    5^d cells around each point blended one after another in Cycles' order,
    each weighted by a smoothstep of its lead over the running blend."""
    s = P.smoothness
    n = local.shape[1]
    dist = np.zeros(n, F32)
    colour = np.zeros((3, n), F32) if "Color" in want else None
    pos = np.zeros(local.shape, F32) if want & {"Position", "W"} else None
    for i, off in enumerate(_offsets(local.shape[0], 2)):
        point = lat.point(off, P.randomness)
        d = _distance(point, local, P.metric, P.exponent)
        if i == 0:
            h = np.ones(n, F32)
        else:   # smoothstep(0, 1, x)
            x = F32(0.5) + F32(0.5) * (dist - d) / s
            h = np.where(x < 0, F32(0), np.where(x >= 1, F32(1), (F32(3) - F32(2) * x) * (x * x)))
        correction = s * h * (F32(1) - h)
        dist = _mix(dist, d, h) - correction
        correction = correction / (F32(1) + F32(3) * s)
        if colour is not None:
            colour = _mix(colour, lat.hashed(_colour_hash, off), h) - correction
        if pos is not None:
            pos = _mix(pos, point, h) - correction
    return dist, colour, None if pos is None else _position4(cell + pos)


def _distance_to_edge(P: _Params, coord: np.ndarray) -> np.ndarray:
    """(N,) float32 Cycles' ``voronoi_distance_to_edge`` of one octave: the
    distance to the nearest bisector between the nearest point and another
    (1D: to the midpoints with the left and right neighbours)."""
    cell = np.floor(coord)
    local = coord - cell
    lat = _Lattice(cell)
    d = coord.shape[0]
    if d == 1:
        mid, left, right = (lat.point(np.full((1, 1), o, F32), P.randomness)[0]
                            for o in (0, -1, 1))
        return np.minimum(np.abs((mid + left) / F32(2) - local[0]),
                          np.abs((mid + right) / F32(2) - local[0]))
    offs = _offsets(d, 1)
    best = np.full(local.shape[1], FLT_MAX, F32)
    to_closest = np.zeros(local.shape, F32)
    for off in offs:
        v = lat.point(off, P.randomness) - local
        dd = _dot(v, v)
        closer = dd < best
        np.copyto(best, dd, where=closer)
        np.copyto(to_closest, v, where=closer[None])
    edge = np.full(local.shape[1], FLT_MAX, F32)
    for off in offs:
        v = lat.point(off, P.randomness) - local
        perp = v - to_closest
        pp = _dot(perp, perp)
        ok = pp > F32(0.0001)     # not the nearest point itself
        with np.errstate(divide="ignore", invalid="ignore"):
            e = _dot((to_closest + v) / F32(2), perp / np.sqrt(pp))
        np.copyto(edge, np.minimum(edge, e), where=ok)
    return edge


def _n_sphere_radius(P: _Params, coord: np.ndarray) -> np.ndarray:
    """(N,) float32 Cycles' ``voronoi_n_sphere_radius``: half the Euclidean
    distance from the nearest point to its own nearest point, searched over
    the 3^d cells around the nearest point's cell (both searches by the
    squared distance)."""
    cell = np.floor(coord)
    local = coord - cell
    d = coord.shape[0]
    _, k = _nearest(P, _Lattice(cell), local, "EUCLIDEAN", False, bound=True)
    closest, _ = _chosen(P, cell, k, False)
    closest_off = _offsets(d, 1)[k.astype(np.intp), :, 0].T
    # cellPosition + (offset + closestPointOffset) hashed as (cellPosition +
    # closestPointOffset) + offset: the same int sums below 2^24 (float ones in 1D)
    lat = _Lattice(cell + closest_off)
    best = np.full(local.shape[1], FLT_MAX, F32)
    nearest = np.zeros(local.shape, F32)
    for off in _offsets(d, 1):
        if not off.any():
            continue
        point = (off + closest_off) + lat.hashed(_point_hash, off) * P.randomness
        dist = _distance(closest, point, "EUCLIDEAN", P.exponent, bound=True)
        closer = dist < best
        np.copyto(best, dist, where=closer)
        np.copyto(nearest, point, where=closer[None])
    return _distance(nearest, closest, "EUCLIDEAN", P.exponent) / F32(2)


# ---------------------------------------------------------------- fractal

def _octaves(P: _Params):
    """Whether each octave Cycles runs (i = 0 .. ceilf(detail)) is whole
    (i <= detail), else the fractional last one."""
    for i in range(int(np.ceil(P.detail)) + 1):
        yield i <= P.detail


def _fractal_f(P: _Params, coord: np.ndarray, want: set):
    """Cycles' ``fractal_voronoi_x_fx``: (distance (N,), colour (3, N) or None,
    position (4, N) or None) float32 summed over the Detail octaves."""
    zero_input = P.detail == 0 or P.roughness == 0
    amplitude, max_amplitude, scale = F32(1), F32(0), F32(1)
    n = coord.shape[1]
    dist = np.zeros(n, F32)
    colour = np.zeros((3, n), F32) if "Color" in want else None
    pos = np.zeros((4, n), F32) if want & {"Position", "W"} else None
    remainder = P.detail - np.floor(P.detail)
    for whole in _octaves(P):
        od, oc, op = _octave_f(P, coord * scale, want)
        if zero_input:
            max_amplitude, dist, colour, pos = F32(1), od, oc, op
            break
        if whole:
            max_amplitude = max_amplitude + amplitude
            dist = dist + od * amplitude
            if colour is not None:
                colour = colour + oc * amplitude
            if pos is not None:
                pos = _mix(pos, op / scale, amplitude)
            scale = scale * P.lacunarity
            amplitude = amplitude * P.roughness
        elif remainder != 0:
            max_amplitude = _mix(max_amplitude, max_amplitude + amplitude, remainder)
            dist = _mix(dist, dist + od * amplitude, remainder)
            if colour is not None:
                colour = _mix(colour, colour + oc * amplitude, remainder)
            if pos is not None:
                pos = _mix(pos, _mix(pos, op / scale, amplitude), remainder)
    if P.normalize:
        dist = dist / (max_amplitude * P.max_distance)
        if colour is not None:
            colour = colour / max_amplitude
    if pos is not None:     # safe_divide(position, scale)
        pos = pos / P.scale if P.scale != 0 else np.zeros_like(pos)
    return dist, colour, pos


def _fractal_edge(P: _Params, coord: np.ndarray) -> np.ndarray:
    """(N,) float32 Cycles' ``fractal_voronoi_distance_to_edge``: the octaves'
    distances (over their scales) min-blended by amplitude."""
    zero_input = P.detail == 0 or P.roughness == 0
    amplitude, max_amplitude, scale = F32(1), P.max_distance, F32(1)
    dist = np.full(coord.shape[1], F32(8))
    remainder = P.detail - np.floor(P.detail)
    for whole in _octaves(P):
        od = _distance_to_edge(P, coord * scale)
        if zero_input:
            dist = od
            break
        if whole:
            max_amplitude = _mix(max_amplitude, P.max_distance / scale, amplitude)
            dist = _mix(dist, np.minimum(dist, od / scale), amplitude)
            scale = scale * P.lacunarity
            amplitude = amplitude * P.roughness
        elif remainder != 0:
            lerp_amplitude = _mix(max_amplitude, P.max_distance / scale, amplitude)
            max_amplitude = _mix(max_amplitude, lerp_amplitude, remainder)
            lerp_dist = _mix(dist, np.minimum(dist, od / scale), amplitude)
            dist = _mix(dist, np.minimum(dist, lerp_dist), remainder)
    if P.normalize:
        dist = dist / max_amplitude
    return dist


def _params(params: dict) -> _Params:
    g = lambda name: params.get(name, VORONOI_DEFAULTS[name])  # noqa: E731
    clamp = lambda x, lo, hi: F32(min(max(F32(x), F32(lo)), F32(hi)))  # noqa: E731
    return _Params(
        dims=_DIMS[g("voronoi_dimensions")], feature=g("feature"), metric=g("distance"),
        scale=F32(g("Scale")), detail=clamp(g("Detail"), 0, 15),
        roughness=clamp(g("Roughness"), 0, 1), lacunarity=F32(g("Lacunarity")),
        smoothness=clamp(F32(g("Smoothness")) / F32(2), 0, 0.5), exponent=F32(g("Exponent")),
        randomness=clamp(g("Randomness"), 0, 1), normalize=bool(g("normalize")))


def voronoi_texture(output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 output ``output`` (Distance, Color, Position, W, Radius) of
    Cycles' ``svm_node_tex_voronoi`` with ``params`` at p (N, 3) float64; an
    output the feature does not give is 0, as in Cycles.  ``params["W"]`` may
    be an (N,) array, a W input that varies over the points."""
    P = _params(params)
    p32 = np.asarray(p, F32).reshape(-1, 3).T * P.scale
    n = p32.shape[1]
    w = np.broadcast_to(np.asarray(params.get("W", VORONOI_DEFAULTS["W"]), F32), (n,))
    w = (w * P.scale)[None]
    coord = {1: w, 2: p32[:2], 3: p32, 4: np.vstack([p32, w])}[P.dims]
    zero = np.zeros(n, F32)
    m = F32(0.5) + F32(0.5) * P.randomness

    if P.feature == "DISTANCE_TO_EDGE":
        if output != "Distance":
            return _grey(zero)
        P.max_distance = m
        return _grey(_fractal_edge(P, coord))
    if P.feature == "N_SPHERE_RADIUS":
        return _grey(_n_sphere_radius(P, coord) if output == "Radius" else zero)
    if output == "Radius":
        return _grey(zero)

    # the largest distance of a point to its cell's point (twice it for F2)
    corner = np.full((P.dims, 1), m, F32)
    P.max_distance = _distance(np.zeros_like(corner), corner, P.metric, P.exponent)[0]
    if P.feature == "F2":
        P.max_distance = P.max_distance * F32(2)
    dist, colour, pos = _fractal_f(P, coord, {output})
    if output == "Distance":
        return _grey(dist)
    if output == "Color":
        return colour.T.astype(np.float64)
    if output == "Position":
        return pos[:3].T.astype(np.float64)
    if output == "W":
        return _grey(pos[3])
    raise ValueError(f"unknown Voronoi output {output!r}")
