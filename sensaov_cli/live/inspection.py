"""One live inspection view (``sensaov view``): a channel painted through a free camera (§3).

The per-object values come from the buffer once (:mod:`.channels`); each camera move only
brings a new :class:`~.coverage.VisibilityPass`, through which they are painted and encoded
as the page asks: signed or magnitude, linear or compressive (a log tone map around a
threshold at 1e-3 of the peak), on the job's shared scale (the one ``sensaov project``'s
previews and display layers use) or the view's own (:mod:`.view_scales`). What the view cannot
stand behind travels with it: the coverage of objects whose value includes a gradient that is
not verified (drawn hatched), the objects with a value that this view does not see, and the
keys behind both.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.live.scales import job_shared_scale, peak_of, value_at, view_own_scale
from sensaov_cli.views.channels import ChannelValues
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.display_scale import DisplayScale, clipped_share, robust_scale
from sensaov_cli.views.encoding import Encoding, Scale, encode_image, signed_object_values
from sensaov_cli.views.texels import TexelField, texel_passes, texture_footprint

SCALE_MODES = ("shared", "view")
LEGEND_STOPS = (-1.0, -0.5, 0.0, 0.5, 1.0)
_COMPRESSIVE = {"signed": "symlog", "magnitude": "log"}


@dataclass(frozen=True)
class Look:
    """How the page asks a channel to be shown."""

    sign: str = "signed"  # "signed" | "magnitude"
    compressive: bool = False  # a log tone map (symlog when signed)
    scale: str = "shared"  # "shared": the job's scale | "view": this view's own

    def encoding(self, values: ChannelValues) -> Encoding:
        tonemap = _COMPRESSIVE[self.sign] if self.compressive else "none"
        base = Encoding.from_channel(values.spec)
        return replace(base, sign=self.sign, tonemap=tonemap, normalize="shared")


@dataclass(frozen=True)
class Legend:
    """What the colour bar says: the encoding, the value at each stop, and the caveats."""

    encoding: str
    scale_mode: str
    scale: Scale
    peak: float  # the value, in the channel's units, at which colours saturate
    stops: tuple[tuple[float, float], ...]  # (position in [-1, 1], value there)
    unverified: tuple[str, ...]  # keys of the channel whose gradient is not verified
    invisible: tuple[str, ...]  # objects with a non-zero value that this view does not see
    notes: tuple[str, ...] = ()  # what else the layer says about itself (a duality check)


@dataclass(frozen=True)
class InspectionView:
    values: np.ndarray  # (H, W) float32: the painted value, linear, in the channel's units
    display: np.ndarray  # (H, W) float32 in [-1, 1]: what the colours show
    coverage: np.ndarray  # (H, W) fraction of samples that hit an object
    unverified: np.ndarray  # (H, W) coverage of objects whose value is not verified
    legend: Legend


def paint_view(
    buffer: SensitivityBuffer,
    values: ChannelValues,
    visibility: VisibilityPass,
    look: Look,
    shared: DisplayScale,
) -> InspectionView:
    """``values`` painted into ``visibility``'s camera and encoded as ``look`` asks; ``shared``
    is the job's display scale of the channel under ``look.sign`` (``look.scale`` "shared")."""
    encoding = look.encoding(values)
    names = visibility.objects
    per_object = signed_object_values(
        dict(zip(names, values.magnitudes, strict=True)),
        dict(zip(names, values.signed_sums, strict=True)),
        encoding.sign,
    )
    painted = visibility.paint(np.array([per_object[name] for name in names]))
    if look.scale == "view":
        scale, rule = view_own_scale(encoding, painted), "p95 of |v| over this view's pixels"
    else:
        scale, rule = job_shared_scale(encoding, shared), f"{shared.rule()}: the job's scale"
    display = np.clip(encode_image(painted, encoding, scale.threshold, scale.scale), -1.0, 1.0)
    doubtful = unverified_objects(buffer, values)
    mask = visibility.paint(np.array([1.0 if name in doubtful else 0.0 for name in names]))
    seen = set(visibility.visible_objects)
    legend = Legend(
        encoding=encoding.describe(),
        scale_mode=look.scale,
        scale=scale,
        peak=peak_of(scale, encoding.tonemap),
        stops=tuple((p, value_at(p, scale, encoding.tonemap)) for p in LEGEND_STOPS),
        unverified=values.unverified,
        invisible=tuple(sorted(n for n, v in per_object.items() if v and n not in seen)),
        notes=(_clipped_note(rule, painted, peak_of(scale, encoding.tonemap)),),
    )
    return InspectionView(painted, display, visibility.coverage_hit, mask, legend)


def _clipped_note(rule: str, painted: np.ndarray, peak: float) -> str:
    """The scale's rule and the share of this view's painted pixels it saturates."""
    return f"scale: {rule}; {clipped_share([painted], peak):.1%} of painted pixels above it"


def unverified_objects(buffer: SensitivityBuffer, values: ChannelValues) -> frozenset[str]:
    """The objects whose value in this channel includes a gradient that is not verified."""
    return frozenset(owner for key in values.unverified for owner in buffer.param(key).owners)


def paint_image(
    image: np.ndarray,
    visibility: VisibilityPass,
    look: Look,
    unverified: tuple[str, ...],
    notes: tuple[str, ...] = (),
) -> InspectionView:
    """A stored image of the objective camera (a forward or transport layer), resampled to
    ``visibility``'s size (nearest pixel) and encoded as ``look`` asks; both scales are the
    image's own (p95 of |v| over its non-zero pixels), since it is seen from one camera only."""
    rows = _nearest(image.shape[0], visibility.height)
    columns = _nearest(image.shape[1], visibility.width)
    values = np.asarray(image, np.float64)[np.ix_(rows, columns)]
    if look.sign == "magnitude":
        values = np.abs(values)
    tonemap = _COMPRESSIVE[look.sign] if look.compressive else "none"
    encoding = Encoding(sign=look.sign, tonemap=tonemap, normalize="shared")
    scale = view_own_scale(encoding, np.asarray(image, np.float64))
    display = np.clip(encode_image(values, encoding, scale.threshold, scale.scale), -1.0, 1.0)
    legend = Legend(
        encoding=encoding.describe(),
        scale_mode="image",
        scale=scale,
        peak=peak_of(scale, tonemap),
        stops=tuple((p, value_at(p, scale, tonemap)) for p in LEGEND_STOPS),
        unverified=unverified,
        invisible=(),
        notes=notes,
    )
    full = np.ones_like(display)
    doubt = full if unverified else np.zeros_like(display)
    return InspectionView(values.astype(np.float32), display, full, doubt, legend)


def _nearest(source: int, target: int) -> np.ndarray:
    """For each of ``target`` pixels, the ``source`` pixel its centre falls in."""
    return np.minimum((np.arange(target) + 0.5) * source / target, source - 1).astype(np.intp)


def paint_texel(
    field: TexelField, panel: str, visibility: VisibilityPass, look: Look
) -> InspectionView:
    """One of Fig. 4's panels of a texel field (``object``, ``texel``, ``joint``) in this view.

    The panel keeps its channel's own encoding (``sensaov project`` writes the same layer);
    the page's scale choice sets where its colours saturate: the view's own peak, or the
    panel's camera-independent one (the object values' peak, the whole field's, or 1 for the
    joint panel, which is a share of its object's value).
    """
    (shown,) = [p for p in texel_passes(field, visibility, texture_footprint(field, visibility))
                if p.panel == panel]  # fmt: skip
    data = shown.data.sum(axis=2) if shown.data.ndim == 3 else shown.data
    if look.scale == "view":
        own = robust_scale({"view": [np.asarray(data, np.float64)]}, scope="tile").value
        scale = Scale(shown.scale.threshold, own or 1.0)  # the view's p95, in encoded units
    else:
        scale = _panel_scale(field, panel, shown.scale)
    display = np.clip(np.asarray(data, np.float64) / scale.scale, -1.0, 1.0)
    tonemap = "none" if shown.scale.threshold == 0.0 else "log"
    legend = Legend(
        encoding=f"{shown.metadata['encoding']} (fixed by the job's texel channel)",
        scale_mode=look.scale,
        scale=scale,
        peak=peak_of(scale, tonemap),
        stops=tuple((p, value_at(p, scale, tonemap)) for p in LEGEND_STOPS),
        unverified=tuple(json.loads(shown.metadata["unverified"])),
        invisible=(),
        notes=tuple(filter(None, shown.metadata["notes"].split(" | "))),
    )
    doubt = float(bool(legend.unverified))
    mask = visibility.paint(np.array([doubt if o in field.record.owners else 0.0
                                      for o in visibility.objects]))  # fmt: skip
    return InspectionView(
        data.astype(np.float32), display.astype(np.float32), visibility.coverage_hit, mask, legend
    )


def _panel_scale(field: TexelField, panel: str, encoded: Scale) -> Scale:
    """The panel's scale whatever the camera sees, in the units its data are encoded in."""
    if panel == "joint":
        return Scale(0.0, 1.0)
    if panel == "object":
        peak = max((abs(v) for v in field.object_values.values()), default=0.0)
        return Scale(0.0, peak or 1.0)
    summed = float(np.abs(field.pooled.sum(axis=2)).max()) if field.pooled.size else 0.0
    if encoded.threshold > 0.0:  # the panel's log tone map, around the threshold it was made with
        summed = math.log10(1.0 + summed / encoded.threshold)
    return Scale(encoded.threshold, (summed / encoded.scale) or 1.0)
