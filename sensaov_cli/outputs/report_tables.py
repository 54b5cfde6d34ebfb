"""The HTML tables of ``sensaov report``: rankings with ± and trust, what was left out and why,
the trust of every parameter, provenance, and the line that says which buffer a section shows."""

from __future__ import annotations

import html
import json
from collections.abc import Mapping, Sequence
from typing import Any

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.outputs.tables import LABEL_MEANINGS, SUSPECT_MARK, UNVERIFIED_MARK
from sensaov_cli.views.hierarchy import Ranking, RankRow

# The provenance fields shown as a table; the whole record follows as JSON.
SHOWN_PROVENANCE = ("tool_version", "mitsuba_version", "drjit_version", "variant", "spp",
                    "max_depth", "primal_seed", "gradient_seeds", "resolution", "created_utc",
                    "wall_time_s", "timings_s", "buffer_id", "run_version")  # fmt: skip
_MARKS = {"unverified": UNVERIFIED_MARK, "biased": UNVERIFIED_MARK, "suspect": SUSPECT_MARK}


def stamp_line(stamp: Mapping[str, str]) -> str:
    """Which buffer and job version a section was made from, in one small line."""
    text = " · ".join(f"{key} {value}" for key, value in stamp.items())
    return f'<p class="stamp">made from {html.escape(text)}</p>'


def table(headers: Sequence[str], rows: Sequence[Sequence[str]], numeric: set[int]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join(
        "<tr>"
        + "".join(
            f'<td class="n">{html.escape(c)}</td>' if i in numeric else f"<td>{html.escape(c)}</td>"
            for i, c in enumerate(row)
        )
        + "</tr>"
        for row in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def ranking_table(r: Ranking, rows: Sequence[RankRow], *, notes: bool = True) -> str:
    """Rows of one ranking: score, signed sum with its standard error, significance, share,
    trust and off-frame cameras (columns as docs/rankings.md)."""
    if not rows:
        return '<p class="note">(none)</p>'
    cameras = any(row.off_frame is not None for row in rows)
    errors = r.batches is not None
    trust = any(row.trust != "verified" for row in rows)  # every row verified: said once, below
    headers = ["#", "", r.by, "score", "signed", *(["±", "sign"] * errors), "share",
               *(["trust"] * trust), *(["off-frame"] * cameras)]  # fmt: skip
    body = [
        [str(row.rank), _MARKS.get(row.trust, "") + ("θ0" if row.zero_value else ""), row.name,
         f"{row.score:.2e}", f"{row.signed:+.2e}",
         *([_se(row.signed_se), _sign(row)] * errors), f"{100 * row.share:.1f}%",
         *([row.trust] * trust), *([", ".join(row.off_frame or ()) or "-"] * cameras)]
        for row in rows
    ]  # fmt: skip
    numeric = {i for i, h in enumerate(headers) if h in ("#", "score", "signed", "±", "share")}
    if not notes:
        return table(headers, body, numeric)
    verified = "" if trust else '<p class="note">every row: verified gradients only.</p>'
    return table(headers, body, numeric) + verified + _significance(r)


def left_out_list(r: Ranking, keys: Mapping[str, tuple[ParamRecord, ...]]) -> str:
    """What the headline ranking left out and why: per object, its untrusted parameters with
    their labels and notes, and the parameters value weighting hides (θ = 0)."""
    parts = []
    if r.left_out:
        items = "".join(
            f"<li><b>{html.escape(row.name)}</b> (score {row.score:.2e}, signed "
            f"{row.signed:+.2e}): "
            + ", ".join(f"{html.escape(p.key)} ({p.trust})" for p in keys.get(row.name, ()))
            + "</li>"
            for row in r.left_out
        )
        notes = sorted({(p.trust, p.note) for found in keys.values() for p in found})
        why = "".join(
            f"<li>{html.escape(LABEL_MEANINGS.get(label, label))}"
            f"{': ' + html.escape(note) if note else ''}</li>"
            for label, note in notes
        )
        parts.append(
            "<h3>Left out of the objects above</h3><p class=note>Gradients sensaov does not "
            "stand behind are not added to any object or type; they are shown apart (their "
            f"own layer <code>…_untrusted</code>, hatched):</p><ul>{items}</ul>"
            f"<p class=note>Why:</p><ul class=note>{why}</ul>"
        )
    if r.zero_valued:
        items = "".join(
            f"<li>{html.escape(z.key)} ({html.escape(', '.join(z.owners) or '-')}): raw "
            f"∂M/∂θ {z.raw_signed:+.3e}</li>"
            for z in r.zero_valued
        )
        parts.append(
            "<h3>Value 0: scored 0 whatever the gradient</h3><p class=note>θ·∂M/∂θ is 0 "
            f"where θ = 0; their raw gradient says whether they matter:</p><ul>{items}</ul>"
        )
    if r.no_gradient:
        parts.append(
            f'<p class="note">{len(r.no_gradient)} parameter(s) with no gradient flowing are '
            "never ranked (appendix: trust).</p>"
        )
    return "".join(parts)


def rankings_html(by_cut: Mapping[str, tuple[Ranking, ...]]) -> str:
    """Every cut of every objective, all rows, the left-out rows beneath."""
    objectives = [r.objective for r in next(iter(by_cut.values()), ())]
    parts = []
    for index, name in enumerate(objectives):
        parts.append(f"<h4>objective {html.escape(name)}</h4><div class=cuts>")
        for cut, found in by_cut.items():
            r = found[index]
            left = (
                f"<p class=note>left out (untrusted)</p>{ranking_table(r, r.left_out, notes=False)}"
                if r.left_out
                else ""
            )
            rows = ranking_table(r, r.rows, notes=False)
            parts.append(f"<div><b>by {html.escape(cut)}</b>{rows}{left}</div>")  # fmt: skip
        parts.append("</div>")
    parts.append(
        f'<p class="note">{UNVERIFIED_MARK} biased or unverified gradient, {SUSPECT_MARK} '
        "suspect, θ0 value exactly 0; share: of the total sum of squares; columns: "
        "docs/rankings.md</p>"
    )
    first = next((r for found in by_cut.values() for r in found), None)
    if first is not None:
        parts.append(_significance(first))
    return "\n".join(parts)


def trust_table(params: Sequence[ParamRecord]) -> str:
    rows = [[p.key, p.type, p.plugin, ", ".join(p.owners) or "-", p.trust, p.note] for p in params]
    return table(["key", "type", "plugin", "owners", "trust", "note"], rows, set())


def provenance_table(provenance: Mapping[str, Any]) -> str:
    rows = [
        [key, provenance[key] if isinstance(provenance[key], str) else json.dumps(provenance[key])]
        for key in SHOWN_PROVENANCE
        if key in provenance
    ]
    full = html.escape(json.dumps(provenance, indent=2, sort_keys=True))
    return (
        table(["field", "value"], rows, set())
        + f"<details><summary>all</summary><pre>{full}</pre></details>"
    )


def _se(se: float | None) -> str:
    return "-" if se is None else f"{se:.1e}"


def _sign(row: RankRow) -> str:
    if row.significant is None:
        return "-"
    return "significant" if row.significant else "noise"


def _significance(r: Ranking) -> str:
    if r.significance is None:
        return (
            '<p class="note">no ±: this buffer has one batch; render.batches ≥ 2 (or a merge '
            "of farm shards) gives standard errors and significance (docs/farm.md).</p>"
        )
    s = r.significance
    return (
        f'<p class="note">± standard error from {s.batches} batches; sign significant when 0 '
        f"lies outside ±{s.factor:.2f} SE (Student's t, {s.dof} dof, "
        f"{100 * s.level:.0f} %).</p>"
    )
