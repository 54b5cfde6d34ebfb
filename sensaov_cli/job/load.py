"""Read a job file into a :class:`~.job.JobSpec`, or say where it is wrong; its JSON Schema.

:func:`load_job` reads the file (``yaml.safe_load`` semantics, see :mod:`.yaml_source`),
validates it straight into the dataclasses of :mod:`.job` (pydantic reads their fields, see
:mod:`.shapes`), and returns the :class:`JobSpec` with every path resolved against the job
file's directory. Anything wrong raises one :class:`~sensaov_cli.errors.SpecError` located as
``<job>:<line>: <key path>``: the first problem in the file, by line. :func:`job_schema` is the
JSON Schema of the format.

The format is documented in ``docs/job-spec.md``.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from functools import cache
from pathlib import Path
from typing import Any

from pydantic import TypeAdapter, ValidationError
from pydantic.json_schema import GenerateJsonSchema
from pydantic_core import ErrorDetails

from sensaov_cli.errors import SpecError
from sensaov_cli.job.fields import PATTERN_MEANINGS
from sensaov_cli.job.problems import Problem, close_match, describe
from sensaov_cli.job.shapes import UNION
from sensaov_cli.job.spec import JobSpec
from sensaov_cli.job.yaml_source import KeyPath, YamlDocument, read_yaml, spec_error

SUPPORTED_VERSIONS = (1,)


def load_job(path: Path) -> JobSpec:
    """Read, validate and resolve the job file at ``path``; raise SpecError if it is wrong."""
    shown = str(path)
    job_path = Path(os.path.abspath(path))
    document = read_yaml(job_path, shown)
    _check_top_level(document, shown)
    try:
        # The job file's own path: JobSpec.path, and where its relative paths start.
        return _adapter().validate_python(document.data, context={"job": job_path})
    except ValidationError as exc:
        raise _first_error(exc, document, shown) from None


def job_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of the YAML job format, for editors and validators."""
    schema = _adapter().json_schema(schema_generator=_JobFileSchema)
    title = f"sensaov job (format version {SUPPORTED_VERSIONS[-1]})"
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema, "title": title}


@cache
def _adapter() -> TypeAdapter[JobSpec]:
    return TypeAdapter(JobSpec)


@cache
def _union_tags() -> frozenset[str]:
    """The tags of the unions' members: they stand in error locations but are no keys."""
    return frozenset(_tags_in(_adapter().core_schema))


def _tags_in(schema: Any) -> set[str]:
    if isinstance(schema, dict):
        found = set(schema["choices"]) if schema.get("type") == "tagged-union" else set()
        return found.union(*(_tags_in(value) for value in schema.values()))
    if isinstance(schema, list | tuple):
        return set().union(*(_tags_in(item) for item in schema))
    return set()


class _JobFileSchema(GenerateJsonSchema):
    """Fields untitled, every definition titled by its name, defaults as a job file writes them."""

    def generate(self, schema: Any, mode: Any = "validation") -> dict[str, Any]:
        json_schema = super().generate(schema, mode)
        # A section has its class's title already; a shape (MeanLuminanceObjective) has none.
        for name, definition in json_schema.get("$defs", {}).items():
            definition.setdefault("title", name)
        return json_schema

    def field_title_should_be_set(self, schema: Any) -> bool:
        # pydantic's per-field titles ("Spp") repeat the key and say nothing.
        return False

    def encode_default(self, dft: Any) -> Any:
        return super().encode_default(_as_written(dft))


def _as_written(value: Any) -> Any:
    """A default as a job file would write it: a spec object by the keys it changes ({})."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {
            field.name: _as_written(getattr(value, field.name))
            for field in dataclasses.fields(value)
            if getattr(value, field.name) != field.default
        }
    if isinstance(value, tuple):
        return [_as_written(item) for item in value]
    return value


def _check_top_level(document: YamlDocument, shown: str) -> None:
    """The checks that must come before the rest: a mapping, of a version we know."""
    data = document.data
    if data is None:
        raise spec_error(shown, None, (), "the job file is empty", "start with 'version: 1'")
    if not isinstance(data, dict):
        message = f"the job file must be a mapping of keys, not {describe(data)}"
        hint = "start with 'version: 1', then 'scene:', 'objectives:'"
        raise spec_error(shown, document.line_of(()), (), message, hint)
    _check_version(document, shown)


def _check_version(document: YamlDocument, shown: str) -> None:
    # Checked before everything else: the version decides what the other keys mean.
    supported = ", ".join(map(str, SUPPORTED_VERSIONS))
    where = (shown, document.line_of(("version",)), ("version",))
    if "version" not in document.data:
        hint = f"add 'version: 1' as the first line; supported versions: {supported}"
        raise spec_error(*where, "missing required key", hint)
    version = document.data["version"]
    if type(version) is not int:
        message = f"must be an integer, got {describe(version)}"
        raise spec_error(*where, message, "write 'version: 1'")
    if version not in SUPPORTED_VERSIONS:
        message = f"unsupported job format version {describe(version)}"
        raise spec_error(*where, message, f"this sensaov reads versions: {supported}")


def _first_error(exc: ValidationError, document: YamlDocument, shown: str) -> SpecError:
    """The problem written earliest in the file, worded for a person who edits YAML."""
    located = []
    for error in exc.errors():
        path, message, hint = _explain(error)
        located.append((document.line_of(path), path, message, hint))
    # min() keeps the first of equals, so pydantic's order settles ties on one line.
    line, path, message, hint = min(
        located, key=lambda item: math.inf if item[0] is None else item[0]
    )
    return spec_error(shown, line, path, message, hint)


def _explain(error: ErrorDetails) -> tuple[KeyPath, str, str | None]:
    """(key path, message, hint) for one pydantic error."""
    # "[key]" is pydantic's marker for a mapping's key (scene_args); the key itself precedes it.
    path: KeyPath = tuple(
        part for part in error["loc"] if part not in _union_tags() and part != "[key]"
    )
    kind, ctx, value = error["type"], error.get("ctx", {}), error["input"]
    if kind == "value_error" and isinstance(ctx.get("error"), Problem):
        problem: Problem = ctx["error"]
        return path + problem.at, problem.message, problem.hint
    if kind == UNION:
        return _explain_union(path, ctx, value)
    if kind == "missing":
        return path, "missing required key", None
    if kind == "literal_error":
        choices = re.findall(r"'([^']*)'", ctx["expected"])
        return (
            path,
            f"must be one of {', '.join(choices)}; got {describe(value)}",
            _typo(value, choices),
        )
    if kind == "dict_type":
        return path, f"must be a mapping, got {describe(value)}", None
    return path, _reword(error), _quoted_number_hint(kind, value)


def _explain_union(
    path: KeyPath, ctx: dict[str, Any], value: Any
) -> tuple[KeyPath, str, str | None]:
    """Why no member of a tagged union fits: not a mapping, or a missing or unknown tag."""
    field, choices = ctx["field"], tuple(ctx["choices"].split(","))
    if not isinstance(value, dict):
        return path, f"must be {ctx['expects']}, got {describe(value)}", None
    if not field:
        return path, ctx["message"], None
    if field not in value:
        # A misspelt tag key ("typ:") is the likelier story than a forgotten one.
        for key in value:
            if close_match(key, (field,)) is not None:
                return path + (key,), f"unknown key {describe(key)}", f"did you mean '{field}'?"
        return path + (field,), f"missing required key (one of: {', '.join(choices)})", None
    message = f"must be one of {', '.join(choices)}; got {describe(value[field])}"
    return path + (field,), message, _typo(value[field], choices)


def _typo(value: Any, choices: list[str] | tuple[str, ...]) -> str | None:
    close = close_match(value, choices) if isinstance(value, str) else None
    return None if close is None else f"did you mean '{close}'?"


def _reword(error: ErrorDetails) -> str:
    """pydantic's "Input should be a valid integer" as "must be an integer, got 'many'"."""
    kind, ctx, value = error["type"], error.get("ctx", {}), error["input"]
    if kind == "string_pattern_mismatch":
        meaning = PATTERN_MEANINGS.get(ctx["pattern"], f"match {ctx['pattern']}")
        return f"must be {meaning}; got {describe(value)}"
    if kind == "string_too_short" and ctx["min_length"] == 1:
        return "must not be empty"
    if kind in ("too_short", "too_long"):
        bound = "at least" if kind == "too_short" else "at most"
        limit = ctx.get("min_length", ctx.get("max_length"))
        unit = "character" if isinstance(value, str) else "item"
        plural = "" if limit == 1 else "s"
        return f"must have {bound} {limit} {unit}{plural}, got {ctx['actual_length']}"
    if kind == "tuple_type":
        # The dataclasses hold a job file's lists as tuples; YAML has only lists.
        return f"must be a list, got {describe(value)}"
    message = error["msg"].replace("Input should be", "must be")
    message = re.sub(r"\ba valid (?=[aeiou])", "an ", message).replace("a valid ", "a ")
    return f"{message}, got {describe(value)}"


def _quoted_number_hint(kind: str, value: Any) -> str | None:
    if kind in ("int_type", "float_type") and isinstance(value, str):
        try:
            float(value)
        except ValueError:
            return None
        return "write the number without quotes"
    return None
