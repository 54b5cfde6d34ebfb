"""``sensaov report``: gather a job's outputs into one self-contained HTML page.

Reads what ``run`` and ``project`` wrote under the job's output folder (the buffer, the primal,
the cameras' EXRs and PNG previews) and renders nothing: a missing buffer is an error, a
missing primal or missing previews are said on the page.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import OutputError
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.frames import visible_objects
from sensaov_cli.outputs.previews import srgb_uint8
from sensaov_cli.outputs.report_html import Picture, ReportContent, png_bytes, write_report
from sensaov_cli.outputs.sunburst_drawing import sunburst_bytes
from sensaov_cli.pipeline.run import BUFFER_NAME, PRIMAL_NAME
from sensaov_cli.spec.job import JobSpec
from sensaov_cli.views.hierarchy import rankings
from sensaov_cli.views.sunburst_geometry import panels

REPORT_NAME = "report.html"
TOP = 12  # rows per ranking table: a page, not a spreadsheet


def make_report(job: JobSpec, path: Path | None = None) -> Path:
    """Write the report of ``job`` (default ``<output>/report.html``) and return its path."""
    buffer_path = job.output / BUFFER_NAME
    if not buffer_path.is_file():
        raise OutputError(
            "no buffer to report on",
            where=str(buffer_path),
            hint=f"run 'sensaov run {job.path}' first",
        )
    buf = read_buffer(buffer_path)
    cameras = [job.output / f"{c.name}.exr" for c in job.inspection_cameras]
    visible = visible_objects([p for p in cameras if p.is_file()]) or None
    content = ReportContent(
        title=f"sensaov report: {job.path.name}",
        primal=_primal(job.output / PRIMAL_NAME),
        sunbursts=tuple(_sunburst(buf, o.name) for o in buf.objectives),
        rankings={
            by: rankings(buf, by=by, top=TOP, visible=None if by == "type" else visible)
            for by in ("object", "type", "key")
        },
        previews=tuple(
            Picture(str(p.relative_to(job.output)), p.read_bytes())
            for p in sorted((job.output / "previews").rglob("*.png"))
        ),
        params=buf.params,
        provenance=buf.provenance,
        absent=_absent(job, job.output / "previews"),
    )
    target = path or job.output / REPORT_NAME
    if target.is_dir():
        raise OutputError("is a folder", where=str(target), hint="name a .html file")
    write_report(target, content)
    return target


def _absent(job: JobSpec, previews: Path) -> tuple[str, ...]:
    """The views of the paper this page does not show, and why, said plainly."""
    names = [p.name for p in previews.rglob("*.png")] if previews.is_dir() else []
    lines = []
    kinds = {
        "texel (per-texel fields through UVs)": any(c.kind == "texel" for c in job.channels),
        "forward-mode and transport": bool(job.forward)
        or any(c.kind == "transport" for c in job.channels),
    }
    for view, asked in kinds.items():
        if not asked:
            lines.append(f"{view} views: this job asks for none (docs/job-spec.md)")
    if not names:
        lines.append("no channel previews: run 'sensaov project JOB --png' first")
    return tuple(lines)


def _primal(path: Path) -> Picture | None:
    if not path.is_file():
        return None
    channels, _ = read_exr(path)
    linear = [channels[c] for c in ("R", "G", "B") if c in channels]
    if len(linear) != 3:
        return None
    rgb = srgb_uint8(np.stack(linear, axis=-1))
    return Picture(f"{path.name} (clipped to [0, 1], sRGB)", png_bytes(rgb))


def _sunburst(buf: SensitivityBuffer, objective: str) -> Picture:
    drawn = panels(buf, [objective])
    data = sunburst_bytes(drawn, fmt="png", order="object,type", encoding="l2 of θ·∂M/∂θ",
                          provenance={"objective": objective})  # fmt: skip
    return Picture(f"sunburst of {objective} (objects → types → parameters)", data)
