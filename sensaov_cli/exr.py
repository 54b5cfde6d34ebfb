"""OpenEXR output: float32 channels plus string metadata, written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_write


def write_exr(path: Path, channels: dict[str, np.ndarray], attributes: dict[str, str]) -> None:
    """Write 2-D float32 ``channels`` (name -> H x W) with ``attributes`` as header strings.

    Arrays are made contiguous first: OpenEXR's Python binding silently writes non-contiguous
    arrays wrong (MITSUBA-NOTES). ZIP compression is lossless, which Cryptomatte IDs require.
    """
    import OpenEXR

    pixels = {name: np.ascontiguousarray(data, dtype=np.float32) for name, data in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(attributes)

    def write(tmp: Path) -> None:
        with OpenEXR.File(header, pixels) as exr:
            exr.write(str(tmp))

    atomic_write(path, write)


def image_channels(image: np.ndarray) -> dict[str, np.ndarray]:
    """An (H, W, C) render as named EXR channels (R, G, B and A when present)."""
    names = "RGBA" if image.shape[2] >= 4 else "RGB"
    if image.shape[2] == 1:
        names = "Y"
    return {name: image[..., index] for index, name in enumerate(names)}
