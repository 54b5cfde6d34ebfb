"""The ranked summary of a buffer as a JSON-able dict (``sensaov rank --json``, ``run --json``).

:mod:`sensaov_cli.outputs.tables` renders the text from this dict, so both always say the same
thing. Every parameter carries its trust label (docs/verification.md) and ``"verified"``
(label "verified"); objects and types carry the weakest label among their parameters. The
text marks them (``!`` unverified or biased, ``?`` suspect) with their notes in a legend.

Objects and types add up only the parameters the tool stands behind (``untrusted: apart``,
:mod:`.headline`); each objective lists the rest under ``"left_out"``, by object and by type,
with every key's label. Parameters whose value is exactly 0 are listed under ``"zero_valued"``
with their raw gradient, and flagged (``"zero_value"``) where they are ranked.

A parameter whose gradient is identically zero (label ``no_gradient``) is not a result: it is
listed apart, under ``"no_gradient"`` with its reason, and left out of every score, and an
object or type made only of such parameters is left out of its ranking.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ObjectiveRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import KeyStats, groups, key_stats, rank, scores
from sensaov_cli.views.headline import check_untrusted, split_groups, zero_valued
from sensaov_cli.vocabulary import Aggregate, Grouping, Trust, Untrusted, Weight

SUMMARY_FORMAT = "sensaov-summary"
# 2: trust labels, the "no_gradient" list, ranked counts; 3: objects and types of trusted
# parameters only ("untrusted", "left_out"), "zero_valued", and "zero_value" on parameters;
# each parameter's estimator, and a repaired one's own standard error
SUMMARY_VERSION = 3

_CONTRIBUTION = {"value": "theta * dM/dtheta", "raw": "dM/dtheta"}
# A group shows the weakest label among its ranked parameters.
_WEAKEST_FIRST: tuple[Trust, ...] = ("suspect", "biased", "unverified", "verified")
_GROUPINGS: tuple[Grouping, ...] = ("param", "object", "type")


def summary_dict(
    buf: SensitivityBuffer,
    *,
    top: int = 8,
    method: Aggregate = "l2",
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
) -> dict[str, Any]:
    """Per objective: M, its definition, the top parameters and objects, and every type's score."""
    check_untrusted(untrusted)
    ranked = ranked_groups(buf)
    return {
        "format": SUMMARY_FORMAT,
        "format_version": SUMMARY_VERSION,
        "aggregation": {
            "method": method,
            "weight": weight,
            "contribution": _CONTRIBUTION.get(weight, weight),
        },
        "counts": {
            "parameters": len(buf.params),
            "objects": len(buf.objects),
            "objectives": len(buf.objectives),
            "ranked_parameters": len(ranked["param"]),
            "ranked_objects": len(ranked["object"]),
            # batches behind the buffer's standard errors (None: no statistics); the summary
            # points at `rank --by`, which shows them
            "batches": None if buf.statistics is None else buf.statistics.batches,
        },
        "provenance": copy.deepcopy(buf.provenance),
        "objectives": [
            _objective_summary(buf, o, ranked, top, method, weight, untrusted)
            for o in buf.objectives
        ],
    }


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


def weakest_trust(buf: SensitivityBuffer, keys: Sequence[str]) -> Trust:
    """The label a group of ``keys`` shows: the weakest among its parameters'."""
    labels = {buf.param(k).trust for k in keys}
    return next((label for label in _WEAKEST_FIRST if label in labels), "verified")


def _objective_summary(
    buf: SensitivityBuffer,
    objective: ObjectiveRecord,
    ranked: Mapping[Grouping, Mapping[str, Sequence[str]]],
    top: int,
    method: Aggregate,
    weight: Weight,
    untrusted: Untrusted,
) -> dict[str, Any]:
    stats = key_stats(buf, objective.name, ranked["param"], weight=weight)  # one pass, 3 groupings
    hidden = zero_valued(buf, objective.name, list(ranked["param"])) if weight == "value" else {}
    objects = split_groups(buf, ranked["object"], untrusted)
    types = split_groups(buf, ranked["type"], untrusted)
    params = _parameters(buf, stats, ranked["param"], top, method)
    for entry in params:
        entry.update(repair_error(buf, objective.name, entry["key"], entry["signed"], weight))
    return {
        "name": objective.name,
        "value": objective.value,
        "definition": copy.deepcopy(objective.definition),
        "grad_seed": objective.grad_seed,
        "untrusted": untrusted,
        "ranked_objects": len(objects.kept),
        "parameters": [
            {
                **entry,
                "zero_value": entry["key"] in hidden,
                "raw_signed": hidden[entry["key"]].raw_signed if entry["key"] in hidden else None,
            }
            for entry in params
        ],  # fmt: skip
        "objects": _group_entries(buf, stats, objects.kept, "name", method, top, hidden),
        "types": _group_entries(buf, stats, types.kept, "type", method, None, hidden),
        "left_out": {
            "objects": _left_out(buf, stats, objects.left_out, method),
            "types": _left_out(buf, stats, types.left_out, method),
        },
        "zero_valued": [
            {
                "key": z.key,
                "owners": list(z.owners),
                "hidden": z.hidden,
                "size": z.size,
                "raw_signed": z.raw_signed,
            }
            for z in hidden.values()
        ],  # fmt: skip
        "no_gradient": [
            {
                "key": p.key,
                "type": p.type,
                "owners": list(p.owners),
                "plugin": p.plugin,
                "note": p.note,
            }
            for p in buf.params
            if p.trust == "no_gradient"
        ],
    }


def _parameters(
    buf: SensitivityBuffer,
    stats: Mapping[str, KeyStats],
    by_param: Mapping[str, Sequence[str]],
    top: int,
    method: Aggregate,
) -> list[dict[str, Any]]:
    entries = []
    for key, score in rank(scores(stats, by_param, method), top):
        p = buf.param(key)
        entries.append(
            {
                "key": key,
                "type": p.type,
                "owners": list(p.owners),
                "plugin": p.plugin,
                "shape": list(p.shape),
                "score": score,
                "signed": stats[key].total,
                "verified": p.verified,
                "trust": p.trust,
                "note": p.note,
                "estimator": p.estimator,
            }
        )
    return entries


def repair_error(
    buf: SensitivityBuffer, objective: str, key: str, signed: float, weight: Weight
) -> dict[str, Any]:
    """A repaired parameter's own standard error of its signed sum, the significance of its
    sign and its seed count (buffer/repairs.py); {} for any other parameter."""
    repair = buf.repairs.get(key)
    if repair is None or not repair.has_error:
        return {}
    theta = buf.value(key) if weight == "value" else np.ones(buf.param(key).shape)
    error = repair.signed_error(objective, theta)
    return {
        "signed_se": error,
        "significant": repair.significant(signed, error),
        "seeds": len(repair.seeds),
    }


def _group_entries(
    buf: SensitivityBuffer,
    stats: Mapping[str, KeyStats],
    grouped: Mapping[str, Sequence[str]],
    field: str,
    method: Aggregate,
    top: int | None,
    hidden: Mapping[str, Any],
) -> list[dict[str, Any]]:
    # The signed sum beside every score, with its own rank: a texture's l2 is about
    # 1/sqrt(texels) of its sum, so l2 and sum can rank one group far apart (docs/encoding.md).
    sums = scores(stats, grouped, "sum")
    sum_rank = {name: i for i, (name, _) in enumerate(rank(sums), 1)}
    entries = []
    for name, score in rank(scores(stats, grouped, method), top):
        trust = weakest_trust(buf, grouped[name])
        entries.append({field: name, "score": score, "signed": sums[name],
                        "signed_rank": sum_rank[name], "verified": trust == "verified",
                        "trust": trust,
                        "zero_value": any(k in hidden for k in grouped[name])})  # fmt: skip
    return entries


def _left_out(
    buf: SensitivityBuffer,
    stats: Mapping[str, KeyStats],
    grouped: Mapping[str, Sequence[str]],
    method: Aggregate,
) -> list[dict[str, Any]]:
    """The untrusted part of each group, largest first, with each key and its label."""
    return [
        {"name": name, "score": score, "signed": scores(stats, {name: grouped[name]}, "sum")[name],
         "trust": weakest_trust(buf, grouped[name]),
         "keys": [[k, buf.param(k).trust] for k in grouped[name]]}
        for name, score in rank(scores(stats, grouped, method))
    ]  # fmt: skip
