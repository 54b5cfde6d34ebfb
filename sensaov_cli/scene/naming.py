"""Names for the objects a scene leaves unnamed, what the scene says about its objects, and
objects used in several places written once per use, so each use has its own parameters.

Mitsuba keys an object without an id by its memory address (``object_<pointer>``), new on
every run, so every unnamed object gets an id before loading, from what the scene says about
it so that people recognise it (``blob`` for ``meshes/blob.ply``, ``Mesh262_Walls`` for a
numbered mesh using ``Walls``, ``white_rectangle``, ``pot_group_2``, ``point_light``). A name
already taken gets a suffix (``_1``, ``_2``, …), so it never clashes with an id the user
wrote. Names depend only on the scene text, so two loads of one scene agree. The copies per
use run on the expanded scene (all ``<alias>``es already resolved into ids).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import PurePath

from sensaov_cli.scene.source import detached_copy, is_object

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
        instance = element.tag == "shape" and element.get("type") == "instance"
        group = (_group_of(element, ids) or "instance") if instance else None
        if group is not None:
            position[group] = position.get(group, -1) + 1
        if element.get("id") or _take_emitter_id(element, referenced):
            continue
        base = f"{group}_{position[group]}" if group is not None else _base_name(element, ids)
        # Parameter keys are dotted paths that start with the id: keep ids to one clean token.
        element.set("id", fresh_id(re.sub(r"[^A-Za-z0-9_]", "_", base) or "object", taken))
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


def _group_of(shape: ET.Element, ids: dict[str, ET.Element]) -> str:
    """The id of the shapegroup an instance instantiates ("" for any other shape)."""
    groups = refs_to(shape, "shape", ids) if shape.get("type") == "instance" else []
    return groups[0].get("id", "") if groups else ""


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
    shapes = root.iter("shape")
    return {s.get("id", ""): group for s in shapes if s.get("id") and (group := _group_of(s, ids))}


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


# --- objects used in several places: one copy per use ---


def place_textures(root: ET.Element, copies: bool) -> dict[str, tuple[str, ...]]:
    """Write each top-level texture used through ``<ref>`` where it is used.

    With ``copies`` every use gets its own copy; otherwise the texture moves into its first
    use, keeping its id, and the other uses keep referring to it. Returns texture id ->
    ``object.slot`` of each use, as written in the scene.
    """
    top = {t.get("id", ""): t for t in root.findall("texture") if t.get("id")}
    parents = {child: parent for parent in root.iter() for child in parent}
    uses: dict[str, list[ET.Element]] = {}
    for ref in root.iter("ref"):
        if ref.get("id") in top:
            uses.setdefault(ref.get("id", ""), []).append(ref)
    placed: dict[str, tuple[str, ...]] = {}
    for texture_id in _inner_first(root, top, uses, parents):
        refs, texture = uses[texture_id], top[texture_id]
        placed[texture_id] = tuple(_slot_path(ref, parents) for ref in refs)
        root.remove(texture)
        for ref in refs if copies else refs[:1]:
            replace_ref(parents[ref], ref, detached_copy(texture) if copies else texture)
    return placed


def _inner_first(
    root: ET.Element,
    top: dict[str, ET.Element],
    uses: dict[str, list[ET.Element]],
    parents: dict[ET.Element, ET.Element],
) -> list[str]:
    """Used textures, each after the top-level textures it refs: a texture is then copied
    with the textures it uses already in place, and no ref is left behind in a copy."""
    needs: dict[str, list[str]] = {texture_id: [] for texture_id in uses}
    for texture_id, refs in uses.items():
        for ref in refs:
            outer = ref
            while parents[outer] is not root:
                outer = parents[outer]
            if outer.tag == "texture" and outer.get("id") in needs:
                needs[outer.get("id", "")].append(texture_id)
    order: list[str] = []

    def visit(texture_id: str, path: tuple[str, ...]) -> None:
        if texture_id in order or texture_id in path:  # a cycle is Mitsuba's error to report
            return
        for inner in needs[texture_id]:
            visit(inner, (*path, texture_id))
        order.append(texture_id)

    for texture_id in needs:
        visit(texture_id, ())
    return order


def _slot_path(ref: ET.Element, parents: dict[ET.Element, ET.Element]) -> str:
    """``object.slot`` for a use: the nearest named ancestor, then the slot names below it."""
    names = [ref.get("name") or ref.tag]
    node = parents[ref]
    while not node.get("id") and node in parents:
        names.append(node.get("name") or node.tag)
        node = parents[node]
    return ".".join([node.get("id") or node.tag, *reversed(names)])


def replace_ref(parent: ET.Element, ref: ET.Element, element: ET.Element) -> None:
    """Put ``element`` where ``ref`` was, filling the slot the ref named."""
    element.attrib.pop("name", None)
    if ref.get("name"):
        element.set("name", ref.get("name", ""))
    parent.insert(list(parent).index(ref), element)
    parent.remove(ref)


def split_shared_bsdfs(root: ET.Element) -> dict[str, tuple[str, ...]]:
    """Copy each top-level BSDF used by several shapes into each of them; returns BSDF id ->
    the shapes that received a copy. The original stays while anything else still refs it."""
    bsdfs = {el.get("id", ""): el for el in root.findall("bsdf")}
    referenced = Counter(ref.get("id") for ref in root.iter("ref"))
    uses: dict[str, list[tuple[ET.Element, ET.Element]]] = {}
    for shape in root.iter("shape"):
        for ref in shape.findall("ref"):
            if ref.get("id") in bsdfs and ref.get("name") in (None, "bsdf"):
                uses.setdefault(ref.get("id", ""), []).append((shape, ref))
    split: dict[str, tuple[str, ...]] = {}
    for bsdf_id, pairs in uses.items():
        if len(pairs) < 2:
            continue
        for shape, ref in pairs:
            replace_ref(shape, ref, detached_copy(bsdfs[bsdf_id]))
        split[bsdf_id] = tuple(shape.get("id", "") for shape, _ in pairs)
        if referenced[bsdf_id] == len(pairs):
            root.remove(bsdfs[bsdf_id])
    return split


def split_shapegroups(root: ET.Element) -> dict[str, tuple[str, ...]]:
    """Give each instance of a shapegroup used by several instances a copy of its own (``g_i``
    for group ``g`` and instance ``i``): instances share their shapegroup's parameters, so each
    would get the whole group's gradient. A group with an object inside it that something
    outside refs is left shared (a copy could not keep that ref). Returns group id -> the
    instances that received a copy."""
    shapes = root.findall("shape")
    groups = {g.get("id", ""): g for g in shapes if g.get("type") == "shapegroup" and g.get("id")}
    uses: dict[str, list[tuple[ET.Element, ET.Element]]] = {}
    for instance in shapes:
        for ref in instance.findall("ref") if instance.get("type") == "instance" else ():
            if ref.get("id") in groups and instance.get("id"):
                uses.setdefault(ref.get("id", ""), []).append((instance, ref))
    taken = {el.get("id", "") for el in root.iter() if el.get("id") and el.tag != "ref"}
    split: dict[str, tuple[str, ...]] = {}
    for group_id, pairs in uses.items():
        group = groups[group_id]
        if len(pairs) < 2 or _refd_from_outside(root, group):
            continue
        position = list(root).index(group)
        for offset, (instance, ref) in enumerate(pairs):
            copy = _group_copy(group, instance.get("id", ""), taken)
            root.insert(position + offset, copy)
            ref.set("id", copy.get("id", ""))
        root.remove(group)
        split[group_id] = tuple(instance.get("id", "") for instance, _ in pairs)
    return split


def _refd_from_outside(root: ET.Element, group: ET.Element) -> bool:
    inner = {el.get("id") for el in group.iter() if el is not group and el.get("id")}
    inside = set(group.iter())
    return any(ref.get("id") in inner for ref in root.iter("ref") if ref not in inside)


def _group_copy(group: ET.Element, suffix: str, taken: set[str]) -> ET.Element:
    copy = detached_copy(group)
    copy.set("id", fresh_id(f"{group.get('id')}_{suffix}", taken))
    for member, copied in zip(group, copy, strict=True):
        if member.tag == "shape" and member.get("id"):
            copied.set("id", fresh_id(f"{member.get('id')}_{suffix}", taken))
    return copy
