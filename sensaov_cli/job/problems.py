"""What a job file gets wrong, in our words: :class:`Problem` and the helpers its messages use.

Plain Python: the field types (:mod:`.fields`), the markers and their schemas
(:mod:`.markers`) and the loader (:mod:`.load`) all raise or word problems with these, and
none of them is imported back.
"""

from __future__ import annotations

import difflib
from typing import Any


class Problem(ValueError):
    """A mistake in a job file, in our own words; ``at`` extends the key path of the value.

    ``at`` holds YAML keys, which may be any scalar, and list indices. pydantic reports a
    ValueError raised while validating as a ``value_error`` that carries it, so raising one
    needs no pydantic.
    """

    def __init__(self, message: str, *, at: tuple[Any, ...] = (), hint: str | None = None):
        super().__init__(message)
        self.message, self.at, self.hint = message, at, hint


def describe(value: Any) -> str:
    """A short YAML-flavoured rendering of a user's value for an error message."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return repr(value if len(value) <= 40 else value[:37] + "...")
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    return f"a {type(value).__name__}"


def close_match(word: object, choices: list[str] | tuple[str, ...]) -> str | None:
    """The choice ``word`` was most likely a typo of, if any."""
    close = difflib.get_close_matches(str(word), choices, n=1, cutoff=0.6)
    return close[0] if close else None


def did_you_mean(word: object, choices: list[str] | tuple[str, ...], what: str) -> str:
    """'did you mean X?' when a choice is close to ``word``, else the list of valid choices."""
    close = close_match(word, choices)
    if close is not None:
        return f"did you mean '{close}'?"
    return f"valid {what}: " + ", ".join(choices)
