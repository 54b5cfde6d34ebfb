"""Markers that need no help from :mod:`.shapes`: a field's description, whether it is a key
at all, which shapes of its class take it, and settings of its scalar's core schema.

Plain data (no pydantic), so :mod:`.shapes` reads them while the markers of :mod:`.markers`,
which call :mod:`.shapes`, are never imported back by it.
"""

from __future__ import annotations

from dataclasses import MISSING
from typing import Any


class Doc:
    """A field's description in the JSON Schema."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        return {**handler(schema), "description": self.text}


class Given:
    """Not a key of the job file: the loader gives the value, in its context as ``key``."""

    def __init__(self, key: str) -> None:
        self.key = key


class In:
    """The field is a key of these shapes of its class only (objective types, camera kinds).

    There it may be ``required``, or have a ``default`` and a ``doc`` of its own.
    """

    def __init__(
        self, *shapes: str, required: bool = False, default: Any = MISSING, doc: str | None = None
    ) -> None:
        self.shapes, self.required, self.default, self.doc = shapes, required, default, doc


class Setting:
    """Keys of pydantic's core schema of a scalar: ``strict``, ``pattern``, ``allow_inf_nan``."""

    def __init__(self, **settings: Any) -> None:
        self.settings = settings

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        return {**handler(source), **self.settings}
