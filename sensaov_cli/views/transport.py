"""Forward channels and the transport view (§4, §7), computed from the buffer and its sidecar.

A forward channel is J·v: the image's derivative along a pushed group S with direction v_S.
The transport layer of S paints where that influence lands at the objective camera:
T_p = Σ_c (∂M/∂I)_{p,c} · (J v_S)_{p,c}, whose sum over pixels equals ⟨g, v_S⟩ from the buffer
(forward/reverse duality at one seed), so every layer carries its residual against
:func:`~sensaov_cli.buffer.forward_sidecar.duality_tolerance`.

Entries that push the same parameters at the same seed are one pass: each pass of each
objective gives one layer, named after the first entry that asked for it, the others as
``aliases``.
"""

from __future__ import annotations

import difflib
import fnmatch
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.forward_sidecar import ForwardData, ForwardLayer, duality_tolerance
from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import per_object
from sensaov_cli.errors import SpecError
from sensaov_cli.job.spec import ForwardSpec

_TINY = 1e-30


@dataclass(frozen=True, eq=False)
class ForwardView:
    """``forward.<name>``: J·v in the image's colour channels, or why it is missing."""

    name: str
    data: np.ndarray | None  # (H, W, 3) or (H, W) for mono; None when Mitsuba could not
    keys: tuple[str, ...]
    direction: str
    seed: int
    unverified: tuple[str, ...]  # pushed keys whose buffer trust label is not verified
    failure: str
    source: str = ""  # the job entry that asked for it
    aliases: tuple[str, ...] = ()  # other entries' names for the same pass


@dataclass(frozen=True, eq=False)
class TransportView:
    """``<objective>.<name>``: where the group's influence on M lands, per pixel."""

    objective: str
    name: str  # the pass: "transport_<forward entry>" or "<transport channel>_<object>"
    data: np.ndarray  # (H, W) float32: T_p
    keys: tuple[str, ...]
    direction: str
    seed: int
    forward_sum: float  # Σ_p T_p
    reverse: float  # ⟨g, v⟩ from the buffer
    residual: float  # |forward_sum − reverse| / |reverse| (absolute when reverse is 0)
    tolerance: float
    unverified: tuple[str, ...]
    source: str = ""  # the job entry that asked for it: "forward[0]", "channels[4] (top 3 ...)"
    aliases: tuple[str, ...] = ()  # other entries' names for the same pass

    @property
    def agrees(self) -> bool:
        return self.residual <= self.tolerance


def group_keys(records: Sequence[ParamRecord], spec: ForwardSpec, where: str) -> tuple[str, ...]:
    """The selected keys a forward entry pushes; an entry that selects nothing is an error."""
    if spec.select is not None:
        keys = tuple(r.key for r in records if fnmatch.fnmatchcase(r.key, spec.select))
        field, known = "select", None
    elif spec.object is not None:
        keys = tuple(r.key for r in records if spec.object in r.owners)
        field, known = "object", sorted({o for r in records for o in r.owners})
    else:
        keys = tuple(r.key for r in records if r.type == spec.type)
        field, known = "type", sorted({r.type for r in records})
    if not keys:
        given = getattr(spec, field)
        close = difflib.get_close_matches(given, known or [r.key for r in records], n=1)
        raise SpecError(
            f"forward channel {spec.name!r}: {field} {given!r} selects no parameter",
            where=f"{where}.{field}",
            hint=f"did you mean {close[0]!r}?" if close else "'sensaov params JOB' lists them",
        )
    return keys


def direction_values(
    buffer: SensitivityBuffer, keys: Sequence[str], direction: str
) -> dict[str, np.ndarray]:
    """v per key: θ itself (value: a proportional change) or ones."""
    if direction == "value":
        return {key: np.asarray(buffer.value(key), np.float32) for key in keys}
    return {key: np.ones_like(buffer.value(key), np.float32) for key in keys}


def reverse_along(
    buffer: SensitivityBuffer, objective: str, keys: Sequence[str], direction: str
) -> float:
    """⟨g, v⟩ from the reverse-mode gradients, in float64: for a repaired parameter the one
    its repair replaced, whose dual the forward pass is (buffer/model.py)."""
    v = direction_values(buffer, keys, direction)
    return float(
        sum(
            np.dot(buffer.reverse_grad(objective, k).astype(np.float64).ravel(), v[k].ravel())
            for k in keys
        )
    )


def top_objects(buffer: SensitivityBuffer, objective: str, k: int, weight: str) -> list[str]:
    """The ``k`` objects with the largest l2 sensitivity (zeros never ranked)."""
    scores = per_object(buffer, objective, method="l2", weight=weight)  # type: ignore[arg-type]
    ranked = sorted((name for name in scores if scores[name] > 0), key=lambda n: -scores[n])
    return ranked[:k]


def unverified_keys(buffer: SensitivityBuffer, keys: Sequence[str]) -> tuple[str, ...]:
    """As channels mark them (no_gradient adds exactly 0), and repaired ones too: the forward
    pass is the reverse mode's twin, known wrong (docs/verification.md, "Repairs")."""
    return tuple(
        k
        for k in keys
        if buffer.param(k).trust not in ("verified", "no_gradient")
        or buffer.param(k).estimator in ("finite-difference", "mixed")
    )


def merged_layers(data: ForwardData, kind: str) -> list[tuple[ForwardLayer, tuple[str, ...]]]:
    """The sidecar's layers of ``kind``, one per (objective, pass), with the names of the
    others that repeat it."""
    first: dict[tuple[str | None, int], ForwardLayer] = {}
    aliases: dict[tuple[str | None, int], list[str]] = {}
    for layer in data.layers:
        if layer.kind == kind:
            at = (layer.objective, layer.pass_index)
            if at in first:
                aliases[at].append(layer.name)
            else:
                first[at], aliases[at] = layer, []
    return [(layer, tuple(aliases[at])) for at, layer in first.items()]


def forward_views(buffer: SensitivityBuffer, data: ForwardData) -> list[ForwardView]:
    views = []
    for layer, aliases in merged_layers(data, "forward"):
        p = data.passes[layer.pass_index]
        image = None if p.image is None else _colour(p.image)
        views.append(
            ForwardView(
                layer.name,
                image,
                p.keys,
                p.direction,
                p.seed,
                unverified_keys(buffer, p.keys),
                p.failure,
                layer.source,
                aliases,
            )
        )
    return views


def transport_views(buffer: SensitivityBuffer, data: ForwardData) -> list[TransportView]:
    """Every transport layer whose forward pass exists, with its duality residual."""
    return [
        transport_view(buffer, data, layer, aliases)
        for layer, aliases in merged_layers(data, "transport")
        if data.passes[layer.pass_index].image is not None
    ]


def transport_view(
    buffer: SensitivityBuffer, data: ForwardData, layer: ForwardLayer, aliases: tuple[str, ...]
) -> TransportView:
    assert layer.objective is not None
    p = data.passes[layer.pass_index]
    assert p.image is not None
    adjoint = data.adjoints[layer.objective].astype(np.float64)
    per_pixel = (adjoint * p.image.astype(np.float64)).sum(axis=2)
    forward_sum = float(per_pixel.sum())
    reverse = reverse_along(buffer, layer.objective, p.keys, p.direction)
    residual = abs(forward_sum - reverse) / (abs(reverse) if abs(reverse) > _TINY else 1.0)
    height, width = per_pixel.shape
    tolerance = duality_tolerance(width * height * int(buffer.provenance.get("spp", 1)))
    return TransportView(
        layer.objective, layer.name, per_pixel.astype(np.float32), p.keys, p.direction, p.seed,
        forward_sum, reverse, residual, tolerance, unverified_keys(buffer, p.keys), layer.source,
        aliases,
    )  # fmt: skip


def _colour(image: np.ndarray) -> np.ndarray:
    """The colour channels of J·v: RGB of an RGB[A] render, Y of a mono one."""
    return image[..., :3] if image.shape[2] >= 3 else image[..., 0]
