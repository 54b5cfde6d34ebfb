"""``sensaov run``: one primal render and one adjoint pass per objective, into a buffer."""

from __future__ import annotations

import re
from pathlib import Path

import click

from sensaov_cli.cli import options


def _shard(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[int, int] | None:
    if value is None:
        return None
    # ASCII digits only: str.isdigit() takes '²' and '٣', which int() refuses or reads.
    match = re.fullmatch(r"([0-9]{1,9})/([0-9]{1,9})", value)
    if match is None or not 1 <= int(match.group(1)) <= int(match.group(2)):
        raise click.BadParameter(f"{value!r} is not I/N with 1 <= I <= N (e.g. 3/8)")
    return int(match.group(1)), int(match.group(2))


@options.command
@options.job_argument
@options.json_option
@options.quiet_option
@options.top_option(help="Rows per table in the summary.")
@options.allow_python_option
@click.option(
    "--shard",
    metavar="I/N",
    callback=_shard,
    help="Render shard I of N (1/N of render.spp, its own seed) into buffer.shard-I-of-N.npz; "
    "'sensaov merge' combines the N shards.",
)
@options.objective_option(
    help="Differentiate this objective only (repeatable): one farm task per pass."
)
@click.option(
    "--resume",
    is_flag=True,
    help="Skip the work if this task's outputs are complete and were made by this job.",
)
@options.progress_option
def run(
    job: Path,
    as_json: bool,
    quiet: bool,
    top: int,
    allow_python: bool,
    shard: tuple[int, int] | None,
    objective: tuple[str, ...],
    resume: bool,
    progress_style: str,
) -> None:
    """Render the objective camera once and fill the sensitivity buffer.

    One primal render, then one reverse-mode pass per objective. Writes
    <output>/buffer.npz and <output>/primal.exr (atomically) and prints a
    ranked summary per objective; progress goes to stderr.

    \b
    Example:
      sensaov run configs/cbox.yaml
      sensaov run configs/cbox.yaml --json -q > summary.json
      sensaov run configs/cbox.yaml --shard 3/8 --resume    # one farm task
      sensaov run configs/cbox.yaml --objective mean_luma   # one adjoint pass
    """
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.rank import summary_of
    from sensaov_cli.pipeline.run import Task, run_task
    from sensaov_cli.progress import Progress

    spec = load_job(job)
    task = Task(shard, tuple(dict.fromkeys(objective)))
    with options.stdout_to_stderr():  # an objective's print() must not end up in the summary
        result = run_task(
            spec,
            allow_python=allow_python,
            progress=Progress(quiet=quiet, style=progress_style),
            task=task,
            resume=resume,
        )
    buffer = result.buffer
    buffer_path, primal_path = (spec.output / name for name in task.file_names())
    files = {"buffer": str(buffer_path), "primal": str(primal_path)}
    summary = summary_of(
        buffer, as_json=as_json, top=top, untrusted=spec.views.untrusted, files=files
    )
    click.echo(summary)
    if not as_json and result.skipped:  # say only what happened: nothing was written
        click.echo(f"kept {buffer_path} and {primal_path} (complete: --resume rendered nothing)")
    elif not as_json:
        click.echo(f"wrote {buffer_path} and {primal_path}")
