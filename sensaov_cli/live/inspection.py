"""One live inspection view (``sensaov view``): a channel painted through a free camera (§3).

The per-object values come from the buffer once; each camera move only brings a new
:class:`~.coverage.VisibilityPass`, through which they are painted and encoded as the page asks,
on the job's shared scale (``sensaov project``'s, so the page and the files agree;
docs/encoding.md) or the same rule over this view's pixels alone. What the view cannot stand
behind travels with it: objects whose value includes a gradient that is not verified (drawn
hatched), the objects with a value that this view does not see, and the keys behind both. A
view is answered as bytes in memory, never a file.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.queries import combine, key_stats, per_object, rank
from sensaov_cli.outputs.previews import BACKGROUND, NEUTRAL, diverging_rgb
from sensaov_cli.views.channels import (
    ChannelValues,
    DisplayScale,
    Encoding,
    Scale,
    choose_scale,
    clipped_share,
    encode_image,
    painted_values,
    robust_scale,
)
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.hierarchy import (
    Uncertainty,
    orders_disagree,
    other_score,
    repair_error,
    weakest_trust,
)
from sensaov_cli.views.texels import TexelField, texel_passes, texture_footprint
from sensaov_cli.vocabulary import DEFAULT_AGGREGATE, Weight

SCALE_MODES = ("shared", "view")
LEGEND_STOPS = (-1.0, -0.5, 0.0, 0.5, 1.0)
_COMPRESSIVE = {"signed": "symlog", "magnitude": "log"}
HATCH_PERIOD = 8  # pixels between the hatch's diagonal stripes
HATCH_DARKEN = 0.45  # how much a stripe darkens the colour beneath it
LISTED_COMPONENTS = 4  # a colour is listed component by component, a texture summarised


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
    """What the colour bar says: the encoding, the value at each stop, and the caveats (the
    page reads it field by field, as JSON)."""

    encoding: str
    scale_mode: str
    peak: float  # the value, in the channel's units, at which colours saturate
    threshold: float  # of the log tone maps; 0 for a linear one
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
    scale: Scale  # what ``display`` was encoded with
    legend: Legend
    # (H, W) bool: pixels painted mostly by unresolved objects, drawn neutral; None: none
    neutral: np.ndarray | None = None


@dataclass(frozen=True)
class ParameterRow:
    """One parameter of a clicked object, with what a reader needs to judge it: a standard
    error is None where the buffer has no batch statistics (none is claimed that was not
    measured); an array of more than four components (a texture) is summarised."""

    rank: int
    key: str
    type: str
    plugin: str
    components: int
    value: tuple[float, ...]  # every component, or (mean,) for a larger array
    gradient: tuple[float, ...]  # ∂M/∂θ per component, or (sum,) for a larger array
    gradient_se: tuple[float, ...] | None  # its standard error per component (listed only)
    score: float  # the default score of its contributions (how the rows are ranked)
    signed: float  # Σ contributions: > 0 when scaling the parameter up raises M
    signed_se: float | None  # standard error of ``signed``; None without batch statistics
    trust: str
    note: str
    shared_with: tuple[str, ...]  # the parameter's other owners
    dof: int | None = None  # degrees of freedom of ``signed_se``
    resolved: bool | None = None  # None: no error measured; False: drawn neutral, ranked last
    noisy: str | None = None  # why its batches look heavy-tailed
    method: str = DEFAULT_AGGREGATE  # what ``score`` is
    other_score: float | None = None  # by the other aggregate (hierarchy.OTHER_SCORE)
    other_rank: int | None = None  # its rank among the object's parameters by that score
    orders_disagree: bool = False  # the two ranks differ markedly: said on the row


@dataclass(frozen=True)
class ObjectRank:
    """Where an object stands in a per-object channel."""

    object_score: float
    object_signed: float
    object_rank: int
    objects_ranked: int  # objects with a non-zero value
    object_signed_se: float | None = None  # None: the buffer has one batch
    object_dof: int | None = None
    object_resolved: bool | None = None  # False: drawn neutral in the channel's pictures
    object_noisy: str | None = None  # why, when heavy-tailed batches are the reason
    object_method: str = DEFAULT_AGGREGATE  # what ``object_score`` is
    object_other_rank: int | None = None  # its rank by the other score among the objects
    object_orders_disagree: bool = False


@dataclass(frozen=True)
class ObjectSummary:
    """What a click on an object shows: its parameters ranked, their weakest trust, its rank."""

    weight: Weight
    parameters: tuple[ParameterRow, ...]
    trust: str
    rank: ObjectRank | None  # None for a layer that is not a per-object channel


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
    per_object, painted = painted_values(values, visibility, encoding.sign)
    # The unresolved objects' share of each pixel: drawn neutral, never in the view's own scale.
    doubtful_part = visibility.paint(
        np.array([per_object[n] if n in values.unresolved else 0.0 for n in names])
    )
    resolved_part = painted - doubtful_part
    neutral = np.abs(doubtful_part) > np.abs(resolved_part)
    if look.scale == "view":
        own = view_own_scale(encoding, np.where(neutral, 0.0, resolved_part))
        which = " (resolved objects only)" if neutral.any() else ""
        scale, rule = own, f"p95 of |v| over this view's pixels{which}"
    else:  # one scale whatever the camera sees: the colours of project's pictures (Fig. 6)
        scale = choose_scale(replace(encoding, normalize="shared"), {"shared": shared.value})
        rule = f"{shared.rule()}: the job's scale"
    display = np.clip(encode_image(painted, encoding, scale.threshold, scale.scale), -1.0, 1.0)
    doubtful = {owner for key in values.unverified for owner in buffer.param(key).owners}
    mask = visibility.paint(np.array([1.0 if name in doubtful else 0.0 for name in names]))
    seen = set(visibility.visible_objects)
    peak = peak_of(scale, encoding.tonemap)
    clipped = f"scale: {rule}; {clipped_share([painted], peak):.1%} of painted pixels above it"
    unresolved = tuple(f"{name}: {why}" for name, why in sorted(values.unresolved.items()))
    grey = ("grey: unresolved, neither red nor blue, out of the scale",) if unresolved else ()
    legend = _legend(
        encoding.describe(), look.scale, scale, encoding.tonemap, values.unverified,
        invisible=tuple(sorted(n for n, v in per_object.items() if v and n not in seen)),
        notes=(clipped, *grey, *unresolved),
    )  # fmt: skip
    return InspectionView(painted, display, visibility.coverage_hit, mask, scale, legend,
                          neutral if neutral.any() else None)  # fmt: skip


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
    legend = _legend(encoding.describe(), "image", scale, tonemap, unverified, (), notes)
    full = np.ones_like(display)
    doubt = full if unverified else np.zeros_like(display)
    return InspectionView(values.astype(np.float32), display, full, doubt, scale, legend)


def _nearest(source: int, target: int) -> np.ndarray:
    """For each of ``target`` pixels, the ``source`` pixel its centre falls in."""
    return np.minimum((np.arange(target) + 0.5) * source / target, source - 1).astype(np.intp)


def paint_texel(
    field: TexelField, panel: str, visibility: VisibilityPass, look: Look
) -> InspectionView:
    """One of Fig. 4's panels of a texel field in this view, in its channel's own encoding
    (``sensaov project`` writes the same layer); the page's scale choice sets where its colours
    saturate: the view's own peak, or the panel's camera-independent one."""
    (shown,) = [p for p in texel_passes(field, visibility, texture_footprint(field, visibility))
                if p.panel == panel]  # fmt: skip
    data = shown.data.sum(axis=2) if shown.data.ndim == 3 else shown.data
    if look.scale == "view":  # never set by what is drawn neutral (unresolved)
        scoped = data if shown.neutral is None else np.where(shown.neutral, 0.0, data)
        own = robust_scale({"view": [np.asarray(scoped, np.float64)]}, scope="tile").value
        scale = Scale(shown.scale.threshold, own or 1.0)  # the view's p95, in encoded units
    else:
        scale = _panel_scale(field, panel, shown.scale)
    display = np.clip(np.asarray(data, np.float64) / scale.scale, -1.0, 1.0).astype(np.float32)
    legend = _legend(
        f"{shown.metadata['encoding']} (fixed by the job's texel channel)",
        look.scale, scale, "none" if shown.scale.threshold == 0.0 else "log",
        tuple(json.loads(shown.metadata["unverified"])),
        invisible=(), notes=tuple(filter(None, shown.metadata["notes"].split(" | "))),
    )  # fmt: skip
    doubt = float(bool(legend.unverified))
    mask = visibility.paint(np.array([doubt if o in field.record.owners else 0.0
                                      for o in visibility.objects]))  # fmt: skip
    values = data.astype(np.float32)
    return InspectionView(values, display, visibility.coverage_hit, mask, scale, legend,
                          shown.neutral)  # fmt: skip


def _panel_scale(field: TexelField, panel: str, encoded: Scale) -> Scale:
    """The panel's scale whatever the camera sees, in the units its data are encoded in: the
    object values' peak, the whole field's, or 1 for the joint panel (a share of its object's)."""
    if panel == "joint":
        return Scale(0.0, 1.0)
    if panel == "object":
        peak = max((abs(v) for v in field.object_values.values()), default=0.0)
        return Scale(0.0, peak or 1.0)
    summed = float(np.abs(field.pooled.sum(axis=2)).max()) if field.pooled.size else 0.0
    if encoded.threshold > 0.0:  # the panel's log tone map, around the threshold it was made with
        summed = math.log10(1.0 + summed / encoded.threshold)
    return Scale(encoded.threshold, (summed / encoded.scale) or 1.0)


def view_own_scale(encoding: Encoding, painted: np.ndarray) -> Scale:
    """This view's own scale: the job's rule (:func:`~.channels.robust_scale`) over this
    view's painted pixels alone, so neither an object off frame (an environment light, a lamp
    behind the camera) nor a few bright pixels wash the picture out."""
    own = robust_scale({"view": [painted]}, scope="tile")
    return choose_scale(replace(encoding, normalize="shared"), {"own": own.value})


def _legend(
    encoding: str,
    scale_mode: str,
    scale: Scale,
    tonemap: str,
    unverified: tuple[str, ...],
    invisible: tuple[str, ...],
    notes: tuple[str, ...],
) -> Legend:
    """The colour bar of ``scale``: its peak and the value at each stop, in the channel's units."""
    stops = tuple((p, value_at(p, scale, tonemap)) for p in LEGEND_STOPS)
    peak = peak_of(scale, tonemap)
    return Legend(encoding, scale_mode, peak, scale.threshold, stops, unverified, invisible, notes)


def peak_of(scale: Scale, tonemap: str) -> float:
    """The value, in the channel's units, at which colours saturate under ``scale``."""
    if tonemap == "none":
        return scale.scale
    return scale.threshold * (10.0**scale.scale - 1.0)


def value_at(position: float, scale: Scale, tonemap: str) -> float:
    """The channel value drawn at ``position`` in [-1, 1] of the colour bar (its inverse)."""
    t = position * scale.scale
    if tonemap == "none":
        return t
    return math.copysign(scale.threshold * (10.0 ** abs(t) - 1.0), t)


def object_summary(
    buffer: SensitivityBuffer, objective: str, obj: str, channel: ChannelValues | None
) -> ObjectSummary:
    """What a click on ``obj`` shows: its parameters ranked with the weight of ``channel`` (the
    per-object channel on screen; None for another layer) and its rank among that channel's."""
    weight = channel.spec.weight if channel is not None else "value"
    rows = object_parameters(buffer, objective, obj, weight)
    trust = weakest_trust(buffer, [r.key for r in rows]) if rows else "verified"
    standing = None if channel is None else object_rank(buffer, objective, obj, channel)
    return ObjectSummary(weight, tuple(rows), trust, standing)


def object_rank(
    buffer: SensitivityBuffer, objective: str, obj: str, channel: ChannelValues
) -> ObjectRank:
    """Where ``obj`` stands in ``channel``: its score with its error and resolution, its rank
    (the unresolved after the resolved, as the rankings order them) and its rank by the other
    score, flagged where the two disagree markedly."""
    names = list(buffer.objects)
    index = names.index(obj)
    magnitude = np.abs(channel.magnitudes)
    first = [i for i in range(len(names)) if names[i] not in channel.unresolved]
    last = [i for i in range(len(names)) if names[i] in channel.unresolved]
    order = [i for group in (first, last) for i in sorted(group, key=lambda i: -magnitude[i])]
    method = channel.spec.aggregate
    other = per_object(buffer, objective, method=other_score(method), weight=channel.spec.weight,
                       keys=channel.keys)  # fmt: skip
    other_order = sorted(range(len(names)), key=lambda i: -abs(other[names[i]]))
    keys = [k for k in channel.keys if obj in buffer.param(k).owners]
    noise = Uncertainty.of(buffer, objective, "sum", channel.spec.weight)
    error = None if noise is None or not keys else noise.error(keys, channel.signed_sums[index])
    rank, by_other = order.index(index) + 1, other_order.index(index) + 1
    return ObjectRank(
        object_score=float(channel.magnitudes[index]),
        object_signed=float(channel.signed_sums[index]),
        object_rank=rank,
        objects_ranked=int((magnitude > 0).sum()),
        object_signed_se=None if error is None else error.signed_se,
        object_dof=None if error is None else error.dof,
        object_resolved=None if error is None else obj not in channel.unresolved,
        object_noisy=None if error is None else error.noisy,
        object_method=method,
        object_other_rank=by_other,
        object_orders_disagree=orders_disagree(rank, by_other),
    )


def object_parameters(
    buf: SensitivityBuffer, objective: str, obj: str, weight: Weight = "value"
) -> list[ParameterRow]:
    """The parameters ``obj`` owns, ranked by the default score of their contributions to
    ``objective`` (the unresolved after the resolved), each with its rank by the other score."""
    keys = [p.key for p in buf.params if obj in p.owners]
    stats = key_stats(buf, objective, keys, weight=weight)
    method, other = DEFAULT_AGGREGATE, other_score(DEFAULT_AGGREGATE)
    noise = Uncertainty.of(buf, objective, method, weight)
    other_scores = {key: combine([stats[key]], other) for key in keys}
    other_rank = {key: i for i, (key, _) in enumerate(rank(other_scores), 1)}
    errors = {key: _judged(buf, objective, key, stats[key].total, weight, noise) for key in keys}
    scored = rank({key: combine([stats[key]], method) for key in keys})
    unresolved = {k for k, e in errors.items() if e is not None and not e.resolved}
    ordered = [(k, s) for k, s in scored if k not in unresolved]
    ordered += [(k, s) for k, s in scored if k in unresolved]
    rows = []
    for index, (key, score) in enumerate(ordered, 1):
        record = buf.param(key)
        value = buf.value(key).astype(np.float64).ravel()
        grad = buf.grad(objective, key).astype(np.float64).ravel()
        listed = value.size <= LISTED_COMPONENTS
        se = None if buf.statistics is None or not listed else buf.statistics.stderr[objective][key]
        rows.append(
            ParameterRow(
                rank=index,
                key=key,
                type=record.type,
                plugin=record.plugin,
                components=int(value.size),
                value=tuple(map(float, value)) if listed else (float(value.mean()),),
                gradient=tuple(map(float, grad)) if listed else (float(grad.sum()),),
                gradient_se=None if se is None else tuple(map(float, np.asarray(se).ravel())),
                score=score,
                signed=stats[key].total,
                signed_se=None if (error := errors[key]) is None else error.signed_se,
                trust=record.trust,
                note=record.note,
                shared_with=tuple(o for o in record.owners if o != obj),
                dof=None if error is None else error.dof,
                resolved=None if error is None else error.resolved,
                noisy=None if error is None else error.noisy,
                method=method,
                other_score=other_scores[key],
                other_rank=other_rank[key],
                orders_disagree=orders_disagree(index, other_rank[key]),
            )
        )
    return rows


@dataclass(frozen=True)
class _Judged:
    """A parameter's error and resolution: from the batches, or a repair's own seeds."""

    signed_se: float
    dof: int
    resolved: bool
    noisy: str | None


def _judged(
    buf: SensitivityBuffer,
    objective: str,
    key: str,
    signed: float,
    weight: Weight,
    noise: Uncertainty | None,
) -> _Judged | None:
    """None where nothing measured an error (one batch, and not a repair with seeds)."""
    if noise is not None:
        error = noise.error([key], signed)  # the score is the sum: the signed sum is the score
        return _Judged(error.signed_se, error.dof, error.resolves(signed), error.noisy)
    repaired = repair_error(buf, objective, key, signed, weight)
    if repaired is None:
        return None
    return _Judged(repaired.signed_se, repaired.dof, repaired.resolved, repaired.noisy)


def view_rgb(
    display: np.ndarray,
    coverage: np.ndarray,
    unverified: np.ndarray,
    neutral: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W, 3) uint8: ``display`` in [-1, 1] on the previews' diverging map (blue lowers M,
    red raises it, white is 0), neutral grey where ``neutral`` (unresolved), blended into their
    dark grey by the coverage, and hatched where a value includes a gradient that is not
    verified (never drawn plain)."""
    colour = diverging_rgb(display, 1.0).astype(np.float64)
    if neutral is not None:
        colour[neutral & (display != 0)] = NEUTRAL
    height, width = display.shape
    rows, columns = np.indices((height, width))
    stripe = ((rows + columns) % HATCH_PERIOD) < HATCH_PERIOD // 4
    darken = 1.0 - HATCH_DARKEN * stripe * np.clip(unverified, 0.0, 1.0)
    colour *= darken[..., None]
    alpha = np.clip(coverage, 0.0, 1.0)[..., None]
    blended = alpha * colour + (1.0 - alpha) * np.array(BACKGROUND, np.float64)
    return np.rint(blended).astype(np.uint8)
