"""What a terminal shows and ``rank``/``run``/``params`` print: the summary and the rankings, a
scene's parameters and their checks, as text and JSON, in aligned tables.

One aligned-table function serves them all. ``rank``: text and JSON are both written from one
:class:`~sensaov_cli.views.hierarchy.Summary`, so they agree. ``rank --by``'s JSON, CSV and
text come from the same :class:`~sensaov_cli.views.hierarchy.Ranking` rows and carry the same
columns (docs/rankings.md): the JSON is the reference, the CSV one line per row with the
objective first, and the text the same numbers aligned, with the trust marks of the summary and
their legend. Plain text only: no colour, no box drawing, so logs and farm consoles read it as
it is.
"""

from __future__ import annotations

import csv
import io
import json
import unicodedata
from collections import Counter, defaultdict
from collections.abc import Collection, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, TypeVar

from sensaov_cli.buffer.model import ExcludedParam, ParamRecord, SensitivityBuffer, TextureSource
from sensaov_cli.views.hierarchy import (
    ORDER_GAP,
    RANKING_FORMAT,
    RANKING_VERSION,
    SUMMARY_FORMAT,
    SUMMARY_VERSION,
    ObjectiveSummary,
    RankedGroup,
    RankedParameter,
    Ranking,
    RankRow,
    Resolution,
    Summary,
    ZeroValued,
    other_score,
    ranked_summary,
)
from sensaov_cli.vocabulary import DEFAULT_AGGREGATE, Aggregate, Untrusted, Weight

# Marks in the mark column of a ranking, one per label that is not "verified"; a parameter
# with no gradient is never ranked: it is listed under its objective behind NO_GRADIENT_MARK.
UNVERIFIED_MARK = "!"  # unverified or known biased
SUSPECT_MARK = "?"  # failed a run-time self-check
NO_GRADIENT_MARK = "0"
# After a sign its batches cannot resolve (within its 95 % interval, or heavy-tailed): "+?".
UNRESOLVED_MARK = "?"
# After a rank by the other score that differs markedly from the row's own (hierarchy.ORDER_GAP).
ORDERS_DISAGREE_MARK = "≠"
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
_REASONS_SHOWN = 3  # distinct reasons a summarised list names
ALL_HINT = "--all lists them"
T = TypeVar("T")
CONTRIBUTION = {"value": "theta * dM/dtheta", "raw": "dM/dtheta"}  # what a score adds up
# What a row's share is of (views.hierarchy.share_total), by score.
SHARE_OF = {
    "sum": "|signed| over the sum of every parameter's |signed|",
    "l2": "of the total sum of squares",
    "rms": "of the total sum of squares",
}
# The columns of a row, in JSON, CSV and text order (CSV puts "objective" first).
COLUMNS = (
    "rank", "name", "score", "signed", "share", "sign", "value", "trust", "not_seen_by",
    "score_se", "signed_se", "dof", "resolved", "noisy", "other_score", "other_rank",
    "orders_disagree", "part", "zero_value", "raw_signed", "estimator",
)  # fmt: skip
# What a row of the summary's parameters, objects and types adds to its own fields.
_ROW_ERRORS = ("score_se", "signed_se", "dof", "resolved", "noisy", "other_score", "other_rank",
               "orders_disagree")  # fmt: skip


def format_table(
    rows: Sequence[Sequence[str]], *, numeric: Collection[int] = (), indent: str = ""
) -> list[str]:
    """Columns separated by two spaces, the first row the header; ``numeric`` right-aligned.
    Cells pass through :func:`printable`: a key with a newline must not break the table."""
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
    method: Aggregate = DEFAULT_AGGREGATE,
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
    show_all: bool = False,
) -> str:
    """The summary as short aligned tables, one block per objective, for a terminal.

    A list longer than ``top`` (parameters with no gradient, objects left out, zero values) is
    summarised in a line per kind unless ``show_all``: a scene of 500 objects stays readable.
    """
    summary = ranked_summary(buf, top=top, method=method, weight=weight, untrusted=untrusted)
    counts = {"parameter": len(buf.params), "object": len(buf.objects),
              "objective": len(buf.objectives)}  # fmt: skip
    head = "sensitivity buffer: " + ", ".join(_count(n, noun) for noun, n in counts.items())
    prov = buf.provenance
    shown = [
        f"{label} {printable(str(prov[key]))}"
        for key, label in _PROVENANCE_SHOWN.items()
        if isinstance(prov.get(key), str | int | float)
    ]
    lines = [" · ".join([head, *shown])]
    method = summary.method
    lines.append(f"scores: {method} of {CONTRIBUTION[summary.weight]} over each group's components")
    if method != "sum":
        lines.append("signed: their plain sum; > 0 means increasing the parameter raises M")
    lines += _repairs_lines(prov.get("repairs"), None if show_all else top)
    lines += resolution_lines(
        buf.statistics.batches if buf.statistics is not None else None,
        summary.objectives[0].resolution if summary.objectives else None,
    )
    for objective in summary.objectives:
        lines.append("")
        limit = None if show_all else top
        lines.extend(_objective_lines(objective, method, summary.ranked_parameters, limit))
    return "\n".join(lines) + "\n"


def summary_json(summary: Summary, files: Mapping[str, str] | None = None) -> str:
    """The ``sensaov-summary`` document (``rank --json``, ``run --json`` with its ``files``)."""
    buf = summary.buffer
    document = {
        "format": SUMMARY_FORMAT,
        "format_version": SUMMARY_VERSION,
        "aggregation": _aggregation(summary.method, summary.weight),
        "counts": {
            "parameters": len(buf.params),
            "objects": len(buf.objects),
            "objectives": len(buf.objectives),
            "ranked_parameters": summary.ranked_parameters,
            "ranked_objects": summary.ranked_objects,
            "batches": None if buf.statistics is None else buf.statistics.batches,
        },
        "provenance": buf.provenance,
        "objectives": [_objective_json(o) for o in summary.objectives],
    }
    if files is not None:
        document["files"] = dict(files)
    return json.dumps(document, indent=2)  # tuples become lists


def _aggregation(method: Aggregate, weight: Weight) -> dict[str, str]:
    return {"method": method, "weight": weight, "contribution": CONTRIBUTION[weight],
            "other": other_score(method), "default": DEFAULT_AGGREGATE}  # fmt: skip


def resolution_lines(batches: int | None, rule: Resolution | None) -> list[str]:
    """What ± and ``?`` mean under a buffer's statistics, or plainly that there is no error."""
    if rule is None:
        return [
            "no error: this buffer has one batch, so no number has a standard error and no sign "
            "is known to be resolved (render.batches >= 2, or a merge of shards, gives them)"
        ]
    return [
        f"±: standard error from {batches} batches; {UNRESOLVED_MARK} = unresolved: |signed| "
        f"within {rule.factor:.2f} standard errors (Student's t, {rule.dof} degrees of freedom, "
        f"{100 * rule.level:.0f} % two-sided) or heavy-tailed batches (noisy); ranked after the "
        "resolved rows, drawn neutral"
    ]


def value_text(value: float, se: float | None) -> str:
    """M with its standard error, or with none measured."""
    return f"{value:.4g}" if se is None else f"{value:.4g} ± {se:.2g}"


def _objective_json(summary: ObjectiveSummary) -> object:
    objective = summary.objective
    return {
        "name": objective.name,
        "value": objective.value,
        "value_se": summary.objective_se,
        "resolution": None if summary.resolution is None else asdict(summary.resolution),
        "definition": objective.definition,
        "grad_seed": objective.grad_seed,
        "untrusted": summary.untrusted,
        "ranked_objects": summary.ranked_objects,
        "parameters": [_parameter_json(p) for p in summary.parameters],
        "objects": [_group_json("name", g) for g in summary.objects],
        "types": [_group_json("type", g) for g in summary.types],
        "left_out": {
            "objects": [asdict(e) for e in summary.left_out_objects],
            "types": [asdict(e) for e in summary.left_out_types],
        },
        "zero_valued": [asdict(z) for z in summary.zero_valued],
        "no_gradient": [
            {"key": p.key, "type": p.type, "owners": p.owners, "plugin": p.plugin, "note": p.note}
            for p in summary.no_gradient
        ],
    }


def _parameter_json(entry: RankedParameter) -> object:
    p = entry.record
    return {
        "key": p.key, "type": p.type, "owners": p.owners, "plugin": p.plugin,
        "shape": p.shape, "score": entry.score, "signed": entry.signed,
        "verified": p.verified, "trust": p.trust, "note": p.note, "estimator": p.estimator,
        **{c: getattr(entry.row, c) for c in _ROW_ERRORS},
        "seeds": None if entry.repaired is None else entry.repaired.seeds,
        "zero_value": entry.zero_value, "raw_signed": entry.raw_signed,
    }  # fmt: skip


def _group_json(field: str, group: RankedGroup) -> object:
    return {field: group.name, "score": group.score, "signed": group.signed,
            **{c: getattr(group.row, c) for c in _ROW_ERRORS},
            "verified": group.trust == "verified", "trust": group.trust,
            "zero_value": group.zero_value}  # fmt: skip


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _fmt(score: float, signed: bool) -> str:
    return f"{score:+.2e}" if signed else f"{score:.2e}"


def trust_mark(trust: str, zero_value: bool = False) -> str:
    """The marks of a ranked row: its label's ("" for verified), and θ0 for a zero value."""
    return _MARKS.get(trust, "") + (ZERO_VALUE_MARK if zero_value else "")


def _owners(owners: Sequence[str]) -> str:
    if len(owners) <= _OWNERS_SHOWN:
        return ", ".join(owners) or "-"
    return ", ".join(owners[:_OWNERS_SHOWN]) + f" +{len(owners) - _OWNERS_SHOWN} more"


def _objective_lines(
    summary: ObjectiveSummary, method: Aggregate, ranked: int, limit: int | None
) -> list[str]:
    signed = method == "sum"
    params, objects, types = summary.parameters, summary.objects, summary.types
    errors = summary.resolution is not None or any(p.row.signed_se is not None for p in params)
    value = value_text(summary.objective.value, summary.objective_se)
    lines = [f"objective {summary.objective.name!r}   M = {value}"]
    lines.append(f"  parameters (top {len(params)} of {ranked})")
    other = other_score(method)
    headers = ["#", "", "score", *(["±"] * errors), *([] if signed else ["signed"]), "sign",
               f"#{other}", "type", "estimator", "key", "owners"]  # fmt: skip
    rows = [
        [str(p.row.rank), trust_mark(p.record.trust, p.zero_value), _fmt(p.score, signed),
         *([se_text(p.row.score_se)] * errors), *([] if signed else [_fmt(p.signed, True)]),
         sign_text(p.row), _other_rank_text(p.row), p.record.type, p.record.estimator,
         p.record.key, _owners(p.record.owners)]
        for p in params
    ]  # fmt: skip
    numeric = {i for i, h in enumerate(headers) if h in ("#", "score", "±", "signed", f"#{other}")}
    lines.extend(_indented(headers, rows, numeric=numeric))
    trusted = " (trusted parameters only)" if summary.untrusted == "apart" else ""
    lines.append(f"  objects{trusted} (top {len(objects)} of {summary.ranked_objects})")
    lines.extend(_group_table("object", objects, method, errors))
    lines.append(f"  types{trusted}")
    lines.extend(_group_table("type", types, method, errors))
    if summary.left_out_objects or summary.left_out_types:
        lines.append("  left out of the objects and types above (not trusted), by object:")
        listed, held = _cut(summary.left_out_objects, limit)
        lines += [
            printable(f"      {e.name}  {_fmt(e.score, signed)}  {_fmt(e.signed, True)}  "
                      + ", ".join(f"{k} ({t})" for k, t in e.keys))
            for e in listed
        ]  # fmt: skip
        lines += _held_back(held, "object", "with untrusted gradients")
    lines.extend(_legend(summary, limit))
    shown = [p.row for p in params] + [g.row for g in (*objects, *types)]
    lines.extend(noisy_legend(shown))
    lines.extend(order_legend(shown, other))
    lines.extend(_repaired_legend(summary.parameters))
    return lines


def sign_text(row: RankRow) -> str:
    """``+``, ``-`` or ``0``, and ``?`` when the batches cannot resolve it."""
    return row.sign + UNRESOLVED_MARK * row.unresolved


def _other_rank_text(row: RankRow) -> str:
    """The row's rank by the other score, marked where the two orders disagree markedly."""
    if row.other_rank is None:
        return "-"
    return f"{row.other_rank}{ORDERS_DISAGREE_MARK if row.orders_disagree else ''}"


def noisy_legend(rows: Sequence[RankRow]) -> list[str]:
    """Every heavy-tailed row with its reason: shown unresolved whatever its interval says."""
    noisy = [row for row in rows if row.noisy]
    if not noisy:
        return []
    lines = ["  noisy (heavy-tailed batches: unresolved, drawn neutral, kept out of scales):"]
    lines += [printable(f"      {row.name}: {row.noisy}") for row in dict.fromkeys(noisy)]
    return lines


def order_legend(rows: Sequence[RankRow], other: str) -> list[str]:
    """What the ``≠`` on a row's rank by the other score means (the row itself says which)."""
    if not any(row.orders_disagree for row in rows):
        return []
    return [
        f"  #{other}: rank by the {other} score; {ORDERS_DISAGREE_MARK} = the two orders "
        f"disagree markedly ({ORDER_GAP} places or more): the score and the pictures say one "
        f'thing, the {other} score another (docs/rankings.md, "One score")'
    ]


def _repairs_lines(figures: object, limit: int | None) -> list[str]:
    """What the run repaired by finite differences, and what it left labelled and why (past
    ``limit`` parameters, how many for each reason)."""
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
    left = figures.get("not_repaired") or {}
    if limit is None or len(left) <= limit:
        for key, why in left.items():
            lines.append(printable(f"  not repaired, still labelled: {key}: {why}"))
        return lines
    for why, n in Counter(map(str, left.values())).most_common():
        counted = f"{_count(n, 'parameter')} ({ALL_HINT})"
        lines.append(printable(f"  not repaired, still labelled: {counted}: {why}"))
    return lines


def _repaired_legend(parameters: Sequence[RankedParameter]) -> list[str]:
    shown = [(p, p.repaired) for p in parameters if p.repaired is not None]
    if not shown:
        return []
    lines = [
        "  finite-difference = repaired (reverse mode is known wrong there), ± its seeds' error:"
    ]
    for p, error in shown:
        sign = "" if error.resolved else "; its seeds do not resolve the sign"
        sign += f" (noisy: {error.noisy})" if error.noisy else ""
        lines.append(
            printable(f"      {p.record.key}: {p.signed:+.2e} ± {error.signed_se:.1e} "
                      f"({error.seeds} seeds{sign})")
        )  # fmt: skip
    return lines


def _group_table(
    title: str, entries: Sequence[RankedGroup], method: Aggregate, errors: bool
) -> list[str]:
    signed = method == "sum"
    other = other_score(method)
    headers = ["#", "", "score", *(["±"] * errors), *([] if signed else ["signed"]), "sign",
               f"#{other}", title]  # fmt: skip
    rows = [
        [str(e.row.rank), trust_mark(e.trust, e.zero_value), _fmt(e.score, signed),
         *([se_text(e.row.score_se)] * errors), *([] if signed else [_fmt(e.signed, True)]),
         sign_text(e.row), _other_rank_text(e.row), e.name]
        for e in entries
    ]  # fmt: skip
    numeric = {i for i, h in enumerate(headers) if h in ("#", "score", "±", "signed", f"#{other}")}
    return _indented(headers, rows, numeric)


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


def zero_value_legend(found: Sequence[ZeroValued], limit: int | None = None) -> list[str]:
    """What ``θ0`` means and the raw gradient of every parameter it marks (the first ``limit``)."""
    if not found:
        return []
    found, held = _cut(found, limit)
    lines = [
        f"  {ZERO_VALUE_MARK} = value exactly 0: θ·∂M/∂θ is 0 whatever the gradient; "
        "its raw gradient (Σ ∂M/∂θ, per unit of θ):"
    ]
    lines += [
        printable(f"      {z.key} ({', '.join(z.owners) or '-'}): {z.raw_signed:+.3e}"
                  f"{'' if z.hidden == z.size else f' ({z.hidden} of {z.size} components 0)'}")
        for z in found
    ]  # fmt: skip
    return lines + _held_back(held, "parameter", "of value 0")


def _legend(summary: ObjectiveSummary, limit: int | None) -> list[str]:
    params = [p.record for p in summary.parameters]
    groups = summary.objects + summary.types
    marked = [p for p in params if p.trust not in ("verified", "no_gradient")]
    lines = trust_legend([p.trust for p in params] + [g.trust for g in groups], groups=False)
    lines += [printable(f"      {p.key}: {p.trust}: {p.note}") for p in marked]
    if any(trust_mark(g.trust) for g in groups):
        lines.append("    objects and types so marked include such a parameter")
    lines += zero_value_legend(summary.zero_valued, limit)
    lines += no_gradient_legend(summary.no_gradient, limit)
    return lines


def no_gradient_legend(found: Sequence[ParamRecord], limit: int | None = None) -> list[str]:
    """The parameters no gradient reaches, never ranked: each with its reason, or, past
    ``limit`` of them, how many there are per reason (the JSON lists every one)."""
    if not found:
        return []
    if limit is None or len(found) <= limit:
        return [f"  {NO_GRADIENT_MARK} = no gradient flows, not ranked:"] + [
            printable(f"      {p.key} ({', '.join(p.owners) or '-'}): {p.note}") for p in found
        ]
    lines = [
        f"  {NO_GRADIENT_MARK} = no gradient flows, not ranked: {_count(len(found), 'parameter')}"
        f" ({ALL_HINT}), because:"
    ]
    reasons = Counter(p.note or "no reason recorded" for p in found).most_common()
    lines += [printable(f"      {n}: {note}") for note, n in reasons[:_REASONS_SHOWN]]
    if len(reasons) > _REASONS_SHOWN:
        lines.append(f"      {len(reasons) - _REASONS_SHOWN} other reasons")
    return lines


def _cut(entries: Sequence[T], limit: int | None) -> tuple[Sequence[T], int]:
    """The first ``limit`` entries and how many are held back (all of them with no limit)."""
    if limit is None or len(entries) <= limit:
        return entries, 0
    return entries[:limit], len(entries) - limit


def _held_back(held: int, noun: str, what: str) -> list[str]:
    if not held:
        return []
    return [f"      ... {held} more {noun if held == 1 else noun + 's'} {what} ({ALL_HINT})"]


def _indented(headers: list[str], rows: list[list[str]], numeric: set[int]) -> list[str]:
    if not rows:
        return ["    (none)"]
    return format_table([headers, *rows], numeric=numeric, indent="    ")


def se_text(se: float | None) -> str:
    """A standard error as the tables show it ("-": none measured)."""
    return "-" if se is None else f"{se:.1e}"


def ranking_json(
    buf: SensitivityBuffer,
    found: Sequence[Ranking],
    *,
    method: Aggregate,
    weight: Weight,
    cameras: Sequence[str] | None,
) -> str:
    """What ``sensaov rank --by ... --json`` prints (docs/rankings.md); tuples become lists."""
    document = {
        "format": RANKING_FORMAT,
        "format_version": RANKING_VERSION,
        "by": found[0].by if found else None,
        "aggregation": _aggregation(method, weight),
        "columns": COLUMNS,
        "cameras": cameras,
        "provenance": buf.provenance,
        "objectives": [
            {
                "name": r.objective,
                "value": r.objective_value,
                "value_se": r.objective_se,
                "ranked": r.ranked,
                "total_signed": r.total_signed,
                "batches": None if r.resolution is None else r.resolution.batches,
                "stability": r.stability,
                "stability_top": r.stability_top,
                "untrusted": r.untrusted,
                "resolution": None if r.resolution is None else asdict(r.resolution),
                "rows": [{c: getattr(row, c) for c in COLUMNS} for row in r.rows],
                "left_out": [{c: getattr(row, c) for c in COLUMNS} for row in r.left_out],
                "zero_valued": [asdict(z) for z in r.zero_valued],
                "no_gradient": [
                    {"key": p.key, "type": p.type, "owners": p.owners, "note": p.note}
                    for p in r.no_gradient
                ],
            }
            for r in found
        ],
    }
    return json.dumps(document, indent=2)


def ranking_csv(found: Sequence[Ranking]) -> str:
    """One line per row, the objective first; ``not_seen_by`` cameras joined by ``;``, none ""."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(("objective", *COLUMNS))
    for r in found:
        for row in (*r.rows, *r.left_out):
            writer.writerow((r.objective, *(_csv_cell(row, c) for c in COLUMNS)))
    return out.getvalue()


def _csv_cell(row: RankRow, column: str) -> object:
    value = getattr(row, column)
    if column == "not_seen_by":
        return "" if value is None else ";".join(value)
    if column in (
        "value",
        "score_se",
        "signed_se",
        "dof",
        "resolved",
        "noisy",
        "other_score",
        "other_rank",
        "raw_signed",
    ):
        return "" if value is None else repr(value)
    return value


def ranking_text(
    found: Sequence[Ranking], *, method: Aggregate, weight: Weight, limit: int | None = None
) -> str:
    """The tables of ``rank --by``; past ``limit`` rows, what is not ranked (left out, no
    gradient, zero values) is summarised in a line per kind (the JSON and CSV keep it all)."""
    lines = [
        f"score: {method} of {CONTRIBUTION[weight]} over each row's components",
        "signed: their sum (> 0: increasing it raises M); share: " + SHARE_OF[method],
    ]
    for r in found:
        value = value_text(r.objective_value, r.objective_se)
        lines += ["", f"objective {r.objective!r}   M = {value}"]
        trusted = " (trusted parameters only)" if r.untrusted == "apart" and r.by != "key" else ""
        lines.append(f"  by {r.by}{trusted} (top {len(r.rows)} of {r.ranked})")
        lines += _ranking_table(r, r.rows)
        if r.left_out:
            lines.append(
                f"  left out of the rows above: parameters sensaov does not stand behind, by {r.by}"
            )
            shown, held = _cut(r.left_out, limit)
            lines += _ranking_table(r, shown)
            lines += _held_back(held, "row", "left out")
        lines += _ranking_legend(r, limit)
    return "\n".join(lines) + "\n"


def _ranking_table(r: Ranking, shown: Sequence[RankRow]) -> list[str]:
    cameras = any(row.not_seen_by is not None for row in shown)
    values = r.by == "key"  # only a parameter has a value; groups leave the column out
    errors = r.resolution is not None or any(row.signed_se is not None for row in r.rows)
    se = ["±"] * errors
    other = f"#{other_score(r.method)}"
    headers = ["#", "", "score", *se, "signed", *se, "sign", other, "share",
               *(["value"] * values)]  # fmt: skip
    headers += ["estimator", r.by, *(["not seen by"] * cameras)]
    rows = []
    for row in shown:
        cells = [str(row.rank), trust_mark(row.trust, row.zero_value), f"{row.score:.2e}"]
        cells += [*[se_text(row.score_se)] * errors, f"{row.signed:+.2e}"]
        cells += [*[se_text(row.signed_se)] * errors, sign_text(row), _other_rank_text(row)]
        value = "-" if row.value is None else f"{row.value:.4g}"
        cells += [f"{100 * row.share:.1f}%", *[value] * values, row.estimator]
        rows.append([*cells, row.name, *[", ".join(row.not_seen_by or ()) or "-"] * cameras])
    numeric = {
        i for i, h in enumerate(headers) if h in ("#", "score", "±", "signed", "share", other)
    }
    numeric |= {headers.index("value")} if values else set()
    return _indented(headers, rows, numeric)


def _ranking_legend(r: Ranking, limit: int | None) -> list[str]:
    shown = (*r.rows, *r.left_out)
    lines = trust_legend([row.trust for row in shown], groups=r.by != "key")
    if r.resolution is not None:
        lines += ["  " + line for line in resolution_lines(r.resolution.batches, r.resolution)]
        if r.stability is not None:
            lines.append(
                f"  the top {r.stability_top} keep their order in {100 * r.stability:.0f}% "
                "of bootstrap resamples of the batches"
            )
    elif any(row.signed_se is not None for row in shown):
        lines.append(
            "  ±: a repaired (finite-difference) parameter's standard error over its seeds; "
            f"{UNRESOLVED_MARK} = sign within Student's t (95 %) of it; others: no error "
            "(one batch: -)"
        )
    else:
        lines += ["  " + line for line in resolution_lines(None, None)]
    lines += noisy_legend(shown)
    lines += order_legend(shown, other_score(r.method))
    if any(row.not_seen_by for row in shown):
        lines.append("  not seen by: the cameras (--exr) whose frame shows none of its objects")
    lines += zero_value_legend(r.zero_valued, limit)
    lines += no_gradient_legend(r.no_gradient, limit)
    return lines


# ``params``: the selected parameters, what was left out, and why; text and ``--json`` come from
# one ParameterInventory, so they agree. (``check``'s tables are the render stage's results:
# pipeline/check.py prints them with format_table, since this stage never imports the renderer.)
_PARAMS_NOTES = {
    "unverified": "UNVERIFIED", "biased": "BIASED", "suspect": "SUSPECT",
    "no_gradient": "NO GRADIENT",
}  # fmt: skip
# The keys of a selected parameter in params --json, in their order.
_SELECTED_KEYS = ("key", "type", "owners", "plugin", "shape", "is_texture", "flags", "verified",
                  "trust", "note", "texture_file", "converted", "estimator", "repair")  # fmt: skip


@dataclass(frozen=True)
class ParameterInventory:
    variant: str
    objects: tuple[str, ...]
    selected: tuple[ParamRecord, ...]
    excluded: tuple[ExcludedParam, ...]
    split: dict[str, tuple[str, ...]]
    textures: dict[str, TextureSource]
    # what sensaov changed in the scene: what, why, where, and whether it alters the image
    changes: tuple[tuple[str, str, str, bool], ...]
    # key -> why run repairs it by finite differences (budget permitting): render/verify/repair.py
    repairs: dict[str, str] = field(default_factory=dict)


def params_dict(loaded: ParameterInventory) -> dict[str, Any]:
    """What ``sensaov params --json`` prints (docs/job-spec.md)."""
    selected = []
    for record in loaded.selected:
        texture = loaded.textures.get(record.key)
        entry = asdict(record) | {
            "verified": record.verified,
            "texture_file": texture.file if texture else None,
            "converted": texture.converted if texture else False,
            "repair": loaded.repairs.get(record.key),
        }
        selected.append({key: entry[key] for key in _SELECTED_KEYS})
    return {
        "variant": loaded.variant,
        "objects": list(loaded.objects),
        "selected": selected,
        "excluded": [asdict(item) for item in loaded.excluded],
        "split_bsdfs": {name: list(shapes) for name, shapes in loaded.split.items()},
        "scene_changes": [
            {"what": what, "why": why, "where": where, "alters_image": alters}
            for what, why, where, alters in loaded.changes
        ],
    }


def params_text(loaded: ParameterInventory, *, show_all: bool = False) -> str:
    rows = [("key", "type", "owners", "plugin", "shape", "notes")]
    for info in loaded.selected:
        notes = list(info.flags)
        if info.is_texture:
            converted = loaded.textures[info.key].converted
            notes.append("texture, 8-bit -> float" if converted else "texture")
        if not info.verified:
            notes.append(_PARAMS_NOTES[info.trust])
        if info.key in loaded.repairs:
            notes.append("REPAIRED" if not info.is_texture else "NOT REPAIRED (texture)")
        shape = "x".join(str(n) for n in info.shape)
        rows.append(
            (info.key, info.type, ",".join(info.owners), info.plugin, shape, ", ".join(notes))
        )
    lines = [f"{len(loaded.selected)} parameters selected over {len(loaded.objects)} objects"]
    lines += format_table(rows)
    lines += _unverified_legend(loaded)
    if loaded.repairs:
        lines += [
            "",
            "REPAIRED: known wrong in reverse mode; run computes them again by central differences "
            "(repair.budget permitting; textures never: two renders per texel) - "
            'docs/verification.md, "Repairs"',
        ]
    if loaded.textures:
        lines += ["", "textures in the buffer:"]
        for key, source in loaded.textures.items():
            how = "converted from 8-bit to float so its texels get gradients"
            lines.append(f"  {key}: {source.file} ({how if source.converted else 'float'})")
    if loaded.split:
        lines += ["", "shared BSDFs split into one copy per object (parameters.shared: split):"]
        lines += [f"  {name} -> {', '.join(shapes)}" for name, shapes in loaded.split.items()]
    lines += _changes(loaded)
    lines += _excluded(loaded, show_all)
    return "\n".join(lines)


def _unverified_legend(loaded: ParameterInventory) -> list[str]:
    notes = sorted(
        {(_PARAMS_NOTES[i.trust], i.note) for i in loaded.selected if i.trust != "verified"}
    )
    if not notes:
        return []
    head = "gradients sensaov does not stand behind (left out of object and type views):"
    return ["", head] + [f"  - {label}: {note}" for label, note in notes]


def _changes(loaded: ParameterInventory) -> list[str]:
    if not loaded.changes:
        return []
    lines = ["", "what sensaov changed in the scene before loading it (your files are untouched):"]
    for what, why, where, alters in loaded.changes:
        mark = "!" if alters else "-"  # M is measured on another image than the scene's
        lines.append(f"  {mark} {what}{f' ({where})' if where else ''}: {why}")
    if any(alters for *_, alters in loaded.changes):
        lines.append("  (!: the image differentiated is not the one the scene renders)")
    return lines


def _excluded(loaded: ParameterInventory, show_all: bool) -> list[str]:
    by_reason: dict[str, list[str]] = defaultdict(list)
    for item in loaded.excluded:
        by_reason[item.reason].append(item.key)
    lines = ["", f"{len(loaded.excluded)} parameters left out:"]
    for reason, keys in sorted(by_reason.items(), key=lambda kv: -len(kv[1])):
        if show_all or len(keys) <= 3:
            lines.append(f"  {reason}: {', '.join(keys)}")
        else:
            lines.append(f"  {reason}: {len(keys)} keys (e.g. {keys[0]}; --all lists them)")
    return lines
