"""Open a sensaov EXR in Blender's compositor and check what an artist would get from it.

Run headless, not under pytest (CI needs no Blender); ``scripts/blender-check.sh`` wraps it:

    blender -b --factory-startup --python-exit-code 1 \\
        --python scripts/blender_check.py -- out/cbox/camera.exr "bunny" [--out DIR]

It lists the layers and passes Blender builds from the file, checks that every sensitivity
channel ``layer.pass.C`` shows up as pass ``pass`` of layer ``layer``, keys OBJECT_NAME with a
Cryptomatte node (source Image), renders that matte to ``DIR/matte.png`` and compares it with
the object's coverage decoded here from the file itself (a small pure-Python EXR reader, since
Blender's Python has no numpy or OpenEXR). It also renders every display layer
(``<objective>.<pass>_display``) straight into the composite with no grade, under Blender's
default view transform and under Standard, and checks that an artist sees it (and sees the
previews' colours). Prints PASS/FAIL lines and a summary; exits 1 on any failure, 2 on bad
arguments.
"""

from __future__ import annotations

import argparse
import ast
import itertools
import json
import operator
import struct
import sys
import tempfile
import zlib
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import bpy

MATTE_TOLERANCE = 2.0 / 65535.0  # one 16-bit PNG step, plus rounding
_MAGIC = b"\x76\x2f\x31\x01"
_LINES_PER_BLOCK = {0: 1, 2: 1, 3: 16}  # NONE, ZIPS, ZIP: all sensaov writes
_PIXEL_BYTES = {1: 2, 2: 4}  # HALF, FLOAT


# --- a minimal scanline EXR reader (NONE / ZIPS / ZIP, HALF / FLOAT) ------------------------


@dataclass
class Header:
    strings: dict[str, str] = field(default_factory=dict)
    channels: list[tuple[str, int]] = field(default_factory=list)  # (name, pixel type)
    data_window: tuple[int, int, int, int] = (0, 0, -1, -1)  # x0, y0, x1, y1 (inclusive)
    compression: int = -1


def read_exr(path: Path) -> tuple[dict[str, list[float]], Header, int, int]:
    """Channels (name -> row-major floats, top row first), header, width and height."""
    data = path.read_bytes()
    if data[:4] != _MAGIC or data[5] & 0x1A:  # tiled, deep or multipart: not for this reader
        raise ValueError(f"{path}: not a single-part scanline EXR")
    header, position = _read_header(data, 8)
    x0, y0, x1, y1 = header.data_window
    width, height = x1 - x0 + 1, y1 - y0 + 1
    if header.compression not in _LINES_PER_BLOCK:
        raise ValueError(f"{path}: compression {header.compression} is not NONE, ZIPS or ZIP")
    lines = _LINES_PER_BLOCK[header.compression]
    chunks = (height + lines - 1) // lines
    offsets = struct.unpack_from(f"<{chunks}Q", data, position)
    line_bytes = width * sum(_PIXEL_BYTES[kind] for _, kind in header.channels)
    raw = bytearray()
    for offset in offsets:
        y, size = struct.unpack_from("<ii", data, offset)
        block = data[offset + 8 : offset + 8 + size]
        stored = min(lines, y0 + height - y) * line_bytes
        raw += block if size == stored else _unzip(block)  # ZIP stores a block raw if no gain
    return _split_channels(bytes(raw), header.channels, width, height), header, width, height


def _read_header(data: bytes, position: int) -> tuple[Header, int]:
    header = Header()
    while data[position] != 0:
        name, position = _cstring(data, position)
        kind, position = _cstring(data, position)
        (size,) = struct.unpack_from("<i", data, position)
        value = data[position + 4 : position + 4 + size]
        position += 4 + size
        if kind == "string":
            header.strings[name] = value.decode("utf-8")
        elif kind == "chlist":
            header.channels = _channel_list(value)
        elif name == "dataWindow":
            header.data_window = struct.unpack("<4i", value)
        elif kind == "compression":
            header.compression = value[0]
    return header, position + 1


def _cstring(data: bytes, position: int) -> tuple[str, int]:
    end = data.index(b"\0", position)
    return data[position:end].decode("utf-8"), end + 1


def _channel_list(value: bytes) -> list[tuple[str, int]]:
    channels: list[tuple[str, int]] = []
    position = 0
    while value[position] != 0:
        name, position = _cstring(value, position)
        (pixel_type,) = struct.unpack_from("<i", value, position)
        channels.append((name, pixel_type))
        position += 16  # type, pLinear + 3 reserved, xSampling, ySampling
    return channels


def _unzip(block: bytes) -> bytes:
    packed = zlib.decompress(block)
    # Undo the predictor (each byte stored as a difference + 128) with C-level iterators.
    deltas = map(operator.sub, packed, itertools.repeat(128))
    running = itertools.islice(itertools.accumulate(deltas, initial=128), 1, None)
    predicted = bytes(map(operator.and_, running, itertools.repeat(0xFF)))
    # Undo the split of even and odd bytes into two halves.
    out = bytearray(len(predicted))
    half = (len(predicted) + 1) // 2
    out[0::2], out[1::2] = predicted[:half], predicted[half:]
    return bytes(out)


def _split_channels(
    raw: bytes, channels: list[tuple[str, int]], width: int, height: int
) -> dict[str, list[float]]:
    result: dict[str, list[float]] = {name: [] for name, _ in channels}
    position = 0
    for _ in range(height):
        for name, kind in channels:
            size = width * _PIXEL_BYTES[kind]
            chunk = raw[position : position + size]
            values = array("f", chunk) if kind == 2 else struct.unpack(f"<{width}e", chunk)
            result[name].extend(values)
            position += size
    return result


# --- what the file promises ------------------------------------------------------------------


def object_coverage(
    channels: dict[str, list[float]], header: Header, object_name: str
) -> tuple[str, list[float]]:
    """The Cryptomatte type holding ``object_name`` and its per-pixel coverage (all ranks)."""
    for key, value in crypto_types(header).items():
        manifest = json.loads(header.strings.get(f"{key}/manifest", "{}"))
        if object_name not in manifest:
            continue
        wanted = int(manifest[object_name], 16)
        total = [0.0] * len(next(iter(channels.values())))
        layer = 0
        while f"{value}{layer:02d}.R" in channels:
            for id_name, cov_name in (("R", "G"), ("B", "A")):
                ids = channels[f"{value}{layer:02d}.{id_name}"]
                covs = channels[f"{value}{layer:02d}.{cov_name}"]
                for pixel, (id_value, cov) in enumerate(zip(ids, covs, strict=True)):
                    if struct.unpack("<I", struct.pack("<f", id_value))[0] == wanted:
                        total[pixel] += cov
            layer += 1
        return value, total
    raise SystemExit(f"FAIL: {object_name!r} is in no Cryptomatte manifest of the file")


def crypto_types(header: Header) -> dict[str, str]:
    """``cryptomatte/<key>`` -> type name, from the header."""
    return {
        key[: -len("/name")]: value
        for key, value in header.strings.items()
        if key.startswith("cryptomatte/") and key.endswith("/name")
    }


def expected_passes(channel_names: list[str]) -> dict[tuple[str, str], list[str]]:
    """(layer, pass) -> channels, split the way Blender splits: last token channel, then pass."""
    passes: dict[tuple[str, str], list[str]] = {}
    for name in channel_names:
        tokens = name.split(".")
        if len(tokens) >= 3:
            passes.setdefault((".".join(tokens[:-2]), tokens[-2]), []).append(tokens[-1])
    return {key: sorted(chans, key="RGBAXYZ".find) for key, chans in passes.items()}


# --- what Blender sees -----------------------------------------------------------------------


def blender_passes(tree: bpy.types.NodeTree, image: bpy.types.Image) -> dict[str, list[str]]:
    """Layer -> 'pass (socket type)' for every layer the Image node offers."""
    node = tree.nodes.new("CompositorNodeImage")
    node.image = image
    seen = {"": _outputs(node)}  # the unnamed layer is current first and not in the enum
    for layer in _enum_choices(node, "layer"):
        node.layer = layer
        seen[layer] = _outputs(node)
    tree.nodes.remove(node)
    return seen


def _outputs(node: bpy.types.Node) -> list[str]:
    return [f"{socket.name} ({socket.type})" for socket in node.outputs if socket.enabled]


def _enum_choices(node: bpy.types.Node, prop: str) -> list[str]:
    """Items of a dynamic enum: RNA lists them only in the error for an invalid value."""
    try:
        setattr(node, prop, "\x01 not a choice")
    except TypeError as error:
        text = str(error)
        choices = ast.literal_eval(text[text.index(" not found in ") + 14 :])
        return [choices] if isinstance(choices, str) else list(choices)  # ('one') is a str
    return []


def render_matte(
    image: bpy.types.Image, type_name: str, object_name: str, size: tuple[int, int], out: Path
) -> list[float]:
    """Key ``object_name`` with a Cryptomatte node; render the composite; top row first."""
    scene = bpy.context.scene
    tree = scene.node_tree
    crypto = tree.nodes.new("CompositorNodeCryptomatteV2")
    crypto.source = "IMAGE"
    crypto.image = image
    choices = _enum_choices(crypto, "layer_name")
    if type_name not in choices:
        raise SystemExit(f"FAIL: Blender offers Cryptomatte layers {choices}, not {type_name!r}")
    crypto.layer_name = type_name
    crypto.matte_id = object_name
    composite = tree.nodes.new("CompositorNodeComposite")
    tree.links.new(crypto.outputs["Matte"], composite.inputs["Image"])
    width, height = size  # a multilayer Image reports size (0, 0)
    render = scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = width, height, 100
    render.image_settings.file_format = "PNG"
    render.image_settings.color_mode = "BW"
    render.image_settings.color_depth = "16"
    render.dither_intensity = 0.0
    scene.view_settings.view_transform = "Raw"
    scene.view_settings.look = "None"
    render.filepath = str(out)
    bpy.ops.render.render(write_still=True)
    png = bpy.data.images.load(str(out))
    png.colorspace_settings.name = "Non-Color"
    rgba = list(png.pixels)
    rows = [rgba[4 * width * y : 4 * width * (y + 1) : 4] for y in range(height)]
    return [value for row in reversed(rows) for value in row]  # Blender stores bottom row first


def render_socket(
    image: bpy.types.Image,
    layer: str,
    socket: str,
    size: tuple[int, int],
    out: Path,
    view: str,
) -> list[tuple[float, float, float]]:
    """Render one pass of the Image node straight into the Composite, with no grade, under the
    view transform ``view``; the 8-bit PNG's RGB in [0, 1], top row first."""
    scene = bpy.context.scene
    tree = scene.node_tree
    for node in list(tree.nodes):
        tree.nodes.remove(node)
    source = tree.nodes.new("CompositorNodeImage")
    source.image = image
    source.layer = layer
    composite = tree.nodes.new("CompositorNodeComposite")
    tree.links.new(source.outputs[socket], composite.inputs["Image"])
    width, height = size
    render = scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = width, height, 100
    render.image_settings.file_format = "PNG"
    render.image_settings.color_mode = "RGB"
    render.image_settings.color_depth = "8"
    render.dither_intensity = 0.0
    scene.view_settings.view_transform = view
    scene.view_settings.look = "None"
    render.filepath = str(out)
    bpy.ops.render.render(write_still=True)
    png = bpy.data.images.load(str(out))
    png.colorspace_settings.name = "Non-Color"
    rgba = list(png.pixels)
    bpy.data.images.remove(png)
    rows = [
        [tuple(rgba[4 * (width * y + x) : 4 * (width * y + x) + 3]) for x in range(width)]
        for y in range(height)
    ]
    return [pixel for row in reversed(rows) for pixel in row]  # type: ignore[misc]


def _srgb(linear: float) -> float:
    linear = min(max(linear, 0.0), 1.0)
    return 12.92 * linear if linear <= 0.0031308 else 1.055 * linear ** (1 / 2.4) - 0.055


def check_display(
    image: bpy.types.Image,
    channels: dict[str, list[float]],
    size: tuple[int, int],
    out: Path,
    default_view: str,
) -> list[tuple[bool, str]]:
    """Every ``<objective>.<pass>_display`` layer as an artist sees it, with no grade: under the
    default view transform at least 10 % of the visible pixels (beauty alpha > 0) are above 0.1
    (its raw layer's share is printed beside it), and under Standard the viewer shows exactly
    the previews' colours (the sRGB encoding of the stored values, within 1.5/255)."""
    results = []
    visible = [k for k, a in enumerate(channels.get("A", [])) if a > 0] or list(
        range(size[0] * size[1])
    )
    displays = sorted(
        {
            n.rsplit(".", 1)[0]
            for n in channels
            if n.count(".") == 2 and n.split(".")[1].endswith("_display")
        }
    )
    for name in displays:
        layer, socket = name.rsplit(".", 1)
        raw_socket = socket.removesuffix("_display")
        shown = render_socket(image, layer, socket, size, out / "display.png", default_view)
        raw_name = next(
            (f"{layer}.{raw_socket}.{c}" for c in "YR" if f"{layer}.{raw_socket}.{c}" in channels),
            None,
        )
        raw_share = 0.0
        if raw_name is not None:
            raw = render_socket(image, layer, raw_socket, size, out / "raw.png", default_view)
            raw_share = sum(max(raw[k]) > 0.1 for k in visible) / len(visible)
        share = sum(max(shown[k]) > 0.1 for k in visible) / len(visible)
        results.append(
            (
                share >= 0.1,
                f"{name} ({default_view}, no grade): {100 * share:.1f} % of "
                f"visible pixels above 0.1 (raw {raw_socket}: {100 * raw_share:.1f} %)",
            )
        )
        standard = render_socket(image, layer, socket, size, out / "standard.png", "Standard")
        stored = [channels[f"{name}.{c}"] for c in "RGB"]
        error = max(
            abs(standard[k][c] - _srgb(stored[c][k]))
            for k in range(len(standard))
            for c in range(3)
        )
        results.append(
            (
                error <= 1.5 / 255,
                f"{name} (Standard): the previews' colours, max |diff| {255 * error:.2f}/255",
            )
        )
    results.append((bool(displays), f"{len(displays)} display layers found"))
    return results


# --- the check -------------------------------------------------------------------------------


def check(exr: Path, object_name: str, out: Path, display: bool) -> list[tuple[bool, str]]:
    channels, header, width, height = read_exr(exr)
    results: list[tuple[bool, str]] = []
    image = bpy.data.images.load(str(exr))
    scene = bpy.context.scene
    default_view = scene.view_settings.view_transform  # what an artist's viewer starts with
    scene.use_nodes = True
    for node in list(scene.node_tree.nodes):
        scene.node_tree.nodes.remove(node)
    seen = blender_passes(scene.node_tree, image)
    print("Blender sees (layer: passes):")
    for layer, passes in seen.items():
        print(f"  {layer or '(unnamed)'!s}: {', '.join(passes)}")
    results.append((image.type == "MULTILAYER", f"image type {image.type} (want MULTILAYER)"))
    for (layer, pass_name), chans in sorted(expected_passes(list(channels)).items()):
        names = [entry.split(" (")[0] for entry in seen.get(layer, [])]
        results.append((pass_name in names, f"pass {layer}.{pass_name} ({','.join(chans)})"))
    types = crypto_types(header).values()
    preview = [f"{t}.{c}" for t in types for c in "RGB" if f"{t}.{c}" in channels]
    results.append((not preview, f"no deprecated Cryptomatte preview channels {preview or ''}"))
    if display:
        results += check_display(image, channels, (width, height), out, default_view)
    type_name, coverage = object_coverage(channels, header, object_name)
    matte = render_matte(image, type_name, object_name, (width, height), out / "matte.png")
    results += compare_matte(matte, coverage, width, height, f"{type_name} {object_name!r}")
    return results


def compare_matte(
    matte: list[float], coverage: list[float], width: int, height: int, what: str
) -> list[tuple[bool, str]]:
    inside = [k for k, c in enumerate(coverage) if c > 0]
    outside = [k for k, c in enumerate(coverage) if c <= 0]
    missing = [k for k in inside if matte[k] <= 0]
    stray = [k for k in outside if matte[k] != 0]
    error = max((abs(m - c) for m, c in zip(matte, coverage, strict=True)), default=0.0)
    return [
        (bool(inside), f"{what} covers {len(inside)} of {width * height} pixels in the EXR"),
        (not missing, f"matte > 0 wherever coverage > 0 ({len(missing)} pixels missing)"),
        (not stray, f"matte = 0 wherever coverage = 0 ({len(stray)} stray pixels)"),
        (error <= MATTE_TOLERANCE, f"matte equals coverage (max |diff| {error:.2e})"),
    ]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="blender_check.py", description=__doc__.split("\n")[0])
    parser.add_argument("exr", type=Path)
    parser.add_argument("object_name")
    parser.add_argument("--out", type=Path, help="folder for matte.png (default: a temp folder)")
    parser.add_argument(
        "--no-display", action="store_true", help="skip the display layers' checks (faster)"
    )
    args = parser.parse_args(argv[argv.index("--") + 1 :] if "--" in argv else [])
    out = args.out or Path(tempfile.mkdtemp(prefix="sensaov-blender-"))
    out.mkdir(parents=True, exist_ok=True)
    results = check(args.exr, args.object_name, out, not args.no_display)
    for ok, text in results:
        print(f"{'PASS' if ok else 'FAIL'}: {text}")
    failed = sum(not ok for ok, _ in results)
    print(f"matte written to {out / 'matte.png'}")
    print(f"SUMMARY: {'FAIL' if failed else 'PASS'} ({len(results) - failed}/{len(results)} ok)")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
