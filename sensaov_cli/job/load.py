"""The job file in YAML: read into a :class:`~.spec.JobSpec` (or where it is wrong), written back.

Anything wrong in a job file raises one :class:`~sensaov_cli.errors.SpecError` located as
``<job>:<line>: <key path>``: the first problem in the file, by line. The format is documented
in ``docs/job-spec.md``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import yaml
from pydantic import TypeAdapter, ValidationError
from pydantic.json_schema import GenerateJsonSchema, JsonSchemaValue
from pydantic_core import ErrorDetails

from sensaov_cli.errors import SpecError
from sensaov_cli.job.markers import UNION, UNION_MEMBERS, Problem, describe, did_you_mean
from sensaov_cli.job.spec import NAME_PATTERN, PATTERN_MEANINGS, CameraSpec, JobSpec
from sensaov_cli.limits import read_regular

SUPPORTED_VERSIONS = (1,)
MAX_JOB_BYTES = 16 << 20
KeyPath = tuple[Any, ...]
_MERGE_TAG = "tag:yaml.org,2002:merge"
_PLAIN_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# YAML 1.2's plain floats: PyYAML reads YAML 1.1, where an exponent needs a dot and a sign
# ("1e-3" would be the string '1e-3'); people write 1e-3, 1E3, +1e-3 and .5.
_FLOAT_12 = re.compile(r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?\Z")


class _JobLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader, reading plain numbers as YAML 1.2 does (integers as before)."""


# A copy: add_implicit_resolver would otherwise change every SafeLoader of the process.
_JobLoader.yaml_implicit_resolvers = {
    first: list(resolvers) for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_JobLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))


def _safe_load(text: str) -> Any:
    """``yaml.safe_load`` with YAML 1.2's numbers, as every job file is read."""
    return yaml.load(text, Loader=_JobLoader)  # noqa: S506 -- a SafeLoader subclass


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
        explained = [_explain(error) for error in exc.errors()]
        # min() keeps the first of equals, so pydantic's order settles ties on one line.
        keys, message, hint = min(explained, key=lambda each: document.line_of(each[0]) or math.inf)
        raise spec_error(shown, document.line_of(keys), keys, message, hint) from None


def job_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of the YAML job format, for editors and validators."""
    schema = _adapter().json_schema(schema_generator=_JobFileSchema)
    title = f"sensaov job (format version {SUPPORTED_VERSIONS[-1]})"
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema, "title": title}


@cache
def _adapter() -> TypeAdapter[JobSpec]:
    return TypeAdapter(JobSpec)


class _JobFileSchema(GenerateJsonSchema):
    """Fields untitled, every definition titled by its name, defaults as a job file writes them."""

    def generate(self, schema: Any, mode: Any = "validation") -> JsonSchemaValue:
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
    """The checks that come before the rest: a mapping, of a version we know (the version
    decides what the other keys mean)."""
    data = document.data
    if data is None:
        raise spec_error(shown, None, (), "the job file is empty", "start with 'version: 1'")
    if not isinstance(data, dict):
        message = f"the job file must be a mapping of keys, not {describe(data)}"
        hint = "start with 'version: 1', then 'scene:', 'objectives:'"
        raise spec_error(shown, document.line_of(()), (), message, hint)
    supported = ", ".join(map(str, SUPPORTED_VERSIONS))
    where = (shown, document.line_of(("version",)), ("version",))
    if "version" not in data:
        hint = f"add 'version: 1' as the first line; supported versions: {supported}"
        raise spec_error(*where, "missing required key", hint)
    version = data["version"]
    if type(version) is not int:
        message = f"must be an integer, got {describe(version)}"
        raise spec_error(*where, message, "write 'version: 1'")
    if version not in SUPPORTED_VERSIONS:
        message = f"unsupported job format version {describe(version)}"
        raise spec_error(*where, message, f"this sensaov reads versions: {supported}")


def _explain(error: ErrorDetails) -> tuple[KeyPath, str, str | None]:
    # "[key]" is pydantic's marker for a mapping's key (scene_args); the key itself precedes it.
    path: KeyPath = tuple(
        part for part in error["loc"] if part not in UNION_MEMBERS and part != "[key]"
    )
    kind, ctx, value = error["type"], error.get("ctx", {}), error["input"]
    if kind == "value_error" and isinstance(ctx.get("error"), Problem):
        problem: Problem = ctx["error"]
        return path + problem.at, problem.message, problem.hint
    if kind == UNION:
        return _explain_union(path, error)
    if kind == "missing":
        return path, "missing required key", None
    if kind == "literal_error":
        return (path, *_not_one_of(re.findall(r"'([^']*)'", ctx["expected"]), value))
    return path, _reword(error), _quoted_number_hint(kind, value)


def _explain_union(path: KeyPath, error: ErrorDetails) -> tuple[KeyPath, str, str | None]:
    """Why no member of a tagged union fits: not a mapping, or a missing or unknown tag."""
    ctx, value = error.get("ctx", {}), error["input"]
    field, choices = ctx.get("field"), tuple(ctx.get("choices", "").split(","))
    if not isinstance(value, dict):
        return path, f"must be {ctx['expects']}, got {describe(value)}", None
    if not field:
        return path, ctx["message"], None
    if field not in value:
        # A misspelt tag key ("typ:") is the likelier story than a forgotten one.
        for key in value:
            hint = did_you_mean(key, (field,))
            if hint is not None:
                return path + (key,), f"unknown key {describe(key)}", hint
        return path + (field,), f"missing required key (one of: {', '.join(choices)})", None
    return (path + (field,), *_not_one_of(choices, value[field]))


def _not_one_of(choices: Sequence[str], value: Any) -> tuple[str, str | None]:
    hint = did_you_mean(value, choices) if isinstance(value, str) else None
    return f"must be one of {', '.join(choices)}; got {describe(value)}", hint


def _reword(error: ErrorDetails) -> str:
    """pydantic's "Input should be a valid integer" as "must be an integer, got 'many'"."""
    kind, ctx, value = error["type"], error.get("ctx", {}), error["input"]
    if kind == "string_pattern_mismatch":
        meaning = PATTERN_MEANINGS.get(ctx["pattern"], f"match {ctx['pattern']}")
        return f"must be {meaning}; got {describe(value)}"
    if kind == "string_too_short" and ctx["min_length"] == 1:
        return "must not be empty"
    if kind in ("tuple_type", "dict_type"):  # the dataclasses hold a job file's lists as tuples
        return f"must be {'a list' if kind == 'tuple_type' else 'a mapping'}, got {describe(value)}"
    message = error["msg"].replace("Input should be", "must be")
    message = re.sub(r"\ba valid (?=[aeiou])", "an ", message).replace("a valid ", "a ")
    return f"{message}, got {describe(value)}"


def _quoted_number_hint(kind: str, value: Any) -> str | None:
    if kind in ("int_type", "float_type") and isinstance(value, str):
        with contextlib.suppress(ValueError):
            float(value)
            return "write the number without quotes"
    return None


# --- the YAML, read as yaml.safe_load reads it, with the line of every key path ---


def format_key_path(path: KeyPath) -> str:
    """``("objectives", 1, "region")`` -> ``objectives[1].region``."""
    text = ""
    for part in path:
        if isinstance(part, int) and not isinstance(part, bool):
            text += f"[{part}]"
        elif isinstance(part, str) and _PLAIN_KEY.fullmatch(part):
            text += f".{part}" if text else part
        else:
            # Odd keys (spaces, newlines, numbers) are quoted so the path stays one line.
            text += f"[{json.dumps(part) if isinstance(part, str) else repr(part)}]"
    return text


def spec_error(
    shown: str, line: int | None, path: KeyPath, message: str, hint: str | None = None
) -> SpecError:
    """A SpecError located as ``<job>:<line>: <key path>``, on one line whatever the inputs."""
    where = shown if line is None else f"{shown}:{line}"
    if path:
        where += f": {format_key_path(path)}"
    return SpecError(_one_line(message), where=where, hint=_one_line(hint) if hint else None)


def _one_line(text: str) -> str:
    return " ".join(text.split())


@dataclass(frozen=True)
class YamlDocument:
    """The data of a job file and the line (1-based) where each key path is written."""

    data: Any
    lines: dict[KeyPath, int]

    def line_of(self, path: KeyPath) -> int | None:
        """The line of ``path``, or of its nearest written ancestor (for a missing key)."""
        for end in range(len(path), -1, -1):
            line = self.lines.get(tuple(path[:end]))
            if line is not None:
                return line
        return None


def read_yaml(path: Path, shown: str) -> YamlDocument:
    """Read and parse ``path``; every failure is a SpecError located in ``shown``."""
    raw = read_regular(path, "job file", cap=MAX_JOB_BYTES, error=SpecError)
    try:
        return _parse(raw, shown)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        parts = [part for part in (exc.context, exc.problem) if part]
        raise spec_error(shown, line, (), "invalid YAML: " + ", ".join(parts)) from None
    except yaml.YAMLError as exc:
        raise spec_error(shown, None, (), f"YAML error: {exc}") from None
    except RecursionError:
        raise spec_error(shown, None, (), "YAML nested too deeply") from None


def _parse(raw: bytes, shown: str) -> YamlDocument:
    """The data and the line of every key and item; a duplicate key is refused.

    yaml.safe_load forgets where things were and silently keeps the last of two equal keys, so
    the node tree is composed with the same (safe) loader, walked, then constructed: the data is
    exactly what safe_load returns.
    """
    loader = _JobLoader(raw)  # reads the encoding: may raise
    lines: dict[KeyPath, int] = {}
    seen: set[int] = set()

    def walk(node: yaml.Node, path: KeyPath) -> None:
        # An alias repeats a node; walking it once keeps "billion laughs" documents cheap.
        if id(node) in seen:
            return
        seen.add(id(node))
        if isinstance(node, yaml.SequenceNode):
            for index, item in enumerate(node.value):
                lines.setdefault(path + (index,), item.start_mark.line + 1)
                walk(item, path + (index,))
        elif isinstance(node, yaml.MappingNode):
            first: dict[Any, int] = {}
            for key_node, value_node in node.value:
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == _MERGE_TAG:
                    continue  # merge keys and complex keys are left to the constructor
                key = loader.construct_object(key_node)
                line = key_node.start_mark.line + 1
                if key in first:
                    raise spec_error(
                        shown,
                        line,
                        path + (key,),
                        f"duplicate key (first given on line {first[key]})",
                        "YAML would silently keep only the last one; remove one",
                    )
                first[key] = line
                lines.setdefault(path + (key,), line)
                walk(value_node, path + (key,))

    try:
        node = loader.get_single_node()
        if node is None:
            raise spec_error(shown, None, (), "the job file is empty", "start with 'version: 1'")
        lines[()] = node.start_mark.line + 1
        walk(node, ())
        return YamlDocument(loader.construct_document(node), lines)
    finally:
        loader.dispose()


# --- a viewpoint saved from sensaov view: a camera entry, or a copy of the job file ---------


def camera_entry(camera: CameraSpec) -> dict[str, Any]:
    """The mapping a job's ``inspection_cameras`` list takes for a ``look_at`` camera, so the
    view can be projected on a farm."""
    assert camera.look_at is not None and camera.resolution is not None
    rounded = {
        k: [_round(v) for v in getattr(camera.look_at, k)] for k in ("origin", "target", "up")
    }
    return {
        "name": camera.name,
        "look_at": rounded,
        "fov": _round(camera.fov),
        "resolution": list(camera.resolution),
        "vis_spp": camera.vis_spp,
    }


def camera_yaml(camera: CameraSpec) -> str:
    """The camera as one YAML list item, ready to paste under ``inspection_cameras:``."""
    return yaml.safe_dump([camera_entry(camera)], sort_keys=False, default_flow_style=None)


def check_camera_name(name: str, taken: Sequence[str]) -> str | None:
    """Why ``name`` cannot name a new inspection camera, or None when it can."""
    if not re.fullmatch(NAME_PATTERN, name):
        return f"camera name {name!r} must be a letter then up to 31 letters, digits or _"
    if name in ("primal", "buffer", "objective"):
        return f"camera name {name!r} is reserved"
    if name in taken:
        return f"the job already has an inspection camera named {name!r}"
    return None


def job_copy_text(
    job: JobSpec, base: Path, cameras: Sequence[CameraSpec], copy: Path, buffer: Path
) -> str:
    """The job file ``base`` (the job itself, or an earlier copy of it, as safe_load reads it:
    without comments) with ``cameras`` appended, its paths rewritten for a file at ``copy`` so
    it names the same files; ``buffer`` is named in its header."""
    data = _safe_load(base.read_text())
    folder = copy.parent
    data["scene"] = _relative(job.scene, folder)
    data["output"] = _relative(job.output, folder)
    for raw, objective in zip(data.get("objectives") or [], job.objectives, strict=False):
        for field in ("mask", "target", "path"):
            value = getattr(objective, field)
            if isinstance(raw, dict) and value is not None:
                raw[field] = _relative(value, folder)
    listed = data.get("inspection_cameras") or []
    data["inspection_cameras"] = [*listed, *(camera_entry(c) for c in cameras)]
    default = os.path.abspath(buffer) == os.path.abspath(job.output / "buffer.npz")
    option = "" if default else f" --buffer {os.path.abspath(buffer)}"
    head = (
        f"# {job.path.name} with cameras saved by 'sensaov view' (comments of the original are "
        "not kept;\n# paths are relative to this file). Project them with:\n"
        f"#   sensaov project {copy.name}{option}\n"
    )
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def camera_names(path: Path) -> tuple[str, ...]:
    """The names of the inspection cameras a job file lists (read as written)."""
    data = _safe_load(path.read_text()) or {}
    listed = data.get("inspection_cameras") or []
    return tuple(str(c.get("name")) for c in listed if isinstance(c, dict))


def _relative(path: Path, folder: Path) -> str:
    return os.path.relpath(os.path.abspath(path), os.path.abspath(folder))


def _round(value: float) -> float:
    """Six significant digits: a camera moved by a mouse needs no more, and reads better."""
    return float(f"{value:.6g}")
