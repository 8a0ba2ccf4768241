"""Photon emission: :func:`sample_photons` draws photons from the light table.

Photons carry ``power = Phi_light(sample) / p_select`` so that the SPPM
density estimate is tau / (pi R^2 N_emitted) (pbrt-v4).  Sun and world
photons start on a plane perpendicular to their direction, at distance R
(the scene's bounding sphere's radius) from the scene centre, over an area
A that covers every triangle (:func:`distant_footprint`: the smallest
rectangle bounding the triangles' box, or the sphere's disc), and carry
their light's flux through A: S A (sun) and 4 pi A L_w (world; the table's
flux counts the disc, S pi R^2 and 4 pi^2 R^2 L_w).  With an environment
map the direction follows the map's distribution (:mod:`.environment`) and
the power is A L(omega) / pdf(omega).

Point/spot lights with r > 0: Cycles' default soft falloff is a disc of
radiance L turned towards each receiver, so the irradiance is exactly
I cos / (d^2 + r^2) (its projected solid angle is pi r^2 / (d^2 + r^2) cos).
No physical emitter produces that field (it is not a light field), so photons
leave the centre and carry ``falloff_r2 = r^2``: the photon tracer multiplies
the power by t^2 / (t^2 + r^2) at the first hit (far field and first-hit field
then match Cycles, and the bounced light inherits it).  Without soft
falloff (sphere model) photons leave the sphere, Lambertian about its normal.

Each such photon also carries one sample y of the disc (``soft_disc``): at
its first hit p the tracer turns its direction into y -> p
(:func:`soft_light_first_hit`), because the light that reaches p comes from
the whole disc facing p, and a mirror or glass there sends it on in a cone
as wide as the disc seen from p (a caustic of a light with a radius is as
blurred in Cycles, whose rays from p hit that disc).  The photon's power is
multiplied there by Cycles' irradiance from the disc sample over the
centre's (1 on average).

A soft spot's cone: Cycles attenuates each disc sample y by the cone along
its own direction y -> p (``spot_light_sample``), which blurs the cone's edge
by the disc's angular size and lights a ring outside the centre's cone.  Its
photons therefore leave the centre without the cone's attenuation, drawn
from the centre's cone and, a share of them, from a tail beyond it that
reaches every direction whose first hit a disc sample's cone can light
(``LightTable.spot_tail``, :func:`spot_pdf_local`), and the factor above
carries the cone's attenuation along y -> p, whose mean over the disc turns
the centre's field I cos / (d^2 + r^2) into Cycles' (docs/integrators.md "A
soft spot's photons carry Cycles' cone, round 35").
"""
from __future__ import annotations

import numpy as np

from ..mathutil import frame
from . import ies as IES

from .table import (AREA, MESH, POINT, SPOT, SUN, WORLD, LightTable, _mesh_emission,
                    _smoothstep, _spot_atten, spread_atten)
from .warps import (_cone_local, _cosine_local, _to_world, _triangle_bary, _uniform_sphere,
                    _unit_disk)


# Angular variance of a cosine-weighted diffuse lobe, pi^2/4 - 2 = 0.467 rad^2
# (docs/frequency.md "Lobe widths"): the angular init of every non-collimated light.
B_DIFFUSE = np.pi ** 2 / 4.0 - 2.0
def spot_tail(table: LightTable) -> np.ndarray:
    """(Nl, 4) float64 ``LightTable.spot_tail``: a soft spot's tail beyond
    its cone (share, x0, X, half-angle), share 0 for every other light (a
    table built without a scene: the tail reaches the whole sphere)."""
    if table.spot_tail is None:                 # computed once, kept on the table
        from .table import _spot_tails
        table.spot_tail = _spot_tails(table, None)
    return table.spot_tail


def spot_pdf_local(tail, cos_h, cz) -> np.ndarray:
    """(K,) the density over local unit directions (solid angle in the
    light's frame) with which a spot's photons leave; tail (K, 4) its
    ``spot_tail`` rows (share P, x0, X, half-angle h), cos_h (K,) and
    cz = -v_z (K,) the local direction's cosine to the axis: (1 - P) uniform
    in the cone cos >= cos_h, and P over the angles x = theta - h in (0, X]
    beyond it with density 1 / (x0 A (1 + x / x0)^2) in x, A = 1 - 1 / (1 +
    X / x0) (``LightTable.spot_tail``), / (2 pi sin theta) in solid angle."""
    P, x0, X, h = tail[:, 0], tail[:, 1], tail[:, 2], tail[:, 3]
    inside = cz >= cos_h
    cone = np.where(inside, (1.0 - P) / (2.0 * np.pi * (1.0 - cos_h)), 0.0)
    th = np.arccos(np.clip(cz, -1.0, 1.0))
    x = th - h
    with np.errstate(divide="ignore", invalid="ignore"):
        A = 1.0 - 1.0 / (1.0 + X / x0)
        px = 1.0 / (x0 * A * (1.0 + x / x0) ** 2)
        t = P * px / (2.0 * np.pi * np.sin(th))
    return cone + np.where((P > 0) & ~inside & (x <= X) & np.isfinite(t), t, 0.0)


def spot_tail_sample(tail, u1, u2) -> np.ndarray:
    """(K, 3) local unit directions (axis +z) of the tail of :func:`spot_pdf_local`:
    x = x0 (1 / (1 - u1 A) - 1) (its density's inverse CDF), theta = h + x,
    phi = 2 pi u2."""
    x0, X, h = tail[:, 1], tail[:, 2], tail[:, 3]
    A = 1.0 - 1.0 / (1.0 + X / x0)
    th = h + np.minimum(x0 * (1.0 / (1.0 - u1 * A) - 1.0), X)
    s = np.sin(th)
    phi = 2.0 * np.pi * u2
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(th)], axis=1)


def soft_light_first_hit(table: LightTable, light, disc, d, t, ng):
    """(factor (K,), direction (K, 3)) of photons of the soft-falloff point
    and spot lights (``LightTable.soft_disc``) at their first hit: photons
    of rows light (K,) left the centre along unit d (K, 3) with the disc
    sample disc (K, 4) (xyz: the offset from the centre on the disc
    perpendicular to d, ``soft_disc``; column 3 a uniform that picks one of
    its turns) and hit p = c + t d (t (K,)) on a surface of geometric normal
    ng (K, 3).  With q = p - y = t d - y, Cycles' disc sample y gives p the
    irradiance L pi r^2 att(q) cos_l cos_p(y) / |q|^2 (cos_l = d . q / |q|,
    cos_p(y) at p towards y; att = 1 for a point light), whose mean over
    the disc without att is the centre's I cos_p(d) / (t^2 + r^2).

    factor multiplies the power beside t^2 / (t^2 + r^2): the ratio of the
    two, averaged over the four turns y_s of the sample, c +- (y - c),
    c +- d x (y - c) (each uniform on the disc: the mean stays unbiased;
    the cone's slope across the disc cancels, and its curvature but for its
    isotropic part).  direction is the one the photon arrives along, from
    the turn y_s picked with probability f_s / sum f (f_s its term): the
    light reaching p comes from the whole disc, so what a mirror or glass
    does with it next is Cycles' (a ray from p hits the disc facing p), and
    since the weight is the mean of the f_s the pair is unbiased for any
    direction-dependent use (E[mean f g(y_s) picked ~ f] = E[f g]).
    Every other light: factor 1, direction d."""
    light = np.asarray(light, np.int64)
    out = np.ones(light.shape[0])
    d_out = np.array(d, np.float64, copy=True)
    s = np.nonzero(table.soft_disc[light])[0]
    if s.size:
        ds, ts = d[s], t[s]
        dn = np.einsum("ki,ki->k", ng[s], ds)
        nf = -np.sign(dn)[:, None] * ng[s]          # faces where the photon came from
        r2 = table.radius[light[s]] ** 2
        spot = table.kind[light[s]] == SPOT
        y = disc[s, :3]
        turned = np.cross(ds, y)
        terms, dirs = [], []
        for off in (y, -y, turned, -turned):
            q = ts[:, None] * ds - off
            qq = np.einsum("ki,ki->k", q, q)
            qh = q / np.sqrt(np.maximum(qq, 1e-300))[:, None]
            cos_l = np.maximum(np.einsum("ki,ki->k", qh, ds), 0.0)
            cos_y = np.maximum(-np.einsum("ki,ki->k", nf, qh), 0.0)
            att = np.where(spot, _spot_atten(table, light[s], qh), 1.0)
            if table.ies.shape[0]:
                att = att * IES.factors(table.ies, light[s], qh)
            with np.errstate(divide="ignore", invalid="ignore"):
                f = att * cos_l * cos_y * (ts * ts + r2) / (np.maximum(qq, 1e-300) * np.abs(dn))
            terms.append(np.where(np.isfinite(f), f, 0.0))
            dirs.append(qh)
        F = np.stack(terms, axis=1)                 # (k, 4)
        tot = F.sum(axis=1)
        out[s] = 0.25 * tot
        # The turn whose cumulative share first exceeds the uniform.
        c = np.cumsum(F, axis=1)
        pick = np.minimum((c <= (disc[s, 3] * tot)[:, None]).sum(axis=1), 3)
        D = np.stack(dirs, axis=1)                  # (k, 4, 3)
        chosen = D[np.arange(s.size), pick]
        d_out[s] = np.where((tot > 0)[:, None], chosen, ds)
    return out, d_out


#: An environment map's photons emitted by environment_kernels.world_photons, a
#: constant world's by environment_kernels.constant_world_photons (off: the
#: numpy reference below; tests).
COMPILED_ENVIRONMENT = True
#: The photons of point, spot, area and untextured mesh lights emitted by
#: the compiled emission (sppm.photon_kernels.emit_lights, the same uniforms)
#: where the table also has emitters it does not cover (a world, a sun);
#: off: the numpy reference below (tests).
COMPILED_EMISSION = True


def distant_footprint(table: LightTable, w: np.ndarray, u1: np.ndarray, u2: np.ndarray):
    """Where the photons of a distant light (the world, a sun) of unit
    directions w (K, 3) start, and over what area: (origins (K, 3), areas
    (K,)).  Each photon starts on a plane
    perpendicular to w behind every triangle (at distance R, the bounding
    sphere's radius, back from its centre), uniformly over the smaller of

    - the smallest rectangle bounding the triangles' box seen along w
      (:func:`box_rectangle`; the box ``LightTable.triangle_box``), centred on
      the box's centre, from (2 u1 - 1, 2 u2 - 1);
    - the bounding sphere's disc, radius R, from ``_unit_disk(u1, u2)``.

    Either covers every triangle's projection, so a photon carrying A
    L(w) / pdf(w) (A its area) is an unbiased sample of the world's flux
    through the scene; the rectangle wastes fewer photons on scenes that
    are not round (an open floor under an HDRI: most directions see it at a
    slant).  A scene without triangles keeps the disc."""
    R = table.radius_scene
    o = np.empty(w.shape)
    area = np.full(w.shape[0], np.pi * R * R)
    box = table.triangle_box
    disc = np.ones(w.shape[0], bool)
    if box is not None:
        c, e = box
        r1, r2, h1, h2 = box_rectangle(w, e)
        rect = 4.0 * h1 * h2
        k = np.nonzero(rect < area)[0]
        C = table.center
        back = (c[0] - C[0]) * w[k, 0] + (c[1] - C[1]) * w[k, 1] + (c[2] - C[2]) * w[k, 2] + R
        o[k] = (c - back[:, None] * w[k] + ((2.0 * u1[k] - 1.0) * h1[k])[:, None] * r1[k]
                + ((2.0 * u2[k] - 1.0) * h2[k])[:, None] * r2[k])
        area[k] = rect[k]
        disc[k] = False
    d = np.nonzero(disc)[0]
    t1, t2 = frame(w[d])
    x, y = _unit_disk(u1[d], u2[d])
    o[d] = table.center - R * w[d] + R * (x[:, None] * t1 + y[:, None] * t2)
    return o, area


def box_rectangle(w: np.ndarray, e: np.ndarray):
    """The smallest rectangle bounding a box of half extents e (3,) (axis
    aligned) seen along unit directions w (K, 3): its unit axes t1, t2
    (K, 3) in the plane perpendicular to w and half sides h1, h2 (K,).
    The box projects to a convex polygon whose edges lie along the box
    axes' projections, and a convex polygon's smallest bounding rectangle
    has a side along one of its edges (Freeman & Shapira 1975), so the
    three rectangles with t1 along a projected axis are compared: h_a =
    sum_i |t_a,i| e_i.  ``environment_kernels.footprint`` computes the same
    in the same order."""
    K = w.shape[0]
    best = np.full(K, np.inf)
    t1, t2, h1, h2 = np.zeros((K, 3)), np.zeros((K, 3)), np.zeros(K), np.zeros(K)
    n2 = np.ones(K)
    for i in range(3):
        # v = a_i - (a_i . w) w, the axis' projection, and w x v, both of
        # length |v|: compared unnormalised (the area is ha hb / |v|^2)
        v = -w[:, i:i + 1] * w
        v[:, i] += 1.0
        m2 = v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2]
        b = np.cross(w, v)
        ha = np.abs(v[:, 0]) * e[0] + np.abs(v[:, 1]) * e[1] + np.abs(v[:, 2]) * e[2]
        hb = np.abs(b[:, 0]) * e[0] + np.abs(b[:, 1]) * e[1] + np.abs(b[:, 2]) * e[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            area = ha * hb / m2
        k = np.nonzero((m2 > 1e-18) & (area < best))[0]
        best[k] = area[k]
        t1[k], t2[k], h1[k], h2[k], n2[k] = v[k], b[k], ha[k], hb[k], m2[k]
    n = np.sqrt(n2)
    return t1 / n[:, None], t2 / n[:, None], h1 / n, h2 / n


def footprint_of(table: LightTable):
    """The table's ``environment_kernels.Footprint`` (:func:`distant_footprint`'s
    inputs, for the compiled world photons)."""
    from .environment_kernels import Footprint
    box = table.triangle_box
    c, e = (np.zeros(3), np.zeros(3)) if box is None else box
    return Footprint(np.ascontiguousarray(table.center, np.float64), float(table.radius_scene),
                     np.ascontiguousarray(c, np.float64), np.ascontiguousarray(e, np.float64),
                     box is not None)


def sample_photons(table: LightTable, n: int, rng: np.random.Generator) -> dict:
    """Emit n photons, choosing emitters with probability ``p_select``.

    Returns a dict of arrays:
      o (n, 3) float64 origin (exactly on area/mesh/sphere emitters: the
        caller offsets it), d (n, 3) unit direction,
      power (n, 3) float64 flux Phi(sample) / p_select: the SPPM estimate is
        tau / (pi R^2 N_emitted); zero for every photon if nothing emits,
      light (n,) int32 emitter row (-1 if nothing emits), kind (n,) int8,
      freq_init (n, 3) float64 spectrum (a, b, c) initial values
        (docs/frequency.md "Light inits"),
      falloff_r2 (n,) float64: r^2 of soft-falloff point/spot lights, else 0.
        At the photon's FIRST surface hit, at distance t from o, multiply its
        power by t^2 / (t^2 + r^2): this reproduces Cycles' soft-falloff near
        field I cos / (d^2 + r^2) exactly (a disc of radiance L facing the
        receiver has projected solid angle pi r^2 / (d^2 + r^2) cos),
      soft_disc (n, 4) float64: a soft-falloff point or spot light's disc
        sample (xyz) and the uniform that picks its turn (module doc; the
        first hit applies :func:`soft_light_first_hit`), else 0.
    """
    n = int(n)
    o = np.zeros((n, 3))
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    power = np.zeros((n, 3))
    freq = np.zeros((n, 3))
    light = np.full(n, -1, np.int32)
    kind = np.full(n, -1, np.int8)
    falloff = np.zeros(n)
    disc = np.zeros((n, 4))
    out = dict(o=o, d=d, power=power, light=light, kind=kind, freq_init=freq,
               falloff_r2=falloff, soft_disc=disc)
    if n == 0 or table.n == 0 or not np.any(table.p_select > 0):
        return out
    u = rng.random((n, 6))
    cdf = np.cumsum(table.p_select)
    j = np.searchsorted(cdf, u[:, 0] * cdf[-1], side="right")
    j = np.minimum(j, table.n - 1)
    # Guard: never land on a zero-probability row (float ties at the end).
    bad = table.p_select[j] <= 0
    if np.any(bad):
        j[bad] = int(np.nonzero(table.p_select > 0)[0][-1])
    light[:] = j
    kind[:] = table.kind[j]
    inv_p = 1.0 / table.p_select[j]
    R = table.radius_scene
    done = _compiled_rows(table, u, j, out) if COMPILED_EMISSION else np.zeros(n, bool)

    for k in (POINT, SPOT):
        m = np.nonzero((kind == k) & ~done)[0]
        if not m.size:
            continue
        jj = j[m]
        if k == POINT:
            w = _uniform_sphere(u[m, 3], u[m, 4])
            weight = table.strength[jj]          # Phi = 4 pi I, pdf 1/(4 pi)
        else:
            # Uniform in the local cone, mapped by the object matrix;
            # d omega = |det M| / |M v|^3 d v.  A soft spot's photons: a
            # share from its wide cone, the cone read at the first hit.
            cos_h = table.cos_half_spot[jj]
            tail = spot_tail(table)[jj]
            soft = tail[:, 0] > 0
            v = _cone_local(cos_h, u[m, 3], u[m, 4])
            beyond = np.nonzero(soft & (u[m, 5] < tail[:, 0]))[0]
            if beyond.size:
                v[beyond] = spot_tail_sample(tail[beyond], u[m[beyond], 3], u[m[beyond], 4])
            v[:, 2] = -v[:, 2]                   # local axis is -Z
            Mv = np.einsum("kij,kj->ki", table.lin[jj], v)
            nMv = np.linalg.norm(Mv, axis=1)
            w = Mv / nMv[:, None]
            jac = np.abs(np.linalg.det(table.lin[jj])) / nMv ** 3
            att = _smoothstep((-v[:, 2] - cos_h) * table.spot_smooth[jj])
            with np.errstate(divide="ignore"):
                f = np.where(soft, jac / spot_pdf_local(tail, cos_h, -v[:, 2]),
                             att * jac * 2.0 * np.pi * (1.0 - cos_h))
            weight = table.strength[jj] / (4.0 * np.pi) * f[:, None]
        if table.ies.shape[0]:
            # An IES profile along the photon's direction; a soft light's is
            # read along y -> p at the first hit (soft_light_first_hit).
            ies = IES.factors(table.ies, jj, w)
            weight = weight * np.where(table.soft_disc[jj], 1.0, ies)[:, None]
        # Sphere model (no soft falloff): origin on the sphere, Lambertian about
        # its normal.  For a given direction w such origins are uniform over
        # the disc perpendicular to w, lifted onto the hemisphere facing w.
        # Soft falloff (Cycles' default disc facing the receiver): from the
        # centre, with the first-hit factor t^2 / (t^2 + r^2) left to the caller.
        r = np.where(table.is_sphere[jj], table.radius[jj], 0.0)
        falloff[m] = np.where(table.is_sphere[jj], 0.0, table.radius[jj] ** 2)
        x, y = _unit_disk(u[m, 1], u[m, 2])
        t1, t2 = frame(w)
        lift = np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))
        off = (x[:, None] * t1 + y[:, None] * t2 + lift[:, None] * w) * r[:, None]
        o[m] = table.co[jj] + off
        d[m] = w
        # Soft falloff: the disc sample and, from u5 (a spot's share of it
        # left after choosing cone or tail), the uniform that picks its turn.
        sd = table.soft_disc[jj]
        if np.any(sd):
            rs = np.where(sd, table.radius[jj], 0.0)
            disc[m, :3] = (x[:, None] * t1 + y[:, None] * t2) * rs[:, None]
            u5 = u[m, 5]
            if k == SPOT:
                P = tail[:, 0]
                with np.errstate(divide="ignore", invalid="ignore"):
                    u5 = np.where(u5 < P, u5 / P, (u5 - P) / (1.0 - P))
            disc[m, 3] = np.where(sd, u5, 0.0)
        power[m] = weight * inv_p[m, None]
        freq[m] = (0.0, B_DIFFUSE, 0.0)

    m = np.nonzero((kind == AREA) & ~done)[0]
    if m.size:
        jj = j[m]
        ell = table.ellipse[jj]
        su = u[m, 1] - 0.5
        sv = u[m, 2] - 0.5
        if np.any(ell):
            x, y = _unit_disk(u[m, 1], u[m, 2])
            su = np.where(ell, 0.5 * x, su)
            sv = np.where(ell, 0.5 * y, sv)
        o[m] = (table.co[jj] + (su * table.len_u[jj])[:, None] * table.axis_u[jj]
                + (sv * table.len_v[jj])[:, None] * table.axis_v[jj])
        # A spread below 180 deg (half angle a): cosine-weighted inside the
        # cone only (Malley's disc of radius sin a, density cos / (pi sin^2 a)),
        # times the radiance's factor along the direction; the factor's mean
        # over the cone's cosine lobe is 1 / sin^2 a, so power flux f sin^2 a.
        s2 = table.spread_sin2[jj]
        loc = _cosine_local(u[m, 3], u[m, 4])
        if np.any(s2 < 1.0):
            loc[:, :2] *= np.sqrt(s2)[:, None]
            loc[:, 2] = np.sqrt(np.maximum(1.0 - loc[:, 0] ** 2 - loc[:, 1] ** 2, 0.0))
        d[m] = _to_world(loc, table.dir[jj])
        power[m] = table.flux[jj] * (inv_p[m] * spread_atten(table, jj, loc[:, 2]) * s2)[:, None]
        freq[m, 0] = table.area[jj] / 12.0       # width w = sqrt(area): w^2/12
        freq[m, 1] = B_DIFFUSE

    m = np.nonzero(kind == SUN)[0]
    if m.size:
        jj = j[m]
        axis = table.dir[jj]
        w = axis.copy()
        h = table.half_angle[jj]
        cone = h > 0
        if np.any(cone):
            mc = np.nonzero(cone)[0]
            w[mc] = _to_world(_cone_local(table.cos_half_angle[jj[mc]], u[m[mc], 3], u[m[mc], 4]),
                              axis[mc])
        # flux = S pi R^2: the photon's share of the area it crossed
        o[m], area = distant_footprint(table, w, u[m, 1], u[m, 2])
        d[m] = w
        power[m] = table.flux[jj] * (inv_p[m] * area / (np.pi * R * R))[:, None]
        freq[m, 0] = table.a_max
        freq[m, 1] = h * h / 3.0

    m = np.nonzero(kind == WORLD)[0]
    if m.size:
        jj = j[m]
        env = table.environment
        if env is None and COMPILED_ENVIRONMENT:
            from .environment_kernels import constant_world_photons
            constant_world_photons(u, m, footprint_of(table),
                                   np.ascontiguousarray(table.flux[jj[0]], np.float64),
                                   np.ascontiguousarray(inv_p[m]), o, d, power)
        elif env is None:
            w = _uniform_sphere(u[m, 3], u[m, 4])
            o[m], area = distant_footprint(table, w, u[m, 1], u[m, 2])
            # flux = L 4 pi (pi R^2): the photon's share of the area it crossed
            power[m] = table.flux[jj] * (inv_p[m] * area / (np.pi * R * R))[:, None]
            d[m] = w
        elif not COMPILED_ENVIRONMENT:
            # Towards the map by its distribution: the photon travels along
            # -omega and carries A L(omega) / pdf(omega), A its footprint's area.
            omega, pdf = env.sample(u[m, 3], u[m, 4])
            w = -omega
            o[m], area = distant_footprint(table, w, u[m, 1], u[m, 2])
            Lw = env.radiance(omega) * (area / np.maximum(pdf, 1e-300))[:, None]
            power[m] = np.where((pdf > 0)[:, None], Lw, 0.0) * inv_p[m, None]
            d[m] = w
        else:
            # The same photons, each in one compiled step (the numpy lines
            # above are its reference; imported here: register() imports
            # this module and must not load numba).
            from .environment_kernels import world_photons
            world_photons(env.kernel_data(), u, m, footprint_of(table),
                          np.ascontiguousarray(inv_p[m]), o, d, power)
        freq[m] = (table.a_max, B_DIFFUSE, 0.0)

    m = np.nonzero((kind == MESH) & ~done)[0]
    if m.size:
        jj = j[m]
        b1, b2 = _triangle_bary(u[m, 1], u[m, 2])
        o[m] = table.co[jj] + b1[:, None] * table.axis_u[jj] + b2[:, None] * table.axis_v[jj]
        side = np.where(u[m, 5] < 0.5, 1.0, -1.0)
        n_side = table.dir[jj] * side[:, None]
        d[m] = _to_world(_cosine_local(u[m, 3], u[m, 4]), n_side)
        Le = _mesh_emission(table, jj, b1, b2)
        power[m] = (2.0 * np.pi * table.area[jj])[:, None] * Le * inv_p[m, None]
        freq[m, 0] = table.area[jj] / 12.0
        freq[m, 1] = B_DIFFUSE
    return out


def _compiled_rows(table: LightTable, u, j, out) -> np.ndarray:
    """Fill the rows of ``out`` (:func:`sample_photons`' dict) whose emitter
    the compiled emission covers (point, spot, area, untextured mesh:
    sppm.photon_kernels.emit_lights on those rows' uniforms, which choose
    the same emitter j) and return them as an (n,) bool mask; the caller
    emits the others (sun, world, textured mesh).  Imported here: register()
    imports this module and must not load numba."""
    k = table.kind[j]
    tex = np.asarray(table.tex)[j] if table.tex is not None else np.full(j.shape, -1)
    done = (k == POINT) | (k == SPOT) | (k == AREA) | ((k == MESH) & (tex < 0))
    m = np.nonzero(done)[0]
    if m.size:
        from ..sppm.photon_kernels import emit_lights, light_arrays
        K = m.size
        o, d, pw, fr = np.empty((K, 3)), np.empty((K, 3)), np.empty((K, 3)), np.empty((K, 3))
        fall, disc, rows = np.empty(K), np.empty((K, 4)), np.empty(K, np.int64)
        emit_lights(np.ascontiguousarray(u[m]), *light_arrays(table), o, d, pw, fall, fr, rows,
                    disc)
        out["o"][m], out["d"][m], out["power"][m] = o, d, pw
        out["falloff_r2"][m], out["freq_init"][m], out["soft_disc"][m] = fall, fr, disc
    return done
