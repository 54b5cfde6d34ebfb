"""PNG previews of sensitivity channels, for people who would rather look than read, and the
PNG files they go to: encoded by Pillow in memory, written atomically, read back.

Values are drawn on ColorBrewer's RdBu: blue where increasing the parameters lowers the
objective, red where it raises it, near-white at zero, saturating at ±scale. The scale is an
argument, so one channel seen from several cameras shares one (Fig. 6). Text is drawn with
OpenImageIO's ``render_text`` in the DroidSans font its wheel ships. The data live in the EXRs.

OpenImageIO's PNG writer reports success on a full disk and leaves a cut-off file; Python's
``write`` raises ``OSError`` for every failure. Text chunks (``tEXt``, Latin-1) trace a preview
back to its data. Pillow's encoder holds the GIL, so previews are written one after the other.
"""

from __future__ import annotations

import functools
import io
import math
import struct
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin

from sensaov_cli.errors import NonFiniteError, PreviewError
from sensaov_cli.outputs.atomic import atomic_write_bytes
from sensaov_cli.views.coverage import run_starts

# ColorBrewer RdBu, 11 classes (Brewer 2002), from -scale (blue) to +scale (red); symmetric in
# lightness, so |value| reads as darkness whatever the sign.
_RDBU_HEX = "053061 2166ac 4393c3 92c5de d1e5f0 f7f7f7 fddbc7 f4a582 d6604d b2182b 67001f"
RDBU = np.array([list(bytes.fromhex(code)) for code in _RDBU_HEX.split()], dtype=np.uint8)

FONT = "DroidSans"
FONT_SIZE = 14
BACKGROUND = (38, 38, 38)  # dark grey: near-white zero sensitivity stays visible against it
# Unresolved values (a sign within its 95 % interval, or heavy-tailed batches): a mid grey,
# neither red nor blue, apart from both the map's near-white zero and the dark background.
NEUTRAL = (150, 150, 150)
TEXT_COLOUR = (230, 230, 230)
PAD = 8  # between and around tiles
LABEL_HEIGHT = 20  # one line of text at FONT_SIZE
BASELINE = 15  # from the top of a text line to its baseline
BAR_HEIGHT = 12
MIN_WIDTH = 256  # room for the legend's numbers under even a single small tile
LEGEND_HEIGHT = LABEL_HEIGHT + BAR_HEIGHT + LABEL_HEIGHT + PAD  # title, bar, numbers, margin
MAX_NOTES = 10  # lines of text under a legend: the scale's rule, what it clips, what is left out


def diverging_rgb(values: np.ndarray, scale: float) -> np.ndarray:
    """``values`` (any shape) as uint8 RGB (shape + (3,)) on RdBu, saturating at ±``scale``,
    interpolated in sRGB as ColorBrewer's maps are meant to be. A scale of 0 draws zero at the
    centre and anything else at the ends."""
    return np.rint(_diverging_srgb(values, scale)).astype(np.uint8)


def diverging_linear(values: np.ndarray, scale: float) -> np.ndarray:
    """``values`` as float32 linear Rec. 709 RGB (shape + (3,)): the 8-bit colours of
    :func:`diverging_rgb` decoded from sRGB, so an sRGB display shows exactly the previews'
    colours. Decoded from the rounded codes, they keep those codes when stored as half."""
    return np.moveaxis(diverging_linear_planes(values, scale), 0, -1)


def diverging_linear_planes(
    values: np.ndarray, scale: float, dtype: type[np.floating] = np.float32
) -> np.ndarray:
    """:func:`diverging_linear` as three contiguous planes, (3,) + shape, in ``dtype`` (the
    float32 colours rounded once), each ready for an EXR channel without a strided copy."""
    x = np.asarray(values)
    # A painted layer is runs of equal pixels (an object's inside): colours once per run.
    flat = x.reshape(-1)
    starts = run_starts(flat)
    lengths = np.diff(starts, append=flat.size)
    srgb = np.rint(_diverging_srgb(flat[starts], scale)) / 255.0
    # decoded by the inverse of the sRGB transfer curve (IEC 61966-2-1)
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    colours = linear.astype(np.float32).astype(dtype)
    planes = np.empty((3, x.size), dtype)
    for channel in range(3):
        planes[channel] = np.repeat(colours[:, channel], lengths)
    return planes.reshape(3, *x.shape)


def _diverging_srgb(values: np.ndarray, scale: float) -> np.ndarray:
    """The RdBu colours of ``values`` in sRGB code values 0-255, float64, not rounded."""
    if not (math.isfinite(scale) and scale >= 0):
        raise ValueError(f"scale must be finite and non-negative, got {scale}")
    x = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise NonFiniteError("values to draw are NaN or infinite", hint="encode finite values")
    t = np.clip(x / scale, -1.0, 1.0) if scale > 0 else np.sign(x)
    position = (t + 1.0) * 0.5 * (len(RDBU) - 1)
    low = np.minimum(np.floor(position).astype(np.intp), len(RDBU) - 2)
    frac = (position - low)[..., None]
    table = RDBU.astype(np.float64)
    return table[low] * (1.0 - frac) + table[low + 1] * frac


def hatch(rgb_uint8: np.ndarray, mask: np.ndarray, period: int = 8, width: int = 2) -> np.ndarray:
    """``rgb_uint8`` with dark diagonal stripes over ``mask`` (untrusted gradients)."""
    rows, columns = np.indices(rgb_uint8.shape[:2])
    stripe = ((rows + columns) % period < width) & np.asarray(mask, bool)
    out = rgb_uint8.copy()
    out[stripe] = (out[stripe] * 0.35).astype(np.uint8)
    return out


def neutral_linear() -> np.ndarray:
    """:data:`NEUTRAL` as (3,) float32 linear Rec. 709, as the EXR's display layers store it."""
    srgb = np.array(NEUTRAL, np.float64) / 255.0
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    return linear.astype(np.float32)


def neutral(rgb_uint8: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``rgb_uint8`` drawn :data:`NEUTRAL` over ``mask``: values whose sign is not resolved."""
    out = rgb_uint8.copy()
    out[np.asarray(mask, bool)] = NEUTRAL
    return out


def underlay(
    rgb_uint8: np.ndarray,
    beauty_linear: np.ndarray,
    coverage_or_alpha: np.ndarray,
    strength: float = 0.25,
) -> np.ndarray:
    """A preview with the beauty pass beneath it, so a viewer can tell what is where.

    Where nothing is hit the beauty shows, dimmed to ``strength``; where objects are hit their
    colour is darkened by up to ``strength`` with the beauty's luminance: shading, never hue,
    since hue carries the sign. Non-finite beauty pixels show black.
    """
    beauty = np.asarray(beauty_linear, dtype=np.float64)
    coverage = np.asarray(coverage_or_alpha, dtype=np.float64)
    linear = np.clip(np.nan_to_num(beauty[..., :3], nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    luminance = _srgb(linear @ np.array([0.2126, 0.7152, 0.0722]))[..., None]
    hit = rgb_uint8 / 255.0 * (1.0 - strength + strength * luminance)
    miss = strength * _srgb(linear)
    c = np.clip(np.nan_to_num(coverage), 0.0, 1.0)[..., None]
    return np.rint((c * hit + (1.0 - c) * miss) * 255.0).astype(np.uint8)


@dataclass(frozen=True)
class _Layout:
    """Where everything of a contact sheet goes, in pixels."""

    width: int
    height: int
    columns: int
    cell: tuple[int, int]  # (height, width) of the largest tile
    legend_top: int

    def cell_origin(self, index: int) -> tuple[int, int]:
        """(top, left) of tile ``index``'s label line; the tile itself starts below it."""
        row, column = divmod(index, self.columns)
        cell_height, cell_width = self.cell
        top = PAD + row * (LABEL_HEIGHT + cell_height + PAD)
        grid_width = self.columns * (cell_width + PAD) + PAD
        left = (self.width - grid_width) // 2 + PAD + column * (cell_width + PAD)
        return top, left


def _layout(shapes: Sequence[tuple[int, ...]], columns: int, notes: int) -> _Layout:
    columns = min(columns, len(shapes))
    rows = math.ceil(len(shapes) / columns)
    cell = (max(s[0] for s in shapes), max(s[1] for s in shapes))
    grid_height = PAD + rows * (LABEL_HEIGHT + cell[0] + PAD)
    width = max(PAD + columns * (cell[1] + PAD), MIN_WIDTH)
    height = grid_height + LEGEND_HEIGHT + notes * LABEL_HEIGHT
    return _Layout(width, height, columns, cell, grid_height)


def contact_sheet(
    tiles: Sequence[tuple[str, np.ndarray]],
    columns: int,
    *,
    scale: float,
    title: str = "",
    notes: Sequence[str] = (),
) -> np.ndarray:
    """The ``tiles`` (label, uint8 RGB) on a grid ``columns`` wide, each under its label, above
    a colour bar marked -``scale``, 0 and +``scale`` with ``title`` over it and up to MAX_NOTES
    lines of ``notes`` under it. Tiles are centred in cells of the largest; long labels are cut
    short in the middle with "...".
    """
    if not tiles:
        raise ValueError("a contact sheet needs at least one tile")
    if isinstance(columns, bool) or not isinstance(columns, int) or columns < 1:
        raise ValueError(f"columns must be a positive integer, got {columns!r}")
    for _, rgb in tiles:
        check_rgb(rgb)
    width = _layout([rgb.shape for _, rgb in tiles], columns, 0).width - 2 * PAD
    notes = [line for note in notes for line in _wrap(note, width)][:MAX_NOTES]
    layout = _layout([rgb.shape for _, rgb in tiles], columns, len(notes))
    sheet = np.full((layout.height, layout.width, 3), BACKGROUND, dtype=np.uint8)
    texts: list[tuple[int, int, str, str]] = []
    cell_height, cell_width = layout.cell
    for index, (label, rgb) in enumerate(tiles):
        top, left = layout.cell_origin(index)
        y = top + LABEL_HEIGHT + (cell_height - rgb.shape[0]) // 2
        x = left + (cell_width - rgb.shape[1]) // 2
        sheet[y : y + rgb.shape[0], x : x + rgb.shape[1]] = rgb
        texts.append((left + cell_width // 2, top, _fit(label, cell_width), "center"))
    texts += _legend(sheet, layout, scale, title)
    notes_top = layout.legend_top + LABEL_HEIGHT + BAR_HEIGHT + LABEL_HEIGHT
    texts += [
        (PAD, notes_top + i * LABEL_HEIGHT, _fit(note, layout.width - 2 * PAD), "left")
        for i, note in enumerate(notes)
    ]
    _draw_text(sheet, texts)
    return sheet


def _legend(
    sheet: np.ndarray, layout: _Layout, scale: float, title: str
) -> list[tuple[int, int, str, str]]:
    """Paint the colour bar into ``sheet``; return the legend's text lines."""
    left, right = PAD, layout.width - PAD
    bar_top = layout.legend_top + LABEL_HEIGHT
    ramp = diverging_rgb(np.linspace(-1.0, 1.0, right - left), 1.0)
    sheet[bar_top : bar_top + BAR_HEIGHT, left:right] = ramp[None, :, :]
    numbers_top = bar_top + BAR_HEIGHT
    middle = layout.width // 2
    return [
        (middle, layout.legend_top, _fit(title, right - left), "center"),
        (left, numbers_top, f"{-scale:.3g}" if scale else "-", "left"),
        (middle, numbers_top, "0", "center"),
        (right, numbers_top, f"+{scale:.3g}" if scale else "+", "right"),
    ]


def _wrap(text: str, width: int) -> list[str]:
    lines: list[str] = []
    for word in text.split(" "):
        candidate = f"{lines[-1]} {word}" if lines else word
        if lines and _text_width(candidate) <= width:
            lines[-1] = candidate
        else:
            lines.append(word)
    return [_fit(line, width) for line in lines]


def _fit(text: str, width: int) -> str:
    """``text``, cut short in the middle with "..." if wider than ``width`` pixels: the end of
    a label (its ± scale, a mark) tells tiles apart."""

    def cut(keep: int) -> str:
        head = keep - keep // 2
        return text[:head] + "..." + text[len(text) - keep // 2 :]

    if _text_width(text) <= width:
        return text
    keep = len(text) - 1
    while keep > 0 and _text_width(cut(keep)) > width:
        keep -= 1
    return cut(keep) if keep else ""


@functools.lru_cache(maxsize=4096)
def _text_width(text: str) -> int:
    """``text``'s width in pixels at FONT_SIZE (cached: sheets measure the same words often)."""
    from OpenImageIO import ImageBufAlgo

    return int(ImageBufAlgo.text_size(text, FONT_SIZE, FONT).width)


def _draw_text(canvas: np.ndarray, texts: Sequence[tuple[int, int, str, str]]) -> None:
    """Draw (x, top, text, alignment) lines onto ``canvas`` in TEXT_COLOUR, antialiased."""
    height, width = canvas.shape[:2]
    alpha = np.zeros((height, width), np.float32)
    for x, top, text, align in texts:
        if not text:
            continue
        glyphs, down, right = _glyphs(text, align)
        top, left = top + down, x + right
        band = slice(max(top, 0), min(top + glyphs.shape[0], height))
        span = slice(max(left, 0), min(left + glyphs.shape[1], width))
        if band.start >= band.stop or span.start >= span.stop:
            continue  # wholly off the canvas
        cover = glyphs[band.start - top : band.stop - top, span.start - left : span.stop - left]
        under = alpha[band, span]
        under[...] = cover + (1.0 - cover) * under  # "over", as render_text composites
    # Blended only where a glyph covers the pixel: elsewhere the blend gives the canvas back.
    np.clip(alpha, 0.0, 1.0, out=alpha)
    rows, columns = np.nonzero(alpha)
    covered = alpha[rows, columns][:, None]
    blended = canvas[rows, columns] * (1.0 - covered) + np.array(TEXT_COLOUR) * covered
    canvas[rows, columns] = np.rint(blended).astype(np.uint8)


@functools.lru_cache(maxsize=512)
def _glyphs(text: str, align: str) -> tuple[np.ndarray, int, int]:
    """``text`` rasterised once: its coverage (h, w) float32, cropped to the glyphs, and the
    offset (down, right) of its top-left pixel from the (top, x) the line is drawn at.
    OpenImageIO renders a line the same at every whole-pixel anchor (tested).
    """
    from OpenImageIO import ImageBuf, ImageBufAlgo, ImageSpec

    margin = 2 * FONT_SIZE  # room for overhanging glyphs on every side
    extent = max(_text_width(text), 0)
    anchor_x = margin + {"left": 0, "center": extent // 2, "right": extent}.get(align, 0)
    anchor_y = margin + BASELINE
    line = ImageBuf(ImageSpec(extent + 2 * margin, BASELINE + 2 * margin, 1, "float"))
    if not ImageBufAlgo.render_text(
        line, anchor_x, anchor_y, text, FONT_SIZE, FONT, (1.0,), alignx=align
    ):
        hint = f"the {FONT} font ships with the PyPI wheel: pip install OpenImageIO"
        raise PreviewError(f"cannot draw text: {line.geterror()}", hint=hint)
    pixels = line.get_pixels()
    if pixels is None:
        raise PreviewError(f"cannot read back drawn text: {line.geterror()}")
    coverage = np.asarray(pixels, np.float32).reshape(line.spec().height, line.spec().width)
    rows, columns = np.flatnonzero(coverage.any(axis=1)), np.flatnonzero(coverage.any(axis=0))
    if not rows.size:
        return np.zeros((0, 0), np.float32), 0, 0
    crop = coverage[rows[0] : rows[-1] + 1, columns[0] : columns[-1] + 1]
    crop.setflags(write=False)  # shared by every later line with this text
    return crop, int(rows[0]) - margin, int(columns[0]) - anchor_x


def srgb_uint8(linear: np.ndarray) -> np.ndarray:
    """A linear (H, W, 3) image as uint8 sRGB: clipped to [0, 1], non-finite pixels black."""
    clean = np.nan_to_num(np.asarray(linear, dtype=np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    return np.rint(_srgb(np.clip(clean, 0.0, 1.0)) * 255.0).astype(np.uint8)


def _srgb(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) of values in [0, 1]."""
    return np.where(
        linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1.0 / 2.4) - 0.055
    )


_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_MAX_KEYWORD = 79  # bytes, by the PNG specification
# A header declaring more pixels than Pillow decodes (the warning: made an error below).
_TOO_LARGE = (Image.DecompressionBombError, Image.DecompressionBombWarning)
LEVEL = 3  # zlib's level for files: nearly as small as the default 6, far faster


def encode_png(
    rgb_uint8: np.ndarray, text: Mapping[str, str] | None = None, level: int = LEVEL
) -> bytes:
    """An (H, W, 3) uint8 image as PNG bytes (8-bit RGB, no interlace), with ``text`` as
    ``tEXt`` chunks (what Latin-1 cannot hold becomes ``?``); ``level`` is zlib's."""
    check_rgb(rgb_uint8)
    info = PngImagePlugin.PngInfo()
    for key, value in (text or {}).items():
        keyword = key.encode("latin-1", "replace")[:_MAX_KEYWORD]
        info.add_text(keyword, value.encode("latin-1", "replace"))  # bytes: always tEXt
    out = io.BytesIO()
    Image.fromarray(rgb_uint8).save(out, "PNG", pnginfo=info, compress_level=level)
    return out.getvalue()


def write_png(path: Path, rgb_uint8: np.ndarray, text: Mapping[str, str] | None = None) -> None:
    atomic_write_bytes(Path(path), encode_png(rgb_uint8, text))


def check_rgb(rgb: np.ndarray) -> None:
    """Refuse anything but an (H, W, 3) uint8 image: Pillow would write another kind of PNG
    (grey, RGBA, 16-bit) without a word."""
    if rgb.dtype != np.uint8:
        raise ValueError(f"expected a uint8 image, got {rgb.dtype}")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {rgb.shape}")


def png_problem(data: bytes) -> str | None:
    """Why ``data`` is not a whole PNG a browser shows as written (None: it is): every chunk's
    checksum through IEND, and pixels that decode to the size the header declares. A header
    declaring more pixels than Pillow's decompression-bomb limit is refused before decoding."""
    if not data:
        return "an empty file"
    if not data.startswith(_SIGNATURE):
        return "not a PNG file"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data), formats=["PNG"]) as image:
                image.verify()
            with Image.open(io.BytesIO(data), formats=["PNG"]) as image:
                image.load()
    except Image.UnidentifiedImageError:  # its message names the stream, not the cause
        return "a PNG whose header chunks are damaged"
    # Pillow says a file is damaged with OSError (cut short), SyntaxError (a checksum),
    # struct.error (a chunk cut short) or ValueError.
    except (OSError, SyntaxError, struct.error, ValueError, *_TOO_LARGE) as error:
        return f"not a whole PNG ({' '.join(str(error).split())[:120]})"
    return None


def read_png_text(path: Path) -> dict[str, str]:
    """The text chunks of a PNG file before its pixels (where sensaov writes its text), without
    decoding the pixels. Raises ``OSError`` or ``ValueError`` for a damaged file."""
    with Image.open(path, formats=["PNG"]) as image:
        info = image.info.items()  # text as str; the rest (gamma, dpi, ...) as other types
        return {
            key: value for key, value in info if isinstance(key, str) and isinstance(value, str)
        }
