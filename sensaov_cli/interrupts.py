"""Ctrl-C and SIGTERM: stop, and never write outputs after a stop was asked for.

Python runs signal handlers only between bytecodes; during a long Dr.Jit kernel the resulting
KeyboardInterrupt can surface inside a callback and be swallowed. So the handler also records the
request, and every stage that is about to write checks it (:func:`check`).
"""

from __future__ import annotations

import signal
import threading
from types import FrameType

_requested = threading.Event()


def _stop(signum: int, frame: FrameType | None) -> None:
    _requested.set()
    raise KeyboardInterrupt


def install() -> None:
    """Farms stop jobs with SIGTERM, people with Ctrl-C: both unwind as KeyboardInterrupt."""
    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)


def check() -> None:
    """Raise KeyboardInterrupt if a stop was requested, even if its first raise was lost."""
    if _requested.is_set():
        raise KeyboardInterrupt
