"""Cryptomatte: the ID mattes of Blender's Cryptomatte passes (View Layer >
Passes > Cryptomatte: Object, Material, Asset, Levels), as Cycles writes
them, so that the compositor's Cryptomatte node and other readers pick the
same objects from an FPPM render.

An ID is a name's 32-bit MurmurHash3 (seed 0) read as a float32 whose
exponent is kept off 0 and 255 (Cycles util/murmurhash.cpp
``util_hash_to_float``): the object's name, its material's
("default_surface" without one), and the name of the object at the top of
its parent chain (the asset; an instance's own chain, not the instancer's).

A camera ray, while it is still on its line (no vertex yet, or only
straight crossings of Transparent BSDFs: Cycles' transparent background
path), adds at every surface it hits

    w = mean(beta) (1 - mean(T))            (kernel/film/data_passes.h)

to the slot of that surface's ID in its pixel, beta its throughput and T
the surface's Transparent lobes there (``core.lights.shadow.pass_through``;
the hits are ``core.sppm.line_hits`` records).
A holdout surface where the ray ends adds nothing.  A pixel keeps 2 x
ceil(Levels / 2) (id, weight) slots a kind (kernel/film/
cryptomatte_passes.h ``film_write_cryptomatte_slots``): an ID takes the
first free slot, or adds to its own; once every slot is taken, the
weights of other IDs go to the last one.  The weights are means over the
passes, sorted by weight (a stable insertion sort, ``film_sort_cryptomatte_
slots``), and pass k of a kind holds slots 2k, 2k + 1 as (id, weight, id,
weight): "CryptoObject00", "CryptoObject01", ...

FPPM's camera chains cross a Transparent lobe by a random choice (its
throughput divided by the choice's probability): the weights behind a
transparent surface have Cycles' expectation.  The manifest (name -> hash)
of each kind goes into the render result's metadata as Cycles writes it
(``cryptomatte/<7 hex digits of the layer name's hash>/name, hash,
conversion, manifest``).
"""
from __future__ import annotations

import json
import re
from typing import Optional

import numpy as np

#: The kinds, in Scene.tri_crypto's column order and Cycles' pass order.
KINDS = ("Object", "Material", "Asset")
#: An empty slot's ID (Cycles' ID_NONE); no name hashes to it.
ID_NONE = np.float32(0.0)
#: The name of a triangle without a material (Cycles' default surface shader).
DEFAULT_MATERIAL = "default_surface"
#: Blender's view-layer property turning each kind on.
FLAGS = {k: f"use_pass_cryptomatte_{k.lower()}" for k in KINDS}
_PASS = re.compile(r"^Crypto(Object|Material|Asset)(\d\d)$")


def murmur3_32(data: bytes, seed: int = 0) -> int:
    """MurmurHash3 x86 32-bit of ``data`` (Austin Appleby's reference, as
    Cycles' ``util_murmur_hash3`` and Blender's ``BLI_hash_mm3``)."""
    c1, c2, m = 0xCC9E2D51, 0x1B873593, 0xFFFFFFFF
    h = seed & m
    n = len(data) // 4
    for i in range(n + 1):
        if i < n:
            k = int.from_bytes(data[4 * i:4 * i + 4], "little")
        else:
            tail = data[4 * n:]
            if not tail:
                break
            k = int.from_bytes(tail, "little")
        k = (k * c1) & m
        k = ((k << 15) | (k >> 17)) & m
        k = (k * c2) & m
        h ^= k
        if i < n:
            h = ((h << 13) | (h >> 19)) & m
            h = (h * 5 + 0xE6546B64) & m
    h ^= len(data)
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & m
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & m
    return h ^ (h >> 16)


def hash_to_float(h: int) -> np.float32:
    """Cycles' ``util_hash_to_float``: the hash's bits as a float32 whose
    exponent is clamped to 1 .. 254 (never 0, inf or NaN)."""
    exponent = min(max((h >> 23) & 0xFF, 1), 254)
    bits = (h & 0x80000000) | (exponent << 23) | (h & 0x7FFFFF)
    return np.array([bits], np.uint32).view(np.float32)[0]


def name_id(name: str) -> np.float32:
    """The ID of a name (its UTF-8 bytes hashed)."""
    return hash_to_float(murmur3_32(name.encode("utf-8")))


def asset_name(ob) -> str:
    """The name of the object at the top of ``ob``'s parent chain (ob's own
    without a parent): Cycles' asset of the object."""
    while getattr(ob, "parent", None) is not None:
        ob = ob.parent
    return ob.name


def pass_names(view_layer) -> list[str]:
    """Blender's pass names of the kinds the view layer turns on: ceil(Levels
    / 2) passes a kind (Cycles' ``list_render_passes``)."""
    if view_layer is None:
        return []
    n = (int(getattr(view_layer, "pass_cryptomatte_depth", 6)) + 1) // 2
    return [f"Crypto{k}{i:02d}" for k in KINDS if getattr(view_layer, FLAGS[k], False)
            for i in range(n)]


def is_pass(name: str) -> bool:
    """Whether ``name`` is a Cryptomatte pass ("CryptoAsset02", ...)."""
    return _PASS.match(name) is not None


def metadata(prefix: str, manifests: dict) -> dict[str, str]:
    """The render result's metadata of each kind in ``manifests`` ({kind:
    names}): ``cryptomatte/<id>/name`` = prefix + "Crypto" + kind (prefix:
    the view layer's name and a dot, as Blender names the passes in a
    multilayer file), hash, conversion and the manifest {name: hex hash}."""
    out = {}
    for kind, names in manifests.items():
        layer = f"{prefix}Crypto{kind}"
        key = f"cryptomatte/{murmur3_32(layer.encode('utf-8')):08x}"[:len("cryptomatte/") + 7]
        out[f"{key}/name"] = layer
        out[f"{key}/hash"] = "MurmurHash3_32"
        out[f"{key}/conversion"] = "uint32_to_float32"
        out[f"{key}/manifest"] = json.dumps(
            {n: f"{murmur3_32(n.encode('utf-8')):08x}" for n in sorted(names)},
            separators=(",", ":"), ensure_ascii=False)
    return out


def scene_metadata(scene, passes, prefix: str) -> dict[str, str]:
    """``metadata`` of the kinds among ``passes`` with the scene's names
    (``Scene.crypto_names``; {} without)."""
    names = getattr(scene, "crypto_names", None) or {}
    kinds = {m.group(1) for m in map(_PASS.match, passes) if m}
    return metadata(prefix, {k: v for k, v in names.items() if k in kinds})


def add_to_slots(ids: np.ndarray, weights: np.ndarray, px: np.ndarray, id_: np.ndarray,
                 w: np.ndarray) -> None:
    """Cycles' ``film_write_cryptomatte_slots`` for hits in distinct pixels
    px (n,): ids (P, S) float32 and weights (P, S) float64 in place; id_
    (n,) float32, w (n,) float64 (a weight 0 adds nothing)."""
    keep = w != 0
    px, id_, w = px[keep], id_[keep], w[keep]
    if px.size == 0:
        return
    S = ids[px]
    free = S == ID_NONE
    take = free | (S == id_[:, None])
    take[:, -1] = True                      # no slot left: the last one
    j = np.argmax(take, axis=1)
    claim = free[np.arange(px.size), j]
    ids[px[claim], j[claim]] = id_[claim]
    weights[px, j] += w


def sorted_slots(ids: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The slots of each pixel by decreasing weight, ties in slot order
    (``film_sort_cryptomatte_slots``; empty slots, of weight 0, last)."""
    order = np.argsort(-weights, axis=1, kind="stable")
    return np.take_along_axis(ids, order, 1), np.take_along_axis(weights, order, 1)


class Mattes:
    """The Cryptomatte sums of a film of P pixels: for each kind on, ids
    (P, S) float32 and weights (P, S) float64 summed over the passes.
    passes: the names of the render's passes ("CryptoObject00", ...; S = 2 x
    the passes of the kind).  tri_ids: (T, 3) float32 each triangle's IDs
    (``Scene.tri_crypto``, columns KINDS)."""

    def __init__(self, passes, P: int, tri_ids: np.ndarray):
        counts = {}
        for name in passes:
            m = _PASS.match(name)
            if m:
                counts[m.group(1)] = max(counts.get(m.group(1), 0), int(m.group(2)) + 1)
        self.kinds = tuple(k for k in KINDS if k in counts)
        self.slots = {k: 2 * counts[k] for k in self.kinds}
        self.tri_ids = tri_ids
        self.ids = {k: np.zeros((P, self.slots[k]), np.float32) for k in self.kinds}
        self.weights = {k: np.zeros((P, self.slots[k])) for k in self.kinds}

    @classmethod
    def of_passes(cls, passes, P: int, scene) -> Optional["Mattes"]:
        """The film's Mattes, or None when no Cryptomatte pass is asked for
        or the scene has no IDs (``Scene.tri_crypto``)."""
        tri = getattr(scene, "tri_crypto", None)
        if tri is None or not any(_PASS.match(n) for n in passes):
            return None
        return cls(passes, P, tri)

    def add(self, records: list) -> None:
        """Add one pass's ``core.sppm.line_hits`` records, each pixel's in the
        order its ray met them (the records of one wavefront are in distinct
        pixels): each surface's w = mean(beta) (1 - mean(T))."""
        for r in records:
            h = np.nonzero(r.hit)[0]
            prim, w = r.prim[h], r.beta[h].mean(axis=1) * (1.0 - r.through[h])
            for c, k in enumerate(KINDS):
                if k in self.ids:
                    add_to_slots(self.ids[k], self.weights[k], r.px[h], self.tri_ids[prim, c], w)

    def passes(self, samples: int) -> dict[str, np.ndarray]:
        """{"Crypto<Kind>NN": (P, 4) float32 (id, weight, id, weight)}: the
        slots sorted, weights the means over ``samples`` passes."""
        out = {}
        for k in self.kinds:
            ids, w = sorted_slots(self.ids[k], self.weights[k] / max(samples, 1))
            for i in range(self.slots[k] // 2):
                out[f"Crypto{k}{i:02d}"] = np.stack(
                    [ids[:, 2 * i], w[:, 2 * i], ids[:, 2 * i + 1], w[:, 2 * i + 1]],
                    axis=1).astype(np.float32)
        return out

    def state_dict(self) -> dict:
        d = {f"crypto_ids_{k}": v.copy() for k, v in self.ids.items()}
        d.update({f"crypto_weights_{k}": v.copy() for k, v in self.weights.items()})
        return d

    def load_state(self, d: dict) -> None:
        for k in self.kinds:
            if f"crypto_ids_{k}" in d and d[f"crypto_ids_{k}"].shape == self.ids[k].shape:
                self.ids[k][...] = d[f"crypto_ids_{k}"]
                self.weights[k][...] = d[f"crypto_weights_{k}"]
