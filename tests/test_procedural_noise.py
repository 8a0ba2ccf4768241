"""Cycles' Noise, White Noise and Wave Texture nodes (core/scene/noise.py)
against Cycles, pixel by pixel (tests/procedural_cycles.py), and the pieces
of the port against per-sample transcriptions of Cycles' kernels.

Each Cycles case is a 64 x 64 tile of a 512 x 512 render of up to 64 cases
(one sample a pixel; ``procedural_cycles.mosaic``, three renders for the
131 cases, made once by the :func:`cycles` fixture): the node under test
fed, through a Mapping with a rotation, a non-zero location and scale 1.5
(z and negative coordinates, several noise cells across the tile), by the
points of a 64 x 64 render of the whole plane, and every pixel's channels
compared with the port at the Mapping's output there: (median, 99th
percentile) of |diff|.  Cycles reads the texture near the pixel centre (its
0.01-pixel filter): a noise of Detail 2 moves by 4e-5 (median, p99 1.4e-4)
over that, so ``procedural_cycles.exact_centres`` first snaps the Object
coordinates to the pixel centres in Cycles' graph (Vector Math Snap to the
pixel grid, then Add half a pixel: exact in float32), and the tile's own
point is made from them by Math nodes, exactly: the very points, and the
very values, of a 64 x 64 render of one case.  What remains is float32
rounding: Cycles' Mapping rounds to float32 where the harness computes in
float64 (an ulp of a point, 2.4e-7, moves a noise of frequency ~10 by
~1e-6, and by ~1e-5 where the Color channels' offsets of 100-200 make the
ulp 1.5e-5).  With a Mapping that is exact in float32 (no
rotation) the port agrees to a few ulp
(:func:`test_noise_is_float32_exact_on_exact_points`).

The tolerances are 3-5x the largest measured values of their group (stated
in each test; Cycles' CPU render is deterministic).  Wrong formulas fail
them: the 3D Perlin scale 0.9820 -> 0.98 moves the 3D medians to 1e-4
(200x the bound); the fBM's scaling of p from the origin given to the other
fractals (or the other's to fBM) moves Lacunarity 2.7 medians to 4e-6..3e-5
(4-30x); rounding 100 h before adding 100 in the Color and distortion
offsets moves the distorted medians to 5e-6..7e-6 (20x) and the exact p99 to
4.4e-5 (9x); dropping the 0.5 shift at |p| >= 1e6, the nudge (p + 1e-6) *
0.999999 of the Wave, a fractional octave in Ridged, a smoothstep fade or a
0.1 % gain on Hybrid each fail their tests.
"""
from __future__ import annotations

import itertools
import os

import numpy as np
import pytest

from core.scene import noise as NZ
from core.scene import procedural as PR
from procedural_cycles import Case

#: One render shows 64 cases, a 64 x 64 tile each: the pixel centres of a
#: 64 x 64 render of the plane, exact in float32.
RES, TILES = 512, 8
LOCATION, ROTATION, SCALE = (0.3, -0.7, 0.45), (0.5, 0.3, 0.9), (1.5, 1.5, 1.5)
#: A Mapping exact in float32: Cycles' Mapping output equals the harness's
#: float64 points rounded to float32.
EXACT = dict(location=(0.25, -0.5, 0.375), rotation=(0.0, 0.0, 0.0), scale=(2.0, 2.0, 2.0))
LARGE = dict(location=(250000.25, -250000.5, 0.375), rotation=(0.0, 0.0, 0.0),
             scale=(1.0, 1.0, 1.0))
TYPES = ("FBM", "MULTIFRACTAL", "RIDGED_MULTIFRACTAL", "HYBRID_MULTIFRACTAL", "HETERO_TERRAIN")
DIMS = ("1D", "2D", "3D", "4D")


def _case(kind, params, output, snap=0.0, **mapping):
    """The procedural_cycles.Case of node ``kind`` with ``params`` (sockets
    by name, properties by identifier) read at ``output``, through the
    rotated Mapping unless ``mapping`` says otherwise.  W, where the
    dimensions read it, is linked to the point's x (an (N,) W for the port);
    snap > 0 feeds the node the point snapped to that grid (White Noise: a
    hash of float bits needs the very float32 point)."""
    dims = params.get("noise_dimensions", "3D")
    uses_w = kind != "TEX_WAVE" and dims in ("1D", "4D")
    m = dict(location=LOCATION, rotation=ROTATION, scale=SCALE)
    m.update(mapping)
    return Case(kind, output, params, {"W": "X"} if uses_w else {}, snap, **m)


# The cases of each test, (case, median tolerance, p99 tolerance), by its
# parameters: the tests check them, and :func:`cycles` renders them all at
# once.

def _types_and_dimensions(dims, noise_type, normalize):
    return [(_case("TEX_NOISE", {"noise_dimensions": dims, "noise_type": noise_type,
                                 "normalize": normalize}, "Color"), 5e-7, 8e-5)]


def _detail(noise_type, detail):
    return [(_case("TEX_NOISE", {"noise_type": noise_type, "Detail": detail,
                                 "normalize": False}, "Color"), 5e-7, 1e-4)]


def _other_inputs(noise_type):
    return [(_case("TEX_NOISE", {"noise_dimensions": "2D", "noise_type": noise_type,
                                 "Detail": 3.3, "Roughness": 0.6, "Lacunarity": 2.7,
                                 "Offset": 0.8, "Gain": 2.5,
                                 "normalize": noise_type == "FBM"}, "Color"), 1e-6, 3e-4)]


def _distortion_and_factor(dims):
    return [(_case("TEX_NOISE", {"noise_dimensions": dims, "Distortion": 1.7}, "Color"),
             3e-7, 6e-5),
            (_case("TEX_NOISE", {"noise_dimensions": dims, "Distortion": 0.6, "Detail": 5.5,
                                 "noise_type": "HYBRID_MULTIFRACTAL", "Offset": 0.5,
                                 "Gain": 3.0}, "Factor"), 2e-6, 8e-5),
            (_case("TEX_NOISE", {"noise_dimensions": dims}, "Factor"), 5e-7, 4e-6)]


def _exact_points(dims):
    return [(_case("TEX_NOISE", {"noise_dimensions": dims, "noise_type": kind, "Detail": 3.3,
                                 "Lacunarity": 2.7, "Roughness": 0.6, "Offset": 0.8,
                                 "normalize": kind == "FBM"}, "Color", **EXACT), 1e-6, 5e-6)
            for kind in ("FBM", "HETERO_TERRAIN")] + [
            (_case("TEX_NOISE", {"noise_dimensions": dims, "Distortion": 1.7}, "Color",
                   **EXACT), 2e-7, 2e-5)]


def _large_coordinates(dims):
    return [(_case("TEX_NOISE", {"noise_dimensions": dims}, "Color", **LARGE), 1e-7, 1e-6)]


def _white_noise(dims, output):
    return [(_case("TEX_WHITE_NOISE", {"noise_dimensions": dims}, output, snap=0.25),
             0.0, 0.0)]


WAVES = ([("BANDS", d) for d in ("X", "Y", "Z", "DIAGONAL")]
         + [("RINGS", d) for d in ("X", "Y", "Z", "SPHERICAL")])
PROFILES = ("SIN", "SAW", "TRI")


def _wave(wave_type, direction, **more):
    key = "bands_direction" if wave_type == "BANDS" else "rings_direction"
    return {"wave_type": wave_type, key: direction, **more}


def _waves(wave_type, direction, profile):
    return [(_case("TEX_WAVE", _wave(wave_type, direction, wave_profile=profile), "Color"),
             4e-6, 6e-5)]


def _wave_distortion(wave_type, direction):
    return [(_case("TEX_WAVE", _wave(wave_type, direction, wave_profile="SAW", Distortion=4.0,
                                     Detail=5.5, **{"Detail Scale": 1.7, "Detail Roughness": 0.6,
                                                    "Phase Offset": 1.3}), "Factor"), 4e-6, 6e-5),
            (_case("TEX_WAVE", _wave(wave_type, direction, wave_profile="SIN", Distortion=2.0,
                                     Detail=0.0), "Factor"), 4e-6, 6e-5)]


#: Each test's parameters, as it is parametrised.
TYPES_AND_DIMENSIONS = list(itertools.product(DIMS, TYPES, (True, False)))
DETAILS = list(itertools.product(TYPES, (0.0, 5.5)))
WAVE_PROFILES = [(t, d, p) for t, d in WAVES for p in PROFILES]
WHITE = list(itertools.product(DIMS, ("Value", "Color")))

#: Every case, in the order they fill the renders.
CASES = [c for args in TYPES_AND_DIMENSIONS for c in _types_and_dimensions(*args)] \
    + [c for args in DETAILS for c in _detail(*args)] \
    + [c for t in TYPES for c in _other_inputs(t)] \
    + [c for d in DIMS for f in (_distortion_and_factor, _exact_points, _large_coordinates)
       for c in f(d)] \
    + [c for args in WHITE for c in _white_noise(*args)] \
    + [c for args in WAVE_PROFILES for c in _waves(*args)] \
    + [c for args in WAVES for c in _wave_distortion(*args)]


@pytest.fixture(scope="module")
def cycles(tmp_path_factory):
    """``compare(case) -> (median, p99)`` of |port - Cycles| over the case's
    pixels' channels: every case of CASES rendered on the first call (131
    cases: three renders of 44, :func:`procedural_cycles.mosaic`), a case
    not among them on its own."""
    pytest.importorskip("bpy")
    from procedural_cycles import agreement, mosaic
    done = {}

    def run(cases):
        for case in cases:
            assert PR.supported(case.kind, case.output), case
        # as many renders as 64 tiles need, the cases spread evenly over them
        per = -(-len(cases) // -(-len(cases) // (TILES * TILES)))
        tmp = tmp_path_factory.mktemp("noise")
        for k in range(0, len(cases), per):
            chunk = cases[k:k + per]
            for case, (ours, theirs) in zip(chunk, mosaic(chunk, tmp, RES, TILES)):
                done[repr(case)] = agreement(ours, theirs)

    def compare(case):
        if not done:
            run([c for c, _, _ in CASES])
        if repr(case) not in done:
            run([case])
        med, p99 = done[repr(case)]
        test = os.environ.get("PYTEST_CURRENT_TEST", "").split("::")[-1].split(" ")[0]
        print(f"{test} {case.kind} {case.output} {case.params}: median {med:.2e}, p99 {p99:.2e}")
        return med, p99
    return compare


def _check(cycles, cases):
    """Each of ``cases`` (case, median tolerance, p99 tolerance) within its
    tolerances."""
    for case, med_tol, p99_tol in cases:
        med, p99 = cycles(case)
        assert med <= med_tol and p99 <= p99_tol, (case.kind, case.output, case.params, med, p99)


# -- Noise Texture ------------------------------------------------------------

@pytest.mark.parametrize("dims,noise_type,normalize", TYPES_AND_DIMENSIONS)
def test_noise_types_and_dimensions_agree_with_cycles(dims, noise_type, normalize, cycles):
    """Every dimension x type x Normalize at Detail 2, Color output (red is
    the Factor).  Measured: median <= 1.2e-7, p99 <= 1.7e-5 (4D FBM not
    normalised)."""
    _check(cycles, _types_and_dimensions(dims, noise_type, normalize))


@pytest.mark.parametrize("noise_type,detail", DETAILS)
def test_noise_detail_agrees_with_cycles(noise_type, detail, cycles):
    """Detail 0 (one octave) and 5.5 (a fractional sixth octave, which
    Ridged ignores), 3D, Color, not normalised.  Measured: median <= 1.2e-7,
    p99 <= 2.4e-5 (FBM 5.5)."""
    _check(cycles, _detail(noise_type, detail))


@pytest.mark.parametrize("noise_type", TYPES)
def test_noise_other_inputs_agree_with_cycles(noise_type, cycles):
    """Detail 3.3, Roughness 0.6, Lacunarity 2.7, Offset 0.8, Gain 2.5, 2D,
    Color (normalised for FBM).  Measured: median <= 2.4e-7, p99 <= 7.6e-5
    (values up to 5)."""
    _check(cycles, _other_inputs(noise_type))


@pytest.mark.parametrize("dims", DIMS)
def test_noise_distortion_and_factor_agree_with_cycles(dims, cycles):
    """Distortion 1.7 (Color, FBM, Detail 2); Distortion 0.6 with Hybrid
    Multifractal, Detail 5.5, Offset 0.5, Gain 3 (Factor); no distortion
    (Factor).  Measured: median <= 6e-8, p99 <= 1.4e-5; median <= 4.8e-7,
    p99 <= 1.8e-5; median <= 1.2e-7, p99 <= 9e-7."""
    _check(cycles, _distortion_and_factor(dims))


@pytest.mark.parametrize("dims", DIMS)
def test_noise_is_float32_exact_on_exact_points(dims, cycles):
    """On points Cycles' Mapping computes exactly, Cycles' float32 arithmetic
    is the port's to the last bits: Color at Detail 3.3, Lacunarity 2.7,
    Roughness 0.6 for FBM and Hetero Terrain, and Distortion 1.7.  Measured:
    median <= 2.4e-7 (an ulp of values up to 4), p99 <= 1.3e-6; distorted:
    median <= 4.5e-8, p99 <= 5e-6 (the ulps of the distortion's noise move
    the point).  Without the fused 100 + 100 h of the Color offsets
    (``random_offset``) the green channel was 1e-5 off (p99 1.1e-5)."""
    _check(cycles, _exact_points(dims))


@pytest.mark.parametrize("dims", DIMS)
def test_noise_precision_correction_at_large_coordinates(dims, cycles):
    """Points near (1.25e6, -1.25e6) after Scale 5: Cycles wraps them every
    1e5 and adds 0.5 where |coordinate| >= 1e6 (``snoise_*d``).  Measured:
    median 0, p99 <= 1.2e-7; without the 0.5 the median is 0.08-0.1."""
    _check(cycles, _large_coordinates(dims))


# -- White Noise Texture -----------------------------------------------------

@pytest.mark.parametrize("dims,output", WHITE)
def test_white_noise_agrees_with_cycles(dims, output, cycles):
    """The point snapped to a 0.25 grid (so that Cycles hashes the very
    float32 coordinates the port hashes).  Measured: every pixel equal."""
    _check(cycles, _white_noise(dims, output))


# -- Wave Texture --------------------------------------------------------------

@pytest.mark.parametrize("wave_type,direction,profile", WAVE_PROFILES)
def test_wave_agrees_with_cycles(wave_type, direction, profile, cycles):
    """Each type, direction and profile, no distortion, Color.  Measured:
    median <= 9.5e-7, p99 <= 1.5e-5 (an ulp of the point times the wave's
    20 x Scale 5)."""
    _check(cycles, _waves(wave_type, direction, profile))


@pytest.mark.parametrize("wave_type,direction", WAVES)
def test_wave_distortion_agrees_with_cycles(wave_type, direction, cycles):
    """Distortion 4 with Detail 5.5, Detail Scale 1.7, Detail Roughness 0.6,
    Phase Offset 1.3 (Saw), and Distortion 2 with Detail 0 (Sine), Factor.
    Measured: median <= 9.5e-7, p99 <= 7.6e-6; median <= 8.1e-7,
    p99 <= 1.5e-5."""
    _check(cycles, _wave_distortion(wave_type, direction))


# -- Pieces and defaults ---------------------------------------------------------

def test_defaults_are_a_fresh_nodes():
    """The defaults tables hold a fresh node's socket values and properties."""
    pytest.importorskip("bpy")
    import bpy
    from procedural_cycles import NODE_TYPES
    mat = bpy.data.materials.new("NoiseDefaults")
    nt = mat.node_tree
    try:
        for kind, table in (("TEX_NOISE", NZ.NOISE_DEFAULTS),
                            ("TEX_WHITE_NOISE", NZ.WHITE_NOISE_DEFAULTS),
                            ("TEX_WAVE", NZ.WAVE_DEFAULTS)):
            nd = nt.nodes.new(NODE_TYPES[kind])
            for key, want in table.items():
                got = (getattr(nd, key) if key[0].islower()
                       else next(s for s in nd.inputs if s.name == key).default_value)
                assert got == pytest.approx(want) if isinstance(want, float) else got == want, \
                    (kind, key, got, want)
            names = {s.name for s in nd.inputs} - {"Vector"}
            assert names == {k for k in table if not k[0].islower()}, kind
    finally:
        bpy.data.materials.remove(mat)


def _grad_reference(d, h, x):
    """Cycles' grad1..grad4 for one hash h and offsets x, branch by branch."""
    def neg(v, c):
        return -v if c else v
    if d == 1:
        h &= 15
        return neg(1.0 + (h & 7), h & 8) * x[0]
    if d == 2:
        h &= 7
        u, v = (x[0], x[1]) if h < 4 else (x[1], x[0])
        return neg(u, h & 1) + neg(2.0 * v, h & 2)
    if d == 3:
        h &= 15
        u = x[0] if h < 8 else x[1]
        v = x[1] if h < 4 else (x[0] if h in (12, 14) else x[2])
        return neg(u, h & 1) + neg(v, h & 2)
    h &= 31
    u = x[0] if h < 24 else x[1]
    v = x[1] if h < 16 else x[2]
    s = x[2] if h < 8 else x[3]
    return neg(u, h & 1) + neg(v, h & 2) + neg(s, h & 4)


@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_gradient_tables_are_cycles_grads(d):
    """The gradient tables give grad1..grad4's float32 result bit for bit,
    for every hash value's low bits."""
    rng = np.random.default_rng(d)
    h = np.arange(64, dtype=np.uint32).repeat(8)
    x = rng.uniform(-1, 1, (d, h.size)).astype(np.float32)
    got = NZ._grad(h, list(x))
    want = np.array([np.float32(_grad_reference(d, int(hh), [np.float32(c) for c in x[:, i]]))
                     for i, hh in enumerate(h)], np.float32)
    np.testing.assert_array_equal(got, want)


def test_perlin_is_zero_on_the_lattice_and_wraps():
    """Perlin is 0 at integer points; snoise wraps every 1e5 and shifts by
    0.5 from 1e6 on (so that it is not 0 at all the integers there)."""
    rng = np.random.default_rng(7)
    for d in (1, 2, 3, 4):
        ints = [rng.integers(-50, 50, 100).astype(np.float32) for _ in range(d)]
        assert np.all(NZ.perlin(ints) == 0.0)
        p = [rng.uniform(-3, 3, 100).astype(np.float32) for _ in range(d)]
        np.testing.assert_array_equal(NZ.snoise([c + np.float32(300000.0) for c in p]),
                                      NZ.snoise([np.fmod(c + np.float32(300000.0),
                                                         np.float32(1e5)) for c in p]))
        big = [np.float32(3e6) + rng.integers(0, 1000, 100).astype(np.float32) * 0.25
               for _ in range(d)]
        np.testing.assert_array_equal(NZ.snoise(big), NZ.snoise(
            [np.fmod(c, np.float32(1e5)) + np.float32(0.5) for c in big]))


def test_outputs_are_grey_where_cycles_gives_a_float():
    """Factor, Value and Wave's two outputs are greys; W may be an array."""
    rng = np.random.default_rng(3)
    p = rng.uniform(-2, 2, (50, 3))
    for kind, out in (("TEX_NOISE", "Factor"), ("TEX_WHITE_NOISE", "Value"),
                      ("TEX_WAVE", "Color"), ("TEX_WAVE", "Factor")):
        v = PR.evaluate(kind, out, {"W": p[:, 0]}, p)
        assert v.shape == (50, 3) and v.dtype == np.float64
        np.testing.assert_array_equal(v[:, 0], v[:, 2])
    col = PR.evaluate("TEX_NOISE", "Color", {}, p)
    np.testing.assert_array_equal(col[:, 0], PR.evaluate("TEX_NOISE", "Factor", {}, p)[:, 0])
    assert np.abs(col[:, 1] - col[:, 0]).max() > 0.01
