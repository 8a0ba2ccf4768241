"""Cycles renders of ``fppm converge`` in a process of their own.

Run as a script by path (``python .../cycles_worker.py CONFIG.json``), never
as ``-m fppm...``: importing the ``fppm`` package loads numba (core's cache
set-up), and the point of this process is that nothing but Blender runs in
it.  Numba's and Embree's worker threads, alive in the ``fppm converge``
process once FPPM has rendered, slow Cycles down there (bench/
converge_examples.py --cycles-speed measures it), which would bias every
equal-time ratio in FPPM's favour.
So this module imports only the standard library and ``bpy``; the parent
(``runs.run_cycles_ladder``) reads the images and computes the metrics.

CONFIG.json: ``{"blend", "resolution" (percentage or null), "seed", "dir",
"mode": "ladder" | "fixed", "budget", "max_samples" (ladder), "samples"
(fixed: a list of sample counts), "clock": "wall" | "cpu" (default wall)}``.
Every render is written to ``<dir>/cycles_<samples>.exr`` and announced on
stdout as one line ``FPPM-CYCLES {"samples", "seconds", "wall_seconds",
"cpu_seconds", "path"}`` (``seconds`` on the chosen clock, which the ladder's
budget is; ``cpu_seconds`` is this process's ``time.process_time`` over
``render.render``: every Cycles thread); the last line is
``FPPM-CYCLES {"done": true, "numba": bool, "embreex": bool, "threads": int}``
(whether those modules were ever imported here; the OS threads of the
process at the end).  Blender's own output goes to stderr.

``cycles_reference_setup`` and ``render_to_file`` are also the reference's
render (``references.py``), so references and ladders share one set-up.
"""
from __future__ import annotations

import json
import math
import os
import sys
import time

PREFIX = "FPPM-CYCLES "


def cycles_reference_setup(scene) -> None:
    """Cycles settings for an unbiased, comparable render.

    CPU, caustics on, blur_glossy 0, no denoising / adaptive sampling /
    clamping / light threshold, view 'Standard' (the image FPPM is compared
    with, docs/method.md "Validation"); the scene's pixel filter and light
    path (bounce) settings are kept.
    """
    r = scene.render
    r.engine = "CYCLES"
    r.use_persistent_data = False
    vs = scene.view_settings
    vs.view_transform = "Standard"
    vs.look = "None"
    vs.exposure = 0.0
    vs.gamma = 1.0
    c = scene.cycles
    c.device = "CPU"
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.blur_glossy = 0.0
    c.use_animated_seed = False


def render_to_file(bpy, scene, samples: int, seed: int, path: str, passes: bool = False,
                   cpu: list | None = None) -> float:
    """Render with Cycles into the EXR ``path``; returns the wall seconds of render.render.

    passes: also the Diffuse Direct / Indirect passes (a multi-layer EXR).
    cpu: when given, the process CPU seconds of render.render are appended to it.
    """
    scene.cycles.samples = int(samples)
    scene.cycles.seed = int(seed)
    vl = bpy.context.view_layer
    vl.use_pass_diffuse_direct = passes
    vl.use_pass_diffuse_indirect = passes
    im = scene.render.image_settings
    if hasattr(im, "media_type"):        # Blender >= 5: multilayer is a media type
        im.media_type = "MULTI_LAYER_IMAGE" if passes else "IMAGE"
    im.file_format = "OPEN_EXR_MULTILAYER" if passes else "OPEN_EXR"
    im.color_depth = "32"
    im.color_mode = "RGBA"
    im.exr_codec = "ZIP"
    if passes:
        # write_still writes every pass (save_render keeps only Combined);
        # the reference's time is not a measurement, the file write may count.
        scene.render.filepath = path
        scene.render.use_file_extension = False
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        return time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    bpy.ops.render.render()
    dt = time.perf_counter() - t0
    if cpu is not None:
        cpu.append(time.process_time() - c0)
    bpy.data.images["Render Result"].save_render(filepath=path, scene=scene)
    return dt


def next_ladder_samples(n: int, seconds: float, budget: float) -> int:
    """The ladder's next sample count after n samples took ``seconds``.

    Doubling, except that the step past the budget aims at ~1.1x the budget
    rather than up to 2x (the last point only brackets 100%).
    """
    n_next = 2 * n
    if 2 * seconds > budget and seconds > 0:
        n_next = min(n_next, max(n + 1, int(math.ceil(n * 1.1 * budget / seconds))))
    return n_next


def os_threads() -> int:
    """Threads of this process (Linux /proc; -1 elsewhere)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Threads:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return -1


def _say(d: dict) -> None:
    sys.stdout.write(PREFIX + json.dumps(d) + "\n")
    sys.stdout.flush()


def main(argv) -> int:
    with open(argv[0]) as f:
        cfg = json.load(f)
    import bpy

    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(cfg["blend"]), load_ui=False,
                             use_scripts=False)
    scene = bpy.context.scene
    if cfg.get("resolution") is not None:
        scene.render.resolution_percentage = int(cfg["resolution"])
    cycles_reference_setup(scene)
    seed = int(cfg["seed"])
    on_cpu = cfg.get("clock", "wall") == "cpu"

    def render(n):
        path = os.path.join(cfg["dir"], f"cycles_{n}.exr")
        cpu = []
        dt = render_to_file(bpy, scene, n, seed, path, cpu=cpu)
        secs = cpu[0] if on_cpu else dt
        _say({"samples": n, "seconds": secs, "wall_seconds": dt, "cpu_seconds": cpu[0],
              "path": path})
        return secs

    if cfg["mode"] == "fixed":
        for n in cfg["samples"]:
            render(int(n))
    else:
        budget, n = float(cfg["budget"]), 1
        while n <= int(cfg["max_samples"]):
            dt = render(n)
            if dt > budget:
                break
            n = next_ladder_samples(n, dt, budget)
    _say({"done": True, "numba": "numba" in sys.modules, "embreex": "embreex" in sys.modules,
          "threads": os_threads()})
    return 0


if __name__ == "__main__":
    # Blender's render log goes to stdout: keep stdout for the protocol lines.
    proto = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = os.fdopen(proto, "w")
    sys.exit(main(sys.argv[1:]))
