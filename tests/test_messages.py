"""Every feature FPPM ignores or approximates reaches the user exactly once.

Each case enables one feature on the same small scene (a plane, a cube, a
point light) and asserts the exporter's single sentence for it
(``Scene.approximations``, the CLI's "Approximated:" line); a render through
the engine then sends each sentence once to Blender's report (the Info log),
and in background mode Blender prints it as "Warning: ...".
"""
from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import bpy_helpers as H  # noqa: E402


def _export():
    from fppm.addon.export import export_scene
    lines = []
    s = export_scene(H.evaluated_depsgraph(), log=lines.append)
    return s, lines


def _world_node(sc, idname):
    w = H.set_world(sc, (0.1, 0.1, 0.1))
    nt = w.node_tree
    return w, nt, next(nd for nd in nt.nodes if nd.type == 'BACKGROUND'), nt.nodes.new(idname)


def _motion_blur(sc):
    sc.render.use_motion_blur = True


def _stereo(sc):
    sc.render.use_multiview = True
    sc.render.views_format = 'STEREO_3D'


def _ray_visibility(sc):
    bpy.data.objects["Cube"].visible_glossy = False


def _light_visibility(sc):
    bpy.data.objects["Point"].visible_diffuse = False


def _particle_hair(sc):
    plane = bpy.data.objects["Plane"]
    mod = plane.modifiers.new("Fur", 'PARTICLE_SYSTEM')
    mod.particle_system.settings.type = 'HAIR'
    mod.particle_system.settings.count = 10


def _curves_hair(sc):
    H.link(bpy.data.objects.new("Strands", bpy.data.hair_curves.new("Strands")), sc)


def _shadow_catcher(sc):
    bpy.data.objects["Cube"].is_shadow_catcher = True


def _volume_object(sc):
    H.link(bpy.data.objects.new("Smoke", bpy.data.volumes.new("Smoke")), sc)


def _world_volume(sc):
    w, nt, bg, vol = _world_node(sc, 'ShaderNodeVolumePrincipled')
    out = next(nd for nd in nt.nodes if nd.type == 'OUTPUT_WORLD')
    nt.links.new(vol.outputs[0], out.inputs["Volume"])


def _world_visibility(sc):
    # (Its camera visibility is honoured: tests/test_ray_visibility.py.)
    H.set_world(sc, (0.1, 0.1, 0.1)).cycles_visibility.glossy = False


def _light_path(sc):
    # The world is baked by Cycles (addon/world_bake.py), 16 pixels wide here.
    from fppm.addon import world_bake
    world_bake.WIDTH = 16
    w, nt, bg, lp = _world_node(sc, 'ShaderNodeLightPath')
    nt.links.new(lp.outputs["Is Glossy Ray"], bg.inputs["Strength"])


def _hdri_no_image(sc):
    w, nt, bg, env = _world_node(sc, 'ShaderNodeTexEnvironment')
    nt.links.new(env.outputs[0], bg.inputs["Color"])


def _mapping_location(sc):
    w, nt, bg, env = _world_node(sc, 'ShaderNodeTexEnvironment')
    im = bpy.data.images.new("Sky", 8, 4, float_buffer=True)
    im.pixels.foreach_set(np.full(8 * 4 * 4, 0.5, np.float32))
    env.image = im
    mp = nt.nodes.new('ShaderNodeMapping')
    mp.inputs["Location"].default_value = (0.0, 0.0, 1.0)
    nt.links.new(mp.outputs[0], env.inputs["Vector"])
    nt.links.new(env.outputs[0], bg.inputs["Color"])


CASES = [
    (_motion_blur, "motion blur ignored: the scene is rendered at the current frame"),
    (_stereo, "stereo 3D / multi-view: every view is rendered from the scene camera "
              "(the right eye repeats the left)"),
    (_ray_visibility, "ray visibility of 1 object(s) (Cube): diffuse, and glossy and "
                      "transmission for photons, light paths and rough bounces, treated as "
                      "visible (camera, shadow, and a mirror's or glass's rays are honoured)"),
    (_light_visibility, "photons and light paths of 1 object(s) (Point) (hidden from some "
                        "kind of ray): a first bounce off a material with lobes of both kinds "
                        "keeps every lobe"),
    (_particle_hair, "hair of 1 object(s) (Plane) not rendered"),
    (_curves_hair, "hair of 1 object(s) (Strands) not rendered"),
    (_shadow_catcher, "shadow catcher on 1 object(s) (Cube): lit without the other objects "
                      "by light samples alone (no light between catchers); the matte at its "
                      "silhouettes approximated"),
    (_volume_object, "volume object(s) not rendered: 1 object(s) (Smoke)"),
    (_world_volume, "world: volume ignored"),
    (_world_visibility, "world (hidden from some kind of ray): its photons and light paths: "
                        "a first bounce off a material with lobes of both kinds keeps every lobe"),
    (_light_path, "world: Light Path Is Glossy Ray read as a diffuse ray's by every ray but "
                  "the camera's"),
    (_hdri_no_image, "world: 'Environment Texture' has no image: the Background colour is used"),
    (_mapping_location, "world: location of 'Mapping' ignored"),
]


def test_plain_scene_has_no_message():
    H.simple_scene(res=(16, 16), passes=1)
    s, lines = _export()
    assert s.approximations == ()
    assert lines[1] == "Approximated: nothing."


@pytest.mark.parametrize("enable, message", CASES, ids=[c[0].__name__[1:] for c in CASES])
def test_each_feature_gives_its_single_message(enable, message, monkeypatch):
    from fppm.addon import world_bake
    monkeypatch.setattr(world_bake, "WIDTH", world_bake.WIDTH)
    sc = H.simple_scene(res=(16, 16), passes=1)
    enable(sc)
    s, lines = _export()
    assert s.approximations == (message,)
    assert lines[-1] == f"Approximated: {message}."


def test_render_reports_each_message_once_and_fills_the_right_eye(monkeypatch):
    from fppm.addon import engine as E
    sc = H.simple_scene(res=(16, 16), passes=1)
    for enable, _ in CASES[:3]:
        enable(sc)
    reported = []
    monkeypatch.setattr(E, "report_warning", lambda engine, msg: reported.append(msg))
    eyes = {}
    write = E.FPPMRenderEngine._write

    def spy(self, rresult, pr, aovs, gain):
        write(self, rresult, pr, aovs, gain)
        layer = rresult.layers[0]
        for v in rresult.views:
            p = layer.passes.find_by_name("Combined", v.name)
            px = np.empty(len(p.rect) * 4, np.float32)
            p.rect.foreach_get(px)
            eyes[v.name] = px
    monkeypatch.setattr(E.FPPMRenderEngine, "_write", spy)
    bpy.ops.render.render()
    assert reported == [m for _, m in CASES[:3]]
    assert set(eyes) == {"left", "right"}
    assert eyes["left"].max() > 0 and np.array_equal(eyes["left"], eyes["right"])


def _background_render(tmp_path, setup: str = "") -> list:
    """The output lines of an 8x8 render of H.simple_scene by bpy in a process
    of its own, no FPPM session (Blender's own render, as ``blender -b``);
    ``setup``: Python lines run on ``sc`` before it."""
    script = tmp_path / "r.py"
    script.write_text(
        "import sys\n"
        f"sys.path.insert(0, {H.ROOT + '/tests'!r})\n"
        "import bpy_helpers as H, bpy\n"
        "sc = H.simple_scene(res=(8, 8), passes=1)\n"
        + setup +
        "bpy.ops.render.render()\n")
    import subprocess
    out = subprocess.run([H.PYTHON, str(script)], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    return (out.stdout + out.stderr).splitlines()


def test_blender_prints_the_report_in_background_mode(tmp_path):
    """The real RenderEngine.report: Blender prints "Warning: <message>" once."""
    lines = _background_render(tmp_path, "sc.render.use_motion_blur = True\n")
    msg = "Warning: motion blur ignored: the scene is rendered at the current frame"
    assert lines.count(msg) == 1, lines[-40:]


def test_plan_lines_are_said_once_by_the_cli_and_by_blender(tmp_path):
    """The plan's lines ("Plan:", "Left out:") go to Blender's Info log when
    Blender renders (``blender -b`` prints them once, as "Info: ..."), and
    only to the CLI's own output under ``fppm render`` (no "Info:" copy): a
    render used to print each twice there, and ``fppm converge`` showed its
    muted warm-up render's lines."""
    H.simple_scene(res=(8, 8), passes=1)
    blend = H.save_blend(tmp_path / "s.blend")
    r = H.run_fppm("render", blend, "-o", tmp_path / "o.exr", "--no-preview", "-q")
    assert r.returncode == 0, r.stderr[-2000:]
    lines = (r.stdout + r.stderr).splitlines()
    plan = [ln for ln in lines if "Plan:" in ln]
    assert len(plan) == 1 and plan[0].startswith("Plan:"), plan
    assert not [ln for ln in lines if ln.startswith("Info: ")]
    plan = [ln for ln in _background_render(tmp_path) if "Plan:" in ln]
    assert len(plan) == 1 and plan[0].startswith("Info: Plan:"), plan
