"""Progress on stderr, one line per finished stage, with its wall time.

Plain lines rather than redrawn bars: sensaov runs on render farms and in Makefiles, where logs
are files and a carriage-return animation turns into noise. In the ``farm`` style (the default
when stderr is not a terminal) every finished stage is also followed by a ``Progress: N%`` line,
the pattern farm managers (Deadline, OpenCue, Tractor) parse; N counts finished stages out of
the stages planned (:meth:`Progress.plan`), so it never goes back.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager


class Progress:
    def __init__(self, quiet: bool = False, stream=None, style: str = "plain"):  # noqa: ANN001
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        if style == "auto":
            style = "plain" if _is_terminal(self.stream) else "farm"
        self.farm = style == "farm"
        self.timings: dict[str, float] = {}
        self._planned = 0
        self._done = 0
        self._shown = -1

    def note(self, message: str) -> None:
        if not self.quiet:
            print(f"sensaov: {message}", file=self.stream, flush=True)

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
        if not self.quiet:
            print(f"sensaov: {label} ...", end="", file=self.stream, flush=True)
        start = time.perf_counter()
        try:
            yield
        except BaseException:
            if not self.quiet:
                print(" failed", file=self.stream, flush=True)
            raise
        elapsed = time.perf_counter() - start
        self.timings[name] = round(elapsed, 4)
        if not self.quiet:
            print(f" {elapsed:.2f} s", file=self.stream, flush=True)
        self._done += 1
        self._report()

    def _report(self) -> None:
        if self.quiet or not self.farm or self._planned <= 0:
            return
        percent = min(100, 100 * self._done // self._planned)
        if percent > self._shown:
            self._shown = percent
            print(f"Progress: {percent}%", file=self.stream, flush=True)


def _is_terminal(stream) -> bool:  # noqa: ANN001 - any text stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False
