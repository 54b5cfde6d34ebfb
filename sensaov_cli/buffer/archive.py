"""The ``.npz`` container of the buffer and its sidecars: a zip of ``.npy`` members.

Written as ``np.savez`` writes (stored members, no pickles, zip64). Read in time linear in the
members, with their number bounded: the count is taken from the archive's end record before
the directory is parsed (a zip of 100,000 members is refused at once, not after minutes of
``np.load``, whose member lookup is a list search), members are found by name in a dict, and
a stored member's array is a read-only view of its bytes, read from the open file when it is
first asked for (its CRC checked then), so a reader pays only for the members it reads; a
deflated member is inflated. Everything malformed raises :class:`ArchiveError`.
"""

from __future__ import annotations

import io
import os
import struct
import zipfile
import zlib
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import IO, BinaryIO

import numpy as np

# A buffer of format 4 holds a handful of members per objective and one per distinct texture
# array; formats 1-3 held one per parameter and objective. 50,000 bounds both with room.
MAX_MEMBERS = 50_000
_END = b"PK\x05\x06"  # end of central directory
_END64_LOCATOR = b"PK\x06\x07"
_LOCAL = b"PK\x03\x04"
_NPY_HEADER_BYTES = 1 << 16  # an .npy header is far smaller (numpy writes up to 64 KiB)
_ReadAt = Callable[[int, int], bytes]  # (offset, size) -> at most size bytes


class ArchiveError(ValueError):
    """The file is not a well-formed archive of .npy members; the message says what is wrong."""


def archive_writer(members: dict[str, np.ndarray]) -> Callable[[Path], None]:
    """A function writing named arrays as an .npz (the buffer's and its sidecars' container)."""

    def write(tmp: Path) -> None:
        # What np.savez does, spelled out: stored (uncompressed) members, no pickles, zip64.
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, arr in members.items():
                with zf.open(f"{name}.npy", "w", force_zip64=True) as out:
                    np.lib.format.write_array(out, arr, allow_pickle=False)

    return write


def _entry_count(read_at: _ReadAt, size: int) -> int:
    """The number of entries the archive's end record declares (zip64 where it says so)."""
    tail_start = max(0, size - (1 << 16) - 22)
    tail = read_at(tail_start, size - tail_start)
    found = tail.rfind(_END)
    end = tail_start + found
    if found < 0 or end + 22 > size:
        raise ArchiveError("not a zip archive: no end of central directory")
    (count,) = struct.unpack_from("<H", tail, found + 10)
    locator = found - 20
    if count == 0xFFFF and locator >= 0 and tail[locator : locator + 4] == _END64_LOCATOR:
        (offset,) = struct.unpack_from("<Q", tail, locator + 8)
        if offset + 56 > size:
            raise ArchiveError("corrupt zip64 end record")
        (count,) = struct.unpack_from("<Q", read_at(offset, 56), 32)
    return int(count)


class Archive:
    """The members of one archive, read from ``file`` (open for reading, kept open) on demand."""

    def __init__(self, file: BinaryIO) -> None:
        self._fd = file.fileno()
        self._size = os.fstat(self._fd).st_size
        count = _entry_count(self._read_at, self._size)
        if count > MAX_MEMBERS:
            raise ArchiveError(f"{count} members, more than the {MAX_MEMBERS} a buffer may hold")
        self._zip = zipfile.ZipFile(file)
        infos = self._zip.infolist()
        twice = sorted(name for name, n in Counter(i.filename for i in infos).items() if n > 1)
        if twice:  # np.load would silently read one of them
            raise ArchiveError(f"archive members appear twice: {twice[:5]}")
        self.members = {i.filename.removesuffix(".npy"): i for i in infos}

    def _read_at(self, start: int, size: int) -> bytes:
        # pread leaves the file's position alone: the zip reader's seeks are not disturbed
        return os.pread(self._fd, size, start)

    def declared(self, name: str) -> tuple[tuple[int, ...], np.dtype]:
        """A member's shape and dtype, from its .npy header only (a forged size is never read)."""
        with self._zip.open(self.members[name]) as stream:
            return _npy_header(stream)[:2]

    def array(self, name: str) -> np.ndarray:
        """A member's array: a read-only view of its bytes where it is stored."""
        info = self.members[name]
        if info.compress_type != zipfile.ZIP_STORED:
            with self._zip.open(info) as stream:
                return np.lib.format.read_array(stream, allow_pickle=False)
        body = self._read_at(self._data_start(info), info.file_size)
        if len(body) != info.file_size or zlib.crc32(body) != info.CRC:
            raise ArchiveError(f"member {name!r} is corrupt or truncated (CRC)")
        stream = io.BytesIO(body[:_NPY_HEADER_BYTES])
        shape, dtype, fortran = _npy_header(stream)
        if dtype.hasobject:
            raise ArchiveError(f"member {name!r} holds Python objects")
        count = int(np.prod(shape, dtype=np.int64))
        if stream.tell() + count * dtype.itemsize != info.file_size:
            raise ArchiveError(f"member {name!r} is not the size its header declares")
        flat = np.frombuffer(body, dtype, count, stream.tell())
        return flat.reshape(shape, order="F" if fortran else "C")

    def _data_start(self, info: zipfile.ZipInfo) -> int:
        local = self._read_at(info.header_offset, 30)
        if local[:4] != _LOCAL or len(local) < 30:
            raise ArchiveError(f"member {info.filename!r}: bad local header")
        name_length, extra_length = struct.unpack_from("<HH", local, 26)
        return info.header_offset + 30 + name_length + extra_length


def _npy_header(stream: IO[bytes]) -> tuple[tuple[int, ...], np.dtype, bool]:
    version = np.lib.format.read_magic(stream)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(stream)
    else:
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(stream)
    return tuple(shape), dtype, fortran
