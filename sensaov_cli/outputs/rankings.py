"""``sensaov rank --by``'s outputs: the JSON document, the CSV and the text table.

All three come from the same :class:`~sensaov_cli.views.hierarchy.Ranking` rows and carry the
same columns (docs/rankings.md): the JSON is the reference, the CSV one line per row with the
objective first, and the text the same numbers aligned, with the trust marks of ``rank``'s
default summary and their legend.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from dataclasses import asdict

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.outputs.tables import (
    CONTRIBUTION,
    NO_GRADIENT_MARK,
    format_table,
    se_text,
    trust_legend,
    trust_mark,
    zero_value_legend,
)
from sensaov_cli.views.hierarchy import RANKING_FORMAT, RANKING_VERSION, Ranking, RankRow
from sensaov_cli.vocabulary import Aggregate, Weight

# The columns of a row, in JSON, CSV and text order (CSV puts "objective" first).
COLUMNS = (
    "rank", "name", "score", "signed", "share", "sign", "value", "trust", "off_frame",
    "score_se", "signed_se", "significant", "part", "zero_value", "raw_signed", "estimator",
)  # fmt: skip


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
        "aggregation": {
            "method": method,
            "weight": weight,
            "contribution": CONTRIBUTION[weight],
        },
        "columns": COLUMNS,
        "cameras": cameras,
        "provenance": buf.provenance,
        "objectives": [
            {
                "name": r.objective,
                "value": r.objective_value,
                "ranked": r.ranked,
                "total_signed": r.total_signed,
                "batches": r.batches,
                "stability": r.stability,
                "stability_top": r.stability_top,
                "untrusted": r.untrusted,
                "significance": None if r.significance is None else asdict(r.significance),
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
    """One line per row, the objective first; off-frame cameras joined by ``;``, no value ""."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(("objective", *COLUMNS))
    for r in found:
        for row in (*r.rows, *r.left_out):
            writer.writerow((r.objective, *(_csv_cell(row, c) for c in COLUMNS)))
    return out.getvalue()


def _csv_cell(row: RankRow, column: str) -> object:
    value = getattr(row, column)
    if column == "off_frame":
        return "" if value is None else ";".join(value)
    if column in ("value", "score_se", "signed_se", "significant", "raw_signed"):
        return "" if value is None else repr(value)
    return value


def ranking_text(found: Sequence[Ranking], *, method: Aggregate, weight: Weight) -> str:
    """The rankings as aligned tables, one per objective, with the marks' legend."""
    lines = [
        f"score: {method} of {CONTRIBUTION[weight]} over each row's components",
        "signed: their sum (> 0: increasing it raises M); share: of the total sum of squares",
    ]
    for r in found:
        lines += ["", f"objective {r.objective!r}   M = {r.objective_value:.4g}"]
        trusted = " (trusted parameters only)" if r.untrusted == "apart" and r.by != "key" else ""
        lines.append(f"  by {r.by}{trusted} (top {len(r.rows)} of {r.ranked})")
        lines += _table(r, r.rows)
        if r.left_out:
            lines.append(
                f"  left out of the rows above: parameters sensaov does not stand behind, by {r.by}"
            )
            lines += _table(r, r.left_out)
        lines += _legend(r)
    return "\n".join(lines) + "\n"


def _table(r: Ranking, shown: Sequence[RankRow]) -> list[str]:
    if not shown:
        return ["    (none)"]
    cameras = any(row.off_frame is not None for row in shown)
    values = r.by == "key"  # only a parameter has a value; groups leave the column out
    errors = r.batches is not None or any(row.signed_se is not None for row in r.rows)
    se = ["±"] * errors
    headers = ["#", "", "score", *se, "signed", *se, "sign", "share", *(["value"] * values)]
    headers += ["estimator", r.by, *(["off-frame"] * cameras)]
    rows = []
    for row in shown:
        cells = [str(row.rank), trust_mark(row.trust, row.zero_value), f"{row.score:.2e}"]
        cells += [*[se_text(row.score_se)] * errors, f"{row.signed:+.2e}"]
        cells += [*[se_text(row.signed_se)] * errors, row.sign + "?" * (row.significant is False)]
        cells += [f"{100 * row.share:.1f}%", *[_value(row.value)] * values, row.estimator]
        rows.append([*cells, row.name, *[", ".join(row.off_frame or ()) or "-"] * cameras])
    numeric = {i for i, h in enumerate(headers) if h in ("#", "score", "±", "signed", "share")}
    numeric |= {headers.index("value")} if values else set()
    return format_table([headers, *rows], numeric=numeric, indent="    ")


def _value(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def _legend(r: Ranking) -> list[str]:
    shown = (*r.rows, *r.left_out)
    lines = trust_legend([row.trust for row in shown], groups=r.by != "key")
    if r.batches is not None and r.significance is not None:
        sig = r.significance
        lines.append(
            f"  ±: standard error from {r.batches} batches; ? = sign not significant: |signed| "
            f"within {sig.factor:.2f} standard errors (Student's t, {sig.dof} degrees of "
            f"freedom, {100 * sig.level:.0f} % two-sided)"
        )
        if r.stability is not None:
            lines.append(
                f"  the top {r.stability_top} keep their order in {100 * r.stability:.0f}% "
                "of bootstrap resamples of the batches"
            )
    elif any(row.signed_se is not None for row in shown):
        lines.append(
            "  ±: a repaired (finite-difference) parameter's standard error over its seeds; "
            "? = sign within Student's t (95 %) of it; others: no error measured (-)"
        )
    if any(row.off_frame for row in shown):
        lines.append("  off-frame: the cameras that see none of its objects")
    lines += zero_value_legend(r.zero_valued)
    if r.no_gradient:
        lines.append(f"  {NO_GRADIENT_MARK} = no gradient flows, not ranked:")
        lines += [f"      {p.key} ({', '.join(p.owners) or '-'}): {p.note}" for p in r.no_gradient]
    return lines
