"""PNG files: encoded by Pillow in memory, written atomically, read back whole or for their text.

OpenImageIO's PNG writer reports success on a full disk and leaves a cut-off file; Python's
``write`` raises ``OSError`` for every failure. Text chunks (``tEXt``, Latin-1) trace a preview
back to its data. Pillow's encoder holds the GIL, so previews are written one after the other.
"""

from __future__ import annotations

import io
import struct
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin

from sensaov_cli.outputs.atomic import atomic_write_bytes

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_MAX_KEYWORD = 79  # bytes, by the PNG specification
# A header declaring more pixels than Pillow decodes (the warning: made an error below).
_TOO_LARGE = (Image.DecompressionBombError, Image.DecompressionBombWarning)
LEVEL = 3  # zlib's level for files: nearly as small as the default 6, far faster


def encode_png(
    rgb_uint8: np.ndarray, text: Mapping[str, str] | None = None, level: int = LEVEL
) -> bytes:
    """An (H, W, 3) uint8 image as PNG bytes (8-bit RGB, no interlace), with ``text`` as
    ``tEXt`` chunks (what Latin-1 cannot hold becomes ``?``); ``level`` is zlib's."""
    check_rgb(rgb_uint8)
    info = PngImagePlugin.PngInfo()
    for key, value in (text or {}).items():
        keyword = key.encode("latin-1", "replace")[:_MAX_KEYWORD]
        info.add_text(keyword, value.encode("latin-1", "replace"))  # bytes: always tEXt
    out = io.BytesIO()
    Image.fromarray(rgb_uint8).save(out, "PNG", pnginfo=info, compress_level=level)
    return out.getvalue()


def write_png(path: Path, rgb_uint8: np.ndarray, text: Mapping[str, str] | None = None) -> None:
    atomic_write_bytes(Path(path), encode_png(rgb_uint8, text))


def check_rgb(rgb: np.ndarray) -> None:
    """Refuse anything but an (H, W, 3) uint8 image: Pillow would write another kind of PNG
    (grey, RGBA, 16-bit) without a word."""
    if rgb.dtype != np.uint8:
        raise ValueError(f"expected a uint8 image, got {rgb.dtype}")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {rgb.shape}")


def png_problem(data: bytes) -> str | None:
    """Why ``data`` is not a whole PNG a browser shows as written (None: it is): every chunk's
    checksum through IEND, and pixels that decode to the size the header declares. A header
    declaring more pixels than Pillow's decompression-bomb limit is refused before decoding."""
    if not data:
        return "an empty file"
    if not data.startswith(_SIGNATURE):
        return "not a PNG file"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data), formats=["PNG"]) as image:
                image.verify()
            with Image.open(io.BytesIO(data), formats=["PNG"]) as image:
                image.load()
    except Image.UnidentifiedImageError:  # its message names the stream, not the cause
        return "a PNG whose header chunks are damaged"
    # Pillow says a file is damaged with OSError (cut short), SyntaxError (a checksum),
    # struct.error (a chunk cut short) or ValueError.
    except (OSError, SyntaxError, struct.error, ValueError, *_TOO_LARGE) as error:
        return f"not a whole PNG ({' '.join(str(error).split())[:120]})"
    return None


def read_png_text(path: Path) -> dict[str, str]:
    """The text chunks of a PNG file before its pixels (where sensaov writes its text), without
    decoding the pixels. Raises ``OSError`` or ``ValueError`` for a damaged file."""
    with Image.open(path, formats=["PNG"]) as image:
        info = image.info.items()  # text as str; the rest (gamma, dpi, ...) as other types
        return {
            key: value for key, value in info if isinstance(key, str) and isinstance(value, str)
        }
