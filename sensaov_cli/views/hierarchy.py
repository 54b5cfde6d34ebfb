"""Rankings of the hierarchy (numpy only): ``rank``'s summary, one cut (``rank --by``), and
the sunburst's rings.

The summary gives per objective the top parameters and objects and every type's score; a
ranking at one cut (key, object or type) gives one table per objective (columns:
docs/rankings.md). Objects and types add up the trusted parameters only (see below) and
rank the untrusted rest apart; ``no_gradient`` parameters are listed apart, never scored, and a
group made only of them is not ranked; zero-valued parameters are flagged with their raw
gradient. :mod:`sensaov_cli.outputs.tables` writes text, JSON and CSV from these types.

A row's share follows its score: under the sum (the default) its |Σc| over Σ|Σc| of every
ranked parameter (the keys' shares sum to 1; a group with both signs has less than its parts);
under ℓ2 or rms its Σc² over Σc² of every ranked parameter, which adds up over disjoint groups
(object shares may sum past 1: a shared parameter counts for each owner).

One score by default (:data:`~sensaov_cli.vocabulary.DEFAULT_AGGREGATE`, the signed sum Σc),
the one the pictures paint; every row also carries its rank by the other score (ℓ2 beside the
sum, the sum beside ℓ2 or rms), flagged where the two orders disagree markedly. With batch
statistics every row is *resolved* or not (its signed sum outside its Student-t 95 % interval,
and batches that do not look heavy-tailed); the unresolved rows rank after the resolved ones.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import KeyStats, combine, groups, key_stats, rank, scores
from sensaov_cli.buffer.statistics import (
    PROJ_RAW,
    PROJ_VALUE,
    SIGNIFICANCE_LEVEL,
    SUM_RAW,
    SUM_VALUE,
    heavy_tail,
    hidden_by_zero,
    interval_factor,
    mean_value,
    pooled_stderr,
)
from sensaov_cli.errors import QueryError
from sensaov_cli.vocabulary import (
    DEFAULT_AGGREGATE,
    ESTIMATORS,
    Aggregate,
    Cut,
    Grouping,
    Order,
    Trust,
    Untrusted,
    Weight,
)

SUMMARY_FORMAT = "sensaov-summary"
SUMMARY_VERSION = 4
RANKING_FORMAT = "sensaov-ranking"
RANKING_VERSION = 4  # 4: resolved, dof, other score; not_seen_by (docs/rankings.md)
# The grouping each cut reads: a key row is one parameter.
GROUPING_OF: dict[Cut, Grouping] = {"key": "param", "object": "object", "type": "type"}
# The score shown beside a ranking's own: the per-component ℓ2 beside the total, else the total.
OTHER_SCORE: dict[Aggregate, Aggregate] = {"sum": "l2", "l2": "sum", "rms": "sum"}
# A row whose rank by the other score is this many places or more from its own is flagged: the
# two scores tell a reader different things about it (a texture's many small same-sign texels).
ORDER_GAP = 3


def other_score(method: Aggregate) -> Aggregate:
    return OTHER_SCORE[method]


def orders_disagree(rank: int, other_rank: int) -> bool:
    return abs(rank - other_rank) >= ORDER_GAP


# Trusted numbers (docs/encoding.md). A headline view (the ``objects`` and ``types`` layers,
# ranked objects and types, the sunburst's rings) sums a group's parameters. One whose gradient
# is not ``verified`` is a number the tool cannot stand behind, so under ``untrusted: apart``
# (the default) it is left out of its group and shown apart (its own layer, rows, hatched
# wedge); ``no_gradient`` adds exactly 0 and stays in; ``untrusted: include`` mixes everything
# in, with a mark. Value weighting (θ·∂M/∂θ) scores a parameter valued exactly 0 as 0 whatever
# its gradient: zero_valued finds them, so views flag them with their raw gradient instead.
# Labels whose numbers a headline view adds up: verified, and no_gradient (exactly 0 anyway).
TRUSTED: tuple[Trust, ...] = ("verified", "no_gradient")
# A group shows the weakest label among its ranked parameters.
_WEAKEST_FIRST: tuple[Trust, ...] = ("suspect", "biased", "unverified", "verified")
_GROUPINGS: tuple[Grouping, ...] = ("param", "object", "type")
# How the part left out of a group is named where one list holds both (sunburst wedges).
APART_SUFFIX = " (untrusted)"


def is_trusted(record: ParamRecord) -> bool:
    return record.trust in TRUSTED


def untrusted_keys(buf: SensitivityBuffer, keys: Sequence[str]) -> tuple[str, ...]:
    """The keys among ``keys`` whose gradient the tool does not stand behind."""
    return tuple(k for k in keys if not is_trusted(buf.param(k)))


def weakest_trust(buf: SensitivityBuffer, keys: Sequence[str]) -> Trust:
    """The label a group of ``keys`` shows: the weakest among its parameters'."""
    labels = {buf.param(k).trust for k in keys}
    return next((label for label in _WEAKEST_FIRST if label in labels), "verified")


def ranked_groups(buf: SensitivityBuffer) -> dict[Grouping, dict[str, tuple[str, ...]]]:
    """Groups by parameter, object and type over the parameters a gradient flows to; a group
    that had parameters and lost them all to ``no_gradient`` is dropped."""
    flowing = [p.key for p in buf.params if p.trust != "no_gradient"]
    ranked: dict[Grouping, dict[str, tuple[str, ...]]] = {}
    for by in _GROUPINGS:
        every = groups(buf, None, by)
        if len(flowing) == len(buf.params):  # nothing lost: the groups are every group
            ranked[by] = every
            continue
        kept = groups(buf, flowing, by)
        ranked[by] = {name: keys for name, keys in kept.items() if keys or not every[name]}
    return ranked


@dataclass(frozen=True)
class SplitGroups:
    """Groups (objects or types) split by trust: what a headline view adds up, and the rest."""

    kept: dict[str, tuple[str, ...]]  # name -> keys a headline score adds up
    left_out: dict[str, tuple[str, ...]]  # name -> untrusted keys, shown apart (never empty)


def split_groups(
    buf: SensitivityBuffer, grouped: Mapping[str, Sequence[str]], mode: Untrusted
) -> SplitGroups:
    """``grouped`` split by trust under ``mode``: under ``apart`` a group left with no trusted
    key is dropped from ``kept``, while one that never had a key keeps its empty row."""
    if mode == "include":
        return SplitGroups({name: tuple(keys) for name, keys in grouped.items()}, {})
    kept: dict[str, tuple[str, ...]] = {}
    left_out: dict[str, tuple[str, ...]] = {}
    for name, keys in grouped.items():
        apart = untrusted_keys(buf, keys)
        trusted = tuple(k for k in keys if k not in apart)
        if trusted or not keys:
            kept[name] = trusted
        if apart:
            left_out[name] = apart
    return SplitGroups(kept, left_out)


def apart_name(name: str, taken: Mapping[str, object]) -> str:
    """``name`` + APART_SUFFIX, made unique against ``taken`` (an object may be named so)."""
    candidate = name + APART_SUFFIX
    while candidate in taken:
        candidate += "'"
    return candidate


@dataclass(frozen=True)
class ZeroValued:
    """A parameter that value weighting hides: θ is exactly 0 where ∂M/∂θ is not."""

    key: str
    owners: tuple[str, ...]
    hidden: int  # components with θ = 0 and ∂M/∂θ ≠ 0
    size: int  # components in all
    raw_signed: float  # Σ ∂M/∂θ over the parameter: the response per unit of θ


def zero_valued(
    buf: SensitivityBuffer, objective: str, keys: Sequence[str] | None = None
) -> dict[str, ZeroValued]:
    """The parameters among ``keys`` (default all) whose value-weighted score hides a gradient."""
    found = {}
    sums = buf.sums
    for key in buf.keys if keys is None else keys:
        record = buf.param(key)
        if sums is not None:  # stored by the writer (buffer/npz.py): no texel is read
            hidden, raw = sums.hidden(objective, key)
        else:
            hidden, raw = hidden_by_zero(buf.value(key), buf.grad(objective, key))
        if hidden:
            found[key] = ZeroValued(key, record.owners, hidden, math.prod(record.shape), raw)
    return found


# Standard errors (from a buffer's batch statistics). Every group a view ranks (a key, an object,
# a type, a sunburst wedge) gets, for each batch, the value its signed sum and its score would
# have had from that batch alone: the signed sum exactly (sums add up), the ℓ2 and rms scores to
# first order (the projection on the mean, see :mod:`sensaov_cli.buffer.statistics`). Their
# spp-weighted spread gives the standard errors; a bootstrap over the batches gives how often the
# top of a ranking keeps its order. Buffers without statistics (one batch) give None everywhere:
# no error is claimed that was not measured.
STABILITY_TOP = 3  # the ranking's top this many rows must keep their order
RESAMPLES = 1000  # bootstrap resamples of the batches (seeded: the figure is reproducible)


@dataclass(frozen=True)
class GroupError:
    score_se: float
    signed_se: float
    dof: int  # degrees of freedom of the error: batches − 1
    factor: float  # standard errors in the two-sided 95 % interval: Student's t at ``dof``
    noisy: str | None = None  # why the batch estimates look heavy-tailed; None: they do not

    def resolves(self, signed: float) -> bool:
        """Whether the sign of ``signed`` is resolved: |Σc| > factor · SE (0 lies outside the
        95 % interval, t with ``dof`` degrees of freedom) and the error itself can be trusted
        (no heavy tail: then the spread understates the error, docs/rankings.md)."""
        return self.noisy is None and abs(signed) > self.factor * self.signed_se


@dataclass(frozen=True)
class Resolution:
    """The rule a ranking's ``resolved`` column applies, recorded beside it."""

    level: float  # two-sided coverage of the interval
    batches: int
    dof: int  # batches - 1
    factor: float  # the t quantile: |Σc| > factor · SE (and no heavy tail) is resolved


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
        batches = len(self.spp)
        self.resolution = Resolution(
            SIGNIFICANCE_LEVEL, batches, batches - 1, interval_factor(batches)
        )

    @classmethod
    def of(
        cls, buf: SensitivityBuffer, objective: str, method: Aggregate, weight: Weight
    ) -> Uncertainty | None:
        return None if buf.statistics is None else cls(buf, objective, method, weight)

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
        scores = projection / l2 if l2 > 0 else np.zeros(len(self.spp))
        return (scores if self.method == "l2" else scores / math.sqrt(count)), signed

    def error(self, keys: Sequence[str], score: float) -> GroupError:
        scores, signed = self.batch_values(keys, score)
        return GroupError(
            float(pooled_stderr(scores, self.spp)),
            float(pooled_stderr(signed, self.spp)),
            self.resolution.dof,
            self.resolution.factor,
            heavy_tail(signed.tolist()),
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
        batches = len(self.spp)
        picks = rng.integers(0, batches, size=(RESAMPLES, batches))
        weights = np.asarray(self.spp, dtype=np.float64)[picks]  # (R, k)
        means = np.einsum("rk,grk->rg", weights, table[:, picks]) / weights.sum(axis=1)[:, None]
        order = np.argsort(-np.abs(means), axis=1, kind="stable")[:, :top]
        held = (order == np.arange(top)).all(axis=1)
        return float(held.mean()), top


def objective_se(buf: SensitivityBuffer, objective: str) -> float | None:
    """The standard error of the objective value M from its batches; None with one batch."""
    if buf.statistics is None:
        return None
    values = np.asarray(buf.statistics.objective_values[objective], np.float64)
    return float(pooled_stderr(values, buf.statistics.spp))


@dataclass(frozen=True)
class RankRow:
    """One row of a ranking; ``value`` only for key rows, ``not_seen_by`` only with cameras."""

    rank: int
    name: str
    score: float  # the aggregate (l2, rms or sum) of the row's contributions c
    signed: float  # Σc: > 0 when scaling the row's parameters up raises M
    share: float  # Σc² of the row over Σc² of every ranked parameter
    sign: str  # "+", "-" or "0", the sign of ``signed``
    value: float | None  # mean of the parameter's value array at the primal
    trust: Trust  # the parameter's label, or the weakest of the group's parameters
    not_seen_by: tuple[str, ...] | None  # cameras that see none of its objects
    score_se: float | None = None  # standard errors, when the buffer has batch statistics
    signed_se: float | None = None
    dof: int | None = None  # degrees of freedom of the errors (batches − 1, or seeds − 1)
    resolved: bool | None = None  # |signed| > t · signed_se and no heavy tail; None: no error
    noisy: str | None = None  # why its batch estimates look heavy-tailed (never resolved then)
    other_score: float | None = None  # the score by the other aggregate (OTHER_SCORE)
    other_rank: int | None = None  # the row's rank by the other score among the same rows
    part: str = "all"  # "trusted" / "untrusted" (left out) under untrusted: apart
    zero_value: bool = False  # θ is 0 where ∂M/∂θ is not (a group: in one of its keys)
    raw_signed: float | None = None  # Σ ∂M/∂θ, for a zero-valued key under weight "value"
    # what produced the gradients: a key's estimator, a group's distinct ones joined by "+"
    estimator: str = "reverse"

    @property
    def orders_disagree(self) -> bool:
        """Whether its rank by the other score differs markedly from its rank here."""
        return self.other_rank is not None and orders_disagree(self.rank, self.other_rank)

    @property
    def unresolved(self) -> bool:
        """Drawn neutral, marked ``?``, ranked after the resolved rows: measured and either
        within its interval or heavy-tailed."""
        return self.resolved is False


@dataclass(frozen=True)
class Ranking:
    """One objective's ranking at one cut: the top rows, how many were ranked, the zeros."""

    objective: str
    objective_value: float
    by: Cut
    rows: tuple[RankRow, ...]
    ranked: int  # rows before the --top cut
    total_signed: float  # Σc over every ranked parameter
    no_gradient: tuple[ParamRecord, ...]  # listed apart, never ranked
    stability: float | None = None  # how often the top ``stability_top`` rows keep their order
    stability_top: int | None = None
    left_out: tuple[RankRow, ...] = ()  # untrusted parts of objects or types, ranked apart
    untrusted: Untrusted = "include"  # how untrusted parameters were treated
    resolution: Resolution | None = None  # the rule behind ``resolved``; None: 1 batch
    zero_valued: tuple[ZeroValued, ...] = ()  # every key value weighting hides
    objective_se: float | None = None  # standard error of M; None: one batch
    method: Aggregate = DEFAULT_AGGREGATE  # the score rows are ranked by


def rankings(
    buf: SensitivityBuffer,
    *,
    by: Cut,
    objectives: Sequence[str] | None = None,
    top: int | None = None,
    method: Aggregate = DEFAULT_AGGREGATE,
    weight: Weight = "value",
    visible: Mapping[str, frozenset[str]] | None = None,
    untrusted: Untrusted = "apart",
) -> tuple[Ranking, ...]:
    """The ranking of every objective (or of ``objectives``) at the cut ``by``.

    ``visible`` maps a camera to the objects it sees; each row then lists the cameras that see
    none of its objects (a key: of its owners; a key with no owner is seen by no camera).
    """
    check_cut(by, cameras=visible is not None)
    names = [o.name for o in buf.objectives] if objectives is None else list(objectives)
    grouped = ranked_groups(buf)
    cut = _Cut(by, method, weight, visible, "include" if by == "key" else untrusted)
    return tuple(
        _ranking(buf, name, grouped[GROUPING_OF[by]], grouped["param"], cut, top) for name in names
    )


@dataclass(frozen=True)
class _Cut:
    """How one ranking is read: the cut, the score, cameras and the untrusted mode."""

    by: Cut
    method: Aggregate
    weight: Weight
    visible: Mapping[str, frozenset[str]] | None
    untrusted: Untrusted


def check_cut(by: Cut, *, cameras: bool) -> None:
    """Refuse cameras with types: a type has no place in a frame."""
    if cameras and by == "type":
        raise QueryError("camera labels (--exr) need --by key or --by object: a type has no place")


def _ranking(
    buf: SensitivityBuffer,
    objective: str,
    grouped: Mapping[str, Sequence[str]],
    flowing: Mapping[str, Sequence[str]],
    cut: _Cut,
    top: int | None,
) -> Ranking:
    stats = key_stats(buf, objective, flowing, weight=cut.weight)
    split = split_groups(buf, grouped, cut.untrusted)
    hidden = zero_valued(buf, objective, list(flowing)) if cut.weight == "value" else {}
    noise = Uncertainty.of(buf, objective, cut.method, cut.weight)
    table = _Table(buf, objective, cut, stats, share_total(stats, cut.method), hidden, noise)
    ordered = rank(scores(stats, split.kept, cut.method))
    stable = None if noise is None else noise.stability(ordered, split.kept)
    return Ranking(
        objective=objective,
        objective_value=buf.objective(objective).value,
        by=cut.by,
        rows=table.rows(split.kept, "all" if cut.untrusted == "include" else "trusted", top),
        ranked=len(split.kept),
        total_signed=math.fsum(s.total for s in stats.values()),
        no_gradient=tuple(p for p in buf.params if p.trust == "no_gradient"),
        stability=None if stable is None else stable[0],
        stability_top=None if stable is None else stable[1],
        left_out=table.rows(split.left_out, "untrusted", None),
        untrusted=cut.untrusted,
        resolution=None if noise is None else noise.resolution,
        zero_valued=tuple(hidden.values()),
        objective_se=objective_se(buf, objective),
        method=cut.method,
    )


def share_total(stats: Mapping[str, KeyStats], method: Aggregate) -> float:
    """What a row's share is of, over every ranked parameter: Σ|Σc| under the sum score (a
    row's share is its |signed| of that, so shares follow the order the score gives, and the
    keys' shares sum to 1), else Σc² (which adds up over disjoint groups)."""
    if method == "sum":
        return math.fsum(abs(s.total) for s in stats.values())
    return math.fsum(s.sum_sq for s in stats.values())


@dataclass(frozen=True)
class _Table:
    """What every row of one objective's ranking is read from."""

    buf: SensitivityBuffer
    objective: str
    cut: _Cut
    stats: Mapping[str, KeyStats]
    share_total: float  # what shares are of (share_total)
    hidden: Mapping[str, ZeroValued]
    noise: Uncertainty | None

    def rows(
        self, groups: Mapping[str, Sequence[str]], part: str, limit: int | None
    ) -> tuple[RankRow, ...]:
        """Every row by |score|, the unresolved after the resolved (each by |score|), then cut:
        a sign the batches cannot resolve never heads a ranking."""
        other = OTHER_SCORE[self.cut.method]
        other_scores = scores(self.stats, groups, other)
        other_rank = {name: i for i, (name, _) in enumerate(rank(other_scores), 1)}
        made = [
            self.row(name, s, groups[name], part)
            for name, s in rank(scores(self.stats, groups, self.cut.method))
        ]
        ordered = [r for r in made if not r.unresolved] + [r for r in made if r.unresolved]
        return tuple(
            replace(r, rank=i, other_score=other_scores[r.name], other_rank=other_rank[r.name])
            for i, r in enumerate(ordered[:limit], 1)
        )

    def row(self, name: str, score: float, keys: Sequence[str], part: str) -> RankRow:
        buf, cut = self.buf, self.cut
        group = [self.stats[k] for k in keys]
        signed = math.fsum(s.total for s in group)
        part_of = abs(signed) if cut.method == "sum" else math.fsum(s.sum_sq for s in group)
        share = part_of / self.share_total if self.share_total else 0.0
        objects = buf.param(name).owners if cut.by == "key" else (name,)
        zero = [self.hidden[k] for k in keys if k in self.hidden]
        row = RankRow(
            rank=0,  # set once the rows are ordered
            name=name,
            score=score,
            signed=signed,
            share=share,
            sign="+" if signed > 0 else "-" if signed < 0 else "0",
            value=_mean_value(buf, name) if cut.by == "key" else None,
            trust=weakest_trust(buf, keys),
            not_seen_by=None if cut.visible is None else cameras_not_seeing(objects, cut.visible),
            part=part,
            zero_value=bool(zero),
            raw_signed=zero[0].raw_signed if cut.by == "key" and zero else None,
            estimator=estimators(buf, keys),
        )
        if self.noise is not None:
            error = self.noise.error(keys, score)
            return replace(row, score_se=error.score_se, signed_se=error.signed_se, dof=error.dof,
                           resolved=error.resolves(signed), noisy=error.noisy)  # fmt: skip
        if cut.by == "key":  # without batches, a repaired parameter has its own seeds' error
            return self.with_repair_error(row)
        return row

    def with_repair_error(self, row: RankRow) -> RankRow:
        objective, weight = self.objective, self.cut.weight
        repaired = repair_error(self.buf, objective, row.name, row.signed, weight)
        if repaired is None:
            return row
        repair, theta = self.buf.repairs[row.name], _theta(self.buf, row.name, weight)
        score_se = {
            "sum": repaired.signed_se,
            "l2": repair.norm_error(objective, theta),
            "rms": repair.norm_error(objective, theta) / math.sqrt(max(theta.size, 1)),
        }[self.cut.method]
        return replace(row, score_se=score_se, signed_se=repaired.signed_se, dof=repaired.dof,
                       resolved=repaired.resolved, noisy=repaired.noisy)  # fmt: skip


@dataclass(frozen=True)
class RepairError:
    """A repaired parameter's own standard error of its signed sum, over its seeds."""

    signed_se: float
    resolved: bool  # the sign of its signed sum is beyond Student's t of that error, not noisy
    seeds: int
    dof: int  # seeds − 1
    noisy: str | None = None  # why its seeds' estimates look heavy-tailed


def repair_error(
    buf: SensitivityBuffer, objective: str, key: str, signed: float, weight: Weight
) -> RepairError | None:
    """A repaired parameter's error (buffer/model.py); None for any other parameter."""
    repair = buf.repairs.get(key)
    if repair is None or not repair.has_error:
        return None
    theta = _theta(buf, key, weight)
    error = repair.signed_error(objective, theta)
    seeds = len(repair.seeds)
    sums = np.asarray(repair.estimates[objective]) @ theta.astype(np.float64).ravel()
    noisy = heavy_tail(sums.tolist())
    resolved = noisy is None and repair.significant(signed, error)
    return RepairError(error, resolved, seeds, seeds - 1, noisy)


def _theta(buf: SensitivityBuffer, key: str, weight: Weight) -> np.ndarray:
    """What a parameter's gradient is weighted by: its value, or ones."""
    return buf.value(key) if weight == "value" else np.ones(buf.param(key).shape)


def estimators(buf: SensitivityBuffer, keys: Sequence[str]) -> str:
    """The distinct estimators of ``keys``' gradients, in vocabulary order, joined by "+"."""
    found = {buf.param(k).estimator for k in keys}
    return "+".join(e for e in ESTIMATORS if e in found) or "-"


def _mean_value(buf: SensitivityBuffer, key: str) -> float | None:
    """One number for a value array (a colour, a texture): its mean; None when it is empty."""
    if buf.sums is not None:  # stored by the writer: a texture's texels are not read
        return buf.sums.mean(key, math.prod(buf.param(key).shape))
    return mean_value(buf.value(key))


def cameras_not_seeing(
    objects: Sequence[str], visible: Mapping[str, frozenset[str]]
) -> tuple[str, ...]:
    """The cameras (in the given order) that see none of ``objects``."""
    return tuple(camera for camera, seen in visible.items() if seen.isdisjoint(objects))


@dataclass(frozen=True)
class RankedParameter:
    """One of an objective's top parameters in the summary: its ranking row (score, errors,
    resolution, its rank by the other score) and its record."""

    record: ParamRecord
    row: RankRow
    repaired: RepairError | None  # a repaired parameter's own error; None for the others
    raw_signed: float | None  # Σ ∂M/∂θ where θ is 0 and ∂M/∂θ is not (weight "value")

    @property
    def score(self) -> float:
        return self.row.score

    @property
    def signed(self) -> float:
        return self.row.signed

    @property
    def zero_value(self) -> bool:
        return self.raw_signed is not None


@dataclass(frozen=True)
class RankedGroup:
    """An object or a type in the summary: its ranking row (score, signed sum, errors,
    resolution, its rank by the other score: a texture's ℓ2 is about 1/sqrt(texels) of its sum,
    so the two orders can differ)."""

    row: RankRow

    @property
    def name(self) -> str:
        return self.row.name

    @property
    def score(self) -> float:
        return self.row.score

    @property
    def signed(self) -> float:
        return self.row.signed

    @property
    def trust(self) -> Trust:
        return self.row.trust

    @property
    def zero_value(self) -> bool:
        return self.row.zero_value


@dataclass(frozen=True)
class LeftOut:
    """The untrusted part of an object or a type: its score, and each key with its label."""

    name: str
    score: float
    signed: float
    trust: Trust
    keys: tuple[tuple[str, Trust], ...]
    signed_se: float | None = None  # as a ranking row's; None: one batch
    dof: int | None = None
    resolved: bool | None = None
    noisy: str | None = None


@dataclass(frozen=True)
class ObjectiveSummary:
    """One objective's block of the summary."""

    objective: ObjectiveRecord
    untrusted: Untrusted
    ranked_objects: int  # objects scored, before the top cut
    parameters: tuple[RankedParameter, ...]
    objects: tuple[RankedGroup, ...]
    types: tuple[RankedGroup, ...]
    left_out_objects: tuple[LeftOut, ...]
    left_out_types: tuple[LeftOut, ...]
    zero_valued: tuple[ZeroValued, ...]
    no_gradient: tuple[ParamRecord, ...]  # listed apart, never ranked
    objective_se: float | None = None  # standard error of M; None: one batch
    resolution: Resolution | None = None  # the rule behind ``resolved``; None: one batch


@dataclass(frozen=True, eq=False)
class Summary:
    """The ranked summary of a buffer: how it was scored, and one block per objective."""

    buffer: SensitivityBuffer  # its counts and provenance head the summary
    method: Aggregate
    weight: Weight
    ranked_parameters: int  # parameters a gradient flows to
    ranked_objects: int
    objectives: tuple[ObjectiveSummary, ...]


def ranked_summary(
    buf: SensitivityBuffer,
    *,
    top: int = 8,
    method: Aggregate = DEFAULT_AGGREGATE,
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
) -> Summary:
    """Per objective: M, the top parameters and objects, and every type's score."""
    ranked = ranked_groups(buf)
    return Summary(
        buf,
        method,
        weight,
        len(ranked["param"]),
        len(ranked["object"]),
        tuple(
            _objective_summary(buf, o, ranked, top, method, weight, untrusted)
            for o in buf.objectives
        ),
    )


def _objective_summary(
    buf: SensitivityBuffer,
    objective: ObjectiveRecord,
    ranked: Mapping[Grouping, Mapping[str, Sequence[str]]],
    top: int,
    method: Aggregate,
    weight: Weight,
    untrusted: Untrusted,
) -> ObjectiveSummary:
    name = objective.name
    stats = key_stats(buf, name, ranked["param"], weight=weight)  # one pass, 3 groupings
    hidden = zero_valued(buf, name, list(ranked["param"])) if weight == "value" else {}
    objects = split_groups(buf, ranked["object"], untrusted)
    types = split_groups(buf, ranked["type"], untrusted)
    noise = Uncertainty.of(buf, name, method, weight)
    total = share_total(stats, method)

    def table(by: Cut) -> _Table:
        mode: Untrusted = "include" if by == "key" else untrusted
        return _Table(buf, name, _Cut(by, method, weight, None, mode), stats, total, hidden,
                      noise)  # fmt: skip

    part = "all" if untrusted == "include" else "trusted"

    def left_out(grouped: Mapping[str, Sequence[str]], by: Cut) -> tuple[LeftOut, ...]:
        """The untrusted part of each group, resolved and largest first, with each key and its
        label and the group's error."""
        return tuple(
            LeftOut(r.name, r.score, r.signed, r.trust,
                    tuple((k, buf.param(k).trust) for k in grouped[r.name]),
                    r.signed_se, r.dof, r.resolved, r.noisy)
            for r in table(by).rows(grouped, "untrusted", None)
        )  # fmt: skip

    parameters = tuple(
        RankedParameter(
            buf.param(row.name),
            row,
            repair_error(buf, name, row.name, row.signed, weight),
            hidden[row.name].raw_signed if row.name in hidden else None,
        )
        for row in table("key").rows(ranked["param"], "all", top)
    )
    return ObjectiveSummary(
        objective,
        untrusted,
        len(objects.kept),
        parameters,
        tuple(RankedGroup(row) for row in table("object").rows(objects.kept, part, top)),
        tuple(RankedGroup(row) for row in table("type").rows(types.kept, part, None)),
        left_out(objects.left_out, "object"),
        left_out(types.left_out, "type"),
        tuple(hidden.values()),
        tuple(p for p in buf.params if p.trust == "no_gradient"),
        objective_se(buf, name),
        None if noise is None else noise.resolution,
    )


# The sunburst's geometry (paper Fig. 1): rings from the objective out to the parameters. Ring 0
# is the objective, a full disc. With the order ``object,type`` ring 1 holds the objects, ring 2
# each object's parameter types and ring 3 the parameters (keys); ``type,object`` swaps rings 1
# and 2. Siblings split their parent's angle in proportion to their scores' magnitudes (with l2
# or rms a parent's score is not the sum of its children's: "proportional" holds among
# siblings, which is what a reader compares). Angles are fractions of a turn, clockwise from
# the top; :mod:`sensaov_cli.outputs.sunburst_drawing` draws them. A ring-1 group holds the
# trusted parameters only; the rest of it gets a hatched sibling ``"<name> (untrusted)"``. As
# in the rankings, only parameters a gradient flows to are drawn, a shared parameter sits under
# each owner, one no object owns under SCENE_WIDE, and a group that scores exactly 0 gets no
# wedge.
# The object ring's wedge for parameters no object owns (a sensor's, an integrator's): the
# paper's "global exposure that never appears in the frame" must not vanish from the rings.
SCENE_WIDE = "(scene-wide)"

Level = Callable[[SensitivityBuffer, Sequence[str]], dict[str, tuple[str, ...]]]


@dataclass(frozen=True)
class Wedge:
    """One wedge: its ring, its path from ring 1, and its span in fractions of a turn."""

    ring: int  # 0 the objective, 1 the innermost group ring, 3 the parameters
    path: tuple[str, ...]  # names from ring 1 to this wedge; () for the objective
    start: float  # fraction of a turn, clockwise from the top
    stop: float
    score: float  # the aggregate of the wedge's keys
    signed: float  # Σc of its keys: its sign colours the wedge
    trust: Trust  # the weakest label among its keys
    resolved: bool | None = None  # sign beyond t standard errors, no heavy tail; None: 1 batch
    noisy: str | None = None  # why its batch estimates look heavy-tailed

    @property
    def unresolved(self) -> bool:
        """Drawn neutral: its sign is measured and not resolved (or heavy-tailed)."""
        return self.resolved is False

    @property
    def label(self) -> str:
        return self.path[-1] if self.path else ""

    @property
    def span(self) -> float:
        return self.stop - self.start


@dataclass(frozen=True)
class Panel:
    """One objective's sunburst: its name, M and wedges, and the keys it leaves out."""

    objective: str
    value: float
    wedges: tuple[Wedge, ...]
    no_gradient: tuple[str, ...]  # no gradient flows: listed under the disc, never drawn
    zero_valued: tuple[ZeroValued, ...] = ()  # θ = 0: no wedge, listed under the disc


def panels(
    buf: SensitivityBuffer,
    objectives: Sequence[str] | None = None,
    *,
    order: Order = "object,type",
    method: Aggregate = DEFAULT_AGGREGATE,
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
) -> tuple[Panel, ...]:
    """One panel per objective (all of the buffer's when ``objectives`` is None)."""
    names = [o.name for o in buf.objectives] if objectives is None else list(objectives)
    zero = tuple(p.key for p in buf.params if p.trust == "no_gradient")
    return tuple(
        Panel(
            name,
            buf.objective(name).value,
            sunburst_wedges(
                buf, name, order=order, method=method, weight=weight, untrusted=untrusted
            ),
            zero,
            tuple(zero_valued(buf, name).values()) if weight == "value" else (),
        )
        for name in names
    )


def _level(names: Callable[[ParamRecord], tuple[str, ...]]) -> Level:
    """Keys grouped by ``names`` of their records, groups in order of first appearance."""

    def group(buf: SensitivityBuffer, keys: Sequence[str]) -> dict[str, tuple[str, ...]]:
        found = dict.fromkeys(n for k in keys for n in names(buf.param(k)))
        return {n: tuple(k for k in keys if n in names(buf.param(k))) for n in found}

    return group


_LEVELS: dict[str, Level] = {
    "object": _level(lambda p: p.owners or (SCENE_WIDE,)),
    "type": _level(lambda p: (p.type,)),
    "key": _level(lambda p: (p.key,)),
}


def _apart(level: Level, mode: Untrusted) -> Level:
    """``level`` whose groups keep their trusted keys, the rest a sibling ``(untrusted)``."""

    def split(buf: SensitivityBuffer, keys: Sequence[str]) -> dict[str, tuple[str, ...]]:
        grouped = split_groups(buf, level(buf, keys), mode)
        result = dict(grouped.kept)
        for name, left_out in grouped.left_out.items():
            result[apart_name(name, result)] = left_out
        return result

    return split


def sunburst_wedges(
    buf: SensitivityBuffer,
    objective: str,
    *,
    order: Order = "object,type",
    method: Aggregate = DEFAULT_AGGREGATE,
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
) -> tuple[Wedge, ...]:
    """Every wedge of ``objective``'s sunburst, ring by ring, largest first within a parent."""
    keys = tuple(ranked_groups(buf)["param"])
    rings = _Rings(buf, key_stats(buf, objective, keys, weight=weight), method,
                   Uncertainty.of(buf, objective, method, weight))  # fmt: skip
    first, second = order.split(",")
    levels = [_apart(_LEVELS[first], untrusted), _LEVELS[second], _LEVELS["key"]]
    centre = rings.wedge(keys, 0, (), 0.0, 1.0)
    wedges = [centre]
    _children(rings, centre, keys, levels, wedges)
    return tuple(wedges)


@dataclass(frozen=True)
class _Rings:
    """What every wedge of one sunburst is scored with."""

    buf: SensitivityBuffer
    stats: Mapping[str, KeyStats]
    method: Aggregate
    noise: Uncertainty | None  # None: no statistics, no resolution

    def wedge(
        self, keys: Sequence[str], ring: int, path: tuple[str, ...], start: float, stop: float
    ) -> Wedge:
        group = [self.stats[k] for k in keys]
        score, signed = combine(group, self.method), math.fsum(s.total for s in group)
        error = None if self.noise is None else self.noise.error(keys, score)
        return Wedge(ring=ring, path=path, start=start, stop=stop, score=score, signed=signed,
                     trust=weakest_trust(self.buf, keys),
                     resolved=None if error is None else error.resolves(signed),
                     noisy=None if error is None else error.noisy)  # fmt: skip


def _children(
    rings: _Rings, parent: Wedge, keys: Sequence[str], levels: Sequence[Level], out: list[Wedge]
) -> None:
    """Split ``parent``'s span among its groups at the next level, then recurse."""
    if not levels:
        return
    grouped = levels[0](rings.buf, keys)
    magnitudes = {
        name: abs(combine((rings.stats[k] for k in members), rings.method))
        for name, members in grouped.items()
    }
    total = math.fsum(magnitudes.values())
    start = parent.start
    for name, magnitude in rank(magnitudes):
        if magnitude == 0.0:
            continue
        stop = start + parent.span * magnitude / total
        wedge = rings.wedge(grouped[name], parent.ring + 1, (*parent.path, name), start, stop)
        out.append(wedge)
        _children(rings, wedge, grouped[name], levels[1:], out)
        start = stop
