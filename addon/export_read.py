"""The export's large reads from Blender, cut so that a cancel lands within 0.1 s.

A call into Blender holds the GIL and has no partial form: a cancel waits for
it.  Two reads used to be single long calls (docs/reliability.md, "Cancel"):

- a mesh's triangles, ``loop_triangles.foreach_get("loops")`` (~0.1-0.4 us a
  triangle: ``MeshLoopTriangle.loops`` has no raw array behind it).
  :func:`corner_triangles` rebuilds the same corner triples from raw arrays
  (face of each triangle, corner vertices, positions) in bands, with a poll
  between them, as Blender's ``mesh_tessellate.cc`` makes them: a triangle
  is (0, 1, 2) of its face; a quad is (0, 1, 2) + (0, 2, 3), or (0, 1, 3) +
  (1, 2, 3) when ``is_quad_flip_v3_first_third_fast`` says the first split
  is degenerate.  N-gons (Blender's polyfill) and quads whose flip test is
  too close to 0 to be sure of Blender's rounding are read from Blender one
  triangle at a time, in bands.  The corner normals are read in three calls
  (face, vertex, then corner normals), each of which Blender computes once
  and caches.
- an image's pixels: Blender makes (generated) or decodes (file) an image on
  the first access, then ``Image.pixels.foreach_get`` copies it whole.
  :func:`image_pixels` does both in a child process (``fork``: the child
  sees the very same Blender data) that writes into shared memory; the
  parent polls and kills the child on a cancel.  Linux only (``fork`` of
  Blender is unsafe on macOS, absent on Windows): elsewhere, and for small
  images, the read is done in-process as before.

Both give the same arrays as the single calls, bit for bit
(tests/test_reliability_cancel.py).
"""
from __future__ import annotations

import gc
import mmap
import os
import signal
import struct
import sys
import threading
import time
import warnings

import numpy as np

# Rows (triangles, texels) per step of a large copy: a cancel is polled
# between steps, so one step must stay well under the 0.1 s promised by
# docs/reliability.md ("Cancel").
CHUNK = 1 << 15

# Triangles read one by one from Blender per step (~0.6-3 us each).
ITEM_CHUNK = 1 << 13

# Meshes of up to this many triangles are read in one call
# (``loop_triangles.foreach_get``, ~0.1-0.4 us a triangle: <= 0.05 s).
SINGLE_MAX = 1 << 17

# Images of at least this many floats are read in a child process: below,
# the in-process read takes a few ms, less than the fork.
CHILD_MIN_FLOATS = 1 << 20

# Interval at which the parent polls while the child reads (s).
CHILD_POLL = 0.005

# A child not done after CHILD_TIMEOUT[0] s + CHILD_TIMEOUT[1] s a float is
# killed and the image read in-process: a child that deadlocked (a lock held
# by another thread of Blender at the fork) costs time, never the image.
# An 8192^2 texture (268M floats) took up to 18 s on a loaded machine; the
# bound gives it 37 s.
CHILD_TIMEOUT = (10.0, 1e-7)

# The child's answer: width, height, channels, is_float, in front of the pixels.
_HEADER = struct.Struct("<4q")


def _never() -> bool:
    return False


# ---------------------------------------------------------------------------
# meshes

def _quad_flips(pa, pb, pc, pd):
    """``is_quad_flip_v3_first_third_fast(a, b, c, d)`` of Blender's math_geom.c
    for (Q, 3) float32 corners, in the same float32 operations and order, and
    whether the sign is unsure: (flip (Q,) bool, unsure (Q,) bool).

    Unsure: |dot| within 8 float32 epsilons of the sum of its terms' absolute
    values, where a compiler contracting a product into an FMA could round
    to the other sign."""
    d12, d13, d14 = pb - pa, pc - pa, pd - pa

    def cross(a, b):
        return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                         a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                         a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)

    def abs_cross(a, b):
        a, b = np.abs(a), np.abs(b)
        return np.stack([a[:, 1] * b[:, 2] + a[:, 2] * b[:, 1],
                         a[:, 2] * b[:, 0] + a[:, 0] * b[:, 2],
                         a[:, 0] * b[:, 1] + a[:, 1] * b[:, 0]], axis=1)

    ca, cb = cross(d12, d13), cross(d14, d13)
    dot = ca[:, 0] * cb[:, 0] + ca[:, 1] * cb[:, 1] + ca[:, 2] * cb[:, 2]
    bound = (abs_cross(d12, d13).astype(np.float64)
             * abs_cross(d14, d13).astype(np.float64)).sum(axis=1) * 2.0 ** -20
    unsure = (np.abs(dot.astype(np.float64)) <= bound) & (bound > 0)
    return dot > 0, unsure


def corner_triangles(me, face, co, cv, poll=_never, single_max=None) -> np.ndarray:
    """(T, 3) int32 corner indices of the mesh's triangles, equal to
    ``me.loop_triangles.foreach_get("loops")``.

    face: (T,) int32 face of each triangle (``loop_triangle_polygons``);
    co: (V, 3) float32 vertex positions; cv: (L,) int32 vertex of each corner.
    Faces are contiguous runs of corners in face order (Blender's face
    offsets), a face of n corners has n - 2 triangles, consecutive.
    poll: called between bands of CHUNK (ITEM_CHUNK read one by one) triangles.
    single_max: up to this many triangles, Blender's single call (default
    SINGLE_MAX; tests: 0).
    """
    T, F, L = len(face), len(me.polygons), len(cv)
    single_max = SINGLE_MAX if single_max is None else single_max
    n_tri = np.bincount(face, minlength=F) if T else np.zeros(F, np.int64)
    size = n_tri + 2
    if T <= single_max or len(n_tri) != F or int(size.sum()) != L or T != L - 2 * F:
        # Small enough for one call well within the cancel promise, or not
        # the layout assumed (faces of < 3 corners?): Blender's own read.
        out = np.empty(T * 3, np.int32)
        me.loop_triangles.foreach_get("loops", out)
        return out.reshape(T, 3)
    start = np.zeros(F, np.int64)
    np.cumsum(size[:-1], out=start[1:])
    first_tri = start - 2 * np.arange(F, dtype=np.int64)   # Blender's poly_to_tri_count
    poll()
    out = np.empty((T, 3), np.int32)
    ask = []                                   # triangles read from Blender
    a = 0
    while a < T:
        b = min(a + CHUNK, T)
        if b < T and face[b] == face[b - 1]:
            b += 1                              # a band never splits a quad
        f = face[a:b]
        s = start[f]
        j = np.arange(a, a + len(f), dtype=np.int64) - first_tri[f]   # index in its face
        n = size[f]
        # Triangles and the first split of quads: s + (0, 1, 2); quads'
        # second triangle: s + (0, 2, 3).
        second = j == 1
        c = np.empty((len(f), 3), np.int64)
        c[:, 0] = s
        c[:, 1] = s + 1 + second
        c[:, 2] = s + 2 + second
        quad = n == 4
        if quad.any():
            q = np.flatnonzero(quad & ~second)        # first triangle of each quad
            qs = s[q]
            flip, unsure = _quad_flips(co[cv[qs]], co[cv[qs + 1]], co[cv[qs + 2]],
                                       co[cv[qs + 3]])
            fq = q[flip & ~unsure]
            c[fq, 2] = s[fq] + 3                        # (0, 1, 3)
            c[fq + 1, 0] = s[fq] + 1                    # (1, 2, 3)
            need = n > 4
            need[q[unsure]] = need[q[unsure] + 1] = True
        else:
            need = n > 4
        ask.append(a + np.flatnonzero(need))     # increasing: no sort needed
        out[a:b] = c
        a = b
        poll()
    ask = np.concatenate(ask)
    if len(ask):
        # Runs of consecutive triangles (an n-gon's), read as slices of the
        # collection (~0.6 us a triangle), ITEM_CHUNK at most between polls.
        # The garbage collector is off meanwhile: the many short-lived
        # objects would trigger a full collection, ~90 ms with bpy and numba
        # loaded (they are freed by reference counting, no cycles).
        tris = me.loop_triangles
        cut = np.flatnonzero(np.diff(ask) != 1) + 1
        was_enabled = gc.isenabled()
        gc.disable()
        try:
            for run in np.split(ask, cut):
                for b in range(0, len(run), ITEM_CHUNK):
                    lo = int(run[b])
                    hi = int(run[min(b + ITEM_CHUNK, len(run)) - 1]) + 1
                    out[lo:hi] = [x.loops[:] for x in tris[lo:hi]]
                    poll()
        finally:
            if was_enabled:
                gc.enable()
    return out


def _corner_normals(me, L: int, poll=_never) -> np.ndarray:
    """(L, 3) float32 ``me.corner_normals``, Blender's normal caches filled one
    at a time (face, then vertex normals) with a poll between, so that no
    single call computes them all."""
    if len(me.polygons):
        me.polygon_normals.foreach_get("vector", np.empty(len(me.polygons) * 3, np.float32))
        poll()
    if getattr(me, "normals_domain", 'CORNER') != 'FACE' and len(me.vertices):
        me.vertex_normals.foreach_get("vector", np.empty(len(me.vertices) * 3, np.float32))
        poll()
    cn = np.empty(L * 3, np.float32)
    me.corner_normals.foreach_get("vector", cn)
    poll()
    return cn.reshape(L, 3)


def _int_attribute(me, name, domain, n):
    """(n,) int32 of an INT attribute on ``domain``, or None."""
    at = me.attributes.get(name)
    if at is None or at.domain != domain or at.data_type != 'INT' or len(at.data) != n:
        return None
    out = np.empty(n, np.int32)
    at.data.foreach_get("value", out)
    return out


def mesh_arrays(me, poll=_never):
    """Local-space (T,3,3) positions and normals, (T,3,2) uvs, (T,) slot index
    of a mesh's loop triangles (Blender's order).

    poll: called between the reads and between bands of CHUNK triangles
    (a cancellation point, ``_Exporter.poll``); no read takes more than
    ~50 ms at 1M triangles (docs/reliability.md, "Cancel").
    """
    poll = poll or _never
    F, L, V = len(me.polygons), len(me.loops), len(me.vertices)
    face = np.empty(len(me.loop_triangle_polygons), np.int32)
    me.loop_triangle_polygons.foreach_get("value", face)
    T = len(face)
    if T == 0:
        z = np.zeros((0, 3, 3), np.float32)
        return z, z, np.zeros((0, 3, 2), np.float32), np.zeros(0, np.int32)
    poll()
    # Material slots through the attribute when Blender has it (a raw copy).
    per_face = _int_attribute(me, "material_index", 'FACE', F)
    if per_face is not None:
        slot = per_face[face]
    elif me.attributes.get("material_index") is None:
        slot = np.zeros(T, np.int32)         # Blender's default: every face slot 0
    else:
        slot = np.empty(T, np.int32)
        me.loop_triangles.foreach_get("material_index", slot)
    poll()
    co = np.empty(V * 3, np.float32)
    pos = me.attributes.get("position")
    if pos is not None and pos.domain == 'POINT' and pos.data_type == 'FLOAT_VECTOR' \
            and len(pos.data) == V:
        pos.data.foreach_get("vector", co)
    else:
        me.vertices.foreach_get("co", co)
    co = co.reshape(V, 3)
    cv = _int_attribute(me, ".corner_vert", 'CORNER', L)
    if cv is None:
        cv = np.empty(L, np.int32)
        me.loops.foreach_get("vertex_index", cv)
    poll()
    corners = corner_triangles(me, face, co, cv, poll)
    cn = _corner_normals(me, L, poll)
    layer = me.uv_layers.active_render or me.uv_layers.active
    uvl = None
    if layer is not None and L:
        uvl = np.empty(L * 2, np.float32)
        layer.uv.foreach_get("vector", uvl)
        uvl = uvl.reshape(L, 2)
        poll()
    p = np.empty((T, 3, 3), np.float32)
    n = np.empty((T, 3, 3), np.float32)
    uv = np.zeros((T, 3, 2), np.float32)
    for a in range(0, T, CHUNK):
        k = corners[a:a + CHUNK]
        p[a:a + CHUNK] = co[cv[k]]
        n[a:a + CHUNK] = cn[k]
        if uvl is not None:
            uv[a:a + CHUNK] = uvl[k]
        poll()
    return p, n, uv, slot


def corner_topology(me, poll=_never):
    """What true displacement needs of a mesh (addon/export_displace.py), in
    ``mesh_arrays``' triangle order: (T, 3) int32 the vertex of each corner,
    (T,) bool the triangle's face is smooth, and whether the mesh's normals
    are per corner (sharp edges, custom normals: Blender's normals_domain
    'CORNER', Cycles' corner normals)."""
    poll = poll or _never
    F, L, V = len(me.polygons), len(me.loops), len(me.vertices)
    face = np.empty(len(me.loop_triangle_polygons), np.int32)
    me.loop_triangle_polygons.foreach_get("value", face)
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    cv = _int_attribute(me, ".corner_vert", 'CORNER', L)
    if cv is None:
        cv = np.empty(L, np.int32)
        me.loops.foreach_get("vertex_index", cv)
    poll()
    corners = corner_triangles(me, face, co.reshape(V, 3), cv, poll)
    smooth = np.empty(F, bool)
    me.polygons.foreach_get("use_smooth", smooth)
    return (cv[corners].astype(np.int32), smooth[face],
            getattr(me, "normals_domain", 'POINT') == 'CORNER')


# ---------------------------------------------------------------------------
# images

def _read_in_process(img) -> tuple[np.ndarray, int, int, int, bool]:
    w, h = (int(x) for x in img.size)
    c = int(img.channels)
    px = np.empty(w * h * c, np.float32)
    if px.size:
        img.pixels.foreach_get(px)
    return px, w, h, c, bool(img.is_float)


def _child_allowed() -> bool:
    return sys.platform.startswith("linux") and hasattr(os, "fork")


# Threads reaping killed children (see _kill).
_reapers: list = []


def _kill(pid: int) -> None:
    """SIGKILL the child and reap it in a daemon thread: the kernel takes tens
    of ms to free a killed child's memory, which ``waitpid`` would wait for."""
    os.kill(pid, signal.SIGKILL)
    t = threading.Thread(target=os.waitpid, args=(pid, 0), daemon=True,
                         name=f"fppm-reap-{pid}")
    t.start()
    _reapers[:] = [r for r in _reapers if r.is_alive()] + [t]


def reap(timeout: float = 5.0) -> None:
    """Wait until every killed child is reaped (tests; nothing needs it)."""
    for t in list(_reapers):
        t.join(timeout)


def _die_with_parent() -> None:
    """In the child: SIGKILL when the parent dies (``prctl(PR_SET_PDEATHSIG)``),
    as when the CLI quits at once on a second Ctrl-C."""
    import ctypes
    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)


def _read_in_child(img, capacity: int, poll):
    """The read of :func:`_read_in_process` in a forked child, written into
    shared memory; the parent polls every CHILD_POLL s and kills the child on
    a cancel (RenderCancelled; the child is reaped in the background).  None
    when the child failed (the caller then reads in-process): an image larger
    than ``capacity`` floats, an error, a crash."""
    buf = mmap.mmap(-1, _HEADER.size + 4 * capacity)
    with warnings.catch_warnings():
        # Python warns that fork() of a threaded process may deadlock the
        # child: the child only reads the image and leaves with os._exit.
        warnings.simplefilter("ignore", DeprecationWarning)
        pid = os.fork()
    if pid == 0:                                  # the child
        code = 3
        try:
            _die_with_parent()
            w, h = (int(x) for x in img.size)
            c = int(img.channels)
            if 0 < w * h * c <= capacity:
                img.pixels.foreach_get(np.frombuffer(buf, np.float32, w * h * c,
                                                     _HEADER.size))
                buf[:_HEADER.size] = _HEADER.pack(w, h, c, int(bool(img.is_float)))
                code = 0
        finally:
            os._exit(code)
    deadline = time.monotonic() + CHILD_TIMEOUT[0] + CHILD_TIMEOUT[1] * capacity
    try:
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            poll()
            if time.monotonic() > deadline:
                _kill(pid)
                buf.close()
                return None
            time.sleep(CHILD_POLL)
    except BaseException:                         # RenderCancelled from poll()
        _kill(pid)
        buf.close()
        raise
    if not os.WIFEXITED(status) or os.WEXITSTATUS(status) != 0:
        buf.close()
        return None
    w, h, c, is_float = _HEADER.unpack(buf[:_HEADER.size])
    # The pixels stay in the shared mapping (no copy): the array keeps it alive.
    return np.frombuffer(buf, np.float32, w * h * c, _HEADER.size), w, h, c, bool(is_float)


def image_pixels(img, capacity: int, poll=_never):
    """(flat float32 pixels, width, height, channels, is_float) of
    ``Image.pixels``, Blender's order (row 0 at the bottom).

    capacity: an upper bound of width x height x channels, known without
    making or decoding the image (``_Exporter.check_image_memory``).  At
    least CHILD_MIN_FLOATS on Linux, with a ``poll`` (a render that can be
    cancelled; not the viewport or previews): made / decoded and read in a
    child process, so a cancel (``poll`` raising RenderCancelled) returns
    within CHILD_POLL s plus the kill; otherwise in-process (one call).
    """
    if capacity >= CHILD_MIN_FLOATS and poll is not _never and _child_allowed():
        r = _read_in_child(img, capacity, poll)
        if r is not None:
            return r
    return _read_in_process(img)


def tile_path(img, number: int) -> str | None:
    """The file of a UDIM image's tile ``number``: its path with the
    ``<UDIM>`` token as the number (1001, 1002, ...) or ``<UVTILE>`` as
    u<column>_v<row> (from 1); None without a token."""
    import bpy
    path = bpy.path.abspath(img.filepath_raw, library=img.library)
    if "<UDIM>" in path:
        return path.replace("<UDIM>", str(number))
    if "<UVTILE>" in path:
        k = number - 1001
        return path.replace("<UVTILE>", f"u{k % 10 + 1}_v{k // 10 + 1}")
    return None


def tile_image(img, number: int):
    """A stand-in image of a UDIM image's tile, with the image's colour space
    and alpha mode (Image.pixels reads the first tile only): decoded from
    the tile's packed data when the image is packed, else loaded from its
    file; None (no such packed tile, no token, no readable file).  The
    caller removes it (:func:`remove_image`)."""
    if img.packed_file is not None:
        return _packed_tile(img, number)
    path = tile_path(img, number)
    return None if path is None else _stand_in(img, path)


def _packed_tile(img, number: int):
    """A packed UDIM image's tile ``number`` as a new image packed from the
    same bytes (``Image.packed_files``: one per tile, ``tile_number``), or
    None when the image packs no such tile."""
    import bpy
    pf = next((p for p in img.packed_files
               if int(p.tile_number) == number and p.packed_file is not None), None)
    if pf is None:
        return None
    t = bpy.data.images.new(f"{img.name}.{number}", 1, 1)
    try:
        t.source = 'FILE'
        t.filepath_raw = pf.filepath         # names the format; the bytes are decoded
        t.pack(data=pf.packed_file.data, data_len=pf.packed_file.size)
        t.reload()
    except (RuntimeError, TypeError):
        bpy.data.images.remove(t)
        return None
    _match(t, img)
    return t


def sequence_frame(iu, frame: int) -> int:
    """The file frame an image sequence shows at scene frame ``frame``,
    Blender's ``BKE_image_user_frame_get`` of the node's image user ``iu``
    (Frames, Start Frame, Offset, Cyclic)."""
    n = int(iu.frame_duration)
    if n == 0:
        return 0
    f = frame - int(iu.frame_start) + 1
    if iu.use_cyclic:
        f %= n
        if f == 0:
            f = n
    f = min(max(f, 0), n)
    return f + int(iu.frame_offset)


def frame_path(path: str, number: int) -> str:
    """``path`` with the last run of digits in its file name replaced by
    ``number``, zero-padded to the run's length (Blender's sequence names:
    shot_0001.png -> shot_0012.png); unchanged without digits."""
    import re
    head, name = os.path.split(path)
    runs = list(re.finditer(r"\d+", name))
    if not runs:
        return path
    r = runs[-1]
    return os.path.join(head, name[:r.start()] + str(number).zfill(len(r.group()))
                        + name[r.end():])


def sequence_image(img, iu, frame: int):
    """A stand-in image of an image sequence's file at scene frame
    ``frame`` (:func:`sequence_frame`), loaded with the image's colour space
    and alpha mode, or None (no such file).  The caller removes it."""
    import bpy
    path = frame_path(bpy.path.abspath(img.filepath_raw, library=img.library),
                      sequence_frame(iu, frame))
    return _stand_in(img, path)


def _stand_in(img, path):
    """``path`` loaded as a new image with img's colour space and alpha
    mode, or None (no readable file, or img is packed)."""
    import bpy
    if img.packed_file is not None or not os.path.isfile(path):
        return None
    try:
        t = bpy.data.images.load(path, check_existing=False)
    except RuntimeError:
        return None
    _match(t, img)
    return t


def _match(t, img) -> None:
    """Give the stand-in ``t`` the colour space and alpha mode of ``img``."""
    try:
        t.colorspace_settings.name = img.colorspace_settings.name
        t.alpha_mode = img.alpha_mode
    except (TypeError, AttributeError):
        pass


def remove_image(img) -> None:
    """Remove a stand-in image from bpy.data."""
    import bpy
    bpy.data.images.remove(img)


def _use_nodes(idblock) -> bool:
    # ``use_nodes`` is deprecated in Blender 5 (node trees are always used).
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return bool(getattr(idblock, "use_nodes", True)) and idblock.node_tree is not None


def _follow(socket):
    """The (node, output socket) feeding ``socket`` through reroutes, or (None, None)."""
    seen = 0
    while socket is not None and socket.is_linked and seen < 64:
        seen += 1
        link = socket.links[0]
        if not getattr(link, "is_valid", True) or getattr(link, "is_muted", False):
            return None, None
        node = link.from_node
        if node.type == 'REROUTE':
            socket = node.inputs[0]
            continue
        return node, link.from_socket
    return None, None
