"""The multilayer EXR a compositor opens: beauty, Cryptomatte ID layers and sensitivity passes.

One file per camera. Channel names follow ``Layer.Pass.Channel`` — here
``objective.pass.Y`` (or ``.R/.G/.B``) — beside a plain ``R,G,B,A`` beauty and a real
Cryptomatte (``CryptoObject00..02``), so a keyer's matte can gate any sensitivity pass.
Compositors are strict about names (MITSUBA-NOTES "Compositors"): every token is rewritten to
``[A-Za-z0-9_]`` and at most 63 bytes, names stay unique, and the original names go into the
metadata. Everything is float32 with ZIP compression: half floats would destroy Cryptomatte IDs
and small sensitivities alike. The layout is specified in ``docs/exr-layout.md``.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sensaov_cli.errors import ExrError
from sensaov_cli.outputs import cryptomatte
from sensaov_cli.outputs.exr import write_exr

FORMAT_NAME = "sensaov-aov-exr"
FORMAT_VERSION = 2  # 2: display layers, display scales, trust parts, stamps (exr-layout.md)
TOKEN_BYTES = 63  # Blender keeps layer and pass names in 64-byte buffers
SUFFIX_HEX = 6
BEAUTY_CHANNELS = ("R", "G", "B", "A")
_UNSAFE = re.compile(r"[^A-Za-z0-9_]")
_METADATA_KEY = re.compile(r"[A-Za-z0-9_]+")
_RENAME_TYPE = "two Cryptomatte types share a metadata key; rename one"
_RENAME_LAYER = "two sensitivity layers share a metadata key; rename one"
_RENAME_ATTRIBUTE = "the layout writes this attribute itself; pick another key"
_WRITER_KEYS = frozenset({"name", "objective", "pass", "channels"})
# Attributes the EXR header itself defines; a caller's attribute must not replace one.
_STANDARD_ATTRIBUTES = frozenset(
    {
        "channels",
        "chunkCount",
        "compression",
        "dataWindow",
        "displayWindow",
        "lineOrder",
        "name",
        "pixelAspectRatio",
        "screenWindowCenter",
        "screenWindowWidth",
        "tiles",
        "type",
        "version",
    }
)


@dataclass(frozen=True, eq=False)
class CryptoLayer:
    """Ranked per-pixel coverage of named things (objects, materials) for one Cryptomatte type.

    ``rank_index`` (H, W, R) indexes ``names`` (-1 = empty); ``rank_coverage`` (H, W, R) is the
    coverage of each rank, largest first.
    """

    type_name: str
    names: Sequence[str]
    rank_index: np.ndarray
    rank_coverage: np.ndarray
    ranks: int = cryptomatte.DEFAULT_RANKS
    ordered: bool = False  # ranks already in order, empty last at 0 (a visibility pass's)


@dataclass(frozen=True, eq=False)
class SensitivityLayer:
    """One sensitivity pass: (H, W) data becomes channel ``Y``, (H, W, 3) becomes ``R, G, B``.

    ``metadata`` (selection, aggregate, weight, encoding, scale, spp, buffer, original_name …)
    is written under ``sensaov/<key>/``; ``original_name`` defaults to ``objective.pass_name``.
    """

    objective: str
    pass_name: str
    data: np.ndarray
    metadata: Mapping[str, str] = field(default_factory=dict)

    @property
    def original_name(self) -> str:
        return f"{self.objective}.{self.pass_name}"


def write_layered_exr(
    path: Path,
    *,
    width: int,
    height: int,
    beauty: np.ndarray | None,
    cryptomattes: Sequence[CryptoLayer],
    layers: Sequence[SensitivityLayer],
    attributes: dict[str, str],
) -> None:
    """Write the compositor EXR atomically; refuse bad input before any file is touched.

    Raises :class:`ExrError` (a ``ValueError``) for a wrong shape, NaN or infinity in
    sensitivity data, two layers with the same objective and pass, or a caller attribute that
    would replace one the layout owns.
    """
    channels, header = assemble_layers(
        width=width,
        height=height,
        beauty=beauty,
        cryptomattes=cryptomattes,
        layers=layers,
        attributes=attributes,
    )
    write_exr(path, channels, header)


def assemble_layers(
    *,
    width: int,
    height: int,
    beauty: np.ndarray | None,
    cryptomattes: Sequence[CryptoLayer],
    layers: Sequence[SensitivityLayer],
    attributes: dict[str, str],
) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The channels and header strings :func:`write_layered_exr` writes, without writing."""
    if not all(isinstance(n, int | np.integer) and n > 0 for n in (width, height)):
        raise ExrError(f"image size must be positive integers, got {width} x {height}")
    shape = (int(height), int(width))
    parts: list[dict[str, np.ndarray]] = []
    header = {
        "sensaov/format": FORMAT_NAME,
        "sensaov/format_version": str(FORMAT_VERSION),
    }
    if beauty is not None:
        parts.append(_beauty_channels(beauty, shape))
    for crypto in cryptomattes:
        parts.append(_crypto_channels(crypto, shape))
        _merge(header, cryptomatte.metadata(crypto.type_name, crypto.names), _RENAME_TYPE)
    reserved = {
        f"{crypto.type_name}{index:02d}"
        for crypto in cryptomattes
        for index in range(cryptomatte.layer_count(crypto.ranks))
    }
    for layer, name in zip(layers, layer_names(layers, reserved=reserved), strict=True):
        parts.append(_sensitivity_channels(layer, name, shape))
        _merge(header, layer_metadata(layer, name), _RENAME_LAYER)
    channels = _union(parts)
    if not channels:
        raise ExrError("nothing to write: no beauty, no Cryptomatte and no sensitivity layer")
    _merge(header, _checked_attributes(attributes), _RENAME_ATTRIBUTE)
    return channels, header


def sanitise_token(text: str) -> tuple[str, bool]:
    """``text`` as a compositor-safe token and whether it had to change.

    Every character outside ``[A-Za-z0-9_]`` becomes ``_`` (an empty token becomes ``_``); a
    token over 63 bytes is cut and ends in ``_`` plus 6 hex digits of the original's hash, so
    two long names that share a beginning stay apart.
    """
    clean = _UNSAFE.sub("_", text) or "_"
    if len(clean) > TOKEN_BYTES:
        clean = _with_suffix(clean, text)
    return clean, clean != text


def layer_names(
    layers: Sequence[SensitivityLayer], *, reserved: set[str] | frozenset[str] = frozenset()
) -> list[str]:
    """The final ``objective.pass`` of each layer: sanitised, at most 63 bytes a token, unique.

    Uniqueness is checked on ``objective_pass`` too, the name Nuke shows once it rewrites the
    dot, and against the ``reserved`` Cryptomatte layer names. In a clash, the layers whose
    names were sanitised get ``_`` plus 6 hex digits of their original name's hash on the pass
    token; clean names keep theirs unless clean names clash among themselves.
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


def layer_key(name: str) -> str:
    """The metadata key of a layer: 7 hex digits of the hash of its final ``objective.pass``."""
    return cryptomatte.layer_key(name)


def layer_metadata(layer: SensitivityLayer, name: str) -> dict[str, str]:
    """``sensaov/<key>/...`` attributes of one layer: name, objective, pass, channels + caller's."""
    for key, value in layer.metadata.items():
        if key in _WRITER_KEYS or not _METADATA_KEY.fullmatch(key) or not isinstance(value, str):
            raise ExrError(
                f"metadata {key!r}: {value!r} of layer {layer.original_name!r} cannot be written",
                hint=f"keys from [A-Za-z0-9_] other than {sorted(_WRITER_KEYS)}, values str",
            )
    prefix = f"sensaov/{layer_key(name)}"
    entries = {
        "name": name,
        "objective": layer.objective,
        "pass": layer.pass_name,
        "channels": ",".join(_data_channels(np.asarray(layer.data))),
        "original_name": layer.original_name,
        **layer.metadata,
    }
    return {f"{prefix}/{key}": value for key, value in entries.items()}


def _with_suffix(token: str, original: str) -> str:
    suffix = f"_{cryptomatte.name_hash(original):08x}"[: SUFFIX_HEX + 1]
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


def _data_channels(data: np.ndarray) -> tuple[str, ...]:
    return ("Y",) if data.ndim == 2 else ("R", "G", "B")


def _beauty_channels(beauty: np.ndarray, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    image = np.asarray(beauty)
    if image.ndim != 3 or image.shape[:2] != shape or image.shape[2] not in (3, 4):
        raise ExrError(
            f"beauty has shape {image.shape}; expected {shape + (3,)} or {shape + (4,)}",
            hint="pass the RGB or RGBA render at the file's resolution",
        )
    image = _as_float32(image, "beauty")
    return {name: image[..., index] for index, name in enumerate(BEAUTY_CHANNELS[: image.shape[2]])}


def _crypto_channels(crypto: CryptoLayer, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    index = np.asarray(crypto.rank_index)
    if index.shape[:2] != shape:
        raise ExrError(
            f"Cryptomatte {crypto.type_name!r} has shape {index.shape}; "
            f"expected {shape} plus a rank axis",
            hint="compute visibility at the file's resolution",
        )
    return cryptomatte.rank_channels(
        crypto.type_name, crypto.names, index, crypto.rank_coverage, crypto.ranks,
        ordered=crypto.ordered,
    )  # fmt: skip


def _sensitivity_channels(
    layer: SensitivityLayer, name: str, shape: tuple[int, int]
) -> dict[str, np.ndarray]:
    data = np.asarray(layer.data)
    if data.shape[:2] != shape or data.ndim not in (2, 3) or data.shape[2:] not in ((), (3,)):
        raise ExrError(
            f"sensitivity layer {layer.original_name!r} has shape {data.shape}; "
            f"expected {shape} (one Y channel) or {shape + (3,)} (R, G, B)",
        )
    if data.dtype != np.float16 or layer.metadata.get("kind") != "display":
        data = _as_float32(data, f"sensitivity layer {layer.original_name!r}")
    bad = _non_finite(data)
    if bad:
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
    """How many values are NaN or infinite. Half (display layers) by its exponent bits, all
    ones exactly there: numpy's isfinite has no vector loop for half, 10x slower."""
    if data.dtype == np.float16:
        return int(np.count_nonzero((data.view(np.uint16) & 0x7C00) == 0x7C00))
    return int(np.count_nonzero(~np.isfinite(data)))


def _as_float32(data: np.ndarray, what: str) -> np.ndarray:
    if data.dtype.kind not in "fiu":
        raise ExrError(f"{what} holds {data.dtype} values; expected real numbers")
    with np.errstate(over="ignore"):  # an overflow becomes inf, which the caller reports
        return np.ascontiguousarray(data, dtype=np.float32)


def _union(parts: Sequence[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    names = Counter(name for part in parts for name in part)
    duplicates = sorted(name for name, count in names.items() if count > 1)
    if duplicates:
        raise ExrError(
            f"channel {duplicates[0]!r} would be written twice",
            hint="give each Cryptomatte type its own name",
        )
    return {name: data for part in parts for name, data in part.items()}


def _merge(header: dict[str, str], extra: Mapping[str, str], hint: str) -> None:
    clash = sorted(set(header) & set(extra))
    if clash:
        raise ExrError(f"header attribute {clash[0]!r} would be written twice", hint=hint)
    header.update(extra)


def _checked_attributes(attributes: Mapping[str, str]) -> dict[str, str]:
    for key, value in attributes.items():
        if key in _STANDARD_ATTRIBUTES or not isinstance(value, str):
            raise ExrError(
                f"attribute {key!r}: {value!r} cannot be written",
                hint="attributes are str -> str and cannot replace a standard EXR attribute "
                f"({', '.join(sorted(_STANDARD_ATTRIBUTES))})",
            )
    return dict(attributes)
