"""Camera rays with Blender's projection and Cycles' pixel filter.

Projection follows Blender's view plane (BKE_camera_params_compute_viewplane):
sensor fit picks the dimension the sensor size applies to; shift is in units
of that fitted dimension; pixel aspect stretches y.  The pixel filter is
Cycles' (film.cpp ``filter_table``) of ``filter_width`` w px, importance-sampled
separably in x and y, so each pixel estimates exactly the filtered value
Cycles computes: Blackman-Harris (the default) over +-w (Cycles doubles the
width it passes to the window), Box over +-w/2, Gaussian exp(-8 x^2 / w^2)
(sigma w/4) over +-1.5 w (Cycles triples the width and scales x by 6 / width).

:meth:`CameraModel.project` is the exact inverse of :meth:`CameraModel.generate`
(a world point and a lens sample -> raster position) with the camera's
importance and pdfs (pbrt-v4 PerspectiveCamera::We / PDF_We / SampleWi; Veach
1997 chapter 10, the t = 1 technique of bidirectional path tracing), for light
tracing (core.integrators.light_tracer).

:meth:`CameraModel.generate` runs one compiled kernel per pixel range
(``core.scene.camera_kernels``: filter offsets, view-plane point, rotation to the world,
clip distances) for the pinhole and orthographic cameras, split over the
numba threads from PARALLEL_MIN rays.  The numpy version
(``generate(..., compiled=False)``) is its reference: the same operations
in the same order, and the rotation's (K, 3) @ (3, 3) product written as
the fused multiply-adds OpenBLAS's dgemm kernel computes (fma(v2, r2,
fma(v1, r1, v0 r0))), so the rays are the same bits
(tests/test_compiled_stages.py).  The matrix product itself went to
multi-threaded OpenBLAS, whose threads busy-wait after every call and took
the CPU the other stages' threads needed.  The thin lens (depth of field)
keeps the numpy path.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .model import Camera

#: Rays from which generate's kernel splits over the numba threads (a
#: parallel region's hand-off costs more than ~16k rays of work).
PARALLEL_MIN = 1 << 16


#: Cycles' Blackman-Harris coefficients: a0 - a1 cos v + a2 cos 2v - a3 cos 3v.
BH_A0, BH_A1, BH_A2, BH_A3 = 0.35875, 0.48829, 0.14128, 0.01168


def blackman_harris(x: np.ndarray, width: float) -> np.ndarray:
    """Cycles' window over [-width, width] (total support 2*width)."""
    v = 2.0 * np.pi * (x / (2.0 * width) + 0.5)
    return BH_A0 - BH_A1 * np.cos(v) + BH_A2 * np.cos(2 * v) - BH_A3 * np.cos(3 * v)


#: The Gaussian profile exp(-8 x^2) over its support +-1.5: sqrt(pi / 8)
#: erf(1.5 sqrt 8) (a filter of width w integrates to w times this).
GAUSS_INTEGRAL = math.sqrt(math.pi / 8.0) * math.erf(1.5 * math.sqrt(8.0))

#: Blender's ``cycles.pixel_filter_type`` values, and their codes in the
#: compiled splat (core.integrators.light_kernels).
FILTER_TYPES = {"BLACKMAN_HARRIS": 0, "BOX": 1, "GAUSSIAN": 2}


def filter_support(width: float, kind: str = "BLACKMAN_HARRIS") -> float:
    """The filter's half support [px]: w, w / 2 (box), 1.5 w (Gaussian)."""
    return {"BLACKMAN_HARRIS": 1.0, "BOX": 0.5, "GAUSSIAN": 1.5}[kind] * float(width)


def filter_profile(x: np.ndarray, width: float, kind: str = "BLACKMAN_HARRIS") -> np.ndarray:
    """The unnormalised filter inside its support (module doc)."""
    x = np.asarray(x, np.float64)
    if kind == "BOX":
        return np.ones_like(x)
    if kind == "GAUSSIAN":
        return np.exp(-8.0 * (x / width) ** 2)
    return np.maximum(blackman_harris(x, width), 0.0)


def filter_integral(width: float, kind: str = "BLACKMAN_HARRIS") -> float:
    """The profile's integral over the support: Blackman-Harris 2 w a0 (the
    cosine terms integrate to zero over whole periods), box w, Gaussian
    w GAUSS_INTEGRAL."""
    if kind == "BOX":
        return float(width)
    if kind == "GAUSSIAN":
        return float(width) * GAUSS_INTEGRAL
    return 2.0 * float(width) * BH_A0


class FilterSampler:
    """Inverse-CDF table of the 1D pixel filter (offsets in pixels)."""

    def __init__(self, width: float, kind: str = "BLACKMAN_HARRIS", size: int = 4096):
        self.width = float(width)
        self.kind = kind
        if width <= 0:
            self.table = np.zeros(size)
            return
        r = filter_support(self.width, kind)
        x = np.linspace(-r, r, 8 * size + 1)
        pdf = filter_profile(x, self.width, kind)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (pdf[1:] + pdf[:-1]) * np.diff(x))])
        cdf /= cdf[-1]
        self.table = np.interp(np.linspace(0.0, 1.0, size), cdf, x)

    def sample(self, u: np.ndarray) -> np.ndarray:
        """Offsets (same shape as u) from uniform u in [0, 1)."""
        idx = u * (len(self.table) - 1)
        i0 = np.minimum(idx.astype(np.int64), len(self.table) - 2)
        f = idx - i0
        return (1.0 - f) * self.table[i0] + f * self.table[i0 + 1]


def filter_weight(x: np.ndarray, width: float, kind: str = "BLACKMAN_HARRIS") -> np.ndarray:
    """Normalised 1D pixel filter f(x) (x in pixels, integral 1): the density
    that :class:`FilterSampler` samples, :func:`filter_profile` over
    :func:`filter_integral` inside :func:`filter_support`."""
    x = np.asarray(x, np.float64)
    w = filter_profile(x, width, kind) / filter_integral(width, kind)
    return np.where(np.abs(x) < filter_support(width, kind), w, 0.0)


@dataclass
class CameraProjection:
    """World points seen through the camera (K points, float64).

    raster (K, 2): film position (x, y) in pixels of the full frame, y counted
      from the BOTTOM; pixel (px, py) covers [px, px+1) x [py, py+1), so
      ``generate`` draws x = px + 0.5 + filter offset.
    ok (K,) bool: the point is in front of the lens between the clip
      distances (the film window is not tested: splats reach neighbours).
    lens (K, 3): the lens point the connection ends at (pinhole: the camera
      origin; orthographic: the foot of the point on the camera plane).
    wi (K, 3) unit direction from the point to the lens, dist (K,) its length.
    cos_cam (K,): cosine between the camera axis and the ray (lens -> point).
    We (K,): importance per unit pixel filter, pbrt-v4's
      1 / (A_pix * A_lens * cos^4): the pixel value is
      I_p = int f(x - c_p) We L cos dA_lens dw, A_pix the area of one pixel
      on the plane at unit depth (orthographic: A_pix in metres^2, We =
      1 / A_pix with a delta direction).
    pdf_pos (K,): density of the lens point (1 / A_lens; pinhole 1,
      orthographic 1 / A_pix per pixel of film area).
    pdf_dir (K,): solid-angle density of this camera ray direction when the
      camera samples x uniformly over one pixel, 1 / (A_pix cos^3)
      (pbrt-v4 PDF_We; orthographic: 0 = delta).
    pdf_wi (K,): solid-angle density at the point of choosing the lens point,
      dist^2 / (cos A_lens) (pbrt-v4 SampleWi; orthographic: 0 = delta).
    weight (K,): We / pdf_wi = 1 / (A_pix cos^3 dist^2), orthographic
      1 / A_pix -- what a light-path vertex multiplies beta f |n.wi| by
      (derivation in core.integrators.light_tracer).
    """
    raster: np.ndarray
    ok: np.ndarray
    lens: np.ndarray
    wi: np.ndarray
    dist: np.ndarray
    cos_cam: np.ndarray
    We: np.ndarray
    pdf_pos: np.ndarray
    pdf_dir: np.ndarray
    pdf_wi: np.ndarray
    weight: np.ndarray


def window(pc: np.ndarray, orthographic: bool, x0: float, y0: float, sx: float,
           sy: float) -> np.ndarray:
    """(K, 3) float64 the Texture Coordinate node's Window output of
    camera-space points pc (K, 3) (:meth:`CameraModel.camera_space`): their
    place on the whole frame through the pinhole, (0, 0) at the bottom left
    and (1, 1) at the top right, z 0 (Cycles' worldtondc; the view plane of
    :attr:`CameraModel.window_params`, shift and sensor fit included)."""
    pc = np.asarray(pc, np.float64).reshape(-1, 3)
    if orthographic:
        xs, ys = pc[:, 0], pc[:, 1]
    else:
        z = np.where(pc[:, 2] != 0.0, pc[:, 2], 1e-300)
        xs, ys = pc[:, 0] / z, pc[:, 1] / z
    return np.stack([(xs - x0) / sx, (ys - y0) / sy, np.zeros(len(pc))], axis=1)


@dataclass
class CameraRays:
    """Primary rays: o (K,3), d (K,3) unit, t_max (K,) (clip end), float64."""
    o: np.ndarray
    d: np.ndarray
    t_max: np.ndarray


class CameraModel:
    """Maps film positions to world rays for one Blender camera."""

    def __init__(self, cam: Camera):
        self.cam = cam
        W, H = cam.resolution
        self.W, self.H = int(W), int(H)
        ax, ay = cam.pixel_aspect
        ycor = ay / ax
        self.ycor = ycor
        fit = cam.sensor_fit
        if fit == "AUTO":
            sensor_size = cam.sensor_width
            fit = "HORIZONTAL" if ax * W >= ay * H else "VERTICAL"
        elif fit == "HORIZONTAL":
            sensor_size = cam.sensor_width
        else:
            sensor_size = cam.sensor_height
        viewfac = W if fit == "HORIZONTAL" else ycor * H
        if cam.kind == "ORTHO":
            pix = cam.ortho_scale / viewfac
        else:
            pix = sensor_size / cam.lens / viewfac   # view-plane size at unit depth
        self.pix = pix                   # metres per pixel at depth 1 (persp) or absolute (ortho)
        self.xmin = (-0.5 * W + cam.shift_x * viewfac) * pix
        self.ymin = (-0.5 * ycor * H + cam.shift_y * viewfac) * pix
        M = np.asarray(cam.matrix_world, np.float64)
        # Remove scale from the rotation (Blender normalises the camera matrix).
        R = M[:3, :3] / np.maximum(np.linalg.norm(M[:3, :3], axis=0, keepdims=True), 1e-300)
        self.R = np.ascontiguousarray(R)     # one kernel signature (C layout)
        self.origin = M[:3, 3].copy()

    @property
    def pixel_area(self) -> float:
        """A_pix: area of one pixel on the plane at unit depth (persp) or of
        the film (ortho), pix * (ycor * pix)."""
        return self.pix * self.pix * self.ycor

    @property
    def lens_area(self) -> float:
        """A_lens: pi r^2 of the thin lens, 1 for a pinhole (pbrt-v4's convention)."""
        r = self.cam.aperture_radius
        return np.pi * r * r if (r > 0 and self.cam.kind != "ORTHO") else 1.0

    def lens_point(self, u_lens: np.ndarray) -> np.ndarray:
        """(K, 3) camera-space lens points from (K, 2) uniforms, as
        :meth:`generate` samples them (zeros for a pinhole or ortho camera)."""
        K = u_lens.shape[0]
        cam = self.cam
        if cam.aperture_radius > 0 and cam.kind != "ORTHO":
            r = cam.aperture_radius * np.sqrt(u_lens[:, 0])
            phi = 2 * np.pi * u_lens[:, 1]
            return np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(K)], axis=1)
        return np.zeros((K, 3))

    def project(self, p: np.ndarray, u_lens: np.ndarray) -> CameraProjection:
        """Where world points p (K, 3) land on the film through the lens
        point of uniforms u_lens (K, 2) (the inverse of :meth:`generate`).

        Perspective: the ray lens -> p crosses the focus plane (depth
        focus_distance; a pinhole projects from the origin) at F, and
        generate's view-plane point is F / depth_F.  Orthographic: the
        view-plane point is p's (x, y) in camera space.
        """
        p = np.asarray(p, np.float64).reshape(-1, 3)
        K = p.shape[0]
        cam = self.cam
        pc = (p - self.origin) @ self.R          # camera space (R orthonormal)
        depth = -pc[:, 2]
        ok = (depth >= cam.clip_start) & (depth <= cam.clip_end)
        A_pix = self.pixel_area
        if cam.kind == "ORTHO":
            xs, ys = pc[:, 0], pc[:, 1]
            lens_c = np.stack([xs, ys, np.zeros(K)], axis=1)
        else:
            lens_c = self.lens_point(u_lens)
            dep = np.where(depth > 0, depth, 1.0)
            if cam.aperture_radius > 0:
                # F = lens + (p - lens) fd / depth; generate's plane point = F / fd.
                fd = cam.focus_distance
                s = fd / dep
                xs = (lens_c[:, 0] + (pc[:, 0] - lens_c[:, 0]) * s) / fd
                ys = (lens_c[:, 1] + (pc[:, 1] - lens_c[:, 1]) * s) / fd
            else:
                xs, ys = pc[:, 0] / dep, pc[:, 1] / dep
        raster = np.stack([(xs - self.xmin) / self.pix,
                           (ys - self.ymin) / (self.ycor * self.pix)], axis=1)
        v = lens_c - pc                          # point -> lens, camera space
        dist = np.linalg.norm(v, axis=1)
        dist_s = np.where(dist > 0, dist, 1.0)
        cos_cam = np.where(dist > 0, v[:, 2] / dist_s, 0.0)   # lens->point along -z
        cos_s = np.where(cos_cam > 0, cos_cam, 1.0)
        ok &= cos_cam > 0
        wi = (v / dist_s[:, None]) @ self.R.T
        lens_w = lens_c @ self.R.T + self.origin
        if cam.kind == "ORTHO":
            We = np.full(K, 1.0 / A_pix)
            pdf_pos = np.full(K, 1.0 / A_pix)
            pdf_dir = np.zeros(K)
            pdf_wi = np.zeros(K)
            weight = np.full(K, 1.0 / A_pix)
        else:
            A_lens = self.lens_area
            We = 1.0 / (A_pix * A_lens * cos_s ** 4)
            pdf_pos = np.full(K, 1.0 / A_lens)
            pdf_dir = 1.0 / (A_pix * cos_s ** 3)
            pdf_wi = dist_s * dist_s / (cos_s * A_lens)
            weight = 1.0 / (A_pix * cos_s ** 3 * dist_s * dist_s)
        return CameraProjection(raster, ok, lens_w, wi, dist, cos_cam, We, pdf_pos, pdf_dir,
                                pdf_wi, weight)

    @property
    def cycles_axes(self) -> np.ndarray:
        """(3, 3) float64 the axes of Cycles' camera space in the world (its
        camera-to-world rotation): x right, y up, z along the view (the
        camera's matrix without its scale, z flipped)."""
        return self.R * np.array([1.0, 1.0, -1.0])

    def camera_space(self, p: np.ndarray) -> np.ndarray:
        """(K, 3) float64 world points p (K, 3) in Cycles' camera space
        (:attr:`cycles_axes`), what the Texture Coordinate node's Camera
        output gives.  Affine in p: a triangle's corners interpolate to its
        points."""
        return (np.asarray(p, np.float64).reshape(-1, 3) - self.origin) @ self.cycles_axes

    @property
    def window_params(self) -> tuple:
        """(orthographic, x0, y0, sx, sy) of :func:`window`: the view plane's
        bottom left corner and size (at unit depth for a perspective camera)."""
        return (self.cam.kind == "ORTHO", float(self.xmin), float(self.ymin),
                float(self.pix * self.W), float(self.ycor * self.pix * self.H))

    def footprint(self, depth: np.ndarray) -> np.ndarray:
        """World size of one pixel at camera depth ``depth`` (K,) (z distance)."""
        if self.cam.kind == "ORTHO":
            return np.full_like(depth, self.pix)
        return depth * self.pix

    def generate(self, px: np.ndarray, py: np.ndarray, u_filter: np.ndarray,
                 u_lens: np.ndarray, fsamp: FilterSampler,
                 compiled: bool = True, threads: bool = True) -> tuple[CameraRays, np.ndarray]:
        """Rays through pixels (px, py) (K,) int or float64, py counted from the BOTTOM.

        u_filter, u_lens: (K,2) uniforms.  Returns the rays and the camera-space
        z-component of the unit direction (K,) (negative), used to turn ray
        distance into depth.  compiled=False: the numpy reference (the
        same bits, see the module docstring); the thin lens always takes it.
        threads=False: in the calling thread only, never a numba parallel
        region (for callers that generate in two threads at once).
        """
        cam = self.cam
        if compiled and not (cam.aperture_radius > 0 and cam.kind != "ORTHO"):
            return self._generate_compiled(px, py, u_filter, fsamp, threads)
        ox = fsamp.sample(u_filter[:, 0])
        oy = fsamp.sample(u_filter[:, 1])
        xs = self.xmin + (px + 0.5 + ox) * self.pix
        ys = self.ymin + (py + 0.5 + oy) * self.ycor * self.pix
        cam = self.cam
        K = px.shape[0]
        if cam.kind == "ORTHO":
            o_c = np.stack([xs, ys, np.zeros(K)], axis=1)
            d_c = np.tile([0.0, 0.0, -1.0], (K, 1))
        else:
            o_c = np.zeros((K, 3))
            d_c = np.stack([xs, ys, -np.ones(K)], axis=1)
            d_c /= np.linalg.norm(d_c, axis=1, keepdims=True)
        if cam.aperture_radius > 0 and cam.kind != "ORTHO":
            # Thin lens: focus plane at depth focus_distance.
            r = cam.aperture_radius * np.sqrt(u_lens[:, 0])
            phi = 2 * np.pi * u_lens[:, 1]
            lens = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(K)], axis=1)
            focus = d_c * (cam.focus_distance / -d_c[:, 2])[:, None]
            o_c = o_c + lens
            d_c = focus - lens
            d_c /= np.linalg.norm(d_c, axis=1, keepdims=True)
        dz = d_c[:, 2]
        # Clip by depth like Blender: start at depth clip_start, end at clip_end.
        t0 = cam.clip_start / np.maximum(-dz, 1e-12)
        t1 = cam.clip_end / np.maximum(-dz, 1e-12)
        o_w = o_c @ self.R.T + self.origin
        d_w = d_c @ self.R.T
        o_w = o_w + d_w * t0[:, None]
        return CameraRays(o_w, d_w, t1 - t0), dz

    def _generate_compiled(self, px, py, u_filter, fsamp, threads=True):
        """:meth:`generate` of a pinhole or orthographic camera in ``_pinhole_range``."""
        px = np.asarray(px, np.float64)
        py = np.asarray(py, np.float64)
        uf = np.ascontiguousarray(u_filter, np.float64)   # one kernel signature
        K = px.shape[0]
        o, d = np.empty((K, 3)), np.empty((K, 3))
        tmax, dz = np.empty(K), np.empty(K)
        cam = self.cam
        view = np.array([self.xmin, self.ymin, self.pix, self.ycor, cam.clip_start,
                         cam.clip_end], np.float64)
        args = (px, py, uf, fsamp.table, view, self.R, self.origin, cam.kind == "ORTHO",
                o, d, tmax, dz)
        # The kernels load here, not at import: enabling the add-on imports
        # this module and must not load numba (tests/test_addon_register.py).
        import numba
        from .camera_kernels import _pinhole_parallel, _pinhole_range
        if threads and K >= PARALLEL_MIN and numba.get_num_threads() > 1:
            _pinhole_parallel(numba.get_num_threads(), *args)
        else:
            _pinhole_range(0, K, *args)
        return CameraRays(o, d, tmax), dz
