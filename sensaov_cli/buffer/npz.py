"""The buffer's file format (version 4): a plain ``.npz`` of one JSON header and its arrays.

Specified in ``docs/buffer-format.md``; written and read here, and the reader validates what it
parses. The header's ``storage`` says where each array is: the parameters that are not textures
packed into one float32 array (``values``; ``grads_{j}`` and ``stderrs_{j}`` per objective),
each distinct texture array stored once (``texture_{t}``, ``texgrad_{g}``, ``texstderr_{s}``:
the copies of one image share it), an all-zero texture gradient not at all. Each parameter's
sums (``sums_{j}``, ``value_means``) are what a ranking reads instead of the arrays.

The archive is read with :mod:`zipfile`, in time linear in its members and with their number
bounded: the count is taken from the end record before the directory is parsed (a zip of
100,000 members is refused at once), each member's declared shape and dtype are checked from
its ``.npy`` header before its data is read (a forged size is never allocated), and zipfile
checks each member's CRC as it reads it. Read lazily, a texture member is read when a view first
asks for its array: ``sensaov rank`` reads the sums and no texel. A file of an older format is
refused in one line (re-run the job); every problem is one :class:`BufferFormatError`.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
import struct
import weakref
import zipfile
import zlib
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, BinaryIO, TypeVar

import numpy as np

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, Repair, SensitivityBuffer
from sensaov_cli.buffer.statistics import SUMS_COLUMNS, ParamSums, Statistics, sums_of
from sensaov_cli.errors import BufferFormatError, SensaovError
from sensaov_cli.vocabulary import ESTIMATORS, TRUSTS

FORMAT_NAME = "sensaov-buffer"
FORMAT_VERSION = 4
HEADER_MEMBER = "header"
VALUE_MEANS_MEMBER = "value_means"
# A buffer holds a handful of members per objective and one per distinct texture array.
MAX_MEMBERS = 50_000
_HEADER_BYTES = 1 << 28  # a few kB per parameter; a header declaring more is not read
_HEADER_FIELDS = ("format", "format_version", "provenance", "objects", "params", "objectives",
                  "statistics", "storage", "repairs")  # fmt: skip
_ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")  # a zip with members, an empty zip
_END, _END64_LOCATOR = b"PK\x05\x06", b"PK\x06\x07"  # end of central directory (zip64)
_REGENERATE = "re-run the job to write it again"
_FOREIGN = "expected a buffer.npz written by sensaov"
_SHOWN_NAMES = 5
Guard = Callable[[], AbstractContextManager[object]]  # turns a late read's error into the file's
_R = TypeVar("_R")


def read_buffer(path: Path | str, *, lazy: bool = False) -> SensitivityBuffer:
    """Read a buffer (``lazy``: texture members on first use, see the module docstring); any
    unreadable or inconsistent file raises BufferFormatError."""
    path = Path(path)
    with _reading(path), ExitStack() as closing:
        if not stat.S_ISREG(os.stat(path).st_mode):  # a FIFO would block, a device never end
            raise _Malformed("not a regular file", _FOREIGN)
        file = closing.enter_context(path.open("rb"))
        magic = file.read(4)
        if magic not in _ZIP_MAGICS:
            problem = "not an .npz (zip) archive" if magic else "the file is empty"
            raise _Malformed(f"not a sensaov buffer: {problem}", _FOREIGN)
        archive = Archive(file)
        buffer = _read_archive(archive, (lambda: _reading(path)) if lazy else None)
        if lazy:  # the archive reads its members on demand: the file closes with it
            weakref.finalize(archive, closing.pop_all().close)
        return buffer


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


# --- writing ---------------------------------------------------------------------------------


def _packed(kind: str, objective: int) -> str:
    return f"{kind}_{objective:03d}"  # grads_000, stderrs_000, sums_000, batchsums_000


def _texture(kind: str, index: int) -> str:
    return f"{kind}_{index:05d}"  # texture_00000, texgrad_00000, texstderr_00000


def _members(buffer: SensitivityBuffer) -> dict[str, np.ndarray]:
    statistics = buffer.statistics
    names = [o.name for o in buffer.objectives]
    storage, members = _pack(buffer, names)
    header = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "provenance": buffer.provenance,
        "objects": list(buffer.objects),
        "params": [{**vars(p), "array": i} for i, p in enumerate(buffer.params)],
        "objectives": [{**vars(o), "array": j} for j, o in enumerate(buffer.objectives)],
        "statistics": None if statistics is None else {
            "source": statistics.source,
            "spp": list(statistics.spp),
            "seeds": list(statistics.seeds),
            "objective_values": {k: list(v) for k, v in statistics.objective_values.items()},
        },
        "storage": storage,
        "repairs": {key: {
            "reason": r.reason, "step": r.step, "spp": list(r.spp), "seeds": list(r.seeds),
            "one_sided": [list(pair) for pair in r.one_sided],
            "estimates": {k: np.asarray(v, np.float64).tolist() for k, v in r.estimates.items()},
            "reverse": {k: np.asarray(v, np.float64).tolist() for k, v in r.reverse.items()},
            "seconds": r.seconds,
        } for key, r in buffer.repairs.items()},
    }  # fmt: skip
    members = {HEADER_MEMBER: np.array(json.dumps(header, allow_nan=False))} | members
    sums = sums_of(buffer.keys, buffer.values, buffer.grads)
    members |= {_packed("sums", j): sums.tables[name] for j, name in enumerate(names)}
    members[VALUE_MEANS_MEMBER] = sums.value_means
    if statistics is not None:
        for j, name in enumerate(names):
            members[_packed("batchsums", j)] = statistics.batch_sums[name]
    return members


class _Distinct:
    """Arrays stored once each: equal contents (same shape, same bytes) share one member."""

    def __init__(self, kind: str, members: dict[str, np.ndarray]) -> None:
        self.kind, self.members = kind, members
        self.seen: dict[tuple[tuple[int, ...], bytes], int] = {}

    def index(self, array: np.ndarray, keep_zero: bool = False) -> int | None:
        if not keep_zero and not np.any(array):
            return None
        array = np.ascontiguousarray(array, dtype=np.float32)
        key = (array.shape, hashlib.blake2b(array.data, digest_size=16).digest())
        if key not in self.seen:
            self.seen[key] = len(self.seen)
            self.members[_texture(self.kind, self.seen[key])] = array
        return self.seen[key]


_StorageEntry = dict[str, int | list[int | None] | None]


def _pack(
    buffer: SensitivityBuffer, names: Sequence[str]
) -> tuple[dict[str, int | list[_StorageEntry]], dict[str, np.ndarray]]:
    """The header's ``storage`` object and the members that hold every array."""
    stderr = buffer.statistics.stderr if buffer.statistics is not None else None
    members: dict[str, np.ndarray] = {}
    flat = [p.key for p in buffer.params if not p.is_texture]
    members["values"] = _concatenated([buffer.values[key] for key in flat])
    for j, name in enumerate(names):
        members[_packed("grads", j)] = _concatenated([buffer.grads[name][k] for k in flat])
        if stderr is not None:
            members[_packed("stderrs", j)] = _concatenated([stderr[name][k] for k in flat])
    textures = _Distinct("texture", members)
    texgrads, texstderrs = _Distinct("texgrad", members), _Distinct("texstderr", members)
    entries: list[_StorageEntry] = []
    offset = 0
    for p in buffer.params:
        if not p.is_texture:
            entries.append({"offset": offset})
            offset += math.prod(p.shape)
            continue
        entry: _StorageEntry = {
            "value": textures.index(buffer.values[p.key], keep_zero=True),
            "grads": [texgrads.index(buffer.grads[name][p.key]) for name in names],
        }
        if stderr is not None:
            entry["stderrs"] = [texstderrs.index(stderr[name][p.key]) for name in names]
        entries.append(entry)
    return {"packed": offset, "params": entries}, members


def _concatenated(arrays: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([np.zeros(0, np.float32), *map(np.ravel, arrays)], dtype=np.float32)


# --- the archive -----------------------------------------------------------------------------


class _Malformed(ValueError):
    """The file is not a consistent sensaov buffer; the message says what is wrong."""

    def __init__(self, message: str, hint: str = _REGENERATE):
        super().__init__(message)
        self.hint = hint


def _inconsistent(message: str) -> _Malformed:
    return _Malformed(f"inconsistent buffer: {message}")


def _entry_count(file: BinaryIO) -> int:
    """The number of entries the archive's end record declares (zip64 where it says so)."""
    size = file.seek(0, os.SEEK_END)
    tail_start = max(0, size - (1 << 16) - 22)
    file.seek(tail_start)
    tail = file.read()
    found = tail.rfind(_END)
    if found < 0 or tail_start + found + 22 > size:
        raise _inconsistent("not a zip archive: no end of central directory")
    (count,) = struct.unpack_from("<H", tail, found + 10)
    locator = found - 20
    if count == 0xFFFF and locator >= 0 and tail[locator : locator + 4] == _END64_LOCATOR:
        (offset,) = struct.unpack_from("<Q", tail, locator + 8)
        if offset + 56 > size:
            raise _inconsistent("corrupt zip64 end record")
        file.seek(offset)
        (count,) = struct.unpack_from("<Q", file.read(56), 32)
    return int(count)


def _npy_header(stream: IO[bytes]) -> tuple[tuple[int, ...], np.dtype, bool]:
    version = np.lib.format.read_magic(stream)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(stream)
    else:
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(stream)
    return tuple(shape), dtype, fortran


_READ_ERRORS = (
    EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile, zlib.error, struct.error,
    NotImplementedError, RuntimeError,  # zipfile: unknown compression method, encrypted member
)  # fmt: skip


@contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Every error of reading ``path`` as one BufferFormatError naming the file."""
    try:
        yield
    except (_Malformed, SensaovError, OSError, *_READ_ERRORS) as exc:
        hint: str | None = _REGENERATE
        if isinstance(exc, _Malformed):
            message, hint = str(exc), exc.hint
        elif isinstance(exc, SensaovError):  # the arrays read, but construction refused them
            message = f"inconsistent buffer: {exc.message}"
        elif isinstance(exc, OSError):
            message, hint = f"cannot read buffer: {exc.strerror or exc}", None
        else:
            message = f"corrupt or truncated buffer: {exc or type(exc).__name__}"
        raise BufferFormatError(message, where=str(path), hint=hint) from exc


# --- reading ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Slot:
    """Where one parameter's arrays are (the header's ``storage.params[i]``)."""

    offset: int | None  # packed: its first component in values, grads_{j} and stderrs_{j}
    value: int = 0  # a texture: the member texture_{value}
    grads: tuple[int | None, ...] = ()  # per objective texgrad_{g}; None where all zero
    stderrs: tuple[int | None, ...] = ()  # per objective texstderr_{s}


class _LazyArrays(Mapping[str, np.ndarray]):
    """The arrays of ``keys``, each made by ``resolve`` inside ``guard`` on first access and
    kept; keys that share a member (copies of one texture) share its array, read once."""

    def __init__(self, keys: tuple[str, ...], resolve: Callable[[str], np.ndarray], guard: Guard):
        self._keys, self._known = keys, frozenset(keys)
        self._resolve, self._guard = resolve, guard
        self._made: dict[str, np.ndarray] = {}

    def __getitem__(self, key: str) -> np.ndarray:
        found = self._made.get(key)
        if found is None:
            if key not in self._known:
                raise KeyError(key)
            with self._guard():
                found = self._made[key] = self._resolve(key)
        return found

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def __contains__(self, key: object) -> bool:
        return key in self._known


class Archive:
    """The members of one archive, read from ``file`` (open for reading, kept open) on demand,
    each checked and read once; ``used`` notes those the header names."""

    def __init__(self, file: BinaryIO) -> None:
        count = _entry_count(file)
        if count > MAX_MEMBERS:
            raise _inconsistent(f"{count} members, more than the {MAX_MEMBERS} a buffer may hold")
        self._zip = zipfile.ZipFile(file)
        infos = self._zip.infolist()
        twice = sorted(name for name, n in Counter(i.filename for i in infos).items() if n > 1)
        if twice:  # np.load would silently read one of them
            raise _inconsistent(f"archive members appear twice: {twice[:_SHOWN_NAMES]}")
        self.members = {i.filename.removesuffix(".npy"): i for i in infos}
        self.used: set[str] = set()
        self._read: dict[str, np.ndarray] = {}
        self._zeros: dict[tuple[int, ...], np.ndarray] = {}

    def array(self, name: str, check: Callable[[tuple[int, ...], np.dtype], None]) -> np.ndarray:
        """A member's array (read-only); its declared shape and dtype are ``check``ed first."""
        with self._zip.open(self.members[name]) as stream:
            shape, dtype, fortran = _npy_header(stream)
            check(shape, dtype)
            if dtype.hasobject:
                raise _inconsistent(f"member {name!r} holds Python objects")
            size = math.prod(shape) * dtype.itemsize
            body = stream.read(size)
            if len(body) != size or stream.read(1):
                raise _inconsistent(f"member {name!r} is not the size its header declares")
        return np.frombuffer(body, dtype).reshape(shape, order="F" if fortran else "C")

    def declared(self, name: str, shape: tuple[int, ...]) -> None:
        """The member exists and its .npy header declares ``shape`` (nothing else is read)."""
        self._named(name)
        with self._zip.open(self.members[name]) as stream:
            _check_shape(name, shape, _npy_header(stream)[0])

    def float32(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        """A float32 member of ``shape``, finite, native and C-contiguous (read once)."""
        if name not in self._read:
            arr = self.floats(name, shape, "f4")
            if not np.isfinite(arr).all():
                raise _inconsistent(f"array {name!r} holds NaN or infinity")
            if not arr.flags.c_contiguous or not arr.dtype.isnative:
                arr = np.ascontiguousarray(arr, np.float32)
                arr.flags.writeable = False
            self._read[name] = arr
        return self._read[name]

    def floats(self, name: str, shape: tuple[int, ...], kind: str = "f8") -> np.ndarray:
        def check(declared: tuple[int, ...], dtype: np.dtype) -> None:
            _check_shape(name, shape, declared)
            if dtype.kind + str(dtype.itemsize) != kind:
                raise _inconsistent(f"array {name!r} is {dtype}, not {np.dtype(kind)}")

        self._named(name)
        return self.array(name, check)

    def _named(self, name: str) -> None:
        if name not in self.members:
            raise _inconsistent(f"missing array {name!r}")
        self.used.add(name)

    def zeros(self, shape: tuple[int, ...]) -> np.ndarray:
        """An all-zero gradient (not stored): one read-only array per shape."""
        if shape not in self._zeros:
            self._zeros[shape] = np.zeros(shape, np.float32)
            self._zeros[shape].flags.writeable = False
        return self._zeros[shape]


def _check_shape(name: str, expected: tuple[int, ...], declared: tuple[int, ...]) -> None:
    if tuple(declared) != expected:
        raise _inconsistent(
            f"array {name!r} has shape {tuple(declared)}, its record declares {expected}"
        )


def _read_archive(archive: Archive, guard: Guard | None) -> SensitivityBuffer:
    """The buffer in ``archive``; with a ``guard``, texture members are read on first use."""
    if HEADER_MEMBER not in archive.members:
        raise _Malformed(f"not a sensaov buffer: the archive has no {HEADER_MEMBER!r}", _FOREIGN)
    header = _read_header(archive)
    params = _records(header, "params", ParamRecord, _PARAM_FIELDS)
    objectives = _records(header, "objectives", ObjectiveRecord, _OBJECTIVE_FIELDS)
    names = [o.name for o in objectives]
    with_stderr = header["statistics"] is not None
    slots = _slots(header["storage"], params, len(names), with_stderr)
    values, grads, stderr = _arrays(archive, params, slots, names, with_stderr, guard)
    sums = _read_sums(archive, params, names)
    statistics = _read_statistics(archive, header["statistics"], len(params), names, stderr)
    expected = {HEADER_MEMBER} | archive.used
    if set(archive.members) != expected:
        raise _inconsistent(_differences("arrays", expected, set(archive.members)))
    return SensitivityBuffer(
        provenance=header["provenance"],
        objects=tuple(header["objects"]),
        params=params,
        objectives=objectives,
        values=values,
        grads=grads,
        statistics=statistics,
        repairs={str(k): _repair(e, f"repairs[{k!r}]") for k, e in header["repairs"].items()},
        sums=sums,
        _copy_arrays=False,  # checked here as they are read, and read-only
    )


def _arrays(
    members: Archive,
    params: tuple[ParamRecord, ...],
    slots: list[_Slot],
    names: list[str],
    with_stderr: bool,
    guard: Guard | None,
) -> tuple[Mapping[str, np.ndarray], dict[str, Mapping[str, np.ndarray]], Any]:
    """Values, gradients and standard errors (or None) by key, all read now without a ``guard``."""
    size = sum(math.prod(p.shape) for p, slot in zip(params, slots, strict=True)
               if slot.offset is not None)  # fmt: skip
    kinds = [("grads", "texgrad")] + [("stderrs", "texstderr")] * with_stderr
    flat = ["values"] + [_packed(kind, j) for kind, _ in kinds for j in range(len(names))]
    for name in flat:  # the packed members exist even if empty
        members.float32(name, (size,))
    at = {p.key: (p.shape, slot) for p, slot in zip(params, slots, strict=True)}
    for shape, slot in at.values():
        if slot.offset is None:
            members.declared(_texture("texture", slot.value), shape)
            for kind, indices in (("texgrad", slot.grads), ("texstderr", slot.stderrs)):
                for index in indices:
                    if index is not None:
                        members.declared(_texture(kind, index), shape)

    def resolver(kind: str, texture: str, j: int) -> Callable[[str], np.ndarray]:
        packed = _packed(kind, j) if kind != "values" else kind

        def resolve(key: str) -> np.ndarray:
            shape, slot = at[key]
            if slot.offset is not None:
                flat = members.float32(packed, (size,))
                arr = flat[slot.offset : slot.offset + math.prod(shape)].reshape(shape)
            elif kind == "values":
                arr = members.float32(_texture(texture, slot.value), shape)
            else:
                index = (slot.grads if kind == "grads" else slot.stderrs)[j]
                arr = members.zeros(shape) if index is None else members.float32(
                    _texture(texture, index), shape)  # fmt: skip
            if kind == "stderrs" and not (arr >= 0).all():
                raise _inconsistent(f"bad standard error of {key!r}")
            return arr

        return resolve

    keys = tuple(at)
    made: dict[str, dict[str, Mapping[str, np.ndarray]]] = {kind: {} for kind, _ in kinds}
    lazy = guard or nullcontext
    values: Mapping[str, np.ndarray] = _LazyArrays(keys, resolver("values", "texture", 0), lazy)
    for kind, texture in kinds:
        for j, name in enumerate(names):
            made[kind][name] = _LazyArrays(keys, resolver(kind, texture, j), lazy)
    if guard is None:  # every member read and checked now
        values = dict(values)
        made = {kind: {n: dict(a) for n, a in per.items()} for kind, per in made.items()}
    return values, made["grads"], made.get("stderrs")


def _read_sums(
    members: Archive, params: tuple[ParamRecord, ...], names: list[str]
) -> ParamSums | None:
    """The parameter sums the file stores (optional: all their members, or none)."""
    if VALUE_MEANS_MEMBER not in members.members:
        return None
    count = len(params)
    tables = {n: members.floats(_packed("sums", j), (count, len(SUMS_COLUMNS)))
              for j, n in enumerate(names)}  # fmt: skip
    means = members.floats(VALUE_MEANS_MEMBER, (count,))
    if not all(np.isfinite(a).all() for a in [*tables.values(), means]):
        raise _inconsistent("parameter sums hold NaN or infinity")
    return ParamSums(tuple(p.key for p in params), tables, means)


def _read_header(archive: Archive) -> dict[str, Any]:
    def check(shape: tuple[int, ...], dtype: np.dtype) -> None:
        if dtype.kind != "U" or shape != ():
            raise _Malformed("not a sensaov buffer: 'header' is not a 0-d unicode array", _FOREIGN)
        if dtype.itemsize > _HEADER_BYTES:  # a header claiming gigabytes is not read
            raise _inconsistent(f"{HEADER_MEMBER!r} declares {dtype.itemsize} bytes")

    header = json.loads(str(archive.array(HEADER_MEMBER, check)[()]))
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        found = header.get("format") if isinstance(header, dict) else None
        raise _Malformed(
            f"not a sensaov buffer: header format is {found!r}, not {FORMAT_NAME!r}", _FOREIGN
        )
    version: Any = header.get("format_version")
    if _is_int(version) and 1 <= version < FORMAT_VERSION:
        raise _Malformed(
            f"buffer format version {version}, written by an older sensaov: re-run",
            f"this sensaov reads format {FORMAT_VERSION} only; 'sensaov run JOB' writes it again",
        )
    if not _is_int(version) or version != FORMAT_VERSION:  # 4.0 is not a version
        newer = isinstance(version, int) and version > FORMAT_VERSION
        raise _Malformed(
            f"buffer format version {version!r} is not supported; this sensaov reads version "
            f"{FORMAT_VERSION}",
            "upgrade sensaov to read it" if newer else _REGENERATE,
        )
    for field in _HEADER_FIELDS:
        if field not in header:
            raise _Malformed(f"malformed header: missing field {field!r}")
    kinds = {"provenance": dict, "objects": list, "params": list, "objectives": list,
             "repairs": dict}  # fmt: skip
    for name, kind in kinds.items():
        if not isinstance(header[name], kind):
            raise _Malformed(f"malformed header: {name!r} must be a JSON {kind.__name__}")
    if not _strings(header["objects"]):
        raise _Malformed("malformed header: 'objects' must hold strings only")
    extra = sorted(set(header) - set(_HEADER_FIELDS))
    if extra:  # no field is optional, none other allowed (docs/buffer-format.md)
        raise _Malformed(f"malformed header: unknown field(s) {', '.join(map(repr, extra))}")
    return header


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _index(value: Any) -> bool:
    return _is_int(value) and value >= 0


def _strings(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(s, str) for s in value)


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


_Check = tuple[Callable[[Any], bool], str]  # a field's test, and what it must be
_TEXT: _Check = (lambda v: isinstance(v, str), "a string")
_NAME: _Check = (lambda v: isinstance(v, str) and v != "", "a non-empty string")
_STRINGS: _Check = (_strings, "a list of strings")
_PARAM_FIELDS: dict[str, _Check] = {
    "key": _NAME, "type": _NAME, "owners": _STRINGS,
    "shape": (lambda v: isinstance(v, list) and all(map(_index, v)), "a list of integers >= 0"),
    "is_texture": (lambda v: isinstance(v, bool), "true or false"), "plugin": _TEXT,
    "flags": _STRINGS, "trust": (TRUSTS.__contains__, f"one of {TRUSTS}"), "note": _TEXT,
    "estimator": (ESTIMATORS.__contains__, f"one of {ESTIMATORS}"),
}  # fmt: skip
_OBJECTIVE_FIELDS: dict[str, _Check] = {
    "name": _NAME, "definition": (lambda v: isinstance(v, dict), "a JSON object"),
    "value": (_number, "a finite number"), "grad_seed": (_is_int, "an integer"),
}  # fmt: skip


def _records(
    header: dict[str, Any], where: str, kind: Callable[..., _R], checks: dict[str, _Check]
) -> tuple[_R, ...]:
    """The header's list ``where`` as records, each field of the type ``checks`` names (a JSON
    list becomes a tuple)."""
    expected = set(checks) | {"array"}
    records = []
    for index, entry in enumerate(header[where]):
        at = f"malformed header: {where}[{index}]"
        if not isinstance(entry, dict):
            raise _Malformed(f"{at} is not a JSON object")
        if set(entry) != expected:
            raise _Malformed(f"{at} has {_differences('fields', expected, set(entry))}")
        if not _is_int(entry["array"]) or entry["array"] != index:
            raise _Malformed(f"{at}.array is {entry['array']!r}")
        for name, (ok, what) in checks.items():
            if not ok(entry[name]):
                raise _Malformed(f"{at}.{name} is {repr(entry[name])[:60]}, not {what}")
        fields = {name: entry[name] for name in checks}
        records.append(
            kind(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})
        )
    return tuple(records)


def _slots(
    storage: Any, params: tuple[ParamRecord, ...], objectives: int, with_stderr: bool
) -> list[_Slot]:
    """The storage object, checked: the packed parameters tile ``values`` in buffer order."""
    if not isinstance(storage, dict) or set(storage) != {"packed", "params"}:
        raise _inconsistent("'storage' must have exactly 'packed' and 'params'")
    entries = storage["params"]
    if not isinstance(entries, list) or len(entries) != len(params):
        raise _inconsistent("'storage.params' must have one entry per parameter")
    slots, offset = [], 0
    for i, (p, entry) in enumerate(zip(params, entries, strict=True)):
        where = f"storage.params[{i}]"
        if not p.is_texture:
            if entry != {"offset": offset}:
                raise _inconsistent(f"{where} must be {{'offset': {offset}}}")
            slots.append(_Slot(offset))
            offset += math.prod(p.shape)
            continue
        names = {"value", "grads"} | ({"stderrs"} if with_stderr else set())
        if not isinstance(entry, dict) or set(entry) != names:
            raise _inconsistent(f"{where} must have exactly {sorted(names)}")
        if not _index(entry["value"]):
            raise _inconsistent(f"{where}.value must be a member index")
        for name in sorted(names - {"value"}):
            listed = entry[name]
            ok = isinstance(listed, list) and len(listed) == objectives
            if not ok or not all(i is None or _index(i) for i in listed):
                raise _inconsistent(f"{where}.{name} must hold an index or null per objective")
        slots.append(_Slot(None, entry["value"], tuple(entry["grads"]),
                           tuple(entry.get("stderrs", ()))))  # fmt: skip
    if storage["packed"] != offset or not _index(offset):
        raise _inconsistent(f"'storage.packed' must be {offset}, the packed components")
    return slots


def _read_statistics(
    members: Archive, entry: Any, params: int, names: list[str], stderr: Any
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
        isinstance(v, list) and all(_number(x) for x in v) for v in values.values()
    ):
        raise _Malformed("malformed header: statistics.objective_values must map to number lists")
    shape = (params, len(entry["spp"]), 4)
    return Statistics(
        source=str(entry["source"]),
        spp=tuple(entry["spp"]),
        seeds=tuple(entry["seeds"]),
        objective_values={k: tuple(float(x) for x in v) for k, v in values.items()},
        stderr=stderr,
        batch_sums={n: members.floats(_packed("batchsums", j), shape) for j, n in enumerate(names)},
    )


_REPAIR_FIELDS = ("reason", "step", "spp", "seeds", "one_sided", "estimates", "reverse",
                  "seconds")  # fmt: skip


def _repair(entry: Any, where: str) -> Repair:
    where = f"malformed header: {where}"
    if not isinstance(entry, dict) or set(entry) != set(_REPAIR_FIELDS):
        raise _Malformed(f"{where} must be an object with fields {list(_REPAIR_FIELDS)}")
    pairs = entry["one_sided"]
    integers = [entry["spp"], entry["seeds"], *(pairs if isinstance(pairs, list) else [None])]
    if not all(isinstance(n, list) and all(map(_is_int, n)) for n in integers) or not all(
        len(pair) == 2 for pair in pairs
    ):
        raise _Malformed(f"{where}: spp and seeds hold integers, one_sided [index, sign] pairs")
    if not all(isinstance(entry[name], dict) for name in ("estimates", "reverse")):
        raise _Malformed(f"{where}: estimates and reverse map objective names to lists")
    try:
        return Repair(
            reason=str(entry["reason"]),
            step=float(entry["step"]),
            spp=tuple(entry["spp"]),
            seeds=tuple(entry["seeds"]),
            one_sided=tuple((index, sign) for index, sign in pairs),
            estimates={str(k): np.asarray(v, np.float64) for k, v in entry["estimates"].items()},
            reverse={str(k): np.asarray(v, np.float64) for k, v in entry["reverse"].items()},
            seconds=float(entry["seconds"]),
        )
    except (TypeError, ValueError, SensaovError) as exc:
        raise _Malformed(f"{where}: {exc}") from exc


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
