"""Sum-conserving pooling of texel fields (paper §6).

The gradient and the visible texel are sampled independently, so at low spp a texel field is
sparse and spiky. Pooling spreads each texel's value over its neighbours before projection.
Every kind conserves the field's sum exactly: each source texel's mass is divided among the
texels it reaches inside the texture (wrapping around for ``repeat``, renormalised at the edges
otherwise), so the pooled field still sums to the buffer's signed sum of the parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sensaov_cli.vocabulary import PoolKind

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
