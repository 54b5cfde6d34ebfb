"""Primary visibility as plain data: which objects each pixel's samples saw (paper §3 "Binding").

The render stage traces the samples (:mod:`sensaov_cli.render.visibility`); everything after
that is numpy and lives here: the per-pixel histogram as run-length triplets, the ranked
coverages a Cryptomatte stores (box filter: the fraction of a pixel's samples that hit each
object), and painting per-object values through them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

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
        # Sorted by pixel already: the stable sort only merges each pixel's few entries.
        order = np.argsort(combined, kind="stable")
        combined = combined[order]
        starts = run_starts(combined)
        counts = np.add.reduceat(self.count[order], starts) if starts.size else self.count[:0]
        keys = combined[starts]
        pixel, group = keys // groups, (keys % groups).astype(np.int32)
        counts = counts.astype(np.int32)
        order = pixel_order(pixel, counts, group)
        return Coverage(pixel[order], group[order], counts[order])


def pixel_order(pixel: np.ndarray, count: np.ndarray, index: np.ndarray) -> np.ndarray:
    """The order by pixel, then decreasing count, then index: ``np.lexsort((index, -count,
    pixel))``, by one stable sort of a combined key where it fits in 63 bits (pixels already
    in order make that sort a pass over short runs, far faster than the lexsort)."""
    if not pixel.size:
        return np.zeros(0, np.intp)
    top = int(count.max())
    low = int(count.min())
    span, indices = top - low + 1, int(index.max()) + 1
    if int(index.min()) < 0 or (int(pixel.max()) + 1) * span * indices >= 2**62:
        return np.lexsort((index, -count, pixel))
    key = (pixel.astype(np.int64) * span + (top - count)) * indices + index
    return np.argsort(key, kind="stable")


def run_starts(values: np.ndarray) -> np.ndarray:
    """Where each run of equal neighbours of a 1-D array begins."""
    if not values.size:
        return np.zeros(0, np.intp)
    head = np.ones(values.size, dtype=bool)
    np.not_equal(values[1:], values[:-1], out=head[1:])
    return np.flatnonzero(head)


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
    sample_object: np.ndarray | None = None  # (H, W, S) int32 object index per sample, with UVs

    @property
    def coverage_hit(self) -> np.ndarray:
        """(H, W) fraction of samples that hit any object (an alpha for the beauty)."""
        return self.paint(np.ones(len(self.objects)))

    @cached_property
    def visible_objects(self) -> tuple[str, ...]:
        """The objects at least one sample of this view hit (counted once: every pass asks)."""
        seen = np.bincount(self.coverage.obj, minlength=len(self.objects))  # O(T), no sort
        return tuple(self.objects[i] for i in np.flatnonzero(seen))

    def paint(self, values: np.ndarray) -> np.ndarray:
        """(H, W) coverage-weighted mean of per-object ``values`` (background contributes 0)."""
        cov = self.coverage
        weights = cov.count * np.asarray(values, np.float64)[cov.obj]
        total = np.bincount(cov.pixel, weights=weights, minlength=self.width * self.height)
        return (total / self.spp).astype(np.float32).reshape(self.height, self.width)


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
    order = pixel_order(pixel, counts, obj)  # by pixel, then most covered, then lowest index
    return Coverage(pixel[order], obj[order], counts[order])


def ranked(
    coverage: Coverage, size: tuple[int, int], spp: int, ranks: int = RANKS
) -> tuple[np.ndarray, np.ndarray]:
    """The ``ranks`` most covering objects per pixel (index, coverage), padded with (-1, 0)."""
    height, width = size
    index = np.full((height * width, ranks), BACKGROUND, np.int32)
    amount = np.zeros((height * width, ranks), np.float32)
    starts = run_starts(coverage.pixel)  # sorted by pixel: a pixel's entries are one run
    lengths = np.diff(starts, append=len(coverage.pixel))
    rank = np.arange(len(coverage.pixel)) - np.repeat(starts, lengths)
    keep = rank < ranks
    index[coverage.pixel[keep], rank[keep]] = coverage.obj[keep]
    amount[coverage.pixel[keep], rank[keep]] = coverage.count[keep] / np.float32(spp)
    return index.reshape(height, width, ranks), amount.reshape(height, width, ranks)
