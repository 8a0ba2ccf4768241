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
# file compiles only what it needs, as before).
PRECOMPILE_MIN_TESTS = 300


def pytest_collection_finish(session):
    flag = os.environ.get("FPPM_PRECOMPILE", "")
    if flag == "0" or session.config.option.collectonly or not session.items:
        return
    if flag != "1" and len(session.items) < PRECOMPILE_MIN_TESTS:
        return
    import precompile
    if precompile.is_precompiled():
        return
    tr = session.config.pluginmanager.get_plugin("terminalreporter")
    say = (lambda s: tr.write_line(s)) if tr is not None else print
    say("compiling the kernels into the empty cache in two processes (tests/precompile.py) ...")
    res = precompile.precompile(2, log=say)
    say(f"compiled in {res['wall']:.0f} s ({res['cpu']:.0f} s of CPU)"
        + ("" if res["ok"] else "; the tests compile the rest"))
