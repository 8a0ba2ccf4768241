"""Scene description: the exported model, textures, camera, and Cycles node translation.

The package exposes what the renderer and the tests read: the model
(:mod:`.model`: lobe kinds, Lobe, Material, Light, Camera, Scene and their
helpers), :func:`sample_texture` (:mod:`.textures`) and the camera model
(:mod:`.camera`).  The shader-node translation :mod:`core.scene.nodes` is the
exporter's and is imported by module (it uses ``core.materials``' Fresnel
formulas, which in turn read the model, so importing it here would make the
two packages import each other).
"""
from __future__ import annotations

from .camera import CameraModel, FilterSampler
from .model import (DIFFUSE, GLASS, GLOSSY, LOBE_NAMES, MAX_LOBES, REFRACTION, TRANSLUCENT,
                    TRANSPARENT, Camera, Light, Lobe, Material, Scene, drop_invalid_triangles,
                    make_scene, scene_digest)
from .textures import sample_texture

__all__ = [
    "DIFFUSE", "GLOSSY", "GLASS", "REFRACTION", "TRANSPARENT", "TRANSLUCENT", "LOBE_NAMES",
    "MAX_LOBES", "Lobe", "Material", "Light", "Camera", "Scene", "make_scene",
    "drop_invalid_triangles", "scene_digest", "sample_texture", "CameraModel", "FilterSampler",
]
