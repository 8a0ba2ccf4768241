"""The export's reads as single Blender calls (the reader before cancel was cut
into bands, addon/export_read.py): the reference its arrays must equal bit for bit."""
import numpy as np


def mesh_arrays(me):
    """(corners (T,3) int32, positions (T,3,3), normals (T,3,3), uvs (T,3,2),
    slot (T,)) through ``loop_triangles.foreach_get`` and ``corner_normals``."""
    tris = me.loop_triangles
    T = len(tris)
    corners = np.empty(T * 3, np.int32)
    tris.foreach_get("loops", corners)
    corners = corners.reshape(T, 3)
    slot = np.empty(T, np.int32)
    tris.foreach_get("material_index", slot)
    V, L = len(me.vertices), len(me.loops)
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    cv = np.empty(L, np.int32)
    me.loops.foreach_get("vertex_index", cv)
    cn = np.empty(L * 3, np.float32)
    me.corner_normals.foreach_get("vector", cn)
    uv = np.zeros((T, 3, 2), np.float32)
    layer = me.uv_layers.active_render or me.uv_layers.active
    if layer is not None and L:
        uvl = np.empty(L * 2, np.float32)
        layer.uv.foreach_get("vector", uvl)
        uv = uvl.reshape(L, 2)[corners]
    return (corners, co.reshape(V, 3)[cv[corners]], cn.reshape(L, 3)[corners], uv, slot)


def image_pixels(img):
    """(flat float32 pixels, w, h, c, is_float): one ``Image.pixels.foreach_get``."""
    w, h = img.size
    c = img.channels
    px = np.empty(w * h * c, np.float32)
    img.pixels.foreach_get(px)
    return px, w, h, c, bool(img.is_float)
