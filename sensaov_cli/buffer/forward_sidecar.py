"""The forward sidecar (``forward.npz``, version 1): forward images stored beside their buffer.

Forward channels (§4) are the one view not derived from the buffer: each is an image J·v
rendered by ``sensaov run``. They are written atomically together with ``buffer.npz``, in a
plain ``.npz`` of one JSON header (member ``header``), the objectives' image-space adjoints
(``adjoint_<j>``) and the forward images (``image_<i>``). The header names the buffer it belongs
to (job hash, scene fingerprint, the buffer's creation time); a reader refuses any other buffer.
Specified in ``docs/buffer-format.md``.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import archive_writer
from sensaov_cli.errors import BufferFormatError, FingerprintMismatch
from sensaov_cli.limits import regular_file

FORMAT_NAME = "sensaov-forward"
FORMAT_VERSION = 1
HEADER = "header"
TIES = ("job_hash", "scene_fingerprint", "created_utc")  # buffer provenance the sidecar repeats
# Forward/reverse duality at one seed holds up to float32 rounding: the backward pass sums one
# gradient over every sample in float32, whose rounding grows as sqrt(samples) · 2^-24
# (docs/verification.md). The tolerance is the larger of 1e-4 and 16 times that rounding.
DUALITY_FLOOR = 1e-4
ROUNDING_MARGIN = 16.0


def duality_tolerance(samples: int) -> float:
    """The relative duality residual a correct buffer stays under, for ``samples`` = W·H·spp."""
    return max(DUALITY_FLOOR, ROUNDING_MARGIN * float(np.sqrt(max(samples, 1))) * 2.0**-24)


@dataclass(frozen=True, eq=False)
class ForwardPass:
    """One forward pass: J·v over ``keys`` (``direction``: value = θ, ones = 1) at ``seed``."""

    keys: tuple[str, ...]
    direction: str
    seed: int
    seconds: float
    integrators: tuple[str, ...]
    failure: str  # Mitsuba's message when it could not produce the derivative ("" = fine)
    image: np.ndarray | None  # (H, W, C) float32; None exactly when ``failure``


@dataclass(frozen=True)
class ForwardLayer:
    """What ``project`` writes: ``forward.<name>`` or ``<objective>.transport_<name>``."""

    kind: str  # "forward" | "transport"
    name: str
    objective: str | None  # the transport layer's objective; None for a forward channel
    pass_index: int
    source: str  # the job entry that asked for it: "forward[0]", "channels[3] (top 2)"


@dataclass(frozen=True, eq=False)
class ForwardData:
    ties: dict[str, str]  # TIES, as the buffer's provenance records them
    provenance: dict[str, Any]
    adjoints: dict[str, np.ndarray]  # objective -> dM/dI at the primal, (H, W, C)
    passes: tuple[ForwardPass, ...] = ()
    layers: tuple[ForwardLayer, ...] = ()


def ties_of(buffer: SensitivityBuffer) -> dict[str, str]:
    return {key: str(buffer.provenance.get(key, "")) for key in TIES}


def check_belongs(data: ForwardData, buffer: SensitivityBuffer, path: Path) -> None:
    """Refuse a sidecar written with another buffer than ``buffer`` (one line, exit 2)."""
    expected = ties_of(buffer)
    differing = [key for key in TIES if data.ties.get(key) != expected[key]]
    if differing:
        raise FingerprintMismatch(
            f"{path.name} belongs to another buffer ({', '.join(differing)} differ)",
            where=str(path),
            hint="re-run 'sensaov run' to write the buffer and its forward images together",
        )


def forward_writer(data: ForwardData) -> Callable[[Path], None]:
    """A function writing ``data`` to a given (temporary) path, for paired atomic writes."""
    objectives = list(data.adjoints)
    header = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "ties": data.ties,
        "provenance": data.provenance,
        "objectives": objectives,
        "passes": [  # every field but the image (a member), in field order
            {k: round(v, 4) if k == "seconds" else v for k, v in vars(p).items() if k != "image"}
            for p in data.passes
        ],
        "layers": [layer.__dict__ for layer in data.layers],
    }
    members = {HEADER: np.array(json.dumps(header, allow_nan=False))}
    for j, name in enumerate(objectives):
        members[f"adjoint_{j}"] = np.ascontiguousarray(data.adjoints[name], np.float32)
    for i, p in enumerate(data.passes):
        if p.image is not None:
            members[f"image_{i}"] = np.ascontiguousarray(p.image, np.float32)
    return archive_writer(members)


def read_forward(path: Path) -> ForwardData:
    """Read a sidecar; any defect is one :class:`BufferFormatError` line (exit 2)."""
    regular_file(path, "forward sidecar", error=BufferFormatError)  # a FIFO would block np.load
    try:
        with np.load(path, allow_pickle=False) as npz:
            header = json.loads(str(npz[HEADER][()]))
            _require(header.get("format") == FORMAT_NAME, "not a sensaov forward sidecar")
            version = header.get("format_version")
            _require(version == FORMAT_VERSION, f"format version {version!r} is not 1")
            adjoints = {
                name: np.array(npz[f"adjoint_{j}"], np.float32)
                for j, name in enumerate(header["objectives"])
            }
            passes = tuple(_pass(npz, i, entry) for i, entry in enumerate(header["passes"]))
            layers = tuple(ForwardLayer(**entry) for entry in header["layers"])
    except BufferFormatError as exc:
        raise BufferFormatError(str(exc), where=str(path), hint=_AGAIN) from exc
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
        raise BufferFormatError(
            f"cannot read forward sidecar: {type(exc).__name__}: {exc}",
            where=str(path),
            hint=_AGAIN,
        ) from exc
    for layer in layers:
        _require(0 <= layer.pass_index < len(passes), f"layer {layer.name!r} names no pass")
    return ForwardData(header["ties"], header["provenance"], adjoints, passes, layers)


_AGAIN = "re-run 'sensaov run' to write it again"


def _pass(npz: Any, index: int, entry: Any) -> ForwardPass:
    failure = str(entry["failure"])
    image = None if failure else np.array(npz[f"image_{index}"], np.float32)
    _require(
        image is None or bool(np.all(np.isfinite(image))), f"image_{index} holds NaN or infinity"
    )
    return ForwardPass(
        tuple(entry["keys"]), str(entry["direction"]), int(entry["seed"]),
        float(entry["seconds"]), tuple(entry["integrators"]), failure, image,
    )  # fmt: skip


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise BufferFormatError(message)
