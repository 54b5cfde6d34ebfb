"""``sensaov validate``: check a job file without loading the scene."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli.options import EXIT_CODES_EPILOG, job_argument, reports_errors


@click.command(epilog=EXIT_CODES_EPILOG)
@job_argument
@reports_errors
def validate(job: Path) -> None:
    """Check a job file without loading the scene.

    \b
    Example:
      sensaov validate configs/cbox.yaml
    """
    from sensaov_cli.spec.load import load_job

    spec = load_job(job)
    names = ", ".join(o.name for o in spec.objectives)
    click.echo(f"{job}: ok (scene {spec.scene.name}, objectives: {names}, output {spec.output})")
