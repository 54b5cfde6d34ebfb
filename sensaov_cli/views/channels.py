"""Channels of a view: queries over the buffer, one value per object, painted per pixel (§3).

Everything here is camera-independent except :func:`paint`: per-object values are computed once
from the buffer and painted into any number of inspection cameras' visibility passes, which is
the whole point of storing the buffer (no new differentiation per view).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.queries import per_object, select
from sensaov_cli.errors import SpecError
from sensaov_cli.spec.job import ChannelSpec
from sensaov_cli.vocabulary import Aggregate, Weight


@dataclass(frozen=True)
class ChannelValues:
    """One sensitivity pass of one objective, before painting."""

    objective: str
    pass_name: str  # "objects", "types_roughness", "<select name>"
    spec: ChannelSpec
    selection: str  # what was selected, for metadata: "all", "type=roughness", "glob=*.eta"
    keys: tuple[str, ...]
    magnitudes: np.ndarray  # (n_objects,) aggregate per object (l2/rms ≥ 0, sum signed)
    signed_sums: np.ndarray  # (n_objects,) Σ c per object: the direction of a group's effect
    unverified: tuple[str, ...]  # selected keys whose gradient is not verified
    estimators: dict[str, str] = field(default_factory=dict)  # key -> what computed its gradient


def channel_values(
    buf: SensitivityBuffer, channels: tuple[ChannelSpec, ...]
) -> list[ChannelValues]:
    """Every (objective, channel[, type]) pass the job asks for."""
    passes = []
    for objective in buf.objectives:
        for index, channel in enumerate(channels):
            if channel.kind in ("transport", "texel"):  # rendered by run / painted through UVs
                continue
            for pass_name, selection, keys in _selections(buf, channel, index):
                passes.append(_values(buf, objective.name, channel, pass_name, selection, keys))
    return passes


def _selections(
    buf: SensitivityBuffer, channel: ChannelSpec, index: int
) -> list[tuple[str, str, tuple[str, ...]]]:
    if channel.kind == "object":
        return [(channel.name, "all", tuple(buf.keys))]
    if channel.kind == "select":
        assert channel.select is not None
        keys = select(buf, glob=channel.select)
        if not keys:  # as with an absent type: an empty layer would look like "no sensitivity"
            raise SpecError(
                f"select glob {channel.select!r} matches no parameter in the buffer",
                where=f"channels[{index}].select",
                hint="'sensaov rank BUFFER --json' lists the keys",
            )
        return [(channel.name, f"glob={channel.select}", keys)]
    present = buf.types()
    for wanted in channel.types or ():
        if wanted not in present:
            close = difflib.get_close_matches(wanted, present, n=1)
            raise SpecError(
                f"no parameter of type {wanted!r} in the buffer",
                where=f"channels[{index}].types",
                hint=f"did you mean {close[0]!r}?"
                if close
                else f"types present: {', '.join(present)}",
            )
    return [
        (f"{channel.name}_{t}", f"type={t}", select(buf, types=t)) for t in channel.types or present
    ]


def _values(
    buf: SensitivityBuffer,
    objective: str,
    channel: ChannelSpec,
    pass_name: str,
    selection: str,
    keys: tuple[str, ...],
) -> ChannelValues:
    method, weight = cast(Aggregate, channel.aggregate), cast(Weight, channel.weight)
    magnitude = per_object(buf, objective, method=method, weight=weight, keys=keys)
    signed = per_object(buf, objective, method="sum", weight=weight, keys=keys)
    # A parameter through which no gradient flows adds exactly 0 to the picture: it is listed
    # apart in the rankings, and marking the pass "!" for it would flag numbers that are right.
    unverified = tuple(k for k in keys if buf.param(k).trust not in ("verified", "no_gradient"))
    return ChannelValues(
        objective,
        pass_name,
        channel,
        selection,
        keys,
        np.array([magnitude[name] for name in buf.objects], np.float64),
        np.array([signed[name] for name in buf.objects], np.float64),
        unverified,
        {k: buf.param(k).estimator for k in keys},
    )
