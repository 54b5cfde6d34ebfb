"""`rank` from each parameter's stored sums (buffer format 4).

The writer stores Σc², Σc, the zero-value counts and each value's mean per parameter; `rank`
reads the file lazily and never decodes a texture's texels. Its every output must be the one
computed from the arrays, to the last digit: summary and cuts, text, JSON and CSV, both weights,
every aggregate, untrusted apart and included, with and without batch statistics, on textures
shared by copies, all-zero texture gradients, zero-valued and untrusted parameters.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.npz import Archive, read_buffer
from sensaov_cli.buffer.statistics import Statistics
from sensaov_cli.errors import BufferFormatError
from sensaov_cli.outputs.tables import ranking_csv, ranking_json, ranking_text
from sensaov_cli.pipeline.rank import rank_buffer, summary_of
from sensaov_cli.views.hierarchy import rankings
from tests.bad_buffers import write_buffer

OBJECTIVES = ("luma", "centre")
TEXEL_MEMBERS = ("texture_", "texgrad_", "texstderr_")


def _record(key: str, owners: tuple[str, ...], shape: tuple[int, ...], trust: str) -> ParamRecord:
    kind = "roughness" if key.endswith("alpha.value") else "reflectance"
    note = "" if trust == "verified" else "a reason"
    return ParamRecord(key, kind, owners, shape, len(shape) == 3, "diffuse", (), trust, note)


def _params() -> list[ParamRecord]:
    params = [_record(f"wall{i}.bsdf.reflectance.data", (f"wall{i}",), (8, 8, 3), "verified")
              for i in range(3)]  # fmt: skip
    params += [
        _record("floor.bsdf.reflectance.data", ("floor",), (8, 8, 3), "unverified"),
        _record("ball.bsdf.reflectance.value", ("ball",), (3,), "verified"),  # zero-valued
        _record("ball.bsdf.alpha.value", ("ball", "floor"), (1,), "biased"),
        _record("lamp.bsdf.reflectance.value", ("lamp",), (3,), "no_gradient"),
    ]
    return params


def buffer_with_everything(with_statistics: bool) -> SensitivityBuffer:
    """Three copies of one image (one never seen), an untrusted texture, a zero-valued colour,
    a shared untrusted scalar and a parameter with no gradient."""
    rng = np.random.default_rng(3)
    params = _params()
    image = rng.random((8, 8, 3), dtype=np.float32)
    image[0, 0] = 0.0  # texels of value 0 with a gradient: hidden by value weighting
    values = {p.key: image for p in params[:3]}
    values |= {p.key: rng.random(p.shape, dtype=np.float32) for p in params[3:]}
    values["ball.bsdf.reflectance.value"] = np.array([0.0, 0.5, 0.0], np.float32)
    grads: dict[str, dict[str, np.ndarray]] = {}
    for name in OBJECTIVES:
        grads[name] = {p.key: rng.standard_normal(p.shape).astype(np.float32) for p in params}
        grads[name]["wall2.bsdf.reflectance.data"] = np.zeros((8, 8, 3), np.float32)
        grads[name]["lamp.bsdf.reflectance.value"] = np.zeros(3, np.float32)
    grads["centre"]["wall1.bsdf.reflectance.data"] = grads["luma"]["wall1.bsdf.reflectance.data"]
    statistics = None
    if with_statistics:
        errors = {n: {p.key: np.abs(grads[n][p.key]) / 4 for p in params} for n in OBJECTIVES}
        sums = {n: rng.random((len(params), 3, 4)) for n in OBJECTIVES}
        batches = {n: (0.5, 0.6, 0.55) for n in OBJECTIVES}
        statistics = Statistics("batches", (8, 8, 8), (1, 2, 3), batches, errors, sums)
    return SensitivityBuffer(
        provenance={"tool": "test"},
        objects=("ball", "floor", "lamp", "wall0", "wall1", "wall2"),
        params=tuple(params),
        objectives=tuple(ObjectiveRecord(n, {}, 0.5, j) for j, n in enumerate(OBJECTIVES)),
        values=values,
        grads=grads,
        statistics=statistics,
    )


CASES = [
    {"method": method, "weight": weight, "untrusted": untrusted}
    for method in ("l2", "rms", "sum")
    for weight in ("value", "raw")
    for untrusted in ("apart", "include")
]


def every_output(buf: SensitivityBuffer) -> Iterator[Any]:
    """Every ranking `rank` prints for ``buf``, under every option that changes a number."""
    for case in CASES:
        yield summary_of(buf, as_json=True, top=50, **case)
        yield summary_of(buf, as_json=False, top=50, **case)
        for by in ("key", "object", "type"):
            found = rankings(buf, by=by, top=None, **case)  # type: ignore[arg-type]
            method, weight = case["method"], case["weight"]
            yield ranking_json(buf, found, method=method, weight=weight, cameras=None)  # type: ignore[arg-type]
            yield ranking_text(found, method=method, weight=weight)  # type: ignore[arg-type]
            yield ranking_csv(found)


@pytest.fixture(scope="module", params=[False, True], ids=["one-batch", "batches"])
def written(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> tuple[SensitivityBuffer, Path]:
    buf = buffer_with_everything(request.param)
    path = tmp_path_factory.mktemp("sums") / "buffer.npz"
    write_buffer(path, buf)
    return buf, path


def test_rank_from_the_sums_is_rank_from_the_arrays(
    written: tuple[SensitivityBuffer, Path],
) -> None:
    buf, path = written
    lazy = read_buffer(path, lazy=True)
    assert lazy.sums is not None and buf.sums is None  # the file's sums, the arrays' sums
    expected = json.dumps(list(every_output(buf)))
    assert json.dumps(list(every_output(lazy))) == expected
    assert json.dumps(list(every_output(read_buffer(path)))) == expected


def test_rank_command_prints_what_the_arrays_give(written: tuple[SensitivityBuffer, Path]) -> None:
    buf, path = written
    for case in CASES:
        for as_json in (False, True):
            style = "json" if as_json else "text"
            shown = rank_buffer(path, by=None, objectives=(), style=style, exrs=(), top=8, **case)  # type: ignore[arg-type]
            assert shown == summary_of(buf, as_json=as_json, top=8, **case)  # type: ignore[arg-type]
        found = rankings(buf, by="object", top=5, **case)  # type: ignore[arg-type]
        text = rank_buffer(path, by="object", objectives=(), style="text", exrs=(), top=5, **case)  # type: ignore[arg-type]
        assert text == ranking_text(found, method=case["method"], weight=case["weight"])  # type: ignore[arg-type]


def test_rank_reads_no_texel(
    written: tuple[SensitivityBuffer, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    read: list[str] = []
    original = Archive.array

    def counting(self: Archive, name: str, check: Any) -> np.ndarray:
        read.append(name)
        return original(self, name, check)

    monkeypatch.setattr(Archive, "array", counting)
    _, path = written
    rank_buffer(
        path, by=None, objectives=(), style="json", exrs=(), top=8, method="l2", weight="value"
    )
    for by in ("key", "object", "type"):
        rank_buffer(path, by=by, objectives=(), style="json", exrs=(), top=8, method="rms",  # type: ignore[arg-type]
                    weight="value", untrusted="apart")  # fmt: skip
    assert read and not [name for name in read if name.startswith(TEXEL_MEMBERS)]
    read.clear()
    read_buffer(path)  # every other command reads, and checks, every member
    assert {"texture_00000", "texture_00001", "texgrad_00000"} <= set(read)


def _flip_texel(path: Path, target: Path) -> None:
    """A copy of ``path`` with one byte of the first texture's texels changed (its CRC fails)."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("texture_00000.npy")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    data[start + info.file_size - 1] ^= 0xFF
    target.write_bytes(bytes(data))


def test_a_corrupt_texture_is_refused_when_it_is_read(
    written: tuple[SensitivityBuffer, Path], tmp_path: Path
) -> None:
    _, path = written
    spoiled = tmp_path / "spoiled.npz"
    _flip_texel(path, spoiled)
    with pytest.raises(BufferFormatError, match="CRC"):
        read_buffer(spoiled)  # the eager reader checks every member
    with pytest.raises(BufferFormatError, match="CRC") as info:  # at the latest when read
        read_buffer(spoiled, lazy=True).value("wall0.bsdf.reflectance.data")
    assert str(spoiled) in str(info.value) and "\n" not in str(info.value)


def test_a_version_4_file_without_sums_is_ranked_from_its_arrays(
    written: tuple[SensitivityBuffer, Path], tmp_path: Path
) -> None:
    """The sums are optional (docs/buffer-format.md): a file without them ranks the same."""
    buf, path = written
    bare = tmp_path / "bare.npz"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(bare, "w") as out:
        for info in src.infolist():
            if not info.filename.startswith(("sums_", "value_means")):
                out.writestr(info, src.read(info))
    loaded = read_buffer(bare, lazy=True)
    assert loaded.sums is None
    assert json.dumps(list(every_output(loaded))) == json.dumps(list(every_output(buf)))


def test_sums_without_value_means_are_refused(
    written: tuple[SensitivityBuffer, Path], tmp_path: Path
) -> None:
    _, path = written
    partial = tmp_path / "partial.npz"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(partial, "w") as out:
        for info in src.infolist():
            if info.filename != "value_means.npy":
                out.writestr(info, src.read(info))
    with pytest.raises(BufferFormatError, match="sums_000"):
        read_buffer(partial, lazy=True)
