"""The size an image file declares in its header, read without decoding the image (pure Python).

A 6 kB PNG may declare 40000x40000 pixels: Mitsuba allocates them all (76 GB as float32) and
the process dies without a word. So before Mitsuba loads a scene, every image it will read
(the formats of Mitsuba's ``Bitmap``: PNG, JPEG, OpenEXR, Radiance RGBE, PFM, PPM, BMP, TGA) is
measured from its first bytes and checked against the memory budget (:func:`check_image`).
A file in none of these formats is left to Mitsuba, which says what it thinks of it.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from pathlib import Path

from sensaov_cli.errors import SceneError
from sensaov_cli.limits import check_memory

HEAD_BYTES = 1 << 16  # a header (EXR attributes, JPEG markers before the frame) fits in this
TEXTURE_COPIES = 4  # the file's pixels, their float conversion, the texture, a gradient leaf

Size = tuple[int, int, int]  # width, height, channels


def check_image(path: Path, where: str) -> None:
    """Refuse an image whose declared pixels, once loaded, are over the memory budget."""
    size = declared_size(path, where)
    if size is None:
        return
    width, height, channels = size
    check_memory(
        width * height * channels * 4 * TEXTURE_COPIES,
        f"loading {path.name}, which declares {width}x{height} pixels x {channels} channels,",
        where=where,
        hint="check the image, or make it smaller",
    )


def declared_size(path: Path, where: str) -> Size | None:
    """(width, height, channels) from the header, or None for a format not listed above."""
    try:
        with open(path, "rb") as stream:
            head = stream.read(HEAD_BYTES)
    except OSError as exc:
        raise SceneError(f"cannot read {path}: {exc.strerror or exc}", where=where) from None
    # TGA has no signature: Mitsuba knows it by its extension, and so does this.
    tga = path.suffix.lower() == ".tga"
    reader = _tga if tga else next((r for magic, r in _READERS if head.startswith(magic)), None)
    try:
        return None if reader is None else reader(head)
    except (struct.error, ValueError, IndexError):
        return None  # a damaged header: Mitsuba's own reader will say so


def _png(head: bytes) -> Size:
    width, height, _, colour = struct.unpack(">IIBB", head[16:26])
    return width, height, {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}.get(colour, 4)


def _jpeg(head: bytes) -> Size | None:
    at = 2
    while at + 9 < len(head):
        if head[at] != 0xFF:
            return None
        marker = head[at + 1]
        (length,) = struct.unpack(">H", head[at + 2 : at + 4])
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE):
            height, width = struct.unpack(">HH", head[at + 5 : at + 9])
            return width, height, head[at + 9]
        at += 2 + length
    return None


def _exr(head: bytes) -> Size | None:
    at, window, channels = 8, None, 0
    while at < len(head) and head[at] != 0:
        name_end = head.index(b"\0", at)
        kind_end = head.index(b"\0", name_end + 1)
        (length,) = struct.unpack("<i", head[kind_end + 1 : kind_end + 5])
        value = head[kind_end + 5 : kind_end + 5 + length]
        name = head[at:name_end]
        if name == b"dataWindow":
            window = struct.unpack("<iiii", value[:16])
        elif name == b"channels":
            channels = _channel_count(value)
        at = kind_end + 5 + length
    if window is None:
        return None
    x0, y0, x1, y1 = window
    return x1 - x0 + 1, y1 - y0 + 1, max(channels, 1)


def _channel_count(chlist: bytes) -> int:
    """Entries of an EXR channel list: a name, its NUL and 16 bytes each; an empty name ends it."""
    count, at = 0, 0
    while at < len(chlist) and chlist[at] != 0:
        at = chlist.index(b"\0", at) + 1 + 16
        count += 1
    return count


def _rgbe(head: bytes) -> Size | None:
    match = re.search(rb"\n\s*([-+])Y\s+(\d+)\s+([-+])X\s+(\d+)", head)
    return (int(match.group(4)), int(match.group(2)), 3) if match else None


def _pfm(head: bytes) -> Size | None:
    fields = head.split(maxsplit=3)
    return int(fields[1]), int(fields[2]), 3 if fields[0] == b"PF" else 1


def _ppm(head: bytes) -> Size | None:
    text = re.sub(rb"#[^\n]*", b" ", head[:1024])
    fields = text.split(maxsplit=3)
    return int(fields[1]), int(fields[2]), 3


def _bmp(head: bytes) -> Size:
    width, height = struct.unpack("<ii", head[18:26])
    return abs(width), abs(height), 4


def _tga(head: bytes) -> Size:
    width, height = struct.unpack("<HH", head[12:16])
    return width, height, 4


_READERS: tuple[tuple[bytes, Callable[[bytes], Size | None]], ...] = (
    (b"\x89PNG\r\n\x1a\n", _png),
    (b"\xff\xd8", _jpeg),
    (b"\x76\x2f\x31\x01", _exr),
    (b"#?", _rgbe),
    (b"PF\n", _pfm),
    (b"Pf\n", _pfm),
    (b"P6", _ppm),
    (b"P5", _ppm),
    (b"BM", _bmp),
)
