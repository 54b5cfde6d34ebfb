"""``sensaov project``'s texel channels: fields from the buffer, lookups from the scene.

Thin orchestration between the render stage (each bitmap's filter, wrap and ``to_uv``; which
meshes lack UVs), the views (fields, pooling, Fig. 4's panels) and the outputs (layers, the
texture-domain files, the Fig. 4 sheet). Nothing here differentiates.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.job.spec import JobSpec
from sensaov_cli.outputs.layered_exr import SensitivityLayer
from sensaov_cli.outputs.texture_files import safe_file_stem, write_fig4_sheet, write_texture_files
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.render.texture_modes import objects_without_uv, texture_probes
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.display_scale import DisplayScale
from sensaov_cli.views.texels import (
    FILTERS,
    WRAPS,
    Footprint,
    TexelField,
    TexelPass,
    TextureSampling,
    lookup,
    texel_fields,
    texel_passes,
    texture_footprint,
    texture_keys,
)

PROBE_TOLERANCE = 1e-4  # relative to the texture's largest value; float32 lookups agree to ~1e-6


def check_texel_channels(job: JobSpec, buffer: SensitivityBuffer) -> None:
    """Refuse a texel channel that selects no texture before anything is rendered."""
    for index, channel in enumerate(job.channels):
        if channel.kind == "texel":
            texture_keys(buffer, channel, index)


def project_fields(
    job: JobSpec,
    buffer: SensitivityBuffer,
    loaded: LoadedScene,
    buffer_path: Path,
    progress: Progress,
) -> list[TexelField]:
    """The texel fields (camera-independent) and their texture-domain files, timed."""
    if not any(channel.kind == "texel" for channel in job.channels):
        return []
    with progress.stage("texels_s", "texel fields and <output>/textures"):
        fields = prepare(job, buffer, loaded)
        write_domain_files(job.output, fields, buffer_path)
    return fields


def prepare(job: JobSpec, buffer: SensitivityBuffer, loaded: LoadedScene) -> list[TexelField]:
    """Every texel field of the job's texel channels, with the scene's lookup settings."""
    channels = [(i, c) for i, c in enumerate(job.channels) if c.kind == "texel"]
    if not channels:
        return []
    keys = tuple(dict.fromkeys(k for i, c in channels for k in texture_keys(buffer, c, i)))
    probes = texture_probes(loaded.mi, loaded.params, keys, loaded.prepared.bitmap_options)
    samplings = {key: sampling_of(probe) for key, probe in probes.items()}
    no_uv = set(objects_without_uv(loaded.mi, loaded.scene, buffer.objects))
    fields = [f for i, c in channels for f in texel_fields(buffer, c, i, samplings)]
    return [_with_uv_note(f, no_uv) for f in fields]


def sampling_of(probe: dict[str, Any]) -> TextureSampling:
    """The filter and wrap whose lookup reproduces the texture's own values at the probes.

    The scene XML's settings are preferred when they match; a texture whose values cannot tell
    the modes apart (a uniform one) keeps the XML's; one no mode reproduces (a spectral
    variant's upsampled colours) keeps them too, with a note saying the lookup is unconfirmed.
    """
    matrix = np.array(probe["to_uv"], np.float64)
    stated = (probe["filter"], probe["wrap"])
    peak = float(np.abs(probe["values"]).max()) or 1.0
    errors = {}
    for mode in [(f, w) for f in FILTERS for w in WRAPS]:
        got = lookup(probe["texels"], probe["uv"], TextureSampling(*mode, to_uv=matrix))
        errors[mode] = float(np.abs(got - probe["values"]).max()) / peak
    matching = [mode for mode, error in errors.items() if error <= PROBE_TOLERANCE]
    if stated in matching:  # confirmed: any doubt the XML match left is settled
        return TextureSampling(*stated, to_uv=matrix)
    if not matching:
        error = min(errors.values())
        note = f"lookup not confirmed against Mitsuba (error {error:.1e}); {probe['note']}"
        return TextureSampling(*stated, to_uv=matrix, note=note.rstrip("; "))
    chosen = matching[0]
    return TextureSampling(*chosen, to_uv=matrix, note="filter and wrap read from Mitsuba's lookup")


def _with_uv_note(field: TexelField, no_uv: set[str]) -> TexelField:
    missing = sorted(no_uv.intersection(field.record.owners))
    if not missing:
        return field
    note = (
        f"{', '.join(missing)} has no UV coordinates: Mitsuba looks the texture up at each "
        "triangle's barycentric (b1, b2), so the field repeats per triangle"
    )
    return replace(field, notes=(*field.notes, note))


def write_domain_files(output: Path, fields: list[TexelField], buffer_path: Path) -> None:
    if fields:
        write_texture_files(output / "textures", fields, buffer_path)


def camera_layers(
    fields: list[TexelField],
    visibility: VisibilityPass,
    buffer_path: Path,
    camera: str,
) -> list[tuple[list[TexelPass], list[SensitivityLayer]]]:
    """Per field, its three panels and the layers they become.

    A panel's display scale is shared by every texture of its (objective, channel) and every
    camera; the joint panel's is fixed at 1, its meaning (the object's value spread evenly)."""
    result = []
    footprints: dict[tuple[str, str], Footprint] = {}  # one per texture and lookup, not per field
    for field in fields:
        look = (field.record.key, field.sampling.describe())
        if look not in footprints:
            footprints[look] = texture_footprint(field, visibility)
        passes = texel_passes(field, visibility, footprints[look])
        layers = []
        for texel_pass in passes:
            metadata = {
                **texel_pass.metadata,
                "selection": f"texture={field.record.key}",
                "aggregate": "none (per texel component)",
                "weight": field.channel.weight,
                "spp": str(visibility.spp),
                "buffer": str(buffer_path),
                "camera": camera,
                "keys": json.dumps([field.record.key]),
                "invisible": "[]",
                "original_name": f"{field.objective}.{texel_pass.pass_name}",
                "kind": "texel",
                "scale_group": f"{field.objective}/{field.channel.name}/{texel_pass.panel}",
                "scale_role": "reference",
            }
            if texel_pass.panel == "joint":
                metadata["scale_fixed"] = "1.0"
            layer = SensitivityLayer(
                field.objective, texel_pass.pass_name, texel_pass.data, metadata
            )
            layers.append(layer)
        result.append((passes, layers))
    return result


def write_fig4_sheets(
    folder: Path,
    camera: str,
    fields: list[TexelField],
    panels: list[tuple[list[TexelPass], list[SensitivityLayer]]],
    scales: Mapping[tuple[str, str], DisplayScale],
    stamp: Mapping[str, str],
) -> list[tuple[Path, TexelField]]:
    """``<previews>/<camera>_<objective>_<texture>_fig4.png`` per texel field."""
    written = []
    for field, (passes, layers) in zip(fields, panels, strict=True):
        stem = f"{camera}_{field.objective}_{field.channel.name}_{safe_file_stem(field.record.key)}"
        values = [scales[(camera, layer.metadata["scale_group"])].value for layer in layers]
        path = write_fig4_sheet(folder / f"{stem}_fig4.png", camera, passes, values, stamp)
        written.append((path, field))
    return written
