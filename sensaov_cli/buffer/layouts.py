"""Where a buffer file keeps its arrays: one member each (formats 1-3), or packed (format 4).

Formats 1-3 hold ``value_{i:06d}`` per parameter and ``grad_{j:03d}_{i:06d}`` (and
``stderr_{j:03d}_{i:06d}``) per objective and parameter. A real interior splits shared BSDFs,
so one image file becomes a texture per owner: the kitchen's 11 images became 40 copies, each
with its value and gradients, 16 of them with no gradient at all (410 MB at 140x80). Format 4 stores

- the values of every parameter that is not a texture packed into one float32 array,
  ``values``, in buffer order, and its gradients likewise in ``grads_{j}`` per objective
  (standard errors in ``stderrs_{j}``): a buffer of 8,000 colours is a handful of members;
- each distinct texture value once (``texture_{t}``: the copies of an image share it), each
  distinct texture gradient once (``texgrad_{g}``), and an all-zero texture gradient not at all
  (null), and standard errors alike (``texstderr_{s}``).

The header's ``storage`` object says where each parameter is (docs/buffer-format.md).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from sensaov_cli.buffer.lazy import LazyArrays
from sensaov_cli.buffer.model import ParamRecord

Arrays = Mapping[str, Mapping[str, np.ndarray]]  # objective -> key -> array


class LayoutError(ValueError):
    """The storage object and the members disagree; the message says how."""


def value_member(param_index: int) -> str:
    """Formats 1-3: the member holding the value of parameter ``param_index``."""
    return f"value_{param_index:06d}"


def grad_member(objective_index: int, param_index: int) -> str:
    """Formats 1-3: the member holding d(objective)/d(parameter)."""
    return f"grad_{objective_index:03d}_{param_index:06d}"


def stderr_member(objective_index: int, param_index: int) -> str:
    """Format 3: the member holding the standard error of a gradient."""
    return f"stderr_{objective_index:03d}_{param_index:06d}"


def per_parameter(
    params: Sequence[ParamRecord],
    objectives: Sequence[str],
    with_stderr: bool,
    array: Callable[[str, tuple[int, ...]], np.ndarray],
) -> tuple[dict[str, np.ndarray], dict[str, dict[str, np.ndarray]], dict | None, set[str]]:
    """Formats 1-3: values, gradients and standard errors (or None), and the members used."""
    used = {value_member(i) for i in range(len(params))}
    values = {p.key: array(value_member(i), p.shape) for i, p in enumerate(params)}
    grads: dict[str, dict[str, np.ndarray]] = {}
    stderr: dict[str, dict[str, np.ndarray]] = {}
    for j, name in enumerate(objectives):
        grads[name] = {p.key: array(grad_member(j, i), p.shape) for i, p in enumerate(params)}
        used |= {grad_member(j, i) for i in range(len(params))}
        if with_stderr:
            stderr[name] = {
                p.key: array(stderr_member(j, i), p.shape) for i, p in enumerate(params)
            }
            used |= {stderr_member(j, i) for i in range(len(params))}
    return values, grads, stderr if with_stderr else None, used


def packed_member(kind: str, objective: int) -> str:
    return f"{kind}_{objective:03d}"  # grads_000, stderrs_000


def texture_member(kind: str, index: int) -> str:
    return f"{kind}_{index:05d}"  # texture_00000, texgrad_00000, texstderr_00000


class _Distinct:
    """Arrays stored once each: equal contents (same shape, same bytes) share one member."""

    def __init__(self, kind: str, members: dict[str, np.ndarray]) -> None:
        self.kind, self.members = kind, members
        self.seen: dict[tuple[tuple[int, ...], bytes], int] = {}
        self.count = 0

    def index(self, array: np.ndarray, keep_zero: bool = False) -> int | None:
        if not keep_zero and not np.any(array):
            return None
        array = np.ascontiguousarray(array, dtype=np.float32)
        digest = hashlib.blake2b(array.data, digest_size=16).digest()
        key = (array.shape, digest)
        if key not in self.seen:
            self.seen[key] = self.count
            self.members[texture_member(self.kind, self.count)] = array
            self.count += 1
        return self.seen[key]


def pack(
    params: Sequence[ParamRecord],
    objectives: Sequence[str],
    values: Mapping[str, np.ndarray],
    grads: Arrays,
    stderr: Arrays | None,
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The header's ``storage`` object and the members that hold every array."""
    members: dict[str, np.ndarray] = {}
    flat = [p for p in params if not p.is_texture]
    members["values"] = _concatenated([values[p.key] for p in flat])
    for j, name in enumerate(objectives):
        members[packed_member("grads", j)] = _concatenated([grads[name][p.key] for p in flat])
        if stderr is not None:
            errors = [stderr[name][p.key] for p in flat]
            members[packed_member("stderrs", j)] = _concatenated(errors)
    textures = _Distinct("texture", members)
    texgrads, texstderrs = _Distinct("texgrad", members), _Distinct("texstderr", members)
    entries: list[dict[str, Any]] = []
    offset = 0
    for p in params:
        if not p.is_texture:
            entries.append({"offset": offset})
            offset += math.prod(p.shape)
            continue
        entry: dict[str, Any] = {
            "value": textures.index(values[p.key], keep_zero=True),
            "grads": [texgrads.index(grads[name][p.key]) for name in objectives],
        }
        if stderr is not None:
            entry["stderrs"] = [texstderrs.index(stderr[name][p.key]) for name in objectives]
        entries.append(entry)
    return {"packed": offset, "params": entries}, members


def _concatenated(arrays: list[np.ndarray]) -> np.ndarray:
    if not arrays:
        return np.zeros(0, np.float32)
    return np.concatenate([np.ravel(a).astype(np.float32, copy=False) for a in arrays])


def unpack(
    storage: Any,
    params: Sequence[ParamRecord],
    objectives: Sequence[str],
    with_stderr: bool,
    array: Callable[[str, tuple[int, ...]], np.ndarray],
    declared: Callable[[str, tuple[int, ...]], None],
) -> tuple[LazyArrays, dict[str, LazyArrays], dict | None, set[str]]:
    """Values, gradients and standard errors (or None) by key, and the member names used.

    ``array(name, shape)`` reads a member, checking its declared shape first; ``declared``
    checks the shape alone. The packed members are read now and every texture member's shape
    checked; a key's array is made, and a texture's member read, when first asked for.
    """
    entries = _entries(storage, params, len(objectives), with_stderr)
    members = _Members(array, int(storage["packed"]))
    kinds = [("grads", "texgrad")] + [("stderrs", "texstderr")] * with_stderr
    members.member("values", (members.size,))  # the packed members exist even if empty
    for kind, _ in kinds:
        for j in range(len(objectives)):
            members.member(packed_member(kind, j), (members.size,))
    at = {p.key: (p.shape, e) for p, e in zip(params, entries, strict=True)}
    for shape, entry in at.values():
        for name in _texture_members(entry):
            if name not in members.names:
                declared(name, shape)
                members.names.add(name)
    keys = list(at)
    values = LazyArrays(keys, lambda key: members.value(at[key][1], at[key][0]))
    found: dict[str, dict[str, LazyArrays]] = {kind: {} for kind, _ in kinds}
    for (kind, texture), field in zip(kinds, ("grads", "stderrs"), strict=False):
        for j, name in enumerate(objectives):

            def resolve(key: str, j: int = j, kind: str = kind, texture: str = texture,
                        field: str = field) -> np.ndarray:  # fmt: skip
                return members.of(at[key][1], field, j, kind, texture, at[key][0])

            found[kind][name] = LazyArrays(keys, resolve)
    stderr = found["stderrs"] if with_stderr else None
    return values, found["grads"], stderr, members.names


def _texture_members(entry: dict[str, Any]) -> list[str]:
    """The members a texture's storage entry names (none for a packed parameter)."""
    if "offset" in entry:
        return []
    names = [texture_member("texture", entry["value"])]
    for field, kind in (("grads", "texgrad"), ("stderrs", "texstderr")):
        names += [texture_member(kind, i) for i in entry.get(field, ()) if i is not None]
    return names


class _Members:
    """Format 4's members as the storage names them: a packed member's slice, or a texture's
    own member, read on first use (all-zero arrays shared, one read-only array per shape)."""

    def __init__(self, array: Callable[[str, tuple[int, ...]], np.ndarray], size: int) -> None:
        self.read, self.size = array, size
        self.names: set[str] = set()
        self.cache: dict[str, np.ndarray] = {}
        self.zeros: dict[tuple[int, ...], np.ndarray] = {}

    def member(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        if name not in self.cache:
            self.cache[name] = self.read(name, shape)
            self.names.add(name)
        return self.cache[name]

    def value(self, entry: dict[str, Any], shape: tuple[int, ...]) -> np.ndarray:
        if "offset" in entry:
            return self._slice("values", entry["offset"], shape)
        return self.member(texture_member("texture", entry["value"]), shape)

    def of(
        self, entry: dict[str, Any], field: str, j: int, kind: str, texture: str,
        shape: tuple[int, ...],
    ) -> np.ndarray:  # fmt: skip
        if "offset" in entry:
            return self._slice(packed_member(kind, j), entry["offset"], shape)
        index = entry[field][j]
        if index is None:  # all zero
            return self.zeros.setdefault(shape, _zeros(shape))
        return self.member(texture_member(texture, index), shape)

    def _slice(self, name: str, start: int, shape: tuple[int, ...]) -> np.ndarray:
        flat = self.member(name, (self.size,))
        return flat[start : start + math.prod(shape)].reshape(shape)


def _zeros(shape: tuple[int, ...]) -> np.ndarray:
    zeros = np.zeros(shape, np.float32)
    zeros.flags.writeable = False
    return zeros


def _entries(
    storage: Any, params: Sequence[ParamRecord], objectives: int, with_stderr: bool
) -> list[dict[str, Any]]:
    """The storage object, checked: the packed parameters tile ``values`` in buffer order."""
    if not isinstance(storage, dict) or set(storage) != {"packed", "params"}:
        raise LayoutError("'storage' must have exactly 'packed' and 'params'")
    entries = storage["params"]
    if not isinstance(entries, list) or len(entries) != len(params):
        raise LayoutError("'storage.params' must have one entry per parameter")
    offset = 0
    for i, (p, entry) in enumerate(zip(params, entries, strict=True)):
        where = f"storage.params[{i}]"
        if not p.is_texture:
            if entry != {"offset": offset}:
                raise LayoutError(f"{where} must be {{'offset': {offset}}}")
            offset += math.prod(p.shape)
            continue
        fields = {"value", "grads"} | ({"stderrs"} if with_stderr else set())
        if not isinstance(entry, dict) or set(entry) != fields:
            raise LayoutError(f"{where} must have exactly {sorted(fields)}")
        if not _index(entry["value"]):
            raise LayoutError(f"{where}.value must be a member index")
        for field in sorted(fields - {"value"}):
            listed = entry[field]
            ok = isinstance(listed, list) and len(listed) == objectives
            if not ok or not all(i is None or _index(i) for i in listed):
                raise LayoutError(f"{where}.{field} must hold an index or null per objective")
    if storage["packed"] != offset or not _index(offset):
        raise LayoutError(f"'storage.packed' must be {offset}, the packed components")
    return entries


def _index(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0
