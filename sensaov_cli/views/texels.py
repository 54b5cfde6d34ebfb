"""Texel fields looked up at hit UVs the way Mitsuba's ``bitmap`` texture looks up its texels.

A bitmap's value at a hit is Σ w_t(uv) θ_t over the texels t its filter touches, so the
gradient of that texel flows back with the same weights: painting a texel field through the
same weights puts each texel's sensitivity exactly where the texture shows it (§3 "Binding").

The lookup follows Mitsuba 3.9's ``bitmap`` (checked against Mitsuba in tests/test_texels.py):
``uv`` is first mapped by the affine ``to_uv``; row = v·H, column = u·W; ``bilinear`` blends
the four texels whose centres surround ``uv·size - 0.5``, ``nearest`` takes the texel
containing ``uv·size``; integer texel indices outside the texture are wrapped by ``repeat``
(modulo), ``mirror`` (reflected with period 2·size) or ``clamp`` (to the edge texel).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FILTERS = ("bilinear", "nearest")
WRAPS = ("repeat", "mirror", "clamp")


@dataclass(frozen=True)
class TextureSampling:
    """How one bitmap is looked up: filter, wrap and the 3x3 affine ``to_uv`` (row-major)."""

    filter: str = "bilinear"
    wrap: str = "repeat"
    to_uv: np.ndarray = field(default_factory=lambda: np.eye(3))
    note: str = ""  # anything the settings could not be sure of

    def __post_init__(self) -> None:
        if self.filter not in FILTERS or self.wrap not in WRAPS:
            raise ValueError(f"unknown bitmap filter/wrap {self.filter!r}/{self.wrap!r}")

    def describe(self) -> str:
        rows = ",".join(f"[{', '.join(f'{x:.6g}' for x in row)}]" for row in self.to_uv[:2])
        return f"filter={self.filter};wrap={self.wrap};to_uv=[{rows}]"


def wrap_index(index: np.ndarray, size: int, mode: str) -> np.ndarray:
    """Integer texel indices wrapped into [0, size) as Mitsuba's bitmap wraps them."""
    if mode == "repeat":
        return np.mod(index, size)
    if mode == "clamp":
        return np.clip(index, 0, size - 1)
    period = np.mod(index, 2 * size)
    return np.where(period >= size, 2 * size - period - 1, period)


def texel_weights(
    uv: np.ndarray, size: tuple[int, int], sampling: TextureSampling
) -> tuple[np.ndarray, np.ndarray]:
    """For N hit UVs, the flat texel indices (N, k) and weights (N, k) the lookup reads.

    k = 4 for bilinear, 1 for nearest; the weights of each hit sum to 1.
    """
    col, row, fx, fy = _cells(uv, size, sampling)
    cells = _nearest_index if fx is None else _corner_index
    return cells(col, row, size, sampling.wrap), _corner_weights(fx, fy, len(col))


def _cells(
    uv: np.ndarray, size: tuple[int, int], sampling: TextureSampling
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Each UV's texel cell before wrapping (column, row: int64) and, for bilinear, its place
    in the cell (fx, fy); a cell is the texel (nearest) or the four whose centres surround it."""
    height, width = size
    # float32 UVs stay float32 (Mitsuba computes its lookup in float32 too): half the traffic.
    uv = np.asarray(uv).reshape(-1, 2)
    if uv.dtype != np.float32:
        uv = uv.astype(np.float64)
    (a, b, c), (d, e, f) = (map(float, row) for row in sampling.to_uv[:2])
    u, v = uv[:, 0], uv[:, 1]
    # Written out: numpy's matmul with an inner size of 2 is ~100x slower on millions of rows.
    x, y = (a * u + b * v + c) * width, (d * u + e * v + f) * height
    if sampling.filter == "nearest":
        return np.floor(x).astype(np.int64), np.floor(y).astype(np.int64), None, None
    x, y = x - 0.5, y - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    return x0.astype(np.int64), y0.astype(np.int64), x - x0, y - y0


def _corner_index(col: np.ndarray, row: np.ndarray, size: tuple[int, int], wrap: str) -> np.ndarray:
    """(N, 4) flat texel indices of the bilinear cells at (``col``, ``row``), wrapped as
    Mitsuba wraps: corners (r0,c0), (r0,c1), (r1,c0), (r1,c1)."""
    height, width = size
    c0, c1 = wrap_index(col, width, wrap), wrap_index(col + 1, width, wrap)
    r0, r1 = wrap_index(row, height, wrap) * width, wrap_index(row + 1, height, wrap) * width
    index = np.empty((len(col), 4), np.int64)
    index[:, 0], index[:, 1], index[:, 2], index[:, 3] = r0 + c0, r0 + c1, r1 + c0, r1 + c1
    return index


def _nearest_index(
    col: np.ndarray, row: np.ndarray, size: tuple[int, int], wrap: str
) -> np.ndarray:
    """(N, 1) flat indices of the texels at (``col``, ``row``), wrapped."""
    height, width = size
    return (wrap_index(row, height, wrap) * width + wrap_index(col, width, wrap))[:, None]


def _corner_weights(fx: np.ndarray | None, fy: np.ndarray | None, count: int) -> np.ndarray:
    """(N, k) lookup weights: 1 for nearest, the four bilinear products in ``_corner_index``'s
    order otherwise."""
    if fx is None or fy is None:
        return np.ones((count, 1))
    gx, gy = 1 - fx, 1 - fy
    weight = np.empty((count, 4), fx.dtype)
    weight[:, 0], weight[:, 1], weight[:, 2], weight[:, 3] = gy * gx, gy * fx, fy * gx, fy * fx
    return weight


def lookup(texels: np.ndarray, uv: np.ndarray, sampling: TextureSampling) -> np.ndarray:
    """``texels`` (H, W, C) read at N UVs: (N, C), as the bitmap would return them."""
    height, width, channels = texels.shape
    index, weight = texel_weights(uv, (height, width), sampling)
    flat = np.asarray(texels, np.float64).reshape(-1, channels)
    return np.einsum("nk,nkc->nc", weight, flat[index])


@dataclass(frozen=True)
class Footprint:
    """How one camera sees one texture: per (pixel, texel, owner) the lookup weight summed over
    the pixel's samples, divided by spp. Built once per texture and camera; every panel and
    objective then paints with a gather and a bincount over these pairs, not over samples."""

    size: tuple[int, int]  # (height, width) of the image
    texels: int  # H x W of the texture
    pixel: np.ndarray  # (P,) int64 flat pixel index
    texel: np.ndarray  # (P,) int64 flat texel index
    owner: np.ndarray  # (P,) int64 position in the owners the footprint was built for
    weight: np.ndarray  # (P,) float64: Σ lookup weights / spp

    def paint(self, field: np.ndarray, owner_factor: np.ndarray) -> np.ndarray:
        """(H, W, C): each pixel's coverage-weighted mean of ``field`` (T, C) at its samples,
        a sample that hit owner ``o`` multiplied by ``owner_factor[o]``."""
        flat = np.asarray(field, np.float64).reshape(self.texels, -1)
        weight = self.weight * np.asarray(owner_factor, np.float64)[self.owner]
        pixels = self.size[0] * self.size[1]
        out = np.empty((pixels, flat.shape[1]), np.float64)
        for channel in range(flat.shape[1]):
            values = weight * flat[self.texel, channel]
            out[:, channel] = np.bincount(self.pixel, weights=values, minlength=pixels)
        return out.reshape(*self.size, -1).astype(np.float32)

    def seen(self, size: tuple[int, int]) -> np.ndarray:
        """(H, W) bool over the texture: texels some owner sample reads with non-zero weight."""
        seen = np.zeros(self.texels, bool)
        seen[self.texel[self.weight > 0]] = True
        return seen.reshape(size)


def footprint(
    size: tuple[int, int],
    sampling: TextureSampling,
    sample_uv: np.ndarray,
    sample_object: np.ndarray,
    owners: np.ndarray,
) -> Footprint:
    """The :class:`Footprint` of a texture of ``size`` texels owned by object indices ``owners``."""
    height, width, spp = sample_object.shape
    objects = sample_object.reshape(-1)
    position = np.full(max(int(objects.max(initial=0)), int(np.max(owners, initial=0))) + 2, -1)
    position[np.asarray(owners, np.int64)] = np.arange(len(owners))
    hits = np.flatnonzero(_owned(objects, np.asarray(owners, np.int64), position))
    texels = size[0] * size[1]
    if not hits.size:
        empty = np.zeros(0, np.int64)
        return Footprint((height, width), texels, empty, empty, empty, np.zeros(0))
    col, row, fx, fy = _cells(sample_uv.reshape(-1, 2)[hits], size, sampling)
    owner = position[objects[hits]]
    pixel = hits // spp
    # Merge runs of samples of a pixel that read the same texels with the same owner (the
    # common case: a pixel is smaller than a texel), summing their corner weights. Samples
    # come in pixel order, so a run never spans two pixels; no sort is needed, and texels that
    # repeat after others stay a second entry (paint sums entries: the same result). Runs are
    # found on the cell before wrapping, which fixes every corner, so texel indices are
    # computed per run, not per sample (issue 23); neighbouring runs whose cells wrap onto the
    # same texels (a seam, UVs past a clamped edge) are then joined, so the entries and their
    # float32 sums are those of merging on the texels themselves.
    head = np.zeros(hits.size, dtype=bool)
    head[0] = True
    for part in (pixel, row, col, owner):
        head[1:] |= part[1:] != part[:-1]
    runs = np.flatnonzero(head)
    cells = _nearest_index if fx is None else _corner_index
    index = cells(col[runs], row[runs], size, sampling.wrap)
    same = np.all(index[1:] == index[:-1], axis=1)
    same &= (pixel[runs[1:]] == pixel[runs[:-1]]) & (owner[runs[1:]] == owner[runs[:-1]])
    first = np.concatenate(([True], ~same))
    starts, index = runs[first], index[first]
    weight = _corner_weights(fx, fy, hits.size)
    summed = np.add.reduceat(weight, starts, axis=0) / spp  # (G, corners)
    corners = index.shape[1]
    return Footprint(
        (height, width),
        texels,
        np.repeat(pixel[starts], corners),
        index.reshape(-1),
        np.repeat(owner[starts], corners),
        summed.reshape(-1),
    )


def _owned(objects: np.ndarray, owners: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Which samples hit one of ``owners``: a comparison per owner for a few (a texture is
    usually on one or two objects: 8x faster than the gather), else through ``position``."""
    if 0 < len(owners) <= 4 and int(owners.min()) >= 0:
        mask = objects == owners[0]
        for owner in owners[1:]:
            mask |= objects == owner
        return mask
    return position[objects] >= 0  # background (-1) reads the last entry: -1
