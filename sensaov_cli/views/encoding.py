"""Encoding: per-object sensitivities turned into the values a channel stores (§3, "Encoding").

Three steps, in this order: the sign (:func:`signed_object_values`), per object before
painting; the tone map (:func:`tonemap_values`), per pixel; the normalisation
(:func:`encode_image`) by the scale :func:`choose_scale` picks. ``weight`` and ``aggregate``
are applied by the query and only recorded here. Two channels are comparable only if their
encodings match (§3), so every channel records its :class:`Encoding` and :class:`Scale`. The
defaults (linear, un-normalised) store the object's score itself. Formulas: docs/encoding.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sensaov_cli.errors import EncodingError, NonFiniteError
from sensaov_cli.vocabulary import AGGREGATES, NORMALIZES, SIGNS, TONEMAPS, WEIGHTS

if TYPE_CHECKING:
    from sensaov_cli.job.spec import ChannelSpec


# The log tone maps are near-linear below the threshold and logarithmic above it; at 1e-3 of
# the peak they resolve three decades below it. The threshold is recorded with the channel.
THRESHOLD_FRACTION = 1e-3


@dataclass(frozen=True)
class Encoding:
    """How a channel's values were produced and scaled; recorded with every channel."""

    weight: str = "value"  # "value" (θ·∂M/∂θ) | "raw" (∂M/∂θ); applied by the query
    sign: str = "signed"  # "signed" | "magnitude"
    aggregate: str = "l2"  # "l2" | "rms" | "sum"; applied by the query
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
    threshold = 0.0 if encoding.tonemap == "none" else _threshold(peak)
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


def _threshold(peak: float) -> float:
    # An all-zero scope (or one so small its fraction underflows) still needs a positive
    # threshold; any will do, since 0 maps to 0.
    threshold = THRESHOLD_FRACTION * peak
    return threshold if threshold > 0 else 1.0


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
