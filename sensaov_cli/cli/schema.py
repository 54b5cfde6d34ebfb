"""``sensaov schema``: the JSON Schema of the job format."""

from __future__ import annotations

import click

from sensaov_cli.cli.options import EXIT_CODES_EPILOG, echo_json, reports_errors


@click.command(epilog=EXIT_CODES_EPILOG)
@reports_errors
def schema() -> None:
    """Print the JSON Schema of the job format (for editors and CI linting).

    \b
    Example:
      sensaov schema > sensaov-job.schema.json
    """
    from sensaov_cli.job.load import job_schema

    echo_json(job_schema(), sort_keys=True)
