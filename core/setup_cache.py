"""What a Renderer builds from a scene before its first pass and may hand
to the next Renderer of the same scene: the rendered viewport's restarts
(addon/viewport.py), where a view that moved and the quick low-resolution
look before the full passes each made a Renderer that built everything
again -- at a million triangles 7.6 s of set-up a restart, most of it the
BVH, the occlusion grid, the curvature and the light table
(docs/interactive.md "Set-up kept across the viewport's restarts").

A :class:`SetupCache` holds the products of one scene, told by the identity
of every field of its :class:`core.scene.model.Scene` but the camera (the
viewport replaces the camera alone when the view moves; an edit exports new
arrays).  Each product is stored under the values it depends on beyond
those fields, so that a Renderer given the cache builds exactly what it
would build without it (bit for bit: ``tests/test_setup_cache.py``):

- the triangles left after ``drop_invalid_triangles``: the fields alone;
- the light table (its bounding sphere holds the camera) and the
  occlusion grid (padded by the diameter): the recentring origin and the
  scene's bounds and diameter, which hold the camera's position;
- the BVH and the curvature: the recentring origin (a Renderer of another
  diameter makes its own Accel over the same Embree scene, its offset
  floor being relative to the diameter).

A view that moves inside the scene's bounds (an interior, a camera over a
large floor) keeps them all; one that moves the bounds keeps the
triangles, the BVH and the curvature.  One cache holds one scene's products (a new scene
replaces them), and one of each kind (the last); the viewport clears it
when it closes.
"""
from __future__ import annotations

from dataclasses import fields
from typing import Callable


class SetupCache:
    """The set-up products of the last scene a Renderer built (module doc)."""

    def __init__(self):
        self._scene = None           # held: the ids in the key stay its fields'
        self._key = None
        self._items: dict = {}
        self.hits = 0                # products taken from the cache (tests, docs)

    def _entry(self, scene) -> dict:
        key = tuple(id(getattr(scene, f.name)) for f in fields(scene) if f.name != "camera")
        if key != self._key:
            self._scene, self._key, self._items = scene, key, {}
        return self._items

    def get(self, scene, key: tuple, make: Callable):
        """The product ``key`` = (kind, what it depends on, ...) of ``scene``
        (the scene the Renderer was given, before it drops triangles or
        recentres): the one kept, or make()'s, which replaces the kind's
        last (one a kind: a view that keeps moving the bounds does not pile
        up grids)."""
        items = self._entry(scene)
        kind, deps = key[0], key[1:]
        got = items.get(kind)
        if got is not None and got[0] == deps:
            self.hits += 1
            return got[1]
        items.pop(kind, None)        # the last one freed before the new one is made
        value = make()
        items[kind] = (deps, value)
        return value

    def clear(self) -> None:
        """Drop everything (the viewport closed)."""
        self._scene, self._key, self._items = None, None, {}


def get(cache, scene, key: tuple, make: Callable):
    """``cache.get(scene, key, make)``, or make() without a cache (None)."""
    return make() if cache is None else cache.get(scene, key, make)
