"""Lights: emitters in Cycles' units for photon emission, next-event estimation and rays.

One flat structure-of-arrays table (:class:`LightTable`) holds every emitter of a
:class:`core.scene.Scene`: Blender lights (point, spot, sun, area), emissive
triangles and the constant world colour.  Units and shapes follow Cycles 5.2
(``docs/cycles_units.md``, "Cycles' units"), read from Cycles' sources
``intern/cycles/kernel/light/{point,spot,area,distant,background,triangle}.h``
and ``intern/cycles/scene/light.cpp``:

============  =================================================================
emitter       model (strength = color * energy * 2**exposure)
============  =================================================================
point r = 0   intensity I = strength / (4 pi) [W/sr], flux = strength.
point r > 0   Cycles' default ``use_soft_falloff``: a disc of radius r always
              facing the shading point, radiance L = strength / (pi * 4 pi r^2)
              (``eval_fac = 1 / (pi * area)``, area = 4 pi r^2).  Irradiance
              on a facing receiver at distance d: I / (d^2 + r^2) ("soft"
              near field), I / d^2 far field.  ``use_soft_falloff = False``
              (attribute read with getattr, default True): a sphere of the same
              radiance, irradiance I / d^2 down to the surface.
spot          point model times Cycles' smoothstep((cos_local - cos(size/2)) /
              ((1 - cos(size/2)) * blend)), evaluated on the direction from the
              light sample to the receiver mapped to the light's local frame
              (object scale makes the cone elliptic).  NOT renormalised:
              flux = strength / (4 pi) * int smoothstep d omega.  Soft falloff
              (r > 0, not a sphere): on the direction from each disc sample,
              as Cycles; the photons from the centre read it through one disc
              sample at their first hit (:mod:`.emission`).
sun           irradiance S = strength on a plane perpendicular to local -Z; with
              angle > 0 a cone of half-angle h = angle / 2 and radiance
              S / (pi sin^2 h) (its projected solid angle is pi sin^2 h cos).
area          one-sided Lambertian towards local -Z, L = strength / (pi A),
              A = |scale_x| size * |scale_y| size_y (* pi/4 for disc/ellipse),
              flux = strength.  ``spread`` < 180 deg: the radiance leaving at
              theta to the normal times Cycles' max((tan a - tan theta) /
              (tan a - a), 0), a = spread / 2 (:func:`spread_atten`; the
              flux unchanged).  Never occludes.
mesh          Cycles' Emission closure: L = Material.emission (times its
              texture), two-sided, per-triangle flux 2 * pi * A * L.
world         constant radiance L_w from every direction, or an equirectangular
              environment map (:mod:`.environment`: Cycles' lookup, sampled by
              a piecewise-constant distribution over its texel regions).
============  =================================================================

Modules: :mod:`.table` (:class:`LightTable`, :func:`build_light_table`, the
kinds), :mod:`.emission` (:func:`sample_photons`), :mod:`.sampling`
(:func:`sample_direct`, next-event estimation), :mod:`.pdf` (:func:`pdf_direct`,
its density for a given direction: MIS), :mod:`.seen`
(:func:`emitted_along_rays`, :func:`world_radiance`: lights seen by rays) and
:mod:`.warps` (the shape warps emission and sampling share) and
:mod:`.environment` (:class:`.environment.EnvironmentLight`, the world map).
"""
from __future__ import annotations

from .emission import B_DIFFUSE, sample_photons
from .pdf import (bsdf_hittable, bsdf_sees, emitter_rows, mis_hittable, pdf_direct,
                  samples_only)
from .sampling import sample_direct
from .seen import emitted_along_rays, world_radiance, world_seen_by
from .table import (AREA, KIND_NAMES, MESH, POINT, SPOT, SUN, WORLD, LightTable,
                    build_light_table, spread_atten)

__all__ = [
    "POINT", "SPOT", "SUN", "AREA", "MESH", "WORLD", "KIND_NAMES", "LightTable",
    "build_light_table", "B_DIFFUSE", "sample_photons", "sample_direct", "pdf_direct",
    "bsdf_hittable", "bsdf_sees", "emitter_rows", "mis_hittable", "samples_only",
    "emitted_along_rays", "world_radiance", "world_seen_by", "spread_atten",
]
