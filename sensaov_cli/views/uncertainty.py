"""Standard errors of groups and the stability of rankings, from a buffer's batch statistics.

Every group a view ranks (a key, an object, a type, a sunburst wedge) gets, for each batch, the
value its signed sum and its score would have had from that batch alone: the signed sum exactly
(sums add up), the ℓ2 and rms scores to first order (the projection on the mean, see
:mod:`sensaov_cli.buffer.statistics`). Their spp-weighted spread gives the standard errors; a
bootstrap over the batches gives how often the top of a ranking keeps its order. Buffers without
statistics (one batch) give None everywhere: no error is claimed that was not measured.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.statistics import (
    PROJ_RAW,
    PROJ_VALUE,
    SIGNIFICANCE_LEVEL,
    SUM_RAW,
    SUM_VALUE,
    interval_factor,
    pooled_stderr,
)
from sensaov_cli.vocabulary import Aggregate, Weight

STABILITY_TOP = 3  # the ranking's top this many rows must keep their order
RESAMPLES = 1000  # bootstrap resamples of the batches (seeded: the figure is reproducible)


@dataclass(frozen=True)
class GroupError:
    score_se: float
    signed_se: float
    factor: float  # standard errors in the two-sided 95 % interval: Student's t at k - 1 dof

    def significant(self, signed: float) -> bool:
        """Whether the sign of ``signed`` is beyond noise: |Σc| > factor · SE, i.e. 0 lies
        outside the 95 % interval (t with k − 1 degrees of freedom, docs/rankings.md)."""
        return abs(signed) > self.factor * self.signed_se


@dataclass(frozen=True)
class Significance:
    """The rule a ranking's ``significant`` column applies, recorded beside it."""

    level: float  # two-sided coverage of the interval
    batches: int
    dof: int  # batches - 1
    factor: float  # the t quantile: |Σc| > factor · SE is significant

    @classmethod
    def of(cls, batches: int) -> Significance:
        return cls(SIGNIFICANCE_LEVEL, batches, batches - 1, interval_factor(batches))


class Uncertainty:
    """One objective's batch table, read once; None from :meth:`of` without statistics."""

    def __init__(self, buf: SensitivityBuffer, objective: str, method: Aggregate, weight: Weight):
        statistics = buf.statistics
        assert statistics is not None
        self.sums = statistics.batch_sums[objective]
        self.spp = statistics.spp
        self.index = {key: i for i, key in enumerate(buf.keys)}
        self.counts = {p.key: math.prod(p.shape) for p in buf.params}  # no texel is read
        self.method, self.weight = method, weight
        self.significance = Significance.of(len(self.spp))

    @classmethod
    def of(
        cls, buf: SensitivityBuffer, objective: str, method: Aggregate, weight: Weight
    ) -> Uncertainty | None:
        return None if buf.statistics is None else cls(buf, objective, method, weight)

    @property
    def batches(self) -> int:
        return len(self.spp)

    def batch_values(self, keys: Sequence[str], score: float) -> tuple[np.ndarray, np.ndarray]:
        """Per batch, the group's score and signed sum (their spp-weighted means: the group's)."""
        rows = self.sums[[self.index[k] for k in keys]]  # (0, k, C) for no key: sums of 0
        value = self.weight == "value"
        signed = rows[:, :, SUM_VALUE if value else SUM_RAW].sum(axis=0)
        if self.method == "sum":
            return signed, signed
        count = sum(self.counts[k] for k in keys)
        l2 = score if self.method == "l2" else score * math.sqrt(count)
        projection = rows[:, :, PROJ_VALUE if value else PROJ_RAW].sum(axis=0)
        scores = projection / l2 if l2 > 0 else np.zeros(self.batches)
        return (scores if self.method == "l2" else scores / math.sqrt(count)), signed

    def error(self, keys: Sequence[str], score: float) -> GroupError:
        scores, signed = self.batch_values(keys, score)
        return GroupError(
            float(pooled_stderr(scores, self.spp)),
            float(pooled_stderr(signed, self.spp)),
            self.significance.factor,
        )

    def stability(
        self, ordered: Sequence[tuple[str, float]], grouped: Mapping[str, Sequence[str]]
    ) -> tuple[float, int] | None:
        """How often (fraction of bootstrap resamples of the batches) the top rows keep their
        order, and how many rows that is; None when fewer than two rows are ranked."""
        top = min(STABILITY_TOP, len(ordered))
        if top < 2:
            return None
        table = np.stack([self.batch_values(grouped[name], s)[0] for name, s in ordered])
        rng = np.random.default_rng(0)
        picks = rng.integers(0, self.batches, size=(RESAMPLES, self.batches))
        weights = np.asarray(self.spp, dtype=np.float64)[picks]  # (R, k)
        means = np.einsum("rk,grk->rg", weights, table[:, picks]) / weights.sum(axis=1)[:, None]
        order = np.argsort(-np.abs(means), axis=1, kind="stable")[:, :top]
        held = (order == np.arange(top)).all(axis=1)
        return float(held.mean()), top
