"""Arrays by parameter key, some read from the file only when first asked for (format 4).

A ranking needs each parameter's sums (buffer/param_sums.py), not its texels: a reader that
asks for lazy arrays gets the packed members at once and a texture's member the first time a
view reads it. The same member serves every key that shares it (one texture, several copies),
so copies stay the same array, read once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import numpy as np

Load = Callable[[], np.ndarray]
Check = Callable[[str, Any], np.ndarray]  # (key, array) -> the array to keep, or raise
Guard = Callable[[], AbstractContextManager[object]]  # turns a late read's error into the file's


class LazyArrays(Mapping[str, np.ndarray]):
    """``ready`` arrays and ``pending`` ones, in ``order``; a pending one is loaded, checked and
    kept on first access. ``guard`` wraps each late load (the reader's error translation)."""

    def __init__(
        self,
        order: Sequence[str],
        ready: Mapping[str, np.ndarray],
        pending: Mapping[str, Load],
        guard: Guard = nullcontext,
    ) -> None:
        self._order = tuple(order)
        self._ready = dict(ready)
        self._pending = dict(pending)
        self._guard = guard
        self._checks: list[Check] = []

    def checked(self, check: Check) -> LazyArrays:
        """These arrays with ``check`` applied: to the ready ones now, to the others on load."""
        out = LazyArrays(self._order, {}, self._pending, self._guard)
        out._checks = [*self._checks, check]
        out._ready = {key: check(key, arr) for key, arr in self._ready.items()}
        return out

    def guarded(self, guard: Guard) -> LazyArrays:
        """These arrays, each late read wrapped in ``guard``."""
        out = self.checked(lambda key, arr: arr)
        out._checks, out._guard = list(self._checks), guard
        return out

    def load_all(self) -> LazyArrays:
        """Read every pending array now (an eager reader validates the whole file)."""
        for key in list(self._pending):
            self[key]
        return self

    def __getitem__(self, key: str) -> np.ndarray:
        found = self._ready.get(key)
        if found is not None:
            return found
        load = self._pending[key]  # KeyError for an unknown key, as a dict would
        with self._guard():
            arr = load()
            for check in self._checks:
                arr = check(key, arr)
        self._ready[key] = arr
        del self._pending[key]
        return arr

    def __iter__(self) -> Iterator[str]:
        return iter(self._order)

    def __len__(self) -> int:
        return len(self._order)

    def __contains__(self, key: object) -> bool:
        return key in self._ready or key in self._pending


def each_checked(
    given: Mapping[str, Any], keys: Sequence[str], check: Callable[[str, Any], np.ndarray]
) -> Mapping[str, np.ndarray]:
    """``check`` applied to every array of ``keys``: now, or for lazy arrays as each is read."""
    if isinstance(given, LazyArrays):
        return given.checked(check)
    return {key: check(key, given[key]) for key in keys}
