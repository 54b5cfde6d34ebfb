"""Names for the objects a scene leaves unnamed, and what the scene says about its objects.

Mitsuba keys an object without an id by its memory address (``object_<pointer>``), new on
every run, so every unnamed object gets an id before loading, from what the scene says about
it so that people recognise it (``blob`` for ``meshes/blob.ply``, ``Mesh262_Walls`` for a
numbered mesh using ``Walls``, ``white_rectangle``, ``pot_group_2``, ``point_light``). A name
already taken gets a suffix (``_1``, ``_2``, …), so it never clashes with an id the user
wrote. Names depend only on the scene text, so two loads of one scene agree.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import PurePath

from sensaov_cli.scene.source import is_object

_NAMED_TAGS = ("shape", "emitter", "bsdf", "texture", "sensor", "medium", "volume")
_MESH_TYPES = ("obj", "ply", "serialized")
_MATERIAL_SUFFIX = re.compile(r"[_-](mat|mtl|material|bsdf)$", re.IGNORECASE)
# Mesh file stems that say nothing about the object (exporters number them: Bitterli's
# interiors ship models/Mesh000.obj ... Mesh294.obj): the material's id is added to them.
_GENERIC_STEM = re.compile(
    r"(mesh|object|obj|shape|geometry|geom|model|part|node|poly|polysurface|surface|untitled"
    r"|group|default|primitive|prim|submesh|piece)?[\W_]*\d*",
    re.IGNORECASE,
)


def child_value(element: ET.Element, name: str) -> str | None:
    """The ``value`` of the property child called ``name``."""
    found = next((c for c in element if c.get("name") == name and c.tag != "ref"), None)
    return None if found is None else found.get("value")


def objects_by_id(root: ET.Element) -> dict[str, ET.Element]:
    return {el.get("id", ""): el for el in root.iter() if el.get("id") and is_object(el)}


def refs_to(element: ET.Element, tag: str, ids: dict[str, ET.Element]) -> list[ET.Element]:
    """The objects of kind ``tag`` that ``element`` uses directly, inline or by ``<ref>``."""
    targets = (ids.get(c.get("id", "")) if c.tag == "ref" else c for c in element)
    return [target for target in targets if target is not None and target.tag == tag]


def name_objects(root: ET.Element) -> dict[str, ET.Element]:
    """Give every unnamed top-level object and shapegroup member an id (document order);
    returns each id given and its element."""
    named: dict[str, ET.Element] = {}
    ids = objects_by_id(root)
    referenced = {ref.get("id") for ref in root.iter("ref")}
    taken = set(ids)
    position: dict[str, int] = {}  # instances counted per shapegroup, named ones too
    for element in _nameable(root):
        group = _instanced_group(element, ids)
        if group is not None:
            position[group] = position.get(group, -1) + 1
        if element.get("id") or _take_emitter_id(element, referenced):
            continue
        base = f"{group}_{position[group]}" if group is not None else _base_name(element, ids)
        element.set("id", fresh_id(_sanitize(base), taken))
        named[element.get("id", "")] = element
    return named


def _nameable(root: ET.Element) -> list[ET.Element]:
    found = []
    for element in root:
        if element.tag in _NAMED_TAGS:
            found.append(element)
        if element.tag == "shape" and element.get("type") == "shapegroup":
            found.extend(member for member in element if member.tag == "shape")
    return found


def _instanced_group(element: ET.Element, ids: dict[str, ET.Element]) -> str | None:
    if element.tag != "shape" or element.get("type") != "instance":
        return None
    return next((g.get("id", "") for g in refs_to(element, "shape", ids)), "") or "instance"


def _take_emitter_id(shape: ET.Element, referenced: set[str | None]) -> bool:
    """A shape whose area emitter the user named takes that name: the shape is the object
    sensaov reports (the emitter's parameters are keyed under it)."""
    emitter = next((e for e in shape if e.tag == "emitter"), None) if shape.tag == "shape" else None
    if emitter is None or not emitter.get("id") or emitter.get("id") in referenced:
        return False
    shape.set("id", emitter.attrib.pop("id"))
    return True


def _base_name(element: ET.Element, ids: dict[str, ET.Element]) -> str:
    kind = element.get("type", element.tag)
    if element.tag == "emitter":
        return f"{kind}_light"
    if element.tag != "shape":
        return f"{kind}_{element.tag}"
    filename = child_value(element, "filename")
    bsdfs = refs_to(element, "bsdf", ids)
    bsdf_id = bsdfs[0].get("id", "") if bsdfs else ""
    # "floor_mat" -> "floor": the material word adds nothing to an object's name.
    material = _MATERIAL_SUFFIX.sub("", bsdf_id) or bsdf_id
    if kind in _MESH_TYPES and filename:
        stem = PurePath(filename).stem
        index = child_value(element, "shape_index")
        stem = f"{stem}_{index}" if kind == "serialized" and index else stem
        if _GENERIC_STEM.fullmatch(stem) and material:
            return f"{stem}_{material}"  # Mesh262_Walls
        return stem
    if any(child.tag == "emitter" for child in element):  # an area light is written inline
        return f"{kind}_light"
    return f"{material}_{kind}" if material else kind


def _sanitize(name: str) -> str:
    # Parameter keys are dotted paths that start with the id: keep ids to one clean token.
    return re.sub(r"[^A-Za-z0-9_]", "_", name) or "object"


def fresh_id(base: str, taken: set[str]) -> str:
    """``base``, or ``base_1``, ``base_2``, … : the first not in ``taken``, which now holds it."""
    name, counter = base, 0
    while name in taken:
        counter += 1
        name = f"{base}_{counter}"
    taken.add(name)
    return name


def shapegroups(root: ET.Element) -> dict[str, tuple[str, ...]]:
    """Shapegroup id -> the ids of its member shapes."""
    return {
        group.get("id", ""): tuple(m.get("id", "") for m in group if m.tag == "shape")
        for group in root.iter("shape")
        if group.get("type") == "shapegroup" and group.get("id")
    }


def instances(root: ET.Element) -> dict[str, str]:
    """Instance id -> the id of the shapegroup it instantiates."""
    ids = objects_by_id(root)
    found = {}
    for shape in root.iter("shape"):
        groups = refs_to(shape, "shape", ids) if shape.get("type") == "instance" else []
        if shape.get("id") and groups and groups[0].get("id"):
            found[shape.get("id", "")] = groups[0].get("id", "")
    return found


def materials(root: ET.Element) -> dict[str, str]:
    """Shape id -> the BSDF id the user named (Mitsuba's implicit BSDF: ``default``).

    An instance has the materials of its shapegroup's members, distinct ones joined with
    ``+`` in member order: the instance shows all of them, and no single one is its material.
    """
    ids = objects_by_id(root)
    found: dict[str, str] = {}
    for shape in root.iter("shape"):
        if shape.get("type") not in ("instance", "shapegroup"):
            bsdfs = refs_to(shape, "bsdf", ids)
            unnamed = f"{shape.get('id', 'shape')}_bsdf"  # an inline BSDF without an id
            found[shape.get("id", "")] = (bsdfs[0].get("id") or unnamed) if bsdfs else "default"
    for instance, group in instances(root).items():
        members = [found.get(m.get("id", ""), "default") for m in ids[group] if m.tag == "shape"]
        found[instance] = "+".join(dict.fromkeys(members)) or "default"
    return found
