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
from sensaov_cli.errors import OutputError, SensaovError
from sensaov_cli.outputs.atomic import check_writable
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.frames import visible_objects
from sensaov_cli.outputs.overwrite import recorded_inputs, refuse_unsafe_outputs
from sensaov_cli.outputs.preview_files import read_previews
from sensaov_cli.outputs.previews import srgb_uint8
from sensaov_cli.outputs.report_html import Picture, ReportContent, png_bytes, write_report
from sensaov_cli.outputs.sunburst_drawing import sunburst_bytes
from sensaov_cli.pipeline.run import BUFFER_NAME, PRIMAL_NAME
from sensaov_cli.render.scene.expand import expand_scene
from sensaov_cli.spec.job import JobSpec
from sensaov_cli.views.hierarchy import rankings
from sensaov_cli.views.sunburst_geometry import panels

REPORT_NAME = "report.html"
TOP = 12  # rows per ranking table: a page, not a spreadsheet


def make_report(job: JobSpec, path: Path | None = None) -> Path:
    """Write the report of ``job`` (default ``<output>/report.html``) and return its path."""
    buffer_path = job.output / BUFFER_NAME
    if not buffer_path.exists():
        raise OutputError(
            "no buffer to report on",
            where=str(buffer_path),
            hint=f"run 'sensaov run {job.path}' first",
        )
    buf = read_buffer(buffer_path)
    target = path or job.output / REPORT_NAME
    check_writable(target.parent, [target.name])  # not a folder, not a FIFO, writable
    cameras = [job.output / f"{c.name}.exr" for c in job.inspection_cameras]
    cameras = [p for p in cameras if p.exists()]  # one that is no regular file is refused
    previews, left_out = read_previews(job.output, job.output / "previews")
    read = [buffer_path, job.output / PRIMAL_NAME, *cameras, *_job_files(job)]
    read += [job.output / name for name in (*previews, *left_out)]
    refuse_unsafe_outputs(
        [*read, *recorded_inputs(buf.provenance)],
        [target],
        where=str(target),
        hint="name another file with -o, e.g. report.html",
    )
    visible = visible_objects(cameras) or None
    content = ReportContent(
        title=f"sensaov report: {job.path.name}",
        primal=_primal(job.output / PRIMAL_NAME),
        sunbursts=tuple(_sunburst(buf, o.name) for o in buf.objectives),
        rankings={
            by: rankings(buf, by=by, top=TOP, visible=None if by == "type" else visible)
            for by in ("object", "type", "key")
        },
        previews=tuple(Picture(name, data) for name, data in previews.items()),
        params=buf.params,
        provenance=buf.provenance,
        absent=_absent(job, job.output / "previews")
        + tuple(f"{name} is not shown: {why}" for name, why in left_out.items()),
    )
    write_report(target, content)
    return target


def _job_files(job: JobSpec) -> tuple[Path, ...]:
    """The job's files and those its scene reads now. A report renders nothing: a scene that
    no longer expands only leaves this list to the buffer's provenance (``recorded_inputs``)."""
    try:
        scene = expand_scene(job.scene, job.scene_args).files
    except SensaovError:
        scene = (job.scene,)
    return (*job.input_files(), *scene)


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
    if not path.exists():
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
