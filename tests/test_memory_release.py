"""core.memory.release_free_heap: glibc keeps the pages of freed arrays below
its dynamic mmap threshold resident; the call hands them back (the 1080p
pass's peak, docs/architecture.md "Performance")."""
import numpy as np
import pytest

from core import memory


def test_small_images_do_not_call():
    assert memory.release_free_heap(memory.RELEASE_MIN_ITEMS - 1) is False


def test_freed_heap_pages_are_returned():
    MiB = 2**20
    # One freed mmapped array raises glibc's mmap threshold to its size: the
    # next arrays of that size come from the heap, like a pass's temporaries.
    a = np.ones(2 * MiB // 8)
    del a
    arrays = [np.ones(2 * MiB // 8) for _ in range(40)]      # 80 MiB touched
    keep = arrays.pop()                                       # holds the heap's top
    rss0 = memory.resident_bytes()
    del arrays
    rss1 = memory.resident_bytes()
    if not memory.release_free_heap():
        pytest.skip("no glibc malloc_trim")
    rss2 = memory.resident_bytes()
    # Measured: glibc kept all 78 MiB freed (RSS -0.0 MiB), the call returned
    # 78.2 MiB; the bounds leave half of it to allocator differences.
    assert rss0 - rss1 < 39 * MiB
    assert rss1 - rss2 > 39 * MiB
    assert rss2 - (rss0 - 78 * MiB) < 8 * MiB
    del keep
