"""Which parameters the headline views add up: those the tool stands behind; the rest apart.

A headline view (the ``objects`` and ``types`` layers, ranked objects and types, the sunburst's
rings) sums a group's parameters. One whose gradient is not ``verified`` is a number the tool
cannot stand behind, so under ``untrusted: apart`` (the default) it is left out of its group and
shown apart (its own layer, rows, hatched wedge); ``no_gradient`` adds exactly 0 and stays in;
``untrusted: include`` mixes everything in, with a mark (docs/encoding.md, "Trusted numbers").

Value weighting (θ·∂M/∂θ) scores a parameter valued exactly 0 as 0 whatever its gradient:
:func:`zero_valued` finds them, so views flag them with their raw gradient instead.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import groups
from sensaov_cli.buffer.statistics import hidden_by_zero
from sensaov_cli.vocabulary import Grouping, Trust, Untrusted

# Labels whose numbers a headline view adds up: verified, and no_gradient (exactly 0 anyway).
TRUSTED: tuple[Trust, ...] = ("verified", "no_gradient")
# A group shows the weakest label among its ranked parameters.
_WEAKEST_FIRST: tuple[Trust, ...] = ("suspect", "biased", "unverified", "verified")
_GROUPINGS: tuple[Grouping, ...] = ("param", "object", "type")
# How the part left out of a group is named where one list holds both (sunburst wedges).
APART_SUFFIX = " (untrusted)"


def is_trusted(record: ParamRecord) -> bool:
    return record.trust in TRUSTED


def untrusted_keys(buf: SensitivityBuffer, keys: Sequence[str]) -> tuple[str, ...]:
    """The keys among ``keys`` whose gradient the tool does not stand behind."""
    return tuple(k for k in keys if not is_trusted(buf.param(k)))


def weakest_trust(buf: SensitivityBuffer, keys: Sequence[str]) -> Trust:
    """The label a group of ``keys`` shows: the weakest among its parameters'."""
    labels = {buf.param(k).trust for k in keys}
    return next((label for label in _WEAKEST_FIRST if label in labels), "verified")


def ranked_groups(buf: SensitivityBuffer) -> dict[Grouping, dict[str, tuple[str, ...]]]:
    """Groups by parameter, object and type over the parameters a gradient flows to; a group
    that had parameters and lost them all to ``no_gradient`` is dropped."""
    flowing = [p.key for p in buf.params if p.trust != "no_gradient"]
    ranked: dict[Grouping, dict[str, tuple[str, ...]]] = {}
    for by in _GROUPINGS:
        every = groups(buf, None, by)
        if len(flowing) == len(buf.params):  # nothing lost: the groups are every group
            ranked[by] = every
            continue
        kept = groups(buf, flowing, by)
        ranked[by] = {name: keys for name, keys in kept.items() if keys or not every[name]}
    return ranked


@dataclass(frozen=True)
class SplitGroups:
    """Groups (objects or types) split by trust: what a headline view adds up, and the rest."""

    kept: dict[str, tuple[str, ...]]  # name -> keys a headline score adds up
    left_out: dict[str, tuple[str, ...]]  # name -> untrusted keys, shown apart (never empty)


def split_groups(
    buf: SensitivityBuffer, grouped: Mapping[str, Sequence[str]], mode: Untrusted
) -> SplitGroups:
    """``grouped`` split by trust under ``mode``: under ``apart`` a group left with no trusted
    key is dropped from ``kept``, while one that never had a key keeps its empty row."""
    if mode == "include":
        return SplitGroups({name: tuple(keys) for name, keys in grouped.items()}, {})
    kept: dict[str, tuple[str, ...]] = {}
    left_out: dict[str, tuple[str, ...]] = {}
    for name, keys in grouped.items():
        apart = untrusted_keys(buf, keys)
        trusted = tuple(k for k in keys if k not in apart)
        if trusted or not keys:
            kept[name] = trusted
        if apart:
            left_out[name] = apart
    return SplitGroups(kept, left_out)


def apart_name(name: str, taken: Mapping[str, object]) -> str:
    """``name`` + APART_SUFFIX, made unique against ``taken`` (an object may be named so)."""
    candidate = name + APART_SUFFIX
    while candidate in taken:
        candidate += "'"
    return candidate


@dataclass(frozen=True)
class ZeroValued:
    """A parameter that value weighting hides: θ is exactly 0 where ∂M/∂θ is not."""

    key: str
    owners: tuple[str, ...]
    hidden: int  # components with θ = 0 and ∂M/∂θ ≠ 0
    size: int  # components in all
    raw_signed: float  # Σ ∂M/∂θ over the parameter: the response per unit of θ


def zero_valued(
    buf: SensitivityBuffer, objective: str, keys: Sequence[str] | None = None
) -> dict[str, ZeroValued]:
    """The parameters among ``keys`` (default all) whose value-weighted score hides a gradient."""
    found = {}
    sums = buf.sums
    for key in buf.keys if keys is None else keys:
        record = buf.param(key)
        if sums is not None:  # stored by the writer (buffer/npz.py): no texel is read
            hidden, raw = sums.hidden(objective, key)
        else:
            hidden, raw = hidden_by_zero(buf.value(key), buf.grad(objective, key))
        if hidden:
            found[key] = ZeroValued(key, record.owners, hidden, math.prod(record.shape), raw)
    return found
