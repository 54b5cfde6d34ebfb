"""A free inspection camera for ``sensaov view``: primary visibility from any viewpoint, fast.

Dr.Jit bakes literal constants into its kernels (MITSUBA-NOTES): every number that changes
between views (frame, field of view, image size, spp, seed) enters the trace as an opaque
variable, so every view after the first reuses the compiled kernel. Rays follow Mitsuba's
``perspective`` sensor with ``fov_axis`` x, so a viewpoint saved as a job's ``look_at`` camera
renders the same picture in ``sensaov project``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from sensaov_cli.job.spec import LookAt
from sensaov_cli.render.visibility import hits, object_index, object_of_registry_id, visibility_pass
from sensaov_cli.views.coverage import VisibilityPass

Vec3 = tuple[float, float, float]
NEAR_CLIP = 0.01  # Mitsuba's perspective default, which a job's look_at camera gets


@dataclass(frozen=True)
class Pose:
    """A camera as a job writes it: ``look_at`` plus the horizontal field of view in degrees."""

    look_at: LookAt
    fov: float
    note: str = ""  # what the pose leaves out of the scene's own sensor, if anything


@dataclass(frozen=True)
class Frame:
    """A pinhole's frame in world space: origin, unit axes, and the tangents of its half fields."""

    origin: list[float]
    forward: list[float]
    right: list[float]
    up: list[float]
    tan_x: float
    tan_y: float


@dataclass(frozen=True)
class Hit:
    """What the ray through a pixel's centre meets: an object index (-1: none) and where."""

    index: int
    position: Vec3 | None
    distance: float | None


class ViewTracer:
    """Primary visibility of one loaded scene from any pose, one compiled kernel for all."""

    def __init__(self, mi: ModuleType, scene: Any, objects: tuple[str, ...]):
        self.mi, self.scene, self.objects = mi, scene, objects
        self._table = mi.Int32(object_of_registry_id(mi, scene, objects))

    def trace(
        self, pose: Pose, width: int, height: int, spp: int, seed: int = 0, *, with_uv: bool = False
    ) -> VisibilityPass:
        """``spp`` rays per pixel (stratified, jittered; the pixel centre at 1 spp), with each
        sample's object and hit UV when ``with_uv`` (texel channels read them)."""
        import drjit as dr

        with dr.suspend_grad():
            ray = self._rays(pose, width, height, spp, seed)
            samples, uv = hits(self.mi, self.scene, ray, self._table, with_uv)
        return visibility_pass(self.objects, samples, uv, width, height, spp)

    def hit(self, pose: Pose, width: int, height: int, x: int, y: int) -> Hit:
        """The ray through the centre of pixel (x, y): the object there, the point and distance."""
        import drjit as dr

        mi = self.mi
        with dr.suspend_grad():
            frame = _frame(pose, width, height)
            u = dr.opaque(mi.Float, (x + 0.5) / width)
            v = dr.opaque(mi.Float, (y + 0.5) / height)
            ray = self._ray(frame, mi.Point2f(u, v))
            si = self.scene.ray_intersect(ray)
            index = int(np.array(object_index(mi, si, self._table))[0])
            if not bool(np.array(si.is_valid())[0]):
                return Hit(index, None, None)
            return Hit(index, _vec(np.array(si.p)), float(np.array(si.t)[0]))

    def _rays(self, pose: Pose, width: int, height: int, spp: int, seed: int) -> Any:
        import drjit as dr

        mi = self.mi
        n = width * height * spp
        w, s = dr.opaque(mi.UInt32, width), dr.opaque(mi.UInt32, spp)
        side = dr.opaque(mi.UInt32, math.ceil(math.sqrt(spp)))
        index = dr.arange(mi.UInt32, n)
        pixel, sample = index // s, index % s
        rng = mi.PCG32(size=n, initstate=dr.opaque(mi.UInt64, seed), initseq=index)
        jitter_x, jitter_y = rng.next_float32(), rng.next_float32()
        one = s == 1  # a single sample sits at the pixel centre: edges do not shimmer in a drag
        jitter_x = dr.select(one, 0.5, jitter_x)
        jitter_y = dr.select(one, 0.5, jitter_y)
        x = mi.Float(pixel % w) + (mi.Float(sample % side) + jitter_x) / mi.Float(side)
        y = mi.Float(pixel // w) + (mi.Float(sample // side) + jitter_y) / mi.Float(side)
        film = mi.Point2f(x / dr.opaque(mi.Float, width), y / dr.opaque(mi.Float, height))
        return self._ray(_frame(pose, width, height), film)

    def _ray(self, frame: Frame, film: Any) -> Any:
        """Mitsuba's pinhole: film x grows to the camera's right, film y downwards."""
        import drjit as dr

        mi = self.mi
        axes = (frame.origin, frame.forward, frame.right, frame.up)
        o, f, r, u = (dr.opaque(mi.Vector3f, axis) for axis in axes)
        tan_x, tan_y = dr.opaque(mi.Float, frame.tan_x), dr.opaque(mi.Float, frame.tan_y)
        direction = f + r * ((2.0 * film.x - 1.0) * tan_x) + u * ((1.0 - 2.0 * film.y) * tan_y)
        # Rays start on the near clip plane, at Mitsuba's default distance, as its sensor's do.
        start = o + direction * dr.opaque(mi.Float, NEAR_CLIP)
        return mi.Ray3f(mi.Point3f(start), dr.normalize(direction))


def _frame(pose: Pose, width: int, height: int) -> Frame:
    """The camera frame of Mitsuba's ``look_at`` (its x axis is the camera's left)."""
    origin = np.array(pose.look_at.origin, np.float64)
    forward = np.array(pose.look_at.target, np.float64) - origin
    forward /= np.linalg.norm(forward)
    left = np.cross(np.array(pose.look_at.up, np.float64), forward)
    left /= np.linalg.norm(left)
    up = np.cross(forward, left)
    tan_x = math.tan(math.radians(pose.fov) / 2.0)
    right = (-left).tolist()
    return Frame(
        origin.tolist(), forward.tolist(), right, up.tolist(), tan_x, tan_x * height / width
    )


def sensor_pose(mi: ModuleType, sensor: Any, bounds: tuple[Vec3, Vec3]) -> Pose:
    """A scene sensor's pose as ``look_at``: origin, the point along the view axis nearest the
    centre of ``bounds``, up, x field of view; a sensor that is not a pinhole or is mirrored is
    shown as the nearest pinhole, and the pose says so."""
    params = mi.traverse(sensor)
    matrix = np.array(params["to_world"].matrix.numpy(), np.float64).reshape(-1, 4, 4)[0]
    origin, axes = matrix[:3, 3], matrix[:3, :3]
    forward = axes[:, 2] / np.linalg.norm(axes[:, 2])
    up = axes[:, 1] / np.linalg.norm(axes[:, 1])
    centre = (np.array(bounds[0]) + np.array(bounds[1])) / 2.0
    reach = max(float(np.dot(centre - origin, forward)), 1e-3 * (1.0 + np.linalg.norm(origin)))
    notes = []
    kind = type(sensor).__name__
    if "x_fov" in params.keys():
        fov = float(np.array(params["x_fov"]).ravel()[0])
    else:
        fov = 40.0
        notes.append(f"the objective sensor ({kind}) is shown through a 40° pinhole")
    if np.linalg.det(axes) < 0:  # look_at's frame (left, up, forward) is right-handed
        notes.append("the objective sensor's frame is mirrored: the view shows it unmirrored")
    target = origin + reach * forward
    look_at = LookAt(_vec(origin), _vec(target), _vec(up))
    return Pose(look_at, fov, "; ".join(notes))


def scene_bounds(scene: Any) -> tuple[Vec3, Vec3]:
    box = scene.bbox()
    return _vec(np.array(box.min, np.float64)), _vec(np.array(box.max, np.float64))


def _vec(values: Any) -> Vec3:
    x, y, z = (float(v) for v in np.asarray(values, np.float64).ravel()[:3])
    return (x, y, z)
