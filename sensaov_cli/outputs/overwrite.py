"""The refusal to write an output over any file a command reads (pure Python).

With ``output`` set to the scene's folder, an inspection camera named like a texture would
replace the texture, and the scene would no longer load. So before anything renders, the
outputs a command will write are compared with its inputs (the job file, every file the scene
reads as the prepared scene lists them, masks, targets, a buffer being projected): same path
after resolving links, or the same file under another name (a hard link), is refused.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from sensaov_cli.errors import OutputError


def refuse_unsafe_outputs(
    inputs: Iterable[Path], files: Iterable[Path], folders: Iterable[Path] = (), *, where: str
) -> None:
    """Refuse, before any work, outputs that would replace an input or a folder that is a file.

    ``inputs`` are every file the command reads, ``files`` the outputs' paths, ``folders`` the
    folders whose contents it writes (``previews/``); ``where`` names the job in messages.
    """
    folders = list(folders)
    for folder in folders:
        if folder.exists() and not folder.is_dir():
            raise OutputError(
                f"{folder} exists and is not a directory",
                where=where,
                hint="move it out of the way: outputs are written into it",
            )
    read = {_real(path): path for path in inputs}
    for output in files:
        clash = read.get(_real(output)) or _same_file(output, read.values())
        if clash is not None:
            raise OutputError(
                f"the output {output} would replace {clash}, which this job reads",
                where=where,
                hint="set output to a folder of its own, or rename the camera",
            )
    for folder in folders:
        inside = [path for real, path in read.items() if real.startswith(_real(folder) + os.sep)]
        if inside:
            raise OutputError(
                f"outputs go into {folder}, which holds {inside[0]}, a file this job reads",
                where=where,
                hint="set output to a folder of its own",
            )


def _real(path: Path) -> str:
    return os.path.realpath(path)


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
