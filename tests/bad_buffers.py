"""Buffer files for tests: ``write_buffer`` writes one as ``sensaov run`` does (atomically, in the
current format), and bad ones are cut at test time from a good one, so the corpus follows the
format (tests/data/bad/README.md). Each maker writes one file and returns it."""

from __future__ import annotations

import io
import json
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.npz import HEADER_MEMBER, buffer_writer
from sensaov_cli.outputs.atomic import atomic_write


def write_buffer(path: Path, buffer: SensitivityBuffer) -> None:
    """Write ``buffer`` to ``path``; a failure leaves any file there as it was."""
    atomic_write(Path(path), buffer_writer(buffer))


def good_buffer(key: str = "box.bsdf.reflectance.value", objective: str = "m") -> SensitivityBuffer:
    param = ParamRecord(key, "reflectance", ("box",), (3,), False, "diffuse", (), "verified", "")
    return SensitivityBuffer(
        provenance={"scene_path": "scene.xml", "spp": 4},
        objects=("box",),
        params=(param,),
        objectives=(ObjectiveRecord(objective, {"type": "mean_luminance"}, 0.5, 1),),
        values={key: np.array([0.5, 0.5, 0.5], np.float32)},
        grads={objective: {key: np.array([0.1, 0.2, 0.3], np.float32)}},
    )


def members(path: Path) -> list[tuple[str, bytes]]:
    with zipfile.ZipFile(path) as zf:
        return [(info.filename, zf.read(info)) for info in zf.infolist()]


def write_members(path: Path, items: list[tuple[str, bytes]]) -> None:
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in items:
            zf.writestr(name, data)


def _npy(array: np.ndarray) -> bytes:
    stream = io.BytesIO()
    np.lib.format.write_array(stream, array, allow_pickle=True)
    return stream.getvalue()


def _header_edit(edit: Callable[[dict], None]) -> Callable[[Path, Path], None]:
    def make(good: Path, bad: Path) -> None:
        items = members(good)
        out = []
        for name, data in items:
            if name == f"{HEADER_MEMBER}.npy":
                header = json.loads(str(np.load(io.BytesIO(data))))
                edit(header)
                data = _npy(np.array(json.dumps(header)))
            out.append((name, data))
        write_members(bad, out)

    return make


def _set(path: tuple[str | int, ...], value: object) -> Callable[[dict], None]:
    def edit(header: dict) -> None:
        node = header
        for part in path[:-1]:
            node = node[part]
        node[path[-1]] = value

    return edit


def _zip_bomb(good: Path, bad: Path) -> None:
    """A member that claims 40 GB of float32 and inflates ~16 MiB of zeros before it ends."""
    items = [(n, d) for n, d in members(good) if n == f"{HEADER_MEMBER}.npy"]
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f4", "fortran_order": False, "shape": (10_000_000_000,)}
    )
    zeros = zlib.compressobj(9, zlib.DEFLATED, -15)
    body = zeros.compress(bytes(1 << 24)) + zeros.flush()
    write_members(bad, items)
    with zipfile.ZipFile(bad, "a", compression=zipfile.ZIP_DEFLATED) as zf:
        names = [n for n, _ in members(good) if n != f"{HEADER_MEMBER}.npy"]
        for name in names:
            zf.writestr(name, header.getvalue() + zlib.decompress(body, -15))


MAKERS: dict[str, Callable[[Path, Path], None]] = {
    "empty": lambda good, bad: bad.write_bytes(b""),
    "truncated": lambda good, bad: bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2]),
    "text": lambda good, bad: bad.write_text("not a zip archive\n"),
    "bit flip": lambda good, bad: bad.write_bytes(
        (lambda b: b[:200] + bytes([b[200] ^ 0xFF]) + b[201:])(good.read_bytes())
    ),
    "header not json": lambda good, bad: write_members(
        bad,
        [
            (n, _npy(np.array("{not json")) if n.startswith(HEADER_MEMBER) else d)
            for n, d in members(good)
        ],
    ),  # fmt: skip
    "pickled member": lambda good, bad: write_members(
        bad,
        [
            (n, d if n.startswith(HEADER_MEMBER) else _npy(np.array([object()], dtype=object)))
            for n, d in members(good)
        ],
    ),  # fmt: skip
    "no header": lambda good, bad: write_members(
        bad, [(n, d) for n, d in members(good) if not n.startswith(HEADER_MEMBER)]
    ),
    "unknown version": _header_edit(_set(("format_version",), 99)),
    "older version": _header_edit(_set(("format_version",), 3)),
    "foreign format": _header_edit(_set(("format",), "someone-else")),
    "zip bomb": _zip_bomb,
    "extra member": lambda good, bad: write_members(
        bad, [*members(good), ("extra.npy", _npy(np.zeros(3, np.float32)))]
    ),
    # version 4: estimators and repair records (docs/buffer-format.md)
    "unknown estimator": _header_edit(_set(("params", 0, "estimator"), "guess")),
    "repairs not an object": _header_edit(_set(("repairs",), [])),
    "repaired without a record": _header_edit(
        _set(("params", 0, "estimator"), "finite-difference")
    ),
    "repair of a reverse parameter": _header_edit(
        _set(("repairs",), {"box.bsdf.reflectance.value": {"reason": "x"}})
    ),
    "repair with a NaN estimate": _header_edit(
        lambda h: h.update(
            repairs={
                "box.bsdf.reflectance.value": {
                    "reason": "biased",
                    "step": 0.05,
                    "spp": [4, 4],
                    "seeds": [1, 2],
                    "one_sided": [],
                    "estimates": {"m": [[1, 2, 3], [1, 2, "nan"]]},
                    "reverse": {"m": [1, 2, 3]},
                    "seconds": 0.1,
                }
            },
            params=[{**h["params"][0], "estimator": "finite-difference"}],
        )
    ),  # fmt: skip
    "no repairs field": _header_edit(lambda h: h.pop("repairs")),
}

# Refused by the reader, where np.load reads them: a twin member, a version 4.0.
STRICT_READER: dict[str, Callable[[Path, Path], None]] = {
    "duplicate member": lambda good, bad: write_members(
        bad, members(good) + [m for m in members(good) if not m[0].startswith(HEADER_MEMBER)]
    ),
    "format_version 1.0": _header_edit(
        lambda h: h.update(format_version=float(h["format_version"]))
    ),
}
