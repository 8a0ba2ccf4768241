"""core/setup_cache.py: a Renderer given the set-up of the last Renderer of
the same scene (the rendered viewport's restarts) takes what does not depend
on what changed, and renders the image it renders without it, bit for bit.

The scene is the warm-up's closed room (core.warmup.warmup_scene: a mirror,
a glass cube, rough glossy walls, four kinds of light), photon mapping with
the frequency kernel from pass 2 (the occlusion grid built in pass 1's step),
two passes at 16 x 16 px.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fppm.core.render import Renderer
from fppm.core.settings import RenderSettings
from fppm.core.setup_cache import SetupCache
from fppm.core.warmup import warmup_scene

ST = RenderSettings(integrator="PHOTON", max_passes=2, photons_per_pass=10_000, seed=3)


@pytest.fixture(scope="module")
def room():
    return warmup_scene(16, ("POINT", "AREA", "SPOT", "SUN"))


def _moved(scene, shift):
    """The scene seen from a camera moved by ``shift`` (3,) [m] and turned 10 degrees."""
    M = np.array(scene.camera.matrix_world, np.float64, copy=True)
    c, s = np.cos(np.radians(10.0)), np.sin(np.radians(10.0))
    M[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ M[:3, :3]
    M[:3, 3] += shift
    return dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, matrix_world=M))


def _render(scene, cache=None):
    r = Renderer(scene, ST, log=lambda _m: None, setup_cache=cache)
    return r, r.run().image


def test_the_same_scene_takes_every_product_and_renders_the_same_image(room):
    cache = SetupCache()
    a, img_a = _render(room, cache)
    b, img_b = _render(room, cache)
    assert a.occ_grid is not None and a.kappa is not None
    assert (b.accel, b.light_table, b.kappa, b.occ_grid) == (a.accel, a.light_table, a.kappa,
                                                             a.occ_grid)
    assert cache.hits == 5           # triangles, light table, BVH, curvature, occlusion grid
    _, fresh = _render(room)
    assert np.array_equal(img_a, fresh) and np.array_equal(img_b, fresh)


def test_a_view_moved_inside_the_bounds_keeps_them_all(room):
    # The camera stays inside the room: the scene's bounds, and with them
    # every product, are the same.
    cache = SetupCache()
    a, _ = _render(room, cache)
    moved = _moved(room, (0.3, 0.4, -0.1))
    b, img = _render(moved, cache)
    assert b.D == a.D and b.accel is a.accel and b.occ_grid is a.occ_grid
    _, fresh = _render(moved)
    assert np.array_equal(img, fresh)


def test_a_view_that_moves_the_bounds_keeps_the_triangles_bvh_and_curvature(room):
    # Out of the room, the camera widens the bounds: the light table and
    # the occlusion grid are built again; the Accel is new (its offset
    # floor follows the diameter) over the same Embree scene.
    cache = SetupCache()
    a, _ = _render(room, cache)
    hits = cache.hits
    moved = _moved(room, (0.0, -6.0, 0.0))
    b, img = _render(moved, cache)
    assert b.D > a.D
    assert b.accel is not a.accel and b.accel._scene is a.accel._scene
    assert b.accel.diameter == b.D and b.light_table is not a.light_table
    assert b.occ_grid is not a.occ_grid and b.kappa is a.kappa
    assert cache.hits == hits + 3     # the triangles, the Embree scene, the curvature
    _, fresh = _render(moved)
    assert np.array_equal(img, fresh)


def test_another_scene_replaces_the_products(room):
    cache = SetupCache()
    a, _ = _render(room, cache)
    other = dataclasses.replace(room, tri_p=room.tri_p.copy())     # a new export
    b, _ = _render(other, cache)
    assert b.accel is not a.accel and b.kappa is not a.kappa and cache.hits == 0


def test_one_product_a_kind_is_kept(room):
    # A view that keeps widening the bounds replaces the light table and the
    # grid; the cache keeps the last of each kind, not one a view.
    cache = SetupCache()
    _render(room, cache)
    for k in range(1, 3):
        _render(_moved(room, (0.0, -4.0 * k, 0.0)), cache)
    assert sorted(cache._items) == ["accel", "kappa", "lights", "occlusion", "valid"]
    cache.clear()
    assert cache._items == {} and cache._scene is None
