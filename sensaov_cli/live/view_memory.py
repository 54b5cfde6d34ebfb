"""The live view's memory: its kept visibility passes and its requests in flight, in the budget.

A view's request allocates while it traces and paints, and its visibility pass may be kept for
the pick or id map that follows; both are counted against the memory budget
(``SENSAOV_MEMORY_BUDGET``, docs/exit-codes.md) that ``run`` and ``project`` plan with. A
request over the whole budget is refused (HTTP 400, one line) before anything is traced; one
that fits waits while other requests hold the rest (kept passes are dropped first, oldest
first), and is refused with HTTP 503 if they hold it for longer than :data:`WAIT_S`. The
figures are measured bounds (peak RSS above the serving process's, CPU backend), not exact.
"""

from __future__ import annotations

import ctypes
import threading
import time
from collections import OrderedDict
from collections.abc import Hashable, Iterator
from contextlib import contextmanager

from sensaov_cli.errors import RequestError
from sensaov_cli.limits import check_memory, memory_budget
from sensaov_cli.render.loading import TEXEL_BYTES_PER_SAMPLE
from sensaov_cli.views.coverage import VisibilityPass

# One view: the live tracer keeps an object index per sample (Dr.Jit's and numpy's copies, the
# histogram's sort): measured 4.5 to 6.5 bytes a sample; texel channels add UVs (run's figure).
# Per pixel the pass's ranked coverage and the painting (values, display values, masks, RGB,
# encoded image): measured 190 bytes at 1024² and 1 spp.
VIEW_BYTES_PER_SAMPLE = 8
VIEW_BYTES_PER_PIXEL = 224
KEPT_PASSES = 8  # at most, within the budget: a pick or an id map reuses the view's own pass
WAIT_S = 120.0  # a request waits this long at most for others to free the budget


class Busy(RequestError):
    """Other requests hold the budget: try again (HTTP 503)."""

    status = 503


def request_bytes(pixels: int, spp: int, *, with_uv: bool) -> int:
    """What tracing and painting one view of ``pixels`` at ``spp`` allocates at its peak."""
    per_sample = TEXEL_BYTES_PER_SAMPLE if with_uv else VIEW_BYTES_PER_SAMPLE
    return pixels * spp * per_sample + pixels * VIEW_BYTES_PER_PIXEL


def pass_bytes(visibility: VisibilityPass) -> int:
    """What a kept pass holds: its arrays."""
    coverage = visibility.coverage
    arrays = [coverage.pixel, coverage.obj, coverage.count, visibility.rank_index,
              visibility.rank_coverage, visibility.sample_uv, visibility.sample_object]  # fmt: skip
    return sum(a.nbytes for a in arrays if a is not None)


def return_freed_memory() -> None:
    """Let freed arrays go back to the system (glibc): by default glibc raises its mmap
    threshold each time a large block is freed, so later arrays of that size come from the
    heap and stay resident after they are freed, and a server that paints view after view,
    from several threads, grows past what it holds. A fixed threshold (glibc's initial one)
    keeps the resident memory that of the ledger. Elsewhere nothing is changed."""
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc: its allocator has no such knob
        return
    mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD)


_M_MMAP_THRESHOLD = -3  # glibc's malloc.h
_MMAP_THRESHOLD = 128 << 10  # glibc's default, made fixed


class MemoryLedger:
    """The bytes the requests in flight reserved and the passes kept, never over the budget."""

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._reserved = 0
        self._kept: OrderedDict[Hashable, tuple[VisibilityPass, int]] = OrderedDict()
        self._own = threading.local()  # the bytes this thread's request reserved

    @property
    def kept_bytes(self) -> int:
        return sum(size for _, size in self._kept.values())

    @contextmanager
    def reserved(self, need: int, setting: str) -> Iterator[None]:
        """Hold ``need`` bytes of the budget for the block; ``setting`` names what asks for
        them in a refusal."""
        what = "the view's visibility pass and painting"
        check_memory(need, what, setting=setting)  # over the whole budget: never, say so now
        deadline = time.monotonic() + WAIT_S
        with self._changed:
            while True:
                budget, _ = memory_budget()
                while self._kept and self._reserved + self.kept_bytes + need > budget:
                    self._kept.popitem(last=False)
                if self._reserved + self.kept_bytes + need <= budget:
                    break
                left = deadline - time.monotonic()
                if left <= 0 or not self._changed.wait(left):
                    raise Busy(
                        f"{setting}: other views hold the memory budget "
                        f"({self._reserved >> 20} MiB in flight)",
                        hint="try again when they are answered",
                    )
            self._reserved += need
        self._own.bytes = need
        try:
            yield
        finally:
            self._own.bytes = 0
            with self._changed:
                self._reserved -= need
                self._changed.notify_all()

    def kept(self, key: Hashable) -> VisibilityPass | None:
        with self._changed:
            found = self._kept.get(key)
            if found is None:
                return None
            self._kept.move_to_end(key)
            return found[0]

    def keep(self, key: Hashable, visibility: VisibilityPass) -> None:
        """Keep ``visibility`` for later requests if the budget has room (the oldest kept
        passes go first); a pass that does not fit is not kept. A pass traced by this thread's
        request is already held in its reservation: it needs room only once that ends."""
        size = pass_bytes(visibility)
        extra = size - min(size, getattr(self._own, "bytes", 0))
        with self._changed:
            budget, _ = memory_budget()
            self._kept.pop(key, None)
            while self._kept and (
                len(self._kept) >= KEPT_PASSES or self._reserved + self.kept_bytes + extra > budget
            ):
                self._kept.popitem(last=False)
            if self._reserved + self.kept_bytes + extra <= budget:
                self._kept[key] = (visibility, size)
