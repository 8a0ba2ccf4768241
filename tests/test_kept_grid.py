"""core.kept.KeptBuffer and hashgrid.build_grid(..., kept=): the grid's table
and entries reused from one build to the next, the same grid bit for bit, and
never while a grid built on them is still referenced."""
import numpy as np

from core.kept import KeptBuffer
from core.sppm import hashgrid as hg


def test_kept_buffer_reused_only_when_unreferenced():
    b = KeptBuffer()
    a = b.get(100, np.int32)
    del a
    a = b.get(90, np.int32)
    assert (b.reused, b.allocations) == (1, 1) and a.size == 90
    v = a[3:]
    del a
    a = b.get(90, np.int32)              # a view of the last one is alive
    assert (b.reused, b.allocations) == (1, 2)
    del a, v
    assert b.get(90 + 90 // 16, np.int32).size == 95 and b.reused == 2   # headroom
    assert b.get(10, np.int64).dtype == np.int64 and b.allocations == 3


def _grid_arrays(g):
    return (g.cell_start.copy(), g.vp_ids.copy(), g.n_slots, g.dense)


def test_kept_grid_equals_fresh_builds():
    rng = np.random.default_rng(1)
    kept = hg.KeptGrid()
    held = None
    for k, (K, layout) in enumerate([(4000, "hash"), (3000, "hash"), (5000, "dense"),
                                     (5000, "hash")]):
        pos = rng.uniform(0, 1, (K, 3))
        R = rng.uniform(0.01, 0.04, K)
        act = rng.random(K) < 0.9
        g = hg.build_grid(pos, R, act, layout=layout, kept=kept)
        fresh = hg.build_grid(pos, R, act, layout=layout)
        for x, y in zip(_grid_arrays(g), _grid_arrays(fresh)):
            assert np.array_equal(x, y)
        if k == 2:
            held, snap = g, _grid_arrays(g)      # kept alive through the next build
        del g, fresh
    for x, y in zip(_grid_arrays(held), snap):
        assert np.array_equal(x, y)
    # build 2 reused build 1's arrays (fewer VPs); build 4 did not reuse
    # build 3's (held)
    assert kept.cell_start.reused + kept.cell_start.allocations == 4
    assert kept.vp_ids.reused >= 1 and kept.cell_start.reused >= 1
    assert kept.vp_ids.allocations >= 2 and kept.cell_start.allocations >= 2
