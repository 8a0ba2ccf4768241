"""The film: the radiance estimate of every pixel, its alpha and the passes, from the progressive state.

    L = L_sum / passes + tau / (pi R^2 N_emitted)        (docs/method.md, "Film")

(direct light and emission averaged over the passes, plus the photon density
estimate of Hachisuka 2008).  PASSES is the one table of the passes beyond
Combined: Blender's pass name, channels, channel id and type, the flag that
turns it on (a RenderSettings field or a view-layer property) and how it is
computed.  The standard passes follow Cycles' conventions (kernel/film/
data_passes.h, denoising_passes.h): Depth, Position, Object Index and Material Index come
from the first pass only (Cycles: sample 0), Normal, Mist, Emission and the denoising
passes are means over the passes (over filter samples, so edges average);
README.md "Passes" lists them.  Alpha (Film > Transparent) is the
mean over passes of 1 - the throughput with which the camera ray escaped
to the world (straight through Transparent BSDFs), Cycles' definition.
Every integrator with camera rays (PHOTON, PATH, COMBINED) accumulates the
camera pass's first hits here, so the alpha and passes are computed once.

The image, the radius and the radius in pixels come from one compiled
kernel per pixel range (``core.sppm.film_kernels``, split over the numba threads from
PARALLEL_MIN pixels); ``Film(..., compiled=False)`` is its numpy reference,
the same operations in the same order (tests/test_compiled_pass_stages.py:
the same bits).  The AOVs are numpy.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple, Optional

import numpy as np

from ..kept import KeptArrays
from ..scene.holdout import triangle_weights
from . import color_passes as CP
from .cryptomatte import Mattes
from .shadow_catcher import PASS as CATCHER_PASS

_F32_MAX = np.finfo(np.float32).max
#: Pixels from which the film kernel splits over the numba threads.
PARALLEL_MIN = 1 << 16


@dataclass
class PassResult:
    """What a pass shows: image (H, W, 4) float32 RGBA linear radiance with row
    0 at the TOP, aovs name -> (H, W, C) float32, counters and statistics."""
    pass_index: int
    photons_emitted: int
    elapsed: float
    image: np.ndarray
    aovs: dict = field(default_factory=dict)
    mean_radius_px: float = 0.0
    held_fraction: float = 0.0

    def stats_line(self) -> str:
        m, s = divmod(int(self.elapsed), 60)
        line = (f"Pass {self.pass_index} | {self.photons_emitted / 1e6:.1f} M photons | "
                f"{m}:{s:02d}")
        # Path and light tracing have no kernel radius (0): say nothing of it.
        if self.mean_radius_px > 0:
            line += f" | mean radius {self.mean_radius_px:.2f} px"
        return line


class FilmPass(NamedTuple):
    """One pass of the render result beyond Combined.

    name, channels, chan_id, kind: as Blender's RenderEngine.register_pass
    takes them.  flag: the RenderSettings field that turns it on, or
    "view_layer.<property>" (a property of the view layer, e.g. use_pass_z,
    or "view_layer.cycles.denoising_store_passes").  source: how it is made --
      'state': compute(state, R, r_px) -> (P, C) or (P,) from the PixelState,
        the radius R (P,) [m] (0 = none yet) and the radius in pixel
        footprints r_px (P,), at film time;
      'mean': compute(sample) -> (P, C) per pass from a PassSample, averaged
        over the passes, then finish(mean) (None: the mean itself);
      'first': compute(sample) of pass 1 only (Cycles writes these on its
        first sample: an edge pixel gets one object, not a blend).
    """
    name: str
    channels: int
    chan_id: str
    kind: str
    flag: str
    source: str
    compute: Callable
    finish: Optional[Callable] = None


class PassSample(NamedTuple):
    """One pass's camera data for the 'mean' / 'first' passes.

    first: core.sppm.visible_points.FirstHit; vp: VisiblePoints (the visible
    points, where the denoising features are taken, as Cycles follows
    specular bounces to the first rough surface); scene: core Scene; eye (3,)
    camera position, view (3,) unit viewing direction, R_wc (3, 3) world ->
    camera rotation (rows: camera x, y, -z axes in world space, so camera-space
    z is the distance in front of the camera, Cycles' convention);
    mtab, light_table: the render's materials and lights (the colour and
    Environment passes; None: those passes are 0); memo: values the passes
    of one PassSample share (``core.sppm.color_passes.line_albedos``);
    accel: the shadow rays' view of the scene and rng a Generator (the
    Ambient Occlusion pass's rays; None: that pass is 0).
    """
    first: object
    vp: object
    scene: object
    eye: np.ndarray
    view: np.ndarray
    R_wc: np.ndarray
    mtab: object = None
    light_table: object = None
    memo: Optional[dict] = None
    accel: object = None
    rng: object = None


#: Cycles' Depth of a pixel whose first sample escaped (its pass accessor
#: turns the empty value into 1e10).
DEPTH_MISS = 1e10


def _spectrum(s, R, r_px):
    # The PAPER model is unguarded by design and can overflow: the AOV stays
    # finite (NaN -> 0, +-inf -> +-float32 max) so viewers cope.
    return np.nan_to_num(np.clip(s.spectrum, -_F32_MAX, _F32_MAX), nan=0.0)


def _depth(x: PassSample):
    """Camera-space z of the first hit (Cycles camera_z_depth), DEPTH_MISS on a miss."""
    z = (x.first.p - x.eye) @ x.view
    return np.where(x.first.hit, z, DEPTH_MISS)


def _mist_transmittance(x: PassSample):
    """(1 - mist) per pass, 0 on a miss; the pass is 1 - its mean (Cycles
    data_passes.h: mist = saturate((d - start) / depth) ^ falloff, d the
    distance to the camera (orthographic: along the view direction))."""
    start, depth, falloff = x.scene.mist
    d = x.first.p - x.eye
    dist = np.abs(d @ x.view) if x.scene.camera.kind == "ORTHO" else np.linalg.norm(d, axis=1)
    m = np.clip((dist - start) / max(depth, 1e-30), 0.0, 1.0) ** falloff
    return np.where(x.first.hit, 1.0 - m, 0.0)


def _position(x: PassSample):
    """World-space position of the first hit (Cycles' Position pass), 0 on a miss."""
    return np.where(x.first.hit[:, None], x.first.p, 0.0)


def _object_index(x: PassSample):
    idx = x.scene.tri_object_index
    if idx is None:
        return np.zeros(x.first.hit.shape)
    return np.where(x.first.hit, idx[np.maximum(x.first.prim, 0)], 0).astype(np.float64)


def _material_index(x: PassSample):
    mpi = x.scene.material_pass_index
    if mpi is None or len(mpi) == 0:
        return np.zeros(x.first.hit.shape)
    mat = x.scene.tri_mat[np.maximum(x.first.prim, 0)]
    return np.where(x.first.hit, mpi[mat], 0).astype(np.float64)


def _denoising_albedo(x: PassSample):
    """Lambert albedo at the visible point times the specular chain's
    throughput (Cycles' denoising albedo of a diffuse surface); a first hit
    without a visible point (an emission-only surface) gives the emission
    it shows, as Cycles writes there; 0 on a miss."""
    v, f = x.vp, x.first
    emitter = (~v.valid & f.hit)[:, None]
    return np.where(v.valid[:, None], v.beta * v.albedo, np.where(emitter, f.emit, 0.0))


def _denoising_normal(x: PassSample):
    """Shading normal at the visible point in camera space (Cycles
    denoising_passes.h transforms it with worldtocamera), 0 on none."""
    v = x.vp
    return np.where(v.valid[:, None], v.ns @ x.R_wc.T, 0.0)


PASSES = (
    # FPPM's own AOVs, from the progressive state.
    FilmPass("FPPM Radius", 1, "X", "VALUE", "aov_radius", "state", lambda s, R, r_px: R),
    FilmPass("FPPM Radius px", 1, "X", "VALUE", "aov_radius", "state", lambda s, R, r_px: r_px),
    FilmPass("Predicted Radius", 1, "X", "VALUE", "aov_predicted_radius", "state",
             lambda s, R, r_px: np.where(np.isfinite(s.r_pred_last), s.r_pred_last, 0.0)),
    FilmPass("Spectrum", 3, "XYZ", "VECTOR", "aov_spectrum", "state", _spectrum),
    FilmPass("Photon Count", 1, "X", "VALUE", "aov_photon_count", "state", lambda s, R, r_px: s.N),
    FilmPass("Held", 1, "X", "VALUE", "aov_held", "state", lambda s, R, r_px: s.held),
    # Blender's standard passes, Cycles' conventions.
    FilmPass("Depth", 1, "Z", "VALUE", "view_layer.use_pass_z", "first", _depth),
    FilmPass("Mist", 1, "Z", "VALUE", "view_layer.use_pass_mist", "mean", _mist_transmittance,
             lambda mean: 1.0 - mean),
    FilmPass("Normal", 3, "XYZ", "VECTOR", "view_layer.use_pass_normal", "mean",
             lambda x: x.first.n),
    FilmPass("Position", 3, "XYZ", "VECTOR", "view_layer.use_pass_position", "first", _position),
    FilmPass("Object Index", 1, "X", "VALUE", "view_layer.use_pass_object_index", "first", _object_index),
    FilmPass("Material Index", 1, "X", "VALUE", "view_layer.use_pass_material_index", "first",
             _material_index),
    FilmPass("Emission", 3, "RGB", "COLOR", "view_layer.use_pass_emit", "mean", lambda x: x.first.emit),
    FilmPass("Denoising Normal", 3, "XYZ", "VECTOR", "view_layer.cycles.denoising_store_passes",
             "mean", _denoising_normal),
    FilmPass("Denoising Albedo", 3, "RGB", "COLOR", "view_layer.cycles.denoising_store_passes",
             "mean", _denoising_albedo),
    FilmPass("Diffuse Color", 3, "RGB", "COLOR", "view_layer.use_pass_diffuse_color", "mean",
             CP.color_pass(CP.COLOR_PASSES["Diffuse Color"])),
    FilmPass("Glossy Color", 3, "RGB", "COLOR", "view_layer.use_pass_glossy_color", "mean",
             CP.color_pass(CP.COLOR_PASSES["Glossy Color"])),
    FilmPass("Transmission Color", 3, "RGB", "COLOR", "view_layer.use_pass_transmission_color",
             "mean", CP.color_pass(CP.COLOR_PASSES["Transmission Color"])),
    FilmPass(CP.ENVIRONMENT, 3, "RGB", "COLOR", "view_layer.use_pass_environment", "mean",
             CP.environment),
    FilmPass(CP.AMBIENT_OCCLUSION, 3, "RGB", "COLOR", "view_layer.use_pass_ambient_occlusion",
             "mean", CP.ambient_occlusion),
    FilmPass("UV", 3, "UVA", "VECTOR", "view_layer.use_pass_uv", "mean", CP.uv_pass),
)
#: The AOVs computed from the progressive state (FPPM's own).
AOVS = tuple(p for p in PASSES if p.source == "state")


def data_passes(passes, scene=None) -> tuple:
    """The PASSES named in ``passes`` that are made from the camera pass's
    first hits ('mean' and 'first' sources, not the state's AOVs), then the
    scene's shader AOVs among them (``core.sppm.shader_aovs``)."""
    from .shader_aovs import film_passes
    names = set(passes)
    return (tuple(p for p in PASSES if p.source != "state" and p.name in names)
            + film_passes(scene, passes))


def pass_enabled(p: FilmPass, settings, view_layer=None) -> bool:
    """Whether p is on: its RenderSettings field, or its view-layer property
    (False without a view layer or when the property does not exist)."""
    if not p.flag.startswith("view_layer."):
        return bool(getattr(settings, p.flag))
    obj = view_layer
    for part in p.flag.split(".")[1:]:
        obj = getattr(obj, part, None)
    return bool(obj)


class Film:
    """settings: RenderSettings (the AOV flags); camera: CameraModel (pixel
    footprint); H, W: the region's size; scene: the core Scene (camera,
    transparency, mist, pass indices; None: no data passes, opaque film);
    passes: names of the 'mean' / 'first' passes of PASSES to produce."""

    def __init__(self, settings, camera, H: int, W: int, scene=None, passes=(),
                 compiled: bool = True):
        self.settings, self.camera, self.H, self.W = settings, camera, H, W
        self.compiled = compiled
        self.scene = scene
        self.transparent = bool(getattr(scene, "film_transparent", False))
        # The film has an alpha: Film > Transparent, or holdout surfaces
        # (core.scene.holdout: Cycles writes their transparency with either
        # film).
        self.alpha = self.transparent or (
            scene is not None and triangle_weights(scene) is not None)
        self.data_passes = data_passes(passes, scene)
        P = H * W
        self.coverage = np.zeros(P)                   # sum over passes of "camera ray hit"
        # The image, reused from pass to pass once no caller holds the last
        # one (core.kept: 33 MB at 1080p not page-faulted in every pass).
        self._image = KeptArrays()
        self.samples = 0                              # passes accumulated
        self.sums = {p.name: np.zeros((P, p.channels)) for p in self.data_passes}
        # The Cryptomatte passes' slots (core.sppm.cryptomatte), or None.
        self.matte = Mattes.of_passes(passes, P, scene)
        # Shadow catchers' sums (core.sppm.shadow_catcher: the Renderer sets
        # it, with its Embree scene and lights), or None.
        self.catcher = None
        self.catcher_pass = CATCHER_PASS in passes
        # The render's MaterialTable and LightTable, the shadow rays' Accel
        # and a Generator (the Renderer sets them: the colour, Environment
        # and Ambient Occlusion passes read them).
        self.mtab = self.light_table = self.shadow_accel = self.rng = None
        if scene is not None:
            M = np.asarray(scene.camera.matrix_world, np.float64)
            axes = M[:3, :3] / np.maximum(np.linalg.norm(M[:3, :3], axis=0), 1e-300)
            self.eye, self.view = M[:3, 3].copy(), -axes[:, 2]
            self.R_wc = np.stack([axes[:, 0], axes[:, 1], -axes[:, 2]])

    @property
    def needs_camera(self) -> bool:
        """Whether :meth:`accumulate` uses a pass's camera data (alpha or a
        data pass is on): integrators without visible points of their own
        (PATH, COMBINED) run the camera pass for it only then."""
        return self.scene is not None and (self.alpha or bool(self.data_passes)
                                           or self.matte is not None or self.catcher is not None)

    @property
    def reads_line_hits(self) -> bool:
        """Whether a pass reads what the camera rays meet on their lines
        (``core.sppm.line_hits``: Cryptomatte, the colour, Environment and
        Ambient Occlusion passes)."""
        return self.matte is not None or any(p.name in CP.LINE_PASSES for p in self.data_passes)

    def accumulate(self, vp) -> None:
        """Add one pass's camera data (VisiblePoints with .first) to alpha and the data passes."""
        first = getattr(vp, "first", None)
        if first is None or self.scene is None:
            return
        self.coverage += 1.0 - first.escape
        if self.matte is not None and first.line:
            self.matte.add(first.line)
        if self.catcher is not None:
            self.catcher.accumulate(vp, self.samples)
        if self.data_passes:
            x = PassSample(first, vp, self.scene, self.eye, self.view, self.R_wc, self.mtab,
                           self.light_table, {}, self.shadow_accel, self.rng)
            for p in self.data_passes:
                if p.source == "mean" or self.samples == 0:
                    v = np.asarray(p.compute(x), np.float64).reshape(-1, p.channels)
                    if p.source == "mean":
                        self.sums[p.name] += v
                    else:
                        self.sums[p.name][...] = v
        self.samples += 1

    def state_dict(self) -> dict:
        """The film's sums for a checkpoint (keys 'film_*')."""
        d = {"film_coverage": self.coverage.copy(), "film_samples": np.asarray(self.samples)}
        d.update({f"film_{k}": v.copy() for k, v in self.sums.items()})
        if self.matte is not None:
            d.update({f"film_{k}": v for k, v in self.matte.state_dict().items()})
        if self.catcher is not None:
            d.update({f"film_{k}": v for k, v in self.catcher.state_dict().items()})
        return d

    def load_state(self, d: dict) -> None:
        """Restore state_dict() output; a checkpoint without film sums (older
        FPPM) restarts alpha and the data passes from the next pass."""
        if "film_coverage" not in d:
            return
        self.coverage[...] = d["film_coverage"]
        self.samples = int(d["film_samples"])
        for k, v in self.sums.items():
            if f"film_{k}" in d:
                v[...] = d[f"film_{k}"]
        if self.matte is not None:
            self.matte.load_state({k[len("film_"):]: v for k, v in d.items()
                                   if k.startswith("film_crypto_")})
        if self.catcher is not None:
            self.catcher.load_state({k[len("film_"):]: v for k, v in d.items()
                                     if k.startswith("film_catcher_")})

    def __call__(self, state, pass_index: int, photons_emitted: int, elapsed: float) -> PassResult:
        """The PassResult of the state after pass_index passes."""
        H, W = self.H, self.W
        img, = self._image.get(lambda: [np.ones((H, W, 4), np.float32)], (H, W))
        alpha = self.alpha and self.samples
        if self.compiled:
            R, r_px = self._image_compiled(state, pass_index, photons_emitted, img, alpha)
        else:
            L = state.L_sum / max(pass_index, 1)
            R2 = np.where(state.R2 > 0, state.R2, np.inf)
            L = L + state.tau / (np.pi * R2[:, None] * max(photons_emitted, 1))
            L = np.where(np.isfinite(L), L, 0.0)
            img[..., :3] = L.reshape(H, W, 3)
            if alpha:
                img[..., 3] = (self.coverage / self.samples).reshape(H, W)
            R = np.sqrt(np.where(state.R2 > 0, state.R2, 0.0))
            fp = self.camera.footprint(state.depth)
            r_px = np.where(fp > 0, R / np.maximum(fp, 1e-300), 0.0)
        aovs = {a.name: a.compute(state, R, r_px).reshape(H, W, a.channels).astype(np.float32)
                for a in AOVS if getattr(self.settings, a.flag)}
        n = max(self.samples, 1)
        for p in self.data_passes:
            v = self.sums[p.name] / (n if p.source == "mean" else 1)
            if p.finish is not None:
                v = p.finish(v)
            aovs[p.name] = v.reshape(H, W, p.channels).astype(np.float32)
        if self.matte is not None:
            aovs.update({k: v.reshape(H, W, 4) for k, v in self.matte.passes(n).items()})
        if self.catcher is not None:
            S = self.catcher.compose(img, self.samples)
            if self.catcher_pass:
                aovs[CATCHER_PASS] = S
        elif self.catcher_pass:
            aovs[CATCHER_PASS] = np.ones((H, W, 3), np.float32)   # Cycles: no catcher, 1
        # r_px[R2 > 0] moved to r_px's front in place (its own array, the AOVs
        # are copies): the mean of the same values in the same order as
        # r_px[R2 > 0].mean(), without a pixel-sized copy and mask
        n = _compact_positive(state.R2, r_px)
        mean_px = float(r_px[:n].mean()) if n else 0.0
        held = float(state.held.mean()) if state.held.size else 0.0
        return PassResult(pass_index, photons_emitted, elapsed, img, aovs, mean_px, held)

    def _image_compiled(self, state, pass_index, photons_emitted, img, alpha):
        """img's pixels (in place), R and r_px (P,) from ``_film_range``."""
        P = state.R2.shape[0]
        R, r_px = np.empty(P), np.empty(P)
        cam = self.camera
        ortho = cam.cam.kind == "ORTHO"
        prm = np.array([max(pass_index, 1), max(photons_emitted, 1),
                        self.samples if alpha else 0, cam.pix], np.float64)
        # Loaded here, not at import: the add-on imports this module at
        # register, which must not load numba (tests/test_addon_register.py).
        import numba
        from .film_kernels import FilmArrays, _film_parallel, _film_range
        a = FilmArrays(state.L_sum, state.tau, state.R2, state.depth, self.coverage,
                       img.reshape(P, 4), R, r_px)
        T = numba.get_num_threads()
        if P >= PARALLEL_MIN and T > 1:
            _film_parallel(T, a, prm, bool(alpha), ortho)
        else:
            _film_range(0, P, a, prm, bool(alpha), ortho)
        return R, r_px


def _compact_positive(R2: np.ndarray, x: np.ndarray) -> int:
    """Move x[R2 > 0] to x[:n] in order (in place) and return n."""
    from .film_kernels import compact_positive
    return int(compact_positive(np.ascontiguousarray(R2, np.float64), x))
