"""``sensaov validate``: check a job file and its scene XML without rendering."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli import options


@options.command
@options.job_argument
def validate(job: Path) -> None:
    """Check a job file and its scene's XML without rendering.

    Reads the scene as Mitsuba would (includes, $name arguments) and checks that every
    camera the job names is a sensor of the scene; Mitsuba is not loaded.

    \b
    Example:
      sensaov validate configs/cbox.yaml
    """
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.validate import validate_job

    spec = load_job(job)
    sensors = validate_job(spec).sensor_ids
    names = ", ".join(o.name for o in spec.objectives)
    click.echo(
        f"{job}: ok (scene {spec.scene.name}, {len(sensors)} sensor(s), objectives: {names}, "
        f"output {spec.output})"
    )
