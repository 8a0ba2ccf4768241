"""The photon pass of one SPPM pass: trace photons, gather them at the visible points.

    photon_pass = PhotonPass(tracer, mtab, settings, frequency, radius_histogram, stage_seconds)
    est = photon_pass(vp, R2, spectrum, rng, check_stop)

Photons are traced (core.sppm.photons) in chunks of PHOTON_CHUNK, so memory
stays bounded and a cancel is seen between chunks; each chunk is gathered
(core.sppm.hashgrid) into the grid of this pass's visible points and their
radii.  A photon counts for every visible point whose sphere it falls in
(cos_ng = -1: every surface inside the sphere, pbrt-v4 SPPM, but only from the
camera's side: rejecting the adjacent wall's photons darkened Cornell-box
corners against Cycles, docs/method.md).  The estimate is pass-local: the
renderer commits it only once the pass is complete, so a cancelled pass
leaves no trace.
"""
from __future__ import annotations

import time
from typing import NamedTuple, Optional

import numpy as np

from .. import materials as B
from ..frequency.kernels import Receivers
from . import hashgrid
from .update import HIST_BINS, needs_sectors

PHOTON_CHUNK = 131_072


class PhotonEstimate(NamedTuple):
    """This pass's photons at the visible points (P pixels).

    gathered: False when no visible point was active (nothing traced).
    M (P,) float64 photons counted; Phi (P, 3) float64 their reflected flux
      (BSDF x power, times the visible point's throughput beta).
    r_pred_min (P,) float64 smallest predicted radius of a counted frequency
      photon [m] (inf = none; negated with the PAPER model).
    r_hist (P, HIST_BINS) uint32 counts of the predicted radii of the counted
      frequency photons (core.sppm.update.RadiusHistogram), or None.
    spectrum (P, 3) float64 the spectrum AOV after this pass, or None.
    sectors (P, SECTOR_CELLS) float64 photons counted per sector cell of each
      kernel disc (core.sppm.hashgrid), or None unless the radius rule needs
      them (core.sppm.update.needs_sectors).
    """
    gathered: bool
    M: np.ndarray
    Phi: np.ndarray
    r_pred_min: np.ndarray
    r_hist: Optional[np.ndarray] = None
    spectrum: Optional[np.ndarray] = None
    sectors: Optional[np.ndarray] = None


class PhotonPass:
    """tracer: core.sppm.photons.PhotonTracer; mtab: material table; settings:
    RenderSettings; frequency: the plan traces frequency photons;
    radius_histogram: core.sppm.update.RadiusHistogram when the QUANTILE
    estimator needs the predicted radii, else None; stage_seconds: dict whose
    "photon_trace" and "gather" entries accumulate wall seconds.
    ``rays``: rays cast by the tracer so far."""

    def __init__(self, tracer, mtab, settings, frequency: bool, radius_histogram,
                 stage_seconds: dict):
        self.tracer, self.mtab, self.settings = tracer, mtab, settings
        self.frequency, self.radius_histogram = frequency, radius_histogram
        self.stage_seconds = stage_seconds
        self.rays = 0
        # Non-Lambert visible points: the radius for their own receiver lobes.
        self.receivers = Receivers(mtab) if frequency else None
        self.sectors = needs_sectors(settings, frequency)

    def __call__(self, vp, R2: np.ndarray, spectrum: Optional[np.ndarray],
                 rng: np.random.Generator, check_stop=lambda: None) -> PhotonEstimate:
        """Photons of one pass at the visible points vp with squared radii R2
        (P,) (0 = none yet); spectrum (P, 3): the committed spectrum AOV (None:
        no spectrum AOV).  check_stop() is called before every chunk."""
        st = self.settings
        P = vp.valid.shape[0]
        active = vp.valid & (R2 > 0)
        M = np.zeros(P)
        Phi = np.zeros((P, 3))
        r_pred = np.full(P, np.inf)
        if not np.any(active):
            return PhotonEstimate(False, M, Phi, r_pred)
        hist = None if self.radius_histogram is None else np.zeros((P, HIST_BINS), np.uint32)
        spec = None if spectrum is None else spectrum.copy()
        sec = np.zeros((P, hashgrid.SECTOR_CELLS)) if self.sectors else None
        want_pairs = self.frequency and (hist is not None or spec is not None)
        grid = hashgrid.build_grid(vp.p, np.sqrt(R2), active)
        n_total = st.photons_per_pass
        n_freq_total = int(round(n_total * st.frequency_fraction)) if self.frequency else 0
        done = 0
        while done < n_total:
            check_stop()
            n = min(PHOTON_CHUNK, n_total - done)
            n_freq = int(np.clip(n_freq_total - done, 0, n))
            t0 = time.perf_counter()
            rays0 = self.tracer.accel.rays_cast
            dep = self.tracer.trace(n, n_freq, rng)
            self.rays += self.tracer.accel.rays_cast - rays0
            t1 = time.perf_counter()
            self.stage_seconds["photon_trace"] += t1 - t0
            done += n
            if dep is None:
                continue
            g = hashgrid.gather(grid, dep["p"], dep["ng"], dep["wi"], dep["power"], dep["rpred"],
                                vp.p, vp.ng, R2, vp.const, cos_ng=-1.0,
                                want_freq_pairs=want_pairs and n_freq > 0,
                                sectors=self.sectors)
            M += g.M
            if sec is not None:
                sec += g.sectors
            Phi += g.Phi_sum * (vp.albedo / np.pi)
            if g.pair_vp.size:
                Phi += self._reflected(vp, dep, g.pair_vp, g.pair_ph, P)
            if self.receivers is None:
                r_pred = np.minimum(r_pred, g.rpred_min)
            else:
                r_pred = np.minimum(r_pred, np.where(vp.const, g.rpred_min, np.inf))
                fr = ~np.isnan(dep["rpred"][g.pair_ph])
                pv, pp = g.pair_vp[fr], g.pair_ph[fr]
                np.minimum.at(r_pred, pv, self.receivers.radius_keys(
                    vp, dep, pv, pp, st.frequency_model))
            if g.freq_pair_vp is not None and g.freq_pair_vp.size:
                self._frequency_pairs(g.freq_pair_vp, g.freq_pair_ph, dep, hist, spec, vp)
            self.stage_seconds["gather"] += time.perf_counter() - t1
        Phi *= vp.beta
        return PhotonEstimate(True, M, Phi, r_pred, hist, spec, sec)

    def _reflected(self, vp, dep, pv, pp, P) -> np.ndarray:
        """(P, 3) BSDF-weighted power of the (visible point pv, photon pp)
        pairs (K,) of the non-Lambert visible points, summed per point."""
        f = B.eval_bsdf(self.mtab, vp.mat[pv], vp.colors[pv], vp.ns[pv], vp.ng[pv],
                        vp.wo[pv], dep["wi"][pp])
        # Photons estimate flux per geometric area; radiance wants the
        # shading cosine: |wi.ns| / |wi.ng| (Veach 1997, 5.3), capped so a
        # grazing geometric normal cannot spike.
        corr = np.minimum(B.shading_correction(vp.ns[pv], vp.ng[pv], dep["wi"][pp]), 4.0)
        contrib = f * (dep["power"][pp] * corr[:, None])
        out = np.zeros((P, 3))
        for ch in range(3):
            out[:, ch] = np.bincount(pv, weights=contrib[:, ch], minlength=P)
        return out

    def _frequency_pairs(self, pv, pp, dep, hist, spec, vp) -> None:
        """(visible point pv, frequency photon pp) pairs (K,): add the
        predicted radii to hist (P, HIST_BINS) and keep in spec (P, 3) the
        spectrum of each point's photon that predicted the smallest radius."""
        rr = dep["rpred"][pp].copy()
        nc = ~vp.const[pv]
        if np.any(nc):
            rr[nc] = self.receivers.radius_keys(vp, dep, pv[nc], pp[nc],
                                                self.settings.frequency_model)
        if hist is not None:
            np.add.at(hist, (pv, self.radius_histogram.bin(rr)), 1)
        if spec is not None and "spec" in dep:
            order = np.lexsort((np.abs(rr), pv))
            first = np.ones(order.size, bool)
            first[1:] = pv[order][1:] != pv[order][:-1]
            sel = order[first]
            spec[pv[sel]] = dep["spec"][pp[sel]]
