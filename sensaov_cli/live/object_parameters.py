"""The parameters of one object, ranked: what a click on it in ``sensaov view`` shows.

Each row carries what a reader needs to judge it: the parameter's value, its gradient ∂M/∂θ,
the contribution Σ θ·∂M/∂θ (or Σ ∂M/∂θ with ``weight: raw``) with its standard error where the
buffer has batch statistics (None where it has none: no error is claimed that was not
measured), the trust label and its note. Arrays of more than four components (a texture) are
summarised: the value's mean and the gradient's sum, with the component count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.queries import combine, key_stats, rank
from sensaov_cli.views.uncertainty import Uncertainty
from sensaov_cli.vocabulary import Weight

LISTED_COMPONENTS = 4  # a colour is listed component by component, a texture summarised


@dataclass(frozen=True)
class ParameterRow:
    rank: int
    key: str
    type: str
    plugin: str
    components: int
    value: tuple[float, ...]  # every component, or (mean,) for a larger array
    gradient: tuple[float, ...]  # ∂M/∂θ per component, or (sum,) for a larger array
    gradient_se: tuple[float, ...] | None  # its standard error per component (listed only)
    score: float  # l2 of the contributions (how the rows are ranked)
    signed: float  # Σ contributions: > 0 when scaling the parameter up raises M
    signed_se: float | None  # standard error of ``signed``; None without batch statistics
    trust: str
    note: str
    shared_with: tuple[str, ...]  # the parameter's other owners


def object_parameters(
    buf: SensitivityBuffer, objective: str, obj: str, weight: Weight = "value"
) -> list[ParameterRow]:
    """The parameters ``obj`` owns, ranked by the l2 of their contributions to ``objective``."""
    keys = [p.key for p in buf.params if obj in p.owners]
    stats = key_stats(buf, objective, keys, weight=weight)
    noise = Uncertainty.of(buf, objective, "l2", weight)
    ordered = rank({key: combine([stats[key]], "l2") for key in keys})
    rows = []
    for index, (key, score) in enumerate(ordered, 1):
        record = buf.param(key)
        value = buf.value(key).astype(np.float64).ravel()
        grad = buf.grad(objective, key).astype(np.float64).ravel()
        listed = value.size <= LISTED_COMPONENTS
        rows.append(
            ParameterRow(
                rank=index,
                key=key,
                type=record.type,
                plugin=record.plugin,
                components=int(value.size),
                value=tuple(map(float, value)) if listed else (float(value.mean()),),
                gradient=tuple(map(float, grad)) if listed else (float(grad.sum()),),
                gradient_se=_gradient_se(buf, objective, key) if listed else None,
                score=score,
                signed=stats[key].total,
                signed_se=None if noise is None else noise.error([key], score).signed_se,
                trust=record.trust,
                note=record.note,
                shared_with=tuple(o for o in record.owners if o != obj),
            )
        )
    return rows


def _gradient_se(buf: SensitivityBuffer, objective: str, key: str) -> tuple[float, ...] | None:
    if buf.statistics is None:
        return None
    return tuple(map(float, np.asarray(buf.statistics.stderr[objective][key]).ravel()))
