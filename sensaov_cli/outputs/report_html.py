"""The one-page HTML report of a job: every image embedded, no network, no server.

The page is one file a browser opens straight from disk: images are PNG ``data:`` URIs, the
style sheet is inline, and there is no script and no external link. It reads top-down as an
artist would ask: a summary first (the question, each objective, its top objects with ± and
trust, what was left out and why, next to its sunburst at 1:1), then one section per camera with
its headline previews (each with its legend and scale) and the other passes folded away, then an
appendix (rankings in full, the trust of every parameter, provenance). Every section records the
buffer id and job version it was made from. Assembled from plain data (:class:`ReportContent`);
:mod:`sensaov_cli.pipeline.report` gathers and checks that data.
"""

from __future__ import annotations

import base64
import html
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.outputs.atomic import atomic_write
from sensaov_cli.outputs.png import encode_png
from sensaov_cli.outputs.report_tables import (
    left_out_list,
    provenance_table,
    ranking_table,
    rankings_html,
    stamp_line,
    trust_table,
)
from sensaov_cli.views.hierarchy import Ranking

REPORT_FORMAT = "sensaov-report"
REPORT_VERSION = 2  # 2: summary first, per-camera sections, appendix; buffer id per section
_STYLE = """
body{font:15px/1.45 system-ui,sans-serif;max-width:1280px;margin:1.5em auto;padding:0 1em;
color:#222}h1{font-size:1.6em;margin:.2em 0}h2{margin-top:1.6em;border-bottom:1px solid #ccc}
h3{margin:.8em 0 .3em}img{border:1px solid #ddd;image-rendering:pixelated}
figure{display:inline-table;margin:.3em .4em;vertical-align:top}
figcaption{display:table-caption;caption-side:bottom;font-size:13px;color:#444}
table{border-collapse:collapse;margin:.3em 0 .8em}
td,th{padding:2px 8px;border-bottom:1px solid #eee;text-align:left}
td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.row{display:flex;flex-wrap:wrap;gap:1.2em;align-items:flex-start}.col{flex:0 1 440px}
.cuts{display:flex;flex-wrap:wrap;gap:2em}.stamp{font-size:13px;color:#555}.note{color:#555}
pre{background:#f6f6f6;padding:1em;overflow:auto;font-size:12px}summary{cursor:pointer}
"""


@dataclass(frozen=True)
class Picture:
    """One embedded image: the PNG's bytes and what it shows."""

    caption: str
    png: bytes
    kind: str = ""  # "primal", "sunburst", "layer", "sheet", "fig4"
    objective: str = ""


@dataclass(frozen=True)
class ObjectiveSection:
    """One objective in the summary: what it measures, its top objects, its sunburst."""

    name: str
    definition: str
    top: Ranking  # by object, trusted parameters only (left_out holds the rest)
    sunburst: Picture
    left_out: Mapping[str, tuple[ParamRecord, ...]]  # object -> its untrusted parameters


@dataclass(frozen=True)
class CameraSection:
    """One camera: its headline previews, the others folded away, what it sees."""

    name: str
    visible: frozenset[str] | None  # None: no EXR from project
    headline: tuple[Picture, ...]
    more: tuple[Picture, ...]
    files: tuple[str, ...]  # the previews shown, relative to the previews folder
    note: str


@dataclass(frozen=True)
class ReportContent:
    """Everything a report shows, as plain data."""

    title: str
    question: str
    stamp: Mapping[str, str]  # buffer id, job version, when, samples
    primal: Picture | None
    objectives: tuple[ObjectiveSection, ...]
    cameras: tuple[CameraSection, ...]
    rankings: Mapping[str, tuple[Ranking, ...]]  # cut -> one full ranking per objective
    params: tuple[ParamRecord, ...]
    provenance: dict[str, Any]
    absent: tuple[str, ...]  # the views this job does not ask for, said plainly
    ignored: tuple[str, ...] = ()  # previews no manifest lists: not shown


def png_bytes(rgb_uint8: np.ndarray) -> bytes:
    """An (H, W, 3) uint8 image as the bytes of a PNG file."""
    return encode_png(rgb_uint8)


def write_report(path: Path, content: ReportContent) -> None:
    """Write the page to ``path`` atomically (UTF-8)."""
    page = report_html(content)

    def write(tmp: Path) -> None:
        tmp.write_text(page, encoding="utf-8")

    atomic_write(path, write)


def report_html(content: ReportContent) -> str:
    """The whole page as one string."""
    title = html.escape(content.title)
    stamp = {k: content.stamp[k] for k in ("buffer id", "job hash") if k in content.stamp}
    attrs = " ".join(f'data-{k.replace(" ", "-")}="{html.escape(v)}"' for k, v in stamp.items())
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
    parts = [
        '<section id="summary">',
        f"<p><b>{html.escape(content.question)}</b></p>",
        stamp_line(content.stamp),
        f'<div class="row">{primal}<div>{_objective_list(content.objectives)}</div></div>',
    ]
    for objective in content.objectives:
        parts += [
            f"<h2>Objective {html.escape(objective.name)}</h2>",
            f'<div class="row"><div class="col">{_top(objective)}</div>'
            f"{_figure(objective.sunburst)}</div>",
        ]
    parts.append("</section>")
    return "\n".join(parts)


def _objective_list(objectives: Sequence[ObjectiveSection]) -> str:
    items = "".join(
        f"<li><b>{html.escape(o.name)}</b>: {html.escape(o.definition)}; "
        f"M = {o.top.objective_value:.4g}</li>"
        for o in objectives
    )
    return f"<p>Objectives (one reverse-mode pass each):</p><ul>{items}</ul>"


def _top(objective: ObjectiveSection) -> str:
    ranking = objective.top
    apart = ranking.untrusted == "apart"
    head = (
        f"<h3>Top objects{' (gradients sensaov stands behind)' if apart else ''}</h3>"
        f"{ranking_table(ranking, ranking.rows)}"
    )
    return head + left_out_list(ranking, objective.left_out)


def _camera(section: CameraSection, stamp: Mapping[str, str]) -> str:
    name = html.escape(section.name)
    sees = (
        "no EXR: run 'sensaov project JOB'"
        if section.visible is None
        else "sees " + (", ".join(sorted(section.visible)) or "nothing")
    )
    parts = [
        f'<section id="camera-{name}" data-buffer-id="{html.escape(stamp.get("buffer id", ""))}">',
        f"<h2>Camera {name}</h2>",
        f'<p class="note">{html.escape(sees)}</p>',
        stamp_line(stamp),
    ]
    if section.note:
        parts.append(f'<p class="note">{html.escape(section.note)}</p>')
    parts.append('<div class="row">' + "".join(_figure(p) for p in section.headline) + "</div>")
    if section.more:
        parts.append(
            f"<details><summary>every pass of this camera ({len(section.more)} images)"
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
    return "\n".join(
        [
            '<section id="appendix">',
            "<h2>Appendix</h2>",
            stamp_line(content.stamp),
            *notes,
            "<h3>Rankings in full</h3>",
            rankings_html(content.rankings),
            "<h3>Trust of the buffer's parameters</h3>",
            trust_table(content.params),
            "<h3>Provenance</h3>",
            provenance_table(content.provenance),
            "</section>",
        ]
    )


def _figure(picture: Picture) -> str:
    """A figure shown at 1:1 (width and height from the PNG), so its text keeps its size."""
    data = base64.b64encode(picture.png).decode("ascii")
    caption = html.escape(picture.caption)
    size = _png_size(picture.png)
    dims = f' width="{size[0]}" height="{size[1]}"' if size else ""
    return (
        f'<figure class="{html.escape(picture.kind)}"><img src="data:image/png;base64,{data}"'
        f'{dims} alt="{caption}"><figcaption>{caption}</figcaption></figure>'
    )


def _png_size(data: bytes) -> tuple[int, int] | None:
    if len(data) < 24 or not data.startswith(b"\x89PNG"):
        return None
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)
