"""The ranked summary of a buffer as a JSON-able dict (``sensaov rank --json``, ``run --json``).

:mod:`sensaov_cli.outputs.tables` renders the text from this dict, so both always say the same
thing. Parameters whose gradient
is not verified against finite differences (``ParamRecord.verified`` false) carry a ``!`` in the
text, with their notes in a legend under the table, and ``"verified": false`` in the dict;
objects and types that include such a parameter are marked the same way.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

from sensaov_cli.buffer.model import ObjectiveRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import groups, key_stats, rank, scores
from sensaov_cli.vocabulary import Aggregate, Weight

SUMMARY_FORMAT = "sensaov-summary"
SUMMARY_VERSION = 1

_CONTRIBUTION = {"value": "theta * dM/dtheta", "raw": "dM/dtheta"}


def summary_dict(
    buf: SensitivityBuffer, *, top: int = 8, method: Aggregate = "l2", weight: Weight = "value"
) -> dict[str, Any]:
    """Per objective: M, its definition, the top parameters and objects, and every type's score."""
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
        },
        "provenance": copy.deepcopy(buf.provenance),
        "objectives": [_objective_summary(buf, o, top, method, weight) for o in buf.objectives],
    }


def _objective_summary(
    buf: SensitivityBuffer, objective: ObjectiveRecord, top: int, method: Aggregate, weight: Weight
) -> dict[str, Any]:
    stats = key_stats(buf, objective.name, weight=weight)  # one pass, three groupings
    by_param = groups(buf, None, "param")
    by_object = groups(buf, None, "object")
    by_type = groups(buf, None, "type")

    def verified(keys: Sequence[str]) -> bool:
        return all(buf.param(k).verified for k in keys)

    parameters = []
    for key, score in rank(scores(stats, by_param, method), top):
        p = buf.param(key)
        parameters.append(
            {
                "key": key,
                "type": p.type,
                "owners": list(p.owners),
                "plugin": p.plugin,
                "shape": list(p.shape),
                "score": score,
                "signed": stats[key].total,
                "verified": p.verified,
                "note": p.note,
            }
        )
    objects = [
        {"name": name, "score": score, "verified": verified(by_object[name])}
        for name, score in rank(scores(stats, by_object, method), top)
    ]
    types = [
        {"type": name, "score": score, "verified": verified(by_type[name])}
        for name, score in rank(scores(stats, by_type, method))
    ]
    return {
        "name": objective.name,
        "value": objective.value,
        "definition": copy.deepcopy(objective.definition),
        "grad_seed": objective.grad_seed,
        "parameters": parameters,
        "objects": objects,
        "types": types,
    }
