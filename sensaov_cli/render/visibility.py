"""The primary-visibility pass: which object each camera sample sees (paper §3 "Binding").

Rays are traced per sample with gradients suspended, so this pass never differentiates. From
the per-sample object ids come the ranked per-pixel coverages a Cryptomatte stores (box filter:
the fraction of a pixel's samples that hit each object). The ``aov`` integrator's averaged
``shape_index`` is no use here: it yields fractional ids at edges.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from sensaov_cli.views.coverage import BACKGROUND, VisibilityPass, histogram, ranked


def film_positions(mi: ModuleType, width: int, height: int, spp: int, seed: int) -> Any:
    """Film positions in [0, 1)^2 for every (pixel, sample), row-major, samples innermost:
    stratified on a ceil(sqrt(spp))^2 grid inside each pixel, jittered by PCG32 (in Dr.Jit, so
    millions of samples never round-trip through numpy)."""
    import drjit as dr

    side = int(np.ceil(np.sqrt(spp)))
    index = dr.arange(mi.UInt32, width * height * spp)
    pixel, sample = index // spp, index % spp
    rng = mi.PCG32(size=width * height * spp, initstate=seed, initseq=index)
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
    """Trace ``spp`` primary rays per pixel of ``sensor``'s film (no gradients).

    Only the object index of each sample leaves Dr.Jit (and the UVs when ``with_uv``).
    """
    import drjit as dr

    size = sensor.film().crop_size()
    width, height = int(size[0]), int(size[1])
    with dr.suspend_grad():
        position = film_positions(mi, width, height, spp, seed)
        ray, _ = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5, 0.5))
        si = scene.ray_intersect(ray)
        # A hit through an instance reports the shapegroup's member in si.shape and the
        # instance (the object people see) in si.instance; 0 there means no instance.
        instance: Any = dr.reinterpret_array(mi.UInt32, si.instance)  # stubs say object
        shape: Any = dr.reinterpret_array(mi.UInt32, si.shape)
        registry = dr.select(instance != 0, instance, shape)
        table = mi.Int32(object_of_registry_id(mi, scene, objects))
        hit = si.is_valid() & (registry < dr.width(table))
        index = dr.select(hit, dr.gather(mi.Int32, table, registry, hit), BACKGROUND)
        if with_uv:  # one kernel for both: converting them apart would trace every ray twice
            dr.eval(index, si.uv)
        samples = np.array(index, dtype=np.int32)
        uv = None
        if with_uv:
            uv = np.empty((samples.size, 2), np.float32)
            uv[:, 0], uv[:, 1] = np.array(si.uv.x), np.array(si.uv.y)
    coverage = histogram(samples.reshape(height * width, spp))
    rank_index, rank_coverage = ranked(coverage, (height, width), spp)
    sample_uv = sample_object = None
    if uv is not None:
        uv[samples == BACKGROUND] = 0.0
        sample_uv = uv.reshape(height, width, spp, 2)
        sample_object = samples.reshape(height, width, spp)
    return VisibilityPass(
        width, height, spp, objects, sample_uv, coverage, rank_index, rank_coverage, sample_object
    )


def object_of_registry_id(mi: ModuleType, scene: Any, objects: tuple[str, ...]) -> np.ndarray:
    """A table from shape registry id (what a hit reports) to object index in ``objects``."""
    import drjit as dr

    names = {name: i for i, name in enumerate(objects)}
    pairs = {}
    for number, shape in enumerate(scene.shapes()):
        registry = int(np.array(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape)))[0])
        pairs[registry] = names.get(shape.id() or f"shape_{number}", BACKGROUND)
    table = np.full(max(pairs, default=0) + 1, BACKGROUND, np.int32)
    for registry, index in pairs.items():
        table[registry] = index
    return table
