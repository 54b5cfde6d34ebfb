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
    height, width = size
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    mapped = uv @ sampling.to_uv[:2, :2].T + sampling.to_uv[:2, 2]
    x, y = mapped[:, 0] * width, mapped[:, 1] * height
    if sampling.filter == "nearest":
        col = wrap_index(np.floor(x).astype(np.int64), width, sampling.wrap)
        row = wrap_index(np.floor(y).astype(np.int64), height, sampling.wrap)
        return (row * width + col)[:, None], np.ones((len(uv), 1))
    x, y = x - 0.5, y - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    cols = [wrap_index(x0.astype(np.int64) + d, width, sampling.wrap) for d in (0, 1)]
    rows = [wrap_index(y0.astype(np.int64) + d, height, sampling.wrap) for d in (0, 1)]
    index = np.stack([rows[j] * width + cols[i] for j in (0, 1) for i in (0, 1)], axis=1)
    wx, wy = [1 - fx, fx], [1 - fy, fy]
    weight = np.stack([wy[j] * wx[i] for j in (0, 1) for i in (0, 1)], axis=1)
    return index, weight


def lookup(texels: np.ndarray, uv: np.ndarray, sampling: TextureSampling) -> np.ndarray:
    """``texels`` (H, W, C) read at N UVs: (N, C), as the bitmap would return them."""
    height, width, channels = texels.shape
    index, weight = texel_weights(uv, (height, width), sampling)
    flat = np.asarray(texels, np.float64).reshape(-1, channels)
    return np.einsum("nk,nkc->nc", weight, flat[index])


def paint_field(
    texels: np.ndarray,
    sampling: TextureSampling,
    sample_uv: np.ndarray,
    sample_object: np.ndarray,
    owner_scale: np.ndarray,
) -> np.ndarray:
    """(H, W, C) per-pixel mean over samples of the field at each sample's UV.

    ``owner_scale[object]`` multiplies a sample that hit ``object`` (0 where the object does not
    own the texture): 1 paints the field, 1/V paints each texel's share of its object's value.
    Background and non-owners contribute 0, so a pixel is averaged with its coverage.
    """
    height, width, spp = sample_object.shape
    out = np.zeros((height * width * spp, texels.shape[2]), np.float64)
    obj = sample_object.reshape(-1)
    factor = np.where(obj >= 0, np.asarray(owner_scale, np.float64)[np.maximum(obj, 0)], 0.0)
    hit = np.flatnonzero(factor != 0)
    if hit.size:
        values = lookup(texels, sample_uv.reshape(-1, 2)[hit], sampling)
        out[hit] = values * factor[hit, None]
    return out.reshape(height, width, spp, -1).mean(axis=2).astype(np.float32)


def texels_seen(
    size: tuple[int, int],
    sampling: TextureSampling,
    sample_uv: np.ndarray,
    sample_object: np.ndarray,
    owners: np.ndarray,
) -> np.ndarray:
    """(H, W) bool: texels a lookup of some sample of an owner reads with non-zero weight."""
    hit = np.isin(sample_object.reshape(-1), owners)
    seen = np.zeros(size[0] * size[1], bool)
    if hit.any():
        index, weight = texel_weights(sample_uv.reshape(-1, 2)[hit], size, sampling)
        seen[index[weight > 0]] = True
    return seen.reshape(size)
