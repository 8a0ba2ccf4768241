"""Materials as arrays: the :class:`MaterialTable` and what is read from it per point.

Lobe colours (colour x mix weight x texture), emitted radiance, the
luminance weights that choose a lobe, the probability of choosing a delta
lobe and the Lambert albedo.  Lobe kinds and MAX_LOBES come from
:mod:`core.scene.model`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..mathutil import LUMINANCE
from ..scene.model import DIFFUSE, GLASS, GLOSSY, MAX_LOBES, REFRACTION, TRANSLUCENT, TRANSPARENT
from ..scene.textures import sample_alpha, sample_texture
from . import rough_maps
from .microfacet import (FRESNEL_CONDUCTOR, FRESNEL_DIELECTRIC, FRESNEL_F82, _fss_dielectric,
                         conductor_fss, f0_from_ior)
from .thin_film import THICKNESS_CUTOFF

# Cycles ``roughness_is_almost_specular``: alpha_x * alpha_y <= 2e-10.
SPECULAR_ALPHA2 = 2e-10
# Cycles ``diffuse_roughness_is_almost_zero``: roughness < 1e-5 -> Lambert.
DIFFUSE_ROUGHNESS_EPS = 1e-5
# Cycles treats refraction as specular when |eta - 1| < 1e-4.
IOR_ONE_EPS = 1e-4
# Multiscatter GGX for lobe objects without the attribute (``Lobe``'s own default).
DEFAULT_MULTISCATTER = False


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
      lambert_only = has_nondelta and every non-delta lobe is Lambert, and
      no Normal Map / Bump (their visible points evaluate the BSDF with the
      perturbed normal and Cycles' bump terms); lambert_lobes: the same
      without the last condition (what the photon tracer's Lambert bounce
      needs: photons scatter off the interpolated normal).
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
    conductor_n: np.ndarray = None      # (M, L, 3) IOR n of FRESNEL_CONDUCTOR (None: no such lobe)
    conductor_k: np.ndarray = None      # (M, L, 3) its extinction k
    thin_film: np.ndarray = None        # (M, L, 2) a film's thickness (nm) and IOR (None: no film)
    layer_ior: np.ndarray = None        # (M, L) DIFFUSE under a specular layer: its ior (0 = none)
    layer_f0: np.ndarray = None         # (M, L) that layer's max-channel F0
    layer_roughness: np.ndarray = None  # (M, L) that layer's roughness
    layer_ms: np.ndarray = None         # (M, L) bool, that layer is Multiscatter GGX
    sel_scale: np.ndarray = None        # (M, L) lobe-selection scale (Fresnel-weighted lobes)
    alpha_tex: np.ndarray = None        # (M, L) int32 texture whose alpha scales the lobe, -1 = none
    view_lut: np.ndarray = None         # (M, L) int32 row of view_tab scaling the lobe, -1 = none
    view_tab: list = None               # (VIEW_SAMPLES,) float64 rows: Lobe.view, see view_factor
    alpha_inv: np.ndarray = None        # (M, L) bool, scaled by 1 - alpha instead
    bump_correction: np.ndarray = None  # (M,) bool, Normal Map / Bump: Cycles' normal tilt
    bump_unshadowed: np.ndarray = None  # (M,) bool, a displacement's bump: no bump shadowing
    lambert_lobes: np.ndarray = None    # (M,) bool, lambert_only before the Normal Map / Bump test
    rough_first: np.ndarray = None      # (M,) int64 a roughness map's first level row, -1 = none
    rough_tex: np.ndarray = None        # (M,) int32 that map (core.materials.rough_maps)
    receiver: np.ndarray = None         # (rows,) int64 light-linking receiver set (core.scene.linking)

    @property
    def n_materials(self) -> int:
        return int(self.kind.shape[0])


def is_delta_lobe(kind: int, roughness: float, ior: float) -> bool:
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
      exporter merges them first, see ``core.scene.nodes.merge_lobes``).  The
      :class:`core.scene.Lobe` fields beyond the original six are read with
      getattr, so a lobe object without them is plain single-scattering GGX /
      Lambert: ``multiscatter`` (Cycles' Multiscatter GGX, the default
      distribution of the Glossy, Glass and Principled nodes; default
      DEFAULT_MULTISCATTER), and the Principled BSDF's layers
      (``core.scene.nodes`` sets them): GLOSSY ``fresnel='DIELECTRIC'`` +
      ``fresnel_ior``: the colour is the specular tint and f is scaled by
      Cycles' generalised-Schlick Fresnel mix(F0 tint, 1, (F(h.v) - F0)/(1 - F0));
      ``fresnel='F82'`` + ``f82_tint``: the colour is F0 of Cycles' F82-tint
      conductor; ``fresnel='CONDUCTOR'`` + ``conductor_n``, ``conductor_k``:
      the colour is the mix weight and f is scaled by the exact Fresnel of a
      conductor of IOR n + ik (the Metallic BSDF's Physical Conductor);
      ``thin_film_thickness`` > THICKNESS_CUTOFF and ``thin_film_ior`` on
      such a lobe or a layered DIFFUSE: its Fresnel (its layer's) is a thin
      film's over it (core.materials.thin_film); DIFFUSE ``layer_ior``,
      ``layer_f0``, ``layer_roughness``, ``layer_multiscatter``: the diffuse
      lies under a dielectric specular layer and is scaled by 1 - its albedo
      estimate (``closure_layering_weight``), which depends on the view
      direction.
    textures: list of (H, W, C) float32 images.
    A material with a roughness map (``Lobe.roughness_texture``) has
    ROUGH_LEVELS level rows (``rough_maps.append_levels``; ``rough_first``,
    ``rough_tex``): rows beyond len(materials) are those levels.
    """
    materials, maps = rough_maps.mapped_lobes(materials)
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
    cn = np.ones((M, L, 3))
    film = np.zeros((M, L, 2))
    ck = np.zeros((M, L, 3))
    lior = np.zeros((M, L))
    lf0 = np.zeros((M, L))
    lrough = np.zeros((M, L))
    lms = np.zeros((M, L), bool)
    sel = np.ones((M, L))
    atex = np.full((M, L), -1, np.int32)
    ainv = np.zeros((M, L), bool)
    vlut = np.full((M, L), -1, np.int32)
    vtab: list = []
    textures = list(textures)
    white = None
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
            atex[m, j] = int(getattr(lobe, "alpha_texture", -1))
            ainv[m, j] = bool(getattr(lobe, "alpha_invert", False))
            if getattr(lobe, "view", ()):
                vlut[m, j] = len(vtab)
                vtab.append(np.asarray(lobe.view, np.float64))
            if atex[m, j] >= 0 and tex[m, j] < 0:
                # A white 1x1 colour texture: the photon tracer computes uvs
                # (and leaves its fast paths) only for lobes with a texture.
                if white is None:
                    white = len(textures)
                    textures.append(np.ones((1, 1, 3), np.float32))
                tex[m, j] = white
            delta[m, j] = is_delta_lobe(kind[m, j], rough[m, j], ior[m, j])
            # Optional Lobe attribute (the exporter sets it from the node's
            # distribution); plain GGX when absent.
            ms[m, j] = (bool(getattr(lobe, "multiscatter", DEFAULT_MULTISCATTER))
                        and kind[m, j] in (GLOSSY, GLASS) and not delta[m, j])
            fr = str(getattr(lobe, "fresnel", "") or "").upper()
            if kind[m, j] == GLOSSY and fr in ("DIELECTRIC", "F82", "CONDUCTOR"):
                fres[m, j] = {"DIELECTRIC": FRESNEL_DIELECTRIC, "F82": FRESNEL_F82,
                              "CONDUCTOR": FRESNEL_CONDUCTOR}[fr]
                fior[m, j] = max(float(getattr(lobe, "fresnel_ior", 1.5)), 1e-5)
                f82t[m, j] = np.clip(np.asarray(getattr(lobe, "f82_tint", (1.0, 1.0, 1.0)),
                                                np.float64)[:3], 0.0, 1.0)
                if fr == "DIELECTRIC":
                    # Selection by the hemispherical Fresnel average (sampling only).
                    sel[m, j] = _fss_dielectric(fior[m, j])
                if fr == "CONDUCTOR":
                    # Cycles: max(n, 0), max(k, 0); selection by the mean F_ss.
                    cn[m, j] = np.maximum(np.asarray(lobe.conductor_n, np.float64)[:3], 0.0)
                    ck[m, j] = np.maximum(np.asarray(lobe.conductor_k, np.float64)[:3], 0.0)
                    sel[m, j] = float(np.mean(conductor_fss(cn[m, j], ck[m, j])))
            if (fres[m, j] or float(getattr(lobe, "layer_ior", 0.0)) > 0.0) \
                    and float(getattr(lobe, "thin_film_thickness", 0.0)) > THICKNESS_CUTOFF:
                # Cycles: the film's IOR fmaxf(ior, 1e-5).
                film[m, j] = (float(lobe.thin_film_thickness),
                              max(float(getattr(lobe, "thin_film_ior", 1.33)), 1e-5))
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
    bump = np.array([getattr(mat, "normal", None) is not None for mat in materials] or [False],
                    bool)
    # (NormalInput.shadowing False: a displacement's bump alone)
    unshadowed = np.array([not getattr(getattr(mat, "normal", None), "shadowing", True)
                           for mat in materials] or [False], bool)
    lambert_lobes = has_nd & ~(nondelta & ~lambert).any(axis=1)
    return rough_maps.append_levels(MaterialTable(
        kind=kind, color=color, weight=weight, roughness=rough, ior=ior, tex=tex,
        emission=emis, emission_tex=emis_tex, lobe_delta=delta,
        has_delta=(used & delta).any(axis=1), has_nondelta=has_nd,
        lambert_only=lambert_lobes & ~bump, lambert_lobes=lambert_lobes,
        textures=textures, multiscatter=ms, fresnel=fres, fresnel_ior=fior,
        f82_tint=f82t, conductor_n=cn if (fres == FRESNEL_CONDUCTOR).any() else None,
        conductor_k=ck if (fres == FRESNEL_CONDUCTOR).any() else None,
        thin_film=film if (film[..., 0] > 0.0).any() else None, layer_ior=lior, layer_f0=lf0,
        layer_roughness=lrough, layer_ms=lms,
        sel_scale=sel, alpha_tex=atex, alpha_inv=ainv, bump_correction=bump,
        bump_unshadowed=unshadowed,
        view_lut=vlut if vtab else None, view_tab=vtab if vtab else None), maps)


# --------------------------------------------------------------------------
# Per-point values
# --------------------------------------------------------------------------
def view_dependent(table) -> np.ndarray:
    """(M,) bool: the materials with a lobe whose weight depends on the view
    (``Lobe.view``): like textured ones, their colours are a hit's own."""
    vl = getattr(table, "view_lut", None)
    return np.zeros(table.kind.shape[0], bool) if vl is None else np.any(vl >= 0, axis=1)


def view_mu(table, w: np.ndarray, ns: np.ndarray):
    """(K,) |w . ns| of directions w and shading normals ns (K, 3): the mu
    :func:`lobe_colors` reads, or None for a table without view factors
    (no work for the others)."""
    if getattr(table, "view_lut", None) is None:
        return None
    return np.abs(np.einsum("ij,ij->i", w, ns))


def view_factor(tab: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Linear interpolation of view-factor rows tab (K, VIEW_SAMPLES) at mu
    (K,) = |w_o . n_s|, clamped to [0, 1] (:func:`lobe_colors`)."""
    S = tab.shape[1]
    x = np.clip(np.asarray(mu, np.float64), 0.0, 1.0) * (S - 1)
    i = np.minimum(x.astype(np.int64), S - 2)
    f = x - i
    k = np.arange(tab.shape[0])
    return tab[k, i] * (1.0 - f) + tab[k, i + 1] * f


def seen_weight(table, mat: np.ndarray, j, mu: np.ndarray) -> np.ndarray:
    """(K,) float64: the mix weight of slot j (an int or (K,)) of materials
    mat (K,) times its view factor at mu (K,) = |w_o . n_s|: what a lobe
    colour of :func:`lobe_colors` divides by to give the closure's own
    colour (Oren-Nayar's and Multiscatter GGX's albedo, a Principled
    layer's tint, which Cycles reads without the mix's factor)."""
    w = np.asarray(table.weight[mat, j], np.float64)
    vl = getattr(table, "view_lut", None)
    if vl is None:
        return w
    r = vl[mat, j]
    k = np.nonzero(r >= 0)[0]
    if k.size == 0:
        return w
    w = w.copy()
    w[k] *= view_factor(np.asarray(table.view_tab)[r[k]], np.asarray(mu, np.float64)[k])
    return w


def lobe_colors(table: MaterialTable, mat: np.ndarray, uv: np.ndarray,
                mu: np.ndarray = None) -> np.ndarray:
    """Per-lobe colour x weight x texture (x alpha or 1 - alpha of an image,
    ``alpha_tex``: a stochastic pass-through like Cycles', since lobes are
    chosen by these colours' luminance) x the view factor at mu (K,) =
    |w_o . n_s| (``view_lut``; mu None: at normal incidence).  mat (K,) int,
    uv (K, 2) -> (K, L, 3) float64."""
    mat = np.asarray(mat, np.int64)
    cols = table.color[mat] * table.weight[mat][:, :, None]
    cols[table.kind[mat] < 0] = 0.0
    vl = getattr(table, "view_lut", None)
    if vl is not None and (vl[mat] >= 0).any():
        tab = np.asarray(table.view_tab)
        mu = np.ones(mat.size) if mu is None else np.asarray(mu, np.float64)
        for j in range(vl.shape[1]):
            k = np.nonzero(vl[mat, j] >= 0)[0]
            if k.size:
                cols[k, j] *= view_factor(tab[vl[mat[k], j]], mu[k])[:, None]
    tex = table.tex[mat]
    if (tex >= 0).any():
        uv = np.asarray(uv, np.float64)
        for j in range(tex.shape[1]):
            for t in np.unique(tex[:, j]):
                if t < 0:
                    continue
                idx = np.nonzero(tex[:, j] == t)[0]
                cols[idx, j] *= sample_texture(table.textures[t], uv[idx])
    atex = table.alpha_tex[mat] if table.alpha_tex is not None else None
    if atex is not None and (atex >= 0).any():
        uv = np.asarray(uv, np.float64)
        inv = table.alpha_inv[mat]
        for j in range(atex.shape[1]):
            for t in np.unique(atex[:, j]):
                if t < 0:
                    continue
                idx = np.nonzero(atex[:, j] == t)[0]
                a = np.clip(sample_alpha(table.textures[t], uv[idx]), 0.0, 1.0)
                cols[idx, j] *= np.where(inv[idx, j], 1.0 - a, a)[:, None]
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


def _selection_probs(table, mat, colors, subset):
    w = _selection_weights(table, mat, colors, subset)
    tot = w.sum(axis=1, keepdims=True)
    return np.where(tot > 0, w / np.where(tot > 0, tot, 1.0), 0.0)


def fresnel_params(table: MaterialTable, mat: np.ndarray, j) -> tuple:
    """The Fresnel of lobes (mat, j) (k,) as ``microfacet._principled_fresnel``
    reads it: (mode (k,) FRESNEL_*, fresnel_ior (k,), tint (k, 3): the
    F82 tint or a conductor's IOR n, k (k, 3): a conductor's extinction,
    film (k, 2): a thin film's thickness and IOR, zero thickness none)."""
    mode = table.fresnel[mat, j]
    tint = table.f82_tint[mat, j]
    ext = np.zeros(tint.shape)
    if table.conductor_n is not None:
        c = (mode == FRESNEL_CONDUCTOR)[:, None]
        tint = np.where(c, table.conductor_n[mat, j], tint)
        ext = np.where(c, table.conductor_k[mat, j], 0.0)
    film = (np.zeros(mode.shape + (2,)) if getattr(table, "thin_film", None) is None
            else table.thin_film[mat, j])
    return mode, table.fresnel_ior[mat, j], tint, ext, film


def delta_probability(table: MaterialTable, mat: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """Probability (K,) that luminance-proportional lobe selection picks a delta lobe."""
    w = _selection_weights(table, mat, colors, "all")
    tot = w.sum(axis=1)
    wd = np.where(table.lobe_delta[np.asarray(mat, np.int64)], w, 0.0).sum(axis=1)
    return np.where(tot > 0, wd / np.where(tot > 0, tot, 1.0), 0.0)


def used_lobes(table: MaterialTable) -> np.ndarray:
    """(M, L) bool: the lobes that scatter light (weight and colour nonzero)."""
    return (table.kind >= 0) & (table.weight != 0.0) & (table.color.max(axis=2) > 0.0)


def glossy_only(table: MaterialTable) -> np.ndarray:
    """(M,) bool: materials with non-delta lobes of nonzero weight and
    colour, none of them diffuse (DIFFUSE or TRANSLUCENT): a metal, a Glossy
    BSDF, rough glass (not an emitter's black diffuse lobe).  pbrt-v4's SPPM makes its visible points only
    where the BSDF has a diffuse part and follows the camera path through
    the others (core.sppm.visible_points, "glossy chains")."""
    used = used_lobes(table) & ~table.lobe_delta
    diffuse = used & ((table.kind == DIFFUSE) | (table.kind == TRANSLUCENT))
    return used.any(axis=1) & ~diffuse.any(axis=1)


def lambert_albedo(table: MaterialTable, mat: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """Sum (K, 3) of the Lambert (DIFFUSE, roughness 0, not layered) lobe colours."""
    mat = np.asarray(mat, np.int64)
    is_l = (table.kind[mat] == DIFFUSE) & (table.roughness[mat] < DIFFUSE_ROUGHNESS_EPS)
    if table.layer_ior is not None:
        is_l &= table.layer_ior[mat] <= 0.0
    return (colors * is_l[:, :, None]).sum(axis=1)
