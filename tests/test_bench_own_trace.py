"""bench/bench_hold_alpha.py's per-pass CPU: every pass billed its own
photons' trace (OwnTrace; docs/method.md "The frequency passes' fixed cost").

The trace-ahead traces pass k + 1's photons inside step k, except before a
frequency pass (pass 2^j: its photons read pass 2^j - 1's radii) and after
the last pass of max_passes.  A step's own CPU is its settled CPU less the
traces that ran in it plus its own pass's, so (T(k): pass k's trace, > 0)
own(k) - billed(k) = T(k) - (traces run in step k):

- FPPM pass 3 (traces nothing ahead; its own ran in step 2): +T(3) > 0;
- FPPM pass 4 (its own trace and pass 5's): -T(5) < 0;
- FPPM pass 8, the last (its own trace alone): 0;
- PPM pass 8, the last (traced in step 7, nothing ahead): +T(8) > 0;
and over a run that ends at max_passes the sums agree.  These are
identities of the bookkeeping, so they hold whatever the machine's load.
"""
import os
import sys

import pytest

from core.render import Renderer
from core.settings import RenderSettings
from core.sppm import photon_pass as PP
from core.sppm import photons as Ph

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "bench"))
from test_photon_kernels import cornell  # noqa: E402

# Imported after core (numba loaded), the bench leaves NUMBA_NUM_THREADS and
# FPPM_PHOTON_THREADS alone (see its header).
bench = pytest.importorskip("bench_hold_alpha")


def _run(frequency, passes=8):
    st = RenderSettings(integrator="PHOTON", photons_per_pass=4000, max_passes=passes,
                        use_frequency=frequency, seed=3)
    r = Renderer(cornell(), st, log=lambda s: None)
    own, billed = [], []
    for _ in range(passes):
        _, c = bench.step_cpu(r)
        own.append(c)
        billed.append(r._own_trace.billed)
    return r, own, billed


def test_each_pass_billed_its_own_trace(monkeypatch):
    monkeypatch.setattr(Ph, "THREADS", 1)       # exact: a trace's halves in its own thread
    assert PP.TRACE_AHEAD and PP.TRACE_NEXT_PASS
    r, own, billed = _run(True)
    assert r.photon_pass.frequency and r.photon_pass.chunks(4)[0][1] > 0   # pass 4 traces some
    assert r._own_trace.exact and r._own_trace.done == []                # every trace attributed
    d = [o - b for o, b in zip(own, billed)]
    assert d[2] > 0                     # pass 3: its own trace ran in step 2, none in step 3
    assert d[3] < 0                     # pass 4: pass 5's trace ran in step 4
    assert d[7] == pytest.approx(0.0, abs=1e-12)       # the last pass: its own trace alone
    assert sum(own) == pytest.approx(sum(billed), abs=1e-9)
    r, own, billed = _run(False)
    d = [o - b for o, b in zip(own, billed)]
    assert d[7] > 0                     # PPM's last pass: traced in step 7, nothing ahead
    assert sum(own) == pytest.approx(sum(billed), abs=1e-9)
