"""Serial parts of a pass moved to both cores, the same bits
(docs/architecture.md "Cores used: the kernel clip and the grid build").

The kernel clip's blocks taken in turn by two threads against one thread
(and a cancel inside a block), its edge rays' fused lift, radii and lengths
against the numpy steps they replaced, and the grid build's median of the
active radii by the compiled selection against np.median.  The grid build itself
(counts zeroed by the tasks that count) is checked against
tests/oracle_grid.py by tests/test_compiled_pass_stages.py.
"""
import numpy as np
import pytest

from core.sppm import clip as C
from core.sppm import hashgrid as hg
from core.sppm import photons as Ph
from test_clip import WALL, _codes, _wall_accel


def _floor_points(n, seed):
    """n visible points on the floor z = 0 near the wall x = WALL, radii
    0.05-0.5 (about a quarter of the discs reach the wall), a few inactive."""
    rng = np.random.default_rng(seed)
    p = np.zeros((n, 3))
    p[:, 0] = rng.uniform(WALL - 1.0, WALL - 0.01, n)
    p[:, 1] = rng.uniform(-5.0, 5.0, n)
    ng = np.tile([0.0, 0.0, 1.0], (n, 1))
    R2 = rng.uniform(0.05, 0.5, n) ** 2
    active = rng.random(n) > 0.1
    return p, ng, R2, active


def test_clip_blocks_in_two_threads_equal_one_thread(monkeypatch):
    """9000 points (four blocks of 2250 in two threads, SPLIT_MIN 4096; every
    active point's rays: near=False) against one thread: the same codes, and
    clipped ones among them; the rays of the points near the wall alone
    (the default) give them too."""
    acc = _wall_accel()
    p, ng, R2, active = _floor_points(9000, 1)
    two = _codes(acc, p, ng, R2, active, near=False)
    monkeypatch.setattr(Ph, "THREADS", 1)
    one = _codes(acc, p, ng, R2, active, near=False)
    assert np.array_equal(one, two)
    assert np.array_equal(_codes(acc, p, ng, R2, active), two)
    assert (two[~active] == hg.CLIP_CLEAR).all()
    clipped = np.count_nonzero(two[active] != hg.CLIP_CLEAR)
    assert 0.15 * active.sum() < clipped < 0.5 * active.sum()   # 27 %


def test_clip_cancel_inside_the_blocks_reaches_the_caller():
    acc = _wall_accel()
    p, ng, R2, active = _floor_points(9000, 2)
    calls = []

    def check_stop():
        calls.append(1)
        if len(calls) == 4:             # the first call: after the proximity test
            raise KeyboardInterrupt
    from types import SimpleNamespace
    from core.sppm.photon_kernels import build_triangle_data
    scene = SimpleNamespace(tri_p=acc.tri_p, tri_n=np.zeros_like(acc.tri_p),
                            tri_mat=np.zeros(acc.tri_p.shape[0], np.int32))
    with pytest.raises(KeyboardInterrupt):
        C.clip_codes(acc, build_triangle_data(scene).ng, p, ng, R2, active, check_stop,
                     near=False)
    assert len(calls) <= 5                  # no block started after the raise but the other's


def _median_cases():
    rng = np.random.default_rng(3)
    return [np.array([3.0]), np.array([2.0, 1.0]), np.array([1.0, 1.0]),
            np.array([5.0, 1.0, 1.0, 5.0]), np.r_[1e300, 1e-300, 3.0, 4.0],
            np.full(6, 5e-324),                       # subnormal
            np.repeat(rng.random(7), 13),             # repeated values, odd count
            np.r_[np.repeat(0.25, 50), np.repeat(0.5, 50)],   # the middle two differ
            rng.uniform(0.5, 1.5, 1001) / 1000.0, rng.uniform(0.5, 1.5, 1000),
            rng.random(4000) ** 8]                    # many exponents


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_compiled_median_is_numpys(threads):
    """The same float64 as np.median, bit for bit (h, hence the grid,
    depends on it), whatever the thread count."""
    f = hg._median_parallel if threads > 1 else hg._median_serial
    for x in _median_cases():
        a, b = f(threads, x), np.median(x)
        assert np.float64(a).tobytes() == np.float64(b).tobytes(), (x[:8], a, b)


def test_edge_rays_lift_and_lengths_are_the_numpy_ones():
    """clip._edge_rays's fused lift, radii and ray lengths against the numpy
    steps they replaced (accel.offset_scale, np.sqrt, np.repeat and Accel's
    float32 t_max), bit for bit; scene-scale coordinates so that both the
    offset and CLIP_LIFT_REL R win somewhere."""
    from core.accel import REL_OFFSET
    acc = _wall_accel()
    p, ng, R2, _ = _floor_points(2000, 4)
    p[::3] *= 1e4                            # the offset above CLIP_LIFT_REL R there
    ng = ng + np.random.default_rng(5).normal(0, 0.1, ng.shape)
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    idx = np.arange(1, 2000, 2)
    o, d, R, t_max = C._edge_rays(p, ng, idx, R2, REL_OFFSET, acc.abs_floor / REL_OFFSET,
                                  C._EDGE_COS, C._EDGE_SIN)
    R_np = np.sqrt(R2[idx])
    lift = np.maximum(acc.offset_scale(p[idx]), C.CLIP_LIFT_REL * R_np)
    assert (lift > C.CLIP_LIFT_REL * R_np).any() and (lift == C.CLIP_LIFT_REL * R_np).any()
    W = C.CLIP_WEDGES
    assert np.array_equal(R, R_np)
    assert np.array_equal(t_max, np.minimum(np.repeat(R_np, W), 3e37).astype(np.float32))
    o_np = np.repeat((p[idx] + lift[:, None] * ng[idx]), W, axis=0).astype(np.float32)
    assert np.array_equal(o, o_np)
    assert np.allclose(np.einsum("ij,ij->i", d, np.repeat(ng[idx], W, axis=0)), 0, atol=1e-6)
