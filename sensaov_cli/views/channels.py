"""Channels of a view: queries over the buffer, one value per object, painted per pixel (§3),
their encoding and display scales; forward channels and the transport view (§4, §7), from the
buffer and its sidecar.

Per-object values are computed once from the buffer (camera-independent, so farm tasks that each
render one camera agree) and painted into any number of cameras' visibility passes by
:func:`paint_pass`, with no new differentiation per view.

Under ``untrusted: apart`` (the default, :mod:`.hierarchy`) each selection becomes ``<pass>``, the
parameters the tool stands behind, and, when the selection holds others, ``<pass>_untrusted``,
so a biased gradient never paints a headline layer. Both share the scale group
``<objective>/<channel>``.

With batch statistics, an object whose signed sum over the pass's keys its batches cannot resolve
(within its Student-t 95 % interval, or heavy-tailed: :mod:`.hierarchy`) is *unresolved*: its
pixels are drawn neutral in every picture and never set a display scale (the raw data keep its
number: they are data).
"""

from __future__ import annotations

import difflib
import fnmatch
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from sensaov_cli.buffer.forward_sidecar import ForwardData, ForwardLayer, duality_tolerance
from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import per_object, select
from sensaov_cli.errors import EncodingError, NonFiniteError, SpecError
from sensaov_cli.job.spec import ChannelSpec, ForwardSpec
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.hierarchy import GroupError, Uncertainty, untrusted_keys, zero_valued
from sensaov_cli.vocabulary import (
    AGGREGATES,
    DEFAULT_AGGREGATE,
    NORMALIZES,
    SIGNS,
    TONEMAPS,
    WEIGHTS,
    Untrusted,
)

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
    # object -> why its value is unresolved (drawn neutral, out of display scales); empty when
    # every object is resolved or the buffer has one batch (``measured`` False: no error at all)
    unresolved: dict[str, str] = field(default_factory=dict)
    measured: bool = False  # the buffer has batch statistics: resolution is known

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
            unresolved_objects(buf, objective, chosen, signed, weight),
            buf.statistics is not None,
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


def unresolved_objects(
    buf: SensitivityBuffer,
    objective: str,
    keys: Sequence[str],
    signed: Mapping[str, float],
    weight: str,
) -> dict[str, str]:
    """Each object whose signed sum over ``keys`` its batches cannot resolve, with the reason:
    heavy-tailed batches, or |Σc| within t standard errors. Empty without statistics."""
    noise = Uncertainty.of(buf, objective, "sum", "raw" if weight == "raw" else "value")
    if noise is None:
        return {}
    owned: dict[str, list[str]] = {}
    for key in keys:
        for owner in buf.param(key).owners:
            owned.setdefault(owner, []).append(key)
    found = {}
    for name, members in owned.items():
        why = unresolved_reason(noise.error(members, signed[name]), signed[name])
        if why is not None:
            found[name] = why
    return found


def unresolved_reason(error: GroupError, signed: float) -> str | None:
    """Why ``signed`` is not resolved under ``error``, in a few words; None when it is."""
    if error.noisy is not None:
        return f"noisy: {error.noisy}"
    if error.resolves(signed):
        return None
    return (
        f"unresolved: |{signed:+.3g}| within {error.factor:.2f} x {error.signed_se:.2g} "
        f"(t, {error.dof} dof)"
    )


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
    # (H, W) bool: pixels whose value comes mostly from unresolved objects (drawn neutral)
    neutral: np.ndarray | None = None
    # (H, W) float32: ``data`` with the unresolved objects left out: what display scales read
    scale_data: np.ndarray | None = None


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
    seen = set(visibility.visible_objects)
    invisible = tuple(sorted(n for n, value in per_object.items() if value and n not in seen))
    if not values.unresolved:
        scale = choose_scale(encoding, per_object,
                             painted if encoding.normalize == "channel" else None)  # fmt: skip
        data = encode_image(painted, encoding, scale.threshold, scale.scale)
        return PaintedPass(encoding, scale, data, invisible)
    # The unresolved objects' share of each pixel, painted apart: they never set a scale.
    doubtful = visibility.paint(
        np.array([per_object[n] if n in values.unresolved else 0.0 for n in visibility.objects])
    )
    resolved = painted - doubtful
    kept = {n: v for n, v in per_object.items() if n not in values.unresolved}
    scale = choose_scale(encoding, kept, resolved if encoding.normalize == "channel" else None)
    data = encode_image(painted, encoding, scale.threshold, scale.scale)
    neutral = np.abs(doubtful) > np.abs(resolved)
    scale_data = encode_image(np.where(neutral, 0.0, resolved), encoding, scale.threshold,
                              scale.scale)  # fmt: skip
    return PaintedPass(encoding, scale, data, invisible, neutral, scale_data)


# Encoding (§3, "Encoding"): per-object sensitivities turned into the values a channel stores,
# in three steps, in this order: the sign (signed_object_values), per object before painting;
# the tone map (tonemap_values), per pixel; the normalisation (encode_image) by the scale
# choose_scale picks. ``weight`` and ``aggregate`` are applied by the query and only recorded
# here. Two channels are comparable only if their encodings match (§3), so every channel records
# its Encoding and Scale. The defaults (linear, un-normalised) store the object's score itself.
# Formulas: docs/encoding.md.

# The log tone maps are near-linear below the threshold and logarithmic above it; at 1e-3 of
# the peak they resolve three decades below it. The threshold is recorded with the channel.
THRESHOLD_FRACTION = 1e-3


@dataclass(frozen=True)
class Encoding:
    """How a channel's values were produced and scaled; recorded with every channel."""

    weight: str = "value"  # "value" (θ·∂M/∂θ) | "raw" (∂M/∂θ); applied by the query
    sign: str = "signed"  # "signed" | "magnitude"
    aggregate: str = DEFAULT_AGGREGATE  # "l2" | "rms" | "sum"; applied by the query
    tonemap: str = "none"  # "none" | "log" | "symlog"
    normalize: str = "none"  # "none" | "channel" | "shared"

    def __post_init__(self) -> None:
        for name, valid in _CHOICES.items():
            _check_choice(name, getattr(self, name), valid)

    @classmethod
    def from_channel(cls, channel: ChannelSpec) -> Encoding:
        """The encoding a job's channel asks for."""
        return cls(**{name: getattr(channel, name) for name in _CHOICES})

    def describe(self) -> str:
        """``weight=value;sign=signed;aggregate=l2;tonemap=none;normalize=none``: fixed order."""
        return ";".join(f"{name}={getattr(self, name)}" for name in _CHOICES)

    @classmethod
    def parse(cls, text: str) -> Encoding:
        """The encoding :meth:`describe` wrote; raise EncodingError on anything else."""
        pairs = [item.partition("=") for item in text.split(";")]
        names = tuple(name for name, _, _ in pairs)
        if names != tuple(_CHOICES) or any(sep != "=" for _, sep, _ in pairs):
            hint = f"expected {';'.join(f'{name}=…' for name in _CHOICES)}"
            raise EncodingError(f"cannot read encoding {text!r}", hint=hint)
        return cls(**{name: value for name, _, value in pairs})


# In Encoding's field order, which is the order describe() writes.
_CHOICES: dict[str, tuple[str, ...]] = {
    "weight": WEIGHTS,
    "sign": SIGNS,
    "aggregate": AGGREGATES,
    "tonemap": TONEMAPS,
    "normalize": NORMALIZES,
}


@dataclass(frozen=True)
class Scale:
    """The numbers an image was encoded with: ``encoded = tonemap(x, threshold) / scale``.

    ``threshold`` is 0.0 when the tone map is linear (it has none); ``scale`` is 1.0 when the
    encoding does not normalise and also when everything is zero (nothing to divide).
    """

    threshold: float
    scale: float

    def describe(self) -> str:
        """``threshold=…;scale=…`` with shortest round-trip floats."""
        return f"threshold={self.threshold!r};scale={self.scale!r}"


def signed_object_values(
    magnitudes: Mapping[str, float], signed_sums: Mapping[str, float], sign: str
) -> dict[str, float]:
    """The value painted for each object: its score (``magnitudes``) with the sign of its Σ c
    (``signed_sums``: the direction in which scaling the whole group by 1 + ε moves M), or
    without (``"magnitude"``). A group whose sum is exactly zero keeps its magnitude, shown
    positive: hiding a large magnitude would mislead more than an arbitrary sign.
    """
    _check_choice("sign", sign, SIGNS)
    if set(magnitudes) != set(signed_sums):
        differ = sorted(set(magnitudes) ^ set(signed_sums))
        raise ValueError(f"magnitudes and signed sums name different objects: {differ}")
    for name in magnitudes:
        _check_finite(
            f"the score of object {name!r}", np.array([magnitudes[name], signed_sums[name]])
        )
    values = {name: abs(float(m)) for name, m in magnitudes.items()}
    if sign == "magnitude":
        return values
    return {name: -v if signed_sums[name] < 0 else v for name, v in values.items()}


def tonemap_values(x: np.ndarray, mode: str, threshold: float) -> np.ndarray:
    """``x`` (none), log10(1 + |x|/threshold) (log, ≥ 0) or sign(x)·log10(1 + |x|/threshold)
    (symlog), as float32. ``threshold`` must be positive for log and symlog.
    """
    values = np.asarray(x, dtype=np.float64)
    _check_finite("values", values)
    return _float32(_tonemap64(values, mode, threshold))


def _tonemap64(values: np.ndarray, mode: str, threshold: float) -> np.ndarray:
    if mode == "none":
        return values
    if not (math.isfinite(threshold) and threshold > 0):
        raise ValueError(f"a {mode} tone map needs a positive finite threshold, got {threshold}")
    # log1p keeps full precision below the threshold, where |x|/threshold is small.
    compressed = np.log1p(np.abs(values) / threshold) / math.log(10)
    return compressed if mode == "log" else np.sign(values) * compressed


def choose_scale(
    encoding: Encoding, object_values: Mapping[str, float], painted: np.ndarray | None = None
) -> Scale:
    """The threshold and scale to encode a channel with, both set by the peak |value| of the
    objects' values (``normalize`` none and shared) or of the ``painted`` image (channel).

    Shared scales never look at an image: a painted pixel is a coverage-weighted mean of object
    values, so it cannot exceed their peak, and a farm task's camera gets the same scale.
    """
    objects = np.array(list(object_values.values()), dtype=np.float64)
    _check_finite("object values", objects)
    if encoding.normalize == "channel":
        if painted is None:
            raise ValueError("normalize=channel takes its scale from the painted image: pass it")
        scope = np.asarray(painted, dtype=np.float64)
        _check_finite("painted pixels", scope)
    else:
        scope = objects
    peak = float(np.max(np.abs(scope))) if scope.size else 0.0
    # An all-zero scope (or one so small its fraction underflows) still needs a positive
    # threshold; any will do, since 0 maps to 0.
    threshold = 0.0 if encoding.tonemap == "none" else THRESHOLD_FRACTION * peak or 1.0
    if encoding.normalize == "none" or peak == 0.0:
        return Scale(threshold, 1.0)
    top = float(_tonemap64(np.array([peak]), encoding.tonemap, threshold)[0])
    return Scale(threshold, top if top > 0 else 1.0)  # a denormal peak can map to 0


def encode_image(
    painted: np.ndarray, encoding: Encoding, threshold: float, scale: float
) -> np.ndarray:
    """``tonemap(painted, threshold) / scale`` as float32; a scale of 0 divides by nothing."""
    if not (math.isfinite(scale) and scale >= 0):
        raise ValueError(f"scale must be finite and non-negative, got {scale}")
    mapped = tonemap_values(painted, encoding.tonemap, threshold)
    if scale == 0.0 or scale == 1.0:
        return mapped
    return _float32(mapped.astype(np.float64) / scale)


def _check_choice(kind: str, given: str, valid: tuple[str, ...]) -> None:
    if given not in valid:
        raise EncodingError(
            f"unknown encoding {kind} {given!r}", hint=f"use one of: {', '.join(valid)}"
        )


def _check_finite(what: str, values: np.ndarray) -> None:
    if not np.all(np.isfinite(values)):
        bad = "NaN" if np.any(np.isnan(values)) else "infinite"
        hint = "sensitivities must be finite: check the objective and the gradient pass"
        raise NonFiniteError(f"{what}: {bad} where a finite number is needed", hint=hint)


def _float32(values: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):  # overflow is reported below, as an error
        result = values.astype(np.float32)
    _check_finite("values beyond the float32 range", result)
    return result


# Display scales: every picture of a layer (PNG previews, contact sheets, the report, the EXR's
# display layers) maps a signed value v to a colour on a diverging map that saturates at ±s. The
# scale s is chosen once per *scale group*, by default one (objective, channel) pair across every
# camera of the job (Fig. 6: "all three share one colour scale"), so an object gets the same
# colour in every view and a channel's passes compare with each other. The rule, recorded with
# every picture and layer:
#
#     s = the p-th percentile (default 95) of |v| over the pixels the group paints (v ≠ 0)
#         in every camera, each camera weighted equally whatever its resolution.
#
# Pixels with v = 0 (not painted, not seen) never count; a percentile, not the maximum, so a few
# pixels never set it. Pixels above s saturate at the map's ends and their share is recorded. A
# layer left apart for its untrusted gradients follows its group's scale, setting it only when
# the group paints nothing else. Reasoning and figures: docs/encoding.md.
DEFAULT_PERCENTILE = 95.0
REC709_LUMA = (0.2126, 0.7152, 0.0722)
# How a layer takes part in its group's scale: sets it, follows it (an untrusted part), or
# has a fixed one (a texel channel's joint panel, whose unit is an even spread).
REFERENCE, FOLLOWER = "reference", "follower"


@dataclass(frozen=True)
class DisplayScale:
    """The |value| at which a group's pictures saturate, how it was chosen, what it clips."""

    value: float  # 0.0 when the group paints nothing in any camera: drawn as all zero
    scope: str  # "shared" (every camera), "tile" (this camera only) or "fixed"
    percentile: float
    cameras: tuple[str, ...]  # the cameras whose pixels were read
    painted: int  # non-zero pixels read, all cameras together
    clipped: float  # share of them above the scale, cameras weighted equally

    def rule(self) -> str:
        """The rule in one line, as legends and EXR metadata print it."""
        if self.scope == "fixed":
            return f"fixed at {self.value:g}"
        if self.scope == "tile":
            return f"p{self.percentile:g} of |v| over the non-zero pixels of {self.cameras[0]} only"
        return (
            f"p{self.percentile:g} of |v| over the non-zero pixels of {', '.join(self.cameras)} "
            "(each camera weighted equally)"
        )

    def describe(self) -> str:
        """``value=…;scope=…;percentile=…;clipped=…``: shortest round-trip floats."""
        return (
            f"value={self.value!r};scope={self.scope};percentile={self.percentile!r};"
            f"clipped={self.clipped!r}"
        )


def signed_pixels(data: np.ndarray, kind: str = "") -> np.ndarray:
    """One signed value per pixel of a layer: (H, W) as is (its own type, not copied: float32
    compares, sorts and widens exactly); an RGB forward or transport image by its Rec. 709
    luminance; an RGB texel field by its components' sum (scaling them all), in float64."""
    if data.ndim == 2:
        return np.asarray(data)
    rgb = np.asarray(data[..., :3], np.float64)
    return rgb @ np.array(REC709_LUMA) if kind in ("forward", "transport") else rgb.sum(axis=2)


def robust_scale(
    pixels: Mapping[str, Sequence[np.ndarray]],
    *,
    percentile: float = DEFAULT_PERCENTILE,
    scope: str = "shared",
    fixed: float | None = None,
) -> DisplayScale:
    """The scale of a group from its signed pixels per camera (``camera -> images``), or the
    ``fixed`` one that what the layer means sets (1 = an even spread), with what it clips."""
    active = [m for m in (_painted(images) for images in pixels.values()) if m.size]
    if fixed is not None:
        value, scope, percentile = float(fixed), "fixed", 100.0
    else:
        value = _weighted_percentile(active, percentile) if active else 0.0
    clipped = [float(np.count_nonzero(m > value)) / m.size for m in active]
    share = float(np.mean(clipped)) if clipped else 0.0
    painted = sum(m.size for m in active)
    return DisplayScale(value, scope, float(percentile), tuple(pixels), painted, share)


def clipped_share(images: Sequence[np.ndarray], value: float) -> float:
    """The share of ``images``' non-zero pixels above ``value`` (one camera's, in legends)."""
    painted = above = 0
    bound = np.float64(value)  # not a Python float: float32 pixels compare in float64, exactly
    for image in images:
        magnitude = _magnitude(image)
        painted += int(np.count_nonzero(magnitude > 0))
        above += int(np.count_nonzero(magnitude > bound))
    return float(above) / painted if painted else 0.0


def group_scales(
    layers: Mapping[str, Sequence[tuple[str, str, np.ndarray]]],
    *,
    percentile: float = DEFAULT_PERCENTILE,
    scope: str = "shared",
    fixed: Mapping[str, float] | None = None,
) -> dict[tuple[str, str], DisplayScale]:
    """The scale of every (camera, group) from ``camera -> [(group, role, signed pixels)]``:
    under ``shared`` the one scale of all cameras together, under ``tile`` each camera's own;
    a group in ``fixed`` gets that value everywhere."""
    groups = {group for entries in layers.values() for group, _, _ in entries}
    scales: dict[tuple[str, str], DisplayScale] = {}
    for group in sorted(groups):
        by_role = {
            role: {
                camera: [data for g, r, data in entries if g == group and r == role]
                for camera, entries in layers.items()
            }
            for role in (REFERENCE, FOLLOWER)
        }
        chosen = by_role[REFERENCE]
        if not any(_painted(images).size for images in chosen.values()):
            chosen = by_role[FOLLOWER]
        cameras = [
            camera for camera, entries in layers.items() if any(g == group for g, _, _ in entries)
        ]
        for camera in cameras:
            scope_pixels = chosen if scope == "shared" else {camera: chosen[camera]}
            scales[(camera, group)] = robust_scale(
                scope_pixels, percentile=percentile, scope=scope, fixed=(fixed or {}).get(group)
            )
    return scales


def shared_channel_scale(
    buf: SensitivityBuffer,
    channel: ChannelSpec,
    objective: str,
    visibilities: Mapping[str, VisibilityPass],
    *,
    untrusted: Untrusted = "apart",
    percentile: float = DEFAULT_PERCENTILE,
) -> DisplayScale:
    """The job's shared display scale of one (objective, channel) of kind object, type or
    select, from the buffer and every camera's visibility pass alone: the ``display_scale``
    ``sensaov project`` records on that channel's layers, which ``sensaov view`` shows."""
    passes = [v for v in channel_values(buf, (channel,), untrusted=untrusted)
              if v.objective == objective]  # fmt: skip
    layers = {
        camera: [
            (
                values.scale_group,
                FOLLOWER if values.part == "untrusted" else REFERENCE,
                signed_pixels(_scale_image(paint_pass(values, visibility))),
            )
            for values in passes
        ]  # fmt: skip
        for camera, visibility in visibilities.items()
    }
    scales = group_scales(layers, percentile=percentile)
    return scales[(next(iter(visibilities)), f"{objective}/{channel.name}")]


def _scale_image(painted: PaintedPass) -> np.ndarray:
    """What a display scale reads of a painted pass: never its unresolved objects."""
    return painted.data if painted.scale_data is None else painted.scale_data


def _painted(images: Sequence[np.ndarray]) -> np.ndarray:
    """|v| of every non-zero pixel of ``images``, flattened, float64."""
    magnitudes = (_magnitude(image).ravel() for image in images)
    parts = [m[m > 0].astype(np.float64) for m in magnitudes]  # only the painted widened
    return np.concatenate(parts) if parts else np.zeros(0)


def _magnitude(image: np.ndarray) -> np.ndarray:
    """|image|, exact: a float image in its own type (no float64 copy of every pixel), any
    other (an int's most negative value has no |v| in its type) in float64."""
    data = np.asarray(image)
    return np.abs(data if data.dtype.kind == "f" else data.astype(np.float64))


def _weighted_percentile(magnitudes: Sequence[np.ndarray], percentile: float) -> float:
    """The percentile of the union of ``magnitudes``, each array weighted 1/len (equal cameras):
    the smallest value whose cumulative weight reaches ``percentile`` % of the total."""
    # 1e-10 below: a cumulative weight that reaches the percentile exactly must not miss it by
    # the rounding of its sum (numpy's own choice at such a tie depends on the summation order).
    reached = max(percentile - 1e-10, 0.0)
    if len({m.size for m in magnitudes}) == 1:  # equal weights: a selection, not a sort
        return float(np.percentile(np.concatenate(magnitudes), reached, method="inverted_cdf"))
    # The cumulative weight is the mean of the cameras' own distribution functions, so its
    # percentile lies between the smallest and the largest of the cameras' own percentiles
    # (widened by two ranks each way against rounding): only the values in between are
    # sorted, those below and above enter as one weight each, at -inf and +inf.
    bounds = [_rank_bounds(m, percentile) for m in magnitudes]
    low, high = min(b[0] for b in bounds), max(b[1] for b in bounds)
    inside = [m[(m >= low) & (m <= high)] for m in magnitudes]
    below = sum(np.count_nonzero(m < low) / m.size for m in magnitudes)
    above = sum(np.count_nonzero(m > high) / m.size for m in magnitudes)
    values = np.concatenate([[-np.inf], *inside, [np.inf]])
    weights = np.concatenate(
        [[below], *(np.full(i.size, 1.0 / m.size) for i, m in zip(inside, magnitudes, strict=True)),
         [above]]
    )  # fmt: skip
    return float(np.percentile(values, reached, weights=weights, method="inverted_cdf"))


def _rank_bounds(magnitude: np.ndarray, percentile: float) -> tuple[float, float]:
    """Two values of one camera's pixels that bracket its own percentile by two ranks each way."""
    rank = math.ceil(percentile / 100.0 * magnitude.size) - 1
    low, high = max(rank - 2, 0), min(rank + 2, magnitude.size - 1)
    parted = np.partition(magnitude, (low, high))
    return float(parted[low]), float(parted[high])


# Forward channels and the transport view. A forward channel is J·v: the image's derivative along
# a pushed group S with direction v_S. The transport layer of S paints where that influence
# lands at the objective camera: T_p = Σ_c (∂M/∂I)_{p,c} · (J v_S)_{p,c}, whose sum over pixels
# equals ⟨g, v_S⟩ from the buffer (forward/reverse duality at one seed), so every layer carries
# its residual against duality_tolerance. Entries that push the same parameters at the same seed
# are one pass: each pass of each objective gives one layer, named after the first entry that
# asked for it, the others as ``aliases``.
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
    """The ``k`` objects with the largest |score| by the default score, the rankings' (zeros
    never ranked)."""
    scores = per_object(buffer, objective, method=DEFAULT_AGGREGATE, weight=weight)  # type: ignore[arg-type]
    ranked = sorted((n for n in scores if scores[n] != 0), key=lambda n: -abs(scores[n]))
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
