"""Shadow catchers (Object > Visibility > Shadow Catcher): the shadows and
light the other objects cast on a catcher, kept apart from the catcher
itself, as Cycles composes them (kernel/integrator/shadow_catcher.h,
kernel/film/read.h).

Cycles splits a camera ray that meets a catcher on its line: the path
goes on as usual (the Combined pass), and a second path sees the catcher
lit in a scene without the other objects (the "catcher" sums).  The paths
that meet no catcher make the "matte" (the other objects and the world).
Per pixel, with sums over the samples:

    shadow   S = (combined - matte) / catcher      (1 where catcher = 0)
    S'         = (1 - a) + a S                     (alpha-over on white, a the
                                                    Combined's alpha)
    alpha_m    = 1 - the matte's transparency (the catcher's share is
                 transparent; with Film > Transparent also the world's)
    alpha'     = (1 - alpha_m) (1 - clamp(mean(S'))) + alpha_m

and Blender's Combined is (matte, alpha_m) with the Shadow Catcher pass S'
on; else (matte, alpha') with Film > Transparent, (matte + background
(1 - alpha'), 1) without it, the background the world the camera rays
behind the catcher see.

FPPM takes, per pass, the camera pass's first hits: c the share of the
passes whose first hit is a catcher, o the share whose first hit is
another object, and the world the others see (Combined's, none with Film
> Transparent).  At the catchers' visible points: their light in the
catcher-only scene from light samples cast in an Embree view without the
other objects (``lights.NextEventEstimation`` on ``Accel.without``; so no
light between catchers, which a lone ground plane has none of) plus their
emission (the catcher sums); the same light samples in the whole scene
(shadowed); the world the camera rays behind them see.

Where no other object shares the pixel (o = 0), combined - matte is the
pixel's colour less the world its other samples see: exact, with every
light the integrator finds on the catcher (caustics, light bounced off the
objects).  At an object's silhouette over a catcher (o, c > 0) the
integrator's colour cannot be split by sample, so the shadow there is the
light samples' (the whole scene's over the catcher-only scene's) and the
matte's colour the pixel's less the catcher's light the light samples
find: approximated on that ring of pixels, without the light the
integrator finds beyond them (the exporter notes it).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

#: Blender's name of the shadow pass (Cycles' view-layer flag turns it on).
PASS = "Shadow Catcher"
#: The flag of that pass.
FLAG = "view_layer.cycles.use_pass_shadow_catcher"


class ShadowCatcher:
    """The catcher sums of a film of P pixels: caught (P,) the passes whose
    first hit is a catcher, catcher (P, 3) the catcher-only radiance summed
    over those, background (P, 3) the world behind them.  scene: core Scene
    with ``tri_catcher``; accel its Embree scene; light_table, mtab: the
    renderer's; eye (3,), view (3,) the camera's position and direction;
    seed: the render's (the light samples' streams); with_pass: the
    Shadow Catcher pass is asked for (the Combined is then the matte)."""

    def __init__(self, scene, accel, light_table, mtab, P: int, eye, view, seed: int,
                 with_pass: bool, direct_light=None):
        from ..lights.nee import NextEventEstimation
        self.catcher_tri = np.asarray(scene.tri_catcher, bool)
        self.nee = NextEventEstimation(light_table, mtab, accel.without(~self.catcher_tri),
                                       scene.tri_p)
        # The whole scene's light samples (the renderer's, shadow linking and
        # Shadow visibility included).
        self.nee_full = direct_light if direct_light is not None else NextEventEstimation(
            light_table, mtab, accel, scene.tri_p)
        self.light_table = light_table
        self.ortho = scene.camera.kind == "ORTHO"
        self.transparent = bool(scene.film_transparent)
        self.eye, self.view = np.asarray(eye, np.float64), np.asarray(view, np.float64)
        self.seed, self.with_pass = int(seed), bool(with_pass)
        self.caught = np.zeros(P)
        self.objects = np.zeros(P)           # passes whose first hit is another object
        self.catcher = np.zeros((P, 3))
        self.lit = np.zeros((P, 3))          # the same light samples, whole scene
        self.world = np.zeros((P, 3))        # the world the other samples see
        self.background = np.zeros((P, 3))

    @classmethod
    def of_scene(cls, scene, accel, light_table, mtab, P, eye, view, seed,
                 passes, direct_light=None) -> Optional["ShadowCatcher"]:
        """The film's ShadowCatcher, or None when no triangle is a catcher."""
        tri = getattr(scene, "tri_catcher", None)
        if tri is None or not np.any(tri):
            return None
        return cls(scene, accel, light_table, mtab, P, eye, view, seed, PASS in passes,
                   direct_light)

    def accumulate(self, vp, sample: int) -> None:
        """Add one pass's camera data (VisiblePoints with .first; sample: the
        pass's index from 0, its light samples' stream)."""
        import dataclasses
        from ..lights import world_radiance
        f = vp.first
        on_catcher = self.catcher_tri[np.maximum(f.prim, 0)]
        self.objects += f.hit & ~on_catcher
        if not self.transparent:
            # The world the camera rays that miss every surface see.
            m = np.nonzero(~f.hit & (f.escape > 0))[0]
            if m.size:
                self.world[m] += f.escape[m, None] * world_radiance(
                    self.light_table, self._directions(f, m), camera=True)
        k = np.nonzero(f.hit & on_catcher)[0]
        if k.size == 0:
            return
        self.caught[k] += 1.0
        # The light samples at the visible points on the first hit, in the
        # catcher-only scene and in the whole scene, on one stream each pass.
        on = np.zeros_like(vp.valid)
        on[k] = vp.valid[k] & ~vp.through_delta[k]
        v = dataclasses.replace(vp, valid=on)
        self.nee(v, np.random.default_rng((self.seed, sample, 0xCA7C)), add_to=self.catcher)
        self.nee_full(v, np.random.default_rng((self.seed, sample, 0xCA7C)), add_to=self.lit)
        self.catcher[k] += f.emit[k]
        self.lit[k] += f.emit[k]
        self.background[k] += world_radiance(self.light_table, self._directions(f, k),
                                             camera=True)

    def _directions(self, f, k) -> np.ndarray:
        """(K, 3) the unit directions of the camera rays of pixels k (from
        the lens centre to their first hit; the view direction when
        orthographic or on a miss)."""
        if self.ortho:
            return np.repeat(self.view[None, :], k.size, 0)
        d = np.where(f.hit[k, None], f.p[k] - self.eye, self.view)
        return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)

    def compose(self, img: np.ndarray, samples: int) -> Optional[np.ndarray]:
        """Blender's Combined in place of img (H, W, 4) (module doc), and
        the Shadow Catcher pass (H, W, 3) float32 it returns."""
        H, W = img.shape[:2]
        n = max(samples, 1)
        c = (self.caught / n).reshape(H, W, 1)
        rgb = img[..., :3].astype(np.float64)
        a = img[..., 3:4].astype(np.float64) if self.transparent else np.ones((H, W, 1))
        o = (self.objects / n).reshape(H, W, 1)
        cat = (self.catcher / n).reshape(H, W, 3)
        # The pixel's colour less the world its other samples see: the
        # catcher's and the other objects' light.
        X = np.maximum(rgb - (self.world / n).reshape(H, W, 3), 0.0)
        sil = (o > 0) & (c > 0)
        lit = (self.lit / n).reshape(H, W, 3)
        # The catcher's share of X: all of it where no other object shares
        # the pixel; at a silhouette the light samples' estimate of it.
        part = np.where(sil, np.minimum(lit, X), np.where(c > 0, X, 0.0))
        S = np.where(cat != 0, np.where(sil, lit, X) / np.where(cat != 0, cat, 1.0), 1.0)
        S = (1.0 - a) + a * S
        matte = rgb - part
        alpha_m = np.clip(a - c, 0.0, 1.0)
        if self.with_pass:
            img[..., :3], img[..., 3:] = matte, alpha_m
        else:
            alpha = (1.0 - alpha_m) * (1.0 - np.clip(S.mean(axis=2, keepdims=True), 0.0, 1.0)) \
                + alpha_m
            if self.transparent:
                img[..., :3], img[..., 3:] = matte, alpha
            else:
                bg = (self.background / n).reshape(H, W, 3)
                img[..., :3], img[..., 3] = matte + bg * (1.0 - alpha), 1.0
        return S.astype(np.float32)

    def _sums(self) -> dict:
        return {"catcher_caught": self.caught, "catcher_objects": self.objects,
                "catcher_light": self.catcher, "catcher_lit": self.lit,
                "catcher_world": self.world, "catcher_background": self.background}

    def state_dict(self) -> dict:
        return {k: a.copy() for k, a in self._sums().items()}

    def load_state(self, d: dict) -> None:
        for k, a in self._sums().items():
            if k in d and d[k].shape == a.shape:
                a[...] = d[k]
