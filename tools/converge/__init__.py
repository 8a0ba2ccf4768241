"""``fppm converge``: error against run time for FPPM, PPM and Cycles.

    fppm converge SCENE.blend --time-limit S --out DIR [--clock wall|cpu]
                  [--reference REF.exr | --cycles-samples N] [--methods fppm,ppm,cycles]
                  [--seeds K] [--resolution PCT] [--photons N] [--mask MASK.png|exr]
                  [--kind diffuse|indirect|caustic-small|caustic-large]
                  [--max-passes N] [--no-cycles-check]

1. Reference (``references.py``): REF.exr, or a Cycles render of the same
   file at N samples (default: the file's Cycles samples) with reference
   settings, as two halves with independent seeds (their difference gives
   the reference's variance, the floor of every relMSE), cached under
   ``$FPPM_CACHE_DIR`` (default ``~/.cache/fppm``) ``/references/<sha256>.exr``.
   A REF.exr with a "Trusted" layer vouches only for the pixels where it is
   1: every error and floor is then over those pixels, "all" included
   (``references.trusted_masks``).
2. Methods (``runs.py``): ``fppm`` (the file's FPPM settings, corrected
   frequency model), ``paper`` (the paper's printed frequency model) and
   ``ppm`` (use_frequency off), same seed, photons per pass and resolution,
   time_limit = S, each rendered through the path of ``fppm render``
   (``addon.cli.open_blend`` + ``render_scene``: the F12 scene); ``cycles`` at
   1, 2, 4, ... samples, each a separate render timed by wall clock, until
   one takes longer than S.  FPPM/PPM time = render set-up (export, BVH,
   occlusion grid) + pass time; Cycles time = the whole ``render.render``,
   rendered in a process of its own (``cycles_worker.py``: no numba or
   Embree threads beside Cycles) whose samples/s is checked against a
   standalone Cycles render of the first seed's last point (report.md says
   whether they agree within 5%; ``--no-cycles-check`` skips it).
3. After every pass (or ladder point): time, photons, relMSE / RMSE / MRE / HDR-FLIP over
   the image and over the smooth / caustic / indirect regions
   (``tools.metrics.region_masks``, or the --mask image: R caustic, G smooth,
   B indirect).
4. --seeds K >= 2: every method runs with seeds seed..seed+K-1; bias and noise
   of the final images are separated (``tools.metrics.bias_noise``).
5. Outputs (``command.py``, ``report.py``, ``plots.py``): DIR/convergence.csv,
   DIR/convergence.png (relMSE and HDR-FLIP), DIR/report.md, DIR/summary.json, DIR/<method>.exr and
   .png (the final image of the first seed), DIR/reference.png.
6. Throughput: FPPM photon-pass time (trace + gather) / raw Embree time for as
   many random rays, in the same process.
7. Ctrl-C: the runs done so far (and the passes of the current one) are written.

--clock cpu: S and every time are CPU seconds (``time.process_time``) of the
process that renders (this one for the photon-mapping methods, less the
metrics computed between passes; the Cycles worker for Cycles), so that a
loaded machine does not change a method's budget.  Every row keeps both
clocks; report.md gives the cores each method used (CPU / wall) and, against
Cycles, the wall-equivalent ratio (x cores(Cycles) / cores(method)).

Equal-time comparisons interpolate each method's error linearly in log-log
between its recorded points (``tools.metrics.loglog_interp``).

A development tool: not shipped in the extension; it imports ``addon`` and
``core``, never the other way round.
"""
from .command import add_parser, converge
from .references import cycles_reference_setup

__all__ = ["add_parser", "converge", "cycles_reference_setup"]
