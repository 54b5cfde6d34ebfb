"""Rankings of the hierarchy (numpy only): ``rank``'s summary, and one cut (``rank --by``).

The summary gives per objective the top parameters and objects and every type's score; a
ranking at one cut (key, object or type) gives one table per objective (columns:
docs/rankings.md). Objects and types add up the trusted parameters only (:mod:`.trusted`) and
rank the untrusted rest apart; ``no_gradient`` parameters are listed apart, never scored, and a
group made only of them is not ranked; zero-valued parameters are flagged with their raw
gradient. :mod:`sensaov_cli.outputs.tables` writes text, JSON and CSV from these types.

A row's share is of Σc² over every ranked parameter, whatever ``--aggregate`` says: Σc² adds
up over disjoint groups, so the shares of keys and of types each sum to 1 (object shares may
sum past 1: a shared parameter counts for each owner).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import KeyStats, key_stats, rank, scores
from sensaov_cli.buffer.statistics import mean_value
from sensaov_cli.errors import QueryError
from sensaov_cli.views.trusted import (
    ZeroValued,
    ranked_groups,
    split_groups,
    weakest_trust,
    zero_valued,
)
from sensaov_cli.views.uncertainty import Significance, Uncertainty
from sensaov_cli.vocabulary import ESTIMATORS, Aggregate, Cut, Grouping, Trust, Untrusted, Weight

SUMMARY_FORMAT = "sensaov-summary"
SUMMARY_VERSION = 3
RANKING_FORMAT = "sensaov-ranking"
RANKING_VERSION = 3
# The grouping each cut reads: a key row is one parameter.
GROUPING_OF: dict[Cut, Grouping] = {"key": "param", "object": "object", "type": "type"}


@dataclass(frozen=True)
class RankRow:
    """One row of a ranking; ``value`` only for key rows, ``off_frame`` only with cameras."""

    rank: int
    name: str
    score: float  # the aggregate (l2, rms or sum) of the row's contributions c
    signed: float  # Σc: > 0 when scaling the row's parameters up raises M
    share: float  # Σc² of the row over Σc² of every ranked parameter
    sign: str  # "+", "-" or "0", the sign of ``signed``
    value: float | None  # mean of the parameter's value array at the primal
    trust: Trust  # the parameter's label, or the weakest of the group's parameters
    off_frame: tuple[str, ...] | None  # cameras that see none of its objects
    score_se: float | None = None  # standard errors, when the buffer has batch statistics
    signed_se: float | None = None
    significant: bool | None = None  # |signed| > t · signed_se: the sign is beyond noise
    part: str = "all"  # "trusted" / "untrusted" (left out) under untrusted: apart
    zero_value: bool = False  # θ is 0 where ∂M/∂θ is not (a group: in one of its keys)
    raw_signed: float | None = None  # Σ ∂M/∂θ, for a zero-valued key under weight "value"
    # what produced the gradients: a key's estimator, a group's distinct ones joined by "+"
    estimator: str = "reverse"


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
    batches: int | None = None  # batches behind the standard errors (None: no statistics)
    stability: float | None = None  # how often the top ``stability_top`` rows keep their order
    stability_top: int | None = None
    left_out: tuple[RankRow, ...] = ()  # untrusted parts of objects or types, ranked apart
    untrusted: Untrusted = "include"  # how untrusted parameters were treated
    significance: Significance | None = None  # the rule behind ``significant``
    zero_valued: tuple[ZeroValued, ...] = ()  # every key value weighting hides


def rankings(
    buf: SensitivityBuffer,
    *,
    by: Cut,
    objectives: Sequence[str] | None = None,
    top: int | None = None,
    method: Aggregate = "l2",
    weight: Weight = "value",
    visible: Mapping[str, frozenset[str]] | None = None,
    untrusted: Untrusted = "apart",
) -> tuple[Ranking, ...]:
    """The ranking of every objective (or of ``objectives``) at the cut ``by``.

    ``visible`` maps a camera to the objects it sees; each row then lists the cameras that see
    none of its objects (a key: of its owners; a key with no owner is off-frame everywhere).
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
        raise QueryError("off-frame labels need --by key or --by object: a type has no place")


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
    total_sq = math.fsum(s.sum_sq for s in stats.values())
    table = _Table(buf, objective, cut, stats, total_sq, hidden, noise)
    stable = None if noise is None else noise.stability(rank(scores(stats, split.kept)), split.kept)
    return Ranking(
        objective=objective,
        objective_value=buf.objective(objective).value,
        by=cut.by,
        rows=table.rows(split.kept, "all" if cut.untrusted == "include" else "trusted", top),
        ranked=len(split.kept),
        total_signed=math.fsum(s.total for s in stats.values()),
        no_gradient=tuple(p for p in buf.params if p.trust == "no_gradient"),
        batches=None if noise is None else noise.batches,
        stability=None if stable is None else stable[0],
        stability_top=None if stable is None else stable[1],
        left_out=table.rows(split.left_out, "untrusted", None),
        untrusted=cut.untrusted,
        significance=None if noise is None else noise.significance,
        zero_valued=tuple(hidden.values()),
    )


@dataclass(frozen=True)
class _Table:
    """What every row of one objective's ranking is read from."""

    buf: SensitivityBuffer
    objective: str
    cut: _Cut
    stats: Mapping[str, KeyStats]
    total_sq: float  # Σc² over every ranked parameter: what shares are of
    hidden: Mapping[str, ZeroValued]
    noise: Uncertainty | None

    def rows(
        self, groups: Mapping[str, Sequence[str]], part: str, limit: int | None
    ) -> tuple[RankRow, ...]:
        ordered = rank(scores(self.stats, groups, self.cut.method))[:limit]
        return tuple(
            self.row(i, name, s, groups[name], part) for i, (name, s) in enumerate(ordered, 1)
        )

    def row(self, index: int, name: str, score: float, keys: Sequence[str], part: str) -> RankRow:
        buf, cut = self.buf, self.cut
        group = [self.stats[k] for k in keys]
        signed = math.fsum(s.total for s in group)
        share = math.fsum(s.sum_sq for s in group) / self.total_sq if self.total_sq else 0.0
        objects = buf.param(name).owners if cut.by == "key" else (name,)
        zero = [self.hidden[k] for k in keys if k in self.hidden]
        row = RankRow(
            rank=index,
            name=name,
            score=score,
            signed=signed,
            share=share,
            sign="+" if signed > 0 else "-" if signed < 0 else "0",
            value=_mean_value(buf, name) if cut.by == "key" else None,
            trust=weakest_trust(buf, keys),
            off_frame=None if cut.visible is None else off_frame(objects, cut.visible),
            part=part,
            zero_value=bool(zero),
            raw_signed=zero[0].raw_signed if cut.by == "key" and zero else None,
            estimator=estimators(buf, keys),
        )
        if self.noise is not None:
            error = self.noise.error(keys, score)
            significant = error.significant(signed)
            return replace(
                row, score_se=error.score_se, signed_se=error.signed_se, significant=significant
            )
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
        return replace(
            row, score_se=score_se, signed_se=repaired.signed_se, significant=repaired.significant
        )


@dataclass(frozen=True)
class RepairError:
    """A repaired parameter's own standard error of its signed sum, over its seeds."""

    signed_se: float
    significant: bool  # the sign of its signed sum is beyond Student's t of that error
    seeds: int


def repair_error(
    buf: SensitivityBuffer, objective: str, key: str, signed: float, weight: Weight
) -> RepairError | None:
    """A repaired parameter's error (buffer/model.py); None for any other parameter."""
    repair = buf.repairs.get(key)
    if repair is None or not repair.has_error:
        return None
    error = repair.signed_error(objective, _theta(buf, key, weight))
    return RepairError(error, repair.significant(signed, error), len(repair.seeds))


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


def off_frame(objects: Sequence[str], visible: Mapping[str, frozenset[str]]) -> tuple[str, ...]:
    """The cameras (in the given order) that see none of ``objects``."""
    return tuple(camera for camera, seen in visible.items() if seen.isdisjoint(objects))


@dataclass(frozen=True)
class RankedParameter:
    """One of an objective's top parameters in the summary."""

    record: ParamRecord
    score: float
    signed: float  # Σc
    repaired: RepairError | None  # a repaired parameter's own error; None for the others
    raw_signed: float | None  # Σ ∂M/∂θ where θ is 0 and ∂M/∂θ is not (weight "value")

    @property
    def zero_value(self) -> bool:
        return self.raw_signed is not None


@dataclass(frozen=True)
class RankedGroup:
    """An object or a type in the summary, with its signed sum and that sum's own rank."""

    name: str
    score: float
    signed: float
    signed_rank: int  # a texture's l2 is about 1/sqrt(texels) of its sum: the two can differ
    trust: Trust
    zero_value: bool  # one of its parameters is valued exactly 0


@dataclass(frozen=True)
class LeftOut:
    """The untrusted part of an object or a type: its score, and each key with its label."""

    name: str
    score: float
    signed: float
    trust: Trust
    keys: tuple[tuple[str, Trust], ...]


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
    method: Aggregate = "l2",
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
    stats = key_stats(buf, objective.name, ranked["param"], weight=weight)  # one pass, 3 groupings
    hidden = zero_valued(buf, objective.name, list(ranked["param"])) if weight == "value" else {}
    objects = split_groups(buf, ranked["object"], untrusted)
    types = split_groups(buf, ranked["type"], untrusted)

    def scored(grouped: Mapping[str, Sequence[str]], top: int | None) -> tuple[RankedGroup, ...]:
        sums = scores(stats, grouped, "sum")
        sum_rank = {name: i for i, (name, _) in enumerate(rank(sums), 1)}
        return tuple(
            RankedGroup(name, score, sums[name], sum_rank[name], weakest_trust(buf, grouped[name]),
                        any(k in hidden for k in grouped[name]))
            for name, score in rank(scores(stats, grouped, method), top)
        )  # fmt: skip

    def left_out(grouped: Mapping[str, Sequence[str]]) -> tuple[LeftOut, ...]:
        """The untrusted part of each group, largest first, with each key and its label."""
        sums = scores(stats, grouped, "sum")
        return tuple(
            LeftOut(name, score, sums[name], weakest_trust(buf, grouped[name]),
                    tuple((k, buf.param(k).trust) for k in grouped[name]))
            for name, score in rank(scores(stats, grouped, method))
        )  # fmt: skip

    parameters = tuple(
        RankedParameter(
            buf.param(key),
            score,
            stats[key].total,
            repair_error(buf, objective.name, key, stats[key].total, weight),
            hidden[key].raw_signed if key in hidden else None,
        )
        for key, score in rank(scores(stats, ranked["param"], method), top)
    )
    return ObjectiveSummary(
        objective,
        untrusted,
        len(objects.kept),
        parameters,
        scored(objects.kept, top),
        scored(types.kept, None),
        left_out(objects.left_out),
        left_out(types.left_out),
        tuple(hidden.values()),
        tuple(p for p in buf.params if p.trust == "no_gradient"),
    )
