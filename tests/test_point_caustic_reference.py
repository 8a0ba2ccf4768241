"""bench/point_caustic_reference.py: joining renders of other seeds into one reference.

The 65536-spp point_caustic reference is two ``render`` outputs (16384 spp,
seeds 11 and 12; 49152 spp, seeds 13 and 14) joined by ``finish``: each half
the sample-weighted mean of the files' halves.  Mitsuba is not needed here.
"""
import os
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))
import point_caustic_reference as R  # noqa: E402


def _halves(path, spp, seeds, rng, cpu=None):
    a, b = rng.random((2, 4, 5, 3))
    extra = {} if seeds is None else {"seeds": np.array(seeds)}
    if cpu is not None:
        extra["cpu"] = cpu
    np.savez(path, a=a, b=b, spp=spp, **extra)
    return a, b


def test_join_weights_by_samples(tmp_path):
    rng = np.random.default_rng(3)
    # The first file as the script wrote it before --seeds (no seeds, no cpu): 11, 12.
    a1, b1 = _halves(tmp_path / "h1.npz", 16384, None, rng)
    a2, b2 = _halves(tmp_path / "h2.npz", 49152, (13, 14), rng, cpu=360.0)
    a, b, spp, seeds, cpu = R.join_halves([str(tmp_path / "h1.npz"), str(tmp_path / "h2.npz")])
    # A half of n1 + n2 samples is the mean over all its samples: (n1 A1 + n2 A2) / (n1 + n2).
    np.testing.assert_allclose(a, 0.25 * a1 + 0.75 * a2, rtol=1e-12)
    np.testing.assert_allclose(b, 0.25 * b1 + 0.75 * b2, rtol=1e-12)
    assert spp == 65536 and seeds == [11, 12, 13, 14] and cpu == 360.0


def test_join_refuses_shared_seeds(tmp_path):
    rng = np.random.default_rng(4)
    _halves(tmp_path / "h1.npz", 1024, (11, 12), rng)
    _halves(tmp_path / "h2.npz", 1024, (12, 13), rng)
    with pytest.raises(SystemExit, match="shared seeds"):
        R.join_halves([str(tmp_path / "h1.npz"), str(tmp_path / "h2.npz")])
