"""Shared helpers for tests that use the real ``bpy`` module.

Tests import the add-on as ``fppm.addon`` (the editable install maps the
package ``fppm`` to the repository root), never as ``addon``: core modules
must be the very ones the add-on uses (``fppm.core.*``), or exception classes
and dataclasses would not match.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PYTHON = sys.executable


def bpy():
    import bpy as _bpy
    return _bpy


def ensure_registered():
    """Register the add-on once per test process (idempotent)."""
    import fppm.addon as addon
    addon.register()
    return addon


def empty_scene(res=(32, 32), engine="FPPM"):
    """A fresh empty file with one scene set to ``engine`` at ``res`` (100%)."""
    b = bpy()
    b.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    sc = b.context.scene
    sc.render.resolution_x, sc.render.resolution_y = res
    sc.render.resolution_percentage = 100
    sc.render.engine = engine
    return sc


def link(ob, sc=None):
    b = bpy()
    (sc or b.context.scene).collection.objects.link(ob)
    return ob


def add_camera(sc, location=(0.0, -4.0, 1.0), rotation=(math.radians(80), 0.0, 0.0), lens=35.0):
    b = bpy()
    cd = b.data.cameras.new("Camera")
    cd.lens = lens
    ob = link(b.data.objects.new("Camera", cd), sc)
    ob.location = location
    ob.rotation_euler = rotation
    sc.camera = ob
    return ob


def add_light(sc, kind="POINT", energy=100.0, location=(0.0, 0.0, 3.0), name=None, **props):
    b = bpy()
    ld = b.data.lights.new(name or kind.title(), kind)
    ld.energy = energy
    for k, v in props.items():
        setattr(ld, k, v)
    ob = link(b.data.objects.new(name or kind.title(), ld), sc)
    ob.location = location
    return ob


def mesh_object(sc, name, verts, faces, material=None):
    """A mesh object from python lists (only for tiny test meshes)."""
    b = bpy()
    me = b.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    ob = link(b.data.objects.new(name, me), sc)
    if material is not None:
        me.materials.append(material)
    return ob


def add_plane(sc, name="Plane", size=4.0, z=0.0, material=None):
    h = size / 2
    return mesh_object(sc, name, [(-h, -h, z), (h, -h, z), (h, h, z), (-h, h, z)],
                       [(0, 1, 2, 3)], material)


def add_cube(sc, name="Cube", size=1.0, location=(0.0, 0.0, 0.5), material=None):
    h = size / 2
    v = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    f = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    ob = mesh_object(sc, name, v, f, material)
    ob.location = location
    return ob


def _ensure_nodes(idblock):
    # ``use_nodes`` is deprecated in Blender 5 (and warns) but still needed
    # when a new datablock has no node tree yet.
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        if idblock.node_tree is None or not idblock.use_nodes:
            idblock.use_nodes = True


def node_material(name, kind="BSDF_DIFFUSE", **inputs):
    """A material whose output is one shader node of ``kind`` with ``inputs`` set."""
    b = bpy()
    m = b.data.materials.new(name)
    _ensure_nodes(m)
    nt = m.node_tree
    for nd in list(nt.nodes):
        if nd.type != 'OUTPUT_MATERIAL':
            nt.nodes.remove(nd)
    out = next(nd for nd in nt.nodes if nd.type == 'OUTPUT_MATERIAL')
    idname = {"BSDF_DIFFUSE": "ShaderNodeBsdfDiffuse", "BSDF_GLOSSY": "ShaderNodeBsdfGlossy",
              "BSDF_GLASS": "ShaderNodeBsdfGlass", "EMISSION": "ShaderNodeEmission",
              "BSDF_PRINCIPLED": "ShaderNodeBsdfPrincipled",
              "BSDF_TRANSPARENT": "ShaderNodeBsdfTransparent",
              "SUBSURFACE_SCATTERING": "ShaderNodeSubsurfaceScattering"}[kind]
    sh = nt.nodes.new(idname)
    for k, v in inputs.items():
        sh.inputs[k].default_value = v
    nt.links.new(sh.outputs[0], out.inputs["Surface"])
    return m


def set_world(sc, color=(0.0, 0.0, 0.0), strength=1.0):
    b = bpy()
    w = b.data.worlds.new("World")
    _ensure_nodes(w)
    bg = next(nd for nd in w.node_tree.nodes if nd.type == 'BACKGROUND')
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    sc.world = w
    return w


def small_settings(sc, passes=2, photons=2000, seed=1, integrator="PHOTON", **kw):
    """Fast FPPM settings for tests (a few ms per pass at 32x32).

    Photon mapping unless ``integrator`` says otherwise: these tests were
    written for it, and the add-on's default is COMBINED."""
    s = sc.fppm
    s.integrator = integrator
    s.max_passes = passes
    s.photons_per_pass = photons
    s.seed = seed
    s.time_limit = 0.0
    for k, v in kw.items():
        setattr(s, k, v)
    return s


def simple_scene(res=(32, 32), passes=2, photons=2000, seed=1):
    """A diffuse plane and cube under a point light, seen by a camera."""
    sc = empty_scene(res)
    grey = node_material("Grey", "BSDF_DIFFUSE", Color=(0.8, 0.8, 0.8, 1.0))
    red = node_material("Red", "BSDF_DIFFUSE", Color=(0.8, 0.1, 0.1, 1.0))
    add_plane(sc, material=grey)
    add_cube(sc, material=red)
    add_light(sc, "POINT", 200.0, (1.0, -1.0, 3.0))
    add_camera(sc)
    small_settings(sc, passes, photons, seed)
    return sc


def evaluated_depsgraph():
    b = bpy()
    dg = b.context.evaluated_depsgraph_get()
    dg.update()
    return dg


def fppm_command() -> list:
    """The installed ``fppm`` console script (what a user runs), else ``python -m``."""
    script = os.path.join(os.path.dirname(sys.executable), "fppm")
    if os.path.exists(script):
        return [script]
    return [PYTHON, "-m", "fppm.tools.cli"]


def run_fppm(*args, timeout=300, cwd=None, env_extra=None):
    """Run ``fppm ARGS`` in a subprocess from a neutral folder; returns CompletedProcess.

    PYTHONPATH is removed so the command sees exactly what a user's shell
    gives it (the repository root is NOT on sys.path); ``env_extra``: more
    variables.
    """
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | (env_extra or {})
    return subprocess.run(fppm_command() + [str(a) for a in args], capture_output=True,
                          text=True, timeout=timeout, env=env,
                          cwd=cwd or tempfile.gettempdir())


def save_blend(path):
    """Save the current file as ``path`` (a copy: the session keeps its own file)."""
    bpy().ops.wm.save_as_mainfile(filepath=str(path), copy=True, check_existing=False)
    return str(path)


def save_scene_without(path, missing: str, res=(16, 16)):
    """Save a plane + light + camera scene with one of them ("plane",
    "light" or "camera") left out: the bad-input files (nothing to see, no
    light, no camera).  Returns the path as str."""
    sc = empty_scene(res)
    if missing != "plane":
        add_plane(sc)
    if missing != "light":
        add_light(sc)
    if missing != "camera":
        add_camera(sc)
    return save_blend(path)


def interrupt_after(p, marker: str, settle: float, timeout: float = 120.0):
    """Wait until the subprocess ``p`` prints ``marker`` on stderr, wait
    ``settle`` seconds, send SIGINT; return (stdout, stderr, seconds from the
    signal to the exit).  Kills ``p`` if anything goes wrong."""
    import signal
    import time
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            line = p.stderr.readline()
            if marker in line or not line:
                break
        assert p.poll() is None, "the process ended before Ctrl-C"
        time.sleep(settle)
        t0 = time.monotonic()
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=60)
        return stdout, stderr, time.monotonic() - t0
    finally:
        if p.poll() is None:
            p.kill()


def render_mean_rgb(sc):
    """Render ``sc`` to a temporary OpenEXR and return its (H, W) float64
    mean of R, G and B (row 0 at the top, as the file stores it)."""
    import numpy as np
    import OpenEXR
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "render.exr")
        sc.render.image_settings.file_format = "OPEN_EXR"
        sc.render.filepath = path
        bpy().ops.render.render(write_still=True)
        ch = OpenEXR.File(path).channels()
        key = next(k for k in ch if k.endswith("RGBA") or k.endswith("RGB"))
        return np.asarray(ch[key].pixels, np.float64)[..., :3].mean(-1)


def save_multilayer(sc, path) -> dict:
    """The last render's result saved as a 32-bit multilayer EXR at path:
    {"<view layer>.<pass>": (H, W, C) float32} (tests/test_passes.py,
    test_cryptomatte.py, test_shadow_catcher.py)."""
    from fppm.core.io.exr import read_exr
    im = sc.render.image_settings
    if hasattr(im, "media_type"):
        im.media_type = 'MULTI_LAYER_IMAGE'
    im.file_format = 'OPEN_EXR_MULTILAYER'
    im.color_depth = '32'
    bpy().data.images["Render Result"].save_render(filepath=str(path), scene=sc)
    return read_exr(str(path))
