"""The ranked summary of a buffer: a JSON-able dict and the aligned text a person reads.

The text is rendered from the dict, so both always say the same thing. Parameters whose gradient
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

UNVERIFIED_MARK = "!"
_CONTRIBUTION = {"value": "theta * dM/dtheta", "raw": "dM/dtheta"}
_PROVENANCE_SHOWN = {"scene_path": "scene", "variant": "variant", "spp": "spp"}  # key: label
_OWNERS_SHOWN = 3


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


def summary_text(
    buf: SensitivityBuffer, *, top: int = 8, method: Aggregate = "l2", weight: Weight = "value"
) -> str:
    """The summary as short aligned tables, one block per objective, for a terminal."""
    return render_text(summary_dict(buf, top=top, method=method, weight=weight))


def render_text(summary: dict[str, Any]) -> str:
    """Text for a dict made by :func:`summary_dict`."""
    counts, agg = summary["counts"], summary["aggregation"]
    head = "sensitivity buffer: " + ", ".join(
        _count(counts[name], name[:-1]) for name in ("parameters", "objects", "objectives")
    )
    prov = summary["provenance"]
    shown = [
        f"{label} {prov[key]}"
        for key, label in _PROVENANCE_SHOWN.items()
        if isinstance(prov.get(key), str | int | float)
    ]
    lines = [" · ".join([head, *shown])]
    lines.append(f"scores: {agg['method']} of {agg['contribution']} over each group's components")
    if agg["method"] != "sum":
        lines.append("signed: their plain sum; > 0 means increasing the parameter raises M")
    for objective in summary["objectives"]:
        lines.append("")
        lines.extend(_objective_lines(objective, agg["method"], counts))
    return "\n".join(lines) + "\n"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _fmt(score: float, signed: bool) -> str:
    return f"{score:+.2e}" if signed else f"{score:.2e}"


def _mark(verified: bool) -> str:
    return "" if verified else UNVERIFIED_MARK


def _owners(owners: Sequence[str]) -> str:
    if len(owners) <= _OWNERS_SHOWN:
        return ", ".join(owners) or "-"
    return ", ".join(owners[:_OWNERS_SHOWN]) + f" +{len(owners) - _OWNERS_SHOWN} more"


def _objective_lines(objective: dict[str, Any], method: str, counts: dict[str, int]) -> list[str]:
    signed = method == "sum"
    params, objects, types = objective["parameters"], objective["objects"], objective["types"]
    lines = [f"objective {objective['name']!r}   M = {objective['value']:.4g}"]

    lines.append(f"  parameters (top {len(params)} of {counts['parameters']})")
    headers = ["#", "", "score", *([] if signed else ["signed"]), "type", "key", "owners"]
    rows = [
        [str(i), _mark(p["verified"]), _fmt(p["score"], signed),
         *([] if signed else [_fmt(p["signed"], True)]), p["type"], p["key"], _owners(p["owners"])]
        for i, p in enumerate(params, 1)
    ]  # fmt: skip
    lines.extend(_table(headers, rows, numeric={0, 2} if signed else {0, 2, 3}))

    lines.append(f"  objects (top {len(objects)} of {counts['objects']})")
    lines.extend(_group_table("object", "name", objects, signed))
    lines.append("  types")
    lines.extend(_group_table("type", "type", types, signed))
    lines.extend(_legend(objective))
    return lines


def _group_table(title: str, field: str, entries: list[dict[str, Any]], signed: bool) -> list[str]:
    rows = [
        [str(i), _mark(e["verified"]), _fmt(e["score"], signed), e[field]]
        for i, e in enumerate(entries, 1)
    ]
    return _table(["#", "", "score", title], rows, numeric={0, 2})


def _legend(objective: dict[str, Any]) -> list[str]:
    unverified = [p for p in objective["parameters"] if not p["verified"]]
    groups_marked = any(not g["verified"] for g in objective["objects"] + objective["types"])
    mark = UNVERIFIED_MARK
    if not unverified:
        return [f"  {mark} = includes a parameter whose gradient is unverified"] * groups_marked
    lines = [f"  {mark} = unverified gradient, do not trust the number:"]
    lines += [f"      {p['key']}: {p['note'] or 'not verified'}" for p in unverified]
    if groups_marked:
        lines.append(f"    objects and types marked {mark} include such a parameter")
    return lines


def _table(headers: list[str], rows: list[list[str]], numeric: set[int]) -> list[str]:
    """Aligned rows indented under a section title; ``numeric`` columns are right-aligned."""
    if not rows:
        return ["    (none)"]
    widths = [max(len(r[c]) for r in [headers, *rows]) for c in range(len(headers))]

    def line(cells: list[str]) -> str:
        padded = [
            cell.rjust(w) if c in numeric else cell.ljust(w)
            for c, (cell, w) in enumerate(zip(cells, widths, strict=True))
        ]
        return ("    " + "  ".join(padded)).rstrip()

    return [line(headers), *(line(r) for r in rows)]
