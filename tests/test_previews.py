"""PNG previews: the colour map's ends and order, the underlay, the contact sheet, the writer."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.errors import NonFiniteError
from sensaov_cli.outputs.previews import (
    BACKGROUND,
    BAR_HEIGHT,
    LABEL_HEIGHT,
    LEGEND_HEIGHT,
    MIN_WIDTH,
    PAD,
    RDBU,
    contact_sheet,
    diverging_rgb,
    underlay,
    write_png,
)

BLUE, WHITE, RED = RDBU[0], RDBU[5], RDBU[-1]


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])


def test_ends_and_centre_are_the_table_stops() -> None:
    got = diverging_rgb(np.array([-2e-3, 0.0, 2e-3]), 2e-3)
    np.testing.assert_array_equal(got, [BLUE, WHITE, RED])
    np.testing.assert_array_equal(WHITE, [0xF7, 0xF7, 0xF7])
    assert BLUE[2] > BLUE[0] and RED[0] > RED[2]


def test_saturates_beyond_the_scale() -> None:
    got = diverging_rgb(np.array([-1e9, 1e9]), 1.0)
    np.testing.assert_array_equal(got, [BLUE, RED])


def test_every_stop_is_hit_exactly() -> None:
    np.testing.assert_array_equal(diverging_rgb(np.linspace(-1.0, 1.0, 11), 1.0), RDBU)


def test_lightness_grows_towards_zero_and_sign_picks_the_hue() -> None:
    stops = luminance(RDBU)
    assert np.all(np.diff(stops[:6]) > 0) and np.all(np.diff(stops[5:]) < 0)
    ramp = diverging_rgb(np.linspace(-1.0, 1.0, 1001), 1.0).astype(np.int64)
    light = luminance(ramp)
    # Between stops, channels round to 8 bits at different places: allow one red step.
    step = 0.2126
    assert np.all(np.diff(light[:501]) >= -step) and np.all(np.diff(light[500:]) <= step)
    # Within 1% of zero both are near-white and may round to equal channels.
    assert np.all(ramp[:495, 2] > ramp[:495, 0]) and np.all(ramp[:500, 2] >= ramp[:500, 0])
    assert np.all(ramp[506:, 0] > ramp[506:, 2]) and np.all(ramp[501:, 0] >= ramp[501:, 2])


def test_keeps_the_shape_and_gives_uint8() -> None:
    got = diverging_rgb(np.zeros((5, 7)), 1.0)
    assert got.shape == (5, 7, 3) and got.dtype == np.uint8


def test_scale_zero_draws_zero_white_and_anything_else_at_the_ends() -> None:
    got = diverging_rgb(np.array([-1e-30, 0.0, 1e-30]), 0.0)
    np.testing.assert_array_equal(got, [BLUE, WHITE, RED])


def test_nan_is_refused() -> None:
    with pytest.raises(NonFiniteError):
        diverging_rgb(np.array([0.0, np.nan]), 1.0)
    with pytest.raises(ValueError, match="scale"):
        diverging_rgb(np.zeros(2), np.nan)


def test_underlay_shows_dim_beauty_where_nothing_is_hit() -> None:
    colour = np.full((1, 3, 3), 200, dtype=np.uint8)
    beauty = np.array([[[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    miss = underlay(colour, beauty, np.zeros((1, 3)), strength=0.25)
    np.testing.assert_array_equal(miss[0], [[64, 64, 64], [0, 0, 0], [64, 0, 0]])


def test_underlay_shades_hit_colours_without_changing_their_hue() -> None:
    colour = np.array([[RED, BLUE]], dtype=np.uint8)
    white = underlay(colour, np.ones((1, 2, 3)), np.ones((1, 2)), strength=0.25)
    np.testing.assert_array_equal(white, colour)
    black = underlay(colour, np.zeros((1, 2, 3)), np.ones((1, 2)), strength=0.25)
    np.testing.assert_array_equal(black, np.rint(colour * 0.75).astype(np.uint8))


def test_underlay_shows_non_finite_beauty_black() -> None:
    beauty = np.array([[[np.nan, np.nan, np.nan]]])
    got = underlay(np.zeros((1, 1, 3), dtype=np.uint8), beauty, np.zeros((1, 1)))
    np.testing.assert_array_equal(got, np.zeros((1, 1, 3)))


def tile(height: int, width: int, value: int) -> np.ndarray:
    return np.full((height, width, 3), value, dtype=np.uint8)


def test_sheet_size() -> None:
    tiles = [(f"t{i}", tile(48, 128, 10 * i)) for i in range(3)]
    sheet = contact_sheet(tiles, 2, scale=1.0)
    assert sheet.dtype == np.uint8
    assert sheet.shape == (PAD + 2 * (LABEL_HEIGHT + 48 + PAD) + LEGEND_HEIGHT, 280, 3)
    assert contact_sheet(tiles[:1], 5, scale=1.0).shape[1] == MIN_WIDTH


def test_tiles_sit_under_their_labels() -> None:
    tiles = [("reflectance", tile(48, 128, 90)), ("", tile(48, 128, 140))]
    sheet = contact_sheet(tiles, 2, scale=1.0)
    top = PAD + LABEL_HEIGHT
    for column, (label, rgb) in enumerate(tiles):
        left = PAD + column * (128 + PAD)
        np.testing.assert_array_equal(sheet[top : top + 48, left : left + 128], rgb)
        strip = sheet[PAD:top, left : left + 128]
        has_text = np.any(strip != BACKGROUND)
        assert has_text == bool(label), label


def test_long_labels_stay_in_their_cell() -> None:
    sheet = contact_sheet([("a_very_long_channel_name_" * 4, tile(32, 40, 0))], 1, scale=1.0)
    cell_left = (MIN_WIDTH - (40 + 2 * PAD)) // 2 + PAD
    strip = sheet[PAD : PAD + LABEL_HEIGHT]
    assert np.any(strip[:, cell_left : cell_left + 40] != BACKGROUND)
    assert np.all(strip[:, : cell_left - 1] == BACKGROUND)
    assert np.all(strip[:, cell_left + 41 :] == BACKGROUND)


def test_smaller_tiles_are_centred_in_their_cell() -> None:
    sheet = contact_sheet([("big", tile(40, 120, 0)), ("small", tile(20, 60, 255))], 2, scale=1.0)
    top, left = PAD + LABEL_HEIGHT + 10, PAD + 120 + PAD + 30
    np.testing.assert_array_equal(sheet[top : top + 20, left : left + 60], tile(20, 60, 255))
    assert np.all(sheet[top - 1, left : left + 60] == BACKGROUND)


def test_legend_is_the_colour_map_with_its_numbers() -> None:
    sheet = contact_sheet([("x", tile(16, 16, 0))], 1, scale=2.5e-3, title="symlog")
    bar_top = sheet.shape[0] - LEGEND_HEIGHT + LABEL_HEIGHT
    bar = sheet[bar_top : bar_top + BAR_HEIGHT, PAD : MIN_WIDTH - PAD]
    assert np.all(bar == bar[:1])
    np.testing.assert_array_equal(bar[0, 0], BLUE)
    np.testing.assert_array_equal(bar[0, -1], RED)
    title = sheet[bar_top - LABEL_HEIGHT : bar_top]
    numbers = sheet[bar_top + BAR_HEIGHT : bar_top + BAR_HEIGHT + LABEL_HEIGHT]
    assert np.any(title != BACKGROUND)
    for left, right in ((0, 40), (MIN_WIDTH // 2 - 8, MIN_WIDTH // 2 + 8), (-40, None)):
        assert np.any(numbers[:, left:right] != BACKGROUND)


@pytest.mark.parametrize("columns", [0, -1, 1.5, True])
def test_sheet_refuses_bad_columns(columns: object) -> None:
    with pytest.raises(ValueError, match="columns"):
        contact_sheet([("x", tile(4, 4, 0))], columns, scale=1.0)  # type: ignore[arg-type]


def test_sheet_refuses_no_tiles_and_bad_images() -> None:
    with pytest.raises(ValueError, match="at least one"):
        contact_sheet([], 1, scale=1.0)
    with pytest.raises(ValueError, match="uint8"):
        contact_sheet([("x", np.zeros((4, 4, 3)))], 1, scale=1.0)


def test_png_is_written_readable_and_alone(tmp_path: Path) -> None:
    import OpenImageIO as oiio

    image = diverging_rgb(np.linspace(-1.0, 1.0, 6 * 8).reshape(6, 8), 1.0)
    path = tmp_path / "previews" / "cam.reflectance.png"
    write_png(path, image, {"sensaov:encoding": "weight=value;sign=signed"})
    assert os.listdir(path.parent) == [path.name]
    source = oiio.ImageInput.open(str(path))
    assert source is not None and source.format_name() == "png"
    assert source.spec().getattribute("sensaov:encoding") == "weight=value;sign=signed"
    np.testing.assert_array_equal(source.read_image("uint8"), image)
    source.close()


def test_failed_png_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "cam.png"
    path.write_bytes(b"old")
    with pytest.raises(ValueError, match="uint8"):
        write_png(path, np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        write_png(path, np.zeros((4, 4, 4), dtype=np.uint8))
    assert os.listdir(tmp_path) == ["cam.png"] and path.read_bytes() == b"old"


def test_a_contact_sheet_names_what_its_tiles_cannot_show(tmp_path: Path) -> None:
    """The per-objective sheet repeats what the single previews say a tile leaves out: objects
    with a sensitivity that this camera does not see, and a failed duality check."""
    from sensaov_cli.outputs.contact_sheets import write_previews
    from sensaov_cli.outputs.layered_exr import SensitivityLayer
    from sensaov_cli.views.channels import robust_scale

    data = np.linspace(-1, 1, 16, dtype=np.float32).reshape(4, 4)
    scale = robust_scale({"cam": [data]})
    meta = {"encoding": "linear", "unverified": "[]"}
    layers = [
        (SensitivityLayer("m", "objects", data, meta, invisible=("light", "sky")), scale),
        (SensitivityLayer("m", "types_radiance", data, meta, invisible=("light",)), scale),
        (SensitivityLayer("m", "walls", data, meta, duality_agrees=False), scale),
        (SensitivityLayer("other", "objects", data, meta), scale),
    ]

    class Visibility:
        coverage_hit = np.ones((4, 4), np.float32)

    entries = write_previews(tmp_path, "cam", layers, None, Visibility(), {})  # type: ignore[arg-type]
    sheets = {entry.objective: entry for entry in entries if entry.kind == "sheet"}
    notes = " | ".join(sheets["m"].notes)
    assert (
        "not in this view, so no tile paints them: light (objects, types_radiance); sky (objects)"
        in notes
    )
    assert "duality check FAILED, do not trust (marked !): walls" in notes
    assert not any("not in this view" in n or "FAILED" in n for n in sheets["other"].notes)
    assert sheets["m"].notes[0].startswith("duality check FAILED")  # first: never cut off
    many = tuple(f"object_{i:02d}" for i in range(20))
    crowded = [(SensitivityLayer("m", "objects", data, meta, invisible=many), scale)]
    (sheet,) = [e for e in write_previews(tmp_path, "c2", crowded, None, Visibility(), {})
                if e.kind == "sheet"]  # fmt: skip
    assert sheet.notes[-1].endswith("object_05 (objects); and 14 more")
    assert (tmp_path / "cam_m.png").is_file()


def test_text_is_blended_where_glyphs_cover_and_nowhere_else() -> None:
    """Lines are rasterised once and copied, and blended on covered pixels only: the result is
    that of render_text in place and a whole-canvas blend, byte for byte, on a canvas with a
    different colour in every pixel, for every alignment, lines cut by an edge, and lines drawn
    over one another."""
    from OpenImageIO import ImageBuf, ImageBufAlgo, ImageSpec

    from sensaov_cli.outputs.previews import BASELINE, FONT, FONT_SIZE, TEXT_COLOUR, _draw_text

    rng = np.random.default_rng(3)
    canvas = rng.integers(0, 256, (60, 180, 3), dtype=np.uint8)
    texts = [
        (90, 4, "mean_luma +1.2e-3", "center"),
        (2, 30, "left", "left"),
        (178, 30, "right, cut by the edge", "right"),
        (-20, 44, "off the left edge", "left"),
        (60, 50, "cut at the bottom", "center"),
        (30, 32, "overlaps", "left"),  # over "left" and the right-aligned line
        (90, 4, "mean_luma +1.2e-3", "center"),  # drawn twice: from the cache the second time
    ]
    drawn = canvas.copy()
    _draw_text(drawn, texts)

    mask = ImageBuf(ImageSpec(180, 60, 1, "float"))
    for x, top, text, align in texts:
        ImageBufAlgo.render_text(
            mask, x, top + BASELINE, text, FONT_SIZE, FONT, (1.0,), alignx=align
        )
    alpha = np.clip(mask.get_pixels().reshape(60, 180, 1), 0.0, 1.0)
    whole = np.rint(canvas * (1.0 - alpha) + np.array(TEXT_COLOUR) * alpha).astype(np.uint8)
    assert (alpha > 0).any() and (alpha == 0).any()
    np.testing.assert_array_equal(drawn, whole)
    assert (drawn != canvas).any(axis=2).sum() > 50  # the glyphs are there


def _preview_layers(values: list[float]) -> list[tuple[object, object]]:
    """One layer per value of ``values`` (a 4x4 ramp times it), all on one scale."""
    from sensaov_cli.outputs.layered_exr import SensitivityLayer
    from sensaov_cli.views.channels import robust_scale

    data = np.linspace(-1, 1, 16, dtype=np.float32).reshape(4, 4)
    scale = robust_scale({"cam": [data]})
    meta = {"encoding": "linear", "unverified": "[]"}
    return [
        (SensitivityLayer("m", f"pass{index}", data * value, meta), scale)
        for index, value in enumerate(values)
    ]


class _Visibility:
    coverage_hit = np.ones((4, 4), np.float32)


def test_previews_are_the_files_write_png_writes(tmp_path: Path) -> None:
    """Every preview is the PNG write_png writes of its pixels and text, byte for byte, and
    each is written as soon as it is drawn (a later picture that fails leaves it written)."""
    from PIL import Image

    from sensaov_cli.outputs.contact_sheets import write_previews
    from sensaov_cli.outputs.previews import encode_png, read_png_text

    layers = _preview_layers([1.0, -0.5, 0.25])
    entries = write_previews(tmp_path, "cam", layers, None, _Visibility(), {"sensaov/i": "x"})  # type: ignore[arg-type]
    assert len(entries) == 4  # three layers and the objective's sheet
    for entry in entries:
        path = tmp_path / entry.file
        with Image.open(path) as image:
            pixels = np.asarray(image)
        text = read_png_text(path)
        assert text["sensaov/i"] == "x" and path.read_bytes() == encode_png(pixels, text)


def test_a_picture_that_fails_writes_nothing_more(tmp_path: Path) -> None:
    from sensaov_cli.outputs.contact_sheets import write_previews

    layers = _preview_layers([1.0, 0.5, float("nan"), 0.25])
    with pytest.raises(NonFiniteError):
        write_previews(tmp_path, "cam", layers, None, _Visibility(), {})  # type: ignore[arg-type]
    assert sorted(os.listdir(tmp_path / "cam")) == ["m.pass0.png", "m.pass1.png"]
    assert not (tmp_path / "cam_m.png").exists()  # the sheet comes after every layer


def test_a_missing_font_is_a_preview_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from sensaov_cli.errors import PreviewError
    from sensaov_cli.outputs import previews

    monkeypatch.setattr(previews, "FONT", "NoSuchFont-sensaov")
    previews._glyphs.cache_clear()
    previews._text_width.cache_clear()
    try:
        with pytest.raises(PreviewError, match="cannot draw text"):
            previews._draw_text(np.zeros((20, 40, 3), np.uint8), [(0, 0, "x", "left")])
    finally:
        previews._glyphs.cache_clear()
        previews._text_width.cache_clear()
