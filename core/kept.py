"""Pixel-sized arrays kept from one pass to the next, so that a pass does not
page-fault its outputs in afresh.

    kept = KeptArrays()
    arrays = kept.get(make, key)   # make() -> list of new arrays, each filled with one value

A stage that returns pixel-sized arrays (the camera pass's visible points and
first hits, the photon pass's sums) used to allocate them every pass.  Arrays
that large come from ``mmap`` and go back to the kernel when freed; on the
virtual machines FPPM is measured on, freed memory also goes back to the host
(virtio balloon free page reporting), so each pass paid their page faults
again, in the kernel and mostly on one core at a time (docs/architecture.md,
"Cores used").  Here the arrays of the last call are cleared (a memset of
memory already mapped, in two threads) and returned again -- but only when
nothing else holds any of them any more: a caller that keeps a result (fixed
visible points, a test comparing two passes, a view of one array) gets new
arrays, and its result is never overwritten.
"""
from __future__ import annotations

import sys

import numpy as np

#: Arrays of at least this many bytes are cleared in two threads.
CLEAR_SPLIT_BYTES = 1 << 22


def _refcounts(arrays: list) -> list:
    return [sys.getrefcount(a) for a in arrays]


#: References to an array that a list alone holds, counted as ``_refcounts``
#: counts them (the list, the loop variable, the call's argument).
_ALONE = _refcounts([np.empty(0)])[0]


class KeptArrays:
    """The arrays last returned by :meth:`get`, and the value each is cleared to."""

    def __init__(self):
        self._arrays: list | None = None
        self._fills: list = []
        self._key = None
        self.reused = 0

    def get(self, make, key=None) -> list:
        """The arrays of the last call, cleared to the values they were made
        with, when that call had the same key (what decides their shapes and
        dtypes) and none of them is referenced outside this object; else
        make()'s new arrays (each uniformly filled: np.zeros, np.ones,
        np.full), kept for the next call."""
        held = self._arrays
        if held is not None and key == self._key and max(_refcounts(held)) <= _ALONE:
            _clear(held, self._fills)
            self.reused += 1
            return list(held)
        arrays = list(make())
        self._fills = [a.reshape(-1)[0] if a.size else 0 for a in arrays]
        self._arrays, self._key = arrays, key
        return list(arrays)


def _clear(arrays: list, fills: list) -> None:
    """arrays[i][...] = fills[i]; the large ones as two halves in two threads
    (numpy releases the GIL while it fills)."""
    from .sppm.photons import _pool, _threads
    big = [(a.reshape(-1), f) for a, f in zip(arrays, fills) if a.nbytes >= CLEAR_SPLIT_BYTES]
    for a, f in zip(arrays, fills):
        if a.nbytes < CLEAR_SPLIT_BYTES:
            a[...] = f
    if not big:
        return

    def second_halves():
        for flat, f in big:
            flat[flat.size // 2:] = f
    if _threads() > 1:
        fut = _pool().submit(second_halves)
        for flat, f in big:
            flat[:flat.size // 2] = f
        fut.result()
    else:
        for flat, f in big:
            flat[...] = f


#: A KeptBuffers buffer is allocated this many times the bytes asked for.
GROW = 1.25

#: Arrays carved from a KeptBuffers buffer start at multiples of this many
#: bytes (a cache line: numba's and numpy's own alignment is 16 or 32).
ALIGN = 64


class KeptBuffers:
    """Named grow-only byte buffers kept from pass to pass, from which a
    stage carves its arrays (``take``): the grid build's and the gather's
    arrays, whose sizes change a little from pass to pass (the number of
    cell entries and of hash slots), so that they are not page-faulted in
    afresh every pass (docs/architecture.md, "The grid build's arrays kept").

        views = kept.take("name", [(shape, dtype), ...])

    The arrays are uninitialised views of one buffer, consecutive.  A buffer
    is handed out again only when nothing else references it (no view of its
    last ``take`` is alive: a grid a caller keeps is never overwritten);
    otherwise, or when it is too small, a new one is allocated (and kept).
    ``allocations`` counts the buffers allocated, ``reused`` the takes that
    reused one."""

    def __init__(self):
        self._bufs: dict = {}
        self.allocations = 0
        self.reused = 0

    def take(self, name: str, specs) -> list:
        offs, counts, n = [], [], 0
        for shape, dtype in specs:
            offs.append(n)
            counts.append(int(np.prod(shape, dtype=np.int64)))
            n += -(-counts[-1] * np.dtype(dtype).itemsize // ALIGN) * ALIGN
        buf = self._bufs.get(name)
        # the arrays start at the buffer's first aligned byte, so a reused
        # buffer must hold n bytes past its own alignment offset
        if (buf is not None and buf.nbytes - _aligned_offset(buf) >= n
                and sys.getrefcount(buf) <= _ALONE_BUF):
            self.reused += 1
        else:
            # drop the old one first: its pages go back before the new one's
            # are touched (unless a caller still holds it)
            self._bufs.pop(name, None)
            buf = None
            # ALIGN extra bytes: the first array starts at an aligned address;
            # GROW: room for the next passes' slightly larger takes (pages
            # never touched are not resident)
            buf = self._bufs[name] = np.empty(int(n * GROW) + ALIGN, np.uint8)
            self.allocations += 1
        base = _aligned_offset(buf)
        out = []
        for (shape, dtype), o, cnt in zip(specs, offs, counts):
            dt = np.dtype(dtype)
            out.append(buf[base + o:base + o + cnt * dt.itemsize].view(dt).reshape(shape))
        return out

    def nbytes(self) -> int:
        """Bytes of the buffers kept (resident once touched)."""
        return sum(b.nbytes for b in self._bufs.values())


def _aligned_offset(buf: np.ndarray) -> int:
    """Bytes from the start of buf to its first ALIGN-aligned byte."""
    return (-buf.ctypes.data) % ALIGN


def _buf_refs() -> int:
    d = {"x": np.empty(1, np.uint8)}
    return sys.getrefcount(d["x"])


#: References to a buffer that the dict alone holds, counted as ``take``
#: counts them (the dict, the local, the call's argument).
_ALONE_BUF = _buf_refs() + 1
