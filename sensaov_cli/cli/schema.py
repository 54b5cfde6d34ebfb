"""``sensaov schema``: the JSON Schema of the job format."""

from __future__ import annotations

from sensaov_cli.cli import options


@options.command
def schema() -> None:
    """Print the JSON Schema of the job format (for editors and CI linting).

    \b
    Example:
      sensaov schema > sensaov-job.schema.json
    """
    from sensaov_cli.job.load import job_schema

    options.echo_json(job_schema(), sort_keys=True)
