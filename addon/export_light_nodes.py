"""A light's node tree (Light > Nodes): what Cycles multiplies its strength by.

Cycles evaluates a light's shader along each direction leaving it and
multiplies the light's strength by the Emission it returns.  FPPM reads the
trees Blender users make:

- an Emission node into the Light Output: its Color times its Strength;
- an IES Texture into the Emission's Strength (a fitting's photometric web,
  from a Text datablock or an .ies file): a per-direction factor, the
  profile (core/lights/ies.py) times the IES node's Strength.

Anything else (other nodes, a linked Color, an IES Texture's linked Vector
or Strength, an IES profile on a sun or area light) is left out with a note;
the light then keeps what was read.
"""
from __future__ import annotations

import os

import numpy as np

from ..core.lights.ies import IesError, parse_ies, scaled
from .export_read import _follow, _use_nodes


def _ies_text(node) -> tuple[str | None, str]:
    """(the IES node's text or None, where it comes from)."""
    if getattr(node, "mode", 'INTERNAL') == 'EXTERNAL':
        import bpy
        path = bpy.path.abspath(node.filepath) if node.filepath else ""
        if not path:
            return None, "no file"
        try:
            with open(path, "r", encoding="latin-1") as f:
                return f.read(), path
        except OSError as e:
            return None, f"{path}: {e.strerror or e}"
    txt = getattr(node, "ies", None)
    if txt is None:
        return None, "no Text datablock"
    return txt.as_string(), f"Text '{txt.name}'"


def light_nodes(ld, name: str, kind: str, notes: list):
    """(colour factor (3,) float64, IES profile or None) of light data ld.

    The factor multiplies the light's strength; the profile (point and spot
    lights only) multiplies it per direction.  Lights without nodes: (1, None).
    """
    one = np.ones(3)
    tree = getattr(ld, "node_tree", None)
    if tree is None:
        return one, None
    import bpy
    # Blender 5's Cycles reads a light's tree whatever its (deprecated)
    # use_nodes says (measured: the same image with it off).
    if bpy.app.version < (5, 0, 0) and not _use_nodes(ld):
        return one, None
    out = tree.get_output_node('CYCLES')       # the output Cycles reads
    if out is None:
        return one, None
    used = {out.name}
    em, _ = _follow(out.inputs["Surface"])
    if em is None:
        return one, None
    if em.type != 'EMISSION':
        notes.append(f"light '{name}': light nodes ignored ('{em.name}' into the output)")
        return one, None
    used.add(em.name)
    col, st = em.inputs["Color"], em.inputs["Strength"]
    factor = np.array(col.default_value, np.float64)[:3]
    if col.is_linked:
        notes.append(f"light '{name}': a linked Emission Color ignored (light nodes)")
        factor = one.copy()
    profile = None
    src, sock = _follow(st) if st.is_linked else (None, None)
    if src is None:
        factor = factor * float(st.default_value)
    elif src.type == 'TEX_IES':
        used.add(src.name)
        profile = _read_ies(src, name, kind, notes)
    else:
        notes.append(f"light '{name}': '{src.name}' into the Emission Strength ignored "
                     "(light nodes)")
    extra = [nd.name for nd in tree.nodes
             if nd.name not in used and nd.type not in ('OUTPUT_LIGHT', 'FRAME', 'REROUTE')
             and any(o.is_linked for o in nd.outputs)]
    if extra:
        notes.append(f"light '{name}': light nodes ignored ({', '.join(sorted(extra))})")
    return factor, profile


def _read_ies(node, name: str, kind: str, notes: list):
    """The IES node's profile (times its Strength), or None with a note."""
    if kind not in ('POINT', 'SPOT'):
        notes.append(f"light '{name}': an IES profile on a {kind.lower()} light ignored")
        return None
    for k in ("Vector", "Strength"):
        s = node.inputs.get(k)
        if s is not None and s.is_linked:
            notes.append(f"light '{name}': the IES Texture's linked {k} ignored")
    text, where = _ies_text(node)
    if text is None:
        notes.append(f"light '{name}': IES profile not read ({where}): light unshaped")
        return None
    try:
        prof = parse_ies(text)
    except IesError as e:
        notes.append(f"light '{name}': IES profile {os.path.basename(where)} not read ({e}): "
                     "light unshaped")
        return None
    return scaled(prof, float(node.inputs["Strength"].default_value))
