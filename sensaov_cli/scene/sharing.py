"""Objects used in several places, written once per use so each use has its own parameters.

Both passes run on the expanded scene (all ``<alias>``es already resolved into ids).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import Counter

from sensaov_cli.scene.naming import fresh_id
from sensaov_cli.scene.source import detached_copy


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
