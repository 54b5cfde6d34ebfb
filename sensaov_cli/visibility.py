"""The primary-visibility pass: which object each camera sample sees (paper §3 "Binding").

Rays are traced per sample with gradients suspended, so this pass never differentiates. From
the per-sample object ids come the ranked per-pixel coverages a Cryptomatte stores (box filter:
the fraction of a pixel's samples that hit each object). The ``aov`` integrator's averaged
``shape_index`` is no use here: it yields fractional ids at edges.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

BACKGROUND = -1
RANKS = 6  # Cryptomatte's customary three layers of two ranks


@dataclass(frozen=True)
class VisibilityPass:
    width: int
    height: int
    spp: int
    objects: tuple[str, ...]  # index -> object name (the buffer's object list)
    sample_object: np.ndarray  # (H, W, S) int32 object index, BACKGROUND where nothing is hit
    sample_uv: np.ndarray  # (H, W, S, 2) float32 surface UV of each hit (0 on background)
    rank_index: np.ndarray  # (H, W, RANKS) int32, objects by decreasing coverage, -1 = empty
    rank_coverage: np.ndarray  # (H, W, RANKS) float32

    @property
    def coverage_hit(self) -> np.ndarray:
        """(H, W) fraction of samples that hit any object (an alpha for the beauty)."""
        return (self.sample_object != BACKGROUND).mean(axis=2, dtype=np.float32)

    def paint(self, values: np.ndarray) -> np.ndarray:
        """(H, W) coverage-weighted mean of per-object ``values`` (background contributes 0)."""
        padded = np.append(np.asarray(values, np.float32), np.float32(0.0))
        return padded[self.sample_object].mean(axis=2, dtype=np.float64).astype(np.float32)


def sample_positions(width: int, height: int, spp: int, seed: int) -> np.ndarray:
    """(H, W, S, 2) film positions in [0, 1)^2: stratified jitter within each pixel."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(spp)))
    strata = np.stack(np.divmod(np.arange(spp), side), axis=-1)[:, ::-1].astype(np.float32)
    jitter = rng.random((height, width, spp, 2), dtype=np.float32)
    within = (strata[None, None] + jitter) / side  # stratified on a side x side grid
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    pixel = np.stack([xs, ys], axis=-1)[:, :, None, :]
    return (pixel + within) / np.array([width, height], np.float32)


def trace(
    mi: ModuleType, scene: Any, sensor: Any, objects: tuple[str, ...], spp: int, seed: int = 0
) -> VisibilityPass:
    """Trace ``spp`` primary rays per pixel of ``sensor``'s film (no gradients)."""
    import drjit as dr

    size = sensor.film().crop_size()
    width, height = int(size[0]), int(size[1])
    positions = sample_positions(width, height, spp, seed).reshape(-1, 2)
    lookup = _shape_lookup(mi, scene, objects)
    with dr.suspend_grad():
        position = mi.Point2f(positions[:, 0], positions[:, 1])
        ray, _ = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5, 0.5))
        si = scene.ray_intersect(ray)
        valid = np.array(si.is_valid(), dtype=bool)
        shape_ids = np.array(dr.reinterpret_array(mi.UInt32, si.shape), dtype=np.int64)
        uv = np.stack([np.array(si.uv.x), np.array(si.uv.y)], axis=-1).astype(np.float32)
    index = np.where(valid, lookup.get_many(shape_ids), BACKGROUND).astype(np.int32)
    uv[~valid] = 0.0
    sample_object = index.reshape(height, width, spp)
    rank_index, rank_coverage = rank_coverages(sample_object)
    return VisibilityPass(
        width,
        height,
        spp,
        objects,
        sample_object,
        uv.reshape(height, width, spp, 2),
        rank_index,
        rank_coverage,
    )


@dataclass(frozen=True)
class _ShapeLookup:
    registry_ids: np.ndarray
    object_index: np.ndarray

    def get_many(self, ids: np.ndarray) -> np.ndarray:
        position = np.searchsorted(self.registry_ids, ids)
        position = np.clip(position, 0, len(self.registry_ids) - 1)
        found = self.registry_ids[position] == ids
        return np.where(found, self.object_index[position], BACKGROUND)


def _shape_lookup(mi: ModuleType, scene: Any, objects: tuple[str, ...]) -> _ShapeLookup:
    """Registry id of each shape (what a hit reports) -> index of its object in ``objects``."""
    import drjit as dr

    names = {name: i for i, name in enumerate(objects)}
    pairs = []
    for number, shape in enumerate(scene.shapes()):
        name = shape.id() or f"shape_{number}"
        registry = int(np.array(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape)))[0])
        pairs.append((registry, names.get(name, BACKGROUND)))
    pairs.sort()
    ids = np.array([p[0] for p in pairs], np.int64)
    return _ShapeLookup(ids, np.array([p[1] for p in pairs], np.int32))


def rank_coverages(sample_object: np.ndarray, ranks: int = RANKS) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the objects hit ranked by coverage (ties: lower index first), padded with -1."""
    height, width, spp = sample_object.shape
    flat = np.sort(sample_object.reshape(-1, spp), axis=1)
    counts = (flat[:, :, None] == flat[:, None, :]).sum(axis=2)
    first = np.ones_like(flat, dtype=bool)
    first[:, 1:] = flat[:, 1:] != flat[:, :-1]
    score = np.where(first & (flat != BACKGROUND), counts, 0)
    order = np.argsort(-score, axis=1, kind="stable")[:, :ranks]
    top_score = np.take_along_axis(score, order, axis=1)
    top_index = np.where(top_score > 0, np.take_along_axis(flat, order, axis=1), BACKGROUND)
    coverage = (top_score / np.float32(spp)).astype(np.float32)
    if top_index.shape[1] < ranks:  # fewer samples than ranks: pad
        pad = ranks - top_index.shape[1]
        top_index = np.pad(top_index, ((0, 0), (0, pad)), constant_values=BACKGROUND)
        coverage = np.pad(coverage, ((0, 0), (0, pad)))
    shape = (height, width, ranks)
    return top_index.astype(np.int32).reshape(shape), coverage.reshape(shape)
