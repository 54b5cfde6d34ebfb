"""``sensaov params``: which scene parameters enter the buffer, and why others do not."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli import options


@options.command
@options.job_argument
@options.json_option
@click.option(
    "--all", "show_all", is_flag=True, help="List every excluded key, not only a count per reason."
)
def params(job: Path, as_json: bool, show_all: bool) -> None:
    """Show which scene parameters enter the buffer, their owners and types.

    Loads the scene (no rendering). Textures converted from 8-bit to float and
    parameters left out are listed with the reason.

    \b
    Example:
      sensaov params configs/cbox.yaml
      sensaov params configs/cbox.yaml --json | jq '.selected[].key'
    """
    from sensaov_cli.job.load import load_job
    from sensaov_cli.outputs.tables import params_dict, params_text
    from sensaov_cli.pipeline.params import parameter_inventory

    inventory = parameter_inventory(load_job(job))
    if as_json:
        options.echo_json(params_dict(inventory))
    else:
        click.echo(params_text(inventory, show_all=show_all))
