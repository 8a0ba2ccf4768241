"""Next-event estimation: :func:`sample_direct` picks a light and a point on it.

One emitter per receiver is chosen with probability ~ an irradiance bound
(flux over squared distance), then sampled: rectangles and large emissive
triangles uniformly in solid angle (Urena et al. 2013, Arvo 1995; as Cycles
does), discs/ellipses and small triangles by area, point/spot discs by area,
sun cones and sphere caps uniformly.
"""
from __future__ import annotations

import numpy as np

from ..mathutil import dot as _dot, frame
from . import ies as IES
from .table import (AREA, MESH, POINT, SPOT, SUN, WORLD, LightTable, _lum, _mesh_emission,
                    spread_atten, spread_rect,
                    _spot_atten)
from .warps import (_cone_local, _cosine_local, _normalize, _to_world, _triangle_bary,
                    _uniform_sphere, _unit_disk)


# ----------------------------------------------------------------------------
# Spherical rectangles and triangles.

def _sample_spherical_rect(p, s, ex, lx, ey, ly, u1, u2):
    """Uniform solid-angle sampling of rectangles (Urena, Fajardo, King 2013).

    p: (K,3) receivers; s: (K,3) rectangle corner; ex, ey: (K,3) unit edge
    directions with lengths lx, ly (K,).  Returns (points (K,3), solid angle S (K,)).
    """
    x, y = ex, ey
    z = np.cross(x, y)
    d = s - p
    z0 = _dot(d, z)
    flip = z0 > 0
    z = np.where(flip[:, None], -z, z)
    z0 = np.where(flip, -z0, z0)
    x0, y0 = _dot(d, x), _dot(d, y)
    x1, y1 = x0 + lx, y0 + ly
    v00 = np.stack([x0, y0, z0], 1)
    v01 = np.stack([x0, y1, z0], 1)
    v10 = np.stack([x1, y0, z0], 1)
    v11 = np.stack([x1, y1, z0], 1)
    n0 = _normalize(np.cross(v00, v10))
    n1 = _normalize(np.cross(v10, v11))
    n2 = _normalize(np.cross(v11, v01))
    n3 = _normalize(np.cross(v01, v00))
    g0 = np.arccos(np.clip(-_dot(n0, n1), -1, 1))
    g1 = np.arccos(np.clip(-_dot(n1, n2), -1, 1))
    g2 = np.arccos(np.clip(-_dot(n2, n3), -1, 1))
    g3 = np.arccos(np.clip(-_dot(n3, n0), -1, 1))
    b0, b1 = n0[:, 2], n2[:, 2]
    k = 2.0 * np.pi - g2 - g3
    S = np.maximum(g0 + g1 - k, 0.0)
    # Invert the solid angle of the sub-rectangle [x0, xu] for xu.
    au = u1 * S + k
    with np.errstate(divide="ignore", invalid="ignore"):
        fu = (np.cos(au) * b0 - b1) / np.sin(au)
        cu = np.clip(np.sign(fu) / np.sqrt(fu * fu + b0 * b0), -1.0, 1.0)
        xu = -(cu * z0) / np.sqrt(np.maximum(1.0 - cu * cu, 1e-300))
    xu = np.clip(np.nan_to_num(xu, nan=x0), x0, x1)
    # Then y by the cosine-weighted height on the chosen column.
    dd = np.sqrt(xu * xu + z0 * z0)
    h0 = y0 / np.sqrt(dd * dd + y0 * y0)
    h1 = y1 / np.sqrt(dd * dd + y1 * y1)
    hv = h0 + u2 * (h1 - h0)
    hv2 = hv * hv
    yv = np.where(hv2 < 1.0 - 1e-6, hv * dd / np.sqrt(np.maximum(1.0 - hv2, 1e-300)), y1)
    yv = np.clip(yv, y0, y1)
    q = p + xu[:, None] * x + yv[:, None] * y + z0[:, None] * z
    return q, S


# Below this solid angle [sr] emissive triangles are sampled by area: Arvo's
# inversion loses precision for tiny spherical triangles, and area sampling is
# already near-optimal there (the 1/t^2 factor is almost constant).
_SPH_TRI_MIN = 1e-3


def _sample_spherical_tri(p, A, B, C, u1, u2):
    """Uniform solid-angle sampling of triangles (Arvo 1995).

    p, A, B, C: (K, 3).  Returns (unit directions (K, 3), solid angle (K,)).
    """
    a = _normalize(A - p)
    b = _normalize(B - p)
    c = _normalize(C - p)
    # Solid angle (Van Oosterom & Strackee 1983), stable for small triangles.
    trip = np.abs(_dot(a, np.cross(b, c)))
    omega = 2.0 * np.arctan2(trip, 1.0 + _dot(a, b) + _dot(b, c) + _dot(c, a))
    omega = np.where(omega < 0, omega + 2 * np.pi, omega)
    n_ab = _normalize(np.cross(a, b))
    n_ca = _normalize(np.cross(c, a))
    alpha = np.arccos(np.clip(-_dot(n_ab, n_ca), -1.0, 1.0))   # angle at a
    cos_c = np.clip(_dot(a, b), -1.0, 1.0)                     # arc a-b
    # Sub-triangle of area u1 * omega: find its third vertex c_hat on arc a-c.
    area_hat = u1 * omega
    s = np.sin(area_hat - alpha)
    t = np.cos(area_hat - alpha)
    uu = t - np.cos(alpha)
    vv = s + np.sin(alpha) * cos_c
    with np.errstate(divide="ignore", invalid="ignore"):
        q = ((vv * t - uu * s) * np.cos(alpha) - vv) / ((vv * s + uu * t) * np.sin(alpha))
    q = np.clip(np.nan_to_num(q, nan=1.0), -1.0, 1.0)
    c_perp = _normalize(c - _dot(c, a)[:, None] * a)
    c_hat = q[:, None] * a + np.sqrt(np.maximum(1.0 - q * q, 0.0))[:, None] * c_perp
    # Then uniformly in cos along the arc b - c_hat.
    z = 1.0 - u2 * (1.0 - _dot(c_hat, b))
    ch_perp = _normalize(c_hat - _dot(c_hat, b)[:, None] * b)
    w = z[:, None] * b + np.sqrt(np.maximum(1.0 - z * z, 0.0))[:, None] * ch_perp
    return _normalize(w), omega


# ----------------------------------------------------------------------------
# The environment map.

def _sample_environment(env, u1, u2):
    """(directions (K, 3), inf distances (K,), L / pdf (K, 3)) towards an
    environment map (:mod:`.environment`), drawn from the map's distribution.

    Its callers weigh these samples against BSDF samples (the camera paths'
    continuation, the visible points' ``nee._environment_bsdf``), so a cosine
    lobe about the receiver normal beside the map (a mixture, until round 27)
    only took samples away from the map's bright texels: docs/integrators.md
    "An HDRI's light sample, round 27".
    """
    K = u1.shape[0]
    w, pdf = env.sample(u1, u2)
    with np.errstate(divide="ignore", invalid="ignore"):
        Lw = env.radiance(w) / pdf[:, None]
    Lw[~(pdf > 0)] = 0.0
    return w, np.full(K, np.inf), Lw


# ----------------------------------------------------------------------------
# Light selection and sampling.

def _entry_weights(table: LightTable, p: np.ndarray) -> np.ndarray:
    """(K, E) unnormalised selection weights ~ irradiance each entry could give.

    Finite emitters: luminance of flux / (c (d^2 + extent^2)); zero only where
    the emitter cannot contribute (behind a one-sided area light, outside a
    hard-edged spot cone of radius 0), so the estimator stays unbiased.
    """
    E = table.entry_emitter.shape[0]
    K = p.shape[0]
    W = np.zeros((K, E))
    for e, j in enumerate(table.entry_emitter):
        if j < 0:
            d2 = np.sum((p - table.group_center) ** 2, axis=1)
            W[:, e] = table.group_cdf[-1] / (2.0 * np.pi * (d2 + table.group_ext2))
            continue
        k = table.kind[j]
        lf = float(_lum(table.flux[j]))
        if lf <= 0:
            continue
        if k == SUN:
            W[:, e] = _lum(table.strength[j])
        elif k == WORLD:
            W[:, e] = np.pi * _lum(table.strength[j])
        elif k in (POINT, SPOT):
            dv = p - table.co[j]
            d2 = np.sum(dv * dv, axis=1)
            Il = _lum(table.strength[j]) / (4.0 * np.pi)
            w = Il / np.maximum(d2 + table.radius[j] ** 2, 1e-300)
            if k == SPOT:
                att = _spot_atten(table, np.full(K, j), _normalize(dv))
                w = w * (att if table.radius[j] == 0 else np.maximum(att, 0.05))
            W[:, e] = w
        elif k == AREA:
            dv = p - table.co[j]
            d2 = np.sum(dv * dv, axis=1)
            h = dv @ table.dir[j]
            cosl = np.clip(h / np.sqrt(np.maximum(d2, 1e-300)), 0.1, 1.0)
            W[:, e] = np.where(h > 0, lf * cosl / (np.pi * (d2 + table.area[j])), 0.0)
        else:  # single triangle
            c = table.co[j] + (table.axis_u[j] + table.axis_v[j]) / 3.0
            d2 = np.sum((p - c) ** 2, axis=1)
            W[:, e] = lf / (2.0 * np.pi * (d2 + table.area[j]))
    W[~np.isfinite(W)] = 0.0
    return W


def sample_direct(table: LightTable, p: np.ndarray, u: np.ndarray, n=None) -> dict:
    """One light sample per receiver point for next-event estimation.

    p: (K, 3) receiver positions; u: (K, 3) uniform numbers in [0, 1).
    n: optional (K, 3) unit receiver normals on the side to light: the world
      is then sampled cosine-weighted about n (pdf cos/pi) instead of over the
      whole sphere, which halves the wasted samples and matches f*cos.
    Returns a dict:
      wi (K, 3) unit direction towards the light sample,
      dist (K,) shadow-ray length (np.inf for sun/world; for emissive
        triangles the caller shortens it by a relative epsilon),
      weight (K, 3) = L_e * G / pdf / p_select so that the direct light is
        f(wo, wi) |cos theta_i| weight when the shadow ray is unoccluded
        (0 where no emitter can contribute),
      light (K,) int32 emitter row (-1: none), kind (K,) int8,
      cast_shadow (K,) bool: False for lights with shadows disabled.
    """
    p = np.asarray(p, np.float64).reshape(-1, 3)
    u = np.asarray(u, np.float64).reshape(-1, 3)
    K = p.shape[0]
    wi = np.tile([0.0, 0.0, 1.0], (K, 1))
    dist = np.zeros(K)
    weight = np.zeros((K, 3))
    light = np.full(K, -1, np.int32)
    kind = np.full(K, -1, np.int8)
    shadow = np.ones(K, bool)
    out = dict(wi=wi, dist=dist, weight=weight, light=light, kind=kind, cast_shadow=shadow)
    if K == 0 or table.n == 0 or table.entry_emitter.shape[0] == 0:
        return out
    W = _entry_weights(table, p)
    C = np.cumsum(W, axis=1)
    tot = C[:, -1]
    ok = tot > 0
    x = u[:, 0] * tot
    e = np.minimum((C <= x[:, None]).sum(axis=1), W.shape[1] - 1)
    rows = np.arange(K)
    We = W[rows, e]
    ok &= We > 0
    p_sel = np.where(ok, We / np.where(tot > 0, tot, 1.0), 0.0)
    j = table.entry_emitter[e].copy()
    # Triangle group: reuse the leftover of u0 inside the chosen entry.
    g = ok & (j < 0)
    if np.any(g):
        u_re = np.clip((x[g] - (C[g, e[g]] - We[g])) / We[g], 0.0, 1.0 - 1e-16)
        cdf = table.group_cdf
        ti = np.minimum(np.searchsorted(cdf, u_re * cdf[-1], side="right"), cdf.shape[0] - 1)
        lum_i = np.diff(np.concatenate([[0.0], cdf]))[ti]
        p_sel[g] *= lum_i / cdf[-1]
        j[g] = table.group_tri[ti]
    j = np.where(ok, j, -1)
    light[ok] = j[ok]
    kind[ok] = table.kind[j[ok]]
    shadow[ok] = table.cast_shadow[j[ok]]
    u1, u2 = u[:, 1], u[:, 2]

    def fill(m, w_dir, t, Lw):
        """Lw: (M, 3) radiance / pdf (solid angle) before light selection."""
        wi[m] = w_dir
        dist[m] = t
        res = Lw / p_sel[m, None]
        res[~np.isfinite(res)] = 0.0
        weight[m] = res

    for k in (POINT, SPOT):
        m = np.nonzero(kind == k)[0]
        if not m.size:
            continue
        jj = j[m]
        pc = p[m]
        co = table.co[jj]
        r = table.radius[jj]
        dv = pc - co
        d = np.linalg.norm(dv, axis=1)
        lightN = dv / np.maximum(d, 1e-300)[:, None]
        sph = table.is_sphere[jj]
        Lw = np.zeros((m.size, 3))
        w_dir = -lightN.copy()
        t = d.copy()
        # Radius 0: L_e G / pdf = I / d^2.
        z = r == 0
        if np.any(z):
            Lw[z] = table.strength[jj[z]] / (4.0 * np.pi) / np.maximum(d[z] ** 2, 1e-300)[:, None]
        # Soft falloff: disc of radius r facing p, uniform by area;
        # pdf_omega = t^2 / (pi r^2 cos_l).
        dk = (~z) & (~sph)
        if np.any(dk):
            x_, y_ = _unit_disk(u1[m[dk]], u2[m[dk]])
            t1, t2 = frame(lightN[dk])
            q = co[dk] + r[dk, None] * (x_[:, None] * t1 + y_[:, None] * t2)
            v = q - pc[dk]
            tt = np.linalg.norm(v, axis=1)
            wd = v / np.maximum(tt, 1e-300)[:, None]
            cosl = -_dot(wd, lightN[dk])
            Lw[dk] = table.radiance[jj[dk]] * (np.pi * r[dk] ** 2 * np.maximum(cosl, 0.0)
                                                / np.maximum(tt * tt, 1e-300))[:, None]
            w_dir[dk] = wd
            t[dk] = tt
        # Sphere: uniform cone of the visible cap (outside), uniform sphere inside.
        sk = (~z) & sph
        if np.any(sk):
            ms = np.nonzero(sk)[0]
            rs, ds = r[ms], d[ms]
            out_ = ds > rs
            sin2 = np.where(out_, (rs / np.maximum(ds, 1e-300)) ** 2, 1.0)
            one_minus_cos = np.where(out_, sin2 / (1.0 + np.sqrt(np.maximum(1.0 - sin2, 0.0))), 2.0)
            cosm = 1.0 - one_minus_cos
            loc = _cone_local(cosm, u1[m[ms]], u2[m[ms]])
            wd = _to_world(loc, -lightN[ms])
            # distance to the sphere along wd (nearest root outside, exit inside)
            b = _dot(wd, co[ms] - pc[ms])
            c = ds * ds - rs * rs
            disc = np.sqrt(np.maximum(b * b - c, 0.0))
            tt = np.where(out_, b - disc, b + disc)
            Lw[ms] = table.radiance[jj[ms]] * (2.0 * np.pi * one_minus_cos)[:, None]
            w_dir[ms] = wd
            t[ms] = np.maximum(tt, 0.0)
        if k == SPOT:
            # The cone along the sample's direction, as Cycles reads it.
            att = _spot_atten(table, jj, -w_dir)
            if np.any(sk):
                inside = sk & (d <= r)
                att = np.where(inside, 1.0, att)  # Cycles: no attenuation inside
            Lw *= att[:, None]
        if table.ies.shape[0]:
            # An IES profile along the direction leaving the light's sample.
            Lw *= IES.factors(table.ies, jj, -w_dir)[:, None]
        fill(m, w_dir, t, Lw)

    m = np.nonzero(kind == SUN)[0]
    if m.size:
        jj = j[m]
        axis = -table.dir[jj]                      # towards the sun
        h = table.half_angle[jj]
        w_dir = axis.copy()
        Lw = table.strength[jj].copy()             # angle 0: irradiance S
        c = h > 0
        if np.any(c):
            com = 1.0 - table.cos_half_angle[jj[c]]
            w_dir[c] = _to_world(_cone_local(table.cos_half_angle[jj[c]], u1[m[c]], u2[m[c]]),
                                 axis[c])
            Lw[c] = table.radiance[jj[c]] * (2.0 * np.pi * com)[:, None]
        fill(m, w_dir, np.full(m.size, np.inf), Lw)

    m = np.nonzero(kind == WORLD)[0]
    if m.size and table.environment is not None:
        fill(m, *_sample_environment(table.environment, u1[m], u2[m]))
    elif m.size:
        jj = j[m]
        if n is None:
            fill(m, _uniform_sphere(u1[m], u2[m]), np.full(m.size, np.inf),
                 table.strength[jj] * 4.0 * np.pi)
        else:
            nm = np.asarray(n, np.float64).reshape(-1, 3)[m]
            r = np.sqrt(u1[m])
            phi = 2.0 * np.pi * u2[m]
            cz = np.sqrt(np.maximum(1.0 - u1[m], 0.0))
            t, b = frame(nm)
            w = (t * (r * np.cos(phi))[:, None] + b * (r * np.sin(phi))[:, None]
                 + nm * cz[:, None])
            # weight = L / pdf with pdf = cos / pi; f*cos*weight = f * L * pi.
            fill(m, _normalize(w), np.full(m.size, np.inf),
                 table.strength[jj] * (np.pi / np.maximum(cz, 1e-12))[:, None])

    m = np.nonzero(kind == AREA)[0]
    if m.size:
        jj = j[m]
        ell = table.ellipse[jj]
        su = u1[m] - 0.5
        sv = u2[m] - 0.5
        if np.any(ell):
            x_, y_ = _unit_disk(u1[m], u2[m])
            su = np.where(ell, 0.5 * x_, su)
            sv = np.where(ell, 0.5 * y_, sv)
        # Uniform by area (ellipses, and rectangles seen under a tiny solid angle).
        q = (table.co[jj] + (su * table.len_u[jj])[:, None] * table.axis_u[jj]
             + (sv * table.len_v[jj])[:, None] * table.axis_v[jj])
        v = q - p[m]
        tt = np.linalg.norm(v, axis=1)
        wd = v / np.maximum(tt, 1e-300)[:, None]
        cosl = -_dot(wd, table.dir[jj])            # one-sided: emits along dir
        Lw = table.radiance[jj] * (table.area[jj] * np.maximum(cosl, 0.0)
                                   / np.maximum(tt * tt, 1e-300))[:, None]
        # Rectangles: uniform in solid angle (Urena et al. 2013), like Cycles;
        # L_e / pdf = L S for a receiver in front of the light.
        rect = np.nonzero(~ell)[0]
        if rect.size:
            jr = jj[rect]
            corner = (table.co[jr] - 0.5 * table.len_u[jr, None] * table.axis_u[jr]
                      - 0.5 * table.len_v[jr, None] * table.axis_v[jr])
            pr = p[m[rect]]
            # A spread: only the part its slats let through to pr.
            corner, lu, lv = spread_rect(table, jr, pr, corner, table.len_u[jr],
                                         table.len_v[jr])
            qs, S = _sample_spherical_rect(pr, corner, table.axis_u[jr], lu,
                                           table.axis_v[jr], lv, u1[m[rect]], u2[m[rect]])
            front = _dot(pr - table.co[jr], table.dir[jr]) > 0
            use = np.nonzero(S > 1e-6)[0]          # else: area sampling (float cancellation)
            if use.size:
                vr = qs[use] - pr[use]
                tr = np.linalg.norm(vr, axis=1)
                k = rect[use]
                wd[k] = vr / np.maximum(tr, 1e-300)[:, None]
                tt[k] = tr
                Lw[k] = table.radiance[jr[use]] * np.where(front[use], S[use], 0.0)[:, None]
        # A spread below 180 deg: its factor along the sampled direction.
        sp = np.nonzero(np.isfinite(table.spread_tan[jj]))[0]
        if sp.size:
            Lw[sp] *= spread_atten(table, jj[sp], -_dot(wd[sp], table.dir[jj[sp]]))[:, None]
        fill(m, wd, tt, Lw)

    m = np.nonzero(kind == MESH)[0]
    if m.size:
        jj = j[m]
        b1, b2 = _triangle_bary(u1[m], u2[m])
        p0, e1, e2 = table.co[jj], table.axis_u[jj], table.axis_v[jj]
        q = p0 + b1[:, None] * e1 + b2[:, None] * e2
        v = q - p[m]
        tt = np.linalg.norm(v, axis=1)
        wd = v / np.maximum(tt, 1e-300)[:, None]
        cosl = np.abs(_dot(wd, table.dir[jj]))     # two-sided
        geo = table.area[jj] * cosl / np.maximum(tt * tt, 1e-300)
        # Triangles seen under a solid angle > _SPH_TRI_MIN: uniform in solid
        # angle (Arvo 1995), as Cycles does for large triangles; L_e/pdf = L Omega.
        wsph, omega = _sample_spherical_tri(p[m], p0, p0 + e1, p0 + e2, u1[m], u2[m])
        sph = np.nonzero(omega > _SPH_TRI_MIN)[0]
        if sph.size:
            ws = wsph[sph]
            n = table.dir[jj[sph]]
            den = _dot(ws, n)
            ts = _dot(p0[sph] - p[m[sph]], n) / np.where(den != 0, den, 1e-300)
            qs = p[m[sph]] + ts[:, None] * ws
            # Barycentrics of the hit point (for the emission texture).
            r = qs - p0[sph]
            d00, d01, d11 = _dot(e1[sph], e1[sph]), _dot(e1[sph], e2[sph]), _dot(e2[sph], e2[sph])
            d20, d21 = _dot(r, e1[sph]), _dot(r, e2[sph])
            den2 = d00 * d11 - d01 * d01
            b1[sph] = (d11 * d20 - d01 * d21) / den2
            b2[sph] = (d00 * d21 - d01 * d20) / den2
            good = np.isfinite(ts) & (ts > 0)
            wd[sph] = ws
            tt[sph] = np.where(good, ts, 0.0)
            geo[sph] = np.where(good, omega[sph], 0.0)
        Le = _mesh_emission(table, jj, b1, b2)
        Lw = Le * geo[:, None]
        Lw[tt <= 0] = 0.0
        fill(m, wd, tt, Lw)
    return out
