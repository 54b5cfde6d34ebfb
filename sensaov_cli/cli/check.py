"""``sensaov check``: reverse-mode gradients against central finite differences."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from sensaov_cli.cli.options import (
    EXIT_CODES_EPILOG,
    allow_python_option,
    echo_json,
    job_argument,
    json_option,
    reports_errors,
)


@click.command(epilog=EXIT_CODES_EPILOG)
@job_argument
@json_option
@click.option("--objective", help="Objective to check (default: the job's first).")
@click.option("--spp", type=click.IntRange(min=1), help="Samples per pixel (default: the job's).")
@click.option(
    "--seeds",
    type=click.IntRange(min=2),
    default=6,
    show_default=True,
    help="Independent seeds averaged per parameter.",
)
@click.option(
    "--key", "keys", multiple=True, help="Check these keys (default: one per plugin and type)."
)
@allow_python_option
@reports_errors
def check(
    job: Path,
    as_json: bool,
    objective: str | None,
    spp: int | None,
    seeds: int,
    keys: tuple[str, ...],
    allow_python: bool,
) -> None:
    """Compare reverse-mode gradients with central finite differences.

    For one parameter of each kind (plugin and type) in the job's selection,
    the adjoint's directional derivative is compared with a central difference
    rendered at the same seed, over several seeds. Verdicts: agrees,
    disagrees, or inconclusive (too noisy at this spp: raise --spp). Exits 1
    if a parameter the verification table trusts disagrees.

    \b
    Example:
      sensaov check configs/cbox.yaml --spp 256
      sensaov check configs/cbox.yaml --key glass.eta --spp 1024 --seeds 12
    """
    from dataclasses import asdict

    from sensaov_cli.check import check_job, exit_code
    from sensaov_cli.outputs.tables import checks_text
    from sensaov_cli.spec.load import load_job

    spec = load_job(job)
    results = check_job(
        spec, objective=objective, spp=spp, seeds=seeds, keys=keys, allow_python=allow_python
    )
    if as_json:
        echo_json([asdict(r) for r in results])
    else:
        click.echo(checks_text(results))
    sys.exit(exit_code(results))
