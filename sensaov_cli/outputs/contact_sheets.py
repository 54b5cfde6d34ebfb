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
from sensaov_cli.outputs.previews import contact_sheet, diverging_rgb, underlay, write_png
from sensaov_cli.views.coverage import VisibilityPass

SHEET_COLUMNS = 4
MIN_TILE_WIDTH = 192  # small views are enlarged (nearest neighbour) so labels stay readable


def write_previews(
    folder: Path,
    camera: str,
    layers: Sequence[tuple[SensitivityLayer, float]],
    beauty: np.ndarray | None,
    visibility: VisibilityPass,
) -> tuple[Path, ...]:
    """Write ``folder/<camera>/<objective>.<pass>.png`` and ``folder/<camera>_<objective>.png``."""
    written = []
    sheets: dict[str, list[tuple[str, np.ndarray]]] = defaultdict(list)
    for layer, scale in layers:
        # An RGB pass (a texel field) is previewed as the sum of its components: the effect
        # of scaling all three together.
        data = layer.data if layer.data.ndim == 2 else layer.data.sum(axis=2)
        rgb = diverging_rgb(data, scale)
        if beauty is not None:
            rgb = underlay(rgb, beauty[..., :3], visibility.coverage_hit)
        path = folder / camera / f"{layer.objective}.{layer.pass_name}.png"
        write_png(
            path,
            rgb,
            {"sensaov/scale": repr(scale), "sensaov/encoding": layer.metadata.get("encoding", "")},
        )
        written.append(path)
        tile = _enlarged(diverging_rgb(data / (scale or 1.0), 1.0))
        mark = " !" if json.loads(layer.metadata.get("unverified", "[]")) else ""
        title = f"{layer.pass_name} +-{scale:.2e}{mark}"
        if not data.any() and json.loads(layer.metadata.get("invisible", "[]")):
            title = f"{layer.pass_name}: unseen{mark}"  # it matters; this camera does not see it
        sheets[layer.objective].append((title, tile))
    for objective, tiles in sheets.items():
        sheet = contact_sheet(
            tiles,
            SHEET_COLUMNS,
            scale=1.0,
            title=f"{camera} / {objective}: each tile at its own +-scale; ! = unverified gradients",
        )
        path = folder / f"{camera}_{objective}.png"
        write_png(path, sheet)
        written.append(path)
    return tuple(written)


def _enlarged(tile: np.ndarray) -> np.ndarray:
    factor = -(-MIN_TILE_WIDTH // tile.shape[1])  # ceil
    return np.repeat(np.repeat(tile, factor, axis=0), factor, axis=1) if factor > 1 else tile
