"""Whether a buffer's top objects are resolved: their signs and their order, per objective.

``render.until`` (run) samples until they are; ``merge`` estimates how many more shards would
resolve what is still open. Both read the ranking ``sensaov rank --by object`` prints (the
views' own function, at its default score), so what they call the top is what rank shows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.statistics import interval_factor, pooled_stderr
from sensaov_cli.views.hierarchy import Uncertainty, ranked_groups, rankings, split_groups
from sensaov_cli.vocabulary import DEFAULT_AGGREGATE, Aggregate, Weight


@dataclass(frozen=True)
class Open:
    """One number of the top that is not resolved: an object's sign or the order of two."""

    objective: str
    name: str  # the object, or "a > b" for the order of two consecutive ones
    what: str  # "sign", "order", "noisy" (heavy-tailed batches) or "no error" (one batch)
    mean: float  # the signed sum, or the difference of the two scores
    stderr: float
    reason: str = ""

    def describe(self) -> str:
        if self.what in ("noisy", "no error"):
            why = f": {self.reason}" if self.reason else ""
            return f"{self.objective}: {self.name} ({self.what}{why})"
        return (
            f"{self.objective}: {self.what} of {self.name} ({self.mean:+.3g} ± {self.stderr:.2g})"
        )

    def more_batches(self, batches: int) -> int | None:
        """An estimate of the batches (or shards) of the same size to add before this resolves,
        from the 1/sqrt(n) law of the standard error at the current t factor; None when the
        mean is 0 or the spread cannot say (noisy, one batch)."""
        if self.what in ("noisy", "no error") or self.mean == 0.0 or batches < 2:
            return None
        factor = interval_factor(batches)
        needed = batches * (factor * self.stderr / abs(self.mean)) ** 2
        return max(1, math.ceil(needed) - batches)


@dataclass(frozen=True)
class Resolution:
    """What the top ``top`` objects of every objective resolve, from ``batches`` batches."""

    top: int
    batches: int
    resolved: tuple[tuple[str, str], ...]  # (objective, object) with a resolved sign
    open: tuple[Open, ...]

    @property
    def done(self) -> bool:
        return not self.open


def resolution(buf: SensitivityBuffer, top: int) -> Resolution:
    """The top ``top`` objects of every objective: which signs and which consecutive orders are
    resolved (outside the Student-t 95 % interval of the batches, and not heavy-tailed)."""
    method: Aggregate = DEFAULT_AGGREGATE  # the score `rank` ranks by when none is asked for
    weight: Weight = "value"
    batches = 1 if buf.statistics is None else buf.statistics.batches
    resolved: list[tuple[str, str]] = []
    found: list[Open] = []
    for ranking in rankings(buf, by="object", top=top, method=method, weight=weight):
        objective = ranking.objective
        rows = ranking.rows[:top]
        noise = Uncertainty.of(buf, objective, method, weight)
        if noise is None:
            found += [Open(objective, r.name, "no error", r.signed, math.inf) for r in rows]
            continue
        groups = split_groups(buf, ranked_groups(buf)["object"], ranking.untrusted).kept
        scores = []
        for row in rows:
            per_batch, signed = noise.batch_values(groups[row.name], row.score)
            scores.append(per_batch)
            se = float(pooled_stderr(signed, noise.spp))
            if row.noisy is not None:
                found.append(Open(objective, row.name, "noisy", row.signed, se, row.noisy))
            elif row.resolved:
                resolved.append((objective, row.name))
            else:
                found.append(Open(objective, row.name, "sign", row.signed, se))
        pairs = zip(rows, scores, strict=True)
        for (a, sa), (b, sb) in zip(pairs, zip(rows[1:], scores[1:], strict=True), strict=False):
            difference = np.sign(a.score) * sa - np.sign(b.score) * sb
            weights = np.asarray(noise.spp, dtype=np.float64)
            mean = float((weights * difference).sum() / weights.sum())
            se = float(pooled_stderr(difference, noise.spp))
            if not abs(mean) > noise.resolution.factor * se:
                found.append(Open(objective, f"{a.name} > {b.name}", "order", mean, se))
    return Resolution(top, batches, tuple(resolved), tuple(found))


def shards_hint(result: Resolution) -> list[str]:
    """Lines for ``merge``: what is still open and, per open number, about how many more shards
    of the same size would resolve it (an estimate)."""
    if result.done:
        return [f"the top {result.top} objects of every objective are resolved (signs and order)"]
    lines = [
        f"still open among the top {result.top} objects ({result.batches} shards); more shards "
        "of the same size that would resolve each, estimated from its standard error and the "
        "1/sqrt(n) law:"
    ]
    for item in result.open:
        more = item.more_batches(result.batches)
        estimate = "cannot say" if more is None else f"about {more} more"
        lines.append(f"  {item.describe()}: {estimate}")
    return lines
