import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)


# A whole-suite run on a cold kernel cache first compiles the suite's kernels
# in two processes at once (tests/precompile.py; docs/architecture.md "The
# test suite's time, round 19"): the compile then takes both cores of the CI
# machine instead of one, and the tests load the kernels from the cache.
# FPPM_PRECOMPILE=0 never does it, =1 does it for any selection of tests;
# by default only a run of at least PRECOMPILE_MIN_TESTS tests does (a single
# file compiles only what it needs, as before).  A run in pytest-xdist
# workers (`-n 2`) is a whole-suite run: its controller always does it.
PRECOMPILE_MIN_TESTS = 300

# Tests that time themselves (a cancel's latency, a responsive viewport or
# warm-up, CPU seconds per pass) carry the marker "serial".  `make test` runs
# the others in two pytest-xdist workers and then these alone, so that the
# other worker's load never stretches what they measure (docs/architecture.md
# "The test suite's time, round 48").
def pytest_configure(config):
    config.addinivalue_line("markers", "serial: times itself; `make test` runs it with no "
                                       "other test beside it")


def _precompile(config, n_items):
    """Compile every kernel into an empty cache first, in two processes
    (tests/precompile.py), when the run is large enough to use them."""
    flag = os.environ.get("FPPM_PRECOMPILE", "")
    if flag == "0" or config.option.collectonly:
        return
    if flag != "1" and n_items is not None and n_items < PRECOMPILE_MIN_TESTS:
        return
    import precompile
    if precompile.is_precompiled():
        return
    tr = config.pluginmanager.get_plugin("terminalreporter")
    say = (lambda s: tr.write_line(s)) if tr is not None else print
    say("compiling the kernels into the empty cache in two processes (tests/precompile.py) ...")
    res = precompile.precompile(2, log=say)
    say(f"compiled in {res['wall']:.0f} s ({res['cpu']:.0f} s of CPU)"
        + ("" if res["ok"] else "; the tests compile the rest"))


def _xdist_workers(config) -> int:
    return int(getattr(config.option, "numprocesses", None) or 0)


def pytest_sessionstart(session):
    # Under pytest-xdist the controller compiles before its workers start
    # (xdist starts them in its own, later, sessionstart); the workers never do.
    if _xdist_workers(session.config) and not hasattr(session.config, "workerinput"):
        _precompile(session.config, None)


def pytest_collection_finish(session):
    if hasattr(session.config, "workerinput") or _xdist_workers(session.config):
        return
    if session.items:
        _precompile(session.config, len(session.items))
