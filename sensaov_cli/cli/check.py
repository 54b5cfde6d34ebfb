"""``sensaov check``: reverse-mode gradients against central finite differences."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from sensaov_cli.cli import options


@options.command
@options.job_argument
@options.json_option
@click.option("--objective", help="Objective to check (default: the job's first).")
@click.option("--spp", type=click.IntRange(min=1), help="Samples per pixel (default: the job's).")
@click.option(
    "--seeds",
    type=click.IntRange(min=2),
    default=6,
    show_default=True,
    help="Seeds averaged for kinds whose value steers sampling (others need one).",
)
@click.option(
    "--full",
    is_flag=True,
    help="The whole audit: every kind over every seed, known-biased kinds included, and "
    "2 random directions in the duality column.",
)
@click.option(
    "--key", "keys", multiple=True, help="Check these keys (default: one per plugin and type)."
)
@options.buffer_option(
    type=options.FilePath(path_type=Path, dir_okay=False),
    help="Buffer whose gradients the duality column checks (default: <output>/buffer.npz).",
)
@click.option(
    "--top", type=click.IntRange(min=1), default=3, show_default=True,
    help="Duality column: parameters per objective, largest first.",
)  # fmt: skip
@click.option(
    "--directions", type=click.IntRange(min=0),
    help="Duality column: random directions per parameter, besides ones [default: 0; 2 "
    "with --full].",
)  # fmt: skip
@options.allow_python_option
@options.quiet_option
@options.progress_option
def check(
    job: Path,
    as_json: bool,
    objective: str | None,
    spp: int | None,
    seeds: int,
    keys: tuple[str, ...],
    buffer_path: Path | None,
    top: int,
    directions: int | None,
    full: bool,
    allow_python: bool,
    quiet: bool,
    progress_style: str,
) -> None:
    """Compare reverse-mode gradients with central finite differences and forward mode.

    For one parameter of each kind (plugin and type) in the job's selection,
    the adjoint's directional derivative is compared with a central difference
    rendered with the same samples. Where the value does not steer sampling
    (reflectance, radiance, texels, conductor eta and k) one seed suffices:
    they agree to float precision. Where it does (roughness, eta, lobe and
    blend weights), and under Russian roulette wherever the value changes a
    path's throughput, the means over --seeds seeds are compared. Verdicts:
    agrees, disagrees, inconclusive (cannot decide at this spp: raise --spp
    or --seeds) or noisy (the seeds' estimates are heavy-tailed, so their
    error says nothing); each but agrees with its reason. Kinds the trust
    table calls biased, and near-specular ones, are what 'sensaov run'
    repairs; they are measured with --full or --key. Progress goes to stderr.

    When the job's buffer exists, a duality column follows: for the --top
    parameters of every objective (or the --key ones) along ones and
    --directions random directions, the stored <g, v> against forward mode
    <dM/dI, J v> at the buffer's own seed (tolerance 1e-4, more for large
    images: float32 sums) and against central
    differences of the image at that seed (2 %). Exits 1 if a parameter the
    verification table trusts disagrees, or the buffer disagrees with forward
    mode (a corrupt or stale buffer); inconclusive and noisy exit 0.

    \b
    Example:
      sensaov check configs/cbox.yaml               # a minute or so on 2 cores
      sensaov check configs/cbox.yaml --full --spp 256 --seeds 12   # the audit
      sensaov check configs/cbox.yaml --key glass.eta --spp 1024 --seeds 12
    """
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.check import checks_text, duality_text, exit_code, run_check
    from sensaov_cli.progress import Progress

    spec = load_job(job)
    report = run_check(
        spec, objective=objective, spp=spp, seeds=seeds, keys=keys, buffer_path=buffer_path,
        top=top, directions=directions, full=full, allow_python=allow_python,
        progress=Progress(quiet=quiet, style=progress_style),
    )  # fmt: skip
    if report.buffer_path is None:
        missing = buffer_path or spec.output / "buffer.npz"
        click.echo(f"sensaov: no buffer at {missing}: duality column skipped", err=True)
    if as_json:
        options.echo_json(report.as_json())
    else:
        click.echo(checks_text(report.gradients))
        for note in report.notes:
            click.echo(f"note: {note}")
        for key, why in report.not_measured:
            click.echo(f"not measured: {key}: {why}")
        if report.duality and report.buffer_path is not None:
            click.echo("")
            click.echo(duality_text(report.duality, report.buffer_path))
    sys.exit(exit_code(report.gradients, report.duality))
