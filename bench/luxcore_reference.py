"""References from LuxCoreRender for the small-light caustic scenes.

bench/converge_examples.py uses coffee_cup's VCM (BIDIRVMCPU) reference and
glass_sphere's composed one (:func:`compose`: LuxCore's light tracer where
the camera sees a diffuse surface first, Cycles where it may see the glass
first).  glass_sphere's VCM reference was not kept: LuxCore's bidirectional
engines are biased with the translation's spot light (docs/peers.md
"References for the glass scenes").

    .venv/bin/python bench/luxcore_reference.py render  SCENE [--runs K] [--cpu S] [--engine E]
    .venv/bin/python bench/luxcore_reference.py finish  SCENE [--engine E]
    .venv/bin/python bench/luxcore_reference.py compose SCENE [--cycles N] [--engine lux_light]
    .venv/bin/python bench/luxcore_reference.py check   SCENE [--cycles N] [--fppm RUN:S,...] [--engine E]
    .venv/bin/python bench/luxcore_reference.py bisect  SCENE [--pct 50] [--cpu 12] [--variants V,...] [--engines E,...]

SCENE: glass_sphere or coffee_cup (any scene bench/peer_luxcore.py translates),
rendered at 100 % (128x128, what bench/converge_examples.py compares at).
Cycles cannot sample the caustic of a 5 cm spot seen through glass or in a
mirror (a camera path must hit the light through the specular surface): its
16384-spp references of these scenes are as noisy as the methods compared
against them.  VCM (vertex connection and merging) renders those paths by
merging, and the rest by light tracing and connections; light tracing
(LIGHTCPU) renders every path whose first camera vertex is diffuse.

``render`` renders K independent LuxCore renders (seeds 0..K-1, each S CPU
seconds of a child process, bench/peer_luxcore.py's ``render_luxcore``) and
keeps each in the cache folder (``<cache>/references/<scene>_luxcore/``);
runs already there are not rendered again, so a second call with a larger
K adds runs.  ``finish`` (run by ``render`` too) writes
``<cache>/references/<scene>_luxcore_<engine>.exr``: Combined = the mean of
the runs, Variance = (A - B)^2 / 4 with A, B the means of the even and odd
runs (the two independent halves ``fppm converge --reference`` reads, the
same floor as its Cycles references: ``tools.metrics.reference_floor``).
``compose`` writes ``<scene>_luxcore_light_cycles<N>.exr`` from the
``lux_light`` runs and ``fppm converge``'s cached Cycles reference of N spp
(rendered when missing).

``bisect`` renders variants of the scene (:func:`variant`: the glass made
diffuse, the world or the spot's radius taken out, ...) with LuxCore's
engines and prints their region means over PATHCPU's.

``check`` compares the reference per region (the regions of
``tools.metrics.region_masks`` and the material each pixel sees first,
LuxCore's MATERIAL_ID) with a Cycles render of N spp (``fppm converge``'s
cached reference) and with FPPM's renders (bench/measure_cpu.py run names,
S CPU seconds each): the ratio of region means and its standard error
(docs/peers.md "References for the glass scenes").  With ``--engine
lux_light`` or ``--engine composed`` (the sum of the parts of ``compose``)
every region is restricted to the pixels ``compose`` takes from LuxCore.

LuxCore's merging radius is its default (0.003 x the scene's bounding
sphere, shrinking with alpha 0.95): the merged paths (caustics seen through
glass or in the mirror) are blurred by about that radius, a bias the floor
of the two halves does not measure.
"""
from __future__ import annotations

import glob
import json
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))
sys.path.insert(0, os.path.join(ROOT, "tests"))
import fppm_alias  # noqa: E402,F401  (fppm.* importable, one numba cache)
import peer_luxcore as P  # noqa: E402

ENGINE = "lux_bidirvm"
PCT = 100


def _arg(argv, flag, default):
    return type(default)(argv[argv.index(flag) + 1]) if flag in argv else default


def _cache():
    from fppm.tools.converge.references import cache_dir
    return cache_dir()


def runs_dir(scene: str) -> str:
    return os.path.join(_cache(), f"{scene}_luxcore")


def _tag(engine: str) -> str:
    """A run name (``ENGINE`` or ``ENGINE:LIGHTS``) as a file-name part."""
    return engine.replace(":", "_")


def reference_path(scene: str, engine: str = ENGINE, runs: int = 2) -> str:
    """The reference file of ``runs`` runs bench/converge_examples.py reads (SCENES):
    ``<scene>_luxcore_<engine>.exr`` for 2 runs, ``..._<runs>runs.exr`` for more
    (a new file: the cache is shared, a reference in use is never rewritten)."""
    tag = "" if runs == 2 else f"_{runs}runs"
    return os.path.join(_cache(), f"{scene}_luxcore_{_tag(engine).removeprefix('lux_')}{tag}.exr")


def blend_of(scene: str) -> str:
    return os.path.join(ROOT, "example_blends", scene + ".blend")


def select_lights(lux, lights: str):
    """``lux`` with some of its lights: "all", "world" (the world light only) or
    "noworld" (every light but the world).  Light transport is linear in the
    emitters, so the renders of "world" and "noworld" add up to "all"."""
    if lights == "all":
        return lux
    if lights not in ("world", "noworld"):
        raise SystemExit(f"unknown light selection '{lights}' (all, world, noworld)")
    world = lights == "world"
    out = P.LuxScene(**{k: v for k, v in vars(lux).items() if k != "props"})
    out.props = {k: v for k, v in lux.props.items()
                 if not (k.startswith("scene.lights.") and
                         (k.startswith("scene.lights.world.") != world))}
    if world and any(k.endswith(".emission") for k in out.props):
        raise SystemExit("'world' with emissive meshes: not supported")
    return out


def render(scene: str, runs: int, cpu: float, engine: str = ENGINE) -> None:
    """``engine``: a key of peer_luxcore.ENGINES, or ``ENGINE:LIGHTS`` to render
    only some lights (:func:`select_lights`)."""
    eng, _, lights = engine.partition(":")
    lux = select_lights(P.translate(P.load_scene(blend_of(scene), PCT)), lights or "all")
    d = runs_dir(scene)
    os.makedirs(d, exist_ok=True)
    for seed in range(runs):
        path = os.path.join(d, f"{_tag(engine)}_seed{seed}.npz")
        if os.path.isfile(path):
            continue
        out = P.render_luxcore(lux, eng, seed, cpu)
        np.savez(path, img=out["img"], spp=out["spp"], cpu=out["cpu"])
        print(f"run seed {seed}: {out['spp']} spp, {out['cpu']:.1f} CPU s, "
              f"mean {out['img'].mean():.5f}, load {os.getloadavg()[0]:.1f}", flush=True)
    finish(scene, engine)


def load_runs(scene: str, engine: str = ENGINE) -> list[dict]:
    """The kept runs, by seed (an even number: the last odd one is left out)."""
    paths = glob.glob(os.path.join(runs_dir(scene), f"{_tag(engine)}_seed*.npz"))
    seeds = sorted(int(os.path.basename(p).split("seed")[1].split(".")[0]) for p in paths)
    runs = [dict(np.load(os.path.join(runs_dir(scene), f"{_tag(engine)}_seed{s}.npz")))
            for s in seeds]
    return runs[: len(runs) // 2 * 2]


def runs_mean(scene: str, engine: str = ENGINE):
    """(mean, per-pixel variance of the mean, spp, CPU s, runs) of the kept runs:
    Variance = (A - B)^2 / 4 with A, B the means of the even and odd runs."""
    runs = load_runs(scene, engine)
    if len(runs) < 2:
        raise SystemExit(f"{scene}: fewer than 2 runs of {engine} in {runs_dir(scene)}")
    a = np.mean([r["img"] for r in runs[0::2]], axis=0)
    b = np.mean([r["img"] for r in runs[1::2]], axis=0)
    spp = int(sum(int(r["spp"]) for r in runs))
    cpu = float(sum(float(r["cpu"]) for r in runs))
    return 0.5 * (a + b), 0.25 * (a - b) ** 2, spp, cpu, len(runs)


def finish(scene: str, engine: str = ENGINE) -> None:
    from fppm.core.io.exr import write_exr
    from fppm.tools.metrics import reference_floor
    ref, var, spp, cpu, n = runs_mean(scene, engine)
    meta = {"source": f"LuxCoreRender {engine} (bench/luxcore_reference.py)", "runs": n,
            "samples": spp, "cpu_seconds": round(cpu, 1)}
    path = reference_path(scene, engine, n)
    write_exr(path, {"Combined": ref.astype(np.float32), "Variance": var.astype(np.float32)},
              {"fppm:reference": json.dumps(meta)})
    print(f"wrote {path}: {n} runs, {spp} spp, {cpu:.0f} CPU s, "
          f"relMSE floor {reference_floor(ref, var):.3g}", flush=True)


#: The parts of the composed reference (:func:`compose`): LuxCore's light
#: tracer with every light but the world, its path tracer with the world only.
COMPOSE_PARTS = ("lux_light:noworld", "lux_path:world")


def composed_path(scene: str, cycles: int) -> str:
    """The composed reference file (:func:`compose`) bench/converge_examples.py reads."""
    return os.path.join(_cache(), f"{scene}_luxcore_light_cycles{cycles}_firsthit.exr")


def first_hit_ids(lux) -> np.ndarray:
    """(H, W) material index each pixel sees first: PATHCPU's camera rays fill
    every pixel of LuxCore's MATERIAL_ID output (VCM's and LIGHTCPU's do not)."""
    return P.render_luxcore(lux, "lux_path", 99, 3.0,
                            outputs=("RGB", "MATERIAL_ID"))["MATERIAL_ID"][..., 0]


def specular_first(lux, ids: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose filter footprint may see a mirror or glass first.

    A pixel's samples reach +-filter_width pixels from its centre, so a pixel
    within ceil(filter_width + 1/2) pixels (Chebyshev) of a pixel whose centre
    sees the specular material is counted: light tracing misses part of it."""
    spec = [int(k.split(".")[2].removeprefix("mat")) for k, v in lux.props.items()
            if k.startswith("scene.materials.mat") and k.endswith(".type")
            and v in (["glass"], ["mirror"])]
    m = np.isin(ids, spec)
    r = int(np.ceil(lux.filter_width + 0.5))
    out = m.copy()
    H, W = m.shape
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            out[max(dy, 0):H + min(dy, 0), max(dx, 0):W + min(dx, 0)] |= \
                m[max(-dy, 0):H + min(-dy, 0), max(-dx, 0):W + min(-dx, 0)]
    return out


def specular_names(exported, lux) -> set[str]:
    """Names of the materials the translation made glass or mirror."""
    return {exported.materials[int(k.split(".")[2].removeprefix("mat"))].name
            for k, v in lux.props.items()
            if k.startswith("scene.materials.mat") and k.endswith(".type")
            and v in (["glass"], ["mirror"])}


def hold_out_for_camera(bpy, names, keep: bool) -> None:
    """Make a holdout for camera rays of every material of the open file named
    in ``names`` (keep False) or not named there (keep True): a camera ray that
    hits it first adds nothing, every later vertex shades as before (Cycles'
    Light Path "Is Camera Ray" mixing the surface with a Holdout)."""
    for m in bpy.data.materials:
        if m.node_tree is None or (m.name in names) == keep:
            continue
        nt = m.node_tree
        out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output)
        if not out.inputs["Surface"].links:
            continue
        src = out.inputs["Surface"].links[0].from_socket
        lp, ho = nt.nodes.new("ShaderNodeLightPath"), nt.nodes.new("ShaderNodeHoldout")
        mix = nt.nodes.new("ShaderNodeMixShader")
        nt.links.new(lp.outputs["Is Camera Ray"], mix.inputs["Fac"])
        nt.links.new(src, mix.inputs[1])
        nt.links.new(ho.outputs[0], mix.inputs[2])
        nt.links.new(mix.outputs[0], out.inputs["Surface"])


def cycles_by_first_hit(scene: str, cycles: int, specular: set[str]):
    """(image, variance of the mean, specular-first part) (H, W, 3) float64 of
    Cycles' paths that light tracing does not render: every path whose camera
    ray hits a material of ``specular`` (or nothing) first, lit by every
    light (the third array), plus every path whose camera ray hits another
    material first, lit by the world only.  Each of the two is rendered in
    two halves of ``cycles``/2 spp (seeds REF_SEEDS; variance (A - B)^2 / 4
    summed)."""
    import bpy

    from fppm.addon.cli import open_blend
    from fppm.tools.converge.cycles_worker import cycles_reference_setup
    from fppm.tools.converge.references import REF_SEEDS, cycles_render, layer
    img = var = first = 0.0
    for part in ("specular first", "world, diffuse first"):
        open_blend(blend_of(scene), resolution=PCT)
        sc = bpy.context.scene
        cycles_reference_setup(sc)
        if part == "specular first":
            hold_out_for_camera(bpy, specular, keep=True)
        else:
            hold_out_for_camera(bpy, specular, keep=False)
            for ob in sc.objects:
                if ob.type == "LIGHT":
                    ob.hide_render = True
            if sc.world is not None:
                sc.world.cycles_visibility.camera = False
        halves = []
        for seed in REF_SEEDS:
            lay, dt = cycles_render(bpy, sc, max(1, cycles // 2), seed)
            halves.append(layer(lay, "Combined")[..., :3].astype(np.float64))
            print(f"  Cycles, {part}: {cycles // 2} spp (seed {seed}) in {dt:.0f} s", flush=True)
        part_img = 0.5 * (halves[0] + halves[1])
        first = part_img if part == "specular first" else first
        img = img + part_img
        var = var + 0.25 * (halves[0] - halves[1]) ** 2
    return img, var, first


def compose(scene: str, cycles: int, parts=COMPOSE_PARTS) -> None:
    """The sum of LuxCore renders ``parts`` where the camera sees a diffuse
    surface first, and, where it may see glass or a mirror first, LuxCore's
    light-traced parts plus Cycles' paths that light tracing does not render
    (:func:`cycles_by_first_hit`; docs/peers.md "References for the glass
    scenes").

    LuxCore's bidirectional engines (BIDIRCPU, BIDIRVMCPU) are biased with the
    translation's spot (mapsphere / mappoint) and sphere lights, LIGHTCPU
    renders the world light (constantinfinite) a few per cent too dark, and
    PATHCPU misses the small spot's light through the glass.  So the spot and
    the other lights come from the light tracer, which renders every path
    whose first camera vertex is diffuse (the caustic seen directly
    included), and the world from the path tracer.  A pixel whose filter
    footprint may see the specular surface first also has paths the light
    tracer cannot connect through it; Cycles renders those, with the diffuse
    surfaces held out for camera rays, so that the caustic those pixels see
    directly on the floor (which Cycles cannot sample) still comes from the
    light tracer."""
    import bpy  # noqa: F401

    from fppm.core.io.exr import write_exr
    from fppm.tools.metrics import reference_floor
    got = [runs_mean(scene, e) for e in parts]
    ref = sum(g[0] for g in got)
    var = sum(g[1] for g in got)
    light = [g for e, g in zip(parts, got) if e.split(":")[0] == "lux_light"]
    exported = P.load_scene(blend_of(scene), PCT)
    lux = P.translate(exported)
    mask = specular_first(lux, first_hit_ids(lux))
    c_img, c_var, c_first = cycles_by_first_hit(scene, cycles, specular_names(exported, lux))
    img = np.where(mask[..., None], c_img + sum(g[0] for g in light), ref)
    v = np.where(mask[..., None], c_var + sum(g[1] for g in light), var)
    desc = " + ".join(f"{e} ({g[4]} runs, {g[2]} spp, {g[3]:.0f} CPU s)"
                      for e, g in zip(parts, got))
    meta = {"source": f"LuxCoreRender {desc} (bench/luxcore_reference.py compose); on the "
                      f"{int(mask.sum())} pixels that may see a specular surface first, the "
                      f"light-traced parts plus Cycles {cycles} spp of the paths whose camera "
                      f"ray hits the specular surface first and of the world's other paths",
            "runs": min(g[4] for g in got), "samples": sum(g[2] for g in got),
            "cpu_seconds": round(sum(g[3] for g in got), 1), "cycles_samples": cycles,
            "cycles_pixels": int(mask.sum())}
    path = composed_path(scene, cycles)
    # Trusted: no camera sample of the pixel met the glass first.  Cycles
    # samples the light through the glass by rare hits of the small light, so
    # where it does the two halves' spread understates the error (4096 against
    # 16384 spp: docs/peers.md "The composed reference's margin, round 34").
    trusted = ~(mask & (c_first.sum(axis=-1) > 0.0))
    meta["trusted_pixels"] = int(trusted.sum())
    write_exr(path, {"Combined": img.astype(np.float32), "Variance": v.astype(np.float32),
                     "Trusted": trusted.astype(np.float32)[..., None]},
              {"fppm:reference": json.dumps(meta)})
    k = mask.sum() / mask.size
    print(f"wrote {path}: {desc}; relMSE floor {reference_floor(img, v):.3g} = LuxCore "
          f"{reference_floor(img, v, ~mask) * (1 - k):.3g} ({int((~mask).sum())} px) + "
          f"composed {reference_floor(img, v, mask) * k:.3g} ({int(mask.sum())} px); trusted "
          f"{int(trusted.sum())} px, floor over them {reference_floor(img, v, trusted):.3g}",
          flush=True)


def variant(lux, name: str):
    """A copy of ``lux`` changed by ``name`` ("+"-joined parts) for bisecting a
    bias of LuxCore's engines (docs/peers.md "References for the glass scenes"):
    "asis"; "matte" (glass and mirror -> Lambert 0.8); "noworld" / "world"
    (:func:`select_lights`); "point" (mapsphere -> mappoint: the spot without
    its radius); "plainsphere" / "plainpoint" (the spot -> an isotropic sphere
    light of its radius / a point light, 40 W)."""
    import copy
    lux = copy.deepcopy(lux)
    for part in name.split("+"):
        spots = [k[:-5] for k, v in lux.props.items() if k.startswith("scene.lights.")
                 and k.endswith(".type") and v in (["mapsphere"], ["mappoint"])]
        if part == "asis":
            pass
        elif part == "matte":
            for k in [k for k, v in lux.props.items() if k.endswith(".type")
                      and v in (["glass"], ["mirror"])]:
                pre = k[:-5]
                mid = lux.props[pre + ".id"]
                for kk in [x for x in lux.props if x.startswith(pre + ".")]:
                    del lux.props[kk]
                lux.props.update({k: ["matte"], pre + ".kd": [0.8] * 3, pre + ".id": mid})
        elif part in ("world", "noworld"):
            lux = select_lights(lux, part)
        elif part == "point":
            for pre in spots:
                lux.props[pre + ".type"] = ["mappoint"]
                lux.props.pop(pre + ".radius", None)
        elif part in ("plainsphere", "plainpoint"):
            for pre in spots:
                pos, r = lux.props[pre + ".transformation"][12:15], lux.props.get(pre + ".radius")
                for kk in [x for x in lux.props if x.startswith(pre + ".")]:
                    del lux.props[kk]
                lux.props.update({pre + ".position": pos, pre + ".color": [40.0] * 3})
                if part == "plainsphere" and r:
                    lux.props.update({pre + ".type": ["sphere"], pre + ".radius": r})
                else:
                    lux.props[pre + ".type"] = ["point"]
        else:
            raise SystemExit(f"unknown variant part '{part}'")
    return lux


def bisect(scene: str, pct: int, cpu: float, variants: list[str], engines: list[str]) -> None:
    """Region means of ``engines`` / PATHCPU's on each variant (one seed, ``cpu``
    CPU s a render).  Regions: the pixels that see the wall, the sphere, the
    floor brighter / darker than half the floor's median on PATHCPU's render of
    the first variant, and the dark floor's interior (3 pixels from the lit)."""
    base = P.translate(P.load_scene(blend_of(scene), pct))
    regions = None
    print(f"{scene} at {pct} %, {cpu:g} CPU s a render; region mean of the engine / PATHCPU's")
    for v in variants:
        lux = variant(base, v)
        path = P.render_luxcore(lux, "lux_path", 0, cpu, outputs=("RGB", "MATERIAL_ID"))
        if regions is None:
            ids, L = path["MATERIAL_ID"][..., 0], path["img"].mean(-1)
            floor = ids == 0
            lit = floor & (L > 0.5 * np.median(L[floor]))
            near = lit.copy()
            for _ in range(3):
                near[1:] |= near[:-1].copy(); near[:-1] |= near[1:].copy()
                near[:, 1:] |= near[:, :-1].copy(); near[:, :-1] |= near[:, 1:].copy()
            regions = {"all": np.ones_like(floor), "wall": ids == 1, "sphere": ids == 2,
                       "floor lit": lit, "floor dark": floor & ~lit,
                       "floor dark interior": floor & ~near}
            print("regions (pixels): " + ", ".join(f"{k} {int(m.sum())}" for k, m in regions.items()))
        for e in engines:
            eng, *kv = e.split("@")
            extra = {k: float(x) for k, x in (p.split("=") for p in kv)}
            out = P.render_luxcore(lux, eng, 0, cpu, extra=extra)
            print(f"{v} {e} ({out['spp']} spp): " + ", ".join(
                f"{k} {out['img'][m].mean() / path['img'][m].mean():.3f}"
                for k, m in regions.items()) + f"; load {os.getloadavg()[0]:.1f}", flush=True)


def _region_ratio(x_runs, y, y_var, m):
    """Ratio of region means mean(x) / mean(y) and its standard error.

    x_runs: (K, H, W, 3) independent images (their spread gives x's error);
    y: (H, W, 3) with per-pixel variance y_var of its mean (pixels taken as
    independent), or y_var None and y of shape (K', H, W, 3)."""
    xm = np.array([r[m].mean() for r in x_runs])
    x, sx = xm.mean(), xm.std(ddof=1) / np.sqrt(len(xm))
    if y_var is None:
        ym = np.array([r[m].mean() for r in y])
        yy, sy = ym.mean(), ym.std(ddof=1) / np.sqrt(len(ym))
    else:
        yy, sy = y[m].mean(), np.sqrt(y_var[m].sum()) / y[m].size
    q = x / yy
    return q, q * np.hypot(sx / x, sy / yy)


def check(scene: str, cycles: int, fppm_runs: list[tuple[str, float]], engine: str = ENGINE):
    import bpy  # noqa: F401

    from fppm.addon.cli import open_blend
    from fppm.tools.converge.references import load_reference, make_reference
    from fppm.tools.metrics import region_masks
    from measure_cpu import render_cpu
    if engine == "composed":
        # Run k of the composed reference: the sum of every part's run k
        # (independent of the other k); the regions from the composed file.
        ref = load_reference(composed_path(scene, cycles))
        parts = [load_runs(scene, e) for e in COMPOSE_PARTS]
        runs = np.stack([sum(p[k]["img"] for p in parts) for k in range(min(map(len, parts)))])
    else:
        runs = np.stack([r["img"] for r in load_runs(scene, engine)])
        ref = load_reference(reference_path(scene, engine, len(runs)))
    s = P.load_scene(blend_of(scene), PCT)
    lux = P.translate(s)
    ids = first_hit_ids(lux)
    masks = {"all": np.ones(ids.shape, bool)}
    masks.update({k: v for k, v in region_masks(ref["image"]).items() if v.any()})
    for i, mat in enumerate(s.materials):
        if (ids == i).any():
            masks["sees " + mat.name] = ids == i
    if engine.startswith("lux_light") or engine == "composed":
        # The light tracer renders only what the camera sees through no
        # specular surface: compare there (what compose() keeps of it).
        keep = ~specular_first(lux, ids)
        masks = {k + " (diffuse first)": m & keep for k, m in masks.items() if (m & keep).any()}
    others = {}
    if cycles:
        c = make_reference(bpy, open_blend(blend_of(scene), resolution=PCT), blend_of(scene),
                           cycles, print, lambda t, force=False: print(t, flush=True))
        others[f"Cycles {cycles} spp"] = (c["image"], c["var"])
    for run, sec in fppm_runs:
        imgs = np.stack([render_cpu(blend_of(scene), PCT, sec, run, seed=7 + k)["img"]
                         for k in range(2)])
        others[f"FPPM {run} 2x{sec:g} CPU s"] = (imgs, None)
    print(f"{scene}: LuxCore {engine} reference ({len(runs)} runs) / other, per region "
          f"(ratio of means +- standard error; pixels):")
    for name, (y, yv) in others.items():
        cells = []
        for k, m in masks.items():
            q, e = _region_ratio(runs, y, yv, m)
            cells.append(f"{k} {q:.4f}+-{e:.4f} ({int(m.sum())})")
        print(f"  / {name}: " + "; ".join(cells), flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}")


def main(argv) -> int:
    if len(argv) < 2 or argv[0] not in ("render", "finish", "check", "compose", "bisect"):
        print(__doc__)
        return 2
    cmd, scene = argv[0], argv[1]
    engine = _arg(argv, "--engine", ENGINE)
    if cmd == "render":
        render(scene, _arg(argv, "--runs", 4), _arg(argv, "--cpu", 200.0), engine)
    elif cmd == "finish":
        finish(scene, engine)
    elif cmd == "bisect":
        bisect(scene, _arg(argv, "--pct", 50), _arg(argv, "--cpu", 12.0),
               _arg(argv, "--variants", "matte,matte+noworld,matte+point,matte+plainsphere,"
                                        "matte+plainpoint").split(","),
               _arg(argv, "--engines", "lux_light,lux_bidir,lux_bidirvm").split(","))
    elif cmd == "compose":
        compose(scene, _arg(argv, "--cycles", 4096),
                tuple(_arg(argv, "--parts", ",".join(COMPOSE_PARTS)).split(",")))
    else:
        fr = [(r.split(":")[0], float(r.split(":")[1]))
              for r in _arg(argv, "--fppm", "light:60,combined:60").split(",") if r]
        check(scene, _arg(argv, "--cycles", 4096), fr, engine)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
