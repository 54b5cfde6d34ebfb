"""The one-page HTML report of a job: every image embedded, no network, no server.

The page is one file a browser opens straight from disk: images are PNG ``data:`` URIs, the
style sheet is inline, and there is no script and no external link. It is assembled from plain
data (:class:`ReportContent`); :mod:`sensaov_cli.pipeline.report` gathers that data from a
job's output.
"""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.outputs.atomic import atomic_write
from sensaov_cli.outputs.tables import SUSPECT_MARK, UNVERIFIED_MARK
from sensaov_cli.views.hierarchy import Ranking

REPORT_FORMAT = "sensaov-report"
REPORT_VERSION = 1
# The provenance fields shown as a table; the whole record follows as JSON.
SHOWN_PROVENANCE = ("tool_version", "mitsuba_version", "drjit_version", "variant", "spp",
                    "max_depth", "primal_seed", "gradient_seeds", "resolution", "created_utc",
                    "wall_time_s", "timings_s")  # fmt: skip
_MARKS = {"unverified": UNVERIFIED_MARK, "biased": UNVERIFIED_MARK, "suspect": SUSPECT_MARK}
_STYLE = """
body{font:14px/1.45 system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{margin-top:2em;border-bottom:1px solid #ccc}h3{margin-bottom:.3em}
img{max-width:100%;height:auto;image-rendering:pixelated;border:1px solid #ddd}
figure{display:inline-block;margin:.4em;vertical-align:top}figcaption{font-size:12px;color:#555}
table{border-collapse:collapse;margin:.5em 0 1em}td,th{padding:2px 8px;border-bottom:1px solid #eee}
td.n{text-align:right;font-variant-numeric:tabular-nums}.cuts{display:flex;flex-wrap:wrap;gap:2em}
.primal img{width:480px;max-width:100%}.sunburst img{width:560px;max-width:100%}
pre{background:#f6f6f6;padding:1em;overflow:auto;font-size:12px}.note{color:#555}
"""


@dataclass(frozen=True)
class Picture:
    """One embedded image: the PNG's bytes and what it shows."""

    caption: str
    png: bytes


@dataclass(frozen=True)
class ReportContent:
    """Everything a report shows, as plain data."""

    title: str
    primal: Picture | None
    sunbursts: tuple[Picture, ...]
    rankings: Mapping[str, tuple[Ranking, ...]]  # cut -> one ranking per objective
    previews: tuple[Picture, ...]
    params: tuple[ParamRecord, ...]
    provenance: dict[str, Any]
    absent: tuple[str, ...]  # the views this buffer does not have, said plainly


def png_bytes(rgb_uint8: np.ndarray) -> bytes:
    """An (H, W, 3) uint8 image as the bytes of a PNG file."""
    from matplotlib import image

    out = io.BytesIO()
    image.imsave(out, rgb_uint8, format="png")
    return out.getvalue()


def write_report(path: Path, content: ReportContent) -> None:
    """Write the page to ``path`` atomically (UTF-8)."""
    page = report_html(content)

    def write(tmp: Path) -> None:
        tmp.write_text(page, encoding="utf-8")

    atomic_write(path, write)


def report_html(content: ReportContent) -> str:
    """The whole page as one string."""
    title = html.escape(content.title)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f'<meta name="generator" content="{REPORT_FORMAT} {REPORT_VERSION}">',
        f"<title>{title}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{title}</h1>",
        "<h2>Primal</h2>",
        _picture(content.primal, "primal")
        if content.primal
        else '<p class="note">no primal.exr</p>',
        "<h2>Sunbursts</h2>",
        *(_picture(p, "sunburst") for p in content.sunbursts),
        "<h2>Rankings</h2>",
        _rankings(content.rankings),
        "<h2>Channel previews</h2>",
        *(_picture(p) for p in content.previews),
        *([] if content.previews else ['<p class="note">none: run sensaov project --png</p>']),
        *[f'<p class="note">{html.escape(line)}</p>' for line in content.absent],
        "<h2>Trust of the buffer's parameters</h2>",
        _trust_table(content.params),
        "<h2>Provenance</h2>",
        _provenance(content.provenance),
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


def _picture(picture: Picture, kind: str = "") -> str:
    """A figure; ``kind`` (a CSS class) sizes it: a 128-pixel primal must not look like a stamp."""
    data = base64.b64encode(picture.png).decode("ascii")
    caption = html.escape(picture.caption)
    return (
        f'<figure class="{kind}"><img src="data:image/png;base64,{data}" alt="{caption}">'
        f"<figcaption>{caption}</figcaption></figure>"
    )


def _table(headers: Sequence[str], rows: Sequence[Sequence[str]], numeric: set[int]) -> str:
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


def _rankings(by_cut: Mapping[str, tuple[Ranking, ...]]) -> str:
    objectives = [r.objective for r in next(iter(by_cut.values()), ())]
    parts = []
    for index, name in enumerate(objectives):
        parts.append(f"<h3>objective {html.escape(name)}</h3><div class=cuts>")
        for cut, found in by_cut.items():
            parts.append(f"<div><b>by {html.escape(cut)}</b>{_ranking_table(found[index])}</div>")
        parts.append("</div>")
    parts.append(
        f'<p class="note">{UNVERIFIED_MARK} unverified or biased gradient, {SUSPECT_MARK} '
        "suspect; share: of the total sum of squares; columns: docs/rankings.md</p>"
    )
    return "\n".join(parts)


def _ranking_table(r: Ranking) -> str:
    cameras = any(row.off_frame is not None for row in r.rows)
    headers = ["#", "", "score", "signed", "share", r.by, *(["off-frame"] * cameras)]
    rows = [
        [str(row.rank), _MARKS.get(row.trust, ""), f"{row.score:.2e}", f"{row.signed:+.2e}",
         f"{100 * row.share:.1f}%", row.name, *([", ".join(row.off_frame or ()) or "-"] * cameras)]
        for row in r.rows
    ]  # fmt: skip
    return _table(headers, rows, {0, 2, 3, 4})


def _trust_table(params: Sequence[ParamRecord]) -> str:
    rows = [
        [p.key, p.type, p.plugin, ", ".join(p.owners) or "-", p.trust, p.estimator, p.note]
        for p in params
    ]
    return _table(["key", "type", "plugin", "owners", "trust", "estimator", "note"], rows, set())


def _provenance(provenance: Mapping[str, Any]) -> str:
    rows = [
        [
            key,
            json.dumps(provenance[key])
            if not isinstance(provenance[key], str)
            else provenance[key],
        ]
        for key in SHOWN_PROVENANCE
        if key in provenance
    ]
    full = html.escape(json.dumps(provenance, indent=2, sort_keys=True))
    return (
        _table(["field", "value"], rows, set())
        + f"<details><summary>all</summary><pre>{full}</pre></details>"
    )
