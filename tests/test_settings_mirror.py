"""scene.fppm mirrors core's RenderSettings one to one: names, types, defaults, ranges."""
import dataclasses

import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

from fppm.addon import properties as P  # noqa: E402
from fppm.core.settings import (RenderSettings, SettingsError, ViewportSettings,  # noqa: E402
                                field_names, viewport_field_names)

RNA_TYPE = {bool: "BOOLEAN", int: "INT", float: "FLOAT", str: "ENUM"}
# The values RenderSettings.validate() accepts for each string field.
ENUM_VALUES = {
    "radius_mode": {"AUTO", "WORLD"},
    "frequency_model": {"CORRECTED", "PAPER"},
    "frequency_estimator": {"MIN", "QUANTILE"},
    "integrator": {"PHOTON", "PATH", "LIGHT", "COMBINED"},
    "radius_rule": {"PPM", "APPM", "CPPM"},
}


@pytest.fixture(scope="module")
def rna():
    H.ensure_registered()
    return P.FPPMRenderSettings.bl_rna.properties


def test_every_field_has_a_property_of_the_same_type_and_default(rna):
    names = [p.identifier for p in rna if p.identifier not in ("rna_type", "name")]
    assert sorted(names) == sorted(field_names() + viewport_field_names())
    for d in (RenderSettings(), ViewportSettings()):
        for f in dataclasses.fields(d):
            p = rna[f.name]
            default = getattr(d, f.name)
            assert p.type == RNA_TYPE[type(default)], f.name
            if p.type == "FLOAT":
                # Blender stores float32: equal to the double default within float32 rounding.
                assert p.default == pytest.approx(default, rel=1e-7, abs=1e-12), f.name
            else:
                assert p.default == default, f.name
            assert p.description, f"{f.name} has no description"
            assert p.name, f"{f.name} has no UI name"


def test_enums_have_explicit_stable_indices(rna):
    for name, values in ENUM_VALUES.items():
        items = rna[name].enum_items
        assert {it.identifier for it in items} == values
        # Explicit indices 0..n-1 in declaration order: files store the index.
        assert [it.value for it in items] == list(range(len(items)))
        assert all(it.description for it in items)


def test_limits_stay_inside_what_validate_accepts(rna):
    # Setting every numeric property to its hard min or max must still give
    # settings that validate (except the one documented cross-field rule:
    # max_passes 0 needs a time limit).
    sc = H.empty_scene()
    props = sc.fppm
    for f in dataclasses.fields(RenderSettings):
        p = rna[f.name]
        if p.type not in ("INT", "FLOAT"):
            continue
        for bound in (p.hard_min, p.hard_max):
            P.apply_settings(props, RenderSettings())
            setattr(props, f.name, bound)
            s = P.to_settings(props)
            if f.name == "max_passes" and s.max_passes == 0:
                s = s.replace(time_limit=1.0)
            s.validate()  # raises SettingsError on a bad bound
        # And the UI cannot go below/above: Blender clamps.
        P.apply_settings(props, RenderSettings())
        setattr(props, f.name, p.hard_min - (1 if p.type == "INT" else 1e-3))
        assert getattr(props, f.name) == pytest.approx(p.hard_min)


def test_to_settings_round_trips_every_field():
    sc = H.empty_scene()
    s = RenderSettings(time_limit=12.5, max_passes=7, photons_per_pass=12345, seed=99,
                       use_animated_seed=True,
                       radius_mode="WORLD", initial_radius_px=3.5, initial_radius=0.02,
                       alpha=0.6, cap_radius_at_edges=False, max_bounces=5, rr_start=2,
                       photons_for_direct=True,
                       fixed_visible_points=True, glossy_chains=False, light_samples=3,
                       use_frequency=False, frequency_fraction=0.3,
                       frequency_decay=0.25, frequency_start=4,
                       frequency_model="PAPER", frequency_estimator="QUANTILE",
                       occlusion_grid_res=32, aov_radius=True, aov_predicted_radius=True,
                       aov_spectrum=True, aov_photon_count=True, aov_held=True,
                       integrator="LIGHT", camera_samples=8, hold_alpha=0.8,
                       light_paths_per_camera_path=2.5, merge_weights="MIS",
                       camera_depth="DIRECT", radius_rule="CPPM", verify_holds=False,
                       clip_kernel=not RenderSettings().clip_kernel)
    # Every field differs from its default, so a missed field would show.
    d = RenderSettings()
    assert all(getattr(s, n) != getattr(d, n) for n in field_names())
    P.apply_settings(sc.fppm, s)
    back = P.to_settings(sc.fppm)
    assert back == s
    assert back.digest() == s.digest()
    # Defaults read back exactly too (float32 0.7 -> 0.7), so digests agree.
    P.apply_settings(sc.fppm, d)
    assert P.to_settings(sc.fppm) == d


def test_viewport_limits_stay_inside_what_validate_accepts(rna):
    sc = H.empty_scene()
    for name in viewport_field_names():
        p = rna[name]
        for bound in (p.hard_min, p.hard_max):
            setattr(sc.fppm, name, bound)
            P.viewport_settings_from_scene(sc).validate()
        setattr(sc.fppm, name, getattr(ViewportSettings(), name))
    assert P.viewport_settings_from_scene(sc) == ViewportSettings()
    with pytest.raises(SettingsError, match="viewport_resolution_divider"):
        ViewportSettings(viewport_resolution_divider=0).validate()


def test_invalid_combination_is_a_settings_error():
    sc = H.empty_scene()
    sc.fppm.max_passes = 0
    sc.fppm.time_limit = 0.0
    with pytest.raises(SettingsError, match="max_passes"):
        P.to_settings(sc.fppm).validate()


def test_unregistered_scene_gives_defaults():
    class Bare:
        pass
    assert P.settings_from_scene(Bare()) == RenderSettings()
