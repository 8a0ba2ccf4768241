"""IES light profiles: an IES Texture node's factor in a light's node tree.

A point or spot light whose Emission Strength is fed by an IES Texture (the
way Blender users give a fitting its photometric web) emits, along each
direction w leaving it, its strength times the profile's value there.  This
module reads the profile as Cycles does (``util/ies.cpp``, the IESNA LM-63
text) and evaluates it as Cycles' kernel does (``kernel/util/ies.h``):

- Intensities are candela times the candela multiplier and the two ballast
  factors, times 4 pi / 177.83: Cycles turns candela (lm/sr) into W/sr with
  the luminous efficacy of D65 (177.83 lm/W), times the 4 pi its point
  light's strength divides by, so a profile of 1/(4 pi / 177.83) cd
  everywhere is a factor of 1.
- Angles are turned into Cycles' type C layout: vertical angle v from the
  light's -Z axis (0 straight down its axis), horizontal h in [0, 2 pi]
  (a quadrant or half given in the file is mirrored to the full circle,
  a type A or B file is transposed and shifted as Cycles does).
- The lookup direction is the light-object's normal transform of w
  (M^T w, normalised: the IES node's default vector is the incoming
  direction in object space), v = acos(-z), h = atan2(x, y) + pi, and the
  table is read with Catmull-Rom interpolation along v then h, wrapping
  around the pole and the full circle where the table covers them, zero
  outside it, negative values clamped to 0.

:func:`pack` lays every light's profile into one float64 array that the
light samples, the emitters seen by rays and the photons' emission read
(``LightTable.ies``); ``ies_kernels.ies_factor`` is the one evaluation they
call.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .warps import cone_grid, smoothstep

# Cycles' candela -> strength conversion: 4 pi / (D65's 177.83 lm/W).
CANDELA_TO_STRENGTH = 4.0 * np.pi / 177.83
_TYPE_C, _TYPE_B, _TYPE_A = 1, 2, 3
_EPS_DEG = 1e-4            # Cycles' angle_close


class IesProfile(NamedTuple):
    """A profile in Cycles' type C layout: h (H,), v (V,) float64 angles
    [rad], ascending; values (H, V) float64 (strength factors, already
    multiplied by the candela conversion and the file's multipliers)."""
    h: np.ndarray
    v: np.ndarray
    values: np.ndarray


class IesError(ValueError):
    """A text that is not an IES profile FPPM reads."""


def _close(a, b):
    return abs(a - b) < _EPS_DEG


def parse_ies(text: str) -> IesProfile:
    """The :class:`IesProfile` of an IES (LM-63) file's text.

    Raises :class:`IesError` when the text has no TILT line, too few numbers,
    an unknown photometric type or no angles."""
    text = text.replace(",", " ").replace("\r", "\n")
    at = text.find("\nTILT=")
    if at < 0:
        if text.startswith("TILT="):
            at = 0
        else:
            raise IesError("no TILT= line (not an IES file)")
    line_end = text.find("\n", at + 1)
    tilt = text[at:line_end if line_end >= 0 else len(text)].strip()
    rest = text[line_end + 1:] if line_end >= 0 else ""
    try:
        nums = [float(x) for x in rest.split()]
    except ValueError as e:
        raise IesError(f"a value that is not a number ({e})") from None
    pos = 0
    if tilt.upper().startswith("TILT=INCLUDE"):
        # Lamp-to-luminaire geometry, the count of tilt angles, angles and factors.
        if len(nums) < 2:
            raise IesError("TILT=INCLUDE without its data")
        pos = 2 + 2 * int(nums[1])
    head = nums[pos:pos + 13]
    if len(head) < 13:
        raise IesError("fewer numbers than an IES header holds")
    _lamps, _lumens, mult, n_v, n_h, ptype = head[:6]
    ballast, ballast_lamp = head[10], head[11]
    n_v, n_h, ptype = int(n_v), int(n_h), int(ptype)
    if ptype not in (_TYPE_A, _TYPE_B, _TYPE_C):
        raise IesError(f"photometric type {ptype} (1, 2 or 3 expected)")
    if n_v < 1 or n_h < 1:
        raise IesError("no vertical or horizontal angles")
    pos += 13
    need = n_v + n_h + n_v * n_h
    if len(nums) - pos < need:
        raise IesError(f"{len(nums) - pos} values for {need} angles and candelas")
    v = list(nums[pos:pos + n_v])
    h = list(nums[pos + n_v:pos + n_v + n_h])
    cd = np.asarray(nums[pos + n_v + n_h:pos + need], np.float64).reshape(n_h, n_v)
    if not (np.all(np.isfinite(cd)) and np.all(np.isfinite(nums[pos:pos + n_v + n_h]))):
        raise IesError("an angle or candela value that is not finite")
    if np.any(np.diff(v) <= 0) or np.any(np.diff(h) <= 0):
        raise IesError("angles not in increasing order")
    factor = mult * ballast * ballast_lamp * CANDELA_TO_STRENGTH
    if not np.isfinite(factor):
        raise IesError("a multiplier that is not finite")
    rows = [list(r * factor) for r in cd]
    if ptype == _TYPE_C:
        h, v, rows = _type_c(h, v, rows)
    elif ptype == _TYPE_B:
        h, v, rows = _type_b(h, v, rows)
    else:
        h, v, rows = _type_a(h, v, rows)
    return IesProfile(np.radians(np.asarray(h, np.float64)),
                      np.radians(np.asarray(v, np.float64)),
                      np.asarray(rows, np.float64).reshape(len(h), len(v)))


def _type_c(h, v, rows):
    """Type C as Cycles lays it out: 90-270 turned to 0-180, a single plane
    made a full circle, a quadrant mirrored to a half and a half to the full
    circle, a missing 360 entry added when the spacing shows it."""
    if _close(h[0], 90.0):
        h = [a - 90.0 for a in h]
    if len(h) == 1:
        h, rows = [0.0, 360.0], [rows[0], rows[0]]
    if _close(h[-1], 90.0):
        n = len(h)
        h = h + [180.0 - h[i] for i in range(n - 2, -1, -1)]
        rows = rows + [rows[i] for i in range(n - 2, -1, -1)]
    if _close(h[-1], 180.0):
        n = len(h)
        h = h + [360.0 - h[i] for i in range(n - 2, -1, -1)]
        rows = rows + [rows[i] for i in range(n - 2, -1, -1)]
    if _close(h[0], 0.0) and not _close(h[-1], 360.0) and len(h) >= 2:
        gap = 360.0 - h[-1]
        if _close(h[-1] - h[-2], gap) or _close(h[1] - h[0], gap):
            h, rows = h + [360.0], rows + [rows[0]]
    return h, v, rows


def _mirror_half(a):
    """0..90 -> -90..90 shifted to 0..180 (index map and angles)."""
    n = len(a)
    idx = list(range(n - 1, 0, -1)) + list(range(n))
    ang = [90.0 - a[i] for i in range(n - 1, 0, -1)] + [90.0 + x for x in a]
    return idx, ang


def _type_b(h, v, rows):
    """Type B transposed into the type C layout (Cycles: the polar axis is
    taken as vertical; users rotate the light), each axis's 0-90 mirrored
    to 0-180 or its -90-90 shifted there."""
    rows = [[rows[j][i] for j in range(len(h))] for i in range(len(v))]
    h, v = v, h
    if _close(h[0], 0.0):
        idx, h = _mirror_half(h)
        rows = [rows[i] for i in idx]
    else:
        h = [a + 90.0 for a in h]
    if _close(v[0], 0.0):
        idx, v = _mirror_half(v)
        rows = [[r[i] for i in idx] for r in rows]
    else:
        v = [a + 90.0 for a in v]
    return h, v, rows


def _type_a(h, v, rows):
    """Type A in the type C layout: vertical +90, horizontal -90..90 to
    270..90 (mirrored about 0 when the file starts there)."""
    v = [a + 90.0 for a in v]
    n = len(h)
    new_h = [180.0 - h[i] for i in range(n - 1, -1, -1)]
    new_rows = [rows[i] for i in range(n - 1, -1, -1)]
    if _close(h[0], 0.0):
        new_h += [180.0 + h[i] for i in range(1, n)]
        new_rows += [rows[i] for i in range(1, n)]
    return new_h, v, new_rows


def scaled(profile: IesProfile, s: float) -> IesProfile:
    """The profile times s (the IES node's Strength)."""
    return profile._replace(values=profile.values * float(s))


# ----------------------------------------------------------------------------
# Packing and evaluation.

HEAD = 11        # a light's block: M^T (9, row-major), H, V


def pack(profiles, lin) -> np.ndarray:
    """One float64 array of the table's profiles: profiles a list of Nl
    :class:`IesProfile` or None, lin (Nl, 3, 3) the lights' object matrices.
    Layout: Nl offsets (-1: none), then per light with a profile M^T (9),
    H, V, h (H), v (V), values (H V, h-major).  Empty when no light has one
    (``ies_kernels.ies_factor`` is then 1 without a read)."""
    if not any(p is not None for p in profiles):
        return np.zeros(0, np.float64)
    n = len(profiles)
    head = np.full(n, -1.0)
    blocks, at = [], n
    for j, p in enumerate(profiles):
        if p is None:
            continue
        H, V = p.h.shape[0], p.v.shape[0]
        b = np.concatenate([np.asarray(lin[j], np.float64).T.ravel(), [H, V], p.h, p.v,
                            np.asarray(p.values, np.float64).ravel()])
        head[j] = at
        at += b.shape[0]
        blocks.append(b)
    return np.concatenate([head] + blocks)


def factors(ies: np.ndarray, j, w) -> np.ndarray:
    """(K,) float64 the IES factors of light rows j (K,) (or one row) along
    the directions w (K, 3) leaving them (``ies_kernels.ies_factors``;
    imported here: register() imports the light table, which must not load
    numba)."""
    from .ies_kernels import ies_factors
    j = np.ascontiguousarray(np.broadcast_to(np.asarray(j, np.int64), (len(w),)))
    return ies_factors(np.ascontiguousarray(ies, np.float64), j,
                       np.ascontiguousarray(w, np.float64))


def mean_factor(profile: IesProfile, cos_h: float = -1.0, smooth: float = 1.0) -> float:
    """The profile's mean over the directions a light sends its power along:
    the sphere (a point light), or a spot's cone weighted by its smoothstep
    (cos_h, smooth: ``LightTable.cos_half_spot``, ``spot_smooth``); in the
    light's own frame.  Photons are drawn from the lights by this share of
    their flux (``LightTable.p_select``)."""
    mu, w, _ = cone_grid(max(cos_h, -1.0), 128, 128)
    att = smoothstep((mu - cos_h) * smooth) if cos_h > -1.0 else np.ones(w.shape[0])
    one = pack([profile], np.eye(3)[None])
    f = factors(one, np.zeros(w.shape[0], np.int64), w)
    s = att.sum()
    return float((att * f).sum() / s) if s > 0 else 0.0
