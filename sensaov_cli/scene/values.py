"""Numbers a scene writes, checked finite before Mitsuba reads them (pure XML).

Mitsuba reads ``nan`` and ``inf`` (and ``1e39``, infinite as float32) wherever a number goes,
and loads the scene; the run then fails at the first objective, blaming the objective. So every
number of a value element (``<float>``, ``<rgb>``, ``<spectrum>``, ``<point>``, ``<vector>``
and the transforms) is checked here, and the first that is not a finite float32 is refused at
its file and line, with the property it belongs to.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

from sensaov_cli.errors import SceneError
from sensaov_cli.scene.source import user_attributes, where

_VALUE_TAGS = frozenset(
    "float rgb spectrum point vector translate scale rotate matrix lookat".split()
)
_NOT_NUMBERS = frozenset({"name", "id", "type", "filename"})
_SEPARATORS = re.compile(r"[\s,:]+")
FLOAT32_MAX = 3.4028234663852886e38


def refuse_non_finite(root: ET.Element) -> None:
    """Raise :class:`SceneError` at the first value element holding NaN or an infinity."""
    for element in root.iter():
        if element.tag not in _VALUE_TAGS:
            continue
        for attribute, text in user_attributes(element):
            if attribute in _NOT_NUMBERS:
                continue
            bad = next((t for t in _SEPARATORS.split(text) if _not_finite(t)), None)
            if bad is not None:
                name = element.get("name")
                what = f'<{element.tag} name="{name}">' if name else f"<{element.tag}>"
                raise SceneError(
                    f"{what} {attribute}={bad!r} is not a finite number",
                    where=where(element),
                    hint="Mitsuba would load it and render NaN: write a finite float32, "
                    "at most 3.4e38",
                )


def _not_finite(token: str) -> bool:
    try:
        value = float(token)
    except ValueError:
        return False  # not a number at all: Mitsuba says so itself
    return not math.isfinite(value) or abs(value) > FLOAT32_MAX
