"""Texel fields of a buffer: per texture and objective, each texel's contribution (§3, §6).

Camera-independent, like every channel's per-object values: computed once from the buffer,
then painted into any camera through its hit UVs (:mod:`.texels`). A texel's contribution is
``c = θ·∂M/∂θ`` (``weight: value``) or ``∂M/∂θ`` (``raw``), per colour component, so the
unpooled field sums exactly to the parameter's signed sum in the buffer; pooling
(:mod:`.pooling`) keeps that sum. ``units: uv_area`` divides by a texel's UV area (1/(H·W)):
a density that reads the same whatever the texture's resolution.
"""

from __future__ import annotations

import fnmatch
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import per_object
from sensaov_cli.errors import SpecError
from sensaov_cli.job.spec import ChannelSpec
from sensaov_cli.views.pooling import Pool, default_pool, pool_field, pool_variance
from sensaov_cli.views.texels import TextureSampling

COLOUR_TYPES = ("reflectance", "radiance", "transmittance", "specular")


@dataclass(frozen=True)
class TexelField:
    """One texture's field for one objective, before painting."""

    objective: str
    channel: ChannelSpec
    record: ParamRecord
    sampling: TextureSampling
    raw: np.ndarray  # (H, W, C) float64 contributions per texel, unpooled
    pooled: np.ndarray  # (H, W, C) float64, pooled, in the channel's units
    pool: Pool
    signed_sum: float  # the buffer's Σ c for this parameter (what both fields sum to)
    object_values: Mapping[str, float]  # Σ c over all parameters of each owner (Fig. 4, left)
    notes: tuple[str, ...]
    # Standard errors (buffers with statistics): of each texel's c, and of the pooled field
    # for independent texel errors (docs/texels.md, "Standard errors"); None without.
    stderr: np.ndarray | None = None
    stderr_pooled: np.ndarray | None = None

    # Cached: each camera's panels state these, and on a 2k texture each is a pass over 12 M
    # values (an exact fsum alone took 0.6 s a camera).
    @functools.cached_property
    def pooled_sum(self) -> float:
        """The pooled field's exact sum, in the buffer's units (it conserves ``signed_sum``)."""
        return math.fsum(self.pooled.ravel()) / self.unit_factor

    @functools.cached_property
    def raw_empty(self) -> np.ndarray:
        """(H, W) bool: texels with no contribution in any channel, before pooling."""
        empty: np.ndarray = np.abs(self.raw).max(axis=2) == 0
        return empty

    @functools.cached_property
    def pooled_empty(self) -> np.ndarray:
        """(H, W) bool: texels that pooling left with nothing in any channel."""
        empty: np.ndarray = np.abs(self.pooled).max(axis=2) == 0
        return empty

    @functools.cached_property
    def stderr_reduction(self) -> float | None:
        """Median over texels with an error of pooled error / unpooled error (same units)."""
        if self.stderr is None or self.stderr_pooled is None:
            return None
        unpooled = self.stderr * self.unit_factor
        has = unpooled > 0
        return float(np.median(self.stderr_pooled[has] / unpooled[has])) if has.any() else None

    @property
    def texel_area(self) -> float:
        height, width = self.raw.shape[:2]
        return 1.0 / (height * width)

    @property
    def unit_factor(self) -> float:
        """What turns a per-texel contribution into the channel's units."""
        return 1.0 / self.texel_area if self.channel.units == "uv_area" else 1.0


def texture_keys(buf: SensitivityBuffer, channel: ChannelSpec, index: int) -> tuple[str, ...]:
    """The texture keys a texel channel shows: its glob over textures, or every texture."""
    textures = [p for p in buf.params if p.is_texture and len(p.shape) == 3]
    keys = tuple(
        p.key
        for p in textures
        if channel.select is None or fnmatch.fnmatchcase(p.key, channel.select)
    )
    if not keys:
        what = f"matches no texture (textures: {', '.join(p.key for p in textures) or 'none'})"
        raise SpecError(
            f"texel channel {channel.name!r} {what}"
            if channel.select
            else f"texel channel {channel.name!r}: the buffer holds no bitmap texture",
            where=f"channels[{index}].select",
            hint="'sensaov params JOB' lists the texture keys",
        )
    return keys


def texel_fields(
    buf: SensitivityBuffer,
    channel: ChannelSpec,
    index: int,
    samplings: Mapping[str, TextureSampling],
) -> list[TexelField]:
    """Every (objective, texture) field a texel channel asks for."""
    keys = texture_keys(buf, channel, index)
    spp = int(buf.provenance.get("spp", 1))
    width, height = buf.provenance.get("resolution", [1, 1])
    fields = []
    for objective in buf.objectives:
        values = per_object(buf, objective.name, method="sum", weight=channel.weight)
        for key in keys:
            sampling = samplings.get(key, TextureSampling(note="no lookup settings: defaults"))
            fields.append(
                _field(buf, objective.name, channel, key, sampling, values, spp * width * height)
            )
    return fields


def _field(
    buf: SensitivityBuffer,
    objective: str,
    channel: ChannelSpec,
    key: str,
    sampling: TextureSampling,
    object_values: Mapping[str, float],
    samples: int,
) -> TexelField:
    record = buf.param(key)
    raw = buf.grad(objective, key).astype(np.float64)
    if channel.weight == "value":
        raw = raw * buf.value(key)
    size = (raw.shape[0], raw.shape[1])
    if channel.pool is None:
        pool = default_pool(1, samples, size)
    else:
        pool = Pool(channel.pool.kind, _job_radius(channel, samples, size), "job")
    factor = raw.shape[0] * raw.shape[1] if channel.units == "uv_area" else 1
    pooled = pool_field(raw, pool, sampling.wrap) * factor
    owners = {name: float(object_values[name]) for name in record.owners}
    stderr = stderr_pooled = None
    if buf.statistics is not None:
        stderr = buf.statistics.stderr[objective][key].astype(np.float64)
        if channel.weight == "value":
            stderr = stderr * np.abs(buf.value(key))
        stderr_pooled = np.sqrt(pool_variance(stderr**2, pool, sampling.wrap)) * factor
    return TexelField(
        objective,
        channel,
        record,
        sampling,
        raw,
        pooled,
        pool,
        math.fsum(raw.ravel()),
        owners,
        _notes(record, sampling),
        stderr,
        stderr_pooled,
    )


def _job_radius(channel: ChannelSpec, samples: int, size: tuple[int, int]) -> float:
    assert channel.pool is not None
    if channel.pool.radius is not None:
        return channel.pool.radius
    return default_pool(1, samples, size).radius


def _notes(record: ParamRecord, sampling: TextureSampling) -> tuple[str, ...]:
    notes = [sampling.note] if sampling.note else []
    if record.trust == "no_gradient":
        notes.append(f"no gradient reached this texture: {record.note}")
    if record.type not in COLOUR_TYPES:
        notes.append(
            f"this bitmap drives '{record.type}', not a colour: its texels are "
            f"{record.type} values and the layer has {record.shape[2]} channel(s)"
        )
    if record.trust not in ("verified", "no_gradient"):
        notes.append(f"gradient {record.trust}: {record.note}")
    return tuple(notes)
