"""The equal-time targets of ``fppm converge`` (tools/converge/report.py):
a tuple denominator is the best of those methods at that time, and a target
judged at several fractions of the budget is judged on its worst ratio."""
import numpy as np

from fppm.tools.converge import report as R
from fppm.tools.converge.runs import Run


def _run(method, err_at_1s, slope=-1.0):
    """A run whose relMSE falls as err_at_1s * t^slope (exact under log-log interpolation)."""
    r = Run(method, 0)
    for t in (1.0, 2.0, 4.0, 8.0, 16.0):
        r.rows.append({"seconds": t, "relmse_all": err_at_1s * t ** slope})
    return r


def test_best_of_and_tuple_denominator():
    runs = [_run("combined", 1.0), _run("path", 2.0), _run("light", 4.0), _run("fppm", 3.0)]
    assert R.best_of(runs, ("fppm", "path", "light"), 8.0) == "path"
    # combined / best single = 1 / 2 at every time (same slopes).
    assert np.isclose(R.ratio(runs, "combined", ("fppm", "path", "light"), 8.0, None, False), 0.5)
    assert np.isnan(R.ratio(runs, "combined", ("appm",), 8.0, None, False))


def test_target_judged_on_worst_fraction():
    # FPPM starts 0.9x PPM at 1 s but falls slower: by 16 s it is 0.9 * 16^0.5 = 3.6x.
    runs = [_run("fppm", 0.9, slope=-0.5), _run("ppm", 1.0)]
    summary = {}
    R._targets(runs, float("nan"), 16.0, "caustic-small", summary)
    t = next(t for t in summary["targets"] if t["target"].startswith("FPPM relMSE <= 1x PPM at 10%"))
    assert not t["met"]
    assert np.isclose(t["ratio"], 0.9 * 16 ** 0.5, rtol=1e-9)      # the worst: at 100%
    missing = [t for t in summary["targets"] if "Combined" in t["target"]]
    assert missing == []                                             # combined not run: not judged
