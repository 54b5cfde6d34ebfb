"""The refusal to write an output over any file a command reads (pure Python): one rule for
every command that writes.

With ``output`` set to the scene's folder, an inspection camera named like a texture would
replace the texture, and the scene would no longer load; ``report -o`` onto the buffer would
replace the buffer. So before anything is written (and before anything renders), the outputs a
command will write are compared with every input of the job, the command and the scene: the
job file, every file the scene reads as the prepared scene lists them, masks, targets, the
buffer, shards, primals, camera EXRs, previews, and for a command that reads only a buffer the
files its provenance says the run read (:func:`recorded_inputs`). The same path after resolving
links, or the same file under another name (a hard link), is refused.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from sensaov_cli.errors import OutputError


def refuse_unsafe_outputs(
    inputs: Iterable[Path],
    files: Iterable[Path],
    folders: Iterable[Path] = (),
    *,
    where: str,
    hint: str = "set output to a folder of its own, or rename the camera",
) -> None:
    """Refuse, before any work, outputs that would replace an input or a folder that is a file.

    ``inputs`` are every file the command reads, ``files`` the outputs' paths, ``folders`` the
    folders whose contents it writes (``previews/``); ``where`` names the job (or the option)
    in messages, ``hint`` says how to choose another output.
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
                f"the output {output} would replace {clash}, which this command reads",
                where=where,
                hint=hint,
            )
    for folder in folders:
        inside = [path for real, path in read.items() if real.startswith(_real(folder) + os.sep)]
        if inside:
            raise OutputError(
                f"outputs go into {folder}, which holds {inside[0]}, a file this command reads",
                where=where,
                hint="set output to a folder of its own",
            )


def recorded_inputs(provenance: Mapping[str, Any]) -> tuple[Path, ...]:
    """The files a buffer's provenance says its run read: the job, the scene and every file the
    scene reads (``scene_files``; a buffer written before it was recorded: the scene and its
    textures). Provenance is a stranger's data: what is not a string is ignored (a hostile
    entry can only make a command refuse more)."""
    named = [provenance.get("job_path"), provenance.get("scene_path")]
    named += _strings(provenance.get("scene_files"))
    textures = provenance.get("textures")
    if isinstance(textures, list):
        named += [entry.get("file") for entry in textures if isinstance(entry, dict)]
    return tuple(
        Path(name) for name in named if isinstance(name, str) and name and "\0" not in name
    )


def _strings(value: Any) -> list[str]:
    return [item for item in value if isinstance(item, str)] if isinstance(value, list) else []


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
