"""The photon tracer's deposits, bit for bit, against digests pinned before
its bounce kernel compacted the survivors without branches
(``photon_kernels.bounce_kernel``, docs/architecture.md "Photon trace against
raw Embree"): a rewrite of the tracer's inner loop that keeps the numbers
passes, any change of a deposit's bits fails.

Covered: the Lambert fast path with Russian roulette and the two halves of a
batch (Cornell box); mirror, smooth glass and the generic fallback of the
GGX and Oren-Nayar walls, a disc and a soft point light (``glass_mirror``);
frequency photons (the hit record the spectra read); caustic photons only
(``after_delta_only``: the delta flags of the survivors); and the MIS state
of integrator 'COMBINED' (one kernel call on the first hits).

Like tests/test_same_image.py the digests are exact on one CPU and
numba/llvmlite build only (libm's sincos, LLVM's code), so they are kept per
CPU (``PINS_BY_CPU``, tests/builds.py): on a new machine compute them with
the code before the change under test (``CASES``) and add its CPU's entry.
"""
import hashlib
import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from core.accel import REL_OFFSET, intersect_f32
from core.sppm import photon_kernels as PK  # noqa: E402
from builds import EARLIER_CPU, for_this_cpu  # noqa: E402
from test_photon_kernels import _tracer, cornell, glass_mirror  # noqa: E402

# Regenerated with compiled.sincos_quarter / sincos_turn (the disk warp's and
# the emission's sine and cosine within 1 ulp of libm's: every direction's
# last bits; docs/architecture.md "The photon pass's own work against raw
# Embree"); the digests before: c7efebd0, e3fe3f01, 4af5479b, 6fc924fd,
# a8fb79be, 11931a94 in this order.  glass_mirror_* regenerated again with
# the bounce kernel's kept normal of flat triangles (photon_kernels.flat_normals:
# no interpolation's rounding; of glass_mirror_plain's 34,222 deposits one
# wi differs, by 1.4e-16; positions and powers the same bits; the Cornell
# box's axis-aligned normals come out the same either way); before:
# 7de02ac3, 85d808c2, d857f9ef.  The disk warp's one division and
# sample_fast inlined changed no digest.
PINS_EARLIER = {
    "cornell_plain": "46aee8b30d5aeab45036c16dab973ec2",
    # freq: one batch (docs/frequency.md); the march's end-plane test after
    # a Lipschitz jump reads the segment's end (occlusion_march)
    "cornell_freq": "462609e4dc01b57ba71df1b07fa83cd6",
    # glass_mirror: its GGX and Oren-Nayar walls sampled by the compiled
    # generic path (compiled.sample_pair): same paths, 118 of 34222 deposit
    # powers 1-2 ulps off (libm's acos in eval_pair against numpy's)
    # glass_mirror_*: its soft point light's photons take their direction at
    # the first hit from a turn of their disc sample (round 36,
    # lights.emission.soft_light_first_hit); before: 7ff590ef, 1e958122,
    # 192d0498 (plain, freq, caustic)
    "glass_mirror_plain": "f5bf21b738a06ac7795009abc6139b63",
    # glass_mirror_freq: the same photons as glass_mirror_plain (each live row
    # draws its row's uniforms of the batch without spectra, docs/frequency.md
    # "The same photons"; one batch before: 4962b7a7740fe36297769e45ed3e7883;
    # regenerated with the occlusion march's end-plane fix merged beside it)
    "glass_mirror_freq": "0ced36fb9663a31e4e21f1adb760b8d5",
    "glass_mirror_caustic": "8686278ab9340b8449b4d6f043c4f939",
    "cornell_mis": "8e405a645e6122aa985523687f138ffd",
}

# llvmlite's host CPU znver3 (AVX2 and FMA, no AVX-512), numba 0.68.1: the
# same code (739843f) as PINS_EARLIER's last regeneration, every digest
# different in the last bits (docs/architecture.md "Pinned images on another CPU").
PINS_BY_CPU = {
    EARLIER_CPU: PINS_EARLIER,
    "znver3": {
        "cornell_plain": "fe8857f704258fe1bc5f9126e53c7587",
        "cornell_freq": "9eb1c09735194097f7d9727e0cdc1ab7",
        # glass_mirror_*: not computed again on znver3 since round 36 (its
        # soft light's photons changed; this machine is znver4, and numba
        # told NUMBA_CPU_NAME=znver3 here reproduces the earlier entry's
        # bits, not znver3's): skipped there until a znver3 machine adds
        # them (before: f0a33acf, 2b2a54a6, 71679c29)
        "glass_mirror_plain": None,
        "glass_mirror_freq": None,
        "glass_mirror_caustic": None,
        "cornell_mis": "a84298558b48b79d393863cb6d2836db",
    },
}


def _digest(arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:32]


def _trace_digest(make, freq, caustic=False):
    tr = _tracer(make(), use_frequency=freq)
    tr.after_delta_only = caustic
    dep = tr.trace(20_000, 5_000 if freq else 0, np.random.default_rng(17))
    return _digest(dep[k] for k in sorted(dep))


def _mis_digest():
    """One bounce_kernel call with the MisState followed (BounceStep.mis) on
    the first hits of 20k photons, from random factors."""
    tr = _tracer(cornell(), use_frequency=False)
    rng = np.random.default_rng(23)
    n = 20_000
    u_emit = rng.random((n, 6))
    live = PK.LiveState(*(np.empty((n, 3), np.float32), np.empty((n, 3), np.float32),
                          np.empty((n, 3)), np.empty((n, 3)), np.empty(n)))
    floor = tr.accel.abs_floor / REL_OFFSET
    K = PK.emit_lights_state(u_emit, *tr._light_arrays, REL_OFFSET, floor, live, False,
                             np.empty((1, 3)), False, np.empty(1, np.int64), np.empty((1, 3)))
    hits = PK.EmbreeHits(*intersect_f32(tr.accel, live.o32[:K], live.d32[:K]))
    dep = tr.deposit_buffers(K)
    mis = PK.mis_state(K, dep.buf.r.shape[0])
    mis.f0[:K], mis.f1[:K] = rng.random(K), rng.random(K)
    mis.row[:K] = np.arange(K)
    mis.first[:K] = rng.random(K) < 0.5
    gen = PK.GenericHits(np.empty(1, np.int64), *(np.empty((1, 3)) for _ in range(6)))
    rec = PK.HitRecord(t=np.empty(1), ng=np.empty((1, 3)), nswi=np.empty(1),
                       hit=np.empty(1, bool), nxt_src=np.empty(1, np.int64),
                       nxt_delta=np.empty(1, bool))
    step = PK.BounceStep(K=K, first=False, store=True, sample=True, roulette=True, bounce=1,
                         dep0=0, record=False, rel=REL_OFFSET, floor=floor, mis=True)
    n_next, n_dep, n_gen = PK.bounce_kernel(step, hits, live, tr.tris, tr.fmat,
                                            rng.random((K, 4)), dep.buf, gen, rec, mis)
    hit = hits.prim[:K] >= 0               # h0, h1 are written at hits only
    return _digest([np.array([n_next, n_dep, n_gen]), live.o32[:n_next], live.d64[:n_next],
                    live.power[:n_next], mis.f0[:n_next], mis.f1[:n_next], mis.row[:n_next],
                    mis.first[:n_next], mis.h0[:K][hit], mis.h1[:K][hit], mis.d0[:n_dep], mis.d1[:n_dep],
                    mis.drow[:n_dep], mis.dfirst[:n_dep]]
                   + [a[:n_dep] for a in dep.buf if a is not dep.buf.src and a is not dep.buf.spec])


CASES = {
    "cornell_plain": lambda: _trace_digest(cornell, False),
    "cornell_freq": lambda: _trace_digest(cornell, True),
    "glass_mirror_plain": lambda: _trace_digest(glass_mirror, False),
    "glass_mirror_freq": lambda: _trace_digest(glass_mirror, True),
    "glass_mirror_caustic": lambda: _trace_digest(glass_mirror, False, caustic=True),
    "cornell_mis": _mis_digest,
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_deposits_equal_pinned(name):
    want = for_this_cpu(PINS_BY_CPU)[name]
    if want is None:
        pytest.skip(f"{name}: no digest for this CPU since the change that made it (see PINS_BY_CPU)")
    assert CASES[name]() == want, (
        f"{name}: the photon tracer's deposits changed bits (see this file's docstring)")


if __name__ == "__main__":
    for name in sorted(CASES):
        print(f'    "{name}": "{CASES[name]()}",')
