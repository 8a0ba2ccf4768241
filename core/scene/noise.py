"""Cycles' Noise, White Noise and Wave Texture nodes, vectorised over points.

Ports of Cycles' SVM kernels (intern/cycles/kernel/svm/): ``noise.h``
(Perlin noise ``perlin_1d``..``perlin_4d``, ``snoise_*d``), ``fractal_noise.h``
(``noise_fbm``, ``noise_multi_fractal``, ``noise_hetero_terrain``,
``noise_hybrid_multi_fractal``, ``noise_ridged_multi_fractal``),
``noisetex.h`` (``svm_node_tex_noise``), ``white_noise.h``
(``svm_node_tex_white_noise``) and ``wave.h`` (``svm_wave``).

Cycles computes in float32, and the noise depends on it where a float is
floored to pick a cell or hashed through its bits: every stage here runs on
float32 arrays in Cycles' order of operations (numpy keeps float32 when a
float32 array meets a Python float), so the cells, hashes and gradients are
Cycles' own.  Cycles' build fuses the multiply-add of the seeded offsets
(:func:`random_offset`), which is followed; what is left is the last-bit
rounding of other contracted multiply-adds and of the SIMD kernels' order of
interpolation: a few ulp on points Cycles and the port hold alike
(tests/test_procedural_noise.py).  The hashes are core/scene/cycles_hash.py's
lookup3.

The public functions take (output, params, p) as core/scene/procedural.py
calls them: p (N, 3) float64 texture-space points, params the node's sockets
by name and properties by identifier (a missing key is Blender's default,
the ``*_DEFAULTS`` tables), and return (N, 3) float64.  W may also be an
(N,) array, as when the W socket is linked.
"""
from __future__ import annotations

import numpy as np

from . import cycles_hash as CH

F32 = np.float32
U32 = np.uint32

#: Points evaluated at a time: the (2^d, CHUNK) corner arrays of a 4D Perlin
#: stay within a few MB and memory stays bounded for any N (measured on the
#: default Color: 1.17 M points/s at 2^14, 0.96 M at 2^15, 1.09 M at 2^13).
CHUNK = 1 << 14

#: A fresh node's inputs and properties in Blender 5.2 (bpy 5.2.3).
NOISE_DEFAULTS = {
    "W": 0.0, "Scale": 5.0, "Detail": 2.0, "Roughness": 0.5, "Lacunarity": 2.0,
    "Offset": 0.0, "Gain": 1.0, "Distortion": 0.0,
    "noise_dimensions": "3D", "noise_type": "FBM", "normalize": True,
}
WHITE_NOISE_DEFAULTS = {"W": 0.0, "noise_dimensions": "3D"}
WAVE_DEFAULTS = {
    "Scale": 5.0, "Distortion": 0.0, "Detail": 2.0, "Detail Scale": 1.0,
    "Detail Roughness": 0.5, "Phase Offset": 0.0,
    "wave_type": "BANDS", "bands_direction": "X", "rings_direction": "X",
    "wave_profile": "SIN",
}

_DIMENSIONS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}


def _param(params: dict, defaults: dict, key: str):
    return params.get(key, defaults[key])


# --------------------------------------------------------------------------
# Perlin noise (noise.h)

#: (2^d, d) int32: bit k of corner c is its offset along axis k, so that the
#: corner values reshaped to (2,)*d + (N,) are indexed [..., bz, by, bx].
_CORNERS = {d: ((np.arange(1 << d)[:, None] >> np.arange(d)) & 1).astype(np.int32)
            for d in (1, 2, 3, 4)}

#: ``noise_scale1``..``noise_scale4``: the OSL factors mapping each Perlin
#: to about [-1, 1].
_NOISE_SCALE = {1: F32(0.25), 2: F32(0.6616), 3: F32(0.9820), 4: F32(0.8344)}

_HASH = {1: CH.hash_uint, 2: CH.hash_uint2, 3: CH.hash_uint3, 4: CH.hash_uint4}


def _gradient_table(d: int) -> np.ndarray:
    """(d, 2^b) float32: column h is the gradient Cycles' ``grad1``..``grad4``
    picks for hash bits h (b = 4, 3, 4, 5 low bits), so that its dot with the
    offset is the sum of table[k, h] * offset_k.

    ``grad1``: +-(1 + (h & 7)), negative if h & 8.  ``grad2``: u +- 2v with
    (u, v) = (x, y) if h < 4 else (y, x).  ``grad3``: u = x if h < 8 else y;
    v = y if h < 4, else x if h is 12 or 14, else z.  ``grad4``: u = x if
    h < 24 else y; v = y if h < 16 else z; s = z if h < 8 else w.  u, v and s
    are negated by bits 0, 1 and 2.  The zero weights make the sum, term by
    term, the very float32 sum Cycles forms (x + 0 = x, and the kept terms
    are added in Cycles' order or commuted)."""
    bits = {1: 4, 2: 3, 3: 4, 4: 5}[d]
    t = np.zeros((d, 1 << bits), F32)
    for h in range(1 << bits):
        def sign(bit):
            return -1.0 if h & bit else 1.0
        if d == 1:
            t[0, h] = sign(8) * (1 + (h & 7))
        elif d == 2:
            u, v = (0, 1) if h < 4 else (1, 0)
            t[u, h] += sign(1)
            t[v, h] += 2.0 * sign(2)
        elif d == 3:
            u = 0 if h < 8 else 1
            v = 1 if h < 4 else (0 if h in (12, 14) else 2)
            t[u, h] += sign(1)
            t[v, h] += sign(2)
        else:
            u, v, s = (0 if h < 24 else 1), (1 if h < 16 else 2), (2 if h < 8 else 3)
            t[u, h] += sign(1)
            t[v, h] += sign(2)
            t[s, h] += sign(4)
    return t


_GRADIENTS = {d: _gradient_table(d) for d in (1, 2, 3, 4)}


def _grad(h: np.ndarray, offsets: list) -> np.ndarray:
    """Cycles' ``grad1``..``grad4``: the hashed gradient dotted with the
    offsets (d arrays like h) to the corner, (2^d, N) float32."""
    table = _GRADIENTS[len(offsets)]
    idx = (h & U32(table.shape[1] - 1)).astype(np.intp)
    g = None
    for k, o in enumerate(offsets):
        term = table[k].take(idx)
        term *= o
        g = term if g is None else np.add(g, term, out=g)
    return g


def _fade(t: np.ndarray) -> np.ndarray:
    """``fade``: Perlin's quintic 6t^5 - 15t^4 + 10t^3 (float32)."""
    return t * t * t * (t * (t * F32(6.0) - F32(15.0)) + F32(10.0))


def perlin(coords: list) -> np.ndarray:
    """(N,) float32 Cycles' ``perlin_1d``..``perlin_4d`` at the point whose
    d = len(coords) coordinates are the (N,) float32 arrays coords.

    The 2^d cell corners are hashed at once as (2^d, N) arrays (the SSE/AVX
    kernels' vectors, widened), their gradients dotted with the offset to
    each corner, and blended by the faded fractions along x, then y, z, w
    with the SIMD kernels' ``mix`` (a + t (b - a)); the AVX2 ``perlin_4d``
    blends w first, a last-bit difference."""
    d = len(coords)
    n = coords[0].shape[0]
    bits = _CORNERS[d]
    cells, fracs, fades = [], [], []
    for k, c in enumerate(coords):
        fl = np.floor(c)                       # floorfrac: floorf, then (int)
        f = c - fl
        cells.append(fl.astype(np.int32)[None, :] + bits[:, k, None])
        fracs.append(f[None, :] - bits[:, k, None].astype(F32))
        fades.append(_fade(f))
    g = _grad(_HASH[d](*cells), fracs).reshape((2,) * d + (n,))
    for t in fades:                            # x first: the axis before N
        a, b = g[..., 0, :], g[..., 1, :]
        g = a + t * (b - a)
    return g


def snoise(coords: list) -> np.ndarray:
    """(N,) float32 Cycles' signed noise ``snoise_1d``..``snoise_4d``: Perlin
    of the coordinates wrapped every 100000 (``fmod``, so that float32 keeps
    a fraction) plus 0.5 where |coordinate| >= 1e6 (Cycles' precision
    correction: there fmod gives integers, where Perlin is 0), times the
    dimension's ``noise_scale``."""
    wrapped = []
    for c in coords:
        big = np.abs(c).max(initial=F32(0.0))
        if big >= F32(100000.0):             # else fmod is the identity
            w = np.fmod(c, F32(100000.0))
            if big >= F32(1000000.0):
                w[np.abs(c) >= F32(1000000.0)] += F32(0.5)
            c = w
        wrapped.append(c)
    return _NOISE_SCALE[len(coords)] * perlin(wrapped)


# --------------------------------------------------------------------------
# Fractal noise (fractal_noise.h)

def _octaves(p: list, lacunarity, from_origin: bool):
    """The octaves' noises, (N,) float32 each, lazily: snoise of p, then of
    p scaled by lacunarity once more each octave.  ``noise_fbm`` scales p by
    an accumulated float32 factor (from_origin), the other fractals
    multiply p itself each octave (the same values for lacunarity 2)."""
    lac = F32(lacunarity)
    fscale = F32(1.0)
    while True:
        if from_origin:
            yield snoise([fscale * c for c in p])
            fscale = F32(fscale * lac)
        else:
            yield snoise(p)
            p = [c * lac for c in p]


def _fbm(oct, n, rmd, rough, offset, gain, normalize):
    """``noise_fbm``: sum of octaves weighted 1, r, r^2, ...; normalised to
    [0, 1] by the weights' sum if asked; a fractional detail blends in one
    more octave."""
    amp, maxamp, s = F32(1.0), F32(0.0), F32(0.0)
    for _ in range(n):
        s = s + next(oct) * amp
        maxamp = F32(maxamp + amp)
        amp = F32(amp * rough)
    if rmd != 0.0:
        s2 = s + next(oct) * amp
        if normalize:
            a = F32(0.5) * s / maxamp + F32(0.5)
            b = F32(0.5) * s2 / F32(maxamp + amp) + F32(0.5)
        else:
            a, b = s, s2
        return a + F32(rmd) * (b - a)
    return F32(0.5) * s / maxamp + F32(0.5) if normalize else s


def _multi_fractal(oct, n, rmd, rough, offset, gain, normalize):
    """``noise_multi_fractal``: product of (1 + r^i octave_i)."""
    value, pwr = F32(1.0), F32(1.0)
    for _ in range(n):
        value = value * (pwr * next(oct) + F32(1.0))
        pwr = F32(pwr * rough)
    if rmd != 0.0:
        value = value * (F32(F32(rmd) * pwr) * next(oct) + F32(1.0))
    return value


def _hetero_terrain(oct, n, rmd, rough, offset, gain, normalize):
    """``noise_hetero_terrain``: each octave after the first adds
    (octave + offset) r^i times the value so far."""
    off = F32(offset)
    value = off + next(oct)
    pwr = F32(rough)
    for _ in range(n - 1):
        value = value + (next(oct) + off) * pwr * value
        pwr = F32(pwr * rough)
    if rmd != 0.0:
        value = value + F32(rmd) * ((next(oct) + off) * pwr * value)
    return value


def _hybrid_multi_fractal(oct, n, rmd, rough, offset, gain, normalize):
    """``noise_hybrid_multi_fractal``: octaves added with a weight that the
    previous signals (times Gain) set, capped at 1; a point's loop stops once
    its weight is <= 0.001 (a mask here), and so does its fractional
    octave."""
    off, gn = F32(offset), F32(gain)
    pwr = F32(1.0)
    value = weight = None
    for i in range(n + (rmd != 0.0)):
        if weight is None:
            live = None
        else:
            live = weight > F32(0.001)
            if not live.any():
                break
            weight = np.minimum(weight, F32(1.0))
        signal = (next(oct) + off) * pwr
        if i == n:                              # the fractional octave
            return value + np.where(live, F32(rmd) * weight * signal, F32(0.0))
        pwr = F32(pwr * rough)
        if live is None:                        # first octave: weight 1, all live
            value, weight = signal, gn * signal
        else:
            value = np.where(live, value + weight * signal, value)
            weight = np.where(live, weight * (gn * signal), weight)
    return value


def _ridged_multi_fractal(oct, n, rmd, rough, offset, gain, normalize):
    """``noise_ridged_multi_fractal``: squared ridges offset - |octave|, each
    weighted by the previous signal times Gain (clamped to [0, 1]) and r^i.
    Cycles ignores a fractional detail here."""
    off, gn = F32(offset), F32(gain)
    signal = off - np.abs(next(oct))
    signal = signal * signal
    value = signal
    pwr = F32(rough)
    for _ in range(n - 1):
        weight = np.clip(signal * gn, F32(0.0), F32(1.0))
        s = off - np.abs(next(oct))
        signal = s * s * weight
        value = value + signal * pwr
        pwr = F32(pwr * rough)
    return value


_FRACTALS = {
    "FBM": _fbm,
    "MULTIFRACTAL": _multi_fractal,
    "HETERO_TERRAIN": _hetero_terrain,
    "HYBRID_MULTIFRACTAL": _hybrid_multi_fractal,
    "RIDGED_MULTIFRACTAL": _ridged_multi_fractal,
}


def fractal(kind: str, p: list, detail: float, roughness: float, lacunarity: float,
            offset: float = 0.0, gain: float = 1.0, normalize: bool = True) -> np.ndarray:
    """(N,) float32 Cycles' ``noise_select``: the fractal ``kind`` (a
    noise_type identifier) of snoise at p, a list of d (N,) float32 arrays.
    Octaves 0..int(detail) (C's truncation), then a fractional one weighted
    by detail - floor(detail) (except ridged)."""
    detail = F32(detail)
    n = int(detail) + 1
    rmd = float(F32(detail - np.floor(detail)))
    oct = _octaves(p, lacunarity, kind == "FBM")
    return np.asarray(_FRACTALS[kind](oct, n, rmd, F32(roughness), offset, gain, normalize),
                      F32)


# --------------------------------------------------------------------------
# Noise Texture (noisetex.h)

def random_offset(d: int, seed: float) -> np.ndarray:
    """(d,) float32 Cycles' ``random_float_offset`` (d = 1) ..
    ``random_float4_offset``: a per-seed shift in [100, 200] per axis, by
    which the Color channels and the distortion read other noises."""
    s = np.full(d, seed, F32)
    h = (CH.hash_float_to_float(s) if d == 1
         else CH.hash_float2_to_float(s, np.arange(d, dtype=F32)))
    # 100 + h * 100 rounded once, as Cycles' build fuses it (an FMA or exact
    # constant folding): rounding the product first moves a third of the
    # offsets by an ulp (1.5e-5), a visible 1e-5 in the Color output.
    return (100.0 + h.astype(F32).astype(np.float64) * 100.0).astype(F32)


def _noise_coords(p32: np.ndarray, w: np.ndarray, d: int) -> list:
    """The d coordinates the node's dimensions read: W (1D), xy, xyz, xyzw."""
    xyz = [p32[:, 0], p32[:, 1], p32[:, 2]]
    return {1: [w], 2: xyz[:2], 3: xyz, 4: xyz + [w]}[d]


def _noise_chunk(output, q, w, d, kind, detail, rough, lac, offset, gain, dist, normalize):
    """The Noise Texture's output at one chunk (``svm_node_tex_noise`` and
    ``noise_texture_1d``..``_4d``), (n, 3) float32 for Color, else (n, 1):
    q (n, 3) and w (n,) float32 already times Scale."""
    p = _noise_coords(q, w, d)
    if dist != 0.0:
        # Each axis shifted by the noise at its own seeded offset (seeds
        # 0..d-1), all read at the undistorted point.
        shift = [snoise([c + o for c, o in zip(p, random_offset(d, float(k)))]) * dist
                 for k in range(d)]
        p = [c + s for c, s in zip(p, shift)]

    def select(pp):
        return fractal(kind, pp, detail, rough, lac, offset, gain, normalize)

    value = select(p)
    if output != "Color":
        return value[:, None]                   # grey: broadcast by _by_chunks
    # Green and blue: the fractal at seeds d and d + 1's offsets.
    chans = [value] + [select([c + o for c, o in zip(p, random_offset(d, float(seed)))])
                       for seed in (d, d + 1)]
    return np.stack(chans, -1)


def _by_chunks(f, p: np.ndarray, w) -> np.ndarray:
    """(N, 3) float64 f(q, w) over chunks of CHUNK points: q (n, 3) and w
    (n,) float32 (p and w as float32); f gives (n, 3) or, for a grey, (n, 1)."""
    p32 = np.asarray(p, np.float64).reshape(-1, 3).astype(F32)
    n = p32.shape[0]
    w = np.broadcast_to(np.asarray(w, F32), (n,))
    out = np.empty((n, 3), np.float64)
    for s in range(0, n, CHUNK):
        out[s:s + CHUNK] = f(p32[s:s + CHUNK], w[s:s + CHUNK])
    return out


def noise_texture(output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 Cycles' Noise Texture (``svm_node_tex_noise``) output
    ``output`` ('Factor' as grey, or 'Color') at p (N, 3) float64.

    Detail is clamped to [0, 15] and Roughness to >= 0 as Cycles does; the
    vector and W are multiplied by Scale in float32."""
    def get(key):
        return _param(params, NOISE_DEFAULTS, key)
    d = _DIMENSIONS[get("noise_dimensions")]
    scale = F32(get("Scale"))
    detail = float(np.clip(F32(get("Detail")), 0.0, 15.0))
    rough = max(float(F32(get("Roughness"))), 0.0)
    args = (d, get("noise_type"), detail, rough, float(get("Lacunarity")),
            float(get("Offset")), float(get("Gain")), float(F32(get("Distortion"))),
            bool(get("normalize")))

    def chunk(q, w):
        return _noise_chunk(output, q * scale, w * scale, *args)
    return _by_chunks(chunk, p, get("W"))


# --------------------------------------------------------------------------
# White Noise Texture (white_noise.h)

def white_noise_texture(output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 Cycles' White Noise Texture (``svm_node_tex_white_noise``)
    output 'Value' (grey) or 'Color' at p (N, 3) float64: lookup3 hashes of
    the float32 bits of W (1D), xy, xyz or xyzw."""
    d = _DIMENSIONS[_param(params, WHITE_NOISE_DEFAULTS, "noise_dimensions")]
    colour = output == "Color"

    def chunk(q, w):
        c = _noise_coords(q, w, d)
        if colour:
            return {1: CH.hash_float_to_float3, 2: CH.hash_float2_to_float3,
                    3: CH.hash_float3_to_float3, 4: CH.hash_float4_to_float3}[d](*c)
        v = {1: CH.hash_float_to_float, 2: CH.hash_float2_to_float,
             3: CH.hash_float3_to_float, 4: CH.hash_float4_to_float}[d](*c)
        return v[:, None]
    return _by_chunks(chunk, p, _param(params, WHITE_NOISE_DEFAULTS, "W"))


# --------------------------------------------------------------------------
# Wave Texture (wave.h)

_BANDS_AXIS = {"X": 0, "Y": 1, "Z": 2}
_RINGS_DROP = {"X": 0, "Y": 1, "Z": 2, "SPHERICAL": None}


def _wave_chunk(q, kind, bands, rings, profile, dist, detail, dscale, drough, phase):
    """(n, 1) float32 ``svm_wave`` at q (n, 3) float32, already times Scale."""
    q = (q + F32(0.000001)) * F32(0.999999)    # off the unit coordinates, as Cycles
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    if kind == "BANDS":
        if bands == "DIAGONAL":
            n = (x + y + z) * F32(10.0)
        else:
            n = q[:, _BANDS_AXIS[bands]] * F32(20.0)
    else:
        rp = q.copy()
        drop = _RINGS_DROP[rings]
        if drop is not None:
            rp[:, drop] *= F32(0.0)             # rp *= (0, 1, 1) etc.
        r2 = rp[:, 0] * rp[:, 0] + rp[:, 1] * rp[:, 1] + rp[:, 2] * rp[:, 2]
        n = np.sqrt(r2) * F32(20.0)
    n = n + F32(phase)
    if dist != 0.0:
        pd = [c * F32(dscale) for c in (x, y, z)]
        fbm = fractal("FBM", pd, detail, drough, 2.0, normalize=True)
        n = n + F32(dist) * (fbm * F32(2.0) - F32(1.0))
    if profile == "SIN":
        f = F32(0.5) + F32(0.5) * np.sin(n - F32(np.pi / 2))
    elif profile == "SAW":
        n = n / F32(2.0 * np.pi)
        f = n - np.floor(n)
    else:                                       # TRI
        n = n / F32(2.0 * np.pi)
        f = np.abs(n - np.floor(n + F32(0.5))) * F32(2.0)
    return f[:, None]


def wave_texture(output: str, params: dict, p: np.ndarray) -> np.ndarray:
    """(N, 3) float64 Cycles' Wave Texture (``svm_node_tex_wave``) output
    'Color' or 'Factor' (both the same grey) at p (N, 3) float64."""
    def get(key):
        return _param(params, WAVE_DEFAULTS, key)
    scale = F32(get("Scale"))
    args = (get("wave_type"), get("bands_direction"), get("rings_direction"),
            get("wave_profile"), float(F32(get("Distortion"))), float(get("Detail")),
            float(get("Detail Scale")), float(get("Detail Roughness")),
            float(get("Phase Offset")))

    def chunk(q, w):
        return _wave_chunk(q * scale, *args)
    return _by_chunks(chunk, p, 0.0)
