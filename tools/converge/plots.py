"""Images of ``fppm converge`` (matplotlib, a development dependency): the
convergence plot and 8-bit previews of the final images.

matplotlib is imported inside the functions, so ``fppm render`` (which loads
the ``converge`` parser) never imports it.
"""
from __future__ import annotations

import numpy as np

from .. import metrics as M
from .runs import methods_run

COLORS = {"fppm": "tab:red", "paper": "tab:orange", "ppm": "tab:blue", "cycles": "tab:green",
          "appm": "tab:cyan", "cppm": "tab:olive", "path": "tab:brown", "light": "tab:pink",
          "combined": "tab:purple"}


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def srgb8(img, exposure_gain: float = 1.0) -> np.ndarray:
    """(H, W, >=3) linear radiance -> (H, W, 3) uint8 sRGB: Blender's 'Standard'
    view (clamp to [0, 1], then the sRGB OETF of IEC 61966-2-1)."""
    a = np.clip(np.asarray(img, np.float64)[..., :3] * exposure_gain, 0.0, 1.0)
    s = np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.power(a, 1 / 2.4) - 0.055)
    return (np.clip(s, 0, 1) * 255 + 0.5).astype(np.uint8)


def write_png(path: str, img, exposure_gain: float = 1.0) -> None:
    """Write a linear (H, W, >=3) image as an 8-bit sRGB PNG (row 0 at the top)."""
    import matplotlib.image
    matplotlib.image.imsave(path, srgb8(img, exposure_gain), format="png")


def plot(path: str, runs, budget, floors, title) -> None:
    """convergence.png: relMSE (top row) and HDR-FLIP (bottom row) against time,
    log-log, one column per region; ``floors`` {region: relMSE floor} drawn as lines.

    One seed: its recorded points; several: the geometric mean of the
    log-log interpolated curves, the seed spread shaded.  One figure for both
    metrics: a second figure would double the time of writing the outputs
    (after a Ctrl-C too).
    """
    plt = _pyplot()
    fig, axes = plt.subplots(2, len(M.REGIONS), figsize=(16, 7.5), sharex=True)
    for row, metric in zip(axes, ("relmse", "flip")):
        for ax, reg in zip(row, M.REGIONS):
            _panel(ax, runs, budget, f"{metric}_{reg}", floors.get(reg) if metric == "relmse" else None)
            ax.set_title(f"{reg}")
            ax.set_ylabel({"relmse": "relMSE", "flip": "HDR-FLIP"}[metric])
    for ax in axes[1]:
        ax.set_xlabel("seconds")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _panel(ax, runs, budget, key, fl) -> None:
    """One panel: the error ``key`` (a CSV column) of every method against time."""
    for m in methods_run(runs):
        mr = [r for r in runs if r.method == m and r.rows and key in r.rows[0]]
        if not mr:
            continue
        tmin = max(min(row["seconds"] for row in r.rows) for r in mr)
        tmax = min(max(row["seconds"] for row in r.rows) for r in mr)
        if len(mr) == 1 or tmax <= tmin:
            pts = [(row["seconds"], row[key]) for row in mr[0].rows if np.isfinite(row[key])]
            ax.plot([p[0] for p in pts], [p[1] for p in pts],
                    "-" if m != "cycles" else "o-", color=COLORS.get(m), label=m.upper(), ms=3)
            continue
        grid = np.geomspace(tmin, tmax, 60)
        vals = np.array([[M.loglog_interp(t, [row["seconds"] for row in r.rows],
                                          [row[key] for row in r.rows]) for t in grid]
                         for r in mr])
        ax.plot(grid, np.exp(np.nanmean(np.log(vals), axis=0)), color=COLORS.get(m),
                label=f"{m.upper()} ({len(mr)} seeds)")
        ax.fill_between(grid, np.nanmin(vals, axis=0), np.nanmax(vals, axis=0),
                        color=COLORS.get(m), alpha=0.2, lw=0)
    if fl is not None and np.isfinite(fl) and fl > 0:
        ax.axhline(fl, color="grey", ls=":", lw=1, label="reference noise")
    ax.axvline(budget, color="k", ls="--", lw=0.8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    # Major grid lines only: minor ticks on log axes are most of the drawing time.
    ax.grid(True, which="major", alpha=0.3)
    ax.minorticks_off()
