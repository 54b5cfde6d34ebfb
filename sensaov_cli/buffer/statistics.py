"""Standard errors of the stored gradients, from independent batches (or farm shards) (§7).

A run with ``render.batches: k`` (``auto`` by default: 8, at most spp) renders k independent
batches of spp/k samples each (their own primal and backward passes at seeds derived from the
job's); ``sensaov merge`` treats each shard as one batch. The buffer keeps the spp-weighted
mean, and from the k batch means:

- per element, the standard error of the mean: with n_b samples in batch b, N = Σ n_b and
  x̄ = Σ n_b x_b / N, the per-sample variance is σ² = Σ n_b (x_b − x̄)² / (k − 1) and the
  error of x̄ is sqrt(σ² / N) (for equal batches: the sample standard deviation of the batch
  means over sqrt(k));
- per parameter and batch, four scalars from which any group's value can be recomputed for every
  batch, so the error of a group (an object, a type) and the stability of a ranking follow
  without keeping the batches' arrays: Σ g_b and Σ θ g_b (the signed sums, exact), and
  ⟨ḡ, g_b⟩ and ⟨θḡ, θg_b⟩, the batch's projection on the mean (the ℓ2 norm's first-order,
  delta-method linearisation: ‖ḡ_G‖ ≈ Σ_{p∈G} ⟨ḡ_p, g_{p,b}⟩ / ‖ḡ_G‖, correlations included).

Each parameter's sums (:class:`ParamSums`), stored beside its arrays, are what a ranking reads
instead of texels. The writer computes them with the very functions the queries use on arrays,
so a ranking read from the sums is the ranking computed from the arrays, to the last bit.

A mean over k batches has a standard error estimated from those same k batches, so
(mean − truth) / SE follows Student's t with k − 1 degrees of freedom, not a normal law
(:func:`interval_factor`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from sensaov_cli.errors import BufferContentError

# Columns of ``batch_sums[objective]`` (P, k, 4): which statistic, by weight.
SUM_RAW, SUM_VALUE, PROJ_RAW, PROJ_VALUE = range(4)
COLUMNS = ("sum_raw", "sum_value", "projection_raw", "projection_value")
# The columns of an objective's parameter sums, one row per parameter (docs/buffer-format.md).
SUMS_COLUMNS = ("sum_sq_value", "total_value", "sum_sq_raw", "total_raw", "hidden", "raw_signed")
SIGNIFICANCE_LEVEL = 0.95  # two-sided: a sign is significant when outside the 95 % interval


@dataclass(frozen=True)
class Statistics:
    """Batch-level figures of a buffer; see the module docstring and docs/buffer-format.md."""

    source: str  # "batches" (one run) or "shards" (sensaov merge)
    spp: tuple[int, ...]  # samples per pixel of each batch
    seeds: tuple[int, ...]  # primal seed of each batch
    objective_values: Mapping[str, tuple[float, ...]]  # M of each batch, per objective
    stderr: Mapping[str, Mapping[str, np.ndarray]]  # objective -> key -> per-element error
    batch_sums: Mapping[str, np.ndarray]  # objective -> (P, k, 4) float64, params in key order

    @property
    def batches(self) -> int:
        return len(self.spp)

    def __post_init__(self) -> None:
        if len(self.spp) < 2 or len(self.seeds) != len(self.spp) or min(self.spp) < 1:
            raise BufferContentError(
                f"statistics need >= 2 batches of >= 1 spp with a seed each, got spp {self.spp}"
            )
        for name, sums in self.batch_sums.items():
            if sums.ndim != 3 or sums.shape[1:] != (self.batches, len(COLUMNS)):
                raise BufferContentError(f"batch sums of {name!r} have shape {sums.shape}")
            if not np.isfinite(sums).all():
                raise BufferContentError(f"batch sums of {name!r} are not all finite")
        for name, values in self.objective_values.items():
            if len(values) != self.batches:
                raise BufferContentError(f"objective {name!r} has {len(values)} batch values")


def whole_run(provenance: Mapping[str, Any]) -> bool:
    """Whether a buffer was written by one ``sensaov run`` of the whole job, in any number of
    batches: not a merge, not a shard or an objective task. Only such a buffer can be replayed
    batch for batch, seed for seed (forward channels, transport duality, ``check``)."""
    task = provenance.get("task") or {}
    return (
        not provenance.get("merged_from")
        and task.get("shard") is None
        and not task.get("objectives")
    )


def pooled_stderr(means: np.ndarray, spp: Sequence[int]) -> np.ndarray:
    """Standard error of the spp-weighted mean of batch ``means`` (axis 0), see module doc."""
    n = np.asarray(spp, dtype=np.float64).reshape((-1,) + (1,) * (means.ndim - 1))
    total = float(n.sum())
    mean = (n * means).sum(axis=0) / total
    variance = (n * (means - mean) ** 2).sum(axis=0) / (len(spp) - 1)
    return np.sqrt(variance / total)


def weighted_mean(arrays: Sequence[np.ndarray], spp: Sequence[int]) -> np.ndarray:
    """The spp-weighted mean, accumulated in float64 and returned as float32."""
    total = float(sum(spp))
    acc = np.zeros(arrays[0].shape, dtype=np.float64)
    for array, n in zip(arrays, spp, strict=True):
        acc += array.astype(np.float64) * (n / total)
    return acc.astype(np.float32)


def combine_batches(
    keys: Sequence[str],
    values: Mapping[str, np.ndarray],
    batch_grads: Sequence[Mapping[str, Mapping[str, np.ndarray]]],
    batch_values: Sequence[Mapping[str, float]],
    spp: Sequence[int],
    seeds: Sequence[int],
    source: str,
) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, float], Statistics | None]:
    """Mean gradients, mean objective values and (for >= 2 batches) their statistics."""
    if len(batch_grads) == 1:  # one batch is its own mean: no copy of every array
        only = batch_grads[0]
        return {o: dict(g) for o, g in only.items()}, dict(batch_values[0]), None
    objectives = list(batch_grads[0])
    grads = {
        name: {key: weighted_mean([b[name][key] for b in batch_grads], spp) for key in keys}
        for name in objectives
    }
    total = float(sum(spp))
    mean_values = {
        name: float(sum(v[name] * n for v, n in zip(batch_values, spp, strict=True)) / total)
        for name in objectives
    }
    stderr: dict[str, dict[str, np.ndarray]] = {}
    sums: dict[str, np.ndarray] = {}
    for name in objectives:
        stderr[name] = {}
        sums[name] = table = np.zeros((len(keys), len(batch_grads), len(COLUMNS)), np.float64)
        for p, key in enumerate(keys):
            stderr[name][key], table[p] = _key_batches(
                [b[name][key] for b in batch_grads], grads[name][key],
                values[key].astype(np.float64), spp,
            )  # fmt: skip
    statistics = Statistics(
        source=source,
        spp=tuple(int(n) for n in spp),
        seeds=tuple(int(s) for s in seeds),
        objective_values={name: tuple(float(v[name]) for v in batch_values) for name in objectives},
        stderr=stderr,
        batch_sums=sums,
    )
    return grads, mean_values, statistics


def _key_batches(
    grads: Sequence[np.ndarray], mean: np.ndarray, theta: np.ndarray, spp: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """One parameter's standard error (float32) and (k, 4) batch rows, SUM_RAW ... PROJ_VALUE."""
    stack = np.stack([g.astype(np.float64) for g in grads])
    mean = mean.astype(np.float64)
    weighted_mean_, rows = theta * mean, []
    for g in stack:
        weighted = theta * g
        rows.append((g.sum(), weighted.sum(), (mean * g).sum(), (weighted_mean_ * weighted).sum()))
    return pooled_stderr(stack, spp).astype(np.float32), np.array(rows)


def with_batch_estimates(
    statistics: Statistics,
    keys: Sequence[str],
    key: str,
    batch_grads: Mapping[str, Sequence[np.ndarray]],
    theta: np.ndarray,
) -> tuple[Statistics, dict[str, np.ndarray]]:
    """``statistics`` with parameter ``key``'s batch estimates replaced by ``batch_grads``
    (objective -> one array per batch: a repair's, render/verify/repair.py), and their new means."""
    index = list(keys).index(key)
    stderr = {name: dict(per_key) for name, per_key in statistics.stderr.items()}
    sums = {name: table.copy() for name, table in statistics.batch_sums.items()}
    means = {}
    for name, grads in batch_grads.items():
        means[name] = weighted_mean(grads, statistics.spp)
        stderr[name][key], sums[name][index] = _key_batches(
            grads, means[name], theta, statistics.spp
        )
    return replace(statistics, stderr=stderr, batch_sums=sums), means


@dataclass(frozen=True)
class KeyStats:
    """The sufficient statistics of one parameter's contributions c for one objective."""

    sum_sq: float  # Σ c²
    total: float  # Σ c
    count: int  # number of components


def stats_of(grad: np.ndarray, value: np.ndarray | None) -> KeyStats:
    """Σc², Σc and the count of c = value·grad (or grad, without a value)."""
    if not grad.any():  # an untouched texture (no gradient): one cheap pass, no float64 copy
        return KeyStats(sum_sq=0.0, total=0.0, count=grad.size)
    weight = 1.0 if value is None else value.ravel()  # times 1.0 in float64: exact
    c = np.multiply(grad.ravel(), weight, dtype=np.float64)
    return KeyStats(sum_sq=float(c @ c), total=float(c.sum()), count=c.size)


def hidden_by_zero(value: np.ndarray, grad: np.ndarray) -> tuple[int, float]:
    """Components with θ = 0 where ∂M/∂θ ≠ 0, and Σ ∂M/∂θ when there are any (else 0.0)."""
    hidden = int(np.count_nonzero((value == 0) & (grad != 0)))
    return hidden, float(grad.astype(np.float64).sum()) if hidden else 0.0


def mean_value(value: np.ndarray) -> float | None:
    """One number for a value array (a colour, a texture): its mean; None when it is empty."""
    return float(value.astype("float64").mean()) if value.size else None


@dataclass(frozen=True, eq=False)
class ParamSums:
    """The sums of every parameter (``keys``, buffer order): per objective a (P, 6) table."""

    keys: tuple[str, ...]
    tables: Mapping[str, np.ndarray]  # objective -> (P, len(SUMS_COLUMNS)) float64
    value_means: np.ndarray  # (P,) float64; 0.0 for an empty value
    _row: Mapping[str, int] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_row", {key: i for i, key in enumerate(self.keys)})

    def stats(self, objective: str, key: str, weight: str, count: int) -> KeyStats:
        row = self.tables[objective][self._row[key]]
        first = 0 if weight == "value" else 2
        return KeyStats(sum_sq=float(row[first]), total=float(row[first + 1]), count=count)

    def hidden(self, objective: str, key: str) -> tuple[int, float]:
        row = self.tables[objective][self._row[key]]
        return int(row[4]), float(row[5])

    def mean(self, key: str, size: int) -> float | None:
        return float(self.value_means[self._row[key]]) if size else None


def sums_of(
    keys: Sequence[str],
    values: Mapping[str, np.ndarray],
    grads: Mapping[str, Mapping[str, np.ndarray]],
) -> ParamSums:
    """The sums computed from the arrays (copies sharing their arrays are summed once)."""
    tables = {}
    for objective, per_key in grads.items():
        done: dict[tuple[int, int], tuple[float, ...]] = {}
        rows = []
        for key in keys:
            grad, value = per_key[key], values[key]
            pair = (id(grad), id(value))
            if pair not in done:
                by_value, raw = stats_of(grad, value), stats_of(grad, None)
                hidden, raw_signed = hidden_by_zero(value, grad)
                done[pair] = (by_value.sum_sq, by_value.total, raw.sum_sq, raw.total,
                              float(hidden), raw_signed)  # fmt: skip
            rows.append(done[pair])
        tables[objective] = np.array(rows, np.float64).reshape(len(keys), len(SUMS_COLUMNS))
    means = [mean_value(values[key]) for key in keys]
    value_means = np.array([0.0 if m is None else m for m in means], np.float64)
    return ParamSums(tuple(keys), tables, value_means)


# Heavy tails (:func:`heavy_tail`). A mean of k batch estimates is trusted with a standard error
# from the same k batches; both assume the batch estimates are roughly normal (light-tailed).
# Where a rare, large path lands in one batch, that batch lies far from the others, carries most
# of the spread, and the mean and its error both follow it: the interval cannot be trusted.
MIN_BATCHES_FOR_TAILS = 4  # fewer batches cannot tell a tail from ordinary spread
# How often light-tailed (normal) batch estimates are called heavy-tailed, per number tested.
TAIL_FALSE_ALARM = 0.01
_TAIL_DRAWS = 2_000_000  # normal variates drawn to find each batch count's threshold


def heavy_tail(
    batch_values: Sequence[float] | np.ndarray, spp: Sequence[int] | None = None
) -> str | None:
    """Why the batch estimates ``batch_values`` of one number look heavy-tailed (so that neither
    their mean nor its standard error can be trusted), or None.

    The test is an outlier test on the batches, robust to the outliers themselves: each batch's
    distance from the batches' median, in units of the median absolute deviation (MAD), both
    scaled by sqrt(spp) where ``spp`` (samples per batch) differ. Its largest value is compared
    with the point that normal batch estimates of the same count exceed with probability
    TAIL_FALSE_ALARM (:func:`tail_threshold`); beyond it, one batch (or a few) disagrees with the
    others by more than their own spread predicts, i.e. a few batches carry the sum. Skewed but
    light-tailed estimates (a mean of exponential or log-normal samples) fire little more
    often than normal ones (docs/verification.md, "Heavy tails", has the measured rates).

    The shared entry point of the views' ``noisy`` label; render/verify routes parameters it
    fires on to a repair."""
    values = np.asarray(batch_values, dtype=np.float64)
    if values.size < MIN_BATCHES_FOR_TAILS or not np.isfinite(values).all():
        return None
    weights = np.ones(values.size) if spp is None else np.sqrt(np.asarray(spp, np.float64))
    deviations = np.abs(values - np.median(values)) * weights / float(weights.mean())
    if not deviations.any():
        return None
    scale = float(np.median(deviations))
    limit = tail_threshold(values.size)
    outliers = int(np.count_nonzero(deviations > limit * scale))
    if outliers == 0:
        return None
    if scale == 0.0:
        how = f"differ from the other {values.size - outliers}, which are all equal"
    else:
        how = (
            f"lie up to {float(deviations.max()) / scale:.0f}x the batches' median deviation "
            f"from their median (normal estimates stay within {limit:.1f}x "
            f"{1 - TAIL_FALSE_ALARM:.0%} of the time)"
        )
    return (
        f"heavy-tailed: {outliers} of {values.size} batch estimates {how}: a few batches carry "
        "the sum, so neither it nor its error can be trusted"
    )


@functools.lru_cache(maxsize=64)
def tail_threshold(batches: int, false_alarm: float = TAIL_FALSE_ALARM) -> float:
    """The largest |x − median| / MAD among ``batches`` normal variates exceeds this with
    probability ``false_alarm``: found by a seeded simulation (the same every run)."""
    rng = np.random.default_rng(batches)
    draws = max(4000, _TAIL_DRAWS // batches)
    sample = rng.standard_normal((draws, batches))
    deviations = np.abs(sample - np.median(sample, axis=1, keepdims=True))
    ratio = deviations.max(axis=1) / np.median(deviations, axis=1)
    return float(np.quantile(ratio, 1.0 - false_alarm))


def t_cdf(x: float, dof: float) -> float:
    """P(T ≤ x) for Student's t with ``dof`` > 0 degrees of freedom."""
    if not dof > 0:
        raise ValueError(f"degrees of freedom must be positive, got {dof}")
    if x == 0.0:
        return 0.5
    tail = 0.5 * _incomplete_beta(dof / (dof + x * x), dof / 2.0, 0.5)
    return 1.0 - tail if x > 0 else tail


def t_quantile(probability: float, dof: float) -> float:
    """The x with P(T ≤ x) = ``probability`` (bisection on :func:`t_cdf`, to 1e-12)."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"probability must lie in (0, 1), got {probability}")
    if probability < 0.5:
        return -t_quantile(1.0 - probability, dof)
    low, high = 0.0, 1.0
    while t_cdf(high, dof) < probability:
        high *= 2.0
    while high - low > 1e-12 * max(1.0, high):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if t_cdf(middle, dof) < probability else (low, middle)
    return 0.5 * (low + high)


def interval_factor(batches: int, level: float = SIGNIFICANCE_LEVEL) -> float:
    """How many standard errors from ``batches`` batches make a two-sided ``level`` interval."""
    if batches < 2:
        raise ValueError(f"a standard error needs at least 2 batches, got {batches}")
    return t_quantile(0.5 + level / 2.0, batches - 1)


def _incomplete_beta(x: float, a: float, b: float) -> float:
    """The regularised incomplete beta function I_x(a, b), by its continued fraction."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (
        math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    )
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _fraction(x, a, b) / a
    return 1.0 - math.exp(log_front) * _fraction(1.0 - x, b, a) / b


def _fraction(x: float, a: float, b: float) -> float:
    """The continued fraction of I_x(a, b) (modified Lentz), converging for x < (a+1)/(a+b+2)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    result = d
    for m in range(1, 300):
        for numerator in (
            m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1)),
        ):
            d = 1.0 + numerator * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + numerator / c
            c = c if abs(c) > tiny else tiny
            result *= c * d
        if abs(c * d - 1.0) < 1e-15:
            break
    return result
