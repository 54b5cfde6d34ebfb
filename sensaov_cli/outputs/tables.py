"""The text tables a terminal shows: ``rank``/``run``'s summary, and the aligned table.

One aligned-table function serves them, ``params`` (params_table.py) and ``check``'s tables
(check_tables.py); JSON output comes from the same data (the dicts of
:mod:`sensaov_cli.views.summary`), so text and JSON always agree.
Plain text only: no colour, no box drawing, so logs and farm consoles read it as it is.
"""

from __future__ import annotations

import unicodedata
from collections.abc import Collection, Sequence
from typing import Any

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.views.headline import ZeroValued
from sensaov_cli.views.summary import summary_dict
from sensaov_cli.vocabulary import Aggregate, Untrusted, Weight

# Marks in the mark column of a ranking, one per label that is not "verified"; a parameter
# with no gradient is never ranked: it is listed under its objective behind NO_GRADIENT_MARK.
UNVERIFIED_MARK = "!"  # unverified or known biased
SUSPECT_MARK = "?"  # failed a run-time self-check
NO_GRADIENT_MARK = "0"
ZERO_VALUE_MARK = "θ0"  # θ is 0 where ∂M/∂θ is not: value weighting scores it 0 regardless
# What each label means, said the same way in every legend (docs/verification.md).
LABEL_MEANINGS = {
    "biased": "biased: disagrees with finite differences, do not trust the number",
    "unverified": "unverified: not checked against finite differences, or too noisy to tell",
    "suspect": "suspect: failed a run-time self-check",
}
_MARKS = {"unverified": UNVERIFIED_MARK, "biased": UNVERIFIED_MARK, "suspect": SUSPECT_MARK}
_PROVENANCE_SHOWN = {"scene_path": "scene", "variant": "variant", "spp": "spp"}  # key: label
_OWNERS_SHOWN = 3


def format_table(
    rows: Sequence[Sequence[str]], *, numeric: Collection[int] = (), indent: str = ""
) -> list[str]:
    """Columns separated by two spaces, the first row the header; ``numeric`` right-aligned.

    Cells pass through :func:`printable`: a key with a newline must not break the table.
    """
    rows = [[printable(cell) for cell in row] for row in rows]
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return [
        (
            indent
            + "  ".join(
                cell.rjust(w) if c in numeric else cell.ljust(w)
                for c, (cell, w) in enumerate(zip(row, widths, strict=True))
            )
        ).rstrip()
        for row in rows
    ]


def printable(text: str) -> str:
    """``text`` with control characters escaped (``\\n``): names from a buffer are data."""
    if text.isprintable():
        return text
    return "".join(
        ch.encode("unicode_escape").decode("ascii") if unicodedata.category(ch)[0] == "C" else ch
        for ch in text
    )


def summary_text(
    buf: SensitivityBuffer,
    *,
    top: int = 8,
    method: Aggregate = "l2",
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
) -> str:
    """The summary as short aligned tables, one block per objective, for a terminal."""
    summary = summary_dict(buf, top=top, method=method, weight=weight, untrusted=untrusted)
    return render_text(summary)


def render_text(summary: dict[str, Any]) -> str:
    """Text for a dict made by :func:`summary_dict`."""
    counts, agg = summary["counts"], summary["aggregation"]
    head = "sensitivity buffer: " + ", ".join(
        _count(counts[name], name[:-1]) for name in ("parameters", "objects", "objectives")
    )
    prov = summary["provenance"]
    shown = [
        f"{label} {printable(str(prov[key]))}"
        for key, label in _PROVENANCE_SHOWN.items()
        if isinstance(prov.get(key), str | int | float)
    ]
    lines = [" · ".join([head, *shown])]
    lines.append(f"scores: {agg['method']} of {agg['contribution']} over each group's components")
    if agg["method"] != "sum":
        lines.append("signed: their plain sum; > 0 means increasing the parameter raises M")
    lines += _repairs_lines(prov.get("repairs"))
    if counts.get("batches"):
        lines.append(
            f"standard errors from {counts['batches']} batches: 'sensaov rank BUFFER --by "
            "object' (or key, type) shows them beside every score"
        )
    for objective in summary["objectives"]:
        lines.append("")
        lines.extend(_objective_lines(objective, agg["method"], counts))
    return "\n".join(lines) + "\n"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _fmt(score: float, signed: bool) -> str:
    return f"{score:+.2e}" if signed else f"{score:.2e}"


def _mark(trust: str) -> str:
    return _MARKS.get(trust, "")


def _owners(owners: Sequence[str]) -> str:
    if len(owners) <= _OWNERS_SHOWN:
        return ", ".join(owners) or "-"
    return ", ".join(owners[:_OWNERS_SHOWN]) + f" +{len(owners) - _OWNERS_SHOWN} more"


def _objective_lines(objective: dict[str, Any], method: str, counts: dict[str, int]) -> list[str]:
    signed = method == "sum"
    params, objects, types = objective["parameters"], objective["objects"], objective["types"]
    lines = [f"objective {objective['name']!r}   M = {objective['value']:.4g}"]

    lines.append(f"  parameters (top {len(params)} of {counts['ranked_parameters']})")
    headers = ["#", "", "score", *([] if signed else ["signed"]), "type", "estimator", "key",
               "owners"]  # fmt: skip
    rows = [
        [str(i), _mark(p["trust"]) + (ZERO_VALUE_MARK if p.get("zero_value") else ""),
         _fmt(p["score"], signed), *([] if signed else [_fmt(p["signed"], True)]), p["type"],
         p["estimator"], p["key"], _owners(p["owners"])]
        for i, p in enumerate(params, 1)
    ]  # fmt: skip
    lines.extend(_indented(headers, rows, numeric={0, 2} if signed else {0, 2, 3}))
    apart = objective.get("untrusted") == "apart"
    trusted = " (trusted parameters only)" if apart else ""
    ranked = objective.get("ranked_objects", counts["ranked_objects"])
    lines.append(f"  objects{trusted} (top {len(objects)} of {ranked})")
    lines.extend(_group_table("object", "name", objects, signed))
    lines.append(f"  types{trusted}")
    lines.extend(_group_table("type", "type", types, signed))
    left = objective.get("left_out") or {}
    if left.get("objects") or left.get("types"):
        lines.append("  left out of the objects and types above (not trusted), by object:")
        lines += [
            printable(f"      {e['name']}  {_fmt(e['score'], signed)}  {_fmt(e['signed'], True)}  "
                      + ", ".join(f"{k} ({t})" for k, t in e["keys"]))
            for e in left["objects"]
        ]  # fmt: skip
    lines.extend(_legend(objective))
    lines.extend(_repaired_legend(objective))
    return lines


def _repairs_lines(figures: Any) -> list[str]:
    """What the run repaired by finite differences, and what it left labelled (and why)."""
    if not isinstance(figures, dict) or not (
        figures.get("repaired") or figures.get("not_repaired")
    ):
        return []
    repaired = figures.get("repaired") or []
    lines = [
        f"repairs: {_count(len(repaired), 'parameter')} known wrong in reverse mode, by central "
        f"differences ({len(figures.get('seeds') or [])} seeds x {figures.get('spp')} spp, "
        f"{figures.get('renders')} renders, {figures.get('seconds', 0):.1f} s)"
    ]
    for key, why in (figures.get("not_repaired") or {}).items():
        lines.append(printable(f"  not repaired, still labelled: {key}: {why}"))
    return lines


def _repaired_legend(objective: dict[str, Any]) -> list[str]:
    """Each repaired parameter shown: its signed sum with its own standard error."""
    shown = [p for p in objective["parameters"] if "signed_se" in p]
    if not shown:
        return []
    lines = [
        "  finite-difference = repaired (reverse mode is known wrong there), ± its seeds' error:"
    ]
    for p in shown:
        sign = "" if p["significant"] else "; sign not significant"
        lines.append(
            printable(f"      {p['key']}: {p['signed']:+.2e} ± {p['signed_se']:.1e} "
                      f"({p['seeds']} seeds{sign})")
        )  # fmt: skip
    return lines


def _group_table(title: str, field: str, entries: list[dict[str, Any]], signed: bool) -> list[str]:
    if signed:
        rows = [
            [str(i), _mark(e["trust"]) + (ZERO_VALUE_MARK if e.get("zero_value") else ""),
             _fmt(e["score"], signed), e[field]]
            for i, e in enumerate(entries, 1)
        ]  # fmt: skip
        return _indented(["#", "", "score", title], rows, numeric={0, 2})
    rows = [  # the signed sum and its rank beside the score (docs/encoding.md: which to read)
        [str(i), _mark(e["trust"]) + (ZERO_VALUE_MARK if e.get("zero_value") else ""),
         _fmt(e["score"], False), _fmt(e["signed"], True),
         str(e["signed_rank"]), e[field]]
        for i, e in enumerate(entries, 1)
    ]  # fmt: skip
    return _indented(["#", "", "score", "signed", "#sum", title], rows, numeric={0, 2, 3, 4})


def trust_legend(trusts: Sequence[str], *, groups: bool) -> list[str]:
    """The marks' meanings for the labels among ``trusts``, each label named as it is."""
    present = set(trusts)
    lines = []
    for mark, labels in ((UNVERIFIED_MARK, ("biased", "unverified")), (SUSPECT_MARK, ("suspect",))):
        shown = [label for label in labels if label in present]
        if shown:
            lines.append(f"  {mark} = " + "; ".join(LABEL_MEANINGS[label] for label in shown))
    if lines and groups:
        lines.append("    a group so marked includes such a parameter")
    return lines


def zero_value_legend(found: Sequence[ZeroValued]) -> list[str]:
    """What ``θ0`` means and the raw gradient of every parameter it marks."""
    if not found:
        return []
    lines = [
        f"  {ZERO_VALUE_MARK} = value exactly 0: θ·∂M/∂θ is 0 whatever the gradient; "
        "its raw gradient (Σ ∂M/∂θ, per unit of θ):"
    ]
    lines += [
        printable(f"      {z.key} ({', '.join(z.owners) or '-'}): {z.raw_signed:+.3e}"
                  f"{'' if z.hidden == z.size else f' ({z.hidden} of {z.size} components 0)'}")
        for z in found
    ]  # fmt: skip
    return lines


def _legend(objective: dict[str, Any]) -> list[str]:
    params = objective["parameters"]
    groups = objective["objects"] + objective["types"]
    lines = []
    marked = [p for p in params if p["trust"] not in ("verified", "no_gradient")]
    labels = [p["trust"] for p in params] + [g["trust"] for g in groups]
    lines += trust_legend(labels, groups=False)
    lines += [printable(f"      {p['key']}: {p['trust']}: {p['note']}") for p in marked]
    if any(_mark(g["trust"]) for g in groups):
        lines.append("    objects and types so marked include such a parameter")
    zero = [ZeroValued(z["key"], tuple(z["owners"]), z["hidden"], z["size"], z["raw_signed"])
            for z in objective.get("zero_valued", ())]  # fmt: skip
    lines += zero_value_legend(zero)
    if objective["no_gradient"]:
        lines.append(f"  {NO_GRADIENT_MARK} = no gradient flows, not ranked:")
        lines += [
            printable(f"      {p['key']} ({', '.join(p['owners']) or '-'}): {p['note']}")
            for p in objective["no_gradient"]
        ]
    return lines


def _indented(headers: list[str], rows: list[list[str]], numeric: set[int]) -> list[str]:
    """Aligned rows indented under a section title."""
    if not rows:
        return ["    (none)"]
    return format_table([headers, *rows], numeric=numeric, indent="    ")
