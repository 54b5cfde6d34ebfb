"""Mitsuba's upgrade of scene files older than format 2.0, done before the files are merged.

Mitsuba upgrades each object by the version of the file it was read from
(``transform_upgrade`` in ``src/core/parser.cpp``). Once included files are merged into one
text there is a single version left, so the upgrade is applied here, per object, and the
merged text carries a version that needs none: property names camelCase -> snake_case,
``diffuse.diffuse_reflectance`` -> ``reflectance``, ``uoffset``/``voffset``/``uscale``/
``vscale`` -> a ``to_uv`` transform. That is all Mitsuba 3 does; what else 3.9.1 lacks of
0.5/0.6 is upgraded (or refused) by legacy.py.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from sensaov_cli.scene.changes import Change, Refusals
from sensaov_cli.scene.legacy import upgrade_object
from sensaov_cli.scene.source import is_object, new_element, source_file

_UV_NAMES = ("uoffset", "voffset", "uscale", "vscale")


def upgrade_legacy(
    root: ET.Element, legacy_files: set[str], changes: list[Change], refusals: Refusals
) -> None:
    """Upgrade every object read from one of ``legacy_files`` (paths as read): Mitsuba's own
    renaming, then what 3.9.1 lacks of 0.5/0.6 (legacy.py), listed in ``changes``."""
    if not legacy_files:
        return
    for element in list(root.iter()):
        if is_object(element) and source_file(element) in legacy_files:
            _upgrade(element)
            upgrade_object(element, changes, refusals)


def snake_case(name: str) -> str:
    """Mitsuba's camel_to_underscore_case, character for character."""
    out: list[str] = []
    i = 0
    while i < len(name):
        if i > 0 and name[i - 1].islower() and name[i].isupper():
            out.append("_" + name[i].lower())
            while i + 1 < len(name) and name[i + 1].isupper():
                i += 1
                out.append(name[i].lower())
        else:
            out.append(name[i])
        i += 1
    return "".join(out)


def _upgrade(element: ET.Element) -> None:
    # A child's name is a property of this object, so this object's file version decides.
    for child in element:
        if child.get("name"):
            child.set("name", snake_case(child.get("name", "")))
    if element.tag == "bsdf" and element.get("type") == "diffuse":
        for child in element:
            if child.get("name") == "diffuse_reflectance":
                child.set("name", "reflectance")
    _uv_transform(element)


def _uv_transform(element: ET.Element) -> None:
    found = {c.get("name"): c for c in element if c.get("name") in _UV_NAMES}
    if not found:
        return
    for child in found.values():
        element.remove(child)
    first = next(iter(found.values()))
    values = {name: child.get("value", "") for name, child in found.items()}
    transform = new_element("transform", {"name": "to_uv"}, like=first)
    # Mitsuba builds scale(s) * translate(o): the translation applies first, as written here.
    offset = {axis: values[n] for axis, n in (("x", "uoffset"), ("y", "voffset")) if n in values}
    scale = {axis: values[n] for axis, n in (("x", "uscale"), ("y", "vscale")) if n in values}
    transform.append(new_element("translate", offset, like=first))
    transform.append(new_element("scale", scale, like=first))
    element.append(transform)
