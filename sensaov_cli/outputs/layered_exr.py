"""The multilayer EXR a compositor opens: beauty, Cryptomatte ID layers, sensitivity passes and
their display layers; and, read back from a camera's EXR, which objects that camera sees.

One file per camera: ``objective.pass.Y`` (or ``.R/.G/.B``) beside an ``R,G,B,A`` beauty and a
real Cryptomatte (``CryptoObject00..02``), so a keyer's matte can gate any pass. Compositors are
strict about names (MITSUBA-NOTES "Compositors"): every token becomes ``[A-Za-z0-9_]``, at most
63 bytes, unique, the original names kept in the metadata. Data are float32 (ZIP): half would
destroy Cryptomatte IDs and small sensitivities alike. Layout: ``docs/exr-layout.md``.

A raw layer keeps its values (often 1e-5: black in any viewer). Its display layer
``<objective>.<pass>_display.R/G/B`` holds the previews' picture of it at the group's display
scale, as half-float linear Rec. 709 whose sRGB encoding is exactly the previews' colours; black
where the camera hits nothing. :func:`layer_metadata` alone turns layers into header strings.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import mmh3
import numpy as np

from sensaov_cli.errors import CameraFileError, CryptomatteError, ExrError
from sensaov_cli.outputs.exr import read_exr, write_exr
from sensaov_cli.outputs.previews import diverging_linear, diverging_linear_planes, neutral_linear
from sensaov_cli.views.channels import ChannelValues, DisplayScale, clipped_share, signed_pixels
from sensaov_cli.vocabulary import DEFAULT_AGGREGATE

FORMAT_NAME = "sensaov-aov-exr"
# 2: display layers, display scales, trust parts, stamps; 3: resolution, and provenance once per
# file with relative paths (exr-layout.md)
FORMAT_VERSION = 3
TOKEN_BYTES = 63  # Blender keeps layer and pass names in 64-byte buffers
SUFFIX_HEX = 6
BEAUTY_CHANNELS = ("R", "G", "B", "A")
_UNSAFE = re.compile(r"[^A-Za-z0-9_]")
DISPLAY_SUFFIX = "_display"
DISPLAY_ENCODING = (
    "RdBu diverging map of the raw layer at +-display_scale (blue < 0 < red, near-white 0), "
    "linear Rec. 709 (its sRGB encoding is the previews' colours); black where nothing is hit"
)
DUALITY_FAILED = "EXCEEDS TOLERANCE: do not trust this layer"
# What a layer shows: "" a buffer channel's values, or a forward, transport, texel or display one.
LayerKind = Literal["", "forward", "transport", "texel", "display"]
# Cryptomatte (below)
HASH_NAME = "MurmurHash3_32"
CONVERSION = "uint32_to_float32"
DEFAULT_RANKS = 6
TYPE_NAME_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,60}")
_EXPONENT_SHIFT = 23
_EXPONENT_MASK = 0xFF
OBJECT_TYPE = "CryptoObject"


@dataclass(frozen=True, eq=False)
class CryptoLayer:
    """Ranked per-pixel coverage of named things for one Cryptomatte type (as
    :func:`rank_channels` takes it)."""

    type_name: str
    names: Sequence[str]
    rank_index: np.ndarray
    rank_coverage: np.ndarray
    ranks: int = DEFAULT_RANKS
    ordered: bool = False  # ranks already in order, empty last at 0 (a visibility pass's)


@dataclass(frozen=True)
class ScaleGroup:
    """The layers whose pictures share one display scale, and how a layer takes part in it."""

    name: str  # e.g. ``<objective>/<channel>``
    role: str | None = None  # REFERENCE sets the scale, FOLLOWER follows it; None: not recorded
    fixed: float | None = None  # set by what the layer means (1: an even spread), not its pixels


@dataclass(frozen=True, eq=False)
class SensitivityLayer:
    """One sensitivity pass: (H, W) data becomes channel ``Y``, (H, W, 3) becomes ``R, G, B``.

    ``metadata`` is written as it is under ``sensaov/<key>/``, the typed fields when set.
    """

    objective: str
    pass_name: str
    data: np.ndarray
    metadata: Mapping[str, str] = field(default_factory=dict)
    kind: LayerKind = ""
    group: ScaleGroup = ScaleGroup("")  # "": in no group (written without one)
    part: str | None = None  # "trusted" / "untrusted" / "all" for a buffer channel's
    invisible: tuple[str, ...] | None = None  # objects it paints that this camera does not see
    left_out: Mapping[str, tuple[str, ...]] | None = None  # object -> its untrusted keys
    zero_valued: Mapping[str, float] | None = None  # key -> raw sum of dM/dtheta at theta = 0
    duality_agrees: bool | None = None  # a transport layer's duality check
    display: DisplayScale | None = None  # the scale a layer is pictured at
    display_clipped: float = 0.0  # the share of this camera's non-zero pixels above it
    # (H, W) bool: pixels drawn neutral in every picture (mostly unresolved objects); None: none
    neutral: np.ndarray | None = None
    # what display scales read instead of ``data``: the unresolved objects left out
    scale_data: np.ndarray | None = None

    def scale_pixels(self) -> np.ndarray:
        """The signed pixels a display scale may read: never an unresolved object's."""
        return signed_pixels(self.data if self.scale_data is None else self.scale_data, self.kind)

    @property
    def original_name(self) -> str:
        return f"{self.objective}.{self.pass_name}"

    @property
    def untrusted(self) -> bool:
        return self.part == "untrusted"

    @property
    def duality_failed(self) -> bool:
        return self.duality_agrees is False


def write_layered_exr(
    path: Path,
    *,
    beauty: np.ndarray | None,
    cryptomattes: Sequence[CryptoLayer],
    layers: Sequence[SensitivityLayer],
    attributes: dict[str, str],
) -> None:
    """Write the compositor EXR atomically; refuse layers a compositor could not use (a name
    clash, NaN or infinity) before any file is touched."""
    header = {"sensaov/format": FORMAT_NAME, "sensaov/format_version": str(FORMAT_VERSION)}
    channels: dict[str, np.ndarray] = {}
    if beauty is not None:
        image = _as_float32(beauty)
        channels.update({n: image[..., i] for i, n in enumerate(BEAUTY_CHANNELS[: image.shape[2]])})
    for crypto in cryptomattes:
        channels.update(rank_channels(
            crypto.type_name, crypto.names, crypto.rank_index, crypto.rank_coverage, crypto.ranks,
            ordered=crypto.ordered,
        ))  # fmt: skip
        header.update(metadata(crypto.type_name, crypto.names))
    reserved = {
        f"{crypto.type_name}{index:02d}"
        for crypto in cryptomattes
        for index in range(layer_count(crypto.ranks))
    }
    for layer, name in zip(layers, layer_names(layers, reserved=reserved), strict=True):
        channels.update(_sensitivity_channels(layer, name))
        header.update(layer_metadata(layer, name))
    header.update(attributes)
    write_exr(path, channels, header)


def sanitise_token(text: str) -> tuple[str, bool]:
    """``text`` as a compositor-safe token and whether it had to change: a token over 63 bytes
    ends in ``_`` plus 6 hex digits of the original's hash, so long names stay apart."""
    clean = _UNSAFE.sub("_", text) or "_"
    if len(clean) > TOKEN_BYTES:
        clean = _with_suffix(clean, text)
    return clean, clean != text


def layer_names(
    layers: Sequence[SensitivityLayer], *, reserved: set[str] | frozenset[str] = frozenset()
) -> list[str]:
    """The final ``objective.pass`` of each layer: sanitised and unique, also as
    ``objective_pass`` (Nuke's rewrite of the dot) and against the ``reserved`` Cryptomatte
    layers. In a clash, sanitised names get a hash suffix on the pass token; clean names keep
    theirs unless clean names clash among themselves.
    """
    seen = Counter((layer.objective, layer.pass_name) for layer in layers)
    duplicates = sorted(f"{o}.{p}" for (o, p), count in seen.items() if count > 1)
    if duplicates:
        raise ExrError(
            f"two sensitivity layers are both named {duplicates[0]!r}",
            hint="give each (objective, pass) pair its own pass name",
        )
    tokens = [
        (sanitise_token(layer.objective), sanitise_token(layer.pass_name)) for layer in layers
    ]
    altered = [o[1] or p[1] for o, p in tokens]
    keys = [f"{o[0]}_{p[0]}" for o, p in tokens]
    clean_holders = Counter(key for key, changed in zip(keys, altered, strict=True) if not changed)
    clean_holders.update(reserved)
    key_count = Counter(keys)
    names = []
    for layer, (objective, pass_name), key, changed in zip(
        layers, tokens, keys, altered, strict=True
    ):
        clash = key_count[key] > 1 or key in reserved
        final_pass = pass_name[0]
        if clash and (changed or clean_holders[key] > 1):
            final_pass = _with_suffix(final_pass, f"{layer.objective}\0{layer.pass_name}")
        names.append(f"{objective[0]}.{final_pass}")
    _check_unique(names, reserved)
    return names


def layer_metadata(layer: SensitivityLayer, name: str) -> dict[str, str]:
    """The ``sensaov/<key>/...`` header strings of one layer."""
    entries = {
        "name": name,
        "objective": layer.objective,
        "pass": layer.pass_name,
        "channels": ",".join(("Y",) if layer.data.ndim == 2 else ("R", "G", "B")),
        "original_name": layer.original_name,
        **layer.metadata,
    }
    if layer.kind:
        entries["kind"] = layer.kind
    if layer.group.name:
        entries["scale_group"] = layer.group.name
        if layer.group.role is not None:
            entries["scale_role"] = layer.group.role
        if layer.group.fixed is not None:
            entries["scale_fixed"] = repr(layer.group.fixed)
    if layer.part is not None:
        entries["part"] = layer.part
    if layer.invisible is not None:
        entries["invisible"] = json.dumps(list(layer.invisible))
    if layer.left_out is not None:
        entries["left_out"] = json.dumps({k: list(v) for k, v in layer.left_out.items()})
    if layer.zero_valued is not None:
        entries["zero_valued"] = json.dumps(dict(layer.zero_valued))
    if layer.duality_agrees is not None:
        entries["duality"] = "agrees" if layer.duality_agrees else DUALITY_FAILED
    if (scale := layer.display) is not None:
        entries |= {
            "display_scale": repr(scale.value),
            "display_rule": scale.rule(),
            "display_scope": scale.scope,
            "display_cameras": json.dumps(list(scale.cameras)),
            "display_clipped": repr(layer.display_clipped),
            "display_clipped_all": repr(scale.clipped),  # every camera of the rule, equally
        }
    prefix = f"sensaov/{layer_key(name)}"
    return {f"{prefix}/{key}": value for key, value in entries.items()}


def display_background(hit: np.ndarray) -> np.ndarray:
    """(3, H, W) half planes: the display colour of a zero pixel of one camera, any layer: the
    map's centre faded to black with ``hit``, the camera's coverage by any object, rounded to
    half once."""
    centre = diverging_linear(np.zeros(1), 1.0)[0]  # (3,) float32, the same at every scale
    fade = np.clip(np.asarray(hit, np.float32), 0.0, 1.0)
    return (centre[:, None, None] * fade[None]).astype(np.float16)


def with_display(
    layer: SensitivityLayer, scale: DisplayScale, background: np.ndarray
) -> tuple[SensitivityLayer, SensitivityLayer]:
    """The raw layer with its display scale, and its display layer (``background``: the
    camera's :func:`display_background`, shown where the layer is zero)."""
    values = signed_pixels(layer.data, layer.kind)
    clipped = clipped_share([layer.scale_pixels()], scale.value)
    # Half keeps the picture's sRGB 8-bit codes (tested); planes make each channel contiguous.
    planes = diverging_linear_planes(values, scale.value, np.float16)
    np.copyto(planes, background, where=(values == 0)[None])
    if layer.neutral is not None:  # unresolved: neither red nor blue (docs/encoding.md)
        grey = neutral_linear().astype(np.float16)[:, None, None]
        np.copyto(planes, grey, where=(layer.neutral & (values != 0))[None])
    display_name = layer.pass_name + DISPLAY_SUFFIX
    metadata = {**layer.metadata, "display_layer": f"{layer.objective}.{display_name}"}
    raw = replace(layer, metadata=metadata, display=scale, display_clipped=clipped)
    display = SensitivityLayer(
        layer.objective,
        display_name,
        planes.transpose(1, 2, 0),
        {
            **{k: v for k, v in layer.metadata.items() if k in _DISPLAY_KEPT},
            "display_of": layer.original_name,
            "encoding": DISPLAY_ENCODING,
        },
        kind="display",
        group=ScaleGroup(layer.group.name),
        part=layer.part,
        left_out=layer.left_out,
        display=scale,
        display_clipped=clipped,
    )
    return raw, display


# The rule every picture of a buffer channel follows, written on its raw and display layers.
NEUTRAL_RULE = (
    "an object whose signed sum lies within its Student-t 95 % interval, or whose batches look "
    "heavy-tailed, is drawn neutral grey in display layers and previews and never sets a display "
    "scale; the raw channel keeps its number"
)


def resolution_metadata(values: ChannelValues) -> dict[str, str]:
    """How a buffer channel's objects stand against noise, for its layer's header: the rule,
    the objects drawn neutral with why, and the score it paints."""
    rule = NEUTRAL_RULE if values.measured else "no error: the buffer has one batch"
    return {
        "resolution": rule,
        "unresolved": json.dumps(values.unresolved),
        "score": f"{values.spec.aggregate} (the rankings' default: {DEFAULT_AGGREGATE})",
    }


# What a display layer repeats of its raw layer's metadata: where it came from, and which objects
# it draws neutral and why (the rule: docs/encoding.md, "Unresolved values").
_DISPLAY_KEPT = ("camera", "buffer", "resolution", "unresolved", "score")


def _with_suffix(token: str, original: str) -> str:
    suffix = f"_{name_hash(original):08x}"[: SUFFIX_HEX + 1]
    return token[: TOKEN_BYTES - len(suffix)] + suffix


def _check_unique(names: Sequence[str], reserved: set[str] | frozenset[str]) -> None:
    views = [name.replace(".", "_") for name in names] + sorted(reserved)
    clashing = sorted(view for view, count in Counter(views).items() if count > 1)
    keys = Counter(layer_key(name) for name in names)
    if clashing or len(keys) < len(names):
        raise ExrError(
            f"sensitivity layer names still clash after sanitising: {clashing or sorted(keys)}",
            hint="rename the objectives or passes so they differ in [A-Za-z0-9_] characters",
        )


def _sensitivity_channels(layer: SensitivityLayer, name: str) -> dict[str, np.ndarray]:
    data = layer.data if layer.kind == "display" else _as_float32(layer.data)
    bad = _non_finite(data)
    if bad:  # a render's NaN or an encoding's overflow: a compositor multiply spreads it
        raise ExrError(
            f"sensitivity layer {layer.original_name!r} has {bad} of {data.size} values NaN "
            f"or infinite (after conversion to {data.dtype})",
            hint="a compositor multiply turns them into NaN mattes; zero them or fix the "
            "encoding's scale",
        )
    if data.ndim == 2:
        return {f"{name}.Y": data}
    return {f"{name}.{channel}": data[..., index] for index, channel in enumerate("RGB")}


def _non_finite(data: np.ndarray) -> int:
    """How many values are NaN or infinite; half by its exponent bits (numpy's isfinite has no
    vector loop for half)."""
    if data.dtype == np.float16:
        return int(np.count_nonzero((data.view(np.uint16) & 0x7C00) == 0x7C00))
    return int(np.count_nonzero(~np.isfinite(data)))


def _as_float32(data: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):  # an overflow becomes inf, which the caller reports
        return np.ascontiguousarray(data, dtype=np.float32)


# Cryptomatte 1.2 ID layers: object names hashed into float IDs, ranked coverage, manifest.
# A keyer picks an object by hashing the name the artist chose, so the IDs must be exactly the
# specification's: MurmurHash3_x86_32 (seed 0) of the UTF-8 name, its exponent forced into
# [1, 254] (never a denormal, infinity or NaN), as the bits of a little-endian float32. Layers
# ``{T}00``, ``{T}01``, … hold two ranks each as (ID, coverage, ID, coverage); the deprecated
# preview layer ``{T}.R/G/B`` is never written (Blender 3.4 mistakes it for another rank).
# An object is in a camera's frame when its ID covers some pixel of the camera's ``CryptoObject``
# layers (:func:`visible_objects`); the manifest names every object of the scene, seen or not.


def name_hash(name: str) -> int:
    return int(mmh3.hash(name.encode("utf-8"), seed=0, signed=False))


def id_bits(name: str) -> int:
    """The 32 bits of ``name``'s ID: its hash with the exponent moved off 0 and 255."""
    bits = name_hash(name)
    exponent = (bits >> _EXPONENT_SHIFT) & _EXPONENT_MASK
    if exponent in (0, _EXPONENT_MASK):
        bits ^= 1 << _EXPONENT_SHIFT
    return bits


def uint32_to_float32(bits: int) -> np.float32:
    """Reinterpret 32 bits as a little-endian float32 (the specification's conversion)."""
    return np.array([bits], dtype="<u4").view("<f4")[0]


def id_float(name: str) -> np.float32:
    return uint32_to_float32(id_bits(name))


def id_hex(name: str) -> str:
    """The ID as the manifest writes it: 8 lowercase hex digits of the float's bits."""
    return f"{id_bits(name):08x}"


def manifest(names: Sequence[str]) -> str:
    """The JSON manifest ``{"name": "8-hex ID"}``, sorted, compact, UTF-8 names unescaped
    (identical names merge into one entry, as the specification intends)."""
    entries = {name: id_hex(name) for name in sorted(set(names))}
    return json.dumps(entries, ensure_ascii=False, separators=(",", ":"), sort_keys=True)


def layer_key(type_name: str) -> str:
    """The metadata key of a type: the first 7 hex digits of its name's hash (stable per type)."""
    return f"{name_hash(type_name):08x}"[:7]


def layer_count(ranks: int) -> int:
    """How many RGBA layers hold ``ranks`` ranks (two per layer)."""
    return (ranks + 1) // 2


def channel_names(type_name: str, ranks: int = DEFAULT_RANKS) -> list[str]:
    """The channel names :func:`rank_channels` writes, in order: ``T00.R`` … ``T02.A``."""
    return [f"{type_name}{layer:02d}.{c}" for layer in range(layer_count(ranks)) for c in "RGBA"]


def rank_channels(
    type_name: str,
    names: Sequence[str],
    rank_index: np.ndarray,
    rank_coverage: np.ndarray,
    ranks: int = DEFAULT_RANKS,
    *,
    ordered: bool = False,
) -> dict[str, np.ndarray]:
    """Cryptomatte channels (name -> H x W float32) from per-pixel ranked coverage.

    ``rank_index`` (H, W, R) indexes ``names`` (-1 = empty rank); ``rank_coverage`` (H, W, R)
    is each rank's coverage. Ranks are stably sorted by coverage, largest first, empty ranks
    last; the first ``ranks`` are written, padded with ID 0 / coverage 0, into a fixed
    ``ceil(ranks / 2)`` layers, so a sequence keeps its channels on every frame. ``ordered``
    promises that order already (empty ranks at coverage 0, as a visibility pass builds them):
    nothing is then zeroed, checked or sorted.
    """
    _check_type_name(type_name)
    index, coverage = _checked_ranks(names, rank_index, rank_coverage)
    ids = np.array([id_float(name) for name in names] + [np.float32(0.0)], dtype=np.float32)
    if not ordered:
        empty = index < 0
        coverage = np.where(empty, np.float32(0.0), coverage)
        if not _in_rank_order(coverage, empty):
            # Empty ranks sort last whatever their coverage; among the rest, largest first.
            order = np.lexsort((-coverage, empty), axis=-1)
            index = np.take_along_axis(index, order, axis=-1)
            coverage = np.take_along_axis(coverage, order, axis=-1)
    height, width, present = index.shape
    channels: dict[str, np.ndarray] = {}
    names_out = channel_names(type_name, ranks)
    for rank in range(2 * layer_count(ranks)):
        id_name, cov_name = names_out[2 * rank], names_out[2 * rank + 1]
        if rank < min(present, ranks):
            channels[id_name] = ids[index[..., rank]]  # index -1 picks the trailing 0.0
            channels[cov_name] = np.ascontiguousarray(coverage[..., rank])
        else:  # padding: ranks asked for beyond those present, and the last layer's odd one
            channels[id_name] = np.zeros((height, width), dtype=np.float32)
            channels[cov_name] = np.zeros((height, width), dtype=np.float32)
    return channels


def metadata(type_name: str, names: Sequence[str]) -> dict[str, str]:
    """The header attributes ``cryptomatte/<key>/name|hash|conversion|manifest`` of one type."""
    _check_type_name(type_name)
    prefix = f"cryptomatte/{layer_key(type_name)}"
    return {
        f"{prefix}/name": type_name,
        f"{prefix}/hash": HASH_NAME,
        f"{prefix}/conversion": CONVERSION,
        f"{prefix}/manifest": manifest(names),
    }


def _check_type_name(type_name: str) -> None:
    if not TYPE_NAME_PATTERN.fullmatch(type_name):
        raise CryptomatteError(
            f"Cryptomatte type name {type_name!r} is not a compositor-safe layer name",
            hint="use 1 to 61 characters from [A-Za-z0-9_], not starting with a digit, "
            "e.g. CryptoObject or CryptoMaterial",
        )


def _in_rank_order(coverage: np.ndarray, empty: np.ndarray) -> bool:
    """Whether the stable sort would leave every pixel's ranks as they are."""
    filled_after_empty = empty[..., :-1] & ~empty[..., 1:]
    increasing = coverage[..., 1:] > coverage[..., :-1]
    return not (filled_after_empty.any() or (increasing & ~empty[..., 1:]).any())


def _checked_ranks(
    names: Sequence[str], rank_index: np.ndarray, rank_coverage: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    index = np.asarray(rank_index)
    coverage = np.asarray(rank_coverage)
    if index.ndim != 3 or coverage.shape != index.shape:
        raise CryptomatteError(
            f"rank_index {index.shape} and rank_coverage {coverage.shape} must share one "
            "(H, W, R) shape",
            hint="pass the visibility pass's ranked ids and coverage unchanged",
        )
    if index.size and (index.min() < -1 or index.max() >= len(names)):
        raise CryptomatteError(
            f"rank_index holds {int(index.min())}..{int(index.max())} but there are "
            f"{len(names)} names",
            hint="indices run from 0 to len(names) - 1, with -1 for an empty rank",
        )
    return index, coverage.astype(np.float32, copy=False)


def visible_objects(
    paths: Sequence[Path], check: Callable[[Path, Mapping[str, Any]], None]
) -> dict[str, frozenset[str]]:
    """Camera name (the file's stem, as ``project`` names it) -> the objects it sees; ``check``
    is called with each file's header first (``rank --exr`` refuses an EXR of another buffer)."""
    seen = {}
    for path in paths:
        if path.stem in seen:
            raise CameraFileError(
                "two files for one camera", where=str(path), hint="pass each once"
            )
        try:
            channels, header = read_exr(path)
        except ExrError as error:  # a file the user named: bad input, not a failed job
            raise CameraFileError(error.message, where=error.where, hint=error.hint) from error
        check(path, header)
        seen[path.stem] = seen_names(channels, header, where=str(path))
    return seen


def seen_names(
    channels: Mapping[str, np.ndarray], header: Mapping[str, Any], *, where: str = "EXR"
) -> frozenset[str]:
    """The manifest names of ``CryptoObject`` whose ID has coverage > 0 in some pixel."""
    names = _manifest(header, where)
    pattern = re.compile(rf"^{OBJECT_TYPE}\d\d\.([RGBA])$")
    layers = {name[:-2] for name in channels if pattern.match(name)}
    ids: set[float] = set()
    for layer in sorted(layers):
        for id_channel, coverage_channel in (("R", "G"), ("B", "A")):  # an ID, its coverage
            pair = (f"{layer}.{id_channel}", f"{layer}.{coverage_channel}")
            missing = [name for name in pair if name not in channels]
            if missing:
                raise CameraFileError(f"Cryptomatte channel {missing[0]} is missing", where=where)
            ids.update(np.asarray(channels[pair[0]])[np.asarray(channels[pair[1]]) > 0].tolist())
    return frozenset(name for name in names if float(id_float(name)) in ids)


def _manifest(header: Mapping[str, Any], where: str) -> list[str]:
    for key, value in header.items():
        if key.startswith("cryptomatte/") and key.endswith("/name") and value == OBJECT_TYPE:
            return _manifest_names(header.get(key[: -len("name")] + "manifest", "{}"), where)
    raise CameraFileError(
        f"no {OBJECT_TYPE} layer",
        where=where,
        hint="pass an inspection camera's EXR written by 'sensaov project'",
    )


def _manifest_names(manifest: Any, where: str) -> list[str]:
    """The object names of a Cryptomatte manifest: a JSON object of name -> 8 hex digits."""
    try:
        names = json.loads(manifest) if isinstance(manifest, str | bytes) else None
    except (ValueError, RecursionError):
        names = None
    if not isinstance(names, dict) or not all(isinstance(v, str) for v in names.values()):
        raise CameraFileError(
            f"the {OBJECT_TYPE} manifest is not a JSON object of names and IDs",
            where=where,
            hint="pass an inspection camera's EXR written by 'sensaov project'",
        )
    # Names are matched by their hash: an ID that is not its name's hash would list the wrong
    # objects as seen.
    wrong = next((name for name, value in names.items() if value.lower() != id_hex(name)), None)
    if wrong is not None:
        raise CameraFileError(
            f"the {OBJECT_TYPE} manifest gives {wrong[:60]!r} the ID {names[wrong][:20]!r}, "
            f"not its Cryptomatte hash {id_hex(wrong)}",
            where=where,
            hint="the file is damaged: run 'sensaov project' again for this camera",
        )
    return list(names)
