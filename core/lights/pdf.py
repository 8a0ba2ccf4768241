"""The density with which next-event estimation would have chosen a direction.

:func:`pdf_direct` is the solid-angle pdf of :func:`core.lights.sampling.sample_direct`
for a direction that reaches a given emitter (light selection x shape
sampling), the quantity multiple importance sampling (Veach 1997, ch. 9) needs
when a BSDF-sampled ray hits an emitter.  It follows sample_direct branch for
branch (same selection weights, same choice between solid-angle and area
sampling), so the two estimators' MIS weights sum to one.
"""
from __future__ import annotations

import numpy as np

from ..mathutil import dot as _dot
from .sampling import _SPH_TRI_MIN, _entry_weights, _sample_spherical_rect, _sample_spherical_tri
from .table import AREA, MESH, POINT, SPOT, SUN, WORLD, LightTable, spread_rect


def _selection_probability(table: LightTable, p: np.ndarray, light: np.ndarray) -> np.ndarray:
    """(K,) probability that sample_direct at p (K, 3) picks emitter row light (K,) (-1: 0)."""
    K = p.shape[0]
    out = np.zeros(K)
    E = table.entry_emitter.shape[0]
    if E == 0 or K == 0:
        return out
    W = _entry_weights(table, p)
    tot = W.sum(axis=1)
    entry = np.full(table.n, -1, np.int64)
    em = table.entry_emitter
    entry[em[em >= 0]] = np.nonzero(em >= 0)[0]
    group = np.ones(table.n)
    if table.group_tri.size:
        g = int(np.nonzero(em < 0)[0][0])
        entry[table.group_tri] = g
        cdf = table.group_cdf
        group[table.group_tri] = np.diff(np.concatenate([[0.0], cdf])) / cdf[-1]
    ok = (light >= 0) & (tot > 0)
    i = np.nonzero(ok)[0]
    e = entry[light[i]]
    good = e >= 0
    i, e = i[good], e[good]
    out[i] = W[i, e] / tot[i] * group[light[i]]
    return out


def pdf_direct(table: LightTable, p: np.ndarray, wi: np.ndarray, light: np.ndarray,
               dist: np.ndarray, n=None) -> np.ndarray:
    """Solid-angle density (K,) with which ``sample_direct(table, p, u, n)`` picks
    emitter row ``light`` and, on it, the point p + dist wi.

    p, wi (K, 3) float64 (wi unit); light (K,) int emitter row, -1 = none (pdf 0);
    dist (K,) distance to the emitter along wi (inf for sun and world); n: the
    same optional receiver normals (K, 3) given to sample_direct.  Delta
    emitters (point/spot of radius 0, sun of angle 0) have no density: 0.
    """
    p = np.asarray(p, np.float64).reshape(-1, 3)
    wi = np.asarray(wi, np.float64).reshape(-1, 3)
    light = np.asarray(light, np.int64).reshape(-1)
    dist = np.asarray(dist, np.float64).reshape(-1)
    K = p.shape[0]
    pdf = np.zeros(K)
    if K == 0 or table.n == 0:
        return pdf
    p_sel = _selection_probability(table, p, light)
    kind = np.where(light >= 0, table.kind[np.maximum(light, 0)], -1)
    d2 = dist * dist
    half = np.full(K, 0.5)

    m = np.nonzero((kind == POINT) | (kind == SPOT))[0]
    if m.size:
        j = light[m]
        r = table.radius[j]
        dv = p[m] - table.co[j]
        d = np.linalg.norm(dv, axis=1)
        sph = table.is_sphere[j]
        # Soft falloff disc facing p, sampled by area: t^2 / (pi r^2 cos_l).
        cosl = np.abs(_dot(wi[m], dv / np.maximum(d, 1e-300)[:, None]))
        disc = d2[m] / np.maximum(np.pi * r * r * cosl, 1e-300)
        # Sphere: uniform in the cone of the visible cap, the whole sphere inside.
        sin2 = np.where(d > r, (r / np.maximum(d, 1e-300)) ** 2, 1.0)
        one_minus_cos = np.where(d > r, sin2 / (1.0 + np.sqrt(np.maximum(1.0 - sin2, 0.0))), 2.0)
        cone = 1.0 / (2.0 * np.pi * np.maximum(one_minus_cos, 1e-300))
        pdf[m] = np.where(r > 0, np.where(sph, cone, disc), 0.0)

    m = np.nonzero(kind == SUN)[0]
    if m.size:
        j = light[m]
        com = 1.0 - table.cos_half_angle[j]
        pdf[m] = np.where(table.half_angle[j] > 0, 1.0 / (2.0 * np.pi * np.maximum(com, 1e-300)), 0.0)

    m = np.nonzero(kind == WORLD)[0]
    if m.size:
        env = table.environment
        if env is not None and env.total > 0:
            pdf[m] = env.pdf(wi[m])     # sampling._sample_environment: the map's own
        elif n is None:
            pdf[m] = 1.0 / (4.0 * np.pi)
        else:
            nm = np.asarray(n, np.float64).reshape(-1, 3)[m]
            pdf[m] = np.maximum(_dot(nm, wi[m]), 0.0) / np.pi

    m = np.nonzero(kind == AREA)[0]
    if m.size:
        j = light[m]
        cosl = -_dot(wi[m], table.dir[j])
        front = _dot(p[m] - table.co[j], table.dir[j]) > 0
        by_area = d2[m] / np.maximum(table.area[j] * np.maximum(cosl, 0.0), 1e-300)
        res = np.where(cosl > 0, by_area, 0.0)
        rect = np.nonzero(~table.ellipse[j])[0]
        if rect.size:
            jr = j[rect]
            corner = (table.co[jr] - 0.5 * table.len_u[jr, None] * table.axis_u[jr]
                      - 0.5 * table.len_v[jr, None] * table.axis_v[jr])
            corner, lu, lv = spread_rect(table, jr, p[m[rect]], corner, table.len_u[jr],
                                         table.len_v[jr])
            _, S = _sample_spherical_rect(p[m[rect]], corner, table.axis_u[jr], lu,
                                          table.axis_v[jr], lv, half[rect], half[rect])
            res[rect] = np.where(S > 1e-6, 1.0 / np.maximum(S, 1e-300), res[rect])
        pdf[m] = np.where(front, res, 0.0)

    m = np.nonzero(kind == MESH)[0]
    if m.size:
        j = light[m]
        p0, e1, e2 = table.co[j], table.axis_u[j], table.axis_v[j]
        _, omega = _sample_spherical_tri(p[m], p0, p0 + e1, p0 + e2, half[m], half[m])
        cosl = np.abs(_dot(wi[m], table.dir[j]))
        by_area = d2[m] / np.maximum(table.area[j] * cosl, 1e-300)
        pdf[m] = np.where(omega > _SPH_TRI_MIN, 1.0 / np.maximum(omega, 1e-300), by_area)

    pdf *= p_sel
    pdf[~np.isfinite(pdf)] = 0.0
    return pdf


def environment_pdf(table: LightTable, p: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(K,) :func:`pdf_direct` of the world's row for directions w (K, 3)
    from points p (K, 3): p_select(world | p) pdf_map(w); 0 without a map.
    For multiple importance sampling with BSDF samples
    (``nee.NextEventEstimation``)."""
    p = np.asarray(p, np.float64).reshape(-1, 3)
    env = table.environment
    e = np.nonzero((table.entry_emitter >= 0)
                   & (table.kind[np.maximum(table.entry_emitter, 0)] == WORLD))[0]
    if env is None or env.total <= 0 or e.size == 0 or p.shape[0] == 0:
        return np.zeros(p.shape[0])
    K = p.shape[0]
    return pdf_direct(table, p, w, np.full(K, table.entry_emitter[e[0]], np.int64),
                      np.full(K, np.inf))


def bsdf_hittable(table: LightTable) -> np.ndarray:
    """(Nl,) bool: the emitters a BSDF-sampled ray can hit (area lights,
    emissive triangles, the world, a sun's disc of angle > 0, a point or spot
    light of radius > 0), to which multiple importance sampling applies; the
    others (delta lights) are found by light samples alone."""
    k = table.kind
    return ((k == AREA) | (k == MESH) | (k == WORLD) | ((k == SUN) & (table.half_angle > 0))
            | (((k == POINT) | (k == SPOT)) & (table.radius > 0)))


def samples_only(table: LightTable) -> np.ndarray:
    """(Nl,) bool: the emitters whose light at a non-delta vertex light
    samples alone find (weight 1; a BSDF ray's hit on them weighs 0): those
    with shadow linking (core.scene.shadow_linking) and those hidden from
    some kind of ray (core.lights.lobe_visibility)."""
    from ..scene.shadow_linking import nee_only
    out = nee_only(table)
    hidden = getattr(table, "hidden", None)
    return out if hidden is None else out | (np.asarray(hidden) != 0)


def mis_hittable(table: LightTable) -> np.ndarray:
    """(Nl,) bool: the emitters whose light a BSDF-sampled ray from a
    non-delta vertex finds and weighs against light samples:
    :func:`bsdf_hittable`'s, less :func:`samples_only`'s."""
    return bsdf_hittable(table) & ~samples_only(table)


def bsdf_sees(table: LightTable, hittable: np.ndarray, light: np.ndarray, ng: np.ndarray,
              wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """(K,) bool: a BSDF ray leaving a vertex (mesh normal ng, wo (K, 3)) along
    the light samples' wi (K, 3) would find their emitter rows light (K,):
    hittable (:func:`bsdf_hittable`) and seen by that kind of ray (a light's
    Glossy or Transmission visibility, by wi's side of ng against wo;
    emissive triangles and the world always)."""
    refl = (_dot(wi, ng) * _dot(wo, ng)) > 0
    return hittable[light] & np.where(
        table.kind[light] == MESH, True,
        np.where(refl, table.visible_glossy[light], table.visible_transmission[light])
        | (table.kind[light] == WORLD))


def emitter_rows(table: LightTable, T: int) -> tuple[np.ndarray, int]:
    """(tri_light (T,) int64 the emitter row of each of a scene's T triangles,
    -1 where it emits nothing; the world's row or -1): the rows a BSDF-sampled
    ray's hit or escape gives :func:`pdf_direct`."""
    tri_light = np.full(T, -1, np.int64)
    mesh = np.nonzero(table.kind == MESH)[0]
    tri_light[table.source[mesh]] = mesh
    w = np.nonzero(table.kind == WORLD)[0]
    return tri_light, int(w[0]) if w.size else -1
