"""Each kernel compiles once for each set of array types it is given.

numba compiles a kernel called from another kernel once for every distinct
tuple of argument types, and a constant argument is a type of its own
(``Literal[int](0)``, ``Literal[bool](False)``): a helper called with
channel 0, 1, 2 or with an int16 and an int32 material id compiles its
whole body again each time.  docs/interactive.md "One signature a kernel,
round 50" has what those extra compiles cost and what removing them saved.

The record read here is the suite's precompile (tests/precompile.py: every
warm-up job and the test-only units, in two processes), kept in its marker
with every kernel's signatures.  A whole-suite run writes it first
(tests/conftest.py); without a complete one, the test compiles every
unit into an empty temporary cache itself (:func:`_record`).
"""
import functools
import json
import os
import tempfile

import precompile
from fppm.core._numba_cache import ENV_VAR

# Kernels that keep more than one signature, with the reason and the count.
# Anything else with two signatures, or any literal argument, fails.
SEVERAL = {
    # The point's lobe colours: float32 per-pixel state (the visible points,
    # the light tracer's hits) or float64 (the numpy callers' tables).
    "fppm.core.materials.compiled:_eval_pair_as": 2,
    # The fold's albedo keeps its dtype: the division by pi in that dtype is
    # numpy's (NEP 50), so the sums equal a GatherResult's bit for bit.
    "fppm.core.sppm.hashgrid:_fold": 2,
    "fppm.core.sppm.hashgrid:_fold_run": 2,
    "fppm.core.sppm.hashgrid:_fold_clipped": 2,
    "fppm.core.sppm.hashgrid:_fold_sweep_parallel": 2,
    # The visible points' float32 receivers (photon mapping) and the path
    # tracer's and glossy MIS's float64 ones.
    "fppm.core.lights.direct_kernels:direct_kernel": 2,
    "fppm.core.lights.direct_kernels:_frame": 2,
    # eval_bsdf's float64 tables and the visible points' float32 state, and
    # their int32 and int64 pair indices.
    "fppm.core.materials.compiled:eval_indexed": 3,
    # The occlusion grid's cones as float64 while built and int16 stored.
    "fppm.core.frequency.occlusion_grid:_quantize_cone": 2,
    "fppm.core.frequency.occlusion_grid:_store_cones": 2,
    # Read-only views (a kept pass's radii) and writable arrays.
    "fppm.core.frequency.kernels:_radius": 2,
}


# Kernels the record must list (the test below checks it does).
GUARDED = ("fppm.core.materials.compiled:_eval_pair_as",
           "fppm.core.materials.compiled:_sample_pair",
           "fppm.core.sppm.hashgrid:_count_range")


@functools.lru_cache(maxsize=None)
def _record() -> dict:
    """The precompile's record of every kernel's signatures.  Its marker's
    when the suite's precompile compiled on an empty cache (a whole-suite
    run on a fresh clone: CI).  A kernel loaded from the cache brings its
    callees' code, not their dispatchers, so a record written on a warm
    cache misses them; then, or with no record, every unit compiles here
    into an empty temporary cache (two processes, minutes), so that the
    test never judges a partial record."""
    path = precompile.marker_path()
    if path is not None and os.path.exists(path):
        with open(path) as f:
            kernels = json.load(f)["kernels"]
        if all(k in kernels for k in GUARDED):
            return kernels
    saved = os.environ.get(ENV_VAR)
    with tempfile.TemporaryDirectory(prefix="fppm-signatures-") as d:
        os.environ[ENV_VAR] = d
        try:
            rec = precompile.precompile(2)
        finally:
            if saved is None:
                del os.environ[ENV_VAR]
            else:
                os.environ[ENV_VAR] = saved
    assert rec["ok"], rec
    return rec["kernels"]


def test_no_kernel_compiles_for_a_literal_argument():
    kernels = _record()
    literal = {k: [s for s in v if "Literal[" in s] for k, v in kernels.items()}
    literal = {k: v for k, v in literal.items() if v}
    assert not literal, literal
    # the record covers the kernels this guards
    for k in GUARDED:
        assert k in kernels, sorted(kernels)


def test_each_kernel_compiles_once_for_its_array_types():
    kernels = _record()
    counts = {k: len(v) for k, v in kernels.items()}
    several = {k: n for k, n in counts.items() if n > 1}
    extra = {k: n for k, n in several.items() if n > SEVERAL.get(k, 1)}
    assert not extra, {k: kernels[k] for k in extra}
    print(f"{len(counts)} kernels, {sum(counts.values())} signatures; several: {several}")
