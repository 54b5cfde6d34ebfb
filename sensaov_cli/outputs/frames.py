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
from sensaov_cli.outputs.cryptomatte import id_float
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
    for layer in layers:
        for id_channel, coverage_channel in _PAIRS:
            covered = channels[f"{layer}.{coverage_channel}"] > 0
            ids.update(np.asarray(channels[f"{layer}.{id_channel}"])[covered].tolist())
    return frozenset(name for name in names if float(id_float(name)) in ids)


def _manifest(header: Mapping[str, Any], where: str) -> list[str]:
    for key, value in header.items():
        if key.startswith("cryptomatte/") and key.endswith("/name") and value == OBJECT_TYPE:
            manifest = header.get(key[: -len("name")] + "manifest", "{}")
            return list(json.loads(manifest))
    raise CameraFileError(
        f"no {OBJECT_TYPE} layer",
        where=where,
        hint="pass an inspection camera's EXR written by 'sensaov project'",
    )
