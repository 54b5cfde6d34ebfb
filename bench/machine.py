"""What the numbers were measured on: machine, versions, date."""

from __future__ import annotations

import datetime
import hashlib
import os
import platform
import subprocess
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def memory_total() -> str:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                return f"{int(line.split()[1]) / 2**20:.1f} GiB"
    except OSError:
        pass
    return "unknown"


def source_tree(repo: Path) -> str:
    """The commit the bench ran on (read-only git query), marked when the tree had changes."""
    try:
        done = subprocess.run(
            ["git", "-C", str(repo), "describe", "--always", "--dirty"],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return done.stdout.strip() or "unknown"


def source_digest(repo: Path) -> str:
    """A hash of the package and bench sources, to notice a checkout that changed mid-run
    (every module, subpackages included)."""
    digest = hashlib.sha256()
    for path in sorted([*repo.glob("sensaov_cli/**/*.py"), *repo.glob("bench/*.py")]):
        digest.update(str(path.relative_to(repo)).encode() + path.read_bytes())
    return digest.hexdigest()[:12]


@dataclass(frozen=True)
class RunInfo:
    """What the run itself records: how it was started and what changed while it ran."""

    variant: str
    llvm: str
    load: tuple[float, float]  # 1-minute load average at start and end
    sources: tuple[str, str]  # source_digest at start and end
    wall: float
    command: str


def header(repo: Path, run: RunInfo) -> list[tuple[str, str]]:
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    changed = run.sources[0] != run.sources[1]
    return [
        ("date (UTC)", datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")),
        (
            "machine",
            f"{cpu_model()}, {usable} usable cores of {os.cpu_count()}, {memory_total()} RAM",
        ),
        ("OS", platform.platform()),
        ("Python", platform.python_version()),
        ("mitsuba / drjit", f"{version('mitsuba')} / {version('drjit')}"),
        ("sensaov", f"{version('sensaov')} (tree {source_tree(repo)})"),
        (
            "sources",
            "**changed during the run: figures mix code versions, run again**"
            if changed
            else f"unchanged during the run (digest {run.sources[0]})",
        ),
        ("variant", f"{run.variant}" + (f", libLLVM {run.llvm}" if run.llvm else "")),
        ("load average", f"{run.load[0]:.2f} at start, {run.load[1]:.2f} at end (1-minute)"),
        ("bench wall time", f"{run.wall / 60:.1f} min"),
        ("command", f"`{run.command}`"),
    ]
