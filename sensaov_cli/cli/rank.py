"""``sensaov rank``: rankings from a stored buffer, with numpy only."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, cast

import click

from sensaov_cli.cli.options import (
    EXIT_CODES_EPILOG,
    aggregate_option,
    echo_json,
    json_option,
    objective_option,
    reports_errors,
    top_option,
    weight_option,
)
from sensaov_cli.vocabulary import CUTS, Aggregate, Cut, Weight

if TYPE_CHECKING:
    from sensaov_cli.buffer.model import SensitivityBuffer


@click.command(epilog=EXIT_CODES_EPILOG)
@click.argument("buffer", type=click.Path(path_type=Path))
@click.option(
    "--by",
    type=click.Choice(CUTS),
    help="One table per objective at this cut, with share, signed sum, sign, value, trust.",
)
@objective_option("Rank only this objective (repeatable; with --by).", multiple=True)
@json_option
@click.option("--csv", "as_csv", is_flag=True, help="Print CSV on stdout (with --by).")
@click.option(
    "--exr",
    "exrs",
    multiple=True,
    type=click.Path(path_type=Path),
    help="A camera's EXR from 'sensaov project' (repeatable): label rows off-frame for it.",
)
@top_option("Rows per table.")
@aggregate_option
@weight_option
@reports_errors
def rank(
    buffer: Path,
    by: str | None,
    objective: tuple[str, ...],
    as_json: bool,
    as_csv: bool,
    exrs: tuple[Path, ...],
    top: int,
    aggregate: str,
    weight: str,
) -> None:
    """Rank parameters, objects and types from a stored buffer (numpy only, no rendering).

    \b
    Without --by: the summary `sensaov run` prints (top keys, objects, types).
    With --by key|object|type: one table per objective at that cut; every row
    has its score, signed sum, sign, share of the total, value (keys: the mean
    of the value array) and trust label. --exr CAMERA.exr labels the objects
    (or keys) that camera does not see. Columns: docs/rankings.md.

    \b
    Example:
      sensaov rank out/cbox/buffer.npz --top 5
      sensaov rank out/cbox/buffer.npz --aggregate rms --json
      sensaov rank out/cbox/buffer.npz --by object --exr out/cbox/overhead.exr
      sensaov rank out/cbox/buffer.npz --by key --objective mean_luma --csv > keys.csv
    """
    from sensaov_cli.buffer.model import SensitivityBuffer
    from sensaov_cli.errors import QueryError

    if as_json and as_csv:
        raise QueryError("--json and --csv exclude each other", hint="choose one")
    if by is None and (objective or as_csv or exrs):
        raise QueryError("--objective, --csv and --exr need --by", hint="add --by key|object|type")
    loaded = SensitivityBuffer.load(buffer)
    method, weighting = cast(Aggregate, aggregate), cast(Weight, weight)
    if by is None:
        _summary(loaded, as_json, top, method, weighting)
        return
    _by_cut(loaded, cast(Cut, by), objective, as_json, as_csv, exrs, top, method, weighting)


def _summary(
    buf: SensitivityBuffer, as_json: bool, top: int, method: Aggregate, weight: Weight
) -> None:
    from sensaov_cli.outputs.tables import summary_text
    from sensaov_cli.views.summary import summary_dict

    if as_json:
        echo_json(summary_dict(buf, top=top, method=method, weight=weight))
    else:
        click.echo(summary_text(buf, top=top, method=method, weight=weight))


def _by_cut(
    buf: SensitivityBuffer,
    by: Cut,
    objective: tuple[str, ...],
    as_json: bool,
    as_csv: bool,
    exrs: tuple[Path, ...],
    top: int,
    method: Aggregate,
    weight: Weight,
) -> None:
    from sensaov_cli.outputs.frames import visible_objects
    from sensaov_cli.outputs.rankings import ranking_csv, ranking_dict, ranking_text
    from sensaov_cli.views.hierarchy import check_cut, rankings

    check_cut(by, cameras=bool(exrs))
    for name in objective:
        buf.objective(name)  # an unknown name is an error that lists the known ones
    visible = visible_objects(list(exrs)) if exrs else None
    found = rankings(
        buf,
        by=by,
        objectives=objective or None,
        top=top,
        method=method,
        weight=weight,
        visible=visible,
    )
    if as_json:
        cameras = None if visible is None else list(visible)
        echo_json(ranking_dict(buf, found, method=method, weight=weight, cameras=cameras))
    elif as_csv:
        click.echo(ranking_csv(found), nl=False)
    else:
        click.echo(ranking_text(found, method=method, weight=weight), nl=False)
