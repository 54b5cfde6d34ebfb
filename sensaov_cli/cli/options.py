"""What the commands share: arguments, options, the exit-code epilog and the error reporting.

After rasterio's ``rio/options.py``: a command takes its common parameters from here, so
``--json`` or the job argument read the same in every ``--help``.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import select
import sys
import traceback
from collections.abc import Callable, Iterator
from functools import partial, wraps
from pathlib import Path
from typing import Any

import click

from sensaov_cli import interrupts
from sensaov_cli.errors import EXIT_BAD_INPUT, EXIT_JOB_FAILED, EXIT_MEANINGS, SensaovError
from sensaov_cli.outputs import atomic
from sensaov_cli.vocabulary import AGGREGATES, DEFAULT_AGGREGATE, UNTRUSTED_MODES, WEIGHTS

# The end of every --help, from the one table of exit codes in errors.py.
EXIT_CODES_EPILOG = "\b\nExit codes:\n" + "".join(
    f"  {code}  {meaning}\n" for code, meaning in EXIT_MEANINGS.items()
)


class FilePath(click.Path):
    """A path argument that refuses the empty string: Python reads ``''`` as the current folder,
    so ``sensaov run ''`` (an unset shell variable, quoted) would blame the folder instead."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and not value.strip():
            self.fail("the path is empty (an unset variable?)", param, ctx)
        return super().convert(value, param, ctx)


job_argument = click.argument("job", type=FilePath(path_type=Path))
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
    default=DEFAULT_AGGREGATE,
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
untrusted_option = click.option(
    "--untrusted",
    type=click.Choice(UNTRUSTED_MODES),
    default="apart",
    show_default=True,
    help="apart: objects and types add up trusted gradients only, the rest shown apart; "
    "include: mix them in, marked (docs/encoding.md, 'Trusted numbers').",
)
# Each command gives these their own help.
objective_option = partial(click.option, "--objective", multiple=True)
top_option = partial(click.option, "--top", default=8, show_default=True, type=click.IntRange(1))
buffer_option = partial(click.option, "--buffer", "buffer_path", type=FilePath(path_type=Path))
output_option = partial(click.option, "-o", "--output", type=FilePath(path_type=Path))
force_option = partial(click.option, "--force", is_flag=True)


class OneLineGroup(click.Group):
    """The ``sensaov`` group: click's usage errors (a missing argument, a value out of range, an
    unknown command) end as every other failure does, in one line and a documented exit code
    (click prints three: the usage, a pointer to --help, the error)."""

    def main(self, args: list[str] | None = None, standalone_mode: bool = True, **rest: Any) -> Any:  # type: ignore[override]
        try:
            result = super().main(args, standalone_mode=False, **rest)
        except click.exceptions.NoArgsIsHelpError as exc:  # bare 'sensaov': its help, exit 0
            click.echo(exc.ctx.get_help() if exc.ctx else "")
            result = 0
        except click.ClickException as exc:
            if not standalone_mode:
                raise
            where = exc.ctx.command_path if isinstance(exc, click.UsageError) and exc.ctx else ""
            hint = f" (see '{where} --help')" if where else ""
            _fail(f"{where}: {exc.format_message()}{hint}" if where else exc.format_message(),
                  exc.exit_code)  # fmt: skip
        except OSError as exc:  # --help into a closed pipe
            _fail(*_reported(exc))
        if not standalone_mode:
            return result
        sys.exit(result if isinstance(result, int) else 0)


def echo_json(data: Any, **dumps: Any) -> None:
    """``data`` as indented JSON on stdout (``dumps``: more ``json.dumps`` arguments)."""
    click.echo(json.dumps(data, indent=2, **dumps))


def _fail(message: str, code: int, earlier: int = 0) -> None:
    written = _written(earlier)
    if code == EXIT_BAD_INPUT and not written.endswith(_NOTHING_REPLACED):
        code = EXIT_JOB_FAILED  # exit 2 promises nothing was written: this job got further
    try:
        click.echo(f"sensaov: error: {_one_line(message)}{written}", err=True)
    except (OSError, ValueError, UnicodeError):
        _silence(2)  # stderr is gone: the exit code is all that can still be said
    sys.exit(code)


def _silence(descriptor: int) -> None:
    """Point a standard stream whose reader went away at /dev/null, so that the interpreter's
    last flush on exit does not print a second complaint (Python's advice for EPIPE)."""
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, descriptor)
    os.close(null)


def _stopped(earlier: int) -> None:
    """Report a stop and end the process at once with 130/143, skipping interpreter
    finalisation: a stop that arrived while Dr.Jit initialised could else end the process by
    SIGINT (exit -2) after the line was printed. Temporaries are removed; nothing else is open."""
    code = interrupts.stop_exit_code()
    with contextlib.suppress(SystemExit):
        _fail(f"stopped by {interrupts.signal_name()}", code, earlier)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


_NOTHING_REPLACED = "; no output was replaced"


def _one_line(text: str) -> str:
    """A message on one line whatever it quotes (a name with a newline from a stranger's file)."""
    return " ".join(text.split("\n")).replace("\r", " ")


def _written(earlier: int) -> str:
    """What this command replaced before it stopped (the process's ledger after its first
    ``earlier`` entries); everything else is as it was."""
    atomic.remove_temporaries()
    done = atomic.replaced()[earlier:]
    if not done:
        return _NOTHING_REPLACED
    named = dict.fromkeys(map(str, done))  # a file replaced twice (view's saves) named once
    return f"; replaced: {', '.join(named)}; no other output was touched"


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
    errno.EPIPE: ("broken pipe: the program reading the output exited first", EXIT_JOB_FAILED),
}


def _os_failure(err: OSError) -> tuple[str, int] | None:
    if err.errno not in _OS_FAILURES:
        return None
    what, code = _OS_FAILURES[err.errno]
    if err.errno == errno.EPIPE:  # stdout's reader (| head) went away; stderr is another case
        _silence(1)
        return f"stdout: {what}", code
    full = err.errno in (errno.ENOSPC, errno.EDQUOT)
    hint = " (free space and run again; the previous outputs were kept)" if full else ""
    if not err.filename and _stdout_refuses(err):
        _silence(1)  # else the interpreter's last flush complains a second time
        return f"stdout: cannot write the result: {what}", code
    where = f"{err.filename}: " if err.filename else ""
    return f"{where}cannot write or read: {what}{hint}", code


def _stdout_refuses(err: OSError) -> bool:
    """Whether it is stdout that cannot take what was printed (``> /dev/full``): an error raised
    by ``click.echo`` writing to descriptor 1, or one that flushing stdout repeats (a buffered
    writer keeps what it could not write)."""
    trace = err.__traceback__
    while trace is not None:
        frame = trace.tb_frame
        stream = frame.f_locals.get("file")
        with contextlib.suppress(OSError, ValueError, AttributeError):  # a stream without an fd
            if frame.f_code.co_name == "echo" and stream is not None and stream.fileno() == 1:
                return True
        trace = trace.tb_next
    try:
        sys.stdout.flush()
    except OSError as again:
        return again.errno == err.errno
    except (ValueError, AttributeError):  # closed or absent: not what failed here
        return False
    return False


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
    detail = str(err).strip().splitlines() or [""]
    hint = "" if verbose >= 2 else " (run with -vv for the traceback)"
    return f"internal error: {type(err).__name__}: {detail[-1]}{hint}", EXIT_JOB_FAILED


def _require_stdout() -> None:
    """A closed stdout (``>&-``) cannot take the result: refused before any work (exit 2).
    Closed standard descriptors get /dev/null first: else the first file the command opens
    becomes descriptor 1, and whatever prints (a library's log) writes into it."""
    closed = []
    for descriptor in (0, 1, 2):  # in order: open() takes the lowest free one, this one
        try:
            os.fstat(descriptor)
        except OSError:
            closed.append(descriptor)
            os.open(os.devnull, os.O_RDWR)
    from sensaov_cli.errors import OutputError

    if 1 in closed or sys.stdout is None:
        raise OutputError(
            "stdout is closed: the result could not be printed",
            hint="send it to a file or to /dev/null instead of closing it",
        )
    # A pipe whose reader exited polls as an error: found now, not after hours of rendering.
    poller = select.poll()
    poller.register(1, select.POLLOUT)
    if any(events & select.POLLERR for _, events in poller.poll(0)):
        raise OutputError(
            "stdout is a pipe nobody reads any more: the result could not be printed",
            hint="check the command after the '|'",
        )


@contextlib.contextmanager
def stdout_to_stderr() -> Iterator[None]:
    """While a command's work runs, what anything prints (a Python objective's ``print``, a
    library's own output) goes to stderr: stdout carries the result only (``run --json``)."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def reports_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn any failure into one line on stderr and a documented exit code (traceback at -vv),
    here and only here. Every line ends saying which outputs this process replaced (none, or
    which), so a farm's log tells what is on disk."""

    @wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        verbose = click.get_current_context().find_root().params.get("verbose", 0)
        interrupts.install()
        earlier = len(atomic.replaced())  # one process may run several commands (tests)
        try:
            interrupts.raise_if_stopped()  # a signal that came while the interpreter was importing
            _require_stdout()
            result = command(*args, **kwargs)
            # The work is done and printed: a stop from here on is only recorded (the process
            # exits 0), one that came while the result was printed still says what was written.
            interrupts.install(raising=False)
            interrupts.raise_if_stopped()
            return result
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


def command(function: Callable[..., Any]) -> click.Command:
    """A ``sensaov`` command: failures reported by :func:`reports_errors`, the exit codes at the
    end of its ``--help``."""
    return click.command(epilog=EXIT_CODES_EPILOG)(reports_errors(function))
