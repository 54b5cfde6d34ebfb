"""Arrays by parameter key, each made only when first asked for (format 4).

A ranking needs each parameter's sums (buffer/param_sums.py), not its arrays: a reader that
asks for lazy arrays slices no packed member per key and reads a texture's member the first
time a view reads it. The same member serves every key that shares it (one texture, several
copies), so copies stay the same array, read once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import numpy as np

Resolve = Callable[[str], np.ndarray]  # key -> its array, as the file stores it
Check = Callable[[str, Any], np.ndarray]  # (key, array) -> the array to keep, or raise
Guard = Callable[[], AbstractContextManager[object]]  # turns a late read's error into the file's


class LazyArrays(Mapping[str, np.ndarray]):
    """The arrays of ``order``'s keys: each resolved, checked and kept on first access.
    ``guard`` wraps each resolution (the reader's error translation)."""

    def __init__(self, order: Sequence[str], resolve: Resolve, guard: Guard = nullcontext) -> None:
        self._order = tuple(order)
        self._known = frozenset(self._order)
        self._resolve, self._guard = resolve, guard
        self._checks: tuple[Check, ...] = ()
        self._made: dict[str, np.ndarray] = {}

    def _with(self, checks: tuple[Check, ...], guard: Guard) -> LazyArrays:
        out = LazyArrays(self._order, self._resolve, guard)
        out._checks = checks
        return out

    def checked(self, check: Check) -> LazyArrays:
        """These arrays, each passed through ``check`` when it is made."""
        return self._with((*self._checks, check), self._guard)

    def guarded(self, guard: Guard) -> LazyArrays:
        """These arrays, each made inside ``guard``."""
        return self._with(self._checks, guard)

    def load_all(self) -> LazyArrays:
        """Make every array now (an eager reader validates the whole file)."""
        for key in self._order:
            self[key]
        return self

    def __getitem__(self, key: str) -> np.ndarray:
        found = self._made.get(key)
        if found is not None:
            return found
        if key not in self._known:
            raise KeyError(key)
        with self._guard():
            arr = self._resolve(key)
            for check in self._checks:
                arr = check(key, arr)
        self._made[key] = arr
        return arr

    def __iter__(self) -> Iterator[str]:
        return iter(self._order)

    def __len__(self) -> int:
        return len(self._order)

    def __contains__(self, key: object) -> bool:
        return key in self._known


def each_checked(
    given: Mapping[str, Any], keys: Sequence[str], check: Callable[[str, Any], np.ndarray]
) -> Mapping[str, np.ndarray]:
    """``check`` applied to every array of ``keys``: now, or for lazy arrays as each is made."""
    if isinstance(given, LazyArrays):
        return given.checked(check)
    return {key: check(key, given[key]) for key in keys}
