"""What ``sensaov view`` answers for a view: PNG, EXR or an object-id map, as bytes in memory.

Nothing here touches the disk: a live view is an answer to one request, not an output file.
The PNG uses the previews' diverging map (blue lowers M, red raises it, white is 0), blended
into the previews' dark grey by the coverage, and hatches objects whose value includes a
gradient that is not verified (a number the tool cannot stand behind is never drawn plain).
Each PNG and EXR carries the encoding, the scale and the camera in its header.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sensaov_cli.outputs.exr import encode_exr
from sensaov_cli.outputs.png import encode_png
from sensaov_cli.outputs.previews import BACKGROUND, diverging_rgb

HATCH_PERIOD = 8  # pixels between the hatch's diagonal stripes
HATCH_DARKEN = 0.45  # how much a stripe darkens the colour beneath it


def view_rgb(display: np.ndarray, coverage: np.ndarray, unverified: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: ``display`` in [-1, 1] coloured, background grey, doubt hatched."""
    colour = diverging_rgb(display, 1.0).astype(np.float64)
    height, width = display.shape
    rows, columns = np.indices((height, width))
    stripe = ((rows + columns) % HATCH_PERIOD) < HATCH_PERIOD // 4
    darken = 1.0 - HATCH_DARKEN * stripe * np.clip(unverified, 0.0, 1.0)
    colour *= darken[..., None]
    alpha = np.clip(coverage, 0.0, 1.0)[..., None]
    blended = alpha * colour + (1.0 - alpha) * np.array(BACKGROUND, np.float64)
    return np.rint(blended).astype(np.uint8)


def png_bytes(rgb: np.ndarray, text: Mapping[str, str]) -> bytes:
    """The PNG of an (H, W, 3) uint8 image, fast to compress (a view lives for one look)."""
    return encode_png(rgb, text, level=1)


def exr_bytes(layer: str, values: np.ndarray, attributes: Mapping[str, str]) -> bytes:
    """The raw layer ``<layer>.Y`` (linear, in the channel's units) as a one-layer EXR."""
    return encode_exr({f"{layer}.Y": values}, dict(attributes))


def id_map_bytes(rank_index: np.ndarray) -> bytes:
    """Per pixel, the index of the object with the most coverage (-1: none), int32 LE."""
    return np.ascontiguousarray(rank_index[..., 0], dtype="<i4").tobytes()
