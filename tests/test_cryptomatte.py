"""The compositing passes against Cycles: Cryptomatte (core/sppm/
cryptomatte.py: the IDs, the slots, the mattes' weights and the manifests)
and shader AOVs (core/sppm/shader_aovs.py).

The pure tests check the hash and the slot rules against values Cycles
wrote: the manifest of a Cycles render of a cube "Parent.Cube" with a child
"Child" and a material "Red Mat" (Blender 5.2, cryptomatte/*/manifest):
{"Parent.Cube": "135bf38e", "Child": "e193c5a2"}, {"Red Mat": "7b9dbf6f",
"default_surface": "78d05529"}, and the pass key "542cafa" of
"ViewLayer.CryptoObject"; the ID in its CryptoObject00 pass of Parent.Cube
was the float32 2.7761768e-27.

The render test renders one scene with FPPM and with Cycles, the three
kinds on at Levels 6, 40 x 32 px, the same 1.5 px Blackman-Harris filter:
a grey floor, a red cube parented to an empty "Rig" (its asset), a cube
without material (default_surface), and a card of a Mix Shader of a
Diffuse and a white Transparent BSDF at 0.5 over part of the red cube.
Two shader AOVs: "tint" (Color), the floor's image texture (an 8 x 8
colour gradient over its UVs), and "mask" (Value), the luminance of that
image on the floor and 0.75 on the red cube; the other objects write none.

Noise model: a pixel's weight of an ID is a mean over n samples (FPPM's
passes, Cycles' samples) of values in [0, 1], whose variance is at most
w (1 - w) (w their mean).  A pixel's difference passes when it is within
5 sigma of the two means' noise, sigma^2 = w (1 - w) (1/n_F + 1/n_C) with
w the two renderers' mean, + 0.01; an ID's coverage (its weights summed
over the image) within 5 sigma of the sum of those variances + 0.5 % of it.
"""

import json

import numpy as np
import pytest

from fppm.core.sppm import cryptomatte as C

N_FPPM, N_CYCLES = 32, 256
KINDS = ("Object", "Material", "Asset")


def test_ids_are_cycles_hashes():
    assert C.murmur3_32(b"Parent.Cube") == 0x135BF38E
    assert C.murmur3_32(b"Child") == 0xE193C5A2
    assert C.murmur3_32(b"Red Mat") == 0x7B9DBF6F
    assert C.murmur3_32(C.DEFAULT_MATERIAL.encode()) == 0x78D05529
    assert C.name_id("Parent.Cube") == np.float32(2.7761768e-27)
    # The exponent is kept off 0 and 255: no ID is 0 (an empty slot), inf or NaN.
    for h in (0, 0x7F800000, 0xFFFFFFFF, 0x807FFFFF):
        f = C.hash_to_float(h)
        assert np.isfinite(f) and f != 0
    meta = C.metadata("ViewLayer.", {"Object": ["Parent.Cube", "Child"]})
    assert meta["cryptomatte/542cafa/name"] == "ViewLayer.CryptoObject"
    assert json.loads(meta["cryptomatte/542cafa/manifest"]) == {
        "Parent.Cube": "135bf38e", "Child": "e193c5a2"}


def test_slots_follow_cycles_rules():
    """An ID takes the first free slot or adds to its own; with every slot
    taken the others' weights go to the last; sorting by weight is stable."""
    ids, w = np.zeros((2, 2), np.float32), np.zeros((2, 2))
    a, b, c = (C.name_id(n) for n in "abc")
    for i, (id_, wt) in enumerate([(a, 0.25), (b, 0.5), (a, 0.5), (c, 0.125), (b, 0.0)]):
        C.add_to_slots(ids, w, np.array([0, 1]), np.array([id_, id_], np.float32),
                       np.array([wt, 0.3 if i == 0 else wt]))
    np.testing.assert_array_equal(ids[0], [a, b])
    np.testing.assert_allclose(w[0], [0.75, 0.625])        # c went to the last slot
    si, sw = C.sorted_slots(np.array([[a, b, c, 0]], np.float32), np.array([[0.2, 0.5, 0.2, 0]]))
    np.testing.assert_array_equal(si[0], [b, a, c, 0])


def test_mattes_state_round_trip():
    m = C.Mattes(["CryptoObject00", "CryptoAsset00", "CryptoAsset01"], 3,
                 np.array([[1.0, 2.0, 3.0]], np.float32))
    assert m.slots == {"Object": 2, "Asset": 4}
    from fppm.core.sppm.line_hits import LineHits
    # Two hits of triangle 0 (beta 1 and 0.5), one miss (no matte).
    m.add([LineHits(np.array([0, 2, 1]), np.array([0, 0, -1]), np.zeros(3), np.zeros(3),
                    np.array([[1.0] * 3, [0.5] * 3, [1.0] * 3]), np.zeros((3, 3)), np.zeros(3))])
    m2 = C.Mattes(["CryptoObject00", "CryptoAsset00", "CryptoAsset01"], 3, m.tri_ids)
    m2.load_state(m.state_dict())
    p = m2.passes(2)
    np.testing.assert_allclose(p["CryptoObject00"][:, :2], [[1.0, 0.5], [0, 0], [1.0, 0.25]])
    assert p["CryptoAsset01"].shape == (3, 4)


def test_exr_layers_use_cryptomatte_channels(tmp_path):
    """The CLI's EXR names a Cryptomatte layer's channels r, g, b, a, as
    Blender writes them, and reads them back in that order."""
    import OpenEXR
    from fppm.core.io.exr import read_exr, write_exr
    x = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)
    write_exr(str(tmp_path / "c.exr"), {"Combined": x, "CryptoObject00": x}, {})
    with OpenEXR.File(str(tmp_path / "c.exr"), separate_channels=True) as f:
        names = {n for p in f.parts for n in p.channels}
    assert {"CryptoObject00.r", "CryptoObject00.a"} <= names
    np.testing.assert_array_equal(read_exr(str(tmp_path / "c.exr"))["CryptoObject00"], x)


# -- against Cycles ----------------------------------------------------------

def _aov(mat, name, **inputs):
    """An AOV Output node ``name`` in ``mat`` with ``inputs`` (a value, or a
    node output to link)."""
    nt = mat.node_tree
    nd = nt.nodes.new('ShaderNodeOutputAOV')
    nd.aov_name = name
    for k, v in inputs.items():
        if isinstance(v, (int, float, tuple)):
            nd.inputs[k].default_value = v
        else:
            nt.links.new(v, nd.inputs[k])


def _scene(engine):
    import bpy_helpers as H
    bpy = H.bpy()
    sc = H.empty_scene((40, 32), engine=engine)
    grey = H.node_material("Grey", "BSDF_DIFFUSE", Color=(0.8, 0.8, 0.8, 1.0))
    red = H.node_material("Red", "BSDF_DIFFUSE", Color=(0.8, 0.1, 0.1, 1.0))
    floor = H.add_plane(sc, material=grey, size=6.0)
    floor.data.uv_layers.new()
    img = bpy.data.images.new("Gradient", 8, 8, float_buffer=True)
    y, x = np.mgrid[0:8, 0:8] / 7.0
    img.pixels.foreach_set(np.stack([x, y, 1 - x, np.ones_like(x)], -1).ravel()
                           .astype(np.float32))
    img.pack()
    tex = grey.node_tree.nodes.new('ShaderNodeTexImage')
    tex.image, tex.interpolation = img, 'Linear'
    _aov(grey, "tint", Color=tex.outputs["Color"])
    _aov(grey, "mask", Value=tex.outputs["Color"])
    _aov(red, "mask", Value=0.75)
    rig = H.link(bpy.data.objects.new("Rig", None), sc)
    cube = H.add_cube(sc, material=red, location=(0.3, 0.0, 0.5))
    cube.parent = rig
    H.add_cube(sc, name="Bare", size=0.6, location=(-1.0, 0.5, 0.3))
    veil = H.node_material("Veil", "BSDF_DIFFUSE", Color=(0.2, 0.5, 0.8, 1.0))
    nt = veil.node_tree
    d = next(n for n in nt.nodes if n.type == 'BSDF_DIFFUSE')
    out = next(n for n in nt.nodes if n.type == 'OUTPUT_MATERIAL')
    mix = nt.nodes.new('ShaderNodeMixShader')
    mix.inputs["Fac"].default_value = 0.5
    nt.links.new(d.outputs[0], mix.inputs[1])
    nt.links.new(nt.nodes.new('ShaderNodeBsdfTransparent').outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    H.mesh_object(sc, "Card", [(0.2, -1.2, 0.1), (1.2, -1.2, 0.1), (1.2, -1.2, 1.3),
                               (0.2, -1.2, 1.3)], [(0, 1, 2, 3)], veil)
    H.add_light(sc, "POINT", 200.0, (1.0, -1.0, 3.0))
    H.add_camera(sc)
    vl = sc.view_layers[0]
    for k in KINDS:
        setattr(vl, C.FLAGS[k], True)
    for name, kind in (("tint", 'COLOR'), ("mask", 'VALUE')):
        a = vl.aovs.add()
        a.name, a.type = name, kind
    return sc


def _save(sc, path):
    import bpy_helpers as H
    from fppm.core.io.exr import read_exr_metadata
    return H.save_multilayer(sc, path), read_exr_metadata(str(path))


def _mattes(layers, kind):
    """{id: (H, W) weights} of one kind from the passes ViewLayer.Crypto<kind>NN."""
    out = {}
    for i in range(3):
        a = layers[f"ViewLayer.Crypto{kind}{i:02d}"]
        for c in (0, 2):
            for id_ in np.unique(a[..., c]):
                if id_ != 0:
                    out.setdefault(id_, np.zeros(a.shape[:2]))
                    out[id_] += np.where(a[..., c] == id_, a[..., c + 1], 0.0)
    return out


def _manifests(meta):
    return {v.split(".Crypto")[1]: json.loads(meta[k[:-len("name")] + "manifest"])
            for k, v in meta.items() if k.startswith("cryptomatte/") and k.endswith("/name")}


@pytest.fixture(scope="module")
def cycles(tmp_path_factory):
    bpy = pytest.importorskip("bpy")
    sc = _scene("CYCLES")
    sc.cycles.samples = N_CYCLES
    sc.cycles.use_denoising = False
    bpy.ops.render.render()
    return _save(sc, tmp_path_factory.mktemp("cycles") / "c.exr")


@pytest.fixture(scope="module", params=["COMBINED", "PHOTON"])
def fppm(request, tmp_path_factory):
    bpy = pytest.importorskip("bpy")
    import bpy_helpers as H
    import fppm.addon.engine as E
    sc = _scene("FPPM")
    H.small_settings(sc, passes=N_FPPM, photons=2000, seed=3, integrator=request.param,
                     camera_samples=1)
    sess = E.RenderSession(log=lambda m: None)
    with E.session(sess):
        bpy.ops.render.render()
    assert sess.error is None
    return request.param, _save(sc, tmp_path_factory.mktemp("fppm") / "f.exr")


def test_mattes_agree_with_cycles(cycles, fppm):
    integrator, (layers, meta) = fppm
    c_layers, c_meta = cycles
    # The manifests: every object and asset Cycles lists (lights too), the
    # materials among its shaders (it lists its default shaders as well).
    mf, mc = _manifests(meta), _manifests(c_meta)
    assert mf["Object"] == mc["Object"] and mf["Asset"] == mc["Asset"]
    assert mf["Material"].items() <= mc["Material"].items()
    assert set(mf["Material"]) == {"Grey", "Red", "Veil", C.DEFAULT_MATERIAL}
    assert mc["Asset"]["Rig"] == f"{C.murmur3_32(b'Rig'):08x}" and "Cube" not in mc["Asset"]
    worst = worst_total = 0.0
    for kind in KINDS:
        f, c = _mattes(layers, kind), _mattes(c_layers, kind)
        assert set(f) == set(c), kind
        for id_ in c:
            w = 0.5 * (f[id_] + c[id_])
            var = w * (1 - w) * (1 / N_FPPM + 1 / N_CYCLES)
            r = float(np.max(np.abs(f[id_] - c[id_]) / (5 * np.sqrt(var) + 0.01)))
            worst = max(worst, r)
            assert r <= 1.0, (kind, r)
            total = abs(f[id_].sum() - c[id_].sum())
            bound = 5 * np.sqrt(var.sum()) + 0.005 * c[id_].sum()
            worst_total = max(worst_total, total / bound)
            assert total <= bound, (kind, total, bound)
    # The card lets half the camera rays through to the red cube: its
    # weight and the cube's are about 0.5 where it covers the cube.
    obj_f, obj_c = _mattes(layers, "Object"), _mattes(c_layers, "Object")
    card, cube = C.name_id("Card"), C.name_id("Cube")
    both = (obj_c[card] > 0.45) & (obj_c[cube] > 0.4)
    assert both.sum() >= 20
    np.testing.assert_allclose(obj_f[cube][both].mean(), 0.5, atol=0.05)
    print(f"\n{integrator}: worst pixel {worst:.2f} of its bound, worst coverage "
          f"{worst_total:.2f}; {int(both.sum())} pixels with the card over the cube")


@pytest.mark.parametrize("blocked", [False, True])
def test_compiled_camera_pass_records_numpy_mattes(blocked, monkeypatch):
    """The compiled camera pass (in blocks of 700 pixels, or one call)
    records the same Cryptomatte hits as the numpy reference, bit for bit,
    in a room whose glass box lets 40 % of the light through (a Transparent
    lobe): hits behind it, weighted by it."""
    import dataclasses
    from core.render import Renderer
    from core.scene.model import TRANSPARENT, Lobe
    from core.settings import RenderSettings
    from core.sppm import visible_points as VP
    from test_compiled_stages import SCENES
    if blocked:
        monkeypatch.setattr(VP, "CAMERA_BLOCK", 700)
    scene = SCENES["room"](40)
    T = scene.tri_p.shape[0]
    mats = list(scene.materials)
    m = [getattr(x, "name", "") for x in mats].index("glass")     # a box in the room
    lobes = [dataclasses.replace(lb, weight=lb.weight * 0.6) for lb in mats[m].lobes]
    mats[m] = dataclasses.replace(mats[m], lobes=lobes + [Lobe(TRANSPARENT, (1, 1, 1), 0.4)])
    ids = np.stack([C.hash_to_float(i) for i in range(1, 3 * T + 1)]).reshape(T, 3)
    scene = dataclasses.replace(scene, materials=mats, tri_crypto=ids,
                                crypto_names={k: () for k in KINDS})
    r = Renderer(scene, RenderSettings(integrator="PHOTON", max_passes=1, photons_per_pass=100,
                                       seed=1), log=lambda _m: None,
                 passes=("CryptoObject00", "CryptoMaterial00"))
    cam = r.camera_pass
    assert cam.line_hits and r.film.matte.kinds == ("Object", "Material")
    out = []
    for compiled in (False, True):
        cam.compiled = compiled
        vp, _ = cam(np.random.default_rng(11))
        # The camera rays' line records (core.sppm.line_hits), hits and
        # misses; a hit's Cryptomatte weight mean(beta) (1 - mean(T)).
        rec = [np.concatenate(a) for a in zip(*vp.first.line)]
        px, prim = rec[0], rec[1]
        o = np.lexsort((prim, px))
        out.append(tuple(a[o] for a in rec))
    for a, b in zip(*out):
        assert np.array_equal(a, b)
    px, prim, u, v, beta, d, through = out[0]
    hit = prim >= 0
    assert (~hit).any()              # the rays through the window see the world
    px, prim, w = px[hit], prim[hit], beta[hit].mean(axis=1) * (1.0 - through[hit])
    on = scene.tri_mat[prim] == m
    # Rays that crossed the box's Transparent lobe hit its back or the
    # room behind: pixels of two hits or more.  The box's own hits weigh
    # mean(beta) (1 - 0.4), beta 1 (0.4 over the choice's probability 0.4).
    assert np.sum(np.bincount(px) >= 2) > 30
    np.testing.assert_allclose(w[on], 0.6, rtol=1e-12)


def test_shader_aovs_agree_with_cycles(cycles, fppm):
    """Each shader AOV: inside surfaces (no other object within the filter
    support) within 3 x the change to the neighbouring pixels + 0.002 (the
    samples' spread over the +-1.5 px filter); at silhouettes within 5
    sigma of the coverage noise of a value in [0, 1]; over the image, the
    means within 0.01 (module docstring)."""
    _, (layers, _) = fppm
    c_layers, _ = cycles
    from test_passes import _neighbour_span
    cov = c_layers["ViewLayer.CryptoObject00"][..., 1]       # the top object's coverage
    inside = (cov > 0.999) & (_neighbour_span(cov[..., None], 2) < 1e-3)
    assert inside.sum() > 300
    for name, ch in (("tint", 4), ("mask", 1)):
        f, c = layers[f"ViewLayer.{name}"], c_layers[f"ViewLayer.{name}"]
        assert f.shape == c.shape == (32, 40, ch), name
        d = np.abs(f - c).max(axis=2)
        tol = 3 * _neighbour_span(c) + 0.002
        r_in = float((d / tol)[inside].max())
        w = np.clip(c.max(axis=2), 0.0, 1.0)
        sigma = np.sqrt(np.maximum(w * (1 - w), 1 / N_FPPM) * (1 / N_FPPM + 1 / N_CYCLES))
        r_edge = float((d / (5 * sigma + tol))[~inside].max())
        dm = float(np.abs(f.mean(axis=(0, 1)) - c.mean(axis=(0, 1))).max())
        print(f"\n{name}: inside {r_in:.2f}, silhouettes {r_edge:.2f} of their bounds, "
              f"mean {dm:.4f}")
        assert r_in <= 1 and r_edge <= 1 and dm < 0.01, name
    # The passes show what they should: the gradient on the floor, the
    # cube's 0.75, no tint (alpha 0) where no material writes it.
    c_mask, c_tint = c_layers["ViewLayer.mask"][..., 0], c_layers["ViewLayer.tint"]
    assert np.sum(np.abs(c_mask - 0.75) < 1e-6) > 10
    assert np.ptp(c_tint[inside & (c_tint[..., 3] > 0.999), 0]) > 0.3
    assert np.all(layers["ViewLayer.tint"][c_tint[..., 3] == 0, 3] == 0)
