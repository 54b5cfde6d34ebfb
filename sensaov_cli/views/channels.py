"""Channels of a view: queries over the buffer, one value per object, painted per pixel (§3).

Per-object values are computed once from the buffer (camera-independent, so farm tasks that each
render one camera agree) and painted into any number of cameras' visibility passes by
:func:`paint_pass`, with no new differentiation per view.

Under ``untrusted: apart`` (the default, :mod:`.trusted`) each selection becomes ``<pass>``, the
parameters the tool stands behind, and, when the selection holds others, ``<pass>_untrusted``,
so a biased gradient never paints a headline layer. Both share the scale group
``<objective>/<channel>``.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.queries import per_object, select
from sensaov_cli.errors import SpecError
from sensaov_cli.job.spec import ChannelSpec
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.encoding import (
    Encoding,
    Scale,
    choose_scale,
    encode_image,
    signed_object_values,
)
from sensaov_cli.views.trusted import untrusted_keys, zero_valued
from sensaov_cli.vocabulary import Untrusted

UNTRUSTED_PASS = "_untrusted"  # the suffix of a selection's untrusted part
LeftOut = dict[str, tuple[str, ...]]  # object -> its keys in the untrusted pass


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
    part: str = "all"  # "trusted" / "untrusted" under untrusted: apart
    left_out: LeftOut | None = None  # on both parts: left out of one, held by the other
    zero_valued: dict[str, float] | None = None  # key -> raw Σ ∂M/∂θ, θ = 0 (weight value)
    estimators: dict[str, str] = field(default_factory=dict)  # key -> what computed its gradient

    @property
    def scale_group(self) -> str:
        """The passes that share one display scale: one (objective, channel)."""
        return f"{self.objective}/{self.spec.name}"


def channel_values(
    buf: SensitivityBuffer, channels: tuple[ChannelSpec, ...], *, untrusted: Untrusted = "apart"
) -> list[ChannelValues]:
    """Every (objective, channel[, type]) pass the job asks for, split by trust (``apart``)."""
    passes = []
    for objective in buf.objectives:
        for index, channel in enumerate(channels):
            if channel.kind in ("transport", "texel"):  # rendered by run / painted through UVs
                continue
            for pass_name, selection, keys in _selections(buf, channel, index):
                passes += _parts(
                    buf, objective.name, channel, pass_name, selection, keys, untrusted
                )
    return passes


def _parts(
    buf: SensitivityBuffer,
    objective: str,
    channel: ChannelSpec,
    pass_name: str,
    selection: str,
    keys: tuple[str, ...],
    untrusted: Untrusted,
) -> list[ChannelValues]:
    """One pass (``include``), or the trusted pass and, if any, the untrusted one (``apart``)."""
    hidden = zero_valued(buf, objective, keys) if channel.weight == "value" else {}

    def values(
        name: str, where: str, chosen: tuple[str, ...], part: str, left_out: LeftOut | None
    ) -> ChannelValues:
        weight = channel.weight
        magnitude = per_object(buf, objective, method=channel.aggregate, weight=weight, keys=chosen)
        signed = per_object(buf, objective, method="sum", weight=weight, keys=chosen)
        return ChannelValues(
            objective,
            name,
            channel,
            where,
            chosen,
            np.array([magnitude[o] for o in buf.objects], np.float64),
            np.array([signed[o] for o in buf.objects], np.float64),
            untrusted_keys(buf, chosen),  # no_gradient adds exactly 0: no "!" for right numbers
            part,
            left_out,
            {key: z.raw_signed for key, z in hidden.items() if key in chosen},
            {k: buf.param(k).estimator for k in chosen},
        )

    if untrusted == "include":
        return [values(pass_name, selection, keys, "all", None)]
    apart = untrusted_keys(buf, keys)
    trusted = tuple(k for k in keys if k not in apart)
    # object -> its untrusted keys: left out of the trusted pass, held by the untrusted one
    owned = {o: tuple(k for k in apart if o in buf.param(k).owners) for o in buf.objects}
    left_out = {o: ks for o, ks in owned.items() if ks}
    passes = [values(pass_name, selection, trusted, "trusted", left_out)]
    if apart:
        name, where = pass_name + UNTRUSTED_PASS, f"{selection};untrusted"
        passes.append(values(name, where, apart, "untrusted", left_out))
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


@dataclass(frozen=True)
class PaintedPass:
    encoding: Encoding
    scale: Scale  # how ``data`` was encoded (recorded with the layer)
    data: np.ndarray  # (H, W) float32, encoded
    invisible: tuple[str, ...]  # objects with a non-zero value that this camera does not see


def painted_values(
    values: ChannelValues, visibility: VisibilityPass, sign: str
) -> tuple[dict[str, float], np.ndarray]:
    """Each object's value under ``sign``, and the (H, W) image they paint into this camera."""
    names = visibility.objects
    per_object = signed_object_values(
        dict(zip(names, values.magnitudes, strict=True)),
        dict(zip(names, values.signed_sums, strict=True)),
        sign,
    )
    return per_object, visibility.paint(np.array([per_object[name] for name in names]))


def paint_pass(values: ChannelValues, visibility: VisibilityPass) -> PaintedPass:
    """One pass painted into one camera: per-object values through the coverage, encoded."""
    encoding = Encoding.from_channel(values.spec)
    per_object, painted = painted_values(values, visibility, encoding.sign)
    scale = choose_scale(encoding, per_object, painted if encoding.normalize == "channel" else None)
    data = encode_image(painted, encoding, scale.threshold, scale.scale)
    seen = set(visibility.visible_objects)
    invisible = tuple(sorted(n for n, value in per_object.items() if value and n not in seen))
    return PaintedPass(encoding, scale, data, invisible)
