"""``sensaov view``: the buffer and the scene loaded once, then any viewpoint on request.

Deferred shading made interactive (§2, §3 "Binding", Fig. 6): each view is one
primary-visibility pass from a free camera (:mod:`sensaov_cli.render.viewpoint`, one compiled
kernel for every pose) plus painting from the stored buffer; no derivative is ever computed.
:class:`ViewSession` answers the interface of docs/view.md with plain values; the HTTP server
(:mod:`.view_server`) only routes to it. Renders run one at a time (one lock): the renderer is
not re-entrant, and one user's page sends one request at a time anyway.
"""

from __future__ import annotations

import json
import threading
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from sensaov_cli.buffer.identity import buffer_id
from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import RequestError, UnknownNameError
from sensaov_cli.job.spec import JobSpec
from sensaov_cli.live.images import exr_bytes, id_map_bytes, png_bytes, view_rgb
from sensaov_cli.live.inspection import InspectionView, paint_image, paint_texel, paint_view
from sensaov_cli.live.job_scales import JobScales
from sensaov_cli.live.object_parameters import object_parameters
from sensaov_cli.live.query import (
    PICK_KEYS,
    VIEW_KEYS,
    ViewRequest,
    pick_request,
    single_values,
    view_request,
)
from sensaov_cli.live.sources import Sources, StoredImage, TexelPanel
from sensaov_cli.outputs.provenance import made_by
from sensaov_cli.pipeline import project_texels
from sensaov_cli.pipeline.consistency import check_buffer_of_job
from sensaov_cli.pipeline.project import check_fingerprint, check_objects
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import LoadedScene, load_scene
from sensaov_cli.render.memory import check_view
from sensaov_cli.render.viewpoint import Pose, ViewTracer, scene_bounds, sensor_pose
from sensaov_cli.scene import prepare_scene
from sensaov_cli.views.channels import ChannelValues
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.sunburst_geometry import panels
from sensaov_cli.views.trusted import weakest_trust

META_FORMAT = "sensaov-view"
META_VERSION = 1
REST_SPP = 16  # what the page asks for once the mouse rests
CACHED_PASSES = 8  # visibility passes kept: a pick or an id map reuses the view's own pass
OBJECTIVE_POSE = "objective"  # the name project gives the objective camera too
SAME_POSE = 1e-4  # relative: a camera this close to the objective camera is that camera


@dataclass(frozen=True)
class Answer:
    body: bytes
    content_type: str
    headers: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class NamedPose:
    name: str
    pose: Pose
    size: tuple[int, int]


class ViewSession:
    """Everything loaded once; each method answers one request of the interface."""

    def __init__(
        self, job: JobSpec, buffer: SensitivityBuffer, buffer_path: Path, loaded: LoadedScene
    ):
        self.job, self.buffer, self.buffer_path, self.loaded = job, buffer, buffer_path, loaded
        self.sources = Sources(
            job, buffer, buffer_path, project_texels.prepare(job, buffer, loaded)
        )
        self.tracer = ViewTracer(loaded.mi, loaded.scene, buffer.objects)
        self.bounds = scene_bounds(loaded.scene)
        self.cameras = _cameras(job, loaded, self.bounds)
        self.buffer_id = buffer_id(buffer)  # the id project, report and rank --exr check
        self.saved: list[Path] = []
        self._lock = threading.Lock()
        self.scales = JobScales(job, buffer, loaded, self._lock)
        self._passes: OrderedDict[tuple[Any, ...], VisibilityPass] = OrderedDict()

    @property
    def objective_camera(self) -> NamedPose:
        return self.cameras[0]

    def meta(self) -> dict[str, Any]:
        first = self.objective_camera
        return {
            "format": META_FORMAT,
            "format_version": META_VERSION,
            "job": str(self.job.path),
            "buffer": str(self.buffer_path),
            "buffer_id": self.buffer_id,
            "objectives": [o.name for o in self.buffer.objectives],
            "objective_values": {o.name: o.value for o in self.buffer.objectives},
            "channels": self.sources.names(),
            "objective_camera_only": self.sources.objective_only(),
            "cameras": [_camera_json(c) for c in self.cameras],
            "bounds": {"min": list(self.bounds[0]), "max": list(self.bounds[1])},
            "objects": list(self.buffer.objects),
            "materials": {o: self.loaded.prepared.materials.get(o, o) for o in self.buffer.objects},
            "defaults": {
                "width": first.size[0],
                "height": first.size[1],
                "spp": 1,
                "rest_spp": REST_SPP,
            },  # fmt: skip
            "made_by": made_by("view"),
        }

    def view(self, query: dict[str, list[str]]) -> Answer:
        request = self.request(single_values(query, VIEW_KEYS))
        start = time.perf_counter()
        visibility, shown = self._paint(request)
        if request.format == "ids":
            body, kind = id_map_bytes(visibility.rank_index), "application/octet-stream"
        elif request.format == "exr":
            layer = f"{request.objective}.{_token(request.channel)}"
            body = exr_bytes(layer, shown.values, self._describe(request, shown))
            kind = "image/x-exr"
        else:
            rgb = view_rgb(shown.display, shown.coverage, shown.unverified)
            body, kind = png_bytes(rgb, self._describe(request, shown)), "image/png"
        headers = {
            "X-Sensaov-Legend": json.dumps(_legend_json(shown), ensure_ascii=True),
            "X-Sensaov-Size": f"{visibility.width}x{visibility.height}",
            "X-Sensaov-Ms": f"{1000 * (time.perf_counter() - start):.1f}",
        }
        return Answer(body, kind, headers)

    def pick(self, query: dict[str, list[str]]) -> dict[str, Any]:
        values = single_values(query, PICK_KEYS)
        camera = {k: v for k, v in values.items() if k not in ("x", "y", "object")}
        pick = pick_request(self.request(camera), values)
        request = pick.view
        if pick.x is None or pick.y is None:
            found = pick.object
            if found not in self.buffer.objects:
                raise UnknownNameError("object", str(found), self.buffer.objects)
            return {"objective": request.objective, "channel": request.channel,
                    "object": found, "material": self.loaded.prepared.materials.get(found, found),
                    **self._object_summary(request, found)}  # fmt: skip
        visibility, shown = self._paint(request)
        with self._lock:
            hit = self.tracer.hit(request.pose, request.width, request.height, pick.x, pick.y)
        index = visibility.rank_index[pick.y, pick.x]
        amount = visibility.rank_coverage[pick.y, pick.x]
        coverage = [
            {"object": self.buffer.objects[i], "coverage": float(c)}
            for i, c in zip(index, amount, strict=True)
            if i >= 0
        ]
        found = coverage[0]["object"] if coverage else None
        return {
            "objective": request.objective,
            "channel": request.channel,
            "x": pick.x,
            "y": pick.y,
            "object": found,
            "material": self.loaded.prepared.materials.get(found, found) if found else None,
            "coverage": coverage,
            "position": None if hit.position is None else list(hit.position),
            "distance": hit.distance,
            "value": float(shown.values[pick.y, pick.x]),
            **(self._object_summary(request, found) if found else {}),
        }

    def sunburst(self, query: dict[str, list[str]]) -> dict[str, Any]:
        values = single_values(query, ("objective",))
        name = values.get("objective", self.buffer.objectives[0].name)
        self.buffer.objective(name)
        (panel,) = panels(self.buffer, [name])
        return {
            "objective": panel.objective,
            "value": panel.value,
            "wedges": [asdict(w) for w in panel.wedges],
            "no_gradient": list(panel.no_gradient),
        }

    def request(self, values: dict[str, str]) -> ViewRequest:
        first = self.objective_camera
        objective, channel = self.buffer.objectives[0].name, self.sources.names()[0]
        return view_request(values, first.pose, first.size[0] / first.size[1], objective, channel)

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

    def visibility(self, request: ViewRequest, with_uv: bool = False) -> VisibilityPass:
        """The visibility pass of a request's camera, traced once and kept for picks (a pass
        with UVs serves a request without them too)."""
        key = (request.pose, request.width, request.height, request.spp)
        with self._lock:
            for uv in (True, False) if not with_uv else (True,):
                if (*key, uv) in self._passes:
                    self._passes.move_to_end((*key, uv))
                    return self._passes[(*key, uv)]
            size = (request.width, request.height, request.spp)
            check_view(  # a request is a stranger's numbers: refused (400) before allocating
                request.width * request.height, request.spp, layers=1, texels=with_uv,
                setting=f"width x height = {request.width}x{request.height} at spp = {request.spp}",
            )  # fmt: skip
            traced = self.tracer.trace(request.pose, *size, with_uv=with_uv)
            self._passes[(*key, with_uv)] = traced
            while len(self._passes) > CACHED_PASSES:
                self._passes.popitem(last=False)
            return traced

    def is_objective_pose(self, pose: Pose) -> bool:
        first = self.objective_camera.pose
        given = (*pose.look_at.origin, *_direction(pose), *pose.look_at.up, pose.fov)
        wanted = (*first.look_at.origin, *_direction(first), *first.look_at.up, first.fov)
        scale = max(1.0, *(abs(v) for v in wanted))
        return all(abs(a - b) <= SAME_POSE * scale for a, b in zip(given, wanted, strict=True))

    def _object_summary(self, request: ViewRequest, obj: str) -> dict[str, Any]:
        source = self.sources.find(request.objective, request.channel)
        weight = source.spec.weight if isinstance(source, ChannelValues) else "value"
        rows = object_parameters(self.buffer, request.objective, obj, weight)
        summary: dict[str, Any] = {
            "weight": weight,
            "parameters": [asdict(r) for r in rows],
            "trust": weakest_trust(self.buffer, [r.key for r in rows]) if rows else "verified",
        }
        if isinstance(source, ChannelValues):
            index = self.buffer.objects.index(obj)
            order = sorted(range(len(source.magnitudes)), key=lambda i: -source.magnitudes[i])
            summary.update(
                object_score=float(source.magnitudes[index]),
                object_signed=float(source.signed_sums[index]),
                object_rank=order.index(index) + 1,
                objects_ranked=int((source.magnitudes > 0).sum()),
            )
        return summary

    def _describe(self, request: ViewRequest, shown: InspectionView) -> dict[str, str]:
        """How a view was made, for the PNG's text chunks and the EXR's header."""
        look = request.pose.look_at
        return {
            "sensaov/made_by": json.dumps(made_by("view")),
            "sensaov/objective": request.objective,
            "sensaov/channel": request.channel,
            "sensaov/encoding": shown.legend.encoding,
            "sensaov/scale": f"{shown.legend.scale_mode};{shown.legend.scale.describe()}",
            "sensaov/camera": json.dumps(
                {
                    "origin": look.origin,
                    "target": look.target,
                    "up": look.up,
                    "fov": request.pose.fov,
                }
            ),  # fmt: skip
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


def _cameras(job: JobSpec, loaded: LoadedScene, bounds: tuple[Any, Any]) -> list[NamedPose]:
    """The objective camera first, then the job's other inspection cameras, as poses."""
    mi = loaded.mi
    found = [NamedPose(OBJECTIVE_POSE, sensor_pose(mi, loaded.sensor, bounds), loaded.resolution)]
    for camera in job.inspection_cameras:
        if camera.objective or camera.name == OBJECTIVE_POSE:
            continue
        sensor = loaded.inspection_sensors[camera.name]
        size = sensor.film().crop_size()
        if camera.look_at is not None:
            pose = Pose(camera.look_at, camera.fov)
        else:
            pose = sensor_pose(mi, sensor, bounds)
        found.append(NamedPose(camera.name, pose, (int(size[0]), int(size[1]))))
    return found


def _camera_json(camera: NamedPose) -> dict[str, Any]:
    look = camera.pose.look_at
    return {
        "name": camera.name,
        "origin": list(look.origin),
        "target": list(look.target),
        "up": list(look.up),
        "fov": camera.pose.fov,
        "width": camera.size[0],
        "height": camera.size[1],
        "note": camera.pose.note,
    }


def _legend_json(shown: InspectionView) -> dict[str, Any]:
    legend = shown.legend
    return {
        "encoding": legend.encoding,
        "scale_mode": legend.scale_mode,
        "peak": legend.peak,
        "threshold": legend.scale.threshold,
        "stops": [list(stop) for stop in legend.stops],
        "unverified": list(legend.unverified),
        "invisible": list(legend.invisible),
        "notes": list(legend.notes),
    }


def _direction(pose: Pose) -> tuple[float, ...]:
    look = pose.look_at
    d = [t - o for t, o in zip(look.target, look.origin, strict=True)]
    norm = sum(v * v for v in d) ** 0.5
    return tuple(v / norm for v in d)


def _token(name: str) -> str:
    return "".join(c if c.isalnum() or c == "_" else "_" for c in name)
