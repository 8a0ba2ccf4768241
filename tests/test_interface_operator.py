"""The interface operator (refraction and oblique reflection at a curved
surface, docs/frequency.md "Refraction and oblique incidence") against
brute-force ray bundles.

A point source at distance s sends a thin bundle (+-1e-5 rad) to a point of a
cylinder or a sphere; each ray is intersected with the exact surface,
reflected or refracted by Snell's law, and the focus is where a neighbour
ray meets the central one (distance along the central outgoing ray; < 0 a
virtual focus).  The spectrum chain travel(s) -> onto_surface(cos_i) ->
interface -> off_surface(cos_t) puts the focus at -c/b.  Coddington's
equations are the closed forms both should reproduce.
"""
import numpy as np
import pytest

from core.frequency import spectrum as F
from core.frequency.curvature import Curvature, bounce_interface


# ------------------------------------------------------------ brute force
def _hit(o, d, shape, R, inside):
    """Nearest hit t > 1e-9 of the ray o + t d with a cylinder (axis y) or a
    sphere of radius R centred at 0; the normal there facing the ray."""
    q = o.copy()
    dd = d.copy()
    if shape == "cylinder":
        q[1] = 0.0
        dd[1] = 0.0
    A = dd @ dd
    B = 2.0 * (q @ dd)
    C = q @ q - R * R
    disc = np.sqrt(B * B - 4 * A * C)
    ts = sorted([(-B - disc) / (2 * A), (-B + disc) / (2 * A)])
    t = [x for x in ts if x > 1e-9][0]
    p = o + t * d
    n = p.copy()
    if shape == "cylinder":
        n[1] = 0.0
    n /= np.linalg.norm(n)
    if n @ d > 0:
        n = -n
    return p, n


def _scatter(d, n, eta):
    """Mirror reflection (eta None) or refraction n_i/n_t = eta of direction d
    at normal n (n . d < 0)."""
    ci = -(n @ d)
    if eta is None:
        return d + 2 * ci * n
    k = 1 - eta * eta * (1 - ci * ci)
    return eta * d + (eta * ci - np.sqrt(k)) * n


def _trace(o, d, shape, R, etas):
    """Trace through len(etas) interfaces; returns the last (point, direction)."""
    for eta in etas:
        p, n = _hit(o, d, shape, R, False)
        d = _scatter(d, n, eta)
        o = p
    return o, d


def _focus(src, d0, axis, shape, R, etas, eps=1e-5):
    """Distance from the last hit of the central ray to where the rays of a
    bundle tilted by +-eps about `axis` meet it (closest approach)."""
    def rot(v, ang):
        k = axis / np.linalg.norm(axis)
        return (v * np.cos(ang) + np.cross(k, v) * np.sin(ang)
                + k * (k @ v) * (1 - np.cos(ang)))
    P0, w0 = _trace(src, d0, shape, R, etas)
    ts = []
    for e in (eps, -eps):
        P1, w1 = _trace(src, rot(d0, e), shape, R, etas)
        # closest point of line (P1, w1) to line (P0, w0), parameter along w0
        r = P1 - P0
        b = w0 @ w1
        den = 1 - b * b
        ts.append(((r @ w0) - b * (r @ w1)) / den)
    return float(np.mean(ts)), P0, w0


# ------------------------------------------------------------ spectrum chain
def _chain_focus(s, steps):
    """-c/b after a point source travels s and meets `steps`: a list of
    (cos_i, cos_t, eta or None for a mirror, kappa_t, kappa_s, travel after)."""
    q = F.travel(F.light_init("POINT", 1), s)
    for ci, ct, eta, kt, ks, d_after in steps:
        refl = eta is None
        sc, mu, k = F.interface_map(ci, ct, -1.0 if refl else eta, kt, ks, 0.0, refl)
        q = F.off_surface(F.interface(F.onto_surface(q, ci), sc, mu, k), ct)
        if d_after:
            q = F.travel(q, d_after)
    a, b, c = q[0]
    return -c / b


def _oblique(theta, plane, up=False):
    """Incident direction at angle theta to the normal at (0, 0, R), going
    down (from outside) or up (from inside the cylinder), in the curved x-z
    plane of a cylinder (tangential) or the y-z plane containing its axis
    (sagittal); returns (d0, rotation axis of the bundle)."""
    z = 1.0 if up else -1.0
    if plane == "tangential":
        d0 = np.array([np.sin(theta), 0.0, z * np.cos(theta)])
        return d0, np.array([0.0, 1.0, 0.0])
    d0 = np.array([0.0, np.sin(theta), z * np.cos(theta)])
    return d0, np.cross(d0, np.array([1.0, 0.0, 0.0]))


@pytest.mark.parametrize("deg", [0, 30, 60])
@pytest.mark.parametrize("plane", ["tangential", "sagittal"])
def test_concave_cylindrical_mirror_at_oblique_incidence(deg, plane):
    """A concave cylindrical mirror (R = 0.5 m, seen from inside) lit from
    2 m: the spectrum's focus matches the traced bundle within 1 %, and
    Coddington's 1/s + 1/s' = 2/(R cos) (tangential) or 2 cos/R (sagittal).
    The former chain (off_surface, then k = 2 kappa in the outgoing frame)
    was right only at 0 deg: it gives 0.286 m at any angle, for 0.133 m (60 deg,
    tangential) and 0.667 m (60 deg, sagittal)."""
    R, s = 0.5, 2.0
    th = np.radians(deg)
    d0, ax = _oblique(th, plane, up=True)
    # the source lies outside the cylinder: the rays start inside, near the wall
    brute = _focus_from_source(np.array([0.0, 0.0, R]) - s * d0, d0, ax, R)
    kt, ks = (-1 / R, 0.0) if plane == "tangential" else (0.0, -1 / R)
    ours = _chain_focus(s, [(np.cos(th), np.cos(th), None, kt, ks, 0.0)])
    power = 2 / (R * np.cos(th)) if plane == "tangential" else 2 * np.cos(th) / R
    coddington = 1 / (power - 1 / s)
    assert brute == pytest.approx(coddington, rel=1e-3)
    assert ours == pytest.approx(brute, rel=0.01)


def _focus_from_source(src, d0, ax, R):
    """The focus of a bundle from src reflected by the inside of the
    cylinder wall at (0, 0, R) (src may lie outside the cylinder: each ray
    starts 1 mm before the wall)."""
    P = np.array([0.0, 0.0, R])
    s = np.linalg.norm(P - src)

    def rot(v, ang):
        k = ax / np.linalg.norm(ax)
        return (v * np.cos(ang) + np.cross(k, v) * np.sin(ang)
                + k * (k @ v) * (1 - np.cos(ang)))
    w0 = _scatter(d0, np.array([0.0, 0.0, -1.0]), None)
    ts = []
    for e in (1e-5, -1e-5):
        d = rot(d0, e)
        # start 1 mm before the wall along the tilted ray: inside the cylinder
        t_near = (s - 1e-3)
        p, n = _hit(src + t_near * d, d, "cylinder", R, True)
        w1 = _scatter(d, n, None)
        r = p - P
        b = w0 @ w1
        ts.append(((r @ w0) - b * (r @ w1)) / (1 - b * b))
    return float(np.mean(ts))


@pytest.mark.parametrize("deg", [0, 30, 60])
def test_refraction_into_a_glass_cylinder(deg):
    """A point 3 m from a glass cylinder (R = 0.5 m, n = 1.5) at 0/30/60 deg:
    the focus inside the glass matches the traced bundle within 1 % and
    Coddington's tangential n cos_t^2/s' = (n cos_t - cos_i)/R - cos_i^2/s.
    The mirror factor the renderer used before (k = 2 kappa, no angle
    scaling) made the convex glass diverge (a virtual focus 0.23 m before
    the surface at 0 deg) instead of focusing 2.25 m inside."""
    R, s, n = 0.5, 3.0, 1.5
    th = np.radians(deg)
    d0, ax = _oblique(th, "tangential")
    src = np.array([0.0, 0.0, R]) - s * d0
    brute, _, _ = _focus(src, d0, ax, "cylinder", R, [1 / n])
    ct = np.sqrt(1 - (np.sin(th) / n) ** 2)
    ours = _chain_focus(s, [(np.cos(th), ct, 1 / n, 1 / R, 0.0, 0.0)])
    coddington = n * ct * ct / ((n * ct - np.cos(th)) / R - np.cos(th) ** 2 / s)
    assert brute == pytest.approx(coddington, rel=1e-3)
    assert ours == pytest.approx(brute, rel=0.01)
    old = F.curvature(F.off_surface(F.onto_surface(F.travel(F.light_init("POINT", 1), s),
                                                   np.cos(th)), ct), 1 / R)
    assert -old[0, 2] / old[0, 1] < 0 < brute


@pytest.mark.parametrize("h", [0.0, 0.3, 0.6])
def test_ball_lens(h):
    """A glass sphere (R = 0.5 m, n = 1.5) lit from 50 m, rays at height h R
    off the axis: focus behind the sphere within 2 % of the traced bundle
    (meridional plane, two refractions and the chord 2 R cos_t between).
    On the axis the paraxial back focal length is R (2 - n) / (2 (n - 1)) =
    0.25 m (0.261 m for a source at 50 m)."""
    R, s, n = 0.5, 50.0, 1.5
    th1 = np.arcsin(h)
    d0 = np.array([np.sin(th1), 0.0, -np.cos(th1)])
    P = np.array([0.0, 0.0, R])
    src = P - s * d0
    brute, _, _ = _focus(src, d0, np.array([0.0, 1.0, 0.0]), "sphere", R, [1 / n, n])
    c1 = np.cos(th1)
    ct = np.sqrt(1 - (np.sin(th1) / n) ** 2)
    ours = _chain_focus(s, [(c1, ct, 1 / n, 1 / R, 1 / R, 2 * R * ct),
                            (ct, c1, n, -1 / R, -1 / R, 0.0)])
    if h == 0.0:     # thick ball lens: f = n R / (2 (n - 1)) from the centre
        f = n * R / (2 * (n - 1))
        assert brute == pytest.approx(1 / (1 / f - 1 / (s + R)) - R, rel=1e-3)
    assert ours == pytest.approx(brute, rel=0.02)


def test_interface_keeps_the_determinant_ratio_and_psd():
    """(u, theta) -> (s u, mu theta + k u) multiplies det Q by (s mu)^2 and
    keeps Q PSD; scale = mu = 1 is the old curvature operator bit for bit."""
    rng = np.random.default_rng(0)
    L = rng.normal(size=(200, 2, 2)) * 0.15
    Q = L @ np.swapaxes(L, 1, 2)
    s = np.stack([Q[:, 0, 0], Q[:, 1, 1], Q[:, 0, 1]], axis=1)
    s = F.sanitize(s)
    sc, mu, k = rng.uniform(0.5, 1.5, 200), rng.uniform(0.5, 1.2, 200), rng.normal(size=200)
    out = F.interface(s, sc, mu, k)
    assert F.is_psd(out).all()
    M = np.zeros((200, 2, 2))
    M[:, 0, 0], M[:, 1, 0], M[:, 1, 1] = sc, k, mu
    Qe = M @ Q @ np.swapaxes(M, 1, 2)
    ok = Qe[:, 1, 1] <= F.B_CAP
    assert np.allclose(out[ok], np.stack([Qe[ok, 0, 0], Qe[ok, 1, 1], Qe[ok, 0, 1]], 1),
                       rtol=1e-9, atol=1e-12)
    assert np.array_equal(F.interface(s, 1.0, 1.0, 2.0 * k), F.curvature(s, k))


def test_bounce_interface_picks_the_focusing_axis():
    """At a delta bounce the plane of incidence decides the axis.  The ring of
    ring_lambert (cylinder wall, axis z, k1 = 1/R around it) lit from above
    by a steep photon: the plane of incidence contains the axis, so the
    curved direction is sagittal, k = 2 kappa cos_i^2 in surface units (the
    tangential 2 kappa / cos_i per unit of beam width would bend 7x as much
    at cos_i = 0.37).  A photon entering a glass sphere:
    refraction with eta = 1/1.5.  The compiled twin agrees to 1e-12."""
    from core.frequency import kernels as FK
    cv = Curvature(np.array([2.0, 1 / 0.35]), np.array([0.0, 1 / 0.35]),
                   np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    d_in = np.array([[0.4, 0.0, -1.0], [0.3, 0.0, -1.0]])
    d_in /= np.linalg.norm(d_in, axis=1)[:, None]
    ng = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    d_out = np.array([d_in[0] - 2 * d_in[0, 0] * ng[0],
                      _scatter(d_in[1], ng[1], 1 / 1.5)])
    sign = np.array([-1.0, 1.0])         # inside the ring: concave; outside the sphere: convex
    sc, mu, k = bounce_interface(cv, np.array([0, 1]), sign, ng, d_in, d_out,
                                 np.array([1.0, 1.5]))
    ci = abs(d_in[0, 0])
    assert (sc[0], mu[0]) == (1.0, 1.0) and k[0] == pytest.approx(2 * -2.0 * ci * ci)
    ci1, ct1 = abs(d_in[1, 2]), abs(d_out[1, 2])
    assert mu[1] == pytest.approx(ci1 / (1.5 * ct1)) and sc[1] == 1.0
    assert k[1] == pytest.approx((ci1 / 1.5 - ct1) / 0.35 / ct1)
    rng = np.random.default_rng(5)
    n = 300
    cv = Curvature(rng.normal(size=n), rng.normal(size=n), rng.normal(size=(n, 3)))
    ng = rng.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1)[:, None]
    d_in, d_out = rng.normal(size=(2, n, 3))
    sign = rng.choice([-1.0, 1.0], n)
    ior = rng.uniform(1.0, 2.0, n)
    want = np.stack(bounce_interface(cv, np.arange(n), sign, ng, d_in, d_out, ior), 1)
    got = np.array([FK.bounce_interface(cv.k1[i], cv.k2[i], *cv.e1[i], sign[i], *ng[i],
                                        *d_in[i], *d_out[i], ior[i]) for i in range(n)])
    assert np.allclose(got, want, rtol=1e-12, atol=1e-15)


def _foci_inside_cylinder(src, d0, R, eps=1e-6):
    """Astigmatic focal distances (ascending) of a bundle from src reflected
    by the inside of the cylinder (axis y) where the central ray d0 meets
    it: the t where the 2x2 map (initial tilt -> transverse offset at
    distance t along the outgoing central ray) is singular."""
    def start(d):
        # src lies outside: the ray enters, crosses the inside, and is
        # reflected where it would leave (the far root)
        p, n = _hit(src, d, "cylinder", R, False)
        return _hit(p + 1e-6 * d, d, "cylinder", R, False)
    P0, n0 = start(d0)
    w0 = _scatter(d0, n0, None)
    u1 = np.cross(d0, [0.0, 0.0, 1.0])
    u1 /= np.linalg.norm(u1)
    u2 = np.cross(d0, u1)
    v1 = np.cross(w0, u1)
    v1 /= np.linalg.norm(v1)
    v2 = np.cross(w0, v1)
    A, B = np.zeros((2, 2)), np.zeros((2, 2))
    for j, u in enumerate((u1, u2)):
        d = d0 + eps * u
        d /= np.linalg.norm(d)
        p, n = start(d)
        w = _scatter(d, n, None)
        q = p + w * ((P0 - p) @ w0) / (w @ w0)
        A[:, j] = [(q - P0) @ v1 / eps, (q - P0) @ v2 / eps]
        B[:, j] = [(w - w0) @ v1 / eps, (w - w0) @ v2 / eps]
    return np.sort(-np.linalg.eigvals(np.linalg.solve(B, A)).real), P0, w0


@pytest.mark.parametrize("d0", [(0.5, 0.6, 1.0), (0.0, 1.0, 0.8), (0.9, 0.3, 1.0)])
def test_oblique_plane_of_incidence_on_a_cylinder_mirror(d0):
    """A concave cylinder (R = 0.5 m) lit from 2 m along a direction that is
    neither in its curved plane nor along its axis: the plane of incidence
    is oblique to the principal directions.  bounce_interface (Euler's
    normal curvatures plus the twist, most focusing eigenvalue) puts the
    spectrum's focus on the nearer astigmatic focus of the traced bundle
    within 1 %.  Without the twist (tau = 0) it was the farther one or
    beyond it: 0.63 m for 0.29 m at (0.5, 0.6, 1)."""
    R, s = 0.5, 2.0
    d0 = np.asarray(d0, float) / np.linalg.norm(d0)
    P = np.array([0.0, 0.0, R])
    # aim the central ray at P from inside: the source is 2 m back along d0
    foci, P0, w0 = _foci_inside_cylinder(P - s * d0, d0, R)
    assert np.allclose(P0, P, atol=1e-9)
    cv = Curvature(np.array([1 / R]), np.array([0.0]), np.array([[1.0, 0.0, 0.0]]))
    ng = np.array([[0.0, 0.0, 1.0]])          # outward; the photon arrives from inside
    sc, mu, k = bounce_interface(cv, np.array([0]), np.array([-1.0]), ng, d0[None], w0[None],
                                 np.array([1.0]))
    ci = abs(d0[2])
    q = F.travel(F.light_init("POINT", 1), s)
    q = F.off_surface(F.interface(F.onto_surface(q, ci), sc, mu, k), ci)
    ours = -q[0, 2] / q[0, 1]
    near = foci[foci > 0].min()
    assert ours == pytest.approx(near, rel=0.01)


def test_ball_lens_of_glass_sphere_foci_and_the_axis_the_chain_keeps():
    """glass_sphere.blend's geometry in the meridional plane
    (bench/diag_ball_lens.py; docs/frequency.md "A ball lens: the glass
    sphere's focus"): spot 2.809 m from a ball R = 0.35 m, n = 1.5, the
    renderer's spot init (0, 0.467, 0).  For every zone the spectrum's focus
    -c/b after both refractions is the traced one: tangential where
    neighbouring heights meet, sagittal where the ray crosses the axis
    (measured: equal to 1e-4 m).  On the floor (0.480 m past the centre
    on the axis) the fold (zone 0.5 R, 32.4 mm off the axis) is a
    tangential focus: r_x 2.0 mm on the kept axis; the axial core (zone
    0.79 R) is a sagittal one: r_x 51 mm on the tangential axis the
    renderer keeps, 0.2 mm on the sagittal one."""
    import os
    import sys
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bench"))
    import diag_ball_lens as D
    rows = {round(r[0], 2): r for r in D.flatland()}
    f = D.IOR * D.RADIUS / (2 * (D.IOR - 1))
    paraxial = 1 / (1 / f - 1 / D.L) - D.RADIUS                   # closed form, from the exit
    assert rows[0.05][3] == pytest.approx(paraxial, abs=3e-3)       # zone 0.05 R is near paraxial
    for hr, y, t_axis, t_tan, f_t, f_s, t_floor, r_t, r_s in rows.values():
        assert f_t == pytest.approx(t_tan, abs=1e-4)
        assert f_s == pytest.approx(t_axis, abs=1e-4)
    fold, core = rows[0.5], rows[0.79]
    assert fold[1] == pytest.approx(0.0324, abs=5e-4) and fold[7] < 3e-3
    assert abs(core[1]) < 1e-3
    assert core[7] == pytest.approx(0.0506, rel=0.05) and core[8] < 1e-3
