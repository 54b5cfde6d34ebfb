"""Cryptomatte 1.2 ID layers: object names hashed into float IDs, ranked coverage, manifest;
and, read back from a camera's EXR, which objects that camera sees.

A keyer picks an object by hashing the name the artist chose, so the IDs must be exactly the
specification's: MurmurHash3_x86_32 (seed 0) of the UTF-8 name, its exponent forced into
[1, 254] (never a denormal, infinity or NaN), as the bits of a little-endian float32. Layers
``{T}00``, ``{T}01``, … hold two ranks each as (ID, coverage, ID, coverage); the deprecated
preview layer ``{T}.R/G/B`` is never written (Blender 3.4 mistakes it for another rank). See
``docs/exr-layout.md``.

An object is in a camera's frame when its ID covers some pixel of the camera's ``CryptoObject``
layers (:func:`visible_objects`); the manifest names every object of the scene, seen or not.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import mmh3
import numpy as np

from sensaov_cli.errors import CameraFileError, CryptomatteError, ExrError
from sensaov_cli.outputs.exr import read_exr

HASH_NAME = "MurmurHash3_32"
CONVERSION = "uint32_to_float32"
DEFAULT_RANKS = 6
TYPE_NAME_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,60}")
_EXPONENT_SHIFT = 23
_EXPONENT_MASK = 0xFF
OBJECT_TYPE = "CryptoObject"


def name_hash(name: str) -> int:
    return int(mmh3.hash(name.encode("utf-8"), seed=0, signed=False))


def id_bits(name: str) -> int:
    """The 32 bits of ``name``'s ID: its hash with the exponent moved off 0 and 255."""
    bits = name_hash(name)
    exponent = (bits >> _EXPONENT_SHIFT) & _EXPONENT_MASK
    if exponent in (0, _EXPONENT_MASK):
        bits ^= 1 << _EXPONENT_SHIFT
    return bits


def uint32_to_float32(bits: int) -> np.float32:
    """Reinterpret 32 bits as a little-endian float32 (the specification's conversion)."""
    return np.array([bits], dtype="<u4").view("<f4")[0]


def id_float(name: str) -> np.float32:
    return uint32_to_float32(id_bits(name))


def id_hex(name: str) -> str:
    """The ID as the manifest writes it: 8 lowercase hex digits of the float's bits."""
    return f"{id_bits(name):08x}"


def manifest(names: Sequence[str]) -> str:
    """The JSON manifest ``{"name": "8-hex ID"}``, sorted, compact, UTF-8 names unescaped
    (identical names merge into one entry, as the specification intends)."""
    entries = {name: id_hex(name) for name in sorted(set(names))}
    return json.dumps(entries, ensure_ascii=False, separators=(",", ":"), sort_keys=True)


def layer_key(type_name: str) -> str:
    """The metadata key of a type: the first 7 hex digits of its name's hash (stable per type)."""
    return f"{name_hash(type_name):08x}"[:7]


def layer_count(ranks: int) -> int:
    """How many RGBA layers hold ``ranks`` ranks (two per layer)."""
    return (ranks + 1) // 2


def channel_names(type_name: str, ranks: int = DEFAULT_RANKS) -> list[str]:
    """The channel names :func:`rank_channels` writes, in order: ``T00.R`` … ``T02.A``."""
    return [f"{type_name}{layer:02d}.{c}" for layer in range(layer_count(ranks)) for c in "RGBA"]


def rank_channels(
    type_name: str,
    names: Sequence[str],
    rank_index: np.ndarray,
    rank_coverage: np.ndarray,
    ranks: int = DEFAULT_RANKS,
    *,
    ordered: bool = False,
) -> dict[str, np.ndarray]:
    """Cryptomatte channels (name -> H x W float32) from per-pixel ranked coverage.

    ``rank_index`` (H, W, R) indexes ``names`` (-1 = empty rank); ``rank_coverage`` (H, W, R)
    is each rank's coverage. Ranks are stably sorted by coverage, largest first, empty ranks
    last; the first ``ranks`` are written, padded with ID 0 / coverage 0, into a fixed
    ``ceil(ranks / 2)`` layers, so a sequence keeps its channels on every frame. ``ordered``
    promises that order already (empty ranks at coverage 0, as a visibility pass builds them):
    nothing is then zeroed, checked or sorted.
    """
    _check_type_name(type_name)
    index, coverage = _checked_ranks(names, rank_index, rank_coverage)
    ids = np.array([id_float(name) for name in names] + [np.float32(0.0)], dtype=np.float32)
    if not ordered:
        empty = index < 0
        coverage = np.where(empty, np.float32(0.0), coverage)
        if not _in_rank_order(coverage, empty):
            # Empty ranks sort last whatever their coverage; among the rest, largest first.
            order = np.lexsort((-coverage, empty), axis=-1)
            index = np.take_along_axis(index, order, axis=-1)
            coverage = np.take_along_axis(coverage, order, axis=-1)
    height, width, present = index.shape
    channels: dict[str, np.ndarray] = {}
    names_out = channel_names(type_name, ranks)
    for rank in range(2 * layer_count(ranks)):
        id_name, cov_name = names_out[2 * rank], names_out[2 * rank + 1]
        if rank < min(present, ranks):
            channels[id_name] = ids[index[..., rank]]  # index -1 picks the trailing 0.0
            channels[cov_name] = np.ascontiguousarray(coverage[..., rank])
        else:  # padding: ranks asked for beyond those present, and the last layer's odd one
            channels[id_name] = np.zeros((height, width), dtype=np.float32)
            channels[cov_name] = np.zeros((height, width), dtype=np.float32)
    return channels


def metadata(type_name: str, names: Sequence[str]) -> dict[str, str]:
    """The header attributes ``cryptomatte/<key>/name|hash|conversion|manifest`` of one type."""
    _check_type_name(type_name)
    prefix = f"cryptomatte/{layer_key(type_name)}"
    return {
        f"{prefix}/name": type_name,
        f"{prefix}/hash": HASH_NAME,
        f"{prefix}/conversion": CONVERSION,
        f"{prefix}/manifest": manifest(names),
    }


def _check_type_name(type_name: str) -> None:
    if not TYPE_NAME_PATTERN.fullmatch(type_name):
        raise CryptomatteError(
            f"Cryptomatte type name {type_name!r} is not a compositor-safe layer name",
            hint="use 1 to 61 characters from [A-Za-z0-9_], not starting with a digit, "
            "e.g. CryptoObject or CryptoMaterial",
        )


def _in_rank_order(coverage: np.ndarray, empty: np.ndarray) -> bool:
    """Whether the stable sort would leave every pixel's ranks as they are."""
    filled_after_empty = empty[..., :-1] & ~empty[..., 1:]
    increasing = coverage[..., 1:] > coverage[..., :-1]
    return not (filled_after_empty.any() or (increasing & ~empty[..., 1:]).any())


def _checked_ranks(
    names: Sequence[str], rank_index: np.ndarray, rank_coverage: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    index = np.asarray(rank_index)
    coverage = np.asarray(rank_coverage)
    if index.ndim != 3 or coverage.shape != index.shape:
        raise CryptomatteError(
            f"rank_index {index.shape} and rank_coverage {coverage.shape} must share one "
            "(H, W, R) shape",
            hint="pass the visibility pass's ranked ids and coverage unchanged",
        )
    if index.size and (index.min() < -1 or index.max() >= len(names)):
        raise CryptomatteError(
            f"rank_index holds {int(index.min())}..{int(index.max())} but there are "
            f"{len(names)} names",
            hint="indices run from 0 to len(names) - 1, with -1 for an empty rank",
        )
    return index, coverage.astype(np.float32, copy=False)


def visible_objects(
    paths: Sequence[Path], check: Callable[[Path, Mapping[str, Any]], None]
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
        for id_channel, coverage_channel in (("R", "G"), ("B", "A")):  # an ID, its coverage
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
    # Names are matched by their hash: an ID that is not its name's hash would list the wrong
    # objects as seen.
    wrong = next((name for name, value in names.items() if value.lower() != id_hex(name)), None)
    if wrong is not None:
        raise CameraFileError(
            f"the {OBJECT_TYPE} manifest gives {wrong[:60]!r} the ID {names[wrong][:20]!r}, "
            f"not its Cryptomatte hash {id_hex(wrong)}",
            where=where,
            hint="the file is damaged: run 'sensaov project' again for this camera",
        )
    return list(names)
