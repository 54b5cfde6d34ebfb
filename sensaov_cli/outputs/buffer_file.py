"""A sensitivity buffer written to disk atomically: the file is complete or untouched.

The format is :mod:`sensaov_cli.buffer.npz`'s; commands that write a buffer with other files
(``run``: its primal and forward sidecar) pass ``buffer_writer`` to ``atomic_write_all``.
"""

from __future__ import annotations

from pathlib import Path

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import buffer_writer
from sensaov_cli.errors import BufferWriteError
from sensaov_cli.outputs.atomic import atomic_write


def write_buffer(path: Path | str, buffer: SensitivityBuffer) -> None:
    """Write ``buffer`` to ``path``; a failure leaves any file there as it was."""
    try:
        atomic_write(Path(path), buffer_writer(buffer))
    except OSError as exc:
        raise BufferWriteError(
            f"cannot write buffer: {exc.strerror or exc}", where=str(path)
        ) from exc
