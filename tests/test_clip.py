"""The kernel disc clipped at walls (core.sppm.clip, hashgrid rule (5)).

A floor z = 0 (normal +z) with a thin wall x = WALL standing on it: the clip
codes in closed form, the photons behind the wall never gathered, and a
uniformly lit floor read at its density next to the wall once the count is
divided by the visible fraction of the disc (without the clip it reads low
by the missing area).
"""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from core.accel import Accel
from core.sppm import clip as C
from core.sppm import hashgrid as hg
from core.sppm.photon_kernels import build_triangle_data
from oracle_gather import gather_bruteforce

WALL = 0.5


def _wall_accel():
    """A wall x = WALL, y in [-10, 10], z in [-1, 10] (two triangles) and a
    ramp rising at 20 degrees towards -x from x = -1.2: oriented like the
    floor (|dot| = 0.94 > CLIP_COS), it must not clip."""
    w = [[WALL, -10, -1], [WALL, 10, -1], [WALL, 10, 10], [WALL, -10, 10]]
    s = math.tan(math.radians(20.0))
    f = [[-1.2, -10, 0], [-1.2, 10, 0], [-10, 10, 8.8 * s], [-10, -10, 8.8 * s]]
    tri = [[w[0], w[1], w[2]], [w[0], w[2], w[3]], [f[0], f[1], f[2]], [f[0], f[2], f[3]]]
    return Accel(np.array(tri, np.float32), 40.0)


def _codes(acc, p, ng, R2, active, **kw):
    """clip_codes with the triangles' normals as the photon tracer has them
    (a copy: clip_codes may reuse its array)."""
    scene = SimpleNamespace(tri_p=acc.tri_p, tri_n=np.zeros_like(acc.tri_p),
                            tri_mat=np.zeros(acc.tri_p.shape[0], np.int32))
    return C.clip_codes(acc, build_triangle_data(scene).ng, p, ng, R2, active, **kw).copy()


def _bytes(code):
    return [(int(code) >> (8 * k)) & 0xFF for k in range(8)]


def test_clip_codes_of_a_wall_in_closed_form():
    # VP at the origin, R = 1, ng = +z: the tangent frame is (x, y), edge j
    # at 45 j degrees.  Edges 0 / 1 / 7 hit the wall at 0.5 / 0.5 sqrt 2 /
    # 0.5 sqrt 2; wedge k keeps cos(22.5 deg) * min(edge k, edge k + 1).
    # At x = -0.9 edges 3, 4, 5 hit the ramp, which does not clip.
    acc = _wall_accel()
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-0.9, 0.0, 0.0]])
    ng = np.array([[0.0, 0.0, 1.0]] * 4)
    R2 = np.array([1.0, 0.04, 1.0, 1.0])
    code = _codes(acc, p, ng, R2, np.array([True, True, False, True]))
    c = math.cos(math.pi / 8)
    near, diag = int(255 * c * 0.5), int(255 * c * 0.5 * math.sqrt(2))
    assert _bytes(code[0]) == [near, diag, 255, 255, 255, 255, diag, near]
    assert code[1] == hg.CLIP_CLEAR             # R = 0.2: the wall is out of reach
    assert code[2] == hg.CLIP_CLEAR             # inactive
    assert code[3] == hg.CLIP_CLEAR             # the ramp 0.3 away: no clip


def test_clip_weights_of_a_half_disc():
    # Wedges 0, 1, 6, 7 (u > 0) closed at 0: half the disc is visible (f =
    # 1/2); the cells of quadrants 0 and 3 see nothing and read the mean of
    # the others, which keep their counts.
    code = np.uint64(0)
    for k in (2, 3, 4, 5):
        code |= np.uint64(255) << np.uint64(8 * k)
    W = np.empty((8, 8))
    assert hg.clip_weights(code, W) == 2.0
    S = np.array([0.0, 10, 14, 0, 0, 12, 16, 0])
    assert np.allclose(W @ S, [13, 10, 14, 13, 13, 12, 16, 13])
    assert hg.clip_weights(hg.CLIP_CLEAR, W) == 1.0 and np.allclose(W, np.eye(8))


def _floor_photons(n, x0, x1, seed):
    """n photons uniform on the floor rectangle [x0, x1] x [-3, 3], arriving
    from above, power 1; returns the gather's photon arrays and the density."""
    rng = np.random.default_rng(seed)
    pos = np.column_stack([rng.uniform(x0, x1, n), rng.uniform(-3, 3, n), np.zeros(n)])
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    return (pos, up, up, np.ones((n, 3)), np.full(n, np.nan)), n / ((x1 - x0) * 6.0)


def _vps(K=12):
    x = np.linspace(-0.9, WALL - 0.05, K)
    pos = np.column_stack([x, np.zeros(K), np.zeros(K)])
    return pos, np.tile([0.0, 0.0, 1.0], (K, 1)), np.ones(K), np.ones(K, bool)


def _gathered(ph, pos, ng, R2, const, clip):
    """(M, Phi) after GatherBuffers.fold with the clip (count and flux
    divided by the visible fraction), sectors too."""
    K = pos.shape[0]
    grid = hg.build_grid(pos, np.sqrt(R2), np.ones(K, bool))
    buf = hg.GatherBuffers(K, sectors=True, threads=1)
    g = hg.gather(grid, *ph, pos, ng, R2, const, cos_ng=-1.0, buffers=buf, clip=clip)
    M, Phi, r, S = np.zeros(K), np.zeros((K, 3)), np.full(K, np.inf), np.zeros((K, 8))
    buf.fold(M, Phi, np.full((K, 3), np.pi), np.pi, r, None, S, clip)
    return M, Phi, S, g


def test_photons_behind_a_thin_wall_are_not_gathered():
    ph, _ = _floor_photons(40_000, WALL, 3.0, 1)       # lit floor behind the wall only
    pos, ng, R2, const = _vps()
    clip = _codes(_wall_accel(), pos, ng, R2, const)
    M0, _, _, _ = _gathered(ph, pos, ng, R2, const, None)
    M1, _, _, _ = _gathered(ph, pos, ng, R2, const, clip)
    assert (M0[-6:] > 300).all()                      # the leak without the clip
    assert not M1.any()


def test_uniform_floor_reads_its_density_next_to_the_wall():
    # The floor ends at the wall (a concave corner): the photons cover x <
    # WALL only.  Density estimate M w / (pi R^2): with the clip it is the
    # density within 4 sigma (sigma = sqrt(M) w / (pi R^2), Poisson) at
    # every distance; without it the VPs within 0.35 R of the wall read low
    # by the missing area (at least 10 sigma).
    ph, rho = _floor_photons(120_000, -3.0, WALL, 2)
    pos, ng, R2, const = _vps()
    clip = _codes(_wall_accel(), pos, ng, R2, const)
    Mc, Phic, S, _ = _gathered(ph, pos, ng, R2, const, clip)
    M0, _, _, _ = _gathered(ph, pos, ng, R2, const, None)
    raw = Mc.copy()
    w = C.inverse_fractions(clip, np.arange(pos.shape[0]))
    raw /= w
    sigma = np.sqrt(raw) * w / np.pi
    assert np.all(np.abs(Mc / np.pi - rho) < 4 * sigma), (Mc / np.pi / rho, sigma / rho)
    assert np.allclose(Phic[:, 0], Mc)                # power 1, albedo pi / pi
    near = WALL - pos[:, 0] < 0.35
    assert np.all(rho - M0[near] / np.pi > 10 * np.sqrt(M0[near]) / np.pi)
    # The sector counts of a clipped disc look uniform to the chi-square test.
    E = S.sum(axis=1, keepdims=True) / 8
    chi2 = ((S - E) ** 2 / E).sum(axis=1)
    assert np.all(chi2 < 18.475 * 1.5), chi2


@pytest.mark.parametrize("parallel", [False, True])
def test_gather_with_a_clip_equals_the_oracle(parallel):
    rng = np.random.default_rng(5)
    K, P = 300, 6000
    vp_pos = rng.uniform(-1, 1, (K, 3))
    vp_ng = rng.normal(size=(K, 3))
    vp_ng /= np.linalg.norm(vp_ng, axis=1, keepdims=True)
    vp_R2 = rng.uniform(0.05, 0.3, K) ** 2
    const = rng.random(K) < 0.5
    clip = rng.integers(0, 256, (K, 8)).astype(np.uint8).view(np.uint64).reshape(K)
    clip[:40] = hg.CLIP_CLEAR
    ph = (rng.uniform(-1, 1, (P, 3)), rng.normal(size=(P, 3)), rng.normal(size=(P, 3)),
          rng.uniform(0, 1, (P, 3)), np.where(rng.random(P) < 0.3, 0.1, np.nan))
    grid = hg.build_grid(vp_pos, np.sqrt(vp_R2), np.ones(K, bool))
    g = hg.gather(grid, *ph, vp_pos, vp_ng, vp_R2, const, cos_ng=-1.0, parallel=parallel,
                  clip=clip, want_freq_pairs=True)
    o = gather_bruteforce(*ph, vp_pos, vp_ng, vp_R2, const, cos_ng=-1.0, clip=clip,
                          want_freq_pairs=True)
    n = gather_bruteforce(*ph, vp_pos, vp_ng, vp_R2, const, cos_ng=-1.0)
    assert np.array_equal(g.M, o.M) and o.M.sum() < 0.8 * n.M.sum()
    assert set(zip(g.pair_vp, g.pair_ph)) == set(zip(o.pair_vp, o.pair_ph))
    assert set(zip(g.freq_pair_vp, g.freq_pair_ph)) == set(zip(o.freq_pair_vp, o.freq_pair_ph))


def test_memory_estimate_counts_the_clip():
    # One uint64 a pixel through the gather (the rays are cast in blocks).
    from core import memory
    a = memory.estimate(1000, 1, 1, 8, False, resident=0, clip_kernel=True)
    b = memory.estimate(1000, 1, 1, 8, False, resident=0)
    assert a["pixels"] - b["pixels"] == 1000 * 8 == 1000 * memory.BYTES_PER_CLIP
    code = _codes(_wall_accel(), np.zeros((1000, 3)), np.tile([0.0, 0, 1], (1000, 1)),
                        np.ones(1000), np.ones(1000, bool))
    assert code.nbytes == 1000 * memory.BYTES_PER_CLIP
    # the clip's grid of the triangles near a point, once a render
    assert a["geometry"] - b["geometry"] == memory.BYTES_PER_CLIP_TRIANGLE + memory.CLIP_GRID_BYTES
