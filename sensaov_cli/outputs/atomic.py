"""Output files, written safely: atomically, never over an input, under names that are safe;
and how each was made (its provenance).

Each file is written to a temporary beside it, checked (an empty write is an error; ``fsync``
reports a full disk the page cache hid), then renamed over the old file. The stop signals are
held back while a temporary is created and while the renames run, so a stop never leaves an
unknown temporary and a set of files is replaced together. The ledger (:func:`replaced`) lets
a failure or a stop name exactly which outputs are new. Names from scenes and buffers are data,
never paths: a file name is built only from :func:`file_token`'s output.

``sensaov run`` and ``sensaov project`` both start their provenance with :func:`made_by` and
store it with :func:`provenance_attributes`, so every file reads the same way.
"""

from __future__ import annotations

import atexit
import errno
import hashlib
import json
import os
import re
import shutil
import signal
import stat
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from sensaov_cli import __version__, interrupts
from sensaov_cli.errors import OutputError

TEMPORARY_SUFFIX = ".partial"
PROVENANCE_ATTRIBUTE = "sensaov/provenance"
_HELD = set(interrupts.STOP_SIGNALS)
_live: set[Path] = set()  # temporaries that exist right now (removed on any failure or stop)
_replaced: list[Path] = []  # every output this process renamed into place, in order
_scratch: list[Path] = []  # private temporary folders (scratch_folder), removed at exit
MAX_TOKEN = 64  # with a camera and a pass name, a preview's path stays far below NAME_MAX
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")
_HASH_CHARS = 8
# An absolute path: a "/" that starts the text or follows a space, quote, "=" or "(", up to the
# next space, quote, comma, semicolon or ")". "dM/dθ" and "3/8" are not paths.
_ABSOLUTE_PATH = re.compile(r"(?:(?<=^)|(?<=[\s'\"=(]))/[^\s'\",;)]+")


def atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    atomic_write_all([(path, write)])


def atomic_write_bytes(path: Path, data: bytes) -> None:
    def write(tmp: Path) -> None:
        tmp.write_bytes(data)

    atomic_write(path, write)


def atomic_write_all(files: list[tuple[Path, Callable[[Path], None]]]) -> None:
    """Write every file to a temporary beside it, then rename them all together.

    An ``OSError`` names the output it was writing (``filename``); a stop asked for while a
    writer ran surfaces as ``KeyboardInterrupt`` whatever the writer raised in its wake.
    """
    temporaries: list[Path] = []
    try:
        for path, write in files:
            temporaries.append(_written_temporary(Path(path), write))
        with _signals_held():
            for tmp, (path, _) in zip(temporaries, files, strict=True):
                os.replace(tmp, path)
                _live.discard(tmp)
                _replaced.append(Path(path))
    finally:
        for tmp in temporaries:
            _remove(tmp)
    for folder in {Path(path).parent for path, _ in files}:
        _fsync_directory(folder)


def scratch_folder(purpose: str) -> Path:
    """A private temporary folder (a library's cache), removed at exit or with the outputs'
    temporaries (:func:`remove_temporaries`)."""
    if not _scratch:
        atexit.register(remove_temporaries)
    folder = Path(tempfile.mkdtemp(prefix=f"sensaov-{purpose}-"))
    _scratch.append(folder)
    return folder


def replaced() -> tuple[Path, ...]:
    return tuple(_replaced)


def remove_temporaries() -> None:
    """Remove every temporary still on disk: the last thing a stopped process does."""
    for tmp in list(_live):
        _remove(tmp)
    while _scratch:
        shutil.rmtree(_scratch.pop(), ignore_errors=True)


def _written_temporary(path: Path, write: Callable[[Path], None]) -> Path:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with _signals_held():  # a temporary exists only once the ledger knows it
            handle, name = tempfile.mkstemp(
                dir=path.parent, prefix=f".{path.name[:200]}.", suffix=TEMPORARY_SUFFIX
            )
            os.close(handle)
            tmp = Path(name)
            _live.add(tmp)
    except OSError as exc:
        raise _named(exc, path) from exc
    try:
        write(tmp)
        _check_written(tmp, path)
    except BaseException as exc:
        _remove(tmp)
        if interrupts.requested():  # e.g. zipfile's error about a write the signal cut short
            raise KeyboardInterrupt from None
        if isinstance(exc, OSError):
            raise _named(exc, path) from exc
        raise
    return tmp


def _check_written(tmp: Path, path: Path) -> None:
    # A writer that wrote nothing failed; fsync makes a full disk show here, not later.
    if tmp.stat().st_size == 0:
        raise OSError(errno.EIO, "the writer produced an empty file")
    # mkstemp creates the file owner-only: a new output gets the permissions any new file
    # would, a replaced one keeps its own (a buffer someone made 0600 stays private).
    os.chmod(tmp, _mode_of(path))
    with open(tmp, "rb") as stream:
        os.fsync(stream.fileno())


def _named(exc: OSError, path: Path) -> OSError:
    return OSError(exc.errno, exc.strerror or str(exc), str(path))


def _remove(tmp: Path) -> None:
    with suppress(OSError):  # the folder vanished or became read-only: nothing more to do
        tmp.unlink(missing_ok=True)
    _live.discard(tmp)


@contextmanager
def _signals_held() -> Iterator[None]:
    """No KeyboardInterrupt inside the block; a stop asked for meanwhile is raised after it.

    The mask alone is not enough: Dr.Jit's and LLVM's worker threads do not block the signals,
    the kernel hands a process-directed signal to one of them, and Python then runs its
    handler in the main thread at once. So sensaov's handler is told to only record it too.
    """
    held = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)
    try:
        with interrupts.deferred():
            yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


def _mode_of(path: Path) -> int:
    with suppress(OSError):
        info = os.stat(path)
        if stat.S_ISREG(info.st_mode):
            return stat.S_IMODE(info.st_mode)
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _fsync_directory(folder: Path) -> None:
    """Make the rename itself durable (a farm node may lose power right after the job)."""
    # Some file systems cannot fsync a directory; the rename is still atomic.
    with suppress(OSError):
        descriptor = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


def check_writable(folder: Path, names: list[str]) -> None:
    """Fail before any work if ``folder/<name>`` cannot be written (nothing is created here).

    A name may be a sub-folder (``previews/``). A dangling or looping link in place of the
    folder, a sub-folder or an output is refused too: creating it would fail after the work.
    """
    for name in names:
        target = folder / name
        _refuse_broken_link(target)
        if name.endswith("/"):
            if target.exists() and not target.is_dir():
                raise OutputError(
                    f"{target} is not a directory", hint="move it out of the way: it holds outputs"
                )
        elif target.is_dir():
            raise OutputError(f"{target} is a directory", hint="move it out of the way")
        elif target.exists() and not target.is_file():
            raise OutputError(f"{target} is not a regular file", hint="move it out of the way")
    existing = folder
    while not existing.exists():  # the folder will be created: its nearest existing parent
        _refuse_broken_link(existing)
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"{existing} is not a directory", where=str(folder))
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputError(f"no permission to write in {existing}", where=str(folder))


def _refuse_broken_link(path: Path) -> None:
    if not path.is_symlink():
        return
    try:
        os.stat(path)
    except OSError as exc:
        looped = exc.errno == errno.ELOOP
        raise OutputError(
            f"{path} is a symbolic link that "
            + ("loops" if looped else f"leads to {os.readlink(path)}, which does not exist"),
            hint="remove the link, or point it at a folder that exists",
        ) from None


def refuse_unsafe_outputs(
    inputs: Iterable[Path],
    files: Iterable[Path],
    folders: Iterable[Path] = (),
    *,
    where: str,
    hint: str = "set output to a folder of its own, or rename the camera",
) -> None:
    """Refuse, before any work, outputs that would replace an input or a folder that is a file.

    With ``output`` set to the scene's folder, a camera named like a texture would replace the
    texture; ``report -o`` onto the buffer would replace the buffer. ``inputs`` are every file
    the command reads (for a command that reads only a buffer, :func:`recorded_inputs`),
    ``folders`` those whose contents it writes (``previews/``). The same file through a link or
    under another name (a hard link) is refused too.
    """
    folders = list(folders)
    for folder in folders:
        if folder.exists() and not folder.is_dir():
            raise OutputError(
                f"{folder} exists and is not a directory",
                where=where,
                hint="move it out of the way: outputs are written into it",
            )
    read = {os.path.realpath(path): path for path in inputs}
    for output in files:
        clash = read.get(os.path.realpath(output)) or _same_file(output, read.values())
        if clash is not None:
            raise OutputError(
                f"the output {output} would replace {clash}, which this command reads",
                where=where,
                hint=hint,
            )
    for folder in folders:
        inside = [
            path
            for real, path in read.items()
            if real.startswith(os.path.realpath(folder) + os.sep)
        ]
        if inside:
            raise OutputError(
                f"outputs go into {folder}, which holds {inside[0]}, a file this command reads",
                where=where,
                hint="set output to a folder of its own",
            )


def recorded_inputs(provenance: Mapping[str, Any]) -> tuple[Path, ...]:
    """The files a buffer's provenance says its run read: the job, the scene and every file the
    scene reads (``scene_files``; older buffers: the scene and its textures). Provenance is a
    stranger's data: what is not a string is ignored (a hostile entry can only refuse more)."""
    named = [provenance.get("job_path"), provenance.get("scene_path")]
    scene_files = provenance.get("scene_files")
    if isinstance(scene_files, list):
        named += scene_files
    textures = provenance.get("textures")
    if isinstance(textures, list):
        named += [entry.get("file") for entry in textures if isinstance(entry, dict)]
    return tuple(
        Path(name) for name in named if isinstance(name, str) and name and "\0" not in name
    )


def _same_file(output: Path, inputs: Iterable[Path]) -> Path | None:
    if not output.exists():
        return None
    for path in inputs:
        try:
            if path.exists() and os.path.samefile(output, path):
                return path
        except OSError:
            continue
    return None


def file_token(name: str) -> str:
    """``name`` itself when it is a safe file-name token already, else a sanitised stand-in.

    A name from a stranger's buffer may hold ``/``, ``..``, control characters or any Unicode.
    A token holds ASCII letters, digits, ``_``, ``-`` and inner ``.``, at most
    :data:`MAX_TOKEN` characters, never empty, never hidden. A changed name gets a short hash
    of the original, so two names never share a file; the file's metadata keeps the original.
    """
    if (
        0 < len(name) <= MAX_TOKEN
        and _UNSAFE.search(name) is None
        and not name.startswith((".", "-"))
        and ".." not in name
    ):
        return name
    digest = hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:_HASH_CHARS]
    stem = _UNSAFE.sub("_", name).strip("._-")[: MAX_TOKEN - _HASH_CHARS - 1]
    return f"{stem}_{digest}" if stem else f"name_{digest}"


def made_by(command: str) -> dict[str, str]:
    """The fields every provenance record starts with: the tool, its version, the command."""
    return {"tool": "sensaov", "tool_version": __version__, "command": command}


def header_provenance(header: Mapping[str, Any]) -> dict[str, Any] | None:
    """The provenance an EXR header carries, or None where it holds none sensaov wrote."""
    try:
        recorded = json.loads(header[PROVENANCE_ATTRIBUTE])
    except (KeyError, TypeError, ValueError):
        return None
    return recorded if isinstance(recorded, dict) else None


def provenance_attributes(
    provenance: dict[str, Any], *, relative_to: Path | None = None
) -> dict[str, str]:
    """The provenance as the one EXR header attribute that carries it (sorted keys, stable
    text); with ``relative_to`` (the job's output folder), every absolute path in it is written
    relative to that folder: farm workers and compositing machines mount it elsewhere."""
    if relative_to is not None:
        provenance = relative_paths(provenance, relative_to)
    return {PROVENANCE_ATTRIBUTE: json.dumps(provenance, sort_keys=True)}


def relative_paths(value: Any, folder: Path) -> Any:
    """``value`` (JSON data) with every absolute path in its strings, a whole string or a word
    of one (a command line), written relative to ``folder``."""
    if isinstance(value, dict):
        return {key: relative_paths(item, folder) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [relative_paths(item, folder) for item in value]
    if isinstance(value, str) and "/" in value:
        base = os.path.abspath(folder)
        return _ABSOLUTE_PATH.sub(lambda found: os.path.relpath(found.group(0), base), value)
    return value
