"""Pinned images: one small render per feature, kept bit for bit.

Each variant opens an example scene (``example_blends/<scene>.blend``) with
bpy, sets its resolution percentage to 25 %, exports it through the add-on
(``fppm.addon.export.export_scene``) and renders 3 passes of 30,000 photons
with seed 7 through ``core.render.Renderer`` (integrator PHOTON: every variant
is a photon-mapping feature), with the scene's own settings plus the
overrides of :data:`VARIANTS`.  The film and every AOV switched on
are stored in ``tests/references/pinned/<scene>_<variant>.npz``;
``tests/test_same_image.py`` renders them again and compares the bytes.

The pins are exact only on the CPU and numba/llvmlite build they were made
on (the kernels are compiled for the host: LLVM's choice of vector width and
FMA contraction changes the last bits, and a last bit can move one photon's
path).  ``tests/references/pinned/made_on.json`` records that build
(``tests/builds.py`` ``build_key``).  On the same build the test compares bytes; on another
one it compares with :data:`ACROSS_BUILDS_REL_MSE` instead (:func:`check`).
After an intended change of behaviour rewrite them with

    .venv/bin/python tests/pin_images.py --update

which records the build they were made on.

Usage:
    pin_images.py [--update | --out DIR] [NAME ...]
        NAME is <scene>_<variant> (default: every variant).
        (no option)   render and compare with the stored pins (exit 1 if any differs)
        --update      rewrite tests/references/pinned/NAME.npz
        --out DIR     write NAME.npz into DIR instead (e.g. to compare two trees)
"""
from __future__ import annotations

import argparse
import json
import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x)

import numpy as np  # noqa: E402

import bpy_helpers as H  # noqa: E402
from builds import build_key  # noqa: E402

PIN_DIR = os.path.join(TESTS, "references", "pinned")
MADE_ON = os.path.join(PIN_DIR, "made_on.json")

#: Largest relMSE, sum((got - pin)^2) / sum(pin^2), that any array of a pin may
#: show when the pin was made on another CPU or numba/llvmlite build.  Measured
#: (docs/architecture.md "Pinned images on another CPU"): between two builds
#: the largest was 4.8e-9 (a Photon Count AOV, one photon's path moved by a
#: last bit), every image 3.5e-11 or less; an intended change of behaviour
#: moved its pin's largest array by 2.5e-6 at the least (a Predicted Radius,
#: a Held or Radius AOV by 1e-3 to 1).  1e-7 sits 20x above the first and 25x
#: below the second.
ACROSS_BUILDS_REL_MSE = 1e-7
EXAMPLES = os.path.join(H.ROOT, "example_blends")

RESOLUTION_PERCENT = 25
PASSES = 3
PHOTONS_PER_PASS = 30000
SEED = 7

#: scene -> {variant: Settings overrides}.  One variant per feature: the
#: frequency kernel with every AOV and the edge cap (on by default), plain
#: PPM, specular chains (glass), the edge cap off, the paper's frequency model
#: through a glossy/glass scene.
VARIANTS = {
    "cornell": {
        "fppm_aovs": dict(aov_radius=True, aov_predicted_radius=True, aov_photon_count=True,
                          aov_held=True, aov_spectrum=True),
        "ppm": dict(use_frequency=False, photons_for_direct=False),
    },
    "glass_sphere": {
        "fppm": dict(aov_held=True),
    },
    "point_caustic": {
        "fppm_noedge": dict(cap_radius_at_edges=False, aov_radius=True),
    },
    "coffee_cup": {
        "paper": dict(frequency_model="PAPER", aov_predicted_radius=True),
    },
}

NAMES = [f"{scene}_{variant}" for scene, vs in VARIANTS.items() for variant in vs]


def _split_name(name):
    for scene, vs in VARIANTS.items():
        for variant in vs:
            if name == f"{scene}_{variant}":
                return scene, variant
    raise KeyError(f"unknown pinned variant {name!r}; known: {', '.join(NAMES)}")


def pin_path(name):
    return os.path.join(PIN_DIR, name + ".npz")


def _export(scene_name):
    """Open example_blends/<scene_name>.blend at 25 %; returns (core Scene, base Settings)."""
    bpy = H.bpy()
    H.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    bpy.ops.wm.open_mainfile(filepath=os.path.join(EXAMPLES, scene_name + ".blend"),
                             load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = RESOLUTION_PERCENT
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    return scene, settings_from_scene(sc)


def render_variants(names):
    """Render the named variants; returns {name: {"image": ..., "aov_<k>": ...}}.

    Scenes are opened once each, in :data:`VARIANTS` order.
    """
    from fppm.core.render import Renderer
    wanted = set(names)
    for n in wanted:
        _split_name(n)
    out = {}
    for scene_name, vs in VARIANTS.items():
        todo = [v for v in vs if f"{scene_name}_{v}" in wanted]
        if not todo:
            continue
        scene, base = _export(scene_name)
        for variant in todo:
            st = base.replace(integrator="PHOTON", max_passes=PASSES, time_limit=0.0,
                              photons_per_pass=PHOTONS_PER_PASS, seed=SEED, **vs[variant])
            res = Renderer(scene, st, log=lambda s: None).run()
            arrays = {"image": np.asarray(res.image)}
            for k, v in res.aovs.items():
                arrays["aov_" + k] = np.asarray(v)
            out[f"{scene_name}_{variant}"] = arrays
    return out


def pinned_build():
    """The build the stored pins were made on (made_on.json), or None if unrecorded."""
    try:
        with open(MADE_ON) as f:
            return json.load(f)
    except FileNotFoundError:
        return None


def rel_mse_lines(got, want, bound=ACROSS_BUILDS_REL_MSE):
    """Lines for every array of ``want`` whose relMSE against ``got`` exceeds
    ``bound`` (or whose key, shape or NaNs differ); [] when all are within it."""
    lines = []
    for k in sorted(set(want) | set(got)):
        if k not in got or k not in want:
            lines.append(f"{k}: {'missing from the render' if k not in got else 'not in the pin'}")
            continue
        x, y = np.asarray(got[k], np.float64), np.asarray(want[k], np.float64)
        if x.shape != y.shape or not np.array_equal(np.isnan(x), np.isnan(y)):
            lines.append(f"{k}: shape or NaNs differ ({x.shape} vs pinned {y.shape})")
            continue
        ok = ~np.isnan(y)
        e = float(np.sum((x[ok] - y[ok]) ** 2) / max(float(np.sum(y[ok] ** 2)), 1e-300))
        if e > bound:
            lines.append(f"{k}: relMSE {e:.3g} against the pin (bound {bound:g} across builds)")
    return lines


def check(got, name):
    """Lines describing how the render ``got`` fails pin ``name``; [] when it passes.

    Bytes on the build the pins were made on; :data:`ACROSS_BUILDS_REL_MSE`
    on another one (the bit-for-bit check needs pins made on this build)."""
    want = load_pin(name)
    if pinned_build() == build_key():
        return differences(got, want)
    return rel_mse_lines(got, want)


def load_pin(name):
    """{key: array} of the stored pin ``name``."""
    with np.load(pin_path(name)) as f:
        return {k: f[k] for k in f.files}


def differences(got, want):
    """Lines describing every array of ``want`` that ``got`` does not reproduce
    bit for bit (missing, extra, shape, dtype or bytes); [] when identical."""
    lines = []
    for k in sorted(set(want) | set(got)):
        if k not in got:
            lines.append(f"{k}: missing from the render")
            continue
        if k not in want:
            lines.append(f"{k}: not in the pin")
            continue
        x, y = got[k], want[k]
        if x.shape != y.shape or x.dtype != y.dtype:
            lines.append(f"{k}: {x.dtype}{x.shape} vs pinned {y.dtype}{y.shape}")
        elif x.tobytes() != y.tobytes():
            with np.errstate(invalid="ignore"):
                d = np.abs(x.astype(np.float64) - y.astype(np.float64))
            n = int(np.count_nonzero(~((x == y) | (np.isnan(x) & np.isnan(y)))))
            lines.append(f"{k}: {n} of {x.size} values differ, max |diff| {np.nanmax(d):.3g}")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--update", action="store_true", help="rewrite tests/references/pinned/*.npz")
    g.add_argument("--out", metavar="DIR", help="write the renders to DIR instead")
    ap.add_argument("names", nargs="*", metavar="NAME", help=f"variants (default all): {' '.join(NAMES)}")
    args = ap.parse_args(argv)
    names = args.names or NAMES
    renders = render_variants(names)
    bad = 0
    for name in names:
        arrays = renders[name]
        if args.update or args.out:
            d = PIN_DIR if args.update else args.out
            os.makedirs(d, exist_ok=True)
            np.savez_compressed(os.path.join(d, name + ".npz"), **arrays)
            print(f"{name}: wrote {', '.join(sorted(arrays))}")
            continue
        diff = check(arrays, name)
        bad += bool(diff)
        same = "bit-identical" if pinned_build() == build_key() else "within the bound across builds"
        print(f"{name}: " + (same if not diff else "DIFFERS\n  " + "\n  ".join(diff)))
    if args.update:
        with open(MADE_ON, "w") as f:
            json.dump(build_key(), f, indent=1)
            f.write("\n")
        print(f"{MADE_ON}: {build_key()}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
