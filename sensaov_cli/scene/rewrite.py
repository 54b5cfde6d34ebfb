"""What sensaov changes in an expanded scene's bitmaps so that Mitsuba differentiates them.

(The integrator is replaced in integrator.py, unnamed objects named in naming.py.)

- bitmap textures, nested ones too, load as float (``format = variant``) so their texels
  receive gradients (8-bit textures load as non-differentiable integers by default); envmaps
  load their images as float already and take no ``format``.

The lookup settings of every bitmap (filter, wrap) are read here too, for texel fields: the
plugin's Python binding does not expose them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from sensaov_cli.scene.naming import child_value

DEFAULT_FILTER, DEFAULT_WRAP = "bilinear", "repeat"


def bitmaps_as_float(root: ET.Element) -> tuple[str, ...]:
    """Load every bitmap texture as float; returns every bitmap's file name, as written."""
    files = []
    for texture in root.iter("texture"):
        if texture.get("type") != "bitmap":
            continue
        filename = child_value(texture, "filename")
        if filename is not None:
            files.append(filename)
        if child_value(texture, "format") is None:
            ET.SubElement(texture, "string", {"name": "format", "value": "variant"})
    return tuple(files)


def bitmap_options(root: ET.Element) -> dict[str, tuple[str, str, str]]:
    """File base name -> (filter_type, wrap_mode, note) of every bitmap in the scene.

    Matched to a loaded texture by its file's base name (the name the plugin prints); where one
    file is used with two different settings the first is taken and a note says so.
    """
    options: dict[str, tuple[str, str, str]] = {}
    for texture in root.iter("texture"):
        filename = child_value(texture, "filename")
        if texture.get("type") != "bitmap" or filename is None:
            continue
        found = (
            child_value(texture, "filter_type") or DEFAULT_FILTER,
            child_value(texture, "wrap_mode") or DEFAULT_WRAP,
        )
        name = Path(filename).name
        if name in options and options[name][:2] != found:
            first = options[name]
            note = f"{name} is used with several filter/wrap settings; the first is shown"
            options[name] = (first[0], first[1], note)
        else:
            options.setdefault(name, (*found, ""))
    return options
