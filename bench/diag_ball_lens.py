"""The glass sphere's focus: what the frequency chain predicts there, and why
(docs/frequency.md "A ball lens: the glass sphere's focus").

    .venv/bin/python bench/diag_ball_lens.py             # flatland chain, seconds
    .venv/bin/python bench/diag_ball_lens.py --render    # + the renderer's deposits and pixels, 128x128

Flatland part (numpy only): glass_sphere.blend's geometry in the meridional
plane of the spot's axis (spot at 2.809 m from the centre of a ball R = 0.35 m,
n = 1.5; the floor crosses the axis 0.4796 m past the centre at cos 0.7298).
For each zone (ray height h at the sphere) the exact ray is traced with Snell's
law, and the spectrum of core/frequency/spectrum.py is carried along it with
the renderer's chain (travel, onto, interface, off, travel, onto, interface,
off, travel, onto the floor), once with the tangential (s, mu, k) of
spectrum.interface_map and once with the sagittal one.  Printed: where the
ray lands (across the axis, in the plane perpendicular to the axis at the
floor's axial distance), its axis crossing (the sagittal focus of a
rotationally symmetric system), the tangential focus where neighbouring rays
of the zone meet, the spectrum's focus -c/b of each axis, and r_x on the floor
for each axis.

--render: the renderer at 128x128 (the file's photons), one pass, then one
trace of --photons frequency photons with every deposit's radius (no radius
cut): the predicted radius of the floor's deposits that went through the
sphere (bounce 2) by distance from the axis' floor point; then --passes
passes of seed 0 and, per pixel near the focus, the image, r_pred_last / R,
held and R.
"""
from __future__ import annotations

import argparse
import os
import sys

if "numba" not in sys.modules:
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("FPPM_PHOTON_THREADS", "1")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
from core.frequency import spectrum as S  # noqa: E402

# glass_sphere.blend (example_blends/make_examples.py): spot at (-1.5, 1.2, 2.4)
# aimed at the centre (0, 0, 0.35) of a ball R = 0.35, IOR 1.5; floor z = 0.
SPOT = np.array([-1.5, 1.2, 2.4])
CENTRE = np.array([0.0, 0.0, 0.35])
RADIUS, IOR = 0.35, 1.5
AXIS = (CENTRE - SPOT) / np.linalg.norm(CENTRE - SPOT)
L = float(np.linalg.norm(CENTRE - SPOT))
COS_FLOOR = float(-AXIS[2])
T_FLOOR = CENTRE[2] / COS_FLOOR                  # centre -> floor along the axis [m]
FOCUS_POINT = CENTRE + T_FLOOR * AXIS            # the axis' floor point


def _refract(d, nrm, eta):
    ci = -d @ nrm
    ct = np.sqrt(1.0 - eta * eta * (1.0 - ci * ci))
    return eta * d + (eta * ci - ct) * nrm, ci, ct


def trace(phi):
    """The exact meridional ray leaving the spot at angle phi to the axis."""
    d = np.array([np.cos(phi), np.sin(phi)])
    C = np.array([L, 0.0])
    b = d @ -C
    t1 = -b - np.sqrt(b * b - (C @ C - RADIUS ** 2))
    p1 = t1 * d
    d2, ci1, ct1 = _refract(d, (p1 - C) / RADIUS, 1.0 / IOR)
    t2 = -2.0 * d2 @ (p1 - C)
    p2 = p1 + t2 * d2
    d3, ci2, ct2 = _refract(d2, -(p2 - C) / RADIUS, IOR)
    return dict(t1=t1, ci1=ci1, ct1=ct1, t2=t2, p2=p2, ci2=ci2, ct2=ct2, d3=d3)


def _map(axis, ci, ct, eta, kappa):
    """(scale, mu, k) of one axis (spectrum.interface_map's two branches, no twist)."""
    g = eta * ci - ct
    if axis == "t":
        return 1.0, eta * ci / ct, g * kappa / ct
    return ci / ct, eta, g * kappa * ci


def chain(phi, axis, init=(0.0, S.B_DIFFUSE, 0.0)):
    """Spectrum (1, 3) leaving the sphere along the ray phi; init: the renderer's spot init."""
    r = trace(phi)
    s = np.array([init], np.float64)
    s = S.travel(s, r["t1"])
    s = S.onto_surface(s, r["ci1"])
    s = S.interface(s, *_map(axis, r["ci1"], r["ct1"], 1.0 / IOR, 1.0 / RADIUS))
    s = S.off_surface(s, r["ct1"])
    s = S.travel(s, r["t2"])
    s = S.onto_surface(s, r["ci2"])
    s = S.interface(s, *_map(axis, r["ci2"], r["ct2"], IOR, -1.0 / RADIUS))
    return S.off_surface(s, r["ct2"]), r


def flatland(zones=(0.05, 0.2, 0.4, 0.5, 0.6, 0.7, 0.75, 0.79, 0.8, 0.85, 0.9)):
    xf = L + T_FLOOR
    f = IOR * RADIUS / (2.0 * (IOR - 1.0))
    print(f"# spot {L:.4f} m from the centre; floor on the axis {T_FLOOR:.4f} m past it (cos {COS_FLOOR:.4f}); "
          f"ball lens f = nR/(2(n-1)) = {f:.4f} m, paraxial image 1/(1/f - 1/L) = {1 / (1 / f - 1 / L):.4f} m "
          f"from the centre")
    print("#  h/R  lands [m]  axis crossing  tangential focus | spectrum -c/b tang / sag  to floor | r_x tang / sag [m]"
          "   (distances from the exit point)")
    rows = []
    for hr in zones:
        phi = np.arcsin(hr * RADIUS / L)
        r = trace(phi)
        p, d = r["p2"], r["d3"]
        t_floor = (xf - p[0]) / d[0]
        y = p[1] + t_floor * d[1]
        t_axis = -p[1] / d[1]
        r2 = trace(phi + 1e-7)
        t_tan = np.linalg.solve(np.array([d, -r2["d3"]]).T, r2["p2"] - p)[0]
        out = []
        for ax in "ts":
            s, _ = chain(phi, ax)
            sf = S.onto_surface(S.travel(s, t_floor), COS_FLOOR)
            out.append((-s[0, 2] / s[0, 1], float(S.predicted_radius(sf, np.inf, np.inf)[0])))
        rows.append((hr, y, t_axis, t_tan, out[0][0], out[1][0], t_floor, out[0][1], out[1][1]))
        print(f"  {hr:4.2f}  {y:+.4f}   {t_axis:8.4f}      {t_tan:8.4f}      | {out[0][0]:8.4f} / {out[1][0]:8.4f}"
              f"  {t_floor:7.4f} | {out[0][1]:.4f} / {out[1][1]:.4f}")
    return rows


def render(photons, passes):
    import bench_hold_alpha as B
    from fppm.core.render import Renderer
    scene, base = B.export("glass_sphere", 100)
    r = Renderer(scene, base.replace(max_passes=passes, seed=0), log=lambda s: None)
    r.step()
    r.tracer.radius_cut = np.inf
    r.tracer.freq_deposits = 0
    dep = r.tracer.trace(photons, photons, np.random.default_rng(5))
    p, rr, bo = dep["p"], S.radius_from_fold_key(dep["rpred"]), dep["bounce"]
    m0 = (np.abs(p[:, 2]) < 1e-4) & np.isfinite(dep["rpred"]) & (bo == 2)
    dist = np.linalg.norm(p - FOCUS_POINT, axis=1)
    print(f"# {photons} frequency photons: {m0.sum()} floor deposits through the sphere (bounce 2)")
    for lo, hi in [(0, .01), (.01, .02), (.02, .03), (.03, .04), (.04, .06), (.06, .1), (.1, .2), (.2, .4)]:
        m = m0 & (dist >= lo) & (dist < hi)
        if m.any():
            q = np.quantile(rr[m], [.1, .5, .9])
            print(f"  [{lo:.2f}, {hi:.2f}) m: {m.sum():5d} deposits, r q10/50/90 {q[0]:.4f} / {q[1]:.4f} / {q[2]:.4f} m")
    for _ in range(passes - 1):
        img = np.asarray(r.step().image[..., :3], np.float64).mean(axis=2)
    vp = r.camera_pass(r._rng(r.pass_index, 0), r._check_stop)[0]
    R = np.sqrt(r.state.R2)
    rp = np.asarray(r.state.r_pred_last)
    held = np.asarray(r.state.held)
    H, W = img.shape
    dist = np.linalg.norm(vp.p - FOCUS_POINT, axis=1)
    floor = vp.valid & (np.abs(vp.p[:, 2]) < 1e-3) & ~vp.through_delta
    g = img.ravel()
    print(f"# pass {passes}, seed 0: floor pixels seen directly, by distance of the visible point from the axis' floor point")
    for lo, hi in [(0, .04), (.04, .06), (.06, .1), (.1, .2), (.2, .4)]:
        m = floor & (dist >= lo) & (dist < hi)
        f = m & np.isfinite(rp)
        if m.any():
            print(f"  [{lo:.2f}, {hi:.2f}) m: {m.sum():4d} px, image median {np.median(g[m]):7.3f}, R median "
                  f"{np.median(R[m]) * 100:.2f} cm, r_pred/R median {np.median(rp[f] / R[f]) if f.any() else np.nan:.2f}, "
                  f"held {held[m].mean():.2f}")
    y0, x0 = divmod(int(np.argmax(g)), W)
    ys, xs = range(max(y0 - 4, 0), min(y0 + 5, H)), range(max(x0 - 6, 0), min(x0 + 8, W))
    print(f"# around the brightest pixel ({y0}, {x0}); columns {xs.start}..{xs.stop - 1}")
    for name, A, fmt in (("image", g, "{:6.2f}"), ("r_pred/R", rp / R, "{:6.2f}"),
                         ("held", held.astype(float), "{:6.0f}"), ("R [cm]", R * 100, "{:6.2f}")):
        print(name)
        A = A.reshape(H, W)
        for yy in ys:
            print(f"{yy:4d} " + " ".join(fmt.format(A[yy, xx]) for xx in xs))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--render", action="store_true")
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--passes", type=int, default=24)
    a = ap.parse_args()
    flatland()
    if a.render:
        render(a.photons, a.passes)


if __name__ == "__main__":
    main()
