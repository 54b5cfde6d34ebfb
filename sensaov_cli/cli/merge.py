"""``sensaov merge``: combine shard buffers into one, with standard errors."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli import options


@options.command
@click.argument(
    "shards", nargs=-1, required=True, type=options.FilePath(path_type=Path, dir_okay=False)
)
@options.output_option(
    required=True,
    type=options.FilePath(path_type=Path, dir_okay=False),
    help="The merged buffer; its primal is written beside it (buffer -> primal, .exr).",
)
@options.quiet_option
@options.progress_option
def merge(shards: tuple[Path, ...], output: Path, quiet: bool, progress_style: str) -> None:
    """Merge the shards of a job ('sensaov run JOB --shard I/N') into one buffer.

    Gradients, objective values and primals become the spp-weighted mean of the
    shards; with 2 or more shards the buffer also stores standard errors (each
    shard is one batch). Refused, with the reason: shards of other scenes, jobs,
    parameter sets or format versions, a missing or duplicated shard.

    \b
    Example:
      sensaov merge out/cbox/buffer.shard-*-of-4.npz -o out/cbox/buffer.npz
      sensaov rank out/cbox/buffer.npz --top 5      # with standard errors
    """
    from sensaov_cli.pipeline.merge import merge_files, primal_beside
    from sensaov_cli.progress import Progress

    result = merge_files(list(shards), output, progress=Progress(quiet, style=progress_style))
    click.echo(
        f"merged {result.shards} shard file(s), {result.buffer.provenance['spp']} spp: "
        f"wrote {output} and {primal_beside(output)}"
    )
    for line in result.hint:
        click.echo(line)
