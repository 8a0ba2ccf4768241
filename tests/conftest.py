import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)

import fppm_alias  # noqa: E402,F401  (core.x is fppm.core.x: one numba cache)
