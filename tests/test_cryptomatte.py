"""Cryptomatte IDs, manifest and rank layers, checked against the specification.

The decoder here is written from the specification alone: it reads the file with OpenImageIO,
parses the metadata and manifest JSON itself, and turns every pixel's ID floats into bits with
``struct``, never calling the writer's conversion.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import mmh3
import numpy as np
import pytest

from sensaov_cli.outputs import layered_exr as cryptomatte
from sensaov_cli.outputs.layered_exr import CryptoLayer, write_layered_exr

SAMPLES = 4  # per axis: 16 stratified samples a pixel, so coverages are multiples of 1/16
NAMES = ("floor/plane", "bunny", "Teapot é", "never-hit")


def synthetic_coverage(
    height: int = 24, width: int = 32, ranks: int = 4
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Box-filtered coverage of three overlapping shapes: (rank_index, rank_coverage, background).

    Front to back: a disc ("bunny", index 1), a rectangle ("Teapot é", 2), and a floor over the
    lower 40 % ("floor/plane", 0). ``NAMES[3]`` is in the manifest but never hit.
    """
    offsets = (np.arange(SAMPLES) + 0.5) / SAMPLES
    y = (np.arange(height)[:, None] + offsets[None, :]).reshape(-1) / height
    x = (np.arange(width)[:, None] + offsets[None, :]).reshape(-1) / width
    yy, xx = np.meshgrid(y, x, indexing="ij")
    samples = np.full(yy.shape, -1)
    samples[yy > 0.6] = 0
    samples[(xx > 0.48) & (xx < 0.85) & (yy > 0.2) & (yy < 0.7)] = 2
    samples[(xx - 0.35) ** 2 + (yy - 0.45) ** 2 < 0.2**2] = 1
    per_pixel = samples.reshape(height, SAMPLES, width, SAMPLES).transpose(0, 2, 1, 3)
    hit = per_pixel.reshape(height, width, SAMPLES * SAMPLES)
    counts = np.stack([(hit == k).sum(axis=-1) for k in range(len(NAMES))], axis=-1)
    order = np.argsort(-counts, axis=-1, kind="stable")[..., :ranks]
    coverage = np.take_along_axis(counts, order, axis=-1).astype(np.float32) / SAMPLES**2
    index = np.where(coverage > 0, order, -1).astype(np.int32)
    background = (hit == -1).mean(axis=-1).astype(np.float32)
    return index, coverage, background


# --- an independent decoder, from the specification ----------------------------------------


def decode_file(
    path: Path, type_name: str
) -> tuple[list[np.ndarray], list[np.ndarray], dict[str, str]]:
    """Per rank: the pixels' names (object array, None = empty) and coverages; plus the manifest."""
    import OpenImageIO as oiio

    source = oiio.ImageInput.open(str(path))
    assert source, oiio.geterror()
    try:
        spec = source.spec()
        pixels = source.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        assert pixels is not None, oiio.geterror()
        attributes: dict[str, Any] = {attr.name: attr.value for attr in spec.extra_attribs}
        names = list(spec.channelnames)
    finally:
        source.close()
    prefixes = [k[: -len("/name")] for k, v in attributes.items() if k.endswith("/name")]
    (prefix,) = [
        p for p in prefixes if p.startswith("cryptomatte/") and attributes[p + "/name"] == type_name
    ]
    assert attributes[prefix + "/hash"] == "MurmurHash3_32"
    assert attributes[prefix + "/conversion"] == "uint32_to_float32"
    manifest = json.loads(attributes[prefix + "/manifest"])
    by_hex = {hex_id: name for name, hex_id in manifest.items()}
    rank_names, rank_coverages = [], []
    layer = 0
    while f"{type_name}{layer:02d}.R" in names:
        for id_channel, cov_channel in (("R", "G"), ("B", "A")):
            ids = pixels[..., names.index(f"{type_name}{layer:02d}.{id_channel}")]
            coverage = pixels[..., names.index(f"{type_name}{layer:02d}.{cov_channel}")]
            decoded = np.empty(ids.shape, dtype=object)
            for position, value in np.ndenumerate(ids):
                bits = struct.unpack("<I", struct.pack("<f", value))[0]
                decoded[position] = None if bits == 0 else by_hex[f"{bits:08x}"]
            rank_names.append(decoded)
            rank_coverages.append(np.asarray(coverage, dtype=np.float64))
        layer += 1
    return rank_names, rank_coverages, manifest


def spec_id_hex(name: str) -> str:
    """The specification's ID for a name, computed here without the writer's helpers."""
    bits = mmh3.hash(name.encode("utf-8"), 0, signed=False)
    if ((bits >> 23) & 0xFF) in (0, 255):
        bits ^= 1 << 23
    return f"{bits:08x}"


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray, np.ndarray]:
    index, coverage, background = synthetic_coverage()
    path = tmp_path_factory.mktemp("crypto") / "ids.exr"
    height, width = index.shape[:2]
    crypto = CryptoLayer("CryptoObject", NAMES, index, coverage)
    write_layered_exr(
        path,
        beauty=None,
        cryptomattes=[crypto],
        layers=[],
        attributes={},
    )
    return path, index, coverage


# --- hashes and IDs ------------------------------------------------------------------------


def test_known_hash_values() -> None:
    assert cryptomatte.name_hash("hello") == 613153351
    assert json.loads(cryptomatte.manifest(["default", "bunny"])) == {
        "bunny": "13851a76",
        "default": "42c9679f",
    }


def test_id_float_holds_the_hash_bits_little_endian() -> None:
    value = cryptomatte.id_float("bunny")
    assert isinstance(value, np.float32)
    assert struct.pack("<f", value) == bytes.fromhex("13851a76")[::-1]


@pytest.mark.parametrize(
    ("crafted", "expected"),
    [
        (0x00000000, 0x00800000),  # exponent 0: zero
        (0x807FFFFF, 0x80FFFFFF),  # exponent 0: negative denormal
        (0x7F800000, 0x7F000000),  # exponent 255: +inf
        (0xFFC00001, 0xFF400001),  # exponent 255: NaN
        (0x13851A76, 0x13851A76),  # an ordinary exponent is left alone
    ],
)
def test_exponent_clamp_on_crafted_hashes(
    monkeypatch: pytest.MonkeyPatch, crafted: int, expected: int
) -> None:
    monkeypatch.setattr(cryptomatte, "name_hash", lambda name: crafted)
    assert cryptomatte.id_bits("any") == expected
    value = cryptomatte.id_float("any")
    assert np.isfinite(value) and abs(value) >= np.finfo(np.float32).tiny
    assert cryptomatte.id_hex("any") == f"{expected:08x}"


def test_exponent_clamp_on_real_names() -> None:
    clamped: dict[int, str] = {}
    for number in range(5000):
        name = f"object_{number}"
        exponent = (mmh3.hash(name.encode(), 0, signed=False) >> 23) & 0xFF
        if exponent in (0, 255):
            clamped.setdefault(exponent, name)
    assert set(clamped) == {0, 255}
    for name in clamped.values():
        assert cryptomatte.id_hex(name) == spec_id_hex(name)
        assert np.isfinite(cryptomatte.id_float(name))


def test_layer_key_and_metadata() -> None:
    key = f"{mmh3.hash(b'CryptoObject', 0, signed=False):08x}"[:7]
    assert cryptomatte.layer_key("CryptoObject") == key
    meta = cryptomatte.metadata("CryptoObject", ["bunny", "bunny", "Teapot é"])
    assert meta == {
        f"cryptomatte/{key}/name": "CryptoObject",
        f"cryptomatte/{key}/hash": "MurmurHash3_32",
        f"cryptomatte/{key}/conversion": "uint32_to_float32",
        f"cryptomatte/{key}/manifest": meta[f"cryptomatte/{key}/manifest"],
    }
    parsed = json.loads(meta[f"cryptomatte/{key}/manifest"])
    assert parsed == {"bunny": spec_id_hex("bunny"), "Teapot é": spec_id_hex("Teapot é")}


def test_bad_type_name_and_shapes_are_refused() -> None:
    index, coverage, _ = synthetic_coverage(4, 4)
    with pytest.raises(ValueError, match="type name"):
        cryptomatte.rank_channels("Crypto.Object", NAMES, index, coverage)
    with pytest.raises(ValueError, match="share one"):
        cryptomatte.rank_channels("CryptoObject", NAMES, index, coverage[..., :2])
    with pytest.raises(ValueError, match="names"):
        cryptomatte.rank_channels("CryptoObject", NAMES[:1], index, coverage)


# --- rank layers -------------------------------------------------------------------------


def test_three_layers_always_present_and_padded() -> None:
    index = np.full((2, 3, 1), -1, dtype=np.int32)
    coverage = np.zeros((2, 3, 1), dtype=np.float32)
    channels = cryptomatte.rank_channels("CryptoObject", [], index, coverage)
    assert list(channels) == [f"CryptoObject{k:02d}.{c}" for k in range(3) for c in "RGBA"]
    for data in channels.values():
        assert data.shape == (2, 3) and data.dtype == np.float32
        assert data.flags.c_contiguous and not data.any()
    assert "CryptoObject.R" not in channels


def test_ranks_are_resorted_and_truncated() -> None:
    names = [f"n{k}" for k in range(8)]
    index = np.arange(8, dtype=np.int32).reshape(1, 1, 8)
    coverage = np.array([[[0.01, 0.3, 0.02, 0.2, 0.25, 0.1, 0.07, 0.05]]], dtype=np.float32)
    channels = cryptomatte.rank_channels("CryptoObject", names, index, coverage)
    covs = [channels[f"CryptoObject{k // 2:02d}.{'GA'[k % 2]}"][0, 0] for k in range(6)]
    ids = [channels[f"CryptoObject{k // 2:02d}.{'RB'[k % 2]}"][0, 0] for k in range(6)]
    assert covs == pytest.approx([0.3, 0.25, 0.2, 0.1, 0.07, 0.05])
    assert [struct.pack("<f", v).hex() for v in ids] == [
        bytes.fromhex(spec_id_hex(f"n{k}"))[::-1].hex() for k in (1, 4, 3, 5, 6, 7)
    ]


def test_empty_ranks_are_zero_even_with_stray_coverage() -> None:
    index = np.array([[[-1, 0]]], dtype=np.int32)
    coverage = np.array([[[0.9, 0.4]]], dtype=np.float32)
    channels = cryptomatte.rank_channels("CryptoObject", ["a"], index, coverage)
    assert channels["CryptoObject00.G"][0, 0] == pytest.approx(0.4)
    assert channels["CryptoObject00.B"][0, 0] == 0.0 and channels["CryptoObject00.A"][0, 0] == 0.0


def test_ranks_already_in_order_skip_the_sort_with_the_same_channels() -> None:
    """A visibility pass's ranks come in order and are not sorted again: the
    channels equal those of the same ranks shuffled per pixel, which must be sorted."""
    rng = np.random.default_rng(3)
    names = [f"n{k}" for k in range(9)]
    counts = -np.sort(-rng.permuted(np.tile(np.arange(1, 7), (6, 7, 1)), axis=-1), axis=-1)
    filled = np.arange(6) < rng.integers(0, 7, size=(6, 7, 1))  # empty ranks last
    index = np.where(filled, rng.integers(0, 9, size=counts.shape), -1).astype(np.int32)
    coverage = np.where(filled, counts / 16.0, 0.5).astype(np.float32)  # stray on empties
    shuffle = np.argsort(rng.random(counts.shape), axis=-1)
    shuffled = [np.take_along_axis(a, shuffle, axis=-1) for a in (index, coverage)]
    in_order = cryptomatte.rank_channels("CryptoObject", names, index, coverage, ranks=4)
    resorted = cryptomatte.rank_channels("CryptoObject", names, *shuffled, ranks=4)
    assert in_order.keys() == resorted.keys()
    assert all(np.array_equal(data, resorted[name]) for name, data in in_order.items())
    assert any(in_order[name].any() for name in in_order if name.endswith("A"))


# --- the written file, decoded independently ---------------------------------------------


def test_decoder_finds_every_pixel_name(written: tuple[Path, np.ndarray, np.ndarray]) -> None:
    path, index, coverage = written
    rank_names, rank_coverages, manifest = decode_file(path, "CryptoObject")
    assert len(rank_names) == 6  # three layers, always
    assert manifest == {name: spec_id_hex(name) for name in NAMES}
    for rank in range(6):
        ranked = index[..., rank] if rank < index.shape[2] else np.full(index.shape[:2], -1)
        expected = np.array([[None if k < 0 else NAMES[k] for k in row] for row in ranked], object)
        assert (rank_names[rank] == expected).all()
        assert (rank_coverages[rank][ranked < 0] == 0).all()
        if rank < index.shape[2]:
            np.testing.assert_allclose(rank_coverages[rank], coverage[..., rank], atol=0)
    for name in NAMES[:3]:
        assert any((names == name).any() for names in rank_names), name


def test_coverage_sums_to_one_and_ranks_are_sorted(
    written: tuple[Path, np.ndarray, np.ndarray],
) -> None:
    path, _, _ = written
    _, rank_coverages, _ = decode_file(path, "CryptoObject")
    _, _, background = synthetic_coverage()
    total = np.sum(rank_coverages, axis=0)
    hit = background < 1
    assert hit.any() and (background == 0).any()
    np.testing.assert_allclose(total[hit] + background[hit], 1.0, atol=1e-6)
    np.testing.assert_allclose(total[background == 0], 1.0, atol=1e-6)
    assert (np.diff(np.stack(rank_coverages), axis=0) <= 0).all()


def test_ranks_a_visibility_pass_builds_need_no_reordering() -> None:
    """``ordered=True`` (what project passes for a visibility pass's ranks) skips the zeroing,
    check and sort: on ranks from random sample ids the channels are bit for bit those of the
    checked path, and the check itself agrees they were in order."""
    from sensaov_cli.views.coverage import histogram, ranked

    rng = np.random.default_rng(8)
    names = [f"object_{i}" for i in range(12)]
    samples = rng.integers(-1, len(names), size=(30 * 40, 16)).astype(np.int32)
    index, coverage = ranked(histogram(samples), (30, 40), 16, ranks=6)
    assert cryptomatte._in_rank_order(coverage, index < 0)
    checked = cryptomatte.rank_channels("CryptoObject", names, index, coverage)
    trusted = cryptomatte.rank_channels("CryptoObject", names, index, coverage, ordered=True)
    assert checked.keys() == trusted.keys()
    assert all(np.array_equal(checked[k], trusted[k]) for k in checked)
