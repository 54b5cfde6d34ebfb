"""Figure 9: writing and reading a buffer that holds one large RGB texture gradient (numpy only)."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bench.jobs import Workspace
from bench.results import Figure, Row, fmt
from bench.settings import Settings
from bench.timing import Stats, interleave
from sensaov_cli.buffer.npz import buffer_writer, read_buffer
from sensaov_cli.outputs.atomic import atomic_write

if TYPE_CHECKING:
    from sensaov_cli.buffer.model import SensitivityBuffer

MB = 1e6


def make_buffer(side: int) -> SensitivityBuffer:
    from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer

    rng = np.random.default_rng(0)
    shape = (side, side, 3)
    key = "wall.reflectance.data"
    param = ParamRecord(key, "reflectance", ("wall",), shape, True, "diffuse", (), "verified", "")
    objective = ObjectiveRecord("mean_luma", {"type": "mean_luminance"}, 0.5, 1)
    return SensitivityBuffer(
        provenance={"tool": "bench"},
        objects=("wall",),
        params=(param,),
        objectives=(objective,),
        values={key: rng.random(shape, dtype=np.float32)},
        grads={"mean_luma": {key: rng.standard_normal(shape, dtype=np.float32) * 1e-6}},
    )


def buffer_io(ws: Workspace, s: Settings, log: Callable[[str], None]) -> Figure:
    side = s.io_texture
    figure = Figure(
        9,
        f"Buffer I/O: a buffer holding a {side}² RGB texture gradient",
        "report (no goal)",
        f"`SensitivityBuffer` built in numpy with one parameter of shape ({side}, {side}, 3): "
        "its value and one objective's gradient (random float32, which does not compress). "
        "`save` (atomic write) and `load` (full validation) interleaved; the file is read back "
        "from the page cache.",
    )
    buffer = make_buffer(side)
    path = ws.root / "io" / "buffer.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    t = interleave({"save": _save(buffer, path), "load": _load(path)}, s.rounds)
    size = path.stat().st_size / MB
    raw = 2 * side * side * 3 * 4 / MB
    figure.rows += [
        Row("save", t["save"], "s", None, f"{fmt(size / t['save'].median, 'MB/s')}"),
        Row("load", t["load"], "s", None, f"{fmt(size / t['load'].median, 'MB/s')}"),
        Row(
            "file size",
            Stats.of([size]),
            "MB",
            None,
            f"arrays {fmt(raw, 'MB')} (stored, uncompressed)",
        ),
    ]
    log("figure 9: done")
    return figure


def _save(buffer: SensitivityBuffer, path: Path) -> Callable[[], float]:
    def measure() -> float:
        start = time.perf_counter()
        atomic_write(path, buffer_writer(buffer))
        return time.perf_counter() - start

    return measure


def _load(path: Path) -> Callable[[], float]:

    def measure() -> float:
        start = time.perf_counter()
        read_buffer(path)
        return time.perf_counter() - start

    return measure
