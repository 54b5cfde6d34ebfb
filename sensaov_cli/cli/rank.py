"""``sensaov rank``: rankings from a stored buffer, with numpy only."""

from __future__ import annotations

from pathlib import Path
from typing import cast

import click

from sensaov_cli.cli.options import (
    EXIT_CODES_EPILOG,
    echo_json,
    json_option,
    reports_errors,
    top_option,
)
from sensaov_cli.vocabulary import AGGREGATES, WEIGHTS, Aggregate, Weight


@click.command(epilog=EXIT_CODES_EPILOG)
@click.argument("buffer", type=click.Path(path_type=Path, dir_okay=False))
@json_option
@top_option("Rows per table.")
@click.option("--aggregate", type=click.Choice(AGGREGATES), default="l2", show_default=True)
@click.option(
    "--weight",
    type=click.Choice(WEIGHTS),
    default="value",
    show_default=True,
    help="value: θ·∂M/∂θ (response to a proportional change); raw: ∂M/∂θ.",
)
@reports_errors
def rank(buffer: Path, as_json: bool, top: int, aggregate: str, weight: str) -> None:
    """Rank parameters, objects and types from a stored buffer (numpy only, no rendering).

    \b
    Example:
      sensaov rank out/cbox/buffer.npz --top 5
      sensaov rank out/cbox/buffer.npz --aggregate rms --json
    """
    from sensaov_cli.buffer.model import SensitivityBuffer
    from sensaov_cli.outputs.tables import summary_text
    from sensaov_cli.views.summary import summary_dict

    loaded = SensitivityBuffer.load(buffer)
    method, weighting = cast(Aggregate, aggregate), cast(Weight, weight)
    if as_json:
        echo_json(summary_dict(loaded, top=top, method=method, weight=weighting))
    else:
        click.echo(summary_text(loaded, top=top, method=method, weight=weighting))
