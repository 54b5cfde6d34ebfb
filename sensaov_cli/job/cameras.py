"""The cameras of a job: a scene sensor, a look_at camera, or the objective camera itself.

A job names one objective camera (which defines the image differentiated) and any number of
inspection cameras (which only look at the result, paper Fig. 6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

from sensaov_cli.job.fields import Fov, Name, Resolution, Text, TrueFlag, Vector, VisSpp
from sensaov_cli.job.markers import After, Doc, In, Section, TaggedByKey
from sensaov_cli.job.problems import Problem

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
    """A camera: a scene sensor, a look_at camera, or (inspection only) the objective camera.

    The objective camera is named "objective"; with neither sensor nor look_at it is the
    scene's first sensor.
    """

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
