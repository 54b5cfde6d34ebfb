"""The shape of a job file, version 1, as pydantic models: keys, types, ranges and defaults.

These models validate the plain data read from YAML and generate the JSON Schema that
``sensaov schema`` prints; :mod:`sensaov_cli.spec.job` turns the validated models into the frozen
dataclasses the pipeline uses. The field types live in :mod:`sensaov_cli.spec.fields`.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal, get_args

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Tag,
    model_validator,
)

from sensaov_cli.spec.fields import (
    FUNCTION_PATTERN,
    DirPath,
    FilePath,
    Fov,
    Globs,
    MaxDepth,
    Name,
    OutputPath,
    Region,
    Resolution,
    Text,
    TrueFlag,
    Vector,
    VisSpp,
    by_field,
    describe,
    did_you_mean,
    problem,
    tagged_union,
    unique_names,
)
from sensaov_cli.vocabulary import Aggregate, Normalize, Sign, Tonemap, Weight

Variant = Literal[
    "auto",
    "llvm_ad_rgb",
    "cuda_ad_rgb",
    "llvm_ad_mono",
    "cuda_ad_mono",
    "llvm_ad_spectral",
    "cuda_ad_spectral",
]
ObjectiveType = Literal["mean_luminance", "region_luminance", "l2_to_target", "python"]
ChannelKind = Literal["object", "type", "select"]
CAMERA_SELECTORS = ("look_at", "sensor", "objective")


class _Model(BaseModel):
    """Unknown keys are refused with a did-you-mean before any field is looked at."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    _owner: ClassVar[str] = ""

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for key in data:
                if key not in cls.model_fields:
                    raise cls._unknown_key(key)
        return data

    @classmethod
    def _unknown_key(cls, key: object) -> Exception:
        valid = list(cls.model_fields)
        return problem(
            f"unknown key {describe(key)}{cls._owner}",
            at=(key,),
            hint=did_you_mean(key, valid, "keys"),
        )


def _by_selector(value: Any) -> str | None:
    """The first of look_at, sensor, objective present; a second one is then an unknown key."""
    present = [key for key in CAMERA_SELECTORS if isinstance(value, dict) and key in value]
    return f"camera: {present[0]}" if present else None


def _sensor_or_look_at(value: Any) -> str | None:
    if value is None:
        return "camera: first sensor"
    if isinstance(value, str):
        return "camera: sensor id"
    return "camera: look_at" if isinstance(value, dict) else None


class RenderModel(_Model):
    """How the objective camera's image is rendered and differentiated."""

    spp: Annotated[
        int, Field(strict=True, ge=1, lt=2**32, description="Samples per pixel (32-bit).")
    ] = 64
    max_depth: Annotated[MaxDepth, Field(description="Longest path; -1 = unbounded.")] = 6
    seed: Annotated[int, Field(strict=True, ge=0, lt=2**31, description="Sampler seed.")] = 0
    resolution: Annotated[
        Resolution | None,
        Field(description="[width, height] of the objective render; null = its film's size."),
    ] = None
    deterministic: Annotated[
        bool,
        Field(
            strict=True,
            description="Byte-identical buffers for the same job and seed. On the CPU backend the "
            "backward passes then run on one thread (parallel atomic adds sum in varying order).",
        ),
    ] = True


class ParametersModel(_Model):
    """Which scene parameters are differentiated."""

    include: Annotated[
        Globs, Field(min_length=1, description="fnmatch globs over parameter keys to select.")
    ] = ["*"]
    exclude: Annotated[Globs, Field(description="Globs removed from the selection.")] = []
    shared: Annotated[
        Literal["split", "keep"],
        Field(
            description="split: copy a BSDF shared by several shapes into each, so each "
            "object gets its own gradient; keep: leave shared BSDFs shared."
        ),
    ] = "split"


class LookAtModel(_Model):
    """A camera placed at origin, looking at target, with up pointing up."""

    origin: Vector
    target: Vector
    up: Vector

    @model_validator(mode="after")
    def _proper_frame(self) -> LookAtModel:
        view = [t - o for t, o in zip(self.target, self.origin, strict=True)]
        if not any(view):
            raise problem("target must differ from origin", at=("target",))
        # The camera frame is built from up x (target - origin); parallel vectors give NaNs.
        ux, uy, uz = self.up
        vx, vy, vz = view
        cross = (uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx)
        if math.hypot(*cross) <= 1e-9 * math.hypot(*view) * max(math.hypot(*self.up), 1e-300):
            raise problem("up must not be zero or parallel to target - origin", at=("up",))
        return self


class ObjectiveLookAt(_Model):
    """An objective camera added to the scene."""

    look_at: LookAtModel
    fov: Fov = 40.0
    resolution: Annotated[
        Resolution | None,
        Field(description="[width, height]; null = 256 x 256. render.resolution overrides it."),
    ] = None


class _Inspection(_Model):
    """A camera the sensitivities are bound to (pictures only: no gradients there)."""

    name: Annotated[Name, Field(description="Unique among inspection cameras; the EXR name.")]
    vis_spp: VisSpp = 16

    @classmethod
    def _unknown_key(cls, key: object) -> Exception:
        if key in CAMERA_SELECTORS:
            return problem(
                f"an inspection camera takes only one of look_at, sensor or objective; "
                f"this one also has {key}",
                at=(key,),
            )
        return super()._unknown_key(key)

    @model_validator(mode="after")
    def _reserved_name(self) -> _Inspection:
        if self.name in ("primal", "buffer"):  # <output>/<camera>.exr must not clobber run's files
            raise problem(
                f"the name {self.name!r} is reserved: 'sensaov run' writes {self.name} files",
                at=("name",),
                hint="choose another name",
            )
        if self.name == "objective" and not isinstance(self, ObjectiveInspection):
            raise problem(
                "the name 'objective' is reserved for the objective camera",
                at=("name",),
                hint="use 'objective: true' to mean that camera, or choose another name",
            )
        return self


class LookAtInspection(_Inspection):
    _owner = " for a look_at camera"
    look_at: LookAtModel
    fov: Fov = 40.0
    resolution: Annotated[Resolution, Field(description="[width, height].")] = (256, 256)


class SensorInspection(_Inspection):
    _owner = " for a sensor camera"
    sensor: Annotated[Text, Field(description="Id of a sensor in the scene.")]
    resolution: Annotated[Resolution | None, Field(description="null = the sensor's film.")] = None


class ObjectiveInspection(_Inspection):
    _owner = " for the objective camera"
    objective: Annotated[TrueFlag, Field(description="The objective camera.")]
    resolution: Annotated[
        Resolution | None, Field(description="null = the objective camera's resolution.")
    ] = None


class _Objective(_Model):
    """A scalar of the rendered image whose derivatives are computed."""

    name: Annotated[Name, Field(description="Unique among objectives.")]


class MeanLuminance(_Objective):
    _owner = " for type mean_luminance"
    type: Literal["mean_luminance"]


class RegionLuminance(_Objective):
    _owner = " for type region_luminance"
    type: Literal["region_luminance"]
    region: Annotated[Region | None, Field(description="[x0, y0, x1, y1], normalised, y down.")] = (
        None
    )
    mask: Annotated[FilePath | None, Field(description="Mask image, relative to the job.")] = None

    @model_validator(mode="after")
    def _one_area(self) -> RegionLuminance:
        if (self.region is None) == (self.mask is None):
            both = self.region is not None
            raise problem(
                "give exactly one of region or mask" + (", not both" if both else ""),
                at=("mask",) if both else (),
            )
        return self


class L2ToTarget(_Objective):
    _owner = " for type l2_to_target"
    type: Literal["l2_to_target"]
    target: Annotated[FilePath, Field(description="Target image, relative to the job.")]


class PythonObjective(_Objective):
    _owner = " for type python"
    type: Literal["python"]
    function: Annotated[
        str, Field(strict=True, pattern=FUNCTION_PATTERN, description="'module:function'.")
    ]
    path: Annotated[
        DirPath | None, Field(description="Put on sys.path; null = the job file's directory.")
    ] = None


class _Channel(_Model):
    """A sensitivity image layer: a selection of parameters, aggregated and encoded."""

    name: Annotated[Name, Field(description="Unique among channels; the EXR layer name.")]
    weight: Weight = "value"
    sign: Sign = "signed"
    aggregate: Aggregate = "l2"
    tonemap: Tonemap = "none"
    normalize: Normalize = "none"


class ObjectChannel(_Channel):
    _owner = " for kind object"
    kind: Literal["object"]


class TypeChannel(_Channel):
    _owner = " for kind type"
    kind: Literal["type"]
    types: Annotated[
        list[Text] | None,
        Field(min_length=1, description="Parameter types to show; null = all present."),
    ] = None


class SelectChannel(_Channel):
    _owner = " for kind select"
    kind: Literal["select"]
    select: Annotated[Text, Field(description="fnmatch glob over parameter keys.")]


Objective = Annotated[
    Annotated[MeanLuminance, Tag("type: mean_luminance")]
    | Annotated[RegionLuminance, Tag("type: region_luminance")]
    | Annotated[L2ToTarget, Tag("type: l2_to_target")]
    | Annotated[PythonObjective, Tag("type: python")],
    tagged_union(
        by_field("type", get_args(ObjectiveType)),
        "a mapping with name and type",
        "type",
        get_args(ObjectiveType),
    ),
]
Inspection = Annotated[
    Annotated[LookAtInspection, Tag("camera: look_at")]
    | Annotated[SensorInspection, Tag("camera: sensor")]
    | Annotated[ObjectiveInspection, Tag("camera: objective")],
    tagged_union(
        _by_selector,
        "a mapping with name and one of look_at, sensor or objective",
        message="an inspection camera needs one of look_at, sensor or objective: true",
    ),
]
Channel = Annotated[
    Annotated[ObjectChannel, Tag("kind: object")]
    | Annotated[TypeChannel, Tag("kind: type")]
    | Annotated[SelectChannel, Tag("kind: select")],
    tagged_union(
        by_field("kind", get_args(ChannelKind)),
        "a mapping with name and kind",
        "kind",
        get_args(ChannelKind),
    ),
]
# None is a member rather than "| None" outside: the discriminator's context makes the
# Annotated unhashable, which typing's Optional cannot take.
ObjectiveCamera = Annotated[
    Annotated[Text, Tag("camera: sensor id")]
    | Annotated[ObjectiveLookAt, Tag("camera: look_at")]
    | Annotated[None, Tag("camera: first sensor")],
    tagged_union(_sensor_or_look_at, "a sensor id or a mapping with look_at"),
]


def _tags(*unions: Any) -> frozenset[str]:
    members = [member for union in unions for member in get_args(get_args(union)[0])]
    return frozenset(meta.tag for m in members for meta in m.__metadata__ if isinstance(meta, Tag))


UNION_TAGS = _tags(Objective, Inspection, Channel, ObjectiveCamera)
DEFAULT_CHANNELS = [{"name": "objects", "kind": "object"}, {"name": "types", "kind": "type"}]


def _default_channels() -> list[Any]:
    return [ObjectChannel(name="objects", kind="object"), TypeChannel(name="types", kind="type")]


class JobModel(_Model):
    """A sensaov job: which scene, which objectives, which views of their sensitivities."""

    model_config = ConfigDict(title="sensaov job (format version 1)")
    version: Annotated[Literal[1], Field(description="Job format version.")]
    scene: Annotated[FilePath, Field(description="Mitsuba scene XML, relative to the job.")]
    variant: Annotated[Variant, Field(description="Mitsuba variant; auto picks one.")] = "auto"
    # Defaults of nested models are shown as {} ("all defaults") in the schema.
    render: Annotated[RenderModel, Field(json_schema_extra={"default": {}})] = RenderModel()
    parameters: Annotated[ParametersModel, Field(json_schema_extra={"default": {}})] = (
        ParametersModel()
    )
    objective_camera: Annotated[
        ObjectiveCamera,
        Field(description="Sensor id or look_at camera; null = the scene's first sensor."),
    ] = None
    objectives: Annotated[
        list[Objective],
        Field(min_length=1, description="What to differentiate; one backward pass each."),
        unique_names("objective", "objectives"),
    ]
    inspection_cameras: Annotated[
        list[Inspection],
        Field(description="Extra views the sensitivities are shown from."),
        unique_names("inspection camera", "inspection_cameras"),
    ] = []
    channels: Annotated[
        list[Channel],
        Field(default_factory=_default_channels, json_schema_extra={"default": DEFAULT_CHANNELS}),
        unique_names("channel", "channels"),
    ]
    output: Annotated[
        OutputPath | None,
        Field(description="Output directory, relative to the job; null = out/<job stem>."),
    ] = None
