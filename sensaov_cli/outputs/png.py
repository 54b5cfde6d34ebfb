"""PNG files written with the standard library, so that every byte's write is checked.

OpenImageIO's PNG writer reports success on a full disk and leaves a cut-off file; here the
bytes are encoded in memory (zlib, filter 0) and written by Python, whose ``write`` raises
``OSError`` (``ENOSPC``, ``EIO``) for every failure, and then renamed into place atomically.
Text chunks (``tEXt``, Latin-1) carry the attributes that trace a preview back to its data.
:class:`PngQueue` compresses a series of previews on a worker thread while the caller draws.
"""

from __future__ import annotations

import struct
import zlib
from collections import deque
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from sensaov_cli.outputs.atomic import atomic_write

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_MAX_KEYWORD = 79  # bytes, by the PNG specification


# zlib's level for files. Measured on the demo's 54 previews (contact sheets and single
# views): level 6 took 0.53 s for 3.6 MB, level 3 0.21 s for 3.9 MB (+7 %), level 1 0.15 s
# for 4.3 MB. Filtering rows (Sub, Up) made them larger at every level: the sheets are flat.
LEVEL = 3


def encode_png(
    rgb_uint8: np.ndarray, text: Mapping[str, str] | None = None, level: int = LEVEL
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
    write_png_bytes(path, encode_png(rgb_uint8, text))


def write_png_bytes(path: Path, data: bytes) -> None:
    """Write an encoded PNG atomically: a failed write leaves the previous file as it was."""

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as stream:
            stream.write(data)  # raises OSError on a short write; close flushes, and may raise

    atomic_write(path, write)


def check_rgb(rgb: np.ndarray) -> None:
    """Refuse anything but an (H, W, 3) uint8 image (ValueError)."""
    if not isinstance(rgb, np.ndarray) or rgb.dtype != np.uint8:
        raise ValueError(f"expected a uint8 image, got {getattr(rgb, 'dtype', type(rgb))}")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {rgb.shape}")


class PngQueue:
    """PNGs written in the order given, each encoded on a worker thread while the caller draws
    the next picture: zlib releases the GIL, so on two cores the compression (0.2 s of the
    demo's previews) runs beside the drawing. A file is written, atomically and by the caller's
    thread, once two more are queued, and the rest when the block ends; a block left by an
    exception writes nothing more (its pending encodings are dropped).
    """

    _AHEAD = 2  # encodings in flight: one compressing while the caller draws the next

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sensaov-png")
        self._queued: deque[tuple[Path, Future[bytes]]] = deque()

    def __enter__(self) -> PngQueue:
        return self

    def put(self, path: Path, rgb_uint8: np.ndarray, attributes: Mapping[str, str]) -> None:
        """Queue ``rgb_uint8`` (not modified afterwards) for ``path``, as :func:`write_png`."""
        check_rgb(rgb_uint8)
        self._queued.append((Path(path), self._pool.submit(encode_png, rgb_uint8, attributes)))
        while len(self._queued) > self._AHEAD:
            self._write_oldest()

    def _write_oldest(self) -> None:
        path, encoded = self._queued.popleft()
        write_png_bytes(path, encoded.result())

    def __exit__(self, kind: object, error: object, trace: object) -> None:
        try:
            while kind is None and self._queued:
                self._write_oldest()
        finally:
            for _, encoded in self._queued:
                encoded.cancel()
            self._pool.shutdown(wait=True)


def png_problem(data: bytes) -> str | None:
    """Why ``data`` is not a whole PNG a browser shows as written (None: it is): the
    signature, every chunk's length and CRC, an IHDR first with a size, image data that
    inflates to the rows it declares (never more: a bomb stops there), an IEND last."""
    if not data:
        return "an empty file"
    if not data.startswith(_SIGNATURE):
        return "not a PNG file"
    chunks, problem = _chunks(data)
    if problem is not None:
        return problem
    if not chunks or chunks[0][0] != b"IHDR" or len(chunks[0][1]) != 13:
        return "no image header (IHDR) first"
    width, height, depth, colour = struct.unpack(">IIBB", chunks[0][1][:10])
    samples = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}.get(colour)
    if not width or not height or samples is None or depth not in (1, 2, 4, 8, 16):
        return f"an image header that declares no image ({width}x{height}, colour type {colour})"
    if chunks[-1][0] != b"IEND":
        return "cut short (no IEND chunk at the end)"
    rows = height * (1 + -(-width * samples * depth // 8))  # one filter byte per row
    interlaced = chunks[0][1][12] != 0  # Adam7's passes hold other rows: only inflated
    data = b"".join(body for kind, body in chunks if kind == b"IDAT")
    if not _inflates_to(data, rows, at_least=not interlaced):
        return "image data that is corrupt or not the size its header declares"
    return None


def _chunks(data: bytes) -> tuple[list[tuple[bytes, bytes]], str | None]:
    chunks: list[tuple[bytes, bytes]] = []
    at = len(_SIGNATURE)
    while at < len(data):
        if at + 12 > len(data):
            return chunks, "cut short inside a chunk"
        (length,) = struct.unpack(">I", data[at : at + 4])
        kind, body = data[at + 4 : at + 8], data[at + 8 : at + 8 + length]
        if len(body) < length or at + 12 + length > len(data):
            return chunks, f"cut short inside its {kind.decode('latin-1')!r} chunk"
        (crc,) = struct.unpack(">I", data[at + 8 + length : at + 12 + length])
        if zlib.crc32(kind + body) & 0xFFFFFFFF != crc:
            return chunks, f"a {kind.decode('latin-1')!r} chunk whose checksum is wrong"
        chunks.append((kind, body))
        at += 12 + length
    return chunks, None


def _inflates_to(compressed: bytes, size: int, *, at_least: bool) -> bool:
    """Whether the zlib stream is whole and holds ``size`` bytes (or, without ``at_least``,
    any number up to about twice that), inflating no more than that."""
    inflater = zlib.decompressobj()
    try:
        produced = len(inflater.decompress(compressed, 2 * size + 64))
    except zlib.error:
        return False
    if not inflater.eof:  # cut short, or more data than the image holds
        return False
    return produced == size if at_least else produced > 0


def _chunk(kind: bytes, body: bytes) -> bytes:
    crc = zlib.crc32(kind + body) & 0xFFFFFFFF
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def read_png_text(path: Path, limit: int = 1 << 26) -> dict[str, str]:
    """The ``tEXt`` chunks of a PNG file (Latin-1), without decoding its pixels.

    Raises ``ValueError`` for a file that is not a PNG or whose chunks run past its end, and
    reads at most ``limit`` bytes (a preview is far smaller).
    """
    with open(path, "rb") as stream:
        data = stream.read(limit)
    if not data.startswith(_SIGNATURE):
        raise ValueError("not a PNG file")
    text: dict[str, str] = {}
    position = len(_SIGNATURE)
    while position + 8 <= len(data):
        (length,) = struct.unpack_from(">I", data, position)
        kind = data[position + 4 : position + 8]
        body = data[position + 8 : position + 8 + length]
        if len(body) < length:
            raise ValueError("a chunk runs past the end of the file")
        if kind == b"tEXt":
            keyword, _, value = body.partition(b"\0")
            text[keyword.decode("latin-1")] = value.decode("latin-1")
        if kind in (b"IDAT", b"IEND"):  # sensaov writes its text before the pixels
            break
        position += 12 + length
    return text
