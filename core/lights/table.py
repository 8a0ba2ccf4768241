"""The light table: every emitter of a scene as one structure of arrays.

Kinds, :class:`LightTable`, :func:`build_light_table`, and what the other
modules read from a row: the spot cone's attenuation and the emitted radiance
of a mesh triangle.  The emitter models and their units are listed in the
package doc (:mod:`core.lights`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..mathutil import LUMINANCE as _LUM
from ..scene.model import Scene
from ..scene.textures import sample_texture
from . import ies as IES
from .environment import EnvironmentLight
from .warps import _normalize, cone_grid, smoothstep as _smoothstep

# Emitter kinds (LightTable.kind, photon "kind").
POINT = 0
SPOT = 1
SUN = 2
AREA = 3
MESH = 4
WORLD = 5
KIND_NAMES = {POINT: "point", SPOT: "spot", SUN: "sun", AREA: "area",
              MESH: "mesh", WORLD: "world"}

# Triangles up to this count get one entry each in the per-point NEE selection;
# above it they share one entry (chosen by distance) and are picked by flux.
_MAX_TRI_ENTRIES = 16

# A spot's 1/((1 - cos h) * blend) for blend = 0 (hard edge): large, finite so
# that 0 * smooth stays 0 (no NaN).
_SMOOTH_MAX = 1e30


@dataclass
class LightTable:
    """All emitters of a scene, structure of arrays, float64, Nl rows.

    kind: (Nl,) int8 POINT/SPOT/SUN/AREA/MESH/WORLD.
    source: (Nl,) int32 index into ``scene.lights`` (lights), triangle index
      (MESH) or -1 (WORLD).
    strength: (Nl, 3) light strength (W or W/m^2); MESH/WORLD: radiance.
    radiance: (Nl, 3) emitted radiance of the visible shape [W/(m^2 sr)]
      (0 for point/spot with r = 0 and sun with angle = 0).
    flux: (Nl, 3) total emitted flux [W] (sun/world: through the scene disc).
    p_select: (Nl,) photon light-selection probability, prop. to luminance of
      flux; 0 for zero-power emitters.
    co: (Nl, 3) position (triangles: first corner); axis_u, axis_v: (Nl, 3)
      unit in-plane axes (area) or edges e1, e2 (MESH, not unit);
      dir: (Nl, 3) unit emission axis (local -Z; MESH: geometric normal).
    len_u, len_v: (Nl,) area light extents [m]; area: (Nl,) emitting area.
    ellipse: (Nl,) bool disc/ellipse area light.
    radius: (Nl,) point/spot radius; is_sphere: (Nl,) bool (no soft falloff).
    lin, lin_inv: (Nl, 3, 3) object linear part and its inverse (spot cone).
    cos_half_spot, spot_smooth: (Nl,) Cycles' spot parameters.
    half_angle, cos_half_angle: (Nl,) sun cone.
    spread_tan, spread_norm: (Nl,) an area light's spread (Cycles'
      ``tan_half_spread``, ``normalize_spread``: :func:`spread_atten`); inf
      and 0 for a spread of 180 deg and every other light.
    tri_uv: (Nl, 3, 2) corner UVs, tex: (Nl,) int32 emission texture or -1.
    visible_camera / visible_glossy / visible_transmission / cast_shadow:
      (Nl,) bool.
    center (3,), radius_scene: bounding sphere; a_max: D^2 (docs/frequency.md).
    world: (3,) world radiance (with an environment map: its mean).
    environment: the world's :class:`.environment.EnvironmentLight` or None
      (a constant world).  warnings: list of str.
    """
    kind: np.ndarray
    source: np.ndarray
    strength: np.ndarray
    radiance: np.ndarray
    flux: np.ndarray
    p_select: np.ndarray
    co: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    dir: np.ndarray
    len_u: np.ndarray
    len_v: np.ndarray
    area: np.ndarray
    ellipse: np.ndarray
    radius: np.ndarray
    is_sphere: np.ndarray
    lin: np.ndarray
    lin_inv: np.ndarray
    cos_half_spot: np.ndarray
    spot_smooth: np.ndarray
    half_angle: np.ndarray
    cos_half_angle: np.ndarray
    spread_tan: np.ndarray
    spread_norm: np.ndarray
    tri_uv: np.ndarray
    tex: np.ndarray
    visible_camera: np.ndarray
    visible_glossy: np.ndarray
    visible_transmission: np.ndarray
    cast_shadow: np.ndarray
    center: np.ndarray
    radius_scene: float
    a_max: float
    world: np.ndarray
    textures: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    # Next-event selection (see _direct_entries): entry -> emitter (-1 = the
    # triangle group), and the group's triangles with their flux-luminance CDF.
    entry_emitter: np.ndarray = None
    group_tri: np.ndarray = None
    group_cdf: np.ndarray = None
    group_center: np.ndarray = None
    group_ext2: float = 0.0
    environment: EnvironmentLight = None
    # Shadow rays pass some object (its Shadow visibility off,
    # Scene.tri_visibility): light tracing cannot follow them
    # (integrators.mis.light_classes).
    shadow_passes: bool = False
    # Camera rays see some material differently (a Light Path node's Is
    # Camera Ray, core.scene.ray_variants): light tracing would join its
    # vertices to the lens with what other rays see (integrators.mis).
    camera_variants: bool = False
    # The world as camera rays see it, when it differs (Scene.world_camera_map).
    camera_environment: EnvironmentLight = None
    # (centre (3,), half extents (3,)) float64 of the triangles' box, with the
    # bounding sphere's margin, or None without triangles: where world
    # photons start (emission.distant_footprint).
    triangle_box: tuple = None
    # (Nl, 4) float64: a soft spot's photons beyond its cone (share, x0, X,
    # half-angle; share 0 for every other light): :func:`_spot_tails`,
    # lights.emission.spot_pdf_local.
    spot_tail: np.ndarray = None
    # (Nl,) uint64 the receiver sets each emitter lights (light linking,
    # core.scene.linking), or None: every emitter lights every object.
    link_sets: np.ndarray = None
    # (Nl,) uint8 the kinds of ray each emitter is hidden from
    # (core.lights.lobe_visibility), or None: every emitter is seen by all.
    hidden: np.ndarray = None
    # (Nl,) uint64 the blocker sets whose objects shadow each emitter (shadow
    # linking, core.scene.shadow_linking), or None: every object shadows
    # every emitter.
    shadow_sets: np.ndarray = None
    # (n,) float64 the point and spot lights' IES profiles packed
    # (core.lights.ies.pack: row offsets, then each profile with its light's
    # frame), empty when no light has one; ies.ies_factor reads it.
    ies: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n(self) -> int:
        return int(self.kind.shape[0])

    @property
    def soft_spot(self) -> np.ndarray:
        """(Nl,) bool: the soft spots (radius > 0, soft falloff: Cycles'
        disc facing the receiver), whose photons read the cone at their
        first hit (lights.emission)."""
        return (self.kind == SPOT) & ~np.asarray(self.is_sphere, bool) & (self.radius > 0)

    @property
    def soft_disc(self) -> np.ndarray:
        """(Nl,) bool: the soft-falloff point and spot lights (radius > 0:
        Cycles' disc facing the receiver), whose photons carry a disc sample
        that sets their direction at the first hit (lights.emission)."""
        return (((self.kind == POINT) | (self.kind == SPOT))
                & ~np.asarray(self.is_sphere, bool) & (self.radius > 0))

    @property
    def spread_sin2(self) -> np.ndarray:
        """(Nl,) sin^2 a of an area light's half spread a (1 for 180 deg and
        every other light): the share of a cosine lobe inside the spread's
        cone, which photons are drawn from (lights.emission; their direction
        density cos / (pi sin^2 a) there, mis.emit_pdf_dir)."""
        t = np.asarray(self.spread_tan, np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            s2 = t * t / (1.0 + t * t)
        return np.where(np.isfinite(t), s2, 1.0)

    @property
    def total_flux(self) -> np.ndarray:
        """(3,) sum of ``flux`` over all emitters."""
        return self.flux.sum(axis=0) if self.n else np.zeros(3)


def _lum(rgb):
    return np.maximum(np.asarray(rgb, np.float64) @ _LUM, 0.0)


# ----------------------------------------------------------------------------
# Spot cone.

def _spot_solid_angle(lin: np.ndarray, cos_h: float, blend: float) -> float:
    """int smoothstep(...) d omega over world directions [sr].

    Local direction v (unit, in the light frame) maps to omega = normalize(M v);
    d omega = |det M| / |M v|^3 d v.  For a similarity M that factor is 1 and
    the integral is closed-form: with mu = -v_z, smoothstep rises over a width
    w = (1 - cos h) * blend of mu and int_0^1 smoothstep = 1/2, so
    Omega = 2 pi ((1 - cos h) - w / 2).  Otherwise a (mu, phi) midpoint grid.
    """
    g = lin.T @ lin
    s2 = np.trace(g) / 3.0
    w = (1.0 - cos_h) * blend
    if s2 > 0 and np.allclose(g, s2 * np.eye(3), rtol=1e-9, atol=1e-12 * s2):
        return 2.0 * np.pi * ((1.0 - cos_h) - 0.5 * w)
    mu, v, dA = cone_grid(cos_h, 512, 256)
    smooth = 1.0 / w if w > 0 else _SMOOTH_MAX
    att = _smoothstep((mu - cos_h) * smooth)
    jac = abs(np.linalg.det(lin)) / np.linalg.norm(v @ lin.T, axis=1) ** 3
    return float(np.sum(att * jac) * dA)


def _spot_atten(table: LightTable, j: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Cycles' spot attenuation of world directions w (K,3) leaving lights j (K,).

    The direction is mapped to the light's local frame (inverse object matrix,
    so scale makes the cone elliptic) and its cosine to local -Z is used.
    """
    loc = np.einsum("kij,kj->ki", table.lin_inv[j], w)
    loc = _normalize(loc)
    return _smoothstep((-loc[:, 2] - table.cos_half_spot[j]) * table.spot_smooth[j])


def _spread_params(spread: float):
    """(tan_half_spread, normalize_spread) of an area light's spread [rad],
    as Cycles' scene/light.cpp computes them: tan(a) and 1 / (tan a - a) with
    a = spread / 2 (3 / a^3, its Taylor form, for a <= 0.05; a spread of 0
    taken as 0.01 deg, which Cycles lights only along the normal); (inf, 0)
    for 180 deg, where :func:`spread_atten` is 1."""
    if not spread < np.pi - 1e-6:
        return np.inf, 0.0
    a = 0.5 * max(spread, np.radians(0.01))
    ta = float(np.tan(a))
    return ta, (1.0 / (ta - a) if a > 0.05 else 3.0 / a ** 3)


def spread_atten(table: LightTable, j, cos_l) -> np.ndarray:
    """(K,) Cycles' ``area_light_spread_attenuation``: the factor on an area
    light's radiance leaving at cos_l (K,) to its normal, lights j (K,),
    max((tan a - tan theta) normalize_spread, 0): a grid of slats in front
    of the light (a soft box), normalised so that the flux stays the light's
    (the integral of cos theta (tan a - tan theta) sin theta over [0, a] is
    (tan a - a) / 2); 1 for a spread of 180 deg, 0 behind the light."""
    tan_s = table.spread_tan[j]
    c = np.asarray(cos_l, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        tan_a = np.sqrt(np.maximum(1.0 - c * c, 0.0)) / c
        a = np.maximum((tan_s - tan_a) * table.spread_norm[j], 0.0)
    return np.where(np.isinf(tan_s), 1.0, np.where(c > 0, a, 0.0))


def spread_rect(table: LightTable, j, p, corner, len_u, len_v):
    """(corner (K, 3), len_u, len_v (K,)) of rectangular area lights j (K,)
    cut to the part that can light p (K, 3) through a spread's slats
    (Cycles' ``area_light_spread_clamp_light``): a light point q reaches p
    when the angle of p - q to the normal is at most a, i.e. q lies within
    h tan a of p's foot on the light's plane (h its height above it), so
    the rectangle is cut to the square of that half side around the foot
    (empty: lengths 0).  Lights without a spread keep corner, len_u, len_v
    (the same arrays).  Next-event estimation samples the cut rectangle in
    solid angle, and its density is 1 / the cut rectangle's solid angle
    (lights.pdf): outside the cut the spread factor is 0."""
    tan = table.spread_tan[j]
    k = np.nonzero(np.isfinite(tan))[0]
    if k.size == 0:
        return corner, len_u, len_v
    corner, len_u, len_v = corner.copy(), np.array(len_u, np.float64), np.array(len_v, np.float64)
    jj = j[k]
    au, av = table.axis_u[jj], table.axis_v[jj]
    d = p[k] - table.co[jj]
    r = np.maximum(np.einsum("ij,ij->i", d, table.dir[jj]), 0.0) * tan[k]
    x = np.einsum("ij,ij->i", d, au)
    y = np.einsum("ij,ij->i", d, av)
    hu, hv = 0.5 * table.len_u[jj], 0.5 * table.len_v[jj]
    u0, u1 = np.maximum(-hu, x - r), np.minimum(hu, x + r)
    v0, v1 = np.maximum(-hv, y - r), np.minimum(hv, y + r)
    corner[k] = table.co[jj] + u0[:, None] * au + v0[:, None] * av
    len_u[k] = np.maximum(u1 - u0, 0.0)
    len_v[k] = np.maximum(v1 - v0, 0.0)
    return corner, len_u, len_v


# ----------------------------------------------------------------------------
# Mesh emission.

def _mesh_emission(table: LightTable, jj, b1, b2):
    """Emitted radiance (K, 3) at barycentrics (b1, b2) of triangles jj."""
    Le = table.strength[jj].copy()
    tex = table.tex[jj]
    if np.any(tex >= 0):
        uvc = table.tri_uv[jj]
        uv = (1.0 - b1 - b2)[:, None] * uvc[:, 0] + b1[:, None] * uvc[:, 1] + b2[:, None] * uvc[:, 2]
        for ti in np.unique(tex[tex >= 0]):
            if ti < len(table.textures):
                mm = tex == ti
                Le[mm] *= sample_texture(table.textures[ti], uv[mm])
    return Le


# ----------------------------------------------------------------------------
# Table construction.

def build_light_table(scene: Scene) -> LightTable:
    """Collect every emitter of ``scene`` into a :class:`LightTable`."""
    lo, hi = scene.bounds()
    center = 0.5 * (lo + hi)
    D = scene.diameter()
    # Bounding sphere of the box (half diagonal), with a small margin so photon
    # discs cover the geometry even after float32 rounding.
    R = 0.5 * D * (1.0 + 1e-4)
    warnings: list[str] = []
    rows: list[dict] = []
    ies_rows: dict = {}     # row -> (IES profile, object matrix)
    eye = np.eye(3)

    def row(**kw):
        base = dict(kind=POINT, source=-1, strength=np.zeros(3), radiance=np.zeros(3),
                    flux=np.zeros(3), co=np.zeros(3), axis_u=np.array([1.0, 0, 0]),
                    axis_v=np.array([0, 1.0, 0]), dir=np.array([0, 0, -1.0]),
                    len_u=0.0, len_v=0.0, area=0.0, ellipse=False, radius=0.0,
                    is_sphere=False, lin=eye, lin_inv=eye, cos_half_spot=-1.0,
                    spot_smooth=_SMOOTH_MAX, half_angle=0.0, cos_half_angle=1.0,
                    spread_tan=np.inf, spread_norm=0.0,
                    tri_uv=np.zeros((3, 2)), tex=-1, visible_camera=True,
                    visible_glossy=True, visible_transmission=True, cast_shadow=True)
        base.update(kw)
        rows.append(base)

    for li, lt in enumerate(scene.lights):
        Mw = np.asarray(lt.matrix_world, np.float64)
        M = Mw[:3, :3]
        co = Mw[:3, 3].copy()
        strength = np.asarray(lt.strength, np.float64).reshape(3)
        vis = dict(visible_camera=bool(lt.visible_camera), visible_glossy=bool(lt.visible_glossy),
                   visible_transmission=bool(lt.visible_transmission),
                   cast_shadow=bool(getattr(lt, "cast_shadow", True)))
        ez = -M[:, 2]
        nz = np.linalg.norm(ez)
        dirv = ez / nz if nz > 0 else np.array([0.0, 0.0, -1.0])
        kind = lt.kind.upper()
        if kind in ("POINT", "SPOT"):
            r = max(float(lt.radius), 0.0)
            # Cycles: eval_fac = 1 / (pi * area), area = 4 pi r^2 (4 when r = 0,
            # which makes eval_fac = 1/(4 pi): the intensity factor).
            radiance = strength / (np.pi * 4.0 * np.pi * r * r) if r > 0 else np.zeros(3)
            is_sphere = (not bool(getattr(lt, "use_soft_falloff", True))) and r > 0
            try:
                lin_inv = np.linalg.inv(M)
            except np.linalg.LinAlgError:
                lin_inv = eye
                warnings.append(f"light '{lt.name}': singular object matrix, scale ignored")
            common = dict(source=li, strength=strength, radiance=radiance, co=co, dir=dirv,
                          radius=r, is_sphere=is_sphere, **vis)
            prof = getattr(lt, "ies", None)
            if prof is not None:
                # Its frame: the object matrix (the IES node's object space).
                ies_rows[len(rows)] = (prof, M)
            if kind == "POINT":
                share = IES.mean_factor(prof) if prof is not None else 1.0
                row(kind=POINT, flux=strength * share, **common)
            else:
                h = 0.5 * float(lt.spot_size)
                cos_h = float(np.cos(h))
                blend = float(np.clip(lt.spot_blend, 0.0, 1.0))
                w = (1.0 - cos_h) * blend
                smooth = min(1.0 / w, _SMOOTH_MAX) if w > 0 else _SMOOTH_MAX
                lin = M if abs(np.linalg.det(M)) > 0 else eye
                omega = _spot_solid_angle(lin, cos_h, blend)
                if prof is not None:
                    omega = omega * IES.mean_factor(prof, cos_h, smooth)
                row(kind=SPOT, flux=strength / (4.0 * np.pi) * omega, lin=lin,
                    lin_inv=lin_inv, cos_half_spot=cos_h, spot_smooth=smooth, **common)
        elif kind == "SUN":
            h = 0.5 * max(float(lt.angle), 0.0)
            radiance = strength / (np.pi * np.sin(h) ** 2) if h > 0 else np.zeros(3)
            row(kind=SUN, source=li, strength=strength, radiance=radiance,
                flux=strength * np.pi * R * R, co=co, dir=dirv, half_angle=h,
                cos_half_angle=float(np.cos(h)), **vis)
        elif kind == "AREA":
            shape = lt.shape.upper()
            sx = float(lt.size)
            sy = float(lt.size_y) if shape in ("RECTANGLE", "ELLIPSE") else sx
            cu, cv = M[:, 0], M[:, 1]
            nu, nv = np.linalg.norm(cu), np.linalg.norm(cv)
            len_u, len_v = nu * abs(sx), nv * abs(sy)
            ellipse = shape in ("DISK", "ELLIPSE")
            area = len_u * len_v * (np.pi / 4.0 if ellipse else 1.0)
            radiance = strength / (np.pi * area) if area > 0 else np.zeros(3)
            spread_tan, spread_norm = _spread_params(float(lt.spread))
            if area <= 0:
                strength_eff = np.zeros(3)
                warnings.append(f"area light '{lt.name}' has zero area and emits nothing")
            else:
                strength_eff = strength
            row(kind=AREA, source=li, strength=strength_eff, radiance=radiance,
                flux=strength_eff.copy(), co=co,
                axis_u=cu / nu if nu > 0 else np.array([1.0, 0, 0]),
                axis_v=cv / nv if nv > 0 else np.array([0, 1.0, 0]),
                dir=dirv, len_u=len_u, len_v=len_v, area=area, ellipse=ellipse,
                spread_tan=spread_tan, spread_norm=spread_norm, **vis)
        else:
            warnings.append(f"light '{lt.name}': unknown kind {lt.kind!r}, ignored")

    # Emissive triangles (Cycles' mesh lights: Emission closure, two-sided).
    tex_mean = []
    for img in scene.textures:
        arr = np.asarray(img, np.float64)
        rgb = arr[..., :3] if arr.shape[-1] >= 3 else np.repeat(arr[..., :1], 3, axis=-1)
        tex_mean.append(rgb.reshape(-1, 3).mean(axis=0))
    emis_mats = [i for i, m in enumerate(scene.materials)
                 if np.any(np.asarray(m.emission, np.float64) != 0)]
    tri_rows = None
    if emis_mats and scene.n_triangles:
        sel = np.nonzero(np.isin(scene.tri_mat, emis_mats))[0]
        P = scene.tri_p[sel].astype(np.float64)
        e1 = P[:, 1] - P[:, 0]
        e2 = P[:, 2] - P[:, 0]
        cr = np.cross(e1, e2)
        A = 0.5 * np.linalg.norm(cr, axis=1)
        keep = A > 0
        sel, P, e1, e2, cr, A = sel[keep], P[keep], e1[keep], e2[keep], cr[keep], A[keep]
        mats = scene.tri_mat[sel]
        L = np.array([np.asarray(scene.materials[m].emission, np.float64) for m in mats]).reshape(-1, 3)
        tex = np.array([scene.materials[m].emission_texture for m in mats], np.int32).reshape(-1)
        tfac = np.ones((sel.shape[0], 3))
        for t in np.unique(tex):
            if 0 <= t < len(tex_mean):
                tfac[tex == t] = tex_mean[t]
        # Flux of a two-sided Lambertian emitter: 2 sides * pi * A * L
        # (texture: its image mean, an approximation used only for selection).
        flux = 2.0 * np.pi * A[:, None] * L * tfac
        tri_rows = dict(kind=np.full(sel.shape[0], MESH, np.int8), source=sel.astype(np.int32),
                        strength=L, radiance=L, flux=flux, co=P[:, 0], axis_u=e1, axis_v=e2,
                        dir=cr / (2.0 * A[:, None]), area=A, tri_uv=scene.tri_uv[sel].astype(np.float64),
                        tex=tex)
        if getattr(scene, "tri_visibility", None) is not None:
            # An emitting object hidden from the camera still lights the
            # scene; light tracing does not splat its emission to the lens.
            from ..accel import RAY_CAMERA
            tri_rows["visible_camera"] = (scene.tri_visibility[sel] & RAY_CAMERA) != 0
        from ..scene import holdout as Holdout, ray_variants as RV
        held = Holdout.ends_camera(Holdout.triangle_weights(scene))
        if held is not None:
            # Nor that of a held-out one (core.scene.holdout).
            tri_rows["visible_camera"] = tri_rows.get(
                "visible_camera", np.ones(sel.shape[0], bool)) & ~held[sel]
        cam = RV.rows(scene, "camera")
        if cam is not None:
            # Nor that of a surface whose material camera rays see without
            # emission (Light Path Is Camera Ray: an unseen light card).
            dark = np.array([not np.any(np.asarray(scene.materials[m].emission) != 0)
                             for m in cam[scene.tri_mat[sel]]], bool).reshape(-1)
            tri_rows["visible_camera"] = tri_rows.get(
                "visible_camera", np.ones(sel.shape[0], bool)) & ~dark

    world = np.asarray(scene.world_color, np.float64).reshape(3)
    env = None
    if getattr(scene, "world_map", None) is not None:
        # An environment map: the row's radiance is the map's mean (used for
        # selection weights); directions and powers come from the map.
        env = EnvironmentLight.build(scene.world_map)
        world = env.mean_radiance if env.total > 0 else np.zeros(3)
    if np.any(world != 0):
        # Every direction carries L_w through a disc of area pi R^2.
        # Its Glossy and Transmission visibility: whether a mirror or glass
        # chain's ray that escapes sees it (core.lights.seen.world_seen_by).
        from .lobe_visibility import GLOSSY_RAYS, TRANSMISSION_RAYS
        wh = int(getattr(scene, "world_hidden", 0))
        row(kind=WORLD, source=-1, strength=world, radiance=world,
            flux=world * 4.0 * np.pi * np.pi * R * R, co=center,
            visible_glossy=not wh & GLOSSY_RAYS, visible_transmission=not wh & TRANSMISSION_RAYS)

    table = _assemble(rows, tri_rows, center, R, D, world, warnings, scene.textures)
    table.environment = env
    if ies_rows:
        table.ies = IES.pack([ies_rows.get(j, (None,))[0] for j in range(table.n)],
                             [ies_rows.get(j, (None, np.eye(3)))[1] for j in range(table.n)])
    vis = getattr(scene, "tri_visibility", None)
    if vis is not None:
        from ..accel import RAY_SHADOW
        table.shadow_passes = bool(np.any((vis & RAY_SHADOW) == 0))
    from ..scene import ray_variants as RV
    if RV.rows(scene, "shadow") is not None:
        # Shadow rays see some material as another (Is Shadow Ray): they
        # pass what light paths meet, as with Shadow visibility off.
        table.shadow_passes = True
    table.camera_variants = RV.rows(scene, "camera") is not None
    if getattr(scene, "world_camera_map", None) is not None:
        table.camera_environment = EnvironmentLight.build(scene.world_camera_map)
    if scene.n_triangles:
        # min and max of the corners as stored (exact): no float64 copy of them
        P = np.asarray(scene.tri_p).reshape(-1, 3)
        t_lo, t_hi = P.min(axis=0).astype(np.float64), P.max(axis=0).astype(np.float64)
        table.triangle_box = (0.5 * (t_lo + t_hi), 0.5 * (t_hi - t_lo) + 0.5e-4 * D)
    table.spot_tail = _spot_tails(table, scene.tri_p)
    from ..scene.linking import emitter_sets
    table.link_sets = emitter_sets(scene, table)
    from .lobe_visibility import hidden_bits
    table.hidden = hidden_bits(scene, table)
    from ..scene.shadow_linking import emitter_shadow_sets
    table.shadow_sets = emitter_shadow_sets(scene, table)
    if table.shadow_sets is not None and getattr(scene, "tri_blocker", None) is not None:
        # Shadow rays of some emitter pass objects that light paths meet,
        # as with Shadow visibility off.
        table.shadow_passes = True
    else:
        table.shadow_sets = None
    return table


def _assemble(rows, tri_rows, center, R, D, world, warnings, textures) -> LightTable:
    names = ["kind", "source", "strength", "radiance", "flux", "co", "axis_u", "axis_v", "dir",
             "len_u", "len_v", "area", "ellipse", "radius", "is_sphere", "lin", "lin_inv",
             "cos_half_spot", "spot_smooth", "half_angle", "cos_half_angle", "spread_tan",
             "spread_norm", "tri_uv", "tex",
             "visible_camera", "visible_glossy", "visible_transmission", "cast_shadow"]
    dtypes = dict(kind=np.int8, source=np.int32, tex=np.int32, ellipse=bool, is_sphere=bool,
                  visible_camera=bool, visible_glossy=bool, visible_transmission=bool,
                  cast_shadow=bool)
    shapes = dict(strength=(3,), radiance=(3,), flux=(3,), co=(3,), axis_u=(3,), axis_v=(3,),
                  dir=(3,), lin=(3, 3), lin_inv=(3, 3), tri_uv=(3, 2))
    defaults = dict(cos_half_spot=-1.0, spot_smooth=_SMOOTH_MAX, cos_half_angle=1.0,
                    spread_tan=np.inf,
                    visible_camera=True, visible_glossy=True, visible_transmission=True,
                    cast_shadow=True, tex=-1)
    n_tri = 0 if tri_rows is None else tri_rows["kind"].shape[0]
    cols = {}
    for nm in names:
        dt = dtypes.get(nm, np.float64)
        a = np.array([r[nm] for r in rows], dtype=dt).reshape((len(rows),) + shapes.get(nm, ()))
        if n_tri:
            if nm in tri_rows:
                b = np.asarray(tri_rows[nm], dtype=dt).reshape((n_tri,) + shapes.get(nm, ()))
            elif nm in ("lin", "lin_inv"):
                b = np.broadcast_to(np.eye(3), (n_tri, 3, 3)).astype(dt)
            else:
                b = np.full((n_tri,) + shapes.get(nm, ()), defaults.get(nm, 0), dtype=dt)
            # Row order: Blender lights, the world (if any), then triangles.
            a = np.concatenate([a, b], axis=0)
        cols[nm] = a
    lumf = _lum(cols["flux"]) if cols["flux"].shape[0] else np.zeros(0)
    tot = lumf.sum()
    p_select = lumf / tot if tot > 0 else np.zeros_like(lumf)
    t = LightTable(**cols, p_select=p_select, center=np.asarray(center, np.float64),
                   radius_scene=float(R), a_max=float(D) ** 2, world=world,
                   textures=list(textures), warnings=warnings)
    _direct_entries(t)
    return t


#: The least share of a soft spot's photons sent beyond its cone (a cone
#: of half-angle 0 would otherwise send none).
SPOT_TAIL_MIN = 0.01


def _spot_tails(t: LightTable, tri_p) -> np.ndarray:
    """(Nl, 4): each soft spot's photons beyond its cone, (share P, x0, X, h)
    (lights.emission.spot_pdf_local), zeros for every other light.

    Reach X: a photon leaving the centre along w first hits p = c + t w at
    t >= t_near (the nearest triangle's distance); a disc sample y = c + r u
    (|u| <= 1) sees it along t w - r u, whose local direction (the inverse
    object matrix L applied) lies within asin(k r / t_near) of L w, k =
    cond(L) (1 for rotation and uniform scale).  So no direction beyond the
    cone's half-angle h plus X = asin(k r / t_near) is lit by any disc
    sample's cone; X reaches the whole sphere (pi - h) where k r >= t_near
    (or t_near is unknown: tri_p None).

    Shape x0 = asin(k r / t_far), the blur of a receiver at the distance of
    the triangles' centre (at least t_near): just outside the cone's edge
    the disc's inner half lights the receiver, so the field there is about
    kappa = 1/2 x (the cone's attenuation averaged over the last x0 inside
    the edge) / (its average over the cone) of the cone's mean, and it
    falls to 0 over about x0; the density beyond the cone falls as
    1 / (1 + x / x0)^2 from kappa times the cone's own, so that a photon
    just outside the edge weighs about what an average one inside does
    (P from that, at least SPOT_TAIL_MIN, at most 1/2).  A hard edge gives
    kappa 1/2; a blend wider than x0 leaves little light beyond the edge
    and sends few photons there.
    """
    out = np.zeros((t.n, 4))
    centre = t.triangle_box[0] if t.triangle_box is not None else t.center
    for j in np.nonzero(t.soft_spot)[0]:
        cos_h = float(np.clip(t.cos_half_spot[j], -1.0, 1.0))
        h = np.arccos(cos_h)
        co = np.asarray(t.co[j], np.float64)
        near = 0.0 if tri_p is None else _nearest_triangle(np.asarray(tri_p), *co)
        s = np.linalg.cond(np.asarray(t.lin[j], np.float64)) * t.radius[j]
        X = np.pi - h if not s < near else min(np.pi - h, np.arcsin(s / near))
        far = max(float(np.linalg.norm(co - centre)), near, s)
        x0 = max(min(X, np.arcsin(min(1.0, s / far))), 1e-9)
        A = 1.0 - 1.0 / (1.0 + X / x0)
        mid = (np.arange(64) + 0.5) / 64
        att = lambda c: _smoothstep((c - cos_h) * t.spot_smooth[j])   # noqa: E731
        a_cone = float(np.mean(att(cos_h + (1.0 - cos_h) * mid)))    # uniform in solid angle
        a_edge = float(np.mean(att(np.cos(h - min(x0, h) * mid))))
        kappa = 0.5 * a_edge / a_cone if a_cone > 0 else 0.5
        ratio = kappa * 2.0 * np.pi * np.sin(h) * x0 * A / (2.0 * np.pi * (1.0 - cos_h))
        P = min(max(ratio / (1.0 + ratio), SPOT_TAIL_MIN), 0.5)
        out[j] = (P, x0, X, h)
    return out


def _nearest_triangle(tri_p, px, py, pz) -> float:
    """The distance from p to the nearest of the triangles tri_p (T, 3, 3)
    (inf without any)."""
    from ..frequency.occlusion_grid import nearest_distance
    return float(nearest_distance(tri_p, px, py, pz)) if len(tri_p) else np.inf


def _direct_entries(t: LightTable) -> None:
    """Entries of the per-point NEE selection.

    Every non-mesh emitter is one entry.  Emissive triangles are one entry each
    when there are few; otherwise they form one group entry whose weight uses
    the group's bounding sphere and whose triangle is then drawn by flux.
    """
    tri = np.nonzero(t.kind == MESH)[0]
    other = np.nonzero(t.kind != MESH)[0]
    lum_tri = _lum(t.flux[tri]) if tri.size else np.zeros(0)
    tri = tri[lum_tri > 0]
    lum_tri = lum_tri[lum_tri > 0]
    if tri.size <= _MAX_TRI_ENTRIES:
        t.entry_emitter = np.concatenate([other, tri]).astype(np.int64)
        t.group_tri = np.zeros(0, np.int64)
        t.group_cdf = np.zeros(0)
    else:
        t.entry_emitter = np.concatenate([other, [-1]]).astype(np.int64)
        t.group_tri = tri.astype(np.int64)
        t.group_cdf = np.cumsum(lum_tri)
        pts = np.concatenate([t.co[tri], t.co[tri] + t.axis_u[tri], t.co[tri] + t.axis_v[tri]])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        t.group_center = 0.5 * (lo + hi)
        t.group_ext2 = float(0.25 * np.sum((hi - lo) ** 2))
