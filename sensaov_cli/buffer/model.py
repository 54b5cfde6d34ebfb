"""The sensitivity buffer: dM/dθ for every selected scene parameter, per objective (§2).

One reverse-mode pass per objective fills it; every view afterwards is a re-projection of the
stored buffer, never a second differentiation. The file is a plain ``.npz`` readable with
``np.load(path, allow_pickle=False)``; its layout (format version 4) is specified in
``docs/buffer-format.md``. This module needs numpy only: loading a buffer never imports Mitsuba.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import InitVar, dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from sensaov_cli.buffer.lazy import LazyArrays, each_checked
from sensaov_cli.buffer.param_sums import ParamSums, check_sums
from sensaov_cli.buffer.record_fields import json_copy, require, shape_tuple, str_tuple
from sensaov_cli.buffer.repairs import Repair
from sensaov_cli.buffer.statistics import Statistics
from sensaov_cli.errors import (
    BufferContentError,
    NonFiniteGradientError,
    UnknownNameError,
)
from sensaov_cli.vocabulary import ESTIMATORS, TRUSTS, Estimator, Trust

FORMAT_NAME = "sensaov-buffer"
FORMAT_VERSION = 4
HEADER_MEMBER = "header"


@dataclass(frozen=True)
class ParamRecord:
    """What the buffer knows about one scene parameter besides its arrays."""

    key: str
    type: str
    owners: tuple[str, ...]
    shape: tuple[int, ...]
    is_texture: bool
    plugin: str
    flags: tuple[str, ...]
    trust: Trust  # docs/verification.md; only "verified" gradients are shown without a mark
    note: str  # why it is not verified: the known reason, or a self-check's figures
    # What produced the stored gradient (docs/verification.md, "Repairs"); "finite-difference"
    # comes with a Repair record in the buffer.
    estimator: Estimator = "reverse"

    @property
    def verified(self) -> bool:
        return self.trust == "verified"

    def __post_init__(self) -> None:
        plain = (type(self.key) is str and self.key != "" and type(self.type) is str
                 and self.type != "" and type(self.plugin) is str and type(self.note) is str
                 and type(self.is_texture) is bool and self.trust in TRUSTS
                 and self.estimator in ESTIMATORS)  # fmt: skip
        if not plain:  # the common case skips the checks that name the field that is wrong
            self._check_fields()
        what = f"parameter {self.key!r}"
        object.__setattr__(self, "owners", str_tuple(self.owners, f"{what}: owners"))
        object.__setattr__(self, "flags", str_tuple(self.flags, f"{what}: flags"))
        object.__setattr__(self, "shape", shape_tuple(self.shape, f"{what}: shape"))

    def _check_fields(self) -> None:
        for name in ("key", "type"):
            value = getattr(self, name)
            if not isinstance(value, str) or value == "":
                raise BufferContentError(f"parameter {name} must be a string")
        what = f"parameter {self.key!r}"
        for name, kind in (("plugin", str), ("note", str), ("is_texture", bool)):
            if not isinstance(getattr(self, name), kind):
                raise BufferContentError(f"{what}: {name} must be a {kind.__name__}")
        if self.trust not in TRUSTS:
            raise BufferContentError(f"{what}: trust {self.trust!r} is not one of {TRUSTS}")
        if self.estimator not in ESTIMATORS:
            raise BufferContentError(
                f"{what}: estimator {self.estimator!r} is not one of {ESTIMATORS}"
            )


@dataclass(frozen=True)
class ExcludedParam:
    """A scene parameter left out of the buffer, and why (``sensaov params`` lists them)."""

    key: str
    reason: str


@dataclass(frozen=True)
class TextureSource:
    """The bitmap file behind a texture parameter; recorded in provenance, not per record."""

    file: str | None
    converted: bool  # an 8-bit texture loaded as float so its texels get gradients


@dataclass(frozen=True)
class ObjectiveRecord:
    """One scalar objective M: how it was defined, its value at the primal, the backward seed."""

    name: str
    definition: dict[str, Any]
    value: float
    grad_seed: int

    def __post_init__(self) -> None:
        require(isinstance(self.name, str) and self.name != "", "objective name must be a string")
        what = f"objective {self.name!r}"
        require(isinstance(self.definition, dict), f"{what}: definition must be a dict")
        object.__setattr__(self, "definition", json_copy(self.definition, f"{what}: definition"))
        require(
            isinstance(self.value, int | float | np.floating) and not isinstance(self.value, bool),
            f"{what}: value must be a number",
        )
        require(math.isfinite(self.value), f"{what}: value M is {self.value}, not finite")
        object.__setattr__(self, "value", float(self.value))
        require(
            isinstance(self.grad_seed, int | np.integer) and not isinstance(self.grad_seed, bool),
            f"{what}: grad_seed must be an integer",
        )
        object.__setattr__(self, "grad_seed", int(self.grad_seed))


def _frozen_array(
    data: Any, shape: tuple[int, ...], what: Callable[[], str], copy: bool, count: bool = True
) -> tuple[np.ndarray, int]:
    """A read-only, C-contiguous float32 copy of ``data`` and its count of NaN/inf components.

    With ``copy=False`` an array that is already native float32 and C-contiguous is frozen in
    place; only the reader asks for that, for arrays nothing else holds. With ``count=False``
    the count is 0: the reader has checked every member it read to be finite already.
    ``what()`` names the array in a message, built only on failure.
    """
    try:
        arr = data if isinstance(data, np.ndarray) else np.asarray(data)
    except (TypeError, ValueError) as exc:
        raise BufferContentError(f"{what()} is not an array: {exc}") from exc
    if arr.dtype.kind not in "fiu":
        raise BufferContentError(f"{what()} has dtype {arr.dtype}; expected real numbers")
    if arr.shape != shape:
        raise BufferContentError(f"{what()} has shape {arr.shape}; the record says {shape}")
    arr = np.array(arr, dtype=np.float32, order="C", copy=True if copy else None)
    arr.flags.writeable = False
    return arr, int(arr.size - np.count_nonzero(np.isfinite(arr))) if count else 0


def _named(what: str, record: ParamRecord) -> Callable[[], str]:
    """``what`` of a parameter, as a message names it (built only when one is needed)."""
    return lambda: f"{what} of {record.key!r}"


def _check_unique(kind: str, names: Sequence[str]) -> None:
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise BufferContentError(f"{kind} {name!r} appears twice")
        seen.add(name)


def _check_no_extra(kind: str, given: Iterable[str], known: Iterable[str]) -> None:
    extra = sorted(set(given) - set(known))
    require(not extra, f"{kind} for undeclared names: {', '.join(map(repr, extra))}")


@dataclass(frozen=True, eq=False, repr=False)
class SensitivityBuffer:
    """Per objective, dM/dθ for every selected parameter, with values, owners and provenance.

    Construction copies every array to a read-only C-contiguous float32 array and refuses an
    inconsistent buffer (:class:`BufferContentError`) or a NaN/inf gradient
    (:class:`NonFiniteGradientError`), so a stored buffer is always complete and finite.
    """

    provenance: dict[str, Any]
    objects: tuple[str, ...]
    params: tuple[ParamRecord, ...]
    objectives: tuple[ObjectiveRecord, ...]
    values: Mapping[str, np.ndarray]
    grads: Mapping[str, Mapping[str, np.ndarray]]
    statistics: Statistics | None = None  # standard errors, from >= 2 batches or shards
    # key -> how its gradient was repaired: every "finite-difference" parameter has one
    repairs: Mapping[str, Repair] = field(default_factory=dict)
    # each parameter's sums as the file stores them (format 4): rankings read them, not texels
    sums: ParamSums | None = None
    _by_key: Mapping[str, ParamRecord] = field(init=False)
    _by_name: Mapping[str, ObjectiveRecord] = field(init=False)
    _copy_arrays: InitVar[bool] = True

    def __post_init__(self, _copy_arrays: bool) -> None:
        set_ = object.__setattr__
        require(isinstance(self.provenance, dict), "provenance must be a dict")
        set_(self, "provenance", json_copy(self.provenance, "provenance"))
        objects = str_tuple(self.objects, "objects")
        _check_unique("object", objects)
        set_(self, "objects", tuple(sorted(objects)))
        set_(self, "params", tuple(self.params))
        set_(self, "objectives", tuple(self.objectives))
        require(all(isinstance(p, ParamRecord) for p in self.params), "params must be ParamRecords")
        require(
            all(isinstance(o, ObjectiveRecord) for o in self.objectives),
            "objectives must be ObjectiveRecords",
        )
        _check_unique("parameter key", [p.key for p in self.params])
        _check_unique("objective", [o.name for o in self.objectives])
        known_objects = set(objects)
        for p in self.params:
            unknown = [o for o in p.owners if o not in known_objects]
            if unknown:
                raise BufferContentError(
                    f"parameter {p.key!r} is owned by unknown objects {unknown}"
                )
        set_(self, "_by_key", MappingProxyType({p.key: p for p in self.params}))
        set_(self, "_by_name", MappingProxyType({o.name: o for o in self.objectives}))
        set_(self, "values", MappingProxyType(self._checked_values(self.values, _copy_arrays)))
        set_(self, "grads", MappingProxyType(self._checked_grads(self.grads, _copy_arrays)))
        if self.statistics is not None:
            self._check_statistics(self.statistics)
        set_(self, "repairs", MappingProxyType(self._checked_repairs(self.repairs)))
        if self.sums is not None:
            problem = check_sums(self.sums, self.keys, [o.name for o in self.objectives])
            require(problem is None, str(problem))

    def _checked_repairs(self, repairs: Mapping[str, Repair]) -> dict[str, Repair]:
        _check_no_extra("repairs", repairs, self._by_key)
        names = sorted(o.name for o in self.objectives)
        for p in self.params:
            repair = repairs.get(p.key)
            if repair is None:
                needed = p.estimator == "finite-difference"
                require(not needed, f"parameter {p.key!r} is repaired but has no repair record")
                continue
            require(isinstance(repair, Repair), f"repair of {p.key!r} must be a Repair")
            require(
                p.estimator in ("finite-difference", "mixed"),
                f"parameter {p.key!r} has a repair record but estimator {p.estimator!r}",
            )
            require(sorted(repair.estimates) == names, f"repair of {p.key!r}: objectives differ")
            size = int(np.prod(p.shape))
            require(repair.components == size, f"repair of {p.key!r} has the wrong size")
        return dict(repairs)

    def _check_statistics(self, statistics: Statistics) -> None:
        require(isinstance(statistics, Statistics), "statistics must be a Statistics")
        names = [o.name for o in self.objectives]
        require(sorted(statistics.stderr) == sorted(names), "statistics: objectives differ")
        require(sorted(statistics.batch_sums) == sorted(names), "batch sums: objectives differ")
        require(
            sorted(statistics.objective_values) == sorted(names), "batch values: objectives differ"
        )
        for name in names:
            sums = statistics.batch_sums[name]
            require(sums.shape[0] == len(self.params), f"batch sums of {name!r}: wrong length")
            given = statistics.stderr[name]
            _check_no_extra(f"standard errors of {name!r}", given, self._by_key)
            if isinstance(given, LazyArrays):
                continue  # the reader checks each array as it reads it (npz.py)
            for p in self.params:
                if p.key not in given:
                    raise BufferContentError(
                        f"objective {name!r} has no standard error for {p.key!r}"
                    )
                arr, bad = _frozen_array(given[p.key], p.shape, _named("standard error", p), False)
                if bad or not (arr >= 0).all():
                    raise BufferContentError(f"bad standard error of {p.key!r}")

    def _checked_values(self, values: Mapping[str, Any], copy: bool) -> Mapping[str, np.ndarray]:
        _check_no_extra("values", values, self._by_key)
        for p in self.params:
            if p.key not in values:
                raise BufferContentError(f"parameter {p.key!r} has no value")

        def check(key: str, given: Any) -> np.ndarray:
            p = self._by_key[key]
            arr, bad = _frozen_array(given, p.shape, _named("value", p), copy, copy)
            if bad:
                raise BufferContentError(f"value of {p.key!r} has {bad} components NaN or infinite")
            return arr

        return each_checked(values, self.keys, check)

    def _checked_grads(self, grads: Mapping[str, Mapping[str, Any]], copy: bool) -> dict[str, Any]:
        _check_no_extra("gradients", grads, self._by_name)
        checked: dict[str, Any] = {}
        for o in self.objectives:
            require(o.name in grads, f"objective {o.name!r} has no gradients")
            given = grads[o.name]
            _check_no_extra(f"gradients of {o.name!r}", given, self._by_key)
            for p in self.params:
                if p.key not in given:
                    raise BufferContentError(f"objective {o.name!r} has no gradient for {p.key!r}")

            def check(key: str, given: Any, name: str = o.name) -> np.ndarray:
                p, what = self._by_key[key], f"gradient of {name!r}"
                arr, bad = _frozen_array(given, p.shape, _named(what, p), copy, copy)
                if bad:
                    raise NonFiniteGradientError(name, p.key, bad, arr.size)
                return arr

            checked[o.name] = MappingProxyType(each_checked(given, self.keys, check))
        return checked

    def __repr__(self) -> str:
        return (
            f"SensitivityBuffer({len(self.objects)} objects, {len(self.params)} parameters, "
            f"objectives {[o.name for o in self.objectives]})"
        )

    @property
    def keys(self) -> tuple[str, ...]:
        """Every parameter key, in buffer order."""
        return tuple(self._by_key)

    def param(self, key: str) -> ParamRecord:
        if key not in self._by_key:
            raise UnknownNameError("parameter", key, self._by_key)
        return self._by_key[key]

    def objective(self, name: str) -> ObjectiveRecord:
        if name not in self._by_name:
            raise UnknownNameError("objective", name, self._by_name)
        return self._by_name[name]

    def value(self, key: str) -> np.ndarray:
        return self.values[self.param(key).key]

    def grad(self, objective: str, key: str) -> np.ndarray:
        return self.grads[self.objective(objective).name][self.param(key).key]

    def reverse_grad(self, objective: str, key: str) -> np.ndarray:
        """The reverse-mode gradient the run computed: for a repaired parameter, the one its
        repair replaced (what forward mode is the dual of), else the stored one."""
        repair = self.repairs.get(self.param(key).key)
        if repair is None:
            return self.grad(objective, key)
        flat = np.asarray(repair.reverse[self.objective(objective).name], np.float32)
        return flat.reshape(self.param(key).shape)

    def types(self) -> tuple[str, ...]:
        """The distinct parameter types, sorted."""
        return tuple(sorted({p.type for p in self.params}))

    def tree(self) -> dict[str, Any]:
        """The parameters as a tree over their dotted keys (§2); leaves are ParamRecords.

        Where a key is both a parameter and the prefix of another ("a.b" and "a.b.c"), the
        parameter sits under the empty name in its node: ``tree["a"]["b"][""]``.
        """
        root: dict[str, Any] = {}
        for record in self.params:
            *parents, leaf = record.key.split(".")
            node = root
            for part in parents:
                child = node.setdefault(part, {})
                if isinstance(child, ParamRecord):
                    child = node[part] = {"": child}
                node = child
            if isinstance(node.get(leaf), dict):
                node[leaf][""] = record
            else:
                node[leaf] = record
        return root
