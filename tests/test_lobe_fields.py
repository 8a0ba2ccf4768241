"""core.scene.model.Lobe's Multiscatter GGX / Principled fields and the material table.

``core.materials.build_material_table`` reads ``multiscatter``, ``fresnel``,
``fresnel_ior``, ``f82_tint``, ``layer_*``, ``conductor_*``, ``thin_film_*``
with getattr.  These tests pin that
a Lobe with default fields builds the table a lobe without those attributes
built before they existed, that a lobe object carrying them as plain
attributes builds the very same table as the Lobe (exact equality: the same
floats go through the same code), and that ``core.scene.nodes`` makes plain
Lobes (there is one lobe type).
"""
import dataclasses
import types

import numpy as np

from core.materials import build_material_table
from core.scene import nodes as shading
from core.scene.model import DIFFUSE, GLASS, GLOSSY, REFRACTION, Lobe, Material

EXTRA = ("multiscatter", "fresnel", "fresnel_ior", "f82_tint", "layer_ior", "layer_f0",
         "layer_roughness", "layer_multiscatter", "alpha_texture", "alpha_invert",
         "roughness_texture", "view", "conductor_n", "conductor_k", "thin_film_thickness",
         "thin_film_ior")


def _tables_equal(a, b):
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "textures":
            assert len(x) == len(y)
            continue
        assert np.array_equal(np.asarray(x), np.asarray(y)), f.name


def _table(lobes):
    return build_material_table([Material("m", tuple(lobes))], [])


BASE = ("kind", "color", "weight", "roughness", "ior", "color_texture")


def _bare(lobe):
    """A lobe object with only the six original attributes (what the exporter made before)."""
    return types.SimpleNamespace(**{k: getattr(lobe, k) for k in BASE})


# Every kind, rough and smooth, with the original attributes only.
PLAIN = [dict(kind=DIFFUSE, color=(0.5, 0.4, 0.3), roughness=0.5),
         dict(kind=GLOSSY, color=(0.9, 0.8, 0.7), weight=0.3, roughness=0.35),
         dict(kind=GLASS, color=(1.0, 1.0, 1.0), roughness=0.0, ior=1.5),
         dict(kind=REFRACTION, color=(0.9, 0.9, 1.0), roughness=0.2, ior=1.33)]


def test_default_fields_reproduce_plain_lobes():
    for kw in PLAIN:
        _tables_equal(_table([Lobe(**kw)]), _table([_bare(Lobe(**kw))]))


def test_nodes_extra_fields_are_the_lobe_fields():
    assert set(EXTRA) <= set(Lobe.__dataclass_fields__)
    assert set(shading._EXTRA) == set(EXTRA)
    assert shading._EXTRA == {f.name: f.default for f in dataclasses.fields(Lobe)
                              if f.name in EXTRA}


# Every extra attribute away from its default, on the kinds that read it.
FULL = [
    dict(kind=GLOSSY, color=(0.95, 0.64, 0.54), roughness=0.3, multiscatter=True,
         fresnel="F82", f82_tint=(0.9, 0.8, 0.7)),
    dict(kind=GLOSSY, color=(1.0, 0.9, 0.8), weight=0.7, roughness=0.45, multiscatter=True,
         fresnel="DIELECTRIC", fresnel_ior=1.6),
    dict(kind=DIFFUSE, color=(0.6, 0.3, 0.2), weight=0.7, roughness=0.25, layer_ior=1.6,
         layer_f0=0.05, layer_roughness=0.45, layer_multiscatter=True),
    dict(kind=GLASS, color=(0.9, 0.95, 1.0), roughness=0.6, ior=1.33, multiscatter=True),
    dict(kind=GLOSSY, color=(1.0, 1.0, 1.0), roughness=0.2, multiscatter=True,
         fresnel="CONDUCTOR", conductor_n=(0.18, 0.42, 1.37), conductor_k=(3.42, 2.35, 1.77),
         thin_film_thickness=420.0, thin_film_ior=1.5),
    dict(kind=DIFFUSE, color=(0.5, 0.5, 0.5), layer_ior=1.5, layer_f0=0.04,
         layer_roughness=0.3, thin_film_thickness=250.0, thin_film_ior=1.8),
]


def _duck(lobe):
    """The same attributes on an object that is not a Lobe (the table reads them with getattr)."""
    return types.SimpleNamespace(**dataclasses.asdict(lobe))


def test_lobe_fields_build_the_same_table_as_attributes():
    for kw in FULL:
        _tables_equal(_table([Lobe(**kw)]), _table([_duck(Lobe(**kw))]))
        _tables_equal(_table([Lobe(**kw)]), _table([shading.make_lobe(**kw)]))
    for part in (FULL[:4], FULL[4:]):       # (at most MAX_LOBES lobes a material)
        _tables_equal(_table([Lobe(**kw) for kw in part]),
                      _table([_duck(Lobe(**kw)) for kw in part]))
    # The Principled mapping's own lobes are Lobes, and rebuild identically.
    lobes, _, _ = shading.principled_to_lobes(base_color=(0.7, 0.4, 0.2), metallic=0.4,
                                              roughness=0.35, specular_tint=(1.0, 0.9, 0.8),
                                              diffuse_roughness=0.3)
    assert len(lobes) == 3
    assert all(type(lb) is Lobe for lb in lobes)
    _tables_equal(_table(lobes), _table([_duck(lb) for lb in lobes]))


def test_shading_keeps_lobes_with_different_extras_apart():
    # make_lobe's extras are plain Lobe fields ...
    lb = shading.make_lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.3, multiscatter=True,
                           fresnel="DIELECTRIC", fresnel_ior=1.5)
    assert lb == Lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.3, multiscatter=True,
                      fresnel="DIELECTRIC", fresnel_ior=1.5)
    # ... and merge_lobes still tells an F82 metal from a dielectric specular
    # lobe of the same colour and roughness (their f differ).
    metal = Lobe(GLOSSY, (1.0, 1.0, 1.0), weight=0.5, roughness=0.3, fresnel="F82")
    merged, _ = shading.merge_lobes([metal, dataclasses.replace(lb, weight=0.5)])
    assert len(merged) == 2
