"""OpenEXR files: float32 channels plus string metadata, written atomically, and read back.

The multilayer layout for compositors (beauty, Cryptomatte, sensitivity passes) is assembled in
``exr_layout.py``; this module only moves named channels and header strings to and from disk.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.errors import ExrError
from sensaov_cli.outputs.atomic import atomic_write


def write_exr(path: Path, channels: dict[str, np.ndarray], attributes: dict[str, str]) -> None:
    """Write 2-D float32 ``channels`` (name -> H x W) with ``attributes`` as header strings.

    Arrays are made contiguous first: OpenEXR's Python binding silently writes non-contiguous
    arrays wrong (MITSUBA-NOTES). ZIP compression is lossless, which Cryptomatte IDs require.
    """
    atomic_write(path, exr_writer(channels, attributes))


def exr_writer(
    channels: dict[str, np.ndarray], attributes: dict[str, str]
) -> Callable[[Path], None]:
    """A function writing the EXR to a given (temporary) path, for paired atomic writes."""
    import OpenEXR

    pixels = {name: np.ascontiguousarray(data, dtype=np.float32) for name, data in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(attributes)

    def write(tmp: Path) -> None:
        try:
            with OpenEXR.File(header, pixels) as exr:
                exr.write(str(tmp))
        except RuntimeError as error:  # the binding's only exception type, even for ENOSPC
            raise _os_error(str(error)) from error

    return write


def encode_exr(channels: dict[str, np.ndarray], attributes: dict[str, str]) -> bytes:
    """The EXR ``write_exr`` would write, as bytes in memory (an HTTP answer, no file)."""
    import io

    import OpenEXR

    pixels = {name: np.ascontiguousarray(data, dtype=np.float32) for name, data in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(attributes)
    stream = io.BytesIO()
    with OpenEXR.File(header, pixels) as exr:
        exr.write(stream)
    return stream.getvalue()


def _os_error(message: str) -> OSError:
    """OpenEXR's message as the OSError it reports ("... No space left on device.")."""
    for code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EACCES, errno.EROFS):
        if os.strerror(code) in message:
            return OSError(code, os.strerror(code))
    return OSError(errno.EIO, message)


def image_channels(image: np.ndarray) -> dict[str, np.ndarray]:
    """An (H, W, C) render as named EXR channels: Y, YA, RGB or RGBA."""
    names = {1: "Y", 2: "YA", 3: "RGB"}.get(image.shape[2], "RGBA")
    return {name: image[..., index] for index, name in enumerate(names)}


def read_exr(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Every channel of a scanline EXR by its full name (``layer.pass.Y``) and the header.

    Channels come back as H x W arrays in the stored type (float32, or float16 for half); the
    header as the OpenEXR binding gives it (strings stay strings, windows are arrays).
    """
    import OpenEXR

    if not path.is_file():  # else the OpenEXR library prints its own line to stderr first
        raise ExrError("no such OpenEXR file", where=str(path))
    try:
        # ``separate_channels`` keeps full channel names: by default the binding groups
        # ``X.R``, ``X.G``, ``X.B`` into one ``X`` entry. Read inside ``with``: the File's
        # header and pixels are invalid once it is closed.
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            header = dict(exr.header())
            channels = {name: np.array(ch.pixels, copy=True) for name, ch in exr.channels().items()}
    except (OSError, RuntimeError) as error:
        raise ExrError(
            f"cannot read OpenEXR file: {error}",
            where=str(path),
            hint="check that the path names a complete OpenEXR file",
        ) from error
    return channels, header
