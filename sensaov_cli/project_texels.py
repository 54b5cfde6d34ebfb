"""``sensaov project``'s texel channels: fields from the buffer, lookups from the scene.

Thin orchestration between the render stage (each bitmap's filter, wrap and ``to_uv``; which
meshes lack UVs), the views (fields, pooling, Fig. 4's panels) and the outputs (layers, the
texture-domain files, the Fig. 4 sheet). Nothing here differentiates.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.outputs.layered_exr import SensitivityLayer
from sensaov_cli.outputs.texture_files import safe_file_stem, write_fig4_sheet, write_texture_files
from sensaov_cli.render.scene import LoadedScene
from sensaov_cli.render.texture_modes import objects_without_uv, texture_sampling
from sensaov_cli.spec.model import JobSpec
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.texel_fields import TexelField, texel_fields, texture_keys
from sensaov_cli.views.texel_passes import TexelPass, texel_passes
from sensaov_cli.views.texels import TextureSampling


def check_texel_channels(job: JobSpec, buffer: SensitivityBuffer) -> None:
    """Refuse a texel channel that selects no texture before anything is rendered."""
    for index, channel in enumerate(job.channels):
        if channel.kind == "texel":
            texture_keys(buffer, channel, index)


def prepare(job: JobSpec, buffer: SensitivityBuffer, loaded: LoadedScene) -> list[TexelField]:
    """Every texel field of the job's texel channels, with the scene's lookup settings."""
    channels = [(i, c) for i, c in enumerate(job.channels) if c.kind == "texel"]
    if not channels:
        return []
    keys = tuple(dict.fromkeys(k for i, c in channels for k in texture_keys(buffer, c, i)))
    found = texture_sampling(loaded.mi, loaded.params, keys, loaded.bitmap_options)
    samplings = {
        key: TextureSampling(s["filter"], s["wrap"], np.array(s["to_uv"]), s["note"])
        for key, s in found.items()
    }
    no_uv = set(objects_without_uv(loaded.mi, loaded.scene, buffer.objects))
    fields = [f for i, c in channels for f in texel_fields(buffer, c, i, samplings)]
    return [_with_uv_note(f, no_uv) for f in fields]


def _with_uv_note(field: TexelField, no_uv: set[str]) -> TexelField:
    missing = sorted(no_uv.intersection(field.record.owners))
    if not missing:
        return field
    note = f"{', '.join(missing)} has no UV coordinates: Mitsuba reads texel (0, 0) wherever hit"
    return replace(field, notes=(*field.notes, note))


def write_domain_files(output: Path, fields: list[TexelField], buffer_path: Path) -> None:
    if fields:
        write_texture_files(output / "textures", fields, buffer_path)


def camera_layers(
    fields: list[TexelField],
    visibility: VisibilityPass,
    buffer_path: Path,
    camera: str,
) -> list[tuple[list[TexelPass], list[tuple[SensitivityLayer, float]]]]:
    """Per field, its three panels and the layers (with preview scales) they become."""
    result = []
    for field in fields:
        passes = texel_passes(field, visibility)
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
            }
            layer = SensitivityLayer(
                field.objective, texel_pass.pass_name, texel_pass.data, metadata
            )
            layers.append((layer, texel_pass.preview_scale))
        result.append((passes, layers))
    return result


def write_fig4_sheets(
    folder: Path,
    camera: str,
    fields: list[TexelField],
    panels: list[tuple[list[TexelPass], list[tuple[SensitivityLayer, float]]]],
) -> tuple[Path, ...]:
    """``<previews>/<camera>_<objective>_<texture>_fig4.png`` per texel field."""
    paths = []
    for field, (passes, _) in zip(fields, panels, strict=True):
        stem = f"{camera}_{field.objective}_{field.channel.name}_{safe_file_stem(field.record.key)}"
        paths.append(write_fig4_sheet(folder / f"{stem}_fig4.png", camera, passes))
    return tuple(paths)
