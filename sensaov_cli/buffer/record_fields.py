"""The checks a buffer's records run on their fields, on every read (8,000 records in a large
scene): plain lists and tuples of plain strings and integers, what JSON and code give, take a
fast path; messages are built only when a check fails."""

from __future__ import annotations

import json
import operator
from collections.abc import Iterable
from typing import Any

from sensaov_cli.errors import BufferContentError

_SEQUENCES = (list, tuple)


def require(ok: bool, message: str) -> None:
    if not ok:
        raise BufferContentError(message)


def str_tuple(items: Any, what: str) -> tuple[str, ...]:
    if type(items) in _SEQUENCES and all(type(s) is str for s in items):
        return tuple(items)
    if isinstance(items, Iterable) and not isinstance(items, str):
        items = tuple(items)
        if all(isinstance(s, str) for s in items):
            return items
        raise BufferContentError(f"{what} must hold strings only")
    raise BufferContentError(f"{what} must be a sequence of strings, got {items!r}")


def shape_tuple(items: Any, what: str) -> tuple[int, ...]:
    if type(items) in _SEQUENCES and all(type(d) is int and d >= 0 for d in items):
        return tuple(items)
    dims: tuple[int, ...] = ()
    try:
        dims = tuple(operator.index(d) for d in items if not isinstance(d, bool))
        ok = len(dims) == len(items) and all(d >= 0 for d in dims)
    except TypeError:
        ok = False
    if not ok:
        raise BufferContentError(
            f"{what} must be a sequence of non-negative integers, got {items!r}"
        )
    return dims


def json_copy(data: Any, what: str) -> Any:
    """A deep copy through JSON, so the record saves and loads back equal (tuples become lists)."""
    try:
        return json.loads(json.dumps(data, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise BufferContentError(f"{what} is not JSON-able: {exc}") from exc
