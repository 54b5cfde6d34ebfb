"""The job spec: a YAML job file, validated, as frozen dataclasses the pipeline stages share.

:func:`load_job` reads the file (``yaml.safe_load`` semantics, see :mod:`.spec_yaml`),
validates it against the models of :mod:`.spec_model`, and returns a :class:`JobSpec` with
every path resolved against the job file's directory. Anything wrong raises one
:class:`~sensaov_cli.errors.SpecError` located as ``<job>:<line>: <key path>``: the first
problem in the file, by line. :func:`job_schema` is the JSON Schema of the format.

The format is documented in ``docs/job-spec.md``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError
from pydantic.json_schema import GenerateJsonSchema
from pydantic_core import ErrorDetails

from sensaov_cli.errors import SpecError
from sensaov_cli.spec.fields import PATTERN_MEANINGS, PROBLEM, UNION, close_match, describe
from sensaov_cli.spec.schema_model import (
    UNION_TAGS,
    JobModel,
    L2ToTarget,
    LookAtInspection,
    LookAtModel,
    MeanLuminance,
    ObjectChannel,
    ObjectiveInspection,
    ObjectiveLookAt,
    PythonObjective,
    RegionLuminance,
    SelectChannel,
    SensorInspection,
    TypeChannel,
)
from sensaov_cli.spec.yaml_source import KeyPath, YamlDocument, read_yaml, spec_error

SUPPORTED_VERSIONS = (1,)


@dataclass(frozen=True)
class RenderSpec:
    spp: int
    max_depth: int  # -1 = unbounded
    seed: int
    resolution: tuple[int, int] | None  # None = the film's size
    deterministic: bool = True  # one thread for backward passes on the CPU backend


@dataclass(frozen=True)
class ParameterSpec:
    include: tuple[str, ...]
    exclude: tuple[str, ...]
    shared: str  # "split" | "keep"


@dataclass(frozen=True)
class LookAt:
    origin: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float]


@dataclass(frozen=True)
class CameraSpec:
    """A camera: a scene sensor, a look_at camera, or (inspection only) the objective camera.

    The objective camera is named "objective"; with neither sensor nor look_at it is the
    scene's first sensor.
    """

    name: str
    sensor: str | None
    look_at: LookAt | None
    fov: float
    resolution: tuple[int, int] | None
    objective: bool
    vis_spp: int


@dataclass(frozen=True)
class ObjectiveSpec:
    name: str
    type: str  # mean_luminance | region_luminance | l2_to_target | python
    region: tuple[float, float, float, float] | None
    mask: Path | None
    target: Path | None
    function: str | None
    path: Path | None

    def definition(self) -> dict[str, Any]:
        """The objective as written down in outputs: its non-None fields, JSON-able."""
        fields = _jsonable(dataclasses.asdict(self), None)
        return {key: value for key, value in fields.items() if value is not None}


@dataclass(frozen=True)
class ChannelSpec:
    name: str
    kind: str  # object | type | select
    types: tuple[str, ...] | None
    select: str | None
    weight: str
    sign: str
    aggregate: str
    tonemap: str
    normalize: str


@dataclass(frozen=True)
class JobSpec:
    path: Path
    version: int
    scene: Path
    variant: str
    render: RenderSpec
    parameters: ParameterSpec
    objective_camera: CameraSpec
    objectives: tuple[ObjectiveSpec, ...]
    inspection_cameras: tuple[CameraSpec, ...]
    channels: tuple[ChannelSpec, ...]
    output: Path

    def to_dict(self) -> dict[str, Any]:
        """The whole spec as a canonical JSON-able dict (absolute paths as strings)."""
        result: dict[str, Any] = _jsonable(dataclasses.asdict(self), None)
        return result

    def job_hash(self) -> str:
        """sha256 of the spec without ``path``, its paths relative to the job's directory.

        Relative paths make the hash survive moving or copying a project directory: the
        same job next to the same files hashes the same wherever it lies.
        """
        fields = _jsonable(dataclasses.asdict(self), self.path.parent)
        del fields["path"]
        return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()


def _jsonable(value: Any, relative_to: Path | None) -> Any:
    if isinstance(value, dict):
        return {key: _jsonable(item, relative_to) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(item, relative_to) for item in value]
    if isinstance(value, Path):
        return str(value) if relative_to is None else os.path.relpath(value, relative_to)
    return value


def load_job(path: Path) -> JobSpec:
    """Read, validate and resolve the job file at ``path``; raise SpecError if it is wrong."""
    shown = str(path)
    job_path = Path(os.path.abspath(path))
    document = read_yaml(job_path, shown)
    _check_top_level(document, shown)
    try:
        model = JobModel.model_validate(document.data, context={"base_dir": job_path.parent})
    except ValidationError as exc:
        raise _first_error(exc, document, shown) from None
    return _to_spec(model, job_path)


def _to_spec(model: JobModel, job_path: Path) -> JobSpec:
    base = job_path.parent
    render, parameters = model.render, model.parameters
    return JobSpec(
        path=job_path,
        version=model.version,
        scene=_resolve(base, model.scene),
        variant=model.variant,
        render=RenderSpec(
            render.spp, render.max_depth, render.seed, render.resolution, render.deterministic
        ),
        parameters=ParameterSpec(
            tuple(parameters.include), tuple(parameters.exclude), parameters.shared
        ),
        objective_camera=_objective_camera(model.objective_camera),
        objectives=tuple(_objective(objective, base) for objective in model.objectives),
        inspection_cameras=tuple(_inspection(camera) for camera in model.inspection_cameras),
        channels=tuple(_channel(channel) for channel in model.channels),
        output=_resolve(base, model.output or f"out/{job_path.stem}"),
    )


def _resolve(base: Path, relative: str) -> Path:
    # abspath, not resolve(): keep the user's symlinks, so paths read as they were written.
    return Path(os.path.abspath(base / relative))


def _look_at(model: LookAtModel) -> LookAt:
    return LookAt(model.origin, model.target, model.up)


def _objective_camera(model: str | ObjectiveLookAt | None) -> CameraSpec:
    if model is None:
        return CameraSpec("objective", None, None, 40.0, None, False, 16)
    if isinstance(model, str):
        return CameraSpec("objective", model, None, 40.0, None, False, 16)
    look_at = _look_at(model.look_at)
    return CameraSpec("objective", None, look_at, model.fov, model.resolution, False, 16)


def _inspection(
    model: LookAtInspection | SensorInspection | ObjectiveInspection,
) -> CameraSpec:
    name, resolution, vis_spp = model.name, model.resolution, model.vis_spp
    if isinstance(model, LookAtInspection):
        look_at = _look_at(model.look_at)
        return CameraSpec(name, None, look_at, model.fov, resolution, False, vis_spp)
    if isinstance(model, SensorInspection):
        return CameraSpec(name, model.sensor, None, 40.0, resolution, False, vis_spp)
    return CameraSpec(name, None, None, 40.0, resolution, True, vis_spp)


def _objective(
    model: MeanLuminance | RegionLuminance | L2ToTarget | PythonObjective, base: Path
) -> ObjectiveSpec:
    def path_of(key: str) -> Path | None:
        value = getattr(model, key, None)
        return None if value is None else _resolve(base, value)

    is_python = isinstance(model, PythonObjective)
    return ObjectiveSpec(
        name=model.name,
        type=model.type,
        region=getattr(model, "region", None),
        mask=path_of("mask"),
        target=path_of("target"),
        function=getattr(model, "function", None),
        path=(path_of("path") or _resolve(base, ".")) if is_python else None,
    )


def _channel(model: ObjectChannel | TypeChannel | SelectChannel) -> ChannelSpec:
    types = getattr(model, "types", None)
    return ChannelSpec(
        name=model.name,
        kind=model.kind,
        types=None if types is None else tuple(types),
        select=getattr(model, "select", None),
        weight=model.weight,
        sign=model.sign,
        aggregate=model.aggregate,
        tonemap=model.tonemap,
        normalize=model.normalize,
    )


def job_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of the YAML job format, for editors and validators."""
    schema = JobModel.model_json_schema(schema_generator=_UntitledFields)
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}


class _UntitledFields(GenerateJsonSchema):
    """Leave out pydantic's per-field titles ("Spp"): they repeat the key and say nothing."""

    def field_title_should_be_set(self, schema: Any) -> bool:
        return False


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
    path: KeyPath = tuple(part for part in error["loc"] if part not in UNION_TAGS)
    kind, ctx, value = error["type"], error.get("ctx", {}), error["input"]
    if kind == PROBLEM:
        return path + tuple(ctx["at"]), ctx["message"], ctx["hint"]
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
    if kind in ("model_type", "model_attributes_type", "dict_type"):
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
