"""What the commands share: arguments, options, the exit-code epilog and the error reporting.

After rasterio's ``rio/options.py``: a command module takes its common parameters from here
rather than declaring them again, so ``--json`` or the job argument read the same in every
``--help``. Standard library and click only; the stages are imported inside the commands.
"""

from __future__ import annotations

import errno
import json
import os
import sys
import traceback
from collections.abc import Callable
from functools import wraps
from pathlib import Path
from typing import Any

import click

from sensaov_cli import interrupts
from sensaov_cli.errors import EXIT_BAD_INPUT, EXIT_JOB_FAILED, EXIT_MEANINGS, SensaovError
from sensaov_cli.outputs import atomic
from sensaov_cli.vocabulary import AGGREGATES, WEIGHTS

Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]

# The end of every --help, from the one table of exit codes in errors.py.
EXIT_CODES_EPILOG = "\b\nExit codes:\n" + "".join(
    f"  {code}  {meaning}\n" for code, meaning in EXIT_MEANINGS.items()
)

job_argument = click.argument("job", type=click.Path(path_type=Path))
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


def _fail(message: str, code: int, earlier: int = 0) -> None:
    click.echo(f"sensaov: error: {_one_line(message)}{_written(earlier)}", err=True)
    sys.exit(code)


def _stopped(earlier: int) -> None:
    """Report a stop and end the process at once with 130/143. Interpreter finalisation is
    skipped on purpose: a stop that arrived while Dr.Jit initialised could otherwise end the
    process by SIGINT (exit -2) after the line was printed (seen in 3 of 10 runs with SIGTERM
    0.2 s after start). Outputs are settled here: temporaries removed, nothing else is open."""
    code = interrupts.exit_code()
    try:
        _fail(f"stopped by {interrupts.signal_name()}", code, earlier)
    except SystemExit:
        pass
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _one_line(text: str) -> str:
    """A message on one line whatever it quotes (a name with a newline from a stranger's file)."""
    return " ".join(text.split("\n")).replace("\r", " ")


def _written(earlier: int) -> str:
    """What this command replaced before it stopped (the process's ledger after its first
    ``earlier`` entries); everything else is as it was."""
    from sensaov_cli.outputs.atomic import remove_temporaries, replaced

    remove_temporaries()
    done = replaced()[earlier:]
    if not done:
        return "; no output was replaced"
    return f"; replaced: {', '.join(map(str, done))}; no other output was touched"


# Failures of the machine or the file system that are no bug: errno -> (what, exit code).
_OS_FAILURES = {
    errno.ENOSPC: ("disk full", EXIT_JOB_FAILED),
    errno.EDQUOT: ("disk quota exceeded", EXIT_JOB_FAILED),
    errno.EFBIG: ("file too large for the file system", EXIT_JOB_FAILED),
    errno.EIO: ("I/O error", EXIT_JOB_FAILED),
    errno.EACCES: ("permission denied", EXIT_BAD_INPUT),
    errno.EPERM: ("operation not permitted", EXIT_BAD_INPUT),
    errno.EROFS: ("read-only file system", EXIT_BAD_INPUT),
    errno.EISDIR: ("is a directory", EXIT_BAD_INPUT),
    errno.ENOTDIR: ("not a directory", EXIT_BAD_INPUT),
    errno.ENOENT: ("no such file or directory", EXIT_BAD_INPUT),
    errno.ENAMETOOLONG: ("file name too long", EXIT_BAD_INPUT),
    errno.EMFILE: ("too many open files", EXIT_JOB_FAILED),
}


def _os_failure(err: OSError) -> tuple[str, int] | None:
    if err.errno not in _OS_FAILURES:
        return None
    what, code = _OS_FAILURES[err.errno]
    where = f"{err.filename}: " if err.filename else ""
    full = err.errno in (errno.ENOSPC, errno.EDQUOT)
    hint = " (free space and run again; the previous outputs were kept)" if full else ""
    return f"{where}cannot write or read: {what}{hint}", code


def _reported(err: BaseException, verbose: int = 0) -> tuple[str, int]:
    """The one line and the exit code of a failure; "internal error" is left for bugs (with a
    hint to ask for the traceback, unless it was asked for and printed above)."""
    if isinstance(err, SensaovError):
        return str(err), err.exit_code
    if isinstance(err, MemoryError):
        return "out of memory (a film, spp or buffer too large for this machine)", EXIT_JOB_FAILED
    known = _os_failure(err) if isinstance(err, OSError) else None
    if known is not None:
        return known
    detail = str(err).strip().splitlines()
    hint = "" if verbose >= 2 else " (run with -vv for the traceback)"
    return (
        f"internal error: {type(err).__name__}: {detail[-1] if detail else ''}{hint}",
        EXIT_JOB_FAILED,
    )


def reports_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn any failure into one line on stderr and a documented exit code (traceback at -vv).

    Library errors become an exit code here, and only here. Every line ends saying which
    outputs this process replaced (none, or which), so a farm's log tells what is on disk.
    """

    @wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        verbose = click.get_current_context().find_root().params.get("verbose", 0)
        interrupts.install()
        earlier = len(atomic.replaced())  # one process may run several commands (tests)
        try:
            interrupts.check()  # a signal that came while the interpreter was importing
            return command(*args, **kwargs)
        except (KeyboardInterrupt, Exception) as err:
            interrupts.install(raising=False)  # a second signal must not break the report
            # After a stop, whatever it made a library raise (Dr.Jit wraps it in a
            # RuntimeError, zipfile complains of a cut write) is the stop, not a failure.
            if isinstance(err, KeyboardInterrupt) or interrupts.requested():
                _stopped(earlier)
            if verbose >= 2:
                traceback.print_exc()
            _fail(*_reported(err, verbose), earlier)

    return wrapper
