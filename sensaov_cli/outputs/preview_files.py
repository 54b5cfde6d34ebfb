"""The PNG previews a report embeds, read back safely: regular files only, each one whole.

``project --png`` writes them; anything may have happened to them since. A FIFO among them
would block the report forever and a device never end: those are refused (exit 2, like any
special input). A file that is not a whole PNG (empty, cut short, another format, too large to
embed) is left out of the page, and the page says which and why.
"""

from __future__ import annotations

import os
from pathlib import Path

from sensaov_cli.limits import read_regular, regular_file
from sensaov_cli.outputs.png import png_problem

MAX_PREVIEW_BYTES = 64 << 20  # a preview is a few hundred kB; a page embeds every one


def read_previews(output: Path, folder: Path) -> tuple[dict[str, bytes], dict[str, str]]:
    """The ``*.png`` files under ``folder`` (links to folders not followed), by their path
    relative to ``output``: the whole PNGs' bytes, and why each other one is left out."""
    whole: dict[str, bytes] = {}
    left_out: dict[str, str] = {}
    for path in _png_files(folder):
        name = str(path.relative_to(output))
        if not path.exists():
            left_out[name] = "a link to a file that does not exist"
            continue
        size = regular_file(path, "preview")
        if size > MAX_PREVIEW_BYTES:
            left_out[name] = f"{size >> 20} MiB, too large to embed"
            continue
        data = read_regular(path, "preview", cap=MAX_PREVIEW_BYTES)
        problem = png_problem(data)
        if problem is None:
            whole[name] = data
        else:
            left_out[name] = problem
    return whole, left_out


def _png_files(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return []
    found = []
    for root, folders, files in os.walk(folder):  # links to folders are listed, not entered
        folders.sort()
        found += [Path(root) / name for name in sorted(files) if name.endswith(".png")]
    return found
