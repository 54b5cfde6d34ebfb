"""Each parameter's sums, stored beside its arrays (format 4): what a ranking reads, not texels.

Per parameter and objective, the sufficient statistics of its contributions c for both weights
(Σc², Σc; the count is the parameter's size) and what value weighting hides (the components with
θ = 0 and ∂M/∂θ ≠ 0, and then Σ ∂M/∂θ); per parameter, the mean of its value. The writer computes
them from the arrays with the very functions the queries use on arrays, so a ranking read from
the sums is the ranking computed from the arrays, to the last bit (tests/test_param_sums.py).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

# The columns of an objective's sums member, one row per parameter (docs/buffer-format.md).
COLUMNS = ("sum_sq_value", "total_value", "sum_sq_raw", "total_raw", "hidden", "raw_signed")
VALUE_MEANS_MEMBER = "value_means"


def sums_member(objective_index: int) -> str:
    """The npz member holding an objective's per-parameter sums (P, 6) float64."""
    return f"sums_{objective_index:03d}"


@dataclass(frozen=True)
class KeyStats:
    """The sufficient statistics of one parameter's contributions c for one objective."""

    sum_sq: float  # Σ c²
    total: float  # Σ c
    count: int  # number of components


def stats_of(grad: np.ndarray, value: np.ndarray | None) -> KeyStats:
    """Σc², Σc and the count of c = value·grad (or grad, without a value)."""
    if not grad.any():  # an untouched texture (no gradient): one cheap pass, no float64 copy
        return KeyStats(sum_sq=0.0, total=0.0, count=grad.size)
    c = (
        grad.ravel().astype(np.float64)
        if value is None
        else np.multiply(grad.ravel(), value.ravel(), dtype=np.float64)
    )
    return KeyStats(sum_sq=float(c @ c), total=float(c.sum()), count=c.size)


def hidden_by_zero(value: np.ndarray, grad: np.ndarray) -> tuple[int, float]:
    """Components with θ = 0 where ∂M/∂θ ≠ 0, and Σ ∂M/∂θ when there are any (else 0.0)."""
    hidden = int(np.count_nonzero((value == 0) & (grad != 0)))
    return hidden, float(grad.astype(np.float64).sum()) if hidden else 0.0


def mean_value(value: np.ndarray) -> float | None:
    """One number for a value array (a colour, a texture): its mean; None when it is empty."""
    return float(value.astype("float64").mean()) if value.size else None


@dataclass(frozen=True, eq=False)
class ParamSums:
    """The sums of every parameter (``keys``, buffer order): per objective a (P, 6) table."""

    keys: tuple[str, ...]
    tables: Mapping[str, np.ndarray]  # objective -> (P, len(COLUMNS)) float64
    value_means: np.ndarray  # (P,) float64; 0.0 for an empty value
    _row: Mapping[str, int] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_row", {key: i for i, key in enumerate(self.keys)})

    def stats(self, objective: str, key: str, weight: str, count: int) -> KeyStats:
        row = self.tables[objective][self._row[key]]
        first = 0 if weight == "value" else 2
        return KeyStats(sum_sq=float(row[first]), total=float(row[first + 1]), count=count)

    def hidden(self, objective: str, key: str) -> tuple[int, float]:
        row = self.tables[objective][self._row[key]]
        return int(row[4]), float(row[5])

    def mean(self, key: str, size: int) -> float | None:
        return float(self.value_means[self._row[key]]) if size else None


def sums_of(
    keys: Sequence[str],
    values: Mapping[str, np.ndarray],
    grads: Mapping[str, Mapping[str, np.ndarray]],
) -> ParamSums:
    """The sums computed from the arrays (copies sharing their arrays are summed once)."""
    tables = {}
    for objective, per_key in grads.items():
        done: dict[tuple[int, int], tuple[float, ...]] = {}
        rows = []
        for key in keys:
            grad, value = per_key[key], values[key]
            pair = (id(grad), id(value))
            if pair not in done:
                by_value, raw = stats_of(grad, value), stats_of(grad, None)
                hidden, raw_signed = hidden_by_zero(value, grad)
                done[pair] = (by_value.sum_sq, by_value.total, raw.sum_sq, raw.total,
                              float(hidden), raw_signed)  # fmt: skip
            rows.append(done[pair])
        tables[objective] = np.array(rows, np.float64).reshape(len(keys), len(COLUMNS))
    means = [mean_value(values[key]) for key in keys]
    value_means = np.array([0.0 if m is None else m for m in means], np.float64)
    return ParamSums(tuple(keys), tables, value_means)


def check_sums(sums: ParamSums, keys: Sequence[str], objectives: Sequence[str]) -> str | None:
    """What is wrong with ``sums`` for a buffer of ``keys`` and ``objectives``; None if nothing."""
    if tuple(sums.keys) != tuple(keys) or sorted(sums.tables) != sorted(objectives):
        return "parameter sums do not match the parameters and objectives"
    shapes = {(len(keys), len(COLUMNS))} | {(len(keys),)}
    arrays = [*sums.tables.values(), sums.value_means]
    if any(a.shape not in shapes or a.dtype != np.float64 for a in arrays):
        return "parameter sums have the wrong shape or type"
    if not all(np.isfinite(a).all() for a in arrays):
        return "parameter sums hold NaN or infinity"
    return None


def sums_members(sums: ParamSums, objectives: Sequence[str]) -> dict[str, np.ndarray]:
    """The npz members that store ``sums`` (one per objective, and the value means)."""
    members = {sums_member(j): sums.tables[name] for j, name in enumerate(objectives)}
    return members | {VALUE_MEANS_MEMBER: sums.value_means}


def sums_from_members(
    keys: Sequence[str],
    objectives: Sequence[str],
    read: Callable[[str, tuple[int, ...]], np.ndarray],
) -> tuple[ParamSums, set[str]]:
    """The sums a file stores, and the member names read; ``read(name, shape)`` reads one
    float64 member of that declared shape."""
    tables = {
        name: read(sums_member(j), (len(keys), len(COLUMNS))) for j, name in enumerate(objectives)
    }
    means = read(VALUE_MEANS_MEMBER, (len(keys),))
    names = {sums_member(j) for j in range(len(objectives))} | {VALUE_MEANS_MEMBER}
    return ParamSums(tuple(keys), tables, means), names
