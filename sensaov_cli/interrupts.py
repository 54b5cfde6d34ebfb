"""Ctrl-C, SIGTERM and SIGHUP: stop, and never write outputs after a stop was asked for.

Python runs signal handlers only between bytecodes; during a long Dr.Jit kernel the resulting
KeyboardInterrupt can surface inside a callback and be swallowed. So the handler also records the
request, and every stage that is about to write checks it (:func:`raise_if_stopped`).

Where an exception must not be raised at all (while the interpreter imports click, or Mitsuba's
C++ extension initialises: a KeyboardInterrupt there ends in ``std::terminate``), the handler only
records the request (:func:`deferred`), and the next :func:`raise_if_stopped` acts on it.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

from sensaov_cli.errors import EXIT_HANGUP, EXIT_INTERRUPTED, EXIT_TERMINATED

# The signals that stop a command, with their exit codes. SIGHUP is a stop like the others: the
# outputs stay whole, and the line says so (if anything still reads it).
STOP_SIGNALS: dict[int, int] = {
    signal.SIGINT: EXIT_INTERRUPTED,
    signal.SIGTERM: EXIT_TERMINATED,
    signal.SIGHUP: EXIT_HANGUP,
}

_signal: list[int] = []  # the first stop signal received: a stop was requested
_raising = [False]  # False: record only (start-up, imports); True: also raise
# Blocks of :func:`deferred` now open, in any thread: a server's threads may open them at once,
# and each must not undo another's (a stop then only recorded, for good).
_deferring = [0]
_count_lock = threading.Lock()
_nested = threading.local()  # this thread's open blocks: only the outermost raises at its end


def _stop(signum: int, frame: FrameType | None) -> None:
    if not _signal:
        _signal.append(signum)
    if _raising[0] and not _deferring[0]:
        raise KeyboardInterrupt


def install(*, raising: bool = True) -> None:
    """Make every stop signal unwind as KeyboardInterrupt; ``raising=False`` only records it:
    the command line's first act, before any import that a raised exception could break."""
    _raising[0] = raising
    for signum in STOP_SIGNALS:
        signal.signal(signum, _stop)


def raise_if_stopped() -> None:
    """Raise KeyboardInterrupt if a stop was requested, even if its first raise was lost."""
    if _signal:
        raise KeyboardInterrupt


def requested() -> bool:
    """Whether a stop signal has arrived."""
    return bool(_signal)


def stop_exit_code() -> int:
    """The first stop signal's exit code (SIGINT's for a KeyboardInterrupt with no signal)."""
    return STOP_SIGNALS[(_signal or [signal.SIGINT])[0]]


def signal_name() -> str:
    return signal.Signals((_signal or [signal.SIGINT])[0]).name


@contextmanager
def deferred() -> Iterator[None]:
    """Within the block a stop is only recorded; it is raised right after the block ends (in the
    main thread, where the handler would have raised it; another thread's caller polls
    :func:`requested`)."""
    depth = getattr(_nested, "depth", 0)
    _nested.depth = depth + 1
    with _count_lock:
        _deferring[0] += 1
    try:
        yield
    finally:
        with _count_lock:
            _deferring[0] -= 1
        _nested.depth = depth
    if _raising[0] and not depth and threading.current_thread() is threading.main_thread():
        raise_if_stopped()
