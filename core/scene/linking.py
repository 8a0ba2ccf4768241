"""Light linking: which emitters light which objects (Cycles' receiver sets).

Blender (Object > Light Linking > Receiver Collection) lets an emitter (a
light, or an object whose material emits) light only some objects.  Its
depsgraph gives every object a *receiver set*, an index 0..63 (0: the
objects no linking names), and every emitter a 64-bit *membership* mask of
the sets it lights (all ones: no linking).  Cycles' rule
(``light_link_object_match``): emitter E lights a point of object O iff bit
``receiver_set(O)`` of ``membership(E)`` is set.  It is tested where light
arrives at a surface from an emitter along one segment: a light sample
(next-event estimation) at O, a BSDF ray from O that hits E (the receiver is
the vertex the ray left: ``light_link_receiver_forward``), and never for
camera rays (an emitter seen directly, or through Transparent BSDFs, is
always seen).  Light that O passes on (its reflection) is not tested
again, so in a light path E -> y1 -> y2 ... the rule is only E's with y1.

FPPM keeps the receiver set per material: the exporter gives each
(material, receiver set, emitter membership) of the scene its own material
(:func:`split_materials`), so every stage that knows a vertex's material
row knows its receiver set (``receivers``), and an emissive triangle's
membership is its material's.  Lights carry ``Light.link_sets``.
"""
from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np

#: The membership of an emitter without linking: every receiver set.
LINK_ALL = (1 << 64) - 1


def split_materials(scene, tri_receiver: Optional[np.ndarray],
                    tri_emitter: Optional[np.ndarray]):
    """The scene with one material per (material, receiver set, emitter
    membership) its triangles use: tri_receiver (T,) int receiver set and
    tri_emitter (T,) uint64 membership of each triangle's object (None: 0
    and LINK_ALL).  Sets ``material_receiver`` (M',) uint8 and
    ``material_emitter`` (M',) uint64; the scene itself when no object is
    linked (both None).  Material copies keep their index order (the first
    copy of material m keeps index m); a copy's ray variants
    (core.scene.ray_variants) are copied with it, with its sets."""
    T = scene.tri_mat.shape[0]
    rcv = (np.zeros(T, np.uint64) if tri_receiver is None
           else np.asarray(tri_receiver, np.uint64))
    emt = (np.full(T, LINK_ALL, np.uint64) if tri_emitter is None
           else np.asarray(tri_emitter, np.uint64))
    if not rcv.any() and bool(np.all(emt == np.uint64(LINK_ALL))):
        return scene
    M = len(scene.materials)
    mats = list(scene.materials)
    receiver = [0] * M
    emitter = [LINK_ALL] * M
    base = list(range(M))
    pass_index = (None if scene.material_pass_index is None
                  else list(np.asarray(scene.material_pass_index)))

    def copy(m):
        base.append(base[m])
        mats.append(mats[m])
        receiver.append(0)
        emitter.append(LINK_ALL)
        if pass_index is not None:
            pass_index.append(pass_index[m])
        return len(mats) - 1
    key = np.stack([np.asarray(scene.tri_mat, np.uint64), rcv, emt], axis=1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    new_index = np.empty(uniq.shape[0], np.int64)
    taken = set()
    for i, (m, r, e) in enumerate(uniq.tolist()):
        if m not in taken:
            taken.add(m)
            new_index[i] = m
        else:
            new_index[i] = copy(m)
        receiver[new_index[i]] = int(r)
        emitter[new_index[i]] = int(e)
    # A material's ray variants are materials of no triangle: each copy of
    # the material gets a copy of them, with its sets.
    variants = {}
    for kind in ("camera", "shadow"):
        v0 = getattr(scene, "material_" + kind, None)
        if v0 is None:
            continue
        v0 = np.asarray(v0, np.int64)
        v = list(range(len(mats)))
        for j in range(len(mats)):
            b = base[j]
            if v0[b] != b:
                w = int(v0[b]) if j == b else copy(int(v0[b]))
                v[j] = w
                receiver[w], emitter[w] = receiver[j], emitter[j]
        variants[kind] = v
    for kind, v in variants.items():
        v += list(range(len(v), len(mats)))     # the copies made: themselves
        variants[kind] = np.asarray(v, np.int32)
    tri_mat = new_index[inv.reshape(-1)].astype(np.int32)
    return dataclasses.replace(
        scene, materials=mats, tri_mat=tri_mat,
        material_pass_index=None if pass_index is None else np.asarray(pass_index, np.int32),
        material_receiver=np.asarray(receiver, np.uint8),
        material_emitter=np.asarray(emitter, np.uint64),
        **{"material_" + k: v for k, v in variants.items()})


def linked(sets: np.ndarray, receiver: np.ndarray) -> np.ndarray:
    """(K,) bool: the emitters of membership sets (K,) uint64 light the
    receiver sets receiver (K,) int (Cycles' ``light_link_object_match``);
    a receiver < 0 (a camera ray) is lit by every emitter."""
    r = np.asarray(receiver, np.int64)
    bit = np.uint64(1) << np.clip(r, 0, 63).astype(np.uint64)
    return ((np.asarray(sets, np.uint64) & bit) != 0) | (r < 0)


def emitter_sets(scene, table) -> Optional[np.ndarray]:
    """(Nl,) uint64 the membership of each row of the LightTable ``table``
    built from ``scene`` (its Blender lights' ``link_sets``, its emissive
    triangles' materials' ``material_emitter``, the world's every set), or
    None when every emitter lights every set."""
    emt = getattr(scene, "material_emitter", None)
    tri = (None if emt is None
           else np.asarray(emt, np.uint64)[np.asarray(scene.tri_mat, np.int64)])
    return row_masks(scene, table, "link_sets", tri)


def row_masks(scene, table, attr: str, tri_masks) -> Optional[np.ndarray]:
    """(Nl,) uint64 a 64-bit mask per row of the LightTable ``table`` built
    from ``scene``: each Blender light's ``attr``, each emissive triangle's
    tri_masks (T,) uint64 entry (None: LINK_ALL), the world's LINK_ALL; None
    when every row is LINK_ALL (light and shadow linking's memberships)."""
    from ..lights import MESH, WORLD
    sets = np.full(table.kind.shape[0], LINK_ALL, np.uint64)
    src = np.asarray(table.source, np.int64)
    for r in np.nonzero((table.kind != MESH) & (table.kind != WORLD) & (src >= 0))[0]:
        sets[r] = getattr(scene.lights[src[r]], attr, LINK_ALL)
    if tri_masks is not None:
        m = np.nonzero(table.kind == MESH)[0]
        sets[m] = np.asarray(tri_masks, np.uint64)[src[m]]
    return None if bool(np.all(sets == np.uint64(LINK_ALL))) else sets


def table_receivers(scene, mtab) -> Optional[np.ndarray]:
    """(rows,) int64 the receiver set of each row of the MaterialTable
    ``mtab`` built from ``scene``'s materials (a roughness map's level rows,
    core.materials.rough_maps, take their material's), or None without
    light linking."""
    rec = getattr(scene, "material_receiver", None)
    if rec is None and not scene_links(scene):
        return None
    M = len(scene.materials)
    out = np.zeros(mtab.kind.shape[0], np.int64)
    if rec is not None:
        out[:M] = np.asarray(rec, np.int64)[:M]
        first = getattr(mtab, "rough_first", None)
        if first is not None:
            from ..materials.rough_maps import ROUGH_LEVELS
            for m in np.nonzero(first[:M] >= 0)[0]:
                out[first[m]:first[m] + ROUGH_LEVELS] = out[m]
    return out


def active(light_table, mtab) -> bool:
    """Whether :func:`lit` tests anything (the renderer's tables have light
    linking): the stages keep a ray's receiver only then."""
    return (getattr(light_table, "link_sets", None) is not None
            and getattr(mtab, "receiver", None) is not None)


def lit(light_table, mtab, rows, mats) -> Optional[np.ndarray]:
    """(K,) bool whether the emitter rows (K,) (-1: none) light the
    material-table rows mats (K,) (-1: a camera ray, which every emitter
    lights), or None when every emitter lights everything (no linking).
    ``light_table.link_sets`` and ``mtab.receiver`` (Renderer setup)."""
    if not active(light_table, mtab):
        return None
    sets, rec = light_table.link_sets, mtab.receiver
    rows = np.asarray(rows, np.int64)
    mats = np.asarray(mats, np.int64)
    out = np.ones(rows.shape[0], bool)
    k = np.nonzero(rows >= 0)[0]
    if k.size:
        r = np.where(mats[k] >= 0, rec[np.maximum(mats[k], 0)], -1)
        out[k] = linked(sets[rows[k]], r)
    return out


def light_links(light_table, mtab, scene) -> Optional[tuple]:
    """(the emitter rows' memberships (Nl,) uint64, the receiver set of each
    of the scene's triangles (T,) int64) for :func:`unlit_first_hits`, or
    None without light linking."""
    sets = getattr(light_table, "link_sets", None)
    rec = getattr(mtab, "receiver", None)
    if sets is None or rec is None:
        return None
    return sets, rec[np.asarray(scene.tri_mat, np.int64)]


def unlit_first_hits(prim: np.ndarray, emitter: np.ndarray, sets: np.ndarray,
                     tri_receiver: np.ndarray) -> None:
    """Photons and light paths: prim (K,) the triangles their first segment
    hit (-1: none), emitter (K,) their emitter rows; the hits on objects
    the emitter does not light become misses (-1, in place): no light of
    that emitter arrives there, so none is deposited or scattered on."""
    h = np.nonzero(prim >= 0)[0]
    if h.size:
        off = ~linked(sets[emitter[h]], tri_receiver[prim[h]])
        prim[h[off]] = -1


def scene_links(scene) -> bool:
    """Whether the scene has light linking (receiver sets or memberships)."""
    return (getattr(scene, "material_receiver", None) is not None
            or any(getattr(lt, "link_sets", LINK_ALL) != LINK_ALL for lt in scene.lights))
