"""Frequency analysis of the local light field carried by frequency photons.

A *spectrum* is an ``(..., 3)`` float64 array of columns ``(a, b, c)``; usually
``(N, 3)`` for N photons.  ``Q = [[a, c], [c, b]]`` is the Gaussian fit of the
local light field around a ray in 2D flatland (space ``x`` [m] across the ray,
angle ``theta`` [rad]):

    |L(Omega)|^2 ~ exp(-Omega^T Q Omega)     (power spectrum, Omega in rad/unit)

which makes ``Q`` the covariance of the light field itself (docs/frequency.md,
"Convention"): ``a`` spatial variance [m^2], ``b`` angular
variance [rad^2], ``c`` [m rad].  Larger a or b = smoother light = larger
admissible kernel.  The local frame is ``x_hat = rot90(ray direction)``; theta > 0
tilts the ray towards +x_hat.  With the amplitude spectrum |L| instead of |L|^2
every number here halves; lobe widths and light inits below are given in the
power-spectrum (= light-field covariance) convention.

Two models, selected by ``model``:

``'CORRECTED'`` (default)
    The operators of docs/frequency.md, each verified against a sampled light field
    (tests/test_frequency_ops.py).  They are made *stable*: every output goes
    through :func:`sanitize` (the notes' "stiff and extreme cases" table), so a
    chain of operators always returns a finite positive semi-definite Q.
``'PAPER'``
    The formulas of Belcour & Soler 2011 (supplementary appendix) verbatim,
    including their errors (shear sign, occlusion leaving b and c, inverted
    surface cosines, ``r = pi sqrt(a) beta``, ``tan(pi sqrt(b) beta)``, max
    accumulation).  No guards: it exists to reproduce the paper's results and
    failure modes, not to render safely.  :func:`predicted_radius` still maps
    NaN to 0 (no hold) for both models.

Every operator takes ``A_MAX`` (= D^2, D the scene diameter, see
``Scene.diameter``): the largest spatial variance and, through D = sqrt(A_MAX),
the longest distance.  The default 1e30 m^2 only keeps products finite.
"""
from __future__ import annotations

import math

import numpy as np

# ---------------------------------------------------------------- constants
#: beta = -ln 0.95: a Gaussian profile exp(-r^2 / 2a) stays >= 95 % of its peak
#: for r^2 <= 2 beta a (docs/frequency.md "At the hitpoint").
BETA = -math.log(0.95)
#: Angular variance of a cosine-weighted diffuse lobe in flatland,
#: int theta^2 cos(theta) / 2 over (-pi/2, pi/2) = pi^2/4 - 2 = 0.4674 rad^2.
#: It is the widest lobe we model, hence the cap for b.
B_DIFFUSE = math.pi ** 2 / 4.0 - 2.0
B_CAP = B_DIFFUSE
#: Smallest cosine used by the surface operators (stiff table "grazing").
COS_MIN = 1e-3
#: Angle sqrt(2 beta (b + b_r)) from which r_theta is treated as unbounded
#: (tan explodes and passes pi/2; stiff table "tan past pi/2").
ANGLE_MAX = 1.2
#: Default largest spatial variance [m^2] (D = 1e15 m) when the caller gives
#: none: finite, so that a * a_occ, a * b and b * d^2 never overflow float64.
#: Renderers pass A_MAX = D^2 of their scene.
A_MAX_DEFAULT = 1e30
#: Radius floor relative to the scene diameter: R >= 1e-7 D (stiff table "tiny radii").
MODELS = ("CORRECTED", "PAPER")


def _model(model: str) -> str:
    m = str(model).upper()
    if m not in MODELS:
        raise ValueError(f"frequency model {model!r} is not one of {MODELS}")
    return m


def _f64(x):
    return np.asarray(x, dtype=np.float64)


def _split(s):
    s = _f64(s)
    if s.shape[-1] != 3:
        raise ValueError(f"a spectrum has shape (..., 3), got {s.shape}")
    return s[..., 0], s[..., 1], s[..., 2]


def _stack(a, b, c):
    a, b, c = np.broadcast_arrays(a, b, c)
    return np.stack([a, b, c], axis=-1).astype(np.float64, copy=False)


# ---------------------------------------------------------------- guards
def sanitize(s, A_MAX=A_MAX_DEFAULT):
    """Return a finite positive semi-definite copy of the spectra ``s``.

    s: (..., 3) float array of (a, b, c).  A_MAX: scalar or broadcastable, the
    largest spatial variance (D^2).  Returns (..., 3) float64.

    Guards (docs/frequency.md, "Stiff and extreme cases"):
    - a row with any NaN becomes (0, 0, 0): the sharpest spectrum, r = 0, no
      hold -- the conservative outcome of an unknown state;
    - a in [0, A_MAX] (+inf -> A_MAX: "grazing", "huge distance");
    - b in [0, B_CAP = 0.467] (+inf -> 0.467: "diffuse b = inf then travel");
    - |c| <= sqrt(a b), applied last so Q stays PSD ("c^2 > ab").

    The operator-specific rows of that table live in the operators, which all
    call this on their input and output: cos >= 1e-3 (onto/off_surface),
    |d| <= D and the PSD-preserving shear (travel, and its twin in
    curvature), t = a + a_o -> 0 and a_o >= A_MAX (occlude), NaN radius -> 0
    (predicted_radius, accumulate), float64 counters, floor and power checks
    (core.sppm.update.ppm_radius_update, valid_photon_power).
    """
    a, b, c = _split(s)
    bad = np.isnan(a) | np.isnan(b) | np.isnan(c)
    a = np.where(bad, 0.0, a)
    b = np.where(bad, 0.0, b)
    c = np.where(bad, 0.0, c)
    a = np.clip(a, 0.0, A_MAX)
    b = np.clip(b, 0.0, B_CAP)
    with np.errstate(invalid="ignore", over="ignore"):
        lim = np.sqrt(a * b)
    lim = np.where(np.isfinite(lim), lim, 0.0)
    c = np.clip(c, -lim, lim)
    return _stack(a, b, c)


def is_psd(s, rtol=1e-9):
    """(...,) bool: finite, a >= 0, b >= 0 and c^2 <= a b (relative tolerance rtol)."""
    a, b, c = _split(s)
    with np.errstate(invalid="ignore", over="ignore"):
        ok = np.isfinite(a) & np.isfinite(b) & np.isfinite(c)
        ok &= (a >= 0) & (b >= 0)
        ok &= c * c <= a * b * (1.0 + rtol) + 1e-300
    return ok


def valid_photon_power(power):
    """(P,) bool: photon powers (P, 3) that may be splatted.

    Rejects non-finite or negative channels and all-zero power (stiff table
    "zero/NaN photon power": one NaN photon would poison tau forever).
    """
    p = _f64(power)
    return np.all(np.isfinite(p), axis=-1) & np.all(p >= 0, axis=-1) & (p.sum(axis=-1) > 0)


# ---------------------------------------------------------------- operators
def travel(s, d, model="CORRECTED", A_MAX=A_MAX_DEFAULT):
    """Free-space transport over a distance d: the shear l(x - d theta, theta).

    s: (N, 3) spectra; d: (N,) or scalar, metres (d < 0 transports backwards).
    Returns (N, 3) float64.

    CORRECTED (docs/frequency.md, Operators, "travel"): a += 2cd + bd^2, c += bd,
    b unchanged.  Written in the PSD-preserving form: the shear has unit
    determinant, so ab - c^2 is invariant and
        a' = (max(ab - c^2, 0) + c'^2) / b,
    which can never go negative (the naive form gives a' = -1e-8 at a float32
    caustic focus, stiff table "caustic focus").  |d| <= D = sqrt(A_MAX).
    PAPER (seed appendix): a - 2cd + bd^2, c - bd -- the opposite theta sign.
    """
    m = _model(model)
    if m == "PAPER":
        a, b, c = _split(s)
        d = _f64(d)
        return _stack(a - 2 * c * d + b * d * d, b, c - b * d)
    a, b, c = _split(sanitize(s, A_MAX))
    D = math.sqrt(A_MAX) if np.isscalar(A_MAX) else np.sqrt(_f64(A_MAX))
    d = np.clip(_f64(d), -D, D)                        # "huge distance": d <= D
    c1 = c + b * d
    det = np.maximum(a * b - c * c, 0.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a1 = np.where(b > 0, (det + c1 * c1) / np.where(b > 0, b, 1.0), a)
    return sanitize(_stack(a1, b, c1), A_MAX)


def occlude(s, a_occ, model="CORRECTED", A_MAX=A_MAX_DEFAULT):
    """Partial occlusion: multiply l by a Gaussian visibility exp(-x^2 / 2 a_occ).

    s: (N, 3); a_occ: (N,) or scalar [m^2], the occluder's spatial variance
    (docs/frequency.md: (distance to the blocker)^2).  Returns (N, 3) float64.

    CORRECTED: the product of Gaussians adds precisions; with t = a + a_occ
        a' = a a_occ / t,  c' = c a_occ / t,  b' = b - c^2 / t
    (exact for c != 0; the determinant scales by a_occ / t so Q stays PSD).
    Guards: a_occ >= A_MAX (incl. inf) is "no occluder" -> identity; t = 0 ->
    (0, b, 0); NaN a_occ is treated as a blocker at distance 0 (conservative).
    PAPER: a' = a a_occ / (a + a_occ) with b and c unchanged -- right only for
    c = 0; with c != 0 it produces c^2 > a'b (non-PSD).
    """
    m = _model(model)
    ao = _f64(a_occ)
    if m == "PAPER":
        a, b, c = _split(s)
        with np.errstate(divide="ignore", invalid="ignore"):
            return _stack(a * ao / (a + ao), b, c)
    s = sanitize(s, A_MAX)
    a, b, c = _split(s)
    ao = np.where(np.isnan(ao), 0.0, np.maximum(ao, 0.0))
    none = ao >= A_MAX                                   # "no occluder": identity
    aof = np.where(none, 0.0, ao)
    t = a + aof
    pos = t > 0
    ts = np.where(pos, t, 1.0)
    a1 = np.where(pos, a * aof / ts, 0.0)
    c1 = np.where(pos, c * aof / ts, 0.0)
    b1 = np.where(pos, b - c * c / ts, b)
    out = _stack(np.where(none, a, a1), np.where(none, b, b1), np.where(none, c, c1))
    return sanitize(out, A_MAX)


def onto_surface(s, cos_i, model="CORRECTED", A_MAX=A_MAX_DEFAULT, disc=False):
    """Project the ray's light field onto a receiving surface.

    s: (N, 3); cos_i: (N,) or scalar, cosine between the ray and the normal.
    Returns (N, 3) float64.  Surface coordinate u = x / cos_i (the footprint
    grows): l_s(u, theta) = l(u cos_i, theta).

    CORRECTED: a / cos^2, c / cos, b unchanged, with |cos| >= 1e-3 and
    a <= A_MAX (stiff table "grazing").  ``disc=True`` leaves a and c
    unchanged: only the in-plane axis stretches, so for an isotropic disc
    kernel the unstretched (perpendicular) axis is the conservative choice
    (docs/frequency.md, "Isotropic disc kernels").
    PAPER: a cos^2, c cos (inverted).
    """
    m = _model(model)
    cs = _f64(cos_i)
    if m == "PAPER":
        a, b, c = _split(s)
        return _stack(a * cs * cs, b, c * cs)
    a, b, c = _split(sanitize(s, A_MAX))
    if disc:
        return _stack(a, b, c)
    cs = np.clip(np.abs(np.nan_to_num(cs, nan=1.0)), COS_MIN, 1.0)
    return sanitize(_stack(a / (cs * cs), b, c / cs), A_MAX)


def off_surface(s, cos_o, model="CORRECTED", A_MAX=A_MAX_DEFAULT, cos_i=None):
    """Leave a surface along a direction at cosine cos_o to the normal.

    s: (N, 3) on-surface spectra; cos_o: (N,) or scalar.  Returns (N, 3).
    x = u cos_o: l_o(x, theta) = l_s(x / cos_o, theta).

    CORRECTED: a cos_o^2, c cos_o (cos clamped to [1e-3, 1] like onto_surface,
    so a grazing round trip is the identity).
    PAPER: a / cos_i^2, c / cos_i -- inverted and using the incoming angle;
    ``cos_i`` (defaults to cos_o when not given).
    """
    m = _model(model)
    if m == "PAPER":
        a, b, c = _split(s)
        ci = _f64(cos_o if cos_i is None else cos_i)
        with np.errstate(divide="ignore", invalid="ignore"):
            return _stack(a / (ci * ci), b, c / ci)
    a, b, c = _split(sanitize(s, A_MAX))
    cs = np.clip(np.abs(np.nan_to_num(_f64(cos_o), nan=1.0)), COS_MIN, 1.0)
    return sanitize(_stack(a * cs * cs, b, c * cs), A_MAX)


def brdf(s, b_lobe, model="CORRECTED", A_MAX=A_MAX_DEFAULT):
    """Reflection by a lobe: angular convolution of l with the lobe.

    s: (N, 3); b_lobe: (N,) or scalar, the lobe's angular variance [rad^2]
    (:func:`lobe_variance`; inf = diffuse).  Returns (N, 3).

    CORRECTED: b += b_lobe (convolution adds variances), capped at 0.467
    (a diffuse lobe; stiff table "diffuse b = inf then travel").  NaN b_lobe
    counts as 0 (no blur: conservative).
    PAPER: b + b_brdf, same formula, uncapped.  (The paper fits amplitude
    spectra, so its own b_brdf is variance / 2; given the same number both
    models add the same thing.)
    """
    m = _model(model)
    bl = _f64(b_lobe)
    if m == "PAPER":
        a, b, c = _split(s)
        return _stack(a, b + bl, c)
    a, b, c = _split(sanitize(s, A_MAX))
    bl = np.where(np.isnan(bl), 0.0, np.maximum(bl, 0.0))
    return sanitize(_stack(a, b + bl, c), A_MAX)


def curvature(s, kappa, model="CORRECTED", A_MAX=A_MAX_DEFAULT, factor=2.0):
    """Curved reflector at normal incidence: theta' = theta + k x with k = factor * kappa.

    s: (N, 3) in the outgoing frame (apply :func:`mirror` first); kappa: (N,)
    or scalar signed curvature [1/m] of the surface along x_hat, kappa > 0
    convex (rays diverge), kappa < 0 concave (focusing); factor = 2 for a mirror
    (the normal tilts by kappa x, the reflected ray by twice that).
    Returns (N, 3).  The renderer uses the general :func:`interface` (oblique
    incidence, refraction); this is its case scale = mu = 1, k = factor kappa.

    CORRECTED (docs/frequency.md, "curvature", missing in the paper):
        b += 2kc + k^2 a,  c += k a,  a unchanged,
    in the PSD-preserving form b' = (max(ab - c^2, 0) + c'^2) / a (unit
    determinant, as for travel).
    PAPER: the paper has no curvature operator: identity.
    """
    return interface(s, 1.0, 1.0, factor * _f64(kappa), model, A_MAX)


def interface(s, scale, mu, k, model="CORRECTED", A_MAX=A_MAX_DEFAULT):
    """A reflection or refraction at a curved interface, in surface coordinates.

    s: (N, 3) on-surface spectra (after :func:`onto_surface`, before
    :func:`off_surface`); scale, mu, k: (N,) or scalars from
    :func:`interface_map`.  The linear map (u, theta) -> (scale u, mu theta + k u):
    mu scales the angles (Snell's law linearised), k [1/m] bends them by the
    tilt of the normal along the surface (docs/frequency.md "Refraction and
    oblique incidence").  Returns (N, 3):

        a' = s^2 a,  c' = s (mu c + k a),  b' = (s^2 mu^2 max(ab - c^2, 0) + c'^2) / a',

    (b' = mu^2 b when a = 0).  When b' > 0.467 the whole Q is scaled, not b
    clipped: clipping b alone moves the focus -c/b of a wide beam (a sun,
    a = D^2, on a parabola of f = 0.5 m: clipped b put the focus at 1.46 D
    instead of f and predicted r = 0.08 m at a point focus, holding the
    radius there; tests/test_stiff_scenes.py).  Scaling keeps -c/b and
    a_eff/a, and a smaller Q is sharper, i.e. conservative.
    PAPER: no such operator in the paper: identity.
    """
    m = _model(model)
    if m == "PAPER":
        return _f64(s).copy()
    a, b, c = _split(sanitize(s, A_MAX))
    sc, mu, k = (np.where(np.isfinite(v), v, d) for v, d in
                 ((_f64(scale), 1.0), (_f64(mu), 1.0), (_f64(k), 0.0)))
    a1 = sc * sc * a
    c1 = sc * (mu * c + k * a)
    det = sc * sc * mu * mu * np.maximum(a * b - c * c, 0.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        b1 = np.where(a1 > 0, (det + c1 * c1) / np.where(a1 > 0, a1, 1.0), mu * mu * b)
    with np.errstate(invalid="ignore"):
        over = b1 > B_CAP
    f = np.where(over, B_CAP / np.where(over, b1, 1.0), 1.0)
    return sanitize(_stack(a1 * f, b1 * f, c1 * f), A_MAX)


def interface_map(cos_i, cos_t, eta, kappa_t, kappa_s, tau, reflect):
    """(scale, mu, k) of :func:`interface` at a delta bounce, each (N,) float64.

    cos_i, cos_t: |cos| of the incident and the leaving ray to the normal
    (clamped to [1e-3, 1]); eta = n_i / n_t (refraction; ignored when
    reflect); kappa_t, kappa_s [1/m]: the normal curvatures of the surface
    along the plane of incidence (tangential) and across it (sagittal),
    > 0 convex seen from the incident side; tau [1/m] the twist (the
    off-diagonal of the shape operator in those axes; its sign does not
    matter); reflect: (N,) bool, a mirror reflection (else a refraction).

    Linearised Snell (n_i cos_i dtheta_i = n_t cos_t dtheta_t, angles taken
    from the local normal, which tilts by kappa u) gives, per axis
    (Coddington's equations; docs/frequency.md "Refraction and oblique
    incidence"), with g = eta cos_i - cos_t:

    - tangential: scale 1, mu = eta cos_i / cos_t, k = g kappa_t / cos_t
      (the footprint stretch is onto_surface / off_surface's);
    - sagittal: scale cos_i / cos_t (undoes that stretch), mu = eta,
      k = g kappa_s cos_i;
    - a mirror: the same with eta = -1, cos_t = cos_i, in the reflected
      rot90 frame: tangential (1, 1, 2 kappa_t), sagittal (1, 1, 2 kappa_s cos_i^2).

    In the outgoing beam's units the bend is the symmetric power matrix
    [[g kappa_t / cos_t^2, g tau / cos_t], [., g kappa_s]] (mirror:
    [[2 kappa_t / cos_i, 2 tau], [., 2 kappa_s cos_i]]).  Flatland keeps
    one axis: its most focusing eigenvalue p (the smaller, signed), with the
    scale and mu of the axis its eigenvector is closer to (the one with the
    smaller diagonal power; ties tangential), and k = p cos_t (tangential)
    or p cos_i (sagittal).  Without twist p is that axis' own power; on a
    cylinder lit obliquely (rank-1 shape operator) p is the sum of both.
    """
    ci = np.clip(np.abs(np.nan_to_num(_f64(cos_i), nan=1.0)), COS_MIN, 1.0)
    ct = np.clip(np.abs(np.nan_to_num(_f64(cos_t), nan=1.0)), COS_MIN, 1.0)
    kt, ks, tw = (np.nan_to_num(_f64(v), nan=0.0, posinf=0.0, neginf=0.0)
                  for v in (kappa_t, kappa_s, tau))
    rf = np.asarray(reflect, bool)
    ci, ct, eta, kt, ks, tw, rf = np.broadcast_arrays(
        ci, ct, np.nan_to_num(_f64(eta), nan=1.0), kt, ks, tw, rf)
    ct = np.where(rf, ci, ct)
    g = np.where(rf, -2.0 * ci, eta * ci - ct)
    p_t = np.where(rf, 2.0 * kt / ci, g * kt / (ct * ct))
    p_s = np.where(rf, 2.0 * ks * ci, g * ks)
    p_x = np.where(rf, 2.0 * tw, g * tw / ct)
    p = 0.5 * (p_t + p_s) - np.sqrt((0.5 * (p_t - p_s)) ** 2 + p_x * p_x)
    sag = p_s < p_t
    scale = np.where(sag, ci / ct, 1.0)
    mu = np.where(rf, 1.0, np.where(sag, eta, eta * ci / ct))
    k = p * np.where(sag, ci, ct)
    return scale.astype(np.float64), mu.astype(np.float64), k.astype(np.float64)


def mirror(s):
    """Flat mirror: (x, theta) -> (-x, -theta) between rot90 frames.

    Q is invariant under a point reflection, so c keeps its sign
    (docs/frequency.md, "flat mirror").  s: (..., 3) -> (..., 3) float64 copy.
    """
    return _f64(s).copy()


# ---------------------------------------------------------------- sources
def lobe_variance(kind, roughness=0.0):
    """Angular variance [rad^2] of a reflection lobe, the ``b_lobe`` of :func:`brdf`.

    kind: 'DIFFUSE', 'PHONG', 'GGX' (also 'GLOSSY', 'GLASS', 'REFRACTION'),
    'TRANSPARENT', 'TRANSLUCENT', or the ``core.scene`` lobe constants
    (also an (N,) integer array of them, one per photon).
    roughness: scalar or array.  For 'PHONG' it is the exponent n; otherwise
    Cycles' roughness (GGX alpha = roughness^2).  Returns float64, shape of
    ``roughness``.

    - Phong: the flatland second moment of cos^n(theta) on (-pi/2, pi/2),
      which is 1/(n + 1) within 1 % for n >= 5 (n = 20: 0.0476, as in
      docs/frequency.md; the peak curvature alone would give 1/n); capped at 0.467;
    - GGX: its variance is infinite (slope density ~ |s|^-3 tails), so it is
      replaced by the Gaussian with the same *peak curvature* (Laplace
      approximation), the part that decides where the lobe stays >= 95 % of
      its peak: ln D(theta_h) = -4 ln cos - 2 ln(alpha^2 + tan^2) ~ const
      - 2 theta_h^2 (1/alpha^2 - 1), a Gaussian of variance
      alpha^2 / (4 (1 - alpha^2)) in the half-vector angle; the reflected
      direction turns by 2 theta_h, so b = alpha^2 / (1 - alpha^2).
      The tails only blur low frequencies: the peak match is the
      conservative (smaller) width.
      Checked against the sampled lobe's 95 % width in tests.
    - diffuse / translucent: 0.467 = pi^2/4 - 2 (also the cap);
    - transparent and perfect mirrors (roughness 0): 0.
    """
    from ..scene import model as _sc
    names = {_sc.DIFFUSE: "DIFFUSE", _sc.GLOSSY: "GGX", _sc.GLASS: "GGX",
             _sc.REFRACTION: "GGX", _sc.TRANSPARENT: "TRANSPARENT",
             _sc.TRANSLUCENT: "TRANSLUCENT"}
    if not isinstance(kind, str) and np.ndim(kind) > 0:
        # per-photon lobe kinds (core.scene integer constants): (N,) -> (N,)
        kinds = np.asarray(kind)
        r = np.broadcast_to(_f64(roughness), kinds.shape)
        out = np.full(kinds.shape, np.nan)
        for code, name in names.items():
            m = kinds == code
            if m.any():
                out[m] = lobe_variance(name, r[m])
        if np.isnan(out).any():
            raise ValueError(f"unknown lobe kinds {np.unique(kinds[np.isnan(out)])}")
        return out
    k = names.get(int(kind), kind) if not isinstance(kind, str) else kind.upper()
    if k in ("GLOSSY", "GLASS", "REFRACTION"):
        k = "GGX"
    r = _f64(roughness)
    if k in ("DIFFUSE", "TRANSLUCENT"):
        return np.full(r.shape, B_DIFFUSE)
    if k == "TRANSPARENT":
        return np.zeros(r.shape)
    if k == "PHONG":
        with np.errstate(divide="ignore"):
            return np.minimum(1.0 / (np.maximum(r, 0.0) + 1.0), B_CAP)
    if k == "GGX":
        al2 = np.clip(r, 0.0, 1.0) ** 4                   # alpha^2, alpha = roughness^2
        with np.errstate(divide="ignore"):
            return np.minimum(al2 / np.maximum(1.0 - al2, 0.0), B_CAP)
    raise ValueError(f"unknown lobe kind {kind!r}")


def light_init(kind, n=1, *, size=0.0, size_y=None, shape="SQUARE", radius=0.0,
               angle=0.0, spot_size=None, A_MAX=A_MAX_DEFAULT):
    """Spectra (n, 3) of photons leaving an emitter (docs/frequency.md "Light inits").

    kind: 'POINT', 'SPOT', 'AREA' or 'SUN' (``core.scene.Light.kind``).
    Each emitter is fitted from its own *primal* variance (a box spectrum's
    second moments diverge with grid resolution):
    - point / spot: a = radius^2 / 4 (a sphere of radius r projects to a disc,
      whose 1D marginal variance is r^2/4; 0 for a true point), b = 0.467
      (cosine-like spread) or, for a spot of full cone angle spot_size,
      min(0.467, h^2/3) with h = spot_size / 2;
    - area of width w: a = w^2 / 12 (uniform box), with w the smaller side
      (conservative in flatland); a disk/ellipse of diameter w: w^2 / 16;
      b = 0.467 (Lambertian emitter);
    - sun of angular diameter ``angle`` (half-angle h = angle / 2):
      a = A_MAX (spatially uniform), b = h^2 / 3.
    c = 0 for all: emitters are not sheared.
    """
    k = str(kind).upper()
    if k in ("POINT", "SPOT"):
        a = float(radius) ** 2 / 4.0
        b = B_DIFFUSE
        if k == "SPOT" and spot_size is not None:
            b = min(B_DIFFUSE, (0.5 * float(spot_size)) ** 2 / 3.0)
    elif k == "AREA":
        w = float(size) if size_y is None else min(float(size), float(size_y))
        a = w * w / (16.0 if str(shape).upper() in ("DISK", "ELLIPSE") else 12.0)
        b = B_DIFFUSE
    elif k == "SUN":
        a = float(A_MAX)
        b = min(B_CAP, (0.5 * float(angle)) ** 2 / 3.0)
    else:
        raise ValueError(f"unknown light kind {kind!r}")
    out = np.empty((int(n), 3), np.float64)
    out[:] = (a, b, 0.0)
    return out


# ---------------------------------------------------------------- hitpoint
def predicted_radius(s, b_receiver, z_camera, model="CORRECTED"):
    """Largest kernel radius [m] over which the radiance stays >= 95 % of peak.

    s: (N, 3) spectra arriving on the receiver (after :func:`onto_surface`);
    b_receiver: (N,) or scalar angular variance of the receiver's lobe
    (inf = diffuse); z_camera: (N,) or scalar camera distance projected on
    the normal [m].  Returns (N,) float64, NaN mapped to 0 (no hold).

    CORRECTED (docs/frequency.md "At the hitpoint"):
        a_eff = a - c^2 / (b + b_r)          (a for a diffuse receiver)
        r_x   = sqrt(2 beta a_eff) = 0.3203 sqrt(a_eff),   beta = -ln 0.95
        r_th  = z tan(sqrt(2 beta (b + b_r))), inf for a diffuse receiver or
                an angle >= 1.2 rad
        r     = min(r_x, r_th)
    PAPER: r_x = pi sqrt(a) beta (0.161 sigma, not a 95 % radius),
    r_th = z tan(pi sqrt(b + b_r) beta) -- passes pi/2 at b = 95 rad^2 and
    turns negative (returned as is); inf for a diffuse receiver.
    """
    m = _model(model)
    br = _f64(b_receiver)
    z = np.abs(_f64(z_camera))
    diffuse = np.isinf(br)
    if m == "PAPER":
        a, b, c = _split(s)
        with np.errstate(invalid="ignore", over="ignore"):
            rx = math.pi * np.sqrt(a) * BETA
            rt = np.where(diffuse, np.inf,
                          z * np.tan(math.pi * np.sqrt(b + np.where(diffuse, 0.0, br)) * BETA))
            r = np.minimum(rx, rt)
        return np.where(np.isnan(r), 0.0, r)
    a, b, c = _split(sanitize(s))
    br = np.where(np.isnan(br), 0.0, np.maximum(br, 0.0))   # unknown lobe: sharpest
    den = b + br
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a_eff = np.where(den > 0, a - c * c / np.where(den > 0, den, 1.0), a)
        a_eff = np.maximum(a_eff, 0.0)
        rx = np.sqrt(2.0 * BETA * a_eff)
        ang = np.sqrt(2.0 * BETA * den)
        rt = np.where(diffuse | ~(ang < ANGLE_MAX), np.inf,
                      z * np.tan(np.minimum(ang, ANGLE_MAX)))
        r = np.minimum(rx, rt)
    return np.where(np.isnan(r), 0.0, r)


def receiver_variance(kind, roughness, nondelta):
    """Angular variance b_r [rad^2] of each material's sharpest receiver lobe.

    kind, roughness: (M, L) lobe kinds (core.scene constants) and Cycles
    roughness; nondelta: (M, L) bool, the lobes a visible point can stop on.
    Returns (M,) float64 (docs/frequency.md "Receivers"):
    - Lambert, Oren-Nayar and translucent lobes: inf (a diffuse receiver:
      Oren-Nayar varies with angle only through cosines and |l.v|, no
      narrower than the cosine lobe);
    - glossy, glass and refraction (rough GGX): :func:`lobe_variance`, the
      peak-matched Gaussian alpha^2 / (1 - alpha^2);
    - the material: the minimum over its non-delta lobes (inf if none).
    """
    from ..scene import model as _sc
    kind = np.asarray(kind)
    r = _f64(roughness)
    glossy = np.isin(kind, (_sc.GLOSSY, _sc.GLASS, _sc.REFRACTION)) & np.asarray(nondelta, bool)
    out = np.full(kind.shape, np.inf)
    if glossy.any():
        out[glossy] = lobe_variance("GGX", r[glossy])
    return out.min(axis=-1) if out.ndim > 1 else out


def layered_radius(r_smooth, r_sharp, w_sharp):
    """Predicted radius [m] of a receiver with a diffuse and a glossy part.

    r_smooth: (K,) :func:`predicted_radius` for the diffuse part (b_r = inf);
    r_sharp: (K,) for the glossy part (b_r = :func:`receiver_variance`);
    w_sharp: (K,) the glossy part's share of the reflected radiance in [0, 1]
    (NaN counts as 1).  Returns (K,) float64 (docs/frequency.md "Receivers"):

        1 / r^2 = (1 - w) / r_smooth^2 + w / r_sharp^2

    Two Gaussian profiles peaking together, shares 1 - w and w, variances
    A_s, A_g: to second order the sum stays >= 95 % of its peak while
    x^2 / 2 ((1 - w) / A_s + w / A_g) <= beta, and r^2 = 2 beta A; a lobe's
    share weights its precision.  w = 0 gives r_smooth, w = 1 r_sharp; a 0
    radius (no hold) in a part with w > 0 gives 0.
    """
    rs = np.abs(_f64(r_smooth))
    rg = np.abs(_f64(r_sharp))
    w = _f64(w_sharp)
    w = np.where(np.isnan(w), 1.0, np.clip(w, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(w < 1.0, (1.0 - w) / (rs * rs), 0.0) + np.where(w > 0.0, w / (rg * rg), 0.0)
        r = 1.0 / np.sqrt(inv)
    return np.where(np.isnan(r), 0.0, r)


def accumulate(current, new, model="CORRECTED"):
    """Fold one pass's predicted radii into the per-hitpoint r_pred.

    current, new: (K,) float; ``inf`` in ``current`` = no frequency photon yet,
    ``new`` NaN counts as 0 (no hold).  Returns (K,) float64.

    CORRECTED: minimum -- conservative; the sharpest photon decides
    (docs/frequency.md: -2 % at a caustic peak next to broad light).
    PAPER: the paper keeps "the max of each coefficient" of (a, b, c)
    (:func:`accumulate_spectrum_paper`).  Reduced to one scalar radius, which
    grows with a and b, that rule is the maximum of the radii: the smoothest
    photon decides (-65 % at that caustic peak).  An empty hitpoint (inf)
    takes the new value.
    """
    m = _model(model)
    cur = _f64(current)
    nw = _f64(new)
    nw = np.where(np.isnan(nw), 0.0, nw)
    if m == "PAPER":
        return np.where(np.isinf(cur) & (cur > 0), nw, np.maximum(cur, nw))
    return np.minimum(np.where(np.isnan(cur), 0.0, cur), nw)


def radius_fold_key(r, model="CORRECTED"):
    """The value a deposit carries for the per-pixel fold of :func:`accumulate`.

    r: (K,) predicted radii.  Returns (K,) float64.  The gather
    (``core.sppm.hashgrid``) folds the radii of the photons a pixel collects
    by a *minimum*, the CORRECTED rule.  The PAPER rule keeps the *maximum*;
    max(r) = -min(-r), so under PAPER the radii travel negated and the same
    minimum serves both models: key = r (CORRECTED) or -r (PAPER).  The
    negation is exact, so the fold is bit-identical to a maximum.
    :func:`radius_from_fold_key` turns the folded key back into a radius.
    """
    r = _f64(r)
    return -r if _model(model) == "PAPER" else r


def radius_from_fold_key(key, model="CORRECTED"):
    """The radius of a folded :func:`radius_fold_key`: (K,) -> (K,) float64.

    ``inf`` (no frequency photon collected, the fold's start) stays inf for
    both models; a PAPER key -inf (a photon with r = inf) also gives inf.
    """
    key = _f64(key)
    if _model(model) == "PAPER":
        return np.where(np.isinf(key), np.inf, -key)
    return key


def accumulate_spectrum_paper(current, new):
    """The paper's per-coefficient max of (a, b, c) over collected photons.

    current, new: (K, 3); NaN rows in ``current`` mean "no photon yet" (they
    take ``new``).  Returns (K, 3).  The per-coefficient max keeps Q PSD
    (max c is either >= 0 and bounded by some sqrt(a_i b_i), or <= 0 and
    smaller in magnitude than every c_i), but it picks the smoothest photon;
    a per-coefficient *min* can make Q invalid.
    """
    return np.fmax(_f64(current), _f64(new))
