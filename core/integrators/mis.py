"""MIS of the combined integrator: path tracing, next-event estimation, light tracing.

For a path y_0 (lens) y_1 ... y_k (on an emitter), numbered from the camera,
the strategies of integrator 'COMBINED' (docs/integrators.md, "Combined") and
their sample densities (area measure, counts included) are

    PT  (emission found by a BSDF ray, s = 0):  q_0 = K   c_1 c_2 ... c_k
    NEE (light sample at y_{k-1},      s = 1):  q_1 = K   c_1 ... c_{k-1} n_k
    LT  (light vertex y_1 to the lens, t = 1):  q_L = N_L l_1 l_2 ... l_k

K camera paths per pixel and pass, N_L light paths per pass; c_i the area
density of y_i on the camera path (c_1 = the one-pixel image density
1 / (A_pix cos^3) |cos_1| / d_01^2, the pixel filter left out of the weights
as in SmallVCM: any weights that sum to one keep the estimate unbiased),
l_i on the light path (l_k = emission position, l_{k-1} = emission direction
x |cos| / d^2, then the BSDF densities), n_k = the next-event density of y_k.
Weights: power heuristic, w_s = q_s^2 / sum_t q_t^2 (Veach 1997, 9.13).

Ratios are running products (VCM's recursion, Georgiev et al. 2012, reduced
to these three strategies).  With r_i = l_i / c_i, the camera side carries
``Q`` = (N_L / K) r_1 ... r_{j-1} / pr_j at vertex y_j (the light-side BSDF
density pr_j at y_j needs the next direction, so it is applied one step
later), and the light side carries ``B`` = (K / N_L) prod (c_i / l_i) over
the vertices from the emitter, the camera-side BSDF density at the current
vertex again deferred.  Delta scattering: both densities are taken as 1
(they cancel), and a strategy that must connect or hit through a delta is
excluded (its q is 0: LT when y_1 scattered by a delta lobe, NEE when y_{k-1}
did, PT for delta lights).

Emitters: AREA and MESH (any position) and POINT / SPOT of radius 0 are
weighted over whole paths.  Point and spot lights of radius > 0 (Cycles'
soft falloff disc, not a light field) are weighted over the path without
its emitter point: LT against the camera strategies by q_L / q_C with q_C
the next-event density of the light's centre as a point light, then PT and
NEE split (1 - w_LT) by their usual two-way power heuristic; both sides use
the centre, so the weights depend only on y_1 .. y_{k-1} and sum to one.
Sun and world light is left to the camera strategies (LT does not splat it).

Photon merging as a fourth strategy (``merge_weights = 'MIS'``):
q_M = 1 c_1 ... c_v N_M l_v ... l_k pi r^2 at the first non-delta camera
vertex y_v, k >= v + 2; its camera-side ratio QM follows Q's recursion from
y_v on (core.integrators.merge.CameraMerge), its light-side weight comes
from B0, B1 (merge.merge_weight).
"""
from __future__ import annotations

import numpy as np

from ..lights.emission import spot_pdf_local, spot_tail
from ..lights.pdf import _selection_probability
from ..lights.table import AREA, MESH, POINT, SPOT
from ..mathutil import dot as _dot

#: Strategy classes of an emitter row (``light_classes``).
NO_LT, FULL, SOFT = 0, 1, 2

#: The direct light of radius-0 point and spot lights at a non-delta first
#: camera vertex y_1 (paths y_0 y_1 y_2, y_2 the light) belongs to
#: next-event estimation alone (w_NEE = 1, w_LT = 0) instead of the power
#: heuristic between the two; every other path keeps the power heuristic.
#: The light sample of a delta light has no variance but y_1's within the
#: pixel, while the splats of light tracing land in a pixel a Poisson number
#: of times; the power heuristic, which compares only the densities (K
#: camera samples against the light paths expected in the pixel's
#: footprint), gave light tracing a share that grows as K falls
#: (docs/integrators.md "The point caustic: `COMBINED` below FPPM and
#: `LIGHT`").  Weights 0 / 1 by path class sum to one, so the image stays
#: unbiased.  Read by combined.CameraMIS and combined.CombinedLightTracer
#: at construction.
NEE_OWNS_DELTA_DIRECT = True


def light_classes(table) -> np.ndarray:
    """(Nl,) int8: FULL (area, mesh, radius-0 point/spot: three-way weights),
    SOFT (point/spot of radius > 0: LT weighted against the camera strategies
    on the path prefix) or NO_LT (sun, world, emitters hidden from diffuse,
    glossy or transmission rays: camera strategies only).  Every row is NO_LT in a
    scene where shadow rays pass some object (Shadow visibility off:
    ``LightTable.shadow_passes``; or shadow rays see a material as another,
    a Light Path node's Is Shadow Ray): light paths still meet it, so their
    direct light would not be the camera paths' (Cycles' is the shadow
    rays').  So is every row where camera rays see a material as another
    (``LightTable.camera_variants``: Is Camera Ray), which light paths would
    join to the lens with what other rays see."""
    kind = table.kind
    pt = (kind == POINT) | (kind == SPOT)
    vis = (table.visible_glossy & table.visible_transmission) | (kind == MESH)
    hidden = getattr(table, "hidden", None)
    if hidden is not None:
        vis &= np.asarray(hidden) == 0        # (core.lights.lobe_visibility)
    cls = np.full(table.n, NO_LT, np.int8)
    cls[((kind == AREA) | (kind == MESH) | (pt & (table.radius <= 0))) & vis] = FULL
    cls[pt & (table.radius > 0) & vis] = SOFT
    cls[table.p_select <= 0] = NO_LT
    if getattr(table, "shadow_passes", False) or getattr(table, "camera_variants", False):
        cls[:] = NO_LT
    return cls


def traced_select(table) -> np.ndarray:
    """(Nl,) the probability that a light path of 'COMBINED' starts on each
    emitter: p_select over the emitters light tracing follows (not NO_LT),
    renormalised; 0 on the others (sun, world: their photons would be
    drawn and dropped, a sixth of the light paths with a bright world)."""
    ps = np.where(light_classes(table) != NO_LT, np.asarray(table.p_select, np.float64), 0.0)
    tot = ps.sum()
    return ps / tot if tot > 0 else ps


def traced_table(table):
    """The light table with :func:`traced_select` as its p_select: the
    emitters 'COMBINED''s light paths are drawn from (lights.sample_photons
    and the compiled emission divide the power by it)."""
    from dataclasses import replace
    return replace(table, p_select=traced_select(table))


def emit_select(table, light) -> np.ndarray:
    """(K,) probability that a light path of 'COMBINED' starts on emitter
    row light (sample_photons of :func:`traced_table`)."""
    return traced_select(table)[light]


def emit_pdf_pos(table, light) -> np.ndarray:
    """(K,) emission density of the photon's origin: selection / area for AREA
    and MESH; the selection alone for point and spot lights (their delta
    position cancels against next-event estimation's)."""
    pa = emit_select(table, light)
    ar = (table.kind[light] == AREA) | (table.kind[light] == MESH)
    return np.where(ar, pa / np.where(ar, table.area[light], 1.0), pa)


def emit_pdf_dir(table, light, w) -> np.ndarray:
    """(K,) solid-angle density with which the emitter rows light (K,) send a
    photon along unit w (K, 3) (sample_photons): cosine about the front
    normal (AREA; inside the cone of a spread below 180 deg), cosine about either side with 1/2 per side (MESH),
    uniform on the sphere (POINT) or in the spot's local cone mapped by its
    object matrix (SPOT: |M v|^3 / |det M| x lights.emission.spot_pdf_local,
    1 / (2 pi (1 - cos_h)) inside a hard spot's cone)."""
    K = light.shape[0]
    out = np.zeros(K)
    kind = table.kind[light]
    n = table.dir[light]
    c = _dot(n, w)
    # An area light's spread of half angle a: cosine inside its cone only,
    # cos / (pi sin^2 a) (lights.emission); sin^2 a = 1 without a spread.
    s2 = table.spread_sin2[light]
    out = np.where(kind == AREA, np.where(c >= np.sqrt(1.0 - s2), c / (np.pi * s2), 0.0), out)
    out = np.where(kind == MESH, 0.5 * np.abs(c) / np.pi, out)
    out = np.where(kind == POINT, 1.0 / (4.0 * np.pi), out)
    m = np.nonzero(kind == SPOT)[0]
    if m.size:
        j = light[m]
        v = np.einsum("kij,kj->ki", table.lin_inv[j], w[m])
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        Mv = np.linalg.norm(np.einsum("kij,kj->ki", table.lin[j], v), axis=1)
        out[m] = (Mv ** 3 / np.abs(np.linalg.det(table.lin[j]))
                  * spot_pdf_local(spot_tail(table)[j], table.cos_half_spot[j], -v[:, 2]))
    return out


def point_emit_over_nee(table, p, light, wi_out, dist) -> np.ndarray:
    """(K,) l_{k-1} n_k^-1 l_k ... the factor of q_L / q_1 at the light end
    for a point/spot (or a soft light's centre) at dist along -wi_out from
    p: emission direction density x 1 / d^2 (the |cos| at p is the caller's)
    x emission selection / next-event selection."""
    nee = _selection_probability(table, p, light)
    return (emit_pdf_dir(table, light, wi_out) / (dist * dist) * emit_select(table, light)
            / np.where(nee > 0, nee, np.inf))


def area_emit_over_nee(table, light, wi_out, pdf_nee, cos_light) -> np.ndarray:
    """(K,) the same factor (without |cos| at p) for an AREA or MESH point:
    emission direction density / d^2 x emission position density / next-event
    area density (pdf_nee |cos_light| / d^2), the d^2 cancelling."""
    return (emit_pdf_dir(table, light, wi_out) * emit_pdf_pos(table, light)
            / np.where(pdf_nee * cos_light > 0, pdf_nee * cos_light, np.inf))


def power3(r_a, r_b) -> np.ndarray:
    """(K,) power-heuristic weight of a strategy whose density ratios to the
    two others are r_a, r_b: 1 / (1 + r_a^2 + r_b^2)."""
    return 1.0 / (1.0 + r_a * r_a + r_b * r_b)
