"""What ``merge`` relies on in a shard's provenance, checked where it is read.

A shard is a buffer ``sensaov run --shard I/N`` wrote; its provenance says which shard it is
(``task.shard.index`` of ``count``), how many samples it holds (``spp``, which over all shards
adds up to the job's ``job_spp``), its seed (``primal_seed``), the job's objectives
(``job.objectives``) and the image size (``resolution``). Those come from a file: a missing
key, a string, a float, an index outside 1..N or ``spp`` 0 would end in an internal error, or
in a shard silently left out of (or over-weighted in) the mean.
Each is refused here (exit 2), naming the shard file and the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sensaov_cli.errors import MergeError

MAX_SHARDS = 1 << 20  # far above any farm; a count beyond it is a damaged file
_HINT = "the file is not a shard as 'sensaov run --shard I/N' writes it: run that shard again"


def check_shard_metadata(path: Path, provenance: Mapping[str, Any]) -> None:
    """Refuse a shard whose provenance lacks what merge reads, or holds it in another form."""
    task = _field(path, provenance, "task", dict)
    shard = task.get("shard")
    if shard is None:
        return  # not a shard at all: merge says so, in those words
    if not isinstance(shard, dict):
        raise _bad(path, "task.shard", shard, "a mapping {index, count}")
    count = _integer(path, shard, "count", "task.shard.count", 1, MAX_SHARDS)
    _integer(path, shard, "index", "task.shard.index", 1, count)
    _integer(path, provenance, "spp", "spp", 1, 2**32 - 1)
    _integer(path, provenance, "job_spp", "job_spp", 1, 2**32 - 1)
    _integer(path, provenance, "primal_seed", "primal_seed", 0, 2**32 - 1)
    objectives = _field(path, _field(path, provenance, "job", dict), "objectives", list)
    names = [entry.get("name") if isinstance(entry, dict) else None for entry in objectives]
    if not names or not all(isinstance(name, str) for name in names):
        raise _bad(path, "job.objectives", objectives, "a list of objectives with names")
    size = provenance.get("resolution")
    if not (isinstance(size, list) and len(size) == 2 and all(_is_int(n, 1) for n in size)):
        raise _bad(path, "resolution", size, "[width, height]")


def _field(path: Path, mapping: Mapping[str, Any], key: str, kind: type) -> Any:
    value = mapping.get(key)
    if not isinstance(value, kind):
        raise _bad(path, key, value, "a mapping" if kind is dict else "a list")
    return value


def _integer(
    path: Path, mapping: Mapping[str, Any], key: str, shown: str, least: int, most: int
) -> int:
    value = mapping.get(key)
    if not isinstance(value, int) or not _is_int(value, least, most):
        raise _bad(path, shown, value, f"an integer from {least} to {most}")
    return value


def _is_int(value: Any, least: int, most: int = 2**63) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and least <= value <= most


def _bad(path: Path, key: str, value: Any, expected: str) -> MergeError:
    shown = "missing" if value is None else f"{type(value).__name__} {str(value)[:40]!r}"
    return MergeError(f"provenance {key} is {shown}, not {expected}", where=str(path), hint=_HINT)
