"""The sensitivity buffer: dM/dθ for every selected scene parameter, per objective (§2).

One reverse-mode pass per objective fills it; every view afterwards is a re-projection of the
stored buffer, never a second differentiation. Its file format is buffer/npz.py's, which
validates what it reads; the records here trust their types.
"""

from __future__ import annotations

import hashlib
import json
import math
import uuid
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import InitVar, dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from sensaov_cli.buffer.statistics import ParamSums, Statistics
from sensaov_cli.errors import BufferContentError, NonFiniteGradientError, UnknownNameError
from sensaov_cli.vocabulary import Estimator, Trust

# Two-sided 95 % points of Student's t by degrees of freedom (seeds − 1), for a repair's own seeds.
_T_975 = {1: 12.71, 2: 4.30, 3: 3.18, 4: 2.78, 5: 2.57, 6: 2.45, 7: 2.36, 8: 2.31, 9: 2.26,
          10: 2.23, 15: 2.13, 20: 2.09, 30: 2.04}  # fmt: skip


@dataclass(frozen=True)
class Repair:
    """How one parameter's stored gradient was computed by finite differences, where Mitsuba's
    reverse mode is known wrong (docs/verification.md, "Repairs"; render/verify/repair.py). It
    keeps every seed's estimate, whose spread gives the gradient's standard error and its sign's
    significance, and the reverse-mode gradient it replaced (the one forward mode is dual to)."""

    reason: str  # why the reverse-mode gradient was not kept: its label and note
    step: float  # relative step: ε = step · max(1, |θ_c|) per component
    spp: tuple[int, ...]  # samples per pixel of each seed's renders
    seeds: tuple[int, ...]  # one per estimate
    # (flat index, +1 or -1) of components differenced one-sided, away from a bound
    one_sided: tuple[tuple[int, int], ...]
    estimates: Mapping[str, np.ndarray]  # objective -> (seeds, components) float64
    reverse: Mapping[str, np.ndarray]  # objective -> (components,) the gradient it replaced
    seconds: float  # wall time of its renders

    def __post_init__(self) -> None:
        count = len(self.seeds)
        _require(count >= 1 and len(self.spp) == count, "a repair needs seeds, spp for each")
        _require(self.step > 0 and math.isfinite(self.step), f"repair step {self.step!r}")
        _require(min(self.spp) >= 1, f"repair spp {self.spp!r}")
        sizes = {np.shape(e)[1:] for e in self.estimates.values()}
        sizes |= {np.shape(r) for r in self.reverse.values()}
        _require(len(sizes) == 1 and len(next(iter(sizes))) == 1, "repair arrays differ in size")
        _require(sorted(self.estimates) == sorted(self.reverse), "repair objectives differ")
        for name, estimates in self.estimates.items():
            _require(np.shape(estimates)[0] == count, f"repair of {name!r}: one row per seed")
            _require(bool(np.isfinite(estimates).all()), f"repair of {name!r}: not finite")
        _require(
            all(0 <= i < self.components and sign in (1, -1) for i, sign in self.one_sided),
            f"one_sided {self.one_sided!r}: (index, +1 or -1) pairs within the parameter",
        )

    @property
    def components(self) -> int:
        return int(np.shape(next(iter(self.reverse.values())))[0]) if self.reverse else 0

    def mean(self, objective: str) -> np.ndarray:
        return np.asarray(self.estimates[objective]).mean(axis=0)

    @property
    def has_error(self) -> bool:
        """Whether its own seeds give a standard error (a shard's share may be one seed: its
        merge has them all, and batch statistics beside)."""
        return len(self.seeds) >= 2

    def stderr(self, objective: str) -> np.ndarray:
        """Per component, the standard error of the mean over seeds (needs has_error)."""
        rows = np.asarray(self.estimates[objective])
        return rows.std(axis=0, ddof=1) / math.sqrt(len(rows))

    def signed_error(self, objective: str, weights: np.ndarray) -> float:
        """Standard error of Σ_c w_c g_c (w = θ for value-weighted sums, ones for raw)."""
        sums = np.asarray(self.estimates[objective]) @ weights.astype(np.float64).ravel()
        return float(sums.std(ddof=1) / math.sqrt(len(sums)))

    def norm_error(self, objective: str, weights: np.ndarray) -> float:
        """Standard error of ‖w · g‖ to first order: each seed's projection on the mean (the
        linearisation the batch statistics use, buffer/statistics.py)."""
        rows = np.asarray(self.estimates[objective]) * weights.astype(np.float64).ravel()
        mean = rows.mean(axis=0)
        norm = float(np.linalg.norm(mean))
        if norm == 0:
            return 0.0
        projections = rows @ mean / norm
        return float(projections.std(ddof=1) / math.sqrt(len(projections)))

    def significant(self, signed: float, error: float) -> bool:
        """Whether |signed| is beyond noise: Student's t at 95 % with seeds − 1 dof (the next
        tabulated dof below)."""
        dof = max(len(self.seeds) - 1, 1)
        t = _T_975[max(d for d in _T_975 if d <= dof)] if dof <= 30 else 1.96
        return abs(signed) > t * error


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise BufferContentError(message)


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
    definition: dict[str, Any]  # the job's objective entry, as JSON
    value: float
    grad_seed: int

    def __post_init__(self) -> None:
        # As the file stores them: a record saves and loads back equal (tuples become lists).
        object.__setattr__(
            self, "definition", _json_copy(self.definition, f"objective {self.name!r}: definition")
        )
        object.__setattr__(self, "value", float(self.value))


def _json_copy(data: Any, what: str) -> Any:
    try:
        return json.loads(json.dumps(data, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise BufferContentError(f"{what} is not JSON-able: {exc}") from exc


def _frozen_array(given: Any, shape: tuple[int, ...], what: str) -> tuple[np.ndarray, int]:
    """A read-only, C-contiguous float32 copy of ``given`` and its count of NaN/inf components."""
    arr = np.asarray(given)
    if arr.shape != shape:
        raise BufferContentError(f"{what} has shape {arr.shape}; the record says {shape}")
    arr = np.array(arr, dtype=np.float32, order="C", copy=True)
    arr.flags.writeable = False
    return arr, int(arr.size - np.count_nonzero(np.isfinite(arr)))


def _check_unique(kind: str, names: Sequence[str]) -> None:
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise BufferContentError(f"{kind} {name!r} appears twice")
        seen.add(name)


def _check_keys(kind: str, given: Iterable[str], known: Sequence[str], missing: str = "") -> None:
    """``given`` names only ``known``; every one of them if ``missing`` (formatted with the name
    it lacks) is given."""
    given = set(given)
    extra = sorted(given - set(known))
    if extra:
        raise BufferContentError(f"{kind} for undeclared names: {', '.join(map(repr, extra))}")
    for name in known:
        if missing and name not in given:
            raise BufferContentError(missing.format(name))


@dataclass(frozen=True, eq=False, repr=False)
class SensitivityBuffer:
    """Per objective, dM/dθ for every selected parameter, with values, owners and provenance.

    Construction copies every array to a read-only C-contiguous float32 array and refuses an
    inconsistent buffer or a NaN/inf gradient, so a stored buffer is always complete and finite.
    With ``_copy_arrays=False`` the arrays are taken as given: the reader's, checked as it read
    them, or those of a buffer already built.
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
    # each parameter's sums as the file stores them: rankings read them, not texels
    sums: ParamSums | None = None
    _by_key: Mapping[str, ParamRecord] = field(init=False)
    _by_name: Mapping[str, ObjectiveRecord] = field(init=False)
    _copy_arrays: InitVar[bool] = True

    def __post_init__(self, _copy_arrays: bool) -> None:
        set_ = object.__setattr__
        set_(self, "provenance", _json_copy(self.provenance, "provenance"))
        _check_unique("object", self.objects)
        set_(self, "objects", tuple(sorted(self.objects)))
        _check_unique("parameter key", [p.key for p in self.params])
        _check_unique("objective", [o.name for o in self.objectives])
        known_objects = set(self.objects)
        for p in self.params:
            unknown = [o for o in p.owners if o not in known_objects]
            _require(not unknown, f"parameter {p.key!r} is owned by unknown objects {unknown}")
        set_(self, "_by_key", MappingProxyType({p.key: p for p in self.params}))
        set_(self, "_by_name", MappingProxyType({o.name: o for o in self.objectives}))
        if _copy_arrays:
            set_(self, "values", self._copied_values())
            set_(self, "grads", self._copied_grads())
        set_(self, "values", MappingProxyType(self.values))
        set_(
            self, "grads", MappingProxyType({n: MappingProxyType(g) for n, g in self.grads.items()})
        )
        statistics = self.statistics  # a header names its batch values' objectives
        if statistics is not None and sorted(statistics.objective_values) != sorted(self._by_name):
            raise BufferContentError("batch values: objectives differ")
        self._check_repairs()
        set_(self, "repairs", MappingProxyType(dict(self.repairs)))

    def _copied_values(self) -> dict[str, np.ndarray]:
        _check_keys("values", self.values, self.keys, "parameter {!r} has no value")
        values = {}
        for p in self.params:
            values[p.key], bad = _frozen_array(self.values[p.key], p.shape, f"value of {p.key!r}")
            if bad:
                raise BufferContentError(f"value of {p.key!r} has {bad} components NaN or infinite")
        return values

    def _copied_grads(self) -> dict[str, Mapping[str, np.ndarray]]:
        names = [o.name for o in self.objectives]
        _check_keys("gradients", self.grads, names, "objective {!r} has no gradients")
        grads: dict[str, Mapping[str, np.ndarray]] = {}
        for name in names:
            given, copied = self.grads[name], {}
            missing = f"objective {name!r} has no gradient for {{!r}}"
            _check_keys(f"gradients of {name!r}", given, self.keys, missing)
            for p in self.params:
                what = f"gradient of {name!r} of {p.key!r}"
                copied[p.key], bad = _frozen_array(given[p.key], p.shape, what)
                if bad:
                    raise NonFiniteGradientError(name, p.key, bad, copied[p.key].size)
            grads[name] = copied
        return grads

    def _check_repairs(self) -> None:
        _check_keys("repairs", self.repairs, self.keys)
        names = sorted(o.name for o in self.objectives)
        for p in self.params:
            repair = self.repairs.get(p.key)
            if repair is None:
                if p.estimator == "finite-difference":
                    raise BufferContentError(
                        f"parameter {p.key!r} is repaired but has no repair record"
                    )
            elif p.estimator not in ("finite-difference", "mixed"):
                raise BufferContentError(
                    f"parameter {p.key!r} has a repair record but estimator {p.estimator!r}"
                )
            elif sorted(repair.estimates) != names:
                raise BufferContentError(f"repair of {p.key!r}: objectives differ")
            elif repair.components != int(np.prod(p.shape)):
                raise BufferContentError(f"repair of {p.key!r} has the wrong size")

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


# --- identity: every buffer run or merge writes carries a fresh random buffer_id and its
# run_version (JobSpec.run_hash) in its provenance; every output made from it records both, so a
# command reading outputs together refuses to mix two states (docs/buffer-format.md, "Identity").

BUFFER_ID = "buffer_id"
RUN_VERSION = "run_version"
# What every output made from a buffer records: the job_hash is that of the job that made the
# output (project's job may differ from run's in cameras and channels).
STAMP_BUFFER = "sensaov/buffer_id"
STAMP_RUN = "sensaov/run_version"
STAMP_JOB = "sensaov/job_hash"


def new_buffer_id() -> str:
    """A fresh id for a buffer about to be written (random: two runs never share one)."""
    return uuid.uuid4().hex[:16]


def buffer_id(buf: SensitivityBuffer) -> str:
    return provenance_id(buf.provenance)


def provenance_id(provenance: dict[str, Any]) -> str:
    """The buffer's id; a buffer without one is named by a hash of its provenance (which holds
    its creation time and timings, so two runs still differ)."""
    recorded = provenance.get(BUFFER_ID)
    if isinstance(recorded, str) and recorded:
        return recorded
    text = json.dumps(provenance, sort_keys=True, default=str)
    return "legacy-" + hashlib.sha256(text.encode()).hexdigest()[:16]


def run_version(buf: SensitivityBuffer) -> str | None:
    """The job version the buffer was made from, or None for a buffer without the field."""
    recorded = buf.provenance.get(RUN_VERSION)
    return recorded if isinstance(recorded, str) and recorded else None


def stamp(buf: SensitivityBuffer, job_hash: str) -> dict[str, str]:
    """The attributes an output made from ``buf`` by a job hashing to ``job_hash`` records."""
    return {STAMP_BUFFER: buffer_id(buf), STAMP_RUN: run_version(buf) or "", STAMP_JOB: job_hash}
