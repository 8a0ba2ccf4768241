"""The world's environment map as a light: radiance by direction and its importance sampling.

    env = EnvironmentLight.build(scene.world_map)
    w, pdf = env.sample(u1, u2)          # world directions towards the map, pdf [1/sr]
    L = env.radiance(w)                  # (K, 3)

The map is an equirectangular image (:class:`core.scene.textures.EnvironmentMap`)
looked up bilinearly as Cycles does.  It is sampled, like Cycles' background
light (``scene/light.cpp`` background_cdf, ``kernel/light/background.h``), by a
piecewise-constant distribution over regions of the image: an H x W grid
of cells, s x s per texel (:func:`supersampling`: s = 8, 4 or 2 while W s
stays within SUPERSAMPLE_WIDTH, as Cycles' importance map is 1024 wide
whatever the image; s = 1, the texels themselves, for wider maps).  Region
(i, j) covers v in [i/H, (i+1)/H), u in [j/W, (j+1)/W), i.e. the band of z = cos(theta)
from -cos(pi i / H) to -cos(pi (i+1) / H), solid angle
Omega_i = (2 pi / W) (cos(pi i / H) - cos(pi (i+1) / H)) (the exact integral of
sin(theta) over the row).  Its weight is f_ij Omega_i, with f_ij the MAXIMUM
over the region of the bilinear image's average |rgb| (Cycles weighs by
average(fabs(rgb)) at the region's centre).  The maximum is positive wherever
the interpolated radiance is non-zero, so the estimator stays unbiased without
Cycles' BSDF-sampling half, and it bounds L / pdf by the map's total: a
region-mean weight let the half-lit neighbours of a bright texel through at
16x the mean weight (fireflies on glossy surfaces).  With s >= 2 (even) a
cell lies inside one bilinear patch, so its maximum is at one of its
corners (:func:`_fine_max`), and L / pdf varies inside a bright texel by
far less than over the texel's own region (whose maximum :func:`_region_max`
takes over the texel and its 8 neighbours' midpoints): on
``example_blends/real_scene.blend`` (a 128 x 64 map with a 2 x 2-texel sun)
the camera paths' relMSE at 64 samples fell 0.71x (docs/integrators.md "An
HDRI's light sample, round 27").
Inside a region the direction is uniform in u and in z, so the density is
constant in solid angle there: pdf = f_ij / sum(f Omega) [1/sr].

The texture vector is normalize(A w) (A = ``to_texture``, Mapping and Texture
Coordinate); a world direction is sampled as w = normalize(A^-1 c) from a
texture direction c, with the Jacobian |det A| / |A w|^3 (as for the spot
cone in :mod:`.table`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene.textures import (EnvironmentMap, UnassociatedImage, _as_image,
                              environment_radiance, equirectangular_direction,
                              equirectangular_uv)


def _region_max(a: np.ndarray) -> np.ndarray:
    """(H, W) maximum over each texel's region of the bilinear interpolation of
    a (H, W) (periodic in both axes, like the lookup): the largest of the texel
    itself, the 4 edge midpoints (means of 2 texels) and the 4 corners (means
    of 4); a bilinear patch takes its extremes at those points."""
    # Edge midpoints between rows (i, i+1) and columns (j, j+1), then corners.
    ev = 0.5 * (a + np.roll(a, -1, axis=0))          # between row i and i + 1
    eh = 0.5 * (a + np.roll(a, -1, axis=1))          # between column j and j + 1
    c = 0.5 * (ev + np.roll(ev, -1, axis=1))         # corner (i + 1/2, j + 1/2)
    m = np.maximum(a, ev)
    np.maximum(m, np.roll(ev, 1, axis=0), out=m)
    np.maximum(m, eh, out=m)
    np.maximum(m, np.roll(eh, 1, axis=1), out=m)
    np.maximum(m, c, out=m)
    np.maximum(m, np.roll(c, 1, axis=0), out=m)
    np.maximum(m, np.roll(c, 1, axis=1), out=m)
    np.maximum(m, np.roll(np.roll(c, 1, axis=0), 1, axis=1), out=m)
    return m


#: The importance map's cells per texel along each axis (even), chosen so
#: that the map's width times it stays within SUPERSAMPLE_WIDTH.
SUPERSAMPLE_WIDTH = 1024


def supersampling(W: int) -> int:
    """Cells per texel along each axis of a map W texels wide: the largest
    of 8, 4, 2 whose fine width is at most SUPERSAMPLE_WIDTH, else 1."""
    for s in (8, 4, 2):
        if W * s <= SUPERSAMPLE_WIDTH:
            return s
    return 1


def _fine_max(a: np.ndarray, s: int) -> np.ndarray:
    """(H s, W s) maximum over each fine cell of the bilinear interpolation of
    a (H, W) (periodic, texel centres at integer coordinates x = u W - 1/2).
    s even: the cells' edges include the centre lines, so each cell lies in
    one bilinear patch and takes its maximum at one of its 4 corners."""
    H, W = a.shape

    def edges(a, n, axis):
        x = np.arange(n * s + 1) / s - 0.5
        j0 = np.floor(x).astype(np.int64)
        t = x - j0
        lo = np.take(a, j0 % n, axis=axis)
        hi = np.take(a, (j0 + 1) % n, axis=axis)
        shape = [1, 1]
        shape[axis] = -1
        return (1.0 - t).reshape(shape) * lo + t.reshape(shape) * hi
    c = edges(edges(a.astype(np.float64), W, 1), H, 0)        # (H s + 1, W s + 1)
    return np.maximum(np.maximum(c[:-1, :-1], c[:-1, 1:]), np.maximum(c[1:, :-1], c[1:, 1:]))


def _blur_118(a: np.ndarray, axis: int) -> np.ndarray:
    """(1/8, 3/4, 1/8) along ``axis`` with wrapping: the mean of a linearly
    interpolated periodic signal over each sample's cell, or (as here, on the
    row solid angles) the weight each row's sum gets in the total of those
    means (the bilinear lookup repeats in v too)."""
    return 0.75 * a + 0.125 * (np.roll(a, 1, axis=axis) + np.roll(a, -1, axis=axis))


def _row_omega(H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """(z at the H + 1 row edges, solid angle (H,) of one texel region per row)."""
    z_edges = -np.cos(np.pi * np.arange(H + 1) / H)
    z_edges[0], z_edges[-1] = -1.0, 1.0
    return z_edges, (2.0 * np.pi / W) * np.diff(z_edges)


def mean_radiance(env: EnvironmentMap) -> np.ndarray:
    """(3,) (1 / 4 pi) int L d omega of the map, per channel: the region means
    of the bilinear image times Omega_i.  Their sum is cheap: the (1/8, 3/4,
    1/8) blur along u keeps each row's sum, and the one along v moves onto the
    row solid angles."""
    img = np.asarray(env.image)
    if img.ndim == 2:
        img = img[:, :, None]
    H, W = img.shape[:2]
    rgb = img[:, :, :3] if img.shape[2] >= 3 else np.repeat(img[:, :, :1], 3, axis=2)
    rows = rgb.sum(axis=1, dtype=np.float64)                  # (H, 3)
    omega = _row_omega(H, W)[1]
    return ((rows * _blur_118(omega, 0)[:, None]).sum(axis=0) / (4.0 * np.pi)
            * np.asarray(env.strength, np.float64).reshape(3))


@dataclass
class EnvironmentLight:
    """Sampling tables of one :class:`EnvironmentMap`.

    env: the map.  H, W: the importance grid's size (the map's times
    :func:`supersampling`).  z_edges: (H + 1,) z = cos(theta) at the row
    edges (z_edges[0] = -1, the nadir).  weight: (H, W) f_ij Omega_i.
    cdf: (H W,) cumulative ``weight`` in row-major order; total = cdf[-1].
    A, A_inv: (3, 3) to_texture and its inverse; det: |det A|.
    mean_radiance: (3,) (1 / 4 pi) int L d omega, per channel
    (:func:`mean_radiance`).
    """
    env: EnvironmentMap
    H: int
    W: int
    z_edges: np.ndarray
    weight: np.ndarray
    cdf: np.ndarray
    A: np.ndarray
    A_inv: np.ndarray
    det: float
    mean_radiance: np.ndarray

    @classmethod
    def build(cls, env: EnvironmentMap) -> "EnvironmentLight":
        img = np.asarray(env.image)
        if img.ndim == 2:
            img = img[:, :, None]
        H, W = img.shape[:2]
        rgb = img[:, :, :3] if img.shape[2] >= 3 else np.repeat(img[:, :, :1], 3, axis=2)
        a = np.abs(rgb).mean(axis=2, dtype=np.float32)
        ss = supersampling(W)
        if ss > 1:
            f = _fine_max(a, ss)
            H, W = H * ss, W * ss
        else:
            f = _region_max(a).astype(np.float64)
        z_edges, omega = _row_omega(H, W)
        weight = f * omega[:, None]
        strength = np.asarray(env.strength, np.float64).reshape(3)
        mean = mean_radiance(env)
        A = np.asarray(env.to_texture, np.float64).reshape(3, 3)
        det = float(abs(np.linalg.det(A)))
        A_inv = np.linalg.inv(A) if det > 0 else np.eye(3)
        if not np.any(strength != 0):
            weight = np.zeros_like(weight)
        return cls(env=env, H=H, W=W, z_edges=z_edges, weight=weight,
                   cdf=np.cumsum(weight.ravel()), A=A, A_inv=A_inv, det=det if det > 0 else 1.0,
                   mean_radiance=mean)

    @property
    def total(self) -> float:
        return float(self.cdf[-1]) if self.cdf.size else 0.0

    def kernel_data(self):
        """This map's ``environment_kernels.EnvironmentKernel`` (built once)."""
        k = self.__dict__.get("_kernel")
        if k is None:
            from .environment_kernels import EnvironmentKernel, guide_table
            img = _as_image(self.env.image)
            flat = self.weight.ravel()
            pos = np.nonzero(flat > 0)[0]
            c = np.ascontiguousarray
            k = EnvironmentKernel(
                cdf=c(self.cdf, np.float64), weight=c(flat, np.float64),
                z_edges=c(self.z_edges, np.float64), A=c(self.A, np.float64),
                A_inv=c(self.A_inv, np.float64),
                strength=c(np.asarray(self.env.strength, np.float64).reshape(3)),
                image=c(img), W=int(self.W), det=float(self.det), total=self.total,
                last=int(pos[-1]) if pos.size else 0,
                unassociate=bool(isinstance(self.env.image, UnassociatedImage)
                                 and img.shape[2] >= 4),
                guide=guide_table(np.asarray(self.cdf, np.float64), self.total))
            self.__dict__["_kernel"] = k
        return k

    def radiance(self, w: np.ndarray) -> np.ndarray:
        """(K, 3) radiance of the map along unit world directions w (K, 3)."""
        return environment_radiance(self.env, w)

    def _jacobian(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(texture directions c (K, 3), d omega_c / d omega_w (K,)) of unit world w."""
        c = w @ self.A.T
        n = np.linalg.norm(c, axis=1)
        return c / np.maximum(n, 1e-300)[:, None], self.det / np.maximum(n, 1e-300) ** 3

    def pdf(self, w: np.ndarray) -> np.ndarray:
        """(K,) solid-angle density of :meth:`sample` at unit world directions w (K, 3)."""
        w = np.asarray(w, np.float64).reshape(-1, 3)
        if self.total <= 0:
            return np.zeros(w.shape[0])
        c, jac = self._jacobian(w)
        uv = equirectangular_uv(c)
        j = np.clip(np.floor(uv[:, 0] * self.W).astype(np.int64) % self.W, 0, self.W - 1)
        i = np.clip(np.searchsorted(self.z_edges, c[:, 2], side="right") - 1, 0, self.H - 1)
        omega = (2.0 * np.pi / self.W) * (self.z_edges[i + 1] - self.z_edges[i])
        return self.weight[i, j] / omega / self.total * jac

    def sample(self, u1: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Directions towards the map: (w (K, 3) unit world directions, pdf (K,) [1/sr]).

        u1 picks the region (its leftover inside the region gives u), u2 the
        height z inside the region's band.  pdf is 0 (and w arbitrary) when
        the map is black."""
        u1 = np.asarray(u1, np.float64)
        u2 = np.asarray(u2, np.float64)
        K = u1.shape[0]
        if self.total <= 0:
            return np.tile([0.0, 0.0, 1.0], (K, 1)), np.zeros(K)
        x = u1 * self.total
        k = np.minimum(np.searchsorted(self.cdf, x, side="right"), self.cdf.size - 1)
        wk = self.weight.ravel()[k]
        # Never a zero-weight region (float ties at the end of the cdf).
        bad = wk <= 0
        if np.any(bad):
            k[bad] = int(np.nonzero(self.weight.ravel() > 0)[0][-1])
            wk = self.weight.ravel()[k]
        a = np.clip((x - (self.cdf[k] - wk)) / wk, 0.0, 1.0 - 1e-12)
        i, j = np.divmod(k, self.W)
        u = (j + a) / self.W
        z = self.z_edges[i] + u2 * (self.z_edges[i + 1] - self.z_edges[i])
        c = equirectangular_direction(u, z)
        w = c @ self.A_inv.T
        w /= np.maximum(np.linalg.norm(w, axis=1), 1e-300)[:, None]
        omega = (2.0 * np.pi / self.W) * (self.z_edges[i + 1] - self.z_edges[i])
        _, jac = self._jacobian(w)
        return w, wk / omega / self.total * jac
