"""``sensaov view``: the buffer and the scene loaded once, then any viewpoint on request.

Deferred shading made interactive (§2, §3 "Binding", Fig. 6): each view is one
primary-visibility pass from a free camera (one compiled kernel for every pose) plus painting
from the stored buffer; no derivative is ever computed. The forward and transport layers are
images of the objective camera that no other viewpoint can re-project (§4, §7). Renders run one
at a time (one lock): the renderer is not re-entrant, and one user's page sends one request at
a time anyway.
"""

from __future__ import annotations

import json
import math
import re
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import cast

import numpy as np

from sensaov_cli.buffer.forward_sidecar import check_belongs, read_forward
from sensaov_cli.buffer.model import SensitivityBuffer, buffer_id
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.queries import select
from sensaov_cli.buffer.statistics import whole_run
from sensaov_cli.errors import RequestError, UnknownNameError
from sensaov_cli.job.markers import Problem
from sensaov_cli.job.spec import ChannelSpec, JobSpec, LookAt
from sensaov_cli.live.inspection import (
    SCALE_MODES,
    InspectionView,
    Legend,
    Look,
    ObjectSummary,
    object_summary,
    paint_image,
    paint_texel,
    paint_view,
    view_rgb,
)
from sensaov_cli.live.view_memory import MemoryLedger, request_bytes, return_freed_memory
from sensaov_cli.outputs.atomic import made_by
from sensaov_cli.outputs.exr import encode_exr
from sensaov_cli.outputs.previews import encode_png
from sensaov_cli.pipeline.project import (
    check_buffer_of_job,
    check_fingerprint,
    check_objects,
    prepare_texel_fields,
    trace_camera,
)
from sensaov_cli.pipeline.run import FORWARD_NAME
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import LoadedScene, check_view, load_scene
from sensaov_cli.render.visibility import Pose, Vec3, ViewTracer, scene_bounds, sensor_pose
from sensaov_cli.scene import prepare_scene
from sensaov_cli.views.channels import (
    ChannelValues,
    DisplayScale,
    channel_values,
    forward_views,
    shared_channel_scale,
    transport_views,
)
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.hierarchy import Panel, panels
from sensaov_cli.views.texels import PANELS, TexelField, texture_token
from sensaov_cli.vocabulary import SIGNS, Sign

REST_SPP = 16  # what the page asks for once the mouse rests
OBJECTIVE_POSE = "objective"  # the name project gives the objective camera too
SAME_POSE = 1e-4  # relative: a camera this close to the objective camera is that camera
SELECT_PREFIX = "select:"
OBJECTS = ChannelSpec("objects", "object")  # offered even when a job lists no object channel


# The query strings of the interface (docs/view.md): every value is checked before anything is
# traced (a number finite and in its range, a camera one a job could hold, a name one the buffer
# knows); a refusal is a RequestError, which the server answers with HTTP 400. Parameters left
# out take the objective camera's values and the defaults below.
MAX_SIDE = 2048  # a live view; larger images are `sensaov project`'s work
MAX_SPP = 256
DEFAULT_WIDTH = 256
FORMATS = ("png", "exr", "ids")
POSE_KEYS = ("origin", "target", "up", "fov", "width", "height")
VIEW_KEYS = ("objective", "channel", *POSE_KEYS, "spp", "sign", "compressive", "scale", "format")
PICK_KEYS = (*VIEW_KEYS, "x", "y", "object")
CAMERA_KEYS = (*VIEW_KEYS, "name")  # a viewpoint shown or saved as a job's camera
SUNBURST_KEYS = ("objective",)

Query = Mapping[str, Sequence[str]]
# A number in a query is ASCII digits (str.isdigit and float accept '²' and other scripts' digits)
# and short: what no camera needs is refused before Python converts it.
_INTEGER = re.compile(r"[+-]?[0-9]+", re.ASCII)
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
MAX_NUMBER_CHARS = 32
SHOWN_CHARS = 40  # of a refused value, in the one line that refuses it


@dataclass(frozen=True)
class ViewRequest:
    objective: str
    channel: str
    pose: Pose
    width: int
    height: int
    spp: int
    look: Look
    format: str


@dataclass(frozen=True)
class PickRequest:
    """A pixel (x, y from the top left), or an object by name (a click on its wedge)."""

    view: ViewRequest
    x: int | None
    y: int | None
    object: str | None = None


def single_values(query: Query, known: Sequence[str]) -> dict[str, str]:
    """Each parameter's one value; an unknown or repeated parameter is refused."""
    values = {}
    for key, given in query.items():
        if key not in known:
            raise RequestError(
                f"unknown parameter {_shown(key)}", hint=f"known: {', '.join(known)}"
            )
        if len(given) != 1:
            raise RequestError(f"parameter {key!r} is given {len(given)} times")
        values[key] = given[0]
    return values


def view_request(
    values: Mapping[str, str], default_pose: Pose, aspect: float, objective: str, channel: str
) -> ViewRequest:
    """A view request; ``aspect`` (width / height) sets a height left out."""
    width = _integer(values, "width", DEFAULT_WIDTH, 1, MAX_SIDE)
    height = _integer(values, "height", max(1, round(width / aspect)), 1, MAX_SIDE)
    sign = _choice(values, "sign", "signed", SIGNS)
    compressive = _choice(values, "compressive", "0", ("0", "1", "false", "true")) in ("1", "true")
    look = Look(sign, compressive, _choice(values, "scale", "shared", SCALE_MODES))
    return ViewRequest(
        objective=values.get("objective", objective),
        channel=values.get("channel", channel),
        pose=pose(values, default_pose),
        width=width,
        height=height,
        spp=_integer(values, "spp", 1, 1, MAX_SPP),
        look=look,
        format=_choice(values, "format", "png", FORMATS),
    )


def pick_request(view: ViewRequest, values: Mapping[str, str]) -> PickRequest:
    """The pixel or the object of a pick; ``view`` is the same values read as a view."""
    if "object" in values:
        if "x" in values or "y" in values:
            raise RequestError("a pick takes either x and y or object, not both")
        return PickRequest(view, None, None, values["object"])
    if "x" not in values or "y" not in values:
        raise RequestError("a pick needs x and y (the pixel, from the top left) or object")
    x = _integer(values, "x", 0, 0, view.width - 1)
    y = _integer(values, "y", 0, 0, view.height - 1)
    return PickRequest(view, x, y)


def pose(values: Mapping[str, str], default: Pose) -> Pose:
    """The camera of a request, from the objective camera's where a value is left out."""
    fov = _finite("fov", values["fov"]) if "fov" in values else default.fov
    if not 0.0 < fov < 180.0:
        raise RequestError(f"fov {fov:g} is outside (0, 180) degrees")
    base = default.look_at
    try:
        look_at = LookAt(
            _vector(values, "origin", base.origin),
            _vector(values, "target", base.target),
            _vector(values, "up", base.up),
        )
    except Problem as problem:
        raise RequestError(f"bad camera: {problem.message}") from None
    return Pose(look_at, fov)


def _vector(
    values: Mapping[str, str], key: str, default: tuple[float, float, float]
) -> tuple[float, float, float]:
    if key not in values:
        return default
    given = values[key]
    try:
        x, y, z = (_finite(key, part) for part in given.split(","))
    except (RequestError, ValueError):
        raise RequestError(
            f"{key} must be three finite numbers x,y,z, got {_shown(given)}"
        ) from None
    return (x, y, z)


def _finite(key: str, text: str) -> float:
    if len(text) > MAX_NUMBER_CHARS or not _NUMBER.fullmatch(text):
        word = text.lower().lstrip("+-") in ("nan", "inf", "infinity")
        raise RequestError(f"{key} must be {'finite' if word else 'a number'}, got {_shown(text)}")
    value = float(text)
    if not math.isfinite(value):
        raise RequestError(f"{key} must be finite, got {_shown(text)}")
    return value


def _integer(values: Mapping[str, str], key: str, default: int, low: int, high: int) -> int:
    if key not in values:
        return default
    text = values[key]
    if not _INTEGER.fullmatch(text):
        raise RequestError(f"{key} must be an integer, got {_shown(text)}")
    if len(text.lstrip("+-0")) > len(str(high)):  # far out of range: never converted
        raise RequestError(f"{key} {_shown(text)} is outside [{low}, {high}]")
    value = int(text)
    if not low <= value <= high:
        raise RequestError(f"{key} {value} is outside [{low}, {high}]")
    return value


def _choice(values: Mapping[str, str], key: str, default: str, valid: Sequence[str]) -> str:
    value = values.get(key, default)
    if value not in valid:
        raise RequestError(f"{key} must be one of {', '.join(valid)}, got {_shown(value)}")
    return value


def _shown(text: str) -> str:
    """A stranger's value as a refusal quotes it: its start only when it is long."""
    if len(text) <= SHOWN_CHARS:
        return repr(text)
    return f"{text[:SHOWN_CHARS]!r}… ({len(text):,} characters)"


@dataclass(frozen=True)
class NamedPose:
    name: str
    pose: Pose
    size: tuple[int, int]


@dataclass(frozen=True)
class Picture:
    """A view in the format asked for, with the legend it is drawn with."""

    body: bytes
    content_type: str
    legend: Legend
    size: tuple[int, int]  # width, height
    ms: float  # painting and encoding, in milliseconds


@dataclass(frozen=True)
class Pixel:
    """What a clicked pixel holds: the objects' coverage, the centre ray's hit, the value."""

    x: int
    y: int
    coverage: tuple[tuple[str, float], ...]  # (object, share of the samples), largest first
    position: Vec3 | None
    distance: float | None
    value: float  # the painted value, in the channel's units


@dataclass(frozen=True)
class Pick:
    """A click: on a pixel, or on an object by name (a wedge of the sunburst)."""

    objective: str
    channel: str
    object: str | None  # None: no object under the pixel
    material: str | None
    pixel: Pixel | None  # None: picked by name
    summary: ObjectSummary | None  # None: no object under the pixel


@dataclass(frozen=True, eq=False)
class StoredImage:
    """A layer of the objective camera: ``data`` (H, W), linear, with what it is."""

    name: str
    kind: str  # "forward" | "transport"
    data: np.ndarray
    unverified: tuple[str, ...]
    note: str  # the duality check of a transport layer; the colour reduction of a forward one


@dataclass(frozen=True, eq=False)
class TexelPanel:
    """One of Fig. 4's panels of a texel field: painted through the hit UVs of each view."""

    field: TexelField
    panel: str  # "object" | "texel" | "joint"


Source = ChannelValues | StoredImage | TexelPanel


class ViewSession:
    """Everything loaded once; each method answers one request of the interface."""

    def __init__(
        self, job: JobSpec, buffer: SensitivityBuffer, buffer_path: Path, loaded: LoadedScene
    ):
        self.job, self.buffer, self.buffer_path, self.loaded = job, buffer, buffer_path, loaded
        self.sources = Sources(job, buffer, buffer_path, prepare_texel_fields(job, buffer, loaded))
        self.tracer = ViewTracer(loaded.mi, loaded.scene, buffer.objects)
        self.bounds = scene_bounds(loaded.scene)
        self.cameras = _cameras(job, loaded, self.bounds)
        self.buffer_id = buffer_id(buffer)  # the id project, report and rank --exr check
        self._lock = threading.Lock()
        self.scales = JobScales(job, buffer, loaded, self._lock)
        self.memory = MemoryLedger()

    @property
    def objective_camera(self) -> NamedPose:
        return self.cameras[0]

    def material(self, obj: str) -> str:
        return self.loaded.prepared.materials.get(obj, obj)

    def request(self, values: dict[str, str]) -> ViewRequest:
        """A view request from a query's values, the objective camera's where one is left out."""
        first = self.objective_camera
        objective, channel = self.buffer.objectives[0].name, self.sources.names()[0]
        return view_request(values, first.pose, first.size[0] / first.size[1], objective, channel)

    def view(self, request: ViewRequest) -> Picture:
        with self._reserved(request):
            return self._view(request)

    def _view(self, request: ViewRequest) -> Picture:
        start = time.perf_counter()
        visibility, shown = self._paint(request)
        if request.format == "ids":  # per pixel, the most covering object's index (-1: none)
            body = np.ascontiguousarray(visibility.rank_index[..., 0], dtype="<i4").tobytes()
            kind = "application/octet-stream"
        elif request.format == "exr":  # the raw layer, linear, in the channel's units
            token = "".join(c if c.isalnum() or c == "_" else "_" for c in request.channel)
            layer = {f"{request.objective}.{token}.Y": shown.values}
            body, kind = encode_exr(layer, self._describe(request, shown)), "image/x-exr"
        else:  # fast to compress: a view lives for one look
            rgb = view_rgb(shown.display, shown.coverage, shown.unverified, shown.neutral)
            body, kind = encode_png(rgb, self._describe(request, shown), level=1), "image/png"
        ms = 1000 * (time.perf_counter() - start)
        return Picture(body, kind, shown.legend, (visibility.width, visibility.height), ms)

    def pick(self, pick: PickRequest) -> Pick:
        request = pick.view
        if pick.x is None or pick.y is None:
            found = str(pick.object)
            if found not in self.buffer.objects:
                raise UnknownNameError("object", found, self.buffer.objects)
            return self._picked(request, found, None)
        with self._reserved(request):
            visibility, shown = self._paint(request)
            with self._lock:
                hit = self.tracer.hit(request.pose, request.width, request.height, pick.x, pick.y)
            index = visibility.rank_index[pick.y, pick.x]
            amount = visibility.rank_coverage[pick.y, pick.x]
            value = float(shown.values[pick.y, pick.x])
        coverage = tuple(
            (self.buffer.objects[i], float(c)) for i, c in zip(index, amount, strict=True) if i >= 0
        )
        pixel = Pixel(pick.x, pick.y, coverage, hit.position, hit.distance, value)
        return self._picked(request, coverage[0][0] if coverage else None, pixel)

    def sunburst(self, objective: str | None) -> Panel:
        name = self.buffer.objectives[0].name if objective is None else objective
        self.buffer.objective(name)
        (panel,) = panels(self.buffer, [name])
        return panel

    def _picked(self, request: ViewRequest, found: str | None, pixel: Pixel | None) -> Pick:
        """The pick of ``found`` (None: no object under the pixel) on the request's layer."""
        if found is None:
            return Pick(request.objective, request.channel, None, None, pixel, None)
        source = self.sources.find(request.objective, request.channel)
        channel = source if isinstance(source, ChannelValues) else None
        summary = object_summary(self.buffer, request.objective, found, channel)
        return Pick(request.objective, request.channel, found, self.material(found), pixel, summary)

    def _paint(self, request: ViewRequest) -> tuple[VisibilityPass, InspectionView]:
        source = self.sources.find(request.objective, request.channel)
        visibility = self.visibility(request, with_uv=isinstance(source, TexelPanel))
        if isinstance(source, TexelPanel):
            return visibility, paint_texel(source.field, source.panel, visibility, request.look)
        if isinstance(source, StoredImage):
            if not self.is_objective_pose(request.pose):
                raise RequestError(
                    f"channel {request.channel!r} is a {source.kind} layer rendered at the "
                    "objective camera by 'sensaov run': it cannot be re-projected to another "
                    "viewpoint (paper §7)",
                    hint="ask for it with the objective camera (leave origin, target, up, fov out)",
                )
            notes = (source.note,) if source.note else ()
            shown = paint_image(source.data, visibility, request.look, source.unverified, notes)
            return visibility, shown
        shared = self.scales.of(source, request.look.sign)
        return visibility, paint_view(self.buffer, source, visibility, request.look, shared)

    @contextmanager
    def _reserved(self, request: ViewRequest) -> Iterator[None]:
        """The request's memory held in the budget while it traces and paints (a request is a
        stranger's numbers: one over the budget is refused, 400, before anything is traced)."""
        with_uv = isinstance(self.sources.find(request.objective, request.channel), TexelPanel)
        pixels = request.width * request.height
        need = request_bytes(pixels, request.spp, with_uv=with_uv)
        setting = f"width x height = {request.width}x{request.height} at spp = {request.spp}"
        with self.memory.reserved(need, setting):
            yield

    def visibility(self, request: ViewRequest, with_uv: bool = False) -> VisibilityPass:
        """The visibility pass of a request's camera, traced once and kept for picks while the
        memory budget has room (a pass with UVs serves a request without them too)."""
        key = (request.pose, request.width, request.height, request.spp)
        with self._lock:
            for uv in (True, False) if not with_uv else (True,):
                kept = self.memory.kept((*key, uv))
                if kept is not None:
                    return kept
            size = (request.width, request.height, request.spp)
            traced = self.tracer.trace(request.pose, *size, with_uv=with_uv)
        self.memory.keep((*key, with_uv), traced)
        return traced

    def is_objective_pose(self, pose: Pose) -> bool:
        first = self.objective_camera.pose
        given = (*pose.look_at.origin, *_direction(pose), *pose.look_at.up, pose.fov)
        wanted = (*first.look_at.origin, *_direction(first), *first.look_at.up, first.fov)
        scale = max(1.0, *(abs(v) for v in wanted))
        return all(abs(a - b) <= SAME_POSE * scale for a, b in zip(given, wanted, strict=True))

    def _describe(self, request: ViewRequest, shown: InspectionView) -> dict[str, str]:
        """How a view was made, for the PNG's text chunks and the EXR's header."""
        look = request.pose.look_at
        camera = {"origin": look.origin, "target": look.target, "up": look.up}
        return {
            "sensaov/made_by": json.dumps(made_by("view")),
            "sensaov/objective": request.objective,
            "sensaov/channel": request.channel,
            "sensaov/encoding": shown.legend.encoding,
            "sensaov/scale": f"{shown.legend.scale_mode};{shown.scale.describe()}",
            "sensaov/camera": json.dumps({**camera, "fov": request.pose.fov}),
            "sensaov/spp": str(request.spp),
            "sensaov/buffer": str(self.buffer_path),
            "sensaov/buffer_id": self.buffer_id,
            "sensaov/unverified": json.dumps(list(shown.legend.unverified)),
        }


def open_session(
    job: JobSpec, *, buffer_path: Path, force: bool, progress: Progress
) -> ViewSession:
    """Read the buffer, prepare and load the scene once (with the job's inspection cameras)."""
    buffer = read_buffer(buffer_path)
    prepared = prepare_scene(job, job.projected_cameras())  # project's cameras: its scales
    check_fingerprint(job, buffer, buffer_path, prepared.fingerprint, force)
    if not force:
        check_buffer_of_job(job, buffer, buffer_path, override="pass --force to view it anyway")
    with progress.stage("load_s", f"loading {job.scene.name}"):
        loaded = load_scene(prepared, variant=job.variant, parameters=job.parameters)
    check_objects(buffer, loaded, buffer_path)
    session = ViewSession(job, buffer, buffer_path, loaded)
    return_freed_memory()
    with progress.stage("warm_s", "compiling the visibility kernel"):
        first = session.objective_camera
        width, height = first.size
        check_view(width * height, REST_SPP, layers=1, texels=False,
                   setting=f"render.resolution = {width}x{height} (traced at {REST_SPP} spp)",
                   where=str(job.path))  # fmt: skip
        for spp in (1, REST_SPP):  # the two kernels a page asks for, compiled before it asks
            session.tracer.trace(first.pose, first.size[0], first.size[1], spp)
    with progress.stage("scales_s", "tracing the job's cameras for its shared scales"):
        session.scales.warm()
    return session


def _cameras(job: JobSpec, loaded: LoadedScene, bounds: tuple[Vec3, Vec3]) -> list[NamedPose]:
    """The objective camera first, then the job's other inspection cameras, as poses."""
    mi = loaded.mi
    found = [NamedPose(OBJECTIVE_POSE, sensor_pose(mi, loaded.sensor, bounds), loaded.resolution)]
    for camera in job.inspection_cameras:
        if camera.objective or camera.name == OBJECTIVE_POSE:
            continue
        sensor = loaded.inspection_sensors[camera.name]
        size = sensor.film().crop_size()
        look_at = camera.look_at
        pose = Pose(look_at, camera.fov) if look_at is not None else sensor_pose(mi, sensor, bounds)
        found.append(NamedPose(camera.name, pose, (int(size[0]), int(size[1]))))
    return found


def _direction(pose: Pose) -> tuple[float, ...]:
    look = pose.look_at
    d = [t - o for t, o in zip(look.target, look.origin, strict=True)]
    norm = sum(v * v for v in d) ** 0.5
    return tuple(v / norm for v in d)


class Sources:
    """Every channel of every objective, by name; typed select queries added on first use.

    Object, type and select channels are per-object values computed once from the buffer and
    painted through any camera; stored images are offered at the objective camera only."""

    def __init__(
        self,
        job: JobSpec,
        buffer: SensitivityBuffer,
        buffer_path: Path,
        fields: list[TexelField],
    ):
        self.buffer = buffer
        has_objects = any(c.kind == "object" for c in job.channels)
        specs = job.channels if has_objects else (OBJECTS, *job.channels)
        self.untrusted = job.views.untrusted
        self.painted = {
            (v.objective, v.pass_name): v
            for v in channel_values(buffer, specs, untrusted=self.untrusted)
        }
        self.images = _stored_images(job, buffer, buffer_path)
        self.texels = {
            (f.objective, f"{f.channel.name}_{texture_token(f.record.key)}_{panel}"): (
                TexelPanel(f, panel)
            )
            for f in fields
            for panel in PANELS
        }  # the names project gives these layers

    def names(self) -> list[str]:
        """Channel names in the order the job lists them, then the stored layers."""
        painted = dict.fromkeys(name for _, name in self.painted)
        texels = dict.fromkeys(name for _, name in self.texels)
        return [*painted, *texels, *self.objective_only()]

    def objective_only(self) -> list[str]:
        return list(dict.fromkeys(name for _, name in self.images))

    def find(self, objective: str, channel: str) -> Source:
        self.buffer.objective(objective)  # UnknownNameError (HTTP 400) names the known ones
        for table in (self.painted, self.texels, self.images):
            if (objective, channel) in table:
                return table[(objective, channel)]
        if channel.startswith(SELECT_PREFIX):
            return self._query(objective, channel)
        raise UnknownNameError("channel", channel, [*self.names(), f"{SELECT_PREFIX}<glob>"])

    def _query(self, objective: str, channel: str) -> ChannelValues:
        glob = channel[len(SELECT_PREFIX) :]
        if not glob or not select(self.buffer, glob=glob):
            raise RequestError(
                f"select query {glob!r} matches no parameter of the buffer",
                hint="globs match keys such as 'white.reflectance.value' or '*.alpha'",
            )
        spec = ChannelSpec(channel, "select", select=glob)  # a name no job channel can have
        for values in channel_values(self.buffer, (spec,), untrusted=self.untrusted):
            part = values.pass_name[len(spec.name) :]  # "" or the untrusted part's suffix
            self.painted[(values.objective, channel + part)] = replace(
                values, pass_name=channel + part
            )
        return self.painted[(objective, channel)]


def _stored_images(
    job: JobSpec, buffer: SensitivityBuffer, buffer_path: Path
) -> dict[tuple[str, str], StoredImage]:
    """The forward and transport layers of the sidecar, under every objective they apply to."""
    path = buffer_path.with_name(FORWARD_NAME)
    if not job.wants_forward or not whole_run(buffer.provenance) or not path.exists():
        return {}
    data = read_forward(path)
    check_belongs(data, buffer, path)
    found: dict[tuple[str, str], StoredImage] = {}
    for f in forward_views(buffer, data):
        if f.data is None:
            continue
        mono = f.data if f.data.ndim == 2 else f.data.mean(axis=2)
        note = "mean of the R, G, B derivatives" if f.data.ndim == 3 else ""
        image = StoredImage(f"forward.{f.name}", "forward", mono, f.unverified, note)
        for objective in buffer.objectives:
            found[(objective.name, image.name)] = image
    for t in transport_views(buffer, data):
        verdict = "agrees" if t.agrees else "EXCEEDS TOLERANCE: do not trust this layer"
        note = f"duality residual {t.residual:.2e} (tolerance {t.tolerance:.0e}): {verdict}"
        found[(t.objective, t.name)] = StoredImage(t.name, "transport", t.data, t.unverified, note)
    return found


class JobScales:
    """The job's shared display scale of each painted channel, under either sign: read over
    every camera ``project`` paints, traced as it traces them (same spp, same seed), so the
    page's colours are those of its previews and EXR display layers
    (:func:`~sensaov_cli.views.channels.shared_channel_scale`). The cameras are traced
    once, on opening; each (objective, channel, sign) is computed once."""

    def __init__(
        self, job: JobSpec, buffer: SensitivityBuffer, loaded: LoadedScene, lock: threading.Lock
    ):
        self.job, self.buffer, self.loaded, self._lock = job, buffer, loaded, lock
        self._passes: dict[str, VisibilityPass] = {}
        self._scales: dict[tuple[str, ChannelSpec, str], DisplayScale] = {}

    def of(self, values: ChannelValues, sign: str) -> DisplayScale:
        """The shared scale of ``values``' (objective, channel), its pixels painted ``sign``
        (signed or magnitude), linear: the job's own encoding when it is the default one.
        Kept by what the channel is (its selection, weight, aggregate), never by its name: a
        job's channel and a typed query may share a name, not a scale."""
        key = (values.objective, replace(values.spec, name=""), sign)
        with self._lock:  # the renderer is not re-entrant
            if key not in self._scales:
                linear = replace(
                    values.spec, sign=cast(Sign, sign), tonemap="none", normalize="none"
                )
                self._scales[key] = shared_channel_scale(
                    self.buffer, linear, values.objective, self._visibilities(),
                    untrusted=self.job.views.untrusted, percentile=self.job.views.percentile,
                )  # fmt: skip
            return self._scales[key]

    def warm(self) -> None:
        """Trace the cameras now (``open_session``), not on the page's first request."""
        with self._lock:
            self._visibilities()

    def _visibilities(self) -> dict[str, VisibilityPass]:
        if not self._passes:
            self._passes = {
                camera.name: trace_camera(self.job, self.buffer, self.loaded, camera, False)
                for camera in self.job.projected_cameras()
            }
        return self._passes
