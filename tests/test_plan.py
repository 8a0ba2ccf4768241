"""The leave-out plan: each stage is left out only where the scene
cannot use it, leaving it out changes nothing, and a scene that needs it keeps it.

"Changes nothing" is exact here: every omitted stage either consumes no random
numbers (occlusion grid, frequency spectra) or stops at the first vertex
(specular chains), so forcing it on must give the same image bit for bit.
"""
import numpy as np
import pytest

from core.render import Renderer
from core.scene.model import DIFFUSE, GLOSSY, Lobe, Material, make_scene
from core.settings import RenderSettings

from analytic_scenes import furnace_box, mirror_caustic, point_light_plane, quad


def _run(scene, force=(), **kw):
    st = RenderSettings(**{"integrator": "PHOTON",
                           "max_passes": 3, "photons_per_pass": 20_000, "photons_for_direct": True,
                           **kw})
    r = Renderer(scene, st, log=lambda s: None, force_stages=force)
    return r, r.run().image


def _left_out(r):
    return {stage for stage, _ in r.plan.left_out}


def test_specular_chains_left_out_without_mirrors_and_kept_with_them():
    scene, _ = point_light_plane(res=12)
    r, img = _run(scene)
    assert "specular chains" in _left_out(r)
    r2, img2 = _run(scene, force=("specular chains",))
    assert r2.plan.specular_chains
    assert np.array_equal(img, img2)
    scene_m, _, _ = mirror_caustic(res=12)
    r3, _ = _run(scene_m)
    assert r3.plan.specular_chains and "specular chains" not in _left_out(r3)


def test_occlusion_grid_left_out_when_nothing_can_occlude():
    scene, _ = point_light_plane(res=12)
    r, img = _run(scene)
    assert r.plan.frequency_photons and not r.plan.occlusion_grid
    assert r.occ_grid is None
    assert "occlusion grid" in _left_out(r)
    r2, img2 = _run(scene, force=("occlusion grid",))
    assert r2.occ_grid is not None
    assert np.array_equal(img, img2)
    # The inside of a convex box cannot occlude itself either (every two
    # points on it see each other).
    box, _ = furnace_box(res=8)
    r3, _ = _run(box, max_passes=1, photons_per_pass=2_000)
    assert not r3.plan.occlusion_grid
    # A plane with a floating card above it can: the grid is built.
    card = quad((0.3, 0, 0.5), (0.2, 0, 0), (0, 0.2, 0))
    occ = make_scene(np.concatenate([scene.tri_p, np.asarray(card, np.float32)]), scene.materials,
                     scene.lights, scene.camera)
    r4, _ = _run(occ, max_passes=1, photons_per_pass=2_000)
    assert r4.plan.occlusion_grid and r4.occ_grid is not None


def test_frequency_photons_left_out_only_without_any_receiver():
    # A perfect mirror has no non-delta lobe: no visible point could hold.
    scene, _ = point_light_plane(res=12)
    scene.materials = [Material("mirror", (Lobe(GLOSSY, (0.8, 0.8, 0.8), roughness=0.0),))]
    r, img = _run(scene)
    assert not r.plan.frequency_photons
    assert "frequency photons" in _left_out(r)
    r2, img2 = _run(scene, force=("frequency photons",))
    assert r2.plan.frequency_photons
    assert np.array_equal(img, img2)
    # A rough glossy receiver keeps them (core.frequency.kernels.Receivers),
    # and so does a Lambert one.
    scene.materials = [Material("rough metal", (Lobe(GLOSSY, (0.8, 0.8, 0.8), roughness=0.5),))]
    r3, _ = _run(scene)
    assert r3.plan.frequency_photons and "frequency photons" not in _left_out(r3)
    scene.materials = [Material("white", (Lobe(DIFFUSE, (0.8, 0.8, 0.8)),))]
    r4, _ = _run(scene)
    assert r4.plan.frequency_photons


def test_settings_switch_stages_off_and_say_why():
    scene, _ = point_light_plane(res=12)
    r, _ = _run(scene, use_frequency=False)
    reasons = dict(r.plan.left_out)
    assert reasons["frequency photons"] == "frequency analysis is off"
    assert reasons["occlusion grid"] == "no frequency photons"
    # Forcing cannot override a setting that turns a stage off.
    r2, _ = _run(scene, use_frequency=False, force=("frequency photons",))
    assert not r2.plan.frequency_photons


def test_aov_and_estimator_arrays_only_when_enabled():
    scene, _ = point_light_plane(res=12)
    r, _ = _run(scene)
    assert r.spectrum is None and r.r_hist is None
    r2, res2 = _run(scene, aov_spectrum=True, frequency_estimator="QUANTILE")
    assert r2.spectrum is not None and r2.r_hist is not None
    assert r2.plan.aovs == ("aov_spectrum",)


def test_emitters_and_world_only_when_present():
    scene, _ = point_light_plane(res=12)
    r, _ = _run(scene)
    assert r.plan.emitter_kinds == ("POINT",) and not r.plan.world_emission
    scene.world_color = np.array([0.1, 0.1, 0.1])
    r2, _ = _run(scene)
    assert "WORLD" in r2.plan.emitter_kinds and r2.plan.world_emission


def test_combined_leaves_light_tracing_out_under_a_world_alone():
    """COMBINED's light paths start on the emitters light tracing follows
    (integrators.mis.light_classes): not the world's or the sun's.  With a
    world alone (an HDRI's scene) there is none: the plan leaves light
    tracing out, says why, and the camera paths render PATH's image bit for
    bit (no light paths, no CameraMIS terms); a point light brings it back."""
    scene, _ = point_light_plane(res=12)
    scene.lights = []
    scene.world_color = np.array([0.3, 0.4, 0.5])
    imgs = {}
    for mode in ("PATH", "COMBINED"):
        st = RenderSettings(integrator=mode, max_passes=2, seed=3)
        r = Renderer(scene, st, log=lambda s: None)
        imgs[mode] = r.run().image
    assert "light tracing" in _left_out(r) and r.combined_lt is None
    assert r.path_tracer.vc is None and r.photons_per_step == 0
    assert any("no emitter it traces" in line for line in r.plan_lines())
    assert imgs["PATH"].max() > 0.1
    np.testing.assert_array_equal(imgs["COMBINED"], imgs["PATH"])
    lit, _ = point_light_plane(res=12)
    lit.world_color = np.array([0.3, 0.4, 0.5])
    r2 = Renderer(lit, RenderSettings(integrator="COMBINED", max_passes=1), log=lambda s: None)
    assert "light tracing" in r2.plan.strategies and r2.combined_lt is not None


def test_plan_lines_and_metadata_name_what_was_left_out():
    scene, _ = point_light_plane(res=12)
    r, _ = _run(scene)
    lines = r.plan_lines()
    assert any(l.startswith("Plan:") for l in lines)
    assert "Left out: specular chains (no mirror, glass or transparent material)." in lines
    assert "specular chains" in r.plan.metadata()["fppm/plan"]


def test_unknown_forced_stage_is_an_error():
    scene, _ = point_light_plane(res=8)
    with pytest.raises(ValueError, match="unknown stage"):
        Renderer(scene, RenderSettings(integrator="PHOTON", max_passes=1), log=lambda s: None,
                 force_stages=("bogus",))


def test_convex_set_keeps_the_grid_when_a_light_is_outside_it():
    """Faces that all see each other cannot occlude light from a source on the
    same side; a light on the other side (or a sun) can be shadowed by them."""
    from core.scene.model import Light
    from analytic_scenes import translate
    box, _ = furnace_box(res=8)          # closed cube, normals inwards
    inside = Light("in", "POINT", (10.0,) * 3, translate(0.2, 0.1, 0.3))
    outside = Light("out", "POINT", (10.0,) * 3, translate(0.0, 0.0, 3.0))
    sun = Light("sun", "SUN", (3.0,) * 3, np.eye(4))
    for lights, needs in (([inside], False), ([outside], True), ([sun], True)):
        box.lights = lights
        r, _ = _run(box, max_passes=1, photons_per_pass=1_000)
        assert r.plan.occlusion_grid == needs, lights[0].name


@pytest.mark.parametrize("merge_weights", ["PARTITION", "MIS"])
def test_merging_kept_where_its_weights_can_use_it(merge_weights):
    """COMBINED.  Merging as an MIS strategy samples every path whose light
    reaches a diffuse or glossy visible point after a bounce: the plan keeps
    it (and its frequency photons) in a closed diffuse box without any mirror
    and says why; it leaves it out on one plane lit by a point light (no
    surface lights another).  The partition owns only caustics seen through
    a mirror or glass: out in both.  With a mirror, both keep it."""
    from core.plan import MERGING, MERGING_MIS
    mis = merge_weights == "MIS"

    def plan(scene):
        return Renderer(scene, RenderSettings(integrator="COMBINED", max_passes=1,
                                              merge_weights=merge_weights),
                        log=lambda s: None)
    box = plan(furnace_box(res=8)[0])
    assert box.merging == box.merge_mis == mis
    assert box.plan.frequency_photons == mis
    if mis:
        assert f"light tracing, power-heuristic MIS, {MERGING_MIS};" in box.plan_lines()[1]
        assert "photon merging" not in dict(box.plan.left_out)
    else:
        assert dict(box.plan.left_out)["photon merging"] == ("no mirror or glass to see a "
                                                             "caustic through")
    flat = plan(point_light_plane(res=8)[0])
    assert not flat.merging
    assert dict(flat.plan.left_out)["photon merging"] == (
        "no light reaches a surface indirectly (one plane, no mirror or glass)" if mis else
        "no mirror or glass to see a caustic through")
    mirror = plan(mirror_caustic(res=8)[0])
    assert mirror.merging and mirror.merge_mis == mis
    assert (MERGING_MIS if mis else MERGING) in mirror.plan.strategies
