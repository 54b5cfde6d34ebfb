"""The buffer's file format (version 4): a plain ``.npz`` of one JSON header and numbered arrays.

Specified in ``docs/buffer-format.md``. Kept apart from the container so that the format, its
validation and its error messages can be read in one place. Version 3 files (no estimators, no
repairs), version 2 files (no statistics either) and version 1 files (a boolean ``verified``
per parameter instead of the ``trust`` label) are read.
"""

from __future__ import annotations

import json
import os
import stat
import struct
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import (
    FORMAT_NAME,
    FORMAT_VERSION,
    HEADER_MEMBER,
    ObjectiveRecord,
    ParamRecord,
    SensitivityBuffer,
)
from sensaov_cli.buffer.repairs import repair_json, repairs_from_json
from sensaov_cli.buffer.statistics import Statistics
from sensaov_cli.errors import BufferFormatError, SensaovError

_ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")  # a zip with members, an empty zip
_REGENERATE = "re-run the job to write it again"
_FOREIGN = "expected a buffer.npz written by sensaov"


def buffer_writer(buffer: SensitivityBuffer) -> Callable[[Path], None]:
    """A function writing ``buffer`` to a given (temporary) path, for paired atomic writes."""
    return archive_writer(_members(buffer))


def archive_writer(members: dict[str, np.ndarray]) -> Callable[[Path], None]:
    """A function writing named arrays as an .npz (the buffer's and its sidecars' container)."""

    def write(tmp: Path) -> None:
        # What np.savez does, spelled out: stored (uncompressed) members, no pickles, zip64.
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, arr in members.items():
                with zf.open(f"{name}.npy", "w", force_zip64=True) as out:
                    np.lib.format.write_array(out, arr, allow_pickle=False)

    return write


def read_buffer(path: Path | str) -> SensitivityBuffer:
    """Read a buffer; any unreadable or inconsistent file raises BufferFormatError."""
    return _load(Path(path))[0]


def read_buffer_versioned(path: Path) -> tuple[SensitivityBuffer, int]:
    """The buffer and the format version its file was written in."""
    return _load(path)


def _members(buffer: SensitivityBuffer) -> dict[str, np.ndarray]:
    header = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "provenance": buffer.provenance,
        "objects": list(buffer.objects),
        "params": [_param_json(p, i) for i, p in enumerate(buffer.params)],
        "objectives": [_objective_json(o, j) for j, o in enumerate(buffer.objectives)],
        "statistics": _statistics_json(buffer.statistics),
        "repairs": {key: repair_json(r) for key, r in buffer.repairs.items()},
    }
    members = {HEADER_MEMBER: np.array(json.dumps(header, allow_nan=False))}
    for i, p in enumerate(buffer.params):
        members[value_member(i)] = buffer.values[p.key]
        for j, o in enumerate(buffer.objectives):
            members[grad_member(j, i)] = buffer.grads[o.name][p.key]
    if buffer.statistics is not None:
        for j, o in enumerate(buffer.objectives):
            members[batch_sums_member(j)] = buffer.statistics.batch_sums[o.name]
            for i, p in enumerate(buffer.params):
                members[stderr_member(j, i)] = buffer.statistics.stderr[o.name][p.key]
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


def value_member(param_index: int) -> str:
    """The npz member holding the value of parameter number ``param_index``."""
    return f"value_{param_index:06d}"


def grad_member(objective_index: int, param_index: int) -> str:
    """The npz member holding d(objective)/d(parameter) for the given header indices."""
    return f"grad_{objective_index:03d}_{param_index:06d}"


def stderr_member(objective_index: int, param_index: int) -> str:
    """The npz member holding the standard error of a gradient (version 3, with statistics)."""
    return f"stderr_{objective_index:03d}_{param_index:06d}"


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


def _load(path: Path) -> tuple[SensitivityBuffer, int]:
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):  # a FIFO would block, a device never end
            raise _Malformed("not a regular file", _FOREIGN)
        _require_zip(path)
        with np.load(path, allow_pickle=False) as npz:
            return _read_npz(npz)
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


def _require_zip(path: Path) -> None:
    with open(path, "rb") as f:
        magic = f.read(4)
    if not magic:
        raise _Malformed("not a sensaov buffer: the file is empty", _FOREIGN)
    if magic not in _ZIP_MAGICS:
        raise _Malformed("not a sensaov buffer: not an .npz (zip) archive", _FOREIGN)


def _read_npz(npz: Any) -> tuple[SensitivityBuffer, int]:
    names = [name.removesuffix(".npy") for name in npz.zip.namelist()]
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:  # np.load would silently read one of them
        raise _Malformed(f"inconsistent buffer: archive members appear twice: {duplicates[:5]}")
    members = set(npz.files)
    if HEADER_MEMBER not in members:
        raise _Malformed(f"not a sensaov buffer: the archive has no {HEADER_MEMBER!r}", _FOREIGN)
    _declared(npz, HEADER_MEMBER, None)  # a header claiming gigabytes is not read
    header = _read_header(npz[HEADER_MEMBER])
    version = header["format_version"]
    path_keys = _path_keys(header["provenance"]) if version < 4 else set()
    params = [
        _param_from_json(entry, i, version, path_keys) for i, entry in enumerate(header["params"])
    ]
    objectives = [_objective_from_json(e, j) for j, e in enumerate(header["objectives"])]
    statistics = header.get("statistics")
    expected = {HEADER_MEMBER} | {value_member(i) for i in range(len(params))}
    expected |= {grad_member(j, i) for j in range(len(objectives)) for i in range(len(params))}
    if statistics is not None:
        expected |= {batch_sums_member(j) for j in range(len(objectives))}
        expected |= {
            stderr_member(j, i) for j in range(len(objectives)) for i in range(len(params))
        }
    if members != expected or len(names) != len(members):
        raise _Malformed(f"inconsistent buffer: {_differences('arrays', expected, members)}")
    values = {p.key: _read_array(npz, value_member(i), p) for i, p in enumerate(params)}
    grads = {
        o.name: {p.key: _read_array(npz, grad_member(j, i), p) for i, p in enumerate(params)}
        for j, o in enumerate(objectives)
    }
    buffer = SensitivityBuffer(
        provenance=header["provenance"],
        objects=tuple(header["objects"]),
        params=tuple(params),
        objectives=tuple(objectives),
        values=values,
        grads=grads,
        statistics=_read_statistics(npz, statistics, params, objectives),
        repairs=repairs_from_json(header.get("repairs", {})),  # none before version 4
        _copy_arrays=False,  # fresh arrays from read_array: freezing them in place halves the peak
    )
    return buffer, version


def _read_statistics(
    npz: Any, entry: Any, params: list[ParamRecord], objectives: list[ObjectiveRecord]
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
        _declared(npz, batch_sums_member(j), (len(params), len(entry["spp"]), 4))
        arr = npz[batch_sums_member(j)]
        if arr.dtype != np.float64:
            raise _Malformed(f"inconsistent buffer: {batch_sums_member(j)!r} is not float64")
        sums[o.name] = arr
    return Statistics(
        source=str(entry["source"]),
        spp=tuple(entry["spp"]),
        seeds=tuple(entry["seeds"]),
        objective_values={k: tuple(float(x) for x in v) for k, v in values.items()},
        stderr={
            o.name: {p.key: _read_array(npz, stderr_member(j, i), p) for i, p in enumerate(params)}
            for j, o in enumerate(objectives)
        },
        batch_sums=sums,
    )


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _differences(kind: str, expected: set[str], found: set[str]) -> str:
    missing, extra = sorted(expected - found), sorted(found - expected)
    parts = []
    if missing:
        parts.append(f"missing {kind} {missing}")
    if extra:
        parts.append(f"unknown {kind} {extra}")
    return ", ".join(parts)


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
    # "statistics" (null or an object) is required from version 3 on, "repairs" from 4 on
    for field, since in (("statistics", 3), ("repairs", 4)):
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


# The header is a few kB per parameter; a member declaring more is refused before it is read.
_MAX_HEADER_BYTES = 1 << 28


def _declared(npz: Any, name: str, shape: tuple[int, ...] | None) -> None:
    """Check a member's npy header before reading it: its declared shape (for an array) or
    its declared size (for the header), so a forged size cannot allocate memory."""
    with npz.zip.open(f"{name}.npy") as stream:
        version = np.lib.format.read_magic(stream)
        if version == (1, 0):
            declared, _, dtype = np.lib.format.read_array_header_1_0(stream)
        else:
            declared, _, dtype = np.lib.format.read_array_header_2_0(stream)
    if shape is None:
        if dtype.itemsize * int(np.prod(declared)) > _MAX_HEADER_BYTES:
            raise _Malformed(f"inconsistent buffer: {name!r} declares {dtype.itemsize} bytes")
    elif tuple(declared) != shape:
        raise _Malformed(
            f"inconsistent buffer: array {name!r} has shape {tuple(declared)}, its record "
            f"declares {shape}"
        )


def _read_array(npz: Any, name: str, record: ParamRecord) -> np.ndarray:
    _declared(npz, name, record.shape)
    arr = npz[name]
    if not isinstance(arr, np.ndarray) or arr.dtype.kind != "f" or arr.dtype.itemsize != 4:
        found = getattr(arr, "dtype", type(arr).__name__)
        raise _Malformed(f"inconsistent buffer: array {name!r} is {found}, not float32")
    if arr.shape != record.shape:
        raise _Malformed(
            f"inconsistent buffer: array {name!r} has shape {arr.shape}, {record.key!r} "
            f"declares {record.shape}"
        )
    return arr
