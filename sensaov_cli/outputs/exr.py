"""OpenEXR files: float32 channels plus string metadata, written atomically, and read back.

The compositor layout is ``layered_exr.py``'s; this module only moves named channels and header
strings to and from disk.
"""

from __future__ import annotations

import errno
import os
import sys
import tempfile
from collections.abc import Callable, Iterator, Sized
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.errors import ExrReadError
from sensaov_cli.limits import check_memory, regular_file
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
    """A function writing the EXR to a given (temporary) path, for :func:`atomic_write_all`."""
    exr = _exr_file(channels, attributes)

    def write(tmp: Path) -> None:
        try:
            with exr:
                exr.write(str(tmp))
        except RuntimeError as error:  # the binding's only exception type, even for ENOSPC
            # Its message names the temporary, which is gone by the time anyone reads it.
            raise _os_error(str(error).replace(str(tmp), "the file")) from error

    return write


def _exr_file(channels: dict[str, np.ndarray], attributes: dict[str, str]) -> Any:
    """The ``OpenEXR.File`` of a ZIP scanline file: half channels stay half (display layers),
    all else becomes float32."""
    import OpenEXR

    # OpenEXR compresses on one thread by default; it writes blocks in line order whatever the
    # thread count, so the bytes do not depend on it.
    affinity = getattr(os, "sched_getaffinity", None)  # Linux; elsewhere every core counts
    cores = len(affinity(0)) if affinity else (os.cpu_count() or 1)
    if OpenEXR.global_thread_count() != cores:
        OpenEXR.set_global_thread_count(cores)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    pixels = {
        name: np.ascontiguousarray(data, np.float16 if data.dtype == np.float16 else np.float32)
        for name, data in channels.items()
    }
    return OpenEXR.File(header | attributes, pixels)


def encode_exr(channels: dict[str, np.ndarray], attributes: dict[str, str]) -> bytes:
    """The EXR ``write_exr`` would write, as bytes in memory (an HTTP answer, no file)."""
    import io

    stream = io.BytesIO()
    with _exr_file(channels, attributes) as exr:
        exr.write(stream)
    return stream.getvalue()


def _os_error(message: str) -> OSError:
    # OpenEXR's message says "... No space left on device.": the errno is found by its text.
    for code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EACCES, errno.EROFS):
        if os.strerror(code) in message:
            return OSError(code, os.strerror(code))
    return OSError(errno.EIO, message)


def image_channels(image: np.ndarray) -> dict[str, np.ndarray]:
    """An (H, W, C) render as named EXR channels: Y, YA, RGB or RGBA."""
    names = {1: "Y", 2: "YA", 3: "RGB"}.get(image.shape[2], "RGBA")
    return {name: image[..., index] for index, name in enumerate(names)}


def read_exr(
    path: Path, what: str = "OpenEXR file"
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Every channel of a scanline EXR by its full name (``layer.pass.Y``), H x W in the stored
    type, and the header as the binding gives it.

    A special file, a corrupt or truncated one, or one whose declared size is over the memory
    budget (checked on the header first) is bad input (:class:`ExrReadError`).
    """
    import OpenEXR

    # Checked first: else a FIFO blocks, and the library prints its own line to stderr first.
    regular_file(path, what, error=ExrReadError)
    try:
        # ``separate_channels`` keeps full channel names (the binding groups ``X.R/G/B`` into
        # one ``X`` by default). Read inside ``with``: a closed File's data are invalid.
        with _library_quiet() as said:
            with OpenEXR.File(str(path), header_only=True) as exr:
                declared = exr.header()
                _check_declared_size(
                    declared.get("dataWindow"), declared.get("channels", ()), path, what
                )
            with OpenEXR.File(str(path), separate_channels=True) as exr:
                header = dict(exr.header())
                channels = {n: np.array(c.pixels, copy=True) for n, c in exr.channels().items()}
    except (OSError, RuntimeError, ValueError, TypeError) as error:
        raise ExrReadError(
            f"cannot read the {what}: {' '.join(str(error).split())[:200]}",
            where=str(path),
            hint="check that the path names a complete OpenEXR file",
        ) from error
    if said:  # a truncated file reads as zeros after the library's own warning
        raise ExrReadError(
            f"the {what} is corrupt or truncated: {' '.join(said[0].split())[:200]}",
            where=str(path),
            hint="write it again: sensaov reads complete OpenEXR files only",
        )
    return channels, header


@contextmanager
def _library_quiet() -> Iterator[list[str]]:
    """Catch what the OpenEXR library prints to the process's stdout and stderr (it would break
    the one-line error and ``--json``); yields the lines, filled once the block ends."""
    said: list[str] = []
    saved = [os.dup(1), os.dup(2)]
    with tempfile.TemporaryFile() as caught:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        os.dup2(caught.fileno(), 1)
        os.dup2(caught.fileno(), 2)
        try:
            yield said
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for descriptor in saved:
                os.close(descriptor)
            caught.seek(0)
            said.extend(
                line for line in caught.read().decode(errors="replace").splitlines() if line
            )


def _check_declared_size(window: object, listed: Sized, path: Path, what: str) -> None:
    corners = np.asarray(window, dtype=np.int64).reshape(-1)
    if corners.size != 4:
        raise ExrReadError(f"the {what} has no data window", where=str(path))
    width, height = corners[2] - corners[0] + 1, corners[3] - corners[1] + 1
    channels = max(len(listed), 1)
    check_memory(
        int(width) * int(height) * channels * 4 * 2,  # float32 channels, and the binding's copy
        f"the {what}'s declared {width}x{height} pixels x {channels} channels",
        where=str(path),
        hint="check that it is the file meant",
    )
