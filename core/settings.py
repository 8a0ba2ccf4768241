"""Render settings: a frozen dataclass mirrored one to one by ``scene.fppm``.

The add-on's PropertyGroup (``addon/properties.py``) has exactly these field
names; ``tests/test_settings_mirror.py`` checks it.  ``validate()`` is the
single place where invalid settings are rejected with a clear sentence.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass


class SettingsError(ValueError):
    """An invalid setting; the message names the setting and its valid range."""


@dataclass(frozen=True)
class RenderSettings:
    # --- Sampling
    time_limit: float = 0.0          # seconds of passes; 0 = no limit
    max_passes: int = 64             # 0 = no limit (then time_limit must be > 0)
    photons_per_pass: int = 200_000
    seed: int = 0
    use_animated_seed: bool = False  # each frame's seed mixes in the frame number (frame_seed; Cycles' Animated Seed)
    # --- Integrator (docs/integrators.md)
    integrator: str = "COMBINED"     # 'COMBINED' (path + light tracing, merging), 'PHOTON', 'PATH', 'LIGHT'
    camera_samples: int = 4          # PATH, COMBINED: camera paths per pixel and pass
    light_paths_per_camera_path: float = 0.0  # COMBINED: light paths per pass / camera paths (0 = photons_per_pass)
    camera_depth: str = "AUTO"       # COMBINED: where camera paths from a diffuse first vertex stop ('AUTO', 'FULL', 'EMITTERS', 'DIRECT'; docs/integrators.md "Camera depth")
    merge_weights: str = "PARTITION"  # COMBINED: photon merging by path classes ('PARTITION') or as an MIS strategy ('MIS')
    # --- Kernel
    radius_mode: str = "AUTO"        # 'AUTO' (pixel footprint) or 'WORLD'
    initial_radius_px: float = 2.0   # AUTO: radius = this many pixel footprints
    initial_radius: float = 0.05     # WORLD: radius in metres
    alpha: float = 0.7               # PPM radius reduction (Hachisuka 2008)
    cap_radius_at_edges: bool = True  # initial radius <= half the distance to a surface boundary (core.edges)
    clip_kernel: bool = True         # kernel discs clipped at walls by short tangent rays (core.sppm.clip)
    radius_rule: str = "PPM"         # 'PPM' (global alpha), 'APPM' or 'CPPM' (per pixel; docs/method.md "Radius rules")
    # --- Light paths
    max_bounces: int = 16            # as the example scenes' Cycles Light Paths
    rr_start: int = 3                # Russian roulette from this bounce on
    photons_for_direct: bool = False  # classic PPM: photons also for direct light
    fixed_visible_points: bool = False  # classic PPM: trace visible points once
    glossy_chains: bool = True       # PHOTON: camera paths go on through materials without a diffuse lobe (pbrt-v4 SPPM; docs/method.md "Glossy chains, round 30")
    light_samples: int = 0           # PHOTON: next-event estimates per visible point and pass, averaged; 0 = automatic (core.plan.auto_light_samples; docs/method.md "Light samples at the visible points, round 31")
    # --- Frequency
    use_frequency: bool = True
    frequency_fraction: float = 0.25
    frequency_decay: float = 2.0        # pass k: frequency_fraction * k^-decay (docs/method.md "Amortised ...", "The frequency schedule ...")
    frequency_start: int = 2            # first pass with frequency photons; the schedule runs from it (docs/method.md "A late start for the frequency photons, round 18"; 2 the default: "Round 19: the rings and the decision")
    frequency_model: str = "CORRECTED"  # 'CORRECTED' or 'PAPER'
    frequency_estimator: str = "MIN"    # 'MIN' or 'QUANTILE'
    hold_alpha: float = 0.9             # PPM alpha of a held radius (1 = held forever; docs/method.md)
    verify_holds: bool = True           # the photons' sector tests veto, add and grow holds (docs/method.md "X as the default")
    occlusion_grid_res: int = 64
    # --- Output (AOV passes)
    aov_radius: bool = False            # FPPM Radius (world and pixels)
    aov_predicted_radius: bool = False
    aov_spectrum: bool = False
    aov_photon_count: bool = False
    aov_held: bool = False

    def validate(self) -> "RenderSettings":
        """Raise SettingsError naming the first invalid field; return self."""
        def bad(name, why):
            raise SettingsError(f"setting '{name}' = {getattr(self, name)!r}: {why}")
        for name in ("time_limit", "initial_radius_px", "initial_radius", "alpha",
                     "frequency_fraction", "frequency_decay", "hold_alpha"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                bad(name, "must be a finite number")
        if self.integrator not in ("PHOTON", "PATH", "LIGHT", "COMBINED"):
            bad("integrator", "must be 'PHOTON', 'PATH', 'LIGHT' or 'COMBINED'")
        if self.time_limit < 0:
            bad("time_limit", "must be >= 0 (0 = no limit)")
        if self.max_passes < 0:
            bad("max_passes", "must be >= 0 (0 = no limit)")
        if self.max_passes == 0 and self.time_limit == 0:
            bad("max_passes", "0 (unlimited) needs a time_limit > 0")
        if not 1 <= self.photons_per_pass <= 100_000_000:
            bad("photons_per_pass", "must be in [1, 100000000]")
        if not 0 <= self.seed < 2**31:
            bad("seed", "must be in [0, 2^31)")
        if not 1 <= self.camera_samples <= 4096:
            bad("camera_samples", "must be in [1, 4096]")
        if not 0 <= self.light_samples <= 64:
            bad("light_samples", "must be in [0, 64] (0: automatic)")
        if self.camera_depth not in ("AUTO", "FULL", "EMITTERS", "DIRECT"):
            bad("camera_depth", "must be 'AUTO', 'FULL', 'EMITTERS' or 'DIRECT'")
        if not (math.isfinite(self.light_paths_per_camera_path)
                and 0 <= self.light_paths_per_camera_path <= 10_000):
            bad("light_paths_per_camera_path", "must be in [0, 10000] (0 = photons_per_pass)")
        if self.merge_weights not in ("PARTITION", "MIS"):
            bad("merge_weights", "must be 'PARTITION' or 'MIS'")
        if self.radius_mode not in ("AUTO", "WORLD"):
            bad("radius_mode", "must be 'AUTO' or 'WORLD'")
        if not 0 < self.initial_radius_px <= 1000:
            bad("initial_radius_px", "must be in (0, 1000]")
        if not self.initial_radius > 0:
            bad("initial_radius", "must be > 0 metres")
        if not 0 < self.alpha <= 1:
            bad("alpha", "must be in (0, 1]")
        if not 0 < self.hold_alpha <= 1:
            bad("hold_alpha", "must be in (0, 1] (1 = a held radius never shrinks; "
                              "<= alpha = never hold)")
        if self.radius_rule not in ("PPM", "APPM", "CPPM"):
            bad("radius_rule", "must be 'PPM', 'APPM' or 'CPPM'")
        if self.radius_rule != "PPM" and self.use_frequency and self.integrator == "PHOTON":
            bad("radius_rule", "APPM and CPPM are the per-pixel radius baselines without "
                               "frequency photons: turn Frequency off (use_frequency), or use "
                               "'PPM' with verify_holds for frequency holds the photons check")
        if not 1 <= self.max_bounces <= 1024:
            bad("max_bounces", "must be in [1, 1024]")
        if not 0 <= self.rr_start <= 1024:
            bad("rr_start", "must be in [0, 1024]")
        if not 0 <= self.frequency_fraction <= 1:
            bad("frequency_fraction", "must be in [0, 1]")
        if not 0 <= self.frequency_decay <= 2:
            bad("frequency_decay", "must be in [0, 2] (0 = every pass traces frequency_fraction)")
        if not isinstance(self.frequency_start, int) or not 1 <= self.frequency_start <= 1_000_000:
            bad("frequency_start", "must be an integer in [1, 1000000] (1 = from the first pass)")
        if self.frequency_model not in ("CORRECTED", "PAPER"):
            bad("frequency_model", "must be 'CORRECTED' or 'PAPER'")
        if self.frequency_estimator not in ("MIN", "QUANTILE"):
            bad("frequency_estimator", "must be 'MIN' or 'QUANTILE'")
        if not 4 <= self.occlusion_grid_res <= 512:
            bad("occlusion_grid_res", "must be in [4, 512]")
        return self

    def effort_split(self, n_pixels: int) -> "RenderSettings":
        """The settings of a COMBINED render of ``n_pixels`` pixels with its
        light paths per pass set by ``light_paths_per_camera_path`` (> 0):
        that many light paths per camera path of the pass (camera_samples x
        pixels), clamped to photons_per_pass' range, so that the balance of
        the two sides measured at one resolution holds at any other
        (docs/integrators.md, "Effort split").  Otherwise self."""
        r = self.light_paths_per_camera_path
        if self.integrator != "COMBINED" or r <= 0:
            return self
        n = int(round(r * self.camera_samples * int(n_pixels)))
        return self.replace(photons_per_pass=min(max(n, 1), 100_000_000))

    def for_frame(self, frame: int) -> "RenderSettings":
        """The settings that render frame ``frame``: with use_animated_seed its
        own seed, :func:`frame_seed` (the engine calls this once per render,
        so the stored Seed is never mixed twice); otherwise self."""
        if not self.use_animated_seed:
            return self
        return self.replace(seed=frame_seed(self.seed, frame))

    def replace(self, **kw) -> "RenderSettings":
        return dataclasses.replace(self, **kw)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    # Fields that change when a render stops, not what it converges to.
    BUDGET_FIELDS = ("time_limit", "max_passes")

    def image_digest(self) -> str:
        """Hash of the fields that shape the image sequence (not the budget):
        a checkpoint may be resumed with a larger time limit or pass count."""
        d = {k: v for k, v in self.to_dict().items() if k not in self.BUDGET_FIELDS}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]

    def digest(self) -> str:
        """Stable hash of every field (checkpoints, caches)."""
        blob = json.dumps(self.to_dict(), sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


def frame_seed(seed: int, frame: int) -> int:
    """The seed of frame ``frame`` under Animated Seed, in [0, 2^31).

    Cycles' ``use_animated_seed`` hashes the frame number into the seed so
    that the noise changes from frame to frame instead of standing still on
    the image; this does the same with its own hash (a frame sequence
    renders differently from Cycles' anyway).  The pair (seed, frame) goes
    through the 64-bit finaliser of SplitMix64 (Steele et al. 2014), a
    bijection whose every output bit depends on every input bit, so
    neighbouring frames and seeds get unrelated streams.  Frames are
    Blender's (negative allowed), taken modulo 2^32.
    """
    z = ((int(seed) & 0xFFFFFFFF) << 32 | (int(frame) & 0xFFFFFFFF)) + 0x9E3779B97F4A7C15
    z &= 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    z ^= z >> 31
    return int(z >> 33)          # the top 31 bits


def field_names() -> list[str]:
    return [f.name for f in dataclasses.fields(RenderSettings)]


@dataclass(frozen=True)
class ViewportSettings:
    """Settings of the rendered viewport only (``addon/viewport.py``).

    Kept apart from RenderSettings so that they never enter the image digest:
    they change how the viewport gets to an image, not the image of a pass.
    """
    viewport_resolution_divider: int = 4  # first pass at 1/this of the viewport's resolution (1 = off)
    viewport_max_passes: int = 64         # passes after which the viewport stops (0 = no cap)

    def validate(self) -> "ViewportSettings":
        if not 1 <= self.viewport_resolution_divider <= 64:
            raise SettingsError(f"setting 'viewport_resolution_divider' = "
                                f"{self.viewport_resolution_divider!r}: must be in [1, 64]")
        if not 0 <= self.viewport_max_passes <= 1_000_000:
            raise SettingsError(f"setting 'viewport_max_passes' = {self.viewport_max_passes!r}: "
                                f"must be in [0, 1000000] (0 = no cap)")
        return self


def viewport_field_names() -> list[str]:
    return [f.name for f in dataclasses.fields(ViewportSettings)]
