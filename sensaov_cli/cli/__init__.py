"""The ``sensaov`` command line: the click group and its commands, with no logic of their own.

One module per command, named after its verb; what the commands share is in
:mod:`sensaov_cli.cli.options`. Each command calls its wiring in :mod:`sensaov_cli.pipeline` and
prints what it returns; heavy imports happen inside, so ``sensaov --help`` starts instantly.
"""

from __future__ import annotations

import os
import sys

from sensaov_cli import interrupts

# The ``sensaov`` entry point imports this module first: record signals before click loads
# (see ``interrupts.install``); each command acts on them when it starts.
interrupts.install(raising=False)

import click  # noqa: E402 - after the signal handlers, on purpose

from sensaov_cli import __version__  # noqa: E402
from sensaov_cli.cli import (  # noqa: E402
    check,
    merge,
    params,
    project,
    rank,
    report,
    run,
    schema,
    sunburst,
    validate,
    view,
)
from sensaov_cli.cli.options import EXIT_CODES_EPILOG, OneLineGroup  # noqa: E402


@click.group(
    cls=OneLineGroup,
    epilog=EXIT_CODES_EPILOG,
    context_settings={"help_option_names": ["-h", "--help"]},
)
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


# Each command module holds one command, named after it (cli/run.py: run).
for module in (validate, schema, params, run, project, check, merge, rank, sunburst, report, view):
    main.add_command(getattr(module, module.__name__.rpartition(".")[2]))


def console() -> None:
    """The ``sensaov`` executable: :func:`main`, then the process ends at once.

    The interpreter's finalisation tears down Dr.Jit, LLVM and every module, with SIGTERM
    already back at its default: a farm's SIGTERM then would kill a finished process. So the
    streams are flushed and the process exits with the command's code, as a stop does
    (``options._stopped``), after sensaov's own exit handler (its scratch folders). A flush that
    fails (stdout on a full disk, a closed pipe) takes the ordinary exit, which reports it.
    In-process callers (tests) use :func:`main`.
    """
    from sensaov_cli.outputs.atomic import remove_temporaries

    try:
        main(prog_name="sensaov")
    except SystemExit as done:
        code = 0 if done.code is None else done.code
        if not isinstance(code, int):
            raise  # a message for Python to print
        remove_temporaries()
        try:
            for stream in (sys.stdout, sys.stderr):
                if stream is not None:  # None: started with that descriptor closed
                    stream.flush()
        except (OSError, ValueError):
            raise done from None
        os._exit(code)


__all__ = ["console", "main"]
