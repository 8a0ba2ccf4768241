"""A world shader FPPM does not evaluate, baked by Cycles into an environment map.

FPPM evaluates a world's Background colour and an Environment Texture
itself (``export._Exporter.world``).  Anything else - a Sky Texture, procedural
textures, a Mix Shader of two Backgrounds - is rendered by Cycles, which
ships with every Blender, into an equirectangular map that FPPM then samples
like any HDRI: Cycles' own evaluation of the user's nodes, not a
re-implementation of them.

The bake runs in a child process (``world_bake_job.py``): the render engine
may be inside a render job, where starting a second render is not allowed.
The parent writes the world (``bpy.data.libraries.write``) to a temporary
.blend; the child appends it, renders it through a panoramic camera and
writes OpenEXR files that the parent reads.  A cancel kills the child.

A Sky Texture's sun disc (single and multiple scattering) is half a degree
wide and holds most of the sky's power: in a map of 1024 x 512 it covers
about six pixels, which a map's importance sampling finds but photons and
shadow rays resolve as a blocky 0.35-deg source.  So the sky is baked with
its disc off and the disc becomes a sun light of the same direction, angle
and irradiance, measured in a narrow render of the disc alone (the sky
inside that render, nearly constant over its 3.5 deg, is its median and
is subtracted).  The sun light is a uniform disc: Cycles' limb darkening
(the edge at 40 % of the centre) is kept in its power, not in its profile.

Bakes are cached in this process by what the world's nodes hold
(:func:`world_key`), so a viewport that re-exports on every change, or the
frames of an animation whose world does not move, bake once.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from typing import NamedTuple

import numpy as np

from ..core.io.exr import read_exr
from .world_bake_job import has_light_path, node_trees, sun_nodes

# The map's width in pixels (height: half): 0.18 deg a pixel.
WIDTH = 2048
JOB = os.path.join(os.path.dirname(os.path.abspath(__file__)), "world_bake_job.py")
# Samples per pixel of the map.  The pixel filter is a one-pixel box, so a
# pixel is the mean over its extent: a sky without its disc is smooth there
# and 16 jittered samples leave its noise well under a percent.
SAMPLES = 8
# Pixels across the sun disc's render (its field of view is twice the disc
# plus 3 deg): the default disc spans 68 of them, and the disc's irradiance
# at SAMPLES is within 0.01 % of 256 samples at 256 pixels (0.3 % at 128
# pixels: the disc's rim is sampled too coarsely).
SUN_RES = 512
# The child's wall-clock limit [s]: a 1024 x 512 bake takes 2-3 s.
TIMEOUT = 600.0
POLL = 0.05
# At most this many bakes are kept (each is width^2 / 2 x 12 bytes).
CACHE_SIZE = 2
_cache: dict[str, "Baked"] = {}


class Baked(NamedTuple):
    """image (H, W, 3) float32 scene-linear radiance, row 0 at the bottom
    (Blender's order, as ``_Exporter.pixels``), H = W / 2, equirectangular in
    world directions (an Environment Texture's lookup, no mapping);
    sun None or (strength (3,) irradiance [W/m^2], angle [rad], direction
    (3,) unit, towards the sun); seconds the bake took; camera_image: with a
    Light Path node in the world, what camera rays see (image is then what
    lights the scene), else None."""
    image: np.ndarray
    sun: tuple | None
    seconds: float
    camera_image: np.ndarray | None = None


class BakeError(RuntimeError):
    """The child failed: the message ends with the tail of its log."""


def _never() -> bool:
    return False


_LAYOUT = frozenset(("location", "location_absolute", "width", "height", "select", "show_options",
                     "show_preview", "hide", "show_texture", "use_custom_color", "color",
                     "label", "parent", "warning_propagation", "dimensions"))


def _value(v):
    """A property value as a hashable, repeatable text."""
    if hasattr(v, "__len__") and not isinstance(v, str):
        try:
            return repr(tuple(round(float(x), 9) for x in v))
        except (TypeError, ValueError):
            return repr(tuple(str(x) for x in v))
    if isinstance(v, float):
        return repr(round(v, 9))
    return repr(v)


def _image_key(img) -> str:
    if img is None:
        return "None"
    path = img.filepath_raw
    try:
        import bpy
        st = os.stat(bpy.path.abspath(path, library=img.library))
        stamp = f"{st.st_mtime_ns}:{st.st_size}"
    except (OSError, ImportError, AttributeError, ValueError):
        stamp = ""
    packed = getattr(img, "packed_file", None)
    return f"{img.name}|{path}|{stamp}|{packed.size if packed else 0}|{img.colorspace_settings.name}"


def world_key(world, frame: int, width: int, samples: int = SAMPLES) -> str:
    """A digest of what a bake of ``world`` depends on: every node's
    settings and input values (node groups inside), the links, images'
    files, texture-coordinate objects' matrices; the frame when the world or
    its nodes are animated; the bake's size."""
    h = hashlib.sha256()
    h.update(f"{width}|{samples}|{SUN_RES}|{world.name}\n".encode())
    anim = getattr(world, "animation_data", None)
    for t in node_trees(world.node_tree):
        anim = anim or getattr(t, "animation_data", None)
        h.update(f"tree {t.name}\n".encode())
        for nd in sorted(t.nodes, key=lambda n: n.name):
            h.update(f"node {nd.bl_idname} {nd.name} {nd.mute}\n".encode())
            for p in nd.bl_rna.properties:
                k = p.identifier
                if k in _LAYOUT or k.startswith("bl_") or k in ("rna_type", "inputs", "outputs",
                                                                 "internal_links", "name", "type"):
                    continue
                v = getattr(nd, k, None)
                if p.type == 'POINTER':
                    if k == "image":
                        v = _image_key(v)
                    elif k == "object":
                        v = None if v is None else (v.name, _value([x for r in v.matrix_world
                                                                     for x in r]))
                    elif k == "node_tree":
                        v = None if v is None else v.name
                    else:
                        continue
                elif p.type == 'COLLECTION':
                    continue
                h.update(f"  {k}={_value(v)}\n".encode())
            for s in nd.inputs:
                if hasattr(s, "default_value"):
                    h.update(f"  in {s.identifier}={_value(s.default_value)}\n".encode())
        for ln in t.links:
            h.update(f"link {ln.from_node.name}.{ln.from_socket.identifier} "
                     f"{ln.to_node.name}.{ln.to_socket.identifier} {ln.is_muted}\n".encode())
    if anim is not None:
        h.update(f"frame {frame}\n".encode())
    return h.hexdigest()


def has_sun_disc(world) -> bool:
    """Whether a Sky Texture in the world draws a disc the child makes a light."""
    return bool(sun_nodes(world))


def _command(spec_path: str) -> list[str]:
    import bpy
    blender = bpy.app.binary_path
    if blender:
        # Inside Blender: its executable, without the user's startup file
        # and add-ons (the world comes with its node groups and images).
        return [blender, "-b", "--factory-startup", "-noaudio", "--python-exit-code", "1",
                "--python", JOB, "--", spec_path]
    return [sys.executable, JOB, spec_path]       # the bpy module: Python imports bpy


def sun_from_render(img: np.ndarray, fov: float, matrix) -> tuple | None:
    """(irradiance (3,), direction (3,)) of a sun disc rendered through a
    square perspective camera of horizontal field of view ``fov`` [rad]
    and ``matrix`` (4, 4) camera-to-world; img (n, n, 3) row 0 at the top.

    A pixel's solid angle is p^2 cos^3(theta) for p = 2 tan(fov/2) / n on
    a sensor at distance 1; the sky in the render is its median; the
    direction is the disc's radiance-weighted mean."""
    n = img.shape[0]
    p = 2.0 * math.tan(0.5 * fov) / n
    c = (np.arange(n) + 0.5) * p - 0.5 * n * p
    x, y = np.meshgrid(c, -c)                    # row 0 at the top: +y
    d = np.stack([x, y, -np.ones_like(x)], -1)
    r = np.linalg.norm(d, axis=-1)
    omega = p * p / r ** 3                       # p^2 cos^3 / 1^2, cos = 1 / r
    L = np.maximum(img[..., :3].astype(np.float64)
                   - np.median(img[..., :3].reshape(-1, 3), axis=0), 0.0)
    E = (L * omega[..., None]).sum(axis=(0, 1))
    lum = L @ np.array([0.2126, 0.7152, 0.0722])
    w = lum * omega
    if w.sum() <= 0:
        return None
    dc = (d / r[..., None] * w[..., None]).sum(axis=(0, 1))
    M = np.asarray(matrix, np.float64)
    dw = M[:3, :3] @ dc
    return E, dw / np.linalg.norm(dw)


class _Child:
    """A bake under way: the child process, its folder and what it will write."""

    def __init__(self, world, frame: int, width: int, key: str):
        import bpy
        self.key = key
        self.t0 = time.monotonic()
        self.tmp = tempfile.TemporaryDirectory(prefix="fppm-world-")
        d = self.tmp.name
        blend = os.path.join(d, "world.blend")
        bpy.data.libraries.write(blend, {world}, path_remap='ABSOLUTE', fake_user=True)
        self.spec = {"blend": blend, "world": world.name, "frame": int(frame), "width": width,
                     "samples": SAMPLES, "out": os.path.join(d, "sky.exr"),
                     "sun": has_sun_disc(world), "sun_out": os.path.join(d, "sun.exr"),
                     "sun_res": SUN_RES, "result": os.path.join(d, "result.json"),
                     "camera_out": (os.path.join(d, "camera.exr") if has_light_path(world)
                                    else "")}
        spec_path = os.path.join(d, "spec.json")
        with open(spec_path, "w") as f:
            json.dump(self.spec, f)
        self.log_path = os.path.join(d, "log.txt")
        with open(self.log_path, "wb") as log:
            self.proc = subprocess.Popen(_command(spec_path), stdout=log,
                                         stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.tmp.cleanup()

    def finish(self) -> "Baked":
        """The child's result (it has ended); BakeError when it failed.  The
        folder is removed either way."""
        try:
            if self.proc.returncode != 0:
                try:
                    with open(self.log_path, "rb") as f:
                        tail = f.read()[-600:].decode(errors="replace").strip()
                except OSError:
                    tail = ""
                raise BakeError(f"Cycles' bake exited with {self.proc.returncode}: {tail}")
            spec = self.spec
            sky = read_exr(spec["out"])["Combined"][::-1, :, :3]   # row 0 at the bottom
            with open(spec["result"]) as f:
                res = json.load(f)
            light = None
            if res.get("suns"):
                found = sun_from_render(read_exr(spec["sun_out"])["Combined"], res["fov"],
                                        res["matrix"])
                if found is not None:
                    light = (found[0], float(res["size"]), found[1])
            cam = None
            if spec["camera_out"]:
                cam = np.ascontiguousarray(
                    read_exr(spec["camera_out"])["Combined"][::-1, :, :3], np.float32)
            out = Baked(np.ascontiguousarray(sky, np.float32), light,
                        time.monotonic() - self.t0, cam)
        finally:
            self.tmp.cleanup()
        while len(_cache) >= CACHE_SIZE:
            _cache.pop(next(iter(_cache)))
        _cache[self.key] = out
        return out


# The viewport's bake under way (at most one: a newer world replaces it) and
# the last one that failed (key, message), not started again.
_background: list[_Child] = []
_failed: dict[str, str] = {}


def bake_world(world, frame: int, width: int = WIDTH, poll=_never,
               timeout: float = TIMEOUT, wait: bool = True) -> Baked | None:
    """The world rendered by Cycles (see the module doc).  poll() raises
    RenderCancelled to stop (the child is killed); BakeError when the
    child fails.

    wait=False (the viewport, which exports on Blender's main thread): a
    bake not yet made is started in the background and None is returned;
    :func:`collect` says when it has ended, and the next export finds it
    cached (or raises its BakeError)."""
    width = max(8, int(width) // 2 * 2)
    key = world_key(world, frame, width)
    hit = _cache.get(key)
    if hit is not None:
        return hit
    if key in _failed:
        raise BakeError(_failed[key])
    if not wait:
        if not any(c.key == key for c in _background):
            for c in _background:
                c.kill()
            _background[:] = [_Child(world, frame, width, key)]
        return None
    child = _Child(world, frame, width, key)
    deadline = time.monotonic() + timeout
    try:
        while child.proc.poll() is None:
            poll()
            if time.monotonic() > deadline:
                raise BakeError(f"the bake took over {timeout:.0f} s")
            time.sleep(POLL)
    except BaseException:
        child.kill()
        raise
    return child.finish()


def collect() -> bool:
    """Whether a background bake has ended since the last call (its result
    is then cached, or its failure kept for the next export to report)."""
    ended = False
    for c in list(_background):
        if c.proc.poll() is None:
            if time.monotonic() - c.t0 > TIMEOUT:
                c.kill()
                _failed[c.key] = f"the bake took over {TIMEOUT:.0f} s"
                _background.remove(c)
                ended = True
            continue
        _background.remove(c)
        try:
            c.finish()
        except (BakeError, OSError, KeyError, ValueError) as ex:
            _failed.clear()
            _failed[c.key] = str(ex)
        ended = True
    return ended


def baking() -> bool:
    """Whether a background bake is under way."""
    return bool(_background)


def cancel_background() -> None:
    """Kill the background bake (the viewport closes)."""
    for c in _background:
        c.kill()
    _background.clear()
