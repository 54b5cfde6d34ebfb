"""What the commands share: arguments, options, the exit-code epilog and the error reporting.

After rasterio's ``rio/options.py``: a command module takes its common parameters from here
rather than declaring them again, so ``--json`` or the job argument read the same in every
``--help``. Standard library and click only; the stages are imported inside the commands.
"""

from __future__ import annotations

import json
import sys
import traceback
from collections.abc import Callable
from functools import wraps
from pathlib import Path
from typing import Any

import click

from sensaov_cli import interrupts
from sensaov_cli.errors import EXIT_INTERRUPTED, EXIT_JOB_FAILED, EXIT_MEANINGS, SensaovError
from sensaov_cli.vocabulary import AGGREGATES, WEIGHTS

Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]

# The end of every --help, from the one table of exit codes in errors.py.
EXIT_CODES_EPILOG = "\b\nExit codes:\n" + "".join(
    f"  {code}  {meaning}\n" for code, meaning in EXIT_MEANINGS.items()
)

job_argument = click.argument("job", type=click.Path(path_type=Path, dir_okay=False))
allow_python_option = click.option(
    "--allow-python",
    is_flag=True,
    help="Allow 'python' objectives (they run code named in the job).",
)
json_option = click.option(
    "--json", "as_json", is_flag=True, help="Print JSON on stdout instead of a table."
)
quiet_option = click.option("-q", "--quiet", is_flag=True, help="No progress on stderr.")
progress_option = click.option(
    "--progress",
    "progress_style",
    type=click.Choice(["auto", "plain", "farm"]),
    default="auto",
    show_default=True,
    help="farm: also print 'Progress: N%' lines for farm managers (Deadline, OpenCue, Slurm "
    "logs); auto: farm when stderr is not a terminal.",
)
aggregate_option = click.option(
    "--aggregate",
    type=click.Choice(AGGREGATES),
    default="l2",
    show_default=True,
    help="How a group's contributions become one score (docs/buffer-format.md).",
)
weight_option = click.option(
    "--weight",
    type=click.Choice(WEIGHTS),
    default="value",
    show_default=True,
    help="value: θ·∂M/∂θ (response to a proportional change); raw: ∂M/∂θ.",
)


def objective_option(help_text: str, *, multiple: bool = False) -> Decorator:
    """``--objective NAME``: an objective of the buffer (all of them when not given)."""
    return click.option("--objective", multiple=multiple, help=help_text)


def top_option(help_text: str) -> Decorator:
    """``--top N`` (at least 1, default 8): how many rows a ranking table shows."""
    return click.option(
        "--top", default=8, show_default=True, type=click.IntRange(min=1), help=help_text
    )


def echo_json(data: Any, **dumps: Any) -> None:
    """``data`` as indented JSON on stdout (``dumps``: more ``json.dumps`` arguments)."""
    click.echo(json.dumps(data, indent=2, **dumps))


def _fail(message: str, code: int) -> None:
    click.echo(f"sensaov: error: {message}", err=True)
    sys.exit(code)


def reports_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn any failure into one line on stderr and a documented exit code (traceback at -vv).

    Library errors become an exit code here, and only here.
    """

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
            _fail("interrupted; no partial output was written", EXIT_INTERRUPTED)
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
