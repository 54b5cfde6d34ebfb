"""PNG previews of a projected view: one legended image per pass, a contact sheet per objective,
and the camera's manifest of what was written from which buffer; texel fields in the texture's
own domain, and Fig. 4's three-panel contact sheet.

Every picture saturates at its layer's display scale (:mod:`sensaov_cli.views.channels`),
so the same object has the same colour in every view; each single preview's legend says the
scale's rule, what it clips and what the layer leaves out. Untrusted layers are hatched. The
manifest ``<previews>/<camera>.json`` lists every file with the buffer id and job version it was
made from: ``sensaov report`` shows exactly those files, and refuses them if they are stale.

``<output>/textures/<texture>.<objective>.exr`` holds a texel field in the texture's own
resolution and UV layout (row 0 = the bitmap's first row, v = 0): ``raw`` (unpooled
contributions) and ``pooled`` (the channel's units), as ``Y`` or ``R, G, B``, with a PNG of the
pooled field beside it. Layout: ``docs/exr-layout.md``.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.outputs.atomic import (
    atomic_write_all,
    atomic_write_bytes,
    file_token,
    made_by,
    provenance_attributes,
)
from sensaov_cli.outputs.exr import exr_writer
from sensaov_cli.outputs.layered_exr import SensitivityLayer
from sensaov_cli.outputs.previews import (
    contact_sheet,
    diverging_rgb,
    hatch,
    neutral,
    underlay,
    write_png,
)
from sensaov_cli.views.channels import DisplayScale, clipped_share, signed_pixels
from sensaov_cli.views.coverage import VisibilityPass
from sensaov_cli.views.hierarchy import TRUSTED
from sensaov_cli.views.texels import TexelField, TexelPass, white_noise_factor

SHEET_COLUMNS = 4
MIN_TILE_WIDTH = 192  # small views are enlarged (nearest neighbour) so labels stay readable
SINGLE_TILE_WIDTH = 256  # a single preview is enlarged further: its legend needs the width
MANIFEST_FORMAT = "sensaov-previews"
MANIFEST_VERSION = 1
SHEET_UNSEEN = 6  # objects a sheet names as not in its view (the single previews name all)
UNTRUSTED_NOTE = "hatched: gradients sensaov does not stand behind, left out of the headline"
NEUTRAL_NOTE = "grey: sign not resolved (within 95 % t interval, or noisy); not in the scale"
TEXEL_FORMAT = "sensaov-texel-exr"
TEXEL_VERSION = 1
_UNSAFE = re.compile(r"[^A-Za-z0-9_-]")


@dataclass(frozen=True)
class PreviewFile:
    """One file of a camera's previews, as its manifest lists it."""

    file: str  # relative to the previews folder
    kind: str  # "layer", "sheet" (an objective's contact sheet) or "fig4"
    objective: str
    pass_name: str = ""
    part: str = "all"  # "trusted" / "untrusted" / "all"
    scale: float | None = None
    scope: str = ""
    rule: str = ""
    clipped: float | None = None  # share of this camera's non-zero pixels above the scale
    clipped_all: float | None = None
    notes: tuple[str, ...] = ()  # the legend's lines, as drawn


def write_previews(
    folder: Path,
    camera: str,
    layers: Sequence[tuple[SensitivityLayer, DisplayScale]],
    beauty: np.ndarray | None,
    visibility: VisibilityPass,
    stamp: Mapping[str, str],
) -> list[PreviewFile]:
    """``folder/<camera>/<objective>.<pass>.png`` per layer and ``folder/<camera>_<objective>.png``
    per objective; the names as they were are kept in each PNG's text, with the ``stamp``."""
    written = []
    sheets: dict[str, list[tuple[str, np.ndarray]]] = defaultdict(list)
    for layer, scale in layers:
        values = signed_pixels(layer.data, layer.kind)
        rgb = diverging_rgb(values, scale.value)
        if layer.neutral is not None:  # unresolved: neither red nor blue
            rgb = neutral(rgb, layer.neutral & (values != 0))
        if beauty is not None:
            rgb = underlay(rgb, beauty[..., :3], visibility.coverage_hit)
        if layer.untrusted:
            rgb = hatch(rgb, values != 0)
        entry = _layer_entry(camera, layer, scale, values)
        names = {"sensaov/camera": camera, "sensaov/objective": layer.objective}
        text = {**stamp, **names, "sensaov/pass": layer.pass_name,
                "sensaov/scale": repr(scale.value), "sensaov/scale_rule": scale.rule(),
                "sensaov/encoding": layer.metadata.get("encoding", "")}  # fmt: skip
        title = f"{layer.objective}.{layer.pass_name} ({camera})"
        tile = enlarged(rgb, SINGLE_TILE_WIDTH)
        sheet = contact_sheet([(_label(layer, scale), tile)], 1, scale=scale.value,
                              title=title, notes=entry.notes)  # fmt: skip
        write_png(folder / entry.file, sheet, text)
        written.append(entry)
        sheets[layer.objective].append((_label(layer, scale), enlarged(rgb, MIN_TILE_WIDTH)))
    for objective, tiles in sheets.items():
        file = f"{file_token(camera)}_{file_token(objective)}.png"
        notes = _sheet_notes(layers, objective)
        sheet = contact_sheet(tiles, SHEET_COLUMNS, scale=1.0,
                              title=f"{camera} / {objective}", notes=notes)  # fmt: skip
        write_png(folder / file, sheet, {**stamp, "sensaov/camera": camera,
                                         "sensaov/objective": objective})  # fmt: skip
        written.append(PreviewFile(file, "sheet", objective, notes=tuple(notes)))
    return written


def write_manifest(
    folder: Path, camera: str, files: Sequence[PreviewFile], stamp: Mapping[str, str]
) -> Path:
    """``folder/<camera>.json``: every preview of the camera and what it was made from.
    Previews only the previous manifest listed (made from another state of the job) go first."""
    path = folder / f"{file_token(camera)}.json"
    _remove_stale(folder, path, {entry.file for entry in files})
    document: dict[str, Any] = {
        "format": MANIFEST_FORMAT,
        "format_version": MANIFEST_VERSION,
        "camera": camera,
        **{key.removeprefix("sensaov/"): value for key, value in stamp.items()},
        "files": [asdict(entry) for entry in files],
    }
    text = json.dumps(document, indent=1, sort_keys=True) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))
    return path


def _remove_stale(folder: Path, manifest: Path, keep: set[str]) -> None:
    try:
        listed = json.loads(manifest.read_text(encoding="utf-8"))["files"]
        old = {entry["file"] for entry in listed if isinstance(entry.get("file"), str)}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return  # no previous manifest, or not one of ours: nothing is ours to remove
    root = folder.resolve()
    for name in sorted(old - keep):
        stale = folder / name
        if (
            stale.suffix == ".png"
            and stale.resolve().is_relative_to(root)
            and not stale.is_symlink()
            and stale.is_file()
        ):
            stale.unlink(missing_ok=True)


def _layer_entry(
    camera: str, layer: SensitivityLayer, scale: DisplayScale, values: np.ndarray
) -> PreviewFile:
    file = f"{file_token(camera)}/{file_token(layer.objective)}.{file_token(layer.pass_name)}.png"
    here = clipped_share([layer.scale_pixels()], scale.value)
    return PreviewFile(
        file=file,
        kind="layer",
        objective=layer.objective,
        pass_name=layer.pass_name,
        part=layer.part or "all",
        scale=scale.value,
        scope=scale.scope,
        rule=scale.rule(),
        clipped=here,
        clipped_all=scale.clipped,
        notes=tuple(_legend_notes(layer, scale, here, values)),
    )


def _legend_notes(
    layer: SensitivityLayer, scale: DisplayScale, here: float, values: np.ndarray
) -> list[str]:
    """The lines under a single preview's colour bar (ASCII: the font has no θ or ∂)."""
    scope = {"shared": "shared scale", "tile": "per-tile scale", "fixed": "fixed scale"}
    lines = [f"{scope[scale.scope]} ±{scale.value:.3g}: {scale.rule()}"]
    if scale.value == 0:
        lines[0] = f"zero in every camera of the rule: {scale.rule()}"
        if layer.neutral is not None and layer.neutral.any():
            lines[0] = f"no resolved value in any camera of the rule: {scale.rule()}"
    elif not values.any():
        lines.append("nothing of it in this view")
    else:
        lines.append(
            f"clipped: {100 * here:.1f} % of this view's non-zero pixels "
            f"({100 * scale.clipped:.1f} % over the rule's cameras)"
        )
    left_out = layer.left_out or {}
    if layer.untrusted:
        held = ", ".join(f"{name} ({len(keys)})" for name, keys in sorted(left_out.items()))
        lines.append(f"{UNTRUSTED_NOTE}: by object (parameters): {held}")
    elif left_out:
        lines.append(f"left out (untrusted, see {layer.pass_name}_untrusted): "
                     + ", ".join(sorted(left_out)))  # fmt: skip
    if layer.zero_valued:
        raw = ", ".join(f"{k} (raw dM/dtheta {v:+.2e})" for k, v in layer.zero_valued.items())
        lines.append(f"theta = 0, scored 0 whatever the gradient: {raw}")
    if layer.invisible:
        lines.append("not in this view: " + ", ".join(layer.invisible))
    unresolved = json.loads(layer.metadata.get("unresolved", "{}"))
    if unresolved:
        lines.append(f"{NEUTRAL_NOTE}: " + ", ".join(sorted(unresolved)))
    if layer.duality_failed:
        lines.append("duality check FAILED: do not trust this layer")
    return lines


def _sheet_notes(
    layers: Sequence[tuple[SensitivityLayer, DisplayScale]], objective: str
) -> list[str]:
    mine = [(layer, scale) for layer, scale in layers if layer.objective == objective]
    scopes = sorted({scale.scope for _, scale in mine})
    shared = ", one per channel across every camera" if "shared" in scopes else ""
    notes = [
        f"colour bar in units of each tile's scale (±, in its label); scales: "
        f"{', '.join(scopes)}{shared}"
    ]
    if any(layer.untrusted for layer, _ in mine):
        notes.append(UNTRUSTED_NOTE)
    if any(layer.neutral is not None and layer.neutral.any() for layer, _ in mine):
        notes.append(NEUTRAL_NOTE)
    # What the tiles cannot show (a failed check, off-frame objects), the failure first and the
    # objects capped: the sheet draws at most MAX_NOTES wrapped lines.
    failed = [layer.pass_name for layer, _ in mine if layer.duality_failed]
    if failed:
        notes.insert(0, "duality check FAILED, do not trust (marked !): " + ", ".join(failed))
    unseen: dict[str, list[str]] = defaultdict(list)
    for layer, _ in mine:
        for name in layer.invisible or ():
            unseen[name].append(layer.pass_name)
    if unseen:
        named = [f"{name} ({', '.join(passes)})" for name, passes in sorted(unseen.items())]
        more = f"; and {len(named) - SHEET_UNSEEN} more" if len(named) > SHEET_UNSEEN else ""
        notes.append(
            "not in this view, so no tile paints them: " + "; ".join(named[:SHEET_UNSEEN]) + more
        )
    return notes


def _label(layer: SensitivityLayer, scale: DisplayScale) -> str:
    marks = " //" if layer.untrusted else ""
    marks += " !" if layer.duality_failed else ""
    tile = " tile" if scale.scope == "tile" else ""
    if scale.value == 0:
        grey = layer.neutral is not None and bool(layer.neutral.any())
        return f"{layer.pass_name}: {'nothing resolved' if grey else '0 everywhere'}{marks}"
    return f"{layer.pass_name} ±{scale.value:.2e}{tile}{marks}"


def enlarged(tile: np.ndarray, width: int = SINGLE_TILE_WIDTH) -> np.ndarray:
    factor = -(-width // tile.shape[1])  # ceil: at least ``width`` pixels across
    return np.repeat(np.repeat(tile, factor, axis=0), factor, axis=1) if factor > 1 else tile


def safe_file_stem(key: str) -> str:
    """``a/b.c`` -> ``a_b_c-<6 hex>``: safe on every file system, unique per key."""
    stem = _UNSAFE.sub("_", key.removesuffix(".data"))
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
        "format": TEXEL_FORMAT,
        "format_version": TEXEL_VERSION,
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
        **provenance_attributes(made, relative_to=buffer_path.parent),
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
