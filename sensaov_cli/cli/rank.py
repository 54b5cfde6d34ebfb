"""``sensaov rank``: rankings from a stored buffer, with numpy only."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli import options
from sensaov_cli.vocabulary import CUTS, Aggregate, Cut, Untrusted, Weight


@options.command
@click.argument("buffer", type=options.FilePath(path_type=Path))
@click.option(
    "--by",
    type=click.Choice(CUTS),
    help="One table per objective at this cut, with share, signed sum, sign, value, trust.",
)
@options.objective_option(help="Rank only this objective (repeatable; with --by).")
@options.json_option
@click.option("--csv", "as_csv", is_flag=True, help="Print CSV on stdout (with --by).")
@click.option(
    "--exr",
    "exrs",
    multiple=True,
    type=options.FilePath(path_type=Path),
    help="A camera's EXR from 'sensaov project' (repeatable): name it on rows it does not see.",
)
@options.top_option(help="Rows per table.")
@click.option(
    "--all",
    "show_all",
    is_flag=True,
    help="List everything not ranked (no gradient, left out, value 0) in the text; past "
    "--top it is counted in a line per kind. JSON and CSV always hold it all.",
)
@options.aggregate_option
@options.weight_option
@options.untrusted_option
def rank(
    buffer: Path,
    by: Cut | None,
    objective: tuple[str, ...],
    as_json: bool,
    as_csv: bool,
    exrs: tuple[Path, ...],
    top: int,
    show_all: bool,
    aggregate: Aggregate,  # click.Choice gives one of these
    weight: Weight,
    untrusted: Untrusted,
) -> None:
    """Rank parameters, objects and types from a stored buffer (numpy only, no rendering).

    \b
    Without --by: the summary `sensaov run` prints (top keys, objects, types).
    With --by key|object|type: one table per objective at that cut; every row
    has its score, signed sum, sign, share of the total, value (keys: the mean
    of the value array) and trust label. The score is the signed sum of
    theta*dM/dtheta unless --aggregate says otherwise; each row's rank by l2
    stands beside it (marked ≠ where the two orders disagree). Objects and
    types add up only the gradients sensaov stands behind; the rest is ranked
    apart ("left out", --untrusted include mixes it in). With batches, every
    number has its standard error, and a sign is resolved when 0 lies outside
    its 95 % interval (Student's t at batches - 1 degrees of freedom) and its
    batches are not heavy-tailed; an unresolved row is marked ? and ranked
    after the resolved ones. With one batch, there is no error (null).
    --exr CAMERA.exr labels the objects (or keys) that camera does not see; the
    EXR must come from this very buffer. Columns: docs/rankings.md.
    What is not ranked (parameters with no gradient, left out as untrusted,
    of value 0) is listed up to --top entries, then counted: --all lists it.

    \b
    Example:
      sensaov rank out/cbox/buffer.npz --top 5
      sensaov rank out/cbox/buffer.npz --top 5 --all
      sensaov rank out/cbox/buffer.npz --aggregate rms --json
      sensaov rank out/cbox/buffer.npz --by object --exr out/cbox/overhead.exr
      sensaov rank out/cbox/buffer.npz --by key --objective mean_luma --csv > keys.csv
    """
    from sensaov_cli.pipeline.rank import rank_buffer, refuse_options

    refuse_options(by=by, objective=bool(objective), as_json=as_json, as_csv=as_csv, exr=bool(exrs))
    style = "json" if as_json else "csv" if as_csv else "text"
    result = rank_buffer(
        buffer,
        by=by,
        objectives=objective,
        style=style,
        exrs=exrs,
        top=top,
        method=aggregate,
        weight=weight,
        untrusted=untrusted,
        show_all=show_all,
    )
    # JSON and the summary end without a newline; a table or CSV ends with its own
    click.echo(result, nl=by is None or as_json)
