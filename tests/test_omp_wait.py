"""numba's OpenMP workers sleep between parallel regions (core/__init__.py).

Importing ``core`` sets ``OMP_WAIT_POLICY=PASSIVE`` unless it is already
set.  What is asserted: in a fresh process that imports ``core`` and then
runs a small parallel kernel 200 times with 1 ms of sleep after each, the
process's CPU a round stays under 0.3 ms (measured 0.04 ms at load 9; with
libgomp's default spin the same loop billed 8.7 ms a round, the worker
spinning through the sleep and past it); with ``OMP_WAIT_POLICY=ACTIVE``
set by the user, the setting is kept (``setdefault``) and the workers spin:
more than 3x the passive CPU (spinning through the 1 ms sleeps: ~1 ms a
round or more).
"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_SCRIPT = r"""
import os, time
import core
import numba
import numpy as np

@numba.njit(parallel=True, cache=False)
def f(a):
    for c in numba.prange(a.shape[0]):
        a[c] += 1.0

numba.set_num_threads(2)
a = np.ones(2)
f(a)
c0 = time.process_time()
for _ in range(200):
    f(a)
    time.sleep(0.001)
print(os.environ["OMP_WAIT_POLICY"], (time.process_time() - c0) / 200)
"""


def _round_cpu(policy):
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    env["NUMBA_NUM_THREADS"] = "2"
    if policy:
        env["OMP_WAIT_POLICY"] = policy
    out = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, cwd=ROOT, check=True,
                         capture_output=True, text=True, timeout=120).stdout.split()
    return out[-2], float(out[-1])


@pytest.mark.serial          # times itself (tests/conftest.py)
def test_workers_sleep_between_regions():
    policy, passive = _round_cpu(None)
    assert policy == "PASSIVE"
    assert passive < 0.3e-3, passive
    policy, active = _round_cpu("ACTIVE")
    assert policy == "ACTIVE"                 # the user's setting wins
    assert active > 3 * passive, (active, passive)
