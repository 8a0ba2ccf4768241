"""An Image Texture node's interpolation (Linear, Closest, Cubic) and extension
(Repeat, Extend, Clip, Mirror) (core/scene/textures.py ``sampler_code``):
numpy against a per-sample transcription of Cycles' interp_closest,
interp_linear and interp_cubic, the compiled lookup against numpy, and rendered against
Cycles."""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from core.scene import textures as TX
from core.scene.texture_kernels import bilinear_rgb

MODES = [TX.sampler_code(i, e) for i in (TX.LINEAR, TX.CLOSEST, TX.CUBIC)
         for e in (TX.REPEAT, TX.EXTEND, TX.CLIP, TX.MIRROR)]


def _reference(img, u, v, sampler):
    """Cycles' interp_closest / interp_linear / interp_cubic of one uv, one
    texel at a time."""
    H, W, _ = img.shape
    closest, ext = sampler & 3, sampler >> 2

    def wrap(i, n):
        if ext == TX.REPEAT:
            return i % n
        if ext == TX.EXTEND:
            return min(max(i, 0), n - 1)
        if ext == TX.MIRROR:
            m = abs(i + (1 if i < 0 else 0)) % (2 * n)
            return 2 * n - m - 1 if m >= n else m
        return i

    def texel(iy, ix):
        iy, ix = wrap(iy, H), wrap(ix, W)
        if not (0 <= iy < H and 0 <= ix < W):
            return np.zeros(3)
        return img[iy, ix, :3].astype(np.float64)

    if closest == TX.CLOSEST:
        return texel(math.floor(v * H), math.floor(u * W))
    x, y = u * W - 0.5, v * H - 0.5
    ix, iy = math.floor(x), math.floor(y)
    tx, ty = x - ix, y - iy
    if closest == TX.CUBIC:
        def spline(t):          # the uniform cubic B-spline's weights
            return [(1 - t) ** 3 / 6, (3 * t ** 3 - 6 * t ** 2 + 4) / 6,
                    (-3 * t ** 3 + 3 * t ** 2 + 3 * t + 1) / 6, t ** 3 / 6]
        return sum(wy * wx * texel(iy - 1 + a, ix - 1 + b)
                   for a, wy in enumerate(spline(ty)) for b, wx in enumerate(spline(tx)))
    return ((1 - ty) * ((1 - tx) * texel(iy, ix) + tx * texel(iy, ix + 1))
            + ty * ((1 - tx) * texel(iy + 1, ix) + tx * texel(iy + 1, ix + 1)))


@pytest.mark.parametrize("sampler", MODES)
def test_numpy_and_compiled_lookups_follow_cycles(sampler):
    rng = np.random.default_rng(sampler)
    img = rng.random((5, 7, 3)).astype(np.float32)
    uv = rng.uniform(-2.3, 3.1, (400, 2))
    uv[:8] = [[0, 0], [1, 1], [0.5, 0.5], [-1e-9, 0.3], [1.0 - 1e-9, 0.2], [2.0, -1.0],
              [1 / 7, 1 / 5], [-0.5 / 7, 0.5]]
    want = np.array([_reference(img, u, v, sampler) for u, v in uv])
    got = TX.sample_texture(TX.with_sampler(img, sampler), uv)
    np.testing.assert_allclose(got, want, atol=1e-12)
    comp = np.array([bilinear_rgb(img, u, v, False, sampler) for u, v in uv])
    np.testing.assert_array_equal(comp, got)


def test_a_sampled_image_keeps_its_sampler():
    code = TX.sampler_code(TX.CLOSEST, TX.CLIP)
    img = TX.with_sampler(np.ones((2, 2, 4), np.float32), code)
    assert TX.sampler_of(img[:, :1]) == TX.sampler_of(img) == code
    back = pickle.loads(pickle.dumps(img))
    assert TX.sampler_of(back) == code and np.array_equal(back, img)
    un = TX.with_sampler(np.ones((2, 2, 4), np.float32).view(TX.UnassociatedImage), code)
    assert isinstance(un, TX.UnassociatedImage) and TX.sampler_of(un) == code
    assert TX.with_sampler(np.ones((1, 1, 3)), 0).__class__ is np.ndarray
    # Closest upsampled stays exact: the same texels, repeated.
    big = TX.upsample(TX.with_sampler(np.arange(6, dtype=np.float32).reshape(2, 3, 1),
                                      TX.CLOSEST), 4)
    assert TX.sampler_of(big) == TX.CLOSEST
    np.testing.assert_array_equal(big[::4, ::4, 0], np.arange(6).reshape(2, 3))


# ------------------------------------------------------------------ Cycles

def _random_pixels(n=4):
    """Texels of random colours: Closest and Linear differ everywhere."""
    return np.random.default_rng(8).uniform(0.05, 0.95, (n, n, 3)).astype(np.float32)


@pytest.mark.parametrize("interp, ext", [("Closest", "REPEAT"), ("Linear", "CLIP"),
                                         ("Linear", "MIRROR"), ("Closest", "EXTEND"),
                                         ("Cubic", "REPEAT"), ("Smart", "CLIP")])
def test_interpolation_and_extension_agree_with_cycles(interp, ext, tmp_path):
    """tests/test_shading_nodes.py's plane, whose uvs run from 0 to 1.5
    (half the plane outside the image), a 4 x 4 image of random colours into a
    Diffuse colour read Closest, Linear, Cubic or Smart with each extension.  The image
    read Linear / Repeat, what FPPM did before (silently), is the effect."""
    pytest.importorskip("bpy")
    import dataclasses

    import test_shading_nodes as TS

    def mat(nodes, links, surface):
        d = TS.diffuse_with_normal(nodes, links, surface)
        tex = nodes.new('ShaderNodeTexImage')
        tex.image = TS._image("C", _random_pixels(), non_color=False)
        tex.interpolation = interp
        tex.extension = ext
        links.new(tex.outputs["Color"], d.inputs["Color"])

    sc, _ = TS.plane_scene(mat)
    label = f"{interp} {ext}"
    err, noise, img, ref, scene, lines = TS.compare(sc, tmp_path, label)
    assert lines[1] == "Approximated: nothing.", lines[1]
    TS._check(err, noise)
    plain = dataclasses.replace(scene, textures=[np.asarray(t) for t in scene.textures])
    effect = np.abs((TS._fppm(plain, 1) + TS._fppm(plain, 2)) / 2 - img).mean() / ref.mean()
    print(f"{label}: read Linear / Repeat the image moves by {effect:.3f} of the mean")
    TS._check(err, noise, effect)


def test_the_scene_digest_follows_the_sampler():
    """A checkpoint of a scene whose texture is read Closest does not resume
    the same scene read Linear (core.scene.model.scene_digest)."""
    from core.scene.model import Camera, Material, make_scene, scene_digest
    img = np.random.default_rng(1).random((4, 4, 3)).astype(np.float32)
    tri = [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]]

    def digest(t):
        return scene_digest(make_scene(tri, [Material("m")], [], Camera(), textures=[t]))
    plain = digest(img)
    assert digest(img.copy()) == plain
    assert digest(TX.with_sampler(img, TX.sampler_code(TX.CLOSEST))) != plain
