"""The buffer's file format (version 4): a plain ``.npz`` of one JSON header and its arrays.

Specified in ``docs/buffer-format.md``. Kept apart from the container (archive.py) so that the
format, its validation and its error messages can be read in one place. Per version:

- 4 (written): the header's ``storage`` says where each array is: parameters that are not
  textures packed into one array per objective, each distinct texture array once, all-zero
  texture gradients not stored (layouts.py); each parameter's ``estimator`` and the header's
  ``repairs`` say which gradients central differences replaced (repairs.py);
- 3: one member per parameter and objective (``value_…``, ``grad_…``), ``statistics``;
- 2: no statistics; 1: a boolean ``verified`` per parameter instead of the ``trust`` label.
"""

from __future__ import annotations

import json
import os
import stat
import struct
import weakref
import zipfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.archive import Archive, ArchiveError, archive_writer
from sensaov_cli.buffer.layouts import LayoutError, pack
from sensaov_cli.buffer.lazy import Guard
from sensaov_cli.buffer.members import arrays, declared_shape, float64
from sensaov_cli.buffer.model import (
    FORMAT_NAME,
    FORMAT_VERSION,
    HEADER_MEMBER,
    ObjectiveRecord,
    ParamRecord,
    SensitivityBuffer,
)
from sensaov_cli.buffer.param_sums import sums_members, sums_of
from sensaov_cli.buffer.repairs import repair_json, repairs_from_json
from sensaov_cli.buffer.statistics import Statistics
from sensaov_cli.errors import BufferFormatError, SensaovError

_ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")  # a zip with members, an empty zip
_REGENERATE = "re-run the job to write it again"
_FOREIGN = "expected a buffer.npz written by sensaov"


def buffer_writer(buffer: SensitivityBuffer) -> Callable[[Path], None]:
    """A function writing ``buffer`` to a given (temporary) path, for paired atomic writes."""
    return archive_writer(_members(buffer))


def read_buffer(path: Path | str, *, lazy: bool = False) -> SensitivityBuffer:
    """Read a buffer; any unreadable or inconsistent file raises BufferFormatError.

    Every member is read and checked now, unless ``lazy``: then a texture's member (format 4)
    is read, and its CRC checked, when a view first asks for its array, and a rank that needs
    only each parameter's sums never reads it (buffer/param_sums.py).
    """
    return _load(Path(path), lazy)[0]


def read_buffer_versioned(path: Path) -> tuple[SensitivityBuffer, int]:
    """The buffer and the format version its file was written in."""
    return _load(path, False)


def _members(buffer: SensitivityBuffer) -> dict[str, np.ndarray]:
    statistics = buffer.statistics
    names = [o.name for o in buffer.objectives]
    storage, arrays = pack(
        buffer.params, names, buffer.values, buffer.grads,
        statistics.stderr if statistics is not None else None,
    )  # fmt: skip
    header = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "provenance": buffer.provenance,
        "objects": list(buffer.objects),
        "params": [_param_json(p, i) for i, p in enumerate(buffer.params)],
        "objectives": [_objective_json(o, j) for j, o in enumerate(buffer.objectives)],
        "statistics": _statistics_json(statistics),
        "storage": storage,  # version 4: where each array is (layouts.py)
        "repairs": {key: repair_json(r) for key, r in buffer.repairs.items()},  # version 4
    }
    members = {HEADER_MEMBER: np.array(json.dumps(header, allow_nan=False))} | arrays
    members |= sums_members(sums_of(buffer.keys, buffer.values, buffer.grads), names)
    for j, name in enumerate(names):
        if statistics is not None:
            members[batch_sums_member(j)] = statistics.batch_sums[name]
    return members


def _statistics_json(statistics: Statistics | None) -> dict[str, Any] | None:
    if statistics is None:
        return None
    return {
        "source": statistics.source,
        "spp": list(statistics.spp),
        "seeds": list(statistics.seeds),
        "objective_values": {k: list(v) for k, v in statistics.objective_values.items()},
    }


def batch_sums_member(objective_index: int) -> str:
    """The npz member holding an objective's per-parameter batch scalars (P, k, 4) float64."""
    return f"batchsums_{objective_index:03d}"


_PARAM_FIELDS = tuple(f.name for f in fields(ParamRecord))
_OBJECTIVE_FIELDS = tuple(f.name for f in fields(ObjectiveRecord))
# Version 4 added "estimator"; version 1 stored a boolean "verified" where 2 stores "trust".
_V3_PARAM_FIELDS = tuple(name for name in _PARAM_FIELDS if name != "estimator")
_V1_PARAM_FIELDS = tuple("verified" if name == "trust" else name for name in _V3_PARAM_FIELDS)
_READABLE_VERSIONS = (1, 2, 3, FORMAT_VERSION)


def _param_json(p: ParamRecord, index: int) -> dict[str, Any]:
    entry: dict[str, Any] = {name: getattr(p, name) for name in _PARAM_FIELDS}
    entry.update(owners=list(p.owners), shape=list(p.shape), flags=list(p.flags), array=index)
    return entry


def _objective_json(o: ObjectiveRecord, index: int) -> dict[str, Any]:
    entry: dict[str, Any] = {name: getattr(o, name) for name in _OBJECTIVE_FIELDS}
    entry["array"] = index
    return entry


class _Malformed(ValueError):
    """The file is not a consistent sensaov buffer; the message says what is wrong."""

    def __init__(self, message: str, hint: str = _REGENERATE):
        super().__init__(message)
        self.hint = hint


_READ_ERRORS = (
    EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile, zlib.error, struct.error,
    NotImplementedError, RuntimeError,  # zipfile: unknown compression method, encrypted member
)  # fmt: skip


def _load(path: Path, lazy: bool) -> tuple[SensitivityBuffer, int]:
    with _reading(path):
        if not stat.S_ISREG(os.stat(path).st_mode):  # a FIFO would block, a device never end
            raise _Malformed("not a regular file", _FOREIGN)
        file = path.open("rb")
        try:
            _require_zip(file.read(4))
            archive = Archive(file)
            found = _read_archive(archive, (lambda: _reading(path)) if lazy else None)
        except BaseException:
            file.close()
            raise
        if lazy:  # the archive reads its members on demand: the file closes with it
            weakref.finalize(archive, file.close)
        else:
            file.close()
        return found


@contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Every error of reading ``path`` as one BufferFormatError naming the file."""
    try:
        yield
    except (ArchiveError, LayoutError) as exc:
        raise BufferFormatError(
            f"inconsistent buffer: {exc}", where=str(path), hint=_REGENERATE
        ) from exc
    except _Malformed as exc:
        raise BufferFormatError(str(exc), where=str(path), hint=exc.hint) from exc
    except SensaovError as exc:  # the arrays read, but construction found them inconsistent
        raise BufferFormatError(
            f"inconsistent buffer: {exc.message}", where=str(path), hint=_REGENERATE
        ) from exc
    except OSError as exc:
        raise BufferFormatError(
            f"cannot read buffer: {exc.strerror or exc}", where=str(path)
        ) from exc
    except _READ_ERRORS as exc:
        raise BufferFormatError(
            f"corrupt or truncated buffer: {exc or type(exc).__name__}",
            where=str(path),
            hint=_REGENERATE,
        ) from exc


def _require_zip(data: bytes) -> None:
    magic = data[:4]
    if not magic:
        raise _Malformed("not a sensaov buffer: the file is empty", _FOREIGN)
    if magic not in _ZIP_MAGICS:
        raise _Malformed("not a sensaov buffer: not an .npz (zip) archive", _FOREIGN)


def _read_archive(archive: Archive, guard: Guard | None) -> tuple[SensitivityBuffer, int]:
    """The buffer in ``archive``; with a ``guard``, texture members are read on first use."""
    members = set(archive.members)
    if HEADER_MEMBER not in members:
        raise _Malformed(f"not a sensaov buffer: the archive has no {HEADER_MEMBER!r}", _FOREIGN)
    declared_shape(archive, HEADER_MEMBER, None)  # a header claiming gigabytes is not read
    header = _read_header(archive.array(HEADER_MEMBER))
    version = header["format_version"]
    path_keys = _path_keys(header["provenance"]) if version < 4 else set()
    params = [
        _param_from_json(entry, i, version, path_keys) for i, entry in enumerate(header["params"])
    ]
    objectives = [_objective_from_json(e, j) for j, e in enumerate(header["objectives"])]
    entry = header.get("statistics")
    values, grads, stderr, used, sums = arrays(archive, header, params, objectives, guard)
    expected = {HEADER_MEMBER} | used
    if entry is not None:
        expected |= {batch_sums_member(j) for j in range(len(objectives))}
    if members != expected:
        raise _Malformed(f"inconsistent buffer: {_differences('arrays', expected, members)}")
    buffer = SensitivityBuffer(
        provenance=header["provenance"],
        objects=tuple(header["objects"]),
        params=tuple(params),
        objectives=tuple(objectives),
        values=values,
        grads=grads,
        statistics=_read_statistics(archive, entry, params, objectives, stderr),
        repairs=repairs_from_json(header.get("repairs", {})),  # none before version 4
        sums=sums,
        _copy_arrays=False,  # views of the file's bytes, read once: frozen in place
    )
    return buffer, version


def _read_statistics(
    archive: Archive,
    entry: Any,
    params: list[ParamRecord],
    objectives: list[ObjectiveRecord],
    stderr: Any,
) -> Statistics | None:
    if entry is None:
        return None
    fields_ = {"source", "spp", "seeds", "objective_values"}
    if not isinstance(entry, dict) or set(entry) != fields_:
        raise _Malformed(f"malformed header: 'statistics' must be null or have {sorted(fields_)}")
    counts = (entry["spp"], entry["seeds"])
    if not all(isinstance(c, list) and all(_is_int(n) for n in c) for c in counts):
        raise _Malformed("malformed header: statistics.spp and .seeds must be integer lists")
    values = entry["objective_values"]
    if not isinstance(values, dict) or not all(
        isinstance(v, list) and all(_is_number(x) for x in v) for v in values.values()
    ):
        raise _Malformed("malformed header: statistics.objective_values must map to number lists")
    sums = {}
    for j, o in enumerate(objectives):
        sums[o.name] = float64(archive, batch_sums_member(j), (len(params), len(entry["spp"]), 4))
    return Statistics(
        source=str(entry["source"]),
        spp=tuple(entry["spp"]),
        seeds=tuple(entry["seeds"]),
        objective_values={k: tuple(float(x) for x in v) for k, v in values.items()},
        stderr=stderr,
        batch_sums=sums,
    )


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _differences(kind: str, expected: set[str], found: set[str]) -> str:
    """What is missing and what is extra: counts, and the first few names (a message of a
    forged archive stays one short line)."""
    parts = []
    for what, names in (("missing", expected - found), ("unknown", found - expected)):
        if names:
            shown = sorted(names)[:_SHOWN_NAMES]
            more = f" and {len(names) - len(shown)} more" if len(names) > len(shown) else ""
            parts.append(f"{what} {kind} {shown}{more}")
    return ", ".join(parts)


_SHOWN_NAMES = 5


def _read_header(member: np.ndarray) -> dict[str, Any]:
    if member.dtype.kind != "U" or member.shape != ():
        raise _Malformed("not a sensaov buffer: 'header' is not a 0-d unicode array", _FOREIGN)
    header = json.loads(str(member[()]))
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        found = header.get("format") if isinstance(header, dict) else None
        raise _Malformed(
            f"not a sensaov buffer: header format is {found!r}, not {FORMAT_NAME!r}", _FOREIGN
        )
    version = header.get("format_version")
    if not _is_int(version) or version not in _READABLE_VERSIONS:  # 1.0 is not a version
        newer = isinstance(version, int) and version > FORMAT_VERSION
        raise _Malformed(
            f"buffer format version {version!r} is not supported; this sensaov reads versions "
            f"{', '.join(map(str, _READABLE_VERSIONS))}",
            "upgrade sensaov to read it" if newer else _REGENERATE,
        )
    kinds = {"provenance": dict, "objects": list, "params": list, "objectives": list}
    for name, kind in kinds.items():
        if not isinstance(header.get(name), kind):
            raise _Malformed(f"malformed header: {name!r} must be a JSON {kind.__name__}")
    allowed = set(kinds) | {"format", "format_version"}
    # required from their version on
    for field, since in (("statistics", 3), ("storage", 4), ("repairs", 4)):
        if version >= since:
            if field not in header:
                raise _Malformed(f"malformed header: missing field {field!r}")
            allowed.add(field)
    extra = sorted(set(header) - allowed)
    if extra:  # no version allows others (docs/buffer-format.md)
        raise _Malformed(f"malformed header: unknown field(s) {', '.join(map(repr, extra))}")
    return header


def _entry(entry: Any, names: tuple[str, ...], index: int, where: str) -> dict[str, Any]:
    expected = set(names) | {"array"}
    if not isinstance(entry, dict):
        raise _Malformed(f"malformed header: {where}[{index}] is not a JSON object")
    if set(entry) != expected:
        problem = _differences("fields", expected, set(entry))
        raise _Malformed(f"malformed header: {where}[{index}] has {problem}")
    if not _is_int(entry["array"]) or entry["array"] != index:
        raise _Malformed(f"malformed header: {where}[{index}].array is {entry['array']!r}")
    return {name: entry[name] for name in names}


def _path_keys(provenance: dict[str, Any]) -> set[str]:
    """Keys a version 1-3 buffer's provenance says Mitsuba's path differentiated."""
    keys = (provenance.get("gradient_integrators") or {}).get("path")
    return {k for k in keys if isinstance(k, str)} if isinstance(keys, list) else set()


def _param_from_json(entry: Any, index: int, version: int, path_keys: set[str]) -> ParamRecord:
    """A parameter record; before version 4 its estimator is the backward pass's integrator."""
    if version >= 4:
        return ParamRecord(**_entry(entry, _PARAM_FIELDS, index, "params"))
    fields_ = _entry(entry, _V3_PARAM_FIELDS if version >= 2 else _V1_PARAM_FIELDS, index, "params")
    by_path = isinstance(fields_.get("key"), str) and fields_["key"] in path_keys
    fields_["estimator"] = "reverse-path" if by_path else "reverse"
    if version >= 2:
        return ParamRecord(**fields_)
    verified = fields_.pop("verified")
    if not isinstance(verified, bool):
        raise _Malformed(f"malformed header: params[{index}].verified must be a bool")
    return ParamRecord(**fields_, trust="verified" if verified else "unverified")


def _objective_from_json(entry: Any, index: int) -> ObjectiveRecord:
    return ObjectiveRecord(**_entry(entry, _OBJECTIVE_FIELDS, index, "objectives"))
