"""The query strings of ``sensaov view``'s interface, read into requests or refused in one line.

Every value is checked before anything is traced: a number must be finite and in its range, a
camera must be one a job could hold (target apart from origin, up not along the view), a name
must be one the buffer knows. A refusal is a :class:`~sensaov_cli.errors.RequestError`, which
the server answers with HTTP 400 and its message. Parameters left out take the objective
camera's values and the defaults below.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from sensaov_cli.errors import RequestError
from sensaov_cli.job.markers import Problem
from sensaov_cli.job.spec import LookAt
from sensaov_cli.live.inspection import SCALE_MODES, Look
from sensaov_cli.render.viewpoint import Pose
from sensaov_cli.vocabulary import SIGNS

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
            raise RequestError(f"unknown parameter {key!r}", hint=f"known: {', '.join(known)}")
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
    parts = values[key].split(",")
    try:
        x, y, z = (_finite(key, part) for part in parts)
    except (RequestError, ValueError):
        given = values[key]
        raise RequestError(f"{key} must be three finite numbers x,y,z, got {given!r}") from None
    return (x, y, z)


def _finite(key: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise RequestError(f"{key} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise RequestError(f"{key} must be finite, got {text!r}")
    return value


def _integer(values: Mapping[str, str], key: str, default: int, low: int, high: int) -> int:
    if key not in values:
        return default
    text = values[key]
    if not text.strip().lstrip("+-").isdigit():
        raise RequestError(f"{key} must be an integer, got {text!r}")
    value = int(text)
    if not low <= value <= high:
        raise RequestError(f"{key} {value} is outside [{low}, {high}]")
    return value


def _choice(values: Mapping[str, str], key: str, default: str, valid: Sequence[str]) -> str:
    value = values.get(key, default)
    if value not in valid:
        raise RequestError(f"{key} must be one of {', '.join(valid)}, got {value!r}")
    return value
