"""Thin-film iridescence: the reflectance of a surface under a thin dielectric film.

Cycles' Principled BSDF (Thin Film Thickness, Thin Film IOR) and Metallic
BSDF put a film of thickness d (nm) and index n_f over the surface.  Light
reflected inside the film interferes with light reflected on top of it,
and the reflectance varies with the wavelength: the colours of a soap
film or an oil slick.  Cycles follows Belcour & Barla 2017, "A Practical
Extension to Microfacet Theory for the Modeling of Varying Iridescence"
(``fresnel_iridescence_channel`` in ``kernel/closure/bsdf_util.h``):

- the Airy sum of the waves reflected m times inside the film (their eq. 10),
  truncated after m = 3:  R = R12 + R_s + 2 sum_m C_m Re(e^{i m phi} S*(m D)),
  R_s = T121^2 R23 / (1 - R12 R23), C_0 = R_s - T121, C_m = C_{m-1} sqrt(R12 R23),
  with the optical path difference D = 2 n_f d cos(theta_2) and the phase
  shifts phi of the two reflections, for s and p polarisation averaged;
- S(D) the Fourier transform of a colour channel's matching function over
  the wavenumber nu = 1/lambda, normalised to S(0) = 1:
  S_c(D) = ∫ cmf_c(lambda) e^{-2 pi i D / lambda} d lambda / ∫ cmf_c d lambda
  (the integral over lambda is the one over nu with the density's
  Jacobian), so the interference is integrated over the spectrum in closed
  form instead of wavelength by wavelength.

Cycles tabulates S at 512 path differences from 0 to 60 um / 2 pi (larger
ones read the last entry) and interpolates linearly; this module computes
the same nodes by direct quadrature of the CIE 1931 2-degree matching
functions (5 nm table, interpolated linearly onto a 0.25 nm grid) turned
into linear Rec.709 (Blender's default scene-linear space) by the matrix
OCIO derives from Blender's config, as Cycles' ``xyz_to_rgb``
(core/spectrum.py).  tests/test_thin_film.py checks the sum against a direct spectral
integration of the Airy reflectance.

This module is numpy only (the material table imports it when the add-on
registers); the compiled sum is ``thin_film_kernels.py``.

Layout of the table (``TABLE_SIZE`` * 6 float64, appended to
``CompiledMaterials.tables``): Re S_R, Re S_G, Re S_B, Im S_R, Im S_G,
Im S_B, each TABLE_SIZE long.
"""
from __future__ import annotations

import math

import numpy as np

from ..spectrum import CIE_1931_2DEG, CIE_LAMBDA_0, XYZ_TO_REC709

#: Cycles' THIN_FILM_TABLE_SIZE and the path difference of its last node (nm).
TABLE_SIZE = 512
D_MAX = 60000.0 / (2.0 * math.pi)
#: Below this thickness (nm) a film is none (Cycles' THINFILM_THICKNESS_CUTOFF).
THICKNESS_CUTOFF = 0.1

_TABLE = None


def sensitivity_table() -> np.ndarray:
    """(6 * TABLE_SIZE,) float64: S_c(D) at D = j D_MAX / (TABLE_SIZE - 1)
    (the module doc's layout), computed once."""
    global _TABLE
    if _TABLE is None:
        lam5 = CIE_LAMBDA_0 + 5.0 * np.arange(CIE_1931_2DEG.shape[0])
        lam = np.arange(360.0, 830.0 + 1e-9, 0.25)
        xyz = np.stack([np.interp(lam, lam5, CIE_1931_2DEG[:, c]) for c in range(3)])
        rgb = XYZ_TO_REC709 @ xyz                               # (3, n)
        D = np.arange(TABLE_SIZE) * (D_MAX / (TABLE_SIZE - 1))
        w = np.full(lam.size, 0.25)
        w[[0, -1]] = 0.125                                      # trapezoid weights
        E = np.exp(-2j * np.pi * D[:, None] / lam[None, :]) * w  # (T, n)
        S = (E @ rgb.T) / (rgb @ w)                             # (T, 3), S(0) = 1
        _TABLE = np.concatenate([S.real.T.ravel(), S.imag.T.ravel()])
    return _TABLE
