"""``sensaov report``: one self-contained HTML page of a job's outputs."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli import options


@options.command
@options.job_argument
@options.output_option(help="The page to write (default: <output>/report.html of the job).")
def report(job: Path, output: Path | None) -> None:
    """Write one HTML page of a job's outputs: nothing is rendered again.

    \b
    A summary first (the question, each objective's top objects with ± and
    trust, what was left out and why, its sunburst), one section per camera
    with its headline previews and legends (`project --png`), then an appendix
    (rankings in full, trust of every parameter, provenance). Images are
    embedded: the file opens in a browser straight from disk. Outputs made
    from another buffer or job version are refused (exit 2).

    \b
    Example:
      sensaov run configs/cbox.yaml && sensaov project configs/cbox.yaml --png
      sensaov report configs/cbox.yaml          # -> out/cbox/report.html
    """
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.report import make_report

    click.echo(str(make_report(load_job(job), output)))
