"""Run the sensaov command line and send it a signal at a chosen point (for test_signals.py).

usage: python signal_driver.py POINT SIGNAL STAMP sensaov-arguments...

POINT is where the signal is sent from:
  stage:PREFIX  when the first progress stage whose name starts with PREFIX begins (load_s,
                primal_s, backward_, view_), before its work;
  write:N       inside the N-th output file's writer (counting from 1), after it wrote a part;
  rename        just before the first rename of a set of outputs (signals are held there);
  written       just after the first set of outputs was renamed into place (the command is
                finishing: printing what it wrote);
  pass:PREFIX   held at the start of the second chunk (sub-pass, path chunk or visibility span)
                of the first chunked pass inside a stage whose name starts with PREFIX; the
                chunk limits are lowered so a 16x16 job has several. The signal's raise is
                swallowed there, as inside a Dr.Jit kernel's callback: only the stop checks
                between chunks can end the pass;
  serve         the signal is not sent by the driver (the test sends it while ``view`` waits for
                requests); STAMP receives the server's poll-loop turns begun after it;
  import:NAME   held when the interpreter starts importing module NAME (the command is run as
                ``python -m sensaov_cli``, unpatched: nothing of sensaov is imported before;
                STAMP says 0).
SIGNAL is TERM, INT, HUP or KILL. STAMP receives the number of chunks that began after the
signal (rewritten at each): a prompt stop begins at most one (the chunk the signal landed in),
however slow the machine.
"""

from __future__ import annotations

import os
import runpy
import signal
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

POINT, SIGNAL, STAMP = sys.argv[1], sys.argv[2], Path(sys.argv[3])
SIGNUM = {
    "TERM": signal.SIGTERM,
    "INT": signal.SIGINT,
    "HUP": signal.SIGHUP,
    "KILL": signal.SIGKILL,
}[SIGNAL]


class HoldImport:
    """Sends the signal when the import of module NAME begins (as a finder that finds nothing)."""

    def __init__(self, name: str) -> None:
        self.name = name

    def find_spec(self, name: str, path: Any, target: Any = None) -> None:
        if name == self.name:
            sys.meta_path.remove(self)
            STAMP.write_text("0")
            os.kill(os.getpid(), SIGNUM)


if POINT.startswith("import:"):
    sys.meta_path.insert(0, HoldImport(POINT.split(":", 1)[1]))
    sys.argv = ["sensaov", *sys.argv[4:]]
    runpy.run_module("sensaov_cli", run_name="__main__", alter_sys=True)
    raise SystemExit(0)

from sensaov_cli import interrupts  # noqa: E402

interrupts.install(raising=False)  # as __main__ does, before the imports

import sensaov_cli.outputs.atomic as atomic  # noqa: E402
import sensaov_cli.render.adjoint as adjoint  # noqa: E402
import sensaov_cli.render.visibility as visibility  # noqa: E402
from sensaov_cli.cli import main  # noqa: E402
from sensaov_cli.progress import Progress  # noqa: E402

SENT = [False]
STAGES: list[str] = []  # the names of the progress stages now open


def send() -> None:
    STAMP.write_text("0")
    SENT[0] = True
    os.kill(os.getpid(), SIGNUM)


def counted(chunks: Callable[..., Iterator[Any]], hold: str | None) -> Callable[..., Iterator[Any]]:
    """``chunks`` (a generator of a pass's chunks), counting those begun after the signal; with
    ``hold``, the signal is sent at the second chunk of a pass inside a stage named hold*."""
    after = [0]

    def wrapped(*args: Any) -> Iterator[Any]:
        for index, item in enumerate(chunks(*args)):
            inside = hold is not None and any(name.startswith(hold) for name in STAGES)
            if index == 1 and inside and not SENT[0]:
                try:
                    send()
                except KeyboardInterrupt:  # lost, as when it surfaces in a kernel's callback
                    pass
            if SENT[0]:
                after[0] += 1
                STAMP.write_text(str(after[0]))
            yield item

    return wrapped


def count_chunks(hold: str | None = None) -> None:
    if hold is not None:  # several chunks even in a 16x16 job
        adjoint.SAMPLES_PER_SUBPASS = adjoint.PATH_SAMPLES_PER_PASS = 64
        visibility.SAMPLES_PER_CHUNK = 64
    adjoint.subpasses = counted(adjoint.subpasses, hold)  # type: ignore
    visibility.sample_spans = counted(visibility.sample_spans, hold)  # type: ignore
    original = Progress.stage

    @contextmanager
    def stage(self: Progress, name: str, label: str) -> Iterator[None]:
        STAGES.append(name)
        try:
            with original(self, name, label):
                yield
        finally:
            STAGES.remove(name)

    Progress.stage = stage  # type: ignore[method-assign]


def patch_stage(prefix: str) -> None:
    original = Progress.stage

    @contextmanager
    def stage(self: Progress, name: str, label: str) -> Iterator[None]:
        with original(self, name, label):
            if name.startswith(prefix) and not SENT[0]:
                send()
            yield

    Progress.stage = stage  # type: ignore[method-assign]


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


def count_polls() -> None:
    import socketserver

    original = socketserver.BaseServer.service_actions
    turns = [0]

    def service_actions(self: socketserver.BaseServer) -> None:
        if interrupts.requested():
            turns[0] += 1
            STAMP.write_text(str(turns[0]))
        original(self)

    socketserver.BaseServer.service_actions = service_actions  # type: ignore[method-assign]


if POINT == "serve":
    count_polls()
elif POINT.startswith("pass:"):
    count_chunks(POINT.split(":", 1)[1])
else:
    count_chunks()
if POINT.startswith("stage:"):
    patch_stage(POINT.split(":", 1)[1])
elif POINT.startswith("write:"):
    patch_write(int(POINT.split(":", 1)[1]))
elif POINT == "rename":
    patch_rename()
elif POINT == "written":
    patch_written()
elif not POINT.startswith("pass:") and POINT != "serve":
    raise SystemExit(f"unknown point {POINT!r}")
main(args=sys.argv[4:], prog_name="sensaov")
