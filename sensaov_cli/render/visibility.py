"""What an inspection camera's layers are painted from: primary visibility, texture lookups,
the beauty pass; a free camera for ``sensaov view``.

The primary-visibility pass: which object each camera sample sees (paper §3 "Binding"), from
which come the ranked per-pixel coverages a Cryptomatte stores (box filter). The ``aov``
integrator's averaged ``shape_index`` is no use here: it yields fractional ids at edges.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from sensaov_cli import interrupts
from sensaov_cli.job.spec import LookAt
from sensaov_cli.render.adjoint import render_primal
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.scene.prepare import DEFAULT_FILTER, DEFAULT_WRAP
from sensaov_cli.views.coverage import BACKGROUND, VisibilityPass, histogram, ranked

# A stop (SIGTERM, Ctrl-C) is acted on between kernel launches of at most this many samples.
SAMPLES_PER_CHUNK = 1 << 19
PROBES, PROBE_SEED = 256, 9  # random UVs at which a texture's own lookup is read


def film_positions(
    mi: ModuleType,
    width: int,
    height: int,
    spp: int,
    seed: int,
    *,
    samples: tuple[int, int] | None = None,
) -> Any:
    """Film positions in [0, 1)^2 for every (pixel, sample), row-major, samples innermost:
    stratified on a ceil(sqrt(spp))^2 grid inside each pixel, jittered by PCG32. ``samples``:
    only the [first, end) range of the flat sample index, as the whole film gives them."""
    import drjit as dr

    first, end = samples or (0, width * height * spp)
    side = int(np.ceil(np.sqrt(spp)))
    # The offset is opaque: a literal would compile a new kernel for every chunk.
    offset = dr.opaque(mi.UInt32, first)
    index = offset + dr.arange(mi.UInt32, end - first)
    pixel, sample = index // spp, index % spp
    # PCG32 adds arange(size) to both seeds (to de-correlate its lanes): offset by ``first``,
    # every sample gets the state the whole film's generator gives it.
    wide = mi.UInt64(offset)
    rng = mi.PCG32(size=end - first, initstate=seed + wide, initseq=mi.UInt64(index) + wide)
    jitter_x, jitter_y = rng.next_float32(), rng.next_float32()
    x = mi.Float(pixel % width) + (mi.Float(sample % side) + jitter_x) / side
    y = mi.Float(pixel // width) + (mi.Float(sample // side) + jitter_y) / side
    return mi.Point2f(x / width, y / height)


def trace(
    mi: ModuleType,
    scene: Any,
    sensor: Any,
    objects: tuple[str, ...],
    spp: int,
    seed: int = 0,
    *,
    with_uv: bool = False,
) -> VisibilityPass:
    """Trace ``spp`` primary rays per pixel of ``sensor``'s film (no gradients), in chunks of
    at most SAMPLES_PER_CHUNK samples; only each sample's object index (and UV when
    ``with_uv``, 0 where nothing is hit) leaves Dr.Jit."""
    import drjit as dr

    size = sensor.film().crop_size()
    width, height = int(size[0]), int(size[1])
    table = mi.Int32(object_of_registry_id(mi, scene, objects))
    samples = np.empty(width * height * spp, np.int32)
    uv = np.empty((samples.size, 2), np.float32) if with_uv else None
    for first, end in sample_spans(samples.size, spp):
        position = film_positions(mi, width, height, spp, seed, samples=(first, end))
        with dr.suspend_grad():
            ray, _ = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5, 0.5))
            samples[first:end], hit_uv = hits(mi, scene, ray, table, with_uv)
        if uv is not None and hit_uv is not None:
            uv[first:end] = hit_uv
    return visibility_pass(objects, samples, uv, width, height, spp)


def hits(
    mi: ModuleType, scene: Any, ray: Any, table: Any, with_uv: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """Per ray, the index of the object hit (``table``: :func:`object_of_registry_id`) and,
    ``with_uv``, the hit's UV (0 where nothing is hit)."""
    import drjit as dr

    with dr.suspend_grad():
        si = scene.ray_intersect(ray)
        index = object_index(mi, si, table)
        if not with_uv:
            return np.array(index, dtype=np.int32), None
        # Selected in the kernel (a numpy mask over every sample costs more), and evaluated with
        # the index in one kernel: converting them apart would trace twice.
        uv = dr.select(index != BACKGROUND, si.uv, mi.Point2f(0.0, 0.0))
        dr.eval(index, uv)
        return np.array(index, dtype=np.int32), np.stack([np.array(uv.x), np.array(uv.y)], 1)


def visibility_pass(
    objects: tuple[str, ...],
    samples: np.ndarray,
    uv: np.ndarray | None,
    width: int,
    height: int,
    spp: int,
) -> VisibilityPass:
    """The pass of per-sample object indices (and UVs, 0 where nothing is hit), rows first."""
    coverage = histogram(samples.reshape(height * width, spp))
    rank_index, rank_coverage = ranked(coverage, (height, width), spp)
    sample_uv = sample_object = None
    if uv is not None:
        sample_uv = uv.reshape(height, width, spp, 2)
        sample_object = samples.reshape(height, width, spp)
    return VisibilityPass(
        width, height, spp, objects, sample_uv, coverage, rank_index, rank_coverage, sample_object
    )


def sample_spans(count: int, spp: int) -> Iterator[tuple[int, int]]:
    """[first, end) spans of whole pixels' samples, at most SAMPLES_PER_CHUNK each (at least
    one pixel); a pending stop is raised (as KeyboardInterrupt) before every span but the first."""
    step = max(1, SAMPLES_PER_CHUNK // spp) * spp
    for first in range(0, count, step):
        if first:
            interrupts.raise_if_stopped()
        yield first, min(first + step, count)


def object_index(mi: ModuleType, si: Any, table: Any) -> Any:
    """Per ray of ``si``, the index of the object hit (``table``: :func:`object_of_registry_id`),
    or BACKGROUND."""
    import drjit as dr

    # A hit through an instance reports the shapegroup's member in si.shape and the instance
    # (the object people see) in si.instance; 0 there means no instance.
    instance: Any = dr.reinterpret_array(mi.UInt32, si.instance)  # stubs say object
    shape: Any = dr.reinterpret_array(mi.UInt32, si.shape)
    registry = dr.select(instance != 0, instance, shape)
    hit = si.is_valid() & (registry < dr.width(table))
    return dr.select(hit, dr.gather(mi.Int32, table, registry, hit), BACKGROUND)


def object_of_registry_id(mi: ModuleType, scene: Any, objects: tuple[str, ...]) -> np.ndarray:
    """A table from shape registry id (what a hit reports) to object index in ``objects``."""
    import drjit as dr

    names = {name: i for i, name in enumerate(objects)}
    pairs = {}
    for number, shape in enumerate(scene.shapes()):
        registry = int(np.array(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape)))[0])
        pairs[registry] = names.get(shape.id() or f"shape_{number}", BACKGROUND)
    table = np.full(max(pairs, default=0) + 1, BACKGROUND, np.int32)
    table[list(pairs)] = list(pairs.values())
    return table


def render_beauty(
    loaded: LoadedScene, sensor: Any, visibility: VisibilityPass, spp: int, seed: int
) -> np.ndarray | None:
    """A quick RGBA render at the inspection camera (alpha = visibility coverage, so the two
    line up); gradients off."""
    if spp <= 0:
        return None
    image = render_primal(loaded, spp, seed, sensor=sensor)
    rgb = np.array(image, dtype=np.float32)[..., :3]
    if rgb.shape[2] < 3:  # a mono variant renders Y (and A): show it grey
        rgb = np.repeat(rgb[..., :1], 3, axis=2)
    return np.concatenate([rgb, visibility.coverage_hit[..., None]], axis=2)


@dataclass(frozen=True)
class TextureProbe:
    """What pins a bitmap texture's lookup down, so the project stage can repeat it: the scene
    XML's settings, ``to_uv``, the texels, and the texture's own values at PROBES random UVs
    (matched against every filter and wrap mode)."""

    filter: str
    wrap: str
    note: str
    to_uv: np.ndarray  # 3x3
    texels: np.ndarray  # (H, W, C)
    uv: np.ndarray  # (PROBES, 2)
    values: np.ndarray  # (PROBES, C)


def texture_probes(
    mi: ModuleType, params: Any, keys: tuple[str, ...], options: dict[str, tuple[str, str, str]]
) -> dict[str, TextureProbe]:
    """Per texture ``data`` key, its probe; ``filter_type`` and ``wrap_mode`` are not exposed by
    the plugin's binding: ``options`` (``PreparedScene.bitmap_options``) has them."""
    import drjit as dr

    rng = np.random.default_rng(PROBE_SEED)
    result = {}
    for key in keys:
        node = params.properties[key][2]
        match = re.search(r'name = "([^"]*)"', str(node))
        found = options.get(match.group(1) if match else "", None)
        filter_type, wrap, note = found or (DEFAULT_FILTER, DEFAULT_WRAP, "")
        to_uv_key = key[: -len("data")] + "to_uv"
        matrix = np.eye(3)
        if to_uv_key in params.keys():
            matrix = np.array(params[to_uv_key].matrix, dtype=np.float64).reshape(3, 3)
        texels = np.array(params[key], dtype=np.float64)
        uv = rng.uniform(-1.5, 2.5, (PROBES, 2))
        with dr.suspend_grad():
            si = dr.zeros(mi.SurfaceInteraction3f, PROBES)
            si.uv = mi.Point2f(uv[:, 0], uv[:, 1])
            if texels.shape[2] == 1:
                values = np.array(node.eval_1(si), dtype=np.float64)[:, None]
            else:
                values = np.array(node.eval(si), dtype=np.float64).T
        result[key] = TextureProbe(filter_type, wrap, note, matrix, texels, uv, values)
    return result


def objects_without_uv(mi: ModuleType, scene: Any, objects: tuple[str, ...]) -> tuple[str, ...]:
    """Meshes without texture coordinates: Mitsuba reads texel (0, 0) wherever they are hit."""
    missing = []
    for number, shape in enumerate(scene.shapes()):
        name = shape.id() or f"shape_{number}"
        if name in objects and shape.is_mesh() and not shape.has_vertex_texcoords():
            missing.append(name)
    return tuple(sorted(missing))


# --- a free inspection camera for `sensaov view`: primary visibility from any viewpoint, fast.
# Dr.Jit bakes literal constants into its kernels (MITSUBA-NOTES): every number that changes
# between views (frame, field of view, image size, spp, seed) enters the trace as an opaque
# variable, so every view after the first reuses the compiled kernel. Rays follow Mitsuba's
# `perspective` sensor with `fov_axis` x, so a viewpoint saved as a job's `look_at` camera
# renders the same picture in `sensaov project`.

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
    look_at = LookAt(_vec(origin), _vec(origin + reach * forward), _vec(up))
    return Pose(look_at, fov, "; ".join(notes))


def scene_bounds(scene: Any) -> tuple[Vec3, Vec3]:
    box = scene.bbox()
    return _vec(np.array(box.min, np.float64)), _vec(np.array(box.max, np.float64))


def _vec(values: Any) -> Vec3:
    x, y, z = (float(v) for v in np.asarray(values, np.float64).ravel()[:3])
    return (x, y, z)
