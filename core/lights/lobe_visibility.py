"""Emitters hidden from some kinds of rays: the lobes their light samples leave out.

Object > Visibility > Ray Visibility of a light, or of an object whose
material emits, can turn Diffuse, Glossy or Transmission off.  Cycles then
does two things (``light_object_visibility_flags``,
``_surface_shader_exclude``):

- a BSDF ray of that kind does not see the emitter;
- the emitter's light samples leave the closures of that kind out of the
  BSDF they evaluate: a light with Glossy off makes no highlight, one with
  Diffuse off lights only the glossy lobes (a "specular-only" light).
  Glass closures are left out only when Glossy and Transmission both are.

FPPM keeps the hidden kinds per emitter row (:func:`hidden_bits`).  Light
samples of such an emitter evaluate the BSDF with the hidden lobes' colours
set to 0 (:func:`masked_colors`, called by every light-sample stage); at a
non-delta vertex its light is the light samples' alone (weight 1, and 0 on
a BSDF ray's hit: ``lights.pdf.samples_only``), the same expectation as
Cycles' two strategies restricted to the lobes that see it.  After a delta
bounce (a mirror or glass chain) its Glossy and Transmission visibility
decide whether the ray sees it, as before.  Photons and light paths start
on it as on any emitter; one whose first hit has only lobes hidden from its
emitter ends there (:func:`unseen_first_hits`), elsewhere its first bounce
keeps every lobe (noted).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

#: The kinds of ray an emitter may be hidden from, one bit each.
DIFFUSE_RAYS, GLOSSY_RAYS, TRANSMISSION_RAYS = 1, 2, 4


def hidden_bits(scene, table) -> Optional[np.ndarray]:
    """(Nl,) uint8 the kinds of ray each emitter row of ``table`` (built
    from ``scene``) is hidden from: a Blender light's ``visible_diffuse``,
    ``visible_glossy``, ``visible_transmission``; an emissive triangle's
    object's ray visibility (``Scene.tri_visibility``); the world's
    (``Scene.world_hidden``: Cycles gives its background light the same
    closure exclusion).  None when no emitter is hidden from any."""
    from ..accel import RAY_DIFFUSE, RAY_GLOSSY, RAY_TRANSMISSION
    from .table import MESH, WORLD
    bits = np.zeros(table.kind.shape[0], np.uint8)
    src = np.asarray(table.source, np.int64)
    for r in np.nonzero((table.kind != MESH) & (table.kind != WORLD) & (src >= 0))[0]:
        lt = scene.lights[src[r]]
        bits[r] = ((0 if getattr(lt, "visible_diffuse", True) else DIFFUSE_RAYS)
                   | (0 if lt.visible_glossy else GLOSSY_RAYS)
                   | (0 if lt.visible_transmission else TRANSMISSION_RAYS))
    vis = getattr(scene, "tri_visibility", None)
    if vis is not None:
        m = np.nonzero(table.kind == MESH)[0]
        v = np.asarray(vis, np.uint8)[src[m]]
        bits[m] = (np.where(v & RAY_DIFFUSE, 0, DIFFUSE_RAYS)
                   | np.where(v & RAY_GLOSSY, 0, GLOSSY_RAYS)
                   | np.where(v & RAY_TRANSMISSION, 0, TRANSMISSION_RAYS)).astype(np.uint8)
    bits[table.kind == WORLD] = int(getattr(scene, "world_hidden", 0))
    return bits if bits.any() else None


def slot_kinds(mtab) -> np.ndarray:
    """(M', L) uint8 the kinds of ray each lobe slot of the material table
    scatters into: diffuse (Diffuse, Oren-Nayar, Translucent), glossy
    (microfacet reflection), transmission (refraction), both glossy and
    transmission (glass), none (Transparent, unused)."""
    from ..scene.model import DIFFUSE, GLASS, GLOSSY, REFRACTION, TRANSLUCENT
    k = np.asarray(mtab.kind)
    out = np.zeros(k.shape, np.uint8)
    out[(k == DIFFUSE) | (k == TRANSLUCENT)] = DIFFUSE_RAYS
    out[k == GLOSSY] = GLOSSY_RAYS
    out[k == REFRACTION] = TRANSMISSION_RAYS
    out[k == GLASS] = GLOSSY_RAYS | TRANSMISSION_RAYS
    return out


def _kinds(mtab) -> np.ndarray:
    """:func:`slot_kinds` of the table, computed once (kept on it)."""
    kinds = getattr(mtab, "_slot_kinds", None)
    if kinds is None:
        kinds = mtab._slot_kinds = slot_kinds(mtab)
    return kinds


def left_out(kinds: np.ndarray, hidden: np.ndarray) -> np.ndarray:
    """(K, L) bool the lobe slots (kinds (K, L) of :func:`slot_kinds`) a
    light sample leaves out for emitters hidden from ``hidden`` (K,) rays:
    every kind a slot scatters into is hidden (Cycles' glass rule)."""
    h = np.asarray(hidden, np.uint8)[:, None]
    return (kinds != 0) & ((kinds & ~h) == 0)


def masked_colors(mtab, hidden_rows: Optional[np.ndarray], light: np.ndarray, mat: np.ndarray,
                  colors: np.ndarray):
    """(rows (n,), their colours (n, L, 3)) of the light samples (emitter
    rows light (K,), materials mat (K,), lobe colours colors (K, L, 3))
    whose emitter is hidden from some kind of ray, with the hidden lobes'
    colours 0: the rows whose BSDF the caller evaluates again with them.
    hidden_rows: :func:`hidden_bits` of the table, or None (nothing)."""
    if hidden_rows is None:
        return np.zeros(0, np.int64), None
    light = np.asarray(light, np.int64)
    h = np.where(light >= 0, hidden_rows[np.maximum(light, 0)], 0)
    r = np.nonzero(h)[0]
    if r.size == 0:
        return r, None
    out = np.array(colors[r], np.float64, copy=True)
    out[left_out(_kinds(mtab)[np.asarray(mat, np.int64)[r]], h[r])] = 0.0
    return r, out


def unseen_first_hits(prim: np.ndarray, emitter: np.ndarray, hidden_rows: np.ndarray,
                      tri_mat: np.ndarray, mtab) -> None:
    """Photons and light paths: prim (K,) their first hits' triangles (-1:
    none), emitter (K,) their emitter rows; the hits on materials every lobe
    of which is hidden from the emitter become misses (-1, in place): no
    light of it is scattered or deposited there."""
    h = np.nonzero(prim >= 0)[0]
    if h.size == 0:
        return
    bits = hidden_rows[emitter[h]]
    k = np.nonzero(bits)[0]
    if k.size == 0:
        return
    sk = _kinds(mtab)[np.asarray(tri_mat, np.int64)[prim[h[k]]]]
    used = sk != 0
    gone = left_out(sk, bits[k]) | ~used
    off = gone.all(axis=1) & used.any(axis=1)
    prim[h[k[off]]] = -1
