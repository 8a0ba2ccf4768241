"""The light-sampling density of a direction, compiled (numba).

:func:`selection_kernel` and :func:`pdf_kernel` are ``core.lights.pdf``'s
``_selection_probability`` and ``pdf_direct`` over arrays of rows: the
probability that next-event estimation (``direct_kernels.direct_kernel``)
picks an emitter at a point, and the solid-angle density of a direction
sampled on it.  Their users weigh light samples against BSDF samples: the
camera paths (core.integrators.path_kernels, combined) and the visible
points' environment map (core.lights.map_mis_kernels).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .direct_kernels import SPH_TRI_MIN, _entry_weight, _spherical_rect, _spherical_tri, rect_of
# map_pdf is compiled into pdf_kernel (numba's cache is stamped by this file).
from .environment_kernels import map_pdf, texture_vector
from .table import AREA, MESH, POINT, SPOT, SUN, WORLD

_PI = np.pi


class LightPdf(NamedTuple):
    """What :func:`pdf_kernel` reads besides ``DirectLights`` (Nl emitters):
    entry (Nl,) int64 the selection entry of each emitter (the group's for
    group triangles, -1: none); group_frac (Nl,) float64 its share of the
    group (1 outside it); hittable (Nl,) bool a BSDF ray can find it;
    vis_glossy, vis_trans (Nl,) bool its visibility to reflected /
    transmitted rays.  The selection weights read ``DirectLights.sel``."""
    entry: np.ndarray
    group_frac: np.ndarray
    hittable: np.ndarray
    vis_glossy: np.ndarray
    vis_trans: np.ndarray


def build_light_pdf(table, hittable, L) -> LightPdf:
    """L: the table's ``DirectLights``."""
    n = table.kind.shape[0]
    entry = np.full(n, -1, np.int64)
    em = table.entry_emitter
    entry[em[em >= 0]] = np.nonzero(em >= 0)[0]
    frac = np.ones(n)
    if table.group_tri is not None and table.group_tri.size:
        entry[table.group_tri] = int(np.nonzero(em < 0)[0][0])
        cdf = table.group_cdf
        frac[table.group_tri] = np.diff(np.concatenate([[0.0], cdf])) / cdf[-1]
    return LightPdf(entry=entry, group_frac=frac, hittable=np.asarray(hittable, bool).copy(),
                    vis_glossy=np.asarray(table.visible_glossy, bool).copy(),
                    vis_trans=np.asarray(table.visible_transmission, bool).copy())


# ----------------------------------------------------------------------------
# The light-sampling density (core.lights.pdf.pdf_direct, one direction).

@njit(cache=True, nogil=True, error_model="numpy")
def selection_kernel(L, Q, p, light, out):
    """out (K,) = pdf._selection_probability: the probability that next-event
    estimation at p (K, 3) picks emitter light (K,) (-1: 0), its entry's
    weight over the sum (``direct_kernel``'s selection) times its share of
    the triangle group.  The per-row work of :func:`pdf_kernel` and of the
    COMBINED ratios is written as loops over rows, not as per-row functions
    taking the light tables (see :class:`EntryLights`)."""
    E = L.entry.shape[0]
    G = L.group_cdf.shape[0]
    for k in range(p.shape[0]):
        j = light[k]
        out[k] = 0.0
        if j < 0:
            continue
        e_j = Q.entry[j]
        if e_j < 0:
            continue
        px, py, pz = p[k, 0], p[k, 1], p[k, 2]
        tot = 0.0
        we = 0.0
        for e in range(E):
            i = L.entry[e]
            if i < 0:
                d2 = (px - L.group[0]) ** 2 + (py - L.group[1]) ** 2 + (pz - L.group[2]) ** 2
                w = L.group_cdf[G - 1] / (2.0 * _PI * (d2 + L.group[3]))
            else:
                w = _entry_weight(L.sel, i, px, py, pz)
            if not np.isfinite(w):
                w = 0.0
            tot += w
            if e == e_j:
                we = w
        if tot > 0:
            out[k] = we / tot * Q.group_frac[j]


@njit(cache=True, nogil=True, error_model="numpy")
def pdf_kernel(L, Q, p, wi, light, dist, n, sel, out):
    """out (K,) = core.lights.pdf_direct: the solid-angle density with which
    next-event estimation at p (receiver normal n, oriented; p, wi, n (K, 3))
    picks emitter light (K,) (-1: 0) and the point p + dist wi on it; 0 for
    delta emitters.  sel (K,): :func:`selection_kernel` of the same rows."""
    for k in range(p.shape[0]):
        j = light[k]
        out[k] = 0.0
        if j < 0:
            continue
        px, py, pz = p[k, 0], p[k, 1], p[k, 2]
        wx, wy, wz = wi[k, 0], wi[k, 1], wi[k, 2]
        kind = L.kind[j]
        d2 = dist[k] * dist[k]
        pdf = 0.0
        if kind == POINT or kind == SPOT:
            r = L.radius[j]
            if r > 0:
                dx, dy, dz = px - L.co[j, 0], py - L.co[j, 1], pz - L.co[j, 2]
                d = np.sqrt(dx * dx + dy * dy + dz * dz)
                if L.is_sphere[j]:
                    if d > r:
                        sin2 = (r / max(d, 1e-300)) ** 2
                        omc = sin2 / (1.0 + np.sqrt(max(1.0 - sin2, 0.0)))
                    else:
                        omc = 2.0
                    pdf = 1.0 / (2.0 * _PI * max(omc, 1e-300))
                else:
                    dm = max(d, 1e-300)
                    cosl = abs(wx * (dx / dm) + wy * (dy / dm) + wz * (dz / dm))
                    pdf = d2 / max(_PI * r * r * cosl, 1e-300)
        elif kind == SUN:
            if L.half_angle[j] > 0:
                pdf = 1.0 / (2.0 * _PI * max(1.0 - L.cos_half_angle[j], 1e-300))
        elif kind == WORLD:
            if L.env.total > 0:
                # An environment map: its own distribution (direct_kernel).
                cx, cy, cz, nt = texture_vector(L.env, wx, wy, wz)
                pdf = map_pdf(L.env, cx, cy, cz, nt)
            else:
                pdf = max(n[k, 0] * wx + n[k, 1] * wy + n[k, 2] * wz, 0.0) / _PI
        elif kind == AREA:
            cosl = -(wx * L.dir[j, 0] + wy * L.dir[j, 1] + wz * L.dir[j, 2])
            front = ((px - L.co[j, 0]) * L.dir[j, 0] + (py - L.co[j, 1]) * L.dir[j, 1]
                     + (pz - L.co[j, 2]) * L.dir[j, 2]) > 0
            if front:
                if cosl > 0:
                    pdf = d2 / max(L.area[j] * max(cosl, 0.0), 1e-300)
                if not L.ellipse[j]:
                    sx, sy, sz, lu, lv = rect_of(L, j, px, py, pz)
                    S = _spherical_rect(px, py, pz, sx, sy, sz, L.axis_u[j, 0], L.axis_u[j, 1],
                                        L.axis_u[j, 2], lu, L.axis_v[j, 0],
                                        L.axis_v[j, 1], L.axis_v[j, 2], lv, 0.5, 0.5)[3]
                    if S > 1e-6:
                        pdf = 1.0 / max(S, 1e-300)
        elif kind == MESH:
            p0x, p0y, p0z = L.co[j, 0], L.co[j, 1], L.co[j, 2]
            e1x, e1y, e1z = L.axis_u[j, 0], L.axis_u[j, 1], L.axis_u[j, 2]
            e2x, e2y, e2z = L.axis_v[j, 0], L.axis_v[j, 1], L.axis_v[j, 2]
            omega = _spherical_tri(px, py, pz, p0x, p0y, p0z, p0x + e1x, p0y + e1y, p0z + e1z,
                                   p0x + e2x, p0y + e2y, p0z + e2z, 0.5, 0.5)[3]
            if omega > SPH_TRI_MIN:
                pdf = 1.0 / max(omega, 1e-300)
            else:
                cosl = abs(wx * L.dir[j, 0] + wy * L.dir[j, 1] + wz * L.dir[j, 2])
                pdf = d2 / max(L.area[j] * cosl, 1e-300)
        pdf *= sel[k]
        out[k] = pdf if np.isfinite(pdf) else 0.0
