"""The colour passes (Diffuse, Glossy and Transmission Color), the
Environment pass and the UV pass, as Cycles writes them
(kernel/film/data_passes.h, light_passes.h).

The colour and Environment passes are sums over what a camera ray meets
while it is still on its line (``core.sppm.line_hits``), means over the
passes:

    Diffuse Color      = sum over the hits of beta x the diffuse albedo,
    Glossy Color       = ... the glossy albedo,
    Transmission Color = ... the transmission albedo
                                 (core.materials.albedo.closure_albedos),
    Environment        = beta x the world the ray sees where it escapes,

beta the ray's throughput before the surface (a Transparent BSDF's
crossings and absorbing volumes lower it).  The Environment pass is the
world as camera rays see it (World > Ray Visibility > Camera off: black)
also under Film > Transparent, as in Cycles.

The Ambient Occlusion pass is, summed over the same surfaces, beta x the
surface's opacity (1 - its Transparent lobes) x the light a ray let
through: one ray a surface, cosine-distributed about the shading normal
facing the camera ray, up to the world's AO distance, through transparent
surfaces as shadow rays pass them (``integrate_surface_ao`` and
``film_write_direct_light``'s PATH_RAY_SHADOW_FOR_AO: an open surface is 1).

The UV pass is (u, v, 1) of the render UV map at the first hit, (0, 0, 0)
where the mesh has none or the ray escapes (``primitive_uv``), averaged
over the passes like the Normal pass; the exporter writes those
coordinates (``Scene.tri_render_uv``) only when the pass is on.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..accel import surface_point
from ..mathutil import dot as _dot
from ..scene import ray_variants as RV

#: Blender's names of the passes made from the line records, with the index
#: of their closure kind in ``core.materials.albedo.ALBEDO_KINDS``.
COLOR_PASSES = {"Diffuse Color": 0, "Glossy Color": 1, "Transmission Color": 2}
ENVIRONMENT = "Environment"
AMBIENT_OCCLUSION = "Ambient Occlusion"
LINE_PASSES = tuple(COLOR_PASSES) + (ENVIRONMENT, AMBIENT_OCCLUSION)


def _line(x, hits: bool, names: tuple) -> Optional[list]:
    """The pass's line records' fields ``names``, concatenated over the
    records, of their hits (hits=True) or of the rays that escaped; None
    when there is none."""
    recs = [r for r in (x.first.line or ()) if (r.hit if hits else ~r.hit).any()]
    if not recs:
        return None
    return [np.concatenate([getattr(r, f)[r.hit if hits else ~r.hit] for r in recs])
            for f in names]


def _surfaces(x) -> Optional[dict]:
    """The line records' hits with their surface points, once a pass (x.memo:
    the colour and Ambient Occlusion passes read them): {px, prim, u, v,
    beta, d, through, p, ng, ns, uv}, or None."""
    if "surfaces" not in x.memo:
        names = ("px", "prim", "u", "v", "beta", "d", "through")
        rec = _line(x, True, names)
        if rec is not None:
            rec = dict(zip(names, rec))
            s = x.scene
            rec.update(zip(("p", "ng", "ns", "uv"), surface_point(
                s.tri_p, s.tri_n, s.tri_uv, rec["prim"], rec["u"], rec["v"])))
        x.memo["surfaces"] = rec
    return x.memo["surfaces"]


def line_albedos(x) -> np.ndarray:
    """(3, P, 3) the pass's sums of beta x the diffuse, glossy and
    transmission albedos over each pixel's line hits (computed once a pass:
    x.memo)."""
    if "albedos" in x.memo:
        return x.memo["albedos"]
    from .. import materials as B
    from ..materials import rough_maps
    from ..materials.albedo import closure_albedos
    P = x.first.escape.shape[0]
    out = np.zeros((3, P, 3))
    h = _surfaces(x)
    if h is not None and x.mtab is not None:
        px, prim, u, v, beta, d = (h[k] for k in ("px", "prim", "u", "v", "beta", "d"))
        ng, ns, uv = h["ng"], h["ns"], h["uv"]
        s, mtab = x.scene, x.mtab
        # On the camera ray's line: the material camera rays see (a Light
        # Path node, core.scene.ray_variants), a roughness map's level row.
        mat = RV.seen(RV.rows(s, "camera"), s.tri_mat[prim])
        mat = rough_maps.pick(mtab, mat, prim, u, v, uv)
        mu = np.abs(_dot(d, ns))
        colors = B.lobe_colors(mtab, mat, uv, B.view_mu(mtab, -d, ns))
        a = closure_albedos(mtab, mat, colors, mu, _dot(d, ng) < 0.0)
        for k in range(3):
            np.add.at(out[k], px, beta * a[k])
    x.memo["albedos"] = out
    return out


def color_pass(kind: int):
    """The compute of the colour pass of closure kind ``kind`` (0 diffuse,
    1 glossy, 2 transmission)."""
    return lambda x: line_albedos(x)[kind]


def environment(x) -> np.ndarray:
    """(P, 3) beta x the world the camera-line rays that escape see."""
    from .. import lights as Lt
    P = x.first.escape.shape[0]
    out = np.zeros((P, 3))
    lt = x.light_table
    rec = _line(x, False, ("px", "beta", "d"))
    if lt is None or rec is None:
        return out
    px, beta, d = rec
    np.add.at(out, px, beta * Lt.world_radiance(lt, d, camera=True))
    return out


def ambient_occlusion(x) -> np.ndarray:
    """(P, 3) the Ambient Occlusion pass's sums of one pass (module doc)."""
    from ..lights.shadow import transmittance
    from ..materials.closures import _cos_hemisphere
    from ..mathutil import frame
    P = x.first.escape.shape[0]
    out = np.zeros((P, 3))
    h = _surfaces(x)
    if h is None or x.accel is None:
        return out
    px, prim, beta, d, through = (h[k] for k in ("px", "prim", "beta", "d", "through"))
    p, ng, ns = h["p"], h["ng"], h["ns"]
    s = x.scene
    # The normal facing the camera ray (Cycles flips N on a back face).
    N = np.where((_dot(ns, d) > 0)[:, None], -ns, ns)
    t, b = frame(N)
    w = _cos_hemisphere(*x.rng.random((2, prim.size)))
    w = w[:, :1] * t + w[:, 1:2] * b + w[:, 2:] * N
    o = x.accel.spawn(p, ng, w)
    T = transmittance(x.accel, o, w, float(s.ao_distance), n0=ng)
    np.add.at(out, px, beta * (1.0 - through)[:, None] * T)
    return out


def uv_pass(x) -> np.ndarray:
    """(P, 3) (u, v, 1) of the render UV map at the first hit (0 without)."""
    f = x.first
    out = np.zeros((f.hit.shape[0], 3))
    tuv = getattr(x.scene, "tri_render_uv", None)
    k = np.nonzero(f.hit & (f.prim >= 0))[0]
    if tuv is None or k.size == 0:
        return out
    t = f.prim[k].astype(np.int64)
    P = x.scene.tri_p[t].astype(np.float64)          # (k, 3, 3)
    # The first hit's barycentrics from its position (on the triangle).
    e1, e2, w = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], f.p[k] - P[:, 0]
    d11, d12, d22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    w1, w2 = _dot(w, e1), _dot(w, e2)
    den = np.where(np.abs(d11 * d22 - d12 * d12) > 0, d11 * d22 - d12 * d12, 1.0)
    b1 = (d22 * w1 - d12 * w2) / den
    b2 = (d11 * w2 - d12 * w1) / den
    U = tuv[t].astype(np.float64)                    # (k, 3, 3): u, v, has-uv per corner
    out[k] = ((1.0 - b1 - b2)[:, None] * U[:, 0] + b1[:, None] * U[:, 1]
              + b2[:, None] * U[:, 2])
    return out
