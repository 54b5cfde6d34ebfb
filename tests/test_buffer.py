"""The sensitivity buffer: construction checks, the .npz format, atomic writes, unreadable files."""

from __future__ import annotations

import io
import json
import os
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sensaov_cli import interrupts
from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.npz import FORMAT_NAME, FORMAT_VERSION, read_buffer
from sensaov_cli.cli import main
from sensaov_cli.errors import (
    EXIT_BAD_INPUT,
    BufferContentError,
    BufferFormatError,
    NonFiniteGradientError,
    UnknownNameError,
)
from tests.bad_buffers import write_buffer

REPO = Path(__file__).resolve().parents[1]

PARAMS = (
    ParamRecord("white.bsdf.reflectance.value", "reflectance", ("white",), (3,), False,
                "diffuse", (), "verified", ""),
    ParamRecord("mat.reflectance.data", "reflectance", ("floor", "wall"), (4, 5, 3), True,
                "diffuse", (), "verified", ""),
    ParamRecord("floor.bsdf.alpha.value", "roughness", ("floor",), (1,), False,
                "roughplastic", ("discontinuous",), "biased", "known biased"),
)  # fmt: skip
OBJECTIVES = (
    ObjectiveRecord("brightness", {"kind": "mean_luminance", "region": [0, 0, 8, 8]}, 0.25, 7),
    ObjectiveRecord("contrast", {"kind": "contrast"}, -1.5, 8),
)


def make_parts(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return {
        "provenance": {"tool": "sensaov 0.1.0", "spp": 16, "seeds": [1, 2], "scene": "cbox.xml"},
        "objects": ("wall", "white", "floor", "light"),
        "params": PARAMS,
        "objectives": OBJECTIVES,
        "values": {p.key: rng.random(p.shape, dtype=np.float32) for p in PARAMS},
        "grads": {
            o.name: {p.key: rng.standard_normal(p.shape, dtype=np.float32) for p in PARAMS}
            for o in OBJECTIVES
        },
    }


@pytest.fixture
def buf() -> SensitivityBuffer:
    return SensitivityBuffer(**make_parts())


@pytest.fixture
def saved(buf: SensitivityBuffer, tmp_path: Path) -> Path:
    path = tmp_path / "buffer.npz"
    write_buffer(path, buf)
    return path


def assert_same(a: SensitivityBuffer, b: SensitivityBuffer) -> None:
    assert (a.provenance, a.objects, a.params, a.objectives) == (
        b.provenance, b.objects, b.params, b.objectives
    )  # fmt: skip
    for p in a.params:
        assert a.value(p.key).tobytes() == b.value(p.key).tobytes()
        for o in a.objectives:
            assert a.grad(o.name, p.key).tobytes() == b.grad(o.name, p.key).tobytes()


def test_round_trip_is_exact(buf: SensitivityBuffer, saved: Path) -> None:
    loaded = read_buffer(saved)
    assert_same(buf, loaded)
    arr = loaded.grad("contrast", "mat.reflectance.data")
    assert arr.dtype == np.float32 and arr.flags.c_contiguous and not arr.flags.writeable


def test_save_leaves_only_the_file(saved: Path) -> None:
    assert os.listdir(saved.parent) == [saved.name]


def test_objects_are_sorted_and_records_accessible(buf: SensitivityBuffer) -> None:
    assert buf.objects == ("floor", "light", "wall", "white")
    assert buf.types() == ("reflectance", "roughness")
    assert buf.param("floor.bsdf.alpha.value").verified is False
    assert buf.param("floor.bsdf.alpha.value").trust == "biased"
    assert buf.param("white.bsdf.reflectance.value").verified is True
    assert buf.objective("contrast").value == -1.5


def test_arrays_are_float32_copies(buf: SensitivityBuffer) -> None:
    parts = make_parts()
    value = np.ones((3,), dtype=np.float64)
    parts["values"]["white.bsdf.reflectance.value"] = value
    built = SensitivityBuffer(**parts)
    value[0] = 7.0
    stored = built.value("white.bsdf.reflectance.value")
    assert stored.dtype == np.float32 and stored[0] == 1.0


def test_nan_gradient_is_refused() -> None:
    parts = make_parts()
    parts["grads"]["contrast"]["mat.reflectance.data"][1, 2, 0] = np.nan
    with pytest.raises(NonFiniteGradientError) as info:
        SensitivityBuffer(**parts)
    assert "'contrast'" in str(info.value) and "'mat.reflectance.data'" in str(info.value)
    assert (info.value.objective, info.value.key) == ("contrast", "mat.reflectance.data")


def _missing_value(parts: dict) -> None:
    del parts["values"]["white.bsdf.reflectance.value"]


def _wrong_shape(parts: dict) -> None:
    parts["grads"]["brightness"]["floor.bsdf.alpha.value"] = np.zeros((2,), np.float32)


def _missing_gradient(parts: dict) -> None:
    del parts["grads"]["contrast"]["floor.bsdf.alpha.value"]


def _duplicate_key(parts: dict) -> None:
    parts["params"] = (*PARAMS, PARAMS[0])


def _unknown_owner(parts: dict) -> None:
    parts["objects"] = ("wall", "white", "light")


def _undeclared_objective(parts: dict) -> None:
    parts["grads"]["extra"] = parts["grads"]["contrast"]


def _infinite_value(parts: dict) -> None:
    parts["values"]["floor.bsdf.alpha.value"] = np.array([np.inf], np.float32)


@pytest.mark.parametrize(
    "spoil",
    [_missing_value, _wrong_shape, _missing_gradient, _duplicate_key, _unknown_owner,
     _undeclared_objective, _infinite_value],
)  # fmt: skip
def test_inconsistent_buffer_is_refused(spoil) -> None:
    parts = make_parts()
    spoil(parts)
    with pytest.raises(BufferContentError):
        SensitivityBuffer(**parts)


def test_a_file_with_an_unknown_trust_label_is_refused(saved: Path) -> None:
    _unknown_label(saved)
    with pytest.raises(BufferFormatError, match=r"params\[0\]\.trust is 'trusted', not one of"):
        read_buffer(saved)


def test_unknown_objective_suggests_the_closest(buf: SensitivityBuffer) -> None:
    with pytest.raises(UnknownNameError) as info:
        buf.objective("brightnes")
    assert "did you mean 'brightness'" in str(info.value)


class _Failure(Exception):
    pass


@pytest.mark.parametrize("error", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_failed_write_keeps_the_existing_file(
    buf: SensitivityBuffer, saved: Path, monkeypatch: pytest.MonkeyPatch, error: BaseException
) -> None:
    before = saved.read_bytes()

    def half_write(out: io.BufferedWriter, arr: np.ndarray, **kwargs: object) -> None:
        out.write(b"\x93NUMPY half an array")
        raise error

    monkeypatch.setattr(np.lib.format, "write_array", half_write)
    with pytest.raises(type(error)):
        write_buffer(saved, buf)
    assert saved.read_bytes() == before
    assert os.listdir(saved.parent) == [saved.name]


def test_unwritable_location_is_an_os_error(buf: SensitivityBuffer, tmp_path: Path) -> None:
    (tmp_path / "a-file").write_text("")
    with pytest.raises(OSError) as info:
        write_buffer(tmp_path / "a-file" / "buffer.npz", buf)
    assert "a-file" in str(info.value)


# --- unreadable files: every one is a one-line BufferFormatError naming the path -------------


def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def _write_members(path: Path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)


def _npy(arr: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array(out, arr, allow_pickle=False)
    return out.getvalue()


def _with_header(path: Path, edit) -> None:
    members = _members(path)
    header = json.loads(str(np.load(io.BytesIO(members["header.npy"]))[()]))
    edit(header)
    members["header.npy"] = _npy(np.array(json.dumps(header)))
    _write_members(path, members)


def _empty(p: Path) -> None:
    p.write_bytes(b"")


def _text(p: Path) -> None:
    p.write_text("hello, not a buffer\n")


def _truncated(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _bit_flip(p: Path) -> None:
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0xFF  # inside a member: the zip CRC catches it
    p.write_bytes(bytes(data))


def _plain_npy(p: Path) -> None:
    p.write_bytes(_npy(np.zeros(3, np.float32)))


def _plain_npz(p: Path) -> None:
    _write_members(p, {"a.npy": _npy(np.zeros(3, np.float32))})


def _foreign_format(p: Path) -> None:
    _with_header(p, lambda h: h.update(format="someone-elses-buffer"))


def _unknown_version(p: Path) -> None:
    _with_header(p, lambda h: h.update(format_version=FORMAT_VERSION + 1))


def _extra_header_field(p: Path) -> None:
    _with_header(p, lambda h: h.update(extra=1))


def _float_version(p: Path) -> None:
    _with_header(p, lambda h: h.update(format_version=float(FORMAT_VERSION)))


def _no_statistics_field(p: Path) -> None:
    _with_header(p, lambda h: h.pop("statistics"))


def _float_array_index(p: Path) -> None:
    _with_header(p, lambda h: h["params"][0].update(array=0.0))


def _duplicate_member(p: Path) -> None:
    """A second member of the same name: np.load would silently read one of them."""
    with zipfile.ZipFile(p, "a") as zf, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zipfile warns about the duplicate name
        zf.writestr("values.npy", _npy(np.array([9, 9, 9, 9], "<f4")))


def _missing_array(p: Path) -> None:
    members = _members(p)
    del members["grads_001.npy"]
    _write_members(p, members)


def _shape_mismatch(p: Path) -> None:
    _with_header(p, lambda h: h["params"][1].update(shape=[5, 4, 3]))


def _float64_array(p: Path) -> None:
    members = _members(p)
    members["values.npy"] = _npy(np.zeros(4, np.float64))
    _write_members(p, members)


def _nan_in_file(p: Path) -> None:
    members = _members(p)
    members["grads_000.npy"] = _npy(np.full(4, np.nan, np.float32))
    _write_members(p, members)


def _bad_record(p: Path) -> None:
    _with_header(p, lambda h: h["params"][0].pop("owners"))


def _unknown_label(p: Path) -> None:
    _with_header(p, lambda h: h["params"][0].update(trust="trusted"))


def _unknown_record_field(p: Path) -> None:
    _with_header(p, lambda h: h["params"][0].update(verified=True))


def _directory(p: Path) -> None:
    p.unlink()
    p.mkdir()


def _nonexistent(p: Path) -> None:
    p.unlink()


@pytest.mark.parametrize(
    "spoil",
    [_empty, _text, _truncated, _bit_flip, _plain_npy, _plain_npz, _foreign_format,
     _unknown_version, _missing_array, _shape_mismatch, _float64_array, _nan_in_file,
     _bad_record, _directory, _nonexistent, _extra_header_field, _unknown_label,
     _unknown_record_field, _float_version, _no_statistics_field, _float_array_index,
     _duplicate_member],
)  # fmt: skip
def test_unreadable_file_is_a_buffer_format_error(saved: Path, spoil) -> None:
    spoil(saved)
    with pytest.raises(BufferFormatError) as info:
        read_buffer(saved)
    message = str(info.value)
    assert str(saved) in message and "\n" not in message


def test_unknown_version_says_so(saved: Path) -> None:
    _unknown_version(saved)
    with pytest.raises(BufferFormatError, match=f"version {FORMAT_VERSION + 1} is not supported"):
        read_buffer(saved)


# --- the format itself: a change to it must show up here ------------------------------------


def test_file_layout_is_version_4(saved: Path) -> None:
    with np.load(saved, allow_pickle=False) as npz:
        names = sorted(npz.files)
        header = json.loads(str(npz["header"]))
    assert names == [
        "grads_000", "grads_001", "header", "sums_000", "sums_001", "texgrad_00000",
        "texgrad_00001", "texture_00000", "value_means", "values",
    ]  # fmt: skip
    assert header == {
        "format": "sensaov-buffer",
        "format_version": 4,
        "provenance": {"tool": "sensaov 0.1.0", "spp": 16, "seeds": [1, 2], "scene": "cbox.xml"},
        "objects": ["floor", "light", "wall", "white"],
        "params": [
            {"key": "white.bsdf.reflectance.value", "type": "reflectance", "owners": ["white"],
             "shape": [3], "is_texture": False, "plugin": "diffuse", "flags": [],
             "trust": "verified", "note": "", "estimator": "reverse", "array": 0},
            {"key": "mat.reflectance.data", "type": "reflectance", "owners": ["floor", "wall"],
             "shape": [4, 5, 3], "is_texture": True, "plugin": "diffuse", "flags": [],
             "trust": "verified", "note": "", "estimator": "reverse", "array": 1},
            {"key": "floor.bsdf.alpha.value", "type": "roughness", "owners": ["floor"],
             "shape": [1], "is_texture": False, "plugin": "roughplastic",
             "flags": ["discontinuous"], "trust": "biased", "note": "known biased",
             "estimator": "reverse", "array": 2},
        ],
        "objectives": [
            {"name": "brightness", "definition": {"kind": "mean_luminance", "region": [0, 0, 8, 8]},
             "value": 0.25, "grad_seed": 7, "array": 0},
            {"name": "contrast", "definition": {"kind": "contrast"}, "value": -1.5,
             "grad_seed": 8, "array": 1},
        ],
        "statistics": None,
        "storage": {"packed": 4, "params": [
            {"offset": 0}, {"value": 0, "grads": [0, 1]}, {"offset": 3},
        ]},
        "repairs": {},
    }  # fmt: skip
    with np.load(saved) as npz:
        assert npz["values"].shape == (4,) and npz["texture_00000"].shape == (4, 5, 3)


def _write_by_hand(path: Path, version: int = FORMAT_VERSION) -> None:
    """A buffer written from docs/buffer-format.md alone, deflated, big-endian value."""
    header = {
        "format": FORMAT_NAME, "format_version": version, "provenance": {}, "objects": ["lamp"],
        "params": [{"key": "lamp.emitter.radiance.value", "type": "radiance", "owners": ["lamp"],
                    "shape": [3], "is_texture": False, "plugin": "area", "flags": [],
                    "trust": "suspect", "note": "", "estimator": "reverse", "array": 0}],
        "objectives": [{"name": "m", "definition": {}, "value": 1.0, "grad_seed": 0, "array": 0}],
        "statistics": None, "repairs": {},
        "storage": {"packed": 3, "params": [{"offset": 0}]},
    }  # fmt: skip
    # packed: the parameter is values[0:3] and grads_000[0:3]
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("header.npy", _npy(np.array(json.dumps(header))))
        zf.writestr("values.npy", _npy(np.array([1, 2, 3], ">f4")))
        zf.writestr("grads_000.npy", _npy(np.array([0.5, 0, -1], "<f4")))


def test_reads_a_file_written_from_the_spec(tmp_path: Path) -> None:
    """docs/buffer-format.md is enough to write a buffer without sensaov's writer."""
    path = tmp_path / "by-hand.npz"
    _write_by_hand(path)
    loaded = read_buffer(path)
    assert loaded.value("lamp.emitter.radiance.value").tolist() == [1, 2, 3]
    assert loaded.grad("m", "lamp.emitter.radiance.value").tolist() == [0.5, 0, -1]
    assert loaded.param("lamp.emitter.radiance.value").trust == "suspect"
    value = loaded.value("lamp.emitter.radiance.value")
    assert value.dtype == np.float32 and value.dtype.isnative and not value.flags.writeable


OLDER = "written by an older sensaov: re-run"


@pytest.mark.parametrize("version", [1, 2, 3])
def test_an_older_format_is_refused_in_one_line(saved: Path, version: int) -> None:
    """A 0.x tool reads its current format only: an older file is one line, exit 2, re-run."""
    _with_header(saved, lambda h: h.update(format_version=version))
    with pytest.raises(BufferFormatError) as info:
        read_buffer(saved)
    message = str(info.value)
    assert info.value.exit_code == EXIT_BAD_INPUT and "\n" not in message
    assert message.startswith(f"{saved}: buffer format version {version}, {OLDER}")


def test_rank_refuses_an_older_format_with_exit_2(
    saved: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        interrupts, "install", lambda **_: None
    )  # the test runner keeps its signals
    _with_header(saved, lambda h: h.update(format_version=3))
    result = CliRunner().invoke(main, ["rank", str(saved)])
    assert result.exit_code == EXIT_BAD_INPUT
    (line,) = result.stderr.splitlines()
    assert str(saved) in line and OLDER in line


def test_plain_numpy_example_in_the_docs_runs(saved: Path, capsys) -> None:
    doc = (REPO / "docs" / "buffer-format.md").read_text()
    example = doc.split("```python\n", 1)[1].split("```", 1)[0]
    exec(example.replace("out/cbox/buffer.npz", str(saved)), {})
    assert len(capsys.readouterr().out.splitlines()) == 2 * 3
