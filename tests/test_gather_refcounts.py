"""The gather's hot loops hold no reference counting: numba keeps an
NRT_incref / NRT_decref pair of every array passed to an inlined helper
that returns from several branches, at every call (atomic operations on a
counter both gather threads share: the count pass cost 1.4-3x its CPU,
docs/architecture.md "The count pass without reference counts").  Each
kernel is compiled afresh (not from the cache) and its LLVM IR read: every
NRT_incref of its own function must sit in its entry block (once a call)."""
import re

import numpy as np
from numba import njit

from core.sppm import hashgrid as hg


def _increfs_past_entry(dispatcher, name):
    """NRT_incref calls outside the entry block of the function `name` (not
    its Python or C wrappers) in the IR of dispatcher's first signature."""
    ir = dispatcher.inspect_llvm(dispatcher.signatures[0])
    n, block, inside = 0, 0, False
    for line in ir.splitlines():
        if line.startswith("define"):
            inside = name in line and "cpython" not in line and "cfunc." not in line
            block = 0
            continue
        if not inside:
            continue
        if line.startswith("}"):
            inside = False
        elif re.match(r"^[A-Za-z0-9_.\"]+:", line):
            block += 1
        elif block >= 2 and "call void @NRT_incref" in line:
            n += 1
    return n


def _small_gather(clip: bool):
    rng = np.random.default_rng(0)
    K = 40
    vp_pos = rng.random((K, 3))
    vp_ng = np.tile([0.0, 0.0, 1.0], (K, 1))
    R = np.full(K, 0.2)
    grid = hg.build_grid(vp_pos, R, np.ones(K, bool))
    rec = hg._vp_records(vp_pos, vp_ng, R * R, np.ones(K, bool))
    # the photons at the visible points of the fullest slot, facing them
    cs = grid.cell_start.astype(np.int64)
    s = int(np.argmax(np.diff(cs)))
    ph = vp_pos[grid.vp_ids[cs[s]:cs[s + 1]]].copy()
    P = ph.shape[0]
    up = np.tile([0.0, 0.0, 1.0], (P, 1))
    slot = np.full(P, s, np.int64)
    out1 = [np.zeros(P, np.uint64), np.zeros(P, np.int32), np.zeros(P, np.int32)]
    vp_clip = np.full(K, hg.CLIP_CLEAR) if clip else np.zeros(0, np.uint64)
    return (0, P, slot, ph, up, up, up, np.full(P, np.nan), rec, vp_clip, 0.5,
            grid.cell_start, grid.vp_ids, np.zeros(K, np.int32), np.zeros((K, 3)),
            np.full(K, np.inf), *out1, np.zeros((K, hg.SECTOR_CELLS), np.int32),
            np.zeros(K, np.int32), np.zeros(1, np.int64), 1)


def test_count_and_pair_passes_have_no_reference_counts_per_candidate():
    f = njit(hg._count_range.py_func)
    args = _small_gather(clip=True)
    f(*args)
    assert _increfs_past_entry(f, "_count_range") == 0
    assert int(args[13].sum()) > 0                 # it counted something


def test_fold_has_no_reference_counts_per_point():
    f = njit(hg._fold_run.py_func)
    K, T = 50, 2
    bM = np.zeros((T, K), np.int32)
    bM[1, 3] = 2
    bPhi = np.zeros((T, K, 3))
    bPhi[1, 3] = 0.5
    M = np.zeros(K, np.int64)
    f(-1, 0, K, np.zeros((T, K), np.int32), bM, bPhi, np.full((T, K), np.inf),
      np.zeros((T, K, 0), np.int32), T, M, np.zeros((K, 3)), np.ones((K, 3), np.float32),
      np.float32(np.pi), np.full(K, np.inf), np.zeros(0, np.bool_), np.zeros((0, 0)),
      np.zeros(0, np.uint64))
    assert _increfs_past_entry(f, "_fold_run") == 0
    assert M[3] == 2 and not bM.any()
