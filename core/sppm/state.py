"""The per-pixel progressive state of a render, checkpointed field by field.

Everything a render accumulates over passes is a field of :class:`PixelState`
(P = pixels of the region); ``state_dict()`` / ``load_state()`` are derived
from the fields, so a new field is checkpointed (core.io.checkpoint) without
a key list to keep in step.  Counters and sums are float64 (docs/frequency.md:
float32 counters stall at 2^24).
"""
from __future__ import annotations

from dataclasses import MISSING, dataclass, fields
from typing import Optional

import numpy as np


@dataclass
class PixelState:
    """Per-pixel progressive statistics (Hachisuka 2008 PPM, with a frequency-held radius).

    R2 (P,) float64 squared radius [m^2], 0 = not initialised yet.
    N (P,) float64 accumulated photon count; tau (P, 3) float64 accumulated flux.
    L_sum (P, 3) float64 direct light and emission, summed over passes.
    r_pred_last (P,) float64 predicted radius [m] of the last pass (NaN = no hold).
    held (P,) bool radius held by the prediction in the last pass.
    M_last (P,) float64 photons counted in the last pass.
    depth (P,) float64 camera depth of the pixel's latest visible point (its
      pixel footprint, for the radius in pixels).
    r_hist (P, B) uint32 histogram of the predicted radii of the frequency
      photons gathered so far (QUANTILE estimator, core.sppm.update), or None.
    spectrum (P, 3) float64 spectrum AOV (the photon that predicted the
      smallest radius in the latest pass that had one), or None.
    sectors (P, C) float64 photons counted per sector cell of the kernel disc
      (core.sppm.hashgrid.SECTOR_CELLS = C), accumulated over passes and
      scaled with N by each radius reduction (the radius rules APPM, CPPM and
      the verified holds, core.sppm.update), or None.
    """
    R2: np.ndarray
    N: np.ndarray
    tau: np.ndarray
    L_sum: np.ndarray
    r_pred_last: np.ndarray
    held: np.ndarray
    M_last: np.ndarray
    depth: np.ndarray
    r_hist: Optional[np.ndarray] = None
    spectrum: Optional[np.ndarray] = None
    sectors: Optional[np.ndarray] = None

    @classmethod
    def zeros(cls, P: int, hist_bins: int = 0, spectrum: bool = False,
              sector_cells: int = 0) -> "PixelState":
        """The state before the first pass; hist_bins = 0: no radius histogram;
        sector_cells = 0: no sector counts."""
        return cls(R2=np.zeros(P), N=np.zeros(P), tau=np.zeros((P, 3)), L_sum=np.zeros((P, 3)),
                   r_pred_last=np.full(P, np.inf), held=np.zeros(P, bool), M_last=np.zeros(P),
                   depth=np.zeros(P),
                   r_hist=np.zeros((P, hist_bins), np.uint32) if hist_bins else None,
                   spectrum=np.zeros((P, 3)) if spectrum else None,
                   sectors=np.zeros((P, sector_cells)) if sector_cells else None)

    @classmethod
    def required_keys(cls) -> tuple[str, ...]:
        """Fields every state has (the optional ones default to None)."""
        return tuple(f.name for f in fields(cls) if f.default is MISSING)

    def state_dict(self) -> dict:
        """Copies of every field that is not None, by field name."""
        return {f.name: getattr(self, f.name).copy() for f in fields(self)
                if getattr(self, f.name) is not None}

    # Value range of each float field in a checkpoint (docs/reliability.md,
    # "Checkpoints"): counts, squared radii and depths are >= 0; r_pred_last
    # is a radius > 0, +inf or NaN (no prediction); the sums are finite.
    _RANGES = {"R2": "nonneg", "N": "nonneg", "M_last": "nonneg", "depth": "nonneg",
               "sectors": "nonneg", "tau": "finite", "L_sum": "finite", "spectrum": "finite",
               "r_pred_last": "radius"}

    def check_state(self, d: dict) -> Optional[str]:
        """Why ``d`` (a loaded checkpoint) cannot be loaded into this state, or None.

        Every field this state has must be in d with this state's shape and a
        dtype that converts without loss (same kind: float to float, bool, the
        histogram's unsigned integers), and its values in the field's range.
        """
        for f in fields(self):
            a = getattr(self, f.name)
            if a is None:
                continue
            if f.name not in d:
                return f"no '{f.name}'"
            v = np.asarray(d[f.name])
            if v.shape != a.shape:
                return f"'{f.name}' has shape {v.shape}, this render needs {a.shape}"
            if v.dtype.kind != a.dtype.kind or v.dtype.itemsize > a.dtype.itemsize:
                return f"'{f.name}' is {v.dtype}, this render needs {a.dtype}"
            rule = self._RANGES.get(f.name)
            if rule == "nonneg" and not (np.isfinite(v).all() and (v >= 0).all()):
                return f"'{f.name}' has values that are negative, NaN or infinite"
            if rule == "finite" and not np.isfinite(v).all():
                return f"'{f.name}' has NaN or infinite values"
            if rule == "radius" and (v <= 0).any():
                return f"'{f.name}' has radii <= 0"
        return None

    def load_state(self, d: dict) -> None:
        """Overwrite (in place, keeping dtypes) every field present in d and not None here."""
        for f in fields(self):
            a = getattr(self, f.name)
            if a is not None and f.name in d:
                a[...] = d[f.name]
