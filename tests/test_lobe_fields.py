"""core.scene.model.Lobe's Principled/multiscatter fields against shading.CyclesLobe.

``core.materials.bsdf.build_material_table`` reads ``multiscatter``, ``fresnel``,
``fresnel_ior``, ``f82_tint``, ``layer_*`` with getattr, so a lobe may carry
them as Lobe fields or as CyclesLobe fields.  These tests pin that both give
the very same material table (exact equality: the same floats go through the
same code), and that a Lobe with default fields builds the table a lobe
without those attributes built before they existed.
"""
import dataclasses

import numpy as np
import pytest

from core.scene import nodes as shading
from core.materials.bsdf import build_material_table
from core.scene.model import DIFFUSE, GLASS, GLOSSY, REFRACTION, Lobe, Material

EXTRA = ("multiscatter", "fresnel", "fresnel_ior", "f82_tint", "layer_ior", "layer_f0",
         "layer_roughness", "layer_multiscatter")
HAS_FIELDS = set(EXTRA) <= set(Lobe.__dataclass_fields__)
needs_fields = pytest.mark.skipif(
    not HAS_FIELDS, reason="core.scene.model.Lobe does not declare the extra lobe fields yet")


def _tables_equal(a, b):
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "textures":
            assert len(x) == len(y)
            continue
        assert np.array_equal(np.asarray(x), np.asarray(y)), f.name


def _table(lobes):
    return build_material_table([Material("m", tuple(lobes))], [])


@dataclasses.dataclass(frozen=True)
class _BareLobe:
    """A lobe with only the six original attributes (what the exporter made before)."""
    kind: int
    color: tuple = (0.8, 0.8, 0.8)
    weight: float = 1.0
    roughness: float = 0.0
    ior: float = 1.45
    color_texture: int = -1


# Every kind, rough and smooth, with the original attributes only.
PLAIN = [dict(kind=DIFFUSE, color=(0.5, 0.4, 0.3), roughness=0.5),
         dict(kind=GLOSSY, color=(0.9, 0.8, 0.7), weight=0.3, roughness=0.35),
         dict(kind=GLASS, color=(1.0, 1.0, 1.0), roughness=0.0, ior=1.5),
         dict(kind=REFRACTION, color=(0.9, 0.9, 1.0), roughness=0.2, ior=1.33)]


def test_default_fields_reproduce_plain_lobes():
    for kw in PLAIN:
        _tables_equal(_table([Lobe(**kw)]), _table([_BareLobe(**kw)]))


@needs_fields
def test_field_defaults_equal_cycles_lobe_defaults():
    lobe = {f.name: f.default for f in dataclasses.fields(Lobe)}
    cyc = {f.name: f.default for f in dataclasses.fields(shading.CyclesLobe)}
    assert {k: lobe[k] for k in EXTRA} == {k: cyc[k] for k in EXTRA}


# Every extra attribute away from its default, on the kinds that read it.
FULL = [
    dict(kind=GLOSSY, color=(0.95, 0.64, 0.54), roughness=0.3, multiscatter=True,
         fresnel="F82", f82_tint=(0.9, 0.8, 0.7)),
    dict(kind=GLOSSY, color=(1.0, 0.9, 0.8), weight=0.7, roughness=0.45, multiscatter=True,
         fresnel="DIELECTRIC", fresnel_ior=1.6),
    dict(kind=DIFFUSE, color=(0.6, 0.3, 0.2), weight=0.7, roughness=0.25, layer_ior=1.6,
         layer_f0=0.05, layer_roughness=0.45, layer_multiscatter=True),
    dict(kind=GLASS, color=(0.9, 0.95, 1.0), roughness=0.6, ior=1.33, multiscatter=True),
]


@needs_fields
def test_lobe_and_cycles_lobe_build_identical_tables():
    for kw in FULL:
        _tables_equal(_table([Lobe(**kw)]), _table([shading.CyclesLobe(**kw)]))
    _tables_equal(_table([Lobe(**kw) for kw in FULL]),
                  _table([shading.CyclesLobe(**kw) for kw in FULL]))
    # The Principled mapping's own lobes, converted either way.
    lobes, _, _ = shading.principled_to_lobes(base_color=(0.7, 0.4, 0.2), metallic=0.4,
                                              roughness=0.35, specular_tint=(1.0, 0.9, 0.8),
                                              diffuse_roughness=0.3)
    assert len(lobes) == 3
    as_lobe = [Lobe(**dataclasses.asdict(lb)) for lb in lobes]
    as_cyc = [shading.CyclesLobe(**dataclasses.asdict(lb)) for lb in lobes]
    _tables_equal(_table(lobes), _table(as_lobe))
    _tables_equal(_table(as_lobe), _table(as_cyc))


@needs_fields
def test_shading_keeps_lobes_with_different_extras_apart():
    # make_lobe's extras are plain Lobe fields now ...
    lb = shading.make_lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.3, multiscatter=True,
                           fresnel="DIELECTRIC", fresnel_ior=1.5)
    assert lb == Lobe(GLOSSY, (1.0, 1.0, 1.0), roughness=0.3, multiscatter=True,
                      fresnel="DIELECTRIC", fresnel_ior=1.5)
    # ... and merge_lobes still tells an F82 metal from a dielectric specular
    # lobe of the same colour and roughness (their f differ).
    metal = Lobe(GLOSSY, (1.0, 1.0, 1.0), weight=0.5, roughness=0.3, fresnel="F82")
    merged, _ = shading.merge_lobes([metal, dataclasses.replace(lb, weight=0.5)])
    assert len(merged) == 2
