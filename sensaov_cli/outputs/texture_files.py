"""Texel fields in the texture's own domain, and Fig. 4's three-panel contact sheet.

``<output>/textures/<texture>.<objective>.exr`` holds the field in the texture's own resolution
and UV layout (row 0 = the bitmap's first row, v = 0): ``raw`` (unpooled contributions) and
``pooled`` (the channel's units), as ``Y`` or ``R, G, B``, with a PNG of the pooled field beside
it. Layout: ``docs/exr-layout.md``.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from sensaov_cli.outputs.atomic import atomic_write_all
from sensaov_cli.outputs.contact_sheets import enlarged
from sensaov_cli.outputs.exr import exr_writer
from sensaov_cli.outputs.png import write_png
from sensaov_cli.outputs.previews import contact_sheet, diverging_rgb
from sensaov_cli.outputs.provenance import made_by, provenance_attributes
from sensaov_cli.views.hierarchy import TRUSTED
from sensaov_cli.views.texels import TexelField, TexelPass, white_noise_factor

FORMAT_NAME = "sensaov-texel-exr"
FORMAT_VERSION = 1
_UNSAFE = re.compile(r"[^A-Za-z0-9_-]")


def safe_file_stem(key: str) -> str:
    """``a/b.c`` -> ``a_b_c-<6 hex>``: safe on every file system, unique per key."""
    stem = _UNSAFE.sub("_", key[: -len(".data")] if key.endswith(".data") else key)
    if stem != key:
        stem += "-" + hashlib.sha256(key.encode()).hexdigest()[:6]
    return stem


def write_texture_files(
    folder: Path, fields: Sequence[TexelField], buffer_path: Path
) -> tuple[Path, ...]:
    """One EXR and one PNG per (texture, objective), all replaced together."""
    files: list[tuple[Path, Callable[[Path], None]]] = []
    for field in fields:
        path = folder / f"{safe_file_stem(field.record.key)}.{field.objective}.exr"
        files.append((path, exr_writer(_channels(field), _attributes(field, buffer_path))))
        files.append((path.with_suffix(".png"), _png_writer(field)))
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_all(files)
    return tuple(path for path, _ in files)


def _channels(field: TexelField) -> dict[str, np.ndarray]:
    names = {1: ("Y",), 3: ("R", "G", "B")}.get(field.raw.shape[2], [f"C{i}" for i in range(9)])
    out = {}
    parts = [("raw", field.raw), ("pooled", field.pooled)]
    if field.stderr is not None and field.stderr_pooled is not None:
        parts += [("stderr_raw", field.stderr), ("stderr_pooled", field.stderr_pooled)]
    for part, data in parts:
        for index in range(data.shape[2]):
            out[f"{part}.{names[index]}"] = data[..., index].astype(np.float32)
    return out


def _attributes(field: TexelField, buffer_path: Path) -> dict[str, str]:
    made = {**made_by("project"), "buffer": str(buffer_path)}
    info = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "texture": field.record.key,
        "objective": field.objective,
        "channel": field.channel.name,
        "weight": field.channel.weight,
        "units": field.channel.units,
        "pool": field.pool.describe(),
        "pool_white_noise_factor": white_noise_factor(field.pool),
        "lookup": field.sampling.describe(),
        "signed_sum": field.signed_sum,
        "stderr_reduction": field.stderr_reduction,
        "raw_peak": float(np.abs(field.raw).max()),
        "pooled_peak": float(np.abs(field.pooled).max()),
        "owners": list(field.record.owners),
        "trust": field.record.trust,
        "notes": list(field.notes),
    }
    return {
        **provenance_attributes(made),
        "sensaov/texel": json.dumps(info, sort_keys=True),
    }


def _png_writer(field: TexelField) -> Callable[[Path], None]:
    values = field.pooled.sum(axis=2)
    peak = float(np.abs(values).max())
    rgb = enlarged(diverging_rgb(values, peak))

    def write(tmp: Path) -> None:
        write_png(tmp, rgb, {"sensaov/scale": repr(peak), "sensaov/texture": field.record.key})

    return write


def write_fig4_sheet(
    path: Path,
    camera: str,
    field: TexelField,
    passes: Sequence[TexelPass],
    scales: Sequence[float],
    stamp: Mapping[str, str],
) -> Path:
    """Fig. 4: the object, per-texel and joint panels of one texture side by side, each titled
    with its display scale."""
    mark = " !" if field.record.trust not in TRUSTED else ""
    tiles = [
        (
            f"{p.panel} ±{scale:.2e}{mark}",
            enlarged(diverging_rgb(p.data if p.data.ndim == 2 else p.data.sum(axis=2), scale)),
        )
        for p, scale in zip(passes, scales, strict=True)
    ]
    texture = field.record.key
    title = f"{camera}: {texture} (object | per texel | joint share; ! = not trusted)"
    notes = ["each panel at its own display scale (shared by every camera); the joint panel "
             "at 1 = the object's value spread evenly over the texture"]  # fmt: skip
    sheet = contact_sheet(tiles, len(tiles), scale=1.0, title=title, notes=notes)
    write_png(path, sheet, {**stamp, "sensaov/camera": camera, "sensaov/texture": texture})
    return path
