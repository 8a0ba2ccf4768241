"""Emitters in Cycles' units: photon emission, next-event estimation, visible lights.

One flat structure-of-arrays table (:class:`LightTable`) holds every emitter of a
:class:`core.scene.Scene`: Blender lights (point, spot, sun, area), emissive
triangles and the constant world colour.  Units and shapes follow Cycles 5.2
(``docs/cycles_units.md``, "Cycles' units"), read from Cycles' sources
``intern/cycles/kernel/light/{point,spot,area,distant,background,triangle}.h``
and ``intern/cycles/scene/light.cpp``:

============  =================================================================
emitter       model (strength = color * energy * 2**exposure)
============  =================================================================
point r = 0   intensity I = strength / (4 pi) [W/sr], flux = strength.
point r > 0   Cycles' default ``use_soft_falloff``: a disc of radius r always
              facing the shading point, radiance L = strength / (pi * 4 pi r^2)
              (``eval_fac = 1 / (pi * area)``, area = 4 pi r^2).  Irradiance
              on a facing receiver at distance d: I / (d^2 + r^2) ("soft"
              near field), I / d^2 far field.  ``use_soft_falloff = False``
              (attribute read with getattr, default True): a sphere of the same
              radiance, irradiance I / d^2 down to the surface.
spot          point model times Cycles' smoothstep((cos_local - cos(size/2)) /
              ((1 - cos(size/2)) * blend)), evaluated on the direction from the
              light sample to the receiver mapped to the light's local frame
              (object scale makes the cone elliptic).  NOT renormalised:
              flux = strength / (4 pi) * int smoothstep d omega.
sun           irradiance S = strength on a plane perpendicular to local -Z; with
              angle > 0 a cone of half-angle h = angle / 2 and radiance
              S / (pi sin^2 h) (its projected solid angle is pi sin^2 h cos).
area          one-sided Lambertian towards local -Z, L = strength / (pi A),
              A = |scale_x| size * |scale_y| size_y (* pi/4 for disc/ellipse),
              flux = strength.  ``spread`` < 180 deg is not supported (treated
              as 180 deg, noted in ``LightTable.warnings``).  Never occludes.
mesh          Cycles' Emission closure: L = Material.emission (times its
              texture), two-sided, per-triangle flux 2 * pi * A * L.
world         constant radiance L_w from every direction.
============  =================================================================

Photons (:func:`sample_photons`) carry ``power = Phi_light(sample) / p_select``
so that the SPPM density estimate is tau / (pi R^2 N_emitted) (pbrt-v4).
Sun and world photons start on a disc of radius R (the scene's bounding sphere)
perpendicular to their direction, at distance R from the scene centre, so their
total flux is S pi R^2 (sun) and 4 pi^2 R^2 L_w (world).

Point/spot lights with r > 0: Cycles' default soft falloff is a disc of
radiance L turned towards each receiver, so the irradiance is exactly
I cos / (d^2 + r^2) (its projected solid angle is pi r^2 / (d^2 + r^2) cos).
No physical emitter produces that field (it is not a light field), so photons
leave the centre and carry ``falloff_r2 = r^2``: the photon tracer multiplies
the power by t^2 / (t^2 + r^2) at the first hit (far field and first-hit field
then match Cycles, and the bounced light inherits it).  Without soft
falloff (sphere model) photons leave the sphere, Lambertian about its normal.

Next-event estimation (:func:`sample_direct`) picks one emitter per receiver with
probability ~ an irradiance bound (flux over squared distance), then samples it:
rectangles and large emissive triangles uniformly in solid angle (Urena et al.
2013, Arvo 1995; as Cycles does), discs/ellipses and small triangles by area,
point/spot discs by area, sun cones and sphere caps uniformly.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..scene.model import Scene
from ..scene.textures import sample_texture

# Emitter kinds (LightTable.kind, photon "kind").
POINT = 0
SPOT = 1
SUN = 2
AREA = 3
MESH = 4
WORLD = 5
KIND_NAMES = {POINT: "point", SPOT: "spot", SUN: "sun", AREA: "area",
              MESH: "mesh", WORLD: "world"}

# Angular variance of a cosine-weighted diffuse lobe, pi^2/4 - 2 = 0.467 rad^2
# (docs/frequency.md "Lobe widths"): the angular init of every non-collimated light.
B_DIFFUSE = np.pi ** 2 / 4.0 - 2.0

# Rec. 709 luminance (Blender's default scene-linear space).
from ..mathutil import LUMINANCE as _LUM, dot as _dot  # noqa: E402

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
    tri_uv: (Nl, 3, 2) corner UVs, tex: (Nl,) int32 emission texture or -1.
    visible_camera / visible_glossy / visible_transmission / cast_shadow:
      (Nl,) bool.
    center (3,), radius_scene: bounding sphere; a_max: D^2 (docs/frequency.md).
    world: (3,) world radiance.  warnings: list of str.
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

    @property
    def n(self) -> int:
        return int(self.kind.shape[0])

    @property
    def total_flux(self) -> np.ndarray:
        """(3,) sum of ``flux`` over all emitters."""
        return self.flux.sum(axis=0) if self.n else np.zeros(3)


# ----------------------------------------------------------------------------
# Small vector helpers, all (K, 3) float64.

def _normalize(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _lum(rgb):
    return np.maximum(np.asarray(rgb, np.float64) @ _LUM, 0.0)


def _basis(n):
    """Orthonormal tangents (t, b) of unit normals n (K, 3) (Duff et al. 2017)."""
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + s * n[:, 0] ** 2 * a, s * b, -s * n[:, 0]], axis=1)
    bb = np.stack([b, s + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, bb


def _to_world(local, n):
    t, b = _basis(n)
    return local[:, :1] * t + local[:, 1:2] * b + local[:, 2:3] * n


def _unit_disk(u1, u2):
    """Uniform points in the unit disc, (K,) x and y."""
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    return r * np.cos(phi), r * np.sin(phi)


def _uniform_sphere(u1, u2):
    z = 1.0 - 2.0 * u1
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * u2
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def _cone_local(cos_max, u1, u2):
    """Uniform directions in the cone cos(theta) >= cos_max around +z (local)."""
    z = 1.0 - u1 * (1.0 - cos_max)
    s = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = 2.0 * np.pi * u2
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def _cosine_local(u1, u2):
    """Cosine-weighted directions about +z, pdf cos/pi (Malley)."""
    x, y = _unit_disk(u1, u2)
    z = np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))
    return np.stack([x, y, z], axis=1)


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


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
    n_mu, n_phi = 512, 256
    mu = cos_h + (1.0 - cos_h) * (np.arange(n_mu) + 0.5) / n_mu
    phi = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    MU, PH = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(np.maximum(1.0 - MU ** 2, 0.0))
    v = np.stack([st * np.cos(PH), st * np.sin(PH), -MU], axis=-1).reshape(-1, 3)
    smooth = 1.0 / w if w > 0 else _SMOOTH_MAX
    att = _smoothstep((MU.ravel() - cos_h) * smooth)
    jac = abs(np.linalg.det(lin)) / np.linalg.norm(v @ lin.T, axis=1) ** 3
    dA = (1.0 - cos_h) / n_mu * 2.0 * np.pi / n_phi
    return float(np.sum(att * jac) * dA)


def _spot_atten(table: LightTable, j: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Cycles' spot attenuation of world directions w (K,3) leaving lights j (K,).

    The direction is mapped to the light's local frame (inverse object matrix,
    so scale makes the cone elliptic) and its cosine to local -Z is used.
    """
    loc = np.einsum("kij,kj->ki", table.lin_inv[j], w)
    loc = _normalize(loc)
    return _smoothstep((-loc[:, 2] - table.cos_half_spot[j]) * table.spot_smooth[j])


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
    eye = np.eye(3)

    def row(**kw):
        base = dict(kind=POINT, source=-1, strength=np.zeros(3), radiance=np.zeros(3),
                    flux=np.zeros(3), co=np.zeros(3), axis_u=np.array([1.0, 0, 0]),
                    axis_v=np.array([0, 1.0, 0]), dir=np.array([0, 0, -1.0]),
                    len_u=0.0, len_v=0.0, area=0.0, ellipse=False, radius=0.0,
                    is_sphere=False, lin=eye, lin_inv=eye, cos_half_spot=-1.0,
                    spot_smooth=_SMOOTH_MAX, half_angle=0.0, cos_half_angle=1.0,
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
            if kind == "POINT":
                row(kind=POINT, flux=strength.copy(), **common)
            else:
                h = 0.5 * float(lt.spot_size)
                cos_h = float(np.cos(h))
                blend = float(np.clip(lt.spot_blend, 0.0, 1.0))
                w = (1.0 - cos_h) * blend
                smooth = min(1.0 / w, _SMOOTH_MAX) if w > 0 else _SMOOTH_MAX
                lin = M if abs(np.linalg.det(M)) > 0 else eye
                omega = _spot_solid_angle(lin, cos_h, blend)
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
            if float(lt.spread) < np.pi - 1e-4:
                warnings.append(
                    f"area light '{lt.name}': spread {np.degrees(lt.spread):.1f} deg is not "
                    f"supported; rendered as 180 deg")
            if area <= 0:
                strength_eff = np.zeros(3)
                warnings.append(f"area light '{lt.name}' has zero area and emits nothing")
            else:
                strength_eff = strength
            row(kind=AREA, source=li, strength=strength_eff, radiance=radiance,
                flux=strength_eff.copy(), co=co,
                axis_u=cu / nu if nu > 0 else np.array([1.0, 0, 0]),
                axis_v=cv / nv if nv > 0 else np.array([0, 1.0, 0]),
                dir=dirv, len_u=len_u, len_v=len_v, area=area, ellipse=ellipse, **vis)
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

    world = np.asarray(scene.world_color, np.float64).reshape(3)
    if np.any(world != 0):
        # Every direction carries L_w through a disc of area pi R^2.
        row(kind=WORLD, source=-1, strength=world, radiance=world,
            flux=world * 4.0 * np.pi * np.pi * R * R, co=center)

    table = _assemble(rows, tri_rows, center, R, D, world, warnings, scene.textures)
    return table


def _assemble(rows, tri_rows, center, R, D, world, warnings, textures) -> LightTable:
    names = ["kind", "source", "strength", "radiance", "flux", "co", "axis_u", "axis_v", "dir",
             "len_u", "len_v", "area", "ellipse", "radius", "is_sphere", "lin", "lin_inv",
             "cos_half_spot", "spot_smooth", "half_angle", "cos_half_angle", "tri_uv", "tex",
             "visible_camera", "visible_glossy", "visible_transmission", "cast_shadow"]
    dtypes = dict(kind=np.int8, source=np.int32, tex=np.int32, ellipse=bool, is_sphere=bool,
                  visible_camera=bool, visible_glossy=bool, visible_transmission=bool,
                  cast_shadow=bool)
    shapes = dict(strength=(3,), radiance=(3,), flux=(3,), co=(3,), axis_u=(3,), axis_v=(3,),
                  dir=(3,), lin=(3, 3), lin_inv=(3, 3), tri_uv=(3, 2))
    defaults = dict(cos_half_spot=-1.0, spot_smooth=_SMOOTH_MAX, cos_half_angle=1.0,
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


# ----------------------------------------------------------------------------
# Photon emission.

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
        receiver has projected solid angle pi r^2 / (d^2 + r^2) cos).
    """
    n = int(n)
    o = np.zeros((n, 3))
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    power = np.zeros((n, 3))
    freq = np.zeros((n, 3))
    light = np.full(n, -1, np.int32)
    kind = np.full(n, -1, np.int8)
    falloff = np.zeros(n)
    out = dict(o=o, d=d, power=power, light=light, kind=kind, freq_init=freq,
               falloff_r2=falloff)
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

    for k in (POINT, SPOT):
        m = np.nonzero(kind == k)[0]
        if not m.size:
            continue
        jj = j[m]
        if k == POINT:
            w = _uniform_sphere(u[m, 3], u[m, 4])
            weight = table.strength[jj]          # Phi = 4 pi I, pdf 1/(4 pi)
        else:
            # Uniform in the local cone, mapped by the object matrix;
            # d omega = |det M| / |M v|^3 d v.
            cos_h = table.cos_half_spot[jj]
            v = _cone_local(cos_h, u[m, 3], u[m, 4])
            v[:, 2] = -v[:, 2]                   # local axis is -Z
            Mv = np.einsum("kij,kj->ki", table.lin[jj], v)
            nMv = np.linalg.norm(Mv, axis=1)
            w = Mv / nMv[:, None]
            jac = np.abs(np.linalg.det(table.lin[jj])) / nMv ** 3
            att = _smoothstep((-v[:, 2] - cos_h) * table.spot_smooth[jj])
            weight = (table.strength[jj] / (4.0 * np.pi)
                      * (att * jac * 2.0 * np.pi * (1.0 - cos_h))[:, None])
        # Sphere model (no soft falloff): origin on the sphere, Lambertian about
        # its normal.  For a given direction w such origins are uniform over
        # the disc perpendicular to w, lifted onto the hemisphere facing w.
        # Soft falloff (Cycles' default disc facing the receiver): from the
        # centre, with the first-hit factor t^2 / (t^2 + r^2) left to the caller.
        r = np.where(table.is_sphere[jj], table.radius[jj], 0.0)
        falloff[m] = np.where(table.is_sphere[jj], 0.0, table.radius[jj] ** 2)
        x, y = _unit_disk(u[m, 1], u[m, 2])
        t1, t2 = _basis(w)
        lift = np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))
        off = (x[:, None] * t1 + y[:, None] * t2 + lift[:, None] * w) * r[:, None]
        o[m] = table.co[jj] + off
        d[m] = w
        power[m] = weight * inv_p[m, None]
        freq[m] = (0.0, B_DIFFUSE, 0.0)

    m = np.nonzero(kind == AREA)[0]
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
        d[m] = _to_world(_cosine_local(u[m, 3], u[m, 4]), table.dir[jj])
        power[m] = table.flux[jj] * inv_p[m, None]
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
        x, y = _unit_disk(u[m, 1], u[m, 2])
        t1, t2 = _basis(axis)
        o[m] = table.center - R * axis + R * (x[:, None] * t1 + y[:, None] * t2)
        d[m] = w
        power[m] = table.flux[jj] * inv_p[m, None]
        freq[m, 0] = table.a_max
        freq[m, 1] = h * h / 3.0

    m = np.nonzero(kind == WORLD)[0]
    if m.size:
        jj = j[m]
        w = _uniform_sphere(u[m, 3], u[m, 4])
        x, y = _unit_disk(u[m, 1], u[m, 2])
        t1, t2 = _basis(w)
        o[m] = table.center - R * w + R * (x[:, None] * t1 + y[:, None] * t2)
        d[m] = w
        power[m] = table.flux[jj] * inv_p[m, None]
        freq[m] = (table.a_max, B_DIFFUSE, 0.0)

    m = np.nonzero(kind == MESH)[0]
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


def _triangle_bary(u1, u2):
    """Uniform barycentrics (b1, b2) on a triangle (p = p0 + b1 e1 + b2 e2)."""
    s = np.sqrt(u1)
    return s * (1.0 - u2), s * u2


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
# Next-event estimation.

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
            t1, t2 = _basis(lightN[dk])
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
            att = _spot_atten(table, jj, -w_dir)
            if np.any(sk):
                inside = sk & (d <= r)
                att = np.where(inside, 1.0, att)  # Cycles: no attenuation inside
            Lw *= att[:, None]
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
    if m.size:
        jj = j[m]
        if n is None:
            fill(m, _uniform_sphere(u1[m], u2[m]), np.full(m.size, np.inf),
                 table.strength[jj] * 4.0 * np.pi)
        else:
            nm = np.asarray(n, np.float64).reshape(-1, 3)[m]
            r = np.sqrt(u1[m])
            phi = 2.0 * np.pi * u2[m]
            cz = np.sqrt(np.maximum(1.0 - u1[m], 0.0))
            t, b = _basis(nm)
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
            qs, S = _sample_spherical_rect(pr, corner, table.axis_u[jr], table.len_u[jr],
                                           table.axis_v[jr], table.len_v[jr],
                                           u1[m[rect]], u2[m[rect]])
            front = _dot(pr - table.co[jr], table.dir[jr]) > 0
            use = np.nonzero(S > 1e-6)[0]          # else: area sampling (float cancellation)
            if use.size:
                vr = qs[use] - pr[use]
                tr = np.linalg.norm(vr, axis=1)
                k = rect[use]
                wd[k] = vr / np.maximum(tr, 1e-300)[:, None]
                tt[k] = tr
                Lw[k] = table.radiance[jr[use]] * np.where(front[use], S[use], 0.0)[:, None]
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


# ----------------------------------------------------------------------------
# Lights seen by rays.

def _ray_disc(o, d, c, n, r, t_max):
    """Hit distance of rays with discs (centre c, unit normal n, radius r), inf on miss."""
    den = _dot(d, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _dot(c - o, n) / den
    hit = np.isfinite(t) & (t > 0) & (t < t_max)
    q = o + np.where(hit, t, 0.0)[:, None] * d - c
    hit &= np.sum(q * q, axis=1) <= r * r
    return np.where(hit, t, np.inf)


def emitted_along_rays(table: LightTable, o: np.ndarray, d: np.ndarray, t_max: np.ndarray,
                       visibility: str = "camera") -> np.ndarray:
    """Radiance (K, 3) of analytic emitters hit by rays o + t d, 0 < t < t_max.

    Area lights (front side only), point/spot lights with radius > 0 (Cycles'
    disc facing the ray origin, or the sphere without soft falloff) and, for
    rays that escape (t_max = inf), the disc of a sun with angle > 0.  The
    nearest light hit wins; lights whose ``visible_<visibility>`` flag is off
    are skipped.  Mesh emission and the world are not included.
    visibility: 'camera', 'glossy' or 'transmission'.
    """
    o = np.asarray(o, np.float64).reshape(-1, 3)
    d = np.asarray(d, np.float64).reshape(-1, 3)
    K = o.shape[0]
    t_max = np.broadcast_to(np.asarray(t_max, np.float64), (K,))
    Lout = np.zeros((K, 3))
    if K == 0 or table.n == 0:
        return Lout
    flags = {"camera": table.visible_camera, "glossy": table.visible_glossy,
             "transmission": table.visible_transmission}
    if visibility not in flags:
        raise ValueError(f"visibility must be 'camera', 'glossy' or 'transmission', "
                         f"not {visibility!r}")
    flag = flags[visibility]
    best = t_max.copy()
    for j in np.nonzero(flag & (table.kind != MESH) & (table.kind != WORLD))[0]:
        k = table.kind[j]
        if not np.any(table.radiance[j] != 0):
            continue
        if k == AREA:
            n = table.dir[j]
            den = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((table.co[j] - o) @ n) / den
            # Front side: the ray travels against the emission direction.
            hit = np.isfinite(t) & (t > 0) & (t < best) & (den < 0)
            q = o + np.where(hit, t, 0.0)[:, None] * d - table.co[j]
            a = 2.0 * (q @ table.axis_u[j]) / table.len_u[j]
            b = 2.0 * (q @ table.axis_v[j]) / table.len_v[j]
            if table.ellipse[j]:
                hit &= a * a + b * b <= 1.0
            else:
                hit &= (np.abs(a) <= 1.0) & (np.abs(b) <= 1.0)
            L = np.broadcast_to(table.radiance[j], (K, 3))
        elif k in (POINT, SPOT):
            r = table.radius[j]
            if r <= 0:
                continue
            c = table.co[j]
            oc = o - c
            if table.is_sphere[j]:
                b = _dot(d, oc)
                cc = np.sum(oc * oc, axis=1) - r * r
                disc = b * b - cc
                sq = np.sqrt(np.maximum(disc, 0.0))
                t0 = -b - sq
                t = np.where(t0 > 0, t0, -b + sq)
                hit = (disc >= 0) & (t > 0) & (t < best)
            else:
                n = _normalize(oc)
                t = _ray_disc(o, d, np.broadcast_to(c, (K, 3)), n, r, best)
                hit = np.isfinite(t)
            L = np.broadcast_to(table.radiance[j], (K, 3))
            if k == SPOT:
                hit &= _dot(d, oc) < 0                # Cycles: one-sided spot disc
                att = _spot_atten(table, np.full(K, j), -d)
                L = L * att[:, None]
        elif k == SUN:
            if table.half_angle[j] <= 0:
                continue
            t = np.full(K, np.inf)
            hit = np.isinf(best) & ((-d @ table.dir[j]) >= table.cos_half_angle[j])
            L = np.broadcast_to(table.radiance[j], (K, 3))
            # The sun never beats a finite hit; a later finite light would.
            Lout[hit] = L[hit]
            continue
        else:
            continue
        best = np.where(hit, t, best)
        Lout[hit] = L[hit]
    return Lout


def world_radiance(table: LightTable) -> np.ndarray:
    """(3,) constant world background radiance."""
    return table.world.copy()
