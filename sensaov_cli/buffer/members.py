"""Reading a buffer file's arrays: each member's declared shape checked before it is read,
its dtype and finiteness after; format 4's texture members on first use when asked (lazy.py),
and its parameter sums (param_sums.py). Every problem raises :class:`LayoutError`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sensaov_cli.buffer.archive import Archive
from sensaov_cli.buffer.layouts import LayoutError, per_parameter, unpack
from sensaov_cli.buffer.lazy import Guard, LazyArrays
from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord
from sensaov_cli.buffer.param_sums import VALUE_MEANS_MEMBER, ParamSums, sums_from_members


def arrays(
    archive: Archive,
    header: dict[str, Any],
    params: list[ParamRecord],
    objectives: list[ObjectiveRecord],
    guard: Guard | None,
) -> tuple[Any, Any, Any, set[str], ParamSums | None]:
    """Values, gradients, standard errors, the members used and (format 4) the sums."""

    def array(name: str, shape: tuple[int, ...]) -> np.ndarray:
        arr = _member(archive, name, shape)
        if arr.dtype.kind != "f" or arr.dtype.itemsize != 4:
            raise LayoutError(f"array {name!r} is {arr.dtype}, not float32")
        if not np.isfinite(arr).all():  # once per member: the model does not count again
            raise LayoutError(f"array {name!r} holds NaN or infinity")
        return arr

    def declared(name: str, shape: tuple[int, ...]) -> None:
        if name not in archive.members:
            raise LayoutError(f"missing array {name!r}")
        declared_shape(archive, name, shape)

    names, with_stderr = [o.name for o in objectives], header.get("statistics") is not None
    if header["format_version"] < 4:
        return (*per_parameter(params, names, with_stderr, array), None)
    storage = header["storage"]
    values, grads, stderr, used = unpack(storage, params, names, with_stderr, array, declared)
    sums: ParamSums | None = None
    sums_used: set[str] = set()
    if VALUE_MEANS_MEMBER in archive.members:  # optional: a writer may leave the sums out
        read = lambda n, s: float64(archive, n, s)  # noqa: E731
        sums, sums_used = sums_from_members([p.key for p in params], names, read)
    if guard is None:  # every member read and checked now
        return (dict(values.load_all()), _loaded(grads), stderr and _loaded(stderr),
                used | sums_used, sums)  # fmt: skip
    values, grads = values.guarded(guard), {n: g.guarded(guard) for n, g in grads.items()}
    if stderr is not None:
        stderr = {n: e.guarded(guard).checked(_nonnegative) for n, e in stderr.items()}
    return values, grads, stderr, used | sums_used, sums


def _loaded(arrays: dict[str, LazyArrays]) -> dict[str, dict[str, np.ndarray]]:
    return {name: dict(each.load_all()) for name, each in arrays.items()}


def _nonnegative(key: str, arr: np.ndarray) -> np.ndarray:
    if not (arr >= 0).all():
        raise LayoutError(f"bad standard error of {key!r}")
    return arr


def _member(archive: Archive, name: str, shape: tuple[int, ...]) -> np.ndarray:
    if name not in archive.members:
        raise LayoutError(f"missing array {name!r}")
    declared_shape(archive, name, shape)
    return archive.array(name)


def float64(archive: Archive, name: str, shape: tuple[int, ...]) -> np.ndarray:
    arr = _member(archive, name, shape)
    if arr.dtype != np.float64:
        raise LayoutError(f"{name!r} is not float64")
    return arr


# The header is a few kB per parameter; a member declaring more is refused before it is read.
_MAX_HEADER_BYTES = 1 << 28


def declared_shape(archive: Archive, name: str, shape: tuple[int, ...] | None) -> None:
    """Check a member's npy header before reading it: its declared shape (for an array) or
    its declared size (for the header), so a forged size cannot allocate memory."""
    declared, dtype = archive.declared(name)
    if shape is None:
        if dtype.itemsize * int(np.prod(declared)) > _MAX_HEADER_BYTES:
            raise LayoutError(f"{name!r} declares {dtype.itemsize} bytes")
    elif tuple(declared) != shape:
        raise LayoutError(
            f"array {name!r} has shape {tuple(declared)}, its record declares {shape}"
        )
