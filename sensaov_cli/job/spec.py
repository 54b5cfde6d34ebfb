"""The job as the pipeline sees it: frozen dataclasses, one per concept, standard library only.

Every field of the job format is defined here once: name, type and default, and in its
``Annotated`` metadata the range, wording and description a job file must respect
(:mod:`.markers`). Types are strict where YAML makes mistakes easy: ``"64"`` is not an integer
and ``true`` is not a number, but ``40`` is accepted where a float is expected. Importing this
module loads neither pydantic nor PyYAML, so views and outputs name its classes freely.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from annotated_types import Ge, Gt, Le, Lt

from sensaov_cli import vocabulary
from sensaov_cli.job.markers import (
    STRICT,
    After,
    Before,
    Doc,
    In,
    JobFilePath,
    JobPath,
    Json,
    NonEmpty,
    Problem,
    Section,
    SensorOrPlaced,
    Setting,
    Tagged,
    TaggedByKey,
    Text,
    describe,
)

# --- the field types ---

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


def _existing(noun: str, test: Callable[[Path], bool]) -> Callable[[Path, Path], None]:
    """A check that a path exists and is a ``noun`` (file, directory) that passes ``test``."""

    def check(path: Path, job_dir: Path) -> None:
        hint = f"relative paths start at the job file's directory, {job_dir}"
        if not path.exists():
            raise Problem(f"{noun} not found: {path}", hint=hint)
        if not test(path):
            raise Problem(f"not a {noun}: {path}", hint=hint)

    return check


def _output_dir(path: Path, job_dir: Path) -> None:
    if path.exists() and not path.is_dir():
        raise Problem(f"exists and is not a directory: {path}", hint="output names a directory")


def _count(n: int, what: str) -> Before:
    """Check a list's length first, so a short list is one clear error, not one per item."""

    def check(value: Any) -> Any:
        if not isinstance(value, list) or len(value) != n:
            got = f"{len(value)} items" if isinstance(value, list) else describe(value)
            raise Problem(f"must be a list of {n} {what}, got {got}")
        return value

    return Before(check)


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
JobFile = Annotated[Path, JobPath(_existing("file", Path.is_file))]
JobDir = Annotated[Path | None, JobPath(_existing("directory", Path.is_dir), null_means=".")]
OutputDir = Annotated[Path, JobPath(_output_dir, null_means="out/{stem}")]
Globs = Annotated[
    tuple[Text, ...],
    Before(lambda value: [value] if isinstance(value, str) else value),
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


SceneArgs = Annotated[
    dict[
        Annotated[str, STRICT, Setting(pattern=SCENE_ARG_PATTERN)],
        Annotated[str, Before(_scene_arg_text), Json({"type": ["string", "number", "boolean"]})],
    ],
    Doc("Values for the scene's $name arguments, like mitsuba.load_file's keywords."),
]


# --- cameras: a job's objective camera and its inspection cameras (paper Fig. 6) ---

# The shapes of a camera: an inspection camera's, named by the key that picks its kind, and
# the mapping that places the objective camera.
LOOK_AT, SENSOR, OBJECTIVE, PLACED = "look_at", "sensor", "objective", "placed"
INSPECTION = (LOOK_AT, SENSOR, OBJECTIVE)


@dataclass(frozen=True)
class LookAt(Section):
    """A camera placed at origin, looking at target, with up pointing up."""

    origin: Vector
    target: Vector
    up: Vector

    def __post_init__(self) -> None:
        view = [t - o for t, o in zip(self.target, self.origin, strict=True)]
        if not any(view):
            raise Problem("target must differ from origin", at=("target",))
        # The camera frame is built from up x (target - origin); parallel vectors give NaNs.
        ux, uy, uz = self.up
        vx, vy, vz = view
        cross = (uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx)
        if math.hypot(*cross) <= 1e-9 * math.hypot(*view) * max(math.hypot(*self.up), 1e-300):
            raise Problem("up must not be zero or parallel to target - origin", at=("up",))


@dataclass(frozen=True)
class CameraSpec:
    """A camera: a scene sensor, a look_at camera, or (inspection only) the objective camera,
    named "objective"; with neither sensor nor look_at, the scene's first sensor."""

    name: Annotated[Name, In(*INSPECTION), Doc("Unique among inspection cameras; the EXR name.")]
    sensor: Annotated[
        Text | None, In(SENSOR, required=True), Doc("Id of a sensor in the scene.")
    ] = None
    look_at: Annotated[LookAt | None, In(LOOK_AT, PLACED, required=True)] = None
    fov: Annotated[Fov, In(LOOK_AT, PLACED)] = 40.0
    resolution: Annotated[
        Resolution | None,
        In(LOOK_AT, default=(256, 256), doc="[width, height]."),
        In(SENSOR, doc="null = the sensor's film."),
        In(OBJECTIVE, doc="null = the objective camera's resolution."),
        In(PLACED, doc="[width, height]; null = 256 x 256. render.resolution overrides it."),
    ] = None
    objective: Annotated[TrueFlag, In(OBJECTIVE, required=True), Doc("The objective camera.")] = (
        False
    )
    vis_spp: Annotated[VisSpp, In(*INSPECTION)] = 16


def _inspection_name(camera: CameraSpec) -> CameraSpec:
    if camera.name in ("primal", "buffer"):  # <output>/<camera>.exr must not clobber run's files
        raise Problem(
            f"the name {camera.name!r} is reserved: 'sensaov run' writes {camera.name} files",
            at=("name",),
            hint="choose another name",
        )
    if camera.name == "objective" and not camera.objective:
        raise Problem(
            "the name 'objective' is reserved for the objective camera",
            at=("name",),
            hint="use 'objective: true' to mean that camera, or choose another name",
        )
    return camera


InspectionCamera = Annotated[
    CameraSpec,
    TaggedByKey(
        INSPECTION,
        owners=(" for a look_at camera", " for a sensor camera", " for the objective camera"),
        expects="a mapping with name and one of look_at, sensor or objective",
        missing="an inspection camera needs one of look_at, sensor or objective: true",
        clash="an inspection camera takes only one of look_at, sensor or objective; "
        "this one also has {}",
        noun="Inspection",
    ),
    After(_inspection_name),
]


# --- how run renders (render:) and repairs what Mitsuba gets wrong (repair:) ---


# Batches of an automatic split: enough degrees of freedom for a Student-t interval (t(0.975, 7)
# = 2.36), few enough that a batch keeps most of its kernels' fixed cost shared (bench/).
AUTO_BATCHES = 8
MAX_BATCHES = 1024


def _batches(value: Any) -> Any:
    """One message for both shapes of ``batches`` (pydantic would word each member's failure)."""
    number = isinstance(value, int) and not isinstance(value, bool)
    if value != "auto" and not (number and 1 <= value <= MAX_BATCHES):
        hint = "write the number without quotes" if str(value).strip().isdigit() else None
        raise Problem(
            f"must be 'auto' or an integer from 1 to {MAX_BATCHES}, got {describe(value)}",
            hint=hint,
        )
    return value


Batches = Annotated[
    int | Literal["auto"],
    Before(_batches),
    Json(
        {"anyOf": [{"type": "integer", "minimum": 1, "maximum": MAX_BATCHES}, {"const": "auto"}]},
        replace=True,
    ),
]


@dataclass(frozen=True)
class UntilSpec(Section):
    """Sampling until the answer is resolved: batches are added at new seeds while it is not."""

    resolved: Annotated[
        int,
        STRICT,
        Ge(1),
        Le(1000),
        Doc(
            "The top objects of every objective (by the ranking's score) whose signs and order "
            "must be resolved (Student-t 95 %) before the run stops."
        ),
    ]
    max_spp: Annotated[
        int,
        STRICT,
        Ge(1),
        Lt(2**32),
        Doc("Samples per pixel the run may spend in all, the first render.spp included."),
    ]


@dataclass(frozen=True)
class RenderSpec(Section):
    """How the objective camera's image is rendered and differentiated."""

    spp: Annotated[int, STRICT, Ge(1), Lt(2**32), Doc("Samples per pixel (32-bit).")] = 64
    max_depth: Annotated[
        MaxDepth | None,
        Doc(
            "Longest path; -1 = unbounded; null = the scene's own (its integrator's max_depth, "
            "or that integrator's default)."
        ),
    ] = None
    seed: Annotated[int, STRICT, Ge(0), Lt(2**31), Doc("Sampler seed.")] = 0
    resolution: Annotated[
        Resolution | None,
        Doc("[width, height] of the objective render; null = its film's size."),
    ] = None
    deterministic: Annotated[
        bool,
        STRICT,
        Doc(
            "Byte-identical buffers for the same job and seed: on the CPU backend the "
            "backward passes then run on one thread (parallel atomic adds sum in varying "
            "order). Off by default: the differences are far below Monte Carlo noise."
        ),
    ] = False
    batches: Annotated[
        Batches,
        Doc(
            "Independent batches of spp/batches samples, each with its own primal and backward "
            f"passes, from whose spread the buffer's standard errors come; auto = "
            f"{AUTO_BATCHES} (at most spp; spp 1 gives 1), an integer exactly that many "
            "(1: no standard errors) (docs/job-spec.md)."
        ),
    ] = "auto"
    until: Annotated[
        UntilSpec | None,
        Doc(
            "Keep adding batches at new seeds until the top objects of every objective are "
            "resolved, or max_spp is spent; null = render spp once."
        ),
    ] = None

    def __post_init__(self) -> None:
        if isinstance(self.batches, int) and self.batches > self.spp:
            raise Problem(
                f"batches ({self.batches}) cannot exceed spp ({self.spp})", at=("batches",)
            )
        if self.until is not None and self.until.max_spp < self.spp:
            raise Problem(
                f"max_spp ({self.until.max_spp}) cannot be less than spp ({self.spp})",
                at=("until", "max_spp"),
                hint="max_spp counts every sample of the run, the first spp included",
            )

    @property
    def batch_count(self) -> int:
        """How many batches render.spp is split into: ``auto`` resolved, at most spp."""
        wanted = AUTO_BATCHES if self.batches == "auto" else self.batches
        return max(1, min(wanted, self.spp))


@dataclass(frozen=True)
class RepairSpec(Section):
    """Gradients Mitsuba is known to get wrong, computed again by finite differences."""

    budget: Annotated[
        float,
        STRICT,
        Ge(0),
        Le(1000),
        Doc(
            "Extra samples for repairs, a multiple of the run's own (its primal and backward "
            "passes); 0 repairs nothing. What does not fit stays labelled and is named."
        ),
    ] = 1.0
    seeds: Annotated[
        int,
        STRICT,
        Ge(2),
        Le(64),
        Doc(
            "Seeds per repair: both sides of a difference share a seed's samples, the "
            "standard error comes from the seeds' spread."
        ),
    ] = 4
    step: Annotated[
        float | None,
        STRICT,
        Gt(0),
        Le(0.5),
        Doc("Relative step: ε = step · max(1, |θ|); null = the measured step of each kind."),
    ] = None


@dataclass(frozen=True)
class ParameterSpec(Section):
    """Which scene parameters are differentiated."""

    include: Annotated[Globs, NonEmpty(), Doc("fnmatch globs over parameter keys to select.")] = (
        "*",
    )
    exclude: Annotated[Globs, Doc("Globs removed from the selection.")] = ()
    shared: Annotated[
        Literal["split", "keep"],
        Doc(
            "split: copy a BSDF shared by several shapes into each, so each "
            "object gets its own gradient; keep: leave shared BSDFs shared."
        ),
    ] = "split"


@dataclass(frozen=True)
class ViewsSpec(Section):
    """How the headline views and the pictures read the buffer (docs/encoding.md)."""

    untrusted: Annotated[
        vocabulary.Untrusted,
        Doc(
            "apart: object and type views add up only gradients sensaov stands behind "
            "(verified); the rest gets layers, rows and wedges of its own, named per object. "
            "include: mix them in, marked."
        ),
    ] = "apart"
    scale: Annotated[
        vocabulary.ScaleScope,
        Doc(
            "shared: one display scale per (objective, channel) across every camera of the "
            "job, for previews, contact sheets, the report and display layers; tile: each "
            "camera its own scale, labelled so."
        ),
    ] = "shared"
    percentile: Annotated[
        Number,
        Gt(50.0),
        Le(100.0),
        Doc(
            "The display scale is this percentile of |value| over the pixels a layer paints "
            "(non-zero), each camera weighted equally; larger values clip, and say so."
        ),
    ] = 95.0


@dataclass(frozen=True)
class ObjectiveSpec:
    """A scalar of the rendered image whose derivatives are computed."""

    name: Annotated[Name, Doc("Unique among objectives.")]
    type: vocabulary.ObjectiveType
    region: Annotated[
        Region | None, In("region_luminance"), Doc("[x0, y0, x1, y1], normalised, y down.")
    ] = None
    mask: Annotated[
        JobFile | None, In("region_luminance"), Doc("Mask image, relative to the job.")
    ] = None
    target: Annotated[
        JobFile | None, In("l2_to_target", required=True), Doc("Target image, relative to the job.")
    ] = None
    function: Annotated[Function | None, In("python", required=True), Doc("'module:function'.")] = (
        None
    )
    path: Annotated[
        JobDir, In("python"), Doc("Put on sys.path; null = the job file's directory.")
    ] = None

    def __post_init__(self) -> None:
        if self.name == "forward":  # the EXR layer of forward channels: forward.<name>.R/G/B
            raise Problem("the name 'forward' is reserved for forward channels", at=("name",))
        if self.type == "region_luminance" and (self.region is None) == (self.mask is None):
            both = self.region is not None
            raise Problem(
                "give exactly one of region or mask" + (", not both" if both else ""),
                at=("mask",) if both else (),
            )

    def definition(self) -> dict[str, str | list[float]]:
        """The objective as written down in outputs: its non-None fields, JSON-able."""
        fields = _jsonable(dataclasses.asdict(self), None)
        return {key: value for key, value in fields.items() if value is not None}


@dataclass(frozen=True)
class PoolSpec(Section):
    """Sum-conserving pooling of a texel field (paper §6): texel gradients are sparse."""

    kind: Annotated[vocabulary.PoolKind, Doc("gaussian, box, mip (block sums) or none.")] = (
        "gaussian"
    )
    radius: Annotated[
        float | None,
        STRICT,
        Ge(0),
        Lt(4096),
        Doc("In texels (gaussian: sigma; box: half-width; mip: log2 of the block); null = auto."),
    ] = None


@dataclass(frozen=True)
class ChannelSpec:
    """A sensitivity image layer: a selection of parameters, aggregated and encoded."""

    name: Annotated[Name, Doc("Unique among channels; the EXR layer name.")]
    kind: vocabulary.ChannelKind
    types: Annotated[
        Annotated[tuple[Text, ...], NonEmpty()] | None,
        In("type"),
        Doc("Parameter types to show; null = all present."),
    ] = None
    select: Annotated[
        Text | None,
        In("select", required=True, doc="fnmatch glob over parameter keys."),
        In("texel", doc="fnmatch glob over texture keys; null = every texture in the buffer."),
    ] = None
    weight: vocabulary.Weight = "value"
    sign: vocabulary.Sign = "signed"
    aggregate: vocabulary.Aggregate = vocabulary.DEFAULT_AGGREGATE  # what rankings score
    tonemap: vocabulary.Tonemap = "none"
    normalize: vocabulary.Normalize = "none"
    top: Annotated[
        int, STRICT, Ge(1), Lt(65), In("transport"), Doc("Objects per objective (top by l2).")
    ] = 3
    pool: Annotated[
        PoolSpec | None,
        In("texel"),
        Doc("How the texel field is pooled before projection; null = chosen from spp and size."),
    ] = None
    units: Annotated[
        vocabulary.TexelUnits,
        In("texel"),
        Doc("texel: θ·∂M/∂θ of each texel; uv_area: per unit UV area (resolution-free)."),
    ] = "texel"


@dataclass(frozen=True)
class ForwardSpec:
    """A forward channel: the image's derivative along one pushed group of parameters (§4).

    The group is a key glob (select), an object's parameters, or a parameter type: one of them.
    """

    name: Annotated[Name, Doc("Unique among forward channels; the EXR layer forward.<name>.")]
    select: Annotated[Text | None, Doc("fnmatch glob over parameter keys.")] = None
    object: Annotated[Text | None, Doc("Every selected parameter of this object.")] = None
    type: Annotated[Text | None, Doc("Every selected parameter of this type.")] = None
    direction: Annotated[
        vocabulary.Direction,
        Doc("value: push v = θ (a proportional change); ones: v = 1 per component."),
    ] = "value"
    transport: Annotated[
        bool, STRICT, Doc("Also write <objective>.transport_<name>.Y for every objective.")
    ] = False

    def __post_init__(self) -> None:
        given = [k for k in ("select", "object", "type") if getattr(self, k) is not None]
        if len(given) != 1:
            raise Problem(
                "give exactly one of select, object or type"
                + (f", not {' and '.join(given)}" if given else ""),
                at=(given[-1],) if len(given) > 1 else (),
            )


Objective = Annotated[ObjectiveSpec, Tagged("type", noun="Objective")]
Channel = Annotated[ChannelSpec, Tagged("kind", noun="Channel")]


@dataclass(frozen=True, kw_only=True)
class JobSpec(Section):
    """A sensaov job: which scene, which objectives, which views of their sensitivities."""

    path: Annotated[Path, JobFilePath]
    version: Annotated[Literal[1], Doc("Job format version.")]
    scene: Annotated[JobFile, Doc("Mitsuba scene XML, relative to the job.")]
    scene_args: SceneArgs = dataclasses.field(default_factory=dict)
    variant: Annotated[vocabulary.Variant, Doc("Mitsuba variant; auto picks one.")] = "auto"
    render: RenderSpec = RenderSpec()
    parameters: ParameterSpec = ParameterSpec()
    repair: RepairSpec = RepairSpec()
    objective_camera: Annotated[
        CameraSpec,
        SensorOrPlaced(PLACED, name="objective"),
        Doc("Sensor id or look_at camera; null = the scene's first sensor."),
    ]
    objectives: Annotated[
        tuple[Objective, ...],
        NonEmpty(),
        unique_names("objective", "objectives"),
        Doc("What to differentiate; one backward pass each."),
    ]
    inspection_cameras: Annotated[
        tuple[InspectionCamera, ...],
        unique_names("inspection camera", "inspection_cameras"),
        Doc("Extra views the sensitivities are shown from."),
    ] = ()
    channels: Annotated[tuple[Channel, ...], unique_names("channel", "channels")] = (
        ChannelSpec("objects", "object"),
        ChannelSpec("types", "type"),
    )
    forward: Annotated[
        tuple[ForwardSpec, ...],
        unique_names("forward channel", "forward"),
        Doc("Forward-mode channels: one forward pass each (more with transport)."),
    ] = ()
    views: ViewsSpec = ViewsSpec()
    output: Annotated[
        OutputDir, Doc("Output directory, relative to the job; null = out/<job stem>.")
    ]

    @property
    def wants_forward(self) -> bool:
        """Whether the job asks for any forward pass: a forward channel or a transport one."""
        return bool(self.forward) or any(c.kind == "transport" for c in self.channels)

    def projected_cameras(self) -> tuple[CameraSpec, ...]:
        """The cameras ``project`` paints: the inspection cameras, with the objective camera
        first unless one of them already is it."""
        cameras = self.inspection_cameras
        if any(camera.objective for camera in cameras):
            return cameras
        return (CameraSpec("objective", objective=True), *cameras)

    def input_files(self) -> tuple[Path, ...]:
        """The files the job itself names: the job file, objectives' masks and targets (the
        scene's files are the prepared scene's ``files``)."""
        named = [(o.mask, o.target) for o in self.objectives]
        return (self.path, *(path for pair in named for path in pair if path is not None))

    def to_dict(self) -> dict[str, Any]:
        """The whole spec as a canonical JSON-able dict (absolute paths as strings)."""
        return dict(_jsonable(dataclasses.asdict(self), None))

    def job_hash(self) -> str:
        """sha256 of the spec without ``path``, its paths relative to the job's directory: the
        same job next to the same files hashes the same wherever the project lies."""
        fields = _jsonable(dataclasses.asdict(self), self.path.parent)
        del fields["path"]
        return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()

    def run_hash(self) -> str:
        """sha256 of what ``sensaov run`` reads of the job: the :meth:`job_hash` fields less the
        ones only later commands read (inspection cameras, placement and texel channels, views,
        the output folder). A buffer records it as ``run_version``: ``project`` and ``report``
        accept a buffer only from a job whose run_hash is the same (docs/buffer-format.md)."""
        fields = _jsonable(dataclasses.asdict(self), self.path.parent)
        for later in ("path", "inspection_cameras", "views", "output"):
            del fields[later]
        fields["channels"] = [c for c in fields["channels"] if c["kind"] == "transport"]
        return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()


def _jsonable(value: Any, relative_to: Path | None) -> Any:
    if isinstance(value, dict):
        return {key: _jsonable(item, relative_to) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(item, relative_to) for item in value]
    if isinstance(value, Path):
        return str(value) if relative_to is None else os.path.relpath(value, relative_to)
    return value
