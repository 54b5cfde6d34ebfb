"""Rankings at one cut of the hierarchy (``sensaov rank --by``): key, object or type; numpy only.

One table per objective whose every row carries what a reader needs to judge it: the score
(the chosen aggregate), the signed sum Σc beside it, its sign, the row's share of the total
response, the parameter's value (key rows), the trust label and, when cameras are given, the
cameras that do not see it (off-frame). The columns are documented in docs/rankings.md.

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
from sensaov_cli.errors import QueryError
from sensaov_cli.views.summary import ranked_groups, weakest_trust
from sensaov_cli.views.uncertainty import GroupError, Uncertainty
from sensaov_cli.vocabulary import ESTIMATORS, Aggregate, Cut, Grouping, Trust, Weight

RANKING_FORMAT = "sensaov-ranking"
RANKING_VERSION = 3  # 2: standard errors, significance and stability; 3: estimators
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
    significant: bool | None = None  # |signed| > 2 signed_se: the sign is beyond noise
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


def rankings(
    buf: SensitivityBuffer,
    *,
    by: Cut,
    objectives: Sequence[str] | None = None,
    top: int | None = None,
    method: Aggregate = "l2",
    weight: Weight = "value",
    visible: Mapping[str, frozenset[str]] | None = None,
) -> tuple[Ranking, ...]:
    """The ranking of every objective (or of ``objectives``) at the cut ``by``.

    ``visible`` maps a camera name to the objects it sees; each row then lists the cameras
    that see none of its objects (for a key: none of its owners; a key with no owner is
    off-frame everywhere). Types have no place in a frame, so ``by="type"`` refuses cameras.
    """
    check_cut(by, cameras=visible is not None)
    names = [o.name for o in buf.objectives] if objectives is None else list(objectives)
    grouped = ranked_groups(buf)
    return tuple(
        _ranking(
            buf, name, grouped[GROUPING_OF[by]], grouped["param"], by, top, method, weight, visible
        )
        for name in names
    )


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
    by: Cut,
    top: int | None,
    method: Aggregate,
    weight: Weight,
    visible: Mapping[str, frozenset[str]] | None,
) -> Ranking:
    stats = key_stats(buf, objective, flowing, weight=weight)
    total_sq = math.fsum(s.sum_sq for s in stats.values())
    ordered = rank(scores(stats, grouped, method))
    rows = tuple(
        _row(
            buf,
            i,
            name,
            score,
            [stats[k] for k in grouped[name]],
            grouped[name],
            by,
            total_sq,
            visible,
        )
        for i, (name, score) in enumerate(ordered if top is None else ordered[:top], 1)
    )
    noise = Uncertainty.of(buf, objective, method, weight)
    stable: tuple[float, int] | None = None
    if noise is not None:
        rows = tuple(_with_errors(row, noise.error(grouped[row.name], row.score)) for row in rows)
        stable = noise.stability(ordered, grouped)
    elif by == "key":  # without batches, a repaired parameter still has its own seeds' error
        rows = tuple(_with_repair_error(buf, objective, row, method, weight) for row in rows)
    return Ranking(
        objective=objective,
        objective_value=buf.objective(objective).value,
        by=by,
        rows=rows,
        ranked=len(ordered),
        total_signed=math.fsum(s.total for s in stats.values()),
        no_gradient=tuple(p for p in buf.params if p.trust == "no_gradient"),
        batches=None if noise is None else noise.batches,
        stability=None if stable is None else stable[0],
        stability_top=None if stable is None else stable[1],
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
    stats: Sequence[KeyStats],
    keys: Sequence[str],
    by: Cut,
    total_sq: float,
    visible: Mapping[str, frozenset[str]] | None,
) -> RankRow:
    signed = math.fsum(s.total for s in stats)
    share = math.fsum(s.sum_sq for s in stats) / total_sq if total_sq else 0.0
    objects = buf.param(name).owners if by == "key" else (name,)
    return RankRow(
        rank=index,
        name=name,
        score=score,
        signed=signed,
        share=share,
        sign="+" if signed > 0 else "-" if signed < 0 else "0",
        value=_mean_value(buf, name) if by == "key" else None,
        trust=weakest_trust(buf, keys),
        off_frame=None if visible is None else off_frame(objects, visible),
        estimator=estimators(buf, keys),
    )


def estimators(buf: SensitivityBuffer, keys: Sequence[str]) -> str:
    """The distinct estimators of ``keys``' gradients, in vocabulary order, joined by "+"."""
    found = {buf.param(k).estimator for k in keys}
    return "+".join(e for e in ESTIMATORS if e in found) or "-"


def _mean_value(buf: SensitivityBuffer, key: str) -> float | None:
    """One number for a value array (a colour, a texture): its mean; None when it is empty."""
    value = buf.value(key)
    return float(value.astype("float64").mean()) if value.size else None


def off_frame(objects: Sequence[str], visible: Mapping[str, frozenset[str]]) -> tuple[str, ...]:
    """The cameras (in the given order) that see none of ``objects``."""
    return tuple(camera for camera, seen in visible.items() if seen.isdisjoint(objects))
