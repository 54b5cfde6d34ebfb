"""``sensaov run``: one primal render and one adjoint pass per objective, into a buffer."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli.options import (
    EXIT_CODES_EPILOG,
    allow_python_option,
    echo_json,
    job_argument,
    json_option,
    quiet_option,
    reports_errors,
    top_option,
)


@click.command(epilog=EXIT_CODES_EPILOG)
@job_argument
@json_option
@quiet_option
@top_option("Rows per table in the summary.")
@allow_python_option
@reports_errors
def run(job: Path, as_json: bool, quiet: bool, top: int, allow_python: bool) -> None:
    """Render the objective camera once and fill the sensitivity buffer.

    One primal render, then one reverse-mode pass per objective. Writes
    <output>/buffer.npz and <output>/primal.exr (atomically) and prints a
    ranked summary per objective; progress goes to stderr.

    \b
    Example:
      sensaov run configs/cbox.yaml
      sensaov run configs/cbox.yaml --json -q > summary.json
    """
    from sensaov_cli.outputs.tables import summary_text
    from sensaov_cli.progress import Progress
    from sensaov_cli.run import run_job
    from sensaov_cli.spec.load import load_job
    from sensaov_cli.views.summary import summary_dict

    spec = load_job(job)
    outputs = run_job(spec, allow_python=allow_python, progress=Progress(quiet=quiet))
    if as_json:
        summary = summary_dict(outputs.buffer, top=top)
        summary["files"] = {"buffer": str(outputs.buffer_path), "primal": str(outputs.primal_path)}
        echo_json(summary)
    else:
        click.echo(summary_text(outputs.buffer, top=top))
        click.echo(f"wrote {outputs.buffer_path} and {outputs.primal_path}")
