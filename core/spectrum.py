"""Light as a spectrum and as a colour: the CIE 1931 observer, Planck's law
and the XYZ to linear Rec.709 matrix, in one place.

Its users: thin-film iridescence integrates its interference over the
matching functions (core/materials/thin_film.py); the Blackbody and
Wavelength shader nodes turn a temperature or a wavelength into a colour
(core/scene/node_math.py).  numpy only: the material table imports it when
the add-on registers.

Colours are linear Rec.709, Blender's default scene-linear space, whose
OCIO config takes XYZ as "Linear CIE-XYZ D65" (the ``cie_xyz_d65_interchange``
role); other working spaces get Rec.709's numbers.
"""
from __future__ import annotations

import numpy as np

#: The first wavelength of :data:`CIE_1931_2DEG` (nm); its rows are 5 nm apart.
CIE_LAMBDA_0 = 360.0

#: CIE 1931 2-degree colour matching functions x, y, z at 360, 365, ..., 830 nm.
CIE_1931_2DEG = np.array([
    [0.0001299, 3.917e-06, 0.0006061],
    [0.0002321, 6.965e-06, 0.001086],
    [0.0004149, 1.239e-05, 0.001946],
    [0.0007416, 2.202e-05, 0.003486],
    [0.001368, 3.9e-05, 0.00645],
    [0.002236, 6.4e-05, 0.01055],
    [0.004243, 0.00012, 0.02005],
    [0.00765, 0.000217, 0.03621],
    [0.01431, 0.000396, 0.06785],
    [0.02319, 0.00064, 0.1102],
    [0.04351, 0.00121, 0.2074],
    [0.07763, 0.00218, 0.3713],
    [0.13438, 0.004, 0.6456],
    [0.21477, 0.0073, 1.03905],
    [0.2839, 0.0116, 1.3856],
    [0.3285, 0.01684, 1.62296],
    [0.34828, 0.023, 1.74706],
    [0.34806, 0.0298, 1.7826],
    [0.3362, 0.038, 1.77211],
    [0.3187, 0.048, 1.7441],
    [0.2908, 0.06, 1.6692],
    [0.2511, 0.0739, 1.5281],
    [0.19536, 0.09098, 1.28764],
    [0.1421, 0.1126, 1.0419],
    [0.09564, 0.13902, 0.81295],
    [0.05795, 0.1693, 0.6162],
    [0.03201, 0.20802, 0.46518],
    [0.0147, 0.2586, 0.3533],
    [0.0049, 0.323, 0.272],
    [0.0024, 0.4073, 0.2123],
    [0.0093, 0.503, 0.1582],
    [0.0291, 0.6082, 0.1117],
    [0.06327, 0.71, 0.07825],
    [0.1096, 0.7932, 0.05725],
    [0.1655, 0.862, 0.04216],
    [0.22575, 0.91485, 0.02984],
    [0.2904, 0.954, 0.0203],
    [0.3597, 0.9803, 0.0134],
    [0.43345, 0.99495, 0.00875],
    [0.51205, 1, 0.00575],
    [0.5945, 0.995, 0.0039],
    [0.6784, 0.9786, 0.00275],
    [0.7621, 0.952, 0.0021],
    [0.8425, 0.9154, 0.0018],
    [0.9163, 0.87, 0.00165],
    [0.9786, 0.8163, 0.0014],
    [1.0263, 0.757, 0.0011],
    [1.0567, 0.6949, 0.001],
    [1.0622, 0.631, 0.0008],
    [1.0456, 0.5668, 0.0006],
    [1.0026, 0.503, 0.00034],
    [0.9384, 0.4412, 0.00024],
    [0.85445, 0.381, 0.00019],
    [0.7514, 0.321, 0.0001],
    [0.6424, 0.265, 5e-05],
    [0.5419, 0.217, 3e-05],
    [0.4479, 0.175, 2e-05],
    [0.3608, 0.1382, 1e-05],
    [0.2835, 0.107, 0],
    [0.2187, 0.0816, 0],
    [0.1649, 0.061, 0],
    [0.1212, 0.04458, 0],
    [0.0874, 0.032, 0],
    [0.0636, 0.0232, 0],
    [0.04677, 0.017, 0],
    [0.0329, 0.01192, 0],
    [0.0227, 0.00821, 0],
    [0.01584, 0.005723, 0],
    [0.0113592, 0.004102, 0],
    [0.00811092, 0.002929, 0],
    [0.00579035, 0.002091, 0],
    [0.00410946, 0.001484, 0],
    [0.00289933, 0.001047, 0],
    [0.00204919, 0.00074, 0],
    [0.00143997, 0.00052, 0],
    [0.000999949, 0.0003611, 0],
    [0.000690079, 0.0002492, 0],
    [0.000476021, 0.0001719, 0],
    [0.000332301, 0.00012, 0],
    [0.000234826, 8.48e-05, 0],
    [0.000166151, 6e-05, 0],
    [0.000117413, 4.24e-05, 0],
    [8.30753e-05, 3e-05, 0],
    [5.87065e-05, 2.12e-05, 0],
    [4.15099e-05, 1.499e-05, 0],
    [2.93533e-05, 1.06e-05, 0],
    [2.06738e-05, 7.4657e-06, 0],
    [1.45598e-05, 5.2578e-06, 0],
    [1.0254e-05, 3.7029e-06, 0],
    [7.22146e-06, 2.6078e-06, 0],
    [5.08587e-06, 1.8366e-06, 0],
    [3.58165e-06, 1.2934e-06, 0],
    [2.52253e-06, 9.1093e-07, 0],
    [1.77651e-06, 6.4153e-07, 0],
    [1.25114e-06, 4.5181e-07, 0],
])

#: Rec.709's primaries R, G, B and its white D65, as CIE xy (ITU-R BT.709).
REC709_PRIMARIES = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
D65_WHITE = (0.3127, 0.3290)


def _rgb_to_xyz(primaries, white) -> np.ndarray:
    """(3, 3) the matrix taking linear RGB of these primaries to XYZ, white
    (1, 1, 1) going to the white point of luminance 1."""
    xyz = lambda x, y: np.array([x / y, 1.0, (1.0 - x - y) / y])   # noqa: E731
    P = np.stack([xyz(*p) for p in primaries], 1)
    return P * np.linalg.solve(P, xyz(*white))[None, :]


#: XYZ to linear Rec.709: what OCIO derives from Blender's config (its
#: "Linear CIE-XYZ D65" to "Linear Rec.709"), the inverse of the primaries'
#: matrix.  Its middle row's inverse is color_ops.RGB_TO_Y's luminance.
XYZ_TO_REC709 = np.linalg.inv(_rgb_to_xyz(REC709_PRIMARIES, D65_WHITE))


#: Planck's second radiation constant h c / k_B in nm K.
PLANCK_C2 = 1.438776877e7

#: The temperatures (K) outside which Cycles' Blackbody node holds its colour
#: (svm_math_blackbody_color_rec709: 800 K, "where light is very dim", and
#: 12000 K).
BLACKBODY_RANGE = (800.0, 12000.0)

#: The span of Cycles' Wavelength node (nm): black outside [380, 780).
WAVELENGTH_RANGE = (380.0, 780.0)

#: The Wavelength node's scale, "empirical, to make all components <= 1"
#: (Cycles' svm_node_wavelength).
WAVELENGTH_SCALE = 1.0 / 2.52


def cie_at(lam) -> np.ndarray:
    """(..., 3) float64 the matching functions at wavelengths lam (nm), linear
    between the 5 nm rows, 0 outside the table."""
    lam = np.asarray(lam, np.float64)
    grid = CIE_LAMBDA_0 + 5.0 * np.arange(CIE_1931_2DEG.shape[0])
    return np.stack([np.interp(lam, grid, CIE_1931_2DEG[:, c], left=0.0, right=0.0)
                     for c in range(3)], -1)


def _blackbody_xyz(T) -> np.ndarray:
    """(K, 3) XYZ of Planck's spectral radiance at temperatures T (K,),
    integrated over the matching functions at 0.25 nm, any scale."""
    lam = np.arange(CIE_LAMBDA_0, CIE_LAMBDA_0 + 5.0 * (CIE_1931_2DEG.shape[0] - 1) + 0.125,
                    0.25)
    cmf = cie_at(lam)                                                  # (L, 3)
    x = PLANCK_C2 / (lam[None, :] * T[:, None])
    # lambda^-5 / (e^x - 1), scaled by 1e15 to stay well inside float64
    B = (lam[None, :] * 1e-3) ** -5.0 / np.expm1(np.minimum(x, 700.0))
    return B @ cmf


#: Mireds (1e6 / K) at which :func:`blackbody_rec709` tabulates the colour,
#: which varies smoothly in them; linear between, it is within 5e-6 of the
#: integral.
_MIREDS = np.linspace(1e6 / BLACKBODY_RANGE[1], 1e6 / BLACKBODY_RANGE[0], 1024)
_BLACKBODY_TABLE = None


def _blackbody_table() -> np.ndarray:
    """(len(_MIREDS), 3) the colours at _MIREDS, computed once."""
    global _BLACKBODY_TABLE
    if _BLACKBODY_TABLE is None:
        xyz = _blackbody_xyz(1e6 / _MIREDS)
        _BLACKBODY_TABLE = (xyz / xyz[:, 1:2]) @ XYZ_TO_REC709.T
    return _BLACKBODY_TABLE


def blackbody_rec709(T) -> np.ndarray:
    """(K, 3) float64 Cycles' Blackbody colour at temperatures T (K,) (K):
    Planck's spectrum seen by the CIE 1931 observer, in linear Rec.709 of
    luminance 1 (Cycles fits the same curve piecewise, normalised the same
    way: its 800 K and 12000 K colours have luminance 1); held at its value
    outside :data:`BLACKBODY_RANGE`.  May be negative (out of gamut): the
    node clamps at 0.  Read from a table over mireds (one integral per
    temperature was a bake's largest cost, a material of texels)."""
    T = np.clip(np.nan_to_num(np.asarray(T, np.float64).reshape(-1), nan=BLACKBODY_RANGE[0]),
                *BLACKBODY_RANGE)
    m, table = 1e6 / T, _blackbody_table()
    return np.stack([np.interp(m, _MIREDS, table[:, c]) for c in range(3)], -1)


def wavelength_rec709(lam) -> np.ndarray:
    """(K, 3) float64 Cycles' Wavelength colour at lam (K,) nm: the matching
    functions as Cycles tabulates them (the 5 nm rows from 380 nm, to four
    decimals), linear between rows, in linear Rec.709, times
    :data:`WAVELENGTH_SCALE`, negatives cut; black outside
    :data:`WAVELENGTH_RANGE`."""
    lam = np.asarray(lam, np.float64).reshape(-1)
    # to four decimals, halves up (0.00645 -> 0.0065: the decimal value's
    # rounding, not its binary neighbour's)
    rows = CIE_1931_2DEG[int((WAVELENGTH_RANGE[0] - CIE_LAMBDA_0) / 5.0):]
    table = np.floor(rows * 1e4 + 0.5 + 1e-6) / 1e4
    ii = (lam - WAVELENGTH_RANGE[0]) / 5.0
    i = np.where(np.isfinite(ii), np.trunc(ii), -1.0)
    inside = (i >= 0.0) & (i < (WAVELENGTH_RANGE[1] - WAVELENGTH_RANGE[0]) / 5.0)
    k = np.where(inside, i, 0.0).astype(np.int64)
    t = (ii - k)[:, None]
    xyz = np.where(inside[:, None], (1.0 - t) * table[k] + t * table[k + 1], 0.0)
    return np.maximum((xyz @ XYZ_TO_REC709.T) * WAVELENGTH_SCALE, 0.0)
