"""The compositor EXR: channel names, types, compression, windows and metadata, read back with
OpenImageIO (a reader independent of the OpenEXR binding that writes)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sensaov_cli.outputs import layered_exr as exr_layout
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.layered_exr import (
    CryptoLayer,
    SensitivityLayer,
    layer_key,
    layer_names,
    write_layered_exr,
)
from tests.test_cryptomatte import NAMES, synthetic_coverage

HEIGHT, WIDTH = 24, 32
# The documented layout (docs/exr-layout.md) for the synthetic file below, in OIIO's order.
GOLDEN_CHANNELS = [
    "R", "G", "B", "A",
    *[f"CryptoObject{k:02d}.{c}" for k in range(3) for c in "RGBA"],
    "mean_luma.albedo.R", "mean_luma.albedo.G", "mean_luma.albedo.B",
    "mean_luma.roughness.Y",
    "sky_region.albedo.R", "sky_region.albedo.G", "sky_region.albedo.B",
    "sky_region.roughness.Y",
]  # fmt: skip


def synthetic_layers(rng: np.random.Generator) -> list[SensitivityLayer]:
    layers = []
    for objective in ("mean_luma", "sky region"):
        # a transposed and a strided view: the binding writes such arrays wrong unless copied
        albedo = rng.normal(size=(WIDTH, HEIGHT, 3)).astype(np.float32).transpose(1, 0, 2)
        roughness = rng.normal(size=(HEIGHT, 2 * WIDTH))[:, ::2]  # float64 too
        for pass_name, data in (("albedo", albedo), ("roughness", roughness)):
            meta = {"selection": f"*.{pass_name}", "aggregate": "l2", "encoding": "signed",
                    "spp": "16"}  # fmt: skip
            layers.append(SensitivityLayer(objective, pass_name, data, meta))
    return layers


def synthetic_crypto() -> CryptoLayer:
    index, coverage, _ = synthetic_coverage(HEIGHT, WIDTH)
    return CryptoLayer("CryptoObject", NAMES, index, coverage)


def write_synthetic(path: Path, seed: int = 0) -> tuple[np.ndarray, list[SensitivityLayer]]:
    rng = np.random.default_rng(seed)
    beauty = rng.uniform(size=(HEIGHT, WIDTH, 4))
    layers = synthetic_layers(rng)
    write_layered_exr(
        path,
        beauty=beauty,
        cryptomattes=[synthetic_crypto()],
        layers=layers,
        attributes={"sensaov/provenance": '{"seed": 0}'},
    )
    return beauty, layers


def oiio_read(path: Path) -> tuple[Any, dict[str, np.ndarray], dict[str, Any]]:
    import OpenImageIO as oiio

    source = oiio.ImageInput.open(str(path))
    assert source, oiio.geterror()
    try:
        spec = source.spec()
        pixels = source.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        assert pixels is not None, oiio.geterror()
    finally:
        source.close()
    channels = {name: pixels[..., k] for k, name in enumerate(spec.channelnames)}
    return spec, channels, {attr.name: attr.value for attr in spec.extra_attribs}


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    path = tmp_path_factory.mktemp("layout") / "camera.exr"
    beauty, layers = write_synthetic(path)
    spec, channels, attributes = oiio_read(path)
    return {
        "path": path,
        "beauty": beauty,
        "layers": layers,
        "spec": spec,
        "channels": channels,
        "attributes": attributes,
    }


def test_channel_names_are_the_documented_ones(synthetic: dict[str, Any]) -> None:
    assert list(synthetic["spec"].channelnames) == GOLDEN_CHANNELS
    assert "CryptoObject.R" not in synthetic["channels"]


def test_every_channel_is_float32_zip_full_window(synthetic: dict[str, Any]) -> None:
    import OpenImageIO as oiio

    spec = synthetic["spec"]
    assert all(spec.channelformat(k) == oiio.FLOAT for k in range(spec.nchannels))
    assert synthetic["attributes"]["compression"] == "zip"
    data_window = (spec.x, spec.y, spec.width, spec.height)
    assert data_window == (spec.full_x, spec.full_y, spec.full_width, spec.full_height)
    assert data_window == (0, 0, WIDTH, HEIGHT)


def test_pixels_survive_including_strided_input(synthetic: dict[str, Any]) -> None:
    channels, beauty, layers = synthetic["channels"], synthetic["beauty"], synthetic["layers"]
    for k, c in enumerate("RGBA"):
        np.testing.assert_array_equal(channels[c], beauty[..., k].astype(np.float32))
    for c, k in zip("RGB", range(3), strict=True):
        np.testing.assert_array_equal(channels[f"mean_luma.albedo.{c}"], layers[0].data[..., k])
    np.testing.assert_array_equal(
        channels["sky_region.roughness.Y"], layers[3].data.astype(np.float32)
    )


def test_metadata_per_layer(synthetic: dict[str, Any]) -> None:
    attributes = synthetic["attributes"]
    assert attributes["sensaov/format"] == "sensaov-aov-exr"
    assert attributes["sensaov/format_version"] == "3"
    assert attributes["sensaov/provenance"] == '{"seed": 0}'
    expected = {
        "mean_luma.albedo": ("mean_luma", "albedo", "R,G,B"),
        "mean_luma.roughness": ("mean_luma", "roughness", "Y"),
        "sky_region.albedo": ("sky region", "albedo", "R,G,B"),
        "sky_region.roughness": ("sky region", "roughness", "Y"),
    }
    for name, (objective, pass_name, channels) in expected.items():
        prefix = f"sensaov/{layer_key(name)}"
        assert attributes[f"{prefix}/name"] == name
        assert attributes[f"{prefix}/objective"] == objective
        assert attributes[f"{prefix}/pass"] == pass_name
        assert attributes[f"{prefix}/original_name"] == f"{objective}.{pass_name}"
        assert attributes[f"{prefix}/channels"] == channels
        assert attributes[f"{prefix}/aggregate"] == "l2"
        assert attributes[f"{prefix}/spp"] == "16"
    crypto = f"cryptomatte/{layer_key('CryptoObject')}"
    assert attributes[f"{crypto}/name"] == "CryptoObject"
    assert attributes[f"{crypto}/hash"] == "MurmurHash3_32"
    assert attributes[f"{crypto}/conversion"] == "uint32_to_float32"
    assert '"bunny":"13851a76"' in attributes[f"{crypto}/manifest"]


def test_own_reader_agrees_with_oiio(synthetic: dict[str, Any]) -> None:
    channels, header = read_exr(synthetic["path"])
    assert sorted(channels) == sorted(GOLDEN_CHANNELS)
    for name, data in channels.items():
        assert data.dtype == np.float32
        np.testing.assert_array_equal(data, synthetic["channels"][name])
    assert header["sensaov/format"] == "sensaov-aov-exr"


def _layer(objective: str, pass_name: str) -> SensitivityLayer:
    return SensitivityLayer(objective, pass_name, np.zeros((2, 2), dtype=np.float32))


def test_sanitising_keeps_names_unique_and_short() -> None:
    long = "o" * 70
    layers = [
        _layer("sky region", "bsdf.albedo"),
        _layer("sky_region", "bsdf_albedo"),
        _layer("sky-region", "bsdf albedo"),
        _layer(long + "a", "p"),
        _layer(long + "b", "p"),
        _layer("a_b", "c"),
        _layer("a", "b_c"),
        _layer("Crypto", "Object00"),
        _layer("ü", "é"),
    ]
    names = layer_names(layers, reserved={"Crypto_Object00"})
    assert names[1] == "sky_region.bsdf_albedo"  # a clean name keeps itself
    assert names[0].startswith("sky_region.bsdf_albedo_") and names[0] != names[2]
    assert names[3] != names[4] and names[3].startswith("o" * 56)
    assert names[5] != "a_b.c" and names[6] != "a.b_c"  # Nuke would show both as a_b_c
    assert names[7].startswith("Crypto.Object00_")
    assert names[8] == "_._"
    nuke_views = [name.replace(".", "_") for name in names] + ["Crypto_Object00"]
    assert len(set(nuke_views)) == len(nuke_views)
    for name in names:
        assert all(0 < len(token.encode()) <= 63 for token in name.split("."))
        assert all(c.isascii() and (c.isalnum() or c in "_.") for c in name)


def test_sanitised_names_keep_originals_in_metadata(tmp_path: Path) -> None:
    layers = [
        SensitivityLayer("sky region", "bsdf.albedo", np.ones((HEIGHT, WIDTH))),
        SensitivityLayer("sky_region", "bsdf_albedo", np.ones((HEIGHT, WIDTH)), {"buffer": "b"}),
    ]
    path = tmp_path / "names.exr"
    write_layered_exr(path, beauty=None, cryptomattes=[], layers=layers, attributes={})
    spec, channels, attributes = oiio_read(path)
    names = layer_names(layers)
    assert sorted(channels) == sorted(f"{name}.Y" for name in names)
    originals = {attributes[f"sensaov/{layer_key(name)}/original_name"]: name for name in names}
    assert originals == {"sky region.bsdf.albedo": names[0], "sky_region.bsdf_albedo": names[1]}
    assert attributes[f"sensaov/{layer_key(names[1])}/buffer"] == "b"


def _refused(tmp_path: Path, layer: SensitivityLayer, message: str) -> None:
    """Writing ``layer`` alone raises ``message`` and leaves nothing on disk."""
    with pytest.raises(ValueError, match=message):
        write_layered_exr(
            tmp_path / "refused.exr",
            beauty=None,
            cryptomattes=[],
            layers=[layer],
            attributes={},
        )
    assert list(tmp_path.iterdir()) == []


def test_nan_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    data = np.zeros((HEIGHT, WIDTH))
    data[3, 4] = np.nan
    _refused(tmp_path, SensitivityLayer("m", "p", data), "NaN")


@pytest.mark.parametrize("bits", [0x7C00, 0xFC00, 0x7E00, 0xFFFF])  # +inf, -inf, NaNs
def test_a_half_display_layer_with_nan_or_inf_is_refused(tmp_path: Path, bits: int) -> None:
    """Half layers are checked by their exponent bits (a faster path than isfinite): every
    NaN and infinity is still found, and no finite half is taken for one."""
    every_half = np.arange(65536, dtype=np.uint16).view(np.float16)
    assert exr_layout._non_finite(every_half) == np.count_nonzero(~np.isfinite(every_half))
    colours = np.zeros((HEIGHT, WIDTH, 3), np.float16)
    colours.view(np.uint16)[2, 3, 1] = bits
    layer = SensitivityLayer("m", "p_display", colours, kind="display")
    _refused(tmp_path, layer, "1 of .* NaN or infinite")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"layers": [_layer("m", "p"), _layer("m", "p")]}, "both named"),
        ({"layers": [SensitivityLayer("m", "p", np.full((HEIGHT, WIDTH), 1e300))]}, "infinite"),
    ],
)
def test_bad_input_is_refused(tmp_path: Path, change: dict[str, Any], message: str) -> None:
    arguments: dict[str, Any] = {"beauty": None, "cryptomattes": [], "layers": [], "attributes": {}}
    arguments |= {"beauty": np.zeros((HEIGHT, WIDTH, 3))} | change
    with pytest.raises(ValueError, match=message):
        write_layered_exr(tmp_path / "bad.exr", **arguments)
    assert list(tmp_path.iterdir()) == []


def test_failed_write_leaves_nothing_and_keeps_the_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import OpenEXR

    class Failing:
        def __init__(self, *args: object) -> None:
            pass

        def __enter__(self) -> Failing:
            return self

        def __exit__(self, *args: object) -> None:
            pass

        def write(self, name: str) -> None:
            Path(name).write_bytes(b"v/1\x01half a file")
            raise OSError("disk full")

    path = tmp_path / "camera.exr"
    path.write_bytes(b"the previous frame")
    monkeypatch.setattr(OpenEXR, "File", Failing)
    with pytest.raises(OSError, match="disk full"):
        write_synthetic(path)
    assert list(tmp_path.iterdir()) == [path]
    assert path.read_bytes() == b"the previous frame"


def test_format_name_and_version_match_the_documentation() -> None:
    docs = (Path(__file__).resolve().parents[1] / "docs" / "exr-layout.md").read_text(
        encoding="utf-8"
    )
    assert f"`{exr_layout.FORMAT_NAME}`" in docs
    assert f"version {exr_layout.FORMAT_VERSION}" in docs


def test_exr_bytes_do_not_depend_on_how_many_cores_compress_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """OpenEXR compresses on every core the process may use; the file is the same
    byte for byte as one compressed on a single core."""
    import os

    import OpenEXR

    from sensaov_cli.outputs.exr import write_exr

    rng = np.random.default_rng(7)
    channels = {
        f"L{k}.{c}": rng.random((70, 90)).astype(np.float32) for k in range(4) for c in "RGB"
    }
    written = {}
    for cores in (1, 2):
        monkeypatch.setattr(os, "sched_getaffinity", lambda _pid, n=cores: set(range(n)))
        write_exr(tmp_path / f"{cores}.exr", channels, {"note": "threads"})
        assert OpenEXR.global_thread_count() == cores
        written[cores] = (tmp_path / f"{cores}.exr").read_bytes()
    assert written[1] == written[2]
