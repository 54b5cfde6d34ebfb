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
class Coverage:
    """Per-pixel object histogram as triplets: pixel ``pixel`` saw object ``obj`` ``count`` times.

    Sorted by pixel, then by decreasing count, then object index. Background is not listed.
    """

    pixel: np.ndarray  # (T,) int64 flat pixel index (row-major)
    obj: np.ndarray  # (T,) int32 object index
    count: np.ndarray  # (T,) int32 samples

    def regroup(self, group_of: np.ndarray) -> Coverage:
        """The same coverage over groups of objects (e.g. materials): ``group_of[obj]``."""
        groups = int(group_of.max()) + 1 if len(group_of) else 1
        combined = self.pixel * groups + group_of[self.obj]
        keys, inverse = np.unique(combined, return_inverse=True)
        counts = np.bincount(inverse, weights=self.count).astype(np.int32)
        pixel, group = keys // groups, (keys % groups).astype(np.int32)
        order = np.lexsort((group, -counts, pixel))
        return Coverage(pixel[order], group[order], counts[order])


@dataclass(frozen=True)
class VisibilityPass:
    width: int
    height: int
    spp: int
    objects: tuple[str, ...]  # index -> object name (the buffer's object list)
    sample_uv: np.ndarray | None  # (H, W, S, 2) float32 UV of each hit (0 on background), if asked
    coverage: Coverage
    rank_index: np.ndarray  # (H, W, RANKS) int32, objects by decreasing coverage, -1 = empty
    rank_coverage: np.ndarray  # (H, W, RANKS) float32

    @property
    def coverage_hit(self) -> np.ndarray:
        """(H, W) fraction of samples that hit any object (an alpha for the beauty)."""
        hits = np.bincount(
            self.coverage.pixel, weights=self.coverage.count, minlength=self.width * self.height
        )
        return (hits / self.spp).astype(np.float32).reshape(self.height, self.width)

    def paint(self, values: np.ndarray) -> np.ndarray:
        """(H, W) coverage-weighted mean of per-object ``values`` (background contributes 0)."""
        cov = self.coverage
        weights = cov.count * np.asarray(values, np.float64)[cov.obj]
        total = np.bincount(cov.pixel, weights=weights, minlength=self.width * self.height)
        return (total / self.spp).astype(np.float32).reshape(self.height, self.width)


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
        registry: Any = dr.reinterpret_array(mi.UInt32, si.shape)  # the stubs type it as object
        table = mi.Int32(_object_of_registry_id(mi, scene, objects))
        hit = si.is_valid() & (registry < dr.width(table))
        index = dr.select(hit, dr.gather(mi.Int32, table, registry, hit), BACKGROUND)
        samples = np.array(index, dtype=np.int32)
        uv = np.stack([np.array(si.uv.x), np.array(si.uv.y)], axis=-1) if with_uv else None
    coverage = histogram(samples.reshape(height * width, spp))
    rank_index, rank_coverage = ranked(coverage, (height, width), spp)
    sample_uv = None
    if uv is not None:
        uv[samples == BACKGROUND] = 0.0
        sample_uv = uv.astype(np.float32).reshape(height, width, spp, 2)
    return VisibilityPass(
        width, height, spp, objects, sample_uv, coverage, rank_index, rank_coverage
    )


def _object_of_registry_id(mi: ModuleType, scene: Any, objects: tuple[str, ...]) -> np.ndarray:
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


def histogram(sample_object: np.ndarray) -> Coverage:
    """Run-length count of each pixel's sorted sample ids: O(N S log S), no N x objects table."""
    pixels, spp = sample_object.shape
    flat = np.sort(sample_object, axis=1)
    first = np.ones_like(flat, dtype=bool)
    first[:, 1:] = flat[:, 1:] != flat[:, :-1]  # a run starts at every row's first sample too
    starts = np.flatnonzero(first)
    counts = np.diff(np.append(starts, flat.size))
    pixel, obj = starts // spp, flat.reshape(-1)[starts]
    keep = obj != BACKGROUND
    pixel, obj, counts = pixel[keep], obj[keep].astype(np.int32), counts[keep].astype(np.int32)
    order = np.lexsort((obj, -counts, pixel))  # by pixel, then most covered, then lowest index
    return Coverage(pixel[order], obj[order], counts[order])


def ranked(
    coverage: Coverage, size: tuple[int, int], spp: int, ranks: int = RANKS
) -> tuple[np.ndarray, np.ndarray]:
    """The ``ranks`` most covering objects per pixel (index, coverage), padded with (-1, 0)."""
    height, width = size
    index = np.full((height * width, ranks), BACKGROUND, np.int32)
    amount = np.zeros((height * width, ranks), np.float32)
    first_of_pixel = np.searchsorted(coverage.pixel, coverage.pixel, side="left")
    rank = np.arange(len(coverage.pixel)) - first_of_pixel
    keep = rank < ranks
    index[coverage.pixel[keep], rank[keep]] = coverage.obj[keep]
    amount[coverage.pixel[keep], rank[keep]] = coverage.count[keep] / np.float32(spp)
    return index.reshape(height, width, ranks), amount.reshape(height, width, ranks)
