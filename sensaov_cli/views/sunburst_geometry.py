"""The sunburst's geometry (paper Fig. 1): rings from the objective out to the parameters.

Ring 0 is the objective, a full disc. With the order ``object,type`` ring 1 holds the objects,
ring 2 each object's parameter types and ring 3 the parameters (keys); ``type,object`` swaps
rings 1 and 2. Siblings split their parent's angle in proportion to their scores' magnitudes
(with l2 or rms a parent's score is not the sum of its children's: "proportional" holds among
siblings, which is what a reader compares). Angles are fractions of a turn, clockwise from the
top; :mod:`sensaov_cli.outputs.sunburst_drawing` draws them.

A ring-1 group holds the trusted parameters only (:mod:`.hierarchy`); the rest of it gets a
hatched sibling ``"<name> (untrusted)"``. As in the rankings, only parameters a gradient flows
to are drawn, a shared parameter sits under each owner, one no object owns under
:data:`SCENE_WIDE`, and a group that scores exactly 0 gets no wedge.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import KeyStats, combine, key_stats, rank
from sensaov_cli.views.hierarchy import (
    Uncertainty,
    ZeroValued,
    apart_name,
    ranked_groups,
    split_groups,
    weakest_trust,
    zero_valued,
)
from sensaov_cli.vocabulary import Aggregate, Order, Trust, Untrusted, Weight

# The object ring's wedge for parameters no object owns (a sensor's, an integrator's): the
# paper's "global exposure that never appears in the frame" must not vanish from the rings.
SCENE_WIDE = "(scene-wide)"

Level = Callable[[SensitivityBuffer, Sequence[str]], dict[str, tuple[str, ...]]]


@dataclass(frozen=True)
class Wedge:
    """One wedge: its ring, its path from ring 1, and its span in fractions of a turn."""

    ring: int  # 0 the objective, 1 the innermost group ring, 3 the parameters
    path: tuple[str, ...]  # names from ring 1 to this wedge; () for the objective
    start: float  # fraction of a turn, clockwise from the top
    stop: float
    score: float  # the aggregate of the wedge's keys
    signed: float  # Σc of its keys: its sign colours the wedge
    trust: Trust  # the weakest label among its keys
    significant: bool | None = None  # sign beyond t standard errors; None: no statistics

    @property
    def label(self) -> str:
        return self.path[-1] if self.path else ""

    @property
    def span(self) -> float:
        return self.stop - self.start


@dataclass(frozen=True)
class Panel:
    """One objective's sunburst: its name, M and wedges, and the keys it leaves out."""

    objective: str
    value: float
    wedges: tuple[Wedge, ...]
    no_gradient: tuple[str, ...]  # no gradient flows: listed under the disc, never drawn
    zero_valued: tuple[ZeroValued, ...] = ()  # θ = 0: no wedge, listed under the disc


def panels(
    buf: SensitivityBuffer,
    objectives: Sequence[str] | None = None,
    *,
    order: Order = "object,type",
    method: Aggregate = "l2",
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
) -> tuple[Panel, ...]:
    """One panel per objective (all of the buffer's when ``objectives`` is None)."""
    names = [o.name for o in buf.objectives] if objectives is None else list(objectives)
    zero = tuple(p.key for p in buf.params if p.trust == "no_gradient")
    return tuple(
        Panel(
            name,
            buf.objective(name).value,
            sunburst_wedges(
                buf, name, order=order, method=method, weight=weight, untrusted=untrusted
            ),
            zero,
            tuple(zero_valued(buf, name).values()) if weight == "value" else (),
        )
        for name in names
    )


def _level(names: Callable[[ParamRecord], tuple[str, ...]]) -> Level:
    """Keys grouped by ``names`` of their records, groups in order of first appearance."""

    def group(buf: SensitivityBuffer, keys: Sequence[str]) -> dict[str, tuple[str, ...]]:
        found = dict.fromkeys(n for k in keys for n in names(buf.param(k)))
        return {n: tuple(k for k in keys if n in names(buf.param(k))) for n in found}

    return group


_LEVELS: dict[str, Level] = {
    "object": _level(lambda p: p.owners or (SCENE_WIDE,)),
    "type": _level(lambda p: (p.type,)),
    "key": _level(lambda p: (p.key,)),
}


def _apart(level: Level, mode: Untrusted) -> Level:
    """``level`` whose groups keep their trusted keys, the rest a sibling ``(untrusted)``."""

    def split(buf: SensitivityBuffer, keys: Sequence[str]) -> dict[str, tuple[str, ...]]:
        grouped = split_groups(buf, level(buf, keys), mode)
        result = dict(grouped.kept)
        for name, left_out in grouped.left_out.items():
            result[apart_name(name, result)] = left_out
        return result

    return split


def sunburst_wedges(
    buf: SensitivityBuffer,
    objective: str,
    *,
    order: Order = "object,type",
    method: Aggregate = "l2",
    weight: Weight = "value",
    untrusted: Untrusted = "apart",
) -> tuple[Wedge, ...]:
    """Every wedge of ``objective``'s sunburst, ring by ring, largest first within a parent."""
    keys = tuple(ranked_groups(buf)["param"])
    rings = _Rings(buf, key_stats(buf, objective, keys, weight=weight), method,
                   Uncertainty.of(buf, objective, method, weight))  # fmt: skip
    first, second = order.split(",")
    levels = [_apart(_LEVELS[first], untrusted), _LEVELS[second], _LEVELS["key"]]
    centre = rings.wedge(keys, 0, (), 0.0, 1.0)
    wedges = [centre]
    _children(rings, centre, keys, levels, wedges)
    return tuple(wedges)


@dataclass(frozen=True)
class _Rings:
    """What every wedge of one sunburst is scored with."""

    buf: SensitivityBuffer
    stats: Mapping[str, KeyStats]
    method: Aggregate
    noise: Uncertainty | None  # None: no statistics, no significance

    def wedge(
        self, keys: Sequence[str], ring: int, path: tuple[str, ...], start: float, stop: float
    ) -> Wedge:
        group = [self.stats[k] for k in keys]
        score, signed = combine(group, self.method), math.fsum(s.total for s in group)
        error = None if self.noise is None else self.noise.error(keys, score)
        return Wedge(ring=ring, path=path, start=start, stop=stop, score=score, signed=signed,
                     trust=weakest_trust(self.buf, keys),
                     significant=None if error is None else error.significant(signed))  # fmt: skip


def _children(
    rings: _Rings, parent: Wedge, keys: Sequence[str], levels: Sequence[Level], out: list[Wedge]
) -> None:
    """Split ``parent``'s span among its groups at the next level, then recurse."""
    if not levels:
        return
    grouped = levels[0](rings.buf, keys)
    magnitudes = {
        name: abs(combine((rings.stats[k] for k in members), rings.method))
        for name, members in grouped.items()
    }
    total = math.fsum(magnitudes.values())
    start = parent.start
    for name, magnitude in rank(magnitudes):
        if magnitude == 0.0:
            continue
        stop = start + parent.span * magnitude / total
        wedge = rings.wedge(grouped[name], parent.ring + 1, (*parent.path, name), start, stop)
        out.append(wedge)
        _children(rings, wedge, grouped[name], levels[1:], out)
        start = stop
