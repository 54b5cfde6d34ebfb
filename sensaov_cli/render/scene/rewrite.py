"""What sensaov changes in an expanded scene so that Mitsuba differentiates it (pure XML).

- every integrator is replaced by ``prb`` (``prbvolpath`` for a ``volpath`` scene, so media
  stay in the image) with the job's ``max_depth`` and the scene's ``hide_emitters`` and
  ``rr_depth`` (``path`` costs memory that grows with spp under AD; ``prb`` is
  constant-memory, MITSUBA-NOTES); an integrator that renders other light transport
  (``direct``, ``aov``, …) is reported, since the objective then sees another image;
- bitmap textures, nested ones too, load as float (``format = variant``) so their texels
  receive gradients (8-bit textures load as non-differentiable integers by default); envmaps
  load their images as float already and take no ``format``.

The lookup settings of every bitmap (filter, wrap) are read here too, for texel fields: the
plugin's Python binding does not expose them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from sensaov_cli.render.scene.naming import child_value

DEFAULT_FILTER, DEFAULT_WRAP = "bilinear", "repeat"
# The user's integrator -> the path-replay one that differentiates the same light transport:
# volumetric path tracers keep their media (prb ignores them), everything else becomes prb.
_REPLAY_OF = {"volpath": "prbvolpath", "volpathmis": "prbvolpath", "prbvolpath": "prbvolpath"}
# What sensaov replaces without changing the image the objective sees (max_depth is the job's).
_SAME_TRANSPORT = frozenset({"path", "prb", "prb_basic", "direct_projective", *_REPLAY_OF})
# Integrator settings that change the image and that prb and prbvolpath take as they are.
_KEPT_SETTINGS = ("hide_emitters", "rr_depth")


def replace_integrator(root: ET.Element, max_depth: int) -> tuple[str, str]:
    """Put the replay integrator in place of the scene's: (the scene's type, the replay's)."""
    found = root.findall("integrator")
    user = found[0] if found else None
    kind = user.get("type", "path") if user is not None else "path"
    for element in found:
        root.remove(element)
    replay = _REPLAY_OF.get(kind, "prb")
    integrator = ET.Element("integrator", {"type": replay})
    ET.SubElement(integrator, "integer", {"name": "max_depth", "value": str(max_depth)})
    for setting in user.iter() if user is not None else ():
        if setting is not user and setting.get("name") in _KEPT_SETTINGS:
            ET.SubElement(integrator, setting.tag, dict(setting.attrib))
    root.insert(0, integrator)
    return kind, replay


def renders_other_transport(kind: str) -> bool:
    """Whether the scene's integrator renders another image than the replay integrator."""
    return kind not in _SAME_TRANSPORT


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
