"""Film > Transparent and the standard passes against Cycles (same .blend, same passes on).

One scene: a grey plane (material pass index 3), a red cube (object index 5,
material 7) and a small emissive cube (object 2, material 9) under a point
light and a dim world, Film > Transparent on, mist start 2 m / depth 6 m.
FPPM renders 16 passes, Cycles 256 samples, 40x32 px, the same 1.5 px
Blackman-Harris filter.  FPPM's passes and alpha come from the camera pass's
first hits whatever the integrator (core.sppm.film): the tests run with
photon mapping (PHOTON) and with the default, COMBINED.

Noise model (measured 2026-12, see the README "Passes"): a pass that is a
mean over filter samples (alpha, Normal, Mist, Emission, denoising passes) has
per-pixel noise only where the samples of one pixel see different values, i.e.
at silhouettes: there a fraction a of samples hits, a Bernoulli mean with
variance a(1-a)/n, n = 16 (FPPM) and 256 (Cycles).  Inside one surface the
values change only with the sub-pixel sample position: a pixel may differ from
Cycles by at most the change across the filter support (+-1.5 px for each
renderer, so 3 px of the local gradient, bounded by 3 x the largest
difference to the 8 neighbours).  Depth and the indices are Cycles' first
sample only (film.py), so inside a surface the same bound holds.
"""

import numpy as np
import pytest

import bpy_helpers as H

bpy = pytest.importorskip("bpy")

import fppm.addon.engine as E  # noqa: E402
from fppm.core.io.exr import read_exr  # noqa: E402

PASSES = ("use_pass_z", "use_pass_mist", "use_pass_normal", "use_pass_object_index",
          "use_pass_material_index", "use_pass_emit", "use_pass_position")
N_FPPM, N_CYCLES = 16, 256
EMISSION = np.array([1.0, 0.5, 0.2]) * 3.0
#: The integrators whose passes and alpha are checked.
INTEGRATORS = ("PHOTON", "COMBINED")


def _render_result(sc, path):
    return {k.split(".", 1)[1]: v for k, v in H.save_multilayer(sc, path).items()}


def _scene(transparent=True, passes=True, integrator="PHOTON"):
    sc = H.empty_scene((40, 32))
    grey = H.node_material("Grey", "BSDF_DIFFUSE", Color=(0.8, 0.8, 0.8, 1.0))
    red = H.node_material("Red", "BSDF_DIFFUSE", Color=(0.8, 0.1, 0.1, 1.0))
    em = H.node_material("Em", "EMISSION", Color=(1.0, 0.5, 0.2, 1.0), Strength=3.0)
    grey.pass_index, red.pass_index, em.pass_index = 3, 7, 9
    H.add_plane(sc, material=grey, size=3.0)
    H.add_cube(sc, material=red).pass_index = 5
    H.add_cube(sc, name="E", size=0.6, location=(-1.0, 0.5, 0.4), material=em).pass_index = 2
    H.add_light(sc, "POINT", 200.0, (1.0, -1.0, 3.0))
    H.set_world(sc, (0.05, 0.05, 0.08))
    H.add_camera(sc)
    sc.render.film_transparent = transparent
    vl = sc.view_layers[0]
    for k in PASSES:
        setattr(vl, k, passes)
    vl.cycles.denoising_store_passes = passes
    sc.world.mist_settings.start, sc.world.mist_settings.depth = 2.0, 6.0
    sc.world.mist_settings.falloff = 'QUADRATIC'
    H.small_settings(sc, passes=N_FPPM, photons=20000, seed=1, integrator=integrator)
    return sc


def _fppm(sc, path):
    sess = E.RenderSession(log=lambda m: None)
    with E.session(sess):
        bpy.ops.render.render()
    assert sess.error is None
    return sess, _render_result(sc, path)


def _cycles(sc, path, samples=N_CYCLES):
    """Cycles' render of sc (no denoising, no adaptive sampling) as _render_result."""
    sc.render.engine = 'CYCLES'
    sc.cycles.samples, sc.cycles.use_denoising, sc.cycles.device = samples, False, 'CPU'
    sc.cycles.use_adaptive_sampling = False
    bpy.ops.render.render()
    return _render_result(sc, path)


@pytest.fixture(scope="module")
def cycles(tmp_path_factory):
    return _cycles(_scene(), tmp_path_factory.mktemp("cycles") / "cycles.exr")


@pytest.fixture(scope="module", params=INTEGRATORS)
def both(request, cycles, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("both")
    sess, f = _fppm(_scene(integrator=request.param), tmp / "fppm.exr")
    return sess, f, cycles


def _interior(c, r=2):
    """Pixels fully covered in Cycles whose (2r+1)^2 neighbourhood is one
    object (r = 2: the filter support is +-1.5 px, so no sample of the pixel
    can see another object)."""
    ob = c["Object Index"][..., 0]
    pad = np.pad(ob, r, mode="edge")
    same = np.ones_like(ob, bool)
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            same &= pad[dy:dy + ob.shape[0], dx:dx + ob.shape[1]] == ob
    m = same & (c["Combined"][..., 3] == 1.0)
    m[:r, :] = m[-r:, :] = m[:, :r] = m[:, -r:] = False
    return m


def _neighbour_span(img, r=1):
    """(H, W) largest |difference| to the neighbours up to r px away (the 8
    neighbours for r = 1), over channels."""
    pad = np.pad(img, ((r, r), (r, r), (0, 0)), mode="edge")
    h, w = img.shape[:2]
    span = np.zeros((h, w))
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            span = np.maximum(span, np.abs(pad[dy:dy + h, dx:dx + w] - img).max(axis=2))
    return span


def test_passes_registered_with_blenders_names(both):
    _, f, c = both
    for name in ("Depth", "Mist", "Normal", "Object Index", "Material Index", "Emission",
                 "Denoising Normal", "Denoising Albedo", "Position"):
        assert name in c, name          # Cycles' name for the same pass
        assert name in f, name
        assert f[name].shape == c[name].shape, name


def test_alpha_is_coverage_as_cycles(both):
    _, f, c = both
    a, b = f["Combined"][..., 3], c["Combined"][..., 3]
    # Bernoulli noise of the coverage (module docstring); p floored at one
    # sample of FPPM so a silhouette Cycles saw as 0 or 1 is not a zero sigma.
    p = np.clip((a * N_FPPM + b * N_CYCLES) / (N_FPPM + N_CYCLES), 1 / N_FPPM, 1 - 1 / N_FPPM)
    sigma = np.sqrt(p * (1 - p) * (1 / N_FPPM + 1 / N_CYCLES))
    z = np.abs(a - b) / sigma
    assert z.max() < 5.0
    # The mean over 1280 pixels: 226 partial ones, sigma of the mean <= 0.0025.
    assert abs(a.mean() - b.mean()) < 0.01
    assert 0.2 < b.mean() < 0.4            # the scene really has background


def test_transparent_film_adds_no_world(both):
    sess, f, c = both
    a, b = f["Combined"][..., 3], c["Combined"][..., 3]
    empty = (a == 0) & (b == 0)
    assert empty.sum() > 500
    assert np.all(c["Combined"][empty][:, :3] == 0.0)
    if sess.settings.integrator != "PHOTON":
        # The camera paths and light paths are not the rays of the alpha
        # (the camera pass): at a silhouette they may see a surface its 16
        # rays missed.  No sample reaches a surface where Cycles' alpha is 0
        # over the whole +-2 px neighbourhood (beyond the filter support).
        empty &= _neighbour_span(b[..., None], 2) == 0
        assert empty.sum() > 400
    assert np.all(f["Combined"][empty][:, :3] == 0.0)


@pytest.mark.parametrize("name", ["Depth", "Normal", "Mist", "Denoising Normal", "Position"])
def test_geometric_pass_inside_surfaces(both, name):
    _, f, c = both
    m = _interior(c)
    assert m.sum() > 100
    a, b = f[name], c[name]
    tol = 3.0 * _neighbour_span(b) + 1e-4 * np.abs(b).max(axis=2)
    assert np.all(np.abs(a - b).max(axis=2)[m] <= tol[m])


@pytest.mark.parametrize("name", ["Normal", "Mist", "Denoising Normal"])
def test_mean_pass_whole_image(both, name):
    # Over the whole image the silhouette noise averages out: the mean of a
    # component bounded by 1 over ~230 partial pixels has sigma < 0.005.
    _, f, c = both
    assert np.all(np.abs(f[name].mean(axis=(0, 1)) - c[name].mean(axis=(0, 1))) < 0.01)


def test_background_values_as_cycles(both):
    _, f, c = both
    empty = (f["Combined"][..., 3] == 0) & (c["Combined"][..., 3] == 0)
    for name, value in (("Depth", 1e10), ("Mist", 1.0), ("Normal", 0.0), ("Position", 0.0),
                        ("Object Index", 0.0),
                        ("Material Index", 0.0), ("Denoising Albedo", 0.0), ("Emission", 0.0)):
        assert np.all(c[name][empty] == np.float32(value)), name
        assert np.all(f[name][empty] == np.float32(value)), name


@pytest.mark.parametrize("name", ["Object Index", "Material Index"])
def test_indices_inside_surfaces(both, name):
    _, f, c = both
    m = _interior(c)
    assert np.array_equal(f[name][m], c[name][m])
    assert set(np.unique(c[name])) == set(np.unique(f[name]))
    # Edge pixels take their first sample's object: same in >= 95 % of pixels
    # (measured 97-98 %: the two renderers' first samples differ at edges).
    assert np.mean(f[name] == c[name]) > 0.95


def test_emission_pass(both):
    _, f, c = both
    m = _interior(c, 1) & (c["Object Index"][..., 0] == 2)
    assert m.sum() >= 4
    assert np.allclose(f["Emission"][m], EMISSION, rtol=1e-5)
    assert np.allclose(c["Emission"][m], EMISSION, rtol=1e-5)
    # Whole-image mean: the emitter covers ~3 % of the image; its silhouette
    # pixels are Bernoulli means of 3.0-valued samples: sigma of the mean < 2e-3.
    assert np.all(np.abs(f["Emission"].mean(axis=(0, 1)) - c["Emission"].mean(axis=(0, 1)))
                  < 0.003 * EMISSION / EMISSION.max() + 1e-3)


def test_denoising_albedo_inside_surfaces(both):
    _, f, c = both
    m = _interior(c)
    # Lambert surfaces: exactly the colour; the emitter: its emission (Cycles).
    assert np.allclose(f["Denoising Albedo"][m], c["Denoising Albedo"][m], rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_opaque_film_alpha_one_and_no_passes(integrator, tmp_path):
    tmp = tmp_path
    sc = _scene(transparent=False, passes=False)
    H.small_settings(sc, passes=2, photons=2000, seed=1, integrator=integrator)
    sess, f = _fppm(sc, tmp / "o.exr")
    assert set(f) == {"Combined"}
    assert np.all(f["Combined"][..., 3] == 1.0)
    assert sess.result.aovs == {}


def test_compositor_sees_the_passes():
    # The Render Layers node offers a socket for every pass the engine
    # registers (what the Denoise node's Albedo / Normal inputs link to).
    sc = _scene()
    tree = bpy.data.node_groups.new("Comp", "CompositorNodeTree")
    if hasattr(sc, "compositing_node_group"):
        sc.compositing_node_group = tree
    rl = tree.nodes.new("CompositorNodeRLayers")
    rl.scene = sc
    names = {o.name for o in rl.outputs if o.enabled}
    assert {"Depth", "Normal", "Mist", "Emission", "Object Index", "Material Index",
            "Denoising Normal", "Denoising Albedo"} <= names, names


def test_compositor_denoise_node_uses_the_passes(tmp_path):
    """Blender's own denoiser (the compositor's Denoise node, OpenImageDenoise)
    fed by FPPM's Denoising Albedo / Normal: a 2-pass render against Cycles at
    512 samples.  Measured: RMS error 0.225 noisy, 0.059 denoised (x0.26);
    asserted x0.5 (the RMS of the noisy image has ~5 % spread between seeds)."""
    sc = _scene(transparent=False)
    if not hasattr(sc, "compositing_node_group"):
        pytest.skip("Blender < 5: compositor node tree API differs")
    H.small_settings(sc, passes=2, photons=2000, seed=1)
    tree = bpy.data.node_groups.new("Comp", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out='OUTPUT', socket_type='NodeSocketColor')
    sc.compositing_node_group = tree
    rl = tree.nodes.new("CompositorNodeRLayers")
    rl.scene = sc
    dn = tree.nodes.new("CompositorNodeDenoise")
    out = tree.nodes.new("NodeGroupOutput")
    tree.links.new(rl.outputs["Image"], dn.inputs["Image"])
    tree.links.new(rl.outputs["Denoising Normal"], dn.inputs["Normal"])
    tree.links.new(rl.outputs["Denoising Albedo"], dn.inputs["Albedo"])
    tree.links.new(dn.outputs[0], out.inputs[0])
    sc.render.use_compositing = True
    tmp = tmp_path
    sess, _ = _fppm(sc, tmp / "f.exr")
    noisy = sess.result.image[..., :3]
    im = sc.render.image_settings
    if hasattr(im, "media_type"):
        im.media_type = 'IMAGE'
    im.file_format, im.color_depth = 'OPEN_EXR', '32'
    bpy.data.images["Render Result"].save_render(filepath=str(tmp / "d.exr"), scene=sc)
    denoised = read_exr(str(tmp / "d.exr"))["Combined"][..., :3]
    sc.render.use_compositing = False
    sc.render.engine = 'CYCLES'
    sc.cycles.samples, sc.cycles.use_denoising, sc.cycles.device = 512, False, 'CPU'
    sc.cycles.use_adaptive_sampling = False
    bpy.ops.render.render()
    bpy.data.images["Render Result"].save_render(filepath=str(tmp / "r.exr"), scene=sc)
    ref = read_exr(str(tmp / "r.exr"))["Combined"][..., :3]

    def rms(a):
        return float(np.sqrt(np.mean((a - ref) ** 2)))
    assert rms(denoised) < 0.5 * rms(noisy)


def _mix_transparent(name, fac):
    """Mix Shader: fac of a white Transparent BSDF, 1 - fac of a grey Diffuse."""
    m = bpy.data.materials.new(name)
    H._ensure_nodes(m)
    nt = m.node_tree
    for nd in list(nt.nodes):
        if nd.type != 'OUTPUT_MATERIAL':
            nt.nodes.remove(nd)
    out = next(nd for nd in nt.nodes if nd.type == 'OUTPUT_MATERIAL')
    mix = nt.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = fac
    diff = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diff.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    tr = nt.nodes.new("ShaderNodeBsdfTransparent")
    nt.links.new(diff.outputs[0], mix.inputs[1])
    nt.links.new(tr.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    return m


def _card_scene(integrator="PHOTON"):
    """_scene without passes, with a 60 % Transparent / 40 % Diffuse card in
    front of the background and a cube."""
    sc = _scene(passes=False, integrator=integrator)
    card = H.add_plane(sc, name="Card", size=1.2, z=0.0, material=_mix_transparent("Card", 0.6))
    card.location = (0.3, -2.0, 1.0)
    card.rotation_euler = (np.radians(80), 0.0, 0.0)
    return sc


@pytest.fixture(scope="module")
def card_cycles(tmp_path_factory):
    return _cycles(_card_scene(), tmp_path_factory.mktemp("card") / "c.exr")


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_alpha_through_transparent_bsdf_as_cycles(card_cycles, integrator, tmp_path):
    """The card: alpha = 1 - the throughput escaping straight through (Cycles).
    Per pass FPPM's alpha is 0 or 1 (the lobe choice), so the per-pixel noise
    is the Bernoulli one of test_alpha_is_coverage_as_cycles."""
    _, f = _fppm(_card_scene(integrator), tmp_path / "f.exr")
    c = card_cycles
    a, b = f["Combined"][..., 3], c["Combined"][..., 3]
    part = (b > 0.2) & (b < 0.8)
    assert part.sum() > 20          # the card over the background: alpha ~0.4
    p = np.clip((a * N_FPPM + b * N_CYCLES) / (N_FPPM + N_CYCLES), 1 / N_FPPM, 1 - 1 / N_FPPM)
    z = np.abs(a - b) / np.sqrt(p * (1 - p) * (1 / N_FPPM + 1 / N_CYCLES))
    assert z.max() < 5.0
    # Mean over the card's see-through pixels: sigma <= 0.12 / sqrt(20).
    assert abs(a[part].mean() - b[part].mean()) < 0.05
    assert abs(b[part].mean() - 0.4) < 0.05


@pytest.mark.parametrize("falloff", ["LINEAR", "INVERSE_QUADRATIC"])
def test_mist_falloff_as_cycles(falloff, tmp_path):
    sc = _scene(passes=False)
    sc.view_layers[0].use_pass_mist = True
    sc.view_layers[0].use_pass_object_index = True
    sc.world.mist_settings.falloff = falloff
    H.small_settings(sc, passes=4, photons=2000, seed=1)
    tmp = tmp_path
    _, f = _fppm(sc, tmp / "f.exr")
    sc.render.engine = 'CYCLES'
    sc.cycles.samples, sc.cycles.use_denoising, sc.cycles.device = 64, False, 'CPU'
    bpy.ops.render.render()
    c = _render_result(sc, tmp / "c.exr")
    m = _interior(c)
    tol = 3.0 * _neighbour_span(c["Mist"]) + 1e-4
    assert np.all(np.abs(f["Mist"] - c["Mist"])[..., 0][m] <= tol[m])


@pytest.mark.parametrize("integrator", INTEGRATORS + ("PATH",))
def test_checkpoint_resume_keeps_alpha_and_passes(integrator):
    """2 passes, checkpoint, 1 more = 3 passes straight, bit for bit (the
    film's sums are in the checkpoint)."""
    from fppm.addon.export import export_scene
    from fppm.core.render import Renderer
    from fppm.core.settings import RenderSettings
    _scene()
    scene = export_scene(H.evaluated_depsgraph(), log=lambda m: None)
    assert scene.film_transparent
    names = ("Depth", "Normal", "Mist", "Denoising Albedo")

    def make(n):
        return Renderer(scene, RenderSettings(integrator=integrator, camera_samples=1,
                                              max_passes=n, photons_per_pass=3000, seed=2),
                        log=lambda m: None, passes=names)
    straight = make(3).run()
    r = make(2)
    r.run()
    d = r.state_dict()
    r2 = make(3)
    r2.load_state(d)
    resumed = r2.run()
    assert np.array_equal(resumed.image, straight.image)
    assert 0.0 < resumed.image[..., 3].mean() < 1.0
    for n in names:
        assert np.array_equal(resumed.aovs[n], straight.aovs[n]), n


def test_film_exposure_scales_emission_not_data(tmp_path):
    # Cycles' Film > Exposure scales the light passes (Emission), not the
    # data passes (Normal, Denoising Albedo).
    sc = _scene()
    H.small_settings(sc, passes=1, photons=2000, seed=1)
    sc.cycles.film_exposure = 2.0
    tmp = tmp_path
    sess, f = _fppm(sc, tmp / "f.exr")
    pr = sess.result
    assert np.array_equal(f["Emission"], pr.aovs["Emission"] * np.float32(2.0))
    assert np.any(pr.aovs["Emission"] > 0)
    for name in ("Normal", "Denoising Albedo", "Depth"):
        assert np.array_equal(f[name], pr.aovs[name]), name
