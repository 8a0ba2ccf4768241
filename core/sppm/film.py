"""The film: the radiance estimate of every pixel and the AOVs, from the progressive state.

    L = L_sum / passes + tau / (pi R^2 N_emitted)        (docs/method.md, "Film")

(direct light and emission averaged over the passes, plus the photon density
estimate of Hachisuka 2008).  AOVS is the one table of the extra passes: name,
channels, the RenderSettings flag that turns it on, and how it is computed.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np

_F32_MAX = np.finfo(np.float32).max


@dataclass
class PassResult:
    """What a pass shows: image (H, W, 4) float32 RGBA linear radiance with row
    0 at the TOP, aovs name -> (H, W, C) float32, counters and statistics."""
    pass_index: int
    photons_emitted: int
    elapsed: float
    image: np.ndarray
    aovs: dict = field(default_factory=dict)
    mean_radius_px: float = 0.0
    held_fraction: float = 0.0

    def stats_line(self) -> str:
        m, s = divmod(int(self.elapsed), 60)
        return (f"Pass {self.pass_index} | {self.photons_emitted / 1e6:.1f} M photons | "
                f"{m}:{s:02d} | mean radius {self.mean_radius_px:.2f} px")


class Aov(NamedTuple):
    """One AOV: compute(state, R, r_px) -> (P, channels) or (P,) per-pixel
    values from the PixelState, the radius R (P,) [m] (0 = none yet) and the
    radius in pixel footprints r_px (P,)."""
    name: str
    channels: int
    setting: str
    compute: Callable


def _spectrum(s, R, r_px):
    # The PAPER model is unguarded by design and can overflow: the AOV stays
    # finite (NaN -> 0, +-inf -> +-float32 max) so viewers cope.
    return np.nan_to_num(np.clip(s.spectrum, -_F32_MAX, _F32_MAX), nan=0.0)


AOVS = (
    Aov("FPPM Radius", 1, "aov_radius", lambda s, R, r_px: R),
    Aov("FPPM Radius px", 1, "aov_radius", lambda s, R, r_px: r_px),
    Aov("Predicted Radius", 1, "aov_predicted_radius",
        lambda s, R, r_px: np.where(np.isfinite(s.r_pred_last), s.r_pred_last, 0.0)),
    Aov("Spectrum", 3, "aov_spectrum", _spectrum),
    Aov("Photon Count", 1, "aov_photon_count", lambda s, R, r_px: s.N),
    Aov("Held", 1, "aov_held", lambda s, R, r_px: s.held),
)


class Film:
    """settings: RenderSettings (the AOV flags); camera: CameraModel (pixel
    footprint); H, W: the region's size."""

    def __init__(self, settings, camera, H: int, W: int):
        self.settings, self.camera, self.H, self.W = settings, camera, H, W

    def __call__(self, state, pass_index: int, photons_emitted: int, elapsed: float) -> PassResult:
        """The PassResult of the state after pass_index passes."""
        H, W = self.H, self.W
        L = state.L_sum / max(pass_index, 1)
        R2 = np.where(state.R2 > 0, state.R2, np.inf)
        L = L + state.tau / (np.pi * R2[:, None] * max(photons_emitted, 1))
        L = np.where(np.isfinite(L), L, 0.0)
        img = np.ones((H, W, 4), np.float32)
        img[..., :3] = L.reshape(H, W, 3)
        R = np.sqrt(np.where(state.R2 > 0, state.R2, 0.0))
        fp = self.camera.footprint(state.depth)
        r_px = np.where(fp > 0, R / np.maximum(fp, 1e-300), 0.0)
        aovs = {a.name: a.compute(state, R, r_px).reshape(H, W, a.channels).astype(np.float32)
                for a in AOVS if getattr(self.settings, a.setting)}
        valid = state.R2 > 0
        mean_px = float(r_px[valid].mean()) if np.any(valid) else 0.0
        held = float(state.held.mean()) if state.held.size else 0.0
        return PassResult(pass_index, photons_emitted, elapsed, img, aovs, mean_px, held)
