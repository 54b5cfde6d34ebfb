"""Texels: a texture's field of contributions, pooled and painted where each camera shows it.

The lookup follows Mitsuba 3.9's ``bitmap`` (checked against Mitsuba in tests/test_texels.py):
a hit reads Σ w_t(uv) θ_t, so each texel's gradient flows back with the same weights, and
painting a texel field through them puts its sensitivity where the texture shows (§3
"Binding"). ``uv`` is first mapped by the affine ``to_uv``; row = v·H, column = u·W;
``bilinear`` blends the four texels whose centres surround ``uv·size - 0.5``, ``nearest``
takes the texel containing ``uv·size``; indices outside are wrapped by ``repeat`` (modulo),
``mirror`` (period 2·size) or ``clamp`` (edge texel).

A texel field (per texture and objective, §3, §6) is camera-independent: c = θ·∂M/∂θ
(``weight: value``) or ∂M/∂θ (``raw``) per component, so it sums to the parameter's signed sum
in the buffer, which pooling (below) keeps. ``units: uv_area`` divides by a texel's
UV area (1/(H·W)): a density independent of the texture's resolution. Painted into one camera
it gives Fig. 4's three panels: ``object`` (each owner's Σ c over all its parameters),
``texel`` (the pooled field at each hit UV, encoded as the channel asks on the texel peak's
scale) and ``joint`` (each texel's share of its object's value per unit UV area, c·H·W / V:
1 everywhere is the object's value spread evenly, the paper's ``normalize: joint``).
"""

from __future__ import annotations

import fnmatch
import functools
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import per_object
from sensaov_cli.errors import SpecError
from sensaov_cli.job.spec import ChannelSpec
from sensaov_cli.views.channels import (
    Encoding,
    Scale,
    choose_scale,
    encode_image,
    unresolved_objects,
    unresolved_reason,
)
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.hierarchy import Uncertainty
from sensaov_cli.vocabulary import PoolKind

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
    """For N hit UVs, the flat texel indices and weights the lookup reads: (N, 4) bilinear,
    (N, 1) nearest; each hit's weights sum to 1."""
    col, row, fx, fy = _cells(uv, size, sampling)
    index = _texel_index(col, row, size, sampling.wrap, corners=fx is not None)
    return index, _corner_weights(fx, fy, len(col))


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
    # Written out: numpy's matmul with an inner size of 2 is far slower on millions of rows.
    x, y = (a * u + b * v + c) * width, (d * u + e * v + f) * height
    if sampling.filter == "nearest":
        return np.floor(x).astype(np.int64), np.floor(y).astype(np.int64), None, None
    x, y = x - 0.5, y - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    return x0.astype(np.int64), y0.astype(np.int64), x - x0, y - y0


def _texel_index(
    col: np.ndarray, row: np.ndarray, size: tuple[int, int], wrap: str, *, corners: bool
) -> np.ndarray:
    """Flat indices of the cells at (``col``, ``row``), wrapped: (N, 1) the texels themselves,
    or (N, 4) the bilinear ``corners`` (r0,c0), (r0,c1), (r1,c0), (r1,c1)."""
    height, width = size
    c0, r0 = wrap_index(col, width, wrap), wrap_index(row, height, wrap) * width
    if not corners:
        return (r0 + c0)[:, None]
    c1, r1 = wrap_index(col + 1, width, wrap), wrap_index(row + 1, height, wrap) * width
    index = np.empty((len(col), 4), np.int64)
    index[:, 0], index[:, 1], index[:, 2], index[:, 3] = r0 + c0, r0 + c1, r1 + c0, r1 + c1
    return index


def _corner_weights(fx: np.ndarray | None, fy: np.ndarray | None, count: int) -> np.ndarray:
    """(N, k) lookup weights: 1 for nearest, else the bilinear products in corner order."""
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
    the pixel's samples, divided by spp; every panel and objective paints from it."""

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
    # Merge runs of a pixel's samples that read the same texels with the same owner, summing
    # their corner weights (samples come in pixel order: no sort; a texel that repeats after
    # others stays a second entry, which paint sums alike). Runs are found on the unwrapped
    # cell, so texel indices are computed per run; neighbouring runs whose cells wrap onto the
    # same texels are then joined, so the float32 sums are those of merging on the texels.
    head = np.zeros(hits.size, dtype=bool)
    head[0] = True
    for part in (pixel, row, col, owner):
        head[1:] |= part[1:] != part[:-1]
    runs = np.flatnonzero(head)
    index = _texel_index(col[runs], row[runs], size, sampling.wrap, corners=fx is not None)
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
    """Which samples hit one of ``owners``: a comparison per owner for a few (faster than the
    gather), else through ``position``."""
    if 0 < len(owners) <= 4 and int(owners.min()) >= 0:
        mask = objects == owners[0]
        for owner in owners[1:]:
            mask |= objects == owner
        return mask
    return position[objects] >= 0  # background (-1) reads the last entry: -1


# Pooling (paper §6). The gradient and the visible texel are sampled independently, so at low
# spp a texel field is sparse and spiky; pooling spreads each texel's value over its neighbours
# before projection. Every kind conserves the field's sum exactly: each source texel's mass is
# divided among the texels it reaches inside the texture (wrapping around for ``repeat``,
# renormalised at the edges otherwise), so the pooled field still sums to the buffer's signed
# sum of the parameter.

# The default pools over about this many expected gradient samples per texel (see default_pool).
TARGET_SAMPLES = 64.0
MAX_RADIUS_FRACTION = 1 / 8  # never blur over more than an eighth of the texture by default


@dataclass(frozen=True)
class Pool:
    kind: PoolKind  # gaussian (radius = sigma), box (half-width), mip (log2 of the block), none
    radius: float
    chosen_by: str  # "job" or the rule that picked it

    def describe(self) -> str:
        return f"kind={self.kind};radius={self.radius:g};chosen_by={self.chosen_by}"


def default_pool(spp: int, pixels: int, size: tuple[int, int]) -> Pool:
    """A gaussian whose footprint holds ~TARGET_SAMPLES gradient samples.

    ``spp · pixels / texels`` bounds the samples that land per texel (the texture filling the
    whole objective frame); sigma grows as the square root of the shortfall, at least 1 texel.
    """
    texels = size[0] * size[1]
    per_texel = max(spp * pixels / max(texels, 1), 1e-9)
    sigma = math.sqrt(TARGET_SAMPLES / per_texel)
    top = max(1.0, min(size) * MAX_RADIUS_FRACTION)
    sigma = float(min(max(1.0, round(sigma, 2)), top))
    return Pool("gaussian", sigma, f"auto: sqrt({TARGET_SAMPLES:g} / (spp*pixels/texels))")


def white_noise_factor(pool: Pool) -> float:
    """How much pooling divides the standard deviation of independent per-texel noise away
    from edges: sqrt(Σ w²) of the 2-D kernel, which is separable, so Σ w² of one axis. Texel
    noise is correlated (a bilinear lookup spreads each gradient sample over four texels), so
    the measured reduction is smaller: docs/texels.md gives it."""
    if pool.kind == "none" or pool.radius <= 0:
        return 1.0
    if pool.kind == "mip":
        return 1.0 / 2 ** int(round(pool.radius))
    impulse = np.zeros((1, 8 * int(math.ceil(3 * pool.radius)) + 9, 1))
    impulse[0, impulse.shape[1] // 2, 0] = 1.0
    row = pool_field(impulse, pool, "repeat")  # a 1-row field spreads along x only
    return float(np.sum(row[0, :, 0] ** 2))


def pool_field(field: np.ndarray, pool: Pool, wrap: str) -> np.ndarray:
    """``field`` (H, W, C) pooled; float64, same shape, same sum (to rounding)."""
    return _pool(field, pool, wrap, 1)


def pool_variance(variance: np.ndarray, pool: Pool, wrap: str) -> np.ndarray:
    """The variance of :func:`pool_field`'s output for texels with independent errors of the
    given ``variance`` (H, W, C): the same linear map with its weights squared."""
    return _pool(variance, pool, wrap, 2)


def _pool(values: np.ndarray, pool: Pool, wrap: str, power: int) -> np.ndarray:
    data = np.asarray(values, np.float64)
    if pool.kind == "none" or pool.radius <= 0:
        return data.copy()
    if pool.kind == "mip":  # a tile's mean; its variance: that of its sum over its area squared
        block = 2 ** int(round(pool.radius))
        pooled = _mip(data, block)
        return pooled if power == 1 else pooled / _tile_sizes(data.shape[:2], block)
    kernel = _kernel(pool)
    # C order for the painting's reshape (the column pass leaves a transposed layout).
    return np.ascontiguousarray(
        _scatter(_scatter(data, kernel, 0, wrap, power), kernel, 1, wrap, power)
    )


def _kernel(pool: Pool) -> np.ndarray:
    """The normalised 1-D weights of a gaussian or box pool."""
    if pool.kind == "gaussian":
        half = max(1, int(math.ceil(3 * pool.radius)))
        kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / pool.radius) ** 2)
    else:
        kernel = np.ones(2 * int(round(pool.radius)) + 1)
    return kernel / kernel.sum()


def _tile_sizes(size: tuple[int, int], block: int) -> np.ndarray:
    """(H, W, 1): how many texels the mip tile of each texel holds (fewer at the edges)."""
    height, width = size
    rows = np.minimum(block, height - (np.arange(height) // block) * block)
    cols = np.minimum(block, width - (np.arange(width) // block) * block)
    return (rows[:, None] * cols[None, :])[..., None].astype(np.float64)


# Kernels up to this many taps are summed tap by tap, longer ones (hundreds, for a large texture
# seen by few samples) by FFT, whose cost does not grow with the kernel.
DIRECT_TAPS = 25


def _scatter(
    data: np.ndarray, kernel: np.ndarray, axis: int, wrap: str, power: int = 1
) -> np.ndarray:
    """Every texel's value scattered along ``axis`` with ``kernel``, conserving its mass: divided
    by the share of the kernel that lands inside the texture (all of it for ``repeat``, which
    wraps around), then scattered with the kernel's weights; both to ``power`` (2 for the
    variances of independent errors: every weight, and the edge normalisation, squared)."""
    n, half = data.shape[axis], len(kernel) // 2
    circular = wrap == "repeat"
    moved = np.moveaxis(data, axis, 0)
    if not circular:
        source = np.arange(n)
        reach = np.zeros(n)  # the kernel weight of each source that lands inside the texture
        for offset, w in zip(range(-half, half + 1), kernel, strict=True):
            reach += w * ((source + offset >= 0) & (source + offset < n))
        moved = moved / (reach**power).reshape((-1,) + (1,) * (moved.ndim - 1))
    weights = kernel**power
    if len(kernel) <= DIRECT_TAPS:
        out = _scatter_direct(moved, weights, circular)
    else:
        out = _scatter_fourier(moved, weights, circular)
    return np.moveaxis(out, 0, axis)


def _scatter_direct(moved: np.ndarray, weights: np.ndarray, circular: bool) -> np.ndarray:
    """``out[j] = Σ w[k] · moved[j - k]`` along the first axis, tap by tap, indices wrapping
    when ``circular``, else sources outside the texture dropped."""
    n, half = moved.shape[0], len(weights) // 2
    out = np.zeros_like(moved)
    for offset, w in zip(range(-half, half + 1), weights, strict=True):
        if circular:
            out += w * np.roll(moved, offset, axis=0)
            continue
        lo, hi = max(0, -offset), min(n, n - offset)
        if lo < hi:
            out[lo + offset : hi + offset] += w * moved[lo:hi]
    return out


def _scatter_fourier(moved: np.ndarray, weights: np.ndarray, circular: bool) -> np.ndarray:
    """:func:`_scatter_direct` by FFT along the first axis: the same sums to rounding, with
    texels that no source reaches set to exactly 0 as the tap-by-tap sums leave them
    (``seen_empty_after_pool`` counts those)."""
    n, half = moved.shape[0], len(weights) // 2
    if circular:
        length = n
        taps = np.zeros(n)
        np.add.at(taps, np.arange(-half, half + 1) % n, weights)  # a kernel longer than n folds
    else:
        length = _fast_length(n + 2 * half)  # no wrap-around: the full linear convolution
        taps = np.zeros(length)
        taps[: len(weights)] = weights
    spectrum = np.fft.rfft(moved, n=length, axis=0)
    spectrum *= np.fft.rfft(taps).reshape((-1,) + (1,) * (moved.ndim - 1))
    full = np.fft.irfft(spectrum, n=length, axis=0)
    out = full[:n] if circular else full[half : half + n]
    out[~_reached(moved != 0, half, circular)] = 0.0
    return out


def _reached(nonzero: np.ndarray, half: int, circular: bool) -> np.ndarray:
    """Which texels have a non-zero source within ``half`` of them along the first axis: a
    dilation of ``nonzero``, by ORs of shifted copies whose reach doubles at each step."""
    n = nonzero.shape[0]
    if circular and 2 * half + 1 >= n:  # the kernel covers the whole (wrapped) column
        return np.broadcast_to(nonzero.any(axis=0), nonzero.shape)
    if circular:  # pad with the wrapped rows; else with rows outside the texture (none)
        padded = np.concatenate([nonzero[n - half :], nonzero, nonzero[:half]])
    else:
        padded = np.zeros((n + 2 * half,) + nonzero.shape[1:], bool)
        padded[half : half + n] = nonzero
    window, covered = 2 * half + 1, 1  # padded[j] now stands for padded[j : j + covered]
    while covered < window:
        step = min(covered, window - covered)
        padded[:-step] |= padded[step:]
        covered += step
    return padded[:n]  # padded[j] covers nonzero[j - half : j + half + 1]


def _fast_length(n: int) -> int:
    """The smallest 2^a·3^b·5^c ≥ n: FFT lengths numpy transforms fastest."""
    best = 1 << max(0, (n - 1).bit_length())
    power5 = 1
    while power5 < best:
        power35 = power5
        while power35 < best:
            size = power35
            while size < n:
                size *= 2
            best = min(best, size)
            power35 *= 3
        power5 *= 5
    return best


def _mip(data: np.ndarray, block: int) -> np.ndarray:
    """Sum over block x block tiles (smaller at the edges), spread evenly inside each tile."""
    height, width = data.shape[:2]
    tall, wide = -(-height // block) * block, -(-width // block) * block
    padded = np.zeros((tall, wide) + data.shape[2:])
    padded[:height, :width] = data
    counts = np.zeros((tall, wide))
    counts[:height, :width] = 1.0
    shape = (tall // block, block, wide // block, block)
    sums = padded.reshape(shape + data.shape[2:]).sum(axis=(1, 3))
    area = counts.reshape(shape).sum(axis=(1, 3))
    mean = sums / area.reshape(area.shape + (1,) * (data.ndim - 2))
    rows, cols = np.arange(height) // block, np.arange(width) // block
    return mean[rows[:, None], cols[None, :]]


def seed_noise(first: np.ndarray, second: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Standard deviation of one field's seed-to-seed noise: std((a - b) / sqrt 2) over ``mask``."""
    diff = (np.asarray(first, np.float64) - np.asarray(second, np.float64)) / math.sqrt(2)
    if mask is not None:
        diff = diff[mask]
    return float(np.sqrt(np.mean(diff**2))) if diff.size else 0.0


COLOUR_TYPES = ("reflectance", "radiance", "transmittance", "specular")


@dataclass(frozen=True)
class TexelField:
    """One texture's field for one objective, before painting."""

    objective: str
    channel: ChannelSpec
    record: ParamRecord
    sampling: TextureSampling
    raw: np.ndarray  # (H, W, C) float64 contributions per texel, unpooled
    pooled: np.ndarray  # (H, W, C) float64, pooled, in the channel's units
    pool: Pool
    signed_sum: float  # the buffer's Σ c for this parameter (what both fields sum to)
    object_values: Mapping[str, float]  # Σ c over all parameters of each owner (Fig. 4, left)
    notes: tuple[str, ...]
    # Standard errors of each texel's c and of the pooled field for independent texel errors
    # (docs/texels.md, "Standard errors"); None without batch statistics.
    stderr: np.ndarray | None = None
    stderr_pooled: np.ndarray | None = None
    # Whether the batches resolve the sign of the texture's Σ c, and of each owner's value:
    # object -> why not (the texture under its own key), drawn neutral; empty: all resolved.
    unresolved: Mapping[str, str] = field(default_factory=dict)
    measured: bool = False  # the buffer has batch statistics

    @functools.cached_property
    def pooled_sum(self) -> float:
        """The pooled field's exact sum, in the buffer's units (it conserves ``signed_sum``)."""
        return math.fsum(self.pooled.ravel()) / self.unit_factor

    @functools.cached_property
    def pooled_empty(self) -> np.ndarray:
        """(H, W) bool: texels that pooling left with nothing in any channel."""
        empty: np.ndarray = np.abs(self.pooled).max(axis=2) == 0
        return empty

    @functools.cached_property
    def stderr_reduction(self) -> float | None:
        """Median over texels with an error of pooled error / unpooled error (same units)."""
        if self.stderr is None or self.stderr_pooled is None:
            return None
        unpooled = self.stderr * self.unit_factor
        has = unpooled > 0
        return float(np.median(self.stderr_pooled[has] / unpooled[has])) if has.any() else None

    @property
    def texel_area(self) -> float:
        height, width = self.raw.shape[:2]
        return 1.0 / (height * width)

    @property
    def unit_factor(self) -> float:
        """What turns a per-texel contribution into the channel's units."""
        return 1.0 / self.texel_area if self.channel.units == "uv_area" else 1.0


def texture_keys(buf: SensitivityBuffer, channel: ChannelSpec, index: int) -> tuple[str, ...]:
    """The texture keys a texel channel shows: its glob over textures, or every texture."""
    textures = [p for p in buf.params if p.is_texture and len(p.shape) == 3]
    keys = tuple(
        p.key
        for p in textures
        if channel.select is None or fnmatch.fnmatchcase(p.key, channel.select)
    )
    if not keys:
        what = f"matches no texture (textures: {', '.join(p.key for p in textures) or 'none'})"
        raise SpecError(
            f"texel channel {channel.name!r} {what}"
            if channel.select
            else f"texel channel {channel.name!r}: the buffer holds no bitmap texture",
            where=f"channels[{index}].select",
            hint="'sensaov params JOB' lists the texture keys",
        )
    return keys


def texel_fields(
    buf: SensitivityBuffer,
    channel: ChannelSpec,
    index: int,
    samplings: Mapping[str, TextureSampling],
) -> list[TexelField]:
    """Every (objective, texture) field a texel channel asks for."""
    keys = texture_keys(buf, channel, index)
    width, height = buf.provenance.get("resolution", [1, 1])
    samples = int(buf.provenance.get("spp", 1)) * width * height
    fields = []
    for objective in (o.name for o in buf.objectives):
        values = per_object(buf, objective, method="sum", weight=channel.weight)
        owners = unresolved_objects(buf, objective, buf.keys, values, channel.weight)
        noise = Uncertainty.of(buf, objective, "sum", channel.weight)
        for key in keys:
            sampling = samplings.get(key, TextureSampling(note="no lookup settings: defaults"))
            record = buf.param(key)
            raw = buf.grad(objective, key).astype(np.float64)
            if channel.weight == "value":
                raw = raw * buf.value(key)
            pool = default_pool(1, samples, (raw.shape[0], raw.shape[1]))
            if channel.pool is not None:  # the job's kind, and its radius or the default one
                radius = pool.radius if channel.pool.radius is None else channel.pool.radius
                pool = Pool(channel.pool.kind, radius, "job")
            factor = raw.shape[0] * raw.shape[1] if channel.units == "uv_area" else 1
            stderr = stderr_pooled = None
            unresolved = {n: why for n, why in owners.items() if n in record.owners}
            total = math.fsum(raw.ravel())
            why = None if noise is None else unresolved_reason(noise.error([key], total), total)
            if why is not None:  # the texture's own Σ c, under its key
                unresolved[key] = why
            if buf.statistics is not None:
                stderr = buf.statistics.stderr[objective][key].astype(np.float64)
                if channel.weight == "value":
                    stderr = stderr * np.abs(buf.value(key))
                stderr_pooled = np.sqrt(pool_variance(stderr**2, pool, sampling.wrap)) * factor
            fields.append(
                TexelField(
                    objective,
                    channel,
                    record,
                    sampling,
                    raw,
                    pool_field(raw, pool, sampling.wrap) * factor,
                    pool,
                    math.fsum(raw.ravel()),
                    {name: float(values[name]) for name in record.owners},
                    _notes(record, sampling),
                    stderr,
                    stderr_pooled,
                    unresolved,
                    buf.statistics is not None,
                )
            )
    return fields


def _notes(record: ParamRecord, sampling: TextureSampling) -> tuple[str, ...]:
    notes = [sampling.note] if sampling.note else []
    if record.trust == "no_gradient":
        notes.append(f"no gradient reached this texture: {record.note}")
    if record.type not in COLOUR_TYPES:
        notes.append(
            f"this bitmap drives '{record.type}', not a colour: its texels are "
            f"{record.type} values and the layer has {record.shape[2]} channel(s)"
        )
    if record.trust not in ("verified", "no_gradient"):
        notes.append(f"gradient {record.trust}: {record.note}")
    return tuple(notes)


PANELS = ("object", "texel", "joint")
_UNSAFE = re.compile(r"[^A-Za-z0-9_]")


@dataclass(frozen=True)
class TexelPass:
    pass_name: str  # "<channel>_<texture token>_<panel>"
    panel: str
    data: np.ndarray  # (H, W) or (H, W, 3) float32, encoded
    scale: Scale
    metadata: dict[str, str]
    # (H, W) bool: drawn neutral (an unresolved owner, or the whole texture unresolved); None
    neutral: np.ndarray | None = None


def texture_token(key: str) -> str:
    """A texture key as one name token: ``wall.reflectance.data`` -> ``wall_reflectance``."""
    return _UNSAFE.sub("_", key.removesuffix(".data"))


def owners_in(tf: TexelField, visibility: VisibilityPass) -> list[str]:
    """The texture's owners among this view's objects, in the order its footprint uses."""
    return [o for o in tf.record.owners if o in visibility.objects]


def texture_footprint(tf: TexelField, visibility: VisibilityPass) -> Footprint:
    """How ``visibility``'s camera sees ``tf``'s texture (shared by objectives and panels)."""
    assert visibility.sample_uv is not None and visibility.sample_object is not None  # traced so
    owners = np.array([visibility.objects.index(o) for o in owners_in(tf, visibility)], np.int64)
    return footprint(
        tf.raw.shape[:2], tf.sampling, visibility.sample_uv, visibility.sample_object, owners
    )


def texel_passes(tf: TexelField, visibility: VisibilityPass, seen_by: Footprint) -> list[TexelPass]:
    """The three panels of ``tf`` in this camera, with what each one means in its metadata."""
    seen = seen_by.seen(tf.raw.shape[:2])
    notes = list(tf.notes)
    if not seen.any():
        notes.append("no sample of this camera sees this texture (painted 0)")
    common = _common_metadata(tf, seen, notes)
    panels = [
        _object_panel(tf, visibility, common),
        _texel_panel(tf, seen_by, common),
        _joint_panel(tf, seen_by, owners_in(tf, visibility), common),
    ]
    if not tf.unresolved:
        return panels
    # The object panel greys its unresolved owners; the texel and joint panels, every texel
    # they paint when the texture's own Σ c is unresolved (its field is then noise as a whole).
    owners = visibility.paint(np.array([1.0 if n in tf.unresolved else 0.0
                                        for n in visibility.objects])) > 0.5  # fmt: skip
    everywhere = tf.record.key in tf.unresolved
    return [
        replace(p, neutral=owners if p.panel == "object" else
                (_painted_mask(p.data) if everywhere else None))
        for p in panels
    ]  # fmt: skip


def _painted_mask(data: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels a panel paints (any channel non-zero)."""
    return np.asarray(data != 0) if data.ndim == 2 else np.asarray((data != 0).any(axis=2))


def _common_metadata(tf: TexelField, seen: np.ndarray, notes: list[str]) -> dict[str, str]:
    return {
        "texture": tf.record.key,
        "texture_type": tf.record.type,
        "texture_size": f"{tf.raw.shape[1]}x{tf.raw.shape[0]}x{tf.raw.shape[2]}",
        "owners": ", ".join(tf.record.owners),
        "lookup": tf.sampling.describe(),
        "pool": tf.pool.describe(),
        "pool_white_noise_factor": repr(white_noise_factor(tf.pool)),
        "units": tf.channel.units,
        "stderr_reduction": "none" if tf.stderr_reduction is None else repr(tf.stderr_reduction),
        "signed_sum": repr(tf.signed_sum),
        "pooled_sum": repr(tf.pooled_sum),
        "texels_seen": str(int(seen.sum())),
        "seen_empty_before_pool": str(int(np.count_nonzero(~tf.raw.any(axis=2) & seen))),
        "seen_empty_after_pool": str(int(np.count_nonzero(tf.pooled_empty & seen))),
        "unverified": json.dumps(
            [tf.record.key] if tf.record.trust not in ("verified", "no_gradient") else []
        ),
        "estimators": json.dumps({tf.record.key: tf.record.estimator}),
        "resolution": "measured: 95 % Student t, heavy tails"
        if tf.measured
        else "no error: the buffer has one batch",
        "unresolved": json.dumps(dict(tf.unresolved)),
        "notes": " | ".join(notes),
    }


def _as_layer_data(painted: np.ndarray) -> np.ndarray:
    """(H, W, C) painted field as what a layer stores: Y for one channel, RGB for three."""
    if painted.shape[2] == 3:
        return painted
    return painted.sum(axis=2) if painted.shape[2] != 1 else painted[..., 0]


def _pass(
    tf: TexelField,
    common: dict[str, str],
    panel: str,
    data: np.ndarray,
    scale: Scale,
    meaning: str,
    encoding: str,
    panel_scale: str,
) -> TexelPass:
    """A panel's pass, its metadata in the order the layer records it."""
    meta = {
        **common,
        "panel": panel,
        "meaning": meaning,
        "encoding": encoding,
        "scale": scale.describe(),
        "panel_scale": panel_scale,
    }
    name = f"{tf.channel.name}_{texture_token(tf.record.key)}_{panel}"
    return TexelPass(name, panel, data, scale, meta)


def _object_panel(tf: TexelField, visibility: VisibilityPass, common: dict[str, str]) -> TexelPass:
    # object_values holds the owners only: every other object paints 0
    values = np.array([tf.object_values.get(name, 0.0) for name in visibility.objects])
    peak = max((abs(v) for v in tf.object_values.values()), default=0.0)
    meaning = "Σ θ·∂M/∂θ over all parameters of each owner (weight as the channel)"
    painted = visibility.paint(values)
    unscaled = Scale(0.0, 1.0)
    return _pass(tf, common, "object", painted, unscaled, meaning, "linear;signed", repr(peak))


def _texel_panel(tf: TexelField, seen_by: Footprint, common: dict[str, str]) -> TexelPass:
    encoding = replace(Encoding.from_channel(tf.channel), aggregate="sum")
    field = np.abs(tf.pooled) if encoding.sign == "magnitude" else tf.pooled
    painted = seen_by.paint(field, np.ones(max(len(tf.record.owners), 1)))
    peak = float(np.abs(field).max()) if field.size else 0.0
    scale = choose_scale(encoding, {"texel_peak": peak}, painted)
    data = encode_image(_as_layer_data(painted), encoding, scale.threshold, scale.scale)
    unit = "per unit UV area" if tf.channel.units == "uv_area" else "per texel"
    meaning = f"pooled θ·∂M/∂θ {unit} read at each hit UV (weight as the channel)"
    return _pass(tf, common, "texel", data, scale, meaning, encoding.describe(), repr(peak))


def _joint_panel(
    tf: TexelField, seen_by: Footprint, names: list[str], common: dict[str, str]
) -> TexelPass:
    # A texel's share sums its components (scaling the whole texel), so the panel is one Y.
    share = tf.pooled.sum(axis=2, keepdims=True) / tf.unit_factor / tf.texel_area
    inverse = [1.0 / tf.object_values[n] if tf.object_values[n] else 0.0 for n in names]
    painted = seen_by.paint(share, np.array(inverse))
    zero = [name for name, value in tf.object_values.items() if not value]
    if zero:
        note = f"object value 0 for {', '.join(zero)}: painted 0"
        common = {**common, "notes": " | ".join(filter(None, [common["notes"], note]))}
    meaning = "each texel's share of its object's value per unit UV area: Σ_rgb c·H·W / V"
    spread = "1.0 (the object's whole value spread evenly over the texture)"
    data, encoding = _as_layer_data(painted), "linear;signed;normalize=joint"
    return _pass(tf, common, "joint", data, Scale(0.0, 1.0), meaning, encoding, spread)
