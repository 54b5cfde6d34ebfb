"""Standard errors of the stored gradients, from independent batches (or farm shards) (§7).

A run with ``render.batches: k`` renders k independent batches of spp/k samples each (their own
primal and backward passes at seeds derived from the job's); ``sensaov merge`` treats each shard
as one batch. The buffer keeps the spp-weighted mean, and from the k batch means:

- per element, the standard error of the mean: with n_b samples in batch b, N = Σ n_b and
  x̄ = Σ n_b x_b / N, the per-sample variance is σ² = Σ n_b (x_b − x̄)² / (k − 1) and the
  error of x̄ is sqrt(σ² / N) (for equal batches: the sample standard deviation of the batch
  means over sqrt(k));
- per parameter and batch, four scalars from which any group's value can be recomputed for every
  batch, so the error of a group (an object, a type) and the stability of a ranking follow
  without keeping the batches' arrays: Σ g_b and Σ θ g_b (the signed sums, exact), and
  ⟨ḡ, g_b⟩ and ⟨θḡ, θg_b⟩, the batch's projection on the mean (the ℓ2 norm's first-order,
  delta-method linearisation: ‖ḡ_G‖ ≈ Σ_{p∈G} ⟨ḡ_p, g_{p,b}⟩ / ‖ḡ_G‖, correlations included).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from sensaov_cli.errors import BufferContentError

# Columns of ``batch_sums[objective]`` (P, k, 4): which statistic, by weight.
SUM_RAW, SUM_VALUE, PROJ_RAW, PROJ_VALUE = range(4)
COLUMNS = ("sum_raw", "sum_value", "projection_raw", "projection_value")


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


def single_pass(provenance: Mapping[str, Any]) -> bool:
    """Whether a buffer holds one backward pass per objective over the whole job's samples:
    not a mean of batches, not a merge, not a shard or an objective task. Only such a buffer
    can be replayed seed for seed (forward channels, transport duality, ``check``)."""
    task = provenance.get("task") or {}
    return (
        len(provenance.get("batches", ())) <= 1
        and not provenance.get("merged_from")
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
    if len(batch_grads) < 2:
        return grads, mean_values, None
    stderr: dict[str, dict[str, np.ndarray]] = {}
    sums: dict[str, np.ndarray] = {}
    for name in objectives:
        stderr[name] = {}
        table = np.zeros((len(keys), len(batch_grads), len(COLUMNS)), dtype=np.float64)
        for p, key in enumerate(keys):
            stack = np.stack([b[name][key].astype(np.float64) for b in batch_grads])
            stderr[name][key] = pooled_stderr(stack, spp).astype(np.float32)
            theta = values[key].astype(np.float64)
            mean = grads[name][key].astype(np.float64)
            for b in range(len(batch_grads)):
                table[p, b] = batch_row(stack[b], mean, theta)
        sums[name] = table
    statistics = Statistics(
        source=source,
        spp=tuple(int(n) for n in spp),
        seeds=tuple(int(s) for s in seeds),
        objective_values={name: tuple(float(v[name]) for v in batch_values) for name in objectives},
        stderr=stderr,
        batch_sums=sums,
    )
    return grads, mean_values, statistics


def batch_row(grad: np.ndarray, mean: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """The four batch scalars of one parameter (columns SUM_RAW ... PROJ_VALUE)."""
    weighted, weighted_mean_ = theta * grad, theta * mean
    return np.array(
        [
            grad.sum(),
            weighted.sum(),
            float((mean * grad).sum()),
            float((weighted_mean_ * weighted).sum()),
        ]
    )


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
        stack = np.stack([g.astype(np.float64) for g in grads])
        mean = weighted_mean(grads, statistics.spp)
        stderr[name][key] = pooled_stderr(stack, statistics.spp).astype(np.float32)
        for b in range(len(grads)):
            sums[name][index, b] = batch_row(stack[b], mean.astype(np.float64), theta)
        means[name] = mean
    return replace(statistics, stderr=stderr, batch_sums=sums), means
