#!/usr/bin/env python3
"""Regenerate the small 8-bit PNG textures used by the test scenes.

Deterministic (no randomness): running it again produces byte-identical
pixel data. Usage (from anywhere):

    export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1
    python scenes/make_textures.py

Writes
    scenes/cbox/textures/wall.png         32x32 RGB checker (left wall of cbox)
    scenes/interior/textures/picture.png  32x32 RGB "landscape" (picture on the wall)
"""

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def checker(size=32, cell=8, a=(200, 40, 35), b=(235, 215, 190)):
    """size x size checker of `cell`-pixel squares, colours a/b (8-bit sRGB)."""
    ij = np.indices((size, size)) // cell
    mask = ((ij[0] + ij[1]) % 2).astype(bool)
    img = np.empty((size, size, 3), np.uint8)
    img[~mask] = a
    img[mask] = b
    return img


def landscape(size=32):
    """A tiny picture: sky gradient, a sun disc, green hills below a horizon."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64) / (size - 1)  # row 0 = top
    sky_top = np.array([40, 90, 200], np.float64)
    sky_bot = np.array([250, 170, 90], np.float64)
    img = sky_top * (1 - y[..., None]) + sky_bot * y[..., None]
    sun = (x - 0.7) ** 2 + (y - 0.35) ** 2 < 0.12**2
    img[sun] = (255, 230, 120)
    horizon = 0.62 + 0.08 * np.sin(2 * np.pi * x * 1.5)
    hills = y > horizon
    img[hills] = np.array([40, 120, 50], np.float64) * (0.7 + 0.3 * (1 - y[hills]))[:, None]
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def write_png(path: Path, img: np.ndarray) -> None:
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        import mitsuba as mi

        mi.set_variant("scalar_rgb")
        mi.Bitmap(np.ascontiguousarray(img)).write(str(path))
    except ImportError:  # plain-zlib fallback, no dependencies beyond numpy
        import struct
        import zlib

        h, w, _ = img.shape
        raw = b"".join(b"\x00" + img[r].tobytes() for r in range(h))

        def chunk(tag, data):
            c = tag + data
            return struct.pack(">I", len(data)) + c + struct.pack(">I", zlib.crc32(c) & 0xFFFFFFFF)

        png = (
            b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 9))
            + chunk(b"IEND", b"")
        )
        path.write_bytes(png)
    print(f"wrote {path.relative_to(HERE.parent)} {img.shape[1]}x{img.shape[0]} uint8")


def main():
    write_png(HERE / "cbox" / "textures" / "wall.png", checker())
    write_png(HERE / "interior" / "textures" / "picture.png", landscape())


if __name__ == "__main__":
    main()
