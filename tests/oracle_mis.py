"""Brute-force strategy densities of one concrete path (the COMBINED integrator's MIS).

A path is a list of vertices y_0 (the pinhole) .. y_k (a point on an emitter),
each a dict with p (3,), n (3,) geometric normal and kind 'camera', 'lambert',
'mirror' (delta) or 'light'.  The three strategies' densities are written as
whole products (area measure, counts included), independently of the
running ratios of core.integrators.mis:

    q_PT  = K   c_1 ... c_k              (0 for a delta-position light)
    q_NEE = K   c_1 ... c_{k-1} n_k      (0 if y_{k-1} is a mirror or k = 1)
    q_LT  = N_L l_1 ... l_k              (0 if y_1 is a mirror, and for the
                                          direct light of a delta-position
                                          light: k = 2, y_1 not a mirror)

The last exception is a rule of the integrator, not a density: the direct
light of radius-0 point and spot lights belongs to next-event estimation
alone (core.integrators.mis.NEE_OWNS_DELTA_DIRECT), so its power weights
are (0, 1, 0).

c_1 = |cos_1| / (A_pix cos_cam^3 d_01^2) (one-pixel pinhole density),
c_i = p_bsdf(y_{i-1}: y_{i-2} -> y_i) |cos_i| / d^2, l_k = emission position
density, l_{k-1} = emission direction density |cos| / d^2, l_i =
p_bsdf(y_{i+1}: y_{i+2} -> y_i) |cos_i| / d^2; a mirror's densities are 1
(deltas cancel).  Lambert: p_bsdf = cos(n, wi) / pi on wo's side, else 0.

Photon merging (core.integrators.merge) owns a path when its first
non-mirror vertex y_v has v > 1 and y_{v+1} is a mirror (``merge_owned``):
then the weight is 1 for merging and 0 for every strategy above.

Merging as an MIS strategy (``vcm_densities``): a fourth density

    q_M = 1 c_1 ... c_v  N_M l_v ... l_k  pi r^2   (0 unless k >= v + 2)

with y_v the first non-mirror vertex (one SPPM camera sample per pixel and
pass, N_M merging photons, r the radius of the pixel containing y_1).
"""
from __future__ import annotations

import numpy as np


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def lambert_pdf(n, wo, wi):
    n = np.asarray(n, float)
    if np.dot(n, wo) * np.dot(n, wi) <= 0:
        return 0.0
    return abs(np.dot(n, wi)) / np.pi


def _cos(v, a, b):
    """|cos| at vertex v of the segment to point b from a = v['p']."""
    return abs(np.dot(v["n"], _unit(np.asarray(b) - a)))


def _d2(a, b):
    return float(np.sum((np.asarray(a) - np.asarray(b)) ** 2))


def _pdf(path, i, frm, to):
    """Solid-angle density at vertex i of scattering from vertex frm to vertex to."""
    v = path[i]
    if v["kind"] == "mirror":
        return 1.0
    wo = _unit(path[frm]["p"] - v["p"])
    wi = _unit(path[to]["p"] - v["p"])
    return lambert_pdf(v["n"], wo, wi)


def densities(path, A_pix, axis, K, N_L, emit_pos, emit_dir, nee_area, hittable,
              nee_owns=True):
    """(q_PT, q_NEE, q_LT) of path.  axis: unit view direction of the camera;
    emit_pos: l_k; emit_dir(w): the emitter's solid-angle density along w
    (leaving y_k); nee_area: n_k; hittable: a BSDF ray can hit the emitter
    (False: a delta-position light); nee_owns: the rule that a delta light's
    direct light is NEE's alone applies (False where the camera paths stop
    before their light sample at y_1, core.integrators.combined.CameraStop)."""
    return _densities(path, A_pix, axis, K, N_L, emit_pos, emit_dir, nee_area, hittable,
                      nee_owns)[:3]


def vcm_densities(path, A_pix, axis, K, N_L, emit_pos, emit_dir, nee_area, hittable, N_M, r2):
    """(q_PT, q_NEE, q_LT, q_M) of path (arguments as :func:`densities`; N_M
    merging photons per pass, r2 the squared radius of y_1's pixel)."""
    q_pt, q_nee, q_lt, c, l = _densities(path, A_pix, axis, K, N_L, emit_pos, emit_dir,
                                         nee_area, hittable)
    k = len(path) - 1
    v = next((i for i in range(1, k) if path[i]["kind"] != "mirror"), None)
    q_m = 0.0
    if v is not None and k >= v + 2:
        q_m = np.prod(c[1:v + 1]) * N_M * np.prod(l[v:]) * np.pi * r2
    return q_pt, q_nee, q_lt, q_m


def _densities(path, A_pix, axis, K, N_L, emit_pos, emit_dir, nee_area, hittable,
               nee_owns=True):
    k = len(path) - 1
    y = [np.asarray(v["p"], float) for v in path]
    c = [None] * (k + 1)
    w01 = _unit(y[1] - y[0])
    cos_cam = float(np.dot(w01, axis))
    c[1] = _cos(path[1], y[1], y[0]) / (A_pix * cos_cam ** 3 * _d2(y[0], y[1]))
    for i in range(2, k + 1):
        c[i] = _pdf(path, i - 1, i - 2, i) * _cos(path[i], y[i], y[i - 1]) / _d2(y[i - 1], y[i])
    l = [None] * (k + 1)
    l[k] = emit_pos
    if k >= 2:
        l[k - 1] = emit_dir(_unit(y[k - 1] - y[k])) * _cos(path[k - 1], y[k - 1], y[k]) \
            / _d2(y[k - 1], y[k])
    for i in range(k - 2, 0, -1):
        l[i] = _pdf(path, i + 1, i + 2, i) * _cos(path[i], y[i], y[i + 1]) / _d2(y[i], y[i + 1])
    q_pt = K * np.prod(c[1:]) if hittable else 0.0
    q_nee = K * np.prod(c[1:k]) * nee_area if k >= 2 and path[k - 1]["kind"] != "mirror" else 0.0
    q_lt = N_L * np.prod(l[1:]) if path[1]["kind"] != "mirror" else 0.0
    if nee_owns and k == 2 and not hittable and path[1]["kind"] != "mirror":
        q_lt = 0.0        # a delta light's direct light: NEE's alone (module doc)
    return q_pt, q_nee, q_lt, c, l


def power_weights(q):
    q = np.asarray(q, float)
    return q * q / np.sum(q * q)


def merge_owned(path) -> bool:
    """Whether photon merging owns the path y_0 .. y_k: y_v the first vertex
    after the lens that is not a mirror, v > 1, and y_{v+1} a mirror (not
    the emitter)."""
    kinds = [v["kind"] for v in path[1:-1]]          # y_1 .. y_{k-1}
    v = next((i + 1 for i, kd in enumerate(kinds) if kd != "mirror"), None)
    return v is not None and v > 1 and v + 1 <= len(kinds) and kinds[v] == "mirror"


def merge_weights(path, q):
    """(w_PT, w_NEE, w_LT, w_merge): the power heuristic of q on the paths
    merging does not own, (0, 0, 0, 1) on the ones it does."""
    if merge_owned(path):
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.append(power_weights(q), 0.0)
