"""Write files so that a reader (or a farm that kills the job) never sees half of one."""

from __future__ import annotations

import os
import signal
import tempfile
from collections.abc import Callable
from pathlib import Path


def atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    """One file; see :func:`atomic_write_all`."""
    atomic_write_all([(path, write)])


def atomic_write_all(files: list[tuple[Path, Callable[[Path], None]]]) -> None:
    """Write every file to a temporary beside it, then rename them all, with SIGINT and SIGTERM
    held back during the renames: a run's outputs are replaced together or not at all."""
    temporaries: list[Path] = []
    try:
        for path, write in files:
            temporaries.append(_written_temporary(path, write))
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            for tmp, (path, _) in zip(temporaries, files, strict=True):
                os.replace(tmp, path)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
    except BaseException:
        for tmp in temporaries:
            tmp.unlink(missing_ok=True)
        raise
    for folder in {path.parent for path, _ in files}:
        _fsync_directory(folder)


def _written_temporary(path: Path, write: Callable[[Path], None]) -> Path:
    """``write(tmp)`` on a temporary file beside ``path``; returns it (removed on failure).

    Renames are atomic on POSIX file systems; on any failure (including KeyboardInterrupt) the
    temporary files are removed and every existing ``path`` is left untouched.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    os.close(handle)
    tmp = Path(name)
    try:
        write(tmp)
        # mkstemp creates the file owner-only; outputs get the permissions any new file would.
        os.chmod(tmp, 0o666 & ~_umask())
        with open(tmp, "rb") as stream:
            os.fsync(stream.fileno())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_directory(folder: Path) -> None:
    """Make the rename itself durable (a farm node may lose power right after the job)."""
    try:
        descriptor = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(descriptor)
    except OSError:
        pass  # some file systems cannot fsync a directory; the rename is still atomic
    finally:
        os.close(descriptor)


def check_writable(folder: Path, names: list[str]) -> None:
    """Fail before any work if ``folder/<name>`` cannot be written (nothing is created here)."""
    from sensaov_cli.errors import OutputError

    for name in names:
        if (folder / name).is_dir():
            raise OutputError(f"{folder / name} is a directory", hint="move it out of the way")
    existing = folder
    while not existing.exists():  # the folder will be created: its nearest existing parent
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"{existing} is not a directory", where=str(folder))
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputError(f"no permission to write in {existing}", where=str(folder))
