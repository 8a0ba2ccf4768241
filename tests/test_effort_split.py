"""COMBINED's effort split: light paths per pass from light_paths_per_camera_path
(core/settings.py ``effort_split``; docs/integrators.md, "Effort split")."""
import numpy as np
import pytest

from core.render import Renderer
from core.settings import RenderSettings, SettingsError

from analytic_scenes import point_light_plane


def test_rule_scales_the_light_paths_with_the_camera_paths():
    st = RenderSettings(integrator="COMBINED", camera_samples=4, light_paths_per_camera_path=12.2)
    # 64x64: the default balance (200k light paths for 16 384 camera paths).
    assert st.effort_split(64 * 64).photons_per_pass == 199_885
    # 128x128: four times the camera paths, four times the light paths.
    assert st.effort_split(128 * 128).photons_per_pass == 799_539
    assert st.replace(camera_samples=1).effort_split(128 * 128).photons_per_pass == 199_885
    # Clamped to photons_per_pass' range.
    assert st.replace(light_paths_per_camera_path=1e4).effort_split(4096 * 4096).photons_per_pass \
        == 100_000_000
    assert st.replace(light_paths_per_camera_path=1e-9).effort_split(1).photons_per_pass == 1


def test_rule_off_or_other_integrators_keep_the_settings():
    off = RenderSettings(integrator="COMBINED")
    assert off.effort_split(64 * 64) is off                   # default 0: photons_per_pass
    for integ in ("PHOTON", "PATH", "LIGHT"):
        st = RenderSettings(integrator=integ, light_paths_per_camera_path=12.0)
        assert st.effort_split(64 * 64) is st


@pytest.mark.parametrize("bad", [-1.0, 10_001.0, float("nan"), float("inf")])
def test_invalid_values_are_refused(bad):
    with pytest.raises(SettingsError, match="light_paths_per_camera_path"):
        RenderSettings(light_paths_per_camera_path=bad).validate()


def test_renderer_traces_the_rule_s_light_paths():
    """16x16, 4 camera paths per pixel, 39.0625 light paths per camera path =
    40 000 light paths a pass: the image is bit for bit the one rendered with
    photons_per_pass 40 000, and the photon count says 40 000 a pass."""
    scene, _ = point_light_plane(res=16)
    kw = dict(integrator="COMBINED", max_passes=2, camera_samples=4, seed=3)
    ra = Renderer(scene, RenderSettings(photons_per_pass=40_000, **kw), log=lambda s: None)
    rb = Renderer(scene, RenderSettings(photons_per_pass=1, light_paths_per_camera_path=39.0625,
                                        **kw), log=lambda s: None)
    a, b = ra.run().image, rb.run().image
    assert rb.settings.photons_per_pass == 40_000
    assert rb.photons_emitted == 2 * 40_000
    assert np.array_equal(a, b) and a[..., :3].max() > 0
