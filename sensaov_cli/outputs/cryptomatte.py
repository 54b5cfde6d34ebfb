"""Cryptomatte 1.2 ID layers: object names hashed into float IDs, ranked coverage, manifest.

Any Cryptomatte keyer (Nuke's gizmo, Natron's, Blender's compositor node) picks an object by
hashing the name the artist chose, so the IDs written here must be exactly the specification's:
MurmurHash3_x86_32 (seed 0) of the UTF-8 name, its exponent forced into [1, 254] so the bits
never form a denormal, an infinity or a NaN, stored as the bits of a little-endian float32.
Layers are ``{T}00``, ``{T}01``, … each holding two ranks as (ID, coverage, ID, coverage); the
deprecated un-numbered preview layer ``{T}.R/G/B`` is never written (Blender 3.4 mistakes it for
another rank). See ``docs/exr-layout.md``. Needs numpy and mmh3 only.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence

import mmh3
import numpy as np

from sensaov_cli.errors import CryptomatteError

HASH_NAME = "MurmurHash3_32"
CONVERSION = "uint32_to_float32"
DEFAULT_RANKS = 6
TYPE_NAME_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,60}")
_EXPONENT_SHIFT = 23
_EXPONENT_MASK = 0xFF


def name_hash(name: str) -> int:
    """MurmurHash3_x86_32 (seed 0) of the UTF-8 bytes of ``name``, as an unsigned 32-bit int."""
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
    """The Cryptomatte ID of ``name``: the float32 whose bits are :func:`id_bits`."""
    return uint32_to_float32(id_bits(name))


def id_hex(name: str) -> str:
    """The ID as the manifest writes it: 8 lowercase hex digits of the float's bits."""
    return f"{id_bits(name):08x}"


def manifest(names: Sequence[str]) -> str:
    """The JSON manifest ``{"name": "8-hex ID"}``, sorted, compact, UTF-8 names unescaped.

    Identical names merge into one entry, as the specification intends.
    """
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

    ``rank_index`` (H, W, R) indexes ``names`` (-1 = empty rank) and ``rank_coverage`` (H, W, R)
    is the coverage of that rank. Ranks are (stably) re-sorted by coverage, largest first, with
    empty ranks last; then the first ``ranks`` are written, padded with ID 0 / coverage 0, into
    a fixed count of ``ceil(ranks / 2)`` layers, so a sequence keeps the same channels on every
    frame. Coverage beyond ``ranks`` is dropped, as in every Cryptomatte writer. ``ordered``
    promises the ranks are in that order already, empty ones last at coverage 0, as a
    visibility pass builds them: nothing is then zeroed, checked or sorted (issue 23).
    """
    _check_type_name(type_name)
    if ranks < 1:
        raise CryptomatteError(f"ranks must be at least 1, got {ranks}")
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
    """Whether every pixel's ranks are already as the stable sort would leave them (no empty
    rank before a filled one, coverage not increasing): then sorting is the identity."""
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
    if not np.issubdtype(index.dtype, np.integer):
        raise CryptomatteError(f"rank_index must hold integers, not {index.dtype}")
    if index.size and (index.min() < -1 or index.max() >= len(names)):
        raise CryptomatteError(
            f"rank_index holds {int(index.min())}..{int(index.max())} but there are "
            f"{len(names)} names",
            hint="indices run from 0 to len(names) - 1, with -1 for an empty rank",
        )
    coverage = coverage.astype(np.float32, copy=False)
    if not np.all(np.isfinite(coverage)):
        raise CryptomatteError("rank_coverage holds NaN or infinity")
    return index, coverage
