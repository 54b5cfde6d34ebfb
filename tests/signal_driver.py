"""Run the sensaov command line and send it a signal at a chosen point (for test_signals.py).

usage: python signal_driver.py POINT SIGNAL DELAY STAMP sensaov-arguments...

POINT is where the signal is sent from:
  stage:PREFIX  a timer started when a progress stage whose name starts with PREFIX begins
                (load_s, primal_s, backward_, view_) fires after DELAY seconds, from another
                thread, so the signal lands in the middle of the stage's work (a kernel);
                should the work be over sooner, the first output file the command then begins
                is held until the signal has come (sent from there): the signal always lands
                before anything is written, however fast the machine;
  write:N       inside the N-th output file's writer (counting from 1), after it wrote a part;
  rename        just before the first rename of a set of outputs (signals are held there);
  written       just after the first set of outputs was renamed into place (the command is
                finishing: printing what it wrote).
SIGNAL is TERM, INT, HUP or KILL. The CLOCK_MONOTONIC time the signal was sent is written to STAMP,
so the test can measure how long the process took to exit after it.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sensaov_cli import interrupts

interrupts.install(raising=False)  # as __main__ does, before the imports

import sensaov_cli.outputs.atomic as atomic  # noqa: E402
from sensaov_cli.cli import main  # noqa: E402
from sensaov_cli.progress import Progress  # noqa: E402

POINT, SIGNAL, DELAY, STAMP = sys.argv[1], sys.argv[2], float(sys.argv[3]), Path(sys.argv[4])
SIGNUM = {
    "TERM": signal.SIGTERM,
    "INT": signal.SIGINT,
    "HUP": signal.SIGHUP,
    "KILL": signal.SIGKILL,
}[SIGNAL]


def send() -> None:
    STAMP.write_text(repr(time.monotonic()))
    os.kill(os.getpid(), SIGNUM)


def patch_stage(prefix: str) -> None:
    original, write = Progress.stage, atomic._written_temporary
    timer: list[threading.Timer] = []  # started by the first matching stage only
    sent = threading.Lock()

    def send_once() -> None:
        if sent.acquire(blocking=False):
            send()

    @contextmanager
    def stage(self: Progress, name: str, label: str) -> Iterator[None]:
        if name.startswith(prefix) and not timer:
            timer.append(threading.Timer(DELAY, send_once))
            timer[0].start()
        with original(self, name, label):
            yield

    def held(path: Path, writer: Callable[[Path], None]) -> Path:
        if timer:
            timer[0].cancel()
            send_once()
            while not interrupts.requested():  # the handler runs (and raises) in this wait
                time.sleep(0.001)
        return write(path, writer)

    Progress.stage = stage  # type: ignore[method-assign]
    atomic._written_temporary = held  # type: ignore[assignment]


def patch_write(n: int) -> None:
    original = atomic._written_temporary
    count = [0]

    def written(path: Path, write: Callable[[Path], None]) -> Path:
        count[0] += 1
        if count[0] != n:
            return original(path, write)

        def cut(tmp: Path) -> None:
            with open(tmp, "wb") as stream:
                stream.write(b"part of a file")
            send()
            write(tmp)

        return original(path, cut)

    atomic._written_temporary = written  # type: ignore[assignment]


def patch_rename() -> None:
    original = os.replace
    sent = [False]

    def replace(src: Any, dst: Any) -> None:
        if not sent[0] and str(src).endswith(atomic.TEMPORARY_SUFFIX):
            sent[0] = True
            send()
        original(src, dst)

    os.replace = replace  # type: ignore[assignment]


def patch_written() -> None:
    original = atomic.atomic_write_all

    def write_all(files: list[tuple[Path, Callable[[Path], None]]]) -> None:
        original(files)
        send()

    atomic.atomic_write_all = write_all  # type: ignore[assignment]
    atomic.atomic_write = lambda path, write: write_all([(path, write)])  # type: ignore


if POINT.startswith("stage:"):
    patch_stage(POINT.split(":", 1)[1])
elif POINT.startswith("write:"):
    patch_write(int(POINT.split(":", 1)[1]))
elif POINT == "rename":
    patch_rename()
elif POINT == "written":
    patch_written()
else:
    raise SystemExit(f"unknown point {POINT!r}")
main(args=sys.argv[5:], prog_name="sensaov")
