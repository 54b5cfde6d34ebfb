"""PNG files written with the standard library, so that every byte's write is checked.

OpenImageIO's PNG writer reports success on a full disk and leaves a cut-off file; here the
bytes are encoded in memory (zlib, filter 0) and written by Python, whose ``write`` raises
``OSError`` (``ENOSPC``, ``EIO``) for every failure, and then renamed into place atomically.
Text chunks (``tEXt``, Latin-1) carry the attributes that trace a preview back to its data.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sensaov_cli.outputs.atomic import atomic_write

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_MAX_KEYWORD = 79  # bytes, by the PNG specification


def encode_png(
    rgb_uint8: np.ndarray, text: Mapping[str, str] | None = None, level: int = 6
) -> bytes:
    """An (H, W, 3) uint8 image as PNG bytes (8-bit RGB, no interlace), with ``text`` chunks;
    ``level`` is zlib's compression level."""
    height, width = rgb_uint8.shape[:2]
    rows = np.zeros((height, 1 + width * 3), np.uint8)  # filter byte 0 ("none") per row
    rows[:, 1:] = np.ascontiguousarray(rgb_uint8).reshape(height, width * 3)
    chunks = [_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))]
    for key, value in (text or {}).items():
        keyword = key.encode("latin-1", "replace")[:_MAX_KEYWORD]
        chunks.append(_chunk(b"tEXt", keyword + b"\0" + value.encode("latin-1", "replace")))
    chunks.append(_chunk(b"IDAT", zlib.compress(rows.tobytes(), level)))
    chunks.append(_chunk(b"IEND", b""))
    return _SIGNATURE + b"".join(chunks)


def write_png_file(path: Path, rgb_uint8: np.ndarray, text: Mapping[str, str] | None) -> None:
    """Encode, then write atomically: a failed write leaves the previous file as it was."""
    data = encode_png(rgb_uint8, text)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as stream:
            stream.write(data)  # raises OSError on a short write; close flushes, and may raise

    atomic_write(path, write)


def _chunk(kind: bytes, body: bytes) -> bytes:
    crc = zlib.crc32(kind + body) & 0xFFFFFFFF
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)
