"""Display scales: the |value| at which a picture of a sensitivity layer saturates (numpy only).

Every picture of a layer (PNG previews, contact sheets, the report, the EXR's display layers)
maps a signed value v to a colour on a diverging map that saturates at ±s. The scale s is chosen
once per *scale group*, by default one (objective, channel) pair across every camera of the job
(Fig. 6: "all three share one colour scale"), so an object gets the same colour in every view
and a channel's passes compare with each other. The rule, recorded with every picture and layer:

    s = the p-th percentile (default 95) of |v| over the pixels the group paints (v ≠ 0)
        in every camera, each camera weighted equally whatever its resolution.

Pixels with v = 0 (not painted, not seen) never count; a percentile, not the maximum, so a few
pixels never set it. Pixels above s saturate at the map's ends and their share is recorded. A
layer left apart for its untrusted gradients follows its group's scale, setting it only when
the group paints nothing else. Reasoning and figures: docs/encoding.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.job.spec import ChannelSpec
from sensaov_cli.views.channels import channel_values, paint_pass
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.vocabulary import Untrusted

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
                signed_pixels(paint_pass(values, visibility).data),
            )
            for values in passes
        ]  # fmt: skip
        for camera, visibility in visibilities.items()
    }
    scales = group_scales(layers, percentile=percentile)
    return scales[(next(iter(visibilities)), f"{objective}/{channel.name}")]


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
