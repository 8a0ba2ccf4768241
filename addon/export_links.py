"""Light and shadow linking as Blender's depsgraph resolves them: sets and memberships.

An emitter (a light, or an object whose material emits) with a Receiver
Collection (Object > Light Linking) lights only part of the scene.  Blender
(``depsgraph_light_linking.cc``) gives each distinct receiver collection a
bit; every object the collections name gets a *light set*, the pair (the
collections that include it, those that exclude it; an object in a child
collection takes the child's Include / Exclude, and a later mention
overrides an earlier one); each distinct light set is a *receiver set* id
1..63, 0 being the objects no collection names.  An emitter's membership is
the sets whose include mask has its collection's bit (all sets when none
has), less those whose exclude mask has it.  core.scene.linking applies
Cycles' test to those numbers.  Shadow linking (a Blocker Collection) is
built by the same rules from the blocker collections: *blocker sets* and
*shadow memberships* (core.scene.shadow_linking).
"""
from __future__ import annotations

from ..core.scene.linking import LINK_ALL

#: Receiver collections and light sets Blender can tell apart (64 bits).
MAX_SETS = 64


#: The collection each kind of linking reads (Object > Light Linking).
LINK_COLLECTION = {"light": "receiver_collection", "shadow": "blocker_collection"}


def _linked_collection(ob, kind: str):
    ll = getattr(ob, "light_linking", None)
    return None if ll is None else getattr(ll, LINK_COLLECTION[kind], None)


def _each_object(collection, visit) -> None:
    """visit(link_state, object) for every object the collection names, in
    Blender's order: the child collections first (each with its own state,
    which its nested collections keep), then the collection's own objects."""
    def inner(state, coll):
        for child in coll.children:
            inner(state, child)
        for ob in coll.objects:
            visit(state, ob)
    for child, entry in zip(collection.children, collection.collection_children):
        inner(entry.light_linking.link_state, child)
    for ob, entry in zip(collection.objects, collection.collection_objects):
        visit(entry.light_linking.link_state, ob)


def light_link_sets(objects, kind: str = "light") -> tuple[dict, dict, list]:
    """(receiver set by object name (absent: 0), membership by emitter object
    name (absent: LINK_ALL), notes) of the (original) objects; kind
    'shadow': (blocker set, shadow membership, notes) instead."""
    bits, notes = {}, []
    emitters = {}
    what = f"{kind} linking"
    for ob in objects:
        coll = _linked_collection(ob, kind)
        if coll is None:
            continue
        key = coll.as_pointer()
        if key not in bits:
            if len(bits) == MAX_SETS:
                notes.append(f"{what}: more than {MAX_SETS} "
                             f"{'receiver' if kind == 'light' else 'blocker'} collections, "
                             f"'{coll.name}' ignored")
                continue
            bits[key] = (1 << len(bits), coll)
        emitters[ob.name] = bits[key][0]
    if not emitters:
        return {}, {}, notes
    sets: dict = {}                         # object name -> [include mask, exclude mask]
    for bit, coll in bits.values():
        def visit(state, ob, bit=bit):
            s = sets.setdefault(ob.name, [0, 0])
            if state == 'INCLUDE':
                s[0] |= bit
                s[1] &= ~bit
            else:
                s[1] |= bit
                s[0] &= ~bit
        _each_object(coll, visit)
    ids: dict = {}
    receiver = {}
    for name, s in sets.items():
        key = tuple(s)
        if key == (0, 0):
            continue
        if key not in ids:
            if len(ids) == MAX_SETS - 1:
                notes.append(f"{what}: more than {MAX_SETS - 1} sets, "
                             f"'{name}' taken as an unlinked object")
                continue
            ids[key] = len(ids) + 1
        receiver[name] = ids[key]
    membership = {}
    for name, bit in emitters.items():
        inc = exc = 0
        for (i_mask, e_mask), k in ids.items():
            if i_mask & bit:
                inc |= 1 << k
            if e_mask & bit:
                exc |= 1 << k
        membership[name] = (inc if inc else LINK_ALL) & ~exc & LINK_ALL
    return receiver, membership, notes
