"""Camera rays with Blender's projection and Cycles' pixel filter.

Projection follows Blender's view plane (BKE_camera_params_compute_viewplane):
sensor fit picks the dimension the sensor size applies to; shift is in units
of that fitted dimension; pixel aspect stretches y.  The pixel filter is
Cycles' default Blackman-Harris of ``filter_width`` px, importance-sampled
separably in x and y over a support of +-filter_width (Cycles doubles the
width it passes to the window, film.cpp), so each pixel estimates exactly the
filtered value Cycles computes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import Camera


def blackman_harris(x: np.ndarray, width: float) -> np.ndarray:
    """Cycles' window over [-width, width] (total support 2*width)."""
    v = 2.0 * np.pi * (x / (2.0 * width) + 0.5)
    return 0.35875 - 0.48829 * np.cos(v) + 0.14128 * np.cos(2 * v) - 0.01168 * np.cos(3 * v)


class FilterSampler:
    """Inverse-CDF table of the 1D Blackman-Harris filter (offsets in pixels)."""

    def __init__(self, width: float, size: int = 4096):
        self.width = float(width)
        if width <= 0:
            self.table = np.zeros(size)
            return
        x = np.linspace(-self.width, self.width, 8 * size + 1)
        pdf = np.maximum(blackman_harris(x, self.width), 0.0)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (pdf[1:] + pdf[:-1]) * np.diff(x))])
        cdf /= cdf[-1]
        self.table = np.interp(np.linspace(0.0, 1.0, size), cdf, x)

    def sample(self, u: np.ndarray) -> np.ndarray:
        """Offsets (same shape as u) from uniform u in [0, 1)."""
        idx = u * (len(self.table) - 1)
        i0 = np.minimum(idx.astype(np.int64), len(self.table) - 2)
        f = idx - i0
        return (1.0 - f) * self.table[i0] + f * self.table[i0 + 1]


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
        self.R = R
        self.origin = M[:3, 3].copy()

    def footprint(self, depth: np.ndarray) -> np.ndarray:
        """World size of one pixel at camera depth ``depth`` (K,) (z distance)."""
        if self.cam.kind == "ORTHO":
            return np.full_like(depth, self.pix)
        return depth * self.pix

    def generate(self, px: np.ndarray, py: np.ndarray, u_filter: np.ndarray,
                 u_lens: np.ndarray, fsamp: FilterSampler) -> tuple[CameraRays, np.ndarray]:
        """Rays through pixels (px, py) (K,) int, py counted from the BOTTOM.

        u_filter, u_lens: (K,2) uniforms.  Returns the rays and the camera-space
        z-component of the unit direction (K,) (negative), used to turn ray
        distance into depth.
        """
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
