"""Run ``fppm converge`` on the example scenes and collect the results in docs/convergence/.

    .venv/bin/python bench/converge_examples.py [scene ...] [--budget 120] [--clock cpu] [--seeds 4] [--methods M,...] [--collect-only | --rereport]
    .venv/bin/python bench/converge_examples.py --cycles-speed [scene] [--samples 128] [--repeats 2]
    .venv/bin/python bench/converge_examples.py --make-reference SCENE [--samples N] [--piece N] [--threads N] [--first-piece K]
    .venv/bin/python bench/converge_examples.py --rescore REF.exr DIR ... [--methods fppm,ppm,appm,cppm]

One scene at a time (the machine has 2 cores), each in its own process (a
fresh Blender state).  The clock is CPU (``fppm converge --clock cpu``): a
budget of 120 s is 60 s of both cores, whatever else loads the machine; each
report gives the cores every method used and, against Cycles, the
wall-equivalent ratios.  Each scene runs its own methods (:data:`SCENE_METHODS`).  Writes docs/convergence/<scene>/ (convergence.csv,
convergence.png, report.md, summary.json, PNG images; the EXRs are deleted to
keep the folder commit-sized) and docs/convergence/report.md, a table of all
scenes built from their summary.json.

Reference sample counts (SCENES) were chosen so that each Cycles reference
takes about 3 minutes on this machine (2 cores, 128x128), about 3x what Cycles
renders in the 60 s budget (the reference's own noise is measured and
subtracted), except where its floor must be lower: a reference's floor must
be at most 1/3 of the smallest excess error compared (cornell: 32768 spp,
indirect_room: 65536 spp).  References are cached under ~/.cache/fppm/references (or
$FPPM_CACHE_DIR), so a second run skips them; --make-reference renders or
extends one in pieces, resumable (tools/converge/references.py, docs/peers.md
"Cycles references in pieces").  --rescore scores the final images of
``fppm converge`` runs (one seed a folder) against another reference.
--cycles-speed: Cycles' samples/s on one example (default ring_lambert)
rendered three ways: in the process that has just rendered FPPM (numba and
Embree threads alive: how the ladder of ``fppm converge`` used to run), in a
process of its own started from there (how it runs now,
tools/converge/cycles_worker.py), and standalone (the same worker started
before anything of FPPM ran in this process); the three are interleaved
``--repeats`` times so the machine's load drifts over all of them.
point_caustic.blend: Cycles cannot render point-light caustics, so its
reference is Mitsuba 3's light tracer, made by bench/point_caustic_reference.py
and read from the cache folder (the scene is skipped when it is missing).
coffee_cup: LuxCoreRender's VCM, made by bench/luxcore_reference.py, read
the same way (:data:`REFERENCE_SCRIPTS`); glass_sphere: LuxCore's light and
path tracers composed with Cycles on the pixels that see the glass first
(bench/luxcore_reference.py compose).
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS = os.path.join(ROOT, "docs", "convergence")

# scene: (kind for the targets, Cycles reference samples)
SCENES = {
    # 32768 spp: the 8192-spp reference's floor (5.0e-5) was above 1/3 of
    # light tracing's, Combined's and Cycles' excess errors (1.2e-4 to 1.4e-4).
    "cornell": ("diffuse", 32768),
    # 65536 spp: the 8192-spp reference's floor (1.1e-3) was above 1/3 of
    # the photon mappers' excess errors at 60 CPU s (4.6e-4 to 1.4e-3).
    "indirect_room": ("indirect", 65536),
    # Cycles' 16384-spp reference of the cup is as noisy as the methods (a
    # camera path must hit the 5 cm spot in the mirror): the reference is
    # LuxCoreRender's VCM (bench/luxcore_reference.py), in the cache folder.
    # The glass sphere's: LuxCore's light tracer (the spot) and path tracer
    # (the world) where the camera sees a diffuse surface first; where it may
    # see the glass first, the light tracer plus Cycles' glass-first paths and
    # the world's other paths; scored only on the pixels Cycles' glass-first
    # paths do not reach (its Trusted layer; bench/luxcore_reference.py
    # compose; its VCM render is biased with the spot, docs/peers.md
    # "References for the glass scenes", "The composed reference's margin,
    # round 34").
    # Eight runs (floor 7.41e-4): after round 34's soft spot cone the
    # photon mappers' excesses fell to 2.8e-3-3.0e-3, and six runs' 9.55e-4
    # was above a third of them (four runs: 1.84e-3).
    "coffee_cup": ("caustic-small", "coffee_cup_luxcore_bidirvm_8runs.exr"),
    "glass_sphere": ("caustic-small", "glass_sphere_luxcore_light_cycles4096_firsthit.exr"),
    # Cycles cannot render this caustic: the reference is Mitsuba 3's light
    # tracer (bench/point_caustic_reference.py), 65536 spp, in the cache folder.
    "point_caustic": ("caustic-point", "point_caustic_mitsuba_ptracer_65536.exr"),
    # A 1 m square area light: caustics from a large light, where Cycles can
    # sample the light well (the targets are parity with Cycles).
    "ring_lambert": ("caustic-large", 8192),
    "ring_principled": ("caustic-large", 8192),
    "principled_interior": ("indirect", 8192),
    # A user's scene: an HDRI world (its only light), Principled materials,
    # a normal-mapped floor.  Its question is Combined (the default) against
    # Cycles.
    "real_scene": ("diffuse", 8192),
}


NOTES = [
    "cornell: `cornell --budget 120 --seeds 4 --methods combined,path,light,fppm,cycles` (120 CPU s "
    "= 60 s of both cores, the issue's equal time) on a439d97, on a machine loaded by other jobs "
    "(load average 4 to 18; 0.6 to 1.1 cores per method).  That commit's COMBINED already renders "
    "the Cornell box as light tracing (camera depth Auto), so COMBINED / LIGHT reads 1.00-1.01; "
    "since, a COMBINED pass without camera paths is LIGHT's pass bit for bit "
    "(docs/integrators.md).  LIGHT's, COMBINED's and Cycles' excess errors at 120 CPU s "
    "(1.2e-4 to 1.4e-4) are below 3x the 8192-spp reference's floor (5.0e-5), so those ratios are "
    "flagged 'near floor'.  Re-run since against the 32768-spp reference (5 pieces, floor 1.25e-5, "
    "1178 CPU s of Cycles; docs/peers.md 'Cycles references in pieces'): `cornell --budget 60 "
    "--seeds 3 --methods combined,light,cycles` on 48f77af and seed 3 by `fppm converge --seed 3 "
    "--seeds 1`, the CSVs joined (`--from-csv`), load average 3 to 5, 0.9 to 1.2 cores a method; "
    "report and CSV in cornell/combined_light_cycles_60s/, kept apart because the table's other "
    "methods ran 120 CPU s.  Every excess is 14-17x the floor (LIGHT 1.88e-4, COMBINED 1.80e-4, "
    "Cycles 2.18e-4): COMBINED / Cycles 0.83 (seeds 0.80-0.85; FLIP 1.08), COMBINED / LIGHT 0.96 "
    "(seeds 0.86-1.04), the same image pass for pass, so the CPU a pass scattering (LIGHT 200-241 "
    "passes, COMBINED 232-241).  The runs above could not be rescored: their EXRs are not kept.  FPPM against "
    "PPM, run since (`cornell --budget 60 --seeds 4 --methods fppm,ppm` on a0b31b1, load average "
    "2 to 3, 1.8 cores a method; its report and CSV in cornell/fppm_ppm_60s/, kept apart "
    "because the table's other methods ran 120 CPU s): FPPM / PPM 1.16 / 0.86 / 0.78 at 10 / "
    "50 / 100 % (excess 0.76 at 100 %; worst fraction 1.17, seeds 1.05-1.49; FLIP 0.93).  FPPM "
    "holds 98 % of the pixels, and the held radii gather more photons: 280-311 passes against "
    "PPM's 322-365, so it loses the first 6 s and wins from the middle on.",
    "ring_lambert: `ring_lambert --budget 60 --seeds 4 --methods fppm,ppm` on 62347fc (the same "
    "images as round 18's later commits, whose changes are bit for bit), load average about 5 (0.7 "
    "cores a method).  FPPM / PPM 1.00 / 0.995 / 1.01 at 10 / 50 / 100 % (excess 1.01; worst "
    "fraction seeds 0.85-1.09; FLIP 1.01): from pass 2 FPPM renders PPM's image to rounding (holds "
    "left out where fewer than 25 % of the pixels hold after pass 1, docs/method.md 'Where "
    "FPPM's extras do not pay'), so the ratio is the CPU per pass scattering between processes "
    "(FPPM 393-496 passes, PPM 420-444).  A run beside a 1M-triangle benchmark read 1.06 / 1.04 / "
    "1.03 (its seed-0 FPPM process made 463 passes against 551-561 for the others).  On c706b47 "
    "(load 3.4 to 5, 1.2 cores a method) it read 1.03 at every fraction, on 5f2b882 1.01.  "
    "COMBINED was not re-run: its earlier row (120 CPU s, 4 seeds, 310a884) read 0.75x PPM; "
    "combined.png is that run's image.",
    "indirect_room: `indirect_room --budget 60 --seeds 4 --methods fppm,ppm,appm,cppm` on "
    "b80097a against the 65536-spp Cycles reference (15 pieces, floor 1.43e-4, 1/8 of the "
    "8192-spp reference's 1.14e-3; docs/peers.md 'Cycles references in pieces'), load average "
    "4.5 to 6 (0.96 to 1.23 cores a method).  Every excess is above 3x the floor (FPPM 4.48e-4 = 3.14x, CPPM 3.17x, APPM 3.80x, PPM 8.17x): no ratio is 'near floor'.  FPPM / PPM 0.384 excess (seeds 0.29-0.48; raw 0.45, 0.14 at 10 %, 0.45 at 50 %), FPPM / APPM 0.83 (seeds 0.79-0.86; raw 0.86), FPPM / CPPM 0.99 (seeds 0.96-1.06; raw 0.99, 0.41 at 10 %, 0.985 at 50 %): a tie with CPPM at 60 CPU s.  COMBINED, LIGHT and Cycles re-run against it "
    "since (`indirect_room --budget 60 --seeds 4 --methods combined,light,cycles` on 48f77af, load "
    "average 4 to 9.5, 0.40 to 0.65 cores a method; report and CSV in "
    "indirect_room/combined_light_cycles_60s/, kept apart): COMBINED / LIGHT 1.04 excess (seeds "
    "0.97-1.11; raw 1.03; FLIP 1.01), COMBINED / Cycles 0.084 (seeds 0.077-0.096), LIGHT / Cycles "
    "0.080; against this table's FPPM (seed by seed across the two runs) FPPM / Cycles 0.099 "
    "(seeds 0.076-0.12), COMBINED / FPPM 0.85 (seeds 0.77-1.07), LIGHT / FPPM 0.81 (seeds "
    "0.72-1.01).  LIGHT's and COMBINED's excesses (3.6e-4, 3.8e-4) are 2.55x and 2.65x the floor: "
    "COMBINED against LIGHT is still 'near floor' (a floor at 1/3 of LIGHT's excess needs about "
    "77 000 spp).  On 1bc5e45 (2 seeds, against the 8192-spp reference) COMBINED read 1.03x LIGHT "
    "and 0.085x Cycles; combined.png, light.png and cycles.png in the folder are that run's "
    "images.  The same four methods' final images at 60 CPU s "
    "from an earlier run on b80097a (3 seeds, load average 15 to 30), rescored "
    "(`--rescore`): FPPM / PPM excess 0.354 against the 8192-spp reference, 0.355 against "
    "the 65536-spp one (raw 0.656 and 0.419), FPPM / CPPM 0.983 and 0.980 (raw 0.995, 0.985): "
    "the excess ratios hold, the raw ones close in on them.",
    "principled_interior: 4 seeds, the same runs and joins as indirect_room (FPPM on 7f7d265 at "
    "load average 1.5 to 4, PPM/APPM/CPPM at load 2 to 3, COMBINED, LIGHT and Cycles the 2-seed "
    "run on 1bc5e45, before frequency_decay 2).  Before X (8b808e2) FPPM read 0.86x PPM and 1.89x "
    "CPPM; on 1bc5e45 (X, 2 seeds) 0.48x and 1.18x.  Re-run with the three interleaved seed by "
    "seed (`principled_interior --budget 60 --seeds 4 --methods fppm,ppm,cppm` on a0b31b1, load "
    "average about 2, 1.7 cores a method; report and CSV in principled_interior/fppm_ppm_cppm_60s/): "
    "FPPM / PPM 0.535 (seeds 0.51-0.57; 0.77 at 10 %), FPPM / CPPM 1.06 (seeds 1.01-1.12; 1.12 at "
    "10 %): FPPM made 298-348 passes, CPPM 343-372, at the same error a pass (docs/method.md "
    "'Where FPPM's extras do not pay').",
    "ring_principled: `ring_principled --budget 60 --seeds 4 --methods fppm,ppm` on 62347fc, "
    "load average about 5 (1.3 cores a method); COMBINED and Cycles images from the earlier 2-seed "
    "run on a434914.  FPPM / PPM 0.977 / 1.01 / 1.06 at 10 / 50 / 100 % (excess 1.06, worst "
    "fraction seeds 0.98-1.10; FLIP 1.02); FPPM made 309-375 passes, PPM 336-368.  In one "
    "process (`bench/bench_pass_stages.py ring_principled --passes 120 --methods fppm,ppm`, load "
    "5.9) FPPM's 120 passes and set-up cost 1.007x PPM's: from pass 2 a pass costs the same "
    "(+-0.3 ms), the difference is the set-up (0.148 s against 0.005 s) and pass 1 (+55 ms), "
    "about 0.2 s of a 60 s budget; so the rows' 1.04-1.06 is the CPU a pass scattering between "
    "processes.  On c706b47 it read 1.04 / 1.04 / 1.06 (seed 0's FPPM 0.146 CPU s a pass against "
    "0.12), on 935d233 (X holding 9-11 % of the pixels) 1.15 / 1.11 / 1.14.",
    "point_caustic: `point_caustic --budget 60 --seeds 4 --methods fppm,ppm` on b80097a, load "
    "average 10 to 12 (0.5 to 0.6 cores a method), against the Mitsuba 3 light tracer's "
    "65536-spp reference (floor 1.4e-4): FPPM / PPM 0.59 / 0.53 / 0.56 at 10 / 50 / 100 % "
    "(excess 0.525; seeds 0.52-0.65), FLIP 0.89.  LIGHT and COMBINED were not re-run: on "
    "ca52af9 (`--budget 30 --seeds 4 --methods fppm,ppm,light,combined`, COMBINED's Camera "
    "Depth Auto Direct where the camera sees no glass under point lights; docs/integrators.md "
    "\"The point caustic\"; load average 3 to 6) COMBINED read 0.75x LIGHT and 0.68x FPPM, "
    "whose FPPM / PPM was 0.98 then; light.png and combined.png are that run's images.  "
    "The rings' COMBINED and Cycles images come from `--budget 30 --seeds 2` on a434914 (load "
    "average 3 to 26), after their Cycles references were made (8192 spp).",
    "glass_sphere: `glass_sphere --budget 30 --seeds 4 --methods fppm,ppm,combined` on 935d233 "
    "(frequency_decay 2; load average 1.5 to 2.5), joined with LIGHT from the run on c330335 "
    "(`--methods fppm,ppm,combined,light`, load average 4 to 11, 0.55 to 0.65 cores per method; PATH not run: 1.57 relMSE at 30 CPU s before); both against "
    "a reference composed of LuxCore's light tracer (the spot) and path tracer (the world) "
    "where the camera sees a diffuse surface first and Cycles' 4096-spp render where it may "
    "see the glass first (bench/luxcore_reference.py compose; floor 1.8e-3, 7x below the "
    "16384-spp Cycles reference's 1.3e-2 of the row before; region means within 1-2 % of "
    "Cycles', docs/peers.md 'The glass sphere's composed reference').  LuxCore's VCM "
    "reference (floor 1.2e-3) was not kept: its bidirectional engines are biased with the "
    "translation's spot (+17 % in the dim region; docs/peers.md 'Why LuxCore's VCM is bright "
    "on the glass sphere').  Every excess (1.9e-2 to 3.6e-2) is now 10-20x the floor.  Seed 3 is an outlier of every photon mapper (FPPM 6.8e-2, PPM 6.7e-2, COMBINED 4.9e-2 relMSE against 1.0e-2 to 1.3e-2 on seeds 0-2; FPPM and PPM share their photons), 14 % of it in the 220 caustic pixels and 84 % outside the three regions (edges, the sphere): the means and COMBINED's 0.81x FPPM follow it.  On seeds 0-2 FPPM / PPM is 1.03, 1.02, 1.15 and COMBINED / FPPM 1.02, 1.31, 0.88 (raw relMSE at 30 CPU s).  That seed-3 paragraph is the c330335 run's.  "
    "FPPM against PPM at 60 CPU s since (`glass_sphere --budget 60 --seeds 4 --methods fppm,ppm` on "
    "a0b31b1, load average 1.8 to 2, 1.6 cores a method; report and CSV in glass_sphere/fppm_ppm_60s/, "
    "kept apart from the 30 s table): 0.88 / 0.94 / 0.99 at 10 / 50 / 100 % on the seeds' mean "
    "errors, which seed 3 carries (seed by seed at 10 / 50 / 100 %: 1.10 / 1.06 / 1.00, 1.11 / "
    "1.06 / 1.02, 1.17 / 1.27 / 1.11, 0.87 / 0.86 / 0.94); FPPM made 301-385 passes, PPM "
    "347-386.  The first verified hold's growth is what loses here at equal passes "
    "(docs/method.md 'Where FPPM's extras do not pay').",
    "coffee_cup: `coffee_cup --budget 60 --seeds 4 --methods fppm,ppm` on a0b31b1 (load average "
    "2 to 3, 1.6 cores a method) against LuxCoreRender's VCM of four runs (bench/luxcore_reference.py "
    "render coffee_cup --runs 4 --cpu 200: 7806 spp, 751 CPU s, floor 1.84e-3; "
    "coffee_cup_luxcore_bidirvm_4runs.exr, named in SCENES; docs/peers.md 'References for the "
    "glass scenes').  FPPM's excess 5.83e-3 is 3.2x the floor: the row ranks.  FPPM / PPM 1.04 / "
    "1.00 / 0.99 at 10 / 50 / 100 % (worst fraction 1.05, seeds 0.98-1.19; FLIP 1.00): a tie, "
    "FPPM holding 48-52 % of the pixels and gaining nothing on the mirror's caustic.  LIGHT and "
    "COMBINED were not re-run: on e64549a (`--budget 30 --seeds 2 --methods "
    "fppm,ppm,light,combined`, load 5 to 6, against the two-run reference, floor 4.15e-3) "
    "COMBINED read 0.94x FPPM and FPPM / PPM 1.11 at 10 %; light.png, combined.png and "
    "path.png are images of earlier runs.",
    "CPU time is not a perfect measure of work on a loaded machine: at the same 30 CPU s, PPM "
    "did 400 and 267 passes on point_caustic's two seeds, FPPM 50 and 36 on indirect_room's "
    "(the other vCPU busy, caches shared).  The seed spreads in the tables include that.",
    "Clock: CPU seconds (`fppm converge --clock cpu`, `time.process_time` of the process that "
    "renders: the `fppm converge` process for the FPPM-family methods, less the metrics computed "
    "between passes; the Cycles worker process for Cycles).  The CPU clock keeps each method's "
    "budget independent of the machine's load, but not of the cache and memory-bandwidth "
    "contention, which slows every method per CPU second.",
    "indirect_room's reference is now 65536 spp (floor 1.43e-4, 1/3.1 of the smallest "
    "photon-mapper excess compared; the 8192-spp one's 1.1e-3 lay above 1/3 of every photon mapper's "
    "excess; LIGHT's and COMBINED's excesses are 2.55x and 2.65x it).  cornell's is now 32768 spp "
    "(floor 1.25e-5, 1/14 of the smallest excess compared at 60 CPU s).  "
    "point_caustic's (1.4e-4) and principled_interior's (2.0e-4) floors are below 1/3 of every "
    "excess compared.",
    "Cores (CPU / wall) are the share of the 2 cores a method got on the loaded machine, not "
    "what it would use alone (FPPM's whole pass uses 1.40 of 2 cores at 1080p on an idle "
    "machine, README): the wall-equivalent ratios against Cycles use them as measured, so they "
    "carry the load's noise.",
    "Measured on the code of main at 47f7a5f (the branch point of this table); other changes to "
    "the performance code made in the same round are not in these numbers.",
    "Cycles: the ladder renders 1, 2, 4, ... spp in a process of its own, each point timed by "
    "that process's CPU; the standalone samples/s check is skipped (--no-cycles-check): it "
    "guarded against the machine's load, which the CPU clock takes out.",
    "References: Cycles at 8192 spp (cornell 32768, indirect_room 65536) with caustics on, "
    "pieces of independent seeds whose spread gives the noise floor "
    "(tools/converge/references.py); point_caustic: Mitsuba 3's light tracer "
    "(ptracer, bench/point_caustic_reference.py), 65536 spp: the script's 16384-spp halves "
    "averaged with 49152-spp halves rendered by the same function with other seeds (floor "
    "1.4e-4, 4x below the 16384-spp reference's 5.5e-4), since Cycles cannot render a point "
    "light's caustic; coffee_cup: LuxCoreRender's VCM (above); glass_sphere: composed (above).  A target whose excess errors "
    "are below 3x the reference floor is marked "
    "'near floor'.",
    "Round 15 re-run on f61a987 (images as round 14's default, growth only from 10 photons a "
    "cell; the indirect room's 65536-spp reference rendered again on this machine: 8 pieces, "
    "3485 CPU s, floor 1.42e-4), `indirect_room --budget 60 --seeds 4 --methods fppm,ppm,cppm`, "
    "interleaved seed by seed, load average 2 to 4 (the fresh-clone test suite ran beside it "
    "from seed 3), in indirect_room/fppm_ppm_cppm_60s/: FPPM / PPM 0.45 excess (raw 0.86 / "
    "0.48 / 0.49 at 10 / 50 / 100 %; worst fraction seeds 0.77-0.91), FPPM / CPPM 1.08 excess "
    "(seeds 0.97-1.12; raw 1.09 / 1.08 / 1.07; FPPM 92-108 passes, CPPM 100-123): round 13's "
    "0.96 on 070c4bb (seeds 0.87-1.04) is now a loss, FPPM making 4-13 % fewer passes.",
    "Round 14 re-runs on 83502bf (a first hold grows only where its sector cells hold 10 photons or "
    "more, docs/method.md 'Grow only where the counts are full'), on a new machine whose CPU a pass "
    "is about 1.7x the old one's, `SCENE --budget 60 --seeds 4 --methods M`, interleaved seed by "
    "seed, load average 4 to 10 (the test suite ran beside them), each in SCENE/<methods>_60s/: "
    "cornell (fppm,ppm; the 32768-spp reference rendered again, floor 1.25e-5) FPPM / PPM 1.21 / "
    "0.77 / 0.698 at 10 / 50 / 100 % (excess 0.695; worst fraction seeds 1.00-1.36; FPPM 164-175 "
    "passes, PPM 159-184); principled_interior (fppm,ppm,cppm; a new 8192-spp reference, floor "
    "1.96e-4) FPPM / PPM 0.43 excess (raw 0.93 / 0.66 / 0.45), FPPM / CPPM 1.04 excess (seeds "
    "0.99-1.09; raw 1.15 / 1.05 / 1.04; FPPM 142-163 passes, CPPM 149-169).  The other scenes' "
    "references were lost with the old machine and not rendered again this round.",
    "Round 13 re-runs on 070c4bb (a verified hold's first-pass growth stops where the "
    "neighbouring pixels' densities curve at the grown scale, docs/method.md 'When the first hold "
    "grows'), `SCENE --budget 60 --seeds 4 --methods M`, the methods interleaved seed by seed, "
    "load average 1 to 3, each in SCENE/<methods>_60s/, kept apart from the joined table: "
    "cornell (fppm,ppm; 32768-spp reference) FPPM / PPM 1.17 / 0.79 / 0.745 at 10 / 50 / 100 % "
    "(excess 0.74; worst fraction seeds 1.10-1.32; FPPM 273-322 passes, PPM 306-396); "
    "indirect_room (fppm,ppm,cppm) FPPM / PPM 0.36 excess (raw 0.67 / 0.38 / 0.43), FPPM / CPPM "
    "0.96 excess (seeds 0.87-1.04; raw 1.02 / 0.89 / 0.97); principled_interior (fppm,ppm,cppm) "
    "FPPM / PPM 0.53 excess (raw 0.76 / 0.55 / 0.56), FPPM / CPPM 1.05 excess (seeds 0.84-1.23; "
    "raw 1.06 / 1.06 / 1.04; FPPM 240-346 passes, CPPM 274-351); glass_sphere (fppm,ppm) FPPM / "
    "PPM 1.26 / 1.09 / 1.07 (excess 1.08; seeds 1.02-1.28; 389-452 passes against 406-451, so "
    "the loss is at equal passes, 0.14 against 0.128 in the caustic region); coffee_cup "
    "(fppm,ppm) 1.001 / 0.99 / 0.99 (excess 0.99; seeds 0.93-1.08); point_caustic (fppm,ppm) 0.53 / 0.52 / 0.54 (excess 0.51; seeds 0.52-0.53).",
    "Round 16 re-runs on 7a8de8c's code (the spectrum's gated hold rate as the default, "
    "docs/method.md 'The gated spectrum rate as the default, round 16'), `SCENE --budget 60 "
    "--seeds 4 --methods fppm,ppm,cppm`, the methods interleaved seed by seed, load average 1 to "
    "15, each in SCENE/fppm_ppm_cppm_60s/ until round 19 replaced them: indirect_room FPPM / PPM 0.44 excess (raw 0.83 / 0.46 "
    "/ 0.49 at 10 / 50 / 100 %), FPPM / CPPM 0.984 excess (seeds 0.90-1.08; raw 1.07 / 1.00 / "
    "0.987; FPPM 112-133 passes, CPPM 118-130); principled_interior FPPM / PPM 0.50 excess (raw "
    "0.83 / 0.61 / 0.52), FPPM / CPPM 0.977 excess (seeds 0.82-1.14; raw 1.17 / 0.99 / 0.98; "
    "FPPM 200-218 passes, CPPM 169-233); cornell FPPM / PPM 1.01 / 0.756 / 0.679 (excess 0.675; "
    "10 % seeds 0.94-1.12), FPPM / CPPM 1.02 excess (seeds 1.00-1.06; raw 1.18 / 1.06 / 1.02).",
    "Round 17 re-runs on 6657bbc (the same code as the round 16 re-runs above) against the "
    "references rendered again in round 16 (docs/peers.md 'References rebuilt, round 16'), "
    "`SCENE --budget 60 --seeds 4 --methods fppm,ppm`, load average 1 to 14, each in "
    "SCENE/fppm_ppm_60s/: glass_sphere FPPM / PPM 0.95 / 1.05 / 1.07 at 10 / 50 / 100 % (excess "
    "1.08, seeds 0.95-1.13; at equal passes 1.00-1.13 at pass 100, the caustic region 1.00-1.02; "
    "FPPM 180-226 passes, PPM 212-240); coffee_cup (6-run reference, floor 1.48e-3) 0.97 / 1.02 / "
    "1.01 (excess 1.01, seeds 1.007-1.023; at equal passes 0.97-0.98; FPPM 213-231 passes, PPM "
    "259-292); point_caustic (65536 spp, floor 1.39e-4) 0.53 / 0.49 / 0.52 (excess 0.49, seeds "
    "0.48-0.53).",
    "Round 17, after the rule that pixels seen through glass or mirrors do not hold "
    "(docs/method.md 'The glass sphere at equal passes, round 17'), on eef1e44, `SCENE --budget 60 "
    "--seeds 4 --methods fppm,ppm`, load average 2 to 4: glass_sphere FPPM / PPM 0.99 / 0.82 / 0.84 "
    "(excess 0.82; seeds at 100 % 1.04, 1.09, 1.09, 0.74; at equal passes 1.00-1.02 at pass 100); "
    "coffee_cup 1.06 / 0.985 / 0.97 (excess 0.96, seeds 0.94-0.98; 10 % seeds 0.94-1.25; at equal "
    "passes 0.97-0.98; FPPM 211-280 passes, PPM 218-250).",
    "Round 19 re-runs on a5fbc25 (round 18's code: its changes since the round 16 re-runs are the "
    "round 17 rules and set-up and round 18's bit-for-bit ones), `SCENE --budget 60 --seeds 4 "
    "--methods fppm,ppm,cppm`, each in SCENE/fppm_ppm_cppm_60s/ (replacing the round 16 runs; cornell's and indirect_room's since moved to SCENE/fppm_ppm_cppm_60s_start1/): "
    "cornell (load 1 to 2, 1.7-1.8 cores a method) FPPM / PPM 1.03 / 0.737 / 0.686 at 10 / 50 / "
    "100 % (excess 0.681; 10 % seeds 0.95-1.19), FPPM / CPPM 1.13 / 1.02 / 1.01 (seeds at 100 % "
    "0.90-1.13; FPPM 232-255 passes, PPM 244-270, CPPM 224-267); indirect_room (load 5 to 14) FPPM "
    "/ PPM 0.817 / 0.462 / 0.509 (excess 0.457, seeds 0.38-0.51), FPPM / CPPM 1.05 / 0.996 / 1.01 "
    "(excess 1.01, seeds 0.87-1.19; FPPM 120-135 passes, CPPM 128-139); principled_interior "
    "(load 6 to 14, 0.5 cores a method) FPPM / PPM 0.782 / 0.596 / 0.482 (excess 0.458, seeds "
    "0.38-0.52), FPPM / CPPM 0.991 / 1.01 / 0.972 (excess 0.969, seeds 0.87-1.06).",
    "Round 19, after Frequency Start 2 became the default (docs/method.md 'Round 19: the rings and "
    "the decision'), on efc9056, `SCENE --budget 60 --seeds 4 --methods fppm,ppm,cppm`, load about "
    "2 (the runs alone, 1.8 cores a method, on a machine then slower per CPU second: fewer passes "
    "for every method), each in SCENE/fppm_ppm_cppm_60s/ (the a5fbc25 runs above, Frequency "
    "Start 1, moved to SCENE/fppm_ppm_cppm_60s_start1/; cornell's since moved to cornell/fppm_ppm_cppm_60s_round19/): cornell FPPM / PPM 1.24 / 0.787 / 0.714 "
    "(excess 0.71; 10 % seeds 0.93-1.57), FPPM / CPPM 1.29 / 1.03 / 1.06 (seeds at 100 % "
    "0.91-1.19; FPPM 178-222 passes, PPM 200-240, CPPM 194-223); indirect_room FPPM / PPM 0.736 / "
    "0.409 / 0.416 (excess 0.37, seeds 0.32-0.49), FPPM / CPPM 0.937 / 0.964 / 0.939 (excess "
    "0.927, seeds 0.74-1.04; FPPM 99-125 passes, CPPM 101-116).  principled_interior was not "
    "re-run (Frequency Start 2: 1.004-1.013x Start 1's error at 6 s, 1.007x at 30 s in "
    "bench/bench_hold_alpha.py).",
    "Round 20, the Cornell box at 6 CPU s with 16 seeds on deada67 (Frequency Start 2), `cornell "
    "--budget 6 --seeds 16 --methods fppm,ppm,cppm`, load 2 to 4, in cornell/fppm_ppm_cppm_6s_16seeds/ "
    "(the round 19 run on 62347fc, Frequency Start 1, moved to cornell/fppm_ppm_cppm_6s_16seeds_start1/): "
    "FPPM / PPM 0.98 at 6 s (seeds 0.86-1.16, 12 of 16 below 1; 1.02 with Start 1), 1.20 at 3 s; "
    "FPPM / CPPM 1.12 (seeds 0.98-1.33; 1.11 with Start 1); FPPM 23-29 passes, PPM 27-35, CPPM "
    "26-32 (docs/method.md 'Round 20: the Cornell box's first passes on an idle machine').  Moved to "
    "cornell/fppm_ppm_cppm_6s_16seeds_round20/ in round 21.",
    "Round 21, the Cornell box at 6 CPU s with 16 seeds on 17f0c6c (round 21's gather and set-up), "
    "`cornell --budget 6 --seeds 16 --methods fppm,ppm,cppm`, load about 2 with a helper's benchmark "
    "beside it (1.7 cores a method), in cornell/fppm_ppm_cppm_6s_16seeds/: FPPM / PPM 0.933 at 6 s "
    "(seeds 0.76-1.11, 12 of 16 below 1; FLIP 0.94), 1.06 at 3 s (round 20: 0.98 and 1.20); FPPM / "
    "CPPM 1.08 at 6 s; FPPM 24-31 passes, PPM 28-35, CPPM 27-35.  That run moved to "
    "cornell/fppm_ppm_cppm_6s_16seeds_round21/ in round 22.",
    "Round 22, the Cornell box at 6 CPU s with 16 seeds on 987d983 (e606929's code: the clock's "
    "fix), idle (the run alone), in cornell/fppm_ppm_cppm_6s_16seeds/: FPPM / PPM 0.894 at 6 s "
    "(seeds 0.68-1.02, 14 of 16 below 1; FLIP 0.928), 1.00 at 3 s, 1.32 at 0.6 s; FPPM / CPPM "
    "1.06 at 6 s (seeds 0.97-1.23); FPPM 27-32 passes, PPM 29-34, CPPM 29-34.",
    "Round 20, the Cornell box on 8076bc8 (the march's runs of blocks: the same images, a cheaper "
    "march), `cornell --budget 60 --seeds 4 --methods fppm,ppm,cppm`, idle (load 1.1 to 1.2, 1.8 "
    "cores a method), in cornell/fppm_ppm_cppm_60s/ (the efc9056 run above moved to "
    "cornell/fppm_ppm_cppm_60s_round19/): FPPM / PPM 1.06 / 0.762 / 0.694 (excess 0.688; 10 % seeds "
    "0.99-1.15), FPPM / CPPM 1.11 / 0.945 / 0.986 (excess 0.986, seeds at 100 % 0.92-1.03); FPPM "
    "260-295 passes, PPM 297-316, CPPM 269-309.  Moved to cornell/fppm_ppm_cppm_60s_round20/ in round 21.",
    "Round 21, the Cornell box on 82071aa (the gather's sector cells in arithmetic and a run's sector "
    "counts in one word, the march blocks built with less work: the same images, FPPM's gather "
    "0.75x), `cornell --budget 60 --seeds 4 --methods fppm,ppm,cppm`, load about 2 with a helper's "
    "coffee-cup run beside it (1.0-1.1 cores a method), in cornell/fppm_ppm_cppm_60s_1core/: FPPM / PPM "
    "0.865 / 0.67 / 0.658 (excess 0.652; 10 % seeds 0.82-0.92, all four below 1; FLIP 0.903 / "
    "0.854 / 0.86), FPPM / CPPM 1.05 / 0.976 / 1.02 (excess 1.02); FPPM 309-331 passes, PPM "
    "287-348, CPPM 330-338.",
    "Round 21, the same row again on cef93cf (the same code), idle (the run alone, load 2 to 3, 1.8 "
    "cores a method), in cornell/fppm_ppm_cppm_60s/: FPPM / PPM 1.07 / 0.711 / 0.636 (excess 0.63; "
    "10 % seeds 0.85, 1.13, 1.32, 1.00; FLIP 0.952 / 0.866 / 0.856), FPPM / CPPM 1.04 / 0.987 / "
    "0.974 (excess 0.973, seeds at 100 % 0.90-1.04); FPPM 274-309 passes, PPM 267-306, CPPM 278-303.  "
    "The four seeds' 10 % point moves with the seeds and the cores (0.865 and 1.07 for the same code); "
    "16 seeds at 6 s read 0.933 (below).  That run moved to cornell/fppm_ppm_cppm_60s_round21/ in "
    "round 22.",
    "Round 22, the same row on e606929 (the frequency deposits' gather without a branch, the same "
    "images; the next pass's traced-ahead photons billed to the method, not left out with the "
    "metrics: docs/method.md 'The convergence runs' CPU clock, round 22'), idle (the run alone, "
    "1.75 cores a method), in cornell/fppm_ppm_cppm_60s/: FPPM / PPM 0.921 / 0.738 / 0.675 (excess "
    "0.669; 10 % seeds 0.937, 0.775, 1.014, 0.941; FLIP 0.925 / 0.871 / 0.872), FPPM / CPPM 1.06 / "
    "1.01 / 0.995 (excess 0.994, seeds at 100 % 0.96-1.02); FPPM 308-318 passes, PPM 324-331, "
    "CPPM 304-335.",
    "Round 21, the coffee cup on 4b45fc3 (Frequency Start 2, round 21's cheaper march and set-up) "
    "against its VCM reference rendered again (`bench/luxcore_reference.py render coffee_cup "
    "--runs 6 --cpu 200`, 12467 spp, 1202 CPU s, floor 1.12e-3 where round 16's file had 9449 "
    "spp and 1.48e-3; docs/peers.md 'The cup's reference rebuilt, round 21'), all at nice 19 "
    "beside another helper's benchmarks.  `coffee_cup --budget 60 --seeds 4 --methods "
    "fppm,ppm,cppm`, load 2.6 to 6.5 (1.1 cores a method), in coffee_cup/fppm_ppm_cppm_60s/: "
    "FPPM / PPM 1.03 / 0.982 / 0.984 at 10 / 50 / 100 % (excess 0.981, seeds 0.974-0.985; 10 % "
    "seeds 0.95-1.14, one of four below 1; FLIP 1.03 / 1.00 / 0.995), FPPM / CPPM 1.01 / 0.999 / "
    "1.001 (excess 1.002, seeds 0.987-1.014); FPPM 392-429 passes, PPM 414-456, CPPM 376-450; "
    "every excess 5.2-5.3x the floor.  At equal passes FPPM is CPPM's error within 0.5 % and "
    "0.97-0.98x PPM's from pass 10.  `coffee_cup --budget 6 --seeds 16 --methods fppm,ppm,cppm`, "
    "load 1.8 to 6.4 (1.4 cores a method), in coffee_cup/fppm_ppm_cppm_6s_16seeds/ (the round-18 "
    "run on 62347fc, Frequency Start 1, scored against round 16's file, moved to "
    "coffee_cup/fppm_ppm_cppm_6s_16seeds_start1/): FPPM / PPM 1.01 at 6 s (excess 1.009, seeds "
    "0.96-1.09, 7 of 16 below 1; 1.02 with Start 1), 1.04 at 3 s, 1.39 at 0.6 s; FPPM / CPPM 1.03 "
    "(seeds 0.97-1.11; 1.03 with Start 1); FPPM 33-44 passes (mean 38.1), PPM 33-47 (40.8), CPPM "
    "34-45 (40.2); every excess 10.6-11x the floor.  That 6-s run moved to "
    "coffee_cup/fppm_ppm_cppm_6s_16seeds_4b45fc3/ in round 21.",
    "Round 21, the coffee cup at 6 CPU s with 16 seeds again on 58a8bb2 (round 21's gather merged: "
    "the same images), idle (the run alone, 1.65 cores a method), in "
    "coffee_cup/fppm_ppm_cppm_6s_16seeds/: FPPM / PPM 1.002 at 6 s (seeds 0.95-1.05, 8 of 16 below "
    "1; FLIP 1.02), 1.05 at 3 s; FPPM / CPPM 1.03; FPPM 29-43 passes, PPM 33-44, CPPM 34-44.  "
    "That run moved to coffee_cup/fppm_ppm_cppm_6s_16seeds_58a8bb2/ in round 22.",
    "Round 22, the coffee cup at 6 CPU s with 16 seeds on 987d983 (e606929's code: the clock's "
    "fix), idle (the run alone), in coffee_cup/fppm_ppm_cppm_6s_16seeds/: FPPM / PPM 1.000 at 6 s "
    "(seeds 0.96-1.04, 10 of 16 below 1; FLIP 1.01), 1.04 at 3 s, 1.27 at 0.6 s; FPPM / CPPM 1.02 "
    "(seeds 0.95-1.06); FPPM 33-39 passes, PPM 35-40, CPPM 33-41.",
    "Round 22, the coffee cup's 60-s row twice, idle (the run alone, 1.6-1.7 cores a method): on "
    "82dfd59 (the frequency deposits' gather without a branch; the next pass's traced-ahead "
    "photons still left out with the metrics), in coffee_cup/fppm_ppm_cppm_60s_82dfd59/: FPPM / PPM "
    "0.972 / 0.978 / 0.984 (excess 0.981; 10 % seeds 1.031, 0.882, 0.980, 1.004; FLIP 0.996), "
    "FPPM / CPPM 1.04 / 1.01 / 1.01; FPPM 362-428 passes, PPM 386-433, CPPM 397-438.  On e606929 "
    "(those photons billed to the method), in coffee_cup/fppm_ppm_cppm_60s/ (the 4b45fc3 run moved "
    "to coffee_cup/fppm_ppm_cppm_60s_4b45fc3/): FPPM / PPM 1.005 / 0.984 / 0.985 (excess 0.982; "
    "10 % seeds 1.039, 0.993, 0.981, 1.006; FLIP 1.01 / 1.00 / 0.999), FPPM / CPPM 1.04 / 1.01 / "
    "1.01; FPPM 355-385 passes, PPM 374-397, CPPM 340-410.  Every excess 5.2-5.3x the floor.",
    "Round 22, ring_lambert on e606929, idle (1.6 cores a method), its Cycles reference rendered "
    "again (8192 spp, floor 1.71e-5), in ring_lambert/fppm_ppm_60s/: FPPM / PPM 1.01 / 1.02 / 1.01 "
    "(excess 1.01; seeds at 100 % 0.963, 0.954, 1.070, 1.053; FLIP 1.01 / 1.01 / 1.00); FPPM "
    "518-595 passes, PPM 552-630.  FPPM renders PPM's image from pass 1 (held share below "
    "HOLD_SHARE_MIN), so each seed's ratio follows its two runs' CPU a pass.",
    "Round 22, ring_principled on e606929, idle (1.7 cores a method), its Cycles reference rendered "
    "again (8192 spp, floor 1.76e-5), in ring_principled/fppm_ppm_60s/: FPPM / PPM 0.972 / 0.970 / "
    "0.995 (excess 0.995; seeds at 100 % 1.034, 0.964, 0.973, 1.007; 10 % seeds 0.880-1.017; FLIP "
    "0.988 / 0.992 / 0.995); FPPM 382-433 passes, PPM 398-429.",
    "The CPU clock before round 22 (every run before e606929): a photon mapper's next pass, traced "
    "ahead in its own thread while the metrics were computed, was left out of the method's CPU "
    "with them, about 5 % of the budget free on the Cornell box (8.4 ms a pass); Cycles' ladder "
    "had nothing free.  Those rows favour the photon mappers against Cycles and the other ways in "
    "by about that; between photon mappers the ratios moved by about 1 % (docs/method.md 'The "
    "convergence runs' CPU clock, round 22').",
    "Round 23, on 80aee96 with the fair clock, idle, each scene alone, against references "
    "rendered again on this machine (principled_interior 8192 spp in 2 pieces, floor 1.96e-4, "
    "534 s wall; indirect_room 65536 spp in 8 pieces, floor 1.42e-4, 1984 s wall): `SCENE "
    "--budget 60 --clock cpu --seeds 4 --methods fppm,ppm,appm,cppm`, in "
    "SCENE/fppm_ppm_appm_cppm_60s/.  indirect_room FPPM / PPM 0.627 / 0.452 / 0.397 at 10 / 50 / "
    "100 % (excess 0.335), / APPM 0.713 / 0.732 / 0.794, / CPPM 0.782 / 0.889 / 0.919 (every seed "
    "<= 1.00; FPPM 166-177 passes, CPPM 160-180); principled_interior FPPM / PPM 0.718 / 0.444 / "
    "0.551 (excess 0.519), / APPM 0.944 / 0.663 / 0.838, / CPPM 1.05 / 0.844 / 1.00 (10 %: all "
    "four seeds 1.01-1.10; at 6 s FPPM made 28 passes, CPPM 29-30; over 60 s 306-310 against "
    "309-322).  The top-level files of both folders are the earlier runs with Combined and "
    "Cycles, on the old clock.",
    "Round 27, real_scene (an HDRI world, its only light; Principled materials; a normal-mapped "
    "floor) against its Cycles reference (8192 spp in 2 pieces, floor 2.76e-5, 105 s wall), "
    "`real_scene --budget 60 --clock cpu --seeds 4` (methods combined,path,fppm,cycles), load 1 "
    "to 3.  On 28ef7ed (the camera paths' HDRI lookup mended, nothing else), in "
    "real_scene/combined_path_fppm_cycles_60s_28ef7ed/: Combined / Cycles 21.1 / 22.7 / 19.8 "
    "(excess 25.5), Path Tracing / Cycles 23.5 (excess), FPPM / Cycles 61.5; 175-190 camera-path "
    "passes.  On 8523e81 (the camera-path kernels on the scene, the microfacet side test, the "
    "map's own light sample over 8 x 8 cells a texel, one Sobol' sequence a pixel across "
    "passes), in real_scene/combined_path_fppm_cycles_60s_8523e81/: Combined / Cycles 2.04 / "
    "2.63 / 2.48 (excess 2.93, seeds 2.61-3.18), Path Tracing / Cycles 1.86 / 2.34 / 2.23 "
    "(excess 2.60), FPPM / Cycles 32; 327-372 Path Tracing passes.  From d949fed Combined leaves light tracing out there (no "
    "emitter it traces) and renders Path Tracing's image bit for bit at its cost, so its row "
    "is Path Tracing's.  Cycles made 2742 spp in 60 CPU s: 1.3 us a path at the margin, 2x "
    "FPPM's camera path (docs/integrators.md \"Cycles' CPU a path at the margin, round 27\").  On "
    "f88a1a6 (the Normal Map and the escaped rays' HDRI lookup compiled as well), `real_scene "
    "--methods path,cycles`, load about 1, in real_scene/path_cycles_60s_f88a1a6/: Path "
    "Tracing (= Combined) / Cycles 1.42 / 1.90 / 1.87 (excess 2.14); 438-446 passes; Cycles "
    "2718 spp (1.99 cores, Path Tracing 1.26: 3.36 wall-equivalent).",
    "Round 28, real_scene with its floor's Image Texture into the Base Color (make_examples.py; "
    "a new Cycles reference, 8192 spp in 2 pieces, floor 3.01e-5), `real_scene --budget 60 "
    "--clock cpu --seeds 4 --methods path,fppm,cycles`, load 2 to 4 (Mitsuba and the other "
    "run beside it).  On 1166bab (textured hits in the camera-path kernels; the photons' "
    "textured hits still numpy's), in real_scene/path_fppm_cycles_60s_1166bab/: Path Tracing / "
    "Cycles 1.30 / 1.86 / 1.83 (excess 2.06), FPPM / Cycles 57 (143-149 passes).  On 4a61295 "
    "(the first vertex's BSDF sample and light sample's point from the pixel's sequence; the "
    "photons' textured hits compiled), the top-level files: Path Tracing (= Combined) / Cycles "
    "1.26 / 1.65 / 1.64 (excess 1.84; seeds at 100 % 1.55-1.83), 375-418 passes, Cycles "
    "2518 spp (1.67 cores, Path Tracing 1.09: 2.83 wall-equivalent); FPPM / Cycles 30.8 "
    "(excess 40; 245-255 passes).",
    "Round 30, real_scene, FPPM alone (`--methods fppm`, the round-28 reference), load 1 to 2, "
    "in real_scene/fppm_60s_71948fe/: glossy chains (Photon Mapping's camera paths through the "
    "gold block, MIS at its glossy points) 0.0118 / 0.00228 / 0.00125 (seeds at 100 % 1.11e-3 "
    "to 1.57e-3, 255-266 passes): 0.59x round 29's 0.00213; FPPM / Cycles 9.9 (excess 12.7) "
    "against round 28's Cycles run.  The first version (the glossy point's light to next-event "
    "estimation alone) read 0.0128 / 0.00244 / 0.00134 (240-256 passes).",
    "Round 30, glass_sphere and coffee_cup on 52314ba (round 29's end: the world's photons over "
    "the smallest rectangle bounding the triangles), their LuxCore references rendered again "
    "(`bench/luxcore_reference.py render coffee_cup --runs 6 --cpu 200`: 14866 spp, 1201 CPU s, "
    "floor 9.55e-4; glass_sphere `render --runs 2 --cpu 100 --engine lux_light:noworld` 17482 "
    "spp, `--runs 2 --cpu 30 --engine lux_path:world` 1503 spp, `compose --cycles 4096`: floor "
    "1.63e-3), `glass_sphere coffee_cup --budget 60 --clock cpu --seeds 4 --methods fppm,ppm`, "
    "nearly idle, in SCENE/fppm_ppm_60s_52314ba/: coffee_cup FPPM / PPM 0.991 / 0.983 / 0.981 "
    "(excess 0.978; seeds at 10 % 0.94-1.04, at 100 % 0.977-0.985), FPPM 308-339 passes, PPM "
    "319-346; glass_sphere 27.8 / 0.982 / 0.977 (excess 0.975): seed 3's firefly (115x PPM's "
    "error at 6 s, 0.92 at 60 s) decides the means, seeds 0-2 read 1.02-1.07 / 1.02-1.04 / "
    "1.03-1.04; FPPM 297-330 passes, PPM 304-337.",
    "Round 29, real_scene, FPPM alone (`--methods fppm`, the round-28 reference), load 1 to 2, "
    "in real_scene/fppm_60s_<commit>/: on 0a9436a (the visible points' HDRI light compiled) "
    "relMSE 0.0183 / 0.00599 / 0.0032 (275-311 passes); on b2ba572 (world photons over the "
    "rectangle bounding the triangles' box in frame(w)'s axes) 0.0174 / 0.00537 / 0.00262; on "
    "62b3aa4 (the smallest such rectangle) 0.0157 / 0.00345 / 0.00213 (seeds at 100 % "
    "1.90e-3 to 2.58e-3, 243-257 passes): 0.67x the disc's, 0.55x round 28's (0.00389); FPPM / "
    "Cycles about 16.9 (excess 21.8) against round 28's Cycles run (docs/method.md 'World "
    "photons where the triangles are, round 29').",
    "Round 29, ring_lambert on 05b0a8d (the world's photons over the smallest rectangle bounding "
    "the triangles: the file's dim world, 17 % of the photons, now reaches the ring), its "
    "reference rendered again (8192 spp, 2 pieces, floor 1.71e-5), `ring_lambert --budget 60 "
    "--clock cpu --seeds 4 --methods fppm,ppm`, load 1 to 2, in "
    "ring_lambert/fppm_ppm_60s_05b0a8d/: FPPM / PPM 1.02 / 0.982 / 0.980 (excess 0.979; seeds "
    "at 100 % 0.94-1.01), FPPM 520-577 passes, PPM 496-544.",
    "Round 29, ring_principled on 1682896 (the world's photons reach the ring, as for "
    "ring_lambert), its reference rendered again (8192 spp, 2 pieces), `ring_principled --budget "
    "60 --clock cpu --seeds 4 --methods fppm,ppm`, idle, in "
    "ring_principled/fppm_ppm_60s_1682896/: FPPM / PPM 1.01 / 1.01 / 0.993 (excess 0.993; seeds "
    "at 100 % 0.89-1.10), FPPM 377-397 passes, PPM 349-418; a first run beside the test suite "
    "(FPPM's seeds under its load, PPM's after it) read 1.06 / 1.04 / 1.04.",
    "Round 28, point_caustic on 171d9fc (rounds 25-28's compiled light and camera paths), "
    "`point_caustic --budget 60 --clock cpu --seeds 4 --methods fppm,ppm,combined,light`, the "
    "Mitsuba reference rendered again (65536 spp, floor 1.39e-4), load 2 to 4 beside other runs, "
    "in point_caustic/fppm_ppm_combined_light_60s_171d9fc/: FPPM / PPM 0.524 / 0.506 / 0.540 "
    "(excess 0.508; seeds at 100 % 0.53-0.56), Combined / FPPM 1.71 / 1.29 / 1.15 (excess 1.17; "
    "seeds 1.12-1.16), Combined / light tracing 0.75 / 0.80 / 0.825, light tracing / FPPM 2.28 / "
    "1.61 / 1.39: round 24's ratios to within the seeds' spread (FPPM 739-762 passes, PPM "
    "746-797, light tracing 868-908, Combined 571-615).",
    "Round 28, principled_interior on 3688844 (the compiled camera and light paths of rounds "
    "25-28), `principled_interior --budget 60 --clock cpu --seeds 4 --methods "
    "combined,fppm,cycles`, the reference rendered again (8192 spp, 2 pieces, floor 1.96e-4), "
    "load 2 to 4, in principled_interior/combined_fppm_cycles_60s_3688844/: Combined / Cycles "
    "0.313 / 0.344 / 0.363 (excess 0.317; seeds 0.359-0.368; 0.630 in round 24), FPPM / Cycles "
    "0.41 / 0.451 / 0.548 (excess 0.515), Combined / FPPM 0.763 / 0.763 / 0.664 (excess 0.616); "
    "Combined 388-398 passes, FPPM 303-317, Cycles 636 spp (1.99 cores; Combined 1.84).",
    "Round 27, ring_principled on 8523e81 (the camera paths' first light sample from one "
    "Sobol' sequence a pixel across the passes), `ring_principled --budget 60 --clock cpu "
    "--seeds 4 --methods combined,cycles`, load 2 to 4 beside other benchmarks, in "
    "ring_principled/combined_cycles_60s_8523e81/: Combined / Cycles 1.82 / 2.27 / 2.26 "
    "(excess 2.67; 3.09, excess 3.7, on b349a7e in round 25); Combined 133-138 passes, Cycles "
    "3136 spp (1.06 cores: the machine was shared).",
    "Round 34, glass_sphere on 5daf67b against its reference composed again "
    "(`bench/luxcore_reference.py compose glass_sphere --cycles 4096`: the margin around the "
    "sphere by first hit, scored on the 15,031 Trusted pixels, floor 7.2e-4 there; docs/peers.md "
    "'The composed reference's margin, round 34'), `glass_sphere --budget 60 --clock cpu --seeds 4 "
    "--methods fppm,ppm`, nearly idle, in glass_sphere/fppm_ppm_60s_5daf67b/: FPPM / PPM 0.945 / "
    "0.967 / 0.978 (excess 0.973; seeds at 10 % 0.93-0.95, at 50 % 0.965-0.972, at 100 % "
    "0.974-0.987; FLIP 0.976 / 0.980 / 0.983); FPPM 258-275 passes, PPM 256-283.  The rows "
    "above were scored against the file before (all pixels).",
    "Round 34, principled_interior on 99c52f3 (round 34's final code: counts that reject shrink "
    "faster), `principled_interior --budget 60 --clock cpu --seeds 4 --methods fppm,cppm,ppm`, "
    "nearly idle, in principled_interior/fppm_cppm_ppm_60s_99c52f3/: FPPM / PPM 0.594 / 0.388 / "
    "0.496 (excess 0.461), FPPM / CPPM 0.982 / 1.02 / 1.01 (seeds at 10 % 0.76-1.18, at 100 % "
    "0.92-1.12: a tie); FPPM 277-295 passes, CPPM 266-307, PPM 301-333.",
    "Round 34, glass_sphere and coffee_cup on bb49216 (the soft spot's cone read as Cycles reads "
    "it; the glass sphere's light tracing of 10 runs, composed: floor 2.26e-4 over the trusted "
    "pixels; the cup's VCM of 8 runs, floor 7.41e-4), `glass_sphere coffee_cup --budget 60 "
    "--clock cpu --seeds 4 --methods fppm,ppm`, nearly idle, in SCENE/fppm_ppm_60s_bb49216/: "
    "glass_sphere FPPM / PPM 0.930 / 0.918 / 0.940 (excess 0.928; every seed below 1 at every "
    "point), FPPM 242-265 passes, PPM 254-278; coffee_cup 0.976 / 0.954 / 0.958 (excess 0.948; "
    "seeds at 10 % 0.87-1.15, at 100 % 0.947-0.969), FPPM 254-279 passes, PPM 229-283.",
    "Round 35, glass_sphere and coffee_cup on 14b75d4 (a soft spot's photons carry Cycles' cone: "
    "a tail beyond it, four disc samples at the first hit), `glass_sphere --budget 60 --clock cpu "
    "--seeds 4 --methods fppm,ppm,combined` in glass_sphere/fppm_ppm_combined_60s_14b75d4/ and "
    "`coffee_cup --budget 60 --clock cpu --seeds 4 --methods fppm,ppm` in "
    "coffee_cup/fppm_ppm_60s_14b75d4/, nearly idle: glass_sphere FPPM / PPM 0.890 / 0.914 / 0.935 "
    "(excess 0.922; every seed below 1 at every point), COMBINED / FPPM 1.35 / 1.48 / 1.50 (excess "
    "1.60; 68-79 passes against FPPM's 229-278, PPM 243-283); coffee_cup FPPM / PPM 0.994 / 0.952 "
    "/ 0.961 (excess 0.951; seeds at 10 % 0.97-1.03), FPPM 246-262 passes, PPM 255-276.",
    "Round 35's final code, 0157188 (spot lights and a constant world emitted compiled), the same "
    "commands with --methods fppm,ppm, in SCENE/fppm_ppm_60s_0157188/: glass_sphere FPPM / PPM "
    "0.881 / 0.918 / 0.943 (excess 0.932), FPPM 349-387 passes, PPM 328-410; coffee_cup 0.937 / "
    "0.953 / 0.963 (excess 0.954), FPPM 374-397 passes, PPM 362-406; every seed below 1 at every "
    "point on both.",
    "Region masks come from the reference (tools/metrics.py): in scenes without caustics the "
    "'caustic' region is made of sharp bright features (light edges, corners), not caustics.",
    "ring_lambert and ring_principled (FPPM 1.40x and 1.29x PPM above): the loss is quality, not cost (an FPPM pass costs 1.05-1.08x a PPM pass there; at equal passes, 128x128, Cycles reference, FPPM was 1.33x / 1.39x PPM at pass 128 on seeds 0 / 1).  99 % of the excess sits on a thin arc of floor at the ring's outer foot, whose discs reach the bright caustic through the zero-thickness wall: a few leaked photons predicted smooth light, the pixels held before the verified holds' test had the counts to reject, and kept 1.3-1.5x PPM's radius after the release.  Since then a hold the test cannot yet judge needs one photon per sector cell and is refused where two of the 8 cells hold 60 % of the counts, and a released prediction shrinks faster (alpha 0.55): 1.08x / 1.09x at pass 128, and at equal CPU (30 s, one thread, 128x128) ring_lambert 1.11-1.12x PPM (before 1.43-1.51x), ring_principled 1.09x (before 1.29x) (docs/method.md 'Rings under a 1 m light').  These rows predate that change.",
]


# Every method of `fppm converge` (tools/converge/runs.py): the photon
# mappers (FPPM, PPM and the two published per-pixel radius rules APPM and
# CPPM), the single strategies of the combined integrator (path and light
# tracing), the combined integrator, and Cycles (the order of the table).
METHODS = "fppm,ppm,appm,cppm,path,light,combined,cycles"
# The script that makes each reference file of SCENES.
REFERENCE_SCRIPTS = {
    "point_caustic": "bench/point_caustic_reference.py",
    "coffee_cup": "bench/luxcore_reference.py render coffee_cup --runs 8 --cpu 200",
    "glass_sphere": "bench/luxcore_reference.py render glass_sphere --engine lux_light:noworld "
                    "--runs 10 --cpu 100 (and --engine lux_path:world --runs 2 --cpu 30), then "
                    "compose glass_sphere --cycles 4096",
}
# The methods each scene's targets need: the combined
# integrator against Cycles and its single strategies, FPPM against PPM, and
# APPM / CPPM where indirect light dominates.  Cycles cannot render
# point_caustic's caustic (its reference is a light tracer).
SCENE_METHODS = {
    "cornell": "combined,path,light,fppm,ppm,cycles",
    "point_caustic": "combined,light,fppm,ppm",
    "indirect_room": "fppm,ppm,appm,cppm,combined,cycles",
    "principled_interior": "fppm,ppm,appm,cppm,combined,cycles",
    "glass_sphere": "combined,fppm,ppm,path,light",
    "coffee_cup": "combined,fppm,ppm,path,light",
    "ring_lambert": "fppm,ppm,combined,cycles",
    "ring_principled": "fppm,ppm,combined,cycles",
    "real_scene": "combined,path,fppm,cycles",
}
# The order the scenes run in (the most important targets first).
ORDER = ("cornell", "point_caustic", "indirect_room", "principled_interior", "glass_sphere",
         "coffee_cup", "ring_lambert", "ring_principled", "real_scene")


def run_scene(name, budget, seeds, from_csv=False, methods=None, clock="cpu"):
    kind, spp = SCENES[name]
    methods = methods or SCENE_METHODS[name]
    out = os.path.join(DOCS, name)
    if isinstance(spp, str):
        base = os.environ.get("FPPM_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "fppm")
        path = os.path.join(base, "references", spp)
        if not os.path.isfile(path):
            print(f"== {name}: skipped, no reference {path} (make it with "
                  f"{REFERENCE_SCRIPTS[name]})", flush=True)
            return None
        ref_args = ["--reference", path]
    else:
        ref_args = ["--cycles-samples", str(spp)]
    os.makedirs(out, exist_ok=True)
    cmd = [sys.executable, "-c",
           "import sys; from fppm.tools.cli import main; sys.exit(main(sys.argv[1:]))",
           "converge", os.path.join(ROOT, "example_blends", name + ".blend"),
           "--time-limit", str(budget), "--clock", clock, "--out", out, *ref_args,
           "--seeds", str(seeds), "--resolution", "100", "--kind", kind, "--methods", methods]
    if clock == "cpu":
        # The standalone Cycles render re-checks the ladder's samples/s against
        # the machine's load, which the CPU clock already takes out: skip its
        # ~1 budget of rendering per scene.
        cmd.append("--no-cycles-check")
    if from_csv:
        if not os.path.isfile(os.path.join(out, "convergence.csv")):
            return None
        cmd.append("--from-csv")
    t0 = time.time()
    print(f"== {name} ({kind}, reference {ref_args[-1]})", flush=True)
    rc = subprocess.call(cmd)
    print(f"== {name}: exit {rc} after {time.time() - t0:.0f} s", flush=True)
    for f in glob.glob(os.path.join(out, "*.exr")):
        os.unlink(f)
    return rc


def fmt(v):
    return "n/a" if v is None or v != v else f"{v:.3g}"


def spread(lo, hi):
    """'min-max' of the seeds (one value when they agree to 3 digits)."""
    lo, hi = fmt(lo), fmt(hi)
    return lo if lo == hi else f"{lo}-{hi}"


def _not_run(name, s):
    """The methods of SCENE_METHODS missing from a scene's summary."""
    want = SCENE_METHODS[name].split(",")
    return [m for m in want if s is None or m not in s["methods"]]


def collect(budget=120.0, seeds=4, clock="cpu"):
    """docs/convergence/report.md: the tables of every scene's summary.json."""
    summaries = {}
    for name in ORDER:
        p = os.path.join(DOCS, name, "summary.json")
        if os.path.isfile(p):
            with open(p) as f:
                summaries[name] = json.load(f)
    unit = "CPU seconds of the rendering process" if clock == "cpu" else "wall seconds"
    lines = ["# Convergence of the example scenes", "",
             f"128x128, up to {seeds} seeds per method, a budget per method in {unit} "
             "(half of it in seconds of both cores of this 2-core machine): "
             + ", ".join(f"{n} {s.get('budget', budget):g}" for n, s in summaries.items())
             + ", `.venv/bin/python "
             "bench/converge_examples.py` (`fppm converge --clock " + clock + "`).  "
             "Each scene's folder has the plot, the CSV and the full report (regions, "
             "bias/noise, every equal-time ratio at 10/50/100% of the budget).", "",
             "relMSE and FLIP (mean HDR-FLIP) at 100% of the budget: mean over the seeds, and "
             "the seeds' min-max.  'excess' = relMSE - the reference's noise floor (what the "
             "method's error against the true image is).  Cores = CPU / wall seconds of the "
             "method's runs.", "",
             "## Error per method", "",
             "| scene | method | relMSE (seeds) | excess | ref floor | FLIP (seeds) | cores |",
             "|---|---|---|---|---|---|---|"]
    for name, s in summaries.items():          # in ORDER
        for m, d in s["methods"].items():
            rs, fs = d.get("relmse_spread", [None, None]), d.get("flip_spread", [None, None])
            lines.append(f"| [{name}]({name}/report.md) | {m.upper()} | "
                         f"{fmt(d['relmse'].get('1.0'))} ({spread(*rs)}) | {fmt(d.get('excess'))} | "
                         f"{fmt(s.get('floor'))} | {fmt(d['flip'].get('1.0'))} ({spread(*fs)}) | "
                         f"{fmt(s.get('cores', {}).get(m))} |")
    lines += ["", "## Targets", "",
              "Ratio < 1: the first method has the lower error at equal time; on the excess "
              "relMSE when both are above the reference floor, else raw; 'seeds' is the "
              "seed-by-seed ratio's min-max.  'near floor': an excess below 3x the reference "
              "floor, so the ratio measures the reference's noise as much as the methods.", "",
              "| scene | target | ratio (seeds) | basis | FLIP ratio | result |",
              "|---|---|---|---|---|---|"]
    for name, s in summaries.items():          # in ORDER
        for t in s.get("targets", []):
            sp = t.get("spread", [None, None])
            lines.append(f"| {name} | {t['target']} | {fmt(t['ratio'])} ({spread(*sp)}) | "
                         f"{t['basis']}" + (f" vs {t['against']}" if t['target'].startswith(
                             "Combined relMSE <= 1x the best") else "")
                         + f" | {fmt(t.get('flip_ratio'))} | "
                         f"{'met' if t['met'] else '**MISSED**'}"
                         + (" (near floor)" if t.get("near_floor") else "") + " |")
    cyc = [(name, k, v) for name in ORDER for k, v in summaries.get(name, {}).get("ratios", {}).items()
           if k.endswith("/cycles")]
    if cyc:
        lines += ["", "## Against Cycles: equal CPU and wall-equivalent", "",
                  "The CPU clock favours the method that uses fewer cores; at equal wall time a "
                  "method on c cores gets c x the time in CPU, so (relMSE ~ 1 / CPU time) the "
                  "wall-equivalent ratio is the equal-CPU ratio x cores(Cycles) / cores(method).", "",
                  "| scene | ratio | equal CPU | wall-equivalent |", "|---|---|---|---|"]
        for name, k, v in cyc:
            e = v.get("excess")
            lines.append(f"| {name} | {k.upper()} | {fmt(e if e is not None else v.get('raw'))} | "
                         f"{fmt(v.get('wall_equivalent'))} |")
    lines += ["", "## Not run", ""]
    missing = [(n, _not_run(n, summaries.get(n))) for n in ORDER]
    missing = [(n, ms) for n, ms in missing if ms]
    lines += ([f"- {n}: {', '.join(ms) if n in summaries else 'not run'}" for n, ms in missing]
              or ["- Every scene and method ran."])
    lines += ["", "## Notes", ""] + [f"- {n}" for n in NOTES] + [""]
    for name in ORDER:
        if os.path.isfile(os.path.join(DOCS, name, "convergence.png")):
            lines += [f"## {name}", "", f"![{name}]({name}/convergence.png)", ""]
    with open(os.path.join(DOCS, "report.md"), "w") as f:
        f.write("\n".join(lines))
    print("\n".join(lines))


def cycles_speed(name="ring_lambert", samples=128, repeats=2, fppm_seconds=20.0):
    """Print Cycles' samples/s on example ``name`` three ways (module docstring)."""
    import tempfile

    from fppm.tools.converge import cycles_worker as CW
    from fppm.tools.converge.runs import cycles_process

    blend = os.path.join(ROOT, "example_blends", name + ".blend")
    stop = {"flag": False}

    def own_process():
        got = {}
        with tempfile.TemporaryDirectory() as tmp:
            cfg = {"blend": blend, "resolution": None, "seed": 0, "dir": tmp, "mode": "fixed",
                   "samples": [samples]}
            cycles_process(cfg, stop, got.update)
        return samples / got["seconds"]

    # Standalone: nothing of FPPM has run in this process yet (numba is
    # imported by the package, but no compiled kernel, no Embree scene).
    results = {"standalone": [own_process() for _ in range(repeats)]}
    import bpy

    from fppm.addon.cli import open_blend, render_scene
    from fppm.addon.engine import RenderSession
    from fppm.tools.converge.references import cycles_render

    def fppm_render():
        sc = open_blend(blend)
        render_scene(sc, {"time_limit": fppm_seconds, "max_passes": 0},
                     RenderSession(log=lambda s: None, should_stop=lambda: False))

    def in_process():
        sc = open_blend(blend)
        CW.cycles_reference_setup(sc)
        _, dt = cycles_render(bpy, sc, samples, 0)
        return samples / dt

    fppm_render()
    for i in range(repeats):
        results.setdefault("in-process", []).append(in_process())
        results.setdefault("own process", []).append(own_process())
    print(f"{name}, {samples} spp per render, after {fppm_seconds:g} s of FPPM in this process, "
          f"{os.cpu_count()} CPU threads:")
    mean = {k: sum(v) / len(v) for k, v in results.items()}
    for k, v in results.items():
        print(f"  {k:12s} samples/s: " + ", ".join(f"{x:.1f}" for x in v) + f"  (mean {mean[k]:.1f})")
    for k in ("in-process", "own process"):
        print(f"  {k} / standalone: {mean[k] / mean['standalone']:.3f}")


def make_reference(name, samples=None, piece=None, threads=0, first_piece=0):
    """Render (or extend) scene ``name``'s Cycles reference of SCENES' samples
    in this process, before anything of FPPM runs in it; resumable piece by
    piece (tools/converge/references.py)."""
    import bpy

    from fppm.addon.cli import open_blend
    from fppm.tools.converge import references as R

    kind, spp = SCENES[name]
    if isinstance(spp, str):
        sys.exit(f"{name}'s reference is {spp}, made by {REFERENCE_SCRIPTS[name]}")
    blend = os.path.join(ROOT, "example_blends", name + ".blend")
    c0, t0 = time.process_time(), time.time()
    ref = R.make_reference(bpy, open_blend(blend, resolution=100), blend, samples or spp, print,
                           lambda s, force=False: print(s, flush=True),
                           piece_samples=piece or R.PIECE_SAMPLES, threads=threads,
                           first_piece=first_piece)
    from fppm.tools import metrics as M

    print(f"{name}: {ref['meta'].get('samples')} spp, {ref['meta'].get('pieces', 2)} pieces, "
          f"floor {M.reference_floor(ref['image'], ref['var']):.3e}, {ref['path']}; this run "
          f"{time.process_time() - c0:.0f} CPU s, {time.time() - t0:.0f} s wall", flush=True)


def rescore(ref_path, dirs, methods, against="fppm"):
    """The final images ``<dir>/<method>.exr`` of ``fppm converge`` runs (one
    seed a dir) scored against the reference ``ref_path``: relMSE, excess
    (relMSE - the reference's floor) and the excess and raw ratios of
    ``against`` to every other method, as report.py's (the ratio of the means
    over seeds; the seeds' min-max of the seed-by-seed ratio)."""
    import numpy as np

    from fppm.core.io.exr import read_exr, read_exr_metadata
    from fppm.tools import metrics as M
    from fppm.tools.converge.references import layer, load_reference

    ref = load_reference(ref_path)
    floor = M.reference_floor(ref["image"], ref["var"])
    meta = json.loads(read_exr_metadata(ref_path).get("fppm:reference", "{}"))
    e = {m: [M.relmse(layer(read_exr(os.path.join(d, m + ".exr")), "Combined"), ref["image"])
             for d in dirs] for m in methods}
    print(f"reference {ref_path}: {meta.get('samples', '?')} spp, floor {floor:.3e}; "
          f"{len(dirs)} seeds")
    for m in methods:
        print(f"  {m.upper():5s} relMSE {np.mean(e[m]):.3e} (seeds {min(e[m]):.3e}-{max(e[m]):.3e})"
              f"  excess {np.mean(e[m]) - floor:.3e}  excess / floor {(np.mean(e[m]) - floor) / floor:.2f}")
    a = np.array(e[against])
    for m in methods:
        if m == against:
            continue
        b = np.array(e[m])
        sx = (a - floor) / (b - floor)
        print(f"  {against.upper()} / {m.upper()}: excess {(a.mean() - floor) / (b.mean() - floor):.3f} "
              f"(seeds {sx.min():.3f}-{sx.max():.3f}), raw {a.mean() / b.mean():.3f} "
              f"(seeds {(a / b).min():.3f}-{(a / b).max():.3f})")
    return floor, e


def main(argv=None):
    if argv is None:
        argv = sys.argv[1:]
    if "--rescore" in argv:
        sp = argparse.ArgumentParser()
        sp.add_argument("--rescore", metavar="REF.exr", required=True)
        sp.add_argument("dirs", nargs="+", help="fppm converge --out folders, one seed each")
        sp.add_argument("--methods", default="fppm,ppm,appm,cppm")
        b = sp.parse_args(argv)
        rescore(b.rescore, b.dirs, b.methods.split(","))
        return
    if "--make-reference" in argv:
        sp = argparse.ArgumentParser()
        sp.add_argument("--make-reference", action="store_true")
        sp.add_argument("scene")
        sp.add_argument("--samples", type=int, default=None, help="default: SCENES' count")
        sp.add_argument("--piece", type=int, default=None,
                        help="largest piece in spp (default references.PIECE_SAMPLES)")
        sp.add_argument("--threads", type=int, default=0,
                        help="Cycles' threads (default: one a CPU)")
        sp.add_argument("--first-piece", type=int, default=0,
                        help="> 0: a separate growing file whose seeds start at that piece's "
                             "(another process; join it with references.join_growing)")
        b = sp.parse_args(argv)
        make_reference(b.scene, b.samples, b.piece, b.threads, b.first_piece)
        return
    if "--cycles-speed" in argv:
        sp = argparse.ArgumentParser()
        sp.add_argument("--cycles-speed", action="store_true")
        sp.add_argument("scene", nargs="?", default="ring_lambert")
        sp.add_argument("--samples", type=int, default=128)
        sp.add_argument("--repeats", type=int, default=2)
        sp.add_argument("--fppm-seconds", type=float, default=20.0)
        b = sp.parse_args(argv)
        cycles_speed(b.scene, b.samples, b.repeats, b.fppm_seconds)
        return
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(ORDER))
    ap.add_argument("--budget", type=float, default=120.0,
                    help="seconds per method on --clock (default 120: 60 s of 2 cores)")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="cpu")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--methods", default=None,
                    help="comma-separated methods of fppm converge (default: the scene's, "
                         "SCENE_METHODS)")
    ap.add_argument("--collect-only", action="store_true")
    ap.add_argument("--rereport", action="store_true",
                    help="no renders: rebuild each scene's report from its CSV (fppm converge --from-csv)")
    a = ap.parse_args(argv)
    if not a.collect_only:
        for name in a.scenes:
            run_scene(name, a.budget, a.seeds, from_csv=a.rereport, methods=a.methods,
                      clock=a.clock)
    collect(a.budget, a.seeds, a.clock)


if __name__ == "__main__":
    main()
