"""PNG previews of a projected view: one image per pass and a labelled contact sheet.

Each pass is coloured at the largest value among the objects this camera sees, so an object
no camera shows (an environment map, a point light, anything off-frame) never washes the
picture out; a pass whose objects all lie out of view is titled "unseen".
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sensaov_cli.outputs.layered_exr import SensitivityLayer
from sensaov_cli.outputs.names import file_token
from sensaov_cli.outputs.previews import contact_sheet, diverging_rgb, underlay, write_png
from sensaov_cli.views.coverage import VisibilityPass

SHEET_COLUMNS = 4
REC709_LUMA = (0.2126, 0.7152, 0.0722)
MIN_TILE_WIDTH = 192  # small views are enlarged (nearest neighbour) so labels stay readable


def write_previews(
    folder: Path,
    camera: str,
    layers: Sequence[tuple[SensitivityLayer, float]],
    beauty: np.ndarray | None,
    visibility: VisibilityPass,
) -> tuple[Path, ...]:
    """Write ``folder/<camera>/<objective>.<pass>.png`` and ``folder/<camera>_<objective>.png``.

    Every name in a path is a :func:`~.names.file_token` (a buffer's objective names come from
    whoever wrote it); the names as they were are kept in each PNG's text chunks.
    """
    written = []
    sheets: dict[str, list[tuple[str, np.ndarray]]] = defaultdict(list)
    for layer, scale in layers:
        values = _signed(layer)
        rgb = diverging_rgb(values, scale)
        if beauty is not None:
            rgb = underlay(rgb, beauty[..., :3], visibility.coverage_hit)
        path = (
            folder
            / file_token(camera)
            / f"{file_token(layer.objective)}.{file_token(layer.pass_name)}.png"
        )
        names = {"sensaov/camera": camera, "sensaov/objective": layer.objective}
        write_png(
            path,
            rgb,
            {
                **names,
                "sensaov/pass": layer.pass_name,
                "sensaov/scale": repr(scale),
                "sensaov/encoding": layer.metadata.get("encoding", ""),
            },
        )
        written.append(path)
        tile = _enlarged(diverging_rgb(values / (scale or 1.0), 1.0))
        marked = layer.metadata.get("duality", "agrees") != "agrees"  # a transport layer's check
        mark = " !" if marked or json.loads(layer.metadata.get("unverified", "[]")) else ""
        title = f"{layer.pass_name} +-{scale:.2e}{mark}"
        if not values.any() and json.loads(layer.metadata.get("invisible", "[]")):
            title = f"{layer.pass_name}: unseen{mark}"  # it matters; this camera does not see it
        sheets[layer.objective].append((title, tile))
    for objective, tiles in sheets.items():
        sheet = contact_sheet(
            tiles,
            SHEET_COLUMNS,
            scale=1.0,
            title=f"{camera} / {objective}: each tile at its own +-scale; ! = unverified gradients",
        )
        path = folder / f"{file_token(camera)}_{file_token(objective)}.png"
        write_png(path, sheet, {"sensaov/camera": camera, "sensaov/objective": objective})
        written.append(path)
    return tuple(written)


def _signed(layer: SensitivityLayer) -> np.ndarray:
    """One signed value per pixel. An RGB image (a forward channel's J·v) by its luminance; an
    RGB texel field by the sum of its components, the effect of scaling all three together."""
    data = layer.data
    if data.ndim == 2:
        return data
    if layer.metadata.get("kind") in ("forward", "transport"):
        return data[..., :3] @ np.array(REC709_LUMA, data.dtype)
    return data.sum(axis=2)


def _enlarged(tile: np.ndarray) -> np.ndarray:
    factor = -(-MIN_TILE_WIDTH // tile.shape[1])  # ceil
    return np.repeat(np.repeat(tile, factor, axis=0), factor, axis=1) if factor > 1 else tile
