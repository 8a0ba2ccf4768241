"""Shadow linking: which objects block which emitters' light (Cycles' blocker sets).

Blender (Object > Light Linking > Blocker Collection) lets an emitter (a
light, or an object whose material emits) be shadowed by only some objects.
Its depsgraph gives every object a *blocker set*, an index 0..63 (0: the
objects no blocker collection names), and every emitter a 64-bit *shadow
membership*, the sets whose objects block it (all ones: no shadow linking),
by the rules of receiver sets (addon/export_links.py).  Cycles' rule
(``intersection_skip_shadow_link``): a shadow ray towards emitter E passes
object O iff bit ``blocker_set(O)`` of ``membership(E)`` is clear.  So E's
direct light reaches every surface that the scene *as E's shadow rays see
it* (its *view*: without the objects that do not block E) leaves in sight,
and the objects left out are still lit by E and seen by every other ray.

FPPM follows it stage by stage:

- light samples (next-event estimation, core.lights.nee) cast each shadow
  ray in its emitter's view (:meth:`ShadowViews.split`);
- photons and light paths travel their first segment in their emitter's
  view, and a second set lands on the objects that view leaves out
  (core.sppm.photons, as for Shadow visibility off): their light's first
  segment is what shadow rays test;
- BSDF rays: Cycles finds a shadow-linked emitter that a non-camera ray
  would see through its view by a dedicated light intersection and weighs
  it by multiple importance sampling.  FPPM gives such an emitter's light at
  a non-delta vertex to the light sample alone (weight 1, :func:`nee_only`),
  and a BSDF ray from such a vertex adds none of it (weight 0): the same
  expectation.  After a camera ray or a delta bounce (a mirror chain) the
  ray's hit on the emitter counts as before, in the whole scene.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .linking import LINK_ALL, row_masks


def emitter_shadow_sets(scene, table) -> Optional[np.ndarray]:
    """(Nl,) uint64 the shadow membership of each row of the LightTable
    ``table`` built from ``scene`` (its Blender lights' ``shadow_sets``, its
    emissive triangles' objects' ``Scene.tri_shadow_sets``; the world's all
    ones), or None when no emitter has shadow linking."""
    return row_masks(scene, table, "shadow_sets", getattr(scene, "tri_shadow_sets", None))


def nee_only(table) -> np.ndarray:
    """(Nl,) bool: the emitter rows with shadow linking, whose light at a
    non-delta vertex only light samples find (module doc)."""
    sets = getattr(table, "shadow_sets", None)
    if sets is None:
        return np.zeros(table.kind.shape[0], bool)
    return np.asarray(sets, np.uint64) != np.uint64(LINK_ALL)


def passed(sets: int, tri_blocker: np.ndarray) -> np.ndarray:
    """(T,) bool: the triangles (blocker sets tri_blocker (T,) uint8) that
    an emitter of shadow membership ``sets`` is not blocked by."""
    bit = np.uint64(1) << np.asarray(tri_blocker, np.uint64)
    return (np.uint64(sets) & bit) == 0


@dataclass
class ShadowViews:
    """The scenes emitters' shadow rays see.  group (Nl,) int64 each
    emitter row's view; accels[g] the Accel of view g (the shadow rays'
    scene without the objects that do not block its emitters); hidden[g]
    (T,) bool the triangles view g leaves out (Shadow visibility off
    included), or None."""
    group: np.ndarray
    accels: list
    hidden: list

    def split(self, light: np.ndarray) -> list:
        """[(Accel, rows)]: the rows of emitter rows light (K,) (-1: none,
        taken as unlinked) whose shadow rays each Accel casts."""
        g = self.group[np.maximum(np.asarray(light, np.int64), 0)]
        g = np.where(np.asarray(light) >= 0, g, 0)
        return [(a, np.nonzero(g == i)[0]) for i, a in enumerate(self.accels)
                if np.any(g == i)]


def views(accel, scene, table) -> Optional[ShadowViews]:
    """The :class:`ShadowViews` of the light table's emitters over the
    scene's Accel (views for their shadow memberships, the unlinked
    emitters' view first), or None without shadow linking.  Built once per
    (Accel, table)."""
    from ..accel import RAY_SHADOW
    sets = getattr(table, "shadow_sets", None)
    blocker = getattr(scene, "tri_blocker", None)
    if sets is None or blocker is None:
        return None
    base = accel.base
    memo = getattr(base, "_shadow_views", None)
    if memo is not None and memo[0] is table:
        return memo[1]
    shadow = base.hidden_from(RAY_SHADOW)
    uniq = [LINK_ALL] + sorted(set(int(s) for s in np.asarray(sets, np.uint64)) - {LINK_ALL})
    index = {s: i for i, s in enumerate(uniq)}
    group = np.array([index[int(s)] for s in np.asarray(sets, np.uint64)], np.int64)
    accels, hidden = [], []
    for s in uniq:
        h = passed(s, blocker)
        if shadow is not None:
            h |= shadow
        hidden.append(h if h.any() else None)
        accels.append(base.for_rays(RAY_SHADOW) if s == LINK_ALL else base.without(h))
    out = ShadowViews(group, accels, hidden)
    base._shadow_views = (table, out)
    return out
