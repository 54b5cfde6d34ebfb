"""The one-page HTML report of a job: every image embedded, no network, no server.

Images are PNG ``data:`` URIs, the style sheet is inline; no script, no external link. It reads
as an artist would ask: a summary (each objective: where its sensitivity lands, the objective
camera's headline view, beside its sunburst; its top objects with ± and trust, what was left out
and why), one section per camera (headline previews, the texel, forward and transport views,
the other passes folded away), then an appendix (rankings in full, trust, provenance). Every
section records the buffer id and job version it was made from.
:mod:`sensaov_cli.pipeline.report` gathers the data.

The previews are read back here (:func:`read_previews`): anything may have happened to them since
``project --png``. Special files (a FIFO would block forever) are refused; a file that is not a
whole PNG is left out, and the page says which and why.
"""

from __future__ import annotations

import base64
import html
import json
import os
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.limits import read_regular, regular_file
from sensaov_cli.outputs import tables
from sensaov_cli.outputs.atomic import atomic_write_bytes
from sensaov_cli.outputs.previews import png_problem
from sensaov_cli.views.hierarchy import Ranking, RankRow

REPORT_FORMAT = "sensaov-report"
REPORT_VERSION = 3  # 3: the headline view beside each sunburst; Fig. 4 and 5 views unfolded
# The provenance fields shown as a table; the whole record follows as JSON.
SHOWN_PROVENANCE = ("tool_version", "mitsuba_version", "drjit_version", "variant", "spp",
                    "max_depth", "primal_seed", "gradient_seeds", "resolution", "created_utc",
                    "wall_time_s", "timings_s", "buffer_id", "run_version")  # fmt: skip
_RESOLVED = {None: "no error", True: "resolved", False: "unresolved"}  # a row's resolution
ORDERS_DISAGREE = tables.ORDERS_DISAGREE_MARK  # on a row whose two ranks differ markedly
MAX_PREVIEW_BYTES = 64 << 20  # a preview is a few hundred kB; a page embeds every one
_STYLE = """
body{font:15px/1.45 system-ui,sans-serif;max-width:1280px;margin:1.5em auto;padding:0 1em;
color:#222}h1{font-size:1.6em;margin:.2em 0}h2{margin-top:1.6em;border-bottom:1px solid #ccc}
h3{margin:.8em 0 .3em}img{border:1px solid #ddd;image-rendering:pixelated}
figure{display:inline-table;margin:.3em .4em;vertical-align:top}
figcaption{display:table-caption;caption-side:bottom;font-size:13px;color:#444}
table{border-collapse:collapse;margin:.3em 0 .8em}
td,th{padding:2px 8px;border-bottom:1px solid #eee;text-align:left}
td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.row{display:flex;flex-wrap:wrap;gap:1.2em;align-items:flex-start}
.col{flex:0 1 520px;min-width:0;overflow-x:auto}
.pair{display:flex;flex-wrap:wrap;align-items:flex-start}
.cuts{display:flex;flex-wrap:wrap;gap:2em}.stamp{font-size:13px;color:#555}.note{color:#555}
pre{background:#f6f6f6;padding:1em;overflow:auto;font-size:12px}summary{cursor:pointer}
"""


@dataclass(frozen=True)
class Stamp:
    """Which buffer and job version a page was made from: every section repeats it."""

    buffer_id: str
    job_version: str  # the run version the buffer records (shortened), or "unrecorded"
    job_hash: str  # of the job file as it is now (shortened)
    made: str  # when the buffer was made (UTC)
    samples: str  # "64 spp, 4 batch(es)"


@dataclass(frozen=True)
class Picture:
    caption: str
    png: bytes
    kind: str = ""  # "primal", "sunburst", "view", "layer", "sheet", "fig4"
    objective: str = ""
    part: str = ""  # "trusted", "untrusted", "all" for a layer's preview


@dataclass(frozen=True)
class ObjectiveSection:
    name: str
    definition: str
    top: Ranking  # by object, trusted parameters only (left_out holds the rest)
    sunburst: Picture
    left_out: Mapping[str, tuple[ParamRecord, ...]]  # object -> its untrusted parameters
    view: Picture | None = None  # the headline object view at the objective camera
    view_note: str = ""  # why there is none


@dataclass(frozen=True)
class CameraSection:
    name: str
    visible: frozenset[str] | None  # None: no EXR from project
    headline: tuple[Picture, ...]
    more: tuple[Picture, ...]  # folded away
    files: tuple[str, ...]  # the previews shown, relative to the previews folder
    note: str
    figures: tuple[Picture, ...] = ()  # texel (Fig. 4) and forward/transport (Fig. 5) views


@dataclass(frozen=True)
class ReportContent:
    title: str
    question: str
    stamp: Stamp
    primal: Picture | None
    objectives: tuple[ObjectiveSection, ...]
    cameras: tuple[CameraSection, ...]
    rankings: Mapping[str, tuple[Ranking, ...]]  # cut -> one full ranking per objective
    buffer: SensitivityBuffer  # the appendix: its parameters' trust, its provenance
    absent: tuple[str, ...]  # the views this job does not ask for, said plainly
    ignored: tuple[str, ...] = ()  # previews no manifest lists: not shown


def write_report(path: Path, content: ReportContent) -> None:
    atomic_write_bytes(path, report_html(content).encode("utf-8"))


def report_html(content: ReportContent) -> str:
    title = html.escape(content.title)
    stamp = content.stamp
    attrs = (
        f'data-buffer-id="{html.escape(stamp.buffer_id)}" '
        f'data-job-hash="{html.escape(stamp.job_hash)}"'
    )
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f'<meta name="generator" content="{REPORT_FORMAT} {REPORT_VERSION}">',
        f"<title>{title}</title><style>{_STYLE}</style></head><body {attrs}>",
        f"<h1>{title}</h1>",
        _summary(content),
        *(_camera(section, content.stamp) for section in content.cameras),
        _appendix(content),
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


def _summary(content: ReportContent) -> str:
    primal = _figure(content.primal) if content.primal else '<p class="note">no primal.exr</p>'
    items = "".join(
        f"<li><b>{html.escape(o.name)}</b>: {html.escape(o.definition)}; "
        f"M = {html.escape(tables.value_text(o.top.objective_value, o.top.objective_se))}</li>"
        for o in content.objectives
    )
    parts = [
        '<section id="summary">',
        f"<p><b>{html.escape(content.question)}</b></p>",
        _stamp_line(content.stamp),
        f"<p>Objectives (one reverse-mode pass each):</p><ul>{items}</ul>",
    ]
    for objective in content.objectives:
        top = objective.top
        apart = " (gradients sensaov stands behind)" if top.untrusted == "apart" else ""
        view = (
            _figure(objective.view)
            if objective.view is not None
            else f'<p class="note">{html.escape(objective.view_note)}</p>'
        )
        # Where sensitivity lands (the picture, the primal beside it for reference) next to how
        # it splits (the sunburst), first.
        parts += [
            f"<h2>Objective {html.escape(objective.name)}</h2>",
            f'<div class="row"><div class="col"><div class="pair">{view}{primal}</div>'
            f"<h3>Top objects{apart}</h3>"
            f"{_ranking_table(top, top.rows)}{_left_out_list(top, objective.left_out)}</div>"
            f"{_figure(objective.sunburst)}</div>",
        ]
    parts.append("</section>")
    return "\n".join(parts)


def _camera(section: CameraSection, stamp: Stamp) -> str:
    name = html.escape(section.name)
    sees = (
        "no EXR: run 'sensaov project JOB'"
        if section.visible is None
        else "sees " + (", ".join(sorted(section.visible)) or "nothing")
    )
    parts = [
        f'<section id="camera-{name}" data-buffer-id="{html.escape(stamp.buffer_id)}">',
        f"<h2>Camera {name}</h2>",
        f'<p class="note">{html.escape(sees)}</p>',
        _stamp_line(stamp),
    ]
    if section.note:
        parts.append(f'<p class="note">{html.escape(section.note)}</p>')
    parts.append('<div class="row">' + "".join(_figure(p) for p in section.headline) + "</div>")
    if section.figures:  # the paper's Fig. 4 and 5: shown, not folded away
        parts.append(
            '<h3>Texel, forward and transport views</h3><div class="row">'
            + "".join(_figure(p) for p in section.figures)
            + "</div>"
        )
    if section.more:
        parts.append(
            f"<details><summary>every other pass of this camera ({len(section.more)} images)"
            f"</summary>{''.join(_figure(p) for p in section.more)}</details>"
        )
    parts.append("</section>")
    return "\n".join(parts)


def _appendix(content: ReportContent) -> str:
    notes = [f'<p class="note">{html.escape(line)}</p>' for line in content.absent]
    if content.ignored:
        notes.append(
            f'<p class="note">not shown: {len(content.ignored)} PNG file(s) under previews/ that '
            "no camera's manifest lists (left from an earlier state of the job): "
            f"{html.escape(', '.join(content.ignored[:8]))}</p>"
        )
    trust = [
        [p.key, p.type, p.plugin, ", ".join(p.owners) or "-", p.trust, p.note]
        for p in content.buffer.params
    ]
    return "\n".join(
        [
            '<section id="appendix">',
            "<h2>Appendix</h2>",
            _stamp_line(content.stamp),
            *notes,
            "<h3>Rankings in full</h3>",
            _rankings_html(content.rankings),
            "<h3>Trust of the buffer's parameters</h3>",
            _table(["key", "type", "plugin", "owners", "trust", "note"], trust, set()),
            "<h3>Provenance</h3>",
            _provenance_table(content.buffer.provenance),
            "</section>",
        ]
    )


def _figure(picture: Picture) -> str:
    """A figure shown at 1:1 (width and height from the PNG), so its text keeps its size."""
    data = base64.b64encode(picture.png).decode("ascii")
    caption = html.escape(picture.caption)
    width, height = struct.unpack(">II", picture.png[16:24])  # IHDR, first in every PNG
    return (
        f'<figure class="{html.escape(picture.kind)}"><img src="data:image/png;base64,{data}"'
        f' width="{width}" height="{height}" alt="{caption}"><figcaption>{caption}</figcaption>'
        "</figure>"
    )


def _stamp_line(stamp: Stamp) -> str:
    text = (
        f"buffer id {stamp.buffer_id} · job version (run) {stamp.job_version} · "
        f"job hash {stamp.job_hash} · made {stamp.made} · samples {stamp.samples}"
    )
    return f'<p class="stamp">made from {html.escape(text)}</p>'


def _table(headers: Sequence[str], rows: Sequence[Sequence[str]], numeric: set[int]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    cell = [('<td class="n">' if i in numeric else "<td>") + "{}</td>" for i in range(len(headers))]
    body = "".join(
        "<tr>" + "".join(cell[i].format(html.escape(c)) for i, c in enumerate(row)) + "</tr>"
        for row in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def _ranking_table(r: Ranking, rows: Sequence[RankRow], *, notes: bool = True) -> str:
    """Rows of one ranking (columns as docs/rankings.md)."""
    if not rows:
        return '<p class="note">(none)</p>'
    cameras = any(row.not_seen_by is not None for row in rows)
    other = tables.other_score(r.method)
    trust = any(row.trust != "verified" for row in rows)  # every row verified: said once, below
    # one batch and no repair's error: no ± at all, said once below the table
    errors = r.resolution is not None or any(row.signed_se is not None for row in rows)
    headers = ["#", "", r.by, "score", "signed", *(["±", "sign"] * errors), f"#{other}", "share",
               *(["trust"] * trust), *(["not seen by"] * cameras)]  # fmt: skip
    body = [
        [str(row.rank), tables.trust_mark(row.trust, row.zero_value), row.name,
         f"{row.score:.2e}", f"{row.signed:+.2e}",
         *([tables.se_text(row.signed_se), _resolution_cell(row)] * errors),
         _order_cell(row), f"{100 * row.share:.1f}%",
         *([row.trust] * trust), *([", ".join(row.not_seen_by or ()) or "-"] * cameras)]
        for row in rows
    ]  # fmt: skip
    numeric = {i for i, h in enumerate(headers) if h in ("#", "score", "signed", "±", "share")}
    if not notes:
        return _table(headers, body, numeric)
    verified = "" if trust else '<p class="note">trust: every row verified gradients only.</p>'
    return _table(headers, body, numeric) + verified + _row_notes(rows, other) + _significance(r)


def _resolution_cell(row: RankRow) -> str:
    """The row's sign and whether its batches resolve it, beside its trust (never instead)."""
    return f"{tables.sign_text(row)} {'noisy' if row.noisy else _RESOLVED[row.resolved]}"


def _order_cell(row: RankRow) -> str:
    """Its rank by the other score; where the two orders disagree markedly, said on the row."""
    if row.other_rank is None:
        return "-"
    return f"{row.other_rank} {ORDERS_DISAGREE}" if row.orders_disagree else str(row.other_rank)


def _row_notes(rows: Sequence[RankRow], other: str) -> str:
    """Why a row is noisy, and what the mark of disagreeing orders means, under its table."""
    lines = [f"{html.escape(row.name)}: noisy, {html.escape(row.noisy)}" for row in rows
             if row.noisy]  # fmt: skip
    if any(row.orders_disagree for row in rows):
        lines.append(
            f"{ORDERS_DISAGREE} the rank by {other} differs markedly from the rank by this score "
            "(a texture's many small same-sign texels: large sum, small l2)"
        )
    return "".join(f'<p class="note">{line}</p>' for line in lines)


def _left_out_list(r: Ranking, keys: Mapping[str, tuple[ParamRecord, ...]]) -> str:
    """What the headline ranking left out and why: per object its untrusted parameters, and the
    parameters value weighting hides (θ = 0)."""
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
            f"<li>{html.escape(tables.LABEL_MEANINGS.get(label, label))}"
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


def _rankings_html(by_cut: Mapping[str, tuple[Ranking, ...]]) -> str:
    """Every cut of every objective, all rows, the left-out rows beneath."""
    objectives = [r.objective for r in next(iter(by_cut.values()), ())]
    parts = []
    for index, name in enumerate(objectives):
        parts.append(f"<h4>objective {html.escape(name)}</h4><div class=cuts>")
        for cut, found in by_cut.items():
            r = found[index]
            rows = _ranking_table(r, r.rows, notes=False)
            if r.left_out:
                rows += "<p class=note>left out (untrusted)</p>"
                rows += _ranking_table(r, r.left_out, notes=False)
            parts.append(f"<div><b>by {html.escape(cut)}</b>{rows}</div>")
        parts.append("</div>")
    first = next((r for found in by_cut.values() for r in found), None)
    share = tables.SHARE_OF[first.method] if first is not None else tables.SHARE_OF["sum"]
    parts.append(
        f'<p class="note">{tables.UNVERIFIED_MARK} biased or unverified gradient, '
        f"{tables.SUSPECT_MARK} suspect, θ0 value exactly 0; share: {html.escape(share)}; "
        "columns: docs/rankings.md</p>"
    )
    if first is not None:
        parts.append(_significance(first))
    return "\n".join(parts)


def _provenance_table(provenance: Mapping[str, Any]) -> str:
    rows = [
        [key, provenance[key] if isinstance(provenance[key], str) else json.dumps(provenance[key])]
        for key in SHOWN_PROVENANCE
        if key in provenance
    ]
    full = html.escape(json.dumps(provenance, indent=2, sort_keys=True))
    return (
        _table(["field", "value"], rows, set())
        + f"<details><summary>all</summary><pre>{full}</pre></details>"
    )


def _significance(r: Ranking) -> str:
    other = tables.other_score(r.method)
    score = f"score: {r.method}; #{other}: rank by {other}. "
    if r.resolution is None:
        return (
            f'<p class="note">{score}No error: one batch, so no ± and no sign known to be '
            "resolved (render.batches ≥ 2 gives them).</p>"
        )
    s = r.resolution
    return (
        f'<p class="note">{score}± from {s.batches} batches; resolved: 0 outside '
        f"±{s.factor:.2f} SE (t, {s.dof} dof, {100 * s.level:.0f} %), not noisy; unresolved rows "
        "rank last, drawn grey.</p>"
    )


def read_previews(output: Path, folder: Path) -> tuple[dict[str, bytes], dict[str, str]]:
    """The ``*.png`` files under ``folder`` by their path relative to ``output``: the whole PNGs'
    bytes, and why each other one is left out."""
    whole: dict[str, bytes] = {}
    left_out: dict[str, str] = {}
    for path in _png_files(folder):
        name = str(path.relative_to(output))
        if not path.exists():
            left_out[name] = "a link to a file that does not exist"
            continue
        size = regular_file(path, "preview")
        if size > MAX_PREVIEW_BYTES:
            left_out[name] = f"{size >> 20} MiB, too large to embed"
            continue
        data = read_regular(path, "preview", cap=MAX_PREVIEW_BYTES)
        problem = png_problem(data)
        if problem is None:
            whole[name] = data
        else:
            left_out[name] = problem
    return whole, left_out


def _png_files(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return []
    found = []
    for root, folders, files in os.walk(folder):  # links to folders are listed, not entered
        folders.sort()
        found += [Path(root) / name for name in sorted(files) if name.endswith(".png")]
    return found
