"""A material's texture nodes as an expression (core/scene/shader_graph.py),
for the materials baked into atlases (addon/export_atlas.py).

:func:`expression` follows a socket upstream through the nodes FPPM can
evaluate at a point: texture coordinates, UV maps, Geometry position and
normal, colour attributes, Mapping, Image and procedural textures, Math,
Vector Math, Map Range, Clamp, Mix, Separate / Combine XYZ and Color, and
the colour nodes (Hue/Saturation/Value, Brightness/Contrast, Gamma, Invert,
RGB Curves, Color Ramp).  A node outside that set (or a colour node's factor
fed by a node) makes the socket's expression None: the caller notes that
the input is ignored.
"""
from __future__ import annotations

import numpy as np

from ..core.scene import procedural as PR
from ..core.scene import shader_graph as SG
from ..core.scene.shader_graph import COLOR, FLOAT, VEC, Attr, Const, Image, Op, Proc

#: Node types only the graph evaluates: a material using one is an atlas
#: material (every texture baked).
GRAPH_NODES = frozenset({'MATH', 'VECT_MATH', 'MAP_RANGE', 'CLAMP', 'SEPXYZ', 'COMBXYZ',
                         'SEPARATE_COLOR', 'COMBINE_COLOR', 'ATTRIBUTE', 'VERTEX_COLOR',
                         'NEW_GEOMETRY', 'OBJECT_INFO', 'VECTOR_ROTATE',
                         'CURVE_FLOAT', 'BLACKBODY', 'WAVELENGTH', 'CAMERA',
                         'VECT_TRANSFORM'})

#: The colour nodes' float inputs, by node type, in color_ops' order: a
#: node feeding one makes the op vary per point (an atlas material's).
PARAM_INPUTS = {'HUE_SAT': ("Hue", "Saturation", "Value", "Fac"),
                'BRIGHTCONTRAST': ("Bright", "Contrast"), 'GAMMA': ("Gamma",),
                'INVERT': ("Fac",), 'CURVE_RGB': ("Fac",)}


def linked_parameter(node) -> bool:
    """Whether a node feeds a colour node's float input (its Fac, Hue, ...)
    or a Mix node's factor: colour chains fold constant ones only."""
    names = PARAM_INPUTS.get(node.type, ())
    if node.type == 'MIX_RGB':
        names = ("Fac",)
    elif node.type == 'MIX':
        names = ("Factor",)
    return any(s.is_linked for s in node.inputs if s.name in names and s.enabled)


_KINDS = {'VALUE': FLOAT, 'INT': FLOAT, 'BOOLEAN': FLOAT, 'VECTOR': VEC, 'RGBA': COLOR}


def _const(sock):
    """A socket's own value as an expression (None for other types)."""
    kind = _KINDS.get(sock.type)
    v = getattr(sock, "default_value", None)
    if kind is None or v is None:
        return None
    if kind == FLOAT:
        return Const(float(v), FLOAT)
    return Const(tuple(float(x) for x in tuple(v)[:3]), kind)


class GraphReader:
    """Builds expressions for one material (``mb``, its _MaterialBuilder),
    sharing the expression of a node output read twice."""

    def __init__(self, mb, view: bool = False):
        self.mb = mb
        self.memo: dict = {}
        # view: Fresnel and Layer Weight read the view (SG.VIEW_COS), for a
        # Mix Shader's Fac; elsewhere they are no expression (as before).
        self.view = view

    def expression(self, sock, depth: int = 0):
        """The expression of what ``sock`` receives, or None."""
        if depth > 128:
            return None
        node, out, vsock = self.mb.follow(sock)
        if node is None:
            return _const(vsock)
        key = (node.as_pointer(), out.identifier,
               tuple(n.as_pointer() for n in self.mb.ctx.get(node.as_pointer(), ())))
        if key not in self.memo:
            self.memo[key] = fold(self._node(node, out, depth + 1))
        return self.memo[key]

    def _in(self, node, ident, depth, kind=None):
        """The expression of input ``ident`` (identifier, else name) as kind."""
        sock = next((s for s in node.inputs if s.identifier == ident), None) \
            or next((s for s in node.inputs if s.name == ident), None)
        if sock is None:
            return None
        e = self.expression(sock, depth)
        if e is None or kind is None:
            return e
        return SG.as_float(e) if kind == FLOAT else SG.as_vector(e, kind)

    def _const_in(self, node, ident):
        """A constant float input's value (None when a node feeds it)."""
        sock = next((s for s in node.inputs if s.identifier == ident), None)
        if sock is None:
            return None
        e = self.expression(sock)
        return None if e is None or not isinstance(e, Const) else float(
            SG.as_float(e).value)

    def _vector(self, node, depth, default):
        sock = node.inputs.get("Vector")
        if sock is None or not sock.is_linked:
            return Attr(default)
        return self._in(node, "Vector", depth, VEC)

    def _node(self, node, out, depth):
        t, name = node.type, out.name
        mb = self.mb
        if node.mute:
            # A muted node passes its internal link's input on (Cycles' bypass),
            # else gives zero.
            links = [lk for lk in node.internal_links if lk.to_socket == out]
            if not links:
                return Const(0.0, FLOAT)
            e = self.expression(links[0].from_socket, depth)
            kind = _KINDS.get(out.type, FLOAT)
            return None if e is None else (SG.as_float(e) if kind == FLOAT
                                           else SG.as_vector(e, kind))
        if t == 'VALUE':
            return Const(float(out.default_value), FLOAT)
        if t == 'RGB':
            return Const(tuple(float(x) for x in tuple(out.default_value)[:3]), COLOR)
        if t == 'TEX_COORD':
            ob = node.object.name if node.object is not None else None
            key = {'Generated': ('Generated',), 'Object': ('Object', ob), 'UV': ('UV', None),
                   'Normal': ('ObjectNormal',), 'Camera': ('Camera',)}.get(name)
            if name == 'Window':
                # A projection of the camera-space point, per point: the
                # point interpolates over a triangle, its projection does not.
                cam = mb.ex.camera_model
                return None if cam is None else Op("window", (Attr(('Camera',)),),
                                                   cam.window_params, VEC)
            return None if key is None else Attr(key)
        if t == 'VECT_TRANSFORM':
            cam = mb.ex.camera_model
            v = self._in(node, "Vector", depth, VEC)
            if v is None or cam is None:
                return None
            axes = tuple(Attr(('ObjectAxis', i)) for i in range(3))
            return Op("vector_transform", (v,) + axes + (Attr(('ObjectInfo', 'Location')),),
                      (node.vector_type, node.convert_from, node.convert_to,
                       tuple(float(x) for x in cam.cycles_axes.ravel()),
                       tuple(float(x) for x in cam.origin)), VEC)
        if t == 'CAMERA':
            # Cycles' svm_node_camera: the camera-space point's direction,
            # its z (depth along the view) and its length.
            p = Attr(('Camera',))
            zero, one = Const((0.0, 0.0, 0.0), VEC), Const(1.0, FLOAT)
            if name == 'View Z Depth':
                return Op("separate", (p,), ("XYZ", 2), FLOAT)
            op = {'View Vector': ('NORMALIZE', 'Vector'),
                  'View Distance': ('LENGTH', 'Value')}.get(name)
            return None if op is None else Op("vector_math", (p, zero, zero, one), op,
                                              VEC if op[1] == 'Vector' else FLOAT)
        if t == 'UVMAP':
            return Attr(('UV', node.uv_map or None))
        if t == 'OBJECT_INFO':
            if name == 'Material Index':
                return Const(float(getattr(mb.mat, "pass_index", 0)), FLOAT)
            kind = {'Location': VEC, 'Color': COLOR, 'Alpha': FLOAT, 'Object Index': FLOAT,
                    'Random': FLOAT}.get(name)
            return None if kind is None else Attr(('ObjectInfo', name), kind)
        if t in ('FRESNEL', 'LAYER_WEIGHT') and self.view:
            # On the material's shading normal: a linked Normal (a Normal Map
            # or Bump) joins the shaders' (the material takes one; another
            # is noted as for the shaders).
            if mb.follow(node.inputs["Normal"])[0] is not None:
                mb.normals.append((node.name, mb.normal_input(node)))
            mu = Attr(SG.VIEW_COS, FLOAT)
            if t == 'FRESNEL':
                ior = self._in(node, "IOR", depth, FLOAT)
                return None if ior is None else Op("fresnel", (mu, ior), (), FLOAT)
            blend = self._in(node, "Blend", depth, FLOAT)
            if blend is None or name not in ("Fresnel", "Facing"):
                return None
            return Op("layer_weight", (mu, blend), (name,), FLOAT)
        if t == 'NEW_GEOMETRY':
            key = {'Position': ('Position',), 'Normal': ('Normal',),
                   'True Normal': ('TrueNormal',), 'Pointiness': ('Pointiness',),
                   'Random Per Island': ('RandomPerIsland',)}.get(name)
            return None if key is None else Attr(key, VEC if key[0] in (
                'Position', 'Normal', 'TrueNormal') else FLOAT)
        if t == 'RGBTOBW':
            c = self._in(node, "Color", depth, COLOR)
            return None if c is None else SG.as_float(c)
        if t == 'VECTOR_ROTATE':
            args = (self._in(node, "Vector", depth, VEC), self._in(node, "Center", depth, VEC),
                    self._in(node, "Axis", depth, VEC), self._in(node, "Angle", depth, FLOAT),
                    self._in(node, "Rotation", depth, VEC))
            return None if None in args else Op(
                "vector_rotate", args, (node.rotation_type, bool(node.invert)), VEC)
        if t == 'CURVE_FLOAT':
            from .export import float_curve_params
            args = (self._in(node, "Factor", depth, FLOAT), self._in(node, "Value", depth, FLOAT))
            return None if None in args else Op("float_curve", args, float_curve_params(node),
                                                FLOAT)
        if t == 'VALTORGB' and name == 'Alpha':
            from .export import ramp_alpha_params
            f = self._in(node, "Fac", depth, FLOAT)
            return None if f is None else Op("ramp_alpha", (f,), ramp_alpha_params(node), FLOAT)
        if t in ('BLACKBODY', 'WAVELENGTH'):
            x = self._in(node, "Temperature" if t == 'BLACKBODY' else "Wavelength", depth, FLOAT)
            return None if x is None else Op(t.lower(), (x,), (), COLOR)
        if t == 'ATTRIBUTE' and node.attribute_type in ('OBJECT', 'VIEW_LAYER'):
            # One value an object (its custom property or RNA path, then its
            # data's), or one for the whole render (the view layer's, the
            # scene's, the world's): (r, g, b, a), zero when none is found.
            from .export import id_attribute
            n = node.attribute_name
            if node.attribute_type == 'VIEW_LAYER':
                sc = mb.ex.scene
                v = id_attribute((mb.ex.dg.view_layer, sc, sc.world), n)
                rgb = Const(tuple(float(x) for x in v[:3]), COLOR)
                return {'Color': rgb, 'Vector': SG.as_vector(rgb, VEC),
                        'Fac': SG.as_float(SG.as_vector(rgb, VEC)),
                        'Alpha': Const(float(v[3]), FLOAT)}.get(out.identifier)
            key = ('ObjectAttr', n)
            return {'Color': Attr(key, COLOR), 'Vector': Attr(key, VEC),
                    'Fac': SG.as_float(Attr(key, VEC)),
                    'Alpha': Attr(('ObjectAttrAlpha', n), FLOAT)}.get(out.identifier)
        if t in ('ATTRIBUTE', 'VERTEX_COLOR'):
            if t == 'ATTRIBUTE' and node.attribute_type != 'GEOMETRY':
                return None
            key = ('Attribute', (node.attribute_name if t == 'ATTRIBUTE'
                                 else node.layer_name) or None)
            if name in ('Color', 'Vector'):
                return Attr(key, COLOR if name == 'Color' else VEC)
            # Cycles' svm_node_attr: a Fac of a vector attribute is its mean
            # (the output Blender 5 names Factor, identifier Fac).
            return SG.as_float(Attr(key, VEC)) if out.identifier == 'Fac' else None
        if t == 'MAPPING':
            from .export import _mapping_matrix
            v = self._in(node, "Vector", depth, VEC)
            if v is None:
                return None
            A = _mapping_matrix(node, mb.notes)
            return Op("mapping", (v,), (tuple(A.ravel()), node.vector_type == 'NORMAL'), VEC)
        if t == 'TEX_IMAGE':
            if name not in ('Color', 'Alpha'):
                return None
            # A UDIM image's first tile stands for it (its density, its
            # pixels' digest); Image.pixels would read that tile again.
            tiles = mb.ex.udim_tiles(node, mb)
            tex = tiles[0][1] if tiles else mb.ex.texture(node, mb)
            if tex < 0:
                return None
            proj = getattr(node, "projection", 'FLAT')
            return Image(tex, name, self._vector(node, depth, ('UV', None)), proj,
                         float(getattr(node, "projection_blend", 0.0)),
                         Attr(('ObjectNormal',)) if proj == 'BOX' else None, tiles)
        if t in PR.KINDS:
            return self._procedural(node, name, depth)
        if t == 'MATH':
            args = tuple(self._in(node, i, depth, FLOAT)
                         for i in ("Value", "Value_001", "Value_002"))
            return None if None in args else Op(
                "math", args, (node.operation, bool(node.use_clamp)), FLOAT)
        if t == 'VECT_MATH':
            args = tuple(self._in(node, i, depth, VEC)
                         for i in ("Vector", "Vector_001", "Vector_002"))
            args += (self._in(node, "Scale", depth, FLOAT),)
            return None if None in args else Op(
                "vector_math", args, (node.operation, name), FLOAT if name == 'Value' else VEC)
        if t == 'MAP_RANGE':
            vec = node.data_type == 'FLOAT_VECTOR'
            ids = (("Vector", "From_Min_FLOAT3", "From_Max_FLOAT3", "To_Min_FLOAT3",
                    "To_Max_FLOAT3", "Steps_FLOAT3") if vec else
                   ("Value", "From Min", "From Max", "To Min", "To Max", "Steps"))
            args = tuple(self._in(node, i, depth, VEC if vec else FLOAT) for i in ids)
            return None if None in args else Op(
                "map_range", args, (node.data_type, node.interpolation_type,
                                    bool(node.clamp)), VEC if vec else FLOAT)
        if t == 'CLAMP':
            args = tuple(self._in(node, i, depth, FLOAT) for i in ("Value", "Min", "Max"))
            return None if None in args else Op("clamp", args, (node.clamp_type,), FLOAT)
        if t in ('MIX', 'MIX_RGB'):
            return self._mix(node, out, depth)
        if t == 'SEPXYZ':
            v = self._in(node, "Vector", depth, VEC)
            return None if v is None else Op("separate", (v,), ("XYZ", "XYZ".index(name)), FLOAT)
        if t == 'COMBXYZ':
            args = tuple(self._in(node, i, depth, FLOAT) for i in ("X", "Y", "Z"))
            return None if None in args else Op("combine", args, ("XYZ",), VEC)
        if t == 'SEPARATE_COLOR':
            c = self._in(node, "Color", depth, COLOR)
            i = [o.identifier for o in node.outputs].index(out.identifier)
            return None if c is None else Op("separate", (c,), (node.mode, i), FLOAT)
        if t == 'COMBINE_COLOR':
            args = tuple(self._in(node, s.identifier, depth, FLOAT) for s in node.inputs)
            return None if None in args else Op("combine", args, (node.mode,), COLOR)
        return self._color_node(node, out, depth)

    def _procedural(self, node, name, depth):
        from .export_atlas import procedural_params
        if not PR.supported(node.type, name):
            return None
        w_sock = node.inputs.get("W")
        w = None
        if w_sock is not None and w_sock.is_linked:
            w = self._in(node, "W", depth, FLOAT)
            if w is None:
                return None
        params = procedural_params(node, self.mb.follow, self.mb.notes, skip=("W",) if w else ())
        return Proc(node.type, name, tuple(sorted(params.items())),
                    self._vector(node, depth, ('Generated',)), w)

    def _mix(self, node, out, depth):
        if node.type == 'MIX_RGB':
            args = (self._in(node, "Fac", depth, FLOAT), self._in(node, "Color1", depth, COLOR),
                    self._in(node, "Color2", depth, COLOR))
            params = (node.blend_type, True, bool(node.use_clamp))
            return None if None in args else Op("mix_color", args, params, COLOR)
        dt = node.data_type
        if dt == 'RGBA':
            args = (self._in(node, "Factor_Float", depth, FLOAT),
                    self._in(node, "A_Color", depth, COLOR),
                    self._in(node, "B_Color", depth, COLOR))
            params = (node.blend_type, bool(node.clamp_factor), bool(node.clamp_result))
            return None if None in args else Op("mix_color", args, params, COLOR)
        if dt == 'FLOAT':
            args = tuple(self._in(node, i, depth, FLOAT) for i in ("Factor_Float", "A_Float",
                                                                   "B_Float"))
            return None if None in args else Op("mix_float", args, (bool(node.clamp_factor),),
                                                FLOAT)
        if dt == 'VECTOR':
            uniform = getattr(node, "factor_mode", 'UNIFORM') == 'UNIFORM'
            f = self._in(node, "Factor_Float" if uniform else "Factor_Vector", depth,
                         FLOAT if uniform else VEC)
            args = (f, self._in(node, "A_Vector", depth, VEC), self._in(node, "B_Vector", depth,
                                                                      VEC))
            return None if None in args else Op("mix_vector", args, (bool(node.clamp_factor),),
                                                VEC)
        return None

    def _color_node(self, node, out, depth):
        """The colour nodes of core/scene/color_ops.py: an op with constant
        factors, else (a factor a node feeds) the op per point."""
        from .export import curves_op, ramp_op
        t = node.type
        if t in PARAM_INPUTS and not all(self._const_in(node, i) is not None
                                         for i in PARAM_INPUTS[t]):
            args = tuple(self._in(node, i, depth, COLOR if i == "Color" else FLOAT)
                         for i in ("Color",) + PARAM_INPUTS[t])
            params = (t,) + (curves_op(node, 1.0)[1:5] if t == 'CURVE_RGB' else ())
            return None if None in args else Op("color_at", args, params, COLOR)
        k = self._const_in
        op, src = None, "Color"
        if t == 'HUE_SAT':
            p = [k(node, i) for i in ("Hue", "Saturation", "Value", "Fac")]
            op = None if None in p else ("hsv", *p)
        elif t == 'BRIGHTCONTRAST':
            p = [k(node, i) for i in ("Bright", "Contrast")]
            op = None if None in p else ("bright", *p)
        elif t == 'GAMMA':
            g = k(node, "Gamma")
            op = None if g is None else ("gamma", g)
        elif t == 'INVERT':
            f = k(node, "Fac")
            op = None if f is None else ("invert", f)
        elif t == 'CURVE_RGB':
            f = k(node, "Fac")
            op = None if f is None else curves_op(node, f)
        elif t == 'VALTORGB' and out.name == 'Color':
            op, src = ramp_op(node), "Fac"
        if op is None:
            return None
        c = self._in(node, src, depth, COLOR)
        return None if c is None else Op("color_op", (c,), op, COLOR)


def fold(e):
    """e with an operation of constants replaced by its constant value."""
    if not isinstance(e, Op) or not all(isinstance(a, Const) for a in e.args):
        return e
    v = SG.evaluate(e, SG.EvalContext({}, []))[0]
    return Const(float(v) if e.kind == FLOAT else tuple(float(x) for x in v), e.kind)


def constant_value(e, kind: str = FLOAT):
    """A constant expression's value as a float (kind FLOAT) or an rgb
    (3,) array, else None."""
    if not isinstance(e, Const):
        return None
    if kind == FLOAT:
        return float(SG.as_float(e).value)
    return np.asarray(SG.as_vector(e, COLOR).value, np.float64)
