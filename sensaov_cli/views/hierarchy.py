"""Rankings at one cut of the hierarchy (``sensaov rank --by``): key, object or type; numpy only.

One table per objective whose every row carries what a reader needs to judge it: the score
(the chosen aggregate), the signed sum Σc beside it, its sign, the row's share of the total
response, the parameter's value (key rows), the trust label and, when cameras are given, the
cameras that do not see it (off-frame). The columns are documented in docs/rankings.md.

Object and type rankings add up only the parameters the tool stands behind (``untrusted:
apart``, the default, :mod:`.headline`): the rest is ranked apart, one ``left_out`` row per
object or type that has any, under the same columns. A parameter whose value is exactly 0 is
flagged (``zero_value``) with its raw gradient: value weighting scores it 0 whatever ∂M/∂θ is.

The share is taken of Σc² over every ranked parameter, whatever ``--aggregate`` says: Σc² adds
up over disjoint groups, so the shares of keys and of types each sum to 1, while an l2 or a
signed sum would not (object shares may sum past 1: a shared parameter counts for each owner).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import KeyStats, key_stats, rank, scores
from sensaov_cli.buffer.statistics import mean_value
from sensaov_cli.errors import QueryError
from sensaov_cli.views.headline import ZeroValued, split_groups, zero_valued
from sensaov_cli.views.summary import ranked_groups, weakest_trust
from sensaov_cli.views.uncertainty import GroupError, Significance, Uncertainty
from sensaov_cli.vocabulary import ESTIMATORS, Aggregate, Cut, Grouping, Trust, Untrusted, Weight

RANKING_FORMAT = "sensaov-ranking"
# 2: standard errors, significance and stability; 3: Student-t significance, untrusted
# parameters ranked apart (left_out), zero-valued parameters flagged, part and raw_signed,
# each row's estimator
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
    untrusted: str = "include"  # how untrusted parameters were treated: apart | include
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

    With ``untrusted="apart"`` object and type rows add up trusted parameters only and the
    untrusted rest of each group becomes a row of ``left_out``. ``visible`` maps a camera name
    to the objects it sees; each row then lists the cameras that see none of its objects (for
    a key: none of its owners; a key with no owner is off-frame everywhere).
    Types have no place in a frame, so ``by="type"`` refuses cameras.
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
    untrusted: str


def check_cut(by: str, *, cameras: bool) -> None:
    """Refuse an unknown cut, and cameras with types: a type has no place in a frame."""
    if by not in GROUPING_OF:
        raise QueryError(f"unknown cut {by!r}", hint=f"use one of: {', '.join(GROUPING_OF)}")
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
    total_sq = math.fsum(s.sum_sq for s in stats.values())
    split = split_groups(buf, grouped, cut.untrusted)
    hidden = zero_valued(buf, objective, list(flowing)) if cut.weight == "value" else {}
    noise = Uncertainty.of(buf, objective, cut.method, cut.weight)
    part = "all" if cut.untrusted == "include" else "trusted"

    def rows(groups: Mapping[str, Sequence[str]], part: str, limit: int | None) -> list[RankRow]:
        ordered = rank(scores(stats, groups, cut.method))
        made = [
            _row(buf, i, name, score, groups[name], stats, total_sq, cut, hidden, part)
            for i, (name, score) in enumerate(ordered if limit is None else ordered[:limit], 1)
        ]
        if noise is not None:
            made = [_with_errors(row, noise.error(groups[row.name], row.score)) for row in made]
        elif cut.by == "key":  # without batches, a repaired parameter has its own seeds' error
            made = [_with_repair_error(buf, objective, r, cut.method, cut.weight) for r in made]
        return made

    stable = None if noise is None else noise.stability(rank(scores(stats, split.kept)), split.kept)
    return Ranking(
        objective=objective,
        objective_value=buf.objective(objective).value,
        by=cut.by,
        rows=tuple(rows(split.kept, part, top)),
        ranked=len(split.kept),
        total_signed=math.fsum(s.total for s in stats.values()),
        no_gradient=tuple(p for p in buf.params if p.trust == "no_gradient"),
        batches=None if noise is None else noise.batches,
        stability=None if stable is None else stable[0],
        stability_top=None if stable is None else stable[1],
        left_out=tuple(rows(split.left_out, "untrusted", None)),
        untrusted=cut.untrusted,
        significance=None if noise is None else noise.significance,
        zero_valued=tuple(hidden.values()),
    )


def _with_repair_error(
    buf: SensitivityBuffer, objective: str, row: RankRow, method: Aggregate, weight: Weight
) -> RankRow:
    repair = buf.repairs.get(row.name)
    if repair is None or not repair.has_error:
        return row
    theta = buf.value(row.name) if weight == "value" else np.ones(buf.param(row.name).shape)
    signed_se = repair.signed_error(objective, theta)
    score_se = {
        "sum": signed_se,
        "l2": repair.norm_error(objective, theta),
        "rms": repair.norm_error(objective, theta) / math.sqrt(max(theta.size, 1)),
    }[method]
    return replace(
        row,
        score_se=score_se,
        signed_se=signed_se,
        significant=repair.significant(row.signed, signed_se),
    )


def _with_errors(row: RankRow, error: GroupError) -> RankRow:
    return replace(
        row,
        score_se=error.score_se,
        signed_se=error.signed_se,
        significant=error.significant(row.signed),
    )


def _row(
    buf: SensitivityBuffer,
    index: int,
    name: str,
    score: float,
    keys: Sequence[str],
    stats: Mapping[str, KeyStats],
    total_sq: float,
    cut: _Cut,
    hidden: Mapping[str, ZeroValued],
    part: str,
) -> RankRow:
    group = [stats[k] for k in keys]
    signed = math.fsum(s.total for s in group)
    share = math.fsum(s.sum_sq for s in group) / total_sq if total_sq else 0.0
    objects = buf.param(name).owners if cut.by == "key" else (name,)
    zero = [hidden[k] for k in keys if k in hidden]
    return RankRow(
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
