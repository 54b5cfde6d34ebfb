"""Which objects an inspection camera sees, read back from the EXR ``sensaov project`` wrote.

The buffer knows nothing of cameras, so "off-frame" is a property of a camera: an object is in
its frame when its Cryptomatte ID covers some pixel of the camera's ``CryptoObject`` layers.
The manifest is not enough: it names every object of the scene, seen or not.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.errors import CameraFileError, ExrError
from sensaov_cli.outputs.cryptomatte import id_float, id_hex
from sensaov_cli.outputs.exr import read_exr

OBJECT_TYPE = "CryptoObject"
# An ID channel and the coverage channel beside it: R with G, B with A.
_PAIRS = (("R", "G"), ("B", "A"))


def visible_objects(
    paths: Sequence[Path], check: Callable[[Path, Mapping[str, Any]], None] | None = None
) -> dict[str, frozenset[str]]:
    """Camera name (the file's stem, as ``project`` names it) -> the objects it sees; ``check``
    is called with each file's header first (``rank --exr`` refuses an EXR of another buffer)."""
    seen = {}
    for path in paths:
        if path.stem in seen:
            raise CameraFileError(
                "two files for one camera", where=str(path), hint="pass each once"
            )
        try:
            channels, header = read_exr(path)
        except ExrError as error:  # a file the user named: bad input, not a failed job
            raise CameraFileError(error.message, where=error.where, hint=error.hint) from error
        if check is not None:
            check(path, header)
        seen[path.stem] = seen_names(channels, header, where=str(path))
    return seen


def seen_names(
    channels: Mapping[str, np.ndarray], header: Mapping[str, Any], *, where: str = "EXR"
) -> frozenset[str]:
    """The manifest names of ``CryptoObject`` whose ID has coverage > 0 in some pixel."""
    names = _manifest(header, where)
    pattern = re.compile(rf"^{OBJECT_TYPE}\d\d\.([RGBA])$")
    layers = {name[:-2] for name in channels if pattern.match(name)}
    ids: set[float] = set()
    for layer in sorted(layers):
        for id_channel, coverage_channel in _PAIRS:
            pair = (f"{layer}.{id_channel}", f"{layer}.{coverage_channel}")
            missing = [name for name in pair if name not in channels]
            if missing:
                raise CameraFileError(f"Cryptomatte channel {missing[0]} is missing", where=where)
            ids.update(np.asarray(channels[pair[0]])[np.asarray(channels[pair[1]]) > 0].tolist())
    return frozenset(name for name in names if float(id_float(name)) in ids)


def _manifest(header: Mapping[str, Any], where: str) -> list[str]:
    for key, value in header.items():
        if key.startswith("cryptomatte/") and key.endswith("/name") and value == OBJECT_TYPE:
            return _manifest_names(header.get(key[: -len("name")] + "manifest", "{}"), where)
    raise CameraFileError(
        f"no {OBJECT_TYPE} layer",
        where=where,
        hint="pass an inspection camera's EXR written by 'sensaov project'",
    )


def _manifest_names(manifest: Any, where: str) -> list[str]:
    """The object names of a Cryptomatte manifest: a JSON object of name -> 8 hex digits."""
    try:
        names = json.loads(manifest) if isinstance(manifest, str | bytes) else None
    except (ValueError, RecursionError):
        names = None
    if not isinstance(names, dict) or not all(isinstance(v, str) for v in names.values()):
        raise CameraFileError(
            f"the {OBJECT_TYPE} manifest is not a JSON object of names and IDs",
            where=where,
            hint="pass an inspection camera's EXR written by 'sensaov project'",
        )
    # Names are matched by their hash (MurmurHash3, as every Cryptomatte writer computes it):
    # an ID that is not that hash means the file was damaged or names other objects, and the
    # objects it lists as seen would be the wrong ones.
    wrong = next((name for name, value in names.items() if value.lower() != id_hex(name)), None)
    if wrong is not None:
        raise CameraFileError(
            f"the {OBJECT_TYPE} manifest gives {wrong[:60]!r} the ID {names[wrong][:20]!r}, "
            f"not its Cryptomatte hash {id_hex(wrong)}",
            where=where,
            hint="the file is damaged: run 'sensaov project' again for this camera",
        )
    return list(names)
