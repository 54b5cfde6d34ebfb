"""The field types of a job file: strict scalars, fixed-length lists, checked paths.

Shared by the models of :mod:`sensaov_cli.spec.schema_model`. Types are strict where YAML makes
mistakes easy: ``"64"`` is not an integer and ``true`` is not a number, but ``40`` is accepted
where a float is expected. Our own checks raise :func:`problem`, which carries the key path
below the failing value (``at``) and a hint; :mod:`sensaov_cli.spec.job` reads them back. The
helpers at the end build the tagged unions (objective types, camera kinds, channel kinds) and
check that names are unique.
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BeforeValidator,
    Discriminator,
    Field,
    ValidationInfo,
    WithJsonSchema,
)
from pydantic_core import PydanticCustomError

NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_]{0,31}$"
FUNCTION_PATTERN = r"^[A-Za-z_][A-Za-z0-9_.]*:[A-Za-z_][A-Za-z0-9_]*$"
PATTERN_MEANINGS = {
    NAME_PATTERN: "a name of 1 to 32 letters, digits or _, starting with a letter",
    FUNCTION_PATTERN: "'module:function', e.g. 'mymodule:objective'",
}
PROBLEM = "sensaov_problem"
UNION = "sensaov_union"


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


def problem(message: str, *, at: tuple[Any, ...] = (), hint: str | None = None) -> Exception:
    """A validation failure with our own wording; ``at`` extends the key path of the value.

    ``at`` holds YAML keys, which may be any scalar, and list indices.
    """
    # The text travels in the context rather than the template so that braces in user input
    # are never taken for placeholders.
    return PydanticCustomError(PROBLEM, "{message}", {"message": message, "at": at, "hint": hint})


def _base_dir(info: ValidationInfo) -> Path:
    context = info.context or {}
    return Path(context.get("base_dir", "."))


def _existing_file(value: str, info: ValidationInfo) -> str:
    path = Path(os.path.abspath(_base_dir(info) / value))
    if not path.exists():
        raise problem(f"file not found: {path}", hint=_relative_hint(info))
    if not path.is_file():
        raise problem(f"not a file: {path}", hint=_relative_hint(info))
    return value


def _existing_dir(value: str, info: ValidationInfo) -> str:
    path = Path(os.path.abspath(_base_dir(info) / value))
    if not path.exists():
        raise problem(f"directory not found: {path}", hint=_relative_hint(info))
    if not path.is_dir():
        raise problem(f"not a directory: {path}", hint=_relative_hint(info))
    return value


def _output_dir(value: str, info: ValidationInfo) -> str:
    path = Path(os.path.abspath(_base_dir(info) / value))
    if path.exists() and not path.is_dir():
        raise problem(f"exists and is not a directory: {path}", hint="output names a directory")
    return value


def _relative_hint(info: ValidationInfo) -> str:
    return f"relative paths start at the job file's directory, {_base_dir(info)}"


def _count(n: int, what: str) -> BeforeValidator:
    """Check a list's length first, so a short list is one clear error, not one per item."""

    def check(value: Any) -> Any:
        if not isinstance(value, list) or len(value) != n:
            raise problem(f"must be a list of {n} {what}, got {_size(value)}")
        return value

    return BeforeValidator(check)


def _size(value: Any) -> str:
    return f"{len(value)} items" if isinstance(value, list) else describe(value)


def _one_or_many(value: Any) -> Any:
    return [value] if isinstance(value, str) else value


def _only_true(value: Any) -> Any:
    if value is not True:
        raise problem(f"must be true, got {describe(value)}", hint="leave the key out instead")
    return value


def _ordered_region(region: tuple[float, float, float, float]) -> tuple[float, ...]:
    x0, y0, x1, y1 = region
    if not x0 < x1:
        raise problem(f"x0 ({x0}) must be less than x1 ({x1})", hint="region is [x0, y0, x1, y1]")
    if not y0 < y1:
        raise problem(f"y0 ({y0}) must be less than y1 ({y1})", hint="region is [x0, y0, x1, y1]")
    return region


def _not_zero(value: int) -> int:
    if value == 0:
        raise problem("must be -1 (unbounded) or at least 1, got 0")
    return value


Picker = Callable[[Any], str | None]


def tagged_union(
    pick: Picker,
    expects: str,
    field: str | None = None,
    choices: tuple[str, ...] = (),
    message: str = "",
) -> Discriminator:
    """A tagged union whose member ``pick`` chooses; tags read "key: value".

    Such tags ("type: python") are never valid keys, so :mod:`sensaov_cli.spec.job` can drop them
    from error locations; a value that picks no member gives a UNION error that it explains from the
    context: not a mapping (``expects``), ``field`` missing or not one of ``choices``, or
    ``message``.
    """
    # pydantic takes only scalars here, hence the joined choices.
    context: dict[str, int | str | float] = {
        "field": field or "",
        "choices": ",".join(choices),
        "expects": expects,
        "message": message,
    }
    return Discriminator(
        pick, custom_error_type=UNION, custom_error_message=expects, custom_error_context=context
    )


def by_field(field: str, choices: tuple[str, ...]) -> Picker:
    """Pick by the value of ``field`` ("type: python"); None if absent or not a choice."""

    def pick(value: Any) -> str | None:
        tag = value.get(field) if isinstance(value, dict) else None
        return f"{field}: {tag}" if isinstance(tag, str) and tag in choices else None

    return pick


def unique_names(what: str, key: str) -> AfterValidator:
    def check(items: list[Any]) -> list[Any]:
        first: dict[str, int] = {}
        for index, item in enumerate(items):
            if item.name in first:
                raise problem(
                    f"{what} name {item.name!r} is already used by {key}[{first[item.name]}]",
                    at=(index, "name"),
                    hint="names must be unique",
                )
            first[item.name] = index
        return items

    return AfterValidator(check)


Text = Annotated[str, Field(strict=True, min_length=1)]
Name = Annotated[str, Field(strict=True, pattern=NAME_PATTERN)]
Number = Annotated[float, Field(strict=True, allow_inf_nan=False)]
Unit = Annotated[float, Field(strict=True, ge=0.0, le=1.0)]
Pixels = Annotated[int, Field(strict=True, ge=1, le=16384)]
Fov = Annotated[float, Field(strict=True, gt=0.0, lt=180.0, description="Field of view, degrees.")]
VisSpp = Annotated[int, Field(strict=True, ge=1, description="Samples per pixel of the pass.")]
Resolution = Annotated[tuple[Pixels, Pixels], _count(2, "integers [width, height]")]
Vector = Annotated[tuple[Number, Number, Number], _count(3, "numbers [x, y, z]")]
Region = Annotated[
    tuple[Unit, Unit, Unit, Unit],
    _count(4, "numbers [x0, y0, x1, y1]"),
    AfterValidator(_ordered_region),
]
FilePath = Annotated[Text, AfterValidator(_existing_file)]
DirPath = Annotated[Text, AfterValidator(_existing_dir)]
OutputPath = Annotated[Text, AfterValidator(_output_dir)]
Globs = Annotated[
    list[Text],
    BeforeValidator(_one_or_many),
    WithJsonSchema({"anyOf": [{"type": "string"}, {"type": "array", "items": {"type": "string"}}]}),
]
MaxDepth = Annotated[
    int,
    Field(strict=True, ge=-1, json_schema_extra={"not": {"const": 0}}),
    AfterValidator(_not_zero),
]
TrueFlag = Annotated[Literal[True], BeforeValidator(_only_true)]
