"""The ``sensaov`` command line: click commands that wire the stages, with no logic of their own.

Heavy imports (Mitsuba, Dr.Jit, pydantic) happen inside the commands, so ``sensaov --help`` and
``sensaov rank`` start instantly. Library errors become one line on stderr and an exit code here,
and only here.
"""

from __future__ import annotations

import json
import sys
import traceback
from collections.abc import Callable
from functools import wraps
from pathlib import Path
from typing import Any, cast

import click

from sensaov_cli import __version__, interrupts
from sensaov_cli.errors import EXIT_BAD_INPUT, EXIT_JOB_FAILED, EXIT_OK, SensaovError, SpecError
from sensaov_cli.vocabulary import AGGREGATES, WEIGHTS

EXIT_CODES = f"""\b
Exit codes:
  {EXIT_OK}  success
  {EXIT_JOB_FAILED}  the job failed (rendering, objective, NaN gradients, internal error)
  {EXIT_BAD_INPUT}  bad input (malformed job, unknown key, missing file, corrupt buffer)
  3  the machine cannot render (no usable libLLVM, no CUDA for a cuda variant)
  130  interrupted (Ctrl-C, SIGTERM); earlier outputs are left untouched
"""

job_argument = click.argument("job", type=click.Path(path_type=Path, dir_okay=False))
allow_python_option = click.option(
    "--allow-python",
    is_flag=True,
    help="Allow 'python' objectives (they run code named in the job).",
)
json_option = click.option(
    "--json", "as_json", is_flag=True, help="Print JSON on stdout instead of a table."
)


def _fail(message: str, code: int) -> None:
    click.echo(f"sensaov: error: {message}", err=True)
    sys.exit(code)


def reports_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn any failure into one line on stderr and a documented exit code (traceback at -vv)."""

    @wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        verbose = click.get_current_context().find_root().params.get("verbose", 0)
        interrupts.install()
        try:
            return command(*args, **kwargs)
        except SensaovError as err:
            if verbose >= 2:
                traceback.print_exc()
            _fail(str(err), err.exit_code)
        except KeyboardInterrupt:
            _fail("interrupted; no partial output was written", 130)
        except Exception as err:  # noqa: BLE001 - the one place unexpected errors are reported
            if verbose >= 2:
                traceback.print_exc()
            detail = str(err).strip().splitlines()
            _fail(
                f"internal error: {type(err).__name__}: {detail[-1] if detail else ''} "
                "(run with -vv for the traceback)",
                EXIT_JOB_FAILED,
            )

    return wrapper


@click.group(epilog=EXIT_CODES, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="sensaov")
@click.option("-v", "--verbose", count=True, help="-vv prints tracebacks with errors.")
def main(verbose: int) -> None:
    """Sensitivity AOVs: which parts of a Mitsuba 3 scene matter for a goal.

    \b
    One reverse-mode pass per objective fills a sensitivity buffer (.npz);
    every view after that reads the buffer without differentiating again.

    \b
    Typical session:
      sensaov validate configs/cbox.yaml
      sensaov params configs/cbox.yaml
      sensaov run configs/cbox.yaml        # -> out/cbox/buffer.npz, primal.exr
      sensaov rank out/cbox/buffer.npz --top 5
    """


@main.command(epilog=EXIT_CODES)
@job_argument
@reports_errors
def validate(job: Path) -> None:
    """Check a job file without loading the scene.

    \b
    Example:
      sensaov validate configs/cbox.yaml
    """
    from sensaov_cli.spec.job import load_job

    spec = load_job(job)
    names = ", ".join(o.name for o in spec.objectives)
    click.echo(f"{job}: ok (scene {spec.scene.name}, objectives: {names}, output {spec.output})")


@main.command(epilog=EXIT_CODES)
@reports_errors
def schema() -> None:
    """Print the JSON Schema of the job format (for editors and CI linting).

    \b
    Example:
      sensaov schema > sensaov-job.schema.json
    """
    from sensaov_cli.spec.job import job_schema

    click.echo(json.dumps(job_schema(), indent=2, sort_keys=True))


@main.command(epilog=EXIT_CODES)
@job_argument
@json_option
@click.option(
    "--all", "show_all", is_flag=True, help="List every excluded key, not only a count per reason."
)
@reports_errors
def params(job: Path, as_json: bool, show_all: bool) -> None:
    """Show which scene parameters enter the buffer, their owners and types.

    Loads the scene (no rendering). Textures converted from 8-bit to float and
    parameters left out are listed with the reason.

    \b
    Example:
      sensaov params configs/cbox.yaml
      sensaov params configs/cbox.yaml --json | jq '.selected[].key'
    """
    from sensaov_cli.outputs.tables import params_dict, params_text
    from sensaov_cli.render.scene import load_scene
    from sensaov_cli.spec.job import load_job

    loaded = load_scene(load_job(job))
    if as_json:
        click.echo(json.dumps(params_dict(loaded), indent=2))
    else:
        click.echo(params_text(loaded, show_all=show_all))


@main.command(epilog=EXIT_CODES)
@job_argument
@json_option
@click.option("-q", "--quiet", is_flag=True, help="No progress on stderr.")
@click.option(
    "--top",
    default=8,
    show_default=True,
    type=click.IntRange(min=1),
    help="Rows per table in the summary.",
)
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
    from sensaov_cli.progress import Progress
    from sensaov_cli.run import run_job
    from sensaov_cli.spec.job import load_job
    from sensaov_cli.outputs.tables import summary_text
    from sensaov_cli.views.summary import summary_dict

    spec = load_job(job)
    outputs = run_job(spec, allow_python=allow_python, progress=Progress(quiet=quiet))
    if as_json:
        summary = summary_dict(outputs.buffer, top=top)
        summary["files"] = {"buffer": str(outputs.buffer_path), "primal": str(outputs.primal_path)}
        click.echo(json.dumps(summary, indent=2))
    else:
        click.echo(summary_text(outputs.buffer, top=top))
        click.echo(f"wrote {outputs.buffer_path} and {outputs.primal_path}")


@main.command(epilog=EXIT_CODES)
@job_argument
@click.option(
    "--camera", "cameras", multiple=True, help="Only this camera (repeatable); default: all."
)
@click.option(
    "--buffer",
    "buffer_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Buffer to project (default: <output>/buffer.npz of the job).",
)
@click.option("--png", is_flag=True, help="Also write PNG previews and a contact sheet per camera.")
@click.option(
    "--beauty-spp",
    type=click.IntRange(min=0),
    default=4,
    show_default=True,
    help="Samples per pixel of the quick beauty pass, a reference for the compositor "
    "(0: none). It is a full path trace: at 16 spp it costs more than the whole view.",
)
@click.option(
    "--force", is_flag=True, help="Project even if the scene changed since the buffer was made."
)
@json_option
@click.option("-q", "--quiet", is_flag=True, help="No progress on stderr.")
@reports_errors
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
    objective and channel; see docs/exr-layout.md) and, with --png, previews.

    \b
    Example:
      sensaov project configs/cbox.yaml
      sensaov project configs/cbox.yaml --camera overhead      # one farm task per camera
      sensaov project configs/cbox.yaml --buffer other/buffer.npz --png
    """
    from dataclasses import asdict

    from sensaov_cli.progress import Progress
    from sensaov_cli.project import project_job
    from sensaov_cli.spec.job import load_job

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
        click.echo(json.dumps([asdict(v) for v in views], indent=2, default=str))
        return
    for view in views:
        extra = f" (+{len(view.previews)} PNG)" if view.previews else ""
        click.echo(
            f"{view.camera}: {view.width}x{view.height}, {view.vis_spp} vis spp, "
            f"{view.seconds:.2f} s -> {view.path}{extra}"
        )


@main.command(epilog=EXIT_CODES)
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

    from sensaov_cli.outputs.tables import checks_text
    from sensaov_cli.render.fdcheck import check_gradients
    from sensaov_cli.render.objectives import build_objectives
    from sensaov_cli.render.scene import load_scene
    from sensaov_cli.spec.job import load_job

    spec = load_job(job)
    loaded = load_scene(spec)
    chosen = [o for o in spec.objectives if objective in (None, o.name)][:1]
    if not chosen:
        names = ", ".join(o.name for o in spec.objectives)
        raise SpecError(
            f"no objective named {objective!r}", where="--objective", hint=f"objectives: {names}"
        )
    width, height = loaded.resolution
    (built,) = build_objectives(loaded.mi, tuple(chosen), (height, width), allow_python)
    results = check_gradients(
        loaded, built, spp=spp or spec.render.spp, seeds=list(range(seeds)), keys=list(keys) or None
    )
    if as_json:
        click.echo(json.dumps([asdict(r) for r in results], indent=2))
    else:
        click.echo(checks_text(results))
    if any(r.claimed_verified and r.verdict == "disagrees" for r in results):
        sys.exit(EXIT_JOB_FAILED)


@main.command(epilog=EXIT_CODES)
@click.argument("buffer", type=click.Path(path_type=Path, dir_okay=False))
@json_option
@click.option(
    "--top", default=8, show_default=True, type=click.IntRange(min=1), help="Rows per table."
)
@click.option(
    "--aggregate", type=click.Choice(AGGREGATES), default="l2", show_default=True
)
@click.option(
    "--weight",
    type=click.Choice(WEIGHTS),
    default="value",
    show_default=True,
    help="value: θ·∂M/∂θ (response to a proportional change); raw: ∂M/∂θ.",
)
@reports_errors
def rank(buffer: Path, as_json: bool, top: int, aggregate: str, weight: str) -> None:
    """Rank parameters, objects and types from a stored buffer (numpy only, no rendering).

    \b
    Example:
      sensaov rank out/cbox/buffer.npz --top 5
      sensaov rank out/cbox/buffer.npz --aggregate rms --json
    """
    from sensaov_cli.buffer.model import SensitivityBuffer
    from sensaov_cli.outputs.tables import summary_text
    from sensaov_cli.views.summary import summary_dict
    from sensaov_cli.vocabulary import Aggregate, Weight

    loaded = SensitivityBuffer.load(buffer)
    method, weighting = cast(Aggregate, aggregate), cast(Weight, weight)
    if as_json:
        click.echo(
            json.dumps(summary_dict(loaded, top=top, method=method, weight=weighting), indent=2)
        )
    else:
        click.echo(summary_text(loaded, top=top, method=method, weight=weighting))


if __name__ == "__main__":  # pragma: no cover
    main()
