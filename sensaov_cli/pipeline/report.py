"""``sensaov report``: gather a job's outputs into one self-contained HTML page.

Reads what ``run`` and ``project`` wrote and renders nothing. Everything shown comes from one
state (the checks in :mod:`~sensaov_cli.pipeline.project`); previews no manifest lists (left over
from an objective or a channel since renamed) are not shown, and the page names them.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer, buffer_id, provenance_id, run_version
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import OutputError, SensaovError, StaleInputError
from sensaov_cli.job.spec import CameraSpec, JobSpec
from sensaov_cli.outputs.atomic import (
    check_writable,
    file_token,
    header_provenance,
    recorded_inputs,
    refuse_unsafe_outputs,
)
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.layered_exr import seen_names
from sensaov_cli.outputs.previews import encode_png, read_png_text, srgb_uint8
from sensaov_cli.outputs.report_html import (
    CameraSection,
    ObjectiveSection,
    Picture,
    ReportContent,
    Stamp,
    read_previews,
    write_report,
)
from sensaov_cli.outputs.sunburst_drawing import sunburst_bytes
from sensaov_cli.pipeline.project import check_buffer_of_job, check_made_from
from sensaov_cli.pipeline.run import BUFFER_NAME, PRIMAL_NAME
from sensaov_cli.scene.expand import expand_scene
from sensaov_cli.views.hierarchy import is_trusted, panels, rankings

REPORT_NAME = "report.html"
SUMMARY_TOP = 5  # objects per objective in the summary; the appendix ranks them all
SUNBURST_INCHES = 5.6  # 672 px at 1:1: beside its objective's table on a 1280 px page
PRIMAL_PIXELS = 128  # the primal beside each headline view: at most this wide and high


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
    check_buffer_of_job(job, buf, buffer_path)
    folder = job.output / "previews"
    previews, broken = read_previews(job.output, folder)  # a FIFO among them: refused here
    exrs = [job.output / f"{c.name}.exr" for c in job.inspection_cameras]
    read = [buffer_path, job.output / PRIMAL_NAME, *exrs, *_job_files(job)]
    read += [job.output / name for name in (*previews, *broken)]
    refuse_unsafe_outputs(
        [*read, *recorded_inputs(buf.provenance)],
        [target],
        where=str(target),
        hint="name another file with -o, e.g. report.html",
    )
    cameras = job.projected_cameras()
    exr = {c.name: _camera_exr(job, buf, c) for c in cameras}
    seen = {name: found.visible for name, found in exr.items() if found is not None}
    sections = [_camera_section(job, buf, c, exr[c.name]) for c in cameras]
    views = _objective_views(job, cameras, sections)
    listed = {f for section in sections for f in section.files}
    names = ", ".join(o.name for o in buf.objectives)
    content = ReportContent(
        title=f"sensaov report: {job.path.name}",
        question=f"Which parts of {job.scene.name} matter for {names}?",
        stamp=_stamp(job, buf),
        primal=_primal(job.output / PRIMAL_NAME, buf),
        objectives=tuple(
            _objective(job, buf, o.name, seen, views.get(o.name)) for o in buf.objectives
        ),
        cameras=tuple(sections),
        rankings={
            by: rankings(
                buf,
                by=by,
                visible=None if by == "type" or not seen else seen,
                untrusted=job.views.untrusted,
            )
            for by in ("object", "type", "key")
        },  # fmt: skip
        buffer=buf,
        absent=_absent(job),
        ignored=_ignored(folder, listed, broken),
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


@dataclass(frozen=True)
class _CameraExr:
    """What the report reads from a camera's EXR: the objects it sees, and what each layer
    shows (``(objective, pass)`` -> its kind: forward, transport, texel; a buffer channel's
    is absent)."""

    visible: frozenset[str]
    kinds: Mapping[tuple[str, str], str]


def _camera_exr(job: JobSpec, buf: SensitivityBuffer, camera: CameraSpec) -> _CameraExr | None:
    """``camera``'s EXR, after checking it belongs; None without one."""
    path = job.output / f"{camera.name}.exr"
    if not path.exists() and not path.is_symlink():  # a FIFO or a device: read_exr refuses it
        return None
    channels, header = read_exr(path)
    remake = f"sensaov project {job.path}"
    check_made_from(header, buf, str(path), remake=remake, job=job)
    kinds = {}
    for key, kind in header.items():
        prefix = key.removesuffix("/kind")
        if key.startswith("sensaov/") and prefix != key and isinstance(kind, str):
            objective, name = header.get(f"{prefix}/objective"), header.get(f"{prefix}/pass")
            if isinstance(objective, str) and isinstance(name, str):
                kinds[(objective, name)] = kind
    return _CameraExr(seen_names(channels, header, where=str(path)), kinds)


def _camera_section(
    job: JobSpec, buf: SensitivityBuffer, camera: CameraSpec, exr: _CameraExr | None
) -> CameraSection:
    folder = job.output / "previews"
    manifest_path = folder / f"{file_token(camera.name)}.json"
    visible = None if exr is None else exr.visible
    if not manifest_path.is_file():
        note = "no previews: run 'sensaov project JOB --png'"
        return CameraSection(camera.name, visible, (), (), (), note)
    manifest = _manifest(manifest_path)
    remake = f"sensaov project {job.path} --png"
    stamped = {f"sensaov/{key}": manifest.get(key) for key in ("buffer_id", "job_hash")}
    check_made_from(stamped, buf, str(manifest_path), remake=remake, job=job)
    headline: list[Picture] = []
    figures: list[Picture] = []
    more: list[Picture] = []
    files: list[str] = []
    kinds = {} if exr is None else exr.kinds
    for entry in map(_Listed.read, manifest["files"]):
        picture = _preview(folder, entry, buf, job, remake)
        files.append(entry.file)
        if _is_headline(job, entry):
            headline.append(picture)
        elif _is_figure(entry, kinds):
            figures.append(picture)
        else:
            more.append(picture)
    return CameraSection(
        camera.name, visible, tuple(headline), tuple(more), tuple(files), "", tuple(figures)
    )


def _is_figure(entry: _Listed, kinds: Mapping[tuple[str, str], str]) -> bool:
    """A texel field's Fig. 4 sheet, or a forward or transport layer (Fig. 5): views the paper
    shows, never folded away (a texel field's single panels are, its sheet holds all three)."""
    layer = kinds.get((entry.objective, entry.pass_name))
    return entry.kind == "fig4" or (entry.kind == "layer" and layer in ("forward", "transport"))


def _objective_views(
    job: JobSpec, cameras: tuple[CameraSpec, ...], sections: list[CameraSection]
) -> dict[str, Picture]:
    """Each objective's headline object view at the objective camera (its trusted part)."""
    named = {section.name: section for section in sections}
    camera = next(c for c in cameras if c.objective)  # projected_cameras always holds one
    views = {}
    for picture in named[camera.name].headline:
        if picture.part != "untrusted" and picture.objective not in views:
            caption = f"{picture.caption} at the objective camera: where sensitivity lands"
            views[picture.objective] = replace(picture, caption=caption, kind="view")
    return views


@dataclass(frozen=True)
class _Listed:
    """One file a previews manifest lists, as the report shows it."""

    file: str
    kind: str
    objective: str
    pass_name: str
    part: str

    @classmethod
    def read(cls, entry: Mapping[str, object]) -> _Listed:
        """An entry of the manifest's ``files``: what a field lacks reads as empty."""
        fields = ("file", "kind", "objective", "pass_name", "part")
        return cls(*(str(entry.get(name, "")) for name in fields))


def _manifest(path: Path) -> dict[str, Any]:
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(document.get("files"), list):
            raise ValueError("no list of files")
        return dict(document)
    except (OSError, ValueError, AttributeError) as error:
        raise StaleInputError(
            f"cannot read this previews manifest: {error}",
            where=str(path),
            hint="re-run 'sensaov project JOB --png'",
        ) from error


def _preview(
    folder: Path, entry: _Listed, buf: SensitivityBuffer, job: JobSpec, remake: str
) -> Picture:
    path = folder / entry.file
    if not path.resolve().is_relative_to(folder.resolve()) or not path.is_file():
        raise StaleInputError("a preview its manifest lists is missing", where=str(path),
                              hint=f"re-run '{remake}'")  # fmt: skip
    try:
        text = read_png_text(path)
    except (OSError, ValueError) as error:
        raise StaleInputError(f"cannot read this preview: {error}", where=str(path),
                              hint=f"re-run '{remake}'") from error  # fmt: skip
    check_made_from(text, buf, str(path), remake=remake, job=job)
    return Picture(
        _caption(entry), path.read_bytes(), kind=entry.kind, objective=entry.objective,
        part=entry.part,
    )  # fmt: skip


def _is_headline(job: JobSpec, entry: _Listed) -> bool:
    """The objective's first object channel (and its untrusted part): a report's headline."""
    headline = next((c.name for c in job.channels if c.kind == "object"), None)
    return entry.kind == "layer" and headline is not None and (
        entry.pass_name in (headline, f"{headline}_untrusted")
    )  # fmt: skip


def _caption(entry: _Listed) -> str:
    if entry.kind == "sheet":
        return f"every pass of {entry.objective} (contact sheet)"
    if entry.kind == "fig4":
        return f"{entry.objective}: texel panels of {entry.pass_name}"
    part = {"trusted": " (trusted gradients)", "untrusted": " (left out: untrusted)"}
    return f"{entry.objective}.{entry.pass_name}{part.get(entry.part, '')}"


def _ignored(folder: Path, listed: set[str], broken: dict[str, str]) -> tuple[str, ...]:
    """PNGs under ``previews`` that no camera's manifest lists: never shown, named, with the
    reason when one is not a whole PNG (``broken`` is keyed by path under the output)."""
    if not folder.is_dir():
        return ()
    found = sorted(
        str(p.relative_to(folder)) for p in folder.rglob("*.png") if p.is_symlink() or p.is_file()
    )
    why = {str(Path(name).relative_to(folder.name)): reason for name, reason in broken.items()}
    return tuple(
        f"{name} ({why[name]})" if name in why else name for name in found if name not in listed
    )


def _objective(
    job: JobSpec,
    buf: SensitivityBuffer,
    name: str,
    seen: dict[str, frozenset[str]],
    view: Picture | None,
) -> ObjectiveSection:
    (top,) = rankings(buf, by="object", objectives=[name], top=SUMMARY_TOP,
                      visible=seen or None, untrusted=job.views.untrusted)  # fmt: skip
    drawn = panels(buf, [name], untrusted=job.views.untrusted)
    data = sunburst_bytes(drawn, fmt="png", order="object,type", encoding="l2 of θ·∂M/∂θ",
                          provenance={"objective": name, "buffer_id": buffer_id(buf)},
                          panel_inches=SUNBURST_INCHES)  # fmt: skip
    sunburst = Picture(f"sunburst of {name}: objects → types → parameters (1:1)", data,
                       kind="sunburst")  # fmt: skip
    apart = {
        row.name: tuple(p for p in buf.params if row.name in p.owners and not is_trusted(p))
        for row in top.left_out
    }
    missing = (
        "no object channel in this job: no view of where its sensitivity lands (docs/job-spec.md)"
        if not any(c.kind == "object" for c in job.channels)
        else "no preview of the objective camera: run 'sensaov project JOB --png'"
    )
    definition = _definition(buf.objective(name).definition)
    return ObjectiveSection(name, definition, top, sunburst, apart, view, "" if view else missing)


def _definition(definition: dict[str, Any]) -> str:
    kind = str(definition.get("type", definition.get("kind", "")))
    words = {
        "mean_luminance": "the mean Rec. 709 luminance of the objective camera's image",
        "region_luminance": "the mean luminance of the region {region} of the image",
        "l2_to_target": "the squared distance of the image to the target {target}",
        "python": "the Python function {function}",
    }
    text = words.get(kind, kind)
    try:
        return text.format(**{k: definition.get(k) for k in ("region", "target", "function")})
    except (KeyError, IndexError, ValueError):
        return text


def _stamp(job: JobSpec, buf: SensitivityBuffer) -> Stamp:
    made = buf.provenance
    batches = buf.statistics.batches if buf.statistics is not None else 1
    return Stamp(
        buffer_id=buffer_id(buf),
        job_version=(run_version(buf) or "unrecorded")[:12],
        job_hash=job.job_hash()[:12],
        made=str(made.get("created_utc", "?")),
        samples=f"{made.get('spp', '?')} spp, {batches} batch(es)",
    )


def _absent(job: JobSpec) -> tuple[str, ...]:
    """The views of the paper this page does not show, and why, said plainly."""
    kinds = {
        "texel (per-texel fields through UVs)": any(c.kind == "texel" for c in job.channels),
        "forward-mode and transport": bool(job.forward)
        or any(c.kind == "transport" for c in job.channels),
    }
    return tuple(
        f"{view} views: this job asks for none (docs/job-spec.md)"
        for view, asked in kinds.items()
        if not asked
    )


def _primal(path: Path, buf: SensitivityBuffer) -> Picture | None:
    if not path.exists() and not path.is_symlink():  # a FIFO or a device: read_exr refuses it
        return None
    channels, header = read_exr(path)
    provenance = header_provenance(header)  # None: not sensaov's, refused below
    recorded = None if provenance is None else provenance_id(provenance)
    check_made_from({"sensaov/buffer_id": recorded}, buf, str(path), remake="sensaov run JOB")
    linear = [channels[c] for c in ("R", "G", "B") if c in channels]
    if len(linear) != 3:
        return None
    image = np.stack(linear, axis=-1)
    # A thumbnail beside each headline view: it fits the summary's first screen with them.
    step = -(-max(image.shape[:2]) // PRIMAL_PIXELS)
    if step > 1:
        height, width = (n // step * step for n in image.shape[:2])
        blocks = image[:height, :width].reshape(height // step, step, width // step, step, 3)
        image = blocks.mean(axis=(1, 3))
    scale = f", 1:{step}" if step > 1 else ""
    caption = f"{path.name} (clipped to [0, 1], sRGB{scale})"
    return Picture(caption, encode_png(srgb_uint8(image)), kind="primal")
