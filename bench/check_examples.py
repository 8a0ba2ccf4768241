"""Every example scene, tried as a user would: each mode, in one process and
on two local Dask workers, and a checkpoint resumed; exit codes and images.

    .venv/bin/python bench/check_examples.py [scene ...] [--modes combined,fppm,ppm,path,light]
                                             [--resolution 10] [--workers 2] [--skip workers,resume,same]

Three checks per scene and mode, each a `fppm render` command (the `fppm`
script beside this interpreter), small images and few passes:

- **workers**: `--passes 2` in one process and with `--workers N` (Path
  Tracing has no photon stage to split: one process only); each must exit 0.
- **resume**: two passes with `--checkpoint DIR --checkpoint-every 0`, then
  `--passes 4 --resume`, against four passes straight: exit 0 and the same
  image bit for bit (README "Command line": a resumed render equals an
  uninterrupted one).
- **same**: `--chunk 65536` at 25 % in one process and on N workers, four
  passes (modes combined, fppm and light): the same image bit for bit
  (docs/scale_out.md).

Prints one line per command pair and a summary; exits 1 if any check
failed.  A heavy check (minutes per scene), not a test: tests/ covers each
case it once found (docs/reliability.md "Every example scene, every way in").
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
import fppm_alias  # noqa: E402,F401  (the repository as the package fppm)

BLENDS = os.path.join(ROOT, "example_blends")
FPPM = os.path.join(os.path.dirname(sys.executable), "fppm")
MODES = ("combined", "fppm", "ppm", "path", "light")


def render(blend: str, out: str, *flags) -> tuple[int, str]:
    """(exit code, last line of its output) of `fppm render blend -o out flags`."""
    p = subprocess.run([FPPM, "render", blend, "-o", out, "--overwrite", "-q", "--no-preview",
                        *map(str, flags)], capture_output=True, text=True, timeout=1800)
    lines = (p.stdout + p.stderr).strip().splitlines()
    return p.returncode, lines[-1] if lines else ""


def max_difference(a: str, b: str) -> float:
    """The largest absolute difference between two EXRs' layers."""
    from fppm.core.io.exr import read_exr
    x, y = read_exr(a), read_exr(b)
    return max(float(np.abs(x[k] - y[k]).max()) for k in x)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", help="example names (default: every .blend)")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--resolution", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip", default="", help="checks to skip: workers,resume,same")
    a = ap.parse_args(argv)
    scenes = a.scenes or sorted(f[:-6] for f in os.listdir(BLENDS) if f.endswith(".blend"))
    modes, skip = a.modes.split(","), set(filter(None, a.skip.split(",")))
    failed = []
    with tempfile.TemporaryDirectory(prefix="fppm-check-") as tmp:
        for name in scenes:
            blend = os.path.join(BLENDS, name + ".blend")
            for mode in modes:
                base = ("--mode", mode, "--seed", 7)
                if "workers" not in skip:
                    for w in ([()] + ([("--workers", a.workers)] if mode != "path" else [])):
                        rc, last = render(blend, os.path.join(tmp, "w.exr"), *base, "--passes", 2,
                                          "--resolution", a.resolution, *w)
                        ok = rc == 0
                        print(f"{name} {mode} {'one process' if not w else f'{a.workers} workers'}: "
                              f"exit {rc}{'' if ok else ': ' + last}", flush=True)
                        if not ok:
                            failed.append((name, mode, "workers", w))
                if "resume" not in skip:
                    ck = os.path.join(tmp, "ck")
                    small = base + ("--resolution", a.resolution)
                    r0 = render(blend, os.path.join(tmp, "full.exr"), *small, "--passes", 4)[0]
                    r1 = render(blend, os.path.join(tmp, "half.exr"), *small, "--passes", 2,
                                "--checkpoint", ck, "--checkpoint-every", 0)[0]
                    r2, last = render(blend, os.path.join(tmp, "res.exr"), *small, "--passes", 4,
                                      "--checkpoint", ck, "--resume")
                    d = (max_difference(os.path.join(tmp, "full.exr"), os.path.join(tmp, "res.exr"))
                         if (r0, r1, r2) == (0, 0, 0) else float("nan"))
                    ok = d == 0.0
                    print(f"{name} {mode} resumed at pass 2: exits {r0}/{r1}/{r2}, "
                          f"largest difference {d}{'' if ok else ': ' + last}", flush=True)
                    if not ok:
                        failed.append((name, mode, "resume"))
                    shutil.rmtree(ck, ignore_errors=True)
                if "same" not in skip and mode in ("combined", "fppm", "light"):
                    chunked = base + ("--resolution", 25, "--chunk", 65536, "--passes", 4)
                    r0 = render(blend, os.path.join(tmp, "one.exr"), *chunked)[0]
                    r1, last = render(blend, os.path.join(tmp, "two.exr"), *chunked,
                                      "--workers", a.workers)
                    d = (max_difference(os.path.join(tmp, "one.exr"), os.path.join(tmp, "two.exr"))
                         if (r0, r1) == (0, 0) else float("nan"))
                    ok = d == 0.0
                    print(f"{name} {mode} one process against {a.workers} workers, --chunk 65536: "
                          f"exits {r0}/{r1}, largest difference {d}{'' if ok else ': ' + last}",
                          flush=True)
                    if not ok:
                        failed.append((name, mode, "same"))
    print(f"{len(failed)} check(s) failed" + (f": {failed}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
