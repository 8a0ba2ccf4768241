"""A material's texture graph as an expression, evaluated at many surface
points at once (numpy): what an atlas material's bake computes at each
texel (addon/export_atlas.py, core/scene/atlas.py).

An expression is a tree of small frozen nodes, each of one of three kinds,
as Cycles' sockets: 'float' (K,), 'vec' (K, 3) and 'color' (K, 3):

- :class:`Const`: a socket's value;
- :class:`Attr`: a surface attribute interpolated over the triangle (UV
  maps, Generated and Object coordinates, position, normals, colour
  attributes), the corner values given by the exporter;
- :class:`Image`: an Image Texture's Color or Alpha at a vector;
- :class:`Proc`: a procedural texture's output at a vector
  (core/scene/procedural.py);
- :class:`Op`: a converter or colour node on its inputs (Math, Vector Math,
  Map Range, Clamp, Mix, Separate / Combine, Mapping, Vector Rotate, Float
  Curve, a Color Ramp's Alpha, Blackbody, Wavelength, the colour nodes of
  core/scene/color_ops.py), or a socket-type conversion.

Conversions follow Cycles' ``svm_node_convert`` (core/scene/node_math.py
``to_float``, ``to_vec``): a colour read as a float is its luminance, a
vector read as a float the mean of its components, a float read as a colour
or vector (f, f, f).

:func:`evaluate` takes an :class:`EvalContext`: the attribute arrays at the
points and the exporter's textures.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..mathutil import unit_rows
from . import color_ops as CO
from . import node_math as NM
from . import procedural as PR
from .. import spectrum as SP
from .camera import window
from .textures import sample_alpha, sample_texture

FLOAT, VEC, COLOR = "float", "vec", "color"

#: The Attr key of |w_o . n_s| at a shading point, which only a Mix Shader's
#: Fac reads (addon/export.py ``_MaterialBuilder.view_fac``: sampled into
#: ``Lobe.view``; an atlas bake never sees it).
VIEW_COS = ("ViewCos",)


@dataclass(frozen=True, eq=False)
class Const:
    """A constant: a float, or an (x, y, z) tuple for 'vec' and 'color'."""
    value: object
    kind: str


@dataclass(frozen=True, eq=False)
class Attr:
    """A surface attribute, 'vec', 'color' or 'float' (its first component):
    key ('UV', map name or None), ('Generated',), ('Object', object name or
    None), ('Position',), ('Normal',), ('ObjectNormal',), ('Attribute',
    name or None: the render colour attribute), ('ObjectInfo', output) (an
    Object Info node's Location, Color, Alpha, Object Index or Random: one
    value an object), ('TrueNormal',) (the Geometry node's: the face's
    normal), ('Pointiness',) and ('RandomPerIsland',) (the Geometry node's,
    computed from the mesh as Cycles does: core/scene/mesh_attributes.py),
    ('Camera',) (the point in Cycles' camera space: x right, y up, z along
    the view; the "window" op projects it onto the frame), ('ObjectAxis',
    i) (the object's i-th axis in the world: its matrix's column i)."""
    key: tuple
    kind: str = VEC


@dataclass(frozen=True, eq=False)
class Image:
    """An Image Texture: ``texture`` indexes the exporter's textures (the
    image as its Color output reads it, core/scene/textures.py), read at
    ``vector`` through its ``projection`` ('FLAT': x, y; 'SPHERE', 'TUBE',
    or 'BOX' blended by ``blend`` over the object-space ``normal``
    expression, :func:`image_projection`); output 'Color' or 'Alpha'.
    ``tiles``: a UDIM image's ((tile number, texture index), ...), each
    tile read over its own unit square of uv (:func:`udim_sample`);
    ``texture`` is then its first tile's."""
    texture: int
    output: str
    vector: object
    projection: str = "FLAT"
    blend: float = 0.0
    normal: object = None
    tiles: tuple = ()

    @property
    def kind(self) -> str:
        return COLOR if self.output == "Color" else FLOAT


@dataclass(frozen=True, eq=False)
class Proc:
    """A procedural texture's ``output`` at ``vector`` (params as
    core/scene/procedural.py reads them; ``w`` an expression for a linked W
    input, or None)."""
    node_kind: str
    output: str
    params: tuple
    vector: object
    w: object = None

    @property
    def kind(self) -> str:
        return COLOR if self.output in ("Color",) else (
            VEC if self.output == "Position" else FLOAT)


@dataclass(frozen=True, eq=False)
class Op:
    """An operation ``name`` on ``args`` (expressions) with constant
    ``params``, giving ``kind``."""
    name: str
    args: tuple
    params: tuple
    kind: str


class EvalContext(NamedTuple):
    """attrs: {Attr key: (K, 3) float64 at the points}; textures: the
    exporter's list of images."""
    attrs: dict
    textures: list


# -- conversions ---------------------------------------------------------------

def as_float(e):
    """e read by a float socket."""
    if e.kind == FLOAT:
        return e
    if isinstance(e, Const):
        return Const(float(NM.to_float(np.asarray(e.value, np.float64), _SOCKET[e.kind])),
                     FLOAT)
    return Op("to_float", (e,), (e.kind,), FLOAT)


def as_vector(e, kind: str = VEC):
    """e read by a vector (or colour, kind=COLOR) socket."""
    if e.kind == kind or e.kind != FLOAT and kind != FLOAT:
        return e if e.kind == kind else Op("retype", (e,), (), kind)
    if isinstance(e, Const):
        return Const((float(e.value),) * 3, kind)
    return Op("splat", (e,), (), kind)


def constant(e):
    """The value of a constant expression, else None."""
    return e.value if isinstance(e, Const) else None


def walk(e):
    """Every expression in e's tree, e first."""
    yield e
    for a in _children(e):
        yield from walk(a)


def _children(e):
    if isinstance(e, (Image, Proc)):
        return tuple(x for x in (e.vector, getattr(e, "w", None), getattr(e, "normal", None))
                     if x is not None)
    if isinstance(e, Op):
        return e.args
    return ()


def attributes(e) -> set:
    """The attribute keys e reads."""
    return {x.key for x in walk(e) if isinstance(x, Attr)}


# -- evaluation ------------------------------------------------------------------

def evaluate(e, ctx: EvalContext, memo: dict | None = None) -> np.ndarray:
    """(K,) or (K, 3) float64: e at the context's points."""
    memo = {} if memo is None else memo
    got = memo.get(id(e))
    if got is not None:
        return got
    out = _evaluate(e, ctx, memo)
    memo[id(e)] = out
    return out


def _points(ctx: EvalContext) -> int:
    return len(next(iter(ctx.attrs.values()))) if ctx.attrs else 1


def _evaluate(e, ctx, memo):
    K = _points(ctx)
    if isinstance(e, Const):
        v = np.asarray(e.value, np.float64)
        return np.broadcast_to(v, (K,) + v.shape).copy()
    if isinstance(e, Attr):
        a = ctx.attrs[e.key]
        if e.key[0] in ("Normal", "ObjectNormal", "TrueNormal"):
            a = unit_rows(a)
        return a[:, 0] if e.kind == FLOAT else a
    if isinstance(e, Image):
        img = ctx.textures[e.texture]
        co = evaluate(e.vector, ctx, memo)
        n = evaluate(e.normal, ctx, memo) if e.normal is not None else None
        looks = image_projection(e.projection, co, n, e.blend)
        out = 0.0
        for w, uv in looks:
            if e.tiles:
                c = udim_sample(ctx.textures, e.tiles, uv, e.output)
            else:
                c = sample_texture(img, uv) if e.output == "Color" else sample_alpha(img, uv)
            out = out + (np.asarray(w)[..., None] * c if c.ndim == 2 else w * c)
        return out
    if isinstance(e, Proc):
        params = dict(e.params)
        if e.w is not None:
            params["W"] = evaluate(e.w, ctx, memo)
        out = PR.evaluate(e.node_kind, e.output, params, evaluate(e.vector, ctx, memo))
        return out[:, 0] if e.kind == FLOAT else out
    args = [evaluate(a, ctx, memo) for a in e.args]
    return OPS[e.name](args, e.params)


#: What Cycles reads where a UDIM image has no tile: IMAGE_MISSING_RGBA.
UDIM_MISSING = (1.0, 0.0, 1.0, 1.0)


def udim_sample(textures, tiles, uv, output: str) -> np.ndarray:
    """(K, 3) colour or (K,) alpha of a UDIM image at uv (K, 2): Cycles'
    ``kernel_image_udim_map``: the tile 1001 + 10 ty + tx of tx, ty the uv's
    integer parts (truncated; u from 0 to 10, v from 0), read at uv - (tx,
    ty); :data:`UDIM_MISSING` where the image has no such tile."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    t = np.trunc(uv).astype(np.int64)
    number = np.where((t[:, 0] >= 0) & (t[:, 1] >= 0) & (t[:, 0] < 10),
                      1001 + 10 * t[:, 1] + t[:, 0], -1)
    colour = output == "Color"
    out = (np.tile(UDIM_MISSING[:3], (len(uv), 1)) if colour
           else np.full(len(uv), UDIM_MISSING[3]))
    for n, index in tiles:
        m = number == n
        if m.any():
            local = uv[m] - t[m]
            out[m] = (sample_texture(textures[index], local) if colour
                      else sample_alpha(textures[index], local))
    return out


#: Expression kinds as node_math's socket kinds.
_SOCKET = {FLOAT: "VALUE", VEC: "VECTOR", COLOR: "RGBA"}


def _remap_square(co):
    """Cycles' texco_remap_square: 0..1 to -1..1."""
    return (co - 0.5) * 2.0


def _map_to_tube(co):
    """Cycles' map_to_tube (util/math): u the angle about z, v the height."""
    x, y, z = co[:, 0], co[:, 1], co[:, 2]
    ln = np.sqrt(x * x + y * y)
    safe = np.where(ln > 0.0, ln, 1.0)
    u = np.where(ln > 0.0, (1.0 - np.arctan2(x / safe, y / safe) / np.pi) * 0.5, 0.0)
    v = np.where(ln > 0.0, (z + 1.0) * 0.5, 0.0)
    return np.stack([u, v], 1)


def _map_to_sphere(co):
    """Cycles' map_to_sphere: u the angle about z, v the polar angle."""
    x, y, z = co[:, 0], co[:, 1], co[:, 2]
    ll = x * x + y * y + z * z
    on = ll > 0.0
    u = np.where(on & ~((x == 0.0) & (y == 0.0)), 0.5 - np.arctan2(x, y) / (2.0 * np.pi), 0.0)
    cz = np.clip(z / np.sqrt(np.where(on, ll, 1.0)), -1.0, 1.0)
    v = np.where(on, 1.0 - np.arccos(cz) / np.pi, 0.0)
    return np.stack([u, v], 1)


def _box_weights(n, blend: float):
    """(K, 3) Cycles' svm_node_tex_image_box weights of the three axis
    projections for object-space normals n (K, 3): one texture near each
    axis, two or three blended between, by ``blend``."""
    a = np.abs(n)
    a = a / np.maximum(a.sum(axis=1, keepdims=True), 1e-30)
    x, y, z = a[:, 0], a[:, 1], a[:, 2]
    limit = 0.5 * (1.0 + blend)
    w = np.zeros_like(a)
    cx = (x > limit * (x + y)) & (x > limit * (x + z))
    cy = ~cx & (y > limit * (x + y)) & (y > limit * (y + z))
    cz = ~cx & ~cy & (z > limit * (x + z)) & (z > limit * (y + z))
    rest = ~(cx | cy | cz)
    w[cx, 0], w[cy, 1], w[cz, 2] = 1.0, 1.0, 1.0
    if blend > 0.0:
        with np.errstate(all='ignore'):
            xy = rest & (z < (1.0 - limit) * (y + x))
            yz = rest & ~xy & (x < (1.0 - limit) * (y + z))
            xz = rest & ~xy & ~yz & (y < (1.0 - limit) * (x + z))
            three = rest & ~xy & ~yz & ~xz

            def two(m, i, j):
                t = np.clip((a[m, i] / (a[m, i] + a[m, j]) - 0.5 * (1.0 - blend)) / blend,
                            0.0, 1.0)
                w[m, i], w[m, j] = t, 1.0 - t
            two(xy, 0, 1)
            two(yz, 1, 2)
            two(xz, 0, 2)
            w[three] = ((2.0 - limit) * a[three] + (limit - 1.0)) / (2.0 * limit - 1.0)
    else:
        w[rest, 0] = 1.0             # Cycles' "desperate mode": one side
    return w


def image_projection(projection: str, co, n=None, blend: float = 0.0) -> list:
    """[(weight (K,) or 1.0, uv (K, 2))]: where an Image Texture of
    ``projection`` reads at texture vectors co (K, 3) (Cycles'
    svm_node_tex_image_mapping and svm_node_tex_image_box: each box face
    mapped so that none is mirrored)."""
    if projection == "SPHERE":
        return [(1.0, _map_to_sphere(_remap_square(co)))]
    if projection == "TUBE":
        return [(1.0, _map_to_tube(_remap_square(co)))]
    if projection != "BOX":
        return [(1.0, co[:, :2])]
    w = _box_weights(n, blend)
    x, y, z = co[:, 0], co[:, 1], co[:, 2]
    faces = [np.stack([np.where(n[:, 0] < 0.0, 1.0 - y, y), z], 1),
             np.stack([np.where(n[:, 1] > 0.0, 1.0 - x, x), z], 1),
             np.stack([np.where(n[:, 2] > 0.0, 1.0 - y, y), x], 1)]
    return [(w[:, i], faces[i]) for i in range(3)]


def _to_float(args, params):
    (x,), (kind,) = args, params
    return NM.to_float(x, _SOCKET[kind])


def _mapping(args, params):
    """Mapping: v A^T + t; NORMAL type renormalised (Cycles' svm_mapping)."""
    (v,), (A, normal) = args, params
    A = np.asarray(A, np.float64).reshape(4, 4)
    out = v @ A[:3, :3].T + A[:3, 3]
    if normal:
        out = unit_rows(out)
    return out


def _color_op(args, params):
    """A colour node of core/scene/color_ops.py (its op tuple)."""
    return CO.apply((params,), args[0])


#: A colour node's color_ops op, by node type.
_COLOR_OPS = {"HUE_SAT": "hsv", "BRIGHTCONTRAST": "bright", "GAMMA": "gamma",
              "INVERT": "invert", "CURVE_RGB": "curves"}


def _color_at(args, params):
    """A colour node with per-point factors (K,): Hue/Saturation/Value, Bright
    Contrast, Gamma, Invert, RGB Curves (params: its type, and a curves'
    table, min_x, range_x, extrapolate), the constant ops' color_ops.apply
    with a factor a point: hue, saturation and value as rows (K,), the
    factors that scale a colour as columns (K, 1)."""
    c, *p = args
    kind = params[0]
    rows = 3 if kind == "HUE_SAT" else 0         # hsv's hue, saturation, value
    p = [x if i < rows else x[:, None] for i, x in enumerate(p)]
    if kind == "CURVE_RGB":
        p = list(params[1:]) + p
    return CO.apply(((_COLOR_OPS[kind], *p),), c)


def _mix_color(args, params):
    """Mix (RGBA) / MixRGB with a per-point factor: svm_mix per point."""
    t, a, b = args
    blend, clamp_factor, clamp_result = params
    if clamp_factor:
        t = np.clip(t, 0.0, 1.0)
    out = CO.mix(blend, t[:, None], a, b)
    return np.clip(out, 0.0, 1.0) if clamp_result else out


def _math(args, params):
    op, clamp = params
    out = NM.math(op, *args)
    return np.clip(out, 0.0, 1.0) if clamp else out


def _vector_math(args, params):
    op, output = params
    vec, val = NM.vector_math(op, *args)
    return val if output == "Value" else vec


def _map_range(args, params):
    data_type, interpolation, clamp = params
    f = NM.map_range_vector if data_type == "FLOAT_VECTOR" else NM.map_range
    return f(interpolation, *args, clamp)


def _separate(args, params):
    mode, i = params
    c = args[0] if mode in (None, "XYZ") else NM.separate_color(mode, args[0])
    return c[:, i]


def _combine(args, params):
    (mode,) = params
    x, y, z = args
    v = np.stack([x, y, z], axis=1)
    return v if mode in (None, "XYZ") else NM.combine_color(mode, x, y, z)


#: Op name -> f(evaluated args, params).
OPS = {
    "to_float": _to_float,
    "retype": lambda args, params: args[0],
    "splat": lambda args, params: NM.to_vec(args[0]),
    "mapping": _mapping,
    "color_op": _color_op,
    "color_at": _color_at,
    "mix_color": _mix_color,
    "mix_float": lambda args, params: NM.mix_float(*args, *params),
    "mix_vector": lambda args, params: NM.mix_vector(*args, *params),
    "math": _math,
    "vector_math": _vector_math,
    "map_range": _map_range,
    "clamp": lambda args, params: NM.clamp(params[0], *args),
    "separate": _separate,
    "combine": _combine,
    "vector_rotate": lambda args, params: NM.vector_rotate(*params, *args),
    "float_curve": lambda args, params: NM.float_curve(*args, *params),
    "ramp_alpha": lambda args, params: NM.ramp_alpha(*args, *params),
    "blackbody": lambda args, params: np.maximum(SP.blackbody_rec709(args[0]), 0.0),
    "wavelength": lambda args, params: SP.wavelength_rec709(args[0]),
    "window": lambda args, params: window(args[0], *params),
    "vector_transform": lambda args, params: NM.vector_transform(
        *params[:3], args[0], np.stack(args[1:4], -1), args[4],
        (np.asarray(params[3]).reshape(3, 3), params[4])),
    # the view-dependent inputs, of Attr VIEW_COS (the Mix Shader Fac's LUT)
    "fresnel": lambda args, params: NM.fresnel(*args),
    "layer_weight": lambda args, params: NM.layer_weight(*args, *params),
}
