"""Camera projection against Blender's own (sensor fit, shift, aspect, ortho).

For random world points in view, Blender's ``world_to_camera_view`` gives the
normalised frame position; core's CameraModel must map the ray through that
film position back onto the same world direction.  Exact up to float error.
"""
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")


def _setup(kind, fit, res, shift, aspect=(1.0, 1.0)):
    import bpy_helpers as H
    sc = H.empty_scene(res=res)
    ob = H.add_camera(sc, location=(0.3, -4.0, 1.2), rotation=(math.radians(75), 0.1, 0.2))
    cd = ob.data
    cd.type = kind
    cd.sensor_fit = fit
    cd.sensor_width, cd.sensor_height = 36.0, 20.0
    cd.shift_x, cd.shift_y = shift
    cd.ortho_scale = 5.0
    sc.render.pixel_aspect_x, sc.render.pixel_aspect_y = aspect
    return sc, ob


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
@pytest.mark.parametrize("fit,res,shift,aspect", [
    ("AUTO", (64, 40), (0.0, 0.0), (1.0, 1.0)),
    ("AUTO", (40, 64), (0.1, -0.2), (1.0, 1.0)),
    ("HORIZONTAL", (50, 50), (0.0, 0.15), (1.0, 1.0)),
    ("VERTICAL", (64, 32), (-0.1, 0.0), (1.0, 1.0)),
    ("AUTO", (48, 48), (0.05, 0.05), (2.0, 1.0)),
])
def test_rays_match_blender_projection(kind, fit, res, shift, aspect):
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    from fppm.addon.export import export_scene
    from fppm.core.scene.camera import CameraModel, FilterSampler

    sc, ob = _setup(kind, fit, res, shift, aspect)
    # A light and a plane so the exporter accepts the scene.
    import bpy_helpers as H
    H.add_light(sc, "POINT", 100.0, (0, 0, 3))
    H.mesh_object(sc, "plane", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [(0, 1, 2, 3)])
    dg = bpy.context.evaluated_depsgraph_get()
    scene = export_scene(dg, log=lambda s: None)
    cam = CameraModel(scene.camera)
    rng = np.random.default_rng(3)
    W, H_ = scene.camera.resolution
    px = rng.uniform(0, W, 50)
    py = rng.uniform(0, H_, 50)
    # Film position px = pixel index + 0.5 (zero-width filter): pass px - 0.5.
    fs = FilterSampler(0.0)
    rays2, _ = cam.generate(px - 0.5, py - 0.5, np.zeros((50, 2)), np.zeros((50, 2)), fs)
    for k in range(50):
        p = rays2.o[k] + 3.0 * rays2.d[k]
        v = world_to_camera_view(sc, ob.evaluated_get(dg), Vector(p.tolist()))
        assert v.x * W == pytest.approx(px[k], abs=1e-3)
        assert v.y * H_ == pytest.approx(py[k], abs=1e-3)
