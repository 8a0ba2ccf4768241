"""Compiled importance sampling of the common closures (the photon fast path).

The photon tracer (``core.sppm.photons``) samples most hits in one numba loop
(``core.sppm.photon_kernels.bounce_kernel``); the closures it can sample
there are classified here (``FastMaterials``; everything else is "generic"
and handed back to ``core.materials.sample_bsdf`` by the caller):

- LAMBERT: every used lobe is DIFFUSE with roughness 0, no texture, no delta
  lobe.  Cosine sampling; weight = sum of lobe colours x Veach's
  shading-normal factor (``bsdf.sample_bsdf`` fast path).
- MIRROR: a single used lobe, GLOSSY and delta (alpha^2 <= 2e-10), no texture,
  no Fresnel (a Principled metal or Metallic BSDF at roughness 0 is GENERIC).
- GLASS: a single used lobe, GLASS and delta (smooth, or |ior - 1| < 1e-4),
  no texture.  Reflect with probability F (exact dielectric Fresnel), weight
  C (/eta^2 on refraction, the importance-mode adjoint), x shading factor.

A GENERIC material without textures (e.g. Blender's default Principled
BSDF) is flagged ``sampled``: the bounce kernel samples it with
``core.materials.compiled.sample_pair`` (importance mode, every lobe kind,
equal to ``sample_bsdf`` sample for sample) and hands the result back in
the generic block (``photon_kernels.generic_survivors`` keeps the
survivors), unless COMPILED_SAMPLING is off.  Those without Normal Map /
Bump are also ``compiled``: the camera paths, light tracing and Combined's
densities evaluate them compiled, where Cycles' normal corrections would
apply.

The formulas are those of ``core.materials.closures`` (``_cos_hemisphere``,
``_frame``, ``fresnel_dielectric``, ``_refract``, ``_adjoint_correction``)
written per ray in float64; tests/test_photon_kernels.py checks
:func:`sample_fast` sample for sample against ``bsdf.sample_bsdf``.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..mathutil import LUM_B as _LUM2, LUM_G as _LUM1, LUM_R as _LUM0
from ..scene.model import GLASS, GLOSSY
from . import rough_maps
from .table import view_dependent
from .compiled import (N_FIELDS, N_TABLES, CompiledMaterials, SelectionTable, _disk,
                       compile_materials, selection_table)

# Fast-path classes of a material.
GENERIC = 0
LAMBERT = 1
MIRROR = 2
SMOOTH_GLASS = 3
ABSORBER = 4          # no lobe with a non-zero weight (e.g. emission only)

#: Sample the ``compiled`` GENERIC materials in the bounce kernel (off: all
#: GENERIC materials go to numpy ``sample_bsdf``; read by build_fast_materials).
COMPILED_SAMPLING = True


class FastMaterials(NamedTuple):
    """Per-material data of the fast path.  M materials.

    cls: (M,) int8 GENERIC / LAMBERT / MIRROR / SMOOTH_GLASS / ABSORBER.
    col: (M, 3) float64 LAMBERT: sum of lobe colour x weight; MIRROR / GLASS:
      the lobe's colour x weight.
    ior: (M,) float64 GLASS index of refraction.
    deposit: (M,) bool material has a non-delta lobe (photons are stored).
    compiled: (M,) bool GENERIC material sampled (both modes), evaluated and
      weighed by core.materials.compiled: untextured, no Normal Map / Bump,
      no roughness map (its level rows are: core.materials.rough_maps).
    sampled: (M,) bool GENERIC material the bounce kernel samples by
      compiled.sample_pair (importance mode): the compiled ones and the
      untextured ones with a Normal Map / Bump, which importance sampling
      treats as any other (closures.sample_bsdf corrects the normal in
      radiance mode only; photons scatter off the interpolated normal).
      The camera paths' kernels take these too (radiance mode, with the
      corrections: core.integrators.path_kernels).
    cm, sel: their CompiledMaterials and SelectionTable (1-material
      placeholders when no material is sampled).
    """
    cls: np.ndarray
    col: np.ndarray
    ior: np.ndarray
    deposit: np.ndarray
    compiled: np.ndarray = None
    sampled: np.ndarray = None
    cm: CompiledMaterials = None
    sel: SelectionTable = None

    @property
    def any_generic(self) -> bool:
        return bool(np.any(self.cls == GENERIC))

    @property
    def any_compiled(self) -> bool:
        return self.compiled is not None and bool(np.any(self.compiled))

    @property
    def any_sampled(self) -> bool:
        return self.sampled is not None and bool(np.any(self.sampled))


def build_fast_materials(mtab) -> FastMaterials:
    """Classify the materials of a ``bsdf.MaterialTable`` for the fast path."""
    M = mtab.kind.shape[0]
    cls = np.zeros(M, np.int8)
    col = np.zeros((M, 3))
    ior = np.ones(M)
    # Colour-textured and view-dependent materials: a colour row per hit
    # (materials.hit_colors), never a fast class's constant colour.
    per_hit = (np.any((mtab.tex >= 0) & (mtab.kind >= 0), axis=1)
               | view_dependent(mtab))
    for m in range(M):
        kinds = mtab.kind[m]
        slots = [j for j in range(kinds.shape[0]) if kinds[j] >= 0]
        used = [j for j in slots if mtab.weight[m, j] != 0.0]
        if not used:
            cls[m] = ABSORBER           # bsdf.sample_bsdf: no lobe, invalid
            continue
        if per_hit[m]:
            continue
        cw = [mtab.color[m, j] * mtab.weight[m, j] for j in slots]
        # Photons bounce off the interpolated normal (docs/shading.md): a
        # Normal Map / Bump Lambert material still bounces them as Lambert.
        lambert = mtab.lambert_lobes if mtab.lambert_lobes is not None else mtab.lambert_only
        if bool(lambert[m]) and not bool(mtab.has_delta[m]):
            # bsdf.sample_bsdf's Lambert fast path: weight = sum of all colours.
            cls[m] = LAMBERT
            col[m] = np.sum(cw, axis=0)
        elif len(used) == 1 and mtab.lobe_delta[m, used[0]]:
            j = used[0]
            if kinds[j] == GLOSSY:
                if mtab.fresnel is not None and mtab.fresnel[m, j] != 0:
                    continue            # a Fresnel of the angle (Principled, Metallic BSDF)
                cls[m] = MIRROR
            elif kinds[j] == GLASS:
                cls[m] = SMOOTH_GLASS
                ior[m] = mtab.ior[m, j]
            else:
                continue
            col[m] = mtab.color[m, j] * mtab.weight[m, j]
    bump = getattr(mtab, "bump_correction", None)
    sampled = (cls == GENERIC) & ~per_hit
    sampled &= COMPILED_SAMPLING & ~rough_maps.mapped(mtab)     # their hits pick a level
    comp = sampled.copy()
    if bump is not None:
        comp &= ~np.asarray(bump, bool)
    if sampled.any():
        cm, sel = compile_materials(mtab), selection_table(mtab)
    else:
        L = mtab.kind.shape[1]
        cm = CompiledMaterials(np.zeros((1, L, N_FIELDS)), np.zeros(N_TABLES))
        sel = SelectionTable(np.zeros((1, L, 3)), np.zeros((1, L)), np.zeros((1, L)),
                             np.zeros(1, np.int64))
    return FastMaterials(cls=cls, col=col, ior=ior,
                         deposit=np.asarray(mtab.has_nondelta, bool).copy(),
                         compiled=comp, sampled=sampled, cm=cm, sel=sel)


@njit(cache=True, inline="always")
def _adjoint(nsx, nsy, nsz, ngx, ngy, ngz, wox, woy, woz, wix, wiy, wiz):
    """bsdf._adjoint_correction: |wo.ns||wi.ng| / (|wo.ng||wi.ns|)."""
    num = abs(wox * nsx + woy * nsy + woz * nsz) * abs(wix * ngx + wiy * ngy + wiz * ngz)
    den = abs(wox * ngx + woy * ngy + woz * ngz) * abs(wix * nsx + wiy * nsy + wiz * nsz)
    if den > 0.0:
        return num / den
    return 0.0


# inline: a call's 17 arguments and 8 results cost ~5 % of the bounce kernel
# (docs/architecture.md "Cores at 256² and the bounce kernel, round 13").
@njit(cache=True, error_model="numpy", inline="always")
def sample_fast(cls, cr, cg, cb, ior, nsx, nsy, nsz, ngx, ngy, ngz, wox, woy, woz,
                u0, u1, u2):
    """Importance-mode sample of one fast-path closure (``bsdf.sample_bsdf``).

    ns, ng: unit shading / geometric normals (any orientation); wo: unit, the
    direction back towards where the photon came from; u0, u1 direction,
    u2 Fresnel choice.  Returns (wx, wy, wz, weight r, g, b, is_delta, ok);
    weight = 0 when not ok.  The Lambert direction's disk point is
    compiled._disk's (its angle's sine and cosine by compiled.sincos_quarter).
    """
    # Orient both normals to wo's side of the geometric normal (Cycles' back faces).
    front = ngx * wox + ngy * woy + ngz * woz >= 0.0
    s = 1.0 if front else -1.0
    Nx, Ny, Nz = nsx * s, nsy * s, nsz * s
    Gx, Gy, Gz = ngx * s, ngy * s, ngz * s
    lum = cr * _LUM0 + cg * _LUM1 + cb * _LUM2
    if cls == LAMBERT:
        # Shirley-Chiu concentric disk, lifted (bsdf._cos_hemisphere).
        lx, ly = _disk(u0, u1)
        lz = np.sqrt(max(0.0, 1.0 - lx * lx - ly * ly))
        # Tangent frame of N (Duff et al. 2017, bsdf._frame).
        sg = 1.0 if Nz >= 0.0 else -1.0
        aa = -1.0 / (sg + Nz)
        bb = Nx * Ny * aa
        tx, ty, tz = 1.0 + sg * Nx * Nx * aa, sg * bb, -sg * Nx
        bx, by, bz = bb, sg + Ny * Ny * aa, -Ny
        wx = lx * tx + ly * bx + lz * Nx
        wy = lx * ty + ly * by + lz * Ny
        wz = lx * tz + ly * bz + lz * Nz
        ok = (Gx * wx + Gy * wy + Gz * wz > 0.0) and lz > 0.0 and lum > 0.0
        if not ok:
            return wx, wy, wz, 0.0, 0.0, 0.0, False, False
        c = _adjoint(nsx, nsy, nsz, ngx, ngy, ngz, wox, woy, woz, wx, wy, wz)
        return wx, wy, wz, cr * c, cg * c, cb * c, False, True
    # Delta microfacet lobes: H = N.
    if not lum > 0.0:          # no lobe to select (bsdf: any_lobe False)
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False
    cI = wox * Nx + woy * Ny + woz * Nz
    hwo = cI
    refr = False
    wgt_scale = 1.0
    if cls == MIRROR:
        wx = 2.0 * hwo * Nx - wox
        wy = 2.0 * hwo * Ny - woy
        wz = 2.0 * hwo * Nz - woz
    else:
        eta = ior if front else 1.0 / ior
        # bsdf.fresnel_dielectric
        cc = abs(hwo)
        g2 = eta * eta - 1.0 + cc * cc
        if g2 <= 0.0:
            F = 1.0
            cos_t = 0.0
        else:
            g = np.sqrt(g2)
            A = (g - cc) / (g + cc)
            B = (cc * (g + cc) - 1.0) / (cc * (g - cc) + 1.0)
            F = 0.5 * A * A * (1.0 + B * B)
            cos_t = np.sqrt(max(0.0, 1.0 - (1.0 - cc * cc) / (eta * eta)))
        u_re = min(max(u2, 0.0), 1.0 - 1e-16)
        refr = u_re >= F
        if refr:
            inv = 1.0 / eta
            k = inv * hwo - cos_t
            wx = k * Nx - inv * wox
            wy = k * Ny - inv * woy
            wz = k * Nz - inv * woz
            wgt_scale = 1.0 / (eta * eta)   # adjoint of Cycles' unscaled BTDF
        else:
            wx = 2.0 * hwo * Nx - wox
            wy = 2.0 * hwo * Ny - woy
            wz = 2.0 * hwo * Nz - woz
    nrm = np.sqrt(wx * wx + wy * wy + wz * wz)
    if nrm > 0.0:
        wx /= nrm
        wy /= nrm
        wz /= nrm
    cN = Nx * wx + Ny * wy + Nz * wz
    cG = Gx * wx + Gy * wy + Gz * wz
    if refr:
        ok = cI > 0.0 and cN < 0.0 and cG < 0.0
    else:
        ok = cI > 0.0 and cN > 0.0 and cG > 0.0
    if not ok:
        return wx, wy, wz, 0.0, 0.0, 0.0, True, False
    c = _adjoint(nsx, nsy, nsz, ngx, ngy, ngz, wox, woy, woz, wx, wy, wz) * wgt_scale
    return wx, wy, wz, cr * c, cg * c, cb * c, True, True
