"""Progress on stderr, one line per finished stage, with its wall time.

Plain lines rather than redrawn bars: sensaov runs on render farms and in Makefiles, where logs
are files and a carriage-return animation turns into noise. In the ``farm`` style (the default
when stderr is not a terminal) every finished stage is also followed by a ``Progress: N%`` line,
the pattern farm managers (Deadline, OpenCue, Tractor) parse; N counts finished stages out of
the stages planned (:meth:`Progress.plan`), so it never goes back.

Progress is for people: when stderr is closed, or its reader went away (``2>&1 | head``), the
lines are dropped and the work goes on; only the exit code and the outputs tell then.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager


class Progress:
    def __init__(self, quiet: bool = False, stream=None, style: str = "plain"):  # noqa: ANN001
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet or self.stream is None  # None: Python started with stderr closed
        self.farm = style != "plain"  # auto: unless stderr is a terminal
        if style == "auto":
            with contextlib.suppress(AttributeError, ValueError):  # no isatty, or a closed stream
                self.farm = not self.stream.isatty()
        self.timings: dict[str, float] = {}
        self._planned = 0
        self._done = 0
        self._shown = -1

    def note(self, message: str) -> None:
        self._print(f"sensaov: {message}")

    def _print(self, text: str, end: str = "\n") -> None:
        if self.quiet:
            return
        try:
            print(text, end=end, file=self.stream, flush=True)
        except (OSError, ValueError, AttributeError):  # broken pipe, closed or absent stream
            self.quiet = True

    def plan(self, stages: int) -> None:
        """``stages`` more stages are to come (a farm's percentage counts them)."""
        self._planned = self._done + stages

    def skip(self, stages: int) -> None:
        """``stages`` planned stages turned out unnecessary: count them as done, silently."""
        if stages > 0:
            self._done += stages
            self._report()

    @contextmanager
    def stage(self, name: str, label: str) -> Iterator[None]:
        """Time the block as ``name`` (recorded in provenance) and report ``label`` on stderr."""
        self._print(f"sensaov: {label} ...", end="")
        start = time.perf_counter()
        try:
            yield
        except BaseException:
            self._print(" failed")
            raise
        elapsed = time.perf_counter() - start
        self.timings[name] = round(elapsed, 4)
        self._print(f" {elapsed:.2f} s")
        self._done += 1
        self._report()

    def _report(self) -> None:
        if self.quiet or not self.farm or self._planned <= 0:
            return
        percent = min(100, 100 * self._done // self._planned)
        if percent > self._shown:
            self._shown = percent
            self._print(f"Progress: {percent}%")
