"""Timing primitives: interleaved repetitions, synchronised in-process timers, child processes.

The machine is shared, so both sides of a comparison are measured alternately (A, B, A, B, ...)
and every ratio is taken per round, from two measurements seconds apart; the spread of the
ratios over rounds is what is reported as min/max.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Stats:
    """min / median / max of repeated measurements (seconds, bytes or a ratio)."""

    values: tuple[float, ...]

    @property
    def min(self) -> float:
        return min(self.values)

    @property
    def median(self) -> float:
        return statistics.median(self.values)

    @property
    def max(self) -> float:
        return max(self.values)

    @property
    def n(self) -> int:
        return len(self.values)

    @staticmethod
    def of(values: Sequence[float]) -> Stats:
        if not values:
            raise ValueError("no measurements")
        return Stats(tuple(float(v) for v in values))

    def ratio_to(self, other: Stats) -> Stats:
        """Per-round ratios self[i] / other[i] (the two were measured in the same round)."""
        if self.n != other.n:
            raise ValueError("ratios need the same number of rounds on both sides")
        return Stats(tuple(a / b for a, b in zip(self.values, other.values, strict=True)))

    def scaled(self, factor: float) -> Stats:
        return Stats(tuple(v * factor for v in self.values))


def interleave(
    sides: dict[str, Callable[[], float]], rounds: int, warmup: int = 1
) -> dict[str, Stats]:
    """Run every side once per round, in turn; each call returns the time (or size) it measured.

    ``warmup`` untimed rounds come first (they fill the kernel cache and the page cache).
    """
    for _ in range(warmup):
        for measure in sides.values():
            measure()
    results: dict[str, list[float]] = {name: [] for name in sides}
    for _ in range(rounds):
        for name, measure in sides.items():
            results[name].append(measure())
    return {name: Stats.of(values) for name, values in results.items()}


def synced(function: Callable[[], Any]) -> tuple[float, Any]:
    """Wall time of ``function()`` including every Dr.Jit kernel it launched."""
    import drjit as dr

    dr.sync_thread()
    start = time.perf_counter()
    result = function()
    dr.sync_thread()
    return time.perf_counter() - start, result


@dataclass(frozen=True)
class ChildRun:
    seconds: float  # whole-process wall time of the command, start-up included
    max_rss_bytes: int  # the command's own peak resident set
    stdout: str
    stderr: str = ""


class ChildFailed(RuntimeError):
    pass


WRAPPER = str(Path(__file__).with_name("child.py"))


def run_child(command: Sequence[str]) -> ChildRun:
    """Run ``command`` through ``bench/child.py``; its wall time and its own peak RSS.

    The wrapper's own start-up is not in the time: it starts the clock just before it spawns.
    """
    with tempfile.TemporaryDirectory() as scratch:
        report = Path(scratch) / "report.json"
        out, err = Path(scratch) / "stdout", Path(scratch) / "stderr"
        with out.open("w") as stdout, err.open("w") as stderr:
            subprocess.run(
                [sys.executable, WRAPPER, str(report), "--", *command],
                stdout=stdout,
                stderr=stderr,
                check=True,
            )
        result = json.loads(report.read_text())
        if result["returncode"] != 0:
            raise ChildFailed(
                f"{' '.join(command)} exited with {result['returncode']}:\n"
                f"{err.read_text()[-2000:]}"
            )
        return ChildRun(
            result["seconds"], result["max_rss_bytes"], out.read_text(), err.read_text()
        )


def timed_child(command: Sequence[str], record: list[ChildRun]) -> Callable[[], float]:
    """A measurement for :func:`interleave`: runs ``command`` (:func:`run_child`), keeps the
    run in ``record`` and returns its wall time."""

    def measure() -> float:
        child = run_child(command)
        record.append(child)
        return child.seconds

    return measure
