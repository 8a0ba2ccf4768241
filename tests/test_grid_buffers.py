"""The grid build's arrays and the gather's visible-point records carved from
kept buffers (core.kept.KeptBuffers, hashgrid.build_grid(..., buffers=),
GatherBuffers.kept): the same grid and the same gather bit for bit, the
buffers reused from pass to pass, never while a caller still holds a grid."""
import numpy as np
import pytest

from core.kept import ALIGN, KeptBuffers
from core.sppm import hashgrid as Hg
from test_hashgrid import _args, random_case

GRID_FIELDS = ("origin", "lo", "hi", "dims", "cell_start", "vp_ids", "R_ins")


def _same_grid(a, b):
    for f in ("K", "n_active", "h", "inv_h", "dense", "log2_table"):
        assert getattr(a, f) == getattr(b, f), f
    for f in GRID_FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and np.array_equal(x, y), f


def test_kept_buffers_reuse_rule():
    kb = KeptBuffers()
    a, b = kb.take("x", [((10,), np.int32), ((3, 2), np.float64)])
    assert a.ctypes.data % ALIGN == 0 and b.ctypes.data % ALIGN == 0
    assert b.shape == (3, 2) and not np.shares_memory(a, b)
    del a, b
    c, = kb.take("x", [((7,), np.int64)])            # fits, nothing holds it
    assert (kb.allocations, kb.reused) == (1, 1)
    d, = kb.take("x", [((7,), np.int64)])            # c still alive: a new buffer
    assert kb.allocations == 2 and not np.shares_memory(c, d)
    del d
    e, = kb.take("x", [((10 ** 4,), np.int64)])      # too small: a new one
    assert kb.allocations == 3 and e.shape == (10 ** 4,)


def test_reused_buffer_counts_its_alignment_offset():
    """A kept buffer whose first aligned byte lies ``base`` bytes in holds
    ``nbytes - base`` bytes of arrays: a take of more than that gets a new
    buffer, not a short view (a border render's grid, one pass to the next,
    failed with "cannot reshape array of size 2380 into shape (2383,)")."""
    raw = np.empty(4096 + 2 * ALIGN, np.uint8)
    for k in range(ALIGN):
        kb = KeptBuffers()
        kb._bufs["x"] = raw[k:k + 4096 + ALIGN // 2]   # held by the dict alone
        nbytes = 4096 + ALIGN // 2
        base = (-(raw.ctypes.data + k)) % ALIGN
        a, = kb.take("x", [((4096 // 4,), np.int32)])   # 4096 bytes
        assert a.shape == (1024,) and a.ctypes.data % ALIGN == 0
        # reused exactly when the bytes past the offset suffice
        assert kb.reused == int(nbytes - base >= 4096), (k, base)
        assert kb.allocations == 1 - kb.reused


@pytest.mark.parametrize("layout,split", [("hash", False), ("dense", False), ("auto", True)])
def test_grid_from_kept_buffers_is_the_same_grid(layout, split, monkeypatch):
    if split:                                  # 9000 VPs: the threaded build
        monkeypatch.setattr(Hg, "PARALLEL_MIN_VPS", 4096)
    kb = KeptBuffers()
    for seed in (3, 4, 5):
        c = random_case(seed, K=9000 if split else 1500, P=10)
        ref = Hg.build_grid(c["vp_pos"], c["vp_R"], c["active"], layout=layout)
        g = Hg.build_grid(c["vp_pos"], c["vp_R"], c["active"], layout=layout, buffers=kb)
        _same_grid(ref, g)
        del g
    # the first build allocated the four buffers, the next two reused them
    # (the third case's grid may need a larger one: at most one more each)
    assert kb.reused >= 4 and kb.allocations <= 6


def test_held_grid_is_not_overwritten():
    kb = KeptBuffers()
    c1, c2 = random_case(1, K=1500, P=10), random_case(2, K=1500, P=10)
    g1 = Hg.build_grid(c1["vp_pos"], c1["vp_R"], c1["active"], buffers=kb)
    keep = [getattr(g1, f).copy() for f in GRID_FIELDS]
    n = kb.allocations
    g2 = Hg.build_grid(c2["vp_pos"], c2["vp_R"], c2["active"], buffers=kb)
    assert kb.allocations == n + 2                 # "grid_R" and "grid" are held
    for f, x in zip(GRID_FIELDS, keep):
        assert np.array_equal(getattr(g1, f), x), f
    _same_grid(Hg.build_grid(c2["vp_pos"], c2["vp_R"], c2["active"]), g2)


def test_gather_records_in_the_build_buffer():
    """GatherBuffers.kept: the records carved from the build's temporaries'
    buffer give the same gather; unbind frees it for the next build."""
    c = random_case(7, K=1500, P=12_000)
    K = c["vp_pos"].shape[0]
    ref = Hg.gather(Hg.build_grid(c["vp_pos"], c["vp_R"], c["active"]), *_args(c),
                    want_freq_pairs=True, sectors=True)
    kb = KeptBuffers()
    buf = Hg.GatherBuffers(K, sectors=True, threads=2)
    buf.kept = kb
    for _ in range(2):
        grid = Hg.build_grid(c["vp_pos"], c["vp_R"], c["active"], buffers=kb)
        g = Hg.gather(grid, *_args(c), want_freq_pairs=True, buffers=buf)
        M, Phi, r, S = (np.zeros(K, np.int64), np.zeros((K, 3)), np.full(K, np.inf),
                        np.zeros((K, Hg.SECTOR_CELLS), np.int64))
        buf.fold(M, Phi, np.ones((K, 3)), 1.0, r, None, S)
        np.testing.assert_array_equal(M, ref.M)
        np.testing.assert_array_equal(S, ref.sectors)
        np.testing.assert_array_equal(Phi, ref.Phi_sum)
        np.testing.assert_array_equal(r, ref.rpred_min)
        for a, b in ((g.pair_vp, ref.pair_vp), (g.freq_pair_vp, ref.freq_pair_vp)):
            np.testing.assert_array_equal(a, b)
        assert np.shares_memory(buf.vp_rec, kb._bufs["grid_tmp"])
        buf.unbind()
        del grid, g
    # the build's four buffers and the photon sort's ("gather_sort"), once
    assert kb.allocations == 5 and kb.reused >= 5
