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
        sc, mu, k = F.interface_map(ci, ct, -1.0 if refl else eta, kt, ks, refl)
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
    scaling) put a diverging virtual image at -0.52 m (0 deg) instead of a
    focus 4.5 m inside."""
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
