"""``sensaov project``: paint a stored buffer into the inspection cameras as layered EXRs."""

from __future__ import annotations

from pathlib import Path

import click

from sensaov_cli.cli import options


@options.command
@options.job_argument
@click.option(
    "--camera", "cameras", multiple=True, help="Only this camera (repeatable); default: all."
)
@options.buffer_option(help="Buffer to project (default: <output>/buffer.npz of the job).")
@click.option("--png", is_flag=True, help="Also write PNG previews and a contact sheet per camera.")
@click.option(
    "--beauty-spp",
    type=click.IntRange(min=0, max=2**32 - 1),  # Mitsuba's spp is 32-bit
    default=4,
    show_default=True,
    help="Samples per pixel of the quick beauty pass, a reference for the compositor "
    "(0: none). It is a full path trace: at 16 spp it costs more than the whole view. The "
    "objective camera shows the run's primal.exr instead when it was written with this buffer "
    "at the view's size and at least these spp.",
)
@options.force_option(
    help="Project even if the scene or the job changed since the buffer was made."
)
@options.json_option
@options.quiet_option
def project(
    job: Path,
    cameras: tuple[str, ...],
    buffer_path: Path | None,
    png: bool,
    beauty_spp: int,
    force: bool,
    as_json: bool,
    quiet: bool,
) -> None:
    """Paint a stored buffer into every inspection camera as layered EXRs.

    Reads the buffer and traces primary visibility only: no derivative is
    computed, so each view costs a fraction of the adjoint pass. Writes
    <output>/<camera>.exr per camera (beauty, CryptoObject, one layer per
    objective and channel, each with a display layer a viewer shows without
    a grade; see docs/exr-layout.md) and, with --png, legended previews.

    \b
    Pictures of one objective and channel share one scale in every camera
    (the 95th percentile of |value| over the pixels it paints; job key views),
    so every camera's visibility is traced even with --camera. The objects and
    types layers add up trusted gradients; the rest goes to <pass>_untrusted.
    A buffer made by another version of the job is refused (exit 2).

    \b
    Example:
      sensaov project configs/cbox.yaml
      sensaov project configs/cbox.yaml --camera overhead      # one farm task per camera
      sensaov project configs/cbox.yaml --buffer other/buffer.npz --png
    """
    from dataclasses import asdict

    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.project import project_job
    from sensaov_cli.progress import Progress

    spec = load_job(job)
    views = project_job(
        spec,
        buffer_path=buffer_path or spec.output / "buffer.npz",
        cameras=cameras,
        force=force,
        png=png,
        beauty_spp=beauty_spp,
        progress=Progress(quiet=quiet),
    )
    if as_json:
        options.echo_json([asdict(v) for v in views], default=str)
        return
    for view in views:
        extra = f" (+{len(view.previews)} PNG)" if view.previews else ""
        click.echo(
            f"{view.camera}: {view.width}x{view.height}, {view.vis_spp} vis spp, "
            f"{view.seconds:.2f} s -> {view.path}{extra}; beauty: {view.beauty}"
        )
