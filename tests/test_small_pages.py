"""core.memory.small_pages: a pass's numpy arrays get no huge-page advice, so
a partly touched array is resident by the 4 KiB pages touched, not by whole
2 MiB pages whose number depends on the machine's free huge pages and on
khugepaged's timing (docs/architecture.md "The 1080p peak without huge pages")."""
import threading

import numpy as np
import pytest

from core import memory
from core.render import Renderer

SW = memory._madvise_switch()
pytestmark = pytest.mark.skipif(SW is None, reason="numpy without a huge-page switch")


def test_advice_off_inside_and_restored_after_overlapping_calls():
    seen, inside, leave = [], threading.Event(), threading.Event()

    @memory.small_pages
    def held():
        seen.append(SW[0]())
        inside.set()
        leave.wait(10)

    before = SW[0]()
    t = threading.Thread(target=held)
    t.start()
    inside.wait(10)

    @memory.small_pages
    def short():
        return SW[0]()
    # the second call ends first: the first one's advice stays off
    assert short() is False
    assert SW[0]() is False
    leave.set()
    t.join()
    assert seen == [False]
    assert SW[0]() is before


def test_a_pass_allocates_without_the_advice():
    from analytic_scenes import area_light_plane
    from core.settings import RenderSettings
    r = Renderer(area_light_plane(res=16)[0], RenderSettings(
        integrator="PHOTON", max_passes=2, photons_per_pass=2000, use_frequency=False, seed=1),
        log=lambda m: None)
    seen, cam = [], r.camera_pass

    def camera_pass(*a, **kw):
        seen.append(SW[0]())
        return cam(*a, **kw)
    r.camera_pass = camera_pass
    before = SW[0]()
    r.step()
    assert seen == [False] and SW[0]() is before


def _thp_mode():
    try:
        with open("/sys/kernel/mm/transparent_hugepage/enabled") as f:
            return f.read().split("[")[1].split("]")[0]
    except (OSError, IndexError):
        return None


def test_a_sparse_array_is_resident_by_its_touched_pages():
    # 64 MiB array, one byte written every 2 MiB (32 pages of 4 KiB).  With
    # the advice and huge pages free, each touch faults a 2 MiB page in (64
    # MiB); without it 32 x 4 KiB.  Measured: 0.1-0.2 MiB inside; outside
    # 64 MiB when the kernel had huge pages, ~0.1 MiB when not (the
    # timing-dependent part this removes).
    if _thp_mode() not in ("madvise", "always"):
        pytest.skip("no transparent huge pages")
    if _thp_mode() == "always":
        pytest.skip("THP 'always': every range gets huge pages, advice or not")
    MiB = 2**20

    @memory.small_pages
    def growth():
        r0 = memory.resident_bytes()
        a = np.empty(64 * MiB, np.uint8)
        a[::2 * MiB] = 1
        return memory.resident_bytes() - r0, a
    g, a = growth()
    del a
    assert g < 2 * MiB
