"""Wire ``sensaov rank``: a stored buffer (and cameras' EXRs) -> rankings; numpy only."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import QueryError
from sensaov_cli.outputs.tables import (
    ranking_csv,
    ranking_json,
    ranking_text,
    summary_json,
    summary_text,
)
from sensaov_cli.views.hierarchy import check_cut, ranked_summary, rankings
from sensaov_cli.vocabulary import DEFAULT_AGGREGATE, Aggregate, Cut, Untrusted, Weight


def summary_of(
    buffer: SensitivityBuffer,
    *,
    as_json: bool,
    top: int,
    method: Aggregate = DEFAULT_AGGREGATE,
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
    files: Mapping[str, str] | None = None,
    show_all: bool = False,
) -> str:
    """A buffer's ranked summary, as text or JSON (``run`` prints it for its buffer, with the
    ``files`` it wrote in the JSON); the text lists all that is not ranked with ``show_all``."""
    if as_json:
        summary = ranked_summary(buffer, top=top, method=method, weight=weight, untrusted=untrusted)
        return summary_json(summary, files)
    return summary_text(
        buffer, top=top, method=method, weight=weight, untrusted=untrusted, show_all=show_all
    )


def rank_buffer(
    buffer: Path,
    *,
    by: Cut | None,
    objectives: tuple[str, ...],
    style: str,
    exrs: tuple[Path, ...],
    top: int,
    method: Aggregate,
    weight: Weight,
    untrusted: Untrusted = "apart",
    show_all: bool = False,
) -> str:
    """The summary ``sensaov run`` prints (top keys, objects, types) without ``by``, else one
    table per objective at that cut: ``style`` "json", "csv" or "text"."""
    loaded = read_buffer(buffer, lazy=True)  # a ranking reads each parameter's sums
    if by is None:
        return summary_of(
            loaded,
            as_json=style == "json",
            top=top,
            method=method,
            weight=weight,
            untrusted=untrusted,
            show_all=show_all,
        )
    check_cut(by, cameras=bool(exrs))
    for name in objectives:
        loaded.objective(name)  # an unknown name is an error that lists the known ones
    visible = _visible(buffer, loaded, exrs) if exrs else None
    found = rankings(
        loaded,
        by=by,
        objectives=objectives or None,
        top=top,
        method=method,
        weight=weight,
        visible=visible,
        untrusted=untrusted,
    )
    if style == "json":
        cameras = None if visible is None else list(visible)
        return ranking_json(loaded, found, method=method, weight=weight, cameras=cameras)
    if style == "csv":
        return ranking_csv(found)
    return ranking_text(found, method=method, weight=weight, limit=None if show_all else top)


def refuse_options(
    *, by: str | None, objective: bool, as_json: bool, as_csv: bool, exr: bool
) -> None:
    """Options that exclude each other, refused before the buffer is read."""
    if as_json and as_csv:
        raise QueryError("--json and --csv exclude each other", hint="choose one")
    if by is None and (objective or as_csv or exr):
        raise QueryError("--objective, --csv and --exr need --by", hint="add --by key|object|type")


def _visible(
    buffer: Path, loaded: SensitivityBuffer, exrs: tuple[Path, ...]
) -> dict[str, frozenset[str]]:
    """What each camera's EXR sees, each EXR checked to come from this very buffer."""
    # Imported here: only --exr needs them, and the job spec they load costs every rank time.
    from sensaov_cli.outputs.layered_exr import visible_objects
    from sensaov_cli.pipeline.project import check_made_from

    remake = f"sensaov project JOB, with the job that wrote {buffer.name}"
    return visible_objects(
        list(exrs), lambda path, header: check_made_from(header, loaded, str(path), remake=remake)
    )
