"""Materials: Cycles' surface closures as masked structure-of-arrays numpy code (float64).

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
  with ``multiscatter=True`` scales f by 1 + F_ms (1 - E)/E as Cycles'
  ``microfacet_ggx_preserve_energy`` (see :func:`multiscatter_factor`).
- Principled BSDF layers (Lobe fields, :func:`build_material_table`):
  GLOSSY with the generalised-Schlick dielectric or F82-tint conductor
  Fresnel, and DIFFUSE attenuated by the view-dependent albedo of the
  specular layer above it.  Checked against Cycles renders to < 1e-3.

Deliberate differences from Cycles (all tiny or sampling-only): lobe choice is
by luminance of weight x colour (Cycles: closure sample weights); rough
refraction pairs with h.v and h.l of equal sign are zero in eval (Cycles'
eval leaves them, its sampler never makes them); Cycles' bump-map normal
correction ``ensure_valid_specular_reflection`` is applied only to materials
with a Normal Map / Bump input (``MaterialTable.bump_correction``; Cycles
also tilts plain smooth normals) and only where the view direction is known
(radiance mode), and there the diffuse lobes get Cycles'
``bump_shadowing_term`` with the geometric normal standing for the smooth
one, except under a displacement's bump alone, whose normal Cycles makes
the surface's own (``MaterialTable.bump_unshadowed``; docs/shading.md).

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

Modules
-------
- :mod:`.table`: :class:`MaterialTable` and the per-point values read from it
  (lobe colours, emission, lobe-selection weights, delta probability, Lambert
  albedo).
- :mod:`.microfacet`: GGX D / Lambda / visible-normal sampling, Fresnel
  (dielectric, Principled Schlick and F82), Oren-Nayar.
- :mod:`.multiscatter`: the albedo tables of Multiscatter GGX and of the
  Principled specular layer.
- :mod:`.closures`: per-lobe f / pdf and the material BSDF every stage calls
  (:func:`eval_bsdf`, :func:`pdf_bsdf`, :func:`sample_bsdf`,
  :func:`shading_correction`).
- :mod:`.compiled`: the numba twin of :func:`eval_bsdf` (radiance mode) per
  (point, direction) pair, for the gather's and the direct light's
  non-Lambert receivers; equal to the numpy evaluation to 1 ulp.
"""
from __future__ import annotations

from .closures import eval_bsdf, pdf_bsdf, sample_bsdf, shading_correction
from .microfacet import (FRESNEL_DIELECTRIC, FRESNEL_F82, FRESNEL_NONE, f0_from_ior,
                         fresnel_dielectric, ggx_D, ggx_lambda, ggx_sample_vndf, oren_nayar_f)
from .multiscatter import layer_transmission, multiscatter_factor
from .table import (DEFAULT_MULTISCATTER, DIFFUSE_ROUGHNESS_EPS, IOR_ONE_EPS, SPECULAR_ALPHA2,
                    MaterialTable, build_material_table, delta_probability, emission_radiance,
                    glossy_only, lambert_albedo, lobe_colors, used_lobes, view_dependent,
                    view_mu)

__all__ = [
    # the table
    "MaterialTable", "build_material_table", "lobe_colors", "emission_radiance",
    "delta_probability", "glossy_only", "lambert_albedo", "used_lobes", "view_dependent",
    "view_mu",
    "SPECULAR_ALPHA2", "DIFFUSE_ROUGHNESS_EPS", "IOR_ONE_EPS", "DEFAULT_MULTISCATTER",
    # the BSDF of a material
    "eval_bsdf", "pdf_bsdf", "sample_bsdf", "shading_correction",
    # building blocks
    "FRESNEL_NONE", "FRESNEL_DIELECTRIC", "FRESNEL_F82", "f0_from_ior", "fresnel_dielectric",
    "ggx_D", "ggx_lambda", "ggx_sample_vndf", "oren_nayar_f",
    "layer_transmission", "multiscatter_factor",
]
