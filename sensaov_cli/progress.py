"""Progress on stderr, one line per finished stage, with its wall time.

Plain lines rather than redrawn bars: sensaov runs on render farms and in Makefiles, where logs
are files and a carriage-return animation turns into noise. A pass is one Dr.Jit kernel, so
there is no finer-grained fraction to show than the stage itself.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager


class Progress:
    def __init__(self, quiet: bool = False, stream=None):  # noqa: ANN001 - any text stream
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.timings: dict[str, float] = {}

    def note(self, message: str) -> None:
        if not self.quiet:
            print(f"sensaov: {message}", file=self.stream, flush=True)

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
