"""Cycles' surface closures as masked structure-of-arrays numpy code (float64).

Every function works on K shading points at once.  A point has a material
index ``mat`` (K,) into a :class:`MaterialTable` whose lobes (closures, up to
``MAX_LOBES``) are summed, like Cycles' closure list after Mix/Add shaders are
flattened.  Formulas follow Cycles 5.x (``intern/cycles/kernel/closure``):

- DIFFUSE, roughness < 1e-5: Lambert, f = C/pi (``bsdf_diffuse.h``).
- DIFFUSE, roughness > 0: Fujii's improved Oren-Nayar plus the OpenPBR
  energy-preserving multiple-scattering term (``bsdf_oren_nayar.h``, Blender
  >= 4.3), sigma = roughness:
    a = 1/(pi + sigma (pi/2 - 2/3)),  b = sigma a,
    s = l.v - (n.l)(n.v),  t = s / max(n.l, n.v) if s > 0 else s,
    E(mu) = a pi + b G(mu),  E_avg = a pi + b (2 pi - 5.6)/3,
    E_ms = (1/pi) A^2 (E_avg/(1 - E_avg)) / (1 - A (1 - E_avg)),  A = sat(C),
    f = C [a + b t + E_ms (1 - E(n.v)) (1 - E(n.l))].
  Sampled with the cosine distribution (Cycles samples both diffuse kinds so).
- GLOSSY: GGX, alpha = roughness^2, D = a^2/(pi (1 + (a^2 - 1) cos^2 h)^2),
  height-correlated Smith G2 = 1/(1 + L(v) + L(l)), L = (sqrt(1 + a^2 tan^2) - 1)/2,
  no Fresnel: f = C D G2 / (4 |n.v| |n.l|).  Sampled with Heitz 2018's visible
  normal distribution, pdf = D G1(wo) / (4 n.wo).  alpha^2 <= 2e-10
  (``roughness_is_almost_specular``) is a perfect mirror with weight C.
- GLASS: the same microfacet model with exact unpolarised dielectric Fresnel
  F(v.h, eta); reflection F C D G2/(4|n.v||n.l|), transmission
  (1 - F) C D G2 eta^2 |h.v||h.l| / (|n.v||n.l| |eta l + v|^2) (Walter 2007),
  reflect/refract chosen with probability F.  Smooth glass chooses by F and
  has weight C for both branches.
- REFRACTION: the transmission part with NO Fresnel factor (Cycles' Refraction
  BSDF uses ``MicrofacetFresnel::NONE``); total internal reflection absorbs.
- TRANSPARENT: wi = -wo, weight C.   TRANSLUCENT: f = C/pi on the far side.
- Multiscatter GGX (the Glossy/Glass/Principled default distribution): a lobe
  with attribute ``multiscatter=True`` scales f by 1 + F_ms (1 - E)/E as
  Cycles' ``microfacet_ggx_preserve_energy`` (see :func:`multiscatter_factor`).
- Principled BSDF layers (optional lobe attributes, :func:`build_material_table`):
  GLOSSY with the generalised-Schlick dielectric or F82-tint conductor
  Fresnel, and DIFFUSE attenuated by the view-dependent albedo of the
  specular layer above it.  Checked against Cycles renders to < 1e-3.

Deliberate differences from Cycles (all tiny or sampling-only): lobe choice is
by luminance of weight x colour (Cycles: closure sample weights); rough
refraction pairs with h.v and h.l of equal sign are zero in eval (Cycles'
eval leaves them, its sampler never makes them); Cycles' bump-map normal
correction ``ensure_valid_specular_reflection`` is not applied.

Conventions
-----------
``wo`` is always the known direction (unit, pointing away from the surface)
and ``wi`` the sampled / evaluated one.

- ``mode='radiance'`` (camera paths): ``wo`` points to the viewer.  Values are
  exactly Cycles' closure evals (Cycles' ``wi`` = our ``wo``).  Like Cycles,
  refraction does NOT scale radiance by 1/eta^2: smooth glass has weight C.
- ``mode='importance'`` (photons): ``wo`` points back to where the photon came
  from and ``wi`` is where it goes.  The BSDF is the exact adjoint of the one
  camera paths use, f*(wo, wi) = f_C(view=wi, light=wo), so that photon
  estimates converge to Cycles' image.  Because Cycles' BTDF omits the
  radiance compression, its adjoint carries it: refraction from index n_wo into
  n_wi multiplies photon power by (n_wo/n_wi)^2 (smooth glass: C/eta^2 when
  entering).  On closed objects the factors cancel either way.  Sampled
  weights also include Veach's shading-normal correction
  |wo.ns||wi.ng| / (|wo.ng||wi.ns|) (pbrt's CorrectShadingNormal).  When a
  photon is *gathered*, multiply eval_bsdf(radiance, wo=view, wi=photon dir) by
  :func:`shading_correction` (|wi.ns|/|wi.ng|), the last factor of the same
  correction.
- Two-sided: normals are flipped towards the view direction's side of the
  geometric normal, as Cycles does for back faces.  Glass/Refraction use
  eta = ior when the view direction is on the geometric normal's side
  (entering) and 1/ior otherwise.
- Like Cycles, ``eval`` does not test directions against the geometric normal
  (shadow-terminator reasons, see ``bsdf_microfacet_sample``), but sampling
  rejects directions on the wrong geometric side; ``pdf_bsdf`` is the density
  of the sampler and so applies the same test.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..scene.model import (DIFFUSE, GLASS, GLOSSY, MAX_LOBES, REFRACTION, TRANSLUCENT,
                    TRANSPARENT)
from ..scene.textures import sample_texture

# Rec. 709 luminance of linear RGB: lobe-selection weights.
from ..mathutil import LUMINANCE, dot as _dot  # noqa: E402
# Cycles ``roughness_is_almost_specular``: alpha_x * alpha_y <= 2e-10.
SPECULAR_ALPHA2 = 2e-10
# Cycles ``diffuse_roughness_is_almost_zero``: roughness < 1e-5 -> Lambert.
DIFFUSE_ROUGHNESS_EPS = 1e-5
# Cycles treats refraction as specular when |eta - 1| < 1e-4.
IOR_ONE_EPS = 1e-4
INV_PI = 1.0 / np.pi
# Multiscatter GGX for lobes that do not say (``Lobe`` has no such field yet).
DEFAULT_MULTISCATTER = False
# GLOSSY Fresnel modes (Principled BSDF layers).
FRESNEL_NONE, FRESNEL_DIELECTRIC, FRESNEL_F82 = 0, 1, 2


def f0_from_ior(ior):
    """Normal-incidence dielectric reflectance ((ior - 1)/(ior + 1))^2."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def _fss_dielectric(eta):
    """Cycles' fresnel_dielectric_Fss: Kulla-Conty fit of 2 ∫ F(mu) mu dmu."""
    eta = np.asarray(eta, np.float64)
    return np.where(eta < 1.0, 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607)),
                    (eta - 1.0) / (4.08567 + 1.00071 * eta))


# --------------------------------------------------------------------------
# Material table
# --------------------------------------------------------------------------
@dataclass
class MaterialTable:
    """Materials as arrays.  M materials, L = MAX_LOBES lobe slots.

    kind: (M, L) int32 lobe kind, -1 = unused slot.
    color: (M, L, 3) float64 Cycles "Color".
    weight: (M, L) float64 mix weight.
    roughness: (M, L) float64 Cycles roughness, clamped to [0, 1].
    ior: (M, L) float64.
    tex: (M, L) int32 texture index multiplying color, -1 = none.
    multiscatter: (M, L) bool, Cycles' "Multiscatter GGX" energy compensation
      on a GLOSSY / GLASS lobe (see :func:`multiscatter_factor`).
    fresnel, fresnel_ior, f82_tint, layer_ior, layer_f0, layer_roughness: the
      Principled BSDF's layers (see :func:`build_material_table`).
    emission: (M, 3) float64 radiance; emission_tex: (M,) int32.
    lobe_delta: (M, L) bool, the lobe is a Dirac delta (mirror, smooth glass /
      refraction, transparent).
    has_delta, has_nondelta, lambert_only: (M,) bool per-material flags;
      lambert_only = has_nondelta and every non-delta lobe is Lambert.
    textures: list of (H, W, C) images (row 0 at the bottom).
    """
    kind: np.ndarray
    color: np.ndarray
    weight: np.ndarray
    roughness: np.ndarray
    ior: np.ndarray
    tex: np.ndarray
    emission: np.ndarray
    emission_tex: np.ndarray
    lobe_delta: np.ndarray
    has_delta: np.ndarray
    has_nondelta: np.ndarray
    lambert_only: np.ndarray
    textures: list = field(default_factory=list)
    multiscatter: np.ndarray = None     # (M, L) bool, see build_material_table
    fresnel: np.ndarray = None          # (M, L) int8 FRESNEL_* (GLOSSY only)
    fresnel_ior: np.ndarray = None      # (M, L) ior of FRESNEL_DIELECTRIC
    f82_tint: np.ndarray = None         # (M, L, 3) tint of FRESNEL_F82
    layer_ior: np.ndarray = None        # (M, L) DIFFUSE under a specular layer: its ior (0 = none)
    layer_f0: np.ndarray = None         # (M, L) that layer's max-channel F0
    layer_roughness: np.ndarray = None  # (M, L) that layer's roughness
    layer_ms: np.ndarray = None         # (M, L) bool, that layer is Multiscatter GGX
    sel_scale: np.ndarray = None        # (M, L) lobe-selection scale (Fresnel-weighted lobes)

    @property
    def n_materials(self) -> int:
        return int(self.kind.shape[0])


def _is_delta_lobe(kind: int, roughness: float, ior: float) -> bool:
    if kind == TRANSPARENT:
        return True
    if kind in (GLOSSY, GLASS, REFRACTION):
        alpha = roughness * roughness
        if alpha * alpha <= SPECULAR_ALPHA2:
            return True
        # Cycles makes the refraction singular for |eta - 1| < 1e-4; the
        # reflection of such glass has F ~ 0, so the whole lobe is delta here.
        if kind in (GLASS, REFRACTION) and abs(ior - 1.0) < IOR_ONE_EPS:
            return True
    return False


def build_material_table(materials: list, textures: list) -> MaterialTable:
    """Pack ``core.scene.Material`` objects into a :class:`MaterialTable`.

    materials: list of Material (lobes beyond MAX_LOBES raise ValueError: the
      exporter merges them first, see ``core.shading``).  A lobe may carry an
      optional boolean attribute ``multiscatter`` (Cycles' Multiscatter GGX,
      the default distribution of the Glossy, Glass and Principled nodes);
      without it DEFAULT_MULTISCATTER applies.  Further optional attributes
      model the Principled BSDF's layers exactly (``core.shading`` sets them):
      GLOSSY ``fresnel='DIELECTRIC'`` + ``fresnel_ior``: the colour is the
      specular tint and f is scaled by Cycles' generalised-Schlick Fresnel
      mix(F0 tint, 1, (F(h.v) - F0)/(1 - F0)); ``fresnel='F82'`` +
      ``f82_tint``: the colour is F0 of Cycles' F82-tint conductor; DIFFUSE
      ``layer_ior``, ``layer_f0``, ``layer_roughness``, ``layer_multiscatter``:
      the diffuse lies under a dielectric specular layer and is scaled by
      1 - its albedo estimate (``closure_layering_weight``), which depends on
      the view direction.
    textures: list of (H, W, C) float32 images.
    """
    M, L = max(len(materials), 1), MAX_LOBES
    kind = np.full((M, L), -1, np.int32)
    color = np.zeros((M, L, 3))
    weight = np.zeros((M, L))
    rough = np.zeros((M, L))
    ior = np.ones((M, L))
    tex = np.full((M, L), -1, np.int32)
    emis = np.zeros((M, 3))
    emis_tex = np.full(M, -1, np.int32)
    delta = np.zeros((M, L), bool)
    ms = np.zeros((M, L), bool)
    fres = np.zeros((M, L), np.int8)
    fior = np.ones((M, L))
    f82t = np.ones((M, L, 3))
    lior = np.zeros((M, L))
    lf0 = np.zeros((M, L))
    lrough = np.zeros((M, L))
    lms = np.zeros((M, L), bool)
    sel = np.ones((M, L))
    for m, mat in enumerate(materials):
        if len(mat.lobes) > L:
            raise ValueError(f"material '{mat.name}' has {len(mat.lobes)} lobes; "
                             f"at most {L} are supported")
        for j, lobe in enumerate(mat.lobes):
            kind[m, j] = int(lobe.kind)
            color[m, j] = np.maximum(np.asarray(lobe.color, np.float64)[:3], 0.0)
            weight[m, j] = float(lobe.weight)
            rough[m, j] = min(max(float(lobe.roughness), 0.0), 1.0)
            ior[m, j] = max(float(lobe.ior), 1e-5)       # Cycles: fmaxf(ior, 1e-5)
            tex[m, j] = int(lobe.color_texture)
            delta[m, j] = _is_delta_lobe(kind[m, j], rough[m, j], ior[m, j])
            # Optional Lobe attribute (the exporter sets it from the node's
            # distribution); plain GGX when absent.
            ms[m, j] = (bool(getattr(lobe, "multiscatter", DEFAULT_MULTISCATTER))
                        and kind[m, j] in (GLOSSY, GLASS) and not delta[m, j])
            fr = str(getattr(lobe, "fresnel", "") or "").upper()
            if kind[m, j] == GLOSSY and fr in ("DIELECTRIC", "F82"):
                fres[m, j] = FRESNEL_DIELECTRIC if fr == "DIELECTRIC" else FRESNEL_F82
                fior[m, j] = max(float(getattr(lobe, "fresnel_ior", 1.5)), 1e-5)
                f82t[m, j] = np.clip(np.asarray(getattr(lobe, "f82_tint", (1.0, 1.0, 1.0)),
                                                np.float64)[:3], 0.0, 1.0)
                if fr == "DIELECTRIC":
                    # Selection by the hemispherical Fresnel average (sampling only).
                    sel[m, j] = _fss_dielectric(fior[m, j])
            if kind[m, j] == DIFFUSE and float(getattr(lobe, "layer_ior", 0.0)) > 0.0:
                lior[m, j] = float(lobe.layer_ior)
                lf0[m, j] = float(getattr(lobe, "layer_f0", f0_from_ior(lior[m, j])))
                lrough[m, j] = min(max(float(getattr(lobe, "layer_roughness", 0.5)), 0.0), 1.0)
                lms[m, j] = bool(getattr(lobe, "layer_multiscatter", False))
        emis[m] = np.asarray(mat.emission, np.float64)[:3]
        emis_tex[m] = int(mat.emission_texture)
    used = (kind >= 0) & (weight != 0.0)
    nondelta = used & ~delta
    lambert = nondelta & (kind == DIFFUSE) & (rough < DIFFUSE_ROUGHNESS_EPS) & (lior <= 0.0)
    has_nd = nondelta.any(axis=1)
    return MaterialTable(
        kind=kind, color=color, weight=weight, roughness=rough, ior=ior, tex=tex,
        emission=emis, emission_tex=emis_tex, lobe_delta=delta,
        has_delta=(used & delta).any(axis=1), has_nondelta=has_nd,
        lambert_only=has_nd & ~(nondelta & ~lambert).any(axis=1),
        textures=list(textures), multiscatter=ms, fresnel=fres, fresnel_ior=fior,
        f82_tint=f82t, layer_ior=lior, layer_f0=lf0, layer_roughness=lrough, layer_ms=lms,
        sel_scale=sel)


def lobe_colors(table: MaterialTable, mat: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Per-lobe colour x weight x texture.  mat (K,) int, uv (K, 2) -> (K, L, 3) float64."""
    mat = np.asarray(mat, np.int64)
    cols = table.color[mat] * table.weight[mat][:, :, None]
    cols[table.kind[mat] < 0] = 0.0
    tex = table.tex[mat]
    if (tex >= 0).any():
        uv = np.asarray(uv, np.float64)
        for j in range(tex.shape[1]):
            for t in np.unique(tex[:, j]):
                if t < 0:
                    continue
                idx = np.nonzero(tex[:, j] == t)[0]
                cols[idx, j] *= sample_texture(table.textures[t], uv[idx])
    return cols


def emission_radiance(table: MaterialTable, mat: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Emitted radiance (two-sided) of each point: (K,) mat, (K, 2) uv -> (K, 3) float64."""
    mat = np.asarray(mat, np.int64)
    e = table.emission[mat].copy()
    et = table.emission_tex[mat]
    for t in np.unique(et):
        if t < 0:
            continue
        idx = np.nonzero(et == t)[0]
        e[idx] *= sample_texture(table.textures[t], np.asarray(uv, np.float64)[idx])
    return e


def _selection_weights(table, mat, colors, subset):
    """Unnormalised lobe-selection weights (K, L): luminance of weight x colour."""
    mat = np.asarray(mat, np.int64)
    w = np.maximum(colors @ LUMINANCE, 0.0)
    if table.sel_scale is not None:
        w *= table.sel_scale[mat]
    w[table.kind[mat] < 0] = 0.0
    if subset == "delta":
        w[~table.lobe_delta[mat]] = 0.0
    elif subset == "nondelta":
        w[table.lobe_delta[mat]] = 0.0
    elif subset != "all":
        raise ValueError(f"subset must be 'all', 'delta' or 'nondelta', not {subset!r}")
    return w


def delta_probability(table: MaterialTable, mat: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """Probability (K,) that luminance-proportional lobe selection picks a delta lobe."""
    w = _selection_weights(table, mat, colors, "all")
    tot = w.sum(axis=1)
    wd = np.where(table.lobe_delta[np.asarray(mat, np.int64)], w, 0.0).sum(axis=1)
    return np.where(tot > 0, wd / np.where(tot > 0, tot, 1.0), 0.0)


def lambert_albedo(table: MaterialTable, mat: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """Sum (K, 3) of the Lambert (DIFFUSE, roughness 0, not layered) lobe colours."""
    mat = np.asarray(mat, np.int64)
    is_l = (table.kind[mat] == DIFFUSE) & (table.roughness[mat] < DIFFUSE_ROUGHNESS_EPS)
    if table.layer_ior is not None:
        is_l &= table.layer_ior[mat] <= 0.0
    return (colors * is_l[:, :, None]).sum(axis=1)


# --------------------------------------------------------------------------
# Vector helpers
# --------------------------------------------------------------------------
def _normalize(a):
    n = np.sqrt(_dot(a, a))
    return a / np.where(n > 0, n, 1.0)[:, None]


def _orient(n_s, n_g, v):
    """Flip both normals to v's side of the geometric normal (Cycles' back faces).

    Returns (N, Ng, front) with front = v on the original geometric side."""
    front = _dot(n_g, v) >= 0.0
    s = np.where(front, 1.0, -1.0)[:, None]
    return n_s * s, n_g * s, front


def _frame(n):
    """Orthonormal tangents (t, b) of unit normals n (Duff et al. 2017)."""
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    bb = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, bb


def shading_correction(n_s: np.ndarray, n_g: np.ndarray, w: np.ndarray) -> np.ndarray:
    """|w.n_s| / |w.n_g| (K,): factor for a gathered photon arriving along w (Veach 1997, 5.3)."""
    d = np.abs(_dot(n_g, w))
    return np.where(d > 0, np.abs(_dot(n_s, w)) / np.where(d > 0, d, 1.0), 0.0)


def _disk(u1, u2):
    """Shirley-Chiu concentric map of [0,1)^2 onto the unit disk (Cycles' sample_uniform_disk)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    big_a = np.abs(a) > np.abs(b)
    r = np.where(big_a, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(big_a, (np.pi / 4) * (b / a), np.pi / 2 - (np.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def _cos_hemisphere(u1, u2):
    x, y = _disk(u1, u2)
    z = np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y))
    return np.stack([x, y, z], axis=1)


def fresnel_dielectric(cos_i: np.ndarray, eta: np.ndarray):
    """Exact unpolarised Fresnel reflectance and cos of the transmitted angle.

    cos_i: (k,) cosine on the incident side; eta: (k,) index of the far side
    over the incident side.  Returns (F, cos_t) with F = 1 and cos_t = 0 under
    total internal reflection (Cycles' ``fresnel_dielectric_cos``)."""
    c = np.abs(cos_i)
    g2 = eta * eta - 1.0 + c * c
    tir = g2 <= 0.0
    g = np.sqrt(np.where(tir, 1.0, g2))
    A = (g - c) / (g + c)
    B = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    F = np.where(tir, 1.0, 0.5 * A * A * (1.0 + B * B))
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - c * c) / (eta * eta)))
    return F, np.where(tir, 0.0, cos_t)


def ggx_D(alpha2, cos_h):
    c2 = np.minimum(cos_h * cos_h, 1.0)
    return alpha2 / (np.pi * (1.0 - c2 + alpha2 * c2) ** 2)


def ggx_lambda(alpha2, cos_n):
    c2 = np.maximum(cos_n * cos_n, 1e-300)
    return 0.5 * (np.sqrt(1.0 + alpha2 * np.maximum(1.0 / c2 - 1.0, 0.0)) - 1.0)


def _oren_nayar_G(c):
    """Cycles' bsdf_oren_nayar_G: the b-coefficient of the directional albedo E(mu)."""
    cs = np.maximum(c, 1e-6)
    s = np.sqrt(np.maximum(0.0, 1.0 - cs * cs))
    th = np.arccos(np.clip(cs, -1.0, 1.0))
    g = s * (th - 2.0 / 3.0 - s * cs) + 2.0 / 3.0 * (s / cs) * (1.0 - s * s * s)
    return np.where(c < 1e-6, (np.pi / 2 - 2.0 / 3.0) - c, g)


def oren_nayar_f(col, ucol, sigma, N, v, l):
    """Energy-preserving Oren-Nayar f (k, 3) (no cosine); zero below the normal."""
    sigma = np.clip(sigma, 0.0, 1.0)
    a = 1.0 / (np.pi + sigma * (np.pi / 2 - 2.0 / 3.0))
    b = sigma * a
    nl_raw = _dot(N, l)
    nl = np.maximum(nl_raw, 0.0)
    nv = np.maximum(_dot(N, v), 0.0)
    t = _dot(l, v) - nl * nv
    t = np.where(t > 0.0, t / (np.maximum(nl, nv) + 1e-38), t)
    single = a + b * t
    A = np.clip(ucol, 0.0, 1.0)
    Eavg = (a * np.pi + (2.0 * np.pi - 5.6) / 3.0 * b)[:, None]
    Ems = INV_PI * A * A * (Eavg / (1.0 - Eavg)) / (1.0 - A * (1.0 - Eavg))
    Ev = a * np.pi + b * _oren_nayar_G(nv)
    El = a * np.pi + b * _oren_nayar_G(nl)
    f = col * (single[:, None] + Ems * ((1.0 - Ev) * (1.0 - El))[:, None])
    return f * (nl_raw > 0.0)[:, None]


# --------------------------------------------------------------------------
# Per-lobe evaluation (Cycles' closure eval, view/light roles explicit)
# --------------------------------------------------------------------------
def _microfacet_f(kind, alpha2, eta, N, v, l):
    """Scalar microfacet f(v, l) (k,) without colour, Cycles' bsdf_microfacet_eval / cos.

    kind GLOSSY, GLASS or REFRACTION; eta = far-side index / v-side index;
    N oriented to v's geometric side."""
    cI = _dot(N, v)
    cO = _dot(N, l)
    out = np.zeros(len(cI))
    trans = cO < 0.0
    ok = cI > 0.0
    if kind == GLOSSY:
        ok &= cO > 0.0
    lam_I = ggx_lambda(alpha2, cI)
    lam_O = ggx_lambda(alpha2, cO)
    G2 = 1.0 / (1.0 + lam_I + lam_O)
    # Reflection.
    r = ok & (cO > 0.0)
    if r.any():
        H = _normalize(v[r] + l[r])
        D = ggx_D(alpha2[r], _dot(N[r], H))
        val = D * G2[r] / (4.0 * cI[r] * cO[r])
        if kind == GLASS:
            val *= fresnel_dielectric(_dot(H, v[r]), eta[r])[0]
        elif kind == REFRACTION:
            val[:] = 0.0
        out[r] = val
    # Transmission (generalised half vector, Walter 2007 eq. 16).
    t = ok & trans & (kind != GLOSSY)
    if t.any():
        Hu = -(eta[t, None] * l[t] + v[t])
        H = _normalize(Hu)
        H = H * np.where(_dot(N[t], H) < 0.0, -1.0, 1.0)[:, None]
        hv = _dot(H, v[t])
        hl = _dot(H, l[t])
        F = fresnel_dielectric(hv, eta[t])[0]
        Tf = (1.0 - F) if kind == GLASS else (F < 1.0).astype(np.float64)
        # A physical refraction pair has h.v > 0 > h.l (Cycles leaves this TODO
        # unchecked in eval; its sampler never produces other pairs).
        phys = (hv > 0.0) & (hl < 0.0)
        D = ggx_D(alpha2[t], _dot(N[t], H))
        val = (Tf * D * G2[t] * eta[t] ** 2 * np.abs(hv * hl)
               / (cI[t] * np.abs(cO[t]) * _dot(Hu, Hu)))
        out[t] = np.where(phys, val, 0.0)
    return out


def _microfacet_pdf(kind, alpha2, eta, N, Ng, wo, wi):
    """Density (k,) of the VNDF sampler of wi given wo; N, Ng oriented to wo's side."""
    cI = _dot(N, wo)
    cO = _dot(N, wi)
    gO = _dot(Ng, wi)
    out = np.zeros(len(cI))
    ok = cI > 0.0
    G1 = 1.0 / (1.0 + ggx_lambda(alpha2, cI))
    r = ok & (cO > 0.0) & (gO > 0.0) & (kind != REFRACTION)
    if r.any():
        H = _normalize(wo[r] + wi[r])
        val = ggx_D(alpha2[r], _dot(N[r], H)) * G1[r] / (4.0 * cI[r])
        if kind == GLASS:
            val *= fresnel_dielectric(_dot(H, wo[r]), eta[r])[0]
        out[r] = val
    t = ok & (cO < 0.0) & (gO < 0.0) & (kind != GLOSSY)
    if t.any():
        Hu = -(eta[t, None] * wi[t] + wo[t])
        H = _normalize(Hu)
        H = H * np.where(_dot(N[t], H) < 0.0, -1.0, 1.0)[:, None]
        ho = _dot(H, wo[t])
        hi = _dot(H, wi[t])
        F = fresnel_dielectric(ho, eta[t])[0]
        sel = (1.0 - F) if kind == GLASS else (F < 1.0).astype(np.float64)
        val = (sel * ggx_D(alpha2[t], _dot(N[t], H)) * G1[t] / cI[t]
               * eta[t] ** 2 * np.abs(ho * hi) / _dot(Hu, Hu))
        out[t] = np.where((ho > 0.0) & (hi < 0.0), val, 0.0)
    return out


# --------------------------------------------------------------------------
# Multiscatter GGX (Cycles' microfacet_ggx_preserve_energy)
# --------------------------------------------------------------------------
# Cycles scales single-scattering GGX by 1 + F_ms (1 - E)/E, with E(rough, mu)
# the directional albedo of the lobe for the view cosine mu, looked up in
# precomputed tables, and F_ms = C E_avg / (1 - C (1 - E_avg)) (Kulla & Conty
# 2017) for the closure colour C (no mix weight).  The tables here are
# recomputed with the same grids as ``cycles_precompute.cpp``: rough = x/(n-1),
# mu = y/(n-1) (both clamped to >= 1e-4), glass ior = (1 + z^2)/(1 - z^2) for
# z = y/(n-1) in [1e-4, 0.99]; E is the mean sample weight G2/G1 of the VNDF
# sampler (glass: Fresnel-weighted reflection + transmission, no eta^2), here
# by deterministic quadrature instead of Monte Carlo.
_MS_CACHE = {}
MS_NODES = 24      # midpoint nodes per axis of the albedo integral


def _ms_weight(alpha, mu, eta, glass, n):
    """Albedo E (shape S) of single-scattering GGX (or glass) for arrays alpha, mu, eta.

    E = ∫ D(h) G2(wo, wi(h)) (wo.h) / (n.wo) dω_h (the mean VNDF weight G2/G1).
    With u = tan^2/(alpha^2 + tan^2), D cos dω_h = du dphi / (2 pi), so E is the
    mean of G2 (wo.h)/((n.wo)(n.h)) over (u, phi); the integrand is continuous
    (G2 -> 0 at the horizon, 1 - F -> 0 at total internal reflection), so an
    n x n midpoint rule over t in [0, 1) (u = 1 - (1-t)^2), phi in [0, pi]
    (mirror symmetry) converges.
    """
    S = alpha.shape
    a2 = (alpha.reshape(-1, 1, 1) ** 2)
    m = mu.reshape(-1, 1, 1)
    e = eta.reshape(-1, 1, 1)
    g = (np.arange(n) + 0.5) / n
    # u = 1 - (1 - t)^2, du = 2 (1 - t) dt, removes the 1/sqrt(1 - u) growth of
    # (wo.h)/(n.h) at the horizon of h.
    t = g.reshape(1, -1, 1)
    u = 1.0 - (1.0 - t) ** 2
    jac = 2.0 * (1.0 - t)
    ph = (np.pi * g).reshape(1, 1, -1)
    tan2 = a2 * u / (1.0 - u)
    ch = 1.0 / np.sqrt(1.0 + tan2)
    sh = np.sqrt(np.maximum(0.0, 1.0 - ch * ch))
    so = np.sqrt(np.maximum(0.0, 1.0 - m * m))
    hx, hy = sh * np.cos(ph), sh * np.sin(ph)
    hwo = so * hx + m * ch                       # wo = (so, 0, m)
    base = np.maximum(hwo, 0.0) / (m * ch) * jac
    lam_o = ggx_lambda(a2, m)
    # Reflection: wi_z = 2 (wo.h) h_z - wo_z.
    wr_z = 2.0 * hwo * ch - m
    G2r = np.where(wr_z > 0, 1.0 / (1.0 + lam_o + ggx_lambda(a2, np.maximum(wr_z, 1e-300))), 0.0)
    if not glass:
        return (G2r * base).mean(axis=(1, 2)).reshape(S)
    c = np.abs(hwo)
    g2 = e * e - 1.0 + c * c
    tir = g2 <= 0
    gg = np.sqrt(np.where(tir, 1.0, g2))
    A = (gg - c) / (gg + c)
    Bc = (c * (gg + c) - 1.0) / (c * (gg - c) + 1.0)
    F = np.where(tir, 1.0, 0.5 * A * A * (1.0 + Bc * Bc))
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - c * c) / (e * e)))
    # Refraction about h: wt = (hwo/eta - cos_t) h - wo/eta, z component:
    wt_z = (hwo / e - cos_t) * ch - m / e
    G2t = np.where((wt_z < 0) & ~tir,
                   1.0 / (1.0 + lam_o + ggx_lambda(a2, np.minimum(wt_z, -1e-300))), 0.0)
    return ((F * G2r + (1.0 - F) * G2t) * base).mean(axis=(1, 2)).reshape(S)


def _ms_tables():
    """Reflection (E (32 rough, 32 mu), E_avg (32,)), computed once per process."""
    if "ggx" not in _MS_CACHE:
        n = 32
        grid = np.clip(np.arange(n) / (n - 1), 1e-4, 1.0)
        R, Mu = np.meshgrid(grid, grid, indexing="ij")
        E = np.clip(_ms_weight(R * R, Mu, np.ones_like(R), False, 64), 0.0, 1.0)
        # E_avg = 2 ∫ mu E(mu) dmu, trapezoid over the mu nodes.
        _MS_CACHE["ggx"] = (E, np.trapezoid(2.0 * grid * E, grid, axis=-1))
    return _MS_CACHE["ggx"]


def _ms_glass_slice(inv: int, k: int):
    """Glass (E (16 rough, 16 mu), E_avg (16,)) for ior node k (inv: 1/ior), cached.

    Scenes use few iors, so only the slices that are read get computed."""
    key = ("glass", inv, k)
    if key not in _MS_CACHE:
        n = 16
        grid = np.clip(np.arange(n) / (n - 1), 1e-4, 1.0)
        z = min(max(k / (n - 1), 1e-4), 0.99)
        ior = (1 + z * z) / (1 - z * z)
        R, Mu = np.meshgrid(grid, grid, indexing="ij")
        eta = np.full_like(R, 1.0 / ior if inv else ior)
        E = np.clip(_ms_weight(R * R, Mu, eta, True, 48), 0.0, 1.0)
        _MS_CACHE[key] = (E, np.trapezoid(2.0 * grid * E, grid, axis=-1))
    return _MS_CACHE[key]


def _schlick_s_weight(alpha, mu, eta, n):
    """Cycles' ggx_gen_schlick_ior_s: mean over VNDF samples (invalid = 0) of
    s = sat((F_real(h.wo) - F0)/(1 - F0)), by the quadrature of :func:`_ms_weight`."""
    S = alpha.shape
    a2 = alpha.reshape(-1, 1, 1) ** 2
    m = mu.reshape(-1, 1, 1)
    e = eta.reshape(-1, 1, 1)
    g = (np.arange(n) + 0.5) / n
    t = g.reshape(1, -1, 1)
    u = 1.0 - (1.0 - t) ** 2
    jac = 2.0 * (1.0 - t)
    ph = (np.pi * g).reshape(1, 1, -1)
    tan2 = a2 * u / (1.0 - u)
    ch = 1.0 / np.sqrt(1.0 + tan2)
    sh = np.sqrt(np.maximum(0.0, 1.0 - ch * ch))
    so = np.sqrt(np.maximum(0.0, 1.0 - m * m))
    hwo = so * sh * np.cos(ph) + m * ch
    G1 = 1.0 / (1.0 + ggx_lambda(a2, m))
    vndf = G1 * np.maximum(hwo, 0.0) / (m * ch) * jac          # VNDF in (t, phi) measure
    valid = (2.0 * hwo * ch - m) > 0
    shp = np.broadcast_shapes(hwo.shape, e.shape)
    Fr = fresnel_dielectric(np.broadcast_to(hwo, shp).reshape(-1),
                            np.broadcast_to(e, shp).reshape(-1))[0].reshape(shp)
    F0 = f0_from_ior(e)
    s = np.clip((Fr - F0) / np.maximum(1.0 - F0, 1e-12), 0.0, 1.0)
    return (vndf * s * valid).mean(axis=(1, 2)).reshape(S)


def _schlick_s_slice(k: int):
    """s table (16 rough, 16 mu) at ior node k (Cycles' z = k/15 grid), cached."""
    key = ("schlick_s", k)
    if key not in _MS_CACHE:
        n = 16
        grid = np.clip(np.arange(n) / (n - 1), 1e-4, 1.0)
        z = min(max(k / (n - 1), 1e-4), 0.99)
        R, Mu = np.meshgrid(grid, grid, indexing="ij")
        eta = np.full_like(R, (1 + z * z) / (1 - z * z))
        _MS_CACHE[key] = np.clip(_schlick_s_weight(R * R, Mu, eta, 48), 0.0, 1.0)
    return _MS_CACHE[key]


def layer_transmission(f0, rough, ior, mu, ms=None):
    """1 - albedo (k,) of a Principled dielectric specular layer seen at cosine mu.

    Cycles' closure_layering_weight: the diffuse below gets 1 - A with the
    layer's bsdf_albedo A = d mix(f0, 1, s), s from the ggx_gen_schlick_ior_s
    table at (roughness, mu, z(ior)), and d = E + F_ms (1 - E) the weight
    change of microfacet_ggx_preserve_energy for Multiscatter GGX (d = 1 for
    plain GGX).  f0: (k,) max-channel F0 x tint; rough, ior, mu: (k,); ms: (k,) bool."""
    z = np.sqrt(np.abs((ior - 1.0) / (ior + 1.0)))
    k, tk = _lerp_index(z, 16)
    i, ti = _lerp_index(rough, 16)
    j, tj = _lerp_index(mu, 16)
    s = np.zeros(len(mu))
    for dk in (0, 1):
        wk = tk if dk else 1 - tk
        for kk in np.unique(k + dk):
            sel = k + dk == kk
            T = _schlick_s_slice(int(kk))
            ii, ti_, jj, tj_ = i[sel], ti[sel], j[sel], tj[sel]
            s[sel] += wk[sel] * ((1 - ti_) * ((1 - tj_) * T[ii, jj] + tj_ * T[ii, jj + 1])
                                 + ti_ * ((1 - tj_) * T[ii + 1, jj] + tj_ * T[ii + 1, jj + 1]))
    A = f0 + (1.0 - f0) * s
    if ms is not None and np.any(ms):
        F0 = f0_from_ior(ior[ms])
        s_ss = np.clip((_fss_dielectric(ior[ms]) - F0) / np.maximum(1.0 - F0, 1e-12), 0.0, 1.0)
        fss = f0[ms] + (1.0 - f0[ms]) * s_ss
        E_t, Eavg_t = _ms_tables()
        i2, ti2 = _lerp_index(rough[ms], 32)
        j2, tj2 = _lerp_index(mu[ms], 32)
        E = ((1 - ti2) * ((1 - tj2) * E_t[i2, j2] + tj2 * E_t[i2, j2 + 1])
             + ti2 * ((1 - tj2) * E_t[i2 + 1, j2] + tj2 * E_t[i2 + 1, j2 + 1]))
        Eavg = (1 - ti2) * Eavg_t[i2] + ti2 * Eavg_t[i2 + 1]
        fms = fss * Eavg / np.maximum(1.0 - fss * (1.0 - Eavg), 1e-12)
        A[ms] *= E + fms * (1.0 - E)
    return np.clip(1.0 - A, 0.0, 1.0)


def _lerp_index(x, n):
    """Cycles' lookup_table_read: clamp x to [0, 1], linear between n nodes."""
    t = np.clip(x, 0.0, 1.0) * (n - 1)
    i = np.minimum(np.floor(t).astype(np.int64), n - 2)
    return i, t - i


def multiscatter_factor(kind, color, rough, eta, mu):
    """Per-channel factor (k, 3) turning single- into multiple-scattering GGX.

    color: (k, 3) closure colour without mix weight; rough: (k,) roughness;
    eta: (k,) relative ior (glass); mu: (k,) cosine of the view direction.
    """
    if kind != GLASS:
        E_t, Eavg_t = _ms_tables()
        i, ti = _lerp_index(rough, 32)
        j, tj = _lerp_index(mu, 32)
        E = ((1 - ti) * ((1 - tj) * E_t[i, j] + tj * E_t[i, j + 1])
             + ti * ((1 - tj) * E_t[i + 1, j] + tj * E_t[i + 1, j + 1]))
        Eavg = (1 - ti) * Eavg_t[i] + ti * Eavg_t[i + 1]
    else:
        inv = (eta < 1.0).astype(np.int64)
        ior = np.where(inv == 1, 1.0 / eta, eta)
        z = np.sqrt(np.abs((ior - 1.0) / (ior + 1.0)))
        # Cycles reads the z axis linearly on the node grid k/15 (clamped nodes).
        k, tk = _lerp_index(z, 16)
        i, ti = _lerp_index(rough, 16)
        j, tj = _lerp_index(mu, 16)
        E = np.zeros(len(rough))
        Eavg = np.zeros(len(rough))
        for dk in (0, 1):
            wk = tk if dk else 1 - tk
            for s_, kk in set(zip(inv.tolist(), (k + dk).tolist())):
                sel = (inv == s_) & (k + dk == kk)
                E_t, Eavg_t = _ms_glass_slice(s_, kk)
                ii, ti_, jj, tj_ = i[sel], ti[sel], j[sel], tj[sel]
                E[sel] += wk[sel] * ((1 - ti_) * ((1 - tj_) * E_t[ii, jj] + tj_ * E_t[ii, jj + 1])
                                     + ti_ * ((1 - tj_) * E_t[ii + 1, jj] + tj_ * E_t[ii + 1, jj + 1]))
                Eavg[sel] += wk[sel] * ((1 - ti_) * Eavg_t[ii] + ti_ * Eavg_t[ii + 1])
    E = np.maximum(E, 1e-6)[:, None]
    Eavg = Eavg[:, None]
    C = np.maximum(color, 0.0)
    Fms = C * Eavg / np.maximum(1.0 - C * (1.0 - Eavg), 1e-12)
    return 1.0 + Fms * (1.0 - E) / E


def _principled_fresnel(mode, C, fior, tint, cos_hv):
    """Per-channel Fresnel (k, 3) of a Principled layer and its F_ss (k, 3).

    FRESNEL_DIELECTRIC: generalised Schlick with exponent -ior, f0 = F0 C,
    F = mix(f0, 1, s), s = sat((F_real(h.v) - F0)/(1 - F0)); F_ss uses
    Cycles' Fss fit for s.  FRESNEL_F82: F82-tint conductor, F0 = sat(C),
    F = sat(mix(F0, 1, (1-c)^5) - B c (1-c)^6),
    B = mix(F0, 1, f^5) 7/f^6 (1 - tint), f = 6/7; F_ss = mix(F0, 1, 1/21) - B/126.
    """
    if mode == FRESNEL_DIELECTRIC:
        F0 = f0_from_ior(fior)[:, None]
        f0 = np.clip(F0 * C, 0.0, 1.0)
        Fr = fresnel_dielectric(cos_hv, fior)[0][:, None]
        s = np.clip((Fr - F0) / np.maximum(1.0 - F0, 1e-12), 0.0, 1.0)
        s_ss = np.clip((_fss_dielectric(fior)[:, None] - F0) / np.maximum(1.0 - F0, 1e-12), 0.0, 1.0)
        return f0 + (1.0 - f0) * s, f0 + (1.0 - f0) * s_ss
    F0 = np.clip(C, 0.0, 1.0)
    f = 6.0 / 7.0
    f5 = f ** 5
    B = (F0 + (1.0 - F0) * f5) * (7.0 / (f5 * f)) * (1.0 - tint)
    c = cos_hv[:, None]
    sm = np.clip(1.0 - c, 0.0, 1.0)
    F = np.clip(F0 + (1.0 - F0) * sm ** 5 - B * c * sm ** 6, 0.0, 1.0)
    return F, F0 + (1.0 - F0) / 21.0 - B / 126.0


def _lobe_f(kind, col, ucol, rough, eta, N, v, l, ms=None, ext=None):
    """Cycles f_C(view=v, light=l) (k, 3) of one non-delta lobe kind.

    ms: (k,) bool, apply Multiscatter GGX energy compensation (GLOSSY, GLASS).
    ext: dict of Principled-layer arrays for these points (or None):
      'weight' (k,), 'fresnel' (k,), 'fresnel_ior' (k,), 'f82_tint' (k, 3),
      'layer_ior', 'layer_f0', 'layer_roughness' (k,)."""
    if kind == DIFFUSE:
        lam = rough < DIFFUSE_ROUGHNESS_EPS
        f = col * (INV_PI * (_dot(N, l) > 0.0))[:, None]
        on = ~lam
        if on.any():
            f[on] = oren_nayar_f(col[on], ucol[on], rough[on], N[on], v[on], l[on])
        if ext is not None and (ext["layer_ior"] > 0).any():
            lay = ext["layer_ior"] > 0
            f[lay] *= layer_transmission(ext["layer_f0"][lay], ext["layer_roughness"][lay],
                                         ext["layer_ior"][lay], _dot(N[lay], v[lay]),
                                         ext["layer_ms"][lay])[:, None]
        return f
    if kind == TRANSLUCENT:
        return col * (INV_PI * (_dot(N, l) < 0.0))[:, None]
    if kind in (GLOSSY, GLASS, REFRACTION):
        alpha2 = rough ** 4
        fs = _microfacet_f(kind, alpha2, eta, N, v, l)
        f = col * fs[:, None]
        fss = ucol
        if kind == GLOSSY and ext is not None and (ext["fresnel"] > 0).any():
            fss = ucol.copy()
            for mode in (FRESNEL_DIELECTRIC, FRESNEL_F82):
                q = ext["fresnel"] == mode
                if not q.any():
                    continue
                H = _normalize(v[q] + l[q])
                F, fss[q] = _principled_fresnel(mode, ucol[q], ext["fresnel_ior"][q],
                                                ext["f82_tint"][q], _dot(H, v[q]))
                # The colour is F0 / tint: Fresnel replaces it, the mix weight stays.
                f[q] = ext["weight"][q, None] * F * fs[q, None]
        if ms is not None and ms.any() and kind != REFRACTION:
            f[ms] *= multiscatter_factor(kind, fss[ms], rough[ms], eta[ms],
                                         _dot(N[ms], v[ms]))
        return f
    return np.zeros_like(col)


def _lobe_pdf(kind, rough, eta, N, Ng, wo, wi):
    """Sampling density (k,) of one non-delta lobe kind (N, Ng oriented to wo)."""
    if kind == DIFFUSE:
        return np.maximum(_dot(N, wi), 0.0) * INV_PI * (_dot(Ng, wi) > 0.0)
    if kind == TRANSLUCENT:
        return np.maximum(-_dot(N, wi), 0.0) * INV_PI * (_dot(Ng, wi) < 0.0)
    if kind in (GLOSSY, GLASS, REFRACTION):
        return _microfacet_pdf(kind, rough ** 4, eta, N, Ng, wo, wi)
    return np.zeros(len(rough))


def _prep(n_s, n_g, wo, wi):
    f64 = lambda a: np.asarray(a, np.float64).reshape(-1, 3)
    return f64(n_s), f64(n_g), f64(wo), None if wi is None else f64(wi)


def eval_bsdf(table: MaterialTable, mat, colors, n_s, n_g, wo, wi, mode="radiance"):
    """Sum of the non-delta lobes' f (K, 3), without cosine.

    mat (K,) int; colors (K, L, 3) from :func:`lobe_colors`; n_s, n_g (K, 3)
    unit shading / geometric normals (any orientation); wo, wi (K, 3) unit.
    mode 'radiance': Cycles' f with wo = view; 'importance': the adjoint
    f_C(view=wi, light=wo) (no shading-normal factor, see the module doc).
    """
    mat = np.asarray(mat, np.int64)
    n_s, n_g, wo, wi = _prep(n_s, n_g, wo, wi)
    if mode == "radiance":
        v, l = wo, wi
    elif mode == "importance":
        v, l = wi, wo
    else:
        raise ValueError(f"mode must be 'radiance' or 'importance', not {mode!r}")
    N, _, front = _orient(n_s, n_g, v)
    return _eval_nd(table, mat, colors, N, front, v, l)


def _groups(valid, kinds):
    """Yield (slot j, kind k, index) groups; the index is a full slice when every
    point is in the group (views instead of fancy-indexed copies)."""
    K = kinds.shape[0]
    for j in range(kinds.shape[1]):
        kj = kinds[valid[:, j], j]
        if kj.size == 0:
            continue
        for k in np.unique(kj):
            m = valid[:, j] & (kinds[:, j] == k)
            if kj.size == K and m.all():
                yield j, int(k), slice(None)
            else:
                yield j, int(k), np.nonzero(m)[0]


def _eval_nd(table, mat, colors, N, front_v, v, l):
    K = len(mat)
    f = np.zeros((K, 3))
    kinds = table.kind[mat]
    nd = (kinds >= 0) & ~table.lobe_delta[mat]
    for j, k, idx in _groups(nd, kinds):
        mj = mat[idx]
        col = colors[idx, j]
        rough = table.roughness[mj, j]
        ms = None if table.multiscatter is None else table.multiscatter[mj, j]
        # Colour without mix weight: only Oren-Nayar and Multiscatter GGX need it.
        if (k == DIFFUSE and (rough >= DIFFUSE_ROUGHNESS_EPS).any()) or (ms is not None and ms.any()):
            w = table.weight[mj, j][:, None]
            ucol = np.where(w != 0.0, col / np.where(w != 0.0, w, 1.0), 0.0)
        else:
            ucol = col
        ior = table.ior[mj, j]
        eta = np.where(front_v[idx], ior, 1.0 / ior)
        ext = None
        if table.fresnel is not None and ((table.fresnel[mj, j] > 0).any()
                                          or (table.layer_ior[mj, j] > 0).any()):
            ext = {"weight": table.weight[mj, j], "fresnel": table.fresnel[mj, j],
                   "fresnel_ior": table.fresnel_ior[mj, j], "f82_tint": table.f82_tint[mj, j],
                   "layer_ior": table.layer_ior[mj, j], "layer_f0": table.layer_f0[mj, j],
                   "layer_roughness": table.layer_roughness[mj, j],
                   "layer_ms": table.layer_ms[mj, j]}
            if not (ms is not None and ms.any()):
                w = table.weight[mj, j][:, None]
                ucol = np.where(w != 0.0, col / np.where(w != 0.0, w, 1.0), 0.0)
        f[idx] += _lobe_f(k, col, ucol, rough, eta, N[idx], v[idx], l[idx], ms, ext)
    return f


def _pdf_nd(table, mat, sel_p, N, Ng, front_o, wo, wi):
    """Σ over non-delta lobes of p_select x pdf (K,); N, Ng oriented to wo."""
    K = len(mat)
    pdf = np.zeros(K)
    kinds = table.kind[mat]
    nd = (kinds >= 0) & ~table.lobe_delta[mat] & (sel_p > 0.0)
    for j, k, idx in _groups(nd, kinds):
        mj = mat[idx]
        ior = table.ior[mj, j]
        eta = np.where(front_o[idx], ior, 1.0 / ior)
        pdf[idx] += sel_p[idx, j] * _lobe_pdf(k, table.roughness[mj, j], eta,
                                              N[idx], Ng[idx], wo[idx], wi[idx])
    return pdf


def _selection_probs(table, mat, colors, subset):
    w = _selection_weights(table, mat, colors, subset)
    tot = w.sum(axis=1, keepdims=True)
    return np.where(tot > 0, w / np.where(tot > 0, tot, 1.0), 0.0)


def pdf_bsdf(table: MaterialTable, mat, colors, n_s, n_g, wo, wi, subset="all"):
    """Solid-angle density (K,) with which :func:`sample_bsdf` (same subset) produces wi.

    Only non-delta lobes have a density; their selection probabilities are the
    luminance weights normalised within ``subset`` ('all' or 'nondelta').
    """
    mat = np.asarray(mat, np.int64)
    n_s, n_g, wo, wi = _prep(n_s, n_g, wo, wi)
    N, Ng, front = _orient(n_s, n_g, wo)
    return _pdf_nd(table, mat, _selection_probs(table, mat, colors, subset), N, Ng, front, wo, wi)


# --------------------------------------------------------------------------
# Sampling
# --------------------------------------------------------------------------
def ggx_sample_vndf(wl, alpha, u1, u2):
    """Heitz 2018 visible-normal sample (k, 3) in the local frame; wl (k, 3) with z > 0."""
    v = np.stack([alpha * wl[:, 0], alpha * wl[:, 1], wl[:, 2]], axis=1)
    v = _normalize(v)
    lensq = v[:, 0] ** 2 + v[:, 1] ** 2
    big = lensq > 1e-7
    inv = 1.0 / np.sqrt(np.where(big, lensq, 1.0))
    T1 = np.where(big[:, None], np.stack([-v[:, 1] * inv, v[:, 0] * inv, np.zeros_like(inv)], 1),
                  np.array([1.0, 0.0, 0.0]))
    T2 = np.cross(v, T1)
    tx, ty = _disk(u1, u2)
    s = 0.5 * (1.0 + v[:, 2])
    ty = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - tx * tx)) + s * ty
    tz = np.sqrt(np.maximum(0.0, 1.0 - tx * tx - ty * ty))
    Hh = tx[:, None] * T1 + ty[:, None] * T2 + tz[:, None] * v
    return _normalize(np.stack([alpha * Hh[:, 0], alpha * Hh[:, 1],
                                np.maximum(0.0, Hh[:, 2])], axis=1))


def _refract(wo, H, cos_t, eta):
    """Refracted direction of wo (pointing away) about H with h.wo > 0 (Cycles' refract_angle)."""
    inv = 1.0 / eta
    return ((inv * _dot(H, wo) - cos_t)[:, None] * H) - inv[:, None] * wo


def sample_bsdf(table: MaterialTable, mat, colors, n_s, n_g, wo, u, subset="all",
                mode="radiance"):
    """Sample wi for K points (all float64).

    mat (K,) int; colors (K, L, 3) from :func:`lobe_colors`; n_s, n_g (K, 3)
    unit shading / geometric normals in any orientation; wo (K, 3) unit.
    u: (K, 3) uniforms in [0, 1): u[:, 0:2] direction, u[:, 2] lobe choice
    (rescaled and reused for glass' reflect/refract choice).
    subset: 'all', 'delta' or 'nondelta' lobes; lobes are picked by luminance
    of weight x colour within the subset.
    Returns (wi (K, 3), weight (K, 3), pdf (K,), is_delta (K,), valid (K,)):
    - non-delta sample: weight = f·|cos(n_s, wi)|/pdf with f the sum of all
      non-delta lobes (:func:`eval_bsdf`) and pdf their combined density
      (:func:`pdf_bsdf` with the same subset), one-sample MIS over lobes;
    - delta sample: weight = lobe throughput / P(select lobe | subset), pdf =
      that discrete probability.  The caller that chose the subset with
      probability P (e.g. :func:`delta_probability`) divides by P itself.
    mode='importance' weights include the adjoint eta and shading-normal
    factors (module doc).  Invalid samples (below the geometric surface, total
    internal reflection of a Refraction BSDF, no lobe) have zero weight.
    """
    mat = np.asarray(mat, np.int64)
    n_s, n_g, wo, _ = _prep(n_s, n_g, wo, None)
    u = np.asarray(u, np.float64).reshape(-1, 3)
    if mode not in ("radiance", "importance"):
        raise ValueError(f"mode must be 'radiance' or 'importance', not {mode!r}")
    if subset not in ("all", "delta", "nondelta"):
        raise ValueError(f"subset must be 'all', 'delta' or 'nondelta', not {subset!r}")
    K = len(mat)
    # Fast path: materials made only of Lambert lobes (the common wall) need no
    # lobe choice, eval or pdf: cosine sampling has weight = sum of colours.
    fast = table.lambert_only[mat] & ~table.has_delta[mat]
    if subset == "delta" or not fast.any():
        return _sample_general(table, mat, colors, n_s, n_g, wo, u, subset, mode)
    wi = np.zeros((K, 3))
    weight = np.zeros((K, 3))
    pdf = np.zeros(K)
    ok = np.zeros(K, bool)
    is_delta = np.zeros(K, bool)
    fi = np.nonzero(fast)[0]
    N, Ng, _ = _orient(n_s[fi], n_g[fi], wo[fi])
    t, b = _frame(N)
    loc = _cos_hemisphere(u[fi, 0], u[fi, 1])
    w = loc[:, 0:1] * t + loc[:, 1:2] * b + loc[:, 2:3] * N
    wt = colors[fi].sum(axis=1)
    good = (_dot(Ng, w) > 0) & (loc[:, 2] > 0) & (wt @ LUMINANCE > 0)
    wi[fi] = w
    pdf[fi] = np.where(good, loc[:, 2] * INV_PI, 0.0)
    if mode == "importance":
        wt = wt * _adjoint_correction(n_s[fi], n_g[fi], wo[fi], w)[:, None]
    weight[fi] = np.where(good[:, None], wt, 0.0)
    ok[fi] = good
    si = np.nonzero(~fast)[0]
    if len(si):
        r = _sample_general(table, mat[si], colors[si], n_s[si], n_g[si], wo[si], u[si],
                            subset, mode)
        wi[si], weight[si], pdf[si], is_delta[si], ok[si] = r
    return wi, weight, pdf, is_delta, ok


def _adjoint_correction(n_s, n_g, wo, wi):
    """pbrt's CorrectShadingNormal |wo.ns||wi.ng| / (|wo.ng||wi.ns|) (K,)."""
    num = np.abs(_dot(wo, n_s)) * np.abs(_dot(wi, n_g))
    den = np.abs(_dot(wo, n_g)) * np.abs(_dot(wi, n_s))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


def _sample_general(table, mat, colors, n_s, n_g, wo, u, subset, mode):
    """sample_bsdf for any material (arrays already converted)."""
    K = len(mat)
    N, Ng, front = _orient(n_s, n_g, wo)
    kinds = table.kind[mat]
    delta_l = table.lobe_delta[mat]
    p = _selection_probs(table, mat, colors, subset)
    cdf = np.cumsum(p, axis=1)
    any_lobe = cdf[:, -1] > 0
    # Lobe choice: first slot with u < cdf (guard round-off at the top end).
    # Lobe choice: first slot with u < cdf.  Zero-probability slots are skipped
    # automatically; u >= cdf[-1] (round-off) falls back to the last usable slot.
    L = kinds.shape[1]
    rows = np.arange(K)
    last_pos = L - 1 - np.argmax(p[:, ::-1] > 0, axis=1)
    j_sel = np.minimum((u[:, 2:3] >= cdf).sum(axis=1), last_pos)
    p_sel = p[rows, j_sel]
    c_lo = np.where(j_sel > 0, cdf[rows, np.maximum(j_sel - 1, 0)], 0.0)
    u_re = np.clip((u[:, 2] - c_lo) / np.where(p_sel > 0, p_sel, 1.0), 0.0, 1.0 - 1e-16)

    t, b = _frame(N)
    wl = np.stack([_dot(wo, t), _dot(wo, b), _dot(wo, N)], axis=1)

    wi = np.zeros((K, 3))
    ok = np.zeros(K, bool)
    dweight = np.zeros((K, 3))      # delta throughput before selection
    is_delta = np.zeros(K, bool)
    k_sel = kinds[rows, j_sel]
    col_sel = colors[rows, j_sel]
    rough_sel = table.roughness[mat, j_sel]
    ior_sel = table.ior[mat, j_sel]
    eta_sel = np.where(front, ior_sel, 1.0 / ior_sel)
    dsel = delta_l[rows, j_sel]

    def to_world(idx, loc):
        return loc[:, 0:1] * t[idx] + loc[:, 1:2] * b[idx] + loc[:, 2:3] * N[idx]

    for k in np.unique(k_sel[any_lobe]):
        for is_d in (False, True):
            idx = np.nonzero(any_lobe & (k_sel == k) & (dsel == is_d))[0]
            if len(idx) == 0:
                continue
            k = int(k)
            if k in (DIFFUSE, TRANSLUCENT):
                loc = _cos_hemisphere(u[idx, 0], u[idx, 1])
                if k == TRANSLUCENT:
                    loc[:, 2] = -loc[:, 2]
                w = to_world(idx, loc)
                gs = _dot(Ng[idx], w)
                wi[idx] = w
                ok[idx] = gs > 0 if k == DIFFUSE else gs < 0
                continue
            if k == TRANSPARENT:
                wi[idx] = -wo[idx]
                ok[idx] = True
                dweight[idx] = col_sel[idx]
                is_delta[idx] = True
                continue
            # Microfacet family.
            cI = wl[idx, 2]
            if is_d:
                H = N[idx]
            else:
                alpha = rough_sel[idx] ** 2
                hl = ggx_sample_vndf(np.where(cI[:, None] > 0, wl[idx], [0.0, 0.0, 1.0]),
                                     alpha, u[idx, 0], u[idx, 1])
                H = to_world(idx, hl)
            hwo = _dot(H, wo[idx])
            eta = eta_sel[idx]
            if k == GLOSSY:
                refr = np.zeros(len(idx), bool)
                F = np.ones(len(idx))
            else:
                F, cos_t = fresnel_dielectric(hwo, eta)
                if k == GLASS:
                    refr = u_re[idx] >= F
                else:   # REFRACTION: always transmit, TIR absorbs
                    refr = np.ones(len(idx), bool)
            wr = 2.0 * hwo[:, None] * H - wo[idx]
            if k != GLOSSY:
                wt = _refract(wo[idx], H, cos_t, eta)
                w = np.where(refr[:, None], wt, wr)
            else:
                w = wr
            w = _normalize(w)
            cN = _dot(N[idx], w)
            cG = _dot(Ng[idx], w)
            good = (cI > 0) & np.where(refr, (cN < 0) & (cG < 0), (cN > 0) & (cG > 0))
            if k == REFRACTION:
                good &= F < 1.0
            wi[idx] = w
            ok[idx] = good
            if is_d:
                is_delta[idx] = True
                dw = col_sel[idx].copy()
                if k == GLOSSY and table.fresnel is not None:
                    # Principled layers at roughness 0: colour is tint / F0, the
                    # Fresnel at h = n scales the mix weight (E = 1: no multiscatter).
                    mj, jj = mat[idx], j_sel[idx]
                    fm = table.fresnel[mj, jj]
                    for mode_f in (FRESNEL_DIELECTRIC, FRESNEL_F82):
                        q = fm == mode_f
                        if q.any():
                            wq = table.weight[mj[q], jj[q]]
                            C = dw[q] / np.where(wq != 0, wq, 1.0)[:, None]
                            F, _ = _principled_fresnel(mode_f, C, table.fresnel_ior[mj[q], jj[q]],
                                                       table.f82_tint[mj[q], jj[q]], hwo[q])
                            dw[q] = wq[:, None] * F
                if mode == "importance":
                    # Adjoint of Cycles' unscaled BTDF: (n_wo / n_wi)^2 = 1/eta^2.
                    dw[refr] /= (eta[refr] ** 2)[:, None]
                dweight[idx] = dw

    weight = np.zeros((K, 3))
    pdf = np.zeros(K)
    # Delta samples.
    d = ok & is_delta
    weight[d] = dweight[d] / p_sel[d, None]
    pdf[d] = p_sel[d]
    # Non-delta samples: combined one-sample estimator over all non-delta lobes.
    nd = np.nonzero(ok & ~is_delta)[0]
    if len(nd):
        pdf_n = _pdf_nd(table, mat[nd], p[nd], N[nd], Ng[nd], front[nd], wo[nd], wi[nd])
        if mode == "radiance":
            f = _eval_nd(table, mat[nd], colors[nd], N[nd], front[nd], wo[nd], wi[nd])
        else:
            Nv, _, fv = _orient(n_s[nd], n_g[nd], wi[nd])
            f = _eval_nd(table, mat[nd], colors[nd], Nv, fv, wi[nd], wo[nd])
        good = pdf_n > 0
        cos = np.abs(_dot(n_s[nd], wi[nd]))
        weight[nd] = np.where(good[:, None], f * (cos / np.where(good, pdf_n, 1.0))[:, None], 0.0)
        pdf[nd] = pdf_n
        ok[nd] = good
    if mode == "importance":
        weight *= _adjoint_correction(n_s, n_g, wo, wi)[:, None]
    weight[~ok] = 0.0
    pdf[~ok] = 0.0
    return wi, weight, pdf, is_delta & ok, ok
