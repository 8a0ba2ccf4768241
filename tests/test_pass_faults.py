"""Pixel-sized arrays a pass no longer page-faults in afresh
(docs/architecture.md "The 1080p clip, camera and film without per-pass
allocations"): the film's image reused in place once no caller holds the
last one, its mean radius in pixels without the masked copy, the camera's
depth factors carried with the live chains instead of a (P,) array.  The
camera pass's chains are checked against the numpy reference bit for bit by
tests/test_compiled_stages.py; here the film and whole renders.
"""
import numpy as np
import pytest

from core.render import Renderer
from core.settings import RenderSettings
from core.sppm import film as Fm
from analytic_scenes import area_light_plane


@pytest.mark.parametrize("P", [1, 1000, 1 << 17])
def test_compacted_mean_is_the_masked_mean(P):
    """r_px[R2 > 0].mean() and the in-place compaction's mean: the same bits,
    for a fifth to all of the pixels valid (and none)."""
    rng = np.random.default_rng(P)
    for frac in (0.0, 0.2, 0.9, 1.0):
        R2 = np.where(rng.random(P) < frac, rng.uniform(1e-6, 1.0, P), 0.0)
        x = rng.lognormal(0.0, 2.0, P)
        want = float(x[R2 > 0].mean()) if np.any(R2 > 0) else None
        n = Fm._compact_positive(R2, x)
        assert n == np.count_nonzero(R2 > 0)
        if want is not None:
            assert float(x[:n].mean()) == want


def _renderer(res=48, passes=10):
    return Renderer(area_light_plane(res=res)[0], RenderSettings(
        integrator="PHOTON", max_passes=passes, photons_per_pass=3000, use_frequency=False,
        seed=3), log=lambda m: None)


def test_the_image_is_reused_only_when_no_caller_holds_it():
    a, b = _renderer(), _renderer()
    a.step()
    kept = a.step()                     # held: the next pass must not write into it
    pixels = kept.image.copy()
    third = a.step()
    assert not np.shares_memory(kept.image, third.image)
    assert np.array_equal(kept.image, pixels)
    addr = third.image.ctypes.data
    del third                           # dropped: the next pass's film reuses it
    fourth = a.step()
    assert fourth.image.ctypes.data == addr
    # the same images as a renderer whose caller holds every result
    held = [b.step() for _ in range(4)]
    assert np.array_equal(held[1].image, pixels)
    assert np.array_equal(held[3].image, fourth.image)
    assert held[3].mean_radius_px == fourth.mean_radius_px


def test_render_loop_does_not_hold_the_last_result():
    """Renderer.run hands each result to on_pass and then drops it: with a
    caller that keeps none, the passes after the second reuse one image."""
    r = _renderer(passes=4)
    seen = []
    r.run(on_pass=lambda res: seen.append(res.image.ctypes.data))
    assert len(seen) == 4 and len(set(seen[1:])) == 1
