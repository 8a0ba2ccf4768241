"""LuxCoreRender as a peer of FPPM at equal CPU time (docs/peers.md).

    .venv/bin/python bench/peer_luxcore.py units   SCENE [--pct P] [--cpu S] [--engine E]
    .venv/bin/python bench/peer_luxcore.py compare SCENE [--pct P] [--budget S] [--seeds K]
                                                         [--lux E1,E2] [--fppm R1,R2]

SCENE: example_blends/<name>.blend (point_caustic, glass_sphere and cornell
are supported; a scene using anything else is refused with the feature
named).  pyluxcore (LuxCoreRender's Python module, PyPI) is a benchmark-only
dependency: ``make bench-deps`` installs it into .venv; the extension and
``make test`` never need it.

The scene LuxCore renders is FPPM's own exported scene
(``addon.export.export_scene`` of the .blend's depsgraph: world-space
triangles with per-corner shading normals, flattened materials, lights in
Cycles' units, the Blender camera), translated by :func:`translate` into
LuxCore properties, meshes and image maps (pure numpy, no bpy, no pyluxcore:
tests/test_peer_luxcore.py checks it).  Unit conversions (each derived from
LuxCore's source, docs/peers.md "Units"):

- point light of strength S (radius 0): LuxCore ``point`` with
  ``color = S`` (its intensity is gain * color / (4 pi), Cycles' S / (4 pi));
  radius r > 0: ``sphere`` of radius r, the same colour (radiance
  S / (4 pi^2 r^2) on both).
- spot: ``mappoint`` (radius 0) or ``mapsphere`` (radius > 0) whose
  spherical image map is Cycles' smoothstep cone (LuxCore's own ``spot``
  has a pow-4 falloff and a 1 / cos factor); LuxCore divides the map by its
  own sin-weighted average ``avg`` over a 512 x 256 grid, so
  ``color = S * avg`` (:func:`spot_gain`).
- area light: an emissive one-sided mesh (quad, or a 64-gon for disc and
  ellipse) facing local -Z, radiance ``S / (pi A)`` with A the mesh's area.
- sun (angle 0): ``sharpdistant``, ``color = S`` (irradiance).
- world colour: ``constantinfinite``, ``color`` = the radiance.
- camera: ``perspective`` with fov 90 deg (tan = 1), so that
  ``screenwindow`` is Blender's view plane at unit depth
  (core.scene.camera.CameraModel: sensor fit, shift, pixel aspect), and
  the film filter is Cycles' Blackman-Harris of the same width.

Timing: LuxCore renders in a child process (``--child``) at
``native.threads.count = 2``; it stops itself when its own CPU time
(getrusage RUSAGE_SELF: scene build, kernels and all render threads)
reaches the budget, and the parent reports the child's CPU seconds read
with RUSAGE_CHILDREN.  FPPM's side is bench/measure_cpu.py's
``render_cpu`` (process_time of this process after an untimed warm-up).
The machine is shared: CPU seconds, not wall seconds, are the clock.
relMSE is tools.metrics.relmse against the scene's reference (Cycles
8192 spp, cached as ``fppm converge`` does; Mitsuba 3's light tracer for
point_caustic, bench/point_caustic_reference.py).
"""
from __future__ import annotations

import math
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if __name__ == "__main__" and sys.argv[1:2] != ["--child"]:
    # fppm.* importable with one numba cache (the child renders with pyluxcore only).
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    import fppm_alias  # noqa: F401

INSTALL_HINT = ("pyluxcore is not installed: run `make bench-deps` (or "
                "`.venv/bin/python -m pip install pyluxcore`); it is a benchmark-only dependency.")

#: LuxCore engines by the name used on the command line: the three of
#: ``compare`` (path + light tracing, VCM, caustic cache), then plain path
#: tracing, light tracing and BDPT for ``units`` (docs/peers.md "Units").
ENGINES = {
    "lux_pathlt": {"renderengine.type": "PATHCPU", "path.hybridbackforward.enable": True},
    "lux_bidirvm": {"renderengine.type": "BIDIRVMCPU"},
    "lux_caustic": {"renderengine.type": "PATHCPU", "path.photongi.caustic.enabled": True},
    "lux_path": {"renderengine.type": "PATHCPU"},
    "lux_light": {"renderengine.type": "LIGHTCPU"},
    "lux_bidir": {"renderengine.type": "BIDIRCPU"},
}
#: Blender's max_bounces of the example scenes (16) as LuxCore depths: LuxCore
#: counts the camera ray's vertex as depth 1, so 16 bounces = depth 17.
MAX_DEPTH = 17
#: The grid of LuxCore's SampleableSphericalFunction (x, y; sphericalfunction.h):
#: the map's average -- its normalisation -- is a midpoint sum over it.
LUX_SPHERE_GRID = (512, 256)
#: Rows (theta) of the spot maps: 0.09 deg a row, fine against the smoothstep band.
SPOT_MAP_ROWS = 2048
#: Sides of the polygon standing for a disc or ellipse area light.
DISC_SIDES = 64
#: FPPM's side of the comparison (bench/measure_cpu.py run names).
FPPM_RUNS = ("combined", "light", "fppm")


class Unsupported(Exception):
    """The scene uses a feature this translation does not carry over."""


@dataclass
class LuxScene:
    """A LuxCore scene as plain data (picklable for the child process).

    props: {property name: list of values} for ``pyluxcore.Properties``.
    meshes: {name: (verts (N, 3) float32, faces (M, 3) int32, normals (N, 3) float32 or None)}.
    images: {name: (H, W, 3) float32} image maps, row 0 = v 0.
    size: (width, height) of the film in pixels.
    filter_width: Blackman-Harris half-support in pixels.
    """
    props: dict = field(default_factory=dict)
    meshes: dict = field(default_factory=dict)
    images: dict = field(default_factory=dict)
    size: tuple = (64, 64)
    filter_width: float = 1.5


# --- unit conversions ---------------------------------------------------------

def area_radiance(strength, area: float) -> np.ndarray:
    """Radiance [W/(m^2 sr)] of a one-sided Lambertian area light of Cycles
    strength S [W] and area A [m^2]: L = S / (pi A) (docs/cycles_units.md)."""
    return np.asarray(strength, np.float64) / (math.pi * area)


def spot_profile(theta: np.ndarray, spot_size: float, blend: float) -> np.ndarray:
    """Cycles' spot attenuation at angle theta [rad] from the spot's axis:
    smoothstep((cos theta - cos(size/2)) / ((1 - cos(size/2)) blend))."""
    from fppm.core.lights.table import _smoothstep
    cos_h = math.cos(0.5 * spot_size)
    w = (1.0 - cos_h) * blend
    x = np.cos(theta) - cos_h
    return _smoothstep(x / w) if w > 0 else (x > 0).astype(np.float64)


def lux_map_average(profile) -> float:
    """LuxCore's ``SampleableSphericalFunction::Average`` of a map f(theta)
    (independent of phi): 4 pi sum_j f(theta_j) sin theta_j / sum_j sin theta_j
    at the row midpoints theta_j of its 512 x 256 grid, ~ int f d omega."""
    rows = LUX_SPHERE_GRID[1]
    th = math.pi * (np.arange(rows) + 0.5) / rows
    s = np.sin(th)
    return float(4.0 * math.pi * np.sum(profile(th) * s) / np.sum(s))


def spot_gain(strength, spot_size: float, blend: float) -> np.ndarray:
    """``color`` of a LuxCore mappoint / mapsphere carrying Cycles' spot of
    strength S.  LuxCore emits I(w) = color f(w) / (4 pi avg) (mappoint) and
    radiance color f(w) / (4 pi^2 r^2 avg) (mapsphere); Cycles I(w) =
    S smoothstep(w) / (4 pi): so color = S avg with f = the smoothstep map."""
    avg = lux_map_average(lambda th: spot_profile(th, spot_size, blend))
    return np.asarray(strength, np.float64) * avg


def spot_map(spot_size: float, blend: float, rows: int = SPOT_MAP_ROWS) -> np.ndarray:
    """(rows, 4, 3) float32 equirectangular map of the spot profile around local
    +Z, row j at theta = pi (j + 0.5) / rows (LuxCore's v = theta / pi)."""
    th = math.pi * (np.arange(rows) + 0.5) / rows
    f = spot_profile(th, spot_size, blend).astype(np.float32)
    return np.repeat(np.repeat(f[:, None, None], 4, axis=1), 3, axis=2)


# --- translation --------------------------------------------------------------

def _column_major(m: np.ndarray) -> list:
    """LuxCore's ``transformation`` property: 16 floats, column after column."""
    return [float(v) for v in np.asarray(m, np.float64).T.ravel()]


def _rotation(m: np.ndarray) -> np.ndarray:
    """The (3, 3) rotation of an object matrix (columns normalised)."""
    R = np.asarray(m, np.float64)[:3, :3]
    return R / np.maximum(np.linalg.norm(R, axis=0, keepdims=True), 1e-300)


def camera_props(cam) -> dict:
    """LuxCore camera properties reproducing Blender's projection (perspective only)."""
    if cam.kind != "PERSP":
        raise Unsupported(f"camera type {cam.kind}: only perspective cameras are translated")
    if cam.border is not None:
        raise Unsupported("a render border")
    from fppm.core.scene.camera import CameraModel
    cm = CameraModel(cam)
    W, H = cm.W, cm.H
    x0, y0 = cm.xmin, cm.ymin
    x1, y1 = x0 + W * cm.pix, y0 + H * cm.ycor * cm.pix
    # LuxCore's raster y is filmHeight - filmY - 1 (perspective.cpp), so pixel
    # row py (from the bottom) looks through the screen one pixel above its
    # centre: the window is lowered by one pixel to see what Blender's row sees.
    dy = cm.ycor * cm.pix
    y0, y1 = y0 - dy, y1 - dy
    fwd, up = -cm.R[:, 2], cm.R[:, 1]
    p = {
        "scene.camera.type": ["perspective"],
        "scene.camera.lookat.orig": list(map(float, cm.origin)),
        "scene.camera.lookat.target": list(map(float, cm.origin + fwd)),
        "scene.camera.up": list(map(float, up)),
        # fov 90 deg: tan(fov / 2) = 1, so the screen window is the view plane at depth 1.
        "scene.camera.fieldofview": [90.0],
        "scene.camera.screenwindow": [float(x0), float(x1), float(y0), float(y1)],
        "scene.camera.cliphither": [float(cam.clip_start)],
        "scene.camera.clipyon": [float(cam.clip_end)],
    }
    if cam.aperture_radius > 0:
        p["scene.camera.lensradius"] = [float(cam.aperture_radius)]
        p["scene.camera.focaldistance"] = [float(cam.focus_distance)]
    return p


def material_props(name: str, mat) -> dict:
    """LuxCore properties of one flattened material (single-lobe matte, mirror, glass)."""
    from fppm.core.scene.model import DIFFUSE, GLASS, GLOSSY
    pre = f"scene.materials.{name}"
    if any(v > 0 for v in mat.emission):
        raise Unsupported(f"material '{mat.name}': an Emission closure on a mesh (Cycles emits "
                          f"it on both sides, LuxCore on one)")
    if mat.normal is not None or mat.emission_texture >= 0:
        raise Unsupported(f"material '{mat.name}': normal maps or emission textures")
    if len(mat.lobes) != 1:
        raise Unsupported(f"material '{mat.name}': {len(mat.lobes)} mixed closures")
    lb = mat.lobes[0]
    if lb.color_texture >= 0 or lb.alpha_texture >= 0:
        raise Unsupported(f"material '{mat.name}': image textures")
    col = [float(c) * lb.weight for c in lb.color]
    if lb.kind == DIFFUSE and lb.roughness == 0 and lb.layer_ior == 0:
        return {f"{pre}.type": ["matte"], f"{pre}.kd": col}
    if lb.kind == GLOSSY and lb.roughness == 0 and not lb.fresnel:
        return {f"{pre}.type": ["mirror"], f"{pre}.kr": col}
    if lb.kind == GLASS and lb.roughness == 0:
        return {f"{pre}.type": ["glass"], f"{pre}.kr": col, f"{pre}.kt": col,
                f"{pre}.exteriorior": [1.0], f"{pre}.interiorior": [float(lb.ior)]}
    raise Unsupported(f"material '{mat.name}': closure {lb.kind} with roughness {lb.roughness} "
                      f"(only Lambert, perfect mirror and smooth glass are translated)")


def area_light_mesh(lt) -> tuple[np.ndarray, np.ndarray, float]:
    """World (verts (N, 3), faces (M, 3), area) of an area light, facing its local -Z."""
    if lt.shape in ("SQUARE", "RECTANGLE"):
        sx, sy = lt.size, (lt.size if lt.shape == "SQUARE" else lt.size_y)
        # Clockwise seen from +Z: the winding's normal is local -Z.
        loc = np.array([[-sx, -sy], [-sx, sy], [sx, sy], [sx, -sy]]) * 0.5
    elif lt.shape in ("DISK", "ELLIPSE"):
        sx, sy = lt.size, (lt.size if lt.shape == "DISK" else lt.size_y)
        a = -2.0 * math.pi * np.arange(DISC_SIDES) / DISC_SIDES
        loc = np.stack([0.5 * sx * np.cos(a), 0.5 * sy * np.sin(a)], axis=1)
    else:
        raise Unsupported(f"area light shape {lt.shape}")
    M = np.asarray(lt.matrix_world, np.float64)
    P = np.concatenate([loc, np.zeros((len(loc), 1)), np.ones((len(loc), 1))], axis=1) @ M.T
    verts = P[:, :3]
    faces = np.array([[0, i, i + 1] for i in range(1, len(loc) - 1)], np.int32)
    ng = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    down = -M[:3, 2]
    if ng.sum(axis=0) @ down < 0:                  # a mirroring matrix: keep facing local -Z
        faces = faces[:, ::-1].copy()
    area = 0.5 * float(np.linalg.norm(ng, axis=1).sum())
    return verts.astype(np.float32), faces, area


def light_props(i: int, lt, lux: LuxScene) -> None:
    """Add light ``lt`` (Cycles units) to ``lux`` as LuxCore light(s)."""
    name = f"light{i}"
    pre = f"scene.lights.{name}"
    S = np.asarray(lt.strength, np.float64)
    if not lt.cast_shadow:
        raise Unsupported(f"light '{lt.name}': shadows off")
    if lt.kind in ("POINT", "SPOT") and lt.radius > 0 and lt.visible_camera:
        raise Unsupported(f"light '{lt.name}': a {lt.kind.lower()} with a radius seen by the "
                          f"camera (LuxCore's sphere lights are not)")
    pos = list(map(float, np.asarray(lt.matrix_world)[:3, 3]))
    if lt.kind == "POINT":
        if lt.radius > 0:
            lux.props.update({f"{pre}.type": ["sphere"], f"{pre}.radius": [float(lt.radius)]})
        else:
            lux.props[f"{pre}.type"] = ["point"]
        lux.props.update({f"{pre}.position": pos, f"{pre}.color": list(map(float, S))})
    elif lt.kind == "SPOT":
        R = _rotation(lt.matrix_world)
        lin = np.asarray(lt.matrix_world, np.float64)[:3, :3]
        sc = np.linalg.norm(lin, axis=0)
        if not np.allclose(sc[:2], sc[0], rtol=1e-6):
            raise Unsupported(f"spot '{lt.name}': non-uniform scale (an elliptic cone)")
        # Local +Z of the LuxCore map = the spot's axis, Blender's local -Z.
        T = np.eye(4)
        T[:3, :3] = R @ np.diag([1.0, -1.0, -1.0])
        T[:3, 3] = pos
        img = f"spotmap{i}"
        lux.images[img] = spot_map(lt.spot_size, lt.spot_blend)
        kind = "mapsphere" if lt.radius > 0 else "mappoint"
        lux.props.update({f"{pre}.type": [kind], f"{pre}.mapfile": [img],
                          f"{pre}.transformation": _column_major(T),
                          f"{pre}.color": list(map(float, spot_gain(S, lt.spot_size,
                                                                    lt.spot_blend)))})
        if lt.radius > 0:
            lux.props[f"{pre}.radius"] = [float(lt.radius)]
    elif lt.kind == "SUN":
        if lt.angle > 0:
            raise Unsupported(f"sun '{lt.name}': angle > 0 (LuxCore's 'distant' light "
                              f"converts its theta to radians twice, distantlight.cpp)")
        d = -np.asarray(lt.matrix_world, np.float64)[:3, 2]
        d /= np.linalg.norm(d)
        lux.props.update({f"{pre}.type": ["sharpdistant"], f"{pre}.direction": list(map(float, d)),
                          f"{pre}.color": list(map(float, S))})
    elif lt.kind == "AREA":
        if lt.spread < math.pi - 1e-6:
            raise Unsupported(f"area light '{lt.name}': spread below 180 deg")
        verts, faces, area = area_light_mesh(lt)
        mname, shape = f"lightmat{i}", f"lightmesh{i}"
        L = area_radiance(S, area)
        mp = f"scene.materials.{mname}"
        lux.props.update({f"{mp}.type": ["matte"], f"{mp}.kd": [0.0, 0.0, 0.0],
                          f"{mp}.emission": list(map(float, L)),
                          f"{mp}.emission.gain": [1.0, 1.0, 1.0],
                          f"{mp}.emission.power": [0.0], f"{mp}.emission.efficency": [0.0]})
        lux.meshes[shape] = (verts, faces, None)
        op = f"scene.objects.{shape}"
        lux.props.update({f"{op}.shape": [shape], f"{op}.material": [mname],
                          f"{op}.camerainvisible": [not lt.visible_camera]})
    else:
        raise Unsupported(f"light '{lt.name}' of kind {lt.kind}")


def translate(scene) -> LuxScene:
    """FPPM's exported ``scene`` as a :class:`LuxScene`; raises Unsupported."""
    if scene.world_map is not None:
        raise Unsupported("an environment texture world")
    if scene.textures:
        raise Unsupported("image textures")
    if scene.film_transparent:
        raise Unsupported("Film > Transparent")
    lux = LuxScene(size=tuple(int(v) for v in scene.camera.resolution),
                   filter_width=float(scene.filter_width))
    lux.props.update(camera_props(scene.camera))
    used = np.unique(scene.tri_mat)
    for m in used:
        lux.props.update(material_props(f"mat{m}", scene.materials[m]))
        lux.props[f"scene.materials.mat{m}.id"] = [int(m)]
        sel = scene.tri_mat == m
        P = scene.tri_p[sel].reshape(-1, 3).astype(np.float32)
        N = scene.tri_n[sel].reshape(-1, 3).astype(np.float32)
        F = np.arange(P.shape[0], dtype=np.int32).reshape(-1, 3)
        lux.meshes[f"mesh{m}"] = (P, F, N)
        lux.props.update({f"scene.objects.mesh{m}.shape": [f"mesh{m}"],
                          f"scene.objects.mesh{m}.material": [f"mat{m}"]})
    for i, lt in enumerate(scene.lights):
        light_props(i, lt, lux)
    wc = np.asarray(scene.world_color, np.float64)
    if np.any(wc > 0):
        lux.props.update({"scene.lights.world.type": ["constantinfinite"],
                          "scene.lights.world.color": list(map(float, wc))})
    return lux


def config_props(lux: LuxScene, engine: str, seed: int, threads: int = 2) -> dict:
    """Render configuration of ``engine`` (a key of ENGINES) for ``lux``."""
    W, H = lux.size
    p = {"native.threads.count": threads, "renderengine.seed": seed + 1,
         "film.width": W, "film.height": H,
         "film.filter.type": "BLACKMANHARRIS", "film.filter.width": lux.filter_width,
         "film.outputs.0.type": "RGB", "film.outputs.0.filename": "image.exr",
         "film.imagepipelines.0.0.type": "NOP",
         "path.pathdepth.total": MAX_DEPTH, "path.pathdepth.diffuse": MAX_DEPTH,
         "path.pathdepth.glossy": MAX_DEPTH, "path.pathdepth.specular": MAX_DEPTH,
         "path.maxdepth": MAX_DEPTH, "light.maxdepth": MAX_DEPTH}
    p.update(ENGINES[engine])
    return p


# --- rendering with pyluxcore (child process) ----------------------------------

def have_pyluxcore() -> bool:
    """Whether pyluxcore is installed (without importing it: its TBB allocator
    must not share a process with bpy, so only the child imports it)."""
    import importlib.util
    return importlib.util.find_spec("pyluxcore") is not None


def import_pyluxcore():
    if not have_pyluxcore():
        raise SystemExit(INSTALL_HINT)
    import pyluxcore
    return pyluxcore


def build_scene(pyluxcore, lux: LuxScene):
    """A ``pyluxcore.Scene`` from ``lux``."""
    sc = pyluxcore.Scene()
    for name, img in lux.images.items():
        h, w, c = img.shape
        sc.DefineImageMap(name, np.ascontiguousarray(img, np.float32).ravel(), 1.0, c, w, h)
    for name, (P, F, N) in lux.meshes.items():
        sc.DefineMesh(name, [tuple(v) for v in P.tolist()], [tuple(f) for f in F.tolist()],
                      None if N is None else [tuple(n) for n in N.tolist()], None, None, None)
    props = pyluxcore.Properties()
    for k, v in lux.props.items():
        props.Set(pyluxcore.Property(k, v))
    sc.Parse(props)
    return sc


def cpu_self() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def render_here(lux: LuxScene, engine: str, seed: int, cpu_budget: float,
                threads: int = 2, outputs=("RGB",), extra=None) -> dict:
    """Render in this process until its CPU time reaches ``cpu_budget`` seconds
    (or a halt condition of ``extra``, config properties over config_props').

    Returns {"img": (H, W, 3) float64 row 0 at the top, "spp", "cpu", "wall"}
    and one (H, W, C) array per extra output name (e.g. "POSITION")."""
    pyluxcore = import_pyluxcore()
    pyluxcore.Init()
    w0 = time.perf_counter()
    cfg = pyluxcore.Properties()
    for k, v in dict(config_props(lux, engine, seed, threads), **(extra or {})).items():
        cfg.Set(pyluxcore.Property(k, v))
    for j, name in enumerate(outputs[1:], start=1):
        cfg.Set(pyluxcore.Property(f"film.outputs.{j}.type", name))
        ext = "png" if name.endswith("_ID") else "exr"    # LuxCore's rule for ID outputs
        cfg.Set(pyluxcore.Property(f"film.outputs.{j}.filename", f"{name}.{ext}"))
    session = pyluxcore.RenderSession(pyluxcore.RenderConfig(cfg, build_scene(pyluxcore, lux)))
    started = threading.Event()

    def watchdog():
        # Start() builds the photon caches before it returns: with no caustic
        # path in the scene the caustic cache traces photons for ever.
        while not started.wait(0.1):
            if cpu_self() > 2 * cpu_budget + 10:
                print(f"LuxCore did not start within {cpu_self():.0f} CPU s", file=sys.stderr)
                os._exit(3)
    threading.Thread(target=watchdog, daemon=True).start()
    session.Start()
    started.set()
    while cpu_self() < cpu_budget and not session.HasDone():
        time.sleep(0.02)
        session.UpdateStats()
    session.Stop()
    spp = session.GetStats().Get("stats.renderengine.pass").GetInt()
    W, H = lux.size
    film = session.GetFilm()
    out = {"spp": spp, "cpu": cpu_self(), "wall": time.perf_counter() - w0}
    for name in outputs:
        kind = getattr(pyluxcore.FilmOutputType, name)
        ids = name in ("MATERIAL_ID", "OBJECT_ID")
        buf = np.zeros((H, W, film.GetOutputSize(kind) // (W * H)),
                       np.uint32 if ids else np.float32)
        (film.GetOutputUInt if ids else film.GetOutputFloat)(kind, buf)
        # LuxCore's film rows run from the bottom (raster y up); FPPM's from the top.
        out["img" if name == "RGB" else name] = buf[::-1] if ids else buf[::-1].astype(np.float64)
    return out


def render_luxcore(lux: LuxScene, engine: str, seed: int, cpu_budget: float,
                   outputs=("RGB",), extra=None) -> dict:
    """:func:`render_here` in a child process; ``cpu`` = the child's CPU seconds
    measured by this process (RUSAGE_CHILDREN)."""
    with tempfile.TemporaryDirectory() as tmp:
        job, res = os.path.join(tmp, "job.pkl"), os.path.join(tmp, "out.pkl")
        with open(job, "wb") as f:
            pickle.dump((vars(lux), engine, seed, cpu_budget, outputs, extra), f)
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        proc = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", job, res],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode != 0:
            raise RuntimeError(f"LuxCore child failed ({proc.returncode}): {proc.stderr[-2000:]}")
        with open(res, "rb") as f:
            out = pickle.load(f)
    out["cpu"] = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return out


def _child(job: str, res: str) -> None:
    with open(job, "rb") as f:
        fields, engine, seed, budget, outputs, extra = pickle.load(f)
    out = render_here(LuxScene(**fields), engine, seed, budget, outputs=outputs, extra=extra)
    with open(res, "wb") as f:
        pickle.dump(out, f)


# --- scenes and references (bpy) ----------------------------------------------

def load_scene(blend: str, pct: int):
    """FPPM's exported scene of ``blend`` at ``pct`` % (the F12 scene, no UI)."""
    import bpy

    from fppm.addon.cli import open_blend
    from fppm.addon.export import export_scene
    open_blend(blend, resolution=pct)
    return export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)


def reference(blend: str, pct: int) -> np.ndarray:
    """(H, W, 3) float64 reference: Cycles 8192 spp (cached), or Mitsuba's light
    tracer for point_caustic (bench/converge_examples.py's file)."""
    import bpy

    from fppm.addon.cli import open_blend
    from fppm.tools.converge.references import cache_dir, load_reference, make_reference
    name = os.path.splitext(os.path.basename(blend))[0]
    if name == "point_caustic":
        path = os.path.join(cache_dir(), "point_caustic_mitsuba_ptracer_65536.exr")
        if not os.path.isfile(path):
            raise SystemExit(f"no reference {path}: make it with bench/point_caustic_reference.py")
        img = load_reference(path)["image"]
        if pct != 100:
            raise SystemExit("point_caustic's reference is 128x128: use --pct 100")
        return img
    return make_reference(bpy, open_blend(blend, resolution=pct), blend, 8192,
                          lambda s: print(s, flush=True),
                          lambda s, force=False: print(s, flush=True))["image"]


# --- commands -----------------------------------------------------------------

def _arg(argv, flag, default):
    return type(default)(argv[argv.index(flag) + 1]) if flag in argv else default


def cmd_units(argv) -> None:
    """A long LuxCore render against the reference: the image mean ratio."""
    from fppm.tools.metrics import relmse
    blend = argv[0]
    pct, cpu = _arg(argv, "--pct", 50), _arg(argv, "--cpu", 240.0)
    engine = _arg(argv, "--engine", "lux_bidirvm")
    lux = translate(load_scene(blend, pct))
    ref = reference(blend, pct)
    out = render_luxcore(lux, engine, 1, cpu)
    img = out["img"]
    print(f"UNITS {os.path.basename(blend)} {engine} {out['spp']} spp, {out['cpu']:.0f} CPU s: "
          f"mean ratio LuxCore / reference {img.mean() / ref.mean():.4f} "
          f"(R {img[..., 0].mean() / ref[..., 0].mean():.4f} "
          f"G {img[..., 1].mean() / ref[..., 1].mean():.4f} "
          f"B {img[..., 2].mean() / ref[..., 2].mean():.4f}), relMSE {relmse(img, ref):.3e}",
          flush=True)
    np.save(os.path.join(tempfile.gettempdir(),
                         f"lux_{os.path.basename(blend)}_{pct}_{engine}.npy"), img)


def cmd_compare(argv) -> None:
    """relMSE of LuxCore's engines and FPPM's integrators at equal CPU time."""
    from fppm.tools.metrics import relmse
    blend = argv[0]
    pct, budget = _arg(argv, "--pct", 50), _arg(argv, "--budget", 30.0)
    seeds = _arg(argv, "--seeds", 2)
    lux_runs = _arg(argv, "--lux", "lux_pathlt,lux_bidirvm,lux_caustic").split(",")
    fppm_runs = _arg(argv, "--fppm", ",".join(FPPM_RUNS)).split(",")
    lux = translate(load_scene(blend, pct))
    specular = any(v in (["mirror"], ["glass"]) for v in lux.props.values())
    if "lux_caustic" in lux_runs and not specular:
        lux_runs.remove("lux_caustic")
        print("SKIP lux_caustic: no mirror or glass, so no caustic for the cache", flush=True)
    ref = reference(blend, pct)
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    from measure_cpu import render_cpu
    err = {}
    for seed in range(seeds):
        for run in fppm_runs:
            last = render_cpu(blend, pct, budget, run, seed=7 + seed)
            err.setdefault(run, []).append(relmse(last["img"], ref))
            print(f"RUN {run} seed {seed} cpu {last['cpu']:.1f} s passes {last['n']} "
                  f"relMSE {err[run][-1]:.3e} mean ratio {last['img'].mean() / ref.mean():.4f}",
                  flush=True)
        for run in lux_runs:
            out = render_luxcore(lux, run, seed, budget)
            err.setdefault(run, []).append(relmse(out["img"], ref))
            print(f"RUN {run} seed {seed} cpu {out['cpu']:.1f} s spp {out['spp']} "
                  f"relMSE {err[run][-1]:.3e} mean ratio {out['img'].mean() / ref.mean():.4f}",
                  flush=True)
    load = os.getloadavg()
    print(f"\n{os.path.basename(blend)} at {pct}%, {budget:g} CPU s each, seeds {seeds}, "
          f"load average {load[0]:.1f}")
    best = {run: float(np.mean(e)) for run, e in err.items()}
    for lr in lux_runs:
        cells = "  ".join(f"{fr} {best[fr] / best[lr]:.2f}x" for fr in fppm_runs)
        print(f"TABLE {lr} relMSE {best[lr]:.3e} (seeds {' '.join(f'{e:.2e}' for e in err[lr])}); "
              f"FPPM / LuxCore: {cells}")
    for fr in fppm_runs:
        print(f"TABLE {fr} relMSE {best[fr]:.3e} (seeds {' '.join(f'{e:.2e}' for e in err[fr])})")


def main(argv) -> int:
    if argv and argv[0] == "--child":
        _child(argv[1], argv[2])
        return 0
    if len(argv) < 2 or argv[0] not in ("units", "compare"):
        print(__doc__)
        return 2
    if not have_pyluxcore():
        print(INSTALL_HINT, file=sys.stderr)
        return 2
    try:
        {"units": cmd_units, "compare": cmd_compare}[argv[0]](argv[1:])
    except Unsupported as ex:
        print(f"error: this scene cannot be translated to LuxCore: {ex}.", file=sys.stderr)
        return 4
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
