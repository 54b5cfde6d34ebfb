"""The field types of a job file: strict scalars, fixed-length lists, checked paths.

Shared by the dataclasses of :mod:`.spec`; no pydantic here (the markers of
:mod:`.markers` speak to pydantic when it asks). Types are strict where YAML makes mistakes
easy: ``"64"`` is not an integer and ``true`` is not a number, but ``40`` is accepted where a
float is expected. Our own checks raise :class:`Problem`, which carries the key path below the
failing value (``at``) and a hint; :mod:`.load` reads them back.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from annotated_types import Ge, Gt, Le, Lt, MinLen

from sensaov_cli.job.markers import After, Before, Doc, JobPath, Json, Setting
from sensaov_cli.job.problems import Problem, describe

NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_]{0,31}$"
FUNCTION_PATTERN = r"^[A-Za-z_][A-Za-z0-9_.]*:[A-Za-z_][A-Za-z0-9_]*$"
SCENE_ARG_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*$"
PATTERN_MEANINGS = {
    NAME_PATTERN: "a name of 1 to 32 letters, digits or _, starting with a letter",
    FUNCTION_PATTERN: "'module:function', e.g. 'mymodule:objective'",
    SCENE_ARG_PATTERN: "a scene argument name (letters, digits, _), as in $name",
}


def unique_names(what: str, key: str) -> After:
    """Refuse a list of named items where a name comes twice."""

    def check(items: tuple[Any, ...]) -> tuple[Any, ...]:
        first: dict[str, int] = {}
        for index, item in enumerate(items):
            if item.name in first:
                raise Problem(
                    f"{what} name {item.name!r} is already used by {key}[{first[item.name]}]",
                    at=(index, "name"),
                    hint="names must be unique",
                )
            first[item.name] = index
        return items

    return After(check)


def _existing_file(path: Path, job_dir: Path) -> None:
    if not path.exists():
        raise Problem(f"file not found: {path}", hint=_relative_hint(job_dir))
    if not path.is_file():
        raise Problem(f"not a file: {path}", hint=_relative_hint(job_dir))


def _existing_dir(path: Path, job_dir: Path) -> None:
    if not path.exists():
        raise Problem(f"directory not found: {path}", hint=_relative_hint(job_dir))
    if not path.is_dir():
        raise Problem(f"not a directory: {path}", hint=_relative_hint(job_dir))


def _output_dir(path: Path, job_dir: Path) -> None:
    if path.exists() and not path.is_dir():
        raise Problem(f"exists and is not a directory: {path}", hint="output names a directory")


def _relative_hint(job_dir: Path) -> str:
    return f"relative paths start at the job file's directory, {job_dir}"


def _count(n: int, what: str) -> Before:
    """Check a list's length first, so a short list is one clear error, not one per item."""

    def check(value: Any) -> Any:
        if not isinstance(value, list) or len(value) != n:
            raise Problem(f"must be a list of {n} {what}, got {_size(value)}")
        return value

    return Before(check)


def _size(value: Any) -> str:
    return f"{len(value)} items" if isinstance(value, list) else describe(value)


def _one_or_many(value: Any) -> Any:
    return [value] if isinstance(value, str) else value


def _only_true(value: Any) -> Any:
    if value is not True:
        raise Problem(f"must be true, got {describe(value)}", hint="leave the key out instead")
    return value


def _ordered_region(region: tuple[float, float, float, float]) -> tuple[float, ...]:
    x0, y0, x1, y1 = region
    if not x0 < x1:
        raise Problem(f"x0 ({x0}) must be less than x1 ({x1})", hint="region is [x0, y0, x1, y1]")
    if not y0 < y1:
        raise Problem(f"y0 ({y0}) must be less than y1 ({y1})", hint="region is [x0, y0, x1, y1]")
    return region


def _not_zero(value: int) -> int:
    if value == 0:
        raise Problem("must be -1 (unbounded) or at least 1, got 0")
    return value


STRICT = Setting(strict=True)
Text = Annotated[str, STRICT, MinLen(1)]
Name = Annotated[str, STRICT, Setting(pattern=NAME_PATTERN)]
Function = Annotated[str, STRICT, Setting(pattern=FUNCTION_PATTERN)]
Number = Annotated[float, STRICT, Setting(allow_inf_nan=False)]
Unit = Annotated[float, STRICT, Ge(0.0), Le(1.0)]
Pixels = Annotated[int, STRICT, Ge(1), Le(16384)]
Fov = Annotated[float, STRICT, Gt(0.0), Lt(180.0), Doc("Field of view, degrees.")]
VisSpp = Annotated[int, STRICT, Ge(1), Lt(2**32), Doc("Samples per pixel of the pass (32-bit).")]
Resolution = Annotated[tuple[Pixels, Pixels], _count(2, "integers [width, height]")]
Vector = Annotated[tuple[Number, Number, Number], _count(3, "numbers [x, y, z]")]
Region = Annotated[
    tuple[Unit, Unit, Unit, Unit],
    _count(4, "numbers [x0, y0, x1, y1]"),
    After(_ordered_region),
]
JobFile = Annotated[Path, JobPath(_existing_file)]
# The directory put on sys.path for a python objective; null = the job file's own.
JobDir = Annotated[Path | None, JobPath(_existing_dir, null_means=".")]
OutputDir = Annotated[Path, JobPath(_output_dir, null_means="out/{stem}")]
Globs = Annotated[
    tuple[Text, ...],
    Before(_one_or_many),
    Json(
        {"anyOf": [{"type": "string"}, {"type": "array", "items": {"type": "string"}}]},
        replace=True,
    ),
]
MaxDepth = Annotated[int, STRICT, Ge(-1), After(_not_zero), Json({"not": {"const": 0}})]
TrueFlag = Annotated[bool, Before(_only_true), Json({"const": True})]


def _scene_arg_text(value: Any) -> Any:
    """A scene argument as the text Mitsuba substitutes: ``str()`` of it, as load_file does."""
    if isinstance(value, str | int | float) and not (isinstance(value, float) and value != value):
        return str(value)
    raise Problem(f"must be a string, a number or true/false, got {describe(value)}")


# A scene's $name arguments, as mitsuba.load_file takes them: each value is passed as text.
SceneArgs = Annotated[
    dict[
        Annotated[str, STRICT, Setting(pattern=SCENE_ARG_PATTERN)],
        Annotated[str, Before(_scene_arg_text), Json({"type": ["string", "number", "boolean"]})],
    ],
    Doc("Values for the scene's $name arguments, like mitsuba.load_file's keywords."),
]
