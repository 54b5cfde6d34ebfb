"""The beauty under a view: ``run``'s own primal for the objective camera, else a quick trace.

The objective camera sees exactly what ``sensaov run`` rendered, at the run's spp (far above the
quick pass's default 4), so its ``primal.exr`` is that camera's beauty when it was written with
this very buffer (the buffer id its provenance records) at the view's size and with at least the
spp asked for. Reading it costs milliseconds where the quick path trace costs more than the rest
of the view (bench figure 4). Any other case renders the quick pass, as every other camera does:
no primal beside the buffer (silently), or one that is unreadable, from another buffer, of
another size or with fewer samples (each said in one line), or ``--force`` (the scene may have
changed since the run). The EXR's provenance records which it was (``beauty``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer, buffer_id, provenance_id
from sensaov_cli.errors import SensaovError
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.provenance import header_provenance
from sensaov_cli.pipeline.merge import primal_beside
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.render.visibility import render_beauty
from sensaov_cli.views.coverage import VisibilityPass


@dataclass(frozen=True)
class RunBeauty:
    """The run's primal, read once before the views: linear RGB and how it was made."""

    rgb: np.ndarray  # (H, W, 3) float32
    path: Path
    spp: int

    def describe(self) -> str:
        return f"{self.path.name} of the buffer's run ({self.spp} spp)"


def run_beauty(
    buffer: SensitivityBuffer, buffer_path: Path, spp: int, progress: Progress
) -> RunBeauty | None:
    """The primal written with ``buffer``, if it can stand in for a ``spp``-sample beauty."""
    path = primal_beside(buffer_path)
    if spp <= 0 or not path.is_file():
        return None
    try:
        channels, header = read_exr(path, "run's primal image")
    except SensaovError as error:
        progress.note(f"{path.name} not used as the objective camera's beauty: {error}")
        return None
    provenance = header_provenance(header)
    recorded = int(provenance.get("spp") or 0) if provenance is not None else 0
    reason = None
    if provenance is None or provenance_id(provenance) != buffer_id(buffer):
        reason = "it was not written with this buffer"
    elif recorded < spp:
        reason = f"it has {recorded} spp, fewer than the {spp} asked for"
    rgb = _rgb(channels)
    if reason is None and rgb is None:
        reason = "it has no R, G, B or Y channels"
    if reason is not None or rgb is None:
        progress.note(f"{path.name} not used as the objective camera's beauty: {reason}")
        return None
    return RunBeauty(rgb, path, recorded)


def view_beauty(
    loaded: LoadedScene,
    sensor: Any,
    visibility: VisibilityPass,
    spp: int,
    seed: int,
    reused: RunBeauty | None,
) -> tuple[np.ndarray | None, str]:
    """The view's RGBA beauty (alpha: the visibility coverage) and what it is."""
    if spp <= 0:
        return None, "none (--beauty-spp 0)"
    if reused is not None and reused.rgb.shape[:2] == (visibility.height, visibility.width):
        alpha = visibility.coverage_hit[..., None].astype(np.float32)
        return np.concatenate([reused.rgb, alpha], axis=2), reused.describe()
    image = render_beauty(loaded, sensor, visibility, spp, seed)
    return image, f"path trace at {spp} spp"


def _rgb(channels: dict[str, np.ndarray]) -> np.ndarray | None:
    if all(name in channels for name in ("R", "G", "B")):
        return np.stack([channels[n] for n in ("R", "G", "B")], axis=-1).astype(np.float32)
    if "Y" in channels:  # a mono variant's primal: shown grey, as the quick pass shows it
        return np.repeat(channels["Y"][..., None], 3, axis=2).astype(np.float32)
    return None
