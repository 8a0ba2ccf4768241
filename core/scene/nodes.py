"""Blender shader nodes -> FPPM lobes: the Principled BSDF and Mix/Add Shader flattening.

Pure Python (no bpy): the exporter reads node inputs and calls these.  Every
function returns human-readable approximation notes next to its result, and
the notes say what differs from Cycles.

Principled BSDF (Cycles 5.x, ``kernel/svm/closure.h``) builds, top to bottom:
alpha -> Transparent (1 - alpha); sheen; coat; metallic -> GGX with F82-tint
Fresnel (F0 = base colour); transmission -> GGX glass whose transmission is
tinted by sqrt(base colour); dielectric specular -> GGX with the real Fresnel
curve remapped to F0 = ((ior-1)/(ior+1))^2 * 2 * specular_ior_level; diffuse
(Lambert or Oren-Nayar with "Diffuse Roughness") with weight base colour times
what the specular layer leaves, ``closure_layering_weight``.  Each layer's
weight is (1 - metallic), (1 - transmission) of the one above.  Metallic,
specular and the diffuse-under-specular attenuation are reproduced exactly
(``Lobe`` fields read by ``core.materials``, checked against Cycles renders
in tests/test_bsdf.py); sheen, subsurface, coat layering, thin film, anisotropy
are approximated and reported.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..materials.microfacet import f0_from_ior
from ..mathutil import LUM_B, LUM_G, LUM_R
from .model import (DIFFUSE, GLASS, GLOSSY, LOBE_NAMES, MAX_LOBES, TRANSPARENT,
                    VIEW_SAMPLES, Lobe)

_LUMA = (LUM_R, LUM_G, LUM_B)
# Cycles' CLOSURE_WEIGHT_CUTOFF: closures lighter than this are not created.
WEIGHT_CUTOFF = 1e-5


# The Lobe fields beyond the original six (Multiscatter GGX and the Principled
# layers), name -> default.
_BASE = ("kind", "color", "weight", "roughness", "ior", "color_texture")
_EXTRA = {f.name: f.default for f in dataclasses.fields(Lobe) if f.name not in _BASE}


def make_lobe(kind, color=(0.8, 0.8, 0.8), weight=1.0, roughness=0.0, ior=1.45,
              color_texture=-1, **extra) -> Lobe:
    """A :class:`Lobe` with float colour, weight, roughness and ior.

    extra: the further Lobe fields, multiscatter (GLOSSY/GLASS with the
    'MULTI_GGX' distribution, the default of the Glossy, Glass and Principled
    nodes; ignored on other kinds), fresnel, fresnel_ior, f82_tint, layer_ior,
    layer_f0, layer_roughness, layer_multiscatter.  Values equal to the
    field's default are left to the default (the Lobe's repr, hence
    ``scene_digest``, does not depend on how a default was spelled)."""
    unknown = set(extra) - set(_EXTRA)
    if unknown:
        raise TypeError(f"unknown lobe attributes {sorted(unknown)}")
    kw = dict(kind=kind, color=tuple(float(c) for c in color), weight=float(weight),
              roughness=float(roughness), ior=float(ior), color_texture=int(color_texture))
    if extra.get("multiscatter") and kind not in (GLOSSY, GLASS):
        extra["multiscatter"] = False
    extra = {k: v for k, v in extra.items() if v != _EXTRA[k]}
    return Lobe(**kw, **extra)


def _extras(lobe) -> tuple:
    return tuple(getattr(lobe, k, d) for k, d in _EXTRA.items())


def ior_from_f0(f0: float) -> float:
    """Inverse of :func:`f0_from_ior` (Cycles clamps f0 to [0, 0.99])."""
    s = math.sqrt(min(max(f0, 0.0), 0.99))
    return (1.0 + s) / (1.0 - s)


def _rgb(c):
    a = np.asarray(c, np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    return np.maximum(a[:3], 0.0)


def _tup(a):
    return tuple(float(x) for x in a)


def thin_film(thickness, ior) -> dict:
    """The Lobe fields of a Thin Film Thickness (nm) and IOR: none below
    Cycles' THINFILM_THICKNESS_CUTOFF (0.1 nm), the IOR at least 1e-5."""
    if thickness <= 0.1:
        return {}
    return dict(thin_film_thickness=float(thickness), thin_film_ior=max(float(ior), 1e-5))


def principled_to_lobes(base_color=(0.8, 0.8, 0.8), metallic=0.0, roughness=0.5, ior=1.5,
                        transmission=0.0, alpha=1.0, coat_weight=0.0, coat_roughness=0.03,
                        coat_ior=1.5, coat_tint=(1.0, 1.0, 1.0), sheen_weight=0.0,
                        subsurface_weight=0.0, specular_ior_level=0.5,
                        specular_tint=(1.0, 1.0, 1.0), anisotropic=0.0, diffuse_roughness=0.0,
                        thin_film_thickness=0.0, thin_film_ior=1.33,
                        emission_color=(1.0, 1.0, 1.0),
                        emission_strength=0.0, base_color_texture=-1,
                        emission_color_texture=-1, multiscatter=True, alpha_texture=-1,
                        metallic_texture=-1, roughness_texture=-1):
    """Map Principled BSDF inputs onto FPPM lobes.

    Colours are linear RGB triples; ``*_texture`` are indices into
    ``Scene.textures`` (-1 = none) for a base colour / emission colour that
    comes straight from an Image Texture (base: lobes get ``color_texture``;
    emission: the returned emission leaves the colour out, and the caller sets
    ``Material.emission_texture``).  multiscatter: the node's
    distribution is 'MULTI_GGX' (default) rather than 'GGX'.
    alpha_texture >= 0: the Alpha input is that image's alpha a(uv): the
    lobes are built for alpha = 1, then scaled by a, under a Transparent
    lobe scaled by 1 - a (:func:`alpha_scaled`).
    metallic_texture >= 0: Metallic is that image's alpha m(uv) per hit
    (``metallic`` is not read).  Cycles' Principled BSDF is linear in
    Metallic: the metal closure has weight m, every dielectric one below it
    (transmission, specular, diffuse) 1 - m, and the coat above is not
    touched.  So the metal is built for m = 1 and the rest for m = 0, then
    scaled by m and 1 - m through ``Lobe.alpha_texture``.  A lobe follows
    one image: with a textured Alpha as well, the exporter passes the
    Metallic image's mean instead (noted).
    roughness_texture >= 0: Roughness is that image's alpha per hit on the
    camera side (``Lobe.roughness_texture`` on the metal, transmission and
    specular lobes and on the diffuse's specular layer; ``roughness`` is the
    map's mean, what light paths read: core.materials.rough_maps).
    Returns (lobes: tuple[Lobe], emission: (3,) float64 radiance,
    approximations: tuple[str]).
    """
    notes = []
    base = _rgb(base_color)
    cbase = np.minimum(base, 1.0)               # Cycles' clamped_base_color
    metallic = min(max(float(metallic), 0.0), 1.0)
    transmission = min(max(float(transmission), 0.0), 1.0)
    alpha = min(max(float(alpha), 0.0), 1.0)
    roughness = min(max(float(roughness), 0.0), 1.0)
    ior = max(float(ior), 1e-5)
    spec_tint = _rgb(specular_tint)
    tex = int(base_color_texture)
    lobes = []
    w = 1.0   # scalar weight left for the layers below (Cycles' `weight`)
    w_rgb = np.ones(3)   # colour part of that weight (coat tint)

    # --- Alpha: Transparent before anything else.
    if alpha < 1.0:
        lobes.append(Lobe(TRANSPARENT, (1.0, 1.0, 1.0), weight=1.0 - alpha))
        w *= alpha

    # --- Sheen: not representable.
    if sheen_weight > WEIGHT_CUTOFF:
        notes.append(f"sheen (weight {sheen_weight:g}) ignored: no sheen lobe")

    # --- Coat: GGX with exact dielectric Fresnel, always energy preserving.
    coat_lobe = None
    if coat_weight > WEIGHT_CUTOFF:
        cw = max(float(coat_weight), 0.0)
        c_ior = max(float(coat_ior), 1.0)
        cf0 = f0_from_ior(c_ior)
        coat_lobe = make_lobe(GLOSSY, (1.0, 1.0, 1.0), weight=w * cw,
                              roughness=min(max(float(coat_roughness), 0.0), 1.0),
                              multiscatter=True, fresnel="DIELECTRIC", fresnel_ior=c_ior)
        # closure_layering_weight with the coat albedo taken at normal incidence.
        w *= max(0.0, 1.0 - cw * cf0)
        ctint = _rgb(coat_tint)
        if not np.allclose(ctint, 1.0):
            # Beer's law along the refracted view ray; taken at normal incidence.
            w_rgb *= (1.0 - min(cw, 1.0)) + min(cw, 1.0) * ctint
            notes.append("coat tint applied at normal incidence (Cycles: tint^(1/cos) "
                         "of the refracted view angle)")
        notes.append("coat: layers below are attenuated by the coat's normal-incidence "
                     "albedo coat*F0 (Cycles: its view-dependent albedo)")

    # --- Metallic: GGX with Cycles' F82-tint conductor Fresnel, F0 = base colour.
    # --- Thin film (Cycles: over the metal and the specular layer, whose
    # Fresnel becomes the film's).
    film = thin_film(thin_film_thickness, thin_film_ior)
    metal = None
    rtex = int(roughness_texture)
    metal_tex = int(metallic_texture)
    if metal_tex >= 0:
        metallic = 1.0
    if metallic > WEIGHT_CUTOFF:
        metal = make_lobe(GLOSSY, _tup(cbase * w_rgb), weight=metallic * w, roughness=roughness,
                          color_texture=tex, multiscatter=multiscatter, fresnel="F82",
                          f82_tint=_tup(np.minimum(spec_tint, 1.0)), roughness_texture=rtex,
                          **film)
        if not np.allclose(w_rgb, 1.0):
            notes.append("metallic under a tinted coat: the tint scales F0")
        if metal_tex < 0:
            w *= 1.0 - metallic
    n_above = len(lobes)    # the Transparent of a constant Alpha: above the metal

    # --- Transmission: GGX glass.
    if transmission > WEIGHT_CUTOFF:
        if tex >= 0:
            gcol = w_rgb
            notes.append("transmission with a textured base colour: the texture tints each "
                         "interface fully (Cycles: sqrt of the base colour per interface)")
        else:
            gcol = np.sqrt(cbase) * w_rgb
        if not np.allclose(cbase, 1.0):
            notes.append("glass reflection is tinted by sqrt(base colour) like its "
                         "transmission (Cycles: reflection untinted)")
        if not np.allclose(spec_tint, 1.0):
            notes.append("specular tint not applied to the transmission lobe's reflection")
        if film:
            notes.append("thin-film iridescence on the transmission ignored")
        lobes.append(make_lobe(GLASS, _tup(gcol), weight=transmission * w, roughness=roughness,
                               ior=ior, color_texture=tex, multiscatter=multiscatter,
                               roughness_texture=rtex))
        w *= 1.0 - transmission
    i_metal = len(lobes)    # the metal's slot: after the transmission, before the specular

    # --- Dielectric specular layer: generalised Schlick with the real Fresnel
    # curve, F0 = F0(ior) * 2 * specular_ior_level, tinted by specular_tint.
    level = max(float(specular_ior_level), 0.0)
    f0 = f0_from_ior(ior)
    eta = ior
    if level != 0.5:
        f0 *= 2.0 * level
        eta = ior_from_f0(f0)
        if ior < 1.0:
            eta = 1.0 / eta
    spec = None
    layer = {}
    if (eta != 1.0 or film) and w > WEIGHT_CUTOFF:
        spec = make_lobe(GLOSSY, _tup(np.minimum(spec_tint, 1e6) * w_rgb), weight=w,
                         roughness=roughness, multiscatter=multiscatter, fresnel="DIELECTRIC",
                         fresnel_ior=eta, roughness_texture=rtex, **film)
        # The diffuse below gets 1 - max_c mix(F0 tint_c, 1, s(view)) (view
        # dependent; with a film, the film's Fresnel at the view).
        layer = dict(layer_ior=eta, layer_roughness=roughness,
                     layer_f0=float(min(f0_from_ior(eta) * float(np.max(spec_tint)), 1.0)),
                     layer_multiscatter=bool(multiscatter), roughness_texture=rtex, **film)
    if spec is not None:
        lobes.append(spec)

    # --- Diffuse (+ subsurface approximated as diffuse).
    if subsurface_weight > WEIGHT_CUTOFF:
        notes.append(f"subsurface (weight {subsurface_weight:g}) rendered as diffuse "
                     "with the base colour")
    if w > WEIGHT_CUTOFF:
        dcol = (base if tex < 0 else np.ones(3)) * w_rgb
        lobes.append(make_lobe(DIFFUSE, _tup(dcol), weight=w,
                               roughness=min(max(float(diffuse_roughness), 0.0), 1.0),
                               color_texture=tex, **layer))

    if metal_tex >= 0 and metal is not None:    # the dielectric lobes 1 - m, the metal m
        lobes[n_above:], _ = alpha_scaled(lobes[n_above:], metal_tex, invert=True)
        (metal,), _ = alpha_scaled([metal], metal_tex)
    if metal is not None:
        lobes.insert(i_metal, metal)
    if coat_lobe is not None:
        lobes.insert(0, coat_lobe)
    if anisotropic > WEIGHT_CUTOFF:
        notes.append(f"anisotropy {anisotropic:g} ignored (isotropic GGX)")

    if int(alpha_texture) >= 0:
        clear, _ = alpha_scaled([Lobe(TRANSPARENT, (1.0, 1.0, 1.0))], alpha_texture, invert=True)
        opaque, more = alpha_scaled(lobes, alpha_texture)
        lobes = list(clear) + list(opaque)
        notes.extend(more)
        if emission_strength > 0:
            notes.append("emission not attenuated by the textured alpha")
    lobes, more = merge_lobes(lobes)
    notes.extend(more)
    # Emission is attenuated by alpha and the coat/sheen layers (Cycles).
    # A textured emission colour is left out (white) here: the exporter puts the
    # texture index in Material.emission_texture, which multiplies this.
    ecol = np.ones(3) if int(emission_color_texture) >= 0 else _rgb(emission_color)
    emission = ecol * float(emission_strength) * alpha
    if coat_lobe is not None:
        emission = emission * max(0.0, 1.0 - max(float(coat_weight), 0.0)
                                  * f0_from_ior(max(float(coat_ior), 1.0)))
        emission = emission * w_rgb
    return tuple(lobes), emission, tuple(notes)


def alpha_scaled(lobes, texture: int, invert: bool = False):
    """Lobes scaled by an image's alpha a(uv) (by 1 - a when invert), through
    ``Lobe.alpha_texture``.  A lobe can follow one alpha only: lobes already
    scaled by another keep theirs (noted).  Returns (list[Lobe], list[str])."""
    out, notes = [], []
    for lb in lobes:
        if getattr(lb, "alpha_texture", -1) >= 0:
            notes.append("nested texture-driven mixes: the inner alpha kept, the outer ignored")
            out.append(lb)
            continue
        out.append(dataclasses.replace(lb, alpha_texture=int(texture), alpha_invert=bool(invert)))
    return out, notes


def mix_by_alpha(mat_a_lobes, mat_b_lobes, texture: int):
    """Mix Shader whose Fac is an image's alpha a(uv): (1 - a) A + a B.
    Returns (tuple[Lobe], tuple[str] notes)."""
    a, na = alpha_scaled(mat_a_lobes, texture, invert=True)
    b, nb = alpha_scaled(mat_b_lobes, texture)
    lobes, notes = merge_lobes(a + b)
    return lobes, tuple(na + nb) + tuple(notes)


def _lum(c):
    return sum(a * b for a, b in zip(c, _LUMA))


def _linear_in_color(lobe: Lobe) -> bool:
    # Oren-Nayar's and Multiscatter GGX's multiple-bounce terms and the
    # Principled Fresnel modes depend non-linearly on the colour (not the weight).
    return not ((lobe.kind == DIFFUSE and lobe.roughness >= 1e-5)
                or getattr(lobe, "multiscatter", False) or getattr(lobe, "fresnel", ""))


def merge_lobes(lobes, max_lobes: int = MAX_LOBES):
    """Merge lobes that differ only in colour/weight; keep at most ``max_lobes``.

    Lobes whose f is linear in colour (all but Oren-Nayar and Multiscatter
    GGX) with equal kind, roughness, ior and texture become one lobe of colour
    sum(w_i c_i) and weight 1 (exact).  The others merge only when their
    colours are equal (weights add).
    Zero-weight lobes are removed.  When more than ``max_lobes`` remain, the
    dimmest (weight x luminance) are dropped and noted.
    Returns (tuple[Lobe], tuple[str] notes).
    """
    out = []
    for lb in lobes:
        if abs(lb.weight) <= 0.0 or max(lb.color) <= 0.0:
            continue
        for i, ob in enumerate(out):
            same = (ob.kind == lb.kind and ob.roughness == lb.roughness and ob.ior == lb.ior
                    and ob.color_texture == lb.color_texture and _extras(ob) == _extras(lb))
            if not same:
                continue
            if tuple(ob.color) == tuple(lb.color):
                out[i] = dataclasses.replace(ob, weight=ob.weight + lb.weight)
                break
            if _linear_in_color(lb):
                col = tuple(ob.weight * a + lb.weight * b for a, b in zip(ob.color, lb.color))
                out[i] = dataclasses.replace(ob, color=col, weight=1.0)
                break
        else:
            out.append(lb)
    notes = []
    if len(out) > max_lobes:
        order = sorted(range(len(out)), key=lambda i: -abs(out[i].weight) * _lum(out[i].color))
        keep = sorted(order[:max_lobes])
        for i in order[max_lobes:]:
            lb = out[i]
            notes.append(f"dropped {LOBE_NAMES.get(lb.kind, lb.kind)} lobe (weight {lb.weight:.3g}, "
                         f"colour {tuple(round(c, 3) for c in lb.color)}): more than "
                         f"{max_lobes} lobes")
        out = [out[i] for i in keep]
    return tuple(out), tuple(notes)


def _scaled(lobes, s):
    return [dataclasses.replace(lb, weight=lb.weight * s) for lb in lobes]


def mix_materials(mat_a_lobes, mat_b_lobes, fac: float):
    """Mix Shader: (1 - fac) A + fac B, fac clamped to [0, 1] like Cycles.

    Returns (tuple[Lobe], tuple[str] notes)."""
    fac = min(max(float(fac), 0.0), 1.0)
    return merge_lobes(_scaled(mat_a_lobes, 1.0 - fac) + _scaled(mat_b_lobes, fac))


def view_values(lobe) -> np.ndarray:
    """(VIEW_SAMPLES,) float64: a lobe's view factor (ones when it has none)."""
    v = getattr(lobe, "view", ())
    return np.asarray(v, np.float64) if v else np.ones(VIEW_SAMPLES)


def mix_by_view(mat_a_lobes, mat_b_lobes, fac):
    """Mix Shader whose Fac is a function of the view, fac (VIEW_SAMPLES,)
    its values at mu = |w_o . n_s| = i / (VIEW_SAMPLES - 1) (clamped to
    [0, 1] like Cycles'): (1 - fac) A + fac B, each lobe's ``view`` the
    product of the factors of the mixes it sits under.  Returns
    (tuple[Lobe], tuple[str] notes)."""
    f = np.clip(np.asarray(fac, np.float64), 0.0, 1.0)

    def scaled(lobes, w):
        return [dataclasses.replace(lb, view=tuple(float(x) for x in view_values(lb) * w))
                for lb in lobes]
    return merge_lobes(scaled(mat_a_lobes, 1.0 - f) + scaled(mat_b_lobes, f))


def add_materials(mat_a_lobes, mat_b_lobes):
    """Add Shader: A + B (weights may exceed 1).  Returns (tuple[Lobe], tuple[str])."""
    return merge_lobes(list(mat_a_lobes) + list(mat_b_lobes))
