"""core.memory's per-pixel bound against a measured render's peak, with the
camera pass's first-hit data off (PHOTON passes without data passes or
merging: CameraPass.first_data, core.sppm.visible_points)."""
import json
import os
import subprocess
import sys

from core import memory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

MEASURE = """
import sys, json
sys.path[:0] = ["tests"]
import fppm_alias  # noqa: core.x is fppm.core.x, the suite's kernel cache (no compile of its own)
from core import memory
from core.render import Renderer
from core.settings import RenderSettings
from analytic_scenes import area_light_plane
def make(res):
    return Renderer(area_light_plane(res=res)[0], RenderSettings(
        integrator="PHOTON", max_passes=10, photons_per_pass=20000, use_frequency=False,
        seed=1), log=lambda m: None)
w = make(16); w.step(); w.step(); del w      # the kernels loaded before the measurement
rss0 = memory.resident_bytes()
r = make(512)
r.step(); r.step()
more = sum(v for k, v in r.memory.items() if k not in ("total", "runtime", "kernels"))
print(json.dumps(dict(growth=memory.peak_bytes_so_far() - rss0, more=more,
                      first=r.camera_pass.first_data)))
"""


def test_first_hits_add_their_bytes_per_pixel():
    a = memory.estimate(1000, 1, 1, 8, False, resident=0)
    b = memory.estimate(1000, 1, 1, 8, False, resident=0, first_hits=False)
    assert a["pixels"] - b["pixels"] == 1000 * memory.BYTES_PER_FIRST_HIT
    assert memory.BYTES_PER_PIXEL + memory.BYTES_PER_FIRST_HIT == 1040


def test_one_first_hit_rule_for_the_camera_pass_and_the_estimate(monkeypatch):
    # memory.keeps_first_hits decides CameraPass.first_data (with the plan's
    # merging) and the estimate's first_hits (before the plan: COMBINED may
    # merge), so the estimate counts the first hits whenever the pass keeps them.
    from core.render import Renderer
    from core.settings import RenderSettings
    from analytic_scenes import area_light_plane
    K = memory.keeps_first_hits
    for dp in (False, True):
        for integ in ("PHOTON", "PATH", "LIGHT", "COMBINED"):
            for merging in (False, True) if integ == "COMBINED" else (False,):
                assert K(dp, integ, merging) <= K(dp, integ)
    assert not K(False, "PHOTON") and K(False, "COMBINED") and not K(False, "COMBINED", False)
    estimated = []
    orig = memory.estimate
    monkeypatch.setattr(memory, "estimate",
                        lambda *a, **kw: estimated.append(kw["first_hits"]) or orig(*a, **kw))
    scene = area_light_plane(res=8)[0]
    got = {}
    for integ, passes in (("PHOTON", ()), ("PHOTON", ("Depth",)), ("COMBINED", ())):
        r = Renderer(scene, RenderSettings(integrator=integ, use_frequency=False, max_passes=1),
                     log=lambda m: None, passes=passes)
        got[integ, passes] = (r.camera_pass.first_data, estimated.pop())
    # (kept by the camera pass, counted by the estimate); the plane has no
    # delta vertex, so COMBINED does not merge, yet its bound counts them.
    assert got == {("PHOTON", ()): (False, False), ("PHOTON", ("Depth",)): (True, True),
                   ("COMBINED", ()): (False, True)}


def test_estimate_bounds_a_photon_render_without_first_hits():
    # 512^2 PHOTON passes (20k photons), peak growth after the kernels are
    # loaded against the estimate of what the passes allocate.  Measured
    # (shared machine, load 2-9, the next pass's photons traced early):
    # growth 145-160 MiB, estimate / growth 1.7-1.9 (the bound covers the numpy light sampler and delta chains at
    # every pixel, which this scene does not have).
    # Twice, the first run discarded: kernels that only a 512^2 pass takes
    # (the parallel variants of the grid build and the update) are compiled
    # there if the cache lacks them, and LLVM's memory would count in the
    # peak (a cold cache read 244-266 MiB of growth instead of 123-160).
    for _ in range(2):
        r = subprocess.run([sys.executable, "-c", MEASURE], cwd=ROOT, capture_output=True,
                           text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    rec = json.loads(r.stdout.strip().splitlines()[-1])
    assert rec["first"] is False
    ratio = rec["more"] / rec["growth"]
    print(f"growth {rec['growth'] / 2**20:.0f} MiB, estimate / growth {ratio:.2f}")
    assert 1.0 <= ratio <= 2.4
