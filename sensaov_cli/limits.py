"""Bounds on what a command reads and allocates: regular files of capped size, a memory budget.

A FIFO blocks its reader until a writer comes (forever, on a farm), ``/dev/zero`` never ends
and a 6 kB PNG may declare 40000x40000 pixels: so every file sensaov opens is checked here
first, and every setting that sizes an allocation is compared with the memory budget before
anything is allocated. Each refusal is one line naming the file or the setting.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import resource
import stat
from dataclasses import dataclass
from pathlib import Path

from sensaov_cli.errors import InputFileError, MemoryBudgetError, SensaovError

MEMORY_BUDGET_VARIABLE = "SENSAOV_MEMORY_BUDGET"
BUDGET_SHARE = 0.75  # of the memory this process may use: the rest is the OS's and Dr.Jit's
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([KMGT]?)(?:i?B)?\s*$", re.IGNORECASE)
_KINDS = (
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def regular_file(
    path: Path, what: str, *, where: str | None = None, error: type[SensaovError] = InputFileError
) -> int:
    """The size of ``path`` if it is a regular file; else ``error`` (located at ``where``,
    default the path), saying what the file is instead."""
    reading = _Reading(path, what, where, error)
    try:
        return reading.checked(os.stat(path), None)
    except OSError as exc:
        raise reading.unreadable(exc) from None


def read_regular(
    path: Path,
    what: str,
    *,
    cap: int,
    where: str | None = None,
    error: type[SensaovError] = InputFileError,
) -> bytes:
    """The bytes of ``path``, checked as :func:`regular_file` on the open descriptor itself (a
    file swapped for a FIFO after a check cannot block: it is opened non-blocking), and never
    more than ``cap`` bytes read (a file that grows while it is read is refused too)."""
    reading = _Reading(path, what, where, error)
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
        try:
            reading.checked(os.fstat(descriptor), cap)
            os.set_blocking(descriptor, True)
            with os.fdopen(descriptor, "rb", closefd=False) as stream:
                data = stream.read(cap + 1)
        finally:
            os.close(descriptor)
    except OSError as exc:
        raise reading.unreadable(exc) from None
    if len(data) > cap:
        raise reading.refusal(f" grew past {size_text(cap)} while it was read")
    return data


@dataclass(frozen=True)
class _Reading:
    """A file being checked: what a refusal calls it, where it is located, what it raises."""

    path: Path
    what: str
    where: str | None
    error: type[SensaovError]

    def refusal(self, said: str, hint: str | None = None, *, before: str = "") -> SensaovError:
        subject = f"{self.what} {self.path}" if self.where else f"the {self.what}"
        return self.error(f"{before}{subject}{said}", where=self.where or str(self.path), hint=hint)

    def checked(self, info: os.stat_result, cap: int | None) -> int:
        if stat.S_ISDIR(info.st_mode):
            raise self.refusal(" is a directory, not a file")
        if not stat.S_ISREG(info.st_mode):
            kind = next((name for test, name in _KINDS if test(info.st_mode)), "no regular file")
            raise self.refusal(
                f" is {kind}, not a regular file",
                "sensaov reads regular files only: a FIFO would block it, a device never end",
            )
        if cap is not None and info.st_size > cap:
            raise self.refusal(
                f" is {size_text(info.st_size)}, over the {size_text(cap)} sensaov reads",
                f"is this the right file? a {self.what} is far smaller",
            )
        return info.st_size

    def unreadable(self, exc: OSError) -> SensaovError:
        if exc.errno == errno.ENOENT:
            return self.refusal(" does not exist")
        if exc.errno == errno.ELOOP:
            return self.refusal(" is a loop of symbolic links")
        return self.refusal(f": {exc.strerror or exc}", before="cannot read ")


def memory_budget() -> tuple[int, str]:
    """Bytes a command may plan to allocate, and where that figure comes from: its variable when
    set, else 3/4 of the least of the machine's memory, the cgroup's limit (a container, a Slurm
    allocation) and the address-space limit (``ulimit -v``)."""
    text = os.environ.get(MEMORY_BUDGET_VARIABLE)
    if text is not None:
        match = _SIZE.match(text)  # 8G, 512M, 1.5G, 1000000: binary units
        if match is None:
            raise MemoryBudgetError(
                f"{MEMORY_BUDGET_VARIABLE}={text!r} is not a size",
                hint="write bytes or a number with K, M, G or T, e.g. 8G",
            )
        size = int(float(match.group(1)) * _UNITS[match.group(2).upper()])
        return size, f"{MEMORY_BUDGET_VARIABLE}={text.strip()}"
    limits = {"the machine's memory": os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")}
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        limits["ulimit -v"] = soft
    with contextlib.suppress(OSError):
        cgroup = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if cgroup.isdigit():
            limits["the cgroup's memory.max"] = int(cgroup)
    source, least = min(limits.items(), key=lambda item: item[1])
    return int(least * BUDGET_SHARE), f"3/4 of {source}; {MEMORY_BUDGET_VARIABLE} sets it"


def resident_bytes() -> int:
    """The memory this process holds now (its resident set): what a check of a long command's
    next allocations adds them to, so that its peak stays within the budget. The peak so far
    where /proc is absent (macOS: ru_maxrss counts bytes there)."""
    with contextlib.suppress(OSError, ValueError, IndexError):
        pages = int(Path("/proc/self/statm").read_text().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if os.uname().sysname == "Darwin" else peak * 1024


def check_memory(
    need: int,
    what: str,
    *,
    setting: str | None = None,
    where: str | None = None,
    hint: str | None = None,
) -> None:
    """Refuse, before allocating, ``what`` needing ``need`` bytes over the budget; the line
    says the need and the budget, and names the ``setting`` ("key = value") that asks for it
    (``hint``: what to do instead of lowering it)."""
    budget, source = memory_budget()
    if need <= budget:
        return
    message = f"{what} needs about {size_text(need)}, over the memory budget of {size_text(budget)}"
    instead = hint or (f"lower {setting.split(' = ')[0]}" if setting else "")
    raise MemoryBudgetError(
        f"{setting}: {message} ({source})" if setting else f"{message} ({source})",
        where=where,
        hint=f"{instead + ', or ' if instead else ''}raise {MEMORY_BUDGET_VARIABLE} on a machine "
        "with more memory",
    )


def size_text(count: float) -> str:
    """A byte count as people read it: 200.0 MiB, 1.5 GiB."""
    value, unit = float(count), "bytes"
    for larger in ("KiB", "MiB", "GiB", "TiB"):
        if value < 1024:
            break
        value, unit = value / 1024, larger
    return f"{value:.0f} bytes" if unit == "bytes" else f"{value:.1f} {unit}"
