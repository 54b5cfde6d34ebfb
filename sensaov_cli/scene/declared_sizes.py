"""The size an image or a mesh declares in its header, read without decoding it (pure Python).

A 6 kB PNG may declare 40000x40000 pixels, a PLY header four billion vertices: Mitsuba
allocates them all and the process dies without a word (SIGSEGV, std::bad_alloc). So before
Mitsuba loads a scene, every image it will read (in the formats of Mitsuba's ``Bitmap``) and
every PLY mesh is measured from its first bytes and checked against the memory budget; a
binary PLY that declares more than the file holds is refused outright.
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


def check_declared_size(path: Path, where: str) -> None:
    """Refuse an image or a mesh whose declared size, once loaded, is over the memory budget."""
    try:
        with open(path, "rb") as stream:
            head = stream.read(HEAD_BYTES)
    except OSError as exc:
        raise SceneError(f"cannot read {path}: {exc.strerror or exc}", where=where) from None
    if head.startswith(b"ply"):
        _check_ply(path, head, where)
        return
    # TGA has no signature: Mitsuba knows it by its extension, and so does this.
    tga = path.suffix.lower() == ".tga"
    reader = _tga if tga else next((r for magic, r in _READERS if head.startswith(magic)), None)
    try:
        size = None if reader is None else reader(head)
    except (struct.error, ValueError, IndexError):
        return  # a damaged header: Mitsuba's own reader will say so
    if size is None:
        return  # another format: Mitsuba says what it thinks of it
    width, height, channels = size
    check_memory(
        width * height * channels * 4 * TEXTURE_COPIES,
        f"loading {path.name}, which declares {width}x{height} pixels x {channels} channels,",
        where=where,
        hint="check the image, or make it smaller",
    )


# Bytes of each PLY scalar type; a list counts as its length and three entries (a triangle).
_PLY_TYPES = {
    **dict.fromkeys(("char", "uchar", "int8", "uint8"), 1),
    **dict.fromkeys(("short", "ushort", "int16", "uint16"), 2),
    **dict.fromkeys(("int", "uint", "float", "int32", "uint32", "float32"), 4),
    **dict.fromkeys(("double", "float64"), 8),
}
MESH_COPIES = 4  # the file's data, Mitsuba's vertex and index buffers, the ray-tracing BVH


def _check_ply(path: Path, head: bytes, where: str) -> None:
    end = head.find(b"end_header")
    if end < 0:
        return  # Mitsuba's reader says what is wrong with it
    least, likely, count = 0, 0, 0  # a list holds at least its length; likely a triangle
    for line in head[:end].decode("latin-1").splitlines():
        words = line.split()
        if words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
            count = int(words[2])
        elif words[:1] == ["property"] and len(words) >= 3:
            sizes = [_PLY_TYPES.get(word, 4) for word in words[1:-1] if word != "list"]
            least += count * sizes[0]
            likely += count * (sizes[0] + 3 * sizes[-1] if words[1] == "list" else sizes[0])
    held = path.stat().st_size - end
    if b"binary" in head[:end] and least > held:
        raise SceneError(
            f"{path.name} declares at least {least:,} bytes of elements but holds {held:,}",
            where=where,
            hint="the PLY file is cut short or its header is wrong: export it again",
        )
    check_memory(likely * MESH_COPIES, f"loading {path.name}, whose header declares about "
                 f"{likely:,} bytes of vertices and faces,", where=where,
                 hint="check the mesh, or simplify it")  # fmt: skip


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
        elif name == b"channels":  # a name, its NUL and 16 bytes each; an empty name ends it
            channels, entry = 0, 0
            while entry < len(value) and value[entry] != 0:
                entry = value.index(b"\0", entry) + 1 + 16
                channels += 1
        at = kind_end + 5 + length
    if window is None:
        return None
    x0, y0, x1, y1 = window
    return x1 - x0 + 1, y1 - y0 + 1, max(channels, 1)


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
